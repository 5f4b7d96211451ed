"""The stages of a job, in data-flow order, by name (imported lazily so the CLI starts fast)."""

from __future__ import annotations

import importlib

from pipeline.config import Job
from pipeline.runtime.stage import Stage

STAGE_CLASSES: dict[str, str] = {
    "shard": "pipeline.scenes.shard:SceneSharder",
    "plan": "pipeline.plan.stage:PathPlanner",
    "render": "pipeline.render.stage:RgbdRenderer",
    "screen": "pipeline.split.stage:VideoScreener",
    "split": "pipeline.split.stage:SplitAssigner",
}
# `evaluate` runs through `mvpd evaluate` (it needs predictions), on the same runtime.
JOB_STAGES = tuple(STAGE_CLASSES)


def stage_class(name: str) -> type[Stage]:
    if name not in STAGE_CLASSES:
        raise KeyError(f"unknown stage {name!r}; stages are {', '.join(STAGE_CLASSES)}")
    module, _, attribute = STAGE_CLASSES[name].partition(":")
    return getattr(importlib.import_module(module), attribute)


def make_stage(name: str, job: Job) -> Stage:
    return stage_class(name)(job)
