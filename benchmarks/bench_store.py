"""The run folder as one object (issue 22): the code before and after it, side by side in one run.

    git worktree add /tmp/before 945c5ba          # the last commit before pipeline/store/
    .venv/bin/python benchmarks/bench_store.py --before /tmp/before [--repeats 5]

Both trees run with this venv (each first on PYTHONPATH; `python -P`, so the working folder never wins),
so only the code differs:
  walk      one `mvpd submit` of a small job (1 generated house, 2 videos; units in-process so the units'
            own trip is counted too), traced with sys.setprofile: every call of a function of the package
            that is handed the run (a RunFolder, a RunStore, a store backend or marker folder, or the run's
            path or URL as a str or Path) is a step; its room is the module the function lives in.
            Counted: steps, rooms (modules) visited, rooms entered (a step into another module than the
            step before), revisits (an entry into a module the walk had already been in, however it got
            there), returns (a step into a module that is already further down the same call
            chain, below another module: a circle walked at run time, such as markers -> marker_index ->
            markers), and resolutions (the run's location turned into a store or folder again:
            `store_of`, `run_root`, `as_run`, `RunFolder.__init__`).
  bytes     the demo job submitted by each tree into its own folder: every output file compared (markers,
            logs and the status table hold times and code versions; `videos` and `frame_stats` parts
            hold render times, compared without that column)
  circles   the import circles of each tree's package (tests/runtime/test_layers.py's AST check)
  speed     `mvpd status`, `mvpd query` (one count) and `mvpd submit` of the same job (nothing to do) on
            the demo run, whole commands, before and after alternating (the order swapped every round);
            median and spread of --repeats, wall and CPU seconds; and what does not drift with the load:
            the Python calls status and query make (cProfile's count) and the self time of importing
            the modules these commands load (`-X importtime`, median of --repeats)

Writes benchmarks/results/store.json.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "store.json"
PYTHON = sys.executable
TIMED = "render_seconds"  # the one column of the data tables that holds a wall time (videos, frame_stats)
SMALL_JOB = """name: walk
seed: 0
scenes:
  procedural: {count: 1, seed: 0, detail: 0.1}
embodiments:
  - name: ambient
    sensor: {width: 64, height: 48, hfov: 69.0}
    placements: [1.0]
    body: {radius: 0.15, height: 1.2}
plan: {trajectories_per_scene: 2, min_frames: 8, max_frames: 12}
"""
# Runs in the tree under test: submit the job with a profiler that follows the run through the package.
TRACER = r"""
import json, os, sys
from pathlib import Path
job, run_dir = sys.argv[1], sys.argv[2]
root = str(Path(run_dir).resolve())
package = str(Path(__import__("pipeline").__file__).resolve().parent)
RUN_TYPES = ("RunFolder", "RunStore", "LocalFiles", "StoreFiles", "LocalMarkerFolder", "FsspecMarkerFolder")
RESOLVERS = {"store_of", "run_root", "as_run"}
steps, resolutions, returns = [], 0, 0
circles = __import__('collections').Counter()

def carries_run(value):
    if type(value).__name__ in RUN_TYPES:
        return True
    return isinstance(value, (str, os.PathLike)) and str(value) == root

def module_of(code):
    return Path(code.co_filename).relative_to(package).with_suffix("").as_posix()

def chain(frame):
    # The package modules on the stack below `frame`, consecutive repeats collapsed.
    found = []
    frame = frame.f_back
    while frame is not None:
        if frame.f_code.co_filename.startswith(package):
            module = module_of(frame.f_code)
            if not found or found[-1] != module:
                found.append(module)
        frame = frame.f_back
    return found

def profile(frame, event, arg):
    global resolutions, returns
    if event != "call":
        return
    code = frame.f_code
    if not code.co_filename.startswith(package):
        return
    arguments = code.co_varnames[:code.co_argcount + code.co_kwonlyargcount]
    values = [frame.f_locals.get(name) for name in arguments]
    if code.co_name in RESOLVERS or (code.co_name == "__init__" and type(values[0]).__name__ == "RunFolder"):
        resolutions += 1
    if any(carries_run(v) for v in values):
        module = module_of(code)
        below = chain(frame)
        # A return: the call comes back into a module that is further down this very call chain, having
        # gone through another one (markers -> marker_index -> markers): a circle walked at run time.
        if module in below[1:] or (below and below[0] != module and module in below):
            returns += 1
            circles[" -> ".join([*reversed(below[:below.index(module) + 1]), module])] += 1
        steps.append(module)

