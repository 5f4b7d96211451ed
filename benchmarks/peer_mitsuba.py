"""Mitsuba 3 peer of bench_light.py and bench_render.py: renders a scene exported by them (`llvm_ad_rgb`), in its own
virtualenv.

Run as `/work/venvs/mitsuba/bin/python benchmarks/peer_mitsuba.py FOLDER`; install with
`bash benchmarks/setup_light_peers.sh` (on Debian 12 Dr.Jit's LLVM backend needs apt's `libllvm19`, found
through DRJIT_LIBLLVM_PATH). Reads FOLDER's `scene.npz`, `poses.npy` and `settings.json` and writes
`mitsuba_<name>.npz` (images (N, H, W, 3) float32 linear radiance, seconds and CPU seconds of the process per
frame) for each entry of `settings["mitsuba"]`:
- `integrator` `direct` or `path` (`max_depth`), `samples` per pixel, optional `poses` (indices into poses.npy;
  all poses otherwise);
- `matched: true` (bench_light.py): the light and the material are ours, as Mitsuba plugins written here in
  Python (`mi.register_emitter` / `mi.register_bsdf`): `matched_spot`, the spot with our (and Blender's)
  smoothstep falloff in cos(theta) and I = P / Omega, and `matched_principled`, the principled material as
  pipeline/render/material.py models it (a Lambertian base weighted by 1 - A(mu_view) under a GGX lobe with
  height-correlated Smith masking, dielectric Fresnel and the multiple-scattering factor M(mu_view); A and M
  come in settings["tables"], made by the bench from material.py). Mitsuba's built-in `spot` falls off
  linearly in angle and its `principled` is Disney's, neither is the authors' light. Rays go through the
  pixel centres as ours do and Cycles' 0.01 px filter does (the stock integrator's `sample` is called on
  them, `samples` passes of one path per pixel, averaged), so the images differ from ours by light alone;
- otherwise (bench_render.py's speed peer): Mitsuba's own `spot` (linear falloff, 90-degree cutoff) on a
  `diffuse` material through the stock `mi.render`, or an `aovs` list ("depth:depth,id:shape_index").
Timing covers the render and the copy to numpy of each frame, after one warm-up frame that compiles the kernels.
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


def smoothstep(x: mi.Float) -> mi.Float:
    x = dr.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class MatchedSpot(mi.Emitter):
    """A point spot at `position` shining along `axis`: I = P / Omega, falloff smoothstep((cos - cos_edge) / width)
    as pipeline/render/lighting.py and Blender's spot blend. Pose it with `place` (opaque: no kernel rebuild)."""

    def __init__(self, props: mi.Properties):
        mi.Emitter.__init__(self, props)
        self.m_flags = mi.EmitterFlags.DeltaPosition
        self.intensity = props.get("intensity", 1.0)
        self.cos_edge = props.get("cos_edge", 0.0)
        self.width = props.get("width", 1.0)
        self.place(np.eye(4))

    def place(self, pose: np.ndarray) -> None:
        """Put the light at the camera of OpenCV camera-to-world `pose`, its axis on the optical axis."""
        self.position = mi.Point3f(*pose[:3, 3].tolist())
        self.axis = mi.Vector3f(*pose[:3, 2].tolist())
        dr.make_opaque(self.position, self.axis)

    def sample_direction(self, it, sample, active=True):
        to_light = self.position - it.p
        dist2 = dr.squared_norm(to_light)
        dist = dr.sqrt(dist2)
        direction = to_light / dist
        falloff = smoothstep((dr.dot(-direction, self.axis) - self.cos_edge) / self.width)
        ds = dr.zeros(mi.DirectionSample3f)
        ds.p, ds.n, ds.uv, ds.time = self.position, mi.Normal3f(0.0), mi.Point2f(0.0), it.time
        ds.pdf, ds.delta, ds.d, ds.dist = mi.Float(1.0), mi.Bool(True), direction, dist
        ds.emitter = mi.EmitterPtr(self)
        return ds, dr.select(active, mi.Spectrum(self.intensity * falloff / dist2), mi.Spectrum(0.0))

    def pdf_direction(self, it, ds, active=True):
        return mi.Float(0.0)

    def eval_direction(self, it, ds, active=True):
        return mi.Spectrum(0.0)

    def eval(self, si, active=True):
        return mi.Spectrum(0.0)

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        raise NotImplementedError("matched_spot: light tracing is not used by the path integrator")

    def traverse(self, callback):
        pass

    def to_string(self):
        return f"MatchedSpot[intensity={self.intensity}]"


