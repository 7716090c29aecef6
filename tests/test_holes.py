"""Tests of filters/holes.py and filters/_border.py: hole-boundary detection
(thesis ch.7, §7.3.1, §7.3.4)."""

from dataclasses import replace

import numpy as np
import pytest

from pcprep import InvalidParameterError, PointCloudError, detect_hole_boundaries
from pcprep.baselines.datasets import cut_holes, make_shape, rim_truth
from pcprep.filters import holes
from pcprep.filters._border import (border_distance, border_gap, border_radius,
                                    largest_angle_gap, near_any, strip_extent,
                                    strip_extent_at, track_border)
from pcprep.filters.holes import HoleResult, hole_features
from pcprep.filters.metrics import precision_recall_f1
from pcprep.filters.multiscale import scale_sizes, trace_steps
from pcprep.filters.neighbors import average_spacing, build_tree, centered, knn

from helpers import random_rotation


def f1(mask, truth):
    return precision_recall_f1(mask, truth)[2]


def off(**steps):
    """The default rules with ``steps`` switched off (``holes._detect``)."""
    return replace(holes.DEFAULT_RULES, **{k: False for k in steps})


@pytest.fixture(scope="module")
def disc():
    return make_shape("disc", n=8000, seed=0)


@pytest.fixture(scope="module")
def disc_result(disc):
    return detect_hole_boundaries(disc.points)


@pytest.fixture(scope="module")
def holed_cube():
    return cut_holes(make_shape("cube", n=12000, seed=1), n_holes=3, radius=8.0, seed=0)


# --------------------------------------------------------------- features
def test_hole_features_known_answers(disc):
    pts, _ = centered(disc.points)
    ks = scale_sizes(16, 80, 10)
    f = hole_features(pts, ks)
    assert f.features.shape == (len(pts), 30) and f.near.shape == (len(pts), 16)
    assert f.near.dtype == np.int32 and (f.near[:, 0] == np.arange(len(pts))).all()
    inner = np.linalg.norm(disc.points[:, :2], axis=1) < 0.6
    rim = disc.extra["boundary_distance"] < 0.5 * disc.h
    # inside a flat disc the density k h²/(π r²) is about 1 and the shift / r
    # small; on its rim a neighbourhood is a half-disc: half the density and
    # the half-disc centroid shift 4/(3π) ≈ 0.42 (measured 0.98 / 0.10 inside,
    # 0.54 / 0.40 on the rim); the surface variation of a plane is 0
    assert 0.8 < np.median(f.features[inner, 1::3]) < 1.2
    assert 0.4 < np.median(f.features[rim, 1::3]) < 0.7
    assert np.median(f.features[inner, 2::3]) < 0.15
    assert 0.35 < np.median(f.features[rim, 2::3]) < 0.45
    assert np.abs(f.variation).max() < 1e-9


def test_features_are_scale_and_rigid_motion_invariant(disc):
    moved = 1000.0 * disc.points @ random_rotation(3).T + np.array([1e6, -2e6, 5e5])
    ks = scale_sizes(16, 80, 10)
    a = hole_features(centered(disc.points)[0], ks)
    b = hole_features(centered(moved)[0], ks)
    np.testing.assert_allclose(b.features, a.features,
                               atol=1e-6 * np.abs(a.features).max())
    np.testing.assert_allclose(b.extent, a.extent, atol=1e-6)


# --------------------------------------------------------------- detection
def test_disc_rim_is_boundary_centre_is_not(disc, disc_result):
    r = disc_result
    assert isinstance(r, HoleResult)
    assert f1(r.mask, disc.rim) > 0.7
    centre = np.linalg.norm(disc.points[:, :2], axis=1) < 0.6
    assert not r.mask[centre].any()
    np.testing.assert_array_equal(r.quality, r.mask.astype(float))


def test_cut_hole_rims_found_creases_not_holes(holed_cube):
    s = holed_cube
    r = detect_hole_boundaries(s.points)
    p, rec, _ = precision_recall_f1(r.mask, s.rim)
    assert rec > 0.7
    crease = s.sharp & ~s.rim
    assert r.mask[crease].mean() < 0.1


