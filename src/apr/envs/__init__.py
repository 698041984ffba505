"""APR's grasping world as Gymnasium environments (registered when ``apr`` is imported)."""

from apr.envs.grasp_env import ActiveGraspEnv, GraspEnv, PassiveGraspEnv
from apr.envs.objects import object_ids

__all__ = ["ActiveGraspEnv", "GraspEnv", "PassiveGraspEnv", "object_ids"]
