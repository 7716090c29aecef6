"""
neighbors.py
------------
Neighbourhoods and local geometry shared by every filter: the average spacing
h (thesis §4.5.1), k-NN and radius neighbourhoods on scipy's cKDTree (all
cores), batched weighted PCA with the covariance features of thesis (2.4)-(2.8),
and consistent normal orientation (Hoppe 1992 MST propagation, or toward a
viewpoint).

Everything here is vectorised over points; large clouds are processed in
chunks so that the per-neighbourhood arrays stay within a few hundred MB.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from . import _kernels, progress
from ._validation import PointCloudError

#: neighbours used for the average spacing h (thesis §4.5.1)
SPACING_K = 6
#: points per chunk in batched neighbourhood computations
CHUNK = 65_536


def build_tree(points: np.ndarray) -> cKDTree:
    """cKDTree over ``points`` (balanced, no data copy beyond scipy's own)."""
    return cKDTree(points, leafsize=16, balanced_tree=False, compact_nodes=False)


def query_settled(tree: cKDTree, q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``tree.query(q, k)`` as (m, k) arrays, with equal distances in a fixed order.

    Neighbours at the same distance from a query come in the k-d tree's order,
    which depends on the rows the tree holds: a tile of a cloud and the whole
    cloud can rank them differently, or keep a different one of them as the
    k-th neighbour.  Every neighbourhood and every scale (a prefix of the list)
    would then differ between a tiled and a one-piece run wherever positions
    make exact ties, as on a regular grid or on quantised coordinates (on a
    1000 × 1000 grid of float32 positions, 40 rows had a tie at a scale's
    boundary, and since the features' medians moved, every score of the
    sharp-feature detector differed).  So equal distances are ordered by the
    neighbour's coordinates (x, then y, then z; then by row, for coincident
    points, which the filters refuse), which a tile and the whole cloud share.
    One more neighbour than asked is queried to see a tie across the k-th
    place; such rows are queried again, with more neighbours, until the run
    of equal distances ends inside the list.  Rows without ties cost the extra
    neighbour and one comparison of their distances; where most rows tie
    across the k-th place (a square grid), their second query makes the pass
    up to half again as long."""
    n = tree.n
    kq = min(k + 1, n)
    dist, idx = tree.query(q, k=kq, workers=_kernels.tree_workers())
    dist, idx = dist.reshape(len(q), kq), idx.reshape(len(q), kq)
    if kq > 1:
        tied = np.flatnonzero((dist[:, 1:] == dist[:, :-1]).any(axis=1))
        for s in range(0, len(tied), TIE_ROWS):  # bounded: on a grid most rows tie
            _settle_ties(tree, q, dist, idx, tied[s:s + TIE_ROWS], k)
    return dist[:, :k], idx[:, :k]


#: tied rows settled at once (their neighbours' coordinates: 24 B per neighbour)
TIE_ROWS = 1 << 14
#: neighbours added to a list whose run of equal distances crosses its end (on a
#: square grid most runs hold 4 or 8 points), before doubling
TIE_MORE = 8


def _settle_ties(tree: cKDTree, q, dist, idx, rows: np.ndarray, k: int) -> None:
    """``query_settled``'s tie order, in place, on the listed rows of (m, k + 1) lists."""
    kq = dist.shape[1]
    across = dist[rows, k - 1] == dist[rows, kq - 1] if kq > k else np.zeros(len(rows), bool)
    groups = [(rows[~across], dist[rows[~across]], idx[rows[~across]])]
    wide, kw = rows[across], kq
    while len(wide):  # the run of equal distances reaches the list's end: query more
        kw = min(kw + TIE_MORE if kw == kq else 2 * kw, tree.n)
        d, i = tree.query(q[wide], k=kw, workers=_kernels.tree_workers())
        d, i = d.reshape(len(wide), kw), i.reshape(len(wide), kw)
        done = (d[:, k - 1] < d[:, kw - 1]) | (kw == tree.n)
        groups.append((wide[done], d[done], i[done]))
        wide = wide[~done]
    for at, d, i in groups:
        if not len(at):
            continue
        if _kernels.ENABLED:  # an insertion sort within the runs, compiled
            _kernels.settle_ties(d, i, tree.data)
            dist[at, :k], idx[at, :k] = d[:, :k], i[:, :k]
            continue
        p = tree.data[i]
        order = np.lexsort((i, p[..., 2], p[..., 1], p[..., 0], d), axis=-1)[:, :k]
        dist[at, :k] = np.take_along_axis(d, order, axis=1)
        idx[at, :k] = np.take_along_axis(i, order, axis=1)


def knn(points: np.ndarray, k: int, *, tree: cKDTree | None = None, query=None,
        include_self: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """k nearest neighbours of every query point.

    Parameters
    ----------
    points : (n, 3) float
        The cloud.
    k : int
        Neighbours per point (counting the point itself when ``include_self``).
    tree : cKDTree, optional
        A tree already built over ``points``.
    query : (m, 3) float, optional
        Query locations; default ``points``.
    include_self : bool
        When querying the cloud itself, keep the point as its own first neighbour.

    Returns
    -------
    dist : (m, k) float
        Distances, ascending; equal ones in ``query_settled``'s order.
    idx : (m, k) int64
        Indices into ``points``.
    """
    n = len(points)
    kk = k if include_self or query is not None else k + 1
    if kk > n:
        raise PointCloudError(f"knn: needs at least {kk} points for k={k}, got {n}")
    tree = build_tree(points) if tree is None else tree
    q = points if query is None else query
    if query is None and n > CHUNK or len(q) > 4 * CHUNK:
        # in slices, so a long query reports its progress; the cloud itself in
        # the tree's leaf order (same answers, several times faster than a
        # scattered input order)
        dist = np.empty((len(q), kk))
        idx = np.empty((len(q), kk), dtype=np.int64)
        step = 4 * CHUNK
        slices = (leaf_chunks(tree, step) if query is None else
                  (slice(s, s + step) for s in range(0, len(q), step)))
        with progress.step(f"{k}-NN query", len(q)) as advance:
            for rows in slices:
                d, i = query_settled(tree, q[rows], kk)
                dist[rows], idx[rows] = d, i
                advance(len(i))
    else:
        dist, idx = query_settled(tree, q, kk)
    if not include_self and query is None:
        dist, idx = dist[:, 1:], idx[:, 1:]
    return np.ascontiguousarray(dist), np.ascontiguousarray(idx.astype(np.int64, copy=False))


def leaf_order(tree: cKDTree, rows: np.ndarray | None = None) -> np.ndarray:
    """The cloud's rows (or the given ``rows``) in the order of the k-d tree's
    leaves: the order in which to query a cloud against its own tree, since
    consecutive queries then walk the same nodes (on a scattered input order a
    1M-point query runs several times faster so)."""
    order = np.asarray(tree.indices, dtype=np.int64)
    if rows is None:
        return order
    rank = np.empty(len(order), dtype=np.int64)  # noqa: NPY-empty -- a permutation fills it
    rank[order] = np.arange(len(order))
    rows = np.asarray(rows, dtype=np.int64)
    return rows[np.argsort(rank[rows], kind="stable")]


def leaf_chunks(tree: cKDTree, size: int):
    """The cloud's rows in leaf order (``leaf_order``), ``size`` at a time."""
    order = leaf_order(tree)
    for s in range(0, len(order), size):
        yield order[s:s + size]


#: a point whose mean distance to its SPACING_K nearest neighbours exceeds this
#: many times the median of those means is isolated: it is left out of h
ISOLATED_FACTOR = 10.0


def spacing_from_rows(row_mean: np.ndarray) -> float:
    """h from every point's mean distance to its ``SPACING_K`` nearest neighbours.

    h is the mean of ``row_mean`` over the points that are not isolated
    (``row_mean <= ISOLATED_FACTOR * median``): a trimmed mean, so that one far
    outlier cannot move the unit of every length (with a point 1e9 away from a
    3000-point cube the plain mean is 13,000 times too large).  When no point is
    isolated this is the plain mean of ``row_mean``, summed in row order, so
    that a tiled run, which gathers the same row means, gets the same h to the
    last bit.  Nothing of the size of ``row_mean`` is allocated unless some
    point is isolated (a tiled run's rows are a memory map of every row).
    """
    row_mean = np.asarray(row_mean, dtype=np.float64)
    limit = isolated_limit(row_mean)
    if not count_isolated(row_mean, limit):
        return float(row_mean.mean())
    return float(row_mean[row_mean <= limit].mean())


def isolated_limit(row_mean: np.ndarray) -> float:
    """The mean neighbour distance above which a point is isolated:
    ``ISOLATED_FACTOR`` times the median."""
    return ISOLATED_FACTOR * median(np.asarray(row_mean, dtype=np.float64))


def isolated(row_mean: np.ndarray) -> np.ndarray:
    """Mask of the isolated points, from their mean neighbour distances."""
    row_mean = np.asarray(row_mean, dtype=np.float64)
    return row_mean > isolated_limit(row_mean)


def count_isolated(row_mean: np.ndarray, limit: float | None = None) -> int:
    """How many points are isolated (``isolated(row_mean).sum()``), counted in
    chunks of ``_SCAN`` rows."""
    limit = isolated_limit(row_mean) if limit is None else limit
    return sum(int(np.count_nonzero(row_mean[s:s + _SCAN] > limit))
               for s in range(0, len(row_mean), _SCAN))


#: arrays longer than this are not copied by :func:`median` and :func:`quantile`
#: (selection in chunks): a copy of at most 256 MiB, per thread, is kept for its
#: speed (at 5M rows the chunked median and MAD of a column take about twice as long)
MEDIAN_COPY_ROWS = 1 << 25
#: rows per chunk of the scans of a whole-cloud array (``count_isolated``, ``_middle``)
_SCAN = 1 << 20
#: bins of one round of :func:`_middle`, and the most rows it partitions at the end
_SELECT_BINS = 1 << 16
_SELECT_ROWS = 1 << 20


def median(x: np.ndarray, transform=None) -> float:
    """``np.median`` of a 1-D float64 array without NaN (of ``transform(x)``,
    an element-wise function, when given), bit for bit.  Up to
    ``MEDIAN_COPY_ROWS`` rows it is ``np.median``, which partitions a copy;
    beyond, the middle values are selected in chunks (:func:`_middle`), so a
    memory map of a tiled run's every row is read, not copied."""
    n = len(x)
    if n <= MEDIAN_COPY_ROWS:
        return float(np.median(x if transform is None else transform(np.asarray(x))))
    a, b = _middle(x, (n - 1) // 2, transform)
    return a if n % 2 else float(np.mean(np.array([a, b])))  # as np.median: (a + b) / 2


def quantile(x: np.ndarray, q: float) -> float:
    """``np.quantile(x, q)`` (its default, linear interpolation) of a 1-D
    float64 array without NaN, bit for bit: a copy up to ``MEDIAN_COPY_ROWS``
    rows, beyond the two order statistics around ``q (n − 1)`` selected in
    chunks (:func:`_middle`) and interpolated as NumPy does (from the upper
    one when the weight is at least ½)."""
    n = len(x)
    if n <= MEDIAN_COPY_ROWS:
        return float(np.quantile(x, q))
    at = (n - 1) * q
    k = int(np.floor(at))
    if k >= n - 1:
        return _extent(x)[1]
    a, b = _middle(x, k)
    g = at - k
    return float(b - (b - a) * (1 - g) if g >= 0.5 else a + (b - a) * g)


def nonzero_rows(x: np.ndarray, test=None) -> np.ndarray:
    """``np.flatnonzero(x)`` (of ``test(x)``, an element-wise test, when given)
    of a 1-D array, read in chunks of ``_SCAN`` rows: a memory map of a tiled
    run's every row makes no temporary of its length."""
    return np.concatenate([s + np.flatnonzero(x[s:s + _SCAN] if test is None
                                              else test(x[s:s + _SCAN]))
                           for s in range(0, len(x), _SCAN)] + [np.zeros(0, np.int64)])


#: the longest block NumPy's pairwise sum adds without cutting it in two
_PAIRWISE_BLOCK = 128


def pairwise_sum(x: np.ndarray, transform=None) -> float:
    """``np.add.reduce`` of the contiguous float64 values of ``x`` (1-D; of
    ``transform(x)``, an element-wise function, when given), bit for bit, read
    in chunks of at most ``_SCAN`` rows.  NumPy sums a contiguous array
    pairwise: it cuts it in two, the first part n/2 rows rounded down to a
    multiple of 8, down to blocks of ``_PAIRWISE_BLOCK`` rows.  Cutting the
    same way down to chunks and summing each with NumPy builds the same tree,
    hence the same sum, with no temporary of the array's length."""
    def part(s: int, e: int):
        if e - s <= max(_SCAN, _PAIRWISE_BLOCK):
            c = x[s:e] if transform is None else transform(x[s:e])
            return np.add.reduce(np.ascontiguousarray(c, dtype=np.float64))
        half = (e - s) // 2
        half -= half % 8
        return part(s, s + half) + part(s + half, e)

    return float(part(0, len(x)))


def mean_std(x: np.ndarray) -> tuple[float, float]:
    """``np.mean`` and ``np.std`` of a contiguous copy of the 1-D float64
    array ``x``, bit for bit, read in chunks: the pairwise sum over n, then
    the square root of the pairwise sum of (x − mean)² over n, as NumPy takes
    them (:func:`pairwise_sum`); no temporary of the array's length, where
    ``np.std`` makes one."""
    n = len(x)
    mean = pairwise_sum(x) / n
    return mean, float(np.sqrt(pairwise_sum(x, lambda c: np.square(c - mean)) / n))


def _middle(x: np.ndarray, k: int, transform=None) -> tuple[float, float]:
    """The ``k``-th and ``k + 1``-th smallest values of ``x`` (of
    ``transform(x)``, when given; from 0), read in chunks of ``_SCAN`` rows.  Each round counts the values of
    the window (at first every value) in ``_SELECT_BINS`` equal bins and
    keeps, as the next window, the bins that hold the two ranks; a value's
    bin is ``floor((v - lo) * scale)`` clipped to the bins, monotone in
    ``v``, and a value is in the window when every round so far put it in the
    kept bins, so the counts and the window agree exactly.  A window of at
    most ``_SELECT_ROWS`` values, or of one value repeated, is partitioned.
    The chunks go through ``_kernels.select_window`` (one pass, no
    temporaries), or its NumPy equivalent without the compiled kernels."""
    rounds = []  # (lo, scale, first kept bin, last kept bin)

    def window(lo, scale, counts, count):
        """Pass over the chunks: the window's size, min and max, and its
        values counted into ``counts`` or, with ``count`` False, returned."""
        r = [np.array(v, dtype=t) for v, t in zip(zip(*rounds) if rounds else [()] * 4,
                                                  (np.float64, np.float64, np.int64, np.int64))]
        m, vmin, vmax, parts = 0, np.inf, -np.inf, []
        for s in range(0, len(x), _SCAN):
            c = x[s:s + _SCAN]
            c = np.ascontiguousarray(c if transform is None else transform(c), dtype=np.float64)
            if _kernels.ENABLED:
                out = np.empty(0 if count else len(c))  # noqa: NPY-empty -- [:got] is read
                got, lo_c, hi_c = _kernels.select_window(c, *r, lo, scale, counts, out, count)
                v = out[:got].copy()  # not a view that would keep the chunk's buffer
            else:
                for lo_r, scale_r, a, b in rounds:
                    j = _bins(c, lo_r, scale_r)
                    c = c[(j >= a) & (j <= b)]
                v, got = c, len(c)
                if got and count:
                    counts += np.bincount(_bins(c, lo, scale).astype(np.int64),
                                          minlength=_SELECT_BINS)
                lo_c, hi_c = (c.min(), c.max()) if got else (np.inf, -np.inf)
            m, vmin, vmax = m + got, min(vmin, lo_c), max(vmax, hi_c)
            if not count:
                parts.append(v)
        return m, float(vmin), float(vmax), parts

    counts = np.zeros(_SELECT_BINS, dtype=np.int64)
    lo, hi = _extent(x, transform)
    if lo == hi:
        return lo, lo
    for _ in range(8):  # each round narrows the window about 65536 times
        scale = _SELECT_BINS / (hi - lo)
        counts = np.zeros(_SELECT_BINS, dtype=np.int64)
        total, vmin, vmax, _ = window(lo, scale, counts, True)
        if vmin == vmax:  # the window, which holds both ranks, is one value
            return vmin, vmin
        if total <= _SELECT_ROWS:
            break
        cum = np.cumsum(counts)
        a, b = (int(np.searchsorted(cum, r, side="right")) for r in (k, k + 1))
        k -= int(cum[a - 1]) if a else 0
        rounds.append((lo, scale, a, b))
        lo, hi = lo + a / scale, lo + (b + 1) / scale
    part = np.partition(np.concatenate(window(0.0, 0.0, counts, False)[3]), [k, k + 1])
    return float(part[k]), float(part[k + 1])


def _bins(v: np.ndarray, lo: float, scale: float) -> np.ndarray:
    """``_kernels._select_bin`` of every value (NumPy)."""
    return np.clip(np.floor((v - lo) * scale), 0, _SELECT_BINS - 1)


def _extent(x: np.ndarray, transform=None) -> tuple[float, float]:
    """The smallest and largest value of ``x`` (of ``transform(x)``, when
    given), read in chunks of ``_SCAN`` rows."""
    lo, hi = np.inf, -np.inf
    for s in range(0, len(x), _SCAN):
        c = x[s:s + _SCAN] if transform is None else transform(x[s:s + _SCAN])
        lo, hi = min(lo, float(c.min())), max(hi, float(c.max()))
    return lo, hi


def spacing_rows(points: np.ndarray, k: int = SPACING_K, *,
                 tree: cKDTree | None = None) -> np.ndarray:
    """Each point's mean distance to its ``k`` nearest neighbours (self
    excluded): the rows of :func:`spacing_from_rows`.  The query runs in the
    tree's leaf order, slice by slice, and keeps only the row means (no (n, k)
    distance or index array): the same values as ``knn(points, k)`` averaged
    over its rows."""
    tree = build_tree(points) if tree is None else tree
    out = np.empty(len(points))  # noqa: NPY-empty -- every row written below
    with progress.step(f"{k}-NN spacing", len(points)) as advance:
        for rows in leaf_chunks(tree, 4 * CHUNK):
            d, _ = tree.query(points[rows], k=k + 1, workers=_kernels.tree_workers())
            out[rows] = d[:, 1:].mean(axis=1)
            advance(len(rows))
    return out


def average_spacing(points: np.ndarray, k: int = SPACING_K, *, tree: cKDTree | None = None) -> float:
    """Spacing h, the unit of every length: the mean distance of each point to
    its ``k`` nearest neighbours (self excluded, thesis §4.5.1), averaged over
    the points that are not isolated (see ``spacing_from_rows``).

    Raises ``PointCloudError`` when h is zero (all points duplicated).
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) < k + 1:
        raise PointCloudError(
            f"average_spacing: needs at least {k + 1} points, got {len(points)}"
        )
    h = spacing_from_rows(spacing_rows(points, k, tree=tree))
    if not np.isfinite(h) or h <= 0.0:
        raise PointCloudError("average_spacing: every point coincides with its neighbours (h = 0)")
    return h


def radius_knn(points: np.ndarray, radius: float, k_max: int, *, tree: cKDTree | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radius neighbourhoods capped at ``k_max`` neighbours, as padded arrays.

    Returns ``dist, idx, valid`` of shape ``(n, k_max)``; ``valid`` is False
    where the neighbour lies farther than ``radius``.  The point itself is
    always the first neighbour and always valid.
    """
    k_max = min(k_max, len(points))
    dist, idx = knn(points, k_max, tree=tree)
    valid = dist <= radius
    valid[:, 0] = True
    return dist, idx, valid


@dataclass(frozen=True)
class LocalPCA:
    """Result of batched weighted PCA.

    Attributes
    ----------
    eigenvalues : (n, 3) float
        λ0 ≤ λ1 ≤ λ2 of the weighted covariance.
    eigenvectors : (n, 3, 3) float
        Columns are the matching unit eigenvectors; ``[:, :, 0]`` is the normal.
    centroid : (n, 3) float
        Weighted mean p̄ of each neighbourhood.
    """

    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    centroid: np.ndarray

    @property
    def normals(self) -> np.ndarray:
        """(n, 3) unoriented unit normals (smallest eigenvector)."""
        return self.eigenvectors[:, :, 0]

    @property
    def surface_variation(self) -> np.ndarray:
        """σ = λ0 / (λ0 + λ1 + λ2), thesis (2.5)."""
        lam = self.eigenvalues
        return lam[:, 0] / np.maximum(lam.sum(axis=1), 1e-300)

    @property
    def sphericity(self) -> np.ndarray:
        """λ0 / λ2."""
        lam = self.eigenvalues
        return lam[:, 0] / np.maximum(lam[:, 2], 1e-300)

    @property
    def border(self) -> np.ndarray:
        """Border criterion |λ2 − 2 λ1| / λ2, thesis (2.8)."""
        lam = self.eigenvalues
        return np.abs(lam[:, 2] - 2.0 * lam[:, 1]) / np.maximum(lam[:, 2], 1e-300)


def weighted_pca(points: np.ndarray, idx: np.ndarray, weights: np.ndarray | None = None,
                 *, center: str = "mean") -> LocalPCA:
    """Batched weighted PCA of the neighbourhoods ``points[idx]``.

    Parameters
    ----------
    points : (n, 3) float
    idx : (m, k) int
        Neighbour indices (padded rows allowed: give them weight 0).
    weights : (m, k) float, optional
        Non-negative weights; default uniform.
    center : {"mean", "point"}
        Covariance about the weighted neighbourhood mean (classic PCA) or about
        the first neighbour of each row (the query point itself, as the
        covariance Σ ω_j (p_i − p_j)(p_i − p_j)ᵀ of thesis (4.9)).

    Returns
    -------
    LocalPCA

    Rows are independent: they run in chunks on the kernels' thread pool
    (``_kernels.run_chunks``; NumPy's einsum and LAPACK release the GIL).
    """
    m, k = idx.shape
    lam = np.empty((m, 3))  # noqa: NPY-empty -- every row is written below
    vec = np.empty((m, 3, 3))
    cen = np.empty((m, 3))

    def rows(s: int, e: int) -> None:
        nb = points[idx[s:e]]  # (c, k, 3)
        w = np.ones((e - s, k)) if weights is None else weights[s:e]
        wsum = w.sum(axis=1, keepdims=True)
        wsum = np.where(wsum > 0, wsum, 1.0)
        wn = w / wsum
        mean = np.einsum("ck,ckd->cd", wn, nb)
        ref = mean if center == "mean" else nb[:, 0, :]
        diff = nb - ref[:, None, :]
        cov = np.einsum("ck,cki,ckj->cij", wn, diff, diff)
        ev, evec = np.linalg.eigh(cov)
        lam[s:e] = np.maximum(ev, 0.0)
        vec[s:e] = evec
        cen[s:e] = mean

    _kernels.run_chunks(rows, m, CHUNK)
    return LocalPCA(lam, vec, cen)


def pca_normals(points: np.ndarray, k: int = 16, *, tree: cKDTree | None = None,
                orient: bool = True) -> np.ndarray:
    """Unit PCA normals from ``k``-NN neighbourhoods, optionally MST-oriented."""
    _, idx = knn(points, min(k, len(points)), tree=tree)
    normals = weighted_pca(points, idx).normals.copy()
    if orient:
        normals = orient_normals_mst(points, normals, k=min(k, len(points)), tree=tree)
    return normals


def normal_agreement(points: np.ndarray, normals: np.ndarray, i: np.ndarray,
                     j: np.ndarray) -> np.ndarray:
    """Signed agreement of the unoriented normals of points ``i`` and ``j`` (index
    arrays of one shape): the plain n_i·n_j, or the mirrored
    (n_i − 2(n_i·e)e)·n_j with e the unit chord p_j − p_i, whichever is larger
    in magnitude.

    The mirror image of n_i in the plane bisecting the chord is the normal a
    circle through both points would have at p_j (the "consistent osculating
    circle" idea of König & Gumhold 2009), so it stays near +1 across a sharp
    crease where the plain product is near 0 (90° edge) or even negative (the
    thin tips of a star), i.e. where Hoppe's rule flips a face.  On a smooth
    patch the plain product is near 1 and wins."""
    ni, nj = normals[i], normals[j]
    e = points[j] - points[i]
    ee = np.einsum("...d,...d->...", e, e)
    plain = np.einsum("...d,...d->...", ni, nj)
    a = np.einsum("...d,...d->...", ni, e)
    b = np.einsum("...d,...d->...", nj, e)
    mirror = plain - 2.0 * a * b / np.where(ee > 0.0, ee, 1.0)
    return np.where(np.abs(mirror) > np.abs(plain), mirror, plain)


def orient_normals_mst(points: np.ndarray, normals: np.ndarray, k: int = 10, *,
                       tree: cKDTree | None = None, neighbors: np.ndarray | None = None,
                       mirror: bool = False) -> np.ndarray:
    """Consistently orient ``normals`` by propagation along a minimum spanning
    tree of the k-NN graph with edge cost 1 − |n_i·n_j| (Hoppe et al. 1992).

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float
        Unit normals of unknown sign.
    k : int
        Neighbours per point in the graph.
    tree : cKDTree, optional
        A tree over ``points`` (used only when ``neighbors`` is not given).
    neighbors : (n, m) int, optional
        A neighbour array a filter already holds, self EXCLUDED; its first
        ``k`` columns are used and no new query is made.
    mirror : bool, default=False
        Judge two neighbours by :func:`normal_agreement` (the plain product or
        the chord-mirrored one, whichever agrees more strongly) instead of
        n_i·n_j, for edge costs and signs alike: Hoppe's plain rule flips whole
        faces of solids with sharp thin tips (a star prism: 26 of 36 seeded
        runs with a flipped face, 7 of 36 with the mirror rule).

    Returns
    -------
    (n, 3) float
        A new array.  Each connected component is rooted at its point of
        largest z, whose normal is made to point toward +z (outward on a closed
        surface).  Edge costs are float32 and each undirected edge is stored
        once, so the graph stays small at 10⁶ points; the sign propagation runs
        by pointer jumping, O(n log depth), without a Python loop over points.
    """
    n = len(points)
    normals = np.array(normals, dtype=np.float64, copy=True)
    if n < 2:
        return normals
    if neighbors is None:
        _, neighbors = knn(points, min(k, n - 1), tree=tree, include_self=False)
    nb = neighbors[:, :k]
    m = nb.shape[1]
    if m == 0:
        return normals
    if _kernels.ENABLED:
        return _orient_compiled(points, normals, nb, mirror)
    # each undirected edge once: (i, j) is kept when i < j, or when i is not among
    # j's own neighbours (mutual k-NN pairs would otherwise appear twice)
    keep = np.zeros((n, m), dtype=bool)
    cost = np.zeros((n, m), dtype=np.float32)
    rows = np.arange(n, dtype=nb.dtype)
    for s in range(0, n, CHUNK):
        e = min(n, s + CHUNK)
        j = nb[s:e]
        if mirror:
            dots = np.abs(normal_agreement(points, normals, rows[s:e, None], j))
        else:
            dots = np.abs(np.einsum("cd,ckd->ck", normals[s:e], normals[j]))
        cost[s:e] = 1.0 - dots + 1e-6  # strictly positive so every edge is stored
        mutual = (nb[j] == rows[s:e, None, None]).any(axis=2)
        keep[s:e] = (rows[s:e, None] < j) | ~mutual
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(keep.sum(axis=1), out=indptr[1:])
    graph = csr_matrix((cost[keep].astype(np.float64), nb[keep], indptr), shape=(n, n))
    del cost, keep
    mst = minimum_spanning_tree(graph)
    del graph
    _, labels = connected_components(mst, directed=False)
    roots = _highest(points, labels)
    parent = np.full(n, -1, dtype=np.int64)
    for r in roots:  # one BFS per connected component (not per point)
        _, pred = breadth_first_order(mst, int(r), directed=False, return_predecessors=True)
        comp = pred >= 0
        parent[comp] = pred[comp]
    parent[roots] = roots
    # rel[i]: sign of node i relative to its parent; the final sign of i is the
    # product of rel along its path to the root, times the root's own sign
    is_root = np.zeros(n, dtype=bool)
    is_root[roots] = True
    agree = (normal_agreement(points, normals, rows, parent) if mirror
             else np.einsum("ij,ij->i", normals, normals[parent]))
    rel = np.where(agree < 0, -1.0, 1.0)
    rel[is_root] = 1.0
    acc, ptr = rel.copy(), parent.copy()  # acc: product of rel over [i, ptr[i])
    live = ~is_root[ptr]
    while live.any():  # pointer jumping: O(log depth) vectorised passes
        nxt = ptr[live]
        acc[live] = acc[live] * acc[nxt]
        ptr[live] = ptr[nxt]
        live = ~is_root[ptr]
    root_sign = np.where(normals[:, 2] < 0, -1.0, 1.0)
    return normals * (acc * root_sign[ptr])[:, None]


def _highest(points, labels):
    """The root of each component (points sharing a label): its highest point,
    the smallest index among equals."""
    order = np.lexsort((-points[:, 2], labels))
    first = np.ones(len(order), dtype=bool)
    first[1:] = labels[order[1:]] != labels[order[:-1]]
    return order[first]


def _orient_edges(points, normals, nb, mirror):
    """The k-NN graph's edges for :func:`_orient_compiled`, each undirected
    edge once, in row order (``_kernels.orient_keep`` and ``orient_emit``,
    by row blocks on the kernels' threads): ends, float32 cost, int8 sign."""
    n, m = nb.shape
    keep = np.empty((n, m), dtype=bool)  # noqa: NPY-empty -- every row written
    per_row = np.empty(n, dtype=np.int64)  # noqa: NPY-empty -- every row written
    _kernels.run_chunks(lambda s, e: _kernels.orient_keep(nb, s, e, keep, per_row), n,
                        _kernels.TASK_ROWS)
    start = np.zeros(n, dtype=np.int64)
    np.cumsum(per_row[:-1], out=start[1:])
    cnt = int(per_row.sum())
    ei, ej = np.empty(cnt, dtype=np.int64), np.empty(cnt, dtype=np.int64)
    cost, sign = np.empty(cnt, dtype=np.float32), np.empty(cnt, dtype=np.int8)
    _kernels.run_chunks(lambda s, e: _kernels.orient_emit(
        points, normals, nb, mirror, keep, start, s, e, ei, ej, cost, sign), n,
        _kernels.TASK_ROWS)
    return ei, ej, cost, sign


def cost_order(cost: np.ndarray) -> np.ndarray:
    """Indices of the float32 ``cost`` in ascending order, equal costs by
    index: the order of a stable argsort, on every machine.

    Kruskal's forest (:func:`_orient_compiled`) takes the edges in this order,
    and where costs tie (exact agreements on planes) the order picks the tree,
    so it must not depend on the sort's implementation (NumPy's quicksort
    breaks ties differently with and without AVX-512).  Each cost's bits, made
    monotone as an unsigned integer, go to the high half of a 64-bit key and
    the index to the low half; the keys are distinct, so any sort gives this
    order: the two halves are sorted on the kernels' threads and merged.
    """
    cost = np.asarray(cost, dtype=np.float32) + np.float32(0.0)   # −0 → +0
    n = len(cost)
    if n >= 2**32:
        return np.argsort(cost, kind="stable")
    bits = cost.view(np.uint32)
    flip = np.where(bits >> np.uint32(31), np.uint32(0xFFFFFFFF), np.uint32(0x80000000))
    key = (bits ^ flip).astype(np.uint64) << np.uint64(32)
    key |= np.arange(n, dtype=np.uint64)
    del bits, flip
    if _kernels.ENABLED and n > CHUNK and _kernels.threads() > 1:
        half = n // 2
        a, b = _kernels.run_chunks(lambda s, e: np.sort(key[s:e]), n, half + 1)
        key = np.empty(n, dtype=np.uint64)  # noqa: NPY-empty -- the merge fills it
        _kernels.merge_sorted(a, b, key)
    else:
        key.sort()
    key &= np.uint64(0xFFFFFFFF)
    return key.astype(np.int64)


def _orient_compiled(points, normals, nb, mirror):
    """The same orientation as :func:`orient_normals_mst`, compiled: Kruskal's
    forest over the edges sorted by cost, with a union-find that carries each
    node's sign relative to its component (no graph matrix, no traversal); each
    component is then rooted at its highest point as before.  Where several
    spanning trees have equal cost the two may pick different ones; a sign
    differs only where two such trees disagree, i.e. on a cycle of
    contradicting agreements."""
    n = len(points)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    ei, ej, cost, sign = _orient_edges(
        pts, np.ascontiguousarray(normals, dtype=np.float64),
        np.ascontiguousarray(nb, dtype=np.int64), bool(mirror))
    order = cost_order(cost)
    del cost
    rep, rel = _kernels.kruskal_signs(order, ei, ej, sign, n)
    del order, ei, ej, sign
    roots = _highest(points, rep)
    top = np.empty(n, dtype=np.int64)
    top[rep[roots]] = roots
    root = top[rep]
    root_sign = np.where(normals[root, 2] < 0, -1.0, 1.0)
    return normals * (rel.astype(np.float64) * rel[root] * root_sign)[:, None]


def orient_normals_toward(points: np.ndarray, normals: np.ndarray, viewpoint) -> np.ndarray:
    """Flip each normal so that it points toward ``viewpoint`` (n·(v − p) ≥ 0)."""
    v = np.asarray(viewpoint, dtype=np.float64).reshape(3)
    s = np.einsum("ij,ij->i", normals, v[None, :] - points)
    return np.where((s < 0)[:, None], -normals, normals)


def centered(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return ``points − c`` and ``c`` (the bounding-box centre).

    Filters work on centred coordinates so that clouds far from the origin
    (UTM LiDAR with 1e6 offsets) keep full float64 precision in differences
    and in the covariance sums; the offset is added back on output.
    """
    c = 0.5 * (points.min(axis=0) + points.max(axis=0))
    return points - c, c


def _box_gap(points: np.ndarray, lo, hi) -> np.ndarray:
    """Each row's distance to the nearest face of the box ``[lo, hi]``."""
    return np.minimum((points - np.asarray(lo)).min(axis=1),
                      (np.asarray(hi) - points).min(axis=1))


def tile_miss(points: np.ndarray, reach: np.ndarray, lo, hi) -> dict | None:
    """``None`` when every row's ball (radius ``reach``) lies inside the box
    ``[lo, hi]`` (``tile_exact`` with no hops), else a tile's "not exact" result
    with ``short``: how much the box must grow on its sides for every ball to
    fit.  Growing the box only adds points, which can only shrink a k-NN reach,
    so a halo grown by ``short`` (and a margin) is wide enough for these rows."""
    points = np.asarray(points)
    if not len(points):
        return None
    over = np.asarray(reach) - _box_gap(points, lo, hi)
    if (over < 0).all():
        return None
    return {"exact": False, "short": float(over.max())}


def tile_exact(points: np.ndarray, idx: np.ndarray, reach: np.ndarray, lo, hi,
               hops: int) -> np.ndarray:
    """Rows of a tile whose result equals the one a run over the whole cloud gives.

    A tile holds every point of the cloud inside the box ``[lo, hi]`` (a face at
    ±inf: nothing of the cloud lies beyond it).  A row's own neighbour list is the
    whole cloud's when the ball it was drawn from, of radius ``reach`` (the
    distance to its last neighbour, or a query radius), lies inside the box; a
    value that reads the neighbours' values ``hops`` times is exact when every row
    within ``hops`` steps of the neighbour graph has an exact list.  This is the
    check behind the halo of a tiled run: a core row that fails it means the halo
    was too narrow.

    Parameters
    ----------
    points : (n, 3) float
    idx : (n, k) int
        Neighbour lists (self included or not), indices into ``points``.
    reach : (n,) float
        Radius of the ball each row's list was drawn from.
    lo, hi : (3,) float
        The box the tile holds every point of.
    hops : int
        Times a result reads its neighbours' intermediate values.

    Returns
    -------
    (n,) bool
    """
    ok = np.asarray(reach) < _box_gap(points, lo, hi)
    for _ in range(hops):
        nxt = ok.copy()
        for s in range(0, len(ok), CHUNK):
            nxt[s:s + CHUNK] &= ok[idx[s:s + CHUNK]].all(axis=1)
        ok = nxt
    return ok
