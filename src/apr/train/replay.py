"""Replay memory: every observation stored once, as uint8 images, and transitions that point at them.

A grasp transition (obs, action, reward, next_obs, terminated, steps) refers to two *frames*; consecutive
transitions of an episode share one, so an episode of n steps takes n + 1 frames instead of 2n. ``steps`` is how
many environment steps lie between the two frames (1, or up to n for n-step returns, whose reward is then the
discounted sum over them). Frames and transitions are
rings: when a frame is overwritten, the transitions still pointing at it are no longer sampled (each frame
remembers when it was written, each transition when its frames were). The fixation policy's bandit samples
(bin-centre observation, fixation action, the episode's grasp reward, and what the robot knows of how its grasp
ended: whether an object was lifted and where its tool tip was when the grasp started) live beside them and point at
frames too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class ReplaySpec:
    """Shapes of what is stored."""

    image_shape: tuple[int, ...]
    """(3, 64, 64, C)"""
    viewpoint_shape: tuple[int, ...]
    """(3, 6)"""
    gripper_dim: int
    grasp_action_dim: int
    fixation_dim: int = 3
    """3 where the observations hold a fixation point (learned fixation, ``reveal_target``), else 0."""
    fixation_action_dim: int = 3
    steps_left: bool = False
    """The observations hold the steps left (the environments' v1 and v2)."""
    max_objects: int = 5
    """Object centres stored per fixation sample (the scene at the fixation action; padded with NaN)."""


class FrameRing:
    """A ring of observations; ``stamp[i]`` counts the writes so far when slot ``i`` was last written."""

    def __init__(self, capacity: int, spec: ReplaySpec):
        self.capacity = capacity
        self.images = np.zeros((capacity, *spec.image_shape), np.uint8)
        self.viewpoints = np.zeros((capacity, *spec.viewpoint_shape), np.float32)
        self.gripper = np.zeros((capacity, spec.gripper_dim), np.float32)
        self.fixation = np.zeros((capacity, spec.fixation_dim), np.float32)
        self.steps_left = np.zeros(capacity if spec.steps_left else 0, np.int8)
        self.stamp = np.full(capacity, -1, np.int64)
        self.writes = 0

    def add(self, observation: dict) -> tuple[int, int]:
        """Store one observation; return (slot, stamp)."""
        slot = self.writes % self.capacity
        self.images[slot] = observation["images"]
        self.viewpoints[slot] = observation["viewpoints"]
        self.gripper[slot] = observation["gripper"]
        if self.fixation.shape[1]:  # the observation has a fixation point (``ReplaySpec.fixation_dim``)
            self.fixation[slot] = observation["fixation"]
        if len(self.steps_left):
            self.steps_left[slot] = observation["steps_left"]
        self.stamp[slot] = self.writes
        self.writes += 1
        return slot, self.writes - 1

    def batch(self, slots: np.ndarray) -> dict[str, np.ndarray]:
        batch = {"images": self.images[slots], "viewpoints": self.viewpoints[slots], "gripper": self.gripper[slots]}
        if self.fixation.shape[1]:
            batch["fixation"] = self.fixation[slots]
        if len(self.steps_left):
            batch["steps_left"] = self.steps_left[slots]
        return batch


class ReplayBuffer:
    """Grasp transitions and fixation samples over one frame ring.

    Args:
        capacity: grasp transitions kept; the frame ring holds ``capacity + capacity // 2`` observations (an
            episode of n steps uses n + 1 frames; episodes average well over 2 steps) and the fixation ring
            ``capacity // 4`` samples.
    """

    def __init__(self, capacity: int, spec: ReplaySpec):
        if capacity < 1:
            raise ValueError(f"replay capacity must be positive, got {capacity}")
        self.spec = spec
        self.capacity = capacity
        self.frames = FrameRing(capacity + capacity // 2, spec)
        self.fixation_capacity = max(capacity // 4, 1)
        # grasp transitions: frame slots and stamps of obs and next obs, action, reward, terminated, steps between
        self.t_frames = np.zeros((capacity, 2), np.int64)
        self.t_stamps = np.full((capacity, 2), -1, np.int64)
        self.t_action = np.zeros((capacity, spec.grasp_action_dim), np.float32)
        self.t_reward = np.zeros(capacity, np.float32)
        self.t_terminated = np.zeros(capacity, np.float32)
        self.t_steps = np.ones(capacity, np.int16)  # ones: a replay file written before n-step returns loads as 1-step
        self.t_count = 0
        # fixation samples
        self.f_frame = np.zeros(self.fixation_capacity, np.int64)
        self.f_stamp = np.full(self.fixation_capacity, -1, np.int64)
        self.f_action = np.zeros((self.fixation_capacity, spec.fixation_action_dim), np.float32)
        self.f_reward = np.zeros(self.fixation_capacity, np.float32)
        self.f_lifted = np.zeros(self.fixation_capacity, np.float32)
        self.f_tip = np.full((self.fixation_capacity, 3), np.nan, np.float32)
        self.f_centres = np.full((self.fixation_capacity, spec.max_objects, 3), np.nan, np.float32)
        self.f_count = 0

    @staticmethod
    def bytes_needed(capacity: int, spec: ReplaySpec) -> int:
        """Memory the buffer allocates for ``capacity`` (what ``__init__`` will take)."""
        poses = int(np.prod(spec.viewpoint_shape)) + spec.gripper_dim + spec.fixation_dim
        frame = int(np.prod(spec.image_shape)) + 4 * poses + 8 + spec.steps_left
        transition = 8 * 4 + 4 * (spec.grasp_action_dim + 2) + 2
        fixation = 16 + 4 * (spec.fixation_action_dim + 1 + 1 + 3 + 3 * spec.max_objects)
        return (capacity + capacity // 2) * frame + capacity * transition + max(capacity // 4, 1) * fixation

    # ----------------------------------------------------------------------------------------------- adding
    def add_frame(self, observation: dict) -> tuple[int, int]:
        """Store an observation; the returned (slot, stamp) is what transitions refer to."""
        return self.frames.add(observation)

    def add_transition(self, obs_ref: tuple[int, int], action: np.ndarray, reward: float,
                       next_ref: tuple[int, int], terminated: bool, steps: int = 1) -> None:  # fmt: skip
        """A grasp transition from the frame ``obs_ref`` to ``next_ref``, ``steps`` environment steps later, with the
        (discounted) reward collected over them."""
        i = self.t_count % self.capacity
        self.t_frames[i] = obs_ref[0], next_ref[0]
        self.t_stamps[i] = obs_ref[1], next_ref[1]
        self.t_action[i] = action
        self.t_reward[i] = reward
        self.t_terminated[i] = float(terminated)
        self.t_steps[i] = steps
        self.t_count += 1

    def add_fixation(self, obs_ref: tuple[int, int], action: np.ndarray, reward: float,
                     object_centres: np.ndarray | None = None, lifted: bool = False,
                     grasp_tip: np.ndarray | None = None) -> None:  # fmt: skip
        """A bandit sample: the observation it chose from, the fixation action, the episode's grasp reward, whether
        an object was lifted and the tool tip (3,) when the grasp started (None: no grasp was attempted), and the
        objects' centres (N, 3) when it chose (the simulator's, for the proximity flag only; at most
        ``max_objects``)."""
        i = self.f_count % self.fixation_capacity
        self.f_frame[i], self.f_stamp[i] = obs_ref
        self.f_action[i] = action
        self.f_reward[i] = reward
        self.f_lifted[i] = float(lifted)
        self.f_tip[i] = np.nan if grasp_tip is None else np.asarray(grasp_tip, np.float32)
        self.f_centres[i] = np.nan
        if object_centres is not None and len(object_centres):
            kept = np.asarray(object_centres, np.float32)[: self.spec.max_objects]
            self.f_centres[i, : len(kept)] = kept
        self.f_count += 1

    # --------------------------------------------------------------------------------------------- sampling
    def _valid_transitions(self) -> np.ndarray:
        stored = min(self.t_count, self.capacity)
        live = self.frames.stamp[self.t_frames[:stored]] == self.t_stamps[:stored]
        return np.flatnonzero(live.all(axis=1))

    def _valid_fixations(self) -> np.ndarray:
        stored = min(self.f_count, self.fixation_capacity)
        return np.flatnonzero(self.frames.stamp[self.f_frame[:stored]] == self.f_stamp[:stored])

    def num_transitions(self) -> int:
        return len(self._valid_transitions())

    def num_fixations(self) -> int:
        return len(self._valid_fixations())

    def sample_grasp(self, batch_size: int, rng: np.random.Generator) -> dict[str, np.ndarray | dict]:
        """Uniform grasp transitions: obs and next_obs dicts of arrays, action, reward, terminated, steps."""
        index = rng.choice(self._valid_transitions(), size=batch_size)
        return {
            "obs": self.frames.batch(self.t_frames[index, 0]),
            "action": self.t_action[index],
            "reward": self.t_reward[index],
            "next_obs": self.frames.batch(self.t_frames[index, 1]),
            "terminated": self.t_terminated[index],
            "steps": self.t_steps[index],
        }

    def sample_fixation(self, batch_size: int, rng: np.random.Generator) -> dict[str, np.ndarray | dict]:
        """Uniform fixation samples: obs dict of arrays, action, reward, lifted (B,), grasp_tip (B, 3; NaN without
        an attempt), object_centres (B, max_objects, 3)."""
        index = rng.choice(self._valid_fixations(), size=batch_size)
        return {"obs": self.frames.batch(self.f_frame[index]), "action": self.f_action[index],
                "reward": self.f_reward[index], "lifted": self.f_lifted[index], "grasp_tip": self.f_tip[index],
                "object_centres": self.f_centres[index]}  # fmt: skip

    # ------------------------------------------------------------------------------------------ persistence
    def state(self) -> dict[str, np.ndarray]:
        """The filled part of every array (for ``np.savez``): a young buffer saves small."""
        filled = {
            "t": min(self.t_count, self.capacity),
            "f": min(self.f_count, self.fixation_capacity),
            "frames": min(self.frames.writes, self.frames.capacity),
        }
        # t_* arrays hold grasp transitions, f_* arrays fixation samples
        arrays = {name: value[: filled[name[0]]] for name, value in vars(self).items()
                  if isinstance(value, np.ndarray)}  # fmt: skip
        arrays.update({f"frames_{name}": value[: filled["frames"]] for name, value in vars(self.frames).items()
                       if isinstance(value, np.ndarray)})  # fmt: skip
        arrays["counts"] = np.array([self.t_count, self.f_count, self.frames.writes])
        return arrays

    def save(self, path: Path) -> None:
        """Write to ``path`` (an .npz file) atomically."""
        temporary = path.with_name(path.name + ".tmp")
        with open(temporary, "wb") as file:
            np.savez(file, **self.state())
        temporary.replace(path)

    def load(self, path: Path) -> None:
        with np.load(path) as data:
            for name in data.files:
                if name == "counts":
                    self.t_count, self.f_count, self.frames.writes = (int(x) for x in data[name])
                elif name.startswith("frames_"):
                    getattr(self.frames, name.removeprefix("frames_"))[: len(data[name])] = data[name]
                else:
                    getattr(self, name)[: len(data[name])] = data[name]
