"""
denoise.py
----------
Feature-preserving point-cloud denoising by L1-median height fitting with L1
(total-variation) normal regularisation, thesis chapter 4, eqs (4.2)-(4.19).

Per point p_i the filter looks for a unit normal n_i and an offset τ_i that
minimise the energy (4.5)

    E_i = Σ_j |h_ij − τ_i| ψ_ij θ_ij  +  λ Σ_j w_ij ‖n_i − n_j‖ ,
    h_ij = n_iᵀ(p_i − p_j),  ψ = exp(−(h−τ)²/σ_h²),  θ = exp(−d²/σ_d²),
    w_ij = exp(−((1 − n_iᵀn_j)/(1 − cos σ_n))²),

over the radius-r neighbourhood N_g(p_i) (‖·‖ is the thesis' component-wise ℓ1
norm with ``tv_norm="l1"``, the rotation-invariant ℓ2 norm by default), then
moves p_i onto its robust plane.  By default a final step (not in the thesis)
projects every input point onto an algebraic sphere fitted with the filtered
normals (see Notes of :func:`denoise_l1_tv`).
Algorithm 4.1: n⁰ by the reweighted eigen-iteration (4.6)-(4.9); then, per outer
iteration, an inner loop alternating one proximal-gradient normal step
(4.10)-(4.12) and the IRLS weighted-median τ step (4.14); the bounded position
update (4.15); edge-point detection (4.16)-(4.17) and correction (4.18)-(4.19).

Everything runs on one padded neighbour array ``(n, k_max)`` built by a single
k-NN query, in chunks of points, on all cores (NumPy releases the GIL); there is
no Python loop over points.
"""

from __future__ import annotations

import logging
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ._params import Param, resolve_params, validate_params
from ._validation import (InvalidParameterError, PointCloudError, as_normals, as_points,
                          check_spread)
from .neighbors import SPACING_K, build_tree, centered, orient_normals_mst

log = logging.getLogger("pcprep")

#: points per chunk of the neighbour passes (small blocks stay in the allocator's
#: heap and in cache)
CHUNK = 2048
#: |h_j − τ| below GUARD (in units of h) uses η = θ instead of ψθ/|h_j − τ|
#: (thesis: 1e-3 absolute, see Notes)
GUARD = 1e-3
#: points per chunk of the k-NN query
QUERY_CHUNK = 131_072
#: neighbour normals tried as starting points of (4.9)
N_CAND = 8
#: init passes followed by the candidate selection
SELECT_PASSES = 1
#: neighbours of the MST orientation of the output normals
MST_K = 6
#: default neighbourhood radius r in units of σ_d (thesis: 1)
RADIUS_FACTOR = 1.5
#: sag |c|·r² (units of h) of the fit h ≈ a + cρ² above which a non-edge point
#: counts as curved and stops moving after ``curved_iter`` outer iterations
CURVED_SAG = 0.05
#: IRLS sub-iterations of the τ step (4.14) per inner iteration
TAU_IRLS = 3
#: neighbours of the plain PCA normals that seed the final sphere fit on curved parts
FIT_PCA_K = 16
#: Newton steps of the projection onto the fitted algebraic sphere
PROJ_STEPS = 3

PARAMS = (
    Param("lambda_tv", float, low=0.0, high=100.0),
    Param("sigma_h", float, low=0.0, high=50.0, closed="right", unit="h"),
    Param("sigma_d", float, low=0.0, high=50.0, closed="right", unit="h"),
    Param("radius", float, low=0.0, high=50.0, closed="right", unit="h", optional=True),
    Param("sigma_n_deg", float, low=0.0, high=90.0, closed="right", unit="deg"),
    Param("rho", float, low=0.0, high=10.0, unit="h"),
    Param("delta", float, low=0.0, high=1.0, unit="h"),
    Param("epsilon", float, low=0.0, high=100.0, closed="right", unit="h"),
    Param("edge_threshold", float, low=0.0, high=1.0, unit="fraction"),
    Param("n_iter", int, low=1, high=500, unit="count"),
    Param("curved_iter", int, low=0, high=500, unit="count", advanced=True),
    Param("inner_iter", int, low=1, high=100, unit="count", advanced=True),
    Param("init_iter", int, low=1, high=50, unit="count", advanced=True),
    Param("tol", float, low=0.0, high=10.0, unit="h", advanced=True),
    Param("edge_correction", bool),
    Param("curvature_offset", bool, advanced=True),
    Param("tv_norm", str, choices=("l2", "l1"), advanced=True),
    Param("k_max", int, low=4, high=512, unit="count", advanced=True),
    Param("final_projection", bool, advanced=True),
    Param("seed", int, low=0, optional=True, advanced=True),
)


@dataclass(frozen=True)
class DenoiseResult:
    """Output of :func:`denoise_l1_tv`.

    Attributes
    ----------
    points : (n, 3) float
        Denoised positions, in input order.
    normals : (n, 3) float
        Unit normals, consistently oriented (toward the input normals when given,
        else by MST propagation).
    edge_mask : (n,) bool
        Edge points of the last outer iteration, V_n < th (4.17).
    edge_score : (n,) float
        Normal variation V_n in [0, 1] (1 = flat neighbourhood).
    h : float
        Average spacing of the input (mean distance to 6 nearest neighbours).
    energy_history : tuple of tuple of float
        Energy (4.5) summed over points, lengths in units of h, at every accepted
        inner iteration of every outer iteration (non-increasing within each).
    n_iter_run : int
        Outer iterations run.
    n_corrected : int
        Points moved by the edge correction in the last outer iteration.
    """

    points: np.ndarray
    normals: np.ndarray
    edge_mask: np.ndarray
    edge_score: np.ndarray
    h: float
    energy_history: tuple
    n_iter_run: int
    n_corrected: int


# ---------------------------------------------------------------------------
# chunked, threaded execution

def _workers() -> int:
    return max(1, min(4, os.cpu_count() or 1))


def _run_chunks(fn, n: int) -> list:
    """Call ``fn(s, e)`` over [0, n) in chunks, on a thread pool; results in order."""
    bounds = [(s, min(n, s + CHUNK)) for s in range(0, n, CHUNK)]
    nw = _workers()
    if nw == 1 or len(bounds) == 1:
        return [fn(s, e) for s, e in bounds]
    with ThreadPoolExecutor(max_workers=nw) as ex:
        return list(ex.map(lambda b: fn(*b), bounds))


F32 = np.float32


