"""The stage contract: a stage turns the job and its inputs into units; a unit is one Ray task.

A unit writes only into its private staging folder (`UnitContext.staging`, laid out like the run
folder); the runtime commits the staged files into the run folder and only then writes the unit's
marker. So a unit may run twice (a retried worker) without leaving partial or duplicated output.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pyarrow as pa

from pipeline.config import Job, StageResources, config_hash
from pipeline.store.tables import write_part

if TYPE_CHECKING:
    from pipeline.store.run_folder import RunFolder


@dataclass(frozen=True)
class Unit:
    """One piece of work of a stage.

    Attributes:
        id: derived from content (scene id, embodiment, video name), safe as a file name; never from
            listing order.
        params: JSON-able inputs the unit needs (paths, ids); part of its config hash.
    """

    id: str
    params: dict[str, Any] = field(default_factory=dict)


@dataclass
class UnitResult:
    """What a unit reports back: rows written per dataset and anything worth keeping in its marker."""

    rows: dict[str, int] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


class UnitContext:
    """What a running unit gets: the job, the run folder (read-only), a staging folder, a seeded RNG, a logger."""

    def __init__(self, job: Job, run: "RunFolder", stage: str, unit: Unit, staging: Path, logger: logging.Logger):
        self.job = job
        self.run = run
        self.stage = stage
        self.unit = unit
        self.staging = staging
        self.log = logger
        self._rows: dict[str, int] = {}

    def rng(self, *extra: str | int) -> np.random.Generator:
        """A generator seeded with (job seed, stage, unit id, *extra): the only source of randomness."""
        return seeded_rng(self.job.seed, self.stage, self.unit.id, *extra)

    def write_table(self, dataset: str, table: pa.Table) -> Path:
        """Stage `table` as `<dataset>/part-<unit>.parquet` (the table must carry its registered schema)."""
        path = write_part(self.staging, dataset, self.unit.id, table)
        self._rows[dataset] = self._rows.get(dataset, 0) + table.num_rows
        return path

    def staged_path(self, relative: str) -> Path:
        """A path inside the staging folder (for Zarr stores and other files); parents are created."""
        path = self.staging / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    @property
    def rows_written(self) -> dict[str, int]:
        return dict(self._rows)


def seeded_rng(seed: int, *keys: str | int) -> np.random.Generator:
    """numpy Generator from a seed and string keys, stable across processes and Python versions."""
    digest = config_hash([seed, *[str(k) for k in keys]])
    return np.random.default_rng([seed, int(digest, 16)])


class Stage(ABC):
    """One step of the pipeline. Subclasses set `name`, `after` and implement `units` and `run_unit`.

    A stage's units are listed from the job and from the committed outputs of the stages it comes
    after, so a unit that failed upstream simply has no units downstream.
    """

    name: ClassVar[str]
    after: ClassVar[tuple[str, ...]] = ()
    datasets: ClassVar[tuple[str, ...]] = ()
    # Why a stage may have no units at all, and where to look (said when a later stage has nothing to read).
    when_empty: ClassVar[str] = "the stages before it produced nothing for it; `mvpd status RUN` shows each stage"

    def __init__(self, job: Job):
        self.job = job

    @abstractmethod
    def units(self, run: "RunFolder") -> list[Unit]:
        """Every unit of this stage for this job, deterministic and sorted by id."""

    @abstractmethod
    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult | None:
        """Do the work of one unit, writing only through `context`. Raise to fail the unit."""

    def resources(self) -> StageResources:
        """CPUs, memory and timeout of one unit (from the job's `runtime.resources`)."""
        return self.job.runtime.for_stage(self.name)

    def settings(self) -> dict[str, Any]:
        """The part of the job this stage's output depends on (hashed into every unit's marker)."""
        return {"seed": self.job.seed}

    def unit_hash(self, unit: Unit) -> str:
        """Config hash of one unit: stage settings + unit params. A changed hash makes the unit stale."""
        return config_hash({"stage": self.name, "settings": self.settings(), "params": unit.params})
