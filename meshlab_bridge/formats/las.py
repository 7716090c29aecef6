"""
las.py
------
LAS 1.2–1.4 and LAZ through laspy (LAZ with the lazrs backend).

Reading keeps every point dimension (intensity, returns, classification and
flags, scan angle, user data, point source id, GPS time, RGB, NIR, extra bytes)
in ``attributes`` and the header (version, point format, scale/offset, CRS and
the other VLRs) in ``meta["las_header"]``; ``NormalX/Y/Z`` extra dimensions
(PDAL's names; also ``normal_x``/``nx``) become the normals.  Writing reuses
the input's header, so the point format and scale/offset are the input's and
unchanged coordinates round-trip bit-exactly; results that are not LAS
dimensions (``sharp``, ``saliency``, normals, …) become named extra dimensions,
never written over an existing one.  A cloud without a LAS header gets LAS 1.4
point format 6 (7 with colours), offset at its minimum corner and the finest
scale (a power of ten) whose integers still span its extent.
"""

from __future__ import annotations

import copy
import os

import numpy as np

from pcprep.filters._validation import PointCloudError

from ..cloud import Cloud

_NORMALS = (("NormalX", "NormalY", "NormalZ"), ("normal_x", "normal_y", "normal_z"),
            ("nx", "ny", "nz"))
#: the extra dimension names pcprep writes normals under
NORMAL_NAMES = _NORMALS[0]


def laz_backend():
    """lazrs with its threads where it is installed (LAZ chunks decode and
    encode in parallel; the bytes written are the same as one thread's), else
    laspy's own choice."""
    import laspy

    par = laspy.LazBackend.LazrsParallel
    return par if par.is_available() else None


def read(path: str) -> Cloud:
    import laspy

    try:
        las = laspy.read(path, laz_backend=laz_backend())
    except (laspy.errors.LaspyException, RuntimeError) as exc:  # lazrs: RuntimeError
        raise PointCloudError(f"cannot read {path!r}: {exc} (truncated or damaged "
                              "file?)") from exc
    header = las.header
    if header.point_count != len(las.points):
        raise PointCloudError(f"cannot read {path!r}: the header declares "
                              f"{header.point_count} points, the file holds {len(las.points)}")
    return to_cloud(las, path)


def to_cloud(las, path: str) -> Cloud:
    """A ``Cloud`` of a ``laspy.LasData`` (a whole file or one chunk of it)."""
    header = las.header
    pts = np.column_stack([np.asarray(las.x, np.float64), np.asarray(las.y, np.float64),
                           np.asarray(las.z, np.float64)])
    names = [d for d in las.point_format.dimension_names if d not in ("X", "Y", "Z")]
    attrs = {d: np.array(las[d]) for d in names}
    normals = None
    for trio in _NORMALS:
        if all(t in attrs for t in trio):
            normals = np.column_stack([attrs.pop(t).astype(np.float64) for t in trio])
            break
    quality = attrs.pop("quality").astype(np.float64) if "quality" in attrs else None
    colors = None
    if all(c in attrs for c in ("red", "green", "blue")):
        colors = np.ones((len(pts), 4))
        for j, c in enumerate(("red", "green", "blue")):
            colors[:, j] = attrs[c] / 65535.0
    meta = {"format": os.path.splitext(path)[1].lower(), "las_header": copy.deepcopy(header),
            "las_normals": normals is not None}
    crs = _crs_text(header)
    if crs:
        meta["crs"] = crs
    return Cloud(pts, normals, colors, quality, None, attrs, os.path.basename(path), meta)


def _crs_text(header) -> str | None:
    try:
        crs = header.parse_crs()
    except Exception:  # pyproj missing or an unparsable WKT: report what is there
        crs = None
    if crs is not None:
        return str(crs.name if hasattr(crs, "name") else crs)
    for vlr in header.vlrs:
        if vlr.user_id == "LASF_Projection":
            return f"LASF_Projection VLR (record {vlr.record_id})"
    return None


