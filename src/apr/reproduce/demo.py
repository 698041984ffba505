"""``apr demo``: the first thing to run. A policy grasps held-out objects; a short report says how it went.

The policy is, in this order: ``--checkpoint PATH`` (a run folder, a training checkpoint, a packaged
checkpoint, or the name of one in ``src/apr/reproduce/checkpoints/``), else the first packaged checkpoint there
(by name) whose policy follows the observation rule, else the first packaged one, else an UNTRAINED agent of the
smoke preset. Out of the box the demo runs the packaged policy that sees only what the robot can know and says
how it was trained and what it measured; the privileged ``cpu-4d`` checkpoint stays available by its name;
without any the demo runs the untrained agent and says so, on the console and in the report.

The report (``OUT/report.md``) gives the success rate over the episodes with its 95% interval, each episode's
outcome, the GIF and the figures of :mod:`apr.reproduce.figures`.
"""

from __future__ import annotations

import json
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from apr.commands import checks
from apr.reproduce.figures import FigureSet, evaluation_episodes, make_figures, ordered_pictures
from apr.reproduce.policies import (
    PACKAGED_DIR,
    PolicySnapshot,
    follows_observation_rule,
    load_packaged,
    load_policy,
    packaged_by_name,
    packaged_checkpoints,
    picture_renderer,
    untrained_snapshot,
)
from apr.reproduce.table import format_percent
from apr.train.evaluation import EVAL_SEED, wilson_interval


@dataclass
class DemoArgs:
    """Run a policy on held-out objects and write a short report with its success rate, a GIF and figures."""

    out: Path = Path("demo")
    """Folder for report.md, the GIF and the figures (created if missing)."""
    episodes: int = 10
    """Evaluation episodes (held-out objects, exactly 5 in the tray, deterministic action)."""
    checkpoint: Path | None = None
    """A run folder, a training checkpoint, a packaged checkpoint or the name of one packaged with apr (e.g.
    cpu-4d__s1__584grasps); default: the first packaged one that follows the observation rule, if any."""
    gif_episodes: int = 2
    """Episodes shown in the GIF (the first ones of the evaluation)."""
    renderer: Literal["trained", "auto", "egl", "tiny"] = "trained"
    """trained: the renderer the policy was trained with (where it cannot serve, the one that can, with a
    warning: the policy never saw those images); auto, egl or tiny: that one (a warning when it is not the
    policy's)."""


@dataclass
class DemoResult:
    snapshot: PolicySnapshot
    successes: int
    episodes: int
    ci_low: float
    ci_high: float
    report: Path
    figures: FigureSet
    renderer: str = ""
    """What the episodes rendered with: "egl" or "tiny"."""
    renderer_warning: str = ""
    """Why those images are not the kind the policy was trained on ("" when they are)."""


def untrained_notice(snapshot: PolicySnapshot, packaged_dir: Path) -> str:
    """What the console and the report say when the policy is untrained (empty when it is trained)."""
    if snapshot.trained:
        return ""
    if snapshot.source.startswith("preset "):
        why = (
            f"No trained checkpoint is packaged with apr yet ({packaged_dir} holds none), so this demo runs an "
            "UNTRAINED policy: freshly initialised weights of the smoke preset's tiny model."
        )
    else:
        why = f"The policy given ({snapshot.source}) has not been trained yet (no learner update): it is UNTRAINED."
    return (
        f"{why} Its success rate says nothing about what APR learns; it shows the pipeline working. For a "
        "trained policy: train one (apr train --preset active-learned-4d), then run apr demo --checkpoint "
        "RUN_DIR, or package it with apr reproduce package RUN_DIR."
    )


def choose_policy(checkpoint: Path | None, packaged_dir: Path = PACKAGED_DIR) -> PolicySnapshot:
    """The given checkpoint (a path, or a packaged checkpoint's name), else the first packaged one that follows
    the observation rule, else the first packaged one, else an untrained agent."""
    if checkpoint is not None:
        named = None if checkpoint.exists() else packaged_by_name(str(checkpoint), packaged_dir)
        return load_policy(named or checkpoint)
    packaged = packaged_checkpoints(packaged_dir)
    if packaged:
        return load_packaged(next((path for path in packaged if follows_observation_rule(path)), packaged[0]))
    return untrained_snapshot()


