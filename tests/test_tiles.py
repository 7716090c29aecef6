"""Tiled runs on Dask (meshlab_bridge/tiles.py): the result of every row equals the
one-piece run's, on seams, with tiles smaller than a neighbourhood, with empty
cells, and when a worker is killed mid-run."""

import math
import os
import signal

import numpy as np
import pytest

distributed = pytest.importorskip("dask.distributed", reason="needs pcprep[scale]")

from pcprep.filters._validation import InvalidParameterError, PointCloudError  # noqa: E402
from pcprep.filters.denoise import denoise_l1_tv  # noqa: E402
from pcprep.filters.outliers import remove_outliers  # noqa: E402
from pcprep.filters.saliency import saliency_sparse_mdl  # noqa: E402
from pcprep.meshlab_bridge import tiles  # noqa: E402


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as c:
        yield c


def _surface(n, seed=0, outliers=5):
    g = np.random.default_rng(seed)
    xy = g.uniform(-1, 1, (n, 2))
    z = 0.3 * np.sin(3 * xy[:, 0]) * np.cos(2 * xy[:, 1]) + 0.004 * g.normal(size=n)
    pts = np.c_[xy, z] + [3e5, -2e5, 100.0]  # far from the origin, like UTM data
    pts[:outliers] += g.normal(size=(outliers, 3)) * 0.4
    return pts


CLOUD = _surface(20_000)
DENOISE = {"n_iter": 1}


@pytest.fixture(scope="module")
def denoise_ref():
    return denoise_l1_tv(CLOUD, **DENOISE)


def test_denoise_equals_one_piece(client, denoise_ref):
    res = tiles.run_tiled("denoise", CLOUD, params=DENOISE, client=client, tiles=2500)
    f, ref = res.fields, denoise_ref
    assert res.stats["tiles"] >= 6
    assert np.abs(f["points"] - ref.points).max() <= 1e-9 * ref.h
    dots = np.einsum("ij,ij->i", f["normals"], ref.normals)
    assert np.abs(1.0 - dots).max() <= 1e-9  # same normals, same signs
    assert np.array_equal(f["edge_mask"], ref.edge_mask)
    assert abs(res.h - ref.h) <= 1e-12 * ref.h


def test_denoise_with_normals_keeps_their_orientation(client):
    g = np.random.default_rng(1)
    hint = np.c_[0.1 * g.normal(size=(len(CLOUD), 2)), np.ones(len(CLOUD))]
    hint /= np.linalg.norm(hint, axis=1)[:, None]
    ref = denoise_l1_tv(CLOUD, hint, **DENOISE)
    res = tiles.run_tiled("denoise", CLOUD, hint, params=DENOISE, client=client, tiles=4000)
    assert np.abs(res.fields["points"] - ref.points).max() <= 1e-9 * ref.h
    assert np.abs(res.fields["normals"] - ref.normals).max() <= 1e-9


def test_saliency_equals_one_piece(client, monkeypatch):
    monkeypatch.setattr(tiles, "CHUNK", 5000)  # the driver's element-wise maps in chunks
    pts = CLOUD[:12_000]
    ref = saliency_sparse_mdl(pts)
    res = tiles.run_tiled("saliency", pts, client=client, tiles=2000)
    assert res.stats["tiles"] >= 4
    assert np.abs(res.fields["saliency"] - ref.saliency).max() <= 1e-9
    # F̄_g is the one-piece mean to the bit, so every Lasso problem is the same:
    # the codes' measure is identical, not merely close
    assert np.array_equal(res.fields["neighbourhood_saliency"], ref.neighbourhood_saliency)


def _surface_normals(pts, seed):
    """The unit normals of ``_surface`` at ``pts``, each with a random sign (a
    one-piece run keeps given signs, so a tiled run must too)."""
    x, y = pts[:, 0] - 3e5, pts[:, 1] + 2e5
    nrm = np.c_[-0.9 * np.cos(3 * x) * np.cos(2 * y), 0.6 * np.sin(3 * x) * np.sin(2 * y),
                np.ones(len(pts))]
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    return nrm * np.random.default_rng(seed).choice([-1.0, 1.0], len(pts))[:, None]


def test_saliency_with_normals_equals_one_piece(client):
    pts = CLOUD[:12_000]
    nrm = _surface_normals(pts, 2)
    ref = saliency_sparse_mdl(pts, nrm)
    res = tiles.run_tiled("saliency", pts, nrm, client=client, tiles=2000)
    assert res.stats["tiles"] >= 4
    assert np.abs(res.fields["saliency"] - ref.saliency).max() <= 1e-9
    assert np.array_equal(res.fields["neighbourhood_saliency"], ref.neighbourhood_saliency)
    assert np.array_equal(res.fields["normals"], ref.normals)
    # the given signs matter: without them the answer is another one
    assert np.abs(saliency_sparse_mdl(pts).saliency - ref.saliency).max() > 1e-3


def test_tiled_normals_are_refused_as_one_piece_refuses_them(client):
    nrm = _surface_normals(CLOUD, 3)
    bad = nrm.copy()
    bad[[7, 9000]] = 0.0
    with pytest.raises(PointCloudError, match=r"zero-length or non-finite rows \(rows 7, 9000\)"):
        tiles.run_tiled("saliency", CLOUD, bad, client=client, tiles=4000)
    with pytest.raises(PointCloudError, match="expected \\(20000, 3\\)"):
        tiles.run_tiled("denoise", CLOUD, nrm[:-1], client=client, tiles=4000)
    with pytest.raises(InvalidParameterError, match="features: takes no input normals"):
        tiles.run_tiled("features", CLOUD, nrm, client=client, tiles=4000)


@pytest.mark.parametrize("name", ["outliers", "denoise", "saliency", "features", "holes",
                                  "simplify"])
def test_tiled_refuses_too_few_points_as_one_piece_does(client, name):
    """The fewest points a tiled run takes are the one-piece run's, with its
    message (a 5-point cloud ran tiled and was written out)."""
    from pcprep.meshlab_bridge import registry

    spec = tiles._spec(registry, name)
    prm = dict(spec.resolve({"ratio": 0.5} if name == "simplify" else {}))
    need = tiles._min_points(spec.command, prm)
    pts = CLOUD[:need - 1]
    prm.pop("preset", None)
    with pytest.raises(PointCloudError) as one:
        spec.func(pts, **prm)
    with pytest.raises(PointCloudError) as tiled:
        tiles.run_tiled(name, pts, params=prm, client=client, tiles=1000)
    assert str(tiled.value) == str(one.value)
    assert f"needs at least {need} points" in str(one.value)


def test_tiled_refuses_collinear_and_duplicate_points(client):
    line = np.c_[np.linspace(0, 1, 500), 2 * np.linspace(0, 1, 500), np.zeros(500)] + 1e5
    with pytest.raises(PointCloudError, match="remove_outliers: all points are collinear"):
        tiles.run_tiled("outliers", line, client=client, tiles=100)
    pts = CLOUD.copy()
    pts[15_000] = pts[123]
    with pytest.raises(PointCloudError, match="remove_outliers: 1 duplicate point"):
        remove_outliers(pts)
    for worker_io in (True, False):  # found by the tile that holds both rows
        with pytest.raises(PointCloudError, match=r"remove_outliers: duplicate points "
                           r"\(rows 123 and 15000, and maybe others\)"):
            tiles.run_tiled("outliers", pts, client=client, tiles=2500, worker_io=worker_io)


class _NewestFirst:
    """``distributed.as_completed`` that hands out the newest future first:
    tile results then arrive in an order unlike the cells' (and unlike
    what two idle workers give), as on a busy cluster."""

    def __init__(self):
        self._futures = []

    def add(self, fut):
        self._futures.append(fut)

    def count(self):
        return len(self._futures)

    def __iter__(self):
        while self._futures:
            distributed.wait(self._futures)
            yield self._futures.pop()


