"""A scripted reach-and-grasp policy: proof that the world is solvable, and a driver for pictures and benchmarks."""

from __future__ import annotations

import numpy as np

from apr.envs.config import GRASP
from apr.envs.grasp_env import GraspEnv

DESCEND_WITHIN = 0.02
"""m: the gripper descends once the tool tip is this close to the fixation point in xy."""


def scripted_grasp_action(env: GraspEnv) -> np.ndarray:
    """Move the tool tip over the fixation point, then straight down (the env then closes and lifts).

    Reads the simulator's state (the tool tip, the fixation point), which a learning agent never sees.

    Returns:
        (dof,) float32 grasp action; the gripper keeps pointing down and does not turn.
    """
    tip = env.world.arm.tool_tip()
    error_xy = env.fixation_point[:2] - tip[:2]
    action = np.zeros(env.dof, dtype=np.float32)
    action[:2] = np.clip(error_xy / GRASP.position_step, -1.0, 1.0)
    action[2] = -1.0 if np.linalg.norm(error_xy) < DESCEND_WITHIN else 0.0
    return action
