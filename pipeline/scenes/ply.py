"""Our PLY reader and writer (numpy only): ASCII, binary little- and big-endian, any polygon size.

The format it trusts (Paul Bourke's PLY, as ScanNet, ScanNet++, Matterport3D and Replica ship it):
a text header `ply`, `format <ascii|binary_little_endian|binary_big_endian> 1.0`, `comment ...`
lines, then `element <name> <count>` each followed by its `property <type> <name>` or
`property list <count type> <item type> <name>` lines, then `end_header`; the body holds the
elements in header order, row by row. Types: char/int8, uchar/uint8, short/int16, ushort/uint16,
int/int32, uint/uint32, float/float32, double/float64.

Why our own: trimesh hands a binary file's face properties back as a structured array (so a label
lookup written for the ASCII dict failed with `TypeError: Cannot compare structured or void to
non-void arrays`), and it triangulates quads as "first triangles of every quad, then second
triangles", so per-polygon properties repeated per polygon landed on the wrong faces. Here every
polygon becomes a fan of triangles (0, i, i + 1) kept together in file order, with the index of the
polygon each triangle came from, so per-face properties follow their faces. Rows whose lists all have
the same length (every dataset above) are read with one `np.frombuffer` / one reshape.
"""

from __future__ import annotations

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


@dataclass
class PlyProperty:
    """One `property` line: its name, item type and (for a list) the type of its length field."""

    name: str
    type: str
    count_type: str | None = None


@dataclass
class PlyElement:
    """One `element` of the header and, once read, its columns (a list column is a list of arrays or a 2-D array)."""

    name: str
    count: int
    properties: list[PlyProperty] = field(default_factory=list)
    data: dict[str, np.ndarray | list[np.ndarray]] = field(default_factory=dict)


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


