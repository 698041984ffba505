"""Running apr beyond one machine: environment workers as Ray actors (``apr train --backend ray``) and the
Table 1 campaign on a Ray cluster or through Slurm (``apr reproduce table1 --backend ray|slurm``).

Ray and submitit are optional (``pip install -e ".[cluster]"``); apr imports without them, and asking for a
backend that needs one says how to install it.
"""

from __future__ import annotations

import importlib
from types import ModuleType

INSTALL_HINT = 'pip install -e ".[cluster]"  (or: pip install "apr[cluster]")'


class MissingDependency(ImportError):
    """An optional dependency of a backend is not installed; the message says how to install it."""


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module`` for ``purpose``, or raise :class:`MissingDependency` with the install command."""
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise MissingDependency(f"{purpose} needs the {module!r} package, which is not installed ({error}). "
                                f"Install apr's cluster extra: {INSTALL_HINT}") from None  # fmt: skip


def missing(module: str, purpose: str) -> str | None:
    """A sentence saying how to install ``module`` when it cannot be imported (None when it can)."""
    try:
        require(module, purpose)
    except MissingDependency as error:
        return str(error)
    return None
