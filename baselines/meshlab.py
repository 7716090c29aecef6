"""
meshlab.py
----------
MeshLab baselines through pymeshlab: MLS projection (APSS, RIMLS), Poisson-disk
and simplified-cloud subsampling, ball pivoting and PCA normals, as plain
functions on NumPy arrays.

Every runner is a module-level function taking and returning float64 arrays,
so that benches can run it crash-isolated::

    from pcprep.baselines import harness, meshlab
    out = harness.measure(meshlab.rimls, points, normals)

Some of these filters segfault on inputs or parameter combinations they do not
expect (MLS projection of a layer onto itself, a point cloud without normals);
the runners use recipes that avoid those cases and validate inputs first, but
always run them under ``harness.run_isolated``.
Coordinates are centred (bounding-box centre) before they reach MeshLab and
shifted back on output, as pcprep's own filters do, so clouds far from the
origin are treated alike.
"""

from __future__ import annotations

import logging

import numpy as np

from pcprep.filters._validation import InvalidParameterError, as_normals, as_points, check_param
from pcprep.filters.neighbors import centered

log = logging.getLogger("pcprep")


def _meshset():
    import pymeshlab

    return pymeshlab, pymeshlab.MeshSet()


def _check_positive(value, name: str, func: str) -> float:
    return check_param(value, func=func, name=name, kind=float, low=0.0, closed="neither")


def _check_count(count, n: int, func: str) -> int:
    return check_param(count, func=func, name="count", kind=int, low=1, high=n)


def _mls(kind: str, points, normals, params: dict) -> tuple[np.ndarray, np.ndarray]:
    """Project the cloud onto its own MLS surface: a control layer and an identical
    proxy layer, the control current (MeshLab crashes when the two are one layer)."""
    func = kind
    X = as_points(points, func=func, min_points=4)
    N = as_normals(normals, len(X), func=func)
    if not (np.linalg.norm(N, axis=1) > 0).all():
        raise InvalidParameterError(
            f"{func}: normals must be non-zero (oriented normals needed)")
    Xc, c = centered(X)
    pymeshlab, ms = _meshset()
    m = pymeshlab.Mesh(vertex_matrix=Xc, v_normals_matrix=N)
    ms.add_mesh(m, "control")                         # id 0, current
    ms.add_mesh(m, "proxy", set_as_current=False)     # id 1, a copy
    ms.set_current_mesh(0)                            # current MUST be the control layer
    name = f"compute_mls_projection_{kind}"
    ms.apply_filter(name, controlmesh=0, proxymesh=1, selectiononly=False, **params)
    Y = np.array(ms.mesh(1).vertex_matrix(), dtype=np.float64)
    NY = np.array(ms.mesh(1).vertex_normal_matrix(), dtype=np.float64)
    if Y.shape != X.shape:
        raise RuntimeError(
            f"{func}: MeshLab returned {Y.shape[0]} points for {X.shape[0]}")
    bad = ~np.isfinite(Y).all(axis=1) | ~np.isfinite(NY).all(axis=1)
    if bad.any():
        log.info("%s: %d point(s) without an MLS fit kept unchanged",
                 func, int(bad.sum()))
        Y[bad] = Xc[bad]
        NY[bad] = N[bad]
    lens = np.linalg.norm(NY, axis=1, keepdims=True)
    NY = np.divide(NY, lens, out=N.copy(), where=lens > 0)
    return Y + c, NY


def apss(points, normals, filterscale: float = 2.0, sphericalparameter: float = 1.0,
         maxprojectioniters: int = 15, accuratenormal: bool = True
         ) -> tuple[np.ndarray, np.ndarray]:
    """APSS projection (Guennebaud & Gross 2007) of the cloud onto its own MLS surface.

    Parameters
    ----------
    points : (n, 3) float
        The cloud.
    normals : (n, 3) float
        CONSISTENTLY ORIENTED normals (required: with zero normals MeshLab returns
        NaN everywhere, half-flipped normals ruin the fit).  The benches use
        ``pcprep.filters.neighbors.pca_normals`` (PCA + MST orientation).
    filterscale : float, default=2.0
        Support radius as a multiple of MeshLab's per-point radius d_16/2 (so 2
        is about the distance to the 16th neighbour); relative to LOCAL spacing.
    sphericalparameter : float, default=1.0
        0 = planar fit, 1 = pure algebraic sphere.
    maxprojectioniters : int, default=15
        Newton iterations per point.
    accuratenormal : bool, default=True
        Exact MLS gradient for the output normals.

    Returns
    -------
    points : (n, 3) float
        Projected points (input order).  Points whose fit failed (NaN) keep
        their input position.
    normals : (n, 3) float
        Unit MLS normals (input normals where the fit failed).

    Notes
    -----
    Single pass against the unmodified cloud: control layer (the input) and
    proxy layer (a copy, projected) are distinct and the control layer is
    current, which avoids MeshLab's segfault when ``controlmesh == proxymesh``.
    Single-threaded, roughly O(n^2) beyond ~100K points (4.6 s at 100K, ~7 min
    at 1M).
    """
    fs = _check_positive(filterscale, "filterscale", "apss")
    return _mls("apss", points, normals, dict(
        filterscale=fs, sphericalparameter=float(sphericalparameter),
        maxprojectioniters=int(maxprojectioniters), accuratenormal=bool(accuratenormal)))


