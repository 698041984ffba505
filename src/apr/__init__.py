"""APR: Active Perception and Representation for Robotic Manipulation.

Importing ``apr`` registers the environments ``apr/ActiveGrasp-v4``, ``apr/PassiveGrasp-v4`` and
``apr/BenchmarkGrasp-v4``, the versions to use, and the earlier versions of the first two, which runs trained on them
still evaluate on (:data:`VERSIONS`; docs/environments.md, "Versions").
"""

import warnings

import gymnasium

from apr.quiet import quiet_c_output

with quiet_c_output():  # pybullet prints its build time when first imported
    import pybullet  # noqa: F401

from apr.envs.benchmark import register_benchmark_envs  # noqa: E402
from apr.envs.config import PASSIVE_CAMERAS, VERSIONS  # noqa: E402
from apr.envs.objects import object_ids  # noqa: E402

__all__ = ["PASSIVE_CAMERAS", "VERSIONS", "object_ids"]
__version__ = "0.1.0"

for version, kwargs in VERSIONS.items():
    gymnasium.register(id=f"apr/ActiveGrasp-{version}", entry_point="apr.envs.grasp_env:ActiveGraspEnv",
                       kwargs=kwargs)  # fmt: skip
    gymnasium.register(id=f"apr/PassiveGrasp-{version}", entry_point="apr.envs.grasp_env:PassiveGraspEnv",
                       kwargs={**kwargs, "cameras": PASSIVE_CAMERAS[version]})  # fmt: skip
register_benchmark_envs()  # apr/BenchmarkGrasp-v4, the benchmark's own task
# Runs saved before v4 name v0-v3: evaluating them is expected, not a sign of an outdated setup.
warnings.filterwarnings("ignore", message=r".*apr/(Active|Passive)Grasp-v[0123] is out of date")
