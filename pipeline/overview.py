"""Pictures of what a run generated: scene plans with paths, video contact sheets, dataset statistics.

Used at the end of `mvpd demo` so that a newcomer sees the data, not only row counts.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.io.dataset_stats import dataset_stats, write_stats_picture
from pipeline.io.reader import load_video
from pipeline.plan.preview import write_plan_preview
from pipeline.render.preview import write_preview
from pipeline.store.run_folder import RunFolder


def write_overview(run: RunFolder, out: Path, scenes: int = 1) -> list[Path]:
    """For the first `scenes` scenes: the plan map, and every height and embodiment of its first trajectory;
    then the distributions of the whole run (`mvpd stats`).

    Returns the written files (plan PNGs, contact-sheet PNGs, GIF animations, the statistics PNG).
    """
    videos = run.read("videos").to_pylist()
    written: list[Path] = []
    for scene_id in sorted({v["scene_id"] for v in videos})[:scenes]:
        written.append(write_plan_preview(run, scene_id, out / f"{scene_id}.plan.png").path)
        in_scene = [v for v in videos if v["scene_id"] == scene_id]
        first = min(v["trajectory"] for v in in_scene)
        for video in sorted((v for v in in_scene if v["trajectory"] == first),
                            key=lambda v: (v["embodiment"], v["video_name"])):
            files = write_preview(load_video(run, video["video_name"], video["embodiment"]), out / video["embodiment"])
            written.extend([files.contact_sheet, files.animation])
    written.append(write_stats_picture(run, dataset_stats(run), out / "stats.png"))
    return written
