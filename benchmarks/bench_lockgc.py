"""Cost of the run lock on object storage and of `mvpd gc` (not a test).

Lock: one take + release of `RemoteRunLock` on moto's S3 server (its own process on 127.0.0.1) against one
of the local `RunLock` (hard link + flock) as the peer, `--cycles` each, interleaved, `--repeats` times:
median per cycle and the ratio. A driver takes the lock once per command, so this is a per-command cost.
GC: `--objects` dead objects (small, under `--attempts` attempt prefixes) next to a committed unit; the
dry run (one listing of `_attempts/` and `_state/`, the markers fetched) is the peer of the real run
(the same plus batched DeleteObjects): per object, median and spread. The machine is shared: the load
average is recorded, and ratios hold where seconds do not.

    .venv/bin/python benchmarks/bench_lockgc.py [--repeats 3] [--objects 2000]

Writes benchmarks/results/lockgc.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.bench_storage import free_port, start_s3  # noqa: E402

RESULTS = REPO / "benchmarks" / "results" / "lockgc.json"
BUCKET = "mvpd-bench-lockgc"


def summary(values: list[float]) -> dict:
    return {"median": round(statistics.median(values), 6), "min": round(min(values), 6), "max": round(max(values), 6)}


def lock_cycle_seconds(make_lock, cycles: int) -> float:
    """Seconds per take + release, over `cycles` cycles."""
    started = time.perf_counter()
    for _ in range(cycles):
        with make_lock():
            pass
    return (time.perf_counter() - started) / cycles


def plant_run(store, objects: int, attempts: int) -> None:
    """One committed unit (a marker naming one attempt) and `objects` dead objects under `attempts` prefixes."""
    from pipeline.store.names import STATE

    live = "_attempts/bench/live/otherhost.1.1/part.bin"
    store.put_text(live, "live")
    store.put_text(f"{STATE}/bench/live.json", json.dumps({"keys": {"part.bin": live}}))
    payload = {store.key(f"_attempts/bench/u{i % attempts}/deadhost.{i % attempts}.1/f{i}.bin"): b"x" * 512
               for i in range(objects)}
    store.fs.pipe(payload)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cycles", type=int, default=20)
    parser.add_argument("--objects", type=int, default=2000)
    parser.add_argument("--attempts", type=int, default=100)
    options = parser.parse_args()
    port = free_port()
    server = start_s3(port)
    os.environ.update({"AWS_ACCESS_KEY_ID": "bench", "AWS_SECRET_ACCESS_KEY": "bench",
                       "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}", "AWS_DEFAULT_REGION": "us-east-1"})
    import s3fs

    from pipeline.store.garbage import collect_garbage
    from pipeline.store.lock import RemoteRunLock, RunLock
    from pipeline.store.remote import RunStore
    from pipeline.store.run_folder import RunFolder

    s3fs.S3FileSystem().mkdir(BUCKET)
    remote_lock, local_lock, dry, real = [], [], [], []
    load_before = os.getloadavg()
    try:
        with tempfile.TemporaryDirectory() as scratch:
            os.environ["MVPD_CACHE_DIR"] = str(Path(scratch) / "cache")
            store = RunStore(f"s3://{BUCKET}/lock")
            for _ in range(options.repeats):
                remote_lock.append(lock_cycle_seconds(lambda: RemoteRunLock(store), options.cycles))
                local_lock.append(lock_cycle_seconds(lambda: RunLock(Path(scratch) / "local"), options.cycles))
            for repeat in range(options.repeats):
                url = f"s3://{BUCKET}/gc-{repeat}"
                store = RunStore(url)
                plant_run(store, options.objects, options.attempts)
                store.put_text("job.yaml", "job_hash: bench\n")
                run = RunFolder(url)  # no refresh: the planted run has no real job
                started = time.perf_counter()
                found = collect_garbage(run, dry_run=True)
                dry.append((time.perf_counter() - started) / options.objects)
                started = time.perf_counter()
                done = collect_garbage(run)
                real.append((time.perf_counter() - started) / options.objects)
                assert found.objects == done.objects == options.objects and store.list_objects("_attempts") == \
                    {"_attempts/bench/live/otherhost.1.1/part.bin": 4}, "gc deleted the wrong objects"
    finally:
        server.terminate()
        server.wait(timeout=30)
    load_after = os.getloadavg()
    result = {
        "lock_take_release_seconds": {"s3": summary(remote_lock), "local": summary(local_lock),
                                      "ratio_s3_to_local": summary([r / l for r, l in zip(remote_lock, local_lock)])},
        "gc_seconds_per_object": {"dry_run": summary(dry), "delete": summary(real),
                                  "ratio_delete_to_dry_run": summary([r / d for r, d in zip(real, dry)])},
        "objects": options.objects, "attempts": options.attempts, "cycles": options.cycles,
        "repeats": options.repeats,
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in load_after],
        "note": "moto's S3 server on 127.0.0.1 in its own process, 2 shared cores under other work",
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
