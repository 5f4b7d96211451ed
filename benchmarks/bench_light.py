"""Light benchmark (issue 21): our spot light (principled material, indirect bounces) against Blender Cycles and Mitsuba 3.

Run: `cd /work/wt/light && .venv/bin/python benchmarks/bench_light.py [--poses 8] [--speed-frames 48]`.
Peers, each in a virtualenv of its own (`bash benchmarks/setup_light_peers.sh` makes them):
- Cycles: `bpy` from PyPI in /work/venvs/bpy (it pins numpy 1.x); driven through benchmarks/peer_cycles.py.
- Mitsuba 3: `mitsuba` in /work/venvs/mitsuba, variant `llvm_ad_rgb` (Debian 12: apt `libllvm19`, found
  through DRJIT_LIBLLVM_PATH); driven through benchmarks/peer_mitsuba.py.
A missing peer is skipped with a message saying how to install it. Override the venvs with BPY_PYTHON /
MITSUBA_PYTHON.

Same run, same poses of the 1 M-triangle benchmark house (bench_render's planned trajectories), 640x480,
2 threads, the MVPd 20 W spot (180-degree cone, blend 1.0) at a fixed exposure:
- quality: PSNR and mean absolute difference (8-bit sRGB) against a converged Cycles reference (the
  authors' light paths and material: Principled specular 1.0 / roughness 0.5, 16 bounces of every kind;
  `REFERENCE` below says how many samples and that OpenImageDenoise cleaned it), for ours, for the
  authors' own Cycles 16 spp render, for our direct light alone, and (checks of the direct models) ours
  against Cycles' direct-only renders, diffuse and principled (no bounces; point light, 0.01 px filter: 1
  spp is exact). The reference's own floor: the same reference rendered with another seed for two poses
  (`REFERENCE_FLOOR`), against the reference (its noise shows twice: each reference alone is ~3 dB
  better). The reference, its second seed and the 16 spp images are cached as 8-bit PNGs under
  benchmarks/results/light/ with JSONs saying how they were made; `--reference`, `--reference-floor` and
  `--cycles16` render them anew (the reference took 2-7 min per frame on the shared 2 cores). Also the
  CPU milliseconds per frame of our indirect light alone (IndirectGather.irradiance).
- speed: ours end to end (every buffer and the Zarr write, bench_render.run_ours), Mitsuba `direct` 1 spp,
  Cycles 1 spp (authors' light paths), per frame, in this run.
- side-by-side PNGs: ours | Cycles 16 spp | reference, one per pose (half size), under benchmarks/results/light/.

Blender's spot spreads its watts over the whole sphere (I = P / 4 pi, as if it were a point light) where
our model spreads them over the cone (P / 2 pi for 180 degrees): Cycles' radiance is scaled by
BLENDER_SPOT_SCALE before the shared exposure. Results: benchmarks/results/light.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
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

from bench_render import planned_poses, run_ours, spread  # noqa: E402
from pipeline.config import Embodiment, Illumination, IndirectLight, Sensor  # noqa: E402
from pipeline.render.lighting import linear_to_srgb, srgb_to_linear  # noqa: E402
from pipeline.render.raycaster import RayHits  # noqa: E402
from pipeline.render.renderer import VideoRenderer  # noqa: E402
from pipeline.scenes.scene import Scene  # noqa: E402

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "light"
EXPOSURE = 4.0  # as bench_render: a 20 W light puts white at 1 m near full scale
BLENDER_SPOT_SCALE = 2.0  # 4 pi / 2 pi: measured 0.5000 ratio of Cycles to our direct radiance
POWER = 20.0
REFERENCE = {"name": "reference", "samples": 32, "bounces": 16, "denoise": True, "seed": 1}
# The reference's own floor: the same render with another seed, of two quality poses (the worst and the first).
REFERENCE_FLOOR = {**REFERENCE, "name": "reference_seed2", "seed": 2, "poses": [0, 6]}
AUTHORS = {"name": "cycles16", "samples": 16, "bounces": 16, "seed": 0}
DEBIAN_LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
TARGET_PSNR = 35.0
TARGET_VS_MITSUBA = 1.5
TARGET_VS_CYCLES = 25.0


def mvpd_spot(material: str = "principled", bounces: int = 16) -> Illumination:
    """The MVPd 20 W spot with the authors' material (or diffuse) and `bounces` of indirect light."""
    return Illumination(kind="spot", power=POWER, cone=180.0, blend=1.0, material=material, specular=1.0,
                        roughness=0.5, indirect=IndirectLight(bounces=bounces))


