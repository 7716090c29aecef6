"""
saliency.py
-----------
Point-cloud saliency by local sparse coding and the MDL principle, thesis
chapter 5, eqs (5.2)-(5.7): each neighbourhood's mean descriptor (normal,
Gaussian curvature, global distinctness) is Lasso-coded against the mean
descriptors of the neighbourhoods at the ends of rays cast in its tangent plane;
the coding residual (with ``measure="mdl"`` times the code's sparsity) is the
neighbourhood's saliency, accumulated over the neighbourhoods that contain each
point.  One k-NN query serves every step; the passes are vectorised over points
and chunked.  The decisions behind each rule, with their measurements, are in
docs/decisions/saliency.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from . import _kernels
from ._params import Param, preset_param, validate_params
from ._validation import PointCloudError, as_normals, as_points, check_spread
from .lasso_batched import lasso_batched
from .neighbors import (SPACING_K, build_tree, centered, leaf_chunks, orient_normals_mst,
                        query_settled,
                        spacing_from_rows, tile_exact)

log = logging.getLogger("pcprep")

#: points per chunk of the neighbour passes
CHUNK = 16_384
#: fewest points the filter accepts (a quadric needs 6 neighbours)
MIN_POINTS = 10
#: coordinate-descent sweeps and tolerance of the Lasso (5.6); the measures used
#: (‖α‖₀ with a 1e-10 threshold, the residual) are stable long before this
LASSO_ITER = 32
LASSO_TOL = 1e-7

#: the method as printed (§5.3): the MDL product (5.7), mean accumulation, the
#: thesis' λ = 0.9 and the density- and curvature-adaptive radius of Mitra &
#: Nguyen (2003), here between 2h and 4h (k_max wide enough to hold 4h)
THESIS = {"measure": "mdl", "accumulation": "mean", "alpha": 0.9,
          "adaptive_radius": True, "radius": 4.0, "k_max": 64}

#: Mitra & Nguyen (2003): r = ((c1 σ/√(ερ) + c2 σ²)/κ)^(1/3); the thesis does not
#: give the constants, these are c1 = 1, c2 = 4, ε = 0.1; the density ρ is read
#: at the 15th neighbour, as their iteration starts; the smallest radius 2h keeps
#: the quadric fit well posed
MN_C1, MN_C2, MN_EPS, MN_K, MN_MIN_RADIUS = 1.0, 4.0, 0.1, 15, 2.0

PARAMS = (
    Param("radius", float, low=1.0, high=50.0, unit="h"),
    Param("n_rays", int, low=3, high=32, unit="count"),
    Param("alpha", float, low=0.0, high=100.0, closed="right"),
    Param("measure", str, choices=("residual", "mdl")),
    Param("accumulation", str, choices=("quantile", "mean")),
    Param("acc_quantile", float, low=0.0, high=1.0, unit="fraction", advanced=True),
    Param("k_max", int, low=8, high=512, unit="count", advanced=True),
    Param("adaptive_radius", bool, advanced=True),
    preset_param({"thesis": THESIS}),
)


@dataclass(frozen=True)
class SaliencyResult:
    """Result of :func:`saliency_sparse_mdl`.

    Attributes
    ----------
    saliency : (n,) float
        Point saliency in [0, 1] (accumulated S_T divided by its maximum).
    neighbourhood_saliency : (n,) float
        S_T(N_g(p_i)) of eq. (5.7) before accumulation, in [0, 1].
    sparsity : (n,) int
        ‖α‖₀ of each neighbourhood's code (S_M).
    residual : (n,) float
        Reconstruction residual S_I (the normal block counted by its Euclidean length).
    descriptors : (n, 5) float
        Neighbourhood descriptors F̄_i = (n̄, K̄ r², d̄).
    normals : (n, 3) float
        The oriented unit normals used in the descriptor.
    curvature : (n,) float
        Gaussian curvature K of the quadric fits, in 1/length² of the input.
    atoms : (n, n_rays) int32
        Index of the point whose neighbourhood is each atom.
    h : float
        Average spacing of the input.
    radius : float or (n,) float
        Neighbourhood radius r in input units (per point with ``adaptive_radius``).
    n_unconverged : int
        Lasso problems not certified optimal within ``LASSO_ITER`` sweeps (their
        atoms are near-duplicates).
    """

    saliency: np.ndarray
    neighbourhood_saliency: np.ndarray
    sparsity: np.ndarray
    residual: np.ndarray
    descriptors: np.ndarray
    normals: np.ndarray
    curvature: np.ndarray
    atoms: np.ndarray
    h: float
    radius: float | np.ndarray
    n_unconverged: int


@dataclass(frozen=True)
class _Hood:
    """Capped radius neighbourhoods: ``idx[i, :count[i]]`` lie within r (sorted by
    distance, the point itself first)."""

    idx: np.ndarray  # (n, k) int32
    count: np.ndarray  # (n,) int

    def valid(self, s: int, e: int) -> np.ndarray:
        return np.arange(self.idx.shape[1])[None, :] < self.count[s:e, None]

    def mean(self, values: np.ndarray) -> np.ndarray:
        """Mean of ``values`` (n, ...) over every neighbourhood."""
        if _kernels.ENABLED:
            v = np.ascontiguousarray(values, dtype=np.float64).reshape(len(values), -1)
            parts = _kernels.run_chunks(lambda s, e: _kernels.hood_mean(
                self.idx[s:e], self.count[s:e], v), len(self.idx), _kernels.TASK_ROWS)
            return np.concatenate(parts).reshape(values.shape)
        out = np.zeros((len(self.idx),) + values.shape[1:])
        for s in range(0, len(self.idx), CHUNK):
            e = min(len(self.idx), s + CHUNK)
            w = self.valid(s, e).astype(np.float64)
            g = values[self.idx[s:e]].reshape(e - s, w.shape[1], -1)
            m = np.matmul(w[:, None, :], g)[:, 0, :] / self.count[s:e, None]
            out[s:e] = m.reshape((e - s,) + values.shape[1:])
        return out

    def quantile(self, values: np.ndarray, q: float) -> np.ndarray:
        """Quantile ``q`` of ``values`` (n,) over every neighbourhood (linear
        interpolation between order statistics, as ``np.quantile``)."""
        out = np.zeros(len(self.idx))
        for s in range(0, len(self.idx), CHUNK):
            e = min(len(self.idx), s + CHUNK)
            v = np.where(self.valid(s, e), values[self.idx[s:e]], np.inf)
            v.sort(axis=1)
            pos = q * (self.count[s:e] - 1.0)
            j = np.floor(pos).astype(np.int64)
            j1 = np.minimum(j + 1, self.count[s:e] - 1)[:, None]
            lo = np.take_along_axis(v, j[:, None], axis=1)[:, 0]
            hi = np.take_along_axis(v, j1, axis=1)[:, 0]
            out[s:e] = lo + (pos - j) * (hi - lo)
        return out


def neighbourhoods(points: np.ndarray, radius_h: float, k_max: int, tree=None,
                   tile=None, distances: bool = False) -> tuple[_Hood, float]:
    """Radius neighbourhoods (radius ``radius_h`` × h) capped at ``k_max`` points and
    the average spacing h, from ONE chunked k-NN query: h is the mean distance to
    the 6 nearest neighbours (columns 1-6 of the same query, thesis §4.5.1).
    int32 indices and float32 distances keep a 1M-point cloud at ~250 MB.

    ``tile = (h, n_total)``: the points are one tile of a cloud of ``n_total``
    points whose spacing is ``h``; that h and the whole cloud's neighbour count
    are used, and a third value, each row's distance to its last neighbour, is
    returned.  ``distances``: the (n, k) float32 neighbour distances are returned
    as a third value instead (one-piece runs)."""
    tree = build_tree(points) if tree is None else tree
    n = len(points)
    k = min(max(k_max, SPACING_K + 1), n if tile is None else min(n, tile[1]))
    idx = np.zeros((n, k), dtype=np.int32)
    dist = np.zeros((n, k), dtype=np.float32)
    kth = np.zeros(n)
    rows = np.zeros(n)
    for at in leaf_chunks(tree, 4 * CHUNK):
        d, j = query_settled(tree, points[at], k)
        idx[at] = j
        dist[at] = d
        kth[at] = d[:, -1]
        rows[at] = d[:, 1:SPACING_K + 1].mean(axis=1)
    if tile is not None:
        h = tile[0]
        r = np.float32(radius_h * h * (1.0 + 1e-6))
        return _Hood(idx, np.maximum((dist <= r).sum(axis=1), 1)), h, kth
    h = spacing_from_rows(rows)
    if not np.isfinite(h) or h <= 0.0:
        raise PointCloudError("saliency_sparse_mdl: every point coincides with its "
                              "neighbours (h = 0)")
    r = np.float32(radius_h * h * (1.0 + 1e-6))
    count = np.maximum((dist <= r).sum(axis=1), 1)
    if distances:
        return _Hood(idx, count), h, dist
    return _Hood(idx, count), h


def mitra_nguyen_radius(kappa: np.ndarray, rho: np.ndarray, sigma: float, hi: float,
                        lo: float = MN_MIN_RADIUS) -> np.ndarray:
    """Per-point neighbourhood radius after Mitra & Nguyen (2003), in h:
    r = ((c1 σ/√(ερ) + c2 σ²)/κ)^(1/3), clipped to [``lo``, ``hi``].

    The radius that balances the normal's error from curvature (growing with r)
    against the error from noise (shrinking with r and with the density).

    Parameters
    ----------
    kappa : (n,) float
        Curvature magnitude in 1/h (0: flat, the radius goes to ``hi``, also
        when σ is 0: with neither error any radius fits, and the widest
        averages most).
    rho : (n,) float
        Sampling density in points per h².
    sigma : float
        Noise level in h (0: clean, the radius goes to ``lo``).
    hi, lo : float
        Largest and smallest radius, in h.

    >>> mitra_nguyen_radius(np.array([0.0, 0.1, 10.0]), np.ones(3), 0.3, 4.0).round(2).tolist()
    [4.0, 2.36, 2.0]
    """
    num = MN_C1 * sigma / np.sqrt(MN_EPS * np.maximum(rho, 1e-300)) + MN_C2 * sigma * sigma
    with np.errstate(divide="ignore", invalid="ignore"):     # x/0 → inf, 0/0 → nan
        r = np.cbrt(num / np.asarray(kappa, dtype=np.float64))
    return np.clip(np.nan_to_num(r, nan=hi, posinf=hi), lo, hi)


def _adaptive_hood(points, hood: _Hood, dist: np.ndarray, h: float, radius: float):
    """The neighbourhoods of radius ``mitra_nguyen_radius`` (at most ``radius`` h):
    κ from the quadric fits at the fixed radius, ρ at the 15th neighbour, σ̂ the
    cloud's noise level from the 8-NN covariances (√ of the median smallest
    eigenvalue, as the sharp detector's).  Returns the new neighbourhoods and the
    radii in h."""
    from ._crease import noise_level

    _, _, kappa = local_frames_and_curvature(points, hood, radius * h)
    k = min(MN_K, dist.shape[1] - 1)
    d15 = np.maximum(dist[:, k].astype(np.float64) / h, 1e-12)
    rho = k / (np.pi * d15 * d15)
    nb = points[hood.idx[:, :min(8, hood.idx.shape[1])]]
    c = nb - nb.mean(axis=1, keepdims=True)
    lam0 = np.linalg.eigvalsh(np.einsum("cki,ckj->cij", c, c) / nb.shape[1])[:, 0]
    sigma = noise_level(lam0 / (h * h))
    r_h = mitra_nguyen_radius(kappa * h, rho, sigma, radius)
    count = np.maximum((dist <= (r_h * h * (1.0 + 1e-6))[:, None]).sum(axis=1), 1)
    log.info("saliency_sparse_mdl: Mitra-Nguyen radius, noise %.3g h: median %.3g h "
             "(%.3g-%.3g h)", sigma, float(np.median(r_h)), float(r_h.min()),
             float(r_h.max()))
    return _Hood(hood.idx, count), r_h


def local_frames_and_curvature(points: np.ndarray, hood: _Hood, r
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA frames and quadric curvatures of every neighbourhood of radius ``r``
    (one radius, or one per point).

    Returns
    -------
    frames : (n, 3, 3) float
        Columns e1, e2 (tangent, largest eigenvalues first) and the PCA normal.
    gaussian : (n,) float
        K = (4ac − b²)/(1 + d² + e²)² of the least-squares quadric
        w = a u² + b uv + c v² + d u + e v + f in the frame (Monge form at p_i).
    mean_abs : (n,) float
        √(k1² + k2²) of the same fit (used by the curvature-magnitude baseline).
    """
    if _kernels.ENABLED and np.ndim(r) == 0:
        return _geometry(points, hood, r, 0)[:3]
    n = len(points)
    radii = np.broadcast_to(np.asarray(r, dtype=np.float64), (n,))
    frames = np.zeros((n, 3, 3))
    gauss = np.zeros(n)
    total = np.zeros(n)
    ridge = 1e-9
    for s in range(0, n, CHUNK):
        e = min(n, s + CHUNK)
        w = hood.valid(s, e).astype(np.float64)
        cnt = hood.count[s:e].astype(np.float64)
        nb = points[hood.idx[s:e]]  # (c, k, 3)
        mean = np.matmul(w[:, None, :], nb)[:, 0, :] / cnt[:, None]
        diff = (nb - mean[:, None, :]) * w[:, :, None]
        cov = np.matmul(diff.transpose(0, 2, 1), diff)
        _, vec = np.linalg.eigh(cov)
        fr = _canonical_signs(vec[:, :, ::-1], diff)  # e1, e2, normal
        frames[s:e] = fr
        rc = radii[s:e]
        loc = np.matmul(nb - points[s:e, None, :], fr) / rc[:, None, None]
        u, v, z = loc[..., 0], loc[..., 1], loc[..., 2]
        A = np.stack([u * u, u * v, v * v, u, v, np.ones_like(u)], axis=-1) * w[..., None]
        At = A.transpose(0, 2, 1)
        M = np.matmul(At, A)
        tr = np.maximum(np.trace(M, axis1=1, axis2=2), 1.0)
        M += ridge * np.eye(6) * tr[:, None, None]
        q = np.linalg.solve(M, np.matmul(At, (z * w)[:, :, None]))[:, :, 0]
        a, b, c, du, dv = q[:, 0], q[:, 1], q[:, 2], q[:, 3], q[:, 4]
        g2 = 1.0 + du * du + dv * dv
        gauss[s:e] = (4.0 * a * c - b * b) / (g2 * g2) / (rc * rc)
        # principal curvatures of the Hessian (small-slope approximation)
        total[s:e] = 2.0 * np.sqrt(a * a + c * c + 0.5 * b * b) / rc
    return frames, gauss, total


