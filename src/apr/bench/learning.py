"""``apr bench learning``: does a preset learn? Held-out success against grasps and minutes, beside baselines.

For each seed it trains the preset into ``OUT/runs/PRESET__sSEED`` (a finished run is reused, an interrupted
one resumed), then evaluates three baselines on the same held-out episodes (the evaluation seeds are fixed):

- untrained: the preset's agent with fresh weights (deterministic action), what training starts from;
- random: uniformly random actions;
- scripted: the scripted reach-and-grasp, which reads the target's true centre and moves the tool tip over
  it, then straight down (environment-selected targets only): the ceiling a reach-and-descend policy can
  hope for.

and, for every run's final policy, the blind baselines on the same episodes: the policy given, in place of its
own images, those of another episode (another scene) in the fixation phase only (does the choice of where to
look use vision?), in the grasp phase only (does grasping?), or in both. A policy that grasps from what it sees
loses most of its success blind. With a learned fixation each evaluation also says where the chosen points lay
(median distance to the nearest object, spread), beside one fixed point in the middle of the drop area and
uniformly random points.

It writes ``OUT/curve.csv`` (every evaluation of every run: grasps, training minutes, success and its 95%
Wilson interval), ``OUT/baselines.json``, ``OUT/curve.png`` (success against grasps and against training
minutes) and ``OUT/summary.md``, and prints grasps per minute, updates per second and where the time went.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

BASELINES = ("untrained", "random", "scripted")
BLIND_MODES = {True: ("fixation", "grasp", "both"), False: ("both",)}
"""Blind evaluations of a final policy, by whether it has a learned fixation (with an env target there is no
fixation phase: "both" is every step)."""
CURVE_COLUMNS = ("run", "seed", "grasps", "updates", "train_minutes", "episodes", "successes", "success_rate",
                 "ci_low", "ci_high", "final")  # fmt: skip


@dataclass
class LearningBenchArgs:
    """Train a preset over seeds, evaluate baselines on the same held-out episodes, write the learning curve."""

    preset: str = "cpu-4d"
    """The preset to measure (``apr presets``)."""
    seeds: tuple[int, ...] = (0, 1)
    """Seeds, one run each (run one after the other: a timing taken beside another job is not a benchmark)."""
    out: Path = Path("results/cpu-4d")
    """Results folder; the runs go to ``OUT/runs``."""
    grasps: int = 0
    """Grasp budget of each run; 0 = the preset's."""
    minutes: float | None = None
    """Training-time budget of each run in minutes (0: none); default: the preset's."""
    baseline_episodes: int = 0
    """Held-out episodes per baseline; 0 = the preset's final evaluation size."""
    workers: int = 0
    """Env processes for training and evaluation; 0 = the preset's."""
    renderer: Literal["", "auto", "egl", "tiny"] = ""
    """Renderer for training and baselines; empty = the preset's."""
    report_only: bool = False
    """Do not train: report the runs already in ``OUT/runs`` (finished or not) and the baselines."""


def run(args: LearningBenchArgs) -> None:
    from apr.train.config import preset

    config = preset(args.preset)  # validates the name before any work
    for name in ("workers", "baseline_episodes", "grasps", "minutes"):
        if (getattr(args, name) or 0) < 0:
            raise SystemExit(f"--{name.replace('_', '-')} must be at least 0, got {getattr(args, name)}")
    if not args.seeds:
        raise SystemExit("--seeds: give at least one seed")
    if args.workers:
        config = dataclasses.replace(config, workers=args.workers)
    if args.grasps:
        config = dataclasses.replace(config, total_grasps=args.grasps)
    if args.minutes is not None:
        config = dataclasses.replace(config, max_train_minutes=args.minutes)
    if args.renderer:
        config = dataclasses.replace(config, env=dataclasses.replace(config.env, renderer=args.renderer))
    args.out.mkdir(parents=True, exist_ok=True)
    runs_dir = args.out / "runs"
    run_dirs = [runs_dir / f"{args.preset}__s{seed}" for seed in args.seeds]
    if not args.report_only:
        for seed, run_dir in zip(args.seeds, run_dirs, strict=True):
            _train(dataclasses.replace(config, seed=seed, runs_dir=runs_dir, run_name=run_dir.name), run_dir)
    episodes = args.baseline_episodes or config.final_eval_episodes or config.eval_episodes
    baselines = _baselines(config.resolved(), episodes, args.out / "baselines.json")
    blind = {}
    for run_dir in run_dirs:
        if _final_eval(run_dir) is None:
            continue
        if not any((run_dir / "checkpoints").glob("checkpoint_*.pt")):
            print(f"{run_dir.name}: no checkpoint kept, so no blind baselines")
            continue
        blind[run_dir.name] = _blind(run_dir, episodes, config.eval_workers or config.workers,
                                     args.out / "baselines.json")  # fmt: skip
    curve = [row for run_dir in run_dirs if run_dir.exists() for row in _curve_rows(run_dir)]
    _write_csv(args.out / "curve.csv", curve)
    timings = [_timing(run_dir) for run_dir in run_dirs if (run_dir / "metrics.csv").exists()]
    _plot(args.out / "curve.png", args.preset, curve, baselines, blind)
    summary = _summary(args, curve, baselines, blind, timings)
    (args.out / "summary.md").write_text(summary)
    print(summary)