def peer_python(variable: str, default: str) -> str | None:
    """The interpreter of a peer's virtualenv, or None when it is not installed."""
    path = os.environ.get(variable, default)
    return path if Path(path).exists() else None


def cycles_python() -> str | None:
    return peer_python("BPY_PYTHON", "/work/venvs/bpy/bin/python")


def mitsuba_python() -> str | None:
    return peer_python("MITSUBA_PYTHON", "/work/venvs/mitsuba/bin/python")


def peer_version(python: str | None, package: str) -> str | None:
    """The installed version of a peer's package (read from its metadata, without importing the renderer)."""
    if python is None:
        return None
    done = subprocess.run([python, "-c", f"import importlib.metadata as m; print(m.version({package!r}))"],
                          capture_output=True, text=True)
    return done.stdout.strip() if done.returncode == 0 else None


def export(scene: Scene, poses: np.ndarray, folder: Path, renders: list[dict], mitsuba: list[dict], threads: int) -> None:
    """Write what the peer scripts read: the mesh with linear vertex colours, poses, settings."""
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "scene.npz", vertices=scene.vertices, faces=scene.faces,
             colors=srgb_to_linear(scene.vertex_colors / 255.0))
    np.save(folder / "poses.npy", poses)
    sensor = Sensor()
    settings = {"width": sensor.width, "height": sensor.height, "hfov": sensor.hfov, "near": sensor.near,
                "far": sensor.far, "power": POWER, "cone": 180.0, "blend": 1.0, "threads": threads,
                "material": {"kind": "principled", "specular": 1.0, "roughness": 0.5},
                "renders": renders, "mitsuba": mitsuba}
    (folder / "settings.json").write_text(json.dumps(settings, indent=1))


def run_peer(python: str, script: str, folder: Path, log: Path) -> bool:
    """Run a peer script; False (with the log's tail printed) when it fails."""
    env = dict(os.environ)
    if "DRJIT_LIBLLVM_PATH" not in env and Path(DEBIAN_LLVM).exists():
        env["DRJIT_LIBLLVM_PATH"] = DEBIAN_LLVM  # Mitsuba's LLVM backend on Debian 12 (apt libllvm19)
    with open(log, "w") as out:
        done = subprocess.run([python, str(HERE / script), str(folder)], stdout=out, stderr=subprocess.STDOUT,
                              cwd=tempfile.gettempdir(), env=env)
    if done.returncode != 0:
        print(f"{script} failed (exit {done.returncode}); last lines of {log}:")
        print("".join(log.read_text().splitlines(keepends=True)[-15:]))
    return done.returncode == 0


def to_8bit(radiance: np.ndarray, scale: float) -> np.ndarray:
    """Linear radiance -> the pipeline's 8-bit sRGB at the fixed exposure."""
    return np.rint(255.0 * linear_to_srgb(np.clip(radiance * scale, 0.0, 1.0))).astype(np.uint8)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two 8-bit images."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0**2 / mse)


