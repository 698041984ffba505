"""The benchmark's 1000 procedurally generated objects and their train/test split.

The test set is the 100 objects whose number ends in 0 (000, 010, ..., 990); the training set is the other 900.
The benchmark's original training glob ``*[^0]`` also matched test objects (fixed in bullet3 PR #2159);
here the split is explicit and pinned by a test.
"""

from __future__ import annotations

from pathlib import Path

import pybullet_data

SPLITS = ("train", "test")
NUM_OBJECTS = 1000


def object_ids(split: str) -> list[int]:
    """Sorted object numbers of ``split`` ("train": 900 objects, "test": the 100 whose number ends in 0)."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    held_out = split == "test"
    return [n for n in range(NUM_OBJECTS) if (n % 10 == 0) == held_out]


def object_urdf(number: int) -> str:
    """Path of object ``number``'s URDF in ``pybullet_data``."""
    if not 0 <= number < NUM_OBJECTS:
        raise ValueError(f"object number must be in [0, {NUM_OBJECTS}), got {number}")
    path = Path(pybullet_data.getDataPath()) / "random_urdfs" / f"{number:03d}" / f"{number:03d}.urdf"
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: this pybullet_data has no benchmark objects")
    return str(path)
