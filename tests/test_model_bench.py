"""``apr bench learner`` runs at tiny sizes and prints its table."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from apr.bench.learner import LearnerBenchArgs, run


def test_importing_the_learner_bench_does_not_import_torch() -> None:
    """The CLI imports this module at startup: torch must wait until ``run``."""
    code = "import sys, apr.bench.learner; print('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"


def test_learner_bench_prints_time_throughput_and_flops(capsys: pytest.CaptureFixture[str]) -> None:
    run(LearnerBenchArgs(size="tiny", batch_size=4, warmup=0, iterations=1, device="cpu"))
    out = capsys.readouterr().out
    rows = dict(re.findall(r"^\| (.+?) +\| +(.+?) \|$", out, flags=re.MULTILINE))
    assert float(rows["ms / joint update (median)"]) > 0
    assert float(rows["samples / s"]) > 0
    assert float(rows["GFLOP / sample (fwd + bwd)"]) > float(rows["  forward: generator"]) > 0
