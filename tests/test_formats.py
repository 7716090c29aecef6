"""Files in and out with nothing lost: every attribute and header field survives,
coordinates in projected systems round-trip bit-exactly, malformed rows are
refused by line or row (never dropped or shifted silently), and destinations that
cannot hold a result are refused before any work."""

import os
import stat

import laspy
import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from pcprep import PointCloudError
from pcprep.meshlab_bridge import formats
from pcprep.meshlab_bridge.cli import main
from pcprep.meshlab_bridge.cloud import Cloud

UTM = np.array([452_000.0, 5_213_000.0, 310.0])


def _random_las(path, fmt, n=400, seed=0, version=None):
    """A LAS/LAZ file of point format ``fmt`` with random values in every
    dimension, two extra-byte dimensions and UTM-like offsets."""
    g = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=fmt, version=version or ("1.4" if fmt >= 6 else "1.2"))
    header.add_extra_dims([laspy.ExtraBytesParams("confidence", "f4"),
                           laspy.ExtraBytesParams("tag", "u2")])
    header.offsets, header.scales = UTM, [0.001, 0.001, 0.001]
    las = laspy.LasData(header)
    las.points = laspy.ScaleAwarePointRecord.zeros(n, header=header)
    rec = las.points.array
    for name in rec.dtype.names:
        dt = rec.dtype[name]
        if dt.kind in "ui":
            info = np.iinfo(dt)
            rec[name] = g.integers(max(info.min, -2**31), min(info.max, 2**31 - 1), n,
                                   endpoint=True).astype(dt)
        else:
            rec[name] = g.random(n).astype(dt)
    # a smooth surface, so the filters have something to work on
    xy = g.uniform(0, 20_000, (n, 2)).astype(np.int64)
    las.X, las.Y = xy[:, 0], xy[:, 1]
    las.Z = (2000 * np.sin(xy[:, 0] / 3000.0)).astype(np.int64) + 5000
    if header.version.minor >= 4:  # an extended VLR after the points
        from laspy.vlrs.vlrlist import VLRList

        las.evlrs = VLRList([laspy.VLR("pcprep_test", 7, "an evlr", b"after the points")])
    las.write(str(path))
    return path


@pytest.mark.parametrize("fmt", [1, 3, 6, 7, 8])
@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_las_round_trip_is_bit_exact(tmp_path, fmt, ext):
    src = _random_las(tmp_path / f"in{ext}", fmt)
    cloud = formats.read_cloud(src)
    assert {"intensity", "classification", "gps_time", "confidence", "tag"} <= set(
        cloud.attributes)
    dst = tmp_path / f"out{ext}"
    formats.write_cloud(cloud, dst)
    a, b = laspy.read(str(src)), laspy.read(str(dst))
    assert a.points.array.tobytes() == b.points.array.tobytes()
    assert a.header.point_format.id == b.header.point_format.id
    assert a.header.version == b.header.version
    assert np.array_equal(a.header.scales, b.header.scales)
    assert np.array_equal(a.header.offsets, b.header.offsets)


def test_laz_of_several_chunks_written_with_threads_is_the_single_thread_file(tmp_path):
    """LAZ is read and written with lazrs' threads (``las.laz_backend``); over
    more than one LAZ chunk (50 000 points each) the file must hold what one
    thread writes, byte for byte, and read back the same rows either way."""
    from pcprep.meshlab_bridge.formats import las as las_io, stream

    src = _random_las(tmp_path / "in.laz", 6, n=120_000)
    cloud = formats.read_cloud(src)
    ours, one = tmp_path / "ours.laz", tmp_path / "one.laz"
    formats.write_cloud(cloud, ours)
    laspy.read(str(ours), laz_backend=laspy.LazBackend.Lazrs).write(
        str(one), laz_backend=laspy.LazBackend.Lazrs)
    assert las_io.laz_backend() is laspy.LazBackend.LazrsParallel
    assert ours.read_bytes() == one.read_bytes()
    ref = laspy.read(str(src), laz_backend=laspy.LazBackend.Lazrs)
    got = np.concatenate([b for _, b in stream.position_chunks(ours, size=30_000)])
    assert np.array_equal(got, np.column_stack([ref.x, ref.y, ref.z]))


@pytest.mark.parametrize("fmt", [3, 6, 8])
def test_streamed_removal_writes_the_records_the_whole_cloud_path_writes(tmp_path, fmt):
    """A tiled removal copies the kept rows' LAS records as they are; the file
    must equal, record for record and in its header, the one written from the
    whole cloud in memory (a chunk with no row kept included)."""
    from types import SimpleNamespace

    from pcprep.meshlab_bridge import registry
    from pcprep.meshlab_bridge.apply import result_cloud
    from pcprep.meshlab_bridge.formats import stream

    registry.load_all()
    spec = registry.get("outliers")
    src = _random_las(tmp_path / "in.laz", fmt, n=5000, seed=fmt)
    keep = np.flatnonzero(np.random.default_rng(1).random(5000) < 0.7)
    keep = keep[(keep < 1000) | (keep >= 2000)]  # rows 1000-1999: one chunk, none kept
    whole = tmp_path / "whole.laz"
    formats.write_cloud(result_cloud(spec, formats.read_cloud(src),
                                     SimpleNamespace(**{spec.index_field: keep})), whole)
    streamed = tmp_path / "streamed.laz"
    assert stream.write_streamed(spec, src, streamed, {spec.index_field: keep},
                                 size=1000) == len(keep)
    a, b = laspy.read(str(whole)), laspy.read(str(streamed))
    assert len(b.points) == len(keep) > 0
    assert a.points.array.tobytes() == b.points.array.tobytes()
    for field in ("point_count", "mins", "maxs", "scales", "offsets", "version"):
        assert np.array_equal(getattr(a.header, field), getattr(b.header, field)), field
    assert a.header.point_format.id == b.header.point_format.id
    assert list(a.point_format.dimension_names) == list(b.point_format.dimension_names)
    # the kept rows are read per block by binary search, so indices that do
    # not increase, or reach past the input, are refused, nothing written
    for bad in (keep[::-1], np.r_[keep, keep[-1]], np.r_[keep, 5000]):
        with pytest.raises(PointCloudError, match="increasing indices below 5000"):
            stream.write_streamed(spec, src, tmp_path / "bad.laz",
                                  {spec.index_field: bad}, size=1000)
    assert not (tmp_path / "bad.laz").exists()


def _ply_float32(path, n: int, order: str):
    """A binary PLY of a noisy unit sphere: float32 positions, 8-bit colours,
    an intensity and a confidence, in byte order ``order``; ``"ascii"`` for
    an ASCII PLY of these and a signed 32-bit column (a row of float32 and
    int32 values is written in float64 by plyfile)."""
    g = np.random.default_rng(n)
    extra = [("return", "i4")] if order == "ascii" else []
    v = np.zeros(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"),
                           ("green", "u1"), ("blue", "u1"), ("intensity", "u2"),
                           ("confidence", "f4")] + extra)
    p = g.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    p += g.normal(scale=0.003, size=(n, 3))
    for j, c in enumerate("xyz"):
        v[c] = p[:, j]
    for c in ("red", "green", "blue"):
        v[c] = g.integers(0, 256, n)
    v["intensity"] = g.integers(0, 65535, n)
    v["confidence"] = g.random(n)
    if extra:
        v["return"] = g.integers(-2**31, 2**31 - 1, n)
    PlyData([PlyElement.describe(v, "vertex")], text=order == "ascii",
            byte_order="<" if order == "ascii" else order,
            comments=["scanner 7"]).write(str(path))
    return path


def _result_fields(spec, result) -> dict:
    names = (spec.points_field, spec.normals_field, spec.mask_field, spec.scalar_field,
             spec.index_field)
    return {n: np.asarray(getattr(result, n)) for n in names
            if n and getattr(result, n, None) is not None}


@pytest.mark.parametrize("name", ["denoise", "saliency", "outliers", "features", "simplify"])
@pytest.mark.parametrize("order", ["<", ">", "ascii", "las"])
def test_streamed_ply_is_the_file_written_whole(tmp_path, name, order):
    """A tiled run writes PLY block by block; the file must be the one
    written from the whole result in memory, byte for byte: every input
    property in its place and type (float32 positions become float64 where a
    filter moves them, in every block), results appended, the input's byte
    order or ASCII encoding and comments (or a LAS input's dimensions)."""
    from types import SimpleNamespace

    from pcprep.meshlab_bridge import registry
    from pcprep.meshlab_bridge.apply import result_cloud
    from pcprep.meshlab_bridge.convert import quality_ramp
    from pcprep.meshlab_bridge.formats import stream

    registry.load_all()
    spec = registry.get(name)
    if order == "las":  # LAS/LAZ in, PLY out: streamed as well
        src = _random_las(tmp_path / "in.laz", 7, n=2500)
    else:
        src = _ply_float32(tmp_path / "in.ply", 2500, order)
    cloud = formats.read_cloud(src)
    params = {"ratio": 0.3} if name == "simplify" else {}
    if name == "outliers":  # some rows to remove
        params = {"method": "radius", "radius": 1.0}
    fields = _result_fields(spec, spec.func(cloud.points, **params))
    out = result_cloud(spec, cloud, SimpleNamespace(**fields))
    if spec.kind == "scalar":
        out = out.with_(colors=quality_ramp(out.quality))
    whole, streamed = tmp_path / "whole.ply", tmp_path / "streamed.ply"
    formats.write_cloud(out, whole)
    assert stream._block_reader(src) is not None  # not the whole-cloud path
    assert stream.write_streamed(spec, src, streamed, fields, size=700) == len(out)
    assert streamed.read_bytes() == whole.read_bytes()
    assert b"end_header" in whole.read_bytes()[:2000]


def _mesh_float32(path, n: int, order: str, edges: bool = True, quad: bool | str = False,
                  props: bool = False):
    """``_ply_float32``'s sphere as a binary mesh: triangles over random
    vertices (a quad among them with ``quad``, quads alone with
    ``quad="all"``), with a colour and a quality per face (``props``), and
    an ``edge`` element."""
    vertex = np.array(PlyData.read(str(_ply_float32(path, n, order)))["vertex"].data)
    g = np.random.default_rng(n + 1)
    m = 4 if quad == "all" else 3
    tri = np.r_[np.stack([np.arange(j, n - m + 1 + j) for j in range(m)], axis=1),
                g.integers(0, n, (3 * n, m))]
    face = np.empty(len(tri), dtype=[("vertex_indices", "O")]
                    + [("red", "u1"), ("quality", "f4")] * props)
    face["vertex_indices"] = [np.asarray(t, dtype="i4") for t in tri]
    if props:
        face["red"], face["quality"] = np.arange(len(tri)) % 251, g.random(len(tri))
    if quad is True:
        face["vertex_indices"][7] = np.array([0, 1, 2, 3], dtype="i4")
    els = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")]
    if edges:
        e = np.zeros(5, dtype=[("vertex1", "i4"), ("vertex2", "i4")])
        e["vertex1"], e["vertex2"] = np.arange(5), np.arange(1, 6)
        els.append(PlyElement.describe(e, "edge"))
    PlyData(els, byte_order=order, comments=["scanner 7"]).write(str(path))
    return path


