"""
_crease.py
----------
Geometric tests of ``sharp.py`` around a detected point (not in the thesis):
the crease line through its neighbourhood, estimated from the ridge strength
(``crease_distance``) or as the intersection of two fitted planes
(``two_plane_distance``), the turn of the normals (``normal_spread``), and the
neighbourhood sizes they use at a given noise level.  Why each exists, and what
it was measured to do, is in docs/decisions/features.md.
"""

from __future__ import annotations

import numpy as np

from .multiscale import MOMENT_CHUNK, sym3_eig
from .neighbors import build_tree, knn, leaf_order, median

#: neighbours of the crease-line estimate on clean data, and its growth per unit σ̂ (h)
_LOC_K = 16
_LOC_NOISE_GAIN = 3.0
#: neighbours of the two-plane crease fit on clean data, and its growth per unit σ̂ (h)
_PLANE_K = 32
_PLANE_NOISE_GAIN = 5.0
#: k-planes refinement passes of the two-plane fit
_PLANE_ITERS = 3
#: neighbours over which the spread of the PCA normals is measured
SPREAD_K = 32


def noise_level(lambda0_h2: np.ndarray) -> float:
    """Noise level of the cloud in h: √ of the median λ0/h² of the smallest scale.

    On a smooth surface λ0 of a small neighbourhood is the variance along the
    normal, i.e. the noise variance, and the median ignores the minority of
    points near features (≈ 0.7σ for Gaussian noise σ along the normal, about 0
    on clean data; see docs/decisions/features.md, section "Noise-aware
    localisation").

    >>> noise_level(np.array([0.0, 0.04, 0.04, 9.0]))
    0.2
    """
    return float(np.sqrt(max(median(lambda0_h2), 0.0)))


def localisation_k(sigma: float) -> int:
    """Neighbours of the crease-line estimate at noise level ``sigma`` (h):
    ``16·(1 + 3σ)``.

    >>> localisation_k(0.0), localisation_k(0.2)
    (16, 26)
    """
    return int(round(_LOC_K * (1.0 + _LOC_NOISE_GAIN * max(float(sigma), 0.0))))


def plane_k(sigma: float) -> int:
    """Neighbours of the two-plane crease fit at noise level ``sigma`` (h):
    ``32·(1 + 5σ)``.

    >>> plane_k(0.0), plane_k(0.2)
    (32, 64)
    """
    return int(round(_PLANE_K * (1.0 + _PLANE_NOISE_GAIN * max(float(sigma), 0.0))))


def crease_distance(points: np.ndarray, mask: np.ndarray, ridge: np.ndarray, *,
                    h: float, k: int = 16, tree=None, reach=None) -> np.ndarray:
    """Distance of each selected point to the crease line through its
    neighbourhood, in units of h.

    The ``k`` nearest neighbours j of a point are weighted by ``ridge_j²``;
    their weighted centroid c_i is taken as a point of the crease and the
    principal axis t_i of their weighted scatter as its direction; the result
    is the component of ``p_i − c_i`` orthogonal to t_i.

    Parameters
    ----------
    points : (n, 3) float
        Centred cloud.
    mask : (n,) bool
        Points whose distance is wanted.
    ridge : (n,) float, ≥ 0
        Ridge strength of every point (peaks on the crease, fades across it).
    h : float
        Average spacing (the unit of the result).
    k : int
        Neighbourhood size (self included).
    reach : (n,) float, optional
        Where given, each selected row's entry is raised to the distance of
        its k-th neighbour (a tiled run checks with it, after the fact, that
        every neighbourhood read lay inside its tile).

    Returns
    -------
    dist : (n,) float
        Crease distance / h for ``mask`` points, ``inf`` elsewhere.
    """
    out = np.full(len(points), np.inf)
    tree = build_tree(points) if tree is None else tree
    sel = leaf_order(tree, np.flatnonzero(mask))
    k = min(k, len(points))
    w_all = ridge * ridge
    eye = np.eye(3)
    for s in range(0, len(sel), MOMENT_CHUNK):
        rows = sel[s:s + MOMENT_CHUNK]
        d, idx = knn(points, k, tree=tree, query=points[rows])
        _raise_reach(reach, rows, d)
        w = w_all[idx]
        tot = w.sum(axis=1, keepdims=True)
        w = np.where(tot > 0, w / np.where(tot > 0, tot, 1.0), 1.0 / k)
        x = points[idx] - points[rows, None, :]                 # (c, k, 3)
        mu = np.einsum("ck,ckd->cd", w, x)                      # c_i − p_i
        cov = np.einsum("ck,cki,ckj->cij", w, x, x) - mu[:, :, None] * mu[:, None, :]
        # principal axis = eigenvector of the smallest eigenvalue of tr·I − cov
        tr = np.trace(cov, axis1=1, axis2=2)
        _, t = sym3_eig(tr[:, None, None] * eye - cov)
        off = mu - np.einsum("cd,cd->c", mu, t)[:, None] * t
        out[rows] = np.sqrt(np.einsum("cd,cd->c", off, off)) / h
    return out


