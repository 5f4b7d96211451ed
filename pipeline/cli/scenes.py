"""`mvpd scenes ...`: generate houses as HM3DSem files, preview a scene from above, print its statistics."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from pipeline.cli.console import HELP_SETTINGS, FullHelpGroup, console, fail, print_table
from pipeline.scenes.scene import SceneError

scenes_app = typer.Typer(cls=FullHelpGroup, rich_markup_mode=None, context_settings=HELP_SETTINGS, no_args_is_help=True,
                         help="Generate, preview and describe scenes.")


def register(app: typer.Typer) -> None:
    """Add `mvpd scenes` (generate, preview, stats) to the app."""
    app.add_typer(scenes_app, name="scenes")


@scenes_app.command()
def generate(
    out: Annotated[Path, typer.Option("--out", help="folder; the house goes to OUT/<id>/")],
    seed: Annotated[int, typer.Option("--seed", min=0, help="house seed (id proc-<seed:06d>)")] = 0,
    detail: Annotated[float, typer.Option("--detail", min=0.01, max=1.0, help="0.05 ~ 50 k, 1.0 ~ 1 M triangles")] = 0.1,
    min_rooms: Annotated[int, typer.Option("--min-rooms", min=1, max=12)] = 3,
    max_rooms: Annotated[int, typer.Option("--max-rooms", min=1, max=12)] = 8,
    floors: Annotated[int, typer.Option("--floors", min=1, max=2, help="2 adds an upper storey and stairs")] = 1,
    preview: Annotated[bool, typer.Option("--preview/--no-preview", help="also write OUT/<id>/<id>.preview.png")] = True,
) -> None:
    """Generate a house and save it as HM3DSem files (<id>.glb, .semantic.glb, .semantic.txt)."""
    from pipeline.scenes.hm3dsem import write_hm3dsem
    from pipeline.scenes.preview import write_preview
    from pipeline.scenes.procedural.house import generate_house

    if min_rooms > max_rooms:
        fail(f"--min-rooms {min_rooms} exceeds --max-rooms {max_rooms}; lower one of them")
    try:
        scene = generate_house(seed, detail, min_rooms, max_rooms, floors)
        text = write_hm3dsem(scene, out)
        if preview:
            write_preview(scene, text.parent / f"{scene.scene_id}.preview.png")
    except SceneError as error:
        fail(str(error))
    console.print(f"{scene.scene_id}: {scene.triangle_count:,} triangles, {len(scene.objects)} objects -> {text.parent}")


@scenes_app.command("preview")
def preview_command(
    scene_path: Annotated[Path, typer.Argument(help="a .semantic.txt / .glb of an HM3DSem scene, or a labelled mesh")],
    out: Annotated[Path, typer.Option("--out", help="PNG to write")],
    size: Annotated[int, typer.Option("--size", min=64, max=8192, help="picture width in pixels")] = 1024,
    up_axis: Annotated[str | None, typer.Option("--up-axis", help="y or z [default: z for HM3DSem, y otherwise]")] = None,
    below: Annotated[float | None, typer.Option("--below", help="leave out what is above this height (m) [default: keep everything]")] = None,
) -> None:
    """Write a top-down picture of a scene, objects coloured by mpcat40 category, with a legend."""
    from pipeline.scenes.preview import write_preview
    from pipeline.scenes.sources import load_scene_file

    try:
        written = write_preview(load_scene_file(scene_path, up_axis), out, size, below)
    except SceneError as error:
        fail(str(error))
    console.print(f"wrote {written}")


@scenes_app.command()
def stats(
    scene_path: Annotated[Path, typer.Argument(help="a .semantic.txt / .glb of an HM3DSem scene, or a labelled mesh")],
    up_axis: Annotated[str | None, typer.Option("--up-axis", help="y or z [default: z for HM3DSem, y otherwise]")] = None,
) -> None:
    """Print a scene's rooms, triangles, objects per category and floor area."""
    from pipeline.scenes.preview import scene_stats
    from pipeline.scenes.sources import load_scene_file

    try:
        summary = scene_stats(load_scene_file(scene_path, up_axis))
    except SceneError as error:
        fail(str(error))
    head = Table(title=f"{summary['scene_id']} ({summary['source']})", show_header=False)
    for key in ("rooms", "triangles", "vertices", "objects", "void_triangles", "unknown_colors", "floor_area_m2"):
        value = summary[key]
        head.add_row(key, "unknown" if value is None else f"{value:,}" if isinstance(value, int) else str(value))
    print_table(head)
    table = Table("category", "objects")
    for name, count in summary["objects_per_category"].items():
        table.add_row(name, str(count))
    print_table(table)
