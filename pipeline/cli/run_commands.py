"""Commands that run and inspect jobs: demo, submit, rerun, status, query, stats, logs, schemas."""

from __future__ import annotations

import json
from enum import Enum
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from pipeline.cli.console import EXIT_FAILED, EXIT_OK, console, fail, stage_progress
from pipeline.config import ConfigError, json_schemas, load_job
from pipeline.io.dataset_stats import StatsError, dataset_stats, write_stats_picture
from pipeline.io.query import QueryError, query, write_result
from pipeline.runtime.executor import StageOrderError
from pipeline.runtime.lock import RunLockedError
from pipeline.runtime.run_folder import RunFolder, RunFolderError
from pipeline.runtime.runner import JobReport, rerun, submit
from pipeline.runtime.inspect import stage_states
from pipeline.stages import JOB_STAGES, STAGE_CLASSES

REPO_ROOT = Path(__file__).resolve().parents[2]
DEMO_JOB = REPO_ROOT / "jobs" / "demo.yaml"
USAGE_ERRORS = (ConfigError, RunFolderError, RunLockedError, StageOrderError, QueryError, StatsError)


class OutputFormat(str, Enum):
    table = "table"
    csv = "csv"
    json = "json"
    parquet = "parquet"


def register(app: typer.Typer) -> None:
    """Add the job commands to `mvpd`."""
    app.command()(demo)
    app.command("submit")(submit_command)
    app.command("rerun")(rerun_command)
    app.command()(status)
    app.command("query")(query_command)
    app.command()(stats)
    app.command()(logs)
    app.command()(schemas)


def _finish(report: JobReport) -> None:
    code = EXIT_FAILED if report.failed else EXIT_OK
    console.print(f"run folder: {report.run}")
    raise typer.Exit(code)


def _parse_stages(stages: str | None) -> list[str] | None:
    if stages is None:
        return None
    names = [s.strip() for s in stages.split(",") if s.strip()]
    unknown = [s for s in names if s not in STAGE_CLASSES]
    if unknown:
        fail(f"--stages: unknown stage {', '.join(unknown)}; stages are {', '.join(JOB_STAGES)}")
    return sorted(names, key=JOB_STAGES.index)


def submit_command(
    job_file: Annotated[Path, typer.Argument(help="job YAML file")],
    run_dir: Annotated[Optional[Path], typer.Option("--run-dir", help="run folder (default runs/<job name>)")] = None,
    address: Annotated[Optional[str], typer.Option(help="Ray cluster address; local Ray when omitted")] = None,
    stages: Annotated[Optional[str], typer.Option(help="comma-separated stages to run (default: all)")] = None,
) -> None:
    """Run a job: every stage, only the units that are not already done with the same config."""
    chosen = _parse_stages(stages)
    try:
        job = load_job(job_file)
        with stage_progress() as observer:
            report = submit(job, run_dir or Path("runs") / job.name, chosen, address, observer)
    except USAGE_ERRORS as error:
        fail(str(error))
    _finish(report)


def demo(
    run_dir: Annotated[Path, typer.Option("--run-dir", help="run folder")] = Path("runs/demo"),
    address: Annotated[Optional[str], typer.Option(help="Ray cluster address; local Ray when omitted")] = None,
) -> None:
    """Run the small demo job (generated houses, local Ray, local disk) and write pictures of it."""
    from pipeline.overview import write_overview

    try:
        with stage_progress() as observer:
            report = submit(load_job(DEMO_JOB), run_dir, None, address, observer)
        if report.failed:
            _finish(report)
        pictures = write_overview(RunFolder.open(run_dir), run_dir / "previews")
    except USAGE_ERRORS as error:
        fail(str(error))
    console.print(f"[bold]look at:[/] {len(pictures)} pictures in {run_dir / 'previews'}, e.g. {pictures[-3]} "
                  f"and {pictures[-1]}")
    console.print(f'[bold]query:[/] mvpd query {run_dir} "select embodiment, count(*) videos, sum(frames) frames '
                  'from videos group by 1"')
    from pipeline.cli.models import demo_model_report

    demo_model_report(run_dir, address)
    _finish(report)


def rerun_command(
    run_dir: Annotated[Path, typer.Argument(help="run folder")],
    stage: Annotated[str, typer.Option(help="stage to rerun")],
    all_units: Annotated[bool, typer.Option("--all", help="rerun every unit, not only failed/missing/stale")] = False,
    address: Annotated[Optional[str], typer.Option(help="Ray cluster address")] = None,
) -> None:
    """Rerun one stage of a run: units that failed, are missing or are stale (or all with --all)."""
    _parse_stages(stage)
    try:
        with stage_progress() as observer:
            report = rerun(run_dir, stage, all_units, address, observer)
    except USAGE_ERRORS as error:
        fail(str(error))
    _finish(report)


