"""
simplify.py
-----------
SDBS: saliency-dictionary-based simplification of a point cloud, thesis chapter
6, §6.3, eqs (6.1)-(6.11).  Per-point features from a weighted PCA are coded
against a K-SVD dictionary; the code's sparsity times its residual is a saliency,
and a greedy pass by decreasing saliency keeps points and removes their
neighbours within a radius inversely proportional to it.  Returns the indices of
the kept input points.  The decisions behind each rule, with their measurements,
are in docs/decisions/simplify.md.
"""

from __future__ import annotations

import logging
from itertools import chain
from dataclasses import dataclass

import numpy as np

from . import progress
from . import _kernels, sparse
from ._params import Param, preset_param, validate_params
from ._validation import (InvalidParameterError, PointCloudError, as_normals, as_points,
                          check_seed, check_spread)
from .neighbors import (CHUNK, build_tree, knn, leaf_chunks, nonzero_rows, query_settled,
                        pairwise_sum, spacing_from_rows, weighted_pca)

log = logging.getLogger("pcprep")

#: the method as printed (§6.3): unscaled features (6.1)-(6.4), S = 200 atoms,
#: λ = 0.5 (λ = 2·alpha in the ½‖·‖² convention of ``sparse.lasso_lars``) and the
#: radius ρ_i = δ/Sf_i in units of h alone
THESIS = {"feature_scale": "thesis", "density_adapt": 0.0, "n_atoms": 200, "alpha": 0.25}

PARAMS = (
    Param("ratio", float, low=0.0, high=1.0, closed="neither", unit="fraction",
          optional=True),
    Param("count", int, low=1, unit="count", optional=True),
    Param("delta", float, low=0.0, closed="neither", unit="h", optional=True),
    Param("k", int, low=4, high=200, unit="count"),
    Param("n_atoms", int, low=2, high=2000, unit="count"),
    Param("alpha", float, low=0.0, closed="neither"),
    Param("feature_scale", str, choices=("balanced", "thesis")),
    Param("density_adapt", float, low=0.0, high=1.0),
    Param("sf_floor", float, low=0.0, high=1.0, closed="neither", advanced=True),
    Param("max_iter", int, low=1, high=200, advanced=True),
    Param("max_train", int, low=100, unit="count", advanced=True),
    Param("seed", int, low=0, optional=True),
    preset_param({"thesis": THESIS}),
)


@dataclass(frozen=True)
class SimplifyResult:
    """Result of ``simplify_sdbs``.

    Attributes
    ----------
    keep_idx : (m,) int64
        Indices of the kept input points, ascending.
    score : (n,) float
        Saliency Sf in [0, 1] of every input point (6.10).
    delta : float
        The δ used (in units of h); searched when ``ratio``/``count`` was given.
    h : float
        Average spacing of the input.
    nnz : (n,) int
        ‖α_j‖₀ of every point's Lasso code (6.5).
    residual : (n,) float
        ‖F_j − Dα_j‖₂ (6.7).
    n_greedy : int
        Points kept by the greedy rule (6.11) for ``delta`` before the exact-count
        adjustment (equal to ``len(keep_idx)`` when ``delta`` was given).
    """

    keep_idx: np.ndarray
    score: np.ndarray
    delta: float
    h: float
    nnz: np.ndarray
    residual: np.ndarray
    n_greedy: int


# --------------------------------------------------------------------------- features
def sdbs_features(points: np.ndarray, normals, k: int, feature_scale: str, tree=None,
                  nn=None):
    """Per-point feature F = (n, σ, p) of thesis §6.3.1 and the spacing h.

    ``nn`` = (dist, idx): k-NN lists (self first) with at least ``k`` columns,
    already computed on ``points`` (their first ``k`` columns are used).

    Returns ``F (n, 7)``, ``h``, ``dist (n, k)``, ``idx (n, k)``.
    """
    P = points - points.mean(axis=0)
    if nn is None:
        tree = build_tree(P) if tree is None else tree
        dist, idx = knn(P, k, tree=tree)
    else:
        dist, idx = nn[0][:, :k], nn[1][:, :k]  # float32 lists stay float32
    # h: the mean distance to the 6 nearest neighbours
    h = spacing_from_rows(dist[:, 1:7].mean(axis=1, dtype=np.float64))
    diag = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    if not np.isfinite(h) or h <= 1e-9 * diag:
        raise PointCloudError("simplify_sdbs: every point coincides with its "
                              "neighbours (h = 0)")
    n, sigma = local_geometry(P, normals, dist, idx, h)
    return scale_features(n, sigma, P, feature_scale), h, dist, idx


