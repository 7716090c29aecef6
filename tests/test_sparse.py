"""Tests for filters/sparse.py: planted codes and dictionaries, agreement with
scikit-learn, determinism, bad input."""

import numpy as np
import pytest
from scipy import sparse as sp
from sklearn.linear_model import Lasso, orthogonal_mp_gram

from pcprep.filters import sparse
from pcprep import InvalidParameterError


def _planted(d, S, m, k, seed):
    rng = np.random.default_rng(seed)
    D = rng.standard_normal((S, d))
    D /= np.linalg.norm(D, axis=1)[:, None]
    codes = np.zeros((m, S))
    idx = np.argsort(rng.random((m, S)), axis=1)[:, :k]
    vals = rng.standard_normal((m, k)) + np.sign(rng.standard_normal((m, k)))
    np.put_along_axis(codes, idx, vals, axis=1)
    return D, codes, codes @ D


def test_omp_recovers_planted_support(solver_path):
    D, codes, X = _planted(d=64, S=80, m=500, k=3, seed=0)
    est = sparse.omp(X, D, n_nonzero_coefs=3)
    assert sp.issparse(est) and est.shape == codes.shape
    est = est.toarray()
    assert np.array_equal(est != 0, codes != 0)
    np.testing.assert_allclose(est, codes, atol=1e-8)


def test_omp_matches_sklearn(solver_path):
    rng = np.random.default_rng(1)
    D = rng.standard_normal((200, 7))
    D /= np.linalg.norm(D, axis=1)[:, None]
    X = rng.standard_normal((300, 7))
    ref = orthogonal_mp_gram(D @ D.T, (X @ D.T).T, n_nonzero_coefs=4).T
    np.testing.assert_allclose(sparse.omp(X, D, n_nonzero_coefs=4).toarray(), ref, atol=1e-9)
    ref = orthogonal_mp_gram(D @ D.T, (X @ D.T).T, tol=0.2,
                             norms_squared=(X ** 2).sum(axis=1)).T
    np.testing.assert_allclose(sparse.omp(X, D, tol=0.2).toarray(), ref, atol=1e-9)


def test_omp_tol_stops_at_residual(solver_path):
    rng = np.random.default_rng(2)
    D = rng.standard_normal((50, 10))
    X = rng.standard_normal((200, 10))
    codes = sparse.omp(X, D, tol=0.5)
    nnz, res = sparse.code_length(codes, X, D / np.linalg.norm(D, axis=1)[:, None])
    assert (res ** 2 <= 0.5 + 1e-9).all()
    assert nnz.min() >= 1 and nnz.max() > nnz.min()


@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_lasso_lars_matches_sklearn_lasso(alpha, solver_path):
    rng = np.random.default_rng(3)
    d = 7
    D = rng.standard_normal((200, d))
    D /= np.linalg.norm(D, axis=1)[:, None]
    X = 2.0 * rng.standard_normal((12, d))
    est = sparse.lasso_lars(X, D, alpha=alpha).toarray()

    def obj(x, b):
        return 0.5 * np.sum((x - b @ D) ** 2) + alpha * np.abs(b).sum()

    for i in range(len(X)):
        ref = Lasso(alpha=alpha / d, fit_intercept=False, tol=1e-12,
                    max_iter=200_000).fit(D.T, X[i]).coef_
        assert obj(X[i], est[i]) <= obj(X[i], ref) + 1e-9
        # optimality (KKT): |d_j·r| ≤ alpha everywhere, = alpha on the support
        cor = (X[i] - est[i] @ D) @ D.T
        assert np.abs(cor).max() <= alpha * (1 + 1e-7)
        on = est[i] != 0
        np.testing.assert_allclose(cor[on], alpha * np.sign(est[i][on]), rtol=1e-7)


def test_lasso_lars_zero_above_alpha_max(solver_path):
    rng = np.random.default_rng(4)
    D = rng.standard_normal((20, 5))
    D /= np.linalg.norm(D, axis=1)[:, None]
    X = rng.standard_normal((10, 5))
    big = np.abs(X @ D.T).max() * 1.01
    assert sparse.lasso_lars(X, D, alpha=big).nnz == 0


def test_ksvd_recovers_planted_dictionary(solver_path):
    D, _, X = _planted(d=16, S=24, m=2000, k=3, seed=1)
    res = sparse.ksvd(X, 24, n_nonzero_coefs=3, max_iter=40, seed=1)
    assert res.dictionary.shape == (24, 16)
    np.testing.assert_allclose(np.linalg.norm(res.dictionary, axis=1), 1.0)
    best = np.abs(res.dictionary @ D.T).max(axis=0)
    assert (best > 0.99).mean() > 0.9
    assert res.errors[-1] < res.errors[0]
    assert res.codes.shape == (2000, 24)


