"""Preview: `mvpd preview RUN VIDEO --out DIR` writes a GIF and a contact sheet of the right size."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.render.preview import GAP, id_colors, sheet_frames
from pipeline.store.run_folder import RunFolder
from tests.render.tiny_run import render_tiny_run

HIGH = "room.0000000000.0000001000"


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> RunFolder:
    return render_tiny_run(tmp_path_factory.mktemp("preview") / "run")


def test_preview_writes_gif_and_contact_sheet(run: RunFolder, tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["preview", str(run.root), HIGH, "--out", str(tmp_path), "--embodiment", "spot",
                                      "--rows", "3"])
    assert result.exit_code == 0, result.output
    sheet = np.asarray(Image.open(tmp_path / f"{HIGH}.png"))
    assert sheet.shape == (3 * 48 + 2 * GAP, 3 * 64 + 2 * GAP, 3)  # 3 rows of RGB | depth | panoptic
    gif = Image.open(tmp_path / f"{HIGH}.gif")
    assert gif.n_frames == 6 and gif.size == (3 * 64 + 2 * GAP, 48)


def test_preview_errors_are_one_line_with_the_fix(run: RunFolder, tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["preview", str(run.root), HIGH, "--out", str(tmp_path)])
    assert result.exit_code == 2 and "pass embodiment" in result.output
    result = CliRunner().invoke(app, ["preview", str(tmp_path / "nowhere"), HIGH, "--out", str(tmp_path)])
    assert result.exit_code == 2 and "not a run folder" in result.output


def test_id_colours_are_stable_and_void_is_black() -> None:
    ids = np.array([[0, 1, 2], [1, 0xFFFFFF, 2]], np.uint32)
    colors = id_colors(ids)
    assert np.all(colors[0, 0] == 0) and np.array_equal(colors[0, 1], colors[1, 0])
    assert not np.array_equal(colors[0, 1], colors[0, 2])


def test_sheet_frames_spread_over_the_video() -> None:
    assert sheet_frames(100, 5) == [0, 25, 50, 74, 99]
    assert sheet_frames(3, 6) == [0, 1, 2]
