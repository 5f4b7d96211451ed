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
every worker: each process's own time, sampled every 0.5 s while it lives), peak RSS
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
import calendar
import json
import os
import signal
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

from benchmarks.bench_scaling import (  # noqa: E402
    MVPD_FRAMES, MVPD_VIDEOS, RESULTS as SCALING_RESULTS, calibrated_projection, job_core_seconds, on_nodes,
    stage_rates, summary)
from pipeline.store.run_folder import RunFolder  # noqa: E402

RESULTS = REPO / "benchmarks" / "results" / "full_job_1pct.json"
JOB = REPO / "jobs" / "mvpd-1pct.yaml"
JOB_STAGES = ("shard", "plan", "render", "screen", "split")
MODEL = "geometric"
EMBODIMENT = "mvpd"
MVPD_SCENES = 180
MVPD_PATHS = 9_000
MVPD_TEST_FRAMES = 606_000  # 18 scenes x 50 paths x 2 heights x 336.7 frames (models.json)
TARGETS = {"cost_model_error": 0.15, "driver_gib": 1.0, "status_s": 2.0}


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
                # Its own time only: a reaped child's time also shows in its parent's children_* fields, and
                # the child was sampled itself (a process that exits loses at most one interval).
                cpu = times.user + times.system
                rss = process.memory_info().rss
        except psutil.Error:
            return
        self.cpu_s[key] = max(self.cpu_s.get(key, 0.0), cpu)
        self.peak_rss[key] = max(self.peak_rss.get(key, 0), rss)
        # A process is what it was first seen as: an exiting worker's command line reads empty.
        self.kind.setdefault(key, kind)

    def total_cpu_s(self) -> float:
        return sum(self.cpu_s.values())

    def peak_gib(self, kind: str) -> float:
        values = [rss for key, rss in self.peak_rss.items() if self.kind[key] == kind]
        return round(max(values, default=0) / 2**30, 3)

    def cpu_of(self, kind: str) -> float:
        return round(sum(cpu for key, cpu in self.cpu_s.items() if self.kind[key] == kind), 1)


def process_kind(process: psutil.Process, root: psutil.Process) -> str:
    """driver (the command), worker (a Ray worker running units, or an export worker) or other (Ray's raylet,
    GCS, agents, log monitor...)."""
    if process.pid == root.pid:
        return "driver"
    try:
        command = " ".join(process.cmdline())
    except psutil.Error:
        return "other"
    # Ray names its workers' processes ray::IDLE or ray::<task>, its agents ray::<Name>Agent; the MVPd
    # export's workers are spawned by multiprocessing.
    is_worker = ("default_worker.py" in command or "multiprocessing.spawn" in command
                 or (command.startswith("ray::") and not command.split()[0].endswith("Agent")))
    return "worker" if is_worker else "other"


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


def run_measured(command: list[str], log: Path, deadline: float | None = None) -> dict[str, Any]:
    """Run one command to its end (or SIGTERM it at `deadline`, epoch seconds: the CLI then stops with exit 143
    and keeps its finished units); wall and CPU seconds of its process tree, peak RSS, load average."""
    load_before = os.getloadavg()[0]
    began = time.perf_counter()
    with log.open("w", encoding="utf-8") as out:
        child = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env=cli_env(), cwd=REPO)
        root = psutil.Process(child.pid)  # `nice` execs the command: same pid
        sample, stop = TreeSample(), threading.Event()
        sampler = threading.Thread(target=sample_tree, args=(root, sample, stop), daemon=True)
        sampler.start()
        while True:
            try:  # returns as soon as the command ends: a sleep between polls added up to 0.5 s to every wall time
                code = child.wait(timeout=0.5)
                break
            except subprocess.TimeoutExpired:
                if deadline is not None and time.time() > deadline:
                    child.send_signal(signal.SIGTERM)
                    deadline = None
        stop.set()
        sampler.join()
    wall = time.perf_counter() - began
    return {"command": " ".join(command[command.index("pipeline.cli.main") + 1:]), "exit": code, "wall_s": round(wall, 1),
            "cpu_s": round(sample.total_cpu_s(), 1), "cpu_s_by_kind": {k: sample.cpu_of(k) for k in ("driver", "worker", "other")},
            "peak_rss_gib": {"driver": sample.peak_gib("driver"), "worker": sample.peak_gib("worker")},
            "load_average_1m": [round(load_before, 2), round(os.getloadavg()[0], 2)], "log": str(log)}


