"""
multiscale.py
-------------
The steps that sharp-feature detection (``sharp.py``) and hole-boundary
detection (``holes.py``) share, thesis ch.7 (§7.3.2-§7.3.5):

1. the scale sizes and one sorted k-NN query serving every scale
   (``scale_moments``: each scale's centroid, covariance eigenvalues and normal);
2. the column standardisation, the K-SVD dictionary and the code of every
   point, reduced to one code-length score per point (``code_lengths``);
3. Otsu's threshold and the chaining of nearby points (``chain_labels``).

What each detector computes from the moments, and how it selects points from
the score, lives in its own module.  The measured reasons behind each choice
are in docs/decisions/features.md.
"""

from __future__ import annotations

import contextlib
import contextvars
from dataclasses import dataclass
from typing import Iterator

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from . import _kernels, neighbors, sparse
from ._params import Param
from ._validation import InvalidParameterError, as_normals, as_points, check_spread
from .neighbors import CHUNK, build_tree, centered, knn, leaf_chunks

#: floor of the robust feature scale, as a fraction of the column's std
_MAD_FLOOR = 0.3
#: points per chunk of the multi-scale moments and of the per-point fits
MOMENT_CHUNK = CHUNK // 4


# ---------------------------------------------------------------------------
# scales and moments
# ---------------------------------------------------------------------------

#: the steps of a detector run inside ``trace_steps()`` (None outside one)
_TRACE: contextvars.ContextVar = contextvars.ContextVar("pcprep_detection_steps",
                                                        default=None)


@contextlib.contextmanager
def trace_steps():
    """Record the detection mask after each step of the detectors run inside the
    block (threshold, then each gate in the order applied).

    Yields a list that fills with ``(step name, mask copy)`` pairs; the benchmark
    reads it to say at which step a missed feature was dropped.  Outside the
    block nothing is recorded and nothing is copied.

    >>> with trace_steps() as steps:
    ...     record_step("threshold", np.array([True, False]))
    >>> [name for name, _ in steps]
    ['threshold']
    """
    steps: list = []
    token = _TRACE.set(steps)
    try:
        yield steps
    finally:
        _TRACE.reset(token)


def record_step(name: str, mask: np.ndarray) -> None:
    """Append a copy of ``mask`` under ``name`` to the active ``trace_steps`` list."""
    steps = _TRACE.get()
    if steps is not None:
        steps.append((name, np.array(mask, dtype=bool, copy=True)))


def scale_sizes(k_min: int, k_max: int, n_scales: int) -> np.ndarray:
    """Neighbourhood sizes of the scales (each counts the point itself).

    ``n_scales`` integers from ``k_min`` to ``k_max``, geometrically spaced,
    duplicates removed, so the result is strictly increasing and may be shorter
    than ``n_scales``.

    >>> scale_sizes(8, 40, 10).tolist()
    [8, 10, 11, 14, 16, 20, 23, 28, 33, 40]
    """
    if n_scales == 1:
        return np.array([k_min], dtype=np.int64)
    return np.unique(np.round(np.geomspace(k_min, k_max, n_scales)).astype(np.int64))


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
        Unit eigenvector of λ0 (sign arbitrary): the largest cross product of
        two rows of ``cov − λ0 I``.

    >>> lam, n = sym3_eig(np.diag([3.0, 1.0, 2.0]))
    >>> lam.round(12).tolist(), np.abs(n).tolist()
    ([1.0, 2.0, 3.0], [0.0, 1.0, 0.0])
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


@dataclass(frozen=True)
class ScaleMoments:
    """The moments of one chunk of points at every scale (``scale_moments``).

    Attributes
    ----------
    rows : (c,) int
        The points of the chunk.
    dist : (c, k_max) float
        Distances to the k_max nearest neighbours, sorted (column 0 is the
        point itself).
    idx : (c, k_max) int
        Their indices.
    points : (n, 3) float
        The cloud the indices refer to (``offsets`` gathers from it).
    mean : (c, s, 3) float
        Centroid of each scale's neighbourhood relative to the point, ``p̄ − p_i``.
    eigenvalues : (c, s, 3) float
        λ0 ≤ λ1 ≤ λ2 of each scale's covariance (7.1), with the 1/(k − 1) factor.
    normal : (c, s, 3) float
        Unit eigenvector of λ0 at each scale (sign arbitrary).
    """

    rows: np.ndarray
    dist: np.ndarray
    idx: np.ndarray
    points: np.ndarray
    mean: np.ndarray
    eigenvalues: np.ndarray
    normal: np.ndarray

    @property
    def offsets(self) -> np.ndarray:
        """(c, k_max, 3) neighbour positions relative to the point, ``p_j − p_i``
        (gathered on each access; the compiled kernels read the cloud instead)."""
        return neighbour_offsets(self.points, self.idx, self.rows)


