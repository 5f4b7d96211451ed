"""Where units run: in this process (`local`) or as Ray tasks (`ray`); the choice is the executor's.

Both run the same `execute_unit` on the same stage contract, so a unit writes the same bytes either way
(datatrove's local executor beside its Ray one). `auto` (the default) starts in-process and hands the
rest of a stage to Ray once the remaining work is projected to take longer than starting Ray costs
(`runtime.inline_seconds`); when Ray is already running in this process, or an address is given, it
uses Ray from the start. Inline units are not isolated from the driver and their `timeout_s` is not
enforced, which is why only small work runs inline unless `--executor local` asks for it.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import Callable, Literal

from pipeline.errors import error_text
from pipeline.runtime.attempt import append_to_unit_log, execute_unit
from pipeline.runtime.stage import Stage, Unit
from pipeline.runtime.status import UnitOutcome
from pipeline.store.lock import LeaseLostError
from pipeline.store.remote import storage_environment, use_storage_environment
from pipeline.store.run_folder import RunAddress, RunFolder

log = logging.getLogger(__name__)

ExecutorName = Literal["auto", "local", "ray"]
EXECUTORS: tuple[str, ...] = ("auto", "local", "ray")
ProgressCallback = Callable[[UnitOutcome], None]


def ray_is_running() -> bool:
    """True when this process is already connected to Ray (without importing Ray when it is not)."""
    ray = sys.modules.get("ray")
    return bool(ray is not None and ray.is_initialized())


def run_units(stage: Stage, run: RunFolder, units: list[Unit], attempts: dict[str, int], executor: ExecutorName,
              address: str | None, on_unit: ProgressCallback | None) -> list[UnitOutcome]:
    """Run `units` with the named executor; outcomes sorted by unit id."""
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor {executor!r}; choose one of {', '.join(EXECUTORS)}")
    report = on_unit or (lambda outcome: None)
    if executor == "local":
        outcomes = run_inline(stage, run, units, attempts, report)
    elif executor == "ray" or address or ray_is_running():
        outcomes = run_on_ray(stage, run, units, attempts, address, report)
    else:
        outcomes = _run_adaptively(stage, run, units, attempts, address, report)
    return sorted(outcomes, key=lambda o: o.unit)


def run_inline(stage: Stage, run: RunFolder, units: list[Unit], attempts: dict[str, int],
               on_unit: ProgressCallback, budget_s: float | None = None) -> list[UnitOutcome]:
    """Run units one after another in this process; with `budget_s`, stop once the rest would exceed it."""
    outcomes: list[UnitOutcome] = []
    started = time.perf_counter()
    for index, unit in enumerate(units):
        if budget_s is not None and outcomes:
            spent = time.perf_counter() - started
            if spent / len(outcomes) * (len(units) - index) > budget_s:
                break
        run.check_lease()
        outcome = execute_unit(stage, run, unit, attempts[unit.id])
        outcomes.append(outcome)
        on_unit(outcome)
    return outcomes


def _run_adaptively(stage: Stage, run: RunFolder, units: list[Unit], attempts: dict[str, int], address: str | None,
                    on_unit: ProgressCallback) -> list[UnitOutcome]:
    budget = stage.job.runtime.inline_seconds
    outcomes = run_inline(stage, run, units, attempts, on_unit, budget_s=budget)
    rest = units[len(outcomes):]
    if rest:
        log.info("%s: %s units left after %s in-process; the rest runs on Ray", stage.name, len(rest), len(outcomes))
        outcomes += run_on_ray(stage, run, rest, attempts, address, on_unit)
    return outcomes


# ------------------------------------------------------------------------------------------ Ray


def execute_unit_on_worker(environment: dict[str, str], stage: Stage, run: RunAddress, unit: Unit,
                           attempt: int) -> UnitOutcome:
    """`execute_unit` in a Ray worker, after taking the driver's storage variables (`environment`); the run
    is opened here, once, with them.

    Credentials travel as this task's argument, in memory, and never through Ray's `runtime_env`: Ray
    writes a task's runtime_env into its session logs (readable by every user of the machine).
    """
    use_storage_environment(environment)
    return execute_unit(stage, run.open(), unit, attempt)


def run_on_ray(stage: Stage, run: RunFolder, units: list[Unit], attempts: dict[str, int], address: str | None,
               on_unit: ProgressCallback) -> list[UnitOutcome]:
    """One Ray task per unit, a bounded number in flight; a dead worker's unit is retried by Ray."""
    import ray

    from pipeline.runtime.ray_session import ensure_ray

    ensure_ray(address)
    resources = stage.resources()
    task = ray.remote(execute_unit_on_worker).options(
        num_cpus=resources.cpus, memory=int(resources.memory_gb * 2**30),
        max_retries=stage.job.runtime.max_retries, retry_exceptions=False, name=f"mvpd.{stage.name}",
    )
    environment = storage_environment(run.store.url if run.store else None)
    stage_ref, address = ray.put(stage), run.address()
    limit = stage.job.runtime.max_in_flight or max(1, int(ray.cluster_resources().get("CPU", 1) // resources.cpus))
    pending = list(reversed(units))
    in_flight: dict[object, tuple[Unit, float]] = {}
    outcomes: list[UnitOutcome] = []
    while pending or in_flight:
        _check_lease(run, in_flight)
        while pending and len(in_flight) < limit:
            unit = pending.pop()
            ref = task.remote(environment, stage_ref, address, unit, attempts[unit.id])
            in_flight[ref] = (unit, time.monotonic())
        ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
        for ref in ready:
            unit, _ = in_flight.pop(ref)
            try:
                outcome = _collect(ref, stage, unit, attempts[unit.id], run)
            except LeaseLostError:
                _cancel(in_flight)
                raise
            outcomes.append(outcome)
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
                on_unit(outcome)
    return outcomes


def _check_lease(run: RunFolder, in_flight: dict) -> None:
    """Stop the stage when the driver's lease is lost: cancel the units in flight (their commits would be
    refused by the fence anyway) and raise LeaseLostError."""
    try:
        run.check_lease()
    except LeaseLostError:
        _cancel(in_flight)
        raise


def _cancel(in_flight: dict) -> None:
    import ray

    for ref in in_flight:
        ray.cancel(ref, force=True)


def _collect(ref: object, stage: Stage, unit: Unit, attempt: int, run: RunFolder) -> UnitOutcome:
    import ray
    from ray.exceptions import NodeDiedError, OutOfMemoryError, RayError, WorkerCrashedError

    try:
        outcome = ray.get(ref)
    except RayError as error:  # the worker died more often than max_retries, or Ray could not run the task
        lost = getattr(error, "cause", None)
        if isinstance(lost, LeaseLostError):  # the unit's fence found another driver on the run: stop
            raise LeaseLostError(str(lost)) from None
        message = error_text(error, 300)
        # Only a lost worker or node is retried by Ray (max_retries times); any other failure (a runtime
        # env or an argument that could not be set up, a cancelled task) ended the first try.
        retried = isinstance(error, (WorkerCrashedError, OutOfMemoryError, NodeDiedError))
        if retried:
            _record_worker_deaths(ref, stage, unit, attempt, run)
        return UnitOutcome(stage.name, unit.id, "failed", attempt + (stage.job.runtime.max_retries if retried else 0),
                           type(error).__name__, message, str(run.log_path(stage.name, unit.id).relative_to(run.root)))
    if outcome.attempt > attempt:
        _record_worker_deaths(ref, stage, unit, attempt, run)
    return outcome


def _record_worker_deaths(ref: object, stage: Stage, unit: Unit, attempt: int, run: RunFolder) -> None:
    """Say in the unit's log (and the driver's) why each dead attempt's worker died."""
    for retry, reason in worker_deaths(ref):
        line = f"attempt {attempt + retry} ended because its Ray worker {reason}"
        append_to_unit_log(run, stage.name, unit.id, line)
        log.warning("%s/%s: %s (full text in %s)", stage.name, unit.id, line[:160],
                    run.log_path(stage.name, unit.id).relative_to(run.root))


def worker_deaths(ref: object, wait_s: float = 3.0) -> list[tuple[int, str]]:
    """Why the workers of earlier attempts of the task behind `ref` died, as Ray's GCS recorded it.

    Best effort through Ray internals (task events give each attempt's worker, the worker table its exit
    type and detail, e.g. NODE_OUT_OF_MEMORY or a killed process): (Ray's attempt number, "(pid P) died:
    TYPE: detail") per dead attempt; an empty list when Ray cannot say.
    Task events reach the GCS about once a second, hence the short wait.
    """
    try:
        from ray._private.state import state
        from ray._raylet import WorkerID
        from ray.core.generated import common_pb2, gcs_pb2

        accessor = state._connect_and_get_accessor()
        task_id = ref.task_id().binary()  # type: ignore[attr-defined]
        deadline = time.monotonic() + wait_s
        while True:
            events = [gcs_pb2.TaskEvents.FromString(raw) for raw in accessor.get_task_events()]
            dead = {e.attempt_number: e.state_updates.worker_id for e in events
                    if e.task_id == task_id and e.state_updates.HasField("error_info") and e.state_updates.worker_id}
            if dead or time.monotonic() > deadline:
                break
            time.sleep(0.25)
        reasons = []
        for number, worker_id in sorted(dead.items()):
            raw = accessor.get_worker_info(WorkerID(worker_id))
            if not raw:
                continue
            worker = gcs_pb2.WorkerTableData.FromString(raw)
            reasons.append((number, f"(pid {worker.pid}) died: {common_pb2.WorkerExitType.Name(worker.exit_type)}: "
                                    f"{' '.join(worker.exit_detail.split())}"))
        return reasons
    except (ImportError, AttributeError, RuntimeError, ValueError, TypeError) as error:
        log.info("Ray did not say why a worker died (%s)", error)
        return []
