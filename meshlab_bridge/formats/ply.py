"""
ply.py
------
PLY through plyfile, which keeps what pymeshlab's loader drops: every vertex
property with its type, faces, other elements, comments, ASCII or binary.

Reading maps ``x y z`` to positions, ``nx ny nz`` (or ``normal_x …``) to
normals, ``red green blue [alpha]`` to colours, ``quality`` (or ``scalar``) to
quality, and keeps every other vertex property in ``attributes``.  A file whose
data holds more or fewer rows than its header declares is refused.  Writing
restores the input's property order and types where the values still fit them
exactly (so an unchanged float32 column stays float32) and uses float64
otherwise; new attributes are appended.  An ASCII PLY of vertices alone is
parsed and written by NumPy in blocks, with plyfile's values and bytes
(plyfile's loop over rows took 18 µs per row to read and 52 µs to write a
10⁶-row file, NumPy 3.8 and 4.7 µs).  A binary mesh of triangles has its
faces memory-mapped too, and written as records, again plyfile's bytes
(its list rows cost about 4 µs a face each way).  Faces are read as
triangles: a polygon becomes the fan of triangles from its first vertex,
and its other properties go to ``Cloud.face_attributes`` on each triangle
(``face_values``).
"""

from __future__ import annotations

import io
import itertools
import os
import warnings

import numpy as np

from pcprep.filters._validation import PointCloudError

from ..cloud import Cloud

_NORMALS = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
_COLORS = ("red", "green", "blue", "alpha")
_QUALITY = ("quality", "scalar")


class _KeepOpen(io.FileIO):
    """plyfile closes the stream it reads; keep it open to check what follows."""

    def close(self):  # noqa: D401 -- closed by ``really_close``
        pass

    def really_close(self):
        super().close()


#: rows per block of a whole ASCII PLY read or write (and ASCII PCD read), and
#: faces per block of a binary write
TEXT_BLOCK = 1 << 18


def read(path: str) -> Cloud:
    head = ascii_header(path)
    if head is not None:  # ASCII vertices alone: NumPy's parser
        ply, count, _ = head
        blocks = [rows for _, rows in ascii_vertex_blocks(path, TEXT_BLOCK, head)]
        rows = np.concatenate(blocks) if blocks else np.empty(0, ply["vertex"].dtype())
        return vertex_cloud(rows, ply, path, count)
    ply = load(path)
    cloud = vertex_cloud(np.array(ply["vertex"].data), ply, path)  # from the memmap
    faces, values, unkept = _faces(ply, len(cloud), path)
    cloud.meta["ply"]["other_elements"] = {el.name: el for el in _other_elements(ply)}
    cloud.meta["face_properties"] = unkept
    return cloud.with_(faces=faces, face_attributes=values)


def load(path: str):
    """plyfile's ``PlyData`` of ``path``, binary elements memory-mapped; refused
    (``PointCloudError``) where plyfile cannot parse it, where it has no vertex
    element, and where its rows are not the ones its header declares (ASCII:
    lines counted; binary: data after the declared elements)."""
    from plyfile import PlyData, PlyParseError

    f = _KeepOpen(path, "rb")
    try:
        ply = None
        key = _index_list(f)
        for size in (3, 4) if key else ():
            # memory-map the faces too, when every one is a triangle (or a quad)
            try:
                ply = PlyData.read(f, known_list_len={"face": {key: size}})
                break
            except PlyParseError:
                f.seek(0)  # faces of other sizes, or a damaged file
        if ply is None:
            try:
                with warnings.catch_warnings():  # an empty list of an ASCII row is valid
                    warnings.filterwarnings("ignore", "loadtxt: input contained no data")
                    ply = PlyData.read(f)
            except PlyParseError as exc:
                raise PointCloudError(f"cannot read {path!r}: {exc}") from exc
        if "vertex" not in ply:
            raise PointCloudError(f"cannot read {path!r}: no vertex element")
        if ply.text:
            _check_ascii_rows(path, ply)
        else:
            rest = f.read(64)
            if rest.strip(b"\x00\n\r\t ") or len(rest) > 8:
                raise PointCloudError(
                    f"cannot read {path!r}: data continues after the {ply['vertex'].count} "
                    "vertices (and other elements) its header declares")
    finally:
        f.really_close()
    return ply


