"""Render benchmark: end-to-end fps at 640x480 on a ~1 M-triangle house, vs pyrender (OSMesa), memory, bytes.

Run: `cd /work/main && .venv/bin/python benchmarks/bench_render.py [--frames 96] [--skip-pyrender]`.
Against warm Mitsuba 3 (issue 31; its virtualenv: benchmarks/setup_light_peers.sh): `--vs-mitsuba --frames 32
[--baseline WORKTREE_OF_AN_OLDER_COMMIT]`: ambient and direct-only spot end to end and cast + depth + ids
against Mitsuba's `direct` 1 spp and `aov` (depth + shape id), 2 threads each, CPU and wall per frame, taking
turns (median of --repeats turns, with spread and the load), into results/render_vs_mitsuba.json. Its poses are
4 runs of consecutive frames from the middle of 4 planned videos (what a renderer meets: its cast reuses the
last frame's visible triangles), not frames spread over every pose as below.
Targets (issue #5): >= 30 fps end to end (ray cast + every buffer + Zarr write) on 2 cores; >= 3x the fps of
pyrender with OSMesa (a lit colour + depth pass plus a flat label pass); <= 2 GiB peak memory of a worker;
<= 150 kB stored per frame (rgb + depth + panoptic, lossless). Results go to benchmarks/results/render.json.

The house is `pipeline.scenes.procedural.house.generate_house(detail=1.0)` when the scenes package has it,
otherwise a synthetic house of the same size built here (the JSON says which). The frames are spread
evenly over every planned pose (four trajectories), so the bytes per frame are the trajectories' average,
not one corridor's: a frame's chunk is compressed on its own, and 96-frame windows of one path range from
35 to 150 kB.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import pickle
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

# MVPD_TREE: the checkout whose pipeline a `--child` process times (`--baseline`: an older commit's worktree).
sys.path.insert(0, os.environ.get("MVPD_TREE") or str(Path(__file__).resolve().parents[1]))

from pipeline.config import Embodiment, Illumination, Sensor  # noqa: E402
from pipeline.io.segments import frame_segments  # noqa: E402
from pipeline.io.zarr_video import VideoWriter  # noqa: E402
from pipeline.render.lighting import SurfaceColors  # noqa: E402
from pipeline.render.raycaster import SceneRaycaster, available_cpus  # noqa: E402
from pipeline.render.renderer import (  # noqa: E402
    SceneLabels, VideoRenderer, camera_of, limit_worker_threads)
from pipeline.render import renderer as renderer_module  # noqa: E402
from pipeline.render.sensors import depth_to_millimetres  # noqa: E402
from pipeline.render.stage import ZSTD_LEVEL, directory_bytes, video_attributes  # noqa: E402
from pipeline.runtime.executor import UnitFailedError  # noqa: E402
from pipeline.scenes.scene import Scene, SceneObject  # noqa: E402

TARGET_FPS = 30.0
TARGET_SPEEDUP = 3.0
TARGET_PEAK_GIB = 2.0
TARGET_KB_PER_FRAME = 150.0
# Issue 31, CPU time per frame against warm Mitsuba 3 (llvm_ad_rgb, same threads, same poses, same run).
TARGETS_VS_MITSUBA = {"ambient_vs_direct1": 2.0, "spot_direct_vs_direct1": 1.5, "cast_depth_ids_vs_aov": 2.0}
MITSUBA_RENDERS = [{"name": "direct1", "integrator": "direct", "samples": 1},
                   {"name": "aov", "integrator": "aov", "samples": 1, "aovs": "depth:depth,id:shape_index"}]
EXPOSURE = 4.0  # a fixed exposure (20 W light: white at 1 m ~ full scale)
PHASES = ("cast", "buffers", "segments", "zarr")  # of a frame in run_ours (buffers: shading, depth and ids)


def spot_body() -> Embodiment:
    """MVPd's camera (640x480, 69 degrees) with a 20 W, 180-degree spot light."""
    return Embodiment(name="bench", sensor=Sensor(), illumination=Illumination(kind="spot", power=20.0))


# ------------------------------------------------------------------------------------------ scene


def generated_house() -> tuple[Scene, str]:
    """The project's procedural house at detail 1.0, or a synthetic stand-in of ~1 M triangles."""
    try:
        from pipeline.scenes.procedural.house import generate_house
    except ImportError:
        return synthetic_house(), "synthetic (pipeline.scenes.procedural.house not available)"
    return generate_house(seed=0, detail=1.0), "pipeline.scenes.procedural.house.generate_house(seed=0, detail=1.0)"


def _grid(origin: np.ndarray, axis_u: np.ndarray, axis_v: np.ndarray, cells_u: int, cells_v: int
          ) -> tuple[np.ndarray, np.ndarray]:
    u, v = np.meshgrid(np.linspace(0, 1, cells_u + 1), np.linspace(0, 1, cells_v + 1))
    vertices = origin + u.reshape(-1, 1) * axis_u + v.reshape(-1, 1) * axis_v
    index = np.arange((cells_u + 1) * (cells_v + 1)).reshape(cells_v + 1, cells_u + 1)
    a, b, c, d = index[:-1, :-1], index[:-1, 1:], index[1:, 1:], index[1:, :-1]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return vertices, faces


