"""``apr reproduce table1``: train the presets of Table 1 over several seeds, then write the table.

``--scale paper`` runs the presets at paper size (GPU jobs); ``--scale cpu`` runs each one's ``cpu-`` preset, the
same structure and learning recipe at a 2-core CPU's budget (``apr.train.config.cpu_scale``). Once a run is
trained its final policy is evaluated blind (another scene's images in every phase, :func:`evaluate_blind`).

Runs are named ``PRESET__sSEED`` under the output folder, so the command is resumable: a finished run (one
with an evaluation at or beyond the grasp budget) is skipped, an unfinished one continues from its latest
checkpoint (``Trainer.resume``), and a folder without a checkpoint starts over. ``--parallel K`` trains K runs
at once, each in its own process (each run also has its environment worker processes); their output goes to
``RUN/train.log``. Where the runs train is the executor's to say (:data:`CampaignExecutor`): this module's
:func:`run_campaign` by default; the ``apr`` command passes the cluster layer's for ``--backend ray`` (each run a
task of a Ray cluster, its environment workers Ray actors: ``apr.cluster.ray_campaign``) and ``--backend slurm``
(each run a task of a Slurm job array, through submitit: ``apr.cluster.slurm_campaign``). This module never
imports the cluster layer. Either way the table is built from the run folders, as here.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Literal

import torch

from apr.commands import checks
from apr.model.config import ModelConfig
from apr.reproduce.paper import PAPER_PRESETS
from apr.reproduce.runs import final_eval, read_config, read_run
from apr.reproduce.table import build_table1, write_readme_block, write_table1
from apr.train.checkpoints import write_text_atomically
from apr.train.config import CPU_PREFIX, PRESETS, SCALE_FREE_MODEL_FIELDS, TrainConfig, preset
from apr.train.workers import WorkersFactory

RunStatus = Literal["done", "resume", "new", "restart"]


@dataclass
class Table1Args:
    """Train the presets of the paper's Table 1 over several seeds (resumable), evaluate each final policy blind, then
    write table1.md, table1.json and figure4.png."""

    scale: Literal["paper", "cpu"] = "paper"
    """paper: the presets at paper size (GPU runs of 70K grasps). cpu: each one's ``cpu-`` preset, the same
    structure and recipe with tiny networks and a budget for a 2-core CPU (``apr presets``)."""
    seeds: int = 0
    """Seeds per preset: 0, 1, ..., SEEDS-1; 0 = the scale's: 2 at paper scale (the paper's Figure 4 used 2); at
    CPU scale 5 for active-target, passive-target and active-learned-4d, 3 for the others."""
    grasps: int | None = None
    """Grasps per run; default: each preset's own budget (70K; 25K for active-learned-4d; 600 at CPU scale)."""
    presets: tuple[str, ...] = PAPER_PRESETS
    """Presets to run, by their paper names (apr presets lists them); with --scale cpu each runs as cpu-PRESET."""
    out: Path = Path("runs/table1")
    """Parent folder of the runs (PRESET__sSEED) and of table1.md."""
    parallel: int = 1
    """Runs trained at once on this machine, each in its own process (1: in this process, with a progress bar)."""
    workers: int = 0
    """Environment processes per run; 0 = the CPU cores shared among the parallel runs (required with ray and
    slurm: the CPUs each run reserves besides its learner's)."""
    backend: Literal["local", "ray", "slurm"] = "local"
    """Where the runs train: on this machine; as Ray tasks of a cluster, one GPU and WORKERS actors each; or as a
    Slurm job array through submitit, one node's GPU and WORKERS+1 CPUs per run (pip install -e ".[cluster]")."""
    ray_address: str = ""
    """The Ray cluster (--backend ray): auto or HOST:6379; empty = RAY_ADDRESS, one started
    on this machine, or a new one here."""
    gpus_per_run: float = 1.0
    """GPUs each run reserves for its learner (ray, slurm; a whole number with slurm)."""
    max_jobs: int = 0
    """Runs training at once on the cluster (ray, slurm); 0 = as many as it has room for."""
    slurm_partition: str = ""
    """The Slurm partition; empty = the cluster's default."""
    slurm_timeout_min: int = 24 * 60
    """Time limit of each Slurm task, minutes; a task cut off is requeued and resumes from its checkpoint."""
    eval_episodes: int | None = None
    """Episodes per evaluation; default: the preset's (100, the paper's protocol)."""
    random_grasps: int | None = None
    """Warm-up episodes with random actions; default: the preset's (200)."""
    replay_capacity: int | None = None
    """Grasp transitions kept in replay; default: the preset's (50,000: about 2.5 GB with the target mask)."""
    tiny_model: bool = False
    """Use the tiny model sizes of the smoke preset (a CPU check of the whole campaign, not the paper)."""
    blind: bool = True
    """Evaluate each finished run's final policy given another scene's images in every phase (``apr eval --blind
    both``), on as many held-out episodes as its final evaluation, into ``RUN/eval/blind_both_GRASPS.json``."""
    table_only: bool = False
    """Train and evaluate nothing: write table1.md, table1.json and figure4.png from the runs already under OUT."""
    readme: Path | None = None
    """Also write the table's compact block into this file, between its ``<!-- table1-cpu -->`` markers (the
    project's README.md)."""

    def preset_names(self) -> list[str]:
        """The presets the runs start from: the paper names, or their CPU scale."""
        return [CPU_PREFIX + name if self.scale == "cpu" else name for name in self.presets]

    def seed_lists(self) -> dict[str, list[int]]:
        """Each preset's seeds (:meth:`preset_names`)."""
        return {
            name: list(range(self.seeds or (CPU_TABLE1_SEEDS.get(paper, 3) if self.scale == "cpu" else 2)))
            for paper, name in zip(self.presets, self.preset_names(), strict=True)
        }


