"""Tests of filters/denoise.py (thesis ch.4 L1-median / L1-TV denoising)."""

import numpy as np
import pymeshlab
import pytest

from pcprep import InvalidParameterError, PointCloudError, denoise_l1_tv
from pcprep.baselines.datasets import add_noise, make_shape
from pcprep.filters.denoise import DenoiseResult, energy_l1_tv
from pcprep.filters.metrics import mad_degrees, precision_recall_f1
from pcprep.filters.neighbors import pca_normals
from helpers import random_rotation


def _jaccard(a, b):
    """|a ∩ b| / |a ∪ b|; 0 when both masks are empty, so two empty masks never agree."""
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 0.0


def _noisy_plane(n=3000, sigma=0.3, seed=0):
    g = np.random.default_rng(seed)
    xy = g.uniform(-1.0, 1.0, (n, 2))
    clean = np.c_[xy, np.zeros(n)]
    h = 1.0 / np.sqrt(n / 4.0)  # rough spacing, only to size the noise
    return clean, clean + np.c_[np.zeros((n, 2)), sigma * h * g.normal(size=n)]


@pytest.fixture(scope="module")
def noisy_cube():
    s = make_shape("cube", n=6000, seed=3)
    noisy = add_noise(s.points, s.normals, sigma=0.3, h=s.h, kind="normal", seed=4)
    return s, noisy


@pytest.fixture(scope="module")
def cube_result(noisy_cube):
    return denoise_l1_tv(noisy_cube[1], n_iter=8)


def test_noisy_plane_converges_onto_the_plane():
    clean, noisy = _noisy_plane()
    out = denoise_l1_tv(noisy, n_iter=10)
    inner = np.abs(clean[:, :2]).max(axis=1) < 0.8  # away from the open border
    before = np.abs(noisy[inner, 2]).mean()
    after = np.abs(out.points[inner, 2]).mean()
    # σ_d = 2h (3000 random points): the residual is ~0.3 of the input noise
    assert after < 0.4 * before
    # normals converge to ±z
    ang = np.degrees(np.arccos(np.clip(np.abs(out.normals[inner, 2]), 0.0, 1.0)))
    assert ang.mean() < 2.0 and np.percentile(ang, 99) < 6.0
    # points move (almost) only along the normal
    tangential = np.linalg.norm(out.points[inner, :2] - noisy[inner, :2], axis=1)
    assert tangential.mean() < 0.1 * out.h


def test_result_shapes_and_types(cube_result, noisy_cube):
    s, noisy = noisy_cube
    r = cube_result
    assert isinstance(r, DenoiseResult)
    n = len(noisy)
    assert r.points.shape == (n, 3) and r.normals.shape == (n, 3)
    assert r.edge_mask.shape == (n,) and r.edge_mask.dtype == bool
    assert np.allclose(np.linalg.norm(r.normals, axis=1), 1.0)
    assert np.isfinite(r.points).all()
    assert r.h == pytest.approx(s.h, rel=0.1)
    # displacement bounded by ε = 4h plus one edge correction (ρ = 0.7h)
    assert np.linalg.norm(r.points - noisy, axis=1).max() <= (4.0 + 0.7) * r.h + 1e-9


def test_noisy_cube_keeps_edges(cube_result, noisy_cube):
    s, noisy = noisy_cube
    r = cube_result
    pca = pca_normals(noisy, k=16, orient=False)
    sharp = s.sharp
    mad_ours = mad_degrees(s.normals[sharp], r.normals[sharp])
    mad_pca = mad_degrees(s.normals[sharp], pca[sharp])
    near = s.extra["edge_distance"] / s.h
    band = (near > 1.0) & (near < 3.0)  # just off the edge: PCA blends faces here
    assert mad_degrees(s.normals[band], r.normals[band]) < 0.7 * mad_degrees(
        s.normals[band], pca[band])
    assert mad_ours < mad_pca
    flat = near > 4.0
    assert mad_degrees(s.normals[flat], r.normals[flat]) < 0.4 * mad_degrees(
        s.normals[flat], pca[flat])
    # edge detector: edge points concentrate at the edges (F1 0.55 against the
    # crease points, 97 % of the detections within 2h of an edge)
    assert precision_recall_f1(r.edge_mask, sharp)[2] > 0.45
    assert precision_recall_f1(r.edge_mask, near < 2.0)[0] > 0.9
    assert np.median(near[r.edge_mask]) < 1.5
    assert r.edge_mask[flat].mean() < 0.02


