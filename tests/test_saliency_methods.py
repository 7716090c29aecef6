"""Tests of baselines/saliency_methods.py: the comparison saliency methods (Tasse
et al. 2015 cluster-based, Lee et al. 2005 centre-surround) and FPFH, by known
answers and invariances."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pcprep.baselines import saliency_methods as sm
from pcprep.baselines.datasets import make_shape
from pcprep.filters.metrics import roc_auc

METHODS = (sm.cluster_saliency, sm.centre_surround_saliency)


@pytest.fixture(scope="module")
def bump():
    """A plane with one Gaussian bump in its middle."""
    rng = np.random.default_rng(0)
    xy = 2 * rng.random((5000, 2)) - 1
    z = 0.25 * np.exp(-(xy ** 2).sum(axis=1) / (2 * 0.15 ** 2))
    return np.column_stack([xy, z])


def test_fpfh_of_a_plane_is_one_bin_per_angle():
    g = np.linspace(-1, 1, 40)
    X, Y = np.meshgrid(g, g)
    pts = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    pts += np.random.default_rng(1).normal(0, 1e-3, pts.shape) * [1, 1, 0]
    d = sm.fpfh(pts)
    assert d.shape == (len(pts), 33)
    np.testing.assert_allclose(d.reshape(-1, 3, 11).sum(axis=2), 1.0)
    # α = φ = θ = 0 on a plane: the middle bin of α and φ, the middle of θ
    assert (d[:, 5] > 0.99).all() and (d[:, 16] > 0.99).all() and (d[:, 27] > 0.99).all()


@pytest.mark.parametrize("method", METHODS)
def test_a_bump_is_more_salient_than_the_plane_far_from_it(method, bump):
    s = method(bump)
    r = np.hypot(bump[:, 0], bump[:, 1])
    inner = s[r < 0.3]
    far = s[(r > 0.6) & (np.abs(bump[:, :2]).max(axis=1) < 0.85)]
    assert np.median(inner) > 2 * np.median(far) + 1e-12
    assert roc_auc(s, r < 0.3) > 0.8


@pytest.mark.parametrize("method", METHODS)
def test_invariant_to_rigid_motion_and_scale(method, bump):
    a = method(bump)
    rot = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    moved = 7.5 * bump @ rot.T + np.array([3.0, -40.0, 12.0])
    b = method(moved)
    # rank agreement: the same points are salient
    assert np.corrcoef(np.argsort(np.argsort(a)), np.argsort(np.argsort(b)))[0, 1] > 0.98
    np.testing.assert_allclose(b, a, rtol=0.05, atol=0.02 * np.abs(a).max())


@pytest.mark.parametrize("method", METHODS)
def test_deterministic_and_input_untouched(method):
    s = make_shape("bumpy_sphere", 3000, seed=2)
    before = s.points.copy()
    a, b = method(s.points), method(s.points)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(s.points, before)
    assert roc_auc(a, s.extra["salient"]) > 0.6


def test_centre_surround_finds_the_small_features_of_the_bumpy_sphere():
    s = make_shape("bumpy_sphere", 8000, seed=3)
    assert roc_auc(sm.centre_surround_saliency(s.points), s.extra["salient"]) > 0.7


def test_errors_name_the_parameter():
    from pcprep import InvalidParameterError

    pts = make_shape("sphere", 500, seed=0).points
    with pytest.raises(InvalidParameterError, match="sigma_p"):
        sm.cluster_saliency(pts, sigma_p=0)
    with pytest.raises(InvalidParameterError, match="n_clusters"):
        sm.cluster_saliency(pts, n_clusters=1)
    with pytest.raises(InvalidParameterError, match="scales"):
        sm.centre_surround_saliency(pts, scales=(2.0, -1.0))
