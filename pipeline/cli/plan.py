"""`mvpd plan ...`: look at the plan stage's output (the stage itself runs with the job)."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape

from pipeline.cli.console import HELP_SETTINGS, FullHelpGroup, print_table
from pipeline.cli.out_paths import check_out_file

console = Console()
plan_app = typer.Typer(cls=FullHelpGroup, rich_markup_mode=None, context_settings=HELP_SETTINGS, no_args_is_help=True,
                       help="Navigable areas and camera trajectories.")


@plan_app.command("preview")
def preview(
    run: Path = typer.Argument(..., help="run folder (written by `mvpd submit`)"),
    scene: str = typer.Argument(..., help="scene id, as in the run's scenes table"),
    out: Path = typer.Option(..., "--out", help="PNG file to write"),
    embodiment: str | None = typer.Option(None, "--embodiment", help="embodiment name; the job's first by default"),
    size: int = typer.Option(1024, "--size", min=64, max=8192, help="picture width in pixels (without legend)"),
) -> None:
    """Draw the scene's navigable area (one colour per island) and the run's paths over its top-down picture."""
    from pipeline.config import ConfigError
    from pipeline.plan.navigable import NavigableAreaError
    from pipeline.plan.preview import PlanPreviewError, write_plan_preview
    from pipeline.store.run_folder import RunFolder, RunFolderError
    from pipeline.scenes.scene import SceneError

    try:
        written = write_plan_preview(RunFolder.open(run), scene, check_out_file(out), embodiment, size)
    except (PlanPreviewError, RunFolderError, ConfigError, SceneError, NavigableAreaError) as error:
        console.print(f"[red]error:[/red] {escape(str(error))}", highlight=False, soft_wrap=True)
        raise typer.Exit(2) from None
    console.print(f"wrote {written.path}: {written.paths} paths of {written.embodiment}, "
                  f"{written.area_m2:.1f} m² navigable in {written.islands} islands", highlight=False, soft_wrap=True)


@plan_app.command("report")
def report(
    run: Path = typer.Argument(..., help="run folder (written by `mvpd submit`)"),
    only_problems: bool = typer.Option(False, "--problems", help="list only scenes with fewer paths than asked"),
) -> None:
    """Per scene and embodiment: paths found, draws tried and why draws were rejected."""
    from rich.table import Table

    from pipeline.plan.report import plan_reports
    from pipeline.store.run_folder import RunFolder, RunFolderError

    try:
        reports = plan_reports(RunFolder.open(run))
    except RunFolderError as error:
        console.print(f"[red]error:[/red] {escape(str(error))}", highlight=False, soft_wrap=True)
        raise typer.Exit(2) from None
    shown = [r for r in reports if r.status != "planned"] if only_problems else reports
    table = Table("unit", "status", "paths", "draws", "rejected", "navigable m²", "islands", "reason")
    for entry in shown:
        rejected = ", ".join(f"{k} {v}" for k, v in entry.rejected.items())
        table.add_row(entry.unit, entry.status, str(entry.paths), str(entry.attempts), rejected,
                      f"{entry.navigable_m2:.1f}", str(entry.islands), entry.reason)
    print_table(table)
    problems = sum(r.status != "planned" for r in reports)
    console.print(f"{len(reports)} plan units, {problems} with fewer paths than asked", highlight=False)


def register(app: typer.Typer) -> None:
    """Add `mvpd plan ...` to the `mvpd` app."""
    app.add_typer(plan_app, name="plan")