@dataclass
class _Ctx:
    """Working state shared by the chunk kernels (lengths in units of h).

    Neighbour arrays are built per chunk in structure-of-arrays float32 form
    (one (c, k) array per coordinate); per-point state stays float64.
    """

    x: np.ndarray        # (n, 3) float64 current positions (units of h, centred)
    idx: np.ndarray      # (n, k) neighbour indices, self first
    r2: float            # radius²
    sd2: float           # σ_d²
    sh2: float           # σ_h²
    lam: float           # λ
    cos_n: float         # cos σ_n
    sn2: float           # σ_n² (radians²)
    l1: bool = False     # component-wise ℓ1 TV (thesis) instead of ℓ2
    xt: np.ndarray = None  # (3, n) float32 copy of x for gathers

    def refresh(self):
        self.xt = np.ascontiguousarray(self.x.T, dtype=F32)


def _geometry(ctx: _Ctx, s: int, e: int):
    """D = p_i − p_j per coordinate, |D|², θ and the radius mask, rows s:e."""
    idx = ctx.idx[s:e]
    d = []
    for a in range(3):
        col = ctx.xt[a]
        da = np.take(col, idx)
        np.subtract(col[s:e, None], da, out=da)
        d.append(da)
    d2 = d[0] * d[0]
    d2 += d[1] * d[1]
    d2 += d[2] * d[2]
    valid = d2 <= ctx.r2
    theta = np.exp(d2 * F32(-1.0 / ctx.sd2))
    theta *= valid
    return d, d2, valid, theta


def _dot(d, v):
    """Σ_a d[a] * v[:, a] for (c, k) arrays ``d`` and (c, 3) ``v``."""
    v = v.astype(F32, copy=False)
    out = d[0] * v[:, 0:1]
    out += d[1] * v[:, 1:2]
    out += d[2] * v[:, 2:3]
    return out


def _psi(res: np.ndarray, sh2: float) -> np.ndarray:
    return np.exp(np.square(res) * F32(-1.0 / sh2))


def _eta(res: np.ndarray, psi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """η = ψθ/|h − τ|, and θ where |h − τ| < GUARD (thesis after (4.10))."""
    a = np.abs(res)
    small = a < GUARD
    a[small] = 1.0
    out = psi * theta
    out /= a
    np.copyto(out, theta, where=small)
    return out


def _rowsum(a: np.ndarray) -> np.ndarray:
    """Row sums of a (c, k) float32 array (BLAS matrix-vector product), as float64."""
    return (a @ np.ones(a.shape[1], dtype=a.dtype)).astype(np.float64)


def _fidelity(hgt, tau, theta, sh2):
    """Per-point fidelity Σ_j |h_j − τ| ψ θ (4.3)."""
    res = hgt - tau.astype(F32)[:, None]
    out = np.abs(res)
    out *= _psi(res, sh2)
    out *= theta
    return _rowsum(out)


def _tau_irls(hgt, tau, theta, sh2, n_steps=TAU_IRLS):
    """IRLS weighted L1-median of the heights (4.14); ``hgt`` (..., k)."""
    tau = tau.astype(F32)
    for _ in range(n_steps):
        r = hgt - tau[..., None]
        et = _eta(r, _psi(r, sh2), theta)
        den = et.sum(axis=-1)
        num = (et * hgt).sum(axis=-1)
        tau = np.where(den > 0, num / np.where(den > 0, den, 1.0), tau).astype(F32)
    return tau.astype(np.float64)


def _smallest_eigvec(c00, c01, c02, c11, c12, c22):
    """Unit eigenvector of the smallest eigenvalue of batched symmetric 3×3
    matrices given by their upper triangles (closed form, float64)."""
    c00, c01, c02, c11, c12, c22 = (np.asarray(v, dtype=np.float64)
                                    for v in (c00, c01, c02, c11, c12, c22))
    q = (c00 + c11 + c22) / 3.0
    p1 = c01 ** 2 + c02 ** 2 + c12 ** 2
    p2 = (c00 - q) ** 2 + (c11 - q) ** 2 + (c22 - q) ** 2 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    ps = np.where(p > 0, p, 1.0)
    b00, b11, b22 = (c00 - q) / ps, (c11 - q) / ps, (c22 - q) / ps
    b01, b02, b12 = c01 / ps, c02 / ps, c12 / ps
    det = (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02)
           + b02 * (b01 * b12 - b11 * b02))
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    lam0 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    r0 = np.stack([c00 - lam0, c01, c02], axis=1)
    r1 = np.stack([c01, c11 - lam0, c12], axis=1)
    r2 = np.stack([c02, c12, c22 - lam0], axis=1)
    cands = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)
    nrm = np.linalg.norm(cands, axis=2)
    best = np.argmax(nrm, axis=1)
    rows = np.arange(len(q))
    v = cands[rows, best]
    ln = nrm[rows, best]
    ok = ln > 1e-300
    v = np.where(ok[:, None], v / np.where(ok, ln, 1.0)[:, None],
                 np.array([0.0, 0.0, 1.0]))
    return v


def _tv(ctx: _Ctx, n_i: np.ndarray, nb, tvmask):
    """Sign-aligned neighbour normals, w_ij and Σ_j w_ij‖n_i − n_j‖ (4.4), the
    norm being ℓ2 (``ctx.l1`` False) or the thesis' component-wise ℓ1."""
    dots = _dot(nb, n_i)
    sgn = np.where(dots < 0, F32(-1.0), F32(1.0))
    al = [nb[a] * sgn for a in range(3)]
    c = np.abs(dots)
    w = np.square((1.0 - c) * F32(1.0 / (1.0 - ctx.cos_n)))
    np.negative(w, out=w)
    np.exp(w, out=w)
    w *= tvmask
    ni = n_i.astype(F32)
    if ctx.l1:
        dist = np.abs(ni[:, 0:1] - al[0])
        dist += np.abs(ni[:, 1:2] - al[1])
        dist += np.abs(ni[:, 2:3] - al[2])
    else:
        dist = np.square(ni[:, 0:1] - al[0])
        dist += np.square(ni[:, 1:2] - al[1])
        dist += np.square(ni[:, 2:3] - al[2])
        np.sqrt(dist, out=dist)
    dist *= w
    return al, w, _rowsum(dist)


# ---------------------------------------------------------------------------
# the steps of Algorithm 4.1

