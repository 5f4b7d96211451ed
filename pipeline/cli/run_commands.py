"""Commands that run and inspect jobs: demo, submit, rerun, status, query, stats, logs, gc, schemas."""

from __future__ import annotations

from contextlib import nullcontext
from enum import Enum
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from pipeline.cli.console import EXIT_FAILED, EXIT_OK, console, fail, print_table, stage_progress
from pipeline.cli.out_paths import check_out_file, out_file
from pipeline.config import ConfigError, Job, load_job
from pipeline.io.dataset_stats import (COMPARISON_COLUMNS, SPLIT_ROWS, DatasetStats, StatsError, dataset_stats,
                                       write_stats_picture)
from pipeline.io.query import (DEFAULT_MEMORY_LIMIT, DEFAULT_TIMEOUT_S, QueryError, QueryStopped, query, result_table,
                               write_result)
from pipeline.runtime.executor import StageOrderError, StagePlan
from pipeline.store.failures import RunStoppedError, stop_on_storage_failure
from pipeline.store.lock import RunLockedError
from pipeline.store.remote import remote_url
from pipeline.store.run_folder import RunFolder, RunFolderError
from pipeline.runtime.runner import JobReport, Observer, rerun, submit
from pipeline.stages import JOB_STAGES, STAGE_CLASSES

REPO_ROOT = Path(__file__).resolve().parents[2]
DEMO_JOB = REPO_ROOT / "jobs" / "demo.yaml"
USAGE_ERRORS = (ConfigError, RunFolderError, RunLockedError, StageOrderError, QueryError, StatsError)


class ExecutorChoice(str, Enum):
    """Where units run: auto (in-process while the work is small, else Ray), local (in-process) or ray."""

    auto = "auto"
    local = "local"
    ray = "ray"


EXECUTOR_HELP = "where units run: auto = in-process while the work is small, else Ray; local; ray"


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
    app.command("gc")(gc_command)
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


def load_checked_job(job_file: Path) -> Job:
    """The job of `job_file`, with its scene sources listed: a source that names a missing scene or holds
    none is refused here, before any run folder is created (ConfigError, one line)."""
    from pipeline.scenes.scene import SceneError
    from pipeline.scenes.sources import list_scene_refs

    job = load_job(job_file)
    try:
        list_scene_refs(job.scenes)
    except SceneError as error:
        raise ConfigError(f"{job_file}: {error}") from None
    return job


def submit_command(
    job_file: Annotated[Path, typer.Argument(help="job YAML file")],
    run_dir: Annotated[Optional[Path], typer.Option("--run-dir", help="run folder [default: runs/<job name>]")] = None,
    address: Annotated[Optional[str], typer.Option(help="Ray cluster address to join [default: a new local Ray, whatever RAY_ADDRESS says]")] = None,
    stages: Annotated[Optional[str], typer.Option(help="comma-separated stages to run [default: all]")] = None,
    executor: Annotated[ExecutorChoice, typer.Option(help=EXECUTOR_HELP)] = ExecutorChoice.auto,
) -> None:
    """Run a job: every stage, only the units that are not already done with the same config (or are damaged)."""
    chosen = _parse_stages(stages)
    try:
        job = load_checked_job(job_file)
        with stage_progress() as observer:
            report = submit(job, _opened(run_dir or Path("runs") / job.name, create=True), chosen, address,
                            _telling_damage(observer), executor.value)
    except USAGE_ERRORS as error:
        fail(str(error))
    except RunStoppedError as error:  # the disk or the store failed under the driver: one line, exit 1
        fail(str(error), EXIT_FAILED)
    _finish(report)


def demo(
    run_dir: Annotated[Path, typer.Option("--run-dir", help="run folder")] = Path("runs/demo"),
    address: Annotated[Optional[str], typer.Option(help="Ray cluster address to join [default: a new local Ray, whatever RAY_ADDRESS says]")] = None,
) -> None:
    """Run the small demo job (generated houses, local Ray, local disk) and write pictures of it."""
    from pipeline.overview import write_overview

    try:
        with stage_progress() as observer:
            run = _opened(run_dir, create=True)
            report = submit(load_checked_job(DEMO_JOB), run, None, address, observer)
        if report.failed:
            _finish(report)
        # Pictures are for looking at here: in the run folder, or for a run on object storage in its local folder.
        previews = run.root / "previews"
        pictures = write_overview(run, previews)
        found = dataset_stats(run)
    except USAGE_ERRORS as error:
        fail(str(error))
    console.print(f"[bold]look at:[/] {len(pictures)} pictures in {previews}, e.g. {pictures[-3]} and {pictures[-1]}")
    console.print(f'[bold]query:[/] mvpd query {run.location} "select embodiment, count(*) videos, sum(frames) frames '
                  'from videos group by 1"')
    print_stats(found, top=15)
    from pipeline.cli.models import demo_model_report

    demo_model_report(run, address)
    _finish(report)


