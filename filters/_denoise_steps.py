"""
_denoise_steps.py
-----------------
The steps of Algorithm 4.1 for :func:`pcprep.filters.denoise.denoise_l1_tv`,
each a pass over all points at fixed positions: the initial normals n⁰ (4.9),
one inner pass (energy (4.5), τ step (4.14), normal step (4.10)-(4.12), normal
variation (4.17)), the inner loop, and the edge correction (4.18)-(4.19).
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np

from . import _denoise_jit, _kernels
from ._denoise_kernels import (CHUNK, COMPILED_CHUNK, WORK, _Ctx, _dot, _eta, _geometry,
                               _psi, _rowsum, _run_chunks, _smallest_eigvec, _tau_irls,
                               _tv)

#: init passes followed by the candidate selection
SELECT_PASSES = 1

_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


# ---------------------------------------------------------------------------
# n⁰ (4.6)-(4.9)

def _init_normals(ctx: _Ctx, init_iter: int, n_cand: int,
                  printed: bool = False) -> np.ndarray:
    """n⁰ by the reweighted eigen-iteration (4.9), with the offset τ of (4.5).

    Pass 1 is θ-weighted PCA (ω = θ, n = 0).  Then every point takes, among its
    own normal and those of ``n_cand`` neighbours spread over its list, the one
    of lowest robust loss Σ_j θ(1 − ψ) (τ by (4.14) for each candidate).  Later
    passes take the smallest eigenvector of Σ_j ω_j (c_i − p_j)(c_i − p_j)ᵀ with
    c_i = p_i − τ_i n_i and ω = ψθ/|h_j − τ_i| (θ where |h_j − τ_i| < GUARD).

    ``printed``: (4.9) as the thesis prints it, τ = 0 throughout: every pass
    takes the smallest eigenvector of Σ_j ω_j (p_i − p_j)(p_i − p_j)ᵀ about p_i
    itself, pass 1 with ω = θ (Cm(0), n⁰ = 0), later passes with
    ω = ψθ/|h_j| (θ where |h_j| < GUARD); no candidate search (``n_cand`` is
    ignored).  NumPy passes only.
    """
    n = len(ctx.x)
    normals = np.zeros((n, 3))
    tau = np.zeros(n)
    k = ctx.idx.shape[1]
    n_cand = 0 if printed else n_cand
    cols = np.unique(np.linspace(1, k - 1, min(n_cand, k - 1)).round().astype(int))
    compiled = _denoise_jit.eigen_rows if _kernels.ENABLED and not printed else None
    for it in range(init_iter):
        new, tau = _rows_pass(ctx, compiled,
                              partial(_eigen_pass, ctx, normals, tau, first=it == 0,
                                      printed=printed),
                              normals, tau, it == 0)
        if it > 0:  # keep each normal's sign from pass to pass
            flip = np.einsum("ij,ij->i", new, normals) < 0
            new[flip] *= -1.0
        normals = new
        if n_cand > 0 and it < SELECT_PASSES:
            normals, tau = _rows_pass(
                ctx, _denoise_jit.select_rows if _kernels.ENABLED else None,
                partial(_select_candidates, ctx, normals, cols), normals, cols)
    return normals


def _rows_pass(ctx: _Ctx, compiled, reference, normals, arg, *extra):
    """(normals, τ) of a pass over all rows: the compiled row kernel
    ``compiled(x, idx, normals, arg, ..., s, e, r2, sd2, sh2, ..., out_n, out_t)``
    when given, else the NumPy ``reference(s, e)`` per chunk."""
    n = len(ctx.x)
    if compiled is None:
        parts = _run_chunks(reference, n)
        return (np.concatenate([q[0] for q in parts], axis=0),
                np.concatenate([q[1] for q in parts]))
    out_n = np.empty((n, 3))  # noqa: NPY-empty -- every chunk writes its rows
    out_t = np.empty(n)  # noqa: NPY-empty -- every chunk writes its rows
    nrm = np.ascontiguousarray(normals, dtype=np.float64)
    _run_chunks(lambda s, e: compiled(ctx.x, ctx.idx, nrm, arg, s, e, ctx.r2, ctx.sd2,
                                      ctx.sh2, *extra, out_n, out_t), n, COMPILED_CHUNK)
    return out_n, out_t


def _eigen_pass(ctx: _Ctx, normals, tau, s: int, e: int, first: bool,
                printed: bool = False):
    """One pass of (4.9) on rows s:e: (normals, τ); ``printed``: about p_i, τ = 0."""
    d, _, _, theta = _geometry(ctx, s, e)
    if printed:
        if first:
            om = theta
        else:
            hgt = _dot(d, normals[s:e])
            om = _eta(hgt, _psi(hgt, ctx.sh2), theta)
        dc = d
        t_new = np.zeros(e - s)
    elif first:
        wsum = theta.sum(axis=1, keepdims=True)
        om = theta / wsum
        dc = [da - _rowsum(om * da)[:, None].astype(WORK) for da in d]
        t_new = np.zeros(e - s)
    else:
        n_i = normals[s:e]
        hgt = _dot(d, n_i)
        t_new = _tau_irls(hgt, tau[s:e], theta, ctx.sh2)
        res = hgt - t_new.astype(WORK)[:, None]
        om = _eta(res, _psi(res, ctx.sh2), theta)
        dc = [d[a] - (t_new * n_i[:, a]).astype(WORK)[:, None] for a in range(3)]
    wd = [om * dc[a] for a in range(3)]
    cov = [_rowsum(wd[a] * dc[b]) for a, b in _UPPER]
    return _smallest_eigvec(*cov), t_new


def _select_candidates(ctx: _Ctx, normals, cols, s: int, e: int):
    """Rows s:e keep, of their own normal and those of the neighbours ``cols``,
    the one of lowest Welsch loss Σ θ(1 − ψ): (normals, τ)."""
    d, _, valid, theta = _geometry(ctx, s, e)
    cand = np.concatenate([normals[s:e, None, :], normals[ctx.idx[s:e][:, cols]]], axis=1)
    ok = np.concatenate([np.ones((e - s, 1), bool), valid[:, cols]], axis=1)
    c32 = cand.astype(WORK)
    hgt = (d[0][:, None, :] * c32[:, :, 0:1] + d[1][:, None, :] * c32[:, :, 1:2]
           + d[2][:, None, :] * c32[:, :, 2:3])
    th = theta[:, None, :]
    # τ from 0, as in Algorithm 4.1: the search favours planes near p_i
    t = _tau_irls(hgt, np.zeros(hgt.shape[:2], WORK), th, ctx.sh2).astype(WORK)
    res = hgt - t[..., None]
    # (4.3) itself redescends to 0 and would prefer a plane that misses every neighbour
    loss = ((1.0 - _psi(res, ctx.sh2)) * th).sum(axis=2, dtype=np.float64)
    loss[~ok] = np.inf
    best = np.argmin(loss, axis=1)
    rows = np.arange(e - s)
    return cand[rows, best], t[rows, best].astype(np.float64)


# ---------------------------------------------------------------------------
# the inner loop

class PlannedDecisions:
    """The cloud-wide decisions of the inner loop in one tile of a tiled run.

    The inner loop decides twice from sums over every point of the cloud (did
    the total energy (4.5) rise; is the RMS move below ``tol``), which one tile
    cannot know.  A tiled run therefore fixes the outcomes in advance
    (``plan``, one bool per decision in the order they arise) and, past the
    plan's end, takes each from the tile's own core rows, which on a tile of
    many points nearly always answer as the whole cloud does.  Every tile
    records the sums over its core rows that the decision read (``trace``:
    ``(kind, a, b, outcome)``).  Added over the tiles the sums are the whole
    cloud's; the caller replays the decisions with them, and where one disagrees
    with a tile's outcome it runs again with the plan corrected up to there
    (see meshlab_bridge/tiles.py).  ``None`` in place of this object: the
    decisions are taken from the cloud itself, as in a one-piece run."""

    def __init__(self, core: np.ndarray, plan=()):
        self.core = np.asarray(core, dtype=bool)
        self.plan = tuple(bool(b) for b in plan)
        self.trace = []

    def decide(self, kind: str, a: float, b: float, local: bool) -> bool:
        """The plan's outcome of this decision, or past its end ``local`` (the
        test on the core rows' sums ``a``, ``b``)."""
        i = len(self.trace)
        out = self.plan[i] if i < len(self.plan) else bool(local)
        self.trace.append((kind, a, b, out))
        return out


