"""Shared console helpers for the CLI: one-line errors, progress bars, tables."""

from __future__ import annotations

import signal
import threading
import time
from contextlib import contextmanager
from typing import Iterator, NoReturn

import click
import typer
from rich.console import Console
from rich.markup import escape
from rich.measure import Measurement
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from typer.core import TyperGroup

from pipeline.cli.out_paths import OutPathError
from pipeline.cli.signals import INTERRUPTED_LINE, TERMINATED_LINE, commands_handle_signals
from pipeline.runtime.executor import StagePlan, StageReport
from pipeline.runtime.ray_session import got_sigterm, stop_on_sigterm
from pipeline.store.names import is_plain_name
from pipeline.runtime.runner import Observer
from pipeline.runtime.status import UnitOutcome
from pipeline.store.failures import RunStoppedError

console = Console(highlight=False)
errors = Console(stderr=True, highlight=False)

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2
EXIT_TERMINATED = 128 + signal.SIGTERM  # the shell's convention for "killed by SIGTERM"
EXIT_INTERRUPTED = 128 + signal.SIGINT
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
        """Run the command; SIGTERM and Ctrl-C stop it (context managers unwind, the run lock is released)
        and exit 143 or 130 with one line instead of a stack dump (before and after the command, the entry
        point's handlers say the same: `pipeline.cli.signals`); an --out that must not be written to is
        refused in one line (exit 2); a driver stopped by its storage or a lost lease exits 1 in one line."""
        try:
            with commands_handle_signals(stop_on_sigterm):
                return super().invoke(ctx)
        except SystemExit as exit_:  # ray.init's own SIGTERM handler (active while Ray starts) calls sys.exit(15)
            if exit_.code != signal.SIGTERM:
                raise
            terminated()
        except KeyboardInterrupt:  # DriverTerminated, or the KeyboardInterrupt Ray made of it
            if got_sigterm():
                terminated()
            interrupted()
        except OutPathError as error:
            fail(str(error))
        except RunStoppedError as error:  # an outage, a full disk or a lost lease under any command's driver
            fail(str(error), EXIT_FAILED)


def terminated() -> NoReturn:
    """Stop after SIGTERM: one line on stderr, exit 143."""
    errors.print(TERMINATED_LINE, soft_wrap=True)
    raise typer.Exit(EXIT_TERMINATED)


def interrupted() -> NoReturn:
    """Stop after Ctrl-C (SIGINT): one line on stderr, exit 130."""
    errors.print(INTERRUPTED_LINE, soft_wrap=True)
    raise typer.Exit(EXIT_INTERRUPTED)


def fail(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print a one-line error and exit (2 = unusable input)."""
    errors.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)
    raise typer.Exit(code)


def check_plain_name(value: str, option: str) -> str:
    """`value` when it is a plain name (`is_plain_name`), else a one-line exit 2: a name from the command
    line never becomes a path outside the folder it names."""
    if not is_plain_name(value):
        fail(f"{option} {value!r}: not a plain name; use letters, digits, '_', '-' and inner '.' (no '/', no leading '.')")
    return value


def print_table(table: Table) -> None:
    """Print a rich table whole: cells fold instead of ending in "…" (ids stay complete), and outside a
    terminal (pipes, logs) the table gets its natural width instead of being cut at 80 columns."""
    for column in table.columns:
        column.overflow = "fold"
    if console.is_terminal:
        console.print(table)
        return
    natural = Measurement.get(console, console.options.update_width(1_000_000), table).maximum
    # A console of the table's own width (print's `width=` is capped at the console's 80 columns).
    Console(highlight=False, width=max(console.width, natural)).print(table)


@contextmanager
def stage_progress() -> Iterator[Observer]:
    """An observer showing each running stage: live bars in a terminal, else a plain line per stage every
    `PROGRESS_SECONDS` (units done, rate, ETA), so logs and pipes show progress too."""
    with (_bar_progress() if console.is_terminal else _line_progress()) as observer:
        yield observer


def _print_stage_end(report: StageReport) -> None:
    console.print(("[red]" if report.failed else "[green]") + report.summary(), soft_wrap=True)
    for outcome in report.failed:
        console.print(f"  [red]x[/] {outcome.unit}: {outcome.error_type}: {escape(outcome.message)}", soft_wrap=True)


@contextmanager
def _bar_progress() -> Iterator[Observer]:
    """One rich progress bar per running stage and a summary line per stage."""
    progress = Progress(TextColumn("{task.description:<8}"), BarColumn(), MofNCompleteColumn(),
                        TextColumn("{task.fields[failed]}"), TimeElapsedColumn(), console=console, transient=False)
    tasks: dict[str, int] = {}
    failures: dict[str, int] = {}

    def start(plan: StagePlan) -> None:
        skipped = f" ({len(plan.up_to_date)} up to date)" if plan.up_to_date else ""
        tasks[plan.stage] = progress.add_task(plan.stage + skipped, total=len(plan.to_run) or 1, failed="",
                                              completed=0 if plan.to_run else 1)

    def unit_done(outcome: UnitOutcome) -> None:
        task = tasks[outcome.stage]
        progress.advance(task)
        if outcome.failed:
            failures[outcome.stage] = failures.get(outcome.stage, 0) + 1
            progress.update(task, failed=f"{failures[outcome.stage]} failed")

    with progress:
        yield Observer(on_stage_start=start, on_unit=unit_done, on_stage_end=_print_stage_end)


class _StageLines:
    """Progress of the running stage as plain text lines, printed every PROGRESS_SECONDS by a timer thread."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.stage = ""
        self.total = self.done = self.failed = 0
        self.started = time.monotonic()

    def start(self, plan: StagePlan) -> None:
        with self.lock:
            self.stage, self.total, self.done, self.failed = plan.stage, len(plan.to_run), 0, 0
            self.started = time.monotonic()
        up_to_date = f", {len(plan.up_to_date)} up to date" if plan.up_to_date else ""
        console.print(f"{plan.stage}: {len(plan.to_run)} units to run{up_to_date}", soft_wrap=True)

    def unit_done(self, outcome: UnitOutcome) -> None:
        with self.lock:
            self.done += 1
            self.failed += bool(outcome.failed)

    def end(self, report: StageReport) -> None:
        with self.lock:
            self.stage = ""
        _print_stage_end(report)

    def line(self) -> str | None:
        """`stage: done/total units (n failed), rate/s, ETA` of the running stage, None between stages."""
        with self.lock:
            if not self.stage or not self.total or self.done >= self.total:
                return None
            elapsed = time.monotonic() - self.started
            rate = self.done / elapsed if elapsed > 0 else 0.0
            eta = f"ETA {_duration((self.total - self.done) / rate)}" if rate > 0 else "ETA unknown"
            failed = f" ({self.failed} failed)" if self.failed else ""
            return (f"{self.stage}: {self.done}/{self.total} units{failed}, {rate:.2f} units/s, "
                    f"{_duration(elapsed)} elapsed, {eta}")


PROGRESS_SECONDS = 5.0


@contextmanager
def _line_progress() -> Iterator[Observer]:
    lines = _StageLines()
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(PROGRESS_SECONDS):
            text = lines.line()
            if text is not None:
                console.print(text, soft_wrap=True)

    timer = threading.Thread(target=tick, daemon=True, name="mvpd-progress")
    timer.start()
    try:
        yield Observer(on_stage_start=lines.start, on_unit=lines.unit_done, on_stage_end=lines.end)
    finally:
        stop.set()
        timer.join(timeout=1)


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m" if seconds >= 3600 else f"{seconds // 60}m{seconds % 60:02d}s"
