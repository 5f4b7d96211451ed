"""Parquet datasets of a run: the table registry and part-file I/O, below every stage.

Every table is written with its registered schema (never an inferred one). Each area declares its tables
with `register(...)` in `pipeline/<area>/tables.py`; those modules are found by that convention when a
dataset is looked up, so this layer names no stage. `schemas/tables/*.json` is generated from the
registry (`mvpd schemas`) and kept in sync by a test.

Readers never list a dataset folder: `dataset_parts` returns the part files that markers name and that
are there with the size their marker recorded (the commit protocol in schemas/README.md).
"""

from __future__ import annotations

import importlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.runtime.failures import error_text
from pipeline.runtime.markers import Damage, Marker, record_damage, stage_markers, stages_writing, unit_damage, unit_marker
from pipeline.runtime.object_store import RunStore, store_of

log = logging.getLogger(__name__)

_REGISTRY: dict[str, "TableSpec"] = {}
# Areas that declare no tables of their own (the runtime registers `status` itself, below).
_NOT_TABLE_AREAS = frozenset({"runtime", "io", "cli", "data"})


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
    importlib.import_module("pipeline.runtime.status")
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
    marker names it (`pipeline.runtime.executor.commit_tables` does both for work done outside a stage).
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


# ------------------------------------------------------------------------- trusted part files


@dataclass(frozen=True)
class _Part:
    """A trusted part: where it is read from (a local path, or a URL on the run's store), who committed it."""

    path: Path | str
    relative: str  # its logical path in the run, `<dataset>/part-<unit>.parquet`
    stage: str
    unit: str


# A stage's markers and its damaged units, as one pass over them found them (shared by the datasets a
# stage wrote: its ~40 files per unit are checked once, not once per dataset).
_Checked = dict[str, tuple[dict[str, Marker], dict[str, list[Damage]]]]


def _trusted_parts(run_root: Path, dataset: str, checked: _Checked | None = None) -> tuple[list[_Part], list[Damage]]:
    """Part files of `dataset` named by markers of undamaged units, and the damage that left the others out.

    On object storage the parts are the keys the markers name, read in place (`object_store.store_of`).
    """
    root = Path(run_root)
    store = store_of(root)
    checked = {} if checked is None else checked
    parts, damaged = [], []
    prefix = f"{dataset}/"
    for stage in stages_writing(root, dataset):
        if stage not in checked:
            markers = stage_markers(root, stage)
            # Any bad file of the unit withholds all its rows: a `videos` row whose Zarr lost a shard would
            # otherwise send readers to zeros.
            checked[stage] = markers, unit_damage(root, markers)
        markers, problems = checked[stage]
        writers = {unit: sorted(o for o in marker.outputs if o.startswith(prefix) and o.endswith(".parquet"))
                   for unit, marker in markers.items()}
        writers = {unit: names for unit, names in writers.items() if names}
        for unit, names in writers.items():
            if unit in problems:
                damaged.extend(problems[unit])
                continue
            keys = markers[unit].keys
            parts.extend(_Part(store.url_of(keys.get(name, name)) if store is not None else root / name, name, stage, unit)
                         for name in names)
    return sorted(parts, key=lambda p: p.relative), damaged


def trusted_parts(run_root: Path, dataset: str) -> tuple[list[Path | str], list[Damage]]:
    """`dataset_parts` and `damaged_parts` from one pass over the markers (a reader that reports damage
    and then reads checks each committed file once, not twice)."""
    return _paths(_trusted_parts(run_root, dataset))


def trusted_parts_of(run_root: Path, datasets: list[str]) -> dict[str, tuple[list[Path | str], list[Damage]]]:
    """`trusted_parts` of several datasets, each stage's files checked once (a reader of many tables)."""
    checked: _Checked = {}
    return {dataset: _paths(_trusted_parts(run_root, dataset, checked)) for dataset in datasets}


def _paths(found: tuple[list[_Part], list[Damage]]) -> tuple[list[Path | str], list[Damage]]:
    return [p.path for p in found[0]], found[1]


def dataset_parts(run_root: Path, dataset: str) -> list[Path | str]:
    """The readable, marker-trusted part files of `dataset`, sorted: the one way every reader finds parts
    (local paths; on object storage, the URLs of the keys their markers name).

    Listed are the parts markers name whose units are intact: a part whose marker is gone (an attempt
    that died, a retired unit) is not listed, nor a part of a unit with any file missing, resized or
    found corrupt (see `damaged_parts`).
    """
    return [p.path for p in _trusted_parts(run_root, dataset)[0]]


def damaged_parts(run_root: Path, dataset: str) -> list[Damage]:
    """Why parts of `dataset` are left out: the damaged files of the units that wrote them (for reporting)."""
    return _trusted_parts(run_root, dataset)[1]


def damage_line(dataset: str, damaged: list[Damage]) -> str:
    """One line saying which parts of `dataset` were left out and how to repair them (for every reader)."""
    stages = sorted({d.stage for d in damaged})
    units = len({(d.stage, d.unit) for d in damaged})
    return (f"{dataset}: rows of {units} damaged unit(s) left out, e.g. {damaged[0].line()}; "
            f"`mvpd rerun RUN --stage {stages[0]}` writes {'them' if units > 1 else 'it'} again"
            + (f" (stages {', '.join(stages)})" if len(stages) > 1 else ""))


def read_dataset(run_root: Path, dataset: str, warn: bool = True) -> pa.Table:
    """All trusted parts of a dataset as one table with the registered schema (empty when none).

    Damaged parts are left out with one warning line (unless `warn` is False, for a caller that reports
    damage itself); a part that cannot be read is skipped too and recorded as damage of the unit that
    wrote it, so `mvpd status` shows that unit as damaged and `mvpd rerun` writes it again.
    """
    schema = spec(dataset).schema
    tables = []
    parts, damaged = _trusted_parts(run_root, dataset)
    if damaged and warn:
        log.warning("%s", damage_line(dataset, damaged))
    store = store_of(run_root)
    for part in parts:
        try:
            tables.append(read_part(part.path, schema, store))
        except (pa.ArrowException, OSError) as error:
            log.warning("%s: unreadable Parquet part (%s); skipped, rerun stage %s to rewrite it",
                        part.path, error_text(error), part.stage)
            marker = unit_marker(Path(run_root), part.stage, part.unit)
            if marker is not None:
                record_damage(Path(run_root), marker, [Damage(part.stage, part.unit, part.relative, "is unreadable Parquet")])
    return pa.concat_tables(tables) if tables else schema.empty_table()


def read_part(location: Path | str, schema: pa.Schema, store: RunStore | None = None, **options: Any) -> pa.Table:
    """One trusted part, from local disk or (a URL from `dataset_parts`) read in place from the run's store."""
    if store is None:
        return pq.read_table(location, schema=schema, **options)
    # One GET of the whole part: through a file system pyarrow asks for the size, opens, then reads the
    # footer and the data by ranges (4 requests a part; each costs more than a small part's bytes).
    return pq.read_table(pa.BufferReader(store.fs.cat_file(str(location))), schema=schema, **options)
