"""The runtime's own table: `status`, the latest outcome of every unit (see `pipeline.runtime.status`)."""

from __future__ import annotations

import pyarrow as pa

from pipeline.store.tables import column, register

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
