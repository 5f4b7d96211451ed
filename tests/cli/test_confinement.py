"""`query`, `stats`, `logs`, `preview`, `import-mvpd` and `export` stay inside the run: reads only, names looked up."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.config import load_job
from pipeline.io.tables import spec
from pipeline.store.run_folder import RunFolder

runner = CliRunner()
JOB = "name: t\nscenes: {procedural: {count: 1}}\nembodiments: [{name: e}]\n"
ZERO = {pa.string(): "x", pa.bool_(): False}


def invoke(*args: object):
    return runner.invoke(app, [str(a) for a in args])


def _rows(dataset: str, count: int, **values: object) -> pa.Table:
    """`count` rows of a registered dataset: the given values, zero (or "x") elsewhere, frame = row index."""
    columns = {}
    for field in spec(dataset).schema:
        if field.name in values:
            columns[field.name] = [values[field.name]] * count
        elif field.name == "frame":
            columns[field.name] = list(range(count))
        elif pa.types.is_fixed_size_list(field.type):
            columns[field.name] = [[0.0] * field.type.list_size] * count
        else:
            columns[field.name] = [ZERO.get(field.type, 0)] * count
    return pa.Table.from_pydict(columns, schema=spec(dataset).schema)


def make_run(root: Path) -> RunFolder:
    """A run folder with a job, a frames + frame_stats + videos + segments dataset of 3 frames, and a log."""
    job_file = root.parent / f"{root.name}.job.yaml"
    job_file.write_text(JOB)
    run = RunFolder.create(root, load_job(job_file))
    key = {"embodiment": "e", "video_name": "v"}
    # Committed as plan and render units would (readers trust only parts a marker names).
    run.commit_tables("plan", "s.e", {"frames": _rows("frames", 3, **key, px=1.5)})
    run.commit_tables("render", "e.v", {
        "frame_stats": _rows("frame_stats", 3, **key, visible_objects=2, void_fraction=0.25),
        "videos": _rows("videos", 1, **key, scene_id="s", frames=3),
        "segments": _rows("segments", 3, **key, object_id=7, category=3, area=10)})
    (run.root / "videos" / "e").mkdir(parents=True)  # an embodiment folder a `*/<name>.zarr` pattern would walk from
    (run.root / "logs" / "shard").mkdir(parents=True)
    (run.root / "logs" / "shard" / "s.log").write_text("shard of s\n")
    return run


@pytest.fixture
def run(tmp_path: Path) -> RunFolder:
    return make_run(tmp_path / "run")


def test_query_reads_tables_and_joins_frame_stats_into_frames(run):
    result = invoke("query", run.root, "select count(*) n, sum(px) px, max(visible_objects) o from frames", "--format", "json")
    assert result.exit_code == 0, result.output
    assert result.output.endswith("]\n") and json.loads(result.output) == [{"n": 3, "px": 4.5, "o": 2}]


@pytest.mark.parametrize("sql, words", [
    ("select * from read_csv('/etc/passwd')", "disabled"),
    ("select * from read_text('/etc/hostname')", "disabled"),
    ("select * from glob('/etc/*')", "disabled"),
    ("select * from 'https://example.com/x.parquet'", "disabled"),
    ("COPY (select 1) TO '{outside}'", "only reads"),
    ("COPY (select * from frames) TO '{run}/frames/part-planted.parquet' (FORMAT parquet)", "only reads"),
    ("ATTACH '{outside}' AS other", "only reads"),
    ("INSTALL httpfs", "only reads"),
    ("LOAD httpfs", "only reads"),
    ("SET enable_external_access = true", "only reads"),
    ("select 1; COPY (select 1) TO '{outside}'", "exactly one"),
    ("EXPLAIN ANALYZE COPY (select 1) TO '{outside}'", "disabled"),
    ("create table planted as select 1", "only reads"),
])
def test_query_refuses_what_is_not_a_read_of_the_run(run, tmp_path, sql, words):
    outside = tmp_path / "outside.csv"
    before = sorted(p.relative_to(run.root) for p in run.root.rglob("*"))
    result = invoke("query", run.root, sql.format(outside=outside, run=run.root))
    assert result.exit_code == 2, result.output
    assert len(result.output.strip().splitlines()) == 1 and words in result.output
    assert not outside.exists()
    assert sorted(p.relative_to(run.root) for p in run.root.rglob("*")) == before


def test_connection_configuration_is_locked(run):
    from pipeline.io.query import connect

    connection = connect(run)
    with pytest.raises(Exception, match="locked"):
        connection.execute("SET enable_external_access = true")


@pytest.mark.parametrize("name", ["[v1]", "runs*", "what?", "a[!b]"])
def test_run_names_with_glob_characters_work_in_query_and_stats(tmp_path, name):
    run = make_run(tmp_path / name)
    decoy = make_run(tmp_path / "v")  # what `[v1]` would match as a pattern: must not be read
    decoy.commit_tables("plan", "extra", {"frames": _rows("frames", 5, embodiment="e", video_name="w")})
    result = invoke("query", run.root, "select count(*) from frames", "--format", "csv")
    assert result.exit_code == 0, result.output
    assert result.output.splitlines()[1] == "3"
    stats = invoke("stats", run.root)
    assert stats.exit_code == 0, stats.output
    assert "frames" in stats.output and "1 object instances" in stats.output


def test_query_json_keeps_numbers_as_numbers(run):
    result = invoke("query", run.root, "select 1::tinyint a, 2.5::decimal(4,1) b, 'x' c, 'inf'::double d, 'nan'::double e, 0.5::double f", "--format", "json")
    assert result.exit_code == 0, result.output
    assert result.output.endswith("\n") and json.loads(result.output) == [{"a": 1, "b": 2.5, "c": "x", "d": None, "e": None, "f": 0.5}]


@pytest.mark.parametrize("unit, stage", [
    ("../../../../etc/hostname", None), ("/etc/hostname", None), ("../shard/s", None), ("s", ".."), ("s", "../logs/shard"),
])
def test_logs_accepts_only_unit_ids_of_the_run(run, unit, stage):
    args = ["logs", run.root, unit] + (["--stage", stage] if stage else [])
    result = invoke(*args)
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
    assert "no log for unit" in result.output
    assert invoke("logs", run.root, "s").output.endswith("shard of s\n")


@pytest.mark.parametrize("video", ["../../../other/videos/e/v", "/abs/v", "..", "e/v"])
def test_preview_accepts_only_video_names_of_the_run(tmp_path, run, video):
    other = make_run(tmp_path / "other")
    (other.root / "videos" / "e" / "v.zarr").mkdir(parents=True)  # a store the traversal would reach
    result = invoke("preview", run.root, video, "--out", tmp_path / "out")
    assert result.exit_code == 2 and "no rendered video" in result.output, result.output
    assert not (tmp_path / "out").exists()


def test_reader_finds_no_video_outside_the_run(tmp_path, run):
    from pipeline.io.reader import VideoNotFoundError, load_video

    (tmp_path / "videos" / "e" / "v.zarr").mkdir(parents=True)
    with pytest.raises(VideoNotFoundError):
        load_video(run, "../../../videos/e/v", "e")


@pytest.mark.parametrize("split", ["../escape", "/tmp/x", ".."])
def test_export_and_import_split_names_stay_inside_their_roots(tmp_path, run, split):
    result = invoke("export", run.root, "--mvpd", tmp_path / "release", "--split", split)
    assert result.exit_code == 2 and "not a plain name" in result.output, result.output
    assert not (tmp_path / "release").exists() and not (tmp_path / "escape").exists()
    (tmp_path / "release" / "test").mkdir(parents=True)
    result = invoke("import-mvpd", tmp_path / "release", tmp_path / "imported", "--split", split)
    assert result.exit_code == 2 and "not a plain name" in result.output, result.output
    assert not (tmp_path / "imported").exists()
