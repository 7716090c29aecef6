import numpy as np
import pytest

from pcprep import PointCloudError
from pcprep.filters.neighbors import (
    average_spacing,
    knn,
    orient_normals_mst,
    orient_normals_toward,
    pca_normals,
    weighted_pca,
)
from helpers import random_rotation, sphere_points


def test_average_spacing_of_a_square_grid_is_known():
    # unit grid: the 6 nearest of an interior point are 4 at distance 1 and 2 at sqrt(2)
    g = np.stack(np.meshgrid(np.arange(40.0), np.arange(40.0)), -1).reshape(-1, 2)
    pts = np.c_[g, np.zeros(len(g))]
    interior = (pts[:, 0] > 0) & (pts[:, 0] < 39) & (pts[:, 1] > 0) & (pts[:, 1] < 39)
    d, _ = knn(pts, 6, include_self=False)
    assert np.allclose(d[interior].mean(axis=1), (4 + 2 * np.sqrt(2)) / 6)
    h = average_spacing(pts)
    assert abs(h - (4 + 2 * np.sqrt(2)) / 6) < 0.02  # borders change it slightly


def test_average_spacing_scales_linearly():
    p = sphere_points(3000, seed=1)
    assert np.isclose(average_spacing(1000.0 * p), 1000.0 * average_spacing(p))


def test_average_spacing_rejects_duplicates_and_tiny_clouds():
    with pytest.raises(PointCloudError, match="coincides"):
        average_spacing(np.zeros((50, 3)))
    with pytest.raises(PointCloudError, match="at least 7"):
        average_spacing(np.random.default_rng(0).normal(size=(5, 3)))


def test_weighted_pca_matches_numpy_per_neighbourhood(rng):
    pts = rng.normal(size=(500, 3)) * [3.0, 1.0, 0.2]
    _, idx = knn(pts, 12)
    w = rng.random(idx.shape)
    res = weighted_pca(pts, idx, w)
    for i in (0, 17, 311):
        nb = pts[idx[i]]
        wi = w[i] / w[i].sum()
        mu = wi @ nb
        cov = (wi[:, None] * (nb - mu)).T @ (nb - mu)
        lam, vec = np.linalg.eigh(cov)
        assert np.allclose(res.eigenvalues[i], lam)
        assert np.allclose(res.centroid[i], mu)
        assert abs(abs(res.normals[i] @ vec[:, 0]) - 1) < 1e-9


def test_plane_features_have_known_values(rng):
    pts = np.c_[rng.random((4000, 2)), np.zeros(4000)]
    _, idx = knn(pts, 16)
    res = weighted_pca(pts, idx)
    assert np.allclose(np.abs(res.normals[:, 2]), 1.0)
    assert np.allclose(res.surface_variation, 0.0, atol=1e-12)
    assert np.allclose(res.sphericity, 0.0, atol=1e-12)


def test_mst_orientation_is_consistent_and_outward_on_a_sphere(solver_path):
    p = sphere_points(8000, seed=2)
    n = pca_normals(p, 12, orient=False)
    # scramble signs, then re-orient
    flip = np.random.default_rng(3).random(len(p)) < 0.5
    n[flip] *= -1
    out = orient_normals_mst(p, n, k=10)
    assert (np.einsum("ij,ij->i", out, p) > 0).all()


def test_mst_orientation_compiled_equals_reference(monkeypatch):
    """Kruskal with a signed union-find (compiled) and scipy's spanning tree
    with a traversal (reference) give the same signs, also with the
    chord-mirrored agreement, on two separate noisy components."""
    from pcprep.filters import _kernels

    if not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    g = np.random.default_rng(8)
    p = np.r_[sphere_points(3000, seed=6), sphere_points(2000, seed=7) * 0.5 + [4.0, 0, 0]]
    p = p + 0.01 * g.standard_normal(p.shape)
    n = pca_normals(p, 12, orient=False)
    n[g.random(len(p)) < 0.5] *= -1
    for mirror in (False, True):
        out = {}
        for enabled in (True, False):
            monkeypatch.setattr(_kernels, "ENABLED", enabled)
            out[enabled] = orient_normals_mst(p, n, k=10, mirror=mirror)
        np.testing.assert_array_equal(out[True], out[False])


def test_mst_orientation_handles_separate_components(solver_path):
    a = sphere_points(3000, seed=4)
    b = sphere_points(3000, seed=5) + [10.0, 0, 0]
    pts = np.r_[a, b]
    n = pca_normals(pts, 12, orient=True)
    centre = np.r_[np.zeros((3000, 3)), np.tile([10.0, 0, 0], (3000, 1))]
    assert (np.einsum("ij,ij->i", n, pts - centre) > 0).all()


