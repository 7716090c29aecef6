"""Tests of baselines/datasets.py: exact geometry, labels, sampling, noise, holes,
mesh helpers and loaders (which skip when their data is absent)."""

import numpy as np
import pytest

from pcprep.baselines import datasets as ds
from pcprep.baselines.datasets import (
    SHAPES,
    Sample,
    add_noise,
    cut_holes,
    load_sample_mesh,
    load_shared_model,
    make_shape,
    mesh_sample,
    sample_mesh_surface,
)
from pcprep import InvalidParameterError, PointCloudError
from pcprep.filters.neighbors import average_spacing, knn

N = 5000


@pytest.fixture(scope="module")
def shapes():
    return {name: make_shape(name, N, seed=3) for name in SHAPES}


# ----------------------------------------------------------------- generic
def test_every_shape_count_unit_normals_labels(shapes):
    for name, s in shapes.items():
        assert isinstance(s, Sample) and s.name == name
        assert s.points.shape == (N, 3) and s.normals.shape == (N, 3)
        np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0, atol=1e-12)
        assert s.sharp.dtype == bool and s.rim.dtype == bool and len(s.sharp) == N
        assert s.h == pytest.approx(average_spacing(s.points))
        if name in ("sphere", "plane", "bumpy_plane", "disc"):
            assert not s.sharp.any()
        else:
            assert 0.02 < s.sharp.mean() < 0.4
        assert s.rim.any() == (name in ("plane", "bumpy_plane", "disc"))


def test_normals_are_tangent_plane_normals(shapes):
    # neighbours lie in the tangent plane up to curvature:
    # |(p_j - p_i) . n_i| <= kappa_max |p_j - p_i|^2 / 2 away from creases (a wrong
    # normal would give ~ |p_j - p_i|, i.e. ~ 1/h times more)
    kappa = dict(cube=0, octahedron=0, star=0, plane=0, disc=0, sphere=1.0, fandisk=0.5,
                 block=1 / 0.4, bumpy_plane=float(np.max(np.abs(ds.BUMPS[:, 2])
                                                         / ds.BUMPS[:, 3] ** 2)))
    for name, s in shapes.items():
        ok = s.extra["edge_distance"] > 4 * s.h
        d, idx = knn(s.points, 7)
        off = np.abs(np.einsum("ikd,id->ik", s.points[idx[:, 1:]] - s.points[:, None],
                               s.normals))[ok]
        bound = 1.2 * kappa[name] * d[ok, 1:] ** 2 / 2 + 1e-12
        assert (off <= bound).all(), name
        if name == "sphere":
            assert np.median(off / bound) > 0.1, name  # the bound is not vacuous


def test_cube_exact():
    s = make_shape("cube", N, seed=1)
    a = np.abs(s.points)
    np.testing.assert_allclose(a.max(axis=1), 0.5, atol=1e-15)
    axis = a.argmax(axis=1)
    expect = np.zeros_like(s.points)
    expect[np.arange(N), axis] = np.sign(s.points[np.arange(N), axis])
    np.testing.assert_array_equal(s.normals, expect)
    # uniform by area: 1/6 per face
    frac = np.bincount(axis * 2 + (s.normals.sum(1) > 0), minlength=6) / N
    np.testing.assert_allclose(frac, 1 / 6, atol=0.02)
    # distance to the nearest edge = second largest |coord| gap to 0.5
    srt = np.sort(a, axis=1)
    np.testing.assert_allclose(s.extra["edge_distance"], 0.5 - srt[:, 1], atol=1e-12)
    np.testing.assert_array_equal(s.sharp, 0.5 - srt[:, 1] <= s.h)


