"""The `shard` stage: one unit per scene; loads it, checks it and writes its rows of `scenes` and `objects`.

A scene that cannot be read raises SceneError inside its unit; the runtime records the one-line
message in `status/` and the other scenes still shard. Later stages list the committed `scenes` rows
and re-load each scene with `pipeline.scenes.sources.load_scene_row`.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from pipeline.io.tables import to_table
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult
from pipeline.scenes.preview import floor_area
from pipeline.scenes.scene import Scene, SceneRef
from pipeline.scenes.sources import list_scene_refs, options_json, ref_from_row


class SceneSharder(Stage):
    """Lists the job's scenes and records each one's geometry summary and object table."""

    name = "shard"
    after = ()
    datasets = ("scenes", "objects")

    def units(self, run: RunFolder) -> list[Unit]:
        """One unit per scene, id = scene id, sorted; params say how to load it."""
        refs = list_scene_refs(self.job.scenes)
        return [Unit(ref.scene_id, {"source": ref.source, "path": ref.path, "options": json.loads(options_json(ref))})
                for ref in refs]

    def settings(self) -> dict[str, Any]:
        """The job's scene sources: a changed source (detail, seed, root) reshards."""
        return {"scenes": self.job.scenes.hashed()}

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        """Load the scene (raising SceneError if unusable) and write its `scenes` and `objects` rows."""
        ref = ref_from_row({"scene_id": unit.id, "source": unit.params["source"], "path": unit.params["path"],
                            "options": json.dumps(unit.params["options"], sort_keys=True)})
        scene = ref.load()
        context.log.info("scene %s: %d triangles, %d objects, %d unknown colours, %d degenerate faces dropped",
                         scene.scene_id, scene.triangle_count, len(scene.objects), scene.unknown_colors,
                         scene.degenerate_faces)
        context.write_table("scenes", to_table("scenes", [scene_row(scene, ref)]))
        context.write_table("objects", to_table("objects", object_rows(scene)))
        return UnitResult(info={"triangles": scene.triangle_count, "objects": len(scene.objects),
                                "unknown_colors": scene.unknown_colors, "degenerate_faces": scene.degenerate_faces})


def scene_row(scene: Scene, ref: SceneRef) -> dict[str, Any]:
    """The `scenes` row of a loaded scene."""
    low, high = scene.bounds()
    regions = {o.region for o in scene.objects.values() if o.region >= 0}
    return {
        "scene_id": scene.scene_id, "source": ref.source, "path": ref.path, "options": options_json(ref),
        "triangles": scene.triangle_count, "vertices": int(len(scene.vertices)),
        "min_x": low[0], "min_y": low[1], "min_z": low[2], "max_x": high[0], "max_y": high[1], "max_z": high[2],
        "object_count": len(scene.objects), "floor_area": floor_area(scene),
        "void_triangles": int((scene.face_object_ids == 0).sum()), "unknown_colors": int(scene.unknown_colors),
        "to_world": [float(v) for v in np.asarray(scene.to_world, np.float64).reshape(-1)],
        "room_count": len(regions) if regions else None, "degenerate_faces": int(scene.degenerate_faces),
    }


def object_rows(scene: Scene) -> list[dict[str, Any]]:
    """One `objects` row per object: bounding box, surface area and triangle count from its faces."""
    ids = scene.face_object_ids.astype(np.int64)
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    areas = scene.face_areas()[order]
    corners = scene.vertices[scene.faces[order]]  # (F, 3, 3) in the vertices' type: min / max need no float64 copy
    unique, starts, counts = np.unique(sorted_ids, return_index=True, return_counts=True)
    low = np.minimum.reduceat(corners.min(axis=1), starts, axis=0).astype(np.float64)
    high = np.maximum.reduceat(corners.max(axis=1), starts, axis=0).astype(np.float64)
    area = np.add.reduceat(areas, starts)
    position = {int(object_id): k for k, object_id in enumerate(unique)}
    rows = []
    for object_id in sorted(scene.objects):
        obj, k = scene.objects[object_id], position.get(object_id)
        if k is None:
            continue  # an object without faces is invisible: nothing to index
        rows.append({
            "scene_id": scene.scene_id, "object_id": object_id, "raw_name": obj.raw_name,
            "mpcat40_index": obj.category, "mpcat40_name": obj.category_name, "is_stuff": obj.is_stuff,
            "region": obj.region, "triangles": int(counts[k]),
            "min_x": low[k, 0], "min_y": low[k, 1], "min_z": low[k, 2],
            "max_x": high[k, 0], "max_y": high[k, 1], "max_z": high[k, 2], "surface_area": float(area[k]),
        })
    return rows