@pytest.mark.parametrize("name", ["denoise", "saliency", "outliers", "features", "simplify"])
@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("quad", [False, "all"])
def test_streamed_mesh_is_the_file_written_whole(tmp_path, monkeypatch, name, order, quad):
    """A binary PLY of triangles, or of quads, is written block by block too:
    the vertices, then the triangles with their colour and quality (quads
    fanned, each triangle with its quad's values; renumbered, those with a
    removed vertex left out, as ``Cloud.subset`` does) and, where every vertex
    is kept, the other elements; byte for byte the file written from the
    whole result, and the input never read whole.  A mesh of triangles and
    quads is read whole."""
    from types import SimpleNamespace

    from pcprep.meshlab_bridge import registry
    from pcprep.meshlab_bridge.apply import result_cloud
    from pcprep.meshlab_bridge.convert import quality_ramp
    from pcprep.meshlab_bridge.formats import stream

    registry.load_all()
    spec = registry.get(name)
    src = _mesh_float32(tmp_path / "in.ply", 2500, order, quad=quad, props=True)
    cloud = formats.read_cloud(src)
    face = PlyData.read(str(src))["face"]  # plyfile's own parse
    for k in ("red", "quality"):
        assert np.array_equal(cloud.face_attributes[k], np.repeat(face[k], 2) if quad
                              else face[k], equal_nan=k == "quality")
    params = {"ratio": 0.3} if name == "simplify" else {}
    if name == "outliers":
        params = {"method": "radius", "radius": 1.0}
    fields = _result_fields(spec, spec.func(cloud.points, **params))
    out = result_cloud(spec, cloud, SimpleNamespace(**fields))
    if spec.kind == "scalar":
        out = out.with_(colors=quality_ramp(out.quality))
    assert out.faces is not None and 0 < len(out.faces)
    removal = spec.kind in ("remove", "new_layer")
    assert (len(out.faces) < len(cloud.faces)) == removal
    whole, streamed = tmp_path / "whole.ply", tmp_path / "streamed.ply"
    formats.write_cloud(out, whole)
    with monkeypatch.context() as m:
        m.setattr(stream, "read_cloud", lambda *a: pytest.fail("read whole"))
        assert stream.write_streamed(spec, src, streamed, fields, size=700) == len(out)
    assert streamed.read_bytes() == whole.read_bytes()
    kept = np.asarray(fields[spec.index_field]) if removal else np.arange(len(cloud))
    ends = [np.isin(np.arange(5) + j, kept) for j in (0, 1)]  # edges (j, j + 1), j < 5
    edge = PlyData.read(str(whole))["edge"]  # renumbered, those with a removed end left out
    assert np.array_equal(kept[edge["vertex1"]], np.flatnonzero(ends[0] & ends[1]))
    assert np.array_equal(kept[edge["vertex2"]], np.flatnonzero(ends[0] & ends[1]) + 1)
    back = formats.read_cloud(streamed)
    assert list(back.face_attributes) == ["red", "quality"]
    for k, v in out.face_attributes.items():
        assert np.array_equal(back.face_attributes[k], v, equal_nan=k == "quality")
        assert len(v) == len(out.faces)
    _mesh_float32(tmp_path / "mixed.ply", 2500, order, quad=True)
    assert stream._block_reader(tmp_path / "mixed.ply") is None


def test_mesh_face_out_of_range_is_refused_before_a_tiled_run(tmp_path):
    from pcprep.meshlab_bridge.formats import stream

    src = _mesh_float32(tmp_path / "in.ply", 300, "<", edges=False)
    data = bytearray(src.read_bytes())
    row = 13  # uchar count and three int32 per triangle: the last face's last index
    data[-4:] = np.array([300], dtype="<i4").tobytes()
    assert len(data) > row
    src.write_bytes(bytes(data))
    for check in (formats.read_cloud, lambda p: stream.check_fields(p, tmp_path / "o.ply")):
        with pytest.raises(PointCloudError, match="does not exist .index 300, 300 vertices"):
            check(src)


@pytest.mark.parametrize("name", ["denoise", "saliency", "outliers", "simplify"])
@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_streamed_las_from_another_format_is_the_file_written_whole(tmp_path, monkeypatch,
                                                                    name, ext):
    """PLY in, LAS/LAZ out, block by block: a first pass over the written rows
    gives the header's scale and offset, which depend on every row; the
    points and header are then those ``las.write`` gives the whole result, and
    the input is never read whole."""
    from types import SimpleNamespace

    from pcprep.meshlab_bridge import registry
    from pcprep.meshlab_bridge.apply import result_cloud
    from pcprep.meshlab_bridge.convert import quality_ramp
    from pcprep.meshlab_bridge.formats import stream

    registry.load_all()
    spec = registry.get(name)
    src = _ply_float32(tmp_path / "in.ply", 2500, "<")
    cloud = formats.read_cloud(src)
    params = {"ratio": 0.3} if name == "simplify" else {}
    if name == "outliers":
        params = {"method": "radius", "radius": 1.0}
    fields = _result_fields(spec, spec.func(cloud.points, **params))
    if name == "denoise":  # moved rows: the extent is the result's, not the input's
        fields["points"] = fields["points"] * 1.5 - 7.0
    out = result_cloud(spec, cloud, SimpleNamespace(**fields))
    if spec.kind == "scalar":
        out = out.with_(colors=quality_ramp(out.quality))
    whole, streamed = tmp_path / ("whole" + ext), tmp_path / ("streamed" + ext)
    formats.write_cloud(out, whole)
    monkeypatch.setattr(stream, "read_cloud", lambda *a: pytest.fail("read whole"))
    assert stream.write_streamed(spec, src, streamed, fields, size=700) == len(out)
    a, b = laspy.read(whole), laspy.read(streamed)
    assert np.array_equal(a.header.scales, b.header.scales)
    assert np.array_equal(a.header.offsets, b.header.offsets)
    assert a.header.point_format.id == b.header.point_format.id
    assert list(a.point_format.dimension_names) == list(b.point_format.dimension_names)
    assert np.array_equal(a.points.array, b.points.array)
    assert np.allclose(np.c_[b.x, b.y, b.z], out.points, rtol=0, atol=b.header.scales[0])


def test_streamed_ply_column_type_is_settled_over_every_block(tmp_path):
    """Float32 positions that a filter leaves unchanged in one block and moves in
    another are float64 in the whole file, as when it is written whole."""
    from pcprep.meshlab_bridge import registry
    from pcprep.meshlab_bridge.formats import stream

    registry.load_all()
    spec = registry.get("denoise")
    src = _ply_float32(tmp_path / "in.ply", 1000, "<")
    pts = formats.read_cloud(src).points
    moved = pts.copy()
    moved[600:] += 1e-9  # rows 600-999 no longer float32
    fields = {"points": moved, "normals": np.tile([0.0, 0.0, 1.0], (1000, 1)),
              "edge_mask": np.zeros(1000, bool)}
    stream.write_streamed(spec, src, tmp_path / "out.ply", fields, size=500)
    back = PlyData.read(str(tmp_path / "out.ply"))["vertex"].data
    assert back.dtype["x"] == np.float64
    assert np.array_equal(back["x"], moved[:, 0])


@pytest.mark.parametrize("parse_rows", [128, 1 << 16])
def test_ascii_ply_is_read_in_blocks_as_it_is_read_whole(tmp_path, monkeypatch, parse_rows):
    """An ASCII PLY of vertices alone is parsed block by block (NumPy's
    loadtxt, each column in its type, ``PARSE_ROWS`` rows at a time): every
    block's cloud holds the rows, attributes, types and header facts of the
    whole read, at any block size; a PLY with faces is still read whole."""
    from pcprep.meshlab_bridge.formats import ply, stream

    monkeypatch.setattr(ply, "PARSE_ROWS", parse_rows)

    src = _ply_float32(tmp_path / "in.ply", 2500, "ascii")
    whole = formats.read_cloud(src)
    for size in (1, 333, 2500, 4096):
        blocks = list(stream._block_reader(str(src))(size))
        assert [s for s, _ in blocks] == list(range(0, 2500, size))
        assert np.array_equal(np.concatenate([b.points for _, b in blocks]), whole.points)
        assert np.array_equal(np.concatenate([b.colors for _, b in blocks]), whole.colors)
        for name, col in whole.attributes.items():
            got = np.concatenate([b.attributes[name] for _, b in blocks])
            assert got.dtype == col.dtype and np.array_equal(got, col), name
        assert all(b.meta == whole.meta for _, b in blocks)
        pos = list(stream.position_chunks(src, size))
        assert np.array_equal(np.concatenate([p for _, p in pos]), whole.points)
    assert stream.point_count(src) == 2500
    mesh = tmp_path / "mesh.ply"
    formats.write_cloud(whole.with_(faces=np.array([[0, 1, 2]])), mesh)
    assert b"format ascii" in mesh.read_bytes()[:100]
    assert stream._block_reader(str(mesh)) is None


def test_ascii_ply_reads_and_writes_as_plyfile_does(tmp_path):
    """ASCII PLY of vertices alone is parsed and written by NumPy, not by
    plyfile's row loop: the values read are plyfile's, bit for bit, and the
    file written is the one plyfile writes, byte for byte, for every property
    type, extreme and non-finite values, and rows whose values share
    float32, float64 or an integer type."""
    from numpy.lib.recfunctions import repack_fields
    from plyfile import PlyData, PlyElement

    from pcprep.meshlab_bridge.formats import ply

    g = np.random.default_rng(11)
    n = 3000
    types = ["f4", "f8", "i1", "u1", "i2", "u2", "i4", "u4"]
    v = np.zeros(n, dtype=[("x", "f8"), ("y", "f4"), ("z", "f4")]
                 + [(f"c_{t}", t) for t in types])
    v["x"] = g.normal(size=n) * 10.0 ** g.integers(-30, 30, n)
    v["y"] = g.normal(size=n).astype("f4")
    v["z"] = g.normal(size=n).astype("f4") * np.float32(1e30)
    for t in types:
        info = np.finfo(t) if t[0] == "f" else np.iinfo(t)
        col = g.integers(info.min, info.max, n, endpoint=True) if t[0] != "f" \
            else g.normal(size=n) * 10.0 ** g.integers(-30, 30, n)
        v[f"c_{t}"] = col
        v[f"c_{t}"][:2] = [info.min, info.max]
    v["c_f8"][2:5] = [np.nan, np.inf, -np.inf]
    v["c_f4"][2:5] = [np.nan, np.inf, 5e-45]
    src = tmp_path / "in.ply"
    PlyData([PlyElement.describe(v, "vertex")], text=True, comments=["c"],
            obj_info=["o"]).write(str(src))
    ours = formats.read_cloud(src)
    theirs = PlyData.read(str(src))["vertex"].data
    assert np.array_equal(ours.points, np.column_stack([theirs[c].astype("f8") for c in "xyz"]))
    for t in types:
        got, want = ours.attributes[f"c_{t}"], theirs[f"c_{t}"]
        assert got.dtype == want.dtype
        assert np.array_equal(got.view(f"u{got.itemsize}"), want.view(f"u{want.itemsize}"))
    # written: a removal (new row count), the same types
    kept = ours.subset(np.arange(0, n, 3), keep_faces=False)
    formats.write_cloud(kept, tmp_path / "ours.ply")
    cols = ply.vertex_columns(kept)
    PlyData([PlyElement.describe(ply.vertex_rows(cols, {k: c.dtype for k, c in cols.items()}),
                                 "vertex")], text=True, comments=["c"], obj_info=["o"]
            ).write(str(tmp_path / "plyfile.ply"))
    assert (tmp_path / "ours.ply").read_bytes() == (tmp_path / "plyfile.ply").read_bytes()
    for group in (["y", "z", "c_u1"], ["x", "c_i1"], ["c_i2", "c_u2", "c_i4"]):
        rows = repack_fields(v[["x", "y", "z"] + [c for c in group if c not in "xyz"]])
        PlyData([PlyElement.describe(rows, "vertex")], text=True).write(
            str(tmp_path / "g.ply"))
        formats.write_cloud(formats.read_cloud(tmp_path / "g.ply"), tmp_path / "g2.ply")
        assert (tmp_path / "g2.ply").read_bytes() == (tmp_path / "g.ply").read_bytes()


def _damaged_ascii(path, damage: str):
    """An ASCII PLY of 1000 rows damaged as ``damage`` says, in a late row."""
    _ply_float32(path, 1000, "ascii")
    head, rows = path.read_bytes().split(b"end_header\n")
    lines = rows.splitlines(keepends=True)
    if damage == "ascii cut":
        lines = lines[:-3]
    elif damage == "ascii too long":
        lines = lines + lines[:2]
    elif damage == "ascii blank line":
        lines.insert(900, b"\n")
    elif damage == "ascii short row":
        lines[901] = b" ".join(lines[901].split()[:-1]) + b"\n"
    elif damage == "ascii long row":
        lines[901] = lines[901].rstrip() + b" 7\n"
    elif damage == "ascii not a number":
        tok = lines[901].split()
        lines[901] = b" ".join(tok[:1] + [b"abc"] + tok[2:]) + b"\n"
    path.write_bytes(head + b"end_header\n" + b"".join(lines))
    return path


@pytest.mark.parametrize("damage", ["ply cut", "ply cut inside a row", "ply too long",
                                    "las of text", "ascii cut", "ascii too long",
                                    "ascii blank line", "ascii short row",
                                    "ascii long row", "ascii not a number"])
