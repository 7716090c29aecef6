"""Property-based checks (hypothesis) of the spine's small pieces: parameter
validation, metrics, and normal orientation."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pcprep.filters import Param, resolve_params
from pcprep import InvalidParameterError
from pcprep.filters.metrics import mse_symmetric, precision_recall_f1, roc_auc
from pcprep.filters.neighbors import orient_normals_mst, pca_normals
from helpers import sphere_points

SIGMA = (Param("sigma_d", float, low=0.5, high=20.0, closed="both", unit="h", default=3.0, help="Support"),)


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_a_bounded_parameter_is_accepted_exactly_inside_its_range(x):
    inside = 0.5 <= x <= 20.0
    try:
        out = resolve_params(SIGMA, {"sigma_d": x}, "f")
        assert inside and out["sigma_d"] == x
    except InvalidParameterError as exc:
        assert not inside and "sigma_d" in str(exc)


@given(st.lists(st.tuples(st.booleans(), st.booleans()), min_size=1, max_size=200))
def test_precision_recall_f1_are_fractions_and_f1_is_their_harmonic_mean(pairs):
    pred = np.array([p for p, _ in pairs])
    truth = np.array([t for _, t in pairs])
    p, r, f1 = precision_recall_f1(pred, truth)
    assert 0 <= p <= 1 and 0 <= r <= 1 and 0 <= f1 <= 1
    if p + r > 0:
        assert np.isclose(f1, 2 * p * r / (p + r))


@settings(max_examples=30, deadline=None)
@given(st.integers(min_value=0, max_value=10_000))
def test_mse_is_symmetric_and_zero_on_itself(seed):
    g = np.random.default_rng(seed)
    a, b = g.normal(size=(60, 3)), g.normal(size=(45, 3))
    assert np.isclose(mse_symmetric(a, b), mse_symmetric(b, a))
    assert mse_symmetric(a, a) == 0.0


@settings(max_examples=30, deadline=None)
@given(st.integers(min_value=0, max_value=10_000))
def test_auc_is_invariant_to_monotone_rescaling(seed):
    g = np.random.default_rng(seed)
    truth = g.random(100) < 0.3
    truth[:2] = [True, False]
    s = g.normal(size=100) + truth
    assert np.isclose(roc_auc(s, truth), roc_auc(np.exp(3 * s) + 7, truth))


@settings(max_examples=10, deadline=None)
@given(st.integers(min_value=0, max_value=10_000))
def test_mst_orientation_ignores_the_input_signs(seed):
    p = sphere_points(1500, seed=seed)
    n = pca_normals(p, 12, orient=False)
    flip = np.random.default_rng(seed + 1).random(len(p)) < 0.5
    a = orient_normals_mst(p, n, k=10)
    n[flip] *= -1
    b = orient_normals_mst(p, n, k=10)
    assert np.array_equal(a, b)