def local_geometry(P: np.ndarray, normals, dist: np.ndarray, idx: np.ndarray, h: float):
    """Normal and surface variation of every row from its k-NN lists (6.1)-(6.3).

    The weighted PCA (6.1) uses exp(-d²/s²), s the point's mean neighbour
    distance (the thesis' exp(-d²/k_i²) mixes a length with a count).  The
    normal takes the sign of the given ``normals``, else it points away from
    the origin of ``P`` (the features need a sign).  Row-local: a tile of a
    tiled run computes it for its rows.
    """
    s = np.maximum(dist[:, 1:].mean(axis=1), 1e-30 * h)
    w = np.exp(-(dist / s[:, None]) ** 2)
    pca = weighted_pca(P, idx, w)
    n = pca.normals.copy()
    if normals is not None:
        sgn = np.sign(np.einsum("ij,ij->i", n, normals))
    else:
        sgn = np.sign(np.einsum("ij,ij->i", n, P))
    sgn[sgn == 0] = 1.0
    n *= sgn[:, None]
    return n, pca.surface_variation


def feature_scales(sigma: np.ndarray, P: np.ndarray, feature_scale: str) -> tuple:
    """The cloud-wide divisors of the σ and position columns: their RMS values
    ("balanced": each block weighs alike in the code) or 1 and the bounding-box
    diagonal (the thesis' unscaled features).  ``sigma`` and ``P`` may be
    memory maps: they are read in chunks, the means being NumPy's to the bit
    (``neighbors.pairwise_sum``) with no temporary of the cloud's length."""
    if feature_scale == "balanced":
        n = len(P)
        rms_s = float(np.sqrt(pairwise_sum(sigma, np.square) / n))
        rms_p = float(np.sqrt(pairwise_sum(P, lambda b: np.einsum("ij,ij->i", b, b)) / n))
        return (rms_s if rms_s > 0 else 1.0), rms_p
    lo = np.min([P[s0:s0 + CHUNK].min(axis=0) for s0 in range(0, len(P), CHUNK)], axis=0)
    hi = np.max([P[s0:s0 + CHUNK].max(axis=0) for s0 in range(0, len(P), CHUNK)], axis=0)
    return 1.0, float(np.linalg.norm(hi - lo))


def scale_features(n: np.ndarray, sigma: np.ndarray, P: np.ndarray, feature_scale: str,
                   scales: tuple | None = None) -> np.ndarray:
    """F = (n, σ / s_σ, P / s_p) (§6.3.1) with the divisors of ``feature_scales``
    (computed from ``sigma`` and ``P`` unless given)."""
    s_sig, s_pos = feature_scales(sigma, P, feature_scale) if scales is None else scales
    return np.column_stack([n, sigma / s_sig, P / s_pos])


def saliency_scores(F: np.ndarray, *, n_atoms: int, alpha: float, max_iter: int,
                    max_train: int, seed):
    """K-SVD dictionary + Lasso codes → (Sf, nnz, residual), eqs (6.5)-(6.10)."""
    # the training subsample is drawn by row (docs/decisions/simplify.md,
    # "Training subsample by row"): a content-based order made the dictionary
    # follow the rounding of coordinates far from the origin
    kres = sparse.ksvd(F, n_atoms, n_nonzero_coefs=min(3, F.shape[1], n_atoms),
                       max_iter=max_iter, max_train=max_train, seed=seed, code_all=False,
                       order="rows")
    log.info("simplify_sdbs: dictionary of %d atoms trained", n_atoms)
    nnz, res = code_rows(F, kres.dictionary, alpha)
    return normalised_saliency(nnz, res), nnz, res


def code_rows(F: np.ndarray, D: np.ndarray, alpha: float):
    """Lasso code of every row on ``D`` (6.7): its atom count and residual.
    A row's code depends on the row and ``D`` only."""
    codes = sparse.lasso_lars(F, D, alpha=alpha)
    return sparse.code_length(codes, F, D)