def test_streamed_reading_refuses_damaged_files(tmp_path, damage):
    """The tiled path's reader (positions memory-mapped, or ASCII rows parsed
    in blocks) refuses what reading the whole file refuses: rows missing or
    left over, rows that are not the header's, records that are not points."""
    from pcprep.meshlab_bridge.formats import stream

    if damage.startswith("ascii"):
        path = _damaged_ascii(tmp_path / "a.ply", damage)
        with pytest.raises(PointCloudError, match="cannot read"):
            formats.read_cloud(path)
        said = {"ascii cut": "row 997 .*is missing", "ascii too long": "declares 1000 rows .*holds 1002",
                "ascii blank line": "row 900 .*is blank", "ascii short row": "row 901 .*8 values",
                "ascii long row": "row 901 .*10 values",
                "ascii not a number": "row 901 .*'abc' is not a value of property 'y'"}[damage]
        with pytest.raises(PointCloudError, match=said):
            for _ in stream.position_chunks(path, size=100):
                pass
        with pytest.raises(PointCloudError, match=said):
            for _ in stream._block_reader(str(path))(300):
                pass
        return
    if damage.startswith("ply"):
        path = _ply_float32(tmp_path / "a.ply", 1000, "<")
        data = path.read_bytes()
        data = {"ply cut": data[:-16 * 300], "ply cut inside a row": data[:-5],
                "ply too long": data + b"\x01" * 100}[damage]
    else:
        path = tmp_path / "a.las"
        data = b"x y z\n" * 100
    path.write_bytes(data)
    with pytest.raises(PointCloudError, match="cannot read"):
        stream.point_count(path)
    with pytest.raises(PointCloudError, match="cannot read"):
        for _ in stream.position_chunks(path, size=100):
            pass


@pytest.mark.parametrize("normals", [False, True])
def test_streamed_xyz_reads_and_writes_what_whole_xyz_does(tmp_path, normals):
    """XYZ in a tiled run is parsed block by block and written block by block:
    the same positions, the same file, and a bad line in a later block named
    by its line number as a whole read names it."""
    from types import SimpleNamespace

    from pcprep.meshlab_bridge import registry
    from pcprep.meshlab_bridge.apply import result_cloud
    from pcprep.meshlab_bridge.formats import stream

    registry.load_all()
    g = np.random.default_rng(4)
    rows = UTM + g.normal(size=(2000, 3)) * [5.0, 5.0, 0.1]
    if normals:
        nrm = g.normal(size=(2000, 3)) * [0.1, 0.1, 1.0]
        rows = np.c_[rows, nrm / np.linalg.norm(nrm, axis=1)[:, None]]
    src = tmp_path / "in.xyz"
    with open(src, "w") as f:
        f.write("# a scan\n")
        for j, r in enumerate(rows):
            f.write(" ".join(f"{v:.17g}" for v in r) + ("  # seam\n" if j == 999 else "\n"))
            if j == 1500:
                f.write("\n")
    whole = formats.read_cloud(src)
    assert stream.point_count(src) == 2000
    got = np.concatenate([b for _, b in stream.position_chunks(src, size=300)])
    assert np.array_equal(got, whole.points)
    spec = registry.get("outliers")
    fields = _result_fields(spec, spec.func(whole.points, method="radius", radius=1.0))
    assert 0 < len(fields["keep_idx"]) < 2000
    ref = tmp_path / "whole.xyz"
    formats.write_cloud(result_cloud(spec, whole, SimpleNamespace(**fields)), ref)
    out = tmp_path / "streamed.xyz"
    assert stream.write_streamed(spec, src, out, fields, size=300) == len(
        formats.read_cloud(ref))
    assert out.read_bytes() == ref.read_bytes()
    lines = src.read_text().splitlines()
    lines[1700] = " ".join(["1", "2", "oops"] + ["0"] * (3 if normals else 0))
    src.write_text("\n".join(lines) + "\n")
    with pytest.raises(PointCloudError, match="line 1701: row"):
        formats.read_cloud(src)
    with pytest.raises(PointCloudError, match="line 1701: row"):
        for _ in stream.position_chunks(src, size=300):
            pass


def test_las_results_go_to_new_extra_dimensions_and_keep_everything(tmp_path):
    src = _random_las(tmp_path / "scan.laz", 6, n=3000)
    out = tmp_path / "holes.laz"
    assert main(["holes", str(src), str(out), "--quiet"]) == 0
    a, b = laspy.read(str(src)), laspy.read(str(out))
    for dim in a.point_format.dimension_names:
        assert np.array_equal(np.asarray(a[dim]), np.asarray(b[dim])), dim
    assert "hole" in b.point_format.extra_dimension_names
    assert b["hole"].dtype == np.uint8 and set(np.unique(b["hole"])) <= {0, 1}
    assert np.array_equal(a.header.offsets, b.header.offsets)


def test_las_written_from_another_format_spans_its_extent(tmp_path):
    g = np.random.default_rng(2)
    pts = UTM + g.uniform(0, 500, (300, 3))
    formats.write_cloud(Cloud(pts), tmp_path / "x.las")
    back = formats.read_cloud(tmp_path / "x.las")
    header = back.meta["las_header"]
    assert np.abs(back.points - pts).max() <= 0.5 * header.scales.max() + 1e-9
    assert header.scales.max() <= 1e-6


def _ply_with_properties(path, text, n=500, seed=3, faces=True):
    g = np.random.default_rng(seed)
    v = np.zeros(n, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("intensity", "u2"),
                           ("classification", "u1"), ("confidence", "f4")])
    ang = g.uniform(0, 2 * np.pi, n)
    h = g.uniform(-1, 1, n)
    v["x"], v["y"], v["z"] = (UTM[0] + np.sqrt(1 - h**2) * np.cos(ang),
                              UTM[1] + np.sqrt(1 - h**2) * np.sin(ang), UTM[2] + h)
    v["intensity"] = g.integers(0, 65535, n)
    v["classification"] = g.integers(0, 20, n)
    v["confidence"] = g.random(n)
    els = [PlyElement.describe(v, "vertex")]
    if faces:
        f = np.zeros(n - 2, dtype=[("vertex_indices", "i4", (3,))])
        f["vertex_indices"] = np.c_[np.zeros(n - 2), np.arange(1, n - 1), np.arange(2, n)]
        els.append(PlyElement.describe(f, "face"))
    PlyData(els, text=text, comments=["made by the tests"]).write(str(path))
    return v


@pytest.mark.parametrize("text", [True, False])
def test_ply_keeps_custom_properties_faces_and_comments(tmp_path, text):
    v = _ply_with_properties(tmp_path / "a.ply", text)
    cloud = formats.read_cloud(tmp_path / "a.ply")
    assert list(cloud.attributes) == ["intensity", "classification", "confidence"]
    assert cloud.faces.shape == (498, 3)
    formats.write_cloud(cloud, tmp_path / "b.ply")
    back = PlyData.read(str(tmp_path / "b.ply"))
    assert back["vertex"].data.dtype == v.dtype
    for name in v.dtype.names:
        assert np.array_equal(back["vertex"].data[name], v[name]), name
    assert back["face"].count == 498 and "made by the tests" in back.comments
    assert back.text == text


@pytest.mark.parametrize("command", ["denoise", "saliency", "features", "holes", "simplify"])
def test_every_filter_keeps_every_input_attribute(tmp_path, command):
    v = _ply_with_properties(tmp_path / "in.ply", text=False, n=2500, faces=False)
    out = tmp_path / "out.ply"
    args = [command, str(tmp_path / "in.ply"), str(out), "--quiet"]
    if command == "denoise":
        args += ["--n-iter", "1"]
    if command == "simplify":
        args += ["--ratio", "0.3"]
    assert main(args) == 0
    got = PlyData.read(str(out))["vertex"].data
    if command == "simplify":
        # kept rows: find them by position (points are never moved by SDBS)
        key = {tuple(r): i for i, r in enumerate(np.c_[v["x"], v["y"], v["z"]])}
        rows = np.array([key[tuple(r)] for r in np.c_[got["x"], got["y"], got["z"]]])
        assert len(rows) == round(0.3 * len(v))
    else:
        rows = np.arange(len(v))
        assert len(got) == len(v)
    for name in ("intensity", "classification", "confidence"):
        assert got.dtype[name] == v.dtype[name]
        assert np.array_equal(got[name], v[name][rows]), name


@pytest.mark.parametrize("text", [True, False])
def test_non_finite_ply_rows_are_refused_or_dropped_by_index(tmp_path, text):
    v = np.zeros(4, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    v["x"] = [0.0, 1.0, np.nan, 3.0]
    PlyData([PlyElement.describe(v, "vertex")], text=text).write(str(tmp_path / "n.ply"))
    with pytest.raises(PointCloudError, match=r"rows 2\)"):
        formats.read_cloud(tmp_path / "n.ply")
    dropped = formats.read_cloud(tmp_path / "n.ply", nonfinite="drop")
    assert len(dropped) == 3 and list(dropped.meta["dropped_rows"]) == [2]
    assert main(["info", str(tmp_path / "n.ply")]) == 0
    # a mesh keeps the faces that do not use a dropped row, renumbered
    face = np.zeros(3, dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = [[0, 1, 3], [1, 2, 3], [3, 1, 0]]
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(face, "face")],
            text=text).write(str(tmp_path / "m.ply"))
    mesh = formats.read_cloud(tmp_path / "m.ply", nonfinite="drop")
    assert mesh.faces.tolist() == [[0, 1, 2], [2, 1, 0]]


def test_ply_with_more_rows_than_declared_is_refused(tmp_path):
    path = tmp_path / "more.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n"
                    "property float y\nproperty float z\nend_header\n0 0 0\n1 1 1\n2 2 2\n")
    with pytest.raises(PointCloudError, match="declares 2 rows"):
        formats.read_cloud(path)
    v = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    PlyData([PlyElement.describe(v, "vertex")], text=False).write(str(tmp_path / "b.ply"))
    with open(tmp_path / "b.ply", "ab") as f:
        f.write(np.ones(6, dtype="f4").tobytes())
    with pytest.raises(PointCloudError, match="continues after"):
        formats.read_cloud(tmp_path / "b.ply")


def _fan_reference(polygons):
    """Each polygon fanned from its first vertex, by the plain loop."""
    tris = [(p[0], p[j], p[j + 1]) for p in polygons for j in range(1, len(p) - 1)]
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


def test_fan_triangles_is_the_plain_fan(tmp_path):
    from pcprep.meshlab_bridge.formats.ply import fan_triangles

    g = np.random.default_rng(5)
    sizes = g.integers(0, 8, 400)
    polys = np.empty(len(sizes), dtype=object)
    polys[:] = [g.integers(0, 10**6, s).astype("u4") for s in sizes]
    got = fan_triangles(polys)
    assert got.dtype == np.int64 and np.array_equal(got, _fan_reference(polys))
    assert len(got) == np.maximum(sizes - 2, 0).sum() > 0
    for m in (2, 3, 4, 6):  # fixed-size rows (a memory-mapped face element)
        rows = g.integers(0, 10**6, (50, m)).astype("i4")
        assert np.array_equal(fan_triangles(rows), _fan_reference(rows)), m
        obj = np.empty(50, dtype=object)
        obj[:] = list(rows)
        assert np.array_equal(fan_triangles(obj), fan_triangles(rows)), m


#: the 60 vertices of the OBJ and OFF meshes
CLOUD_60 = np.random.default_rng(60).random((60, 3)).round(6)


def _mesh_ply(path, polygons, n=60, order="<", text=False, edges=False):
    """A PLY of ``n`` vertices and the faces ``polygons`` (one list each),
    with a per-face colour; and an ``edge`` element (``edges`` True) or one
    with a list property (``"list"``) when asked."""
    g = np.random.default_rng(len(polygons))
    v = np.zeros(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "u2")])
    for c in "xyz":
        v[c] = g.random(n)
    v["intensity"] = g.integers(0, 65535, n)
    face = np.empty(len(polygons), dtype=[("vertex_indices", "O"), ("red", "u1")])
    face["vertex_indices"] = [np.asarray(p, dtype="i4") for p in polygons]
    face["red"] = g.integers(0, 255, len(polygons))
    els = [PlyElement.describe(v, "vertex"), PlyElement.describe(face, "face")]
    if edges == "list":  # an element with a list property of its own
        e = np.empty(3, dtype=[("vertex_list", "O")])
        e["vertex_list"] = [np.arange(k, dtype="i4") for k in (2, 5, 3)]
        els.append(PlyElement.describe(e, "path"))
    elif edges:
        e = np.zeros(4, dtype=[("vertex1", "i4"), ("vertex2", "i4")])
        e["vertex1"], e["vertex2"] = [0, 1, 2, 3], [1, 2, 3, 4]
        els.append(PlyElement.describe(e, "edge"))
    PlyData(els, text=text, byte_order=order).write(str(path))