def test_octahedron_and_sphere_exact(shapes):
    o = shapes["octahedron"]
    np.testing.assert_allclose(np.abs(o.points).sum(1), 1.0, atol=1e-12)
    np.testing.assert_allclose(o.normals, np.sign(o.points) / np.sqrt(3), atol=1e-12)
    s = shapes["sphere"]
    np.testing.assert_allclose(np.linalg.norm(s.points, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(s.normals, s.points, atol=1e-12)


def test_block_exact_and_area_uniform():
    s = make_shape("block", 20000, seed=2)
    p, n = s.points, s.normals
    cyl = np.abs(n[:, 2]) < 1e-12
    cyl &= np.abs(np.hypot(p[:, 0], p[:, 1]) - 0.4) < 1e-12
    np.testing.assert_allclose(n[cyl, :2], -p[cyl, :2] / 0.4, atol=1e-12)  # into the hole
    box = ~cyl
    half = np.array([1.0, 0.75, 0.5])
    on = np.abs(np.abs(p[box]) - half) < 1e-12
    assert on.any(axis=1).all()
    caps = box & (np.abs(n[:, 2]) == 1)
    assert (np.hypot(p[caps, 0], p[caps, 1]) >= 0.4).all()
    areas = dict(x=1.5 * 2, y=2.0 * 2, z=2 * (3.0 - np.pi * 0.16), cyl=2 * np.pi * 0.4)
    total = sum(areas.values())
    assert cyl.mean() == pytest.approx(areas["cyl"] / total, abs=0.01)
    assert caps.mean() == pytest.approx(areas["z"] / total, abs=0.01)
    # hole rims are sharp edges
    rimz = cyl & (0.5 - np.abs(p[:, 2]) < 0.5 * s.h)
    assert s.sharp[rimz].all()


def test_star_exact(shapes):
    s = shapes["star"]
    p, n = s.points, s.normals
    cap = np.abs(p[:, 2]) == 0.25
    np.testing.assert_array_equal(np.abs(n[cap, 2]), 1.0)
    poly = ds._star_polygon()
    side_ok = np.zeros(len(p), bool)
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        nn = np.array([b[1] - a[1], a[0] - b[0], 0.0]) / np.linalg.norm(b - a)
        on = np.abs((p[:, :2] - a) @ nn[:2]) < 1e-12
        side_ok |= on & np.all(np.abs(n - nn) < 1e-12, axis=1)
    assert (side_ok | cap).all()


def test_fandisk_exact():
    s = make_shape("fandisk", 10000, seed=4)
    p, n = s.points, s.normals
    top = np.abs(np.hypot(p[:, 0], p[:, 2] + 1.0) - 2.0) < 1e-12
    top &= np.abs(n[:, 1]) == 0
    top &= n[:, 2] > 0.8
    np.testing.assert_allclose(n[top], np.column_stack([p[top, 0], 0 * p[top, 0],
                                                        p[top, 2] + 1]) / 2, atol=1e-12)
    assert top.mean() > 0.2
    # every point is under the cylinder top and on the same side of the cut
    assert (p[:, 2] <= -1 + np.sqrt(4 - p[:, 0] ** 2) + 1e-12).all()
    assert (p[:, 0] + p[:, 1] <= 1.3 + 1e-12).all()
    cut = np.abs(n @ (np.array([1, 1, 0]) / np.sqrt(2)) - 1) < 1e-12
    np.testing.assert_allclose(p[cut, 0] + p[cut, 1], 1.3, atol=1e-12)
    # the 45° creases drop out above a 50° threshold, nothing is sharper than 90°
    s50 = make_shape("fandisk", 10000, seed=4, sharp_angle_deg=50)
    assert s50.sharp.sum() < s.sharp.sum() and not (s50.sharp & ~s.sharp).any()
    assert not make_shape("fandisk", 2000, seed=4, sharp_angle_deg=91).sharp.any()


def test_bumpy_plane_normals_and_saliency(shapes):
    s = shapes["bumpy_plane"]
    p, n = s.points, s.normals
    z, fx, fy, g = ds._bumps(p[:, 0], p[:, 1])
    np.testing.assert_allclose(p[:, 2], z, atol=1e-14)
    eps = 1e-6  # finite differences: independent of the analytic gradient
    def f(x, y):
        return ds._bumps(x, y)[0]

    gx = (f(p[:, 0] + eps, p[:, 1]) - f(p[:, 0] - eps, p[:, 1])) / (2 * eps)
    gy = (f(p[:, 0], p[:, 1] + eps) - f(p[:, 0], p[:, 1] - eps)) / (2 * eps)
    ref = np.column_stack([-gx, -gy, np.ones(len(p))])
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    np.testing.assert_allclose(n, ref, atol=1e-6)
    sal = s.extra["salient"]
    assert 0.05 < sal.mean() < 0.5
    r = np.min(np.hypot(p[:, None, 0] - ds.BUMPS[:, 0], p[:, None, 1] - ds.BUMPS[:, 1])
               / ds.BUMPS[:, 3], axis=1)
    np.testing.assert_array_equal(sal, r < 2.0)


def test_open_shapes_rim(shapes):
    for name in ("plane", "disc"):
        s = shapes[name]
        np.testing.assert_array_equal(s.points[:, 2], 0.0)
        np.testing.assert_array_equal(s.normals, np.tile([0.0, 0.0, 1.0], (N, 1)))
        bd = s.extra["boundary_distance"]
        assert (bd >= -1e-15).all()
        np.testing.assert_array_equal(s.rim, bd <= 1.5 * s.h)
    d = shapes["disc"]
    # rim share ~ annulus area / disc area
    w = 1.5 * d.h
    assert d.rim.mean() == pytest.approx(1 - (1 - w) ** 2, rel=0.15)


# -------------------------------------------------------- sampling options
def test_sharp_fraction_scales_with_band():
    s = make_shape("cube", 20000, seed=5)
    # band of half-width w around 12 unit edges on a surface of area 6: 12*2w/6 = 4w
    assert s.sharp.mean() == pytest.approx(4 * s.h, rel=0.1)
    s2 = make_shape("cube", 20000, seed=5, sharp_width=2.0)
    assert s2.sharp.mean() == pytest.approx(2 * s.sharp.mean(), rel=0.1)
    coarse = make_shape("cube", 5000, seed=5)
    assert coarse.h == pytest.approx(2 * s.h, rel=0.05)
    assert coarse.sharp.mean() == pytest.approx(2 * s.sharp.mean(), rel=0.12)


def test_rotate_and_scale_consistent():
    a = make_shape("fandisk", 3000, seed=9)
    b = make_shape("fandisk", 3000, seed=9, rotate=True, scale=10.0)
    rot, t = b.extra["rotation"], b.extra["translation"]
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    np.testing.assert_allclose(b.points, 10 * a.points @ rot.T + t, atol=1e-12)
    np.testing.assert_allclose(b.normals, a.normals @ rot.T, atol=1e-12)
    assert b.h == pytest.approx(10 * a.h, rel=1e-9)
    np.testing.assert_array_equal(a.sharp, b.sharp)
    np.testing.assert_allclose(b.extra["edge_distance"], 10 * a.extra["edge_distance"])
    c = make_shape("fandisk", 3000, seed=10, rotate=True)
    assert not np.allclose(c.extra["rotation"], rot)


def test_seeds_deterministic():
    a = make_shape("star", 2000, seed=11)
    b = make_shape("star", 2000, seed=11)
    c = make_shape("star", 2000, seed=12)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.sharp, b.sharp)
    assert not np.array_equal(a.points, c.points)


def test_nonuniform_density_1_to_5():
    s = make_shape("plane", 20000, seed=6, uniform=False)
    x = s.points[:, 0]
    # density 1 + 4 s with s = (x + 1)/2: share of x > 0 is 2/3
    assert (x > 0).mean() == pytest.approx(2 / 3, abs=0.015)
    lo, hi = (x < -0.8).sum(), (x > 0.8).sum()
    assert hi / lo == pytest.approx(4.8 / 1.2, rel=0.12)  # mean strip densities
    np.testing.assert_allclose(s.extra["density"], (1 + 4 * (x + 1) / 2) / 5)
    assert len(s) == 20000


def test_make_shape_errors():
    with pytest.raises(InvalidParameterError, match="name"):
        make_shape("teapot")
    with pytest.raises(InvalidParameterError, match="scale"):
        make_shape("cube", 100, scale=0.0)
    with pytest.raises(InvalidParameterError, match="n"):
        make_shape("cube", 3)


# ------------------------------------------------------------------- noise
def test_noise_normal_along_normal_and_sigma():
    s = make_shape("sphere", 20000, seed=0)
    before = s.points.copy()
    q = add_noise(s.points, s.normals, sigma=0.3, kind="normal", seed=1)
    np.testing.assert_array_equal(s.points, before)
    d = q - s.points
    along = np.einsum("ij,ij->i", d, s.normals)
    np.testing.assert_allclose(np.linalg.norm(d - along[:, None] * s.normals, axis=1), 0,
                               atol=1e-14)
    assert along.std() / s.h == pytest.approx(0.3, rel=0.03)
    assert abs(along.mean()) / s.h < 0.01
    # explicit h gives exactly proportional noise
    q2 = add_noise(s.points, s.normals, sigma=0.3, h=2 * s.h, seed=1)
    np.testing.assert_allclose(q2 - s.points, 2 * d, atol=1e-14)


def test_noise_random_and_impulsive():
    s = make_shape("plane", 20000, seed=0)
    q = add_noise(s.points, None, sigma=0.2, kind="random", seed=2)
    d = q - s.points
    rms = np.sqrt((d * d).sum(1).mean()) / s.h
    assert rms == pytest.approx(0.2, rel=0.03)
    rms_z = np.sqrt(np.mean(d[:, 2] ** 2)) / s.h
    assert rms_z == pytest.approx(0.2 / np.sqrt(3), rel=0.04)
    q = add_noise(s.points, s.normals, sigma=0.5, kind="impulsive", seed=3)
    d = q - s.points
    hit = np.linalg.norm(d, axis=1) > 0
    assert hit.sum() == 10000  # default fraction 0.5
    np.testing.assert_array_equal(d[:, :2], 0.0)
    assert d[hit, 2].std() / s.h == pytest.approx(0.5, rel=0.05)
    q3 = add_noise(s.points, s.normals, sigma=0.5, kind="impulsive", seed=3, fraction=0.1)
    assert (np.linalg.norm(q3 - s.points, axis=1) > 0).sum() == 2000


def test_noise_seed_and_errors():
    s = make_shape("disc", 1000, seed=0)
    a = add_noise(s.points, s.normals, seed=5)
    np.testing.assert_array_equal(a, add_noise(s.points, s.normals, seed=5))
    assert not np.array_equal(a, add_noise(s.points, s.normals, seed=6))
    with pytest.raises(PointCloudError, match="normals"):
        add_noise(s.points, None, kind="normal")
    with pytest.raises(InvalidParameterError, match="kind"):
        add_noise(s.points, s.normals, kind="salt")
    with pytest.raises(InvalidParameterError, match="sigma"):
        add_noise(s.points, s.normals, sigma=-1)
    with pytest.raises(PointCloudError, match="rows"):
        add_noise(s.points, s.normals[:10])


# ------------------------------------------------------------------- holes
def test_cut_holes_cube():
    s = make_shape("cube", 20000, seed=0)
    c = cut_holes(s, n_holes=3, radius=8.0, seed=1)
    C = c.extra["hole_centers"]
    assert C.shape == (3, 3)
    r = 8.0 * s.h
    d_all = np.linalg.norm(s.points[:, None] - C[None], axis=2).min(1)
    np.testing.assert_array_equal(c.extra["keep_idx"], np.flatnonzero(d_all >= r))
    np.testing.assert_array_equal(c.points, s.points[c.extra["keep_idx"]])
    np.testing.assert_array_equal(c.sharp, s.sharp[c.extra["keep_idx"]])
    # every hole removed points; rims are exactly the band outside each ball
    d = d_all[c.extra["keep_idx"]]
    np.testing.assert_array_equal(c.rim, d < r + 1.5 * s.h)
    for k in range(3):
        dk = np.linalg.norm(c.points - C[k], axis=1)
        assert ((dk >= r) & (dk < r + 1.5 * s.h)).sum() > 20
    # centres avoid the cube's edges
    srt = np.sort(np.abs(C), axis=1)
    assert (0.5 - srt[:, 1] > r).all()
    assert average_spacing(c.points) == pytest.approx(c.h)


def test_cut_holes_sphere_twice_avoids_old_holes():
    s = make_shape("sphere", 10000, seed=0)
    c = cut_holes(s, n_holes=2, radius=6.0, seed=0)
    assert not s.rim.any() and c.rim.any()
    np.testing.assert_allclose(c.extra["boundary_distance"],
                               np.linalg.norm(c.points[:, None] - c.extra["hole_centers"],
                                              axis=2).min(1) - 6.0 * s.h)
    cc = cut_holes(c, n_holes=2, radius=6.0, seed=1)
    # new centres sit at least radius + 2h from the old hole rims
    new_c, old_c = cc.extra["hole_centers"], c.extra["hole_centers"]
    old = np.linalg.norm(new_c[:, None] - old_c[None], axis=2)
    assert (old >= 6.0 * s.h + (6.0 + 2.0) * c.h - 1e-12).all()
    np.testing.assert_array_equal(cc.points, s.points[cc.extra["keep_idx"]])
    assert cc.rim.sum() > c.rim.sum()


def test_cut_holes_keeps_open_boundary_and_is_seeded():
    s = make_shape("plane", 8000, seed=0)
    c = cut_holes(s, n_holes=2, radius=6.0, seed=3)
    old = s.rim[c.extra["keep_idx"]]
    assert (c.rim & old).sum() == old.sum()
    assert (c.extra["hole_rim"] & ~old).any()
    c2 = cut_holes(s, n_holes=2, radius=6.0, seed=3)
    np.testing.assert_array_equal(c.points, c2.points)
    with pytest.raises(InvalidParameterError, match="radius"):
        cut_holes(s, radius=-1)


def test_cut_holes_at_given_centres():
    s = make_shape("cube", 8000, seed=0)
    C = np.array([[0.5, 0.5, 0.0], [-0.5, 0.0, -0.5]])   # on two edges
    c = cut_holes(s, radius=6.0, centers=C, seed=None)
    np.testing.assert_array_equal(c.extra["hole_centers"], C)
    d = np.linalg.norm(s.points[:, None] - C[None], axis=2).min(1)
    np.testing.assert_array_equal(c.points, s.points[d >= 6.0 * s.h])
    np.testing.assert_array_equal(c.rim, (d < 7.5 * s.h)[d >= 6.0 * s.h])
    with pytest.raises(PointCloudError, match="centers"):
        cut_holes(s, centers=[[np.nan, 0.0, 0.0]])


def test_cut_holes_in_a_mesh_label_the_first_vertex_row():
    # a 60 x 60 unit grid mesh: the rim of a hole is the row of kept vertices
    # joined by a mesh edge to a removed one; the band rule stays in rim_band
    m = 60
    i, j = (a.ravel() for a in np.meshgrid(np.arange(m), np.arange(m), indexing="ij"))
    V = np.column_stack([i, j, np.zeros(m * m)]).astype(float)
    q = (i < m - 1) & (j < m - 1)
    a = np.flatnonzero(q)
    Fc = np.r_[np.c_[a, a + m, a + m + 1], np.c_[a, a + m + 1, a + 1]]
    s = mesh_sample(V, Fc)
    C = np.array([[30.3, 29.6, 0.0]])
    c = cut_holes(s, radius=5.0, centers=C, seed=None)
    d = np.linalg.norm(c.points - C, axis=1)
    r = 5.0 * s.h
    hole = c.extra["hole_rim"]
    # each row vertex lies within one (diagonal) edge of the ball ...
    assert (d[hole] < r + np.sqrt(2.0)).all()
    # ... and every kept vertex within 0.7 of it has a removed edge neighbour
    assert hole[d < r + 0.7].all()
    np.testing.assert_array_equal(c.rim, hole | s.rim[c.extra["keep_idx"]])
    np.testing.assert_array_equal(c.extra["rim_band"],
                                  (d < r + 1.5 * s.h) | s.rim[c.extra["keep_idx"]])
    assert hole.sum() < (c.extra["rim_band"] & ~s.rim[c.extra["keep_idx"]]).sum()
    # a cloud without faces keeps the band rule
    cloud = cut_holes(make_shape("plane", 6000, seed=0), radius=5.0, seed=0)
    np.testing.assert_array_equal(cloud.rim, cloud.extra["rim_band"])


# ------------------------------------------------------------------- meshes
def _grid_mesh(fold_deg=0.0):
    """3x3-vertex unit square (8 triangles), the x > 0.5 half folded up by fold_deg."""
    xs, ys = np.meshgrid([0.0, 0.5, 1.0], [0.0, 0.5, 1.0], indexing="ij")
    V = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(9)])
    t = np.radians(fold_deg)
    right = V[:, 0] > 0.5
    V[right, 2] = (V[right, 0] - 0.5) * np.sin(t)
    V[right, 0] = 0.5 + (V[right, 0] - 0.5) * np.cos(t)
    F = []
    for i in range(2):
        for j in range(2):
            a, b, c, d = 3 * i + j, 3 * (i + 1) + j, 3 * (i + 1) + j + 1, 3 * i + j + 1
            F += [[a, b, c], [a, c, d]]
    return V, np.array(F)


