"""HM3DSem scenes: `<id>.glb` (coloured mesh), `<id>.semantic.glb` (the same geometry, each object
painted one flat colour, by vertex colours or a texture) and `<id>.semantic.txt` (a header line, then
`object_id,HEXCOLOR,"raw name",region_id` per object).

Reading: each face of the semantic mesh gets the colour of its vertices (or of its texture at the
face centre); that colour, as the integer 0xRRGGBB, is the object id when the table lists it. Colours
missing from the table become void (0) and are counted in `Scene.unknown_colors` (pure black is
the explicit void colour and not counted). Raw names map to mpcat40 through the Matterport table
(unmapped names are void categories). When the two meshes do not have the same triangles in the same
order, each face takes the label of the semantic face with the nearest centre.

Frames: HM3D declares its meshes +Z up. The reader rotates the file's frame into the world (+Y up)
with `to_world` = (x, y, z) -> (x, z, -y); the writer applies the exact inverse (x, y, z) -> (x, -z, y),
a permutation with one sign change, so float32 coordinates round-trip bit for bit.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from pipeline.scenes.categories import category_of
from pipeline.scenes.glb import GlbMesh, read_glb, write_glb
from pipeline.scenes.scans import integer_field, to_world, transfer_face_labels, up_axis_transform
from pipeline.scenes.scene import Scene, SceneError, SceneObject

HEADER = "HM3D Semantic Annotations"
VOID_COLOR = 0x000000
SEMANTIC_TXT = ".semantic.txt"
SEMANTIC_GLB = ".semantic.glb"
HEX_DIGITS = set("0123456789abcdefABCDEF")


# ----------------------------------------------------------------------------------------- reading


def _looks_like_row(line: str) -> bool:
    try:
        _row(Path(), 0, line)
    except SceneError:
        return False
    return True


def read_semantic_table(path: Path) -> dict[int, tuple[str, int]]:
    """colour (0xRRGGBB) -> (raw name, region) from a `.semantic.txt`; errors name file:line.

    As habitat-sim's HM3DSemanticScene.cpp reads it: a header line, blank lines skipped, the name's quotes
    dropped. It keys objects by the row's first field (the last of two rows wins); we fail naming both
    lines when an instance id or a colour is listed twice, since either would merge two objects."""
    try:
        lines = path.read_bytes().decode("utf-8-sig").splitlines()
    except FileNotFoundError:
        raise SceneError(f"{path}: missing semantic table; put the scene's .semantic.txt beside its .glb") from None
    except UnicodeDecodeError as error:
        raise SceneError(f"{path}: not UTF-8 text ({error.reason} at byte {error.start}); re-download the file") from None
    table: dict[int, tuple[str, int]] = {}
    seen: dict[str, dict[int, int]] = {"instance id": {}, "colour": {}}  # -> value -> line
    # The first line is a header ("HM3D Semantic Annotations"); a file without one starts with data.
    first = 1 if lines and not _looks_like_row(lines[0]) else 0
    for number, line in enumerate(lines[first:], start=first + 1):
        if not line.strip():
            continue
        instance, color, name, region = _row(path, number, line)
        for what, value in (("instance id", instance), ("colour", color)):
            if value in seen[what]:
                shown = f"{value:06X}" if what == "colour" else str(value)
                raise SceneError(f"{path}:{number}: {what} {shown} is also on line {seen[what][value]}; each object "
                                 "needs its own; fix or delete one line")
            seen[what][value] = number
        table[color] = (name, region)
    return table


def _row(path: Path, number: int, line: str) -> tuple[int, int, str, int]:
    """(instance id, colour, raw name, region) of one row; SceneError naming file:line when it is not one."""
    try:
        fields = next(csv.reader([line]))
        if len(fields) != 4 or len(fields[1].strip()) != 6 or not set(fields[1].strip()) <= HEX_DIGITS:
            raise ValueError("wrong field count or colour")
        instance, color, region = int(fields[0]), int(fields[1].strip(), 16), int(fields[3])
    except (ValueError, csv.Error):
        raise SceneError(f"{path}:{number}: expected `object_id,HEXCOLOR,\"raw name\",region_id`, got {line.strip()[:80]!r};"
                         " fix or delete the line") from None
    integer_field(region, f"{path}:{number}: region_id", -1, 2**31 - 1)
    return instance, color, fields[2], region


def _face_colors(mesh: GlbMesh, path: Path) -> np.ndarray:
    """(F,) int64 0xRRGGBB colour of each semantic face (vertex colour, or texture at the face centre)."""
    if mesh.vertex_colors is not None:
        rgb = mesh.vertex_colors[mesh.faces[:, 0]].astype(np.int64)
    elif mesh.vertex_uvs is not None and mesh.textures:
        rgb = np.zeros((len(mesh.faces), 3), np.int64)
        centre = mesh.vertex_uvs[mesh.faces].mean(axis=1)
        texture_of_face = mesh.vertex_texture[mesh.faces[:, 0]]
        for index, texture in enumerate(mesh.textures):
            select = texture_of_face == index
            h, w = texture.shape[:2]
            col = np.floor((centre[select, 0] % 1.0) * w).astype(np.int64).clip(0, w - 1)
            row = np.floor((centre[select, 1] % 1.0) * h).astype(np.int64).clip(0, h - 1)
            rgb[select] = texture[row, col, :3]
        untextured = texture_of_face < 0
        rgb[untextured] = mesh.base_colors[mesh.faces[untextured, 0]]
    else:
        rgb = mesh.base_colors[mesh.faces[:, 0]].astype(np.int64)
    return (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]


def _align_labels(geometry: GlbMesh, semantic: GlbMesh, semantic_colors: np.ndarray) -> np.ndarray:
    """Semantic colour for each face of the geometry mesh (same order, or nearest face centre)."""
    return transfer_face_labels(semantic.vertices, semantic.faces, semantic_colors, geometry.vertices, geometry.faces)


def _appearance(mesh: GlbMesh) -> dict:
    """Scene colour fields from a GLB: vertex colours, or UVs + textures (+ 1x1 textures for the rest)."""
    if mesh.vertex_colors is not None:
        return {"vertex_colors": mesh.vertex_colors}
    if mesh.vertex_uvs is None:
        return {"vertex_colors": mesh.base_colors}
    textures = list(mesh.textures)
    face_texture = mesh.vertex_texture[mesh.faces[:, 0]].astype(np.int64)
    untextured = face_texture < 0
    if untextured.any():
        # Faces without a texture get a one-pixel texture of their base colour, so one model fits all.
        colors, inverse = np.unique(mesh.base_colors[mesh.faces[untextured, 0]], axis=0, return_inverse=True)
        face_texture[untextured] = len(textures) + inverse.reshape(-1)
        textures += [c.reshape(1, 1, 3).astype(np.uint8) for c in colors]
    uvs = mesh.vertex_uvs[mesh.faces].copy()
    uvs[..., 1] = 1.0 - uvs[..., 1]  # glTF v runs down the image; the Scene's v runs up
    return {"face_uvs": uvs.astype(np.float32), "textures": textures, "face_material": face_texture.astype(np.uint16)}


def trio_stem(semantic_txt: Path) -> str:
    """The `<id>` every file of an HM3DSem trio is named after (`<id>.semantic.txt`, `<id>.glb`, ...)."""
    return semantic_txt.name[: -len(SEMANTIC_TXT)]


def hm3dsem_scene_id(semantic_txt: Path) -> str:
    """The scene id of an HM3DSem trio: in HM3D's own layout, `<NNNNN>-<id>/<id>.semantic.txt`, the numbered
    folder name (MVPd's video names and the `hm3d` split need it); elsewhere the files' `<id>`."""
    stem = trio_stem(semantic_txt)
    folder = semantic_txt.parent.name
    return folder if re.fullmatch(rf"\d{{5}}-{re.escape(stem)}", folder) else stem


def read_hm3dsem(semantic_txt: Path, up_axis: str = "z") -> Scene:
    """Read an HM3DSem trio given its `.semantic.txt` path; raises SceneError naming the bad file."""
    semantic_txt = Path(semantic_txt)
    if not semantic_txt.name.endswith(SEMANTIC_TXT):
        raise SceneError(f"{semantic_txt}: expected a *{SEMANTIC_TXT} file of an HM3DSem scene")
    stem = trio_stem(semantic_txt)
    glb_path = semantic_txt.with_name(stem + ".glb")
    semantic_path = semantic_txt.with_name(stem + SEMANTIC_GLB)
    for required in (semantic_txt, glb_path, semantic_path):
        if not required.is_file():
            raise SceneError(f"{required}: missing; an HM3DSem scene needs {stem}.glb, {stem}{SEMANTIC_GLB} and {stem}{SEMANTIC_TXT}")
    table = read_semantic_table(semantic_txt)
    geometry = read_glb(glb_path)
    semantic = read_glb(semantic_path)
    for mesh, path in ((geometry, glb_path), (semantic, semantic_path)):
        if len(mesh.faces) == 0:
            raise SceneError(f"{path}: the mesh is empty (0 triangles); check the file was exported with geometry")
        if not np.isfinite(mesh.vertices).all():
            bad = int((~np.isfinite(mesh.vertices)).any(axis=1).sum())
            raise SceneError(f"{path}: {bad} vertices are NaN or infinite; repair the mesh before using it")
    colors = _align_labels(geometry, semantic, _face_colors(semantic, semantic_path))
    known = np.array(sorted(table), dtype=np.int64)
    listed = np.isin(colors, known)
    face_ids = np.where(listed, colors, 0).astype(np.uint32)
    unknown = np.unique(colors[~listed])
    transform = up_axis_transform(up_axis)
    present = np.unique(face_ids[face_ids > 0])
    objects = {int(c): SceneObject(int(c), table[int(c)][0], category_of(table[int(c)][0]), table[int(c)][1]) for c in present}
    return Scene(
        scene_id=hm3dsem_scene_id(semantic_txt), vertices=to_world(geometry.vertices, transform), faces=geometry.faces.astype(np.int32),
        face_object_ids=face_ids, objects=objects, to_world=transform, source="hm3dsem", path=str(semantic_txt),
        unknown_colors=int((unknown != VOID_COLOR).sum()), **_appearance(geometry),
    )


# ----------------------------------------------------------------------------------------- writing


def _split_shared_vertices(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertices, faces and colours where no vertex is shared by faces of two objects (flat paint)."""
    per_vertex = np.zeros(len(scene.vertices), np.int64) - 1
    per_vertex[scene.faces.reshape(-1)] = np.repeat(scene.face_object_ids.astype(np.int64), 3)
    if np.array_equal(per_vertex[scene.faces], np.repeat(scene.face_object_ids[:, None].astype(np.int64), 3, 1)):
        return scene.vertices, scene.faces, scene.vertex_colors
    flat = scene.faces.reshape(-1)
    colors = scene.vertex_colors[flat] if scene.vertex_colors is not None else None
    return scene.vertices[flat], np.arange(len(flat), dtype=np.int64).reshape(-1, 3), colors


def write_hm3dsem(scene: Scene, out_dir: str | Path, up_axis: str = "z") -> Path:
    """Write `out_dir/<id>/<id>.glb`, `.semantic.glb` and `.semantic.txt`; returns the `.semantic.txt` path.

    Object ids must be 24-bit colours (they are painted as 0xRRGGBB); procedural houses are built so.
    The main GLB carries vertex colours (textured scenes are written with each face's mean colour).
    """
    too_large = [i for i in scene.objects if not 0 < i <= 0xFFFFFF]
    if too_large or (scene.face_object_ids > 0xFFFFFF).any():
        raise SceneError(f"{scene.scene_id}: object ids must be 1..0xFFFFFF to be painted as colours (e.g. {too_large[:3]})")
    folder = Path(out_dir) / scene.scene_id
    folder.mkdir(parents=True, exist_ok=True)
    vertices, faces, colors = _split_shared_vertices(scene)
    if colors is None:  # textured scene: bake each face's colour into its own vertices
        flat = faces.reshape(-1)
        colors = np.repeat(scene.face_colors(), 3, axis=0)
        vertices, faces = vertices[flat], np.arange(len(flat)).reshape(-1, 3)
    from_world = np.linalg.inv(up_axis_transform(up_axis))
    file_vertices = to_world(np.asarray(vertices, np.float32), np.round(from_world))
    ids = np.zeros(len(vertices), np.int64)
    ids[faces.reshape(-1)] = np.repeat(scene.face_object_ids.astype(np.int64), 3)
    paint = np.stack([(ids >> 16) & 255, (ids >> 8) & 255, ids & 255], 1).astype(np.uint8)
    write_glb(folder / f"{scene.scene_id}.glb", file_vertices, faces, colors, scene.scene_id)
    write_glb(folder / f"{scene.scene_id}{SEMANTIC_GLB}", file_vertices, faces, paint, f"{scene.scene_id}-semantic")
    lines = [HEADER]
    for number, object_id in enumerate(sorted(scene.objects), start=1):
        obj = scene.objects[object_id]
        name = obj.raw_name.replace('"', '""')
        lines.append(f'{number},{object_id:06X},"{name}",{obj.region}')
    text_path = folder / f"{scene.scene_id}{SEMANTIC_TXT}"
    temporary = text_path.with_name(f".{text_path.name}.tmp")
    temporary.write_text("\n".join(lines) + "\n", encoding="utf-8")
    temporary.replace(text_path)
    return text_path