@pytest.mark.parametrize("name", ["saliency", "denoise"])
def test_results_do_not_depend_on_the_order_tiles_finish(client, monkeypatch, name):
    # the cloud-wide sums (saliency's mean block, denoise's decision traces)
    # and the tiles' sign votes are taken in cell order, so that the same
    # cloud gives the same bits whichever tile comes back first
    params = DENOISE if name == "denoise" else None
    first = tiles.run_tiled(name, CLOUD, params=params, client=client, tiles=2000)
    monkeypatch.setattr(distributed, "as_completed", _NewestFirst)
    again = tiles.run_tiled(name, CLOUD, params=params, client=client, tiles=2000)
    assert first.stats["tiles"] >= 8
    for key, v in first.fields.items():
        assert np.array_equal(v, again.fields[key]), key


@pytest.mark.parametrize("method", ["statistical", "radius"])
def test_outliers_identical(client, method):
    ref = remove_outliers(CLOUD, method=method)
    res = tiles.run_tiled("outliers", CLOUD, params={"method": method}, client=client,
                          tiles=1500)
    assert len(ref.removed_idx) > 0
    assert np.array_equal(res.fields["removed_idx"], ref.removed_idx)
    assert np.array_equal(res.fields["score"], ref.score)


def test_driver_keeps_per_row_results_on_disk(client, tmp_path, monkeypatch):
    # with a scratch folder every per-row field is a memory map in it (the
    # driver's memory does not grow with the cloud); without one, arrays.  The
    # driver's chunk is cut to 3000 rows so that its chunked loops (ingest,
    # index, the written-once check, the copies to disk) run over many chunks
    monkeypatch.setattr(tiles, "CHUNK", 3000)
    ref = remove_outliers(CLOUD)
    res = tiles.run_tiled("outliers", CLOUD, client=client, tiles=1500,
                          scratch=str(tmp_path))
    for name, v in res.fields.items():
        assert isinstance(v, np.memmap), name
        assert os.path.dirname(os.path.abspath(v.filename)) == str(tmp_path), name
    assert np.array_equal(res.fields["removed_idx"], ref.removed_idx)
    assert np.array_equal(res.fields["keep_idx"], ref.keep_idx)
    assert np.array_equal(res.fields["score"], ref.score)
    assert not [f for f in os.listdir(tmp_path) if f.startswith("seen")]  # pass checks gone
    with pytest.raises(InvalidParameterError, match="already holds"):  # never overwritten
        tiles.run_tiled("outliers", CLOUD, client=client, tiles=1500, scratch=str(tmp_path))
    assert np.array_equal(res.fields["score"], ref.score)
    own = tiles.run_tiled("outliers", CLOUD, client=client, tiles=1500)
    assert not any(isinstance(v, np.memmap) for v in own.fields.values())
    assert np.array_equal(own.fields["keep_idx"], ref.keep_idx)


def test_rows_where_lists_a_stored_masks_rows_chunk_by_chunk(tmp_path, monkeypatch):
    # the outlier lists of a tiled run: np.flatnonzero, built in chunks of the
    # driver (7 rows here) into the scratch folder, empty and full lists included
    monkeypatch.setattr(tiles, "CHUNK", 7)
    runner = object.__new__(tiles._Runner)  # rows_where needs the scratch folder only
    runner.scratch = str(tmp_path)
    mask = np.random.default_rng(1).random(50) < 0.3
    for name, m, value in [("some", mask, True), ("others", mask, False),
                           ("none", np.zeros(20, bool), True), ("all", np.zeros(20, bool), False)]:
        got = runner.rows_where(name, m, value)
        assert isinstance(got, np.memmap) and got.dtype == np.int64
        assert np.array_equal(got, np.flatnonzero(m == value)), name


def test_rows_on_seams_belong_to_one_core(client):
    # a third of the points moved exactly onto the grid's cell faces
    g = np.random.default_rng(2)
    pts = CLOUD.copy()
    side = 0.25
    lo = pts.min(axis=0)
    pick = g.choice(len(pts), len(pts) // 3, replace=False)
    pts[pick, 0] = lo[0] + np.round((pts[pick, 0] - lo[0]) / side) * side
    pts[pick, 1] = lo[1] + np.round((pts[pick, 1] - lo[1]) / side) * side
    on_face = np.isclose(((pts[:, 0] - lo[0]) / side) % 1.0, 0.0)
    assert on_face.sum() > 1000
    ref = remove_outliers(pts)
    res = tiles.run_tiled("outliers", pts, client=client, grid_side=side)
    assert res.stats["grid_side"] == side
    assert np.array_equal(res.fields["score"], ref.score)  # every row written once


def test_small_and_empty_tiles(client):
    # two clusters far apart (the cells between them are empty) and a group of
    # five points, fewer than one neighbourhood, alone in its tile
    g = np.random.default_rng(3)
    a = _surface(6000, seed=4, outliers=0)
    b = a[:3000] + [5.0, 0.0, 0.0]
    lone = a[0] + [2.5, 2.5, 0.0] + 0.05 * g.normal(size=(5, 3))
    pts = np.r_[a, b, lone]
    ref = remove_outliers(pts)
    res = tiles.run_tiled("outliers", pts, client=client, tiles=800)
    cells = int(np.prod(res.stats["grid_shape"]))
    assert res.stats["tiles"] < cells  # empty cells exist and are skipped
    assert np.array_equal(res.fields["score"], ref.score)
    assert set(range(len(a) + len(b), len(pts))) <= set(ref.removed_idx)


def test_killed_worker_loses_nothing(client, denoise_ref):
    killed = []

    def kill_one(label, cell):
        if label == "denoise" and not killed:
            pids = client.run(os.getpid)
            addr, pid = sorted(pids.items())[0]
            killed.append(addr)
            os.kill(pid, signal.SIGKILL)

    res = tiles.run_tiled("denoise", CLOUD, params=DENOISE, client=client, tiles=2500,
                          on_result=kill_one)
    assert killed
    ref = denoise_ref
    assert np.abs(res.fields["points"] - ref.points).max() <= 1e-9 * ref.h
    assert np.array_equal(res.fields["edge_mask"], ref.edge_mask)
    client.wait_for_workers(2, timeout=60)


def test_unknown_or_untiled_filter_is_refused(client):
    from pcprep.filters import InvalidParameterError

    with pytest.raises(InvalidParameterError, match="unknown filter"):
        tiles.run_tiled("nope", CLOUD, client=client)
    with pytest.raises(InvalidParameterError, match="tiles must be"):
        tiles.run_tiled("outliers", CLOUD, client=client, tiles=0)


def test_cli_tiled_laz_equals_one_piece(tmp_path):
    import laspy

    from pcprep.meshlab_bridge.cli import main

    g = np.random.default_rng(5)
    n = 12_000
    pts = _surface(n, seed=5, outliers=0)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets = np.floor(pts.min(axis=0))
    header.scales = [1e-4] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts.T
    las.intensity = g.integers(0, 65535, n)
    las.classification = g.integers(0, 10, n)
    las.gps_time = np.arange(n) * 0.1
    src = tmp_path / "in.laz"
    las.write(src)
    assert main(["saliency", str(src), str(tmp_path / "one.laz"), "--quiet"]) == 0
    assert main(["saliency", str(src), str(tmp_path / "tiled.laz"), "--tiles", "3000",
                 "--workers", "2", "--quiet"]) == 0
    a, b = laspy.read(tmp_path / "one.laz"), laspy.read(tmp_path / "tiled.laz")
    names = list(a.point_format.dimension_names)
    assert names == list(b.point_format.dimension_names)
    assert {"intensity", "classification", "gps_time", "saliency"} <= set(names)
    for d in names:
        va, vb = np.asarray(a[d], np.float64), np.asarray(b[d], np.float64)
        if d == "saliency" or d == "quality":
            assert np.abs(va - vb).max() <= 1e-9, d
        elif d not in ("red", "green", "blue"):  # colours: a ramp of the saliency
            assert np.array_equal(va, vb), d


@pytest.mark.parametrize("name", ["saliency", "denoise"])
def test_cli_tiled_uses_the_files_normals_as_one_piece_does(tmp_path, name):
    from plyfile import PlyData, PlyElement

    from pcprep.meshlab_bridge.cli import main

    pts = _surface(8000, seed=9, outliers=0)
    nrm = _surface_normals(pts, 4)
    v = np.zeros(len(pts), dtype=[(c, "f8") for c in ("x", "y", "z", "nx", "ny", "nz")])
    for j, c in enumerate("xyz"):
        v[c], v["n" + c] = pts[:, j], nrm[:, j]
    src = tmp_path / "in.ply"
    PlyData([PlyElement.describe(v, "vertex")]).write(str(src))
    extra = ["--n-iter", "1"] if name == "denoise" else []
    assert main([name, str(src), str(tmp_path / "one.ply"), "--quiet", *extra]) == 0
    assert main([name, str(src), str(tmp_path / "tiled.ply"), "--tiles", "2000",
                 "--workers", "2", "--quiet", *extra]) == 0
    a = PlyData.read(str(tmp_path / "one.ply"))["vertex"].data
    b = PlyData.read(str(tmp_path / "tiled.ply"))["vertex"].data
    assert a.dtype == b.dtype
    for c in a.dtype.names:
        assert np.abs(a[c].astype(np.float64) - b[c].astype(np.float64)).max() <= 1e-9, c
    # the given signs are kept (denoise: as an orientation hint)
    got = np.c_[b["nx"], b["ny"], b["nz"]]
    assert (np.einsum("ij,ij->i", got, nrm) > 0).mean() > 0.99


def test_cli_refuses_bad_tiles(capsys):
    from pcprep.meshlab_bridge.cli import main

    with pytest.raises(SystemExit):
        main(["denoise", "a.ply", "b.ply", "--tiles", "0"])
    assert "positive count" in capsys.readouterr().err


@pytest.mark.parametrize("cut", ["record", "inside"])
def test_cli_tiled_refuses_a_truncated_las(tmp_path, capsys, cut):
    """A LAS file cut short (at a record's end, where laspy's chunks simply
    stop, or inside one) is refused with the counts, and nothing is written;
    the ingest refuses chunks that do not cover the declared rows."""
    import laspy

    from pcprep.meshlab_bridge.cli import main

    pts = _surface(5000, seed=8, outliers=0)
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.offsets, header.scales = np.floor(pts.min(axis=0)), [1e-4] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts.T
    whole = tmp_path / "whole.las"
    las.write(whole)
    size = header.offset_to_point_data + 3000 * header.point_format.size
    src = tmp_path / "cut.las"
    src.write_bytes(whole.read_bytes()[:size + (0 if cut == "record" else 7)])
    dst = tmp_path / "out.las"
    assert main(["outliers", str(src), str(dst), "--tiles", "1000", "--workers", "1",
                 "--quiet"]) != 0
    err = capsys.readouterr().err
    assert "declares 5000 points, the file holds 3000" in err or "truncated" in err, err
    assert not dst.exists()
    from pcprep.meshlab_bridge.formats import stream

    with pytest.raises(PointCloudError, match="truncated|declares 5000 points, the file "
                       "holds 3000"):
        for _ in stream.position_chunks(src, size=1000):  # blocks that end on records
            pass
    with pytest.raises(PointCloudError, match="holds 3 rows, not the 4"):
        tiles.ingest(iter([(0, pts[:3])]), 4, str(tmp_path))
    with pytest.raises(PointCloudError, match="do not match its point count 4"):
        tiles.ingest(iter([(0, pts[:3]), (3, pts[:3])]), 4, str(tmp_path))


def _jittered_grid_with_hole(side=160, seed=6):
    # mesh-like sampling (a jittered grid: no exact neighbour ties) with a round hole
    g = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(side), np.arange(side))
    p = np.c_[u.ravel(), v.ravel()].astype(np.float64)
    p += 0.05 * g.normal(size=p.shape)
    p = p[np.linalg.norm(p - 0.4 * side, axis=1) > 0.12 * side]
    z = 0.002 * side * np.sin(p[:, 0] / 9.0)
    return np.c_[p, z] * 0.01 + [5e5, 4e6, 30.0]


