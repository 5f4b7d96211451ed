"""Mesh readers side by side on one 1 M-triangle generated HM3DSem trio: what trimesh costs.

Since the trimesh reader replaced the hand-written GLB parser, every mesh is read through trimesh
(pipeline/scenes/trimesh_reader.py). This measures, in one process, alternating, RUNS times each
(a ratio holds on a loaded machine, a time does not):
    - trimesh.load_scene of the geometry GLB (the parse alone),
    - glb.read_glb (parse + merge into arrays: what HM3DSem reads, twice per scene),
    - read_hm3dsem of the whole trio (the figure benchmarks/results/scenes.json tracks, 0.61 s before),
    - the `meshes:` source on the same GLB (trimesh + names labels + colours + degenerate-face check),
    - with `--compare-ref REF` (e.g. main), the hand-written `read_glb` of that git ref as the peer.
Run:
    cd /work/main && .venv/bin/python benchmarks/bench_mesh_readers.py [--compare-ref main]

`--real-size` (issue 30) measures the PLY reader on files of the sizes the datasets publish instead, each
reader in a fresh subprocess per run so that its peak RSS is its own (benchmarks/ply_real_size.py says
what and how; results: benchmarks/results/mesh_readers_real_size.json):
    cd /work/main && .venv/bin/python benchmarks/bench_mesh_readers.py --real-size [--runs 3] [--folder DIR]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RUNS = 5


def module_at_ref(ref: str, source: str, folder: Path) -> ModuleType:
    """The module `source` (e.g. pipeline/scenes/glb.py) as it is at git `ref`, loaded stand-alone from `folder`."""
    text = subprocess.run(["git", "show", f"{ref}:{source}"], cwd=ROOT, check=True, capture_output=True, text=True).stdout
    name = "reference_" + Path(source).stem
    path = folder / f"{name}.py"
    path.write_text(text, encoding="utf-8")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def _reference_reader(ref: str, folder: Path) -> Callable[[Path], object]:
    """`read_glb` of pipeline/scenes/glb.py as it is at git `ref`."""
    return module_at_ref(ref, "pipeline/scenes/glb.py", folder).read_glb


def main() -> None:
    """Time each reader, print median and spread, save benchmarks/results/mesh_readers.json."""
    import trimesh

    from pipeline.scenes.glb import read_glb
    from pipeline.scenes.hm3dsem import read_hm3dsem, write_hm3dsem
    from pipeline.scenes.meshes import read_labelled_mesh
    from pipeline.scenes.procedural.house import generate_house

    parser = argparse.ArgumentParser()
    parser.add_argument("--compare-ref", default=None, help="git ref whose glb.read_glb is timed as the peer")
    parser.add_argument("--real-size", action="store_true", help="PLY files of the datasets' sizes (issue 30)")
    parser.add_argument("--runs", type=int, default=3, help="--real-size: fresh-process runs per reader and file")
    parser.add_argument("--folder", default=None, help="--real-size: where the big files are written (kept)")
    options = parser.parse_args()
    if options.real_size:
        from benchmarks.ply_real_size import run_real_size

        run_real_size(options.runs, Path(options.folder) if options.folder else None)
        return
    with tempfile.TemporaryDirectory() as folder:
        text = write_hm3dsem(generate_house(seed=2, detail=1.0), folder)
        glb = text.with_name(text.name.replace(".semantic.txt", ".glb"))
        readers: dict[str, Callable[[], object]] = {
            "trimesh.load_scene (parse only)": lambda: trimesh.load_scene(str(glb), process=False),
            "glb.read_glb (trimesh + merge)": lambda: read_glb(glb),
            "read_hm3dsem (whole trio)": lambda: read_hm3dsem(text),
            "meshes: source (labels: names)": lambda: read_labelled_mesh(glb, labels="names"),
        }
        if options.compare_ref:
            old = _reference_reader(options.compare_ref, Path(folder))
            readers[f"hand-written read_glb ({options.compare_ref})"] = lambda: old(glb)
        times: dict[str, list[float]] = {name: [] for name in readers}
        for read in readers.values():
            read()  # warm imports and caches
        for _ in range(RUNS):
            for name, read in readers.items():
                started = time.perf_counter()
                read()
                times[name].append(time.perf_counter() - started)
    peer = f"hand-written read_glb ({options.compare_ref})" if options.compare_ref else "glb.read_glb (trimesh + merge)"
    base = statistics.median(times[peer])
    results = {"runs": RUNS, "peer": peer, "readers": {
        name: {"median_s": round(statistics.median(t), 4), "min_s": round(min(t), 4), "max_s": round(max(t), 4),
               "ratio_to_peer": round(statistics.median(t) / base, 2)} for name, t in times.items()}}
    for name, row in results["readers"].items():
        print(f"{name:>40}: median {row['median_s']:.3f} s ({row['min_s']:.3f}-{row['max_s']:.3f}), "
              f"{row['ratio_to_peer']:.2f} x peer")
    out = Path(__file__).resolve().parent / "results" / "mesh_readers.json"
    out.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
