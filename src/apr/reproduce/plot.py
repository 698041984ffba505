"""``apr plot RUN_DIR... --out FILE``: held-out success against grasps, one line per preset (Figure 4).

Runs are grouped by the preset in their ``config.json``. A preset's line is the mean over its seeds of the
``eval_success`` column of ``metrics.csv``; the shaded band is the mean plus and minus one standard deviation
across seeds (Figure 4 shades one standard deviation over two seeds). Where seeds evaluated at different
grasps, each seed's curve is interpolated linearly within its own range.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from apr.commands import checks
from apr.reproduce.paper import PAPER_TABLE1, paper_row
from apr.reproduce.runs import eval_curve, find_run_dirs, read_config, run_preset


@dataclass
class PlotArgs:
    """Plot held-out success against grasps for runs, one line per preset, the spread across seeds shaded."""

    run_dirs: Annotated[tuple[Path, ...], tyro.conf.Positional]
    """Run folders, or folders holding run folders."""
    out: Path = Path("learning_curves.png")
    """The picture (its suffix picks the format: .png, .pdf, .svg)."""
    title: str = ""
    """Title; default: says what is plotted and the largest grasp count."""


@dataclass
class PresetCurve:
    """A preset's learning curve over its seeds."""

    preset: str
    grasps: np.ndarray
    mean: np.ndarray
    """Mean held-out success over the seeds evaluated at (or around) each grasp count, in [0, 1]."""
    std: np.ndarray
    """Sample standard deviation (ddof=1, as in Table 1) over those seeds; 0 where only one seed covers it."""
    seeds: list[int]


def preset_curves(run_dirs: Iterable[Path]) -> list[PresetCurve]:
    """Each preset's mean and spread of held-out success against grasps (presets in first-seen order)."""
    runs: dict[str, list[tuple[int, np.ndarray, np.ndarray]]] = {}
    for run_dir in find_run_dirs(run_dirs):
        config = read_config(run_dir)
        grasps, success = eval_curve(run_dir)
        if len(grasps):
            runs.setdefault(run_preset(config), []).append((int(config.get("seed", 0)), grasps, success))
    curves = []
    for name, seed_curves in runs.items():
        grid = np.unique(np.concatenate([grasps for _, grasps, _ in seed_curves]))
        values = np.full((len(seed_curves), len(grid)), np.nan)
        for row, (_, grasps, success) in enumerate(seed_curves):
            covered = (grid >= grasps[0]) & (grid <= grasps[-1])
            values[row, covered] = np.interp(grid[covered], grasps, success)
        counts = np.sum(~np.isnan(values), axis=0)
        mean = np.nanmean(values, axis=0)
        squares = np.nansum((values - mean) ** 2, axis=0)
        std = np.where(counts >= 2, np.sqrt(squares / np.maximum(counts - 1, 1)), 0.0)
        curves.append(PresetCurve(name, grid, mean, std, sorted(seed for seed, _, _ in seed_curves)))
    return curves


def plot_learning_curves(run_dirs: Iterable[Path], title: str = "",
                         blind: Mapping[str, tuple[float, float]] | None = None) -> Figure:  # fmt: skip
    """The figure: one line (with markers) per preset, mean +- std across seeds shaded; ``blind`` (preset ->
    grasps, mean success given another scene's images) adds a cross in the preset's colour."""
    curves = preset_curves(run_dirs)
    figure = Figure(figsize=(7.5, 4.5), layout="constrained")
    axes = figure.subplots()
    for curve in curves:
        row = paper_row(curve.preset)
        paper = f"paper: {PAPER_TABLE1[row].text}" if row else "not in the paper"
        seeds = f"{len(curve.seeds)} seed{'s' if len(curve.seeds) > 1 else ''}"
        (line,) = axes.plot(
            curve.grasps, 100 * curve.mean, marker="o", markersize=3, label=f"{curve.preset} ({seeds}; {paper})"
        )
        axes.fill_between(
            curve.grasps,
            100 * (curve.mean - curve.std),
            100 * (curve.mean + curve.std),
            color=line.get_color(),
            alpha=0.2,
            linewidth=0,
        )
        if blind and curve.preset in blind:
            grasps, rate = blind[curve.preset]
            axes.plot([grasps], [100 * rate], marker="x", markersize=8, color=line.get_color(), linestyle="none")
    most = max((int(curve.grasps[-1]) for curve in curves), default=0)
    axes.xaxis.set_major_locator(MaxNLocator(integer=True))
    axes.set_xlabel("training grasps")
    axes.set_ylabel("held-out success (%)")
    axes.set_ylim(-2, 102)
    axes.grid(alpha=0.3)
    if blind:
        axes.plot([], [], marker="x", color="gray", linestyle="none", label="x: final policy, another scene's images")
    if curves:
        axes.legend(fontsize=7, loc="best")
    else:
        axes.text(0.5, 0.5, "no evaluation in these runs yet", ha="center", transform=axes.transAxes)
    axes.set_title(title or f"Held-out grasp success (mean ± 1 std across seeds), up to {most:,} grasps", fontsize=9)
    return figure


def _run_dir_problem(path: Path) -> str | None:
    """Why ``path`` is neither a run folder nor a folder of runs (None when it is one of them)."""
    if not path.exists():
        return f"{path} does not exist"
    try:
        find_run_dirs([path])
    except FileNotFoundError as error:
        return str(error)
    return None


def run(args: PlotArgs) -> Path:
    if not args.run_dirs:
        raise SystemExit("apr plot: give at least one run folder (or a folder of runs)")
    checks.refuse("apr plot", [
        f"--out {args.out} is a folder; give a file name" if args.out.is_dir() else None,
        checks.output_folder("--out", args.out.parent),
        *(_run_dir_problem(path) for path in args.run_dirs),
    ])  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    plot_learning_curves(args.run_dirs, args.title).savefig(args.out, dpi=120)
    print(f"wrote {args.out}")
    return args.out
