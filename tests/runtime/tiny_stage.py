"""A tiny stage for runtime tests: one unit per embodiment, behaviour steered by files in the run.

`control/<unit>.fail` makes the unit raise; `control/<unit>.kill` makes its worker process die once
(after writing part of its output), as a crashed machine would.
"""

from __future__ import annotations

import os
import signal
import time

import pyarrow as pa

from pipeline.config import StageResources
from pipeline.io.tables import column, register, to_table
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult


def register_table() -> None:
    """Register the tiny stage's table (tests/runtime/conftest.py does for the runtime tests, and each unit in
    its own process: a table registered at import would show in other tests' registry, e.g. schemas/)."""
    register("tiny", [column("unit", pa.string(), "unit id"), column("value", pa.int64(), "a seeded draw")],
             row="one draw of one tiny unit")


class TinyStage(Stage):
    """Writes one seeded number and one text file per embodiment of the job."""

    name = "tiny"
    datasets = ("tiny",)

    def units(self, run: RunFolder) -> list[Unit]:
        return sorted((Unit(e.name, {"placements": list(e.placements)}) for e in self.job.embodiments),
                      key=lambda u: u.id)

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        register_table()  # Ray workers import this module by value: register the table there too
        control = context.run.root / "control"
        if (control / f"{unit.id}.hang").exists():
            time.sleep(600)
        if (control / f"{unit.id}.fail").exists():
            raise ValueError(f"{unit.id}: told to fail by {control / (unit.id + '.fail')}")
        value = int(context.rng().integers(0, 2**62))
        context.staged_path(f"tiny_files/{unit.id}.txt").write_text(str(value))
        if (control / f"{unit.id}.kill").exists() and not (control / f"{unit.id}.killed").exists():
            (control / f"{unit.id}.killed").touch()
            os.kill(os.getpid(), signal.SIGKILL)
        context.write_table("tiny", to_table("tiny", [{"unit": unit.id, "value": value}]))
        return UnitResult(info={"value": value})


class QuickTimeoutStage(TinyStage):
    """The tiny stage with a 3-second unit timeout."""

    def resources(self) -> StageResources:
        return StageResources(cpus=1, memory_gb=0.1, timeout_s=3)


_DRIVER_PID = os.getpid()


def _only_in_the_driver(job: object) -> "UnsendableStage":
    if os.getpid() != _DRIVER_PID:
        raise RuntimeError("this stage cannot be set up in a worker")
    return UnsendableStage(job)  # type: ignore[arg-type]


class UnsendableStage(TinyStage):
    """The tiny stage, failing to unpickle in any Ray worker: Ray cannot start its tasks and never retries them."""

    def __reduce__(self) -> tuple:
        return (_only_in_the_driver, (self.job,))
