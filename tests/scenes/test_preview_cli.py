"""Preview picture, stats and the `mvpd scenes` commands."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.scenes.preview import scene_stats, top_down_image
from pipeline.scenes.scene import Scene


def test_top_down_image_shows_walls_and_categories(small_house: Scene) -> None:
    image = top_down_image(small_house, size=256)
    assert image.shape[1] == 256 + 230 and image.dtype == np.uint8
    assert (image == [45, 45, 50]).all(axis=2).sum() > 500  # dark walls
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 10  # many category colours


def test_stats_count_rooms_and_categories(small_house: Scene) -> None:
    stats = scene_stats(small_house)
    assert stats["rooms"] >= 3 and stats["triangles"] == small_house.triangle_count
    walls = [o for o in small_house.objects.values() if o.category == 1]  # each room's walls and baseboard
    assert stats["objects_per_category"]["wall"] == len(walls) == 2 * stats["rooms"]


def test_floor_area_counts_a_rug_on_the_floor_once(small_house: Scene) -> None:
    from pipeline.scenes.preview import floor_area

    up = small_house.face_normals()[:, 1] > 0.9
    kind = {i: (o.category, o.raw_name) for i, o in small_house.objects.items()}
    floors = np.isin(small_house.face_object_ids, [i for i, k in kind.items() if k == (2, "floor")]) & up
    rugs = np.isin(small_house.face_object_ids, [i for i, k in kind.items() if k[0] == 2 and k[1] != "floor"]) & up
    exact = float(small_house.face_areas()[floors].sum())  # rugs lie inside the rooms' floors
    assert rugs.any() and exact <= floor_area(small_house) <= 1.01 * exact


def test_cli_generate_preview_stats(tmp_path: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["scenes", "generate", "--seed", "5", "--detail", "0.05", "--max-rooms", "4", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    folder = tmp_path / "proc-000005"
    assert sorted(p.name for p in folder.iterdir()) == ["proc-000005.glb", "proc-000005.preview.png",
                                                        "proc-000005.semantic.glb", "proc-000005.semantic.txt"]
    png = tmp_path / "top.png"
    result = runner.invoke(app, ["scenes", "preview", str(folder / "proc-000005.semantic.txt"), "--out", str(png), "--size", "200"])
    assert result.exit_code == 0, result.output
    assert cv2.imread(str(png)).shape[1] == 200 + 230
    result = runner.invoke(app, ["scenes", "stats", str(folder / "proc-000005.glb")])
    assert result.exit_code == 0 and "triangles" in result.output and "wall" in result.output


def test_cli_reports_a_bad_scene_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "x.semantic.txt"
    bad.write_text("header\n")
    result = CliRunner().invoke(app, ["scenes", "stats", str(bad)])
    assert result.exit_code == 2
