"""The run's bytes: one `RunFolder`, opened once from a path or a URL, owns them all.

    run = RunFolder.open("runs/demo")            # or "s3://bucket/runs/demo": chosen here, never again
    run.markers("render"); run.read("videos")    # markers and marker-trusted tables
    with run.locked(): run.commit_unit(...)      # staging, commit protocol, fenced by the run lock

Modules, bottom up: `names` (the layout and its name checks), `markers` (a marker's content), `remote`
(an object store), `marker_index`, `lock`, `backends` (local disk or a store: the one place that knows
which), `tables` (the table registry and part writer), `datasets` (marker-trusted reading), `run_folder`,
and the run-wide operations `verify` and `garbage`. Nothing here imports the runtime or a stage.
"""

from __future__ import annotations

from typing import Any

__all__ = ["RunAddress", "RunFolder", "RunFolderError", "as_run"]


def __getattr__(name: str) -> Any:
    # Lazy, so that `pipeline.store.names` stays a light import (the CLI's console uses it).
    if name in __all__:
        from pipeline.store import run_folder

        return getattr(run_folder, name)
    raise AttributeError(f"module 'pipeline.store' has no attribute {name!r}")
