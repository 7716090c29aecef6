"""Tests of filters/multiscale.py: the steps both chapter-7 detectors share."""

import numpy as np
import pytest

from pcprep import InvalidParameterError, PointCloudError
from pcprep.baselines.datasets import make_shape
from pcprep.filters import multiscale
from pcprep.filters.multiscale import (ScoreConfig, chain_labels, code_lengths,
                                       otsu_threshold, prepare_cloud, scale_moments,
                                       scale_sizes, standardise, sym3_eig)
from pcprep.filters.neighbors import build_tree, centered, knn, weighted_pca


def _config(**kw):
    base = dict(n_scales=10, k_min=8, k_max=40, n_atoms=100, coder="omp", alpha=0.01,
                tol=0.1, score="l1", max_iter=10, max_train=4000, seed=0)
    return ScoreConfig(**{**base, **kw})


def test_scale_sizes_are_increasing_and_span_the_range():
    ks = scale_sizes(8, 40, 10)
    assert ks[0] == 8 and ks[-1] == 40 and np.all(np.diff(ks) > 0)
    assert scale_sizes(8, 40, 1).tolist() == [8]
    assert scale_sizes(8, 10, 10).tolist() == [8, 9, 10]      # duplicates removed


def test_sym3_eig_matches_eigh(rng):
    a = rng.normal(size=(500, 3, 3))
    cov = a @ a.transpose(0, 2, 1)
    cov[:50, 2] = 0.0          # rank-deficient ones (flat neighbourhoods)
    cov[:50, :, 2] = 0.0
    lam, n = sym3_eig(cov)
    ref, vec = np.linalg.eigh(cov)
    np.testing.assert_allclose(lam, np.maximum(ref, 0), atol=1e-9 * ref.max())
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", n, vec[:, :, 0])), 1.0,
                               atol=1e-6)


def test_scale_moments_equal_direct_pca(monkeypatch):
    cube = make_shape("cube", n=3000, seed=0)
    pts, _ = centered(cube.points)
    ks = scale_sizes(8, 40, 10)
    monkeypatch.setattr(multiscale, "MOMENT_CHUNK", 700)  # several chunks
    chunks = list(scale_moments(pts, ks))
    rows = np.concatenate([c.rows for c in chunks])
    assert len(chunks) == 5 and np.array_equal(np.sort(rows), np.arange(len(pts)))
    lam = np.empty((len(pts), len(ks), 3))
    mean = np.empty((len(pts), len(ks), 3))
    for c in chunks:
        lam[c.rows], mean[c.rows] = c.eigenvalues, c.mean
    _, idx = knn(pts, int(ks[-1]))
    for s in (0, 4, len(ks) - 1):
        k = int(ks[s])
        pca = weighted_pca(pts, idx[:, :k])
        np.testing.assert_allclose(lam[:, s], pca.eigenvalues * k / (k - 1),   # 1/(k−1)
                                   atol=1e-12 * cube.h ** 2)
        np.testing.assert_allclose(mean[:, s], pca.centroid - pts, atol=1e-12)


def test_standardise_maps_the_bulk_to_zero_and_keeps_the_rare_side(rng):
    F = np.c_[rng.normal(0.0, 1.0, 1000), rng.normal(5.0, 0.01, 1000)]
    F[:10] += 20.0
    Z = standardise(F)
    assert (Z >= 0).all()
    assert np.median(Z, axis=0).max() < 0.01                 # the bulk at zero
    assert Z[:10].min() > 5.0                                # the rare side is large
    # the 0.3·std floor: a constant column stays 0, no division by zero
    assert not standardise(np.c_[np.ones(50), np.arange(50.0)])[:, 0].any()


def test_code_lengths_rank_rare_vectors_higher(rng):
    # 2000 ordinary feature vectors and 40 from a rare cluster
    F = np.abs(rng.normal(0.0, 1.0, (2040, 12)))
    F[2000:] += rng.normal(6.0, 1.0, (40, 12))
    for kw in ({}, {"score": "count"}, {"coder": "lasso_lars"}):
        c = code_lengths(F, _config(n_atoms=20, **kw))
        assert c.score.shape == (2040,) and c.dictionary.shape == (20, 12)
        rare = np.zeros(2040, bool)
        rare[2000:] = True
        # the count is an integer of a few atoms and ranks more coarsely than ‖α‖₁
        q = 0.9 if kw.get("score") == "count" else 0.99
        assert np.median(c.score[rare]) > np.quantile(c.score[~rare], q), kw
    count = code_lengths(F, _config(n_atoms=20, score="count"))
    # the residual tie-break lies in [0, 1)
    np.testing.assert_array_equal(np.floor(count.score), count.nnz)


def test_otsu_splits_two_modes(rng):
    v = np.concatenate([rng.normal(0, 1, 5000), rng.normal(10, 1, 500)])
    t = otsu_threshold(v)
    assert 3 < t < 7
    assert otsu_threshold(np.r_[np.ones(90), 5 * np.ones(10)]) == pytest.approx(3.0)
    assert otsu_threshold(np.ones(5)) == 1.0


