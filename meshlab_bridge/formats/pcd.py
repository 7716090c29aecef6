"""
pcd.py
------
PCL's PCD format, version 0.7, ``DATA ascii`` and ``DATA binary`` (read and
write; ``binary_compressed`` is refused with a message).  Fields ``x y z`` are
the positions, ``normal_x normal_y normal_z`` the normals, ``rgb``/``rgba`` (a
packed float or uint, as PCL writes it) the colours; every other field is kept
in ``attributes`` with its type (fields with COUNT > 1 as (n, k) arrays).
PCL marks invalid points of organised clouds with NaN: those rows are reported
like any non-finite row.
"""

from __future__ import annotations

import io
import itertools
import os

import numpy as np

from pcprep.filters._validation import PointCloudError

from ..cloud import Cloud

_NORMALS = ("normal_x", "normal_y", "normal_z")
_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT",
         "POINTS", "DATA")


def _header(f, path: str) -> dict:
    head: dict = {}
    while True:
        raw = f.readline()
        if not raw:
            raise PointCloudError(f"cannot read {path!r}: the PCD header has no DATA line")
        line = raw.decode("ascii", errors="replace").strip()
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        if key not in _KEYS:
            raise PointCloudError(f"cannot read {path!r}: unknown PCD header line {line!r}")
        head[key] = vals
        if key == "DATA":
            return head


def _dtype(head: dict, path: str) -> np.dtype:
    fields = head.get("FIELDS", [])
    sizes = [int(s) for s in head.get("SIZE", [])]
    types = head.get("TYPE", [])
    counts = [int(c) for c in head.get("COUNT", ["1"] * len(fields))]
    if not (len(fields) == len(sizes) == len(types) == len(counts)):
        raise PointCloudError(f"cannot read {path!r}: FIELDS, SIZE, TYPE and COUNT differ "
                              "in length")
    out = []
    for name, size, kind, count in zip(fields, sizes, types, counts):
        code = {"F": "f", "U": "u", "I": "i"}.get(kind)
        if code is None:
            raise PointCloudError(f"cannot read {path!r}: unknown PCD type {kind!r}")
        out.append((name, f"<{code}{size}") if count == 1 else (name, f"<{code}{size}", (count,)))
    return np.dtype(out)


def binary_rows(path: str):
    """``(rows, head)``: a binary PCD's records memory-mapped, with the row
    count checked against the header, or ``(None, head)`` for another DATA."""
    with open(path, "rb") as f:
        head = _header(f, path)
        offset = f.tell()
    if head["DATA"][0] != "binary":
        return None, head
    dt = _dtype(head, path)
    for c in "xyz":
        if c not in dt.names:
            raise PointCloudError(f"cannot read {path!r}: the PCD file has no {c!r} field")
    n = _count(head)
    room = os.path.getsize(path) - offset
    if room < n * dt.itemsize:
        raise PointCloudError(f"cannot read {path!r}: the header declares {n} points, "
                              f"the file holds {room // dt.itemsize}")
    if room > n * dt.itemsize:
        raise PointCloudError(f"cannot read {path!r}: data continues after the {n} "
                              "points the header declares")
    if n == 0:
        return np.zeros(0, dtype=dt), head
    return np.memmap(path, dtype=dt, mode="r", offset=offset, shape=(n,)), head


def _count(head: dict) -> int:
    return int(head.get("POINTS", [0])[0]) or int(head["WIDTH"][0]) * int(head["HEIGHT"][0])


def data_kind(path: str) -> str:
    """The PCD file's ``DATA`` line: ``ascii``, ``binary`` or another."""
    with open(path, "rb") as f:
        return _header(f, path)["DATA"][0]


