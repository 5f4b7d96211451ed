"""The PLY reader on files of the sizes the datasets publish (issue 30), against trimesh and the old reader.

Files, generated here (never committed; written under --folder or a temporary folder):
    replica_2m_quads    Replica's mesh.ply layout: binary little-endian, vertex x y z nx ny nz red green blue,
                        face `list uchar int vertex_indices` of 4 (a 1600 x 1600 grid: 2.56 M quads, ~113 MB);
                        beside it habitat/mesh_semantic.ply (the same quads + an int object_id per quad) and
                        habitat/info_semantic.json, so the whole Replica scene can be sharded.
    mixed_134mb         the same vertex layout; faces mixing quads and triangles (n-gon exports: runs of 1 to 64
                        quads of a grid alternate with runs split into two triangles), an int object_id per face.
    scannet_vh_clean_2  ScanNet's vh_clean_2 layout: x y z red green blue alpha, triangles (~150 k vertices).
    scannet_size_ascii  the ScanNet-size grid in ASCII, quads and triangles mixed (the ragged ASCII path).
Readers, each run in a fresh `python` process (so ru_maxrss is that reader's own peak), RUNS times, interleaved:
    read_ply            pipeline/scenes/ply.py (this tree), in a process that has not read a PLY yet
    read_ply b5d67c7    the reader before issue 30 (row by row on mixed faces), loaded from git
    trimesh.load        `trimesh.load(path)` as a user calls it (process=True). trimesh 4 cannot read a binary
                        PLY whose lists vary in length ("PLY is unexpected length!"), so on mixed_134mb the peer
                        is also `trimesh.load` of the same mesh fanned into triangles (a uniform file, 151 MB).
    shard               what the shard unit does with the file (scene load + its `scenes` / `objects` rows):
                        the Replica source on replica_2m_quads, the `meshes:` source on mixed_134mb.
Reported per reader and file: median and spread of wall time and of peak RSS (MB; also the peak above the
process's RSS after its imports), and the ratios of read_ply to trimesh.load (targets: time <= 2x,
peak RSS <= 1.5x). Targets of issue 30: mixed_134mb shards under 1.5 GB, replica_2m_quads within 2 GB.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "mesh_readers_real_size.json"
OLD_REF = "b5d67c7"
READERS = ("read_ply", f"read_ply {OLD_REF}", "trimesh.load", "trimesh.load triangulated copy", "shard")
TRIANGULATED = "mixed_134mb_triangulated.ply"
SHARDED = {"replica_2m_quads": "replica", "mixed_134mb": "mesh"}


# ------------------------------------------------------------------------------------------ files


def _grid(size: int, rng: np.random.Generator) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Vertex columns (Replica's layout) of a gently waving (size + 1)^2 grid, 1 cm apart, and its (size^2, 4) quads."""
    row, column = np.divmod(np.arange((size + 1) ** 2), size + 1)
    x, y = column * 0.01, row * 0.01
    z = 0.02 * np.sin(x * 3.0) * np.cos(y * 2.0)
    vertex = {"x": x.astype(np.float32), "y": y.astype(np.float32), "z": z.astype(np.float32),
              "nx": np.zeros_like(x, np.float32), "ny": np.zeros_like(x, np.float32), "nz": np.ones_like(x, np.float32)}
    vertex |= {c: rng.integers(0, 256, len(x)).astype(np.uint8) for c in ("red", "green", "blue")}
    corner = (np.arange(size)[:, None] * (size + 1) + np.arange(size)[None, :]).reshape(-1)
    quads = np.stack([corner, corner + 1, corner + size + 2, corner + size + 1], axis=1).astype(np.int32)
    return vertex, quads


