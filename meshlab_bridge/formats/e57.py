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
per-point results (``sharp``, ``saliency``) or a quality, so only positions,
colours and the standard fields of ``_WRITABLE`` are written, as one scan in
the global frame (``scan_index`` reads back as 0), and the CLI refuses E57 as
the output of a filter whose result needs a named attribute.  ``write`` takes
a cloud in memory, ``write_blocks`` a streamed result's blocks.
"""

from __future__ import annotations

import os
import tempfile

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


def blocks(path: str, size: int = 1 << 20, *, attributes: bool = True,
           colour_pass: bool = True):
    """``(start, Cloud)`` blocks of the file's points in order (scan by scan,
    at most ``size`` rows each), each what ``read`` gives for those rows: the
    scans' poses applied, the fields every scan has kept, ``scan_index``, and
    colours scaled as ``read`` scales them (by a first pass over the colour
    fields, which decides on every point).  ``attributes=False`` reads the
    coordinates alone (and their invalid states); ``colour_pass=False`` skips
    that first pass and leaves the colours unscaled, for a look at which
    fields the blocks hold (``stream.check_fields``)."""
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
        top = 1.0
        if colour_pass:
            top = max((float(max(raw[c].max() for c in _RGB)) if len(raw[_RGB[0]]) else 1.0)
                      for i in range(e57.scan_count)
                      for raw in _raw_blocks(e57, i, list(_RGB), size))
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
    _refuse_float32(*_precision(cloud.points), path)


def _precision(pts: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The largest move of a point rounded to float32, and the bounds."""
    err = float(np.abs(pts.astype(np.float32).astype(np.float64) - pts).max(initial=0.0))
    return err, pts.min(axis=0, initial=np.inf), pts.max(axis=0, initial=-np.inf)


def _refuse_float32(err: float, lo: np.ndarray, hi: np.ndarray, path: str) -> None:
    extent = float(np.linalg.norm(hi - lo)) if np.isfinite(lo).all() else 0.0
    if err > 1e-6 * max(extent, 1e-300):
        raise PointCloudError(
            f"cannot write {path!r}: the E57 writer stores float32 coordinates, which would "
            f"move points by up to {err:.3g} (cloud extent {extent:.3g}); use .ply or .las")


#: the per-point fields pye57 writes besides the coordinates
_WRITABLE = ("intensity", "rowIndex", "columnIndex", "cartesianInvalidState")


def _columns(cloud: Cloud, path: str) -> dict:
    """The scan's fields pye57 writes, as contiguous columns."""
    data = {k: np.ascontiguousarray(cloud.points[:, j]) for j, k in enumerate(_XYZ)}
    if all(k in cloud.attributes for k in _RGB):  # as read from an E57 file
        rgb = [np.asarray(cloud.attributes[k]) for k in _RGB]
    elif cloud.colors is not None:
        rgb = [np.rint(cloud.colors[:, j] * 255) for j in range(3)]
    else:
        rgb = []
    for k, v in zip(_RGB, rgb):
        if len(v) and (v.min() < 0 or v.max() > 255):
            raise PointCloudError(f"cannot write {path!r}: pye57 writes 8-bit colours and "
                                  f"{k} reaches {v.max():.6g}; use .ply or .las")
        data[k] = v.astype(np.uint8)
    for name in _WRITABLE:
        if name in cloud.attributes:
            data[name] = np.ascontiguousarray(cloud.attributes[name])
    return data


def _write_scan(data: dict, path: str) -> None:
    import pye57

    e57 = pye57.E57(path, mode="w")
    try:
        e57.write_scan_raw(data)
    finally:
        e57.close()


def write(cloud: Cloud, path: str) -> None:
    check_precision(cloud, path)
    _write_scan(_columns(cloud, path), path)


def write_blocks(clouds, path: str) -> int:
    """One scan from the blocks of a streamed result (``Cloud`` objects with the
    same fields), never whole in memory: each column is appended to a raw file
    in a temporary folder beside ``path``, then pye57 writes the scan from
    memory maps of them (it copies rows into its buffers chunk by chunk, and
    its minima and maxima read the maps; with a ``cartesianInvalidState``
    column its bounding box copies the valid rows' coordinates, 25 B per
    point).  The format and float32 tests run over the blocks before anything
    is written, and the file appears whole or not at all.  The result is the
    file ``write`` makes of the whole cloud.  Returns the row count."""
    from . import _temporary

    folder = os.path.dirname(os.path.abspath(path))
    with tempfile.TemporaryDirectory(prefix=".pcprep-e57-", dir=folder) as tmp:
        files, dtypes, n = {}, {}, 0
        err, lo, hi = 0.0, np.full(3, np.inf), np.full(3, -np.inf)
        try:
            for cloud in clouds:
                cols = _columns(cloud, path)
                if not files:
                    files = {k: open(os.path.join(tmp, k), "wb") for k in cols}
                    dtypes = {k: v.dtype for k, v in cols.items()}
                if cols.keys() != files.keys():
                    raise PointCloudError(f"cannot write {path!r}: the blocks of the "
                                          "result do not carry the same fields")
                for k, v in cols.items():
                    files[k].write(v.astype(dtypes[k], copy=False).tobytes())
                e, a, b = _precision(cloud.points)
                err, lo, hi = max(err, e), np.minimum(lo, a), np.maximum(hi, b)
                n += len(cloud.points)
        finally:
            for f in files.values():
                f.close()
        _refuse_float32(err, lo, hi, path)
        if n == 0:
            raise PointCloudError(f"cannot write {path!r}: the result holds no points")
        with _temporary(path) as out:
            _write_scan({k: np.memmap(os.path.join(tmp, k), dtypes[k], "r", shape=(n,))
                         for k in files}, out)
    return n
