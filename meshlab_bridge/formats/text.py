"""
text.py
-------
The plain-text formats XYZ, OBJ and OFF, read and written here at full
precision (17 significant digits), every row kept.  pymeshlab's readers skip
rows they cannot parse (a NaN row vanishes and every later index shifts; an OBJ
line ``v abc def ghi`` becomes a point at the origin) and its writers keep six
digits, so pcprep does these itself: a malformed row is an error naming its line.

XYZ holds ``x y z`` or ``x y z nx ny nz`` per line (``#`` comments).  OBJ keeps
``v x y z [r g b]``, ``vn`` (as vertex normals when there is one per vertex),
``f`` (polygons fan-triangulated; ``i/j/k`` indices and negative indices
understood) and what the faces carry (``vt`` texture coordinates, ``o``,
``g``, ``usemtl``, ``s``, ``mtllib``; ``_read_obj``).  OFF, COFF, NOFF and
CNOFF keep positions, normals, colours and faces, and a colour per face
(``r g b [a]`` after its indices, integers 0–255 or floats 0–1) as the face
attributes ``red green blue [alpha]``.
"""

from __future__ import annotations

import os

import numpy as np

from pcprep.filters._validation import PointCloudError

from ..cloud import Cloud

_FMT = "%.17g"


def read(path: str) -> Cloud:
    ext = os.path.splitext(path)[1].lower()
    return {".xyz": _read_xyz, ".obj": _read_obj, ".off": _read_off}[ext](path)


def write(cloud: Cloud, path: str) -> None:
    ext = os.path.splitext(path)[1].lower()
    {".xyz": _write_xyz, ".obj": _write_obj, ".off": _write_off}[ext](cloud, path)


def _numbers(tokens: list[str], path: str, line: int, what: str) -> list[float]:
    try:
        return [float(t) for t in tokens]
    except ValueError:
        raise PointCloudError(f"cannot read {path!r}: line {line}: {what} "
                              f"{' '.join(tokens)!r} is not numeric") from None


def _read_xyz(path: str) -> Cloud:
    return xyz_cloud(np.concatenate([b for _, b in xyz_blocks(path)]), path)


