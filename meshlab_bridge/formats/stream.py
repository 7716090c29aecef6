"""
stream.py
---------
Streamed reading and writing for tiled runs of clouds larger than memory.

``position_chunks(path)`` yields ``(start, xyz)`` blocks without loading the
file: LAS/LAZ through laspy's chunk iterator, binary PLY and PCD memory-mapped,
ASCII PLY of vertices alone, ASCII PCD and XYZ parsed block by block, E57
through libe57's reader with block-sized buffers; the other formats are read
whole.  ``write_streamed`` writes a
filter's per-row results (arrays or memory maps, in input order) with every
input attribute kept, block by block where the input is LAS/LAZ, XYZ, E57,
PCD, a PLY of vertices alone or a binary PLY of triangles: to LAS/LAZ (laspy's writer;
from LAS/LAZ under the input's header, new results as extra dimensions, a
removal copying the kept rows' records as they are; from another format under
the header ``las.write`` gives the whole result, its scale and offset from a
first pass over the written rows' positions), to PLY (plyfile's header, then
the rows, binary or ASCII as the input, then a mesh's triangles and other
elements; the same bytes ``ply.write`` gives the whole result), to XYZ,
to binary PCD and to E57 (the columns gathered on disk, then pye57 writes the
scan from memory maps of them).  The inputs read whole go through
``read_cloud``/``write_cloud`` with the cloud in memory.  Every write is
atomic; a reader refuses what reading the whole file refuses.
"""

from __future__ import annotations

import os
from functools import partial
from types import SimpleNamespace

import numpy as np

from pcprep.filters._validation import PointCloudError

from . import _ext, _temporary, check_kept, read_cloud
from .las import laz_backend

#: rows per streamed chunk
CHUNK = 1 << 20
#: input rows per block of a streamed write: each block is a whole ``Cloud``
#: with every attribute and its output record, about 170 B per row.  Writing a
#: holes result over 10^6 LAZ points took the same time in blocks of 2^18 and
#: 2^20 rows, at 153 against 250 MB anonymous memory.
WRITE_ROWS = 1 << 18
_STREAMED = (".las", ".laz")


def point_count(path) -> int:
    path = os.fspath(path)
    ext = _ext(path)
    if ext in _STREAMED:
        import laspy

        try:
            with laspy.open(path) as f:
                return int(f.header.point_count)
        except (laspy.errors.LaspyException, ValueError) as exc:
            raise PointCloudError(f"cannot read {path!r}: {exc}") from exc
    if ext == ".xyz":
        from . import text

        return text.xyz_count(path)
    if ext == ".e57":
        from . import e57

        return e57.point_count(path)
    if ext == ".pcd":
        from . import pcd

        rows, head = pcd.binary_rows(path)
        if rows is not None:
            return len(rows)
        if head["DATA"][0] == "ascii":
            return pcd._count(head)
    if ext == ".ply":
        ply = _ply_mmap(path)
        if ply is not None:
            return int(ply["vertex"].count)
        from .ply import ascii_header

        head = ascii_header(path)
        if head is not None:
            return head[1]
    return len(read_cloud(path))


def _ply_mmap(path):
    """A binary PLY's ``PlyData``, its vertices memory-mapped and its rows
    checked against the header (``ply.load``); None for ASCII PLY."""
    from . import ply

    with open(path, "rb") as f:
        head = f.read(512)
    if b"format ascii" in head:
        return None
    return ply.load(path)


