"""Frames resolved straight into their buffers (fused.FramePass) against the general path: the same bytes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.config import Illumination, IndirectLight, Sensor
from pipeline.io.segments import frame_segments
from pipeline.render.fused import FramePass
from pipeline.render.lighting import Shader, SurfaceColors
from pipeline.render.raycaster import RayHits, SceneRaycaster
from pipeline.render.renderer import SceneLabels, VideoRenderer, new_frame
from pipeline.render.sensors import depth_to_millimetres
from tests.render.test_resolve import CAMERA, resolved
from tests.render.tiny_scenes import embodiment, look_at, room_scene

# Inside the room, and far outside it looking at it (the room and the void around it: hits and misses).
POSES = [look_at(np.array([0.5, 1.0, -1.5]), np.array([0.0, 0.4, 1.5])),
         look_at(np.array([0.3, 3.0, -12.0]), np.array([0.5, 0.7, 1.0]))]
SPOT = Illumination(kind="spot", power=20.0)


def _shaded_room():
    """The room with colours that vary over every other quad (interpolated) and are one colour on the others
    (whose albedo needs no barycentrics): both kinds of face in one frame."""
    scene = room_scene()
    colors = np.random.default_rng(7).integers(0, 256, scene.vertex_colors.shape).astype(np.uint8)
    uniform = (np.arange(len(colors)) // 4) % 2 == 1  # 4 vertices per quad
    colors[uniform] = scene.vertex_colors[uniform]
    return dataclasses.replace(scene, vertex_colors=colors)


def _body(near: float = 0.01, far: float = 1000.0, **kwargs):
    body = embodiment(width=96, height=71, **kwargs)
    return body.model_copy(update={"sensor": Sensor(width=96, height=71, near=near, far=far)})


def _general(renderer: VideoRenderer, pose: np.ndarray):
    """The frame and segment statistics of the general path: hits, then the buffers' passes, then the counts."""
    frame = renderer.buffers(renderer.trace(pose))
    return frame, frame_segments(frame.panoptic, renderer.labels, frame.dense)


def _same_segments(found, expected) -> bool:
    return (np.array_equal(found.object_ids, expected.object_ids) and np.array_equal(found.areas, expected.areas)
            and np.array_equal(found.boxes, expected.boxes) and np.array_equal(found.categories, expected.categories)
            and found.void_pixels == expected.void_pixels)


@pytest.mark.parametrize("light", ["ambient", "spot"])
@pytest.mark.parametrize("threads", [1, 3])
@pytest.mark.parametrize("scene_kind", ["interpolated", "flat"])
@pytest.mark.parametrize("clip", [(0.01, 1000.0), (1.2, 3.0)])
def test_a_fused_frame_is_the_general_path_s_frame(light: str, threads: int, scene_kind: str,
                                                    clip: tuple[float, float]) -> None:
    """RGB, depth (mm), panoptic ids and segment rows equal the general path's, under ambient light and under a
    spot alone (lit by each hit's normal, ray and depth), on faces of one colour and of interpolated colours,
    with hits the clip range removes (near 1.2 m, far 3 m) and rays that hit nothing, in one band and in three."""
    scene = _shaded_room() if scene_kind == "interpolated" else room_scene()
    caster = SceneRaycaster(scene, threads=threads)
    spot = light == "spot"
    renderer = VideoRenderer(scene, _body(*clip, light=SPOT if spot else None), exposure=4.0, raycaster=caster)
    assert renderer.fused and renderer.colors.flat == (scene_kind == "flat")
    misses = []
    for pose in POSES:
        fused = renderer.render(pose)
        general, segments = _general(renderer, pose)
        for name in ("rgb", "depth", "panoptic"):
            assert np.array_equal(getattr(fused, name), getattr(general, name)), name
        assert fused.dense is None and _same_segments(fused.segment_statistics(renderer.labels), segments)
        assert (general.rgb[general.depth == 0] == 0).all() and (general.panoptic[general.depth == 0] == 0).all()
        misses.append(float((general.depth == 0).mean()))
        # The spot's frame is lit: not the albedo the ambient frame shows (where anything is hit).
        albedo = renderer.colors.albedo(renderer.trace(pose))
        assert np.any(general.rgb != albedo) == (spot and general.depth.any())
    assert 0.0 < misses[1] < 1.0 or clip[0] > 0.01  # the void around the room
    # Inside the room every ray hits; the clip range removes the far wall and the floor under the camera.
    assert (misses[0] > 0.05) == (clip[0] > 0.01)


