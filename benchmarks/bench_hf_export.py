"""Hugging Face export benchmark: `export --hf` against `export --mvpd` on one run, and reading the export
through `datasets` (plain and streaming) against the project's own `iter_clips`.

Run: `.venv/bin/python benchmarks/bench_hf_export.py [--run runs/demo] [--repeats 3]`.
Without `--run`, the demo job (jobs/demo.yaml: three generated houses, 12 videos per embodiment, 320x240)
is rendered into a temporary folder first with `mvpd submit`. The ambient embodiment is exported (the
MVPd export adds the spot-lit copy's JPEGs as `imagesRGB.0000000020`: its bytes are reported with and
without them). Every figure is taken `--repeats` times, the contenders taking turns so that a burst of
load from other processes falls on all alike; medians and spreads go to benchmarks/results/hf_export.json.

- export: seconds, frames/s and bytes per frame of each format (one process each: under 2,000 frames the
  MVPd export does not start worker processes).
- memory: the --hf export's peak resident set growth, and its resident set after each video (flat in the
  number of videos: one video, one row group at a time): the highest of the first and of the second half.
- read: frames/s of one pass over every row, one process: `datasets` plain (the Arrow cache made by the
  first `load_dataset`, timed apart as `prepare`) and streaming (straight from the Parquet shards), both
  `.with_format("numpy")` reading rgb, depth and panoptic, row by row and in batches of 8 rows;
  `iter_clips(clip_len=8)` over the same videos.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_exports import timed  # noqa: E402
from bench_split import PeakRss  # noqa: E402

from pipeline.io.huggingface import export_hf_dataset  # noqa: E402
from pipeline.io.mvpd import export_release_splits  # noqa: E402
from pipeline.io.reader import iter_clips, list_videos  # noqa: E402
from pipeline.store.run_folder import RunFolder  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
EMBODIMENT = "ambient"
PIXELS = ("rgb", "depth", "panoptic")
BATCH = 8  # rows per batch of the batched reads: the clip length iter_clips is read with


def demo_run(folder: Path) -> Path:
    """Render the demo job into `folder` / run with the CLI (local Ray, about two minutes on 2 cores)."""
    run = folder / "run"
    subprocess.run([str(ROOT / ".venv" / "bin" / "mvpd"), "submit", str(ROOT / "jobs" / "demo.yaml"), "--run-dir",
                    str(run)], check=True, stdout=subprocess.DEVNULL)
    return run


def folder_bytes(folder: Path, skip: str | None = None) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not (skip and skip in p.parts))


def summary(values: list[float]) -> dict[str, Any]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "all": values}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, help="an existing rendered run with a split (default: render the demo)")
    parser.add_argument("--repeats", type=int, default=3)
    arguments = parser.parse_args()
    os.environ.update(HF_DATASETS_OFFLINE="1", HF_HUB_OFFLINE="1")
    with tempfile.TemporaryDirectory() as scratch:
        scratch_path = Path(scratch)
        os.environ["HF_HOME"] = str(scratch_path / "hf-home")
        run = RunFolder.open(arguments.run or demo_run(scratch_path))
        record = measure(run, scratch_path, arguments.repeats)
    record.update(benchmark="hf_export", host=platform.node(), cpus=os.cpu_count(),
                  note="shared 2-core VM, other sessions running: compare ratios, not times")
    out = Path(__file__).resolve().parent / "results" / "hf_export.json"
    out.write_text(json.dumps(record, indent=2) + "\n")
    report(record)
    print(f"-> {out}")


def measure(run: RunFolder, scratch: Path, repeats: int) -> dict[str, Any]:
    import datasets

    videos = [key for key in list_videos(run) if key[0] == EMBODIMENT]
    frames = int(sum(r["frames"] for r in run.read("videos").to_pylist() if r["embodiment"] == EMBODIMENT))
    hf, mvpd = scratch / "hf", scratch / "mvpd"

    def export_hf() -> int:
        return sum(export_hf_dataset(run, hf, embodiment=EMBODIMENT, overwrite=True).frames.values())

    def export_mvpd() -> int:
        shutil.rmtree(mvpd, ignore_errors=True)
        return sum(summary.frames for summary in export_release_splits(run, mvpd, EMBODIMENT))

    seconds = {label: times for label, (times, _) in timed({"hf": export_hf, "mvpd": export_mvpd}, repeats).items()}
    sizes = {"hf": folder_bytes(hf), "mvpd": folder_bytes(mvpd),
             "mvpd_without_lit_rgb": folder_bytes(mvpd, skip="imagesRGB.0000000020")}

    memory: dict[str, list[float]] = {"peak_growth": [], "first_half_max": [], "second_half_max": []}
    series = []
    for _ in range(repeats):  # resident set after each video: flat in the number of videos written
        before = psutil.Process().memory_info().rss
        after_video: list[float] = []
        with PeakRss() as peak:
            export_hf_dataset(run, scratch / "hf-memory", embodiment=EMBODIMENT, overwrite=True,
                              on_video=lambda name: after_video.append(psutil.Process().memory_info().rss / 2**20))
        half = len(after_video) // 2
        memory["peak_growth"].append((peak.peak - before) / 2**20)
        memory["first_half_max"].append(max(after_video[:half]))
        memory["second_half_max"].append(max(after_video[half:]))
        series.append(after_video)

    def prepare() -> int:
        shutil.rmtree(scratch / "cache", ignore_errors=True)
        return sum(d.num_rows for d in datasets.load_dataset(str(hf), cache_dir=str(scratch / "cache")).values())

    def read_plain() -> int:
        loaded = datasets.load_dataset(str(hf), cache_dir=str(scratch / "cache"))
        return sum(_touch(row) for split in loaded.values() for row in split.with_format("numpy"))

    def read_streaming() -> int:
        loaded = datasets.load_dataset(str(hf), streaming=True, cache_dir=str(scratch / "cache"))
        return sum(_touch(row) for split in loaded.values() for row in split.with_format("numpy"))

    def read_plain_batched() -> int:
        loaded = datasets.load_dataset(str(hf), cache_dir=str(scratch / "cache"))
        return sum(_touch_batch(batch) for split in loaded.values()
                   for batch in split.with_format("numpy").iter(batch_size=BATCH))

    def read_streaming_batched() -> int:
        loaded = datasets.load_dataset(str(hf), streaming=True, cache_dir=str(scratch / "cache"))
        return sum(_touch_batch(batch) for split in loaded.values()
                   for batch in split.with_format("numpy").iter(batch_size=BATCH))

    def read_iter_clips() -> int:
        return sum(clip["panoptic"].shape[0] for clip in iter_clips(run, 8, videos=videos, arrays=PIXELS))

    reads: dict[str, Callable[[], int]] = {
        "prepare": prepare, "datasets_plain": read_plain, "datasets_streaming": read_streaming,
        "datasets_plain_batch8": read_plain_batched, "datasets_streaming_batch8": read_streaming_batched,
        "iter_clips": read_iter_clips}
    read_times = timed(reads, repeats)
    rates = {label: [frames / s for s in times] for label, (times, frames) in read_times.items()}
    counted = {label: frames for label, (_, frames) in read_times.items()}
    return {
        "run": str(run.location), "embodiment": EMBODIMENT, "videos": len(videos), "frames": frames,
        "resolution": list(_resolution(run)), "repeats": repeats,
        "export_seconds": {label: summary(values) for label, values in seconds.items()},
        "export_fps": {label: summary([frames / s for s in values]) for label, values in seconds.items()},
        "bytes": sizes, "bytes_per_frame": {label: size / frames for label, size in sizes.items()},
        "export_rss_mib": {label: summary(values) for label, values in memory.items()},
        "export_rss_after_each_video_mib": series,
        "read_fps": {label: summary(values) for label, values in rates.items()},
        "read_frames": counted,
    }


def _touch(row: dict[str, Any]) -> int:
    """Use every pixel column of a decoded row (so lazy decoding cannot skip work); counts one frame."""
    return int(all(row[name].size > 0 for name in PIXELS))


def _touch_batch(batch: dict[str, Any]) -> int:
    """Use every pixel column of a decoded batch; counts its frames."""
    return int(min(len(batch[name]) for name in PIXELS)) if all(batch[name].size > 0 for name in PIXELS) else 0


def _resolution(run: RunFolder) -> tuple[int, int]:
    row = next(r for r in run.read("videos").to_pylist() if r["embodiment"] == EMBODIMENT)
    return int(row["width"]), int(row["height"])


def report(record: dict[str, Any]) -> None:
    print(f"run {record['run']}: {record['videos']} videos, {record['frames']} frames of {EMBODIMENT} "
          f"at {record['resolution'][0]}x{record['resolution'][1]}, {record['repeats']} repeats")
    for label in ("hf", "mvpd"):
        s, f = record["export_seconds"][label], record["export_fps"][label]
        print(f"export --{label:5s} {s['median']:6.2f} s (min {s['min']:.2f}, max {s['max']:.2f}), "
              f"{f['median']:6.1f} frames/s, {record['bytes_per_frame'][label] / 1024:7.1f} kB/frame")
    print(f"  --mvpd without the lit copy's JPEGs: {record['bytes_per_frame']['mvpd_without_lit_rgb'] / 1024:.1f} kB/frame")
    for label, values in record["export_rss_mib"].items():
        print(f"export --hf RSS, {label}: {values['median']:.0f} MiB (min {values['min']:.0f}, "
              f"max {values['max']:.0f})")
    for label, values in record["read_fps"].items():
        print(f"read {label:20s} {values['median']:7.1f} frames/s (min {values['min']:.1f}, max {values['max']:.1f})")


if __name__ == "__main__":
    main()
