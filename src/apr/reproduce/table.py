"""Table 1 of the paper from run folders: each preset's held-out success beside the paper's figure.

Every number comes from the runs' final evaluations (``eval/eval_XXXXXXXX.json``, the one with the most
grasps): the pooled success rate and its 95% Wilson interval over the episodes of all seeds, and the mean and
standard deviation of the per-seed rates (the spread Figure 4 shades).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apr.reproduce.runs import RunSummary, find_run_dirs, read_run
from apr.train.config import PRESETS
from apr.train.evaluation import wilson_interval


@dataclass(frozen=True)
class PaperResult:
    """What the paper's Table 1 (or its text) says about a preset."""

    text: str
    """As the paper puts it."""
    budget_grasps: int | None
    """The grasps behind the paper's number, where the paper says (otherwise our preset's budget is shown)."""


PAPER_TABLE1: dict[str, PaperResult] = {
    "active-target": PaperResult("84%", None),
    "passive-target": PaperResult("76%", None),
    "active-target-no-logpolar": PaperResult("79%", None),
    "active-target-no-representation": PaperResult('"negligible improvement" (no number)', None),
    "active-learned-6d": PaperResult("85% after 70K grasps", 70_000),
    "active-learned-4d": PaperResult("85% after 25K grasps", 25_000),
}
"""The paper's Table 1, and its section 4C for the ablation without representation learning."""

PAPER_PRESETS: tuple[str, ...] = tuple(PAPER_TABLE1)
"""The presets of Table 1, in the paper's order."""


@dataclass
class TableRow:
    """One preset of the table: its runs and what their final evaluations add up to."""

    preset: str
    paper: str
    runs: list[RunSummary] = field(default_factory=list)
    """Runs of this preset with a final evaluation."""
    runs_without_eval: list[RunSummary] = field(default_factory=list)

    @property
    def episodes(self) -> int:
        return sum(int(run.final_eval["episodes"]) for run in self.runs)

    @property
    def successes(self) -> int:
        return sum(int(run.final_eval["successes"]) for run in self.runs)

    @property
    def pooled_rate(self) -> float | None:
        return self.successes / self.episodes if self.episodes else None

    @property
    def pooled_interval(self) -> tuple[float, float] | None:
        """95% Wilson interval of the pooled rate (all episodes of all seeds)."""
        return wilson_interval(self.successes, self.episodes) if self.episodes else None

    @property
    def seed_rates(self) -> list[float]:
        return [float(run.final_eval["success_rate"]) for run in self.runs]

    @property
    def seed_mean(self) -> float | None:
        return float(np.mean(self.seed_rates)) if self.runs else None

    @property
    def seed_std(self) -> float | None:
        """Sample standard deviation (ddof=1) of the per-seed rates; None with fewer than 2 seeds."""
        return float(np.std(self.seed_rates, ddof=1)) if len(self.runs) >= 2 else None

    @property
    def smaller_model(self) -> bool:
        """True when a run used a smaller model than the preset's (``apr reproduce table1 --tiny-model``)."""
        if self.preset not in PRESETS:
            return False
        channels = PRESETS[self.preset][1].model.encoder_channels
        return any(run.config.get("model", {}).get("encoder_channels", channels) < channels for run in self.runs)

    @property
    def grasps(self) -> list[int]:
        """The grasps of each run's final evaluation."""
        return [int(run.final_eval["grasps"]) for run in self.runs]


def format_percent(rate: float) -> str:
    """0.625 -> "62.5%" (the table's format for rates and interval ends)."""
    return f"{100 * rate:.1f}%"


def format_grasps(count: int) -> str:
    """1234 -> "1,234"; 70000 -> "70K"."""
    return f"{count // 1000}K" if count >= 10_000 and count % 1000 == 0 else f"{count:,}"


def build_table1(run_dirs: Iterable[Path], presets: Sequence[str] | None = None) -> list[TableRow]:
    """Group the runs by preset (``config.json``) and summarise their final evaluations.

    Args:
        run_dirs: run folders, or folders holding run folders.
        presets: the rows, in order (a preset without runs gets an empty row); default: the paper's presets
            followed by any other preset found among the runs.
    """
    runs = [read_run(run_dir) for run_dir in find_run_dirs(run_dirs)]
    found = list(dict.fromkeys(run.preset for run in runs))
    order = list(presets) if presets is not None else [*PAPER_PRESETS, *(p for p in found if p not in PAPER_TABLE1)]
    rows = []
    for name in order:
        paper = PAPER_TABLE1[name].text if name in PAPER_TABLE1 else "(not in the paper)"
        row = TableRow(preset=name, paper=paper)
        for run in sorted((run for run in runs if run.preset == name), key=lambda run: run.seed):
            (row.runs if run.final_eval is not None else row.runs_without_eval).append(run)
        rows.append(row)
    return rows


