"""The `evaluate` stage: VSQ of a model's predictions, one unit (one Ray task) per video.

`VsqEvaluator` evaluates the rendered videos of a run (after `render`); `MvpdVsqEvaluator` the videos
of an MVPd-layout split, inside an evaluation run folder of its own. A unit writes its counts to
`metrics/part-<unit>.parquet`; the summary is assembled from that table after all units
(`pipeline.evaluate.report`).
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from pipeline.config import Job
from pipeline.evaluate.frames import GroundTruthFrame, LazyFrames, PredictionFrame, ground_truth_frame
from pipeline.evaluate.errors import GroundTruthError, MissingPredictionError
from pipeline.evaluate.ground_truth import GroundTruthLoader, MvpdSplit, VideoSpec, run_videos
from pipeline.evaluate.predictions import RLE_FOLDER, PredictionSource
from pipeline.evaluate.subset import filter_by_patterns, select_split
from pipeline.evaluate.vsq import BUCKETS, VideoCounts, VsqProtocol, evaluate_video
from pipeline.io.tables import to_table
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult
from pipeline.store.run_folder import RunFolder


@dataclass(frozen=True)
class EvaluationInputs:
    """What is evaluated against what (part of every unit's config hash).

    Attributes:
        predictions: the prediction folder (`<pred>/panomasksRLE/<video>/...` or `<pred>/<video>.zarr`).
        allow_missing: a missing prediction frame counts as empty (and is reported) instead of failing.
        embodiment: runs only: the embodiment whose videos are evaluated.
        mvpd_root: MVPd only: the release root holding `<split>/panoptic_<split>.json`.
        split: the split name (MVPd: its folder; runs: a split of the run's split stage, None for every video).
        videos: names or globs of the videos to score (empty: every video of the split).
    """

    predictions: str
    allow_missing: bool = False
    embodiment: str | None = None
    mvpd_root: str | None = None
    split: str | None = None
    videos: tuple[str, ...] = ()


def unit_id(spec: VideoSpec) -> str:
    """Unit id from content: the video name, prefixed by its embodiment for runs (api.py relies on this)."""
    return f"{spec.embodiment}.{spec.video_name}" if spec.embodiment else spec.video_name


def _fingerprint(folder: Path) -> str:
    """Name, size and modification time of every file of a video's predictions ("" when absent): a file
    rewritten in place makes its unit stale, which the folder's own mtime would not show."""
    if not folder.exists():
        return ""
    digest = hashlib.sha1()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        stat = path.stat()
        digest.update(f"{path.relative_to(folder)}\0{stat.st_size}\0{stat.st_mtime_ns}\n".encode())
    return digest.hexdigest()


class VsqEvaluator(Stage):
    """VSQ of predictions on the rendered videos of this run (every object non-zero-shot for now)."""

    name = "evaluate"
    after = ("render",)
    datasets = ("metrics",)

    def __init__(self, job: Job, inputs: EvaluationInputs):
        super().__init__(job)
        self.inputs = inputs
        self.protocol = VsqProtocol.from_config(job.evaluate)

    def videos(self, run: RunFolder) -> list[VideoSpec]:
        """The ground-truth videos, sorted by key: the split's accepted ones when a split is chosen."""
        specs = run_videos(run, self.inputs.embodiment)
        return specs if self.inputs.split is None else select_split(run, specs, self.inputs.split)

    def units(self, run: RunFolder) -> list[Unit]:
        predictions = Path(self.inputs.predictions)
        units = []
        for spec in filter_by_patterns(self.videos(run), self.inputs.videos):
            stamp = (_fingerprint(predictions / RLE_FOLDER / spec.video_name)
                     + _fingerprint(predictions / f"{spec.video_name}.zarr"))
            if not stamp:  # checked here, in the driver, so the error comes at once and names the folder
                raise MissingPredictionError(f"{predictions / RLE_FOLDER / spec.video_name}: no predictions for video "
                                             f"{spec.key}; predict it, or evaluate a split without it")
            units.append(Unit(unit_id(spec), {"video": spec.to_params(), "predictions_fingerprint": stamp}))
        return sorted(units, key=lambda u: u.id)

    def settings(self) -> dict[str, Any]:
        return {"protocol": asdict(self.protocol), "inputs": asdict(self.inputs)}

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        spec = VideoSpec.from_params(unit.params["video"])
        counts, missing = evaluate_spec(spec, Path(self.inputs.predictions), self.protocol, self.inputs.allow_missing)
        if missing:
            context.log.warning("%d prediction frames missing, counted as empty: %s", len(missing), missing)
        context.write_table("metrics", to_table("metrics", metric_rows(spec, counts, len(missing))))
        return UnitResult(info={"video": spec.key, "frames": spec.frames, "missing_frames": missing})


class MvpdVsqEvaluator(VsqEvaluator):
    """VSQ of predictions on an MVPd-layout split (`--gt-mvpd ROOT --split SPLIT`)."""

    after = ()

    def videos(self, run: RunFolder) -> list[VideoSpec]:
        assert self.inputs.mvpd_root is not None and self.inputs.split is not None
        return MvpdSplit(self.inputs.mvpd_root, self.inputs.split).videos()


def evaluate_spec(spec: VideoSpec, predictions: Path, protocol: VsqProtocol,
                  allow_missing: bool = False) -> tuple[VideoCounts, list[int]]:
    """Read one video's ground truth and predictions lazily and count it; returns (counts, missing frames)."""
    load = GroundTruthLoader(spec)
    source = PredictionSource(predictions, spec.video_name, spec.stems, allow_missing)
    if spec.frames == 0:
        return VideoCounts(protocol.ks), []
    first = load(0)
    shape = first.shape

    def truth(index: int) -> GroundTruthFrame:
        label = first if index == 0 else load(index)
        if label.shape != shape:
            where = spec.labels[index] or f"{spec.store} frame {index}"
            raise GroundTruthError(f"{where}: ground-truth frame is {label.shape[0]}x{label.shape[1]}, frame 0 is "
                                   f"{shape[0]}x{shape[1]}; every frame of a video must have one size")
        return ground_truth_frame(label, protocol.min_area_fraction, protocol.subsample)

    def prediction(index: int) -> PredictionFrame:
        return source.frame(index, shape, protocol.subsample)

    counts = evaluate_video(LazyFrames(spec.frames, truth), LazyFrames(spec.frames, prediction), spec.zero_shot, protocol)
    return counts, sorted(set(source.missing))


def metric_rows(spec: VideoSpec, counts: VideoCounts, missing_frames: int) -> list[dict[str, Any]]:
    """Rows of the `metrics` dataset for one video: one per (bucket, k)."""
    return [{"embodiment": spec.embodiment, "video_name": spec.video_name, "bucket": bucket, "k": k,
             "iou": float(c.iou), "tp": c.tp, "fp": c.fp, "fn": c.fn, "frames": spec.frames,
             "missing_frames": missing_frames}
            for bucket in BUCKETS for k, c in counts.buckets[bucket].items()]