def test_depth_and_ids_alone_are_the_general_path_s() -> None:
    """Without colour the pass writes depth, ids and segment rows (and never the rgb buffer)."""
    scene = _shaded_room()
    renderer = VideoRenderer(scene, _body(1.2, 3.0), exposure=1.0, raycaster=SceneRaycaster(scene, threads=2))
    for pose in POSES:
        bare = renderer.resolve_frame(pose, colour=False)
        general, segments = _general(renderer, pose)
        assert np.array_equal(bare.depth, general.depth) and np.array_equal(bare.panoptic, general.panoptic)
        assert _same_segments(bare.segments, segments)


def test_a_cast_into_a_frame_pass_fills_its_frame_and_leaves_the_hits_alone() -> None:
    """`SceneRaycaster.cast(into=...)` hands each band's winners to the FramePass (the bytes the hits it would have
    written give) and leaves the caster's hit buffers as the previous cast left them."""
    scene, pose = _shaded_room(), POSES[1]
    labels, colors = SceneLabels(scene), SurfaceColors(scene)
    caster = SceneRaycaster(scene, threads=2)
    before = [np.copy(buffer) for buffer in dataclasses.astuple(caster.cast(CAMERA, POSES[0]))]
    frame = new_frame(CAMERA.height, CAMERA.width, dense=False)
    stale = caster.cast(CAMERA, pose, into=FramePass(frame, labels, colors, 0.01, 1000.0))
    assert all(np.array_equal(kept, now) for kept, now in zip(before, dataclasses.astuple(stale)))
    depth, face, barycentric, normal, direction = resolved(True, pose, scene)
    hits = RayHits(depth, face, barycentric, normal, direction, np.isfinite(depth))
    assert np.array_equal(frame.depth, depth_to_millimetres(depth, 0.01, 1000.0))
    assert np.array_equal(frame.panoptic, labels.object_ids[face]) and np.array_equal(frame.rgb, colors.albedo(hits))
    assert (frame.depth == 0).any() and frame.depth.any()
    with pytest.raises(ValueError, match="z-buffer"):
        SceneRaycaster(scene, rasterize=False).cast(CAMERA, pose, into=FramePass(frame, labels, colors, 0.01, 1.0))


def test_only_ambient_or_direct_diffuse_spot_frames_with_an_ideal_sensor_on_vertex_colours_and_a_z_buffer_are_fused(
        ) -> None:
    scene = room_scene()
    assert VideoRenderer(scene, embodiment(), 1.0).fused
    assert VideoRenderer(scene, embodiment(light=SPOT), 1.0).fused
    principled = SPOT.model_copy(update={"material": "principled"})
    bounced = SPOT.model_copy(update={"indirect": IndirectLight(bounces=1, virtual_lights=16)})
    assert not VideoRenderer(scene, embodiment(light=principled), 1.0).fused
    assert not VideoRenderer(scene, embodiment(light=bounced), 1.0).fused
    assert not VideoRenderer(scene, embodiment(model="structured_light"), 1.0).fused
    assert not VideoRenderer(scene, embodiment(model="structured_light", light=SPOT), 1.0).fused
    assert not VideoRenderer(scene, embodiment(), 1.0, raycaster=SceneRaycaster(scene, rasterize=False)).fused
    textured = dataclasses.replace(scene, vertex_colors=None)
    assert not VideoRenderer(textured, embodiment(), 1.0).fused
    with pytest.raises(ValueError, match="vertex-coloured"):
        FramePass(new_frame(2, 2), VideoRenderer(textured, embodiment(), 1.0).labels,
                  VideoRenderer(textured, embodiment(), 1.0).colors, 0.01, 1.0)


