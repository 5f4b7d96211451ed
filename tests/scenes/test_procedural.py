"""The procedural house generator: deterministic, varied, realistic vocabulary, no interpenetration."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.scenes.categories import category_of, raw_names
from pipeline.scenes.procedural.house import generate_house, plan_house
from pipeline.scenes.procedural.layout import DOOR_TOP
from pipeline.scenes.scene import Scene, SceneError


def test_same_seed_gives_identical_arrays(small_house: Scene) -> None:
    again = generate_house(seed=7, detail=0.05, min_rooms=3, max_rooms=4)
    assert np.array_equal(again.vertices, small_house.vertices)
    assert np.array_equal(again.faces, small_house.faces)
    assert np.array_equal(again.face_object_ids, small_house.face_object_ids)
    assert np.array_equal(again.vertex_colors, small_house.vertex_colors)
    assert again.objects == small_house.objects


def test_different_seed_gives_a_different_house(small_house: Scene) -> None:
    other = generate_house(seed=8, detail=0.05, min_rooms=3, max_rooms=4)
    same_shape = other.vertices.shape == small_house.vertices.shape
    assert not (same_shape and np.array_equal(other.vertices, small_house.vertices))
    assert [o.raw_name for o in other.objects.values()] != [o.raw_name for o in small_house.objects.values()]


def test_every_face_is_labelled_with_a_unique_positive_id(small_house: Scene) -> None:
    small_house.validate()
    assert (small_house.face_object_ids > 0).all()
    assert set(np.unique(small_house.face_object_ids).tolist()) == set(small_house.objects)
    assert all(0 < i <= 0xFFFFFF for i in small_house.objects)


def test_vocabulary_comes_from_the_mapping_table(small_house: Scene) -> None:
    table = {r.raw_name for r in raw_names()}
    for obj in small_house.objects.values():
        assert obj.raw_name in table, obj.raw_name
        assert obj.category == category_of(obj.raw_name) != 0
    categories = {o.category for o in small_house.objects.values()}
    assert {1, 2, 17} <= categories  # wall, floor, ceiling
    assert {39, 40} & categories  # the long tail of "objects" / "misc" names


def test_house_is_dense_like_mvpd() -> None:
    plan = plan_house(seed=0)
    rooms = len(plan.layout.rooms)
    assert 3 <= rooms <= 8
    assert len(plan.objects) >= 20 * rooms  # hundreds of instances for a multi-room house


@pytest.mark.parametrize(("seed", "floors"), [(0, 1), (1, 1), (2, 1), (4, 2)])
def test_objects_do_not_interpenetrate(seed: int, floors: int) -> None:
    plan = plan_house(seed, floors=floors)
    boxes, owner = [], []
    for k, obj in enumerate(plan.objects):
        for part in obj.piece.parts:
            boxes.append(part.bounds())
            owner.append(k)
    b, owner_array = np.array(boxes), np.array(owner)
    low = np.maximum(b[:, None, 0], b[None, :, 0])
    high = np.minimum(b[:, None, 1], b[None, :, 1])
    overlapping = np.all(high - low > 1e-4, axis=2) & (owner_array[:, None] != owner_array[None, :])
    pairs = [(plan.objects[owner[i]].raw_name, plan.objects[owner[j]].raw_name) for i, j in zip(*np.nonzero(overlapping), strict=True)]
    assert pairs == []


def test_doors_let_a_robot_through_and_rooms_are_connected() -> None:
    plan = plan_house(seed=3, min_rooms=5, max_rooms=8)
    layout = plan.layout
    doors = [o for o in layout.openings if o.kind == "door"]
    assert all(o.end - o.start >= 0.8 and o.top - o.bottom >= 2.0 for o in doors)
    assert all(o.top == DOOR_TOP for o in doors)
    assert 2.5 <= layout.ceiling <= 2.8
    reached, frontier = {0}, [0]
    while frontier:
        room = frontier.pop()
        for a, b in layout.doors:
            for here, there in ((a, b), (b, a)):
                if here == room and there not in reached:
                    reached.add(there)
                    frontier.append(there)
    assert reached == set(range(len(layout.rooms)))


def test_floors_are_horizontal_at_zero(small_house: Scene) -> None:
    floors = np.isin(small_house.face_object_ids, [i for i, o in small_house.objects.items() if o.raw_name == "floor"])
    up = small_house.face_normals()[:, 1] > 0.99
    tops = small_house.vertices[small_house.faces[floors & up]]
    assert len(tops) > 0 and np.allclose(tops[..., 1], 0.0)


def test_detail_scales_the_triangle_count(small_house: Scene) -> None:
    larger = generate_house(seed=7, detail=0.2, min_rooms=3, max_rooms=4)
    assert 40_000 <= small_house.triangle_count <= 60_000
    assert 170_000 <= larger.triangle_count <= 210_000
    assert larger.objects.keys() >= {i for i, o in small_house.objects.items() if o.category in (1, 2, 17)}


def test_two_storeys_are_joined_by_climbable_stairs() -> None:
    plan = plan_house(seed=4, floors=2)
    ground, upper = plan.storeys
    assert upper.rooms[0].index == len(ground.rooms)
    stairs = [o for o in plan.objects if o.category == 16]
    assert len(stairs) == 1
    steps = sorted(stairs[0].piece.parts, key=lambda p: p.high[1])
    tops = [0.0] + [p.high[1] for p in steps]
    assert max(np.diff(tops)) <= 0.19 + 1e-6  # every step climbable with max_step 0.2 m
    upper_floor_top = ground.ceiling + 0.1
    assert tops[-1] == pytest.approx(upper_floor_top)
    upper_floors = [o for o in plan.objects if o.category == 2 and o.region == upper.hallway]
    assert all(p.high[1] == pytest.approx(upper_floor_top) for o in upper_floors for p in o.piece.parts)
    # The stairwell is open: no ceiling of the ground hallway above the steps.
    x0, z0 = steps[0].low[0], steps[0].low[2]
    x1, z1 = steps[-1].high[0], steps[-1].high[2]
    for obj in plan.objects:
        if obj.category == 17 and obj.region == ground.hallway:
            for p in obj.piece.parts:
                assert p.high[0] <= x0 + 1e-6 or p.low[0] >= x1 - 1e-6 or p.high[2] <= z0 + 1e-6 or p.low[2] >= z1 - 1e-6
    assert any(o.category == 30 for o in plan.objects)  # a railing around the hole upstairs


def test_unknown_storey_count_is_refused() -> None:
    with pytest.raises(SceneError, match="floors"):
        generate_house(seed=1, floors=3)
