"""Memory of writing an MVPd split's `panoptic_<split>.json`: spooled per video against the whole object at once.

Run: `cd /work/main && .venv/bin/python benchmarks/bench_mvpd_json.py [--videos 180] [--repeats 3]`.
The entries are synthetic but shaped like MVPd's (6.06 M frames and 162 M masks over 18,000 videos: 337
frames per video, 27 segments per frame); 180 videos is the 1 % job. Each way runs in a fresh process
(its peak RSS, `ru_maxrss`, is the figure), `--repeats` times, taking turns:
- whole: every video's entries held until the end, then `write_json` of the object (the export before the
  spool; the 1 % job's export driver peaked at 0.87 GiB);
- spooled: `PanopticJsonSpool`, each video's entries appended as it is made, then joined.
Both files must be the same bytes. Once more, spooled only, at 4x the videos: its peak must not grow with
the split. Results: benchmarks/results/mvpd_json.json.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.io.mvpd.layout import mvpd_categories, write_json  # noqa: E402
from pipeline.io.mvpd.panoptic_json import PanopticJsonSpool  # noqa: E402

FRAMES, SEGMENTS = 337, 27
RESULTS = Path(__file__).resolve().parent / "results" / "mvpd_json.json"


def video_entries(index: int) -> tuple[str, list, list, dict, list]:
    """One video's images, annotations, instance map and instances, as the exporter makes them."""
    name = f"00{index:03d}-SCENE{index:06d}.{index:010d}.0000001000"
    images, annotations = [], []
    for frame in range(FRAMES):
        stem = f"{frame:010d}"
        images.append({"id": index * FRAMES + frame, "width": 640, "height": 480, "file_name": f"{stem}.jpg",
                       "depth_file_name": f"{stem}.png", "scene_id": name[:17],
                       "camera_position": [0.1 * frame, 1.0, -0.5], "camera_rotation": [0.5, 0.5, 0.5, 0.5]})
        annotations.append({"image_id": index * FRAMES + frame, "file_name": f"{stem}.png", "segments_info": [
            {"id": 1 + s, "category_id": 1 + s % 40, "area": 1000 + s, "bbox": [s, s, 40, 30], "iscrowd": 0}
            for s in range(SEGMENTS)]})
    instance_map = {str(1 + s): {"category_id": 1 + s % 40, "scene_name": name[:17], "color": [s, 2 * s, 3 * s]}
                    for s in range(SEGMENTS)}
    instances = [{"video_name": name, "segment_id": 1 + s, "raw_name": f"object {s}"} for s in range(SEGMENTS)]
    return name, images, annotations, instance_map, instances


def write_whole(path: Path, videos: int) -> None:
    entries = [video_entries(i) for i in range(videos)]
    write_json(path, {
        "videos": [{"video_id": n, "video_name": n, "images": im} for n, im, _, _, _ in entries],
        "annotations": [{"video_id": n, "video_name": n, "annotations": a, "instance_id_map": m}
                        for n, _, a, m, _ in entries],
        "categories": mvpd_categories(),
        "instances": [i for *_, instances in entries for i in instances]})


def write_spooled(path: Path, videos: int) -> None:
    spool = PanopticJsonSpool(path.parent, path.name)
    for i in range(videos):
        spool.add(*video_entries(i))
    spool.finish()


def child(way: str, path: Path, videos: int) -> None:
    """Write the file one way; print wall seconds and this process's peak RSS."""
    started = time.perf_counter()
    (write_whole if way == "whole" else write_spooled)(path, videos)
    print(json.dumps({"seconds": time.perf_counter() - started,
                      "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--videos", type=int, default=180)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], Path(args.child[1]), args.videos)
        return
    runs: dict[str, list[dict]] = {"whole": [], "spooled": []}
    digests = set()
    with tempfile.TemporaryDirectory() as folder:
        for repeat in range(args.repeats):
            for way in runs:
                path = Path(folder) / f"{way}.json"
                done = subprocess.run([sys.executable, __file__, "--videos", str(args.videos), "--child", way, str(path)],
                                      capture_output=True, text=True, check=True)
                runs[way].append(json.loads(done.stdout))
                digests.add(hashlib.sha256(path.read_bytes()).hexdigest())
                size = path.stat().st_size
                print(f"repeat {repeat} {way}: {runs[way][-1]['peak_rss_gib']:.3f} GiB, {runs[way][-1]['seconds']:.1f} s",
                      flush=True)
        done = subprocess.run([sys.executable, __file__, "--videos", str(4 * args.videos), "--child", "spooled",
                               str(Path(folder) / "larger.json")], capture_output=True, text=True, check=True)
        larger = json.loads(done.stdout)
        print(f"spooled at {4 * args.videos} videos: {larger['peak_rss_gib']:.3f} GiB", flush=True)
    summary = {way: {key: {"median": statistics.median(r[key] for r in rows), "min": min(r[key] for r in rows),
                           "max": max(r[key] for r in rows)} for key in ("peak_rss_gib", "seconds")}
               for way, rows in runs.items()}
    result = {"videos": args.videos, "frames_per_video": FRAMES, "segments_per_frame": SEGMENTS,
              "file_bytes": size, "same_bytes": len(digests) == 1, "repeats": args.repeats, **summary,
              "spooled_at_4x_videos": larger, "memory_ratio_whole_over_spooled": round(summary["whole"]["peak_rss_gib"]["median"]
                                                       / summary["spooled"]["peak_rss_gib"]["median"], 2)}
    RESULTS.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
