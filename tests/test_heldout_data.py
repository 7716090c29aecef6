"""Tests of the held-out data of baselines/datasets.py: the new shapes, sampling
styles, noise kinds, the benchmark's truth rules with their "don't care" zones,
and the held-out case table (fixed before any default is chosen on it)."""

import numpy as np
import pytest

from pcprep.baselines import datasets as ds
from pcprep.baselines.datasets import (
    HELD_OUT,
    HELD_OUT_SHAPES,
    SAMPLINGS,
    add_noise,
    add_outliers,
    build_case,
    cut_holes,
    make_shape,
    mesh_sample,
    rim_truth,
    sharp_truth,
)
from pcprep import InvalidParameterError, PointCloudError
from pcprep.filters.neighbors import knn


@pytest.fixture(scope="module")
def held_shapes():
    return {name: make_shape(name, 4000, seed=5) for name in HELD_OUT_SHAPES}


def test_held_out_shapes_counts_normals_labels(held_shapes):
    for name, s in held_shapes.items():
        assert s.points.shape == (4000, 3)
        np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0, atol=1e-12)
        pos, care = sharp_truth(s)
        if name in ("torus", "bumpy_sphere"):
            assert not pos.any() and care.all()
        else:
            assert 0.03 < pos.mean() < 0.4, name
            assert (care | ~pos).all() and not care.all()


def test_held_out_normals_are_tangent_plane_normals(held_shapes):
    # neighbours lie in the tangent plane up to curvature away from creases
    kappa = dict(bracket=0, channel=0, steps=0, cylinder=1 / 0.6, cone=1 / 0.3,
                 torus=1 / 0.3)
    for name, k in kappa.items():
        s = held_shapes[name]
        ok = s.extra["edge_distance"] > 4 * s.h
        d, idx = knn(s.points, 7)
        off = np.abs(np.einsum("ikd,id->ik", s.points[idx[:, 1:]] - s.points[:, None],
                               s.normals))[ok]
        # neighbours across a thin wall (0.06 apart) are not in the tangent plane
        same_side = d[ok, 1:] < 0.05
        bound = 1.2 * k * d[ok, 1:] ** 2 / 2 + 1e-12
        assert (off[same_side] <= bound[same_side]).all(), name
        assert same_side.mean() > 0.3, name


def test_extrusions_have_concave_creases_and_thin_walls():
    s = make_shape("bracket", 20000, seed=1)
    # the inner corner of the L is a vertical concave crease at (-0.94, -0.64)
    inner = np.hypot(s.points[:, 0] + 0.94, s.points[:, 1] + 0.64) < 0.5 * s.h
    assert inner.sum() > 5 and s.sharp[inner].all()
    # the walls are 0.06 thick: a few h, so the faces of a wall are close
    assert 2.0 < 0.06 / s.h < 5.0
    p = s.points
    on_cap = np.abs(np.abs(p[:, 2]) - 0.4) < 1e-12
    assert ds._in_polygon(p[on_cap, :2], np.array(ds.PROFILES["bracket"][0])).all()


def test_torus_and_cone_exact():
    t = make_shape("torus", 3000, seed=2)
    rho = np.hypot(t.points[:, 0], t.points[:, 1])
    np.testing.assert_allclose(np.hypot(rho - 0.7, t.points[:, 2]), 0.3, atol=1e-12)
    c = make_shape("cone", 3000, seed=2)
    side = np.abs(np.abs(c.points[:, 2]) - 0.5) > 1e-9
    r = np.hypot(c.points[side, 0], c.points[side, 1])
    np.testing.assert_allclose(r, 0.8 - 0.5 * (c.points[side, 2] + 0.5), atol=1e-12)
    # area-uniform: the side holds its share of the total area
    side_area = np.pi * (0.8 + 0.3) * np.hypot(1.0, 0.5)
    total = side_area + np.pi * (0.8 ** 2 + 0.3 ** 2)
    assert side.mean() == pytest.approx(side_area / total, abs=0.03)


def test_bumpy_sphere_normals_by_finite_differences():
    s = make_shape("bumpy_sphere", 3000, seed=4)
    u = s.points / np.linalg.norm(s.points, axis=1, keepdims=True)
    r, _, _ = ds._sphere_bumps(u)
    np.testing.assert_allclose(np.linalg.norm(s.points, axis=1), r, atol=1e-12)
    # the normal is orthogonal to two independent tangent directions of p(u)
    for k in range(2):
        t = np.cross(u, np.eye(3)[k])
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        eps = 1e-6
        up = (u + eps * t)
        up /= np.linalg.norm(up, axis=1, keepdims=True)
        um = (u - eps * t)
        um /= np.linalg.norm(um, axis=1, keepdims=True)
        dp = ds._sphere_bumps(up)[0][:, None] * up - ds._sphere_bumps(um)[0][:, None] * um
        dp /= np.linalg.norm(dp, axis=1, keepdims=True)
        assert np.abs(np.einsum("ij,ij->i", dp, s.normals)).max() < 1e-5
    sal = s.extra["salient"]
    assert 0.03 < sal.mean() < 0.5