def _index_list(f) -> str | None:
    """The name of the face element's vertex-index list of a binary PLY
    whose face element holds no other list, read from the header's lines;
    None for an ASCII file or one without such a list (a header plyfile
    would not parse is refused by the read that follows).  The stream is left
    at its start.

    plyfile parses an element with a list property row by row in Python
    (about 4 µs a face here), unless told each list's length
    (``known_list_len``), when it memory-maps the element and refuses it if
    any row's count differs.  A mesh of triangles, or of quads, is then read
    at the speed of its vertices; any other mesh is read again, row by row,
    as before."""
    element, lists, binary = None, [], False
    try:
        for _ in range(10_000):
            tok = f.readline(4096).split()
            if tok[:1] == [b"end_header"]:
                break
            if tok[:1] == [b"format"]:
                binary = tok[1:2] != [b"ascii"]
            elif tok[:1] == [b"element"]:
                element = tok[1:2]
            elif tok[:2] == [b"property", b"list"] and element == [b"face"]:
                lists.append(tok[-1])
        else:
            return None
    finally:
        f.seek(0)
    if not binary or lists not in ([b"vertex_indices"], [b"vertex_index"]):
        return None
    return lists[0].decode("ascii")


def vertex_cloud(data: np.ndarray, ply, path: str, count: int | None = None) -> Cloud:
    """A ``Cloud`` of the vertex rows ``data`` (all of ``ply``'s vertices or a
    block of them), with the header facts that writing restores; no faces.
    ``count`` is the file's vertex count where ``ply`` holds the header alone
    (``ascii_vertex_blocks``)."""
    names = list(data.dtype.names)
    for c in "xyz":
        if c not in names:
            raise PointCloudError(f"cannot read {path!r}: vertices have no {c!r} property")
    pts = np.column_stack([data[c].astype(np.float64) for c in "xyz"])
    used = {"x", "y", "z"}
    normals = None
    for trio in _NORMALS:
        if all(t in names for t in trio):
            normals = np.column_stack([data[t].astype(np.float64) for t in trio])
            used.update(trio)
            break
    colors = None
    if all(c in names for c in _COLORS[:3]):
        cols = [c for c in _COLORS if c in names]
        colors = np.ones((len(pts), 4))
        for j, c in enumerate(cols):
            colors[:, j] = _unit_color(data[c])
        used.update(cols)
    quality = None
    for q in _QUALITY:
        if q in names:
            quality = data[q].astype(np.float64)
            used.add(q)
            break
    attrs = {n: np.ascontiguousarray(data[n]) for n in names if n not in used}
    meta = {"format": ".ply", "ply": {
        "text": bool(ply.text), "byte_order": ply.byte_order,
        "comments": list(ply.comments), "obj_info": list(ply.obj_info),
        "types": {n: data.dtype[n].str for n in names}, "order": names,
        "lists": {p.name: (p.len_dtype, p.val_dtype) for p in ply["vertex"].properties
                  if _is_list(p)},
        "other_elements": {}, "face_types": face_types(ply),
        "n_vertices": ply["vertex"].count if count is None else count},
        "face_properties": ()}
    return Cloud(pts, normals, colors, quality, None, attrs, os.path.basename(path), meta)


def face_types(ply) -> dict:
    """The face element's properties besides its vertex-index list (colours,
    quality, flags, texture coordinates, …) by name, in file order: a scalar's
    type, or a list's ``(count type, value type)``, the types ``write``
    restores where the values fit them.  Empty for a file without faces."""
    if "face" not in ply or ply["face"].count == 0:
        return {}
    el = ply["face"]
    key = _face_key(el)
    if key is None:
        return {}
    return {p.name: (p.len_dtype, p.val_dtype) if _is_list(p) else p.val_dtype
            for p in el.properties if p.name != key}


def vertex_lists(ply) -> list[str]:
    """The vertex element's list properties (kept as object attributes,
    read and written whole: a list has no fixed place in a row)."""
    return [p.name for p in ply["vertex"].properties if _is_list(p)]


def _is_list(prop) -> bool:
    from plyfile import PlyListProperty

    return isinstance(prop, PlyListProperty)


def ascii_header(path: str):
    """``(ply, count, offset)`` of an ASCII PLY whose one element is ``vertex``
    with scalar properties: plyfile's ``PlyData`` of its header (read with a
    vertex count of 0, so no row is parsed), the vertex count the header
    declares and the byte offset of the first row.  None for a binary PLY,
    for other elements or list properties (faces index every vertex, so such
    a file is read whole), and for a header plyfile would not parse (the whole
    read then names the fault)."""
    from plyfile import PlyData, PlyParseError

    lines, count, offset = [], None, 0
    with open(path, "rb") as f:
        for line in f:
            lines.append(line)
            offset += len(line)
            tok = line.split()
            if tok[:1] == [b"end_header"]:
                break
            if tok[:1] == [b"format"] and tok[1:2] != [b"ascii"]:
                return None
            if tok[:1] == [b"element"]:
                if tok[1:2] != [b"vertex"] or count is not None or len(tok) != 3:
                    return None
                try:
                    count = int(tok[2])
                except ValueError:
                    return None
                lines[-1] = b"element vertex 0\n"
            if len(lines) > 10_000:
                return None
        else:
            return None
    try:
        ply = PlyData.read(io.BytesIO(b"".join(lines)))
    except (PlyParseError, ValueError):
        return None
    if count is None or count < 0 or not ply.text or _has_list(ply["vertex"]):
        return None
    return ply, count, offset


