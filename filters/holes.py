"""
holes.py
--------
Hole-boundary detection (hole rims, open borders) by the rarity of the codes of
multi-scale border features, thesis §7.3.1 and §7.3.4, eqs (7.5)-(7.7).

1. Features per scale (7.5)-(7.7): |λ2 − 2λ1|/λ2, the density k h²/(π r²) and
   the tangential centroid shift / r, from one sorted k-NN query
   (``hole_features``), oriented so that larger is more border-like.
2. Shared stage (``multiscale.fit_score_model``, ``score_rows``): robust
   standardisation and K-SVD fitted once per cloud,
   every point coded, a code-length score f per point (higher = rarer).
3. Threshold: Otsu, or T = β·max f as (7.10); f > T.  The printed rule
   (7.12)-(7.13), f < β·min f, selects nothing.
4. Not in the thesis: point-wise tests on the geometry of each detection
   (shift, border distance, flatness, strip extent), then tests along the
   border (support, smallest hole, border row and its tracking), the same on
   every sampling; helpers in ``_border.py``.

The measurements behind every rule are in docs/decisions/features.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields

import numpy as np

from ._border import (border_distance, border_gap, border_radius, near_any,
                      strip_extent_at, track_border)
from ._params import Param, preset_param, resolve_params, validate_params
from .multiscale import (SCORE_PARAMS, CodeLengths, Detection, ScoreConfig, fit_score_model,
                         otsu_threshold, prepare_cloud, record_step, scale_moments,
                         scale_sizes, score_rows)
from .neighbors import _SCAN, average_spacing, build_tree

log = logging.getLogger("pcprep")

_FUNC = "detect_hole_boundaries"
#: radius (h) within which a detection counts its detected neighbours, and the
#: largest gap (h) within one border of the smallest-hole test
_SUPPORT_RADIUS = 3.0
#: largest step (h) between two samples of one border row (border tracking)
_TRACK_LINK = 1.5
#: a border-row candidate joins the tracking only within this distance (h) of a
#: detection, and a detection is kept within _ROW_BAND (h) of the tracked row
_ROW_REACH = 1.0
_ROW_BAND = 1.2
#: default smallest hole radius (h) per unit of ln(n)
_CHANCE_GAP_PER_LOG_N = 0.3


@dataclass(frozen=True)
class _HoleRules:
    """Which of the steps not in the thesis run (all do by default).

    Off switches for the benchmark's ablation rows and a future thesis preset;
    the public function always uses ``DEFAULT_RULES``.  Without the strip test
    the threshold is a two-level Otsu.  See docs/decisions/features.md, section
    "Parameters that left the public API".
    """

    rim_distance: bool = True    # border distance from the half-disc law (rim_width)
    strip_extent: bool = True    # outermost samples toward the border (extent_width)
    flatness: bool = True        # flatness gate (max_variation)
    support: bool = True         # detected neighbours along the border (min_support)
    smallest_hole: bool = True   # border radius (min_radius)
    border_row: bool = True      # border row, its tracking and the band along it
    second_split: bool = True    # without the strip test, Otsu again inside the upper class
    tangential_shift: bool = True  # shift in the tangent plane / r, not ‖p̄ − p_i‖/h (7.7)


DEFAULT_RULES = _HoleRules()
#: the thesis' method: the printed descriptors (7.5)-(7.7) and one threshold
THESIS_RULES = _HoleRules(rim_distance=False, strip_extent=False, flatness=False,
                          support=False, smallest_hole=False, border_row=False,
                          second_split=False, tangential_shift=False)

#: the method as printed (§7.3.4), with (7.12)-(7.13) read as the mirror of
#: (7.10): Lasso coding (λ = 0.01), S = 100 atoms, the atom count (7.8), and the
#: automatic threshold (Otsu) the thesis names for β
THESIS = {"coder": "lasso_lars", "alpha": 0.005, "score": "count", "beta": None,
          "n_atoms": 100, "n_scales": 10, "min_shift": 0.0}

PARAMS = (
    Param("min_shift", float, low=0.0, high=1.0, unit="fraction"),
    Param("rim_width", float, low=0.0, high=100.0, closed="right", unit="h"),
    Param("extent_width", float, low=0.0, high=100.0, closed="right", unit="h"),
    Param("max_variation", float, low=0.0, high=1.0 / 3.0, unit="fraction"),
    Param("min_support", int, low=0, high=1000, unit="count"),
    Param("min_radius", float, low=0.0, high=1000.0, unit="h", optional=True),
    Param("row_angle", float, low=0.0, high=360.0, unit="deg"),
    *SCORE_PARAMS,
    preset_param({"thesis": THESIS}),
)


@dataclass(frozen=True)
class _HoleConfig:
    """The hole-specific parameters of ``detect_hole_boundaries``, validated."""

    min_shift: float
    rim_width: float
    extent_width: float
    max_variation: float
    min_support: int
    min_radius: float | None
    row_angle: float
    beta: float | None


@dataclass(frozen=True)
class HoleFeatures:
    """Multi-scale border features of a cloud (``hole_features``).

    Attributes
    ----------
    features : (n, 3·s) float
        Scale-major columns (|λ2 − 2λ1|/λ2, k h²/(π r²), shift / r) of scale 0,
        then scale 1, ...  (not yet oriented).
    h : float
        Average spacing.
    extent : (n,) float
        ``strip_extent`` at the largest scale, in h.
    variation : (n,) float
        Surface variation λ0/Σλ of the smallest scale.
    near : (n, k_min) int32
        Each point's k_min nearest neighbours (column 0: the point itself).
    shift_mean : (n,) float
        Mean shift / r over the scales, the input of the ``min_shift`` test,
        kept apart from ``features``, which the detector orients and
        standardises in place to stay within one copy of the feature matrix.
    reach : (n,) float
        Distance to the largest scale's last neighbour: every feature of the
        row reads only points within it (a tiled run checks its halo with it).
    """

    features: np.ndarray
    h: float
    extent: np.ndarray
    variation: np.ndarray
    near: np.ndarray
    shift_mean: np.ndarray
    reach: np.ndarray


@dataclass(frozen=True)
class HoleResult(Detection):
    """Result of ``detect_hole_boundaries``: the fields of
    ``multiscale.Detection`` and the diagnostics of its localisation.

    Attributes
    ----------
    border_distance : (n,) float or None
        Border distance from the half-disc law (``border_distance``), in h
        (None when that step is switched off).
    border_extent : (n,) float
        Each point's ``strip_extent`` in h.
    """

    border_distance: np.ndarray | None = None
    border_extent: np.ndarray | None = None


def hole_features(points: np.ndarray, ks: np.ndarray, *, h: float | None = None,
                  tree=None, tangential: bool = True) -> HoleFeatures:
    """Features (7.5)-(7.7) of every point at every scale, and the per-point
    quantities of the localisation tests.

    Per scale: epv = |λ2 − 2λ1|/λ2 (7.5), the density k h²/(π r²) (7.6, with
    π for the printed p_i and r the distance to the k-th neighbour) and the
    centroid shift ‖p̄ − p_i‖ (7.7) in the tangent plane, divided by r.

    Parameters
    ----------
    points : (n, 3) float
        Centred cloud.
    ks : (s,) int
        Increasing neighbourhood sizes (``multiscale.scale_sizes``).
    h : float, optional
        Average spacing (mean distance to the 6 nearest neighbours by default).
    tree : cKDTree, optional
    tangential : bool
        The shift column: its tangent-plane part divided by r (the default), or
        the printed ‖p̄ − p_i‖ (7.7) divided by h (the thesis preset).

    Returns
    -------
    HoleFeatures

    Examples
    --------
    >>> from pcprep.baselines.datasets import make_shape
    >>> s = make_shape("disc", n=2000, seed=0)
    >>> hole_features(s.points, scale_sizes(16, 80, 10)).features.shape
    (2000, 30)
    """
    n = len(points)
    ks = np.asarray(ks, dtype=np.int64)
    h = average_spacing(points, tree=tree) if h is None else h
    kf = ks.astype(np.float64)
    out = np.empty((n, 3 * len(ks)))  # noqa: NPY-empty -- every row written below
    extent = np.empty(n)  # noqa: NPY-empty -- every entry written below
    variation = np.empty(n)  # noqa: NPY-empty -- every entry written below
    near = np.empty((n, int(ks[0])), dtype=np.int32)  # noqa: NPY-empty -- all rows set
    reach = np.empty(n)  # noqa: NPY-empty -- every entry written below
    for m in scale_moments(points, ks, tree=tree):
        at = m.rows
        reach[at] = m.dist[:, -1]
        near[at] = m.idx[:, :ks[0]]
        lam, mean = m.eigenvalues, m.mean
        l2s = np.maximum(lam[..., 2], 1e-300)
        shift_n = np.einsum("csd,csd->cs", mean, m.normal)
        r = np.maximum(m.dist[:, ks - 1], 1e-300)               # radius of the scale
        shift_t = np.sqrt(np.maximum(np.einsum("csd,csd->cs", mean, mean)
                                     - shift_n ** 2, 0.0))
        shift = (shift_t / r if tangential
                 else np.sqrt(np.einsum("csd,csd->cs", mean, mean)) / h)
        f = np.stack([np.abs(lam[..., 2] - 2.0 * lam[..., 1]) / l2s,
                      kf[None, :] / (np.pi * r * r), shift], axis=-1)
        out[at] = f.reshape(len(at), -1)
        extent[at] = strip_extent_at(points, m.idx, at, mean[:, -1], m.normal[:, -1], h=h)
        variation[at] = lam[:, 0, 0] / np.maximum(lam[:, 0].sum(-1), 1e-300)
    out[:, 1::3] *= h * h                                       # k h² / (π r²)
    return HoleFeatures(features=out, h=float(h), extent=extent, variation=variation,
                        near=near, shift_mean=out[:, 2::3].mean(axis=1), reach=reach)


def _orient(F: np.ndarray) -> np.ndarray:
    """Turn the columns, in place, so that larger is more border-like (§7.3.1:
    epv and density drop at a border, the shift grows); returns ``F``."""
    F *= np.tile([-1.0, -1.0, 1.0], F.shape[1] // 3)
    return F


def _rim_distance(F: np.ndarray, ks: np.ndarray) -> np.ndarray:
    """Border distance in h from the half-disc law, every scale's radius taken
    from its density column."""
    r_h = np.sqrt(ks[None, :] / (np.pi * np.maximum(F[:, 1::3], 1e-300)))
    return border_distance(F[:, 2::3], r_h)


def _threshold(score: np.ndarray, cfg: _HoleConfig, rules: _HoleRules) -> float:
    """T = β·max f, or Otsu's split (a second split inside the upper class when
    the strip test is off; docs/decisions/features.md, "Hole threshold")."""
    if cfg.beta is not None:
        return float(cfg.beta * score.max())
    T = otsu_threshold(score)
    if rules.second_split and not rules.strip_extent and (score > T).sum() > 1:
        T = otsu_threshold(score[score > T])
    return T


def _keep(mask: np.ndarray, test, what: str) -> None:
    """``mask &= test(rows)`` over row chunks, in place and logged; ``test``
    reads its column per chunk, so a memory-mapped mask and column of a tiled
    run make no temporary of the cloud's length."""
    n_det = n_kept = 0
    for s0 in range(0, len(mask), _SCAN):
        rows = slice(s0, s0 + _SCAN)
        part = mask[rows]  # a view: the test is applied in place
        n_det += int(part.sum())
        part &= test(rows)
        n_kept += int(part.sum())
    record_step(what, mask)
    log.info("%s: %s keeps %d of %d detected points", _FUNC, what, n_kept, n_det)