def ascii_rows(path: str, size: int):
    """``(start, records)`` blocks of an ASCII PCD's rows (blank lines are
    skipped), parsed by NumPy's ``loadtxt`` as float64 (``ply.PARSE_ROWS``
    rows at a time), then stored in each field's type.  Refused, naming the
    rows: a row that is not numeric or holds another number of values than
    the fields declare, fewer or more rows than the header's point count."""
    from .ply import PARSE_ROWS

    with open(path, "rb") as f:
        head = _header(f, path)
        dt = _dtype(head, path)
        n = _count(head)
        lines = (line for line in f if line.strip())
        start = 0
        while True:
            parts, m = [], 0
            while m < size:
                part = list(itertools.islice(lines, min(PARSE_ROWS, size - m)))
                if not part:
                    break
                if start + m + len(part) > n:
                    more = start + m + len(part) + sum(1 for _ in lines)
                    raise PointCloudError(f"cannot read {path!r}: the header declares {n} "
                                          f"points, the file holds {more} rows")
                parts.append(_parse_rows(part, start + m, dt, path))
                m += len(part)
            if not parts:
                break
            yield start, parts[0] if len(parts) == 1 else np.concatenate(parts)
            start += m
    if start != n:
        raise PointCloudError(f"cannot read {path!r}: the header declares {n} points, "
                              f"the file holds {start} rows")


def _parse_rows(part: list[bytes], start: int, dt: np.dtype, path: str) -> np.ndarray:
    """Rows ``start``… of an ASCII PCD from their lines ``part``."""
    widths = [dt[name].shape[0] if dt[name].shape else 1 for name in dt.names]
    try:
        table = np.loadtxt(io.StringIO(b"".join(part).decode("ascii", "replace")),
                           dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        table = None
    if table is None or table.shape[1] != sum(widths):
        raise PointCloudError(
            f"cannot read {path!r}: in rows {start}–{start + len(part) - 1} (from 0) a row "
            f"is not numeric or does not hold the {sum(widths)} values of the header's "
            "fields")
    data = np.zeros(len(part), dtype=dt)
    col = 0
    for name, width in zip(dt.names, widths):
        vals = table[:, col:col + width]
        data[name] = vals[:, 0] if not dt[name].shape else vals
        col += width
    return data


def blocks(path: str, size: int = 1 << 20):
    """``(start, Cloud)`` blocks of a binary or ASCII PCD's rows (None for
    another DATA)."""
    rows, head = binary_rows(path)
    if rows is not None:
        return ((s, _to_cloud(np.array(rows[s:s + size]), head, path))
                for s in range(0, len(rows), size))
    if head["DATA"][0] == "ascii":
        return ((s, _to_cloud(data, head, path)) for s, data in ascii_rows(path, size))
    return None


def read(path: str) -> Cloud:
    rows, head = binary_rows(path)
    if rows is not None:
        return _to_cloud(np.array(rows), head, path)
    mode = head["DATA"][0]
    if mode != "ascii":
        raise PointCloudError(f"cannot read {path!r}: PCD DATA {mode} is not supported "
                              "(save it as ascii or binary, e.g. pcl_convert_pcd_ascii_binary)")
    from .ply import TEXT_BLOCK

    parts = [data for _, data in ascii_rows(path, TEXT_BLOCK)]
    data = np.concatenate(parts) if parts else np.zeros(0, dtype=_dtype(head, path))
    return _to_cloud(data, head, path)


def _to_cloud(data: np.ndarray, head: dict, path: str) -> Cloud:
    names = list(data.dtype.names)
    for c in "xyz":
        if c not in names:
            raise PointCloudError(f"cannot read {path!r}: the PCD file has no {c!r} field")
    pts = np.column_stack([data[c].astype(np.float64) for c in "xyz"])
    used = {"x", "y", "z"}
    normals = None
    if all(c in names for c in _NORMALS):
        normals = np.column_stack([data[c].astype(np.float64) for c in _NORMALS])
        used.update(_NORMALS)
    colors = None
    key = next((c for c in ("rgb", "rgba") if c in names), None)
    if key is not None:
        packed = np.ascontiguousarray(data[key]).view(np.uint32)
        colors = np.column_stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255,
                                  (packed >> 24) & 255 if key == "rgba" else
                                  np.full(len(packed), 255)]) / 255.0
        used.add(key)
    quality = None
    if "quality" in names:  # pcprep writes MeshLab's quality under this name
        quality = data["quality"].astype(np.float64)
        used.add("quality")
    attrs = {nm: np.ascontiguousarray(data[nm]) for nm in names if nm not in used}
    meta = {"format": ".pcd", "pcd": {"viewpoint": head.get("VIEWPOINT"), "rgb": key,
                                      "width": head.get("WIDTH"), "height": head.get("HEIGHT")}}
    return Cloud(pts, normals, colors, quality, None, attrs, os.path.basename(path), meta)


