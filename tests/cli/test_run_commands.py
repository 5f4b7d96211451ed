"""The `mvpd` job commands: exit codes and one-line errors on bad input, nothing written."""

from __future__ import annotations


from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.store.lock import RunLock

runner = CliRunner()
GOOD = "name: t\nscenes: {procedural: {count: 1}}\nembodiments: [{name: e}]\n"


def invoke(*args: str):
    return runner.invoke(app, [str(a) for a in args])


def test_misspelt_key_exits_2_with_one_line_and_writes_nothing(tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text(GOOD.replace("scenes:", "scenez:"))
    result = invoke("submit", job, "--run-dir", tmp_path / "run")
    assert result.exit_code == 2
    assert "scenez: unknown key" in result.output
    assert not (tmp_path / "run").exists()


def test_run_folder_that_is_not_one_is_refused(tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text(GOOD)
    other = tmp_path / "photos"
    other.mkdir()
    (other / "holiday.jpg").write_bytes(b"x")
    result = invoke("submit", job, "--run-dir", other)
    assert result.exit_code == 2 and "not empty and has no job.yaml" in result.output
    assert sorted(p.name for p in other.iterdir()) == ["holiday.jpg"]
    assert invoke("status", other).exit_code == 2


def test_second_submit_into_a_running_folder_is_refused(tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text(GOOD)
    (tmp_path / "run").mkdir()
    with RunLock(tmp_path / "run"):
        result = invoke("submit", job, "--run-dir", tmp_path / "run")
    assert result.exit_code == 2 and "already being run" in result.output
    assert not (tmp_path / "run" / "job.yaml").exists()


def test_unknown_stage_is_a_usage_error(tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text(GOOD)
    result = invoke("submit", job, "--run-dir", tmp_path / "run", "--stages", "shard,paint")
    assert result.exit_code == 2 and "unknown stage paint" in result.output


def test_query_with_bad_sql_names_the_tables(tmp_path):
    from pipeline.config import load_job
    from pipeline.store.run_folder import RunFolder

    job = tmp_path / "job.yaml"
    job.write_text(GOOD)
    RunFolder.create(tmp_path / "run", load_job(job))
    result = invoke("query", tmp_path / "run", "select * from nowhere")
    assert result.exit_code == 2 and "nowhere" in result.output
