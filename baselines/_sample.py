"""
_sample.py
----------
What the synthetic shapes (datasets.py) and the mesh ground truth (meshes.py)
share: the ``Sample`` record and the batched point-to-segment distance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class Sample:
    """A point cloud with ground truth.

    Attributes
    ----------
    points : (n, 3) float
        Positions.
    normals : (n, 3) float
        Exact unit outward normals (interpolated for mesh surface samples).
    sharp : (n,) bool or None
        Point within ``sharp_width`` h of an edge whose dihedral angle exceeds the
        threshold (None when unknown).
    rim : (n,) bool or None
        Point near a surface boundary (open border or cut hole); None when unknown.
    h : float
        Average spacing (mean distance to the 6 nearest neighbours).
    name : str
        Shape or model name.
    faces : (m, 3) int or None
        Triangles when the sample is a mesh's vertex set.
    extra : dict
        Shape-specific ground truth, e.g. ``"edge_distance"`` (n,) distance to the
        nearest sharp edge, ``"salient"`` / ``"saliency"`` for "bumpy_plane",
        ``"density"`` for non-uniform sampling, ``"rotation"``/``"translation"``,
        ``"keep_idx"`` after :func:`cut_holes`.
    """

    points: np.ndarray
    normals: np.ndarray
    sharp: np.ndarray | None
    rim: np.ndarray | None
    h: float
    name: str
    faces: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)


def _segment_distance(points, a, b, step, k=8):
    """Distance from points to a set of segments.

    The segments are densified at ``step`` and put in a KD-tree; the segments of
    the ``k`` nearest dense samples are the candidates, and the exact point-to-
    segment distance is taken over them (the result is exact whenever the nearest
    segment is among the candidates, and never worse than the dense-sample
    distance, whose error is below step/2)."""
    if len(a) == 0:
        return np.full(len(points), np.inf)
    ab = b - a
    length = np.linalg.norm(ab, axis=1)
    cnt = np.maximum(1, np.ceil(length / step).astype(np.int64)) + 1
    seg = np.repeat(np.arange(len(a)), cnt)
    within = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    t = within / np.repeat(cnt - 1, cnt)
    dense = a[seg] + t[:, None] * ab[seg]
    k = min(k, len(dense))
    _, nn = cKDTree(dense).query(points, k=k, workers=-1)
    cand = seg[nn.reshape(len(points), k)]  # (n, k)
    ll = np.maximum(length[cand] ** 2, 1e-300)
    ap = points[:, None, :] - a[cand]
    u = np.clip(np.einsum("nkd,nkd->nk", ap, ab[cand]) / ll, 0.0, 1.0)
    d = ap - u[..., None] * ab[cand]
    return np.sqrt((d * d).sum(axis=2).min(axis=1))
