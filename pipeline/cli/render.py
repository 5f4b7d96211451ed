"""CLI commands of the render area: `mvpd preview RUN VIDEO --out DIR`."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated, Optional

import typer

from pipeline.cli.console import console, fail
from pipeline.cli.out_paths import out_folder
from pipeline.io.reader import VideoNotFoundError
from pipeline.io.zarr_video import ZARR_SCHEMA_VERSION
from pipeline.store.run_folder import RunFolder, RunFolderError


class AnimationFormat(str, Enum):
    """File format of the animation."""

    gif = "gif"
    mp4 = "mp4"


def register(app: typer.Typer) -> None:
    """Add this area's commands to the `mvpd` app."""
    app.command()(preview)


def preview(
    run: Annotated[Path, typer.Argument(help="run folder")],
    video: Annotated[str, typer.Argument(help="video name, e.g. proc-000000.0000000003.0000001000")],
    out: Annotated[Path, typer.Option("--out", help="folder for <video>.gif|mp4 and <video>.png")],
    embodiment: Annotated[Optional[str], typer.Option(help="embodiment, when several rendered this video [default: the only one]")] = None,
    rows: Annotated[int, typer.Option(min=1, max=64, help="frames on the contact sheet")] = 6,
    format: Annotated[AnimationFormat, typer.Option("--format", help="animation format")] = AnimationFormat.gif,
) -> None:
    """Write an animation and a PNG contact sheet of a video: RGB | depth | panoptic side by side."""
    from pipeline.io.reader import load_video
    from pipeline.render.preview import write_preview

    try:
        with out_folder(out, "mvpd preview") as target:
            loaded = load_video(RunFolder.open(run), video, embodiment)
            if loaded.attributes.get("schema_version") != ZARR_SCHEMA_VERSION:
                fail(f"{loaded.path}/zarr.json: schema_version {loaded.attributes.get('schema_version')} is not "
                     f"{ZARR_SCHEMA_VERSION}; re-render it with this version (`mvpd rerun {run} --stage render --all`)")
            files = write_preview(loaded, target, rows=rows, animation=format.value)
    except (RunFolderError, VideoNotFoundError) as error:
        fail(str(error))
    except OSError as error:
        fail(f"{out}: cannot write the preview ({error}); choose a writable folder")
    console.print(f"{loaded.embodiment}/{loaded.name}: {loaded.frames} frames, "
                  f"{loaded.intrinsics['width']}x{loaded.intrinsics['height']}")
    console.print(f"animation:     {files.animation}")
    console.print(f"contact sheet: {files.contact_sheet}")
