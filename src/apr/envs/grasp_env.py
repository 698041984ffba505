"""Gymnasium environments of APR: ``apr/ActiveGrasp-v2`` (a head camera that looks) and ``apr/PassiveGrasp-v2``
(three static cameras). Both share the episode logic of :class:`GraspEnv`; they differ only in how a step's
three views are made.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from apr.envs.config import CAMERA, GRASP, HEAD, PASSIVE_LAYOUTS, PHYSICS, REWARD, PassiveCameras
from apr.envs.task import GraspTask
from apr.envs.world import GraspWorld, passive_cameras
from apr.foveation import FOVEATIONS, foveate

DOFS = (4, 6)
FIXATION_PHASE, GRASP_PHASE = 0, 1
INITIAL_VIEWS = ("drawn", "fixed")
"""How the head's views at reset are placed: drawn around the point as at every step, or from the fixed viewpoints
of ``HEAD.fixed_initial_views`` (ours)."""


class GraspEnv(gym.Env):
    """Episode logic shared by the active and passive environments (see their docstrings for the API)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, *, dof: int, target: str, foveation: str, split: str, renderer: str,
                 render_mode: str | None, with_head: bool, reach_scale: float, render_size: int,
                 reveal_target: bool, limit_in_task: bool, tilted_reach: bool, tilt_about_tip: bool):  # fmt: skip
        _check_choice("dof", dof, DOFS)
        _check_render_size(render_size)
        _check_choice("foveation", foveation, FOVEATIONS)
        _check_choice("render_mode", render_mode, (None, *self.metadata["render_modes"]))
        self.task = GraspTask(target, split, reach_scale)  # validates target, split and reach_scale
        self.dof, self.foveation, self.render_mode = dof, foveation, render_mode
        self.learned_fixation = target == "learned"
        self.with_mask = target == "env"
        if reveal_target and self.learned_fixation:
            raise ValueError("reveal_target needs target='env': with a learned fixation there is no target to reveal")
        self.reveal_target = bool(reveal_target)
        self.observes_fixation = self.learned_fixation or self.reveal_target
        """The observation has ``fixation``: the point a learned fixation chose, or the revealed target."""
        self.limit_in_task = bool(limit_in_task)
        """The 15-step limit is part of the task (v1): it terminates the episode, and the observation has
        ``steps_left``. False (v0): the limit truncates, and the observation says nothing of time."""
        self.tilted_reach = bool(tilted_reach)
        """The workspace's lower bound holds the tool tip (v2), so that a tilted gripper can reach the grasp height;
        False (v0, v1): it holds the end-effector link."""
        if tilt_about_tip and not tilted_reach:
            raise ValueError("tilt_about_tip needs tilted_reach (v3 builds on v2)")
        self.tilt_about_tip = bool(tilt_about_tip)
        """A change of tilt turns the gripper about its tool tip (v3); False (v0-v2): about the end-effector link."""
        self.world = GraspWorld(renderer, with_head=with_head, render_size=render_size, tilted_reach=tilted_reach,
                                tilt_about_tip=tilt_about_tip)  # fmt: skip

        views, size, channels = CAMERA.views_per_step, CAMERA.image_size, 4 if self.with_mask else 3
        observation = {
            "images": spaces.Box(0, 255, (views, size, size, channels), np.uint8),
            "viewpoints": spaces.Box(-2 * np.pi, 2 * np.pi, (views, 6), np.float32),
            "gripper": spaces.Box(-2.0, 2.0, (9,), np.float32),
        }
        if self.observes_fixation:
            observation["fixation"] = spaces.Box(-2.0, 2.0, (3,), np.float32)
        if self.limit_in_task:
            observation["steps_left"] = spaces.Discrete(GRASP.max_grasp_steps + 1)
        grasp_action = spaces.Box(-1.0, 1.0, (dof,), np.float32)
        if self.learned_fixation:
            observation["phase"] = spaces.Discrete(2)
            self.action_space = spaces.Dict({"fixation": spaces.Box(-1.0, 1.0, (3,), np.float32),
                                             "grasp": grasp_action})  # fmt: skip
        else:
            self.action_space = grasp_action
        self.observation_space = spaces.Dict(observation)

        self.fixation_point: np.ndarray | None = None
        self.raw_views: list[np.ndarray] = []
        """The last step's three renders before foveation: uint8 (S, S, 3 or 4), S = ``render_size``, the mask
        last."""
        self._phase = GRASP_PHASE
        self._grasp_steps = 0
        self._tip_distance = 0.0
        self._tip = np.zeros(3)
        self._object_centres = np.zeros((0, 3))
        self._episode_over = True
        self.on_grasp_start: Callable[[GraspEnv], None] | None = None
        """Called with the env when a grasp starts, before the fingers close (e.g. to picture the pre-grasp pose)."""

    # ------------------------------------------------------------------------------------------------ API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.fixation_point = self.task.reset(self.world, self.np_random)
        self._phase = FIXATION_PHASE if self.learned_fixation else GRASP_PHASE
        self._grasp_steps = 0
        self._tip_distance = self._distance_to_fixation()
        self._tip = self.world.arm.tool_tip()
        self._object_centres = self._centres_of_objects()
        self._episode_over = False
        return self._observation(), self._info()

    def step(self, action):
        if self._episode_over:
            raise RuntimeError("the episode is over (or never started): call reset() before step()")
        action = self._checked_action(action)
        if self._phase == FIXATION_PHASE:
            self.fixation_point = self.task.fixation_from_action(action["fixation"])
            self._phase = GRASP_PHASE
            self._tip_distance = self._distance_to_fixation()
            self._object_centres = self._centres_of_objects()
            return self._observation(), 0.0, False, False, self._info()

        grasp = action["grasp"] if self.learned_fixation else action
        delta_angles = np.zeros(3)
        delta_angles[: self.dof - 3] = grasp[3:] * GRASP.angle_step
        self.world.arm.move(grasp[:3] * GRASP.position_step, delta_angles)
        self.world.step_simulation(PHYSICS.action_repeat)
        self._grasp_steps += 1

        distance = self._distance_to_fixation()
        reach_reward = self.task.reach_reward(self._tip_distance, distance)
        self._tip_distance = distance
        tip = self._tip = self.world.arm.tool_tip()
        attempted = bool(tip[2] <= GRASP.grasp_height)
        success, lifted = False, 0
        if attempted:
            if self.on_grasp_start is not None:
                self.on_grasp_start(self)
            self.world.arm.close_and_lift(self.world.step_simulation)
            outcome = self.task.grasp_outcome(self.world, tip, self.fixation_point)
            success, lifted = outcome.success, len(outcome.lifted)
        grasp_reward = float(success)
        at_limit = not attempted and self._grasp_steps >= GRASP.max_grasp_steps
        terminated = attempted or (at_limit and self.limit_in_task)
        truncated = at_limit and not self.limit_in_task
        self._episode_over = terminated or truncated
        info = self._info(attempted=attempted, success=success, lifted=lifted, reach_reward=reach_reward,
                          grasp_reward=grasp_reward)  # fmt: skip
        return self._observation(), grasp_reward + reach_reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """``rgb_array``: the first of the last step's raw views (``render_size`` square), before foveation."""
        if self.render_mode != "rgb_array" or not self.raw_views:
            return None
        return self.raw_views[0][..., :3].copy()

    def close(self) -> None:
        self.world.close()

    def renderer_in_use(self) -> str:
        """The renderer this environment's images come from, "egl" or "tiny" (with ``renderer="auto"``, what it
        resolved to); builds the world if it was not built yet."""
        self.world.build()
        return self.world.renderer

    # --------------------------------------------------------------------------------------------- helpers
    def _render_views(self) -> tuple[list[np.ndarray], list[np.ndarray | None], np.ndarray]:
        """The step's three raw RGB renders, their body-id masks (or None), and viewpoints (3, 6)."""
        raise NotImplementedError

    def _observation(self) -> dict[str, np.ndarray | int]:
        rgbs, segmentations, viewpoints = self._render_views()
        raw = []
        for rgb, segmentation in zip(rgbs, segmentations, strict=True):
            if self.with_mask:
                mask = np.where(segmentation == self.task.target_uid, 255, 0).astype(np.uint8)
                rgb = np.concatenate([rgb, mask[..., None]], axis=-1)
            raw.append(rgb)
        self.raw_views = raw
        images = np.stack([foveate(view, self.foveation, CAMERA.image_size) for view in raw])
        observation: dict[str, np.ndarray | int] = {
            "images": images,
            "viewpoints": viewpoints.astype(np.float32),
            "gripper": self.world.arm.pose(),
        }
        if self.observes_fixation:
            observation["fixation"] = np.asarray(self.fixation_point, dtype=np.float32).copy()
        if self.learned_fixation:
            observation["phase"] = self._phase
        if self.limit_in_task:
            observation["steps_left"] = GRASP.max_grasp_steps - self._grasp_steps
        return observation

    def _info(self, attempted: bool = False, success: bool = False, lifted: int = 0, reach_reward: float = 0.0,
              grasp_reward: float = 0.0) -> dict[str, Any]:  # fmt: skip
        return {
            "phase": self._phase,
            "fixation_point": np.array(self.fixation_point, dtype=np.float32),
            "grasp_steps": self._grasp_steps,
            "grasp_attempted": attempted,
            "grasp_success": success,
            "objects_lifted": lifted,
            "reach_reward": reach_reward,
            "grasp_reward": grasp_reward,
            "num_objects": len(self.world.object_uids),
            "object_centres": self._object_centres.astype(np.float32),
            "fixation_object_distance": self._fixation_object_distance(),
            "tool_tip": self._tip.astype(np.float32),
            "tip_fixation_distance": self._tip_distance,
        }

    def _centres_of_objects(self) -> np.ndarray:
        """(N, 3) the centres of the objects in the tray now (m), N = ``info["num_objects"]``."""
        return np.array([self.world.object_centre(uid) for uid in self.world.object_uids]).reshape(-1, 3)

    def _fixation_object_distance(self) -> float:
        """m from the fixation point to the nearest object centre, as the objects lay at the last reset or
        fixation action (inf with no objects)."""
        if not len(self._object_centres):
            return float("inf")
        return float(np.linalg.norm(self._object_centres - self.fixation_point, axis=1).min())

    def _distance_to_fixation(self) -> float:
        return float(np.linalg.norm(self.world.arm.tool_tip() - self.fixation_point))

    def _checked_action(self, action):
        """Raise on NaN or infinite entries (naming them); clip the rest into the action box."""
        if isinstance(self.action_space, spaces.Dict):
            if not isinstance(action, dict) or set(action) != set(self.action_space.spaces):
                raise ValueError(f"action must be a dict with keys {sorted(self.action_space.spaces)}, got {action!r}")
            return {key: _checked_box(f"action[{key!r}]", action[key], space)
                    for key, space in self.action_space.spaces.items()}  # fmt: skip
        return _checked_box("action", action, self.action_space)


