"""The rest of the fuzz property: a reader ends in bounded time and memory, whatever the bytes."""

from __future__ import annotations

import time
import tracemalloc
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def within(read: Callable[[], T], seconds: float, megabytes: float) -> T:
    """Call `read` and return its result (or let its exception through); fail when it took longer than
    `seconds` (a hang shows as a very slow example) or its Python and NumPy allocations peaked above
    `megabytes` (tracemalloc sees both), whether it returned or raised."""
    tracemalloc.start()
    started = time.monotonic()
    try:
        return read()
    finally:
        elapsed = time.monotonic() - started
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert elapsed < seconds, f"took {elapsed:.1f} s, more than {seconds} s"
        assert peak < megabytes * 2**20, f"allocated {peak / 2**20:.0f} MB at its peak, more than {megabytes} MB"
