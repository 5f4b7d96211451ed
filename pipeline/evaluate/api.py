"""Evaluate predictions on a run of ours or on an MVPd split, through the stage runtime (Ray).

Both paths run `VsqEvaluator` units (one Ray task per video) with the stage executor, so videos are
evaluated in parallel, each video is committed atomically with a marker, and a rerun with the same
inputs only evaluates videos that are not done yet. For an MVPd split there is no run folder, so an
*evaluation run folder* is created (by default next to the output JSON: `<out>.run/`): it holds a
job naming the split and the VSQ protocol, the `metrics/` table, markers and logs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import pyarrow as pa
from pydantic import ValidationError

from pipeline.config import ConfigError, Embodiment, EvaluateConfig, Job, MvpdReleaseSource, SceneSources
from pipeline.evaluate.ground_truth import MvpdSplit
from pipeline.evaluate.report import EvaluationResult, result_from_table
from pipeline.evaluate.stage import EvaluationInputs, MvpdVsqEvaluator, VsqEvaluator
from pipeline.runtime.executor import ProgressCallback, StagePlan, StageReport, run_stage
from pipeline.runtime.executors import ExecutorName
from pipeline.store.run_folder import RunFolder

StartCallback = Callable[[StagePlan], None]


def with_protocol(job: Job, overrides: dict[str, Any] | None) -> Job:
    """`job` with its `evaluate` section updated by the non-None `overrides` (validated)."""
    changes = {key: value for key, value in (overrides or {}).items() if value is not None}
    if not changes:
        return job
    try:
        config = EvaluateConfig(**{**job.evaluate.model_dump(), **changes})
    except ValidationError as error:
        first = error.errors()[0]
        raise ConfigError(f"evaluate.{'.'.join(str(p) for p in first['loc'])}: {first['msg']}") from None
    return job.model_copy(update={"evaluate": config})


def evaluation_job(mvpd_root: Path, split: str, overrides: dict[str, Any] | None = None) -> Job:
    """The job of an MVPd evaluation run folder: the release split as its source, the VSQ protocol."""
    job = Job(name=f"mvpd-evaluation-{split}",
              scenes=SceneSources(mvpd=MvpdReleaseSource(root=mvpd_root, split=split)),
              embodiments=[Embodiment(name="mvpd")])
    return with_protocol(job, overrides)


def evaluate_run(run: RunFolder, predictions: str | Path, embodiment: str | None = None,
                 allow_missing: bool = False, overrides: dict[str, Any] | None = None, force: bool = False,
                 address: str | None = None, on_start: StartCallback | None = None,
                 on_unit: ProgressCallback | None = None, split: str | None = None,
                 videos: tuple[str, ...] = (), executor: ExecutorName = "auto") -> EvaluationResult:
    """VSQ of `predictions` on the rendered videos of a run; counts go to the run's `metrics/`.

    With a split stage in the run, `split` (default test) chooses the accepted videos scored and fills the
    zero-shot bucket; without one every video is scored (`result.split` is then "all"). `videos` narrows
    the set to names or globs.
    """
    from pipeline.split.selection import has_split

    job = with_protocol(run.job(), overrides)
    chosen = (split or "test") if has_split(run) else None
    inputs = EvaluationInputs(str(Path(predictions).resolve()), allow_missing, embodiment, split=chosen, videos=videos)
    result = _run(VsqEvaluator(job, inputs), run, force, address, on_start, on_unit, executor)
    result.split = chosen or "all"
    return result


def evaluate_mvpd(mvpd_root: str | Path, split: str, predictions: str | Path, work: RunFolder,
                  allow_missing: bool = False, overrides: dict[str, Any] | None = None, force: bool = False,
                  address: str | None = None, on_start: StartCallback | None = None,
                  on_unit: ProgressCallback | None = None, videos: tuple[str, ...] = (),
                  executor: ExecutorName = "auto") -> EvaluationResult:
    """VSQ of `predictions` on an MVPd split; counts go to `work_dir/metrics/` (an evaluation run folder)."""
    MvpdSplit(mvpd_root, split)  # fails fast, before any folder is created, without panoptic_<split>.json
    job = evaluation_job(Path(mvpd_root).resolve(), split, overrides)
    run = work.prepared()
    run.save_job(job)
    inputs = EvaluationInputs(str(Path(predictions).resolve()), allow_missing,
                              mvpd_root=str(Path(mvpd_root).resolve()), split=split, videos=videos)
    return _run(MvpdVsqEvaluator(job, inputs), run, force, address, on_start, on_unit, executor)


def _run(stage: VsqEvaluator, run: RunFolder, force: bool, address: str | None, on_start: StartCallback | None,
         on_unit: ProgressCallback | None, executor: ExecutorName) -> EvaluationResult:
    with run.locked():
        report: StageReport = run_stage(stage, run, force=force, address=address, on_start=on_start, on_unit=on_unit,
                                        executor=executor)
    # Units no longer in the split were retired by `run_stage`; rows of units that failed this time
    # may be left from an earlier success and are not reported as current numbers.
    failed_units = {o.unit for o in report.failed}
    table = run.read("metrics")
    keep = [(f"{e}.{v}" if e else v) not in failed_units
            for e, v in zip(table.column("embodiment").to_pylist(), table.column("video_name").to_pylist())]
    return result_from_table(table.filter(pa.array(keep, type=pa.bool_())), stage.protocol, report.failed)