def _pointwise(mask, feats: HoleFeatures, bdist, cfg: _HoleConfig, rules: _HoleRules):
    """The tests on each detection's own neighbourhood, in place."""
    if cfg.min_shift > 0:
        _keep(mask, lambda r: feats.shift_mean[r] >= cfg.min_shift, "shift gate")
    if bdist is not None:
        _keep(mask, lambda r: bdist[r] <= cfg.rim_width, "border distance")
    if rules.flatness:
        _keep(mask, lambda r: feats.variation[r] <= cfg.max_variation, "flatness gate")
    if rules.strip_extent:
        _keep(mask, lambda r: feats.extent[r] <= cfg.extent_width, "strip extent")


def _support(take, mask, h: float, min_support: int) -> None:
    """Drop detections with fewer than ``min_support`` others within 3h, in place
    (``take(rows)`` gives the rows' centred positions)."""
    det = np.flatnonzero(mask)
    p = take(det)
    support = build_tree(p).query_ball_point(
        p, _SUPPORT_RADIUS * h, return_length=True) - 1
    mask[det[support < min_support]] = False
    record_step("border support", mask)
    log.info("%s: border support keeps %d of %d detected points", _FUNC,
             int(mask.sum()), len(det))


def _smallest_hole(take, mask, n: int, h: float, min_radius: float | None) -> None:
    """Drop the borders of radius below ``min_radius`` h (default 0.3·ln n), in place."""
    r_min = (min_radius if min_radius is not None
             else _CHANCE_GAP_PER_LOG_N * np.log(n))
    det = np.flatnonzero(mask)
    radius = border_radius(take(det), _SUPPORT_RADIUS * h) / h
    mask[det[radius < r_min]] = False
    record_step("smallest hole", mask)
    log.info("%s: borders of radius >= %.3g h keep %d of %d detected points", _FUNC,
             r_min, int(mask.sum()), len(det))


