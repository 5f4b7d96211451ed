"""One attempt of one unit: stage it, commit it, write its marker, record the outcome.

Runs in a Ray worker or in the driver (the inline executor): the same code either way, so where a
unit runs never changes what it writes.
"""

from __future__ import annotations

import logging
import socket
import sys
import time
import traceback

from pipeline.errors import error_text
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult
from pipeline.runtime.status import UnitOutcome
from pipeline.store.failures import failure_line, is_no_space
from pipeline.store.lock import LeaseLostError
from pipeline.store.run_folder import RunFolder


def execute_unit(stage: Stage, run: RunFolder, unit: Unit, attempt: int) -> UnitOutcome:
    """Run one unit: stage it, commit it, write its marker.

    `attempt` is the run folder's count for this unit (earlier runs + 1); a Ray retry after a dead
    worker adds its retry number, so the marker and status say attempt 2 when the first worker died.
    The commit checks that the run lock still names the driver (`run.fence`, its owner id).
    Errors raised by the stage become a failed outcome; a dying process leaves only its staging folder.
    A lost lease (LeaseLostError) is raised: it is the driver's end, not this unit's failure.
    """
    retry = ray_retry_number()
    attempt += retry
    log_file = run.log_path(stage.name, unit.id)
    logger, handler = _unit_logger(run, stage.name, unit.id)
    started = time.perf_counter()
    relative_log = str(log_file.relative_to(run.root))
    try:
        node = ray_node_id()
        logger.info("unit %s of stage %s, attempt %s, on %s%s%s", unit.id, stage.name, attempt, socket.gethostname(),
                    f" (Ray node {node})" if node else "",
                    f" (Ray retry {retry}: the worker of the previous attempt died)" if retry else "")
        staging = run.staging(stage.name, unit.id)
        context = UnitContext(stage.job, run, stage.name, unit, staging, logger)
        result = stage.run_unit(unit, context) or UnitResult()
        marker = run.commit_unit(stage.name, unit.id, staging, stage.unit_hash(unit),
                                 {**context.rows_written, **result.rows}, time.perf_counter() - started, attempt,
                                 time.time(), socket.gethostname(), result.info, node=node)
        logger.info("committed %s outputs (%s files) in %.2f s", len(marker.outputs), len(marker.files), marker.seconds)
        return UnitOutcome(stage.name, unit.id, "done", attempt, log_path=relative_log, seconds=marker.seconds)
    except LeaseLostError as error:
        logger.error("not committed: %s", error)
        raise
    except Exception as error:  # noqa: BLE001 - every unit error is recorded, none escapes to Ray
        logger.error("failed: %s\n%s", error, traceback.format_exc())
        # A full disk is said with the path and the free space (the status table keeps it as the reason).
        message = (failure_line(error, str(run.root)) if is_no_space(error)
                   else error_text(error, None))
        return UnitOutcome(stage.name, unit.id, "failed", attempt, type(error).__name__, message, relative_log,
                           time.perf_counter() - started)
    finally:
        logger.removeHandler(handler)
        handler.close()
        run.upload_log(stage.name, unit.id)


def ray_retry_number() -> int:
    """How often Ray has retried the task running this code (0 on a first try, in the driver, or without Ray)."""
    worker = _ray_worker()
    if worker is None:
        return 0
    try:
        # Not in Ray's public API (2.60); without it the attempt is the driver's count.
        return int(worker.core_worker.get_current_task_attempt_number())
    except (AttributeError, TypeError, ValueError):
        return 0


def ray_node_id() -> str:
    """The id of the Ray node whose worker runs this code; "" in the driver (inline units) or without Ray."""
    if _ray_worker() is None:
        return ""
    import ray

    return str(ray.get_runtime_context().get_node_id())


def _ray_worker() -> object | None:
    """Ray's worker object when this code runs as a Ray task, else None (Ray is not imported for this)."""
    ray = sys.modules.get("ray")
    if ray is None or not ray.is_initialized():
        return None
    worker = ray._private.worker.global_worker
    return worker if worker.mode == ray.WORKER_MODE else None


def append_to_unit_log(run: RunFolder, stage: str, unit: str, message: str) -> None:
    """Add a line to a unit's log from the driver (e.g. why its earlier worker died)."""
    logger, handler = _unit_logger(run, stage, unit)
    try:
        logger.warning("%s", message)
    finally:
        logger.removeHandler(handler)
        handler.close()


class _UnitLogHandler(logging.StreamHandler):
    """A unit's log file as the run folder opened it (through no link); closing the handler closes the file."""

    def close(self) -> None:
        try:
            self.stream.close()
        finally:
            super().close()


def _unit_logger(run: RunFolder, stage: str, unit: str) -> tuple[logging.Logger, logging.Handler]:
    logger = logging.getLogger(f"mvpd.unit.{stage}.{unit}")
    logger.setLevel(logging.INFO)
    logger.propagate = False
    handler = _UnitLogHandler(run.open_log(stage, unit))
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    logger.addHandler(handler)
    return logger, handler
