"""Evaluation (SPEC section 5): held-out objects, exactly 5 in the tray, the deterministic action, and the
success rate with a 95% confidence interval (Wilson score interval, sound near 0% and 100%).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Literal

import numpy as np
from tqdm import tqdm

from apr.envs.config import GRASP, REWARD, SCENE
from apr.model.agent import APRAgent
from apr.train.config import ConfigError, EnvConfig
from apr.train.rollout import (
    BLIND_PHASES,
    EVAL_SEED,
    EVAL_SEED_COUNT,
    EpisodeResult,
    Policy,
    Recorder,
    run_round,
    stack,
)
from apr.train.workers import LocalWorkers, WorkersFactory, pool_renderer

GQN_MEASURE_SCENES = 100
"""Scenes of an evaluation (its first episodes) whose first views the generator's measure takes."""


def wilson_interval(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """95% (by default) Wilson score interval of a binomial proportion."""
    if trials == 0:
        return 0.0, 1.0
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    return max(0.0, centre - half), min(1.0, centre + half)


@dataclass
class EvalResult:
    split: str
    episodes: int
    successes: int
    success_rate: float
    ci_low: float
    ci_high: float
    attempts: int
    lost: int
    renderer: str = ""
    """What the evaluation's environments rendered with: "egl", "tiny" or "mixed" (they did not agree)."""
    blind: str = ""
    """"" (the policy saw its own images), or the phases in which it saw another scene's ("fixation", "grasp",
    "both": :func:`apr.train.rollout.run_round`)."""
    fixation: dict = field(default_factory=dict)
    """Learned fixation: where the chosen points lay (:func:`fixation_statistics`); empty otherwise."""
    gqn: dict = field(default_factory=dict)
    """The generator on the episodes' first views (:meth:`apr.model.agent.APRAgent.gqn_measure`): its prediction
    error of view 2 from views 0 and 1, beside the mean image's; empty without a generator, and when blind."""
    episode_ends: dict = field(default_factory=dict)
    """How the episodes ended (:func:`episode_end_statistics`): how many at the 15-step limit, and where the tool
    tip then was."""
    outcomes: list[dict] = field(default_factory=list)
    """Per episode: seed, grasp steps, attempted, success, the tool tip's height and distance to the fixation point
    after each grasp step (m), and with a learned fixation the chosen point and its distance to the nearest
    object."""

    def to_dict(self) -> dict:
        return asdict(self)


class RendererMismatch(ConfigError):
    """A policy would be evaluated on images from another renderer than the one it was trained with."""

    def __init__(self, message: str, trained: str, actual: str):
        super().__init__(message)
        self.trained, self.actual = trained, actual


def renderer_request(trained: str, configured: str) -> str:
    """The renderer to ask evaluation environments for, for a policy trained on ``trained`` images ("egl",
    "tiny", "mixed", or "" when not recorded): "tiny" by name, since it serves everywhere (an "auto" would give
    EGL where it loads); otherwise ``configured``, the run's own setting, whose fallback to TinyRenderer where
    EGL does not load :func:`renderer_mismatch` then names."""
    return "tiny" if trained == "tiny" else configured


def renderer_mismatch(trained: str, actual: str) -> str | None:
    """Why images from ``actual`` are not the kind a policy trained on ``trained`` images saw; None when they
    are, or when the training renderer is not recorded ("")."""
    if not trained or (trained == actual and actual != "mixed"):
        return None
    if trained == "mixed":
        return (f"the policy was trained on images of both renderers (its workers did not agree); these "
                f"environments render with {actual}")  # fmt: skip
    why = " (pybullet's EGL plugin does not load here)" if trained == "egl" and actual == "tiny" else ""
    return (f"the policy was trained on {trained} images, but these environments render with {actual}{why}; the "
            "two renderers' images differ (74% of the values of one observation), so its success on them is not "
            "the policy's own")  # fmt: skip


def evaluate(agent: APRAgent, env: EnvConfig, episodes: int, split: str = "test", num_workers: int = 1,
             workers: WorkersFactory | None = None, trained_renderer: str = "",
             on_mismatch: Literal["refuse", "warn"] = "refuse", blind: str = "") -> EvalResult:  # fmt: skip
    """Run ``episodes`` episodes with the mean action of both policies; lost episodes are rerun (the other
    arguments as for :func:`evaluate_policy`)."""

    def policy(observations, phase):
        return agent.act(observations, deterministic=True, policy=phase)

    first_views = None if blind else FirstViews(GQN_MEASURE_SCENES)  # blind images are not the scene's own
    result = evaluate_policy(policy, env, episodes, split, num_workers, workers, trained_renderer, on_mismatch,
                             blind, recorder=first_views)  # fmt: skip
    if first_views is not None and first_views.observations:
        result.gqn = agent.gqn_measure(stack(first_views.observations))
    return result


class FirstViews:
    """A recorder (:class:`apr.train.rollout.Recorder`) that keeps the first observation of the first ``limit``
    episodes."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.observations: list[dict] = []

    def on_reset(self, worker: int, observation: dict) -> None:
        if len(self.observations) < self.limit:
            self.observations.append(observation)

    def on_fixation(self, worker: int, action: np.ndarray, result: object) -> None: ...

    def on_step(self, worker: int, action: np.ndarray, result: object) -> None: ...

    def on_end(self, worker: int, result: EpisodeResult) -> None: ...


def evaluate_policy(policy: Policy, env: EnvConfig, episodes: int, split: str = "test", num_workers: int = 1,
                    workers: WorkersFactory | None = None, trained_renderer: str = "",
                    on_mismatch: Literal["refuse", "warn"] = "refuse", blind: str = "",
                    recorder: Recorder | None = None) -> EvalResult:  # fmt: skip
    """Run ``episodes`` episodes of ``policy`` on the evaluation seeds ``EVAL_SEED + k`` (the same episodes for
    every policy, checkpoint and run); lost episodes are rerun with the next seeds, up to the last of the
    ``EVAL_SEED_COUNT`` evaluation seeds (which no training episode gets: :func:`apr.train.rollout.episode_seed`).

    Args:
        workers: opens the environments (default: :class:`LocalWorkers`, processes of this machine), as an
            evaluation pool: Ray actors then reserve no CPU (a run's training actors wait meanwhile).
        trained_renderer: what the policy's training images came from ("egl", "tiny", "mixed"; "": not recorded,
            not checked). Before the first episode the environments' renderer is compared with it; a mismatch
            raises :class:`RendererMismatch` (``on_mismatch="refuse"``) or is written to the console ("warn").
        blind: "" or the phases ("fixation", "grasp", "both") in which the policy sees another scene's images
            (:func:`apr.train.rollout.run_round`). Blind rounds pair episodes EVAL_SEED + 2j with EVAL_SEED + 2j + 1,
            whatever the number of workers (at least 2 are opened), so ``episodes`` is rounded up to even.
        recorder: sees every episode's observations, as in training (nothing learns from them here).
    """
    if not 1 <= episodes <= EVAL_SEED_COUNT:
        raise ValueError(f"episodes must be 1 to {EVAL_SEED_COUNT:,} (the evaluation seeds), got {episodes}")
    if blind not in BLIND_PHASES:
        raise ValueError(f"blind must be one of {tuple(BLIND_PHASES)}, got {blind!r}")
    pair = 2 if blind else 1
    episodes = -(-episodes // pair) * pair
    pool_size = max(min(num_workers, episodes) // pair * pair, pair)
    open_workers = workers or LocalWorkers()
    done: list[EpisodeResult] = []
    lost = 0
    next_seed = EVAL_SEED
    with open_workers(pool_size, env.env_id, env.make_kwargs(split), evaluation=True) as pool:
        renderer = pool_renderer(pool.renderers())
        problem = renderer_mismatch(trained_renderer, renderer)
        if problem and on_mismatch == "refuse":
            raise RendererMismatch(problem, trained_renderer, renderer)
        if problem:
            tqdm.write(f"warning: {problem}")
        while len(done) < episodes:
            count = max(min(len(pool), episodes - len(done)) // pair * pair, pair)
            if next_seed + count > EVAL_SEED + EVAL_SEED_COUNT:
                raise RuntimeError(f"{lost} lost episodes spent the {EVAL_SEED_COUNT:,} evaluation seeds; the rest "
                                   "could be training scenes")  # fmt: skip
            seeds = list(range(next_seed, next_seed + count))
            next_seed += count
            for result in run_round(pool, seeds, policy, env.dof, env.learned_fixation, recorder, blind=blind):
                if result.lost:
                    lost += 1
                else:
                    done.append(result)
    successes = sum(r.success for r in done)
    low, high = wilson_interval(successes, len(done))
    return EvalResult(
        split=split, episodes=len(done), successes=successes, success_rate=successes / len(done), ci_low=low,
        ci_high=high, attempts=sum(r.attempted for r in done), lost=lost, renderer=renderer, blind=blind,
        fixation=fixation_statistics(done) if env.learned_fixation else {}, episode_ends=episode_end_statistics(done),
        outcomes=[_outcome(r, env.learned_fixation) for r in done],
    )  # fmt: skip


def _outcome(result: EpisodeResult, learned_fixation: bool) -> dict:
    outcome = {"seed": result.seed, "grasp_steps": result.grasp_steps, "attempted": result.attempted,
               "success": result.success, "tip_heights": [round(z, 4) for z in result.tip_heights],
               "tip_distances": [round(d, 4) for d in result.tip_distances]}  # fmt: skip
    if learned_fixation and result.fixation_point is not None:
        outcome["fixation_point"] = [round(float(x), 4) for x in result.fixation_point]
        outcome["fixation_object_distance"] = round(result.fixation_object_distance, 4)
    return outcome


def episode_end_statistics(results: list[EpisodeResult]) -> dict[str, float]:
    """How episodes ended: ``at_limit`` (how many reached the 15-step limit without an attempt) and its share of
    the episodes, and for those the median height of the tool tip above the grasp trigger and its median distance
    to the fixation point (cm) at the end; ``final_tip_distance_cm``: that median distance over every episode, at
    its last step (an attempt's: where the grasp started). {} without episodes."""
    ended = [r for r in results if r.tip_heights]
    if not ended:
        return {}
    limit = [r for r in ended if not r.attempted]
    centimetres = lambda values: round(100 * float(np.median(values)), 2) if values else None  # noqa: E731
    return {
        "episodes": len(ended), "at_limit": len(limit), "at_limit_share": round(len(limit) / len(ended), 4),
        "at_limit_height_above_trigger_cm": centimetres([r.tip_heights[-1] - GRASP.grasp_height for r in limit]),
        "at_limit_tip_distance_cm": centimetres([r.tip_distances[-1] for r in limit]),
        "final_tip_distance_cm": centimetres([r.tip_distances[-1] for r in ended]),
    }  # fmt: skip


UNIFORM_POINTS_PER_EPISODE = 100
"""Uniformly random fixation points drawn per episode for the chance level of :func:`fixation_statistics`."""


def fixation_statistics(results: list[EpisodeResult]) -> dict[str, float]:
    """Where a learned fixation looked, beside two policies that do not look: one fixed point in the middle of
    the drop area (the bin centre) and uniformly random points of the fixation box, on the same scenes.

    Returns:
        ``median_cm`` (the chosen points' median distance to the nearest object centre), ``spread_x_cm`` and
        ``spread_y_cm`` (the chosen points' standard deviations over the scenes), and ``fixed_median_cm``,
        ``uniform_median_cm`` (the same median for the fixed point and for the random points); {} without
        scenes.
    """
    scenes = [r for r in results if r.object_centres is not None and len(r.object_centres)]
    if not scenes:
        return {}
    rng = np.random.default_rng(0)
    low, high = np.array(REWARD.workspace_low), np.array(REWARD.workspace_high)

    def nearest(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
        return np.linalg.norm(points[:, None] - centres[None], axis=-1).min(axis=1)

    chosen = np.array([r.fixation_point for r in scenes], dtype=np.float64)
    fixed = np.concatenate([nearest(np.array([SCENE.bin_centre]), r.object_centres) for r in scenes])
    uniform = np.concatenate([nearest(rng.uniform(low, high, (UNIFORM_POINTS_PER_EPISODE, 3)), r.object_centres)
                              for r in scenes])  # fmt: skip
    centimetres = lambda value: round(100 * float(value), 2)  # noqa: E731
    return {
        "median_cm": centimetres(np.median([r.fixation_object_distance for r in scenes])),
        "spread_x_cm": centimetres(chosen[:, 0].std()), "spread_y_cm": centimetres(chosen[:, 1].std()),
        "fixed_median_cm": centimetres(np.median(fixed)), "uniform_median_cm": centimetres(np.median(uniform)),
        "scenes": len(scenes),
    }  # fmt: skip