def latency(command: list[str], repeats: int, log: Path) -> dict[str, Any]:
    """Wall and CPU seconds of a read-only command, `repeats` times (not niced: a user waits for it). On a
    loaded machine the wall time is mostly waiting for a core: the CPU time is the command's own cost."""
    runs = [run_measured(command[3:], log) for _ in range(repeats)]
    return {"command": runs[0]["command"], "exit": sorted({r["exit"] for r in runs}),
            "seconds": summary([r["wall_s"] for r in runs]), "cpu_s": summary([r["cpu_s"] for r in runs]),
            "load_average_1m": [r["load_average_1m"][0] for r in runs]}


def export_workers(run_dir: Path, outputs: Path, split: str, repeats: int) -> dict[str, Any]:
    """`mvpd export --split SPLIT` on one core (`taskset -c 0`: the export then uses one process) against every
    core (one worker process each), `repeats` times interleaved; wall and CPU seconds."""
    runs: dict[str, list[dict[str, Any]]] = {"one_core": [], "all_cores": []}
    for index in range(repeats):
        for name, prefix in (("one_core", ["taskset", "-c", "0"]), ("all_cores", [])):
            out = outputs / f"export-{name}-{index}"
            runs[name].append(run_measured([*prefix, *mvpd_command("export", str(run_dir), "--mvpd", str(out), "--split", split)],
                                           outputs / "logs" / f"export-{name}.log"))
            subprocess.run(["rm", "-rf", str(out)], check=True)
    wall = {name: summary([r["wall_s"] for r in found]) for name, found in runs.items()}
    return {"split": split, "cores": len(os.sched_getaffinity(0)), "wall_s": wall,
            "cpu_s": {name: summary([r["cpu_s"] for r in found]) for name, found in runs.items()},
            "speedup": round(wall["one_core"]["median"] / wall["all_cores"]["median"], 2),
            "load_average_1m": [r["load_average_1m"][0] for found in runs.values() for r in found]}


def first_test_video(run_dir: Path) -> str:
    """A test video the report scored (the split's first accepted one), for `mvpd view`."""
    from pipeline.split.selection import accepted_videos

    accepted = accepted_videos(RunFolder(run_dir), "test") or []
    names = sorted(name for owner, name in accepted if owner == EMBODIMENT)
    if not names:
        raise RuntimeError(f"{run_dir}: the test split has no accepted {EMBODIMENT} video to view")
    return names[0]


def step_commands(job: Path, run_dir: Path, outputs: Path, export_split: str | None = None) -> dict[str, list[str]]:
    """Step name -> command, in the order a user runs them (the view's video is chosen when it runs)."""
    run = str(run_dir)
    report = outputs / "report"
    commands = {stage: mvpd_command("submit", str(job), "--run-dir", run, "--stages", stage, "--executor", "ray")
                for stage in JOB_STAGES}
    commands.update({
        # Everything is done: what submitting a finished run again costs (no unit runs).
        "resubmit": mvpd_command("submit", str(job), "--run-dir", run, "--executor", "ray"),
        "stats": mvpd_command("stats", run, "--out", str(outputs / "stats.png")),
        "report": mvpd_command("report", run, "--models", MODEL, "--embodiment", EMBODIMENT, "--out", str(report)),
        "evaluate": mvpd_command("evaluate", run, "--pred", str(report / "predictions" / MODEL), "--embodiment",
                                 EMBODIMENT, "--all", "--executor", "ray", "--out", str(outputs / "vsq.json")),
        "predict": mvpd_command("predict", run, "--model", MODEL, "--split", "test", "--embodiment", EMBODIMENT,
                                "--out", str(report / "predictions" / MODEL)),
        "view": mvpd_command("view", run, "VIDEO", "--embodiment", EMBODIMENT, "--out", str(outputs / "view.rrd")),
        "export": mvpd_command("export", run, "--mvpd", str(outputs / "mvpd"),
                               *(["--split", export_split] if export_split else [])),
    })
    return commands


