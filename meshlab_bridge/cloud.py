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
        (rows removed for non-finite coordinates), ``"crs"`` (text, when known).
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    quality: np.ndarray | None = None
    faces: np.ndarray | None = None
    attributes: dict = field(default_factory=dict)
    label: str = ""
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, idx: np.ndarray, *, keep_faces: bool = True) -> "Cloud":
        """The cloud restricted to rows ``idx`` (in that order); faces whose
        three vertices are all kept are renumbered, the others dropped."""
        idx = np.asarray(idx, dtype=np.int64)
        take = (lambda a: None if a is None else a[idx])
        faces = None
        if keep_faces and self.faces is not None and len(self.faces):
            new = np.full(len(self.points), -1, dtype=np.int64)
            new[idx] = np.arange(len(idx))
            f = new[self.faces]
            f = f[(f >= 0).all(axis=1)]
            faces = f if len(f) else None
        return replace(self, points=self.points[idx], normals=take(self.normals),
                       colors=take(self.colors), quality=take(self.quality), faces=faces,
                       attributes={k: v[idx] for k, v in self.attributes.items()})

    def with_(self, **changes) -> "Cloud":
        return replace(self, **changes)


def describe(cloud: Cloud) -> list[tuple[str, str, str]]:
    """``(name, dtype, range)`` for every per-point field of ``cloud``."""
    rows = [("x y z", "float64", _range(cloud.points))]
    for name, arr in (("normals", cloud.normals), ("colors", cloud.colors),
                      ("quality", cloud.quality)):
        if arr is not None:
            rows.append((name, str(arr.dtype), _range(arr)))
    for name, arr in cloud.attributes.items():
        rows.append((name, str(arr.dtype) + ("" if arr.ndim == 1 else f" x{arr.shape[1]}"),
                     _range(arr)))
    return rows


def _range(arr: np.ndarray) -> str:
    a = np.asarray(arr)
    if a.size == 0:
        return "empty"
    if a.dtype == bool:
        return f"{int(a.sum())} true of {a.size}"
    fin = a[np.isfinite(a)] if a.dtype.kind == "f" else a
    if fin.size == 0:
        return "no finite value"
    return f"[{fin.min():.6g}, {fin.max():.6g}]"