def _init_normals(ctx: _Ctx, init_iter: int, n_cand: int) -> np.ndarray:
    """n⁰ by the reweighted eigen-iteration (4.9), with the offset τ of (4.5).

    Pass 1 is θ-weighted PCA (ω = θ, n = 0).  Then every point takes, among its
    own normal and those of ``n_cand`` neighbours spread over its list, the one
    of lowest robust loss Σ_j θ(1 − ψ) (τ by (4.14) for each candidate).  Later
    passes take the smallest eigenvector of Σ_j ω_j (c_i − p_j)(c_i − p_j)ᵀ with
    c_i = p_i − τ_i n_i and ω = ψθ/|h_j − τ_i| (θ where |h_j − τ_i| < GUARD).
    """
    n = len(ctx.x)
    normals = np.zeros((n, 3))
    tau = np.zeros(n)
    k = ctx.idx.shape[1]
    cols = np.unique(np.linspace(1, k - 1, min(n_cand, k - 1)).round().astype(int))

    def kernel(s, e, first):
        d, _, _, theta = _geometry(ctx, s, e)
        if first:
            wsum = theta.sum(axis=1, keepdims=True)
            om = theta / wsum
            dc = [da - _rowsum(om * da)[:, None].astype(F32) for da in d]
            t_new = np.zeros(e - s)
        else:
            n_i = normals[s:e]
            hgt = _dot(d, n_i)
            t_new = _tau_irls(hgt, tau[s:e], theta, ctx.sh2)
            res = hgt - t_new.astype(F32)[:, None]
            om = _eta(res, _psi(res, ctx.sh2), theta)
            dc = [d[a] - (t_new * n_i[:, a]).astype(F32)[:, None] for a in range(3)]
        wd = [om * dc[a] for a in range(3)]
        cov = [_rowsum(wd[a] * dc[b]) for a, b in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2),
                                                   (2, 2))]
        return _smallest_eigvec(*cov), t_new

    def select(s, e):
        d, _, valid, theta = _geometry(ctx, s, e)
        m = len(cols) + 1
        cand = np.concatenate([normals[s:e, None, :], normals[ctx.idx[s:e][:, cols]]],
                              axis=1)
        ok = np.concatenate([np.ones((e - s, 1), bool), valid[:, cols]], axis=1)
        c32 = cand.astype(F32)
        hgt = (d[0][:, None, :] * c32[:, :, 0:1] + d[1][:, None, :] * c32[:, :, 1:2]
               + d[2][:, None, :] * c32[:, :, 2:3])
        th = theta[:, None, :]
        # τ from 0, as in Algorithm 4.1: the search favours planes near p_i
        t = _tau_irls(hgt, np.zeros(hgt.shape[:2], F32), th, ctx.sh2).astype(F32)
        res = hgt - t[..., None]
        # Welsch loss Σ θ(1 − ψ): (4.3) itself redescends to 0 and would prefer a
        # plane that misses every neighbour
        loss = ((1.0 - _psi(res, ctx.sh2)) * th).sum(axis=2, dtype=np.float64)
        loss[~ok] = np.inf
        best = np.argmin(loss, axis=1)
        rows = np.arange(e - s)
        del m
        return cand[rows, best], t[rows, best].astype(np.float64)

    for it in range(init_iter):
        parts = _run_chunks(lambda s, e: kernel(s, e, it == 0), n)
        new = np.concatenate([q[0] for q in parts], axis=0)
        tau = np.concatenate([q[1] for q in parts])
        if it > 0:  # keep each normal's sign from pass to pass
            flip = np.einsum("ij,ij->i", new, normals) < 0
            new[flip] *= -1.0
        normals = new
        if n_cand > 0 and it < SELECT_PASSES:
            parts = _run_chunks(select, n)
            normals = np.concatenate([q[0] for q in parts], axis=0)
            tau = np.concatenate([q[1] for q in parts])
    return normals


def _inner_pass(ctx: _Ctx, normals: np.ndarray, tau: np.ndarray, propose: bool,
                vn: bool = False):
    """One pass over all points at fixed positions.

    Returns the per-point energy (4.5) of the current state ``(normals, tau)``;
    when ``propose`` also the next state: the IRLS τ step (4.14) at the current
    normals (kept per point only if it lowers the point's fidelity), then one
    proximal-gradient normal step (4.10)-(4.12) at the new τ.  With ``vn`` also
    returns the normal variation V_n (4.17).
    """
    n = len(ctx.x)
    energy = np.zeros(n)
    new_n = np.zeros((n, 3)) if propose else None
    new_t = np.zeros(n) if propose else None
    vnorm = np.zeros(n) if vn else None
    offset = np.zeros(n) if vn else None
    curv = np.zeros(n) if vn else None
    nt = np.ascontiguousarray(normals.T, dtype=F32)

    def kernel(s, e):
        d, d2, valid, theta = _geometry(ctx, s, e)
        idx = ctx.idx[s:e]
        n_i = normals[s:e]
        t_i = tau[s:e]
        nb = [np.take(nt[a], idx) for a in range(3)]
        tvmask = valid.astype(F32)
        tvmask[:, 0] = 0.0  # ‖n_i − n_i‖ = 0: the point itself adds nothing
        cnt = _rowsum(tvmask)
        hgt = _dot(d, n_i)
        res = hgt - t_i.astype(F32)[:, None]
        psi = _psi(res, ctx.sh2)
        ares = np.abs(res)
        fid = _rowsum(ares * psi * theta)
        al, w, tv = _tv(ctx, n_i, nb, tvmask)
        energy[s:e] = fid + ctx.lam * tv
        if vn:
            diff2 = np.square(n_i[:, 0:1].astype(F32) - al[0])
            diff2 += np.square(n_i[:, 1:2].astype(F32) - al[1])
            diff2 += np.square(n_i[:, 2:3].astype(F32) - al[2])
            wn = np.exp(diff2 * F32(-1.0 / (2.0 * ctx.sn2)))
            wn *= tvmask
            vnorm[s:e] = np.where(cnt > 0, _rowsum(wn) / np.maximum(cnt, 1), 1.0)
            # curvature-compensated offset: η-weighted fit h_j ≈ a + c ρ_j² (ρ_j the
            # tangential distance); a replaces τ in the position update (Notes)
            eta = _eta(res, psi, theta)
            rho2 = np.maximum(d2 - hgt * hgt, 0.0)
            s0, s1, s2 = _rowsum(eta), _rowsum(eta * rho2), _rowsum(eta * rho2 * rho2)
            b0, b1 = _rowsum(eta * hgt), _rowsum(eta * rho2 * hgt)
            det = s0 * s2 - s1 * s1
            good = det > 1e-9 * np.maximum(s0 * s2, 1e-300)
            a = np.where(good, (b0 * s2 - b1 * s1) / np.where(good, det, 1.0), t_i)
            offset[s:e] = a
            curv[s:e] = np.where(good, (s0 * b1 - s1 * b0) / np.where(good, det, 1.0),
                                 0.0)
        if not propose:
            return
        # --- τ-step (4.14): one IRLS sweep from the current τ
        eta = _eta(res, psi, theta)
        den = _rowsum(eta)
        num = _rowsum(eta * hgt)
        t_new = np.where(den > 0, num / np.where(den > 0, den, 1.0), t_i)
        res = hgt - t_new.astype(F32)[:, None]
        psi = _psi(res, ctx.sh2)
        f_new = _rowsum(np.abs(res) * psi * theta)
        keep = f_new > fid
        if keep.any():
            t_new[keep] = t_i[keep]
            res[keep] = hgt[keep] - t_i[keep].astype(F32)[:, None]
            psi[keep] = _psi(res[keep], ctx.sh2)
        new_t[s:e] = t_new
        # --- n-step: gradient of E_f (4.10), step 1/L of its IRLS majoriser
        eta = _eta(res, psi, theta)
        lip = _rowsum(eta * d2)
        eta *= res
        grad = np.stack([_rowsum(eta * d[a]) for a in range(3)], axis=1)
        gamma = np.where(lip > 0, 1.0 / np.where(lip > 0, lip, 1.0), 0.0)
        half = n_i - gamma[:, None] * grad
        # proximal step (4.11)-(4.12) on d_ij = n_i − n_j, averaged over j
        thr = w * (gamma * ctx.lam * cnt).astype(F32)[:, None]
        h32 = half.astype(F32)
        dd = [h32[:, a:a + 1] - al[a] for a in range(3)]
        if ctx.l1:  # thesis (4.12): per component, n_j + soft(d) = n_i − clip(d, ±t)
            for a in range(3):
                np.minimum(dd[a], thr, out=dd[a])
                np.maximum(dd[a], -thr, out=dd[a])
        else:  # vector soft threshold: n_j + soft(d) = n_i − d·min(1, t/‖d‖)
            ln = np.sqrt(dd[0] * dd[0] + dd[1] * dd[1] + dd[2] * dd[2])
            fac = np.minimum(thr / np.maximum(ln, F32(1e-30)), F32(1.0))
            for a in range(3):
                dd[a] *= fac
        cand = half - np.stack([_rowsum(dd[a]) for a in range(3)], axis=1) \
            / np.maximum(cnt, 1)[:, None]
        norm = np.linalg.norm(cand, axis=1)
        ok = norm > 1e-12
        new_n[s:e] = np.where(ok[:, None], cand / np.where(ok, norm, 1.0)[:, None], n_i)

    _run_chunks(kernel, n)
    return energy, new_n, new_t, (vnorm, offset, curv) if vn else None