def _border_row(take, mask, row_near, h: float, row_angle: float) -> np.ndarray:
    """The border row and the band along it, written over ``mask`` (returned).

    Row samples are those with an empty angle > ``row_angle``.  The row
    samples within ``_ROW_REACH`` h of a detection (``row_near``) are chained
    within ``_TRACK_LINK`` h, and the chains that hold a detection are kept
    (the tracked row).  The result is the tracked row and the detections
    within ``_ROW_BAND`` h of it.
    """
    det = np.flatnonzero(mask)
    rows = row_near(det, _ROW_REACH * h, np.radians(row_angle))
    seeds = mask[rows]
    tracked = rows[track_border(take(rows), seeds, np.ones(len(rows), dtype=bool),
                                _TRACK_LINK * h)]
    rest = det[~np.isin(det, tracked, assume_unique=True)]
    band = rest[near_any(take(tracked), take(rest), _ROW_BAND * h)]
    mask[:] = False
    mask[tracked] = True
    mask[band] = True
    record_step("border row and band", mask)
    log.info("%s: border row (angular gap > %.3g deg): %d samples tracked from %d "
             "detections; %d of the %d detected points kept within %.3g h of it", _FUNC,
             row_angle, len(tracked), int(seeds.sum()), len(det) - len(rest) + len(band),
             len(det), _ROW_BAND)
    return mask