def _total(e_i: np.ndarray, sync) -> float:
    return float(e_i.sum()) if sync is None else float(e_i[sync.core].sum())


def _rose(e_tot: float, before: float, sync) -> bool:
    """Did the total energy rise (the whole cloud's, or the plan's answer)."""
    if sync is None:
        return e_tot > before
    return sync.decide("rise", e_tot, before, e_tot > before)


def _move_sq(ctx: _Ctx, n_new, t_new, n_old, t_old) -> np.ndarray:
    """|(p − τ'n') − (p − τn)|² per point: the squared move of the tentative
    positions between two states (one compiled pass, or NumPy)."""
    if _kernels.ENABLED:
        out = np.empty(len(ctx.x))  # noqa: NPY-empty -- every row written
        _denoise_jit.move_sq(ctx.x, t_new, n_new, t_old, n_old, out)
        return out
    step = (ctx.x - t_new[:, None] * n_new) - (ctx.x - t_old[:, None] * n_old)
    return np.square(step).sum(axis=1)


def _settled(sq: np.ndarray, tol: float, sync) -> bool:
    """Is the RMS of the squared moves ``sq`` below ``tol``."""
    if sync is None:
        return float(np.sqrt(np.mean(sq))) < tol
    a = float(sq[sync.core].sum())
    return sync.decide("move", a, 0.0, math.sqrt(a / max(1, int(sync.core.sum()))) < tol)


