"""What a user meets on a damaged run, a runaway query and wrong input: an answer or one line, never a traceback."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.cli.test_confinement import invoke, make_run
from tests.demo_run import demo_shaped_run

RUNAWAY = "select sum(a.range * b.range) from range(1000000) a, range(1000000) b"


@pytest.fixture
def run(tmp_path: Path):
    return make_run(tmp_path / "run")


@pytest.fixture(scope="module")
def demo_run(ray_session, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return demo_shaped_run(tmp_path_factory)


def one_line(result, code: int, *words: str) -> None:
    assert result.exit_code == code, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in result.output, result.output
    for word in words:
        assert word in result.output, result.output


def test_status_answers_on_a_run_missing_a_shard_part(tmp_path, demo_run):
    damaged = tmp_path / "demo"
    shutil.copytree(demo_run, damaged)
    sorted((damaged / "scenes").glob("part-*.parquet"))[0].unlink()  # the split now sees 2 of 3 scenes
    result = invoke("status", damaged)
    assert result.exit_code == 1, result.output  # unhealthy, but answered
    assert "Traceback" not in result.output and "shard" in result.output and "render" in result.output
    assert "damaged: scenes/part-" in result.output
    assert "cannot be listed" in result.output and "fewer than the 3 splits" in result.output


def test_status_on_a_job_file_that_is_not_yaml(run):
    (run.root / "job.yaml").write_text("job: [unclosed\n")
    one_line(invoke("status", run.root), 2, "job.yaml: not valid YAML", "resubmit")


def test_a_runaway_query_stops_at_its_timeout(run):
    started = time.monotonic()
    result = invoke("query", run.root, RUNAWAY, "--timeout", "1")
    one_line(result, 1, "longer than 1 s", "--timeout")
    assert time.monotonic() - started < 30


@pytest.mark.parametrize("sent, code, words", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "SIGTERM")])
def test_a_running_query_stops_on_a_signal_with_one_line(run, sent, code, words):
    command = [sys.executable, "-m", "pipeline.cli.main", "query", str(run.root), RUNAWAY, "--timeout", "120"]
    # A shell may start children with SIGINT ignored; a user's terminal does not.
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(5)  # imported, connected and inside DuckDB
    sent_at = time.monotonic()
    process.send_signal(sent)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == code, stderr
    assert time.monotonic() - sent_at < 10
    assert [line for line in stderr.splitlines() if line.strip()] == [stderr.strip()] and words in stderr


def test_query_table_output_needs_no_pytz(run, monkeypatch):
    monkeypatch.setitem(sys.modules, "pytz", None)  # not installed: importing it raises
    result = invoke("query", run.root, "select now() as t, 1.5 as x")
    assert result.exit_code == 0, result.output
    assert "1.5" in result.output


def test_query_csv_quotes_only_where_needed(run):
    result = invoke("query", run.root, "select 'ambient' as kind, 'a,b' as pair, true as yes, 2 as n", "--format", "csv")
    assert result.exit_code == 0, result.output
    assert result.output.splitlines() == ["kind,pair,yes,n", 'ambient,"a,b",true,2']


@pytest.mark.parametrize("command", [["predict", "--model", "geometric", "--out", "{tmp}/p"],
                                     ["report", "--out", "{tmp}/r"]])
def test_an_unknown_split_is_one_line(tmp_path, run, command):
    arguments = [a.format(tmp=tmp_path) for a in command]
    result = invoke(arguments[0], run.root, *arguments[1:], "--split", "nosuch")
    one_line(result, 2, "split 'nosuch': unknown", "train, val, test")


def test_hints_with_brackets_survive_the_console(tmp_path, run):
    pytest.importorskip("pipeline.models.segmenter")
    if __import__("importlib").util.find_spec("ultralytics") is not None:
        pytest.skip("ultralytics is installed: its missing-extra hint cannot be shown")
    checkpoint = tmp_path / "model.pt"
    checkpoint.write_bytes(b"weights")
    model = tmp_path / "model.yaml"
    model.write_text(f"name: ultralytics\noptions: {{checkpoint: {checkpoint}}}\n")
    result = invoke("predict", run.root, "--model-file", model, "--out", tmp_path / "p")
    one_line(result, 2, "pip install 'mvpd-pipeline[ultralytics]'")


def test_a_scene_that_cannot_be_planned_points_to_the_plan_report(tmp_path):
    import trimesh

    (tmp_path / "meshes").mkdir()
    floating = trimesh.creation.box((1.0, 1.0, 1.0))
    floating.apply_translation((0.0, 3.0, 0.0))  # nothing to stand on
    floating.export(tmp_path / "meshes" / "floaty.obj")
    job = tmp_path / "job.yaml"
    job.write_text("name: nofloor\nscenes: {meshes: {root: meshes}}\n"
                   "embodiments: [{name: e, sensor: {width: 32, height: 24}, placements: [1.0]}]\n"
                   "plan: {trajectories_per_scene: 1, min_frames: 10, max_frames: 20}\n"
                   "split: {scenes: {mode: lists, lists: {train: [floaty], val: [], test: []}}}\n")
    result = invoke("submit", job, "--run-dir", tmp_path / "run", "--executor", "local")
    assert result.exit_code == 2, result.output
    assert "stage render had no units" in result.output and "mvpd plan report RUN" in result.output
    assert "run render first" not in result.output
