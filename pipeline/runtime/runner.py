"""Runs a job's stages in order on one run folder, holding the run lock."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from pipeline.config import Job
from pipeline.runtime.executor import ProgressCallback, StageOrderError, StagePlan, StageReport, run_stage
from pipeline.runtime.executors import ExecutorName
from pipeline.stages import JOB_STAGES, make_stage
from pipeline.store.failures import stop_on_storage_failure
from pipeline.store.run_folder import RunFolder


@dataclass
class Observer:
    """Hooks the console (or a test) uses to follow a run."""

    on_stage_start: Callable[[StagePlan], None] | None = None
    on_unit: ProgressCallback | None = None
    on_stage_end: Callable[[StageReport], None] | None = None


@dataclass
class JobReport:
    """The reports of the stages that ran."""

    run: Path | str  # the folder, or the object-store URL of a run kept there
    stages: list[StageReport] = field(default_factory=list)

    @property
    def failed(self) -> int:
        return sum(len(s.failed) for s in self.stages)


def submit(job: Job, run: RunFolder, stages: list[str] | None = None, address: str | None = None,
           observer: Observer | None = None, executor: ExecutorName = "auto") -> JobReport:
    """Run the stages of `job` in a prepared run folder (`RunFolder.prepare`), saving the job in it; only
    stale or damaged units run.

    A failure of the storage (a full disk, an unreachable store) stops the driver with RunStoppedError (one
    line), after the run lock is released.
    """
    with stop_on_storage_failure(run.location):
        run.check_links()
        with run.locked():
            run.save_job(job)
            return _run(job, run, stages or list(JOB_STAGES), False, address, observer, executor)


def rerun(run: RunFolder, stage: str, force: bool = False, address: str | None = None,
          observer: Observer | None = None, executor: ExecutorName = "auto") -> JobReport:
    """Run one stage of an existing run again: failed, missing, stale and damaged units, or all with `force`
    (storage failures as in `submit`)."""
    with stop_on_storage_failure(run.location):
        run.check_links()
        with run.locked():
            return _run(run.job(), run, [stage], force, address, observer, executor)


def _run(job: Job, run: RunFolder, stages: list[str], force: bool, address: str | None,
         observer: Observer | None, executor: ExecutorName) -> JobReport:
    observer = observer or Observer()
    report = JobReport(run.root if run.store is None else run.location)
    for name in stages:
        try:
            stage_report = run_stage(make_stage(name, job), run, force=force, address=address,
                                     on_start=observer.on_stage_start, on_unit=observer.on_unit, executor=executor)
        except StageOrderError:
            if report.failed:  # every unit upstream failed: those failures are the news, not the order
                break
            empty = next((r.stage for r in report.stages if r.total == 0), None)
            if empty is None:
                raise
            # Rerunning the empty stage would run nothing: say why it is empty instead.
            raise StageOrderError(f"stage {name} has nothing to read: stage {empty} had no units "
                                  f"({make_stage(empty, job).when_empty})") from None
        report.stages.append(stage_report)
        if observer.on_stage_end is not None:
            observer.on_stage_end(stage_report)
    return report