def position_chunks(path, size: int = CHUNK):
    """``(start, (m, 3) float64)`` blocks of the file's positions, in order."""
    path = os.fspath(path)
    ext = _ext(path)
    if ext in _STREAMED:
        import laspy

        try:
            with laspy.open(path, laz_backend=laz_backend()) as f:
                start, declared = 0, int(f.header.point_count)
                for pts in f.chunk_iterator(size):
                    xyz = np.column_stack([np.asarray(pts.x, np.float64),
                                           np.asarray(pts.y, np.float64),
                                           np.asarray(pts.z, np.float64)])
                    yield start, xyz
                    start += len(xyz)
        except (laspy.errors.LaspyException, RuntimeError, ValueError) as exc:
            # lazrs: RuntimeError; a LAS cut inside a record: ValueError
            raise PointCloudError(f"cannot read {path!r}: {exc} (truncated or damaged "
                                  "file?)") from exc
        if start != declared:  # laspy stops quietly where a LAS file ends
            raise PointCloudError(f"cannot read {path!r}: the header declares {declared} "
                                  f"points, the file holds {start}")
        return
    if ext == ".xyz":
        from . import text

        for s, data in text.xyz_blocks(path, size):
            yield s, np.ascontiguousarray(data[:, :3])
        return
    if ext == ".e57":
        from . import e57

        for s, cloud in e57.blocks(path, size, attributes=False):
            yield s, cloud.points
        return
    if ext == ".pcd":
        from . import pcd

        rows, head = pcd.binary_rows(path)
        if rows is not None:
            yield from _record_positions(rows, size)
            return
        if head["DATA"][0] == "ascii":
            for s, data in pcd.ascii_rows(path, size):
                yield from _record_positions(data, size, s)
            return
    ply = _ply_mmap(path) if ext == ".ply" else None
    if ply is not None:
        yield from _record_positions(ply["vertex"].data, size)
        return
    from .ply import ascii_header, ascii_vertex_blocks

    head = ascii_header(path) if ext == ".ply" else None
    if head is not None:
        for s, rows in ascii_vertex_blocks(path, size, head):
            yield from _record_positions(rows, size, s)
        return
    pts = read_cloud(path).points
    for s in range(0, len(pts), size):
        yield s, pts[s:s + size]


def _record_positions(rows: np.ndarray, size: int, first: int = 0):
    """``(start, xyz)`` blocks of (memory-mapped) records with fields x, y, z,
    the first of them row ``first`` of the file."""
    for s in range(0, len(rows), size):
        block = rows[s:s + size]
        yield first + s, np.column_stack([np.asarray(block[c], np.float64) for c in "xyz"])


def normals_into(path, n: int, out: str):
    """The file's normals (LAS ``NormalX/Y/Z`` or its other names, PLY ``nx ny
    nz``, XYZ columns 4–6, …) streamed into a float64 (n, 3) memory map at
    ``out``, for a tiled filter that uses them as its one-piece run does; None
    where the file has none (nothing written)."""
    path = os.fspath(path)
    blocks = _block_reader(path)
    parts = ((0, read_cloud(path)) for _ in (0,)) if blocks is None else blocks(CHUNK)
    arr = None
    for start, cloud in parts:
        if cloud.normals is None:  # the first block says: the file has none
            parts.close()
            return None
        if arr is None:
            from ..tiles import open_scratch

            arr = open_scratch(out, (n, 3))
        arr[start:start + len(cloud)] = cloud.normals
    if arr is not None:
        arr.flush()
    return arr


def write_streamed(spec, src, dst, fields: dict, *, size: int = WRITE_ROWS,
                   n: int | None = None, drop_faces: bool = False,
                   drop_face_properties: bool = False, drop_elements: bool = False) -> int:
    """Write ``spec``'s result over ``src`` to ``dst``: ``fields`` holds the
    result's per-row arrays in input order (``keep_idx`` for a removal); ``n``
    is the input's row count where the caller has it (``point_count``, which
    for XYZ reads the file); ``drop_faces``: write the vertices without the
    input's faces; ``drop_face_properties``: the faces without the
    properties they carry (``check_faces``); ``drop_elements``: without a
    PLY's other elements (``check_elements``).  Returns the number of rows
    written."""
    src, dst = os.fspath(src), os.fspath(dst)
    blocks = _block_reader(src)
    to = _ext(dst)
    if blocks is None or to not in (".ply", ".xyz", ".pcd", ".e57") + _STREAMED:
        # no chunked reader or writer for the pair: the cloud in memory, written whole
        from . import write_cloud

        cloud = _dropped(read_cloud(src), drop_faces, drop_face_properties, drop_elements)
        keep = _kept(spec, fields, len(cloud))
        out = next(_results(spec, iter([(0, cloud)]), fields, keep, dst))
        write_cloud(out, dst)
        return len(out)
    tail = _check_tail(src, dst, drop_faces, drop_face_properties, drop_elements)
    n = point_count(src) if n is None else n
    keep = _kept(spec, fields, n)
    if to == ".ply":
        return _write_ply(lambda: _results(spec, blocks(size), fields, keep, dst), dst,
                          tail, keep)
    if to == ".xyz":
        return _write_xyz(_results(spec, blocks(size), fields, keep, dst), dst)
    if to == ".e57":
        from . import e57

        return e57.write_blocks(_results(spec, blocks(size), fields, keep, dst), dst)
    if to == ".pcd":
        count = n if keep is None else keep.count
        return _write_pcd(_results(spec, blocks(size), fields, keep, dst), dst, count)
    if _ext(src) not in _STREAMED:  # a new header, over every written row's position
        return _write_las(_results(spec, blocks(size), fields, keep, dst), dst,
                          _header_over(_results(spec, blocks(size), fields, keep, dst)))
    if keep is not None and not spec.scalar_field:
        return _write_kept_records(src, dst, keep, size)
    return _write_las(_results(spec, blocks(size), fields, keep, dst), dst)


