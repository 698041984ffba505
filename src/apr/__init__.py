"""APR: Active Perception and Representation for Robotic Manipulation.

Importing ``apr`` registers the environments ``apr/ActiveGrasp-v0`` and ``apr/PassiveGrasp-v0``.
"""

import gymnasium

from apr.envs.objects import object_ids

__all__ = ["object_ids"]
__version__ = "0.1.0"

gymnasium.register(id="apr/ActiveGrasp-v0", entry_point="apr.envs.grasp_env:ActiveGraspEnv")
gymnasium.register(id="apr/PassiveGrasp-v0", entry_point="apr.envs.grasp_env:PassiveGraspEnv")
