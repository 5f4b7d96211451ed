"""`mvpd export` and `mvpd import-mvpd`: a run <-> one split of an MVPd release (schemas/mvpd.md)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from pipeline.cli.out_paths import OutPathError, out_folder
from pipeline.cli.run_commands import EXECUTOR_HELP, ExecutorChoice
from pipeline.config import ConfigError
from pipeline.io.mvpd import (MvpdExportError, MvpdFormatError, MvpdImportError, export_release, export_release_splits,
                              import_release)
from pipeline.store.lock import RunLockedError
from pipeline.store.run_folder import RunFolder, RunFolderError

EXPORT = "mvpd export"
USAGE_ERRORS = (MvpdFormatError, MvpdExportError, MvpdImportError, ConfigError, RunFolderError, RunLockedError,
                OutPathError)


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
    mvpd: Annotated[Optional[Path],
                    typer.Option("--mvpd", help="MVPd root to write; the split folder goes inside it")] = None,
    split: Annotated[Optional[str], typer.Option(help="split to write [default: every split of the run's split stage; without one, every video as 'test' (--hf: 'train')]")] = None,
    embodiment: Annotated[Optional[str], typer.Option(help="embodiment to export; needed when the job has several [default: the only one]")] = None,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="replace an existing export (<mvpd>/<split>, the --coco/--yolo files, or the --hf folder)")] = False,
    coco: Annotated[Optional[Path],
                    typer.Option("--coco", help="write COCO instance segmentation here instead")] = None,
    yolo: Annotated[Optional[Path],
                    typer.Option("--yolo", help="write the ultralytics YOLO-seg layout here instead")] = None,
    hf: Annotated[Optional[Path], typer.Option(
        "--hf", help="write a Hugging Face dataset folder here instead (`datasets.load_dataset(DIR)`; extra `hf`)")] = None,
    every: Annotated[int, typer.Option(help="--coco/--yolo: keep every n-th frame of each video")] = 1,
    categories: Annotated[str, typer.Option(help="--coco/--yolo: agnostic (one class) or mpcat40")] = "agnostic",
    drop_stuff: Annotated[bool,
                          typer.Option("--drop-stuff", help="--coco/--yolo: leave out wall, floor, ceiling")] = False,
) -> None:
    """Write a run's videos as an MVPd release split (JPEG colour, uint16 depth PNG, COCO panoptic PNG, JSON),
    or as training data: COCO instance segmentation (--coco), the ultralytics YOLO layout (--yolo) or a
    Hugging Face dataset folder (--hf)."""
    from pipeline.cli.console import check_plain_name, console, fail
    from pipeline.split.selection import has_split

    if split is not None:
        check_plain_name(split, "--split")

    if hf is not None:
        if sum(target is not None for target in (mvpd, coco, yolo)):
            fail("give exactly one of --mvpd, --coco, --yolo or --hf")
        _hf_export(run_dir, hf, split, embodiment, overwrite)
        return
    if coco is not None or yolo is not None or mvpd is None:
        _training_export(run_dir, coco, yolo, mvpd, every, categories, drop_stuff, embodiment, overwrite)
        return
    try:
        run = RunFolder.open(run_dir)
        with out_folder(mvpd, EXPORT, "--mvpd") as root, _video_progress("export") as (on_start, on_video):
            if split is None and has_split(run):
                summaries = export_release_splits(run, root, embodiment, overwrite, on_video=on_video, on_start=on_start)
            else:
                summaries = [export_release(run, root, split or "test", embodiment, overwrite, on_video=on_video,
                                            on_start=on_start)]
    except USAGE_ERRORS as error:
        fail(str(error))
    for warning in dict.fromkeys(w for summary in summaries for w in summary.warnings):
        console.print(f"[yellow]warning:[/] {escape(warning)}", soft_wrap=True)
    for summary in summaries:
        rejected = f", {len(summary.rejected)} rejected" if summary.rejected else ""
        console.print(f"export: {summary.videos} videos, {summary.frames} frames{rejected} -> {summary.split_folder} "
                      f"in {summary.seconds:.1f} s")


def _training_export(run_dir: Path, coco: Optional[Path], yolo: Optional[Path], mvpd: Optional[Path], every: int,
                     categories: str, drop_stuff: bool, embodiment: Optional[str], overwrite: bool) -> None:
    """`export --coco OUT` / `--yolo OUT`: every split of the run (or all videos as `all`) as training data."""
    from pipeline.cli.console import console, fail
    from pipeline.io.coco import CocoExporter
    from pipeline.io.training_export import (ExportOptions, TrainingExportError, export_training_data, run_splits,
                                             unsplit)
    from pipeline.io.yolo import YoloExporter

    if sum(target is not None for target in (mvpd, coco, yolo)) != 1:
        fail("give exactly one of --mvpd, --coco or --yolo")
    from pipeline.split.selection import accepted_videos
    out, exporter, option = (coco, CocoExporter, "--coco") if coco is not None else (yolo, YoloExporter, "--yolo")
    options = ExportOptions(every, categories, drop_stuff, embodiment, overwrite)  # type: ignore[arg-type]
    try:
        run = RunFolder.open(run_dir)
        splits = run_splits(lambda name: accepted_videos(run, name))
        has_split = splits is not None
        splits = splits if splits is not None else unsplit(run)
        with out_folder(out, EXPORT, option) as folder, _video_progress("export") as (on_start, on_video):
            summary = export_training_data(run, folder, splits, exporter, options, on_start=on_start,
                                           on_video=on_video)
    except (TrainingExportError, *USAGE_ERRORS) as error:
        fail(str(error))
    if not has_split:
        console.print(f"{run_dir}: the run has no split; every video was exported as one split named `all`")
    frames = ", ".join(f"{split} {count}" for split, count in summary.frames.items())
    console.print(f"export: {sum(summary.frames.values())} frames ({frames}), {summary.objects} objects -> "
                  f"{summary.out} in {summary.seconds:.1f} s")


def _hf_export(run_dir: Path, out: Path, split: Optional[str], embodiment: Optional[str], overwrite: bool) -> None:
    """`export --hf DIR`: the run's splits as a Hugging Face dataset folder."""
    from pipeline.cli.console import console, fail
    from pipeline.io.huggingface import HfExportError, export_hf_dataset

    try:
        run = RunFolder.open(run_dir)
        with out_folder(out, EXPORT, "--hf") as folder, _video_progress("export") as (on_start, on_video):
            summary = export_hf_dataset(run, folder, split, embodiment, overwrite, on_start=on_start,
                                        on_video=on_video)
    except (HfExportError, *USAGE_ERRORS) as error:
        fail(str(error))
    if not summary.has_split:
        console.print(f"{run_dir}: the run has no split; every video was exported as one split named "
                      f"`{next(iter(summary.frames))}`, with null filter flags")
    frames = ", ".join(f"{name} {count}" for name, count in summary.frames.items())
    console.print(f"export: {sum(summary.frames.values())} frames ({frames}) of {summary.videos} videos in "
                  f"{summary.shards} shards -> {summary.out} in {summary.seconds:.1f} s")


