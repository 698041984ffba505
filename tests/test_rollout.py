"""Rounds of episodes (``apr.train.rollout.run_round``) on a pool of scripted, in-process environments: what each
episode plays, and the order of actions, answers and learner updates."""

from __future__ import annotations

import numpy as np
import pytest

from apr.train.rollout import EpisodeResult, run_round
from apr.train.workers import StepResult


class ScriptedPool:
    """A pool of toy environments that answers at once and logs every call.

    Worker ``w``'s episode with seed ``s`` lasts ``1 + s % 5`` grasp steps; each observation's ``gripper`` holds
    (seed, step), so a policy that reads it is a pure function of the episode's state, and its images hold
    (seed, step, fixation pending) in their three channels: whose scene, at which step, in which phase.
    """

    def __init__(self, size: int, learned_fixation: bool = False):
        self.size, self.learned_fixation = size, learned_fixation
        self.log: list[tuple] = []
        self.state: dict[int, list[int]] = {}  # worker -> [seed, grasp steps, fixation pending]
        self.answers: dict[int, object] = {}

    def __len__(self) -> int:
        return self.size

    def _observation(self, worker: int) -> dict[str, np.ndarray]:
        seed, steps, _ = self.state[worker]
        gripper = np.zeros(9, np.float32)
        gripper[:2] = seed, steps
        images = np.zeros((3, 2, 2, 3), np.uint8)
        images[..., 0], images[..., 1], images[..., 2] = seed, steps, self.state[worker][2]  # whose, when, phase
        return {"images": images, "viewpoints": np.zeros((3, 6), np.float32),
                "gripper": gripper, "fixation": np.zeros(3, np.float32)}  # fmt: skip

    def send_reset(self, index: int, seed: int) -> None:
        self.state[index] = [seed, 0, int(self.learned_fixation)]
        self.log.append(("reset", index))
        self.answers[index] = (self._observation(index), {})

    def send_step(self, index: int, action: object) -> None:
        self.log.append(("send", index))
        state = self.state[index]
        if state[2]:  # the fixation step
            state[2] = 0
            info = {"fixation_point": np.full(3, index, np.float32), "grasp_steps": 0, "reach_reward": 0.0}
            self.answers[index] = StepResult(self._observation(index), 0.0, False, False, info)
            return
        state[1] += 1
        done = state[1] >= 1 + state[0] % 5
        action_value = float(np.asarray(action["grasp"] if isinstance(action, dict) else action)[0])
        info = {"grasp_steps": state[1], "reach_reward": action_value, "grasp_attempted": done,
                "grasp_success": done and state[0] % 2 == 0, "fixation_point": np.zeros(3, np.float32),
                "tool_tip": np.full(3, 0.01 * state[1], np.float32), "tip_fixation_distance": 0.1}  # fmt: skip
        self.answers[index] = StepResult(self._observation(index), 0.0, done, False, info)

    def receive(self, index: int) -> object:
        self.log.append(("receive", index))
        return self.answers.pop(index)