@pytest.mark.parametrize("sampling", SAMPLINGS)
def test_samplings_stay_on_the_surface(sampling):
    s = make_shape("cube", 3000, seed=3, sampling=sampling)
    assert abs(len(s) - 3000) <= 0.011 * 3000
    np.testing.assert_allclose(np.abs(s.points).max(axis=1), 0.5, atol=1e-12)
    assert len(np.unique(s.points, axis=0)) == len(s)
    assert s.extra["view_dir"].shape == s.points.shape


def test_blue_noise_keeps_points_apart_and_random_does_not():
    blue = make_shape("plane", 4000, seed=1, sampling="blue")
    rnd = make_shape("plane", 4000, seed=1)
    d_blue = knn(blue.points, 2)[0][:, 1]
    d_rnd = knn(rnd.points, 2)[0][:, 1]
    # blue noise: the closest pair is far from zero; random: 1 % of pairs closer
    # than 0.2 h
    assert d_blue.min() > 0.5 * blue.h
    assert (d_rnd < 0.2 * rnd.h).mean() > 0.005


def test_range_rows_and_anisotropy():
    rows = make_shape("plane", 4000, seed=2, sampling="rows")
    # a single face-on scan of a plane: its rays are the same for every point
    d = rows.extra["view_dir"]
    assert len(np.unique(np.round(d, 12), axis=0)) <= 3
    aniso = make_shape("plane", 4000, seed=2, sampling="aniso")
    # anisotropic pixels: nearest-neighbour offsets favour one direction
    _, idx = knn(aniso.points, 2)
    off = aniso.points[idx[:, 1]] - aniso.points
    cov = np.cov(off[:, :2].T)
    ev = np.linalg.eigvalsh(cov)
    _, idx = knn(rows.points, 2)
    off_r = rows.points[idx[:, 1]] - rows.points
    ev_r = np.linalg.eigvalsh(np.cov(off_r[:, :2].T))
    assert ev[1] / ev[0] > 1.5 * ev_r[1] / ev_r[0]


def test_gradient_is_1_to_10():
    s = make_shape("plane", 30000, seed=6, sampling="gradient")
    x = s.points[:, 0]
    lo, hi = (x < -0.8).sum(), (x > 0.8).sum()
    # mean strip densities 1 + 9 s over s in [0, 0.1] and [0.9, 1]
    assert hi / lo == pytest.approx(9.55 / 1.45, rel=0.12)


def test_view_noise_and_outliers():
    s = make_shape("cube", 2000, seed=1, sampling="rows")
    d = s.extra["view_dir"]
    noisy = add_noise(s.points, s.normals, sigma=0.3, h=s.h, kind="view", seed=2,
                      directions=d)
    step = noisy - s.points
    # every displacement lies along its own ray
    np.testing.assert_allclose(np.linalg.norm(np.cross(step, d), axis=1), 0, atol=1e-12)
    assert np.std(np.einsum("ij,ij->i", step, d)) == pytest.approx(0.3 * s.h, rel=0.1)
    with pytest.raises(PointCloudError, match="directions"):
        add_noise(s.points, s.normals, kind="view")
    pts, flag = add_outliers(s.points, 0.05, seed=3)
    assert flag.sum() == round(0.05 * len(s)) and not flag[:len(s)].any()
    np.testing.assert_array_equal(pts[:len(s)], s.points)
    with pytest.raises(InvalidParameterError, match="fraction"):
        add_outliers(s.points, 1.5)


