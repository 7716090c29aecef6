"""
features.py
-----------
Sharp-feature and hole-boundary detection by dictionary learning and sparse
coding of multi-scale covariance features (thesis ch.7, eqs (7.1)-(7.13)).

Pipeline (both detectors): covariance features of every point at ``n_scales``
neighbourhood sizes from ONE sorted k-NN query (prefix sums over the sorted
neighbours), concatenated (§7.3.5); columns standardised; a K-SVD dictionary
of ``n_atoms`` atoms (§7.3.2, Alg. 3.3); every point coded on it; a per-point
code-length score; a threshold (Otsu by default, or β·max as in (7.10)).

A final localisation step (not in the thesis; on by default, off with
``crease_width=None`` / ``rim_width=None``) narrows the detected band: the
code length marks every point whose multi-scale neighbourhood sees the
feature, a band as wide as the largest neighbourhood, while a feature is a
line.  Sharp points are kept within ``plane_width`` h of the intersection
of two planes fitted to their neighbourhood where that model fits
(``two_plane_distance``), elsewhere within ``crease_width`` h of the crease
line estimated from the ridge strength (``crease_distance``); on a regularly
sampled cloud both widths are ``row_width`` h; rim points within
``rim_width`` h of the border implied by their centroid shifts
(``border_distance``) and within ``extent_width`` h of the outermost
neighbours in a strip toward the border (``strip_extent``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from . import sparse
from ._params import Param, resolve_params, validate_params
from ._validation import (InvalidParameterError, PointCloudError, as_normals, as_points,
                          check_spread)
from .neighbors import CHUNK, SPACING_K, average_spacing, build_tree, centered, knn

log = logging.getLogger("pcprep")

#: floor of the robust feature scale, as a fraction of the column's std
_MAD_FLOOR = 0.3
#: points per chunk in the multi-scale moment computation
_CHUNK = CHUNK // 4
#: neighbours used to estimate the crease line around a detected point (clean data)
_LOC_K = 16
#: growth of that neighbourhood with the estimated noise level (per unit h)
_LOC_NOISE_GAIN = 3.0
#: quantile at which the sharp score is winsorised before Otsu's threshold
_WINSOR_Q = 0.95
#: neighbours of the two-plane crease fit on clean data, and its growth with σ̂ (per h)
_PLANE_K = 32
_PLANE_NOISE_GAIN = 5.0
#: k-planes refinement passes of the two-plane fit
_PLANE_ITERS = 3
#: two-plane model accepted when its RMS residual is ≤ _PLANE_RMS0 + _PLANE_RMS_GAIN·σ̂ (h)
_PLANE_RMS0 = 0.05
_PLANE_RMS_GAIN = 1.2
#: neighbourhood size whose PCA normals seed the two-plane split
_NORMAL_K = 16
#: sampling counted as regular (mesh vertices, grids) when the coefficient of
#: variation of the nearest-neighbour distance is below this (a uniform random
#: sampling of a surface gives √(4/π − 1) ≈ 0.52)
_REGULAR_CV = 0.35
#: neighbours over which the spread of the PCA normals is measured (crease-angle gate)
_SPREAD_K = 32
#: hole localisation: half-width (h) of the strip along the border normal in
#: which the outermost samples are sought, and the empty stretch (h) along it
#: that counts as the surface's end (see ``detect_hole_boundaries`` Notes)
_STRIP_HALF = 1.5
_STRIP_GAP = 2.5
#: radius (h) within which a detected border point counts its detected neighbours
_SUPPORT_RADIUS = 3.0
#: automatic sharp threshold as a fraction of Otsu's split when the crease-angle
#: gate and the localisation are on (see detect_sharp_features Notes)
_OTSU_SCALE_GATED = 0.6
#: hole borders: a sampling is random-like (Poisson clumping, chance gaps, a
#: border that is a band) when at least this fraction of the points has its
#: nearest neighbour closer than ``_CLOSE_RATIO`` × the median nearest-neighbour
#: distance; a uniform random sampling gives about 6 %, mesh vertices and range
#: grids (graded ones too) below 0.5 % (see ``detect_hole_boundaries`` Notes)
_CLOSE_RATIO = 0.3
_RANDOM_CLOSE = 0.01
#: border tracking on mesh-like sampling: largest step (h) between two samples
#: of one border row
_TRACK_LINK = 1.5
#: default smallest hole radius (h) per unit of ln(n) on irregular sampling
_CHANCE_GAP_PER_LOG_N = 0.3


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
        Average spacing; when omitted it is taken from the same sorted query
        (mean distance to the 6 nearest neighbours, as ``average_spacing``).

    Returns
    -------
    features : (n, 4·s) or (n, 3·s) float
        Scale-major columns: all features of scale 0, then scale 1, ...
    """
    return _multiscale(points, ks, kind, h, tree)[0]


def _multiscale(points, ks, kind, h, tree):
    """``multiscale_features``, the spacing h it used, (``kind="sharp"``) the
    PCA normals of the scale nearest 16 points (``kind="hole"``: the
    ``strip_extent`` of every point at the largest scale, in h, the
    surface variation λ0/Σλ of the smallest scale and the indices of the
    smallest scale's neighbours) and the
    coefficient of variation of the nearest-neighbour distance (sampling
    regularity, see ``detect_sharp_features`` Notes) with, for the hole kind,
    the fraction of close pairs (see ``detect_hole_boundaries`` Notes)."""
    n = len(points)
    ks = np.asarray(ks, dtype=np.int64)
    tree = build_tree(points) if tree is None else tree
    k_max = int(ks[-1])
    # the hole kind needs h inside the loop (strip extents), so takes it first
    own_h = h is None and k_max > SPACING_K and kind == "sharp"
    if h is None and not own_h:
        h = average_spacing(points, tree=tree)
    n_f = 4 if kind == "sharp" else 3
    out = np.empty((n, n_f * len(ks)))  # noqa: NPY-empty -- every row written below
    # PCA normal of the scale nearest _NORMAL_K (sharp only: seeds the two-plane fit)
    j_nrm = int(np.argmin(np.abs(ks - _NORMAL_K)))
    normals = np.empty((n, 3)) if kind == "sharp" else None  # noqa: NPY-empty -- all rows set
    extent = np.empty(n) if kind == "hole" else None  # noqa: NPY-empty -- all rows set
    variation = np.empty(n) if kind == "hole" else None  # noqa: NPY-empty -- all rows set
    # the k_min nearest neighbours of every point (hole kind: the border-row test)
    near = (np.empty((n, int(ks[0])), dtype=np.int32)  # noqa: NPY-empty -- all rows set
            if kind == "hole" else None)
    starts = np.concatenate([[0], ks[:-1]])
    kf = ks.astype(np.float64)
    corr = kf / np.maximum(kf - 1.0, 1.0)                       # 1/(k−1) of (7.1)
    iu = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))
    hsum = 0.0
    nn1 = np.empty(n)  # noqa: NPY-empty -- every entry set below
    for s in range(0, n, _CHUNK):
        e = min(n, s + _CHUNK)
        dist, idx = knn(points, k_max, tree=tree, query=points[s:e])
        if own_h:
            hsum += float(dist[:, 1:SPACING_K + 1].sum())
        nn1[s:e] = dist[:, 1]
        if near is not None:
            near[s:e] = idx[:, :ks[0]]
        x = points[idx]                                         # (c, k, 3)
        x -= points[s:e, None, :]
        xt = np.ascontiguousarray(x.transpose(2, 0, 1))         # (3, c, k)
        if kind == "sharp":
            del x
        # features are computed in model units and made unit-free (h) below
        mean = np.cumsum(np.add.reduceat(xt, starts, axis=2), axis=2) / kf  # (3, c, S)
        cov = np.empty((e - s, len(ks), 3, 3))  # noqa: NPY-empty -- all 9 entries set
        for i, j in zip(*iu):
            s2 = np.cumsum(np.add.reduceat(xt[i] * xt[j], starts, axis=1), axis=1)
            cij = (s2 / kf - mean[i] * mean[j]) * corr
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
            r = np.maximum(dist[:, ks - 1], 1e-300)             # radius of the scale
            shift_t = np.sqrt(np.maximum(np.einsum("csd,csd->cs", mean, mean)
                                         - shift_n ** 2, 0.0))
            f = np.stack([np.abs(l2 - 2.0 * l1) / l2s, kf[None, :] / (np.pi * r * r),
                          shift_t / r], axis=-1)
        out[s:e] = f.reshape(e - s, -1)
        if normals is not None:
            normals[s:e] = nrm[:, j_nrm]
        if kind == "hole":
            # extent of the surface toward the border, in h (see strip_extent)
            extent[s:e] = strip_extent(x, mean[:, -1], nrm[:, -1], h=h)
            variation[s:e] = l0[:, 0] / np.maximum(lam[:, 0].sum(-1), 1e-300)
            del x
    if own_h:
        h = hsum / (n * SPACING_K)
        if not np.isfinite(h) or h <= 0.0:
            raise PointCloudError(
                "average_spacing: every point coincides with its neighbours (h = 0)")
    if kind == "sharp":
        out[:, 0::4] /= h * h                                   # λ0 in h²
        out[:, 3::4] /= h                                       # Pd in h
    else:
        out[:, 1::3] *= h * h                                   # k h² / (π r²)
    m1 = float(nn1.mean())
    cv = float(nn1.std() / m1) if m1 > 0 else 0.0
    if kind == "hole":
        # the hole kind returns the strip extent (in h) in the normals' slot,
        # and the fraction of close pairs (random-like sampling) with the CV
        close = float(np.mean(nn1 < _CLOSE_RATIO * np.median(nn1)))
        return out, float(h), (extent, variation, near), (cv, close)
    return out, float(h), normals, (cv, None)


def strip_extent(x: np.ndarray, mean: np.ndarray, normal: np.ndarray, *, h: float,
                 half_width: float = _STRIP_HALF, gap: float = _STRIP_GAP
                 ) -> np.ndarray:
    """Distance from each point to where its surface ends toward the border,
    in units of h, from the outermost neighbours in a strip.

    The border normal of a point is the direction u opposite to its
    tangential centroid shift (the shift points away from a border).  The
    neighbours within ``half_width`` h of the line through the point along u
    are projected on u; sorted from the point outward, the first empty
    stretch longer than ``gap`` h marks the end of the surface, and the
    distance to the last neighbour before it is returned (the farthest
    projection when there is none: about the neighbourhood radius inside a
    surface).  Unlike the centroid shift this does not depend on the density
    of the neighbours, only on where they stop; unlike the farthest
    projection it is not fooled by a curved border (a hole of radius 8h bends
    its rim toward the hole by 1.6h within 5h) nor by a hole narrower than
    the neighbourhood (the far side of the hole lies beyond the gap).

    Parameters
    ----------
    x : (c, k, 3) float
        Neighbours relative to each point (self included), model units.
    mean : (c, 3) float
        Their centroid relative to the point.
    normal : (c, 3) float
        Unit surface normal (PCA) of the neighbourhood.
    h : float
        Average spacing.
    half_width, gap : float
        Strip half-width and ending gap, in h.

    Returns
    -------
    (c,) float
        Distance in h (0 for a point on the outermost row).
    """
    t = mean - np.einsum("cd,cd->c", mean, normal)[:, None] * normal
    tl = np.sqrt(np.einsum("cd,cd->c", t, t))
    u = -t / np.maximum(tl, 1e-300)[:, None]                    # toward the border
    v = np.cross(normal, u)
    a = np.einsum("ckd,cd->ck", x, u) / h
    b = np.abs(np.einsum("ckd,cd->ck", x, v)) / h
    a = np.sort(np.where((b <= half_width) & (a > 0.0), a, 0.0), axis=1)
    big = np.diff(a, axis=1) > gap
    first = np.where(big.any(axis=1), np.argmax(big, axis=1), a.shape[1] - 1)
    return a[np.arange(len(a)), first]


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
        centers, counts = np.unique(v, return_counts=True)
        counts = counts.astype(np.float64)
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