def mad(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference in grey levels (of 255)."""
    return float(np.mean(np.abs(a.astype(np.float64) - b.astype(np.float64))))


def compare(images: list[np.ndarray], references: list[np.ndarray]) -> dict[str, Any]:
    """Median, min and max PSNR and MAD of image lists, and the per-pose values."""
    values = [psnr(a, b) for a, b in zip(images, references)]
    errors = [mad(a, b) for a, b in zip(images, references)]
    return {"psnr_median": round(float(np.median(values)), 2), "psnr_min": round(min(values), 2),
            "psnr_max": round(max(values), 2), "mad_median": round(float(np.median(errors)), 2),
            "psnr": [round(v, 2) for v in values], "mad": [round(v, 2) for v in errors]}


def ours_frames(scene: Scene, poses: np.ndarray, light: Illumination, seed: int = 0) -> list[np.ndarray]:
    """Our RGB frames of `poses` under `light` (BGR-free (H, W, 3) uint8)."""
    renderer = VideoRenderer(scene, Embodiment(name="bench", sensor=Sensor(), illumination=light), EXPOSURE, seed=seed)
    return [renderer.render(pose).rgb.copy() for pose in poses]


def load_cached(name: str, indices: Sequence[int]) -> list[np.ndarray] | None:
    """Cached 8-bit renders `<name>_XX.png` (RGB) of the quality poses `indices`, or None when one is missing."""
    paths = [RESULTS / f"{name}_{i:02d}.png" for i in indices]
    if not all(p.exists() for p in paths):
        return None
    return [cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in paths]


def cache_renders(name: str, radiance: np.ndarray, render: dict, poses: np.ndarray, threads: int,
                  bpy_version: str | None) -> list[np.ndarray]:
    """Encode Cycles renders like ours, store them as `<name>_XX.png` (XX: the index of the quality pose) with
    `<name>.json` saying how they were made."""
    images = [to_8bit(image, BLENDER_SPOT_SCALE * EXPOSURE) for image in radiance]
    poses = poses[render["poses"]] if "poses" in render else poses
    for index, image in zip(render.get("poses", range(len(images))), images):
        save_png(RESULTS / f"{name}_{index:02d}.png", image)
    (RESULTS / f"{name}.json").write_text(json.dumps({
        "renderer": f"Blender Cycles (bpy {bpy_version} from PyPI, benchmarks/peer_cycles.py), CPU, {threads} threads",
        "settings": {**render, "filter_width_px": 0.01, "light_paths": f"{render['bounces']} bounces of every kind",
                     "material": "Principled BSDF, specular IOR level 1.0, IOR 1.5, roughness 0.5, base colour = vertex colour",
                     "light": "spot 20 W parented to the camera, spot_size 180, blend 1.0, radius 0",
                     "denoiser": "OpenImageDenoise, albedo + normal passes, prefilter ACCURATE" if render.get("denoise")
                     else "none", "clamp_indirect": "Blender's default (10)", "world": "none"},
        "encoding": f"linear radiance x {BLENDER_SPOT_SCALE} (Blender's spot watts) x exposure {EXPOSURE}, "
                    "clipped, sRGB, rounded to 8 bits",
        "poses": np.asarray(poses).tolist()}, indent=1) + "\n")
    return images


def save_png(path: Path, rgb: np.ndarray) -> None:
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])


def main() -> None:
    """Run the benchmark and write benchmarks/results/light.json."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=8, help="poses compared for quality")
    parser.add_argument("--speed-frames", type=int, default=48, help="frames of the end-to-end speed runs")
    parser.add_argument("--cycles-speed-frames", type=int, default=4, help="frames of Cycles' 1 spp timing")
    parser.add_argument("--repeats", type=int, default=3, help="speed runs of ours and Mitsuba (median kept)")
    parser.add_argument("--reference", action="store_true", help="render the converged reference anew")
    parser.add_argument("--cycles16", action="store_true", help="render the authors' 16 spp images anew "
                        "(cached beside the reference otherwise: ~1 min per frame on 2 cores)")
    parser.add_argument("--reference-floor", action="store_true", help="render the reference of poses "
                        f"{REFERENCE_FLOOR['poses']} anew with another seed (its own noise floor; cached otherwise)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--speed-only", action="store_true", help="only ours against Mitsuba direct 1 spp (no "
                        "Cycles, no quality); writes results/light_speed.json")
    args = parser.parse_args()

    folder = Path(tempfile.mkdtemp(prefix="bench_light_"))
    RESULTS.mkdir(parents=True, exist_ok=True)
    try:
        result = measure_speed_only(args, folder) if args.speed_only else measure(args, folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    out = HERE / "results" / ("light_speed.json" if args.speed_only else "light.json")
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k not in ("poses",)}, indent=1))
    print(f"wrote {out}")


