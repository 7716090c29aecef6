"""Tests of filters/saliency.py (thesis ch.5) and its registry declaration."""

import warnings

import numpy as np
import pytest

from pcprep import InvalidParameterError, PointCloudError, saliency_sparse_mdl
from pcprep.baselines.datasets import add_noise, make_shape
from pcprep.filters.metrics import roc_auc
from pcprep.filters.neighbors import average_spacing, build_tree
from pcprep.filters.saliency import local_frames_and_curvature, neighbourhoods

N = 4000


@pytest.fixture(scope="module")
def bumpy():
    s = make_shape("bumpy_plane", n=N, seed=0)
    return s, saliency_sparse_mdl(s.points)


def test_plane_is_uniform():
    s = make_shape("plane", n=N, seed=0)
    sal = saliency_sparse_mdl(s.points).saliency
    assert sal.min() >= 0.0 and sal.max() == pytest.approx(1.0)
    assert sal.std() < 0.02 and sal.min() > 0.9


def test_sphere_is_near_uniform():
    s = make_shape("sphere", n=N, seed=0)
    sal = saliency_sparse_mdl(s.points).saliency
    assert sal.std() < 0.05


def test_bumps_on_a_plane_are_salient(bumpy):
    s, res = bumpy
    truth = s.extra["salient"]
    assert roc_auc(res.saliency, truth) > 0.95
    assert res.saliency[truth].mean() > 1.1 * res.saliency[~truth].mean()
    # correlates with the graded ground truth (bump height profile)
    assert np.corrcoef(res.saliency, s.extra["saliency"])[0, 1] > 0.6


def test_bumps_stay_salient_under_noise():
    s = make_shape("bumpy_plane", n=N, seed=1)
    noisy = add_noise(s.points, s.normals, sigma=0.3, h=s.h, kind="normal", seed=2)
    assert roc_auc(saliency_sparse_mdl(noisy).saliency, s.extra["salient"]) > 0.9


def test_cube_edges_and_corners_are_salient():
    s = make_shape("cube", n=6000, seed=0)
    res = saliency_sparse_mdl(s.points)
    assert roc_auc(res.saliency, s.sharp) > 0.85
    to_corner = np.linalg.norm(np.abs(s.points) - 0.5, axis=1) / s.h
    corner, edge = to_corner < 1.5, s.sharp & (to_corner > 6.0)
    # the thesis' mean accumulation (default) keeps corners above edges ...
    sal = res.saliency
    assert sal[corner].mean() > 1.03 * sal[edge].mean() > 1.05 * sal[~s.sharp].mean()
    # ... the quantile accumulation lifts them to about the edge level
    sal = saliency_sparse_mdl(s.points, accumulation="quantile").saliency
    assert sal[corner].mean() > 0.98 * sal[edge].mean() > 1.05 * sal[~s.sharp].mean()


def test_invariant_to_scale_and_rigid_motion(bumpy):
    s, res = bumpy
    moved = make_shape("bumpy_plane", n=N, seed=0, rotate=True, scale=1000.0)
    np.testing.assert_allclose(moved.points / 1000.0 @ moved.extra["rotation"],
                               s.points + moved.extra["translation"] / 1000.0
                               @ moved.extra["rotation"], atol=1e-9)  # same cloud
    sal = saliency_sparse_mdl(moved.points).saliency
    # only the in-plane start angle of the rays may change (degenerate PCA frames);
    # S_T moves by up to ~0.05 on the flat part, which the mean passes on less
    # than the low-quantile accumulation does
    assert np.abs(sal - res.saliency).max() < 0.05
    assert np.corrcoef(sal, res.saliency)[0, 1] > 0.995
    # scale alone changes nothing (every length is in units of h)
    scaled = saliency_sparse_mdl(s.points * 1000.0).saliency
    np.testing.assert_allclose(scaled, res.saliency, atol=1e-6)
    q = [saliency_sparse_mdl(p, accumulation="quantile").saliency
         for p in (s.points, moved.points)]
    assert np.abs(q[0] - q[1]).max() < 0.05 and np.corrcoef(*q)[0, 1] > 0.98


