"""Reading run folders: the configuration, the evaluations and the learning curve a run wrote.

A run folder (``apr train``) holds ``config.json``, ``metrics.csv``, ``eval/eval_XXXXXXXX.json`` (one per
evaluation on held-out objects) and ``checkpoints/``. Everything the reproduction reports is read from these
files, never recomputed.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class RunSummary:
    """What the table and the plot need from one run folder."""

    run_dir: Path
    preset: str
    """The preset the run started from (``config.json``'s ``preset``)."""
    seed: int
    config: dict
    """``config.json`` as a dict."""
    final_eval: dict | None
    """The evaluation with the most grasps (``eval/eval_*.json``), or None if the run has none yet."""
    blind_eval: dict | None = None
    """The blind evaluation of the final evaluation's policy (``eval/blind_MODE_GRASPS.json``, another scene's
    images), or None."""
    trained_as: str = ""
    """The preset's name when the run was made, where it has been renamed since (``RENAMED_PRESETS``)."""

    @property
    def finished(self) -> bool:
        """True when the run has its final evaluation: at its grasp budget, or the last of a run that ran out of
        training time (``final`` in the file)."""
        result = self.final_eval
        return result is not None and (bool(result.get("final")) or int(result["grasps"]) >= self.total_grasps)

    @property
    def train_minutes(self) -> float | None:
        """Training minutes (evaluations not counted) up to the final evaluation, where it records them."""
        if self.final_eval is None or "train_s" not in self.final_eval:
            return None
        return float(self.final_eval["train_s"]) / 60

    @property
    def total_grasps(self) -> int:
        """The grasp budget the run was configured for."""
        return int(self.config.get("total_grasps", 0))


def is_run_dir(path: Path) -> bool:
    return (path / "config.json").is_file()


def find_run_dirs(paths: Iterable[Path]) -> list[Path]:
    """Run folders among ``paths``: each path is a run folder, or a folder whose sub-folders are runs.

    Raises:
        FileNotFoundError: a path is neither a run folder nor holds one.
    """
    found: list[Path] = []
    for path in paths:
        path = Path(path)
        if is_run_dir(path):
            found.append(path)
            continue
        children = sorted(child for child in path.iterdir() if is_run_dir(child)) if path.is_dir() else []
        if not children:
            raise FileNotFoundError(f"{path} is not a run folder (no config.json) and holds none")
        found.extend(children)
    return found


class UnreadableFile(ValueError):
    """A file of a run folder that cannot be read as what it should be (the message names it)."""


def read_json(path: Path) -> dict:
    """A JSON file of a run folder; :class:`UnreadableFile` naming it when it is not JSON."""
    try:
        return json.loads(Path(path).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise UnreadableFile(f"{path} is not valid JSON ({error}): restore it, or move its run folder away") from None


def read_config(run_dir: Path) -> dict:
    return read_json(run_dir / "config.json")


def eval_results(run_dir: Path) -> list[dict]:
    """Every evaluation of the run (``eval/eval_*.json``), by increasing grasps."""
    results = []
    for path in sorted((run_dir / "eval").glob("eval_*.json")):
        result = read_json(path)
        result.setdefault("grasps", int(path.stem.split("_")[-1]))
        result["path"] = str(path)
        results.append(result)
    return sorted(results, key=lambda result: result["grasps"])


def final_eval(run_dir: Path) -> dict | None:
    """The run's final evaluation: the one with the most grasps, or None."""
    results = eval_results(run_dir)
    return results[-1] if results else None


def run_preset(config: dict) -> str:
    """The preset a run started from, by its current name."""
    from apr.train.config import RENAMED_PRESETS

    name = str(config.get("preset", "unknown"))
    return RENAMED_PRESETS.get(name, name)


def blind_eval_files(run_dir: Path, grasps: int) -> list[Path]:
    """The run's blind evaluations of its policy at ``grasps`` (``eval/blind_MODE_GRASPS.json``), by mode's name."""
    return sorted((run_dir / "eval").glob(f"blind_*_{grasps:08d}.json"))


def blind_eval(run_dir: Path, grasps: int) -> dict | None:
    """The run's blind evaluation of its policy at ``grasps`` (the first of :func:`blind_eval_files`), or None."""
    for path in blind_eval_files(run_dir, grasps):
        result = json.loads(path.read_text())
        result["path"] = str(path)
        return result
    return None


def read_run(run_dir: Path) -> RunSummary:
    config = read_config(run_dir)
    final = final_eval(run_dir)
    name, preset = str(config.get("preset", "unknown")), run_preset(config)
    return RunSummary(
        run_dir=run_dir,
        preset=preset,
        seed=int(config.get("seed", 0)),
        config=config,
        final_eval=final,
        blind_eval=blind_eval(run_dir, int(final["grasps"])) if final is not None else None,
        trained_as=name if preset != name else "",
    )


def read_metrics(run_dir: Path) -> list[dict[str, str]]:
    """The rows of the run's ``metrics.csv``, oldest first (empty if it has none yet)."""
    path = run_dir / "metrics.csv"
    if not path.exists():
        return []
    with open(path, newline="") as file:
        return list(csv.DictReader(file))


def without_timings(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    """The rows less their wall-clock columns: what a run computed, to compare two runs of one configuration."""
    from apr.train.trainer import TIMING_COLUMNS

    return [{name: value for name, value in row.items() if name not in TIMING_COLUMNS} for row in rows]


def eval_curve(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """Held-out success against grasps: the ``metrics.csv`` rows that carry an evaluation.

    Returns:
        grasps (int array) and success rates in [0, 1] (float array), by increasing grasps.
    """
    rows = [row for row in read_metrics(run_dir) if row.get("eval_success", "") != ""]
    by_grasps = {int(row["grasps"]): float(row["eval_success"]) for row in rows}  # a later row wins
    grasps = np.array(sorted(by_grasps), dtype=int)
    return grasps, np.array([by_grasps[g] for g in grasps], dtype=float)
