"""Training export benchmark: frames/s of `--coco` and `--yolo` at 640x480 against the bare frame walk.

Run: `cd /work/main && .venv/bin/python benchmarks/bench_exports.py [--repeats 5]`.
A run of the test room (tests/render/tiny_scenes.py: a room with furniture, 7-9 objects per frame) is
rendered at MVPd's 640x480, both heights, 6 frames each. Each export runs `--repeats` times into a fresh
folder; the peer, in the same process and on the same frames, reads every frame's RGB and panoptic
arrays and finds its objects without writing anything, so the ratio export / walk is the cost of the
format itself (JPEG encoding, RLE or contour tracing, JSON or text). Medians and spreads go to
benchmarks/results/exports.json; from the export rate, the hours one core needs for MVPd's 6.06 M frames
(or a tenth of them with `--every 10`).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.config import Job, ProceduralSource, RenderConfig, SceneSources  # noqa: E402
from pipeline.io.coco import CocoExporter  # noqa: E402
from pipeline.io.reader import load_video  # noqa: E402
from pipeline.io.training_export import ExportOptions, export_training_data, frame_objects, unsplit  # noqa: E402
from pipeline.io.yolo import YoloExporter  # noqa: E402
from pipeline.runtime.executor import run_unit_locally  # noqa: E402
from pipeline.runtime.run_folder import RunFolder  # noqa: E402
from tests.render.tiny_run import RoomRenderer, write_plan  # noqa: E402
from tests.render.tiny_scenes import embodiment  # noqa: E402

MVPD_FRAMES = 6_060_000


def render_run(root: Path) -> RunFolder:
    """The test room at 640 x 480, heights 1.0 m and 0.1 m, 6 frames each."""
    job = Job(name="bench-exports", scenes=SceneSources(procedural=ProceduralSource(count=1)),
              render=RenderConfig(frames_per_shard=16), embodiments=[embodiment(640, 480, name="ambient")])
    run = RunFolder.create(root, job)
    write_plan(run, job)
    stage = RoomRenderer(job)
    for unit in stage.units(run):
        run_unit_locally(stage, run, unit)
    return run


def walk(run: RunFolder) -> int:
    """The peer: read every frame's RGB and panoptic and find its objects, write nothing. Returns frames."""
    frames = 0
    for embodiment_name, name in unsplit(run.root)["all"]:
        video = load_video(run, name, embodiment_name)
        for t in range(video.frames):
            np.asarray(video.rgb[t])
            frame_objects(np.asarray(video.panoptic[t]), video, drop_stuff=False)
            frames += 1
    return frames


def timed(action: Any, repeats: int) -> tuple[list[float], int]:
    """Seconds of each repeat and the frames one repeat handled."""
    seconds, frames = [], 0
    for _ in range(repeats):
        started = time.perf_counter()
        frames = action()
        seconds.append(time.perf_counter() - started)
    return seconds, frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    arguments = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        run = render_run(Path(folder) / "run")
        results: dict[str, Any] = {}

        def export(exporter: type) -> Any:
            def action() -> int:
                out = Path(folder) / "out"
                shutil.rmtree(out, ignore_errors=True)
                summary = export_training_data(run.root, out, unsplit(run.root), exporter, ExportOptions())
                return sum(summary.frames.values())
            return action

        for label, action in (("walk", lambda: walk(run)), ("coco", export(CocoExporter)),
                              ("yolo", export(YoloExporter)), ("walk_again", lambda: walk(run))):
            seconds, frames = timed(action, arguments.repeats)
            rates = [frames / s for s in seconds]
            results[label] = {"frames": frames, "fps_median": statistics.median(rates),
                              "fps_min": min(rates), "fps_max": max(rates), "fps_all": rates}
    walk_fps = statistics.median([results["walk"]["fps_median"], results["walk_again"]["fps_median"]])
    for label in ("coco", "yolo"):
        fps = results[label]["fps_median"]
        results[label]["time_vs_walk"] = walk_fps / fps
        results[label]["mvpd_core_hours"] = MVPD_FRAMES / fps / 3600
    record = {"benchmark": "exports", "resolution": [640, 480], "host": platform.node(), "cpus": os.cpu_count(),
              "note": "shared 2-core VM, other sessions running: compare ratios, not times", **results}
    out = Path(__file__).resolve().parent / "results" / "exports.json"
    out.write_text(json.dumps(record, indent=2) + "\n")
    for label in ("walk", "coco", "yolo", "walk_again"):
        r = results[label]
        extra = (f", {r['time_vs_walk']:.1f}x the walk's time, MVPd's 6.06 M frames: {r['mvpd_core_hours']:.0f} "
                 "core-hours" if "time_vs_walk" in r else "")
        print(f"{label:10s} {r['fps_median']:6.1f} frames/s (min {r['fps_min']:.1f}, max {r['fps_max']:.1f}){extra}")
    print(f"-> {out}")


if __name__ == "__main__":
    main()
