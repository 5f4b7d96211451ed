"""Our PLY reader and writer (numpy, numba for rows of varying length): ASCII, binary little- and
big-endian, any polygon size.

The format it trusts (Paul Bourke's PLY, as ScanNet, ScanNet++, Matterport3D and Replica ship it):
a first line `ply`, `format <ascii|binary_little_endian|binary_big_endian> 1.0`, `comment ...` /
`obj_info ...` lines, then `element <name> <count>` each followed by its `property <type> <name>` or
`property list <count type> <item type> <name>` lines, then a line `end_header`; the body holds the
elements in header order, row by row. Types: char/int8, uchar/uint8, short/int16, ushort/uint16,
int/int32, uint/uint32, float/float32, double/float64 (list counts: an integer type).

Why our own: trimesh hands a binary file's face properties back as a structured array (so a label
lookup written for the ASCII dict failed with `TypeError: Cannot compare structured or void to
non-void arrays`), and it triangulates quads as "first triangles of every quad, then second
triangles", so per-polygon properties repeated per polygon landed on the wrong faces. Here every
polygon becomes a fan of triangles (0, i, i + 1) kept together in file order, with the index of the
polygon each triangle came from, so per-face properties follow their faces.

Memory: the file is memory-mapped, never copied whole. Rows whose lists all have the first row's
length (every dataset above) are one `np.frombuffer` / one reshape; rows of varying length (meshes
exported with n-gons mix triangles and quads) are walked twice by a compiled loop (ply_kernels.py:
counts, then one copy of each property's bytes into a flat column), never one Python object per row:
the reader holds the mapped file, the counts (4 bytes a row) and the columns it returns (a 134 MB
mixed-face file: 0.52 GB peak RSS, numba included, where the row-by-row reader took 1.35 GB;
benchmarks/results/mesh_readers_real_size.json). An ASCII body is parsed a few
MB at a time into float64 numbers. Every count in the header is checked against what the body can
hold before anything is allocated. Every fault is a SceneError of one line,
`<file>:<header line | element[row].property>: <what>; <fix>`.
"""

from __future__ import annotations

import mmap
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.scenes.scene import SceneError

TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
POLYGON_PROPERTIES = ("vertex_indices", "vertex_index")
ELEMENT_COUNT = re.compile(r"[0-9]{1,18}")  # a plain decimal count (no sign, no exponent, no nan)
TOKEN = re.compile(rb"\S+")
WHITESPACE = re.compile(rb"\s")
ASCII_CHUNK = 1 << 23  # bytes of an ASCII body parsed per call: bounds the text held beside the numbers


@dataclass
class PlyProperty:
    """One `property` line: its name, item type and (for a list) the type of its length field."""

    name: str
    type: str
    count_type: str | None = None


@dataclass
class PlyList:
    """A list property whose rows differ in length: each row's item count and every item, flat, in file order."""

    counts: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return len(self.counts)


@dataclass
class PlyElement:
    """One `element` of the header and, once read, its columns: (N,) arrays, and for a list property
    an (N, k) array when every row holds k items, else a PlyList."""

    name: str
    count: int
    properties: list[PlyProperty] = field(default_factory=list)
    data: dict[str, np.ndarray | PlyList] = field(default_factory=dict)