def synthetic_house(rooms_x: int = 4, rooms_z: int = 3, room: float = 4.0, wall: float = 2.6) -> Scene:
    """Rooms on a grid (floors, ceilings, walls with door gaps) and furniture boxes, tessellated to ~1 M triangles."""
    rng = np.random.default_rng(0)
    parts: list[tuple[np.ndarray, np.ndarray, int, tuple[int, int, int]]] = []
    objects: dict[int, SceneObject] = {}

    def add(vertices: np.ndarray, faces: np.ndarray, object_id: int, name: str, category: int) -> None:
        color = tuple(int(c) for c in rng.integers(40, 230, 3))
        parts.append((vertices, faces, object_id, color))  # type: ignore[arg-type]
        objects.setdefault(object_id, SceneObject(object_id, name, category))

    next_id = 1
    cells = 60  # 6.7 cm tessellation: scanned meshes are dense everywhere, not only where detail is
    for i in range(rooms_x):
        for k in range(rooms_z):
            x0, z0 = i * room, k * room
            add(*_grid(np.array([x0, 0, z0]), np.array([room, 0, 0]), np.array([0, 0, room]), cells, cells),
                next_id, "floor", 2)
            add(*_grid(np.array([x0, wall, z0]), np.array([room, 0, 0]), np.array([0, 0, room]), cells, cells),
                next_id + 1, "ceiling", 17)
            for side in range(4):
                origin = [np.array([x0, 0, z0]), np.array([x0 + room, 0, z0]), np.array([x0 + room, 0, z0 + room]),
                          np.array([x0, 0, z0 + room])][side]
                direction = [np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), np.array([-1.0, 0, 0]),
                             np.array([0, 0, -1.0])][side]
                # A door gap in the middle of each wall: two wall pieces and a lintel.
                for start, length in ((0.0, 1.6), (2.4, 1.6)):
                    add(*_grid(origin + direction * start, direction * length, np.array([0, wall, 0]), 24, 40),
                        next_id + 2 + side, "wall", 1)
                add(*_grid(origin + direction * 1.6 + np.array([0, 2.1, 0]), direction * 0.8,
                           np.array([0, wall - 2.1, 0]), 12, 8), next_id + 2 + side, "wall", 1)
            next_id += 6
            for _ in range(12):
                size = rng.uniform(0.3, 1.2, 3) * np.array([1, 0.8, 1])
                low = np.array([x0 + rng.uniform(0.3, room - 1.5), 0, z0 + rng.uniform(0.3, room - 1.5)])
                add(*_box(low, low + size, 16), next_id, "table", 5)
                next_id += 1
    offsets = np.cumsum([0] + [len(p[0]) for p in parts])[:-1]
    vertices = np.concatenate([p[0] for p in parts]).astype(np.float32)
    faces = np.concatenate([p[1] + o for p, o in zip(parts, offsets)]).astype(np.int32)
    ids = np.concatenate([np.full(len(p[1]), p[2], np.uint32) for p in parts])
    colors = np.concatenate([np.tile(np.array(p[3], np.uint8), (len(p[0]), 1)) for p in parts])
    return Scene("synthetic-house", vertices, faces, ids, objects, vertex_colors=colors)


def _box(low: np.ndarray, high: np.ndarray, cells: int) -> tuple[np.ndarray, np.ndarray]:
    size = high - low
    sides = [
        (low, np.array([size[0], 0, 0]), np.array([0, size[1], 0])),
        (low + np.array([0, 0, size[2]]), np.array([size[0], 0, 0]), np.array([0, size[1], 0])),
        (low, np.array([0, 0, size[2]]), np.array([0, size[1], 0])),
        (low + np.array([size[0], 0, 0]), np.array([0, 0, size[2]]), np.array([0, size[1], 0])),
        (low + np.array([0, size[1], 0]), np.array([size[0], 0, 0]), np.array([0, 0, size[2]])),
    ]
    vertices, faces, offset = [], [], 0
    for origin, axis_u, axis_v in sides:
        v, f = _grid(origin, axis_u, axis_v, cells, cells)
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def planned_poses(frames: int, folder: Path, detail: float = 1.0) -> tuple[Scene, list[np.ndarray], str]:
    """The house of `detail` (1.0: the bench house, ~1 M triangles; 0.1: the 1 % job's) and real trajectories
    from the shard and plan stages (run inline, no Ray).

    Returns the scene, the (n, 4, 4) poses of each planned video at 1.0 m (at least `frames` in all when the
    plan finds enough) and a description. Raises UnitFailedError when a stage fails.
    """
    from pipeline.config import Job, PlanConfig, ProceduralSource, SceneSources
    from pipeline.render.stage import RgbdRenderer, read_poses
    from pipeline.runtime.executor import run_unit_locally
    from pipeline.store.run_folder import RunFolder
    from pipeline.stages import make_stage

    job = Job(name="bench-render", seed=0, embodiments=[Embodiment(name="bench", placements=[1.0])],
              scenes=SceneSources(procedural=ProceduralSource(count=1, seed=0, detail=detail)),
              plan=PlanConfig(trajectories_per_scene=4, min_frames=100, max_frames=600))
    run = RunFolder.create(folder / "run", job)
    for name in ("shard", "plan"):
        stage = make_stage(name, job)
        for unit in stage.units(run):
            run_unit_locally(stage, run, unit)
    rows = run.read("trajectories").to_pylist()
    videos = [read_poses(run, r) for r in rows]
    scene = RgbdRenderer(job).load_scene(run, rows[0]["scene_id"])
    return scene, videos, f"{len(rows)} planned trajectories at 1.0 m ({sum(map(len, videos))} poses)"


def spread(videos: list[np.ndarray], count: int) -> np.ndarray:
    """`count` poses evenly spaced over all poses of `videos` (all of them when there are fewer)."""
    poses = np.concatenate(videos)
    return poses[np.unique(np.linspace(0, len(poses) - 1, min(count, len(poses))).round().astype(int))]


