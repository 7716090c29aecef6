"""
_border.py
----------
Geometric tests of ``holes.py`` (not in the thesis): where the surface ends
toward a border (``strip_extent``, ``strip_extent_at``), the border distance
implied by centroid shifts (``border_distance``), the empty angle around a point
(``largest_angle_gap``, ``border_gap``), the chains along a border
(``track_border``, ``border_radius``) and the points near a set
(``near_any``).  Why each exists, and what it was
measured to do, is in docs/decisions/features.md.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from . import _kernels
from .multiscale import chain_labels, neighbour_offsets, sym3_eig
from .neighbors import CHUNK, build_tree

#: half-width (h) of the strip toward the border in which the outermost samples are
#: sought, and the empty stretch (h) along it that counts as the surface's end
_STRIP_HALF = 1.5
_STRIP_GAP = 2.5


def strip_extent(x: np.ndarray, mean: np.ndarray, normal: np.ndarray, *, h: float,
                 half_width: float = _STRIP_HALF, gap: float = _STRIP_GAP
                 ) -> np.ndarray:
    """Distance from each point to where its surface ends toward the border,
    in units of h.

    The border direction u is opposite to the tangential centroid shift.  The
    neighbours within ``half_width`` h of the line through the point along u
    are projected on u and sorted outward; the first empty stretch longer than
    ``gap`` h ends the surface, and the distance to the last neighbour before
    it is returned (the farthest projection when there is none: about the
    neighbourhood radius inside a surface).  See docs/decisions/features.md,
    section "Strip extent".

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


def strip_extent_at(points: np.ndarray, idx: np.ndarray, rows: np.ndarray,
                    mean: np.ndarray, normal: np.ndarray, *, h: float,
                    half_width: float = _STRIP_HALF, gap: float = _STRIP_GAP
                    ) -> np.ndarray:
    """``strip_extent`` of the points ``rows`` with the neighbours ``idx``
    (c, k) of ``points``: the offsets ``points[idx] − points[rows]`` are read
    by the compiled kernel from the cloud (no (c, k, 3) array) or gathered for
    the NumPy reference."""
    if _kernels.ENABLED:
        out = np.empty(len(rows))  # noqa: NPY-empty -- every row written by the kernel
        _kernels.run_chunks(lambda s, e: _kernels.strip_extent_rows(
            points, idx[s:e], rows[s:e], mean[s:e], normal[s:e], h, half_width, gap,
            out[s:e]), len(rows), _kernels.TASK_ROWS)
        return out
    return strip_extent(neighbour_offsets(points, idx, rows), mean, normal, h=h,
                        half_width=half_width, gap=gap)


def _half_disc_table(m: int = 2001) -> tuple[np.ndarray, np.ndarray]:
    """Centroid shift g(u)/r of a disc of radius r whose part beyond a line at
    distance u·r from the centre is missing (u ∈ [0, 1]; g(0) = 4/(3π))."""
    u = np.linspace(0.0, 1.0, m)
    root = np.sqrt(1.0 - u * u)
    g = (2.0 / 3.0) * root ** 3 / (np.pi - np.arccos(u) + u * root)
    return u, g