def _canonical_signs(fr: np.ndarray, diff: np.ndarray) -> np.ndarray:
    """Fix the signs of the tangent axes by the data, not by the eigen-solver:
    e1 and e2 point where the neighbourhood's third moment along them is
    positive, and the normal completes a right-handed frame.  The rays of
    (5.5) then turn with the cloud, so a rotated cloud gets the same dictionaries
    in the same order."""
    fr = fr.copy()
    for a in (0, 1):
        proj = np.einsum("ckd,cd->ck", diff, fr[:, :, a])
        skew = np.einsum("ck,ck,ck->c", proj, proj, proj)
        far = np.take_along_axis(proj, np.abs(proj).argmax(axis=1)[:, None], axis=1)[:, 0]
        scale = np.einsum("ck,ck->c", proj, proj) ** 1.5
        sign = np.where(np.abs(skew) > 1e-6 * scale, np.sign(skew), np.sign(far))
        fr[:, :, a] *= np.where(sign == 0, 1.0, sign)[:, None]
    fr[:, :, 2] = np.cross(fr[:, :, 0], fr[:, :, 1])
    return fr


def orient_normals_hood(points: np.ndarray, normals: np.ndarray, hood: _Hood,
                        k: int = 16) -> np.ndarray:
    """Consistent normal signs by :func:`pcprep.filters.neighbors.orient_normals_mst`
    with the chord-mirror agreement (``mirror=True``) on the ``k`` nearest
    neighbours already held in ``hood`` (no new k-NN query; neighbours beyond
    the radius still join the graph, so a sparse region does not fall apart
    into components).  The mirror admits the neighbour's normal reflected in the
    plane bisecting the chord, which keeps solids with thin sharp tips from
    flipping whole faces (docs/decisions/saliency.md, "Normal orientation")."""
    kk = min(k + 1, hood.idx.shape[1])
    return orient_normals_mst(points, normals, k=kk - 1, neighbors=hood.idx[:, 1:kk],
                              mirror=True)


