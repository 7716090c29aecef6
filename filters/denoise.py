"""
denoise.py
----------
Feature-preserving point-cloud denoising, thesis chapter 4 (Algorithm 4.1): per
point a robust tangent plane (unit normal n_i, offset τ_i) minimising an
L1-median height fit plus an L1 total-variation term on the normals (4.5), then
a bounded move of the point onto its plane (4.15), with edge detection
(4.16)-(4.17) and an optional edge correction (4.18)-(4.19).  A final projection
onto algebraic spheres (on by default) is not in the thesis.

The steps live in ``_denoise_steps`` (Algorithm 4.1), ``_denoise_project``
(final projection) and ``_denoise_kernels`` (the chunked, threaded array
kernels); this module holds the public API and the outer iteration.  The
decisions behind each rule and default, with their measurements, are in
docs/decisions/denoise.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from . import progress
from ._denoise_kernels import _Ctx, _prepare
from ._denoise_project import _pca_normals, _sphere_project
from ._denoise_steps import PlannedDecisions, _edge_correct, _init_normals, _inner_loop, \
    _inner_pass, _smooth_curvature
from ._params import Param, preset_param, validate_params
from ._validation import InvalidParameterError
from .neighbors import orient_normals_mst, tile_exact

log = logging.getLogger("pcprep")

#: neighbour normals tried as starting points of (4.9)
N_CAND = 8
#: neighbours of the MST orientation of the output normals
MST_K = 6
#: default neighbourhood radius r in units of σ_d
RADIUS_FACTOR = 1.5
#: sag |c|·r² (units of h) of the fit h ≈ a + cρ² above which a non-edge point
#: counts as curved and stops moving after ``curved_iter`` outer iterations
CURVED_SAG = 0.05
#: neighbours of the plain PCA normals that seed the final sphere fit on curved parts
FIT_PCA_K = 16

#: the method as printed (Algorithm 4.1): λ = 0.2, the component-wise ℓ1 TV of
#: (4.5), σ_h = 0.7h and σ_d = r = 3h (Table 4.1, fandisk and rocker arm), 16 outer
#: iterations, the inner loop run to its stopping rule, n⁰ by (4.9), edge correction
#: (4.18)-(4.19) on, and none of the added steps (n⁰ about the robust plane,
#: curvature offset, final projection, freezing curved points); k_max wide enough
#: that the 3h ball is not cut
THESIS = {"lambda_tv": 0.2, "tv_norm": "l1", "sigma_h": 0.7, "sigma_d": 3.0, "radius": 3.0,
          "n_iter": 16, "curved_iter": 16, "inner_iter": 10, "init_iter": 3,
          "robust_init": False, "edge_correction": True, "curvature_offset": False, "final_projection": False,
          "k_max": 64}

PARAMS = (
    Param("lambda_tv", float, low=0.0, high=100.0),
    Param("sigma_h", float, low=0.01, high=50.0, unit="h"),
    Param("sigma_d", float, low=0.1, high=50.0, unit="h"),
    Param("radius", float, low=0.5, high=50.0, unit="h", optional=True),
    Param("sigma_n_deg", float, low=0.1, high=90.0, unit="deg"),
    Param("rho", float, low=0.0, high=10.0, unit="h"),
    Param("delta", float, low=0.0, high=1.0, unit="h"),
    Param("epsilon", float, low=0.0, high=100.0, closed="right", unit="h"),
    Param("edge_threshold", float, low=0.0, high=1.0, unit="fraction"),
    Param("n_iter", int, low=1, high=500, unit="count"),
    Param("curved_iter", int, low=0, high=500, unit="count", advanced=True),
    Param("inner_iter", int, low=1, high=100, unit="count", advanced=True),
    Param("init_iter", int, low=1, high=50, unit="count", advanced=True),
    Param("robust_init", bool, advanced=True),
    Param("tol", float, low=0.0, high=10.0, unit="h", advanced=True),
    Param("edge_correction", bool),
    Param("curvature_offset", bool, advanced=True),
    Param("tv_norm", str, choices=("l2", "l1"), advanced=True),
    Param("k_max", int, low=4, high=512, unit="count", advanced=True),
    Param("final_projection", bool, advanced=True),
    preset_param({"thesis": THESIS}),
)


@dataclass(frozen=True)
class DenoiseResult:
    """Output of :func:`denoise_l1_tv`.

    Attributes
    ----------
    points : (n, 3) float
        Denoised positions, in input order.
    normals : (n, 3) float
        Unit normals, consistently oriented (toward the input normals when given,
        else by MST propagation).
    edge_mask : (n,) bool
        Edge points of the last outer iteration, V_n < th (4.17).
    edge_score : (n,) float
        Normal variation V_n in [0, 1] (1 = flat neighbourhood).
    h : float
        Average spacing of the input (mean distance to 6 nearest neighbours).
    energy_history : tuple of tuple of float
        Energy (4.5) summed over points, lengths in units of h, at every accepted
        inner iteration of every outer iteration (non-increasing within each).
    n_iter_run : int
        Outer iterations run.
    n_corrected : int
        Points moved by the edge correction in the last outer iteration.
    """

    points: np.ndarray
    normals: np.ndarray
    edge_mask: np.ndarray
    edge_score: np.ndarray
    h: float
    energy_history: tuple
    n_iter_run: int
    n_corrected: int


@dataclass(frozen=True)
class _Config:
    """The keyword arguments of :func:`denoise_l1_tv`, one field each (lengths in
    units of h).  ``_DEFAULTS`` holds the signature's defaults."""

    lambda_tv: float
    sigma_h: float
    sigma_d: float
    radius: float | None
    sigma_n_deg: float
    rho: float
    delta: float
    epsilon: float
    edge_threshold: float
    n_iter: int
    curved_iter: int
    inner_iter: int
    init_iter: int
    robust_init: bool
    tol: float
    edge_correction: bool
    curvature_offset: bool
    tv_norm: str
    k_max: int
    final_projection: bool