def _cube_mesh():
    c = (-0.5, 0.5)
    V = np.array([[x, y, z] for x in c for y in c for z in c])
    F = []
    for axis in range(3):
        for side in (0, 1):
            quad = [i for i in range(8) if (i >> (2 - axis)) & 1 == side]
            a, b, c, d = quad[0], quad[1], quad[3], quad[2]  # cyclic order
            nrm = np.zeros(3)
            nrm[axis] = 1 if side else -1
            if np.cross(V[b] - V[a], V[c] - V[a]) @ nrm < 0:
                a, b, c, d = a, d, c, b
            F += [[a, b, c], [a, c, d]]
    return V, np.array(F)


def test_mesh_sample_flat_and_folded():
    V, F = _grid_mesh()
    s = mesh_sample(V, F)
    np.testing.assert_allclose(np.abs(s.normals), np.tile([0, 0, 1.0], (9, 1)),
                               atol=1e-12)
    assert not s.sharp.any()
    np.testing.assert_array_equal(s.rim, np.arange(9) != 4)  # all but the centre
    V2, F2 = _grid_mesh(40.0)
    s2 = mesh_sample(V2, F2)
    np.testing.assert_array_equal(s2.sharp, np.isclose(V2[:, 0], 0.5) & (V2[:, 2] == 0))
    assert not mesh_sample(V2, F2, sharp_angle_deg=45).sharp.any()
    # unreferenced vertices are dropped and reported
    s3 = mesh_sample(np.vstack([V, [[9, 9, 9]]]), F)
    assert len(s3) == 9 and (s3.extra["vertex_idx"] == np.arange(9)).all()
    with pytest.raises(PointCloudError, match="outside"):
        mesh_sample(V, F + 20)


