"""``apr bench backends``: the cost of running the environment workers as Ray actors, on one machine.

First the environments alone: ``--env-episodes`` episodes of uniformly random actions with 1, 2, ...,
``--workers`` workers of each backend, in env steps per second (how each pool scales with its workers). Then it
trains the same configuration twice, one run after the other, with the local worker pool and with Ray actors (a
new local Ray instance, or ``--ray-address``), and prints grasps per minute, env steps per second and updates
per second of each, their ratio, and whether the two runs computed the same numbers (every ``metrics.csv``
column but the timings, and the final evaluation's episodes). The runs go to ``OUT/local`` and ``OUT/ray``;
``OUT/backends.json`` keeps the figures with the machine and the command.
"""

from __future__ import annotations

import csv
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


def run(args: BackendsBenchArgs) -> dict:
    from apr.cluster import missing
    from apr.commands import checks
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
    from apr.train.trainer import Trainer

    command = "apr bench backends " + " ".join(sys.argv[3:])
    figures: dict = {"preset": args.preset, "grasps": args.grasps, "workers": config.workers,
                     "machine": machine_description(), "command": command}  # fmt: skip
    if args.env_episodes:
        figures["env_steps_per_s"] = scaling = {}
        print(f"--- environments alone: {args.env_episodes} episodes of random actions each")
        for backend in ("local", "ray"):
            scaling[backend] = {n: _env_steps_per_s(config, backend, n, args.env_episodes)
                                for n in range(1, config.workers + 1)}  # fmt: skip
        print("| workers | local env steps/s | Ray env steps/s | Ray / local |\n| --- | --- | --- | --- |")
        for n in range(1, config.workers + 1):
            local, ray = scaling["local"][n], scaling["ray"][n]
            print(f"| {n} | {local:.2f} | {ray:.2f} | {ray / local:.3f} |")
    rows = {}
    for backend in ("local", "ray"):
        shutil.rmtree(args.out / backend, ignore_errors=True)
        print(f"--- {backend}: {args.grasps} grasps, {config.workers} workers")
        run_dir = Trainer(dataclasses.replace(config, backend=backend, run_name=backend)).train()
        rows[backend] = _read_metrics(run_dir)
        last = rows[backend][-1]
        train_s = float(last["train_s"])
        figures[backend] = {
            "train_s": round(train_s, 1),
            "grasps_per_min": round(60 * int(last["grasps"]) / train_s, 2),
            "env_steps_per_s": round(int(last["env_steps"]) / train_s, 2),
            "updates_per_s": round(int(last["updates"]) / train_s, 3),
        }
    figures["ray_over_local_grasps_per_min"] = round(
        figures["ray"]["grasps_per_min"] / figures["local"]["grasps_per_min"], 3
    )
    same_metrics = [_computed(r) for r in rows["local"]] == [_computed(r) for r in rows["ray"]]
    same_eval = _final_outcomes(args.out / "local") == _final_outcomes(args.out / "ray")
    figures["same_numbers"] = same_metrics and same_eval
    (args.out / "backends.json").write_text(json.dumps(figures, indent=2))
    print(f"\nmachine: {figures['machine']}")
    print("| backend | training s | grasps/min | env steps/s | updates/s |\n| --- | --- | --- | --- | --- |")
    for backend in ("local", "ray"):
        f = figures[backend]
        print(f"| {backend} | {f['train_s']} | {f['grasps_per_min']} | {f['env_steps_per_s']} | {f['updates_per_s']} |")
    print(f"Ray / local, grasps per minute: {figures['ray_over_local_grasps_per_min']:.3f}")
    print(f"same metrics and final evaluation: {'yes' if figures['same_numbers'] else 'NO'}")
    return figures


def _read_metrics(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "metrics.csv", newline="") as file:
        return list(csv.DictReader(file))


def _computed(row: dict[str, str]) -> dict[str, str]:
    from apr.train.trainer import TIMING_COLUMNS

    return {k: v for k, v in row.items() if k not in TIMING_COLUMNS}


def _final_outcomes(run_dir: Path) -> list[dict]:
    newest = sorted((run_dir / "eval").glob("eval_*.json"))[-1]
    return json.loads(newest.read_text())["outcomes"]


def _env_steps_per_s(config, backend: str, workers: int, episodes: int) -> float:
    """Env steps per second of ``episodes`` episodes of uniformly random actions on ``workers`` workers (the
    pool's start not counted)."""
    import time

    import numpy as np

    from apr.train.rollout import episode_seed, random_policy, run_round
    from apr.train.workers import open_workers

    env = config.env
    policy = random_policy(env.dof, np.random.default_rng(0))
    with open_workers(workers, env.env_id, env.make_kwargs("train"), backend, config.ray_address) as pool:
        steps, started = 0, time.perf_counter()
        for first in range(0, episodes, workers):
            seeds = [episode_seed(0, k) for k in range(first, min(first + workers, episodes))]
            results = run_round(pool, seeds, policy, env.dof, env.learned_fixation)
            steps += sum(result.grasp_steps + env.learned_fixation for result in results)
        return steps / (time.perf_counter() - started)
