import numpy as np
import pytest

from pcprep.filters import (InvalidParameterError, Param, PointCloudError, as_normals,
                            as_points, check_spread, resolve_params)

PARAMS = (
    Param("sigma_d", float, low=0.0, high=20.0, closed="right", unit="h", default=3.0, help="support radius"),
    Param("n_iter", int, low=1, high=100, unit="count", default=10, help="iterations"),
    Param("mode", str, choices=("a", "b"), default="a", help="mode"),
    Param("flag", bool, default=False, help="a flag"),
    Param("count", int, low=1, optional=True, default=None, help="target count"),
)


def test_as_points_copies_and_never_aliases():
    x = np.arange(12.0).reshape(4, 3)
    y = as_points(x, func="f")
    y[0, 0] = 99
    assert x[0, 0] == 0


@pytest.mark.parametrize(
    "bad, message",
    [
        (np.zeros((0, 3)), "empty"),
        (np.zeros((4, 2)), "shape"),
        (np.array([[0, 0, np.nan]] * 4), "NaN or Inf"),
        (np.array([[0, 0, np.inf]] * 4), "NaN or Inf"),
        ("not numbers", "numeric"),
    ],
)
def test_as_points_rejects_bad_clouds(bad, message):
    with pytest.raises(PointCloudError, match=message):
        as_points(bad, func="denoise_l1_tv")


def test_as_points_counts_points_for_the_neighbourhood():
    with pytest.raises(PointCloudError, match="at least 16 points"):
        as_points(np.zeros((5, 3)), func="f", min_points=16)


def test_as_normals_normalises_and_rejects_zero_rows():
    n = as_normals([[0, 0, 2.0], [3.0, 0, 0]], 2, func="f")
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    with pytest.raises(PointCloudError, match="zero-length"):
        as_normals([[0, 0, 0.0], [1.0, 0, 0]], 2, func="f")
    with pytest.raises(PointCloudError, match="rows"):
        as_normals([[0, 0, 1.0]], 2, func="f")


def test_check_spread_detects_degenerate_clouds():
    with pytest.raises(PointCloudError, match="coincide"):
        check_spread(np.ones((100, 3)), func="f")
    t = np.linspace(0, 1, 100)[:, None]
    with pytest.raises(PointCloudError, match="collinear"):
        check_spread(t * [1.0, 2.0, 3.0], func="f")
    check_spread(np.c_[np.random.default_rng(0).random((100, 2)), np.zeros(100)], func="f")


def test_resolve_params_fills_defaults_and_converts():
    p = resolve_params(PARAMS, {"n_iter": 5.0}, "f")
    assert p == {"sigma_d": 3.0, "n_iter": 5, "mode": "a", "flag": False, "count": None}
    assert isinstance(p["n_iter"], int)


@pytest.mark.parametrize(
    "given, message",
    [
        ({"sigma_d": -1.0}, r"sigma_d must be in \(0, 20\]"),
        ({"sigma_d": 0.0}, "sigma_d"),
        ({"sigma_d": float("nan")}, "finite"),
        ({"sigma_d": "3"}, "number"),
        ({"n_iter": 2.5}, "integer"),
        ({"n_iter": 0}, r"n_iter must be in \[1, 100\]"),
        ({"mode": "c"}, "one of 'a', 'b'"),
        ({"flag": 1}, "bool"),
        ({"bogus": 1}, "unknown parameter"),
        ({"count": 0}, "count"),
    ],
)
def test_resolve_params_names_the_problem(given, message):
    with pytest.raises(InvalidParameterError, match=message):
        resolve_params(PARAMS, given, "denoise_l1_tv")
    try:
        resolve_params(PARAMS, given, "denoise_l1_tv")
    except InvalidParameterError as exc:
        assert str(exc).startswith("denoise_l1_tv: ")
        assert isinstance(exc, ValueError) and isinstance(exc, TypeError)


def test_check_spread_names_duplicate_points():
    pts = np.random.default_rng(1).random((50, 3))
    check_spread(pts, func="f")
    pts[40] = pts[7]
    with pytest.raises(PointCloudError, match=r"1 duplicate point\(s\) \(first: rows 7 and 40\)"):
        check_spread(pts, func="f")


def test_a_bool_is_not_a_count():
    """Regression: count=True was accepted as 1 (bool is an int subclass)."""
    with pytest.raises(InvalidParameterError, match="n_iter must be an integer"):
        resolve_params(PARAMS, {"n_iter": True}, "f")
