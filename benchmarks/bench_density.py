"""How dense the generated houses look through the camera: object instances seen per video (the scenes
issue asks for roughly 50-150, like MVPd) and per frame (MVPd: 162 M masks / 6 M frames = 27).

Runs the real pipeline (shard, plan, render on local Ray) on three houses at detail 0.5 with MVPd-length
trajectories (100-600 frames) at both camera heights, at 320x240 to keep it to a few minutes (small
objects a 640x480 camera would also resolve are undercounted, so the numbers are a lower bound), then
reads the counts with `mvpd stats`' queries. Run: `.venv/bin/python benchmarks/bench_density.py`;
numbers are printed and written to benchmarks/results/density.json.
"""

from __future__ import annotations

import json
import os
import platform
import tempfile
import time
from pathlib import Path

from pipeline.config import Job
from pipeline.io.dataset_stats import dataset_stats
from pipeline.io.query import connect
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.runner import submit

OBJECTS_PER_VIDEO_TARGET = (50, 150)
MVPD_OBJECTS_PER_FRAME = 162e6 / 6e6
RESULTS = Path(__file__).resolve().parent / "results" / "density.json"

JOB = {
    "name": "density", "seed": 0,
    "scenes": {"procedural": {"count": 3, "seed": 11, "detail": 0.5}},
    "embodiments": [{"name": "mvpd", "sensor": {"width": 320, "height": 240, "hfov": 69.0}, "placements": [1.0, 0.1],
                     "body": {"radius": 0.15, "height": 1.2}, "illumination": {"kind": "ambient"}}],
    "plan": {"trajectories_per_scene": 4, "min_frames": 100, "max_frames": 600},
}

PER_HEIGHT = """
select height_m, count(*) as videos, avg(frames) as frames, min(objects) as fewest, avg(objects) as mean,
       max(objects) as most
from (select v.height_m, v.video_name, any_value(v.frames) as frames, count(distinct s.object_id) as objects
      from videos v join segments s using (embodiment, video_name) group by all)
group by 1 order by 1 desc
"""


def main() -> None:
    """Render the job, print objects per video and per frame against the targets, write JSON."""
    with tempfile.TemporaryDirectory() as scratch:
        started = time.perf_counter()
        report = submit(Job.model_validate(JOB), RunFolder.prepare(Path(scratch) / "run"))
        seconds = time.perf_counter() - started
        run = RunFolder.open(Path(scratch) / "run")
        stats = dataset_stats(run)
        relation = connect(run).sql(PER_HEIGHT)
        per_height = [dict(zip(relation.columns, row)) for row in relation.fetchall()]
    (overall,) = stats.per_embodiment
    low, high = OBJECTS_PER_VIDEO_TARGET
    verdict = "ok" if low <= overall["objects_per_video"] <= high else "OUTSIDE"
    print(f"{overall['videos']} videos, {overall['frames']:,} frames, {overall['masks']:,} masks, "
          f"{stats.instances} object instances in {overall['scenes']} houses ({seconds:.0f} s, failed units: "
          f"{report.failed})")
    for row in per_height:
        print(f"  camera {row['height_m']:.1f} m: {row['videos']} videos of {row['frames']:.0f} frames on average, "
              f"objects per video {row['fewest']}-{row['most']} (mean {row['mean']:.1f})")
    print(f"objects per video {overall['objects_per_video']:.1f} (target {low}-{high}: {verdict}); objects per frame "
          f"{overall['objects_per_frame']:.1f} (MVPd {MVPD_OBJECTS_PER_FRAME:.0f})")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({
        "targets": {"objects_per_video": OBJECTS_PER_VIDEO_TARGET, "mvpd_objects_per_frame": MVPD_OBJECTS_PER_FRAME},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()}, "job": JOB,
        "seconds": round(seconds, 1), "overall": overall, "per_height": per_height,
        "top_categories": stats.per_category[:10],
    }, indent=1, default=float) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
