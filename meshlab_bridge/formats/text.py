"""
text.py
-------
The plain-text formats XYZ, OBJ and OFF, read and written here at full
precision (17 significant digits), every row kept.  pymeshlab's readers skip
rows they cannot parse (a NaN row vanishes and every later index shifts; an OBJ
line ``v abc def ghi`` becomes a point at the origin) and its writers keep six
digits, so pcprep does these itself: a malformed row is an error naming its line.

XYZ holds ``x y z`` or ``x y z nx ny nz`` per line (``#`` comments).  OBJ keeps
``v x y z [r g b]``, ``vn`` (as vertex normals when there is one per vertex)
and ``f`` (polygons fan-triangulated; ``i/j/k`` indices and negative indices
understood).  OFF, COFF, NOFF and CNOFF keep positions, normals, colours and
faces, and a colour per face (``r g b [a]`` after its indices, integers 0–255
or floats 0–1) as the face attributes ``red green blue [alpha]``.
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
    verts, cols, vns, faces = [], [], [], []
    textured = materials = False
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
            elif tok[0] == "f":
                textured = textured or any(len(t.split("/")) > 1 and t.split("/")[1]
                                           for t in tok[1:])
                try:
                    idx = [int(t.split("/")[0]) for t in tok[1:]]
                except ValueError:
                    raise PointCloudError(f"cannot read {path!r}: line {no}: face "
                                          f"{' '.join(tok[1:])!r} is not numeric") from None
                n = len(verts)
                idx = [i - 1 if i > 0 else n + i for i in idx]
                faces.extend(_triangles(idx))
            elif tok[0] == "usemtl":
                materials = True
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
    # what the faces carry that pcprep does not keep (formats.check_faces)
    carried = (("texture coordinates",) * textured + ("materials (usemtl)",) * materials
               + ("normals per corner",) * (len(vns) > 0 and normals is None))
    return Cloud(pts, normals, colors, None, tri, label=os.path.basename(path),
                 meta={"format": ".obj", "face_properties": carried})


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


def _write_obj(cloud: Cloud, path: str) -> None:
    with open(path, "w", encoding="utf-8") as f:
        f.write(f"# written by pcprep: {len(cloud)} vertices\n")
        if cloud.normals is not None:
            for row in cloud.normals:
                f.write("vn " + " ".join(_FMT % v for v in row) + "\n")
        cols = cloud.points if cloud.colors is None else np.c_[cloud.points, cloud.colors[:, :3]]
        for row in cols:
            f.write("v " + " ".join(_FMT % v for v in row) + "\n")
        if cloud.faces is not None:
            for a, b, c in cloud.faces + 1:
                f.write(f"f {a} {b} {c}\n")


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
