"""Small builders shared by the evaluate tests: arrays in, VideoCounts out."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from pipeline.evaluate.frames import ground_truth_frame, prediction_frame_from_masks
from pipeline.evaluate.vsq import VideoCounts, VsqProtocol, evaluate_video


def masks_of(*masks: np.ndarray) -> np.ndarray:
    """Stack boolean masks into (n, H, W); no argument needs a shape, so use `no_masks` for empty frames."""
    return np.stack([np.asarray(m, dtype=bool) for m in masks])


def no_masks(height: int, width: int) -> np.ndarray:
    return np.zeros((0, height, width), dtype=bool)


def evaluate_arrays(truth: np.ndarray, predictions: Sequence[np.ndarray], zero_shot: Sequence[int] = (),
                    protocol: VsqProtocol = VsqProtocol(min_area_fraction=0.0, subsample=1)) -> VideoCounts:
    """Counts of one video given full-resolution id frames (T, H, W) and per-frame masks (n, H, W).

    The default protocol here switches off the small-segment filter and the subsampling so that hand
    arithmetic stays simple; tests of those two steps pass their own protocol.
    """
    gt = [ground_truth_frame(frame, protocol.min_area_fraction, protocol.subsample) for frame in truth]
    pred = [prediction_frame_from_masks(m, protocol.subsample) for m in predictions]
    return evaluate_video(gt, pred, zero_shot, protocol)


def counts(video: VideoCounts, bucket: str, k: int) -> tuple[int, int, int]:
    """(TP, FP, FN) of one bucket and k."""
    c = video[bucket][k]
    return c.tp, c.fp, c.fn


def write_mvpd_case(root, videos: dict[str, tuple[np.ndarray, list[np.ndarray]]], split: str = "test",
                    zero_shot: dict[str, list[int]] | None = None, accepted: list[str] | None = None) -> tuple:
    """Write a tiny MVPd-layout split (`root/MVPd/<split>`) and predictions (`root/pred`); returns both paths.

    Ids double as colours in `instance_id_map` (colour [R, G, B] of id = R + 256 G + 256^2 B); ids
    listed in `zero_shot[video]` are written to zero_shot.json by (scene_name, colour).
    """
    import json
    from pathlib import Path

    import cv2
    import pycocotools.mask as mask_utils

    root = Path(root)
    folder, pred = root / "MVPd" / split, root / "pred"
    entries, annotations, zero = [], [], []
    for name, (truth, predictions) in videos.items():
        (folder / "panomasksRGB" / name).mkdir(parents=True, exist_ok=True)
        (pred / "panomasksRLE" / name).mkdir(parents=True, exist_ok=True)
        for t, label in enumerate(truth):
            rgb = np.stack([label & 255, (label >> 8) & 255, label >> 16], axis=-1).astype(np.uint8)
            cv2.imwrite(str(folder / "panomasksRGB" / name / f"{t:010d}.png"), rgb[..., ::-1])
            rles = mask_utils.encode(np.asfortranarray(predictions[t].transpose(1, 2, 0).astype(np.uint8))) if len(predictions[t]) else []
            payload = {"coco_rle": [{"size": r["size"], "counts": r["counts"].decode()} for r in rles]}
            (pred / "panomasksRLE" / name / f"{t:010d}.json").write_text(json.dumps(payload))
        scene = name.split(".")[0]
        ids = sorted(int(i) for i in np.unique(truth) if i != 0)
        colors = {i: [i & 255, (i >> 8) & 255, i >> 16] for i in ids}
        zero += [{"scene_name": scene, "color": colors[i]} for i in (zero_shot or {}).get(name, [])]
        entries.append({"video_name": name, "images": [{"file_name": f"{t:010d}.jpg"} for t in range(len(truth))]})
        annotations.append({"video_name": name, "annotations": [{"file_name": f"{t:010d}.png"} for t in range(len(truth))],
                            "instance_id_map": {str(i): {"category_id": 39, "scene_name": scene, "color": colors[i]} for i in ids}})
    (folder / f"panoptic_{split}.json").write_text(json.dumps({"videos": entries, "annotations": annotations, "categories": []}))
    (folder / "zero_shot.json").write_text(json.dumps({"zero-shot": zero}))
    if accepted is not None:
        (folder / "empty_videos.json").write_text(json.dumps({"accepted": accepted, "rejected": []}))
    return root / "MVPd", pred
