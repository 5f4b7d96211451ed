"""A run folder of synthetic metadata for the split tests: scenes, objects, videos, frames and masks."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources, SplitConfig
from pipeline.store.run_folder import RunFolder
from pipeline.split.synthetic import mark_done, neutral_rows, write_dataset

WIDTH, HEIGHT = 64, 48


@dataclass
class FakeVideo:
    """One video: its scene, the void fraction of each frame and the objects it shows."""

    scene_id: str
    name: str
    void: list[float]
    objects: list[int] = field(default_factory=list)
    embodiment: str = "cam"


def split_job(split: SplitConfig | None = None, embodiments: tuple[str, ...] = ("cam",)) -> Job:
    """A job whose split section is `split` (the default split config when omitted)."""
    return Job(name="split-test", scenes=SceneSources(procedural=ProceduralSource(count=1)),
               embodiments=[Embodiment(name=e) for e in embodiments], split=split or SplitConfig())


def build_run(root: Path, job: Job, objects: dict[str, list[tuple[int, str, int]]], videos: list[FakeVideo]) -> RunFolder:
    """A run folder holding `objects` (scene -> [(object id, raw name, mpcat40)]) and `videos`, with shard/render markers."""
    run = RunFolder.create(root, job)
    write_dataset(run, "scenes", neutral_rows("scenes", [{"scene_id": s, "source": "procedural"} for s in sorted(objects)]))
    write_dataset(run, "objects", neutral_rows("objects", [
        {"scene_id": s, "object_id": o, "raw_name": n, "mpcat40_index": c, "mpcat40_name": str(c), "region": -1}
        for s, rows in sorted(objects.items()) for o, n, c in rows]))
    category = {(s, o): c for s, rows in objects.items() for o, _, c in rows}
    write_dataset(run, "videos", neutral_rows("videos", [
        {"embodiment": v.embodiment, "video_name": v.name, "scene_id": v.scene_id, "frames": len(v.void),
         "width": WIDTH, "height": HEIGHT, "store_path": f"videos/{v.embodiment}/{v.name}.zarr", "illumination": "ambient"}
        for v in videos]))
    write_dataset(run, "frame_stats", neutral_rows("frame_stats", [
        {"embodiment": v.embodiment, "video_name": v.name, "frame": t, "void_fraction": f}
        for v in videos for t, f in enumerate(v.void)]))
    write_dataset(run, "segments", neutral_rows("segments", [
        {"embodiment": v.embodiment, "video_name": v.name, "frame": 0, "object_id": o,
         "category": category[(v.scene_id, o)], "area": 10}
        for v in videos for o in v.objects]))
    mark_done(run, "shard", sorted(objects))
    mark_done(run, "render", sorted(f"{v.embodiment}.{v.name}" for v in videos))
    return run
