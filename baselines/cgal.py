"""
cgal.py
-------
CGAL Point Set Processing baselines (the ``cgal`` SWIG bindings): bilateral
and jet smoothing, grid / hierarchy / WLOP / random simplification and the
average spacing, as plain functions on NumPy arrays.

Every runner is a module-level function taking and returning float64 arrays,
so benches can run it crash-isolated (``harness.measure(cgal.bilateral, P, N)``).
Simplifiers return the sorted indices of the kept input points, tracked through
CGAL's removals with an int property map ``orig_id``; WLOP creates new points
and returns them.  Coordinates are centred (bounding-box centre) before they
reach CGAL and shifted back on output.  CGAL runs on all cores through TBB.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from pcprep.filters._validation import InvalidParameterError, as_normals, as_points, check_param
from pcprep.filters.neighbors import centered

log = logging.getLogger("pcprep")

#: relative tolerance of the count-targeting helpers (|kept - count| <= RTOL * count)
COUNT_RTOL = 0.01


# ----------------------------------------------------------------------------------------
# NumPy <-> Point_set_3
# ----------------------------------------------------------------------------------------

def _psp():
    from CGAL import CGAL_Point_set_processing_3 as psp

    return psp


def to_point_set(points: np.ndarray, normals: np.ndarray | None = None, ids: bool = True):
    """Build a CGAL ``Point_set_3`` from (n, 3) float64 arrays.

    With ``ids`` an int property ``orig_id`` = 0..n-1 is attached so identities
    survive removals and shuffles.  The normal map is created before the points
    are inserted (CGAL requirement).
    """
    from CGAL.CGAL_Kernel import Vector_3
    from CGAL.CGAL_Point_set_3 import Point_set_3

    ps = Point_set_3()
    if normals is not None:
        ps.add_normal_map()
    ps.insert_range(np.ascontiguousarray(points, dtype=np.float64).ravel().tolist())
    if normals is not None:
        nm = ps.normal_map()
        for i, (a, b, c) in enumerate(np.asarray(normals, dtype=np.float64).tolist()):
            nm.set(i, Vector_3(a, b, c))
    if ids:
        oid = ps.add_int_map("orig_id")
        for i in range(len(points)):
            oid.set(i, i)
    return ps


def point_set_points(ps) -> np.ndarray:
    """(m, 3) float64 coordinates of the non-removed points, iteration order."""
    out = np.array([(p.x(), p.y(), p.z()) for p in ps.points()], dtype=np.float64)
    return out.reshape(-1, 3)


def point_set_normals(ps) -> np.ndarray:
    """(m, 3) float64 normals of the non-removed points, same order as points."""
    out = np.array([(v.x(), v.y(), v.z()) for v in ps.normals()], dtype=np.float64)
    return out.reshape(-1, 3)


def point_set_ids(ps) -> np.ndarray:
    """(m,) int64 ``orig_id`` of the non-removed points, same order as points."""
    return np.fromiter(ps.range(ps.int_map("orig_id")), dtype=np.int64)


# ----------------------------------------------------------------------------------------
# checks
# ----------------------------------------------------------------------------------------

def _check_int(value, name: str, func: str, low: int) -> int:
    return check_param(value, func=func, name=name, kind=int, low=low)


def _check_real(value, name: str, func: str, low: float, high: float = math.inf,
                low_open: bool = True) -> float:
    return check_param(value, func=func, name=name, kind=float, low=low,
                       high=None if math.isinf(high) else high,
                       closed="right" if low_open else "both")


def _check_count(count, n: int, func: str) -> int:
    return check_param(count, func=func, name="count", kind=int, low=1, high=n)


# ----------------------------------------------------------------------------------------
# smoothing
# ----------------------------------------------------------------------------------------

def bilateral(points, normals, k: int = 24, sharpness_angle: float = 30.0,
              iterations: int = 1, neighbor_radius: float = 0.0
              ) -> tuple[np.ndarray, np.ndarray]:
    """CGAL ``bilateral_smooth_point_set`` (edge-aware resampling projection,
    Huang et al. 2013), ``iterations`` calls in a row.

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float
        Non-zero normals (required: CGAL segfaults without a normal map).
        Orientation need only be consistent.
    k : int, default=24
        Neighbours per point.
    sharpness_angle : float, default=30.0
        Degrees in (0, 90]; larger = smoother.
    iterations : int, default=1
        One CGAL call = one iteration (CGAL's example uses 3).
    neighbor_radius : float, default=0.0
        > 0 switches to a radius search capped at k (cloud units).

    Returns
    -------
    points, normals : (n, 3) float
        Smoothed points and updated unit normals, input order.

    Notes
    -----
    The Gaussian spatial width is 0.95 x the largest k-NN radius over the
    whole cloud (global), so isolated outliers widen it for everybody.
    """
    func = "bilateral"
    X = as_points(points, func=func, min_points=2)
    N = as_normals(normals, len(X), func=func)
    k = _check_int(k, "k", func, 2)
    angle = _check_real(sharpness_angle, "sharpness_angle", func, 0.0, 90.0)
    iterations = _check_int(iterations, "iterations", func, 1)
    radius = _check_real(neighbor_radius, "neighbor_radius", func, 0.0, low_open=False)
    Xc, c = centered(X)
    ps = to_point_set(Xc, N)
    psp = _psp()
    for _ in range(iterations):
        psp.bilateral_smooth_point_set(ps, k, radius, angle)
    ids = point_set_ids(ps)
    if len(ids) != len(X) or len(np.unique(ids)) != len(X):
        raise RuntimeError(f"{func}: CGAL returned {len(ids)} points for {len(X)}")
    Y = np.empty_like(X)
    NY = np.empty_like(N)
    Y[ids] = point_set_points(ps)
    NY[ids] = point_set_normals(ps)
    lens = np.linalg.norm(NY, axis=1, keepdims=True)
    NY = np.divide(NY, lens, out=N.copy(), where=lens > 0)
    return Y + c, NY


def jet_smooth(points, k: int = 24, degree_fitting: int = 2, degree_monge: int = 2,
               neighbor_radius: float = 0.0) -> np.ndarray:
    """CGAL ``jet_smooth_point_set``: project each point onto the degree-2 jet
    (local polynomial height field, Cazals & Pouget 2005) fitted to its k-NN.

    Returns the (n, 3) smoothed points in input order.
    """
    func = "jet_smooth"
    X = as_points(points, func=func, min_points=2)
    k = _check_int(k, "k", func, 2)
    df = _check_int(degree_fitting, "degree_fitting", func, 1)
    dm = _check_int(degree_monge, "degree_monge", func, 1)
    if dm > df:
        raise InvalidParameterError(
            f"{func}: degree_monge ({dm}) must be <= degree_fitting ({df})")
    radius = _check_real(neighbor_radius, "neighbor_radius", func, 0.0, low_open=False)
    Xc, c = centered(X)
    ps = to_point_set(Xc)
    _psp().jet_smooth_point_set(ps, k, radius, df, dm)
    ids = point_set_ids(ps)
    if len(ids) != len(X) or len(np.unique(ids)) != len(X):
        raise RuntimeError(f"{func}: CGAL returned {len(ids)} points for {len(X)}")
    Y = np.empty_like(X)
    Y[ids] = point_set_points(ps)
    return Y + c


# ----------------------------------------------------------------------------------------
# simplification
# ----------------------------------------------------------------------------------------

def _kept(ps, n: int, func: str) -> np.ndarray:
    ids = np.sort(point_set_ids(ps))
    if len(ids) and (ids[0] < 0 or ids[-1] >= n or (np.diff(ids) == 0).any()):
        raise RuntimeError(f"{func}: CGAL returned invalid point identities")
    return ids


def grid_simplify(points, cell: float) -> np.ndarray:
    """CGAL ``grid_simplify_point_set``: keep one point per occupied cubic cell
    of side ``cell`` (cloud units).  Returns the sorted kept input indices."""
    func = "grid_simplify"
    X = as_points(points, func=func)
    cell = _check_real(cell, "cell", func, 0.0)
    Xc, _ = centered(X)
    ps = to_point_set(Xc)
    _psp().grid_simplify_point_set(ps, cell)
    return _kept(ps, len(X), func)


def hierarchy_simplify(points, size: int = 10, maximum_variation: float = 1.0 / 3.0
                       ) -> np.ndarray:
    """CGAL ``hierarchy_simplify_point_set`` (Pauly et al. 2002): recursive PCA
    splitting until each cluster has at most ``size`` points and surface
    variation at most ``maximum_variation``; one point per cluster.
    Returns the sorted kept input indices (count not directly settable; see
    :func:`hierarchy_simplify_count`)."""
    func = "hierarchy_simplify"
    X = as_points(points, func=func)
    size = _check_int(size, "size", func, 1)
    var = _check_real(maximum_variation, "maximum_variation", func, 0.0, 1.0)
    Xc, _ = centered(X)
    ps = to_point_set(Xc)
    _psp().hierarchy_simplify_point_set(ps, size, var)
    return _kept(ps, len(X), func)


def wlop(points, percentage: float, neighbor_radius: float = -1.0, iterations: int = 35,
         require_uniform_sampling: bool = False) -> np.ndarray:
    """CGAL ``wlop_simplify_and_regularize_point_set`` (Huang et al. 2009).

    Parameters
    ----------
    points : (n, 3) float
    percentage : float
        Output size in percent of n, in (0, 100].
    neighbor_radius : float, default=-1
        Support radius in cloud units; <= 0 = CGAL default (8 x average spacing).
    iterations : int, default=35
    require_uniform_sampling : bool, default=False
        Density weights for non-uniform input.

    Returns
    -------
    new_points : (m, 3) float
        NEW points (not a subset of the input), m ~= percentage/100 * n.
        Deterministic across calls and processes.
    """
    func = "wlop"
    X = as_points(points, func=func, min_points=2)
    pct = _check_real(percentage, "percentage", func, 0.0, 100.0)
    iterations = _check_int(iterations, "iterations", func, 1)
    r = float(neighbor_radius)
    if not math.isfinite(r):
        raise InvalidParameterError(
            f"{func}: neighbor_radius must be finite, got {neighbor_radius!r}")
    from CGAL.CGAL_Point_set_3 import Point_set_3

    Xc, c = centered(X)
    ps = to_point_set(Xc, ids=False)
    out = Point_set_3()
    _psp().wlop_simplify_and_regularize_point_set(
        ps, out, pct, r if r > 0 else -1.0, iterations, bool(require_uniform_sampling))
    return point_set_points(out) + c


def random_simplify(points, fraction: float, seed: int | None = 0) -> np.ndarray:
    """Uniform random subset of ``round(fraction * n)`` points (at least 1).

    NumPy (``default_rng(seed).choice`` without replacement) instead of CGAL's
    ``random_simplify_point_set``, which draws from an unseedable global RNG;
    both are the same uniform subsampling.  Returns sorted kept indices.
    """
    func = "random_simplify"
    X = as_points(points, func=func)
    fraction = _check_real(fraction, "fraction", func, 0.0, 1.0)
    if seed is not None and (isinstance(seed, (bool, np.bool_))
                             or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise InvalidParameterError(
            f"{func}: seed must be a non-negative integer or None, got {seed!r}")
    m = max(1, int(round(fraction * len(X))))
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(len(X), size=m, replace=False)).astype(np.int64)


def _closest(best, count, value, key):
    if best is None or abs(count - key) < abs(best[0] - key):
        return (count, value)
    return best


def _prepare_count(points, count, rtol, func):
    X = as_points(points, func=func, min_points=2)
    count = _check_count(count, len(X), func)
    rtol = _check_real(rtol, "rtol", func, 0.0, 1.0, low_open=False)
    Xc, _ = centered(X)
    return X, Xc, count, rtol


def _grid_search(ps, Xc, count: int, rtol: float, max_iter: int) -> float:
    """Cell size keeping about ``count`` points; leaves ``ps`` simplified with it."""
    psp = _psp()

    def run(cell: float) -> int:
        ps.cancel_removals()
        psp.grid_simplify_point_set(ps, cell)
        return ps.size()

    diag = float(np.linalg.norm(Xc.max(0) - Xc.min(0)))
    lo, hi = math.log(diag * 1e-7), math.log(diag * 2.0)   # lo keeps ~all, hi keeps 1
    best = None
    for _ in range(max_iter):
        mid = 0.5 * (lo + hi)
        got = run(math.exp(mid))
        best = _closest(best, got, mid, count)
        if abs(got - count) <= rtol * count:
            break
        if got > count:
            lo = mid
        else:
            hi = mid
    cell = math.exp(best[1])
    got = run(cell)
    if abs(got - count) > rtol * count:
        log.info("grid_simplify_count: kept %d points for a target of %d "
                 "(tolerance %.3g)", got, count, rtol)
    return cell


def grid_cell_for_count(points, count: int, rtol: float = COUNT_RTOL,
                        max_iter: int = 60) -> float:
    """Cell size (cloud units) for which :func:`grid_simplify` keeps about
    ``count`` points (see :func:`grid_simplify_count`).  Benches time
    ``grid_simplify(points, cell)`` with it, without the search."""
    func = "grid_cell_for_count"
    X, Xc, count, rtol = _prepare_count(points, count, rtol, func)
    return _grid_search(to_point_set(Xc), Xc, count, rtol, max_iter)


def grid_simplify_count(points, count: int, rtol: float = COUNT_RTOL, max_iter: int = 60
                        ) -> np.ndarray:
    """:func:`grid_simplify` with the cell size found by bisection so that about
    ``count`` points are kept.

    The kept count is a non-increasing step function of the cell size (up to
    grid-alignment jitter); the cell is bisected in log scale until
    ``|kept - count| <= rtol * count`` (default 1 %) or ``max_iter`` steps, and
    the closest result found is returned (logged at info level when outside the
    tolerance; e.g. when several cells change at once on tiny clouds).
    Returns sorted kept indices.  The search costs ~20 grid passes; time
    :func:`grid_simplify` with :func:`grid_cell_for_count` to bench the method.
    """
    func = "grid_simplify_count"
    X, Xc, count, rtol = _prepare_count(points, count, rtol, func)
    if count == len(X):
        return np.arange(len(X), dtype=np.int64)
    ps = to_point_set(Xc)
    _grid_search(ps, Xc, count, rtol, max_iter)
    return _kept(ps, len(X), func)


def _hierarchy_search(ps, n: int, count: int, rtol: float, max_iter: int
                      ) -> tuple[int, float]:
    """(size, maximum_variation) keeping about ``count`` points; leaves ``ps``
    simplified with them."""
    psp = _psp()
    var0 = 1.0 / 3.0

    def run(size: int, var: float) -> int:
        ps.cancel_removals()
        psp.hierarchy_simplify_point_set(ps, int(size), float(var))
        return ps.size()

    lo, hi = 1, min(n, max(2, math.ceil(2.0 * n / count)))   # size=1 keeps all points
    got = run(hi, var0)
    best = _closest(None, got, (hi, var0), count)              # (kept, (size, var))
    while got > count and hi < n:            # expand until kept(hi) <= count
        lo, hi = hi, min(n, 2 * hi)
        got = run(hi, var0)
        best = _closest(best, got, (hi, var0), count)
    while hi - lo > 1:                       # invariant: kept(lo) > count >= kept(hi)
        mid = (lo + hi) // 2
        got = run(mid, var0)
        best = _closest(best, got, (mid, var0), count)
        if got > count:
            lo = mid
        else:
            hi = mid
    if abs(best[0] - count) > rtol * count and hi >= 4:
        vlo, vhi = math.log(1e-6), math.log(var0)   # vlo keeps more, vhi keeps fewer
        for _ in range(max_iter):
            if abs(best[0] - count) <= rtol * count:
                break
            mid = 0.5 * (vlo + vhi)
            got = run(hi, math.exp(mid))
            best = _closest(best, got, (hi, math.exp(mid)), count)
            if got > count:
                vlo = mid
            else:
                vhi = mid
    got = run(*best[1])
    if abs(got - count) > rtol * count:
        log.info("hierarchy_simplify_count: kept %d points for a target of %d "
                 "(tolerance %.3g)", got, count, rtol)
    return int(best[1][0]), float(best[1][1])


def hierarchy_params_for_count(points, count: int, rtol: float = COUNT_RTOL,
                               max_iter: int = 40) -> tuple[int, float]:
    """``(size, maximum_variation)`` for which :func:`hierarchy_simplify` keeps
    about ``count`` points (see :func:`hierarchy_simplify_count`).  Benches time
    ``hierarchy_simplify(points, size, var)`` with them, without the search."""
    func = "hierarchy_params_for_count"
    X, Xc, count, rtol = _prepare_count(points, count, rtol, func)
    if count == len(X):
        return 1, 1.0 / 3.0
    return _hierarchy_search(to_point_set(Xc), len(X), count, rtol, max_iter)


def hierarchy_simplify_count(points, count: int, rtol: float = COUNT_RTOL,
                             max_iter: int = 40) -> np.ndarray:
    """:func:`hierarchy_simplify` tuned to keep about ``count`` points.

    The cluster ``size`` is an integer, so it only brackets the target (on a
    100K bunny, size 28-30 keep 4.7-5.2 %; size 2 keeps 61 %, size 3 43 %).
    Step 1 bisects the integer size to the smallest size keeping <= count at
    CGAL's default ``maximum_variation`` 1/3; step 2 lowers
    ``maximum_variation`` (more splitting in curved regions, more points) by
    log-scale bisection in [1e-6, 1/3] at that size until
    ``|kept - count| <= rtol * count`` (default 1 %).  The closest result found
    is returned.  Returns sorted kept indices.  The search costs 10-40
    hierarchy passes; time :func:`hierarchy_simplify` with
    :func:`hierarchy_params_for_count` to bench the method.

    Targets between kept(size=2) and kept(size=3) (about 43-61 % of a surface
    cloud) are NOT reachable: clusters of <= 3 points are always coplanar
    (variation 0) and never split by the variation test, so only the nearer of
    the two counts can be returned; check ``len(kept)`` in benches.
    """
    func = "hierarchy_simplify_count"
    X, Xc, count, rtol = _prepare_count(points, count, rtol, func)
    if count == len(X):
        return np.arange(len(X), dtype=np.int64)
    ps = to_point_set(Xc)
    _hierarchy_search(ps, len(X), count, rtol, max_iter)
    return _kept(ps, len(X), func)


# ----------------------------------------------------------------------------------------
# spacing
# ----------------------------------------------------------------------------------------

def average_spacing_cgal(points, k: int = 6) -> float:
    """CGAL ``compute_average_spacing(ps, k)``, the raw CGAL value.

    CGAL queries k + 1 neighbours including the point itself and divides the
    sum of distances by k + 1, so it equals ``k / (k + 1)`` times pcprep's h
    (``pcprep.filters.neighbors.average_spacing``: mean distance to the k nearest
    OTHER points); multiply by ``(k + 1) / k`` to compare.
    """
    func = "average_spacing_cgal"
    X = as_points(points, func=func, min_points=2)
    k = _check_int(k, "k", func, 1)
    Xc, _ = centered(X)
    return float(_psp().compute_average_spacing(to_point_set(Xc, ids=False), k))
