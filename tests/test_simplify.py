"""Tests for filters/simplify.py (SDBS, thesis ch.6)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pcprep import InvalidParameterError, PointCloudError, simplify_sdbs
from pcprep.baselines.datasets import make_shape
from pcprep.filters import simplify as S  # private steps: _knn32, _search_delta
from pcprep.filters.metrics import simplification_error
from pcprep.filters.neighbors import build_tree, knn
from pcprep.filters.simplify import greedy_keep, sdbs_features

FAST = dict(n_atoms=60, max_iter=3, max_train=3000)


def _jaccard(a, b):
    """|a ∩ b| / |a ∪ b|; 0 when both masks are empty, so two empty masks never agree."""
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 0.0


@pytest.fixture(scope="module")
def cube():
    return make_shape("cube", n=6000, seed=0)


@pytest.fixture(scope="module")
def cube_result(cube):
    return simplify_sdbs(cube.points, ratio=0.1, seed=0, **FAST)


def test_creases_kept_denser_than_faces(cube, cube_result):
    keep = np.zeros(len(cube.points), dtype=bool)
    keep[cube_result.keep_idx] = True
    sharp = cube.sharp
    assert sharp.any() and (~sharp).any()
    assert keep[sharp].mean() > 1.5 * keep[~sharp].mean()
    # and the saliency itself is higher on the creases
    assert np.median(cube_result.score[sharp]) > np.median(cube_result.score[~sharp])


def test_count_ratio_honoured_and_subset(cube, cube_result):
    n = len(cube.points)
    idx = cube_result.keep_idx
    assert len(idx) == round(0.1 * n)
    assert idx.dtype == np.int64 and np.all(np.diff(idx) > 0)
    assert idx[0] >= 0 and idx[-1] < n
    assert abs(cube_result.n_greedy - len(idx)) <= 0.01 * len(idx) + 1
    res = simplify_sdbs(cube.points, count=777, seed=0, **FAST)
    assert len(res.keep_idx) == 777


def test_delta_direct(cube, cube_result):
    res = simplify_sdbs(cube.points, delta=cube_result.delta, seed=0, **FAST)
    assert len(res.keep_idx) == res.n_greedy == cube_result.n_greedy
    more = simplify_sdbs(cube.points, delta=0.5 * cube_result.delta, seed=0, **FAST)
    assert len(more.keep_idx) > len(res.keep_idx)


def test_deterministic_and_input_untouched(cube, cube_result):
    pts = cube.points.copy()
    res = simplify_sdbs(pts, ratio=0.1, seed=0, **FAST)
    np.testing.assert_array_equal(pts, cube.points)
    np.testing.assert_array_equal(res.keep_idx, cube_result.keep_idx)
    np.testing.assert_array_equal(res.score, cube_result.score)


def test_scale_and_rigid_motion_invariance(cube, cube_result):
    rot = Rotation.from_euler("xyz", [30, -50, 70], degrees=True).as_matrix()
    moved = 1000.0 * cube.points @ rot.T + np.array([1e5, -3e4, 2e3])
    res = simplify_sdbs(moved, ratio=0.1, seed=0, **FAST)
    a, b = set(res.keep_idx.tolist()), set(cube_result.keep_idx.tolist())
    # scores agree to rounding; the greedy cascade may flip a few choices
    np.testing.assert_allclose(res.score, cube_result.score, atol=1e-6)
    assert len(a & b) / len(a | b) > 0.9


def test_better_than_random_subset(cube, cube_result):
    rng = np.random.default_rng(0)
    rand = np.sort(rng.choice(len(cube.points), len(cube_result.keep_idx), replace=False))
    _, avg_sdbs = simplification_error(cube.points, cube.points[cube_result.keep_idx])
    _, avg_rand = simplification_error(cube.points, cube.points[rand])
    assert avg_sdbs < avg_rand


def _naive_greedy(P, score, rho):
    n = len(P)
    order = np.lexsort((np.arange(n), -score))
    removed = np.zeros(n, dtype=bool)
    visited = np.zeros(n, dtype=bool)
    keep = np.zeros(n, dtype=bool)
    for i in order:
        visited[i] = True
        if removed[i]:
            continue
        keep[i] = True
        d = np.linalg.norm(P - P[i], axis=1)
        removed |= (d <= rho[i]) & ~visited
    return keep


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_parallel_greedy_equals_sequential(seed, solver_path):
    rng = np.random.default_rng(seed)
    P = rng.random((1500, 3)) * [1, 1, 0.05]
    score = rng.random(1500) ** 2
    score[:50] = score[50]  # ties are broken by index
    rho = 0.02 / np.maximum(score, 0.1)
    dist, idx = knn(P, 12)  # short lists: the exact ball fallback is exercised
    got = greedy_keep(P, dist.astype(np.float32), idx.astype(np.int32), score, rho,
                      tree=build_tree(P))
    assert _jaccard(got, _naive_greedy(P, score, rho)) == 1.0


def test_seed_policy(cube, cube_result):
    """Randomness (K-SVD) is seeded by ``seed``, 0 by default; None draws fresh entropy."""
    assert {p.name: p.default for p in simplify_sdbs.params}["seed"] == 0
    again = simplify_sdbs(cube.points, ratio=0.1, **FAST)  # default seed
    np.testing.assert_array_equal(again.keep_idx, cube_result.keep_idx)
    fresh = simplify_sdbs(cube.points, ratio=0.1, seed=None, **FAST)
    assert len(fresh.keep_idx) == len(cube_result.keep_idx)


def test_bad_input(cube):
    pts = cube.points
    f = simplify_sdbs
    with pytest.raises(InvalidParameterError, match="exactly one"):
        f(pts)
    with pytest.raises(InvalidParameterError, match="exactly one"):
        f(pts, ratio=0.1, count=10)
    with pytest.raises(InvalidParameterError, match="ratio"):
        f(pts, ratio=1.5)
    with pytest.raises(InvalidParameterError, match="count"):
        f(pts, count=len(pts) + 1)
    with pytest.raises(InvalidParameterError, match="delta"):
        f(pts, delta=-1.0)
    with pytest.raises(InvalidParameterError, match="feature_scale"):
        f(pts, ratio=0.1, feature_scale="raw")
    with pytest.raises(InvalidParameterError, match="integer"):
        f(pts, ratio=0.1, k=2.5)
    with pytest.raises(PointCloudError, match="empty"):
        f(np.zeros((0, 3)), ratio=0.1)
    bad = pts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(PointCloudError, match="NaN"):
        f(bad, ratio=0.1)
    with pytest.raises(PointCloudError, match="at least"):
        f(pts[:5], ratio=0.5)
    line = np.outer(np.linspace(0, 1, 100), [1.0, 2.0, 3.0])
    with pytest.raises(PointCloudError, match="collinear"):
        f(line, ratio=0.5)
    with pytest.raises(PointCloudError, match="normals"):
        f(pts, normals=np.ones((3, 3)), ratio=0.1)


def test_density_adapt_follows_input_density():
    s = make_shape("bumpy_plane", n=6000, seed=1, uniform=False)
    x = s.points[:, 0]
    dense = x < np.median(x)
    if s.points[dense].shape[0] and np.ptp(s.points[dense][:, 0]) > np.ptp(s.points[~dense][:, 0]):
        dense = ~dense  # the half with the smaller extent is the denser one

    def kept_ratio(beta):
        res = simplify_sdbs(s.points, ratio=0.1, density_adapt=beta, seed=0, **FAST)
        keep = np.zeros(len(x), dtype=bool)
        keep[res.keep_idx] = True
        return keep[dense].mean() / keep[~dense].mean()

    # global h (thesis) thins the dense side much more; local spacing keeps
    # a similar fraction on both sides
    r0, r1 = kept_ratio(0.0), kept_ratio(1.0)
    assert r0 < r1
    assert abs(np.log(r1)) < abs(np.log(r0))


def test_duplicated_points_rejected():
    rng = np.random.default_rng(0)
    P = np.repeat(rng.random((50, 3)), 20, axis=0)
    with pytest.raises(PointCloudError, match="duplicate point"):
        simplify_sdbs(P, ratio=0.1)


def test_greedy_long_balls_completed_lazily(solver_path):
    """Lists far shorter than most balls: nearly every kept row needs the
    exact ball query (several completion passes); still the sequential answer."""
    rng = np.random.default_rng(5)
    P = rng.random((1200, 3)) * [1, 1, 0.02]
    score = rng.random(1200)
    rho = 0.06 / np.maximum(score, 0.2)
    dist, idx = knn(P, 5)
    got = greedy_keep(P, dist.astype(np.float32), idx.astype(np.int32), score, rho)
    assert _jaccard(got, _naive_greedy(P, score, rho)) == 1.0


def test_features_from_shared_knn_lists(cube):
    """The single float32 k-NN query gives the same features as a fresh query."""
    P = cube.points - cube.points.mean(axis=0)
    F0, h0 = sdbs_features(P, None, 16, "balanced")[:2]
    gd, gi = S._knn32(P, 32, build_tree(P))
    F1, h1 = sdbs_features(P, None, 16, "balanced", nn=(gd, gi))[:2]
    assert abs(h1 - h0) <= 1e-6 * h0
    np.testing.assert_allclose(F1, F0, atol=1e-4)


@pytest.mark.parametrize("name,ratio", [("fandisk", 0.05), ("sphere", 0.2),
                                        ("block", 0.5)])
def test_delta_search_hits_count(name, ratio, monkeypatch):
    """The δ search ends within 1 % of the target in a few greedy runs."""
    s = make_shape(name, n=8000, seed=1)
    calls = []
    orig = S._search_delta

    def spy(run, target, d, max_eval=30):
        def counted(dl):
            calls.append(dl)
            return run(dl)
        return orig(counted, target, d, max_eval)

    monkeypatch.setattr(S, "_search_delta", spy)
    res = simplify_sdbs(s.points, ratio=ratio, seed=0, **FAST)
    target = round(ratio * len(s.points))
    assert len(res.keep_idx) == target
    assert abs(res.n_greedy - target) <= max(1, int(0.01 * target))
    assert len(calls) <= 6


@pytest.mark.parametrize("scan", [1 << 20, 1000])
def test_feature_scales_are_numpys_means_read_in_chunks(monkeypatch, scan):
    # the divisors of (6.x)'s columns are RMS values over every row; read in
    # chunks (here of 1000 rows) they are NumPy's whole-array means to the bit
    from pcprep.filters import neighbors

    monkeypatch.setattr(neighbors, "_SCAN", scan)
    g = np.random.default_rng(4)
    P = g.normal(size=(12_345, 3)) * [3.0, 1.0, 0.2] + 1e3
    sigma = g.random(12_345) / 3
    s_sig, s_pos = S.feature_scales(sigma, P, "balanced")
    assert s_sig == float(np.sqrt(np.mean(sigma ** 2)))
    assert s_pos == float(np.sqrt(np.mean(np.einsum("ij,ij->i", P, P))))
    assert S.feature_scales(np.zeros(5), P[:5], "balanced")[0] == 1.0
    inv = 1.0 / np.maximum(sigma, 0.05)
    want = float(np.sqrt(12_345 / (1234 * np.mean(inv ** 2))))
    assert S._delta_guess(1234, 12_345, inv) == want


@pytest.mark.parametrize("target", [0, 1, 137, 480, 500, 523, 999, 1000])
def test_exact_count_picked_chunk_by_chunk(monkeypatch, target):
    # the count made exact drops the least salient kept rows or adds the most
    # salient removed ones, ties by row, as a whole-array lexsort does; the
    # flips are picked in chunks (of 64 rows here) without copying the flags
    from pcprep.filters import neighbors

    monkeypatch.setattr(S, "CHUNK", 64)
    monkeypatch.setattr(neighbors, "_SCAN", 64)
    g = np.random.default_rng(target)
    keep = g.random(1000) < 0.5
    score = np.round(g.random(1000), 1)  # many ties
    ref = keep.copy()
    kept, rem = np.flatnonzero(keep), np.flatnonzero(~keep)
    if len(kept) > target:
        ref[kept[np.lexsort((kept, score[kept]))[:len(kept) - target]]] = False
    else:
        ref[rem[np.lexsort((rem, -score[rem]))[:target - len(kept)]]] = True
    got = S._kept_rows(keep, score, target)
    assert len(got) == target and got.dtype == np.int64
    np.testing.assert_array_equal(got, np.flatnonzero(ref))
    np.testing.assert_array_equal(S._kept_rows(keep, score, None), kept)
