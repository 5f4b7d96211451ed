"""The driver process: embedded Ray stays embedded whatever RAY_ADDRESS says; SIGTERM stops it like Ctrl-C."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
DEAD_ADDRESS = "127.0.0.1:9"  # the discard port: no Ray cluster answers there


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO), "RAY_USAGE_STATS_ENABLED": "0"}


def test_ray_address_of_a_dead_cluster_does_not_affect_a_local_run(monkeypatch):
    monkeypatch.setenv("RAY_ADDRESS", DEAD_ADDRESS)  # restored by monkeypatch after the test
    script = ("from pipeline.runtime.ray_session import ensure_ray\n"
              "import ray\n"
              "ensure_ray(num_cpus=1)\n"
              "print(ray.get(ray.remote(lambda: 6 * 7).remote()), len(ray.nodes()))\n")
    done = subprocess.run([sys.executable, "-c", script], env=_env(), capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["42", "1"]  # its own one-node Ray, not the address in the environment


SLOW_JOB = """
name: slow
scenes: {procedural: {count: 4}}
embodiments: [{name: e, sensor: {width: 64, height: 48}}]
plan: {trajectories_per_scene: 2, min_frames: 8, max_frames: 12}
"""


def test_sigterm_stops_submit_with_one_line_exit_143_and_the_lock_released(tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text(SLOW_JOB)
    run = tmp_path / "run"
    driver = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "submit", str(job), "--run-dir", str(run)],
                              env=_env(), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        # Wait until units run on Ray (their logs appear), so the signal lands in the middle of a stage.
        while not (run / "logs" / "shard").is_dir() and time.monotonic() < deadline and driver.poll() is None:
            time.sleep(0.2)
        assert driver.poll() is None, "the job ended before it could be stopped"
        driver.send_signal(signal.SIGTERM)
        _, stderr = driver.communicate(timeout=120)
    finally:
        if driver.poll() is None:
            driver.kill()
    assert driver.returncode == 143, stderr
    assert len(stderr.strip().splitlines()) == 1 and "SIGTERM" in stderr, stderr
    assert not (run / "_state" / "lock.json").exists()
