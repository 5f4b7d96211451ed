"""The light benchmark's own logic (benchmarks/bench_light.py): it compares at the reference's stored poses, refuses
a cached render made for another scene, poses, light or encoding in one line, and turns a peer's settings into
"their CPU to reach our PSNR / ours". No peer renderer runs here."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location("bench_light", BENCHMARKS / "bench_light.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    yield module
    sys.path.remove(str(BENCHMARKS))


def test_poses_are_the_references_stored_ones(bench):
    stored = json.loads((BENCHMARKS / "results" / "light" / "reference.json").read_text())["poses"]
    poses = bench.stored_poses()
    assert poses.shape == (len(stored), 4, 4)
    assert np.array_equal(poses, np.asarray(stored))


def expected(bench, poses=None):
    poses = np.tile(np.eye(4), (3, 1, 1)) if poses is None else poses
    return bench.made_for("ab" * 32, poses, bench.ENCODING_CYCLES)


@pytest.mark.parametrize("field, change", [
    ("scene_sha256", lambda v: "cd" * 32),
    ("poses_sha256", lambda v: "0" * 64),
    ("resolution", lambda v: [320, 240]),
    ("light", lambda v: {**v, "power_w": 200.0}),
    ("shading", lambda v: "smooth"),
    ("encoding", lambda v: v.replace("exposure 4.0", "exposure 2.0")),
])
def test_a_cache_made_for_something_else_is_refused_naming_the_field_and_the_flag(bench, field, change):
    wanted = expected(bench)
    recorded = {**wanted, field: change(wanted[field])}
    with pytest.raises(bench.CacheMismatch) as caught:
        bench.check_made_for(Path("reference.json"), recorded, wanted, "--reference")
    message = str(caught.value)
    assert "\n" not in message
    assert f"another {field}" in message and message.endswith("render it anew with --reference")
    assert message.startswith("reference.json: ")


def test_a_cache_without_a_record_is_refused(bench):
    with pytest.raises(bench.CacheMismatch, match="no 'made_for' record.*--cycles16$"):
        bench.check_made_for(Path("cycles16.json"), None, expected(bench), "--cycles16")


def test_a_matching_cache_passes(bench):
    wanted = expected(bench)
    bench.check_made_for(Path("reference.json"), json.loads(json.dumps(wanted)), wanted, "--reference")


def test_moved_poses_change_the_record(bench):
    poses = np.tile(np.eye(4), (3, 1, 1))
    moved = poses.copy()
    moved[1, 0, 3] += 1e-9
    assert expected(bench, poses)["poses_sha256"] != expected(bench, moved)["poses_sha256"]
    # JSON keeps float64 exactly: the poses stored in a cache's JSON hash as they were rendered
    assert expected(bench, np.asarray(json.loads(json.dumps(moved.tolist()))))["poses_sha256"] == \
        expected(bench, moved)["poses_sha256"]


def test_the_bench_refuses_a_stale_cache_in_one_line(bench, tmp_path, monkeypatch, capsys):
    """measure() stops before rendering when reference.json was made for another scene (here: a changed hash)."""
    for name in ("reference", "reference_seed2", "cycles16"):
        meta = json.loads((BENCHMARKS / "results" / "light" / f"{name}.json").read_text())
        if name == "reference":
            meta["made_for"] = {**meta.get("made_for", {}), "scene_sha256": "0" * 64}
        (tmp_path / f"{name}.json").write_text(json.dumps(meta))
    monkeypatch.setattr(bench, "RESULTS", tmp_path)
    monkeypatch.setattr(bench, "scene_hash", lambda scene: "f" * 64)
    monkeypatch.setattr(sys, "argv", ["bench_light.py"])
    monkeypatch.setattr(bench, "bench_house", lambda folder: None)  # the scene is only hashed before the check
    monkeypatch.setattr(bench, "export", lambda *a: pytest.fail("went on to render with a stale cache"))
    with pytest.raises(SystemExit) as stopped:
        bench.main()
    assert str(stopped.value).startswith(f"bench_light: {tmp_path / 'reference.json'}: made for another scene_sha256")
    assert "render it anew with --reference" in str(stopped.value) and "\n" not in str(stopped.value)


def test_cpu_to_reach_interpolates_in_log_cpu(bench):
    # 1 s at 30 dB, 4 s at 36 dB: 33 dB halfway in log(CPU) -> 2 s, over ours' 0.1 s
    reached = bench.cpu_to_reach([(4.0, 36.0), (1.0, 30.0)], 33.0, 0.1)
    assert reached["reached"] and reached["ratio"] == pytest.approx(20.0)


def test_cpu_to_reach_bounds_outside_the_sweep(bench):
    better = bench.cpu_to_reach([(5.0, 42.7), (60.0, 48.2)], 35.0, 0.15)
    assert better["reached"] and better["ratio_at_most"] == pytest.approx(33.33, abs=0.01)
    worse = bench.cpu_to_reach([(1.0, 19.0), (64.0, 31.0)], 35.0, 0.15)
    assert not worse["reached"] and worse["ratio_more_than"] == pytest.approx(426.67, abs=0.01)
    assert "31.00 dB" in worse["note"]


def test_cpu_to_reach_takes_the_first_crossing(bench):
    # PSNR need not grow monotonically with CPU (a noisy sweep): the cheapest setting that gets there counts
    points = [(1.0, 30.0), (2.0, 36.0), (4.0, 34.0), (8.0, 40.0)]
    assert bench.cpu_to_reach(points, 35.0, 1.0)["ratio"] < 2.0


def test_the_cached_renders_were_made_for_the_bench_house(bench, tmp_path):
    """The committed reference, its second seed and Cycles 16 spp record the house and poses they show; today's
    bench house (shard stage inline) hashes the same."""
    scene = bench.bench_house(tmp_path)
    args = type("Flags", (), {"reference": False, "reference_floor": False, "cycles16": False})()
    bench.check_caches(args, bench.scene_hash(scene), bench.stored_poses())


def test_a_bad_sweep_list_is_a_one_line_usage_error(bench, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["bench_light.py", "--mitsuba-spp", "1,4,x"])
    with pytest.raises(SystemExit) as stopped:
        bench.main()
    assert stopped.value.code == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--mitsuba-spp: '1,4,x' is not a comma-separated list of whole numbers" in error


def test_comparisons_are_plain_json(bench):
    """A whole run once died writing light.json: a numpy bool in the checks. Comparisons hold Python numbers."""
    a = np.zeros((4, 4, 3), np.uint8)
    b = a.copy()
    b[0, 0, 0] = 9
    result = bench.compare([a, b], [b, b])
    assert type(result["psnr_min"]) is float and type(result["psnr_median"]) is float
    assert type(bool(result["psnr_min"] >= bench.REPRODUCED_PSNR)) is bool
    assert json.loads(json.dumps(result))["psnr_max"] == 99.0
