"""Speed of VSQ evaluation against the published evaluator's rate (not a test).

Cases:
  small      tests/data/vsq_small, the input the published evaluator was timed on
             (`published_evaluator_seconds` for `frames` frames on this 2-core machine).
  realistic  generated: 480x640, ~60 ground-truth objects and ~70 overlapping predicted masks per
             frame, MVPd layout (PNG ground truth, per-frame COCO RLE JSON predictions).

For each case it measures frames per second end to end (read PNG + JSON, decode, metric) in one
process, and on 2 cores through `mvpd evaluate`'s Ray path; plus the metric alone on decoded arrays.
Frames are the videos' frames (as `frames` in expected.json counts them). Target: >= 100x the
published rate. Writes benchmarks/results/evaluate.json.

    cd /work/main && .venv/bin/python benchmarks/bench_evaluate.py [--videos 8] [--frames 61]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from pipeline.evaluate.frames import LazyFrames, ground_truth_frame  # noqa: E402
from pipeline.evaluate.ground_truth import GroundTruthLoader, MvpdSplit  # noqa: E402
from pipeline.evaluate.predictions import PredictionSource  # noqa: E402
from pipeline.evaluate.vsq import VsqProtocol, evaluate_video  # noqa: E402
from pipeline.store.run_folder import RunFolder  # noqa: E402

SMALL = REPO / "tests" / "data" / "vsq_small"
RESULTS = REPO / "benchmarks" / "results" / "evaluate.json"
TARGET_FACTOR = 100.0


# ------------------------------------------------------------------------------ realistic case


def _label_video(rng: np.random.Generator, frames: int, height: int, width: int, objects: int) -> np.ndarray:
    """Voronoi cells drifting across the frame: ~`objects` ids per frame, a few small ones."""
    seeds = rng.uniform([0, 0], [height, width], size=(objects + 10, 2))
    velocity = rng.normal(0, 1.5, size=seeds.shape)
    ids = rng.choice(np.arange(1, 2**24), size=seeds.shape[0], replace=False)
    yy, xx = np.mgrid[0:height:4, 0:width:4]
    video = np.zeros((frames, height, width), dtype=np.uint32)
    for t in range(frames):
        points = seeds + velocity * t
        distance = (yy[..., None] - points[:, 0]) ** 2 + (xx[..., None] - points[:, 1]) ** 2
        coarse = ids[np.argmin(distance, axis=-1)].astype(np.uint32)
        video[t] = np.repeat(np.repeat(coarse, 4, axis=0), 4, axis=1)[:height, :width]
        video[t, : height // 20] = 0  # a void band, as where the renderer hits nothing
    return video


def _predicted_masks(rng: np.random.Generator, label: np.ndarray, masks: int) -> np.ndarray:
    """~`masks` overlapping masks: cells with a shifted boundary, some split in two, some extra blobs."""
    import cv2

    height, width = label.shape
    ids = [i for i in np.unique(label) if i != 0]
    out = []
    for object_id in ids:
        mask = (label == object_id).astype(np.uint8)
        mask = cv2.dilate(mask, np.ones((5, 5), np.uint8)) if rng.random() < 0.5 else cv2.erode(mask, np.ones((3, 3), np.uint8))
        if rng.random() < 0.1:
            half = mask.copy()
            half[:, : width // 2] = 0
            mask[:, width // 2:] = 0
            out.append(half)
        out.append(mask)
    while len(out) < masks:
        blob = np.zeros((height, width), np.uint8)
        cv2.circle(blob, (int(rng.integers(0, width)), int(rng.integers(0, height))), int(rng.integers(10, 60)), 1, -1)
        out.append(blob)
    order = rng.permutation(len(out))[:masks]
    return np.stack([out[i] for i in order]).astype(bool)


def make_realistic_case(root: Path, videos: int, frames: int, seed: int = 0) -> Path:
    """Write an MVPd-layout split `root/MVPd/test` and predictions `root/pred` (cached by arguments)."""
    import cv2
    import pycocotools.mask as mask_utils

    stamp = root / f"case-{videos}x{frames}-{seed}.done"
    if stamp.is_file():
        return root
    shutil.rmtree(root, ignore_errors=True)
    split = root / "MVPd" / "test"
    rng = np.random.default_rng(seed)
    entries, annotations = [], []
    for v in range(videos):
        name = f"00000-BENCH{v:06d}.{v:010d}.0000000100"
        labels = _label_video(rng, frames, 480, 640, objects=60)
        (split / "panomasksRGB" / name).mkdir(parents=True, exist_ok=True)
        (root / "pred" / "panomasksRLE" / name).mkdir(parents=True, exist_ok=True)
        for t in range(frames):
            rgb = np.stack([labels[t] & 255, (labels[t] >> 8) & 255, labels[t] >> 16], axis=-1).astype(np.uint8)
            cv2.imwrite(str(split / "panomasksRGB" / name / f"{t:010d}.png"), rgb[..., ::-1])
            masks = _predicted_masks(rng, labels[t], masks=70)
            rles = mask_utils.encode(np.asfortranarray(masks.transpose(1, 2, 0).astype(np.uint8)))
            payload = {"coco_rle": [{"size": r["size"], "counts": r["counts"].decode()} for r in rles]}
            (root / "pred" / "panomasksRLE" / name / f"{t:010d}.json").write_text(json.dumps(payload))
        ids = sorted(int(i) for i in np.unique(labels) if i != 0)
        entries.append({"video_name": name, "images": [{"file_name": f"{t:010d}.jpg", "camera_position": [0, 0, 0],
                                                        "camera_rotation": [1, 0, 0, 0]} for t in range(frames)]})
        annotations.append({"video_name": name, "annotations": [{"file_name": f"{t:010d}.png"} for t in range(frames)],
                            "instance_id_map": {str(i): {"category_id": 39, "scene_name": "00000-BENCH",
                                                         "color": [i & 255, (i >> 8) & 255, i >> 16]} for i in ids}})
    (split / "panoptic_test.json").write_text(json.dumps({"videos": entries, "annotations": annotations, "categories": []}))
    stamp.write_text("ok")
    return root


# ----------------------------------------------------------------------------------- measures


def _video_inputs(root: Path, protocol: VsqProtocol):
    for spec in MvpdSplit(root / "MVPd", "test").videos():
        yield spec, GroundTruthLoader(spec), PredictionSource(root / "pred", spec.video_name, spec.stems)


def end_to_end_one_process(root: Path, protocol: VsqProtocol) -> tuple[int, float]:
    """(frames, seconds) reading and evaluating every video in this process."""
    frames, started = 0, time.perf_counter()
    for spec, load, source in _video_inputs(root, protocol):
        shape = load(0).shape
        truth = LazyFrames(spec.frames, lambda i: ground_truth_frame(load(i), protocol.min_area_fraction, protocol.subsample))
        predictions = LazyFrames(spec.frames, lambda i: source.frame(i, shape, protocol.subsample))
        evaluate_video(truth, predictions, spec.zero_shot, protocol)
        frames += spec.frames
    return frames, time.perf_counter() - started


def metric_only(root: Path, protocol: VsqProtocol) -> tuple[int, float]:
    """(frames, seconds) of `evaluate_video` on frames already read and decoded."""
    frames, seconds = 0, 0.0
    for spec, load, source in _video_inputs(root, protocol):
        shape = load(0).shape
        truth = [ground_truth_frame(load(i), protocol.min_area_fraction, protocol.subsample) for i in range(spec.frames)]
        predictions = [source.frame(i, shape, protocol.subsample) for i in range(spec.frames)]
        started = time.perf_counter()
        evaluate_video(truth, predictions, spec.zero_shot, protocol)
        seconds += time.perf_counter() - started
        frames += spec.frames
    return frames, seconds


def end_to_end_ray(root: Path) -> dict[str, tuple[int, float]]:
    """(frames, seconds) of the CLI's path: an evaluation run folder, one Ray task per video, 2 CPUs.

    "cold" includes starting the Ray workers (imports); "warm" evaluates every video again (`--all`)
    on the started workers, which is the rate a whole split sees.
    """
    from pipeline.evaluate.api import evaluate_mvpd
    from pipeline.runtime.ray_session import ensure_ray

    ensure_ray(num_cpus=2)
    measures = {}
    with tempfile.TemporaryDirectory() as work:
        for name, force in (("ray_2_cores_cold", False), ("ray_2_cores_warm", True)):
            started = time.perf_counter()
            result = evaluate_mvpd(root / "MVPd", "test", root / "pred", RunFolder(Path(work) / "eval"), force=force)
            seconds = time.perf_counter() - started
            if result.failed:
                raise RuntimeError(f"benchmark evaluation failed: {result.failed[0].message}")
            measures[name] = (sum(v["frames"] for v in result.videos.values()), seconds)
    return measures


def literal_reference_rate(root: Path, videos: int, frames: int) -> tuple[int, float]:
    """(frames, seconds) of tests/evaluate/reference.py, a literal re-statement of the published
    evaluator's algorithm (pairwise F in Python loops over tubes), on decoded arrays.

    Run on the small case it calibrates against the published evaluator's measured time; run on one
    window of the realistic case it estimates the published rate there, which is far lower than on
    the small case (its cost grows with objects x tubes x pixels).
    """
    import pycocotools.mask as mask_utils

    from pipeline.evaluate.predictions import read_rle_file
    from tests.evaluate.reference import reference_video

    total, seconds = 0, 0.0
    for spec in MvpdSplit(root / "MVPd", "test").videos()[:videos]:
        load = GroundTruthLoader(spec)
        count = min(frames, spec.frames)
        truth = np.stack([load(i) for i in range(count)])
        predictions = []
        for i in range(count):
            rles = read_rle_file(root / "pred" / "panomasksRLE" / spec.video_name / f"{spec.stems[i]}.json")["coco_rle"]
            decoded = [{"size": r["size"], "counts": r["counts"].encode()} for r in rles]
            predictions.append(mask_utils.decode(decoded).transpose(2, 0, 1).astype(bool) if decoded
                               else np.zeros((0, *truth.shape[1:]), dtype=bool))
        started = time.perf_counter()
        reference_video(truth, predictions, set(spec.zero_shot))
        seconds += time.perf_counter() - started
        total += count
    return total, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--videos", type=int, default=16, help="videos of the realistic case")
    parser.add_argument("--frames", type=int, default=61, help="frames per video of the realistic case")
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "mvpd-bench-evaluate")
    parser.add_argument("--no-ray", action="store_true", help="skip the 2-core Ray measurement")
    parser.add_argument("--no-estimate", action="store_true",
                        help="skip estimating the published rate on the realistic case (about a minute)")
    args = parser.parse_args()

    expected = json.loads((SMALL / "expected.json").read_text())
    published_rate = expected["frames"] / expected["published_evaluator_seconds"]
    target = TARGET_FACTOR * published_rate
    protocol = VsqProtocol()
    realistic = make_realistic_case(args.data, args.videos, args.frames)
    results: dict[str, object] = {"published_frames_per_second": published_rate, "target_frames_per_second": target}
    for case, root in (("small", SMALL), ("realistic", realistic)):
        measures = {"one_process": end_to_end_one_process(root, protocol), "metric_only": metric_only(root, protocol)}
        if not args.no_ray:
            measures.update(end_to_end_ray(root))
        results[case] = {name: {"frames": f, "seconds": round(s, 4), "frames_per_second": round(f / s, 1),
                                "times_published": round(f / s / published_rate, 1)} for name, (f, s) in measures.items()}
    if not args.no_estimate:
        small_frames, small_seconds = literal_reference_rate(SMALL, 3, 10**6)
        calibration = published_rate / (small_frames / small_seconds)  # published speed / reference speed
        real_frames, real_seconds = literal_reference_rate(realistic, 1, 16)  # one window
        estimate = calibration * real_frames / real_seconds
        results["published_estimate_realistic"] = {
            "reference_small_frames_per_second": small_frames / small_seconds,
            "reference_realistic_frames_per_second": real_frames / real_seconds,
            "calibration": calibration, "estimated_published_frames_per_second": estimate}
        print(f"estimated published rate on the realistic case: {estimate:.3f} frames/s "
              f"(literal reference {real_frames / real_seconds:.3f} frames/s x calibration {calibration:.2f})")
        for name, row in results["realistic"].items():  # type: ignore[union-attr]
            row["times_published_estimate_realistic"] = round(row["frames_per_second"] / estimate, 1)
    try:
        import psutil

        results["load_average_1min"] = psutil.getloadavg()[0]
    except (ImportError, OSError):
        pass
    print(f"published evaluator: {published_rate:.2f} frames/s; target (x{TARGET_FACTOR:g}): {target:.0f} frames/s")
    for case in ("small", "realistic"):
        for name, row in results[case].items():  # type: ignore[union-attr]
            verdict = "meets" if row["frames_per_second"] >= target else "below"
            extra = (f", x{row['times_published_estimate_realistic']} the estimated published rate on this case"
                     if "times_published_estimate_realistic" in row else "")
            print(f"{case:>9} {name:<16} {row['frames']:>5} frames {row['seconds']:>8.3f} s "
                  f"{row['frames_per_second']:>8.1f} frames/s  x{row['times_published']:<6} ({verdict} target){extra}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