def test_border_distance_follows_the_true_rim_distance(disc):
    r = detect_hole_boundaries(disc.points, min_shift=0.0, beta=0.0)
    true = disc.extra["boundary_distance"] / disc.h
    est = r.border_distance
    near = true < 4
    # measured: correlation 0.84, every point within 0.75h kept at 1.5h,
    # 6 % of those 2.5h-4h inside
    assert np.corrcoef(est[near], true[near])[0, 1] > 0.75
    assert (est[true < 0.75] <= 1.5).mean() > 0.95
    assert (est[(true > 2.5) & (true < 4)] <= 1.5).mean() < 0.2


def test_rim_localisation_raises_precision(holed_cube):
    s = holed_cube
    # min_radius=0 and the border row off: the steps along the border would
    # clean the raw rule's detections too (tested on their own below)
    loc = holes._detect(s.points, rules=off(border_row=1), min_radius=0)
    raw = holes._detect(s.points, rules=off(rim_distance=1, strip_extent=1, border_row=1),
                        min_radius=0)
    assert raw.border_distance is None and loc.border_distance is not None
    assert raw.border_extent is not None and loc.border_extent is not None
    p0, r0, _ = precision_recall_f1(raw.mask, s.rim)
    p1, r1, _ = precision_recall_f1(loc.mask, s.rim)
    # measured: precision 0.65 -> 0.88, recall 0.97 -> 0.86
    assert r0 > 0.9 and p1 > p0 + 0.15 and r1 > 0.8
    # the two localisation tests are applied as documented
    assert (loc.border_extent[loc.mask] <= 1.4).all()
    assert (loc.border_distance[loc.mask] <= 2.0).all()
    # without the strip test: two-level Otsu, then the half-disc width alone
    half = holes._detect(s.points, rules=off(strip_extent=1, border_row=1), min_radius=0)
    assert f1(half.mask, s.rim) > 0.7
    assert not (half.mask & ~raw.mask).any()
    np.testing.assert_array_equal(half.mask, raw.mask & (half.border_distance <= 2.0))


def test_small_hole_rims_found():
    # holes of radius 3h are narrower than the largest neighbourhood (about
    # 5h): its centroid shift spans the hole, so a largest-scale gate and the
    # half-disc distance lost them (measured recall 0.09 on their rims); the
    # scale-averaged gate and the strip extent keep 0.55
    s = cut_holes(make_shape("plane", n=12000, seed=3), n_holes=4, radius=3.0, seed=0)
    r = detect_hole_boundaries(s.points)
    assert r.mask[s.extra["hole_rim"]].mean() > 0.4
    p, rec, f1_ = precision_recall_f1(r.mask, s.rim)
    assert p > 0.8 and f1_ > 0.8


def test_closed_surface_has_almost_no_boundary():
    cube = make_shape("cube", n=8000, seed=0)
    r = detect_hole_boundaries(cube.points, min_support=0, min_radius=0)
    # measured 0.05 % (1.9 % without the strip test, with the two-level Otsu)
    assert r.mask.mean() < 0.005
    # without the shift gate more points pass (measured 12 against 4)
    r0 = detect_hole_boundaries(cube.points, min_shift=0.0, min_support=0, min_radius=0)
    assert r0.mask.sum() > r.mask.sum()


def test_thesis_beta_rule_and_count_score(disc):
    r0 = detect_hole_boundaries(disc.points, beta=1.0)
    assert not r0.mask.any()                              # f > max f: nothing
    r = detect_hole_boundaries(disc.points, beta=0.3)
    assert r.threshold == pytest.approx(0.3 * r.score.max()) and r.beta == 0.3
    assert f1(r.mask, disc.rim) > 0.5
    c = detect_hole_boundaries(disc.points, score="count")
    np.testing.assert_array_equal(np.floor(c.score), c.nnz)
    assert c.mask.any()


