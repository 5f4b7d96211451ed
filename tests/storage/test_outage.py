"""An S3 endpoint that goes away and comes back (issue 20, points 2 and 4), against moto on 127.0.0.1.

The driver reaches the server through a TCP proxy on 127.0.0.1; stopping the proxy refuses new connections
and drops open ones, exactly what a driver sees when the server stops, and starting it again is the
server's restart. Another driver (this test, straight to the server) is not affected by the outage.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from typing import Iterator

import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.store import lock as lock_module
from pipeline.store.lock import LOCK_KEY, LeaseLostError, RemoteRunLock, RunLockedError
from pipeline.store.remote import RunStore
from pipeline.store.run_folder import RunFolder
from tests.storage.conftest import S3Server, forget_clients
from tests.storage.test_lock_gc import TINY_JOB
from tests.storage.test_s3_run import trusted_bytes_on_store


class Outage:
    """A TCP proxy to the S3 server whose `stop()` and `start()` play the server stopping and restarting."""

    def __init__(self, target: tuple[str, int]):
        self.target = target
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            self.port = probe.getsockname()[1]
        self.endpoint = f"http://127.0.0.1:{self.port}"
        self._open: set[socket.socket] = set()
        self._guard = threading.Lock()
        self._serving = threading.Event()
        self._accepting: threading.Thread | None = None
        self.start()

    def start(self) -> None:
        listener = socket.socket()
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", self.port))
        listener.listen(64)
        listener.settimeout(0.1)
        self._serving.set()
        self._accepting = threading.Thread(target=self._accept, args=(listener,), daemon=True)
        self._accepting.start()

    def stop(self) -> None:
        """Refuse connections (the listener is closed) and drop every open one."""
        self._serving.clear()
        if self._accepting is not None:
            self._accepting.join(timeout=5)
        with self._guard:
            for connection in self._open:
                _close(connection)
            self._open.clear()

    def _accept(self, listener: socket.socket) -> None:
        with listener:
            while self._serving.is_set():
                try:
                    client, _ = listener.accept()
                except (socket.timeout, OSError):
                    continue
                try:
                    upstream = socket.create_connection(self.target, timeout=10)
                except OSError:
                    _close(client)
                    continue
                client.settimeout(None)
                with self._guard:
                    self._open.update((client, upstream))
                for source, sink in ((client, upstream), (upstream, client)):
                    threading.Thread(target=_pipe, args=(source, sink), daemon=True).start()


def _pipe(source: socket.socket, sink: socket.socket) -> None:
    try:
        while data := source.recv(65536):
            sink.sendall(data)
    except OSError:
        pass
    finally:
        _close(source)
        _close(sink)


def _close(connection: socket.socket) -> None:
    try:
        connection.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    connection.close()


@pytest.fixture
def outage(s3: S3Server, monkeypatch) -> Iterator[Outage]:
    """The driver's endpoint goes through the proxy; botocore does not retry, so an outage is seen at once.

    s3fs keeps one client per set of options: the driver's clients are made afresh for the proxy, and the
    session's client (`s3.fs`, shared with the code under test in other modules) is put back afterwards, so
    their listing caches stay one and the same.
    """
    host, port = s3.endpoint.removeprefix("http://").split(":")
    proxy = Outage((host, int(port)))
    clients = type(s3.fs)._cache  # fsspec's instance cache (no public way to put an instance back)
    saved = dict(clients)
    monkeypatch.setenv("AWS_ENDPOINT_URL", proxy.endpoint)
    monkeypatch.setenv("AWS_MAX_ATTEMPTS", "1")
    forget_clients()
    try:
        yield proxy
    finally:
        proxy.stop()
        monkeypatch.undo()
        forget_clients()
        clients.update(saved)


def lock_record(s3: S3Server, url: str) -> dict | None:
    try:
        return json.loads(s3.fs.cat_file(f"{url.removeprefix('s3://')}/{LOCK_KEY}"))
    except FileNotFoundError:
        return None


def wait_for(condition, seconds: float = 20.0) -> bool:
    deadline = time.monotonic() + seconds
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def invoke(*args: object):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_the_heartbeat_survives_an_outage_and_keeps_a_second_driver_out(s3, outage, monkeypatch):
    monkeypatch.setattr(lock_module, "HEARTBEAT_SECONDS", 0.2)
    monkeypatch.setattr(lock_module, "RETRY_SECONDS", 0.1)
    url = s3.url("runs/outage-heartbeat")
    with RemoteRunLock(RunStore(url)) as lock:
        outage.stop()
        time.sleep(2.0)  # about ten heartbeats fail
        outage.start()
        resumed = time.time()
        assert wait_for(lambda: lock_record(s3, url)["heartbeat"] > resumed), "the heartbeat never resumed"
        assert lock.lost is None
        lock.check()  # the lease holds: this driver goes on committing
        with pytest.raises(RunLockedError, match="already being run"):
            RemoteRunLock(RunStore(url)).__enter__()
    assert lock_record(s3, url) is None


def test_a_lapsed_lease_stops_commits_and_leaves_the_new_owner_alone(s3, outage, monkeypatch):
    monkeypatch.setattr(lock_module, "HEARTBEAT_SECONDS", 0.2)
    monkeypatch.setattr(lock_module, "RETRY_SECONDS", 0.1)
    monkeypatch.setattr(lock_module, "STALE_SECONDS", 2.0)  # a lease of 1 s
    url = s3.url("runs/outage-lease")
    run = RunFolder(url)
    with run.locked() as lock:
        outage.stop()
        assert wait_for(lambda: lock.lost is not None, 10), "the lease never lapsed"
        time.sleep(2.5)  # the lock is stale now: another driver takes it over, straight on the server
        other = {"host": "elsewhere", "pid": 7, "started": 0, "owner": "elsewhere.7.0", "heartbeat": time.time()}
        s3.fs.pipe_file(f"{url.removeprefix('s3://')}/{LOCK_KEY}", json.dumps(other).encode())
        outage.start()
        with pytest.raises(LeaseLostError, match="no heartbeat reached the run lock"):
            lock.check()
        staging = run.staging("fence", "u")
        (staging / "fence").mkdir()
        (staging / "fence" / "x.txt").write_text("x")
        with pytest.raises(LeaseLostError):
            run.commit_unit("fence", "u", staging, "", {}, 0.0, 1, time.time(), "host")
        worker = RunFolder(url)  # a Ray worker of this driver: it knows only the owner id, and reads the lock
        worker.fence = lock.owner
        with pytest.raises(LeaseLostError, match="now held by pid 7 on elsewhere"):
            worker.commit_unit("fence", "u", staging, "", {}, 0.0, 1, time.time(), "host")
        assert run.marker("fence", "u") is None and not run.store.exists("_attempts/fence")
    assert lock_record(s3, url)["owner"] == "elsewhere.7.0"  # release left the new owner's lock alone
    s3.fs.rm_file(f"{url.removeprefix('s3://')}/{LOCK_KEY}")


def test_an_outage_during_an_in_process_stage_is_one_line_and_releases_the_lock(s3, outage, tmp_path, monkeypatch):
    (tmp_path / "tiny.yaml").write_text(TINY_JOB, encoding="utf-8")
    url = s3.url("runs/outage-stage")
    first = invoke("submit", tmp_path / "tiny.yaml", "--run-dir", url, "--stages", "shard", "--executor", "local")
    assert first.exit_code == 0, first.output
    clean = trusted_bytes_on_store(s3, url)
    commit, release = RunFolder.commit_unit, RemoteRunLock.release

    def commit_into_an_outage(self, *args, **options):
        outage.stop()  # the server stops just as the first unit commits
        return commit(self, *args, **options)

    def restart_then_release(self):
        outage.start()  # and is back by the time the driver lets go of the run
        release(self)

    with monkeypatch.context() as patch:
        patch.setattr(RunFolder, "commit_unit", commit_into_an_outage)
        patch.setattr(RemoteRunLock, "release", restart_then_release)
        started = time.monotonic()
        result = invoke("rerun", url, "--stage", "shard", "--all", "--executor", "local")
    assert time.monotonic() - started < 120
    assert result.exit_code == 1 and isinstance(result.exception, (SystemExit, type(None))), result.output
    assert "Traceback" not in result.output
    last = result.output.strip().splitlines()[-1]
    assert last.startswith(f"error: {url}: the object store failed") and "rerun the same command" in last, result.output
    assert lock_record(s3, url) is None  # released
    again = invoke("rerun", url, "--stage", "shard", "--all", "--executor", "local")
    assert again.exit_code == 0 and "2 done, 0 failed" in again.output, again.output
    assert trusted_bytes_on_store(s3, url).keys() == clean.keys()
    assert all(trusted_bytes_on_store(s3, url)[p] == clean[p] for p in clean if not p.startswith("status/"))
