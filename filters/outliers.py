"""
outliers.py
-----------
Outlier removal before the thesis filters, with the two criteria PCL, Open3D
and MeshLab users know: statistical (a point whose mean distance to its k
nearest neighbours lies more than ``std_ratio`` standard deviations above the
mean of those distances, PCL's ``StatisticalOutlierRemoval``) and radius (a
point with fewer than ``min_neighbors`` others within ``radius``, PCL's
``RadiusOutlierRemoval``).  Lengths are in units of the robust spacing h, so
the same parameters serve a model in millimetres and a scan in metres; the
removed indices are returned, so a caller can report or undo the removal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _kernels
from ._params import Param, validate_params
from ._validation import as_points, check_spread
from .neighbors import SPACING_K, build_tree, centered, knn, spacing_from_rows


@dataclass(frozen=True)
class OutlierResult:
    """Result of :func:`remove_outliers`.

    Attributes
    ----------
    keep_idx : (m,) int64
        Indices of the points kept, increasing.
    removed_idx : (n - m,) int64
        Indices of the points removed, increasing.
    score : (n,) float64
        The criterion per point: the mean distance to the k nearest neighbours
        in units of h (statistical), or the neighbour count within the radius.
    threshold : float
        The cut applied to ``score``.
    h : float
        The spacing, in input units.
    """

    keep_idx: np.ndarray
    removed_idx: np.ndarray
    score: np.ndarray
    threshold: float
    h: float


@validate_params(
    Param("method", str, choices=("statistical", "radius")),
    Param("k", int, low=2, high=256, unit="count"),
    Param("std_ratio", float, low=0.0, high=100.0, closed="neither"),
    Param("radius", float, low=0.0, high=1000.0, closed="neither", unit="h"),
    Param("min_neighbors", int, low=1, high=1000, unit="count"),
)
def remove_outliers(points, normals=None, *, method: str = "statistical", k: int = 16,
                    std_ratio: float = 2.0, radius: float = 3.0,
                    min_neighbors: int = 4) -> OutlierResult:
    """Find the outliers of a cloud by a statistical or a radius criterion.

    Parameters
    ----------
    points : (n, 3) float
        The cloud (more than k points).
    normals : (n, 3) float, optional
        Not used; accepted for the filter interface.
    method : {"statistical", "radius"}, default='statistical'
        Statistical: remove a point whose mean distance to its k nearest neighbours
        exceeds the mean of those distances by std_ratio standard deviations.
        Radius: remove a point with fewer than min_neighbors others within radius.
    k : int, default=16
        Neighbours of the statistical criterion (PCL's meanK, Open3D's nb_neighbors).
    std_ratio : float, default=2.0
        Standard deviations above the mean (PCL's stddevMulThresh).
    radius : float, default=3.0
        Radius of the radius criterion, in units of h.
    min_neighbors : int, default=4
        Fewest other points within the radius for a point to stay (PCL's
        setMinNeighborsInRadius).

    Returns
    -------
    OutlierResult
        ``keep_idx`` and ``removed_idx`` partition ``range(n)``.

    Notes
    -----
    h is the trimmed mean distance to the 6 nearest neighbours over the points
    that are not isolated (``neighbors.spacing_from_rows``), so the outliers being
    removed do not set the unit of the radius.  The statistical criterion keeps
    PCL's definition (mean and standard deviation over every point) so that its
    parameters mean what they mean in PCL and Open3D.  Both criteria depend only
    on distances: the result is invariant to rigid motion, scale and the order of
    the points (up to exact ties in neighbour distances).

    Examples
    --------
    >>> g = np.random.default_rng(0)
    >>> plane = np.c_[g.uniform(size=(2000, 2)), np.zeros(2000)]
    >>> cloud = np.r_[plane, [[0.5, 0.5, 3.0], [9.0, 9.0, 9.0]]]
    >>> remove_outliers(cloud).removed_idx.tolist()
    [2000, 2001]
    """
    func = "remove_outliers"
    pts = as_points(points, func=func, min_points=max(k, SPACING_K) + 1)
    check_spread(pts, func=func)
    pts, _ = centered(pts)
    tree = build_tree(pts)
    kk = max(k, SPACING_K)
    dist, _ = knn(pts, kk, tree=tree, include_self=False)
    h = spacing_from_rows(dist[:, :SPACING_K].mean(axis=1))
    if method == "statistical":
        score = dist[:, :k].mean(axis=1) / h
        threshold = float(score.mean() + std_ratio * score.std())
        out = score > threshold
    else:
        counts = tree.query_ball_point(pts, r=radius * h, return_length=True,
                                       workers=_kernels.tree_workers())
        score = np.asarray(counts, dtype=np.float64) - 1.0  # the point itself
        threshold = float(min_neighbors)
        out = score < threshold
    return OutlierResult(np.flatnonzero(~out), np.flatnonzero(out), score, threshold, h)
