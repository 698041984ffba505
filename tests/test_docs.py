"""The documentation against the code: the generated presets table, the versions, the departures' flags, and the
documentation site's strict build (a broken link or a docstring that does not
parse fails it)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import apr
from apr.commands.train import presets_markdown
from apr.reproduce.campaign import Table1Args
from apr.reproduce.table import README_BLOCK, build_table1, readme_block
from apr.train.config import TrainConfig

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _block(text: str, name: str) -> str:
    """The text between ``<!-- name -->`` and ``<!-- /name -->``."""
    match = re.search(rf"<!-- {name} -->\n(.*?)<!-- /{name} -->", text, re.S)
    assert match, f"no <!-- {name} --> block"
    return match.group(1)


def test_the_presets_page_is_the_generated_table() -> None:
    assert _block((DOCS / "presets.md").read_text(), "presets") == presets_markdown(), (
        "docs/presets.md is out of date: replace its block with `apr presets --markdown`"
    )


def test_the_readme_is_short_and_its_generated_blocks_are_current() -> None:
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 220
    assert _block(readme, "presets") == presets_markdown(compact=True)
    table = ROOT / "results" / "table1-cpu"
    rows = build_table1([table], Table1Args(scale="cpu").preset_names())
    assert _block(readme, README_BLOCK) == readme_block(rows), (
        "README.md's Table 1 block is out of date: apr reproduce table1 --scale cpu --out results/table1-cpu "
        "--table-only --readme README.md"
    )
    assert "https://arxiv.org/abs/2003.06734" in readme.split("## Set up")[0]  # the paper, on the first screen


def test_the_versions_table_lists_every_registered_version_newest_first() -> None:
    text = (DOCS / "environments.md").read_text()
    listed = re.findall(r"^\| `-(v\d+)` \|", text, re.M)
    assert listed == sorted(apr.VERSIONS, reverse=True)
    newest = listed[0]
    assert f"apr/ActiveGrasp-{newest}" in text and f"apr/PassiveGrasp-{newest}" in text


def _field_paths(config: object, prefix: str = "") -> set[str]:
    import dataclasses

    paths = set()
    for item in dataclasses.fields(config):
        value = getattr(config, item.name)
        if dataclasses.is_dataclass(value):
            paths |= _field_paths(value, f"{prefix}{item.name}.")
        else:
            paths.add(f"{prefix}{item.name}")
    return paths


def test_every_flag_of_the_departures_table_is_a_field() -> None:
    text = (DOCS / "decisions.md").read_text()
    table = text[text.index("## Departures from the paper") : text.index("## The world")]
    flags = set(re.findall(r"`--([a-z][a-z.-]*)", table))
    assert len(flags) >= 10
    fields = _field_paths(TrainConfig())
    unknown = {flag for flag in flags if flag.replace("-", "_") not in fields}
    assert not unknown, f"the departures table names flags that are no fields: {sorted(unknown)}"


@pytest.mark.skipif(shutil.which("mkdocs") is None and not (Path(sys.executable).parent / "mkdocs").exists(),
                    reason="mkdocs is not installed (pip install -e '.[docs]')")  # fmt: skip
def test_the_documentation_site_builds_strictly(tmp_path: Path) -> None:
    mkdocs = shutil.which("mkdocs") or str(Path(sys.executable).parent / "mkdocs")
    environment = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    result = subprocess.run([mkdocs, "build", "--strict", "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                            capture_output=True, text=True, timeout=300, env=environment)  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