def _pca_normals(ctx: _Ctx, k: int) -> np.ndarray:
    """Plain (unweighted) PCA normals over the first ``k`` neighbours of the rows."""
    out = np.empty((len(ctx.x), 3))  # noqa: NPY-empty -- every chunk writes its rows

    def kernel(s, e):
        nb = ctx.x[ctx.idx[s:e, :k]]
        dc = nb - nb.mean(axis=1, keepdims=True)
        cov = [np.einsum("ck,ck->c", dc[:, :, a], dc[:, :, b])
               for a, b in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))]
        out[s:e] = _smallest_eigvec(*cov)

    _run_chunks(kernel, len(ctx.x))
    return out


def _sphere_project(ctx: _Ctx, fit_n: np.ndarray):
    """Project every point of ``ctx.x`` onto an algebraic sphere fitted to its
    neighbours (positions ``ctx.x``, normals ``fit_n``), Notes "final projection".

    Weights: θ (σ_d, radius r) times the normal similarity w_ij of (4.4) between
    each neighbour's normal and the point's own, so the fit stays on one side of
    an edge.  The sphere s(x) = u₀ + uᵀx + u₄‖x‖² (x relative to p_i) fits
    positions and normals in the least-squares sense of algebraic point set
    surfaces (position and gradient terms weighted equally); p_i moves to s = 0
    by Newton steps along ∇s.  Returns ``(offset (n, 3), ok (n,))``; ``ok`` is
    False where the fit is degenerate.
    """
    n = len(ctx.x)
    off = np.zeros((n, 3))
    ok = np.zeros(n, dtype=bool)
    ft = np.ascontiguousarray(fit_n.T, dtype=F32)

    def kernel(s, e):
        d, d2, _, theta = _geometry(ctx, s, e)
        q = [-da for da in d]  # q_j = p_j − p_i
        idx = ctx.idx[s:e]
        ri = fit_n[s:e]
        nb = [np.take(ft[a], idx) for a in range(3)]
        dots = _dot(nb, ri)
        sgn = np.where(dots < 0, F32(-1.0), F32(1.0))
        nb = [nb[a] * sgn for a in range(3)]
        w = np.square((1.0 - np.abs(dots)) * F32(1.0 / (1.0 - ctx.cos_n)))
        np.negative(w, out=w)
        np.exp(w, out=w)
        w *= theta
        s0 = _rowsum(w)
        good = s0 > 0
        inv = 1.0 / np.where(good, s0, 1.0)
        mq = np.stack([_rowsum(w * q[a]) for a in range(3)], axis=1) * inv[:, None]
        mn = np.stack([_rowsum(w * nb[a]) for a in range(3)], axis=1) * inv[:, None]
        qq = _rowsum(w * d2) * inv
        qn = _rowsum(w * (q[0] * nb[0] + q[1] * nb[1] + q[2] * nb[2])) * inv
        den = qq - np.einsum("ij,ij->i", mq, mq)
        flat = den <= 1e-9 * np.maximum(qq, 1e-300)
        u4 = np.where(flat, 0.0,
                      0.5 * (qn - np.einsum("ij,ij->i", mq, mn)) / np.where(flat, 1.0, den))
        u = mn - 2.0 * u4[:, None] * mq
        u0 = -np.einsum("ij,ij->i", u, mq) - u4 * qq
        x = np.zeros((e - s, 3))
        for _ in range(PROJ_STEPS):
            g = u + 2.0 * u4[:, None] * x
            f = u0 + np.einsum("ij,ij->i", u, x) + u4 * np.einsum("ij,ij->i", x, x)
            g2 = np.einsum("ij,ij->i", g, g)
            x -= (f / np.where(g2 > 1e-24, g2, np.inf))[:, None] * g
        good &= np.isfinite(x).all(axis=1)
        off[s:e] = np.where(good[:, None], x, 0.0)
        ok[s:e] = good

    _run_chunks(kernel, n)
    return off, ok


def _smooth_curvature(ctx: _Ctx, normals: np.ndarray, curv: np.ndarray) -> np.ndarray:
    """θ-weighted mean over N_g(p_i) of the curvatures c_j of the fits
    h ≈ a + cρ², each sign-aligned to n_i (c flips with the normal's sign)."""
    out = np.empty(len(curv))

    def kernel(s, e):
        _, _, _, theta = _geometry(ctx, s, e)
        idx = ctx.idx[s:e]
        sgn = np.einsum("ij,ikj->ik", normals[s:e], normals[idx]) < 0
        c = np.where(sgn, -curv[idx], curv[idx])
        out[s:e] = (theta * c).sum(axis=1) / np.maximum(theta.sum(axis=1), 1e-300)

    _run_chunks(kernel, len(curv))
    return out