def test_a_frame_pass_lights_by_a_diffuse_spot_alone_or_fails_in_one_line() -> None:
    """Its spot is a diffuse surface's (a principled one, or ambient light, fails naming the shader to use), and it
    needs the colours it lights."""
    scene = room_scene()
    labels, colors, frame = SceneLabels(scene), SurfaceColors(scene), new_frame(2, 2, dense=False)
    lengths = np.ones((2, 2), np.float32)
    for light in (SPOT.model_copy(update={"material": "principled"}), Illumination()):
        with pytest.raises(ValueError, match="shade_surfaces") as error:
            FramePass(frame, labels, colors, 0.01, 1.0, Shader(light, 1.0, lengths))
        assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match="SurfaceColors"):
        FramePass(frame, labels, None, 0.01, 1.0, Shader(SPOT, 1.0, lengths))
    assert FramePass(frame, labels, colors, 0.01, 1.0, Shader(SPOT, 1.0, lengths)).spot_terms is not None


@pytest.mark.parametrize("light", [None, SPOT])
def test_hits_beyond_the_millimetres_range_keep_their_ids_and_colour(light: Illumination | None) -> None:
    """A hit farther than 65.535 m stores depth 0 (uint16 mm) but is a hit: its id, segment rows and colour are the
    general path's (the pass's depth and its hit test are separate loops)."""
    scene = _shaded_room()
    renderer = VideoRenderer(scene, _body(light=light), exposure=4.0e4, raycaster=SceneRaycaster(scene, threads=2))
    pose = look_at(np.array([0.0, 20.0, -75.0]), np.array([0.0, 1.2, 0.0]))  # the room ~77 m away
    fused = renderer.render(pose)
    general, segments = _general(renderer, pose)
    for name in ("rgb", "depth", "panoptic"):
        assert np.array_equal(getattr(fused, name), getattr(general, name)), name
    assert _same_segments(fused.segments, segments)
    assert not fused.depth.any() and fused.panoptic.any() and fused.rgb[fused.panoptic > 0].any()


def test_per_face_tables_are_read_by_reordered_triangle_taken_once_per_mesh_and_table() -> None:
    from pipeline.render.fused import by_triangle
    from pipeline.render.raster import ClusteredMesh

    scene = _shaded_room()
    mesh = ClusteredMesh(scene.vertices, scene.faces)
    assert not np.array_equal(mesh.face_ids, np.arange(len(scene.faces)))  # (the Morton order moves faces)
    labels, records = SceneLabels(scene).dense_of_face, SurfaceColors(scene).records
    for table in (labels, records):
        reordered = by_triangle(mesh, table)
        np.testing.assert_array_equal(reordered, table[mesh.face_ids])
        assert reordered.flags.c_contiguous and by_triangle(mesh, table) is reordered  # built once, then reused
    other = ClusteredMesh(scene.vertices[::-1].copy(), (len(scene.vertices) - 1 - scene.faces)[:, ::-1].copy())
    np.testing.assert_array_equal(by_triangle(other, labels), labels[other.face_ids])  # another mesh: its own order