@validate_params(*PARAMS, presets={"thesis": THESIS})
def denoise_l1_tv(points, normals=None, *, lambda_tv: float = 0.4, sigma_h: float = 0.6,
                  sigma_d: float = 2.0, radius: float | None = None,
                  sigma_n_deg: float = 15.0, rho: float = 0.7, delta: float = 1e-4,
                  epsilon: float = 4.0, edge_threshold: float = 0.5, n_iter: int = 6,
                  curved_iter: int = 2, inner_iter: int = 2, init_iter: int = 3,
                  robust_init: bool = True, tol: float = 1e-3, edge_correction: bool = False,
                  curvature_offset: bool = True, tv_norm: str = "l2", k_max: int = 32,
                  final_projection: bool = True, preset: str | None = None
                  ) -> DenoiseResult:
    """Denoise a point cloud, preserving sharp edges (Leal Narváez 2020, Algorithm 4.1).

    Per point, n_i and τ_i minimise (4.5), Σ_j |h_ij − τ_i| ψ θ + λ Σ_j w_ij ‖n_i − n_j‖
    (h_ij = n_iᵀ(p_i − p_j); ψ, θ (4.3); w_ij (4.4)): n⁰ by (4.9), then IRLS τ steps
    (4.14) alternate with proximal normal steps (4.10)-(4.12); p_i ← p_i − τ_i n_i
    within ε (4.15); V_n < th marks edges (4.16)-(4.17), optionally corrected
    (4.18)-(4.19).  Lengths are in units of the robust spacing h.

    Parameters
    ----------
    points : (n, 3) float
        Noisy positions.
    normals : (n, 3) float, optional
        Orientation hint only: the output normals are flipped to agree with it.
    lambda_tv : float, default=0.4
        λ, weight of the TV normal term of (4.5).
    sigma_h : float, default=0.6
        σ_h of the height weight ψ (4.3).
    sigma_d : float, default=2.0
        σ_d of the distance weight θ (4.3).
    radius : float, optional
        Neighbourhood radius r; None uses 1.5 σ_d (the thesis: σ_d).
    sigma_n_deg : float, default=15.0
        σ_n of w_ij (4.4), the edge detector (4.16) and the correction (4.18).
    rho : float, default=0.7
        ρ: the edge correction moves a point by less than ρ (4.19).
    delta : float, default=1e-4
        δ: edge-correction moves below δ are skipped (4.19).
    epsilon : float, default=4.0
        ε: a move that would take a point farther than ε from its input is skipped (4.15).
    edge_threshold : float, default=0.5
        th: V_n < th marks an edge point (4.17); the thesis uses 0.2-0.5.
    n_iter : int, default=6
        Outer iterations j_max (the thesis: 10-50).
    curved_iter : int, default=2
        Outer iterations after which curved non-edge points stop moving (≥ n_iter: never).
    inner_iter : int, default=2
        Most (τ, n) passes per outer iteration.
    init_iter : int, default=3
        Passes of the eigen-iteration (4.9) that gives n⁰.
    robust_init : bool, default=True
        (4.9) about the robust plane p_i − τ_i n_i, with a search over neighbour
        normals (False: as printed, about p_i with τ = 0).
    tol : float, default=1e-3
        The inner loop stops when the RMS move of p − τn is below tol.
    edge_correction : bool, default=False
        Apply the edge-point correction (4.18)-(4.19).
    curvature_offset : bool, default=True
        Move by the intercept a of the fit h ≈ a + cρ² instead of τ (False: (4.15)).
    tv_norm : {"l2", "l1"}, default="l2"
        Norm of n_i − n_j in (4.4): Euclidean, or the thesis' component-wise "l1".
    k_max : int, default=32
        Most neighbours per point (the radius neighbourhood keeps the k_max nearest).
    final_projection : bool, default=True
        Finish by projecting each input point onto a sphere fitted to its neighbours.
    preset : {"thesis"}, optional
        "thesis": Algorithm 4.1 as printed (λ = 0.2, ℓ1 TV, σ_h = 0.7, σ_d = r = 3,
        16 iterations, edge correction, no added steps); explicit parameters
        override it.

    Returns
    -------
    DenoiseResult
        Positions, normals, edge mask and diagnostics, in input order.

    Raises
    ------
    PointCloudError
        Empty, NaN/Inf, fewer than 7, coincident or collinear points; bad normals.
    InvalidParameterError
        A parameter out of range or of the wrong type.

    Notes
    -----
    Deviations (docs/decisions/denoise.md, by heading): the signs of (4.15) and
    (4.16) are corrected ("Sign of the position update"); (4.9) uses τ, as τ = 0 lets
    a point's noise tilt n⁰ ("Initial normals n⁰"); the ℓ2 TV norm is rotation
    invariant ("Regulariser norm"); curvature offset, per-point stopping and final
    projection counter the shrinkage of curved parts ("Bounded position update",
    "Per-point stopping on curved parts", "Final projection").  The thesis' form:
    tv_norm="l1", curvature_offset=False, curved_iter ≥ n_iter,
    final_projection=False, edge_correction=True, radius=sigma_d, robust_init=False.

    Examples
    --------
    >>> g = np.random.default_rng(0)
    >>> noisy = np.c_[g.uniform(-1, 1, (2000, 2)), 0.01 * g.normal(size=2000)]
    >>> out = denoise_l1_tv(noisy, n_iter=5)
    >>> bool(np.abs(out.points[:, 2]).mean() < np.abs(noisy[:, 2]).mean())
    True
    """
    args = locals()  # the checked arguments, by name
    return _denoise(points, normals, _Config(**{k: args[k] for k in _FIELDS}))


