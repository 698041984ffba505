"""Checks a command makes before any work: numbers in range and output paths it will be able to write."""

from __future__ import annotations

import os
from pathlib import Path


def at_least(flag: str, value: int, low: int) -> str | None:
    """A sentence naming ``flag`` when ``value`` is below ``low`` (None when it is fine)."""
    return None if value >= low else f"{flag} must be at least {low}, got {value}"


def _writable_ancestor(path: Path) -> str | None:
    """Why folders cannot be created at ``path`` (None when they can): the nearest existing ancestor must be a
    writable folder."""
    for ancestor in (path, *path.parents):
        if ancestor.exists():
            if not ancestor.is_dir():
                return f"{ancestor} is a file, not a folder"
            if not os.access(ancestor, os.W_OK | os.X_OK):
                return f"{ancestor} is not writable"
            return None
    return None


def output_file(flag: str, path: Path) -> str | None:
    """Why ``path`` cannot be written as a file by the end of a command (None when it can)."""
    path = Path(path)
    if path.is_dir():
        return f"{flag} {path} is a folder; give a file name"
    if not path.parent.is_dir():
        return f"{flag} {path}: the folder {path.parent} does not exist"
    if not os.access(path.parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        return f"{flag} {path}: not writable"
    return None


def output_folder(flag: str, path: Path) -> str | None:
    """Why ``path`` cannot be made (or written into) as a folder (None when it can)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        return f"{flag} {path} is a file, not a folder"
    problem = _writable_ancestor(path)
    return f"{flag} {path}: {problem}" if problem else None


def refuse(command: str, problems: list[str | None]) -> None:
    """Exit with every problem found, one per line, before the command does any work."""
    found = [problem for problem in problems if problem]
    if found:
        raise SystemExit("\n".join(f"{command}: error: {problem}" for problem in found))