def _edge_correct(ctx: _Ctx, normals: np.ndarray, edge: np.ndarray, rho: float,
                  delta: float) -> int:
    """Edge-point correction (4.18)-(4.19), in place on ``ctx.x``.

    For every edge point, the nearest neighbour whose normal differs by more
    than σ_n gives the plane (p_j, n_j); d = n_jᵀ(p_i − p_j) and, if
    δ < |d| < ρ, p_i ← p_i − d n_j.  All edge points use the positions from
    before the correction.
    """
    rows = np.flatnonzero(edge)
    if rows.size == 0:
        return 0
    moved = np.zeros(len(rows), dtype=bool)
    shift = np.zeros((len(rows), 3))
    for s in range(0, len(rows), CHUNK):
        r = rows[s:s + CHUNK]
        idx = ctx.idx[r, 1:]
        d = ctx.x[r, None, :] - ctx.x[idx]
        d2 = np.einsum("ckd,ckd->ck", d, d)
        nbn = normals[idx]
        c = np.abs(np.einsum("ckd,cd->ck", nbn, normals[r]))
        other = (c < ctx.cos_n) & (d2 <= ctx.r2)
        has = other.any(axis=1)
        jpos = np.argmin(np.where(other, d2, np.inf), axis=1)
        sel = np.arange(len(r))
        nj = nbn[sel, jpos]
        dproj = np.einsum("cd,cd->c", d[sel, jpos], nj)
        move = has & (np.abs(dproj) > delta) & (np.abs(dproj) < rho)
        moved[s:s + CHUNK] = move
        shift[s:s + CHUNK] = np.where(move[:, None], dproj[:, None] * nj, 0.0)
    ctx.x[rows] -= shift
    return int(moved.sum())


# ---------------------------------------------------------------------------
# public API

def _prepare(points, normals, p: dict, func: str):
    """Validate data, centre, scale to units of h, and build the neighbour array."""
    k_max = p["k_max"]
    x = as_points(points, func=func, min_points=SPACING_K + 1)
    nrm = None if normals is None else as_normals(normals, len(x), func=func)
    check_spread(x, func=func)
    k = min(max(k_max, SPACING_K + 1), len(x))
    x, centre = centered(x)
    tree = build_tree(x)
    # work in the tree's leaf order: neighbours then sit close in memory, which
    # makes the gathers of every pass cache-friendly
    perm = np.asarray(tree.indices, dtype=np.int64)
    x = x[perm]
    del tree
    tree = build_tree(x)
    itype = np.int32 if len(x) < 2**31 else np.int64
    idx = np.empty((len(x), k), dtype=itype)  # noqa: NPY-empty -- filled by chunks
    dsum = 0.0
    for s in range(0, len(x), QUERY_CHUNK):  # chunked: float64 distances stay small
        dist, ii = tree.query(x[s:s + QUERY_CHUNK], k=k, workers=-1)
        idx[s:s + QUERY_CHUNK] = ii
        dsum += float(dist[:, 1:SPACING_K + 1].sum())
    del tree, dist, ii
    h = dsum / (len(x) * SPACING_K)
    if not np.isfinite(h) or h <= 0.0:
        raise PointCloudError(
            f"{func}: every point coincides with its neighbours (h = 0)")
    if nrm is not None:
        nrm = nrm[perm]
    return x / h, nrm, centre, h, idx, perm


def _context(x, idx, p: dict) -> _Ctx:
    r = RADIUS_FACTOR * p["sigma_d"] if p["radius"] is None else p["radius"]
    sig_n = np.deg2rad(p["sigma_n_deg"])
    return _Ctx(x=x, idx=idx, r2=r * r, sd2=p["sigma_d"] ** 2, sh2=p["sigma_h"] ** 2,
                lam=p["lambda_tv"], cos_n=float(np.cos(sig_n)), sn2=float(sig_n ** 2),
                l1=p["tv_norm"] == "l1")


