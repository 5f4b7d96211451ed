"""Reading a run's Parquet datasets: only the parts markers name, of units whose files are intact.

Readers never list a dataset folder: `dataset_parts` returns the part files that markers name and that
are there with the size their marker recorded (the commit protocol in schemas/README.md). On object
storage the parts are the keys the markers name, read in place.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pyarrow as pa

from pipeline.errors import error_text
from pipeline.store.markers import Damage, Marker
from pipeline.store.tables import spec

if TYPE_CHECKING:
    from pipeline.store.run_folder import RunFolder

log = logging.getLogger(__name__)


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


def _trusted_parts(run: RunFolder, dataset: str, checked: _Checked | None = None) -> tuple[list[_Part], list[Damage]]:
    """Part files of `dataset` named by markers of undamaged units, and the damage that left the others out."""
    checked = {} if checked is None else checked
    parts, damaged = [], []
    prefix = f"{dataset}/"
    for stage in run.stages_writing(dataset):
        if stage not in checked:
            markers = run.markers(stage)
            # Any bad file of the unit withholds all its rows: a `videos` row whose Zarr lost a shard would
            # otherwise send readers to zeros.
            checked[stage] = markers, run.damage(markers)
        markers, problems = checked[stage]
        for unit, marker in markers.items():
            names = sorted(o for o in marker.outputs if o.startswith(prefix) and o.endswith(".parquet"))
            if not names:
                continue
            if unit in problems:
                damaged.extend(problems[unit])
                continue
            parts.extend(_Part(run.part_location(marker, name), name, stage, unit) for name in names)
    return sorted(parts, key=lambda p: p.relative), damaged


def trusted_parts(run: RunFolder, dataset: str) -> tuple[list[Path | str], list[Damage]]:
    """`dataset_parts` and `damaged_parts` from one pass over the markers (a reader that reports damage
    and then reads checks each committed file once, not twice)."""
    return _paths(_trusted_parts(run, dataset))


def trusted_parts_of(run: RunFolder, datasets: list[str]) -> dict[str, tuple[list[Path | str], list[Damage]]]:
    """`trusted_parts` of several datasets, each stage's files checked once (a reader of many tables)."""
    checked: _Checked = {}
    return {dataset: _paths(_trusted_parts(run, dataset, checked)) for dataset in datasets}


def _paths(found: tuple[list[_Part], list[Damage]]) -> tuple[list[Path | str], list[Damage]]:
    return [p.path for p in found[0]], found[1]


def dataset_parts(run: RunFolder, dataset: str) -> list[Path | str]:
    """The readable, marker-trusted part files of `dataset`, sorted: the one way every reader finds parts
    (local paths; on object storage, the URLs of the keys their markers name).

    Listed are the parts markers name whose units are intact: a part whose marker is gone (an attempt
    that died, a retired unit) is not listed, nor a part of a unit with any file missing, resized or
    found corrupt (see `damaged_parts`).
    """
    return [p.path for p in _trusted_parts(run, dataset)[0]]


def damaged_parts(run: RunFolder, dataset: str) -> list[Damage]:
    """Why parts of `dataset` are left out: the damaged files of the units that wrote them (for reporting)."""
    return _trusted_parts(run, dataset)[1]


def damage_line(dataset: str, damaged: list[Damage]) -> str:
    """One line saying which parts of `dataset` were left out and how to repair them (for every reader)."""
    stages = sorted({d.stage for d in damaged})
    units = len({(d.stage, d.unit) for d in damaged})
    return (f"{dataset}: rows of {units} damaged unit(s) left out, e.g. {damaged[0].line()}; "
            f"`mvpd rerun RUN --stage {stages[0]}` writes {'them' if units > 1 else 'it'} again"
            + (f" (stages {', '.join(stages)})" if len(stages) > 1 else ""))


def read_dataset(run: RunFolder, dataset: str, warn: bool = True) -> pa.Table:
    """All trusted parts of a dataset as one table with the registered schema (empty when none).

    Damaged parts are left out with one warning line (unless `warn` is False, for a caller that reports
    damage itself); a part that cannot be read is skipped too and recorded as damage of the unit that
    wrote it, so `mvpd status` shows that unit as damaged and `mvpd rerun` writes it again.
    """
    schema = spec(dataset).schema
    tables = []
    parts, damaged = _trusted_parts(run, dataset)
    if damaged and warn:
        log.warning("%s", damage_line(dataset, damaged))
    for part in parts:
        try:
            tables.append(run.read_part(part.path, schema))
        except (pa.ArrowException, OSError) as error:
            log.warning("%s: unreadable Parquet part (%s); skipped, rerun stage %s to rewrite it",
                        part.path, error_text(error), part.stage)
            marker = run.marker(part.stage, part.unit)
            if marker is not None:
                run.record_damage(part.stage, [(marker, [Damage(part.stage, part.unit, part.relative,
                                                                "is unreadable Parquet")])])
    return pa.concat_tables(tables) if tables else schema.empty_table()
