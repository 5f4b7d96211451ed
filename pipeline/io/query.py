"""SQL over a run's Parquet datasets with DuckDB: every dataset is a view of the same name, read-only.

One view joins two datasets: `frames` (poses, written by `plan`) also shows the per-frame columns of
`frame_stats` (written by `render`; NULL until a video is rendered). They stay two datasets on disk
because each stage commits only its own outputs, so re-rendering never rewrites the plan's files.

The connection is confined to the run: each dataset is a view over its explicit list of marker-trusted
part files (their glob characters escaped, so no pattern of the run is ever expanded and a run folder
named `runs/[v1]*` works; DuckDB's own parallel Parquet scan, 15x faster than registered pyarrow
datasets on 164 M segment rows), those files become the only `allowed_paths`, then DuckDB's file system,
extension loading and Python replacement scans are switched off and its configuration locked. On
object storage the parts are the keys their markers name, read in place through the run's fsspec client
registered with DuckDB (no httpfs extension is installed or loaded; the allowed paths are those keys). `query` also accepts only a single read statement, so
`COPY ... TO`, `ATTACH`, `INSTALL`/`LOAD` and `SET` are refused before they reach DuckDB.

`query` bounds DuckDB's memory to a quarter of the machine's (`DEFAULT_MEMORY_LIMIT`; DuckDB's own
default, 80 %, is too much beside Ray workers on a head node) and never spills to disk (DuckDB would
write a `.tmp` folder into the working directory): a query that needs more ends in one line.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import duckdb
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.io.tables import damage_line, trusted_parts_of
from pipeline.store.markers import Damage
from pipeline.store.run_folder import RunFolder

log = logging.getLogger(__name__)


class QueryError(ValueError):
    """SQL that DuckDB rejected or that is not a read; the message is one line."""


class QueryStopped(QueryError):
    """A valid query stopped by a bound (its time or its memory); the CLI exits 1, not 2."""


FRAME_KEY = ("embodiment", "video_name", "frame")
READ_STATEMENTS = {duckdb.StatementType.SELECT, duckdb.StatementType.EXPLAIN}
# Applied after the datasets are registered; `lock_configuration` last so SQL cannot undo any of them.
LOCKDOWN = (
    "SET python_enable_replacements = false",  # SQL must not reach Python objects of the caller
    "SET autoinstall_known_extensions = false",
    "SET autoload_known_extensions = false",
    "SET enable_external_access = false",  # no file, network, ATTACH, COPY TO or extension access
    "SET lock_configuration = true",
)


def connect(run: RunFolder, only: Sequence[str] | None = None,
            memory_limit: str | None = None) -> duckdb.DuckDBPyConnection:
    """An in-memory, locked-down DuckDB connection with one view per Parquet dataset of the run (`frames` joined).

    `only` registers just those datasets (what a stage reads), sparing the marker reads of the others.
    `memory_limit` (DuckDB's notation: "8GB", "500MB", "25%" of the machine) bounds DuckDB's memory and
    switches spilling to disk off; None keeps DuckDB's defaults.
    """
    connection = duckdb.connect(":memory:")
    if run.store is not None:  # parts are read in place, through the run's own fsspec client (no httpfs)
        connection.register_filesystem(run.store.fs)
    datasets = [d for d in run.datasets() if only is None or d in only]
    found = trusted_parts_of(run, datasets)  # each stage's files checked once
    _report_damage({dataset: damaged for dataset, (_, damaged) in found.items()})
    parts = {dataset: [str(path) for path in paths] for dataset, (paths, _) in found.items()}
    scans = {dataset: _scan(files) for dataset, files in parts.items() if files}
    for dataset, scan in scans.items():
        connection.execute(f'CREATE VIEW "{dataset}" AS {scan}')
    if {"frames", "frame_stats"} <= set(scans):
        keys = ", ".join(FRAME_KEY)
        connection.execute(f"CREATE OR REPLACE VIEW frames AS SELECT f.*, s.* EXCLUDE ({keys}) "
                           f"FROM ({scans['frames']}) f LEFT JOIN ({scans['frame_stats']}) s USING ({keys})")
    # The part files are the only files the connection may open once external access is off (DuckDB checks
    # the escaped pattern of a scan entry, then the file it names: both are allowed).
    allowed = sorted({form for files in parts.values() for f in files for name in _spellings(run, f)
                      for form in (name, _glob_escaped(name))})
    connection.execute(f"SET allowed_paths = [{', '.join(_literal(path) for path in allowed)}]")
    if memory_limit is not None:
        _limit_memory(connection, memory_limit)
    for setting in LOCKDOWN:
        connection.execute(setting)
    return connection


def _limit_memory(connection: duckdb.DuckDBPyConnection, memory_limit: str) -> None:
    """DuckDB's memory bound, and no spilling (its `temp_directory` would be `.tmp` in the working directory)."""
    try:
        connection.execute(f"SET memory_limit = {_literal(memory_limit)}")
    except duckdb.Error as error:
        raise QueryError(f"--memory-limit {memory_limit!r}: {_first_line(error)}; give a size such as 8GB, "
                         "500MB or 50% (of the machine's memory)") from None
    connection.execute("SET temp_directory = ''")


def _spellings(run: RunFolder, file: str) -> tuple[str, ...]:
    """A part's path, and on object storage also the spelling DuckDB checks it under (its fsspec client's
    normal form of the URL: `memory://b/k` is checked as `memory:///b/k`)."""
    if run.store is None:
        return (file,)
    fs = run.store.fs
    return (file, fs.unstrip_protocol(fs._strip_protocol(file)))


def _scan(files: list[str]) -> str:
    """DuckDB's own parallel Parquet scan over an explicit file list, glob characters escaped so every entry
    is read literally (a run folder named `runs/[v1]*` works); parts of older code versions may lack newer
    columns (NULL)."""
    return f"SELECT * FROM read_parquet([{', '.join(_literal(_glob_escaped(f)) for f in files)}], union_by_name = true)"


def _glob_escaped(path: str) -> str:
    """`path` as a DuckDB glob matching only itself: each glob character becomes a one-character class."""
    return "".join(f"[{c}]" if c in "[*?" else c for c in path)


def _literal(text: str) -> str:
    return "'" + text.replace("'", "''") + "'"


def _report_damage(damaged: dict[str, list[Damage]]) -> None:
    """Rows of damaged units are left out (`trusted_parts`); say so once, on stderr (json output stays clean)."""
    affected = [dataset for dataset, found in damaged.items() if found]
    if affected:
        log.warning("%s", damage_line(", ".join(affected), sorted({d for found in damaged.values() for d in found},
                                                                  key=lambda d: (d.stage, d.unit, d.path))))


def check_read_only(sql: str) -> None:
    """Refuse anything but one SELECT (or EXPLAIN of one): `query` never writes, attaches or configures."""
    try:
        statements = duckdb.extract_statements(sql)
    except duckdb.Error as error:
        raise QueryError(_first_line(error)) from None
    if len(statements) != 1:
        raise QueryError(f"give exactly one SQL statement, got {len(statements)}")
    kind = statements[0].type
    if kind not in READ_STATEMENTS:
        raise QueryError(f"only reads are allowed (SELECT, WITH, DESCRIBE, SHOW, EXPLAIN); got a "
                         f"{kind.name} statement; `mvpd query` never changes the run or touches other files")


DEFAULT_TIMEOUT_S = 600.0
DEFAULT_MEMORY_LIMIT = "25%"  # of the machine's memory, as DuckDB sees it (a container's limit included)


class QueryTimeout(QueryStopped):
    """The query ran longer than its timeout and was stopped."""


class QueryOutOfMemory(QueryStopped):
    """The query needed more memory than its limit and was stopped."""


def query(run: RunFolder, sql: str, timeout_s: float | None = DEFAULT_TIMEOUT_S,
          memory_limit: str = DEFAULT_MEMORY_LIMIT) -> duckdb.DuckDBPyRelation:
    """Run one read-only `sql` statement against the run's datasets within `timeout_s` and `memory_limit`
    (`connect`); the result is materialised, so every DuckDB error surfaces here as a one-line QueryError.

    DuckDB runs the statement in a thread of its own while this thread waits, so that a timeout (None or
    0: none) or a signal (Ctrl-C, or SIGTERM through the CLI's handler) is noticed at once and interrupts
    DuckDB: a Python signal handler runs only in the main thread, and only between bytecodes, never while
    DuckDB's C++ holds the main thread.
    """
    check_read_only(sql)
    connection = connect(run, memory_limit=memory_limit)
    outcome: dict[str, object] = {}

    def execute() -> None:
        try:
            outcome["result"] = connection.sql(sql).materialize()
        except Exception as error:  # handed to the waiting thread, which raises it
            outcome["error"] = error

    worker = threading.Thread(target=execute, name="mvpd-query", daemon=True)
    deadline = time.monotonic() + timeout_s if timeout_s else math.inf
    try:
        worker.start()  # inside the try: a signal during start() must still interrupt and join the worker
        while worker.is_alive() and time.monotonic() < deadline:
            worker.join(0.05)  # a short wait: signal handlers run between waits
    finally:
        if worker.is_alive():  # timed out, or a signal raised here: stop DuckDB before leaving
            connection.interrupt()
            worker.join()
    error = outcome.get("error")
    if error is None:
        return outcome["result"]  # type: ignore[return-value]
    if isinstance(error, duckdb.InterruptException):
        raise QueryTimeout(f"the query ran longer than {timeout_s:g} s and was stopped; narrow it, "
                           "or give a longer --timeout (0: none)")
    if isinstance(error, duckdb.OutOfMemoryException):
        raise QueryOutOfMemory(f"the query needed more than its memory limit ({_first_line(error)}); narrow it, "
                               f"or give a larger --memory-limit (now {memory_limit})")
    if not isinstance(error, duckdb.Error):
        raise error  # type: ignore[misc]
    known = ", ".join(run.datasets()) or "none yet"
    raise QueryError(f"{_first_line(error)} (tables in {run.location}: {known})")


def _first_line(error: Exception) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0]


