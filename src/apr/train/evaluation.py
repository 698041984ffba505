"""Evaluation (SPEC section 5): held-out objects, exactly 5 in the tray, the deterministic action, and the
success rate with a 95% confidence interval (Wilson score interval, sound near 0% and 100%).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Literal

from tqdm import tqdm

from apr.model.agent import APRAgent
from apr.train.config import ConfigError, EnvConfig
from apr.train.rollout import EpisodeResult, Policy, run_round
from apr.train.workers import LocalWorkers, WorkersFactory, pool_renderer

EVAL_SEED = 2_000_000_000
"""Evaluation episodes use fixed seeds (EVAL_SEED + k), the same for every checkpoint and run: paired comparisons."""


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
    outcomes: list[dict] = field(default_factory=list)
    """Per episode: seed, grasp steps, attempted, success."""

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
             on_mismatch: Literal["refuse", "warn"] = "refuse") -> EvalResult:  # fmt: skip
    """Run ``episodes`` episodes with the mean action of both policies; lost episodes are rerun (the other
    arguments as for :func:`evaluate_policy`)."""

    def policy(observations, phase):
        return agent.act(observations, deterministic=True, policy=phase)

    return evaluate_policy(policy, env, episodes, split, num_workers, workers, trained_renderer, on_mismatch)


def evaluate_policy(policy: Policy, env: EnvConfig, episodes: int, split: str = "test", num_workers: int = 1,
                    workers: WorkersFactory | None = None, trained_renderer: str = "",
                    on_mismatch: Literal["refuse", "warn"] = "refuse") -> EvalResult:  # fmt: skip
    """Run ``episodes`` episodes of ``policy`` on the evaluation seeds ``EVAL_SEED + k`` (the same episodes for
    every policy, checkpoint and run); lost episodes are rerun with the next seeds.

    Args:
        workers: opens the environments (default: :class:`LocalWorkers`, processes of this machine), as an
            evaluation pool: Ray actors then reserve no CPU (a run's training actors wait meanwhile).
        trained_renderer: what the policy's training images came from ("egl", "tiny", "mixed"; "": not recorded,
            not checked). Before the first episode the environments' renderer is compared with it; a mismatch
            raises :class:`RendererMismatch` (``on_mismatch="refuse"``) or is written to the console ("warn").
    """
    if episodes < 1:
        raise ValueError(f"episodes must be at least 1, got {episodes}")
    open_workers = workers or LocalWorkers()
    done: list[EpisodeResult] = []
    lost = 0
    next_seed = EVAL_SEED
    with open_workers(min(num_workers, episodes), env.env_id, env.make_kwargs(split), evaluation=True) as pool:
        renderer = pool_renderer(pool.renderers())
        problem = renderer_mismatch(trained_renderer, renderer)
        if problem and on_mismatch == "refuse":
            raise RendererMismatch(problem, trained_renderer, renderer)
        if problem:
            tqdm.write(f"warning: {problem}")
        while len(done) < episodes:
            count = min(len(pool), episodes - len(done))
            seeds = list(range(next_seed, next_seed + count))
            next_seed += count
            for result in run_round(pool, seeds, policy, env.dof, env.learned_fixation):
                if result.lost:
                    lost += 1
                else:
                    done.append(result)
    successes = sum(r.success for r in done)
    low, high = wilson_interval(successes, len(done))
    return EvalResult(
        split=split, episodes=len(done), successes=successes, success_rate=successes / len(done), ci_low=low,
        ci_high=high, attempts=sum(r.attempted for r in done), lost=lost, renderer=renderer,
        outcomes=[{"seed": r.seed, "grasp_steps": r.grasp_steps, "attempted": r.attempted, "success": r.success}
                  for r in done],
    )  # fmt: skip
