"""Runs stages as Ray tasks: one task per unit, atomic commit, marker last, status recorded.

Which units run: those without a valid marker (missing, or a config hash that no longer matches),
or all with `force`. Ray resubmits a unit whose worker died (`max_retries`); an exception raised by
the unit's own code is caught in the worker, logged and recorded in `status/`, never retried blindly.
"""

from __future__ import annotations

import hashlib
import logging
import shutil
import socket
import time
import traceback
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Callable

from pipeline import __version__
from pipeline.config import Job
from pipeline.runtime.run_folder import STAGING, Marker, RunFolder
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult
from pipeline.runtime.status import UnitOutcome, read_status, write_status

log = logging.getLogger(__name__)


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


@lru_cache(maxsize=1)
def code_version() -> str:
    """Package version + hash of the package's source files: changes whenever the code does."""
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parents[1].rglob("*.py")):
        digest.update(path.read_bytes())
    return f"{__version__}+{digest.hexdigest()[:12]}"


# --------------------------------------------------------------------------------- one unit


def execute_unit(stage: Stage, run_root: str, unit: Unit, attempt: int) -> UnitOutcome:
    """Run one unit: stage it, commit it, write its marker. Runs inside a Ray worker (or inline).

    Errors raised by the stage become a failed outcome; a dying process leaves only its staging folder.
    """
    run = RunFolder(run_root)
    log_file = run.log_path(stage.name, unit.id)
    logger, handler = _unit_logger(stage.name, unit.id, log_file)
    started = time.perf_counter()
    relative_log = str(log_file.relative_to(run.root))
    try:
        logger.info("unit %s of stage %s, attempt %s, on %s", unit.id, stage.name, attempt, socket.gethostname())
        staging = run.staging(stage.name, unit.id)
        context = UnitContext(stage.job, run, stage.name, unit, staging, logger)
        result = stage.run_unit(unit, context) or UnitResult()
        marker = _commit(stage, run, unit, staging, context, result, attempt, time.perf_counter() - started)
        logger.info("committed %s outputs in %.2f s", len(marker.outputs), marker.seconds)
        return UnitOutcome(stage.name, unit.id, "done", attempt, log_path=relative_log, seconds=marker.seconds)
    except Exception as error:  # noqa: BLE001 - every unit error is recorded, none escapes to Ray
        logger.error("failed: %s\n%s", error, traceback.format_exc())
        message = " ".join(str(error).split()) or type(error).__name__
        return UnitOutcome(stage.name, unit.id, "failed", attempt, type(error).__name__, message, relative_log,
                           time.perf_counter() - started)
    finally:
        logger.removeHandler(handler)
        handler.close()


def _commit(stage: Stage, run: RunFolder, unit: Unit, staging: Path, context: UnitContext, result: UnitResult,
            attempt: int, seconds: float) -> Marker:
    previous = run.marker(stage.name, unit.id)
    # Drop the old proof first: if the process dies during the commit, the unit is simply not done.
    run.drop_marker(stage.name, unit.id)
    outputs = run.commit(staging, previous.outputs if previous else [])
    marker = Marker(stage.name, unit.id, stage.unit_hash(unit), code_version(), outputs,
                    {**context.rows_written, **result.rows}, round(seconds, 3), attempt, socket.gethostname(),
                    time.time(), result.info)
    run.write_marker(marker)
    return marker


def _unit_logger(stage: str, unit: str, path: Path) -> tuple[logging.Logger, logging.Handler]:
    logger = logging.getLogger(f"mvpd.unit.{stage}.{unit}")
    logger.setLevel(logging.INFO)
    logger.propagate = False
    handler = logging.FileHandler(path, mode="a", encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    logger.addHandler(handler)
    return logger, handler


def run_unit_locally(stage: Stage, run: RunFolder, unit: Unit) -> Marker:
    """Run one unit in this process without Ray (for tests and debugging); raises on failure."""
    outcome = execute_unit(stage, str(run.root), unit, attempt=1)
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
                                  f"unit in {run.root}; run {upstream} first (mvpd rerun RUN --stage {upstream})")
    units = stage.units(run)
    markers = run.markers(stage.name)
    to_run, up_to_date = [], []
    for unit in units:
        marker = markers.get(unit.id)
        if not force and marker is not None and marker.config_hash == stage.unit_hash(unit):
            up_to_date.append(unit.id)
        else:
            to_run.append(unit)
    retired = sorted(set(markers) - {u.id for u in units})
    return StagePlan(stage.name, units, to_run, up_to_date, retired)


