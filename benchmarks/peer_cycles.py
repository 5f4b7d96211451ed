"""Blender Cycles peer of bench_light.py: renders a scene exported by it, in its own virtualenv (bpy pins numpy 1.x).

Run by bench_light.py as `/work/venvs/bpy/bin/python benchmarks/peer_cycles.py FOLDER`; install with
`bash benchmarks/setup_light_peers.sh`. FOLDER holds `scene.npz` (vertices (V, 3) float32, faces (F, 3) int32,
colors (V, 3) float32 linear albedo), `poses.npy` ((N, 4, 4) camera-to-world, OpenCV axes) and `settings.json`
(camera, light, material, the list of `renders` to make: the first `frames` poses, or the poses of the
indices `poses`; `denoise` turns on OpenImageDenoise with Blender's default passes, as a new scene has it). An
untimed 1 spp frame first builds the BVH, so the timed frames are what a frame costs in a long render. Each render writes `<name>.npz` beside them:
`images` (N, H, W, 3) float32 linear radiance as Cycles reports it, `seconds` and `cpu_seconds` (of the
process, every thread) per frame (render and EXR write).

The scene is built as MVPd's `simulators/blender/render_color.py` sets it up: a spot light parented to the
camera (spot_size 180 degrees, spot_blend 1.0, shadow_soft_size 0), Cycles with the given samples and
bounces of every kind, Principled BSDF (specular IOR level 1.0 = Blender 3's specular 1.0 at IOR 1.5,
roughness 0.5) on the scan's colour (here the vertex colours), persistent data on. Differences, on purpose:
no world light (our model has none; Blender's startup world adds a dim grey), the pixel filter narrowed to
0.01 px so that a pixel samples its centre as our ray caster does (the comparison is about light, not
anti-aliasing), flat shading (the mesh has no normals; glTF gives such a mesh flat normals, where
bpy 5 would build it smooth), no dithering, linear output (the benchmark applies the exposure and sRGB itself).
"""

from __future__ import annotations

import json
import math
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

# OpenCV camera axes (x right, y down, z forward) -> Blender's (x right, y up, looking down -z).
OPENCV_TO_BLENDER = np.diag([1.0, -1.0, -1.0, 1.0])