@pytest.fixture(scope="module")
def holed_cube_20k():
    return cut_holes(make_shape("cube", n=20000, seed=0), n_holes=3, radius=8.0, seed=0)


def test_border_support_drops_lone_detections(holed_cube_20k):
    # a holed cube: most interior detections (no border within 5h) go, the
    # rims stay (the border row, which reads the supported detections, off)
    s = holed_cube_20k
    row_off = off(border_row=1)
    on = holes._detect(s.points, rules=row_off, min_radius=0)
    off_ = holes._detect(s.points, rules=row_off, min_support=0, min_radius=0)
    assert f1(on.mask, s.rim) > 0.8
    assert not (on.mask & ~off_.mask).any()
    far = s.extra["boundary_distance"] > 5.0 * s.h
    # measured: 22 interior detections without the support test, 7 with it
    # (small clusters remain)
    assert (off_.mask & far).sum() >= 10
    assert (on.mask & far).sum() <= 0.5 * (off_.mask & far).sum()
    assert (off_.mask & ~on.mask & s.rim).sum() <= 0.02 * s.rim.sum()
    # one pass: support counted among the detections before the test
    det = s.points[off_.mask]
    support = (np.linalg.norm(det[:, None] - det[None], axis=2) <= 3.0 * on.h).sum(1) - 1
    np.testing.assert_array_equal(on.mask[off_.mask], support >= 2)
    # the private switch is the same as min_support=0
    sw = holes._detect(s.points, rules=off(support=1, border_row=1), min_radius=0)
    assert f1(sw.mask, off_.mask) == 1.0


def test_min_radius_drops_small_borders_on_every_sampling():
    # a 3h hole in a random and in a regular (grid) sampling of a plane: the
    # default (0.3 ln n h) keeps it, min_radius=10 drops it from both, the
    # outer border stays
    s = make_shape("plane", n=10000, seed=0)
    s = cut_holes(s, radius=3.0, centers=np.array([[0.0, 0.0, 0.0]]))
    hole = s.extra["hole_rim"]
    kept = detect_hole_boundaries(s.points)                # default 0.3 ln n = 2.76h
    assert kept.mask[hole].mean() > 0.5                     # measured 0.68
    big = detect_hole_boundaries(s.points, min_radius=10.0)
    assert not big.mask[hole].any()
    assert big.mask[s.rim & ~hole].mean() > 0.8             # the square's border stays
    g = np.arange(100.0)
    u, v = np.meshgrid(g, g)
    grid = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    grid = grid[np.hypot(grid[:, 0] - 50, grid[:, 1] - 50) > 3.0]
    near = np.hypot(grid[:, 0] - 50, grid[:, 1] - 50) < 4.5
    kept = detect_hole_boundaries(grid)                     # 0.3 ln n = 2.76h
    assert kept.mask[near].mean() > 0.3                     # measured 0.45
    big = detect_hole_boundaries(grid, min_radius=10.0)
    assert not big.mask[near].any()
    outer = (grid[:, :2].min(axis=1) == 0) | (grid[:, :2].max(axis=1) == 99)
    assert big.mask[outer].all()


def test_min_radius_removes_interior_clusters_keeps_rims(holed_cube_20k):
    # a holed 20K-point cube: the clusters the support test leaves in the
    # interior are chance gaps of the sampling (border radius <= 2.3h here)
    s = holed_cube_20k
    on = holes._detect(s.points, rules=off(border_row=1))
    off_ = holes._detect(s.points, rules=off(border_row=1), min_radius=0)
    assert f1(on.mask, s.rim) > 0.8
    # dropped: exactly the borders of radius < 0.3 ln n (2.97h)
    det = np.flatnonzero(off_.mask)
    radius = border_radius(s.points[det], 3.0 * off_.h) / off_.h
    np.testing.assert_array_equal(on.mask[det], radius >= 0.3 * np.log(len(s.points)))
    # what lies beyond a link (3h) of the rims' 1.5h band is gone (measured:
    # 3 such points without the test); the rims stay
    far = s.extra["boundary_distance"] > 4.5 * s.h
    assert (off_.mask & far).sum() > (on.mask & far).sum()
    assert not (on.mask & (s.extra["boundary_distance"] > 8.0 * s.h)).any()
    assert (off_.mask & ~on.mask & s.rim).sum() <= 0.02 * s.rim.sum()


