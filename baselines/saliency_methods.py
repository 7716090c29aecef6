"""
saliency_methods.py
-------------------
The saliency methods the thesis compares against (ch. 5), implemented from their
papers for point clouds:

* ``cluster_saliency``: cluster-based point-set saliency (Tasse, Kosinka and
  Dodgson, "Cluster-based point set saliency", ICCV 2015; "CS" in thesis
  Table 5.1).  The cloud is cut into clusters, each cluster is described by the
  mean FPFH of its points, and a cluster is salient when its descriptor differs
  from those of the clusters near it (uniqueness) and when the clusters that
  look like it lie close together rather than all over the shape (spatial
  distribution).  Points take the saliency of their clusters through soft
  memberships.
* ``centre_surround_saliency``: multi-scale centre-surround saliency of mean
  curvature (Lee, Varshney and Jacobs, "Mesh saliency", SIGGRAPH 2005), adapted
  to points: Gaussian-weighted averages of the mean curvature at scales σ and
  2σ, their absolute difference per scale, the non-linear normalisation that
  promotes scales with few strong maxima, summed over five scales.

Both return one score per point (higher = more salient), are deterministic, and
follow a rigid motion or a uniform scaling of the cloud (every length is in
units of the cloud's own spacing h or of its own extent).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from pcprep.filters._validation import as_points, check_param
from pcprep.filters.neighbors import average_spacing, build_tree, knn, pca_normals
from pcprep.filters.saliency import local_frames_and_curvature, neighbourhoods

__all__ = ["fpfh", "cluster_saliency", "centre_surround_saliency", "mean_curvature"]

_FPFH_BINS = 11


def _spfh(points, normals, idx):
    """Simplified point feature histograms (Rusu et al. 2009): for every point and
    each of its neighbours the Darboux-frame angles (α, φ, θ), each binned in 11
    bins, as shares of the neighbours; (n, 33)."""
    n, k = idx.shape
    ps = points[:, None, :]
    ns = np.broadcast_to(normals[:, None, :], (n, k, 3))
    pt = points[idx]
    nt = normals[idx]
    d = pt - ps
    dist = np.linalg.norm(d, axis=2)
    ok = dist > 0
    dn = d / np.where(ok, dist, 1.0)[..., None]
    u = ns
    v = np.cross(u, dn)
    vl = np.linalg.norm(v, axis=2)
    ok &= vl > 1e-12
    v = v / np.where(vl > 1e-12, vl, 1.0)[..., None]
    w = np.cross(u, v)
    alpha = np.einsum("nkd,nkd->nk", v, nt)
    phi = np.einsum("nkd,nkd->nk", u, dn)
    theta = np.arctan2(np.einsum("nkd,nkd->nk", w, nt), np.einsum("nkd,nkd->nk", u, nt))
    hist = np.zeros((n, 3 * _FPFH_BINS))
    cnt = np.maximum(ok.sum(axis=1), 1).astype(np.float64)
    rows = np.repeat(np.arange(n), k).reshape(n, k)
    for j, (val, lo, hi) in enumerate(((alpha, -1.0, 1.0), (phi, -1.0, 1.0),
                                       (theta, -np.pi, np.pi))):
        b = np.clip(((val - lo) / (hi - lo) * _FPFH_BINS).astype(np.int64), 0,
                    _FPFH_BINS - 1)
        np.add.at(hist, (rows[ok], j * _FPFH_BINS + b[ok]), 1.0)
    return hist / cnt[:, None], dist


def fpfh(points, normals=None, k: int = 16) -> np.ndarray:
    """Fast point feature histograms (Rusu, Blodow and Beetz 2009), (n, 33).

    FPFH_i = SPFH_i + (1/k) Σ_j SPFH_j / ‖p_j − p_i‖ (distances in units of h), each
    of the three 11-bin histograms rescaled to sum to one.  ``normals`` default
    to MST-oriented 16-NN PCA normals.
    """
    pts = as_points(points, func="fpfh", min_points=k + 1)
    if normals is None:
        normals = pca_normals(pts, k=k, orient=True)
    tree = build_tree(pts)
    _, idx = knn(pts, k + 1, tree=tree)
    idx = idx[:, 1:]
    spfh, dist = _spfh(pts, np.asarray(normals, dtype=np.float64), idx)
    h = average_spacing(pts, tree=tree)
    wgt = 1.0 / np.maximum(dist / h, 1e-3)
    out = spfh + np.einsum("nk,nkb->nb", wgt, spfh[idx]) / k
    for j in range(3):
        blk = out[:, j * _FPFH_BINS:(j + 1) * _FPFH_BINS]
        blk /= np.maximum(blk.sum(axis=1, keepdims=True), 1e-300)
    return out


def _unit_range(x):
    lo, hi = float(np.min(x)), float(np.max(x))
    return (x - lo) / (hi - lo) if hi > lo else np.zeros_like(x)


def cluster_saliency(points, *, n_clusters: int | None = None, k: int = 16,
                     sigma_p: float = 0.25, distribution_weight: float = 6.0,
                     seed: int = 0) -> np.ndarray:
    """Cluster-based point-set saliency (Tasse et al. 2015), one score per point.

    Steps: FPFH descriptors (``fpfh``); k-means clusters of the positions
    (``n_clusters``, default n/100, at least 16; k-means++ seeded by ``seed``);
    per cluster i the centroid μ_i and mean descriptor f_i; then

    * uniqueness U_i = Σ_j ‖f_i − f_j‖² w_ij with w_ij ∝ exp(−‖μ_i − μ_j‖² /
      (2 (σ_p L)²)), Σ_j w_ij = 1, L the largest centroid distance;
    * spatial distribution D_i = Σ_j ‖μ_j − m_i‖² φ_ij with φ_ij ∝ exp(−‖f_i −
      f_j‖² / (2 σ_f²)), Σ_j φ_ij = 1, m_i = Σ_j φ_ij μ_j and σ_f the median
      descriptor distance between clusters;
    * cluster saliency S_i = Û_i exp(−``distribution_weight`` D̂_i), Û and D̂
      rescaled to [0, 1];
    * point saliency s(p) = Σ_i P(i | p) S_i over the three nearest clusters,
      P ∝ exp(−‖p − μ_i‖² / (2 r²)) with r the RMS cluster radius (the soft
      memberships of the paper's fuzzy clustering).
    """
    from sklearn.cluster import KMeans

    func = "cluster_saliency"
    pts = as_points(points, func=func, min_points=max(k + 1, 32))
    sigma_p = check_param(sigma_p, func=func, name="sigma_p", low=0.0, closed="neither")
    distribution_weight = check_param(distribution_weight, func=func,
                                      name="distribution_weight", low=0.0)
    n = len(pts)
    if n_clusters is None:
        n_clusters = max(16, n // 100)
    n_clusters = int(check_param(n_clusters, func=func, name="n_clusters", kind=int,
                                 low=2, high=n, unit="count"))
    centre = pts.mean(axis=0)
    x = pts - centre
    scale = float(np.sqrt((x * x).sum(axis=1).mean()))
    x = x / scale
    desc = fpfh(x, k=k)
    km = KMeans(n_clusters=n_clusters, n_init=1, random_state=seed).fit(x)
    lab = km.labels_
    mu = np.zeros((n_clusters, 3))
    f = np.zeros((n_clusters, desc.shape[1]))
    cnt = np.bincount(lab, minlength=n_clusters).astype(np.float64)
    np.add.at(mu, lab, x)
    np.add.at(f, lab, desc)
    live = cnt > 0
    mu, f, cnt = mu[live], f[live], cnt[live]
    mu /= cnt[:, None]
    f /= cnt[:, None]
    dmu = ((mu[:, None, :] - mu[None, :, :]) ** 2).sum(axis=2)
    df = ((f[:, None, :] - f[None, :, :]) ** 2).sum(axis=2)
    big = float(np.sqrt(dmu.max()))
    w = np.exp(-dmu / (2.0 * (sigma_p * big) ** 2))
    w /= w.sum(axis=1, keepdims=True)
    uniq = (df * w).sum(axis=1)
    off = df[~np.eye(len(f), dtype=bool)]
    sig_f2 = float(np.median(off)) if off.size and np.median(off) > 0 else 1.0
    phi = np.exp(-df / (2.0 * sig_f2))
    phi /= phi.sum(axis=1, keepdims=True)
    m = phi @ mu
    dist = (phi * ((mu[None, :, :] - m[:, None, :]) ** 2).sum(axis=2)).sum(axis=1)
    sal = _unit_range(uniq) * np.exp(-distribution_weight * _unit_range(dist))
    # soft memberships over the three nearest clusters
    remap = np.cumsum(live) - 1
    r2 = float(((x - mu[remap[lab]]) ** 2).sum(axis=1).mean())
    kk = min(3, len(mu))
    d2, near = build_tree(mu).query(x, k=kk)
    d2 = np.asarray(d2).reshape(n, kk) ** 2
    near = np.asarray(near).reshape(n, kk)
    p = np.exp(-(d2 - d2[:, :1]) / (2.0 * max(r2, 1e-300)))
    p /= p.sum(axis=1, keepdims=True)
    return (p * sal[near]).sum(axis=1)


def mean_curvature(points, radius: float = 3.0) -> np.ndarray:
    """|H| = |k1 + k2| / 2 of the radius-``radius``·h quadric fit the saliency filter
    uses (from its K = k1 k2 and √(k1² + k2²): (k1 + k2)² = k1² + k2² + 2K)."""
    pts = as_points(points, func="mean_curvature", min_points=8)
    tree = build_tree(pts)
    hood, h = neighbourhoods(pts, radius, 48, tree)
    _, gauss, total = local_frames_and_curvature(pts, hood, radius * h)
    return 0.5 * np.sqrt(np.maximum(total * total + 2.0 * gauss, 0.0))


def _diffusion(points, k: int, h: float):
    """Row-stochastic Gaussian weights over the k nearest neighbours (σ = h) and
    the variance per step of the random walk they define, per tangent direction."""
    dist, idx = knn(points, k)
    w = np.exp(-(dist / h) ** 2 / 2.0)
    w /= w.sum(axis=1, keepdims=True)
    step_var = float(((w * dist * dist).sum(axis=1)).mean() / 2.0)
    n = len(points)
    W = sparse.csr_matrix((w.ravel(), idx.ravel(), np.arange(0, n * k + 1, k)),
                          shape=(n, n))
    return W, step_var


def centre_surround_saliency(points, *, scales=(2.0, 3.0, 4.0, 5.0, 6.0),
                             radius: float = 3.0, k: int = 16) -> np.ndarray:
    """Multi-scale centre-surround saliency of mean curvature (Lee et al. 2005),
    adapted to points; one score per point.

    Per scale σ_i = ``scales[i]`` ε with ε = h (the paper's ε is 0.3 % of the
    diagonal, about one vertex spacing of its meshes): G(C, σ) is the
    Gaussian-weighted average of the mean curvature C = |H| (``mean_curvature``),
    S_i = |G(C, σ_i) − G(C, 2σ_i)|.  G is computed on the points themselves: t
    steps of a Gaussian-weighted k-NN random walk, t = σ² / (its variance per
    step), i.e. a Gaussian of standard deviation σ along the surface (the paper
    sums over the vertices within 2σ in space).  Each S_i is rescaled to [0, 1]
    and multiplied by (M_i − m̄_i)², M_i its maximum and m̄_i the mean of its other
    local maxima (a point at least as large as its k neighbours); the result is
    the sum over the scales.  Orientation-free: |H| needs no sign of the normal.
    """
    func = "centre_surround_saliency"
    pts = as_points(points, func=func, min_points=k + 1)
    scales = [check_param(s, func=func, name="scales", low=0.0, closed="neither")
              for s in scales]
    h = average_spacing(pts)
    C = mean_curvature(pts, radius)
    W, step_var = _diffusion(pts, k, h)
    _, nbr = knn(pts, k)
    cache = {}

    def smooth(sigma):
        t = max(1, int(round((sigma * h) ** 2 / step_var)))
        if t not in cache:
            done = max([s for s in cache if s <= t], default=0)
            v = cache[done] if done else C.copy()
            for _ in range(t - done):
                v = W @ v
            cache[t] = v
        return cache[t]

    total = np.zeros(len(pts))
    for s in scales:
        S = np.abs(smooth(s) - smooth(2.0 * s))
        S = _unit_range(S)
        peak = S >= S[nbr].max(axis=1)
        vals = S[peak]
        top = float(S.max())
        others = vals[vals < top]
        mbar = float(others.mean()) if others.size else 0.0
        total += S * (top - mbar) ** 2
    return total
