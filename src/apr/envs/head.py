"""The head: an xArm6 with a camera on its wrist, pointed at a fixation point.

Given a fixation point, a viewpoint is drawn on a sphere around it (yaw, pitch and distance uniform in fixed
ranges, the line of sight through the point), inverse kinematics moves the head there, and the camera is
placed where the head actually got to. The view parameters ``v`` are the six joint angles actually reached.

The head moves kinematically (its joints are set to the IK solution) and has no collisions: it carries a
camera and never touches the scene.
"""

from __future__ import annotations

import math

import numpy as np
import pybullet_data
from pybullet_utils.bullet_client import BulletClient

from apr.envs.config import HEAD, SCENE, HeadSpec
from apr.envs.rendering import Camera


class Head:
    """The camera-carrying arm. All randomness comes from the generator passed to :meth:`look_at`."""

    def __init__(self, client: BulletClient, spec: HeadSpec = HEAD):
        self.client = client
        self.spec = spec
        facing_kuka = client.getQuaternionFromEuler((0.0, 0.0, math.pi))
        urdf = f"{pybullet_data.getDataPath()}/xarm/xarm6_robot.urdf"
        self.uid = client.loadURDF(urdf, SCENE.head_base_position, facing_kuka, useFixedBase=True)
        for link in range(-1, client.getNumJoints(self.uid)):
            client.setCollisionFilterGroupMask(self.uid, link, 0, 0)
        self.joints = [j for j in range(client.getNumJoints(self.uid)) if client.getJointInfo(self.uid, j)[2] == 0]
        if len(self.joints) != 6:
            raise RuntimeError(f"the head should have 6 revolute joints, found {len(self.joints)}")
        self._colors = {shape[1]: shape[7] for shape in client.getVisualShapeData(self.uid)}
        """Link -> RGBA of the head's visual shapes, to show it again after :meth:`set_visible`."""
        self.visible = True
        self.reset()

    def set_visible(self, visible: bool) -> None:
        """Show or hide the head's visual shapes (hidden ones cost TinyRenderer nothing; physics is unaffected)."""
        if visible == self.visible:
            return
        for link, color in self._colors.items():
            self.client.changeVisualShape(self.uid, link, rgbaColor=color if visible else (0.0, 0.0, 0.0, 0.0))
        self.visible = visible

    def reset(self) -> None:
        """Put the head back in its rest pose."""
        self._set_joints(np.array(self.spec.rest_joint_positions))

    def joint_angles(self) -> np.ndarray:
        """(6,) float32 view parameters v = (j1, ..., j6) as reached (rad)."""
        return np.array([self.client.getJointState(self.uid, j)[0] for j in self.joints], dtype=np.float32)

    def look_at(self, point: np.ndarray, rng: np.random.Generator) -> tuple[Camera, np.ndarray]:
        """Draw a viewpoint around ``point``, move the head there, and return the camera it reached.

        Viewpoints are drawn until one is reached with its line of sight within ``max_sight_error`` of the
        point (at most ``max_pose_tries``); the best one reached is kept.

        Returns:
            camera: the camera at the reached pose.
            joints: (6,) float32 view parameters v.
        """
        point = np.asarray(point, dtype=np.float64)
        best: tuple[float, np.ndarray] | None = None
        for _ in range(self.spec.max_pose_tries):
            yaw = rng.uniform(*self.spec.yaw_range)
            pitch = rng.uniform(*self.spec.pitch_range)
            distance = rng.uniform(*self.spec.distance_range)
            solution = self._solve(point, yaw, pitch, distance)  # leaves the head at the solution
            error = self.camera().sight_error(point)
            if best is None or error < best[0]:
                best = (error, solution)
            if error <= self.spec.max_sight_error:
                break
        assert best is not None
        self._set_joints(best[1])
        return self.camera(), self.joint_angles()

    def look_from(self, point: np.ndarray, yaw: float, pitch: float, distance: float) -> tuple[Camera, np.ndarray]:
        """Move the head to the viewpoint (yaw, pitch, distance) around ``point``, no draw; as :meth:`look_at`."""
        self._solve(np.asarray(point, dtype=np.float64), yaw, pitch, distance)
        return self.camera(), self.joint_angles()

    def camera(self) -> Camera:
        """The camera at the head's current pose: it looks along the flange normal, image up is the flange's -x."""
        state = self.client.getLinkState(self.uid, self.spec.camera_link, computeForwardKinematics=True)
        position, orientation = np.array(state[4]), state[5]
        axes = np.array(self.client.getMatrixFromQuaternion(orientation)).reshape(3, 3)  # columns: x, y, z
        forward, up = axes[:, 2], -axes[:, 0]
        return Camera(eye=position + self.spec.camera_offset * forward, forward=forward, up=up,
                      fov_deg=self.spec.fov_deg)  # fmt: skip

    def _solve(self, point: np.ndarray, yaw: float, pitch: float, distance: float) -> np.ndarray:
        """Joint angles that put the camera at (yaw, pitch, distance) from ``point``, looking at it."""
        outward = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)])
        forward = -outward
        up = np.array([0.0, 0.0, 1.0]) - forward[2] * forward  # world up, made perpendicular to the sight line
        up /= np.linalg.norm(up)
        x_axis = -up
        y_axis = np.cross(forward, x_axis)
        flange = point + distance * outward - self.spec.camera_offset * forward
        orientation = _quaternion_from_axes(x_axis, y_axis, forward)
        self._set_joints(np.array(self.spec.rest_joint_positions))  # the same start: the solution is history-free
        solution = np.zeros(6)
        for _ in range(self.spec.ik_iterations):
            angles = self.client.calculateInverseKinematics(
                self.uid, self.spec.camera_link, flange, orientation, maxNumIterations=100, residualThreshold=1e-5
            )
            solution = np.array(angles)
            self._set_joints(solution)
        return solution

    def _set_joints(self, angles: np.ndarray) -> None:
        for joint, angle in zip(self.joints, angles, strict=True):
            self.client.resetJointState(self.uid, joint, float(angle))


def _quaternion_from_axes(x_axis: np.ndarray, y_axis: np.ndarray, z_axis: np.ndarray) -> tuple[float, ...]:
    """Quaternion (x, y, z, w) of the rotation whose columns are the given orthonormal axes."""
    m = np.stack([x_axis, y_axis, z_axis], axis=1)
    trace = np.trace(m)
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        return ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    i = int(np.argmax(np.diag(m)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2.0 * math.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
    q = np.zeros(4)
    q[i] = 0.25 * s
    q[j] = (m[j, i] + m[i, j]) / s
    q[k] = (m[k, i] + m[i, k]) / s
    q[3] = (m[k, j] - m[j, k]) / s
    return tuple(q)