def _chains(take, mask, feats: HoleFeatures, row_near, cfg: _HoleConfig,
            rules: _HoleRules) -> np.ndarray:
    """The tests along the border: support, the smallest hole, the border row
    and the band along it, the same on every sampling.  They read the
    detected points and the row samples near them only, through
    ``take(rows)`` and ``row_near(rows, radius, angle)`` (the rows within
    ``radius`` of ``rows`` whose empty angle exceeds ``angle``, sorted).
    Border chains are cloud-wide, so a tiled run runs this on the gathered
    detections."""
    if rules.support and cfg.min_support > 0 and mask.any():
        _support(take, mask, feats.h, cfg.min_support)
    if rules.smallest_hole and mask.any():
        _smallest_hole(take, mask, len(mask), feats.h, cfg.min_radius)
    if rules.border_row and mask.any():
        mask = _border_row(take, mask, row_near, feats.h, cfg.row_angle)
    return mask


def select_borders(take, score: np.ndarray, feats: HoleFeatures, bdist, row_near,
                   cfg: _HoleConfig, rules: _HoleRules = DEFAULT_RULES, out=None):
    """Threshold the scores, then the point-wise tests and the tests along the
    border (``take`` and ``row_near`` as in ``_chains``).  Returns the mask,
    written into ``out`` when given (a tiled run's memory map), and the
    threshold.  Every step works in place over row chunks of the mask and of
    the column it reads."""
    T = _threshold(score, cfg, rules)
    mask = np.empty(len(score), dtype=bool) if out is None else out
    for s0 in range(0, len(score), _SCAN):
        mask[s0:s0 + _SCAN] = score[s0:s0 + _SCAN] > T
    record_step("threshold", mask)
    _pointwise(mask, feats, bdist, cfg, rules)
    return _chains(take, mask, feats, row_near, cfg, rules), T


