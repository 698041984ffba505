"""The Gymnasium API of ``apr/ActiveGrasp-v2`` and ``apr/PassiveGrasp-v2``: checker, determinism, memory,
spaces, bad input, episode structure, vectorisation."""

from __future__ import annotations

import re
import warnings

import gymnasium
import numpy as np
import pytest
from conftest import ACTIVE, FALLBACK_WARNING, PASSIVE, assert_obs_equal, obs_differ
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env

from apr.envs import ActiveGraspEnv, PassiveGraspEnv

# The learned-fixation workspace, as the ActiveGraspEnv docstring states it (m).
WORKSPACE_LOW = np.array([0.38, -0.2, -0.2])
WORKSPACE_HIGH = np.array([0.75, 0.2, -0.05])
GRASP_HEIGHT = -0.115


# ------------------------------------------------------------------------------------------------ env_checker
# Every active (dof, target) combination and both passive dofs. The render and close checks (which make two
# more environments each) depend on neither dof nor target: they run once per class, on its defaults (6-DoF,
# the environment's target, TinyRenderer), as a new user runs the checker: check_env(gym.make(ID).unwrapped).
CHECK_ENV_CASES = [
    pytest.param(ACTIVE, {}, True, id="active-defaults"),
    pytest.param(ACTIVE, {"dof": 4, "target": "env", "foveation": "resize"}, False, id="active-4dof-env-resize"),
    pytest.param(ACTIVE, {"dof": 6, "target": "learned"}, False, id="active-6dof-learned"),
    pytest.param(ACTIVE, {"dof": 4, "target": "learned"}, False, id="active-4dof-learned"),
    pytest.param(PASSIVE, {}, True, id="passive-defaults"),
    pytest.param(PASSIVE, {"dof": 4}, False, id="passive-4dof"),
]


@pytest.mark.parametrize(("env_id", "kwargs", "full"), CHECK_ENV_CASES)
def test_check_env_passes(make_env, env_id, kwargs, full) -> None:
    env = make_env(env_id, **kwargs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=not full, skip_close_check=not full)
    # The checker reports most findings (observation out of its space, wrong dtypes, ...) as warnings only.
    complaints = [str(w.message) for w in caught if FALLBACK_WARNING not in str(w.message)]
    assert not complaints, complaints


# ------------------------------------------------------------------------------------------------ determinism
def _random_actions(seed: int, dof: int, count: int = 15) -> np.ndarray:
    """A fixed action sequence that tends downward, so an episode usually ends in a grasp attempt."""
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1.0, 1.0, (count, dof)).astype(np.float32)
    actions[:, 2] = rng.uniform(-1.0, -0.2, count)
    return actions


def test_two_default_envs_in_one_process_with_one_seed_give_identical_episodes(make_env) -> None:
    first, second = make_env(ACTIVE), make_env(ACTIVE)  # both open at once, with every default
    assert first.unwrapped.renderer_in_use() == second.unwrapped.renderer_in_use() == "tiny"
    obs_a, info_a = first.reset(seed=11)
    obs_b, info_b = second.reset(seed=11)
    assert_obs_equal(obs_a, obs_b, "reset")
    np.testing.assert_array_equal(info_a["fixation_point"], info_b["fixation_point"])
    done, steps = False, 0
    for steps, action in enumerate(_random_actions(0, 6), start=1):
        obs_a, reward_a, term_a, trunc_a, info_a = first.step(action)
        obs_b, reward_b, term_b, trunc_b, info_b = second.step(action)
        assert_obs_equal(obs_a, obs_b, f"step {steps}")
        assert reward_a == reward_b, f"step {steps}"
        assert (term_a, trunc_a) == (term_b, trunc_b), f"step {steps}"
        assert info_a.keys() == info_b.keys()
        for key in info_a:
            np.testing.assert_array_equal(info_a[key], info_b[key], err_msg=f"step {steps} info[{key!r}]")
        done = term_a or trunc_a
        if done:
            break
    assert done, "the episode neither terminated nor truncated within 15 grasp steps"
    assert steps > 1


