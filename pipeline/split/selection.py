"""What the split stages decided, for other code: accepted videos of a split, unseen object instances.

Reads the run's `splits` and `zero_shot_instances` Parquet (never recomputes anything). These are the
names evaluate, the reader, stats and the MVPd export call; a run without split output gives None / an
empty set, and each caller says so in its own words.
"""

from __future__ import annotations

from typing import Any

from pipeline.config import SPLIT_NAMES
from pipeline.store.datasets import dataset_parts, read_dataset
from pipeline.store.run_folder import RunFolder


class UnknownSplitError(ValueError):
    """A split name that is not train, val or test."""


def has_split(run: RunFolder) -> bool:
    """True when the split stage committed its `splits` table in this run."""
    return bool(dataset_parts(run, "splits"))


def check_split_name(split: str) -> str:
    if split not in SPLIT_NAMES:
        raise UnknownSplitError(f"split {split!r}: unknown; splits are {', '.join(SPLIT_NAMES)}")
    return split


def split_rows(run: RunFolder) -> list[dict[str, Any]]:
    """Every `splits` row of the run (empty without a split stage)."""
    return read_dataset(run, "splits").to_pylist() if has_split(run) else []


def accepted_videos(run: RunFolder, split: str) -> list[tuple[str, str]] | None:
    """Sorted (embodiment, video_name) of the accepted videos of `split`; None when the run has no split output.

    Accepted = not empty and (train only) showing no unseen object, as the authors' loader filters with
    `MVPDataset(empty_videos_split=True, zero_shot_split=True)`.
    """
    check_split_name(split)
    if not has_split(run):
        return None
    return sorted((r["embodiment"], r["video_name"]) for r in split_rows(run) if r["split"] == split and r["accepted"])


def zero_shot_objects(run: RunFolder) -> set[tuple[str, int]]:
    """(scene_id, object_id) of every unseen (zero-shot) object instance; empty without split output."""
    table = read_dataset(run, "zero_shot_instances")
    return {(s, int(o)) for s, o, unseen in zip(table.column("scene_id").to_pylist(), table.column("object_id").to_pylist(),
                                                table.column("unseen").to_pylist()) if unseen}