def test_point_order_and_normal_sign_do_not_matter(bumpy):
    s, res = bumpy
    perm = np.random.default_rng(3).permutation(N)
    np.testing.assert_allclose(saliency_sparse_mdl(s.points[perm]).saliency,
                               res.saliency[perm], atol=5e-3)
    a = saliency_sparse_mdl(s.points, s.normals).saliency
    b = saliency_sparse_mdl(s.points, -s.normals).saliency
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_deterministic_and_input_untouched(bumpy):
    s, res = bumpy
    pts = s.points.copy()
    again = saliency_sparse_mdl(pts)
    np.testing.assert_array_equal(pts, s.points)
    np.testing.assert_array_equal(again.saliency, res.saliency)


def test_result_fields(bumpy):
    s, res = bumpy
    n = len(s.points)
    assert res.saliency.shape == res.residual.shape == res.sparsity.shape == (n,)
    assert res.descriptors.shape == (n, 5) and res.atoms.shape == (n, 8)
    np.testing.assert_allclose(np.linalg.norm(res.normals, axis=1), 1.0)
    assert res.radius == pytest.approx(3.0 * res.h)
    assert np.isfinite(res.saliency).all()
    assert 0 <= res.saliency.min() <= res.saliency.max() <= 1
    # atoms lie near the 1-ring: within r, mostly beyond r/2 on the open plane
    d = np.linalg.norm(s.points[res.atoms] - s.points[:, None, :], axis=2)
    assert (d <= res.radius * (1 + 1e-9)).all() and np.median(d) > 0.6 * res.radius


def test_mdl_measure_is_reachable(bumpy):
    s, _ = bumpy
    res = saliency_sparse_mdl(s.points, measure="mdl")
    expected = res.sparsity / res.sparsity.max() * res.residual / res.residual.max()
    np.testing.assert_allclose(res.neighbourhood_saliency, expected)


def test_quadric_curvature_of_a_sphere():
    g = np.random.default_rng(0)
    p = g.normal(size=(6000, 3))
    R = 7.0
    p = R * p / np.linalg.norm(p, axis=1)[:, None]
    hood, h = neighbourhoods(p, 3.0, 48, build_tree(p))
    assert h == pytest.approx(average_spacing(p))
    frames, gauss, total = local_frames_and_curvature(p, hood, 3 * h)
    np.testing.assert_allclose(np.median(gauss), 1 / R ** 2, rtol=0.05)
    np.testing.assert_allclose(np.median(total), np.sqrt(2) / R, rtol=0.05)
    # the third frame column is the radial direction
    assert np.median(np.abs(np.einsum("ij,ij->i", frames[:, :, 2], p / R))) > 0.999


@pytest.mark.parametrize("points, match", [
    (np.zeros((0, 3)), "empty"),
    (np.full((50, 3), np.nan), "NaN"),
    (np.random.default_rng(0).normal(size=(5, 3)), "at least"),
    (np.zeros((50, 3)), "coincide"),
    (np.outer(np.linspace(0, 1, 50), [1.0, 2.0, 3.0]), "collinear"),
    (np.ones((50, 2)), "shape"),
])
def test_bad_clouds_raise(points, match):
    with pytest.raises(PointCloudError, match=f"saliency_sparse_mdl.*{match}|{match}"):
        saliency_sparse_mdl(points)


@pytest.mark.parametrize("kwargs, name", [
    ({"radius": 0.5}, "radius"), ({"radius": -1.0}, "radius"), ({"n_rays": 2}, "n_rays"),
    ({"n_rays": 8.5}, "n_rays"), ({"alpha": 0.0}, "alpha"),
    ({"alpha": float("nan")}, "alpha"),
    ({"measure": "max"}, "measure"), ({"k_max": 4}, "k_max"),
    ({"accumulation": "max"}, "accumulation"), ({"acc_quantile": 1.5}, "acc_quantile"),
    ({"acc_quantile": -0.1}, "acc_quantile"),
])
def test_bad_parameters_raise(bumpy, kwargs, name):
    s, _ = bumpy
    with pytest.raises(InvalidParameterError, match=f"saliency_sparse_mdl.*{name}"):
        saliency_sparse_mdl(s.points[:100], **kwargs)


def test_takes_no_seed(bumpy):
    """The filter draws no random numbers, so it takes no seed (project policy)."""
    s, _ = bumpy
    assert "seed" not in {p.name for p in saliency_sparse_mdl.params}
    with pytest.raises(InvalidParameterError, match="seed"):
        saliency_sparse_mdl(s.points[:100], seed=0)


def test_bad_normals_raise(bumpy):
    s, _ = bumpy
    with pytest.raises(PointCloudError, match="rows"):
        saliency_sparse_mdl(s.points, s.normals[:10])
    nrm = s.normals.copy()
    nrm[3] = 0.0
    with pytest.raises(PointCloudError, match="zero-length"):
        saliency_sparse_mdl(s.points, nrm)


