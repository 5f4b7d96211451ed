"""Frames agree with the geometry from frame to frame: reprojection, stable ids, segment statistics."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from pipeline.io.segments import frame_segments
from pipeline.render.camera import pixels_inside, project, unproject
from pipeline.render.renderer import VideoRenderer, _depth_and_labels
from pipeline.render.sensors import depth_to_millimetres
from tests.render.tiny_scenes import CHAIR, TABLE, embodiment, look_at, room_scene


def _poses(count: int) -> list[np.ndarray]:
    """A camera walking 5 cm per frame and turning 2 degrees per frame (MVPd's steps, exaggerated)."""
    poses = []
    for t in range(count):
        angle = np.radians(2.0 * t)
        position = np.array([0.3 - 0.05 * t, 1.0, -1.5])
        poses.append(look_at(position, position + np.array([np.sin(angle), -0.3, np.cos(angle)])))
    return poses


def _reprojection_agreement(renderer: VideoRenderer, pose_a: np.ndarray, pose_b: np.ndarray) -> tuple[float, int]:
    frame_a, frame_b = renderer.render(pose_a), renderer.render(pose_b)
    camera = renderer.camera
    v, u = np.nonzero(frame_a.depth)
    z = frame_a.depth[v, u] / 1000.0
    world = unproject(u, v, z, camera.intrinsics, pose_a)
    x, y, z_projected = project(world, camera.intrinsics, pose_b)
    column, row, inside = pixels_inside(x, y, z_projected, camera.width, camera.height)
    column, row, ids_a, z_b = column[inside], row[inside], frame_a.panoptic[v, u][inside], z_projected[inside]
    # Visible in both: frame b's depth at the projected pixel matches the point's depth (not occluded).
    depth_b = frame_b.depth[row, column] / 1000.0
    visible = np.abs(depth_b - z_b) < 0.02 + 0.02 * z_b
    same = frame_b.panoptic[row, column][visible] == ids_a[visible]
    return float(same.mean()), int(visible.sum())


def test_reprojection_into_the_next_frame_keeps_the_panoptic_id() -> None:
    renderer = VideoRenderer(room_scene(), embodiment(width=160, height=120), exposure=1.0)
    poses = _poses(4)
    for pose_a, pose_b in zip(poses, poses[1:]):
        agreement, visible = _reprojection_agreement(renderer, pose_a, pose_b)
        assert visible > 0.8 * 160 * 120  # most pixels are seen in both frames
        assert agreement >= 0.99


def test_object_ids_are_stable_across_frames() -> None:
    renderer = VideoRenderer(room_scene(), embodiment(), exposure=1.0)
    scene_ids = set(renderer.scene.objects)
    seen = [set(np.unique(renderer.render(pose).panoptic).tolist()) - {0} for pose in _poses(5)]
    # Ids are the scene's object ids (not per-frame instance indices), and the table stays in view.
    assert all(ids <= scene_ids for ids in seen)
    assert all(TABLE in ids for ids in seen)
    # A small motion loses or gains few objects; the ids of the ones kept are unchanged.
    assert all(len(a & b) >= len(a) - 1 for a, b in zip(seen, seen[1:]))


def test_labels_never_blend_across_objects() -> None:
    renderer = VideoRenderer(room_scene(), embodiment(width=160, height=120), exposure=1.0)
    panoptic = renderer.render(_poses(1)[0]).panoptic
    assert set(np.unique(panoptic).tolist()) <= set(renderer.scene.objects) | {0}


def test_frame_segments_match_a_brute_force_count() -> None:
    renderer = VideoRenderer(room_scene(), embodiment(), exposure=1.0)
    panoptic = renderer.render(_poses(1)[0]).panoptic
    found = frame_segments(panoptic, renderer.labels)
    expected_ids = [i for i in np.unique(panoptic) if i != 0]
    assert found.object_ids.tolist() == expected_ids
    assert CHAIR in expected_ids
    for k, object_id in enumerate(found.object_ids):
        rows, columns = np.nonzero(panoptic == object_id)
        assert found.areas[k] == len(rows)
        assert found.boxes[k].tolist() == [columns.min(), rows.min(), columns.max() + 1, rows.max() + 1]
        assert found.categories[k] == renderer.scene.objects[int(object_id)].category
    assert found.void_pixels == int((panoptic == 0).sum())


def test_frame_segments_from_dense_labels_equal_those_from_ids() -> None:
    renderer = VideoRenderer(room_scene(), embodiment(), exposure=1.0)
    frame = renderer.render(_poses(2)[1])
    from_ids, from_dense = frame_segments(frame.panoptic, renderer.labels), frame_segments(
        frame.panoptic, renderer.labels, frame.dense)
    assert from_ids.object_ids.tolist() == from_dense.object_ids.tolist()
    assert np.array_equal(from_ids.boxes, from_dense.boxes) and np.array_equal(from_ids.areas, from_dense.areas)


def test_row_bands_render_exactly_like_the_whole_frame() -> None:
    # Frames are shaded in row bands (MIN_BANDS, or one per cast thread, in parallel): the split must not
    # change a single value against shading the whole frame at once.
    from pipeline.config import Illumination
    from pipeline.render.raycaster import SceneRaycaster
    from pipeline.render.sensors import depth_to_millimetres

    scene, pose = room_scene(), _poses(2)[1]
    for light in (Illumination(), Illumination(kind="spot", power=20.0)):
        body = embodiment(width=96, height=71, light=light)  # 71 rows: bands of unequal height
        for threads in (1, 7):
            renderer = VideoRenderer(scene, body, exposure=2.0, raycaster=SceneRaycaster(scene, threads=threads))
            hits = renderer.trace(pose)
            frame = renderer.buffers(hits)
            assert np.array_equal(frame.rgb, renderer.shader.shade(renderer.colors.planes(hits), hits))
            assert np.array_equal(frame.depth, depth_to_millimetres(hits.depth, body.sensor.near, body.sensor.far))
            assert np.array_equal(frame.panoptic, renderer.labels.object_ids[hits.face])
            assert np.array_equal(frame.dense, renderer.labels.dense_of_face[hits.face])
            assert frame.rgb.any() and frame.panoptic.any()


def test_several_threads_render_the_bytes_of_one_with_indirect_light() -> None:
    # With several threads the camera rays are rasterised in bands and the spot's virtual lights are traced
    # on a thread of their own meanwhile; neither may change a byte against one thread doing it all in turn.
    from pipeline.config import Illumination, IndirectLight
    from pipeline.render.raycaster import SceneRaycaster

    light = Illumination(kind="spot", power=20.0, material="principled", indirect=IndirectLight(
        bounces=2, virtual_lights=256, gather_stride=4, interleave=2, clamp_distance=0.1))
    scene, body = room_scene(), embodiment(width=96, height=71, light=light)
    frames = []
    for threads in (1, 3):
        renderer = VideoRenderer(scene, body, exposure=2.0, raycaster=SceneRaycaster(scene, threads=threads), seed=3)
        frames.append([renderer.render(pose).rgb.copy() for pose in _poses(3)])
    assert all(a.tobytes() == b.tobytes() for a, b in zip(*frames)) and frames[0][1].any()


def test_depth_and_labels_in_one_pass_equal_the_numpy_passes() -> None:
    """The band's fused pass gives the bytes of depth_to_millimetres and the two clipped look-ups, at the
    edges that differ between float32 and float64 arithmetic: depths at near and far, a near that float32
    rounds down, half millimetres, the uint16 limit, inf, NaN, negatives; faces of misses (F) and beyond."""
    rng = np.random.default_rng(5)
    near, far = 0.3000000119, 65.5355  # float32(near) < near: NumPy compares float32 depths with float32(near)
    special = np.array([np.float32(0.3), np.float32(near), 0.0005, 0.0015, 65.5345, 65.5355, 65.536, np.inf, np.nan,
                        -1.0, np.nextafter(np.float32(far), np.float32(0)), 1.2345], np.float32)
    depth = np.concatenate([special, rng.uniform(0, 70, 500).astype(np.float32)]).reshape(8, -1)
    faces = rng.integers(0, 12, depth.shape).astype(np.intp)  # 10 faces: 10 is the miss, 11 beyond the table
    object_ids = np.append(rng.integers(1, 2**32, 10, dtype=np.uint32), np.uint32(0))
    dense_of_face = np.append(rng.integers(1, 9, 10).astype(np.int32), np.int32(0))
    millimetres, panoptic, dense = np.empty(depth.shape, np.uint16), np.empty(depth.shape, np.uint32), np.empty(depth.shape, np.int32)
    _depth_and_labels(depth, faces, np.float32(near), np.float32(far), object_ids, dense_of_face, millimetres, panoptic, dense)
    assert np.array_equal(millimetres, depth_to_millimetres(depth, near, far))
    assert np.array_equal(panoptic, np.take(object_ids, faces, mode="clip"))
    assert np.array_equal(dense, np.take(dense_of_face, faces, mode="clip"))
    assert millimetres[0, 0] == 300 and millimetres[0, 4] == 65534  # float32(near) kept; 65534.5 mm rounds to even



def test_a_clipped_hit_is_found_as_numpy_comparisons_find_it() -> None:
    """`trace` builds the clip masks only when `_any_clipped` says a hit lies outside [near, far]: it must say so
    exactly when NumPy's float32 comparisons of the depths with near and far exclude a finite depth."""
    from pipeline.render.renderer import _any_clipped

    near, far = 0.3000000119, 65.5355  # float32(near) < near: a depth of float32(0.3) is inside
    for value in [np.float32(0.3), np.nextafter(np.float32(0.3), np.float32(0)), 0.0, -1.0, 65.5355,
                  np.nextafter(np.float32(far), np.float32(np.inf)), 1e30, np.inf, -np.inf, np.nan, 2.0]:
        depth = np.full((3, 17), 2.0, np.float32)
        depth[1, 16] = value
        depth[0, :4] = np.inf  # misses
        inside = (depth >= near) & (depth <= far)
        expected = bool(np.count_nonzero(inside) != np.count_nonzero(np.isfinite(depth)))
        assert _any_clipped(depth, np.float32(near), np.float32(far)) == expected, value
    assert _any_clipped(np.float32([[0.1, 2.0]]), np.float32(near), np.float32(far))

# sha256 of rgb, depth and panoptic bytes of one 96 x 71 frame of the room (pose and seed of the test below),
# generated with ff1406f: the indirect light's changes must not move a byte of the frames that have none.
FRAMES_WITHOUT_INDIRECT_LIGHT = {
    "ambient": "fe0122332513158f1bbfe295dccefc888a7e54359ce0552ee3fabb8d025f1978",
    "spot diffuse": "9d3aa685d8d05911f47b3b156c1677e471170dce2e7d70a4459460c2f5bd1ed4",
    "spot principled": "31a8202b927a1ec204b9405f9b4a1749c79cdf0d15c1567d7578da7c7b102233",
}


@pytest.mark.parametrize("name", sorted(FRAMES_WITHOUT_INDIRECT_LIGHT))
@pytest.mark.parametrize("threads", [1, 2])
def test_frames_without_indirect_light_keep_their_bytes(name: str, threads: int) -> None:
    from pipeline.config import Illumination
    from pipeline.render.raycaster import SceneRaycaster

    light = {"ambient": Illumination(), "spot diffuse": Illumination(kind="spot", power=20.0),
             "spot principled": Illumination(kind="spot", power=20.0, material="principled", specular=1.0,
                                             roughness=0.5)}[name]
    scene = room_scene()
    renderer = VideoRenderer(scene, embodiment(width=96, height=71, light=light), exposure=2.0,
                             raycaster=SceneRaycaster(scene, threads=threads), seed=3)
    frame = renderer.render(look_at(np.array([0.5, 1.0, -1.5]), np.array([0.0, 0.4, 1.5])))
    buffers = b"".join(np.ascontiguousarray(b).tobytes() for b in (frame.rgb, frame.depth, frame.panoptic))
    assert hashlib.sha256(buffers).hexdigest() == FRAMES_WITHOUT_INDIRECT_LIGHT[name]


def test_only_frames_that_read_no_surfaces_skip_them_on_a_shared_caster() -> None:
    """Ambient light with an ideal sensor renders without the hits' normals and directions (the resolve skips
    them); a spot or a depth-noise model needs them, and a frame rendered after a skipping one on the same
    caster (the stage shares one per scene) is the frame rendered alone."""
    from pipeline.config import Illumination
    from pipeline.render.raycaster import SceneRaycaster

    scene, spot = room_scene(), Illumination(kind="spot", power=20.0)
    first, second = _poses(2)
    caster = SceneRaycaster(scene)
    ambient = VideoRenderer(scene, embodiment(), exposure=2.0, raycaster=caster)
    noisy = VideoRenderer(scene, embodiment(model="structured_light"), exposure=2.0, raycaster=caster)
    lit = VideoRenderer(scene, embodiment(light=spot), exposure=2.0, raycaster=caster)
    assert (ambient.needs_surfaces, noisy.needs_surfaces, lit.needs_surfaces) == (False, True, True)
    alone = {name: VideoRenderer(scene, embodiment(model=model, light=light), exposure=2.0).render(
                 second, np.random.default_rng(0))
             for name, model, light in (("noisy", "structured_light", None), ("lit", "ideal", spot))}
    for name, renderer in (("noisy", noisy), ("lit", lit)):
        ambient.render(first)  # leaves the first pose's normals and directions in the caster's buffers
        frame = renderer.render(second, np.random.default_rng(0))
        for buffer in ("rgb", "depth", "panoptic"):
            assert np.array_equal(getattr(frame, buffer), getattr(alone[name], buffer)), (name, buffer)