def consecutive_runs(videos: list[np.ndarray], count: int, runs: int = 4) -> np.ndarray:
    """`count` poses in `runs` runs of consecutive frames (5 cm apart), each from the middle of another video:
    what a renderer meets along a video, whose cast reuses the last frame's visible triangles (frames spread
    over all videos, a metre or more apart, would hide that)."""
    runs = max(1, min(runs, len(videos)))
    lengths = [count // runs + (k < count % runs) for k in range(runs)]
    picked = [videos[k * len(videos) // runs] for k in range(runs)]
    return np.concatenate([video[max(0, (len(video) - length) // 2):][:length] for video, length in zip(picked, lengths)])


def walk_poses(scene: Scene, frames: int, height: float = 1.0) -> np.ndarray:
    """A level camera walking 5 cm per frame and turning 0.5 degrees per frame through the house's middle
    (a fallback when the plan stage is unavailable: it may walk through walls)."""
    low, high = scene.bounds()
    start = np.array([low[0] + 1.0, low[1] + height, (low[2] + high[2]) / 2])
    poses = np.tile(np.eye(4), (frames, 1, 1))
    for t in range(frames):
        heading = np.radians(0.5 * t)
        forward = np.array([np.cos(heading), 0.0, np.sin(heading)])
        down = np.array([0.0, -1.0, 0.0])
        poses[t, :3, :3] = np.stack([np.cross(down, forward), down, forward], axis=1)
        poses[t, :3, 3] = start + 0.05 * t * np.array([1.0, 0.0, 0.0])
    return poses


# ---------------------------------------------------------------------------------------- ours


def run_ours(scene: Scene, poses: np.ndarray, body: Embodiment, exposure: float, store: Path,
             threads: int = 0, barrier: Any = None, background: bool | None = None) -> dict[str, float]:
    """End-to-end render of `poses` into a Zarr store; returns timings (seconds) and bytes.

    The BVH is built and the renderer warmed by one frame before the clock starts: a worker builds the BVH
    once per scene and compiles its kernels once per process (Mitsuba's peer warms up with a frame too).
    Per phase (cast, buffers, segments, zarr) wall and CPU seconds (`<phase>_s`, `<phase>_cpu_s`); the shard
    writes run behind the loop as the render stage's do (`background` None: with several threads), so their
    CPU lands in whichever phase they overlap: `background=False` gives a clean profile. A fused frame
    (`VideoRenderer.fused`: ambient light, or a spot alone on diffuse surfaces) is written and its segments counted
    by the cast's resolve, so its "cast" holds its buffers and segments too, which then take ~0 ms.
    """
    started = time.perf_counter()
    raycaster = SceneRaycaster(scene, threads=threads)
    limit_worker_threads(raycaster.threads)  # as the render stage's workers do
    raycaster.cast(camera_of(body), poses[0])
    colors, labels = SurfaceColors(scene), SceneLabels(scene)
    build = time.perf_counter() - started
    renderer = VideoRenderer(scene, body, exposure, raycaster=raycaster, colors=colors, labels=labels)
    renderer.render(poses[0])
    if barrier is not None:
        barrier.wait()  # every worker starts rendering at the same moment
    trajectory = {"video_name": "bench", "scene_id": scene.scene_id, "trajectory": 0, "height_m": 1.0}
    wall, cpu_of = dict.fromkeys(PHASES, 0.0), dict.fromkeys(PHASES, 0.0)

    def clocks() -> tuple[float, float]:
        # CPU seconds of this process (every thread): what the frames cost, whatever else shares the machine.
        return time.perf_counter(), time.process_time()

    def lap(phase: str, since: tuple[float, float]) -> tuple[float, float]:
        now = clocks()
        wall[phase] += now[0] - since[0]
        cpu_of[phase] += now[1] - since[1]
        return now

    started = clocks()
    writer = VideoWriter(store, len(poses), body.sensor.width, body.sensor.height,
                         video_attributes(renderer, poses, trajectory), level=ZSTD_LEVEL,
                         background=raycaster.threads > 1 if background is None else background)  # as the stage writes
    mark = started
    for pose in poses:
        if getattr(renderer, "fused", False):  # the cast writes the buffers (an older tree has no such path)
            frame = renderer.render(pose)
            mark = lap("cast", mark)
        else:
            hits = trace_as_rendered(renderer, pose)
            mark = lap("cast", mark)
            frame = renderer.buffers(hits, camera_to_world=pose)
        mark = lap("buffers", mark)
        if hasattr(frame, "segment_statistics"):  # (an older tree's frames have none)
            frame.segment_statistics(labels)
        else:
            frame_segments(frame.panoptic, labels, frame.dense)
        mark = lap("segments", mark)
        writer.append(rgb=frame.rgb, depth=frame.depth, panoptic=frame.panoptic)
        mark = lap("zarr", mark)
    writer.close()
    lap("zarr", mark)
    ended = clocks()
    return {"bvh_build_s": build, "total_s": ended[0] - started[0], "cpu_s": ended[1] - started[1],
            **{f"{k}_s": v for k, v in wall.items()}, **{f"{k}_cpu_s": v for k, v in cpu_of.items()},
            "bytes": directory_bytes(store), "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}


def trace_as_rendered(renderer: VideoRenderer, pose: np.ndarray, surfaces: bool | None = None) -> Any:
    """`renderer.trace` filling the normals and directions when `render` (the stage) would (`needs_surfaces`),
    or as `surfaces` says; an older tree (a `--baseline`) has no such flag and always fills them."""
    if not hasattr(renderer, "needs_surfaces"):
        return renderer.trace(pose)
    return renderer.trace(pose, renderer.needs_surfaces if surfaces is None else surfaces)


def _worker(index: int, poses: np.ndarray, barrier: Any, results: Any) -> None:
    """One rendering worker process (1 Embree thread), as Ray runs one render task per CPU."""
    scene, _ = generated_house()
    folder = Path(tempfile.mkdtemp(prefix=f"bench_render_worker{index}_"))
    try:
        results.put((index, run_ours(scene, poses, spot_body(), EXPOSURE, folder / "v.zarr", threads=1,
                                     barrier=barrier)))
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def run_workers(count: int, poses: np.ndarray) -> dict[str, Any]:
    """`count` worker processes rendering a share of `poses` each at the same time: the machine's throughput."""
    context = multiprocessing.get_context("spawn")
    barrier, results = context.Barrier(count), context.Queue()
    frames = len(poses) // count
    processes = [context.Process(target=_worker, args=(i, poses[i * frames:(i + 1) * frames], barrier, results))
                 for i in range(count)]
    for process in processes:
        process.start()
    outcomes = dict(results.get() for _ in processes)
    for process in processes:
        process.join()
    slowest = max(o["total_s"] for o in outcomes.values())
    cpu_per_frame = sum(o["cpu_s"] for o in outcomes.values()) / (count * frames)
    return {"workers": count, "frames_each": frames, "wall_s": round(slowest, 3),
            "fps_total": round(count * frames / slowest, 2),
            "cpu_ms_per_frame": round(1000 * cpu_per_frame, 2),
            # Throughput if each worker had its core to itself (the benchmark machine is shared).
            "fps_total_from_cpu_time": round(count / cpu_per_frame, 2),
            "peak_rss_gib_per_worker": round(max(o["peak_rss_gib"] for o in outcomes.values()), 3),
            "per_frame_ms": {k: round(1000 * sum(o[f"{k}_s"] for o in outcomes.values()) / (count * frames), 2)
                             for k in ("cast", "buffers", "segments", "zarr")}}


def median_of_worker_runs(count: int, poses: np.ndarray, repeats: int) -> dict[str, Any]:
    """`run_workers` `repeats` times: the run with the median throughput, and every run's fps (a shared
    VM's speed drifts by +-20 % within minutes)."""
    runs = sorted((run_workers(count, poses) for _ in range(repeats)), key=lambda run: run["fps_total"])
    return {**runs[len(runs) // 2], "fps_total_runs": [run["fps_total"] for run in runs]}


def primary_visibility(scene: Scene, poses: np.ndarray, camera: Any, threads: int = 0, repeats: int = 3
                       ) -> dict[str, Any]:
    """The z-buffer (raster.py) against the Embree packet cast on the same poses: agreement per frame (share
    of pixels with the same triangle, of those with the same hit/miss, largest depth difference where the
    triangle is the same and where it differs) and the wall and CPU seconds per frame of each, the two taking
    turns `repeats` times (median and every run)."""
    casters = {"raster": SceneRaycaster(scene, threads=threads, rasterize=True),
               "embree": SceneRaycaster(scene, threads=threads, rasterize=False)}
    same_face, same_hit, depth_same, depth_other = [], [], [], []
    for pose in poses:
        raster, rays = (casters[name].cast(camera, pose) for name in ("raster", "embree"))
        same, hit = raster.face == rays.face, raster.hit == rays.hit
        same_face.append(float(same.mean()))
        same_hit.append(float(hit.mean()))
        both = same & rays.hit
        depth_same.append(float(np.abs(raster.depth[both] - rays.depth[both]).max(initial=0.0)))
        other = ~same & rays.hit & raster.hit
        depth_other.append(float(np.abs(raster.depth[other] - rays.depth[other]).max(initial=0.0)))
    seconds: dict[str, dict[str, list[float]]] = {name: {"wall": [], "cpu": []} for name in casters}
    for _ in range(repeats):
        for name, caster in casters.items():
            started, cpu_started = time.perf_counter(), time.process_time()
            for pose in poses:
                caster.cast(camera, pose)
            seconds[name]["wall"].append((time.perf_counter() - started) / len(poses))
            seconds[name]["cpu"].append((time.process_time() - cpu_started) / len(poses))
    timing = {name: {f"{kind}_ms": [round(1000 * v, 2) for v in values] for kind, values in runs.items()}
              | {f"{kind}_median_ms": round(1000 * float(np.median(values)), 2) for kind, values in runs.items()}
              for name, runs in seconds.items()}
    return {"frames": len(poses), "threads": casters["raster"].threads,
            "same_face_share": {"median": float(np.median(same_face)), "min": min(same_face)},
            "same_hit_or_miss_share_min": min(same_hit),
            "max_depth_difference_m": {"same_triangle": max(depth_same), "other_triangle": max(depth_other)},
            **timing,
            "raster_speedup": {kind: round(timing["embree"][f"{kind}_median_ms"] / timing["raster"][f"{kind}_median_ms"], 2)
                               for kind in ("wall", "cpu")}}


# ------------------------------------------------------------------------------------ pyrender


def run_pyrender(scene: Scene, poses: np.ndarray, body: Embodiment) -> dict[str, float | str]:
    """The same poses with pyrender + OSMesa: a lit colour + depth pass and a flat (SEG) label pass.

    Set up as a careful user would, so the ratio is fair: Mesa's llvmpipe rasterizer on every CPU (not
    softpipe), PyOpenGL's per-call error checking off (pyrender sets a dozen uniforms per draw, and the
    checks made the Python side cost more than the rasterization), every mesh uploaded once before the
    clock starts, the colour pass as one merged mesh (one draw call), the label pass one node per object
    (pyrender's SEG mode colours whole nodes).
    """
    os.environ["PYOPENGL_PLATFORM"] = "osmesa"
    os.environ.setdefault("PYOPENGL_ERROR_CHECKING", "0")  # read when OpenGL is first imported
    os.environ.setdefault("GALLIUM_DRIVER", "llvmpipe")
    os.environ.setdefault("LP_NUM_THREADS", str(available_cpus()))
    try:
        import pyrender
        import trimesh
    except ImportError as error:
        return {"error": f"pyrender not importable: {error}"}
    fx, fy, cx, cy = body.sensor.intrinsics()
    pr_scene = pyrender.Scene(ambient_light=[0.2, 0.2, 0.2], bg_color=[0, 0, 0, 0])
    colour_node = pr_scene.add(_pyrender_colour_mesh(scene, pyrender, trimesh))
    seg_map = {}
    order = np.argsort(scene.face_object_ids, kind="stable")
    bounds = np.flatnonzero(np.diff(scene.face_object_ids[order])) + 1
    for faces in np.split(order, bounds):
        object_id = int(scene.face_object_ids[faces[0]])
        mesh = trimesh.Trimesh(scene.vertices, scene.faces[faces], process=False)
        mesh.remove_unreferenced_vertices()
        # No colours (SEG draws a uniform per node) and shared vertices: the fewest vertices to transform.
        node = pr_scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=True))
        # The label pass draws each node in a flat colour that encodes its id (R + 256 G + 65536 B).
        seg_map[node] = [object_id & 255, (object_id >> 8) & 255, (object_id >> 16) & 255]
    # OpenGL camera looks down -Z with +Y up: flip the OpenCV pose's y and z axes.
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    camera = pyrender.IntrinsicsCamera(fx, fy, cx, cy, znear=body.sensor.near, zfar=body.sensor.far)
    camera_node = pr_scene.add(camera, pose=poses[0] @ flip)
    light_node = pr_scene.add(pyrender.SpotLight(color=np.ones(3), intensity=20.0, outerConeAngle=np.pi / 2 - 0.01),
                              pose=poses[0] @ flip)
    renderer = pyrender.OffscreenRenderer(body.sensor.width, body.sensor.height)
    # Compile shaders and upload every buffer outside the timing (pyrender uploads on first use).
    _pyrender_frame(pyrender, renderer, pr_scene, colour_node, seg_map)
    from OpenGL import GL

    gl_renderer = GL.glGetString(GL.GL_RENDERER).decode()
    started = time.perf_counter()
    for pose in poses:
        pr_scene.set_pose(camera_node, pose @ flip)
        pr_scene.set_pose(light_node, pose @ flip)
        _pyrender_frame(pyrender, renderer, pr_scene, colour_node, seg_map)
    seconds = time.perf_counter() - started
    renderer.delete()
    return {"total_s": seconds, "nodes": len(seg_map) + 1, "gl_renderer": gl_renderer,
            "lp_num_threads": os.environ["LP_NUM_THREADS"]}


def _pyrender_colour_mesh(scene: Scene, pyrender: Any, trimesh: Any) -> Any:
    """The whole scene as one pyrender mesh with its vertex colours (or flat face colours)."""
    mesh = trimesh.Trimesh(scene.vertices, scene.faces, process=False)
    if scene.vertex_colors is not None:
        # Shared vertices with vertex colours (smooth): the cheapest input for a rasterizer.
        mesh.visual.vertex_colors = np.c_[scene.vertex_colors, np.full(len(scene.vertices), 255, np.uint8)]
        return pyrender.Mesh.from_trimesh(mesh, smooth=True)
    mesh.visual.face_colors = np.c_[scene.face_colors(), np.full(len(scene.faces), 255, np.uint8)]
    return pyrender.Mesh.from_trimesh(mesh, smooth=False)


def _pyrender_frame(pyrender: Any, renderer: Any, pr_scene: Any, colour_node: Any, seg_map: dict) -> None:
    """One frame's buffers: the lit colour + depth pass (merged mesh only), then the label pass."""
    for node in seg_map:
        node.mesh.is_visible = False
    colour_node.mesh.is_visible = True
    color, depth = renderer.render(pr_scene)
    for node in seg_map:
        node.mesh.is_visible = True
    colour_node.mesh.is_visible = False  # the SEG pass skips nodes without a colour anyway
    labels, _ = renderer.render(pr_scene, flags=pyrender.RenderFlags.SEG, seg_node_map=seg_map)
    _ = (labels[..., 0].astype(np.uint32) | labels[..., 1].astype(np.uint32) << 8
         | labels[..., 2].astype(np.uint32) << 16, np.rint(depth * 1000).astype(np.uint16), color)


# ------------------------------------------------------------------------------ against Mitsuba 3


def cast_depth_ids(scene: Scene, poses: np.ndarray, threads: int) -> dict[str, float]:
    """Wall and CPU seconds per frame of the primary cast, the depth buffer (mm) and the panoptic ids: what
    Mitsuba's AOV integrator (depth + shape id) computes. Warmed by one frame, like `run_ours`."""
    body = spot_body()
    renderer = VideoRenderer(scene, body.model_copy(update={"illumination": Illumination()}), 1.0,
                             raycaster=SceneRaycaster(scene, threads=threads))
    sensor, labels = body.sensor, renderer.labels
    fused = getattr(renderer_module, "_depth_and_labels", None)  # the renderer's one pass (absent before issue 31)
    shape = (sensor.height, sensor.width)
    millimetres, panoptic, dense = np.empty(shape, np.uint16), np.empty(shape, np.uint32), np.empty(shape, np.int32)

    def depth_and_ids(hits: Any) -> None:
        if fused is None:  # what the renderer did before: whole-array passes (without its dense labels)
            depth_to_millimetres(hits.depth, sensor.near, sensor.far)
            np.take(labels.object_ids, hits.face, mode="clip")
        else:  # the renderer's own pass (it also writes the dense labels)
            fused(hits.depth, hits.face, np.float32(sensor.near), np.float32(sensor.far), labels.object_ids,
                  labels.dense_of_face, millimetres, panoptic, dense)

    def frame(pose: np.ndarray) -> None:
        if getattr(renderer, "fused", False):  # the resolve writes depth and ids itself (and the segment rows)
            renderer.resolve_frame(pose, colour=False)
        else:  # (an older tree) depth and ids read no normals or directions
            depth_and_ids(trace_as_rendered(renderer, pose, False))

    frame(poses[0])
    started, cpu_started = time.perf_counter(), time.process_time()
    for pose in poses:
        frame(pose)
    return {"wall_s": (time.perf_counter() - started) / len(poses), "cpu_s": (time.process_time() - cpu_started) / len(poses)}


def child_ours(folder: Path, threads: int) -> None:
    """One turn of ours (run in a process of its own, on the pipeline of MVPD_TREE): ambient and direct-only
    spot end to end, and cast + depth + ids; writes `ours.json` in `folder`."""
    scene, poses = pickle.loads((folder / "house.pkl").read_bytes())
    body = spot_body()
    # Warm every kernel of the loop (run_ours warms the cast and buffers, not the segments and the writer).
    run_ours(scene, poses[:2], body, EXPOSURE, folder / "warm.zarr", threads=threads)
    shutil.rmtree(folder / "warm.zarr", ignore_errors=True)
    timings = {}
    for name, embodiment, exposure in (("ambient", body.model_copy(update={"illumination": Illumination()}), 1.0),
                                       ("spot_direct", body, EXPOSURE)):
        store = folder / f"{name}.zarr"
        run = run_ours(scene, poses, embodiment, exposure, store, threads=threads)
        shutil.rmtree(store, ignore_errors=True)
        timings[name] = {"wall_s": run["total_s"] / len(poses), "cpu_s": run["cpu_s"] / len(poses),
                         "bytes_per_frame": run["bytes"] / len(poses)}
        # The profile: the same frames with the shard writes inline, so each phase's CPU is its own.
        inline = run_ours(scene, poses, embodiment, exposure, store, threads=threads, background=False)
        shutil.rmtree(store, ignore_errors=True)
        timings[name]["profile_cpu_s"] = {phase: inline[f"{phase}_cpu_s"] / len(poses) for phase in PHASES}
    timings["cast_depth_ids"] = cast_depth_ids(scene, poses, threads)
    import pipeline

    (folder / "ours.json").write_text(json.dumps({**timings, "tree": str(Path(pipeline.__file__).parents[1])}))


def turn_of_ours(tree: Path, folder: Path, threads: int) -> dict[str, Any]:
    """`child_ours` on the pipeline of `tree`, in a fresh process (numba's cache warm, kernels loaded anew)."""
    env = {**os.environ, "MVPD_TREE": str(tree), "OMP_NUM_THREADS": str(threads)}
    subprocess.run([sys.executable, __file__, "--child", str(folder), "--threads", str(threads)], check=True, env=env,
                   cwd=tree)
    return json.loads((folder / "ours.json").read_text())


def turn_of_mitsuba(python: str, folder: Path) -> dict[str, Any] | None:
    """Mitsuba 3 direct 1 spp and AOV (depth + shape id) on the exported poses, warm (bench_light's peer)."""
    from bench_light import run_peer

    if not run_peer(python, "peer_mitsuba.py", folder, "mitsuba", MITSUBA_RENDERS, folder / "mitsuba.log"):
        return None
    runs = {render["name"]: np.load(folder / f"mitsuba_{render['name']}.npz") for render in MITSUBA_RENDERS}
    return {name: {"wall_s": float(np.median(run["seconds"])), "cpu_s": float(np.median(run["cpu_seconds"]))}
            for name, run in runs.items()}


def summary(values: list[float]) -> dict[str, Any]:
    """Median, min, max and every run, in milliseconds."""
    ms = [round(1000 * v, 2) for v in values]
    return {"median_ms": round(float(np.median(ms)), 2), "min_ms": min(ms), "max_ms": max(ms), "runs_ms": ms}


def versus_mitsuba(frames: int, repeats: int, threads: int, baseline: Path | None, detail: float = 1.0) -> dict[str, Any]:
    """Ours (this tree, and `baseline`'s when given) and warm Mitsuba 3 taking turns `repeats` times on the
    same poses of the bench house: CPU and wall per frame, median of the turns with spread; ratios by CPU."""
    from bench_light import export, peer_python, peer_version

    folder = Path(tempfile.mkdtemp(prefix="bench_render_mitsuba_"))
    try:
        scene, videos, pose_source = planned_poses(frames, folder, detail)
        poses = consecutive_runs(videos, frames)
        pose_source += f", {len(poses)} of them in 4 runs of consecutive frames from the middle of different videos"
        (folder / "house.pkl").write_bytes(pickle.dumps((scene, poses)))
        export(scene, poses, folder / "peer", threads)
        trees = {"ours": Path(__file__).resolve().parents[1], **({"baseline": baseline} if baseline else {})}
        python = peer_python("MITSUBA_PYTHON", "/work/venvs/mitsuba/bin/python")
        turns: dict[str, list[dict[str, Any]]] = {name: [] for name in [*trees, "mitsuba"]}
        loads = []
        sides = [*trees, "mitsuba"]
        for round_index in range(repeats):
            # Every side takes one turn per round, so drifts of the load fall on all alike, and the order turns
            # by one each round: with a fixed order, this tree (always first) cast 1.5-4 ms per frame slower than
            # ff1406f's identical cast in two runs at load 11-15, and alternating processes did not show it.
            for name in sides[round_index % len(sides):] + sides[:round_index % len(sides)]:
                if name != "mitsuba":
                    loads.append(os.getloadavg()[0])
                    turns[name].append(turn_of_ours(trees[name], folder, threads))
                elif python is not None:
                    loads.append(os.getloadavg()[0])
                    mitsuba = turn_of_mitsuba(python, folder / "peer")
                    python = python if mitsuba is not None else None
                    if mitsuba is not None:
                        turns["mitsuba"].append(mitsuba)
        loads.append(os.getloadavg()[0])
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    table = {name: {kind: {clock: summary([turn[kind][f"{clock}_s"] for turn in runs]) for clock in ("cpu", "wall")}
                    for kind in runs[0] if kind != "tree"} for name, runs in turns.items() if runs}
    for name in trees:
        for kind in ("ambient", "spot_direct"):
            table[name][kind]["kb_per_frame"] = round(turns[name][0][kind]["bytes_per_frame"] / 1000, 1)
            if all("profile_cpu_s" in turn[kind] for turn in turns[name]):  # (absent in a baseline before it)
                table[name][kind]["profile_cpu_ms"] = {phase: summary([turn[kind]["profile_cpu_s"][phase]
                                                                       for turn in turns[name]]) for phase in PHASES}
    result: dict[str, Any] = {
        "scene": {"triangles": scene.triangle_count, "detail": detail, "poses": pose_source}, "frames": len(poses),
        "resolution": [640, 480], "threads": threads, "repeats": repeats,
        "peers": {"mitsuba": peer_version(python, "mitsuba"), "variant": "llvm_ad_rgb", "renders": MITSUBA_RENDERS},
        "load_1m": {"min": min(loads), "max": max(loads), "each_turn": loads},
        "trees": {name: turns[name][0]["tree"] for name in trees}, "per_frame": table}
    if "mitsuba" in table:
        result["ratios_by_cpu"] = {name: _ratios(table[name], table["mitsuba"]) for name in trees}
        result["targets"] = {key: {"target": target, "met": result["ratios_by_cpu"]["ours"][key] >= target}
                             for key, target in TARGETS_VS_MITSUBA.items()}
    return result


def _ratios(ours: dict[str, Any], mitsuba: dict[str, Any]) -> dict[str, float]:
    """How many times less CPU per frame ours needs than Mitsuba (medians)."""
    def ratio(theirs: str, mine: str) -> float:
        return round(mitsuba[theirs]["cpu"]["median_ms"] / ours[mine]["cpu"]["median_ms"], 3)  # 2 digits made 1.499 "met"

    return {"ambient_vs_direct1": ratio("direct1", "ambient"), "spot_direct_vs_direct1": ratio("direct1", "spot_direct"),
            "cast_depth_ids_vs_aov": ratio("aov", "cast_depth_ids")}


# ---------------------------------------------------------------------------------------- main


def main() -> None:
    """Run the benchmark and write benchmarks/results/render.json."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=96)
    parser.add_argument("--pyrender-frames", type=int, default=32)
    parser.add_argument("--skip-pyrender", action="store_true")
    parser.add_argument("--repeats", type=int, default=3, help="runs of the parallel-workers measurement (median kept)")
    parser.add_argument("--workers", action=argparse.BooleanOptionalAction, default=True,
                        help="also measure one 1-thread worker process per CPU rendering at the same time")
    parser.add_argument("--primary-only", action="store_true", help="only the z-buffer against the Embree cast "
                        "(agreement, CPU and wall); writes results/render_primary.json")
    parser.add_argument("--vs-mitsuba", action="store_true", help="only ours against warm Mitsuba 3 (direct 1 spp, "
                        "AOV), interleaved, --repeats turns of --frames poses; writes results/render_vs_mitsuba.json")
    parser.add_argument("--baseline", type=Path, help="with --vs-mitsuba: also time this checkout's pipeline (an "
                        "older commit's worktree) in the same turns")
    parser.add_argument("--threads", type=int, default=2, help="threads of ours and Mitsuba in --vs-mitsuba")
    parser.add_argument("--detail", type=float, default=1.0, help="with --vs-mitsuba: the house's detail (0.1: the 1 %% "
                        "job's houses, for bench_scaling's calibrated cost model); results/render_vs_mitsuba_detail<d>.json")
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)  # one turn of ours (versus_mitsuba)
    args = parser.parse_args()

    if args.child:
        child_ours(args.child, args.threads)
        return
    if args.vs_mitsuba:
        result = versus_mitsuba(args.frames, args.repeats, args.threads, args.baseline, args.detail)
        suffix = "" if args.detail == 1.0 else f"_detail{args.detail:g}"
        out = Path(__file__).resolve().parent / "results" / f"render_vs_mitsuba{suffix}.json"
        out.write_text(json.dumps(result, indent=1) + "\n")
        print(json.dumps({k: v for k, v in result.items() if k != "per_frame"}, indent=1))
        for name, kinds in result["per_frame"].items():
            for kind, clocks in kinds.items():
                print(f"{name:9s} {kind:15s} CPU {clocks['cpu']['median_ms']:7.2f} ms ({clocks['cpu']['min_ms']}-"
                      f"{clocks['cpu']['max_ms']})  wall {clocks['wall']['median_ms']:7.2f} ms")
                if "profile_cpu_ms" in clocks:
                    print(" " * 26 + "CPU by phase, writes inline: " + ", ".join(
                        f"{phase} {value['median_ms']:.2f}" for phase, value in clocks["profile_cpu_ms"].items()))
        print(f"wrote {out}")
        return

    folder = Path(tempfile.mkdtemp(prefix="bench_render_"))
    if args.primary_only:
        scene, videos, pose_source = planned_poses(args.frames, folder)
        shutil.rmtree(folder, ignore_errors=True)
        result = {"scene": {"triangles": scene.triangle_count, "poses": pose_source},
                  **primary_visibility(scene, spread(videos, args.frames), camera_of(spot_body()))}
        out = Path(__file__).resolve().parent / "results" / "render_primary.json"
        out.write_text(json.dumps(result, indent=1) + "\n")
        print(json.dumps(result, indent=1))
        return
    started = time.perf_counter()
    body = spot_body()
    try:
        scene, videos, pose_source = planned_poses(args.frames, folder)
        source = "shard stage: procedural seed 0, detail 1.0"
    except (UnitFailedError, ValueError, IndexError) as error:
        print(f"plan stage unavailable ({error}); using a straight walk")
        scene, source = generated_house()
        videos = [walk_poses(scene, args.frames * available_cpus())]
        pose_source = "straight walk (plan stage unavailable)"
    prepare_s = time.perf_counter() - started
    poses = spread(videos, args.frames)
    try:
        primary = primary_visibility(scene, poses, camera_of(body))
        ours = run_ours(scene, poses, body, exposure=EXPOSURE, store=folder / "bench.zarr")
        ambient = run_ours(scene, poses, body.model_copy(update={"illumination": Illumination()}), 1.0,
                           folder / "ambient.zarr")
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    peak_gib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # ru_maxrss is in KiB on Linux
    fps = len(poses) / ours["total_s"]
    workers = median_of_worker_runs(available_cpus(), spread(videos, args.frames * available_cpus()),
                                    args.repeats) if args.workers else None
    result: dict = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
        "scene": {"source": source, "triangles": scene.triangle_count, "objects": len(scene.objects),
                  "prepare_s": round(prepare_s, 2)},
        "resolution": [body.sensor.width, body.sensor.height], "frames": len(poses), "poses": pose_source,
        "ours_spot": {k: round(v, 4) for k, v in ours.items()},
        "ours_ambient": {k: round(v, 4) for k, v in ambient.items()},
        "fps_end_to_end_spot": round(fps, 2),
        "fps_end_to_end_ambient": round(len(poses) / ambient["total_s"], 2),
        "fps_cast_only": round(len(poses) / ours["cast_s"], 2),
        "primary_visibility": primary,
        "kb_per_frame_spot": round(ours["bytes"] / len(poses) / 1000, 1),
        "kb_per_frame_ambient": round(ambient["bytes"] / len(poses) / 1000, 1),
        "peak_memory_gib": round(peak_gib, 3),
        "parallel_workers": workers,
        "targets": {"fps": TARGET_FPS, "speedup_vs_pyrender": TARGET_SPEEDUP, "peak_memory_gib": TARGET_PEAK_GIB,
                    "kb_per_frame": TARGET_KB_PER_FRAME},
    }
    if not args.skip_pyrender:
        theirs = run_pyrender(scene, poses[: args.pyrender_frames], body)
        result["pyrender_osmesa"] = theirs
        if "total_s" in theirs:
            their_fps = args.pyrender_frames / float(theirs["total_s"])
            result["pyrender_fps"] = round(their_fps, 2)
            # Both sides use the whole machine: pyrender through llvmpipe's threads, ours through the
            # better of one 2-thread process and one 1-thread worker per CPU.
            best = max(fps, workers["fps_total"] if workers else 0.0)
            result["speedup_vs_pyrender"] = round(best / their_fps, 2)
    _report(result)
    out = Path(__file__).resolve().parent / "results" / "render.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out}")


def _report(result: dict) -> None:
    def line(name: str, value: float | None, target: float, higher_is_better: bool, unit: str) -> None:
        if value is None:
            print(f"{name:34s} n/a (target {target} {unit})")
            return
        ok = value >= target if higher_is_better else value <= target
        print(f"{name:34s} {value:10.2f} {unit:6s} target {'>=' if higher_is_better else '<='} {target}  "
              f"{'OK' if ok else 'MISSED'}")

    print(f"scene: {result['scene']['triangles']} triangles, {result['scene']['objects']} objects "
          f"({result['scene']['source']})")
    line("end-to-end fps (spot light)", result["fps_end_to_end_spot"], TARGET_FPS, True, "fps")
    line("end-to-end fps (ambient)", result["fps_end_to_end_ambient"], TARGET_FPS, True, "fps")
    if result.get("parallel_workers"):
        workers = result["parallel_workers"]
        line(f"end-to-end fps, {workers['workers']} workers x 1 thread", workers["fps_total"], TARGET_FPS, True, "fps")
        print(f"  (median of runs at {workers['fps_total_runs']} fps)")
        line("  same, from CPU time per frame", workers["fps_total_from_cpu_time"], TARGET_FPS, True, "fps")
        line("peak memory per worker", workers["peak_rss_gib_per_worker"], TARGET_PEAK_GIB, False, "GiB")
        print(f"per frame (ms, per worker): {workers['per_frame_ms']}")
    print(f"{'ray cast only fps':34s} {result['fps_cast_only']:10.2f}")
    primary = result["primary_visibility"]
    print(f"primary visibility, z-buffer vs Embree packets: same triangle on {primary['same_face_share']['median']:.6f} "
          f"of pixels (median; min {primary['same_face_share']['min']:.6f}), {primary['raster_speedup']['cpu']}x less CPU, "
          f"{primary['raster_speedup']['wall']}x less wall")
    line("speed-up vs pyrender/OSMesa", result.get("speedup_vs_pyrender"), TARGET_SPEEDUP, True, "x")
    line("peak memory", result["peak_memory_gib"], TARGET_PEAK_GIB, False, "GiB")
    line("stored kB/frame (spot)", result["kb_per_frame_spot"], TARGET_KB_PER_FRAME, False, "kB")
    line("stored kB/frame (ambient)", result["kb_per_frame_ambient"], TARGET_KB_PER_FRAME, False, "kB")
    ours = result["ours_spot"]
    per_frame = {k[:-2]: round(1000 * ours[k] / result["frames"], 2) for k in ("cast_s", "buffers_s", "segments_s", "zarr_s")}
    print(f"per frame (ms, spot): {per_frame}")


if __name__ == "__main__":
    main()
