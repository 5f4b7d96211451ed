"""Issue 29 (trust, round 3), points 1-5 and 11: a run folder no link leads out of, outputs that never write
into a file they do not own, answers on damaged runs, and run folders recognised by what `submit` writes.

Every symlink and hard-link test builds a victim folder outside the run and asserts that no byte of it
changed (names, sizes, contents and modification times of the whole tree, links not followed).
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from pipeline.cli.out_paths import TAG, OutPathError, check_out_folder
from pipeline.runtime.attempt import append_to_unit_log
from pipeline.store.garbage import GarbageReport, _collect_staging
from pipeline.store.links import RunLinkError
from pipeline.store.run_folder import RunFolder
from tests.cli.test_confinement import invoke, make_run
from tests.cli.test_trust import one_line
from tests.demo_run import DEMO_VIDEO, demo_shaped_run


def tree(folder: Path) -> dict[str, tuple]:
    """Every entry below `folder` (links not followed): kind, size, content hash and mtime in ns."""
    found = {}
    for dirpath, dirnames, filenames in os.walk(folder):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            info = path.lstat()
            content = (hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() and not path.is_symlink()
                       else os.readlink(path) if path.is_symlink() else "")
            found[str(path.relative_to(folder))] = (info.st_mode, info.st_size, content, info.st_mtime_ns)
    return found


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    """A user's folder outside the run, shaped like what the issue's commands deleted or wrote into."""
    root = tmp_path / "victim"
    for relative in ("photos/2024/a.jpg", "photos/2025/b.jpg", "thesis/chapters/1.tex", "render/x.host.1/part.bin",
                     "split/u.host.2/f.txt", "shard/s.log", "frames/part-s.e.parquet"):
        (root / relative).parent.mkdir(parents=True, exist_ok=True)
        (root / relative).write_bytes(f"precious {relative}\n".encode())
    return root


@pytest.fixture
def run(tmp_path: Path) -> RunFolder:
    return make_run(tmp_path / "run")


def linked(run: RunFolder, relative: str, target: Path) -> None:
    """Replace the run's `relative` (a folder or file) by a symbolic link to `target`."""
    path = run.root / relative
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.symlink_to(target)


# ----------------------------------------------------------------------------- point 1: _staging a link


def test_gc_never_deletes_through_a_linked_staging_folder(run, victim):
    before = tree(victim)
    linked(run, "_staging", victim)
    one_line(invoke("gc", run.root), 2, "_staging is a symbolic link", "rm ")
    assert tree(victim) == before
    with pytest.raises(RunLinkError):  # the guard below the up-front refusal, at the store's depth
        _collect_staging(run.root, GarbageReport(), lambda: None)
    assert tree(victim) == before


def test_rerun_never_deletes_or_writes_through_a_linked_staging_folder(run, victim):
    before = tree(victim)
    linked(run, "_staging", victim)
    one_line(invoke("rerun", run.root, "--stage", "render", "--all", "--executor", "local"), 2,
             "_staging is a symbolic link")
    assert tree(victim) == before
    for act in (lambda: run.staging("render", "x"), lambda: run.clear_staging("render")):
        with pytest.raises(RunLinkError):
            act()
    assert tree(victim) == before


def test_a_linked_data_folder_is_never_deleted_through(run, victim):
    before = tree(victim)
    linked(run, "frames", victim / "frames")
    with pytest.raises(RunLinkError):  # retiring the plan unit would delete frames/part-s.e.parquet
        run.retire("plan", ["s.e"])
    assert tree(victim) == before
    result = invoke("status", run.root)
    assert result.exit_code == 1 and "Traceback" not in result.output, result.output
    assert "frames is a symbolic link" in result.output and f"rm {run.root}/frames" in result.output


# --------------------------------------------------------------------------------- point 2: logs a link


def test_a_rerun_never_appends_to_logs_outside_the_run(run, victim):
    before = tree(victim)
    linked(run, "logs", victim)
    one_line(invoke("rerun", run.root, "--stage", "shard", "--executor", "local"), 2, "logs is a symbolic link")
    with pytest.raises(RunLinkError):
        append_to_unit_log(run, "shard", "s", "a line a driver adds")
    assert tree(victim) == before


def test_a_unit_log_that_is_a_link_is_never_appended_to(run, victim):
    before = tree(victim)
    linked(run, "logs/shard/s.log", victim / "shard" / "s.log")
    with pytest.raises(RunLinkError):
        append_to_unit_log(run, "shard", "s", "a line a driver adds")
    assert tree(victim) == before
    result = invoke("logs", run.root, "s")
    assert "precious" not in result.output and "Traceback" not in result.output, result.output


# ------------------------------------------------------------------------ point 3: a forged tag in a run


def test_preview_into_the_run_root_is_refused_whatever_a_tag_says(run):
    (run.root / TAG).write_text("mvpd preview\n")
    before = sorted(p.name for p in run.root.iterdir())
    one_line(invoke("preview", run.root, "v", "--embodiment", "e", "--out", run.root), 2, "is a run folder")
    assert sorted(p.name for p in run.root.iterdir()) == before
    for command in ("mvpd preview", "mvpd export", "mvpd report"):
        with pytest.raises(OutPathError, match="is a run folder"):
            check_out_folder(run.root, command)


# ------------------------------------------------------------- point 4: --out onto a hard link of a run file


