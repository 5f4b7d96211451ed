"""SQL over a run's Parquet datasets with DuckDB: every dataset is a view of the same name.

One view joins two datasets: `frames` (poses, written by `plan`) also shows the per-frame columns of
`frame_stats` (written by `render`; NULL until a video is rendered). They stay two datasets on disk
because each stage commits only its own outputs, so re-rendering never rewrites the plan's files.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.lazy_import import lazy_module
from pipeline.runtime.run_folder import RunFolder

duckdb = lazy_module("duckdb")  # loaded on first query, not by every `mvpd` command


class QueryError(ValueError):
    """SQL that DuckDB rejected; the message is DuckDB's first line."""


FRAME_KEY = ("embodiment", "video_name", "frame")


def connect(run: RunFolder) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB connection with one view per Parquet dataset of the run (`frames` joined)."""
    connection = duckdb.connect(":memory:")
    datasets = run.datasets()
    for dataset in datasets:
        connection.execute(f'CREATE VIEW "{dataset}" AS {_scan(run, dataset)}')
    if {"frames", "frame_stats"} <= set(datasets):
        keys = ", ".join(FRAME_KEY)
        connection.execute(f"CREATE OR REPLACE VIEW frames AS SELECT f.*, s.* EXCLUDE ({keys}) "
                           f"FROM ({_scan(run, 'frames')}) f LEFT JOIN ({_scan(run, 'frame_stats')}) s USING ({keys})")
    return connection


def _scan(run: RunFolder, dataset: str) -> str:
    """SELECT over every part file of a dataset (parts of older code versions may lack newer columns)."""
    pattern = str(run.root / dataset / "part-*.parquet").replace("'", "''")
    return f"SELECT * FROM read_parquet('{pattern}', union_by_name = true)"


def query(run: RunFolder, sql: str) -> duckdb.DuckDBPyRelation:
    """Run `sql` against the run's datasets."""
    try:
        return connect(run).sql(sql)
    except duckdb.Error as error:
        first = str(error).strip().splitlines()[0]
        known = ", ".join(run.datasets()) or "none yet"
        raise QueryError(f"{first} (tables in {run.root}: {known})") from None


def write_result(relation: duckdb.DuckDBPyRelation, fmt: str, out: Path | None) -> str | None:
    """Write a result as csv/json/parquet to `out` (csv/json to the returned text when `out` is None)."""
    table = relation.arrow()
    if hasattr(table, "read_all"):  # DuckDB >= 1.4 returns a RecordBatchReader
        table = table.read_all()
    if fmt == "parquet":
        if out is None:
            raise QueryError("--format parquet needs --out FILE.parquet")
        import pyarrow.parquet as pq

        pq.write_table(table, out)
        return None
    if fmt == "csv":
        import pyarrow.csv as pacsv
        import io

        buffer = io.BytesIO()
        pacsv.write_csv(table, buffer)
        text = buffer.getvalue().decode()
    else:
        import json

        text = json.dumps(table.to_pylist(), default=str, indent=1)
    if out is not None:
        out.write_text(text)
        return None
    return text