def latency_commands(run_dir: Path) -> dict[str, list[str]]:
    run = str(run_dir)
    return {"status": mvpd_command("status", run),
            "query": mvpd_command("query", run, "select embodiment, count(*) as videos, sum(frames) as frames "
                                  "from videos group by 1")}


def utc_today(clock: str) -> float:
    """Epoch seconds of today's HH:MM in UTC."""
    hours, minutes = (int(part) for part in clock.split(":"))
    now = time.gmtime()
    return float(calendar.timegm((now.tm_year, now.tm_mon, now.tm_mday, hours, minutes, 0)))


def exported_frames(root: Path) -> int:
    """Frames of an MVPd export: one panoptic PNG each."""
    return sum(1 for _ in root.glob("*/panomasksRGB/*/*.png"))


def folder_bytes(folder: Path) -> int:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())


def run_size(run_dir: Path) -> dict[str, Any]:
    """What the run holds: scenes, paths, videos and frames (all and the test split's), bytes."""
    from pipeline.split.selection import accepted_videos

    run = RunFolder.open(run_dir)
    videos = run.read("videos")
    frames_of = dict(zip(videos.column("video_name").to_pylist(), videos.column("frames").to_pylist()))
    test = sorted(name for owner, name in accepted_videos(run, "test") or [] if owner == EMBODIMENT)
    rendered = sum(f.size for m in run.markers("render").values() for f in m.files)
    frames = sum(frames_of.values())
    return {"scenes": run.read("scenes").num_rows, "paths": run.read("trajectories").num_rows // 2,
            "videos": len(frames_of), "frames": frames,
            "frames_per_video": {"mean": round(frames / len(frames_of), 1), "min": min(frames_of.values()),
                                 "max": max(frames_of.values())},
            "test_videos_accepted": len(test), "test_frames_accepted": sum(frames_of[v] for v in test),
            "render_bytes": rendered, "render_bytes_per_frame": round(rendered / frames),
            "run_bytes": folder_bytes(run_dir), "run_bytes_per_frame": round(folder_bytes(run_dir) / frames)}


def measured_rates(steps: dict[str, Any], size: dict[str, Any], command_s: float) -> dict[str, float]:
    """This run's CPU seconds per unit of work (each stage's command cost taken out), in stage_rates' terms.

    Plan is charged per path only (an upper bound at 50 paths a scene: its BVH and navigable area are per scene).
    """
    work = {stage: max(0.0, steps[stage]["cpu_s"] - command_s) if stage in steps else 0.0 for stage in JOB_STAGES}
    return {"render_s_per_frame": work["render"] / size["frames"], "shard_s_per_scene": work["shard"] / size["scenes"],
            "plan_s_per_scene": 0.0, "plan_s_per_path": work["plan"] / size["paths"],
            "screen_split_s_per_video": (work["screen"] + work["split"]) / size["videos"]}


def command_cpu_s(steps: dict[str, Any]) -> tuple[float, str]:
    """CPU seconds one `mvpd submit` with work to do costs by itself (the driver and a local Ray starting,
    tracking and stopping): the shard command's driver and Ray processes, its workers left out. (A submit
    that finds everything done starts no Ray: `resubmit` is not that cost.)"""
    kinds = steps["shard"]["cpu_s_by_kind"]
    return round(kinds["driver"] + kinds.get("other", kinds.get("ray", 0.0)), 1), "shard command's driver + Ray processes"