def test_sample_mesh_surface_cube_matches_analytic():
    V, F = _cube_mesh()
    s = sample_mesh_surface(V, F, 20000, seed=5)
    a = make_shape("cube", 20000, seed=5)
    assert len(s) == 20000
    np.testing.assert_allclose(np.abs(s.points).max(axis=1), 0.5, atol=1e-12)
    axis = np.abs(s.points).argmax(axis=1)
    expect = np.zeros_like(s.points)
    expect[np.arange(len(s)), axis] = np.sign(s.points[np.arange(len(s)), axis])
    np.testing.assert_allclose(s.normals, expect, atol=1e-12)  # "auto": creases kept
    srt = np.sort(np.abs(s.points), axis=1)
    np.testing.assert_allclose(s.extra["edge_distance"], 0.5 - srt[:, 1], atol=0.01 * s.h)
    assert s.sharp.mean() == pytest.approx(a.sharp.mean(), rel=0.1)
    assert not s.rim.any()
    b = sample_mesh_surface(V, F, 20000, seed=5)
    np.testing.assert_array_equal(s.points, b.points)


def test_sample_mesh_surface_smooth_normals_on_sphere():
    th, ph = np.meshgrid(np.linspace(0, np.pi, 25)[1:-1],
                         np.linspace(0, 2 * np.pi, 49)[:-1], indexing="ij")
    V = np.column_stack([np.sin(th).ravel() * np.cos(ph).ravel(),
                         np.sin(th).ravel() * np.sin(ph).ravel(), np.cos(th).ravel()])
    V = np.vstack([V, [[0, 0, 1], [0, 0, -1]]])
    nt, npf = th.shape
    F = []
    for i in range(nt - 1):
        for j in range(npf):
            a, b = i * npf + j, i * npf + (j + 1) % npf
            c, d = (i + 1) * npf + j, (i + 1) * npf + (j + 1) % npf
            F += [[a, c, d], [a, d, b]]
    top, bot = len(V) - 2, len(V) - 1
    for j in range(npf):
        F += [[top, j, (j + 1) % npf]]
        k = (nt - 1) * npf
        F += [[bot, k + (j + 1) % npf, k + j]]
    F = np.array(F)
    err = {}
    for mode in ("face", "interpolated", "auto"):
        s = sample_mesh_surface(V, F, 4000, seed=0, normals=mode)
        true = s.points / np.linalg.norm(s.points, axis=1, keepdims=True)
        cos = np.clip(np.abs((s.normals * true).sum(1)), 0, 1)
        err[mode] = np.degrees(np.arccos(cos))
    assert err["interpolated"].mean() < 0.5 * err["face"].mean()
    np.testing.assert_allclose(err["auto"], err["interpolated"], atol=1e-9)
    assert not s.sharp.any() and not s.rim.any()


