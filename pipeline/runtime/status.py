"""The run's status table: one row per (stage, unit), the latest attempt's outcome.

Stored as `status/part-<stage>.parquet`, rewritten atomically after each stage run, so a rerun
replaces rows instead of adding them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import pyarrow as pa

from pipeline.io.tables import column, read_dataset, register, to_table, write_part

STATUS = register(
    "status",
    [
        column("stage", pa.string(), "stage name"),
        column("unit", pa.string(), "unit id"),
        column("state", pa.string(), "done | failed"),
        column("attempt", pa.int32(), "how many times the unit has been run in this run folder"),
        column("error_type", pa.string(), "exception class of a failed unit (empty when done)"),
        column("message", pa.string(), "one-line error message (empty when done)"),
        column("log_path", pa.string(), "the unit's log file, relative to the run folder"),
        column("seconds", pa.float64(), "wall time of the last attempt, seconds"),
    ],
    row="the latest outcome of one unit of one stage",
)


@dataclass
class UnitOutcome:
    """What came of one attempt of one unit (returned by the Ray task)."""

    stage: str
    unit: str
    state: str
    attempt: int
    error_type: str = ""
    message: str = ""
    log_path: str = ""
    seconds: float = 0.0

    @property
    def failed(self) -> bool:
        return self.state != "done"


def read_status(run_root: Path, stage: str | None = None) -> dict[tuple[str, str], UnitOutcome]:
    """(stage, unit) -> latest outcome, for one stage or all."""
    rows = read_dataset(run_root, "status").to_pylist()
    return {(r["stage"], r["unit"]): UnitOutcome(**r) for r in rows if stage is None or r["stage"] == stage}


def write_status(run_root: Path, stage: str, outcomes: dict[str, UnitOutcome]) -> None:
    """Replace the stage's status rows with `outcomes` (unit -> outcome), sorted by unit."""
    rows = [asdict(outcomes[unit]) for unit in sorted(outcomes)]
    write_part(run_root, "status", stage, to_table("status", rows))