def run(args: DemoArgs, packaged_dir: Path = PACKAGED_DIR) -> DemoResult:
    checks.refuse("apr demo", [
        checks.at_least("--episodes", args.episodes, 1),
        checks.at_least("--gif-episodes", args.gif_episodes, 0),
        checks.output_folder("--out", args.out),
        f"--checkpoint {args.checkpoint} is neither a path nor a checkpoint packaged in {packaged_dir}"
        if args.checkpoint and not args.checkpoint.exists() and not packaged_by_name(str(args.checkpoint), packaged_dir)
        else None,
    ])  # fmt: skip
    snapshot = choose_policy(args.checkpoint, packaged_dir)
    notice = untrained_notice(snapshot, packaged_dir)
    if notice:
        print("=" * 100 + "\n" + textwrap.fill(notice, 100) + "\n" + "=" * 100)
    print(f"policy: {snapshot.label}")
    if snapshot.training:
        print(textwrap.fill(snapshot.training, 100))
    renderer, renderer_warning = picture_renderer(snapshot, args.renderer, "apr demo")
    if renderer_warning:
        print(textwrap.fill(f"warning: {renderer_warning}", 100))
    records = evaluation_episodes(snapshot, args.episodes, renderer, keep_frames=max(args.gif_episodes, 3))
    successes = sum(record.success for record in records)
    low, high = wilson_interval(successes, len(records))
    summary = (
        f"{successes}/{len(records)} held-out episodes succeeded: {format_percent(successes / len(records))} "
        f"(95% CI {format_percent(low)}-{format_percent(high)})"
    )
    print(summary)
    figures = make_figures(snapshot, args.out, records, renderer=renderer, gif_episodes=args.gif_episodes)
    report = args.out / "report.md"
    report.write_text(_report(snapshot, notice, records, summary, figures, renderer, renderer_warning))
    (args.out / "result.json").write_text(json.dumps({
        "policy": snapshot.label, "trained": snapshot.trained, "grasps": snapshot.grasps, "source": snapshot.source,
        "split": "test", "episodes": len(records), "successes": successes, "success_rate": successes / len(records),
        "ci_low": low, "ci_high": high, "renderer": renderer, "trained_renderer": snapshot.renderer,
        "outcomes": [{"seed": r.seed, "attempted": r.attempted, "success": r.success} for r in records],
    }, indent=2))  # fmt: skip
    print(f"report: {report}")
    return DemoResult(snapshot, successes, len(records), low, high, report, figures, renderer, renderer_warning)


def _report(snapshot: PolicySnapshot, notice: str, records: list, summary: str, figures: FigureSet, renderer: str,
            renderer_warning: str) -> str:  # fmt: skip
    env = snapshot.config.env
    lines = ["# apr demo", ""]
    if notice:
        lines += [f"> **UNTRAINED POLICY.** {notice}", ""]
    if renderer_warning:
        lines += [f"> **Other images than in training.** {renderer_warning[0].upper()}{renderer_warning[1:]}.", ""]
    lines += [
        f"**Policy:** {snapshot.label}.",
        "",
        *([f"**Training:** {snapshot.training}", ""] if snapshot.training else []),
        f"**Task:** `{env.env_id}` (dof {env.dof}, target `{env.target}`, foveation `{env.foveation}`) on held-out "
        f"objects (exactly 5 in the tray), the deterministic (mean) action, seeds {EVAL_SEED} to "
        f"{EVAL_SEED + len(records) - 1} (those `apr eval` uses), rendered with `{renderer}`"
        + (f" (the policy was trained on `{snapshot.renderer}` images)." if snapshot.renderer else "."),
        "",
        f"## Result: {summary}",
        "",
        "The interval is the 95% Wilson score interval; the paper's protocol uses at least 100 episodes.",
        "",
        "| episode | seed | outcome |",
        "| --- | --- | --- |",
    ]
    lines += [f"| {k + 1} | {record.seed} | {record.outcome} |" for k, record in enumerate(records)]
    lines += ["", "## Pictures", ""]
    for name, path in ordered_pictures(figures):
        lines += [f"![{name}]({path.name})", "", figures.captions[name], ""]
    lines += [f"- {note}" for note in figures.notes]
    return "\n".join(lines) + "\n"
