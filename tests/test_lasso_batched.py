"""Tests of filters/lasso_batched.py: the batched Lasso agrees with scikit-learn,
on the compiled path (numba) and on the NumPy reference alike."""

import numpy as np
import pytest
from sklearn.linear_model import Lasso, LassoLars

from pcprep import InvalidParameterError
from pcprep.filters.lasso_batched import lasso_batched


def _problems(rng, n=60, d=5, m=10):
    return rng.normal(size=(n, d)), rng.normal(size=(n, d, m))


@pytest.mark.parametrize("lam", [0.05, 0.5, 0.9, 2.0])
def test_matches_sklearn_lasso_and_lassolars(rng, solver_path, lam):
    x, D = _problems(rng)
    res = lasso_batched(x, D, lam)
    assert res.converged.all()
    d = D.shape[1]
    for i in range(len(x)):
        # sklearn scales the loss by 1/(2 n_samples): alpha_sklearn = lam / d
        ref_cd = Lasso(alpha=lam / d, fit_intercept=False, tol=1e-14,
                       max_iter=200_000).fit(D[i], x[i]).coef_
        ref_lars = LassoLars(alpha=lam / d, fit_intercept=False).fit(D[i], x[i]).coef_
        np.testing.assert_allclose(res.coef[i], ref_lars, atol=1e-6)
        np.testing.assert_allclose(res.coef[i], ref_cd, atol=1e-6)
    np.testing.assert_allclose(res.residual, x - np.einsum("ndm,nm->nd", D, res.coef))


def test_per_problem_alpha_equals_separate_calls(rng, solver_path):
    x, D = _problems(rng, n=40)
    lam = rng.uniform(0.1, 1.5, size=len(x))
    together = lasso_batched(x, D, lam).coef
    for v in np.unique(np.round(lam, 12))[:5]:
        i = np.flatnonzero(np.round(lam, 12) == v)
        alone = lasso_batched(x[i], D[i], v).coef
        np.testing.assert_allclose(together[i], alone, atol=1e-9)


def test_kkt_conditions_hold(rng, solver_path):
    x, D = _problems(rng, n=200, m=12)
    lam = 0.7
    a = lasso_batched(x, D, lam).coef
    grad = np.einsum("ndm,nd->nm", D, x - np.einsum("ndm,nm->nd", D, a))
    act = a != 0
    np.testing.assert_allclose(grad[act], lam * np.sign(a[act]), atol=1e-8)
    assert (np.abs(grad[~act]) <= lam + 1e-8).all()


def test_large_alpha_gives_zero_and_zero_alpha_gives_least_squares(rng, solver_path):
    x, D = _problems(rng, n=30, d=8, m=4)  # overdetermined: unique LS solution
    big = np.abs(np.einsum("ndm,nd->nm", D, x)).max() + 1e-9
    assert (lasso_batched(x, D, big).coef == 0).all()
    ls = np.stack([np.linalg.lstsq(D[i], x[i], rcond=None)[0] for i in range(len(x))])
    np.testing.assert_allclose(lasso_batched(x, D, 0.0).coef, ls, atol=1e-8)


def test_zero_and_duplicate_atoms(rng, solver_path):
    x, D = _problems(rng, n=20, m=6)
    D[:, :, 0] = 0.0
    res = lasso_batched(x, D, 0.3)
    assert (res.coef[:, 0] == 0).all()
    D2 = np.concatenate([D, D[:, :, 1:2]], axis=2)  # an exact duplicate atom
    res2 = lasso_batched(x, D2, 0.3)
    # the objective value (unique even when the minimiser is not) is unchanged
    f = lambda xx, DD, a: 0.5 * ((xx - np.einsum("ndm,nm->nd", DD, a)) ** 2).sum(1) \
        + 0.3 * np.abs(a).sum(1)  # noqa: E731
    np.testing.assert_allclose(f(x, D2, res2.coef), f(x, D, res.coef), atol=1e-8)


def test_chunks_do_not_change_the_answer(rng, solver_path, monkeypatch):
    import pcprep.filters.lasso_batched as lb
    x, D = _problems(rng, n=100)
    whole = lasso_batched(x, D, 0.4).coef
    monkeypatch.setattr(lb, "CHUNK", 7)
    np.testing.assert_array_equal(lasso_batched(x, D, 0.4).coef, whole)


def test_compiled_and_numpy_paths_agree(rng, monkeypatch):
    """The numba kernel and the stacked NumPy solver certify the same optimum,
    also on the saliency-like shape (d = 5, m = 8) with many ill-posed
    problems (m > d: the support must be chosen among dependent atoms)."""
    from pcprep.filters import _kernels

    if not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    x, D = _problems(rng, n=3000, d=5, m=8)
    lam = rng.uniform(0.05, 1.0, size=len(x))
    out = {}
    for enabled in (True, False):
        monkeypatch.setattr(_kernels, "ENABLED", enabled)
        out[enabled] = lasso_batched(x, D, lam)
    assert out[True].converged.mean() > 0.99
    both = out[True].converged & out[False].converged
    np.testing.assert_allclose(out[True].coef[both], out[False].coef[both], atol=1e-8)
    np.testing.assert_array_equal(out[True].coef[both] != 0, out[False].coef[both] != 0)


def test_inputs_untouched(rng):
    x, D = _problems(rng, n=10)
    x0, D0 = x.copy(), D.copy()
    lasso_batched(x, D, 0.5)
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(D, D0)


@pytest.mark.parametrize("bad", [
    lambda x, D: (x[:, :3], D, 0.5),
    lambda x, D: (x, D[0], 0.5),
    lambda x, D: (x, D, -0.1),
    lambda x, D: (x, D, np.ones(3)),
    lambda x, D: (np.where(x > 1, np.nan, x), D, 0.5),
])
def test_bad_input_raises(rng, bad):
    x, D = _problems(rng, n=10)
    with pytest.raises(InvalidParameterError, match="lasso_batched"):
        lasso_batched(*bad(x, D))