def test_reset_with_a_seed_on_a_used_env_matches_a_fresh_env(make_env) -> None:
    fresh, used = make_env(ACTIVE, dof=6, target="learned"), make_env(ACTIVE, dof=6, target="learned")
    fixation = np.array([0.2, -0.1, -0.6], np.float32)
    grasp = np.array([0.3, -0.5, -1.0, 0.5, 0.2, -0.3], np.float32)
    action = {"fixation": fixation, "grasp": grasp}

    reference, _ = fresh.reset(seed=5)
    reference_steps = [fresh.step(action)[:2] for _ in range(2)]

    other, _ = used.reset(seed=6)  # other objects in the tray, the pool holds other bodies
    assert obs_differ(reference, other), "seeds 5 and 6 gave the same first observation"
    for _ in range(3):
        used.step(action)
    again, _ = used.reset(seed=5)
    assert_obs_equal(reference, again, "first observation after reset(seed=5) on a used env")
    for i, (ref_obs, ref_reward) in enumerate(reference_steps):
        obs, reward, *_ = used.step(action)
        assert_obs_equal(ref_obs, obs, f"step {i} after the reset")
        assert reward == ref_reward


# --------------------------------------------------------------------------------------------------- memory
def test_observations_do_not_share_memory(make_env) -> None:
    env = make_env(ACTIVE, dof=4, target="learned")
    action = {"fixation": np.array([0.1, 0.2, -0.5], np.float32), "grasp": np.array([0.5, 0.5, -1, 1], np.float32)}

    env.reset(seed=3)
    expected = [env.step(action)[0] for _ in range(2)]

    obs, info = env.reset(seed=3)
    for i, want in enumerate(expected):
        previous = obs
        for key in ("images", "viewpoints", "gripper"):  # scribble over what the env returned
            previous[key][...] = 0
        info["fixation_point"][...] = 0
        obs, _, _, _, info = env.step(action)
        for key in ("images", "viewpoints", "gripper"):
            assert not np.shares_memory(obs[key], previous[key]), key
        assert_obs_equal(want, obs, f"step {i} after the previous observation was mutated")
    assert not np.shares_memory(info["fixation_point"], env.unwrapped.fixation_point)
    assert not np.shares_memory(obs["images"], env.unwrapped.raw_views[0])


# ------------------------------------------------------------------------------------------- spaces and shapes
@pytest.mark.parametrize(
    ("env_id", "kwargs", "channels"),
    [
        pytest.param(ACTIVE, {"dof": 6, "target": "env"}, 4, id="active-env"),
        pytest.param(ACTIVE, {"dof": 4, "target": "learned"}, 3, id="active-learned"),
        pytest.param(PASSIVE, {"dof": 4}, 4, id="passive"),
    ],
)
def test_observation_shapes_and_dtypes(make_env, env_id, kwargs, channels) -> None:
    env = make_env(env_id, **kwargs)
    obs, info = env.reset(seed=0)
    assert obs["images"].shape == (3, 64, 64, channels)
    assert obs["images"].dtype == np.uint8
    assert obs["viewpoints"].shape == (3, 6)
    assert obs["viewpoints"].dtype == np.float32
    assert obs["gripper"].shape == (9,)
    assert obs["gripper"].dtype == np.float32
    assert ("phase" in obs) == (kwargs.get("target") == "learned")
    assert env.observation_space.contains(obs)
    raw = env.unwrapped.raw_views
    assert len(raw) == 3
    assert all(view.shape == (256, 256, channels) and view.dtype == np.uint8 for view in raw)
    if channels == 4:  # the target mask: 0 or 255, with the target in view
        assert set(np.unique(np.stack(raw)[..., 3]).tolist()) == {0, 255}
        assert obs["images"][..., 3].max() > 0
    # The gripper pose at reset: the tool tip hangs below (0.537, 0, 0.5), pointing down (b = c = 0).
    tip = env.unwrapped.world.arm.tool_tip()
    np.testing.assert_allclose(obs["gripper"][:3], tip, atol=1e-6)
    assert abs(tip[0] - 0.537) < 0.03 and abs(tip[1]) < 0.03 and 0.2 < tip[2] < 0.35
    np.testing.assert_allclose(obs["gripper"][5:], [0, 1, 0, 1], atol=0.02)
    np.testing.assert_allclose(obs["gripper"][3:5] ** 2 @ [1, 1], 1.0, atol=1e-5)


def test_passive_viewpoints_are_the_static_cameras(make_env) -> None:
    env = make_env(PASSIVE, dof=4)
    first, _ = env.reset(seed=0)
    later, *_ = env.step(np.array([1, 1, -1, 1], np.float32))
    np.testing.assert_array_equal(first["viewpoints"], later["viewpoints"])
    np.testing.assert_allclose(np.linalg.norm(first["viewpoints"][:, 3:], axis=1), 1.0, atol=1e-5)