class ActiveGraspEnv(GraspEnv):
    """Grasping with a head camera that looks: the active model of APR (Zaky et al., Method A).

    A Kuka arm with a two-finger gripper grasps procedurally generated objects from a tray (the benchmark of
    Quillen et al. 2018), while a second arm, the head (an xArm6), carries a camera on its wrist and fixates a
    point. Every step renders three views from viewpoints drawn on a sphere around the fixation point and
    samples each render (256x256 by default) to 64x64 with the log-polar-like warp (or a plain resize).

    ## Arguments
    ``gymnasium.make("apr/ActiveGrasp-v2", dof=6, target="env", foveation="logpolar", split="train",
    renderer="tiny")``

    - ``dof``: 6 (dx, dy, dz, da, db, dc) or 4 (dx, dy, dz, da; the gripper points down).
    - ``target``: "env" (the environment picks a target object and fixates it; its mask is a 4th channel) or
      "learned" (the agent picks the fixation point: see Episode structure).
    - ``foveation``: "logpolar" or "resize" (the "w/o log-polar" ablation).
    - ``split``: "train" (at most 5 of the 900 training objects) or "test" (exactly 5 of the 100 held out).
    - ``initial_views``: "drawn" (the views at reset are drawn around the point, as at every step) or "fixed"
      (the views at reset come from the fixed viewpoints of ``HEAD.fixed_initial_views``, the same in every
      episode: with a learned fixation, the views it chooses from; the later steps' views are drawn).
    - ``renderer``: "tiny" (pybullet's TinyRenderer, on the CPU; any number of environments in one process),
      "egl" (pybullet's EGL plugin: about 1.5 times the steps per second on a CPU, through Mesa's llvmpipe; one
      EGL environment per process) or "auto" (EGL if its plugin loads, else TinyRenderer). The two renderers' images
      differ: a policy must be evaluated on the renderer it was trained with.
    - ``reach_scale``: reach reward per metre of progress toward the fixation point (default 1.0).
    - ``render_size``: side of each render in pixels, a multiple of 64 (default 256, the paper's). 128 costs about
      a sixth less CPU time per render with EGL and 60% less with TinyRenderer, and blurs the warp's inner ring
      (``docs/decisions.md``, "Views and rendering").
    - ``reveal_target``: also put the target's true centre in the observation (``fixation``; ``target="env"``
      only). Not the robot's knowledge: for scripted baselines and the labelled ``cpu-4d`` preset.
    - ``limit_in_task``: the 15-step limit is part of the task (default; ``apr/ActiveGrasp-v1`` and ``-v2``):
      reaching it terminates the episode and the observation has ``steps_left``. ``False`` is
      ``apr/ActiveGrasp-v0``, the earlier task: the limit truncates, and nothing in the observation tells the time
      (see Episode End).
    - ``tilted_reach``: a tilted gripper can reach the grasp height (default; ``apr/ActiveGrasp-v2``): its axis
      stays within 45 deg of vertical and the workspace's floor holds the tool tip. ``False`` is ``-v1`` and
      ``-v0``: b and c are clipped each to 45 deg and the floor holds the end-effector link, where a gripper
      tilted by more than about 40 deg stops above the grasp height (see Action Space).
    - ``tilt_about_tip``: a change of tilt turns the gripper about its tool tip (default; ``apr/ActiveGrasp-v3``),
      so that the position and the tilt actions move the tip apart. ``False`` is ``-v2`` and before: the gripper
      turns about its wrist, and a tilt alone swings the tip by up to 15 cm sideways.

    ## Action Space
    ``target="env"``: ``Box(-1, 1, (dof,), float32)``, the change of the gripper's commanded pose: position
    0.06 m per unit on each axis, Euler angles 0.25 rad per unit. ``a`` turns the gripper about its own axis,
    ``b`` and ``c`` tilt it about the world x and y axes (clipped to +-45 deg each, and in v2 scaled down together
    so that the gripper's axis lies within 45 deg of vertical). The commanded end-effector position stays within
    a box; its floor, z = 0.05 m, puts the tool tip at z = -0.167 m, 5 cm below the grasp height, when the gripper
    points down, and in v2 it is lowered by as much as the tilt raises the tip. In v3 a change of tilt turns the
    gripper about its tool tip: the commanded position moves with the link around the tip, and the box holds the
    tip (the box above is where the link sits pointing down).

    ``target="learned"``: ``Dict(fixation=Box(-1, 1, (3,)), grasp=Box(-1, 1, (dof,)))``. In the fixation phase
    only ``fixation`` is used: it maps linearly onto the workspace box x in [0.38, 0.75], y in [-0.2, 0.2],
    z in [-0.2, -0.05] m (where the objects lie and the gripper reaches). In the grasp phase only ``grasp`` is
    used, as above.

    Entries outside [-1, 1] are clipped. A NaN or infinite entry raises ``ValueError`` naming it.

    ## Observation Space
    ``Dict`` with
    - ``images``: uint8 (3, 64, 64, C), the step's three views, C = 4 with the target mask
      (``target="env"``: 255 on the target object) and 3 otherwise.
    - ``viewpoints``: float32 (3, 6), the head's six joint angles reached for each view (rad).
    - ``gripper``: float32 (9,), the tool tip (x, y, z) in m and sin/cos of the Euler angles (a, b, c).
    - ``fixation`` (``target="learned"``, or ``reveal_target=True``): float32 (3,), the point the head fixates
      (m), where the views' lines of sight meet. With a learned fixation it is what the robot chose (the bin
      centre in the fixation phase). With the environment's target it is the target's true centre, the
      simulator's answer, which a policy never sees: only ``reveal_target=True`` puts it here.
    - ``phase`` (``target="learned"`` only): 0 in the fixation phase, 1 in the grasp phase.
    - ``steps_left`` (``limit_in_task=True``, v1): ``Discrete(16)``, the grasp steps the episode has left: 15
      at reset and in the fixation phase, 15 - k after the k-th grasp step. The robot's own clock.

    An observation holds only what the robot can know (its images, its joints and poses, the point it chose),
    unless ``reveal_target=True``. The simulator's view of the scene is in ``info``: ``fixation_point`` (the
    point the head fixates), ``object_centres`` (N, 3) and ``fixation_object_distance`` (m from the fixation
    point to the nearest object centre), as the objects lay at reset or at the fixation action. ``tool_tip``
    is the tool tip (m) after the step's motion (before the fingers close, on an attempt) and
    ``tip_fixation_distance`` its distance to the fixation point (the target's centre with ``target="env"``).

    ## Episode structure
    ``target="env"``: reset fixates the target; then up to 15 grasp steps. ``target="learned"``: reset shows
    three views around the bin centre (phase 0); the first ``step`` is the fixation action (reward 0; the
    fixation policy's one-step contextual bandit, whose reward is the episode's grasp reward); then up to 15
    grasp steps with views around the chosen point (phase 1).

    ## Rewards
    A grasp step earns the dense reach reward ``reach_scale * (d_before - d_after)`` (``d``: the distance in m
    from the tool tip to the fixation point). The step that attempts a grasp also earns the sparse grasp reward, 1 if
    ``target="env"`` and the target was lifted, or ``target="learned"`` and an object was lifted while the tool
    tip was within 10 cm of the fixation point when the grasp started. ``info`` holds both parts
    (``reach_reward``, ``grasp_reward``), so the fixation policy can be trained on the grasp reward only.

    ## Episode End
    Terminated when a grasp is attempted: the tool tip drops to z <= -0.115 m; the fingers then close and the
    arm lifts, and the object counts as lifted when its base ends above z = 0.2 m. After 15 grasp steps without
    an attempt the episode ends with no grasp reward: terminated in v1 and v2, where the limit is part of the task (the
    paper's "a fixed number of timesteps (maximum 15)") and ``steps_left`` says how near it is (Pardo et al.
    2018, "Time Limits in Reinforcement Learning"); truncated in v0 (``limit_in_task=False``).
    ``info["grasp_attempted"]`` and ``info["grasp_success"]`` tell the outcome.
    """

    def __init__(self, dof: int = 6, target: str = "env", foveation: str = "logpolar", split: str = "train",
                 renderer: str = "tiny", render_mode: str | None = None,
                 reach_scale: float = REWARD.reach_scale, render_size: int = CAMERA.render_size,
                 reveal_target: bool = False, limit_in_task: bool = True, initial_views: str = "drawn",
                 tilted_reach: bool = True, tilt_about_tip: bool = False):  # fmt: skip
        _check_choice("initial_views", initial_views, INITIAL_VIEWS)
        self.initial_views = initial_views
        self._at_reset = False
        super().__init__(dof=dof, target=target, foveation=foveation, split=split, renderer=renderer,
                         render_mode=render_mode, with_head=True, reach_scale=reach_scale,
                         render_size=render_size, reveal_target=reveal_target,
                         limit_in_task=limit_in_task, tilted_reach=tilted_reach,
                         tilt_about_tip=tilt_about_tip)  # fmt: skip

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self._at_reset = True
        try:
            return super().reset(seed=seed, options=options)
        finally:
            self._at_reset = False

    def _render_views(self):
        head = self.world.head
        fixed = self.initial_views == "fixed" and self._at_reset
        rgbs, segmentations, viewpoints = [], [], []
        for view in range(CAMERA.views_per_step):
            if fixed:
                camera, joints = head.look_from(self.fixation_point, *HEAD.fixed_initial_views[view])
            else:
                camera, joints = head.look_at(self.fixation_point, self.np_random)
            rgb, segmentation = self.world.render(camera, segmentation=self.with_mask, from_head=True)
            rgbs.append(rgb)
            segmentations.append(segmentation)
            viewpoints.append(joints)
        return rgbs, segmentations, np.stack(viewpoints)


