"""APR: Active Perception and Representation for Robotic Manipulation.

Importing ``apr`` registers the environments ``apr/ActiveGrasp-v2`` and ``apr/PassiveGrasp-v2`` (the 15-step limit
is part of the task: it terminates, and the observation has the steps left; the workspace's floor holds the tool
tip, so a tilted gripper can reach the grasp height), their ``-v3`` (a change of tilt turns the gripper about its tool
tip rather than its wrist), and their earlier versions, which runs trained on them still evaluate on: ``-v1`` (the
floor holds the end-effector link) and ``-v0`` (also the limit truncates, no clock).
"""

import warnings

import gymnasium

from apr.quiet import quiet_c_output

with quiet_c_output():  # pybullet prints its build time when first imported
    import pybullet  # noqa: F401

from apr.envs.objects import object_ids  # noqa: E402

__all__ = ["object_ids"]
__version__ = "0.1.0"

for version, limit_in_task, tilted_reach, tilt_about_tip in (
    ("v0", False, False, False),
    ("v1", True, False, False),
    ("v2", True, True, False),
    ("v3", True, True, True),
):
    kwargs = {"limit_in_task": limit_in_task, "tilted_reach": tilted_reach, "tilt_about_tip": tilt_about_tip}
    for name, entry_point in (("ActiveGrasp", "ActiveGraspEnv"), ("PassiveGrasp", "PassiveGraspEnv")):
        gymnasium.register(id=f"apr/{name}-{version}", entry_point=f"apr.envs.grasp_env:{entry_point}", kwargs=kwargs)
# Runs saved before v3 name v0, v1 or v2: evaluating them is expected, not a sign of an outdated setup.
warnings.filterwarnings("ignore", message=r".*apr/(Active|Passive)Grasp-v[012] is out of date")
