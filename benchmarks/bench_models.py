"""The model experiment of the paper on a generated run, and predict's speed.

One command: `.venv/bin/python benchmarks/bench_models.py [--run-dir DIR]` (with --run-dir an existing
rendered run is reused; otherwise one is generated in a temporary folder). It

1. renders 3 generated houses (detail 0.5), one MVPd-length trajectory each (100-300 frames; MVPd's are
   100-600), at 640x480 and both camera heights (1.0 m, 0.1 m), ambient light;
2. predicts every video with `geometric` per frame and with FastSPAM self-prompting (`geometric+sp`),
   and with the two-level `geometric` (nested fine + coarse regions: overlapping masks like FastSAM's
   everything mode) with and without self-prompting, and scores each with VSQ (published protocol)
   per camera height;
3. measures throughput: (a) segmenter time per frame in one process (one core), plain and wrapped in
   FastSPAM, on the frames of one video held in memory (3 runs, median and spread, ratio sp / plain);
   (b) end-to-end `predict` frames/s on 2 Ray workers (Zarr reads, RLE encoding, JSON writes), 3 runs;
4. derives the cost of predicting MVPd's test split.

The machine is shared: the load average is recorded, and ratios between runs made side by side are
what to compare, not absolute times. Writes benchmarks/results/models.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.config import Job
from pipeline.evaluate.api import evaluate_run
from pipeline.evaluate.vsq import AGGREGATE, VsqProtocol
from pipeline.io.reader import list_videos
from pipeline.io.zarr_video import open_video
from pipeline.models.fastspam import FastSpam
from pipeline.models.geometric import GeometricSegmenter
from pipeline.models.predict import ModelConfig, iter_video_frames, predict_run
from pipeline.models.segmenter import FrameInput, Segmenter
from pipeline.models.report import ModelScores, video_height_m
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.runner import submit

RESULTS = Path(__file__).resolve().parent / "results" / "models.json"
REPEATS = 3
# MVPd (DESIGN.md): 18,000 videos and 6.06 M frames over 180 scenes; every trajectory at both heights.
MVPD_FRAMES_PER_VIDEO = 6.06e6 / 18_000
MVPD_TEST_VIDEOS = 18 * 50 * 2  # 18 scenes x 50 trajectories x 2 heights (59 later rejected as empty)
TARGET_FPS_PER_CORE, TARGET_SP_OVERHEAD = 4.0, 0.30

JOB = {
    "name": "bench-models", "seed": 0,
    "scenes": {"procedural": {"count": 3, "seed": 11, "detail": 0.5}},
    "embodiments": [{"name": "mvpd", "sensor": {"width": 640, "height": 480, "hfov": 69.0}, "placements": [1.0, 0.1],
                     "body": {"radius": 0.15, "height": 1.2}, "illumination": {"kind": "ambient"}}],
    "plan": {"trajectories_per_scene": 1, "min_frames": 100, "max_frames": 300},
}

MODELS = {
    "geometric": ModelConfig(name="geometric"),
    "geometric+sp": ModelConfig(name="geometric", self_prompting=True),
    "geometric(levels=2)": ModelConfig(name="geometric", options={"levels": 2}),
    "geometric(levels=2)+sp": ModelConfig(name="geometric", options={"levels": 2}, self_prompting=True),
}


def spread(values: list[float]) -> dict[str, float]:
    """Median, min and max of repeated measurements."""
    return {"median": round(statistics.median(values), 4), "min": round(min(values), 4), "max": round(max(values), 4),
            "runs": [round(v, 4) for v in values]}


def render_run(run_dir: Path) -> float:
    """Shard, plan and render the job into `run_dir` (reused when already done); returns seconds."""
    started = time.perf_counter()
    report = submit(Job.model_validate(JOB), RunFolder.prepare(run_dir))
    if report.failed:
        raise SystemExit(f"render failed for {report.failed} units; see mvpd status {run_dir}")
    return time.perf_counter() - started


def quality(run_dir: Path, work: Path) -> dict[str, Any]:
    """VSQ^k per model and camera height (published protocol)."""
    protocol = VsqProtocol()
    out: dict[str, Any] = {}
    for label, config in MODELS.items():
        folder = work / "quality" / label
        report = predict_run(RunFolder.open(run_dir), folder, config)
        if report.failed:
            raise SystemExit(f"{label}: predict failed: {report.failed[0].message}")
        result = evaluate_run(RunFolder.open(run_dir), folder)
        scores = ModelScores(label, dict(result.per_video), protocol)
        per_height = {}
        for height in sorted({video_height_m(k) for k in scores.per_video}, reverse=True):
            per_height[f"{height:g} m"] = scores.summary([k for k in scores.per_video if video_height_m(k) == height])[AGGREGATE]
        out[label] = {"all": scores.summary()[AGGREGATE], **per_height}
        print(f"  {label:24s} " + "  ".join(f"{h}: VSQ {100 * (v['VSQ'] or 0):.2f} (k=1 {100 * (v['1'] or 0):.2f}, "
                                            f"k=15 {100 * (v['15'] or 0):.2f})" for h, v in out[label].items()))
    return out


class TimedSegmenter(Segmenter):
    """A segmenter that adds up the seconds spent inside it, so FastSPAM's own share is measured in the
    same run (same load) as the segmenter it wraps."""

    name = "timed"

    def __init__(self, inner: Segmenter):
        self.inner = inner
        self.seconds = 0.0

    def segment(self, frame: FrameInput) -> np.ndarray:
        started = time.perf_counter()
        masks = self.inner.segment(frame)
        self.seconds += time.perf_counter() - started
        return masks


def segmenter_speed(run_dir: Path) -> dict[str, Any]:
    """Per-frame seconds of geometric alone and inside FastSPAM, one process, frames in memory.

    The self-prompting overhead is FastSPAM's own time over the wrapped segmenter's time in the same
    pass (robust to a shared machine's load); a separate pass of the plain segmenter gives its fps.
    """
    embodiment, name = list_videos(run_dir)[0]
    video = open_video(RunFolder(run_dir).video_store(embodiment, name))
    frames = list(iter_video_frames(video, False))[:120]
    results: dict[str, Any] = {"video": name, "frames": len(frames),
                               "size": [int(frames[0].rgb.shape[1]), int(frames[0].rgb.shape[0])]}
    plain_runs, prompted_runs, overheads = [], [], []
    for _ in range(REPEATS):
        segmenter = GeometricSegmenter()
        started = time.perf_counter()
        for frame in frames:
            segmenter.segment(frame)
        plain_runs.append((time.perf_counter() - started) / len(frames))
        timed = TimedSegmenter(GeometricSegmenter())
        model = FastSpam(timed)
        model.reset(np.random.default_rng(0))
        started = time.perf_counter()
        for frame in frames:
            model.segment(frame)
        total = time.perf_counter() - started
        prompted_runs.append(total / len(frames))
        overheads.append((total - timed.seconds) / timed.seconds)
    results.update(seconds_per_frame_plain=spread(plain_runs), seconds_per_frame_self_prompting=spread(prompted_runs),
                   fps_per_core_plain=round(1 / statistics.median(plain_runs), 2),
                   fps_per_core_self_prompting=round(1 / statistics.median(prompted_runs), 2),
                   self_prompting_overhead=spread(overheads))
    return results


def predict_speed(run_dir: Path, work: Path) -> dict[str, Any]:
    """End-to-end predict frames/s on 2 Ray workers, plain and self-prompting, 3 runs each, on the two
    videos (both heights) of the first house: one per worker."""
    videos = list_videos(run_dir)
    first_scene = videos[0][1].split(".")[0]
    chosen = [(e, n) for e, n in videos if n.startswith(first_scene + ".")]
    frames = sum(int(open_video(RunFolder(run_dir).video_store(e, n)).frames) for e, n in chosen)
    out: dict[str, Any] = {"videos": [n for _, n in chosen], "frames": frames}
    labels = ("geometric", "geometric+sp")
    rates: dict[str, list[float]] = {label: [] for label in labels}
    predict_run(RunFolder.open(run_dir), work / "speed" / "warm-up", MODELS["geometric"], videos=[n for _, n in chosen])  # starts Ray
    for _ in range(REPEATS):
        for label in labels:  # interleaved, so both see the same drift in the machine's load
            started = time.perf_counter()
            report = predict_run(RunFolder.open(run_dir), work / "speed" / label, MODELS[label], videos=[n for _, n in chosen],
                                 force=True)
            assert not report.failed
            rates[label].append(frames / (time.perf_counter() - started))
    for label in labels:
        out[label] = {"fps_2_workers": spread(rates[label])}
    out["self_prompting_overhead"] = round(out["geometric"]["fps_2_workers"]["median"]
                                           / out["geometric+sp"]["fps_2_workers"]["median"] - 1, 4)
    return out


def main() -> None:
    """Render (or reuse), score, time, print and write the results JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run-dir", type=Path, help="a rendered run to reuse (or where to render one)")
    parser.add_argument("--work-dir", type=Path, help="prediction folders to reuse (or where to write them)")
    args = parser.parse_args()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as scratch:
        run_dir = (args.run_dir or Path(scratch) / "run").resolve()
        work = (args.work_dir or Path(scratch) / "work").resolve()
        render_seconds = render_run(run_dir)
        print(f"run {run_dir}: {len(list_videos(run_dir))} videos ({render_seconds:.0f} s to render or reuse)")
        print("VSQ (percent, published protocol):")
        scores = quality(run_dir, work)
        print("speed:")
        segmenter = segmenter_speed(run_dir)
        print(f"  one core, {segmenter['size'][0]}x{segmenter['size'][1]}: geometric {segmenter['fps_per_core_plain']} fps, "
              f"with self-prompting {segmenter['fps_per_core_self_prompting']} fps (overhead "
              f"{100 * segmenter['self_prompting_overhead']['median']:.1f} %, target <= {100 * TARGET_SP_OVERHEAD:.0f} %)")
        end_to_end = predict_speed(run_dir, work)
        print(f"  predict on 2 workers: geometric {end_to_end['geometric']['fps_2_workers']['median']:.2f} fps, "
              f"+sp {end_to_end['geometric+sp']['fps_2_workers']['median']:.2f} fps")
    test_frames = MVPD_TEST_VIDEOS * MVPD_FRAMES_PER_VIDEO
    cost = {"videos": MVPD_TEST_VIDEOS, "frames_per_video": round(MVPD_FRAMES_PER_VIDEO, 1), "frames": round(test_frames),
            "derivation": "6.06 M frames / 18,000 videos = 336.7 frames per video; test = 18 scenes x 50 trajectories "
                          "x 2 heights = 1,800 videos (before 59 empty ones are rejected)"}
    for label in ("geometric", "geometric+sp"):
        fps = end_to_end[label]["fps_2_workers"]["median"]
        cost[label] = {"hours_on_2_cores": round(test_frames / fps / 3600, 2),
                       "core_hours": round(2 * test_frames / fps / 3600, 2)}
    print(f"MVPd test split: {test_frames / 1e6:.3f} M frames -> geometric {cost['geometric']['hours_on_2_cores']} h, "
          f"geometric+sp {cost['geometric+sp']['hours_on_2_cores']} h on 2 cores")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({
        "targets": {"fps_per_core": TARGET_FPS_PER_CORE, "self_prompting_overhead": TARGET_SP_OVERHEAD},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "load_before": load_before,
                    "load_after": os.getloadavg(), "note": "shared with other jobs: compare ratios, not times"},
        "job": JOB, "vsq": scores, "segmenter": segmenter, "predict": end_to_end, "mvpd_test_cost": cost,
    }, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