def rerun_command(
    run_dir: Annotated[Path, typer.Argument(help="run folder")],
    stage: Annotated[str, typer.Option(help="stage to rerun")],
    all_units: Annotated[bool, typer.Option("--all", help="rerun every unit, not only failed/missing/stale")] = False,
    address: Annotated[Optional[str], typer.Option(help="Ray cluster address to join [default: a new local Ray, whatever RAY_ADDRESS says]")] = None,
    executor: Annotated[ExecutorChoice, typer.Option(help=EXECUTOR_HELP)] = ExecutorChoice.auto,
) -> None:
    """Rerun one stage of a run: units that failed, are missing, stale or damaged (or all with --all)."""
    _parse_stages(stage)
    try:
        with stage_progress() as observer:
            report = rerun(_opened(run_dir), stage, all_units, address, _telling_damage(observer), executor.value)
    except USAGE_ERRORS as error:
        fail(str(error))
    except RunStoppedError as error:  # the disk or the store failed under the driver: one line, exit 1
        fail(str(error), EXIT_FAILED)
    _finish(report)


def _opened(run_dir: Path, create: bool = False) -> RunFolder:
    """The run folder a driver runs: created (or reopened) with `create`, else an existing one; a disk or a
    store that fails under it stops here in one line (RunStoppedError)."""
    with stop_on_storage_failure(remote_url(run_dir) or run_dir):
        return RunFolder.prepare(run_dir) if create else RunFolder.open(run_dir)


def _telling_damage(observer: Observer) -> Observer:
    """`observer` that also says, in one line per stage, how many damaged units run again and why."""
    inner = observer.on_stage_start

    def start(plan: StagePlan) -> None:
        if plan.damaged:
            unit, problems = next(iter(sorted(plan.damaged.items())))
            console.print(f"[yellow]{plan.stage}: {len(plan.damaged)} damaged units run again[/] "
                          f"(e.g. {unit}: {problems[0].path} {problems[0].problem})", soft_wrap=True)
        for damage in plan.status_damage:
            console.print(f"[yellow]status table of stage {plan.stage}: {damage.path} {damage.problem}[/]; outcomes "
                          "rebuilt from markers, the part is written again", soft_wrap=True)
        if inner is not None:
            inner(plan)

    return Observer(start, observer.on_unit, observer.on_stage_end)


def status(
    run_dir: Annotated[Path, typer.Argument(help="run folder")],
    verify: Annotated[bool, typer.Option("--verify", help="re-read every output and check its checksum "
                                                           "(reads the whole run; without it only sizes are checked)")] = False,
    executor: Annotated[ExecutorChoice, typer.Option(help="--verify: " + EXECUTOR_HELP)] = ExecutorChoice.auto,
) -> None:
    """Per stage: done / stale / failed / damaged / pending units, each failed unit's error and each damaged unit's files."""
    from pipeline.runtime.inspect import run_state

    try:
        run = RunFolder.open(run_dir)
        if verify:
            _verify(run, executor.value)
        state = run_state(run)
    except USAGE_ERRORS as error:
        fail(str(error))
    table = Table("stage", "units", "done", "stale", "failed", "damaged", "pending", title=run.location)
    for stage in state.stages:
        table.add_row(stage.stage, str(stage.total), str(len(stage.done)), str(len(stage.stale)), str(len(stage.failed)),
                      str(len(stage.damaged)),
                      str(len(stage.pending)) + (f" ({stage.waiting_for})" if stage.waiting_for else ""))
    print_table(table)
    for stage in state.stages:
        if stage.unlisted:
            console.print(f"[yellow]{stage.stage}[/]: its units cannot be listed from the run as it is "
                          f"({escape(stage.unlisted)}); shown are the units it recorded", soft_wrap=True)
        for outcome in stage.failed:
            console.print(f"[red]{stage.stage}/{outcome.unit}[/] attempt {outcome.attempt}: "
                          f"{outcome.error_type}: {escape(outcome.message)} (log: {outcome.log_path})", soft_wrap=True)
        for unit, problems in sorted(stage.damaged.items()):
            more = f" (and {len(problems) - 1} more files)" if len(problems) > 1 else ""
            console.print(f"[red]{stage.stage}/{unit}[/] damaged: {problems[0].path} {problems[0].problem}{more}; "
                          f"`mvpd rerun {run.location} --stage {stage.stage}` writes it again", soft_wrap=True)
    for damage in state.status_damage:
        console.print(f"[yellow]status table of stage {damage.unit}[/]: {damage.path} {damage.problem}; its outcomes "
                      "were rebuilt from markers (failed units show as pending) until the stage runs again",
                      soft_wrap=True)
    bad_markers = _print_run_damage(run)
    unhealthy = any(s.failed or s.damaged for s in state.stages) or bad_markers
    raise typer.Exit(EXIT_FAILED if unhealthy else EXIT_OK)