@pytest.mark.parametrize("order", ["<", ">"])
def test_binary_triangle_mesh_is_read_without_plyfile_row_loop(tmp_path, monkeypatch, order):
    """A binary PLY of triangles, or of quads, is memory-mapped whole, faces
    too: the faces read are plyfile's own parse, while plyfile's row-by-row
    reader is made to fail.  A mesh of triangles and a quad is read row by
    row, as before, and fanned."""
    import plyfile

    from pcprep.meshlab_bridge.formats import ply

    g = np.random.default_rng(2)
    tris = [list(g.choice(60, 3, replace=False)) for _ in range(200)]
    _mesh_ply(tmp_path / "t.ply", tris, order=order, edges=True)
    _mesh_ply(tmp_path / "q.ply", tris[:50] + [[0, 1, 2, 3]] + tris[50:], order=order)
    plain = {name: formats.read_cloud(tmp_path / name) for name in ("t.ply", "q.ply")}
    assert np.array_equal(plain["t.ply"].faces, _fan_reference(tris))
    assert np.array_equal(plain["q.ply"].faces,
                          _fan_reference(tris[:50] + [[0, 1, 2, 3]] + tris[50:]))

    quads = [list(g.choice(60, 4, replace=False)) for _ in range(200)]
    _mesh_ply(tmp_path / "all4.ply", quads, order=order)
    plain["all4.ply"] = formats.read_cloud(tmp_path / "all4.ply")
    assert np.array_equal(plain["all4.ply"].faces, _fan_reference(quads))

    def refuse(self, *args):
        raise AssertionError("plyfile parsed a binary element row by row")

    monkeypatch.setattr(plyfile.PlyElement, "_read_bin", refuse)
    for name in ("t.ply", "all4.ply"):
        fast = formats.read_cloud(tmp_path / name)
        assert np.array_equal(fast.faces, plain[name].faces)
        assert np.array_equal(fast.points, plain[name].points)
    assert list(formats.read_cloud(tmp_path / "t.ply").meta["ply"]["other_elements"]) == \
        ["edge"]
    with pytest.raises(AssertionError, match="row by row"):
        formats.read_cloud(tmp_path / "q.ply")
    # a tiled run's quads: fanned slice by slice, slices that cut a quad in two
    tri = ply.mesh_tail(ply.load(str(tmp_path / "all4.ply")), "all4.ply")[0]
    assert len(tri) == 400
    for size in (1, 7, 400, 1000):
        got = np.concatenate([tri[s:s + size] for s in range(0, len(tri), size)])
        assert np.array_equal(got, _fan_reference(quads))


def test_cut_binary_triangle_mesh_is_refused_as_before(tmp_path):
    tris = [[0, 1, 2], [1, 2, 3]] * 40
    _mesh_ply(tmp_path / "t.ply", tris)
    data = (tmp_path / "t.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-7])
    with pytest.raises(PointCloudError, match="early end-of-file"):
        formats.read_cloud(tmp_path / "cut.ply")
    (tmp_path / "long.ply").write_bytes(data + b"\x01" * 40)
    with pytest.raises(PointCloudError, match="continues after"):
        formats.read_cloud(tmp_path / "long.ply")


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("edges", [False, True, "list"])
def test_binary_mesh_is_written_as_plyfile_writes_it(tmp_path, order, edges):
    """The faces of a binary PLY are written as records, not by plyfile's row
    loop, with plyfile's bytes: a mesh with another element and both byte
    orders, its faces with and without their colour; an element with a list
    of its own goes through plyfile."""
    from pcprep.meshlab_bridge.formats import ply

    g = np.random.default_rng(3)
    polys = [list(g.choice(60, m, replace=False)) for m in g.integers(3, 6, 300)]
    _mesh_ply(tmp_path / "in.ply", polys, order=order, edges=edges)
    coloured = formats.read_cloud(tmp_path / "in.ply")
    for cloud in (coloured, formats.drop_face_properties(coloured)):
        formats.write_cloud(cloud, tmp_path / "ours.ply")
        cols = ply.vertex_columns(cloud)
        face = np.empty(len(cloud.faces), dtype=[("vertex_indices", "i4", (3,))]
                        + [("red", "u1")] * bool(cloud.face_attributes))
        face["vertex_indices"] = cloud.faces
        if cloud.face_attributes:
            face["red"] = cloud.face_attributes["red"]
        els = [PlyElement.describe(ply.vertex_rows(cols, {k: c.dtype for k, c in cols.items()}),
                                   "vertex"), PlyElement.describe(face, "face")]
        els += list(cloud.meta["ply"]["other_elements"].values())
        PlyData(els, byte_order=order).write(str(tmp_path / "plyfile.ply"))
        assert (tmp_path / "ours.ply").read_bytes() == (tmp_path / "plyfile.ply").read_bytes()
        back = formats.read_cloud(tmp_path / "ours.ply")
        assert np.array_equal(back.faces, cloud.faces) and len(back.faces) > len(polys)
    red = PlyData.read(str(tmp_path / "in.ply"))["face"]["red"]  # each polygon's, on its fan
    assert np.array_equal(coloured.face_attributes["red"],
                          np.repeat(red, [len(p) - 2 for p in polys]))


@pytest.mark.parametrize("tiled", [[], ["--tiles", "20", "--workers", "1"]])
def test_what_faces_carry_is_not_lost_without_a_word(tmp_path, capsys, tiled):
    # PLY face colours (a binary mesh, read in blocks when tiled) and OFF
    # face colours written to OBJ, OBJ texture coordinates on some faces
    # only, an OFF colour-map index: pcprep does not write them there, so a
    # write of the faces is refused, naming them, unless the user drops them
    # (the faces stay) or the faces
    tris = [[i, i + 1, i + 2] for i in range(58)]
    v = np.array([tuple(p) for p in CLOUD_60], dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    face = np.empty(len(tris), dtype=[("vertex_indices", "i4", (3,)), ("red", "u1")])
    face["vertex_indices"], face["red"] = tris, 200
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(face, "face")]).write(
        str(tmp_path / "m.ply"))
    verts = "".join(f"v {x} {y} {z}\n" for x, y, z in CLOUD_60)
    (tmp_path / "m.obj").write_text(
        verts + "vt 0 0\nvt 1 0\nvt 0 1\nusemtl stone\n" + "f 1 2 3\n"
        + "".join(f"f {a + 1}/1 {b + 1}/2 {c + 1}/3\n" for a, b, c in tris[1:]))
    for name, colour in (("m.off", "255 0 0"), ("map.off", "7")):  # a colour; a map index
        (tmp_path / name).write_text(
            f"OFF\n60 {len(tris)} 0\n" + verts.replace("v ", "")
            + "".join(f"3 {a} {b} {c} {colour}\n" for a, b, c in tris))
    carried = {"m.ply": "red, which pcprep does not write to .obj files",
               "m.off": "red, green, blue, which pcprep does not write to .obj files",
               "m.obj": "texture coordinates (on some faces only), which pcprep does not",
               "map.off": "face colours, which pcprep does not"}
    for name, what in carried.items():
        src = tmp_path / name
        dst = tmp_path / (f"from_{name[-3:]}.obj" if name in ("m.ply", "m.off")
                          else f"out_{name}")
        run = ["outliers", str(src), str(dst), "--std-ratio", "50", "--quiet", *tiled]
        assert main(run) == 1
        assert f"faces carry {what}" in capsys.readouterr().err
        assert not dst.exists()
        assert main([*run, "--drop-face-properties"]) == 0
        out, one = formats.read_cloud(dst), formats.read_cloud(src)
        assert np.array_equal(out.faces, one.faces) and len(out.faces) == len(tris)
        assert out.meta["face_properties"] == ()
        assert main([*run, "--drop-faces"]) == 0
        assert formats.read_cloud(dst).faces is None


def test_a_face_element_without_vertex_indices_is_kept_as_another_element(tmp_path):
    v = np.zeros(4, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    v["x"] = np.arange(4)
    odd = np.zeros(2, dtype=[("area", "f4")])
    odd["area"] = [0.5, 2.0]
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(odd, "face")]).write(
        str(tmp_path / "in.ply"))
    cloud = formats.read_cloud(tmp_path / "in.ply")
    assert cloud.faces is None and list(cloud.meta["ply"]["other_elements"]) == ["face"]
    formats.write_cloud(cloud, tmp_path / "out.ply")
    assert np.array_equal(PlyData.read(str(tmp_path / "out.ply"))["face"]["area"], [0.5, 2.0])


@pytest.mark.parametrize("name, text, match", [
    ("nan.off", "OFF\n3 0 0\n0 0 0\nnan nan nan\n1 1 1\n", r"rows 1\)"),
    ("nan.obj", "v 0 0 0\nv 1 1 1\nv inf 0 0\n", r"rows 2\)"),
    ("abc.obj", "v 0 0 0\nv abc def ghi\n", r"line 2: vertex 'abc def ghi' is not numeric"),
    ("short.off", "OFF\n3 0 0\n0 0 0\n1 1 1\n", "declares 3 vertices"),
    ("long.off", "OFF\n2 0 0\n0 0 0\n1 1 1\n2 2 2\n", "continues after"),
    ("cols.xyz", "0 0 0\n1 1\n", "line 2: expected 3"),
])
def test_text_formats_refuse_malformed_rows(tmp_path, name, text, match):
    (tmp_path / name).write_text(text)
    with pytest.raises(PointCloudError, match=match):
        formats.read_cloud(tmp_path / name)


@pytest.mark.parametrize("ext", [".xyz", ".obj", ".off", ".pcd", ".ply"])
def test_text_and_pcd_formats_keep_full_precision(tmp_path, ext):
    g = np.random.default_rng(4)
    pts = UTM + g.normal(size=(200, 3))
    nrm = g.normal(size=(200, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    formats.write_cloud(Cloud(pts, nrm), tmp_path / f"c{ext}")
    back = formats.read_cloud(tmp_path / f"c{ext}")
    assert np.array_equal(back.points, pts) and np.array_equal(back.normals, nrm)


def test_pcd_ascii_and_binary_as_pcl_writes_them(tmp_path):
    header = ("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
              "FIELDS x y z intensity rgb\nSIZE 4 4 4 4 4\nTYPE F F F F F\nCOUNT 1 1 1 1 1\n"
              "WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\n")
    packed = np.array([0xFF0000, 0x00FF00, 0x0000FF], dtype=np.uint32).view(np.float32)
    rows = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
    inten = np.array([0.5, 1.0, 2.0], dtype=np.float32)
    ascii_body = "".join(f"{r[0]} {r[1]} {r[2]} {i} {float(p)!r}\n" for r, i, p in
                         zip(rows, inten, packed.astype(np.float64)))
    (tmp_path / "a.pcd").write_text(header + "DATA ascii\n" + ascii_body)
    rec = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"),
                             ("rgb", "<f4")])
    rec["x"], rec["y"], rec["z"] = rows.T
    rec["intensity"], rec["rgb"] = inten, packed
    (tmp_path / "b.pcd").write_bytes((header + "DATA binary\n").encode() + rec.tobytes())
    for name in ("a.pcd", "b.pcd"):
        c = formats.read_cloud(tmp_path / name)
        assert np.array_equal(c.points, rows.astype(np.float64))
        assert np.array_equal(c.attributes["intensity"], inten)
        assert np.array_equal(c.colors[:, :3], np.eye(3))
    (tmp_path / "c.pcd").write_text(header + "DATA binary_compressed\n")
    with pytest.raises(PointCloudError, match="binary_compressed is not supported"):
        formats.read_cloud(tmp_path / "c.pcd")


