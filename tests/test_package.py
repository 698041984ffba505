"""The package as a whole: its modules import each other without circles, the optional cluster layer plugs in
from above, and CI runs the README's test command."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "src"


def module_files(source: Path = SOURCE) -> dict[str, Path]:
    """Every module of the ``apr`` package by its dotted name (a package by its ``__init__.py``)."""
    modules = {}
    for path in sorted((source / "apr").rglob("*.py")):
        parts = list(path.relative_to(source).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(parts)] = path
    return modules


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the ``apr`` modules it imports, from every import statement in it (those inside functions and
    ``if TYPE_CHECKING`` blocks included).

    ``from PACKAGE import NAME`` is an edge to ``PACKAGE.NAME`` when that is a module, else to ``PACKAGE`` (its
    ``__init__``). The implicit import of a module's parent packages (``import apr.train.workers`` runs
    ``apr/__init__.py`` and ``apr/train/__init__.py`` first) is not an edge: Python initialises a package before
    any of its submodules, so a package ``__init__`` that imports its submodules does not make a circle with
    them. A submodule that imports a name from its own package's ``__init__`` is an edge, and a circle if that
    ``__init__`` imports the submodule: that is the case that breaks (the name may not exist yet).
    """
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from the package, up level - 1
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*anchor, base] if base else anchor)
                targets = [
                    f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names
                ]
            else:
                continue
            for target in targets:
                if target.split(".")[0] == "apr" and target != name:
                    assert target in modules, f"{name} imports {target}, which is not a module of apr"
                    graph[name].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` (its modules in order, the first repeated at the end), or None."""
    state: dict[str, str] = {}  # "open" while on the current path, "done" once every path from it was walked
    path: list[str] = []

    def visit(module: str) -> list[str] | None:
        state[module] = "open"
        path.append(module)
        for target in sorted(graph[module]):
            if state.get(target) == "open":
                return path[path.index(target) :] + [target]
            if target not in state and (cycle := visit(target)):
                return cycle
        path.pop()
        state[module] = "done"
        return None

    for module in sorted(graph):
        if module not in state and (cycle := visit(module)):
            return cycle
    return None


def test_the_graph_reader_sees_imports_inside_functions_and_finds_a_circle(tmp_path: Path):
    package = tmp_path / "apr"
    (package / "low").mkdir(parents=True)
    (package / "__init__.py").write_text("from apr.low.a import x\n")
    (package / "low" / "__init__.py").write_text("")
    (package / "low" / "a.py").write_text("x = 1\n\ndef f():\n    from apr.high import y\n")
    (package / "high.py").write_text("from .low import a\ny = 2\n")
    graph = import_graph(module_files(tmp_path))
    assert graph["apr"] == {"apr.low.a"} and graph["apr.high"] == {"apr.low.a"}
    cycle = find_cycle(graph)
    assert cycle is not None and cycle[0] == cycle[-1] and set(cycle) == {"apr.high", "apr.low.a"}
    (package / "low" / "a.py").write_text("x = 1\n")
    assert find_cycle(import_graph(module_files(tmp_path))) is None


def test_no_import_circles_among_the_modules_of_apr():
    cycle = find_cycle(import_graph(module_files()))
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_training_and_reproduction_never_import_the_cluster_layer():
    """The cluster layer plugs in from above: the command layer passes its workers factory or campaign executor."""
    graph = import_graph(module_files())
    below = [name for name in graph if name.split(".")[1:2] in (["envs"], ["model"], ["train"], ["reproduce"])]
    reaching_up = {name: sorted(t for t in graph[name] if t.startswith("apr.cluster")) for name in below}
    assert not {name: targets for name, targets in reaching_up.items() if targets}


def _line_after(path: Path, marker: str) -> str:
    """The first line after the line that starts with ``marker``."""
    lines = path.read_text().splitlines()
    index = next(k for k, line in enumerate(lines) if line.strip().startswith(marker))
    return lines[index + 1].strip()


def test_ci_runs_exactly_the_readme_test_command_which_lints_checks_formatting_and_tests():
    readme = _line_after(ROOT / "README.md", "# 2. install")
    assert _line_after(ROOT / ".ci" / "run", "# README test command") == readme
    assert "ruff check ." in readme and "ruff format --check ." in readme and "python -m pytest" in readme
