"""The compiled loops of the PLY reader (pipeline/scenes/ply.py) for rows whose lists differ in length.

Kept apart so that importing the reader does not import numba (~170 MB of RSS): only a file with rows of
varying length (n-gon exports mixing triangles and quads) loads this module. Each walk returns
(end, row, property, problem) with problem one of WALK_OK, WALK_TRUNCATED, WALK_BAD_COUNT.
"""

from __future__ import annotations

import numba
import numpy as np

WALK_OK, WALK_TRUNCATED, WALK_BAD_COUNT = 0, 1, 2


@numba.njit(nogil=True, cache=True)
def walk_binary_counts(data, offset, rows, sizes, items, signed, big_endian, counts):  # noqa: ANN001, ANN202
    """Each list's item count per row into counts[list, row]; (end offset, row, property, problem)."""
    cursor, end = offset, data.shape[0]
    for row in range(rows):
        slot = 0
        for prop in range(sizes.shape[0]):
            size = sizes[prop]
            if cursor + size > end:
                return cursor, row, prop, WALK_TRUNCATED
            if items[prop] == 0:
                cursor += size
                continue
            value = 0
            for k in range(size):  # the count's bytes, most significant first
                value = value * 256 + data[cursor + (k if big_endian else size - 1 - k)]
            if signed[prop] and value >= 1 << (8 * size - 1):
                return cursor, row, prop, WALK_BAD_COUNT  # a negative count
            counts[slot, row] = value
            slot += 1
            cursor += size + value * items[prop]
            if cursor > end:
                return cursor, row, prop, WALK_TRUNCATED
    return cursor, -1, -1, WALK_OK


@numba.njit(nogil=True, cache=True)
def copy_rows(data, offset, rows, sizes, items, counts, starts, out):  # noqa: ANN001, ANN202
    """Each property's bytes (or ASCII numbers) of every row, in row order, into out[starts[property]:].
    A scalar spans sizes[p] units; a list, its count's sizes[p] units then counts * items[p] units."""
    filled = starts[:-1].copy()
    cursor = offset
    for row in range(rows):
        slot = 0
        for prop in range(sizes.shape[0]):
            length = sizes[prop]
            if items[prop] != 0:
                cursor += length
                length = counts[slot, row] * items[prop]
                slot += 1
            target = filled[prop]
            for k in range(length):
                out[target + k] = data[cursor + k]
            filled[prop] = target + length
            cursor += length


@numba.njit(nogil=True, cache=True)
def walk_ascii_counts(numbers, start, rows, is_list, counts):  # noqa: ANN001, ANN202
    """Each list's item count per row into counts[list, row]; (end index, row, property, problem)."""
    cursor, end = start, numbers.shape[0]
    for row in range(rows):
        slot = 0
        for prop in range(is_list.shape[0]):
            if cursor >= end:
                return cursor, row, prop, WALK_TRUNCATED
            if not is_list[prop]:
                cursor += 1
                continue
            value = numbers[cursor]
            if not (value >= 0 and value == np.floor(value)):
                return cursor, row, prop, WALK_BAD_COUNT
            if value >= end - cursor:
                return cursor, row, prop, WALK_TRUNCATED
            counts[slot, row] = int(value)
            slot += 1
            cursor += 1 + int(value)
    return cursor, -1, -1, WALK_OK


@numba.njit(nogil=True, cache=True)
def fan_ragged(counts, values, triangles, polygon):  # noqa: ANN001, ANN202
    """Fans (0, i, i + 1) of polygons of any size, polygon after polygon, into triangles and polygon."""
    corner, made = 0, 0
    for index in range(counts.shape[0]):
        size = counts[index]
        for k in range(size - 2):
            triangles[made, 0] = values[corner]
            triangles[made, 1] = values[corner + k + 1]
            triangles[made, 2] = values[corner + k + 2]
            polygon[made] = index
            made += 1
        corner += size


@numba.njit(nogil=True, cache=True)
def fan_size(counts):  # noqa: ANN001, ANN202
    """The number of fan triangles of polygons with these corner counts."""
    total = 0
    for size in counts:
        total += max(size - 2, 0)
    return total