def rows_by_gap(take, gap):
    """``row_near`` of a cloud whose every row's empty angle ``gap`` is known
    (a tiled run gathers it from the tiles).  The rows are read ``_SCAN`` at
    a time against one tree over the detections, so the row samples of the
    whole cloud and their positions are never held at once."""
    def row_near(det, radius, angle):
        near = [np.zeros(0, np.int64)]
        if len(det):
            tree = build_tree(take(det))
            for s0 in range(0, len(gap), _SCAN):
                row = s0 + np.flatnonzero(np.asarray(gap[s0:s0 + _SCAN]) > angle)
                near.append(row[near_any(tree, take(row), radius)])
        return np.concatenate(near)
    return row_near


def _row_near_in_memory(pts, tree, near):
    """``row_near`` of a whole cloud: the rows within reach come from the tree,
    and only their empty angles are computed."""
    def row_near(det, radius, angle):
        hits = tree.query_ball_point(pts[det], np.nextafter(radius, np.inf))
        rows = np.unique(np.concatenate([np.asarray(hit, dtype=np.int64) for hit in hits]
                                        + [np.zeros(0, np.int64)]))
        rows = rows[border_gap(pts, near[rows]) > angle]
        return rows[near_any(pts[det], pts[rows], radius)]
    return row_near


def _select(pts, tree, ks, feats: HoleFeatures, bdist, codes: CodeLengths,
            cfg: _HoleConfig, rules: _HoleRules) -> HoleResult:
    """``select_borders`` over the whole cloud, and the result."""
    score = codes.score
    mask, T = select_borders(lambda rows: pts[rows], score, feats, bdist,
                             _row_near_in_memory(pts, tree, feats.near), cfg, rules)
    log.info("%s: threshold %.4g selects %d of %d points", _FUNC, T, int(mask.sum()),
             len(pts))
    return HoleResult(mask=mask, score=score, threshold=float(T),
                      quality=mask.astype(np.float64), nnz=codes.nnz,
                      residual=codes.residual, scales=ks, dictionary=codes.dictionary,
                      h=feats.h, beta=cfg.beta, border_distance=bdist,
                      border_extent=feats.extent)


def _run(points, normals, cfg: _HoleConfig, stage: ScoreConfig,
         rules: _HoleRules) -> HoleResult:
    pts, tree = prepare_cloud(points, normals, k_min=stage.k_min, k_max=stage.k_max,
                              func=_FUNC)
    ks = scale_sizes(stage.k_min, stage.k_max, stage.n_scales)
    feats = hole_features(pts, ks, tree=tree, tangential=rules.tangential_shift)
    log.info("%s: n=%d h=%.4g scales=%s", _FUNC, len(pts), feats.h, ks.tolist())
    bdist = _rim_distance(feats.features, ks) if rules.rim_distance else None
    # oriented and standardised in place: _select needs only the per-point
    # quantities kept apart in ``feats`` and ``bdist``
    F = _orient(feats.features)
    codes = score_rows(F, fit_score_model(F, stage), stage, overwrite=True)
    return _select(pts, tree, ks, feats, bdist, codes, cfg, rules)