def measure(args: argparse.Namespace, folder: Path) -> dict[str, Any]:
    """Every measurement of one run (see the module docstring)."""
    scene, all_poses, pose_source = planned_poses(args.speed_frames, folder)
    poses = spread(all_poses, args.poses)
    speed_poses = spread(all_poses, args.speed_frames)
    reference = None if args.reference else load_cached("reference", range(len(poses)))
    authors = None if args.cycles16 else load_cached("cycles16", range(len(poses)))
    floor = None if args.reference_floor else load_cached(REFERENCE_FLOOR["name"], REFERENCE_FLOOR["poses"])
    quality_frames = {"frames": len(poses)}
    # Direct light only (no bounces; a point light and a 0.01 px filter: 1 spp is exact), diffuse and principled.
    renders = [{"name": "direct", "samples": 4, "bounces": 0, "material": "diffuse", **quality_frames},
               {"name": "direct_principled", "samples": 1, "bounces": 0, **quality_frames},
               {"name": "cycles1", "samples": 1, "bounces": 16, "frames": args.cycles_speed_frames}]
    renders += [{**AUTHORS, **quality_frames}] if authors is None else []
    renders += [{**REFERENCE, **quality_frames}] if reference is None else []
    renders += [REFERENCE_FLOOR] if floor is None else []
    # The poses file holds the quality poses, then the speed poses (Mitsuba times those).
    export(scene, np.concatenate([poses, speed_poses]), folder / "peer", renders, [], args.threads)
    result: dict[str, Any] = {"scene": {"triangles": scene.triangle_count, "poses": pose_source},
                              "resolution": [640, 480], "threads": args.threads, "exposure": EXPOSURE,
                              "power_w": POWER, "quality_poses": len(poses), "speed_frames": len(speed_poses),
                              "ours": mvpd_spot().model_dump(mode="json")}
    cycles = cycles_python()
    bpy_version = peer_version(cycles, "bpy")
    result["peers"] = {"bpy": bpy_version, "mitsuba": peer_version(mitsuba_python(), "mitsuba")}
    cycles_ok = False
    if cycles is None:
        print("Cycles skipped: no bpy virtualenv (bash benchmarks/setup_light_peers.sh, or set BPY_PYTHON)")
    else:
        cycles_ok = run_peer(cycles, "peer_cycles.py", folder / "peer", folder / "cycles.log")
    if cycles_ok and authors is None:
        authors = cache_renders("cycles16", np.load(folder / "peer" / "cycles16.npz")["images"], AUTHORS, poses,
                                args.threads, bpy_version)
    if cycles_ok and reference is None:
        reference = cache_renders("reference", np.load(folder / "peer" / "reference.npz")["images"], REFERENCE, poses,
                                  args.threads, bpy_version)
    if cycles_ok and floor is None:
        floor = cache_renders(REFERENCE_FLOOR["name"], np.load(folder / "peer" / "reference_seed2.npz")["images"],
                              REFERENCE_FLOOR, poses, args.threads, bpy_version)
    if reference is None:
        print("no converged reference (cached PNGs missing and Cycles unavailable): quality not measured")
    quality = measure_quality(scene, poses, reference, authors, folder / "peer" if cycles_ok else None)
    if reference is not None and floor is not None:
        quality["reference_seed2_vs_reference"] = {
            "poses": REFERENCE_FLOOR["poses"], **compare(floor, [reference[i] for i in REFERENCE_FLOOR["poses"]])}
    result["quality"] = quality
    result["speed"] = measure_speed(scene, speed_poses, args, folder, cycles_ok)
    result["targets"] = targets(result)
    return result


def measure_speed_only(args: argparse.Namespace, folder: Path) -> dict[str, Any]:
    """The speed part of `measure`: ours end to end against Mitsuba direct 1 spp, same poses, same run."""
    scene, all_poses, pose_source = planned_poses(args.speed_frames, folder)
    speed_poses = spread(all_poses, args.speed_frames)
    # The peer times the poses after the first `args.poses` (the quality poses in a full run).
    export(scene, np.concatenate([speed_poses[: args.poses], speed_poses]), folder / "peer", [], [], args.threads)
    result: dict[str, Any] = {"scene": {"triangles": scene.triangle_count, "poses": pose_source},
                              "resolution": [640, 480], "threads": args.threads, "speed_frames": len(speed_poses),
                              "ours": mvpd_spot().model_dump(mode="json"), "quality": {},
                              "peers": {"mitsuba": peer_version(mitsuba_python(), "mitsuba")}}
    result["speed"] = measure_speed(scene, speed_poses, args, folder, cycles_ok=False)
    result["targets"] = targets(result)
    return result


