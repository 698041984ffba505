"""A run folder's safety: checkpoint files written atomically and verified, a fallback to the newest intact
checkpoint, and a lock so that one process at a time trains in a folder.

A checkpoint is a pair: ``checkpoints/checkpoint_GRASPS.pt`` (networks, optimisers, counters, random states, the
configuration) and ``checkpoints/replay_GRASPS.npz`` (the replay memory at the same moment). Every kept
checkpoint keeps its replay, so each one can be resumed exactly (docs/decisions.md). The replay is written
first, then the checkpoint, each to a temporary file that is flushed to disk and renamed: a process killed at
any moment leaves the previous pairs whole. A new pair is read back before older pairs are deleted.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

CHECKPOINT_GLOB = "checkpoint_*.pt"
REQUIRED_KEYS = ("agent", "progress", "config")
"""What every training checkpoint holds (a resumable one also names its replay file under "replay")."""
LOCK_NAME = "train.lock"


class CheckpointError(Exception):
    """A checkpoint (or its replay file) that cannot be used; the message names the file and the reason."""


class RunLocked(Exception):
    """Another live process trains in the run folder; the message names its PID."""


# ------------------------------------------------------------------------------------------- writing
def commit(temporary: Path, path: Path) -> None:
    """Rename ``temporary`` onto ``path`` (atomic on POSIX) and flush the folder entry to disk."""
    os.replace(temporary, path)
    fsync_folder(path.parent)


def fsync_file(path: Path) -> None:
    """Flush ``path``'s data to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_folder(folder: Path) -> None:
    """Flush a folder's entries (a rename) to disk; a no-op where folders cannot be opened."""
    with contextlib.suppress(OSError):
        fsync_file(folder)


def write_atomically(path: Path, write: Callable[[Path], None]) -> None:
    """``write(temporary)``, flush it to disk, then rename it onto ``path``: ``path`` is the old file or the new
    one, never a partial one."""
    temporary = path.with_name(path.name + ".tmp")
    write(temporary)
    fsync_file(temporary)
    commit(temporary, path)


def write_text_atomically(path: Path, text: str) -> None:
    write_atomically(path, lambda temporary: temporary.write_text(text))


# ------------------------------------------------------------------------------------------- reading
def checkpoint_files(run_dir: Path) -> list[Path]:
    """The run's checkpoint files, oldest first (their names sort by grasps)."""
    return sorted((Path(run_dir) / "checkpoints").glob(CHECKPOINT_GLOB))


def read_checkpoint(path: Path, map_location: Any = "cpu") -> dict[str, Any]:
    """The state saved in a training checkpoint; :class:`CheckpointError` naming the file when it cannot be used."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such file")
    try:
        state = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as error:  # truncated, corrupt, or not a torch file at all
        raise CheckpointError(f"{path}: unreadable ({type(error).__name__}: {_first_line(error)})") from error
    if not isinstance(state, dict) or any(key not in state for key in REQUIRED_KEYS):
        raise CheckpointError(f"{path}: not a training checkpoint (it lacks {', '.join(REQUIRED_KEYS)})")
    return state


def replay_file(checkpoint: Path, state: dict[str, Any]) -> Path:
    """The replay file that goes with ``checkpoint``."""
    if "replay" not in state:
        raise CheckpointError(f"{checkpoint}: names no replay file")
    return Path(checkpoint).parent / state["replay"]


def verify_replay(path: Path) -> None:
    """Check that a replay file is whole (every member's CRC) and holds the replay counters."""
    if not path.is_file():
        raise CheckpointError(f"{path}: its replay file is missing")
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
            names = archive.namelist()
    except (OSError, zipfile.BadZipFile, EOFError) as error:
        raise CheckpointError(f"{path}: unreadable replay file ({type(error).__name__}: {error})") from error
    if bad is not None:
        raise CheckpointError(f"{path}: replay file damaged ({bad} fails its checksum)")
    if "counts.npy" not in names:
        raise CheckpointError(f"{path}: not a replay file (no counts)")


def newest_intact(
    run_dir: Path, with_replay: bool, map_location: Any = "cpu", report: Callable[[str], None] = print
) -> tuple[Path, dict[str, Any]] | None:
    """The newest checkpoint of ``run_dir`` that loads (and, ``with_replay``, whose replay file is whole), with its
    state; each newer one passed over is reported with the reason. None when the run has no checkpoint file.

    Raises:
        CheckpointError: there are checkpoint files, but none is intact (the message lists why, file by file).
    """
    files = checkpoint_files(run_dir)
    if not files:
        return None
    reasons = []
    for path in reversed(files):
        try:
            state = read_checkpoint(path, map_location)
            if with_replay:
                verify_replay(replay_file(path, state))
        except CheckpointError as error:
            reasons.append(str(error))
            report(f"skipping {path.name}: {error}")
            continue
        if reasons:
            report(f"using {path.name}, the newest intact checkpoint")
        return path, state
    raise CheckpointError(f"{run_dir} has no intact checkpoint:\n  " + "\n  ".join(reasons))


def prune(directory: Path, keep: int) -> list[Path]:
    """Delete all but the newest ``keep`` checkpoints with their replay files, replay files whose checkpoint is
    gone, and temporary files left by a killed writer. Returns what it deleted."""
    checkpoints = sorted(directory.glob(CHECKPOINT_GLOB))
    kept = checkpoints[-keep:] if keep > 0 else []
    kept_replays = {f"replay_{path.stem.removeprefix('checkpoint_')}.npz" for path in kept}
    doomed = [path for path in checkpoints if path not in kept]
    doomed += [path for path in directory.glob("replay_*.npz") if path.name not in kept_replays]
    doomed += list(directory.glob("*.tmp"))
    for path in doomed:
        path.unlink(missing_ok=True)
    return doomed


def _first_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return text[0] if text else ""


# ------------------------------------------------------------------------------------------- the lock
class RunLock:
    """An exclusive lock on a run folder: ``RUN/train.lock``, held with ``flock`` and holding the holder's PID.

    The kernel drops a ``flock`` when its process dies however it dies, so a lock file left by a dead process
    is stale and is taken over; a live holder is named in the refusal.
    """

    def __init__(self, run_dir: Path, report: Callable[[str], None] = print):
        self.path = Path(run_dir) / LOCK_NAME
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read_pid(fd)
                os.close(fd)
                raise RunLocked(
                    f"{run_dir} is in use: process {holder or '(unknown)'} is training in it (lock file {self.path}). "
                    "Wait for it to finish, or stop it (Ctrl-C saves a checkpoint) and resume."
                ) from None
            if _same_file(fd, self.path):  # not unlinked by a holder releasing it since we opened it
                break
            os.close(fd)
        previous = _read_pid(fd)
        if previous and previous != os.getpid():
            report(f"took over the lock of process {previous}, which is no longer running ({self.path})")
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd: int | None = fd

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Delete the lock file and drop the lock (idempotent)."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        with contextlib.suppress(OSError):
            if _same_file(fd, self.path):
                self.path.unlink()
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)

    def __enter__(self) -> RunLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.release()


def _read_pid(fd: int) -> int | None:
    try:
        return int(os.pread(fd, 32, 0).decode().strip() or 0) or None
    except (OSError, ValueError):
        return None


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.stat(path).st_ino == os.fstat(fd).st_ino
    except FileNotFoundError:
        return False
