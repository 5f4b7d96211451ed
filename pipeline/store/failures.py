"""Failures of the storage under a run (a full disk, an object store that went away), said in one line.

A driver whose disk fills up or whose store stops answering must not die with a traceback and leave its
lock behind: `stop_on_storage_failure` turns such an error into `RunStoppedError` (one line naming the
path, and for a full disk the free space; the CLI exits 1), after the `with` blocks inside it have
released the run lock. A unit that hits a full disk fails with the same line as its recorded reason.
"""

from __future__ import annotations

import errno
import shutil
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from pipeline.errors import error_text

# An object store's client raises these besides OSError (s3fs translates only some botocore errors).
_CLIENT_ERRORS = (("botocore.exceptions", "BotoCoreError"), ("botocore.exceptions", "ClientError"),
                  ("aiohttp", "ClientError"))


class RunStoppedError(RuntimeError):
    """The driver stopped because the storage under the run failed; the message is one line saying what to do."""


def storage_errors() -> tuple[type[BaseException], ...]:
    """OSError and the error types of the object-store clients already imported (an outage raises those)."""
    found: list[type[BaseException]] = [OSError]
    for module, name in _CLIENT_ERRORS:
        loaded = sys.modules.get(module)
        if loaded is not None and isinstance(getattr(loaded, name, None), type):
            found.append(getattr(loaded, name))
    return tuple(found)


def is_no_space(error: BaseException) -> bool:
    return isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT)


def no_space_line(path: str | Path) -> str:
    """`PATH: no space left on device (N MiB free); ...`: the free space of the file system holding `path`."""
    folder = Path(path)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        free = f"{shutil.disk_usage(folder).free / 2**20:.1f} MiB free"
    except OSError:
        free = "free space unknown"
    return f"{path}: no space left on device ({free}); free some space, then rerun the same command"


def failure_line(error: BaseException, where: str) -> str:
    """One line for a storage failure met while running `where` (a run folder or URL)."""
    if is_no_space(error):
        return no_space_line(getattr(error, "filename", None) or where)
    text = error_text(error, 300)
    if isinstance(error, OSError) and not type(error).__module__.startswith(("s3fs", "gcsfs", "botocore")):
        return f"{getattr(error, 'filename', None) or where}: {text}; the driver stopped (finished units are kept)"
    return (f"{where}: the object store failed ({type(error).__name__}: {text}); the driver stopped and released "
            "the run lock, finished units are kept; rerun the same command once the store answers")


@contextmanager
def stop_on_storage_failure(where: str | Path) -> Iterator[None]:
    """Turn a storage failure inside the block into RunStoppedError (one line); other errors pass unchanged."""
    try:
        yield
    except storage_errors() as error:
        raise RunStoppedError(failure_line(error, str(where))) from None
