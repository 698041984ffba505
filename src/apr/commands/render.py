"""``apr render``: PNGs of one episode, as the robot sees it.

For every step of a scripted episode (the gripper reaching for the environment's target) it writes the raw
256x256 head views beside their log-polar 64x64 samples (the paper's Figure 1 G/H), the target masks, and the
three passive camera views of the same seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import gymnasium as gym
import imageio.v3 as iio
import numpy as np

from apr.commands import checks
from apr.envs.scripted import scripted_grasp_action
from apr.train.config import ACTIVE_ENV_ID, PASSIVE_ENV_ID


@dataclass
class RenderArgs:
    """Write PNGs of one episode: head views, their log-polar samples, and the passive views."""

    out: Path = Path("renders")
    """Folder for the PNGs (created if missing)."""
    seed: int = 0
    """Episode seed: the objects, the target and the viewpoints."""
    steps: int = 5
    """Grasp steps to picture (the episode may end sooner with a grasp)."""
    split: Literal["train", "test"] = "train"
    """Object split: train or test."""
    renderer: Literal["auto", "egl", "tiny"] = "auto"
    """auto, egl or tiny."""


def run(args: RenderArgs) -> None:
    checks.refuse("apr render", [
        checks.at_least("--steps", args.steps, 0), checks.at_least("--seed", args.seed, 0),
        checks.output_folder("--out", args.out),
    ])  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    written = _render_episode(ACTIVE_ENV_ID, "active", args)
    written += _render_episode(PASSIVE_ENV_ID, "passive", args)
    print(f"wrote {len(written)} PNGs to {args.out}/ (e.g. {written[0].name})")


def _render_episode(env_id: str, name: str, args: RenderArgs) -> list[Path]:
    """Run one scripted episode of ``env_id`` and write a PNG per step: raw views on top, 64x64 samples below."""
    env = gym.make(env_id, dof=4, split=args.split, renderer=args.renderer)
    written = []
    try:
        observation, _ = env.reset(seed=args.seed)
        for step in range(args.steps + 1):
            path = args.out / f"{name}_step{step:02d}.png"
            iio.imwrite(path, _step_sheet(env.unwrapped.raw_views, observation["images"]))
            written.append(path)
            if step == args.steps:
                break
            observation, _, terminated, truncated, info = env.step(scripted_grasp_action(env.unwrapped))
            if terminated or truncated:
                print(f"{name}: episode ended after {step + 1} steps, grasp success: {info['grasp_success']}")
                break
    finally:
        env.close()
    return written


def _step_sheet(raw_views: list[np.ndarray], images: np.ndarray) -> np.ndarray:
    """One picture of a step: each raw 256x256 view (and its mask) above its 64x64 sample, shown 4x larger."""
    columns = []
    for raw, sample in zip(raw_views, images, strict=True):
        scale = raw.shape[0] // sample.shape[0]
        big = sample.repeat(scale, axis=0).repeat(scale, axis=1)
        rows = [raw[..., :3], big[..., :3]]
        if raw.shape[-1] == 4:  # the target mask, as grey
            rows += [np.repeat(raw[..., 3:], 3, axis=-1), np.repeat(big[..., 3:], 3, axis=-1)]
        columns.append(np.concatenate(rows, axis=0))
    gap = np.full((columns[0].shape[0], 4, 3), 255, np.uint8)
    return np.concatenate([piece for column in columns for piece in (column, gap)][:-1], axis=1)
