"""Parquet datasets of a run: the table registry and part-file I/O, below every stage.

Every table is written with its registered schema (never an inferred one). Each area declares its tables
with `register(...)` in `pipeline/<area>/tables.py`; those modules are found by that convention when a
dataset is looked up, so this layer names no stage. `schemas/tables/*.json` is generated from the
registry (`mvpd schemas`) and kept in sync by a test. Which parts a reader may trust is the run
folder's business (`pipeline.store.datasets`).
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

_REGISTRY: dict[str, "TableSpec"] = {}
# Areas whose `tables.py` is no declaration of tables (this registry, and the public face of it).
_NOT_TABLE_AREAS = frozenset({"store", "io"})


@dataclass(frozen=True)
class TableSpec:
    """A dataset name, its Arrow schema (with a description per field) and what one row is."""

    name: str
    schema: pa.Schema
    row: str
    version: int = 1


def column(name: str, dtype: pa.DataType, doc: str, nullable: bool = False) -> pa.Field:
    """A schema field whose description (with unit) is stored in the Parquet metadata."""
    return pa.field(name, dtype, nullable=nullable, metadata={"description": doc})


def register(name: str, fields: list[pa.Field], row: str, version: int = 1) -> TableSpec:
    """Declare a dataset of the run folder."""
    spec = TableSpec(name, pa.schema(fields, metadata={"dataset": name, "version": str(version)}), row, version)
    _REGISTRY[name] = spec
    return spec


def all_tables() -> dict[str, TableSpec]:
    """Every registered dataset, by name (imports each `pipeline/<area>/tables.py` once)."""
    package = Path(__file__).resolve().parents[1]
    for area in sorted(p.name for p in package.iterdir() if (p / "tables.py").is_file()):
        if area not in _NOT_TABLE_AREAS:
            importlib.import_module(f"pipeline.{area}.tables")
    return dict(sorted(_REGISTRY.items()))


def spec(name: str) -> TableSpec:
    """The registered spec of dataset `name`; KeyError naming the known datasets otherwise."""
    if name in _REGISTRY:
        return _REGISTRY[name]
    tables = all_tables()
    if name not in tables:
        raise KeyError(f"no registered dataset {name!r}; known: {', '.join(tables)}")
    return tables[name]


def to_table(name: str, rows: list[dict] | dict[str, list]) -> pa.Table:
    """Build a table of a registered dataset from rows (list of dicts) or columns (dict of lists)."""
    schema = spec(name).schema
    if isinstance(rows, dict):
        return pa.Table.from_pydict(rows, schema=schema)
    return pa.Table.from_pylist(rows, schema=schema)


def write_part(root: Path, dataset: str, unit_id: str, table: pa.Table) -> Path:
    """Write `<root>/<dataset>/part-<unit_id>.parquet` atomically (temp file + rename).

    `root` is a unit's staging folder: the part becomes visible to readers only once the unit's
    marker names it (`RunFolder.commit_tables` does both for work done outside a stage).
    """
    expected = spec(dataset).schema
    if not table.schema.equals(expected, check_metadata=False):
        table = table.cast(expected)
    table = table.replace_schema_metadata(expected.metadata)
    path = Path(root) / dataset / f"part-{unit_id}.parquet"
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    # Deterministic bytes: no timestamps, fixed writer options.
    pq.write_table(table, temporary, compression="zstd", write_statistics=True, store_schema=True)
    os.replace(temporary, path)
    return path
