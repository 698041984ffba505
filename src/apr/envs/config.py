"""Every constant of the grasping world in one place, each with where it comes from.

"Benchmark" is the simulated grasping benchmark APR extends (Quillen et al. 2018; bullet3's
``kuka_diverse_object_gym_env.py`` and ``kuka.py``). "Paper" is APR (Zaky et al.), Method A. Anything marked
"ours" is a choice the paper leaves open; ``docs/decisions.md`` gives the reason for each.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, get_args

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class PhysicsSpec:
    """Simulation settings (benchmark)."""

    time_step: float = 1.0 / 240.0
    gravity: float = -10.0
    solver_iterations: int = 150
    action_repeat: int = 80
    """Simulation steps per agent action, on every step including the last (benchmark; its defect fixed)."""


@dataclass(frozen=True)
class SceneSpec:
    """Where things stand (benchmark, plus the head and the passive cameras)."""

    table_position: Vec3 = (0.5, 0.0, -0.82)
    tray_position: Vec3 = (0.64, 0.075, -0.19)
    tray_orientation: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 0.0)
    kuka_base_position: Vec3 = (-0.1, 0.0, 0.07)
    head_base_position: Vec3 = (1.12, 0.075, -0.194)
    """ours: the xArm6 stands on the table on the far side of the tray, facing the Kuka."""
    bin_centre: Vec3 = (0.55, 0.0, -0.15)
    """ours: the initial fixation point, the centre of the object drop area at object height."""


@dataclass(frozen=True)
class ObjectSpec:
    """The procedurally generated objects and how they are dropped (benchmark)."""

    mass: float = 0.1
    drop_x: tuple[float, float] = (0.4, 0.3)
    """x = drop_x[0] + drop_x[1] * U."""
    drop_y_width: float = 0.3
    """y = drop_y_width * (U - 0.5)."""
    drop_z: float = 0.15
    min_spacing: float = 0.08
    """ours: objects dropped together are at least this far apart in xy (no interpenetration at spawn)."""
    settle_steps_max: int = 600
    """ours: after this many steps objects move by at most ~1 mm more (measured); the benchmark took 500 each."""
    settle_check_every: int = 20
    settle_speed: float = 0.02
    """ours: the drop has settled when every object moves slower than this (m/s) ..."""
    settle_spin: float = 0.3
    """... and turns slower than this (rad/s: 1.5 cm/s at the rim of a 5 cm object)."""
    tray_inner_x: tuple[float, float] = (0.36, 0.92)
    tray_inner_y: tuple[float, float] = (-0.23, 0.35)
    """ours: an object whose base is outside this xy box after settling has fallen out of the tray."""
    tray_floor_z_min: float = -0.3
    """ours: an object whose base is below this z after settling (or whose bounding box is not finite) has fallen
    through the tray floor (about 1 drop in 1000 of the training objects)."""
    park_position: Vec3 = (0.0, 0.0, -50.0)
    """ours: where unused objects of the pool wait (static, collision-free, out of every view)."""
    pool_size: int = 8
    """ours: the most objects kept loaded; the least recently used is unloaded beyond that. Small on purpose:
    with 900 objects a pooled one is rarely drawn again, and every parked body is still processed by each
    render (200 parked objects doubled the EGL render time; docs/benchmarks.md)."""


@dataclass(frozen=True)
class ArmSpec:
    """The Kuka iiwa with its WSG gripper and its Cartesian controller (benchmark ``kuka.py``)."""

    initial_joint_positions: tuple[float, ...] = (
        0.006418, 0.413184, -0.011401, -1.589317, 0.005379, 1.137684, -0.006539,
        0.000048, -0.299912, 0.0, -0.000043, 0.299960, 0.0, -0.0002,
    )  # fmt: skip
    end_effector_link: int = 6
    gripper_yaw_joint: int = 7
    finger_joints: tuple[int, int] = (8, 11)
    fingertip_joints: tuple[int, int] = (10, 13)
    gripper_links: tuple[int, ...] = (7, 8, 9, 10, 11, 12, 13)
    initial_end_effector_position: Vec3 = (0.537, 0.0, 0.5)
    max_force: float = 200.0
    position_gain: float = 0.03
    velocity_gain: float = 1.0
    finger_a_force: float = 6.0
    finger_b_force: float = 5.5
    fingertip_force: float = 6.0
    finger_open: float = 0.3
    workspace_x: tuple[float, float] = (0.38, 0.75)
    workspace_y: tuple[float, float] = (-0.22, 0.22)
    workspace_z: tuple[float, float] = (0.05, 0.55)
    """Commanded end-effector bounds: y from the benchmark; z ours (start height 0.5, room to descend); x ours: the
    benchmark's 0.45 lower bound left 17% of the objects (dropped over x in [0.40, 0.70]) out of reach."""
    max_tilt: float = math.pi / 4
    """ours: |b| and |c| (tilts of the gripper away from pointing down) are clipped to this, in rad."""
    tip_below_end_effector: float = 0.22
    """m from the end-effector link down to the tool tip when the gripper points down (0.217 measured at reset).
    Tilted by b and c, the tip hangs about this times cos(b) cos(c) below the link."""


