"""List the scenes of a job's scene sources, and load one (from a ref, a file or a `scenes` row).

Procedural houses are not stored: a house is regenerated from its seed and options on load, which is
deterministic and fast (a detail-0.1 house takes well under 2 s). Loaders are module-level functions
so that a `SceneRef` pickles by reference into a Ray task.
"""

from __future__ import annotations

import json
from pathlib import Path
from collections.abc import Callable, Mapping
from typing import Any

from pipeline.config import (Hm3dSemSource, Matterport3dSource, MeshFolderSource, ProceduralSource, ReplicaSource,
                             ScanDatasetSource, ScanNetSource, SceneSources)
from pipeline.scenes.trimesh_reader import MESH_SUFFIXES
from pipeline.scenes.procedural import procedural_scene_id
from pipeline.scenes.scene import Scene, SceneError, SceneRef

SEMANTIC_TXT = ".semantic.txt"
SEMANTIC_GLB = ".semantic.glb"


def list_scene_refs(sources: SceneSources) -> list[SceneRef]:
    """Every scene of the sources, sorted by scene id; raises SceneError on duplicate ids."""
    refs: list[SceneRef] = []
    if sources.procedural is not None:
        refs.extend(_procedural_refs(sources.procedural))
    if sources.hm3dsem is not None:
        refs.extend(_hm3dsem_refs(sources.hm3dsem))
    if sources.meshes is not None:
        refs.extend(_found(_mesh_refs(sources.meshes), "meshes", sources.meshes.root, sources.meshes.pattern))
    if sources.matterport3d is not None:
        refs.extend(_matterport3d_refs(sources.matterport3d))
    if sources.scannet is not None:
        refs.extend(_scannet_refs(sources.scannet))
    if sources.replica is not None:
        refs.extend(_replica_refs(sources.replica))
    refs.sort(key=lambda ref: ref.scene_id)
    ids = [ref.scene_id for ref in refs]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise SceneError(f"scenes: ids {duplicates} come from more than one file; rename the files or drop a source")
    return refs


def _found(refs: list[SceneRef], source: str, root: Path, pattern: str) -> list[SceneRef]:
    """`refs`, or a one-line SceneError when a named source holds no scene (a job must never run on nothing)."""
    if not refs:
        raise SceneError(f"{root}: no scene file matches {pattern!r}; fix scenes.{source}.root or its pattern")
    return refs


def _procedural_refs(source: ProceduralSource) -> list[SceneRef]:
    refs = []
    for index in range(source.count):
        seed = source.seed + index
        options = (
            ("seed", seed), ("detail", source.detail), ("min_rooms", source.min_rooms),
            ("max_rooms", source.max_rooms), ("floors", source.floors),
        )
        refs.append(SceneRef(procedural_scene_id(seed), "procedural", "", load_procedural, options))
    return refs


def _hm3dsem_refs(source: Hm3dSemSource) -> list[SceneRef]:
    from pipeline.scenes.hm3dsem import hm3dsem_scene_id

    found = {hm3dsem_scene_id(path): path for path in sorted(source.root.rglob(f"*{SEMANTIC_TXT}"))}
    refs = _wanted_refs(found, source, "hm3dsem", f"*{SEMANTIC_TXT}", load_hm3dsem, (("up_axis", source.up_axis),))
    for ref in refs:
        _refuse_basis_glb(Path(ref.path))
    return refs


def _refuse_basis_glb(semantic_txt: Path) -> None:
    """A scene whose folder holds habitat's `<stem>.basis.glb` but not the plain `<stem>.glb`: refused while the
    job is listed, since no well-kept Python package decodes Basis Universal textures (KHR_texture_basisu)."""
    from pipeline.scenes.hm3dsem import trio_stem

    stem = trio_stem(semantic_txt)
    plain = semantic_txt.with_name(f"{stem}.glb")
    basis = semantic_txt.with_name(f"{stem}.basis.glb")
    if basis.is_file() and not plain.is_file():
        raise SceneError(f"{basis}: Basis-compressed textures (habitat's variant) are not decoded; put HM3D's plain "
                         f"{plain.name} (the hm3d-*-glb download) beside it")


def _wanted_refs(found: dict[str, Path], source: ScanDatasetSource | Hm3dSemSource, kind: str, marker: str,
                 loader: Callable[[SceneRef], Scene], options: tuple[tuple[str, object], ...]) -> list[SceneRef]:
    """Refs of the scenes a dataset source wants (all found, or its `scenes` list); one-line errors when
    a listed scene or every scene is missing."""
    if not found:
        raise SceneError(f"{source.root}: no scene file matches {marker!r}; fix scenes.{kind}.root")
    wanted = source.scenes if source.scenes is not None else sorted(found)
    missing = [scene_id for scene_id in wanted if scene_id not in found]
    if missing:
        raise SceneError(f"{source.root}: no {marker.replace('*', missing[0])} found; fix scenes.{kind}.scenes or the root")
    return [SceneRef(scene_id, kind, str(found[scene_id]), loader, options) for scene_id in wanted]


