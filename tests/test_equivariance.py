"""Every filter's output transforms with its input: under a rotation, a
permutation of the points, and a translation far from the origin (one that is
exact in floating point, so that the input really is the same cloud moved),
positions agree to 1e-6 h and masks, scores and kept sets are the same."""

import numpy as np
import pytest

from pcprep.baselines.datasets import add_noise, make_shape
from pcprep.meshlab_bridge import registry

from helpers import random_rotation

SPECS = sorted(registry.load_all().values(), key=lambda s: s.name)


@pytest.fixture(scope="module")
def cloud():
    s = make_shape("fandisk", n=4000, seed=0)
    noisy = add_noise(s.points, s.normals, sigma=0.2, h=s.h, kind="normal", seed=1)
    return np.round(noisy * 2**20) / 2**20, s.h  # exact after a shift by 5e6


def _call(spec, pts):
    kw = dict(spec.example)
    if spec.command == "simplify":
        kw.setdefault("ratio", 0.2)
    return spec.func(pts, **kw)


def _compare(spec, a, b, h, back_points, back_rows):
    """``b`` is the result for the moved cloud; map it back and compare with ``a``."""
    if spec.kind == "coord":
        pa, pb = a.points, back_points(b.points)[back_rows]
        assert np.abs(pa - pb).max() < 1e-6 * h
    for field in (spec.mask_field, spec.scalar_field):
        if field:
            va, vb = np.asarray(getattr(a, field)), np.asarray(getattr(b, field))[back_rows]
            if va.dtype == bool:
                assert np.array_equal(va, vb), field
            else:
                assert np.allclose(va, vb, rtol=0, atol=1e-6), field
    if spec.index_field:
        inv = np.empty(len(back_rows), dtype=np.int64)
        inv[back_rows] = np.arange(len(back_rows))
        kept_b = np.sort(inv[np.asarray(getattr(b, spec.index_field))])
        assert np.array_equal(np.sort(getattr(a, spec.index_field)), kept_b)


def _same_outcome(a, b, pts, h):
    """SDBS under a rotation: nearly the same kept set, the same coverage."""
    from scipy.spatial import cKDTree

    A, B = set(a.keep_idx.tolist()), set(b.keep_idx.tolist())
    assert len(A) == len(B)
    assert len(A & B) / len(A | B) >= 0.9
    davg = [cKDTree(pts[k]).query(pts)[0].mean() / h for k in (a.keep_idx, b.keep_idx)]
    assert abs(davg[0] - davg[1]) <= 0.01 * davg[0]


@pytest.mark.parametrize("spec", SPECS, ids=[s.command for s in SPECS])
def test_rotation_permutation_and_translation(spec, cloud):
    pts, h = cloud
    base = _call(spec, pts)
    n = len(pts)
    rot = random_rotation(7)
    if spec.command == "simplify":  # near-ties decided by rounding noise, see
        # docs/decisions/simplify.md, "Rotation on another machine"
        _same_outcome(base, _call(spec, pts @ rot.T), pts, h)
        return
    _compare(spec, base, _call(spec, pts @ rot.T), h, lambda y: y @ rot, np.arange(n))
    # SDBS returned above; it also samples its K-SVD training set by row, so a
    # permutation or a translation changes its dictionary (docs/decisions/simplify.md,
    # "Training subsample by row")
    perm = np.random.default_rng(3).permutation(n)
    inv = np.argsort(perm)
    _compare(spec, base, _call(spec, pts[perm]), h, lambda y: y, inv)
    shift = np.array([5e6, -2e6, 3e5])
    assert np.array_equal((pts + shift) - shift, pts)
    _compare(spec, base, _call(spec, pts + shift), h, lambda y: y - shift, np.arange(n))