def _inner_loop(ctx: _Ctx, nrm: np.ndarray, inner_iter: int, tol: float, sync=None):
    """Alternate τ and n steps at fixed positions (Algorithm 4.1, inner loop).

    τ starts at 0. Every pass returns the energy of the current state and a
    proposal; a proposal that raised the total energy (4.5) is undone and ends
    the loop. The loop also ends when the RMS change of the tentative positions
    p − τn falls below ``tol``. Returns normals, τ, (V_n, a, c) and the energy
    history.  ``sync`` (a :class:`PlannedDecisions`) takes the two cloud-wide
    decisions for one tile of a tiled run.
    """
    n = len(ctx.x)
    tau = np.zeros(n)
    hist = []
    prev = None
    for k in range(inner_iter + 1):
        last = k == inner_iter
        e_i, n_next, t_next, vn = _inner_pass(ctx, nrm, tau, propose=not last, vn=last)
        e_tot = _total(e_i, sync)
        if hist and _rose(e_tot, hist[-1], sync):
            nrm, tau = prev  # the parallel step raised (4.5): undo it and stop
            _, _, _, vn = _inner_pass(ctx, nrm, tau, propose=False, vn=True)
            break
        hist.append(e_tot)
        if last:
            break
        sq = _move_sq(ctx, n_next, t_next, nrm, tau)
        prev = (nrm, tau)
        nrm, tau = n_next, t_next
        if _settled(sq, tol, sync):
            e_i, _, _, vn = _inner_pass(ctx, nrm, tau, propose=False, vn=True)
            e_tot = _total(e_i, sync)
            if _rose(e_tot, hist[-1], sync):
                nrm, tau = prev
                _, _, _, vn = _inner_pass(ctx, nrm, tau, propose=False, vn=True)
            else:
                hist.append(e_tot)
            break
    return nrm, tau, vn, tuple(hist)


