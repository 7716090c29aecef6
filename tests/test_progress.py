"""Long steps report their progress to the listener a caller installs, and to
nobody by default."""

import numpy as np

import pcprep
from pcprep.baselines.datasets import make_shape
from pcprep.filters import progress as _progress


def _record(fn):
    events = []
    previous = _progress.set_listener(lambda *e: events.append(e))
    try:
        fn()
    finally:
        _progress.set_listener(previous)
    return events


def test_filters_report_their_steps_from_start_to_end():
    s = make_shape("cube", n=3000, seed=0)
    events = _record(lambda: pcprep.denoise_l1_tv(s.points, s.normals, n_iter=2))
    steps = [e for e in events if e[0] == "denoise iterations"]
    assert steps[0] == ("denoise iterations", 0, 2)
    assert ("denoise iterations", 2, 2) in steps and steps[-1][1] == -1
    events = _record(lambda: pcprep.simplify_sdbs(s.points, s.normals, ratio=0.2))
    names = {e[0] for e in events}
    assert "K-SVD dictionary" in names and any(n.startswith("greedy removal") for n in names)


def test_a_long_neighbour_query_reports_slices_and_gives_the_same_answer():
    from pcprep.filters.neighbors import CHUNK, knn

    g = np.random.default_rng(0)
    pts = g.random((4 * CHUNK + 1000, 3))
    events = _record(lambda: knn(pts, 6))
    done = [e[1] for e in events if e[0] == "6-NN query" and e[1] >= 0]
    assert done[0] == 0 and done[-1] == len(pts) and len(done) == 3
    d, i = knn(pts, 6)
    from scipy.spatial import cKDTree

    d0, i0 = cKDTree(pts).query(pts, k=6)
    assert np.array_equal(i, i0) and np.array_equal(d, d0)


def test_nobody_listens_by_default():
    assert _progress.set_listener(None) is None