def _geometry(points: np.ndarray, hood: _Hood, r, n_rays: int):
    """Frames, Gaussian and total curvature (:func:`local_frames_and_curvature`)
    and the ray atoms (:func:`_ray_atoms`) of every neighbourhood; in one
    compiled pass when numba is available and ``r`` is one radius, else by the
    NumPy functions (a radius per point: ``adaptive_radius``)."""
    if _kernels.ENABLED and np.ndim(r) == 0:
        n = len(hood.idx)
        frames, gauss, total = np.zeros((n, 3, 3)), np.zeros(n), np.zeros(n)
        atoms = np.zeros((n, int(n_rays)), dtype=np.int32)
        p = np.ascontiguousarray(points, dtype=np.float64)
        count = hood.count.astype(np.int64)
        _kernels.run_chunks(lambda s, e: _kernels.saliency_geometry(
            p, hood.idx, count, float(r), int(n_rays), s, e, frames, gauss, total, atoms),
            n, _kernels.TASK_ROWS)
        return frames, gauss, total, atoms
    frames, gauss, total = local_frames_and_curvature(points, hood, r)
    return frames, gauss, total, _ray_atoms(points, hood, frames, r, n_rays)


def _ray_atoms(points: np.ndarray, hood: _Hood, frames: np.ndarray, r,
               n_rays: int) -> np.ndarray:
    """Index of the neighbour nearest each ray end point, in the tangent plane
    (rays of length ``r``: one radius, or one per point)."""
    n = len(points)
    th = 2.0 * np.pi * np.arange(n_rays) / n_rays
    unit = np.stack([np.cos(th), np.sin(th)], axis=1)  # (m, 2)
    radii = np.broadcast_to(np.asarray(r, dtype=np.float64), (n,))
    atoms = np.zeros((n, n_rays), dtype=np.int32)
    for s in range(0, n, CHUNK):
        e = min(n, s + CHUNK)
        nb = points[hood.idx[s:e]] - points[s:e, None, :]
        uv = np.matmul(nb, frames[s:e, :, :2])  # (c, k, 2)
        # |uv − end|² up to the constant |end|² = r²
        ends = radii[s:e, None, None] * unit[None]  # (c, m, 2)
        d2 = ((uv * uv).sum(axis=2)[:, :, None]
              - 2.0 * np.matmul(uv, ends.transpose(0, 2, 1)))  # (c, k, m)
        d2[~hood.valid(s, e)] = np.inf
        j = d2.argmin(axis=1)
        atoms[s:e] = np.take_along_axis(hood.idx[s:e], j, axis=1)
    return atoms


