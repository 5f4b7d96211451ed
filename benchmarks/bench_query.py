"""What confining `mvpd query` costs: the locked-down connection (each dataset a scan of its list of
marker-trusted part files, glob characters escaped, DuckDB's file access off) against DuckDB's own `read_parquet` over a glob
of the same files (the unconfined peer it replaced).

A `segments`-shaped dataset of 200 part files (2 M rows, one per mask) is written to a temporary run
folder; three `mvpd stats`-style aggregates run 3 times on each connection. Each connection is opened
fresh per run (as every `mvpd query` does). Run: `.venv/bin/python benchmarks/bench_query.py`; prints
and writes benchmarks/results/query.json (median and spread of each, and the confined/peer ratio).
"""

from __future__ import annotations

import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

import duckdb
import numpy as np
import pyarrow as pa

from pipeline.io.query import connect
from pipeline.io.tables import spec
from pipeline.store.names import atomic_write_text
from pipeline.store.run_folder import RunFolder

RESULTS = Path(__file__).resolve().parent / "results" / "query.json"
PARTS, ROWS_PER_PART, REPEATS = 200, 10_000, 3
QUERIES = {
    "masks per category": "select category, count(*), count(distinct object_id) from segments group by 1",
    "area of one video": "select sum(area) from segments where video_name = 'v-00017'",
    "rows": "select count(*) from segments",
}


def write_run(root: Path) -> RunFolder:
    """A run folder holding only a `segments` dataset of PARTS parts (job.yaml just marks it as a run)."""
    atomic_write_text(root / "job.yaml", "job: {}\n")
    run = RunFolder(root)
    rng = np.random.default_rng(0)
    schema = spec("segments").schema
    for part in range(PARTS):
        n = ROWS_PER_PART
        columns = {
            "embodiment": ["e"] * n, "video_name": [f"v-{part:05d}"] * n, "frame": np.repeat(np.arange(n // 20), 20),
            "object_id": rng.integers(1, 300, n, dtype=np.uint32), "category": rng.integers(0, 41, n, dtype=np.int16),
            "area": rng.integers(10, 5000, n), "x0": np.zeros(n, np.int32), "y0": np.zeros(n, np.int32),
            "x1": np.full(n, 63, np.int32), "y1": np.full(n, 47, np.int32),
        }
        run.commit_tables("render", f"v-{part:05d}", {"segments": pa.Table.from_pydict(columns, schema=schema)})
    return run


def unconfined(run: RunFolder) -> duckdb.DuckDBPyConnection:
    """The previous connection: read_parquet over a glob of the run path (what glob characters broke)."""
    connection = duckdb.connect(":memory:")
    pattern = str(run.root / "segments" / "part-*.parquet")
    connection.execute(f"CREATE VIEW segments AS SELECT * FROM read_parquet('{pattern}', union_by_name = true)")
    return connection


def timed(open_connection, run: RunFolder, sql: str) -> tuple[float, object]:
    started = time.perf_counter()
    result = open_connection(run).sql(sql).fetchall()
    return time.perf_counter() - started, result


def main() -> None:
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as folder:
        run = write_run(Path(folder) / "run")
        for name, sql in QUERIES.items():
            seconds: dict[str, list[float]] = {"confined": [], "read_parquet": []}
            answers = {}
            for _ in range(REPEATS):  # interleaved, so a load spike on the shared machine hits both
                for label, opener in (("confined", connect), ("read_parquet", unconfined)):
                    elapsed, answers[label] = timed(opener, run, sql)
                    seconds[label].append(elapsed)
            assert sorted(answers["confined"]) == sorted(answers["read_parquet"]), name
            row = {label: {"median_s": statistics.median(v), "min_s": min(v), "max_s": max(v), "runs": v}
                   for label, v in seconds.items()}
            row["ratio_confined_over_peer"] = row["confined"]["median_s"] / row["read_parquet"]["median_s"]
            results[name] = row
            print(f"{name:20s} confined {row['confined']['median_s'] * 1000:7.1f} ms "
                  f"[{row['confined']['min_s'] * 1000:.1f}-{row['confined']['max_s'] * 1000:.1f}]  "
                  f"read_parquet {row['read_parquet']['median_s'] * 1000:7.1f} ms "
                  f"[{row['read_parquet']['min_s'] * 1000:.1f}-{row['read_parquet']['max_s'] * 1000:.1f}]  "
                  f"ratio {row['ratio_confined_over_peer']:.2f}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"parts": PARTS, "rows": PARTS * ROWS_PER_PART, "repeats": REPEATS,
                                   "machine": platform.node(), "note": "shared 2-core VM under load from other work",
                                   "queries": results}, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