@validate_params(*PARAMS, presets={"thesis": THESIS})
def detect_hole_boundaries(points, normals=None, *, min_shift: float = 0.2,
                           rim_width: float = 2.0, extent_width: float = 1.4,
                           max_variation: float = 0.13, min_support: int = 2,
                           min_radius: float | None = None, row_angle: float = 90.0,
                           n_scales: int = 10, k_min: int = 16, k_max: int = 80,
                           n_atoms: int = 100, coder: str = "omp", alpha: float = 0.01,
                           tol: float = 0.3, score: str = "l1", beta: float | None = None,
                           max_iter: int = 10, max_train: int = 4000, seed: int | None = 0,
                           preset: str | None = None) -> HoleResult:
    """Detect hole rims and open borders by the rarity of multi-scale codes (§7.3.4).

    Parameters
    ----------
    points : (n, 3) float
        The cloud (n > k_max).
    normals : (n, 3) float, optional
        Validated, not used: each scale's PCA normal is used.
    min_shift : float, default=0.2
        Smallest tangential centroid shift / radius, averaged over the scales (0: off).
    rim_width : float, default=2.0
        Keep a detection within this many h of the border implied by its shifts.
    extent_width : float, default=1.4
        Keep a detection within this many h of the outermost samples toward the border.
    max_variation : float, default=0.13
        Largest surface variation λ0/Σλ of the smallest neighbourhood.
    min_support : int, default=2
        Fewest other detections within 3h of a kept one.
    min_radius : float, optional
        Smallest hole radius in h; auto: 0.3·ln(n).
    row_angle : float, default=90.0
        Empty angle (degrees) of a sample of the border row.
    n_scales : int, default=10
        Number of neighbourhood sizes, geometrically spaced from k_min to k_max.
    k_min, k_max : int, default=16, 80
        Smallest and largest neighbourhood (points, the point itself included).
    n_atoms : int, default=100
        Dictionary size S (thesis §7.4.1).
    coder : {"omp", "lasso_lars"}, default='omp'
        How every point is coded on the learned dictionary.
    alpha : float, default=0.01
        Lasso penalty of coder="lasso_lars", ½‖z − αD‖² + alpha‖α‖₁.
    tol : float, default=0.3
        OMP squared-residual target per feature, for coder="omp".
    score : {"l1", "count"}, default='l1'
        Rarity: ‖α‖₁ + residual, or the atom count of (7.8) (thesis).
    beta : float, optional
        Threshold T = β·max f as (7.10); auto: Otsu's method.
    max_iter : int, default=10
        K-SVD iterations.
    max_train : int, default=4000
        Points in the K-SVD training subsample.
    seed : int or None, default=0
        Seeds the K-SVD subsample and initialisation (None: fresh entropy).
    preset : {"thesis"}, optional
        "thesis": the method as printed — the descriptors (7.5)-(7.7) with the
        untouched centroid shift ‖p̄ − p_i‖, Lasso coding (λ = 0.01), the atom
        count (7.8), f above Otsu's split, none of the added tests; parameters
        given explicitly override it.

    Returns
    -------
    HoleResult
        ``mask`` (n,) bool: f > T and every test below; ``score`` (n,): f.

    Raises
    ------
    PointCloudError, InvalidParameterError
        As ``detect_sharp_features``.

    Notes
    -----
    Per scale (7.5)-(7.7): epv, the density k h²/(π r²) (printed k/(p_i·r²))
    and the tangential centroid shift over r, which a crease does not produce
    (docs/decisions/features.md, "Hole features (7.5)-(7.7)", as every heading
    quoted).  (7.12)-(7.13), f < β·min f, selects nothing for β ≤ 1: as for
    edges, borders are the rare codes ("Rarity rule instead of (7.12)-(7.13)").

    Added, in the order applied: the shift gate, a rim's neighbourhood being
    one-sided ("Shift gate"); border distance and strip extent, against a band
    as wide as the largest neighbourhood ("Border distance", "Strip extent");
    the flatness gate against thin parts ("Flatness gate"); border support, a
    border being a curve ("Border support"); the smallest hole, as chance gaps
    of a random sampling grow with n ("Smallest hole"); the border row,
    followed along itself near the detections, and the detections within
    1.2h of it ("Border row and band", "Border tracking").  No step depends
    on how the cloud was sampled ("One rule on every sampling").

    Examples
    --------
    >>> from pcprep.baselines.datasets import make_shape
    >>> s = make_shape("disc", n=4000, seed=0)
    >>> r = detect_hole_boundaries(s.points)
    >>> bool(r.mask[s.rim].mean() > 0.5 and not r.mask[~s.rim].mean() > 0.05)
    True
    """
    cfg = _HoleConfig(min_shift, rim_width, extent_width, max_variation, min_support,
                      min_radius, row_angle, beta)
    stage = ScoreConfig(n_scales, k_min, k_max, n_atoms, coder, alpha, tol, score,
                        max_iter, max_train, seed)
    return _run(points, normals, cfg, stage,
                THESIS_RULES if preset == "thesis" else DEFAULT_RULES)


