"""What state each stage of a run is in: done, stale, failed and pending units."""

from __future__ import annotations

from dataclasses import dataclass, field

from pipeline.runtime.executor import StageOrderError, plan_stage
from pipeline.runtime.run_folder import STATE, RunFolder
from pipeline.runtime.status import UnitOutcome, read_status
from pipeline.stages import JOB_STAGES, make_stage


@dataclass
class StageState:
    """Units of one stage by state; `waiting_for` names the upstream stage when none can be listed yet."""

    stage: str
    done: list[str] = field(default_factory=list)
    stale: list[str] = field(default_factory=list)
    failed: list[UnitOutcome] = field(default_factory=list)
    pending: list[str] = field(default_factory=list)
    waiting_for: str = ""

    @property
    def total(self) -> int:
        return len(self.done) + len(self.stale) + len(self.failed) + len(self.pending)


def stage_states(run: RunFolder) -> list[StageState]:
    """The state of every job stage of `run`."""
    job = run.job()
    statuses = read_status(run.root)
    states = [_state(run, make_stage(name, job), statuses) for name in JOB_STAGES]
    # Stages outside the job (import, evaluate) are shown by what they recorded.
    recorded = sorted({stage for stage, _ in statuses} | {p.name for p in (run.root / STATE).glob("*") if p.is_dir()})
    return states + [_recorded_state(run, name, statuses) for name in recorded if name not in JOB_STAGES]


def _recorded_state(run: RunFolder, stage: str, statuses: dict[tuple[str, str], UnitOutcome]) -> StageState:
    state = StageState(stage, done=sorted(run.markers(stage)))
    state.failed = [o for (name, unit), o in sorted(statuses.items())
                    if name == stage and o.failed and unit not in state.done]
    return state


def _state(run: RunFolder, stage, statuses: dict[tuple[str, str], UnitOutcome]) -> StageState:
    state = StageState(stage.name)
    try:
        plan = plan_stage(stage, run)
    except StageOrderError:
        state.waiting_for = "waiting for " + ", ".join(stage.after)
        return state
    markers = run.markers(stage.name)
    state.done = sorted(plan.up_to_date)
    for unit in plan.to_run:
        outcome = statuses.get((stage.name, unit.id))
        if outcome is not None and outcome.failed:
            state.failed.append(outcome)
        elif unit.id in markers:
            state.stale.append(unit.id)
        else:
            state.pending.append(unit.id)
    return state