CPU_TABLE1_SEEDS = {"active-target": 5, "passive-target": 5, "active-learned-4d": 5}
"""Seeds per row at CPU scale where more than 3: the rows of the orderings the campaign must resolve first
(active against passive; the learned 4-DoF fixation)."""


@dataclass
class PlannedRun:
    """One run of the campaign and what to do with it."""

    preset: str
    seed: int
    run_dir: Path
    config: TrainConfig
    """The configuration a new run starts with (a resumed run keeps its saved one, with this budget)."""
    status: RunStatus
    blind: bool = False
    """Once trained, also evaluate the final policy blind (:func:`evaluate_blind`)."""


def run_name(preset_name: str, seed: int) -> str:
    """The deterministic folder name of a campaign run."""
    return f"{preset_name}__s{seed}"


def campaign_config(
    preset_name: str, seed: int, out: Path, overrides: dict[str, Any] | None = None, tiny_model: bool = False
) -> TrainConfig:
    """The configuration of one campaign run: the preset, the seed, the run folder and any overrides."""
    config = preset(preset_name)
    if tiny_model:  # keep the preset's ablation switch and recipe
        config.model = ModelConfig.tiny(**{name: getattr(config.model, name) for name in SCALE_FREE_MODEL_FIELDS})
    return dataclasses.replace(
        config, seed=seed, runs_dir=out, run_name=run_name(preset_name, seed), **(overrides or {})
    )


def run_status(run_dir: Path, total_grasps: int) -> RunStatus:
    """done: it has an evaluation at or beyond ``total_grasps``, or the final one of a run of that budget that ran
    out of training time; resume: it has a checkpoint; new: no run folder; restart: a run folder without a
    checkpoint. A finished run asked for more grasps than it had resumes."""
    from apr.train.trainer import latest_checkpoint

    if not (run_dir / "config.json").exists():
        return "new"
    result = final_eval(run_dir)
    if result is not None:
        same_budget = int(read_config(run_dir).get("total_grasps", 0)) >= total_grasps
        if int(result["grasps"]) >= total_grasps or (result.get("final") and same_budget):
            return "done"
    return "resume" if latest_checkpoint(run_dir) is not None else "restart"