def test_estimated_normals_point_outward_on_a_closed_surface():
    s = make_shape("sphere", n=3000, seed=2, rotate=True)
    res = saliency_sparse_mdl(s.points)
    assert (np.einsum("ij,ij->i", res.normals, s.normals) > 0.9).mean() > 0.99


def test_compiled_geometry_equals_reference(monkeypatch):
    """The one-pass compiled frames, curvatures, ray atoms and neighbourhood
    means agree with the NumPy functions (frames up to the sign-free tangent
    choice where the PCA is degenerate: compared through the normal)."""
    from pcprep.filters import _kernels
    from pcprep.filters.saliency import _geometry

    if not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    s = make_shape("bumpy_plane", n=3000, seed=5)
    hood, h = neighbourhoods(s.points, 3.0, 32, build_tree(s.points))
    out = {}
    for enabled in (True, False):
        monkeypatch.setattr(_kernels, "ENABLED", enabled)
        out[enabled] = _geometry(s.points, hood, 3.0 * h, 8) + (hood.mean(s.points),)
    (fa, ga, ta, aa, ma), (fb, gb, tb, ab, mb) = out[True], out[False]
    np.testing.assert_allclose(fa[:, :, 2], fb[:, :, 2], atol=1e-9)
    np.testing.assert_allclose(ga, gb, rtol=1e-7, atol=1e-9 * np.abs(gb).max())
    np.testing.assert_allclose(ta, tb, rtol=1e-7, atol=1e-9 * np.abs(tb).max())
    assert (aa == ab).mean() > 0.999
    np.testing.assert_allclose(ma, mb, atol=1e-12)


def test_ray_atoms_match_a_naive_loop():
    from pcprep.filters.saliency import _ray_atoms

    s = make_shape("bumpy_plane", n=800, seed=4)
    hood, h = neighbourhoods(s.points, 3.0, 32, build_tree(s.points))
    r = 3.0 * h
    frames, _, _ = local_frames_and_curvature(s.points, hood, r)
    fast = _ray_atoms(s.points, hood, frames, r, 8)
    for i in range(0, 800, 37):
        nb = hood.idx[i, :hood.count[i]]
        uv = (s.points[nb] - s.points[i]) @ frames[i, :, :2]
        for k in range(8):
            th = 2 * np.pi * k / 8
            end = r * np.array([np.cos(th), np.sin(th)])
            assert fast[i, k] == nb[np.argmin(((uv - end) ** 2).sum(1))]


def test_accumulation_over_the_neighbourhoods(bumpy):
    """Point saliency = mean (default) or a quantile of S_T over the point's own
    radius neighbourhood, checked against a plain loop."""
    s, mean = bumpy
    hood, _ = neighbourhoods(s.points, 3.0, 32, build_tree(s.points))
    st = mean.neighbourhood_saliency
    res = saliency_sparse_mdl(s.points, accumulation="quantile")
    q0 = saliency_sparse_mdl(s.points, accumulation="quantile", acc_quantile=0.0)
    np.testing.assert_allclose(res.neighbourhood_saliency, st)
    exp_q = np.zeros(N)
    exp_m = np.zeros(N)
    exp_0 = np.zeros(N)
    for i in range(N):
        v = st[hood.idx[i, :hood.count[i]]]
        exp_q[i], exp_m[i], exp_0[i] = np.quantile(v, 0.1), v.mean(), v.min()
    np.testing.assert_allclose(res.saliency, exp_q / exp_q.max(), atol=1e-12)
    np.testing.assert_allclose(mean.saliency, exp_m / exp_m.max(), atol=1e-12)
    np.testing.assert_allclose(q0.saliency, exp_0 / exp_0.max(), atol=1e-12)


def test_quantile_accumulation_sharpens_edges():
    """The low-quantile accumulation ranks the narrow 1 h edge band above the
    thesis' mean accumulation (default) on a cube, clean and noisy."""
    s = make_shape("cube", n=6000, seed=1)
    for pts in (s.points, add_noise(s.points, s.normals, sigma=0.3, h=s.h,
                                    kind="normal", seed=2)):
        q = roc_auc(saliency_sparse_mdl(pts, accumulation="quantile").saliency, s.sharp)
        m = roc_auc(saliency_sparse_mdl(pts).saliency, s.sharp)
        assert q > m + 0.01


