"""The release's split files, both ways: `empty_videos.json`, `zero_shot.json` and `<split>.txt` scene lists.

Export writes them from the run's split stage (`splits`, `zero_shot_instances`) exactly as the authors'
scripts do: `{"accepted": [sorted names], "rejected": [...]}` for the empty filter in every split and the
zero-shot filter in train; in val/test `{"zero-shot": [{"scene_name", "color": [r, g, b]}]}` sorted by
scene then upper-case hex colour. Import reads them back into the same `splits` flags.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.io.mvpd.layout import EMPTY_VIDEOS, ZERO_SHOT, parse_video_name, read_json

if TYPE_CHECKING:
    from pipeline.store.run_folder import RunFolder

TRAIN = "train"


def split_rows_of(run: RunFolder, split: str) -> dict[str, dict[str, Any]]:
    """video name -> its `splits` row, for one split of a run with a split stage."""
    from pipeline.split.selection import split_rows

    return {r["video_name"]: r for r in split_rows(run) if r["split"] == split}


def empty_videos_file(rows: list[dict[str, Any]]) -> dict[str, list[str]]:
    """`empty_videos.json` of the exported videos' split rows."""
    return {"accepted": sorted(r["video_name"] for r in rows if not r["empty"]),
            "rejected": sorted(r["video_name"] for r in rows if r["empty"])}


def zero_shot_file(run: RunFolder, split: str, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """`zero_shot.json`: train: videos accepted / rejected by the zero-shot filter; val/test: unseen instances."""
    if split == TRAIN:
        return {"accepted": sorted(r["video_name"] for r in rows if not r["zero_shot_rejected"]),
                "rejected": sorted(r["video_name"] for r in rows if r["zero_shot_rejected"])}
    scenes = {r["scene_id"] for r in rows}
    instances = [r for r in run.read("zero_shot_instances").to_pylist() if r["unseen"] and r["scene_id"] in scenes]
    key = lambda r: (r["scene_id"], "%02X%02X%02X" % tuple(r["color"]))  # noqa: E731 - the authors' sort key
    return {"zero-shot": [{"scene_name": r["scene_id"], "color": [int(c) for c in r["color"]]} for r in sorted(instances, key=key)]}


def read_split_flags(folder: Path, split: str, video_names: list[str]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(`splits` rows, unseen `zero_shot_instances` rows) of an imported split from its files (absent files: no flags)."""
    empty = read_json(folder / EMPTY_VIDEOS, f"{split}/{EMPTY_VIDEOS}") if (folder / EMPTY_VIDEOS).is_file() else {}
    zero_shot = read_json(folder / ZERO_SHOT, f"{split}/{ZERO_SHOT}") if (folder / ZERO_SHOT).is_file() else {}
    rejected_empty = set(empty.get("rejected", []))
    rejected_zero_shot = set(zero_shot.get("rejected", [])) if split == TRAIN else set()
    rows = []
    for name in sorted(video_names):
        scene = parse_video_name(name, folder / EMPTY_VIDEOS).scene_id
        is_empty, is_zero_shot = name in rejected_empty, name in rejected_zero_shot
        rows.append({"embodiment": "", "video_name": name, "scene_id": scene, "split": split, "empty": is_empty,
                     "zero_shot_rejected": is_zero_shot, "accepted": not (is_empty or is_zero_shot)})
    instances = [{"scene_id": str(e["scene_name"]), "object_id": (int(e["color"][0]) << 16) | (int(e["color"][1]) << 8) | int(e["color"][2]),
                  "color": [int(c) for c in e["color"]], "raw_name": "", "cluster": -1, "unseen": True}
                 for e in zero_shot.get("zero-shot", [])]
    return rows, instances