@dataclass
class PlyMesh:
    """A PLY file's mesh: vertex columns, triangles (polygon fans) and per-polygon columns.

    Attributes:
        vertex: every vertex property by name ((V,) arrays).
        triangles: (F, 3) integer fan triangles (the file's index type for triangle meshes, else int64),
            polygon after polygon in file order.
        triangle_polygon: (F,) int64 index of the polygon each triangle comes from.
        face: every scalar face property by name ((P,) arrays, one entry per polygon).
        comments: the header's `comment` lines (without the keyword), e.g. `TextureFile x.png`.
        only_triangles: every polygon is a triangle (triangle k is polygon k).
        short_polygons: polygons with fewer than 3 corners (they give no triangle).
    """

    path: Path
    vertex: dict[str, np.ndarray]
    triangles: np.ndarray
    triangle_polygon: np.ndarray
    face: dict[str, np.ndarray]
    comments: list[str]
    only_triangles: bool = False
    short_polygons: int = 0

    @property
    def vertices(self) -> np.ndarray:
        """(V, 3) positions in the file's dtype."""
        return np.stack([self.vertex["x"], self.vertex["y"], self.vertex["z"]], axis=1)

    def per_triangle(self, name: str) -> np.ndarray:
        """A face property repeated onto the triangles of its polygon."""
        return self.face[name] if self.only_triangles else self.face[name][self.triangle_polygon]

    def vertex_colors(self) -> np.ndarray | None:
        """(V, 3) uint8 from `red`/`green`/`blue` (or `r`/`g`/`b`); floats in 0..1 are scaled; None without."""
        keys = next((k for k in (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue"))
                     if all(c in self.vertex for c in k)), None)
        if keys is None:
            return None
        rgb = np.stack([self.vertex[c] for c in keys], axis=1)
        if rgb.dtype.kind == "f":
            rgb = np.clip(np.rint(rgb * 255.0), 0, 255)
        return rgb.astype(np.uint8)


# ------------------------------------------------------------------------------------------ header


def _header_error(path: Path, number: int, what: str) -> SceneError:
    return SceneError(f"{path}:{number}: {what}; fix the header or re-export the mesh")


def _header(data: bytes | mmap.mmap, path: Path) -> tuple[str, list[PlyElement], list[str], int]:
    """(format, elements, comments, byte offset of the body), every header line checked."""
    if data[:3] != b"ply" or data[3:4] not in (b"\n", b"\r"):
        raise SceneError(f"{path}: not a PLY file (its first line is not `ply`); give a PLY mesh or re-export it")
    fmt, elements, comments = "", [], []
    offset, number = 0, 0
    while offset < len(data):
        end = data.find(b"\n", offset)
        end = len(data) if end < 0 else end
        line = data[offset:end].decode("utf-8", errors="backslashreplace").strip()
        offset, number = end + 1, number + 1
        words = line.split()
        if number == 1 or not words:
            continue
        if words[0].startswith("end_header") and words != ["end_header"]:
            raise _header_error(path, number, "`end_header` is not followed by a newline")
        if words == ["end_header"]:
            if not fmt:
                raise _header_error(path, number, "the header has no `format` line")
            return fmt, elements, comments, min(offset, len(data))
        if words[0] in ("comment", "obj_info"):
            comments.append(line[len(words[0]):].strip())
        elif words[0] == "format":
            fmt = _format_line(words, fmt, path, number)
        elif words[0] == "element":
            elements.append(_element_line(words, elements, path, number))
        elif words[0] == "property":
            _property_line(words, elements, path, number)
        else:
            raise _header_error(path, number, f"{line[:40]!r} is not a PLY header line (or `end_header` is missing)")
    raise SceneError(f"{path}: the PLY header has no `end_header` line; the file is truncated or not a PLY, re-export it")


def _format_line(words: list[str], previous: str, path: Path, number: int) -> str:
    if previous:
        raise _header_error(path, number, "a second `format` line")
    if len(words) != 3 or words[1] not in FORMATS:
        raise _header_error(path, number, f"format {' '.join(words[1:])[:40]!r} is not one of {', '.join(FORMATS)} + version")
    try:
        version = float(words[2])
    except ValueError:
        version = 0.0
    if version != 1.0:
        raise _header_error(path, number, f"PLY version {words[2][:20]!r}; only 1.0 is defined")
    return words[1]


def _element_line(words: list[str], elements: list[PlyElement], path: Path, number: int) -> PlyElement:
    if len(words) != 3:
        raise _header_error(path, number, f"`element` needs a name and a count, got {' '.join(words[1:])[:40]!r}")
    if not ELEMENT_COUNT.fullmatch(words[2]):
        raise _header_error(path, number, f"element {words[1]!r} count {words[2][:20]!r} is not a count (a whole number 0..10^18)")
    if any(e.name == words[1] for e in elements):
        raise _header_error(path, number, f"element {words[1]!r} occurs twice")
    return PlyElement(words[1], int(words[2]))


def _property_line(words: list[str], elements: list[PlyElement], path: Path, number: int) -> None:
    if not elements:
        raise _header_error(path, number, "a `property` line before any `element` line")
    element = elements[-1]
    is_list = len(words) > 1 and words[1] == "list"
    if len(words) != (5 if is_list else 3):
        raise _header_error(path, number, "expected `property <type> <name>` or `property list <count type> <type> <name>`")
    types = words[2:4] if is_list else words[1:2]
    unknown = [t for t in types if t not in TYPES]
    if unknown:
        raise _header_error(path, number, f"unknown type {unknown[0][:20]!r} (known: {', '.join(TYPES)})")
    if is_list and np.dtype(TYPES[words[2]]).kind == "f":
        raise _header_error(path, number, f"list count type {words[2]!r} is not an integer type")
    name = words[-1]
    if any(p.name == name for p in element.properties):
        raise _header_error(path, number, f"property {name!r} occurs more than once in element {element.name!r}")
    element.properties.append(PlyProperty(name, TYPES[words[3]], TYPES[words[2]]) if is_list
                              else PlyProperty(name, TYPES[words[1]]))


# ------------------------------------------------------------------------------------------ body


def _field(path: Path, element: PlyElement, row: int | None = None, prop: PlyProperty | None = None) -> str:
    """`<file>:<element>[<row>].<property>`: where a body fault is."""
    where = f"{path}:{element.name}"
    if row is not None:
        where += f"[{row}]"
    return where + (f".{prop.name}" if prop is not None else "")


def _empty_columns(element: PlyElement) -> dict[str, np.ndarray | PlyList]:
    return {p.name: np.zeros((0, 0) if p.count_type else 0, p.type) for p in element.properties}


def _list_column(counts: np.ndarray, values: np.ndarray) -> np.ndarray | PlyList:
    """(N, k) when every row holds k items, else the counts with the flat items."""
    if len(counts) and (counts == counts[0]).all():
        return values.reshape(len(counts), int(counts[0]))
    return PlyList(counts, values)


def _native(values: np.ndarray) -> np.ndarray:
    """The array in the machine's byte order, swapped in place when it is not (its buffer is ours)."""
    if values.dtype.isnative:
        return values
    return values.byteswap(inplace=True).view(values.dtype.newbyteorder("="))


def _binary_element(element: PlyElement, data: np.ndarray, offset: int, order: str, path: Path) -> int:
    """Read one element of a binary body into `element.data`; returns the offset after it."""
    if not element.properties or not element.count:
        element.data = _empty_columns(element)
        return offset
    # The bytes of a row whose lists are all empty: checked before anything is allocated for the rows.
    least = sum(np.dtype(p.count_type or p.type).itemsize for p in element.properties)
    if element.count * least > len(data) - offset:
        raise SceneError(f"{_field(path, element)}: {element.count} rows need at least {element.count * least} bytes, "
                         f"the file has {len(data) - offset} left; the file is truncated or its header count is wrong, "
                         "re-download it")
    dtype = _uniform_dtype(element, data, offset, order)
    if dtype is not None:
        rows = np.frombuffer(data, dtype, element.count, offset)
        props = list(enumerate(element.properties))
        if all((rows[f"n{i}"] == dtype[f"p{i}"].shape[0]).all() for i, p in props if p.count_type):
            element.data = {p.name: rows[f"p{i}"].astype(p.type) for i, p in props}
            return offset + element.count * dtype.itemsize
    return _binary_ragged(element, data, offset, order, path)


def _uniform_dtype(element: PlyElement, data: np.ndarray, offset: int, order: str) -> np.dtype | None:
    """The structured dtype of a row whose lists have the first row's lengths; None when the rows cannot
    all be so (the file is too short for it, or the first row is broken: the ragged walk says where)."""
    fields, cursor = [], offset  # fields named by position: property names may be anything
    for i, prop in enumerate(element.properties):
        if prop.count_type is None:
            fields.append((f"p{i}", order + prop.type))
            cursor += np.dtype(prop.type).itemsize
            continue
        size = np.dtype(prop.count_type).itemsize
        if cursor + size > len(data):
            return None
        length = int(np.frombuffer(data, order + prop.count_type, 1, cursor)[0])
        cursor += size + length * np.dtype(prop.type).itemsize
        if length < 0 or cursor > len(data):
            return None
        fields += [(f"n{i}", order + prop.count_type), (f"p{i}", order + prop.type, (length,))]
    dtype = np.dtype(fields)
    return dtype if offset + element.count * dtype.itemsize <= len(data) else None


def _binary_ragged(element: PlyElement, data: np.ndarray, offset: int, order: str, path: Path) -> int:
    """Rows whose lists differ in length: one compiled walk for the counts, one copying every property's
    bytes into its own region of one buffer, viewed as the columns."""
    props = element.properties
    sizes = np.array([np.dtype(p.count_type or p.type).itemsize for p in props], np.int64)
    items = np.array([np.dtype(p.type).itemsize if p.count_type else 0 for p in props], np.int64)
    signed = np.array([bool(p.count_type) and np.dtype(p.count_type).kind == "i" for p in props])
    lists = [i for i, p in enumerate(props) if p.count_type]
    counts = np.empty((len(lists), element.count), np.uint32)  # a count is at most a uint: 4 bytes a row, not 8
    end, row, bad, problem = _kernels().walk_binary_counts(data, offset, element.count, sizes, items, signed, order == ">", counts)
    _raise_walk_problem(problem, path, element, row, bad)
    lengths = [int(counts[lists.index(i)].sum()) * items[i] if i in lists else element.count * sizes[i]
               for i in range(len(props))]
    starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    out = np.empty(int(starts[-1]), np.uint8)
    _kernels().copy_rows(data, offset, element.count, sizes, items, counts, starts, out)
    columns: dict[str, np.ndarray | PlyList] = {}
    for i, prop in enumerate(props):
        values = _native(out[starts[i]:starts[i + 1]].view(order + prop.type))
        # A scalar column is copied out: a view would keep the whole buffer (the lists' items too) alive.
        columns[prop.name] = _list_column(counts[lists.index(i)], values) if prop.count_type else values.copy()
    element.data = columns
    return int(end)


def _kernels():  # noqa: ANN202 (the module)
    """The compiled row walks, imported on the first file that needs them: numba costs ~170 MB of RSS and
    ~0.4 s to load, which files whose rows all have one length (every dataset's) never pay."""
    from pipeline.scenes import ply_kernels

    return ply_kernels


def _raise_walk_problem(problem: int, path: Path, element: PlyElement, row: int, bad: int) -> None:
    if problem == _kernels().WALK_TRUNCATED:
        raise SceneError(f"{_field(path, element, row)}: the file ends inside this row (a list count runs past the "
                         "end, or the body is cut short); the file is truncated or corrupt, re-download it")
    if problem == _kernels().WALK_BAD_COUNT:
        raise SceneError(f"{_field(path, element, row, element.properties[bad])}: the list count is not a whole "
                         "number >= 0; the file is corrupt, re-export it")


def _ascii_numbers(data: bytes | mmap.mmap, offset: int, header_lines: int, path: Path) -> tuple[np.ndarray, str]:
    """Every number of an ASCII body (float64), parsed a chunk at a time, and where parsing stopped:
    "" at the end of the file, else `<line>: <token> is not a number` (reported only if a row needs it)."""
    parts, start = [], offset
    while start < len(data):
        boundary = WHITESPACE.search(data, min(start + ASCII_CHUNK, len(data)))  # type: ignore[call-overload]
        stop = boundary.start() if boundary else len(data)
        chunk = data[start:stop]
        numbers, bad = _parse_chunk(chunk)
        parts.append(numbers)
        if bad is not None:
            line = header_lines + data[offset:start].count(b"\n") + chunk[:bad.start()].count(b"\n") + 1
            return np.concatenate(parts), f"{line}: {repr(bad.group()[:20])[1:]} is not a number"
        start = stop
    return (np.concatenate(parts) if parts else np.zeros(0)), ""


def _parse_chunk(chunk: bytes) -> tuple[np.ndarray, re.Match | None]:
    """The numbers of a chunk of text; on a token no number parser reads, those before it and its match."""
    if not chunk.strip():
        return np.zeros(0), None  # (numpy's parser reads blank text as [-1.0])
    try:
        return np.fromstring(chunk, sep=" "), None
    except ValueError:
        pass
    numbers = []
    for match in TOKEN.finditer(chunk):  # slow, only for a chunk numpy refused: find the token to blame
        try:
            numbers.append(float(match.group()))
        except ValueError:
            return np.array(numbers, np.float64), match
    return np.array(numbers, np.float64), None


def _ascii_element(element: PlyElement, numbers: np.ndarray, start: int, stopped: str, path: Path) -> int:
    """Read one element of an ASCII body from the numbers; returns the index after it."""
    if not element.properties or not element.count:
        element.data = _empty_columns(element)
        return start
    if element.count * len(element.properties) > len(numbers) - start:  # one number a property at least
        raise _ascii_short(path, element, None, stopped)
    width = _ascii_uniform_width(element, numbers, start)
    if width is not None and start + element.count * width <= len(numbers):
        table = numbers[start: start + element.count * width].reshape(element.count, width)
        if _ascii_lists_uniform(table, element):
            element.data = _ascii_columns(table, element, path)
            return start + element.count * width
    return _ascii_ragged(element, numbers, start, stopped, path)


def _ascii_lists_uniform(table: np.ndarray, element: PlyElement) -> bool:
    column = 0
    for prop in element.properties:
        if prop.count_type is None:
            column += 1
            continue
        length = int(table[0, column])
        if not (table[:, column] == length).all():
            return False
        column += 1 + length
    return True


def _ascii_columns(table: np.ndarray, element: PlyElement, path: Path) -> dict[str, np.ndarray | PlyList]:
    columns: dict[str, np.ndarray | PlyList] = {}
    column = 0
    for prop in element.properties:
        if prop.count_type is None:
            columns[prop.name] = _ascii_cast(table[:, column], path, element, prop)
            column += 1
        else:
            length = int(table[0, column])
            columns[prop.name] = _ascii_cast(table[:, column + 1: column + 1 + length], path, element, prop)
            column += 1 + length
    return columns


def _ascii_uniform_width(element: PlyElement, numbers: np.ndarray, start: int) -> int | None:
    """Numbers per row if every list had its first row's length; None when the first row is broken."""
    width = 0
    for prop in element.properties:
        if prop.count_type is None:
            width += 1
            continue
        if start + width >= len(numbers):
            return None
        length = numbers[start + width]
        if not (0 <= length <= len(numbers) and length == int(length)):
            return None
        width += 1 + int(length)
    return width


def _ascii_ragged(element: PlyElement, numbers: np.ndarray, start: int, stopped: str, path: Path) -> int:
    props = element.properties
    is_list = np.array([p.count_type is not None for p in props])
    lists = [i for i, p in enumerate(props) if p.count_type]
    counts = np.empty((len(lists), element.count), np.int64)
    end, row, bad, problem = _kernels().walk_ascii_counts(numbers, start, element.count, is_list, counts)
    if problem == _kernels().WALK_TRUNCATED:
        raise _ascii_short(path, element, row, stopped)
    _raise_walk_problem(problem, path, element, row, bad)
    lengths = [int(counts[lists.index(i)].sum()) if i in lists else element.count for i in range(len(props))]
    starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    out = np.empty(int(starts[-1]), np.float64)
    ones = np.ones(len(props), np.int64)  # every scalar and list count is one number; every item too
    _kernels().copy_rows(numbers, start, element.count, ones, is_list.astype(np.int64), counts, starts, out)
    columns: dict[str, np.ndarray | PlyList] = {}
    for i, prop in enumerate(props):
        values = _ascii_cast(out[starts[i]:starts[i + 1]], path, element, prop)
        columns[prop.name] = _list_column(counts[lists.index(i)], values) if prop.count_type else values
    element.data = columns
    return int(end)


def _ascii_short(path: Path, element: PlyElement, row: int | None, stopped: str) -> SceneError:
    if stopped:
        return SceneError(f"{path}:{stopped}, element {element.name!r} needs it; fix the line or re-export the file")
    return SceneError(f"{_field(path, element, row)}: the file ends before this element's {element.count} rows do; "
                      "the file is truncated or its header count is wrong, re-download it")


def _ascii_cast(values: np.ndarray, path: Path, element: PlyElement, prop: PlyProperty) -> np.ndarray:
    """The numbers as the property's type; an integer type refuses fractions, nan and values out of its range."""
    dtype = np.dtype(prop.type)
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        fits = (values >= info.min) & (values <= info.max) & (values == np.trunc(values))
        if not fits.all():
            value = values.reshape(-1)[np.argmin(fits.reshape(-1))].item()
            raise SceneError(f"{_field(path, element, None, prop)}: {value!r} is not a value of type {dtype.name} "
                             f"(whole numbers {info.min}..{info.max}); fix the file or its header type")
    return values.astype(dtype)


def read_ply_elements(path: Path) -> tuple[list[PlyElement], list[str]]:
    """Every element of a PLY file with its columns, and the header comments."""
    try:
        with open(path, "rb") as handle:
            size = os.fstat(handle.fileno()).st_size
            data = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    except OSError as error:
        raise SceneError(f"{path}: cannot read ({error.strerror}); check the file") from None
    fmt, elements, comments, offset = _header(data, path)
    if fmt == "ascii":
        numbers, stopped = _ascii_numbers(data, offset, data[:offset].count(b"\n"), path)
        index = 0
        for element in elements:
            index = _ascii_element(element, numbers, index, stopped, path)
    else:
        buffer = np.frombuffer(data, np.uint8)
        for element in elements:
            offset = _binary_element(element, buffer, offset, FORMATS[fmt], path)
    return elements, comments


# ------------------------------------------------------------------------------------------ mesh


def _fan(corners: np.ndarray) -> np.ndarray:
    """(P, k) polygons of one size -> (P, k - 2, 3) int64 fans (0, i, i + 1)."""
    count, k = corners.shape
    triangles = np.empty((count, max(k - 2, 0), 3), np.int64)
    if k >= 3:
        triangles[:, :, 0] = corners[:, :1]
        triangles[:, :, 1] = corners[:, 1:-1]
        triangles[:, :, 2] = corners[:, 2:]
    return triangles


def fan_triangles(polygons: np.ndarray | PlyList | list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) fan triangles (0, i, i + 1) of each polygon, polygon after polygon, and each one's polygon."""
    if isinstance(polygons, list):
        flat = np.concatenate(polygons) if polygons else np.zeros(0, np.int64)
        polygons = PlyList(np.array([len(p) for p in polygons], np.int64), flat)
    if isinstance(polygons, np.ndarray):
        count, corners = polygons.shape
        if corners == 3:  # already triangles: the file's index array as it is (no copy)
            return polygons, np.arange(count, dtype=np.int64)
        per_polygon = max(corners - 2, 0)
        return _fan(polygons).reshape(-1, 3), np.repeat(np.arange(count, dtype=np.int64), per_polygon)
    total = _kernels().fan_size(polygons.counts)
    triangles, polygon = np.empty((total, 3), np.int64), np.empty(total, np.int64)
    _kernels().fan_ragged(polygons.counts, polygons.values, triangles, polygon)
    return triangles, polygon


def _mesh_elements(path: Path, elements: list[PlyElement]) -> tuple[PlyElement, PlyElement, str]:
    """The `vertex` and `face` elements and the face's index list property, each checked."""
    by_name = {e.name: e for e in elements}
    vertex = by_name.get("vertex")
    if vertex is None or not {"x", "y", "z"} <= set(vertex.data):
        raise SceneError(f"{path}: no `vertex` element with x, y, z; not a mesh PLY")
    flat = next((p for p in vertex.properties if p.name in "xyz" and p.count_type), None)
    if flat is not None:
        raise SceneError(f"{path}:vertex.{flat.name}: a list property; x, y and z must be numbers, re-export the mesh")
    face = by_name.get("face")
    if face is None:
        raise SceneError(f"{path}: no `face` element (a point cloud?); give a mesh PLY")
    indices = next((p for p in face.properties if p.name in POLYGON_PROPERTIES), None)
    if indices is None or indices.count_type is None:
        raise SceneError(f"{path}: the `face` element has no vertex_indices list; re-export the mesh")
    if np.dtype(indices.type).kind == "f":
        raise SceneError(f"{path}:face.{indices.name}: items of type {np.dtype(indices.type).name}; vertex indices "
                         "must be an integer type, re-export the mesh")
    return vertex, face, indices.name


def read_ply(path: Path) -> PlyMesh:
    """Read a PLY mesh: vertices, polygon fans and the per-polygon properties; raises SceneError naming the file."""
    elements, comments = read_ply_elements(path)
    vertex, face, key = _mesh_elements(path, elements)
    polygons = face.data[key]
    triangles, polygon = fan_triangles(polygons)
    if len(triangles):
        low, high = int(triangles.min()), int(triangles.max())
        if low < 0 or high >= vertex.count:
            raise SceneError(f"{path}:face.{key}: index {low if low < 0 else high} outside 0..{vertex.count - 1} "
                             f"(the file has {vertex.count} vertices); the file is corrupt, re-export it")
    scalars = {name: values for name, values in face.data.items()
               if name != key and isinstance(values, np.ndarray) and values.ndim == 1}
    if isinstance(polygons, PlyList):
        with_triangles = int(np.count_nonzero(polygons.counts >= 3))
    else:  # every polygon has the first one's corner count
        with_triangles = face.count if polygons.shape[1] >= 3 else 0
    return PlyMesh(Path(path), dict(vertex.data), triangles, polygon, scalars, comments,  # type: ignore[arg-type]
                   only_triangles=bool(len(polygon) == face.count == with_triangles),
                   short_polygons=face.count - with_triangles)


# The type name the writer gives each numpy item type (the readers accept every alias in TYPES).
TYPE_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint", "f4": "float",
              "f8": "double"}