#: ASCII rows parsed at once: the lines, their text and loadtxt's buffer take
#: about 8 bytes per byte of text, so a parse stays within tens of MB whatever
#: the block asked for
PARSE_ROWS = 1 << 16


def ascii_vertex_blocks(path: str, size: int, head=None):
    """``(start, rows)`` blocks of an ASCII PLY's vertex rows (``ascii_header``
    says which files), each a structured array of the header's property types,
    parsed by NumPy's ``loadtxt`` with the type of each column (``PARSE_ROWS``
    at a time), which gives the values plyfile's row-by-row parse gives.
    Refused as the whole read refuses them: a blank or short line among the
    declared rows, a row with another number of values or one that does not
    parse as its type, fewer rows than declared or rows after them; the error
    names the rows.  ``head`` is the file's ``ascii_header`` where the caller
    has it."""
    ply, count, offset = ascii_header(path) if head is None else head
    dtype = ply["vertex"].dtype()
    start = 0
    with open(path, "rb") as f:
        f.seek(offset)
        while start < count:
            m = min(size, count - start)
            parts = [_parse_rows(f, path, start + s, min(PARSE_ROWS, m - s), count, dtype)
                     for s in range(0, m, PARSE_ROWS)]
            yield start, parts[0] if len(parts) == 1 else np.concatenate(parts)
            start += m
        more = sum(1 for line in f if line.strip())
        if more:
            raise PointCloudError(f"cannot read {path!r}: the header declares {count} rows "
                                  f"({count} vertex) but the file holds {count + more}")


def _parse_rows(f, path: str, first: int, m: int, count: int, dtype: np.dtype) -> np.ndarray:
    """The next ``m`` vertex rows of ``f`` (rows ``first``… of ``count``)."""
    lines = list(itertools.islice(f, m))
    short = next((j for j, line in enumerate(lines) if not line.strip()), len(lines))
    if short < m:
        raise PointCloudError(
            f"cannot read {path!r}: vertex row {first + short} (from 0) of the {count} the "
            "header declares is " + ("blank" if short < len(lines) else "missing"))
    try:
        return np.loadtxt(io.StringIO(b"".join(lines).decode("ascii")), dtype=dtype,
                          comments=None, ndmin=1)
    except (ValueError, UnicodeDecodeError) as exc:
        raise PointCloudError(f"cannot read {path!r}: "
                              f"{_row_fault(lines, first, dtype) or exc}") from None


def _row_fault(lines: list[bytes], start: int, dtype: np.dtype) -> str | None:
    """What is wrong with the first of ``lines`` (vertex rows from ``start``)
    that does not hold one value of each type of ``dtype``: its row and the
    count or the value at fault, as plyfile parses a row; None if every line
    parses that way."""
    names = dtype.names
    for j, line in enumerate(lines):
        try:
            tok = line.decode("ascii").split()
        except UnicodeDecodeError:
            return f"vertex row {start + j} (from 0) is not ASCII text"
        if len(tok) != len(names):
            return (f"vertex row {start + j} (from 0) holds {len(tok)} values, the header "
                    f"declares {len(names)} properties")
        for name, t in zip(names, tok):
            try:
                dtype[name].type(t)
            except (ValueError, OverflowError):
                return (f"vertex row {start + j} (from 0): {t!r} is not a value of property "
                        f"{name!r} ({dtype[name]})")
    return None


def _unit_color(col: np.ndarray) -> np.ndarray:
    if col.dtype.kind in "ui":
        return col.astype(np.float64) / float(np.iinfo(col.dtype).max)
    return col.astype(np.float64)


def _check_ascii_rows(path: str, ply) -> None:
    """In ASCII PLY each row is one line: count them against the header."""
    declared = sum(el.count for el in ply.elements)
    with open(path, "rb") as f:
        for line in f:
            if line.strip() == b"end_header":
                break
        rows = sum(1 for line in f if line.strip())
    if rows != declared:
        raise PointCloudError(
            f"cannot read {path!r}: the header declares {declared} rows "
            f"({', '.join(f'{el.count} {el.name}' for el in ply.elements)}) but the file "
            f"holds {rows}")


