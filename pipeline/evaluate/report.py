"""Evaluation results: from the `metrics` table to the published JSON layout and a rich table.

JSON: {"per_video": {video: {"zero-shot"|"non-zero-shot": {"1"|"5"|...: {"IOU", "TP", "FP", "FN"}}}},
       "summary": {"aggregate"|"zero-shot"|"non-zero-shot": {"1", "5", ..., "VSQ"}},
       "videos": {video: {"frames", "missing_frames"}}, "protocol": {...}, "failed": [...]}
Values are fractions (not percent); a bucket no video adds to is 0.0 for every k, as published.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
from rich.table import Table

from pipeline.evaluate.vsq import SUMMARY_BUCKETS, Counts, VideoCounts, VsqProtocol, summarize
from pipeline.runtime.status import UnitOutcome


@dataclass
class EvaluationResult:
    """Everything one evaluation produced."""

    protocol: VsqProtocol
    per_video: dict[str, VideoCounts]
    videos: dict[str, dict[str, int]]
    failed: list[UnitOutcome] = field(default_factory=list)
    split: str = ""

    @property
    def summary(self) -> dict[str, dict[str, float]]:
        return summarize(self.per_video.values(), self.protocol.ks)

    @property
    def missing_frames(self) -> int:
        return sum(v["missing_frames"] for v in self.videos.values())

    def to_json(self) -> dict[str, Any]:
        return {
            "per_video": {key: counts.as_dict() for key, counts in sorted(self.per_video.items())},
            "summary": self.summary,
            "split": self.split,
            "videos": dict(sorted(self.videos.items())),
            "protocol": {**asdict(self.protocol), "ks": list(self.protocol.ks)},
            "failed": [{"unit": o.unit, "error_type": o.error_type, "message": o.message} for o in self.failed],
        }


def video_key(embodiment: str, video_name: str) -> str:
    """Key of a video in outputs: its name, prefixed by the embodiment for runs."""
    return f"{embodiment}/{video_name}" if embodiment else video_name


def result_from_table(table: pa.Table, protocol: VsqProtocol, failed: list[UnitOutcome] | None = None) -> EvaluationResult:
    """Per-video counts from `metrics` rows (rows with another k than the protocol's are ignored)."""
    per_video: dict[str, VideoCounts] = {}
    videos: dict[str, dict[str, int]] = {}
    for row in table.to_pylist():
        key = video_key(row["embodiment"], row["video_name"])
        counts = per_video.setdefault(key, VideoCounts(protocol.ks))
        videos[key] = {"frames": row["frames"], "missing_frames": row["missing_frames"]}
        if row["k"] in protocol.ks:
            counts.buckets[row["bucket"]][row["k"]] += Counts(row["iou"], row["tp"], row["fp"], row["fn"])
    return EvaluationResult(protocol, per_video, videos, list(failed or []))


def write_json(result: EvaluationResult, path: Path) -> None:
    """Write the result JSON (temp file + rename)."""
    from pipeline.store.names import atomic_write_text

    atomic_write_text(Path(path), json.dumps(result.to_json(), indent=1, sort_keys=False))


def summary_table(result: EvaluationResult) -> Table:
    """VSQ^k and VSQ per bucket, in percent for reading (the JSON holds fractions)."""
    ks = [str(k) for k in result.protocol.ks]
    table = Table(title=f"VSQ over {len(result.per_video)} videos (percent)")
    table.add_column("bucket")
    for k in ks:
        table.add_column(f"k={k}", justify="right")
    table.add_column("VSQ", justify="right", style="bold")
    for bucket in SUMMARY_BUCKETS:
        values = result.summary[bucket]
        table.add_row(bucket, *[_percent(values[k]) for k in [*ks, "VSQ"]])
    return table


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.2f}"