def build_scene(folder: Path, settings: dict) -> tuple[bpy.types.Object, bpy.types.Object]:
    """Mesh with vertex colours and the chosen material, camera, spot light parented to it."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    data = np.load(folder / "scene.npz")
    vertices, faces, colors = data["vertices"], data["faces"], data["colors"]
    mesh = bpy.data.meshes.new("house")
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", vertices.astype(np.float32).ravel())
    mesh.loops.add(faces.size)
    mesh.loops.foreach_set("vertex_index", faces.astype(np.int32).ravel())
    mesh.polygons.add(len(faces))
    mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    mesh.polygons.foreach_set("loop_total", np.full(len(faces), 3, np.int32))
    mesh.update(calc_edges=True)
    mesh.polygons.foreach_set("use_smooth", np.zeros(len(faces), bool))  # flat: the mesh has no normals
    attribute = mesh.color_attributes.new("albedo", "FLOAT_COLOR", "POINT")
    rgba = np.ones((len(vertices), 4), np.float32)
    rgba[:, :3] = colors
    attribute.data.foreach_set("color", rgba.ravel())
    house = bpy.data.objects.new("house", mesh)
    scene.collection.objects.link(house)
    house.data.materials.append(material(settings["material"]))
    house.data.materials.append(material({"kind": "diffuse"}))

    camera_data = bpy.data.cameras.new("camera")
    camera_data.lens_unit = "FOV"
    camera_data.sensor_fit = "HORIZONTAL"
    camera_data.angle_x = math.radians(settings["hfov"])
    camera_data.clip_start, camera_data.clip_end = settings["near"], settings["far"]
    camera = bpy.data.objects.new("camera", camera_data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    light_data = bpy.data.lights.new("spot", type="SPOT")
    light_data.energy = settings["power"]
    light_data.spot_size = math.radians(settings["cone"])
    light_data.spot_blend = settings["blend"]
    light_data.shadow_soft_size = 0.0
    light = bpy.data.objects.new("spot", light_data)
    scene.collection.objects.link(light)
    light.parent = camera

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.render.threads_mode = "FIXED"
    scene.render.threads = settings["threads"]
    scene.render.resolution_x, scene.render.resolution_y = settings["width"], settings["height"]
    scene.render.resolution_percentage = 100
    scene.render.use_persistent_data = True
    scene.render.dither_intensity = 0.0
    scene.cycles.filter_width = 0.01
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    return camera, light


def material(settings: dict) -> bpy.types.Material:
    """Principled BSDF (the authors') or a plain diffuse BSDF, with the vertex colour as base colour."""
    mat = bpy.data.materials.new("scan")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    output = nodes.new("ShaderNodeOutputMaterial")
    color = nodes.new("ShaderNodeVertexColor")
    color.layer_name = "albedo"
    if settings["kind"] == "principled":
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Specular IOR Level"].default_value = settings["specular"]
        bsdf.inputs["Roughness"].default_value = settings["roughness"]
        bsdf.inputs["IOR"].default_value = 1.5
        bsdf.inputs["Metallic"].default_value = 0.0
        links.new(color.outputs["Color"], bsdf.inputs["Base Color"])
    else:
        bsdf = nodes.new("ShaderNodeBsdfDiffuse")
        bsdf.inputs["Roughness"].default_value = 0.0
        links.new(color.outputs["Color"], bsdf.inputs["Color"])
    links.new(bsdf.outputs["BSDF"], output.inputs["Surface"])
    return mat


def configure(render: dict) -> None:
    """Samples, bounces, denoising and time limit of one render."""
    cycles = bpy.context.scene.cycles
    cycles.samples = render["samples"]
    cycles.use_adaptive_sampling = render.get("adaptive", False)
    cycles.time_limit = render.get("time_limit", 0.0)
    bounces = render["bounces"]
    cycles.max_bounces = bounces
    cycles.diffuse_bounces = cycles.glossy_bounces = cycles.transmission_bounces = bounces
    cycles.use_denoising = render.get("denoise", False)
    if cycles.use_denoising:
        cycles.denoiser = "OPENIMAGEDENOISE"
        cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        cycles.denoising_prefilter = "ACCURATE"
    cycles.seed = render.get("seed", 0)


def render_all(folder: Path, poses: np.ndarray, camera: bpy.types.Object, render: dict) -> None:
    """Render every pose with the settings of `render`; write `<name>.npz`."""
    configure(render)
    scene = bpy.context.scene
    # Slot 0 is the job's material, slot 1 plain diffuse (for the direct-light check of our Lambertian model).
    slot = 1 if render.get("material") == "diffuse" else 0
    scene.objects["house"].data.polygons.foreach_set("material_index", np.full(len(scene.objects["house"].data.polygons), slot, np.int32))
    scene.objects["house"].data.update()
    images, seconds, cpu_seconds = [], [], []
    with tempfile.TemporaryDirectory() as scratch:
        for index, pose in enumerate(poses[render["poses"]] if "poses" in render else poses):
            camera.matrix_world = Matrix((pose @ OPENCV_TO_BLENDER).tolist())
            bpy.context.view_layer.update()
            scene.render.filepath = str(Path(scratch) / f"{index}.exr")
            started, cpu_started = time.perf_counter(), time.process_time()
            bpy.ops.render.render(write_still=True)
            seconds.append(time.perf_counter() - started)
            cpu_seconds.append(time.process_time() - cpu_started)
            image = bpy.data.images.load(scene.render.filepath)
            pixels = np.array(image.pixels[:], np.float32).reshape(image.size[1], image.size[0], 4)
            bpy.data.images.remove(image)
            images.append(pixels[::-1, :, :3])  # Blender's rows start at the bottom
            print(f"cycles {render['name']}: frame {index} {seconds[-1]:.2f} s", flush=True)
    np.savez(folder / f"{render['name']}.npz", images=np.stack(images), seconds=np.array(seconds),
             cpu_seconds=np.array(cpu_seconds))


def main() -> None:
    folder = Path(sys.argv[1])
    settings = json.loads((folder / "settings.json").read_text())
    poses = np.load(folder / "poses.npy")
    camera, _ = build_scene(folder, settings)
    # One untimed frame first: Cycles builds its BVH at the first render (persistent data keeps it after).
    render_all(folder, poses[:1], camera, {"name": "warm_up", "samples": 1, "bounces": 0})
    for render in settings["renders"]:
        render_all(folder, poses[: render.get("frames", len(poses))], camera, render)


if __name__ == "__main__":
    main()