def test_outputs_oriented_consistently_with_hint(noisy_cube):
    s, noisy = noisy_cube
    r = denoise_l1_tv(noisy, s.normals, n_iter=2)
    assert (np.einsum("ij,ij->i", r.normals, s.normals) > 0).all()


def test_energy_does_not_increase_over_inner_iterations(noisy_cube):
    _, noisy = noisy_cube
    r = denoise_l1_tv(noisy, n_iter=4, inner_iter=6, tol=0.0)
    assert len(r.energy_history) == 4
    assert any(len(h) > 2 for h in r.energy_history)
    for hist in r.energy_history:
        assert np.all(np.diff(hist) <= 1e-9 * abs(hist[0]))
    # the optimisation lowers the energy overall
    assert r.energy_history[-1][-1] < r.energy_history[0][0]


def test_energy_function_known_answers():
    clean, _ = _noisy_plane(n=1500)
    up = np.tile([0.0, 0.0, 1.0], (len(clean), 1))
    assert energy_l1_tv(clean, up) == pytest.approx(0.0, abs=1e-6)
    # flipping half the normals changes nothing (unoriented), tilting them costs
    flip = up.copy()
    flip[::2] *= -1
    assert energy_l1_tv(clean, flip) == pytest.approx(0.0, abs=1e-6)
    tilt = np.tile([np.sin(0.3), 0.0, np.cos(0.3)], (len(clean), 1))
    assert energy_l1_tv(clean, tilt) > 1.0
    # an offset τ raises the fidelity term
    assert energy_l1_tv(clean, up, np.full(len(clean), 0.3)) > 1.0


def _close(a, b, h):
    """Positions equal up to float32 rounding of the neighbour arrays; a few
    discrete choices (accept/reject of a step) may flip for isolated points."""
    d = np.linalg.norm(a - b, axis=1) / h
    return np.median(d) < 1e-4 and np.percentile(d, 95) < 1e-2 and d.max() < 0.3


def test_invariant_to_scale_rigid_motion_and_order(noisy_cube):
    _, noisy = noisy_cube
    pts = noisy[:2500]
    base = denoise_l1_tv(pts, n_iter=3)
    scaled = denoise_l1_tv(1000.0 * pts + 1e4, n_iter=3)
    assert np.abs((scaled.points - 1e4) / 1000.0 - base.points).max() < 1e-6 * base.h
    assert _jaccard(scaled.edge_mask, base.edge_mask) == 1.0
    rot = random_rotation(5)
    t = np.array([1e3, -2e3, 5e2])
    moved = denoise_l1_tv(pts @ rot.T + t, n_iter=3)
    assert _close((moved.points - t) @ rot, base.points, base.h)
    cosines = np.abs(np.einsum("ij,ij->i", moved.normals @ rot, base.normals))
    assert np.median(cosines) > 1 - 1e-9
    assert _jaccard(moved.edge_mask, base.edge_mask) > 0.97
    perm = np.random.default_rng(1).permutation(len(pts))
    shuf = denoise_l1_tv(pts[perm], n_iter=3)
    assert _close(shuf.points, base.points[perm], base.h)
    assert _jaccard(shuf.edge_mask, base.edge_mask[perm]) > 0.97