@validate_params(*PARAMS)
def denoise_l1_tv(points, normals=None, *, lambda_tv: float = 0.4, sigma_h: float = 0.6,
                  sigma_d: float = 2.0, radius: float | None = None,
                  sigma_n_deg: float = 15.0, rho: float = 0.7, delta: float = 1e-4,
                  epsilon: float = 4.0, edge_threshold: float = 0.5, n_iter: int = 6,
                  curved_iter: int = 2, inner_iter: int = 2, init_iter: int = 3,
                  tol: float = 1e-3,
                  edge_correction: bool = False, curvature_offset: bool = True,
                  tv_norm: str = "l2", k_max: int = 32,
                  final_projection: bool = True,
                  seed: int | None = None) -> DenoiseResult:
    """Denoise a point cloud, preserving sharp edges (thesis ch. 4, Algorithm 4.1).

    Parameters
    ----------
    points : (n, 3) float
        Noisy positions.
    normals : (n, 3) float, optional
        Only an orientation hint: output normals are flipped to agree with them.
        The filter estimates its own normals (4.9).
    lambda_tv : float, default=0.4
        λ, weight of the L1 (TV) normal term of (4.5) (thesis §4.5.1).
    sigma_h : float, default=0.6
        σ_h of the height weight ψ (4.3), in units of h (mean distance to the 6
        nearest neighbours).
    sigma_d : float, default=2.0
        σ_d of the distance weight θ (4.3), in units of h.
    radius : float, optional
        Neighbourhood radius r in units of h; None uses r = 1.5 σ_d (the thesis,
        §4.5.1, uses r = σ_d; see Notes).
    sigma_n_deg : float, default=15.0
        σ_n in degrees, for w_ij (4.4), the edge detector (4.16) and the "other
        side of the edge" test of the correction (4.18).
    rho : float, default=0.7
        ρ in units of h: edge points move at most ρh (4.19).
    delta : float, default=1e-4
        δ in units of h: edge-correction moves below δh are skipped (4.19).
    epsilon : float, default=4.0
        ε in units of h: a point whose total displacement from the input would
        exceed εh keeps its previous position (4.15).
    edge_threshold : float, default=0.5
        th: V_n < th marks an edge point (4.17); the thesis uses 0.2-0.5.
    n_iter : int, default=6
        Outer iterations j_max; the thesis uses 10, 16, 20 or 50 (§4.5.1; see
        Notes for the default).
    curved_iter : int, default=2
        Outer iterations after which points that are not edge points (V_n ≥ th)
        and lie on a curved part (sag |c|r² of the fit h ≈ a + cρ² above 0.05h)
        stop moving and keep their normal; values ≥ ``n_iter`` move every point
        in every iteration, as in the thesis.
    inner_iter : int, default=2
        Largest number of (n, τ) alternations per outer iteration.
    init_iter : int, default=3
        Passes of the reweighted eigen-iteration (4.9) that gives n⁰.
    tol : float, default=1e-3
        The inner loop stops when the RMS move ‖p^{k+1} − p^k‖ is below tol·h.
    edge_correction : bool, default=False
        Apply the edge-point correction (4.18)-(4.19) (see Notes for why it is
        off by default).
    curvature_offset : bool, default=True
        Move each point by the intercept a of the η-weighted fit
        h_j ≈ a + c ρ_j² (ρ_j: tangential distance) instead of by τ; False
        gives the thesis' (4.15).
    tv_norm : {"l2", "l1"}, default="l2"
        Norm of each normal difference in the regulariser (4.4): "l2" (isotropic
        TV, vector soft thresholding) or the thesis' component-wise "l1" (4.12),
        which depends on the coordinate frame.
    k_max : int, default=32
        Largest number of neighbours kept in N_g (the radius neighbourhood is
        truncated to the k_max nearest).
    final_projection : bool, default=True
        Finish by projecting every input point onto an algebraic sphere fitted
        to its neighbours with the filtered normals (Notes); False ends with the
        positions of the last update (4.15), as in the thesis.
    seed : int, optional
        Accepted for a uniform filter API; the filter is deterministic.

    Returns
    -------
    DenoiseResult
        ``points``, ``normals``, ``edge_mask`` (plus ``edge_score``, ``h``,
        ``energy_history``, ``n_iter_run``, ``n_corrected``).

    Raises
    ------
    PointCloudError
        Empty input, NaN/Inf, fewer than 7 points, all points coincident or
        collinear, or normals of the wrong shape.
    InvalidParameterError
        A parameter out of range or of the wrong type.

    Notes
    -----
    Thesis eqs (4.2)-(4.19), Algorithm 4.1. Choices where the text is ambiguous
    or wrong (see docs/ALGORITHMS.md §Ch.4):

    * Lengths are in units of h: the filter works on (p − c)/h, so the guard
      |h_j − τ| < 1e-3 after (4.10)/(4.14) is 1e-3·h, not an absolute 1e-3.
    * Position update (4.15) is p ← p − τn, not p + τn: τ is the weighted
      L1-median of h_j = nᵀ(p_i − p_j), the height of p_i above its plane,
      so the minus sign projects the point onto the plane.
    * Edge detector (4.16): w_n = exp(−‖n_i − n_j‖²/(2σ_n²)) with the minus
      sign the thesis omits; σ_n in radians.
    * Normals are unoriented inside the filter: each neighbour's normal is
      aligned to the centre's sign (n_j ← sign(n_iᵀn_j) n_j) in (4.4), (4.12)
      and (4.16).
    * n⁰ (4.6)-(4.9): the thesis iterates with τ = 0, i.e. the covariance about
      the noisy p_i itself, whose own noise then tilts the normal (measured: the
      iteration made n⁰ worse pass after pass). Here pass 1 is θ-weighted PCA
      about the weighted mean (ω = θ), later passes use the covariance about
      p_i − τ_i n_i with τ_i from (4.14), i.e. (4.9) with the offset of (4.5).
      Near edges the eigen-iteration converges to the blended normal (a
      stationary point of (4.3)), so after pass 1 every point also tries the
      normals of 8 neighbours spread over its list and keeps the one with the
      lowest robust loss Σ_j θ(1 − ψ) (τ by (4.14) from 0). (4.3) itself is not
      usable for that choice: |r|ψ(r) redescends to 0, so (4.3) is smallest for
      a plane that misses every neighbour.
    * Inner loop at fixed positions: each pass takes the IRLS τ step (4.14)
      (one sweep) at the current normals, then one proximal-gradient normal
      step (4.10)-(4.12) at the new τ. Step size γ = 1/trace(Σ_j η_j
      (p_i − p_j)(p_i − p_j)ᵀ), the curvature bound of the IRLS majoriser of
      E_f. The proximal map of λΣ_j w_ij‖n_i − n_j‖₁ is approximated by the
      proximal average: each d_ij = n_i − n_j is soft-thresholded (4.12) at
      γλK_i w_ij (K_i = number of neighbours, which keeps the fixed point of
      the summed regulariser) and n_i is rebuilt as the mean of
      n_j + soft(d_ij), then renormalised.
    * Descent: the τ step keeps a point's previous τ when its fidelity would
      rise; a pass whose proposal raised the total energy (4.5) is undone and
      ends the inner loop (parallel updates of the coupled TV terms can do
      that). Hence ``energy_history`` never increases within an outer
      iteration. The loop also ends when the RMS change of the tentative
      positions p − τn is below tol·h (the thesis' ‖p^{k+1} − p^k‖² < ε); the
      move (4.15) is applied once, after the inner loop; τ restarts at 0 in
      every outer iteration.
    * One k-NN query (k_max neighbours of the noisy input) serves every
      iteration; the radius test d ≤ r and all weights use the current
      positions. Points move by well under r, so the lists stay valid; a
      re-query per iteration would cost ~6-12 s per pass at 1M points.
      Neighbour arrays are float32 (in units of h, so ~1e-5 h resolution for
      clouds up to ~10⁶ points); per-point state and sums are float64.
    * Shrinkage: τ, the L1-median of the heights, sits ≈ r²/(4R) below a
      surface of curvature radius R, so (4.15) flattens curved parts a little
      in every outer iteration (measured on the rocker arm at 6000 points: SNR
      35.9 dB, below the noisy input). With ``curvature_offset`` (default) the
      move uses the intercept a of an η-weighted least-squares fit
      h_j ≈ a + cρ_j² at the final (n, τ) of the inner loop (same robust
      weights as (4.14)); on a plane a ≈ τ. n and τ are still the minimisers of
      (4.5); only the length of the move changes.
    * Regulariser norm: (4.4) sums the component-wise ℓ1 norm of n_i − n_j, and
      (4.12) soft-thresholds each component. That depends on the coordinate
      axes, so the output would change when the cloud is rotated. The default
      ``tv_norm="l2"`` uses ‖n_i − n_j‖₂ (still ℓ1 over the pairs, so sparse
      normal jumps survive) and the vector soft threshold; "l1" keeps the
      thesis' form.
    * Defaults: n_iter = 6, below the thesis' smallest count (10, §4.5.1). On
      curved parts every outer iteration adds a little drift (rocker arm, 6000
      points: RMS distance to the surface 0.160h after 1 iteration, 0.176h
      after 4, 0.242h after 14), while on CAD parts MAD keeps improving slowly.
      With the scales and the per-point stopping below, 4 / 6 / 8 / 10 / 15 /
      20 iterations gave mean MAD 8.28 / 8.27 / 8.29 / 8.32 / 8.39 / 8.46° and
      SNR 42.3 / 42.2 / 42.1 / 41.9 / 41.7 / 41.5 dB on 10 cases (the same
      trend on 15 others); 6 keeps most of the CAD gain (cube 0.3h: 6.04°
      against 5.90° at 10) and costs 40 % less.
      ``edge_correction`` is off by default: snapping edge points onto the
      plane across the edge lowered the SNR on every model measured (cube
      0.3h: 43.6 → 42.6 dB, fandisk random 0.3h: 38.4 → 37.8 dB, rocker arm
      0.2h: 38.6 → 37.2 dB), because points within ρh of an edge end up on the
      edge line and leave a gap beside it; it is implemented as printed and
      reachable with ``edge_correction=True``.
    * Default scales: σ_d = 2h with r = 1.5σ_d = 3h (thesis §4.5.1: r = σ_d;
      the earlier default here was σ_d = r = 3h), σ_h = 0.6h, λ = 0.4. A
      narrower θ inside the same 3h support (same ≤ 32 neighbours, same cost)
      lowers the bias of the plane fit on curved and finely sampled parts:
      on the bunny at 6000 points even clean-data PCA normals are 7.7° off
      with 16 neighbours and 10.1° with 32. Measured with ``curved_iter`` on
      10 cases (5 curved/CAD models, normal 0.2h/0.3h, random 0.3h): mean
      MAD 8.81 → 8.32°, MAD of re-estimated PCA normals 9.93 → 9.76°, SNR
      41.3 → 41.9 dB; on 15 other cases (0.1h, impulsive, non-uniform):
      8.68 → 8.20°, 41.2 → 41.8 dB. The defaults are global, never chosen
      per model.
    * Per-point stopping (``curved_iter``, default 2): the thesis moves every
      point in all j_max outer iterations. On flat faces and at edges repeated
      projection keeps helping (cube, normal 0.3h: SNR 41.0 dB after 1
      iteration, 43.8 after 10), but on curved parts each iteration adds
      shrinkage and TV faceting (bunny, normal 0.2h: mean signed distance to
      the surface −0.03h after 1 iteration, −0.12h after 10; SNR 43.5 → 39.2
      dB). From iteration ``curved_iter`` + 1 on, a point that is not an edge
      point and whose fit h ≈ a + cρ² sags by more than 0.05h over the radius
      (|c|r² > 0.05, a data-driven test, no ground truth) is frozen: it keeps
      its position and its normal of that iteration, while still serving as a
      neighbour. Sag and sign-aligned curvature are θ-averaged over N_g(p_i)
      first (single-point fits are too noisy: a plane lost 0.06 of its noise
      reduction). Measured with the former scales σ_d = r = 3h and 10
      iterations on 10 cases (6000 points): bunny 0.2h 39.2 → 41.5
      dB, rocker arm 0.2h 39.6 → 41.2 dB, mean SNR 40.5 → 41.3 dB, mean MAD
      8.94 → 8.85°; cube 0.3h loses 0.6 dB (43.8 → 43.2). Tried and dropped:
      a full robust quadric fit a + bᵀu + uᵀCu for the move and/or the normal
      (6 parameters from ≤ 32 noisy neighbours: noisier, mean SNR 38.4-39.9
      dB, MAD up to 11°); restoring the tangential part of the input
      displacement (no change: the drift is along the normal); freezing all
      non-edge points (cube 0.3h −3 dB).
    * Final projection (``final_projection``, default on; not in the thesis):
      after the outer iterations each *input* point is projected once onto an
      algebraic sphere s(x) = u₀ + uᵀx + u₄‖x‖² fitted to its input neighbours
      (within r, weights θ times the normal similarity w_ij of (4.4), so the fit
      stays on one side of an edge) with the closed-form position + normal fit
      of algebraic point set surfaces; 3 Newton steps along ∇s. The neighbour
      normals of the fit are the filter's L1-TV normals, except on the points
      frozen as curved (``curved_iter``), where plain 16-NN PCA normals are
      used (the piecewise-constant TV normals bias a sphere on smooth curved
      parts). The output normals stay the L1-TV normals. Moves beyond ε or
      degenerate fits keep the iterated position. Measured on all 64 benchmark
      cases (6000 points): mean SNR 42.24 → 43.33 dB (every model gains
      0.8-1.5 dB; cube 43.9 → 44.7, bunny 41.5 → 42.5), MAD of re-estimated
      PCA normals 9.24 → 8.91°, own-normal MAD unchanged; ~10 % more time.
      Tried and dropped (means over cube, fandisk, trim-star, rocker arm,
      bunny, 8 conditions each): the sphere's gradient as output normal on the
      frozen points (bunny 9.98 → 9.70°, rocker arm 9.24 → 9.09°, but cube
      4.44 → 4.62°, trim-star 8.88 → 9.34°); the exact MLS gradient (with the
      derivative of the weights, as MeshLab's APSS "accurate normal") of a
      PCA-seeded sphere with compact weights (1 − d²/r²)⁴: applied to every
      point it reaches 7.5° on the bunny and 7.9° on the rocker arm (normal
      0.2h), level with the tuned APSS/RIMLS, but it is 6.4° against 3.0° for
      the L1-TV normals on the cube's faces, and no per-point selector tried
      (V_n, frozen set, sphere sag, angle between the two normals) kept the CAD
      gains: overall MAD 8.07 → 8.11-9.32°; PCA normals in the fit on all
      non-edge points (cube MAD 6.2°); wider fits (k = 64, σ = 3-4h: SNR −0.7
      to −1.5 dB on the curved models); projecting the iterated positions
      instead of the input (SNR −0.5 dB); iterating the projection (no gain).
    * Edge correction (4.18)-(4.19): the "opposite surface" point is the nearest
      neighbour whose normal differs from n_i by more than σ_n; all edge points
      are corrected from the same (pre-correction) positions.

    References
    ----------
    E. A. Leal Narváez, *Sparse Representation-Based Algorithms for
    Pre-Processing Point Clouds*, PhD thesis, 2020, ch. 4.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.random.default_rng(0)
    >>> xy = g.uniform(-1, 1, (2000, 2))
    >>> noisy = np.c_[xy, 0.01 * g.normal(size=2000)]
    >>> out = denoise_l1_tv(noisy, n_iter=5)
    >>> bool(np.abs(out.points[:, 2]).mean() < np.abs(noisy[:, 2]).mean())
    True
    """
    func = "denoise_l1_tv"
    p = dict(
        lambda_tv=lambda_tv, sigma_h=sigma_h, sigma_d=sigma_d, radius=radius,
        sigma_n_deg=sigma_n_deg, rho=rho, delta=delta, epsilon=epsilon,
        edge_threshold=edge_threshold, n_iter=n_iter, curved_iter=curved_iter,
        inner_iter=inner_iter,
        init_iter=init_iter, tol=tol, edge_correction=edge_correction,
        curvature_offset=curvature_offset, tv_norm=tv_norm,
        k_max=k_max, final_projection=final_projection, seed=seed)
    x, hint, centre, h, idx, perm = _prepare(points, normals, p, func)
    n = len(x)
    x0 = x.copy()
    ctx = _context(x, idx, p)
    ctx.refresh()
    log.info("%s: n=%d h=%.4g k_max=%d", func, n, h, idx.shape[1])

    nrm = _init_normals(ctx, p["init_iter"], N_CAND)
    history = []
    vn = np.ones(n)
    n_corr = 0
    eps2 = p["epsilon"] ** 2
    frozen = np.zeros(n, dtype=bool)
    frozen_n = np.zeros((n, 3))
    for j in range(p["n_iter"]):
        nrm, tau, (vn, off, curv), hist_j = _inner_loop(ctx, nrm, p["inner_iter"],
                                                         p["tol"])
        history.append(hist_j)
        # position update (4.15), sign corrected, bounded by ε
        shift = off if p["curvature_offset"] else tau
        cand = ctx.x - shift[:, None] * nrm
        far = np.square(cand - x0).sum(axis=1) > eps2
        cand[far] = ctx.x[far]
        if j >= p["curved_iter"]:
            # curved, non-edge points stop after curved_iter iterations (Notes)
            sag = np.abs(_smooth_curvature(ctx, nrm, curv)) * ctx.r2
            new = ~frozen & (vn >= p["edge_threshold"]) & (sag > CURVED_SAG)
            frozen_n[new] = nrm[new]
            frozen |= new
            cand[frozen] = ctx.x[frozen]
        ctx.x[:] = cand
        edge = vn < p["edge_threshold"]
        if p["edge_correction"]:
            n_corr = _edge_correct(ctx, nrm, edge, p["rho"], p["delta"])
        ctx.refresh()
        log.info("%s: iteration %d/%d energy %.6g, %d edge points, %d corrected",
                 func, j + 1, p["n_iter"], hist_j[-1], int(edge.sum()), n_corr)

    inv = np.empty(n, dtype=np.int64)  # noqa: NPY-empty -- a permutation fills it
    inv[perm] = np.arange(n)
    if frozen.any():  # frozen points keep the normal of their last move
        same = np.einsum("ij,ij->i", frozen_n, nrm) >= 0
        nrm = np.where(frozen[:, None], np.where(same[:, None], frozen_n, -frozen_n), nrm)
    if p["final_projection"]:
        # final projection of the input points onto algebraic spheres (Notes)
        cin = _context(x0, idx, p)
        cin.refresh()
        fit_n = nrm
        if frozen.any():  # curved parts: plain PCA normals seed the fit
            pca = _pca_normals(cin, min(FIT_PCA_K, idx.shape[1]))
            fit_n = np.where(frozen[:, None], pca, nrm)
        off, ok = _sphere_project(cin, fit_n)
        ok &= np.square(off).sum(axis=1) <= eps2
        if p["edge_correction"]:  # corrected edge points keep (4.18)-(4.19)
            ok &= vn >= p["edge_threshold"]
        ctx.x[ok] = x0[ok] + off[ok]
    if normals is None:
        k = min(MST_K, idx.shape[1] - 1)
        nrm = orient_normals_mst(ctx.x, nrm, k=k, neighbors=idx[:, 1:k + 1])
    out_n = nrm[inv]
    out_p = ctx.x[inv] * h + centre
    if normals is not None:
        hint = as_normals(normals, n, func=func)
        flip = np.einsum("ij,ij->i", out_n, hint) < 0
        out_n[flip] *= -1.0
    vn = vn[inv]
    edge = vn < p["edge_threshold"]
    return DenoiseResult(points=out_p, normals=out_n, edge_mask=edge, edge_score=vn,
                         h=h, energy_history=tuple(history), n_iter_run=p["n_iter"],
                         n_corrected=n_corr)