def _grid_plane(m=60):
    g = np.arange(m, dtype=float)
    u, v = np.meshgrid(g, g)
    pts = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    edge = ((pts[:, 0] == 0) | (pts[:, 0] == m - 1)
            | (pts[:, 1] == 0) | (pts[:, 1] == m - 1))
    return pts, edge


def _graded_grid(m: int = 60):
    """A grid plane whose row and column spacings grow 1 → 4 across it (a
    nearest-neighbour CV like a graded mesh's, but no two samples close)."""
    xs = np.cumsum(np.linspace(1.0, 4.0, m)) - 1.0
    u, v = np.meshgrid(xs, xs)
    pts = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    edge = ((u == xs[0]) | (u == xs[-1]) | (v == xs[0]) | (v == xs[-1])).ravel()
    return pts, edge


def _rings(pts):
    """Index of each sample's ring on a (graded) square grid, 0 on its border."""
    xs = np.unique(pts[:, 0])
    ix, iy = np.searchsorted(xs, pts[:, 0]), np.searchsorted(xs, pts[:, 1])
    m = len(xs)
    return np.minimum.reduce([ix, iy, m - 1 - ix, m - 1 - iy])


def test_border_row_and_its_band_on_every_sampling(disc, disc_result):
    # grid plane (h = 1.14 spacings): the tracked border row is the whole
    # border ring, and the detections within 1.2h (1.37 spacings) of it add
    # the second ring (the benchmark's "don't care" ring on mesh vertices),
    # never the third
    pts, edge = _grid_plane()
    on = detect_hole_boundaries(pts)
    ring = _rings(pts)
    assert on.mask[edge].all()
    assert on.mask[ring == 1].mean() > 0.8                  # measured 212 of 228
    assert not on.mask[ring >= 2].any()
    # a graded grid (spacings 1 -> 4): the border ring whole, inner rings only
    # where the spacing is below 1.2h
    pts, edge = _graded_grid()
    g = detect_hole_boundaries(pts)
    assert g.mask[edge].all() and not g.mask[_rings(pts) >= 3].any()
    # random and blue-noise discs: the band, nothing beyond the truth's
    # "don't care" ring (2.5h); F1 against the 1.5h band (measured 0.97 / 0.96)
    for sample, res in ((disc, disc_result), (make_shape("disc", n=8000, seed=0,
                                                        sampling="blue"), None)):
        res = res if res is not None else detect_hole_boundaries(sample.points)
        pos, care = rim_truth(sample)
        assert precision_recall_f1(res.mask[care], pos[care])[2] > 0.9
        bd = sample.extra["boundary_distance"] / sample.h
        assert bd[res.mask].max() < 3.0
    # without the row step the disc keeps the detections alone: the step adds
    # the row samples near them and keeps the detections near the row
    no_row = holes._detect(disc.points, rules=off(border_row=1))
    assert f1(disc_result.mask, no_row.mask) > 0.9


def test_flatness_gate_keeps_rims_across_creases():
    # known answer: half a disc folded by 90 degrees (a rim crossing a
    # right-angle crease) has surface variation 0.128, under the default 0.13
    u = np.random.default_rng(0).uniform(-1, 1, (40000, 2))
    u = u[(u ** 2).sum(1) < 1]
    u = u[u[:, 0] > 0]
    fold = np.column_stack([u[:, 0], np.minimum(u[:, 1], 0), np.maximum(u[:, 1], 0)])
    lam = np.linalg.eigvalsh(np.cov(fold.T))
    assert lam[0] / lam.sum() == pytest.approx(0.128, abs=0.003)
    # holes centred on the cube's edges: the gate removes no rim point there
    from pcprep.baselines.bench_features import crease_centres
    base = make_shape("cube", n=12000, seed=1)
    s = cut_holes(base, radius=6.0, centers=crease_centres(base, 3, 6.0, seed=0))
    on = detect_hole_boundaries(s.points)
    no_gate = holes._detect(s.points, rules=off(flatness=1))
    assert not (on.mask & ~no_gate.mask).any()
    assert (no_gate.mask & ~on.mask & s.rim).sum() <= 0.02 * s.rim.sum()
    assert f1(on.mask, s.rim) > 0.7                         # measured 0.74