def plan_runs(
    presets: Sequence[str],
    seeds: Sequence[int] | Mapping[str, Sequence[int]],
    out: Path,
    overrides: dict[str, Any] | None = None,
    tiny_model: bool = False,
) -> list[PlannedRun]:
    """Every (preset, seed) with its run folder, configuration and status, seed by seed (every preset's seed 0
    first, so that a campaign cut short has every row), ``seeds`` for every preset or by preset."""
    unknown = [name for name in presets if name not in PRESETS]
    if unknown:
        raise SystemExit(f"unknown preset(s) {', '.join(unknown)}; the presets are: {', '.join(PRESETS)}")
    seed_lists = seeds if isinstance(seeds, Mapping) else {name: list(seeds) for name in presets}
    plans = []
    for seed in sorted({seed for name in presets for seed in seed_lists[name]}):
        for name in (name for name in presets if seed in seed_lists[name]):
            config = campaign_config(name, seed, out, overrides, tiny_model)
            run_dir = out / config.run_name
            plans.append(PlannedRun(name, seed, run_dir, config, run_status(run_dir, config.total_grasps)))
    return plans


CampaignExecutor = Callable[[Sequence[PlannedRun]], list[tuple[PlannedRun, int]]]
"""Trains the runs of a campaign that are not done and returns (run, exit code) for each one it trained: where
the runs train (this machine, a Ray cluster, a Slurm job array). The caller chooses it (:func:`run`)."""


def train_planned(plan: PlannedRun, torch_threads: int = 0, workers: WorkersFactory | None = None) -> Path:
    """Train one planned run to its budget (start, resume or restart it), then, with ``plan.blind``, evaluate it
    blind; return its folder. ``workers`` opens its environment workers (default: local processes) and must serve
    ``plan.config.backend``; a resumed run trains where the plan says (``backend`` and ``ray_address`` may change
    on resume)."""
    from apr.train.trainer import Trainer

    if torch_threads > 0:
        torch.set_num_threads(torch_threads)
    if plan.status == "resume":
        saved = Trainer.saved_config(plan.run_dir)
        config = dataclasses.replace(saved, total_grasps=plan.config.total_grasps, backend=plan.config.backend,
                                     ray_address=plan.config.ray_address)  # fmt: skip
        Trainer.resume(plan.run_dir, config, workers=workers).train()
    else:
        if plan.status == "restart":  # no checkpoint: what it logged cannot be continued
            print(f"{plan.run_dir}: no checkpoint, starting it over")
            (plan.run_dir / "metrics.csv").unlink(missing_ok=True)
            for stale in [*(plan.run_dir / "eval").glob("eval_*.json"), *blind_eval_paths(plan.run_dir)]:
                stale.unlink()
        plan.run_dir.mkdir(parents=True, exist_ok=True)
        Trainer(plan.config, run_dir=plan.run_dir, workers=workers).train()
    if plan.blind:
        evaluate_blind(plan.run_dir, workers=workers)
    return plan.run_dir


BLIND_MODE = "both"
"""The campaign's blind baseline: another scene's images in every phase (for an environment target, the only
phase), so that what remains is what a policy does without seeing its scene."""


def blind_eval_path(run_dir: Path, grasps: int) -> Path:
    """Where :func:`evaluate_blind` writes the blind evaluation of the policy at ``grasps``."""
    return run_dir / "eval" / f"blind_{BLIND_MODE}_{grasps:08d}.json"


def blind_eval_paths(run_dir: Path) -> list[Path]:
    """Every blind evaluation a run folder holds."""
    return sorted((run_dir / "eval").glob("blind_*.json"))


def evaluate_blind(run_dir: Path, workers: WorkersFactory | None = None) -> Path | None:
    """Evaluate the run's final policy given another scene's images (:data:`BLIND_MODE`) on as many held-out
    episodes as its final evaluation (the same evaluation seeds), and write :func:`blind_eval_path` (with ``eval_s``,
    its wall-clock seconds); skipped (None) when it is there already, or when the newest checkpoint is not the final
    evaluation's policy."""
    from apr.reproduce.policies import load_run
    from apr.train.evaluation import evaluate

    result = final_eval(run_dir)
    if result is None or blind_eval_path(run_dir, int(result["grasps"])).exists():
        return None
    snapshot = load_run(run_dir)
    if snapshot.grasps != int(result["grasps"]):
        print(f"{run_dir}: its newest checkpoint is at {snapshot.grasps} grasps, its final evaluation at "
              f"{result['grasps']}: no blind evaluation")  # fmt: skip
        return None
    config = snapshot.config
    print(f"{run_dir}: its final policy on {result['episodes']} held-out episodes, another scene's images in every "
          "phase ...", flush=True)  # fmt: skip
    start = time.monotonic()
    blind = evaluate(snapshot.agent, config.env, int(result["episodes"]), "test",
                     config.eval_workers or config.workers, workers, trained_renderer=snapshot.renderer,
                     on_mismatch="warn", blind=BLIND_MODE).to_dict()  # fmt: skip
    return write_blind_eval(run_dir, blind, result, snapshot.grasps, time.monotonic() - start)