# ---------------------------------------------------------------------------------------------------- training
def _train(config, run_dir: Path) -> None:
    """Train ``config`` into ``run_dir``: reuse it when finished, resume it when interrupted."""
    from apr.train.trainer import Trainer

    if _final_eval(run_dir) is not None:
        print(f"{run_dir}: finished, reused")
    elif (run_dir / "config.json").exists():
        Trainer.resume(run_dir).train()  # from its newest intact checkpoint, or from the start if it has none
    else:
        Trainer(config).train()


def _final_eval(run_dir: Path) -> dict | None:
    """The evaluation the run wrote when it ended (grasp or time budget spent), or None."""
    from apr.reproduce.runs import eval_results

    return next((result for result in reversed(eval_results(run_dir)) if result.get("final")), None)


# --------------------------------------------------------------------------------------------------- baselines
def _baselines(config, episodes: int, path: Path) -> dict[str, dict]:
    """Each baseline's evaluation on ``episodes`` held-out episodes, cached in ``path`` per environment."""
    from apr.envs.scripted import scripted_grasp_actions
    from apr.reproduce.policies import new_agent
    from apr.train.evaluation import evaluate, evaluate_policy
    from apr.train.rollout import random_policy

    env = config.env
    key = json.dumps({"env": dataclasses.asdict(env), "episodes": episodes, "preset": config.preset}, sort_keys=True)
    cached = _read_json(path)
    if cached.get("key") == key:
        return cached["results"]
    dof = env.dof
    uniform = random_policy(dof, np.random.default_rng(0))

    def scripted_policy(observations, phase):  # reads the simulator's answer: its env reveals the target
        return scripted_grasp_actions(observations["fixation"], observations["gripper"][:, :3], dof)

    workers = config.eval_workers
    policies = {"untrained": lambda: evaluate(new_agent(config), env, episodes, "test", workers),
                "random": lambda: evaluate_policy(uniform, env, episodes, "test", workers)}  # fmt: skip
    if not env.learned_fixation:
        revealed = dataclasses.replace(env, reveal_target=True)
        policies["scripted"] = lambda: evaluate_policy(scripted_policy, revealed, episodes, "test", workers)
    results = {}
    for name, run_baseline in policies.items():
        print(f"baseline {name}: {episodes} held-out episodes ...", flush=True)
        results[name] = run_baseline().to_dict()
        results[name].pop("outcomes")
        print(f"baseline {name}: {results[name]['success_rate']:.1%} ({results[name]['successes']}/{episodes})")
    _update_json(path, key=key, results=results, blind={})  # new baselines: the blind results are redone too
    return results


def _read_json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.exists() else {}


def _update_json(path: Path, **sections: object) -> None:
    """Replace some top-level sections of the JSON file ``path`` (written atomically), keeping the others."""
    from apr.train.checkpoints import write_text_atomically

    write_text_atomically(path, json.dumps({**_read_json(path), **sections}, indent=2))