@pytest.mark.parametrize("fmt", ["csv", "parquet", "json"])
def test_query_out_onto_a_hard_link_keeps_the_run_file(run, tmp_path, fmt):
    part = next((run.root / "frames").glob("part-*.parquet"))
    before = tree(run.root)
    out = tmp_path / f"o.{fmt}"
    os.link(part, out)
    result = invoke("query", run.root, "select 1 as x", "--format", fmt, "--out", out)
    assert result.exit_code == 0, result.output
    assert tree(run.root) == before  # the part's bytes, size and mtime as they were
    assert out.stat().st_ino != part.stat().st_ino and part.stat().st_nlink == 1
    if fmt == "parquet":
        assert pq.read_table(out).to_pylist() == [{"x": 1}]
    else:
        assert "1" in out.read_text()
    assert invoke("status", run.root).exit_code == 0


# ---------------------------------------------------------------------- point 11: a project's job.yaml


def test_a_folder_holding_a_job_yaml_is_no_run_folder(run, tmp_path):
    project = tmp_path / "project"
    (project / "sub").mkdir(parents=True)
    (project / "job.yaml").write_text("name: mine\n")
    for out in (project / "rows.csv", project / "sub" / "rows.csv"):
        result = invoke("query", run.root, "select 1 as x", "--format", "csv", "--out", out)
        assert result.exit_code == 0, result.output
        assert out.read_text() == "x\n1\n"
    # A real run is still one, from its first moment (its `_state/` folder), with or without its job file.
    one_line(invoke("query", run.root, "select 1 as x", "--format", "csv", "--out", run.root / "x.csv"), 2,
             "inside the run folder")
    (run.root / "job.yaml").unlink()
    one_line(invoke("query", tmp_path / "other", "select 1", "--out", run.root / "sub" / "x.csv"), 2,
             "inside the run folder")


# ----------------------------------------------------------------- on a demo-shaped run (render, videos)


@pytest.fixture(scope="module")
def demo_run(ray_session, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return demo_shaped_run(tmp_path_factory)


@pytest.fixture
def demo(tmp_path, demo_run) -> Path:
    copy = tmp_path / "demo"
    shutil.copytree(demo_run, copy, symlinks=True)
    return copy


def test_preview_into_its_own_folder_never_writes_into_a_hard_linked_file(tmp_path, demo):
    part = next((demo / "frames").glob("part-*.parquet"))
    before = tree(demo)
    out = tmp_path / "previews"
    out.mkdir()
    (out / TAG).write_text("mvpd preview\n")  # a folder preview wrote before, outside every run
    for suffix in ("png", "gif"):
        os.link(part, out / f"{DEMO_VIDEO}.{suffix}")
    result = invoke("preview", demo, DEMO_VIDEO, "--embodiment", "ambient", "--out", out)
    assert result.exit_code == 0, result.output
    assert tree(demo) == before
    assert (out / f"{DEMO_VIDEO}.png").read_bytes()[:4] == b"\x89PNG"


def unit_of(demo: Path, stage: str) -> str:
    return sorted(p.stem for p in (demo / "_state" / stage).glob("*.json"))[0]


def damage_index_folder(demo: Path) -> None:
    index = demo / "_state" / "render" / "_index.parquet"
    index.unlink()
    (index / "inside").mkdir(parents=True)


def damage_marker_folder(demo: Path) -> None:
    marker = demo / "_state" / "render" / f"{unit_of(demo, 'render')}.json"
    marker.unlink()
    (marker / "inside").mkdir(parents=True)


def damage_marker_nesting(demo: Path) -> None:
    (demo / "_state" / "render" / f"{unit_of(demo, 'render')}.json").write_text("[" * 200_000)


def answered(result, code: int = 1) -> None:
    assert result.exit_code == code and "Traceback" not in result.output, result.output


@pytest.mark.parametrize("damage", [damage_index_folder, damage_marker_folder, damage_marker_nesting])
def test_status_verify_rerun_and_gc_answer_and_rerun_repairs(demo, damage):
    damage(demo)
    status = invoke("status", demo)
    answered(status, 0 if damage is damage_index_folder else 1)
    if damage is not damage_index_folder:
        assert "no readable marker" in status.output and f"mvpd rerun {demo} --stage render" in status.output
    answered(invoke("status", demo, "--verify"), 0 if damage is damage_index_folder else 1)
    answered(invoke("gc", demo), 0)
    answered(invoke("rerun", demo, "--stage", "render", "--executor", "local"), 0)
    assert (demo / "_state" / "render" / "_index.parquet").is_file()
    answered(invoke("status", demo), 0)  # repaired: every marker readable, nothing damaged


def test_a_symlink_loop_in_videos_is_damage_and_refused_until_removed(demo):
    ambient = demo / "videos" / "ambient"
    shutil.rmtree(ambient)
    ambient.symlink_to(ambient)  # a loop: ELOOP for anything that follows it
    status = invoke("status", demo)
    answered(status)
    assert "videos/ambient is a symbolic link" in status.output and f"rm {ambient}" in status.output
    assert "passes through the symbolic link videos/ambient" in status.output
    answered(invoke("status", demo, "--verify"))
    one_line(invoke("rerun", demo, "--stage", "render", "--executor", "local"), 2, "videos/ambient is a symbolic link")
    one_line(invoke("gc", demo), 2, "videos/ambient is a symbolic link")
    ambient.unlink()  # the repair the line names; then rerun writes the videos again
    answered(invoke("rerun", demo, "--stage", "render", "--executor", "local"), 0)
    answered(invoke("status", demo), 0)