def border_distance(shift: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Distance to a straight border implied by tangential centroid shifts.

    A neighbourhood at distance d < r from a straight border is a disc of
    radius r missing the segment beyond it; its centroid shifts away from the
    border by ``r·g(d/r)``, g falling from 4/(3π) ≈ 0.42 at d = 0 to 0 at
    d = r.  Inverting g per scale gives d; the median over the scales is
    returned.

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

    >>> border_distance(np.array([[0.0, 0.5]]), np.array([[1.0, 1.0]])).tolist()
    [0.5]
    """
    u, g = _half_disc_table()
    out = np.empty(len(shift))  # noqa: NPY-empty -- every chunk written below

    def rows(s: int, e: int) -> None:   # interp and median release the GIL: threads
        out[s:e] = np.median(np.interp(shift[s:e], g[::-1], u[::-1]) * radius[s:e],
                             axis=1)

    _kernels.run_chunks(rows, len(out), CHUNK)
    return out


def largest_angle_gap(offsets: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Largest angle between consecutive neighbour directions around a point.

    The offsets are projected on the plane orthogonal to the normal and their
    polar angles sorted; the largest difference between consecutive angles
    (the wrap-around one included) is about 2π/k inside a surface, π on a
    straight border, more at a convex corner (PCL's ``BoundaryEstimation``).

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

    >>> half = np.array([[[1.0, 0, 0], [0, 1, 0], [-1, 0, 0]]])
    >>> (largest_angle_gap(half, np.array([[0.0, 0, 1]])) / np.pi).tolist()
    [1.0]
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
    """Largest angular gap (radians) of each point's nearest neighbours around
    their PCA normal (``largest_angle_gap``).  The compiled kernel
    (``_kernels.border_gap_rows``) reads the offsets from the cloud row by row;
    the NumPy reference gathers them in chunks.  A tiled run computes it for
    every row, so its cost is per point of the cloud.

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
    if _kernels.ENABLED and m and neighbours.shape[1] > 1:
        out = np.empty(m)  # noqa: NPY-empty -- every row written by the kernel
        nb = np.ascontiguousarray(neighbours)
        pts = np.ascontiguousarray(points, dtype=np.float64)
        _kernels.run_chunks(lambda s, e: _kernels.border_gap_rows(pts, nb[s:e], out[s:e]),
                            m, _kernels.TASK_ROWS)
        return out
    out = np.zeros(m)
    for s in range(0, m, CHUNK):
        e = min(m, s + CHUNK)
        x = points[neighbours[s:e, 1:]] - points[neighbours[s:e, 0], None, :]
        xc = x - x.mean(axis=1, keepdims=True)
        _, nrm = sym3_eig(np.einsum("cki,ckj->cij", xc, xc))
        out[s:e] = largest_angle_gap(x, nrm)
    return out


def track_border(points: np.ndarray, seeds: np.ndarray, candidates: np.ndarray,
                 link: float) -> np.ndarray:
    """Hysteresis along a border: the candidates chained to a seed.

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
    lab = chain_labels(points[cand], link)
    seeded = np.zeros(lab.max() + 1, dtype=bool)
    seeded[lab[seeds[cand]]] = True
    out[cand[seeded[lab]]] = True
    return out


def border_radius(points: np.ndarray, link: float) -> np.ndarray:
    """Radius of the border each point belongs to.

    Points closer than ``link`` are joined; every connected chain is one
    border, and its radius is the largest distance of its points from their
    centroid (about the hole's radius for a closed rim, half the length of a
    straight stretch, 0 for a lone point).

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
    lab = chain_labels(points, link)
    count = np.bincount(lab)
    centre = np.stack([np.bincount(lab, points[:, j]) / count for j in range(3)],
                      axis=1)
    radius = np.zeros(len(count))
    np.maximum.at(radius, lab, np.linalg.norm(points - centre[lab], axis=1))
    return radius[lab]


def near_any(points: np.ndarray, queries: np.ndarray, radius: float) -> np.ndarray:
    """Which ``queries`` lie within ``radius`` of at least one of ``points``.

    Parameters
    ----------
    points : (m, 3) float, or a cKDTree built over them
    queries : (q, 3) float
    radius : float
        In the points' units.

    Returns
    -------
    (q,) bool
        False everywhere when ``points`` is empty.

    >>> near_any(np.zeros((1, 3)), np.array([[0.5, 0, 0], [2.0, 0, 0]]), 1.0).tolist()
    [True, False]
    """
    if (points.n if isinstance(points, cKDTree) else len(points)) == 0 or len(queries) == 0:
        return np.zeros(len(queries), dtype=bool)
    tree = points if isinstance(points, cKDTree) else build_tree(points)
    d, _ = tree.query(queries, k=1, distance_upper_bound=np.nextafter(radius, np.inf))
    return d <= radius
