"""The grasping task: which objects, where to look, what counts as success, and the rewards.

Kept apart from the physics (:mod:`apr.envs.world`) as in dm_control: the world knows bodies and motors,
the task knows episodes and rewards.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apr.envs.config import GRASP, REWARD, SCENE
from apr.envs.objects import object_ids
from apr.envs.world import GraspWorld

TARGETS = ("env", "learned")
OBJECTS_PER_EPISODE = 5  # paper: at most 5 objects when training, exactly 5 when evaluating


@dataclass
class GraspOutcome:
    """What a grasp attempt achieved."""

    lifted: list[int]
    """Bodies whose base ended above the success height."""
    success: bool
    """The sparse grasp reward was earned."""


class GraspTask:
    """Episode logic shared by the active and passive environments.

    Args:
        target: "env" (the environment picks a target object; only lifting it is rewarded) or "learned"
            (the agent picks a fixation point; lifting any object counts if the tool tip was within
            ``REWARD.fixation_radius`` of that point when the grasp started).
        split: "train" (at most 5 objects, from the 900 training objects) or "test" (exactly 5, held out).
        reach_scale: metres of progress toward the fixation point -> reach reward (``REWARD.reach_scale``).
    """

    def __init__(self, target: str, split: str, reach_scale: float = REWARD.reach_scale):
        if target not in TARGETS:
            raise ValueError(f"target must be one of {TARGETS}, got {target!r}")
        if not (np.isfinite(reach_scale) and reach_scale >= 0):
            raise ValueError(f"reach_scale must be a finite number >= 0, got {reach_scale!r}")
        self.target = target
        self.reach_scale = float(reach_scale)
        self.split = split
        self.objects = np.array(object_ids(split))  # validates the split
        self.target_uid: int | None = None

    def reset(self, world: GraspWorld, rng: np.random.Generator) -> np.ndarray:
        """Fill the tray and pick the target; return the episode's first fixation point (3,)."""
        while True:
            numbers = rng.choice(self.objects, size=OBJECTS_PER_EPISODE, replace=False)
            world.reset_scene([int(n) for n in numbers], rng, all_in_tray=self.split == "test")
            if world.object_uids:  # all of them fell out of the tray: draw again
                break
        if self.target == "learned":
            self.target_uid = None
            return np.array(SCENE.bin_centre)
        self.target_uid = int(rng.choice(world.object_uids))
        return world.object_centre(self.target_uid)

    @staticmethod
    def fixation_from_action(action: np.ndarray) -> np.ndarray:
        """Map a fixation action in [-1, 1]^3 linearly onto the workspace box (m)."""
        low, high = np.array(REWARD.workspace_low), np.array(REWARD.workspace_high)
        return low + 0.5 * (np.asarray(action, dtype=np.float64) + 1.0) * (high - low)

    def reach_reward(self, distance_before: float, distance_after: float) -> float:
        """Dense reach reward: progress of the tool tip toward the fixation point this step (potential-based)."""
        return self.reach_scale * (distance_before - distance_after)

    def grasp_outcome(self, world: GraspWorld, tip_at_grasp: np.ndarray, fixation_point: np.ndarray) -> GraspOutcome:
        """Judge a finished grasp attempt (after close and lift)."""
        lifted = [uid for uid in world.object_uids if world.object_position(uid)[2] > GRASP.success_height]
        if self.target == "env":
            success = self.target_uid in lifted
        else:
            near = np.linalg.norm(tip_at_grasp - fixation_point) <= REWARD.fixation_radius
            success = bool(lifted) and bool(near)
        return GraspOutcome(lifted=lifted, success=success)
