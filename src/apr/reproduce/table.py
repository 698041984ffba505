"""Table 1 of the paper from run folders: each preset's held-out success beside the paper's figure.

Every number comes from the runs' final evaluations (``eval/eval_XXXXXXXX.json``, the one with the most
grasps): the pooled success rate and its 95% Wilson interval over the episodes of all seeds, and the mean and
standard deviation of the per-seed rates (the spread Figure 4 shades); the blind success of each final policy
(``eval/blind_MODE_XXXXXXXX.json``: another scene's images); and, for each ordering the paper claims, the
difference of the row means with its two-level bootstrap interval (:mod:`apr.reproduce.orderings`).
:func:`write_table1` writes ``table1.md``, ``table1.json`` (the same numbers, per seed) and ``figure4.png``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apr.reproduce.orderings import (
    MEASURES,
    MIN_SEEDS,
    PAPER_ORDERINGS,
    Measure,
    SeedResult,
    bootstrap_difference,
    evaluations_for,
    verdict,
)
from apr.reproduce.paper import PAPER_PRESETS, PAPER_TABLE1, paper_row
from apr.reproduce.plot import plot_learning_curves
from apr.reproduce.runs import RunSummary, eval_results, find_run_dirs, read_run
from apr.train.checkpoints import write_text_atomically
from apr.train.config import CPU_PREFIX, PRESETS, TABLE1_CPU_GRASPS
from apr.train.evaluation import wilson_interval


@dataclass
class TableRow:
    """One preset of the table: its runs and what their final evaluations add up to."""

    preset: str
    paper: str
    runs: list[RunSummary] = field(default_factory=list)
    """Runs of this preset with a final evaluation (:attr:`RunSummary.finished`)."""

    @property
    def episodes(self) -> int:
        return sum(int(run.final_eval["episodes"]) for run in self.runs)

    @property
    def successes(self) -> int:
        return sum(int(run.final_eval["successes"]) for run in self.runs)

    @property
    def attempts(self) -> int:
        """Final evaluation episodes that attempted a grasp; the rest ended at the 15-step limit (a lost episode is
        rerun, so every counted episode ends one way or the other)."""
        return sum(int(run.final_eval["attempts"]) for run in self.runs)

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
    def seed_results(self) -> list[tuple[int, int]]:
        """(successes, episodes) of each seed's final evaluation."""
        return [(int(run.final_eval["successes"]), int(run.final_eval["episodes"])) for run in self.runs]

    def seed_measures(self, measure: Measure) -> list[SeedResult]:
        """Each seed's evaluations that ``measure`` reads (:func:`apr.reproduce.orderings.evaluations_for`), up to
        its final evaluation."""
        found = []
        for run in self.runs:
            final = int(run.final_eval["grasps"])
            evaluations = [(int(item["grasps"]), int(item["successes"]), int(item["episodes"]))
                           for item in eval_results(run.run_dir) if int(item["grasps"]) <= final]  # fmt: skip
            found.append(evaluations_for(measure, evaluations))
        return found

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

    @property
    def blind_rates(self) -> list[float]:
        """The blind success of each run whose final policy was evaluated blind."""
        return [float(run.blind_eval["success_rate"]) for run in self.runs if run.blind_eval is not None]

    @property
    def look_cm(self) -> list[float]:
        """With a learned fixation: each seed's median distance (cm) from where it looked to the nearest object, in
        its final evaluation."""
        return [float(run.final_eval["fixation"]["median_cm"]) for run in self.runs
                if (run.final_eval.get("fixation") or {}).get("median_cm") is not None]  # fmt: skip

    @property
    def blind_mean(self) -> float | None:
        return float(np.mean(self.blind_rates)) if self.blind_rates else None


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
        row_name = paper_row(name)
        paper = PAPER_TABLE1[row_name].text if row_name else "(not in the paper)"
        row = TableRow(preset=name, paper=paper)
        for run in sorted((run for run in runs if run.preset == name), key=lambda run: run.seed):
            if run.finished:  # a run still training has no final evaluation to report
                row.runs.append(run)
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
        return [row.preset, row.paper, "not run", "", "", "", "0", "", "", _budget(row.preset), ""]
    low, high = row.pooled_interval
    pooled = (
        f"{format_percent(row.pooled_rate)} ({row.successes}/{row.episodes}) [{format_percent(low)}, "
        f"{format_percent(high)}]"
    )
    spread = format_percent(row.seed_mean)
    spread += f" ± {100 * row.seed_std:.1f} pts" if row.seed_std is not None else " (1 seed: no spread)"
    blind = row.blind_rates
    blind_text = f"{format_percent(row.blind_mean)} ({len(blind)} of {len(row.runs)} seeds)" if blind else "-"
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
        blind_text,
        attempts_text(row.attempts, row.episodes),
        f"{len(row.runs)} ({seeds})",
        grasps_text,
        str(row.episodes),
        _budget(row.preset),
        ", ".join(f"{cm:.2f}" for cm in row.look_cm) or "-",
    ]


