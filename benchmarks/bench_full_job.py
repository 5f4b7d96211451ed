"""The full-dataset job at 1 % of MVPd, end to end, as a user runs it (not a test): jobs/mvpd-1pct.yaml.

Every step is one `mvpd` command in its own process, under `nice -n 19` (the machine is shared: Ray's
workers inherit the niceness, so the run soaks up idle CPU without slowing anyone), in this order:
  shard, plan, render, screen, split   `mvpd submit JOB --stages <stage> --executor ray` (one stage each, so
                                       each stage's CPU time is its own)
  status, query                        latency on the finished run (`--repeats` times: median and spread)
  stats, report, evaluate, predict,    `report --models geometric` predicts the test split and scores it;
  export, view                         `evaluate` re-scores those predictions (`--all`); `predict` into the
                                       same folder finds them done; the MVPd export; `view` of one video
Per step: wall seconds, CPU seconds of the command's whole process tree (the driver, Ray's raylet and GCS,
every worker: sampled every 0.5 s while they live, since an exiting worker takes its time along), peak RSS
of the driver and of the largest worker, and the 1-minute load average before and after. CPU time is the
primary cost figure; wall times were measured on a machine shared with other work.

Then: frames per core-second, bytes per frame and in total, the cost model's prediction for this size
(bench_scaling.cost_model's per-frame render rate, extended to every stage: benchmarks/cost_model.py) next
to what was measured, and the projection to MVPd's 18,000 videos in core-hours and on N nodes of 16 cores.

    nice -n 19 .venv/bin/python benchmarks/bench_full_job.py --run-dir /work/runs-1pct/run [--resume] [--only STEP ...]

Writes benchmarks/results/full_job_1pct.json after every step; `--resume` keeps the steps already recorded
there (a long run can be continued after the script itself changed). The run folder and the command
outputs go under --run-dir's parent, never into the repository.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import psutil  # noqa: E402

from benchmarks.bench_scaling import NODE_CORES, NODE_COUNTS, summary  # noqa: E402

RESULTS = REPO / "benchmarks" / "results" / "full_job_1pct.json"
JOB = REPO / "jobs" / "mvpd-1pct.yaml"
JOB_STAGES = ("shard", "plan", "render", "screen", "split")
MODEL = "geometric"
EMBODIMENT = "mvpd"


@dataclass
class TreeSample:
    """CPU seconds and peak RSS of every process seen under one root (pid + start time: pids are reused)."""

    cpu_s: dict[tuple[int, float], float] = field(default_factory=dict)
    peak_rss: dict[tuple[int, float], int] = field(default_factory=dict)
    kind: dict[tuple[int, float], str] = field(default_factory=dict)

    def add(self, process: psutil.Process, kind: str) -> None:
        try:
            with process.oneshot():
                key = (process.pid, process.create_time())
                times = process.cpu_times()
                # children_*: descendants already reaped by this process (a worker that exited in between).
                cpu = times.user + times.system + times.children_user + times.children_system
                rss = process.memory_info().rss
        except psutil.Error:
            return
        self.cpu_s[key] = max(self.cpu_s.get(key, 0.0), cpu)
        self.peak_rss[key] = max(self.peak_rss.get(key, 0), rss)
        self.kind[key] = kind

    def total_cpu_s(self) -> float:
        return sum(self.cpu_s.values())

    def peak_gib(self, kind: str) -> float:
        values = [rss for key, rss in self.peak_rss.items() if self.kind[key] == kind]
        return round(max(values, default=0) / 2**30, 3)

    def cpu_of(self, kind: str) -> float:
        return round(sum(cpu for key, cpu in self.cpu_s.items() if self.kind[key] == kind), 1)


def process_kind(process: psutil.Process, root: psutil.Process) -> str:
    """driver (the command), worker (a Ray worker: runs units) or ray (raylet, GCS, log monitor...)."""
    if process.pid == root.pid:
        return "driver"
    try:
        command = " ".join(process.cmdline())
    except psutil.Error:
        return "ray"
    return "worker" if ("default_worker.py" in command or command.startswith("ray::")) else "ray"


def sample_tree(root: psutil.Process, sample: TreeSample, stop: threading.Event, every_s: float = 0.5) -> None:
    while not stop.is_set():
        try:
            processes = [root, *root.children(recursive=True)]
        except psutil.Error:
            processes = [root]
        for process in processes:
            sample.add(process, process_kind(process, root))
        stop.wait(every_s)


def mvpd_command(*args: str) -> list[str]:
    """The CLI as a user runs it, at the lowest priority."""
    return ["nice", "-n", "19", sys.executable, "-m", "pipeline.cli.main", *args]


def cli_env() -> dict[str, str]:
    # Never join a cluster someone else started: each command starts its own local Ray.
    return {**{k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}, "PYTHONPATH": str(REPO),
            "RAY_USAGE_STATS_ENABLED": "0"}


def run_measured(command: list[str], log: Path) -> dict[str, Any]:
    """Run one command to its end; wall and CPU seconds of its process tree, peak RSS, load average."""
    load_before = os.getloadavg()[0]
    began = time.perf_counter()
    with log.open("w", encoding="utf-8") as out:
        child = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env=cli_env(), cwd=REPO)
        root = psutil.Process(child.pid)
        sample, stop = TreeSample(), threading.Event()
        sampler = threading.Thread(target=sample_tree, args=(root, sample, stop), daemon=True)
        sampler.start()
        code = child.wait()
        stop.set()
        sampler.join()
    wall = time.perf_counter() - began
    return {"command": " ".join(command[4:]), "exit": code, "wall_s": round(wall, 1),
            "cpu_s": round(sample.total_cpu_s(), 1), "cpu_s_by_kind": {k: sample.cpu_of(k) for k in ("driver", "worker", "ray")},
            "peak_rss_gib": {"driver": sample.peak_gib("driver"), "worker": sample.peak_gib("worker")},
            "load_average_1m": [round(load_before, 2), round(os.getloadavg()[0], 2)], "log": str(log)}


def latency(command: list[str], repeats: int) -> dict[str, Any]:
    """Seconds of a read-only command, `repeats` times (not niced: a user waits for it)."""
    seconds, codes = [], set()
    for _ in range(repeats):
        began = time.perf_counter()
        codes.add(subprocess.run(command[3:], capture_output=True, env=cli_env(), cwd=REPO).returncode)
        seconds.append(time.perf_counter() - began)
    return {"command": " ".join(command[5:]), "exit": sorted(codes), "seconds": summary(seconds),
            "load_average_1m": round(os.getloadavg()[0], 2)}


def first_test_video(run_dir: Path) -> str:
    """A test video the report scored (the split's first accepted one), for `mvpd view`."""
    from pipeline.split.selection import accepted_videos

    accepted = accepted_videos(run_dir, "test") or []
    names = sorted(name for owner, name in accepted if owner == EMBODIMENT)
    if not names:
        raise RuntimeError(f"{run_dir}: the test split has no accepted {EMBODIMENT} video to view")
    return names[0]


def step_commands(job: Path, run_dir: Path, outputs: Path) -> dict[str, list[str]]:
    """Step name -> command, in the order a user runs them (the view's video is chosen when it runs)."""
    run = str(run_dir)
    report = outputs / "report"
    commands = {stage: mvpd_command("submit", str(job), "--run-dir", run, "--stages", stage, "--executor", "ray")
                for stage in JOB_STAGES}
    commands.update({
        "stats": mvpd_command("stats", run, "--out", str(outputs / "stats.png")),
        "report": mvpd_command("report", run, "--models", MODEL, "--embodiment", EMBODIMENT, "--out", str(report)),
        "evaluate": mvpd_command("evaluate", run, "--pred", str(report / "predictions" / MODEL), "--embodiment",
                                 EMBODIMENT, "--all", "--executor", "ray", "--out", str(outputs / "vsq.json")),
        "predict": mvpd_command("predict", run, "--model", MODEL, "--split", "test", "--embodiment", EMBODIMENT,
                                "--out", str(report / "predictions" / MODEL)),
        "export": mvpd_command("export", run, "--mvpd", str(outputs / "mvpd")),
        "view": mvpd_command("view", run, "VIDEO", "--embodiment", EMBODIMENT, "--out", str(outputs / "view.rrd")),
    })
    return commands


def latency_commands(run_dir: Path) -> dict[str, list[str]]:
    run = str(run_dir)
    return {"status": mvpd_command("status", run),
            "query": mvpd_command("query", run, "select embodiment, count(*) as videos, sum(frames) as frames "
                                  "from videos group by 1")}


def save(results: dict[str, Any], path: Path) -> None:
    path.write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run-dir", type=Path, required=True, help="the run folder (outside the repository)")
    parser.add_argument("--job", type=Path, default=JOB, help="job file (default: the 1 %% job)")
    parser.add_argument("--results", type=Path, default=RESULTS, help="results file (default: %(default)s)")
    parser.add_argument("--repeats", type=int, default=3, help="times each latency is measured")
    parser.add_argument("--resume", action="store_true", help="keep the steps already in the results file")
    parser.add_argument("--only", nargs="+", help="run only these steps (others keep their recorded values)")
    args = parser.parse_args()
    run_dir = args.run_dir.resolve()
    if REPO in run_dir.parents:
        parser.error(f"--run-dir {run_dir} is inside the repository; give a folder outside it")
    outputs = run_dir.parent / "outputs"
    (outputs / "logs").mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = json.loads(args.results.read_text()) if (args.resume or args.only) and args.results.exists() else {}
    results.update({"job": str(args.job), "run_dir": str(run_dir),
                    "machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]}})
    steps = results.setdefault("steps", {})
    commands = step_commands(args.job.resolve(), run_dir, outputs)
    for name, command in commands.items():
        wanted = name in args.only if args.only else name not in steps
        if not wanted:
            continue
        if name == "view":
            command = [first_test_video(run_dir) if word == "VIDEO" else word for word in command]
        print(f"{time.strftime('%H:%M:%S')} {name}: {' '.join(command[4:])}", flush=True)
        steps[name] = run_measured(command, outputs / "logs" / f"{name}.log")
        print(f"  {json.dumps(steps[name])}", flush=True)
        save(results, args.results)
        if steps[name]["exit"] != 0 and name in JOB_STAGES:
            sys.exit(f"{name} exited {steps[name]['exit']}; see {steps[name]['log']}")
    for name, command in latency_commands(run_dir).items():
        if args.only and name not in args.only:
            continue
        results.setdefault("latency", {})[name] = latency(command, args.repeats)
    save(results, args.results)
    print(f"wrote {args.results}")


if __name__ == "__main__":
    main()