#: the parameters as the signature declares them (defaults of the private path)
_FIELDS = tuple(p.name for p in denoise_l1_tv.params if p.name != "preset")
_DEFAULTS = _Config(**{p.name: p.default for p in denoise_l1_tv.params if p.name in _FIELDS})


def _denoise(points, normals, cfg: _Config) -> DenoiseResult:
    """:func:`denoise_l1_tv` with its parameters in ``cfg`` (not checked here)."""
    func = "denoise_l1_tv"
    x, hint, centre, h, idx, perm = _prepare(points, normals, cfg.k_max, func)
    n = len(x)
    x0 = x.copy()
    ctx = _context(x, idx, cfg)
    log.info("%s: n=%d h=%.4g k_max=%d", func, n, h, idx.shape[1])
    nrm, vn, frozen, history, n_corr = _iterate(ctx, x0, cfg)
    if cfg.final_projection:
        _project_input(ctx, x0, nrm, vn, frozen, cfg)
    if normals is None:
        k = min(MST_K, idx.shape[1] - 1)
        nrm = orient_normals_mst(ctx.x, nrm, k=k, neighbors=idx[:, 1:k + 1])
    inv = np.empty(n, dtype=np.int64)  # noqa: NPY-empty -- a permutation fills it
    inv[perm] = np.arange(n)
    out_n = nrm[inv]
    out_p = ctx.x[inv] * h + centre
    if hint is not None:
        flip = np.einsum("ij,ij->i", out_n, hint[inv]) < 0
        out_n[flip] *= -1.0
    vn = vn[inv]
    return DenoiseResult(points=out_p, normals=out_n, edge_mask=vn < cfg.edge_threshold,
                         edge_score=vn, h=h, energy_history=history,
                         n_iter_run=cfg.n_iter, n_corrected=n_corr)