def _matterport3d_refs(source: Matterport3dSource) -> list[SceneRef]:
    found = {path.stem: path for path in sorted(source.root.rglob("*.house"))}
    options = (("textured", source.textured), ("up_axis", source.up_axis))
    return _wanted_refs(found, source, "matterport3d", "*.house", load_matterport3d, options)


def _scannet_refs(source: ScanNetSource) -> list[SceneRef]:
    from pipeline.scenes.scannet import LABELS_TSV, SCANNET_MESH, SCANNETPP_MESH, scene_files

    meshes = sorted(source.root.rglob(f"*{SCANNET_MESH}"))
    meshes += sorted(p for p in source.root.rglob(SCANNETPP_MESH) if p.parent.name == "scans")
    found = {scene_files(path)[0]: path for path in meshes}
    tsv = source.labels_tsv or next(iter(sorted(source.root.rglob(LABELS_TSV))), None)
    if source.labels_tsv is not None and not source.labels_tsv.is_file():
        raise SceneError(f"{source.labels_tsv}: missing; fix scenes.scannet.labels_tsv or drop it")
    options = (("labels_tsv", str(tsv or "")), ("up_axis", source.up_axis))
    return _wanted_refs(found, source, "scannet", f"*{SCANNET_MESH} or */scans/{SCANNETPP_MESH}", load_scannet, options)


def _replica_refs(source: ReplicaSource) -> list[SceneRef]:
    from pipeline.scenes.replica import SEMANTIC_MESH

    found = {path.parent.parent.name: path for path in sorted(source.root.rglob(SEMANTIC_MESH))
             if path.parent.name == "habitat"}
    return _wanted_refs(found, source, "replica", f"*/habitat/{SEMANTIC_MESH}", load_replica, (("up_axis", source.up_axis),))


def _mesh_refs(source: MeshFolderSource) -> list[SceneRef]:
    paths = sorted(p for p in source.root.glob(source.pattern)
                   if p.is_file() and p.suffix.lower() in MESH_SUFFIXES and not _is_hm3dsem_part(p))
    options = (("keep_uniform_color", source.keep_uniform_color), ("labels", source.labels), ("scale", source.scale),
               ("up_axis", source.up_axis))
    return [SceneRef(_mesh_scene_id(path), "mesh", str(path), load_mesh, options) for path in paths]


def _is_hm3dsem_part(path: Path) -> bool:
    return path.name.endswith(SEMANTIC_GLB)


def _mesh_scene_id(path: Path) -> str:
    return path.name[: -len(path.suffix)] if path.suffix else path.name


# ------------------------------------------------------------------------------------------ loaders


def load_procedural(ref: SceneRef) -> Scene:
    """Generate the house of a procedural ref (deterministic from its seed and options)."""
    from pipeline.scenes.procedural.house import generate_house

    return generate_house(
        seed=int(ref.option("seed")),  # type: ignore[arg-type]
        detail=float(ref.option("detail", 0.1)),  # type: ignore[arg-type]
        min_rooms=int(ref.option("min_rooms", 3)),  # type: ignore[arg-type]
        max_rooms=int(ref.option("max_rooms", 8)),  # type: ignore[arg-type]
        floors=int(ref.option("floors", 1)),  # type: ignore[arg-type]
    )


def load_hm3dsem(ref: SceneRef) -> Scene:
    """Read an HM3DSem trio (`<id>.glb`, `<id>.semantic.glb`, `<id>.semantic.txt`)."""
    from pipeline.scenes.hm3dsem import read_hm3dsem

    return read_hm3dsem(Path(ref.path), up_axis=str(ref.option("up_axis", "z")))


def load_mesh(ref: SceneRef) -> Scene:
    """Read a mesh file through trimesh (OBJ, PLY, GLB / glTF, STL, OFF; see pipeline/scenes/meshes.py)."""
    from pipeline.scenes.meshes import read_labelled_mesh

    return read_labelled_mesh(Path(ref.path), up_axis=str(ref.option("up_axis", "y")),
                              labels=str(ref.option("labels", "auto")), scale=float(ref.option("scale", 1.0)),  # type: ignore[arg-type]
                              keep_uniform_color=bool(ref.option("keep_uniform_color", False)))


def load_matterport3d(ref: SceneRef) -> Scene:
    """Read a Matterport3D scan from its `.house` (pipeline/scenes/matterport3d.py)."""
    from pipeline.scenes.matterport3d import read_matterport3d

    return read_matterport3d(Path(ref.path), up_axis=str(ref.option("up_axis", "z")),
                             textured=bool(ref.option("textured", True)))


