"""``apr bench backends``: the cost of running the environment workers as Ray actors, on one machine.

First the environments alone: ``--env-episodes`` episodes of uniformly random actions with 1, 2, ...,
``--workers`` workers of each backend, in env steps per second (how each pool scales with its workers). Then it
trains the same configuration twice, one run after the other, with the local worker pool and with Ray actors (a
new local Ray instance, or ``--ray-address``), and prints grasps per minute, env steps per second and updates
per second of each from its first metrics row on (the local pool's processes start inside a run's clock, Ray's
actors before it), their ratio, and whether the two runs computed the same numbers (every ``metrics.csv``
column but the timings, and the final evaluation's episodes). The runs go to ``OUT/local`` and ``OUT/ray``
(``--report-only`` reports the runs already there); ``OUT/backends.json`` keeps the figures with the machine
and the command.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal


@dataclass
class BackendsBenchArgs:
    """Train one configuration with the local worker pool and with Ray actors; compare speed and numbers."""

    preset: str = "cpu-4d"
    """The preset to run (``apr presets``)."""
    grasps: int = 100
    """Grasps of each run (the preset's warm-up grasps included)."""
    workers: int = 0
    """Environment workers of each run; 0 = the preset's (or this machine's cores)."""
    env_episodes: int = 16
    """Episodes of random actions per (backend, worker count) in the environment-only part; 0 skips it."""
    eval_episodes: int = 10
    """Held-out episodes of each run's final evaluation (not timed: grasps per minute count training time)."""
    renderer: Literal["", "auto", "egl", "tiny"] = ""
    """Renderer; empty = the preset's."""
    ray_address: str = ""
    """A Ray cluster to use instead of a new instance on this machine (``auto``, ``HOST:6379``)."""
    out: Path = Path("results/backends")
    """Folder of the two runs and of ``backends.json``; runs already there are replaced."""
    report_only: bool = False
    """Run nothing: report the runs already in ``OUT/local`` and ``OUT/ray`` (and the environment-only figures
    already in ``OUT/backends.json``)."""


def run(args: BackendsBenchArgs) -> dict:
    from apr.cluster import missing
    from apr.commands import checks
    from apr.commands.backends import workers_factory
    from apr.train.config import preset

    config = preset(args.preset)  # validates the name before any work
    checks.refuse("apr bench backends", [
        checks.at_least("--grasps", args.grasps, 1), checks.at_least("--workers", args.workers, 0),
        checks.at_least("--eval-episodes", args.eval_episodes, 1),
        checks.at_least("--env-episodes", args.env_episodes, 0), checks.output_folder("--out", args.out),
        missing("ray", "apr bench backends"),
    ])  # fmt: skip
    config = dataclasses.replace(
        config, total_grasps=args.grasps, max_train_minutes=0.0, workers=args.workers or config.workers or 0,
        eval_every_grasps=0, eval_episodes=args.eval_episodes, final_eval_episodes=0, checkpoint_every_grasps=0,
        log_every_grasps=max(1, args.grasps // 10), image_every_grasps=0, runs_dir=args.out,
        ray_address=args.ray_address,
    )  # fmt: skip
    if args.renderer:
        config = dataclasses.replace(config, env=dataclasses.replace(config.env, renderer=args.renderer))
    config = dataclasses.replace(config, workers=config.resolved().workers)

    from apr.machine import machine_description
    from apr.reproduce.runs import final_eval, read_metrics, without_timings
    from apr.train.trainer import Trainer

    saved = args.out / "backends.json"
    previous = json.loads(saved.read_text()) if args.report_only and saved.exists() else {}
    command = "apr bench backends " + " ".join(sys.argv[3:])
    figures: dict = {"preset": args.preset, "grasps": args.grasps, "workers": config.workers,
                     "machine": previous.get("machine", machine_description()),
                     "command": previous.get("command", command)}  # fmt: skip
    if args.report_only:
        if "env_steps_per_s" in previous:
            figures["env_steps_per_s"] = previous["env_steps_per_s"]
    elif args.env_episodes:
        print(f"--- environments alone: {args.env_episodes} episodes of random actions each")
        figures["env_steps_per_s"] = {
            backend: {str(n): round(_env_steps_per_s(config, backend, n, args.env_episodes), 2)
                      for n in range(1, config.workers + 1)}
            for backend in ("local", "ray")
        }  # fmt: skip
    rows = {}
    for backend in ("local", "ray"):
        if not args.report_only:
            shutil.rmtree(args.out / backend, ignore_errors=True)
            print(f"--- {backend}: {args.grasps} grasps, {config.workers} workers")
            workers = workers_factory(backend, config.ray_address)
            Trainer(dataclasses.replace(config, backend=backend, run_name=backend), workers=workers).train()
        rows[backend] = read_metrics(args.out / backend)
        if not rows[backend]:
            raise SystemExit(f"{args.out / backend} holds no run to report: run apr bench backends without "
                             "--report-only first")  # fmt: skip
        figures[backend] = _speed(rows[backend])
    figures["ray_over_local_grasps_per_min"] = round(
        figures["ray"]["steady_grasps_per_min"] / figures["local"]["steady_grasps_per_min"], 3
    )
    same_metrics = without_timings(rows["local"]) == without_timings(rows["ray"])
    same_eval = final_eval(args.out / "local")["outcomes"] == final_eval(args.out / "ray")["outcomes"]
    figures["same_numbers"] = same_metrics and same_eval
    saved.write_text(json.dumps(figures, indent=2))
    _print_report(figures)
    return figures


def _speed(rows: list[dict[str, str]]) -> dict:
    """A run's speed over its whole training time, and from its first metrics row on. The second is the one to
    compare: the local pool's processes start inside the run's clock, Ray's actors before it (the pool waits
    for them, to say where they run)."""
    first, last = rows[0], rows[-1]
    train_s = float(last["train_s"])
    span = train_s - float(first["train_s"])

    def rate(column: str) -> float:
        return (int(last[column]) - int(first[column])) / span

    return {
        "train_s": round(train_s, 1),
        "grasps_per_min": round(60 * int(last["grasps"]) / train_s, 2),
        "steady_from_grasps": int(first["grasps"]),
        "steady_grasps_per_min": round(60 * rate("grasps"), 2),
        "steady_env_steps_per_s": round(rate("env_steps"), 2),
        "steady_updates_per_s": round(rate("updates"), 3),
    }


def _print_report(figures: dict) -> None:
    print(f"\nmachine: {figures['machine']}")
    if "env_steps_per_s" in figures:
        scaling = figures["env_steps_per_s"]
        print(
            "environments alone:\n| workers | local env steps/s | Ray env steps/s | Ray / local |\n"
            "| --- | --- | --- | --- |"
        )
        for n, local in scaling["local"].items():
            ray = scaling["ray"][n]
            print(f"| {n} | {local:.2f} | {ray:.2f} | {ray / local:.3f} |")
    start = figures["local"]["steady_from_grasps"]
    print(f"training (the rates from grasp {start} on):\n"
          "| backend | training s | grasps/min, whole run | grasps/min | env steps/s | updates/s |\n"
          "| --- | --- | --- | --- | --- | --- |")  # fmt: skip
    for backend in ("local", "ray"):
        f = figures[backend]
        print(f"| {backend} | {f['train_s']} | {f['grasps_per_min']} | {f['steady_grasps_per_min']} | "
              f"{f['steady_env_steps_per_s']} | {f['steady_updates_per_s']} |")  # fmt: skip
    print(f"Ray / local, grasps per minute from grasp {start} on: {figures['ray_over_local_grasps_per_min']:.3f}")
    print(f"same metrics and final evaluation: {'yes' if figures['same_numbers'] else 'NO'}")


def _env_steps_per_s(config, backend: str, workers: int, episodes: int) -> float:
    """Env steps per second of ``episodes`` episodes of uniformly random actions on ``workers`` workers (the
    pool's start not counted)."""
    import time

    import numpy as np

    from apr.commands.backends import workers_factory
    from apr.train.rollout import episode_seed, random_policy, run_round

    env = config.env
    policy = random_policy(env.dof, np.random.default_rng(0))
    open_workers = workers_factory(backend, config.ray_address)
    with open_workers(workers, env.env_id, env.make_kwargs("train")) as pool:
        steps, started = 0, time.perf_counter()
        for first in range(0, episodes, workers):
            seeds = [episode_seed(0, k) for k in range(first, min(first + workers, episodes))]
            results = run_round(pool, seeds, policy, env.dof, env.learned_fixation)
            steps += sum(result.grasp_steps + env.learned_fixation for result in results)
        return steps / (time.perf_counter() - started)