def _iterate(ctx: _Ctx, x0: np.ndarray, cfg: _Config, sync=None):
    """The outer iterations of Algorithm 4.1, moving ``ctx.x`` in place.

    Returns the normals, V_n of the last iteration, the points frozen as curved
    (they keep the normal of their last move), the energy history and the number
    of points the last edge correction moved.
    """
    n = len(ctx.x)
    nrm = _init_normals(ctx, cfg.init_iter, N_CAND, printed=not cfg.robust_init)
    history = []
    vn = np.ones(n)
    n_corr = 0
    eps2 = cfg.epsilon ** 2
    frozen = np.zeros(n, dtype=bool)
    frozen_n = np.zeros((n, 3))
    with progress.step("denoise iterations", cfg.n_iter) as advance:
        for j in range(cfg.n_iter):
            nrm, tau, (vn, off, curv), hist_j = _inner_loop(ctx, nrm, cfg.inner_iter, cfg.tol, sync)
            history.append(hist_j)
            # position update (4.15), sign corrected, bounded by ε
            shift = off if cfg.curvature_offset else tau
            cand = ctx.x - shift[:, None] * nrm
            far = np.square(cand - x0).sum(axis=1) > eps2
            cand[far] = ctx.x[far]
            if j >= cfg.curved_iter:  # curved, non-edge points stop moving
                sag = np.abs(_smooth_curvature(ctx, nrm, curv)) * ctx.r2
                new = ~frozen & (vn >= cfg.edge_threshold) & (sag > CURVED_SAG)
                frozen_n[new] = nrm[new]
                frozen |= new
                cand[frozen] = ctx.x[frozen]
            ctx.x[:] = cand
            edge = vn < cfg.edge_threshold
            if cfg.edge_correction:
                n_corr = _edge_correct(ctx, nrm, edge, cfg.rho, cfg.delta)
            ctx.refresh()
            log.info("denoise_l1_tv: iteration %d/%d energy %.6g, %d edge points, "
                     "%d corrected", j + 1, cfg.n_iter, hist_j[-1], int(edge.sum()), n_corr)
            advance()
    if frozen.any():
        same = np.einsum("ij,ij->i", frozen_n, nrm) >= 0
        nrm = np.where(frozen[:, None], np.where(same[:, None], frozen_n, -frozen_n), nrm)
    return nrm, vn, frozen, tuple(history), n_corr