def _print_run_damage(run: RunFolder) -> bool:
    """Say, one line each, the links inside the run and the marker files that are no marker (a folder, a
    link, bytes that are no marker's JSON), each with its repair; True when there was any."""
    from pipeline.store.links import link_repair, run_links

    found = run_links(run.root) if run.store is None else []
    for relative in found:
        console.print(f"[red]link[/] {escape(link_repair(run.location, relative))}", soft_wrap=True)
    bad = sorted((stage, name) for stage, names in run.unreadable_markers.items() for name in names)
    for stage, name in bad:
        console.print(f"[red]{stage}/{escape(name.removesuffix('.json'))}[/] marker _state/{stage}/{escape(name)} is no "
                      f"readable marker (the unit is not done); `mvpd rerun {run.location} --stage {stage}` runs it "
                      "again and replaces it", soft_wrap=True)
    return bool(found or bad)


def _verify(run: RunFolder, executor: str) -> None:
    """Re-read the run's files with a progress bar (bytes); damage found is recorded for status and rerun."""
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TimeRemainingColumn, TransferSpeedColumn

    from pipeline.runtime.verify import verify_run

    with Progress(TextColumn("verify"), BarColumn(), DownloadColumn(), TransferSpeedColumn(), TimeRemainingColumn(),
                  console=console) as progress:
        task = progress.add_task("verify", total=None)
        verify_run(run, executor, on_start=lambda total: progress.update(task, total=total),
                   on_progress=lambda done: progress.advance(task, done))


def query_command(
    run_dir: Annotated[Path, typer.Argument(help="run folder")],
    sql: Annotated[str, typer.Argument(help='SQL; every Parquet dataset is a table, e.g. "select * from scenes"')],
    fmt: Annotated[OutputFormat, typer.Option("--format", help="output format")] = OutputFormat.table,
    out: Annotated[Optional[Path], typer.Option(help="write the result to this file [default: standard output]")] = None,
    timeout: Annotated[float, typer.Option(min=0, help="stop the query after this many seconds (0: no limit)")] = DEFAULT_TIMEOUT_S,
    memory_limit: Annotated[str, typer.Option(help="stop the query when DuckDB needs more memory than this, e.g. 8GB, "
                                              "500MB, 50% (of this machine's); it never spills to disk")] = DEFAULT_MEMORY_LIMIT,
) -> None:
    """Query the run's Parquet metadata with SQL (DuckDB)."""
    if out is not None:
        check_out_file(out)  # refused before the query runs
    try:
        relation = query(RunFolder.open(run_dir), sql, timeout, memory_limit)
        if fmt is OutputFormat.table:
            result = result_table(relation)
            table = Table(*result.column_names)
            for row in zip(*(column.to_pylist() for column in result.columns)):
                table.add_row(*[_cell(v) for v in row])
            print_table(table)
            return
        with out_file(out) if out is not None else nullcontext(None) as target:  # a new file renamed over --out
            text = write_result(relation, fmt.value, target)
    except QueryStopped as error:  # its time or memory bound: the query was fine, exit 1
        fail(str(error), EXIT_FAILED)
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
    out: Annotated[Optional[Path], typer.Option(help="also draw the distributions into this PNG [default: no picture]")] = None,
    top: Annotated[int, typer.Option(min=1, help="categories listed (and drawn)")] = 15,
) -> None:
    """Dataset statistics: scenes, videos, frames, masks and objects per embodiment and per category."""
    try:
        target = check_out_file(out) if out is not None else None
        folder = RunFolder.open(run_dir)
        found = dataset_stats(folder)
        picture = write_stats_picture(folder, found, target, top=max(top, 30)) if target else None
    except USAGE_ERRORS as error:
        fail(str(error))
    except OSError as error:
        fail(f"{out}: cannot write the picture ({error}); choose a writable path")
    print_stats(found, top)
    if picture:
        console.print(f"picture: {picture}")