def _blind(run_dir: Path, episodes: int, workers: int, path: Path) -> dict[str, dict]:
    """The run's newest policy evaluated blind in each of its modes (:data:`BLIND_MODES`) on ``episodes``
    held-out episodes, and its own-image evaluation beside them ("own"); cached in the "blind" section of ``path``
    (``baselines.json``) per run and grasps."""
    from apr.reproduce.policies import load_run
    from apr.train.evaluation import evaluate
    from apr.train.rollout import blind_phases_text

    cache = _read_json(path).get("blind", {})
    snapshot = load_run(run_dir)
    key = f"{snapshot.grasps}:{episodes}"
    if cache.get(run_dir.name, {}).get("key") == key:
        return cache[run_dir.name]["results"]
    env = snapshot.config.env
    results = {}
    for mode in ("", *BLIND_MODES[env.learned_fixation]):
        name = mode or "own"
        whose = "another scene's" if mode else "its own"
        print(f"{run_dir.name} at {snapshot.grasps} grasps, {whose} images in {blind_phases_text(mode)}: "
              f"{episodes} held-out episodes ...", flush=True)  # fmt: skip
        result = evaluate(snapshot.agent, env, episodes, "test", workers, trained_renderer=snapshot.renderer,
                          blind=mode).to_dict()  # fmt: skip
        result.pop("outcomes")
        results[name] = result
        print(f"{run_dir.name}, {name}: {result['success_rate']:.1%} ({result['successes']}/{result['episodes']})")
    results["own"]["grasps"] = snapshot.grasps
    cache[run_dir.name] = {"key": key, "results": results}
    _update_json(path, blind=cache)
    return results


# ------------------------------------------------------------------------------------------------------ curves
def _curve_rows(run_dir: Path) -> list[dict]:
    from apr.reproduce.runs import eval_results, read_config

    config = read_config(run_dir)
    rows = []
    for result in eval_results(run_dir):
        rows.append({
            "run": run_dir.name, "seed": config["seed"], "grasps": result["grasps"],
            "updates": result.get("updates", ""),
            "train_minutes": round(result["train_s"] / 60, 2) if "train_s" in result else "",
            "episodes": result["episodes"], "successes": result["successes"], "success_rate": result["success_rate"],
            "ci_low": result["ci_low"], "ci_high": result["ci_high"], "final": bool(result.get("final")),
        })  # fmt: skip
    return rows


def _write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=CURVE_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def _timing(run_dir: Path) -> dict:
    """Throughput and the split of a run's training time, from the last row of its ``metrics.csv``."""
    from apr.reproduce.runs import read_metrics

    last = read_metrics(run_dir)[-1]
    train_s = float(last["train_s"])
    learner_s, act_s = float(last["learner_s"]), float(last["act_s"])
    return {
        "run": run_dir.name, "grasps": int(last["grasps"]), "env_steps": int(last["env_steps"]),
        "updates": int(last["updates"]), "train_minutes": train_s / 60, "eval_minutes": float(last["eval_s"]) / 60,
        "grasps_per_min": 60 * int(last["grasps"]) / train_s, "updates_per_s": int(last["updates"]) / train_s,
        "learner_share": learner_s / train_s, "act_share": act_s / train_s,
        "env_share": max(train_s - learner_s - act_s, 0.0) / train_s,
    }  # fmt: skip


BLIND_MARKERS = {"fixation": "^", "grasp": "v", "both": "x"}


