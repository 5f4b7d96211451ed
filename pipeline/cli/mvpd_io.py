"""`mvpd export` and `mvpd import-mvpd`: a run <-> one split of an MVPd release (schemas/mvpd.md)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from pipeline.config import ConfigError
from pipeline.io.mvpd import MvpdExportError, MvpdFormatError, MvpdImportError, export_release, import_release
from pipeline.runtime.lock import RunLockedError
from pipeline.runtime.run_folder import RunFolderError

USAGE_ERRORS = (MvpdFormatError, MvpdExportError, MvpdImportError, ConfigError, RunFolderError, RunLockedError)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the `mvpd` app."""
    app.command("export")(export_command)
    app.command("import-mvpd")(import_command)


@contextmanager
def _video_progress(label: str) -> Iterator[tuple[Callable[[int], None], Callable[[str], None]]]:
    """(on_start, on_video) callbacks driving one rich progress bar over videos (export runs in one process)."""
    from pipeline.cli.console import console

    progress = Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[video]}"),
                        TimeElapsedColumn(), console=console)

    def start(total: int) -> None:
        # Shown only once the input has been checked, so a bad-input error is not preceded by an empty bar.
        progress.add_task(label, total=total, video="")
        progress.start()

    try:
        yield start, lambda name: progress.update(progress.task_ids[0], advance=1, video=name)
    finally:
        progress.stop()


def export_command(
    run_dir: Annotated[Path, typer.Argument(help="run folder to export")],
    mvpd: Annotated[Path, typer.Option("--mvpd", help="MVPd root to write; the split folder goes inside it")],
    split: Annotated[str, typer.Option(help="split name (every video goes in it until a split stage exists)")] = "test",
    embodiment: Annotated[Optional[str], typer.Option(help="embodiment to export; needed when the job has several [default: the only one]")] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="replace an existing <mvpd>/<split>")] = False,
) -> None:
    """Write a run's videos as an MVPd release split: JPEG colour, uint16 depth PNG, COCO panoptic PNG, JSON."""
    from pipeline.cli.console import check_plain_name, console, fail

    check_plain_name(split, "--split")
    try:
        with _video_progress("export") as (on_start, on_video):
            summary = export_release(run_dir, mvpd, split, embodiment, overwrite, on_video=on_video, on_start=on_start)
    except USAGE_ERRORS as error:
        fail(str(error))
    rejected = f", {len(summary.rejected)} empty (rejected)" if summary.rejected else ""
    console.print(f"export: {summary.videos} videos, {summary.frames} frames{rejected} -> {summary.split_folder} "
                  f"in {summary.seconds:.1f} s")


def import_command(
    root: Annotated[Path, typer.Argument(help="MVPd root (holds <split>/panoptic_<split>.json)")],
    run_dir: Annotated[Path, typer.Argument(help="run folder to create or update")],
    split: Annotated[str, typer.Option(help="split folder to read: train, val or test")] = "test",
    embodiment: Annotated[str, typer.Option(help="embodiment name the videos are stored under")] = "mvpd",
    all_units: Annotated[bool, typer.Option("--all", help="re-import videos that are already up to date")] = False,
    address: Annotated[Optional[str], typer.Option(help="Ray cluster address [default: a local Ray]")] = None,
) -> None:
    """Read one split of an MVPd release into a run folder (one Ray task per video), so query, stats, preview
    and evaluate work on it. Exit 0 when every unit is done, 1 when some failed (listed), 2 on unusable input."""
    from pipeline.cli.console import EXIT_FAILED, EXIT_OK, check_plain_name, console, fail, stage_progress

    check_plain_name(split, "--split")  # a plain name: <root>/<split> stays inside the release root
    try:
        with stage_progress() as observer:
            summary = import_release(root, split, run_dir, embodiment, all_units, address,
                                     on_start=observer.on_stage_start, on_unit=observer.on_unit)
            if observer.on_stage_end is not None:
                observer.on_stage_end(summary.report)  # the stage's summary line and its failed units
    except USAGE_ERRORS as error:
        fail(str(error))
    absent = f"; absent in the release (stored as zeros): {', '.join(sorted(summary.absent_arrays))}" \
        if summary.absent_arrays else ""
    failed = f", {len(summary.failed)} failed" if summary.failed else ""
    console.print(f"import: {len(summary.imported)} videos ({summary.frames} frames) imported, "
                  f"{len(summary.up_to_date)} up to date{failed} -> {summary.run_root} "
                  f"in {summary.seconds:.1f} s{absent}")
    raise typer.Exit(EXIT_FAILED if summary.failed else EXIT_OK)
