"""Wrappers that give apr's environments the spaces library agents expect (Stable-Baselines3, CleanRL, TorchRL).

:class:`ImageObservation` turns apr's observation (images uint8 (V, 64, 64, C) channel-last, viewpoints (V, 6),
``steps_left`` Discrete) into channel-first uint8 images, one entry per view, and flat float32 vectors: SB3's
``MultiInputPolicy`` then builds its NatureCNN on each image (its ``CnnPolicy`` on a single ``image_0`` with
``gymnasium.wrappers.FilterObservation``), and a hand-written agent reads ``obs["image_0"]`` as a (C, 64, 64) tensor.
:class:`DiscreteActions` gives the discrete action set of the benchmark's DQN (Quillen et al. 2018).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from apr.envs.config import GRASP
from apr.envs.grasp_env import GraspEnv

IMAGE_KEY = "image_{view}"
"""The key of view ``view``'s image (``image_0``, ``image_1``, ...), or ``images`` when the views are stacked."""
VECTOR_KEYS = ("viewpoints", "gripper", "fixation", "steps_left")
"""The vector entries kept, flat, where the environment's observation has them (``phase`` never: see
:class:`ImageObservation`)."""


def _unsupported(env: gym.Env) -> str | None:
    """Why ``env`` cannot be wrapped (None when it can)."""
    base = env.unwrapped
    if not isinstance(base, GraspEnv):
        return f"it wraps apr's grasping environments, got {type(base).__name__}"
    if base.learned_fixation:
        return ("a learned fixation (target='learned') has a Dict action (fixation, grasp) and two phases: wrap "
                "target='env' or apr/BenchmarkGrasp, whose action is one Box")  # fmt: skip
    return None


class ImageObservation(gym.ObservationWrapper):
    """apr's observation as channel-first uint8 images and flat float32 vectors, for library agents.

    Wraps ``apr/ActiveGrasp`` with ``target="env"``, ``apr/PassiveGrasp`` and ``apr/BenchmarkGrasp`` (any version);
    refuses a learned fixation (its action is a Dict of two phases) with ``ValueError``. The action is unchanged.

    ## Observation Space
    ``Dict`` with, for V views of C channels (C = 4 where the target's mask is the 4th channel, else 3):

    - ``image_0`` ... ``image_{V-1}``: ``Box(0, 255, (C, 64, 64), uint8)``, each view channel-first (RGB, then the
      mask, as an RGB-D image is laid out); with ``stack_views=True`` one ``images``: ``Box(0, 255, (V * C, 64,
      64), uint8)``, the views' channels one after another (one CNN for all views).
    - ``viewpoints``: ``Box(-2 pi, 2 pi, (V * 6,), float32)``, the views' viewpoints, view after view.
    - ``gripper``: ``Box(-2, 2, (9,), float32)``, as in the environment.
    - ``fixation`` (``reveal_target=True`` only): ``Box(-2, 2, (3,), float32)``.
    - ``steps_left`` (``limit_in_task=True``): ``Box(0, 1, (1,), float32)``, the grasp steps left over 15 (1 at
      reset, 0 at the limit): a scaled number, not a one-hot, so that every vector entry is a float in a small
      range.

    Every entry is a fresh array: none shares memory with the environment's observation or with another entry.
    SB3's ``MultiInputPolicy`` builds one NatureCNN per image entry (its ``is_image_space``: 3 dimensions, uint8,
    bounds 0 and 255, the channel axis first and smallest) and flattens the vectors; ``check_env`` passes without a
    warning.
    """

    def __init__(self, env: gym.Env, stack_views: bool = False):
        problem = _unsupported(env)
        if problem:
            raise ValueError(f"ImageObservation cannot wrap this environment: {problem}")
        super().__init__(env)
        raw = env.observation_space
        self.views, size, _, self.channels = raw["images"].shape
        self.stack_views = bool(stack_views)
        observation: dict[str, spaces.Space] = {}
        if self.stack_views:
            observation["images"] = spaces.Box(0, 255, (self.views * self.channels, size, size), np.uint8)
        else:
            for view in range(self.views):
                observation[IMAGE_KEY.format(view=view)] = spaces.Box(0, 255, (self.channels, size, size), np.uint8)
        for key in VECTOR_KEYS:
            if key not in raw.spaces:
                continue
            space = raw[key]
            if key == "steps_left":
                observation[key] = spaces.Box(0.0, 1.0, (1,), np.float32)
            else:
                observation[key] = spaces.Box(space.low.ravel(), space.high.ravel(), (int(np.prod(space.shape)),),
                                              np.float32)  # fmt: skip
        self.observation_space = spaces.Dict(observation)

    def observation(self, observation: dict[str, Any]) -> dict[str, np.ndarray]:
        """One raw observation (the environment's, or one of a batch of them) -> the wrapped one (fresh arrays).

        Args:
            observation: ``images`` uint8 (V, 64, 64, C), ``viewpoints`` (V, 6), ``gripper`` (9,), and where the
                environment has them ``fixation`` (3,) and ``steps_left`` (an int); other keys are ignored.
        Returns:
            the entries of :attr:`observation_space`: images uint8 (C, 64, 64) per view (or (V * C, 64, 64)),
            vectors float32 (n,).
        """
        images = np.asarray(observation["images"])
        channel_first = images.transpose(0, 3, 1, 2)  # (V, C, 64, 64), a view of the environment's array
        wrapped: dict[str, np.ndarray] = {}
        if self.stack_views:
            wrapped["images"] = np.array(channel_first.reshape(-1, *channel_first.shape[2:]), np.uint8, copy=True)
        else:
            for view in range(self.views):
                wrapped[IMAGE_KEY.format(view=view)] = np.array(channel_first[view], np.uint8, copy=True, order="C")
        for key in VECTOR_KEYS:
            if key not in self.observation_space.spaces:
                continue
            if key == "steps_left":
                wrapped[key] = np.array([float(observation[key]) / GRASP.max_grasp_steps], np.float32)
            else:
                wrapped[key] = np.array(np.asarray(observation[key]).ravel(), np.float32, copy=True)
        return wrapped