def test_chain_labels_join_points_closer_than_the_link():
    x = np.r_[np.arange(5.0), 10 + np.arange(3.0)]
    lab = chain_labels(np.c_[x, np.zeros(8), np.zeros(8)], 1.5)
    assert len(set(lab[:5])) == 1 and len(set(lab[5:])) == 1 and lab[0] != lab[5]


@pytest.mark.parametrize("chunk", [1, 7, 100, 1 << 20])
@pytest.mark.parametrize("compiled", [True, False])
def test_chain_labels_equal_one_pair_graph_in_any_chunking(rng, monkeypatch, chunk, compiled):
    # the chunked union-find (compiled, and its NumPy reference) gives scipy's
    # components of the whole pair graph, to the label: on scattered points,
    # on a lattice whose spacing is the link itself (pairs exactly at the link
    # join), and with repeated points
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    from pcprep.filters import _kernels

    if compiled and not _kernels.HAVE_NUMBA:
        pytest.skip("numba not importable")
    monkeypatch.setattr(_kernels, "ENABLED", compiled)
    monkeypatch.setattr(multiscale, "_CHAIN_PARTS", 10 ** 9)
    g = np.stack(np.meshgrid(np.arange(12.0), np.arange(9.0), [0.0]), -1).reshape(-1, 3)
    lattice = 0.1 * g[rng.permutation(len(g))]
    lattice = lattice[np.abs(lattice[:, 0] - 0.6) > 0.05]  # two chains
    scattered = rng.uniform(0, 10, (1500, 3))
    for pts, link in ((scattered, 0.9), (lattice, 0.1),
                      (np.r_[scattered[:300], scattered[:50]], 0.7)):
        pairs = build_tree(pts).query_pairs(link, output_type="ndarray")
        graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                              shape=(len(pts), len(pts)))
        n_chains, want = connected_components(graph, directed=False)
        assert 1 < n_chains < len(pts)
        np.testing.assert_array_equal(chain_labels(pts, link, chunk=chunk), want)
    assert chain_labels(np.zeros((0, 3)), 1.0).shape == (0,)


def test_prepare_cloud_validates_and_centres(rng):
    pts = rng.normal(size=(100, 3)) + 1e3
    c, tree = prepare_cloud(pts, None, k_min=8, k_max=40, func="f")
    # centred on the bounding-box centre
    np.testing.assert_allclose(c.min(axis=0) + c.max(axis=0), 0.0, atol=1e-9)
    assert tree.n == 100
    with pytest.raises(InvalidParameterError, match="k_min must be <= k_max"):
        prepare_cloud(pts, None, k_min=50, k_max=40, func="f")
    with pytest.raises(PointCloudError, match="at least"):
        prepare_cloud(pts[:30], None, k_min=8, k_max=40, func="f")


def test_docstring_examples_run():
    import doctest

    from pcprep.filters import _border, _crease, holes, multiscale, sharp

    for module in (multiscale, sharp, holes, _crease, _border):
        result = doctest.testmod(module)
        assert result.attempted > 0 and result.failed == 0, module.__name__


@pytest.mark.parametrize("coder", ["omp", "lasso_lars"])
def test_score_rows_of_a_subset_equal_the_whole_cloud_rows(rng, coder):
    """The global state is fitted once; a row's score then depends on that row
    only, so a tile of rows scored alone gets the whole cloud's scores."""
    from pcprep.filters.multiscale import fit_score_model, score_rows

    F = np.abs(rng.normal(size=(3000, 12)))
    F[:60] *= 6.0                                   # rare vectors
    cfg = _config(n_atoms=20, coder=coder)
    model = fit_score_model(F, cfg)
    whole = score_rows(F, model, cfg)
    assert np.array_equal(whole.score, code_lengths(F, cfg).score)
    rows = rng.permutation(3000)[:700]
    part = score_rows(F[rows], model, cfg)
    np.testing.assert_allclose(part.score, whole.score[rows], rtol=0, atol=1e-12)
    assert np.array_equal(part.nnz, whole.nnz[rows])
    assert whole.score[:60].mean() > 2 * whole.score[60:].mean()


def test_standardise_in_place_equals_a_copy(rng):
    F = rng.normal(size=(500, 7))
    Z = standardise(F)
    G = F.copy()
    out = standardise(G, overwrite=True)
    assert out is G and np.array_equal(out, Z)
    assert (Z >= 0).all() and np.isclose(np.median(F[:, 0] - np.median(F[:, 0])), 0.0)