def check_fields(src, dst, *, drop_faces: bool = False, drop_face_properties: bool = False,
                 drop_elements: bool = False) -> None:
    """Refuse, before a tiled run, a destination whose format cannot store the
    input's normals, colours, quality, attributes or faces, or faces that
    carry properties, as the one-piece run refuses it once the cloud is read
    (``check_kept``): on the first block of a format read in blocks (and the
    faces of a mesh read so), on the whole cloud of a format read whole
    (which the run reads whole as well).  ``drop_faces``: the output is to
    hold no faces; ``drop_face_properties``: its faces are to be written
    without their properties; ``drop_elements``: without a PLY's other
    elements.  An input ``read_cloud`` cannot read is refused here too, not
    at the write after the run."""
    src, dst = os.fspath(src), os.fspath(dst)
    drops = (drop_faces, drop_face_properties, drop_elements)
    blocks = _block_reader(src)
    if blocks is None:
        check_kept(_dropped(read_cloud(src), *drops), dst)
        return
    _check_tail(src, dst, *drops)
    if _ext(src) == ".e57":  # which fields, not their values: no pass over the colours
        from . import e57

        blocks = partial(e57.blocks, src, colour_pass=False)
    for _, cloud in blocks(1024):
        check_kept(cloud, dst)
        return


def _dropped(cloud, drop_faces: bool, drop_face_properties: bool,
             drop_elements: bool = False):
    """``cloud`` without the faces, their properties or the PLY's other
    elements, as the user dropped them."""
    from . import drop_elements as without_elements
    from . import drop_face_properties as without

    if drop_faces:
        cloud = cloud.with_(faces=None)
    cloud = without(cloud) if drop_face_properties else cloud
    return without_elements(cloud) if drop_elements else cloud


def _check_tail(src: str, dst: str, drop_faces: bool, drop_face_properties: bool,
                drop_elements: bool = False):
    """``check_faces`` on a mesh read in blocks (its faces and other
    elements are in its ``mesh_tail``, not in the blocks), and
    ``check_elements`` where ``dst`` is not a PLY; returns that tail,
    without the faces or elements dropped."""
    from . import check_elements, check_faces

    tail = mesh_tail(src)
    if tail is None:
        return tail
    tri, others = tail
    if drop_elements:
        others = []
    if _ext(dst) != ".ply":
        check_elements([el.name for el in others], dst)
    if tri is None or drop_faces:
        return None, others
    tri = tri.without_values() if drop_face_properties else tri
    check_faces(len(tri), dst, (), tri.names)  # a mesh read in blocks keeps them all
    return tri, others


def _header_over(outputs):
    """``las.new_header`` over the rows of ``outputs`` (a first pass over the
    result): the header ``las.write`` gives the whole result, whose scale and
    offset depend on every row's position."""
    from . import las

    lo, hi, colors = np.full(3, np.inf), np.full(3, -np.inf), False
    for out in outputs:
        colors = colors or out.colors is not None
        if len(out):
            lo = np.minimum(lo, out.points.min(axis=0))
            hi = np.maximum(hi, out.points.max(axis=0))
    if not np.isfinite(lo).all():  # nothing to write
        lo = hi = np.zeros(3)
    return las.new_header(lo, hi, colors)


def _kept(spec, fields: dict, n: int):
    """A removal's or new layer's kept rows (``_Kept``), None for other kinds."""
    if spec.kind not in ("remove", "new_layer"):
        return None
    return _Kept(fields[spec.index_field], n)


class _Kept:
    """The kept rows of n input rows, from their increasing indices (a memory
    map in a tiled run), read per block by binary search: no mask of the
    input's length in memory.  The indices are checked increasing and in
    range, chunk by chunk, since a binary search over others would pick
    wrong rows silently."""

    def __init__(self, idx, n: int):
        self.idx, self.count = idx, len(idx)
        last = -1
        for s0 in range(0, self.count, CHUNK):
            part = np.asarray(idx[s0:s0 + CHUNK])
            if part[0] <= last or (np.diff(part) <= 0).any() or part[-1] >= n:
                raise PointCloudError(f"the kept rows must be increasing indices "
                                      f"below {n}")
            last = part[-1]

    def rows(self, start: int, m: int) -> np.ndarray:
        """The kept rows among ``start:start + m``, relative to ``start``."""
        lo, hi = np.searchsorted(self.idx, [start, start + m])
        return np.asarray(self.idx[lo:hi], dtype=np.int64) - start


