"""`mvpd report` on the tiny run: tables, pictures, reuse, bad input."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from pipeline.cli.main import app

runner = CliRunner()


def test_report_writes_the_tables_and_pictures_and_reuses_what_is_done(run_root, tmp_path, ray_session) -> None:
    out = tmp_path / "report"
    args = ["report", str(run_root), "--models", "geometric,geometric+sp,oracle", "--embodiment", "ambient", "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    text = (out / "report.md").read_text()
    for heading in ("## VSQ per model", "## Per camera height", "## Zero-shot bucket", "## Per frame against self-prompting"):
        assert heading in text
    assert "| geometric+sp - geometric |" in text and "| oracle: 1 m - 0.1 m |" in text
    assert "missing: the run has no split" in text
    oracle_row = next(line for line in text.splitlines() if line.startswith("| oracle |"))
    assert "missing" not in oracle_row and float(oracle_row.split("|")[-2]) > 90.0
    for picture in ("vsq_by_k.png", "vsq_by_height.png", "strip.png"):
        assert (out / picture).stat().st_size > 1000 and f"({picture})" in text
    scores = {p: p.stat().st_mtime_ns for p in (out / "scores").iterdir()}
    assert len(scores) == 3
    again = runner.invoke(app, args)
    assert again.exit_code == 0 and again.output.count("2 up to date") >= 3
    assert {p: p.stat().st_mtime_ns for p in (out / "scores").iterdir()} == scores  # nothing re-scored


def test_report_with_an_unknown_model_exits_2_and_writes_nothing(run_root: Path, tmp_path) -> None:
    result = runner.invoke(app, ["report", str(run_root), "--models", "geometric,maskformer", "--out", str(tmp_path / "r")])
    assert result.exit_code == 2 and "unknown model 'maskformer'" in result.output
    assert not (tmp_path / "r").exists()
