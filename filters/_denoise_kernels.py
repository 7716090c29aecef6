"""
_denoise_kernels.py
-------------------
Array kernels of :func:`pcprep.filters.denoise.denoise_l1_tv`: the neighbour
query in units of h, the chunked thread-pool runner, and the per-chunk weights
of the energy (4.5) (θ, ψ, η, the TV term) on a padded ``(n, k)`` neighbour
array in float64 structure-of-arrays form (float32 made the result depend on
the pose of the cloud: a rotation changed it by up to 0.3 h).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._kernels import run_chunks
from ._validation import PointCloudError, as_normals, as_points, check_spread
from .neighbors import SPACING_K, build_tree, centered, query_settled, spacing_from_rows

#: points per chunk of the neighbour passes (small blocks stay in the allocator's
#: heap and in cache)
CHUNK = 2048
#: rows per task of the compiled row kernels: they allocate nothing per row, so
#: larger tasks only cut the thread pool's overhead, whose Python side competes
#: with the workers for the cores
COMPILED_CHUNK = 16_384
#: |h_j − τ| below GUARD (in units of h) uses η = θ instead of ψθ/|h_j − τ|
GUARD = 1e-3
#: points per chunk of the k-NN query
QUERY_CHUNK = 131_072
#: IRLS sub-iterations of the τ step (4.14) in the n⁰ passes
TAU_IRLS = 3

WORK = np.float64  # the working precision of the chunk kernels

# ---------------------------------------------------------------------------
# chunked, threaded execution

def _run_chunks(fn, n: int, chunk: int = CHUNK) -> list:
    """:func:`_kernels.run_chunks` with the NumPy passes' chunk by default."""
    return run_chunks(fn, n, chunk)


@dataclass
class _Ctx:
    """Working state shared by the chunk kernels (lengths in units of h).

    Neighbour arrays are built per chunk in structure-of-arrays form (one
    (c, k) float64 array per coordinate).
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
    xt: np.ndarray = None  # (3, n) float64 copy of x for gathers

    def refresh(self):
        self.xt = np.ascontiguousarray(self.x.T, dtype=np.float64)


def _geometry(ctx: _Ctx, s: int, e: int):
    """D = p_i − p_j per coordinate, |D|², θ and the radius mask, rows s:e."""
    idx = ctx.idx[s:e]
    d = []
    for a in range(3):
        # full precision whatever the distance of the cloud from the origin
        col = ctx.xt[a]
        da = np.take(col, idx)
        np.subtract(col[s:e, None], da, out=da)
        d.append(da)
    d2 = d[0] * d[0]
    d2 += d[1] * d[1]
    d2 += d[2] * d[2]
    valid = d2 <= ctx.r2
    theta = np.exp(d2 * WORK(-1.0 / ctx.sd2))
    theta *= valid
    return d, d2, valid, theta


def _dot(d, v):
    """Σ_a d[a] * v[:, a] for (c, k) arrays ``d`` and (c, 3) ``v``."""
    v = v.astype(WORK, copy=False)
    out = d[0] * v[:, 0:1]
    out += d[1] * v[:, 1:2]
    out += d[2] * v[:, 2:3]
    return out


def _psi(res: np.ndarray, sh2: float) -> np.ndarray:
    """ψ = exp(−(h − τ)²/σ_h²) of (4.3), from the residuals h − τ."""
    return np.exp(np.square(res) * WORK(-1.0 / sh2))


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
    """Row sums of a (c, k) array (BLAS matrix-vector product), as float64."""
    return (a @ np.ones(a.shape[1], dtype=a.dtype)).astype(np.float64)


def _tau_irls(hgt, tau, theta, sh2, n_steps=TAU_IRLS):
    """IRLS weighted L1-median of the heights (4.14); ``hgt`` (..., k)."""
    tau = tau.astype(WORK)
    for _ in range(n_steps):
        r = hgt - tau[..., None]
        et = _eta(r, _psi(r, sh2), theta)
        den = et.sum(axis=-1)
        num = (et * hgt).sum(axis=-1)
        tau = np.where(den > 0, num / np.where(den > 0, den, 1.0), tau).astype(WORK)
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
    sgn = np.where(dots < 0, WORK(-1.0), WORK(1.0))
    al = [nb[a] * sgn for a in range(3)]
    c = np.abs(dots)
    w = np.square((1.0 - c) * WORK(1.0 / (1.0 - ctx.cos_n)))
    np.negative(w, out=w)
    np.exp(w, out=w)
    w *= tvmask
    ni = n_i.astype(WORK)
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
# the neighbour array

def _prepare(points, normals, k_max: int, func: str, tile=None):
    """Validate the data, centre it, scale it to units of h and query ``k_max``
    neighbours per point (self first), in the k-d tree's leaf order.

    Returns ``(x / h, normals or None, centre, h, idx, perm)``; ``x`` and the
    normals are permuted by ``perm``.  With ``tile = (centre, h, n_total)`` (a
    tile of a larger cloud) the whole cloud's centre, h and neighbour count
    (from its size ``n_total``) are used instead of the tile's own, the spread is
    not checked (the caller checked the whole cloud), and a seventh value, the
    distance to each row's last neighbour in units of h, is returned.
    """
    x = as_points(points, func=func, min_points=1 if tile else SPACING_K + 1)
    nrm = None if normals is None else as_normals(normals, len(x), func=func)
    if tile is None:
        check_spread(x, func=func)
        k = min(max(k_max, SPACING_K + 1), len(x))
        x, centre = centered(x)
    else:
        centre, h_all, n_total = tile
        k = min(max(k_max, SPACING_K + 1), n_total, len(x))
        x = x - centre
    tree = build_tree(x)
    # work in the tree's leaf order: neighbours then sit close in memory, which
    # makes the gathers of every pass cache-friendly
    perm = np.asarray(tree.indices, dtype=np.int64)
    x = x[perm]
    del tree
    tree = build_tree(x)
    itype = np.int32 if len(x) < 2**31 else np.int64
    idx = np.empty((len(x), k), dtype=itype)  # noqa: NPY-empty -- filled by chunks
    rows = np.zeros(len(x))
    kth = np.zeros(len(x))
    for s in range(0, len(x), QUERY_CHUNK):  # chunked: float64 distances stay small
        dist, ii = query_settled(tree, x[s:s + QUERY_CHUNK], k)
        idx[s:s + QUERY_CHUNK] = ii
        kth[s:s + QUERY_CHUNK] = dist[:, -1]
        if tile is None:
            rows[s:s + QUERY_CHUNK] = dist[:, 1:SPACING_K + 1].mean(axis=1)
    del tree, dist, ii
    if tile is not None:
        h = h_all
        return x / h, None if nrm is None else nrm[perm], centre, h, idx, perm, kth / h
    h = spacing_from_rows(rows)
    if not np.isfinite(h) or h <= 0.0:
        raise PointCloudError(
            f"{func}: every point coincides with its neighbours (h = 0)")
    if nrm is not None:
        nrm = nrm[perm]
    return x / h, nrm, centre, h, idx, perm