class PassiveGraspEnv(GraspEnv):
    """Grasping seen by three static cameras: the passive model of APR (Zaky et al., Section 4A).

    The same world and task as :class:`ActiveGraspEnv` with ``target="env"`` but no head: three fixed
    cameras (front, left and right of the tray, looking down at 56 deg) see the tray and the gripper, with no
    attention to any object. Renders (256x256 by default) are resized to 64x64 (no log-polar warp).

    ## Arguments
    ``gymnasium.make("apr/PassiveGrasp-v4", dof=6, split="train", renderer="tiny")``, as for the active env
    (``reveal_target`` too), and

    - ``cameras``: ``"sides"`` (default; ``-v4``): framed on the tray as the benchmark's camera is, a field of view
      of 20 deg, 1.4 m from the middle of the tray's floor, whose corners lie inside each image; an object 5 cm
      across spans about 6 pixels of the 64; from the tray's front, left and right. ``"front"`` (an option): so
      framed, all three from the tray's front, 20 deg apart, as the head's views at reset are. ``"wide"``
      (``-v0`` to ``-v3``): a field of view of 50 deg from about 1 m, the tray a third of each image and an object
      a few pixels.

    ## Action Space
    ``Box(-1, 1, (dof,), float32)``, as for ``apr/ActiveGrasp-v2`` with ``target="env"``.

    ## Observation Space
    ``images`` uint8 (3, 64, 64, 4) (RGB and the target mask), ``viewpoints`` float32 (3, 6) (each camera's
    position and unit line of sight, constant), ``gripper`` float32 (9,), and in v1 ``steps_left``. The target's
    centre, toward which the reach reward pays, is not observed: the policy must find the target in the images
    (``info`` has it as ``fixation_point``; ``reveal_target=True`` adds it as ``fixation``, for scripted
    baselines).

    ## Rewards and Episode End
    As for ``apr/ActiveGrasp-v2`` with ``target="env"``: the reach reward toward the target's centre, 1 for
    lifting the target; terminated by a grasp attempt, and after 15 steps (v1; truncated in v0).
    """

    def __init__(self, dof: int = 6, split: str = "train", renderer: str = "tiny",
                 render_mode: str | None = None, reach_scale: float = REWARD.reach_scale,
                 render_size: int = CAMERA.render_size, reveal_target: bool = False,
                 limit_in_task: bool = True, tilted_reach: bool = True, tilt_about_tip: bool = False,
                 cameras: PassiveCameras = "sides"):  # fmt: skip
        super().__init__(dof=dof, target="env", foveation="resize", split=split, renderer=renderer,
                         render_mode=render_mode, with_head=False, reach_scale=reach_scale,
                         render_size=render_size, reveal_target=reveal_target,
                         limit_in_task=limit_in_task, tilted_reach=tilted_reach,
                         tilt_about_tip=tilt_about_tip)  # fmt: skip
        _check_choice("cameras", cameras, PASSIVE_LAYOUTS)
        self.camera_layout = cameras
        """The cameras' layout (:data:`apr.envs.config.PASSIVE_CAMERAS`, by version)."""
        self.cameras = passive_cameras(cameras)
        self._viewpoints = np.stack([np.concatenate([cam.eye, cam.forward]) for cam in self.cameras])

    def _render_views(self):
        rendered = [self.world.render(camera, segmentation=True) for camera in self.cameras]
        return [rgb for rgb, _ in rendered], [mask for _, mask in rendered], self._viewpoints.copy()


def render_size_problem(render_size: Any) -> str | None:
    """Why ``render_size`` is not a render side the foveations can sample (a positive multiple of the 64-pixel
    observation), as the end of a sentence naming it; None when it is."""
    size = CAMERA.image_size
    if isinstance(render_size, bool) or not isinstance(render_size, int) or render_size < size or render_size % size:
        return f"must be a positive multiple of {size} (the paper: 256), got {render_size!r}"
    return None


def _check_render_size(render_size: Any) -> None:
    problem = render_size_problem(render_size)
    if problem:
        raise ValueError(f"render_size {problem}")


def _check_choice(name: str, value: Any, valid: tuple) -> None:
    if value not in valid:
        raise ValueError(f"{name} must be one of {valid}, got {value!r}")


def _checked_box(name: str, value: Any, space: spaces.Box) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != space.shape:
        raise ValueError(f"{name} must have shape {space.shape}, got {array.shape}")
    bad = np.flatnonzero(~np.isfinite(array))
    if bad.size:
        raise ValueError(f"{name}[{int(bad[0])}] is {array[bad[0]]}: actions must be finite")
    return np.clip(array, space.low, space.high)