def _residual_norm(res: np.ndarray) -> np.ndarray:
    """ℓ1 norm over the descriptor's groups: the normal block counts by its
    Euclidean length (rotation invariant), K and d by their absolute values."""
    return np.linalg.norm(res[:, :3], axis=1) + np.abs(res[:, 3]) + np.abs(res[:, 4])


def _normalise(v: np.ndarray) -> np.ndarray:
    top = float(v.max())
    return v / top if top > 0 else np.zeros_like(v, dtype=np.float64)


@validate_params(*PARAMS, presets={"thesis": THESIS})
def saliency_sparse_mdl(points, normals=None, *, radius: float = 3.0, n_rays: int = 8,
                        alpha: float = 0.9, measure: str = "residual",
                        accumulation: str = "mean", acc_quantile: float = 0.1,
                        k_max: int = 32, adaptive_radius: bool = False,
                        preset: str | None = None) -> SaliencyResult:
    """Saliency of every point by local sparse coding and MDL (Leal Narváez 2020, ch. 5).

    Per point: the descriptor F = (n, K r², d) — oriented unit normal, Gaussian
    curvature K of a local quadric, global distinctness d (5.4); its mean F̄_i over
    the radius-r neighbourhood N_g(p_i) (5.2); a dictionary D of the F̄_j of the
    ``n_rays`` neighbours nearest the ends of rays of length r in the PCA tangent
    plane (§5.3.2.2); the Lasso code α of F̄_i (5.6); the neighbourhood saliency
    S_T = N(‖F̄_i − Dα‖₁), or N(‖α‖₀)·N(‖F̄_i − Dα‖₁) (5.7), with N(·) division by
    the maximum; and the point saliency, the mean (or a low quantile) of the S_T
    of the neighbourhoods containing the point.  Lengths are in units of h (mean
    distance to the 6 nearest neighbours).

    Parameters
    ----------
    points : (n, 3) float
        The cloud (n ≥ 10).
    normals : (n, 3) float, optional
        Oriented normals, used as given; None: PCA normals oriented by MST.
    radius : float, default=3.0
        r: neighbourhood radius and ray length (with ``adaptive_radius``: the largest).
    n_rays : int, default=8
        m: rays in the tangent plane, i.e. atoms per dictionary.
    alpha : float, default=0.9
        λ of (5.6), ‖x − Dα‖₂² + λ‖α‖₁ (the thesis' value).
    measure : {"residual", "mdl"}, default='residual'
        Neighbourhood saliency: the coding residual, or the thesis' product (5.7).
    accumulation : {"mean", "quantile"}, default='mean'
        Point saliency from the neighbourhoods containing it: their mean (the
        thesis'), or a quantile.
    acc_quantile : float, default=0.1
        The quantile of ``accumulation="quantile"`` (0 = minimum).
    k_max : int, default=32
        Most neighbours kept within the radius (the nearest).
    adaptive_radius : bool, default=False
        A radius per point by Mitra & Nguyen (2003), from the local curvature,
        density and the cloud's noise level, between 2h and ``radius`` (the
        thesis' choice; whole-cloud runs only).
    preset : {"thesis"}, optional
        "thesis": the MDL product (5.7), mean accumulation and the adaptive
        radius up to 4h; explicit parameters override it.

    Returns
    -------
    SaliencyResult
        ``saliency`` in [0, 1] (1 at the most salient point) and the terms behind it.

    Raises
    ------
    PointCloudError
        Empty, NaN/Inf, fewer than 10, coincident or collinear points; bad normals.
    InvalidParameterError
        A parameter out of range or of the wrong type.

    Notes
    -----
    Deviations (docs/decisions/saliency.md, by heading): K is scaled by r², so the
    result does not depend on the model's units ("Descriptor"); the residual counts
    the normal block by its Euclidean length, for rotation invariance ("Residual
    norm"); the default measure drops ‖α‖₀, which is higher on flat regions than on
    features ("Measure"); the point saliency is the thesis' mean over the
    neighbourhoods, which keeps a feature's whole region salient, not only its
    core ("Accumulation"); r is a fixed multiple
    of h unless ``adaptive_radius`` ("Radius"); the Lasso is solved by
    batched coordinate descent, stopped after 32 sweeps ("Lasso solver").  The
    thesis' form: ``measure="mdl"`` (``preset="thesis"``).  Deterministic.

    Examples
    --------
    >>> g = np.random.default_rng(0)
    >>> xy = g.uniform(-1, 1, (3000, 2))
    >>> z = 0.3 * np.exp(-(xy ** 2).sum(1) / 0.05)
    >>> res = saliency_sparse_mdl(np.column_stack([xy, z]))
    >>> rad = np.hypot(*xy.T)
    >>> bool(res.saliency[rad < 0.2].mean() > res.saliency[rad > 0.7].mean())
    True
    """
    func = "saliency_sparse_mdl"
    pts = as_points(points, func=func, min_points=MIN_POINTS)
    n = len(pts)
    nrm = None if normals is None else as_normals(normals, n, func=func)
    check_spread(pts, func=func)
    pts, _ = centered(pts)

    tree = build_tree(pts)
    hood, h, dist = neighbourhoods(pts, radius, k_max, tree, distances=True)
    del tree
    r = radius * h
    if adaptive_radius:
        hood, r_h = _adaptive_hood(pts, hood, dist, h, radius)
        r = r_h * h
    del dist
    if np.median(hood.count) < 6:
        raise PointCloudError(f"{func}: neighbourhoods of radius {radius} h hold "
                              "fewer than 6 points (median); increase radius")
    log.info("%s: n=%d h=%.4g r=%.4g median |N_g|=%d", func, n, h, float(np.median(r)),
             int(np.median(hood.count)))

    # surroundings (§5.3.2.2) with the frames, so that these are freed before
    # the MST orientation
    frames, gauss, _, atoms = _geometry(pts, hood, r, n_rays)
    pca_normal = np.ascontiguousarray(frames[:, :, 2])
    del frames
    if nrm is None:
        nrm = orient_normals_hood(pts, pca_normal, hood)
    del pca_normal

    Fbar = _descriptors(nrm, gauss * r * r, hood)
    sparsity, resid, n_bad = _code(Fbar, atoms, alpha)

    # MDL saliency (5.7) and accumulation over overlapping neighbourhoods
    s_t = _normalise(resid)
    if measure == "mdl":
        s_t = _normalise(sparsity.astype(np.float64)) * s_t
    if accumulation == "quantile":
        sal = _normalise(hood.quantile(s_t, acc_quantile))
    else:
        sal = _normalise(hood.mean(s_t))
    log.debug("%s: %d of %d Lasso problems kept their iterate after %d sweeps (their "
              "atoms are near-duplicates; the residual is settled, nothing to do)",
              func, n_bad, n, LASSO_ITER)
    return SaliencyResult(sal, s_t, sparsity, resid, Fbar, nrm, gauss, atoms, h, r, n_bad)


