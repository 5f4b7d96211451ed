"""Where `mvpd status --verify` reads: threads of this process, or Ray tasks (batches of about
`BATCH_BYTES`) when the run is big or Ray is asked for (`pipeline.store.verify` does the reading)."""

from __future__ import annotations

from typing import Callable

from pipeline.runtime.executors import ExecutorName, ray_is_running
from pipeline.store.markers import Damage, Marker
from pipeline.store.remote import storage_environment, use_storage_environment
from pipeline.store.run_folder import RunAddress, RunFolder
from pipeline.store.verify import ProgressBytes, check_batch, check_here, record_verification, run_markers

BATCH_BYTES = 512 * 2**20
# auto: Ray pays for itself only when there is much to read (several nodes reading a shared store).
RAY_FROM_BYTES = 64 * 2**30


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
    found = _verify_on_ray(run, markers, address, progress) if use_ray else check_here(run, markers, progress)
    return record_verification(run, markers, found)


def _check_batch(environment: dict[str, str], markers: list[Marker], run: RunAddress) -> list[list[Damage]]:
    use_storage_environment(environment)  # a remote run's credentials: a task argument, never a runtime_env
    return check_batch(run.open(), markers)


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
    # A task is handed the run's address: a node of a cluster reads a remote run from its store.
    environment = storage_environment(run.store.url if run.store else None)
    refs = {task.remote(environment, [markers[i] for i in batch], run.address()): batch for batch in batches if batch}
    results: list[list[Damage]] = [[] for _ in markers]
    pending = list(refs)
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        batch = refs[ready[0]]
        for index, problems in zip(batch, ray.get(ready[0])):
            results[index] = problems
        progress(sum(f.size for i in batch for f in markers[i].files))
    return results