def test_test_split_has_exactly_five_held_out_objects(make_env) -> None:
    env = make_env(ACTIVE, dof=4, target="env", split="test", foveation="resize")
    for seed in range(3):
        _, info = env.reset(seed=seed)
        assert info["num_objects"] == 5
        numbers = env.unwrapped.world.object_numbers
        assert len(numbers) == 5 and all(n % 10 == 0 for n in numbers), numbers


def test_train_split_draws_training_objects(make_env) -> None:
    env = make_env(PASSIVE, dof=4, split="train")
    _, info = env.reset(seed=0)
    numbers = env.unwrapped.world.object_numbers
    assert 1 <= info["num_objects"] == len(numbers) <= 5
    assert all(n % 10 != 0 for n in numbers), numbers


# ------------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("env_id", "name", "value", "valid"),
    [
        (ACTIVE, "dof", 5, "(4, 6)"),
        (ACTIVE, "target", "x", "('env', 'learned')"),
        (ACTIVE, "foveation", "x", "('logpolar', 'resize')"),
        (ACTIVE, "split", "x", "('train', 'test')"),
        (ACTIVE, "renderer", "x", "('auto', 'egl', 'tiny')"),
        (ACTIVE, "initial_views", "random", "('drawn', 'fixed')"),
        (PASSIVE, "dof", 3, "(4, 6)"),
        (PASSIVE, "split", "val", "('train', 'test')"),
        (PASSIVE, "renderer", "opengl", "('auto', 'egl', 'tiny')"),
    ],
)
def test_bad_constructor_args_raise_listing_valid_values(env_id, name, value, valid) -> None:
    kwargs = {"renderer": "tiny", name: value}
    with pytest.raises(ValueError, match=rf"{name} must be one of {re.escape(valid)}"):
        gymnasium.make(env_id, **kwargs)


@pytest.mark.parametrize("env_id", [ACTIVE, PASSIVE])
@pytest.mark.parametrize("render_size", [0, 96, 100, 64.0, True, "256"])
def test_a_render_size_that_is_not_a_multiple_of_64_is_refused(env_id, render_size) -> None:
    with pytest.raises(ValueError, match=r"render_size must be a positive multiple of 64"):
        gymnasium.make(env_id, render_size=render_size)


@pytest.mark.parametrize(("env_id", "kwargs"), [(ACTIVE, {"foveation": "logpolar"}), (PASSIVE, {})])
def test_a_smaller_render_gives_the_same_observation_space(make_env, env_id, kwargs) -> None:
    env = make_env(env_id, dof=4, render_size=128, render_mode="rgb_array", **kwargs)
    observation, _ = env.reset(seed=0)
    assert env.observation_space.contains(observation) and observation["images"].shape == (3, 64, 64, 4)
    assert env.render().shape == (128, 128, 3)
    assert all(view.shape == (128, 128, 4) for view in env.unwrapped.raw_views)


@pytest.mark.parametrize("env_class", [ActiveGraspEnv, PassiveGraspEnv])
def test_bad_render_mode_raises(env_class) -> None:
    # Through the class: gymnasium.make would wrap an unknown "human" mode in its own HumanRendering.
    with pytest.raises(ValueError, match=r"render_mode must be one of \(None, 'rgb_array'\)"):
        env_class(renderer="tiny", render_mode="depth")


@pytest.fixture(scope="module")
def box_env(make_module_env):
    return make_module_env(ACTIVE, dof=4, target="env", foveation="resize")


@pytest.fixture(scope="module")
def dict_env(make_module_env):
    return make_module_env(ACTIVE, dof=6, target="learned", foveation="resize")


@pytest.mark.parametrize(("index", "value"), [(0, np.nan), (2, np.inf), (3, -np.inf)])
def test_non_finite_box_action_raises_naming_the_entry(box_env, index, value) -> None:
    box_env.reset(seed=0)
    action = np.zeros(4, np.float32)
    action[index] = value
    with pytest.raises(ValueError, match=rf"action\[{index}\]"):
        box_env.step(action)
    # The rejected action did not count as a step.
    *_, info = box_env.step(np.zeros(4, np.float32))
    assert info["grasp_steps"] == 1