def test_compiled_and_numpy_scale_moments_agree(monkeypatch):
    from pcprep.filters import _kernels

    if not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    cube = make_shape("cube", n=3000, seed=1)
    pts, _ = centered(cube.points)
    ks = scale_sizes(8, 40, 10)
    out = {}
    for enabled in (True, False):
        monkeypatch.setattr(_kernels, "ENABLED", enabled)
        out[enabled] = list(scale_moments(pts, ks))
    for a, b in zip(out[True], out[False]):
        np.testing.assert_array_equal(a.rows, b.rows)
        np.testing.assert_allclose(a.mean, b.mean, rtol=0, atol=1e-12 * cube.h)
        np.testing.assert_allclose(a.eigenvalues, b.eigenvalues, rtol=1e-9,
                                   atol=1e-12 * cube.h ** 2)
        # the normal of a near-degenerate λ0 is ill-posed; compare where λ0 is clear
        gap = (a.eigenvalues[..., 1] - a.eigenvalues[..., 0]) > 1e-6 * cube.h ** 2
        cos = np.abs(np.einsum("csd,csd->cs", a.normal, b.normal))
        assert gap.mean() > 0.9 and (cos[gap] > 1 - 1e-9).all()


def test_otsu_does_not_depend_on_which_values_come_first(rng):
    """The probe of the leading values only shortcuts the test "at most
    ``bins`` distinct values": a score whose leading 8192 values take three
    values and whose tail is continuous is thresholded as a continuous score,
    whatever the row order; one with three values throughout gets a cut between
    two of them."""
    few = rng.choice([0.0, 1.0, 4.0], 9000, p=[0.6, 0.3, 0.1])
    tail = rng.gamma(2.0, 1.0, 3000)
    v = np.r_[few, tail]
    t = otsu_threshold(v)
    assert t == otsu_threshold(np.r_[tail, few]) == otsu_threshold(v[::-1])
    assert t not in (0.5, 2.5)          # not a cut between two of the three values
    assert otsu_threshold(few) in (0.5, 2.5)


@pytest.mark.parametrize("case", ["continuous", "few", "few_at_first", "constant_after_clip"])
def test_otsu_read_in_chunks_and_clipped_is_the_whole_arrays(monkeypatch, rng, case):
    """The counts added chunk by chunk are the whole array's, and ``clip`` is
    ``np.minimum`` (the features threshold winsorises a memory map of every
    score with it): the same threshold to the bit, whatever the chunks."""
    from pcprep.filters import neighbors

    v = {"continuous": rng.gamma(2.0, 1.0, 5000),
         "few": rng.choice([0.0, 1.0, 4.0, 9.0], 5000, p=[0.5, 0.3, 0.15, 0.05]),
         # few distinct values among the probed rows, many after them
         "few_at_first": np.r_[np.repeat([1.0, 2.0], 4200), rng.random(3000) + 1.5],
         "constant_after_clip": np.r_[np.full(10, 3.0), rng.random(100) + 5.0]}[case]
    c = float(np.quantile(v, 0.9))
    whole, clipped = otsu_threshold(v), otsu_threshold(np.minimum(v, c))
    monkeypatch.setattr(neighbors, "_SCAN", 377)
    assert otsu_threshold(v) == whole
    assert otsu_threshold(v, clip=c) == clipped
    assert otsu_threshold(np.minimum(v, c)) == clipped


def test_column_scale_is_the_plain_formula_and_leaves_the_input(rng):
    """Median, max(1.4826·MAD, 0.3·std) per column (1 where that is 0), to the
    bit; the in-place medians work on copies, so ``F`` is unchanged, whether
    its columns are strided (rows of features) or contiguous (a transposed
    column store, as the tiled driver keeps them)."""
    F = rng.gamma(2.0, 1.0, (5001, 4))
    F[:, 2] = 3.0                                   # constant: scale 1
    for X in (F, np.ascontiguousarray(F.T).T):
        before = X.copy()
        med, scale = multiscale.column_scale(X)
        np.testing.assert_array_equal(X, before)
        want_m = np.median(F, axis=0)
        mad = np.median(np.abs(F - want_m), axis=0)
        want_s = np.maximum(1.4826 * mad, 0.3 * F.std(axis=0))
        np.testing.assert_array_equal(med, want_m)
        np.testing.assert_array_equal(scale, np.where(want_s > 0, want_s, 1.0))


def test_column_scale_of_long_columns_reads_them_in_chunks(monkeypatch):
    # past MEDIAN_COPY_ROWS the columns of a tiled run's memory map are not
    # copied: the medians, MADs and stds are numpy's to the bit
    from pcprep.filters import multiscale, neighbors

    g = np.random.default_rng(8)
    F = np.c_[g.lognormal(size=3001), np.repeat(g.random(7), 429)[:3001], np.zeros(3001)]
    med, scale = multiscale.column_scale(F)
    monkeypatch.setattr(neighbors, "MEDIAN_COPY_ROWS", 1000)
    monkeypatch.setattr(neighbors, "_SCAN", 97)
    monkeypatch.setattr(neighbors, "_SELECT_BINS", 8)
    monkeypatch.setattr(neighbors, "_SELECT_ROWS", 32)
    calls = []
    chunked = neighbors._middle
    monkeypatch.setattr(neighbors, "_middle", lambda *a: calls.append(1) or chunked(*a))
    med2, scale2 = multiscale.column_scale(F)
    assert len(calls) == 2 * F.shape[1]  # the median and the MAD of each column, chunked
    assert np.array_equal(med, med2)
    assert np.array_equal(scale, scale2) and scale[2] == 1.0