def _descriptors(normals: np.ndarray, k_r2: np.ndarray, hood: _Hood) -> np.ndarray:
    """F̄_i = (n̄, K̄ r², d̄) (5.2)-(5.4): d_i = ‖F̄⁴_i − F̄_g‖ is computed from the
    means of the first four components, then averaged over N_g like them."""
    F4 = np.column_stack([normals, k_r2])
    Fbar4 = hood.mean(F4)
    d = np.linalg.norm(Fbar4 - Fbar4.mean(axis=0), axis=1)
    return np.column_stack([Fbar4, hood.mean(d)])


def _code(Fbar: np.ndarray, atoms: np.ndarray, alpha: float):
    """Lasso codes (5.6) of every F̄_i against the F̄ of its atoms: ‖α‖₀, the
    residual norm and the number of problems not certified optimal."""
    n = len(Fbar)
    sparsity = np.zeros(n, dtype=np.int64)
    resid = np.zeros(n)
    n_bad = 0
    for s in range(0, n, 4 * CHUNK):
        e = min(n, s + 4 * CHUNK)
        D = Fbar[atoms[s:e]].transpose(0, 2, 1)  # (c, 5, m)
        sol = lasso_batched(Fbar[s:e], D, 0.5 * alpha, max_iter=LASSO_ITER,
                            tol=LASSO_TOL)
        sparsity[s:e] = (np.abs(sol.coef) > 1e-10).sum(axis=1)
        resid[s:e] = _residual_norm(sol.residual)
        n_bad += int((~sol.converged).sum())
    return sparsity, resid, n_bad