def import_command(
    root: Annotated[Path, typer.Argument(help="MVPd root (holds <split>/panoptic_<split>.json)")],
    run_dir: Annotated[Path, typer.Argument(help="run folder to create or update")],
    split: Annotated[str, typer.Option(help="split folder to read: train, val or test")] = "test",
    embodiment: Annotated[str, typer.Option(help="embodiment name the videos are stored under")] = "mvpd",
    all_units: Annotated[bool, typer.Option("--all", help="re-import videos that are already up to date")] = False,
    address: Annotated[Optional[str], typer.Option(help="Ray cluster address [default: a local Ray]")] = None,
    executor: Annotated[ExecutorChoice, typer.Option(help=EXECUTOR_HELP)] = ExecutorChoice.auto,
) -> None:
    """Read one split of an MVPd release into a run folder (one Ray task per video), so query, stats, preview
    and evaluate work on it. Exit 0 when every unit is done, 1 when some failed (listed), 2 on unusable input."""
    from pipeline.cli.console import EXIT_FAILED, EXIT_OK, check_plain_name, console, fail, stage_progress

    check_plain_name(split, "--split")  # a plain name: <root>/<split> stays inside the release root
    try:
        with stage_progress() as observer:
            summary = import_release(root, split, RunFolder(run_dir), embodiment, all_units, address,
                                     on_start=observer.on_stage_start, on_unit=observer.on_unit, executor=executor.value)
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