def _project_input(ctx: _Ctx, x0: np.ndarray, nrm: np.ndarray, vn: np.ndarray,
                   frozen: np.ndarray, cfg: _Config) -> None:
    """Final projection: ``ctx.x`` ← the input points projected onto spheres
    fitted with the filtered normals (plain PCA normals on frozen points), where
    the move stays within ε and the fit is sound."""
    cin = _context(x0, ctx.idx, cfg)
    fit_n = nrm
    if frozen.any():
        rows = np.flatnonzero(frozen)
        fit_n = nrm.copy()
        fit_n[rows] = _pca_normals(cin, min(FIT_PCA_K, ctx.idx.shape[1]), rows)
    off, ok = _sphere_project(cin, fit_n, ctx.x)
    ok &= np.square(off).sum(axis=1) <= cfg.epsilon ** 2
    if cfg.edge_correction:  # corrected edge points keep (4.18)-(4.19)
        ok &= vn >= cfg.edge_threshold
    ctx.x[ok] = x0[ok] + off[ok]


def _context(x: np.ndarray, idx: np.ndarray, cfg: _Config) -> _Ctx:
    """Working state over positions ``x`` (units of h) and neighbours ``idx``."""
    r = RADIUS_FACTOR * cfg.sigma_d if cfg.radius is None else cfg.radius
    sig_n = np.deg2rad(cfg.sigma_n_deg)
    ctx = _Ctx(x=x, idx=idx, r2=r * r, sd2=cfg.sigma_d ** 2, sh2=cfg.sigma_h ** 2,
               lam=cfg.lambda_tv, cos_n=float(np.cos(sig_n)), sn2=float(sig_n ** 2),
               l1=cfg.tv_norm == "l1")
    ctx.refresh()
    return ctx


def denoise_hops(params: dict) -> int:
    """How many times a point's result reads its neighbours' intermediate values.

    n⁰: the candidate selection reads the neighbours' normals (1; the eigen
    passes read only their input positions).  Every outer iteration: each inner
    pass reads the neighbours' positions and normals (at most ``inner_iter + 1``
    passes, the undo or the ``tol`` re-check included), the curvature smoothing
    their curvatures (1, once ``curved_iter`` is reached) and the edge correction
    their normals (1, when on).  The final projection reads the neighbours'
    normals once (1).  Defaults: 1 + 6 × (2 + 1 + 1) + 1 = 26.
    """
    cfg = replace(_DEFAULTS, **params)
    per = cfg.inner_iter + 1 + 1 + int(cfg.edge_correction)
    return 1 + cfg.n_iter * per + int(cfg.final_projection)


