"""`mvpd`: the command-line entry point. Each area registers its own commands."""

from __future__ import annotations

if __name__ == "__main__":  # `python -m pipeline.cli.main`: a signal during the imports below is one line too
    from pipeline.cli.signals import exit_on_signals_while_starting, run_command_line

    exit_on_signals_while_starting()

from importlib.metadata import PackageNotFoundError, version  # noqa: E402 - after the signal handlers
from typing import Annotated  # noqa: E402

import typer  # noqa: E402

from pipeline.cli import evaluate, models, mvpd_io, plan, render, run_commands, scenes, view  # noqa: E402
from pipeline.cli.console import HELP_SETTINGS, FullHelpGroup  # noqa: E402

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


for area in (run_commands, scenes, plan, render, evaluate, mvpd_io, models, view):
    area.register(app)


if __name__ == "__main__":
    run_command_line(app)
