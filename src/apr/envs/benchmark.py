"""The benchmark's own task in apr's world: grasp any object, seen by one static camera (Quillen et al. 2018;
bullet3's ``KukaDiverseObjectEnv``), as ``apr/BenchmarkGrasp-v4``.

The world, the arm, the objects, the 900/100 split, the grasp routine and the 15-step limit are apr's (the same
scene for the same seed as ``apr/PassiveGrasp-v4``); what differs from apr's tasks is the benchmark's: one camera
where the benchmark puts it, no target (the grasp succeeds when any object is lifted), and no reach reward.
"""

from __future__ import annotations

import gymnasium
import numpy as np
import pybullet as p
from gymnasium import spaces

from apr.envs.config import CAMERA, GRASP, SCENE, VERSIONS
from apr.envs.grasp_env import GraspEnv
from apr.envs.rendering import Camera, render
from apr.envs.task import GraspOutcome, GraspTask
from apr.envs.world import GraspWorld

BENCHMARK_ENV_ID = "apr/BenchmarkGrasp-v4"
"""The benchmark's task at the version the other environments share (v4: ``apr.VERSIONS["v4"]``)."""
BENCHMARK_VERSIONS = ("v4",)
"""The versions registered: the task is new at v4, so there is no earlier one to evaluate saved runs on."""

LOOK_POINT = (0.23, 0.2, 0.54)
"""m: the point the benchmark's camera is aimed through (``KukaDiverseObjectEnv.reset``: ``look``)."""
LOOK_DISTANCE = 1.0
"""m from the camera to ``LOOK_POINT`` (benchmark); the tray lies beyond it, about 1.83 m from the camera."""
YAW_DEG, PITCH_DEG, ROLL_DEG = 245.0, -56.0, 0.0
"""The benchmark camera's yaw, pitch and roll (``computeViewMatrixFromYawPitchRoll``, z up), with
``cameraRandom=0``."""
FOV_DEG = 20.0
"""The benchmark camera's vertical field of view."""
FAR = 10.0
"""m: the benchmark's far clipping plane (apr's cameras use ``CAMERA.far``, 3 m, which would clip the floor at the
top of this camera's image)."""
RENDER_SIZE = 128
"""The benchmark's render, resized to the 64x64 observation."""


def benchmark_camera() -> Camera:
    """The benchmark's static camera as an apr :class:`~apr.envs.rendering.Camera`: the eye, line of sight and up
    of bullet3's view matrix (``computeViewMatrixFromYawPitchRoll(LOOK_POINT, 1.0, 245, -56, 0, 2)``), the same
    matrix to float precision. The eye is at about (-0.28, 0.44, 1.37) m, above and behind the arm's base, looking
    down at 56 deg through the tray's middle."""
    view = (
        np.array(
            p.computeViewMatrixFromYawPitchRoll(LOOK_POINT, LOOK_DISTANCE, YAW_DEG, PITCH_DEG, ROLL_DEG, 2), np.float64
        )
        .reshape(4, 4)
        .T
    )  # pybullet's matrices are column-major
    to_world = np.linalg.inv(view)
    return Camera(eye=to_world[:3, 3].copy(), forward=-to_world[:3, 2], up=to_world[:3, 1], fov_deg=FOV_DEG)


class AnyObjectTask(GraspTask):
    """The benchmark's task: no target; a grasp succeeds when any object ends above the success height
    (``KukaDiverseObjectEnv._reward``), and there is no reach reward.

    The tray is filled as in apr's environment-target episodes, draw for draw, so that a seed gives the scene that
    ``apr/PassiveGrasp-v4`` gives it (the same held-out episodes for ``EVAL_SEED + k``).
    """

    def __init__(self, split: str):
        super().__init__("env", split, reach_scale=0.0)

    def reset(self, world: GraspWorld, rng: np.random.Generator) -> np.ndarray:
        """Fill the tray (and draw the target apr's env-target episodes draw, which is then dropped: the last draw
        of a reset, so the scene is theirs); return the bin centre (3,), the episode's reference point for the
        statistics of ``info`` (``tip_fixation_distance``)."""
        super().reset(world, rng)
        self.target_uid = None
        return np.array(SCENE.bin_centre)

    def grasp_outcome(self, world: GraspWorld, tip_at_grasp: np.ndarray, fixation_point: np.ndarray) -> GraspOutcome:
        """Any object lifted is a success."""
        lifted = super().grasp_outcome(world, tip_at_grasp, fixation_point).lifted
        return GraspOutcome(lifted=lifted, success=bool(lifted))


