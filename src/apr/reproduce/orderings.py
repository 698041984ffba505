"""The paper's claims that one row of Table 1 does better than another, each with the sentence it tests, and whether
a campaign's seeds resolve them.

Every claim is read from its sentence: which row is ahead, and on what measure of the held-out evaluations
(:data:`MEASURES`): the final success (Table 1), the mean over the learning curve (Figure 4's speed of learning), or
its first third (Figure 4's "initial stages"). For each claim, the difference of the two rows' means over their
seeds, with a two-level bootstrap 95% interval: each resample draws every row's seeds with replacement, then each
drawn seed's evaluations again (each one's successes binomial with its episodes and rate), and the interval is the
2.5th to 97.5th percentile of the resampled differences. The second level keeps seeds that agree (every seed at 0 of
100, or 1 of 100) from making a difference look certain. The verdict reads the interval, and needs
:data:`MIN_SEEDS` seeds in each row: the claim holds when the interval lies above 0, is reversed when it lies below
0, and is not resolved when it holds 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0
"""The bootstrap's generator seed: the same seeds' results give the same interval."""
MIN_SEEDS = 3
"""Seeds each row needs before a verdict other than "not resolved" (the campaign's least per row)."""

Verdict = Literal["holds", "reversed", "not resolved"]
Measure = Literal["final", "curve", "early"]
MEASURES: dict[str, str] = {
    "final": "the final held-out success (Table 1)",
    "curve": "the mean held-out success over the learning curve, every evaluation of the run (Figure 4)",
    "early": "the mean held-out success over the first third of the run's grasps (Figure 4's initial stages)",
}
"""What a claim is measured on, from each run's held-out evaluations (:func:`evaluations_for`)."""


@dataclass(frozen=True)
class Ordering:
    """A claim of the paper that the row ``first`` does better than ``second`` on ``measure`` (rows by their paper
    preset names)."""

    first: str
    second: str
    measure: Measure
    sentence: str
    """The paper's words, quoted."""
    where: str
    """Where the paper says it."""

    @property
    def claim(self) -> str:
        return f"{self.first} ahead of {self.second}, {self.measure}"


LOG_POLAR_SENTENCE = (
    "The absence of the space-variant sampling impacts both the speed of learning and final performance (Table 1)."
)
"""Section 4C's sentence on the log-polar warp: one sentence, two claims (final success and the curve)."""
PAPER_ORDERINGS: tuple[Ordering, ...] = (
    Ordering("active-target", "passive-target", "final",
             "We observe that the active model achieves 8% better performance.", "section 4A, Table 1"),
    Ordering("active-target", "passive-target", "curve",
             "Figure 4 (yellow vs blue curves) shows that the active model is more sample-efficient as well.",
             "section 4A, Figure 4"),
    Ordering("active-target-no-representation", "passive-target-no-representation", "final",
             "We observe that the active model achieves 8% better performance.",
             "section 4A's claim for the two rows without the generator (ours: at CPU scale the passive GQN loses the "
             "target, docs/investigations.md)"),
    Ordering("active-target", "active-target-no-logpolar", "final",
             LOG_POLAR_SENTENCE, "section 4C, Table 1"),
    Ordering("active-target", "active-target-no-logpolar", "curve",
             LOG_POLAR_SENTENCE, "section 4C, Figure 4"),
    Ordering("active-target", "active-target-no-representation", "final",
             "Figure 4 (red curve) shows that APR without representation learning achieves negligible improvement "
             "within the given amount of environment interaction.", "section 4C, Figure 4"),
    Ordering("passive-target", "passive-target-no-representation", "final",
             "The biggest improvement over vanilla model-free RL algorithms came from representation learning, which "
             "benefited both passive and active models.", "Discussion"),
    Ordering("active-learned-6d", "active-target", "early",
             "In this setting, the model learns faster in the initial stages than in the targeted grasping case "
             "(Figure 4)", "section 4B, Figure 4"),
    Ordering("active-learned-6d", "active-target", "final",
             "... and is slightly better in final performance (Table 1).", "section 4B, Table 1"),
    Ordering("active-learned-4d", "active-learned-6d", "final",
             "We tested the model in the 4-DoF case, where it achieves an 85% success rate with 25K grasps (Table 1). "
             "... On the more challenging 6-DoF version, we achieve an 85% success rate with 70K grasps",
             "section 4B, Table 1"),
)  # fmt: skip
"""The paper's claims about the rows of Table 1, each as its sentence says it."""


Evaluation = tuple[int, int]
"""One held-out evaluation: (successes, episodes)."""
SeedResult = Sequence[Evaluation]
"""One seed's evaluations that a measure reads; its value is the mean of their success rates."""


def evaluations_for(measure: Measure, evaluations: Sequence[tuple[int, int, int]]) -> list[Evaluation]:
    """The evaluations of one run that ``measure`` reads, from all of its (grasps, successes, episodes) by
    increasing grasps: the last one ("final"); every one after the first grasp ("curve"); those within the first
    third of the last one's grasps, at least the first ("early")."""
    if not evaluations:
        raise ValueError("a run without evaluations has no measure")
    trained = [item for item in evaluations if item[0] > 0] or list(evaluations[-1:])
    if measure == "final":
        chosen = [evaluations[-1]]
    elif measure == "curve":
        chosen = trained
    elif measure == "early":
        chosen = [item for item in trained if 3 * item[0] <= evaluations[-1][0]] or trained[:1]
    else:
        raise ValueError(f"measure must be one of {tuple(MEASURES)}, got {measure!r}")
    return [(successes, episodes) for _, successes, episodes in chosen]


@dataclass(frozen=True)
class Difference:
    """The mean of ``first``'s seeds minus the mean of ``second``'s, in [-1, 1], and its bootstrap interval."""

    difference: float
    low: float
    high: float


def seed_value(evaluations: SeedResult) -> float:
    """The mean success rate of one seed's evaluations."""
    return float(np.mean([successes / episodes for successes, episodes in evaluations]))


def bootstrap_difference(first: Sequence[SeedResult], second: Sequence[SeedResult],
                         resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED) -> Difference:  # fmt: skip
    """The mean value of ``first``'s seeds minus ``second``'s (:func:`seed_value`), with the 95% interval of
    ``resamples`` two-level bootstrap resamples (the module's docstring).

    Args:
        first: each seed's evaluations (successes, episodes) of the row said to be ahead (at least one seed).
        second: the same of the row said to be behind.
    """
    if not first or not second:
        raise ValueError("each row needs at least one seed")
    rng = np.random.default_rng(seed)

    def resampled_means(seeds: Sequence[SeedResult]) -> tuple[float, np.ndarray]:
        drawn = rng.integers(len(seeds), size=(resamples, len(seeds)))
        values = np.zeros(drawn.shape)
        for index, evaluations in enumerate(seeds):
            where = drawn == index
            successes, episodes = np.asarray(evaluations, dtype=float).T
            rates = rng.binomial(episodes.astype(int), successes / episodes, size=(int(where.sum()), len(episodes)))
            values[where] = (rates / episodes).mean(axis=1)
        return float(np.mean([seed_value(evaluations) for evaluations in seeds])), values.mean(axis=1)

    mean_a, draws_a = resampled_means(first)
    mean_b, draws_b = resampled_means(second)
    low, high = np.percentile(draws_a - draws_b, [2.5, 97.5])
    return Difference(mean_a - mean_b, float(low), float(high))


def verdict(difference: Difference, seeds: tuple[int, int] = (MIN_SEEDS, MIN_SEEDS)) -> Verdict:
    """Whether the interval of ``difference`` (the first row's lead) resolves a claim, the rows having ``seeds``
    seeds: holds above 0, reversed below 0, not resolved across 0 or with fewer than :data:`MIN_SEEDS` seeds."""
    if min(seeds) < MIN_SEEDS:
        return "not resolved"
    return "holds" if difference.low > 0 else "reversed" if difference.high < 0 else "not resolved"