def new_header(lo: np.ndarray, hi: np.ndarray, colors: bool):
    """The LAS 1.4 header of a cloud from another format whose positions span
    ``lo``..``hi``: point format 7 with colours, else 6; the offset at the
    floor of ``lo`` and the finest power-of-ten scale that spans the extent."""
    import laspy

    header = laspy.LasHeader(point_format=7 if colors else 6, version="1.4")
    lo = np.floor(lo)
    extent = float(np.max(hi - lo))
    # the finest power-of-ten scale whose int32 range still spans the extent
    scale = 10.0 ** np.ceil(np.log10(max(extent, 1e-300) / 2.0e9))
    header.offsets = lo
    header.scales = np.full(3, scale)
    return header


def _extra_type(arr: np.ndarray) -> str:
    if arr.dtype == bool:
        return "u1"
    if arr.dtype.kind in "uif" and arr.dtype.itemsize <= 8:
        return arr.dtype.str.lstrip("<>=|")
    raise PointCloudError(f"cannot store attribute of type {arr.dtype} in LAS")


def write(cloud: Cloud, path: str) -> None:
    header, columns = output_header(cloud, path)
    las = record(cloud, header, columns, path)
    las.update_header()
    las.write(path, do_compress=path.lower().endswith(".laz"), laz_backend=laz_backend())


def output_header(cloud: Cloud, path: str, base=None):
    """The header ``cloud`` is written with (``base``, else the input's, else
    ``new_header`` over its points; plus an extra dimension per new
    attribute) and the columns to write, by name."""
    import laspy

    header = base if base is not None else cloud.meta.get("las_header")
    header = copy.deepcopy(header) if header is not None else new_header(
        cloud.points.min(axis=0), cloud.points.max(axis=0), cloud.colors is not None)
    existing = set(header.point_format.dimension_names)
    columns = output_columns(cloud, header)
    new = [laspy.ExtraBytesParams(name=n, type=_extra_type(np.asarray(v)))
           for n, v in columns.items() if n not in existing and np.asarray(v).ndim == 1]
    if new:
        header.add_extra_dims(new)
    return header, columns


def output_columns(cloud: Cloud, header) -> dict:
    """The columns of ``cloud`` (one chunk of a streamed write) under ``header``."""
    existing = set(header.point_format.dimension_names)
    standard = set(header.point_format.standard_dimension_names)
    columns = dict(cloud.attributes)
    if cloud.normals is not None:
        trio = next((t for t in _NORMALS if t[0] in existing), NORMAL_NAMES)
        for j, name in enumerate(trio):
            columns[name] = cloud.normals[:, j]
    if cloud.colors is not None and "red" in standard and "red" not in columns:
        for j, c in enumerate(("red", "green", "blue")):
            columns[c] = np.rint(cloud.colors[:, j] * 65535).astype(np.uint16)
    if cloud.quality is not None and "quality" not in columns:
        columns["quality"] = cloud.quality
    return columns


def record(cloud: Cloud, header, columns: dict, path: str):
    """A ``laspy.LasData`` holding ``cloud`` under ``header``."""
    import laspy

    _check_range(cloud.points, header, path)
    las = laspy.LasData(header=header,
                        points=laspy.ScaleAwarePointRecord.zeros(len(cloud), header=header))
    las.x, las.y, las.z = cloud.points[:, 0], cloud.points[:, 1], cloud.points[:, 2]
    for name, values in columns.items():
        values = np.asarray(values)
        if values.ndim != 1:
            raise PointCloudError(f"cannot write {path!r}: attribute {name!r} is not "
                                  "one value per point")
        las[name] = values.astype(np.uint8) if values.dtype == bool else values
    return las


def _check_range(points: np.ndarray, header, path: str) -> None:
    ints = (points - header.offsets) / header.scales
    if np.abs(ints).max() >= 2**31 - 1:
        raise PointCloudError(
            f"cannot write {path!r}: the coordinates do not fit the LAS header's "
            f"scale {header.scales.tolist()} and offset {header.offsets.tolist()}")