@dataclass(frozen=True)
class GraspSpec:
    """The grasp routine and the success test (benchmark), the episode length (paper)."""

    position_step: float = 0.06
    """m per unit action per axis (benchmark)."""
    angle_step: float = 0.25
    """rad per unit action per Euler angle (benchmark, extended to the paper's three angles)."""
    grasp_height: float = -0.115
    """A grasp is initiated when the tool tip (midpoint of the fingertips) is at or below this z. The
    benchmark's trigger is end-effector z <= 0.1; its fingertips hang 0.215 m lower when pointing down."""
    close_steps: int = 500
    lift_steps: int = 500
    lift_speed: float = 0.001
    """m the end-effector target rises per simulation step of the lift (benchmark)."""
    success_height: float = 0.2
    """An object is lifted when its base ends above this z (benchmark)."""
    max_grasp_steps: int = 15
    """Paper: a grasp episode lasts at most 15 steps."""


@dataclass(frozen=True)
class HeadSpec:
    """The head: an xArm6 carrying a camera on its wrist, and how views are sampled (ours within the paper)."""

    camera_link: int = 6
    camera_offset: float = 0.03
    """m from the flange to the optical centre, along the flange normal."""
    yaw_range: tuple[float, float] = (-0.7, 0.7)
    """rad, azimuth of the camera around the fixation point, 0 = on the +x side (facing the Kuka)."""
    pitch_range: tuple[float, float] = (0.6, 1.1)
    """rad, elevation of the camera above the fixation point's horizontal plane."""
    distance_range: tuple[float, float] = (0.32, 0.45)
    """m from the camera to the fixation point."""
    fov_deg: float = 60.0
    ik_iterations: int = 4
    """Refinement passes of the IK (each resets the joints to the last solution and solves again)."""
    fixed_initial_views: tuple[tuple[float, float, float], ...] = ((-0.35, 0.85, 0.385), (0.35, 0.85, 0.385),
                                                                   (0.0, 0.85, 0.385))  # fmt: skip
    """ours: (yaw, pitch, distance) of views 0, 1 and 2 at reset with ``initial_views="fixed"``: the middle of the
    ranges' pitch and distance, yaw half-way to either end, so views 0 and 1 see the tray from two fixed sides."""
    max_pose_tries: int = 8
    """Viewpoints drawn until one is reached with its line of sight within ``max_sight_error``."""
    max_sight_error: float = 0.01
    rest_joint_positions: tuple[float, ...] = (0.0, -0.3, -1.0, 0.0, 1.3, 0.0)