def cost_model_check(steps: dict[str, Any], size: dict[str, Any], command_s: float) -> dict[str, Any]:
    """The cost model's CPU seconds for the stages this run ran (their work and one command each) beside the
    measured ones; error = predicted / measured - 1."""
    ran = [stage for stage in JOB_STAGES if stage in steps]
    rates = stage_rates(json.loads(SCALING_RESULTS.read_text())["render_workers"])
    videos = size["videos"] if "screen" in ran else 0
    predicted = job_core_seconds(rates, size["scenes"], size["paths"], videos, size["frames"], command_s, len(ran))
    measured = sum(steps[stage]["cpu_s"] for stage in ran)
    return {"stages": ran, "predicted_cpu_s": predicted,
            "measured_cpu_s": {**{stage: steps[stage]["cpu_s"] for stage in ran}, "total": round(measured, 1)},
            "predicted_core_hours": round(predicted["total"] / 3600, 3), "measured_core_hours": round(measured / 3600, 3),
            "error": round(predicted["total"] / measured - 1, 3),
            "rates_predicted": {k: round(v, 5) for k, v in rates.items()},
            "note": "rates from benchmarks/results/{scaling,scenes,plan,split}.json (bench_scaling.stage_rates); "
                    "render frames are the frames this run rendered"}


def analyse(results: dict[str, Any], run_dir: Path, outputs: Path) -> dict[str, Any]:
    """Frames per core-second, bytes, peak memory, the cost model next to the measurement, the projection."""
    steps = results["steps"]
    size = run_size(run_dir)
    command_s, command_how = command_cpu_s(steps)
    job_cpu_s = sum(steps[stage]["cpu_s"] for stage in JOB_STAGES if stage in steps)
    projected = job_core_seconds(measured_rates(steps, size, command_s), MVPD_SCENES, MVPD_PATHS, MVPD_VIDEOS,
                                 MVPD_FRAMES, command_s)
    analysis: dict[str, Any] = {
        "size": size,
        "job_cpu_s": round(job_cpu_s, 1),
        "job_wall_s": round(sum(steps[s]["wall_s"] for s in JOB_STAGES if s in steps), 1),
        "frames_per_core_second": {"render": round(size["frames"] / steps["render"]["cpu_s"], 2),
                                   "render_workers_only": round(size["frames"] / steps["render"]["cpu_s_by_kind"]["worker"], 2),
                                   "job": round(size["frames"] / job_cpu_s, 2)},
        "peak_rss_gib": {"driver": max(s["peak_rss_gib"]["driver"] for s in steps.values()),
                         "worker": max(s["peak_rss_gib"]["worker"] for s in steps.values())},
        "command_cpu_s": {"seconds": command_s, "from": command_how},
        "cost_model": cost_model_check(steps, size, command_s),
        "projection_mvpd": {"videos": MVPD_VIDEOS, "frames": MVPD_FRAMES, "job_core_seconds": projected,
                            "job_core_hours": round(projected["total"] / 3600, 1),
                            "job_wall_hours_on_nodes": on_nodes(projected["total"] / 3600),
                            "stored_tb": round(MVPD_FRAMES * size["run_bytes_per_frame"] / 1e12, 3),
                            "how": "this run's CPU seconds per frame (render), per scene (shard), per path (plan), per "
                                   "video (screen + split), each without its command's cost, times MVPd's counts"},
        # The render cost model calibrated on one house of this job (bench_scaling.py --only calibration), beside
        # this run's own render rate above: the release's render core-hours by both.
        "calibrated_render_model": calibrated_projection(),
    }
    test_frames = size["test_frames_accepted"]
    if "report" in steps and test_frames:
        per_frame_s = (steps["report"]["cpu_s"] - command_s) / test_frames
        analysis["report_cpu_ms_per_test_frame"] = round(1000 * per_frame_s, 1)
        analysis["projection_mvpd"]["report_geometric_test_core_hours"] = round(per_frame_s * MVPD_TEST_FRAMES / 3600, 1)
    if steps.get("export", {}).get("exit") == 0:
        export_bytes = folder_bytes(outputs / "mvpd")
        frames = exported_frames(outputs / "mvpd")
        per_frame_s = steps["export"]["cpu_s"] / frames
        analysis["export"] = {"frames": frames, "bytes": export_bytes, "bytes_per_frame": round(export_bytes / frames),
                              "cpu_ms_per_frame": round(1000 * per_frame_s, 1)}
        analysis["projection_mvpd"]["export_core_hours"] = round(per_frame_s * MVPD_FRAMES / 3600, 1)
    status_s = results.get("latency", {}).get("status", {}).get("seconds", {}).get("median")
    analysis["targets"] = {**TARGETS, "met": {
        "cost_model_error": abs(analysis["cost_model"]["error"]) <= TARGETS["cost_model_error"],
        "driver_gib": analysis["peak_rss_gib"]["driver"] < TARGETS["driver_gib"],
        "status_s": status_s is not None and status_s < TARGETS["status_s"]}}
    return analysis


