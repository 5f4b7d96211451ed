"""The run lock on object storage, garbage collection of dead attempts and a driver SIGKILLed mid-upload,
against a real S3 API (moto on 127.0.0.1). Two "machines" are two processes with two cache folders."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.store import lock as lock_module
from pipeline.store.garbage import attempt_prefix, collect_garbage
from pipeline.store.markers import parse_marker
from pipeline.store.lock import LOCK_KEY, RemoteRunLock, RunLockedError
from pipeline.store.remote import RunStore
from pipeline.store.names import ATTEMPTS
from pipeline.store.run_folder import RunFolder
from tests.storage.conftest import TEST_KEY_ID, TEST_SECRET, S3Server
from tests.storage.test_s3_run import assert_same_outputs, trusted_bytes_on_store

REPO = Path(__file__).resolve().parents[2]
TINY_JOB = """
name: tiny
seed: 0
scenes:
  procedural: {count: 2, seed: 0, detail: 0.05}
embodiments:
  - name: ambient
    sensor: {width: 64, height: 48, hfov: 69.0}
    placements: [1.0]
    body: {radius: 0.15, height: 1.2}
    illumination: {kind: ambient}
plan: {trajectories_per_scene: 1, min_frames: 10, max_frames: 30}
"""
# A driver on "another machine": holds the run's lock until its standard input closes.
HOLD_LOCK = """
import sys
from pipeline.store.lock import RemoteRunLock
from pipeline.store.remote import RunStore
with RemoteRunLock(RunStore(sys.argv[1])):
    print("held", flush=True)
    sys.stdin.read()
"""
# `mvpd ARGS` on a slow link: each object of a commit is PUT on its own, 0.25 s apart, so a test can kill the
# driver while a unit's objects are being uploaded (the PUTs themselves are real ones to the S3 server).
SLOW_UPLOAD_MVPD = """
import sys, time
from pipeline.store import remote as object_store
real_put_files = object_store.RunStore.put_files
def one_at_a_time(self, uploads):
    for upload in uploads:
        real_put_files(self, [upload])
        time.sleep(0.25)