def write(cloud: Cloud, path: str) -> None:
    data = records(cloud)
    with open(path, "wb") as f:
        f.write(header(data.dtype, len(cloud), cloud.meta.get("pcd", {})))
        f.write(data.tobytes())


def records(cloud: Cloud) -> np.ndarray:
    """``cloud``'s rows as binary PCD records: positions, normals, the packed
    colour under the input's key, quality, then every attribute, each of its
    own type (floats as float32 or float64, little-endian)."""
    cols: list[tuple[str, np.ndarray]] = [(c, cloud.points[:, j]) for j, c in enumerate("xyz")]
    if cloud.normals is not None:
        cols += [(c, cloud.normals[:, j]) for j, c in enumerate(_NORMALS)]
    info = cloud.meta.get("pcd", {})
    if cloud.colors is not None:
        c8 = np.rint(np.clip(cloud.colors, 0, 1) * 255).astype(np.uint32)
        packed = (c8[:, 0] << 16) | (c8[:, 1] << 8) | c8[:, 2]
        key = info.get("rgb") or "rgb"
        if key == "rgba":
            packed |= c8[:, 3] << 24
        cols.append((key, packed.view(np.float32) if key == "rgb" else packed))
    if cloud.quality is not None:
        cols.append(("quality", cloud.quality))
    for name, arr in cloud.attributes.items():
        arr = np.asarray(arr)
        cols.append((name, arr.astype(np.uint8) if arr.dtype == bool else arr))
    dt = []
    for name, arr in cols:
        a = arr if arr.dtype.kind != "f" or name in ("rgb",) else arr.astype(
            np.float32 if arr.dtype == np.float32 else np.float64)
        dt.append((name, a.dtype.newbyteorder("<").str) if a.ndim == 1 else
                  (name, a.dtype.newbyteorder("<").str, (a.shape[1],)))
    data = np.empty(len(cloud), dtype=dt)
    for name, arr in cols:
        data[name] = arr
    return data


def header(dtype: np.dtype, count: int, info: dict) -> bytes:
    """The PCD 0.7 header of ``count`` binary records of ``dtype`` (the input's
    viewpoint kept, and its organisation, WIDTH × HEIGHT, where every row is
    kept in its place); the records follow it."""
    kinds = {"f": "F", "u": "U", "i": "I"}
    fields = dtype.names
    view = " ".join(info.get("viewpoint") or ["0", "0", "0", "1", "0", "0", "0"])
    width, height = count, 1
    grid = [int(v[0]) for v in (info.get("width"), info.get("height")) if v]
    if len(grid) == 2 and grid[0] * grid[1] == count:
        width, height = grid
    return "\n".join([
        "# .PCD v0.7 - Point Cloud Data file format (written by pcprep)",
        "VERSION 0.7",
        "FIELDS " + " ".join(fields),
        "SIZE " + " ".join(str(dtype[f].base.itemsize) for f in fields),
        "TYPE " + " ".join(kinds[dtype[f].base.kind] for f in fields),
        "COUNT " + " ".join(str(dtype[f].shape[0] if dtype[f].shape else 1) for f in fields),
        f"WIDTH {width}", f"HEIGHT {height}", f"VIEWPOINT {view}", f"POINTS {count}",
        "DATA binary", ""]).encode("ascii")
