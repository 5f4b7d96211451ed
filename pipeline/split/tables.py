"""Parquet datasets of the two split stages.

`screen` writes `video_void` (per video, its worst frame's void pixels and the empty flag; one part per
embodiment), `zero_shot_clusters`, `zero_shot_instances` and `zero_shot_videos` (one part: the
zero-shot unit). `split` writes `splits` (one part per split name).
"""

from __future__ import annotations

import pyarrow as pa

from pipeline.io.tables import column, register

_VIDEO = [
    column("embodiment", pa.string(), "embodiment name (job file)"),
    column("video_name", pa.string(), "<scene_id>.<trajectory:010d>.<height_mm:010d>"),
    column("scene_id", pa.string(), "scene the video was rendered in"),
]

VIDEO_VOID = register("video_void", [
    *_VIDEO,
    column("frames", pa.int32(), "frames of the video with a frame_stats row"),
    column("max_void_pixels", pa.int64(), "void pixels (panoptic id 0) of the video's worst frame"),
    column("pixels", pa.int64(), "pixels of one frame (width x height)"),
    column("empty", pa.bool_(), "some frame has more void pixels than split.empty_threshold of the frame"),
], row="one rendered video: the input of the empty-video filter")

SPLITS = register("splits", [
    *_VIDEO,
    column("split", pa.string(), "'train', 'val' or 'test' (by scene: a scene is in one split)"),
    column("empty", pa.bool_(), "rejected by the empty-video filter (some frame more than the threshold void)"),
    column("zero_shot_rejected", pa.bool_(), "train only: the video shows an unseen (zero-shot) object instance"),
    column("accepted", pa.bool_(), "neither empty nor zero-shot rejected: the video is in the split's data"),
], row="one video of a split scene and its filter flags")

ZERO_SHOT_CLUSTERS = register("zero_shot_clusters", [
    column("cluster", pa.int32(), "k-means cluster index (scikit-learn's label)"),
    column("size", pa.int32(), "unique raw names in the cluster"),
    column("training_videos", pa.int64(), "training videos (embodiment, video) showing an instance of any of its names"),
    column("rank", pa.int32(), "0 = least seen in training (ties: lower cluster index first)"),
    column("unseen", pa.bool_(), "held out: one of the split.zero_shot.unseen_fraction least-seen clusters"),
    column("example_names", pa.list_(pa.string()), "up to 5 names, most-seen in training first"),
    column("encoder", pa.string(), "text encoder and its options, e.g. 'tfidf(char_wb 2-4)'"),
], row="one cluster of raw object names")

ZERO_SHOT_INSTANCES = register("zero_shot_instances", [
    column("scene_id", pa.string(), "scene of the instance (train or held-out pool)"),
    column("object_id", pa.uint32(), "panoptic id of the instance in its scene"),
    column("color", pa.list_(pa.uint8(), 3), "semantic colour [R, G, B] (HM3DSem: object id 0xRRGGBB), as zero_shot.json names it"),
    column("raw_name", pa.string(), "annotator's raw name (the clustered text)"),
    column("cluster", pa.int32(), "cluster of its raw name"),
    column("unseen", pa.bool_(), "its cluster is held out (a zero-shot object)"),
], row="one object instance of a clustered category (split.zero_shot.categories)")

ZERO_SHOT_VIDEOS = register("zero_shot_videos", [
    *_VIDEO,
    column("unseen_instances", pa.int32(), "unseen object instances visible in some frame of the video"),
], row="one video that shows at least one unseen object instance (any split)")