def print_stats(found: DatasetStats, top: int) -> None:
    """Tables of `dataset_stats`: per embodiment, the `top` categories, splits, and the paper's comparison row."""
    table = Table("", *(row["embodiment"] for row in found.per_embodiment), title=f"{found.instances:,} object instances")
    for key, (label, fmt) in STATS_ROWS.items():
        table.add_row(label, *("-" if row[key] is None else fmt.format(row[key]) for row in found.per_embodiment))
    print_table(table)
    categories = Table("category", "masks", "instances", title=f"top {min(top, len(found.per_category))} of "
                       f"{len(found.per_category)} categories")
    for row in found.per_category[:top]:
        categories.add_row(str(row["name"]), f"{row['masks']:,}", f"{row['instances']:,}")
    print_table(categories)
    if found.per_split:
        splits = Table("", *(str(row["split"]) for row in found.per_split), title="splits (all embodiments)")
        for key, label in SPLIT_ROWS.items():
            splits.add_row(label, *(f"{int(row[key]):,}" for row in found.per_split))
        print_table(splits)
    else:
        console.print("no split stage in this run (add a `split:` section to the job for train / val / test)")
    # Transposed (one line per column of the paper's table) so it fits a terminal.
    comparison = Table("column", "this run", title="as a row of the MVPd paper's dataset comparison")
    for key, label in COMPARISON_COLUMNS.items():
        value = found.comparison[key]
        comparison.add_row(label, f"{value:,.1f}" if isinstance(value, float) else f"{value:,}" if isinstance(value, int)
                           else str(value))
    print_table(comparison)


def _cell(value: object) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def logs(
    run_dir: Annotated[Path, typer.Argument(help="run folder")],
    unit: Annotated[str, typer.Argument(help="unit id (see `mvpd status`)")],
    stage: Annotated[Optional[str], typer.Option(help="stage, when the unit id is in several [default: every stage]")] = None,
) -> None:
    """Print the log of one unit."""
    try:
        run = RunFolder.open(run_dir)
    except USAGE_ERRORS as error:
        fail(str(error))
    try:
        found = _unit_logs(run, unit, stage)
    except RunFolderError as error:  # a link on the way to the logs: not followed
        fail(str(error))
    if not found:
        fail(f"{run.location}/logs: no log for unit {unit!r}{f' of stage {stage!r}' if stage else ''}; "
             "unit ids are listed by `mvpd status` and `_state/`")
    for relative, text in found:
        typer.echo(f"== {relative} ==")
        typer.echo(text, nl=False)


def _unit_logs(run: RunFolder, unit: str, stage: str | None) -> list[tuple[str, str]]:
    """(path in the run, text) of the logs named exactly `<unit>.log` in the stage folders of `logs/` (all,
    or the one named): on local disk, or as uploaded to the run's object store.

    Names are compared with the folder listing, never joined into a path: `../x` or `/etc/x` finds nothing.
    """
    wanted = f"{unit}.log"
    if run.store is not None:
        listed = sorted(key for key in run.store.list_objects("logs") if key.count("/") == 2)
        return [(key, run.store.read_text(key) or "") for key in listed
                if key.split("/")[2] == wanted and stage in (None, key.split("/")[1])]
    import pipeline.store.links as links

    # Listed and read through no link (`pipeline.store.links`): a linked log folder or log is not read.
    found = []
    for folder, is_folder in sorted(links.entries(run.root, "logs")):
        if is_folder and stage in (None, folder) and (wanted, False) in links.entries(run.root, f"logs/{folder}"):
            try:
                text = links.read_bytes(run.root, f"logs/{folder}/{wanted}")
            except (OSError, RunFolderError):  # a link or a folder by that name: no log of the unit
                continue
            found.append((f"logs/{folder}/{wanted}", text.decode("utf-8", errors="replace")))
    return found


def gc_command(
    run_dir: Annotated[Path, typer.Argument(help="run folder (a path or an object-store URL)")],
    dry_run: Annotated[bool, typer.Option("--dry-run", help="only count what would be deleted")] = False,
) -> None:
    """Delete what dead attempts left (objects under `_attempts/` no marker names, old staging folders), under the run lock."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from pipeline.store.garbage import GarbageCollectionError, collect_garbage

    try:
        run = RunFolder.open(run_dir)
        with Progress(TextColumn("gc"), BarColumn(), MofNCompleteColumn(), console=console, transient=True) as progress:
            task = progress.add_task("gc", total=None)
            report = collect_garbage(run, dry_run, lambda done, total: progress.update(task, completed=done, total=total))
    except (*USAGE_ERRORS, GarbageCollectionError) as error:
        fail(str(error))
    verb = "would delete" if dry_run else "deleted"
    console.print(f"{run.location}: {verb} {report.objects} objects ({report.bytes / 2**20:.1f} MiB) of "
                  f"{len(report.attempts)} dead attempts and {len(report.staging)} staging folders"
                  + (f"; kept {len(report.kept_alive)} attempts of processes still running here"
                     if report.kept_alive else ""),
                  soft_wrap=True)


def schemas(
    out: Annotated[Path, typer.Option(help="folder to write the schemas to")] = REPO_ROOT / "schemas",
) -> None:
    """Write the JSON Schemas of job/embodiment files and of every Parquet dataset."""
    from pipeline.io.schema_export import write_schemas

    for path in write_schemas(out):
        console.print(f"wrote {path}")
