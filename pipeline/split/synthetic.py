"""Synthetic run metadata for the split stages' tests and benchmark: the Parquet tables shard and render
write (`scenes`, `objects`, `videos`, `frame_stats`, `segments`) and their markers, without any pixels.

Rows are given as dicts holding the columns that matter; every other registered column gets a neutral
value of its type. Markers are real markers (the split stages read their config hashes).
"""

from __future__ import annotations

import socket
import time
from collections.abc import Iterable
from typing import Any

import pyarrow as pa

from pipeline.io.tables import spec
from pipeline.store.markers import Marker
from pipeline.store.run_folder import RunFolder


def neutral_rows(dataset: str, rows: Iterable[dict[str, Any]]) -> pa.Table:
    """A table of `dataset` from partial rows: missing columns are 0, '', False, [] or zeros of a fixed-size list."""
    schema = spec(dataset).schema
    filled = []
    for row in rows:
        full = {}
        for field in schema:
            if field.name in row:
                full[field.name] = row[field.name]
            elif pa.types.is_fixed_size_list(field.type):
                full[field.name] = [0] * field.type.list_size
            elif pa.types.is_list(field.type):
                full[field.name] = []
            elif pa.types.is_string(field.type):
                full[field.name] = ""
            elif pa.types.is_boolean(field.type):
                full[field.name] = False
            else:
                full[field.name] = None if field.nullable else 0
        filled.append(full)
    return pa.Table.from_pylist(filled, schema=schema)


def write_dataset(run: RunFolder, dataset: str, table: pa.Table, part: str = "synthetic") -> None:
    """Commit one part file of a dataset into the run, as a unit of the pseudo-stage `_synthetic` (readers
    trust only parts a marker names; the registered schema is enforced by `write_part`)."""
    run.commit_tables("_synthetic", f"{dataset}.{part}", {dataset: table})


def mark_done(run: RunFolder, stage: str, unit_ids: Iterable[str], config_hash: str = "synthetic") -> None:
    """Write markers for `unit_ids` of `stage`, as if the stage had committed them."""
    for unit in unit_ids:
        run.write_marker(Marker(stage, unit, config_hash, "synthetic", [], {}, 0.0, 1, socket.gethostname(), time.time()))