def result_table(relation: duckdb.DuckDBPyRelation) -> pa.Table:
    """A result as an Arrow table: every output format converts from it, so values become Python objects
    in one way (time zones through zoneinfo, never pytz, which DuckDB's own row fetch may ask for)."""
    table = relation.arrow()
    return table.read_all() if hasattr(table, "read_all") else table  # DuckDB >= 1.4 returns a RecordBatchReader


def write_result(relation: duckdb.DuckDBPyRelation, fmt: str, out: Path | None) -> str | None:
    """Write a result as csv/json/parquet to `out` (csv/json to the returned text when `out` is None).

    JSON is a list of row objects with numbers as JSON numbers (NaN and infinities as null), one
    trailing newline.
    """
    table = result_table(relation)
    if fmt == "parquet":
        if out is None:
            raise QueryError("--format parquet needs --out FILE.parquet")
        pq.write_table(table, out)
        return None
    if fmt == "csv":
        # Python's csv quotes only where a value needs it, as DuckDB's own CSV does (Arrow's writer quotes
        # every string), so `tail -1` in a shell gives plain values.
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(table.column_names)
        writer.writerows([_csv_value(v) for v in row] for row in zip(*(c.to_pylist() for c in table.columns)))
        text = buffer.getvalue()
    else:
        rows = [{key: _json_value(value) for key, value in row.items()} for row in table.to_pylist()]
        text = json.dumps(rows, indent=1, allow_nan=False) + "\n"
    if out is not None:
        out.write_text(text)
        return None
    return text


def _csv_value(value: object) -> object:
    """A CSV cell: booleans as SQL writes them (true/false), nested values as JSON, the rest as csv writes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, dict)):
        return json.dumps(_json_value(value))
    return value


def _json_value(value: object) -> object:
    """A JSON-native value: numbers stay numbers (Decimal too), NaN/inf become null, nested values recurse,
    everything else (dates, bytes) its text."""
    import decimal

    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, decimal.Decimal):
        return int(value) if value == value.to_integral_value() else float(value)
    if isinstance(value, dict):
        return {str(k): _json_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_value(v) for v in value]
    return str(value)
