"""Light benchmark (issues 21, 32): our spot light against the authors' Cycles renders and a matched Mitsuba 3.

Run (the whole bench, one command; ~30 min on the shared 2 cores, 64 spp of Mitsuba the dearest part):

    .venv/bin/python benchmarks/bench_light.py

Peers, each in a virtualenv of its own (`bash benchmarks/setup_light_peers.sh` makes them; BPY_PYTHON /
MITSUBA_PYTHON override): Blender Cycles (`bpy` from PyPI, benchmarks/peer_cycles.py) and Mitsuba 3 (`mitsuba`,
variant `llvm_ad_rgb`, benchmarks/peer_mitsuba.py). A missing peer is skipped with a message.

Everything is rendered at the converged reference's STORED poses (benchmarks/results/light/reference.json
"poses"; 8 poses of the 1 M-triangle benchmark house, 640x480, the MVPd 20 W spot with the authors' principled
material, fixed exposure), never at today's planned poses. Each cached render (reference, its second seed,
Cycles 16 spp) records in its JSON what it was made for ("made_for": a hash of the scene's vertices, faces
and colours, a hash of the poses, resolution, light and encoding); when that differs from this run the bench
stops in one line naming the field and the flag that renders the cache anew (`--reference`: 2-7 min per frame).

Measured, each against the reference (PSNR of 8-bit sRGB frames) and in CPU milliseconds per frame (every thread
of the renderer's process; the median of 3 rounds, each round's value the median of its frames):
- ours end to end (bench_render.run_ours: every buffer and the Zarr write), ours' direct light alone;
- Cycles 16 spp without denoising (cached; each round re-renders one pose with the same seed: the proof that the
  cache matches its poses), Cycles 16 spp + OpenImageDenoise (the authors' setting: MVPd's
  simulators/blender/render_color.py never turns Cycles' default denoiser off), Cycles 1 spp + OIDN;
- Mitsuba 3 `path` (max_depth 18: 16 bounces) over a sweep of samples per pixel, with our light and material as
  Mitsuba plugins (peer_mitsuba.py); the match is checked: its `direct` render against our direct light;
- for each peer, "their CPU to reach our PSNR / our CPU" (log-linear in CPU between the peer's settings).
The rounds interleave ours, Cycles and Mitsuba, so load drifts fall on all alike; the load average is recorded.
Side-by-side pictures (ours | Cycles 16 spp + OIDN | reference, half size) go to benchmarks/results/light/.

Blender's spot spreads its watts over the whole sphere (I = P / 4 pi) where our model spreads them over the cone
(P / 2 pi for 180 degrees): Cycles' radiance is scaled by BLENDER_SPOT_SCALE before the shared exposure
(Mitsuba's matched spot has our intensity: its radiance meets the exposure as is).
Results: benchmarks/results/light.json.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_render import run_ours  # noqa: E402
from pipeline.config import Embodiment, Illumination, IndirectLight, Sensor  # noqa: E402
from pipeline.render.lighting import linear_to_srgb, srgb_to_linear  # noqa: E402
from pipeline.render.material import reflection_tables  # noqa: E402
from pipeline.render.renderer import VideoRenderer  # noqa: E402
from pipeline.scenes.scene import Scene  # noqa: E402

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "light"
EXPOSURE = 4.0  # as bench_render: a 20 W light puts white at 1 m near full scale
BLENDER_SPOT_SCALE = 2.0  # 4 pi / 2 pi: measured 0.5000 ratio of Cycles to our direct radiance
POWER = 20.0
ROUNDS = 3
DEBIAN_LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
TARGET_PSNR = 42.0  # issue 32: spot frames >= 42 dB median against the reference
TARGET_CPU_MS = 150.0  # issue 32: <= 150 ms CPU per frame end to end
REPRODUCED_PSNR = 60.0  # a cached frame rendered again agrees at least this well (measured: 82.96 dB)

# Cached Cycles renders (PNG + JSON under RESULTS) and the flag that renders each anew.
REFERENCE = {"name": "reference", "samples": 32, "bounces": 16, "denoise": True, "seed": 1}
REFERENCE_FLOOR = {**REFERENCE, "name": "reference_seed2", "seed": 2, "poses": [0, 6]}
CYCLES16 = {"name": "cycles16", "samples": 16, "bounces": 16, "seed": 0}
FLAGS = {"reference": "--reference", "reference_seed2": "--reference-floor", "cycles16": "--cycles16"}
# Rendered every run, timed in the rounds: the authors' setting (denoised) and the cheapest denoised one.
CYCLES16_OIDN = {"name": "cycles16_oidn", "samples": 16, "bounces": 16, "denoise": True, "seed": 0}
CYCLES1_OIDN = {"name": "cycles1_oidn", "samples": 1, "bounces": 16, "denoise": True, "seed": 0}
MITSUBA_DEPTH = 18  # Mitsuba counts the camera segment and the light's: 16 bounces = max_depth 18
# How the peers shade the mesh: it has no normals, so flat (glTF 2.0: a mesh without normals gets flat normals,
# and the authors imported their GLBs with Blender's glTF importer); bpy 5 builds a new mesh smooth-shaded.
SHADING = "flat: each triangle's own normal (the mesh has no normals)"
ENCODING_CYCLES = (f"linear radiance x {BLENDER_SPOT_SCALE} (Blender's spot watts) x exposure {EXPOSURE}, "
                   "clipped, sRGB, rounded to 8 bits")


class CacheMismatch(Exception):
    """A cached render was made for another scene, poses, resolution, light, shading or encoding (one-line message)."""


def mvpd_spot(material: str = "principled", bounces: int = 16) -> Illumination:
    """The MVPd 20 W spot with the authors' material (or diffuse) and `bounces` of indirect light."""
    return Illumination(kind="spot", power=POWER, cone=180.0, blend=1.0, material=material, specular=1.0,
                        roughness=0.5, indirect=IndirectLight(bounces=bounces))