def test_ksvd_deterministic_and_subsample(solver_path):
    rng = np.random.default_rng(5)
    X = rng.standard_normal((3000, 7))
    a = sparse.ksvd(X, 20, n_nonzero_coefs=2, max_iter=3, max_train=1000, seed=7)
    b = sparse.ksvd(X, 20, n_nonzero_coefs=2, max_iter=3, max_train=1000, seed=7)
    np.testing.assert_array_equal(a.dictionary, b.dictionary)
    assert len(a.train_idx) == 1000 and a.codes.shape == (3000, 20)
    c = sparse.ksvd(X, 20, n_nonzero_coefs=2, max_iter=3, max_train=1000, seed=8)
    assert not np.array_equal(a.dictionary, c.dictionary)


def test_code_length():
    D = np.eye(3)
    X = np.array([[1.0, 0, 0], [1.0, 2.0, 0.5]])
    codes = np.array([[1.0, 0, 0], [1.0, 2.0, 0]])
    nnz, res = sparse.code_length(codes, X, D)
    np.testing.assert_array_equal(nnz, [1, 2])
    np.testing.assert_allclose(res, [0.0, 0.5])


def test_bad_input():
    D = np.eye(3)
    with pytest.raises(InvalidParameterError, match="omp"):
        sparse.omp(np.full((2, 3), np.nan), D, n_nonzero_coefs=1)
    with pytest.raises(InvalidParameterError, match="columns"):
        sparse.omp(np.ones((2, 4)), D, n_nonzero_coefs=1)
    with pytest.raises(InvalidParameterError, match="n_nonzero_coefs"):
        sparse.omp(np.ones((2, 3)), D, n_nonzero_coefs=5)
    with pytest.raises(InvalidParameterError, match="alpha"):
        sparse.lasso_lars(np.ones((2, 3)), D, alpha=-1.0)
    with pytest.raises(InvalidParameterError, match="zero atoms"):
        sparse.lasso_lars(np.ones((2, 3)), np.zeros((2, 3)), alpha=0.1)
    with pytest.raises(InvalidParameterError, match="ksvd"):
        sparse.ksvd(np.ones((0, 3)), 4)
    with pytest.raises(InvalidParameterError, match="seed"):
        sparse.ksvd(np.ones((5, 3)), 4, seed=-1)


def test_non_finite_signals_are_found_in_any_row_chunk(monkeypatch):
    # the check reads the signals in row chunks (7 rows here): a NaN or Inf in
    # the first, a middle or the last, partial, chunk is refused
    monkeypatch.setattr(sparse, "CHUNK", 7)
    for row, value in ((0, np.nan), (23, np.inf), (49, -np.inf)):
        X = np.ones((50, 3))
        X[row, 2] = value
        with pytest.raises(InvalidParameterError, match="ksvd: X contains NaN or Inf"):
            sparse.ksvd(X, 4)
    assert sparse.ksvd(np.random.default_rng(0).normal(size=(50, 3)), 4).dictionary.shape \
        == (4, 3)


def test_lasso_lars_kkt_on_many_structured_signals(solver_path):
    # clustered signals (like point features) exercise atom screening, drops
    # and re-entries; every code must satisfy the Lasso optimality conditions
    rng = np.random.default_rng(6)
    centres = rng.standard_normal((20, 7))
    X = centres[rng.integers(0, 20, 4000)] + 0.3 * rng.standard_normal((4000, 7))
    D = rng.standard_normal((200, 7))
    D /= np.linalg.norm(D, axis=1)[:, None]
    alpha = 0.25
    codes = sparse.lasso_lars(X, D, alpha=alpha).toarray()
    cor = (X - codes @ D) @ D.T
    assert np.abs(cor).max() <= alpha * (1 + 1e-7)
    on = codes != 0
    np.testing.assert_allclose(cor[on], alpha * np.sign(codes[on]), rtol=1e-6)


def test_compiled_and_numpy_paths_agree(monkeypatch):
    """The numba kernels and the NumPy reference give the same K-SVD dictionary
    and the same Lasso / OMP codes (up to rounding)."""
    from pcprep.filters import _kernels

    if not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    rng = np.random.default_rng(11)
    X = rng.standard_normal((3000, 7)) * [1, 1, 1, 0.3, 2, 2, 2]
    out = {}
    for enabled in (True, False):
        monkeypatch.setattr(_kernels, "ENABLED", enabled)
        k = sparse.ksvd(X, 40, n_nonzero_coefs=3, max_iter=4, seed=3)
        out[enabled] = (k.dictionary, k.codes.toarray(),
                        sparse.lasso_lars(X, k.dictionary, alpha=0.2).toarray())
    for a, b in zip(out[True], out[False]):
        np.testing.assert_allclose(a, b, atol=1e-8)