def test_orientation_survives_the_thin_tips_of_a_star():
    """Hoppe's plain n_i·n_j rule flips a whole face of this star (seed 3, 20000
    points, clean); the mirrored-chord agreement keeps the normals consistent."""
    from pcprep.filters.neighbors import orient_normals_mst

    s = make_shape("star", n=20000, seed=3)
    res = saliency_sparse_mdl(s.points)
    agree = np.einsum("ij,ij->i", res.normals, s.normals) > 0
    assert min(agree.mean(), 1 - agree.mean()) < 0.02
    hood, _ = neighbourhoods(s.points, 3.0, 32, build_tree(s.points))
    hoppe = orient_normals_mst(s.points, res.normals, k=16, neighbors=hood.idx[:, 1:17])
    agree = np.einsum("ij,ij->i", hoppe, s.normals) > 0
    assert min(agree.mean(), 1 - agree.mean()) > 0.1


def test_sign_agreement_across_a_crease():
    from pcprep.filters.neighbors import normal_agreement as _sign_agreement

    p = np.array([[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [0.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    s2 = np.sqrt(0.5)
    # two faces of a 90° roof ridge (outward normals), and a flat pair
    n = np.array([[-s2, 0.0, s2], [s2, 0.0, s2], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    i, j = np.array([0, 2]), np.array([1, 3])
    np.testing.assert_allclose(_sign_agreement(p, n, i, j), [1.0, 1.0], atol=1e-12)
    # one sign flipped -> the agreement flips too
    n[1] *= -1
    np.testing.assert_allclose(_sign_agreement(p, n, i, j), [-1.0, 1.0], atol=1e-12)


def test_mitra_nguyen_radius_known_answers():
    from pcprep.filters.saliency import MN_C1, MN_C2, MN_EPS, mitra_nguyen_radius

    kappa, rho, sigma = 0.1, 1.0, 0.3
    expect = ((MN_C1 * sigma / np.sqrt(MN_EPS * rho) + MN_C2 * sigma ** 2) / kappa) ** (1 / 3)
    got = mitra_nguyen_radius(np.array([kappa]), np.array([rho]), sigma, hi=10.0)
    assert got[0] == pytest.approx(expect, rel=1e-12)
    # more curvature: smaller; more noise or sparser sampling: larger; clipped
    r = lambda k, p, s: mitra_nguyen_radius(np.array([k]), np.array([p]), s, hi=10.0)[0]  # noqa: E731
    assert r(0.2, 1.0, 0.3) < r(0.1, 1.0, 0.3) < r(0.1, 1.0, 0.5)
    assert r(0.1, 0.5, 0.3) > r(0.1, 1.0, 0.3)
    assert r(0.0, 1.0, 0.3) == 10.0 and r(5.0, 1.0, 0.0) == 2.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")      # flat and clean: the widest, silently
        assert r(0.0, 1.0, 0.0) == 10.0


def test_adaptive_radius_per_point():
    """The thesis' radius (Mitra & Nguyen): one per point, in [2h, radius], larger
    on the flat part of a noisy bumpy plane than on its bumps (measured mean
    2.64h / 2.18h); the thesis preset takes it, tiles refuse it."""
    from pcprep.filters.saliency import THESIS

    s = make_shape("bumpy_plane", n=8000, seed=0)
    pts = add_noise(s.points, s.normals, sigma=0.5, h=s.h, seed=1)
    res = saliency_sparse_mdl(pts, adaptive_radius=True, radius=4.0, k_max=64)
    r = res.radius / res.h
    assert r.shape == (len(pts),) and r.min() >= 2.0 - 1e-9 and r.max() <= 4.0 + 1e-9
    pos = s.extra["salient"]
    assert r[~pos].mean() > r[pos].mean() + 0.2
    assert roc_auc(res.saliency, pos) > 0.8
    assert THESIS["adaptive_radius"] is True
    fixed = saliency_sparse_mdl(pts, radius=4.0, k_max=64)
    assert np.ndim(fixed.radius) == 0 and not np.allclose(fixed.saliency, res.saliency)


def test_tiles_refuse_the_adaptive_radius():
    from pcprep.meshlab_bridge.tiles import run_tiled

    pts = make_shape("bumpy_plane", n=2000, seed=0).points
    with pytest.raises(InvalidParameterError, match="adaptive_radius"):
        run_tiled("saliency", pts, params={"adaptive_radius": True})