def light_record() -> dict[str, Any]:
    """What a cached render's light and material were (the part of `made_for` that is not geometry)."""
    spot = mvpd_spot()
    return {"power_w": spot.power, "cone_deg": spot.cone, "blend": spot.blend, "material": spot.material,
            "specular": spot.specular, "roughness": spot.roughness}


def scene_hash(scene: Scene) -> str:
    """SHA-256 of what a peer renders of the scene: vertices, faces and vertex colours."""
    digest = hashlib.sha256()
    for array in (scene.vertices, scene.faces, scene.vertex_colors):
        digest.update(b"none" if array is None else np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


def poses_hash(poses: np.ndarray) -> str:
    """SHA-256 of (N, 4, 4) float64 poses (exact: JSON keeps float64 round trip)."""
    return hashlib.sha256(np.ascontiguousarray(poses, dtype=np.float64).tobytes()).hexdigest()


def made_for(scene_sha: str, poses: np.ndarray, encoding: str) -> dict[str, Any]:
    """What a cached render is valid for (compared field by field by `check_made_for`)."""
    sensor = Sensor()
    return {"scene_sha256": scene_sha, "poses_sha256": poses_hash(poses), "resolution": [sensor.width, sensor.height],
            "light": light_record(), "shading": SHADING, "encoding": encoding}


def check_made_for(path: Path, recorded: dict[str, Any] | None, expected: dict[str, Any], flag: str) -> None:
    """Raise CacheMismatch (one line: the file, the first field that differs, the flag) unless they agree."""
    if recorded is None:
        raise CacheMismatch(f"{path}: no 'made_for' record (scene, poses, resolution, light, shading, encoding); "
                            f"render it anew with {flag}")
    for field, value in expected.items():
        if recorded.get(field) != value:
            raise CacheMismatch(f"{path}: made for another {field} ({short(recorded.get(field))} here, this run "
                                f"needs {short(value)}); render it anew with {flag}")


def short(value: Any) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= 40 else text[:37] + "..."


def cpu_to_reach(points: Sequence[tuple[float, float]], target_psnr: float, ours_cpu: float) -> dict[str, Any]:
    """A peer's CPU per frame to reach `target_psnr`, over ours, from its (cpu, psnr) settings.

    Between two settings that straddle the target the CPU is interpolated linearly in log(CPU) (PSNR grows
    about linearly in log(samples)). Beyond the settings measured the answer is a bound: 'at most' when even the
    cheapest setting is better, 'not reached' (and 'more than') when even the dearest is worse."""
    ordered = sorted(points)
    if not ordered:
        return {"reached": False, "note": "no settings measured"}
    cheapest_cpu, cheapest_psnr = ordered[0]
    if cheapest_psnr >= target_psnr:
        return {"reached": True, "ratio_at_most": round(cheapest_cpu / ours_cpu, 2),
                "note": "its cheapest setting measured is already at least as good"}
    for (cpu_a, psnr_a), (cpu_b, psnr_b) in zip(ordered, ordered[1:]):
        if psnr_a < target_psnr <= psnr_b:
            t = (target_psnr - psnr_a) / (psnr_b - psnr_a)
            cpu = math.exp(math.log(cpu_a) + t * (math.log(cpu_b) - math.log(cpu_a)))
            return {"reached": True, "ratio": round(cpu / ours_cpu, 2), "cpu_ms": round(1000.0 * cpu, 1)}
    return {"reached": False, "ratio_more_than": round(ordered[-1][0] / ours_cpu, 2),
            "note": f"not reached: its best setting measured is {max(p for _, p in ordered):.2f} dB"}


def peer_python(variable: str, default: str) -> str | None:
    """The interpreter of a peer's virtualenv, or None when it is not installed."""
    path = os.environ.get(variable, default)
    return path if Path(path).exists() else None


def peer_version(python: str | None, package: str) -> str | None:
    """The installed version of a peer's package (read from its metadata, without importing the renderer)."""
    if python is None:
        return None
    done = subprocess.run([python, "-c", f"import importlib.metadata as m; print(m.version({package!r}))"],
                          capture_output=True, text=True)
    return done.stdout.strip() if done.returncode == 0 else None


def bench_house(folder: Path) -> Scene:
    """The 1 M-triangle benchmark house (bench_render's: procedural seed 0, detail 1.0), from the shard stage
    run inline (no plan: the poses are the reference's)."""
    from pipeline.config import Job, ProceduralSource, SceneSources
    from pipeline.runtime.executor import run_unit_locally
    from pipeline.scenes.sources import load_scene_row
    from pipeline.stages import make_stage
    from pipeline.store.run_folder import RunFolder

    job = Job(name="bench-render", seed=0, embodiments=[Embodiment(name="bench", placements=[1.0])],
              scenes=SceneSources(procedural=ProceduralSource(count=1, seed=0, detail=1.0)))
    run = RunFolder.create(folder / "run", job)
    stage = make_stage("shard", job)
    for unit in stage.units(run):
        run_unit_locally(stage, run, unit)
    return load_scene_row(run.read("scenes").to_pylist()[0])


def export(scene: Scene, poses: np.ndarray, folder: Path, threads: int) -> None:
    """Write what the peer scripts read: the mesh with linear vertex colours, poses, camera, light, material."""
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "scene.npz", vertices=scene.vertices, faces=scene.faces,
             colors=srgb_to_linear(scene.vertex_colors / 255.0))
    np.save(folder / "poses.npy", poses)
    sensor, spot = Sensor(), mvpd_spot()
    tables = reflection_tables(spot)
    settings = {"width": sensor.width, "height": sensor.height, "hfov": sensor.hfov, "near": sensor.near,
                "far": sensor.far, "intrinsics": list(sensor.intrinsics()), "power": POWER, "cone": spot.cone,
                "blend": spot.blend, "threads": threads,
                "material": {"kind": "principled", "specular": spot.specular, "roughness": spot.roughness,
                             "alpha": tables.alpha, "ior": tables.ior,
                             "tables": {"albedo": tables.albedo.tolist(), "energy": tables.energy.tolist()}},
                "renders": [], "mitsuba": []}
    (folder / "settings.json").write_text(json.dumps(settings))


