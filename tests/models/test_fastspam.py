"""FastSPAM's steps on hand-made masks and on a rendered scene with a known camera motion."""

from __future__ import annotations

import numpy as np

from pipeline.models.fastspam import FastSpam, FastSpamOptions, MaskAtoms, self_prompted_masks
from pipeline.models.oracle import OracleSegmenter
from pipeline.models.segmenter import FrameInput
from pipeline.render.camera import pixels_inside, project
from pipeline.render.renderer import VideoRenderer
from tests.render.tiny_scenes import embodiment, look_at, room_scene

H, W = 20, 30


def _mask(*cells: tuple[slice, slice]) -> np.ndarray:
    mask = np.zeros((H, W), bool)
    for rows, columns in cells:
        mask[rows, columns] = True
    return mask


def test_prompt_masks_with_iou_at_least_0_9_merge_and_others_stay_apart() -> None:
    core = _mask((slice(0, 10), slice(0, 10)))  # 100 pixels
    near_a, near_b = _mask((slice(10, 11), slice(0, 5))), _mask((slice(10, 11), slice(5, 10)))  # 5 pixels each
    everything = np.stack([core | near_a, core | near_b])
    atoms = MaskAtoms(everything)
    # Prompts in near_a and near_b select one mask each: IoU = 100 / 110 = 0.909 >= 0.9, one merged mask.
    merged = self_prompted_masks(atoms, [(10, 1), (10, 6)], FastSpamOptions(), np.random.default_rng(0))
    assert len(merged) == 1 and np.array_equal(atoms.dense(merged)[0], core | near_a | near_b)
    # At a threshold above 0.909 the two stay apart.
    apart = self_prompted_masks(atoms, [(10, 1), (10, 6)], FastSpamOptions(merge_iou=0.95), np.random.default_rng(0))
    assert sorted(int(m.sum()) for m in atoms.dense(apart)) == [105, 105]


def test_an_everything_mask_the_prompts_leave_uncovered_seeds_a_new_prompt() -> None:
    table, chair = _mask((slice(0, 10), slice(0, 10))), _mask((slice(12, 16), slice(20, 25)))
    everything = np.stack([table, chair])
    atoms = MaskAtoms(everything)
    outputs = atoms.dense(self_prompted_masks(atoms, [(5, 5)], FastSpamOptions(), np.random.default_rng(0)))
    # The prompt gives the table; the chair (covered 0 % < 90 %) is born from its own centroid.
    assert len(outputs) == 2
    assert np.array_equal(outputs[0], table) and np.array_equal(outputs[1], chair)  # sorted by area


def test_a_mask_covered_at_least_90_percent_seeds_nothing() -> None:
    big = _mask((slice(0, 10), slice(0, 10)))
    mostly_inside = _mask((slice(0, 10), slice(0, 1)), (slice(10, 11), slice(0, 1)))  # 10 of 11 pixels in big
    atoms = MaskAtoms(np.stack([big, mostly_inside]))
    outputs = atoms.dense(self_prompted_masks(atoms, [(5, 5)], FastSpamOptions(), np.random.default_rng(0)))
    # The prompt selects `big`; the small mask is covered 10 / 11 = 91 % >= 90 %, so it seeds nothing.
    assert len(outputs) == 1 and np.array_equal(outputs[0], big)
    # Above 91 % it seeds a prompt at its centroid (5, 0), inside both masks: their union (101 pixels),
    # IoU 100 / 101 with `big`, so it merges into it.
    outputs = atoms.dense(self_prompted_masks(atoms, [(5, 5)], FastSpamOptions(coverage=0.95), np.random.default_rng(0)))
    assert len(outputs) == 1 and np.array_equal(outputs[0], big | mostly_inside)


