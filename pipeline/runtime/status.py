"""The run's status table: one row per (stage, unit), the latest attempt's outcome.

Stored as `status/part-<stage>.parquet`, rewritten after each stage run, so a rerun replaces rows
instead of adding them. The driver commits it like a unit of the pseudo-stage `_status` (marker
`_state/_status/<stage>.json`), so it is checked like every other output. A damaged status part never
stops a command: its stage's outcomes are rebuilt from the stage's markers (done units with their
attempts; failed units show as pending until they run again), and the next run of the stage rewrites it.
"""

from __future__ import annotations

import socket
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import pyarrow as pa

from pipeline.runtime.markers import STATUS_STAGE, stage_markers
from pipeline.runtime.run_folder import RunFolder
from pipeline.runtime.tables import column, damaged_parts, read_dataset, register, to_table, write_part

STATUS = register(
    "status",
    [
        column("stage", pa.string(), "stage name"),
        column("unit", pa.string(), "unit id"),
        column("state", pa.string(), "done | failed"),
        column("attempt", pa.int32(), "how many times the unit has been run in this run folder (Ray retries included)"),
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
    """(stage, unit) -> latest outcome, for one stage or all; a damaged stage's rows come from its markers."""
    root = Path(run_root)
    rows = read_dataset(root, "status", warn=False).to_pylist()  # damage here is rebuilt, and shown by `status`
    found = {(r["stage"], r["unit"]): UnitOutcome(**r) for r in rows if stage is None or r["stage"] == stage}
    for damaged_stage in sorted({d.unit for d in damaged_parts(root, "status")}):
        if stage is None or damaged_stage == stage:
            for unit, marker in stage_markers(root, damaged_stage).items():
                found.setdefault((damaged_stage, unit), UnitOutcome(
                    damaged_stage, unit, "done", marker.attempt, log_path=f"logs/{damaged_stage}/{unit}.log",
                    seconds=marker.seconds))
    return found


def write_status(run_root: Path, stage: str, outcomes: dict[str, UnitOutcome]) -> None:
    """Replace the stage's status rows with `outcomes` (unit -> outcome), sorted by unit, by a commit."""
    run = RunFolder(run_root)
    rows = [asdict(outcomes[unit]) for unit in sorted(outcomes)]
    staging = run.staging(STATUS_STAGE, stage)
    write_part(staging, "status", stage, to_table("status", rows))
    run.commit_unit(STATUS_STAGE, stage, staging, config_hash="", rows={"status": len(rows)}, seconds=0.0,
                    attempt=1, finished_at=time.time(), host=socket.gethostname())