def _rows(columns: dict[str, np.ndarray], count: int, order: str = "<", leading: list[tuple] | None = None) -> np.ndarray:
    """One structured array of the columns (after the `leading` fields) in byte order `order`."""
    rows = np.zeros(count, (leading or []) + [(k, order + np.asarray(v).dtype.str[1:]) for k, v in columns.items()])
    for name, values in columns.items():
        rows[name] = values
    return rows


def _header_lines(columns: dict[str, np.ndarray]) -> list[str]:
    return [f"property {TYPE_NAMES[np.asarray(v).dtype.str[1:]]} {k}" for k, v in columns.items()]


def _polygon_lists(polygons: np.ndarray | PlyList | list) -> tuple[np.ndarray, np.ndarray]:
    """(counts, flat int32 indices) of (P, k) polygons, a PlyList or a list of index sequences."""
    if isinstance(polygons, PlyList):
        return np.asarray(polygons.counts, np.int64), np.asarray(polygons.values, np.int32)
    if isinstance(polygons, list):
        flat = np.concatenate([np.asarray(p, np.int32).reshape(-1) for p in polygons]) if polygons else np.zeros(0, np.int32)
        return np.array([len(p) for p in polygons], np.int64), flat
    polygons = np.asarray(polygons, np.int32)
    return np.full(len(polygons), polygons.shape[1], np.int64), polygons.reshape(-1)