def load_scannet(ref: SceneRef) -> Scene:
    """Read a ScanNet v2 or ScanNet++ scene from its mesh (pipeline/scenes/scannet.py)."""
    from pipeline.scenes.scannet import read_scannet

    return read_scannet(Path(ref.path), up_axis=str(ref.option("up_axis", "z")),
                        labels_tsv=str(ref.option("labels_tsv", "")))


def load_replica(ref: SceneRef) -> Scene:
    """Read a Replica scene from its `habitat/mesh_semantic.ply` (pipeline/scenes/replica.py)."""
    from pipeline.scenes.replica import read_replica

    return read_replica(Path(ref.path), up_axis=str(ref.option("up_axis", "z")))


_LOADERS = {"procedural": load_procedural, "hm3dsem": load_hm3dsem, "mesh": load_mesh, "matterport3d": load_matterport3d,
            "scannet": load_scannet, "replica": load_replica}


def ref_from_row(row: Mapping[str, Any]) -> SceneRef:
    """Rebuild the SceneRef of a `scenes` table row (source, path and JSON options)."""
    source = str(row["source"])
    if source not in _LOADERS:
        raise SceneError(f"scenes row {row.get('scene_id')}: unknown source {source!r}; rerun `shard`")
    options = json.loads(row.get("options") or "{}")
    return SceneRef(str(row["scene_id"]), source, str(row.get("path") or ""), _LOADERS[source], tuple(sorted(options.items())))


def load_scene_row(row: Mapping[str, Any]) -> Scene:
    """Load (and validate) the scene of one row of the `scenes` table; what plan and render call."""
    return ref_from_row(row).load()


def options_json(ref: SceneRef) -> str:
    """The ref's options as canonical JSON (stored in the `scenes` table)."""
    return json.dumps(dict(ref.options), sort_keys=True, separators=(",", ":"))


def load_scene_file(path: str | Path, up_axis: str | None = None) -> Scene:
    """Load a scene from a file path, choosing the reader from the name.

    An HM3DSem trio is recognised by its `.semantic.txt` (or a `.glb` with a `.semantic.txt` beside
    it, or the `.semantic.glb`); a folder holding exactly one trio works too. A Matterport3D `.house`,
    a ScanNet `_vh_clean_2.ply` / ScanNet++ `scans/mesh_aligned_0.05.ply` and a Replica
    `habitat/mesh_semantic.ply` are read with their dataset's files. Anything else with a mesh suffix
    is read as a plain labelled mesh. `up_axis` defaults to "z" for HM3DSem and the datasets, "y" otherwise.
    """
    path = Path(path)
    if path.is_dir():
        trios = sorted(path.glob(f"*{SEMANTIC_TXT}"))
        if len(trios) != 1:
            raise SceneError(f"{path}: holds {len(trios)} *{SEMANTIC_TXT} files; give the scene's file instead")
        path = trios[0]
    trio_text = _hm3dsem_text_of(path)
    dataset_loader = _dataset_loader_of(path)
    if dataset_loader is not None:
        scene = dataset_loader(SceneRef(path.stem, "file", str(path), dataset_loader,
                                        (("up_axis", up_axis),) if up_axis else ()))
    elif trio_text is not None:
        from pipeline.scenes.hm3dsem import read_hm3dsem

        scene = read_hm3dsem(trio_text, up_axis=up_axis or "z")
    elif path.suffix.lower() in MESH_SUFFIXES:
        from pipeline.scenes.meshes import read_labelled_mesh

        scene = read_labelled_mesh(path, up_axis=up_axis or "y")
    else:
        raise SceneError(f"{path}: not a scene file; give a .semantic.txt or a mesh ({', '.join(MESH_SUFFIXES)})")
    scene.validate()
    return scene


def _dataset_loader_of(path: Path) -> Callable[[SceneRef], Scene] | None:
    """The scan dataset reader a file's name belongs to (a Matterport3D `.house`, a ScanNet / ScanNet++
    mesh, a Replica `habitat/mesh_semantic.ply`), or None."""
    from pipeline.scenes.replica import SEMANTIC_MESH
    from pipeline.scenes.scannet import SCANNET_MESH, SCANNETPP_MESH

    if path.suffix == ".house":
        return load_matterport3d
    if path.name.endswith(SCANNET_MESH) or (path.name == SCANNETPP_MESH and path.parent.name == "scans"):
        return load_scannet
    if path.name == SEMANTIC_MESH and path.parent.name == "habitat":
        return load_replica
    return None


def _hm3dsem_text_of(path: Path) -> Path | None:
    name = path.name
    if name.endswith(SEMANTIC_TXT):
        return path
    if name.endswith(SEMANTIC_GLB):
        return path.with_name(name[: -len(SEMANTIC_GLB)] + SEMANTIC_TXT)
    if path.suffix.lower() == ".glb":
        text = path.with_name(path.stem + SEMANTIC_TXT)
        return text if text.exists() else None
    return None