def crease_distance(points: np.ndarray, mask: np.ndarray, ridge: np.ndarray, *,
                    h: float, k: int = 16, tree=None) -> np.ndarray:
    """Distance of each selected point to the crease line through its
    neighbourhood, in units of h.

    For a point i with ``mask[i]``, its ``k`` nearest neighbours j are weighted
    by ``w_j = ridge_j²`` (the ridge strength peaks on the crease and fades
    over a few h across it).  Their weighted centroid c_i lies on the crease
    and the principal axis t_i of their weighted scatter runs along it (the
    weight concentrates on a line of ridge points); the distance is the
    component of ``p_i − c_i`` orthogonal to t_i.

    Parameters
    ----------
    points : (n, 3) float
        Centred cloud.
    mask : (n,) bool
        Points whose distance is wanted.
    ridge : (n,) float, ≥ 0
        Ridge strength of every point.
    h : float
        Average spacing (the unit of the result).
    k : int
        Neighbourhood size (self included).

    Returns
    -------
    dist : (n,) float
        Crease distance / h for ``mask`` points, ``inf`` elsewhere.
    """
    out = np.full(len(points), np.inf)
    sel = np.flatnonzero(mask)
    tree = build_tree(points) if tree is None else tree
    k = min(k, len(points))
    w_all = ridge * ridge
    eye = np.eye(3)
    for s in range(0, len(sel), _CHUNK):
        rows = sel[s:s + _CHUNK]
        _, idx = knn(points, k, tree=tree, query=points[rows])
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


