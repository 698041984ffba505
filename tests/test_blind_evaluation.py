"""The blind evaluation on real environments: in a blind phase the policy sees the images of the episode paired with
its own, and everything else of its own episode: the head's joint angles of its own views, its gripper, the point it
looked at, its clock.

``test_rollout.py`` checks the pairing on a scripted pool whose viewpoints are zeros, where views' joint angles
given with the partner's images would pass unseen; here the active environment draws each episode's views around
its own point, so two episodes' joint angles differ. (The passive cameras are static: their views are the same in
every episode, and their framing is tested elsewhere.)
"""

from __future__ import annotations

import numpy as np
import pytest
from test_recipe_training import SpyWorkers

from apr.train.config import EnvConfig
from apr.train.evaluation import EVAL_SEED, evaluate_policy
from apr.train.rollout import blind_donor

BLIND_PHASES = {"fixation": ("fixation",), "grasp": ("grasp",), "both": ("fixation", "grasp")}
"""The phases in which each blind mode shows the partner's images (:func:`apr.train.rollout.run_round`)."""
ENV = EnvConfig(dof=4, target="learned", renderer="tiny", render_size=64)
"""The active environment with a learned fixation (the head draws each episode's views around the point chosen)."""


def looks_then_descends(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
    """Look at opposite corners of the fixation box (row 0 low x, row 1 high x); then descend, fast beside the low
    corner and at half speed beside the high one, so that one episode ends steps before its partner."""
    if phase == "fixation":
        return np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, -1.0]][: len(observations["images"])], np.float32)
    speed = np.where(observations["fixation"][:, 0] < 0.5, -1.0, -0.5)
    return np.stack([np.zeros_like(speed), np.zeros_like(speed), speed, np.zeros_like(speed)], 1).astype(np.float32)


@pytest.mark.parametrize("blind", ["fixation", "grasp", "both"])
def test_a_blind_policy_sees_its_partner_s_images_with_its_own_joint_angles_gripper_point_and_clock(blind: str):
    seen: list[tuple[str, dict[str, np.ndarray]]] = []

    def policy(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
        seen.append((phase, {key: value.copy() for key, value in observations.items()}))
        return looks_then_descends(observations, phase)

    workers = SpyWorkers()
    result = evaluate_policy(policy, ENV, 2, "test", num_workers=2, workers=workers, blind=blind)
    assert [outcome["seed"] for outcome in result.outcomes] == [EVAL_SEED, EVAL_SEED + 1]
    (pool,) = workers.pools
    # What each episode's own policy input was at each call: the reset's, then after each step but its last.
    own = [[episode.reset] + [answer.observation for _, answer in episode.steps[:-1]] for episode in pool.episodes]
    lengths = [len(views) for views in own]
    assert lengths[0] != lengths[1], "the episodes end together: a partner that ended would go untested"
    assert len(seen) == max(lengths)
    for call, (phase, batch) in enumerate(seen):
        active = [w for w in range(2) if call < lengths[w]]
        assert len(batch["images"]) == len(active)
        for row, worker in enumerate(active):
            mine, where = own[worker][call], f"call {call} ({phase}), episode {worker}"
            for key in ("viewpoints", "gripper", "fixation", "steps_left"):
                assert np.array_equal(batch[key][row], mine[key]), f"{where}: {key} not its own"
            partner = own[blind_donor(worker)]
            shown = partner[min(call, len(partner) - 1)] if phase in BLIND_PHASES[blind] else mine
            assert np.array_equal(batch["images"][row], shown["images"]), f"{where}: images"
        if len(active) == 2:  # what tells the two episodes apart, so that a swap would show
            assert not np.array_equal(own[0][call]["viewpoints"], own[1][call]["viewpoints"]), call
            assert not np.array_equal(own[0][call]["images"], own[1][call]["images"]), call
