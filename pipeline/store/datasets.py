"""Reading a run's Parquet datasets: only the parts markers name, of units whose files are intact.

Readers never list a dataset folder: `dataset_parts` returns the part files that markers name and that
are there with the size their marker recorded (the commit protocol in schemas/README.md). On object
storage the parts are the keys the markers name, read in place. The run folder finds them
(`RunFolder.trusted_parts`, `RunFolder.read`); these are the names every reader calls.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pyarrow as pa

from pipeline.store.markers import Damage, Marker

if TYPE_CHECKING:
    from pipeline.store.run_folder import RunFolder


@dataclass(frozen=True)
class TrustedPart:
    """A trusted part: where it is read from (a local path, or a URL on the run's store), who committed it."""

    path: Path | str
    relative: str  # its logical path in the run, `<dataset>/part-<unit>.parquet`
    stage: str
    unit: str


# A stage's markers and its damaged units, as one pass over them found them (shared by the datasets a
# stage wrote: its ~40 files per unit are checked once, not once per dataset).
CheckedStages = dict[str, tuple[dict[str, Marker], dict[str, list[Damage]]]]


def trusted_parts(run: RunFolder, dataset: str) -> tuple[list[Path | str], list[Damage]]:
    """`dataset_parts` and `damaged_parts` from one pass over the markers (a reader that reports damage
    and then reads checks each committed file once, not twice)."""
    return _paths(run.trusted_parts(dataset))


def trusted_parts_of(run: RunFolder, datasets: list[str]) -> dict[str, tuple[list[Path | str], list[Damage]]]:
    """`trusted_parts` of several datasets, each stage's files checked once (a reader of many tables)."""
    checked: CheckedStages = {}
    return {dataset: _paths(run.trusted_parts(dataset, checked)) for dataset in datasets}


def _paths(found: tuple[list[TrustedPart], list[Damage]]) -> tuple[list[Path | str], list[Damage]]:
    return [p.path for p in found[0]], found[1]


def dataset_parts(run: RunFolder, dataset: str) -> list[Path | str]:
    """The readable, marker-trusted part files of `dataset`, sorted: the one way every reader finds parts
    (local paths; on object storage, the URLs of the keys their markers name).

    Listed are the parts markers name whose units are intact: a part whose marker is gone (an attempt
    that died, a retired unit) is not listed, nor a part of a unit with any file missing, resized or
    found corrupt (see `damaged_parts`).
    """
    return [p.path for p in run.trusted_parts(dataset)[0]]


def damaged_parts(run: RunFolder, dataset: str) -> list[Damage]:
    """Why parts of `dataset` are left out: the damaged files of the units that wrote them (for reporting)."""
    return run.trusted_parts(dataset)[1]


def damage_line(dataset: str, damaged: list[Damage]) -> str:
    """One line saying which parts of `dataset` were left out and how to repair them (for every reader)."""
    stages = sorted({d.stage for d in damaged})
    units = len({(d.stage, d.unit) for d in damaged})
    return (f"{dataset}: rows of {units} damaged unit(s) left out, e.g. {damaged[0].line()}; "
            f"`mvpd rerun RUN --stage {stages[0]}` writes {'them' if units > 1 else 'it'} again"
            + (f" (stages {', '.join(stages)})" if len(stages) > 1 else ""))


def read_dataset(run: RunFolder, dataset: str, warn: bool = True) -> pa.Table:
    """All trusted parts of a dataset as one table with the registered schema (see `RunFolder.read`)."""
    return run.read(dataset, warn)