def test_lasso_lars_degenerate_dictionary(solver_path):
    """Duplicate atoms (also with flipped sign) and an atom in the span of two
    others: the codes still satisfy the Lasso optimality conditions and reach
    scikit-learn's objective; duplicates get no coefficient."""
    rng = np.random.default_rng(0)
    D = rng.standard_normal((30, 7))
    D[5], D[9], D[12] = D[3], -D[3], D[1] + D[2]
    D /= np.linalg.norm(D, axis=1)[:, None]
    X = rng.standard_normal((300, 7))
    alpha = 0.1
    codes = sparse.lasso_lars(X, D, alpha=alpha).toarray()
    R = X - codes @ D
    assert np.abs(R @ D.T).max() <= alpha * (1 + 1e-7)
    assert not codes[:, [5, 9]].any()
    ours = 0.5 * (R ** 2).sum(axis=1) + alpha * np.abs(codes).sum(axis=1)
    model = Lasso(alpha=alpha / 7, fit_intercept=False, tol=1e-12, max_iter=100_000)
    for i in range(0, 300, 30):
        model.fit(D.T, X[i])
        r = X[i] - D.T @ model.coef_
        ref = 0.5 * r @ r + alpha * np.abs(model.coef_).sum()
        assert ours[i] <= ref + 1e-9


def test_coding_selected_rows_equals_coding_their_copy(solver_path):
    D, codes, X = _planted(d=32, S=40, m=400, k=3, seed=5)
    rows = np.random.default_rng(1).permutation(400)[:150]
    a = sparse.omp(X, D, n_nonzero_coefs=3, rows=rows).toarray()
    assert np.array_equal(a, sparse.omp(X[rows], D, n_nonzero_coefs=3).toarray())
    b = sparse.lasso_lars(X, D, alpha=0.05, rows=rows).toarray()
    assert np.array_equal(b, sparse.lasso_lars(X[rows], D, alpha=0.05).toarray())
    assert np.count_nonzero(a) >= 150
    with pytest.raises(InvalidParameterError, match="rows"):
        sparse.omp(X, D, n_nonzero_coefs=3, rows=np.array([0, 400]))


def test_content_keys_of_pieces_are_the_keys_of_the_whole():
    X = np.random.default_rng(2).normal(size=(70_000, 5))   # more than one chunk
    keys = sparse.content_keys(X, seed=3)
    assert np.array_equal(keys[65_000:], sparse.content_keys(X[65_000:], seed=3))
    assert np.array_equal(sparse.content_order(X, 3), np.argsort(keys, kind="stable"))
    assert len(np.unique(keys)) == len(X)


def test_first_in_order_is_the_head_of_the_stable_argsort(rng):
    """The training rows picked by selection are the first m of a stable sort
    of the keys, ties (many here) in row order, for m below, at and above n."""
    from pcprep.filters.sparse import first_in_order

    keys = rng.integers(0, 300, 5000).astype(np.uint64)
    for m in (1, 7, 4000, 5000, 6000):
        np.testing.assert_array_equal(first_in_order(keys, m),
                                      np.argsort(keys, kind="stable")[:m])


@pytest.mark.parametrize("merged", [True, False])
def test_first_in_order_by_chunks_is_the_head_of_the_stable_argsort(rng, monkeypatch, merged):
    """Keys fed chunk by chunk, the chunks out of order and from threads, give
    the first m rows of a stable sort of the whole (ties, many here, in row
    order), merged chunk by chunk or, above MERGE_MAX, selected whole."""
    from concurrent.futures import ThreadPoolExecutor

    from pcprep.filters.sparse import FirstInOrder

    if not merged:
        monkeypatch.setattr(FirstInOrder, "MERGE_MAX", 0)
    keys = rng.integers(0, 300, 5000).astype(np.uint64)
    starts = rng.permutation(np.arange(0, len(keys), 377))
    for m in (1, 7, 376, 377, 1200, 5000, 6000):
        first = FirstInOrder(m)
        with ThreadPoolExecutor(4) as pool:
            list(pool.map(lambda s: first.add(keys[s:s + 377], s), starts))
        rows = first.rows()
        assert rows.dtype == np.int64
        np.testing.assert_array_equal(rows, np.argsort(keys, kind="stable")[:m])
    assert len(FirstInOrder(3).rows()) == 0
