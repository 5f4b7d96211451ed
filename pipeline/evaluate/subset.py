"""Which videos an evaluation scores: a run's split (accepted videos only) and any `--videos` subset.

Runs with a split stage are scored on their `test` split by default (`--split` chooses), only on the
split's accepted videos, with each video's zero-shot ids taken from `zero_shot_instances`. A run without
a split scores every video (the caller says so). `--videos` narrows any of these (and an MVPd split)
to names matching a glob or a comma-separated list, so predictions are needed only for those videos.
"""

from __future__ import annotations

import fnmatch
from dataclasses import replace
from pipeline.evaluate.errors import EvaluationInputError
from pipeline.evaluate.ground_truth import VideoSpec
from pipeline.store.run_folder import RunFolder


def parse_video_patterns(text: str | None) -> tuple[str, ...]:
    """`--videos` value -> patterns: a comma-separated list of names or globs ('' or None: every video)."""
    return tuple(p.strip() for p in (text or "").split(",") if p.strip())


def filter_by_patterns(specs: list[VideoSpec], patterns: tuple[str, ...]) -> list[VideoSpec]:
    """The specs whose video name (or '<embodiment>/<name>' key) matches a pattern; each pattern must match one."""
    if not patterns:
        return specs
    for pattern in patterns:
        if not any(fnmatch.fnmatchcase(s.video_name, pattern) or fnmatch.fnmatchcase(s.key, pattern) for s in specs):
            raise EvaluationInputError(f"--videos: {pattern!r} matches none of the {len(specs)} videos evaluated; "
                                       "give names or globs such as '*.0000000003.*'")
    return [s for s in specs if any(fnmatch.fnmatchcase(s.video_name, p) or fnmatch.fnmatchcase(s.key, p) for p in patterns)]


def select_split(run: RunFolder, specs: list[VideoSpec], split: str) -> list[VideoSpec]:
    """The accepted videos of `split` among `specs`, each with its unseen object ids as zero-shot ids."""
    from pipeline.split.selection import UnknownSplitError, accepted_videos, zero_shot_objects

    try:
        accepted = set(accepted_videos(run, split) or [])
    except UnknownSplitError as error:
        raise EvaluationInputError(f"--split: {error}") from None
    videos = run.read("videos")
    scene_of = dict(zip(zip(videos.column("embodiment").to_pylist(), videos.column("video_name").to_pylist()),
                        videos.column("scene_id").to_pylist()))
    unseen_by_scene: dict[str, list[int]] = {}
    for scene, object_id in sorted(zero_shot_objects(run)):
        unseen_by_scene.setdefault(scene, []).append(object_id)
    chosen = []
    for spec in specs:
        key = (spec.embodiment, spec.video_name)
        if key in accepted:
            chosen.append(replace(spec, zero_shot=unseen_by_scene.get(scene_of[key], [])))
    return chosen
