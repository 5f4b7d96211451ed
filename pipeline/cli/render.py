"""CLI commands of the render area (placeholder until its issue lands)."""

import typer


def register(app: typer.Typer) -> None:
    """Add this area's commands to the `mvpd` app."""
