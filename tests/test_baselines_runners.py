"""Tests of the MeshLab and CGAL baseline runners (baselines/meshlab.py,
baselines/cgal.py), each run crash-isolated on a small noisy unit sphere."""

from __future__ import annotations

import numpy as np
import pytest

from pcprep.baselines import cgal, meshlab
from pcprep.baselines.harness import run_isolated
from pcprep import InvalidParameterError, PointCloudError
from pcprep.filters.neighbors import average_spacing, pca_normals

N_POINTS = 3000


def _sphere(n=N_POINTS, sigma_h=0.3, seed=0):
    """Uniform unit sphere with Gaussian noise of sigma_h * spacing."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    h = np.sqrt(4.0 * np.pi / n)
    return p + rng.normal(size=(n, 3)) * sigma_h * h


def _dist(p):
    """Mean distance to the true unit sphere."""
    return float(np.abs(np.linalg.norm(p, axis=1) - 1.0).mean())


@pytest.fixture(scope="module")
def noisy():
    x = _sphere()
    return x, pca_normals(x, 16)  # consistently oriented (MST)


def _call(fn, *args, **kwargs):
    """Crash-isolated call (the way benches run the baselines)."""
    out = run_isolated(fn, *args, timeout=120, **kwargs)
    assert out.ok, out.error
    return out.value


def _direct(fn, *args, **kwargs):
    """In-process call, for CGAL simplifiers that never crashed (saves spawn time)."""
    return fn(*args, **kwargs)


# --- smoothing --------------------------------------------------------------------------

@pytest.mark.parametrize("fn", [meshlab.apss, meshlab.rimls, cgal.bilateral])
def test_projection_smoothers_reduce_error(noisy, fn):
    x, n = noisy
    y, ny = _call(fn, x, n)
    assert y.shape == x.shape and ny.shape == x.shape
    assert np.isfinite(y).all() and np.isfinite(ny).all()
    assert _dist(y) < 0.8 * _dist(x)
    np.testing.assert_allclose(np.linalg.norm(ny, axis=1), 1.0, atol=1e-6)
    # output normals stay consistently oriented along the radial direction
    radial = np.einsum("ij,ij->i", ny, y / np.linalg.norm(y, axis=1, keepdims=True))
    assert abs(radial.mean()) > 0.9
    # points stay in input order: each moves by less than a few spacings
    h = average_spacing(x)
    assert np.linalg.norm(y - x, axis=1).max() < 3 * h


def test_jet_smooth_reduces_error_and_keeps_order(noisy):
    x, _ = noisy
    y = _call(cgal.jet_smooth, x)
    assert _dist(y) < 0.8 * _dist(x)
    perm = np.random.default_rng(3).permutation(len(x))
    y_perm = _call(cgal.jet_smooth, x[perm])
    np.testing.assert_allclose(y_perm, y[perm], atol=1e-9)


def test_far_offset_is_handled(noisy):
    x, _ = noisy
    off = np.array([1e6, -2e6, 5e5])
    y = _call(cgal.jet_smooth, x + off)
    assert _dist(y - off) < 0.8 * _dist(x)


def test_mls_without_normals_is_refused(noisy):
    x, _ = noisy
    out = run_isolated(meshlab.apss, x, np.zeros_like(x), timeout=120)
    assert not out.ok and out.error.startswith("PointCloudError")
    with pytest.raises((PointCloudError, InvalidParameterError)):
        cgal.bilateral(x, None)  # would segfault in CGAL without a normal map


def test_bad_parameters_raise(noisy):
    x, n = noisy
    with pytest.raises(InvalidParameterError):
        meshlab.rimls(x, n, filterscale=0)
    with pytest.raises(InvalidParameterError):
        cgal.bilateral(x, n, sharpness_angle=120)
    with pytest.raises(InvalidParameterError):
        cgal.grid_simplify_count(x, len(x) + 1)
    with pytest.raises(PointCloudError):
        cgal.jet_smooth(np.full((10, 3), np.nan))


# --- simplification ---------------------------------------------------------------------

def _valid(idx, n):
    assert idx.dtype == np.int64 and idx.ndim == 1
    assert len(np.unique(idx)) == len(idx) and idx.min() >= 0 and idx.max() < n
    assert (np.diff(idx) > 0).all()


def test_poisson_disk_exact_count(noisy):
    x, _ = noisy
    idx = _call(meshlab.poisson_disk_exact, x, 300)
    _valid(idx, len(x))
    assert abs(len(idx) - 300) <= 3
    # Poisson-disk: kept points are spread (min spacing well above random subsets)
    from scipy.spatial import cKDTree
    d_pd = cKDTree(x[idx]).query(x[idx], k=2)[0][:, 1].min()
    rnd = cgal.random_simplify(x, 0.1, seed=0)
    d_rnd = cKDTree(x[rnd]).query(x[rnd], k=2)[0][:, 1].min()
    assert d_pd > 2 * d_rnd


def test_simplified_cloud_valid(noisy):
    x, _ = noisy
    idx = _call(meshlab.simplified_cloud, x, 300)
    _valid(idx, len(x))
    assert 100 < len(idx) < len(x)


@pytest.mark.parametrize("frac", [0.05, 0.1, 0.2])
def test_count_targeting_simplifiers(noisy, frac):
    x, _ = noisy
    count = int(frac * len(x))
    for fn in (cgal.grid_simplify_count, cgal.hierarchy_simplify_count):
        idx = _direct(fn, x, count)
        _valid(idx, len(x))
        assert abs(len(idx) - count) <= max(2, cgal.COUNT_RTOL * count), fn.__name__


def test_params_for_count_reproduce_count(noisy):
    x, _ = noisy
    count = 400
    cell = _direct(cgal.grid_cell_for_count, x, count)
    kept = _direct(cgal.grid_simplify, x, cell)
    np.testing.assert_array_equal(kept, _direct(cgal.grid_simplify_count, x, count))
    size, var = _direct(cgal.hierarchy_params_for_count, x, count)
    assert isinstance(size, int) and 0 < var <= 1 / 3
    kept = _direct(cgal.hierarchy_simplify, x, size, var)
    np.testing.assert_array_equal(kept, _direct(cgal.hierarchy_simplify_count, x, count))
    assert abs(len(kept) - count) <= cgal.COUNT_RTOL * count


def test_grid_and_hierarchy(noisy):
    x, _ = noisy
    h = average_spacing(x)
    fine = _direct(cgal.grid_simplify, x, h)
    coarse = _direct(cgal.grid_simplify, x, 3 * h)
    _valid(fine, len(x))
    _valid(coarse, len(x))
    assert len(coarse) < len(fine) < len(x)
    hier = _direct(cgal.hierarchy_simplify, x, 10)
    _valid(hier, len(x))
    assert len(x) / 15 < len(hier) < len(x) / 3


def test_wlop_creates_points_near_surface(noisy):
    x, _ = noisy
    y = _call(cgal.wlop, x, 10.0)
    assert y.shape == (300, 3)
    assert _dist(y) < 1.5 * _dist(x)
    assert not np.isin(y.view([("", y.dtype)] * 3), x.view([("", x.dtype)] * 3)).all()


def test_random_simplify_seeded(noisy):
    x, _ = noisy
    a = cgal.random_simplify(x, 0.2, seed=1)
    _valid(a, len(x))
    assert len(a) == round(0.2 * len(x))
    np.testing.assert_array_equal(a, cgal.random_simplify(x, 0.2, seed=1))
    assert not np.array_equal(a, cgal.random_simplify(x, 0.2, seed=2))


# --- other ------------------------------------------------------------------------------

def test_average_spacing_matches_ours(noisy):
    x, _ = noisy
    for k in (6, 10):
        raw = _call(cgal.average_spacing_cgal, x, k)
        assert raw * (k + 1) / k == pytest.approx(average_spacing(x, k), rel=1e-9)


def test_ball_pivoting_mesh(noisy):
    x, n = noisy
    v, f = _call(meshlab.ball_pivoting, x, n)
    assert v.shape == x.shape and np.allclose(v, x)
    assert f.ndim == 2 and f.shape[1] == 3 and len(f) > len(x)  # closed sphere ~ 2n faces
    assert f.min() >= 0 and f.max() < len(v)


def test_meshlab_normals_are_radial(noisy):
    x, _ = noisy
    nm = _call(meshlab.pca_normals_meshlab, x, 10)
    radial = np.einsum("ij,ij->i", nm, x / np.linalg.norm(x, axis=1, keepdims=True))
    assert abs(radial.mean()) > 0.95  # consistent, either all in or all out
