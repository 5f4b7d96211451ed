"""Starting or joining Ray: embedded (local, quiet, no dashboard) unless an address is given.

Embedded means embedded: without an address, a new local Ray is started (`address="local"`) even when
`RAY_ADDRESS` is set or another Ray cluster runs on the machine; only an explicit address joins one.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from types import FrameType


class DriverTerminated(KeyboardInterrupt):
    """The driver got SIGTERM: unwinds like Ctrl-C (locks released, staging left for the next run)."""


_terminated = threading.Event()


def got_sigterm() -> bool:
    """Whether this process received SIGTERM (Ray's waits turn the raised DriverTerminated into a plain
    KeyboardInterrupt, so the exception type alone does not tell)."""
    return _terminated.is_set()


def stop_on_sigterm() -> None:
    """Make SIGTERM raise DriverTerminated in the main thread, as SIGINT raises KeyboardInterrupt."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _raise_terminated)


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    _terminated.set()
    raise DriverTerminated(f"signal {signum}")


def ensure_ray(address: str | None = None, num_cpus: int | None = None) -> None:
    """Connect to the cluster at `address`, or start a quiet local Ray once per process."""
    import ray

    if ray.is_initialized():
        return
    os.environ.setdefault("RAY_ACCEPT_CLUSTER_AUTO_UPGRADE", "0")
    # Workers must not try to reach the internet for usage stats on a closed network.
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    # ray.init installs its own SIGTERM handler (sys.exit); a handler the caller set (the CLI's) wins.
    previous = signal.getsignal(signal.SIGTERM)
    if address:
        ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False)
    else:
        ray.init(address="local", num_cpus=num_cpus, include_dashboard=False, logging_level=logging.ERROR,
                 log_to_driver=False, configure_logging=True)
    if callable(previous) and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, previous)