def test_sharp_truth_bands_and_dont_care():
    s = make_shape("fandisk", 20000, seed=2)
    pos, care = sharp_truth(s)
    h = s.h
    d40 = s.extra["edge_distance"]  # edges > 30°; the fandisk's creases are >= 45°
    np.testing.assert_array_equal(pos, d40 <= h)
    # the ring between 1 and 2 bands of a crease is "don't care"
    ring = (d40 > 1.05 * h) & (d40 < 1.95 * h)
    assert not care[ring].any()
    assert care[d40 > 2.05 * h].all()
    # a mesh: a strip folded by 30° at path point 4 and by 60° at path point 8
    ang = np.radians(np.r_[np.zeros(4), np.full(4, 30.0), np.full(4, 90.0)])
    path = np.vstack([[0.0, 0.0], np.cumsum(0.25 * np.column_stack([np.cos(ang),
                                                                    np.sin(ang)]), 0)])
    V = np.vstack([np.column_stack([np.full(13, x), path]) for x in (0.0, 1.0)])
    F = np.array([f for i in range(12) for f in ([i, 13 + i, 14 + i], [i, 14 + i, i + 1])])
    m = mesh_sample(V, F)
    pos, care = sharp_truth(m)
    row = np.r_[np.arange(13), np.arange(13)]
    np.testing.assert_array_equal(pos, row == 8)
    np.testing.assert_array_equal(~care, np.isin(row, (3, 4, 5, 7, 9)))


def test_rim_truth_ring_for_cut_holes_samples_and_meshes():
    s = make_shape("cube", 20000, seed=4)
    c = cut_holes(s, n_holes=2, radius=8.0, seed=1)
    pos, care = rim_truth(c)
    dist = c.extra["boundary_distance"] / s.h
    np.testing.assert_array_equal(pos, dist < 1.5)
    assert not care[(dist > 1.55) & (dist < 2.45)].any()
    assert care[dist > 2.55].all()
    # mesh vertices: the second vertex row is "don't care"
    g = np.linspace(0, 1, 41)
    X, Y = np.meshgrid(g, g)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(X.size).reshape(41, 41)
    a, b, cc, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), \
        idx[1:, 1:].ravel()
    F = np.vstack([np.column_stack([a, b, d]), np.column_stack([a, d, cc])])
    m = mesh_sample(V, F)
    pos, care = rim_truth(m)
    ring = (np.minimum.reduce([X, Y, 1 - X, 1 - Y]).ravel() * 40).round()
    np.testing.assert_array_equal(pos, ring == 0)
    np.testing.assert_array_equal(~care, ring == 1)
    holed = cut_holes(m, n_holes=1, radius=5.0, centers=[[0.5, 0.5, 0.0]])
    pos, care = rim_truth(holed)
    hole_rim = holed.extra["hole_rim"]
    assert hole_rim.sum() > 10 and pos[hole_rim].all()
    r = np.hypot(holed.points[:, 0] - 0.5, holed.points[:, 1] - 0.5)
    dont = ~care
    assert dont.sum() > 10 and not (dont & hole_rim).any()
    assert (r[dont & (r < 0.4)] > r[hole_rim].min()).all()


def test_holes_beside_creases_stay_off_the_crease():
    s = make_shape("steps", 20000, seed=3)
    C = ds.centres_beside_edges(s, 3, 8.0, gap=1.5, seed=1)
    c = cut_holes(s, radius=8.0, centers=C)
    # the crease is kept whole: every sharp point of the input within 3 h of a
    # centre's rim is still there
    kept = np.zeros(len(s), bool)
    kept[c.extra["keep_idx"]] = True
    assert kept[s.sharp].mean() > 0.999
    d = np.min(np.linalg.norm(s.points[:, None] - C[None], axis=2), axis=1) / s.h
    assert ((d > 8.0) & (d < 10.5) & s.sharp).sum() > 0  # the rim runs beside it


def test_held_out_table_is_well_formed():
    seeds = set()
    for family, cases in HELD_OUT.items():
        assert cases, family
        for spec in cases:
            assert spec["seed"] >= ds.HELD_OUT_SEED
            assert spec["source"].split(":")[0] in ("shape", "surface", "vertices",
                                                    "points")
            if spec["source"].startswith("shape:"):
                assert spec["source"][6:] in ds.ALL_SHAPES
            assert spec["sampling"] in SAMPLINGS
            seeds.add((family, spec["case"], spec["seed"]))
    for fam, idx in ds.HELD_OUT_QUICK.items():
        assert all(i < len(HELD_OUT[fam]) for i in idx)


def test_build_case_tiny():
    spec = dict(HELD_OUT["denoise"][6])  # bracket + noise + 2 % outliers
    c = build_case(spec, n=1500)
    assert len(c["points"]) == 1530 and c["is_outlier"].sum() == 30
    clean = c["sample"].points
    step = np.linalg.norm(c["points"][:1500] - clean, axis=1)
    assert 0 < np.median(step) < 1.0 * c["sample"].h
    holes = build_case(HELD_OUT["holes"][2], n=6000)
    pos, care = rim_truth(holes["sample"])
    assert pos.any() and not care.all()
