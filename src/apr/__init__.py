"""APR: Active Perception and Representation for Robotic Manipulation.

Importing ``apr`` registers the environments ``apr/ActiveGrasp-v0`` and ``apr/PassiveGrasp-v0``.
"""

import gymnasium

from apr.quiet import quiet_c_output

with quiet_c_output():  # pybullet prints its build time when first imported
    import pybullet  # noqa: F401

from apr.envs.objects import object_ids  # noqa: E402

__all__ = ["object_ids"]
__version__ = "0.1.0"

gymnasium.register(id="apr/ActiveGrasp-v0", entry_point="apr.envs.grasp_env:ActiveGraspEnv")
gymnasium.register(id="apr/PassiveGrasp-v0", entry_point="apr.envs.grasp_env:PassiveGraspEnv")
