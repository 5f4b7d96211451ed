"""A demo-shaped run built once per test session: the demo job's embodiments, scenes, split and video names,
at 64x48 pixels with a handful of frames, so commands written for `runs/demo` can run against it."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

DEMO_SHAPED_JOB = """
name: demo
seed: 0
scenes:
  procedural: {count: 3, seed: 0, detail: 0.05}
embodiments:
  - name: ambient
    sensor: {width: 64, height: 48, hfov: 69.0}
    placements: [1.0, 0.1]
    body: {radius: 0.15, height: 1.2}
    illumination: {kind: ambient}
  - name: spot20w
    sensor: {width: 64, height: 48, hfov: 69.0}
    placements: [1.0, 0.1]
    body: {radius: 0.15, height: 1.2}
    illumination: {kind: spot, power: 20.0, cone: 180.0, blend: 1.0}
plan: {trajectories_per_scene: 1, min_frames: 10, max_frames: 30}
split:
  scenes: {mode: fractions, fractions: {train: 0.34, val: 0.33, test: 0.33}}
  zero_shot: {encoder: tfidf, clusters: 10, unseen_fraction: 0.2}
"""
# The demo's first video: scene proc-000000, trajectory 0, camera at 0.1 m.
DEMO_VIDEO = "proc-000000.0000000000.0000000100"

_built: dict[str, Path] = {}


def demo_shaped_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The run folder (built on the first call of the session; needs the `ray_session` fixture active)."""
    if "run" not in _built:
        from pipeline.cli.main import app

        folder = tmp_path_factory.mktemp("demo-shaped")
        (folder / "demo.yaml").write_text(DEMO_SHAPED_JOB, encoding="utf-8")
        run = folder / "runs" / "demo"
        result = CliRunner().invoke(app, ["submit", str(folder / "demo.yaml"), "--run-dir", str(run)])
        assert result.exit_code == 0, result.output
        _built["run"] = run
    return _built["run"]