def _inner_loop(ctx: _Ctx, nrm: np.ndarray, inner_iter: int, tol: float):
    """Alternate τ and n steps at fixed positions (Algorithm 4.1, inner loop).

    τ starts at 0. Every pass returns the energy of the current state and a
    proposal; a proposal that raised the total energy (4.5) is undone and ends
    the loop. The loop also ends when the RMS change of the tentative positions
    p − τn falls below ``tol``. Returns normals, τ, V_n and the energy history.
    """
    n = len(ctx.x)
    tau = np.zeros(n)
    hist = []
    prev = None
    for k in range(inner_iter + 1):
        last = k == inner_iter
        e_i, n_next, t_next, vn = _inner_pass(ctx, nrm, tau, propose=not last, vn=last)
        e_tot = float(e_i.sum())
        if hist and e_tot > hist[-1]:
            nrm, tau = prev  # the parallel step raised (4.5): undo it and stop
            _, _, _, vn = _inner_pass(ctx, nrm, tau, propose=False, vn=True)
            break
        hist.append(e_tot)
        if last:
            break
        step = (ctx.x - t_next[:, None] * n_next) - (ctx.x - tau[:, None] * nrm)
        move = float(np.sqrt(np.mean(np.square(step).sum(axis=1))))
        prev = (nrm, tau)
        nrm, tau = n_next, t_next
        if move < tol:
            e_i, _, _, vn = _inner_pass(ctx, nrm, tau, propose=False, vn=True)
            e_tot = float(e_i.sum())
            if e_tot > hist[-1]:
                nrm, tau = prev
                _, _, _, vn = _inner_pass(ctx, nrm, tau, propose=False, vn=True)
            else:
                hist.append(e_tot)
            break
    return nrm, tau, vn, tuple(hist)


