"""
features.py
-----------
Sharp-feature and hole-boundary detection by dictionary learning and sparse
coding of multi-scale covariance features (thesis ch.7, eqs (7.1)-(7.13)).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ._params import Param, resolve_params
from ._validation import InvalidParameterError, as_normals, as_points, check_spread
from .neighbors import CHUNK, average_spacing, build_tree, centered, knn

log = logging.getLogger("pcprep")

#: points per chunk in the multi-scale moment computation
_CHUNK = CHUNK // 4


# ---------------------------------------------------------------------------
# multi-scale local moments from ONE sorted k-NN query
# ---------------------------------------------------------------------------

def scale_sizes(k_min: int, k_max: int, n_scales: int) -> np.ndarray:
    """Neighbourhood sizes of the scales: ``n_scales`` integers from ``k_min``
    to ``k_max``, geometrically spaced (strictly increasing, duplicates
    removed)."""
    if n_scales == 1:
        return np.array([k_min], dtype=np.int64)
    ks = np.unique(np.round(np.geomspace(k_min, k_max, n_scales)).astype(np.int64))
    return ks


def sym3_eig(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and smallest eigenvector of many symmetric 3x3 matrices.

    Closed form (trigonometric solution of the characteristic cubic), about
    ten times faster than ``np.linalg.eigh`` on millions of 3x3 matrices.

    Parameters
    ----------
    cov : (..., 3, 3) float
        Symmetric positive semi-definite matrices.

    Returns
    -------
    lam : (..., 3) float
        λ0 ≤ λ1 ≤ λ2, clipped below at 0.
    normal : (..., 3) float
        Unit eigenvector of λ0 (sign arbitrary); the largest cross product of
        two rows of ``cov − λ0 I``.
    """
    a00, a11, a22 = cov[..., 0, 0], cov[..., 1, 1], cov[..., 2, 2]
    a01, a02, a12 = cov[..., 0, 1], cov[..., 0, 2], cov[..., 1, 2]
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    safe = np.where(p > 0, p, 1.0)
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
           + a02 * (a01 * a12 - b11 * a02))
    r = np.clip(det / (2.0 * safe ** 3), -1.0, 1.0)
    phi = np.arccos(r) / 3.0
    l2 = q + 2.0 * p * np.cos(phi)
    l0 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    l1 = 3.0 * q - l2 - l0
    lam = np.stack([l0, l1, l2], axis=-1)
    lam = np.sort(np.maximum(lam, 0.0), axis=-1)
    # eigenvector of λ0: null direction of (A − λ0 I), from row cross products
    m = cov - l0[..., None, None] * np.eye(3)
    r0, r1, r2 = m[..., 0, :], m[..., 1, :], m[..., 2, :]
    c = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=-2)
    cn = np.einsum("...ij,...ij->...i", c, c)
    best = np.argmax(cn, axis=-1)
    v = np.take_along_axis(c, best[..., None, None], axis=-2)[..., 0, :]
    vn = np.sqrt(np.take_along_axis(cn, best[..., None], axis=-1))
    normal = np.where(vn > 0, v / np.where(vn > 0, vn, 1.0), np.array([0.0, 0.0, 1.0]))
    return lam, normal