def measure_quality(scene: Scene, poses: np.ndarray, reference: list[np.ndarray] | None,
                    authors: list[np.ndarray] | None, peer: Path | None) -> dict[str, Any]:
    """PSNR / MAD of ours and of Cycles 16 spp (`authors`) against the reference; the checks of the direct
    models (Cycles' diffuse and principled direct renders in `peer`); side-by-side PNGs."""
    quality: dict[str, Any] = {}
    ours = ours_frames(scene, poses, mvpd_spot())
    ours_direct = ours_frames(scene, poses, mvpd_spot(bounces=0))
    if peer is not None:
        for material, name, frames in (("diffuse", "direct", ours_frames(scene, poses, mvpd_spot("diffuse", 0))),
                                       ("principled", "direct_principled", ours_direct)):
            cycles_direct = [to_8bit(image, BLENDER_SPOT_SCALE * EXPOSURE)
                             for image in np.load(peer / f"{name}.npz")["images"][: len(poses)]]
            quality[f"{material}_direct_vs_cycles_direct"] = compare(frames, cycles_direct)
    quality["indirect_cpu_ms_per_frame"] = indirect_cpu_ms(scene, poses)
    if reference is None:
        return quality
    quality["ours_vs_reference"] = compare(ours, reference)
    quality["ours_direct_only_vs_reference"] = compare(ours_direct, reference)
    quality["ours_diffuse_material_vs_reference"] = compare(ours_frames(scene, poses, mvpd_spot(material="diffuse")),
                                                            reference)
    if authors is not None:
        quality["cycles16_vs_reference"] = compare(authors, reference)
        for index, (a, b, c) in enumerate(zip(ours, authors, reference)):
            # Half size (area-averaged) keeps the 8 files small; the full-size panels are the cached PNGs.
            panels = np.concatenate([a, b, c], axis=1)
            save_png(RESULTS / f"side_by_side_{index:02d}.png",
                     cv2.resize(panels, (panels.shape[1] // 2, panels.shape[0] // 2), interpolation=cv2.INTER_AREA))
    return quality


def indirect_cpu_ms(scene: Scene, poses: np.ndarray, repeats: int = 3) -> dict[str, Any]:
    """CPU milliseconds per frame of the indirect light alone (IndirectGather.irradiance, every thread), per
    repeat over `poses`, and their median."""
    renderer = VideoRenderer(scene, Embodiment(name="bench", sensor=Sensor(), illumination=mvpd_spot()), EXPOSURE)
    traced = [(copied(renderer.trace(pose)), pose) for pose in poses]
    renderer.indirect.irradiance(*traced[0])  # compiled and warm
    per_repeat = []
    for _ in range(repeats):
        started = time.process_time()
        for hits, pose in traced:
            renderer.indirect.irradiance(hits, pose)
        per_repeat.append(1000.0 * (time.process_time() - started) / len(traced))
    return {"per_repeat": [round(v, 1) for v in per_repeat], "median": round(float(np.median(per_repeat)), 1)}


def copied(hits: RayHits) -> RayHits:
    """A copy of `hits`: the caster writes every pose's hits into the same buffers."""
    return RayHits(*(np.array(getattr(hits, field.name)) for field in dataclasses.fields(hits)))


def measure_speed(scene: Scene, poses: np.ndarray, args: argparse.Namespace, folder: Path,
                  cycles_ok: bool) -> dict[str, Any]:
    """Per frame: wall and CPU seconds of ours end to end (each repeat), Mitsuba direct 1 spp (each repeat),
    Cycles 1 spp; ratios of medians. The machine is shared: CPU seconds (every thread of the process) say
    what a frame costs whatever else runs, wall seconds what this run saw."""
    body = Embodiment(name="bench", sensor=Sensor(), illumination=mvpd_spot())
    mitsuba = mitsuba_python()
    if mitsuba is None:
        print("Mitsuba skipped: no mitsuba virtualenv (bash benchmarks/setup_light_peers.sh, or set MITSUBA_PYTHON)")
    wall, cpu, their_wall, their_cpu = [], [], [], []
    settings_path = folder / "peer" / "settings.json"
    for repeat in range(args.repeats):  # ours and Mitsuba take turns, so load drifts fall on both alike
        timing = run_ours(scene, poses, body, EXPOSURE, folder / f"speed{repeat}.zarr", threads=args.threads)
        wall.append(timing["total_s"] / len(poses))
        cpu.append(timing["cpu_s"] / len(poses))
        shutil.rmtree(folder / f"speed{repeat}.zarr", ignore_errors=True)
        if mitsuba is None:
            continue
        settings = json.loads(settings_path.read_text())
        settings["mitsuba"] = [{"name": f"direct1_{repeat}", "integrator": "direct", "samples": 1}]
        settings_path.write_text(json.dumps(settings, indent=1))
        if not run_peer(mitsuba, "peer_mitsuba.py", folder / "peer", folder / "mitsuba.log"):
            mitsuba = None
            continue
        run = np.load(folder / "peer" / f"mitsuba_direct1_{repeat}.npz")
        # The peer renders the quality poses first: time the speed poses only.
        their_wall.append(float(np.median(run["seconds"][args.poses:])))
        their_cpu.append(float(np.median(run["cpu_seconds"][args.poses:])))
    speed: dict[str, Any] = {"ours_end_to_end": per_frame(wall, cpu)}
    if their_wall and mitsuba is not None:
        speed["mitsuba_direct1"] = per_frame(their_wall, their_cpu)
        speed["ours_vs_mitsuba"] = ratios(speed["mitsuba_direct1"], speed["ours_end_to_end"])
    if cycles_ok:
        run = np.load(folder / "peer" / "cycles1.npz")
        speed["cycles1"] = per_frame(list(run["seconds"]), list(run["cpu_seconds"]))
        speed["ours_vs_cycles1"] = ratios(speed["cycles1"], speed["ours_end_to_end"])
    return speed


def per_frame(wall: list[float], cpu: list[float]) -> dict[str, Any]:
    """Medians and spreads of per-frame wall and CPU seconds, and the fps of the median."""
    return {"wall_s": [round(float(v), 4) for v in wall], "cpu_s": [round(float(v), 4) for v in cpu],
            "wall_median_s": round(float(np.median(wall)), 4), "cpu_median_s": round(float(np.median(cpu)), 4),
            "fps_median": round(1.0 / float(np.median(wall)), 2)}


def ratios(theirs: dict[str, Any], ours: dict[str, Any]) -> dict[str, float]:
    """How many times faster ours is, by wall time (the target) and by CPU time."""
    return {"wall": round(theirs["wall_median_s"] / ours["wall_median_s"], 2),
            "cpu": round(theirs["cpu_median_s"] / ours["cpu_median_s"], 2)}


def targets(result: dict[str, Any]) -> dict[str, Any]:
    """Each target of the issue and whether this run met it."""
    quality, speed = result["quality"], result["speed"]
    out: dict[str, Any] = {}
    if "ours_vs_reference" in quality:
        ours = quality["ours_vs_reference"]["psnr_median"]
        out["psnr_at_least_35"] = ours >= TARGET_PSNR
        if "cycles16_vs_reference" in quality:
            out["closer_than_cycles16"] = ours > quality["cycles16_vs_reference"]["psnr_median"]
    if "ours_vs_mitsuba" in speed:
        out["at_least_1.5x_mitsuba_direct1"] = speed["ours_vs_mitsuba"]["wall"] >= TARGET_VS_MITSUBA
    if "ours_vs_cycles1" in speed:
        out["at_least_25x_cycles1"] = speed["ours_vs_cycles1"]["wall"] >= TARGET_VS_CYCLES
    return out


if __name__ == "__main__":
    main()