def _header(data: bytes, path: Path) -> tuple[str, list[PlyElement], list[str], int]:
    """(format, elements, comments, byte offset of the body)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise SceneError(f"{path}: not a PLY file (no `ply` ... `end_header` header); re-export the mesh")
    body = data.index(b"\n", end) + 1
    fmt, elements, comments = "", [], []
    for number, raw in enumerate(data[:end].decode("ascii", errors="replace").splitlines()[1:], start=2):
        words = raw.split()
        if not words:
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
                if fmt not in FORMATS:
                    raise ValueError(f"format {fmt!r}")
            elif words[0] in ("comment", "obj_info"):
                comments.append(raw.strip()[len(words[0]):].strip())
            elif words[0] == "element":
                elements.append(PlyElement(words[1], int(words[2])))
            elif words[0] == "property" and words[1] == "list":
                elements[-1].properties.append(PlyProperty(words[4], TYPES[words[3]], TYPES[words[2]]))
            elif words[0] == "property":
                elements[-1].properties.append(PlyProperty(words[2], TYPES[words[1]]))
        except (IndexError, KeyError, ValueError) as error:
            raise SceneError(f"{path}:{number}: bad PLY header line {raw.strip()!r} ({error}); re-export the mesh") from None
    if not fmt:
        raise SceneError(f"{path}: PLY header has no `format` line; re-export the mesh")
    return fmt, elements, comments, body


# ------------------------------------------------------------------------------------------ body


def _binary_element(element: PlyElement, data: bytes, offset: int, order: str, path: Path) -> int:
    """Read one element of a binary body into `element.data`; returns the offset after it."""
    lists = [p for p in element.properties if p.count_type is not None]
    if not lists:
        dtype = np.dtype([(p.name, order + p.type) for p in element.properties])
        return _frombuffer(element, data, offset, dtype, path)
    # Fast path: every list of the first row has the length it has in every row (true of every dataset).
    fields, cursor = [], offset
    for prop in element.properties:
        if prop.count_type is None:
            fields.append((prop.name, order + prop.type))
            cursor += np.dtype(prop.type).itemsize
            continue
        if cursor + np.dtype(prop.count_type).itemsize > len(data):
            raise SceneError(f"{path}: the file ends inside element {element.name!r}; re-download the file")
        length = int(np.frombuffer(data, order + prop.count_type, 1, cursor)[0]) if element.count else 0
        fields += [(f"{prop.name}#count", order + prop.count_type), (prop.name, order + prop.type, (length,))]
        cursor += np.dtype(prop.count_type).itemsize + length * np.dtype(prop.type).itemsize
    dtype = np.dtype(fields)
    if offset + element.count * dtype.itemsize <= len(data):
        rows = np.frombuffer(data, dtype, element.count, offset)
        if all((rows[f"{p.name}#count"] == rows.dtype[p.name].shape[0]).all() for p in lists):
            element.data = {p.name: rows[p.name] for p in element.properties}
            return offset + element.count * dtype.itemsize
    return _binary_rows(element, data, offset, order, path)


def _frombuffer(element: PlyElement, data: bytes, offset: int, dtype: np.dtype, path: Path) -> int:
    end = offset + element.count * dtype.itemsize
    if end > len(data):
        raise SceneError(f"{path}: element {element.name!r} needs {end - offset} bytes, the file has "
                         f"{len(data) - offset} left; the file is truncated, re-download it")
    rows = np.frombuffer(data, dtype, element.count, offset)
    element.data = {name: rows[name] for name in dtype.names or ()}
    return end


def _binary_rows(element: PlyElement, data: bytes, offset: int, order: str, path: Path) -> int:
    """Row by row (lists of varying length, e.g. triangles mixed with quads)."""
    columns: dict[str, list] = {p.name: [] for p in element.properties}
    try:
        for _ in range(element.count):
            for prop in element.properties:
                if prop.count_type is None:
                    value = np.frombuffer(data, order + prop.type, 1, offset)[0]
                    columns[prop.name].append(value)
                    offset += np.dtype(prop.type).itemsize
                    continue
                length = int(np.frombuffer(data, order + prop.count_type, 1, offset)[0])
                offset += np.dtype(prop.count_type).itemsize
                columns[prop.name].append(np.frombuffer(data, order + prop.type, length, offset))
                offset += length * np.dtype(prop.type).itemsize
    except ValueError:
        raise SceneError(f"{path}: the file ends inside element {element.name!r}; re-download the file") from None
    element.data = {p.name: (columns[p.name] if p.count_type else np.array(columns[p.name], p.type))
                    for p in element.properties}
    return offset


def _ascii_element(element: PlyElement, tokens: list[bytes], start: int, path: Path) -> int:
    """Read one element of an ASCII body from the token list; returns the index after it."""
    lists = [p for p in element.properties if p.count_type is not None]
    width = len(element.properties)
    if lists and element.count:
        # Fixed width when every list has the first row's length (checked below).
        width = len(element.properties) - len(lists)
        cursor = start
        for prop in element.properties:
            if prop.count_type is None:
                cursor += 1
            elif cursor >= len(tokens):
                return _ascii_rows(element, tokens, start, path)  # says where the file ends
            else:
                length = int(float(tokens[cursor]))
                width += 1 + length
                cursor += 1 + length
    end = start + element.count * width
    table = _ascii_table(tokens[start:end], element, width)
    if table is not None and _fixed_lists(table, element):
        element.data = _columns_of(table, element)
        return end
    return _ascii_rows(element, tokens, start, path)


def _ascii_table(tokens: list[bytes], element: PlyElement, width: int) -> np.ndarray | None:
    if len(tokens) < element.count * width:
        return None  # lists of varying length (or a truncated file: the row reader says which)
    try:
        return np.array(tokens, dtype=np.float64).reshape(element.count, width)
    except ValueError:
        return None


def _fixed_lists(table: np.ndarray, element: PlyElement) -> bool:
    column = 0
    for prop in element.properties:
        if prop.count_type is None:
            column += 1
            continue
        length = int(table[0, column]) if len(table) else 0
        if len(table) and not (table[:, column] == length).all():
            return False
        column += 1 + length
    return True


def _columns_of(table: np.ndarray, element: PlyElement) -> dict[str, np.ndarray]:
    columns, column = {}, 0
    for prop in element.properties:
        if prop.count_type is None:
            columns[prop.name] = table[:, column].astype(prop.type)
            column += 1
        else:
            length = int(table[0, column]) if len(table) else 0
            columns[prop.name] = table[:, column + 1: column + 1 + length].astype(prop.type)
            column += 1 + length
    return columns


def _ascii_rows(element: PlyElement, tokens: list[bytes], start: int, path: Path) -> int:
    columns: dict[str, list] = {p.name: [] for p in element.properties}
    cursor = start
    try:
        for _ in range(element.count):
            for prop in element.properties:
                if prop.count_type is None:
                    columns[prop.name].append(float(tokens[cursor]))
                    cursor += 1
                else:
                    length = int(tokens[cursor])
                    columns[prop.name].append(np.array(tokens[cursor + 1: cursor + 1 + length], np.float64).astype(prop.type))
                    cursor += 1 + length
    except IndexError:
        raise SceneError(f"{path}: element {element.name!r} has fewer values than its {element.count} rows need; "
                         "the file is truncated, re-download it") from None
    except ValueError as error:
        raise SceneError(f"{path}: element {element.name!r} row values do not parse ({error}); fix or re-export the file") from None
    element.data = {p.name: (columns[p.name] if p.count_type else np.array(columns[p.name]).astype(p.type))
                    for p in element.properties}
    return cursor


def read_ply_elements(path: Path) -> tuple[list[PlyElement], list[str]]:
    """Every element of a PLY file with its columns, and the header comments."""
    try:
        data = Path(path).read_bytes()
    except OSError as error:
        raise SceneError(f"{path}: cannot read ({error.strerror}); check the file") from None
    fmt, elements, comments, offset = _header(data, path)
    if fmt == "ascii":
        tokens, index = data[offset:].split(), 0
        for element in elements:
            index = _ascii_element(element, tokens, index, path)
    else:
        for element in elements:
            offset = _binary_element(element, data, offset, FORMATS[fmt], path)
    return elements, comments


# ------------------------------------------------------------------------------------------ mesh


def fan_triangles(polygons: np.ndarray | list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) fan triangles (0, i, i + 1) of each polygon, polygon after polygon, and each one's polygon."""
    if isinstance(polygons, np.ndarray) and polygons.ndim == 2:
        count, corners = polygons.shape
        if corners == 3:  # already triangles: the file's index array as it is (no copy)
            return polygons, np.arange(count, dtype=np.int64)
        sizes = np.full(count, corners, np.int64)
        flat = polygons.reshape(-1).astype(np.int64)
    else:
        sizes = np.array([len(p) for p in polygons], np.int64)
        flat = np.concatenate(list(polygons)).astype(np.int64) if len(polygons) else np.zeros(0, np.int64)
    per_polygon = np.maximum(sizes - 2, 0)
    polygon = np.repeat(np.arange(len(sizes), dtype=np.int64), per_polygon)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])[polygon]
    # The k-th triangle of a polygon uses its corners 0, k + 1, k + 2.
    k = np.arange(len(polygon)) - np.concatenate([[0], np.cumsum(per_polygon)[:-1]])[polygon]
    triangles = np.stack([flat[starts], flat[starts + k + 1], flat[starts + k + 2]], axis=1)
    return triangles, polygon