def _mixed(quads: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(corner counts, flat indices, source quad) of faces: runs of 1-64 quads alternately kept and split in two."""
    runs = np.cumsum(rng.integers(1, 65, len(quads) // 8 + 2))
    split = (np.searchsorted(runs, np.arange(len(quads)), side="right") % 2).astype(bool)
    faces_per_quad = np.where(split, 2, 1)
    source = np.repeat(np.arange(len(quads)), faces_per_quad)
    second = np.zeros(len(source), bool)
    second[(np.cumsum(faces_per_quad) - 1)[split]] = True  # the second triangle of a split quad
    sizes = np.where(split[source], 3, 4)
    start = np.cumsum(sizes) - sizes
    items = np.empty(int(sizes.sum()), np.int32)
    for picked, columns in ((sizes == 4, [0, 1, 2, 3]), ((sizes == 3) & ~second, [0, 1, 2]), (second, [0, 2, 3])):
        faces = np.flatnonzero(picked)
        items[(start[faces][:, None] + np.arange(len(columns))).reshape(-1)] = quads[source[faces]][:, columns].reshape(-1)
    return sizes, items, source


def write_files(folder: Path) -> dict[str, Path]:
    """The four files (and the Replica scene's habitat folder) under `folder`, written once and kept."""
    from pipeline.scenes.ply import PlyList, fan_triangles, write_ply

    rng = np.random.default_rng(30)
    files = {"replica_2m_quads": folder / "replica" / "room_0" / "habitat" / "mesh_semantic.ply",
             "mixed_134mb": folder / "mixed_134mb.ply", "scannet_vh_clean_2": folder / "scene0000_00_vh_clean_2.ply",
             "scannet_size_ascii": folder / "scannet_size_ascii.ply"}
    if all(path.is_file() for path in files.values()):
        return files
    vertex, quads = _grid(1600, rng)
    object_ids = ((np.arange(len(quads)) // 1600) // 100 * 16 + (np.arange(len(quads)) % 1600) // 100).astype(np.int32)
    habitat = files["replica_2m_quads"].parent
    habitat.mkdir(parents=True, exist_ok=True)
    write_ply(habitat.parent / "mesh.ply", vertex, quads)
    write_ply(habitat / "mesh_semantic.ply", vertex, quads, {"object_id": object_ids})
    names = ["floor", "wall", "chair", "table", "undefined"]
    (habitat / "info_semantic.json").write_text(json.dumps({
        "classes": [{"id": k + 1, "name": n} for k, n in enumerate(names)],
        "objects": [{"id": int(i), "class_id": int(i % 5) + 1, "class_name": names[i % 5]} for i in range(256)]}))
    vertex, quads = _grid(1568, rng)
    sizes, items, source = _mixed(quads, rng)
    object_ids = (source // 20_000).astype(np.int32)
    write_ply(files["mixed_134mb"], vertex, PlyList(sizes, items), {"object_id": object_ids})
    triangles, polygon = fan_triangles(PlyList(sizes, items))
    write_ply(folder / TRIANGULATED, vertex, triangles, {"object_id": object_ids[polygon]})
    vertex, quads = _grid(386, rng)
    scannet = {k: vertex[k] for k in ("x", "y", "z", "red", "green", "blue")} | {"alpha": np.full(len(vertex["x"]), 255, np.uint8)}
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    write_ply(files["scannet_vh_clean_2"], scannet, triangles)
    sizes, items, _ = _mixed(quads, rng)
    write_ply(files["scannet_size_ascii"], scannet, PlyList(sizes, items), binary=False)
    return files


# ------------------------------------------------------------------------------------------ one measurement


def _status_mb(field: str) -> float:
    """A memory line of /proc/self/status in MB: VmRSS (now) or VmHWM (the peak). getrusage's ru_maxrss is
    no use here: Linux keeps it across exec, so a child would report its parent's peak."""
    with open("/proc/self/status") as handle:
        line = next(line for line in handle if line.startswith(field + ":"))
    return int(line.split()[1]) / 1e3  # kB


def _old_reader(folder: Path):  # noqa: ANN202
    """read_ply of pipeline/scenes/ply.py at OLD_REF."""
    from benchmarks.bench_mesh_readers import module_at_ref

    return module_at_ref(OLD_REF, "pipeline/scenes/ply.py", folder).read_ply


def _shard(path: Path, source: str) -> None:
    """What ShardStage.run_unit does with the scene (pipeline/scenes/shard.py), minus writing the tables."""
    from pipeline.scenes.scene import SceneRef
    from pipeline.scenes.shard import object_rows, scene_row
    from pipeline.scenes.sources import load_mesh, load_replica

    loader = load_replica if source == "replica" else load_mesh
    ref = SceneRef(path.stem, source, str(path), loader, ())
    scene = ref.load()
    scene_row(scene, ref)
    object_rows(scene)


def measure(reader: str, path: Path, dataset: str) -> dict:
    """In this (fresh) process: import what the reader needs, then time it and read its peak RSS."""
    sys.path.insert(0, str(ROOT))
    with tempfile.TemporaryDirectory() as folder:
        if reader.startswith("trimesh.load"):
            import trimesh

            if reader != "trimesh.load":
                path = path.with_name(TRIANGULATED)
            read = lambda: trimesh.load(str(path))  # noqa: E731
        elif reader == "read_ply":
            from pipeline.scenes.ply import read_ply

            # Not warmed: on mixed faces the time and peak include importing numba and loading the compiled
            # walks from numba's cache (~0.4 s, once per process), as a fresh worker pays them.
            read = lambda: read_ply(path)  # noqa: E731
        elif reader == "shard":
            import pipeline.scenes.shard  # noqa: F401

            read = lambda: _shard(path, SHARDED[dataset])  # noqa: E731
        else:
            old = _old_reader(Path(folder))
            read = lambda: old(path)  # noqa: E731
        baseline = _status_mb("VmRSS")
        started = time.perf_counter()
        read()
        seconds = time.perf_counter() - started
    peak = _status_mb("VmHWM")
    return {"seconds": seconds, "peak_rss_mb": peak, "peak_above_imports_mb": peak - baseline}


# ------------------------------------------------------------------------------------------ the run


def _child(reader: str, path: Path, dataset: str) -> dict:
    command = [sys.executable, str(Path(__file__)), reader, str(path), dataset]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    if done.returncode != 0:
        tail = " ".join(done.stderr.split()[-30:])
        return {"failed": f"exit {done.returncode}: {tail}"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _summary(samples: list[dict]) -> dict:
    good = [s for s in samples if "failed" not in s]
    if not good:
        return {"failed": samples[0]["failed"]}
    row = {"runs": len(good)}
    for key in ("seconds", "peak_rss_mb", "peak_above_imports_mb"):
        values = [s[key] for s in good]
        row |= {f"{key}_median": round(statistics.median(values), 3), f"{key}_min": round(min(values), 3),
                f"{key}_max": round(max(values), 3)}
    return row


def run_real_size(runs: int, folder: Path | None) -> None:
    """Write the files (once), measure every reader RUNS times each in fresh processes, save the results."""
    sys.path.insert(0, str(ROOT))
    with tempfile.TemporaryDirectory() as temporary:
        folder = folder or Path(temporary)
        folder.mkdir(parents=True, exist_ok=True)
        files = write_files(folder)
        samples: dict[tuple[str, str], list[dict]] = {}
        for _ in range(runs):
            for dataset, path in files.items():
                for reader in READERS:
                    if (reader == "shard" and dataset not in SHARDED) or (reader == READERS[3] and dataset != "mixed_134mb"):
                        continue
                    samples.setdefault((dataset, reader), []).append(_child(reader, path, dataset))
                    print(dataset, reader, samples[dataset, reader][-1], flush=True)
        results = {"runs": runs, "load_average": round(os.getloadavg()[0], 1), "old_reader": OLD_REF,
                   "targets": {"time_vs_trimesh_load": 2.0, "peak_rss_vs_trimesh_load": 1.5,
                               "mixed_134mb_shard_peak_rss_mb": 1500, "replica_2m_quads_shard_peak_rss_mb": 2000},
                   "files": {}}
        for dataset, path in files.items():
            row = {"bytes": path.stat().st_size, "readers": {r: _summary(samples[dataset, r]) for r in READERS
                                                             if (dataset, r) in samples}}
            ours, peer = row["readers"]["read_ply"], row["readers"]["trimesh.load"]
            if "failed" in peer and READERS[3] in row["readers"]:
                row["peer"], peer = READERS[3], row["readers"][READERS[3]]
            if "failed" not in ours and "failed" not in peer:
                row["read_ply_time_vs_trimesh_load"] = round(ours["seconds_median"] / peer["seconds_median"], 2)
                row["read_ply_peak_rss_vs_trimesh_load"] = round(ours["peak_rss_mb_median"] / peer["peak_rss_mb_median"], 2)
            results["files"][dataset] = row
    RESULTS.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
    for dataset, row in results["files"].items():
        print(f"{dataset} ({row['bytes'] / 1e6:.0f} MB): time x{row.get('read_ply_time_vs_trimesh_load')} "
              f"RSS x{row.get('read_ply_peak_rss_vs_trimesh_load')} of trimesh.load")
        for reader, summary in row["readers"].items():
            print(f"    {reader:>18}: " + (summary.get("failed") or
                  f"{summary['seconds_median']:.2f} s ({summary['seconds_min']:.2f}-{summary['seconds_max']:.2f}), "
                  f"peak {summary['peak_rss_mb_median']:.0f} MB ({summary['peak_rss_mb_min']:.0f}-"
                  f"{summary['peak_rss_mb_max']:.0f}; {summary['peak_above_imports_mb_median']:.0f} above imports)"))


if __name__ == "__main__":
    print(json.dumps(measure(sys.argv[1], Path(sys.argv[2]), sys.argv[3])))
