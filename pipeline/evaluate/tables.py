"""Parquet dataset written by the evaluate stage: `metrics` (one part file per evaluated video).

The rows are the additive per-video counts of the published evaluator (IoU sum, TP, FP, FN per
bucket and k); VSQ ratios are never stored, they are computed from pooled counts (`vsq.summarize`).
"""

from __future__ import annotations

import pyarrow as pa

from pipeline.io.tables import column, register

METRICS = register("metrics", [
    column("embodiment", pa.string(), "embodiment of the video ('' when the ground truth is an MVPd split)"),
    column("video_name", pa.string(), "<scene_id>.<trajectory:010d>.<height_mm:010d>"),
    column("bucket", pa.string(), "'zero-shot' or 'non-zero-shot' (the ground-truth object's bucket; FPs go to both)"),
    column("k", pa.int32(), "prefix length: only the first k frames of each window are scored"),
    column("iou", pa.float64(), "sum over true positives of the tube IoU (fraction, not percent)"),
    column("tp", pa.int64(), "true positives: assigned (ground-truth tube, predicted tube) pairs with F > 0"),
    column("fp", pa.int64(), "false positives: predicted tubes left unassigned"),
    column("fn", pa.int64(), "false negatives: ground-truth tubes of this bucket left unassigned"),
    column("frames", pa.int32(), "frames in the video"),
    column("missing_frames", pa.int32(), "prediction frames missing and counted as empty (--allow-missing)"),
], row="one (video, bucket, k) of a VSQ evaluation")
