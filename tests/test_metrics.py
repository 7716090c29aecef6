"""Tests of filters/metrics.py: hand-computed answers on tiny arrays plus properties."""

import numpy as np
import pytest

from pcprep import PointCloudError
from pcprep.filters.metrics import (
    bbox_diagonal,
    mad_degrees,
    mse_symmetric,
    precision_recall_f1,
    roc_auc,
    simplification_error,
    snr_db,
)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


# --------------------------------------------------------------------- MAD
def test_mad_hand_computed():
    n_true = [[0, 0, 1], [0, 0, 1], [1, 0, 0]]
    # flipped (0°, unoriented), 45°, 90°; the second row is not unit on purpose
    n_est = [[0, 0, -1], [1, 0, 1], [0, 1, 0]]
    assert mad_degrees(n_true, n_est) == pytest.approx(45.0, abs=1e-12)


def test_mad_properties(rng):
    a = rng.normal(size=(500, 3))
    b = a + 0.3 * rng.normal(size=(500, 3))
    m = mad_degrees(a, b)
    assert 0.0 < m < 90.0
    assert mad_degrees(b, a) == pytest.approx(m)
    rot = _rotation(rng)
    assert mad_degrees(a @ rot.T, b @ rot.T) == pytest.approx(m)
    assert mad_degrees(a, -a) == pytest.approx(0.0, abs=1e-6)


def test_mad_errors():
    with pytest.raises(PointCloudError, match="mad_degrees"):
        mad_degrees(np.ones((3, 3)), np.ones((4, 3)))
    with pytest.raises(PointCloudError, match="zero-length"):
        mad_degrees([[0, 0, 0]], [[0, 0, 1]])
    with pytest.raises(PointCloudError, match="NaN"):
        mad_degrees([[np.nan, 0, 1]], [[0, 0, 1]])
    with pytest.raises(PointCloudError, match="empty"):
        mad_degrees(np.zeros((0, 3)), np.zeros((0, 3)))


# --------------------------------------------------------------------- MSE
def test_mse_hand_computed():
    p_true = [[0, 0, 0], [1, 0, 0]]
    p_est = [[0, 0, 0.1], [1, 0, 0], [5, 0, 0]]
    # true -> est: 0.1^2, 0       -> mean 0.005
    # est -> true: 0.1^2, 0, 4^2  -> mean 16.01 / 3
    expected = 0.5 * 0.005 + 0.5 * 16.01 / 3
    assert mse_symmetric(p_true, p_est) == pytest.approx(expected, rel=1e-12)
    assert mse_symmetric(p_est, p_true) == pytest.approx(expected, rel=1e-12)


def test_mse_properties(rng):
    p = rng.random((2000, 3))
    assert mse_symmetric(p, p) == 0.0
    q = p + 0.01 * rng.normal(size=p.shape)
    m = mse_symmetric(p, q)
    assert m > 0
    assert mse_symmetric(q, p) == pytest.approx(m)
    assert mse_symmetric(p, q[rng.permutation(len(q))]) == pytest.approx(m)
    # rigid motion far from the origin changes nothing; scaling by s scales by s^2
    rot, t = _rotation(rng), np.array([1e6, -2e6, 3e5])
    assert mse_symmetric(p @ rot.T + t, q @ rot.T + t) == pytest.approx(m, rel=1e-6)
    assert mse_symmetric(3 * p, 3 * q) == pytest.approx(9 * m, rel=1e-12)
    # unit-diagonal MSE is scale-free
    diag = bbox_diagonal(p)
    assert mse_symmetric(p, q, unit_diagonal=True) == pytest.approx(m / diag**2)
    assert mse_symmetric(3 * p, 3 * q, unit_diagonal=True) == pytest.approx(m / diag**2)


def test_bbox_diagonal_hand_computed():
    assert bbox_diagonal([[0, 0, 0], [1, 2, 2], [0.5, 1, 0]]) == pytest.approx(3.0)


# --------------------------------------------------------------------- SNR
def test_snr_hand_computed():
    p_true = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=float)
    p_est = p_true + [0, 0, 0.1]
    # MSE = 0.01 (each point's nearest is its own shifted copy); mean |q - c|^2 = 1.01
    assert snr_db(p_true, p_est) == pytest.approx(10 * np.log10(1.01 / 0.01), rel=1e-12)
    assert snr_db(p_true, p_true) == np.inf


def test_snr_drops_6db_when_noise_doubles(rng):
    # offsets far smaller than the spacing: nearest neighbours stay the own copies
    p = np.stack(np.meshgrid(np.arange(30.0), np.arange(30.0), [0.0]), -1).reshape(-1, 3)
    d = rng.normal(size=p.shape)
    d *= 0.01 / np.linalg.norm(d, axis=1, keepdims=True).max()
    s1, s2 = snr_db(p, p + d), snr_db(p, p + 2 * d)
    c = p.mean(axis=0)
    pw1 = np.mean(((p + d - c) ** 2).sum(1))
    pw2 = np.mean(((p + 2 * d - c) ** 2).sum(1))
    assert s1 - s2 == pytest.approx(10 * np.log10(4) + 10 * np.log10(pw1 / pw2), abs=1e-9)
    assert s1 - s2 == pytest.approx(6.02, abs=0.05)
    # invariant to rigid motion and scale (power measured about the true centroid)
    rot, t = _rotation(rng), np.array([5e5, 1e5, -3e5])
    moved = snr_db(7 * p @ rot.T + t, 7 * (p + d) @ rot.T + t)
    assert moved == pytest.approx(s1, abs=1e-6)