object_store.RunStore.put_files = one_at_a_time
from pipeline.cli.main import app
sys.argv[0] = "mvpd"
app()
"""


def invoke(*args: object) -> object:
    return CliRunner().invoke(app, [str(a) for a in args])


def machine(cache: Path) -> dict[str, str]:
    """The environment of a process on another machine: the same store, its own cache folder."""
    return {**os.environ, "MVPD_CACHE_DIR": str(cache), "PYTHONPATH": str(REPO), "RAY_ADDRESS": ""}


@pytest.fixture(scope="module")
def tiny_url(s3: S3Server, tmp_path_factory: pytest.TempPathFactory) -> str:
    folder = tmp_path_factory.mktemp("tiny-job")
    (folder / "tiny.yaml").write_text(TINY_JOB, encoding="utf-8")
    url = s3.url("runs/lockgc")
    result = invoke("submit", folder / "tiny.yaml", "--run-dir", url, "--executor", "local")
    assert result.exit_code == 0, result.output
    return url


def store_markers(s3: S3Server, url: str) -> dict[str, object]:
    """The markers on the bucket now, while another process may be changing it (s3fs caches listings)."""
    s3.fs.invalidate_cache()
    keys = [k for k in s3.fs.find(f"{url.removeprefix('s3://')}/_state") if k.endswith(".json")]
    found = {}
    for data in s3.fs.cat(keys, on_error="omit").values():
        marker = parse_marker(data.decode()) if isinstance(data, bytes) else None
        if marker is not None:
            found[f"{marker.stage}/{marker.unit}"] = marker
    return found


def lock_object(s3: S3Server, url: str) -> dict | None:
    try:
        return json.loads(s3.fs.cat_file(f"{url.removeprefix('s3://')}/{LOCK_KEY}"))
    except FileNotFoundError:
        return None


def test_a_second_machine_is_kept_out_until_the_holder_exits(s3, tiny_url, tmp_path, monkeypatch):
    holder = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, tiny_url], env=machine(tmp_path / "machine-a"),
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        record = lock_object(s3, tiny_url)
        assert record["pid"] == holder.pid and record["heartbeat"] > time.time() - 60
        raw = s3.fs.cat_file(f"{tiny_url.removeprefix('s3://')}/{LOCK_KEY}")
        assert TEST_SECRET.encode() not in raw and TEST_KEY_ID.encode() not in raw
        monkeypatch.setenv("MVPD_CACHE_DIR", str(tmp_path / "machine-b"))
        refused = invoke("rerun", tiny_url, "--stage", "render", "--executor", "local")
        assert refused.exit_code == 2, refused.output
        lines = [line for line in refused.output.splitlines() if line.strip()]
        assert len(lines) == 1 and f"already being run by pid {holder.pid}" in lines[0], refused.output
    finally:
        holder.communicate("", timeout=60)
    assert holder.returncode == 0 and lock_object(s3, tiny_url) is None  # released on exit
    again = invoke("rerun", tiny_url, "--stage", "render", "--executor", "local")
    assert again.exit_code == 0 and "0 done, 0 failed, 2 up to date" in again.output, again.output
    assert lock_object(s3, tiny_url) is None


def test_a_stale_lock_is_taken_over_and_a_live_one_is_not(s3, tiny_url):
    store = RunStore(tiny_url)
    other = {"host": "elsewhere", "pid": 1, "process_started": 0, "started": 0, "owner": "elsewhere.1.0"}
    store.put_text(LOCK_KEY, json.dumps({**other, "heartbeat": time.time()}))
    with pytest.raises(RunLockedError, match="already being run by pid 1 on elsewhere"):
        with RemoteRunLock(store):
            pass
    assert lock_object(s3, tiny_url)["host"] == "elsewhere"  # a refused taker changes nothing
    store.put_text(LOCK_KEY, json.dumps({**other, "heartbeat": time.time() - lock_module.STALE_SECONDS - 5}))
    with RemoteRunLock(store):
        assert lock_object(s3, tiny_url)["pid"] == os.getpid()
    assert lock_object(s3, tiny_url) is None
    # A create that landed but whose answer was lost (the client's retry then fails If-None-Match): ours, kept.
    landed = RemoteRunLock(store)
    store.put_text(LOCK_KEY, landed._record().decode())
    with landed:
        assert lock_object(s3, tiny_url)["owner"] == landed.owner
    assert lock_object(s3, tiny_url) is None


def test_heartbeat_refreshes_the_lock_and_never_overwrites_a_new_owner(s3, tiny_url, monkeypatch):
    monkeypatch.setattr(lock_module, "HEARTBEAT_SECONDS", 0.2)
    store = RunStore(tiny_url)
    with RemoteRunLock(store):
        first = lock_object(s3, tiny_url)["heartbeat"]
        deadline = time.time() + 20
        while lock_object(s3, tiny_url)["heartbeat"] == first and time.time() < deadline:
            time.sleep(0.1)
        assert lock_object(s3, tiny_url)["heartbeat"] > first
        # Judged dead from another machine and taken over: our next beat and our release must fail their If-Match.
        store.put_text(LOCK_KEY, json.dumps({"host": "elsewhere", "pid": 7, "heartbeat": time.time(), "started": 0}))
        time.sleep(1.0)
        assert lock_object(s3, tiny_url)["pid"] == 7
    assert lock_object(s3, tiny_url)["pid"] == 7  # release left the new owner's lock alone
    store.fs.rm_file(store.key(LOCK_KEY))


def _race(url: str, trials: int, barrier, results) -> None:
    """One racer: in each trial all racers take the same lock at once (a fresh one, or a stale one)."""
    store = RunStore(url)
    for trial in range(trials):
        barrier.wait()
        lock = RemoteRunLock(store)
        try:
            lock.__enter__()
            held = 1
        except RunLockedError:
            held = 0
        barrier.wait()  # every racer has tried while the winner still holds the lock
        if held:
            lock.release()
        results.put((trial, held))
        barrier.wait()


def test_racing_drivers_on_other_machines_never_both_hold_the_lock(s3, tmp_path):
    import multiprocessing

    url, trials, racers = s3.url("runs/lock-race"), 8, 4
    store = RunStore(url)
    context = multiprocessing.get_context("spawn")
    barrier, results = context.Barrier(racers + 1, timeout=120), context.Queue()
    processes = [context.Process(target=_race, args=(url, trials, barrier, results)) for _ in range(racers)]
    for process in processes:
        process.start()
    holders = [0] * trials
    try:
        for trial in range(trials):
            if trial % 2:  # odd trials: a stale lock of a dead driver elsewhere, which every racer tries to take over
                store.put_text(LOCK_KEY, json.dumps({"host": "elsewhere", "pid": 1, "started": 0, "heartbeat": 0}))
            barrier.wait()
            barrier.wait()
            barrier.wait()
        for _ in range(trials * racers):
            trial, held = results.get(timeout=60)
            holders[trial] += held
    finally:
        for process in processes:
            process.join(timeout=30)
            if process.is_alive():
                process.terminate()
    assert holders == [1] * trials, holders
    assert lock_object(s3, url) is None


def test_sigkill_mid_upload_leaves_nothing_visible_and_gc_removes_the_dead_attempt(s3, tiny_url, tmp_path,
                                                                                  monkeypatch):
    s3.fs.invalidate_cache()
    clean = trusted_bytes_on_store(s3, tiny_url)
    committed = {k: m for k, m in store_markers(s3, tiny_url).items() if k.startswith("render/")}
    named = {attempt_prefix(key) for m in store_markers(s3, tiny_url).values() for key in m.keys.values()}
    bucket_prefix = tiny_url.removeprefix("s3://")
    killed_cache = tmp_path / "killed-machine"
    driver = subprocess.Popen([sys.executable, "-c", SLOW_UPLOAD_MVPD, "rerun", tiny_url, "--stage", "render", "--all",
                               "--executor", "local"], env=machine(killed_cache),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    dead_objects: list[str] = []
    try:
        deadline = time.time() + 120
        while time.time() < deadline and driver.poll() is None:
            s3.fs.invalidate_cache()
            attempts = [k for k in s3.fs.find(f"{bucket_prefix}/{ATTEMPTS}/render")
                        if attempt_prefix(k.removeprefix(bucket_prefix + "/")) not in named]
            markers = store_markers(s3, tiny_url)
            unit = attempts[0].split("/")[5] if attempts else None  # <bucket>/runs/lockgc/_attempts/render/<unit>
            if len(attempts) >= 3 and f"render/{unit}" not in markers:
                dead_objects = attempts
                break
            time.sleep(0.05)
        os.kill(driver.pid, signal.SIGKILL)  # mid-upload: some objects of the unit are PUT, its marker is not
    finally:
        driver.wait(timeout=30)
    assert dead_objects, "the driver never uploaded a unit's objects"
    unit = dead_objects[0].split("/")[5]
    assert driver.returncode == -signal.SIGKILL and f"render/{unit}" not in store_markers(s3, tiny_url)

    # Another machine: the unit is not done, and readers see nothing of it.
    monkeypatch.setenv("MVPD_CACHE_DIR", str(tmp_path / "reader"))
    from pipeline.runtime.inspect import run_state

    render = next(s for s in run_state(RunFolder.open(tiny_url)).stages if s.stage == "render")
    assert unit not in render.done and len(render.done) < len(committed)
    status = invoke("status", tiny_url)
    row = next(line for line in status.output.splitlines() if line.strip("│ ").startswith("render "))
    assert [cell.strip() for cell in row.split("│")[2:4]] == [str(len(committed)), str(len(committed) - 1)], status.output
    query = invoke("query", tiny_url, "select count(*) as n from videos", "--format", "json")
    assert json.loads(query.output)[0]["n"] == len(render.done), query.output

    # gc, from the killed driver's machine (its lock is stale: same host, pid gone): the dry run deletes nothing.
    monkeypatch.setenv("MVPD_CACHE_DIR", str(killed_cache))
    dry = invoke("gc", tiny_url, "--dry-run")
    assert dry.exit_code == 0 and "would delete" in dry.output and "staging folders" in dry.output, dry.output
    s3.fs.invalidate_cache()
    assert all(s3.fs.exists(k) for k in dead_objects)
    report = collect_garbage(RunFolder.open(tiny_url))
    assert {attempt_prefix(k.removeprefix(bucket_prefix + "/")) for k in dead_objects} <= set(report.attempts)
    assert report.objects >= len(dead_objects) and report.bytes > 0
    # Left alone: the unit's first commit, dropped by the killed --all rerun, was made by this (live) process.
    assert all(prefix.split("/")[-1].split(".")[-2] == str(os.getpid()) for prefix in report.kept_alive), report
    assert any(folder.startswith(f"_staging/render/{unit}.") for folder in report.staging)
    s3.fs.invalidate_cache()
    assert not any(s3.fs.exists(k) for k in dead_objects) and not list((killed_cache).glob("*/_staging/render/*"))
    for marker in store_markers(s3, tiny_url).values():  # never what a marker names
        assert all(s3.fs.exists(f"{bucket_prefix}/{key}") for key in marker.keys.values())

    # A rerun completes the run, equal to the clean one; nothing is left for gc afterwards.
    again = invoke("rerun", tiny_url, "--stage", "render", "--executor", "local")
    assert again.exit_code == 0 and "0 failed" in again.output, again.output
    s3.fs.invalidate_cache()
    assert_same_outputs(trusted_bytes_on_store(s3, tiny_url), clean)
    after = invoke("gc", tiny_url)
    assert after.exit_code == 0 and "deleted 0 objects" in after.output, after.output


def test_gc_deletes_only_what_no_marker_names_and_refuses_a_locked_run(s3, tiny_url, monkeypatch, tmp_path):
    store = RunStore(tiny_url)
    named = sorted({key for m in store_markers(s3, tiny_url).values() for key in m.keys.values()})
    live_unit = named[0].split("/")[2]
    dead = [f"{ATTEMPTS}/render/{live_unit}/otherhost.4242.1/videos/x.zarr/zarr.json",
            f"{ATTEMPTS}/render/{live_unit}/otherhost.4242.1/videos/x.zarr/c/0",
            f"{ATTEMPTS}/plan/gone-unit/otherhost.4243.2/trajectories/part-gone-unit.parquet"]
    for key in dead:
        store.put_text(key, "left by a dead attempt")
    monkeypatch.setenv("MVPD_CACHE_DIR", str(tmp_path / "gc-machine"))
    with RemoteRunLock(store):  # a run going on elsewhere: gc waits its turn, deletes nothing
        refused = invoke("gc", tiny_url)
    assert refused.exit_code == 2 and "already being run" in refused.output, refused.output
    assert all(store.exists(key) for key in dead)
    result = invoke("gc", tiny_url)
    assert result.exit_code == 0, result.output
    assert "deleted 3 objects" in result.output and "of 2 dead attempts" in result.output, result.output
    assert not any(store.exists(key) for key in dead)
    assert all(store.exists(key) for key in named)


def test_gc_on_local_disk_removes_staging_folders_of_dead_attempts(tmp_path):
    import socket

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    run = tmp_path / "run"
    (run / "_state").mkdir(parents=True)
    (run / "job.yaml").write_text("job_hash: x\n", encoding="utf-8")
    host = socket.gethostname()
    dead_folder = run / "_staging" / "render" / f"emb.proc-1.0000.{host}.{int(dead.stdout)}"
    alive_folder = run / "_staging" / "render" / f"emb.proc-2.0000.{host}.{os.getpid()}"
    for folder in (dead_folder, alive_folder):
        (folder / "videos").mkdir(parents=True)
        (folder / "videos" / "part.bin").write_bytes(b"x" * 100)
    dry = collect_garbage(RunFolder.open(run), dry_run=True)
    assert dry.staging == [dead_folder.relative_to(run).as_posix()] and dead_folder.exists()
    report = collect_garbage(RunFolder.open(run))
    assert report.staging == dry.staging and report.kept_alive == [alive_folder.relative_to(run).as_posix()] and report.objects == 0
    assert not dead_folder.exists() and alive_folder.exists()


def test_gc_that_loses_its_lock_stops_deleting(tmp_path, monkeypatch):
    from pipeline.store import garbage
    from pipeline.store.lock import LeaseLostError

    run = tmp_path / "run"
    (run / "_state").mkdir(parents=True)
    (run / "job.yaml").write_text("job_hash: x\n", encoding="utf-8")
    dead = [run / "_staging" / "render" / f"emb.proc-{k}.0000.otherhost.4242" for k in (1, 2)]
    for folder in dead:
        folder.mkdir(parents=True)
    real_remove = garbage.links.remove

    def then_another_driver_takes_the_lock(root, relative):
        real_remove(root, relative)  # the first folder goes; then the lease is lost to another driver
        (run / lock_module.LOCK_KEY).write_text(json.dumps({"owner": "another", "pid": 1, "host": "elsewhere",
                                                            "heartbeat": time.time()}), encoding="utf-8")

    monkeypatch.setattr(garbage.links, "remove", then_another_driver_takes_the_lock)
    with pytest.raises(LeaseLostError, match="held by pid 1 on elsewhere"):
        collect_garbage(RunFolder.open(run))
    assert not dead[0].exists() and dead[1].exists()  # fenced: nothing deleted after the lease was lost
    assert json.loads((run / lock_module.LOCK_KEY).read_text())["owner"] == "another"  # and its lock kept


@pytest.mark.parametrize("where", ["s3", "memory"])
def test_conditional_writes_refuse_a_writer_that_read_an_older_version(s3, where):
    store = RunStore(s3.url("runs/conditions") if where == "s3" else "memory://lockgc/conditions")
    first = store.create_object("thing.json", b"one")
    assert first is not None and store.create_object("thing.json", b"two") is None  # If-None-Match: *
    found = store.read_object("thing.json")
    assert found.data == b"one" and found.tag == first and found.modified > time.time() - 600
    second = store.replace_object("thing.json", b"three", first)
    assert second not in (None, first)
    assert store.replace_object("thing.json", b"four", first) is None  # If-Match on a tag already replaced
    assert not store.remove_object("thing.json", first) and store.read_object("thing.json").data == b"three"
    assert store.remove_object("thing.json", second) and store.read_object("thing.json") is None
    assert store.replace_object("thing.json", b"five", second) is None