@pytest.mark.parametrize("kwargs", [
    dict(n_iter=3),
    dict(n_iter=3, tv_norm="l1", edge_correction=True, curvature_offset=False,
         final_projection=False, inner_iter=4, k_max=48),
], ids=["defaults", "thesis-like"])
def test_compiled_and_numpy_passes_agree(noisy_cube, monkeypatch, kwargs):
    """The compiled row kernels (filters/_denoise_jit.py) and the NumPy passes
    compute the same thing; only the order of the float64 sums differs."""
    from pcprep.filters import _kernels

    if not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    pts = noisy_cube[1][:3000] @ random_rotation(2).T + [50.0, -20.0, 7.0]
    out = {}
    for enabled in (True, False):
        monkeypatch.setattr(_kernels, "ENABLED", enabled)
        out[enabled] = denoise_l1_tv(pts, **kwargs)
    a, b = out[True], out[False]
    assert np.abs(a.points - b.points).max() < 1e-9 * a.h
    assert np.abs(a.normals - b.normals).max() < 1e-9
    assert np.abs(a.edge_score - b.edge_score).max() < 1e-9
    assert a.n_corrected == b.n_corrected
    assert [len(e) for e in a.energy_history] == [len(e) for e in b.energy_history]
    np.testing.assert_allclose(np.concatenate(a.energy_history),
                               np.concatenate(b.energy_history), rtol=1e-10)
    if kwargs.get("edge_correction"):
        assert a.n_corrected > 0  # the correction ran on both paths


def test_compiled_exp_is_within_two_ulp_of_libm():
    """The kernels' exponential (filters/_denoise_jit._exp_into) against NumPy's
    over the arguments the energy produces, the underflow to subnormals and
    zero, and exact points."""
    from pcprep.filters import _denoise_jit, _kernels

    if not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    rng = np.random.default_rng(5)
    edges = [0.0, -0.0, -1e-300, -0.5 * np.log(2), -np.log(2), -1.0, -708.0, -708.5,
             -744.0, -745.0, -745.2, -746.0, -1e4, 1.0, 5.0, 700.0, 709.0]
    x = np.concatenate([-rng.random(200_000) * 60.0, -rng.random(50_000) * 1e-6,
                        -rng.random(50_000) * 760.0, rng.random(10_000) * 700.0, edges])
    got = _denoise_jit.exp_rows(x)
    ref = np.exp(x)
    normal = ref >= np.finfo(float).tiny
    ulp = np.abs(got - ref)[normal] / np.spacing(ref[normal])
    assert ulp.max() <= 2.0
    assert np.abs(got - ref)[~normal].max() <= np.finfo(float).smallest_subnormal
    assert got[x < -745.2].max() == 0.0 and got[x == 0.0].min() == 1.0
    assert np.mean(got == ref) > 0.5  # most values exact, not merely close


def test_thesis_l1_norm_is_reachable(noisy_cube):
    _, noisy = noisy_cube
    a = denoise_l1_tv(noisy[:1500], n_iter=2, tv_norm="l1")
    b = denoise_l1_tv(noisy[:1500], n_iter=2)
    assert not np.allclose(a.points, b.points)


def test_deterministic_and_input_untouched(noisy_cube):
    _, noisy = noisy_cube
    pts = noisy[:2000].copy()
    keep = pts.copy()
    a = denoise_l1_tv(pts, n_iter=2)
    b = denoise_l1_tv(pts, n_iter=2)
    assert np.array_equal(a.points, b.points)
    assert np.array_equal(a.normals, b.normals)
    assert np.array_equal(pts, keep)


@pytest.mark.parametrize("points, match", [
    (np.zeros((0, 3)), "empty"),
    (np.full((50, 3), np.nan), "NaN"),
    (np.random.default_rng(0).normal(size=(5, 3)), "at least"),
    (np.zeros((50, 3)), "coincide"),
    (np.c_[np.linspace(0, 1, 50), np.zeros((50, 2))], "collinear"),
    (np.zeros((10, 2)), "shape"),
])
def test_bad_input_raises(points, match):
    with pytest.raises(PointCloudError, match=match):
        denoise_l1_tv(points)


@pytest.mark.parametrize("kwargs", [
    dict(sigma_d=-1.0), dict(sigma_h=0.0), dict(lambda_tv=-0.1), dict(n_iter=0),
    dict(sigma_n_deg=120.0), dict(edge_threshold=1.5), dict(k_max=2), dict(tv_norm="l0"),
    dict(n_iter=2.5), dict(edge_correction="yes"),
])
def test_bad_parameters_raise(kwargs):
    clean, noisy = _noisy_plane(n=200)
    with pytest.raises(InvalidParameterError, match="denoise_l1_tv"):
        denoise_l1_tv(noisy, **kwargs)