def test_sample_mesh_surface_rim_on_open_square():
    V, F = _grid_mesh()
    s = sample_mesh_surface(V, F, 4000, seed=1)
    bd = np.minimum.reduce([s.points[:, 0], 1 - s.points[:, 0], s.points[:, 1],
                            1 - s.points[:, 1]])
    np.testing.assert_allclose(s.extra["boundary_distance"], bd, atol=0.01 * s.h)
    np.testing.assert_array_equal(s.rim[np.abs(bd - 1.5 * s.h) > 0.02 * s.h],
                                  (bd <= 1.5 * s.h)[np.abs(bd - 1.5 * s.h) > 0.02 * s.h])


# ------------------------------------------------------------------ loaders
def test_load_sample_mesh():
    if ds.pymeshlab_sample_dir() is None:
        pytest.skip("pymeshlab sample meshes not available")
    s = load_sample_mesh("bone")
    assert s.faces is not None and s.faces.max() < len(s)
    np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0, atol=1e-9)
    c = load_sample_mesh("cube")  # 8 corners, all on 90° edges
    assert len(c) == 8 and c.sharp.all() and not c.rim.any()
    with pytest.raises(InvalidParameterError):
        load_sample_mesh("teapot")


def test_load_shared_model_absent_and_tmp(tmp_path, monkeypatch):
    monkeypatch.setenv("PCPREP_SHARED_MODELS", str(tmp_path / "nowhere"))
    assert load_shared_model("cad/fandisk_clean.obj") is None
    with pytest.raises(FileNotFoundError, match="PCPREP_SHARED_MODELS"):
        load_shared_model("cad/fandisk_clean.obj", required=True)
    # a PLY2 file plus a per-face saliency table, in a private root
    V, F = _grid_mesh(40.0)
    lines = [f"{len(V)}", f"{len(F)}"] + [" ".join(f"{x:.17g}" for x in v) for v in V]
    lines += ["3 " + " ".join(map(str, f)) for f in F]
    (tmp_path / "m.ply2").write_text("\n".join(lines) + "\n")
    (tmp_path / "m_face_saliency.txt").write_text("\n".join(str(i) for i in range(8)))
    s = load_shared_model("m.ply2", root=tmp_path)
    np.testing.assert_allclose(s.points, V)
    assert s.sharp.sum() == 3
    np.testing.assert_array_equal(s.extra["face_saliency"], np.arange(8.0))
    assert s.extra["vertex_saliency"][0] == pytest.approx(0.5)  # faces 0 and 1


def test_load_shared_model_real_data_if_present():
    root = ds.shared_models_root()
    if not (root / "cad" / "fandisk_clean.obj").is_file():
        pytest.skip("shared model folder not present")
    s = load_shared_model("cad/fandisk_clean.obj")
    assert len(s) == 6475 and len(s.faces) == 12946
    assert 0.02 < s.sharp.mean() < 0.3 and not s.rim.any()