class MatchedPrincipled(mi.BSDF):
    """pipeline/render/material.py's principled material (two-sided, as Cycles shades a back face):
    f = rho (1 - A(mu_v)) / pi + D(h) G2(mu_l, mu_v) F(v.h) / (4 mu_l mu_v) M(mu_v), v the view direction (si.wi).
    Sampled as a mixture of the cosine hemisphere and GGX normals, the GGX share = the lobe's albedo A(mu_v)."""

    def __init__(self, props: mi.Properties):
        mi.BSDF.__init__(self, props)
        self.reflectance = props["reflectance"]
        self.alpha = props.get("alpha", 0.25)
        self.ior = props.get("ior", 1.5)
        tables = json.loads(props.get("tables", "{}"))
        self.albedo_table = mi.Float(np.asarray(tables["albedo"], np.float32))
        self.energy_table = mi.Float(np.asarray(tables["energy"], np.float32))
        self.table_last = len(tables["albedo"]) - 1
        diffuse = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        glossy = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        self.m_components = [diffuse, glossy]
        self.m_flags = diffuse | glossy

    def table(self, values: mi.Float, mu: mi.Float) -> mi.Float:
        """material.py's table lookup: entry round(mu * (size - 1))."""
        index = mi.UInt32(dr.clip(dr.round(mu * self.table_last), 0, self.table_last))
        return dr.gather(mi.Float, values, index)

    def ggx(self, cos_h: mi.Float) -> mi.Float:
        a2 = self.alpha * self.alpha
        d = cos_h * cos_h * (a2 - 1.0) + 1.0
        return a2 / (dr.pi * d * d)

    def smith_lambda(self, cos: mi.Float) -> mi.Float:
        cos2 = dr.clip(cos * cos, 1e-12, 1.0)
        return 0.5 * (dr.sqrt(1.0 + self.alpha * self.alpha * (1.0 - cos2) / cos2) - 1.0)

    def fresnel(self, cos: mi.Float) -> mi.Float:
        g = dr.sqrt(dr.maximum(self.ior * self.ior - 1.0 + cos * cos, 0.0))
        a = (g - cos) / (g + cos)
        b = (cos * (g + cos) - 1.0) / (cos * (g - cos) + 1.0)
        return 0.5 * a * a * (1.0 + b * b)

    def facing(self, si, wo):
        """View and light directions flipped to the side the viewer is on (a two-sided surface)."""
        flip = dr.select(si.wi.z < 0.0, -1.0, 1.0)
        return mi.Vector3f(si.wi.x, si.wi.y, si.wi.z * flip), mi.Vector3f(wo.x, wo.y, wo.z * flip)

    def share(self, si, mu_v: mi.Float) -> mi.Float:
        return dr.clip(self.table(self.albedo_table, mu_v), 0.05, 0.95)

    def eval_pdf(self, ctx, si, wo, active=True):
        view, light = self.facing(si, wo)
        valid = active & (view.z > 0.0) & (light.z > 0.0)
        mu_v, mu_l = dr.maximum(view.z, 1e-6), dr.maximum(light.z, 1e-6)
        half = dr.normalize(view + light)
        cos_vh = dr.maximum(dr.dot(view, half), 1e-6)
        lobe_albedo = self.table(self.albedo_table, mu_v)
        diffuse = self.reflectance.eval(si, valid) * (1.0 - lobe_albedo) / dr.pi
        glossy = (self.ggx(half.z) * self.fresnel(cos_vh) * self.table(self.energy_table, mu_v)
                  / ((1.0 + self.smith_lambda(mu_l) + self.smith_lambda(mu_v)) * 4.0 * mu_l * mu_v))
        value = (diffuse + glossy) * mu_l
        share = self.share(si, mu_v)
        pdf = share * self.ggx(half.z) * half.z / (4.0 * cos_vh) + (1.0 - share) * mu_l / dr.pi
        return dr.select(valid, value, 0.0), dr.select(valid, pdf, 0.0)

    def eval(self, ctx, si, wo, active=True):
        return self.eval_pdf(ctx, si, wo, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        return self.eval_pdf(ctx, si, wo, active)[1]

    def sample(self, ctx, si, sample1, sample2, active=True):
        view, _ = self.facing(si, mi.Vector3f(0.0, 0.0, 1.0))
        glossy = sample1 < self.share(si, dr.maximum(view.z, 1e-6))
        # GGX normal: cos^2 theta_h = (1 - u) / (1 + (alpha^2 - 1) u), phi = 2 pi v
        a2 = self.alpha * self.alpha
        cos2 = (1.0 - sample2.x) / (1.0 + (a2 - 1.0) * sample2.x)
        cos_h, sin_h = dr.sqrt(cos2), dr.sqrt(dr.maximum(1.0 - cos2, 0.0))
        phi = 2.0 * dr.pi * sample2.y
        half = mi.Vector3f(sin_h * dr.cos(phi), sin_h * dr.sin(phi), cos_h)
        reflected = 2.0 * dr.dot(view, half) * half - view
        wo = dr.select(glossy, reflected, mi.warp.square_to_cosine_hemisphere(sample2))
        wo = mi.Vector3f(wo.x, wo.y, dr.select(si.wi.z < 0.0, -wo.z, wo.z))  # back to the surface's own side
        value, pdf = self.eval_pdf(ctx, si, wo, active)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo, bs.pdf, bs.eta = wo, pdf, mi.Float(1.0)
        bs.sampled_component = dr.select(glossy, mi.UInt32(1), mi.UInt32(0))
        bs.sampled_type = dr.select(glossy, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                    mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
        ok = active & (pdf > 0.0)
        return bs, dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)

    def traverse(self, callback):
        pass

    def to_string(self):
        return f"MatchedPrincipled[alpha={self.alpha}, ior={self.ior}]"


mi.register_emitter("matched_spot", lambda props: MatchedSpot(props))
mi.register_bsdf("matched_principled", lambda props: MatchedPrincipled(props))


def house_mesh(folder: Path, bsdf: dict) -> mi.Mesh:
    """The exported triangles with their linear vertex colours (attribute `vertex_color`) and `bsdf`."""
    data = np.load(folder / "scene.npz")
    vertices, faces, colors = data["vertices"], data["faces"], data["colors"]
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    mesh = mi.Mesh("house", len(vertices), len(faces), props=props, has_vertex_normals=False)
    mesh.add_attribute("vertex_color", 3, mi.Float(colors.astype(np.float32).ravel()))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params.update()
    return mesh


def vertex_colour() -> dict:
    return {"type": "mesh_attribute", "name": "vertex_color"}


def matched_bsdf(settings: dict) -> dict:
    material = settings["material"]
    if material["kind"] == "diffuse":
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": vertex_colour()}}
    return {"type": "matched_principled", "reflectance": vertex_colour(), "alpha": float(material["alpha"]),
            "ior": float(material["ior"]), "tables": json.dumps(material["tables"])}


def matched_spot(settings: dict) -> dict:
    cos_edge = math.cos(math.radians(settings["cone"]) / 2.0)
    solid_angle = 2.0 * math.pi * (1.0 - cos_edge)
    return {"type": "matched_spot", "intensity": settings["power"] / solid_angle, "cos_edge": cos_edge,
            "width": max((1.0 - cos_edge) * settings["blend"], 1e-6)}


class PixelCentres:
    """The stock integrator's `sample` on rays through the pixel centres of our pinhole camera, one path per pixel
    per pass (a fresh sampler seed each pass), averaged."""

    def __init__(self, settings: dict):
        fx, fy, cx, cy = settings["intrinsics"]
        self.width, self.height = settings["width"], settings["height"]
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        camera = np.stack([(u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, np.ones_like(u, np.float64)], -1).reshape(-1, 3)
        self.camera = camera / np.linalg.norm(camera, axis=1, keepdims=True)
        self.sampler = mi.load_dict({"type": "independent"})

    def render(self, scene: mi.Scene, integrator: mi.Integrator, pose: np.ndarray, samples: int, seed: int) -> np.ndarray:
        directions = self.camera @ pose[:3, :3].T
        origin = mi.Point3f(*(np.full(len(directions), value, np.float32) for value in pose[:3, 3]))
        ray = mi.Ray3f(origin, mi.Vector3f(*(directions[:, k].astype(np.float32) for k in range(3))))
        total = np.zeros((len(directions), 3), np.float64)
        for sample in range(samples):
            self.sampler.seed(seed * 100_003 + sample, len(directions))
            radiance, _, _ = integrator.sample(scene, self.sampler, ray, None, mi.Bool(True))
            total += np.asarray(radiance, np.float64).reshape(3, -1).T if radiance.shape[0] == 3 else np.asarray(radiance)
        return (total / samples).reshape(self.height, self.width, 3).astype(np.float32)


def render_matched(folder: Path, settings: dict, poses: np.ndarray, render: dict) -> None:
    """One `matched` entry: our light and material, pixel centres; writes `mitsuba_<name>.npz`."""
    integrator = {"type": render["integrator"], **({"max_depth": render["max_depth"]} if "max_depth" in render else {})}
    scene = mi.load_dict({"type": "scene", "house": house_mesh(folder, matched_bsdf(settings)),
                          "spot": matched_spot(settings)})
    light, camera = scene.emitters()[0], PixelCentres(settings)
    chosen = [poses[i] for i in render.get("poses", range(len(poses)))]
    images, seconds, cpu_seconds = [], [], []
    path = mi.load_dict(integrator)
    for index, pose in enumerate([chosen[0], *chosen]):  # the first frame (one pass) compiles the kernels
        light.place(pose)
        started, cpu_started = time.perf_counter(), time.process_time()
        image = camera.render(scene, path, pose, render["samples"] if index > 0 else 1, seed=index)
        if index > 0:
            seconds.append(time.perf_counter() - started)
            cpu_seconds.append(time.process_time() - cpu_started)
            images.append(image)
    np.savez(folder / f"mitsuba_{render['name']}.npz", images=np.stack(images), seconds=np.array(seconds),
             cpu_seconds=np.array(cpu_seconds))
    print(f"mitsuba {render['name']}: {np.median(seconds):.3f} s per frame", flush=True)


def render_stock(folder: Path, settings: dict, poses: np.ndarray, render: dict) -> None:
    """One entry with Mitsuba's own spot and diffuse material through `mi.render`; writes `mitsuba_<name>.npz`."""
    mesh = house_mesh(folder, {"type": "diffuse", "reflectance": vertex_colour()})
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
    for render in settings["mitsuba"]:
        (render_matched if render.get("matched") else render_stock)(folder, settings, poses, render)


if __name__ == "__main__":
    main()