@pytest.mark.parametrize(("key", "index", "value"), [("fixation", 1, np.nan), ("grasp", 4, np.inf)])
def test_non_finite_dict_action_raises_naming_key_and_entry(dict_env, key, index, value) -> None:
    dict_env.reset(seed=0)
    action = {"fixation": np.zeros(3, np.float32), "grasp": np.zeros(6, np.float32)}
    action[key][index] = value
    with pytest.raises(ValueError, match=rf"\[{key!r}\]\[{index}\]"):
        dict_env.step(action)
    obs, *_ = dict_env.step({"fixation": np.zeros(3, np.float32), "grasp": np.zeros(6, np.float32)})
    assert obs["phase"] == 1


def test_action_outside_the_box_is_clipped(box_env) -> None:
    direction = np.array([1.0, -1.0, -1.0, 1.0], np.float32)
    results = {}
    for scale in (1.0, 5.0, 0.5):
        box_env.reset(seed=2)
        obs, reward, *_ = box_env.step(scale * direction)
        results[scale] = (obs, reward)
    assert_obs_equal(results[1.0][0], results[5.0][0], "action 5.0 vs 1.0")
    assert results[1.0][1] == results[5.0][1]
    assert obs_differ(results[1.0][0], results[0.5][0]), "the comparison cannot tell actions apart"


def test_fixation_action_outside_the_box_is_clipped(dict_env) -> None:
    points = {}
    for scale in (1.0, 5.0):
        dict_env.reset(seed=0)
        fixation = scale * np.array([1.0, -1.0, 1.0], np.float32)
        *_, info = dict_env.step({"fixation": fixation, "grasp": np.zeros(6, np.float32)})
        points[scale] = info["fixation_point"]
    np.testing.assert_array_equal(points[1.0], points[5.0])
    np.testing.assert_allclose(points[5.0], [WORKSPACE_HIGH[0], WORKSPACE_LOW[1], WORKSPACE_HIGH[2]], atol=1e-6)


def test_malformed_actions_raise(box_env, dict_env) -> None:
    box_env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        box_env.step(np.zeros(6, np.float32))
    dict_env.reset(seed=0)
    with pytest.raises(ValueError, match="keys"):
        dict_env.step({"grasp": np.zeros(6, np.float32)})


def test_step_before_reset_raises(make_env) -> None:
    env = make_env(ACTIVE, dof=4, target="env").unwrapped  # below gymnasium's own OrderEnforcing wrapper
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(4, np.float32))


# ----------------------------------------------------------------------------------------- episode structure
def test_env_target_episode_ends_after_15_grasp_steps_terminated_with_its_clock(box_env) -> None:
    """v1: the 15-step limit is part of the task: it terminates, and the observation counts the steps left."""
    assert box_env.observation_space["steps_left"] == spaces.Discrete(16)
    obs, _ = box_env.reset(seed=1)
    assert obs["steps_left"] == 15 and obs["steps_left"] in box_env.observation_space["steps_left"]
    stay_high = np.array([0.3, -0.3, 1.0, 0.5], np.float32)
    for step in range(1, 16):
        obs, reward, terminated, truncated, info = box_env.step(stay_high)
        assert not info["grasp_attempted"] and not truncated, step
        assert terminated == (step == 15), step
        assert info["grasp_steps"] == step and obs["steps_left"] == 15 - step
        assert reward == pytest.approx(info["reach_reward"])
    with pytest.raises(RuntimeError, match="reset"):
        box_env.unwrapped.step(stay_high)
    obs, _ = box_env.reset(seed=1)
    assert obs["steps_left"] == 15


def test_the_earlier_task_v0_truncates_after_15_grasp_steps_with_no_clock(make_env) -> None:
    env = make_env("apr/ActiveGrasp-v0", dof=4, target="env", foveation="resize", render_size=64)
    assert "steps_left" not in env.observation_space.spaces
    env.reset(seed=1)
    stay_high = np.array([0.3, -0.3, 1.0, 0.5], np.float32)
    for step in range(1, 16):
        obs, _, terminated, truncated, _ = env.step(stay_high)
        assert not terminated and truncated == (step == 15) and "steps_left" not in obs, step


def test_grasp_attempt_terminates_the_episode(box_env) -> None:
    obs, _ = box_env.reset(seed=4)
    down = np.array([0.0, 0.0, -1.0, 0.0], np.float32)
    for _ in range(15):
        tip_z = obs["gripper"][2]
        obs, reward, terminated, truncated, info = box_env.step(down)
        assert reward == pytest.approx(info["reach_reward"] + info["grasp_reward"])
        assert terminated == info["grasp_attempted"]
        if terminated:
            break
        assert obs["gripper"][2] > GRASP_HEIGHT, "the tool tip went below the grasp height without an attempt"
        assert not truncated
    assert terminated and not truncated, "descending at full speed never attempted a grasp"
    assert tip_z > GRASP_HEIGHT
    assert info["grasp_reward"] == float(info["grasp_success"])
    with pytest.raises(RuntimeError, match="reset"):
        box_env.unwrapped.step(down)