def attempts_text(attempts: int, episodes: int) -> str:
    """``attempts/episodes (share ended at the limit)``: so that a policy that stopped trying cannot pass for one
    that tried and missed."""
    return f"{attempts}/{episodes} ({format_percent(1 - attempts / episodes)} at the limit)"


def render_table1(rows: Sequence[TableRow], source: str = "") -> str:
    """Table 1 as markdown: the table, how to read it, and each run's final evaluation file."""
    header = [
        "preset",
        "paper (Table 1)",
        "ours: held-out success, pooled (successes/episodes) [95% CI]",
        "ours: per-seed mean ± std",
        "blind: per-seed mean",
        "attempts (ended at the limit)",
        "seeds",
        "grasps",
        "eval episodes",
        "full budget of the preset",
        "looks: median cm to the nearest object, per seed",
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
        "- *blind*: the final policies given, in every phase, the images of another held-out scene (another "
        "episode of the same evaluation); what is left is what they do without seeing their own scene.",
        "- *attempts*: final evaluation episodes, all seeds, that started a grasp; the rest ended at the 15-step "
        "limit without one.",
        "- *grasps*: the training grasps behind each run's final evaluation (the `eval/eval_XXXXXXXX.json` with "
        "the most grasps); *full budget of the preset*: the grasps of a full run (the paper's, where it says).",
    ]
    if any(row.runs and row.preset.startswith(CPU_PREFIX) and paper_row(row.preset) for row in rows):
        lines.append(
            f"- **`cpu-` rows: the paper's settings at CPU scale** (tiny networks, TinyRenderer at 128, "
            f"{TABLE1_CPU_GRASPS} grasps, the same structure and learning recipe as the paper-size presets). They "
            "say whether each setting learns under this code and whether the paper's orderings appear at a small "
            "budget; they do not reproduce the paper's numbers, which come after 25-70K grasps."
        )
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
    if any(row.runs and paper_row(row.preset) is None for row in rows):
        lines.append(
            "- Presets marked *(not in the paper)*, such as `smoke` (tiny model, a few grasps), only "
            "exercise the pipeline."
        )
    lines += _ordering_lines(rows)
    lines += [
        "",
        "## Runs",
        "",
        "| preset | seed | final evaluation | grasps | training minutes | successes/episodes | rate | attempts "
        "| blind |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for row in rows:
        for run in row.runs:
            result, minutes = run.final_eval, run.train_minutes
            blind = run.blind_eval
            blind_text = (f"{blind['successes']}/{blind['episodes']} ({format_percent(blind['success_rate'])})"
                          if blind else "not evaluated")  # fmt: skip
            renamed = f" (trained as {run.trained_as})" if run.trained_as else ""
            lines.append(
                f"| {row.preset}{renamed} | {run.seed} | `{result['path']}` | {result['grasps']} | "
                f"{f'{minutes:.1f}' if minutes is not None else '?'} | {result['successes']}/{result['episodes']} | "
                f"{format_percent(result['success_rate'])} | "
                f"{attempts_text(int(result['attempts']), int(result['episodes']))} | {blind_text} |"
            )
    return "\n".join(lines) + "\n"


def orderings(rows: Sequence[TableRow]) -> list[dict]:
    """Each claim of :data:`PAPER_ORDERINGS` whose two rows have runs: the paper's sentence, the difference of the
    rows' seed means on its measure, its bootstrap 95% interval, and the verdict (:mod:`apr.reproduce.orderings`)."""
    by_row = {paper_row(row.preset): row for row in rows if row.runs and paper_row(row.preset)}
    found = []
    for ordering in PAPER_ORDERINGS:
        if ordering.first in by_row and ordering.second in by_row:
            first, second = by_row[ordering.first], by_row[ordering.second]
            difference = bootstrap_difference(first.seed_measures(ordering.measure),
                                              second.seed_measures(ordering.measure))  # fmt: skip
            seeds = (len(first.runs), len(second.runs))
            found.append({
                "claim": ordering.claim, "measure": ordering.measure, "sentence": ordering.sentence,
                "where": ordering.where, "first": first.preset, "second": second.preset,
                "seeds": list(seeds), "difference": difference.difference,
                "ci_low": difference.low, "ci_high": difference.high, "verdict": verdict(difference, seeds),
            })  # fmt: skip
    return found


def _ordering_lines(rows: Sequence[TableRow]) -> list[str]:
    found = orderings(rows)
    if not found:
        return []
    lines = [
        "",
        "## The paper's claims",
        "",
        "| the paper says | where | ahead | behind | measure | seeds | difference of the means | bootstrap 95% CI "
        "| verdict |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for item in found:
        lines.append(
            f'| "{item["sentence"]}" | {item["where"]} | {item["first"]} | {item["second"]} | {item["measure"]} | '
            f"{item['seeds'][0]} and {item['seeds'][1]} | {100 * item['difference']:+.1f} pts | "
            f"[{100 * item['ci_low']:+.1f}, {100 * item['ci_high']:+.1f}] | "
            f"**{item['verdict']}**{f' (fewer than {MIN_SEEDS} seeds)' if min(item['seeds']) < MIN_SEEDS else ''} |"
        )
    used: list[Measure] = list(dict.fromkeys(item["measure"] for item in found))
    lines += [
        "",
        "- Each claim says the *ahead* row does better than the *behind* one, as its sentence reads; the difference "
        "is the ahead row's mean minus the behind row's.",
        *(f"- *{measure}*: {MEASURES[measure]}." for measure in used),
        f"- The interval: {BOOTSTRAP_TEXT}.",
        "- A claim holds when the interval lies above 0, is reversed when it lies below 0, and is not resolved when "
        "it holds 0.",
    ]
    return lines


BOOTSTRAP_TEXT = (
    "10,000 resamples, each drawing every row's seeds with replacement and then each drawn seed's evaluations "
    "again (binomial at each one's rate); the 2.5th and 97.5th percentiles of the difference of the resampled means. "
    f"A verdict needs {MIN_SEEDS} seeds in each row; with 3 to 5 it is coarse"
)


README_BLOCK = "table1-cpu"
"""The name of the README's block that :func:`readme_block` writes (``<!-- table1-cpu -->``)."""


def readme_block(rows: Sequence[TableRow]) -> str:
    """Table 1 and the paper's claims, compact, for the README: each row's per-seed mean and spread, its blind mean
    and attempts; each claim with its verdict (:func:`write_readme_block` puts it between the README's markers)."""
    lines = ["| row | paper | ours: held-out success, mean ± std over seeds | seeds | blind | attempts | looks |",
             "| --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for row in rows:
        if not row.runs:
            lines.append(f"| `{row.preset}` | {row.paper} | not run yet | 0 | | | |")
            continue
        spread = f" ± {100 * row.seed_std:.1f}" if row.seed_std is not None else ""
        blind = format_percent(row.blind_mean) if row.blind_mean is not None else "-"
        looks = ", ".join(f"{cm:.1f}" for cm in row.look_cm) + " cm" if row.look_cm else "-"
        lines.append(f"| `{row.preset}` | {row.paper} | {format_percent(row.seed_mean)}{spread} | {len(row.runs)} | "
                     f"{blind} | {row.attempts}/{row.episodes} | {looks} |")  # fmt: skip
    if any(row.look_cm for row in rows):
        lines += ["", "*looks*: with a learned fixation, each seed's median distance from where it looked to the "
                  "nearest object (the middle of the drop area: about 5.4 cm)."]  # fmt: skip
    found = orderings(rows)
    if found:
        lines += ["", "| the paper says | ahead | behind | measure | difference [95% CI] | verdict |",
                  "| --- | --- | --- | --- | --- | --- |"]  # fmt: skip
        for item in found:
            short = f"{item['seeds'][0]} and {item['seeds'][1]} seeds"
            lines.append(
                f'| "{item["sentence"]}" | {paper_row(item["first"])} | {paper_row(item["second"])} | '
                f"{item['measure']} | {100 * item['difference']:+.1f} pts [{100 * item['ci_low']:+.1f}, "
                f"{100 * item['ci_high']:+.1f}] ({short}) | **{item['verdict']}** |"
            )
    return "\n".join(lines) + "\n"


def write_readme_block(readme: Path, rows: Sequence[TableRow]) -> None:
    """Replace the text between ``<!-- table1-cpu -->`` and ``<!-- /table1-cpu -->`` in ``readme`` with
    :func:`readme_block`; raise ``ValueError`` when the file has no such block."""
    text = readme.read_text()
    start, end = f"<!-- {README_BLOCK} -->\n", f"<!-- /{README_BLOCK} -->"
    if start not in text or end not in text:
        raise ValueError(f"{readme} has no {start.strip()} ... {end} block to replace")
    head, rest = text.split(start, 1)
    write_text_atomically(readme, head + start + readme_block(rows) + end + rest.split(end, 1)[1])


def table1_json(rows: Sequence[TableRow], source: str = "") -> dict:
    """The table's numbers, per seed: what ``table1.json`` holds."""
    return {
        "source": source,
        "rows": [
            {
                "preset": row.preset, "paper_row": paper_row(row.preset), "paper": row.paper,
                "seed_mean": row.seed_mean, "seed_std": row.seed_std, "blind_mean": row.blind_mean,
                "attempts": row.attempts, "episodes": row.episodes, "look_cm": row.look_cm,
                "seeds": [
                    {
                        "seed": run.seed, "run": run.run_dir.name, "trained_as": run.trained_as or None,
                        "successes": int(run.final_eval["successes"]), "episodes": int(run.final_eval["episodes"]),
                        "success_rate": float(run.final_eval["success_rate"]), "grasps": int(run.final_eval["grasps"]),
                        "attempts": int(run.final_eval["attempts"]),
                        "train_minutes": run.train_minutes,
                        "blind": None if run.blind_eval is None else {
                            name: run.blind_eval[name] for name in ("blind", "successes", "episodes", "success_rate")
                        },
                    }
                    for run in row.runs
                ],
            }
            for row in rows
        ],
        "orderings": orderings(rows),
    }  # fmt: skip


def write_table1(run_dirs: Iterable[Path], out: Path, presets: Sequence[str] | None = None, source: str = "") -> Path:
    """Build Table 1 from ``run_dirs`` and write it as markdown to ``out``, its numbers beside it
    (``table1.json``) and its learning curves (``figure4.png``, with the blind means at the end); return ``out``."""
    run_dirs = list(run_dirs)
    rows = build_table1(run_dirs, presets)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomically(out, render_table1(rows, source))
    write_text_atomically(out.with_name("table1.json"), json.dumps(table1_json(rows, source), indent=2) + "\n")
    blind = {row.preset: (float(np.mean(row.grasps)), row.blind_mean) for row in rows if row.blind_mean is not None}
    if run_dirs:
        plot_learning_curves(run_dirs, blind=blind).savefig(out.with_name("figure4.png"), dpi=120)
    return out