def test_flatness_gate_drops_thin_part_ends():
    # pymeshlab's closed cow (2,903 vertices): legs, ears and muzzle 2-4h
    # thick end inside the larger neighbourhoods, which then look like rims;
    # measured 10.4 % flagged without the gate, 6.8 % with it
    from pcprep.baselines.datasets import load_sample_mesh
    try:
        cow = load_sample_mesh("cow")
    except Exception as exc:  # pymeshlab without its sample meshes
        pytest.skip(f"cow sample mesh unavailable: {exc}")
    on = detect_hole_boundaries(cow.points)
    no_gate = holes._detect(cow.points, rules=off(flatness=1))
    assert not (on.mask & ~no_gate.mask).any()
    assert no_gate.mask.mean() > 0.01 and on.mask.mean() < 0.75 * no_gate.mask.mean()


def test_seed_policy_and_invariance(disc, disc_result):
    # seed=0 is the default; a seeded run repeats; a moved cloud agrees
    np.testing.assert_array_equal(detect_hole_boundaries(disc.points, seed=0).score,
                                  disc_result.score)
    a = detect_hole_boundaries(disc.points, seed=2)
    b = detect_hole_boundaries(disc.points, seed=2)
    np.testing.assert_array_equal(a.score, b.score)
    assert f1(a.mask, disc.rim) > 0.7
    moved = 0.001 * disc.points @ random_rotation(5).T + 7.0
    c = detect_hole_boundaries(moved, seed=2)
    assert f1(c.mask, a.mask) > 0.95                        # measured 1.0


def test_border_row_is_scale_and_rigid_motion_invariant():
    # a rotated, shrunk and shifted grid gives the same border row and band
    pts, edge = _graded_grid()
    moved = 0.003 * pts @ random_rotation(7).T + np.array([5.0, -2.0, 1.0])
    a = detect_hole_boundaries(pts, seed=1).mask
    np.testing.assert_array_equal(detect_hole_boundaries(moved, seed=1).mask, a)
    assert a[edge].all()


def test_private_path_with_default_rules_is_the_public_function(disc, disc_result):
    r = holes._detect(disc.points, rules=holes.DEFAULT_RULES)
    assert f1(r.mask, disc_result.mask) == 1.0 and r.mask.any()
    with pytest.raises(InvalidParameterError, match="detect_hole_boundaries.*rim_width"):
        holes._detect(disc.points, rules=off(rim_distance=1), rim_width=0.0)


# --------------------------------------------------------------- border helpers
def test_selection_by_row_chunks_is_the_whole_arrays(holed_cube, monkeypatch):
    # the threshold, the point-wise tests and the row-sample scan run over row
    # chunks (a tiled run's memory maps make no temporary of the cloud's
    # length): chunks of 997 rows give every step's mask of one chunk
    def steps():
        with trace_steps() as out:
            res = detect_hole_boundaries(holed_cube.points)
        return res, out

    whole, whole_steps = steps()
    monkeypatch.setattr(holes, "_SCAN", 997)
    chunked, chunked_steps = steps()
    assert whole.mask.any() and len(whole_steps) >= 6
    np.testing.assert_array_equal(chunked.mask, whole.mask)
    assert [n for n, _ in chunked_steps] == [n for n, _ in whole_steps]
    for (name, a), (_, b) in zip(whole_steps, chunked_steps):
        np.testing.assert_array_equal(b, a, err_msg=name)


