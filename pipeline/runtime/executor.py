"""Runs stages: plans which units must run, hands them to an executor, records their outcomes.

Which units run: those without a valid marker (missing, or a config hash that no longer matches),
those whose committed files are damaged (missing, resized, or found corrupt by a verify or a reader),
or all with `force`. Where they run is the executor's choice (`pipeline.runtime.executors`: in-process
or Ray). Ray resubmits a unit whose worker died (`max_retries`); an exception raised by the unit's own
code is caught in the worker, logged and recorded in `status/`, never retried blindly.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Callable

from pipeline.errors import error_text
from pipeline.runtime.attempt import execute_unit
from pipeline.runtime.executors import ExecutorName, ProgressCallback, run_units
from pipeline.runtime.stage import Stage, Unit
from pipeline.runtime.status import UnitOutcome, read_status, write_status
from pipeline.store.datasets import damaged_parts
from pipeline.store.markers import Damage, Marker
from pipeline.store.run_folder import RunFolder

log = logging.getLogger(__name__)

__all__ = ["ProgressCallback", "StageOrderError", "StagePlan", "StageReport", "UnitFailedError", "execute_unit",
           "plan_stage", "run_stage", "run_unit_locally"]


class StageOrderError(RuntimeError):
    """A stage was asked to run before the stages it reads from."""


@dataclass
class StagePlan:
    """The units of a stage split by what a run must do with them."""

    stage: str
    units: list[Unit]
    to_run: list[Unit]
    up_to_date: list[str]
    retired: list[str] = field(default_factory=list)
    damaged: dict[str, list[Damage]] = field(default_factory=dict)  # unit -> its damaged files (also in to_run)
    status_damage: list[Damage] = field(default_factory=list)  # the stage's status part (rebuilt, then rewritten)


@dataclass
class StageReport:
    """What one stage run did."""

    stage: str
    total: int
    skipped: int
    outcomes: list[UnitOutcome]
    seconds: float

    @property
    def done(self) -> int:
        return sum(not o.failed for o in self.outcomes)

    @property
    def failed(self) -> list[UnitOutcome]:
        return [o for o in self.outcomes if o.failed]

    def summary(self) -> str:
        return (f"{self.stage}: {self.done} done, {len(self.failed)} failed, {self.skipped} up to date "
                f"(of {self.total}) in {self.seconds:.1f} s")


# --------------------------------------------------------------------------------- one unit


def run_unit_locally(stage: Stage, run: RunFolder, unit: Unit) -> Marker:
    """Run one unit in this process without Ray (for tests and debugging); raises on failure."""
    outcome = execute_unit(stage, run, unit, attempt=1)
    if outcome.failed:
        raise UnitFailedError(f"{stage.name}/{unit.id}: {outcome.error_type}: {outcome.message} (log: {outcome.log_path})")
    marker = run.marker(stage.name, unit.id)
    assert marker is not None
    return marker


class UnitFailedError(RuntimeError):
    """A unit run with `run_unit_locally` raised."""


# ------------------------------------------------------------------------------ one stage


def plan_stage(stage: Stage, run: RunFolder, force: bool = False) -> StagePlan:
    """Split the stage's units into those to run and those already done with the same config."""
    for upstream in stage.after:
        if not run.markers(upstream):
            raise StageOrderError(f"stage {stage.name} reads the outputs of {upstream}, which has no finished "
                                  f"unit in {run.location}; run {upstream} first (mvpd rerun RUN --stage {upstream})")
    units = stage.units(run)
    markers = run.markers(stage.name)
    damaged = run.damage(markers)
    to_run, up_to_date = [], []
    for unit in units:
        marker = markers.get(unit.id)
        if not force and marker is not None and marker.config_hash == stage.unit_hash(unit) and unit.id not in damaged:
            up_to_date.append(unit.id)
        else:
            to_run.append(unit)
    retired = sorted(set(markers) - {u.id for u in units})
    return StagePlan(stage.name, units, to_run, up_to_date, retired, {u: d for u, d in damaged.items() if u not in retired},
                     [d for d in damaged_parts(run, "status") if d.unit == stage.name])


def upstream_damage(stage: Stage, run: RunFolder) -> dict[str, list[Damage]]:
    """Damaged units of the stages `stage` reads from (its units may be listed from incomplete tables)."""
    found = {}
    for upstream in stage.after:
        found.update({f"{upstream}/{unit}": d for unit, d in run.damage(run.markers(upstream)).items()})
    return found


def run_stage(stage: Stage, run: RunFolder, force: bool = False, address: str | None = None,
              on_start: Callable[[StagePlan], None] | None = None, on_unit: ProgressCallback | None = None,
              executor: ExecutorName = "auto") -> StageReport:
    """Run every unit of `stage` that is not up to date (or is damaged) and record their outcomes.

    `executor` chooses where units run: "local" (this process), "ray", or "auto" (in-process while the
    work is small, see `pipeline.runtime.executors`).
    """
    started = time.perf_counter()
    plan = plan_stage(stage, run, force)
    damaged_upstream = upstream_damage(stage, run) if plan.retired else {}
    if damaged_upstream:
        # Units missing from a damaged upstream table are not gone from the job: keep their outputs.
        log.warning("%s: not retiring %s units while %s upstream units are damaged (e.g. %s); rerun those first",
                    stage.name, len(plan.retired), len(damaged_upstream), next(iter(damaged_upstream)))
    else:
        run.retire(stage.name, plan.retired)
    if on_start is not None:
        on_start(plan)
    previous = read_status(run, stage.name)
    markers = run.markers(stage.name)
    attempts = {u.id: 1 + max(previous[(stage.name, u.id)].attempt if (stage.name, u.id) in previous else 0,
                              markers[u.id].attempt if u.id in markers else 0)
                for u in plan.to_run}
    outcomes = run_units(stage, run, plan.to_run, attempts, executor, address, on_unit) if plan.to_run else []
    statuses = {unit: outcome for (_, unit), outcome in previous.items() if unit in {u.id for u in plan.units}}
    statuses.update({o.unit: o for o in outcomes})
    # First, so that what failed units staged is gone (on a full disk, the room the status table needs).
    run.clear_staging(stage.name)
    write_status(run, stage.name, statuses)  # committed like a unit: fenced by this driver's run lock
    _index_markers(run, stage.name)

    return StageReport(stage.name, len(plan.units), len(plan.up_to_date), outcomes, time.perf_counter() - started)


def _index_markers(run: RunFolder, stage: str) -> None:
    """One file of all the stage's markers, for the next reader; a failure costs only speed (logged)."""
    try:
        run.index_markers(stage)
    except OSError as error:
        log.warning("marker index of stage %s not written (%s); readers read the markers instead", stage,
                    error_text(error))