from pipeline.cli.main import app
sys.setprofile(profile)
try:
    app(["submit", job, "--run-dir", run_dir, "--executor", "local"], standalone_mode=False)
finally:
    sys.setprofile(None)
entered = [module for index, module in enumerate(steps) if index == 0 or steps[index - 1] != module]
revisits = sum(module in entered[:index] for index, module in enumerate(entered))
print(json.dumps({"steps": len(steps), "rooms": len(set(steps)), "entered": len(entered), "revisits": revisits,
                  "returns": returns,
                  "resolutions": resolutions, "circles": dict(circles.most_common()), "walk": entered[:60]}))
"""


def in_tree(tree: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(tree), "RAY_ADDRESS": ""}


# Runs in the tree under test: the Python calls one command makes (deterministic, unlike its seconds).
COUNTER = r"""
import cProfile, pstats, sys
from pipeline.cli.main import app
profile = cProfile.Profile()
profile.enable()
try:
    app(sys.argv[1:], standalone_mode=False)
except SystemExit:
    pass
profile.disable()
print(pstats.Stats(profile).total_calls)
"""
IMPORTS = "import pipeline.cli.main, pipeline.cli.run_commands, pipeline.io.query, pipeline.runtime.inspect"


def calls(tree: Path, *args: str) -> int:
    done = subprocess.run([PYTHON, "-P", "-c", COUNTER, *args], env=in_tree(tree), cwd=tree, check=True,
                          capture_output=True, text=True)
    return int(done.stdout.strip().splitlines()[-1])


def import_seconds(tree: Path) -> float:
    """Seconds the modules of these commands take to import (`python -X importtime`, self times summed)."""
    done = subprocess.run([PYTHON, "-P", "-X", "importtime", "-c", IMPORTS], env=in_tree(tree), cwd=tree, check=True,
                          capture_output=True, text=True)
    rows = [line.split("|")[0].split(":")[-1] for line in done.stderr.splitlines()[1:] if "|" in line]
    return sum(int(row) for row in rows) / 1e6


def walk(tree: Path, folder: Path) -> dict:
    job = folder / "walk.yaml"
    job.write_text(SMALL_JOB)
    done = subprocess.run([PYTHON, "-P", "-c", TRACER, str(job), str(folder / "run")], env=in_tree(tree), cwd=tree,
                          check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


CPU_SECONDS: list[float] = []  # of each command, in order (the machine is shared: CPU time drifts less than wall)
CRASHES: list[str] = []  # commands that died of a signal (timed again; listed in the results)


def mvpd(tree: Path, *args: str) -> float:
    """Seconds one whole `mvpd` command takes with the code of `tree` (its CPU seconds go to CPU_SECONDS)."""
    for _ in range(3):
        used = resource.getrusage(resource.RUSAGE_CHILDREN)
        started = time.perf_counter()
        # In the tree's folder: Ray puts the driver's working folder on its workers' path.
        done = subprocess.run([PYTHON, "-P", "-c", "from pipeline.cli.main import app; app()", *args], env=in_tree(tree),
                              cwd=tree, capture_output=True, text=True)
        seconds = time.perf_counter() - started
        now = resource.getrusage(resource.RUSAGE_CHILDREN)
        CPU_SECONDS.append(now.ru_utime + now.ru_stime - used.ru_utime - used.ru_stime)
        if done.returncode >= 0:
            break
        CRASHES.append(f"{tree.name}: mvpd {' '.join(args[:1])} died of signal {-done.returncode}: {done.stderr[-300:]}")
    if done.returncode != 0:
        raise RuntimeError(f"mvpd {' '.join(args)} exited {done.returncode}: {done.stdout[-500:]} {done.stderr[-500:]}")
    return seconds


def digests(run: Path) -> dict[str, str]:
    """Path -> SHA-256 of every output file (a Parquet part with render times: of its rows without them)."""
    import pyarrow.parquet as pq

    found = {}
    for path in sorted(p for p in run.rglob("*") if p.is_file()):
        relative = path.relative_to(run).as_posix()
        if relative.split("/")[0] in ("_state", "logs", "status", "previews"):
            continue
        if path.suffix == ".parquet" and TIMED in pq.read_schema(path).names:
            table = pq.read_table(path).drop_columns([TIMED])
            found[relative] = hashlib.sha256(str(table.to_pylist()).encode()).hexdigest()
        else:
            found[relative] = hashlib.sha256(path.read_bytes()).hexdigest()
    return found


def spread(values: list[float]) -> dict:
    return {"median_s": round(statistics.median(values), 3), "min_s": round(min(values), 3),
            "max_s": round(max(values), 3), "runs": [round(v, 3) for v in values]}


def paired(times: dict[str, list[float]]) -> float:
    """Median of after/before within each round (the two ran back to back, so a drift of the load between
    rounds cancels out)."""
    return round(statistics.median(a / b for a, b in zip(times["after"], times["before"])), 3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", type=Path, required=True, help="a checkout of the code before pipeline/store/")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--demo-repeats", type=int, default=2, help="fresh demo-job runs per tree")
    args = parser.parse_args()
    trees = {"before": args.before.resolve(), "after": REPO}
    sys.path.insert(0, str(REPO))
    from tests.runtime.test_layers import circles, module_graph

    result: dict = {"import_circles": {name: circles(module_graph(tree / "pipeline")) for name, tree in trees.items()}}
    print("import circles:", result["import_circles"], flush=True)
    result["before_commit"] = subprocess.run(["git", "-C", str(trees["before"]), "rev-parse", "HEAD"],
                                             capture_output=True, text=True).stdout.strip()
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        result["walk"] = {}
        for name, tree in trees.items():
            (folder / name).mkdir()
            result["walk"][name] = walk(tree, folder / name)
            print(name, "walk:", {k: v for k, v in result["walk"][name].items() if k not in ("walk", "circles")},
                  result["walk"][name]["circles"], flush=True)
        demo = REPO / "jobs" / "demo.yaml"
        runs, demo_times = {}, {"before": [], "after": []}
        for repeat in range(args.demo_repeats):  # before, after, then after, before: a load drift hits both
            for name in (("before", "after") if repeat % 2 == 0 else ("after", "before")):
                target = runs.setdefault(name, folder / f"demo-{name}") if repeat == 0 else folder / f"{name}-{repeat}"
                demo_times[name].append(mvpd(trees[name], "submit", str(demo), "--run-dir", str(target)))
                print(f"{name}: demo job in {demo_times[name][-1]:.0f} s", flush=True)
        result["demo_job"] = {name: spread(values) for name, values in demo_times.items()}
        before, after = digests(runs["before"]), digests(runs["after"])
        differing = sorted(p for p in before.keys() | after.keys() if before.get(p) != after.get(p))
        result["bytes"] = {"files_compared": len(before), "differing": differing, "identical": not differing}
        print("bytes:", "identical" if not differing else f"{len(differing)} files differ, e.g. {differing[:3]}")
        commands = {"status": ["status", str(runs["before"])],
                    "query": ["query", str(runs["before"]), "select count(*) from videos"],
                    "submit_noop": ["submit", str(demo), "--run-dir", str(runs["before"])]}
        times = {c: {"before": [], "after": []} for c in commands}
        cpu = {c: {"before": [], "after": []} for c in commands}
        for repeat in range(args.repeats):
            for command, arguments in commands.items():
                for name in (("before", "after") if repeat % 2 == 0 else ("after", "before")):
                    times[command][name].append(mvpd(trees[name], *arguments))
                    cpu[command][name].append(CPU_SECONDS[-1])
        result["calls"] = {command: {name: calls(tree, *arguments) for name, tree in trees.items()}
                           for command, arguments in commands.items() if command != "submit_noop"}
        print("python calls:", result["calls"], flush=True)
        imports = {name: [] for name in trees}
        for _ in range(args.repeats):
            for name, tree in trees.items():
                imports[name].append(import_seconds(tree))
        result["import_seconds"] = {name: spread(values) for name, values in imports.items()}
        print("imports:", {name: round(statistics.median(v), 3) for name, v in imports.items()}, flush=True)
        result["speed"] = {}
        for command in commands:
            wall, used = times[command], cpu[command]
            ratio = statistics.median(wall["after"]) / statistics.median(wall["before"])
            cpu_ratio = statistics.median(used["after"]) / statistics.median(used["before"])
            result["speed"][command] = {"before": spread(wall["before"]), "after": spread(wall["after"]),
                                        "after_over_before": round(ratio, 3), "paired": paired(wall),
                                        "cpu_before": spread(used["before"]),
                                        "cpu_after": spread(used["after"]), "cpu_after_over_before": round(cpu_ratio, 3)}
            print(f"{command}: before {statistics.median(wall['before']):.2f} s, after "
                  f"{statistics.median(wall['after']):.2f} s (after/before {ratio:.2f}, paired by round "
                  f"{paired(wall):.2f}; CPU {cpu_ratio:.2f})", flush=True)
    result["crashes"] = CRASHES
    RESULTS.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