def test_orientation_toward_viewpoint():
    p = sphere_points(1000, seed=6)
    n = -p.copy()
    out = orient_normals_toward(p, n, [0, 0, 0])
    assert (np.einsum("ij,ij->i", out, -p) > 0.99).all()


def test_pca_normals_rotate_with_the_cloud():
    p = sphere_points(4000, seed=7)
    r = random_rotation(8)
    n1 = pca_normals(p, 12, orient=False)
    n2 = pca_normals(p @ r.T, 12, orient=False)
    assert np.allclose(np.abs(np.einsum("ij,ij->i", n1 @ r.T, n2)), 1.0, atol=1e-9)


def test_pca_of_a_sphere_patch_has_the_known_answer():
    # a cap of angular radius a on the unit sphere: normal radial, and the
    # surface variation of a uniform cap is known in closed form
    a = 0.2
    g = np.random.default_rng(9)
    n = 200_000
    cos_t = 1 - g.random(n) * (1 - np.cos(a))  # uniform on the cap
    phi = g.random(n) * 2 * np.pi
    s = np.sqrt(1 - cos_t**2)
    cap = np.c_[s * np.cos(phi), s * np.sin(phi), cos_t]
    res = weighted_pca(cap, np.arange(n)[None, :])
    assert abs(abs(res.normals[0, 2]) - 1) < 1e-6
    # variances: z uniform on [cos a, 1] -> (1 - cos a)^2 / 12; x, y: E[s^2] / 2
    c = np.cos(a)
    var_z = (1 - c) ** 2 / 12
    var_xy = (1 - (1 + c + c * c) / 3) / 2  # E[1 - z^2] / 2 with z ~ U[c, 1]
    assert np.allclose(res.eigenvalues[0], [var_z, var_xy, var_xy], rtol=2e-2)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_h_relative_quantities_are_scale_and_motion_invariant(scale):
    p = sphere_points(3000, seed=10) * [1.0, 0.7, 0.4]
    r = random_rotation(11)
    q = (scale * p) @ r.T + [5e5, -3e5, 1e5]
    assert np.isclose(average_spacing(q) / scale, average_spacing(p), rtol=1e-8)
    _, i1 = knn(p, 12)
    _, i2 = knn(q, 12)
    a, b = weighted_pca(p, i1), weighted_pca(q - q.mean(axis=0), i2)
    # float64 at a 5e5 offset resolves ~1e-10: a 1e-3-scale cloud keeps ~6 digits
    assert np.allclose(a.surface_variation, b.surface_variation, rtol=1e-4, atol=1e-9)
    assert np.allclose(a.border, b.border, rtol=1e-4, atol=1e-6)
    assert np.allclose(np.abs(np.einsum("ij,ij->i", a.normals @ r.T, b.normals)), 1, atol=1e-6)


def test_knn_in_leaf_order_equals_one_query_in_input_order(monkeypatch):
    """A large cloud is queried in the tree's leaf order, slice by slice; the
    answer is row for row the one of a single query in input order."""
    from pcprep.filters import neighbors

    p = sphere_points(3000, seed=11)[np.random.default_rng(2).permutation(3000)]
    tree = neighbors.build_tree(p)
    want_d, want_i = tree.query(p, k=9)
    monkeypatch.setattr(neighbors, "CHUNK", 200)  # leaf-order path, 4 slices
    d, i = knn(p, 9, tree=tree)
    np.testing.assert_array_equal(i, want_i)
    np.testing.assert_array_equal(d, want_d)
    d, i = knn(p, 8, tree=tree, include_self=False)
    np.testing.assert_array_equal(i, want_i[:, 1:])


def _settled_reference(p, q_rows, k):
    """Each query row's k nearest, ranked by exact squared distance (integer
    coordinates), then x, y, z, then row."""
    out = []
    for r in q_rows:
        d2 = np.square(p - p[r]).sum(axis=1)
        order = np.lexsort((np.arange(len(p)), p[:, 2], p[:, 1], p[:, 0], d2))
        out.append(order[:k])
    return np.array(out)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("k", [1, 3, 4, 5, 7, 13, 19, 27])
