"""The package as a whole: CI runs the README's test command."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _line_after(path: Path, marker: str) -> str:
    """The first line after the line that starts with ``marker``."""
    lines = path.read_text().splitlines()
    index = next(k for k, line in enumerate(lines) if line.strip().startswith(marker))
    return lines[index + 1].strip()


def test_ci_runs_exactly_the_readme_test_command_which_lints_checks_formatting_and_tests():
    readme = _line_after(ROOT / "README.md", "# 2. install")
    assert _line_after(ROOT / ".ci" / "run", "# README test command") == readme
    assert "ruff check ." in readme and "ruff format --check ." in readme and "python -m pytest" in readme