def test_row_samples_near_detections_in_memory_and_from_gathered_angles(holed_cube,
                                                                       monkeypatch):
    # the one-piece path computes the empty angle of the rows near the
    # detections only; a tiled run reads every row's angle, in row chunks
    # (of 997 rows here), each chunk against one tree over the detections:
    # same rows
    monkeypatch.setattr(holes, "_SCAN", 997)
    s = holed_cube
    pts = centered(s.points)[0]
    tree = build_tree(pts)
    near = knn(pts, 16, tree=tree)[1]
    det = np.flatnonzero(np.random.default_rng(1).random(len(pts)) < 0.02)
    every = holes.rows_by_gap(lambda r: pts[r], border_gap(pts, near))
    local = holes._row_near_in_memory(pts, tree, near)
    h = average_spacing(pts)
    for radius, angle in ((1.0, np.pi / 2), (2.0, np.pi / 3)):
        a = every(det, radius * h, angle)
        np.testing.assert_array_equal(local(det, radius * h, angle), a)
        assert len(a) > 0
    assert len(local(det[:0], h, np.pi / 2)) == 0


def test_near_any_is_a_brute_force_radius_test(rng):
    p, q = rng.normal(size=(50, 3)), rng.normal(size=(400, 3))
    d = np.linalg.norm(q[:, None] - p[None], axis=2).min(axis=1)
    tree = build_tree(p)
    for r in (0.1, 0.3, 1.0):
        np.testing.assert_array_equal(near_any(p, q, r), d <= r)
        np.testing.assert_array_equal(near_any(tree, q, r), d <= r)  # a tree given
    # the radius itself counts as near; nothing is near an empty set
    assert near_any(np.zeros((1, 3)), np.array([[0.0, 0.0, 0.5]]), 0.5).all()
    assert not near_any(np.zeros((0, 3)), q, 10.0).any()
    assert near_any(p, np.zeros((0, 3)), 1.0).shape == (0,)


def test_border_distance_inverts_the_half_disc_law():
    # known answer: a disc of radius r missing the segment beyond a line at
    # distance u·r has its centroid shifted by r·g(u), g(0) = 4/(3π)
    u = np.linspace(0.0, 0.95, 20)
    root = np.sqrt(1 - u ** 2)
    g = (2 / 3) * root ** 3 / (np.pi - np.arccos(u) + u * root)
    r = np.full((20, 3), 3.0)
    d = border_distance(np.repeat(g[:, None], 3, axis=1), r)
    np.testing.assert_allclose(d, 3.0 * u, atol=2e-3)
    assert g[0] == pytest.approx(4 / (3 * np.pi))
    # beyond the half-disc value -> 0, no shift -> r; the median over scales
    est = border_distance(np.array([[0.5, 0.0, 0.43], [0.0, 0.0, 0.5]]),
                          np.array([[1.0, 2.0, 4.0], [1.0, 2.0, 4.0]]))
    # the medians of (0, 2, 0) and (1, 2, 0)
    np.testing.assert_allclose(est, [0.0, 1.0], atol=1e-12)


def test_strip_extent_known_answers():
    # a half-plane sampled on a unit grid (x <= 0): the surface ends at x = 0
    g = np.arange(-15.0, 0.5)
    xx, yy = np.meshgrid(g, np.arange(-15.0, 16.0))
    pts = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    # a narrow hole (radius 3) centred 6 units inside: a strip beyond it
    # finds the far side, which must not count as surface
    hole = np.hypot(pts[:, 0] + 8.0, pts[:, 1] - 8.0) < 3.0
    pts = pts[~hole]
    q = np.array([[0.0, -5.0, 0], [-1.0, -5.0, 0], [-2.0, -5.0, 0], [-7.0, -7.0, 0],
                  [-4.0, 8.0, 0]])
    qi = np.array([int(np.argmin(np.linalg.norm(pts - a, axis=1))) for a in q])
    _, idx = knn(pts, 80, query=pts[qi])
    x = pts[idx] - pts[qi, None, :]
    ext = strip_extent(x, x.mean(axis=1), np.tile([0.0, 0.0, 1.0], (len(qi), 1)), h=1.0)
    # rows 0, 1, 2 from the border: distance to the outermost row (the
    # border normal comes from the centroid shift of a k-NN set with ties at
    # equal grid distances, so it may tilt slightly)
    np.testing.assert_allclose(ext[:3], [0.0, 1.0, 2.0], atol=0.05)
    # interior: about the neighbourhood radius (80 grid points: 4-5 units)
    assert ext[3] > 3.5
    # 1 unit from the edge of the hole (which spans x in (-11, -5) on y = 8):
    # the hole is the gap, its far side (x <= -11) is not counted
    assert ext[4] == pytest.approx(1.0, abs=0.05)


