"""The `predict` stage: a model's per-frame masks for a run's videos, one unit (one Ray task) per video.

Where things live: the output folder DIR is a small run folder of its own (the `evaluate --gt-mvpd`
design): `prediction.yaml` says which run, embodiment, video selection and model the predictions are
of; `job.yaml` is the source run's job (seed and runtime settings); `_state/predict/` holds the
markers, `logs/predict/` the logs, `status/` the outcomes; `panomasksRLE/<video>/<frame:010d>.json`
the predictions, exactly as `mvpd evaluate --pred DIR` reads them. Why not inside the source run:
a run is the ground truth; several models' predictions of it must coexist, be deleted or shipped
independently, and `predict` must touch only what it was given (`--out`). The manifest makes reuse
safe: the same run and model in the same DIR continue where they stopped (only videos without a
valid marker run); anything else is refused before a byte is written.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from pipeline.config import Job, config_hash, load_yaml
from pipeline.evaluate.predictions import RLE_FOLDER
from pipeline.models.fastspam import FastSpam, FastSpamOptions
from pipeline.models.segmenter import SEGMENTERS, FrameInput, ModelError, Segmenter, make_segmenter
from pipeline.runtime.executor import ProgressCallback, StagePlan, StageReport, run_stage
from pipeline.store.names import JOB_FILE, atomic_write_text
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult

MANIFEST = "prediction.yaml"
SELF_PROMPTING_SUFFIX = "+sp"


NO_SPLIT = "all"  # the selection of a run without a split (or of no --split): every video

class PredictionInputError(ValueError):
    """Unusable predict input (output folder of another run or model, run without depth or poses)."""


class ModelConfig(BaseModel):
    """A model to predict with: a segmenter, its options and whether FastSPAM wraps it (a model file)."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description=f"segmenter: one of {', '.join(SEGMENTERS)}")
    options: dict[str, Any] = Field(default_factory=dict, description="the segmenter's own options")
    self_prompting: bool = Field(False, description="wrap the segmenter in FastSPAM")
    fastspam: FastSpamOptions = Field(default_factory=FastSpamOptions, description="FastSPAM thresholds")

    @property
    def spec(self) -> str:
        """Short name: the segmenter's, with `+sp` for self-prompting (the `mvpd report --models` syntax)."""
        return self.name + (SELF_PROMPTING_SUFFIX if self.self_prompting else "")

    @classmethod
    def from_spec(cls, spec: str) -> "ModelConfig":
        """`geometric` or `geometric+sp` -> config with default options."""
        name = spec.removesuffix(SELF_PROMPTING_SUFFIX)
        return cls(name=name, self_prompting=spec.endswith(SELF_PROMPTING_SUFFIX))


