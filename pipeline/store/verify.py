"""`mvpd status --verify`: re-read every committed file and compare it with its marker's checksum.

Damage found is recorded with the unit's marker (`RunFolder.record_damage`), so `mvpd status` keeps showing
the unit as damaged and `mvpd rerun` runs it again; a unit that passes loses an earlier note. Files are
read by a few threads in this process (`check_here`), or in batches by other processes (the runtime hands
batches to Ray when the run is big): reading is the limit, so on one machine threads are as fast as
processes.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

from pipeline.store.markers import Damage, Marker
from pipeline.store.run_folder import RunFolder

ProgressBytes = Callable[[int], None]


def run_markers(run: RunFolder) -> list[Marker]:
    """Every valid marker of the run, the status table's included, in (stage, unit) order."""
    return [marker for stage in run.marked_stages() for _, marker in sorted(run.markers(stage).items())]


def check_batch(run: RunFolder, markers: list[Marker]) -> list[list[Damage]]:
    """Each marker's files read against their checksums (recorded notes aside)."""
    return [run.check_files(marker, verify=True, recorded=False) for marker in markers]


def check_here(run: RunFolder, markers: list[Marker], progress: ProgressBytes) -> list[list[Damage]]:
    """`check_batch` by a few threads of this process, saying each marker's bytes to `progress` when read."""
    with ThreadPoolExecutor(max_workers=min(8, os.cpu_count() or 1)) as pool:
        futures = [pool.submit(check_batch, run, [marker]) for marker in markers]
        results = []
        for marker, future in zip(markers, futures):
            results.append(future.result()[0])
            progress(sum(f.size for f in marker.files))
    return results


def record_verification(run: RunFolder, markers: list[Marker],
                        found: list[list[Damage]]) -> dict[tuple[str, str], list[Damage]]:
    """Note the damage found and forget the notes of units found intact (one update per stage);
    (stage, unit) -> damage of the damaged units."""
    for stage in sorted({m.stage for m in markers}):
        checked = [(m, problems) for m, problems in zip(markers, found) if m.stage == stage]
        run.record_damage(stage, [(m, p) for m, p in checked if p], [m.unit for m, p in checked if not p])
    return {(m.stage, m.unit): problems for m, problems in zip(markers, found) if problems}
