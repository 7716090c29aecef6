"""
e57.py
------
E57 through pye57.  Reading merges every scan of the file into one cloud in the
file's global frame (each scan's pose applied), keeps every per-point field
pye57 reads (intensity, colours, row/column index, return index, time stamps,
…) in ``attributes`` and adds ``scan_index``.  Points whose
``cartesianInvalidState`` (or ``sphericalInvalidState``) is set carry no valid
coordinates: they are read as NaN rows, which the reader refuses or drops like
any non-finite row.  pye57 writes coordinates as float32, so writing is refused
when that would move a point by more than 1e-6 of the cloud's extent (scans in
projected coordinates); use PLY or LAS there.  E57 has no place for named
per-point results (``sharp``, ``saliency``), so only positions, colours and the
standard fields of ``_WRITABLE`` are written, and the CLI refuses E57 as the
output of a filter whose result needs a named attribute.
"""

from __future__ import annotations

import os

import numpy as np

from pcprep.filters._validation import PointCloudError

from ..cloud import Cloud

_XYZ = ("cartesianX", "cartesianY", "cartesianZ")
_SPH = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
_RGB = ("colorRed", "colorGreen", "colorBlue")


def check_available(path: str) -> None:
    try:
        import pye57  # noqa: F401
    except ImportError:
        raise PointCloudError(f"cannot write {path!r}: E57 needs pye57 "
                              "(pip install pye57)") from None


def _scan_points(raw: dict, path: str) -> np.ndarray:
    if all(k in raw for k in _XYZ):
        pts = np.column_stack([np.asarray(raw[k], np.float64) for k in _XYZ])
        bad = np.asarray(raw.get("cartesianInvalidState", 0)) != 0
    elif all(k in raw for k in _SPH):
        r, az, el = (np.asarray(raw[k], np.float64) for k in _SPH)
        pts = np.column_stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az),
                               r * np.sin(el)])
        bad = np.asarray(raw.get("sphericalInvalidState", 0)) != 0
    else:
        raise PointCloudError(f"cannot read {path!r}: a scan has neither cartesian nor "
                              "spherical coordinates")
    pts[np.broadcast_to(bad, len(pts))] = np.nan
    return pts


def read(path: str) -> Cloud:
    try:
        import pye57
    except ImportError:
        raise PointCloudError(f"cannot read {path!r}: E57 needs pye57 "
                              "(pip install pye57)") from None
    e57 = pye57.E57(path)
    parts, fields = [], []
    for i in range(e57.scan_count):
        raw = e57.read_scan_raw(i, ignore_unsupported_fields=True)
        header = e57.get_header(i)
        pts = _scan_points(raw, path)
        ok = np.isfinite(pts).all(axis=1)
        pts[ok] = pts[ok] @ header.rotation_matrix.T + header.translation
        parts.append(pts)
        fields.append({k: np.asarray(v) for k, v in raw.items()
                       if k not in _XYZ + _SPH} | {"scan_index": np.full(len(pts), i, np.int32)})
    if not parts:
        raise PointCloudError(f"cannot read {path!r}: the file holds no scan")
    names = [k for k in fields[0] if all(k in f for f in fields)]
    attrs = {k: np.concatenate([f[k] for f in fields]) for k in names}
    pts = np.concatenate(parts)
    colors = None
    if all(k in attrs for k in _RGB):
        rgb = np.column_stack([attrs[k].astype(np.float64) for k in _RGB])
        top = float(rgb.max()) if rgb.size else 1.0
        colors = np.c_[rgb / (255.0 if top > 1.0 else 1.0), np.ones(len(rgb))]
    return Cloud(pts, None, colors, None, None, attrs, os.path.basename(path),
                 {"format": ".e57", "e57_scans": e57.scan_count})


def check_precision(cloud: Cloud, path: str) -> None:
    pts = cloud.points
    err = float(np.abs(pts.astype(np.float32).astype(np.float64) - pts).max())
    extent = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    if err > 1e-6 * max(extent, 1e-300):
        raise PointCloudError(
            f"cannot write {path!r}: the E57 writer stores float32 coordinates, which would "
            f"move points by up to {err:.3g} (cloud extent {extent:.3g}); use .ply or .las")


#: the per-point fields pye57 writes besides the coordinates
_WRITABLE = ("intensity", "rowIndex", "columnIndex", "cartesianInvalidState")


def write(cloud: Cloud, path: str) -> None:
    import pye57

    check_precision(cloud, path)
    data = {k: np.ascontiguousarray(cloud.points[:, j]) for j, k in enumerate(_XYZ)}
    if cloud.colors is not None:
        for j, k in enumerate(_RGB):
            data[k] = np.rint(cloud.colors[:, j] * 255).astype(np.uint8)
    for name in _WRITABLE:
        if name in cloud.attributes:
            data[name] = np.ascontiguousarray(cloud.attributes[name])
    e57 = pye57.E57(path, mode="w")
    try:
        e57.write_scan_raw(data)
    finally:
        e57.close()
