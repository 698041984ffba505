"""``apr bench learning`` reports what the run folders and the baselines measured, and nothing else."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from apr.bench.learning import LearningBenchArgs, run
from apr.train.config import preset
from apr.train.trainer import METRICS_COLUMNS


def fabricate_run(run_dir: Path, seed: int, evaluations: list[tuple[int, int, int, float, bool]]) -> None:
    """A run folder with evaluations (grasps, successes, episodes, training seconds, final) and a metrics row."""
    (run_dir / "eval").mkdir(parents=True)
    config = preset("cpu-4d")
    config.seed = seed
    (run_dir / "config.json").write_text(config.resolved().to_json())
    for grasps, successes, episodes, train_s, final in evaluations:
        result = {"grasps": grasps, "episodes": episodes, "successes": successes,
                  "success_rate": successes / episodes, "ci_low": 0.1, "ci_high": 0.9, "train_s": train_s,
                  "updates": 10 * grasps, "final": final}  # fmt: skip
        (run_dir / "eval" / f"eval_{grasps:08d}.json").write_text(json.dumps(result))
    row = dict.fromkeys(METRICS_COLUMNS, "")
    row.update(grasps=evaluations[-1][0], env_steps=1000, updates=900, train_s=600.0, learner_s=300.0, act_s=6.0,
               eval_s=60.0)  # fmt: skip
    with open(run_dir / "metrics.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=METRICS_COLUMNS)
        writer.writeheader()
        writer.writerow(row)


def test_report_reads_the_runs_and_measures_the_baselines(tmp_path: Path, capsys):
    runs = tmp_path / "runs"
    fabricate_run(runs / "cpu-4d__s0", 0, [(50, 1, 4, 120.0, False), (100, 3, 4, 300.0, True)])
    fabricate_run(runs / "cpu-4d__s1", 1, [(60, 2, 4, 200.0, True)])
    run(LearningBenchArgs(preset="cpu-4d", seeds=(0, 1), out=tmp_path, baseline_episodes=2, workers=2,
                          renderer="tiny", report_only=True))  # fmt: skip

    with open(tmp_path / "curve.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    assert [(row["run"], row["grasps"], row["successes"], row["train_minutes"], row["final"]) for row in rows] == [
        ("cpu-4d__s0", "50", "1", "2.0", "False"), ("cpu-4d__s0", "100", "3", "5.0", "True"),
        ("cpu-4d__s1", "60", "2", "3.33", "True"),
    ]  # fmt: skip
    baselines = json.loads((tmp_path / "baselines.json").read_text())["results"]
    assert set(baselines) == {"untrained", "random", "scripted"}
    assert all(result["episodes"] == 2 for result in baselines.values())
    assert baselines["untrained"]["attempts"] == 0  # its mean action never brings the gripper down
    assert (tmp_path / "curve.png").stat().st_size > 10_000
    summary = (tmp_path / "summary.md").read_text()
    assert "| cpu-4d__s0 | 100 | 5.0 | 75.0% |" in summary and "| cpu-4d__s1 | 60 | 3.33 | 50.0% |" in summary
    assert "| cpu-4d__s0 | 100 | 900 | 10.0 | 1.0 | 10.0 | 1.50 | 49% | 50% | 1% |" in summary
    assert summary in capsys.readouterr().out

    # The baselines are cached per environment and episode count: a second report reads them back.
    cached = json.loads((tmp_path / "baselines.json").read_text())
    cached["results"]["random"]["success_rate"] = 0.123
    (tmp_path / "baselines.json").write_text(json.dumps(cached))
    run(LearningBenchArgs(preset="cpu-4d", seeds=(0, 1), out=tmp_path, baseline_episodes=2, workers=2,
                          renderer="tiny", report_only=True))  # fmt: skip
    assert "| random | 12.3% |" in (tmp_path / "summary.md").read_text()
