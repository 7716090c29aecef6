"""Tests of baselines/classic.py: the classic sharp-feature and boundary detectors."""

import numpy as np
import pytest

from pcprep.baselines import classic as C
from pcprep.baselines.datasets import make_shape
from pcprep import InvalidParameterError, PointCloudError
from pcprep.filters.metrics import precision_recall_f1
from helpers import random_rotation


@pytest.fixture(scope="module")
def cube():
    return make_shape("cube", n=6000, seed=0)


@pytest.fixture(scope="module")
def disc():
    return make_shape("disc", n=6000, seed=0)


@pytest.mark.parametrize("name", sorted(C.SHARP_METHODS))
def test_sharp_methods_find_cube_edges(cube, name):
    r = C.run_method(name, cube.points)
    assert r.mask.shape == (len(cube),)
    p, rec, _ = precision_recall_f1(r.mask, cube.sharp)
    assert rec > 0.8                      # edges are found ...
    far = cube.extra["edge_distance"] > 6 * cube.h
    assert r.mask[far].mean() < 0.02      # ... and face interiors are not
    assert np.array_equal(r.mask, r.score > r.threshold)


def test_projected_distance_is_invariant(cube):
    a = C.projected_distance(cube.points)
    b = C.projected_distance(50.0 * cube.points @ random_rotation(1).T + 3e5)
    np.testing.assert_allclose(a.score, b.score, atol=1e-6)


def test_angle_gap_disc_rim(disc):
    r = C.angle_gap(disc.points)
    p, rec, f1 = precision_recall_f1(r.mask, disc.rim)
    assert rec > 0.6 and p > 0.8
    centre = np.linalg.norm(disc.points[:, :2], axis=1) < 0.6
    assert not r.mask[centre].any()
    # a half-disc neighbourhood has a gap of about π
    assert r.score[r.mask].max() > 2.5


def test_angle_gap_ignores_cube_creases(cube):
    r = C.angle_gap(cube.points)
    assert r.mask.mean() < 0.03           # a closed surface has no boundary


def test_explicit_threshold(cube):
    r = C.surface_variation(cube.points, threshold=0.05)
    assert r.threshold == 0.05 and np.array_equal(r.mask, r.score > 0.05)


def test_bad_input(rng):
    with pytest.raises(PointCloudError):
        C.surface_variation(np.zeros((0, 3)))
    with pytest.raises(PointCloudError):
        C.angle_gap(rng.normal(size=(10, 3)))
    with pytest.raises(InvalidParameterError):
        C.normal_variation(rng.normal(size=(100, 3)), k=2)
    with pytest.raises(InvalidParameterError):
        C.run_method("nope", rng.normal(size=(100, 3)))
    with pytest.raises(InvalidParameterError):
        C.angle_gap(rng.normal(size=(100, 3)), threshold=10.0)
