"""Training export benchmark: frames/s of `--coco` and `--yolo` at 640x480 against the bare frame walk.

Run: `cd /work/main && .venv/bin/python benchmarks/bench_exports.py [--repeats 7]`.
A run of the test room (tests/render/tiny_scenes.py: a room with furniture, 7-9 objects per frame) is
rendered at MVPd's 640x480, two lights, both heights, 6 frames each (24 frames). Each export runs
`--repeats` times into a fresh folder, taking turns with the peer. The peer, in the same process and on
the same frames, reads every frame's RGB and panoptic arrays and finds its objects without writing
anything, so the ratio export / walk is the cost of the format itself (JPEG encoding, RLE or contour
tracing, JSON or text). Medians and spreads go to benchmarks/results/exports.json; from the export rate,
the hours one core needs for MVPd's 6.06 M frames (or a tenth of them with `--every 10`).
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

from pipeline.config import Illumination, Job, ProceduralSource, RenderConfig, SceneSources  # noqa: E402
from pipeline.io.coco import CocoExporter  # noqa: E402
from pipeline.io.reader import load_video  # noqa: E402
from pipeline.io.training_export import ExportOptions, export_training_data, frame_objects, unsplit  # noqa: E402
from pipeline.io.yolo import YoloExporter  # noqa: E402
from pipeline.store.run_folder import RunFolder  # noqa: E402
from tests.render.tiny_run import render_tiny_run  # noqa: E402
from tests.render.tiny_scenes import embodiment  # noqa: E402

MVPD_FRAMES = 6_060_000
SPOT = Illumination(kind="spot", power=20.0)


def render_run(root: Path) -> RunFolder:
    """The test room at 640 x 480, ambient and spot light, heights 1.0 m and 0.1 m: 4 videos of 6 frames."""
    job = Job(name="bench-exports", scenes=SceneSources(procedural=ProceduralSource(count=1)),
              render=RenderConfig(frames_per_shard=16), embodiments=[embodiment(640, 480, name="ambient"),
                                                                    embodiment(640, 480, name="spot", light=SPOT)])
    return render_tiny_run(root, job=job)


def walk(run: RunFolder) -> int:
    """The peer: read every frame's RGB and panoptic and find its objects, write nothing. Returns frames."""
    frames = 0
    for embodiment_name, name in unsplit(run)["all"]:
        video = load_video(run, name, embodiment_name)
        for t in range(video.frames):
            np.asarray(video.rgb[t])
            frame_objects(np.asarray(video.panoptic[t]), video, drop_stuff=False)
            frames += 1
    return frames


def timed(actions: dict[str, Any], repeats: int) -> dict[str, tuple[list[float], int]]:
    """Seconds of each repeat of each action and the frames one repeat handled. The actions take turns
    (walk, coco, yolo, walk, ...) so a burst of load from other processes falls on all of them alike."""
    seconds: dict[str, list[float]] = {label: [] for label in actions}
    frames: dict[str, int] = {}
    for _ in range(repeats):
        for label, action in actions.items():
            started = time.perf_counter()
            frames[label] = action()
            seconds[label].append(time.perf_counter() - started)
    return {label: (seconds[label], frames[label]) for label in actions}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    arguments = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        run = render_run(Path(folder) / "run")
        results: dict[str, Any] = {}

        def export(exporter: type) -> Any:
            def action() -> int:
                out = Path(folder) / "out"
                shutil.rmtree(out, ignore_errors=True)
                summary = export_training_data(run, out, unsplit(run), exporter, ExportOptions())
                return sum(summary.frames.values())
            return action

        actions = {"walk": lambda: walk(run), "coco": export(CocoExporter), "yolo": export(YoloExporter)}
        for label, (seconds, frames) in timed(actions, arguments.repeats).items():
            rates = [frames / s for s in seconds]
            results[label] = {"frames": frames, "fps_median": statistics.median(rates),
                              "fps_min": min(rates), "fps_max": max(rates), "fps_all": rates}
    walk_fps = results["walk"]["fps_median"]
    for label in ("coco", "yolo"):
        fps = results[label]["fps_median"]
        results[label]["time_vs_walk"] = walk_fps / fps
        results[label]["mvpd_core_hours"] = MVPD_FRAMES / fps / 3600
    record = {"benchmark": "exports", "resolution": [640, 480], "host": platform.node(), "cpus": os.cpu_count(),
              "note": "shared 2-core VM, other sessions running: compare ratios, not times", **results}
    out = Path(__file__).resolve().parent / "results" / "exports.json"
    out.write_text(json.dumps(record, indent=2) + "\n")
    for label in ("walk", "coco", "yolo"):
        r = results[label]
        extra = (f", {r['time_vs_walk']:.1f}x the walk's time, MVPd's 6.06 M frames: {r['mvpd_core_hours']:.0f} "
                 "core-hours" if "time_vs_walk" in r else "")
        print(f"{label:10s} {r['fps_median']:6.1f} frames/s (min {r['fps_min']:.1f}, max {r['fps_max']:.1f}){extra}")
    print(f"-> {out}")


if __name__ == "__main__":
    main()