def write_ply(path: Path, vertex: dict[str, np.ndarray], polygons: np.ndarray | PlyList | list,
              face: dict[str, np.ndarray] | None = None, binary: bool = True, big_endian: bool = False) -> Path:
    """Write a PLY mesh (binary little- or big-endian, or ASCII) with the given vertex columns, polygons
    ((P, k) array, or polygons of any sizes up to 255 corners as a PlyList or a list of index sequences;
    uchar count, int indices, as the datasets ship them) and per-polygon scalar columns. Consecutive
    polygons of one size are written as one block, so a file of long runs writes at numpy speed."""
    face = face or {}
    counts, flat = _polygon_lists(polygons)
    if len(counts) and counts.max() > 255:
        raise ValueError("write_ply writes polygons of up to 255 corners (a uchar count)")
    order = ">" if big_endian else "<"
    fmt = ("binary_big_endian" if big_endian else "binary_little_endian") if binary else "ascii"
    vertex_rows = _rows(vertex, len(next(iter(vertex.values()))), order)
    lines = ["ply", f"format {fmt} 1.0", f"element vertex {len(vertex_rows)}", *_header_lines(vertex),
             f"element face {len(counts)}", "property list uchar int vertex_indices", *_header_lines(face), "end_header"]
    temporary = Path(path).with_name(f".{Path(path).name}.tmp")
    with temporary.open("wb") as handle:
        handle.write(("\n".join(lines) + "\n").encode("ascii"))
        _write_rows(handle, vertex_rows, binary)
        run_starts = np.flatnonzero(np.diff(counts, prepend=-1)).tolist() + [len(counts)]
        corner = 0
        for start, stop in zip(run_starts[:-1], run_starts[1:]):
            size = int(counts[start])
            run = _rows({k: np.asarray(v)[start:stop] for k, v in face.items()}, stop - start, order,
                        [("count", "u1"), ("indices", order + "i4", (size,))])
            run["count"], run["indices"] = size, flat[corner: corner + (stop - start) * size].reshape(stop - start, size)
            corner += (stop - start) * size
            _write_rows(handle, run, binary)
    temporary.replace(path)
    return Path(path)


def _write_rows(handle: object, rows: np.ndarray, binary: bool) -> None:
    if binary:
        handle.write(rows.tobytes())  # type: ignore[attr-defined]
    else:
        handle.writelines((" ".join(_ascii_values(row)) + "\n").encode("ascii") for row in rows.tolist())  # type: ignore[attr-defined]


def _ascii_values(row: tuple) -> list[str]:
    """The tokens of one row: lists flattened, floats as their shortest round-trip text."""
    values: list[str] = []
    for value in row:
        if isinstance(value, (tuple, list, np.ndarray)):
            values += [str(v) for v in np.asarray(value).tolist()]
        else:
            values.append(repr(value) if isinstance(value, float) else str(value))
    return values