def two_plane_distance(points: np.ndarray, mask: np.ndarray, normals: np.ndarray, *,
                       h: float, k: int = _PLANE_K, iters: int = _PLANE_ITERS,
                       min_angle: float = 15.0, tree=None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Distance of each selected point to the intersection line of two planes
    fitted to its neighbourhood, in units of h, and the fit's RMS residual.

    For a point i with ``mask[i]`` and its ``k`` nearest neighbours: the
    neighbours' normals, taken as sign-free axes, are split into two groups
    -- the two faces of a crease -- by 2-means seeded with the dominant axis
    of their scatter Σ n nᵀ and the normal farthest from it
    (``_split_axes``), and a least-squares plane is fitted to each group;
    ``iters`` k-planes passes then reassign every neighbour to the nearer
    plane and refit.  The crease is the intersection
    line of the two planes; the result is the distance of p_i to it.  Points
    whose planes meet at less than ``min_angle`` degrees or hold fewer than
    4 points get ``inf`` (no crease model).

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

    Returns
    -------
    dist : (n,) float
        Distance / h to the fitted crease line (``inf`` for points not in
        ``mask`` and for degenerate fits).
    rms : (n,) float
        RMS distance / h of the neighbours to the nearer of the two planes
        (``inf`` where ``dist`` is).
    """
    n = len(points)
    dist = np.full(n, np.inf)
    rms = np.full(n, np.inf)
    sel = np.flatnonzero(mask)
    tree = build_tree(points) if tree is None else tree
    k = min(k, n)
    sin_min = np.sin(np.radians(min_angle))
    for s in range(0, len(sel), _CHUNK):
        rows = sel[s:s + _CHUNK]
        _, idx = knn(points, k, tree=tree, query=points[rows])
        x = points[idx] - points[rows, None, :]                 # (c, k, 3)
        nb = normals[idx]
        grp = _split_axes(nb)
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


def _chains(points: np.ndarray, link: float) -> np.ndarray:
    """Connected-component label of each point, points closer than ``link``
    being joined (``points`` not empty)."""
    m = len(points)
    pairs = build_tree(points).query_pairs(link, output_type="ndarray")
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                          shape=(m, m))
    return connected_components(graph, directed=False)[1]


def track_border(points: np.ndarray, seeds: np.ndarray, candidates: np.ndarray,
                 link: float) -> np.ndarray:
    """Hysteresis along a border: the candidates connected to a seed.

    Candidates closer than ``link`` are joined into chains; a chain is kept
    when it holds at least one seed (as Canny's edge tracking keeps the weak
    edges connected to strong ones).

    Parameters
    ----------
    points : (n, 3) float
    seeds : (n,) bool
        Points certainly on the border (they count as candidates too).
    candidates : (n,) bool
        Points that may be on it.
    link : float
        Largest gap within one chain, in the points' units.

    Returns
    -------
    (n,) bool
        Seeds and the candidates chained to them.
    """
    cand = np.flatnonzero(candidates | seeds)
    out = np.zeros(len(points), dtype=bool)
    if not seeds.any():
        return out
    lab = _chains(points[cand], link)
    seeded = np.zeros(lab.max() + 1, dtype=bool)
    seeded[lab[seeds[cand]]] = True
    out[cand[seeded[lab]]] = True
    return out


def border_radius(points: np.ndarray, link: float) -> np.ndarray:
    """Radius of the border each point belongs to.

    Points closer than ``link`` are joined; every connected chain is one
    border, and its radius is the largest distance of its points from their
    centroid (about the hole's radius for a closed rim, half the length for
    a straight stretch, 0 for a lone point).

    Parameters
    ----------
    points : (m, 3) float
        The detected border points.
    link : float
        Largest gap within one border, in the points' units.

    Returns
    -------
    (m,) float
        The radius of each point's border, in the points' units.
    """
    if len(points) == 0:
        return np.zeros(0)
    lab = _chains(points, link)
    count = np.bincount(lab)
    centre = np.stack([np.bincount(lab, points[:, j]) / count for j in range(3)],
                      axis=1)
    radius = np.zeros(len(count))
    np.maximum.at(radius, lab, np.linalg.norm(points - centre[lab], axis=1))
    return radius[lab]


def largest_angle_gap(offsets: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Largest angle between consecutive neighbour directions around a point.

    The offsets are projected on the plane orthogonal to the normal, their
    polar angles sorted, and the largest difference between consecutive
    angles (the wrap-around one included) is returned: about 2π/k inside a
    surface, π on a straight border, more at a convex corner of a border
    (the angle criterion of PCL's ``BoundaryEstimation``).

    Parameters
    ----------
    offsets : (c, k, 3) float
        Neighbour positions relative to each point (the point excluded).
    normals : (c, 3) float
        Unit normal of each point.

    Returns
    -------
    (c,) float
        Largest gap in radians, in [0, 2π].
    """
    nn = normals
    a = np.where(np.abs(nn[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]),
                 np.array([[0.0, 1.0, 0.0]]))
    u = np.cross(nn, a)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(nn, u)
    ang = np.sort(np.arctan2(np.einsum("ckd,cd->ck", offsets, v),
                             np.einsum("ckd,cd->ck", offsets, u)), axis=1)
    wrap = 2.0 * np.pi - (ang[:, -1] - ang[:, 0])
    return np.maximum(np.diff(ang, axis=1).max(axis=1, initial=0.0), wrap)


def border_gap(points: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Largest angular gap (radians) of each point's nearest neighbours,
    around their PCA normal (``largest_angle_gap``).

    Parameters
    ----------
    points : (n, 3) float
        The whole cloud.
    neighbours : (m, k) int
        Each tested point's k nearest neighbours, sorted by distance: column
        0 is the point itself (as ``knn`` returns them).

    Returns
    -------
    (m,) float
    """
    m = len(neighbours)
    out = np.zeros(m)
    for s in range(0, m, CHUNK):
        e = min(m, s + CHUNK)
        x = points[neighbours[s:e, 1:]] - points[neighbours[s:e, 0], None, :]
        xc = x - x.mean(axis=1, keepdims=True)
        _, nrm = sym3_eig(np.einsum("cki,ckj->cij", xc, xc))
        out[s:e] = largest_angle_gap(x, nrm)
    return out


def normal_spread(points: np.ndarray, mask: np.ndarray, normals: np.ndarray, *,
                  k: int = _SPREAD_K, tree=None) -> np.ndarray:
    """Angle in degrees by which the normals turn within each selected point's
    neighbourhood (the crease angle a sharp feature there would have).

    The ``k`` nearest neighbours' normals, taken as sign-free axes, give the
    scatter M = (1/k) Σ n nᵀ.  Two groups of equal size whose axes meet at θ
    give M the middle eigenvalue (1 − cos θ)/2; the result is
    θ = arccos(1 − 2 λ_mid), 0 on a plane, about the normals' turn over the
    neighbourhood on a smooth surface (a few degrees), and up to the dihedral
    deviation across a crease (90° at most).

    Parameters
    ----------
    points : (n, 3) float
    mask : (n,) bool
        Points whose spread is wanted.
    normals : (n, 3) float
        Unit normals of every point (any sign), e.g. PCA normals.
    k : int
        Neighbourhood size (self included).

    Returns
    -------
    (n,) float
        Degrees; NaN for points not in ``mask``.
    """
    out = np.full(len(points), np.nan)
    sel = np.flatnonzero(mask)
    tree = build_tree(points) if tree is None else tree
    k = min(k, len(points))
    for s in range(0, len(sel), _CHUNK):
        rows = sel[s:s + _CHUNK]
        _, idx = knn(points, k, tree=tree, query=points[rows])
        nb = normals[idx]
        lam = sym3_eig(np.einsum("cki,ckj->cij", nb, nb) / k)[0]
        out[rows] = np.degrees(np.arccos(np.clip(1.0 - 2.0 * lam[:, 1], -1.0, 1.0)))
    return out


def plane_k(sigma: float) -> int:
    """Neighbourhood size of the two-plane crease fit at noise level ``sigma``
    (in h): ``32·(1 + 5σ̂)``, 32 on clean data, 64 at σ̂ = 0.2."""
    return int(round(_PLANE_K * (1.0 + _PLANE_NOISE_GAIN * max(float(sigma), 0.0))))


def noise_level(features: np.ndarray) -> float:
    """Noise level of the cloud in h, estimated from the sharp features.

    The square root of the median over the points of λ0/h² at the smallest
    scale (the first column of ``kind="sharp"`` features): on a smooth
    surface λ0 of a small neighbourhood is the variance along the normal,
    i.e. the noise variance (plus a curvature term of order k²h⁴/R²), and the
    median ignores the minority of points near features.  Measured on the
    synthetic CAD parts with Gaussian noise σ along the normal: 0 at σ = 0,
    0.08 at 0.1h, 0.20 at 0.3h (≈ 0.7σ: a k = 8 neighbourhood's own fit
    absorbs part of the noise); the coarser mesh models give 0-0.06 clean.
    """
    return float(np.sqrt(max(float(np.median(features[:, 0])), 0.0)))


def localisation_k(sigma: float) -> int:
    """Neighbourhood size of the crease-line estimate at noise level ``sigma``
    (in h): ``16·(1 + 3σ)``, 16 on clean data, about 26 at σ̂ = 0.2."""
    return int(round(_LOC_K * (1.0 + _LOC_NOISE_GAIN * max(float(sigma), 0.0))))


def _half_disc_table(m: int = 2001) -> tuple[np.ndarray, np.ndarray]:
    """Centroid shift g(u)/r of a disc of radius r whose part beyond a line at
    distance u·r from the centre is missing (u ∈ [0, 1]; g(0) = 4/(3π))."""
    u = np.linspace(0.0, 1.0, m)
    root = np.sqrt(1.0 - u * u)
    g = (2.0 / 3.0) * root ** 3 / (np.pi - np.arccos(u) + u * root)
    return u, g


def border_distance(shift: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Distance to a straight border implied by tangential centroid shifts.

    A k-NN neighbourhood of a point at distance d < r from a straight border
    is a disc of radius r with the segment beyond the border missing; its
    centroid is shifted away from the border by ``r·g(d/r)`` (g decreasing
    from 4/(3π) ≈ 0.42 at d = 0 to 0 at d = r).  Inverting g per scale gives
    d; the median over the scales is returned.

    Parameters
    ----------
    shift : (n, s) float
        Tangential centroid shift / r at each scale.
    radius : (n, s) float
        Radius of each scale's neighbourhood (any unit; the result has it).

    Returns
    -------
    (n,) float
        Median over the scales of ``r·g⁻¹(shift)`` (shifts above 0.42 give 0,
        shifts of 0 give r).
    """
    u, g = _half_disc_table()
    d = np.interp(shift, g[::-1], u[::-1]) * radius
    return np.median(d, axis=1)


# ---------------------------------------------------------------------------
# public detectors
# ---------------------------------------------------------------------------

@dataclass(frozen=True)
class DetectionResult:
    """Result of ``detect_sharp_features`` / ``detect_hole_boundaries``.

    Attributes
    ----------
    mask : (n,) bool
        Detected points.
    score : (n,) float
        Per-point code-length score (higher = rarer); ``mask = score > threshold``
        (for sharp features further restricted by ``crease_distance``).
    threshold : float
        The threshold T applied to ``score``.
    quality : (n,) float
        ``mask`` as 1.0 / 0.0 (the MeshSet vertex quality written by the bridge).
    nnz : (n,) int
        Number of atoms in each point's code, ``f(α_j)`` of (7.8)-(7.9).
    residual : (n,) float
        ``‖z_j − α_j D‖₂`` of each standardised feature vector.
    scales : (s,) int
        Neighbourhood sizes used (each counts the point itself).
    dictionary : (n_atoms, d) float
        The learned K-SVD dictionary (rows are atoms).
    h : float
        Average spacing (mean distance to the 6 nearest neighbours).
    beta : float or None
        β of (7.10) when given; None when the threshold came from Otsu.
    border_extent : (n,) float or None
        Hole boundaries: each point's ``strip_extent`` in h (distance to the
        outermost neighbours toward the border).  None for sharp features.
    crease_distance : (n,) float or None
        Sharp features with the localisation step: each point's distance to
        its estimated crease line in h (``inf`` for points not above the
        threshold); then ``mask = (score > threshold) & (crease_distance ≤
        crease_limit)``.  None when the step is off and for hole boundaries.
    crease_limit : (n,) float or None
        The width each point's ``crease_distance`` was compared with (h).
    normal_spread : (n,) float or None
        Sharp features with the crease-angle gate (``min_angle``): the
        ``normal_spread`` in degrees of every point above the threshold (NaN
        elsewhere); ``mask`` also requires ``normal_spread ≥ min_angle``.
        None when the gate is off and for hole boundaries.
    """

    mask: np.ndarray
    score: np.ndarray
    threshold: float
    quality: np.ndarray
    nnz: np.ndarray
    residual: np.ndarray
    scales: np.ndarray
    dictionary: np.ndarray
    h: float
    beta: float | None
    crease_distance: np.ndarray | None = None
    border_distance: np.ndarray | None = None
    crease_limit: np.ndarray | None = None
    border_extent: np.ndarray | None = None
    normal_spread: np.ndarray | None = None


def _common_params(k_min: int, k_max: int, tol: float, score: str,
                   extra: tuple[Param, ...] = ()) -> tuple[Param, ...]:
    return extra + (
        Param("n_scales", int, low=1, high=32, unit="count"),
        Param("k_min", int, low=5, high=500, unit="count"),
        Param("k_max", int, low=5, high=500, unit="count"),
        Param("n_atoms", int, low=2, high=1000, unit="count"),
        Param("coder", str, choices=("omp", "lasso_lars")),
        Param("alpha", float, low=0.0, high=100.0, closed="right", advanced=True),
        Param("tol", float, low=0.0, high=10.0, closed="right", advanced=True),
        Param("score", str, choices=("count", "l1")),
        Param("beta", float, low=0.0, high=1.0, optional=True),
        Param("max_iter", int, low=1, high=200, unit="count", advanced=True),
        Param("max_train", int, low=100, high=10_000_000, unit="count", advanced=True),
        Param("seed", int, low=0, optional=True),
    )


#: parameters of ``detect_sharp_features``
PARAMS_SHARP = _common_params(8, 40, 0.1, "l1", (
    Param("crease_width", float, low=0.0, high=100.0, closed="right", unit="h", optional=True),
    Param("plane_width", float, low=0.0, high=100.0, closed="right", unit="h", optional=True),
    Param("row_width", float, low=0.0, high=100.0, closed="right", unit="h", optional=True),
    Param("min_angle", float, low=0.0, high=90.0, unit="deg"),
    Param("otsu_scale", float, low=0.0, high=1.0, closed="right", optional=True)))
#: parameters of ``detect_hole_boundaries``
PARAMS_HOLES = _common_params(16, 80, 0.3, "l1", (
    Param("min_shift", float, low=0.0, high=1.0, unit="fraction"),
    Param("rim_width", float, low=0.0, high=100.0, closed="right", unit="h", optional=True),
    Param("extent_width", float, low=0.0, high=100.0, closed="right", unit="h", optional=True),
    Param("max_variation", float, low=0.0, high=1.0 / 3.0, unit="fraction", optional=True),
    Param("min_support", int, low=0, high=1000, unit="count"),
    Param("min_radius", float, low=0.0, high=1000.0, unit="h", optional=True),
    Param("row_angle", float, low=0.0, high=360.0, unit="deg", optional=True)))
#: alias used by the bridge convention (one ``PARAMS`` per module)
PARAMS = PARAMS_SHARP


def _standardise(F: np.ndarray, robust: bool) -> np.ndarray:
    """Column standardisation of the feature matrix (see the detectors' Notes)."""
    if robust:
        med = np.median(F, axis=0)
        std = F.std(axis=0)
        # MAD, floored at 0.3 std: on clean or slightly noisy data most points
        # are flat and the MAD of λ0-like columns collapses to round-off or
        # to the noise, which would make tiny deviations look rare (measured:
        # clean cube F1 0.72 with a 1e-3 floor, 0.85 with 0.3)
        scale = np.maximum(1.4826 * np.median(np.abs(F - med), axis=0), _MAD_FLOOR * std)
        return (F - med) / np.where(scale > 0, scale, 1.0)
    mu = F.mean(axis=0)
    sd = F.std(axis=0)
    return (F - mu) / np.where(sd > 1e-12 * np.maximum(np.abs(mu), 1e-300), sd, 1.0)


def _score_stage(points, normals, p: dict, func: str, kind: str) -> dict:
    """Features, dictionary, codes and code-length score (parameters resolved)."""
    if p["k_min"] > p["k_max"]:
        raise InvalidParameterError(
            f"{func}: k_min must be <= k_max, got k_min={p['k_min']}, k_max={p['k_max']}")
    pts = as_points(points, func=func, min_points=p["k_max"] + 1)
    if normals is not None:
        as_normals(normals, len(pts), func=func)
    check_spread(pts, func=func)
    pts, _ = centered(pts)
    tree = build_tree(pts)
    ks = scale_sizes(p["k_min"], p["k_max"], p["n_scales"])
    F, h, nrm, (nn_cv, close) = _multiscale(pts, ks, kind, None, tree)
    log.info("%s: n=%d h=%.4g scales=%s", func, len(pts), h, ks.tolist())
    bdist = None
    if kind == "hole" and p["rim_width"] is not None:
        # radius of each scale in h from the density column k h²/(π r²)
        r_h = np.sqrt(ks[None, :] / (np.pi * np.maximum(F[:, 1::3], 1e-300)))
        bdist = border_distance(F[:, 2::3], r_h)
    if kind == "hole":
        # orient so that larger = more boundary-like (thesis §7.3.1: epv and
        # density drop at a border, the centroid shift grows)
        F[:, 0::3] *= -1.0
        F[:, 1::3] *= -1.0
    # robust one-sided standardisation: every column is oriented so that larger
    # means more feature-like, centred on the bulk (median) and scaled by its
    # spread (MAD); deviations toward the ordinary side are clipped to 0
    Z = np.maximum(_standardise(F, robust=True), 0.0)
    d = Z.shape[1]
    n_atoms = p["n_atoms"]
    L = max(1, min(d, n_atoms) // 10)
    # the training subsample is drawn here so that K-SVD codes only it; every
    # point is coded below with the coding rule of the score
    rng = np.random.default_rng(p["seed"])
    m = len(Z)
    train = np.arange(m) if m <= p["max_train"] else np.sort(
        rng.choice(m, size=p["max_train"], replace=False))
    res = sparse.ksvd(Z[train], n_atoms, n_nonzero_coefs=L, max_iter=p["max_iter"],
                      max_train=len(train), seed=p["seed"])
    D = res.dictionary
    if p["coder"] == "omp":
        # signals already within the residual target need no atom (most flat
        # points: the one-sided standardisation maps them near 0); only the
        # others are pursued -- the same codes, without their correlations
        busy = np.flatnonzero(np.einsum("ij,ij->i", Z, Z) > p["tol"] * d)
        part = sparse.omp(Z[busy], D, tol=p["tol"] * d).tocoo()
        codes = sp.csr_matrix((part.data, (busy[part.row], part.col)),
                              shape=(len(Z), D.shape[0]))
    else:
        codes = sparse.lasso_lars(Z, D, alpha=p["alpha"])
    nnz, resid = sparse.code_length(codes, Z, D)
    tie = resid / (1.0 + resid)            # in [0, 1): orders points of equal count
    if p["score"] == "count":
        score = nnz + tie
    else:
        codes = codes.tocsr()
        l1 = np.asarray(abs(codes).sum(axis=1)).ravel()
        score = l1 + resid
    return dict(pts=pts, tree=tree, ks=ks, F=F, h=h, bdist=bdist, score=score,
                nnz=nnz, resid=resid, D=D, nn_cv=nn_cv, close=close,
                nrm=nrm if kind == "sharp" else None,
                extent=nrm[0] if kind == "hole" else None,
                variation=nrm[1] if kind == "hole" else None,
                near=nrm[2] if kind == "hole" else None)


def _otsu_scale(p: dict) -> float:
    """Fraction of Otsu's split used as the automatic sharp-feature threshold."""
    if p["otsu_scale"] is not None:
        return float(p["otsu_scale"])
    gated = p["min_angle"] > 0 and p["crease_width"] is not None
    return _OTSU_SCALE_GATED if gated else 1.0


def _detect(points, normals, p: dict, func: str, kind: str) -> DetectionResult:
    """Shared body of the two detectors (parameters already resolved)."""
    st = _score_stage(points, normals, p, func, kind)
    return _select(st, p, func, kind)


def _select(st: dict, p: dict, func: str, kind: str) -> DetectionResult:
    """Threshold and localisation of the score of ``_score_stage``."""
    pts, tree, ks, F, h = st["pts"], st["tree"], st["ks"], st["F"], st["h"]
    bdist, score, nnz, resid, D = (st["bdist"], st["score"], st["nnz"], st["resid"],
                                   st["D"])
    beta = p["beta"]
    if beta is None:
        if kind == "sharp":
            # Otsu on the score winsorised at its 95th percentile: the few
            # extreme scores (corners, tips) would otherwise form Otsu's upper
            # class alone
            T = otsu_threshold(np.minimum(score, np.quantile(score, _WINSOR_Q)))
            T *= _otsu_scale(p)
        else:
            T = otsu_threshold(score)
        if (kind == "hole" and p["extent_width"] is None
                and (score > T).sum() > 1):
            # without the strip localisation: rims are a small minority and
            # Otsu's upper class still holds the tail of the interior; split
            # it once more (the rare class of the rare class, cf. multi-level
            # Otsu).  With it, the strip test removes that tail instead.
            T = otsu_threshold(score[score > T])
    else:
        T = float(beta * score.max())      # (7.10)
    mask = score > T                       # (7.11)
    cdist = limit = None
    if kind == "hole" and p["min_shift"] > 0:
        # tangential shift / r, averaged over the scales (see Notes)
        mask &= F[:, 2::3].mean(axis=1) >= p["min_shift"]
    if bdist is not None:
        n_det = int(mask.sum())
        mask &= bdist <= p["rim_width"]
        log.info("%s: localisation keeps %d of %d detected points", func,
                 int(mask.sum()), n_det)
    extent = st.get("extent") if kind == "hole" else None
    if kind == "hole" and p["max_variation"] is not None:
        # flatness gate: the smallest neighbourhood of a rim point is a (folded)
        # half-disc; one wrapped around a thin part is not (see Notes)
        n_det = int(mask.sum())
        mask &= st["variation"] <= p["max_variation"]
        log.info("%s: flatness gate keeps %d of %d detected points", func,
                 int(mask.sum()), n_det)
    if extent is not None and p["extent_width"] is not None:
        n_det = int(mask.sum())
        mask &= extent <= p["extent_width"]
        log.info("%s: strip extent keeps %d of %d detected points", func,
                 int(mask.sum()), n_det)
    if kind == "hole" and p["min_support"] > 0 and mask.any():
        # a border is a curve: drop detections without detected neighbours
        # along it (see Notes)
        det = np.flatnonzero(mask)
        support = build_tree(pts[det]).query_ball_point(
            pts[det], _SUPPORT_RADIUS * h, return_length=True) - 1
        mask[det[support < p["min_support"]]] = False
        log.info("%s: border support keeps %d of %d detected points", func,
                 int(mask.sum()), len(det))
    random_like = kind == "hole" and st["close"] >= _RANDOM_CLOSE
    if kind == "hole":
        log.info("%s: %.3g %% of the points have a neighbour closer than %.2g x the "
                 "median spacing: %s sampling", func, 100.0 * st["close"], _CLOSE_RATIO,
                 "random-like" if random_like else "mesh-like")
    if random_like and mask.any():
        # chance gaps of a random sampling: drop borders too small to be told
        # from them (see detect_hole_boundaries Notes)
        r_min = (p["min_radius"] if p["min_radius"] is not None
                 else _CHANCE_GAP_PER_LOG_N * np.log(len(pts)))
        det = np.flatnonzero(mask)
        radius = border_radius(pts[det], _SUPPORT_RADIUS * h) / h
        mask[det[radius < r_min]] = False
        log.info("%s: borders of radius >= %.3g h keep %d of %d detected points", func,
                 r_min, int(mask.sum()), len(det))
    if (kind == "hole" and not random_like and p["row_angle"] is not None
            and mask.any()):
        # a mesh-like sampling's border is a row of samples, each with an
        # empty side; the row is then followed along itself (see
        # detect_hole_boundaries Notes)
        n_det = int(mask.sum())
        row = border_gap(pts, st["near"]) > np.radians(p["row_angle"])
        mask &= row
        n_row = int(mask.sum())
        mask = track_border(pts, mask, row, _TRACK_LINK * h)
        log.info("%s: border row (angular gap > %.3g deg) keeps %d of %d detected "
                 "points; tracking along it adds %d", func, p["row_angle"], n_row, n_det,
                 int(mask.sum()) - n_row)
    spread = None
    if kind == "sharp" and p["min_angle"] > 0 and mask.any():
        # crease-angle gate: the code length ranks points by rarity, so a
        # cloud without creases still has a rare class; require the normals
        # to turn by a crease's angle (see detect_sharp_features Notes)
        spread = normal_spread(pts, mask, st["nrm"], tree=tree)
        n_det = int(mask.sum())
        mask &= spread >= p["min_angle"]
        log.info("%s: crease-angle gate (%.3g deg) keeps %d of %d detected points",
                 func, p["min_angle"], int(mask.sum()), n_det)
    if kind == "sharp" and p["crease_width"] is not None and mask.any():
        # code length × mean Pd (in h) over the larger half of the scales
        # (the small-scale Pd is dominated by noise); more neighbours for the
        # crease line when the data are noisy (see detect_sharp_features Notes)
        ridge = score * F[:, 3::4][:, len(ks) // 2:].mean(axis=1)
        sigma = noise_level(F)
        k_loc = localisation_k(sigma)
        log.info("%s: noise estimate %.3g h, crease neighbourhood k=%d", func, sigma, k_loc)
        cdist = crease_distance(pts, mask, ridge, h=h, k=k_loc, tree=tree)
        # on a regular sampling the crease is itself a row of samples, and
        # row_width replaces both widths (see detect_sharp_features Notes)
        regular = p["row_width"] is not None and st["nn_cv"] < _REGULAR_CV
        log.info("%s: nearest-neighbour CV %.3g: %s sampling", func, st["nn_cv"],
                 "regular" if regular else "irregular")
        limit = np.full(len(pts), float(p["row_width"] if regular else p["crease_width"]))
        if p["plane_width"] is not None:
            # two-plane crease model where it fits the neighbourhood as well as
            # the noise allows; the ridge-line estimate elsewhere (curved faces,
            # corners, rounded creases)
            k_pl = plane_k(sigma)
            pdist, prms = two_plane_distance(pts, mask, st["nrm"], h=h, k=k_pl,
                                             tree=tree)
            planar = np.isfinite(pdist) & (prms <= _PLANE_RMS0 + _PLANE_RMS_GAIN * sigma)
            log.info("%s: two-plane crease model (k=%d) fits %d of %d detected points",
                     func, k_pl, int(planar.sum()), int(mask.sum()))
            cdist = np.where(planar, pdist, cdist)
            limit[planar] = p["row_width"] if regular else p["plane_width"]
        n_det = int(mask.sum())
        mask &= cdist <= limit
        log.info("%s: localisation keeps %d of %d detected points", func,
                 int(mask.sum()), n_det)
    log.info("%s: threshold %.4g selects %d of %d points", func, T, int(mask.sum()),
             len(pts))
    return DetectionResult(mask=mask, score=score, threshold=float(T),
                           quality=mask.astype(np.float64), nnz=nnz, residual=resid,
                           scales=ks, dictionary=D, h=float(h), beta=beta,
                           crease_distance=cdist, border_distance=bdist,
                           crease_limit=limit if cdist is not None else None,
                           normal_spread=spread,
                           border_extent=extent)


@validate_params(*PARAMS_SHARP)
def detect_sharp_features(points, normals=None, *, crease_width: float | None = 0.7,
                          plane_width: float | None = 1.0,
                          row_width: float | None = 0.5,
                          min_angle: float = 25.0, otsu_scale: float | None = None,
                          n_scales: int = 10, k_min: int = 8,
                          k_max: int = 40, n_atoms: int = 100, coder: str = "omp",
                          alpha: float = 0.01, tol: float = 0.1, score: str = "l1",
                          beta: float | None = None, max_iter: int = 10,
                          max_train: int = 4000, seed: int | None = None
                          ) -> DetectionResult:
    """Detect points on sharp features (edges, corners) by the code length of
    their multi-scale covariance features on a learned dictionary (thesis §7.3).

    Parameters
    ----------
    points : (n, 3) float
        The cloud.
    normals : (n, 3) float, optional
        Accepted for the filter interface and validated, but not used: the
        normal of (7.4) is the PCA normal of each scale's neighbourhood.
    crease_width : float or None, default=0.7
        Localisation step (see Notes): keep a point above the threshold only
        if it lies within this many h of its estimated crease line.  None:
        off, ``mask = score > T`` as in (7.11).
    plane_width : float or None, default=1.0
        Width of the localisation step where the two-plane crease model fits
        (see Notes); None: the ridge-line estimate with ``crease_width``
        everywhere.
    row_width : float or None, default=0.5
        The localisation width on regularly sampled clouds, in place of both
        ``plane_width`` and ``crease_width`` (see Notes); None: those two
        whatever the sampling.
    min_angle : float, default=25.0
        Crease-angle gate in degrees (see Notes): a detected point is kept
        only if the PCA normals of its 32 nearest neighbours turn by at least
        this angle (``normal_spread``).  0: off.
    otsu_scale : float in (0, 1], optional
        With ``beta=None`` the threshold is ``otsu_scale`` times Otsu's
        split of f (see Notes).  None (default): 0.6 when the crease-angle
        gate and the localisation step are both on, 1 (Otsu's split, the
        thesis' automatic rule) otherwise.
    n_scales : int, default=10
        Neighbourhood sizes, geometrically spaced from ``k_min`` to ``k_max``.
    k_min, k_max : int, default=8, 40
        Smallest and largest neighbourhood (points, the point itself included).
    n_atoms : int, default=100
        Dictionary size S (thesis §7.4.1).
    coder : {"omp", "lasso_lars"}, default="omp"
        How every point is coded on the learned dictionary.
    alpha : float, default=0.01
        Lasso penalty λ (thesis §7.4.1), for ``coder="lasso_lars"``.
    tol : float, default=0.1
        OMP squared-residual target per feature, for ``coder="omp"``.
    score : {"l1", "count"}, default="l1"
        ``"l1"``: f = ‖α_j‖₁ + r, the ℓ1 code length plus the residual r;
        ``"count"``: f = ‖α_j‖₀ (7.8)-(7.9) plus ``r/(1+r)`` as a tie-break in
        [0, 1) -- the thesis' rule.
    beta : float in [0, 1], optional
        T = β·max f (7.10).  None (default): ``otsu_scale`` times Otsu's
        threshold on f.
    max_iter : int, default=10
        K-SVD iterations.
    max_train : int, default=4000
        Training-subsample size of the K-SVD.
    seed : int, optional
        Seeds the K-SVD subsample and initialisation.

    Returns
    -------
    DetectionResult
        ``mask`` = (f > T) (7.11) and, with the localisation step,
        ``crease_distance ≤ crease_limit`` (``plane_width`` where the
        two-plane model fits, ``crease_width`` elsewhere) and, with the
        crease-angle gate, ``normal_spread ≥ min_angle``; ``score`` = f.

    Raises
    ------
    PointCloudError
        Empty cloud, NaN/Inf, fewer than ``k_max + 1`` points, collinear points.
    InvalidParameterError
        A parameter out of range, or ``k_min > k_max``.

    Notes
    -----
    Features per scale (7.1)-(7.4): F = (λ0/h², λ0/λ2, σ = λ0/Σλ, Pd/h), with
    Pd = |(p_i − p̄)·n| and n the eigenvector of λ0; concatenated over the
    scales (§7.3.5), d = 4·n_scales.  Deviations from the thesis and why:

    * Weights of (7.1): uniform.  The printed weight exp(−d²/k²) mixes a length
      with a count; with lengths in h and k ≥ 8 it lies within a few percent of
      1, and uniform weights let all scales come from one sorted k-NN query by
      prefix sums (O(n·k_max) instead of ten queries).
    * Features are standardised per column before K-SVD: the raw columns
      differ by orders of magnitude (λ0 in h², ratios in [0, 1]) and would
      otherwise let one column own the dictionary.  The standardisation is
      robust and one-sided: z = max(0, (F − median)/s) with
      s = max(1.4826·MAD, 0.3·std) (the floor keeps the scale meaningful
      when most points are exactly flat and the MAD collapses).  All four
      features grow at a sharp feature (§7.3.1), so the bulk of smooth points
      maps to near-zero signals that need no atoms, and a point's code grows
      with how far, and at how many scales, it departs from the bulk: its
      rarity.  With a plain z-score the flat points sit at a non-zero common
      vector and the code length measured the distance to the *mean* (F1 on
      the synthetic cube 0.80 clean / 0.63 at 0.3h noise, against 0.85 /
      0.72 with this choice).
    * Score: ``score="l1"`` (default) uses the ℓ1 size ‖α_j‖₁ of the code
      -- the ℓ1 code length of (3.13), the thesis' own ‖α_j‖₁ of §7.3.3 --
      plus the residual; the atom count of (7.8) (``score="count"``) is an
      integer between 0 and a few atoms and ranks points more coarsely
      (best-threshold F1 on the synthetic cube 0.84 against 0.87).
    * Coding: the dictionary is learned by K-SVD (OMP with ⌊d/10⌋ atoms per
      training signal) on a seeded subsample of ``max_train`` points; every
      point is then coded by OMP until its squared residual is at most
      ``tol·d``, so the atom count is the number of atoms the point *needs*,
      the thesis' notion of rarity (§7.3.3).  ``coder="lasso_lars"`` gives the
      thesis' Lasso coding, ``½‖z − αD‖² + alpha‖α‖₁`` (the convention of
      ``sparse.lasso_lars``; the thesis' (3.7) without the ½ has λ = 2·alpha);
      it is several times slower and, measured on the synthetic cube, ranks
      points worse than the OMP count.
    * Threshold: Otsu by default, as the thesis suggests after Tran et al.
      2014 (§7.4.1), computed on the score winsorised at its 95th percentile
      (the few extreme scores of corners and tips would otherwise form the
      upper class alone; 0.95 rather than 0.98 since the localisation step
      below removes the extra band points a lower threshold admits: mean F1
      over 3 synthetic and 4 mesh-vertex CAD models at 0 and 0.3h noise 0.759
      at 0.98, 0.767 at 0.95); ``beta`` restores (7.10), T = β·max f.
    * Localisation (``crease_width``, not in the thesis): the code length
      marks every point whose largest neighbourhood (k_max = 40, a radius of
      about 3.5h) reaches the edge, a band several h wide, while the feature is
      a line -- on the benchmark the rule alone had recall 0.95 and
      precision 0.35-0.75.  Each detected point gets a crease estimate from
      its 16 nearest neighbours (more on noisy data, below) weighted by the
      squared ridge strength ``score × mean_s Pd_s`` (code length times the
      projected distance averaged over the larger half of the scales; it
      peaks on the crease and fades across it):
      their weighted centroid is a point of the crease and the principal axis
      of their weighted scatter its direction.  The point is kept when its
      distance to that line is at most ``crease_width`` h
      (``crease_distance``).  Measured on the cases above: mean F1 0.63 →
      0.77 (random-sampled synthetic parts 0.72 → 0.77, mesh-vertex models
      0.56 → 0.77, at 0.3h noise 0.60 → 0.69).  Alternatives measured and
      dropped: non-maximum suppression of the score or of the small-scale
      Pd among the 8-16 nearest neighbours (mesh models +0.17 but synthetic
      −0.03: it keeps one row, while the synthetic truth band is 2h wide);
      two mean-shift iterations of the crease point (no gain); exempting
      corners (non-linear weighted scatter) from the step (−0.01); Otsu on
      log or square-root scores (worse).  ``crease_width=None`` restores the
      plain rule (7.11).
    * Noise-aware localisation (data-driven, no parameter): the noise level
      σ̂ is estimated from the features themselves (``noise_level``: √ of the
      median λ0/h² at the smallest scale; ≈ 0.7σ for Gaussian noise σ along
      the normal, ~0 on clean data), and the crease line is estimated from
      ``16·(1 + 3σ̂)`` neighbours (``localisation_k``) instead of 16: a
      noisy crease needs more points to fix its line.  The ridge weight uses
      the projected distance of the larger half of the scales only (the
      small-scale Pd is mostly noise).  Measured on 13 models (5 synthetic,
      8 mesh-vertex) at 0 / 0.1h / 0.3h noise, mean F1: 0.3h 0.628 → 0.664
      (synthetic 0.739 → 0.777, mesh models 0.559 → 0.594); clean 0.792 →
      0.789; 0.1h synthetic 0.854 → 0.852, mesh 0.720 → 0.709.  Measured and
      dropped (mean F1, same cases): hysteresis -- seeds above 1.5-2× the
      Otsu threshold grown through the candidates along the 8-NN graph --
      (+0.005 at 0.3h, −0.005 clean); a neighbour-support or connected-
      component size filter (+0.015 at 0.3h, −0.01 clean); a threshold scaled
      by (1 + c·σ̂) (no gain once the neighbourhood adapts); Otsu on log(score)
      (0.40 overall: its split falls inside the bulk); winsorising at 0.90
      (clean +0.02, 0.3h −0.03); thinning to the crease row (drop a point when
      a neighbour within 0.5h along the crease is ≥ 0.5h closer to the line:
      mesh models +0.015, synthetic −0.01, since the synthetic truth is a
      band); a wider (0.8h) or narrower (0.6h) width (synthetic clean 0.893 /
      0.837 against mesh models clean 0.662 / 0.756: the two truths differ,
      see the benchmark notes).
    * Two-plane crease model (``plane_width``, not in the thesis): the
      ridge-weighted line above is a proxy (its centroid is pulled toward the
      point; median error 0.15-0.27h clean, 0.23-0.34h at 0.3h noise on the
      synthetic parts).  Where a detected point's neighbourhood is two faces,
      the crease is their intersection: the neighbours' PCA normals (the
      scale of 16 points) are split into two axis groups by 2-means, a
      least-squares plane is fitted to each and refined by 3 k-planes passes
      (each neighbour to the nearer plane), and the distance of the point to
      the planes' intersection line is measured (``two_plane_distance``;
      exact on clean planar faces, median error 0.15-0.24h at 0.3h noise).
      The model is used where it explains the neighbourhood to the noise
      level -- RMS residual to the nearer plane ≤ 0.05h + 1.2σ̂ (the noise
      floor a fit cannot beat plus a margin) and the planes ≥ 15° apart --
      and the point is kept within ``plane_width`` (1h) of the line;
      elsewhere (curved faces, rounded creases, corners) the ridge-line
      distance with ``crease_width`` (0.7h) applies (both ``row_width`` on
      regular sampling, below).  The fit uses ``32·(1 + 5σ̂)``
      neighbours (``plane_k``): a wider patch fixes a noisy plane better.
      The clean-data size was 24 until a coarse regular mesh showed its
      failure: on twelve (clean mesh vertices) 24 neighbours can hold the
      crease row, a parallel row and a few points of a third face, and two
      planes through such coincidentally coplanar subsets fit exactly (RMS
      1e-16 h) yet meet 1-3h from the true crease (86 of its 470 crease
      vertices dropped, F1 0.875; 0.969 with 32).  Mean F1 over the 5
      synthetic parts / 8 mesh models at noise 0, 0.1h, 0.3h for base sizes
      24 / 28 / 32 / 36 / 40: synthetic 0.954/0.912/0.829, 0.954/0.912/0.835,
      0.954/0.913/0.839, 0.953/0.913/0.843, 0.951/0.913/0.843; mesh
      0.759/0.746/0.610, 0.770/0.746/0.612, 0.770/0.744/0.613,
      0.769/0.741/0.608, 0.769/0.737/0.610.  Also tried: rejecting fits whose
      planes disagree with their members' PCA normals (> 25°): it rejects
      true creases, whose PCA normals are blended (synthetic clean 0.905).
      Benchmark mean F1 (5 synthetic parts / 8 mesh-vertex models) at noise
      0, 0.05h, 0.1h, 0.3h: synthetic 0.869 / 0.861 / 0.852 / 0.777 →
      0.867 / 0.862 / 0.857 / 0.813; mesh models 0.739 / 0.726 / 0.709 /
      0.594 → 0.746 / 0.717 / 0.694 / 0.595 (the mesh models lose at light
      noise where the vertex row next to the crease lies 0.7-0.85h from it,
      e.g. twelve, and gain on sharp-sphere and octa-flower).  Choices measured
      on cached scores (mean F1): width 0.7 / 0.9 (synthetic clean 0.813 /
      0.912, 0.3h 0.769 / 0.830; mesh clean 0.757 / 0.628 -- the two truth
      widths again); with an earlier normal split (sign of the second
      eigenvector): the model wherever defined, no residual test (0.3h mesh
      models 0.537), residual bounds 0.05 + 1.5σ̂ / 0.1 + 2σ̂ (0.553 / 0.532,
      against 0.573 with 1.2σ̂), a fixed 24-point fit (0.3h synthetic 0.747
      against 0.841 with the noise-grown size, width 0.9) or 64-point fit
      (clean synthetic 0.893 against 0.911: the fits swallow corners).
      (The benchmark figures of this bullet are for one width, 0.8h, on all
      samplings; the next bullet gives the adopted rule.)
    * Width by sampling (``row_width``, data-driven): what the feature points
      of a line are depends on how the surface is sampled.  On an irregular
      (random) sampling no sample lies on the crease and the feature is a
      band around it, here ±1h (``plane_width``).  On a regular sampling --
      mesh vertices, grids, whose sharp edges are themselves rows of
      samples -- the feature points are that row, and a band of ±1h would
      also take the neighbouring rows (on the mesh models they lie 0.5-0.85h
      from the crease); there the width is ``row_width`` = 0.5h, half a
      row spacing.  Regularity is measured, not assumed: the coefficient of
      variation of the nearest-neighbour distance (from the same k-NN query)
      is √(4/π − 1) ≈ 0.52 for a uniform random sampling of a surface
      (measured 0.52 on the synthetic parts, 0.41 at 0.3h noise) and below
      0.25 on regular meshes (0.00-0.25, also at 0.3h noise); the cloud is
      called regular below 0.35.  Meshes with strongly graded vertex density
      (rocker arm, sharp-sphere, octa-flower: 0.41-0.48) count as irregular.
      A local CV (each nearest-neighbour distance over the mean of its 16
      neighbours' ones) would call those three regular (0.22-0.32, random
      sampling 0.42-0.54) but was measured no better: mesh-model mean F1 at
      0 / 0.1h / 0.3h 0.771 / 0.745 / 0.625 → 0.779 / 0.744 / 0.606
      (octa-flower 0.3h 0.415 → 0.293).
      ``row_width=None`` applies ``plane_width`` to every cloud.  Measured
      on cached scores (mean F1 at 0 / 0.1h / 0.3h): one width 0.8h
      everywhere: synthetic 0.866 / 0.857 / 0.811, mesh models 0.746 /
      0.688 / 0.596; 1h / 0.5h by sampling: synthetic 0.953 / 0.913 / 0.827,
      mesh models 0.759 / 0.744 / 0.612; 0.8h / 0.5h: 0.866 / 0.857 / 0.811
      and 0.764 / 0.749 / 0.610; 1h / 0.6h: mesh 0.756 / 0.735 / 0.619.
      Full benchmark with the adopted 1h / 0.5h (noise 0 / 0.05h / 0.1h /
      0.3h): synthetic 0.954 / 0.934 / 0.912 / 0.829, mesh models 0.759 /
      0.762 / 0.746 / 0.610 (before the two-plane model: 0.869 / 0.861 /
      0.852 / 0.777 and 0.739 / 0.726 / 0.709 / 0.594).
      This choice follows the two benchmark truths (1h band on the random
      synthetic parts, the vertices of sharp mesh edges on the mesh models),
      which encode the same two notions.
      On a regular cloud ``row_width`` also replaces ``crease_width`` where
      the ridge-line estimate applies (corners, curved faces, creases the
      two-plane model does not fit): the same argument holds there, and
      0.7h kept the second rows beside corners and along the curved creases.
      Benchmark (F1 at 0 / 0.05h / 0.1h / 0.3h, ridge width 0.7h → 0.5h):
      fandisk 0.877 / 0.858 / 0.840 / 0.720 → 0.912 / 0.897 / 0.877 / 0.735,
      twelve 0.969 / 0.994 / 0.967 / 0.784 → 0.982 / 1.000 / 0.996 / 0.820,
      smooth-feature 0.976 / 0.941 / 0.924 / 0.837 → 0.978 / 0.971 / 0.967 /
      0.865, block +0.005 to +0.009, trim-star 0.822 / 0.814 / 0.803 / 0.672
      → 0.823 / 0.803 / 0.795 / 0.640 (the one loss: its thin tips are
      rounded at 0.3h noise); mesh-model mean 0.771 / 0.760 / 0.745 / 0.625
      → 0.778 / 0.768 / 0.759 / 0.632 (the three irregular models and the
      random synthetic parts are unchanged).
    * Crease-angle gate (``min_angle``, not in the thesis): the code length
      ranks points by how rare their features are and Otsu's threshold
      always finds a rare class, so without a gate a cloud with no crease
      at all gets one: 25 % of a smooth sphere (5085 of 20000 points), 32 %
      of a square patch of plane, 11-17 % of a bumpy plane.  A crease is
      where the normal turns by a finite angle within a few spacings, so a
      detected point is kept only if the PCA normals (16-NN) of its 32
      nearest neighbours turn by at least ``min_angle`` = 25°
      (``normal_spread``: θ = arccos(1 − 2λ_mid) of their axis scatter,
      exact for two equal groups).  Measured on the 20000-point shapes:
      on true crease points of every benchmark model the spread is ≥ 29°
      at the 5th percentile (rocker arm; 40-57° on the others), on a sphere
      ≤ 6.7° clean and ≤ 22° at 0.3h noise (99th percentile), 0° on a
      clean plane.  Points kept on sphere / plane / bumpy plane at noise 0,
      0.1h, 0.3h for gates 0 / 15 / 20 / 25 / 30°: sphere 5085, 4242, 3390
      → 0, 0, 541 / 0, 0, 61 / 0, 0, 6 / 0, 0, 0; plane 6497, 4220, 3664 →
      0, 0, 247 / 0, 0, 44 / 0, 0, 18 / 0, 0, 18; bumpy plane 2179, 3900,
      3451 → 472, 482, 685 / 146, 157, 167 / 37, 31, 45 / 1, 0, 3.  Benchmark
      mean F1 (noise 0 / 0.1h / 0.3h) for the same gates: synthetic
      0.954 / 0.913 / 0.839 → 0.954 / 0.914 / 0.867, 0.954 / 0.914 / 0.875,
      0.954 / 0.914 / 0.877, 0.954 / 0.914 / 0.877; mesh models 0.770 /
      0.744 / 0.613 → 0.770 / 0.744 / 0.619, 0.771 / 0.745 / 0.622, 0.771 /
      0.745 / 0.625, 0.769 / 0.745 / 0.626 (rocker arm, the model with the
      gentlest creases, peaks at 20-25° clean).  25° sits below the 30°
      dihedral rule of the benchmark truths; a user who wants gentler creases
      lowers it, and ``min_angle=0`` restores the rule without the gate.
    * Threshold below Otsu's split (``otsu_scale``, not in the thesis): Otsu
      separates the rarest codes, but crease points are not all rare -- on
      models with many crease points (sharp-sphere, octa-flower: 10 % of
      the vertices) the dictionary learns half of them well, and only 586
      of sharp-sphere's 1108 crease vertices score above the split.  With the
      crease-angle gate and the localisation on, precision no longer rests
      on the threshold (a smooth sphere / bumpy plane keeps 0-0.03 % /
      0.18-0.32 % flagged down to 0.6 of the split), so the threshold is
      lowered to 0.6 of it.  Mean F1 for scales 1 / 0.8 / 0.6 / 0.45
      (benchmark models, noise 0 and 0.3h): synthetic parts clean 0.954 /
      0.967 / 0.975 / 0.979, 0.3h 0.877 / 0.886 / 0.890 / 0.891; mesh models
      clean 0.778 / 0.791 / 0.798 / 0.797, 0.3h 0.632 / 0.639 / 0.634 /
      0.624 (sharp-sphere clean 0.500 → 0.593, octa-flower 0.529 → 0.626,
      star 0.899 → 0.947; the loss: the fandisk mesh 0.912 → 0.890, whose
      extra candidates beside the crease row pass the 0.5h row width).  On
      a held-out sampling (the 5 synthetic parts, 12000 points, sampling
      seed 1, noise seed 2, K-SVD seed 3; noise 0 / 0.1h / 0.3h) scales 1 /
      0.8 / 0.6 gave mean F1 0.899 / 0.917 / 0.928 (star 0.864 → 0.934
      clean).  The lower split of a two-level Otsu (0.18-0.39 of the
      split) was also tried: synthetic clean 0.975, but the fandisk mesh
      0.884 / 0.691 (clean / 0.3h).
      Hole boundaries keep Otsu's split: their masks did not change with
      the scale (the strip and support tests decide there).

    References
    ----------
    Tran et al. 2014, "Automatic sharp feature detection", Otsu threshold on the
    projected distance.  Pauly, Keiser & Gross 2003 (surface variation).

    Examples
    --------
    >>> from pcprep.baselines.datasets import make_shape
    >>> s = make_shape("cube", n=4000, seed=0)
    >>> r = detect_sharp_features(s.points, seed=0)
    >>> bool(r.mask.shape == (4000,) and 0 < r.mask.sum() < 4000)
    True
    """
    p = dict(
        crease_width=crease_width, plane_width=plane_width, row_width=row_width,
        min_angle=min_angle, otsu_scale=otsu_scale, n_scales=n_scales, k_min=k_min,
        k_max=k_max,
        n_atoms=n_atoms, coder=coder,
        alpha=alpha, tol=tol, score=score, beta=beta, max_iter=max_iter,
        max_train=max_train, seed=seed)
    return _detect(points, normals, p, "detect_sharp_features", "sharp")


@validate_params(*PARAMS_HOLES)
def detect_hole_boundaries(points, normals=None, *, min_shift: float = 0.2,
                           rim_width: float | None = 2.0,
                           extent_width: float | None = 1.4,
                           max_variation: float | None = 0.13,
                           min_support: int = 2, min_radius: float | None = None,
                           row_angle: float | None = 90.0,
                           n_scales: int = 10, k_min: int = 16,
                           k_max: int = 80, n_atoms: int = 100, coder: str = "omp",
                           alpha: float = 0.01, tol: float = 0.3, score: str = "l1",
                           beta: float | None = None, max_iter: int = 10,
                           max_train: int = 4000, seed: int | None = None
                           ) -> DetectionResult:
    """Detect points on hole rims and open borders by the rarity of the codes
    of their multi-scale border features (thesis §7.3.1, §7.3.4).

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float, optional
        Validated, not used (the PCA normal of each scale is used).
    min_shift : float, default=0.2
        Geometric gate (see Notes): a detected point must have a tangential
        centroid shift of at least ``min_shift`` times the neighbourhood
        radius, averaged over the scales.  0 disables it.
    rim_width : float or None, default=2.0
        Localisation step (see Notes): keep a detected point only if its
        estimated distance to the border is at most this many h.  None: off.
    extent_width : float or None, default=1.4
        Strip localisation (see Notes): keep a detected point only if its
        ``strip_extent`` -- the distance, in h, to the outermost neighbours
        toward the border -- is at most this.  None: off (and the earlier
        two-level Otsu threshold is used).
    max_variation : float or None, default=0.13
        Flatness gate (see Notes): keep a detected point only if the surface
        variation λ0/(λ0+λ1+λ2) of its smallest neighbourhood (k_min points)
        is at most this.  None: off.
    min_support : int, default=2
        Border support (see Notes): keep a detected point only if at least
        this many other detected points lie within 3h of it.  0: off.
    min_radius : float or None, default=None
        Smallest hole (see Notes): the detected points are linked into
        borders (chains of points at most 3h apart, ``border_radius``); on
        a random-like sampling (see Notes) a border whose radius -- the
        largest distance of its points from their centroid -- is below this
        many h is dropped.  None: 0.3·ln(n) h (2.97h at 20K points, 4.1h at
        1M), just above the largest chance gap of a random sampling of n
        points.  Mesh-like clouds keep every border.  0: off.
    row_angle : float or None, default=90
        Border row (see Notes): on a mesh-like sampling a detected point is
        kept only if its ``k_min`` nearest neighbours, projected on their
        tangent plane, leave an empty angle wider than this many degrees
        around it (``border_gap``, on the neighbours of the k-NN query of the
        scales), and the other points with such an angle
        that are chained to a kept one (steps ≤ 1.5h) are added
        (``track_border``).  Random-like clouds are not affected.  None: off.
    n_scales : int, default=10
        Neighbourhood sizes, geometrically spaced from ``k_min`` to ``k_max``.
    k_min, k_max : int, default=16, 80
        Smallest and largest neighbourhood (points, the point itself included).
    n_atoms : int, default=100
        Dictionary size S (thesis §7.4.1).
    coder : {"omp", "lasso_lars"}, default="omp"
        How every point is coded on the learned dictionary.
    alpha : float, default=0.01
        Lasso penalty λ (thesis §7.4.1), for ``coder="lasso_lars"``.
    tol : float, default=0.3
        OMP squared-residual target per feature, for ``coder="omp"``.
    max_iter : int, default=10
        K-SVD iterations.
    max_train : int, default=4000
        Training-subsample size of the K-SVD.
    seed : int, optional
        Seeds the K-SVD subsample and initialisation.
    score : {"l1", "count"}, default="l1"
        ``"l1"``: ‖α_j‖₁ + residual (default, see Notes); ``"count"``: the atom
        count of (7.8) with the residual tie-break.
    beta : float in [0, 1], optional
        T = β·max(score); None (default) = Otsu.

    Returns
    -------
    DetectionResult

    Raises
    ------
    PointCloudError, InvalidParameterError
        As ``detect_sharp_features``.

    Notes
    -----
    Features per scale (7.5)-(7.7): epv = |λ2 − 2λ1|/λ2, density
    k h²/(π r²), centroid shift ‖p̄ − p_i‖_t / r.  Deviations and why:

    * The density (7.6) is printed k/(p_i·r²), a typo for k/(π r²).  Here r is
      the distance to the k-th neighbour (the radius of the scale's
      neighbourhood, free from the sorted query) instead of the largest
      distance to the centroid; at a rim both grow by about √2.
    * The centroid shift is taken in the tangent plane (component orthogonal
      to the scale's PCA normal) and divided by r: at a rim the shift is
      tangential anyway, while at a sharp crease the shift points along the
      normal; this keeps creases from being called holes.
    * The rule printed in (7.12)-(7.13), f < β·min f, selects nothing for
      β ≤ 1 (f ≥ min f always).  We keep its idea -- boundary points are the
      rare codes -- as follows: each column is oriented so that larger means
      more border-like (epv and density drop at a border, the shift grows,
      §7.3.1), robustly standardised (median, 1.4826·MAD) and clipped at 0
      (as for edges), so
      the bulk of interior points have near-zero signals; a point's rarity is
      then the ℓ1 size of its code on the K-SVD dictionary, ‖α_j‖₁ (the
      ℓ1 code length of (3.13)), plus its residual, thresholded like (7.10) --
      by Otsu, or T = β·max.  The atom count alone does not separate rims
      (measured ROC AUC ≈ 0.45-0.5 on holed spheres): interior and rim vectors
      need similar numbers of atoms; the rims need *larger* coefficients.
      ``score="count"`` keeps the thesis' count reachable.
    * Automatic threshold: Otsu on the rarity score.  Without the strip
      localisation (``extent_width=None``) Otsu's upper class still holds the
      tail of the interior (rims are a few percent of the points) and Otsu is
      applied a second time inside it (its rare part), as before that step
      existed.  With it, one Otsu split is used: the second split cut into
      the rims (long borders: disc recall 0.73) and moved with the K-SVD
      seed (disc F1 0.819 / 0.845 at seeds 0 / 1), while the interior tail
      it removed is now removed by the geometric tests below.
    * Geometric gate ``min_shift``: the rarity rule always selects the tail
      of the score, even on a closed surface (on a closed cube 11 % of the
      points, its creases and corners).  A boundary point has a one-sided
      neighbourhood: its tangential centroid shift is about 0.42 r for an
      exact half-disc, and near 0 inside a surface.  The gate requires the
      shift / r averaged over the scales to be at least 0.2.  (It first used
      the largest scale alone: closed-cube false positives 11 % → 0.7 %,
      sphere 0.70 → 0.86, cube 0.58 → 0.76.  But a hole narrower than the
      largest neighbourhood, about 5h across, is spanned by it and its shift
      falls: on the real bunny's own small bottom holes that gate dropped
      107 of the 223 rim vertices, and on a plane with holes of radius 3h it
      kept 9 % of their rims; averaged over the scales, the smaller scales
      keep the evidence: 55 %, and bunny 0.574 → 0.768.)  With the
      defaults, a closed cube of 8000 / 20000 points gets 0.05 % / 0.13 %
      of its points flagged (0.15 % / 0.34 % without the gate; 1.9 % /
      1.8 % without the strip test, i.e. two-level Otsu and a 1.5h rim
      width).
    * Larger scales than for edges (16-80 points): the border signal is a
      first-order moment, noisy at small k.
    * Localisation ``rim_width`` (not in the thesis): the detected band is as
      wide as the largest neighbourhood.  A k-NN neighbourhood at distance d
      from a straight border is a disc of radius r missing the segment beyond
      the border; its centroid shift is r·g(d/r) with g known in closed form
      (4/(3π) at d = 0, 0 at d = r).  Inverting g at every scale and taking
      the median gives a border distance in h (``border_distance``); points
      beyond ``rim_width`` are dropped.  Measured on the 9 benchmark cases
      (with the two-level Otsu and the largest-scale gate, 1.5h): mean F1
      0.707 → 0.737 (holed synthetic parts 0.77 → 0.81, the real bunny with
      its own bottom holes 0.43 → 0.56).  The estimate refers to the
      continuum border, which lies about half a spacing beyond the outermost
      samples (median 0.5h on points within 0.25h of the true border of the
      randomly sampled parts and of the cut bunny), and it depends on the
      density of the neighbours (a density gradient shifts the centroid too:
      on the non-uniform cow 66 % of the interior has an estimate ≤ 1.5h).
      With the strip test below it is a loose second check, at 2h = the
      strip width plus that half-spacing offset (mean F1 0.790 at 1.5h,
      0.795 at 2h, 0.795 off).
    * Strip localisation ``extent_width`` (not in the thesis, data-driven,
      no per-case parameter): where the surface ends is read from the
      samples themselves rather than from a model of their centroid.  For
      each point, u is the tangential direction opposite to its centroid
      shift at the largest scale (toward the border); its k_max neighbours
      within 1.5h of the line through the point along u are projected on u,
      and, walking outward, the first empty stretch longer than 2.5h ends
      the surface; the distance to the last neighbour before it is
      ``strip_extent`` (0 on the outermost row, about the neighbourhood
      radius, 4-5h, inside a surface).  It does not depend on the
      neighbours' density, only on where they stop; the strip keeps a curved
      rim from counting as near (the farthest projection over the whole
      neighbourhood gave a median 2.3-2.5h on the rims of the 8h holes of
      the synthetic parts: the rim bends 1.6h toward the hole within 5h),
      and the gap rule keeps the
      far side of a hole narrower than the neighbourhood from counting as
      surface (the farthest projection in the strip gave 4.4h on the own
      bottom-hole rims of the real bunny).  A point is kept when its extent
      is at most 1.4h: the rim truth is a band of 1.5h from the border and
      the outermost samples lie a fraction of a spacing inside it.  On the
      disc the extent correlates 0.93 with the true border distance
      (within 4h), every point within 0.75h of the border is kept and 0.7 %
      of the interior passes.  Measured on the 9 benchmark cases (mean F1;
      before this step 0.737, angle gap 0.726): strip 1h / gap 2h with the
      earlier gate and threshold 0.759 (two-level Otsu) / 0.773 (one Otsu);
      strip 1.5h / gap 2.5h 0.778, with the scale-averaged gate 0.790 (rim
      width 1.5h), 0.795 (2h, adopted); extent widths 1.2 / 1.3 / 1.4 /
      1.5 / 1.6h: 0.787 / 0.792 / 0.795 / 0.796 / 0.793; gate thresholds
      0.15 / 0.18 / 0.22 / 0.25: 0.773 / 0.791 / 0.793 / 0.771; the gate on
      the largest shift over the scales instead of the mean (0.70: the small
      scales are noisy) or the largest scale at 0.1 / 0.15 (0.775 / 0.784, rim width 2h);
      no gate (0.74-0.79: random sampling leaves an empty 2.5h stretch in
      the strip of some interior points).  Same means at K-SVD seeds 0 and 1
      (0.795 / 0.795; the earlier rule 0.737 / 0.741).
    * Sampling regularity (measured, not adopted): unlike the sharp edges,
      a width chosen by the nearest-neighbour CV (``_REGULAR_CV``) does not
      help here.  Extent width 1.0 / 0.8 / 0.5h on regular clouds (mesh
      vertices; 1.4h on random ones): mean 0.793 / 0.778 / 0.743.  The
      regular clouds of the benchmark carry two truths: the border-vertex
      row on the natural mesh borders (face range map, bunny's own holes:
      a narrower width helps, 0.768 → 0.827 at 1h on the bunny) and a 1.5h
      band on the holes cut into the bunny mesh (0.915 → 0.845 at 1h, 0.60
      at 0.5h).  The ragged border of the range scan also tilts u, so even
      its outermost row does not reach extent ≈ 0 everywhere (face 0.77 at
      1.4h, 0.66 at 0.5h).  The benchmark has since given the cut meshes the
      row truth too (next bullet), and the row is found by the border-row
      test rather than by a width.
    * Border row ``row_angle`` (not in the thesis): on mesh vertices and range
      grids the border is itself a row of samples (a mesh's border is the
      vertices of its boundary edges), while the steps above keep a band
      about two rows wide (a 60 × 60 grid plane: precision 0.53 against its
      border row).  A sample of the row has an empty side: its ``k_min``
      nearest neighbours, projected on their tangent plane, leave an angle
      of about π around it (3π/2 at a convex corner), the row behind it
      sees the row in front (≤ π/4 inside a square grid).  So a detected
      point is kept only if that largest angle exceeds ``row_angle`` = 90°,
      the threshold of PCL's boundary criterion (``border_gap``; the
      classic ``angle_gap`` baseline applies the same criterion to every
      point with k = 50).  The grid plane and a grid graded 1 → 4 in both
      directions: exactly their border rows.  Against the border-vertex row
      (the benchmark's mesh truth), before → after: bunny with three cut
      holes 0.983 → 0.994, cow with three cut holes 0.493 → 0.633, face
      range map 0.776 → 0.805, the 35,947-vertex bunny's own holes 0.842 →
      0.864, nicolo 14,846 / 50,419 vertices 0.659 → 0.717 / 0.809 →
      0.895 (mean 0.760 → 0.818).  "Before" is the outer-row test it
      replaces: a detected point was dropped when another detected point
      lay 0.6h further out, inside a cone behind it; on top of the angle
      test it gains nothing (6-case mean 0.818 vs 0.817), and it could not
      see the second row behind a border with long edges (nicolo 14,846:
      border edges 0.7-2.2h, its second row 0.35-1.1h inside, precision
      0.50 for ours and the angle gap alike).  Sensitivity, mean over the
      six: 72° / 90° / 108° / 135°: 0.775 / 0.818 / 0.826 / 0.769; the
      default is PCL's value, not the best one here.  Random-like clouds
      are not tested: their truth is a band (about two rows at 1.5h), and the test would
      keep its outer edge only (seven random-sample cases, mean 0.880 →
      0.800).
    * Border tracking (not in the thesis): the code-length rule misses
      stretches of a border that it does not find rare enough (on the face
      range map's ragged scan border, 23 % of the border vertices with every
      step after the threshold off), so the row test above leaves recall at
      0.70 there.  The row is followed along itself as in Canny's hysteresis:
      every sample with an empty angle > ``row_angle`` is a candidate,
      candidates closer than 1.5h are chained, and a chain that holds a
      kept detection is kept whole (``track_border``).  Candidates alone
      would be the angle-gap criterion at k = 16, which flags chance gaps and
      thin parts everywhere; the chains only go where the code found a
      border.  Before → after (the six mesh-vertex cases): cow with cut
      holes 0.633 → 0.733, face 0.805 → 0.849, bunny's own holes 0.864 →
      0.903, cut bunny 0.994 (same), nicolo 14,846 / 50,419 0.717 → 0.705
      / 0.895 → 0.890 (their second rows behind long border edges join the
      chains); mean 0.818 → 0.846.  Link 1.0 / 1.25 / 1.5 / 2.0h: mean
      0.835 / 0.837 / 0.846 / 0.809 (at 2h the chains cross the cow's thin
      parts, 0.534).  The closed cow: 1.7 % → 2.7 % of its points flagged.
      Cost: one 16-NN angle per point of a mesh-like cloud (0.27 s on the
      85K-point face).
    * Mesh-like or random-like sampling: the row test above and the
      smallest-hole test below depend on whether the samples form rows or
      clump like a random (Poisson) sampling, which leaves chance gaps.  A
      random sampling puts about 6 % of the points closer than 0.3 × the
      median nearest-neighbour distance to their nearest neighbour
      (measured 5.9-6.2 % on the synthetic parts), a mesh almost none:
      0 % on pymeshlab's bunny and face, 0.4 % on its cow, 0.5 % on nicolo
      14,846 -- also when its spacing is graded: the cow's
      nearest-neighbour CV is 0.53, that of a random sampling (0.52), so
      the CV rule of the sharp detector (``_REGULAR_CV``) calls it
      irregular.  A cloud with at least 1 % such close pairs is random-like
      (``_RANDOM_CLOSE``; the sharp-sphere CAD mesh, whose creases are
      lined with slivers, has 2.6 % and would be).  The cow is the one
      benchmark case the choice moves: as random-like (CV rule) 0.493,
      mesh-like 0.633 (row test, before the tracking); it loses its
      smallest-hole test with it (0.645 with both, measured with the
      baseline's normals), and its closed mesh drops from 5.6 % to 1.7 %
      of its points flagged.
    * Flatness gate ``max_variation`` (not in the thesis): a neighbourhood that
      wraps around a part thinner than itself ends where the part ends, so
      its centroid shifts like a rim's.  pymeshlab's closed 2,903-vertex cow
      (legs, ears and muzzle 2-4h thick) got 10.4 % of its points flagged.
      The smallest neighbourhood (k_min) of a rim point is a flat half-disc,
      or half a disc folded along a crease the rim crosses: surface
      variation 0.014 / 0.056 / 0.128 / 0.222 for a fold of 30 / 60 / 90 /
      120 degrees (computed for uniform samples).  The default, 0.13, keeps
      rims across creases of up to 90 degrees.  Measured (gate at 0.05 /
      0.07 / 0.10 / 0.13 / off): closed cow flagged 1.7 / 2.3 / 4.9 / 6.8 /
      10.4 %, closed star 0.26 / 0.46 / 0.80 / 1.20 / 1.78 %; the holed cow
      F1 0.475 / 0.479 / 0.451 / 0.443 / 0.394; the two benchmark cases
      whose holes sit on creases lose 0.03 / 0.012 / 0 / 0 / 0 (cube) and
      0.015 / 0.005 / 0 / 0 / 0 (fandisk); every other case moves by at
      most 0.001.  The gate at the largest scale instead (0.07) costs the
      crease cases 0.083 / 0.024 and leaves the cow at 0.397.
    * Border support ``min_support`` (not in the thesis): the point-wise tests
      above still pass a few lone interior points where random sampling
      leaves an empty stretch in the strip (0.13 % of a closed 20K-point
      cube, 25-30 points of each holed synthetic part, 20-40h from any
      border).  A border is a curve: a point on it has detected neighbours
      along it on both sides, at about h spacing.  Most of those interior
      points have 0-1 detected points within 3h (a few form clusters of
      3), rim points a median of 7 (1 % have 3 or fewer).  A detection is kept when at least 2 others lie within 3h
      (one on each side, allowing a missed sample).  Measured on the 11
      benchmark cases (mean F1 0.804 → 0.820; synthetic parts +0.02 to
      +0.04, e.g. cube 0.837 → 0.862, crease cases 0.830 / 0.815 → 0.861 /
      0.847; face range map 0.771 → 0.762, whose tiny islands lose their
      rims); closed cube / sphere / fandisk flagged 0.13 / 0.10 / 0.10 % →
      0.03 / 0.05 / 0.00 %.  At least 3 within 3h: 0.819; 4: 0.811; 2 within
      2h: 0.812.  With noise (holed cube / sphere / fandisk at 0.3h): F1
      0.848 / 0.898 / 0.839 → 0.861 / 0.913 / 0.850.
    * Smallest hole ``min_radius`` (not in the thesis): a uniform random
      sampling leaves empty patches by chance, and their rims pass every
      point-wise test above.  Their number grows with n -- about 0.035 % of
      the points of a closed random sphere or cube at 300K-1M points, in
      clusters of 5-9 -- while a hole of fixed size in h keeps its rim, so
      at 1M points they swamp it (fandisk with three 8h holes: 578
      detections for 242 rim points, F1 0.53).  The detections are linked
      into borders (chains with gaps ≤ 3h; ``border_radius``), and a border
      is kept if its radius, the largest distance of its points from their
      centroid, reaches ``min_radius``.  The largest chance border measured
      on closed random spheres and cubes (1-4 seeds each): 1.2h at 5K
      points, 2.3h at 20K, 2.2h at 80K, 3.1h at 300K, 3.4-3.5h at 1M (also
      the holed fandisk); its upper envelope is about 0.3·ln n − 0.65 (20K,
      300K and 1M lie on it, 5K and 80K below), so the default
      is 0.3·ln(n) h, 0.65h above it (2.3h at 2K, 2.97h at 20K, 4.1h at
      1M, 4.8h at 10M).  A hole of radius R gives a border of radius about
      R + 0.7h (measured 3.6-4.3h for R = 3h), so holes down to about
      0.3·ln(n) − 0.7 h are reported.  The test applies only to random-like
      sampling ("Mesh-like or random-like sampling" above; the numbers here
      were measured with the CV rule, nearest-neighbour CV ≥ 0.35): a mesh
      has no chance gaps, and a one-vertex hole in a range grid is a real
      hole.  Measured: fandisk 1M with three 8h
      holes F1 0.529 → 0.923, cube 200K 0.719 → 0.857 (a fixed 4h: 0.923 /
      0.857); closed random sphere 1M 339 false detections → 0, closed
      20K sphere / cube 10 / 6 → 0; the 11 benchmark cases mean F1 0.820 →
      0.825 (cube 0.862 → 0.868, sphere 0.896 → 0.909, cube on creases
      0.861 → 0.873, cow 0.454 → 0.465; face range map and the 35,947-vertex
      bunny are regular and unchanged), where a fixed 4h would have cost
      the cow 0.02 and, applied to regular clouds too, the face 0.026.
    * Direction u: from the largest scale.  From the 30-point scale it
      follows the raggedness of a scan border better but is noisier inside
      (mean F1 0.765), and the smaller of the two extents 0.783.
    * Cost: one sort of the k_max strip projections per point (the
      neighbours come from the same k-NN query, no Python loop per point);
      in the features benchmark the 85K-point face range map takes 2.7 s
      instead of 1.5 s, the 20K-point synthetic parts 0.8-1.0 s instead of
      0.5-0.8 s.
    """
    p = dict(
        min_shift=min_shift, rim_width=rim_width, extent_width=extent_width,
        max_variation=max_variation, min_support=min_support,
        min_radius=min_radius, row_angle=row_angle, n_scales=n_scales, k_min=k_min,
        k_max=k_max,
        n_atoms=n_atoms, coder=coder,
        alpha=alpha, tol=tol, score=score, beta=beta, max_iter=max_iter,
        max_train=max_train, seed=seed)
    return _detect(points, normals, p, "detect_hole_boundaries", "hole")
