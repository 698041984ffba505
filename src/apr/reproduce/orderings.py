"""The orderings the paper claims between rows of Table 1, and whether a campaign's seeds resolve them.

For each claim, the difference of the two rows' mean held-out success (each row's mean over its seeds'
final evaluations) with a two-level bootstrap 95% interval: each resample draws every row's seeds with
replacement, then each drawn seed's evaluation again (its successes binomial with its episodes and rate), and the
interval is the 2.5th to 97.5th percentile of the resampled differences. The second level keeps seeds that agree
(every seed at 0 of 100, or 1 of 100) from making a difference look certain. The verdict reads the interval, and
needs :data:`MIN_SEEDS` seeds in each row:

- a claim that one row beats another holds when the interval lies above 0, is reversed when it lies below 0,
  and is not resolved when it holds 0;
- a claim of no real difference ("negligible improvement"; "as good as") holds when the interval lies inside
  +-:data:`NEGLIGIBLE_POINTS`, is reversed when it excludes 0 (a clear difference), and is otherwise not resolved.
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
NEGLIGIBLE_POINTS = 10.0
"""Percentage points within which a difference counts as negligible (ours: the paper gives no margin; its
"negligible" rows and its 85% against 84% are within 1 point, our seeds' spread is wider)."""

Verdict = Literal["holds", "reversed", "not resolved"]


@dataclass(frozen=True)
class Ordering:
    """A claim of the paper about two rows of Table 1 (by the rows' paper preset names)."""

    first: str
    second: str
    kind: Literal["better", "negligible"]
    """better: ``first`` beats ``second``; negligible: they do about as well."""
    paper: str
    """What the paper says."""

    @property
    def claim(self) -> str:
        relation = "beats" if self.kind == "better" else "does about as well as"
        return f"{self.first} {relation} {self.second}"


PAPER_ORDERINGS: tuple[Ordering, ...] = (
    Ordering("active-target", "passive-target", "better", "active 84% against passive 76% (Table 1)"),
    Ordering("active-target", "active-target-no-logpolar", "better", "log-polar 84% against a plain resize 79% "
             "(Table 1)"),
    Ordering("active-target", "active-target-no-representation", "negligible", "the learned representation: "
             '"negligible improvement" (section 4C)'),
    Ordering("active-learned-6d", "active-target", "negligible", "a learned fixation 85% against the "
             "environment's target 84% (Table 1)"),
    Ordering("active-learned-4d", "active-learned-6d", "better", "at 4-DoF 85% after 25K grasps, at 6-DoF after "
             "70K: 4-DoF learns faster, so at an equal budget it is ahead (Table 1)"),
)  # fmt: skip
"""The orderings of the paper's Table 1 and section 4C."""


@dataclass(frozen=True)
class Difference:
    """The mean of ``first``'s seeds minus the mean of ``second``'s, in [-1, 1], and its bootstrap interval."""

    difference: float
    low: float
    high: float


SeedResult = tuple[int, int]
"""One seed's final evaluation: (successes, episodes)."""


def bootstrap_difference(first: Sequence[SeedResult], second: Sequence[SeedResult],
                         resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED) -> Difference:  # fmt: skip
    """The mean success of ``first``'s seeds minus ``second``'s, with the 95% interval of ``resamples`` two-level
    bootstrap resamples (the module's docstring).

    Args:
        first, second: (successes, episodes) of each seed of the two rows (at least one each).
    """
    if not first or not second:
        raise ValueError("each row needs at least one seed")
    rng = np.random.default_rng(seed)

    def resampled_means(seeds: Sequence[SeedResult]) -> tuple[float, np.ndarray]:
        successes, episodes = np.asarray(seeds, dtype=float).T
        drawn = rng.integers(len(seeds), size=(resamples, len(seeds)))
        rates = rng.binomial(episodes[drawn].astype(int), (successes / episodes)[drawn]) / episodes[drawn]
        return float(np.mean(successes / episodes)), rates.mean(axis=1)

    mean_a, draws_a = resampled_means(first)
    mean_b, draws_b = resampled_means(second)
    low, high = np.percentile(draws_a - draws_b, [2.5, 97.5])
    return Difference(mean_a - mean_b, float(low), float(high))


def verdict(ordering: Ordering, difference: Difference, seeds: tuple[int, int] = (MIN_SEEDS, MIN_SEEDS)) -> Verdict:
    """Whether the interval of ``difference`` resolves ``ordering`` (the module's rules), the rows having
    ``seeds`` seeds."""
    if min(seeds) < MIN_SEEDS:
        return "not resolved"
    low, high = 100 * difference.low, 100 * difference.high
    if ordering.kind == "better":
        return "holds" if low > 0 else "reversed" if high < 0 else "not resolved"
    if low >= -NEGLIGIBLE_POINTS and high <= NEGLIGIBLE_POINTS:
        return "holds"
    return "reversed" if low > 0 or high < 0 else "not resolved"