def test_learned_fixation_phase(dict_env) -> None:
    obs, info = dict_env.reset(seed=7)
    assert obs["phase"] == 0 and info["phase"] == 0
    np.testing.assert_allclose(info["fixation_point"], [0.55, 0.0, -0.15], atol=1e-6)  # the bin centre
    head = dict_env.unwrapped.world.head
    assert head.camera().sight_error(info["fixation_point"]) < 0.02

    fixation = np.array([0.4, -0.2, 0.6], np.float32)
    grasp = np.array([1.0, 1.0, -1.0, 1.0, 1.0, 1.0], np.float32)  # unused in the fixation phase
    gripper_before = obs["gripper"]
    obs, reward, terminated, truncated, info = dict_env.step({"fixation": fixation, "grasp": grasp})
    expected = WORKSPACE_LOW + 0.5 * (fixation.astype(np.float64) + 1.0) * (WORKSPACE_HIGH - WORKSPACE_LOW)
    assert reward == 0.0 and not terminated and not truncated
    assert obs["phase"] == 1 and info["phase"] == 1
    assert info["grasp_steps"] == 0 and obs["steps_left"] == 15  # the glimpse is no grasp step
    np.testing.assert_allclose(info["fixation_point"], expected, atol=1e-6)
    np.testing.assert_allclose(dict_env.unwrapped.fixation_point, expected, atol=1e-9)
    np.testing.assert_array_equal(obs["gripper"], gripper_before)  # the arm did not move
    assert head.camera().sight_error(expected) < 0.02  # the new views look at the chosen point

    obs, reward, terminated, truncated, info = dict_env.step({"fixation": -fixation, "grasp": grasp * 0})
    assert obs["phase"] == 1 and info["grasp_steps"] == 1
    np.testing.assert_allclose(info["fixation_point"], expected, atol=1e-6)  # fixed for the episode


def test_render_rgb_array(make_env) -> None:
    env = make_env(ACTIVE, dof=4, target="env", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, env.unwrapped.raw_views[0][..., :3])
    assert not np.shares_memory(frame, env.unwrapped.raw_views[0])


# ---------------------------------------------------------------------------------------------- vectorised
def test_a_sync_vector_env_of_default_envs_works_and_its_members_agree_for_one_seed(make_env) -> None:
    envs = gymnasium.make_vec(ACTIVE, num_envs=2, vectorization_mode="sync")
    try:
        batch, _ = envs.reset(seed=[4, 4])
        assert batch["images"].shape == (2, 3, 64, 64, 4)
        lone, _ = make_env(ACTIVE).reset(seed=4)
        for key in lone:
            np.testing.assert_array_equal(batch[key][0], batch[key][1], err_msg=key)
            np.testing.assert_array_equal(batch[key][0], lone[key], err_msg=key)
        batch, reward, *_ = envs.step(np.tile(np.array([0.2, 0.0, -0.5, 0.1, 0.0, 0.0], np.float32), (2, 1)))
        np.testing.assert_array_equal(batch["images"][0], batch["images"][1])
        assert reward[0] == reward[1]
    finally:
        envs.close()


def test_async_vector_env_steps_with_batched_dict_actions() -> None:
    envs = gymnasium.vector.AsyncVectorEnv([lambda: gymnasium.make(ACTIVE, dof=4, target="learned")] * 2)
    try:
        obs, info = envs.reset(seed=0)
        assert obs["images"].shape == (2, 3, 64, 64, 3) and obs["images"].dtype == np.uint8
        np.testing.assert_array_equal(obs["phase"], [0, 0])
        assert not np.array_equal(obs["images"][0], obs["images"][1])  # seeds 0 and 1
        action = {
            "fixation": np.array([[0.0, 0.0, -0.5], [0.5, -0.5, -0.5]], np.float32),
            "grasp": np.zeros((2, 4), np.float32),
        }
        obs, reward, terminated, truncated, info = envs.step(action)
        np.testing.assert_array_equal(obs["phase"], [1, 1])
        np.testing.assert_array_equal(reward, [0.0, 0.0])
        assert not terminated.any() and not truncated.any()
        action["grasp"][:, 2] = -1.0
        obs, reward, terminated, truncated, info = envs.step(action)
        assert obs["gripper"].shape == (2, 9) and reward.shape == (2,)
        np.testing.assert_array_equal(info["grasp_steps"], [1, 1])
    finally:
        envs.close()


