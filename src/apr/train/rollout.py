"""Rounds of episodes: every worker runs one episode, in lockstep, with actions from one batched forward pass.

Between sending actions and receiving the next observations the workers simulate in their processes, and a
``while_waiting`` hook lets the learner update meanwhile. Rounds make a run reproducible whatever the number
of workers: episode ``k`` of a run always gets the seed ``episode_seed(seed, k)``, and a run resumed at a
round boundary continues exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from apr.train.workers import StepResult, WorkerFailure, Workers

Policy = Callable[[dict[str, np.ndarray], str], np.ndarray]
"""(batched observations, "grasp" or "fixation") -> actions (N, A) in [-1, 1]."""


def random_policy(dof: int, rng: np.random.Generator, down_probability: float = 0.0) -> Policy:
    """Random actions in [-1, 1]: ``dof`` numbers for the grasp, 3 for the fixation, uniform, except that with
    ``down_probability`` a grasp step's dz (its third number) is -1 (the benchmark's downward bias)."""

    def policy(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
        size = 3 if phase == "fixation" else dof
        actions = rng.uniform(-1.0, 1.0, (len(observations["images"]), size)).astype(np.float32)
        if phase == "grasp" and down_probability > 0:
            actions[rng.random(len(actions)) < down_probability, 2] = -1.0
        return actions

    return policy


EVAL_SEED = 2_000_000_000
"""Evaluation episodes use fixed seeds (EVAL_SEED + k), the same for every checkpoint and run: paired comparisons."""
EVAL_SEED_COUNT = 100_000
"""The evaluation seeds are EVAL_SEED to EVAL_SEED + EVAL_SEED_COUNT - 1; no training episode gets one of them."""


def episode_seed(run_seed: int, episode: int) -> int:
    """The environment seed of the run's ``episode``-th episode: a draw of ``SeedSequence([run_seed, episode])``,
    moved past the evaluation seeds where it falls among them (about one draw in 43,000), so that no training scene
    is an evaluation scene."""
    seed = int(np.random.SeedSequence([run_seed, episode]).generate_state(1)[0])
    return seed + EVAL_SEED_COUNT if EVAL_SEED <= seed < EVAL_SEED + EVAL_SEED_COUNT else seed


@dataclass
class EpisodeResult:
    """How one episode ended."""

    seed: int
    grasp_steps: int = 0
    attempted: bool = False
    success: bool = False
    lifted: int = 0
    """Objects lifted by the grasp (the lift the paper's grasp reward reads)."""
    grasp_tip: np.ndarray | None = None
    """(3,) m: the tool tip when the grasp started, before the fingers closed (the robot's own pose); None when no
    grasp was attempted."""
    reach_return: float = 0.0
    lost: str = ""
    """Why the episode was lost (its worker died), or empty."""
    fixation_point: np.ndarray | None = None
    fixation_object_distance: float = float("nan")
    """m from the fixation point to the nearest object centre at the fixation action (learned fixation)."""
    object_centres: np.ndarray | None = None
    """(N, 3) the objects' centres when the fixation point was chosen (the simulator's, for statistics)."""
    tip_heights: list[float] = field(default_factory=list)
    """m: the tool tip's z after each grasp step's motion (an attempt's: before the fingers close)."""
    tip_distances: list[float] = field(default_factory=list)
    """m: the tool tip's distance to the fixation point (the target's centre with ``target="env"``) after each grasp
    step's motion (the simulator's, for statistics)."""


class Recorder(Protocol):
    """What the trainer does with experience (evaluation records nothing)."""

    def on_reset(self, worker: int, observation: dict) -> None: ...

    def on_fixation(self, worker: int, action: np.ndarray, result: StepResult) -> None: ...

    def on_step(self, worker: int, action: np.ndarray, result: StepResult) -> None: ...

    def on_end(self, worker: int, result: EpisodeResult) -> None: ...


MODEL_KEYS = ("images", "viewpoints", "gripper", "fixation", "steps_left")
"""The observation entries the model reads (``fixation`` and ``steps_left`` only where the environment's observation
has them)."""


BLIND_PHASES = {"": (), "fixation": ("fixation",), "grasp": ("grasp",), "both": ("fixation", "grasp")}
"""Blind modes of :func:`run_round`: the phases whose policy inputs get another episode's images."""


def blind_phases_text(blind: str) -> str:
    """The phases a blind mode covers, in words ("every phase" for "both", and for "": own images throughout)."""
    return "every phase" if blind in ("", "both") else f"the {blind} phase"


def blind_donor(worker: int) -> int:
    """The episode whose images a blind episode sees: rounds pair episodes (0 with 1, 2 with 3, ...)."""
    return worker ^ 1


def stack(observations: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Batch a list of observation dicts (the keys the model reads that they have)."""
    return {key: np.stack([o[key] for o in observations]) for key in MODEL_KEYS if key in observations[0]}


def run_round(
    workers: Workers,
    seeds: list[int],
    policy: Policy,
    dof: int,
    learned_fixation: bool,
    recorder: Recorder | None = None,
    while_waiting: Callable[[int], None] | None = None,
    blind: str = "",
) -> list[EpisodeResult]:
    """Run one episode on each of the first ``len(seeds)`` workers; return how each ended.

    Args:
        dof: the grasp action size (the learned-fixation env takes a Dict action with both entries).
        while_waiting: called with the number of workers stepping, while they step.
        blind: "" (the policy sees each episode's own observations), or the phases ("fixation", "grasp",
            "both") in which it sees, in place of an episode's images, those of the episode paired with it
            (:func:`blind_donor`): another scene, in the same phase, at the same step or, once that episode has
            ended, at its last step. Everything else (viewpoints, gripper, fixation point) stays the episode's
            own. Needs an even number of seeds.
    """
    if blind not in BLIND_PHASES:
        raise ValueError(f"blind must be one of {tuple(BLIND_PHASES)}, got {blind!r}")
    if blind and len(seeds) % 2:
        raise ValueError(f"a blind round pairs its episodes: give an even number of seeds, got {len(seeds)}")
    results = [EpisodeResult(seed=seed) for seed in seeds]
    observations: dict[int, dict] = {}
    latest: dict[int, dict] = {}  # each episode's last observation before its end: what a blind partner sees
    for worker, seed in enumerate(seeds):
        workers.send_reset(worker, seed)
    for worker in range(len(seeds)):
        answer = workers.receive(worker)
        if isinstance(answer, WorkerFailure):
            results[worker].lost = answer.reason
            continue
        observations[worker] = latest[worker] = answer[0]
        if recorder:
            recorder.on_reset(worker, answer[0])

    def policy_inputs(active: list[int], phase: str) -> dict[str, np.ndarray]:
        batch = stack([observations[w] for w in active])
        if phase in BLIND_PHASES[blind]:
            donors = [latest.get(blind_donor(w), observations[w]) for w in active]
            batch["images"] = np.stack([donor["images"] for donor in donors])
        return batch

    def step_all(phase: str) -> dict[int, StepResult]:
        active = sorted(observations)
        actions = policy(policy_inputs(active, phase), phase)
        for worker, action in zip(active, actions, strict=True):
            if learned_fixation:
                fixation = action if phase == "fixation" else np.zeros(3, np.float32)
                grasp = action if phase == "grasp" else np.zeros(dof, np.float32)
                workers.send_step(worker, {"fixation": fixation, "grasp": grasp})
            else:
                workers.send_step(worker, action)
        if while_waiting:
            while_waiting(len(active))
        answers = {}
        for worker, action in zip(active, actions, strict=True):
            answer = workers.receive(worker)
            if isinstance(answer, WorkerFailure):
                results[worker].lost = answer.reason
                del observations[worker]
                continue
            answers[worker] = answer
            if recorder:
                if phase == "fixation":
                    recorder.on_fixation(worker, action, answer)
                else:
                    recorder.on_step(worker, action, answer)
            observations[worker] = answer.observation
            if not (answer.terminated or answer.truncated):
                latest[worker] = answer.observation
        return answers

    if learned_fixation and observations:
        for worker, answer in step_all("fixation").items():
            result, info = results[worker], answer.info
            result.fixation_point = info["fixation_point"]
            result.fixation_object_distance = float(info.get("fixation_object_distance", float("nan")))
            result.object_centres = info.get("object_centres")
    while observations:
        for worker, answer in step_all("grasp").items():
            result, info = results[worker], answer.info
            result.grasp_steps = info["grasp_steps"]
            result.reach_return += info["reach_reward"]
            result.tip_heights.append(float(info["tool_tip"][2]))
            result.tip_distances.append(float(info["tip_fixation_distance"]))
            if answer.terminated or answer.truncated:
                result.attempted, result.success = info["grasp_attempted"], info["grasp_success"]
                result.lifted = int(info.get("objects_lifted", 0))
                if result.attempted:
                    result.grasp_tip = np.asarray(info["tool_tip"], np.float32).copy()
                result.fixation_point = info["fixation_point"]
                del observations[worker]
                if recorder:
                    recorder.on_end(worker, result)
    return results
