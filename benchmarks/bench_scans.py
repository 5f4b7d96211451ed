"""Scan dataset readers against trimesh's own load of the same mesh file, on a ~1 M-triangle scan.

One generated house at detail 1.0 (about 1 M triangles) is written in each dataset's own layout
(tests/scenes/scanfiles.py: binary PLY, Z up; ScanNet with shared vertices, as a real scan has), then,
in one process, alternating, RUNS times each (a ratio holds on a loaded machine, a time does not):
    - peer "trimesh.load": `trimesh.load(<the scene's mesh file>)` as a user calls it (default
      process=True: merges duplicate vertices, drops NaN and degenerate faces; no labels),
    - peer "trimesh parse only": the same with process=False (the arrays as the file holds them: for a
      triangle PLY with no face properties this is little more than np.frombuffer),
    - our reader of the whole scene: mesh + the dataset's label files -> a labelled Scene in the world
      frame (Matterport3D: .house + segmentation .ply; ScanNet v2 / ScanNet++: .ply + segs + aggregation;
      Replica: mesh_semantic.ply + info_semantic.json + the coloured mesh.ply, two PLY files), with the
      exact zero-area test and the per-face labels computed.
The target (issue 19): each reader at most 2x trimesh's load (median of RUNS); both ratios are
recorded. Results: benchmarks/results/scans.json. No extra packages (trimesh is a project dependency).
Run:
    cd /work/main && .venv/bin/python benchmarks/bench_scans.py
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RUNS = 3
TARGET_RATIO = 2.0


def _datasets(folder: Path) -> dict[str, tuple[Path, Callable[[], object]]]:
    """Dataset -> (the mesh file trimesh loads, our reader of the whole scene), written under `folder`."""
    from pipeline.scenes.matterport3d import read_matterport3d
    from pipeline.scenes.procedural.house import generate_house
    from pipeline.scenes.replica import read_replica
    from pipeline.scenes.scannet import read_scannet
    from tests.scenes.scanfiles import write_matterport3d, write_replica, write_scannet, write_scannetpp

    house = generate_house(seed=2, detail=1.0)
    print(f"house: {house.triangle_count} triangles, {len(house.vertices)} vertices, {len(house.objects)} objects")
    house_file = write_matterport3d(house, folder / "mp", "bench0000001")
    scannet = write_scannet(house, folder / "scannet", "scene0000_00", unshare=False)
    scannetpp = write_scannetpp(house, folder / "scannetpp", "bench0000pp", unshare=False)
    replica = write_replica(house, folder / "replica", "room_0")
    return {
        "matterport3d": (house_file.with_suffix(".ply"), lambda: read_matterport3d(house_file, textured=False)),
        "scannet v2": (scannet, lambda: read_scannet(scannet)),
        "scannet++": (scannetpp, lambda: read_scannet(scannetpp)),
        "replica": (replica, lambda: read_replica(replica)),
    }


def main() -> None:
    """Time each reader and its peer, print median and spread, save benchmarks/results/scans.json."""
    import trimesh

    with tempfile.TemporaryDirectory() as folder:
        datasets = _datasets(Path(folder))
        timed: dict[str, Callable[[], object]] = {}
        for name, (mesh, read) in datasets.items():
            timed[f"{name}: trimesh.load"] = lambda mesh=mesh: trimesh.load(str(mesh))
            timed[f"{name}: trimesh parse only"] = lambda mesh=mesh: trimesh.load(str(mesh), process=False)
            timed[f"{name}: our reader"] = read
        for read in timed.values():
            read()  # warm imports and the page cache
        times: dict[str, list[float]] = {name: [] for name in timed}
        for _ in range(RUNS):
            for name, read in timed.items():
                started = time.perf_counter()
                read()
                times[name].append(time.perf_counter() - started)
        triangles = len(trimesh.load(str(next(iter(datasets.values()))[0]), process=False).faces)
    # The machine's 1-minute load average when the runs ended (2 cores shared: ratios, not times, carry over).
    results: dict = {"runs": RUNS, "triangles": triangles, "target_ratio": TARGET_RATIO, "datasets": {},
                     "load_average": round(os.getloadavg()[0], 1)}
    for name in datasets:
        row = {}
        for key, label in (("trimesh_load", "trimesh.load"), ("trimesh_parse_only", "trimesh parse only"),
                           ("reader", "our reader")):
            sample = times[f"{name}: {label}"]
            row |= {f"{key}_median_s": round(statistics.median(sample), 4), f"{key}_min_s": round(min(sample), 4),
                    f"{key}_max_s": round(max(sample), 4)}
        row["ratio_to_trimesh_load"] = round(row["reader_median_s"] / row["trimesh_load_median_s"], 2)
        row["ratio_to_parse_only"] = round(row["reader_median_s"] / row["trimesh_parse_only_median_s"], 2)
        results["datasets"][name] = row
        print(f"{name:>13}: reader {row['reader_median_s']:.3f} s ({row['reader_min_s']:.3f}-{row['reader_max_s']:.3f}); "
              f"trimesh.load {row['trimesh_load_median_s']:.3f} s ({row['trimesh_load_min_s']:.3f}-"
              f"{row['trimesh_load_max_s']:.3f}) -> {row['ratio_to_trimesh_load']:.2f} x (target <= {TARGET_RATIO:g}); "
              f"parse only {row['trimesh_parse_only_median_s']:.3f} s -> {row['ratio_to_parse_only']:.2f} x")
    out = Path(__file__).resolve().parent / "results" / "scans.json"
    out.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