# ------------------------------------------------------------------------------------ what a policy may see
def _float_entries(obs: dict) -> np.ndarray:
    """Every float the observation holds, flattened (images excluded: they are uint8 pictures)."""
    return np.concatenate([np.ravel(value) for key, value in obs.items()
                           if key != "images" and np.asarray(value).dtype.kind == "f"])  # fmt: skip


@pytest.mark.parametrize(("env_id", "kwargs"), [pytest.param(PASSIVE, {"dof": 4}, id="passive"),
                                                pytest.param(ACTIVE, {"dof": 4}, id="active-env")])  # fmt: skip
def test_an_env_target_observation_holds_no_target_coordinates(make_env, env_id, kwargs) -> None:
    env = make_env(env_id, **kwargs)
    obs, info = env.reset(seed=3)
    unwrapped = env.unwrapped
    target = unwrapped.world.object_centre(unwrapped.task.target_uid)  # the simulator's answer
    np.testing.assert_allclose(info["fixation_point"], target, atol=1e-6)  # info may say it ...
    assert "fixation" not in obs and "fixation" not in env.observation_space.spaces  # ... the observation not
    values = _float_entries(obs)
    windows = np.lib.stride_tricks.sliding_window_view(values, 3)
    assert np.abs(windows - target).max(axis=1).min() > 1e-3  # no three entries in a row are the target (to 1 mm)
    obs, *_ = env.step(np.zeros(4, np.float32))
    assert "fixation" not in obs


def test_reveal_target_puts_the_simulator_target_in_the_observation(make_env) -> None:
    env = make_env(ACTIVE, dof=4, reveal_target=True)
    obs, _ = env.reset(seed=3)
    unwrapped = env.unwrapped
    np.testing.assert_allclose(obs["fixation"], unwrapped.world.object_centre(unwrapped.task.target_uid), atol=1e-6)
    assert env.observation_space.contains(obs)
    with pytest.raises(ValueError, match="reveal_target needs target='env'"):
        ActiveGraspEnv(target="learned", reveal_target=True)


def test_a_learned_fixation_observes_the_point_it_chose_and_info_the_objects(dict_env) -> None:
    obs, info = dict_env.reset(seed=0)
    np.testing.assert_allclose(obs["fixation"], [0.55, 0.0, -0.15], atol=1e-6)  # the bin centre, not an object
    centres = info["object_centres"]
    assert centres.shape == (info["num_objects"], 3)
    obs, _, _, _, info = dict_env.step({"fixation": np.zeros(3, np.float32), "grasp": np.zeros(6, np.float32)})
    np.testing.assert_allclose(obs["fixation"], info["fixation_point"], atol=1e-6)
    nearest = np.linalg.norm(info["object_centres"] - info["fixation_point"], axis=1).min()
    assert info["fixation_object_distance"] == pytest.approx(nearest, abs=1e-6)


def test_fixed_initial_views_are_the_same_in_every_episode_and_the_later_views_are_drawn(make_env) -> None:
    fixed = make_env(ACTIVE, dof=4, target="learned", foveation="resize", render_size=64, initial_views="fixed")
    drawn = make_env(ACTIVE, dof=4, target="learned", foveation="resize", render_size=64)
    action = {"fixation": np.zeros(3, np.float32), "grasp": np.zeros(4, np.float32)}
    views = {}
    for seed in (1, 2):
        for name, env in (("fixed", fixed), ("drawn", drawn)):
            observation, info = env.reset(seed=seed)
            assert env.unwrapped.world.head.camera().sight_error(info["fixation_point"]) < 0.02
            views[name, seed] = observation["viewpoints"], env.step(action)[0]["viewpoints"]
    np.testing.assert_array_equal(views["fixed", 1][0], views["fixed", 2][0])  # the same three viewpoints at reset
    assert len({tuple(view) for view in views["fixed", 1][0].round(3)}) == 3  # three different ones
    assert not np.allclose(views["fixed", 1][1], views["fixed", 2][1])  # after the fixation: drawn
    assert not np.allclose(views["drawn", 1][0], views["drawn", 2][0])
