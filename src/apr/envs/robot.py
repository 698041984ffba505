"""The Kuka iiwa with its WSG gripper: a Cartesian controller for 4- and 6-DoF actions, and the grasp routine.

The gripper's orientation is three Euler angles relative to pointing straight down:
``a`` turns the gripper about its own axis (the benchmark's single angle, joint 7), ``b`` tilts it about the
world x axis and ``c`` about the world y axis. The 4-DoF mode keeps ``b = c = 0``.
"""

from __future__ import annotations

import math

import numpy as np
from pybullet_utils.bullet_client import BulletClient

from apr.envs.config import ARM, GRASP, SCENE, ArmSpec, GraspSpec

_POINTING_DOWN = (0.0, -math.pi, 0.0)  # Euler angles of the end-effector link when the gripper points down


def within_tilt(b: float, c: float, max_tilt: float) -> tuple[float, float]:
    """Tilts (b, c) scaled down together, if needed, so that the gripper's axis lies within ``max_tilt`` of
    vertical: the angle from vertical of Euler tilts (b, c) is acos(cos b cos c)."""
    if math.cos(b) * math.cos(c) >= math.cos(max_tilt):
        return b, c
    low, high = 0.0, 1.0  # bisection on the common scale
    for _ in range(40):
        middle = 0.5 * (low + high)
        within = math.cos(middle * b) * math.cos(middle * c) >= math.cos(max_tilt)
        low, high = (middle, high) if within else (low, middle)
    return low * b, low * c


