"""n-step returns (``ModelConfig.n_step``): what replay stores for an episode, cut short at its end, and the critic's
target over n steps, against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_sac import CHANNELS, GRID, heads_with_constant_target

from apr.model import sac_critic_loss
from apr.train.config import ConfigError, preset
from apr.train.replay import ReplayBuffer, ReplaySpec
from apr.train.trainer import _Recorder
from apr.train.workers import StepResult

SPEC = ReplaySpec(image_shape=(3, 4, 4, 4), viewpoint_shape=(3, 6), gripper_dim=9, grasp_action_dim=4, fixation_dim=0)
GAMMA = 0.9


def observation(value: int) -> dict:
    """A synthetic observation whose images are all ``value`` (to tell frames apart)."""
    return {"images": np.full(SPEC.image_shape, value, np.uint8), "viewpoints": np.zeros(SPEC.viewpoint_shape),
            "gripper": np.zeros(SPEC.gripper_dim)}  # fmt: skip


def record(rewards: list[float], n_step: int, terminated: bool) -> ReplayBuffer:
    """One episode of ``len(rewards)`` steps, ending terminated (or truncated), through the recorder."""
    replay = ReplayBuffer(32, SPEC)
    recorder = _Recorder(replay, n_step, GAMMA)
    recorder.on_reset(0, observation(0))
    for step, reward in enumerate(rewards, start=1):
        last = step == len(rewards)
        action = np.full(4, step, np.float32)
        result = StepResult(observation(step), reward, terminated and last, not terminated and last, {})
        recorder.on_step(0, action, result)
    return replay


def stored(replay: ReplayBuffer) -> list[tuple[int, int, float, float, int, float]]:
    """Per stored transition: (first frame, frame reached, reward, terminated, steps, the action's first entry)."""
    count = replay.t_count
    return [(int(replay.t_frames[i, 0]), int(replay.t_frames[i, 1]), round(float(replay.t_reward[i]), 5),
             float(replay.t_terminated[i]), int(replay.t_steps[i]), float(replay.t_action[i, 0]))
            for i in range(count)]  # fmt: skip


def test_three_step_transitions_of_a_terminated_episode_are_cut_short_at_its_end() -> None:
    rewards = [1.0, 2.0, 3.0, 4.0, 5.0]
    hand = [  # frames 0..5: frame k is the observation after k steps
        (0, 3, 1 + 0.9 * 2 + 0.81 * 3, 0.0, 3, 1.0),
        (1, 4, 2 + 0.9 * 3 + 0.81 * 4, 0.0, 3, 2.0),
        (2, 5, 3 + 0.9 * 4 + 0.81 * 5, 1.0, 3, 3.0),
        (3, 5, 4 + 0.9 * 5, 1.0, 2, 4.0),
        (4, 5, 5.0, 1.0, 1, 5.0),
    ]
    assert stored(record(rewards, 3, terminated=True)) == [(*h[:2], round(h[2], 5), *h[3:]) for h in hand]


def test_a_truncated_episode_bootstraps_from_its_last_frame() -> None:
    transitions = stored(record([1.0, 2.0], 3, terminated=False))
    assert transitions == [(0, 2, round(1 + 0.9 * 2, 5), 0.0, 2, 1.0), (1, 2, 2.0, 0.0, 1, 2.0)]


def test_one_step_stores_each_step_as_it_comes() -> None:
    replay = ReplayBuffer(32, SPEC)
    recorder = _Recorder(replay, 1, GAMMA)
    recorder.on_reset(0, observation(0))
    recorder.on_step(0, np.zeros(4, np.float32), StepResult(observation(1), 0.5, False, False, {}))
    assert stored(replay) == [(0, 1, 0.5, 0.0, 1, 0.0)]


def test_a_lost_episode_s_waiting_steps_are_dropped_and_workers_do_not_mix() -> None:
    replay = ReplayBuffer(32, SPEC)
    recorder = _Recorder(replay, 3, GAMMA)
    recorder.on_reset(0, observation(0))
    recorder.on_reset(1, observation(10))
    recorder.on_step(0, np.zeros(4, np.float32), StepResult(observation(1), 1.0, False, False, {}))
    recorder.on_step(1, np.ones(4, np.float32), StepResult(observation(11), 7.0, True, False, {}))
    recorder.on_reset(0, observation(20))  # worker 0's episode was lost: its step never reaches replay
    recorder.on_step(0, np.zeros(4, np.float32), StepResult(observation(21), 2.0, True, False, {}))
    assert stored(replay) == [(1, 3, 7.0, 1.0, 1, 1.0), (4, 5, 2.0, 1.0, 1, 0.0)]  # frames in the order written


def test_the_critic_target_discounts_the_bootstrap_by_gamma_to_the_steps() -> None:
    """Target critics that answer 2.0 everywhere and a temperature of ~0: the target is R + 0.99^k * 2.0 where the
    episode goes on after k steps, and R where it ended."""
    heads = heads_with_constant_target(4)
    reward = torch.tensor([0.5, 0.5, 0.5, 1.2])
    terminated = torch.tensor([0.0, 0.0, 0.0, 1.0])
    steps = torch.tensor([1, 2, 3, 3], dtype=torch.int16)
    r = torch.randn(4, CHANNELS, GRID, GRID)
    hand = [0.5 + 0.99 * 2.0, 0.5 + 0.99**2 * 2.0, 0.5 + 0.99**3 * 2.0, 1.2]
    for row in range(4):
        rows = slice(row, row + 1)
        _, metrics = sac_critic_loss(heads, r[rows], torch.zeros(1, 4), reward[rows], r[rows], terminated[rows], 0.99,
                                     steps=steps[rows])  # fmt: skip
        assert metrics["target_q"].item() == pytest.approx(hand[row], abs=1e-5)


def test_n_step_below_one_is_refused_before_any_work() -> None:
    config = preset("cpu-active-target")
    config.model = config.model.replace(n_step=0)
    with pytest.raises(ConfigError, match="--model.n-step must be at least 1"):
        config.check()
