"""The `mvpd` console script: the signal handlers first (`pipeline.cli.signals`), then the commands.

Importing the commands takes a second or more; a Ctrl-C meanwhile is one line, not a traceback.
"""

from __future__ import annotations

from pipeline.cli.signals import exit_on_signals_while_starting, run_command_line


def main() -> None:
    """Entry point of `mvpd` ([project.scripts]): signal handling first, then the heavy imports and the command."""
    exit_on_signals_while_starting()
    from pipeline.cli.main import app

    run_command_line(app)
