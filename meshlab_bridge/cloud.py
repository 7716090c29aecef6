"""
cloud.py
--------
``Cloud``: everything pcprep reads from a file or a MeshLab layer and writes
back.  Positions, normals, colours and quality have their own fields because
MeshLab gives them meaning; every other per-point field a file brings
(intensity, classification, GPS time, confidence, extra bytes, …) is kept in
``attributes`` under its own name and dtype, in the file's order, and
``meta`` keeps what the format's header says (LAS header with its point format,
scale/offset and VLRs; PLY comments and property types), so a write in the
same format reproduces the input.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True)
class Cloud:
    """Arrays of one point cloud.

    Attributes
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64 or None
    colors : (n, 4) float64 in [0, 1] or None
        RGBA, as MeshLab holds colours.
    quality : (n,) float64 or None
        MeshLab's per-vertex quality (scalar).
    faces : (f, 3) int64 or None
    attributes : dict of str -> (n,) or (n, k) array
        Every other per-point field, any dtype, in file order.
    label : str
    meta : dict
        Format details: ``"format"`` (the extension read), ``"las_header"``,
        ``"ply"`` (comments, text/binary, property types), ``"dropped_rows"``
        (rows removed for non-finite coordinates), ``"crs"`` (text, when known),
        ``"face_properties"`` (what the faces carry that pcprep does not keep).
    face_attributes : dict of str -> (f,) or (f, k) array
        Per-triangle values, row t for ``faces[t]``, in file order: a PLY face
        element's properties besides its vertex list (colours, quality, flags,
        texture coordinates as the (f, 6) corners of each triangle, …), a
        polygon's values on each triangle of its fan.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    quality: np.ndarray | None = None
    faces: np.ndarray | None = None
    attributes: dict = field(default_factory=dict)
    label: str = ""
    meta: dict = field(default_factory=dict)
    face_attributes: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, idx: np.ndarray, *, keep_faces: bool = True) -> "Cloud":
        """The cloud restricted to rows ``idx`` (in that order); faces whose
        three vertices are all kept are renumbered, with their face
        attributes, the others dropped."""
        idx = np.asarray(idx, dtype=np.int64)

        def take(a):
            return None if a is None else a[idx]

        faces, face_attrs = None, {}
        if keep_faces and self.faces is not None and len(self.faces):
            new = np.full(len(self.points), -1, dtype=np.int64)
            new[idx] = np.arange(len(idx))
            f = new[self.faces]
            whole = (f >= 0).all(axis=1)
            if whole.any():
                faces = f[whole]
                face_attrs = {k: v[whole] for k, v in self.face_attributes.items()}
        meta = self.meta
        info = meta.get("ply", {})
        if info.get("other_elements"):  # which input rows remain: the writer renumbers edges
            rows = info.get("kept_rows")
            meta = {**meta, "ply": {**info, "kept_rows": idx if rows is None else rows[idx]}}
        if "obj" in meta:  # an OBJ's polylines and point groups, renumbered and cut
            from .formats.text import chains_after

            meta = {**meta, "obj": chains_after(meta["obj"], idx, len(self.points))}
        return replace(self, points=self.points[idx], normals=take(self.normals),
                       colors=take(self.colors), quality=take(self.quality), faces=faces,
                       attributes={k: v[idx] for k, v in self.attributes.items()},
                       face_attributes=face_attrs, meta=meta)

    def __post_init__(self):
        count = 0 if self.faces is None else len(self.faces)
        bad = [k for k, v in self.face_attributes.items() if len(v) != count]
        if bad:
            raise ValueError(f"face attributes {', '.join(bad)} do not hold one row per "
                             f"face ({count} faces)")

    def with_(self, **changes) -> "Cloud":
        """A copy with ``changes``; new faces (or none) come without the old
        faces' attributes unless ``face_attributes`` is given too."""
        if "faces" in changes and "face_attributes" not in changes:
            changes["face_attributes"] = {}
        return replace(self, **changes)


def describe(cloud: Cloud) -> list[tuple[str, str, str]]:
    """``(name, dtype, range)`` for every per-point field of ``cloud``."""
    ranges = FieldRanges()
    ranges.add(cloud)
    return ranges.rows()


class FieldRanges:
    """:func:`describe` of a cloud read in blocks: each field's dtype and the
    range of its finite values (a count of true values for a mask), gathered
    block by block; the same rows as :func:`describe` of the whole cloud."""

    def __init__(self):
        self._fields: dict = {}  # name -> [dtype text, lo, hi, trues (masks), size]

    def add(self, cloud: Cloud) -> None:
        fields = [("x y z", cloud.points, "")]
        fields += [(name, arr, "") for name, arr in (("normals", cloud.normals),
                                                    ("colors", cloud.colors),
                                                    ("quality", cloud.quality))
                   if arr is not None]
        fields += [(name, arr, "" if arr.ndim == 1 else f" x{arr.shape[1]}")
                   for name, arr in cloud.attributes.items()]
        for name, arr, shape in fields:
            a = np.asarray(arr)
            got = self._fields.setdefault(
                name, [str(a.dtype) + shape, None, None, 0 if a.dtype == bool else None, 0])
            got[4] += a.size
            if a.dtype == object:  # a PLY list per point
                got[0] = "list"
                continue
            if a.dtype == bool:
                got[3] += int(a.sum())
                continue
            fin = a[np.isfinite(a)] if a.dtype.kind == "f" else a
            if fin.size:
                lo, hi = fin.min(), fin.max()
                got[1] = lo if got[1] is None else min(got[1], lo)
                got[2] = hi if got[2] is None else max(got[2], hi)

    def rows(self) -> list[tuple[str, str, str]]:
        out = []
        for name, (dtype, lo, hi, trues, size) in self._fields.items():
            if size == 0:
                text = "empty"
            elif dtype == "list":
                text = "a list per point"
            elif trues is not None:
                text = f"{trues} true of {size}"
            elif lo is None:
                text = "no finite value"
            else:
                text = f"[{lo:.6g}, {hi:.6g}]"
            out.append((name, dtype, text))
        return out
