"""Episodes in this process that keep what the pictures need: every step's raw renders and observation, the
actions, and close-up renders of the gripper at the moment a grasp starts.

The policy side mirrors :func:`apr.train.rollout.run_round` for one environment: with a learned fixation the
first step is the fixation action, then grasp steps until a grasp is attempted or 15 steps pass. With an
agent the action is the deterministic (mean) one, as in evaluation; with the same environment settings and
seed an episode here is the episode ``apr eval`` runs.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

import apr  # noqa: F401  (registers the environments)
from apr.envs.grasp_env import GraspEnv
from apr.envs.rendering import Camera
from apr.envs.scripted import scripted_grasp_action
from apr.model.agent import APRAgent
from apr.train.config import EnvConfig
from apr.train.rollout import stack

ActionSource = Callable[[GraspEnv, dict[str, Any], str], np.ndarray]
"""(the unwrapped env, its observation, "fixation" or "grasp") -> the action of that phase."""

CLOSE_UP_DISTANCE = 0.5
"""m from the tool tip to the close-up cameras."""
CLOSE_UP_DIRECTIONS = {"behind": (-1.0, -0.3, 0.9), "side": (0.0, -1.0, 0.9)}
"""Where the close-up cameras stand, relative to the tool tip: behind (the Kuka's side, clear of the head arm)
and to the side; together they show both tilts of a 6-DoF gripper."""


def agent_actions(agent: APRAgent) -> ActionSource:
    """The agent's deterministic (mean) actions, as in evaluation."""

    def act(env: GraspEnv, observation: dict[str, Any], phase: str) -> np.ndarray:
        return agent.act(stack([observation]), deterministic=True, policy=phase)[0]

    return act


def scripted_actions(env: GraspEnv, observation: dict[str, Any], phase: str) -> np.ndarray:
    """The scripted reach-and-grasp (it reads the simulator's state; environment-selected targets only)."""
    if phase == "fixation":
        raise ValueError("the scripted policy has no fixation action: use it with target='env'")
    return scripted_grasp_action(env)


def replayed_actions(actions: list[np.ndarray]) -> ActionSource:
    """The given grasp actions in order (then zeros): the same gripper motion in another environment."""
    remaining = list(actions)

    def act(env: GraspEnv, observation: dict[str, Any], phase: str) -> np.ndarray:
        return remaining.pop(0) if remaining else np.zeros(env.dof, np.float32)

    return act


@dataclass
class Frame:
    """What one observation of the episode showed."""

    phase: str
    """"start" (after reset), "fixation" (after the fixation action) or "grasp" (after a grasp step)."""
    grasp_steps: int
    raw_views: list[np.ndarray]
    """The three raw renders (``render_size`` square; RGB, plus the target mask with environment-selected
    targets)."""
    observation: dict[str, Any]
    """The observation the policy saw: images (3, 64, 64, C), viewpoints, gripper."""


@dataclass
class GraspStart:
    """Close-ups of the gripper at one moment: when a grasp starts (the tool tip has reached the grasp height,
    the fingers are still open), or where an episode without a grasp stopped."""

    views: dict[str, np.ndarray]
    """Close-up RGB renders of the gripper, by camera name ("front", "side")."""
    gripper: np.ndarray
    """(9,) the gripper pose g: tool tip xyz and sin/cos of the Euler angles (a, b, c)."""

    @property
    def euler_degrees(self) -> np.ndarray:
        """(a, b, c) in degrees: the turn about the gripper's axis and the two tilts from pointing down."""
        return np.degrees(np.arctan2(self.gripper[3::2], self.gripper[4::2]))


@dataclass
class EpisodeRecord:
    seed: int
    frames: list[Frame] = field(default_factory=list)
    grasp_actions: list[np.ndarray] = field(default_factory=list)
    attempted: bool = False
    success: bool = False
    truncated: bool = False
    grasp_start: GraspStart | None = None
    """The gripper when the grasp started (None if none was attempted)."""
    final_pose: GraspStart | None = None
    """The gripper where an episode without a grasp attempt stopped (None otherwise)."""

    @property
    def outcome(self) -> str:
        if self.success:
            return "grasp succeeded"
        if self.attempted:
            return "grasp attempted, failed"
        return "no grasp attempted (stopped after 15 steps)" if self.truncated else "stopped early"


def make_env(env_config: EnvConfig, split: str = "test", renderer: str | None = None) -> gym.Env:
    """The environment of ``env_config`` on ``split`` (``renderer`` overrides the config's)."""
    kwargs = env_config.make_kwargs(split)
    if renderer is not None:
        kwargs["renderer"] = renderer
    return gym.make(env_config.env_id, **kwargs)


def close_up_cameras(tip: np.ndarray) -> dict[str, Camera]:
    """Cameras a little way from the tool tip, looking at it."""
    cameras = {}
    for name, direction in CLOSE_UP_DIRECTIONS.items():
        offset = np.array(direction) / np.linalg.norm(direction) * CLOSE_UP_DISTANCE
        forward = -offset / np.linalg.norm(offset)
        up = np.array([0.0, 0.0, 1.0]) - forward[2] * forward
        cameras[name] = Camera(eye=tip + offset, forward=forward, up=up / np.linalg.norm(up), fov_deg=40.0)
    return cameras


def gripper_close_ups(env: GraspEnv) -> GraspStart:
    """Close-up renders of the gripper as it is now, and its pose."""
    cameras = close_up_cameras(env.world.arm.tool_tip())
    views = {name: env.world.render(camera)[0] for name, camera in cameras.items()}
    return GraspStart(views=views, gripper=env.world.arm.pose())


@contextlib.contextmanager
def grasp_start_capture(env: GraspEnv) -> Iterator[list[GraspStart]]:
    """Collect a :class:`GraspStart` each time ``env`` starts a grasp (through its ``on_grasp_start`` hook)."""
    captured: list[GraspStart] = []
    env.on_grasp_start = lambda started: captured.append(gripper_close_ups(started))
    try:
        yield captured
    finally:
        env.on_grasp_start = None


def run_episode(env: gym.Env, policy: ActionSource, seed: int, max_grasp_steps: int | None = None) -> EpisodeRecord:
    """Run one episode of ``env`` with ``policy`` from ``seed``, recording every frame.

    Args:
        max_grasp_steps: stop after this many grasp steps (None: until the episode ends).
    """
    unwrapped: GraspEnv = env.unwrapped
    record = EpisodeRecord(seed=seed)
    observation, _ = env.reset(seed=seed)
    record.frames.append(Frame("start", 0, unwrapped.raw_views, observation))
    with grasp_start_capture(unwrapped) as starts:
        if unwrapped.learned_fixation:
            fixation = policy(unwrapped, observation, "fixation")
            observation, *_ = env.step({"fixation": fixation, "grasp": np.zeros(unwrapped.dof, np.float32)})
            record.frames.append(Frame("fixation", 0, unwrapped.raw_views, observation))
        while max_grasp_steps is None or len(record.grasp_actions) < max_grasp_steps:
            action = np.asarray(policy(unwrapped, observation, "grasp"), dtype=np.float32)
            record.grasp_actions.append(action)
            step_action: Any = action
            if unwrapped.learned_fixation:
                step_action = {"fixation": np.zeros(3, np.float32), "grasp": action}
            observation, _, terminated, truncated, info = env.step(step_action)
            record.frames.append(Frame("grasp", info["grasp_steps"], unwrapped.raw_views, observation))
            if terminated or truncated:
                record.attempted, record.success = bool(info["grasp_attempted"]), bool(info["grasp_success"])
                record.truncated = bool(truncated)
                break
        if not record.attempted:
            record.final_pose = gripper_close_ups(unwrapped)
    record.grasp_start = starts[0] if starts else None
    return record


def upscale(image: np.ndarray, size: int) -> np.ndarray:
    """Nearest-neighbour upscaling of an (H, W, C) image to (size, size, C)."""
    factor = max(size // image.shape[0], 1)
    return image.repeat(factor, axis=0).repeat(factor, axis=1)


def rgb(image: np.ndarray) -> np.ndarray:
    """The RGB channels of a view (drops the target mask)."""
    return image[..., :3]
