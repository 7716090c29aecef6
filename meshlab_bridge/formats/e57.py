"""
e57.py
------
E57 through pye57.  Reading merges every scan of the file into one cloud in the
file's global frame (each scan's pose applied; whole, or in blocks of rows for
a tiled run, ``blocks``), keeps every per-point field
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


def _open(path: str):
    try:
        import pye57
    except ImportError:
        raise PointCloudError(f"cannot read {path!r}: E57 needs pye57 "
                              "(pip install pye57)") from None
    return pye57.E57(path)


def _fields(e57) -> list[list[str]]:
    """Each scan's point fields that pye57 reads (it skips the others)."""
    from pye57.e57 import SUPPORTED_POINT_FIELDS

    return [[f for f in e57.get_header(i).point_fields if f in SUPPORTED_POINT_FIELDS]
            for i in range(e57.scan_count)]


def point_count(path: str) -> int:
    """The number of points of every scan, from the scans' headers."""
    e57 = _open(path)
    return int(sum(e57.get_header(i).point_count for i in range(e57.scan_count)))


def _raw_blocks(e57, i: int, fields: list[str], size: int):
    """Scan ``i``'s fields in blocks of at most ``size`` rows (libe57's reader
    filling buffers of that size, as pye57 fills one of the scan's size)."""
    from pye57 import libe57

    header = e57.get_header(i)
    bufs, arrays = libe57.VectorSourceDestBuffer(), {}
    for f in fields:
        arrays[f], buf = e57.make_buffer(f, min(size, max(1, header.point_count)))
        bufs.append(buf)
    reader = header.points.reader(bufs)
    try:
        while True:
            m = reader.read()
            if m == 0:
                return
            yield {f: a[:m].copy() for f, a in arrays.items()}
    finally:
        reader.close()


def blocks(path: str, size: int = 1 << 20, *, attributes: bool = True):
    """``(start, Cloud)`` blocks of the file's points in order (scan by scan,
    at most ``size`` rows each), each what ``read`` gives for those rows: the
    scans' poses applied, the fields every scan has kept, ``scan_index``, and
    colours scaled as ``read`` scales them (by a first pass over the colour
    fields, which decides on every point).  ``attributes=False`` reads the
    coordinates alone (and their invalid states)."""
    e57 = _open(path)
    if e57.scan_count == 0:
        raise PointCloudError(f"cannot read {path!r}: the file holds no scan")
    fields = _fields(e57)
    if not attributes:
        keep = set(_XYZ + _SPH + ("cartesianInvalidState", "sphericalInvalidState"))
        fields = [[f for f in fs if f in keep] for fs in fields]
    common = [f for f in fields[0] if all(f in fs for fs in fields)]
    top = None
    if attributes and all(c in common for c in _RGB):
        top = max((float(max(raw[c].max() for c in _RGB)) if len(raw[_RGB[0]]) else 1.0)
                  for i in range(e57.scan_count) for raw in _raw_blocks(e57, i, list(_RGB), size))
    start = 0
    for i in range(e57.scan_count):
        header = e57.get_header(i)
        for raw in _raw_blocks(e57, i, fields[i], size):
            pts = _scan_points(raw, path)
            ok = np.isfinite(pts).all(axis=1)
            pts[ok] = pts[ok] @ header.rotation_matrix.T + header.translation
            attrs = {}
            if attributes:
                attrs = {k: raw[k] for k in common if k not in _XYZ + _SPH}
                attrs["scan_index"] = np.full(len(pts), i, np.int32)
            colors = None
            if top is not None:
                rgb = np.column_stack([attrs[k].astype(np.float64) for k in _RGB])
                colors = np.c_[rgb / (255.0 if top > 1.0 else 1.0), np.ones(len(rgb))]
            yield start, Cloud(pts, None, colors, None, None, attrs, os.path.basename(path),
                               {"format": ".e57", "e57_scans": e57.scan_count})
            start += len(pts)


def read(path: str) -> Cloud:
    parts = [c for _, c in blocks(path, 1 << 22)]
    if not parts:
        raise PointCloudError(f"cannot read {path!r}: its scans hold no points")
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    return first.with_(
        points=np.concatenate([c.points for c in parts]),
        colors=None if first.colors is None else np.concatenate([c.colors for c in parts]),
        attributes={k: np.concatenate([c.attributes[k] for c in parts])
                    for k in first.attributes})


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
