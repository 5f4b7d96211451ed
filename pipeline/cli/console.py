"""Shared console helpers for the CLI: one-line errors, progress bars, tables."""

from __future__ import annotations

import re
import signal
from contextlib import contextmanager
from typing import Iterator, NoReturn

import click
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from typer.core import TyperGroup

from pipeline.runtime.executor import StagePlan, StageReport
from pipeline.runtime.ray_session import got_sigterm
from pipeline.runtime.runner import Observer
from pipeline.runtime.status import UnitOutcome

console = Console(highlight=False)
errors = Console(stderr=True, highlight=False)

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2
EXIT_TERMINATED = 128 + signal.SIGTERM  # the shell's convention for "killed by SIGTERM"
# Plain (click) help everywhere (`rich_markup_mode=None` on each Typer): option texts in full however long,
# `[default: ...]` kept literally (rich markup would eat it as a tag), flags shown as flags, `-h` as `--help`.
HELP_SETTINGS = {"help_option_names": ["-h", "--help"], "show_default": True}


class FullHelpGroup(TyperGroup):
    """Lists each command with its whole first paragraph (wrapped), not click's 45-character cut."""

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = []
        for name in self.list_commands(ctx):
            command = self.get_command(ctx, name)
            if command is not None and not command.hidden:
                text = command.short_help or (command.help or "").split("\n\n")[0]
                rows.append((name, " ".join(text.split())))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def invoke(self, ctx: click.Context) -> object:
        """Run the command; SIGTERM stops it like Ctrl-C (context managers unwind, the run lock is
        released) and exits 143 with one line instead of a stack dump."""
        try:
            return super().invoke(ctx)
        except SystemExit as exit_:  # ray.init's own SIGTERM handler (active while Ray starts) calls sys.exit(15)
            if exit_.code != signal.SIGTERM:
                raise
            terminated()
        except KeyboardInterrupt:  # DriverTerminated, or the KeyboardInterrupt Ray made of it
            if not got_sigterm():
                raise
            terminated()


def terminated() -> NoReturn:
    """Stop after SIGTERM: one line on stderr, exit 143."""
    errors.print("stopped: the process got SIGTERM; finished units are kept, rerun the same command to go on",
                 soft_wrap=True)
    raise typer.Exit(EXIT_TERMINATED)


def fail(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print a one-line error and exit (2 = unusable input)."""
    errors.print(f"[bold red]error:[/] {message}", soft_wrap=True)
    raise typer.Exit(code)


def check_plain_name(value: str, option: str) -> str:
    """`value` when it is a plain file name (letters, digits, `_`, `-`, `.`; not `.` or `..`), else a
    one-line exit 2: a name from the command line never becomes a path outside the folder it names."""
    if not re.fullmatch(r"[A-Za-z0-9_.\-]+", value) or set(value) == {"."}:
        fail(f"{option} {value!r}: not a plain name; use letters, digits, '_', '-' and '.' (no '/' or '..')")
    return value


@contextmanager
def stage_progress() -> Iterator[Observer]:
    """An observer that shows one progress bar per running stage and a summary line per stage."""
    progress = Progress(TextColumn("{task.description:<8}"), BarColumn(), MofNCompleteColumn(),
                        TextColumn("{task.fields[failed]}"), TimeElapsedColumn(), console=console, transient=False)
    tasks: dict[str, int] = {}

    def start(plan: StagePlan) -> None:
        skipped = f" ({len(plan.up_to_date)} up to date)" if plan.up_to_date else ""
        tasks[plan.stage] = progress.add_task(plan.stage + skipped, total=len(plan.to_run) or 1, failed="",
                                              completed=0 if plan.to_run else 1)

    def unit_done(outcome: UnitOutcome) -> None:
        task = tasks[outcome.stage]
        progress.advance(task)
        if outcome.failed:
            count = int(progress.tasks[task].fields["failed"].split()[0] or 0) if progress.tasks[task].fields["failed"] else 0
            progress.update(task, failed=f"{count + 1} failed")

    def end(report: StageReport) -> None:
        progress.console.print(("[red]" if report.failed else "[green]") + report.summary())
        for outcome in report.failed:
            progress.console.print(f"  [red]x[/] {outcome.unit}: {outcome.error_type}: {outcome.message}", soft_wrap=True)

    with progress:
        yield Observer(on_stage_start=start, on_unit=unit_done, on_stage_end=end)
