"""APR: Active Perception and Representation for Robotic Manipulation.

Importing ``apr`` registers the environments ``apr/ActiveGrasp-v1`` and ``apr/PassiveGrasp-v1`` (the 15-step limit
is part of the task: it terminates, and the observation has the steps left), and their earlier versions ``-v0``
(the limit truncates, no clock in the observation), which runs trained on them still evaluate on.
"""

import warnings

import gymnasium

from apr.quiet import quiet_c_output

with quiet_c_output():  # pybullet prints its build time when first imported
    import pybullet  # noqa: F401

from apr.envs.objects import object_ids  # noqa: E402

__all__ = ["object_ids"]
__version__ = "0.1.0"

for version, limit_in_task in (("v0", False), ("v1", True)):
    gymnasium.register(id=f"apr/ActiveGrasp-{version}", entry_point="apr.envs.grasp_env:ActiveGraspEnv",
                       kwargs={"limit_in_task": limit_in_task})  # fmt: skip
    gymnasium.register(id=f"apr/PassiveGrasp-{version}", entry_point="apr.envs.grasp_env:PassiveGraspEnv",
                       kwargs={"limit_in_task": limit_in_task})  # fmt: skip
# Runs saved before v1 name v0: evaluating them is expected, not a sign of an outdated setup.
warnings.filterwarnings("ignore", message=r".*apr/(Active|Passive)Grasp-v0 is out of date")