def _block_reader(src: str):
    """``size -> iterator of (start, Cloud)`` over ``src``'s rows in blocks,
    every attribute kept, for LAS/LAZ, XYZ, E57, PCD, PLY holding vertices
    alone and binary PLY of triangles (the vertices; the triangles are
    ``mesh_tail``'s); None for the formats read whole."""
    ext = _ext(src)
    if ext in _STREAMED:
        import laspy

        from . import las

        def las_blocks(size):
            with laspy.open(src, laz_backend=laz_backend()) as reader:
                start = 0
                for pts in reader.chunk_iterator(size):
                    yield start, las.to_cloud(laspy.LasData(header=reader.header,
                                                            points=pts), src)
                    start += len(pts)

        return las_blocks
    if ext == ".xyz":
        from . import text

        return lambda size: ((s, text.xyz_cloud(data, src))
                             for s, data in text.xyz_blocks(src, size))
    if ext == ".e57":
        from . import e57

        return lambda size: e57.blocks(src, size)
    if ext == ".pcd":
        from . import pcd

        if pcd.data_kind(src) in ("binary", "ascii"):
            return lambda size: pcd.blocks(src, size)
        return None
    from . import ply

    head = ply.ascii_header(src) if ext == ".ply" else None
    if head is not None:
        return lambda size: ((s, ply.vertex_cloud(rows, head[0], src, head[1]))
                             for s, rows in ply.ascii_vertex_blocks(src, size, head))
    ply_data = _ply_mmap(src) if ext == ".ply" else None
    if ply_data is None or ply.mesh_tail(ply_data, src) is None or ply.vertex_lists(ply_data):
        return None  # faces that are not all triangles, or lists in another element

    def ply_blocks(size):
        v = ply_data["vertex"]
        for s in range(0, v.count, size):
            yield s, ply.vertex_cloud(np.array(v.data[s:s + size]), ply_data, src)

    return ply_blocks


def _results(spec, blocks, fields: dict, keep, dst: str):
    """The output cloud of each block: the filter's result on its rows (with
    MeshLab's quality ramp as colours for a scalar), refused where ``dst``'s
    format would lose one of its fields (``check_kept``)."""
    from ..apply import result_cloud
    from ..convert import quality_ramp

    for start, block in blocks:
        out = result_cloud(spec, block, _chunk_result(spec, fields, start, len(block), keep),
                           dst=dst)
        check_kept(out, dst)
        if spec.kind == "scalar" and out.quality is not None:
            out = out.with_(colors=quality_ramp(out.quality))
        yield out


def _write_las(outputs, dst: str, header=None) -> int:
    """LAS/LAZ block by block under ``header`` (by default the input's; new
    results as extra dimensions) with laspy's writer, then the input's
    extended VLRs (laspy's writer leaves them to its caller)."""
    import laspy

    from . import las

    written = 0
    with _temporary(dst) as tmp:
        writer = None
        try:
            for out in outputs:
                if writer is None:
                    header, _ = las.output_header(out, dst, base=header)
                    writer = laspy.open(tmp, mode="w", header=header,
                                        laz_backend=laz_backend(),
                                        do_compress=dst.lower().endswith(".laz"))
                rec = las.record(out, header, las.output_columns(out, header), dst)
                writer.write_points(rec.points)
                written += len(out)
            if writer is not None and getattr(header, "evlrs", None):
                writer.write_evlrs(header.evlrs)  # after the points, as las.write does
        finally:
            if writer is not None:
                writer.close()
    return written


def _write_xyz(outputs, dst: str) -> int:
    """XYZ block by block (the lines ``text`` writes for the whole result)."""
    from . import text

    written = 0
    with _temporary(dst) as tmp, open(tmp, "wb") as f:
        for out in outputs:
            text._write_xyz(out, f)
            written += len(out)
    return written


def _write_pcd(outputs, dst: str, count: int) -> int:
    """Binary PCD block by block: the header (of ``count`` rows) from the first
    block's record type, which every block shares, then each block's records."""
    from . import pcd

    written = 0
    with _temporary(dst) as tmp, open(tmp, "wb") as f:
        for out in outputs:
            data = pcd.records(out)
            if f.tell() == 0:
                f.write(pcd.header(data.dtype, count, out.meta.get("pcd", {})))
            f.write(data.tobytes())
            written += len(out)
        if written != count:  # the header would lie: nothing is kept
            raise RuntimeError(f"{dst}: {written} rows written, {count} declared")
    return written