def _plot(path: Path, preset: str, curve: list[dict], baselines: dict[str, dict], blind: dict[str, dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    colours = {"untrained": "tab:gray", "random": "tab:brown", "scripted": "tab:green"}
    panels = ((axes[0], "grasps", "training grasps"),
              (axes[1], "train_minutes", "training minutes (evaluations not counted)"))  # fmt: skip
    for axis, x_name, x_label in panels:
        for run in sorted({row["run"] for row in curve}):
            rows = [row for row in curve if row["run"] == run and row[x_name] != ""]
            if not rows:
                continue
            x = np.array([float(row[x_name]) for row in rows])
            y = np.array([row["success_rate"] for row in rows])
            low, high = np.array([row["ci_low"] for row in rows]), np.array([row["ci_high"] for row in rows])
            line = axis.plot(x, y, marker="o", label=f"{run} (held-out)")[0]
            axis.fill_between(x, low, high, color=line.get_color(), alpha=0.15)
            for mode, result in blind.get(run, {}).items():
                if mode in BLIND_MARKERS:  # at the end of the run, where its final policy was evaluated blind
                    axis.plot(x[-1], result["success_rate"], BLIND_MARKERS[mode], color=line.get_color(),
                              markersize=9, label=f"{run}, another scene's images ({mode})")  # fmt: skip
        for name, result in baselines.items():
            axis.axhline(result["success_rate"], color=colours[name], linestyle="--",
                         label=f"{name}: {result['success_rate']:.0%} ({result['episodes']} ep.)")  # fmt: skip
        axis.set_xlabel(x_label)
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("held-out success (95% Wilson interval shaded)")
    axes[0].set_ylim(-0.02, 1.02)
    axes[1].legend(fontsize=7, loc="upper left")
    figure.suptitle(f"apr bench learning: {preset}, 5 held-out objects per episode, deterministic action")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def _summary(args: LearningBenchArgs, curve: list[dict], baselines: dict[str, dict], blind: dict[str, dict],
             timings: list[dict]) -> str:  # fmt: skip
    from apr.machine import machine_description

    lines = [f"# apr bench learning: {args.preset}", "",
             f"Machine: {machine_description()}. Command: `apr bench learning --preset {args.preset} --seeds "
             f"{' '.join(map(str, args.seeds))} --out {args.out}{' --report-only' if args.report_only else ''}`", "",
             "## Held-out success at the end of each run", "",
             "| run | grasps | training minutes | success | 95% CI | episodes |", "|" + " --- |" * 6]  # fmt: skip
    finals = [row for row in curve if row["final"]]
    for row in finals:
        lines.append(f"| {row['run']} | {row['grasps']} | {row['train_minutes']} | {row['success_rate']:.1%} | "
                     f"{row['ci_low']:.1%}-{row['ci_high']:.1%} | {row['episodes']} |")  # fmt: skip
    if not finals:
        lines.append("| (no run has finished) | | | | | |")
    lines += ["", "## Baselines on the same held-out episodes", "",
              "| policy | success | 95% CI | attempts | episodes |", "|" + " --- |" * 5]  # fmt: skip
    for name, result in baselines.items():
        lines.append(f"| {name} | {result['success_rate']:.1%} | {result['ci_low']:.1%}-{result['ci_high']:.1%} | "
                     f"{result['attempts']} | {result['episodes']} |")  # fmt: skip
    lines += _blind_lines(blind)
    lines += ["", "## Throughput and where the training time went", "",
              "| run | grasps | updates | training min | eval min | grasps/min | updates/s | env and waiting | "
              "learner | acting |", "|" + " --- |" * 10]  # fmt: skip
    for t in timings:
        lines.append(f"| {t['run']} | {t['grasps']} | {t['updates']} | {t['train_minutes']:.1f} | "
                     f"{t['eval_minutes']:.1f} | {t['grasps_per_min']:.1f} | {t['updates_per_s']:.2f} | "
                     f"{t['env_share']:.0%} | {t['learner_share']:.0%} | {t['act_share']:.0%} |")  # fmt: skip
    lines += [
        "",
        "The learner updates while the workers simulate, so its share overlaps the env's: *env and "
        "waiting* is the rest of the training time (the main process waiting for the workers).",
        "",
    ]
    return "\n".join(lines)


def _blind_lines(blind: dict[str, dict]) -> list[str]:
    """The summary's section on the blind baselines and, with a learned fixation, where the policies looked."""
    if not blind:
        return []
    rate = lambda result: f"{result['success_rate']:.1%}" if result else "-"  # noqa: E731
    lines = ["", "## Blind baselines: each final policy given another scene's images, same episodes", "",
             "| run | grasps | own images | other scene's in the fixation phase | in the grasp phase | in both | "
             "episodes |", "|" + " --- |" * 7]  # fmt: skip
    for run, results in blind.items():
        own = results["own"]
        lines.append(f"| {run} | {own.get('grasps', '')} | {rate(own)} | {rate(results.get('fixation'))} | "
                     f"{rate(results.get('grasp'))} | {rate(results.get('both'))} | {own['episodes']} |")  # fmt: skip
    looked = {run: results["own"]["fixation"] for run, results in blind.items() if results["own"].get("fixation")}
    if looked:
        lines += ["", "## Where the fixation policies looked (held-out scenes, own images)", "",
                  "| run | median distance to the nearest object | spread x, y | one fixed point (bin centre) | "
                  "uniformly random points |", "|" + " --- |" * 5]  # fmt: skip
        for run, stats in looked.items():
            lines.append(f"| {run} | {stats['median_cm']:.1f} cm | {stats['spread_x_cm']:.1f}, "
                         f"{stats['spread_y_cm']:.1f} cm | {stats['fixed_median_cm']:.1f} cm | "
                         f"{stats['uniform_median_cm']:.1f} cm |")  # fmt: skip
    return lines
