"""What the plan stage did per (scene, embodiment): status, reason and draw counts, from its markers.

Scenes that gave fewer paths than asked (or none) are not failures of the run; this is where they are
reported with their counts (`mvpd plan report RUN`).
"""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.store.run_folder import RunFolder


@dataclass(frozen=True)
class PlanReport:
    """One plan unit's outcome."""

    unit: str
    status: str
    paths: int
    attempts: int
    rejected: dict[str, int]
    navigable_m2: float
    islands: int
    reason: str


def plan_reports(run: RunFolder) -> list[PlanReport]:
    """Every finished plan unit of the run, sorted by unit id (scene, embodiment)."""
    reports = []
    for unit, marker in sorted(run.markers("plan").items()):
        draws = marker.info.get("draws", {})
        navigable = marker.info.get("navigable", {})
        reports.append(PlanReport(unit=unit, status=str(marker.info.get("status", "unknown")),
                                  paths=int(draws.get("accepted", 0)), attempts=int(draws.get("attempts", 0)),
                                  rejected=dict(draws.get("rejected", {})),
                                  navigable_m2=float(navigable.get("area_m2", 0.0)),
                                  islands=int(navigable.get("islands", 0)), reason=str(marker.info.get("reason", ""))))
    return reports
