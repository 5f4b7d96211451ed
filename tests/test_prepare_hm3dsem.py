"""deploy/prepare_hm3dsem.py: HM3D's download layout -> numbered scene ids the `hm3d` split mode needs."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from pipeline.config import Hm3dSemSource, SceneSources, SceneSplitConfig
from pipeline.scenes.sources import list_scene_refs
from pipeline.split.scenes import assign_scenes

SCRIPT = Path(__file__).resolve().parents[1] / "deploy" / "prepare_hm3dsem.py"


def load_script():
    spec = importlib.util.spec_from_file_location("prepare_hm3dsem", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def fake_download(root: Path, folders: list[str], without_glb: str = "") -> None:
    """HM3D's two archives per split: `<NNNNN>-<id>/<id>.glb` and `<NNNNN>-<id>/<id>.semantic.{glb,txt}`."""
    for folder in folders:
        scene = folder.split("-", 1)[1]
        annots = root / "hm3d-semantic-annots-v0.2" / folder
        annots.mkdir(parents=True)
        (annots / f"{scene}.semantic.glb").write_bytes(b"semantic " + folder.encode())
        (annots / f"{scene}.semantic.txt").write_text("HM3D Semantic Annotations\n")
        if folder != without_glb:
            (root / "hm3d-glb-v0.2" / folder).mkdir(parents=True)
            (root / "hm3d-glb-v0.2" / folder / f"{scene}.glb").write_bytes(b"mesh " + folder.encode())


def test_numbered_ids_split_as_hm3d(tmp_path):
    folders = ["00000-kfPV7w3FaU5", "00001-UVdNNRcVyV1", "00800-TEEsavR23oF", "00801-HaxA7YrQdEC"]
    fake_download(tmp_path / "downloads", folders)
    out = tmp_path / "hm3dsem"
    assert load_script().prepare(tmp_path / "downloads", out) == []
    placed = out / "00800-TEEsavR23oF" / "00800-TEEsavR23oF.glb"
    assert placed.read_bytes() == b"mesh 00800-TEEsavR23oF"  # the mesh of its own scene, unchanged
    refs = list_scene_refs(SceneSources(hm3dsem=Hm3dSemSource(root=out)))
    assert [ref.scene_id for ref in refs] == folders
    split = assign_scenes([ref.scene_id for ref in refs], SceneSplitConfig(mode="hm3d"), 0, set())
    assert split[folders[0]] == split[folders[1]] == "train"  # HM3D's 00000-00799
    assert sorted(split[f] for f in folders[2:]) == ["test", "val"]  # the held-out 008xx pool, halved


def test_a_scene_without_its_mesh_is_named_and_skipped(tmp_path):
    fake_download(tmp_path / "downloads", ["00000-kfPV7w3FaU5", "00800-TEEsavR23oF"], without_glb="00800-TEEsavR23oF")
    problems = load_script().prepare(tmp_path / "downloads", tmp_path / "out")
    assert len(problems) == 1 and problems[0].startswith("00800-TEEsavR23oF: no .glb file under")
    assert not (tmp_path / "out" / "00800-TEEsavR23oF").exists()
    assert (tmp_path / "out" / "00000-kfPV7w3FaU5" / "00000-kfPV7w3FaU5.semantic.txt").is_file()