def _ascii_pcd(binary, path):
    """The ASCII PCD of a binary PCD's records (every value as repr of its
    float64, which reads back to the same value), with a blank line."""
    from pcprep.meshlab_bridge.formats import pcd

    rec, _ = pcd.binary_rows(str(binary))
    head = binary.read_bytes().split(b"DATA binary\n")[0]
    cols = [np.asarray(rec[name], np.float64).reshape(len(rec), -1) for name in rec.dtype.names]
    table = np.hstack(cols)
    lines = [" ".join(repr(float(v)) for v in row) for row in table]
    lines.insert(len(lines) // 2, "")
    path.write_bytes(head + b"DATA ascii\n" + "\n".join(lines).encode() + b"\n")
    return path


@pytest.mark.parametrize("data", ["binary", "ascii"])
def test_pcd_streams_as_its_whole_read(tmp_path, monkeypatch, data):
    """A binary PCD is memory-mapped for a tiled run, an ASCII PCD parsed
    block by block: positions and blocks are the whole read's, a PLY written
    from its blocks is the whole write, and a file cut short is refused with
    its counts."""
    from types import SimpleNamespace

    from pcprep.meshlab_bridge import registry
    from pcprep.meshlab_bridge.apply import result_cloud
    from pcprep.meshlab_bridge.formats import pcd, ply, stream

    g = np.random.default_rng(8)
    n = 2500
    formats.write_cloud(Cloud(UTM + g.normal(size=(n, 3)), None, np.c_[g.random((n, 3)),
                              np.ones(n)], None, None,
                              {"intensity": g.random(n).astype(np.float32)}), tmp_path / "a.pcd")
    path = tmp_path / "a.pcd"
    assert b"DATA binary" in path.read_bytes()[:400]
    if data == "ascii":
        monkeypatch.setattr(ply, "PARSE_ROWS", 256)  # blocks of 700 from parses of 256
        binary = formats.read_cloud(path)
        path = _ascii_pcd(path, tmp_path / "t.pcd")
        whole = formats.read_cloud(path)
        assert np.array_equal(whole.points, binary.points)
        assert np.array_equal(whole.colors, binary.colors)
        assert np.array_equal(whole.attributes["intensity"], binary.attributes["intensity"])
    whole = formats.read_cloud(path)
    assert stream._block_reader(str(path)) is not None
    assert stream.point_count(path) == n
    assert np.array_equal(np.concatenate([b for _, b in stream.position_chunks(path, 700)]),
                          whole.points)
    parts = [c for _, c in pcd.blocks(str(path), 700)]
    assert np.array_equal(np.concatenate([c.colors for c in parts]), whole.colors)
    assert np.array_equal(np.concatenate([c.attributes["intensity"] for c in parts]),
                          whole.attributes["intensity"])
    registry.load_all()
    spec = registry.get("saliency")
    fields = {"saliency": g.random(n)}
    ref = tmp_path / "whole.ply"
    from pcprep.meshlab_bridge.convert import quality_ramp

    out = result_cloud(spec, whole, SimpleNamespace(**fields))
    formats.write_cloud(out.with_(colors=quality_ramp(out.quality)), ref)
    assert stream.write_streamed(spec, path, tmp_path / "s.ply", fields, size=700) == n
    assert (tmp_path / "s.ply").read_bytes() == ref.read_bytes()
    # PCD out, block by block: the whole write's bytes (a removal's count included)
    for name, fields in (("saliency", fields),
                         ("outliers", {"keep_idx": np.flatnonzero(g.random(n) < 0.6)})):
        spec = registry.get(name)
        out = result_cloud(spec, whole, SimpleNamespace(**fields))
        if spec.kind == "scalar":
            out = out.with_(colors=quality_ramp(out.quality))
        formats.write_cloud(out, tmp_path / "whole.pcd")
        assert stream.write_streamed(spec, path, tmp_path / "s.pcd", fields,
                                     size=700) == len(out)
        assert (tmp_path / "s.pcd").read_bytes() == (tmp_path / "whole.pcd").read_bytes()
    if data == "ascii":
        lines = path.read_bytes().splitlines(keepends=True)
        path.write_bytes(b"".join(lines[:-2]))
        with pytest.raises(PointCloudError, match=f"declares {n} points, the file holds "
                                                  f"{n - 2} rows"):
            for _ in stream.position_chunks(path, 700):
                pass
        path.write_bytes(b"".join(lines + lines[-3:]))
        with pytest.raises(PointCloudError, match=f"holds {n + 3} rows"):
            formats.read_cloud(path)
        bad = lines[:-5] + [lines[-5].replace(b" ", b" x", 1)] + lines[-4:]
        path.write_bytes(b"".join(bad))
        with pytest.raises(PointCloudError, match=f"rows 2356–{n - 1} .*not numeric"):
            for _ in stream._block_reader(str(path))(700):
                pass
        return
    path.write_bytes(path.read_bytes()[:-50])
    with pytest.raises(PointCloudError, match=f"declares {n} points"):
        stream.point_count(path)


def test_e57_scans_merge_with_their_fields(tmp_path):
    pye57 = pytest.importorskip("pye57")
    g = np.random.default_rng(5)
    pts = g.normal(size=(300, 3))
    e57 = pye57.E57(str(tmp_path / "s.e57"), mode="w")
    e57.write_scan_raw({"cartesianX": pts[:, 0], "cartesianY": pts[:, 1],
                        "cartesianZ": pts[:, 2], "intensity": g.random(300).astype(np.float32)})
    e57.close()
    c = formats.read_cloud(tmp_path / "s.e57")
    assert np.allclose(c.points, pts, atol=1e-6) and "intensity" in c.attributes
    with pytest.raises(PointCloudError, match="float32"):
        formats.write_cloud(Cloud(pts + UTM), tmp_path / "far.e57")


def _two_scan_e57(path, translation=(0.0, 1.0, 2.0)):
    """Two E57 scans (the second rotated, 5 apart, both at ``translation``) with
    intensity, colours and row and column indices."""
    import pye57

    g = np.random.default_rng(7)
    f = pye57.E57(str(path), mode="w")
    for i, (n, rot) in enumerate(((700, [1, 0, 0, 0]), (450, [0.8, 0.0, 0.6, 0.0]))):
        f.write_scan_raw({"cartesianX": g.normal(size=n), "cartesianY": g.normal(size=n),
                          "cartesianZ": g.normal(size=n),
                          "intensity": g.random(n).astype(np.float32),
                          "colorRed": g.integers(0, 256, n).astype(np.uint8),
                          "colorGreen": g.integers(0, 256, n).astype(np.uint8),
                          "colorBlue": g.integers(0, 256, n).astype(np.uint8),
                          "rowIndex": np.arange(n, dtype=np.int32),
                          "columnIndex": np.full(n, i, dtype=np.int32)},
                         rotation=np.array(rot),
                         translation=np.array(translation) + [5.0 * i, 0.0, 0.0])
    f.close()
    return path


@pytest.mark.parametrize("name", ["outliers", "simplify"])
def test_streamed_e57_is_the_scan_written_whole(tmp_path, monkeypatch, name):
    """E57 out of a tiled run: the columns are gathered on disk and pye57
    writes the scan from memory maps of them; read back, the scan is the one
    written from the whole result (every field, its bounds), the input is
    never read whole, and no temporary is left."""
    pye57 = pytest.importorskip("pye57")
    from types import SimpleNamespace

    from pcprep.meshlab_bridge import registry
    from pcprep.meshlab_bridge.apply import result_cloud
    from pcprep.meshlab_bridge.formats import stream

    registry.load_all()
    spec = registry.get(name)
    src = _two_scan_e57(tmp_path / "in.e57")
    cloud = formats.read_cloud(src)
    params = {"ratio": 0.3} if name == "simplify" else {"method": "radius", "radius": 1.0}
    fields = _result_fields(spec, spec.func(cloud.points, **params))
    whole, streamed = tmp_path / "whole.e57", tmp_path / "streamed.e57"
    out = result_cloud(spec, cloud, SimpleNamespace(**fields), dst=str(whole))
    assert 0 < len(out) < len(cloud) and out.quality is None
    formats.write_cloud(out, whole)
    monkeypatch.setattr(stream, "read_cloud", lambda *a: pytest.fail("read whole"))
    assert stream.write_streamed(spec, src, streamed, fields, size=200) == len(out)
    a, b = pye57.E57(str(whole)), pye57.E57(str(streamed))
    ra, rb = a.read_scan_raw(0), b.read_scan_raw(0)
    assert sorted(ra) == sorted(rb) and "rowIndex" in rb and "colorRed" in rb
    for k in ra:
        assert np.array_equal(ra[k], rb[k]), k
    ha, hb = a.get_header(0), b.get_header(0)
    for k in ("xMinimum", "xMaximum", "yMinimum", "yMaximum", "zMinimum", "zMaximum",
              "point_count"):
        assert getattr(ha, k) == getattr(hb, k), k
    a.close()
    b.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.e57", "streamed.e57",
                                                          "whole.e57"]
    # far from the origin float32 would move the points: refused before
    # anything is written, as the whole write refuses
    far = _two_scan_e57(tmp_path / "far.e57", translation=(5e5, 5e6, 0.0))
    far_fields = {spec.index_field: np.arange(0, 1150, 3)}
    with pytest.raises(PointCloudError, match="float32"):
        stream.write_streamed(spec, far, tmp_path / "far_out.e57", far_fields, size=200)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["far.e57", "in.e57",
                                                          "streamed.e57", "whole.e57"]


def test_e57_read_in_blocks_is_the_whole_read(tmp_path):
    """E57 scans are read in blocks for a tiled run (libe57's reader with small
    buffers): the blocks, put together, are the whole read (poses, fields,
    scan index, colours scaled over every point), and the streamed positions
    and count are the cloud's."""
    pye57 = pytest.importorskip("pye57")
    from pcprep.meshlab_bridge.formats import e57 as e57_io
    from pcprep.meshlab_bridge.formats import stream

    g = np.random.default_rng(6)
    path = tmp_path / "two.e57"
    f = pye57.E57(str(path), mode="w")
    for i, (n, rot) in enumerate(((700, [1, 0, 0, 0]), (450, [0.8, 0.0, 0.6, 0.0]))):
        data = {"cartesianX": g.normal(size=n), "cartesianY": g.normal(size=n),
                "cartesianZ": g.normal(size=n), "intensity": g.random(n).astype(np.float32),
                "colorRed": g.integers(0, 256, n).astype(np.uint8),
                "colorGreen": g.integers(0, 256, n).astype(np.uint8),
                "colorBlue": g.integers(0, 256, n).astype(np.uint8)}
        f.write_scan_raw(data, rotation=np.array(rot), translation=np.array([i * 5.0, 1.0, 2.0]))
    f.close()
    whole = formats.read_cloud(path)
    parts = list(e57_io.blocks(str(path), 200))
    assert [s for s, _ in parts] == list(range(0, 700, 200)) + [700 + s for s in
                                                                   range(0, 450, 200)]
    assert np.array_equal(np.concatenate([c.points for _, c in parts]), whole.points)
    assert np.array_equal(np.concatenate([c.colors for _, c in parts]), whole.colors)
    for k in whole.attributes:
        assert np.array_equal(np.concatenate([c.attributes[k] for _, c in parts]),
                              whole.attributes[k]), k
    assert set(np.unique(whole.attributes["scan_index"])) == {0, 1}
    assert whole.colors[:, :3].max() <= 1.0 and whole.colors[:, :3].max() > 0.9
    assert stream.point_count(path) == 1150
    got = np.concatenate([b for _, b in stream.position_chunks(path, size=300)])
    assert np.array_equal(got, whole.points)


def test_e57_fields_are_checked_on_the_first_block_alone(tmp_path, monkeypatch):
    """Before a tiled run, the check that the output keeps the input's fields
    reads the E57's first block, not every point's colours (the pass that
    scales them): an output that would lose the colours is still refused."""
    pytest.importorskip("pye57")
    from pcprep.meshlab_bridge.formats import e57 as e57_io
    from pcprep.meshlab_bridge.formats import stream

    path = _two_scan_e57(tmp_path / "two.e57")
    read, real = [], e57_io._raw_blocks

    def counted(e57, i, fields, size):
        for raw in real(e57, i, fields, size):
            read.append(len(next(iter(raw.values()))))
            yield raw

    monkeypatch.setattr(e57_io, "_raw_blocks", counted)
    stream.check_fields(path, tmp_path / "out.ply")
    assert sum(read) == 700  # the first block (1024 rows asked, the first scan's 700)
    with pytest.raises(PointCloudError, match="colou?r"):
        stream.check_fields(path, tmp_path / "out.xyz")
    read.clear()
    whole = list(e57_io.blocks(str(path), 1024))  # a read for the run: colours scaled
    assert sum(read) == 2 * 1150 and whole[0][1].colors[:, :3].max() <= 1.0


@pytest.mark.parametrize("ext", [".stl", ".dxf", ".u3d", ".wrl", ".e57x", ""])
def test_outputs_that_cannot_hold_the_result_are_refused_before_the_run(tmp_path, ext):
    src = tmp_path / "in.ply"
    _ply_with_properties(src, text=False, n=600, faces=False)
    out = tmp_path / f"out{ext}"
    assert main(["saliency", str(src), str(out), "--quiet"]) == 1
    assert sorted(os.listdir(tmp_path)) == ["in.ply"]


