"""Any mesh without surprises: an OBJ whose MTL is missing, an OBJ whose materials are all one grey,
warnings summarised per file, a wrong unit named, and HM3D's Basis variant refused when listed."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.config import Job, SceneSources
from pipeline.scenes.meshes import read_labelled_mesh
from pipeline.scenes.scene import SceneError
from pipeline.scenes.sources import list_scene_refs
from tests.scenes.meshfiles import BOX_FACES, QUAD_FACES, box, floor_quad
from tests.scenes.test_heldout_meshes import _assert_coloured, _top_down_frame

FURNITURE = {"chair": 3, "table": 5, "bed": 11, "sofa": 10, "cabinet": 7, "toilet": 18, "sink": 15, "bathtub": 25}


def write_building_obj(folder: Path, grey_mtl: bool, copies: int = 1, object_lines: bool = False) -> Path:
    """A floor and furniture boxes, one `usemtl <name>_<k>` per object (with `object_lines`, an
    `o <name>_<k>` before it, as Blender exports), and an `mtllib` line; with `grey_mtl` the MTL declares
    every material with the same default grey, without it the MTL file is missing. `copies` repeats the
    furniture (more materials)."""
    lines = ["mtllib building.mtl"]
    offset, names = 1, []

    def emit(name: str, vertices: np.ndarray, faces: np.ndarray) -> None:
        nonlocal offset
        if object_lines:
            lines.append(f"o {name}")  # Blender writes the object name, then its material
        lines.extend(f"v {x:.4f} {y:.4f} {z:.4f}" for x, y, z in vertices)
        lines.append(f"usemtl {name}")
        lines.extend("f " + " ".join(str(i + offset) for i in face) for face in faces)
        offset += len(vertices)
        names.append(name)

    emit("floor_0", floor_quad(6.5), QUAD_FACES)
    for copy in range(copies):
        for k, name in enumerate(FURNITURE):  # a 4 x 2 grid per copy, copies further along +z
            low = (0.5 + 1.5 * (k % 4), 0.0, 0.5 + 1.5 * (k // 4 + 2 * copy))
            emit(f"{name}_{copy}", box(low, (low[0] + 1.0, 0.8, low[2] + 1.0)), BOX_FACES)
    if grey_mtl:
        (folder / "building.mtl").write_text("".join(f"newmtl {n}\nKd 0.8 0.8 0.8\nKa 1 1 1\nd 1\n\n" for n in names),
                                             encoding="utf-8")
    path = folder / "building.obj"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _job() -> Job:
    return Job.model_validate({"name": "m", "scenes": {"procedural": {"count": 1}},
                               "embodiments": [{"name": "cam", "sensor": {"width": 64, "height": 48}}]})


@pytest.mark.parametrize("grey_mtl", [False, True], ids=["mtl_missing", "all_grey_mtl"])
def test_objects_come_from_usemtl_names_and_frames_are_not_flat(tmp_path: Path, grey_mtl: bool,
                                                                caplog: pytest.LogCaptureFixture) -> None:
    path = write_building_obj(tmp_path, grey_mtl)
    with caplog.at_level(logging.WARNING):
        scene = read_labelled_mesh(path)
    names = {o.raw_name: o.category for o in scene.objects.values()}
    assert names == {"floor_0": 2, **{f"{n}_0": c for n, c in FURNITURE.items()}}  # "chair_0" maps as chair
    _assert_coloured(_top_down_frame(scene, _job()))
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1
    assert ("building.mtl is missing" in warned[0]) if not grey_mtl else ("same colour (204, 204, 204)" in warned[0])


def test_a_uniform_colour_is_kept_when_asked(tmp_path: Path) -> None:
    scene = read_labelled_mesh(write_building_obj(tmp_path, grey_mtl=True), keep_uniform_color=True)
    assert np.unique(scene.face_colors(), axis=0).tolist() == [[204, 204, 204]]


def test_many_materials_without_mtl_warn_once(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # 81 materials and Blender's `o` lines, as in the issue (the old reader warned once per material).
    path = write_building_obj(tmp_path, grey_mtl=False, copies=10, object_lines=True)
    with caplog.at_level(logging.WARNING):
        scene = read_labelled_mesh(path)
    assert len(scene.objects) == 81
    assert len(caplog.records) == 1 and "81 `usemtl` (and `o` / `g`) names" in caplog.records[0].getMessage()


@pytest.mark.parametrize("scale, unit", [(100.0, "centimetres: set scale: 0.01"), (1000.0, "millimetres: set scale: 0.001")])
def test_an_unlikely_extent_names_the_unit_and_the_option(tmp_path: Path, scale: float, unit: str,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "big.obj"
    lines = [f"v {x * scale} {y * scale} {z * scale}" for x, y, z in box((0, 0, 0), (25.0, 3.0, 12.0))]
    path.write_text("\n".join(lines + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in BOX_FACES]) + "\n", encoding="utf-8")
    with caplog.at_level(logging.WARNING):
        read_labelled_mesh(path)
    assert sum(unit in r.getMessage() for r in caplog.records) == 1
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        scene = read_labelled_mesh(path, scale=1.0 / scale)
    assert not any("across" in r.getMessage() for r in caplog.records)
    assert np.allclose(scene.bounds()[1], [25.0, 3.0, 12.0], rtol=1e-5)


def test_a_tiny_extent_is_named(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "tiny.obj"
    lines = [f"v {x} {y} {z}" for x, y, z in box((0, 0, 0), (0.25, 0.03, 0.12))]
    path.write_text("\n".join(lines + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in BOX_FACES]) + "\n", encoding="utf-8")
    with caplog.at_level(logging.WARNING):
        read_labelled_mesh(path)
    assert sum("0.25 m across" in r.getMessage() and "scale" in r.getMessage() for r in caplog.records) == 1


def test_hm3ds_own_layout_names_the_scene_after_its_numbered_folder(house_files: Path, tmp_path: Path) -> None:
    stem = house_files.name[: -len(".semantic.txt")]
    numbered, flat = tmp_path / "hm3d" / "00800-TEEsavR23oF", tmp_path / "hm3d" / "flat"
    for folder, name in ((numbered, "TEEsavR23oF"), (flat, "ownname")):  # HM3D's <NNNNN>-<id>/<id>.*; any other folder
        folder.mkdir(parents=True)
        for suffix in (".semantic.txt", ".semantic.glb", ".glb"):
            shutil.copy(house_files.with_name(stem + suffix), folder / f"{name}{suffix}")
    refs = list_scene_refs(SceneSources.model_validate({"hm3dsem": {"root": str(tmp_path / "hm3d")}}))
    assert [r.scene_id for r in refs] == ["00800-TEEsavR23oF", "ownname"]  # MVPd's video names need the number
    assert [r.load().scene_id for r in refs] == ["00800-TEEsavR23oF", "ownname"]


def test_a_basis_glb_without_the_plain_glb_is_refused_when_listed(house_files: Path, tmp_path: Path) -> None:
    folder = tmp_path / "hm3d" / "00009-basis"
    folder.mkdir(parents=True)
    stem = house_files.name[: -len(".semantic.txt")]
    for suffix in (".semantic.txt", ".semantic.glb"):
        shutil.copy(house_files.with_name(stem + suffix), folder / f"00009-basis{suffix}")
    shutil.copy(house_files.with_name(stem + ".glb"), folder / "00009-basis.basis.glb")
    sources = SceneSources.model_validate({"hm3dsem": {"root": str(tmp_path / "hm3d")}})
    with pytest.raises(SceneError, match=r"00009-basis\.basis\.glb: Basis-compressed .* put HM3D's plain 00009-basis\.glb"):
        list_scene_refs(sources)
    shutil.copy(house_files.with_name(stem + ".glb"), folder / "00009-basis.glb")
    assert [r.scene_id for r in list_scene_refs(sources)] == ["00009-basis"]
