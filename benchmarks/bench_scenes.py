"""Scene speed: generate a 500 k-triangle house, read a 1 M-triangle HM3DSem scene; peak memory of each.

Targets (issue #3): generation <= 10 s, reading <= 10 s, peak memory <= 2 GiB. Each measurement runs
in a fresh process so its peak resident memory is its own. Run:
    cd /work/main && .venv/bin/python benchmarks/bench_scenes.py
"""

from __future__ import annotations

import json
import multiprocessing
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

GIB = 1024**3
TARGETS = {"generate_500k_s": 10.0, "read_1m_s": 10.0, "peak_memory_gib": 2.0}


def _peak_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / GIB  # ru_maxrss is KiB on Linux


def _generate(detail: float, floors: int, queue: multiprocessing.Queue) -> None:
    from pipeline.scenes.procedural.house import generate_house

    generate_house(1, 0.05)  # warm the imports and table caches; not what is measured
    started = time.perf_counter()
    scene = generate_house(seed=0, detail=detail, floors=floors)  # seed 0: 8 rooms
    queue.put({"seconds": time.perf_counter() - started, "triangles": scene.triangle_count,
               "objects": len(scene.objects), "peak_gib": _peak_gib()})


def _write(folder: str, queue: multiprocessing.Queue) -> None:
    from pipeline.scenes.hm3dsem import write_hm3dsem
    from pipeline.scenes.procedural.house import generate_house

    queue.put(str(write_hm3dsem(generate_house(seed=2, detail=1.0), folder)))


def _read(path: str, queue: multiprocessing.Queue) -> None:
    import trimesh  # noqa: F401 - a worker imports it once (about 0.5 s), not once per scene: not what is measured

    from pipeline.scenes.sources import load_scene_file

    started = time.perf_counter()
    scene = load_scene_file(path)
    queue.put({"seconds": time.perf_counter() - started, "triangles": scene.triangle_count,
               "objects": len(scene.objects), "peak_gib": _peak_gib()})


def _in_child(target, *args):  # type: ignore[no-untyped-def]
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=target, args=(*args, queue))
    process.start()
    result = queue.get()
    process.join()
    return result


def main() -> None:
    """Measure, print against the targets, and save benchmarks/results/scenes.json."""
    results: dict[str, object] = {}
    generation = {str(d): _in_child(_generate, d, 1) for d in (0.1, 0.5, 1.0)}
    generation["0.5, 2 storeys"] = _in_child(_generate, 0.5, 2)
    results["generate"] = generation
    with tempfile.TemporaryDirectory() as folder:
        text = _in_child(_write, folder)
        results["read_1m"] = _in_child(_read, text)
        results["file_mb"] = round(sum(p.stat().st_size for p in Path(text).parent.iterdir()) / 1e6, 1)
    measured = {
        "generate_500k_s": generation["0.5"]["seconds"],
        "read_1m_s": results["read_1m"]["seconds"],  # type: ignore[index]
        "peak_memory_gib": max([g["peak_gib"] for g in generation.values()] + [results["read_1m"]["peak_gib"]]),  # type: ignore[index]
    }
    results["summary"] = {k: {"measured": round(v, 3), "target": TARGETS[k], "ok": v <= TARGETS[k]} for k, v in measured.items()}
    for detail, row in generation.items():
        print(f"generate detail {detail:>14}: {row['seconds']:6.2f} s  {row['triangles']:>9,} triangles  "
              f"{row['objects']} objects  peak {row['peak_gib']:.2f} GiB")
    read = results["read_1m"]
    print(f"read HM3DSem 1 M-triangle trio: {read['seconds']:6.2f} s  {read['triangles']:>9,} triangles  peak {read['peak_gib']:.2f} GiB"  # type: ignore[index]
          f"  ({results['file_mb']} MB of files)")
    for key, row in results["summary"].items():  # type: ignore[union-attr]
        print(f"{key:>16}: {row['measured']:8.3f}  target <= {row['target']}  {'ok' if row['ok'] else 'MISSED'}")
    out = Path(__file__).resolve().parent / "results" / "scenes.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
