"""
sharp.py
--------
Sharp-feature detection (edges, corners) by the code length of multi-scale
covariance features on a learned dictionary, thesis §7.3, eqs (7.1)-(7.11).

1. Features per scale (7.1)-(7.4): λ0/h², λ0/λ2, σ = λ0/Σλ and Pd/h, from one
   sorted k-NN query (``sharp_features``), concatenated over the scales (§7.3.5).
2. Shared stage (``multiscale.fit_score_model``, ``score_rows``): robust
   standardisation and K-SVD fitted once per cloud,
   every point coded, a code-length score f per point.
3. Threshold: Otsu on the winsorised score, or T = β·max f (7.10); f > T (7.11).
4. Not in the thesis: a crease-angle gate (``min_angle``) and a localisation
   step that keeps the points near the crease line (``crease_width``,
   ``plane_width``); helpers in ``_crease.py``.

The measurements behind every rule are in docs/decisions/features.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields

import numpy as np

from ._crease import (SPREAD_K, crease_distance, localisation_k, noise_level,
                      normal_spread, plane_k, two_plane_distance)
from ._params import Param, preset_param, resolve_params, validate_params
from ._validation import PointCloudError
from .multiscale import (SCORE_PARAMS, CodeLengths, Detection, ScoreConfig, fit_score_model,
                         otsu_threshold, prepare_cloud, record_step, scale_moments,
                         scale_sizes, score_rows)
from .neighbors import SPACING_K, average_spacing, quantile, spacing_from_rows

log = logging.getLogger("pcprep")

_FUNC = "detect_sharp_features"
#: quantile at which the score is winsorised before Otsu's threshold
_WINSOR_Q = 0.95
#: automatic threshold as a fraction of Otsu's split when gate and localisation are on
_OTSU_SCALE_GATED = 0.6
#: the two-plane model is used where its RMS residual is at most
#: _PLANE_RMS0 + _PLANE_RMS_GAIN·σ̂ (in h)
_PLANE_RMS0 = 0.05
_PLANE_RMS_GAIN = 1.2
#: neighbourhood size whose PCA normals seed the two-plane split and the angle gate
_NORMAL_K = 16


@dataclass(frozen=True)
class _SharpRules:
    """Which of the steps not in the thesis run (all do by default).

    Off switches for the benchmark's ablation rows and a future thesis preset;
    the public function always uses ``DEFAULT_RULES``.  See
    docs/decisions/features.md, section "Parameters that left the public API".
    """

    localise: bool = True         # keep points within a width of the crease line
    two_plane: bool = True        # the two-plane crease model where it fits
    angle_gate: bool = True       # the crease-angle gate (min_angle)
    uniform_pca: bool = True      # uniform weights in (7.1), not the printed Gaussian


DEFAULT_RULES = _SharpRules()
#: the thesis' method has none of the added steps
THESIS_RULES = _SharpRules(localise=False, two_plane=False, angle_gate=False,
                           uniform_pca=False)

#: the method as printed (§7.3-§7.4.1): Lasso coding with λ = 0.01 (λ = 2·alpha in
#: the ½‖·‖² convention of ``sparse.lasso_lars``), S = 100 atoms, ten scales, the
#: atom count (7.8) and T = β·max f (7.10) with the β = 0.02 of Figure 7.2
THESIS = {"coder": "lasso_lars", "alpha": 0.005, "score": "count", "beta": 0.02,
          "n_atoms": 100, "n_scales": 10, "min_angle": 0.0}

PARAMS = (
    Param("crease_width", float, low=0.0, high=100.0, closed="right", unit="h"),
    Param("plane_width", float, low=0.0, high=100.0, closed="right", unit="h"),
    Param("min_angle", float, low=0.0, high=90.0, unit="deg"),
    Param("otsu_scale", float, low=0.0, high=1.0, closed="right", optional=True),
    *SCORE_PARAMS,
    preset_param({"thesis": THESIS}),
)


@dataclass(frozen=True)
class _SharpConfig:
    """The sharp-specific parameters of ``detect_sharp_features``, validated."""

    crease_width: float
    plane_width: float
    min_angle: float
    otsu_scale: float | None
    beta: float | None


@dataclass(frozen=True)
class SharpFeatures:
    """Multi-scale sharp features of a cloud (``sharp_features``).

    Attributes
    ----------
    features : (n, 4·s) float
        Scale-major columns (λ0/h², λ0/λ2, σ, Pd/h) of scale 0, then scale 1, ...
    h : float
        Average spacing used to make them unit-free.
    normals : (n, 3) float
        PCA normals of the scale nearest 16 points (sign arbitrary).
    noise_column : (n,) float
        λ0/h² of the smallest scale (``features[:, 0]``), the input of the
        noise estimate.
    ridge_pd : (n,) float
        Mean Pd/h over the larger half of the scales, the ridge strength's
        factor.  Both are kept apart from ``features``, which the detector
        standardises in place to stay within one copy of the feature matrix.
    reach : (n,) float
        Distance to the largest scale's last neighbour: every feature of the
        row reads only points within it (a tiled run checks its halo with it).
    spacing_rows : (n,) float or None
        With ``raw``: every row's mean distance to its ``SPACING_K`` nearest
        neighbours, from the same query (None when the largest scale is not
        larger than ``SPACING_K``).
    """

    features: np.ndarray
    h: float | None
    normals: np.ndarray
    noise_column: np.ndarray | None
    ridge_pd: np.ndarray | None
    reach: np.ndarray
    spacing_rows: np.ndarray | None = None


@dataclass(frozen=True)
class SharpResult(Detection):
    """Result of ``detect_sharp_features``: the fields of ``multiscale.Detection``
    and the diagnostics of its two gates.

    Attributes
    ----------
    crease_distance : (n,) float or None
        Each point's distance to its estimated crease line, in h (``inf`` for
        points below the threshold); None when the step did not run (nothing
        above the threshold).
    crease_limit : (n,) float or None
        The width each ``crease_distance`` was compared with, in h.
    normal_spread : (n,) float or None
        ``normal_spread`` in degrees of the points above the threshold (NaN
        elsewhere); None when the gate is off or nothing passed the threshold.
    """

    crease_distance: np.ndarray | None = None
    crease_limit: np.ndarray | None = None
    normal_spread: np.ndarray | None = None


def sharp_features(points: np.ndarray, ks: np.ndarray, *, h: float | None = None,
                   tree=None, weighted: bool = False, raw: bool = False) -> SharpFeatures:
    """Features (7.1)-(7.4) of every point at every scale.

    Per scale: λ0/h², λ0/λ2, σ = λ0/(λ0 + λ1 + λ2) (7.2) and Pd/h with
    Pd = |(p_i − p̄)·n| (7.4), n the eigenvector of λ0 (7.1).

    Parameters
    ----------
    points : (n, 3) float
        Centred cloud.
    ks : (s,) int
        Increasing neighbourhood sizes (``multiscale.scale_sizes``).
    h : float, optional
        Average spacing; by default the mean distance to the 6 nearest
        neighbours over the points that are not isolated
        (``neighbors.spacing_from_rows``), taken from the same query.
    tree : cKDTree, optional
    weighted : bool
        The Gaussian weights of (7.1) as printed (``scale_moments``).
    raw : bool
        Leave λ0 and Pd in the cloud's units (``h``, ``noise_column`` and
        ``ridge_pd`` None) and return ``spacing_rows``: for a caller that
        fits h over more rows than these (a tiled run, whose h is the whole
        cloud's) and then applies ``scale_features``.

    Returns
    -------
    SharpFeatures

    Examples
    --------
    >>> from pcprep.baselines.datasets import make_shape
    >>> s = make_shape("cube", n=2000, seed=0)
    >>> sharp_features(s.points, scale_sizes(8, 40, 10)).features.shape
    (2000, 40)
    """
    n = len(points)
    ks = np.asarray(ks, dtype=np.int64)
    own_h = (h is None or raw) and int(ks[-1]) > SPACING_K
    if h is None and not own_h and not raw:
        h = average_spacing(points, tree=tree)
    out = np.empty((n, 4 * len(ks)))  # noqa: NPY-empty -- every row written below
    normals = np.empty((n, 3))  # noqa: NPY-empty -- every row written below
    reach = np.empty(n)  # noqa: NPY-empty -- every entry written below
    rows = np.empty(n) if own_h else None  # noqa: NPY-empty -- every entry written below
    j_nrm = int(np.argmin(np.abs(ks - _NORMAL_K)))
    for m in scale_moments(points, ks, tree=tree, weighted=weighted):
        at = m.rows
        if own_h:
            rows[at] = m.dist[:, 1:SPACING_K + 1].mean(axis=1)
        reach[at] = m.dist[:, -1]
        lam = m.eigenvalues
        l0, l2s = lam[..., 0], np.maximum(lam[..., 2], 1e-300)
        shift_n = np.einsum("csd,csd->cs", m.mean, m.normal)   # (p̄ − p_i)·n
        f = np.stack([l0, l0 / l2s, l0 / np.maximum(lam.sum(-1), 1e-300),
                      np.abs(shift_n)], axis=-1)
        out[at] = f.reshape(len(at), -1)
        normals[at] = m.normal[:, j_nrm]
    if raw:
        return SharpFeatures(features=out, h=None, normals=normals, noise_column=None,
                             ridge_pd=None, reach=reach, spacing_rows=rows)
    if own_h:
        h = spacing_from_rows(rows)
        if not np.isfinite(h) or h <= 0.0:
            raise PointCloudError(
                "average_spacing: every point coincides with its neighbours (h = 0)")
    scale_features(out, h)
    return SharpFeatures(features=out, h=float(h), normals=normals,
                         noise_column=out[:, 0].copy(),
                         ridge_pd=ridge_factor(out[:, 3::4][:, len(ks) // 2:]), reach=reach)


def scale_features(out: np.ndarray, h: float) -> None:
    """λ0 in h² and Pd in h (7.2), (7.4), in place, for scale-major rows
    (λ0, λ0/λ2, σ, Pd) of ``sharp_features``: the rule that makes the
    features independent of the cloud's scale."""
    out[:, 0::4] /= h * h
    out[:, 3::4] /= h


def ridge_factor(pd: np.ndarray) -> np.ndarray:
    """The ridge strength's factor: every row's mean Pd/h over the larger
    half of the scales, ``pd`` (m, s) being those columns.  The mean is taken
    over a contiguous copy, so that a tiled run, which holds the columns
    apart, gets the same bits."""
    return np.ascontiguousarray(pd).mean(axis=1)


def threshold(score: np.ndarray, cfg: _SharpConfig, rules: _SharpRules) -> float:
    """T = β·max f (7.10), or a fraction of Otsu's split of the score winsorised
    at its 95th percentile (see docs/decisions/features.md, sections
    "Sharp threshold: winsorised Otsu" and "Threshold below Otsu's split")."""
    if cfg.beta is not None:
        return float(cfg.beta * score.max())
    T = otsu_threshold(score, clip=quantile(score, _WINSOR_Q))
    if cfg.otsu_scale is not None:
        return T * float(cfg.otsu_scale)
    gated = rules.angle_gate and cfg.min_angle > 0 and rules.localise
    return T * (_OTSU_SCALE_GATED if gated else 1.0)


def _crease_limits(pts, mask, ridge, normals, *, h: float, sigma: float,
                   cfg: _SharpConfig, rules: _SharpRules, tree,
                   reach=None) -> tuple[np.ndarray, np.ndarray]:
    """Each detected point's distance to its crease line and the width it must
    meet (two-plane model where it fits, ridge line elsewhere), both in h."""
    cdist = crease_distance(pts, mask, ridge, h=h, k=localisation_k(sigma), tree=tree,
                            reach=reach)
    limit = np.full(len(pts), float(cfg.crease_width))
    if rules.two_plane:
        k_pl = plane_k(sigma)
        pdist, prms = two_plane_distance(pts, mask, normals, h=h, k=k_pl, tree=tree,
                                         reach=reach)
        planar = np.isfinite(pdist) & (prms <= _PLANE_RMS0 + _PLANE_RMS_GAIN * sigma)
        log.info("%s: two-plane crease model (k=%d) fits %d of %d detected points",
                 _FUNC, k_pl, int(planar.sum()), int(mask.sum()))
        cdist = np.where(planar, pdist, cdist)
        limit[planar] = cfg.plane_width
    return cdist, limit


def local_k(sigma: float, cfg: _SharpConfig, rules: _SharpRules) -> int:
    """The largest neighbourhood the steps after the threshold read (a tiled
    run's halo must hold it around every detected core point)."""
    k = 1
    if rules.angle_gate and cfg.min_angle > 0:
        k = max(k, SPREAD_K)
    if rules.localise:
        k = max(k, localisation_k(sigma), plane_k(sigma) if rules.two_plane else 1)
    return k


def _localise(pts, tree, mask, normals, ridge, *, h: float, sigma: float,
              cfg: _SharpConfig, rules: _SharpRules, reach=None):
    """The crease-angle gate and the localisation of the thresholded ``mask``
    (changed in place).  Every test reads one detected point's neighbourhood
    only, given the cloud-wide noise level ``sigma``; ``reach``, where given,
    gets the widest neighbourhood each row read (``_crease``).  Returns
    ``spread, cdist, limit`` (None for a step not run)."""
    spread = cdist = limit = None
    if rules.angle_gate and cfg.min_angle > 0 and mask.any():
        spread = normal_spread(pts, mask, normals, tree=tree, reach=reach)
        n_det = int(mask.sum())
        mask &= spread >= cfg.min_angle
        record_step("crease-angle gate", mask)
        log.info("%s: crease-angle gate (%.3g deg) keeps %d of %d detected points",
                 _FUNC, cfg.min_angle, int(mask.sum()), n_det)
    if rules.localise and mask.any():
        cdist, limit = _crease_limits(pts, mask, ridge, normals, h=h, sigma=sigma,
                                      cfg=cfg, rules=rules, tree=tree, reach=reach)
        n_det = int(mask.sum())
        mask &= cdist <= limit
        record_step("localisation", mask)
        log.info("%s: localisation keeps %d of %d detected points", _FUNC,
                 int(mask.sum()), n_det)
    return spread, cdist, limit


def cloud_state(noise_column: np.ndarray) -> float:
    """The cloud-wide input of the localisation: the noise level σ̂ in h
    (``noise_level``)."""
    sigma = noise_level(noise_column)
    log.info("%s: noise estimate %.3g h, crease neighbourhood k=%d", _FUNC, sigma,
             localisation_k(sigma))
    return sigma


def _select(pts, tree, ks, feats: SharpFeatures, codes: CodeLengths, cfg: _SharpConfig,
            rules: _SharpRules) -> SharpResult:
    """Threshold (7.10)-(7.11), then the crease-angle gate and the localisation."""
    score = codes.score
    T = threshold(score, cfg, rules)
    mask = score > T                                            # (7.11)
    record_step("threshold", mask)
    sigma = cloud_state(feats.noise_column)
    # ridge strength: code length × mean Pd (h) over the larger half of the scales
    spread, cdist, limit = _localise(pts, tree, mask, feats.normals, score * feats.ridge_pd,
                                     h=feats.h, sigma=sigma, cfg=cfg, rules=rules)
    log.info("%s: threshold %.4g selects %d of %d points", _FUNC, T, int(mask.sum()),
             len(pts))
    return SharpResult(mask=mask, score=score, threshold=float(T),
                       quality=mask.astype(np.float64), nnz=codes.nnz,
                       residual=codes.residual, scales=ks, dictionary=codes.dictionary,
                       h=feats.h, beta=cfg.beta, crease_distance=cdist,
                       crease_limit=limit, normal_spread=spread)


def _run(points, normals, cfg: _SharpConfig, stage: ScoreConfig,
         rules: _SharpRules) -> SharpResult:
    pts, tree = prepare_cloud(points, normals, k_min=stage.k_min, k_max=stage.k_max,
                              func=_FUNC)
    ks = scale_sizes(stage.k_min, stage.k_max, stage.n_scales)
    feats = sharp_features(pts, ks, tree=tree, weighted=not rules.uniform_pca)
    log.info("%s: n=%d h=%.4g scales=%s", _FUNC, len(pts), feats.h, ks.tolist())
    # the features are standardised in place: _select needs only the columns
    # kept apart in ``feats``
    codes = score_rows(feats.features, fit_score_model(feats.features, stage), stage,
                       overwrite=True)
    return _select(pts, tree, ks, feats, codes, cfg, rules)


@validate_params(*PARAMS, presets={"thesis": THESIS})
def detect_sharp_features(points, normals=None, *, crease_width: float = 1.0,
                          plane_width: float = 1.15, min_angle: float = 25.0, otsu_scale: float | None = None,
                          n_scales: int = 10, k_min: int = 8, k_max: int = 40,
                          n_atoms: int = 100, coder: str = "omp", alpha: float = 0.01,
                          tol: float = 0.1, score: str = "l1", beta: float | None = None,
                          max_iter: int = 10, max_train: int = 4000, seed: int | None = 0,
                          preset: str | None = None) -> SharpResult:
    """Detect sharp edges and corners by the code length of multi-scale features (§7.3).

    Parameters
    ----------
    points : (n, 3) float
        The cloud (n > k_max).
    normals : (n, 3) float, optional
        Validated, not used: (7.4) uses each scale's PCA normal.
    crease_width : float, default=1.0
        Keep a detected point within this many h of its ridge-line crease estimate.
    plane_width : float, default=1.15
        The same width where the two-plane crease model fits, in h.
    min_angle : float, default=25.0
        Keep a detected point only if its neighbours' normals turn by this angle (0: off).
    otsu_scale : float, optional
        Threshold as a fraction of Otsu's split; auto: 0.6 with the gates on, else 1.
    n_scales : int, default=10
        Number of neighbourhood sizes, geometrically spaced from k_min to k_max.
    k_min, k_max : int, default=8, 40
        Smallest and largest neighbourhood (points, the point itself included).
    n_atoms : int, default=100
        Dictionary size S (thesis §7.4.1).
    coder : {"omp", "lasso_lars"}, default='omp'
        How every point is coded on the learned dictionary.
    alpha : float, default=0.01
        Lasso penalty of coder="lasso_lars", ½‖z − αD‖² + alpha‖α‖₁.
    tol : float, default=0.1
        OMP squared-residual target per feature, for coder="omp".
    score : {"l1", "count"}, default='l1'
        Code length: ‖α‖₁ + residual, or the atom count of (7.8) (thesis).
    beta : float, optional
        Threshold T = β·max f of (7.10); auto: Otsu's method.
    max_iter : int, default=10
        K-SVD iterations.
    max_train : int, default=4000
        Points in the K-SVD training subsample.
    seed : int or None, default=0
        Seeds the K-SVD subsample and initialisation (None: fresh entropy).
    preset : {"thesis"}, optional
        "thesis": the method as printed — the weighted PCA (7.1), Lasso coding
        (λ = 0.01), the atom count (7.8), T = 0.02·max f (7.10), none of the added
        gates; parameters given explicitly override it.

    Returns
    -------
    SharpResult
        ``mask`` (n,) bool: f > T (7.11), ``normal_spread ≥ min_angle`` and
        ``crease_distance ≤ crease_limit``; ``score`` (n,): f.

    Raises
    ------
    PointCloudError, InvalidParameterError
        A bad cloud (empty, NaN/Inf, ≤ k_max points, collinear) or parameter.

    Notes
    -----
    f is the code length of F = (λ0/h², λ0/λ2, σ, Pd/h) per scale (7.1)-(7.4),
    concatenated (§7.3.5), on a K-SVD dictionary; T = β·max f (7.10) or Otsu.
    Deviations, measured in docs/decisions/features.md under the headings
    quoted: uniform weights in (7.1), for one k-NN query ("Uniform weights in
    (7.1)"); a robust one-sided standardisation, so that the code measures the
    distance from the bulk ("Robust one-sided standardisation"); ‖α‖₁, finer
    than the count (7.8) ("Code-length score"); Otsu on the score winsorised
    at 95 %, lest a few corners form the upper class alone ("Sharp threshold:
    winsorised Otsu").

    Added: a crease-angle gate, as Otsu finds a rare class even on a sphere
    ("Crease-angle gate"); a localisation, as the code marks a band as wide as
    the largest neighbourhood: points beyond a width of the crease line (two
    fitted planes, else the ridge line) are dropped, with the same widths on
    every sampling ("Crease localisation", "Two-plane crease model", "One
    width on every sampling"); with both, T is 0.6 of Otsu's split, for recall ("Threshold
    below Otsu's split").

    Examples
    --------
    >>> from pcprep.baselines.datasets import make_shape
    >>> s = make_shape("cube", n=4000, seed=0)
    >>> r = detect_sharp_features(s.points)
    >>> bool(r.mask.shape == (4000,) and 0 < r.mask.sum() < 4000)
    True
    """
    cfg = _SharpConfig(crease_width, plane_width, min_angle, otsu_scale, beta)
    stage = ScoreConfig(n_scales, k_min, k_max, n_atoms, coder, alpha, tol, score,
                        max_iter, max_train, seed)
    return _run(points, normals, cfg, stage,
                THESIS_RULES if preset == "thesis" else DEFAULT_RULES)


def split_params(kw: dict) -> tuple[_SharpConfig, ScoreConfig]:
    """The validated keywords of ``detect_sharp_features`` (``preset`` left out)
    as its own configuration and the shared stage's."""
    kw = dict(kw)
    own = {f.name: kw.pop(f.name) for f in fields(_SharpConfig)}
    return _SharpConfig(**own), ScoreConfig(**kw)


def _detect(points, normals=None, *, rules: _SharpRules = DEFAULT_RULES,
            **params) -> SharpResult:
    """``detect_sharp_features`` with the steps of ``rules`` (the benchmark's
    ablation rows).  ``params`` are its keywords, validated as there."""
    kw = resolve_params(detect_sharp_features.params, params, _FUNC)
    kw.pop("preset")  # the ablation rows name their rules and values themselves
    return _run(points, normals, *split_params(kw), rules)


def sharp_tile(points, lo, hi, core, *, stage: str, centre, h: float | None, n_total: int,
               params: dict, mask=None, normals=None, ridge=None,
               sigma: float = 0.0) -> dict:
    """One tile of a tiled run (``pcprep.meshlab_bridge.tiles``), default rules.

    ``points`` are every point of the cloud in the box ``[lo, hi]`` (its core
    rows ``core``); ``params`` the validated keywords of
    ``detect_sharp_features``.  Stage ``"features"`` returns the core rows'
    features (7.1)-(7.4) unscaled (``sharp_features(raw=True)``: λ0 and Pd
    in the cloud's units, which the tiler divides by the cloud-wide h with
    ``scale_features``), column by column (a (d, m) array: the tiler stores
    features by column, and the transpose is done here, on the workers, not
    on the driver), their PCA normals and their mean 6-NN distances (from
    the same query: the tiler fits h from them, no pass of its own; ``h`` is
    not read); stage ``"gates"`` runs the
    crease-angle gate and the localisation on the core rows of the
    thresholded ``mask`` (``normals``, ``ridge`` given for every row; σ̂ is
    cloud-wide) and returns the final mask of the core rows.  A result is ``{"exact": False}`` when a core row's neighbourhood
    may reach beyond the box, which makes the tiler widen the halo.
    """
    from .neighbors import build_tree, tile_miss

    x = points - centre
    box = (lo - centre, hi - centre)
    cfg, score_cfg = split_params(params)
    rules = DEFAULT_RULES
    if stage == "features":
        if len(x) < min(score_cfg.k_max + 1, n_total):
            return {"exact": False}
        tree = build_tree(x)
        ks = scale_sizes(score_cfg.k_min, score_cfg.k_max, score_cfg.n_scales)
        feats = sharp_features(x, ks, tree=tree, weighted=not rules.uniform_pca, raw=True)
        miss = tile_miss(x[core], feats.reach[core], *box)
        if miss is not None:
            return miss
        rows6 = feats.spacing_rows
        return {"exact": True, "features": np.ascontiguousarray(feats.features[core].T),
                "normals": feats.normals[core],
                "spacing_rows": None if rows6 is None else rows6[core]}
    sel = core & mask
    k = local_k(sigma, cfg, rules)
    if sel.any():
        if len(x) < min(k, n_total):
            return {"exact": False}
        tree = build_tree(x)
        reach = np.zeros(len(x))
        _localise(x, tree, sel, normals, ridge, h=h, sigma=sigma, cfg=cfg, rules=rules,
                  reach=reach)
        # checked after the steps, with the neighbourhoods they read: when each
        # lay inside the box, each step saw what it sees in one piece, and so
        # kept the same rows for the next
        miss = tile_miss(x[core], reach[core], *box)
        if miss is not None:
            return miss
    return {"exact": True, "mask": sel[core]}