def retire_units(run: RunFolder, stage: str, unit_ids: list[str]) -> None:
    """Remove outputs and markers of units the job no longer has (so queries never see stale rows)."""
    for unit_id in unit_ids:
        marker = run.marker(stage, unit_id)
        run.drop_marker(stage, unit_id)
        run.commit(run.staging(stage, unit_id), marker.outputs if marker else [])


ProgressCallback = Callable[[UnitOutcome], None]


def run_stage(stage: Stage, run: RunFolder, force: bool = False, address: str | None = None,
              on_start: Callable[[StagePlan], None] | None = None,
              on_unit: ProgressCallback | None = None) -> StageReport:
    """Run every unit of `stage` that is not up to date, as Ray tasks, and record their outcomes."""
    started = time.perf_counter()
    plan = plan_stage(stage, run, force)
    retire_units(run, stage.name, plan.retired)
    if on_start is not None:
        on_start(plan)
    previous = read_status(run.root, stage.name)
    attempts = {u.id: previous[(stage.name, u.id)].attempt + 1 if (stage.name, u.id) in previous else 1
                for u in plan.to_run}
    outcomes = _run_on_ray(stage, run, plan.to_run, attempts, address, on_unit) if plan.to_run else []
    statuses = {unit: outcome for (_, unit), outcome in previous.items() if unit in {u.id for u in plan.units}}
    statuses.update({o.unit: o for o in outcomes})
    write_status(run.root, stage.name, statuses)
    shutil.rmtree(run.root / STAGING / stage.name, ignore_errors=True)
    return StageReport(stage.name, len(plan.units), len(plan.up_to_date), outcomes, time.perf_counter() - started)


def _run_on_ray(stage: Stage, run: RunFolder, units: list[Unit], attempts: dict[str, int], address: str | None,
                on_unit: ProgressCallback | None) -> list[UnitOutcome]:
    import ray

    from pipeline.runtime.ray_session import ensure_ray

    ensure_ray(address)
    resources = stage.resources()
    task = ray.remote(execute_unit).options(
        num_cpus=resources.cpus, memory=int(resources.memory_gb * 2**30),
        max_retries=stage.job.runtime.max_retries, retry_exceptions=False, name=f"mvpd.{stage.name}",
    )
    stage_ref = ray.put(stage)
    limit = stage.job.runtime.max_in_flight or max(1, int(ray.cluster_resources().get("CPU", 1) // resources.cpus))
    pending = list(reversed(units))
    in_flight: dict[object, tuple[Unit, float]] = {}
    outcomes: list[UnitOutcome] = []
    while pending or in_flight:
        while pending and len(in_flight) < limit:
            unit = pending.pop()
            in_flight[task.remote(stage_ref, str(run.root), unit, attempts[unit.id])] = (unit, time.monotonic())
        ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
        for ref in ready:
            unit, _ = in_flight.pop(ref)
            outcome = _collect(ref, stage.name, unit, attempts[unit.id], run)
            outcomes.append(outcome)
            if on_unit is not None:
                on_unit(outcome)
        for ref, (unit, submitted) in list(in_flight.items()):
            if time.monotonic() - submitted > resources.timeout_s:
                ray.cancel(ref, force=True)
                in_flight.pop(ref)
                outcome = UnitOutcome(stage.name, unit.id, "failed", attempts[unit.id], "UnitTimeout",
                                      f"ran longer than runtime.resources.{stage.name}.timeout_s = "
                                      f"{resources.timeout_s:g} s; raise it or shrink the unit",
                                      str(run.log_path(stage.name, unit.id).relative_to(run.root)), resources.timeout_s)
                outcomes.append(outcome)
                if on_unit is not None:
                    on_unit(outcome)
    return sorted(outcomes, key=lambda o: o.unit)


def _collect(ref: object, stage: str, unit: Unit, attempt: int, run: RunFolder) -> UnitOutcome:
    import ray
    from ray.exceptions import RayError

    try:
        return ray.get(ref)
    except RayError as error:  # the worker died more often than max_retries, or the task was lost
        message = " ".join(str(error).split())[:300]
        return UnitOutcome(stage, unit.id, "failed", attempt, type(error).__name__, message,
                           str(run.log_path(stage, unit.id).relative_to(run.root)))