def test_features_identical_on_200k_points(client):
    from pcprep.baselines.datasets import make_shape
    from pcprep.filters.sharp import detect_sharp_features

    s = make_shape("fandisk", n=200_000, seed=2)
    pts = s.points + [4e5, -3e6, 50.0]
    ref = detect_sharp_features(pts)
    res = tiles.run_tiled("features", pts, client=client, tiles=20_000)
    assert res.stats["tiles"] >= 8
    assert ref.mask.sum() > 1000
    assert np.array_equal(res.fields["mask"], ref.mask)
    assert np.array_equal(res.fields["score"], ref.score)
    assert res.h == ref.h
    # the driver's CPU time is kept for every pass whose wall time is
    cpu = res.stats["cpu_passes"]
    assert set(cpu) == set(res.stats["time_passes"]) and all(v > 0 for v in cpu.values())
    # ... and of it the main thread's, pcprep's own work, a part of the whole
    main = res.stats["cpu_passes_main"]
    assert set(main) == set(cpu) and all(0 < main[k] <= cpu[k] + 1e-3 for k in cpu)


@pytest.mark.parametrize("kw", [{"k_min": 5, "k_max": 6, "n_scales": 2},
                                {"k_min": 12, "k_max": 12, "n_scales": 4}])
def test_features_identical_with_few_scales(client, kw):
    # k_max ≤ 6: h needs a pass of its own (the features' query does not
    # reach the 6 nearest); k_min = k_max: the scales collapse to one
    from pcprep.baselines.datasets import make_shape
    from pcprep.filters.sharp import detect_sharp_features

    pts = make_shape("fandisk", n=30_000, seed=5).points
    ref = detect_sharp_features(pts, **kw)
    res = tiles.run_tiled("features", pts, params=kw, client=client, tiles=4000)
    assert res.stats["tiles"] >= 6
    assert ref.mask.sum() > 200
    assert ("spacing" in res.stats["time_passes"]) == (kw["k_max"] <= 6)
    assert np.array_equal(res.fields["mask"], ref.mask)
    assert np.array_equal(res.fields["score"], ref.score)
    assert res.h == ref.h


def _tied_grid(n):
    """A grid of quantised heights with a step and a hole: nearly every row's
    neighbour distances hold ties, at every scale's boundary too."""
    u, v = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    z = np.round(3.0 * np.sin(u / 7.0) + 2.0 * (u + v > 1.2 * n), 2)
    p = np.c_[u.ravel(), v.ravel(), z.ravel()]
    p = p[np.linalg.norm(p[:, :2] - 0.3 * n, axis=1) > 0.08 * n]
    return p * 0.01 + [1000.0, 2000.0, 10.0]