def xyz_blocks(path: str, size: int = 1 << 20):
    """``(start, (m, 3 or 6) float64)`` blocks of an XYZ file's rows, in order,
    refused as a whole read refuses them: a line of other than 3 or 6 columns,
    or of another count than the lines before it, or not numeric, by its line
    number; no rows at all."""
    rows, width, start = [], None, 0
    with open(path, encoding="utf-8", errors="replace") as f:
        for no, line in enumerate(f, 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            tok = text.replace(",", " ").split()
            if len(tok) not in (3, 6):
                raise PointCloudError(
                    f"cannot read {path!r}: line {no}: expected 3 (x y z) or 6 "
                    f"(x y z nx ny nz) columns, got {len(tok)}")
            if width is not None and len(tok) != width:
                raise PointCloudError(f"cannot read {path!r}: line {no}: {len(tok)} columns, "
                                      f"earlier lines {width}")
            width = len(tok)
            rows.append(_numbers(tok, path, no, "row"))
            if len(rows) == size:
                yield start, np.array(rows, dtype=np.float64)
                start += size
                rows = []
    if rows:
        yield start, np.array(rows, dtype=np.float64)
    elif width is None:
        raise PointCloudError(f"cannot read {path!r}: the file holds no vertices")


def xyz_count(path: str) -> int:
    """The number of rows of an XYZ file (its non-blank lines outside comments),
    without parsing them (``xyz_blocks`` checks them)."""
    with open(path, encoding="utf-8", errors="replace") as f:
        return sum(1 for line in f if line.split("#", 1)[0].strip())


def xyz_cloud(data: np.ndarray, path: str) -> Cloud:
    """The ``Cloud`` of XYZ rows (positions, and normals in columns 4–6)."""
    normals = data[:, 3:6].copy() if data.shape[1] == 6 else None
    return Cloud(np.ascontiguousarray(data[:, :3]), normals, label=os.path.basename(path),
                 meta={"format": ".xyz"})


def _triangles(poly: list[int]) -> list[tuple[int, int, int]]:
    return [(poly[0], poly[j], poly[j + 1]) for j in range(1, len(poly) - 1)]


def _read_obj(path: str) -> Cloud:
    """An OBJ's vertices (``v``, with colours), normals (``vn``, one per vertex)
    and faces, each polygon fanned, with what the faces carry as face
    attributes on each triangle of the fan: ``texcoord`` (the u v of its three
    corners, from ``vt`` by the faces' ``v/vt`` indices, the layout MeshLab's
    PLY uses), ``object`` (``o``), ``group`` (``g``), ``material``
    (``usemtl``) and ``smoothing`` (``s``), the last four as indices into the
    names in ``meta["obj"]`` (with the ``mtllib`` lines; -1 before the first
    such line), so that a write gives the lines back; ``l`` and ``p`` lines
    as lists of vertex rows there too (``OBJ_CHAINS``).  What is not kept is
    named in ``meta["face_properties"]``: texture coordinates on some faces
    only or with a w, normals per corner."""
    verts, cols, vns, vts = [], [], [], []
    faces, corner_vt, n_tri, state = [], [], [], []
    keys = {"o": "object", "g": "group", "usemtl": "material", "s": "smoothing"}
    names = {k: [] for k in keys.values()}
    now = {k: -1 for k in keys.values()}
    mtllib, w_used, seen = [], False, set()
    chains = {"l": [], "p": []}  # polylines and point groups, as vertex rows
    with open(path, encoding="utf-8", errors="replace") as f:
        for no, line in enumerate(f, 1):
            tok = line.split("#", 1)[0].split()
            if not tok:
                continue
            if tok[0] == "v":
                vals = _numbers(tok[1:], path, no, "vertex")
                if len(vals) not in (3, 4, 6, 7):
                    raise PointCloudError(f"cannot read {path!r}: line {no}: a vertex needs "
                                          f"3 coordinates (and optionally w, r g b), got {len(vals)}")
                verts.append(vals[:3])
                if len(vals) >= 6:
                    cols.append(vals[-3:])
            elif tok[0] == "vn":
                vns.append(_numbers(tok[1:4], path, no, "normal"))
            elif tok[0] == "vt":
                vals = _numbers(tok[1:], path, no, "texture coordinate")
                w_used = w_used or (len(vals) > 2 and vals[2] != 0.0)
                vts.append((vals + [0.0, 0.0])[:2])
            elif tok[0] == "f":
                try:
                    parts = [t.split("/") for t in tok[1:]]
                    idx = [int(p[0]) for p in parts]
                    tex = [int(p[1]) if len(p) > 1 and p[1] else None for p in parts]
                except ValueError:
                    raise PointCloudError(f"cannot read {path!r}: line {no}: face "
                                          f"{' '.join(tok[1:])!r} is not numeric") from None
                n, m = len(verts), len(vts)
                idx = [i - 1 if i > 0 else n + i for i in idx]
                faces.extend(_triangles(idx))
                n_tri.append(max(len(idx) - 2, 0))
                corner_vt.append(None if None in tex else
                                 [t - 1 if t > 0 else m + t for t in tex])
                state.append(tuple(now.values()))
            elif tok[0] in keys:
                key = keys[tok[0]]
                text = " ".join(tok[1:])
                if text not in names[key]:
                    names[key].append(text)
                now[key] = names[key].index(text)
                seen.add(key)
            elif tok[0] == "mtllib":
                mtllib.append(" ".join(tok[1:]))
            elif tok[0] in chains:
                try:
                    idx = [int(t.split("/")[0]) for t in tok[1:]]
                except ValueError:
                    raise PointCloudError(f"cannot read {path!r}: line {no}: {tok[0]} "
                                          f"{' '.join(tok[1:])!r} is not numeric") from None
                n = len(verts)
                chains[tok[0]].append(np.array([i - 1 if i > 0 else n + i for i in idx],
                                               dtype=np.int64))
    if not verts:
        raise PointCloudError(f"cannot read {path!r}: the file holds no vertices")
    pts = np.array(verts, dtype=np.float64)
    colors = None
    if cols:
        if len(cols) != len(verts):
            raise PointCloudError(f"cannot read {path!r}: {len(cols)} of {len(verts)} "
                                  "vertices carry a colour")
        colors = np.c_[np.array(cols, dtype=np.float64), np.ones(len(cols))]
    normals = np.array(vns, dtype=np.float64) if len(vns) == len(verts) else None
    tri = _check_faces(np.array(faces, dtype=np.int64).reshape(-1, 3), len(pts), path)
    values, lost = {}, []
    if tri is not None:
        values, lost = _obj_face_values(path, corner_vt, n_tri, vts, w_used, state, seen)
        lost += ["normals per corner"] * (len(vns) > 0 and normals is None)
    for key, rows in chains.items():
        if any(len(r) and (r.min() < 0 or r.max() >= len(pts)) for r in rows):
            raise PointCloudError(f"cannot read {path!r}: a {key} line refers to a vertex "
                                  f"that does not exist ({len(pts)} vertices)")
    meta = {"format": ".obj", "face_properties": tuple(lost),
            "obj": {"mtllib": mtllib, **{k: v for k, v in names.items() if k in seen},
                    **{OBJ_CHAINS[k]: v for k, v in chains.items() if v}}}
    return Cloud(pts, normals, colors, None, tri, label=os.path.basename(path), meta=meta,
                 face_attributes=values)


def _obj_face_values(path, corner_vt, n_tri, vts, w_used, state, seen):
    """``(face attributes, unkept names)`` of an OBJ's faces (``_read_obj``)."""
    from .ply import fan_corners

    values, lost = {}, []
    n_tri = np.asarray(n_tri, dtype=np.int64)
    textured = [c is not None for c in corner_vt]
    if any(textured) and not all(textured):
        lost.append("texture coordinates (on some faces only)")
    elif any(textured) and w_used:
        lost.append("texture coordinates (u v w)")
    elif any(textured):
        flat = np.fromiter((t for c in corner_vt for t in c), dtype=np.int64)
        if len(flat) and (flat.min() < 0 or flat.max() >= len(vts)):
            raise PointCloudError(f"cannot read {path!r}: a face refers to a texture "
                                  f"coordinate that does not exist ({len(vts)} of them)")
        sizes = np.fromiter(map(len, corner_vt), dtype=np.int64, count=len(corner_vt))
        uv = np.asarray(vts, dtype=np.float64)[flat[fan_corners(sizes)]]  # (t, 3, 2)
        values["texcoord"] = uv.reshape(len(uv), 6)
    table = np.repeat(np.asarray(state, dtype=np.int32).reshape(-1, 4), n_tri, axis=0)
    for j, key in enumerate(("object", "group", "material", "smoothing")):
        if key in seen:
            values[key] = table[:, j].copy()
    return values, lost


def _check_faces(faces: np.ndarray, n: int, path: str) -> np.ndarray | None:
    if not len(faces):
        return None
    if faces.min() < 0 or faces.max() >= n:
        raise PointCloudError(f"cannot read {path!r}: a face refers to a vertex that does "
                              f"not exist ({n} vertices)")
    return faces


def _read_off(path: str) -> Cloud:
    with open(path, encoding="utf-8", errors="replace") as f:
        lines = [(no, ln.split("#", 1)[0].split()) for no, ln in enumerate(f, 1)]
    lines = [(no, tok) for no, tok in lines if tok]
    if not lines or not lines[0][1][0].endswith("OFF"):
        raise PointCloudError(f"cannot read {path!r}: not an OFF file (no OFF header)")
    kind = lines[0][1][0]
    rest = lines[0][1][1:]
    body = lines[1:]
    if not rest:
        rest, body = body[0][1], body[1:]
    nv, nf = (int(v) for v in _numbers(rest[:2], path, lines[0][0], "counts"))
    if len(body) < nv + nf:
        raise PointCloudError(f"cannot read {path!r}: the header declares {nv} vertices and "
                              f"{nf} faces, the file holds {len(body)} rows")
    if len(body) > nv + nf:
        raise PointCloudError(f"cannot read {path!r}: data continues after the {nv} vertices "
                              f"and {nf} faces the header declares")
    width = 3 + 3 * ("N" in kind) + 4 * ("C" in kind)
    rows = [_numbers(tok, path, no, "vertex") for no, tok in body[:nv]]
    if any(len(r) < 3 + 3 * ("N" in kind) for r in rows):
        raise PointCloudError(f"cannot read {path!r}: a vertex row has too few values for {kind}")
    pts = np.array([r[:3] for r in rows], dtype=np.float64)
    normals = np.array([r[3:6] for r in rows]) if "N" in kind else None
    colors = None
    if "C" in kind:
        c = np.array([(r[width - 4:width] + [255.0])[:4] if len(r) >= width - 1 else
                      [255.0] * 4 for r in rows])
        colors = c / 255.0 if c.max() > 1.0 else c
    faces, extra, n_tri, floats = [], [], [], False
    for no, tok in body[nv:]:
        vals = _numbers(tok, path, no, "face")
        count = int(vals[0])
        faces.extend(_triangles([int(v) for v in vals[1:1 + count]]))
        n_tri.append(max(count - 2, 0))
        extra.append(vals[1 + count:])
        floats = floats or any(not t.lstrip("+-").isdigit() for t in tok[1 + count:])
    tri = _check_faces(np.array(faces, dtype=np.int64).reshape(-1, 3), nv, path)
    values, lost = _off_face_colours(extra, n_tri, floats)
    if tri is None:
        values, lost = {}, ()
    return Cloud(pts, normals, colors, None, tri, label=os.path.basename(path),
                 meta={"format": ".off", "face_properties": lost}, face_attributes=values)


#: the face attributes an OFF file holds, after each face's indices
OFF_FACE = ("red", "green", "blue", "alpha")


def _off_face_colours(extra: list, n_tri: list, floats: bool):
    """``(face attributes, unkept)`` of the values after each OFF face's
    indices: a colour of 3 or 4 values on every face, as ``red green blue
    [alpha]`` (uint8 where every value is an integer, else float64 in
    [0, 1]; a face without alpha among faces with one is opaque) on each
    triangle of the face's fan; any other layout (a colour map index,
    colours on some faces only) is named as not kept."""
    sizes = {len(e) for e in extra}
    if sizes <= {0}:
        return {}, ()
    if not sizes <= {3, 4}:
        return {}, ("face colours",)
    opaque = 1.0 if floats else 255.0  # a face without alpha, among faces with one
    rows = [e + [opaque] * (max(sizes) - len(e)) for e in extra]
    table = np.repeat(np.array(rows, dtype=np.float64), n_tri, axis=0)
    if not floats and table.min() >= 0 and table.max() <= 255:
        table = table.astype(np.uint8)
    return {name: table[:, j].copy() for j, name in enumerate(OFF_FACE[:table.shape[1]])}, ()


def _write_xyz(cloud: Cloud, path) -> None:
    """``cloud``'s rows as XYZ into ``path`` (a file name, or an open file a
    streamed write appends block after block to)."""
    cols = cloud.points if cloud.normals is None else np.c_[cloud.points, cloud.normals]
    np.savetxt(path, cols, fmt=_FMT)


#: an OBJ's statements that list vertex rows besides faces, by their key in
#: ``meta["obj"]``: ``l`` polylines, ``p`` point groups (``chains_after``)
OBJ_CHAINS = {"l": "polylines", "p": "point groups"}


def chains_after(info: dict, idx: np.ndarray, n: int) -> dict:
    """``meta["obj"]`` after a subset that kept rows ``idx`` of ``n``: each
    polyline renumbered and cut where it meets a removed vertex (the pieces
    of two vertices or more kept), each point group renumbered without the
    removed vertices (empty ones left out)."""
    if not any(info.get(k) for k in OBJ_CHAINS.values()):
        return info
    new = np.full(n, -1, dtype=np.int64)
    new[idx] = np.arange(len(idx))
    out = dict(info)
    for key, least in (("polylines", 2), ("point groups", 1)):
        kept = []
        for rows in info.get(key, ()):
            r = new[rows]
            if key == "point groups":
                pieces = [r[r >= 0]]
            else:
                pieces = np.split(r, np.flatnonzero(r < 0))
                pieces = [p[p >= 0] for p in pieces]
            kept += [p for p in pieces if len(p) >= least]
        if key in info:
            out[key] = kept
    return out


#: the face attributes an OBJ file holds: ``texcoord`` (u v per corner) as
#: ``vt`` lines, the others as the lines that switch them, by their names in
#: ``meta["obj"]``
OBJ_FACE = ("texcoord", "object", "group", "material", "smoothing")
_OBJ_SWITCH = {"object": "o ", "group": "g ", "material": "usemtl ", "smoothing": "s "}


def _write_obj(cloud: Cloud, path: str) -> None:
    """The lines ``_read_obj`` reads back: the ``mtllib`` lines, normals,
    vertices, a face's three texture coordinates as ``vt`` lines, the faces,
    with a ``o``/``g``, ``usemtl`` or ``s`` line wherever the face's group,
    material or smoothing group changes, then the ``l`` and ``p`` lines."""
    values = cloud.face_attributes if cloud.faces is not None else {}
    info = cloud.meta.get("obj", {})
    for key in _OBJ_SWITCH:
        if key in values and len(values[key]) and values[key].max() >= len(info.get(key, ())):
            raise PointCloudError(f"cannot write {path!r}: face attribute {key!r} holds an "
                                  f"index with no name in the input's {key} names")
    tex = values.get("texcoord")
    if tex is not None and np.shape(tex)[1:] != (6,):
        raise PointCloudError(f"cannot write {path!r}: OBJ holds a u v per corner, the "
                              f"faces' texcoord holds {np.shape(tex)[1]} values per face")
    with open(path, "w", encoding="utf-8") as f:
        f.write(f"# written by pcprep: {len(cloud)} vertices\n")
        for lib in info.get("mtllib", ()) if "material" in values else ():
            f.write(f"mtllib {lib}\n")
        if cloud.normals is not None:
            for row in cloud.normals:
                f.write("vn " + " ".join(_FMT % v for v in row) + "\n")
        cols = cloud.points if cloud.colors is None else np.c_[cloud.points, cloud.colors[:, :3]]
        for row in cols:
            f.write("v " + " ".join(_FMT % v for v in row) + "\n")
        if cloud.faces is not None:
            _write_obj_faces(f, cloud, values, info)
        for key, word in (("polylines", "l"), ("point groups", "p")):
            for rows in info.get(key, ()):
                f.write(word + " " + " ".join(str(int(i) + 1) for i in rows) + "\n")


def _write_obj_faces(f, cloud: Cloud, values: dict, info: dict) -> None:
    """The ``vt`` and ``f`` lines of ``_write_obj``, with the lines that switch
    a face's object, group, material and smoothing group."""
    tex = values.get("texcoord")
    if tex is not None:
        np.savetxt(f, np.asarray(tex, np.float64).reshape(-1, 2), fmt=f"vt {_FMT} {_FMT}")
    rows = cloud.faces + 1
    if tex is not None:  # v/vt, the corners' vt lines in face order
        t = np.arange(1, 3 * len(rows) + 1).reshape(-1, 3)
        rows = np.stack([rows, t], axis=2).reshape(len(rows), 6)
        fmt = "f %d/%d %d/%d %d/%d"
    else:
        fmt = "f %d %d %d"
    keys = [k for k in _OBJ_SWITCH if k in values]
    state = np.stack([np.asarray(values[k]) for k in keys], axis=1) if keys else None
    starts = [0] if state is None else \
        [0, *(np.flatnonzero((np.diff(state, axis=0) != 0).any(axis=1)) + 1)]
    for a, b in zip(starts, [*starts[1:], len(rows)]):
        for j, key in enumerate(keys):
            i = int(state[a, j])
            if i >= 0 and (a == 0 or state[a - 1, j] != i):
                f.write(f"{_OBJ_SWITCH[key]}{info[key][i]}\n")
        np.savetxt(f, rows[a:b], fmt=fmt)


def _write_off(cloud: Cloud, path: str) -> None:
    kind = ("C" if cloud.colors is not None else "") + \
        ("N" if cloud.normals is not None else "") + "OFF"
    nf = 0 if cloud.faces is None else len(cloud.faces)
    cols = [cloud.points]
    if cloud.normals is not None:
        cols.append(cloud.normals)
    if cloud.colors is not None:
        cols.append(cloud.colors)
    with open(path, "w", encoding="utf-8") as f:
        f.write(f"{kind}\n{len(cloud)} {nf} 0\n")
        np.savetxt(f, np.hstack(cols), fmt=_FMT)
        if nf:
            table = np.c_[np.full(nf, 3), cloud.faces].astype(np.float64)
            fmt = ["%d"] * 4
            for name in OFF_FACE:  # ``check_faces`` allows no other face attribute
                if name in cloud.face_attributes:
                    v = np.asarray(cloud.face_attributes[name])
                    table = np.c_[table, v.astype(np.float64)]
                    # a float always with its point, or "1 0 0" would read as 0-255
                    fmt.append("%d" if v.dtype.kind in "ui" else "%#.17g")
            np.savetxt(f, table, fmt=fmt)
