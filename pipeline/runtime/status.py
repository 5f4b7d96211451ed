"""The run's status table: one row per (stage, unit), the latest attempt's outcome.

Stored as `status/part-<stage>.parquet`, rewritten after each stage run, so a rerun replaces rows
instead of adding them. The driver commits it like a unit of the pseudo-stage `_status` (marker
`_state/_status/<stage>.json`), so it is checked like every other output. A damaged status part never
stops a command: its stage's outcomes are rebuilt from the stage's markers (done units with their
attempts; failed units show as pending until they run again), and the next run of the stage rewrites it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from pipeline.runtime.tables import STATUS
from pipeline.store.datasets import damaged_parts, read_dataset
from pipeline.store.names import STATUS_STAGE
from pipeline.store.run_folder import RunFolder
from pipeline.store.tables import to_table


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


def read_status(run: RunFolder, stage: str | None = None) -> dict[tuple[str, str], UnitOutcome]:
    """(stage, unit) -> latest outcome, for one stage or all; a damaged stage's rows come from its markers."""
    rows = read_dataset(run, STATUS.name, warn=False).to_pylist()  # damage here is rebuilt, and shown by `status`
    found = {(r["stage"], r["unit"]): UnitOutcome(**r) for r in rows if stage is None or r["stage"] == stage}
    for damaged_stage in sorted({d.unit for d in damaged_parts(run, STATUS.name)}):
        if stage is None or damaged_stage == stage:
            for unit, marker in run.markers(damaged_stage).items():
                found.setdefault((damaged_stage, unit), UnitOutcome(
                    damaged_stage, unit, "done", marker.attempt, log_path=f"logs/{damaged_stage}/{unit}.log",
                    seconds=marker.seconds))
    return found


def write_status(run: RunFolder, stage: str, outcomes: dict[str, UnitOutcome]) -> None:
    """Replace the stage's status rows with `outcomes` (unit -> outcome), sorted by unit, by a commit."""
    rows = [asdict(outcomes[unit]) for unit in sorted(outcomes)]
    run.commit_tables(STATUS_STAGE, stage, {STATUS.name: to_table(STATUS.name, rows)})