def _detect(points, normals=None, *, rules: _HoleRules = DEFAULT_RULES,
            **params) -> HoleResult:
    """``detect_hole_boundaries`` with the steps of ``rules`` (the benchmark's
    ablation rows).  ``params`` are its keywords, validated as there."""
    kw = resolve_params(detect_hole_boundaries.params, params, _FUNC)
    kw.pop("preset")  # the ablation rows name their rules and values themselves
    return _run(points, normals, *split_params(kw), rules)


def split_params(kw: dict) -> tuple[_HoleConfig, ScoreConfig]:
    """The validated keywords of ``detect_hole_boundaries`` (``preset`` left
    out) as its own configuration and the shared stage's."""
    kw = dict(kw)
    own = {f.name: kw.pop(f.name) for f in fields(_HoleConfig)}
    return _HoleConfig(**own), ScoreConfig(**kw)


def hole_tile(points, lo, hi, core, *, centre, h: float, n_total: int,
              params: dict) -> dict:
    """One tile of a tiled run (``pcprep.meshlab_bridge.tiles``), default rules:
    the point-wise part of the detector for the core rows of ``points`` (every
    point of the cloud in the box ``[lo, hi]``), with the cloud-wide h.

    Returns the core rows' oriented features (7.5)-(7.7) column by column (a
    (d, m) array, transposed here on the workers for the tiler's column
    store), the inputs of the
    point-wise tests (shift, border distance, flatness, extent) and the empty
    angle of the border-row test; or
    ``{"exact": False}`` when a core row's neighbourhood may reach beyond
    the box.  Scores, threshold and the chain tests are cloud-wide and run
    on the gathered rows.
    """
    from .neighbors import tile_miss

    x = points - centre
    _, score_cfg = split_params(params)
    rules = DEFAULT_RULES
    if len(x) < min(score_cfg.k_max + 1, n_total):
        return {"exact": False}
    tree = build_tree(x)
    ks = scale_sizes(score_cfg.k_min, score_cfg.k_max, score_cfg.n_scales)
    feats = hole_features(x, ks, h=h, tree=tree, tangential=rules.tangential_shift)
    miss = tile_miss(x[core], feats.reach[core], lo - centre, hi - centre)
    if miss is not None:
        return miss
    F = feats.features[core]
    bdist = _rim_distance(F, ks) if rules.rim_distance else None
    return {"exact": True, "features": np.ascontiguousarray(_orient(F).T), "extent": feats.extent[core],
            "variation": feats.variation[core], "shift_mean": feats.shift_mean[core],
            "border_distance": bdist, "gap": border_gap(x, feats.near[core])}