def normalised_saliency(nnz: np.ndarray, res: np.ndarray, maxima=None) -> np.ndarray:
    """Sf = f·g (6.10): the atom count and the residual, each divided by its
    maximum over the cloud (``maxima``, from :func:`saliency_maxima` of every
    row, when ``nnz`` and ``res`` are a chunk of the rows: a row's Sf depends
    on the row and the two maxima only)."""
    nmax, rmax = saliency_maxima(nnz, res) if maxima is None else maxima
    f = nnz / nmax
    g = res / rmax if rmax > 0 else np.zeros_like(res)
    return f * g


def saliency_maxima(nnz: np.ndarray, res: np.ndarray) -> tuple[int, float]:
    """The divisors of (6.10): the largest atom count (at least 1) and the
    largest residual."""
    return max(int(nnz.max()), 1), float(res.max())


# --------------------------------------------------------------------------- greedy
def _list_edges(dist, idx, rank, rho):
    """Edges i → j with j within ρ_i of i and i visited before j (rank_i < rank_j),
    from the stored k-NN lists.  Also returns the rows whose list does not reach
    ρ_i (their edge set may be incomplete)."""
    n, K = idx.shape
    src_l, dst_l, trunc = [], [], np.zeros(n, dtype=bool)
    for s0 in range(0, n, CHUNK):
        e = min(n, s0 + CHUNK)
        r = rho[s0:e].astype(dist.dtype)
        m = dist[s0:e, 1:] <= r[:, None]
        nb = idx[s0:e, 1:]
        m &= rank[nb] > rank[s0:e, None]
        if K < n:
            trunc[s0:e] = dist[s0:e, -1] <= r
        ii, jj = np.nonzero(m)
        src_l.append((ii + s0).astype(np.int32))
        dst_l.append(nb[ii, jj].astype(np.int32))
    return np.concatenate(src_l), np.concatenate(dst_l), trunc