@pytest.mark.parametrize("name", ["features", "holes", "saliency"])
def test_tied_distances_give_the_one_piece_result(client, name):
    # a tile ranks equal distances as the whole cloud does (by position), so
    # neighbourhoods and scales match; before, features differed in 38 of 472
    # mask rows and every score here, holes in one row and saliency by 1e-2
    from pcprep.filters.holes import detect_hole_boundaries
    from pcprep.filters.saliency import saliency_sparse_mdl
    from pcprep.filters.sharp import detect_sharp_features

    pts = _tied_grid(160)
    fn = {"features": detect_sharp_features, "holes": detect_hole_boundaries,
          "saliency": saliency_sparse_mdl}[name]
    ref = fn(pts)
    res = tiles.run_tiled(name, pts, client=client, tiles=len(pts) // 8)
    assert res.stats["tiles"] >= 8
    if name == "saliency":
        np.testing.assert_allclose(res.fields["saliency"], ref.saliency, rtol=0, atol=1e-9)
        assert ref.saliency.std() > 0
    else:
        assert ref.mask.sum() > 300
        assert np.array_equal(res.fields["mask"], ref.mask)
        assert np.array_equal(res.fields["score"], ref.score)


@pytest.mark.parametrize("cloud", ["random", "mesh-like"])
def test_holes_identical(client, cloud):
    from pcprep.baselines.datasets import make_shape
    from pcprep.filters.holes import detect_hole_boundaries

    # random-like sampling runs the smallest-hole test, mesh-like the border row
    pts = (make_shape("disc", n=30_000, seed=3).points if cloud == "random"
           else _jittered_grid_with_hole())
    # mesh-like with scales that collapse to two (k_min = 30, k_max = 31)
    kw = {} if cloud == "random" else {"k_min": 30, "k_max": 31}
    ref = detect_hole_boundaries(pts, **kw)
    res = tiles.run_tiled("holes", pts, params=kw, client=client, tiles=3000)
    assert res.stats["tiles"] >= 6
    assert ref.mask.sum() > 200
    assert np.array_equal(res.fields["mask"], ref.mask)
    assert np.array_equal(res.fields["score"], ref.score)


def test_cli_tiled_features_ply(tmp_path):
    from pcprep.baselines.datasets import make_shape
    from pcprep.meshlab_bridge.cli import main
    from pcprep.meshlab_bridge.formats import read_cloud, write_cloud
    from pcprep.meshlab_bridge.cloud import Cloud

    s = make_shape("cube", n=20_000, seed=4)
    src = tmp_path / "cube.ply"
    write_cloud(Cloud(points=s.points), src)
    assert main(["features", str(src), str(tmp_path / "one.ply"), "--quiet"]) == 0
    assert main(["features", str(src), str(tmp_path / "tiled.ply"), "--tiles", "2500",
                 "--workers", "2", "--quiet"]) == 0
    assert main(["features", str(src), str(tmp_path / "sent.ply"), "--tiles", "2500",
                 "--workers", "2", "--worker-io", "off", "--quiet"]) == 0
    a, b = read_cloud(tmp_path / "one.ply"), read_cloud(tmp_path / "tiled.ply")
    c = read_cloud(tmp_path / "sent.ply")
    assert a.quality.sum() > 500
    assert np.array_equal(a.quality, b.quality) and np.array_equal(a.quality, c.quality)
    assert np.array_equal(a.points, b.points)


def _scan_vertices(pts, position: str) -> np.ndarray:
    """PLY vertex rows of ``pts``: positions of type ``position`` and a colour."""
    rows = np.empty(len(pts), dtype=[("x", position), ("y", position), ("z", position),
                                     ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for c, v in zip("xyz", pts.T):
        rows[c] = v
    for c in ("red", "green", "blue"):
        rows[c] = np.arange(len(pts)) % 251
    return rows


def _outliers_one_and_tiled(tmp_path, monkeypatch, src):
    """``pcprep outliers`` on ``src`` in one piece, then tiled on 2 workers in
    blocks of 1000 rows with the whole read made to fail: the two files' bytes."""
    from pcprep.meshlab_bridge.cli import main
    from pcprep.meshlab_bridge.formats import stream

    assert main(["outliers", str(src), str(tmp_path / "one.ply"), "--quiet"]) == 0

    def whole(*a, **k):
        raise AssertionError("the tiled run read the whole file")

    monkeypatch.setattr(stream, "read_cloud", whole)
    monkeypatch.setattr(stream, "CHUNK", 1000)
    assert main(["outliers", str(src), str(tmp_path / "tiled.ply"), "--tiles", "1500",
                 "--workers", "2", "--quiet"]) == 0
    return (tmp_path / "one.ply").read_bytes(), (tmp_path / "tiled.ply").read_bytes()


def test_cli_tiled_ascii_ply_is_streamed_and_equals_one_piece(tmp_path, monkeypatch):
    # an ASCII PLY (float64 positions, a colour and a scanner's column) through
    # the tiled command line: read and written in blocks, never whole, and the
    # same ASCII file as the one-piece run's
    import plyfile
    from numpy.lib.recfunctions import append_fields

    pts = CLOUD[:6000]
    rows = append_fields(_scan_vertices(pts, "f8"), "gps_time",
                         1e9 + np.arange(len(pts)) / 7.0, usemask=False)
    src = tmp_path / "scan.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rows, "vertex")], text=True).write(str(src))
    one, tiled = _outliers_one_and_tiled(tmp_path, monkeypatch, src)
    assert b"format ascii" in one[:30] and one.count(b"\n") < rows.size + 20
    assert tiled == one


def test_cli_tiled_binary_mesh_is_streamed_and_equals_one_piece(tmp_path, monkeypatch):
    # a binary PLY of triangles through the tiled command line: the vertices
    # read and written in blocks, the triangles after them renumbered where
    # outliers were removed, the same file as the one-piece run's
    import plyfile

    from pcprep.meshlab_bridge.formats import read_cloud

    pts = CLOUD[:6000]
    i = np.arange(len(pts) - 2)
    face = np.empty(len(i), dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = np.c_[i, i + 1, i + 2]
    src = tmp_path / "scan.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(_scan_vertices(pts, "f4"), "vertex"),
                     plyfile.PlyElement.describe(face, "face")]).write(str(src))
    one, tiled = _outliers_one_and_tiled(tmp_path, monkeypatch, src)
    kept = read_cloud(tmp_path / "one.ply")
    assert 0 < len(pts) - len(kept) < 100 and 0 < len(kept.faces) < len(i)
    assert tiled == one


def test_denoise_plan_replay_finds_the_cloud_decisions():
    # two tiles of 60 and 40 core rows and a fixed sequence of "is the RMS move
    # below tol" decisions; per decision each tile's sum of squared moves.  At
    # decision 3 the small tile alone has settled (its local answer is "yes",
    # the cloud's "no"); at decision 5 both and the cloud have.
    tol, sizes = 0.1, (60, 40)
    rms = [(0.5, 0.5), (0.3, 0.3), (0.2, 0.2), (0.15, 0.05), (0.12, 0.11), (0.05, 0.05)]
    sums = [[(r * tol) ** 2 * m / tol ** 2 for r, m in zip(row, sizes)] for row in rms]
    truth = [math.sqrt(sum(row) / sum(sizes)) < tol for row in sums]
    assert truth == [False] * 5 + [True]

    def run(plan):  # the tiles' traces: the plan, then each tile's own answer
        return [[("move", sums[i][t], 0.0, plan[i] if i < len(plan)
                  else math.sqrt(sums[i][t] / sizes[t]) < tol) for i in range(len(sums))]
                for t in range(2)]

    plan, runs = [], 0
    while True:
        runs += 1
        wrong = tiles._replay(run(plan), plan, sum(sizes), tol)
        if wrong is None:
            break
        assert len(wrong) > len(plan)  # every run fixes one more decision
        plan = wrong
    assert runs == 2 and plan == truth[:4]  # one miss: the small tile's early "yes"
    assert [d[3] for d in run(plan)[1]] == truth


def test_simplify_exact_count_and_same_error(client):
    from pcprep.baselines.datasets import make_shape
    from pcprep.filters.metrics import simplification_error
    from pcprep.filters.simplify import simplify_sdbs

    pts = make_shape("fandisk", n=60_000, seed=1).points + [4e5, 3e6, 10.0]
    ref = simplify_sdbs(pts, ratio=0.1)
    res = tiles.run_tiled("simplify", pts, params={"ratio": 0.1}, client=client,
                          tiles=8000)
    got = res.fields["keep_idx"]
    assert res.stats["tiles"] >= 6
    assert len(got) == len(ref.keep_idx) == 6000          # the exact requested count
    a, b = set(ref.keep_idx.tolist()), set(got.tolist())
    assert len(a & b) / len(a | b) >= 0.97
    e_ref = simplification_error(pts, pts[ref.keep_idx])
    e_got = simplification_error(pts, pts[got])
    assert abs(e_got[0] - e_ref[0]) <= 0.01 * e_ref[0]
    assert abs(e_got[1] - e_ref[1]) <= 0.01 * e_ref[1]


def test_grid_cells_fill_the_box_without_slivers(tmp_path):
    # 5.05 × 5 plane: a cubic grid of side 1 (or 2.5) would add a last row of
    # cells 0.05 wide; the fitted grid's cells share the box evenly
    g = np.random.default_rng(6)
    pts = np.c_[g.uniform(0, 5.05, 50_000), g.uniform(0, 5.0, 50_000), np.zeros(50_000)]
    src = tiles.source_from_array(pts, str(tmp_path))
    index = tiles.build_index(src, 10_000, str(tmp_path))
    counts = np.diff(index.start)[index.cells]
    assert counts.mean() <= 10_000
    assert counts.min() > 0.5 * counts.max()
    assert np.array_equal(np.sort(np.asarray(index.order)), np.arange(len(pts)))
    assert np.array_equal(index.xyz, pts[index.order])  # positions in cell order
    lo, hi = index.cell_box(int(index.cells[-1]))
    assert np.allclose(hi[:2], pts.max(axis=0)[:2])  # the last cell ends at the box


@pytest.mark.parametrize("shape", ["slab", "ball", "box"])
def test_side_search_finds_the_largest_side_that_fits(tmp_path, shape):
    # the breakpoint bisection against an exhaustive scan of every grid shape a
    # fitted grid can take (one side inside each interval between breakpoints)
    g = np.random.default_rng(7)
    n = 4000
    pts = {"slab": np.c_[g.uniform(0, 1, (n, 2)) * [30, 17], g.normal(0, 0.05, n)],
           "ball": g.normal(size=(n, 3)) / 3,
           "box": g.uniform(0, 1, (n, 3)) * [5, 2, 9]}[shape] + [1e4, -7, 3]
    src = tiles.source_from_array(pts, str(tmp_path))
    for target in (150, 700, 1900):
        side = tiles._fit_side(src, pts, n, target)
        ext = np.maximum(src.hi - src.lo, 1e-300)
        cuts = np.unique((ext[:, None] / np.arange(1, tiles._MOST_CELLS + 1)).ravel())
        cuts = cuts[cuts >= ext.max() / tiles._MOST_CELLS]
        fits = [s for s in np.sqrt(cuts[:-1] * cuts[1:])
                if n / len(np.unique(tiles._cell_ids(pts, src.lo, *tiles._grid(src, s)[::-1])))
                <= target]
        assert tiles._grid(src, side)[0] == tiles._grid(src, max(fits))[0]


def test_fill_cells_kernel_equals_numpy(monkeypatch):
    # two chunks filled in turn into one counting sort: rows grouped by cell,
    # in input order within a cell, positions carried along
    from pcprep.filters import _kernels

    g = np.random.default_rng(4)
    ids = g.integers(0, 9, 3000) * 3  # every third cell empty
    pts = g.normal(size=(3000, 3))

    def fill_both():
        start = np.concatenate([[0], np.cumsum(np.bincount(ids, minlength=27))])
        fill, order, xyz = start[:-1].copy(), np.full(3000, -1), np.full((3000, 3), np.nan)
        for s in (0, 1700):
            e = 1700 if s == 0 else 3000
            tiles._fill_cells(ids[s:e], pts[s:e], s, fill, order, xyz)
        return order, xyz, fill, start

    got = fill_both()
    monkeypatch.setattr(_kernels, "ENABLED", False)
    ref = fill_both()
    assert _kernels.HAVE_NUMBA
    for a, b in zip(got, ref):
        assert np.array_equal(a, b)
    order, xyz, fill, start = ref
    assert np.array_equal(order, np.argsort(ids, kind="stable"))
    assert np.array_equal(xyz, pts[order]) and np.array_equal(fill, start[1:])


def test_cell_ids_kernel_equals_numpy(monkeypatch):
    # rows on cell faces, on the box's far faces and outside it (clipped),
    # on a grid whose sides are not powers of two
    from pcprep.filters import _kernels

    g = np.random.default_rng(3)
    lo, sides, shape = np.array([-1.5, 2.0, 1e5]), np.array([0.3, 0.7, 0.11]), (7, 5, 13)
    on_faces = lo + g.integers(0, 8, (500, 3)) * sides
    inside = lo + g.uniform(0, 1, (5000, 3)) * sides * shape
    outside = lo + g.uniform(-0.5, 1.5, (500, 3)) * sides * shape
    xyz = np.concatenate([on_faces, inside, outside])
    got = tiles._cell_ids(xyz, lo, sides, shape)
    monkeypatch.setattr(_kernels, "ENABLED", False)
    ref = tiles._cell_ids(xyz, lo, sides, shape)
    assert _kernels.HAVE_NUMBA and got.dtype == ref.dtype == np.int64
    assert np.array_equal(got, ref)
    assert len(np.unique(ref)) > 300 and ref.min() == 0 and ref.max() == math.prod(shape) - 1


def _family_case(name):
    from pcprep.baselines.datasets import make_shape

    if name in ("outliers", "saliency"):
        return CLOUD[:8000], None, {}
    if name == "denoise":  # given normals: the workers read them from disk
        g = np.random.default_rng(7)
        hint = np.c_[0.1 * g.normal(size=(8000, 2)), np.ones(8000)]
        return CLOUD[:8000], hint / np.linalg.norm(hint, axis=1)[:, None], DENOISE
    if name == "holes":
        return make_shape("disc", n=12_000, seed=3).points, None, {}
    pts = make_shape("fandisk", n=12_000, seed=1).points + [4e5, 3e6, 10.0]
    return pts, None, ({"ratio": 0.1} if name == "simplify" else {})


@pytest.mark.parametrize("name", ["outliers", "denoise", "saliency", "features", "holes",
                                  "simplify"])
def test_worker_io_and_driver_io_give_the_same_bits(client, name):
    # a local cluster shares the scratch disk, so by default the workers cut
    # their tiles from the memory maps and write their rows in place; with
    # worker_io=False the driver cuts, sends and stores.  Same cells, same
    # kernels: the same bits.
    pts, normals, params = _family_case(name)
    own = tiles.run_tiled(name, pts, normals, params=params, client=client, tiles=1500)
    sent = tiles.run_tiled(name, pts, normals, params=params, client=client, tiles=1500,
                           worker_io=False)
    assert own.stats["worker_io"] is True and sent.stats["worker_io"] is False
    assert own.stats["tiles"] >= 4 and set(own.fields) == set(sent.fields)
    for key, v in own.fields.items():
        assert np.array_equal(v, sent.fields[key]), key
    some = {"outliers": "removed_idx", "denoise": "points", "saliency": "saliency",
            "features": "mask", "holes": "mask", "simplify": "keep_idx"}[name]
    assert np.count_nonzero(own.fields[some]) > 0


def test_stored_arrays_travel_as_paths(tmp_path):
    # a task that names a stored array carries its path, not its rows
    import pickle

    a = np.lib.format.open_memmap(tmp_path / "a.npy", mode="w+", dtype=np.float64,
                                  shape=(100_000, 3))
    a[:] = 1.5
    a.flush()
    h = tiles._Runner.handle(a)
    blob = pickle.dumps(h)
    assert len(blob) < 1000
    back = pickle.loads(blob)
    assert np.array_equal(back.array[:10], a[:10])
    tiles.Stored.release()


def test_worker_io_refused_where_workers_do_not_share_the_disk(client, monkeypatch):
    monkeypatch.setattr(tiles, "_shares_scratch", lambda client, scratch: False)
    with pytest.raises(InvalidParameterError, match="worker_io"):
        tiles.run_tiled("outliers", CLOUD[:4000], client=client, tiles=1000, worker_io=True)
    res = tiles.run_tiled("outliers", CLOUD[:4000], client=client, tiles=1000)
    assert res.stats["worker_io"] is False  # detected, not refused


@pytest.mark.parametrize("name", ["features", "denoise"])
def test_tasks_on_a_worker_away_from_the_scratch_folder_move_to_driver_io(client, tmp_path,
                                                                           name):
    # a worker that cannot read the folder's token (as one that joins from
    # another host after the check) must touch nothing: each of its tasks,
    # tile or row chunk, is redone with the driver reading and writing, and
    # the results are the bits of a run that never shared the folder
    import glob

    pts, normals, params = _family_case(name)
    gone = []

    def lose_the_folder(label, cell):
        if not gone:
            gone.extend(glob.glob(str(tmp_path / "scratch" / "probe-*")))
            for p in gone:
                os.remove(p)

    os.mkdir(tmp_path / "scratch")
    moved = tiles.run_tiled(name, pts, normals, params=params, client=client, tiles=1500,
                            scratch=str(tmp_path / "scratch"), on_result=lose_the_folder)
    sent = tiles.run_tiled(name, pts, normals, params=params, client=client, tiles=1500,
                           worker_io=False)
    assert len(gone) == 1 and moved.stats["worker_io"] is True
    in_flight = tiles.IN_FLIGHT * len(client.scheduler_info()["workers"])
    assert moved.stats["moved_to_driver_io"] >= moved.stats["tiles"] - in_flight
    assert sent.stats["moved_to_driver_io"] == 0
    for key, v in sent.fields.items():
        assert np.array_equal(np.asarray(moved.fields[key]), v), key
    some = {"features": "mask", "denoise": "points"}[name]
    assert np.count_nonzero(sent.fields[some]) > 0
    tiles.Stored.release()


def test_blockwise_reads_and_writes_of_stored_arrays(tmp_path, monkeypatch):
    # scattered rows of a stored array are read and written in blocks of a few
    # pages, the pages dropped after each block: the values must be those of
    # plain indexing, and what is written must reach the file
    monkeypatch.setattr(tiles, "MAPPED_BYTES", 3 * 4096)
    g = np.random.default_rng(3)
    a = np.lib.format.open_memmap(tmp_path / "a.npy", mode="w+", dtype=np.float64,
                                  shape=(50_000, 3))
    a[:] = g.normal(size=a.shape)
    a.flush()
    np.lib.format.open_memmap(tmp_path / "c.npy", mode="w+", dtype=np.float64,
                              shape=(4, 50_000)).flush()  # zeros
    idx = np.sort(g.choice(50_000, 7_000, replace=False))
    assert len(list(tiles._blocks(idx, a))) > 10
    h, hc = tiles.Stored(str(tmp_path / "a.npy")), tiles.Stored(str(tmp_path / "c.npy"))
    try:
        assert np.array_equal(tiles._gather(h, idx), a[idx])
        vals = g.normal(size=(len(idx), 3))
        tiles._scatter(h, idx, vals)
        cols = g.normal(size=(4, len(idx)))
        tiles._store_columns(hc, idx, cols)
    finally:
        tiles.Stored.release()
    back, backc = np.load(tmp_path / "a.npy"), np.load(tmp_path / "c.npy")
    assert np.array_equal(back[idx], vals)
    assert np.array_equal(np.delete(back, idx, axis=0), np.delete(np.asarray(a), idx, axis=0))
    assert np.array_equal(backc[:, idx], cols)
    assert not np.delete(backc, idx, axis=1).any()


def _warmed() -> bool:
    import sys

    kernels = sys.modules.get("pcprep.filters._kernels")
    return ("pcprep.filters.simplify" in sys.modules and kernels is not None
            and (not kernels.ENABLED or bool(kernels.cell_ids.signatures)))


def _profiler_on() -> bool:
    import dask

    return dask.config.get("distributed.worker.profile.enabled")


def test_a_new_cluster_runs_quiet_and_an_attached_one_warms_its_workers(monkeypatch):
    # the workers of a cluster dask_client starts run without Dask's statistical
    # profiler unless the user's config asks for it; those of a cluster it
    # attaches to import the tile tasks' modules and load the compiled kernels
    # on their own, with no task run on them
    import time

    monkeypatch.delenv("DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED", raising=False)
    with tiles.dask_client(workers=1) as c:
        assert not any(c.run(_profiler_on).values())
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster, \
            tiles.dask_client(scheduler=cluster.scheduler_address) as c:
        deadline = time.monotonic() + 120
        while not all(c.run(_warmed).values()) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert all(c.run(_warmed).values())
        assert not c.run(lambda dask_worker: len(dask_worker.data)).popitem()[1]


def test_quiet_monitors_leave_what_the_user_configured(monkeypatch):
    monkeypatch.delenv("DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED", raising=False)
    assert tiles._quiet_monitors()["distributed.worker.profile.enabled"] is False
    monkeypatch.setenv("DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED", "True")
    quiet = tiles._quiet_monitors()
    assert "distributed.worker.profile.enabled" not in quiet
    assert set(quiet) == set(tiles.QUIET_MONITORS) - {"distributed.worker.profile.enabled"}


@pytest.mark.parametrize("budget", ["abc", "4 parsecs", 1.5, True, "100MB", 0, -1, "767MiB"])
def test_a_memory_budget_that_is_not_a_size_or_too_small_is_refused(budget):
    # below MIN_BUDGET a worker at rest is over Dask's 95 % line and its nanny
    # restarts it for ever: the run would hang, so it is refused before it starts
    with pytest.raises(InvalidParameterError, match="memory_budget"):
        with tiles.dask_client(memory_budget=budget):
            pass


def test_a_budget_is_read_as_dask_reads_sizes():
    assert tiles.worker_budget(None) == tiles.worker_budget("auto") == "auto"
    assert tiles.worker_budget("768MiB") == tiles.MIN_BUDGET == 768 << 20
    assert tiles.worker_budget("4GB") == 4_000_000_000
    assert tiles.worker_budget(np.int64(1 << 30)) == 1 << 30


@pytest.mark.parametrize("kwargs", [{"workers": 0}, {"workers": -2}, {"workers": "2"},
                                    {"workers": True},
                                    {"workers": 2, "scheduler": "tcp://127.0.0.1:1"},
                                    {"memory_budget": "2GB", "scheduler": "tcp://127.0.0.1:1"},
                                    {"workers": 2, "client": object()},
                                    {"threads": 0}, {"threads": 2.0},
                                    {"threads": 2, "scheduler": "tcp://127.0.0.1:1"}])
def test_cluster_sizes_that_cannot_apply_are_refused(kwargs):
    # a size for a cluster that is not started here would be ignored in silence
    with pytest.raises(InvalidParameterError, match="workers|memory_budget|threads"):
        with tiles.dask_client(**kwargs):
            pass


class _Limits:
    def __init__(self, *limits, threads=1):
        self.limits, self.threads = limits, threads

    def scheduler_info(self):
        return {"workers": {f"w{i}": {"memory_limit": m, "nthreads": self.threads}
                            for i, m in enumerate(self.limits)}}


def test_auto_tiles_fit_the_smallest_budget_above_a_worker_at_rest():
    room = (1 << 30) - tiles.WORKER_AT_REST
    want = room // (2 * tiles.BYTES_PER_POINT)
    assert tiles.tile_target("auto", _Limits(4 << 30, 1 << 30), 10**9) == want
    # a worker of two threads runs two tiles at once in its budget
    assert tiles.tile_target("auto", _Limits(1 << 30, threads=2), 10**9) == room // 2 // (
        2 * tiles.BYTES_PER_POINT)
    assert tiles.tile_target("auto", _Limits(1 << 30), 50_000) == 50_000  # at most the cloud
    assert tiles.tile_target("auto", _Limits(tiles.MIN_BUDGET), 10**9) == max(
        10_000, tiles.WORKER_AT_REST // (2 * tiles.BYTES_PER_POINT))


def _die_in_a_task(runner, src, normals, h, prm):
    runner.client.submit(os._exit, 3, pure=False).result()


def test_a_task_that_kills_its_workers_is_named_with_its_remedy(monkeypatch):
    # Dask gives up on a task after its workers died allowed-failures + 1 times
    # (KilledWorker); the run says so with the budget and the tile size
    import dask

    monkeypatch.setitem(tiles._FAMILIES, "outliers", _die_in_a_task)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), \
            tiles.dask_client(workers=1, memory_budget="800MiB") as c:
        with pytest.raises(tiles.WorkersLostError,
                           match=r"outliers: .* each of the 1 workers .*800 MiB per worker, "
                                 r"tiles of 5000 core points"):
            tiles.run_tiled("outliers", CLOUD, client=c, tiles=5000)


def test_cli_names_a_bad_budget_and_a_lost_task_and_writes_nothing(tmp_path, capsys,
                                                                    monkeypatch):
    import dask
    import laspy

    from pcprep.meshlab_bridge.cli import main

    pts = _surface(5000, seed=9, outliers=0)
    las = laspy.LasData(laspy.LasHeader(point_format=0, version="1.2"))
    las.header.offsets, las.header.scales = np.floor(pts.min(axis=0)), [1e-4] * 3
    las.x, las.y, las.z = pts.T
    src, dst = tmp_path / "in.las", tmp_path / "out.las"
    las.write(src)
    assert main(["outliers", str(src), str(dst), "--memory-budget", "2 bananas",
                 "--quiet"]) == 1
    assert "memory_budget '2 bananas': not a size" in capsys.readouterr().err
    monkeypatch.setitem(tiles._FAMILIES, "outliers", _die_in_a_task)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        assert main(["outliers", str(src), str(dst), "--tiles", "1000", "--workers", "1",
                     "--memory-budget", "800MiB", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "pcprep: error: outliers: a tile's task killed" in err and "Traceback" not in err
    assert not dst.exists()


def _no_room_for(name: str):
    """A ``posix_fallocate`` whose disk is full for the files called ``name``."""
    import errno

    real = os.posix_fallocate

    def fallocate(fd, offset, size):
        if os.path.basename(os.readlink(f"/proc/self/fd/{fd}")) == name:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fd, offset, size)

    return fallocate


@pytest.mark.skipif(not hasattr(os, "posix_fallocate"), reason="no posix_fallocate here")
def test_scratch_maps_reserve_their_blocks_or_name_the_full_folder(tmp_path, monkeypatch):
    # a memory map takes disk blocks as its pages are written, and a write to a
    # full disk is answered with SIGBUS (the process dies without a word): the
    # blocks are reserved when the map is made, where a full disk is an error
    import errno

    calls = []
    real = os.posix_fallocate
    monkeypatch.setattr(os, "posix_fallocate", lambda *a: calls.append(a[1:]) or real(*a))
    arr = tiles.open_scratch(str(tmp_path / "a.npy"), (10, 3))
    assert arr.shape == (10, 3) and not arr.any()
    assert calls == [(0, os.path.getsize(tmp_path / "a.npy"))]

    monkeypatch.setattr(os, "posix_fallocate", _no_room_for("b.npy"))
    with pytest.raises(tiles.ScratchSpaceError,
                       match=rf"scratch folder {tmp_path} has no room for b\.npy .*MiB free"):
        tiles.open_scratch(str(tmp_path / "b.npy"), 1000, np.int64)
    assert not (tmp_path / "b.npy").exists()

    def unsupported(fd, offset, size):
        raise OSError(errno.EOPNOTSUPP, "Operation not supported")

    monkeypatch.setattr(os, "posix_fallocate", unsupported)  # nothing to check: kept
    assert tiles.open_scratch(str(tmp_path / "c.npy"), 5).shape == (5,)


@pytest.mark.skipif(not hasattr(os, "posix_fallocate"), reason="no posix_fallocate here")
def test_cli_names_a_full_scratch_folder_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    # the tile index's first map finds the disk full (after the ingest's): one
    # line naming the folder, no output, and the scratch folder removed
    import tempfile

    from pcprep.meshlab_bridge.cli import main

    src, dst, tmp = tmp_path / "in.xyz", tmp_path / "out.xyz", tmp_path / "tmp"
    tmp.mkdir()
    np.savetxt(src, _surface(5000, seed=9, outliers=0))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    monkeypatch.setattr(os, "posix_fallocate", _no_room_for("order.npy"))
    assert main(["outliers", str(src), str(dst), "--tiles", "1000", "--workers", "1",
                 "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "pcprep: error:" in err and "has no room for order.npy" in err
    assert "Traceback" not in err
    assert not dst.exists()
    assert not [p for p in tmp.iterdir() if p.name.startswith("pcprep-")]


def _scratch_peak(monkeypatch):
    """Spy on open_scratch: the largest sum of the ``.npy`` files in the
    folder just after an array is made (files only go away between passes)."""
    peak = [0]
    real = tiles.open_scratch

    def spy(path, shape, dtype=np.float64):
        arr = real(path, shape, dtype)
        peak[0] = max(peak[0], sum(e.stat().st_size for e in os.scandir(os.path.dirname(path))
                                   if e.name.endswith(".npy")))
        return arr

    monkeypatch.setattr(tiles, "open_scratch", spy)
    return peak


@pytest.mark.parametrize("name,params,with_normals", [
    ("outliers", {}, False), ("outliers", {"method": "radius"}, False),
    ("denoise", DENOISE, False), ("denoise", DENOISE, True), ("saliency", {}, True),
    ("features", {}, False), ("features", {"n_scales": 3}, False), ("holes", {}, False),
    ("simplify", {"ratio": 0.3}, False)])
def test_scratch_need_is_what_the_run_keeps_on_disk(client, monkeypatch, name, params,
                                                   with_normals):
    # the check before a run counts every array the run stores; nothing it
    # counts is left out, nor is anything counted that is not made (the .npy
    # headers aside; SDBS's δ trials past the first: 1 B per row each)
    from pcprep.meshlab_bridge import registry

    pts = _family_case(name)[0]
    normals = _surface_normals(pts, seed=4) if with_normals else None
    peak = _scratch_peak(monkeypatch)
    res = tiles.run_tiled(name, pts, normals, params=params, client=client, tiles=1500)
    spec = tiles._spec(registry, name)
    need = tiles.scratch_need(spec.command, spec.resolve(dict(params)), len(pts),
                              normals="copy" if with_normals else None)
    extra = res.stats.get("greedy_passes", 1) - 1
    assert need <= peak[0] <= need + extra * len(pts) + 4096


def test_normals_in_the_scratch_folder_are_read_in_place(client, tmp_path, monkeypatch):
    # the command line streams a file's normals into the scratch folder; the
    # run reads them there instead of copying them (24 B per point less)
    from pcprep.meshlab_bridge import registry

    pts, normals, params = _family_case("denoise")
    ref = tiles.run_tiled("denoise", pts, normals, params=params, client=client, tiles=1500)
    stored = tiles.open_scratch(str(tmp_path / "input_normals.npy"), normals.shape)
    stored[:] = normals
    peak = _scratch_peak(monkeypatch)
    res = tiles.run_tiled("denoise", pts, stored, params=params, client=client, tiles=1500,
                          scratch=str(tmp_path))
    assert not (tmp_path / "given_normals.npy").exists()
    assert np.array_equal(np.asarray(res.fields["points"]), ref.fields["points"])
    spec = tiles._spec(registry, "denoise")
    need = tiles.scratch_need("denoise", spec.resolve(dict(params)), len(pts),
                              normals="stored")
    added = peak[0] - os.path.getsize(tmp_path / "input_normals.npy")
    assert need <= added <= need + 4096
    view = stored[: len(pts) // 2]  # a view is not the whole file: copied
    assert tiles._in_folder(stored, str(tmp_path)) and not tiles._in_folder(view, str(tmp_path))


def test_a_float32_memory_map_is_converted_a_chunk_at_a_time(tmp_path, monkeypatch):
    # a float32 (n, 3) memory map larger than memory must not become one
    # float64 copy: ingest gets slices of the map, and stores their float64 values
    pts = np.lib.format.open_memmap(str(tmp_path / "p.npy"), mode="w+", dtype=np.float32,
                                    shape=(5000, 3))
    pts[:] = CLOUD[:5000] - CLOUD[:5000].mean(axis=0)
    seen, real = [], tiles.ingest
    monkeypatch.setattr(tiles, "CHUNK", 1200)

    def spy(chunks, n, scratch):
        def watched():
            for s, block in chunks:
                seen.append((block.dtype, len(block)))
                yield s, block
        return real(watched(), n, scratch)

    monkeypatch.setattr(tiles, "ingest", spy)
    src = tiles.source_from_array(pts, str(tmp_path))
    assert seen == [(np.float32, 1200)] * 4 + [(np.float32, 200)]
    assert np.array_equal(np.asarray(src.xyz), np.asarray(pts, dtype=np.float64))
    for bad in (np.array([["a", "b", "c"]]), np.zeros((4, 3), dtype=complex)):
        with pytest.raises(PointCloudError, match="numeric"):
            tiles.source_from_array(bad, str(tmp_path))


def test_cli_refuses_a_scratch_folder_without_room_before_reading(tmp_path, capsys,
                                                                 monkeypatch):
    # --scratch names the folder; one without the room the run needs is
    # refused with both sizes before the file is read, and nothing is left
    import shutil

    from pcprep.meshlab_bridge.cli import main

    src, dst, tmp = tmp_path / "in.xyz", tmp_path / "out.xyz", tmp_path / "tmp"
    tmp.mkdir()
    np.savetxt(src, _surface(5000, seed=9, outliers=0))
    real = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage",
                        lambda p: real(p)._replace(free=89 * 5000 - 1))  # outliers: 89 B/pt
    monkeypatch.setattr(tiles, "ingest", lambda *a: pytest.fail("the file was read"))
    argv = ["outliers", str(src), str(dst), "--tiles", "1000", "--workers", "1", "--quiet"]
    assert main(argv + ["--scratch", str(tmp)]) == 1
    err = capsys.readouterr().err
    assert f"outliers: the run needs at least 0.4 MiB in the scratch folder {tmp}{os.sep}" \
        "pcprep-tiles-" in err and ", which has 0.4 MiB free" in err, err
    assert "Traceback" not in err
    assert not dst.exists() and not list(tmp.iterdir())
    # --scratch alone asks for a tiled run (it is not ignored by a one-piece run)
    assert main(argv[:3] + ["--quiet", "--scratch", str(tmp)]) == 1
    assert ", which has 0.4 MiB free" in capsys.readouterr().err
    assert main(argv + ["--scratch", str(tmp_path / "none")]) == 1
    assert "--scratch: " + str(tmp_path / "none") + " is not a folder" in capsys.readouterr().err


def _thread_use():
    from pcprep.filters import _kernels

    return _kernels.threads(), _kernels.tree_workers()


def test_tile_tasks_run_on_one_thread_each(client):
    # a worker's threads are the parallelism: a task that started threads of
    # its own (row kernels, k-d tree queries) would crowd the other workers
    assert tiles._submit(client, _thread_use).result() == (1, 1)
    assert _thread_use()[1] == -1  # the driver's own steps use every core


def test_a_worker_of_two_threads_runs_two_tiles_at_once_with_the_same_result():
    # the tasks of one worker process share its memory maps and its module
    # state; the result is still the one-piece run's
    from pcprep.filters.sharp import detect_sharp_features

    ref = detect_sharp_features(CLOUD)
    with tiles.dask_client(workers=1, threads=2) as c:
        assert tiles._slots(c) == 2
        res = tiles.run_tiled("features", CLOUD, client=c, tiles=2500)
        out = tiles.run_tiled("outliers", CLOUD, client=c, tiles=2500)
    assert res.stats["tiles"] >= 6
    assert np.array_equal(res.fields["mask"], ref.mask) and ref.mask.any()
    assert np.array_equal(out.fields["removed_idx"], remove_outliers(CLOUD).removed_idx)


@pytest.mark.parametrize("address", ["notanaddress", "tcp://", "tcp://host:port", 8786])
def test_a_scheduler_address_that_is_not_one_is_refused_by_name(address):
    with pytest.raises(InvalidParameterError, match=f"scheduler {address!r}"):
        with tiles.dask_client(scheduler=address):
            pass


def _rss() -> int:
    import psutil

    return psutil.Process().memory_info().rss


def test_a_worker_at_rest_fits_the_allowance_the_budget_keeps_for_it(client):
    # MIN_BUDGET and the auto tile size keep WORKER_AT_REST for a worker's own
    # modules and kernels: after every filter has run on them, the workers
    # hold less than that (227–283 MiB measured)
    for name in ("denoise", "saliency", "features", "holes", "outliers"):
        tiles.run_tiled(name, CLOUD[:6000], client=client, tiles=2000,
                        params=DENOISE if name == "denoise" else None)
    tiles.run_tiled("simplify", CLOUD[:6000], client=client, tiles=2000,
                    params={"ratio": 0.5})
    rest = client.run(_rss)
    assert len(rest) == 2 and max(rest.values()) < tiles.WORKER_AT_REST, rest


def _info(capsys, *argv):
    from pcprep.meshlab_bridge.cli import main

    assert main(["info", *argv]) == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("text", [False, True])
def test_cli_info_in_blocks_prints_what_the_whole_read_prints(tmp_path, capsys, text):
    # positions with non-finite rows and a few attributes, in a binary or an
    # ASCII PLY read in blocks of 2000 rows: counts, rows left out, box,
    # spacing, isolated points and every field's range as when the file is
    # read whole
    import plyfile

    from pcprep.meshlab_bridge.formats import stream

    g = np.random.default_rng(3)
    pts = _surface(5000, seed=3)
    pts[[17, 2500, 4999], [0, 1, 2]] = [np.nan, np.inf, np.nan]
    rows = np.empty(5000, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("red", "u1"),
                                 ("green", "u1"), ("blue", "u1"), ("intensity", "u2"),
                                 ("confidence", "f4")])
    for c, v in zip("xyz", pts.T):
        rows[c] = v
    for c in ("red", "green", "blue"):
        rows[c] = g.integers(0, 256, 5000)
    rows["intensity"] = g.integers(0, 4096, 5000)
    rows["confidence"] = g.random(5000)
    rows["confidence"][100] = np.nan
    src = tmp_path / "cloud.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rows, "vertex")], text=text).write(str(src))
    assert stream._block_reader(str(src)) is not None
    whole = _info(capsys, str(src))
    assert "non-finite points: 3 (rows 17, 2500, 4999)" in whole and "confidence" in whole
    import unittest.mock

    with unittest.mock.patch.object(stream, "CHUNK", 2000):
        tiled = _info(capsys, str(src), "--tiles", "800", "--workers", "1", "--quiet")
    assert tiled == whole


@pytest.mark.parametrize("ext", [".obj", ".ply"])
def test_cli_info_of_a_mesh_is_the_whole_read(tmp_path, capsys, ext):
    # an OBJ is read whole; a binary PLY of triangles in blocks, its faces
    # counted from the face element
    from pcprep.meshlab_bridge.cloud import Cloud
    from pcprep.meshlab_bridge.convert import save_cloud
    from pcprep.meshlab_bridge.formats import stream

    src = tmp_path / ("mesh" + ext)
    pts = _surface(400, seed=4, outliers=0)
    save_cloud(Cloud(points=pts, faces=np.array([[0, 1, 2], [2, 3, 4]])), str(src))
    assert (stream._block_reader(str(src)) is None) == (ext == ".obj")
    whole = _info(capsys, str(src))
    assert "faces: 2" in whole
    assert _info(capsys, str(src), "--tiles", "100", "--workers", "1") == whole
    if ext == ".ply":  # a non-finite vertex: its face goes, in blocks as whole
        pts[3] = np.nan
        save_cloud(Cloud(points=pts, faces=np.array([[0, 1, 2], [2, 3, 4]])), str(src))
        whole = _info(capsys, str(src))
        assert "faces: 1" in whole and "non-finite points: 1 (rows 3)" in whole
        assert _info(capsys, str(src), "--tiles", "100", "--workers", "1") == whole


def test_cli_info_names_what_faces_carry(tmp_path, capsys):
    # the face colour a write keeps, in blocks as whole
    import plyfile

    from pcprep.meshlab_bridge.formats import stream

    pts = _surface(400, seed=4, outliers=0)
    face = np.zeros(2, dtype=[("vertex_indices", "i4", (3,)), ("red", "u1")])
    face["vertex_indices"] = [[0, 1, 2], [2, 3, 4]]
    src = tmp_path / "mesh.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(_scan_vertices(pts, "f8"), "vertex"),
                     plyfile.PlyElement.describe(face, "face")]).write(str(src))
    assert stream._block_reader(str(src)) is not None
    whole = _info(capsys, str(src))
    assert "faces: 2 (with red)" in whole
    assert _info(capsys, str(src), "--tiles", "100", "--workers", "1") == whole