def test_strip_extent_follows_the_true_rim_distance(disc, disc_result):
    true = disc.extra["boundary_distance"] / disc.h
    e = disc_result.border_extent
    near = true < 4
    # measured: correlation 0.93; all points within 0.75h at most 1.4h; 1 % of
    # those 2.5h-4h inside and 0.7 % of the interior (beyond 6h) at most 1.4h
    assert np.corrcoef(e[near], true[near])[0, 1] > 0.85
    assert (e[true < 0.75] <= 1.4).mean() > 0.98
    assert (e[(true > 2.5) & (true < 4)] <= 1.4).mean() < 0.05
    assert np.median(e[true > 6]) > 3.5


def test_border_radius_known_answers():
    # two rings (radius 5 and 12, spacing < 1) far apart, and a lone point
    t = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    ring = np.column_stack([np.cos(t), np.sin(t), np.zeros_like(t)])
    pts = np.vstack([5 * ring, 12 * ring + [100, 0, 0], [[0, 100, 0]]])
    r = border_radius(pts, link=1.5)
    np.testing.assert_allclose(r[:80], 5.0)
    np.testing.assert_allclose(r[80:160], 12.0)
    assert r[160] == 0.0
    # a link shorter than the spacing splits the rings into lone points
    assert (border_radius(pts, link=0.1) == 0).all()
    assert border_radius(np.zeros((0, 3)), link=1.0).shape == (0,)


def test_border_gap_known_answer():
    # a grid's straight border leaves half the plane empty (π), its corner
    # three quarters (3π/2); inside, the 15 neighbours are 45° apart at most
    pts, _ = _grid_plane()
    side = np.flatnonzero((pts[:, 0] == 0) & (pts[:, 1] == 30))
    corner = np.flatnonzero((pts[:, 0] == 0) & (pts[:, 1] == 0))
    inner = np.flatnonzero((pts[:, 0] == 30) & (pts[:, 1] == 30))
    _, nb = knn(pts, 16, query=pts[np.concatenate([side, corner, inner])])
    gap = border_gap(pts, nb)
    np.testing.assert_allclose(gap[:2], [np.pi, 1.5 * np.pi], atol=1e-9)
    assert gap[2] <= np.pi / 4 + 1e-9
    assert len(border_gap(pts, np.zeros((0, 16), dtype=int))) == 0


def test_largest_angle_gap_is_rotation_invariant():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(5, 12, 3))
    x[..., 2] = 0.0
    x[:, :, 0] = np.abs(x[:, :, 0])          # a half-plane: gap >= π
    nrm = np.tile([0.0, 0.0, 1.0], (5, 1))
    g0 = largest_angle_gap(x, nrm)
    R = random_rotation(5)
    g1 = largest_angle_gap(x @ R.T, nrm @ R.T)
    np.testing.assert_allclose(g0, g1, atol=1e-9)
    assert (g0 >= np.pi - 1e-9).all()