def read_ply(path: Path) -> PlyMesh:
    """Read a PLY mesh: vertices, polygon fans and the per-polygon properties; raises SceneError naming the file."""
    elements, comments = read_ply_elements(path)
    by_name = {e.name: e for e in elements}
    vertex = by_name.get("vertex")
    if vertex is None or not {"x", "y", "z"} <= set(vertex.data):
        raise SceneError(f"{path}: no `vertex` element with x, y, z; not a mesh PLY")
    face = by_name.get("face")
    if face is None:
        raise SceneError(f"{path}: no `face` element (a point cloud?); give a mesh PLY")
    key = next((k for k in POLYGON_PROPERTIES if k in face.data), None)
    if key is None:
        raise SceneError(f"{path}: the `face` element has no vertex_indices list; re-export the mesh")
    triangles, polygon = fan_triangles(face.data[key])  # type: ignore[arg-type]
    if len(triangles) and (triangles.min() < 0 or triangles.max() >= vertex.count):
        raise SceneError(f"{path}: face vertex_indices outside 0..{vertex.count - 1}; the file is corrupt")
    scalars = {name: np.asarray(values) for name, values in face.data.items()
               if name != key and not isinstance(values, list) and np.asarray(values).ndim == 1}
    polygons = face.data[key]
    if isinstance(polygons, np.ndarray) and polygons.ndim == 2 and polygons.shape[1] == 3:
        with_triangles = face.count  # a triangle mesh (every scan's file): nothing to count
    else:  # polygon indices never decrease, so the distinct ones are counted where they change
        with_triangles = int(np.count_nonzero(np.diff(polygon, prepend=-1)))
    return PlyMesh(Path(path), dict(vertex.data), triangles, polygon, scalars, comments,  # type: ignore[arg-type]
                   only_triangles=bool(len(polygon) == face.count == with_triangles),
                   short_polygons=face.count - with_triangles)


