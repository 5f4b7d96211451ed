"""The scan datasets' metadata readers at real size, against a bare parse of the same file in the same run.

Files (written here, shaped as published): a ScanNet++ segs file of 1.5 M vertices (ScanNet++'s
mesh_aligned_0.05 meshes hold ~0.5-2 M; ScanNet v2's _vh_clean_2 ~0.05-0.3 M) and an aggregation of 600
groups over 3,000 segments; a Matterport3D .house of 1,500 objects and 30,000 segments (large houses); a
Replica info_semantic.json of 800 objects (apartment_0's order); an HM3DSem .semantic.txt of 2,000 rows.
Each reader (with every check it makes: ranges, types, repeats) and its peer run alternately RUNS times:
    segs         ours: scannet._segment_list        peer: json.loads + np.array (ScanNet's own scripts)
    aggregation  ours: read_groups + vertex_objects peer: json.loads + a dict of objectId -> segments
    .house       ours: read_house                   peer: splitting every line into fields
    info         ours: replica.read_info            peer: json.loads
    .semantic.txt ours: read_semantic_table         peer: csv.reader over the lines
Results (median and spread of RUNS, ms; ratio ours / peer): benchmarks/results/scan_metadata.json.
Run:
    .venv/bin/python benchmarks/bench_scan_metadata.py
"""

from __future__ import annotations

import csv
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RUNS = 7


def _write_files(folder: Path) -> dict[str, Path]:
    rng = np.random.default_rng(0)
    segs = folder / "scene_vh_clean_2.0.010000.segs.json"
    segments = np.sort(rng.integers(0, 3000, 1_500_000)) * 7 + 11
    segs.write_text(json.dumps({"params": {"kThresh": "0.0001"}, "sceneId": "scene", "segIndices": segments.tolist()}))
    aggregation = folder / "scene.aggregation.json"
    pool = np.unique(segments)
    groups = [{"id": k, "objectId": k, "segments": pool[k * 5:(k + 1) * 5].tolist(), "label": "chair"} for k in range(600)]
    aggregation.write_text(json.dumps({"sceneId": "scannet.scene", "segGroups": groups}))
    house = folder / "scan.house"
    lines = ["ASCII 1.1"] + [f"C  {c}  {c + 1} chair  3 chair  0 0 0 0 0" for c in range(100)]
    lines += [f"O  {o} {o % 20} {o % 100}  0 0 0  1 0 0  0 1 0  0.5 0.5 0.5  0 0 0 0 0 0 0 0" for o in range(1500)]
    lines += [f"E  {e} {e % 1500} {(e % 20) * 1000000 + e}  1  0 0 0  0 0 0 1 1 1  0 0 0 0 0" for e in range(30000)]
    house.write_text("\n".join(lines) + "\n")
    info = folder / "info_semantic.json"
    objects = [{"id": i, "class_id": i % 60 if i % 9 else -1, "class_name": "undefined", "node_id": i,
                "oriented_bbox": {"abb": {"center": [0, 0, 0], "sizes": [1, 1, 1]},
                                  "orientation": {"rotation": [0, 0, 0, 1], "translation": [0, 0, 0]}}} for i in range(1, 801)]
    info.write_text(json.dumps({"classes": [{"id": c, "name": f"class{c}"} for c in range(60)], "objects": objects,
                                "id_to_label": [-2] + [o["class_id"] for o in objects], "gravity_dir": [0, 0, -1]}))
    semantic = folder / "scene.semantic.txt"
    semantic.write_text("HM3D Semantic Annotations\n" + "".join(f'{k},{k * 37:06X},"chair",{k % 12}\n' for k in range(1, 2001)))
    return {"segs": segs, "aggregation": aggregation, "house": house, "info": info, "semantic": semantic}


def _pairs(files: dict[str, Path]) -> dict[str, tuple[Callable[[], object], Callable[[], object]]]:
    from pipeline.scenes.hm3dsem import read_semantic_table
    from pipeline.scenes.matterport3d import read_house
    from pipeline.scenes.replica import read_info
    from pipeline.scenes.scannet import _segment_list, read_groups, vertex_objects

    segments = _segment_list(files["segs"])

    def peer_groups() -> object:
        document = json.loads(files["aggregation"].read_text())
        return {g["objectId"] + 1: g["segments"] for g in document["segGroups"]}

    return {
        "segs": (lambda: _segment_list(files["segs"]),
                 lambda: np.array(json.loads(files["segs"].read_text())["segIndices"], np.int64)),
        "aggregation": (lambda: vertex_objects(segments, read_groups(files["aggregation"]), files["segs"], files["aggregation"]),
                        peer_groups),
        "house": (lambda: read_house(files["house"]), lambda: [line.split() for line in files["house"].read_text().splitlines()]),
        "info": (lambda: read_info(files["info"]), lambda: json.loads(files["info"].read_text())),
        "semantic.txt": (lambda: read_semantic_table(files["semantic"]),
                         lambda: list(csv.reader(files["semantic"].read_text().splitlines()))),
    }


def _timed(function: Callable[[], object]) -> float:
    start = time.perf_counter()
    function()
    return (time.perf_counter() - start) * 1000


def main() -> None:
    results = {}
    with tempfile.TemporaryDirectory() as folder:
        for name, (ours, peer) in _pairs(_write_files(Path(folder))).items():
            times: dict[str, list[float]] = {"ours": [], "peer": []}
            for _ in range(RUNS):
                times["ours"].append(_timed(ours))
                times["peer"].append(_timed(peer))
            row = {who: {"median_ms": round(statistics.median(t), 2), "min_ms": round(min(t), 2),
                         "max_ms": round(max(t), 2)} for who, t in times.items()}
            row["ratio"] = round(statistics.median(times["ours"]) / statistics.median(times["peer"]), 2)
            results[name] = row
            print(f"{name:13s} ours {row['ours']['median_ms']:8.1f} ms ({row['ours']['min_ms']}-{row['ours']['max_ms']})  "
                  f"peer {row['peer']['median_ms']:8.1f} ms ({row['peer']['min_ms']}-{row['peer']['max_ms']})  "
                  f"ratio {row['ratio']}")
    out = ROOT / "benchmarks" / "results" / "scan_metadata.json"
    out.write_text(json.dumps({"runs": RUNS, "results": results}, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
