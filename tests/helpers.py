"""Helpers shared by the test modules (imported as ``helpers``: pytest puts this
folder on ``sys.path``, with ``pytest`` and ``python -m pytest`` alike)."""

import numpy as np

from pcprep.filters import Param, validate_params
from pcprep.filters.neighbors import pca_normals
from pcprep.meshlab_bridge import registry


def sphere_points(n, seed=0, radius=1.0):
    g = np.random.default_rng(seed)
    p = g.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    return radius * p


def random_rotation(seed=0):
    g = np.random.default_rng(seed)
    q, r = np.linalg.qr(g.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


# --- filters declared for the bridge tests -------------------------------------------




class _Res:
    def __init__(self, **kw):
        self.__dict__.update(kw)


@validate_params(Param("k", int, low=4, high=64, unit="count"))
def _flatten(points, normals=None, *, k: int = 12):
    """Double the coordinates; PCA normals; select the points above z = 0.5.

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float, optional
    k : int, default=12
        Neighbours of the PCA normals.
    """
    pts = np.array(points, dtype=float)
    n = pca_normals(pts, k)
    mask = pts[:, 2] > 0.5
    return _Res(points=pts * 2.0, normals=n, mask=mask, score=np.clip(pts[:, 2], 0, 1),
                keep=np.flatnonzero(mask))


SPECS = {
    kind: registry.FilterSpec(
        name=f"_test_{kind}", command=f"_test_{kind}", label="test", description="Test filter.",
        func=_flatten, kind=kind,
        mask_field="mask" if kind in ("coord", "selection") else None,
        scalar_field="score" if kind in ("scalar", "selection") else None,
        index_field="keep" if kind == "new_layer" else None,
    )
    for kind in ("coord", "scalar", "selection", "new_layer")
}
