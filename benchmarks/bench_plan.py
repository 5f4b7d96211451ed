"""Plan-stage speed: navigable area of ~1 M-triangle scenes (target <= 5 s) and 50 trajectories after
that (target <= 2 s).

Scenes: generated houses at detail 1.0 (~1 M triangles, the size the target names) and a large box
house (4 x 4 rooms of 5 m, 400 m² of floor, 1.5 M triangles) as a stress case. Times include building
the ray-casting structure. Run: `cd /work/main && .venv/bin/python benchmarks/bench_plan.py`; numbers
are printed and written to benchmarks/results/plan.json.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from pipeline.config import Body, PlanConfig
from pipeline.plan.navigable import MeshQuery, compute_navigable_area
from pipeline.plan.paths import FloorPathSampler
from pipeline.plan.synthetic import house
from pipeline.scenes.procedural.house import generate_house
from pipeline.scenes.scene import Scene

AREA_TARGET_S = 5.0
PATHS_TARGET_S = 2.0
RESULTS = Path(__file__).resolve().parent / "results" / "plan.json"


def measure(scene: Scene, body: Body, plan: PlanConfig) -> dict:
    """Seconds to build the mesh query, the navigable area and 50 trajectories of one scene."""
    started = time.perf_counter()
    mesh = MeshQuery(scene.vertices, scene.faces)
    built = time.perf_counter()
    area = compute_navigable_area(mesh, body, plan.grid_resolution)
    computed = time.perf_counter()
    sampler = FloorPathSampler(area, mesh, body, plan)
    paths, report = sampler.draw(np.random.default_rng(0), plan.trajectories_per_scene)
    drawn = time.perf_counter()
    return {
        "scene": scene.scene_id, "triangles": scene.triangle_count,
        "navigable_m2": round(area.area_m2, 2), "islands": area.island_count, "grid": area.stats["grid"],
        "bvh_s": round(built - started, 3), "navigable_area_s": round(computed - started, 3),
        "trajectories": len(paths), "trajectories_s": round(drawn - computed, 3),
        "draws": report.as_dict(), "mean_frames": round(float(np.mean([p.trajectory.frame_count for p in paths])), 1)
        if paths else 0.0,
    }


def main() -> None:
    """Measure, print against the targets, write JSON."""
    body, plan = Body(), PlanConfig()
    scenes = [generate_house(seed=seed, detail=1.0) for seed in (0, 1, 2)]
    scenes.append(house(4, 4, subdivisions=5))
    results = []
    for scene in scenes:
        result = measure(scene, body, plan)
        results.append(result)
        area_ok = "ok" if result["navigable_area_s"] <= AREA_TARGET_S else "SLOW"
        paths_ok = "ok" if result["trajectories_s"] <= PATHS_TARGET_S else "SLOW"
        print(f"{result['scene']:>18}  {result['triangles']:>9,} triangles  {result['navigable_m2']:>7.1f} m²  "
              f"navigable area {result['navigable_area_s']:5.2f} s (target {AREA_TARGET_S} s: {area_ok}; "
              f"BVH {result['bvh_s']:.2f} s)  {result['trajectories']} trajectories {result['trajectories_s']:5.2f} s "
              f"(target {PATHS_TARGET_S} s: {paths_ok})  draws {result['draws']}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({
        "targets": {"navigable_area_s": AREA_TARGET_S, "trajectories_s": PATHS_TARGET_S},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "plan": plan.model_dump(mode="json"), "body": body.model_dump(mode="json"), "results": results,
    }, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