def test_bad_normals_raise():
    _, noisy = _noisy_plane(n=200)
    with pytest.raises(PointCloudError, match="normals"):
        denoise_l1_tv(noisy, np.ones((10, 3)))


def test_registry_filter_on_meshset(noisy_cube):
    from pcprep.meshlab_bridge.apply import apply_filter

    s, noisy = noisy_cube
    pts = noisy[:3000]
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=pts, v_normals_matrix=s.normals[:3000]))
    out = apply_filter(ms, "denoise", n_iter=3)
    direct = denoise_l1_tv(pts, s.normals[:3000], n_iter=3)
    m = ms.current_mesh()
    assert m.vertex_number() == len(pts)
    assert np.allclose(m.vertex_matrix(), direct.points)
    assert np.allclose(m.vertex_normal_matrix(), direct.normals, atol=1e-6)
    assert _jaccard(m.vertex_selection_array(), direct.edge_mask) == 1.0
    assert out["selected"] == int(direct.edge_mask.sum())


def test_edge_correction_moves_edge_points_within_rho(noisy_cube):
    s, noisy = noisy_cube
    # the correction as printed, without the final sphere projection
    off = denoise_l1_tv(noisy, n_iter=1, final_projection=False)
    on = denoise_l1_tv(noisy, n_iter=1, edge_correction=True, final_projection=False)
    assert off.n_corrected == 0
    assert on.n_corrected > 0
    # the correction acts near the edges only
    near = s.extra["edge_distance"] / s.h
    step = np.linalg.norm(on.points - off.points, axis=1)
    moved = step > 1e-9 * on.h
    assert moved.sum() == on.n_corrected
    assert step.max() < 0.7 * on.h  # |d| < ρh (4.19)
    assert np.median(near[moved]) < 2.0
    # with the final projection, corrected edge points keep their corrected place
    both = denoise_l1_tv(noisy, n_iter=1, edge_correction=True)
    assert both.n_corrected == on.n_corrected
    assert _jaccard(both.edge_mask, on.edge_mask) == 1.0
    assert np.allclose(both.points[both.edge_mask], on.points[on.edge_mask])


def test_final_projection_removes_shrinkage_on_a_sphere():
    s = make_shape("sphere", n=4000, seed=5)
    noisy = add_noise(s.points, s.normals, sigma=0.3, h=s.h, kind="normal", seed=6)
    c = s.points.mean(axis=0)
    radius = np.linalg.norm(s.points - c, axis=1).mean()

    def err(p):
        return (np.linalg.norm(p - c, axis=1) - radius) / s.h

    on = denoise_l1_tv(noisy)
    off = denoise_l1_tv(noisy, final_projection=False)
    assert np.abs(err(on.points)).mean() < 0.45 * np.abs(err(noisy)).mean()
    assert np.abs(err(on.points)).mean() < 0.85 * np.abs(err(off.points)).mean()
    # plane projections sit inside a convex surface; the sphere fit does not
    assert abs(err(on.points).mean()) < 0.5 * abs(err(off.points).mean())
    # normals are the filter's own: the projection does not change them
    assert np.allclose(on.normals, off.normals)


def test_normals_consistently_oriented_without_hint():
    s = make_shape("sphere", n=3000, seed=2)
    noisy = add_noise(s.points, s.normals, sigma=0.2, h=s.h, kind="normal", seed=3)
    r = denoise_l1_tv(noisy, n_iter=2)
    side = np.sign(np.einsum("ij,ij->i", r.normals, r.points))
    assert abs(side.sum()) == len(side)  # all outward or all inward


def test_takes_no_seed():
    """The filter draws no random numbers, so it takes no seed (project policy)."""
    _, noisy = _noisy_plane(n=200)
    assert "seed" not in {p.name for p in denoise_l1_tv.params}
    with pytest.raises(InvalidParameterError, match="seed"):
        denoise_l1_tv(noisy, seed=0)


