"""The physical world: table, tray, Kuka with gripper, objects, the head, and the cameras. No rewards here.

One :class:`GraspWorld` owns one pybullet physics client. Objects come from a pool: a URDF is loaded the first
time its object is needed, then parked (static, collision-free, out of view) between uses and moved back in
when drawn again, so a reset neither reloads meshes nor grows memory without bound.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np
import pybullet as p
import pybullet_data
from pybullet_utils.bullet_client import BulletClient

from apr.envs.config import CAMERA, OBJECTS, PASSIVE_LAYOUTS, PHYSICS, SCENE, PassiveCameras
from apr.envs.head import Head
from apr.envs.objects import object_urdf
from apr.envs.rendering import Camera, claim_renderer, load_egl, release, render
from apr.envs.robot import KukaGripper
from apr.quiet import quiet_c_output


class GraspWorld:
    """The benchmark's scene in one physics client, optionally with the head.

    The scene is built at first use (a reset, a step or a render), not at construction: a process that only
    constructs worlds (``gymnasium.vector.AsyncVectorEnv`` reads the spaces of one) never loads EGL, so the
    processes it forks can (``apr.envs.rendering``). An explicit ``renderer="egl"`` builds at once, so that an
    unusable EGL fails at construction.

    Args:
        renderer: "tiny" (any number of worlds per process), "egl" (one EGL world per process) or "auto" (EGL if
            its plugin loads, else TinyRenderer; never both in one process).
        with_head: load the xArm6 head (the active model); the passive model has none.
        render_size: side of every render in pixels (the paper: 256).
        tilted_reach: the workspace's lower bound holds the tool tip, not the end-effector link
            (:class:`apr.envs.robot.KukaGripper`).
        tilt_about_tip: a change of tilt turns the gripper about its tool tip, not the end-effector link.
    """

    def __init__(self, renderer: str = "tiny", with_head: bool = True, render_size: int = CAMERA.render_size,
                 tilted_reach: bool = True, tilt_about_tip: bool = True):  # fmt: skip
        with quiet_c_output():  # pybullet prints argv[0] on connect
            self.client: BulletClient | None = BulletClient(connection_mode=p.DIRECT)
        self.renderer = claim_renderer(self, renderer)
        """The renderer in use: "egl" or "tiny" ("egl" may still fall back to "tiny" at first use with "auto")."""
        self._requested = renderer
        self._with_head = with_head
        self._tilted_reach = tilted_reach
        self._tilt_about_tip = tilt_about_tip
        self.render_size = render_size
        self._built = False
        self._pool: OrderedDict[int, int] = OrderedDict()  # object number -> body uid, least recent first
        self._inertia: dict[int, tuple[float, float, float]] = {}
        self.object_uids: list[int] = []
        """Bodies of the objects in the scene this episode."""
        self.object_numbers: list[int] = []
        if renderer == "egl":
            self.build()

    def build(self) -> None:
        """Load the renderer and the scene (done at first use; idempotent)."""
        if self._built:
            return
        self._built = True
        c = self.client
        if c is None:
            raise RuntimeError("this world is closed")
        # The renderer first: pybullet's EGL plugin only draws bodies loaded after it.
        if self.renderer == "egl" and not load_egl(self, c, self._requested):
            self.renderer = "tiny"
        c.setAdditionalSearchPath(pybullet_data.getDataPath())
        # Sorted contact pairs: the solver order no longer depends on which objects the pool loaded before.
        c.setPhysicsEngineParameter(numSolverIterations=PHYSICS.solver_iterations, deterministicOverlappingPairs=1)
        c.setTimeStep(PHYSICS.time_step)
        c.setGravity(0, 0, PHYSICS.gravity)
        c.loadURDF("plane.urdf", (0, 0, -1))
        self._table_uid = c.loadURDF("table/table.urdf", SCENE.table_position)
        self._tray_uid = c.loadURDF("tray/tray.urdf", SCENE.tray_position, SCENE.tray_orientation)
        self._arm = KukaGripper(c, f"{pybullet_data.getDataPath()}/kuka_iiwa/kuka_with_gripper2.sdf",
                                tilted_reach=self._tilted_reach, tilt_about_tip=self._tilt_about_tip)  # fmt: skip
        self._head = Head(c) if self._with_head else None
        if self.renderer == "egl":
            # The EGL renderer's first frames lack the shadows of later ones; render them now, so that an
            # episode's images do not depend on whether it is the first in this world.
            for camera in passive_cameras()[:2]:
                self.render(camera)

    @property
    def arm(self) -> KukaGripper:
        self.build()
        return self._arm

    @property
    def head(self) -> Head | None:
        self.build()
        return self._head

    @property
    def table_uid(self) -> int:
        self.build()
        return self._table_uid

    @property
    def tray_uid(self) -> int:
        self.build()
        return self._tray_uid

    def close(self) -> None:
        if getattr(self, "client", None) is not None:
            release(self, self.client)
            self.client = None

    def __del__(self) -> None:
        self.close()

    # ----------------------------------------------------------------------------------------------- physics
    def step_simulation(self, steps: int = 1) -> None:
        self.build()
        for _ in range(steps):
            self.client.stepSimulation()

    def reset_scene(self, numbers: Sequence[int], rng: np.random.Generator, all_in_tray: bool) -> None:
        """Reset the arm and the head, then drop the objects ``numbers`` into the tray and let them settle.

        Objects that land outside the tray are dropped again when ``all_in_tray`` (evaluation: exactly as many
        objects as asked), and removed otherwise (training: at most as many).
        """
        self.arm.reset()
        if self.head is not None:
            self.head.reset()
        for uid in self.object_uids:
            self._park(uid)
        uids = [self._acquire(number) for number in numbers]
        self.object_uids, self.object_numbers = list(uids), list(numbers)
        to_drop = list(uids)
        for _ in range(5 if all_in_tray else 1):
            self._drop(to_drop, rng)
            to_drop = [uid for uid in to_drop if not self._in_tray(uid)]
            if not to_drop:
                break
        for uid in to_drop:
            index = self.object_uids.index(uid)
            del self.object_uids[index], self.object_numbers[index]
            self._park(uid)

    def object_position(self, uid: int) -> np.ndarray:
        return np.array(self.client.getBasePositionAndOrientation(uid)[0])

    def object_centre(self, uid: int) -> np.ndarray:
        """(3,) centre of the object's axis-aligned bounding box (m)."""
        low, high = self.client.getAABB(uid)
        return 0.5 * (np.array(low) + np.array(high))

    def _drop(self, uids: Sequence[int], rng: np.random.Generator) -> None:
        placed: list[np.ndarray] = []
        for uid in uids:
            xy = self._draw_drop_xy(rng, placed)
            placed.append(xy)
            yaw = rng.uniform(0.0, 2.0 * np.pi)
            orientation = self.client.getQuaternionFromEuler((0.0, 0.0, yaw))
            self._unpark(uid, (xy[0], xy[1], OBJECTS.drop_z), orientation)
        self._settle(uids)

    def _draw_drop_xy(self, rng: np.random.Generator, placed: list[np.ndarray]) -> np.ndarray:
        """The benchmark's drop distribution, redrawn while closer than ``min_spacing`` to an earlier object."""
        xy = np.zeros(2)
        for _ in range(100):
            xy = np.array([
                OBJECTS.drop_x[0] + OBJECTS.drop_x[1] * rng.uniform(),
                OBJECTS.drop_y_width * (rng.uniform() - 0.5),
            ])  # fmt: skip
            if all(np.linalg.norm(xy - other) >= OBJECTS.min_spacing for other in placed):
                break
        return xy

    def _settle(self, uids: Sequence[int]) -> None:
        """Step until every object in ``uids`` is at rest (or ``settle_steps_max`` steps)."""
        for _ in range(0, OBJECTS.settle_steps_max, OBJECTS.settle_check_every):
            self.step_simulation(OBJECTS.settle_check_every)
            velocities = [self.client.getBaseVelocity(uid) for uid in uids]
            moving = any(np.abs(linear).max() >= OBJECTS.settle_speed for linear, _ in velocities)
            turning = any(np.abs(angular).max() >= OBJECTS.settle_spin for _, angular in velocities)
            if not (moving or turning):
                return

    def _in_tray(self, uid: int) -> bool:
        x, y, z = self.object_position(uid)
        low, high = self.client.getAABB(uid)
        return (
            OBJECTS.tray_inner_x[0] <= x <= OBJECTS.tray_inner_x[1]
            and OBJECTS.tray_inner_y[0] <= y <= OBJECTS.tray_inner_y[1]
            and z >= OBJECTS.tray_floor_z_min
            and bool(np.isfinite([*low, *high]).all())
        )

    # ------------------------------------------------------------------------------------------- object pool
    def _acquire(self, number: int) -> int:
        """The body of object ``number``: from the pool, or loaded (the least recently used is unloaded)."""
        if number in self._pool:
            self._pool.move_to_end(number)
            return self._pool[number]
        if len(self._pool) >= OBJECTS.pool_size:
            _, evicted = self._pool.popitem(last=False)
            self.client.removeBody(evicted)
            del self._inertia[evicted]
        uid = self.client.loadURDF(object_urdf(number), OBJECTS.park_position)
        self._inertia[uid] = self.client.getDynamicsInfo(uid, -1)[2]
        self._pool[number] = uid
        self._park(uid)
        return uid

    def _park(self, uid: int) -> None:
        c = self.client
        c.changeDynamics(uid, -1, mass=0.0)
        c.setCollisionFilterGroupMask(uid, -1, 0, 0)
        c.resetBasePositionAndOrientation(uid, OBJECTS.park_position, (0, 0, 0, 1))

    def _unpark(self, uid: int, position: Sequence[float], orientation: Sequence[float]) -> None:
        c = self.client
        c.resetBasePositionAndOrientation(uid, position, orientation)
        c.resetBaseVelocity(uid, (0, 0, 0), (0, 0, 0))
        c.changeDynamics(uid, -1, mass=OBJECTS.mass, localInertiaDiagonal=self._inertia[uid])
        c.setCollisionFilterGroupMask(uid, -1, 1, -1)

    # --------------------------------------------------------------------------------------------- rendering
    def render(
        self, camera: Camera, segmentation: bool = False, from_head: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """RGB (uint8, (S, S, 3)) and, when asked, body ids (int32, (S, S)) seen by ``camera``; S =
        ``render_size``.

        ``from_head``: the camera is the head's own. The head never appears in its own views (0 of 120 views
        measured, bitwise; docs/decisions.md), so TinyRenderer then renders without it, a third less CPU time;
        EGL keeps it, since it casts shadows into the scene.
        """
        self.build()
        if self._head is not None and self.renderer == "tiny":
            self._head.set_visible(not from_head)
        return render(self.client, camera, self.render_size, self.renderer, CAMERA.near, CAMERA.far, segmentation)


def passive_cameras(layout: PassiveCameras = "sides") -> list[Camera]:
    """The passive model's three static cameras: they see the tray and the gripper, with no attention.

    Args:
        layout: "sides" (v4): framed on the tray as the benchmark's camera is (a field of view of 20 deg, the tray's
            floor filling the image) from its front, left and right; "front": so framed, all three from its front,
            20 deg apart; "wide" (v0-v3): 50 deg, the tray a third of the image.
    """
    if layout == "wide":
        return [_camera_at(np.array(eye), np.array(CAMERA.passive_target), CAMERA.passive_fov_deg)
                for eye in CAMERA.passive_eyes]  # fmt: skip
    if layout == "sides":
        placements = zip(CAMERA.tray_azimuths_deg, CAMERA.tray_distances, strict=True)
    elif layout == "front":
        placements = zip(CAMERA.front_azimuths_deg, CAMERA.front_distances, strict=True)
    else:
        raise ValueError(f"layout must be one of {PASSIVE_LAYOUTS}, got {layout!r}")
    aim, elevation = np.array(CAMERA.tray_aim), math.radians(CAMERA.tray_elevation_deg)
    cameras = []
    for azimuth, distance in placements:
        azimuth = math.radians(azimuth)
        away = np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                         math.sin(elevation)])  # fmt: skip
        cameras.append(_camera_at(aim + distance * away, aim, CAMERA.tray_fov_deg))
    return cameras


def _camera_at(eye: np.ndarray, target: np.ndarray, fov_deg: float) -> Camera:
    """A camera at ``eye`` looking at ``target``, the image's up as near the world's up as its line of sight
    allows."""
    forward = (target - eye) / np.linalg.norm(target - eye)
    up = np.array([0.0, 0.0, 1.0]) - forward[2] * forward
    return Camera(eye=eye, forward=forward, up=up / np.linalg.norm(up), fov_deg=fov_deg)
