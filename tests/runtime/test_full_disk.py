"""A full disk (issue 20, point 9): one line naming the path and the free space, exit 1, the failed units
recorded with that reason, and a rerun after space is freed completes them bit-identically.

ENOSPC is injected at the Parquet write call (the call every table part goes through), not made by a
small file system: a tmpfs or loop mount needs privileges CI may not have, and the injection hits an
exact unit or the driver's own status write, which a real full disk would not do reproducibly.
"""

from __future__ import annotations

import errno
import hashlib
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.runtime.status import read_status
from pipeline.store.run_folder import RunFolder

JOB = "name: t\nseed: 0\nscenes: {procedural: {count: 2, seed: 0, detail: 0.05}}\nembodiments: [{name: e}]\n"


def invoke(*args: object):
    return CliRunner().invoke(app, [str(a) for a in args])


def digest(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for folder in ("scenes", "objects") for p in sorted((root / folder).rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> tuple[Path, Path]:
    """The job file and a clean run of its shard stage."""
    folder = tmp_path_factory.mktemp("full-disk")
    (folder / "job.yaml").write_text(JOB)
    result = invoke("submit", folder / "job.yaml", "--run-dir", folder / "clean", "--stages", "shard", "--executor", "local")
    assert result.exit_code == 0, result.output
    return folder / "job.yaml", folder / "clean"


def disk_full_at(monkeypatch: pytest.MonkeyPatch, fragment: str) -> None:
    """Parquet writes to a path containing `fragment` fail as on a full disk."""
    real = pq.write_table

    def write_table(table, where, *args, **options):
        if fragment in str(where):
            raise OSError(errno.ENOSPC, "No space left on device", str(where))
        return real(table, where, *args, **options)

    monkeypatch.setattr(pq, "write_table", write_table)


def test_units_on_a_full_disk_fail_with_path_and_free_space_and_a_rerun_completes_them(clean, tmp_path, monkeypatch):
    job, clean_run = clean
    run = tmp_path / "run"
    units = sorted(p.stem for p in (clean_run / "_state" / "shard").glob("*.json"))
    with monkeypatch.context() as patch:
        disk_full_at(patch, f"_staging/shard/{units[1]}.")
        result = invoke("submit", job, "--run-dir", run, "--stages", "shard", "--executor", "local")
    assert result.exit_code == 1 and not isinstance(result.exception, OSError), result.output
    assert "1 done, 1 failed" in result.output and "Traceback" not in result.output, result.output
    failed = read_status(RunFolder(run))[("shard", units[1])]
    assert failed.state == "failed" and f"_staging/shard/{units[1]}." in failed.message
    assert "no space left on device (" in failed.message and " MiB free)" in failed.message, failed.message
    status = invoke("status", run)
    assert status.exit_code == 1 and "MiB free" in status.output, status.output
    assert not (run / "_state" / "lock.json").exists()
    again = invoke("rerun", run, "--stage", "shard", "--executor", "local")  # space freed
    assert again.exit_code == 0 and "1 done, 0 failed, 1 up to date" in again.output, again.output
    assert digest(run) == digest(clean_run)


def test_a_full_disk_under_the_drivers_status_write_is_one_line_and_exit_1(clean, tmp_path, monkeypatch):
    job, clean_run = clean
    run = tmp_path / "run"
    with monkeypatch.context() as patch:
        disk_full_at(patch, "_staging/_status/")
        result = invoke("submit", job, "--run-dir", run, "--stages", "shard", "--executor", "local")
    assert result.exit_code == 1 and not isinstance(result.exception, OSError), result.output
    last = result.output.strip().splitlines()[-1]
    assert "_staging/_status/" in last and "no space left on device (" in last and "MiB free" in last, result.output
    assert not (run / "_state" / "lock.json").exists()
    again = invoke("submit", job, "--run-dir", run, "--stages", "shard", "--executor", "local")
    assert again.exit_code == 0 and "0 done, 0 failed, 2 up to date" in again.output, again.output
    assert digest(run) == digest(clean_run)
