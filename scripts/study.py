"""Train any presets over chosen seeds, two or more at a time, each final policy also evaluated blind (another scene's
images in every phase): the runs of an investigation, resumable as a Table 1 campaign is.

    python scripts/study.py --presets cpu-active-learned-4d cpu-active-learned-4d-tip-proximity --seeds 0 \
        --out results/fixation-reward --parallel 2 --workers 2
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import tyro

from apr.reproduce.campaign import plan_runs, run_campaign
from apr.reproduce.table import write_table1


@dataclass
class StudyArgs:
    presets: tuple[str, ...]
    """Full preset names (``apr presets``)."""
    seeds: tuple[int, ...] = (0,)
    out: Path = Path("runs/study")
    """Parent folder of the runs (PRESET__sSEED)."""
    parallel: int = 2
    """Runs trained at once, each in its own process."""
    workers: int = 2
    """Environment processes per run."""
    grasps: int = 0
    """Grasps per run; 0 = the preset's budget."""
    table_only: bool = False
    """Train nothing: write OUT/table.md (and table.json, figure4.png) from the runs already there."""


def main(args: StudyArgs) -> None:
    overrides = {"workers": args.workers, **({"total_grasps": args.grasps} if args.grasps else {})}
    plans = [dataclasses.replace(plan, blind=True) for plan in plan_runs(args.presets, args.seeds, args.out, overrides)]
    failed = [] if args.table_only else [plan.run_dir for plan, code in run_campaign(plans, args.parallel) if code]
    present = [plan.run_dir for plan in plans if (plan.run_dir / "config.json").exists()]
    if present:
        command = f"python scripts/study.py --presets {' '.join(args.presets)} --seeds {' '.join(map(str, args.seeds))}"
        write_table1(present, args.out / "table.md", list(args.presets), f"Built by `{command} --out {args.out}`.")
    if failed:
        raise SystemExit(f"{len(failed)} run(s) failed: " + ", ".join(map(str, failed)))


if __name__ == "__main__":
    main(tyro.cli(StudyArgs))