class KukaGripper:
    """Position control of the arm through inverse kinematics, as in the benchmark's ``kuka.py``.

    The controller holds a commanded end-effector position and Euler angles; an action moves the command,
    inverse kinematics turns it into joint targets, and the simulation moves the joints there.
    """

    def __init__(self, client: BulletClient, sdf_path: str, spec: ArmSpec = ARM, grasp: GraspSpec = GRASP,
                 tilted_reach: bool = True, tilt_about_tip: bool = True):  # fmt: skip
        self.client = client
        self.spec = spec
        if tilt_about_tip and not tilted_reach:
            raise ValueError("tilt_about_tip needs tilted_reach (v3 builds on v2)")
        self.tilted_reach = tilted_reach
        """v2: a tilted gripper can reach the grasp height. The gripper's axis stays within ``max_tilt`` of vertical
        (b and c scaled down together where each alone is within it but both together are not), and the
        workspace's lower bound holds the tool tip where pointing down puts it. False (v0, v1): b and c are
        clipped each to ``max_tilt`` (together up to 60 degrees from vertical) and the lower bound holds the
        end-effector link, so a gripper tilted by more than about 40 degrees stops above the grasp height and can
        never attempt."""
        self.tilt_about_tip = tilt_about_tip
        """v3: a change of tilt turns the gripper about its tool tip, and the workspace box holds the tip: the
        commanded end-effector position moves by as much as the tilt moves the link around the tip. False (v0-v2):
        the tilt turns the gripper about the end-effector link, and the tip swings by up to
        ``tip_below_end_effector`` sin(45 deg), 15 cm, sideways."""
        self.grasp_spec = grasp
        self.uid = client.loadSDF(sdf_path)[0]
        client.resetBasePositionAndOrientation(self.uid, SCENE.kuka_base_position, (0.0, 0.0, 0.0, 1.0))
        self._down = np.array(client.getQuaternionFromEuler(_POINTING_DOWN))
        self.target_position = np.zeros(3)
        self.target_angles = np.zeros(3)
        self.finger_angle = spec.finger_open
        self.reset()

    def reset(self) -> None:
        """Put the arm back in its initial pose with the fingers open; no simulation step is taken."""
        for joint, angle in enumerate(self.spec.initial_joint_positions):
            self.client.resetJointState(self.uid, joint, angle)
            self.client.setJointMotorControl2(
                self.uid, joint, self.client.POSITION_CONTROL, targetPosition=angle, force=self.spec.max_force
            )
        self.target_position = np.array(self.spec.initial_end_effector_position, dtype=np.float64)
        self.target_angles = np.zeros(3)
        self.finger_angle = self.spec.finger_open

    def move(self, delta_position: np.ndarray, delta_angles: np.ndarray) -> None:
        """Shift the commanded pose by metres and radians (clipped to the workspace) and send joint targets."""
        before = self.target_angles
        angles = self.target_angles + delta_angles
        angles[0] = np.clip(angles[0], -math.pi, math.pi)
        angles[1:] = np.clip(angles[1:], -self.spec.max_tilt, self.spec.max_tilt)
        low = np.array([self.spec.workspace_x[0], self.spec.workspace_y[0], self.spec.workspace_z[0]])
        high = np.array([self.spec.workspace_x[1], self.spec.workspace_y[1], self.spec.workspace_z[1]])
        if self.tilted_reach:
            angles[1:] = within_tilt(angles[1], angles[2], self.spec.max_tilt)
            # a tilted gripper's tip hangs less far below the link: the link may go as much lower
            low[2] -= self.spec.tip_below_end_effector * (1.0 - math.cos(angles[1]) * math.cos(angles[2]))
        if self.tilt_about_tip:
            shift = self.link_shift(angles)
            delta_position = delta_position + shift - self.link_shift(before)  # the tip stays where it was
            low[:2] += shift[:2]  # the box holds the tip (its floor does already)
            high += shift
        self.target_angles = angles
        self.target_position = np.clip(self.target_position + delta_position, low, high)
        self.send_targets()

    def link_shift(self, angles: np.ndarray) -> np.ndarray:
        """(3,) m: where the end-effector link sits relative to the tool tip with the tilts of ``angles`` (a, b, c),
        less where it sits pointing down, (0, 0, ``tip_below_end_effector``); exactly 0 pointing down."""
        tilt = self.client.getQuaternionFromEuler((angles[1], angles[2], 0.0))
        rotation = np.array(self.client.getMatrixFromQuaternion(tilt)).reshape(3, 3)
        return (rotation[:, 2] - (0.0, 0.0, 1.0)) * self.spec.tip_below_end_effector

    def send_targets(self) -> None:
        """Solve inverse kinematics for the commanded pose and set every motor's target."""
        c, spec = self.client, self.spec
        _, tilt_b, tilt_c = self.target_angles
        tilt = c.getQuaternionFromEuler((tilt_b, tilt_c, 0.0))
        _, orientation = c.multiplyTransforms((0, 0, 0), tilt, (0, 0, 0), self._down)
        joints = c.calculateInverseKinematics(self.uid, spec.end_effector_link, self.target_position, orientation)
        for joint in range(spec.end_effector_link + 1):
            c.setJointMotorControl2(
                self.uid, joint, c.POSITION_CONTROL, targetPosition=joints[joint], targetVelocity=0,
                force=spec.max_force, positionGain=spec.position_gain, velocityGain=spec.velocity_gain,
            )  # fmt: skip
        c.setJointMotorControl2(
            self.uid, spec.gripper_yaw_joint, c.POSITION_CONTROL, targetPosition=self.target_angles[0],
            force=spec.max_force,
        )  # fmt: skip
        self.send_finger_targets()

    def send_finger_targets(self) -> None:
        """Set the finger motors' targets from ``finger_angle`` (open: ``finger_open``, closed: 0)."""
        c, spec = self.client, self.spec
        finger_a, finger_b = spec.finger_joints
        c.setJointMotorControl2(
            self.uid, finger_a, c.POSITION_CONTROL, targetPosition=-self.finger_angle, force=spec.finger_a_force
        )
        c.setJointMotorControl2(
            self.uid, finger_b, c.POSITION_CONTROL, targetPosition=self.finger_angle, force=spec.finger_b_force
        )
        for tip in spec.fingertip_joints:
            c.setJointMotorControl2(self.uid, tip, c.POSITION_CONTROL, targetPosition=0, force=spec.fingertip_force)

    def tool_tip(self) -> np.ndarray:
        """(3,) the midpoint of the two fingertips, world frame (m)."""
        tips = self.client.getLinkStates(self.uid, list(self.spec.fingertip_joints))
        return 0.5 * (np.array(tips[0][4]) + np.array(tips[1][4]))

    def pose(self) -> np.ndarray:
        """(9,) float32 gripper pose g = (x, y, z, sin a, cos a, sin b, cos b, sin c, cos c), as reached.

        (x, y, z) is the tool tip; ``a`` is the measured gripper joint angle; ``b`` and ``c`` are the measured
        tilts of the end-effector link away from pointing down.
        """
        c = self.client
        link_orientation = c.getLinkState(self.uid, self.spec.end_effector_link)[5]
        _, inverse_down = c.invertTransform((0, 0, 0), self._down)
        _, relative = c.multiplyTransforms((0, 0, 0), link_orientation, (0, 0, 0), inverse_down)
        tilt_b, tilt_c, _ = c.getEulerFromQuaternion(relative)
        yaw = c.getJointState(self.uid, self.spec.gripper_yaw_joint)[0]
        angles = np.array([yaw, tilt_b, tilt_c])
        trig = np.stack([np.sin(angles), np.cos(angles)], axis=1).ravel()
        return np.concatenate([self.tool_tip(), trig]).astype(np.float32)

    def close_and_lift(self, step_simulation) -> None:
        """The benchmark's grasp: close the fingers over ``close_steps``, then lift over ``lift_steps``.

        Args:
            step_simulation: callable that advances the physics by one step.
        """
        spec = self.grasp_spec
        closing_rate = self.spec.finger_open / 100.0  # the benchmark closes fully in 100 steps, then squeezes
        for _ in range(spec.close_steps):
            self.finger_angle = max(self.finger_angle - closing_rate, 0.0)
            self.send_finger_targets()  # the arm's targets stand: its commanded pose has not changed
            step_simulation()
        for _ in range(spec.lift_steps):
            self.target_position[2] += spec.lift_speed
            self.send_targets()
            step_simulation()