def _faces(ply, n: int, path: str):
    """``(triangles, values, unkept)`` of ``ply``'s face element: the fan of
    each polygon (``fan_triangles``; None without faces), each other face
    property on the triangles (``face_values``) and the names of those that
    cannot be (``formats.check_faces`` refuses to lose them)."""
    if "face" not in ply or ply["face"].count == 0:
        return None, {}, ()
    el = ply["face"]
    key = _face_key(el)
    if key is None:
        return None, {}, ()
    polygons = el.data[key]
    faces = fan_triangles(polygons)
    if len(faces) and (faces.min() < 0 or faces.max() >= n):
        raise _missing_vertex(path, int(faces.max()), n)
    sizes = _sizes(polygons)
    values, unkept = {}, []
    for p in el.properties:
        if p.name == key:
            continue
        v = face_values(el.data[p.name], sizes, _is_list(p))
        if v is None:
            unkept.append(p.name)
        else:
            values[p.name] = v
    if not len(faces):
        return None, {}, ()
    return faces, values, tuple(unkept)


def _sizes(polygons) -> np.ndarray:
    """The vertex count of each of ``polygons`` (``fan_triangles``' input)."""
    polygons = np.asarray(polygons)
    if polygons.dtype != object:
        return np.full(len(polygons), polygons.reshape(len(polygons), -1).shape[1], np.int64)
    return np.fromiter(map(len, polygons), dtype=np.int64, count=len(polygons))


