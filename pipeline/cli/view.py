"""`mvpd view RUN VIDEO [--out FILE.rrd]`: a video of a run as a Rerun recording, to look at in 3D."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from pipeline.cli.console import console, fail
from pipeline.cli.out_paths import check_out_file


def register(app: typer.Typer) -> None:
    """Add `view` to the `mvpd` app."""
    app.command()(view)


def view(
    run: Annotated[Path, typer.Argument(help="run folder")],
    video: Annotated[str, typer.Argument(help="video name, as in the run's videos table")],
    out: Annotated[Optional[Path], typer.Option("--out", help="recording to write; default <video>.rrd here")] = None,
    embodiment: Annotated[Optional[str], typer.Option(help="embodiment, when several rendered this video")] = None,
    point_stride: Annotated[int, typer.Option(min=1, max=64, help="back-project every n-th pixel of depth")] = 2,
) -> None:
    """Write a Rerun recording: scene mesh coloured by object, camera path, RGB, depth as points, named masks.

    Open it with `rerun FILE.rrd` (the viewer ships with the `view` extra: pip install 'mvpd-pipeline[view]').
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from pipeline.io.reader import VideoNotFoundError
    from pipeline.rerun_recording import RecordingError, write_recording
    from pipeline.store.run_folder import RunFolder, RunFolderError
    from pipeline.scenes.scene import SceneError

    target = check_out_file(out if out is not None else Path(f"{video}.rrd"))
    try:
        opened = RunFolder.open(run)
        with Progress(TextColumn("view"), BarColumn(), MofNCompleteColumn(), console=console, transient=True) as progress:
            task = progress.add_task("frames", total=None)
            written = write_recording(opened, video, target, embodiment, point_stride,
                                      on_frame=lambda done, total: progress.update(task, completed=done, total=total))
    except (RunFolderError, VideoNotFoundError, RecordingError, SceneError) as error:
        fail(str(error))
    except OSError as error:
        fail(f"{target}: cannot write the recording ({error}); choose a writable file")
    console.print(f"wrote {written.path}: {written.embodiment}/{written.video_name}, {written.frames} frames, "
                  f"{written.objects} objects; open it with `rerun {written.path}`")
