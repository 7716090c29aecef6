"""Outlier removal: planted outliers found (by the positives), the PCL/Open3D
statistics reproduced with scikit-learn as the oracle, invariance to rigid
motion, scale and order, and the MeshSet / CLI conventions."""

import numpy as np
import pymeshlab
import pytest
from sklearn.neighbors import NearestNeighbors

import pcprep
from pcprep.baselines.datasets import make_shape
from pcprep.filters.metrics import precision_recall_f1
from pcprep.filters.outliers import remove_outliers
from pcprep.meshlab_bridge.cli import main
from pcprep.meshlab_bridge.convert import Cloud, load_cloud, save_cloud

from helpers import random_rotation


@pytest.fixture(scope="module")
def planted():
    s = make_shape("fandisk", n=8000, seed=0)
    g = np.random.default_rng(1)
    lo, hi = s.points.min(0), s.points.max(0)
    # 1 % of points scattered in the bounding box, 6h or more off the surface
    extra = []
    while len(extra) < 80:
        p = g.uniform(lo - 0.2, hi + 0.2)
        if np.min(np.linalg.norm(s.points - p, axis=1)) > 6 * s.h:
            extra.append(p)
    pts = np.r_[s.points, np.array(extra)]
    truth = np.r_[np.zeros(len(s.points), bool), np.ones(80, bool)]
    return pts, truth, s.h


@pytest.mark.parametrize("kw", [{"method": "statistical"},
                                {"method": "radius", "radius": 3.0, "min_neighbors": 4}])
def test_planted_outliers_are_found(planted, kw):
    pts, truth, _ = planted
    res = remove_outliers(pts, **kw)
    removed = np.zeros(len(pts), bool)
    removed[res.removed_idx] = True
    precision, recall, f1 = precision_recall_f1(removed, truth)
    assert recall > 0.9 and f1 > 0.6, (precision, recall)
    assert np.array_equal(np.sort(np.r_[res.keep_idx, res.removed_idx]), np.arange(len(pts)))


def test_statistical_criterion_matches_its_definition(planted):
    pts, _, _ = planted
    res = remove_outliers(pts, k=12, std_ratio=1.5)
    d, _ = NearestNeighbors(n_neighbors=13).fit(pts).kneighbors(pts)
    mean = d[:, 1:].mean(axis=1)
    expect = np.flatnonzero(mean > mean.mean() + 1.5 * mean.std())
    assert np.array_equal(res.removed_idx, expect)


def test_invariant_to_rigid_motion_scale_and_order(planted):
    pts, _, _ = planted
    base = remove_outliers(pts, method="radius").removed_idx
    moved = 1000.0 * pts @ random_rotation(3).T + [4.5e6, -2.5e6, 300.0]
    assert np.array_equal(remove_outliers(moved, method="radius").removed_idx, base)
    perm = np.random.default_rng(2).permutation(len(pts))
    back = np.sort(perm[remove_outliers(pts[perm], method="radius").removed_idx])
    assert np.array_equal(back, base)


def test_meshset_removes_in_place_and_cli_reports_the_rows(planted, tmp_path, caplog):
    pts, truth, _ = planted
    ms = pcprep.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=pts), "scan")
    out = ms.meshing_remove_point_outliers(method="radius")
    res = remove_outliers(pts, method="radius")
    assert out["mesh_id"] == 0 and out["removed"] == len(res.removed_idx)
    assert np.array_equal(ms.current_mesh().vertex_matrix(), pts[res.keep_idx])
    src, dst = tmp_path / "in.ply", tmp_path / "out.ply"
    tag = np.arange(len(pts), dtype=np.int32)
    save_cloud(Cloud(pts, attributes={"tag": tag}), str(src))
    assert main(["outliers", str(src), str(dst), "--method", "radius"]) == 0
    got = load_cloud(str(dst))
    assert np.array_equal(got.attributes["tag"], res.keep_idx)
    assert f"removed {len(res.removed_idx)} of {len(pts)} points" in caplog.text