class BenchmarkGraspEnv(GraspEnv):
    """The benchmark's own task in apr's world: grasp any object, seen by one static camera (Quillen et al. 2018,
    "Deep Reinforcement Learning for Vision-Based Robotic Grasping"; bullet3's ``KukaDiverseObjectEnv``).

    A Kuka arm with a two-finger gripper grasps procedurally generated objects from a tray. One camera sees the tray
    and the gripper from where the benchmark puts it: aimed through (0.23, 0.2, 0.54) m from 1 m away at yaw 245
    deg and pitch -56 deg, a field of view of 20 deg, the tray about 1.83 m away filling most of the image, rendered
    at 128x128 and resized to 64x64. There is no target: lifting any object succeeds, as in the benchmark. The
    world, the objects and their split, the grasp routine, the action scales and the 15-step limit are those of
    ``apr/PassiveGrasp-v4``, whose scene it shares for a seed.

    ## Arguments
    ``gymnasium.make("apr/BenchmarkGrasp-v4", dof=4, split="train", renderer="tiny")``

    - ``dof``: 4 (dx, dy, dz, da: the benchmark's continuous action with its "height hack" removed, the gripper
      pointing down; default) or 6 (dx, dy, dz, da, db, dc: apr's full control).
    - ``split``: "train" (at most 5 of the 900 training objects) or "test" (exactly 5 of the 100 held out: the
      held-out protocol of Quillen et al.'s Table 1 and of apr's evaluations).
    - ``renderer``: "tiny" (default), "egl" or "auto", as for ``apr/ActiveGrasp-v4``.
    - ``render_size``: side of the render before the resize to 64x64, a multiple of 64 (default 128, the
      benchmark's).
    - ``limit_in_task``, ``tilted_reach``, ``tilt_about_tip``: the version's task, as for the other environments
      (``apr.VERSIONS["v4"]``, which the id passes).

    ## Action Space
    ``Box(-1, 1, (dof,), float32)``: the change of the gripper's commanded pose, 0.06 m per unit on x, y and z
    (the benchmark's ``dv``) and 0.25 rad per unit on each Euler angle (the benchmark's), as for
    ``apr/PassiveGrasp-v4``. ``a`` turns the gripper about its own axis; at 6-DoF ``b`` and ``c`` tilt it (within 45
    deg of vertical). Entries outside [-1, 1] are clipped; a NaN or infinite entry raises ``ValueError``.

    ## Observation Space
    ``Dict``, the layout of the other environments with one view:

    - ``images``: uint8 (1, 64, 64, 3), the camera's RGB image (no mask: there is no target).
    - ``viewpoints``: float32 (1, 6), the camera's position (m) and unit line of sight (constant).
    - ``gripper``: float32 (9,), the tool tip (x, y, z) in m and sin/cos of the Euler angles (a, b, c).
    - ``steps_left`` (``limit_in_task=True``): ``Discrete(16)``, the grasp steps the episode has left.

    ``info`` holds the simulator's view as in the other environments; its ``fixation_point`` is the bin centre
    (there is no target) and ``tip_fixation_distance`` the tool tip's distance to it.

    ## Rewards
    1 on the step that attempts a grasp when any object ends above z = 0.2 m after the lift (the benchmark's
    reward), else 0. No reach reward (``info["reach_reward"]`` is 0).

    ## Episode End
    Terminated when a grasp is attempted (the tool tip drops to z <= -0.115 m, as the benchmark's end-effector
    trigger z <= 0.1 m; the fingers close and the arm lifts), or after 15 steps without one (the limit is part of
    the task, as in the other v4 environments; the benchmark's own default was 8). ``info["grasp_attempted"]``,
    ``info["grasp_success"]`` and ``info["objects_lifted"]`` tell the outcome.
    """

    def __init__(self, dof: int = 4, split: str = "train", renderer: str = "tiny", render_mode: str | None = None,
                 render_size: int = RENDER_SIZE, limit_in_task: bool = True, tilted_reach: bool = True,
                 tilt_about_tip: bool = False):  # fmt: skip
        super().__init__(dof=dof, target="env", foveation="resize", split=split, renderer=renderer,
                         render_mode=render_mode, with_head=False, reach_scale=0.0, render_size=render_size,
                         reveal_target=False, limit_in_task=limit_in_task, tilted_reach=tilted_reach,
                         tilt_about_tip=tilt_about_tip)  # fmt: skip
        self.task = AnyObjectTask(split)
        self.with_mask = False
        self.camera = benchmark_camera()
        self._viewpoints = np.concatenate([self.camera.eye, self.camera.forward])[None].astype(np.float32)
        size = CAMERA.image_size
        observation = {
            "images": spaces.Box(0, 255, (1, size, size, 3), np.uint8),
            "viewpoints": spaces.Box(-2 * np.pi, 2 * np.pi, (1, 6), np.float32),
            "gripper": spaces.Box(-2.0, 2.0, (9,), np.float32),
        }
        if self.limit_in_task:
            observation["steps_left"] = spaces.Discrete(GRASP.max_grasp_steps + 1)
        self.observation_space = spaces.Dict(observation)

    def _render_views(self) -> tuple[list[np.ndarray], list[np.ndarray | None], np.ndarray]:
        """The camera's raw RGB render (S, S, 3), S = ``render_size``, no mask, and its viewpoint (1, 6)."""
        world = self.world
        world.build()
        rgb, _ = render(world.client, self.camera, world.render_size, world.renderer, CAMERA.near, FAR)
        return [rgb], [None], self._viewpoints.copy()


def register_benchmark_envs() -> list[str]:
    """Register ``apr/BenchmarkGrasp-v4`` (idempotent: an id already registered is left as it is); return the ids.

    Its keyword arguments are the version's task, ``apr.VERSIONS["v4"]``.
    """
    ids = []
    for version in BENCHMARK_VERSIONS:
        env_id = f"apr/BenchmarkGrasp-{version}"
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point="apr.envs.benchmark:BenchmarkGraspEnv", kwargs=VERSIONS[version])
        ids.append(env_id)
    return ids