def test_the_prompt_pixel_is_the_centroid_or_a_pixel_inside_when_the_centroid_is_outside() -> None:
    square = _mask((slice(2, 7), slice(2, 7)))
    ring = _mask((slice(0, 20), slice(0, 3)), (slice(0, 3), slice(0, 30)), (slice(17, 20), slice(0, 30)),
                 (slice(0, 20), slice(27, 30)))
    atoms = MaskAtoms(np.stack([square, ring]))
    assert atoms.prompt_pixel(atoms.masks[0], np.random.default_rng(0)) == (4, 4)
    row, column = atoms.prompt_pixel(atoms.masks[1], np.random.default_rng(0))
    centroid = np.argwhere(ring).mean(axis=0).astype(int)
    assert not ring[centroid[0], centroid[1]]  # the ring's centroid is in its hole...
    assert ring[row, column]  # ...so a pixel of the ring is drawn
    draws = {atoms.prompt_pixel(atoms.masks[1], np.random.default_rng(seed)) for seed in range(5)}
    assert len(draws) > 1 and all(ring[r, c] for r, c in draws)  # drawn, seeded, always inside
    assert atoms.prompt_pixel(atoms.masks[1], np.random.default_rng(3)) == atoms.prompt_pixel(atoms.masks[1], np.random.default_rng(3))


def _frames(poses: list[np.ndarray], width: int = 160, height: int = 120) -> list[FrameInput]:
    renderer = VideoRenderer(room_scene(), embodiment(width=width, height=height), exposure=1.0)
    camera = renderer.camera
    frames = []
    for index, pose in enumerate(poses):
        frame = renderer.render(pose)
        frames.append(FrameInput(frame.rgb, frame.depth, camera.intrinsics, frame.panoptic, index, pose))
    return frames


def test_with_a_known_camera_motion_each_prompt_stays_on_its_object() -> None:
    poses = []
    for t in range(4):  # walk 5 cm and turn 2 degrees per frame
        angle = np.radians(2.0 * t)
        position = np.array([0.3 - 0.05 * t, 1.0, -1.5])
        poses.append(look_at(position, position + np.array([np.sin(angle), -0.3, np.cos(angle)])))
    frames = _frames(poses)
    model = FastSpam(OracleSegmenter())
    model.reset(np.random.default_rng(0))
    checked = 0
    for previous, frame in zip(frames, frames[1:]):
        outputs = model.segment(previous)
        # Memory holds one 3D point per output mask (in output order); each oracle mask is one object.
        objects = [int(np.unique(previous.panoptic[m])[0]) for m in outputs]
        assert len(model.memory) == len(outputs) >= 3
        column, row, z = project(model.memory, frame.intrinsics, frame.pose)
        inside = pixels_inside(column, row, z, 160, 120)[2]
        carried = model._reprojected_prompts(frame)
        landed = [int(frame.panoptic[r, c]) for r, c in carried]
        assert landed == [o for o, keep in zip(objects, inside) if keep]
        checked += len(landed)
    assert checked >= 9


def test_a_prompt_that_leaves_the_image_is_dropped() -> None:
    start = look_at(np.array([0.0, 1.0, -1.5]), np.array([0.0, 0.8, 0.0]))
    turned = look_at(np.array([0.0, 1.0, -1.5]), np.array([-1.5, 0.8, -1.5]))  # 90 degrees to the left
    frames = _frames([start, turned])
    model = FastSpam(OracleSegmenter())
    model.reset(np.random.default_rng(0))
    model.segment(frames[0])
    remembered = len(model.memory)
    carried = model._reprojected_prompts(frames[1])
    assert remembered >= 3 and len(carried) < remembered
    # Every prompt kept is inside the image and in front of the camera.
    assert all(0 <= r < 120 and 0 <= c < 160 for r, c in carried)
    behind = look_at(np.array([0.0, 1.0, -1.5]), np.array([0.0, 1.0, -3.0]))  # facing away: every prompt is behind
    assert model._reprojected_prompts(_frames([behind])[0]) == []


def test_without_prompts_the_output_is_the_everything_masks_by_area() -> None:
    frame = _frames([look_at(np.array([0.0, 1.0, -1.5]), np.array([0.0, 0.8, 0.0]))])[0]
    model = FastSpam(OracleSegmenter())
    model.reset(np.random.default_rng(0))
    outputs = model.segment(frame)
    areas = [int(m.sum()) for m in outputs]
    everything = OracleSegmenter().segment(frame)
    assert areas == sorted((int(m.sum()) for m in everything), reverse=True)