def energy_l1_tv(points, normals, tau=None, *, lambda_tv: float = 0.4,
                 sigma_h: float = 0.6, sigma_d: float = 2.0, radius: float | None = None,
                 sigma_n_deg: float = 15.0, k_max: int = 32) -> float:
    """The energy (4.5) summed over all points, lengths in units of h.

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float
        Unit normals (their signs do not matter: neighbours are sign-aligned).
    tau : (n,) float, optional
        Offsets τ_i in units of h; default 0.
    lambda_tv, sigma_h, sigma_d, radius, sigma_n_deg, k_max
        As in :func:`denoise_l1_tv`.

    Returns
    -------
    float
        Σ_i [Σ_j |h_ij − τ_i| ψ θ + λ Σ_{j≠i} w_ij ‖n_i − n_j‖₁].
    """
    func = "energy_l1_tv"
    full = {q.name: q.default for q in denoise_l1_tv.params}
    full.update(lambda_tv=lambda_tv, sigma_h=sigma_h, sigma_d=sigma_d, radius=radius,
                sigma_n_deg=sigma_n_deg, k_max=k_max)
    p = resolve_params(denoise_l1_tv.params, full, func)
    if normals is None:
        raise InvalidParameterError(f"{func}: normals must be given")
    x, nrm, _, _, idx, perm = _prepare(points, normals, p, func)
    t = np.zeros(len(x)) if tau is None else \
        np.asarray(tau, dtype=np.float64).reshape(len(x))
    t = t[perm]
    ctx = _context(x, idx, p)
    ctx.refresh()
    e_i, _, _, _ = _inner_pass(ctx, nrm, t, propose=False)
    return float(e_i.sum())