def markdown_table(results: dict[str, Any]) -> str:
    """The README's table of the steps: wall and CPU seconds, peak RSS of the driver and of a worker."""
    lines = ["| step | wall s | CPU s | driver GiB | worker GiB | load |", "|---|---:|---:|---:|---:|---|"]
    for name, step in results["steps"].items():
        rss = step["peak_rss_gib"]
        load = "-".join(f"{value:.0f}" for value in step["load_average_1m"])
        lines.append(f"| {name} | {step['wall_s']:.0f} | {step['cpu_s']:.1f} | {rss['driver']:.2f} | {rss['worker']:.2f} | {load} |")
    return "\n".join(lines)


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
    parser.add_argument("--export-split", help="export only this split (default: every split, as a user does)")
    parser.add_argument("--export-workers", metavar="SPLIT", help="also time exporting SPLIT on one core against "
                        "every core (--repeats times)")
    parser.add_argument("--deadline", help="UTC HH:MM: stop the running step then (SIGTERM, finished units kept), "
                        "skip the rest and measure what was done")
    args = parser.parse_args()
    deadline = utc_today(args.deadline) if args.deadline else None
    run_dir = args.run_dir.resolve()
    if REPO in run_dir.parents:
        parser.error(f"--run-dir {run_dir} is inside the repository; give a folder outside it")
    outputs = run_dir.parent / "outputs"
    (outputs / "logs").mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = json.loads(args.results.read_text()) if (args.resume or args.only) and args.results.exists() else {}
    results.update({"job": str(args.job), "run_dir": str(run_dir),
                    "machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]}})
    steps = results.setdefault("steps", {})
    commands = step_commands(args.job.resolve(), run_dir, outputs, args.export_split)
    for name, command in commands.items():
        wanted = name in args.only if args.only else name not in steps
        if not wanted or (name == "resubmit" and "stopped_in" in results):
            continue  # a resubmit of a run stopped early would go on with its work
        if name == "view":
            command = [first_test_video(run_dir) if word == "VIDEO" else word for word in command]
        print(f"{time.strftime('%H:%M:%S')} {name}: {' '.join(command[4:])}", flush=True)
        steps[name] = run_measured(command, outputs / "logs" / f"{name}.log", deadline)
        print(f"  {json.dumps(steps[name])}", flush=True)
        save(results, args.results)
        if steps[name]["exit"] != 0 and name in JOB_STAGES:
            # Later steps need this stage whole: measure the run as far as it got.
            results["stopped_in"] = name
            print(f"{name} exited {steps[name]['exit']} (see {steps[name]['log']}); measuring the run as it is")
            break
    if args.export_workers:
        results["export_workers"] = export_workers(run_dir, outputs, args.export_workers, args.repeats)
        save(results, args.results)
    for name, command in latency_commands(run_dir).items():
        if args.only and name not in args.only:
            continue
        results.setdefault("latency", {})[name] = latency(command, args.repeats, outputs / "logs" / f"{name}.log")
    save(results, args.results)
    results["analysis"] = analyse(results, run_dir, outputs)
    save(results, args.results)
    print(json.dumps(results["analysis"], indent=1))
    print(markdown_table(results))
    print(f"wrote {args.results}")


if __name__ == "__main__":
    main()