def _inner_pass(ctx: _Ctx, normals: np.ndarray, tau: np.ndarray, propose: bool,
                vn: bool = False):
    """One pass over all points at fixed positions.

    Returns the per-point energy (4.5) of the current state ``(normals, tau)``;
    when ``propose`` also the next state: the IRLS τ step (4.14) at the current
    normals (kept per point only if it lowers the point's fidelity), then one
    proximal-gradient normal step (4.10)-(4.12) at the new τ.  With ``vn`` also
    the normal variation V_n (4.17) and the intercept a and curvature c of the
    height fit h ≈ a + cρ².
    """
    n = len(ctx.x)
    energy = np.zeros(n)
    new_n = np.zeros((n, 3)) if propose else None
    new_t = np.zeros(n) if propose else None
    vnorm = np.zeros(n) if vn else None
    offset = np.zeros(n) if vn else None
    curv = np.zeros(n) if vn else None
    if _kernels.ENABLED:
        nrm = np.ascontiguousarray(normals, dtype=np.float64)
        t0 = np.ascontiguousarray(tau, dtype=np.float64)
        none1, none3 = np.zeros(0), np.zeros((0, 3))
        _run_chunks(lambda s, e: _denoise_jit.inner_rows(
            ctx.x, ctx.idx, nrm, t0, s, e, ctx.r2, ctx.sd2, ctx.sh2, ctx.lam, ctx.cos_n,
            ctx.sn2, ctx.l1, propose, vn, energy, none3 if new_n is None else new_n,
            none1 if new_t is None else new_t, none1 if vnorm is None else vnorm,
            none1 if offset is None else offset, none1 if curv is None else curv), n,
            COMPILED_CHUNK)
        return energy, new_n, new_t, (vnorm, offset, curv) if vn else None
    nt = np.ascontiguousarray(normals.T, dtype=WORK)

    def kernel(s, e):
        d, d2, valid, theta = _geometry(ctx, s, e)
        idx = ctx.idx[s:e]
        n_i = normals[s:e]
        t_i = tau[s:e]
        nb = [np.take(nt[a], idx) for a in range(3)]
        tvmask = valid.astype(WORK)
        tvmask[:, 0] = 0.0  # ‖n_i − n_i‖ = 0: the point itself adds nothing
        cnt = _rowsum(tvmask)
        hgt = _dot(d, n_i)
        res = hgt - t_i.astype(WORK)[:, None]
        psi = _psi(res, ctx.sh2)
        ares = np.abs(res)
        fid = _rowsum(ares * psi * theta)
        al, w, tv = _tv(ctx, n_i, nb, tvmask)
        energy[s:e] = fid + ctx.lam * tv
        if vn:
            vnorm[s:e] = _variation(n_i, al, tvmask, cnt, ctx.sn2)
            offset[s:e], curv[s:e] = _height_fit(res, psi, theta, d2, hgt, t_i)
        if not propose:
            return
        t_new, res, psi = _tau_step(hgt, res, psi, theta, fid, t_i, ctx.sh2)
        new_t[s:e] = t_new
        new_n[s:e] = _normal_step(ctx, n_i, d, d2, res, psi, theta, al, w, cnt)

    _run_chunks(kernel, n)
    return energy, new_n, new_t, (vnorm, offset, curv) if vn else None


def _variation(n_i, al, tvmask, cnt, sn2: float) -> np.ndarray:
    """V_n (4.17): mean of exp(−‖n_i − n_j‖²/(2σ_n²)) over the neighbours."""
    diff2 = np.square(n_i[:, 0:1].astype(WORK) - al[0])
    diff2 += np.square(n_i[:, 1:2].astype(WORK) - al[1])
    diff2 += np.square(n_i[:, 2:3].astype(WORK) - al[2])
    wn = np.exp(diff2 * WORK(-1.0 / (2.0 * sn2)))
    wn *= tvmask
    return np.where(cnt > 0, _rowsum(wn) / np.maximum(cnt, 1), 1.0)


def _height_fit(res, psi, theta, d2, hgt, t_i):
    """Intercept a and curvature c of the η-weighted fit h_j ≈ a + cρ_j² (ρ_j the
    tangential distance); a replaces τ in the position update."""
    eta = _eta(res, psi, theta)
    rho2 = np.maximum(d2 - hgt * hgt, 0.0)
    s0, s1, s2 = _rowsum(eta), _rowsum(eta * rho2), _rowsum(eta * rho2 * rho2)
    b0, b1 = _rowsum(eta * hgt), _rowsum(eta * rho2 * hgt)
    det = s0 * s2 - s1 * s1
    good = det > 1e-9 * np.maximum(s0 * s2, 1e-300)
    a = np.where(good, (b0 * s2 - b1 * s1) / np.where(good, det, 1.0), t_i)
    c = np.where(good, (s0 * b1 - s1 * b0) / np.where(good, det, 1.0), 0.0)
    return a, c