def load_model_file(path: Path) -> ModelConfig:
    """A model file (YAML: name, options, self_prompting, fastspam) -> ModelConfig; one-line errors."""
    try:
        data = load_yaml(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ModelError(f"{path}: model file not found; pass an existing YAML file") from None
    except yaml.YAMLError as error:
        raise ModelError(f"{path}: not valid YAML ({' '.join(str(error).split())})") from None
    try:
        return ModelConfig(**(data or {}))
    except (ValidationError, TypeError) as error:
        if isinstance(error, ValidationError):
            first = error.errors()[0]
            raise ModelError(f"{path}: {'.'.join(str(p) for p in first['loc'])}: {first['msg']}") from None
        raise ModelError(f"{path}: expected a mapping with name, options, self_prompting, fastspam") from None


def build_model(config: ModelConfig) -> Segmenter:
    """The segmenter of `config`, wrapped in FastSPAM when it self-prompts; ModelError when unusable."""
    segmenter = make_segmenter(config.name, **config.options)
    if config.self_prompting:
        return FastSpam(segmenter, **config.fastspam.model_dump())
    return segmenter


@dataclass(frozen=True)
class PredictionInputs:
    """What is predicted (part of every unit's config hash).

    Attributes:
        source_run: the run folder whose rendered videos are read.
        embodiment: the embodiment whose videos are predicted.
        model: ModelConfig as a dict.
        selection: which videos ("all", or a split's name): the folder holds predictions of these only.
        videos: the video names, or None for every video of the embodiment.
    """

    source_run: str
    embodiment: str
    model: dict[str, Any]
    selection: str = NO_SPLIT
    videos: tuple[str, ...] | None = None

    def identity(self, job_hash: str) -> dict[str, Any]:
        """What the output folder's manifest records and a later predict into it must match."""
        return {"source_run": self.source_run, "source_job_hash": job_hash, "embodiment": self.embodiment,
                "selection": self.selection, "model": self.model}


class SegmentationPredictor(Stage):
    """Per-frame masks of a model for the rendered videos of a run (units: one per video)."""

    name = "predict"
    datasets = ()

    def __init__(self, job: Job, inputs: PredictionInputs):
        super().__init__(job)
        self.inputs = inputs

    def units(self, run: RunFolder) -> list[Unit]:
        from pipeline.io.reader import video_locations

        wanted = set(self.inputs.videos) if self.inputs.videos is not None else None
        source = RunFolder.open(self.inputs.source_run)  # the run predicted, apart from `run` (the predictions)
        locations = video_locations(source)  # local paths, or URLs on the source run's object store
        units = []
        for row in source.read("videos").to_pylist():
            if row["embodiment"] != self.inputs.embodiment or (wanted is not None and row["video_name"] not in wanted):
                continue
            store = locations.get((row["embodiment"], row["video_name"]), str(source.root / row["store_path"]))
            units.append(Unit(f"{row['embodiment']}.{row['video_name']}",
                              {"video": row["video_name"], "store": store, "frames": int(row["frames"])}))
        return sorted(units, key=lambda u: u.id)

    def settings(self) -> dict[str, Any]:
        return {"seed": self.job.seed, "model": self.inputs.model, "source_run": self.inputs.source_run}

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        from pipeline.io.zarr_video import open_video

        model = build_model(ModelConfig(**self.inputs.model))
        model.reset(context.rng())
        video = open_video(unit.params["store"])
        name = unit.params["video"]
        started, masks = time.perf_counter(), 0
        for frame in iter_video_frames(video, model.needs_ground_truth):
            predicted, ids = model.segment_tracked(frame)
            masks += len(predicted)
            path = context.staged_path(f"{RLE_FOLDER}/{name}/{frame.index:010d}.json")
            path.write_text(json.dumps(rle_payload(predicted, ids)), encoding="utf-8")
        seconds = time.perf_counter() - started
        context.log.info("%s: %d frames, %d masks in %.2f s", name, unit.params["frames"], masks, seconds)
        return UnitResult(info={"video": name, "frames": unit.params["frames"], "masks": masks,
                                "predict_seconds": round(seconds, 3)})


def iter_video_frames(video: Any, with_ground_truth: bool) -> Any:
    """FrameInputs of a stored video, one shard-friendly read at a time."""
    poses = video.poses() if "poses" in video.group.attrs else None
    intrinsics = video.intrinsics()
    camera = (float(intrinsics["fx"]), float(intrinsics["fy"]), float(intrinsics["cx"]), float(intrinsics["cy"]))
    has_depth = "depth" in video.group
    for index in range(video.frames):
        yield FrameInput(rgb=np.asarray(video.rgb[index]),
                         depth=np.asarray(video.depth[index]) if has_depth else None, intrinsics=camera,
                         panoptic=np.asarray(video.panoptic[index]) if with_ground_truth else None, index=index,
                         pose=poses[index] if poses is not None else None)


def rle_payload(masks: np.ndarray, ids: np.ndarray | None) -> dict[str, Any]:
    """{"coco_rle": [{"size": [H, W], "counts": "..."}], optional "ids"}: what `mvpd evaluate` reads."""
    import pycocotools.mask as mask_utils

    if len(masks) == 0:
        payload: dict[str, Any] = {"coco_rle": []}
    else:
        encoded = mask_utils.encode(np.asfortranarray(masks.transpose(1, 2, 0).astype(np.uint8)))
        payload = {"coco_rle": [{"size": [int(s) for s in r["size"]], "counts": r["counts"].decode("ascii")}
                                for r in encoded]}
    if ids is not None:
        payload["ids"] = [int(i) for i in ids]
    return payload


def resolve_embodiment(run: RunFolder, embodiment: str | None) -> str:
    """The embodiment to predict: the given one (checked) or the run's only one."""
    names = sorted(set(run.read("videos").column("embodiment").to_pylist()))
    if not names:
        raise PredictionInputError(f"{run.location}/videos: no rendered videos; run the render stage first "
                                   "(mvpd rerun RUN --stage render)")
    if embodiment is None:
        if len(names) > 1:
            raise PredictionInputError(f"{run.location}: the run has embodiments {', '.join(names)}; choose one with --embodiment")
        return names[0]
    if embodiment not in names:
        raise PredictionInputError(f"{run.location}: no videos of embodiment {embodiment!r}; the run has {', '.join(names)}")
    return embodiment


def check_self_prompting_inputs(stage: SegmentationPredictor, run: RunFolder) -> None:
    """Every video to predict has depth, poses and intrinsics (FastSPAM's 3D memory needs them)."""
    from pipeline.io.zarr_video import open_video

    for unit in stage.units(run):
        video = open_video(unit.params["store"])
        attributes = video.group.attrs
        missing = [what for what, present in (("depth", "depth" in video.group), ("poses", "poses" in attributes),
                                              ("intrinsics", "intrinsics" in attributes)) if not present]
        if missing:
            raise PredictionInputError(f"{unit.params['store']}: no {' or '.join(missing)}; self-prompting needs depth, "
                                       "camera poses and intrinsics: render them, or drop --self-prompting")


def check_output_folder(out: Path, identity: dict[str, Any]) -> None:
    """Refuse an output folder holding anything but predictions of the same run, selection and model."""
    if not out.exists():
        return
    if not out.is_dir():
        raise PredictionInputError(f"{out}: is a file; choose a folder for --out")
    manifest = out / MANIFEST
    if manifest.is_file():
        recorded = load_yaml(manifest.read_text(encoding="utf-8")) or {}
        if recorded.get("identity") != identity:
            differs = sorted(k for k in identity if recorded.get("identity", {}).get(k) != identity[k])
            raise PredictionInputError(f"{out}: holds predictions of another {', '.join(differs)} "
                                       f"({MANIFEST}); choose another --out or delete that folder")
        return
    if any(out.iterdir()):
        what = "a run folder" if (out / JOB_FILE).is_file() else f"files but no {MANIFEST}"
        raise PredictionInputError(f"{out}: holds {what}, not predictions; choose an empty or new --out folder")


def predict_run(source: RunFolder, out: str | Path, model: ModelConfig, embodiment: str | None = None,
                videos: Sequence[str] | None = None, selection: str = NO_SPLIT, force: bool = False,
                address: str | None = None, on_start: Callable[[StagePlan], None] | None = None,
                on_unit: ProgressCallback | None = None) -> StageReport:
    """Predict the rendered videos of a run (or the named `videos`) with `model` into the folder `out`.

    Every check (model, run, depth and poses for self-prompting, output folder) happens before anything
    is written; then one unit per video runs on Ray and only videos without a valid marker run.
    """
    job = source.job()
    build_model(model)  # unknown name, bad options, missing extra or checkpoint: fail before writing
    chosen = resolve_embodiment(source, embodiment)
    inputs = PredictionInputs(str(source.root), chosen, model.model_dump(mode="json"), selection,
                              tuple(sorted(videos)) if videos is not None else None)
    stage = SegmentationPredictor(job, inputs)
    if model.self_prompting:
        check_self_prompting_inputs(stage, source)
    out = Path(out).expanduser().resolve()
    if out == source.root or out in source.root.parents:
        raise PredictionInputError(f"{out}: is or holds the run folder {source.root}; predictions go to a folder of their own")
    identity = inputs.identity(job.hash())
    check_output_folder(out, identity)
    target = RunFolder.create(out, job)
    atomic_write_text(out / MANIFEST, yaml.safe_dump({"identity": identity, "identity_hash": config_hash(identity)},
                                                    sort_keys=True))
    with target.locked():
        return run_stage(stage, target, force=force, address=address, on_start=on_start, on_unit=on_unit)

