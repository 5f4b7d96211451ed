"""Every `--out` is confined: never `/`, never inside a run folder (this one or another), never a non-empty
folder the command did not write; each refusal is one line, exit 2, and nothing is written."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.cli.out_paths import TAG, OutPathError, check_out_file, check_out_folder, out_folder
from tests.cli.test_confinement import invoke, make_run


@pytest.fixture
def run(tmp_path: Path):
    return make_run(tmp_path / "run")


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under `root` with its bytes."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def assert_refused(result, *words: str) -> None:
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), result.output
    assert "Traceback" not in result.output
    for word in words:
        assert word in result.output, result.output


def test_checks_refuse_root_runs_and_foreign_folders(tmp_path, run):
    other = make_run(tmp_path / "other")
    foreign = tmp_path / "home"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("mine")
    for path in (Path("/"), run.root / "job.yaml", run.root / "scenes" / "x.parquet", other.root / "deep" / "f.png"):
        with pytest.raises(OutPathError):
            check_out_file(path)
    for path in (Path("/"), run.root, run.root / "report", other.root / "new", foreign):
        with pytest.raises(OutPathError):
            check_out_folder(path, "mvpd report")
    with pytest.raises(OutPathError, match="is a folder"):
        check_out_file(foreign)
    assert check_out_file(tmp_path / "stats.png") == (tmp_path / "stats.png").resolve()
    assert check_out_folder(tmp_path / "new", "mvpd report") == (tmp_path / "new").resolve()


def test_a_folder_written_by_the_command_may_be_written_again_by_it_only(tmp_path):
    with out_folder(tmp_path / "out", "mvpd export") as folder:
        (folder / "train").mkdir(parents=True)
    assert (folder / TAG).read_text().strip() == "mvpd export"
    assert check_out_folder(folder, "mvpd export") == folder
    with pytest.raises(OutPathError, match="was not written by `mvpd report`"):
        check_out_folder(folder, "mvpd report")
    with out_folder(tmp_path / "untouched", "mvpd export"):
        pass  # a command that wrote nothing leaves no folder and no tag behind
    assert not (tmp_path / "untouched").exists()


@pytest.mark.parametrize("arguments", [
    ("view", "{run}", "v", "--out", "{run}/job.yaml"),
    ("view", "{run}", "v", "--out", "/"),
    ("stats", "{run}", "--out", "{run}/job.yaml"),
    ("query", "{run}", "select 1 x", "--format", "parquet", "--out", "{run}/scenes/part-x.parquet"),
    ("query", "{run}", "select 1 x", "--format", "csv", "--out", "{other}/result.csv"),
    ("report", "{run}", "--out", "/"),
    ("report", "{run}", "--out", "{other}/report"),
    ("report", "{run}", "--out", "{home}"),
    ("export", "{run}", "--mvpd", "{run}"),
    ("export", "{run}", "--mvpd", "{home}"),
    ("export", "{run}", "--coco", "{other}/coco"),
    ("evaluate", "{run}", "--pred", "{home}", "--out", "/"),
    ("predict", "{run}", "--model", "geometric", "--out", "{other}/preds"),
    ("preview", "{run}", "v", "--out", "{run}/previews"),
    ("plan", "preview", "{run}", "s", "--out", "{run}/plan.png"),
])
def test_every_out_is_refused_in_one_line_and_nothing_is_written(tmp_path, run, arguments):
    other = make_run(tmp_path / "other")
    home = tmp_path / "home"
    home.mkdir()
    (home / "thesis.tex").write_text("mine")
    before = {folder: snapshot(folder) for folder in (run.root, other.root, home)}
    result = invoke(*(a.format(run=run.root, other=other.root, home=home) for a in arguments))
    assert_refused(result, "--")
    assert {folder: snapshot(folder) for folder in before} == before


def test_query_out_writes_outside_runs(tmp_path, run):
    out = tmp_path / "result.csv"
    result = invoke("query", run.root, "select 1 as x", "--format", "csv", "--out", out)
    assert result.exit_code == 0, result.output
    assert out.read_text().splitlines() == ["x", "1"]