def test_private_config_path_equals_the_public_call(noisy_cube):
    """The path a harness or a preset uses: a config whose defaults are the
    signature's, changed with dataclasses.replace."""
    from dataclasses import asdict, replace

    from pcprep.filters.denoise import _DEFAULTS, _denoise

    assert asdict(_DEFAULTS) == {p.name: p.default for p in denoise_l1_tv.params
                                 if p.name != "preset"}  # the preset only fills values
    pts = noisy_cube[1][:1500]
    a = _denoise(pts, None, replace(_DEFAULTS, n_iter=2, tv_norm="l1"))
    b = denoise_l1_tv(pts, n_iter=2, tv_norm="l1")
    assert np.array_equal(a.points, b.points) and np.array_equal(a.normals, b.normals)
    assert _jaccard(a.edge_mask, b.edge_mask) == 1.0


def test_printed_initial_normals_known_answer():
    """(4.9) as printed: pass 1 is the smallest eigenvector of Σ θ (p_i − p_j)(p_i − p_j)ᵀ
    about p_i itself (Cm(0)); pass 2 reweights by ψθ/|h_j|, h_j = n¹ᵀ(p_i − p_j)."""
    from pcprep.filters._denoise_kernels import _prepare
    from pcprep.filters._denoise_steps import _init_normals
    from pcprep.filters.denoise import _DEFAULTS, _context

    _, noisy = _noisy_plane(n=800, sigma=0.5, seed=2)
    x, _, _, _, idx, _ = _prepare(noisy, None, 32, "t")
    ctx = _context(x, idx, _DEFAULTS)
    r2, sd2, sh2 = ctx.r2, ctx.sd2, ctx.sh2

    def brute(prev):
        out = np.zeros((len(x), 3))
        for i in range(len(x)):
            d = x[i] - x[idx[i]]
            d2 = (d * d).sum(1)
            w = np.exp(-d2 / sd2) * (d2 <= r2)
            if prev is not None:
                hj = d @ prev[i]
                a = np.abs(hj)
                w = np.where(a < 1e-3, w, np.exp(-hj ** 2 / sh2) * w / np.maximum(a, 1e-300))
            out[i] = np.linalg.eigh((w[:, None] * d).T @ d)[1][:, 0]
        return out

    def angle(a, b):
        return np.degrees(np.arccos(np.clip(np.abs((a * b).sum(1)), 0, 1)))

    one = _init_normals(ctx, 1, 8, printed=True)
    ref1 = brute(None)
    assert angle(one, ref1).max() < 1e-3
    two = _init_normals(ctx, 2, 8, printed=True)
    assert angle(two, brute(ref1)).max() < 1e-3
    # not the default n⁰ (weighted mean, robust plane, candidate search)
    assert angle(_init_normals(ctx, 2, 8), two).max() > 1.0


def test_thesis_preset_takes_the_printed_initial_normals(noisy_cube):
    from pcprep.filters.denoise import THESIS

    assert THESIS["robust_init"] is False
    _, noisy = noisy_cube
    a = denoise_l1_tv(noisy[:1500], n_iter=1, robust_init=False)
    b = denoise_l1_tv(noisy[:1500], n_iter=1)
    assert not np.allclose(a.normals, b.normals)


def test_thin_wall_keeps_both_faces():
    """A plate 2h thick: the far face lies inside every 3h neighbourhood.  The
    final sphere fit leaves it out (its height is not explained by any turn of
    the normals), so the plate keeps its thickness and the output is closer to
    the clean plate than the input (measured +10 dB; without the sheet test the
    fit spans both faces: thickness 1.3h, −12 dB)."""
    from pcprep.filters.metrics import snr_db
    from pcprep.filters.neighbors import average_spacing

    g = np.random.default_rng(0)
    n = 12000
    xy = g.uniform(0, 1, (n, 2))
    h = average_spacing(np.c_[xy[: n // 2], np.zeros(n // 2)])
    top = np.arange(n) >= n // 2
    clean = np.c_[xy, np.where(top, 2.0 * h, 0.0)]
    noisy = clean + np.c_[np.zeros((n, 2)), 0.1 * h * g.normal(size=n)]
    out = denoise_l1_tv(noisy)
    thick = np.median(out.points[top, 2]) - np.median(out.points[~top, 2])
    assert thick == pytest.approx(2.0 * h, abs=0.1 * h)
    assert snr_db(clean, out.points) > snr_db(clean, noisy) + 5.0
