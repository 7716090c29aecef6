"""
_validation.py
--------------
Every input check of pcprep lives here, so that each filter raises the same
errors with the same wording.

Two error types reach users:

* ``PointCloudError`` -- the data cannot be processed (empty cloud, NaN/Inf,
  too few points for a neighbourhood, all points coincident/collinear/coplanar).
* ``InvalidParameterError`` -- a parameter is unknown, of the wrong type or out
  of its range.  It subclasses both ``ValueError`` and ``TypeError`` like
  scikit-learn's error of the same name.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

import numpy as np


class PointCloudError(ValueError):
    """The point cloud itself cannot be processed."""


class InvalidParameterError(ValueError, TypeError):
    """A parameter is unknown, of the wrong type or out of range."""


def as_points(points, *, func: str, min_points: int = 1, name: str = "points") -> np.ndarray:
    """Return ``points`` as a fresh C-contiguous ``(n, 3)`` float64 array.

    Raises ``PointCloudError`` naming ``func`` when the array is not ``(n, 3)``,
    is empty, holds NaN/Inf, or has fewer than ``min_points`` rows.
    The input is never modified: the result is always a copy.
    """
    try:
        arr = np.array(points, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as exc:
        raise PointCloudError(f"{func}: {name} must be numeric, got {type(points).__name__}") from exc
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise PointCloudError(f"{func}: {name} must have shape (n, 3), got {arr.shape}")
    n = arr.shape[0]
    if n == 0:
        raise PointCloudError(f"{func}: {name} is empty (0 points)")
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise PointCloudError(
            f"{func}: {name} contains NaN or Inf in {int(bad.sum())} row(s) (first: row {first})"
        )
    if n < min_points:
        raise PointCloudError(
            f"{func}: needs at least {min_points} points for its neighbourhoods, got {n}"
        )
    return np.ascontiguousarray(arr)


def as_normals(normals, n: int, *, func: str, name: str = "normals") -> np.ndarray:
    """Return ``normals`` as a fresh ``(n, 3)`` float64 array of unit vectors.

    Zero-length rows are an error (they carry no direction).
    """
    arr = as_points(normals, func=func, name=name)
    if arr.shape[0] != n:
        raise PointCloudError(f"{func}: {name} has {arr.shape[0]} rows but there are {n} points")
    length = np.linalg.norm(arr, axis=1)
    if (length < 1e-12).any():
        rows = np.flatnonzero(length < 1e-12)
        shown = ", ".join(map(str, rows[:5])) + (", …" if len(rows) > 5 else "")
        raise PointCloudError(
            f"{func}: {name} has {len(rows)} zero-length row(s) (rows {shown}); give those "
            "rows a normal, or pass no normals to have them estimated"
        )
    arr /= length[:, None]
    return arr


def _duplicate_pairs(points: np.ndarray):
    """(count, row a, row b) of the exact duplicate rows of ``points``, or None.

    One sort of a 64-bit hash of each row (not a 3-key lexsort: 5-10× faster
    at 10^6 points; a plain sort of the hashes first, which decides the usual
    case of no shared hash faster than the argsort the rest needs); only rows
    whose hash is shared are compared exactly, so a hash collision cannot
    report a false duplicate.  −0.0 counts as 0.0.
    """
    bits = np.ascontiguousarray(points + 0.0).view(np.uint64)
    with np.errstate(over="ignore"):
        key = (bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)
               ^ bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)
               ^ bits[:, 2] * np.uint64(0x165667B19E3779F9))
    ks = np.sort(key)
    if not (ks[1:] == ks[:-1]).any():    # the usual case: no shared hash
        return None
    order = np.argsort(key)
    ks = key[order]
    shared = np.zeros(len(ks), dtype=bool)
    eq = ks[1:] == ks[:-1]
    shared[1:] |= eq
    shared[:-1] |= eq
    cand = order[shared]
    if cand.size == 0:
        return None
    sub = points[cand]
    o = np.lexsort(sub.T[::-1])
    same = (sub[o[1:]] == sub[o[:-1]]).all(axis=1)
    if not same.any():
        return None
    first = int(np.flatnonzero(same)[0])
    a, b = sorted((int(cand[o[first]]), int(cand[o[first + 1]])))
    return int(same.sum()), a, b


def check_spread(points: np.ndarray, *, func: str, need_surface: bool = True) -> None:
    """Reject degenerate clouds: all points coincident, all collinear (when
    ``need_surface``), or holding exact duplicate points.  Coplanar clouds are
    valid surfaces.

    A cloud is collinear when the second largest principal extent is below
    1e-9 of the largest.  Duplicates are rejected because they make the
    spacing h and every k-NN neighbourhood degenerate (zero distances); the
    message says how many and where, and how to remove them.
    """
    check_extent(points[:: max(1, len(points) // 200_000)], points.mean(axis=0),
                 float(np.abs(points).max()), func=func, need_surface=need_surface)
    dup = _duplicate_pairs(points)
    if dup is not None:
        raise duplicate_error(func, *dup)


def check_extent(sample: np.ndarray, mean: np.ndarray, largest: float, *, func: str,
                 need_surface: bool = True) -> None:
    """``check_spread``'s coincident and collinear tests on a row ``sample`` of
    the cloud, its ``mean`` and its ``largest`` absolute coordinate (a tiled
    run passes those of the whole cloud, computed in chunks)."""
    # singular values of the centred cloud are the principal extents
    sv = np.linalg.svd(sample - mean, compute_uv=False)
    if sv[0] <= 1e-12 * max(1.0, largest):
        raise PointCloudError(f"{func}: all points coincide; no surface to process")
    if need_surface and sv[1] <= 1e-9 * sv[0]:
        raise PointCloudError(f"{func}: all points are collinear; no surface to process")


def duplicate_error(func: str, count: int | None, a: int, b: int) -> PointCloudError:
    """The error for duplicate rows ``a`` and ``b`` (``count`` pairs in all,
    None where only some of the cloud was searched)."""
    which = (f"{count} duplicate point(s) (first: rows {a} and {b})" if count is not None
             else f"duplicate points (rows {a} and {b}, and maybe others)")
    return PointCloudError(f"{func}: {which}; remove duplicates first (MeshLab: "
                           "meshing_remove_duplicate_vertices)")


def check_param(
    value,
    *,
    func: str,
    name: str,
    kind: type = float,
    low: float | None = None,
    high: float | None = None,
    closed: str = "both",
    unit: str | None = None,
    allow_none: bool = False,
):
    """Validate one scalar parameter and return it converted to ``kind``.

    ``closed`` is one of ``"both"``, ``"left"``, ``"right"``, ``"neither"`` and
    says which interval ends are allowed.  Values are never clamped.
    """
    if value is None:
        if allow_none:
            return None
        raise InvalidParameterError(f"{func}: {name} must be given, got None")
    if kind is bool:
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        raise InvalidParameterError(f"{func}: {name} must be a bool, got {value!r}")
    if kind is int:
        if isinstance(value, (bool, np.bool_)):
            raise InvalidParameterError(f"{func}: {name} must be an integer, got {value!r}")
        if not isinstance(value, Integral):
            if isinstance(value, Real) and float(value).is_integer():
                value = int(value)
            else:
                raise InvalidParameterError(f"{func}: {name} must be an integer, got {value!r}")
        value = int(value)
    elif kind is float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real):
            raise InvalidParameterError(f"{func}: {name} must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise InvalidParameterError(f"{func}: {name} must be finite, got {value!r}")
    elif kind is str:
        if not isinstance(value, str):
            raise InvalidParameterError(f"{func}: {name} must be a string, got {value!r}")
        return value
    lo_ok = low is None or (value >= low if closed in ("both", "left") else value > low)
    hi_ok = high is None or (value <= high if closed in ("both", "right") else value < high)
    if not (lo_ok and hi_ok):
        lb = "[" if closed in ("both", "left") else "("
        rb = "]" if closed in ("both", "right") else ")"
        lo_s = "-inf" if low is None else f"{low:g}"
        hi_s = "inf" if high is None else f"{high:g}"
        suffix = f" {unit}" if unit else ""
        raise InvalidParameterError(
            f"{func}: {name} must be in {lb}{lo_s}, {hi_s}{rb}{suffix}, got {value!r}"
        )
    return value


def check_choice(value, *, func: str, name: str, choices) -> str:
    """Validate a string option against its allowed set."""
    if value not in choices:
        allowed = ", ".join(repr(c) for c in choices)
        raise InvalidParameterError(f"{func}: {name} must be one of {allowed}, got {value!r}")
    return value


def check_seed(seed, *, func: str) -> int | None:
    """A seed is ``None`` or a non-negative integer."""
    if seed is None:
        return None
    return check_param(seed, func=func, name="seed", kind=int, low=0)
