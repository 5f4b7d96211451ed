"""What state each stage of a run is in: done, stale, failed, pending and damaged units."""

from __future__ import annotations

from dataclasses import dataclass, field

from pipeline.config import ConfigError
from pipeline.runtime.executor import StageOrderError, plan_stage
from pipeline.runtime.stage import Stage
from pipeline.runtime.status import UnitOutcome, read_status
from pipeline.stages import JOB_STAGES, make_stage
from pipeline.store.datasets import damaged_parts
from pipeline.store.markers import Damage
from pipeline.store.run_folder import RunFolder


@dataclass
class StageState:
    """Units of one stage by state; `waiting_for` names the upstream stage when none can be listed yet.

    `damaged` units have a marker but committed files that are missing, resized or found corrupt
    (`mvpd status --verify`); `mvpd rerun` runs them again.
    """

    stage: str
    done: list[str] = field(default_factory=list)
    stale: list[str] = field(default_factory=list)
    failed: list[UnitOutcome] = field(default_factory=list)
    pending: list[str] = field(default_factory=list)
    damaged: dict[str, list[Damage]] = field(default_factory=dict)
    waiting_for: str = ""
    unlisted: str = ""  # why the stage's units cannot be listed now (the run's tables as they are); else ""

    @property
    def total(self) -> int:
        return len(self.done) + len(self.stale) + len(self.failed) + len(self.pending) + len(self.damaged)


@dataclass
class RunState:
    """Every stage's state, and damage of the status table itself (its outcomes then come from markers)."""

    stages: list[StageState]
    status_damage: list[Damage] = field(default_factory=list)


def run_state(run: RunFolder) -> RunState:
    """The state of every job stage of `run`, then of stages outside the job (import, evaluate)."""
    job = run.job()
    statuses = read_status(run)
    states = [_state(run, make_stage(name, job), statuses) for name in JOB_STAGES]
    # Stages outside the job are shown by what they recorded; `_`-names are the runtime's own records.
    recorded = sorted({stage for stage, _ in statuses} | set(run.marked_stages()))
    states += [_recorded_state(run, name, statuses) for name in recorded
               if name not in JOB_STAGES and not name.startswith("_")]
    return RunState(states, damaged_parts(run, "status"))


def stage_states(run: RunFolder) -> list[StageState]:
    """The state of every stage of `run` (see `run_state`)."""
    return run_state(run).stages


def _recorded_state(run: RunFolder, stage: str, statuses: dict[tuple[str, str], UnitOutcome]) -> StageState:
    markers = run.markers(stage)
    state = StageState(stage, damaged=run.damage(markers))
    state.done = sorted(set(markers) - set(state.damaged))
    state.failed = [o for (name, unit), o in sorted(statuses.items())
                    if name == stage and o.failed and unit not in markers]
    return state


def _state(run: RunFolder, stage: Stage, statuses: dict[tuple[str, str], UnitOutcome]) -> StageState:
    state = StageState(stage.name)
    try:
        plan = plan_stage(stage, run)
    except StageOrderError:
        state.waiting_for = "waiting for " + ", ".join(stage.after)
        return state
    except ConfigError as error:  # e.g. a split of the scenes left after damage: show what was recorded
        state = _recorded_state(run, stage.name, statuses)
        state.unlisted = str(error)
        return state
    markers = run.markers(stage.name)
    state.done = sorted(plan.up_to_date)
    for unit in plan.to_run:
        outcome = statuses.get((stage.name, unit.id))
        if unit.id in plan.damaged and markers[unit.id].config_hash == stage.unit_hash(unit):
            state.damaged[unit.id] = plan.damaged[unit.id]
        elif outcome is not None and outcome.failed:
            state.failed.append(outcome)
        elif unit.id in markers:
            state.stale.append(unit.id)
        else:
            state.pending.append(unit.id)
    return state