@dataclass(frozen=True)
class CameraSpec:
    """Rendering and the observation images (paper, SPEC section 2)."""

    render_size: int = 256
    image_size: int = 64
    near: float = 0.01
    far: float = 3.0
    views_per_step: int = 3
    tray_fov_deg: float = 20.0
    """The passive cameras' field of view from v4 on (benchmark: ``KukaDiverseObjectEnv``'s camera, 20 deg)."""
    tray_aim: Vec3 = (0.64, 0.06, -0.19)
    """ours: where the passive cameras look from v4 on: the middle of the tray's floor."""
    tray_elevation_deg: float = 56.0
    """How far above the horizontal the passive cameras look down from v4 on (benchmark: its camera's pitch, -56
    deg)."""
    tray_azimuths_deg: tuple[float, float, float] = (0.0, 90.0, -90.0)
    """ours: v4's passive cameras' directions from ``tray_aim``, about the vertical from +x: the front (facing the
    Kuka), the left and the right of the tray."""
    tray_distances: tuple[float, float, float] = (1.43, 1.38, 1.38)
    """m from ``tray_aim`` to each of v4's passive cameras (ours): the nearest at which the four corners of the
    tray's floor (x 0.43-0.85, y -0.16-0.28 m) lie within the middle 95% of the image, so that the tray fills it,
    as the benchmark's camera frames it (docs/decisions.md, "The passive cameras")."""
    front_azimuths_deg: tuple[float, float, float] = (-20.0, 20.0, 0.0)
    """ours: the directions of the passive cameras of ``cameras="front"`` (an option, no version's), all from the
    front: those of the head's fixed views at reset (``HeadSpec.fixed_initial_views``, yaw -0.35, 0.35 and 0 rad), so
    that the GQN predicts one view from two that differ by a small turn, not a quarter turn. Measured: its GQN keeps
    the target no better than v4's (docs/investigations.md, "The passive cameras framed on the tray")."""
    front_distances: tuple[float, float, float] = (1.74, 1.74, 1.44)
    """m from ``tray_aim`` to each camera of ``cameras="front"``: the nearest that frame the tray's floor as
    ``tray_distances`` do."""
    passive_fov_deg: float = 50.0
    """v0-v3's passive cameras (ours): field of view."""
    passive_target: Vec3 = (0.62, 0.05, -0.05)
    """v0-v3's passive cameras (ours): where they look, between the tray floor and the gripper's start."""
    passive_eyes: tuple[Vec3, Vec3, Vec3] = ((1.35, 0.05, 0.45), (0.75, 0.85, 0.5), (0.75, -0.75, 0.5))
    """v0-v3's passive cameras (ours): front (facing the Kuka), left and right of the tray, each about 0.9-1 m away
    and 30-45 deg up; the tray covers about a third of each image, an object a few pixels."""


@dataclass(frozen=True)
class RewardSpec:
    """Rewards (paper, Method A; the reach formula is ours)."""

    fixation_radius: float = 0.10
    """Learned fixation: the grasp counts only if the tool tip was within this of the fixation point."""
    reach_scale: float = 1.0
    """Dense reach reward per step = reach_scale * (d_before - d_after), d = tool tip to fixation point (m).
    The default of the environment; training presets set their own (``EnvConfig.reach_scale``)."""
    workspace_low: Vec3 = (0.38, -0.2, -0.2)
    workspace_high: Vec3 = (0.75, 0.2, -0.05)
    """Learned fixation: the action in [-1, 1]^3 maps linearly onto this box (m): the drop area (x 0.40-0.70,
    |y| <= 0.15) with a margin, within the arm's reach, from the tray floor up to where a grasp can still count
    (a grasp starts with the tip at z <= -0.115 and must be within 0.10 m of the fixation point)."""


PHYSICS = PhysicsSpec()
SCENE = SceneSpec()
OBJECTS = ObjectSpec()
ARM = ArmSpec()
GRASP = GraspSpec()
HEAD = HeadSpec()
CAMERA = CameraSpec()
REWARD = RewardSpec()


VERSIONS: dict[str, dict[str, bool]] = {
    "v0": {"limit_in_task": False, "tilted_reach": False, "tilt_about_tip": False},
    "v1": {"limit_in_task": True, "tilted_reach": False, "tilt_about_tip": False},
    "v2": {"limit_in_task": True, "tilted_reach": True, "tilt_about_tip": False},
    "v3": {"limit_in_task": True, "tilted_reach": True, "tilt_about_tip": True},
    "v4": {"limit_in_task": True, "tilted_reach": True, "tilt_about_tip": False},
}
"""Each version's task, as keyword arguments of the environments (docs/environments.md, "Versions"): v1 puts the
15-step limit in the task, v2 lets a tilted gripper reach the grasp height, v3 turns it about its tool tip (measured,
not carried on), v4 frames the passive cameras on the tray (:data:`PASSIVE_CAMERAS`)."""
PassiveCameras = Literal["wide", "sides", "front"]
PASSIVE_LAYOUTS: tuple[PassiveCameras, ...] = get_args(PassiveCameras)
"""Every layout of the passive cameras (:func:`apr.envs.world.passive_cameras`)."""
PASSIVE_CAMERAS: dict[str, PassiveCameras] = {"v0": "wide", "v1": "wide", "v2": "wide", "v3": "wide", "v4": "sides"}
"""The passive model's cameras by version (:func:`apr.envs.world.passive_cameras`): "wide" (v0-v3: 50 deg, the tray a
third of each image), "sides" (v4: framed on the tray from its front, left and right). "front" (framed on the tray,
all three from its front, 20 deg apart) is an option of the environment (``cameras="front"``), no version's."""
