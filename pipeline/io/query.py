"""SQL over a run's Parquet datasets with DuckDB: every dataset is a view of the same name, read-only.

One view joins two datasets: `frames` (poses, written by `plan`) also shows the per-frame columns of
`frame_stats` (written by `render`; NULL until a video is rendered). They stay two datasets on disk
because each stage commits only its own outputs, so re-rendering never rewrites the plan's files.

The connection is confined to the run: each dataset is registered from its explicit list of part files
as a pyarrow dataset (so no path or glob pattern of the run ever goes through SQL, and a run folder named
`runs/[v1]*` works), then DuckDB's file system, extension loading and Python replacement scans are
switched off and its configuration locked. `query` also accepts only a single read statement, so
`COPY ... TO`, `ATTACH`, `INSTALL`/`LOAD` and `SET` are refused before they reach DuckDB.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Sequence
from pathlib import Path

import duckdb
import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.parquet as pq

from pipeline.io.tables import all_tables, damage_line, damaged_parts, dataset_parts
from pipeline.runtime.run_folder import RunFolder

log = logging.getLogger(__name__)


class QueryError(ValueError):
    """SQL that DuckDB rejected or that is not a read; the message is one line."""


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


def connect(run: RunFolder, only: Sequence[str] | None = None) -> duckdb.DuckDBPyConnection:
    """An in-memory, locked-down DuckDB connection with one view per Parquet dataset of the run (`frames` joined).

    `only` registers just those datasets (what a stage reads), sparing the marker reads of the others.
    """
    connection = duckdb.connect(":memory:")
    datasets = [d for d in run.datasets() if only is None or d in only]
    _report_damage(run, datasets)
    for dataset in datasets:
        connection.register(_hidden(dataset), _arrow_dataset(run, dataset))
        connection.execute(f'CREATE VIEW "{dataset}" AS SELECT * FROM "{_hidden(dataset)}"')
    if {"frames", "frame_stats"} <= set(datasets):
        keys = ", ".join(FRAME_KEY)
        connection.execute(f'CREATE OR REPLACE VIEW frames AS SELECT f.*, s.* EXCLUDE ({keys}) '
                           f'FROM "{_hidden("frames")}" f LEFT JOIN "{_hidden("frame_stats")}" s USING ({keys})')
    for setting in LOCKDOWN:
        connection.execute(setting)
    return connection


def _report_damage(run: RunFolder, datasets: list[str]) -> None:
    """Rows of damaged units are left out (`dataset_parts`); say so once, on stderr (json output stays clean)."""
    damaged = {dataset: damaged_parts(run.root, dataset) for dataset in datasets}
    affected = [dataset for dataset, found in damaged.items() if found]
    if affected:
        log.warning("%s", damage_line(", ".join(affected), sorted({d for found in damaged.values() for d in found},
                                                                  key=lambda d: (d.stage, d.unit, d.path))))


def _hidden(dataset: str) -> str:
    return f"_parts_{dataset}"


def _arrow_dataset(run: RunFolder, dataset: str) -> pads.Dataset:
    """The dataset's part files as one pyarrow dataset: the registered schema when known (parts of older
    code versions may lack newer columns; they read as NULL), else the union of the parts' schemas."""
    parts = [str(path) for path in dataset_parts(run.root, dataset)]
    known = all_tables().get(dataset)
    schema = known.schema if known is not None else pa.unify_schemas([pq.read_schema(p) for p in parts])
    return pads.dataset(parts, schema=schema, format="parquet")


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


def query(run: RunFolder, sql: str) -> duckdb.DuckDBPyRelation:
    """Run one read-only `sql` statement against the run's datasets; the result is materialised, so every
    DuckDB error surfaces here as a one-line QueryError."""
    check_read_only(sql)
    try:
        return connect(run).sql(sql).materialize()
    except (duckdb.Error, pa.ArrowException) as error:  # Arrow: a part file pyarrow cannot read
        known = ", ".join(run.datasets()) or "none yet"
        raise QueryError(f"{_first_line(error)} (tables in {run.root}: {known})") from None


def _first_line(error: Exception) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0]


def write_result(relation: duckdb.DuckDBPyRelation, fmt: str, out: Path | None) -> str | None:
    """Write a result as csv/json/parquet to `out` (csv/json to the returned text when `out` is None).

    JSON is a list of row objects with numbers as JSON numbers (NaN and infinities as null), one
    trailing newline.
    """
    table = relation.arrow()
    if hasattr(table, "read_all"):  # DuckDB >= 1.4 returns a RecordBatchReader
        table = table.read_all()
    if fmt == "parquet":
        if out is None:
            raise QueryError("--format parquet needs --out FILE.parquet")
        pq.write_table(table, out)
        return None
    if fmt == "csv":
        import io

        import pyarrow.csv as pacsv

        buffer = io.BytesIO()
        pacsv.write_csv(table, buffer)
        text = buffer.getvalue().decode()
    else:
        rows = [{key: _json_value(value) for key, value in row.items()} for row in table.to_pylist()]
        text = json.dumps(rows, indent=1, allow_nan=False) + "\n"
    if out is not None:
        out.write_text(text)
        return None
    return text


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
