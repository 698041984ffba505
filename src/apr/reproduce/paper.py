"""What the paper's Table 1 says: its rows (the presets), their figures and the budgets behind them."""

from __future__ import annotations

from dataclasses import dataclass

from apr.train.config import CPU_PREFIX


@dataclass(frozen=True)
class PaperResult:
    """What the paper's Table 1 (or its text) says about a preset."""

    text: str
    """As the paper puts it."""
    budget_grasps: int | None
    """The grasps behind the paper's number, where the paper says (otherwise our preset's budget is shown)."""


PAPER_TABLE1: dict[str, PaperResult] = {
    "active-target": PaperResult("84%", None),
    "passive-target": PaperResult("76%", None),
    "active-target-no-logpolar": PaperResult("79%", None),
    "active-target-no-representation": PaperResult('"negligible improvement" (no number)', None),
    "passive-target-no-representation": PaperResult(
        'representation learning "benefited both passive and active models" (Discussion; no number)', None
    ),
    "active-learned-6d": PaperResult("85% after 70K grasps", 70_000),
    "active-learned-4d": PaperResult("85% after 25K grasps", 25_000),
}
"""The paper's Table 1, its section 4C for the ablation without representation learning, and its Discussion for the
passive model without it."""

PAPER_PRESETS: tuple[str, ...] = tuple(PAPER_TABLE1)
"""The presets of Table 1, in the paper's order."""


def paper_row(name: str) -> str | None:
    """The row of Table 1 the preset ``name`` runs (a paper preset or its ``cpu-`` scale), or None."""
    for row in (name, name.removeprefix(CPU_PREFIX)):
        if row in PAPER_TABLE1:
            return row
    return None