def test_equal_distances_come_in_the_same_order_in_any_tree(monkeypatch, k, compiled):
    """On an integer grid nearly every neighbour is tied with others.  The
    settled query ranks them by distance, then by position, whatever rows the
    tree holds and in whatever order: the whole grid, the grid shuffled, and a
    block of it around the queries (a tile) give the same neighbours, and
    those of the exact reference, also where a tie spans the k-th place; the
    compiled insertion sort and NumPy's lexsort alike."""
    from pcprep.filters import _kernels, neighbors
    from pcprep.filters.neighbors import build_tree, query_settled

    monkeypatch.setattr(_kernels, "ENABLED", compiled and _kernels.HAVE_NUMBA)
    if k == 13:  # tied rows settled a few at a time
        monkeypatch.setattr(neighbors, "TIE_ROWS", 4)
    g = np.random.default_rng(k)
    u = np.arange(12, dtype=float)
    p = np.stack(np.meshgrid(u, u, u[:6], indexing="ij"), axis=-1).reshape(-1, 3)
    rows = np.flatnonzero(np.all(np.abs(p - [6.0, 6.0, 3.0]) <= 1.0, axis=1))
    want = _settled_reference(p, rows, k)
    d, i = query_settled(build_tree(p), p[rows], k)
    np.testing.assert_array_equal(i, want)
    np.testing.assert_array_equal(d, np.sqrt(np.square(p[want] - p[rows][:, None]).sum(-1)))
    perm = g.permutation(len(p))
    _, i2 = query_settled(build_tree(p[perm]), p[rows], k)
    np.testing.assert_array_equal(perm[i2], want)
    block = np.flatnonzero(np.all(np.abs(p - [6.0, 6.0, 3.0]) <= 4.5, axis=1))[::-1]
    _, i3 = query_settled(build_tree(p[block]), p[rows], k)
    np.testing.assert_array_equal(block[i3], want)
    # the plain query differs: the tie order is the tree's
    if k == 19:
        _, raw = build_tree(p[perm]).query(p[rows], k=k)
        assert not np.array_equal(perm[raw], want)


def test_spacing_rows_in_leaf_slices_equal_the_plain_query(monkeypatch):
    """The spacing's row means, queried slice by slice in leaf order, are the
    plain 7-NN query's row means to the bit (so h is)."""
    from pcprep.filters import neighbors

    p = sphere_points(3000, seed=12)[np.random.default_rng(3).permutation(3000)]
    d, _ = neighbors.build_tree(p).query(p, k=7)
    want = np.ascontiguousarray(d[:, 1:]).mean(axis=1)
    monkeypatch.setattr(neighbors, "CHUNK", 100)  # 400-row slices, 8 of them
    np.testing.assert_array_equal(neighbors.spacing_rows(p), want)
    assert average_spacing(p) == neighbors.spacing_from_rows(want)


@pytest.mark.parametrize("compiled", [True, False])
def test_cost_order_is_the_stable_argsort(monkeypatch, compiled):
    """Kruskal's edge order: ascending cost, ties by index (what a stable
    argsort gives), with −0.0 equal to 0.0 and negative and subnormal costs in
    place, through the threaded sort-and-merge and the plain sort alike."""
    from pcprep.filters import _kernels, neighbors

    monkeypatch.setattr(_kernels, "ENABLED", compiled and _kernels.HAVE_NUMBA)
    monkeypatch.setattr(_kernels, "threads", lambda: 2)
    rng = np.random.default_rng(5)
    n = 3 * neighbors.CHUNK + 7
    ties = np.array([-1.5, -0.0, 0.0, 1e-6, 0.5, 2.0, -3e-40, 3e-40], dtype=np.float32)
    cost = np.where(rng.random(n) < 0.6, rng.choice(ties, n),
                    rng.standard_normal(n).astype(np.float32))
    order = neighbors.cost_order(cost)
    np.testing.assert_array_equal(order, np.argsort(cost, kind="stable"))
    assert order.dtype == np.int64


def test_tile_miss_says_how_far_the_worst_ball_pokes_out():
    from pcprep.filters.neighbors import tile_miss

    lo, hi = np.zeros(3), np.ones(3)
    pts = np.array([[0.5, 0.5, 0.5], [0.1, 0.5, 0.5], [0.5, 0.95, 0.5]])
    reach = np.array([0.2, 0.3, 0.1])
    miss = tile_miss(pts, reach, lo, hi)
    assert miss["exact"] is False
    assert miss["short"] == pytest.approx(0.2)  # the second row: 0.3 - 0.1
    grown = 0.2 * 1.02
    assert tile_miss(pts, reach, lo - grown, hi + grown) is None
    assert tile_miss(pts, reach, [-np.inf] * 3, [np.inf] * 3) is None  # open sides
    assert tile_miss(pts, reach, lo - 0.15, hi + 0.15)["short"] == pytest.approx(0.05)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("case", ["odd", "even", "ties", "all_equal", "far_outlier",
                                  "two_neighbouring_floats"])
