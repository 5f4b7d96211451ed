"""Speed of the runtime's everyday commands (not a test): small work without Ray, status, verify.

Figures (each run `--repeats` times; median and spread; every time also as a ratio to its peer):
  python_startup     `python -c pass`: the floor of any command (peer of the two below)
  cli_import         `python -c "from pipeline.cli.main import app"`
  evaluate_small     `mvpd evaluate --gt-mvpd <vsq small case> --split test` as a whole command, in-process
                     (executor auto) and on Ray (`--executor ray`); target <= 3 s; the published evaluator
                     took 34.5 s on this case (issue 15)
  status_demo        `mvpd status` on the demo run (`--demo-run`, made by `mvpd demo`); target < 2 s
  verify_1gb         `mvpd status --verify` on a generated run of >= 1 GiB against `cat` of the same files
                     (the limit: reading the bytes), and against a plain `mvpd status` of that run (the
                     command's start, so that verify minus status is the reading); warm page cache for all

    .venv/bin/python benchmarks/bench_runtime.py [--demo-run runs/demo] [--repeats 3] [--gigabytes 1.0]

Writes benchmarks/results/runtime.json. The machine is shared: compare ratios, not seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

RESULTS = REPO / "benchmarks" / "results" / "runtime.json"
# ../shared/vsq_cases/small from a checkout in /work/main; the repository keeps the same files.
VSQ_SMALL = next(p for p in (REPO.parent / "shared" / "vsq_cases" / "small", REPO / "tests" / "data" / "vsq_small")
                 if (p / "MVPd").is_dir())
PUBLISHED_EVALUATOR_SECONDS = 34.5  # issue 15, the same case on an idle machine
PYTHON = sys.executable
CLI = ["-c", "from pipeline.cli.main import app; app()"]


def timed(command: list[str], repeats: int, before: "callable | None" = None) -> dict:
    """Median and spread of a command's wall time over `repeats` runs (each must exit 0 or 1)."""
    seconds = []
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    for _ in range(repeats):
        if before is not None:
            before()
        started = time.perf_counter()
        done = subprocess.run(command, env=env, capture_output=True, text=True)
        seconds.append(time.perf_counter() - started)
        if done.returncode not in (0, 1):
            raise RuntimeError(f"{' '.join(command)} exited {done.returncode}: {done.stderr[-800:]}")
    return {"median_s": round(statistics.median(seconds), 3), "min_s": round(min(seconds), 3),
            "max_s": round(max(seconds), 3), "runs_s": [round(s, 3) for s in seconds]}


def ratio(figure: dict, peer: dict) -> float:
    return round(figure["median_s"] / peer["median_s"], 2)


def evaluate_small(repeats: int, executor: str, work: Path) -> dict:
    out = work / f"evaluate-{executor}.json"

    def fresh() -> None:
        out.unlink(missing_ok=True)
        shutil.rmtree(out.with_suffix(".run"), ignore_errors=True)

    command = [PYTHON, *CLI, "evaluate", "--gt-mvpd", str(VSQ_SMALL / "MVPd"), "--split", "test",
               "--pred", str(VSQ_SMALL / "pred"), "--out", str(out), "--executor", executor]
    return timed(command, repeats, before=fresh)


def make_big_run(root: Path, gigabytes: float) -> int:
    """A run folder of committed random files (64 MiB each) with markers, as units would leave them."""
    from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources
    from pipeline.store.run_folder import RunFolder

    job = Job(name="big", scenes=SceneSources(procedural=ProceduralSource(count=1)), embodiments=[Embodiment(name="e")])
    run = RunFolder.create(root, job)
    block = 64 * 2**20
    count = max(1, round(gigabytes * 2**30 / block))
    rng = __import__("numpy").random.default_rng(0)
    for index in range(count):
        unit = f"blob{index:04d}"
        staging = run.staging("blobs", unit)
        (staging / "blobs").mkdir()
        (staging / "blobs" / f"{unit}.bin").write_bytes(rng.bytes(block))
        run.commit_unit("blobs", unit, staging, config_hash="", rows={}, seconds=0.0, attempt=1,
                        finished_at=time.time(), host="bench")
    return count * block


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo-run", type=Path, default=REPO / "runs" / "demo")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--gigabytes", type=float, default=1.0)
    args = parser.parse_args()
    results: dict = {"machine": f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start (shared)"}
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        peer = results["python_startup"] = timed([PYTHON, "-c", "pass"], args.repeats)
        results["cli_import"] = {**timed([PYTHON, "-c", "from pipeline.cli.main import app"], args.repeats)}
        results["cli_import"]["x_python_startup"] = ratio(results["cli_import"], peer)
        for executor in ("auto", "ray"):
            figure = results[f"evaluate_small_{executor}"] = evaluate_small(args.repeats, executor, work)
            figure["x_python_startup"] = ratio(figure, peer)
            figure["published_evaluator_s"] = PUBLISHED_EVALUATOR_SECONDS
            figure["target_s"] = 3.0
        print(json.dumps(results, indent=1), flush=True)
        if (args.demo_run / "job.yaml").is_file():
            figure = results["status_demo"] = timed([PYTHON, *CLI, "status", str(args.demo_run)], args.repeats)
            figure["x_python_startup"] = ratio(figure, peer)
            figure["target_s"] = 2.0
        else:
            results["status_demo"] = f"skipped: no demo run at {args.demo_run} (run `mvpd demo` first)"
        big = work / "big"
        size = make_big_run(big, args.gigabytes)
        files = sorted(str(p) for p in (big / "blobs").iterdir())
        cat = timed(["sh", "-c", 'cat "$@" > /dev/null', "cat", *files], args.repeats)
        plain = timed([PYTHON, *CLI, "status", str(big)], args.repeats)
        verify = timed([PYTHON, *CLI, "status", str(big), "--verify", "--executor", "local"], args.repeats)
        # What --verify adds to a plain status is the reading; that part is what `cat` bounds.
        reading = verify["median_s"] - plain["median_s"]
        results["verify_1gb"] = {"bytes": size, "cat": cat, "status_plain": plain, "status_verify": verify,
                                 "x_cat": ratio(verify, cat), "verify_reading_s": round(reading, 3),
                                 "verify_reading_x_cat": round(reading / cat["median_s"], 2),
                                 "verify_reading_gb_per_s": round(size / 2**30 / max(reading, 1e-3), 2),
                                 "cat_gb_per_s": round(size / 2**30 / cat["median_s"], 2),
                                 "note": "warm page cache for both; cat is the limit for reading the bytes"}
    results["load_average_at_end"] = round(os.getloadavg()[0], 1)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1) + "\n")
    print(json.dumps(results, indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