def write_blind_eval(run_dir: Path, blind: dict, own: dict, grasps: int, seconds: float) -> Path:
    """Write a blind evaluation (an ``EvalResult`` dict) of the policy at ``grasps`` to :func:`blind_eval_path`, with
    its mode and wall-clock seconds, and say it beside ``own`` (the same policy's evaluation with its own images)."""
    blind.update(grasps=grasps, blind=BLIND_MODE, eval_s=round(seconds, 2))
    path = blind_eval_path(run_dir, grasps)
    write_text_atomically(path, json.dumps(blind, indent=2))
    print(f"{run_dir}: blind {blind['success_rate']:.1%} ({blind['successes']}/{blind['episodes']}), with its own "
          f"images {own['success_rate']:.1%}")  # fmt: skip
    return path


def _train_logged(plan: PlannedRun, torch_threads: int, workers: WorkersFactory | None = None) -> None:
    """The body of a campaign process: train one run, its stdout and stderr into RUN/train.log."""
    plan.run_dir.mkdir(parents=True, exist_ok=True)
    log = os.open(plan.run_dir / "train.log", os.O_WRONLY | os.O_CREAT | os.O_APPEND)
    os.dup2(log, 1)
    os.dup2(log, 2)
    train_planned(plan, torch_threads, workers)


def train_replanned_logged(plan: PlannedRun, workers: WorkersFactory | None = None) -> None:
    """The body of a cluster job: plan the run again from its folder (a retried or requeued job resumes what an
    earlier attempt checkpointed; a finished one is left alone), then train it into RUN/train.log, its
    environment workers opened by ``workers`` (default: local processes)."""
    plan = dataclasses.replace(plan, status=run_status(plan.run_dir, plan.config.total_grasps))
    if plan.status != "done":
        _train_logged(plan, torch_threads=0, workers=workers)