def rimls(points, normals, filterscale: float = 2.0, sigman: float = 0.75,
          maxprojectioniters: int = 15, maxrefittingiters: int = 3
          ) -> tuple[np.ndarray, np.ndarray]:
    """RIMLS projection (Öztireli, Guennebaud & Gross 2009) of the cloud onto
    its own robust implicit MLS surface.

    Parameters
    ----------
    points : (n, 3) float
        The cloud.
    normals : (n, 3) float
        CONSISTENTLY ORIENTED normals (required: without them no point moves).
    filterscale : float, default=2.0
        Support radius relative to the local spacing (see :func:`apss`).
    sigman : float, default=0.75
        Sharpness: width of the Gaussian on normal differences (0.5 sharp ... 2 smooth).
    maxprojectioniters : int, default=15
        Projection iterations per point.
    maxrefittingiters : int, default=3
        Robust refitting iterations (0 or 1 = plain IMLS).

    Returns
    -------
    points, normals : (n, 3) float
        Projected points and unit normals, input order; failed fits keep the input.

    Notes
    -----
    Same layer recipe as :func:`apss`.  RIMLS's spatial robust weight
    ``sigmar`` is not exposed by MeshLab.
    """
    fs = _check_positive(filterscale, "filterscale", "rimls")
    sn = _check_positive(sigman, "sigman", "rimls")
    return _mls("rimls", points, normals, dict(
        filterscale=fs, sigman=sn, maxprojectioniters=int(maxprojectioniters),
        maxrefittingiters=int(maxrefittingiters)))


def _subsample_indices(ms, n: int, func: str) -> np.ndarray:
    """Indices of the points of the current (generated) layer, read back from
    the quality channel that held ``arange(n)``."""
    q = np.asarray(ms.current_mesh().vertex_scalar_array(), dtype=np.float64)
    idx = np.rint(q).astype(np.int64)
    if len(idx) and (np.abs(q - idx).max() > 1e-6 or idx.min() < 0 or idx.max() >= n):
        raise RuntimeError(f"{func}: MeshLab did not carry the index channel through")
    if len(np.unique(idx)) != len(idx):
        raise RuntimeError(f"{func}: MeshLab returned duplicated points")
    return np.sort(idx)


def _indexed_meshset(points, func: str, min_points: int = 1):
    X = as_points(points, func=func, min_points=min_points)
    Xc, _ = centered(X)
    pymeshlab, ms = _meshset()
    ids = np.arange(len(X), dtype=np.float64)
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=Xc, v_scalar_array=ids), "input")
    return pymeshlab, ms, len(X)


def poisson_disk_exact(points, count: int, tolerance: float = 0.005) -> np.ndarray:
    """Poisson-disk subset of ``count`` points (Corsini et al. 2012), count
    honoured within ``tolerance`` (fraction) by MeshLab's radius bisection.

    Parameters
    ----------
    points : (n, 3) float
    count : int
        Target number of kept points, 1 <= count <= n.
    tolerance : float, default=0.005
        MeshLab's ``exactnumtolerance``.

    Returns
    -------
    kept : (m,) int64
        Sorted indices of the kept input points (m ~= count).

    Notes
    -----
    ``generate_sampling_poisson_disk(subsample=True, exactnumflag=True)``; the
    indices ride along in the quality channel (``v_scalar_array = arange(n)``),
    which MeshLab copies to the samples.  MeshLab uses a global RNG: the result
    is reproducible per fresh process (one call per process, as under the
    harness) but differs between calls in the same process.  ~8-20x slower
    than without ``exactnumflag`` (2.3 s at 100K -> 10K).
    """
    pymeshlab, ms, n = _indexed_meshset(points, "poisson_disk_exact")
    count = _check_count(count, n, "poisson_disk_exact")
    tol = _check_positive(tolerance, "tolerance", "poisson_disk_exact")
    if count == n:
        return np.arange(n, dtype=np.int64)
    ms.generate_sampling_poisson_disk(samplenum=count, subsample=True, exactnumflag=True,
                                      exactnumtolerance=tol)
    return _subsample_indices(ms, n, "poisson_disk_exact")


