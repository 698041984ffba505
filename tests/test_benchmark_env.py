"""``apr/BenchmarkGrasp-v4``, the benchmark's own task in apr's world: registration, spaces and the Gymnasium checker,
the benchmark's camera, the scene a seed gives (apr's held-out episodes), the reward for lifting any object, and the
scripted floor on seeded episodes."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pybullet as p
import pytest
from conftest import FALLBACK_WARNING, PASSIVE
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env

import apr
from apr.envs.benchmark import (
    BENCHMARK_ENV_ID,
    AnyObjectTask,
    BenchmarkGraspEnv,
    benchmark_camera,
    register_benchmark_envs,
)
from apr.envs.config import GRASP, SCENE
from apr.train.evaluation import EVAL_SEED

DOWN = np.array([0.0, 0.0, -1.0, 0.0], np.float32)
"""The scripted floor's action at 4-DoF: straight down, no turn."""


@pytest.fixture(autouse=True)
def registered() -> None:
    register_benchmark_envs()


def test_registration_is_idempotent_and_passes_the_v4_task() -> None:
    assert register_benchmark_envs() == [BENCHMARK_ENV_ID] == register_benchmark_envs()
    spec = gymnasium.spec(BENCHMARK_ENV_ID)
    assert spec.entry_point == "apr.envs.benchmark:BenchmarkGraspEnv"
    assert spec.kwargs == apr.VERSIONS["v4"]


@pytest.mark.parametrize("dof", [4, 6])
def test_spaces_and_the_checker(make_env, dof: int) -> None:
    env = make_env(BENCHMARK_ENV_ID, dof=dof, split="test")
    base = env.unwrapped
    assert isinstance(base, BenchmarkGraspEnv)
    assert env.action_space == spaces.Box(-1.0, 1.0, (dof,), np.float32)
    space = env.observation_space
    assert set(space.spaces) == {"images", "viewpoints", "gripper", "steps_left"}
    assert space["images"] == spaces.Box(0, 255, (1, 64, 64, 3), np.uint8)
    assert space["viewpoints"].shape == (1, 6)
    assert space["steps_left"] == spaces.Discrete(GRASP.max_grasp_steps + 1)
    observation, info = env.reset(seed=3)
    assert space.contains(observation)
    assert observation["steps_left"] == GRASP.max_grasp_steps
    assert base.raw_views[0].shape == (128, 128, 3)  # the benchmark's render, resized to 64
    np.testing.assert_allclose(info["fixation_point"], SCENE.bin_centre)  # no target: the bin centre
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=dof != 4, skip_close_check=dof != 4)  # render and close: once
    complaints = [str(w.message) for w in caught if FALLBACK_WARNING not in str(w.message)]
    assert not complaints, complaints


def test_the_camera_is_the_benchmarks() -> None:
    camera = benchmark_camera()
    theirs = np.array(p.computeViewMatrixFromYawPitchRoll([0.23, 0.2, 0.54], 1.0, 245, -56, 0, 2))
    np.testing.assert_allclose(np.array(camera.view_matrix()), theirs, atol=1e-5)
    assert camera.fov_deg == 20.0
    tray = np.array(SCENE.tray_position)
    assert 1.8 < np.linalg.norm(tray - camera.eye) < 1.9  # the tray lies beyond the look point, 1.83 m away
    assert camera.sight_error(tray) < 0.1  # and the line of sight passes through it


def test_a_seed_gives_the_scene_of_apr_evaluation(make_env) -> None:
    """The same seed fills the tray as ``apr/PassiveGrasp-v4`` does: the held-out episodes of apr's evaluations."""
    ours, theirs = make_env(BENCHMARK_ENV_ID, split="test"), make_env(PASSIVE, split="test", render_size=128)
    for seed in (EVAL_SEED, EVAL_SEED + 1):
        _, info_ours = ours.reset(seed=seed)
        _, info_theirs = theirs.reset(seed=seed)
        assert ours.unwrapped.world.object_numbers == theirs.unwrapped.world.object_numbers
        assert len(ours.unwrapped.world.object_numbers) == 5  # the held-out protocol: exactly 5 in the tray
        assert all(number % 10 == 0 for number in ours.unwrapped.world.object_numbers)  # held-out objects
        np.testing.assert_array_equal(info_ours["object_centres"], info_theirs["object_centres"])