def test_reordered_tables_kept_per_mesh_are_bounded() -> None:
    from pipeline.render.fused import _BY_TRIANGLE, _TABLES_PER_MESH, by_triangle
    from pipeline.render.raster import ClusteredMesh

    scene = _shaded_room()
    mesh = ClusteredMesh(scene.vertices, scene.faces)
    for _ in range(3 * _TABLES_PER_MESH):  # renderers that each bring labels of their own
        by_triangle(mesh, SceneLabels(scene).dense_of_face)
    assert len(_BY_TRIANGLE[mesh]) == _TABLES_PER_MESH


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_depth_and_ids_through_the_table_of_winners_equal_the_per_run_resolve(seed: int) -> None:
    """`_resolve_depth_and_ids` (each winner's plane, id and label kept in a table of TRIANGLE_SLOTS entries) writes
    the millimetres, ids and segment counts of `_resolve_rows` (each taken anew per run of a winner), bit for bit, on
    random triangles and winners: runs of every length, misses, winners that share a slot (t and t + TRIANGLE_SLOTS,
    in turns) and a clip range that cuts through the depths."""
    from pipeline.io.segments import empty_boxes
    from pipeline.render.fused import (_NO_DECODE, _NO_ENCODE, _NO_RECORDS, _NO_RGB, _NO_SCALE, TRIANGLE_SLOTS,
                                       _resolve_depth_and_ids, _resolve_rows)

    rng = np.random.default_rng(seed)
    height, width, triangles = 37, 53, 3 * TRIANGLE_SLOTS
    corners = rng.uniform(-1.0, 1.0, (triangles, 3, 3)).astype(np.float32)
    corners[..., 2] = rng.uniform(3.7, 4.3, (triangles, 3))  # (planes of depths ~3.7 to 4.3 m at the pixels)
    pool = np.concatenate([[-1], rng.integers(0, triangles - TRIANGLE_SLOTS, 50)])
    pool = np.concatenate([pool, pool[pool >= 0][:10] + TRIANGLE_SLOTS])  # (sharing slots with others in the pool)
    lengths = rng.geometric(0.2, height * width)  # runs of ~5 pixels, some of dozens
    winner = np.repeat(rng.choice(pool, len(lengths)), lengths)[:height * width].reshape(height, width)
    winner = winner.astype(np.int32)
    dense_ids = np.unique(np.append(rng.integers(1, 1000, 12), 0)).astype(np.uint32)
    label_of_triangle = rng.integers(0, len(dense_ids), triangles).astype(np.int32)
    pose = np.eye(4)
    pose[:3, 3] = rng.uniform(-0.2, 0.2, 3)
    pixel_x, pixel_y = np.linspace(-0.6, 0.6, width), np.linspace(-0.5, 0.5, height)
    near, far = np.float32(3.8), np.float32(4.4)  # (both ends clip)
    found, expected = [], []
    for resolve in ("table", "per run"):
        millimetres, panoptic = np.full((height, width), 7, np.uint16), np.full((height, width), 7, np.uint32)
        counts = []
        for rows in (slice(0, 20), slice(20, height)):
            areas, boxes = empty_boxes(len(dense_ids), height, width)
            arguments = (corners, winner, pose, pixel_x, pixel_y, rows.start, rows.stop, near, far, dense_ids,
                         label_of_triangle, millimetres, panoptic, areas, boxes)
            if resolve == "table":
                _resolve_depth_and_ids(*arguments)
            else:
                _resolve_rows(*arguments, False, _NO_RECORDS, False, _NO_RGB, False, _NO_SCALE, _NO_DECODE, _NO_ENCODE)
            counts.append((areas, boxes))
        (found if resolve == "table" else expected).append((millimetres, panoptic, counts))
    (millimetres, panoptic, counts), = found
    (expected_millimetres, expected_panoptic, expected_counts), = expected
    assert (millimetres > 0).mean() > 0.1 and (millimetres == 0).mean() > 0.1  # (hits and misses, clipped ones too)
    np.testing.assert_array_equal(millimetres, expected_millimetres)
    np.testing.assert_array_equal(panoptic, expected_panoptic)
    for (areas, boxes), (expected_areas, expected_boxes) in zip(counts, expected_counts):
        np.testing.assert_array_equal(areas, expected_areas)
        np.testing.assert_array_equal(boxes, expected_boxes)
