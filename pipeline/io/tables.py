"""Parquet datasets of a run: one registered, documented schema per dataset, one part file per unit.

Every table is written with its registered schema (never an inferred one). Each stage module declares
its tables with `register(...)` in `pipeline/<stage>/tables.py`; `schemas/tables/*.json` is generated
from the registry (`mvpd schemas`) and kept in sync by a test.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

_REGISTRY: dict[str, "TableSpec"] = {}
# Modules that register tables; imported lazily so that `io` does not depend on the stages.
_TABLE_MODULES = (
    "pipeline.runtime.status",
    "pipeline.scenes.tables",
    "pipeline.plan.tables",
    "pipeline.render.tables",
    "pipeline.split.tables",
    "pipeline.evaluate.tables",
)


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
    """Every registered dataset, by name."""
    for module in _TABLE_MODULES:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as error:
            if error.name != module:
                raise
    return dict(sorted(_REGISTRY.items()))


def spec(name: str) -> TableSpec:
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
    """Write `<root>/<dataset>/part-<unit_id>.parquet` atomically (temp file + rename)."""
    expected = spec(dataset).schema
    if not table.schema.equals(expected, check_metadata=False):
        table = table.cast(expected)
    table = table.replace_schema_metadata(expected.metadata)
    path = root / dataset / f"part-{unit_id}.parquet"
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    # Deterministic bytes: no timestamps, fixed writer options.
    pq.write_table(table, temporary, compression="zstd", write_statistics=True, store_schema=True)
    os.replace(temporary, path)
    return path


def dataset_parts(run_root: Path, dataset: str) -> list[Path]:
    """The part files of a dataset, sorted; names are matched literally, so no character of the run
    path (`[v1]`, `*`, `?`) is ever read as a pattern."""
    folder = Path(run_root) / dataset
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.name.startswith("part-") and p.name.endswith(".parquet") and p.is_file())


def read_dataset(run_root: Path, dataset: str) -> pa.Table:
    """All part files of a dataset as one table with the registered schema (empty when none)."""
    folder = Path(run_root) / dataset
    parts = sorted(folder.glob("part-*.parquet")) if folder.is_dir() else []
    schema = spec(dataset).schema
    if not parts:
        return schema.empty_table()
    return pa.concat_tables([pq.read_table(p, schema=schema) for p in parts])
