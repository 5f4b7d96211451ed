"""Overhead of a run folder on object storage (not a test): a job on local disk vs a local S3 API.

Two jobs: `tiny` (the tests' demo shape: 3 procedural scenes, 2 embodiments, 64x48 px, 10-30 frames per
video) and `vga` (1 scene, 3 videos of 100-160 frames at 640x480, MVPd's resolution). Each is submitted as a
whole command (`mvpd submit --executor local`, in-process, so both sides run the same units the same
way) into a fresh local folder and into a fresh prefix of a bucket on moto's S3 server (started here as
its own process on 127.0.0.1, so its CPU is not ours to count). Runs alternate local / S3, `--repeats`
each. Figures per rendered frame, median and spread, with the ratio S3 / local (target <= 1.10): the whole
command's wall time, and the render stage's (its summary line: units rendered, staged and committed). The machine is shared: the load average is recorded before and after, and ratios hold where
seconds do not.

    .venv/bin/python benchmarks/bench_storage.py [--repeats 3] [--jobs tiny vga]

Writes benchmarks/results/storage.json (one entry per job; a job not measured keeps its last figures).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

# The demo's shape (3 scenes, 2 embodiments, 2 heights) at 64x48 px, 10-30 frames: the tests' demo-shaped run.
from tests.demo_run import DEMO_SHAPED_JOB as TINY_DEMO_JOB  # noqa: E402
RESULTS = REPO / "benchmarks" / "results" / "storage.json"
PYTHON = sys.executable
CLI = ["-c", "from pipeline.cli.main import app; app()"]
BUCKET = "mvpd-bench"
VGA_JOB = """
name: storage-vga
seed: 0
scenes:
  procedural: {count: 1, seed: 0, detail: 0.5}
embodiments:
  - name: cam
    sensor: {width: 640, height: 480, hfov: 69.0}
    placements: [1.0]
    body: {radius: 0.15, height: 1.2}
plan: {trajectories_per_scene: 3, min_frames: 100, max_frames: 160}
"""
JOBS = {"tiny": (TINY_DEMO_JOB, "tiny demo: 3 procedural scenes x 2 embodiments x 2 heights, 64x48 px, executor local"),
        "vga": (VGA_JOB, "1 procedural scene, 3 videos of 100-160 frames at 640x480, executor local")}


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def start_s3(port: int) -> subprocess.Popen:
    """moto's S3 server as its own process on the loopback address; returns once it answers."""
    server = subprocess.Popen([PYTHON, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return server
        except OSError:
            time.sleep(0.3)
    server.kill()
    raise RuntimeError("moto's S3 server did not start within 60 s")


def submit(job: Path, run_dir: str, env: dict[str, str]) -> tuple[float, float]:
    """Wall seconds of the whole command, and of its render stage (its summary line: plan the stage, run
    and commit every unit, write the status table)."""
    started = time.perf_counter()
    done = subprocess.run([PYTHON, *CLI, "submit", str(job), "--run-dir", run_dir, "--executor", "local"],
                          env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"submit {run_dir} exited {done.returncode}: {done.stdout[-800:]} {done.stderr[-800:]}")
    render = re.search(r"^render: \d+ done.* in ([0-9.]+) s", done.stdout, re.MULTILINE)
    if render is None:
        raise RuntimeError(f"submit {run_dir}: no render summary line in {done.stdout[-800:]}")
    return seconds, float(render.group(1))


def frame_count(run_dir: str, env: dict[str, str]) -> int:
    done = subprocess.run([PYTHON, *CLI, "query", run_dir, "select count(*) as n from frame_stats", "--format", "json"],
                          env=env, capture_output=True, text=True, check=True)
    return int(json.loads(done.stdout)[0]["n"])


def summary(values: list[float]) -> dict:
    return {"median": round(statistics.median(values), 5), "min": round(min(values), 5), "max": round(max(values), 5),
            "runs": [round(v, 5) for v in values]}


def measure(name: str, work: Path, env: dict[str, str], repeats: int) -> dict:
    """The job `name` on local disk and on the bucket, interleaved, `repeats` times each."""
    text, description = JOBS[name]
    job = work / f"{name}.yaml"
    job.write_text(text, encoding="utf-8")
    load_before = os.getloadavg()
    seconds: dict[str, list[float]] = {"local": [], "s3": []}
    unit_seconds: dict[str, list[float]] = {"local": [], "s3": []}
    frames = 0
    for repeat in range(repeats):
        for side in ("local", "s3"):  # interleaved: a load change hits both sides alike
            run_dir = str(work / f"{name}-local-{repeat}") if side == "local" else f"s3://{BUCKET}/{name}-{repeat}"
            whole, rendering = submit(job, run_dir, env)
            seconds[side].append(whole)
            unit_seconds[side].append(rendering)
            frames = frames or frame_count(run_dir, env)
            print(f"{name} {side} run {repeat + 1}: {whole:.2f} s, render stage {rendering:.2f} s", flush=True)
    load_after = os.getloadavg()
    per_frame = {side: [s / frames for s in values] for side, values in seconds.items()}
    ratios = [s3 / local for s3, local in zip(seconds["s3"], seconds["local"])]
    unit_per_frame = {side: [s / frames for s in values] for side, values in unit_seconds.items()}
    unit_ratios = [s3 / local for s3, local in zip(unit_seconds["s3"], unit_seconds["local"])]
    return {
        "job": description,
        "frames": frames,
        "seconds_per_frame": {side: summary(values) for side, values in per_frame.items()},
        "ratio_s3_to_local": summary(ratios),
        "ratio_of_medians": round(statistics.median(seconds["s3"]) / statistics.median(seconds["local"]), 3),
        # The per-frame figure of the target: the render stage's wall time (its units' rendering, staging and
        # commit: upload and marker on S3, rename on disk), without the command's start and the other stages.
        "render_stage_seconds_per_frame": {side: summary(values) for side, values in unit_per_frame.items()},
        "render_stage_ratio_s3_to_local": summary(unit_ratios),
        "target_ratio": 1.10,
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in load_after],
        "cpus": os.cpu_count(),
        "note": "seconds_per_frame: whole `mvpd submit` commands (Python start, planning, render, commit, status); the "
                "S3 side uploads every file, each marker last, to moto's server on 127.0.0.1 (its own process), "
                "and reads every input in place",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--jobs", nargs="+", choices=sorted(JOBS), default=sorted(JOBS))
    args = parser.parse_args()
    port = free_port()
    server = start_s3(port)
    work = Path(tempfile.mkdtemp(prefix="bench-storage-"))
    env = {**os.environ, "PYTHONPATH": str(REPO), "AWS_ACCESS_KEY_ID": "bench", "AWS_SECRET_ACCESS_KEY": "bench",
           "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}", "AWS_DEFAULT_REGION": "us-east-1",
           "MVPD_CACHE_DIR": str(work / "cache"), "RAY_USAGE_STATS_ENABLED": "0"}
    env.pop("AWS_PROFILE", None)
    env.pop("AWS_SESSION_TOKEN", None)
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    results = results if set(results) <= set(JOBS) else {}  # the one-job layout of earlier versions is replaced
    try:
        import s3fs

        os.environ.update({k: env[k] for k in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_ENDPOINT_URL",
                                               "AWS_DEFAULT_REGION")})
        s3fs.S3FileSystem().mkdir(BUCKET)
        for name in args.jobs:
            results[name] = measure(name, work, env, args.repeats)
            print(name, json.dumps(results[name], indent=1), flush=True)
    finally:
        server.terminate()
        server.wait(timeout=30)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