#: neighbour steps behind a point's saliency: the accumulation reads S_T of the
#: neighbourhood (1); S_T reads the F̄ of the atoms, which are neighbours (1); F̄
#: is a neighbourhood mean of F (1) and of d, itself read from F̄⁴ (2)
SALIENCY_HOPS = 4


def saliency_tile(points, lo, hi, core, *, centre, h: float, n_total: int, stage: str,
                  hops: int = SALIENCY_HOPS, fbar_mean=None, reference=None,
                  radius: float = 3.0,
                  n_rays: int = 8, alpha: float = 0.9, measure: str = "residual",
                  accumulation: str = "mean", acc_quantile: float = 0.1,
                  k_max: int = 32, adaptive_radius: bool = False,
                  preset: str | None = None, normals=None) -> dict:
    """One tile of a tiled :func:`saliency_sparse_mdl` run (meshlab_bridge/tiles.py).

    The filter has two cloud-wide values: F̄_g, the mean descriptor behind the
    distinctness d (5.4), and the maxima that normalise S_T and the point
    saliency.  ``stage="mean"`` returns every row's F̄⁴ (the first four
    descriptor components; the caller averages the core rows') and oriented
    normal (their signs are the tile's: MST within the tile); ``stage="code"``, given
    ``fbar_mean`` (F̄_g) and ``reference = (row, normal)`` (the normal of one core
    row in the signs F̄_g was summed in, which turns F̄_g into the tile's own
    signs; None: they are the tile's), returns per row the raw
    residual, ‖α‖₀ and the accumulated, not yet normalised S_T; the caller
    divides by the cloud-wide maxima.  Both return ``exact`` (False: a core row
    depends on points outside the box ``[lo, hi]``) and ``sure`` (exact rows).
    ``preset`` is accepted with the resolved parameters, whose values already
    carry it; ``adaptive_radius`` must be False (``run_tiled`` refuses it).
    ``normals`` (the tile's rows of the input's normals) are used as given, as
    a one-piece run uses them: no orientation, and the signs are the input's
    in every tile.
    """
    pts = np.asarray(points, dtype=np.float64) - np.asarray(centre)
    k_all = min(max(k_max, SPACING_K + 1), n_total)
    if len(pts) < k_all:
        return {"exact": False}
    hood, h, kth = neighbourhoods(pts, radius, k_max, tile=(h, n_total))
    r = radius * h
    lo = np.asarray(lo) - centre
    hi = np.asarray(hi) - centre
    core = np.asarray(core, dtype=bool)
    sure = tile_exact(pts, hood.idx, kth, lo, hi, hops if stage == "code" else 1)
    if not sure[core].all():
        return {"exact": False}
    frames, gauss, _, atoms = _geometry(pts, hood, r, n_rays)
    if normals is None:
        nrm = orient_normals_hood(pts, np.ascontiguousarray(frames[:, :, 2]), hood)
    else:
        nrm = as_normals(normals, len(pts), func="saliency_sparse_mdl")
    del frames
    F4 = np.column_stack([nrm, gauss * r * r])
    Fbar4 = hood.mean(F4)
    if stage == "mean":
        return {"exact": True, "fbar4": Fbar4, "normals": nrm, "sure": sure}
    fbar_mean = np.array(fbar_mean, dtype=np.float64)
    if reference is not None and nrm[reference[0]] @ np.asarray(reference[1]) < 0:
        fbar_mean[:3] *= -1.0
    d = np.linalg.norm(Fbar4 - fbar_mean, axis=1)
    Fbar = np.column_stack([Fbar4, hood.mean(d)])
    sparsity, resid, _ = _code(Fbar, atoms, alpha)
    raw = resid * sparsity if measure == "mdl" else resid
    acc = hood.quantile(raw, acc_quantile) if accumulation == "quantile" else hood.mean(raw)
    return {"exact": True, "residual": resid, "sparsity": sparsity, "accumulated": acc,
            "sure": sure}
