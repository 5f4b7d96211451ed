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
from typing import Annotated, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

SCHEMA_VERSION = 1


class ConfigError(ValueError):
    """An unusable job or embodiment file; the message is one line naming file, key and fix."""


class Strict(BaseModel):
    """Base: unknown keys are errors, instances are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


# ----------------------------------------------------------------------------------------- scenes


class ProceduralSource(Strict):
    """Generated houses (the embedded default: no download)."""

    count: int = Field(3, ge=1, description="number of houses")
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
    """Plain mesh files (OBJ / PLY / GLB) with per-face or per-vertex instance labels."""

    root: Path = Field(description="folder of mesh files")
    pattern: str = Field("*.glb", description="glob of the files to use, relative to root")
    up_axis: Literal["y", "z"] = Field("y", description="up axis of the files")


class MvpdReleaseSource(Strict):
    """A split of an MVPd release read by `mvpd import-mvpd` (the run holds its videos, not scenes)."""

    root: Path = Field(description="MVPd root holding <split>/panoptic_<split>.json")
    split: str = Field(pattern=r"^[A-Za-z0-9_\-]+$", description="split folder name: train, val or test")


class SceneSources(Strict):
    """Where the scenes come from; any combination of sources."""

    procedural: ProceduralSource | None = None
    hm3dsem: Hm3dSemSource | None = None
    meshes: MeshFolderSource | None = None
    mvpd: MvpdReleaseSource | None = Field(None, description="an imported MVPd release split (import-mvpd)")

    @model_validator(mode="after")
    def _at_least_one(self) -> "SceneSources":
        if not (self.procedural or self.hm3dsem or self.meshes or self.mvpd):
            raise ValueError("name at least one scene source (procedural, hm3dsem, meshes or mvpd)")
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
    width: int = Field(640, ge=8, le=8192, description="pixels")
    height: int = Field(480, ge=8, le=8192, description="pixels")
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


class Illumination(Strict):
    """`ambient`: surface colour as is. `spot`: a light at the camera (see schemas/README.md)."""

    kind: Literal["ambient", "spot"] = "ambient"
    power: float = Field(0.0, ge=0, description="watts (spot only)")
    cone: float = Field(180.0, gt=0, le=180, description="full cone angle, degrees")
    blend: float = Field(1.0, ge=0, le=1, description="fraction of the cone over which light fades out")

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
        default_factory=lambda: [1.0, 0.1], min_length=1, description="camera heights above the floor, metres"
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

    trajectories_per_scene: int = Field(50, ge=1)
    min_frames: int = Field(100, ge=2)
    max_frames: int = Field(600, ge=2)
    max_step: float = Field(0.05, gt=0, description="metres per frame along a straight move")
    max_turn: float = Field(0.5, gt=0, description="degrees per frame when turning in place")
    grid_resolution: float = Field(0.05, gt=0, description="metres per cell of the navigable-area grid")
    max_attempts: int = Field(2000, ge=1, description="start/goal draws per scene before giving up")
    require_ceiling: bool = Field(True, description="floors need a surface above them (keeps robots off roofs); "
                                                    "turn off for scans with holes in their ceilings")

    @model_validator(mode="after")
    def _frames_ordered(self) -> "PlanConfig":
        if self.min_frames > self.max_frames:
            raise ValueError("min_frames must not exceed max_frames")
        return self


class RenderConfig(Strict):
    """Rendering: storage and exposure."""

    frames_per_shard: int = Field(16, ge=1, le=256, description="Zarr shard length in frames")
    exposure: float | None = Field(None, gt=0, description="spot light: linear scale from radiance W/(m^2 sr) to full "
                                   "scale, fixed for the job (schemas/render.md); derived from the brightest spot when omitted")


class EvaluateConfig(Strict):
    """VSQ protocol knobs; the defaults are the published evaluator's."""

    ks: list[Annotated[int, Field(ge=1)]] = Field(default_factory=lambda: [1, 5, 10, 15],
                                                  description="prefix lengths: score the first k frames of each window")
    window: int = Field(15, ge=1, description="frames per window; windows start while start < T - window")
    stride: int = Field(15, ge=1, description="frames between window starts")
    min_area_fraction: float = Field(0.001, ge=0, lt=1, description="ground-truth ids below this fraction of the full frame become void")
    subsample: int = Field(2, ge=1, description="keep every n-th row and column")


class StageResources(Strict):
    """What one unit of a stage asks Ray for, and how long it may run."""

    cpus: float = Field(1.0, gt=0)
    memory_gb: float = Field(2.0, gt=0)
    timeout_s: float = Field(3600.0, gt=0, description="a unit running longer is cancelled and recorded as failed")


class RuntimeConfig(Strict):
    """How the job runs on Ray."""

    max_in_flight: int = Field(0, ge=0, description="tasks in flight per stage; 0 = twice the cluster's CPUs")
    max_retries: int = Field(3, ge=0, description="retries of a unit whose worker died (not of its errors)")
    resources: dict[Literal["shard", "plan", "render", "evaluate", "import", "predict"], StageResources] = Field(default_factory=dict)

    def for_stage(self, stage: str) -> StageResources:
        return self.resources.get(stage, StageResources())  # type: ignore[call-overload]


class Job(Strict):
    """A whole dataset job: scenes x embodiments -> trajectories -> videos."""

    name: str = Field(pattern=r"^[A-Za-z0-9_\-.]+$")
    seed: int = Field(0, ge=0, description="root of every random draw")
    scenes: SceneSources
    embodiments: list[Embodiment] = Field(min_length=1)
    plan: PlanConfig = PlanConfig()
    render: RenderConfig = RenderConfig()
    evaluate: EvaluateConfig = EvaluateConfig()
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
    more = f" (+{len(errors) - 1} more)" if len(errors) > 1 else ""
    return f"{source}: {key}: {message}{more}"


def _read_yaml(path: Path) -> dict:
    if not path.is_file():
        raise ConfigError(f"{path}: no such file; give the path of a YAML job file")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{path}{line}: not valid YAML ({getattr(error, 'problem', error)})") from None
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
    try:
        job = Job.model_validate(data)
    except ValidationError as error:
        raise ConfigError(_format_error(str(path), error)) from None
    _check_folders(path, job)
    return job


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
