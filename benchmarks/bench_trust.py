"""What the trust checks of issue 20 cost (not a test): marker path checks and the commit fence.

Figures (each `--repeats` times, interleaved with their peer so the machine's load falls on both alike;
median and spread):
  marker_checks  loading one stage of `--units` (18,000 = MVPd's videos) markers of 39 files each (a full-scale
                 render marker) as `mvpd status` does, from the stage's marker index and from the marker files
                 alone, with the path checks (`markers.marker_problem`, the index's column-wise match) against
                 the same load with the checks switched off (the peer)
  commit_fence   committing `--commits` one-file units on local disk under the run lock, with the fence (two
                 reads of the lock file per commit) against the same commits without it (the peer)
  link_checks    issue 29: what closing the run folder to links costs (wall and CPU seconds: on a loaded machine the
                 CPU time of the process is the steadier figure), this tree against `--against` (b5d67c7,
                 checked out as a git worktree): loading a stage of `--link-units` markers of 39 files (from
                 the index, and from the marker files), `status`'s check of every file (an lstat each and one
                 per folder, against a stat each), and a commit of a one-file unit under the lock. Each
                 repetition runs both trees as child processes (`--child TREE`), alternating, on the same run
                 folder, so the load of the machine falls on both alike; a child keeps the least of 3 tries of
                 each read figure, the figure is the median over the children

    .venv/bin/python benchmarks/bench_trust.py [--units 18000] [--commits 300] [--repeats 3]
    .venv/bin/python benchmarks/bench_trust.py --figures link_checks [--link-units 4000] [--against b5d67c7]

Writes benchmarks/results/trust.json. The machine is shared (the load average is recorded): compare ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

REPO = Path(__file__).resolve().parents[1]
# `--child TREE`: measure the code of another tree (an old commit's worktree) with this script.
CHILD_TREE = sys.argv[sys.argv.index("--child") + 1] if "--child" in sys.argv else None
sys.path.insert(0, CHILD_TREE or str(REPO))

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


# ----------------------------------------------------------------------------------- link checks
ZARR_ARRAYS = ("rgb", "depth", "panoptic")  # a render store's arrays, each chunked as <array>/c/<t>/0/0


def build_files(root: Path, units: int) -> RunFolder:
    """A run whose stage has `units` markers of 39 files each, every file on disk: a store of 36 files in ~80
    folders shaped as render writes it (arrays rgb, depth, panoptic, 64-frame shards) and 3 Parquet parts
    (what `status` stats), and the stage's index."""
    run = RunFolder.create(root, job())
    for index in range(units):
        video = f"e.scene-{index // 100:05d}.{index % 100:010d}.0000001000"
        store = f"videos/e/{video}.zarr"
        names = [f"{store}/zarr.json", *(f"{store}/{a}/zarr.json" for a in ZARR_ARRAYS)]
        # As render writes them: rgb/c/<t>/0/0/0, depth and panoptic /c/<t>/0/0, one shard per 64 frames.
        names += [f"{store}/{a}/c/{t}/0/0" + ("/0" if a == "rgb" else "") for t in range(11) for a in ZARR_ARRAYS]
        names = names[:FILES_PER_MARKER - 3]
        parts = [f"{dataset}/part-{video}.parquet" for dataset in ("videos", "segments", "frame_stats")]
        files = []
        for number, relative in enumerate(names + parts):
            path = root / relative
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"x" * (number + 1))
            files.append(OutputFile(relative, number + 1, "0badf00d"))
        run.write_marker(Marker(STAGE, video, "hash", code_version(), [store, *parts], {"videos": 1}, 1.0, 1,
                                "bench", float(index), {}, sorted(files, key=lambda f: f.path)))
    run.index_markers(STAGE)
    return run


def timed_both(found: dict[str, float], name: str, action: Callable[[], object], per: int = 1,
               tries: int = 1) -> None:
    """Wall and CPU seconds (this process: user + system, so the syscalls count and other processes' load
    does not) of `action`, divided by `per`, the least of `tries`, into `found` as `<name>_s` and `<name>_cpu_s`."""
    for _ in range(tries):
        wall, cpu = time.perf_counter(), time.process_time()
        action()
        wall, cpu = (time.perf_counter() - wall) / per, (time.process_time() - cpu) / per
        found[f"{name}_s"] = min(found.get(f"{name}_s", wall), wall)
        found[f"{name}_cpu_s"] = min(found.get(f"{name}_cpu_s", cpu), cpu)