@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("tiled", [[], ["--tiles", "200", "--workers", "1"]])
def test_formats_that_would_lose_input_attributes_are_refused(tmp_path, capsys, monkeypatch,
                                                              tiled, text):
    # a tiled run checks the input's first block before any work (the whole
    # cloud of an ASCII PLY, a format read whole), as the one-piece run
    # checks the cloud it read
    from pcprep.meshlab_bridge import tiles

    monkeypatch.setattr(tiles, "dask_client", lambda **kw: pytest.fail("a cluster started"))
    src = tmp_path / "in.ply"
    _ply_with_properties(src, text=text, n=600, faces=False)
    assert main(["denoise", str(src), str(tmp_path / "out.xyz"), "--quiet", *tiled]) == 1
    assert "intensity" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["in.ply"]
    if tiled:  # the streamed writer refuses as well, block by block
        from pcprep.meshlab_bridge import registry
        from pcprep.meshlab_bridge.formats import stream

        registry.load_all()
        pts = formats.read_cloud(src).points
        fields = {"points": pts, "normals": np.tile([0.0, 0.0, 1.0], (len(pts), 1)),
                  "edge_mask": np.zeros(len(pts), bool)}
        with pytest.raises(PointCloudError, match="intensity"):
            stream.write_streamed(registry.get("denoise"), src, tmp_path / "out.xyz",
                                  fields, size=100)
        assert sorted(os.listdir(tmp_path)) == ["in.ply"]


@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("tiled", [[], ["--tiles", "200", "--workers", "1"]])
def test_a_mesh_is_written_as_points_alone_only_when_asked(tmp_path, capsys, monkeypatch,
                                                           tiled, text):
    # LAS and PCD store points alone: a mesh's faces are not lost without a
    # word but refused before any work (a binary mesh tiled: from its face
    # count, the vertices being read in blocks); --drop-faces writes the
    # vertices, with every attribute, as the run that keeps the faces does
    from pcprep.meshlab_bridge import tiles

    src = tmp_path / "in.ply"
    _ply_with_properties(src, text=text, n=600)
    with monkeypatch.context() as m:
        m.setattr(tiles, "dask_client", lambda **kw: pytest.fail("a cluster started"))
        for ext in (".las", ".pcd"):
            assert main(["outliers", str(src), str(tmp_path / f"out{ext}"), "--quiet",
                         *tiled]) == 1
            err = capsys.readouterr().err
            assert "598 faces" in err and "--drop-faces" in err
    assert sorted(os.listdir(tmp_path)) == ["in.ply"]
    runs = {"mesh.ply": [], "points.ply": ["--drop-faces"], "points.las": ["--drop-faces"]}
    out = {}
    for name, flag in runs.items():
        assert main(["outliers", str(src), str(tmp_path / name), "--quiet", *flag,
                     *tiled]) == 0
        out[name] = formats.read_cloud(tmp_path / name)
    mesh = out["mesh.ply"]
    assert 0 < len(mesh.faces) <= 598
    for name in ("points.ply", "points.las"):
        assert out[name].faces is None
        assert np.allclose(out[name].points, mesh.points, rtol=0, atol=1e-6)
        for k in ("intensity", "classification"):
            assert np.array_equal(out[name].attributes[k], mesh.attributes[k]), (name, k)
    plain = formats.read_cloud(src).with_(attributes={})
    with pytest.raises(PointCloudError, match="598 faces"):
        formats.write_cloud(plain, tmp_path / "api.xyz")
    formats.write_cloud(plain.with_(faces=None), tmp_path / "api.xyz")
    assert len(formats.read_cloud(tmp_path / "api.xyz")) == 600


def _ply_with_elements(path, n=600, edges=True, grid=False):
    """``_ply_with_properties``' vertices (no faces) with a ``camera`` element,
    which refers to no vertex, with ``edges`` an ``edge`` element (scalar
    references), with ``grid`` a ``range_grid`` (a list of references)."""
    v = _ply_with_properties(path, text=False, n=n, faces=False)
    cam = np.zeros(1, dtype=[("view_px", "f4"), ("view_py", "f4"), ("focal", "f4")])
    cam["focal"] = 35.0
    els = [PlyElement.describe(v, "vertex"), PlyElement.describe(cam, "camera")]
    if edges:
        e = np.zeros(n - 1, dtype=[("vertex1", "i4"), ("vertex2", "i4"), ("weight", "f4")])
        e["vertex1"], e["vertex2"] = np.arange(n - 1), np.arange(1, n)
        e["weight"] = np.arange(n - 1) / 4
        els.append(PlyElement.describe(e, "edge", comments=["a polyline"]))
    if grid:
        r = np.empty(n, dtype=[("vertex_indices", "O")])
        r["vertex_indices"] = [np.array([i], "i4") for i in range(n)]
        els.append(PlyElement.describe(r, "range_grid", val_types={"vertex_indices": "i4"}))
    PlyData(els).write(str(path))


@pytest.mark.parametrize("tiled", [[], ["--tiles", "200", "--workers", "1"]])
def test_other_ply_elements_are_not_lost_without_a_word(tmp_path, capsys, monkeypatch, tiled):
    # a camera refers to no vertex: kept after a removal; an edge refers to
    # vertex rows by two scalars: renumbered, those with a removed end left
    # out, as faces are; a range grid's lists of rows would be left wrong, so
    # the write is refused unless --drop-elements; a format other than PLY
    # holds none of them (refused before any work, the tiled run too)
    from pcprep.meshlab_bridge import tiles

    _ply_with_elements(tmp_path / "all.ply", grid=True)
    _ply_with_elements(tmp_path / "edges.ply")
    remove = ["outliers", "--std-ratio", "1", "--quiet", *tiled]
    assert main([*remove[:1], str(tmp_path / "all.ply"), str(tmp_path / "o.ply"),
                 *remove[1:]]) == 1
    assert "element(s) range_grid refer to vertex rows" in capsys.readouterr().err
    assert not (tmp_path / "o.ply").exists()
    for src, flag in (("all.ply", ["--drop-elements"]), ("edges.ply", [])):
        assert main([*remove[:1], str(tmp_path / src), str(tmp_path / "o.ply"),
                     *remove[1:], *flag]) == 0
        back = PlyData.read(str(tmp_path / "o.ply"))
        assert back["vertex"].count < 600
        assert [el.name for el in back.elements] == ["vertex", *["camera", "edge"] * (not flag)]
    x = PlyData.read(str(tmp_path / "edges.ply"))["vertex"]["x"]
    kept = np.flatnonzero(np.isin(x, back["vertex"]["x"]))
    whole = np.isin(np.arange(599), kept) & np.isin(np.arange(1, 600), kept)
    edge = back["edge"]
    assert 0 < whole.sum() < 599 and edge.count == whole.sum()
    assert np.array_equal(kept[edge["vertex1"]], np.flatnonzero(whole))  # renumbered
    assert np.array_equal(kept[edge["vertex2"]], np.flatnonzero(whole) + 1)
    assert np.array_equal(edge["weight"], np.flatnonzero(whole) / 4)
    assert edge.comments == ["a polyline"] and edge.data.dtype["vertex1"] == np.dtype("i4")
    with monkeypatch.context() as m:
        m.setattr(tiles, "dask_client", lambda **kw: pytest.fail("a cluster started"))
        assert main(["saliency", str(tmp_path / "all.ply"), str(tmp_path / "o.las"),
                     "--quiet", *tiled]) == 1
        assert ("element(s) camera, edge, range_grid have no place in a .las"
                in capsys.readouterr().err)
    assert main(["saliency", str(tmp_path / "all.ply"), str(tmp_path / "o.las"), "--quiet",
                 "--drop-elements", *tiled]) == 0


def test_a_tiled_run_refuses_an_input_it_could_not_write_from(tmp_path, capsys, monkeypatch):
    # positions alone in a .npy are not a cloud read_cloud reads: the tiled
    # command line refuses it before any work, not at the write after the run
    from pcprep.meshlab_bridge import tiles

    monkeypatch.setattr(tiles, "dask_client", lambda **kw: pytest.fail("a cluster started"))
    np.save(tmp_path / "in.npy", np.random.default_rng(0).normal(size=(500, 3)))
    assert main(["denoise", str(tmp_path / "in.npy"), str(tmp_path / "out.laz"), "--quiet",
                 "--tiles", "200", "--workers", "1"]) == 1
    assert "unknown format .npy" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["in.npy"]


def test_a_removal_keeps_every_field_its_format_holds(tmp_path):
    """A removal's or new layer's score is MeshLab's quality for display: PLY
    keeps it (the input's own quality as ``quality_before``), a format without
    quality (XYZ, E57) gets the kept rows without it, and an E57 scan's own
    fields (colours, intensity, row and column) go back to E57."""
    pytest.importorskip("pye57")
    g = np.random.default_rng(3)
    pts = g.normal(size=(3000, 3))
    q = g.random(3000)
    formats.write_cloud(Cloud(pts, None, None, q, None, {}), tmp_path / "q.ply")
    assert main(["simplify", str(tmp_path / "q.ply"), str(tmp_path / "s.ply"),
                 "--ratio", "0.5", "--quiet"]) == 0
    out = formats.read_cloud(tmp_path / "s.ply")
    kept = _rows_of(pts, out.points)
    assert len(out.points) == 1500
    assert np.array_equal(out.attributes["quality_before"], q[kept])
    assert not np.array_equal(out.quality, q[kept])
    np.savetxt(tmp_path / "p.xyz", pts)
    assert main(["simplify", str(tmp_path / "p.xyz"), str(tmp_path / "s.xyz"),
                 "--ratio", "0.5", "--quiet"]) == 0
    assert np.array_equal(formats.read_cloud(tmp_path / "s.xyz").points,
                          formats.read_cloud(tmp_path / "s.ply").points)
    src = _two_scan_e57(tmp_path / "in.e57")
    for name, extra in (("outliers", ["--method", "radius", "--radius", "1.0"]),
                        ("simplify", ["--ratio", "0.5"])):
        dst = tmp_path / f"{name}.e57"
        assert main([name, str(src), str(dst), "--quiet", *extra]) == 0
        a, b = formats.read_cloud(src), formats.read_cloud(dst)
        rows = _rows_of(a.points, b.points)
        assert 0 < len(b.points) < len(a.points)
        assert sorted(b.attributes) == sorted(a.attributes)
        for k in a.attributes:  # one scan written, in the global frame
            want = 0 * a.attributes[k][rows] if k == "scan_index" else a.attributes[k][rows]
            assert np.array_equal(b.attributes[k], want), k
        assert np.array_equal(b.colors, a.colors[rows])


def _rows_of(pts: np.ndarray, sub: np.ndarray) -> np.ndarray:
    """The row of ``pts`` each row of ``sub`` is (to E57's float32), every one
    found."""
    from scipy.spatial import cKDTree

    dist, rows = cKDTree(pts).query(sub)
    assert dist.max() < 1e-6 * np.ptp(pts)
    return rows


def test_unwritable_or_missing_destinations_and_folder_inputs(tmp_path, capsys, monkeypatch):
    src = tmp_path / "in.ply"
    _ply_with_properties(src, text=False, n=600, faces=False)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(stat.S_IRUSR | stat.S_IXUSR)
    real_access = os.access
    if real_access(locked, os.W_OK):  # root writes anywhere: let the check see the mode
        monkeypatch.setattr(os, "access", lambda p, mode: real_access(p, mode) and not (
            os.fspath(p) == str(locked) and mode & os.W_OK))
    try:
        assert main(["saliency", str(src), str(locked / "o.ply"), "--quiet"]) == 1
        assert "not writable" in capsys.readouterr().err
    finally:
        locked.chmod(stat.S_IRWXU)
    assert main(["saliency", str(src), str(tmp_path / "no" / "o.ply"), "--quiet"]) == 1
    assert "does not exist" in capsys.readouterr().err
    assert main(["saliency", str(tmp_path), str(tmp_path / "o.ply"), "--quiet"]) == 1
    assert "is a folder" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["in.ply", "locked"]


def test_info_lists_attributes_crs_and_counts(tmp_path, capsys):
    src = _random_las(tmp_path / "s.las", 7, n=500)
    assert main(["info", str(src)]) == 0
    out = capsys.readouterr().out
    for word in ("intensity", "gps_time", "confidence", "uint16", "point format 7",
                 "isolated points", "non-finite points: 0"):
        assert word in out, word


def test_batch_runs_every_input_reports_failures_and_exits_non_zero(tmp_path, capsys, caplog):
    for i in range(2):
        _ply_with_properties(tmp_path / f"scan{i}.ply", text=False, n=600, seed=i, faces=False)
    (tmp_path / "broken.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\n")
    out = tmp_path / "out"
    out.mkdir()
    inputs = [str(tmp_path / n) for n in ("scan0.ply", "broken.ply", "scan1.ply")]
    assert main(["saliency", *inputs, "--out-dir", str(out), "--format", "laz"]) == 1
    err = caplog.text
    assert "broken.ply: failed" in err and "2 of 3 file(s) done" in err
    assert sorted(os.listdir(out)) == ["scan0.laz", "scan1.laz"]
    assert "saliency" in laspy.read(str(out / "scan1.laz")).point_format.extra_dimension_names
    assert main(["saliency", *inputs[::2], "--out-dir", str(out)]) == 0
    assert main(["saliency", *inputs]) == 1  # three paths and no --out-dir
    assert "--out-dir" in capsys.readouterr().err