def test_median_of_a_long_array_is_numpys_without_a_copy(monkeypatch, case, compiled):
    # long arrays are not copied: their middle values are selected by rounds of
    # histograms over chunks; tiny bins and chunks here force many rounds
    from pcprep.filters import _kernels
    from pcprep.filters import neighbors as nb

    monkeypatch.setattr(_kernels, "ENABLED", compiled and _kernels.HAVE_NUMBA)

    g = np.random.default_rng(5)
    x = {"odd": g.lognormal(size=4001), "even": g.random(4000),
         "ties": np.repeat(g.random(9), 301), "all_equal": np.full(3000, 0.25),
         "far_outlier": np.r_[g.random(2999), 1e12],
         "two_neighbouring_floats": np.tile([1.0, np.nextafter(1.0, 2.0)], 1500)}[case]
    monkeypatch.setattr(nb, "MEDIAN_COPY_ROWS", 100)
    monkeypatch.setattr(nb, "_SELECT_BINS", 4)
    monkeypatch.setattr(nb, "_SELECT_ROWS", 16)
    monkeypatch.setattr(nb, "_SCAN", 333)
    assert nb.median(x) == float(np.median(x))
    m = float(np.median(x))
    assert nb.median(x, lambda c: np.abs(c - m)) == float(np.median(np.abs(x - m)))
    assert nb.count_isolated(x) == int(np.count_nonzero(nb.isolated(x)))


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("case", ["odd", "even", "ties", "all_equal", "far_outlier"])
def test_quantile_of_a_long_array_is_numpys_bit_for_bit(monkeypatch, case, compiled):
    # the features threshold winsorises every score at a quantile: past
    # MEDIAN_COPY_ROWS the two order statistics are selected in chunks and
    # interpolated as numpy does, from below or (weight >= 1/2) from above
    from pcprep.filters import _kernels
    from pcprep.filters import neighbors as nb

    monkeypatch.setattr(_kernels, "ENABLED", compiled and _kernels.HAVE_NUMBA)
    g = np.random.default_rng(6)
    x = {"odd": g.lognormal(size=4001), "even": g.random(4000),
         "ties": np.repeat(g.random(9), 301), "all_equal": np.full(3000, 0.25),
         "far_outlier": np.r_[g.random(2999), 1e12]}[case]
    monkeypatch.setattr(nb, "MEDIAN_COPY_ROWS", 100)
    monkeypatch.setattr(nb, "_SELECT_BINS", 4)
    monkeypatch.setattr(nb, "_SELECT_ROWS", 16)
    monkeypatch.setattr(nb, "_SCAN", 333)
    for q in (0.0, 0.05, 0.5, 0.6, 0.95, 0.999, 0.9999, 1.0):
        assert nb.quantile(x, q) == float(np.quantile(x, q)), q
    calls = []
    chunked = nb._middle
    monkeypatch.setattr(nb, "_middle", lambda *a: calls.append(1) or chunked(*a))
    nb.quantile(x, 0.95)
    assert calls  # the long array went through the chunked selection


@pytest.mark.parametrize("n", [5, 128, 129, 1000, 4099, 100_003])
def test_mean_and_std_read_in_chunks_are_numpys_bit_for_bit(monkeypatch, n):
    # the statistical outlier threshold of a tiled run reads every score in
    # chunks: cut as numpy's pairwise sum cuts, the sums are numpy's; a column
    # of an (n, 3) array gives the values of its contiguous copy
    from pcprep.filters import neighbors as nb

    g = np.random.default_rng(n)
    # magnitudes over ten decades and both signs: another tree rounds otherwise
    x = g.standard_normal(n) * np.exp(g.uniform(-12.0, 12.0, n)) + 1e4
    cols = g.lognormal(size=(n, 3))
    for scan in (7, 97, 1 << 20):
        monkeypatch.setattr(nb, "_SCAN", scan)
        assert nb.mean_std(x) == (float(np.mean(x)), float(np.std(x))), scan
        copy = np.ascontiguousarray(cols[:, 1])
        assert nb.mean_std(cols[:, 1]) == (float(copy.mean()), float(copy.std())), scan
        assert nb.pairwise_sum(x, np.abs) == float(np.sum(np.abs(x))), scan


def test_spacing_of_a_memory_mapped_cloud_reads_its_rows_without_copying_them(
        tmp_path, monkeypatch):
    import tracemalloc

    from pcprep.filters import neighbors as nb

    monkeypatch.setattr(nb, "_SCAN", 1 << 16)  # chunks of 0.5 MB: a copy would show
    monkeypatch.setattr(nb, "MEDIAN_COPY_ROWS", 1 << 22)
    n = nb.MEDIAN_COPY_ROWS + 1001  # 33 MB of rows, past the copying median
    rows = np.lib.format.open_memmap(str(tmp_path / "rows.npy"), mode="w+",
                                     dtype=np.float64, shape=(n,))
    rows[:] = np.random.default_rng(6).random(n) + 1.0
    want = float(np.asarray(rows).mean())
    tracemalloc.start()
    try:
        h = nb.spacing_from_rows(rows)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert h == want  # nothing isolated: the plain mean, in row order
    assert peak < rows.nbytes / 4, peak
