"""
_denoise_project.py
-------------------
The final step of :func:`pcprep.filters.denoise.denoise_l1_tv` (not in the
thesis): each input point is projected onto an algebraic sphere fitted to its
neighbours' positions and normals, as in algebraic point set surfaces.
"""

from __future__ import annotations

import numpy as np

from . import _denoise_jit, _kernels
from ._denoise_kernels import (COMPILED_CHUNK, WORK, _Ctx, _dot, _geometry, _rowsum,
                               _run_chunks, _smallest_eigvec)

#: Newton steps of the projection onto the fitted algebraic sphere
PROJ_STEPS = 3
#: a neighbour is on another sheet (the far face of a thin wall) when its height
#: above the point's tangent plane, both at their filtered positions, exceeds
#: what the turn of the normals between them explains (½ d sin∠) by more than
#: this many h
SHEET_GAP = 1.0


def _pca_normals(ctx: _Ctx, k: int, rows: np.ndarray) -> np.ndarray:
    """Plain (unweighted) PCA normals of ``rows`` over their first ``k`` neighbours."""
    out = np.empty((len(rows), 3))  # noqa: NPY-empty -- every chunk writes its rows

    def kernel(s, e):
        nb = ctx.x[ctx.idx[rows[s:e], :k]]
        dc = nb - nb.mean(axis=1, keepdims=True)
        cov = [np.einsum("ck,ck->c", dc[:, :, a], dc[:, :, b])
               for a, b in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))]
        out[s:e] = _smallest_eigvec(*cov)

    _run_chunks(kernel, len(rows))
    return out


def _sphere_project(ctx: _Ctx, fit_n: np.ndarray, sheet_x: np.ndarray):
    """Project every point of ``ctx.x`` onto an algebraic sphere fitted to its
    neighbours (positions ``ctx.x``, normals ``fit_n``).

    Weights: θ (σ_d, radius r) times the normal similarity w_ij of (4.4) between
    each neighbour's normal and the point's own, so the fit stays on one side of
    an edge, and 0 for a neighbour on another sheet: its height above the
    point's tangent plane, measured between the filtered positions ``sheet_x``,
    exceeds ½ d sin∠(n_i, n_j) + ``SHEET_GAP`` (a surface turning by ∠ over d
    rises by about ½ d sin∠; the far face of a wall thinner than the radius
    does not turn, it is offset).  The sphere s(x) = u₀ + uᵀx + u₄‖x‖² (x relative to p_i) fits
    positions and normals in the least-squares sense of algebraic point set
    surfaces (position and gradient terms weighted equally); p_i moves to s = 0
    by Newton steps along ∇s.  Returns ``(offset (n, 3), ok (n,))``; ``ok`` is
    False where the fit is degenerate.
    """
    n = len(ctx.x)
    off = np.zeros((n, 3))
    ok = np.zeros(n, dtype=bool)
    if _kernels.ENABLED:
        fn = np.ascontiguousarray(fit_n, dtype=np.float64)
        xs = np.ascontiguousarray(sheet_x, dtype=np.float64)
        _run_chunks(lambda s, e: _denoise_jit.sphere_rows(
            ctx.x, ctx.idx, fn, xs, s, e, ctx.r2, ctx.sd2, ctx.cos_n, SHEET_GAP,
            PROJ_STEPS, off, ok), n, COMPILED_CHUNK)
        return off, ok
    ft = np.ascontiguousarray(fit_n.T, dtype=WORK)

    def kernel(s, e):
        u0, u, u4, good = _sphere_fit(ctx, ft, fit_n[s:e], sheet_x, s, e)
        x = _newton(u0, u, u4)
        good &= np.isfinite(x).all(axis=1)
        off[s:e] = np.where(good[:, None], x, 0.0)
        ok[s:e] = good

    _run_chunks(kernel, n)
    return off, ok


def _sphere_fit(ctx: _Ctx, ft, ri, sheet_x, s: int, e: int):
    """Coefficients (u₀, u, u₄) of the weighted sphere fit about each p_i of rows
    s:e, and whether the weights are non-zero."""
    d, d2, _, theta = _geometry(ctx, s, e)
    q = [-da for da in d]  # q_j = p_j − p_i
    idx = ctx.idx[s:e]
    nb = [np.take(ft[a], idx) for a in range(3)]
    dots = _dot(nb, ri)
    sgn = np.where(dots < 0, WORK(-1.0), WORK(1.0))
    nb = [nb[a] * sgn for a in range(3)]
    w = np.square((1.0 - np.abs(dots)) * WORK(1.0 / (1.0 - ctx.cos_n)))
    np.negative(w, out=w)
    np.exp(w, out=w)
    w *= theta
    # another sheet: a height the turn of the normals does not explain
    hs = sum((sheet_x[idx, a] - sheet_x[s:e, a, None]) * ri[:, a, None] for a in range(3))
    turn = 0.5 * np.sqrt(d2) * np.sqrt(np.maximum(1.0 - np.square(dots), 0.0))
    w *= np.abs(hs) <= turn + SHEET_GAP
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
    return u0, u, u4, good


def _newton(u0, u, u4) -> np.ndarray:
    """Offsets x from p_i to s(x) = u₀ + uᵀx + u₄‖x‖² = 0 by Newton steps along ∇s."""
    x = np.zeros((len(u0), 3))
    for _ in range(PROJ_STEPS):
        g = u + 2.0 * u4[:, None] * x
        f = u0 + np.einsum("ij,ij->i", u, x) + u4 * np.einsum("ij,ij->i", x, x)
        g2 = np.einsum("ij,ij->i", g, g)
        x -= (f / np.where(g2 > 1e-24, g2, np.inf))[:, None] * g
    return x