def _budget_grasps(name: str) -> int:
    """The grasps of a paper-size run of this preset (the paper's, where it says; else the preset's)."""
    paper = PAPER_TABLE1.get(name)
    if paper is not None and paper.budget_grasps is not None:
        return paper.budget_grasps
    return PRESETS[name][1].total_grasps if name in PRESETS else 0


def _budget(name: str) -> str:
    budget = _budget_grasps(name)
    return format_grasps(budget) if budget else "?"


def _row_cells(row: TableRow) -> list[str]:
    if not row.runs:
        pending = f" ({len(row.runs_without_eval)} run(s) without an evaluation yet)" if row.runs_without_eval else ""
        return [row.preset, row.paper, "not run" + pending, "", "0", "", "", _budget(row.preset)]
    low, high = row.pooled_interval
    pooled = (
        f"{format_percent(row.pooled_rate)} ({row.successes}/{row.episodes}) [{format_percent(low)}, "
        f"{format_percent(high)}]"
    )
    spread = format_percent(row.seed_mean)
    spread += f" ± {100 * row.seed_std:.1f} pts" if row.seed_std is not None else " (1 seed: no spread)"
    seeds = ", ".join(f"s{run.seed}" for run in row.runs)
    grasps = sorted(set(row.grasps))
    grasps_text = format_grasps(grasps[0])
    if len(grasps) > 1:
        grasps_text += f"-{format_grasps(grasps[-1])}"
    return [
        row.preset + (" (tiny model)" if row.smaller_model else ""),
        row.paper,
        pooled,
        spread,
        f"{len(row.runs)} ({seeds})",
        grasps_text,
        str(row.episodes),
        _budget(row.preset),
    ]


def render_table1(rows: Sequence[TableRow], source: str = "") -> str:
    """Table 1 as markdown: the table, how to read it, and each run's final evaluation file."""
    header = [
        "preset",
        "paper (Table 1)",
        "ours: held-out success, pooled (successes/episodes) [95% CI]",
        "ours: per-seed mean ± std",
        "seeds",
        "grasps",
        "eval episodes",
        "full budget of the preset",
    ]
    lines = ["# Table 1: grasp success on held-out objects", ""]
    if source:
        lines += [source, ""]
    lines += ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(_row_cells(row)) + " |" for row in rows]
    lines += [
        "",
        "- *pooled*: all evaluation episodes of all seeds together, with the 95% Wilson score interval.",
        "- *per-seed mean ± std*: the mean of the seeds' success rates and their sample standard deviation "
        "(ddof=1), in percentage points.",
        "- *grasps*: the training grasps behind each run's final evaluation (the `eval/eval_XXXXXXXX.json` with "
        "the most grasps); *full budget of the preset*: the grasps of a full run (the paper's, where it says).",
    ]
    short = [
        row.preset
        for row in rows
        if row.runs and row.preset in PAPER_TABLE1 and max(row.grasps) < _budget_grasps(row.preset)
    ]
    if short:
        lines.append(
            f"- **{', '.join(short)}: fewer grasps than a paper-size run; these rows check the pipeline, "
            "they do not reproduce the paper's numbers.**"
        )
    if any(row.smaller_model for row in rows):
        lines.append(
            "- *(tiny model)*: the runs used the smoke preset's tiny network sizes (`--tiny-model`), not the paper's."
        )
    if any(row.runs and row.preset not in PAPER_TABLE1 for row in rows):
        lines.append(
            "- Presets marked *(not in the paper)*, such as `smoke` (tiny model, a few grasps), only "
            "exercise the pipeline."
        )
    lines += [
        "",
        "## Runs",
        "",
        "| preset | seed | final evaluation | grasps | successes/episodes | rate |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for row in rows:
        for run in row.runs:
            result = run.final_eval
            lines.append(
                f"| {row.preset} | {run.seed} | `{result['path']}` | {result['grasps']} | "
                f"{result['successes']}/{result['episodes']} | {format_percent(result['success_rate'])} |"
            )
        for run in row.runs_without_eval:
            lines.append(f"| {row.preset} | {run.seed} | `{run.run_dir}`: no evaluation yet | | | |")
    return "\n".join(lines) + "\n"


def write_table1(run_dirs: Iterable[Path], out: Path, presets: Sequence[str] | None = None, source: str = "") -> Path:
    """Build Table 1 from ``run_dirs`` and write it as markdown to ``out``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(render_table1(build_table1(run_dirs, presets), source))
    return out