def test_mse_snr_errors():
    with pytest.raises(PointCloudError, match="mse_symmetric"):
        mse_symmetric(np.zeros((0, 3)), np.ones((2, 3)))
    with pytest.raises(PointCloudError, match="shape"):
        mse_symmetric(np.ones((3, 2)), np.ones((2, 3)))
    with pytest.raises(PointCloudError, match="NaN"):
        snr_db([[0, 0, np.inf]], [[0, 0, 0]])


# ------------------------------------------------- simplification error
def test_simplification_error_hand_computed():
    g = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0), [0.0]), -1).reshape(-1, 3)
    original = np.array([[1.0, 1.0, 0.0], [2.0, 2.5, 0.1], [3.2, 1.7, -0.3]])
    # the 10 nearest grid points of every query are coplanar (z = 0): d = |z|
    dmax, davg = simplification_error(original, g, k=10)
    assert dmax == pytest.approx(0.3, abs=1e-12)
    assert davg == pytest.approx(0.4 / 3, abs=1e-12)


def test_simplification_error_properties(rng):
    x = rng.normal(size=(4000, 3))
    sphere = x / np.linalg.norm(x, axis=1, keepdims=True)
    e_full = simplification_error(sphere, sphere)
    e_half = simplification_error(sphere, sphere[::2])
    e_tenth = simplification_error(sphere, sphere[::10])
    assert e_full[1] < e_half[1] < e_tenth[1]
    assert e_tenth[0] >= e_tenth[1] > 0
    # plane: any subset reproduces it exactly; scale-equivariant
    plane = np.column_stack([rng.random((3000, 2)), np.zeros(3000)])
    assert simplification_error(plane, plane[::20])[0] == pytest.approx(0.0, abs=1e-12)
    assert simplification_error(5 * sphere, 5 * sphere[::10])[1] == pytest.approx(
        5 * e_tenth[1], rel=1e-9)


def test_simplification_error_errors():
    with pytest.raises(PointCloudError, match="at least 3"):
        simplification_error(np.ones((5, 3)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="k"):
        simplification_error(np.ones((5, 3)), np.ones((4, 3)), k=2)


# ------------------------------------------------------- P / R / F1
def test_prf_hand_computed():
    # tp=2, fp=1, fn=1
    assert precision_recall_f1([1, 1, 0, 0, 1], [1, 0, 1, 0, 1]) == pytest.approx(
        (2 / 3, 2 / 3, 2 / 3))
    p, r, f = precision_recall_f1(np.array([1, 0, 0, 0], bool),
                                  np.array([1, 1, 1, 0], bool))
    assert (p, r) == pytest.approx((1.0, 1 / 3)) and f == pytest.approx(0.5)


def test_prf_zero_denominators():
    z = np.zeros(4, bool)
    o = np.array([1, 0, 0, 0], bool)
    assert precision_recall_f1(z, z) == (1.0, 1.0, 1.0)
    assert precision_recall_f1(z, o) == (0.0, 0.0, 0.0)
    assert precision_recall_f1(o, z) == (0.0, 0.0, 0.0)


def test_prf_errors():
    with pytest.raises(PointCloudError, match="entries"):
        precision_recall_f1([1, 0], [1, 0, 1])
    with pytest.raises(PointCloudError, match="boolean"):
        precision_recall_f1([2, 0], [1, 0])
    with pytest.raises(PointCloudError, match="empty"):
        precision_recall_f1([], [])


# ------------------------------------------------------------- ROC AUC
def test_auc_hand_computed():
    # pos 0.35 beats 0.1, loses to 0.4; pos 0.8 beats both -> 3/4
    assert roc_auc([0.1, 0.4, 0.35, 0.8], [0, 0, 1, 1]) == pytest.approx(0.75)
    # tie between the negative and a positive counts 1/2: (0.5 + 1) / 2
    assert roc_auc([0.5, 0.5, 1.0], [False, True, True]) == pytest.approx(0.75)
    assert roc_auc(np.ones(4), [0, 1, 0, 1]) == pytest.approx(0.5)
    assert roc_auc([3, 2, 1], [1, 0, 0]) == 1.0 and roc_auc([1, 2, 3], [1, 0, 0]) == 0.0


def test_auc_matches_sklearn_with_ties(rng):
    sk = pytest.importorskip("sklearn.metrics")
    scores = np.round(rng.random(3000), 2)  # many ties
    truth = rng.random(3000) < 0.2 + 0.5 * scores
    expected = sk.roc_auc_score(truth, scores)
    assert roc_auc(scores, truth) == pytest.approx(expected, abs=1e-12)
    # invariant to a monotone transform of the scores
    assert roc_auc(np.exp(5 * scores), truth) == pytest.approx(roc_auc(scores, truth))


def test_auc_errors():
    with pytest.raises(PointCloudError, match="single class"):
        roc_auc([0.1, 0.2], [1, 1])
    with pytest.raises(PointCloudError, match="NaN"):
        roc_auc([np.nan, 0.2], [1, 0])
    with pytest.raises(PointCloudError, match="entries"):
        roc_auc([0.1, 0.2, 0.3], [1, 0])
    with pytest.raises(PointCloudError, match="empty"):
        roc_auc([], [])
