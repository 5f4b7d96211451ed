"""`mvpd status --verify` on a read-only run folder answers (issue 20, point 10).

The run is seen through a real read-only bind mount (the test runs as root, as CI does); where the machine
refuses mounts the test is skipped with that reason.
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Iterator

import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app

JOB = "name: t\nseed: 0\nscenes: {procedural: {count: 2, seed: 0, detail: 0.05}}\nembodiments: [{name: e}]\n"


def invoke(*args: object):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture
def read_only_run(tmp_path) -> Iterator[tuple[Path, Path]]:
    """(the run, the same run mounted read-only)."""
    (tmp_path / "job.yaml").write_text(JOB)
    run, view = tmp_path / "run", tmp_path / "read-only"
    result = invoke("submit", tmp_path / "job.yaml", "--run-dir", run, "--stages", "shard", "--executor", "local")
    assert result.exit_code == 0, result.output
    view.mkdir()
    mounted = subprocess.run(["mount", "--bind", run, view], capture_output=True, text=True)
    if mounted.returncode:
        pytest.skip(f"no bind mount here ({mounted.stderr.strip()})")
    try:
        subprocess.run(["mount", "-o", "remount,ro,bind", view], check=True, capture_output=True)
        yield run, view
    finally:
        subprocess.run(["umount", view], check=True)


def test_status_verify_on_a_read_only_run_answers(read_only_run):
    run, view = read_only_run
    with pytest.raises(OSError, match="Read-only file system"):
        (view / "probe").write_text("x")
    result = invoke("status", view, "--verify")
    assert result.exit_code == 0 and not isinstance(result.exception, OSError), result.output
    assert "shard" in result.output and "2" in result.output
    part = next((run / "scenes").glob("part-*.parquet"))  # a flipped byte, seen through the read-only view
    data = bytearray(part.read_bytes())
    data[len(data) // 2] ^= 0xFF
    part.write_bytes(bytes(data))
    result = invoke("status", view, "--verify")
    assert result.exit_code == 1 and not isinstance(result.exception, OSError), result.output
    assert f"scenes/{part.name} fails its checksum" in result.output