def multiscale_features(points: np.ndarray, ks: np.ndarray, *, kind: str,
                        h: float | None = None, tree=None) -> np.ndarray:
    """Covariance features of every point at several neighbourhood sizes.

    One k-NN query with ``k = ks[-1]`` (neighbours sorted by distance) serves
    all scales: block sums of the relative positions ``x = p_j − p_i`` and of
    their outer products ``x xᵀ`` between consecutive sizes, accumulated over
    the blocks, give every scale's mean and covariance in O(n·k_max).

    Parameters
    ----------
    points : (n, 3) float
        Centred cloud.
    ks : (s,) int
        Increasing neighbourhood sizes (each counts the point itself).
    kind : {"sharp", "hole"}
        ``"sharp"``: (λ0/h², λ0/λ2, σ, Pd/h) per scale, thesis (7.1)-(7.4).
        ``"hole"``: (|λ2 − 2λ1|/λ2, k h²/(π r²), ‖p̄ − p_i‖_t / r) per scale,
        thesis (7.5)-(7.7) (see ``detect_hole_boundaries`` Notes).
    h : float, optional
        Average spacing (computed when omitted).

    Returns
    -------
    features : (n, 4·s) or (n, 3·s) float
        Scale-major columns: all features of scale 0, then scale 1, ...
    """
    n = len(points)
    ks = np.asarray(ks, dtype=np.int64)
    tree = build_tree(points) if tree is None else tree
    h = average_spacing(points, tree=tree) if h is None else h
    k_max = int(ks[-1])
    n_f = 4 if kind == "sharp" else 3
    out = np.empty((n, n_f * len(ks)))  # noqa: NPY-empty -- every row written below
    starts = np.concatenate([[0], ks[:-1]])
    kf = ks.astype(np.float64)
    iu = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))
    for s in range(0, n, _CHUNK):
        e = min(n, s + _CHUNK)
        dist, idx = knn(points, k_max, tree=tree, query=points[s:e])
        x = points[idx]                                         # (c, k, 3)
        x -= points[s:e, None, :]
        xt = np.ascontiguousarray(x.transpose(2, 0, 1))         # (3, c, k)
        del x
        s1 = np.cumsum(np.add.reduceat(xt, starts, axis=2), axis=2)   # (3, c, S)
        mean = s1 / (kf * h)                                    # in units of h
        cov = np.empty((e - s, len(ks), 3, 3))  # noqa: NPY-empty -- all 9 entries set
        corr = kf / np.maximum(kf - 1.0, 1.0)                   # 1/(k−1) of (7.1)
        for i, j in zip(*iu):
            s2 = np.cumsum(np.add.reduceat(xt[i] * xt[j], starts, axis=1), axis=1)
            cij = (s2 / (kf * h * h) - mean[i] * mean[j]) * corr
            cov[..., i, j] = cij
            cov[..., j, i] = cij
        mean = np.moveaxis(mean, 0, -1)                         # (c, S, 3)
        lam, nrm = sym3_eig(cov)                                # (c, S, 3)
        l0, l1, l2 = lam[..., 0], lam[..., 1], lam[..., 2]
        l2s = np.maximum(l2, 1e-300)
        shift_n = np.einsum("csd,csd->cs", mean, nrm)           # (p̄ − p_i)·n
        if kind == "sharp":
            f = np.stack([l0, l0 / l2s, l0 / np.maximum(lam.sum(-1), 1e-300),
                          np.abs(shift_n)], axis=-1)
        else:
            r = dist[:, ks - 1] / h                             # radius of scale
            r = np.maximum(r, 1e-12)
            shift_t = np.sqrt(np.maximum(np.einsum("csd,csd->cs", mean, mean)
                                         - shift_n ** 2, 0.0))
            f = np.stack([np.abs(l2 - 2.0 * l1) / l2s, kf[None, :] / (np.pi * r * r),
                          shift_t / r], axis=-1)
        out[s:e] = f.reshape(e - s, -1)
    return out


def otsu_threshold(values: np.ndarray, bins: int = 256) -> float:
    """Otsu's threshold (maximal between-class variance) of ``values``.

    For integer-valued scores with few distinct values each value gets its
    own bin.  Returns a value t; the upper class is ``values > t``.
    """
    v = np.asarray(values, dtype=np.float64).ravel()
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        return hi
    uniq = np.unique(v)
    if len(uniq) <= bins:
        centers = uniq
        counts = np.searchsorted(np.sort(v), uniq, side="right")
        counts = np.diff(np.concatenate([[0], counts])).astype(np.float64)
        cuts = 0.5 * (uniq[:-1] + uniq[1:])
    else:
        counts, edges = np.histogram(v, bins=bins, range=(lo, hi))
        counts = counts.astype(np.float64)
        centers = 0.5 * (edges[:-1] + edges[1:])
        cuts = edges[1:-1]
    w = counts / counts.sum()
    w0 = np.cumsum(w)[:-1]
    mu = np.cumsum(w * centers)
    mu_t = mu[-1]
    mu0 = mu[:-1]
    w1 = 1.0 - w0
    ok = (w0 > 0) & (w1 > 0)
    between = np.zeros_like(w0)
    between[ok] = (mu_t * w0[ok] - mu0[ok]) ** 2 / (w0[ok] * w1[ok])
    return float(cuts[int(np.argmax(between))])