# The type name the writer gives each numpy item type (the readers accept every alias in TYPES).
TYPE_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint", "f4": "float",
              "f8": "double"}


def _rows(columns: dict[str, np.ndarray], count: int, leading: list[tuple] | None = None) -> np.ndarray:
    """One little-endian structured array of the columns (after the `leading` fields)."""
    rows = np.zeros(count, (leading or []) + [(k, "<" + np.asarray(v).dtype.str[1:]) for k, v in columns.items()])
    for name, values in columns.items():
        rows[name] = values
    return rows


def _header_lines(columns: dict[str, np.ndarray]) -> list[str]:
    return [f"property {TYPE_NAMES[np.asarray(v).dtype.str[1:]]} {k}" for k, v in columns.items()]


def write_ply(path: Path, vertex: dict[str, np.ndarray], polygons: np.ndarray, face: dict[str, np.ndarray] | None = None,
              binary: bool = True) -> Path:
    """Write a PLY mesh (binary little-endian or ASCII) with the given vertex columns, (P, k) polygons
    (uchar count, int indices, as the datasets ship them) and per-polygon scalar columns."""
    face = face or {}
    polygons = np.asarray(polygons, np.int32)
    vertex_rows = _rows(vertex, len(next(iter(vertex.values()))))
    face_rows = _rows(face, len(polygons), [("count", "u1"), ("indices", "<i4", (polygons.shape[1],))])
    face_rows["count"], face_rows["indices"] = polygons.shape[1], polygons
    lines = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", f"element vertex {len(vertex_rows)}",
             *_header_lines(vertex), f"element face {len(polygons)}", "property list uchar int vertex_indices",
             *_header_lines(face), "end_header"]
    temporary = Path(path).with_name(f".{Path(path).name}.tmp")
    with temporary.open("wb") as handle:
        handle.write(("\n".join(lines) + "\n").encode("ascii"))
        for rows in (vertex_rows, face_rows):
            if binary:
                handle.write(rows.tobytes())
            else:
                handle.writelines((" ".join(_ascii_values(row)) + "\n").encode("ascii") for row in rows.tolist())
    temporary.replace(path)
    return Path(path)


def _ascii_values(row: tuple) -> list[str]:
    """The tokens of one row: lists flattened, floats as their shortest round-trip text."""
    values: list[str] = []
    for value in row:
        if isinstance(value, (tuple, list, np.ndarray)):
            values += [str(v) for v in np.asarray(value).tolist()]
        else:
            values.append(repr(value) if isinstance(value, float) else str(value))
    return values

