"""
metrics.py
----------
Evaluation measures of the thesis: normal error MAD (4.20), symmetric MSE (4.21)
and SNR (4.22) for denoising, the simplification errors Δmax / Δavg (6.12-6.13),
precision / recall / F1 for feature and rim detection, and the ROC AUC for
saliency scores.

All functions take arrays and return plain floats; inputs are validated (shape,
emptiness, NaN/Inf) and never modified.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import rankdata

from ._validation import PointCloudError, as_points, check_param
from .neighbors import build_tree, knn, weighted_pca


def _unit_rows(v, func: str, name: str) -> np.ndarray:
    arr = as_points(v, func=func, name=name)
    length = np.linalg.norm(arr, axis=1)
    if (length < 1e-12).any():
        raise PointCloudError(
            f"{func}: {name} has {int((length < 1e-12).sum())} zero-length row(s)")
    return arr / length[:, None]


def mad_degrees(n_true, n_est) -> float:
    """Mean angular deviation between two sets of unoriented normals, thesis (4.20).

    Parameters
    ----------
    n_true : (n, 3) float
        Ground-truth normals (any non-zero length; normalised here).
    n_est : (n, 3) float
        Estimated normals, same order as ``n_true``.

    Returns
    -------
    mad : float
        mean_i acos(|n̄_i · n̂_i|) in degrees, in [0, 90].

    Notes
    -----
    Point-cloud normals carry no orientation, so a flipped normal counts as exact
    (the absolute value of the dot product); the thesis does not say.
    """
    func = "mad_degrees"
    a = _unit_rows(n_true, func, "n_true")
    b = _unit_rows(n_est, func, "n_est")
    if a.shape != b.shape:
        raise PointCloudError(
            f"{func}: n_true has shape {a.shape} but n_est has {b.shape}")
    dot = np.abs(np.einsum("ij,ij->i", a, b))
    return float(np.degrees(np.arccos(np.clip(dot, 0.0, 1.0))).mean())


def _two_clouds(p_true, p_est, func):
    a = as_points(p_true, func=func, name="p_true")
    b = as_points(p_est, func=func, name="p_est")
    c = a.mean(axis=0)  # common origin: keeps precision for large offsets
    return a - c, b - c


def bbox_diagonal(points) -> float:
    """Length of the axis-aligned bounding-box diagonal of ``points`` (n, 3)."""
    p = as_points(points, func="bbox_diagonal")
    return float(np.linalg.norm(p.max(axis=0) - p.min(axis=0)))


def mse_symmetric(p_true, p_est, *, unit_diagonal: bool = False) -> float:
    """Symmetric mean squared nearest-neighbour distance, thesis (4.21).

    Parameters
    ----------
    p_true : (n1, 3) float
        Ground-truth points.
    p_est : (n2, 3) float
        Processed points; ``n2`` may differ from ``n1``.
    unit_diagonal : bool, default=False
        Divide by the squared bounding-box diagonal of ``p_true``, i.e. report the
        MSE of both clouds scaled so that the ground truth has a unit diagonal
        (so that models of different sizes compare).

    Returns
    -------
    mse : float
        ½ mean_i min_j ‖p_i − q_j‖² + ½ mean_j min_i ‖q_j − p_i‖², in
        squared input units (scale models to unit bounding-box diagonal to
        compare across models).

    Examples
    --------
    >>> round(mse_symmetric([[0, 0, 0], [1, 0, 0]], [[0, 0, 0.1], [1, 0, 0]]), 12)
    0.005
    """
    a, b = _two_clouds(p_true, p_est, "mse_symmetric")
    d_ab, _ = knn(b, 1, query=a)
    d_ba, _ = knn(a, 1, query=b)
    mse = 0.5 * np.mean(d_ab[:, 0] ** 2) + 0.5 * np.mean(d_ba[:, 0] ** 2)
    if unit_diagonal:
        diag = float(np.linalg.norm(a.max(axis=0) - a.min(axis=0)))
        if diag <= 0.0:
            raise PointCloudError("mse_symmetric: p_true has a zero bounding box")
        mse /= diag * diag
    return float(mse)


def snr_db(p_true, p_est) -> float:
    """Signal-to-noise ratio in dB, thesis (4.22).

    Parameters
    ----------
    p_true : (n1, 3) float
    p_est : (n2, 3) float

    Returns
    -------
    snr : float
        10 log10( mean_j ‖q_j − c‖² / MSE ) with q_j the points of ``p_est``, c the
        centroid of ``p_true`` and MSE from :func:`mse_symmetric`; ``inf`` when
        the clouds coincide (MSE = 0).

    Notes
    -----
    The thesis measures ‖q_j‖ about the coordinate origin, which makes the value
    depend on where the model sits; here it is measured about the ground-truth
    centroid, so SNR is invariant to rigid motion and scale.
    """
    a, b = _two_clouds(p_true, p_est, "snr_db")
    mse = mse_symmetric(a, b)
    power = float(np.mean(((b - a.mean(axis=0)) ** 2).sum(axis=1)))
    if mse == 0.0:
        return float("inf")
    return float(10.0 * np.log10(power / mse))


def simplification_error(original, simplified, k: int = 10) -> tuple[float, float]:
    """Geometric error of a simplification, thesis (6.12)-(6.13).

    Parameters
    ----------
    original : (n, 3) float
        The input cloud P.
    simplified : (m, 3) float
        The simplified cloud P' (m >= 3).
    k : int, default=10
        Size of the neighbourhood of P' that defines the local surface S'.

    Returns
    -------
    dmax : float
        Δmax = max over p in P of d(p, S').
    davg : float
        Δavg = mean over p in P of d(p, S').

    Notes
    -----
    The thesis (after Pauly et al. 2002) leaves d(p, S') open; here it is the
    distance from p to the least-squares (PCA) plane of its ``min(k, m)`` nearest
    points of P'.  Both clouds are centred on a common origin first.
    """
    func = "simplification_error"
    k = check_param(k, func=func, name="k", kind=int, low=3, unit="count")
    a = as_points(original, func=func, name="original")
    b = as_points(simplified, func=func, name="simplified", min_points=3)
    c = b.mean(axis=0)
    a, b = a - c, b - c
    _, idx = knn(b, min(k, len(b)), tree=build_tree(b), query=a)
    pca = weighted_pca(b, idx)
    d = np.abs(np.einsum("ij,ij->i", a - pca.centroid, pca.normals))
    return float(d.max()), float(d.mean())


def _as_mask(mask, func, name) -> np.ndarray:
    arr = np.asarray(mask)
    if arr.ndim != 1:
        raise PointCloudError(f"{func}: {name} must be 1-D, got shape {arr.shape}")
    if arr.size == 0:
        raise PointCloudError(f"{func}: {name} is empty")
    if arr.dtype != bool:
        if not np.issubdtype(arr.dtype, np.number) or not np.isin(arr, (0, 1)).all():
            raise PointCloudError(f"{func}: {name} must be boolean (or 0/1)")
        arr = arr.astype(bool)
    return arr


def precision_recall_f1(pred_mask, true_mask) -> tuple[float, float, float]:
    """Precision, recall and F1 of a detected point set.

    Parameters
    ----------
    pred_mask : (n,) bool
        Points reported by the detector.
    true_mask : (n,) bool
        Ground-truth labels.

    Returns
    -------
    precision, recall, f1 : float

    Notes
    -----
    Cases with a zero denominator are defined, not warned about:
    nothing predicted and nothing true gives (1, 1, 1); otherwise a ratio with a
    zero denominator is 0 (nothing predicted: precision 0; no true points: recall
    0), and F1 = 0 when precision + recall = 0.
    """
    func = "precision_recall_f1"
    pred = _as_mask(pred_mask, func, "pred_mask")
    true = _as_mask(true_mask, func, "true_mask")
    if pred.shape != true.shape:
        raise PointCloudError(
            f"{func}: pred_mask has {pred.size} entries but true_mask has {true.size}")
    tp = int(np.count_nonzero(pred & true))
    n_pred = int(np.count_nonzero(pred))
    n_true = int(np.count_nonzero(true))
    if n_pred == 0 and n_true == 0:
        return 1.0, 1.0, 1.0
    p = tp / n_pred if n_pred else 0.0
    r = tp / n_true if n_true else 0.0
    f1 = 2.0 * p * r / (p + r) if p + r > 0 else 0.0
    return float(p), float(r), float(f1)


def roc_auc(scores, truth) -> float:
    """Area under the ROC curve of ``scores`` for the labels ``truth``.

    Parameters
    ----------
    scores : (n,) float
        Higher means "more likely positive".
    truth : (n,) bool
        Ground-truth labels; both classes must be present.

    Returns
    -------
    auc : float
        Probability that a random positive scores above a random negative, ties
        counted ½ (Mann-Whitney U / (n_pos n_neg) with average ranks).

    Raises
    ------
    PointCloudError
        Shape mismatch, empty input, NaN/Inf scores, or a single class (the AUC is
        undefined).
    """
    func = "roc_auc"
    s = np.asarray(scores, dtype=np.float64)
    if s.ndim != 1:
        raise PointCloudError(f"{func}: scores must be 1-D, got shape {s.shape}")
    if s.size == 0:
        raise PointCloudError(f"{func}: scores is empty")
    if not np.isfinite(s).all():
        raise PointCloudError(f"{func}: scores contains NaN or Inf")
    t = _as_mask(truth, func, "truth")
    if t.shape != s.shape:
        raise PointCloudError(
            f"{func}: scores has {s.size} entries but truth has {t.size}")
    n_pos = int(t.sum())
    n_neg = t.size - n_pos
    if n_pos == 0 or n_neg == 0:
        raise PointCloudError(f"{func}: truth holds a single class; the AUC is undefined")
    ranks = rankdata(s)  # average ranks for ties
    u = ranks[t].sum() - n_pos * (n_pos + 1) / 2.0
    return float(u / (n_pos * n_neg))