def child_figures(folder: Path, commits: int) -> dict[str, float]:
    """One repetition of the link-check figures with the code this process imported (seconds)."""
    run = RunFolder.open(folder)
    index = run.root / "_state" / STAGE / INDEX_NAME
    saved_index = index.read_bytes()
    found: dict[str, float] = {}
    timed_both(found, "markers_index", lambda: run.markers(STAGE), tries=3)
    index.unlink()
    marker_index.REFRESH_AFTER = 10**9  # read every marker file, write no index
    try:
        timed_both(found, "markers_files", lambda: run.markers(STAGE), tries=3)
    finally:
        index.write_bytes(saved_index)
    loaded = run.markers(STAGE)
    damage: dict[str, Any] = {}
    timed_both(found, "status", lambda: damage.update(run.damage(loaded)), tries=3)
    assert not damage, next(iter(damage.values()))
    with tempfile.TemporaryDirectory(prefix="bench-commit-", dir=folder.parent) as scratch:
        fenced = RunFolder.create(Path(scratch) / "run", job())
        with fenced.locked():
            def commit_all() -> None:
                for number in range(commits):
                    staging = fenced.staging("commit", f"u{number}")
                    (staging / "commit").mkdir()
                    (staging / "commit" / f"part-u{number}.bin").write_bytes(b"x" * 64)
                    fenced.commit_unit("commit", f"u{number}", staging, "", {}, 0.0, 1, time.time(), socket.gethostname())
            timed_both(found, "commit", commit_all, commits)
    return found


def link_checks(units: int, commits: int, repeats: int, against: str, workdir: Path) -> dict[str, Any]:
    """This tree against `against` (a git worktree made here), alternating child processes on one run."""
    old_tree = workdir / "old-tree"
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(old_tree), against], check=True,
                   capture_output=True)
    try:
        run_folder = workdir / "links-run"
        build_files(run_folder, units)
        times: dict[str, dict[str, list[float]]] = {"new": {}, "old": {}}
        for repeat in range(repeats):
            pair = (("old", old_tree), ("new", REPO))
            for side, tree in pair[::-1] if repeat % 2 else pair:  # each side first in every other repetition
                output = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", str(tree),
                                         "--child-run", str(run_folder), "--commits", str(commits)],
                                        check=True, capture_output=True, text=True).stdout
                for key, value in json.loads(output.splitlines()[-1]).items():
                    times[side].setdefault(key, []).append(value)
    finally:
        subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(old_tree)], capture_output=True)
    result: dict[str, Any] = {"units": units, "files_per_marker": FILES_PER_MARKER, "commits": commits,
                              "against": against}
    for key in times["new"]:
        result[key] = {"new": summary(times["new"][key]), "old": summary(times["old"][key]),
                       "ratio": round(statistics.median(times["new"][key]) / statistics.median(times["old"][key]), 3)}
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=18_000)
    parser.add_argument("--commits", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--link-units", type=int, default=4_000)
    parser.add_argument("--against", default="b5d67c7", help="link_checks: the commit to compare with")
    parser.add_argument("--figures", default="marker_checks,commit_fence,link_checks")
    parser.add_argument("--child", help="internal: measure the code of this tree once, print JSON")
    parser.add_argument("--child-run", help="internal: the run folder the child measures")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child_figures(Path(args.child_run), args.commits)))
        return
    results: dict[str, Any] = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    results["machine"] = {"cpus": os.cpu_count(), "python": sys.version.split()[0]}
    with tempfile.TemporaryDirectory(prefix="bench-trust-") as scratch:
        figures = {"marker_checks": lambda: marker_checks(args.units, args.repeats, Path(scratch)),
                   "commit_fence": lambda: commit_fence(args.commits, args.repeats, Path(scratch)),
                   "link_checks": lambda: link_checks(args.link_units, args.commits, args.repeats, args.against,
                                                      Path(scratch))}
        for name in args.figures.split(","):
            load_before = os.getloadavg()[0]
            results[name] = figures[name]()
            results[name]["load_average_1m"] = [round(load_before, 2), round(os.getloadavg()[0], 2)]
            print(name, json.dumps(results[name], indent=1), flush=True)
            RESULTS.write_text(json.dumps(results, indent=1) + "\n")  # before the scratch folder's slow removal
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