def _raise_reach(reach, rows: np.ndarray, d: np.ndarray) -> None:
    if reach is not None:
        reach[rows] = np.maximum(reach[rows], d[:, -1])


def _axis(nb: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Dominant axis of the weighted normal scatter Σ w n nᵀ (sign-free mean)."""
    return np.linalg.eigh(np.einsum("ck,cki,ckj->cij", w, nb, nb))[1][..., 2]


def _split_axes(nb: np.ndarray, iters: int = 2) -> np.ndarray:
    """Split each row's normals (c, k, 3), taken as axes (sign-free), into two
    groups: seeds = the dominant axis and the normal farthest from it, then
    ``iters`` passes of 2-means on |n·seed|.  Returns (c, k) bool (group 1)."""
    ones = np.ones(nb.shape[:2])
    s1 = _axis(nb, ones)
    far = np.argmin(np.abs(np.einsum("ckd,cd->ck", nb, s1)), axis=1)
    s2 = nb[np.arange(len(nb)), far]
    for it in range(iters + 1):
        grp = (np.abs(np.einsum("ckd,cd->ck", nb, s1))
               >= np.abs(np.einsum("ckd,cd->ck", nb, s2)))
        if it < iters:
            s1 = _axis(nb, grp.astype(np.float64))
            s2 = _axis(nb, (~grp).astype(np.float64))
    return grp


def _two_planes(x: np.ndarray, grp: np.ndarray, iters: int):
    """Least-squares planes of the two groups of neighbours, refined by
    ``iters`` k-planes passes; returns ((n_a, d_a, count_a), (n_b, d_b,
    count_b)) and the residuals (ra, rb) of every neighbour to each plane."""
    for it in range(iters + 1):
        fits = []
        for g in (grp, ~grp):
            w = g.astype(np.float64)
            cnt = w.sum(axis=1)
            w /= np.maximum(cnt, 1.0)[:, None]
            mu = np.einsum("ck,ckd->cd", w, x)
            xc = x - mu[:, None, :]
            nrm = sym3_eig(np.einsum("ck,cki,ckj->cij", w, xc, xc))[1]
            fits.append((nrm, np.einsum("cd,cd->c", nrm, mu), cnt))
        ra = np.abs(np.einsum("ckd,cd->ck", x, fits[0][0]) - fits[0][1][:, None])
        rb = np.abs(np.einsum("ckd,cd->ck", x, fits[1][0]) - fits[1][1][:, None])
        if it < iters:
            # reassign only where both planes are determined (≥ 4 points)
            both = (fits[0][2] >= 4) & (fits[1][2] >= 4)
            grp = np.where(both[:, None], ra < rb, grp)
    return fits, ra, rb


def two_plane_distance(points: np.ndarray, mask: np.ndarray, normals: np.ndarray, *,
                       h: float, k: int = _PLANE_K, iters: int = _PLANE_ITERS,
                       min_angle: float = 15.0, tree=None, reach=None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Distance of each selected point to the intersection line of two planes
    fitted to its neighbourhood, in units of h, and the fit's RMS residual.

    The normals of the ``k`` nearest neighbours, taken as sign-free axes, are
    split into two groups (the two faces of a crease) by 2-means; a plane is
    fitted to each group and refined by ``iters`` k-planes passes (every
    neighbour to the nearer plane).  Points whose planes meet at less than
    ``min_angle`` degrees, or hold fewer than 4 points, get ``inf``.

    Parameters
    ----------
    points : (n, 3) float
        Centred cloud.
    mask : (n,) bool
        Points whose distance is wanted.
    normals : (n, 3) float
        Unit normals of every point (any sign), e.g. PCA normals.
    h : float
        Average spacing (the unit of the results).
    k : int
        Neighbourhood size (self included).
    reach : (n,) float, optional
        Where given, each selected row's entry is raised to the distance of
        its k-th neighbour (a tiled run checks with it, after the fact, that
        every neighbourhood read lay inside its tile).

    Returns
    -------
    dist : (n,) float
        Distance / h to the fitted crease line (``inf`` outside ``mask`` and
        for degenerate fits).
    rms : (n,) float
        RMS distance / h of the neighbours to the nearer plane (``inf`` where
        ``dist`` is).
    """
    n = len(points)
    dist = np.full(n, np.inf)
    rms = np.full(n, np.inf)
    tree = build_tree(points) if tree is None else tree
    sel = leaf_order(tree, np.flatnonzero(mask))
    k = min(k, n)
    sin_min = np.sin(np.radians(min_angle))
    for s in range(0, len(sel), MOMENT_CHUNK):
        rows = sel[s:s + MOMENT_CHUNK]
        d, idx = knn(points, k, tree=tree, query=points[rows])
        _raise_reach(reach, rows, d)
        x = points[idx] - points[rows, None, :]                 # (c, k, 3)
        fits, ra, rb = _two_planes(x, _split_axes(normals[idx]), iters)
        (na, da, ca), (nb_, db, cb) = fits
        t = np.cross(na, nb_)
        tn = np.sqrt(np.einsum("cd,cd->c", t, t))
        ok = (tn > sin_min) & (ca >= 4) & (cb >= 4)
        t /= np.maximum(tn, 1e-300)[:, None]
        # crease point in the plane through p_i orthogonal to the line
        A = np.stack([na, nb_, t], axis=1)
        A[~ok] = np.eye(3)
        b = np.stack([da, db, np.zeros(len(rows))], axis=1)
        c = np.linalg.solve(A, b[..., None])[..., 0]
        dist[rows] = np.where(ok, np.sqrt(np.einsum("cd,cd->c", c, c)) / h, np.inf)
        rms[rows] = np.where(ok, np.sqrt(np.mean(np.minimum(ra, rb) ** 2, axis=1)) / h,
                             np.inf)
    return dist, rms


def normal_spread(points: np.ndarray, mask: np.ndarray, normals: np.ndarray, *,
                  k: int = SPREAD_K, tree=None, reach=None) -> np.ndarray:
    """Angle in degrees by which the normals turn within each selected point's
    neighbourhood.

    The ``k`` nearest neighbours' normals, taken as sign-free axes, give the
    scatter M = (1/k) Σ n nᵀ; two equal groups whose axes meet at θ give M the
    middle eigenvalue (1 − cos θ)/2, so the result is θ = arccos(1 − 2 λ_mid):
    0 on a plane, a few degrees on a smooth surface, the dihedral deviation
    (90° at most) across a crease.

    Parameters
    ----------
    points : (n, 3) float
    mask : (n,) bool
        Points whose spread is wanted.
    normals : (n, 3) float
        Unit normals of every point (any sign), e.g. PCA normals.
    k : int
        Neighbourhood size (self included).
    reach : (n,) float, optional
        Where given, each selected row's entry is raised to the distance of
        its k-th neighbour (a tiled run checks with it, after the fact, that
        every neighbourhood read lay inside its tile).

    Returns
    -------
    (n,) float
        Degrees; NaN for points not in ``mask``.
    """
    out = np.full(len(points), np.nan)
    tree = build_tree(points) if tree is None else tree
    sel = leaf_order(tree, np.flatnonzero(mask))
    k = min(k, len(points))
    for s in range(0, len(sel), MOMENT_CHUNK):
        rows = sel[s:s + MOMENT_CHUNK]
        d, idx = knn(points, k, tree=tree, query=points[rows])
        _raise_reach(reach, rows, d)
        nb = normals[idx]
        lam = sym3_eig(np.einsum("cki,ckj->cij", nb, nb) / k)[0]
        out[rows] = np.degrees(np.arccos(np.clip(1.0 - 2.0 * lam[:, 1], -1.0, 1.0)))
    return out
