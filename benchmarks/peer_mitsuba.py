"""Mitsuba 3 peer of bench_light.py: renders a scene exported by it (`llvm_ad_rgb`), in its own virtualenv.

Run by bench_light.py as `/work/venvs/mitsuba/bin/python benchmarks/peer_mitsuba.py FOLDER`; install with
`bash benchmarks/setup_light_peers.sh` (on Debian 12 Dr.Jit's LLVM backend needs apt's `libllvm19`, found
through DRJIT_LIBLLVM_PATH). Reads the same FOLDER as peer_cycles.py (`scene.npz`, `poses.npy`,
`settings.json`) and writes `mitsuba_<name>.npz` (images (N, H, W, 3) float32 linear radiance, seconds
per frame, and CPU seconds of the process per frame) for each entry of `settings["mitsuba"]`: integrator `direct` or `path`, samples per pixel;
an entry with `aovs` (e.g. "depth:depth,id:shape_index") renders those AOVs instead (the `aov` integrator: bench_render.py).

The light is Mitsuba's `spot` with our intensity I = P / Omega (W/sr) and a 90-degree cutoff; its falloff is
linear in angle (Mitsuba's), not Blender's smoothstep, so its pixels are compared for speed, not for light.
Surfaces are `diffuse` with the vertex colour (a `mesh_attribute`). Timing covers `mi.render` and the copy
to numpy of each frame, after one warm-up frame that compiles the kernels.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

# OpenCV camera axes (x right, y down, z forward) -> Mitsuba's (x left, y up, z forward).
OPENCV_TO_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])


def house_mesh(folder: Path) -> mi.Mesh:
    """The exported triangles with their linear vertex colours as a diffuse Mitsuba mesh."""
    data = np.load(folder / "scene.npz")
    vertices, faces, colors = data["vertices"], data["faces"], data["colors"]
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}})
    mesh = mi.Mesh("house", len(vertices), len(faces), props=props, has_vertex_normals=False)
    mesh.add_attribute("vertex_color", 3, mi.Float(colors.astype(np.float32).ravel()))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params.update()
    return mesh


def render_all(folder: Path, settings: dict, mesh: mi.Mesh, poses: np.ndarray, render: dict) -> None:
    """Render every pose with one integrator; write `mitsuba_<name>.npz`."""
    intensity = settings["power"] / (2.0 * math.pi * (1.0 - math.cos(math.radians(settings["cone"]) / 2.0)))
    scene = mi.load_dict({
        "type": "scene", "house": mesh,
        "camera": {"type": "perspective", "fov": settings["hfov"], "fov_axis": "x",
                   "near_clip": settings["near"], "far_clip": settings["far"],
                   "film": {"type": "hdrfilm", "width": settings["width"], "height": settings["height"],
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": render["samples"]}},
        "spot": {"type": "spot", "intensity": {"type": "rgb", "value": [intensity] * 3},
                 "cutoff_angle": min(89.9, settings["cone"] / 2.0), "beam_width": 0.0},
        "integrator": ({"type": "aov", "aovs": render["aovs"]} if "aovs" in render else
                       {"type": render["integrator"], **({"max_depth": render["max_depth"]} if "max_depth" in render else {})}),
    })
    params = mi.traverse(scene)
    camera_key = next(key for key in params.keys() if key.endswith("to_world") and "camera" in key)
    light_key = next(key for key in params.keys() if key.endswith("to_world") and "spot" in key)
    images, seconds, cpu_seconds = [], [], []
    for index, pose in enumerate([poses[0], *poses]):  # the first frame warms the kernels up
        transform = mi.ScalarTransform4f(np.asarray(pose @ OPENCV_TO_MITSUBA, np.float64).tolist())
        params[camera_key] = transform
        params[light_key] = transform
        params.update()
        started, cpu_started = time.perf_counter(), time.process_time()
        image = np.array(mi.render(scene, spp=render["samples"], seed=index), np.float32)
        dr.sync_thread()
        if index > 0:
            seconds.append(time.perf_counter() - started)
            cpu_seconds.append(time.process_time() - cpu_started)
            images.append(image[..., :3])  # (an AOV render has as many channels as AOVs)
    np.savez(folder / f"mitsuba_{render['name']}.npz", images=np.stack(images), seconds=np.array(seconds),
             cpu_seconds=np.array(cpu_seconds))
    print(f"mitsuba {render['name']}: {np.median(seconds):.3f} s per frame", flush=True)


def main() -> None:
    folder = Path(sys.argv[1])
    settings = json.loads((folder / "settings.json").read_text())
    dr.set_thread_count(settings["threads"])
    poses = np.load(folder / "poses.npy")
    mesh = house_mesh(folder)
    for render in settings["mitsuba"]:
        render_all(folder, settings, mesh, poses, render)


if __name__ == "__main__":
    main()
