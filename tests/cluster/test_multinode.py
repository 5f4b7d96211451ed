"""The demo-shaped job on a real two-node Ray cluster on this machine, with a node lost mid-render.

`local_cluster.py` runs a head node and a second node (real GCS and raylet processes, loopback only, a
temporary folder of their own) in a process of its own; `mvpd submit --address` runs in another, as a
user would run it against a cluster. While the render stage runs, the second node is killed: its
units must run again on the head node, the job must finish, a rerun must find nothing to do, and the
outputs must equal a single-node run's bit for bit (timing columns aside).
"""

from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Iterator

import pyarrow.parquet as pq
import pytest

from pipeline.store.markers import Marker
from pipeline.store.names import STATUS_STAGE
from pipeline.store.run_folder import as_run
from tests.demo_run import DEMO_SHAPED_JOB, demo_shaped_run

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
START_TIMEOUT_S = 120.0  # two raylets on 2 loaded cores
JOB_TIMEOUT_S = 600.0


class TwoNodeCluster:
    """The cluster process: its address, both node ids, and the command that kills the second node."""

    def __init__(self, process: subprocess.Popen[str]):
        self.process = process
        self._lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        info = json.loads(self.next_line(START_TIMEOUT_S))
        self.address: str = info["address"]
        self.head: str = info["head"]
        self.second: str = info["second"]

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self._lines.put(line)

    def next_line(self, timeout_s: float) -> str:
        try:
            return self._lines.get(timeout=timeout_s)
        except queue.Empty:
            raise AssertionError(f"the cluster process said nothing for {timeout_s:g} s") from None

    def remove_second_node(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write("remove\n")
        self.process.stdin.flush()
        assert self.next_line(START_TIMEOUT_S).strip() == "removed"

    def stop(self) -> None:
        """Shut the cluster down (end of stdin); killed after a minute, when Ray's reapers finish the job."""
        try:
            if self.process.stdin is not None:
                self.process.stdin.close()
            self.process.wait(timeout=60)
        except (subprocess.TimeoutExpired, BrokenPipeError):
            self.process.kill()
            self.process.wait(timeout=30)


def clean_environment() -> dict[str, str]:
    """This repo first on the path, loopback only; no ambient cluster address leaks in."""
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["RAY_USAGE_STATS_ENABLED"] = "0"
    # Ray turns a loopback address into the machine's outward IP unless "cluster mode" is off: off, every
    # node, driver and worker stays on 127.0.0.1 (the nodes are still separate raylets).
    env["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    return env


@pytest.fixture(scope="module")
def cluster() -> Iterator[TwoNodeCluster]:
    process = subprocess.Popen([sys.executable, str(HERE / "local_cluster.py")], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, text=True, env=clean_environment(), cwd=REPO)
    try:
        running = TwoNodeCluster(process)
    except BaseException:
        process.kill()
        process.wait(timeout=30)
        raise
    try:
        yield running
    finally:
        running.stop()


def mvpd(*args: str) -> subprocess.Popen[str]:
    """`mvpd ARGS` in a process of its own, as a user runs it against a cluster."""
    code = "from pipeline.cli.main import app; app()"
    return subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=clean_environment(), cwd=REPO)


def finish(process: subprocess.Popen[str], timeout_s: float = JOB_TIMEOUT_S) -> tuple[int, str]:
    """Exit code and output of an mvpd process; killed (and the test failed) after `timeout_s`."""
    try:
        output, _ = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        output, _ = process.communicate()
        raise AssertionError(f"mvpd did not finish in {timeout_s:g} s:\n{output[-3000:]}") from None
    return process.returncode, output


@pytest.fixture(scope="module")
def lost_node_run(cluster: TwoNodeCluster, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float, str]:
    """The job submitted to the cluster; the second node is killed while it runs a render unit.

    Returns the run folder, when the node was removed, and the render unit it was running then.
    """
    folder = tmp_path_factory.mktemp("cluster-job")
    (folder / "demo.yaml").write_text(DEMO_SHAPED_JOB, encoding="utf-8")
    run = folder / "runs" / "demo"
    submit = mvpd("submit", str(folder / "demo.yaml"), "--run-dir", str(run), "--address", cluster.address)
    deadline = time.monotonic() + JOB_TIMEOUT_S
    while (running := render_unit_running_on(run, cluster.second)) is None:
        assert submit.poll() is None, "the job ended before a render unit ran on the second node"
        assert time.monotonic() < deadline, "no render unit ran on the second node in time"
        time.sleep(0.02)
    cluster.remove_second_node()
    removed_at = time.time()
    code, output = finish(submit)
    assert code == 0, output[-3000:]
    return run, removed_at, running


def render_unit_running_on(run: Path, node: str) -> str | None:
    """A render unit whose log says it started on `node` and that has no marker yet (its first attempt)."""
    for log in sorted((run / "logs" / "render").glob("*.log")) if (run / "logs" / "render").is_dir() else []:
        unit = log.name.removesuffix(".log")
        if f"(Ray node {node})" in log.read_text() and not (run / "_state" / "render" / f"{unit}.json").exists():
            return unit
    return None


def all_markers(run: Path) -> dict[str, dict[str, Marker]]:
    stages = sorted(p.name for p in (run / "_state").iterdir() if p.is_dir() and not p.name.startswith("_"))
    return {stage: as_run(run).markers(stage) for stage in stages}


def test_units_ran_on_both_nodes_and_record_their_node(cluster: TwoNodeCluster, lost_node_run) -> None:
    run, _, _ = lost_node_run
    nodes = {m.node for markers in all_markers(run).values() for m in markers.values()}
    assert {cluster.head, cluster.second} <= nodes  # both nodes committed units
    assert nodes <= {cluster.head, cluster.second}  # and every unit says which


def test_units_of_the_lost_node_run_again_and_the_output_equals_a_single_node_run(
        cluster: TwoNodeCluster, lost_node_run, ray_session, tmp_path_factory: pytest.TempPathFactory) -> None:
    run, removed_at, lost_unit = lost_node_run
    markers = [m for stage in all_markers(run).values() for m in stage.values()]
    assert all(m.node == cluster.head for m in markers if m.finished_at > removed_at)  # nothing from a dead node
    # The unit that was running on the lost node ran again on the head: Ray's retry shows in its attempt.
    marker = as_run(run).markers("render")[lost_unit]
    assert marker.node == cluster.head and marker.attempt == 2, (marker.node, marker.attempt)
    assert "Ray retry 1" in (run / "logs" / "render" / f"{lost_unit}.log").read_text()
    code, output = finish(mvpd("rerun", str(run), "--stage", "render", "--address", cluster.address))
    assert code == 0 and "render: 0 done, 0 failed, 12 up to date (of 12)" in output, output[-2000:]
    single = demo_shaped_run(tmp_path_factory)
    assert trusted_contents(run) == trusted_contents(single)


def trusted_contents(run: Path) -> dict[str, object]:
    """Every file the markers name: Parquet parts as tables without timing columns, other files by CRC-32C."""
    contents: dict[str, object] = {}
    for stage, markers in all_markers(run).items():
        if stage == STATUS_STAGE:
            continue  # the status table records attempts, hosts and seconds
        for marker in markers.values():
            for file in marker.files:
                if file.path.endswith(".parquet"):
                    table = pq.read_table(run / file.path)
                    contents[file.path] = table.drop([c for c in table.column_names if c.endswith("seconds")])
                else:
                    contents[file.path] = file.crc32c
    assert contents
    return contents
