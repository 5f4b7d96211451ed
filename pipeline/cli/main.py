"""`mvpd`: the command-line entry point. Each area registers its own commands."""

from __future__ import annotations

import typer

from pipeline.cli import evaluate, models, mvpd_io, plan, render, run_commands, scenes

app = typer.Typer(no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
                  help="Embodiment-configurable RGB-D video segmentation datasets (MVPd) on Ray.")

for area in (run_commands, scenes, plan, render, evaluate, mvpd_io, models):
    area.register(app)