def _tau_step(hgt, res, psi, theta, fid, t_i, sh2: float):
    """One IRLS sweep of (4.14) from τ_i, kept only where it does not raise the
    fidelity term: (τ, residuals h − τ, ψ) of the new state."""
    eta = _eta(res, psi, theta)
    den = _rowsum(eta)
    num = _rowsum(eta * hgt)
    t_new = np.where(den > 0, num / np.where(den > 0, den, 1.0), t_i)
    res = hgt - t_new.astype(WORK)[:, None]
    psi = _psi(res, sh2)
    f_new = _rowsum(np.abs(res) * psi * theta)
    keep = f_new > fid
    if keep.any():
        t_new[keep] = t_i[keep]
        res[keep] = hgt[keep] - t_i[keep].astype(WORK)[:, None]
        psi[keep] = _psi(res[keep], sh2)
    return t_new, res, psi


def _normal_step(ctx: _Ctx, n_i, d, d2, res, psi, theta, al, w, cnt) -> np.ndarray:
    """Gradient step on E_f (4.10) with step 1/L of its IRLS majoriser, then the
    proximal average (4.11)-(4.12) of the TV term; unit normals."""
    eta = _eta(res, psi, theta)
    lip = _rowsum(eta * d2)
    eta *= res
    grad = np.stack([_rowsum(eta * d[a]) for a in range(3)], axis=1)
    gamma = np.where(lip > 0, 1.0 / np.where(lip > 0, lip, 1.0), 0.0)
    half = n_i - gamma[:, None] * grad
    # proximal step on d_ij = n_i − n_j, averaged over j
    thr = w * (gamma * ctx.lam * cnt).astype(WORK)[:, None]
    h32 = half.astype(WORK)
    dd = [h32[:, a:a + 1] - al[a] for a in range(3)]
    if ctx.l1:  # thesis (4.12): per component, n_j + soft(d) = n_i − clip(d, ±t)
        for a in range(3):
            np.minimum(dd[a], thr, out=dd[a])
            np.maximum(dd[a], -thr, out=dd[a])
    else:  # vector soft threshold: n_j + soft(d) = n_i − d·min(1, t/‖d‖)
        ln = np.sqrt(dd[0] * dd[0] + dd[1] * dd[1] + dd[2] * dd[2])
        fac = np.minimum(thr / np.maximum(ln, WORK(1e-30)), WORK(1.0))
        for a in range(3):
            dd[a] *= fac
    cand = half - np.stack([_rowsum(dd[a]) for a in range(3)], axis=1) \
        / np.maximum(cnt, 1)[:, None]
    norm = np.linalg.norm(cand, axis=1)
    ok = norm > 1e-12
    return np.where(ok[:, None], cand / np.where(ok, norm, 1.0)[:, None], n_i)


# ---------------------------------------------------------------------------
# after the inner loop

def _smooth_curvature(ctx: _Ctx, normals: np.ndarray, curv: np.ndarray) -> np.ndarray:
    """θ-weighted mean over N_g(p_i) of the curvatures c_j of the fits
    h ≈ a + cρ², each sign-aligned to n_i (c flips with the normal's sign)."""
    out = np.empty(len(curv))  # noqa: NPY-empty -- every chunk writes its rows
    if _kernels.ENABLED:
        nrm = np.ascontiguousarray(normals, dtype=np.float64)
        c = np.ascontiguousarray(curv, dtype=np.float64)
        _run_chunks(lambda s, e: _denoise_jit.curvature_rows(
            ctx.x, ctx.idx, nrm, c, s, e, ctx.r2, ctx.sd2, out), len(curv),
            COMPILED_CHUNK)
        return out

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
    before the correction.  Returns the number of points moved.
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