class DiscreteActions(gym.ActionWrapper):
    """The benchmark's discrete action set (``KukaDiverseObjectEnv(isDiscrete=True, removeHeightHack=True)``, which
    Quillen et al.'s DQN-style agents used), extended to 6-DoF: one unit move of one axis per step.

    ## Action Space
    ``Discrete(2 * dof + 1)``: 0 stays; ``2k + 1`` moves axis k by -1 and ``2k + 2`` by +1 (axes x, y, z, a, and
    at 6-DoF b, c), i.e. -+6 cm or -+0.25 rad. At 4-DoF the 9 actions are the benchmark's, in its order (stay,
    -x, +x, -y, +y, -z, +z, -a, +a).
    """

    def __init__(self, env: gym.Env):
        problem = _unsupported(env)
        if problem:
            raise ValueError(f"DiscreteActions cannot wrap this environment: {problem}")
        super().__init__(env)
        dof = int(env.action_space.shape[0])
        table = np.zeros((2 * dof + 1, dof), np.float32)
        for axis in range(dof):
            table[2 * axis + 1, axis], table[2 * axis + 2, axis] = -1.0, 1.0
        table.setflags(write=False)
        self.table = table
        """(2 * dof + 1, dof) float32: row n is the continuous action of discrete action n."""
        self.action_space = spaces.Discrete(len(table))

    def action(self, action: Any) -> np.ndarray:
        """A discrete action (an int, or a 0-d or 1-element array) -> the continuous one, float32 (dof,)."""
        index = int(np.asarray(action).reshape(-1)[0])
        if not 0 <= index < len(self.table):
            raise ValueError(f"action must be in [0, {len(self.table)}), got {index}")
        return self.table[index].copy()