def run_peer(python: str, script: str, folder: Path, key: str, renders: list[dict], log: Path) -> bool:
    """Run a peer script on `renders` (settings[key]); False (with the log's tail printed) when it fails."""
    settings = json.loads((folder / "settings.json").read_text())
    settings[key] = renders
    (folder / "settings.json").write_text(json.dumps(settings))
    env = dict(os.environ)
    if "DRJIT_LIBLLVM_PATH" not in env and Path(DEBIAN_LLVM).exists():
        env["DRJIT_LIBLLVM_PATH"] = DEBIAN_LLVM  # Mitsuba's LLVM backend on Debian 12 (apt libllvm19)
    with open(log, "a") as out:
        done = subprocess.run([python, str(HERE / script), str(folder)], stdout=out, stderr=subprocess.STDOUT,
                              cwd=tempfile.gettempdir(), env=env)
    if done.returncode != 0:
        print(f"{script} failed (exit {done.returncode}); last lines of {log}:")
        print("".join(log.read_text().splitlines(keepends=True)[-15:]))
    return done.returncode == 0


def peer_output(folder: Path, name: str, scale: float) -> tuple[list[np.ndarray], list[float]]:
    """A peer's 8-bit frames (encoded at `scale` x radiance) and CPU seconds per frame."""
    run = np.load(folder / f"{name}.npz")
    return [to_8bit(image, scale) for image in run["images"]], [float(v) for v in run["cpu_seconds"]]