def _ball_edges(P, rows, rank, rho, tree):
    """Every edge i → j (j within ρ_i, rank_i < rank_j) of the given rows, by an
    exact ball query."""
    src_l, dst_l = [], []
    for s0 in range(0, rows.size, CHUNK // 4):
        tt = rows[s0:s0 + CHUNK // 4]
        balls = tree.query_ball_point(P[tt], rho[tt], workers=_kernels.tree_workers())
        lens = np.fromiter(map(len, balls), dtype=np.int64, count=len(balls))
        bs = np.repeat(tt, lens)
        bd = np.fromiter(chain.from_iterable(balls), dtype=np.int64,
                         count=int(lens.sum()))
        ok = rank[bd] > rank[bs]
        src_l.append(bs[ok].astype(np.int32))
        dst_l.append(bd[ok].astype(np.int32))
    if not src_l:
        return np.zeros(0, np.int32), np.zeros(0, np.int32)
    return np.concatenate(src_l), np.concatenate(dst_l)


def _rounds(n, src, dst, state=None):
    """Parallel form of the sequential greedy on the edge DAG src → dst:
    returns the state (1 kept, 2 removed) and the number of rounds.  A given
    ``state`` (0 = undecided) is completed in place."""
    if state is None:
        state = np.zeros(n, dtype=np.int8)  # 0 undecided, 1 kept, 2 removed
    undecided = np.flatnonzero(state == 0)
    live = (state[dst] == 0) & (state[src] != 2)
    src, dst = src[live], dst[live]
    covered = np.zeros(n, dtype=bool)
    waiting = np.zeros(n, dtype=bool)
    rounds = 0
    while undecided.size:
        rounds += 1
        ss = state[src]
        covered[dst[ss == 1]] = True
        m0 = ss == 0
        src, dst = src[m0], dst[m0]  # edges from decided sources are spent
        waiting[dst] = True
        cu, wu = covered[undecided], waiting[undecided]
        covered[undecided] = False
        waiting[undecided] = False
        state[undecided[cu]] = 2
        state[undecided[~cu & ~wu]] = 1
        undecided = undecided[~cu & wu]
        live = state[dst] == 0
        src, dst = src[live], dst[live]
    return state, rounds


def greedy_keep(P, dist, idx, score, rho, tree=None) -> np.ndarray:
    """Greedy removal of (6.11) without a per-point loop.

    Sequential rule: visit the points by decreasing ``score`` (ties by index);
    a point not yet removed is kept and removes every later point within its
    radius ``rho``.  Equivalent parallel form, run here in rounds: with the
    edges i → j (j within ρ_i, i earlier), a point is removed as soon as one of
    its sources is kept, and kept as soon as all its sources are removed.  Each
    round decides every point whose sources are decided, so the result equals
    the sequential one exactly (tested against a naive loop).

    Edges come from the stored k-NN lists ``dist``/``idx``.  Rows whose list
    does not reach ρ_i need an exact ball query, but only if they end up kept
    (a removed point removes nobody): the rounds are run with the list edges,
    the kept rows with incomplete lists get their ball edges, and this repeats
    until no kept row is incomplete.  By induction over the visiting order the
    result then equals the one with every edge.

    Returns a boolean keep mask.
    """
    n = len(P)
    order = np.lexsort((np.arange(n), -score))
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    if _kernels.ENABLED:
        return _greedy_compiled(P, dist, idx, rho, order, rank, tree)
    src, dst, trunc = _list_edges(dist, idx, rank, rho)
    rounds = n_ball = passes = 0
    state = None
    while True:
        passes += 1
        state, r = _rounds(n, src, dst, state)
        rounds += r
        need = np.flatnonzero((state == 1) & trunc)
        if need.size == 0:
            break
        if tree is None:
            tree = build_tree(P)
        s2, d2 = _ball_edges(P, need, rank, rho, tree)
        src, dst = np.concatenate([src, s2]), np.concatenate([dst, d2])
        trunc[need] = False
        n_ball += need.size
        # the first point that can change is the earliest kept point a new
        # edge reaches (by induction every earlier decision stands)
        hit = d2[state[d2] == 1]
        if hit.size:
            state[rank >= rank[hit].min()] = 0
    log.info("simplify_sdbs: greedy removal in %d rounds, %d pass(es), %d exact ball "
             "queries", rounds, passes, n_ball)
    return state == 1


def _greedy_compiled(P, dist, idx, rho, order, rank, tree):
    """``greedy_keep`` by the compiled sequential loop: one pass over the
    stored lists, then exact ball queries for the kept rows whose list does
    not reach ρ_i and a new pass with those balls, until no kept row is
    incomplete (same induction as the rounds)."""
    n, K = idx.shape
    r32 = rho.astype(dist.dtype)
    trunc = dist[:, -1] <= r32 if K < n else np.zeros(n, dtype=bool)
    src = np.zeros(0, np.int64)
    dst = np.zeros(0, np.int64)
    done = np.zeros(n, dtype=bool)  # rows whose exact ball is in (src, dst)
    passes = 0
    while True:
        passes += 1
        order_e = np.argsort(src, kind="stable")
        ptr = np.searchsorted(src[order_e], np.arange(n + 1)).astype(np.int64)
        state = np.zeros(n, dtype=np.int8)
        _kernels.greedy_sequential(order, rank, dist, idx, r32, ptr, dst[order_e], state)
        need = np.flatnonzero((state == 1) & trunc & ~done)
        if need.size == 0:
            break
        s2, d2 = _ball_edges(P, need, rank, rho, tree if tree is not None
                             else build_tree(P))
        src = np.concatenate([src, s2.astype(np.int64)])
        dst = np.concatenate([dst, d2.astype(np.int64)])
        done[need] = True
    log.info("simplify_sdbs: greedy removal in %d sequential pass(es), %d exact ball "
             "queries", passes, int(done.sum()))
    return state == 1


def _knn32(P, k, tree):
    """k-NN lists stored as float32 distances / int32 indices, queried in chunks
    (half the memory of ``knn``'s float64 / int64 at 10^6 points)."""
    n = len(P)
    gd = np.zeros((n, k), dtype=np.float32)
    gi = np.zeros((n, k), dtype=np.int32)
    for at in leaf_chunks(tree, CHUNK):
        gd[at], gi[at] = query_settled(tree, P[at], k)
    return gd, gi


#: length of the stored k-NN lists (PCA neighbourhoods and removal candidates);
#: kept rows whose removal ball is longer get an exact ball query
GRAPH_K = 32


# --------------------------------------------------------------------------- main
@validate_params(*PARAMS, presets={"thesis": THESIS})
def simplify_sdbs(points, normals=None, *, ratio: float | None = None,
                  count: int | None = None, delta: float | None = None, k: int = 16,
                  n_atoms: int = 200, alpha: float = 0.25,
                  feature_scale: str = "balanced", density_adapt: float = 0.5,
                  sf_floor: float = 0.3,
                  max_iter: int = 5, max_train: int = 10000,
                  seed: int | None = 0, preset: str | None = None) -> SimplifyResult:
    """Simplify a point cloud by sparse-coding saliency (SDBS, Leal Narváez 2020, ch. 6).

    Features F = (n, σ, p) per point from a weighted PCA (6.1)-(6.4); a K-SVD
    dictionary of ``n_atoms`` atoms (Alg. 3.3) and Lasso codes α of every point
    (3.7); the saliency Sf = N(‖α‖₀)·N(‖F − Dα‖₂) (6.5)-(6.10), N(·) division by
    the maximum; then, visiting the points by decreasing Sf, each point not yet
    removed is kept and removes the unvisited points within
    ρ_i = δ·unit_i / max(Sf_i, sf_floor) (6.11).  δ and the unit are in units of h
    (mean distance to the 6 nearest neighbours).  Points are never moved.

    Parameters
    ----------
    points : (n, 3) float
        The cloud.
    normals : (n, 3) float, optional
        Only orient the PCA normals of the features (else away from the centroid).
    ratio : float, optional
        Fraction of the points to keep, in (0, 1); count = round(ratio·n).
    count : int, optional
        Number of points to keep, in [1, n].
    delta : float, optional
        δ of (6.11); the kept count then follows from it.  Give exactly one of
        ``ratio``, ``count``, ``delta``.
    k : int, default=16
        Neighbourhood size of the weighted PCA (6.1).
    n_atoms : int, default=200
        Dictionary size S (the thesis' value).
    alpha : float, default=0.25
        Lasso weight in ½‖F − Dα‖² + alpha‖α‖₁ (the thesis' λ = 0.5 in (3.7)).
    feature_scale : {"balanced", "thesis"}, default="balanced"
        Feature columns: each group scaled to unit RMS, or the thesis' raw vector.
    density_adapt : float, default=0.5
        β: the radius unit is h^(1−β)·h_i^β, h_i the local spacing (0 = thesis).
    sf_floor : float, default=0.3
        Lower clamp of Sf in the radius (6.11), which is infinite at Sf = 0.
    max_iter : int, default=5
        K-SVD iterations.
    max_train : int, default=10000
        Size of the random subsample that trains the dictionary.
    seed : int or None, default=0
        Seed of the K-SVD subsample and initialisation; None draws fresh entropy.
    preset : {"thesis"}, optional
        "thesis": unscaled features, S = 200, λ = 0.5 and ρ_i = δ/Sf_i in h;
        explicit parameters override it.

    Returns
    -------
    SimplifyResult
        ``keep_idx`` (ascending) and the scores behind it.

    Raises
    ------
    PointCloudError
        Empty, NaN/Inf, fewer than k + 1, coincident or collinear points; bad normals.
    InvalidParameterError
        A parameter out of range, or not exactly one of ratio/count/delta.

    Notes
    -----
    Deviations (docs/decisions/simplify.md, by heading): the PCA weight uses a
    length, exp(−d²/s_i²), where (6.1) mixes a length with a count ("PCA weight");
    the feature groups are balanced, since raw positions dominate ("Feature
    scaling"); the radius is clamped and measured in a blend of global and local
    spacing ("Removal radius"); the dictionary is trained on a subsample, for speed
    ("Dictionary").  For ``ratio``/``count`` δ is searched and the kept set made
    exact ("Hitting a count"); the greedy pass gives exactly the sequential result
    ("Greedy removal").  The thesis' form: ``feature_scale="thesis",
    density_adapt=0.0``.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> pts = rng.normal(size=(3000, 3)); pts /= np.linalg.norm(pts, axis=1)[:, None]
    >>> res = simplify_sdbs(pts, ratio=0.1, n_atoms=50)
    >>> len(res.keep_idx)
    300
    """
    func = "simplify_sdbs"
    size_params(ratio, count, delta, func)
    check_seed(seed, func=func)
    P = as_points(points, func=func, min_points=k + 1)
    n = len(P)
    N = None if normals is None else as_normals(normals, n, func=func)
    check_spread(P, func=func)
    target = target_count(ratio, count, n, func)

    P = P - P.mean(axis=0)
    tree = build_tree(P)
    # one k-NN query serves h, the PCA and the removal candidates
    gd, gi = _knn32(P, min(n, max(k, GRAPH_K)), tree)
    F, h, fdist = sdbs_features(P, N, k, feature_scale, nn=(gd, gi))[:3]
    # length unit of the radius: h^(1-β) h_i^β with h_i the local spacing
    # (mean distance to the 6 nearest neighbours) and β = density_adapt
    local = np.maximum(fdist[:, 1:7].mean(axis=1, dtype=np.float64), 1e-3 * h)
    unit = h * (local / h) ** density_adapt
    del fdist, local
    log.info("simplify_sdbs: features of %d points, h = %.4g", n, h)
    score, nnz, res = saliency_scores(F, n_atoms=n_atoms, alpha=alpha,
                                      max_iter=max_iter, max_train=max_train,
                                      seed=seed)
    del F
    inv = 1.0 / np.maximum(score, sf_floor)

    def run(dl):
        return greedy_keep(P, gd, gi, score, dl * unit * inv, tree=tree)

    return removal(run, score, nnz, res, h, n, target, delta, inv)


def removal(run, score, nnz, res, h: float, n: int, target, delta, inv) -> SimplifyResult:
    """The removal (6.11): δ given, or searched until the greedy count is
    within 1 % of ``target`` and the count then made exact; ``run(δ)`` is the
    greedy pass (one piece, or by tiles)."""
    d0 = delta if target is None else _delta_guess(target, n, inv)
    log.info("simplify_sdbs: saliency done; first delta %.4g h", d0)
    exact = None  # the count the greedy flags are made to keep
    if target is not None and target >= n:
        keep = np.ones(n, dtype=bool)
        d_use, n_greedy = 0.0, n
    elif target is None:
        d_use = delta
        keep = run(d_use)
        n_greedy = int(keep.sum())
    else:
        d_use, keep = _search_delta(run, target, d0)
        n_greedy, exact = int(keep.sum()), target
    keep_idx = _kept_rows(keep, score, exact)
    log.info("simplify_sdbs: kept %d of %d points (delta = %.4g h)", len(keep_idx), n,
             d_use)
    return SimplifyResult(keep_idx=keep_idx, score=score, delta=float(d_use), h=h,
                          nnz=nnz, residual=res, n_greedy=n_greedy)


def size_params(ratio, count, delta, func: str) -> None:
    """Exactly one of ratio, count and delta must be given."""
    given = [name for name, v in (("ratio", ratio), ("count", count), ("delta", delta))
             if v is not None]
    if len(given) != 1:
        raise InvalidParameterError(
            f"{func}: give exactly one of ratio, count, delta "
            f"(got {', '.join(given) or 'none'})")


def sdbs_tile(points, lo, hi, core, *, stage: str, centre, h: float, n_total: int, k: int,
              normals=None, score=None, rho=None) -> dict:
    """One tile of a tiled run (``pcprep.meshlab_bridge.tiles``).

    ``points`` are every point of the cloud in the box ``[lo, hi]``, ``core``
    the tile's own rows.  Stage ``"features"``: the normal and surface
    variation (``local_geometry``, about the cloud-wide ``centre``) and the
    mean 6-NN distance of the core rows, or ``{"exact": False}`` when a core
    row's k-NN ball may leave the box.  Stage ``"greedy"``: the greedy removal
    (6.11) over the tile's rows with the cloud-wide ``score`` and radii
    ``rho``, and the core rows' keep flags.  The greedy visit order is
    cloud-wide, so a core row's decision equals the one-piece decision unless
    a chain of earlier decisions reaches it from beyond the halo (measured in
    docs/decisions/scale.md).
    """
    from .neighbors import tile_miss

    x = points - centre
    kk = min(n_total, max(k, GRAPH_K))
    if len(x) < kk:
        return {"exact": False}
    tree = build_tree(x)
    gd, gi = _knn32(x, kk, tree)
    if stage == "features":
        reach = gd[core, k - 1].astype(np.float64) * (1.0 + 1e-6)  # float32 distances
        miss = tile_miss(x[core], reach, lo - centre, hi - centre)
        if miss is not None:
            return miss
        nrm, sigma = local_geometry(x, normals, gd[:, :k], gi[:, :k], h)
        return {"exact": True, "normals": nrm[core], "sigma": sigma[core],
                "rows6": gd[core, 1:7].mean(axis=1, dtype=np.float64)}
    keep = greedy_keep(x, gd, gi, score, rho, tree=tree)
    return {"exact": True, "keep": keep[core]}


def target_count(ratio, count, n: int, func: str) -> int | None:
    """The number of points to keep, or None when δ is given."""
    if count is not None:
        if count > n:
            raise InvalidParameterError(f"{func}: count must be in [1, {n}] (the number "
                                        f"of points), got {count}")
        return count
    if ratio is not None:
        return max(1, int(round(ratio * n)))
    return None


def _delta_guess(target: int, n: int, inv: np.ndarray) -> float:
    """First δ: the kept balls tile the surface (area ∝ n h², a ball ∝ (δ h inv)²).
    The mean of inv² is NumPy's read in chunks (``pairwise_sum``): ``inv`` of a
    tiled run is a memory map of every row."""
    return float(np.sqrt(n / (target * (pairwise_sum(inv, np.square) / len(inv)))))


#: first guess of the exponent e in count ∝ δ^-e (measured ≈ 1.5 on the
#: benchmark scans: greedy balls overlap, so the count falls slower than δ^-2)
_COUNT_EXP = 1.5


def _search_delta(run, target: int, d: float, max_eval: int = 30):
    """Find δ whose greedy count is within 1 % of ``target``.

    Secant steps on log count vs log δ through the last two evaluations (the
    first step assumes count ∝ δ^-1.5), kept inside the bracket once the
    target is bracketed."""
    tol = max(1, int(0.01 * target))
    lo = hi = None  # lo: δ with count > target; hi: δ with count < target
    best = prev = None
    for _ in range(max_eval):
        with progress.step(f"greedy removal (delta {d:.3g} h)", 1) as advance:
            keep = run(d)
            advance()
        c = int(keep.sum())
        log.info("simplify_sdbs: delta %.5g h keeps %d points (target %d)", d, c, target)
        if best is None or abs(c - target) < abs(best[2] - target):
            best = (d, keep, c)
        if abs(c - target) <= tol:
            break
        if c > target:
            lo = (d, c) if lo is None or d > lo[0] else lo
        else:
            hi = (d, c) if hi is None or d < hi[0] else hi
        e = _COUNT_EXP
        if prev is not None and prev[0] != d and prev[1] != c and min(c, prev[1]) > 0:
            e = -(np.log(c) - np.log(prev[1])) / (np.log(d) - np.log(prev[0]))
            e = float(min(max(e, 0.5), 4.0)) if np.isfinite(e) else _COUNT_EXP
        prev = (d, c)
        d_new = d * float((max(c, 1) / target) ** (1.0 / e))
        if lo is not None and hi is not None:
            a, b = np.log(lo[0]), np.log(hi[0])
            t = (np.log(d_new) - a) / (b - a)
            if not 0.05 <= t <= 0.95:  # secant left the bracket: interpolate in it
                c0, c1 = lo[1], hi[1]
                t = (np.log(target) - np.log(c0)) / (np.log(c1) - np.log(c0))
                t = min(max(t, 0.1), 0.9)
                d_new = float(np.exp(a + t * (b - a)))
        d = d_new
    return best[0], best[1]


def _kept_rows(keep, score: np.ndarray, target) -> np.ndarray:
    """The rows of the greedy keep flags, made ``target`` many when given: the
    least salient kept rows dropped, or the most salient removed rows added,
    ties by row.  The rows to flip are picked chunk by chunk
    (``sparse.FirstInOrder`` over the eligible rows' scores, +inf for the
    others), so the flags and scores of a tiled run, memory maps, are read
    and never copied whole; only the kept rows' list is built."""
    n = len(keep)
    rows = nonzero_rows(keep)
    c = len(rows)
    if target is None or c == target:
        return rows.astype(np.int64)
    drop = c > target
    first = sparse.FirstInOrder(abs(c - target))
    for s0 in range(0, n, CHUNK):
        k = np.asarray(keep[s0:s0 + CHUNK], dtype=bool)
        v = np.asarray(score[s0:s0 + CHUNK], dtype=np.float64)
        first.add(np.where(k, v, np.inf) if drop else np.where(k, np.inf, -v), s0)
    flip = np.sort(first.rows())
    if drop:
        return rows[~np.isin(rows, flip, assume_unique=True)].astype(np.int64)
    return np.sort(np.concatenate([rows, flip])).astype(np.int64)
