"""`mvpd status --verify`: re-read every committed file and compare it with its marker's checksum.

Damage found is recorded next to the unit's marker (`record_damage`), so `mvpd status` keeps showing the
unit as damaged and `mvpd rerun` runs it again; a unit that passes loses an earlier note. Files are read
by a few threads in this process, or by Ray tasks (batches of about `BATCH_BYTES`) when the run is big
or Ray is asked for: reading is the limit, so on one machine threads are as fast as processes.
"""

from __future__ import annotations

import logging
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

from pipeline.runtime.executors import ExecutorName, ray_is_running
from pipeline.runtime.markers import Damage, Marker, check_files, clear_damage, marked_stages, record_damage, stage_markers
from pipeline.runtime.object_store import storage_environment, use_storage_environment
from pipeline.runtime.run_folder import RunFolder
from pipeline.runtime.store_markers import update_damage

log = logging.getLogger(__name__)

BATCH_BYTES = 512 * 2**20
# auto: Ray pays for itself only when there is much to read (several nodes reading a shared store).
RAY_FROM_BYTES = 64 * 2**30

ProgressBytes = Callable[[int], None]


def run_markers(run: RunFolder) -> list[Marker]:
    """Every valid marker of the run, the status table's included, in (stage, unit) order."""
    return [marker for stage in marked_stages(run.root) for _, marker in sorted(stage_markers(run.root, stage).items())]


def verify_run(run: RunFolder, executor: ExecutorName = "auto", address: str | None = None,
               on_start: Callable[[int], None] | None = None,
               on_progress: ProgressBytes | None = None) -> dict[tuple[str, str], list[Damage]]:
    """(stage, unit) -> damage, for every unit whose files are not as its marker says (checksums read)."""
    markers = run_markers(run)
    total = sum(f.size for m in markers for f in m.files)
    if on_start is not None:
        on_start(total)
    progress = on_progress or (lambda done: None)
    use_ray = executor == "ray" or (executor == "auto" and (address or ray_is_running() or total >= RAY_FROM_BYTES))
    found = _verify_on_ray(run, markers, address, progress) if use_ray else _verify_inline(run, markers, progress)
    damaged = {(m.stage, m.unit): problems for m, problems in zip(markers, found) if problems}
    if run.store is not None:  # one read and one write of each stage's damage notes
        for stage in sorted({m.stage for m in markers}):
            checked = [(m, problems) for m, problems in zip(markers, found) if m.stage == stage]
            update_damage(run.store, stage, [(m, p) for m, p in checked if p], [m.unit for m, p in checked if not p])
        return damaged
    for marker, problems in zip(markers, found):
        if problems:
            record_damage(run.root, marker, problems)
        else:
            _forget_damage(run, marker)
    return damaged


def _forget_damage(run: RunFolder, marker: Marker) -> None:
    """Drop an earlier damage note of a unit that passed; a read-only run folder keeps it (with a warning)
    and the verify still answers: `status` then shows the old note until a writable verify clears it."""
    try:
        clear_damage(run.root, marker.stage, marker.unit)
    except OSError as error:
        log.warning("cannot clear the damage note of %s/%s: %s", marker.stage, marker.unit, error)


def _check(marker: Marker, root: str) -> list[Damage]:
    return check_files(marker, Path(root), verify=True, recorded=False)


def _verify_inline(run: RunFolder, markers: list[Marker], progress: ProgressBytes) -> list[list[Damage]]:
    with ThreadPoolExecutor(max_workers=min(8, os.cpu_count() or 1)) as pool:
        futures = [pool.submit(_check, marker, str(run.root)) for marker in markers]
        results = []
        for marker, future in zip(markers, futures):
            results.append(future.result())
            progress(sum(f.size for f in marker.files))
    return results


def _check_batch(environment: dict[str, str], markers: list[Marker], root: str) -> list[list[Damage]]:
    use_storage_environment(environment)  # a remote run's credentials: a task argument, never a runtime_env
    return [_check(marker, root) for marker in markers]


def _verify_on_ray(run: RunFolder, markers: list[Marker], address: str | None,
                   progress: ProgressBytes) -> list[list[Damage]]:
    import ray

    from pipeline.runtime.ray_session import ensure_ray

    ensure_ray(address)
    batches: list[list[int]] = [[]]
    size = 0
    for index, marker in enumerate(markers):
        if size >= BATCH_BYTES:
            batches.append([])
            size = 0
        batches[-1].append(index)
        size += sum(f.size for f in marker.files)
    task = ray.remote(_check_batch).options(num_cpus=1, name="mvpd.verify")
    # A task is handed the run's location: a node of a cluster reads a remote run from its store.
    environment = storage_environment(run.store.url if run.store else None)
    refs = {task.remote(environment, [markers[i] for i in batch], run.location): batch for batch in batches if batch}
    results: list[list[Damage]] = [[] for _ in markers]
    pending = list(refs)
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        batch = refs[ready[0]]
        for index, problems in zip(batch, ray.get(ready[0])):
            results[index] = problems
        progress(sum(f.size for i in batch for f in markers[i].files))
    return results
