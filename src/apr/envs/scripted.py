"""A scripted reach-and-grasp policy: proof that the world is solvable, and a driver for pictures and benchmarks."""

from __future__ import annotations

import numpy as np

from apr.envs.config import GRASP
from apr.envs.grasp_env import GraspEnv

DESCEND_WITHIN = 0.02
"""m: the gripper descends once the tool tip is this close to the fixation point in xy."""


def scripted_grasp_action(env: GraspEnv) -> np.ndarray:
    """Move the tool tip over the fixation point, then straight down (the env then closes and lifts).

    Reads the simulator's state (the tool tip, the fixation point: the target's true centre).

    Returns:
        (dof,) float32 grasp action; the gripper keeps pointing down and does not turn.
    """
    tip = env.world.arm.tool_tip()
    return scripted_grasp_actions(env.fixation_point[None], tip[None], env.dof)[0]


def scripted_grasp_actions(fixation: np.ndarray, tip: np.ndarray, dof: int) -> np.ndarray:
    """The same policy for a batch: fixation points (N, 3) and tool tips (N, 3) -> actions float32 (N, dof).

    With ``target="env"`` the observation's ``fixation`` is the target's centre as the simulator knows it and
    ``gripper[:, :3]`` the tool tip, so this runs on observations (``apr bench learning``'s ceiling).
    """
    error_xy = np.asarray(fixation, np.float64)[:, :2] - np.asarray(tip, np.float64)[:, :2]
    actions = np.zeros((len(error_xy), dof), dtype=np.float32)
    actions[:, :2] = np.clip(error_xy / GRASP.position_step, -1.0, 1.0)
    actions[:, 2] = np.where(np.linalg.norm(error_xy, axis=1) < DESCEND_WITHIN, -1.0, 0.0)
    return actions