def to_8bit(radiance: np.ndarray, scale: float) -> np.ndarray:
    """Linear radiance -> the pipeline's 8-bit sRGB at the fixed exposure."""
    return np.rint(255.0 * linear_to_srgb(np.clip(radiance * scale, 0.0, 1.0))).astype(np.uint8)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two 8-bit images."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(255.0**2 / mse))


def compare(images: Sequence[np.ndarray], references: Sequence[np.ndarray]) -> dict[str, Any]:
    """Median, min and max PSNR of image lists, and the per-pose values."""
    values = [min(psnr(a, b), 99.0) for a, b in zip(images, references)]
    return {"psnr_median": round(float(np.median(values)), 2), "psnr_min": round(min(values), 2),
            "psnr_max": round(max(values), 2), "psnr": [round(v, 2) for v in values]}


def ours_frames(scene: Scene, poses: np.ndarray, light: Illumination) -> list[np.ndarray]:
    """Our RGB frames of `poses` under `light` ((H, W, 3) uint8)."""
    renderer = VideoRenderer(scene, Embodiment(name="bench", sensor=Sensor(), illumination=light), EXPOSURE, seed=0)
    return [renderer.render(pose).rgb.copy() for pose in poses]


def cached_json(name: str) -> dict[str, Any] | None:
    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text()) if path.exists() else None


def load_cached(name: str, indices: Sequence[int]) -> list[np.ndarray]:
    """Cached 8-bit renders `<name>_XX.png` (RGB) of the poses `indices`; CacheMismatch names a missing one."""
    images = []
    for index in indices:
        path = RESULTS / f"{name}_{index:02d}.png"
        if not path.exists():
            raise CacheMismatch(f"{path}: missing; render it anew with {FLAGS[name]}")
        images.append(cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB))
    return images


def cache_renders(name: str, images: list[np.ndarray], render: dict, indices: Sequence[int], poses: np.ndarray,
                  scene_sha: str, bpy_version: str | None, threads: int) -> None:
    """Store Cycles' 8-bit frames as `<name>_XX.png` (XX: the index of the reference pose) with `<name>.json`
    saying how they were made and what for."""
    for index, image in zip(indices, images):
        save_png(RESULTS / f"{name}_{index:02d}.png", image)
    (RESULTS / f"{name}.json").write_text(json.dumps({
        "renderer": f"Blender Cycles (bpy {bpy_version} from PyPI, benchmarks/peer_cycles.py), CPU, {threads} threads",
        "settings": {**render, "poses": list(indices), **cycles_notes(render)},
        "encoding": ENCODING_CYCLES, "made_for": made_for(scene_sha, poses[list(indices)], ENCODING_CYCLES),
        "poses": poses[list(indices)].tolist()}, indent=1) + "\n")


def cycles_notes(render: dict) -> dict[str, Any]:
    """How peer_cycles.py sets up a render (recorded beside its numbers)."""
    return {"filter_width_px": 0.01, "light_paths": f"{render['bounces']} bounces of every kind",
            "material": "Principled BSDF, specular IOR level 1.0, IOR 1.5, roughness 0.5, base colour = vertex colour",
            "light": "spot 20 W parented to the camera, spot_size 180, blend 1.0, radius 0",
            "denoiser": "OpenImageDenoise (Blender's defaults: albedo + normal passes, prefilter ACCURATE)"
            if render.get("denoise") else "none", "clamp_indirect": "Blender's default (10)", "world": "none"}


def save_png(path: Path, rgb: np.ndarray) -> None:
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])


