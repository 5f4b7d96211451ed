"""Ctrl-C or SIGTERM at any moment of an `mvpd` command ends it with one line (exit 130 / 143).

Importing the commands takes a second or more (Typer, Rich, pyarrow, numpy, ...). Python turns Ctrl-C
into a KeyboardInterrupt wherever the main thread happens to be, so a Ctrl-C during those imports ended
in a traceback from deep inside some library (and a library that catches BaseException could even
swallow it and go on). So the signals are answered here, before any heavy import and again after the
command ended: nothing of the command has run yet (or it has finished), so the process says so in one
line and exits at once. While a command runs, `commands_handle_signals` hands them back to Python's
KeyboardInterrupt (and `stop_on_sigterm`'s DriverTerminated), which the CLI unwinds (locks released)
before it prints the same line.

This module imports only the standard library: the entry point (`pipeline.cli.startup`) runs it before
everything else.
"""

from __future__ import annotations

import atexit
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType

INTERRUPTED_LINE = "stopped: interrupted (Ctrl-C); finished work is kept, run the same command again to go on"
TERMINATED_LINE = "stopped: the process got SIGTERM; finished units are kept, rerun the same command to go on"
_LINES = {signal.SIGINT: INTERRUPTED_LINE, signal.SIGTERM: TERMINATED_LINE}


def _exit_at_once(signum: int, frame: FrameType | None) -> None:
    """Say why in one line and exit 128 + signum, without unwinding (no command is running)."""
    os.write(2, (_LINES[signum] + "\n").encode())
    os._exit(128 + signum)


def run_command_line(app: Callable[[], object]) -> None:
    """Run the `mvpd` app (it ends in SystemExit). A command stopped by a signal (exit 130 / 143) then exits
    once the exit callbacks ran (Ray's shutdown, logging's flush) but without the interpreter's teardown:
    a native thread the stop interrupted (DuckDB's query worker, a Ray call) may still be unwinding, and
    finalizing Python under it aborted the process now and then (SIGABRT, "FATAL: exception not rethrown")
    after the one line was printed, so the exit code was -6 instead of 130 / 143."""
    try:
        app()
    except SystemExit as done:
        if done.code in (128 + signal.SIGINT, 128 + signal.SIGTERM):
            for stream in (sys.stdout, sys.stderr):
                stream.flush()
            atexit._run_exitfuncs()
            os._exit(done.code)
        raise


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()  # signal.signal works only there


def exit_on_signals_while_starting() -> None:
    """Until a command runs, Ctrl-C and SIGTERM exit at once with one line (130 / 143); so they do after it
    ended, until the interpreter's last moments, when they are held (`_ignore_signals_at_the_end`)."""
    if _in_main_thread():
        for signum in _LINES:
            signal.signal(signum, _exit_at_once)
        atexit.register(_ignore_signals_at_the_end)  # registered first, so it runs last


def _ignore_signals_at_the_end() -> None:
    """The last exit callback (after Ray's shutdown, which a Ctrl-C still ends in one line): Python resets its
    handlers to the default right after the exit callbacks, and a Ctrl-C then would kill the finished process
    silently (status -2). Ignored signals stay ignored (a mask would not do: DuckDB's threads still run and
    would take the signal), so the command's own exit code stands."""
    for signum in _LINES:
        signal.signal(signum, signal.SIG_IGN)


@contextmanager
def commands_handle_signals(on_sigterm: Callable[[], None]) -> Iterator[None]:
    """While the block runs, Ctrl-C raises KeyboardInterrupt and `on_sigterm()` installs the SIGTERM
    handler, so the command unwinds; the handlers from before (this module's, in the `mvpd` process) are
    restored afterwards.

    DuckDB stops a statement that a signal interrupts on this thread (a query's views, its result's conversion,
    the stats) with RuntimeError('Query interrupted') and drops the handler's exception: it is raised again as
    KeyboardInterrupt, which the CLI ends in its one line (exit 130, or 143 after SIGTERM), not a stack dump."""
    if not _in_main_thread():
        yield
        return
    previous = {signum: signal.getsignal(signum) for signum in _LINES}
    try:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        on_sigterm()
        try:
            yield
        except RuntimeError as error:
            if str(error) != "Query interrupted":
                raise
            raise KeyboardInterrupt from error
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)