def simplified_cloud(points, count: int) -> np.ndarray:
    """MeshLab's "Point Cloud Simplification" (``generate_simplified_point_cloud``).

    Returns the sorted indices of the kept input points.  The count is NOT
    honoured: the Poisson radius is derived from ``count`` and the bounding-box
    area (a cloud has no triangle area), and the filter's ``exactnumflag`` is a
    no-op (asked 10K of a 100K bunny -> 18,638).  Use
    :func:`poisson_disk_exact` for a target count.
    """
    pymeshlab, ms, n = _indexed_meshset(points, "simplified_cloud")
    count = _check_count(count, n, "simplified_cloud")
    ms.generate_simplified_point_cloud(samplenum=count)
    return _subsample_indices(ms, n, "simplified_cloud")


def ball_pivoting(points, normals=None, radius: float = 0.0, clustering: float = 20.0,
                  creasethr: float = 90.0) -> tuple[np.ndarray, np.ndarray]:
    """Ball-pivoting surface reconstruction (Bernardini et al. 1999) for the
    report's figures.

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float, optional
        Orient the triangles when given.
    radius : float, default=0.0
        Ball radius in the cloud's units; 0 = MeshLab's guess (bbox diagonal / sqrt(n)).
    clustering : float, default=20.0
        Percent of the radius under which vertices are merged.
    creasethr : float, default=90.0
        Crease angle threshold in degrees.

    Returns
    -------
    vertices : (m, 3) float
        Mesh vertices (the input points; MeshLab may drop merged ones).
    faces : (f, 3) int64
        Triangles indexing ``vertices``.

    Notes
    -----
    Works best on evenly sampled clouds; on random (Monte-Carlo) samples the
    guessed radius leaves holes.  Noisy 100K clouds take about a minute.
    """
    X = as_points(points, func="ball_pivoting", min_points=3)
    N = None if normals is None else as_normals(normals, len(X), func="ball_pivoting")
    r = float(radius)
    if not np.isfinite(r) or r < 0:
        raise InvalidParameterError(f"ball_pivoting: radius must be >= 0, got {radius!r}")
    Xc, c = centered(X)
    pymeshlab, ms = _meshset()
    mesh = (pymeshlab.Mesh(vertex_matrix=Xc) if N is None
            else pymeshlab.Mesh(vertex_matrix=Xc, v_normals_matrix=N))
    ms.add_mesh(mesh, "cloud")
    ball = pymeshlab.PercentageValue(0.0) if r == 0 else pymeshlab.PureValue(r)
    ms.generate_surface_reconstruction_ball_pivoting(
        ballradius=ball, clustering=float(clustering), creasethr=float(creasethr))
    cm = ms.current_mesh()
    V = np.array(cm.vertex_matrix(), dtype=np.float64) + c
    F = np.array(cm.face_matrix(), dtype=np.int64).reshape(-1, 3)
    return V, F


def pca_normals_meshlab(points, k: int = 10, smoothiter: int = 0) -> np.ndarray:
    """MeshLab's point-cloud normals (``compute_normal_for_point_clouds``): PCA on
    the k-NN, then orientation propagation.  The global sign is arbitrary
    (inward on a sphere in tests).  Returns (n, 3) unit normals, input order."""
    X = as_points(points, func="pca_normals_meshlab", min_points=3)
    if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or k < 3:
        raise InvalidParameterError(
            f"pca_normals_meshlab: k must be an integer >= 3, got {k!r}")
    Xc, _ = centered(X)
    pymeshlab, ms = _meshset()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=Xc), "cloud")
    ms.compute_normal_for_point_clouds(k=int(k), smoothiter=int(smoothiter),
                                       flipflag=False)
    N = np.array(ms.current_mesh().vertex_normal_matrix(), dtype=np.float64)
    lens = np.linalg.norm(N, axis=1, keepdims=True)
    return np.divide(N, lens, out=np.zeros_like(N), where=lens > 0)
