"""Evaluation (SPEC section 5): held-out objects, exactly 5 in the tray, the deterministic action, and the
success rate with a 95% confidence interval (Wilson score interval, sound near 0% and 100%).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from apr.model.agent import APRAgent
from apr.train.config import EnvConfig
from apr.train.rollout import EpisodeResult, Policy, run_round
from apr.train.workers import LocalWorkers, WorkersFactory

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
    outcomes: list[dict] = field(default_factory=list)
    """Per episode: seed, grasp steps, attempted, success."""

    def to_dict(self) -> dict:
        return asdict(self)


def evaluate(agent: APRAgent, env: EnvConfig, episodes: int, split: str = "test", num_workers: int = 1,
             workers: WorkersFactory | None = None) -> EvalResult:  # fmt: skip
    """Run ``episodes`` episodes with the mean action of both policies; lost episodes are rerun."""

    def policy(observations, phase):
        return agent.act(observations, deterministic=True, policy=phase)

    return evaluate_policy(policy, env, episodes, split, num_workers, workers)


def evaluate_policy(policy: Policy, env: EnvConfig, episodes: int, split: str = "test", num_workers: int = 1,
                    workers: WorkersFactory | None = None) -> EvalResult:  # fmt: skip
    """Run ``episodes`` episodes of ``policy`` on the evaluation seeds ``EVAL_SEED + k`` (the same episodes for
    every policy, checkpoint and run); lost episodes are rerun with the next seeds. ``workers`` opens the
    environments (default: :class:`LocalWorkers`, processes of this machine), as an evaluation pool: Ray actors
    then reserve no CPU (a run's training actors wait meanwhile)."""
    if episodes < 1:
        raise ValueError(f"episodes must be at least 1, got {episodes}")
    open_workers = workers or LocalWorkers()
    done: list[EpisodeResult] = []
    lost = 0
    next_seed = EVAL_SEED
    with open_workers(min(num_workers, episodes), env.env_id, env.make_kwargs(split), evaluation=True) as pool:
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
        ci_high=high, attempts=sum(r.attempted for r in done), lost=lost,
        outcomes=[{"seed": r.seed, "grasp_steps": r.grasp_steps, "attempted": r.attempted, "success": r.success}
                  for r in done],
    )  # fmt: skip