def test_track_border_known_answer():
    # two candidate chains 1h-stepped along x, 5h apart; a seed on the first
    # keeps it whole, the second (no seed) is dropped, a lone seed stays
    x = np.arange(10, dtype=float)
    pts = np.concatenate([np.column_stack([x, np.zeros(10), np.zeros(10)]),
                          np.column_stack([x, np.full(10, 5.0), np.zeros(10)]),
                          [[30.0, 0.0, 0.0]]])
    cand = np.ones(21, dtype=bool)
    cand[20] = False
    seeds = np.zeros(21, dtype=bool)
    seeds[[3, 20]] = True
    out = track_border(pts, seeds, cand, 1.5)
    np.testing.assert_array_equal(out, np.r_[np.ones(10, bool), np.zeros(10, bool), True])
    # a gap wider than the link cuts the chain
    cand[6] = False
    np.testing.assert_array_equal(np.flatnonzero(track_border(pts, seeds, cand, 1.5)),
                                  [0, 1, 2, 3, 4, 5, 20])
    assert not track_border(pts, np.zeros(21, dtype=bool), cand, 1.5).any()


# --------------------------------------------------------------- bad input
def test_bad_points(rng):
    fn = detect_hole_boundaries
    with pytest.raises(PointCloudError, match=fn.__name__):
        fn(np.zeros((0, 3)))
    bad = rng.normal(size=(500, 3))
    bad[3, 1] = np.nan
    with pytest.raises(PointCloudError, match="NaN"):
        fn(bad)
    with pytest.raises(PointCloudError, match="at least"):
        fn(rng.normal(size=(50, 3)))
    line = np.outer(np.linspace(0, 1, 500), [1.0, 2.0, 3.0])
    with pytest.raises(PointCloudError, match="collinear"):
        fn(line)
    with pytest.raises(PointCloudError, match="rows"):
        fn(rng.normal(size=(500, 3)), normals=np.ones((499, 3)))


@pytest.mark.parametrize("kw", [dict(beta=1.5), dict(beta=-0.1), dict(k_min=50, k_max=20),
                                dict(coder="ksvd"), dict(n_atoms=1), dict(seed=-1),
                                dict(n_scales=0), dict(score="max"),
                                dict(rim_width=0.0), dict(rim_width=-2.0),
                                dict(max_variation=0.5), dict(min_support=-1),
                                # the off switches left the public API
                                dict(rim_width=None), dict(extent_width=None),
                                dict(max_variation=None), dict(row_angle=None)])
def test_bad_params(kw, rng):
    with pytest.raises(InvalidParameterError, match="detect_hole_boundaries"):
        detect_hole_boundaries(rng.normal(size=(300, 3)), **kw)


def test_strip_extent_compiled_equals_numpy(holed_cube, monkeypatch):
    from pcprep.filters import _kernels
    from pcprep.filters.multiscale import scale_moments

    if not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    pts = centered(holed_cube.points)[0]
    m = next(iter(scale_moments(pts, scale_sizes(16, 80, 10))))
    args = (m.mean[:, -1], m.normal[:, -1])
    compiled = strip_extent_at(pts, m.idx, m.rows, *args, h=holed_cube.h)
    reference = strip_extent(m.offsets, *args, h=holed_cube.h)
    np.testing.assert_allclose(compiled, reference, rtol=0, atol=1e-12)
    monkeypatch.setattr(_kernels, "ENABLED", False)
    fallback = strip_extent_at(pts, m.idx, m.rows, *args, h=holed_cube.h)
    assert np.array_equal(fallback, reference)
    assert (reference == 0).any() and (reference > 2.0).any()   # rims and interiors


def test_border_gap_compiled_equals_numpy(holed_cube, monkeypatch):
    """The compiled empty angle against the NumPy reference, on a cloud with
    rims (gaps near π and more) and interiors (small gaps)."""
    from pcprep.filters import _kernels

    if not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    pts = centered(holed_cube.points)[0]
    _, nb = knn(pts, 16)
    compiled = border_gap(pts, nb)
    monkeypatch.setattr(_kernels, "ENABLED", False)
    reference = border_gap(pts, nb)
    np.testing.assert_allclose(compiled, reference, rtol=0, atol=1e-12)
    assert (reference > 0.9 * np.pi).any() and (reference < 0.5 * np.pi).any()
