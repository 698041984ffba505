"""Keeping pybullet's C-level chatter off the console, and everything else on it.

pybullet and its EGL plugin print status lines straight to the C streams (``pybullet build time``,
``argv[0]=``, ``EGL device choice``, the GL strings, ``ven = ...``, ``Destroy EGL OpenGL window.``), where
Python's ``sys.stdout`` redirection cannot reach them. :func:`quiet_c_output` points file descriptors 1 and 2 at
temporary files for the length of a block, then writes back to the real streams every line that is not such
chatter: warnings and errors stay visible (at the end of the block).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterator
from typing import IO

CHATTER = re.compile(
    r"(pybullet build time: .*|argv\[0\]=.*|EGL device choice: .*|Loaded EGL .*"
    r"|GL_(VENDOR|RENDERER|VERSION|SHADING_LANGUAGE_VERSION)=.*|(Version|Vendor|Renderer) = .*|ven = .*"
    r"|Destroy EGL OpenGL window\.)"
)
"""Whole lines that pybullet and its EGL plugin print on import, connect, plugin load, render and disconnect."""

_lock = threading.RLock()
_depth = 0
_captures: tuple[int, dict[int, IO[bytes]]] | None = None
_libc: ctypes.CDLL | None = None


def is_chatter(line: str) -> bool:
    return CHATTER.fullmatch(line.rstrip("\r\n")) is not None


def drop_chatter(text: bytes) -> bytes:
    """``text`` without its chatter lines."""
    lines = text.splitlines(keepends=True)
    return b"".join(line for line in lines if not is_chatter(line.decode(errors="replace")))


@contextlib.contextmanager
def quiet_c_output() -> Iterator[None]:
    """Within the block, C-level output to stdout and stderr is held back; at its end, all but pybullet's
    chatter is written out. Re-entrant; a no-op where the descriptors cannot be redirected."""
    global _depth
    with _lock:
        if _depth > 0:
            _depth += 1
            try:
                yield
            finally:
                _depth -= 1
            return
        try:
            files = _capture_files()
            _flush()
            for file in files.values():
                file.seek(0)
                file.truncate()
            saved = {fd: os.dup(fd) for fd in files}
        except (OSError, ValueError):  # closed descriptors or files (a daemon, interpreter exit): no redirection
            yield
            return
        for fd, file in files.items():
            os.dup2(file.fileno(), fd)
        _depth = 1
        try:
            yield
        finally:
            _depth = 0
            _flush()
            for fd, file in files.items():
                os.dup2(saved[fd], fd)
                os.close(saved[fd])
                file.seek(0)
                _write_all(fd, drop_chatter(file.read()))


def _capture_files() -> dict[int, IO[bytes]]:
    """One temporary file per descriptor, made once per process (a forked child makes its own)."""
    global _captures
    if _captures is None or _captures[0] != os.getpid():
        _captures = (os.getpid(), {fd: tempfile.TemporaryFile() for fd in (1, 2)})  # noqa: SIM115 (kept open)
    return _captures[1]


def _flush() -> None:
    """Flush Python's and C's buffers, so that nothing lands on the wrong side of a redirection."""
    global _libc
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    if _libc is None:
        _libc = ctypes.CDLL(None)
    _libc.fflush(None)


def _write_all(fd: int, data: bytes) -> None:
    while data:
        try:
            written = os.write(fd, data)
        except OSError:
            return
        data = data[written:]