def mesh_tail(src: str):
    """``ply.mesh_tail`` of a binary PLY read in blocks; None for other files."""
    from . import ply

    ply_data = _ply_mmap(src) if _ext(src) == ".ply" else None
    return None if ply_data is None else ply.mesh_tail(ply_data, src)


def _write_ply(outputs, dst: str, tail=None, keep=None) -> int:
    """PLY block by block, binary or ASCII as the input, the same file
    ``ply.write`` makes of the whole result.  A column keeps the input's type only where every row's value
    fits it, so a first pass over the blocks settles each column's type (and
    whether an alpha is written) and the row count for the header; the second
    writes the rows.  ``outputs()`` gives the blocks' output clouds afresh.
    ``tail``: a binary mesh's triangles and other elements (``mesh_tail``),
    written after the vertices as the whole write does: the triangles whose
    vertices are all kept (``keep``), renumbered, counted in a first pass
    over them, and the other elements where every vertex is kept."""
    from . import ply

    types: dict = {}
    alpha, count, info = False, 0, {}
    for out in outputs():
        info = out.meta.get("ply", {})
        cols = ply.vertex_columns(out)
        alpha = alpha or "alpha" in cols
        for n, v in cols.items():
            types[n] = ply.wider_type(n, types[n], v.dtype, info) if n in types else v.dtype
        count += len(out)
    tri, others = (None, []) if tail is None else tail
    kept = None if keep is None else keep.idx
    faces = 0 if tri is None else sum(len(b) for b in ply.kept_triangles(tri, kept))
    face_layout = None if tri is None else ply.face_layout(tri.values(0, 0), info)
    elements = [ply.face_element(faces, face_layout)] if faces else []
    from . import check_elements

    kept_rows = None if keep is None else keep.idx
    written = ply.kept_elements(others, count, info, kept_rows, increasing=True)
    names = {w.name for w in written}
    check_elements([el.name for el in others if el.name not in names], dst)
    others = written
    written = 0
    with _temporary(dst) as tmp, open(tmp, "wb") as f:
        rows = None
        for out in outputs():
            cols = ply.vertex_columns(out, alpha=alpha)
            if rows is None:
                layout = {n: types[n] for n in cols}
                f.write(ply.header(layout, count, info, elements + others))
                rows = ply.row_type(layout, info)
            if info.get("text"):
                f.write(ply.text_rows(cols, layout))
            else:
                f.write(ply.vertex_rows(cols, {n: rows[n] for n in cols}).tobytes())
            written += len(out)
        order = info.get("byte_order", "<")
        if faces:
            for block, values in ply.kept_triangles(tri, kept, values=True):
                f.write(ply.face_records(ply.face_rows(block, values, face_layout),
                                         elements[0], order))
        for el in others:
            f.write(ply.element_bytes(el, order))
    return written


def _write_kept_records(src: str, dst: str, keep: _Kept, size: int) -> int:
    """A removal with nothing added, LAS/LAZ to LAS/LAZ: the kept rows' point
    records copied as they are under the input's header (laspy's writer sets
    the count and bounds).  The records are the ones the general path would
    rebuild from a ``Cloud``, without its conversions (0.36 s instead of
    0.47 s to write 10⁶ LAZ points here)."""
    import laspy

    written = start = 0
    with _temporary(dst) as tmp, laspy.open(src, laz_backend=laz_backend()) as reader:
        with laspy.open(tmp, mode="w", header=reader.header, laz_backend=laz_backend(),
                        do_compress=dst.lower().endswith(".laz")) as writer:
            for pts in reader.chunk_iterator(size):
                rows = pts[keep.rows(start, len(pts))]
                writer.write_points(rows)
                written += len(rows)
                start += len(pts)
            if reader.evlrs:
                writer.write_evlrs(reader.evlrs)
    return written


def _chunk_result(spec, fields: dict, start: int, m: int, keep):
    """The filter's result object restricted to rows ``start:start + m``."""
    part = {}
    for name, values in fields.items():
        if name in ("keep_idx", "removed_idx"):
            continue
        part[name] = np.asarray(values[start:start + m])
    if keep is not None:
        part[spec.index_field] = keep.rows(start, m)
    return SimpleNamespace(**part)