def pure_policy(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
    """An action that depends only on each observation: (seed + step) / 100 in every entry."""
    size = 3 if phase == "fixation" else 4
    value = (observations["gripper"][:, 0] + observations["gripper"][:, 1]) / 100.0
    return np.repeat(value[:, None], size, axis=1).astype(np.float32)


def outcome(result: EpisodeResult) -> tuple:
    return result.seed, result.grasp_steps, result.attempted, result.success, round(result.reach_return, 6)


@pytest.mark.parametrize("learned_fixation", [False, True])
def test_every_episode_plays_as_it_would_alone(learned_fixation: bool):
    """Episodes of one round are independent: each plays as it does in a round of its own."""
    seeds = [11, 3, 7, 20]
    together = run_round(ScriptedPool(4, learned_fixation), seeds, pure_policy, 4, learned_fixation)
    alone = [run_round(ScriptedPool(1, learned_fixation), [s], pure_policy, 4, learned_fixation)[0] for s in seeds]
    assert [outcome(r) for r in together] == [outcome(r) for r in alone]
    assert [r.grasp_steps for r in together] == [2, 4, 3, 1]
    assert [r.success for r in together] == [False, False, False, True]


def test_the_learner_runs_while_every_worker_steps():
    pool = ScriptedPool(2)
    updates: list[int] = []

    def learn(stepping: int) -> None:
        updates.append(stepping)
        pool.log.append(("learn", stepping))

    run_round(pool, [1, 6], pure_policy, 4, False, while_waiting=learn)
    steps = [event for event in pool.log if event[0] != "reset"]
    assert steps[:5] == [("receive", 0), ("receive", 1), ("send", 0), ("send", 1), ("learn", 2)]  # the resets
    assert steps[5:10] == [("receive", 0), ("receive", 1), ("send", 0), ("send", 1), ("learn", 2)]
    assert steps[10:] == [("receive", 0), ("receive", 1)]
    assert updates == [2, 2]  # both episodes last 2 steps: one update owed per grasp step taken


def test_learned_fixation_starts_with_the_fixation_step_of_every_worker():
    pool = ScriptedPool(2, learned_fixation=True)
    phases: list[str] = []

    def policy(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
        phases.append(phase)
        return pure_policy(observations, phase)

    results = run_round(pool, [0, 1], policy, 4, True)
    assert phases == ["fixation", "grasp", "grasp"]  # seed 0: 1 grasp step, seed 1: 2
    assert [r.grasp_steps for r in results] == [1, 2]


@pytest.mark.parametrize("blind", ["", "fixation", "grasp", "both"])
def test_a_blind_round_shows_each_episode_its_partners_images_in_the_blind_phases_only(blind: str):
    """Episodes are paired (0 with 1, 2 with 3); in a blind phase an episode's images are its partner's, of the
    same phase, at the same step or, once the partner has ended, at its last step; all else stays its own."""
    seeds = [0, 3, 7, 1]  # 1, 4, 3 and 2 grasp steps
    seen: list[tuple[str, np.ndarray, np.ndarray]] = []

    def policy(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
        seen.append((phase, observations["images"][:, 0, 0, 0, 0].copy(), observations["gripper"][:, :2].copy()))
        return pure_policy(observations, phase)

    results = run_round(ScriptedPool(4, learned_fixation=True), seeds, policy, 4, True, blind=blind)
    blind_phases = {"": (), "fixation": ("fixation",), "grasp": ("grasp",), "both": ("fixation", "grasp")}[blind]
    assert [r.grasp_steps for r in results] == [1, 4, 3, 2]  # the policy reads the gripper: episodes play alike
    partner = {0: 3, 3: 0, 7: 1, 1: 7}
    for phase, image_seeds, gripper in seen:
        own = gripper[:, 0].astype(int)
        expected = [partner[s] for s in own] if phase in blind_phases else own.tolist()
        assert image_seeds.tolist() == expected, (phase, gripper)
    assert seen[0][0] == "fixation" and all(phase == "grasp" for phase, *_ in seen[1:])


def test_a_blind_episode_whose_partner_ended_sees_the_partners_last_images_of_its_phase():
    pool = ScriptedPool(2, learned_fixation=True)
    seen: list[np.ndarray] = []

    def policy(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
        seen.append(observations["images"][:, 0, 0, 0].copy())  # (seed, step, fixation pending) of each input
        return pure_policy(observations, phase)

    run_round(pool, [0, 3], policy, 4, True, blind="grasp")  # seed 0 ends after 1 grasp step, seed 3 after 4
    # grasp step 1: each sees the other's post-fixation images (step 0, the grasp phase: nothing pending)
    assert seen[1].tolist() == [[3, 0, 0], [0, 0, 0]]
    # steps 2-4: seed 3 alone, shown seed 0's last images before its grasp (its post-fixation view)
    assert [images.tolist() for images in seen[2:]] == [[[0, 0, 0]]] * 3


def test_a_blind_round_refuses_an_odd_number_of_episodes_and_an_unknown_mode():
    with pytest.raises(ValueError, match="even number of seeds"):
        run_round(ScriptedPool(3), [1, 2, 3], pure_policy, 4, False, blind="both")
    with pytest.raises(ValueError, match="blind must be one of"):
        run_round(ScriptedPool(2), [1, 2], pure_policy, 4, False, blind="images")
