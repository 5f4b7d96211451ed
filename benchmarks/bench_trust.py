"""What the trust checks of issue 20 cost (not a test): marker path checks and the commit fence.

Figures (each `--repeats` times, interleaved with their peer so the machine's load falls on both alike;
median and spread):
  marker_checks  loading one stage of `--units` (18,000 = MVPd's videos) markers of 39 files each (a full-scale
                 render marker) as `mvpd status` does, from the stage's marker index and from the marker files
                 alone, with the path checks (`markers.marker_problem`, the index's column-wise match) against
                 the same load with the checks switched off (the peer)
  commit_fence   committing `--commits` one-file units on local disk under the run lock, with the fence (two
                 reads of the lock file per commit) against the same commits without it (the peer)

    .venv/bin/python benchmarks/bench_trust.py [--units 18000] [--commits 300] [--repeats 3]

Writes benchmarks/results/trust.json. The machine is shared (the load average is recorded): compare ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import statistics
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources  # noqa: E402
from pipeline.store import marker_index, markers  # noqa: E402
from pipeline.store.marker_index import INDEX_NAME
from pipeline.store.markers import Marker, OutputFile, code_version
from pipeline.store.run_folder import RunFolder  # noqa: E402

RESULTS = REPO / "benchmarks" / "results" / "trust.json"
STAGE = "render"
FILES_PER_MARKER = 39  # benchmarks/bench_scaling.py: FULL_SCALE_MARKER_FILES with 64-frame shards


def summary(values: list[float]) -> dict[str, Any]:
    return {"median": round(statistics.median(values), 4), "min": round(min(values), 4),
            "max": round(max(values), 4), "runs": len(values)}


def timed(action: Callable[[], object]) -> float:
    began = time.perf_counter()
    action()
    return time.perf_counter() - began


@contextmanager
def checks_off() -> Iterator[None]:
    """The peer: the same code with the path checks answering "fine" at once."""
    saved = markers.marker_problem, marker_index.marker_problem, marker_index._rows_with_bad_paths
    markers.marker_problem = marker_index.marker_problem = lambda *args: None
    marker_index._rows_with_bad_paths = lambda *args: set()
    try:
        yield
    finally:
        markers.marker_problem, marker_index.marker_problem, marker_index._rows_with_bad_paths = saved


def job() -> Job:
    return Job(name="bench", scenes=SceneSources(procedural=ProceduralSource(count=1)), embodiments=[Embodiment(name="e")])


def build_markers(root: Path, units: int) -> RunFolder:
    """A run whose stage has `units` markers shaped like full-scale render markers (a Zarr store of 36 files
    and 3 Parquet parts each), and the stage's index; the files themselves are not needed to load markers."""
    run = RunFolder.create(root, job())
    for index in range(units):
        video = f"e.scene-{index // 100:05d}.{index % 100:010d}.0000001000"
        store = f"videos/e/{video}.zarr"
        parts = [f"{dataset}/part-{video}.parquet" for dataset in ("videos", "segments", "frame_stats")]
        files = [OutputFile(f"{store}/rgb/c/{number}", 100_000 + number, f"{number:08x}")
                 for number in range(FILES_PER_MARKER - len(parts))]
        files += [OutputFile(path, 4_000, "0badf00d") for path in parts]
        run.write_marker(Marker(STAGE, video, "hash", code_version(), [store, *parts], {"videos": 1}, 1.0, 1,
                                      "bench", float(index), {}, sorted(files, key=lambda f: f.path)))
    run.index_markers(STAGE)
    return run


def marker_checks(units: int, repeats: int, workdir: Path) -> dict[str, Any]:
    run = build_markers(workdir / "markers", units)
    index = run.root / "_state" / STAGE / INDEX_NAME
    saved_index = index.read_bytes()
    load = lambda: run.markers(STAGE)  # noqa: E731
    times: dict[str, list[float]] = {"index": [], "index_peer": [], "files": [], "files_peer": []}
    for _ in range(repeats):
        times["index"].append(timed(load))
        with checks_off():
            times["index_peer"].append(timed(load))
        for name, off in (("files", False), ("files_peer", True)):
            index.unlink()
            marker_index.REFRESH_AFTER, refresh = 10**9, marker_index.REFRESH_AFTER  # read every file, write no index
            try:
                if off:
                    with checks_off():
                        times[name].append(timed(load))
                else:
                    times[name].append(timed(load))
            finally:
                marker_index.REFRESH_AFTER = refresh
            index.write_bytes(saved_index)
    assert len(load()) == units
    result = {"units": units, "files_per_marker": FILES_PER_MARKER, **{f"{k}_s": summary(v) for k, v in times.items()}}
    for source in ("index", "files"):
        result[f"{source}_ratio"] = round(statistics.median(times[source]) / statistics.median(times[f"{source}_peer"]), 3)
    return result


def commit_fence(commits: int, repeats: int, workdir: Path) -> dict[str, Any]:
    run = RunFolder.create(workdir / "fence", job())
    times: dict[str, list[float]] = {"fenced": [], "unfenced": []}

    def commit_all(tag: str) -> None:
        for number in range(commits):
            staging = run.staging("fence", f"{tag}-{number}")
            (staging / "fence").mkdir()
            (staging / "fence" / f"part-{tag}-{number}.bin").write_bytes(b"x" * 64)
            run.commit_unit("fence", f"{tag}-{number}", staging, "", {}, 0.0, 1, time.time(), socket.gethostname())

    with run.locked():
        fence = run.fence
        for repeat in range(repeats):
            run.fence = fence
            times["fenced"].append(timed(lambda: commit_all(f"f{repeat}")) / commits)
            run.fence, run.lease, lease = "", None, run.lease
            times["unfenced"].append(timed(lambda: commit_all(f"u{repeat}")) / commits)
            run.lease = lease
    shutil.rmtree(run.root)
    return {"commits": commits, "seconds_per_commit_fenced": summary(times["fenced"]),
            "seconds_per_commit_unfenced": summary(times["unfenced"]),
            "ratio": round(statistics.median(times["fenced"]) / statistics.median(times["unfenced"]), 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=18_000)
    parser.add_argument("--commits", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    results: dict[str, Any] = {"machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]}}
    with tempfile.TemporaryDirectory(prefix="bench-trust-") as scratch:
        for name, figure in (("marker_checks", lambda: marker_checks(args.units, args.repeats, Path(scratch))),
                             ("commit_fence", lambda: commit_fence(args.commits, args.repeats, Path(scratch)))):
            load_before = os.getloadavg()[0]
            results[name] = figure()
            results[name]["load_average_1m"] = [round(load_before, 2), round(os.getloadavg()[0], 2)]
            print(name, json.dumps(results[name], indent=1), flush=True)
    RESULTS.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
