"""Budgets chosen from an error tolerance, and whether they met it.

A stage that picks a budget from a tolerance (the PCA component count of a material,
a wavelet coefficient budget, ...) reports one :class:`ToleranceResult` per thing it
budgeted through its ``finalize`` output (``Output.tolerances``). The runner stores
them in the artifact's provenance record under ``tolerances``; ``prt run`` warns about
those not reached and ``prt inspect`` lists them all. Nothing here knows a stage.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class ToleranceResult:
    """One budget chosen from a tolerance. ``achieved`` is the worst error at the chosen
    budget, in the same units as ``tolerance`` (what ``measure`` names); ``budget`` is
    the budget's name and value (``{"k": 24}``); ``limit`` says why the search stopped
    short of the tolerance, when it did (``"max_k 24"``), and ``hint`` what would help."""

    subject: str  # what was budgeted, e.g. "material floor"
    measure: str  # the error measured, e.g. "worst relative RMS of the PCA fit"
    tolerance: float
    achieved: float
    budget: dict[str, int | float]
    limit: str = ""
    hint: str = ""

    @property
    def reached(self) -> bool:
        return self.achieved <= self.tolerance

    def as_record(self) -> dict[str, Any]:
        """A JSON-ready dict (what the provenance record stores), with ``reached``."""
        return {**asdict(self), "reached": self.reached}


def warning(stage: str, record: dict[str, Any]) -> str:
    """One line about a stored tolerance result that was not reached."""
    budget = ", ".join(f"{k} = {v}" for k, v in record["budget"].items())
    limit = f", capped at {record['limit']}" if record.get("limit") else ""
    hint = f" ({record['hint']})" if record.get("hint") else ""
    return (f"{stage}: {record['subject']}: tolerance not reached: {record['measure']} "
            f"{record['achieved']:.3g} > {record['tolerance']:.3g} at {budget}{limit}{hint}")


def unmet(record: dict[str, Any] | None) -> list[dict[str, Any]]:
    """The tolerance results in an artifact's provenance record that were not reached."""
    return [t for t in (record or {}).get("tolerances", []) if not t.get("reached", True)]