def test_a_laz_write_that_fails_is_named_and_leaves_no_file(tmp_path, capsys, monkeypatch):
    # lazrs reports a write that fails (a full disk, say) as LazrsError, a
    # RuntimeError: one error line with the folder's free space, no traceback,
    # and neither the output nor its temporary left behind
    lazrs = pytest.importorskip("lazrs")
    from laspy._compression import lazrsbackend

    def full_disk(self):
        raise lazrs.LazrsError("IoError: Failed to call write")

    monkeypatch.setattr(lazrsbackend.LazrsPointWriter, "done", full_disk)
    src = _random_las(tmp_path / "in.las", 1)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["outliers", str(src), str(out / "o.laz"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "pcprep: error: cannot write" in err and "Failed to call write" in err
    assert f"({out} has " in err and "MiB free)" in err and "Traceback" not in err
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("order", ["<", ">"])
def test_face_attributes_and_list_elements_keep_their_values_in_either_byte_order(
        tmp_path, order):
    # plyfile writes the scalars of an element with a list property in the
    # machine's byte order; pcprep writes them in the file's, so a big-endian
    # mesh's face quality and a path element's weight read back as written
    v = np.zeros(5, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    v["x"] = np.arange(5)
    face = np.empty(3, dtype=[("vertex_indices", "O"), ("quality", "f4"), ("id", "i4")])
    face["vertex_indices"] = [np.array(t, "i4") for t in ([0, 1, 2], [1, 2, 3, 4], [0, 2, 4])]
    face["quality"], face["id"] = [1.5, 2.25, -3.0], [7, 8, 9]
    path = np.empty(2, dtype=[("vertex_list", "O"), ("weight", "f8")])
    path["vertex_list"] = [np.array([0, 1], "i4"), np.array([2, 3, 4], "i4")]
    path["weight"] = [0.5, 4.0]
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(face, "face"),
             PlyElement.describe(path, "path")]).write(str(tmp_path / "in.ply"))
    cloud = formats.read_cloud(tmp_path / "in.ply")
    info = {**cloud.meta["ply"], "byte_order": order}
    formats.write_cloud(cloud.with_(meta={**cloud.meta, "ply": info}), tmp_path / "out.ply")
    back = PlyData.read(str(tmp_path / "out.ply"))
    assert back.byte_order == order
    assert np.array_equal(back["face"]["quality"], [1.5, 2.25, 2.25, -3.0])  # the quad: 2
    assert np.array_equal(back["face"]["id"], [7, 8, 8, 9])
    assert np.array_equal(back["path"]["weight"], [0.5, 4.0])
    assert [list(p) for p in back["path"]["vertex_list"]] == [[0, 1], [2, 3, 4]]


def _textured_ply(path, text: bool, odd: bool = False):
    """A mesh of 60 vertices, two triangles and a quad whose faces carry a
    colour, a quality and texture coordinates (two per corner; with ``odd``
    the quad's list holds 6 values, not 8)."""
    v = np.array([tuple(p) for p in CLOUD_60], dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    face = np.empty(3, dtype=[("vertex_indices", "O"), ("red", "u1"), ("quality", "f4"),
                              ("texcoord", "O")])
    face["vertex_indices"] = [np.array(t, "i4") for t in ([0, 1, 2], [3, 4, 5, 6], [7, 8, 9])]
    face["red"], face["quality"] = [10, 20, 30], [0.5, 1.5, 2.5]
    quad = np.arange(6 if odd else 8, dtype="f4") + 100
    face["texcoord"] = [np.arange(6, dtype="f4"), quad, np.arange(6, dtype="f4") + 200]
    PlyData([PlyElement.describe(v, "vertex"),
             PlyElement.describe(face, "face", val_types={"texcoord": "f4"})],
            text=text).write(str(path))
    return path


@pytest.mark.parametrize("text", [False, True])
def test_face_attributes_are_kept_on_each_triangle(tmp_path, text):
    # a polygon's colour and quality on each triangle of its fan, its texture
    # coordinates split by corner (v0, vj, vj+1); written back with the
    # input's types, and cut with the faces by a removal
    src = _textured_ply(tmp_path / "in.ply", text)
    cloud = formats.read_cloud(src)
    assert np.array_equal(cloud.faces, [[0, 1, 2], [3, 4, 5], [3, 5, 6], [7, 8, 9]])
    assert np.array_equal(cloud.face_attributes["red"], [10, 20, 20, 30])
    assert np.array_equal(cloud.face_attributes["quality"], [0.5, 1.5, 1.5, 2.5])
    q = 100 + np.arange(8)  # the quad's corners 0..3, two values each
    assert np.array_equal(cloud.face_attributes["texcoord"], [
        np.arange(6), [*q[0:2], *q[2:4], *q[4:6]], [*q[0:2], *q[4:6], *q[6:8]],
        200 + np.arange(6)])
    formats.write_cloud(cloud, tmp_path / "out.ply")
    back = PlyData.read(str(tmp_path / "out.ply"))
    assert [(p.name, str(p)) for p in back["face"].properties] == [
        ("vertex_indices", "property list uchar int vertex_indices"),
        ("red", "property uchar red"), ("quality", "property float quality"),
        ("texcoord", "property list uchar float texcoord")]
    again = formats.read_cloud(tmp_path / "out.ply")
    for k, v in cloud.face_attributes.items():
        assert np.array_equal(again.face_attributes[k], v)
        assert again.face_attributes[k].dtype == v.dtype
    keep = np.setdiff1d(np.arange(60), [4])  # vertex 4 goes: the quad's first triangle with it
    cut = cloud.subset(keep)
    assert np.array_equal(cut.face_attributes["red"], [10, 20, 30])
    assert np.array_equal(cut.face_attributes["texcoord"],
                          cloud.face_attributes["texcoord"][[0, 2, 3]])
    pts = np.asarray(CLOUD_60, np.float64)
    far = np.vstack([pts, [[1e6, 1e6, 1e6]]])  # a far point the outlier filter removes
    v = np.array([tuple(p) for p in far], dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    f = PlyData.read(str(src))["face"]
    PlyData([PlyElement.describe(v, "vertex"), f], text=text).write(str(tmp_path / "far.ply"))
    assert main(["outliers", str(tmp_path / "far.ply"), str(tmp_path / "kept.ply"),
                 "--quiet"]) == 0
    kept = formats.read_cloud(tmp_path / "kept.ply")
    assert len(kept) == 60 and np.array_equal(kept.faces, cloud.faces)
    for k, v in cloud.face_attributes.items():
        assert np.array_equal(kept.face_attributes[k], v)


def test_a_face_list_that_is_not_per_corner_is_refused_then_dropped(tmp_path):
    src = _textured_ply(tmp_path / "in.ply", False, odd=True)
    cloud = formats.read_cloud(src)
    assert cloud.meta["face_properties"] == ("texcoord",)
    assert list(cloud.face_attributes) == ["red", "quality"]
    run = ["denoise", str(src), str(tmp_path / "out.ply"), "--quiet"]
    with pytest.raises(PointCloudError, match="faces carry texcoord, which pcprep does not"):
        formats.write_cloud(cloud, tmp_path / "out.ply")
    assert main(run) == 1 and not (tmp_path / "out.ply").exists()
    assert main([*run, "--drop-face-properties"]) == 0
    out = formats.read_cloud(tmp_path / "out.ply")
    assert len(out.faces) == 4 and not out.face_attributes


@pytest.mark.parametrize("quad", [False, "all"])
def test_a_tiled_run_keeps_face_attributes_as_one_piece_does(tmp_path, quad):
    # the faces' colour and quality stream from the memory-mapped face rows
    # beside their triangles: the same file as the one-piece run's
    src = _mesh_float32(tmp_path / "in.ply", 3000, "<", edges=False, quad=quad, props=True)
    for name, tiled in (("one.ply", []), ("tiled.ply", ["--tiles", "400", "--workers", "1"])):
        assert main(["outliers", str(src), str(tmp_path / name), "--method", "radius",
                     "--radius", "1.0", "--quiet", *tiled]) == 0
    one = (tmp_path / "one.ply").read_bytes()
    assert (tmp_path / "tiled.ply").read_bytes() == one
    out, cloud = formats.read_cloud(tmp_path / "one.ply"), formats.read_cloud(src)
    assert 0 < len(out) < len(cloud)
    keep = np.flatnonzero(np.isin(cloud.points[:, 0], out.points[:, 0]))
    ref = cloud.subset(keep)
    assert len(ref.faces) and np.array_equal(out.faces, ref.faces)
    for k in ("red", "quality"):
        assert np.array_equal(out.face_attributes[k], ref.face_attributes[k])


@pytest.mark.parametrize("name", ["cloud.off", "cloud.obj"])
def test_a_tiled_run_on_a_file_read_whole_without_normals(tmp_path, name):
    # OFF and OBJ are read whole; a filter that takes input normals found
    # none there and the tiled run stopped with a traceback
    from pcprep.baselines.datasets import make_shape

    src = tmp_path / name
    formats.write_cloud(Cloud(make_shape("fandisk", n=1500, seed=2).points), src)
    outs = {}
    for key, tiled in (("one", []), ("tiled", ["--tiles", "400", "--workers", "1"])):
        assert main(["saliency", str(src), str(tmp_path / f"{key}.ply"), "--quiet",
                     *tiled]) == 0
        outs[key] = formats.read_cloud(tmp_path / f"{key}.ply")
    assert np.allclose(outs["tiled"].quality, outs["one"].quality, rtol=0, atol=1e-9)
    assert np.ptp(outs["one"].quality) > 0


def test_a_meshset_removal_renumbers_a_ply_s_edges(tmp_path):
    # pcprep's removal in a MeshSet knows the rows it kept: the save renumbers
    # the edges as the command line does; after a MeshLab filter that removed
    # rows pcprep does not know which, so the save refuses to write them wrong
    import pcprep

    _ply_with_elements(tmp_path / "edges.ply")
    assert main(["outliers", str(tmp_path / "edges.ply"), str(tmp_path / "cli.ply"),
                 "--std-ratio", "1", "--quiet"]) == 0
    ms = pcprep.MeshSet()
    ms.load_new_mesh(str(tmp_path / "edges.ply"))
    ms.apply_filter("meshing_remove_point_outliers", std_ratio=1.0)
    ms.save_current_mesh(str(tmp_path / "ms.ply"))
    cli, got = (PlyData.read(str(tmp_path / n)) for n in ("cli.ply", "ms.ply"))
    assert 0 < got["edge"].count < 599
    assert np.array_equal(got["edge"].data, cli["edge"].data)
    ms = pcprep.MeshSet()
    ms.load_new_mesh(str(tmp_path / "edges.ply"))
    ms.apply_filter("meshing_remove_point_outliers", std_ratio=1.0)
    ms.apply_filter("generate_simplified_point_cloud_sdbs", ratio=0.5)
    ms.save_current_mesh(str(tmp_path / "twice.ply"))  # both pcprep's: known rows
    assert PlyData.read(str(tmp_path / "twice.ply"))["edge"].count < got["edge"].count
    ms = pcprep.MeshSet()
    ms.load_new_mesh(str(tmp_path / "edges.ply"))
    mid = float(np.median(PlyData.read(str(tmp_path / "edges.ply"))["vertex"]["x"]))
    ms.compute_selection_by_condition_per_vertex(condselect=f"x < {mid!r}")
    ms.meshing_remove_selected_vertices()
    assert ms.current_mesh().vertex_number() < 600
    ms.apply_filter("meshing_remove_point_outliers", std_ratio=1.0)
    with pytest.raises(PointCloudError, match="element.s. edge refer to vertex rows"):
        ms.save_current_mesh(str(tmp_path / "lost.ply"))
    assert not (tmp_path / "lost.ply").exists()


def test_off_face_colours_are_kept(tmp_path):
    # integers 0-255 or floats 0-1 after a face's indices, alpha or not: a
    # polygon's colour on each triangle of its fan, written back to OFF and
    # PLY; floats keep their point, so 1.0 does not come back as 1 of 255
    verts = "0 0 0\n1 0 0\n0 1 0\n1 1 0\n2 2 0\n"
    (tmp_path / "i.off").write_text(f"OFF\n5 2 0\n{verts}3 0 1 2 255 0 0\n"
                                    "4 1 3 4 2 0 128 255 40\n")
    (tmp_path / "f.off").write_text(f"OFF\n5 1 0\n{verts}3 0 1 2 1.0 0 0\n")
    ints, floats = (formats.read_cloud(tmp_path / n) for n in ("i.off", "f.off"))
    assert np.array_equal(ints.faces, [[0, 1, 2], [1, 3, 4], [1, 4, 2]])
    want = {"red": [255, 0, 0], "green": [0, 128, 128], "blue": [0, 255, 255],
            "alpha": [255, 40, 40]}
    assert {k: v.tolist() for k, v in ints.face_attributes.items()} == want
    assert ints.face_attributes["red"].dtype == np.uint8
    assert {k: v.tolist() for k, v in floats.face_attributes.items()} == {
        "red": [1.0], "green": [0.0], "blue": [0.0]}
    for cloud, name in ((ints, "i"), (floats, "f")):
        for ext in (".off", ".ply"):
            formats.write_cloud(cloud, tmp_path / f"{name}_out{ext}")
            back = formats.read_cloud(tmp_path / f"{name}_out{ext}")
            assert np.array_equal(back.faces, cloud.faces)
            for k, v in cloud.face_attributes.items():
                assert np.array_equal(back.face_attributes[k], v)
                assert back.face_attributes[k].dtype == v.dtype
    quality = ints.with_(face_attributes={**ints.face_attributes, "quality": np.ones(3)})
    with pytest.raises(PointCloudError, match="carry quality, which pcprep does not write"):
        formats.write_cloud(quality, tmp_path / "q.off")
    partial = ints.with_(faces=ints.faces, face_attributes={"red": ints.face_attributes["red"]})
    with pytest.raises(PointCloudError, match="carry red, which pcprep does not write"):
        formats.write_cloud(partial, tmp_path / "r.off")


_OBJ = """mtllib a.mtl
o Box
v 0 0 0
v 1 0 0
v 0 1 0
v 1 1 0
v 2 2 0
vt 0 0
vt 1 0
vt 0 1
vt 1 1
vt 0.5 0.5
g top
usemtl stone
s 1
f 1/1 2/2 3/3
usemtl wood
f 2/2 4/4 5/5 3/3
s off
g side
f -3/-3 -2/-2 -1/-1
"""


def test_obj_texture_coordinates_materials_and_groups_are_kept(tmp_path, capsys):
    # each triangle of a face's fan gets the u v of its corners and the
    # object, group, material and smoothing group in force; written back as
    # the lines that give them, cut with the faces by a removal, and refused
    # where PLY has no place for the names
    (tmp_path / "a.obj").write_text(_OBJ)
    cloud = formats.read_cloud(tmp_path / "a.obj")
    assert np.array_equal(cloud.faces, [[0, 1, 2], [1, 3, 4], [1, 4, 2], [2, 3, 4]])
    assert cloud.face_attributes["texcoord"].tolist() == [
        [0, 0, 1, 0, 0, 1], [1, 0, 1, 1, .5, .5], [1, 0, .5, .5, 0, 1], [0, 1, 1, 1, .5, .5]]
    want = {"object": [0, 0, 0, 0], "group": [0, 0, 0, 1], "material": [0, 1, 1, 1],
            "smoothing": [0, 0, 0, 1]}
    assert {k: cloud.face_attributes[k].tolist() for k in want} == want
    assert cloud.meta["obj"] == {"mtllib": ["a.mtl"], "object": ["Box"],
                                 "group": ["top", "side"], "material": ["stone", "wood"],
                                 "smoothing": ["1", "off"]}
    formats.write_cloud(cloud, tmp_path / "b.obj")
    text = (tmp_path / "b.obj").read_text()
    assert text.count("usemtl") == 2 and text.count("\ng ") == 2 and "mtllib a.mtl" in text
    cut = cloud.subset(np.array([1, 2, 3, 4]))  # vertex 0 goes, and the first face
    for c, name in ((cloud, "b.obj"), (cut, "cut.obj")):
        formats.write_cloud(c, tmp_path / name)
        back = formats.read_cloud(tmp_path / name)
        assert np.array_equal(back.faces, c.faces)
        assert np.array_equal(back.face_attributes["texcoord"], c.face_attributes["texcoord"])
        for k in want:  # the same name on each face (the names unused are not written)
            assert ([back.meta["obj"][k][i] for i in back.face_attributes[k]]
                    == [c.meta["obj"][k][i] for i in c.face_attributes[k]]), (name, k)
    assert cut.face_attributes["material"].tolist() == [1, 1, 1]
    with pytest.raises(PointCloudError, match="object, group, material, smoothing, which "
                                              "pcprep does not write to .ply"):
        formats.write_cloud(cloud, tmp_path / "b.ply")
    formats.write_cloud(formats.drop_face_properties(cloud), tmp_path / "b.ply")
    assert not formats.read_cloud(tmp_path / "b.ply").face_attributes
    assert main(["info", str(tmp_path / "a.obj")]) == 0
    assert "faces: 4 (with texcoord, object, group, material, smoothing)" in (
        capsys.readouterr().out)
    (tmp_path / "w.obj").write_text(_OBJ.replace("vt 0.5 0.5", "vt 0.5 0.5 0.25"))
    assert formats.read_cloud(tmp_path / "w.obj").meta["face_properties"] == (
        "texture coordinates (u v w)",)


@pytest.mark.filterwarnings("ignore:loadtxt")  # plyfile's, on an ASCII row's empty list
@pytest.mark.parametrize("text", [False, True])
def test_a_vertex_list_property_is_kept_in_ply_and_refused_elsewhere(tmp_path, text):
    # a list per point (plyfile's list property on the vertices) was read
    # and then failed every write with NumPy's "truth value" message, after
    # the run; it is now written back as the list it was, in one piece and in
    # a tiled run (which reads such a file whole), and refused before any
    # work by formats that have no place for it
    import pcprep
    from pcprep.meshlab_bridge import tiles

    g = np.random.default_rng(4)
    p = g.normal(size=(2000, 3))
    v = np.empty(2000, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("tags", "O")])
    v["x"], v["y"], v["z"] = (p / np.linalg.norm(p, axis=1)[:, None]).T
    v["tags"] = [np.arange(i % 4, dtype="i2") for i in range(2000)]
    src = tmp_path / "in.ply"
    PlyData([PlyElement.describe(v, "vertex", len_types={"tags": "u2"},
                                 val_types={"tags": "i2"})], text=text).write(str(src))
    formats.write_cloud(formats.read_cloud(src), tmp_path / "same.ply")
    assert (tmp_path / "same.ply").read_bytes() == src.read_bytes()
    for name, tiled in (("one.ply", []), ("tiled.ply", ["--tiles", "500", "--workers", "1"])):
        assert main(["outliers", str(src), str(tmp_path / name), "--quiet", *tiled]) == 0
    assert (tmp_path / "tiled.ply").read_bytes() == (tmp_path / "one.ply").read_bytes()
    out = PlyData.read(str(tmp_path / "one.ply"))["vertex"]
    kept = np.flatnonzero(np.isin(v["x"], out["x"]))
    assert 0 < len(kept) < 2000
    assert [list(t) for t in out["tags"]] == [list(v["tags"][i]) for i in kept]
    assert str(out.ply_property("tags")) == "property list ushort short tags"
    with pytest.MonkeyPatch.context() as m:
        m.setattr(tiles, "dask_client", lambda **kw: pytest.fail("a cluster started"))
        assert main(["saliency", str(src), str(tmp_path / "o.las"), "--quiet",
                     "--tiles", "500", "--workers", "1"]) == 1
    with pytest.raises(PointCloudError, match="tags hold a list per point"):
        formats.write_cloud(formats.read_cloud(src), tmp_path / "o.pcd")
    ms = pcprep.MeshSet()
    with pytest.raises(PointCloudError, match="'tags' holds a list per point"):
        ms.load_new_mesh(str(src))
    assert ms.mesh_number() == 0  # no layer half made


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_extended_vlrs_survive_a_streamed_write(tmp_path, ext):
    # laspy's writer leaves a LAS 1.4 file's EVLRs to its caller: a tiled
    # run wrote its result without them, the one-piece run with them
    from pcprep.meshlab_bridge import registry
    from pcprep.meshlab_bridge.formats import stream

    registry.load_all()
    src = _random_las(tmp_path / f"in{ext}", 6, n=3000)
    want = [(v.user_id, v.record_id, v.record_data) for v in laspy.read(str(src)).evlrs]
    assert want == [("pcprep_test", 7, b"after the points")]
    n = 3000
    runs = {"outliers": {"keep_idx": np.arange(0, n, 3)},  # kept records copied
            "saliency": {"saliency": np.linspace(0, 1, n)}}  # records rebuilt
    for name, fields in runs.items():
        spec = registry.get(name)
        dst = tmp_path / f"{name}{ext}"
        stream.write_streamed(spec, src, dst, fields, size=1000)
        got = laspy.read(str(dst))
        assert [(v.user_id, v.record_id, v.record_data) for v in got.evlrs] == want, name
        assert len(got.points) == len(next(iter(fields.values())))



@pytest.mark.parametrize("tiled", [[], ["--tiles", "500", "--workers", "1"]])
def test_an_organised_pcd_keeps_its_grid_where_every_row_stays(tmp_path, tiled):
    # WIDTH x HEIGHT (a depth camera's image grid) was written as WIDTH n
    # HEIGHT 1; a filter that keeps every row in its place now keeps it, and
    # its viewpoint, and a removal writes the rows it kept as one line
    g = np.random.default_rng(3)
    u, v = np.meshgrid(np.arange(40), np.arange(30))
    pts = np.c_[u.ravel(), v.ravel(), 0.05 * g.random(1200)].astype(np.float32)
    pts[7] = [500, 500, 500]  # one far point for the removal
    head = ("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 40\n"
            "HEIGHT 30\nVIEWPOINT 1 2 3 1 0 0 0\nPOINTS 1200\nDATA binary\n")
    (tmp_path / "grid.pcd").write_bytes(head.encode() + pts.tobytes())
    for name, want in (("saliency", "WIDTH 40\nHEIGHT 30\n"),
                       ("outliers", "WIDTH 1199\nHEIGHT 1\n")):
        dst = tmp_path / f"{name}.pcd"
        assert main([name, str(tmp_path / "grid.pcd"), str(dst), "--quiet", *tiled]) == 0
        text = dst.read_bytes()[:600].decode("ascii", "replace")
        assert want in text and "VIEWPOINT 1 2 3 1 0 0 0" in text, name


@pytest.mark.parametrize("tiled", [[], ["--tiles", "500", "--workers", "1"]])
def test_obj_polylines_and_point_groups_are_kept_and_cut_by_a_removal(tmp_path, tiled):
    # `l` and `p` lines were read past without a word; they are written back,
    # a polyline cut where it meets a removed vertex (pieces of 2 vertices or
    # more kept), a point group without the removed ones; refused by formats
    # that have no place for them unless --drop-elements, before any work
    from pcprep.meshlab_bridge import tiles

    g = np.random.default_rng(6)
    p = g.normal(size=(1500, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    p[10] = [40, 40, 40]  # a far point the outlier filter removes
    lines = "l 9 10 11 12 13\nl 13 1\np 2 11 4\np 11\n"
    src = tmp_path / "in.obj"
    src.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in p.tolist()) + lines)
    cloud = formats.read_cloud(src)
    assert [r.tolist() for r in cloud.meta["obj"]["polylines"]] == [[8, 9, 10, 11, 12], [12, 0]]
    assert [r.tolist() for r in cloud.meta["obj"]["point groups"]] == [[1, 10, 3], [10]]
    formats.write_cloud(cloud, tmp_path / "same.obj")
    assert (tmp_path / "same.obj").read_text().endswith(lines)
    assert main(["outliers", str(src), str(tmp_path / "out.obj"), "--quiet", *tiled]) == 0
    out = formats.read_cloud(tmp_path / "out.obj")
    assert len(out) == 1499
    assert [r.tolist() for r in out.meta["obj"]["polylines"]] == [[8, 9], [10, 11], [11, 0]]
    assert [r.tolist() for r in out.meta["obj"]["point groups"]] == [[1, 3]]
    with pytest.MonkeyPatch.context() as m:
        m.setattr(tiles, "dask_client", lambda **kw: pytest.fail("a cluster started"))
        assert main(["outliers", str(src), str(tmp_path / "out.ply"), "--quiet", *tiled]) == 1
    assert not (tmp_path / "out.ply").exists()
    assert main(["outliers", str(src), str(tmp_path / "out.ply"), "--quiet", "--drop-elements",
                 *tiled]) == 0