def whole_numbers(text: str) -> list[int]:
    """A comma-separated list of whole numbers (an argparse type: a bad one is a one-line usage error)."""
    try:
        return [int(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of whole numbers, e.g. 1,4,16") from None


def load_average() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def main() -> None:
    """Run the benchmark and write benchmarks/results/light.json."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", action="store_true", help="render the converged reference anew at its "
                        "stored poses (2-7 min per frame on 2 cores)")
    parser.add_argument("--reference-floor", action="store_true", help="render the reference of poses "
                        f"{REFERENCE_FLOOR['poses']} anew with another seed (its own noise floor)")
    parser.add_argument("--cycles16", action="store_true", help="render Cycles 16 spp (no denoiser) anew at "
                        "every pose (~1 min per frame)")
    parser.add_argument("--mitsuba-spp", default="1,4,16,64", type=whole_numbers,
                        help="samples per pixel of the Mitsuba path sweep")
    parser.add_argument("--mitsuba-poses", default="0,2,4,6", type=whole_numbers,
                        help="reference poses of the Mitsuba sweep")
    parser.add_argument("--speed-repeat", type=int, default=6, help="ours' speed run renders the poses this often")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    started = time.perf_counter()
    folder = Path(tempfile.mkdtemp(prefix="bench_light_"))
    try:
        result = measure(args, folder)
    except CacheMismatch as error:
        shutil.rmtree(folder, ignore_errors=True)
        sys.exit(f"bench_light: {error}")
    except BaseException:
        print(f"bench_light: stopped; the last round's renders are kept in {folder}", file=sys.stderr)
        raise
    shutil.rmtree(folder, ignore_errors=True)
    result["wall_s"] = round(time.perf_counter() - started, 1)
    out = RESULTS.parent / "light.json"
    # numpy scalars as Python numbers: a 45-minute run must not die in its last line
    out.write_text(json.dumps(result, indent=1, default=lambda value: value.item()) + "\n")
    print(json.dumps(result["summary"], indent=1))
    print(f"wrote {out} ({result['wall_s']:.0f} s)")


def stored_poses() -> np.ndarray:
    """The reference's poses (CacheMismatch when there is no reference to read them from)."""
    meta = cached_json(REFERENCE["name"])
    if meta is None or "poses" not in meta:
        raise CacheMismatch(f"{RESULTS / 'reference.json'}: missing or without 'poses'; the bench compares at the "
                            "reference's poses (restore it from git)")
    return np.asarray(meta["poses"], dtype=np.float64)


def check_caches(args: argparse.Namespace, scene_sha: str, poses: np.ndarray) -> None:
    """Every cached render this run reuses must have been made for this scene, these poses, light and encoding."""
    for render, fresh in ((REFERENCE, args.reference), (REFERENCE_FLOOR, args.reference_floor),
                          (CYCLES16, args.cycles16)):
        if fresh:
            continue
        indices = render.get("poses", list(range(len(poses))))
        path = RESULTS / f"{render['name']}.json"
        meta = cached_json(render["name"])
        check_made_for(path, None if meta is None else meta.get("made_for"),
                       made_for(scene_sha, poses[indices], ENCODING_CYCLES), FLAGS[render["name"]])


def measure(args: argparse.Namespace, folder: Path) -> dict[str, Any]:
    """Every measurement of one run (see the module docstring)."""
    poses = stored_poses()
    scene = bench_house(folder)
    scene_sha = scene_hash(scene)
    check_caches(args, scene_sha, poses)
    export(scene, poses, folder / "peer", args.threads)
    cycles, mitsuba = (peer_python("BPY_PYTHON", "/work/venvs/bpy/bin/python"),
                       peer_python("MITSUBA_PYTHON", "/work/venvs/mitsuba/bin/python"))
    result: dict[str, Any] = {
        "scene": {"triangles": scene.triangle_count, "sha256": scene_sha, "poses": "the reference's stored poses",
                  "poses_sha256": poses_hash(poses)},
        "resolution": [Sensor().width, Sensor().height], "threads": args.threads, "exposure": EXPOSURE,
        "power_w": POWER, "ours": mvpd_spot().model_dump(mode="json"),
        "peers": {"bpy": peer_version(cycles, "bpy"), "mitsuba": peer_version(mitsuba, "mitsuba"),
                  "mitsuba_variant": "llvm_ad_rgb"},
        "load_average_start": load_average()}
    fresh = render_cached_anew(args, cycles, folder, poses, scene_sha, result["peers"]["bpy"])
    rounds = run_rounds(args, scene, poses, folder, cycles, mitsuba)
    result["load_average_end"] = load_average()
    result["rounds"] = [{"poses": e["poses"], "mitsuba_poses": e.get("mitsuba_poses", []),
                         "load_average_1_5_15_min": e["load_average"]} for e in rounds]
    result.update(evaluate(args, scene, poses, rounds, fresh))
    return result


def render_cached_anew(args: argparse.Namespace, cycles: str | None, folder: Path, poses: np.ndarray,
                       scene_sha: str, bpy_version: str | None) -> list[str]:
    """Render the caches the flags ask for (Cycles, at the stored poses) and store them; their names."""
    wanted = [r for r, flag in ((REFERENCE, args.reference), (REFERENCE_FLOOR, args.reference_floor),
                                (CYCLES16, args.cycles16)) if flag]
    if not wanted:
        return []
    if cycles is None:
        raise CacheMismatch("no bpy virtualenv to render the caches anew (bash benchmarks/setup_light_peers.sh, or "
                            "set BPY_PYTHON)")
    renders = [{**r, "poses": r.get("poses", list(range(len(poses))))} for r in wanted]
    if not run_peer(cycles, "peer_cycles.py", folder / "peer", "renders", renders, folder / "cycles.log"):
        raise CacheMismatch(f"Cycles failed rendering {', '.join(r['name'] for r in wanted)} (log above)")
    for render in renders:
        images, _ = peer_output(folder / "peer", render["name"], BLENDER_SPOT_SCALE * EXPOSURE)
        cache_renders(render["name"], images, render, render["poses"], poses, scene_sha, bpy_version, args.threads)
    return [r["name"] for r in wanted]


def run_rounds(args: argparse.Namespace, scene: Scene, poses: np.ndarray, folder: Path, cycles: str | None,
               mitsuba: str | None) -> list[dict[str, Any]]:
    """ROUNDS rounds of ours (end to end), Cycles and Mitsuba in turn. Round r renders the peers at the poses
    r, r + ROUNDS, ... (so the rounds together cover every pose once), ours at every pose; the first round also
    the direct-light checks. Returns per round: ours' CPU and wall per frame, each peer's frames and CPU."""
    body = Embodiment(name="bench", sensor=Sensor(), illumination=mvpd_spot())
    speed_poses = np.tile(poses, (args.speed_repeat, 1, 1))
    sweep_poses, spps = args.mitsuba_poses, args.mitsuba_spp
    run_ours(scene, poses[:2], body, EXPOSURE, folder / "warm.zarr", threads=args.threads)  # first-use costs
    shutil.rmtree(folder / "warm.zarr", ignore_errors=True)
    rounds = []
    for r in range(ROUNDS):
        mine = list(range(r, len(poses), ROUNDS))
        entry: dict[str, Any] = {"poses": mine, "load_average": load_average()}
        timing = run_ours(scene, speed_poses, body, EXPOSURE, folder / f"speed{r}.zarr", threads=args.threads)
        shutil.rmtree(folder / f"speed{r}.zarr", ignore_errors=True)
        entry["ours"] = {"cpu_s": timing["cpu_s"] / len(speed_poses), "wall_s": timing["total_s"] / len(speed_poses)}
        print(f"round {r}: ours {1000 * entry['ours']['cpu_s']:.0f} ms CPU per frame", flush=True)
        if cycles is not None:
            renders = [{**CYCLES16_OIDN, "poses": mine}, {**CYCLES1_OIDN, "poses": mine},
                       {**CYCLES16, "name": "cycles16_again", "poses": mine[:1]}]
            if r == 0:
                renders.append({"name": "cycles_direct", "samples": 1, "bounces": 0})
            if run_peer(cycles, "peer_cycles.py", folder / "peer", "renders", renders, folder / "cycles.log"):
                entry["cycles"] = collect(folder / "peer", "", renders, len(poses), BLENDER_SPOT_SCALE * EXPOSURE)
        mine_sweep = [i for i in sweep_poses if i in mine] or mine[:1]
        if mitsuba is not None:
            renders = [{"name": f"path{spp}", "matched": True, "integrator": "path", "max_depth": MITSUBA_DEPTH,
                        "samples": spp, "poses": mine_sweep} for spp in spps]
            if r == 0:
                renders += [{"name": "direct", "matched": True, "integrator": "direct", "samples": 1},
                            {"name": "stock_direct", "integrator": "direct", "samples": 1}]  # what matching mends
            if run_peer(mitsuba, "peer_mitsuba.py", folder / "peer", "mitsuba", renders, folder / "mitsuba.log"):
                entry["mitsuba"] = collect(folder / "peer", "mitsuba_", renders, len(poses), EXPOSURE)
                entry["mitsuba_poses"] = mine_sweep
        rounds.append(entry)
    return rounds


def per_frame_ms(rounds: list[list[float]]) -> dict[str, Any]:
    """CPU ms per frame: each round's median frame, the median and spread over rounds."""
    values = [1000.0 * float(np.median(r)) for r in rounds if r]
    return {"per_round": [round(v, 1) for v in values], "median": round(float(np.median(values)), 1),
            "min": round(min(values), 1), "max": round(max(values), 1)}


def collect(folder: Path, prefix: str, renders: list[dict], count: int, scale: float
            ) -> dict[str, tuple[list[int], list[np.ndarray], list[float]]]:
    """Each render of a peer's run: the pose indices it rendered (all `count` when it names none), its 8-bit
    frames and CPU seconds per frame."""
    return {render["name"]: (render.get("poses", list(range(count))),
                             *peer_output(folder, prefix + render["name"], scale)) for render in renders}


def gather(rounds: list[dict[str, Any]], peer: str, name: str) -> tuple[dict[int, np.ndarray], list[list[float]]]:
    """A peer render's frames by pose index over the rounds, and its CPU seconds per round."""
    frames: dict[int, np.ndarray] = {}
    cpu: list[list[float]] = []
    for entry in rounds:
        if name in entry.get(peer, {}):
            indices, images, seconds = entry[peer][name]
            frames.update(zip(indices, images))
            cpu.append(seconds)
    return frames, cpu


def evaluate(args: argparse.Namespace, scene: Scene, poses: np.ndarray, rounds: list[dict[str, Any]],
             fresh: list[str]) -> dict[str, Any]:
    """Quality and speed of every peer from the rounds; the ratios; the side-by-side pictures."""
    everything = list(range(len(poses)))
    reference = load_cached("reference", everything)
    ours = ours_frames(scene, poses, mvpd_spot())
    ours_direct = ours_frames(scene, poses, mvpd_spot(bounces=0))
    ours_cpu = per_frame_ms([[e["ours"]["cpu_s"]] for e in rounds])
    quality: dict[str, Any] = {"ours": compare(ours, reference), "ours_direct_only": compare(ours_direct, reference)}
    floor = load_cached("reference_seed2", REFERENCE_FLOOR["poses"])
    quality["reference_seed2_vs_reference"] = {"poses": REFERENCE_FLOOR["poses"],
                                               **compare(floor, [reference[i] for i in REFERENCE_FLOOR["poses"]])}
    speed: dict[str, Any] = {"ours_end_to_end_cpu_ms": ours_cpu,
                             "ours_end_to_end_wall_ms": per_frame_ms([[e["ours"]["wall_s"]] for e in rounds])}
    checks: dict[str, Any] = {}
    peers: dict[str, list[tuple[float, float]]] = {}
    cached16 = load_cached("cycles16", everything)
    quality["cycles16"] = compare(cached16, reference)
    again, again_cpu = gather(rounds, "cycles", "cycles16_again")
    if again:
        agreement = compare([again[i] for i in sorted(again)], [cached16[i] for i in sorted(again)])
        # Same seed, samples and threads: Cycles repeats itself to the last bit but for a few values off by one.
        checks["cycles16_cache_rerendered_vs_cached"] = {"poses": sorted(again), "reproduces":
                                                         bool(agreement["psnr_min"] >= REPRODUCED_PSNR), **agreement}
        speed["cycles16_cpu_ms"] = per_frame_ms(again_cpu)
        peers["cycles16"] = [(speed["cycles16_cpu_ms"]["median"], quality["cycles16"]["psnr_median"])]
    for name in ("cycles16_oidn", "cycles1_oidn"):
        frames, cpu = gather(rounds, "cycles", name)
        if len(frames) == len(poses):
            quality[name] = compare([frames[i] for i in everything], reference)
            speed[f"{name}_cpu_ms"] = per_frame_ms(cpu)
    if "cycles16_oidn_cpu_ms" in speed and "cycles1_oidn_cpu_ms" in speed:
        peers["cycles_oidn"] = [(speed[f"{n}_cpu_ms"]["median"], quality[n]["psnr_median"])
                                for n in ("cycles1_oidn", "cycles16_oidn")]
    direct, _ = gather(rounds, "cycles", "cycles_direct")
    if direct:
        checks["ours_direct_vs_cycles_direct"] = compare(ours_direct, [direct[i] for i in everything])
    direct, _ = gather(rounds, "mitsuba", "direct")
    if direct:
        checks["ours_direct_vs_mitsuba_matched_direct"] = compare(ours_direct, [direct[i] for i in everything])
    direct, _ = gather(rounds, "mitsuba", "stock_direct")
    if direct:  # Mitsuba's own spot (linear falloff) and diffuse material, its box filter: not our light
        checks["ours_direct_vs_mitsuba_stock_spot_diffuse_direct"] = compare(ours_direct, [direct[i] for i in everything])
    sweep = mitsuba_sweep(args, rounds, ours, reference)
    if sweep:
        quality["mitsuba_path"] = sweep
        sweep_poses = sweep["poses"]
        ours_there = compare([ours[i] for i in sweep_poses], [reference[i] for i in sweep_poses])["psnr_median"]
    ratios = {}
    target = quality["ours"]["psnr_median"]
    for name, points in peers.items():
        ratios[name] = cpu_to_reach(points, target, ours_cpu["median"])
    if sweep:
        ratios["mitsuba_path"] = {"ours_psnr_on_its_poses": ours_there,
                                  **cpu_to_reach([(s["cpu_ms"]["median"], s["psnr_median"]) for s in sweep["spp"]],
                                                 ours_there, ours_cpu["median"])}
    side_by_side(ours, gather(rounds, "cycles", "cycles16_oidn")[0], reference)
    summary = summarise(quality, speed, ratios, checks)
    return {"rendered_anew": fresh, "quality": quality, "speed": speed, "checks": checks,
            "their_cpu_to_reach_our_psnr_over_ours": ratios, "summary": summary,
            "targets": {"psnr_at_least_42": target >= TARGET_PSNR,
                        "cpu_at_most_150_ms": ours_cpu["median"] <= TARGET_CPU_MS}}


def mitsuba_sweep(args: argparse.Namespace, rounds: list[dict[str, Any]], ours: list[np.ndarray],
                  reference: list[np.ndarray]) -> dict[str, Any] | None:
    """The Mitsuba path sweep: per spp, PSNR on the sweep poses and CPU ms per frame."""
    points = []
    covered: list[int] = []
    for spp in args.mitsuba_spp:
        frames, cpu = gather(rounds, "mitsuba", f"path{spp}")
        if not frames:
            return None
        covered = sorted(frames)
        points.append({"spp": spp, **compare([frames[i] for i in covered], [reference[i] for i in covered]),
                       "cpu_ms": per_frame_ms(cpu)})
    return {"poses": covered, "max_depth": MITSUBA_DEPTH, "spp": points}


def side_by_side(ours: list[np.ndarray], authors: dict[int, np.ndarray], reference: list[np.ndarray]) -> None:
    """ours | Cycles 16 spp + OIDN | reference per pose, half size (area-averaged), under RESULTS."""
    for index, (a, c) in enumerate(zip(ours, reference)):
        if index not in authors:
            continue
        panels = np.concatenate([a, authors[index], c], axis=1)
        save_png(RESULTS / f"side_by_side_{index:02d}.png",
                 cv2.resize(panels, (panels.shape[1] // 2, panels.shape[0] // 2), interpolation=cv2.INTER_AREA))


def summarise(quality: dict[str, Any], speed: dict[str, Any], ratios: dict[str, Any], checks: dict[str, Any]
              ) -> dict[str, Any]:
    """The table of the issue: per peer PSNR median and CPU ms per frame, and the ratios."""
    table: dict[str, Any] = {"ours": {"psnr": quality["ours"]["psnr_median"],
                                      "cpu_ms": speed["ours_end_to_end_cpu_ms"]["median"]}}
    for name in ("cycles16", "cycles16_oidn", "cycles1_oidn"):
        if name in quality and f"{name}_cpu_ms" in speed:
            table[name] = {"psnr": quality[name]["psnr_median"], "cpu_ms": speed[f"{name}_cpu_ms"]["median"]}
    for point in quality.get("mitsuba_path", {}).get("spp", []):
        table[f"mitsuba_path_{point['spp']}spp"] = {"psnr": point["psnr_median"], "cpu_ms": point["cpu_ms"]["median"]}
    return {"table": table, "ratios": ratios,
            "checks": {name: value["psnr_median"] for name, value in checks.items()}}


if __name__ == "__main__":
    main()
