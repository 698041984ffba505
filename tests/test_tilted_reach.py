"""v2's gripper: tilted, it can still reach the grasp height; pointing down, it moves as in v1. v3's: a change of
tilt turns it about its tool tip; pointing down, it moves as in v2."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from conftest import FALLBACK_WARNING
from gymnasium.utils.env_checker import check_env

from apr.envs.robot import within_tilt


@pytest.mark.parametrize(("b", "c"), [(0.3, 0.2), (math.pi / 4, 0.0), (math.pi / 4, math.pi / 4), (-0.7, 0.6)])
def test_within_tilt_keeps_the_axis_within_the_limit_and_its_direction(b: float, c: float) -> None:
    limit = math.pi / 4
    scaled_b, scaled_c = within_tilt(b, c, limit)
    from_vertical = math.acos(math.cos(scaled_b) * math.cos(scaled_c))
    if math.acos(math.cos(b) * math.cos(c)) <= limit:
        assert (scaled_b, scaled_c) == (b, c)  # within the limit: unchanged
    else:
        assert from_vertical == pytest.approx(limit, abs=1e-6)  # on the limit, scaled together
        assert scaled_b * c == pytest.approx(scaled_c * b)


def _push_down(make_env, env_id: str, action: list[float]) -> tuple[bool, list[float]]:
    env = make_env(env_id, dof=len(action), target="env", foveation="resize", render_size=64)
    env.reset(seed=3)
    heights = []
    for _ in range(15):
        _, _, terminated, truncated, info = env.step(np.array(action, dtype=np.float32))
        heights.append(float(info["tool_tip"][2]))
        if terminated or truncated:
            break
    return bool(info["grasp_attempted"]), heights


def test_a_gripper_tilted_45_degrees_reaches_the_grasp_height_in_v2_and_not_in_v1(make_env) -> None:
    """Straight down, tilted 45 degrees about x: v1's floor holds the end-effector link at z = 0.05 m, where the
    tilted tool tip hangs only 0.155 m lower, above the grasp height (-0.115 m), for all 15 steps."""
    down_tilted = [0.0, 0.0, -1.0, 0.0, 1.0, 0.0]
    attempted_v1, heights_v1 = _push_down(make_env, "apr/ActiveGrasp-v1", down_tilted)
    attempted_v2, _ = _push_down(make_env, "apr/ActiveGrasp-v2", down_tilted)
    assert not attempted_v1 and len(heights_v1) == 15 and min(heights_v1) > -0.115
    assert attempted_v2


@pytest.mark.parametrize(
    ("before", "after"), [("apr/ActiveGrasp-v1", "apr/ActiveGrasp-v2"), ("apr/ActiveGrasp-v2", "apr/ActiveGrasp-v3")]
)
def test_pointing_down_a_version_moves_the_gripper_as_the_one_before(make_env, before: str, after: str) -> None:
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (15, 4)).astype(np.float32)
    actions[:, 2] = -0.8  # descend to the grasp height
    rollouts = []
    for env_id in (before, after):
        env = make_env(env_id, dof=4, target="env", foveation="resize", render_size=64)
        env.reset(seed=5)
        tips = []
        for action in actions:
            _, _, terminated, truncated, info = env.step(action)
            tips.append(info["tool_tip"])
            if terminated or truncated:
                break
        rollouts.append(np.array(tips))
    np.testing.assert_array_equal(rollouts[0], rollouts[1])


def _tip_moves_while_tilting(make_env, env_id: str) -> float:
    """The largest xy distance (m) the tool tip moves from where it was while only the tilts change, 5 steps."""
    env = make_env(env_id, dof=6, target="env", foveation="resize", render_size=64)
    env.reset(seed=3)
    _, _, _, _, info = env.step(np.array([0, 0, -0.5, 0, 0, 0], dtype=np.float32))
    start = info["tool_tip"].copy()
    moved = 0.0
    for tilt in ([1, 0], [1, 0], [0, 1], [0, 1], [-1, -1]):
        _, _, terminated, truncated, info = env.step(np.array([0, 0, 0, 0, *tilt], dtype=np.float32))
        moved = max(moved, float(np.linalg.norm(info["tool_tip"][:2] - start[:2])))
        assert not (terminated or truncated)
    return moved


def test_v3_tilts_about_the_tool_tip_where_v2_swings_it(make_env) -> None:
    """Measured once: v2's tip swings up to 13 cm sideways over these tilts, v3's stays within 1.1 cm (the arm's
    controller does not quite reach the commanded pose in one step)."""
    assert _tip_moves_while_tilting(make_env, "apr/ActiveGrasp-v2") > 0.08
    assert _tip_moves_while_tilting(make_env, "apr/ActiveGrasp-v3") < 0.02


def test_v3_tilted_45_degrees_still_reaches_the_grasp_height(make_env) -> None:
    attempted, _ = _push_down(make_env, "apr/ActiveGrasp-v3", [0.0, 0.0, -1.0, 0.0, 1.0, 0.0])
    assert attempted


def test_v3_passes_the_environment_checker(make_env) -> None:
    """The checker reports most findings (an observation outside its space, a wrong dtype, ...) as warnings only:
    they are collected, and none may be raised."""
    env = make_env("apr/ActiveGrasp-v3", render_size=64)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    complaints = [str(w.message) for w in caught if FALLBACK_WARNING not in str(w.message)]
    assert not complaints, complaints


def test_tilting_about_the_tip_needs_the_tilted_reach() -> None:
    from apr.envs import ActiveGraspEnv

    with pytest.raises(ValueError, match="tilt_about_tip needs tilted_reach"):
        ActiveGraspEnv(tilted_reach=False, tilt_about_tip=True)