def neighbour_offsets(points: np.ndarray, idx: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``points[idx] − points[rows]``: (c, k, 3) offsets of each row's neighbours,
    the subtraction the compiled kernels do element by element."""
    x = points[idx]
    x -= points[rows, None, :]
    return x


def scale_moments(points: np.ndarray, ks: np.ndarray, *, tree=None,
                  weighted: bool = False) -> Iterator[ScaleMoments]:
    """Centroid and covariance of every point's neighbourhood at every scale.

    One k-NN query with ``k = ks[-1]`` (neighbours sorted by distance) serves
    all scales: block sums of ``x = p_j − p_i`` and of ``x xᵀ`` between
    consecutive sizes, accumulated over the blocks, give each scale's mean and
    covariance in O(n·k_max).  The covariance is (7.1) with uniform weights
    (see docs/decisions/features.md, section "Uniform weights in (7.1)");
    ``weighted`` gives (7.1) as printed, each scale's own pass in O(n·k):
    ``w_j = exp(−d_j²/s²)``, d_j = ‖p_j − p̄‖, with s the scale's mean d_j
    where the thesis writes the count k_i (a length, as for (6.1)).

    Parameters
    ----------
    points : (n, 3) float
        Centred cloud, in model units.
    ks : (s,) int
        Increasing neighbourhood sizes (each counts the point itself).
    tree : cKDTree, optional
        The k-d tree of ``points`` (built when omitted).

    Yields
    ------
    ScaleMoments
        One per chunk of ``MOMENT_CHUNK`` points; the chunks follow the tree's
        leaf order (``neighbors.leaf_order``), which makes the query several
        times faster than the input order, and together cover every point once.
    """
    ks = np.asarray(ks, dtype=np.int64)
    tree = build_tree(points) if tree is None else tree
    k_max = int(ks[-1])
    starts = np.concatenate([[0], ks[:-1]])
    kf = ks.astype(np.float64)
    corr = kf / np.maximum(kf - 1.0, 1.0)                       # 1/(k−1) of (7.1)
    iu = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))
    for rows in leaf_chunks(tree, MOMENT_CHUNK):
        c = len(rows)
        dist, idx = knn(points, k_max, tree=tree, query=points[rows])
        if _kernels.ENABLED and not weighted:
            parts = _kernels.run_chunks(lambda s, e: _kernels.scale_moments(
                points, idx[s:e], rows[s:e], ks, corr), c, _kernels.TASK_ROWS)
            mean, lam, nrm = _kernels.stack_parts(parts, 3)
            yield ScaleMoments(rows, dist, idx, points, mean, lam, nrm)
            continue
        x = neighbour_offsets(points, idx, rows)                # (c, k, 3)
        xt = np.ascontiguousarray(x.transpose(2, 0, 1))         # (3, c, k)
        mean = np.cumsum(np.add.reduceat(xt, starts, axis=2), axis=2) / kf  # (3, c, S)
        cov = np.empty((c, len(ks), 3, 3))  # noqa: NPY-empty -- all 9 entries set
        for i, j in zip(*iu):
            s2 = np.cumsum(np.add.reduceat(xt[i] * xt[j], starts, axis=1), axis=1)
            cij = (s2 / kf - mean[i] * mean[j]) * corr
            cov[..., i, j] = cij
            cov[..., j, i] = cij
        if weighted:
            cov = _weighted_covariances(x, ks, np.moveaxis(mean, 0, -1), corr)
        lam, nrm = sym3_eig(cov)                                # (c, S, 3)
        yield ScaleMoments(rows, dist, idx, points, np.moveaxis(mean, 0, -1), lam, nrm)


def _weighted_covariances(x: np.ndarray, ks: np.ndarray, mean: np.ndarray,
                          corr: np.ndarray) -> np.ndarray:
    """(7.1) with w_j = exp(−d_j²/s²) about each scale's centroid: (c, S, 3, 3)."""
    cov = np.empty((len(x), len(ks), 3, 3))  # noqa: NPY-empty -- every scale written
    for j, k in enumerate(ks):
        y = x[:, :k] - mean[:, j, None, :]                      # p_j − p̄
        d2 = np.einsum("ckd,ckd->ck", y, y)
        s2 = np.maximum(np.sqrt(d2).mean(axis=1), 1e-300) ** 2
        w = np.exp(-d2 / s2[:, None])
        cov[:, j] = np.einsum("ck,ckd,cke->cde", w, y, y) / k * corr[j]
    return cov


# ---------------------------------------------------------------------------
# standardisation, dictionary, codes
# ---------------------------------------------------------------------------

def column_scale(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-column centre and scale of the robust standardisation.

    ``median`` of each column and ``s = max(1.4826·MAD, 0.3·std)`` (1 where
    s = 0), column by column so that the temporaries are one column long per
    thread (the columns are independent; NumPy's partition releases the GIL,
    so they run on the kernels' thread pool, ``_kernels.run_chunks``).  These
    are the global state of the standardisation: computed once over the whole
    cloud and applied to any rows (``standardise``).  A column longer than
    ``neighbors.MEDIAN_COPY_ROWS`` (a tiled run's memory map) is read in
    chunks instead of copied, to the same values bit for bit.
    """
    def stats(j: int) -> tuple[float, float, float]:
        if len(F) > neighbors.MEDIAN_COPY_ROWS:
            col = F[:, j]
            m = neighbors.median(col)
            return m, neighbors.median(col, lambda c: np.abs(c - m)), neighbors.mean_std(col)[1]
        col = np.array(F[:, j], dtype=np.float64)      # a private copy, reused:
        std = col.std()                                 # std first (row order),
        m = np.median(col, overwrite_input=True)        # then medians in place
        np.subtract(col, m, out=col)
        np.abs(col, out=col)
        return m, np.median(col, overwrite_input=True), std

    med, mad, std = (np.array(v, dtype=np.float64) for v in zip(
        *_kernels.run_chunks(lambda s, e: stats(s), F.shape[1], 1)))
    scale = np.maximum(1.4826 * mad, _MAD_FLOOR * std)
    return med, np.where(scale > 0, scale, 1.0)


def standardise(F: np.ndarray, med: np.ndarray | None = None,
                scale: np.ndarray | None = None, *, overwrite: bool = False) -> np.ndarray:
    """Robust one-sided standardisation of the feature columns.

    ``z = max(0, (F − median) / s)`` per column, with
    ``s = max(1.4826·MAD, 0.3·std)`` (1 where s = 0) from ``column_scale``
    (given, or computed from ``F``).  The columns must be oriented so that
    larger means more feature-like; the bulk of ordinary points then maps to
    (near) zero.  Rows are standardised in chunks, into ``F`` itself with
    ``overwrite`` (then the result is ``F``).  See
    docs/decisions/features.md, section "Robust one-sided standardisation".

    >>> standardise(np.array([[0.0], [1.0], [2.0], [10.0]])).ravel().round(3).tolist()
    [0.0, 0.0, 0.337, 5.733]
    """
    if med is None or scale is None:
        med, scale = column_scale(F)
    Z = F if overwrite else np.empty(F.shape)  # noqa: NPY-empty -- every chunk written
    for s0 in range(0, len(F), CHUNK):  # one temporary per chunk, the same bits
        z = F[s0:s0 + CHUNK] - med
        z /= scale
        Z[s0:s0 + CHUNK] = np.maximum(z, 0.0, out=z)
    return Z


#: constraints of the shared stage's parameters, the tail of both detectors'
#: declarations (each detector's signature holds its own defaults)
SCORE_PARAMS = (
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

@dataclass(frozen=True)
class ScoreConfig:
    """Parameters of the shared stage: scales, dictionary and coding.

    The fields are the detectors' parameters of the same names (see
    ``detect_sharp_features``); they arrive validated.
    """

    n_scales: int
    k_min: int
    k_max: int
    n_atoms: int
    coder: str
    alpha: float
    tol: float
    score: str
    max_iter: int
    max_train: int
    seed: int | None


@dataclass(frozen=True)
class CodeLengths:
    """The coded features (``code_lengths``).

    Attributes
    ----------
    score : (n,) float
        Code-length score f of every point (higher = rarer).
    nnz : (n,) int
        Atoms in each code, ``f(α_j)`` of (7.8)-(7.9).
    residual : (n,) float
        ``‖z_j − α_j D‖₂`` of each standardised feature vector.
    dictionary : (n_atoms, d) float
        The learned K-SVD dictionary (rows are atoms).
    """

    score: np.ndarray
    nnz: np.ndarray
    residual: np.ndarray
    dictionary: np.ndarray


@dataclass(frozen=True)
class ScoreModel:
    """The global state of the code-length score, fitted once per cloud
    (``fit_score_model``) and applied to any rows (``score_rows``).

    Attributes
    ----------
    median, scale : (d,) float
        The standardisation of each feature column (``column_scale``).
    dictionary : (n_atoms, d) float
        The K-SVD dictionary (rows are atoms).
    train : (t,) int
        The rows it was learned on (the first ``max_train`` in content order).
    """

    median: np.ndarray
    scale: np.ndarray
    dictionary: np.ndarray
    train: np.ndarray


def fit_score_model(F: np.ndarray, cfg: ScoreConfig) -> ScoreModel:
    """Standardisation and K-SVD dictionary of the features ``F``.

    A dictionary of ``cfg.n_atoms`` atoms (§7.3.2, Alg. 3.3, ⌊d/10⌋ atoms per
    training signal) is learned on the first ``cfg.max_train`` standardised
    rows in content order (``sparse.content_order``): the subsample follows
    the rotation-invariant features, not the row order, so a permuted or
    rotated cloud gets the same dictionary.
    """
    med, scale = column_scale(F)
    d = F.shape[1]
    L = max(1, min(d, cfg.n_atoms) // 10)
    first = sparse.FirstInOrder(cfg.max_train)  # not one key per row kept

    def hash_rows(s0: int, e: int) -> None:     # NumPy releases the GIL: threads
        first.add(sparse.content_keys(standardise(F[s0:e], med, scale), cfg.seed), s0)

    _kernels.run_chunks(hash_rows, len(F), CHUNK)
    train = first.rows()
    Zt = standardise(F[train], med, scale)
    D = sparse.ksvd(Zt, cfg.n_atoms, n_nonzero_coefs=L, max_iter=cfg.max_iter,
                    max_train=len(train), seed=cfg.seed, code_all=False).dictionary
    return ScoreModel(median=med, scale=scale, dictionary=D, train=train)


def score_rows(F: np.ndarray, model: ScoreModel, cfg: ScoreConfig, *,
               overwrite: bool = False) -> CodeLengths:
    """Code every row of ``F`` on the model's dictionary and score its code.

    Each row is standardised with the model, then coded by OMP to the squared
    residual ``tol·d`` or by the Lasso (``coder="lasso_lars"``, penalty
    ``alpha``).  The score is ``‖α_j‖₁ + r_j`` (``score="l1"``) or the atom
    count (7.8) plus ``r_j/(1 + r_j)`` as a tie-break (``score="count"``), r_j
    the residual.  A row's result depends on that row and the model only.
    With ``overwrite`` the rows are standardised in ``F`` itself (float64,
    C-contiguous), which saves one copy of the feature matrix.
    """
    Z = standardise(F, model.median, model.scale, overwrite=overwrite)
    D = model.dictionary
    d = Z.shape[1]
    if cfg.coder == "omp":
        # signals already within the residual target need no atom (most
        # ordinary points); only the others are pursued
        busy = np.flatnonzero(np.einsum("ij,ij->i", Z, Z) > cfg.tol * d)
        if len(busy):
            part = sparse.omp(Z, D, tol=cfg.tol * d, rows=busy).tocoo()
            codes = sp.csr_matrix((part.data, (busy[part.row], part.col)),
                                  shape=(len(Z), D.shape[0]))
        else:  # a tolerance every signal already meets: no atom for anyone
            codes = sp.csr_matrix((len(Z), D.shape[0]))
    else:
        codes = sparse.lasso_lars(Z, D, alpha=cfg.alpha)
    nnz, resid = sparse.code_length(codes, Z, D)
    del Z
    if cfg.score == "count":
        score = nnz + resid / (1.0 + resid)     # the tie-break is in [0, 1)
    else:
        l1 = np.asarray(abs(codes.tocsr()).sum(axis=1)).ravel()
        score = l1 + resid
    return CodeLengths(score=score, nnz=nnz, residual=resid, dictionary=D)


def code_lengths(F: np.ndarray, cfg: ScoreConfig) -> CodeLengths:
    """Standardise, learn a dictionary, code every point, score its code:
    ``score_rows(F, fit_score_model(F, cfg), cfg)``.

    Parameters
    ----------
    F : (n, d) float
        Features, oriented so that larger means more feature-like.
    cfg : ScoreConfig

    Returns
    -------
    CodeLengths
    """
    return score_rows(F, fit_score_model(F, cfg), cfg)


# ---------------------------------------------------------------------------
# the cloud, the threshold, chains
# ---------------------------------------------------------------------------

def prepare_cloud(points, normals, *, k_min: int, k_max: int, func: str):
    """Validate a detector's input and centre it.

    Raises ``InvalidParameterError`` when ``k_min > k_max`` and
    ``PointCloudError`` for an empty or non-finite cloud, fewer than
    ``k_max + 1`` points, normals of the wrong shape, or collinear points.

    Returns
    -------
    points : (n, 3) float
        The centred cloud (a copy).
    tree : cKDTree
        Its k-d tree.
    """
    if k_min > k_max:
        raise InvalidParameterError(
            f"{func}: k_min must be <= k_max, got k_min={k_min}, k_max={k_max}")
    pts = as_points(points, func=func, min_points=k_max + 1)
    if normals is not None:
        as_normals(normals, len(pts), func=func)
    check_spread(pts, func=func)
    pts, _ = centered(pts)
    return pts, build_tree(pts)


#: leading values of ``otsu_threshold`` tested for more than ``bins`` distinct ones
_DISTINCT_PROBE = 8192


def otsu_threshold(values: np.ndarray, bins: int = 256, clip: float | None = None) -> float:
    """Otsu's threshold (maximal between-class variance) of ``values``, or of
    ``np.minimum(values, clip)`` when ``clip`` is given.

    A score with at most ``bins`` distinct values gets one bin per value.
    The values are read in chunks (``neighbors._SCAN`` rows) and their counts
    added, which are those of the whole array, so a memory map of a tiled
    run's every score is neither copied nor clipped in a copy.  Returns t;
    the upper class is ``values > t``.

    >>> otsu_threshold(np.r_[np.ones(90), 5 * np.ones(10)])
    3.0
    """
    v = np.asarray(values, dtype=np.float64).ravel()
    clipped = None if clip is None else (lambda c: np.minimum(c, clip))
    scan = neighbors._SCAN

    def chunks():
        for s in range(0, len(v), scan):
            yield v[s:s + scan] if clipped is None else clipped(v[s:s + scan])

    lo, hi = neighbors._extent(v, clipped)
    if hi <= lo:
        return hi
    # more than ``bins`` distinct values among the first rows settles it without
    # sorting every value (a continuous score, the usual case)
    head = v[:_DISTINCT_PROBE] if clipped is None else clipped(v[:_DISTINCT_PROBE])
    centers = _distinct_counts(chunks(), bins) if len(np.unique(head)) <= bins else None
    if centers is not None:
        centers, counts = centers
        cuts = 0.5 * (centers[:-1] + centers[1:])
    else:
        counts = np.zeros(bins)
        for c in chunks():
            counts += np.histogram(c, bins=bins, range=(lo, hi))[0]
        edges = np.histogram_bin_edges(v[:0], bins=bins, range=(lo, hi))
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


def _distinct_counts(chunks, most: int):
    """The distinct values of the chunks and their counts (float64), merged
    chunk by chunk; None once there are more than ``most`` of them."""
    centers, counts = np.empty(0), np.empty(0)
    for c in chunks:
        u, k = np.unique(c, return_counts=True)
        centers, at = np.unique(np.r_[centers, u], return_inverse=True)
        counts = np.bincount(at, weights=np.r_[counts, k], minlength=len(centers))
        if len(centers) > most:
            return None
    return centers, counts


#: query points per chunk of ``chain_labels``' pair search (at least; see there)
CHAIN_CHUNK = 1 << 15
#: the most chunks ``chain_labels`` cuts a cloud into (the NumPy merge rereads
#: every point's chain once per chunk)
_CHAIN_PARTS = 64


def chain_labels(points: np.ndarray, link: float, *, chunk: int = CHAIN_CHUNK) -> np.ndarray:
    """Connected-component label of each point, points closer than ``link``
    being joined (``points`` (m, 3)).  Chains are numbered by their smallest
    row, as ``scipy.sparse.csgraph.connected_components`` numbers them.

    The pairs within ``link`` are found for ``chunk`` points at a time (a
    tree over the chunk against the tree over all, ``sparse_distance_matrix``)
    and joined in a union-find forest whose roots are each chain's smallest
    row (``_kernels.join_min``; ``_join_chunk`` without the kernels).  So
    only one chunk's pairs are held, never every pair of the cloud: a
    border's points have tens of others within the link, and a tiled run
    chains every detection of the cloud on its driver.  The chunks follow the
    tree's leaf order, so each is a compact piece of space whose search
    prunes most of the tree (in input order a shuffled cloud took 8x as
    long).  The chunk grows so that there are at most ``_CHAIN_PARTS``.

    >>> chain_labels(np.array([[0.0, 0, 0], [1, 0, 0], [5, 0, 0]]), 1.5).tolist()
    [0, 0, 1]
    """
    m = len(points)
    chunk = max(int(chunk), -(-m // _CHAIN_PARTS), 1)
    tree = build_tree(points)
    root = np.arange(m)
    for s in range(0, m, chunk):
        rows = tree.indices[s:s + chunk]
        pairs = build_tree(points[rows]).sparse_distance_matrix(
            tree, link, output_type="ndarray")
        i, j = rows[pairs["i"]], pairs["j"]
        once = j > i  # each pair is found from both ends
        if _kernels.ENABLED:
            _kernels.join_min(root, i[once], j[once])
        else:
            root = _join_chunk(root, i[once], j[once])
    while True:  # every point straight under its root (pointer jumping)
        up = root[root]
        if np.array_equal(up, root):
            break
        root = up
    first = root == np.arange(m)
    return (np.cumsum(first) - 1)[root]


def _join_chunk(first: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """``chain_labels``' union-find step in NumPy: ``first`` holds every
    point's chain by its smallest row; the chains the pairs (i, j) join
    take the smallest of theirs (connected components of the graph over the
    chains the pairs touch).  Returns the new ``first``."""
    a, b = first[i], first[j]
    cut = a != b
    if not cut.any():
        return first
    ends, at = np.unique(np.r_[a[cut], b[cut]], return_inverse=True)  # ascending
    k = int(cut.sum())
    graph = sp.coo_matrix((np.ones(k, np.int8), (at[:k], at[k:])),
                          shape=(len(ends), len(ends)))
    joined = connected_components(graph, directed=False)[1]
    # ``ends`` ascends, so each joined chain's first entry is its smallest row
    remap = np.arange(len(first))
    remap[ends] = ends[np.unique(joined, return_index=True)[1]][joined]
    return remap[first]


@dataclass(frozen=True)
class Detection:
    """What both detectors return (``SharpResult`` and ``HoleResult`` add
    their own diagnostics).

    Attributes
    ----------
    mask : (n,) bool
        Detected points, in input order.
    score : (n,) float
        Code-length score f (higher = rarer).
    threshold : float
        The threshold T applied to ``score``.
    quality : (n,) float
        ``mask`` as 1.0 / 0.0 (the vertex quality written by the bridge).
    nnz : (n,) int
        Atoms in each point's code, ``f(α_j)`` of (7.8)-(7.9).
    residual : (n,) float
        ``‖z_j − α_j D‖₂`` of each standardised feature vector.
    scales : (s,) int
        Neighbourhood sizes used (each counts the point itself).
    dictionary : (n_atoms, d) float
        The learned K-SVD dictionary (rows are atoms).
    h : float
        Average spacing (mean distance to the 6 nearest neighbours), input units.
    beta : float or None
        β of (7.10) when given; None when the threshold came from Otsu.
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