def run_campaign(plans: Sequence[PlannedRun], parallel: int = 1) -> list[tuple[PlannedRun, int]]:
    """Train the runs that are not done, ``parallel`` at a time; return (run, exit code) for each one trained."""
    todo = [plan for plan in plans if plan.status != "done"]
    for plan in plans:
        if plan.status == "done":
            print(f"{plan.run_dir}: done, skipped")
    if parallel <= 1:
        finished = []
        for plan in todo:
            print(f"{plan.run_dir}: {plan.status}")
            train_planned(plan)
            finished.append((plan, 0))
        return finished

    context = multiprocessing.get_context("spawn")
    threads = max(1, (os.cpu_count() or 1) // parallel)
    pending, running, finished = list(todo), [], []
    while pending or running:
        while pending and len(running) < parallel:
            plan = pending.pop(0)
            process = context.Process(target=_train_logged, args=(plan, threads), name=plan.run_dir.name)
            process.start()
            print(f"{plan.run_dir}: {plan.status}, training in process {process.pid} (log: train.log)")
            running.append((plan, process))
        time.sleep(1.0)
        for plan, process in list(running):
            if not process.is_alive():
                process.join()
                running.remove((plan, process))
                finished.append((plan, process.exitcode))
                outcome = "finished" if process.exitcode == 0 else f"FAILED (exit code {process.exitcode})"
                print(f"{plan.run_dir}: {outcome}")
    return finished


def overrides_from_args(args: Table1Args) -> dict[str, Any]:
    """The TrainConfig fields the command line changes for every run."""
    overrides: dict[str, Any] = {}
    if args.grasps is not None:
        overrides["total_grasps"] = args.grasps
    if args.eval_episodes is not None:
        overrides["eval_episodes"] = args.eval_episodes
    if args.random_grasps is not None:
        overrides["random_grasps"] = args.random_grasps
    if args.replay_capacity is not None:
        overrides["replay_capacity"] = args.replay_capacity
    if args.workers > 0 or args.parallel > 1:
        overrides["workers"] = args.workers or max(1, (os.cpu_count() or 1) // args.parallel)
    return overrides


def command_line(args: Table1Args) -> str:
    """The ``apr reproduce table1`` command line that gives ``args``."""
    parts = ["apr reproduce table1"] + ([f"--scale {args.scale}"] if args.scale != "paper" else [])
    parts += [f"--seeds {args.seeds}"] if args.seeds else []
    if args.grasps is not None:
        parts.append(f"--grasps {args.grasps}")
    if tuple(args.presets) != PAPER_PRESETS:
        parts.append("--presets " + " ".join(args.presets))
    parts.append(f"--out {args.out}")
    defaults = Table1Args()
    for name in ("parallel", "workers", "eval_episodes", "random_grasps", "replay_capacity", "backend",
                 "ray_address", "gpus_per_run", "max_jobs", "slurm_partition", "slurm_timeout_min"):  # fmt: skip
        if getattr(args, name) != getattr(defaults, name):
            parts.append(f"--{name.replace('_', '-')} {getattr(args, name)}")
    if args.tiny_model:
        parts.append("--tiny-model")
    if not args.blind:
        parts.append("--no-blind")
    return " ".join(parts)


def problems(args: Table1Args) -> list[str | None]:
    """What makes ``args`` unrunnable, each naming its flag (None entries: fine); the cluster options are the
    caller's to check (``apr.commands.backends.cluster_problems``)."""
    return [
        checks.at_least("--seeds", args.seeds, 0), checks.at_least("--parallel", args.parallel, 1),
        "--tiny-model: the presets of --scale cpu are tiny already" if args.tiny_model and args.scale == "cpu"
        else None,
        checks.at_least("--workers", args.workers, 0),
        *(checks.at_least(f"--{name.replace('_', '-')}", getattr(args, name), 1)
          for name in ("grasps", "eval_episodes", "replay_capacity") if getattr(args, name) is not None),
        checks.at_least("--random-grasps", args.random_grasps, 0) if args.random_grasps is not None else None,
        checks.output_folder("--out", args.out),
        f"--readme {args.readme} is not a file" if args.readme is not None and not args.readme.is_file() else None,
    ]  # fmt: skip


def run(args: Table1Args, overrides: dict[str, Any] | None = None, executor: CampaignExecutor | None = None) -> Path:
    """Plan, train what is missing, and write ``OUT/table1.md``; return its path.

    Args:
        overrides: further TrainConfig fields for every run (tests use them to shrink the smoke preset).
        executor: trains the runs (default: :func:`run_campaign` on this machine, ``--parallel`` at a time). Any
            other ``--backend`` needs its executor from the cluster layer, which ``apr reproduce table1`` passes
            (``apr.commands.backends.campaign_executor``).
    """
    checks.refuse("apr reproduce table1", problems(args))
    if executor is None:
        if args.backend != "local" and not args.table_only:
            raise SystemExit(f"apr reproduce table1: error: --backend {args.backend} needs its campaign executor, "
                             "which apr.commands.backends.campaign_executor(args) gives")  # fmt: skip
        executor = partial(run_campaign, parallel=args.parallel)
    plans = plan_runs(args.preset_names(), args.seed_lists(), args.out,
                      {**overrides_from_args(args), **(overrides or {})}, args.tiny_model)  # fmt: skip
    plans = [dataclasses.replace(plan, blind=args.blind) for plan in plans]
    failed = []
    if not args.table_only:
        for plan in plans:  # finished before blind evaluations were asked for
            if plan.blind and plan.status == "done":
                evaluate_blind(plan.run_dir)
        failed = [plan for plan, code in executor(plans) if code != 0]
    present = [plan.run_dir for plan in plans if (plan.run_dir / "config.json").exists()]
    finished = sum(read_run(run_dir).finished for run_dir in present)
    source = (
        f"Built from the final evaluations of the runs under `{args.out}` ({finished} of {len(plans)} planned runs "
        f"finished; a run still training is left out) by `{command_line(args)}`."
    )
    path = write_table1(present, args.out / "table1.md", args.preset_names(), source)
    print(f"wrote {path}")
    if args.readme is not None:
        write_readme_block(args.readme, build_table1(present, args.preset_names()))
        print(f"wrote the table's block in {args.readme}")
    if failed:
        raise SystemExit(f"{len(failed)} run(s) failed: " + ", ".join(str(plan.run_dir) for plan in failed))
    return path
