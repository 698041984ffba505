"""Every command's bad input ends in one clear line and a non-zero exit, before any work: a path that does not
exist, a run folder whose file is damaged, and an output folder that cannot be made (under a file)."""

from __future__ import annotations

from pathlib import Path

import pytest

from apr.cli import main


@pytest.fixture
def paths(tmp_path: Path) -> dict[str, Path]:
    damaged = tmp_path / "damaged"
    (damaged / "eval").mkdir(parents=True)
    (damaged / "config.json").write_text("{not json")
    (damaged / "eval" / "eval_00000010.json").write_text("{not json either")
    a_file = tmp_path / "a-file"
    a_file.write_text("not a folder")
    return {"missing": tmp_path / "no-such-run", "damaged": damaged, "unmakeable": a_file / "sub", "tmp": tmp_path}


COMMANDS = {
    "missing": [
        ["eval", "{missing}"],
        ["plot", "{missing}", "--out", "{tmp}/x.png"],
        ["figures", "{missing}", "--out", "{tmp}/figures"],
        ["demo", "--checkpoint", "{missing}", "--out", "{tmp}/demo"],
        ["probe", "{missing}"],
        ["train", "--resume", "{missing}"],
        ["reproduce", "package", "{missing}"],
    ],
    "damaged": [
        ["plot", "{damaged}", "--out", "{tmp}/x.png"],
        ["eval", "{damaged}"],
        ["train", "--resume", "{damaged}"],
        ["figures", "{damaged}", "--out", "{tmp}/figures"],
    ],
    "unmakeable": [
        ["train", "--preset", "smoke", "--runs-dir", "{unmakeable}"],
        ["demo", "--out", "{unmakeable}"],
        ["render", "--out", "{unmakeable}"],
        ["reproduce", "table1", "--scale", "cpu", "--out", "{unmakeable}", "--table-only"],
    ],
}


@pytest.mark.parametrize(("kind", "argv"), [(kind, argv) for kind, lists in COMMANDS.items() for argv in lists],
                         ids=lambda value: value if isinstance(value, str) else " ".join(value[:2]))  # fmt: skip
def test_bad_input_gives_one_line_and_a_non_zero_exit(kind: str, argv: list[str], paths: dict[str, Path],
                                                      capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    argv = [part.format(**paths) for part in argv]
    with pytest.raises(SystemExit) as raised:
        main(argv)
    code = raised.value.code
    assert code not in (0, None), f"apr {' '.join(argv)} exited with {code!r}"
    captured = capsys.readouterr()
    message = (code if isinstance(code, str) else "") + captured.err
    lines = [line for line in message.splitlines() if line.strip() and not line.startswith("replay:")]
    assert lines, f"apr {' '.join(argv)} said nothing"
    assert "Traceback" not in message
    assert len(lines) <= 2, lines  # one line (tyro's parser may add its usage line)
    named = str(paths[kind]) if kind != "unmakeable" else str(paths[kind].parent)
    assert named in message or paths[kind].name in message, message