def status(run_dir: Annotated[Path, typer.Argument(help="run folder")]) -> None:
    """Per stage: done / stale / failed / pending units, and each failed unit's error."""
    try:
        run = RunFolder.open(run_dir)
        states = stage_states(run)
    except USAGE_ERRORS as error:
        fail(str(error))
    table = Table("stage", "units", "done", "stale", "failed", "pending", title=str(run.root))
    for state in states:
        table.add_row(state.stage, str(state.total), str(len(state.done)), str(len(state.stale)),
                      str(len(state.failed)), str(len(state.pending)) + (f" ({state.waiting_for})" if state.waiting_for else ""))
    console.print(table)
    for state in states:
        for outcome in state.failed:
            console.print(f"[red]{state.stage}/{outcome.unit}[/] attempt {outcome.attempt}: "
                          f"{outcome.error_type}: {outcome.message} (log: {outcome.log_path})", soft_wrap=True)
    raise typer.Exit(EXIT_FAILED if any(s.failed for s in states) else EXIT_OK)


def query_command(
    run_dir: Annotated[Path, typer.Argument(help="run folder")],
    sql: Annotated[str, typer.Argument(help='SQL; every Parquet dataset is a table, e.g. "select * from scenes"')],
    fmt: Annotated[OutputFormat, typer.Option("--format", help="output format")] = OutputFormat.table,
    out: Annotated[Optional[Path], typer.Option(help="write the result to this file")] = None,
) -> None:
    """Query the run's Parquet metadata with SQL (DuckDB)."""
    try:
        relation = query(RunFolder.open(run_dir), sql)
        if fmt is OutputFormat.table:
            table = Table(*relation.columns)
            for row in relation.fetchall():
                table.add_row(*[_cell(v) for v in row])
            console.print(table)
            return
        text = write_result(relation, fmt.value, out)
    except USAGE_ERRORS as error:
        fail(str(error))
    if text is not None:
        typer.echo(text, nl=False)


STATS_ROWS = {  # per-embodiment statistic -> (label, format)
    "scenes": ("scenes", "{:,}"), "videos": ("videos", "{:,}"), "frames": ("frames", "{:,}"),
    "masks": ("masks", "{:,}"), "frames_per_video": ("frames per video", "{:.1f}"),
    "objects_per_video": ("objects per video", "{:.1f}"), "objects_per_frame": ("objects per frame", "{:.1f}"),
    "void_fraction": ("void pixels", "{:.2%}"), "gigabytes": ("stored GB", "{:.3f}"),
}


def stats(
    run_dir: Annotated[Path, typer.Argument(help="run folder (rendered or imported videos)")],
    out: Annotated[Optional[Path], typer.Option(help="also draw the distributions into this PNG")] = None,
    top: Annotated[int, typer.Option(min=1, help="categories listed (and drawn)")] = 15,
) -> None:
    """Dataset statistics: scenes, videos, frames, masks and objects per embodiment and per category."""
    try:
        folder = RunFolder.open(run_dir)
        found = dataset_stats(folder)
        picture = write_stats_picture(folder, found, out, top=max(top, 30)) if out else None
    except USAGE_ERRORS as error:
        fail(str(error))
    except OSError as error:
        fail(f"{out}: cannot write the picture ({error}); choose a writable path")
    table = Table("", *(row["embodiment"] for row in found.per_embodiment), title=f"{found.instances:,} object instances")
    for key, (label, fmt) in STATS_ROWS.items():
        table.add_row(label, *("-" if row[key] is None else fmt.format(row[key]) for row in found.per_embodiment))
    console.print(table)
    categories = Table("category", "masks", "instances", title=f"top {min(top, len(found.per_category))} of "
                       f"{len(found.per_category)} categories")
    for row in found.per_category[:top]:
        categories.add_row(str(row["name"]), f"{row['masks']:,}", f"{row['instances']:,}")
    console.print(categories)
    if picture:
        console.print(f"picture: {picture}")


def _cell(value: object) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def logs(
    run_dir: Annotated[Path, typer.Argument(help="run folder")],
    unit: Annotated[str, typer.Argument(help="unit id (see `mvpd status`)")],
    stage: Annotated[Optional[str], typer.Option(help="stage, when the unit id is in several")] = None,
) -> None:
    """Print the log of one unit."""
    try:
        run = RunFolder.open(run_dir)
    except USAGE_ERRORS as error:
        fail(str(error))
    found = sorted((run.root / "logs").glob(f"{stage or '*'}/{unit}.log"))
    if not found:
        fail(f"{run.root / 'logs'}: no log for unit {unit!r}; unit ids are listed by `mvpd status` and `_state/`")
    for path in found:
        console.rule(str(path.relative_to(run.root)))
        typer.echo(path.read_text(encoding="utf-8"), nl=False)


def schemas(
    out: Annotated[Path, typer.Option(help="folder to write the schemas to")] = REPO_ROOT / "schemas",
) -> None:
    """Write the JSON Schemas of job/embodiment files and of every Parquet dataset."""
    from pipeline.io.schema_export import write_schemas

    for path in write_schemas(out):
        console.print(f"wrote {path}")
