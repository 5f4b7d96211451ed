"""`mvpd`: the command-line entry point. Each area registers its own commands."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from typing import Annotated

import typer

from pipeline.cli import evaluate, models, mvpd_io, plan, render, run_commands, scenes, view
from pipeline.cli.console import HELP_SETTINGS, FullHelpGroup
from pipeline.runtime.ray_session import stop_on_sigterm

app = typer.Typer(cls=FullHelpGroup, no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
                  rich_markup_mode=None, context_settings=HELP_SETTINGS,
                  help="Embodiment-configurable RGB-D video segmentation datasets (MVPd) on Ray.")


def _version(value: bool) -> None:
    if value:
        try:
            typer.echo(f"mvpd {version('mvpd-pipeline')}")
        except PackageNotFoundError:
            typer.echo("mvpd (not installed as a package)")
        raise typer.Exit()


@app.callback()
def main(
    show_version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                               help="print the version and exit")] = False,
) -> None:
    """Embodiment-configurable RGB-D video segmentation datasets (MVPd) on Ray."""
    stop_on_sigterm()


for area in (run_commands, scenes, plan, render, evaluate, mvpd_io, models, view):
    area.register(app)


if __name__ == "__main__":
    app()