def face_values(values, sizes: np.ndarray, is_list: bool):
    """One face property of polygons of ``sizes`` vertices on the triangles
    ``fan_triangles`` makes of them, row t for triangle t: a scalar repeated
    on each triangle of its polygon's fan; a list of c values per corner (a
    polygon of m vertices holds c·m; texture coordinates, c = 2) as the
    3c values of each triangle's corners (v₀, v_j, v_j+1), so a triangle
    mesh's lists are kept as they are.  None for a list of another length,
    which has no meaning per triangle that pcprep could know."""
    n_tri = np.maximum(sizes - 2, 0)
    if not is_list:
        values = np.asarray(values)
        return values.copy() if (n_tri == 1).all() else np.repeat(values, n_tri)
    values = np.asarray(values)
    if values.dtype != object:  # memory-mapped lists of one length
        values = values.reshape(len(values), -1)
        lengths = np.full(len(values), values.shape[1], np.int64)
    else:
        lengths = np.fromiter(map(len, values), dtype=np.int64, count=len(values))
    if not len(values):
        return None
    c = int(lengths[0] // sizes[0]) if sizes[0] else 0
    if not (lengths == c * sizes).all():
        return None
    if values.dtype == object:
        flat = (np.concatenate(values) if lengths.sum() else
                np.empty(0, np.asarray(values[0]).dtype))
    else:
        flat = values.reshape(-1)
    if (sizes == 3).all():
        return flat.reshape(len(values), 3 * c).copy()
    corners = fan_corners(sizes)
    cols = (c * corners)[:, :, None] + np.arange(c)
    return flat[cols.reshape(len(corners), 3 * c)]


def fan_corners(sizes: np.ndarray) -> np.ndarray:
    """(t, 3) places, among all corners of polygons of ``sizes`` vertices
    listed one polygon after another, of the corners of each triangle of
    their fans (``fan_triangles``)."""
    first = np.cumsum(sizes) - sizes  # each polygon's first corner
    n_tri = np.maximum(sizes - 2, 0)
    owner = np.repeat(np.arange(len(sizes)), n_tri)
    j = np.arange(n_tri.sum()) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    base = first[owner]
    return np.stack([base, base + j, base + j + 1], axis=1)


def indexes_vertices(el) -> bool:
    """Whether element ``el`` refers to vertex rows: a property whose name
    starts with ``vertex``, as the PLY convention names them (an ``edge``'s
    ``vertex1`` and ``vertex2``, a range grid's ``vertex_indices``)."""
    return any(p.name.startswith("vertex") for p in el.properties)


def kept_elements(others, count: int, info: dict, kept=None, increasing: bool = False) -> list:
    """Of the other elements ``others``, those a PLY of ``count`` vertices
    written from the file ``info`` describes keeps: all of them as they were
    read where every vertex is kept; after a removal that kept the input's
    rows ``kept`` (row j of the result is input row ``kept[j]``; by default
    ``info["kept_rows"]``, which ``Cloud.subset`` records), those that refer
    to no vertex (a camera, a material) as they were read and those that
    refer to vertices by scalar properties (an edge's ``vertex1`` and
    ``vertex2``) renumbered, their rows that refer to a removed vertex left
    out, as a face is (``renumbered``).  An element that refers to vertices
    by a list (a range grid's ``vertex_indices``), and any that refers to
    vertices where the kept rows are not known, would refer to the wrong
    rows; ``formats.check_elements`` refuses to leave it out without a word.
    ``increasing``: ``kept`` is known to increase (a memory map, not read
    whole to check)."""
    kept = info.get("kept_rows") if kept is None else kept
    if kept is None and count == info.get("n_vertices", -1):
        return list(others)
    out = []
    for el in others:
        if not indexes_vertices(el):
            out.append(el)
        elif kept is not None and len(kept) == count and all(
                not _is_list(p) for p in el.properties if p.name.startswith("vertex")):
            out.append(renumbered(el, kept, increasing))
    return out


def renumbered(el, kept, increasing: bool = False):
    """Element ``el`` after a removal that kept the input's rows ``kept``:
    its rows whose vertex references (scalar properties named ``vertex…``)
    are all kept, those references renumbered to the kept rows' order, its
    other properties, types and comments as they were."""
    from plyfile import PlyElement

    data = np.asarray(el.data)
    refs = [p.name for p in el.properties if p.name.startswith("vertex")]
    new, found = _positions(np.column_stack([np.asarray(data[n], np.int64) for n in refs]),
                            kept, increasing)  # every reference in one search
    keep = found.all(axis=1)
    data = data[keep].copy()
    for j, name in enumerate(refs):
        data[name] = new[keep, j]
    lists = [p for p in el.properties if _is_list(p)]
    return PlyElement.describe(data, el.name, len_types={p.name: p.len_dtype for p in lists},
                               val_types={p.name: p.val_dtype for p in lists},
                               comments=list(el.comments))


def _positions(values: np.ndarray, kept, increasing: bool):
    """``(positions, found)``: where each of ``values`` (input rows) is among
    ``kept``, found by binary search (the rows in ``kept`` sorted first
    unless ``increasing``)."""
    if not len(kept):
        return np.zeros_like(values), np.zeros(values.shape, dtype=bool)
    kept = kept if increasing else np.asarray(kept)
    order = None if increasing else np.argsort(kept, kind="stable")
    sorted_rows = kept if order is None else kept[order]
    pos = np.minimum(np.searchsorted(sorted_rows, values), len(kept) - 1)
    found = np.asarray(sorted_rows[pos]) == values
    return (pos if order is None else order[pos]), found


def _other_elements(ply) -> list:
    """The elements besides the vertices and the faces (a ``face`` element
    without a vertex-index list is one of them), in file order."""
    return [el for el in ply.elements if el.name != "vertex"
            and not (el.name == "face" and _face_key(el) is not None)]


def _face_key(el) -> str | None:
    """The face element's vertex-index list, by either of its usual names."""
    return next((p.name for p in el.properties if p.name in ("vertex_indices", "vertex_index")),
                None)


def _missing_vertex(path: str, index: int, n: int) -> PointCloudError:
    return PointCloudError(f"cannot read {path!r}: a face refers to a vertex that "
                           f"does not exist (index {index}, {n} vertices)")


def fan_triangles(polygons) -> np.ndarray:
    """(t, 3) int64 triangles of the faces ``polygons`` (a (f, m) array of
    indices, or an object array of index lists), each polygon fanned from its
    first vertex, (v₀, v_j, v_j+1) for j = 1 … m − 2, polygon after polygon;
    a polygon of fewer than three vertices gives none."""
    polygons = np.asarray(polygons)
    if polygons.dtype != object:
        rows = polygons.astype(np.int64).reshape(len(polygons), -1)
        j = np.arange(1, rows.shape[1] - 1)
        fan = np.stack([np.repeat(rows[:, :1], len(j), axis=1), rows[:, j], rows[:, j + 1]],
                       axis=2)
        return fan.reshape(-1, 3)
    sizes = np.fromiter(map(len, polygons), dtype=np.int64, count=len(polygons))
    flat = (np.concatenate(polygons).astype(np.int64, copy=False) if len(polygons)
            else np.empty(0, np.int64))
    return flat[fan_corners(sizes)]


def _fits(values: np.ndarray, dtype: np.dtype) -> bool:
    """True when ``values`` survive a cast to ``dtype`` exactly."""
    try:
        cast = values.astype(dtype)
    except (TypeError, ValueError):
        return False
    with np.errstate(invalid="ignore"):
        back = cast.astype(values.dtype)
    same = (back == values) | (np.isnan(values) & np.isnan(back)) if values.dtype.kind == "f" \
        else back == values
    return bool(np.all(same))


def _column(values: np.ndarray, original: str | None) -> np.ndarray:
    values = np.asarray(values)
    if values.dtype == object:  # a list per row, written as the list property it was
        return values
    if values.dtype == bool:
        values = values.astype(np.uint8)
    if original is not None and _fits(values, np.dtype(original)):
        return values.astype(np.dtype(original))
    if values.dtype.kind == "f":
        return values.astype(np.float64)
    return values


def write(cloud: Cloud, path: str) -> None:
    from plyfile import PlyElement

    cols = vertex_columns(cloud)
    vertex = vertex_rows(cols, {n: v.dtype for n, v in cols.items()})
    info = cloud.meta.get("ply", {})
    lists = {n: info.get("lists", {}).get(n, ("u1", "f8")) for n, v in cols.items()
             if v.dtype == object}  # a vertex list property, as it was read
    elements = [PlyElement.describe(vertex, "vertex", len_types={n: t[0] for n, t in lists.items()},
                                    val_types={n: t[1] for n, t in lists.items()})]
    face = None
    if cloud.faces is not None and len(cloud.faces):
        layout = face_layout(cloud.face_attributes, info)
        face = face_element(face_rows(cloud.faces, cloud.face_attributes, layout), layout)
        elements.append(face)
    others = kept_elements(info.get("other_elements", {}).values(), len(cloud), info)
    elements += others
    if info.get("text") and len(elements) == 1 and not lists:  # plyfile's bytes, by NumPy
        with open(path, "wb") as f:
            f.write(header({n: v.dtype for n, v in cols.items()}, len(vertex), info))
            for s in range(0, len(vertex), TEXT_BLOCK):
                f.write(text_rows({n: v[s:s + TEXT_BLOCK] for n, v in cols.items()},
                                  {n: vertex.dtype[n] for n in cols}))
        return
    data = _ply_data(elements, info)
    if data.text:
        data.write(path)
    else:
        _write_binary(data, path, face)


def _has_list(el) -> bool:
    from plyfile import PlyListProperty

    return any(isinstance(p, PlyListProperty) for p in el.properties)


def _write_binary(data, path: str, face=None) -> None:
    """The binary PLY ``data`` with plyfile's header and layout.  plyfile
    writes an element with a list property row by row in Python (about
    4 µs a face here), and writes that element's scalar properties in the
    machine's byte order whatever the file's (plyfile 1.1: a big-endian
    file's face colours and qualities come back wrong), so the triangles
    ``face`` (``face_element``) are written as records (``face_records``),
    another element with a list row by row in the file's byte order
    (``list_element_bytes``), the others as records (``element_bytes``)."""
    order = data.byte_order
    with open(path, "wb") as f:
        f.write(data.header.encode("ascii") + b"\n")
        for el in data.elements:
            if el is face:
                for s in range(0, len(el.data), TEXT_BLOCK):
                    f.write(face_records(el.data[s:s + TEXT_BLOCK], el, order))
            elif _has_list(el):
                f.write(list_element_bytes(el, order))
            else:
                f.write(element_bytes(el, order))


def list_element_bytes(el, order: str) -> bytes:
    """The rows of an element with list properties, one after another, each
    value in byte order ``order``: a list as its count, then its values."""
    out = io.BytesIO()
    props = [(p.name, p.list_dtype(order) if _is_list(p) else p.dtype(order))
             for p in el.properties]
    for rec in el.data:
        for name, kind in props:
            if isinstance(kind, tuple):
                v = np.asarray(rec[name], dtype=kind[1]).ravel()
                out.write(np.array(v.size, dtype=kind[0]).tobytes())
                out.write(v.tobytes())
            else:
                out.write(np.array(rec[name], dtype=kind).tobytes())
    return out.getvalue()


def face_layout(values: dict, info: dict) -> tuple[list, dict]:
    """The face rows' structured type and each list's count type: the
    triangles' ``vertex_indices`` (count ``uchar`` 3, indices ``int``), then
    each face attribute of ``values`` in the type the input had
    (``face_types``) where its values fit it exactly, else float64 (for
    floats) or their own; an (f, k) attribute is a list of k values."""
    fields, len_types = [("vertex_indices", "i4", (3,))], {"vertex_indices": "u1"}
    types = info.get("face_types", {})
    for name, v in values.items():
        v = np.asarray(v)
        original = types.get(name)
        if v.ndim == 1:
            fields.append((name, _column(v, None if isinstance(original, (list, tuple))
                                         else original).dtype.str))
            continue
        count, val = original if isinstance(original, (list, tuple)) else ("u1", None)
        if np.iinfo(np.dtype(count)).max < v.shape[1]:
            count = "u4"
        fields.append((name, _column(v, val).dtype.str, (v.shape[1],)))
        len_types[name] = np.dtype(count).str.lstrip("<>|=")
    return fields, len_types


def face_rows(tri, values: dict, layout) -> np.ndarray:
    """The structured face rows of triangles ``tri`` and their attributes
    ``values`` in the type ``layout`` (``face_layout``) gives."""
    rows = np.empty(len(tri), dtype=layout[0])
    rows["vertex_indices"] = tri
    for name, v in values.items():
        rows[name] = v
    return rows


def face_element(rows, layout):
    """plyfile's face element of ``rows`` (``face_rows``), or of that many
    rows for a header when ``rows`` is a count (no rows are made)."""
    from plyfile import PlyElement

    if isinstance(rows, (int, np.integer)):
        rows = np.broadcast_to(np.zeros(1, dtype=layout[0]), (int(rows),))
    return PlyElement.describe(rows, "face", len_types=layout[1])


def face_records(rows: np.ndarray, el, order: str) -> memoryview:
    """The bytes plyfile writes for these face rows of element ``el``
    (``face_element``) in byte order ``order``: each list property as its
    count, then its values."""
    fields, fill = [], []
    for p in el.properties:
        if _is_list(p):
            length, value = p.list_dtype(order)
            fields += [(p.name + "#", length), (p.name, value, rows.dtype[p.name].shape)]
            fill.append((p.name + "#", rows.dtype[p.name].shape[0]))
        else:
            fields.append((p.name, p.dtype(order)))
    out = np.empty(len(rows), dtype=fields)
    for name, count in fill:
        out[name] = count
    for name in rows.dtype.names:
        out[name] = rows[name]
    return out.data


def element_bytes(el, order: str) -> memoryview:
    """The rows plyfile writes for an element without list properties."""
    return el.data.astype(el.dtype(order), copy=False).data


def mesh_tail(ply, path: str):
    """What a binary PLY (``load``) holds besides its vertices, for a write in
    blocks: ``(triangles, others)``, the memory-mapped faces as the triangles
    ``read`` makes of them, with their other properties, slice by slice
    (``_Fan``; None without faces), and the other elements in file order.
    None where the file is read whole: a face element read row by row (faces
    of other or mixed sizes, or another list on the faces) or another element
    with a list property.  A face that refers to a vertex that does not exist is
    refused as ``read`` refuses it."""
    others = _other_elements(ply)
    if any(_has_list(el) for el in others):
        return None
    if "face" not in ply or ply["face"].count == 0:
        return None, others
    el = ply["face"]
    key = _face_key(el)
    if key is None:
        return None, others
    polygons = el.data[key]
    if polygons.dtype == object:
        return None
    lo, hi, n = 0, -1, ply["vertex"].count
    for s in range(0, len(polygons), TEXT_BLOCK):
        part = polygons[s:s + TEXT_BLOCK]
        lo, hi = min(lo, int(part.min())), max(hi, int(part.max()))
    if lo < 0 or hi >= n:
        raise _missing_vertex(path, hi, n)
    names = tuple(p.name for p in el.properties if p.name != key)  # scalars: lists refused
    return _Fan(polygons, el.data, names), others


class _Fan:
    """The triangles ``fan_triangles`` makes of (f, m) polygons (m ≥ 3, the
    memory-mapped faces of a mesh read in blocks), made slice by slice:
    triangle t is triangle t mod (m − 2) of polygon t div (m − 2).
    ``values(start, stop)`` gives those triangles' face attributes, the
    scalar properties ``names`` of the face rows ``data``, as ``read`` gives
    them (``face_values``)."""

    def __init__(self, polygons: np.ndarray, data=None, names: tuple = ()):
        self.polygons, self.per = polygons, polygons.shape[1] - 2
        self.data, self.names = data, names

    def __len__(self) -> int:
        return len(self.polygons) * self.per

    def _span(self, key: slice) -> tuple[int, int, int]:
        start, stop, step = key.indices(len(self))
        if step != 1:
            raise IndexError("_Fan: slices of step 1 only")
        return start, max(start, stop), start // self.per

    def __getitem__(self, key: slice) -> np.ndarray:
        start, stop, first = self._span(key)
        if self.per == 1:
            return np.asarray(self.polygons[start:stop])
        tri = fan_triangles(self.polygons[first:-(-stop // self.per)])
        return tri[start - first * self.per:stop - first * self.per]

    def values(self, start: int, stop: int) -> dict:
        start, stop, first = self._span(slice(start, stop))
        out = {}
        for name in self.names:
            v = np.asarray(self.data[name][first:-(-stop // self.per)])
            v = np.repeat(v, self.per) if self.per > 1 else v
            out[name] = v[start - first * self.per:stop - first * self.per]
        return out

    def without_values(self) -> "_Fan":
        return _Fan(self.polygons)


def kept_triangles(tri, kept, size: int = TEXT_BLOCK, values: bool = False):
    """(m, 3) int64 blocks of the triangles ``tri`` after a removal that kept
    the rows ``kept`` (increasing indices; None: every row): each triangle
    whose three vertices are kept, renumbered to the kept rows' order, as
    ``Cloud.subset`` renumbers them, found by binary search in ``kept`` (no
    map of the input's length).  With ``values``, ``(block, attributes)``
    pairs, the kept triangles' face attributes (``_Fan.values``) beside them."""
    for s in range(0, len(tri), size):
        part = np.asarray(tri[s:s + size], dtype=np.int64)
        vals = tri.values(s, s + size) if values else None
        if kept is None:
            yield (part, vals) if values else part
            continue
        if len(kept) == 0:
            return
        pos, found = _positions(part, kept, increasing=True)
        whole = found.all(axis=1)
        yield (pos[whole], {k: v[whole] for k, v in vals.items()}) if values else pos[whole]


def _ply_data(elements, info: dict):
    from plyfile import PlyData

    return PlyData(elements, text=info.get("text", False),
                   byte_order=info.get("byte_order", "<") if not info.get("text") else "=",
                   comments=info.get("comments", []), obj_info=info.get("obj_info", []))


def vertex_columns(cloud: Cloud, *, alpha: bool = False) -> dict[str, np.ndarray]:
    """The vertex properties ``cloud`` is written with, by name in file order:
    the input's properties in their order and types where the values still fit
    them exactly, new ones after them.  An alpha the input did not have is
    written only where some colour is not opaque, or where ``alpha`` asks
    (a streamed write decides it over every block first)."""
    info = cloud.meta.get("ply", {})
    types = info.get("types", {})
    cols: dict[str, np.ndarray] = {}
    for j, c in enumerate("xyz"):
        cols[c] = _column(cloud.points[:, j], types.get(c))
    if cloud.normals is not None:
        trio = next((t for t in _NORMALS if t[0] in types), _NORMALS[0])
        for j, c in enumerate(trio):
            cols[c] = _column(cloud.normals[:, j], types.get(c))
    if cloud.colors is not None:
        for j, c in enumerate(_COLORS):
            if (c == "alpha" and c not in types and not alpha
                    and np.all(cloud.colors[:, 3] == 1.0)):
                continue
            t = np.dtype(types.get(c, "u1"))
            v = cloud.colors[:, j]
            cols[c] = (np.rint(v * np.iinfo(t).max).astype(t) if t.kind in "ui"
                       else v.astype(t))
    if cloud.quality is not None:
        q = next((q for q in _QUALITY if q in types), "quality")
        cols[q] = _column(cloud.quality, types.get(q))
    for name, arr in cloud.attributes.items():
        arr = np.asarray(arr)
        if arr.ndim == 1:
            cols[name] = _column(arr, types.get(name))
        else:
            for k in range(arr.shape[1]):
                cols[f"{name}_{k}"] = _column(arr[:, k], types.get(f"{name}_{k}"))
    order = [n for n in info.get("order", []) if n in cols] + \
        [n for n in cols if n not in info.get("order", [])]
    return {n: cols[n] for n in order}


def vertex_rows(cols: dict[str, np.ndarray], types: dict) -> np.ndarray:
    """The structured vertex array of ``cols``, each column of type ``types[name]``."""
    vertex = np.empty(len(next(iter(cols.values()))),
                      dtype=[(n, np.dtype(types[n]).str) for n in cols])
    for n, v in cols.items():
        vertex[n] = v
    return vertex


def wider_type(name: str, a: np.dtype, b: np.dtype, info: dict) -> np.dtype:
    """The type of a column written in blocks whose values gave types ``a`` and
    ``b``: a block keeps the input's type only where its values fit it, so
    where the blocks differ the whole column does not fit, and the other type
    is the one writing it whole gives."""
    if a == b:
        return a
    original = info.get("types", {}).get(name)
    if original is not None and np.dtype(original) in (a, b):
        return b if a == np.dtype(original) else a
    return np.result_type(a, b)


def header(types: dict, count: int, info: dict, elements=()) -> bytes:
    """The header of a PLY of ``count`` vertices with the properties ``types``
    (name → type, in file order), then ``elements`` (plyfile's), the input's
    comments, encoding and byte order, through plyfile; the rows follow it as
    ``vertex_rows(...).tobytes()`` in that byte order (``row_type``), or as
    ``text_rows`` for ASCII."""
    from plyfile import PlyElement

    shape = np.broadcast_to(np.zeros(1, dtype=list(types.items())), (count,))
    ply = _ply_data([PlyElement.describe(shape, "vertex"), *elements], info)
    return ply.header.encode("ascii") + b"\n"


def text_rows(cols: dict[str, np.ndarray], types: dict) -> bytes:
    """The lines of these vertex rows in an ASCII PLY, as plyfile writes them:
    each value in its column's type, as ``%.18g``, one space apart.  The values
    are formatted from a float64 table: every PLY type (8- to 32-bit integers,
    float32, float64) converts to float64 exactly, and ``%.18g`` of a value
    does not depend on the type that holds it."""
    table = np.column_stack([np.asarray(v).astype(np.dtype(types[n])).astype(np.float64)
                             for n, v in cols.items()])
    out = io.BytesIO()
    np.savetxt(out, table, "%.18g", newline="\n")
    return out.getvalue()


def row_type(types: dict, info: dict) -> np.dtype:
    """The on-disk row type of ``types`` in the byte order ``header`` writes."""
    order = info.get("byte_order", "<")
    order = "<" if order == "=" else order
    return np.dtype([(n, np.dtype(t).newbyteorder(order)) for n, t in types.items()])