def _hold_up(env: gymnasium.Env, number: int) -> None:
    """Fix object ``number`` of the scene above the success height, out of the gripper's way."""
    world = env.unwrapped.world
    uid = world.object_uids[world.object_numbers.index(number)]
    world.client.changeDynamics(uid, -1, mass=0.0)  # static: it stays where it is put
    world.client.resetBasePositionAndOrientation(uid, (0.75, 0.2, GRASP.success_height + 0.3), (0, 0, 0, 1))


def _descend(env: gymnasium.Env) -> tuple[float, dict]:
    """Step straight down until the episode ends; return the last reward and info."""
    for _ in range(GRASP.max_grasp_steps):
        _, reward, terminated, truncated, info = env.step(DOWN)
        assert info["reach_reward"] == 0.0 or env.unwrapped.task.reach_scale > 0
        if terminated or truncated:
            return float(reward), info
    raise AssertionError("the episode did not end within 15 steps")


def test_lifting_an_object_that_is_not_the_target_earns_the_reward(make_env) -> None:
    """Any object above the success height counts (the benchmark's reward), where apr's env-target task counts only
    its target: the same scene, the same object held up, one grasp each."""
    seed = EVAL_SEED + 5
    ours, theirs = make_env(BENCHMARK_ENV_ID, split="test"), make_env(PASSIVE, split="test", dof=4, render_size=128)
    ours.reset(seed=seed)
    theirs.reset(seed=seed)
    world = theirs.unwrapped.world
    target = world.object_numbers[world.object_uids.index(theirs.unwrapped.task.target_uid)]
    other = next(number for number in world.object_numbers if number != target)
    for env in (ours, theirs):
        _hold_up(env, other)
    reward, info = _descend(ours)
    assert info["grasp_attempted"] and info["grasp_success"]
    assert info["objects_lifted"] >= 1 and reward == 1.0
    _, info = _descend(theirs)
    target_up = world.object_position(theirs.unwrapped.task.target_uid)[2] > GRASP.success_height
    assert info["grasp_attempted"] and info["objects_lifted"] >= 1 + target_up
    assert not target_up, "the scene of this seed was chosen so that the gripper misses the target"
    assert not info["grasp_success"] and info["grasp_reward"] == 0.0


def test_the_task_counts_any_lifted_body() -> None:
    class World:
        object_uids = [4, 7, 9]

        @staticmethod
        def object_position(uid: int) -> np.ndarray:
            return np.array([0.6, 0.0, 0.5 if uid == 7 else -0.15])

    task = AnyObjectTask("test")
    outcome = task.grasp_outcome(World(), np.zeros(3), np.array(SCENE.bin_centre))
    assert outcome.lifted == [7] and outcome.success
    World.object_uids = [4, 9]
    assert not task.grasp_outcome(World(), np.zeros(3), np.array(SCENE.bin_centre)).success


def test_the_scripted_floor_on_seeded_episodes(make_env) -> None:
    """Straight down from where the gripper starts (over the tray's middle): every one of the first three held-out
    episodes attempts at the 7th step and lifts something (pinned), with the reward 1 on that step only, and a
    second environment replays them exactly."""
    first, second = make_env(BENCHMARK_ENV_ID, split="test"), make_env(BENCHMARK_ENV_ID, split="test")
    for k in range(3):
        outcomes = []
        for env in (first, second):
            env.reset(seed=EVAL_SEED + k)
            rewards = []
            for _ in range(GRASP.max_grasp_steps):
                observation, reward, terminated, truncated, info = env.step(DOWN)
                rewards.append(reward)
                if terminated or truncated:
                    break
            assert terminated and not truncated
            outcomes.append((len(rewards), info["grasp_success"], info["objects_lifted"], observation["steps_left"]))
            assert rewards[:-1] == [0.0] * (len(rewards) - 1) and rewards[-1] == float(info["grasp_success"])
        assert outcomes[0] == outcomes[1], f"episode {k}: {outcomes}"
        steps, success, lifted, steps_left = outcomes[0]
        assert (steps, success, steps_left) == (7, True, GRASP.max_grasp_steps - 7), f"episode {k}: {outcomes[0]}"
        assert lifted >= 1
