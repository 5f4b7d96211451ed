"""Unusable input: exit 2, one line naming the file and the fix, and no run folder written."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app

runner = CliRunner()
EMBODIMENT = "[{name: e, sensor: {width: 64, height: 48}}]"


def submit(tmp_path: Path, job_text: str | bytes, run_dir: Path | None = None):
    job = tmp_path / "job.yaml"
    job.write_bytes(job_text if isinstance(job_text, bytes) else job_text.encode())
    run_dir = run_dir or tmp_path / "run"
    return runner.invoke(app, ["submit", str(job), "--run-dir", str(run_dir)]), run_dir


def assert_refused(result, run_dir: Path, words: str) -> None:
    assert result.exit_code == 2, result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
    assert words in result.output, result.output
    assert not run_dir.exists()


def test_binary_job_file(tmp_path):
    result, run_dir = submit(tmp_path, b"\x89PNG\r\n\x1a\n\xff\xfe\x00binary")
    assert_refused(result, run_dir, "not UTF-8")


@pytest.mark.parametrize("setup, scenes, words", [
    ("hm3d/a.semantic.txt", "{hm3dsem: {root: hm3d, scenes: [b]}}", "no b.semantic.txt"),
    ("hm3d/", "{hm3dsem: {root: hm3d}}", "no scene file matches '*.semantic.txt'"),
    ("meshes/", "{meshes: {root: meshes}}", "no scene file matches"),
    ("meshes/house.ply", "{meshes: {root: meshes, pattern: '*.obj'}}", "no scene file matches '*.obj'"),
])
def test_scene_sources_that_yield_no_scene(tmp_path, setup, scenes, words):
    target = tmp_path / setup
    if setup.endswith("/"):
        target.mkdir()
    else:
        target.parent.mkdir()
        target.write_text("")
    result, run_dir = submit(tmp_path, f"name: t\nscenes: {scenes}\nembodiments: {EMBODIMENT}\n")
    assert_refused(result, run_dir, words)


@pytest.mark.parametrize("key, value", [
    ("body: {radius: .inf}", "finite"), ("body: {height: .nan}", "finite"), ("sensor: {hfov: .inf}", "finite"),
    ("sensor: {width: 64, height: 48, far: .inf}", "finite"), ("placements: [.inf]", "finite"),
])
def test_non_finite_numbers(tmp_path, key, value):
    result, run_dir = submit(tmp_path, f"name: t\nscenes: {{procedural: {{count: 1}}}}\nembodiments: [{{name: e, {key}}}]\n")
    assert_refused(result, run_dir, value)


def test_non_finite_stage_number(tmp_path):
    result, run_dir = submit(tmp_path, f"name: t\nscenes: {{procedural: {{count: 1, detail: .nan}}}}\n"
                                       f"embodiments: {EMBODIMENT}\nplan: {{max_step: -.inf}}\n")
    assert_refused(result, run_dir, "finite")


@pytest.mark.parametrize("name", ["..", ".", "a/b", "../up", "a\\\\b"])
def test_job_names_that_would_be_paths(tmp_path, monkeypatch, name):
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")  # the run folder would be runs/<name> under here
    job = tmp_path / "job.yaml"
    job.write_text(f"name: '{name}'\nscenes: {{procedural: {{count: 1}}}}\nembodiments: {EMBODIMENT}\n")
    before = set(tmp_path.rglob("*"))
    result = runner.invoke(app, ["submit", str(job)])
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
    assert "name" in result.output
    assert set(tmp_path.rglob("*")) == before


GOOD = f"name: t\nscenes: {{procedural: {{count: 1}}}}\nembodiments: {EMBODIMENT}\n"


def test_run_folder_under_a_file(tmp_path):
    (tmp_path / "plain").write_text("a file, not a folder")
    result, run_dir = submit(tmp_path, GOOD, tmp_path / "plain" / "run")
    assert_refused(result, run_dir, "cannot create the run folder")


@pytest.fixture
def read_only_folder(tmp_path: Path):
    """An empty folder nothing can be written into: chmod 0o555, or (root ignores permissions) a read-only
    tmpfs mounted on it when the process may mount; skipped when neither makes it read-only."""
    folder = tmp_path / "ro"
    folder.mkdir()
    mounted = False
    if os.geteuid() == 0:
        mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(folder)],
                                 capture_output=True).returncode == 0
    else:
        folder.chmod(0o555)
    try:
        probe = folder / "probe"
        try:
            probe.mkdir()
        except OSError:
            yield folder
        else:
            probe.rmdir()
            pytest.skip("cannot make a read-only folder here (root without mount rights)")
    finally:
        if mounted:
            subprocess.run(["umount", str(folder)], check=True)
        folder.chmod(0o755)


def test_run_folder_on_a_read_only_file_system(tmp_path, read_only_folder):
    result, run_dir = submit(tmp_path, GOOD, read_only_folder / "run")
    assert_refused(result, run_dir, "cannot create the run folder")
    result, _ = submit(tmp_path, GOOD, read_only_folder)  # the read-only folder itself: empty, exists
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
    assert "cannot create the run lock" in result.output and not any(read_only_folder.iterdir())