def denoise_tile(points, normals, lo, hi, core, *, centre, h: float, n_total: int,
                 hops: int, plan=(), **params) -> dict:
    """One tile of a tiled :func:`denoise_l1_tv` run (meshlab_bridge/tiles.py).

    ``points`` are every point of the cloud inside the box ``[lo, hi]`` (±inf on
    the sides beyond which the cloud has nothing), ``core`` the rows whose
    result is kept.  The whole cloud's ``centre``, ``h`` and size ``n_total``
    replace the tile's own; the inner loop's cloud-wide decisions follow
    ``plan`` (see :class:`PlannedDecisions`).  Returns a dict: ``exact`` (False:
    a core row depends on points outside the box within ``hops`` neighbour
    steps; nothing else is computed), ``points``, ``normals`` (MST-oriented
    within the tile when ``normals`` is None), ``edge_score`` for every row,
    ``sure`` (the rows whose result is exact) and ``trace``.  The parameters are
    :func:`denoise_l1_tv`'s, checked by the caller.
    """
    func = "denoise_l1_tv"
    cfg = replace(_DEFAULTS, **{k: v for k, v in params.items() if k != "preset"})
    k_all = min(max(cfg.k_max, 7), n_total)
    if len(points) < k_all:
        return {"exact": False}
    x, hint, centre, h, idx, perm, kth = _prepare(points, normals, cfg.k_max, func,
                                                  tile=(np.asarray(centre), h, n_total))
    core = np.asarray(core, dtype=bool)[perm]
    sure = tile_exact(x, idx, kth, (np.asarray(lo) - centre) / h,
                      (np.asarray(hi) - centre) / h, hops)
    if not sure[core].all():
        return {"exact": False}
    n = len(x)
    x0 = x.copy()
    ctx = _context(x, idx, cfg)
    sync = PlannedDecisions(core, plan)
    nrm, vn, frozen, _, _ = _iterate(ctx, x0, cfg, sync)
    if cfg.final_projection:
        _project_input(ctx, x0, nrm, vn, frozen, cfg)
    if normals is None:
        k = min(MST_K, idx.shape[1] - 1)
        nrm = orient_normals_mst(ctx.x, nrm, k=k, neighbors=idx[:, 1:k + 1])
    inv = np.empty(n, dtype=np.int64)  # noqa: NPY-empty -- a permutation fills it
    inv[perm] = np.arange(n)
    out_n = nrm[inv]
    if hint is not None:
        flip = np.einsum("ij,ij->i", out_n, hint[inv]) < 0
        out_n[flip] *= -1.0
    return {"exact": True, "points": ctx.x[inv] * h + centre, "normals": out_n,
            "edge_score": vn[inv], "sure": sure[inv], "trace": tuple(sync.trace)}


_ENERGY_NAMES = ("lambda_tv", "sigma_h", "sigma_d", "radius", "sigma_n_deg", "k_max")
_ENERGY_PARAMS = tuple(p for p in PARAMS if p.name in _ENERGY_NAMES)


@validate_params(*_ENERGY_PARAMS)
def energy_l1_tv(points, normals, tau=None, *, lambda_tv: float = 0.4,
                 sigma_h: float = 0.6, sigma_d: float = 2.0, radius: float | None = None,
                 sigma_n_deg: float = 15.0, k_max: int = 32) -> float:
    """The energy (4.5) summed over all points, lengths in units of h.

    Σ_i [Σ_j |h_ij − τ_i| ψ θ + λ Σ_{j≠i} w_ij ‖n_i − n_j‖₂], with the weights of
    :func:`denoise_l1_tv` (its default ``tv_norm="l2"``).

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float
        Unit normals (their signs do not matter: neighbours are sign-aligned).
    tau : (n,) float, optional
        Offsets τ_i in units of h; default 0.
    lambda_tv : float, default=0.4
        As in :func:`denoise_l1_tv`.
    sigma_h : float, default=0.6
        As in :func:`denoise_l1_tv`.
    sigma_d : float, default=2.0
        As in :func:`denoise_l1_tv`.
    radius : float, optional
        As in :func:`denoise_l1_tv`.
    sigma_n_deg : float, default=15.0
        As in :func:`denoise_l1_tv`.
    k_max : int, default=32
        As in :func:`denoise_l1_tv`.

    Returns
    -------
    float
    """
    func = "energy_l1_tv"
    if normals is None:
        raise InvalidParameterError(f"{func}: normals must be given")
    cfg = replace(_DEFAULTS, lambda_tv=lambda_tv, sigma_h=sigma_h, sigma_d=sigma_d,
                  radius=radius, sigma_n_deg=sigma_n_deg, k_max=k_max)
    x, nrm, _, _, idx, perm = _prepare(points, normals, cfg.k_max, func)
    t = np.zeros(len(x)) if tau is None else \
        np.asarray(tau, dtype=np.float64).reshape(len(x))
    ctx = _context(x, idx, cfg)
    e_i, _, _, _ = _inner_pass(ctx, nrm, t[perm], propose=False)
    return float(e_i.sum())
