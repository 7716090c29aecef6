"""Property-based robustness suite: corrupt files, odd clouds and odd parameter
values for every registered filter.  Each case must end in a result that is
whole (every row, finite) or in one of pcprep's own errors naming the problem;
never another exception, a dropped row or a partly written file."""

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcprep import InvalidParameterError, PointCloudError
from pcprep.baselines.bench_robustness import odd_cloud
from pcprep.meshlab_bridge import formats, registry
from pcprep.meshlab_bridge.cloud import Cloud

SPECS = sorted(registry.load_all().values(), key=lambda s: s.name)
CLEAN = (PointCloudError, InvalidParameterError)
FAST = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])

# --- files ---------------------------------------------------------------------------

_ROWS = st.lists(st.tuples(*[st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from(["abc", "", "1e999", "-0", "0x1"]))] * 3), min_size=0, max_size=8)


def _cell(v):
    return v if isinstance(v, str) else repr(float(v))


def _text_file(ext, rows, declared):
    body = "\n".join(" ".join(_cell(v) for v in r) for r in rows)
    if ext == ".xyz":
        return body + "\n"
    if ext == ".obj":
        return "".join(f"v {' '.join(_cell(v) for v in r)}\n" for r in rows)
    if ext == ".off":
        return f"OFF\n{declared} 0 0\n{body}\n"
    if ext == ".ply":
        return ("ply\nformat ascii 1.0\n"
                f"element vertex {declared}\nproperty double x\nproperty double y\n"
                f"property double z\nend_header\n{body}\n")
    return ("VERSION 0.7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {declared}\nHEIGHT 1\nPOINTS {declared}\nDATA ascii\n{body}\n")


def _valid(rows):
    try:
        arr = np.array([[float(v) for v in r] for r in rows], dtype=np.float64)
    except ValueError:
        return None
    return arr if len(arr) and np.isfinite(arr).all() else None


@FAST
@given(ext=st.sampled_from([".xyz", ".obj", ".off", ".ply", ".pcd"]), rows=_ROWS,
       extra=st.integers(-2, 2))
def test_a_corrupt_text_file_is_read_whole_or_refused(tmp_path_factory, ext, rows, extra):
    folder = tmp_path_factory.mktemp("f")
    path = folder / f"c{ext}"
    declared = max(len(rows) + extra, 0)
    path.write_text(_text_file(ext, rows, declared))
    try:
        cloud = formats.read_cloud(path)
    except CLEAN:
        return
    want = _valid(rows)
    assert want is not None  # nothing non-finite or unparsable was accepted
    if ext in (".off", ".ply", ".pcd"):
        assert declared == len(rows)  # nor a header that disagrees with the data
    assert np.array_equal(cloud.points, want)


@FAST
@given(cut=st.integers(0, 400), junk=st.binary(max_size=40))
def test_a_truncated_or_padded_binary_ply_is_refused(tmp_path_factory, cut, junk):
    folder = tmp_path_factory.mktemp("b")
    pts = np.random.default_rng(0).normal(size=(20, 3))
    good = folder / "g.ply"
    formats.write_cloud(Cloud(pts), good)
    data = good.read_bytes()
    bad = folder / "b.ply"
    bad.write_bytes(data[:len(data) - cut] + (junk if cut == 0 else b""))
    try:
        cloud = formats.read_cloud(bad)
    except CLEAN:
        return
    assert np.array_equal(cloud.points, pts)  # only an intact file reads


# --- clouds and parameters -----------------------------------------------------------

def _odd_cloud(kind, n, scale, offset, seed):
    return odd_cloud(kind, n, scale, offset, np.random.default_rng(seed))


def _example(spec):
    return dict(spec.example)


@pytest.mark.parametrize("spec", SPECS, ids=[s.command for s in SPECS])
@settings(max_examples=6, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(kind=st.sampled_from(["sphere", "plane", "line", "clusters", "duplicates"]),
       n=st.sampled_from([3, 40, 400]), scale=st.sampled_from([1e-6, 1.0, 1e6]),
       offset=st.sampled_from([0.0, 5e6]), seed=st.integers(0, 3))
def test_odd_clouds_give_a_whole_result_or_a_clean_error(spec, kind, n, scale, offset, seed):
    pts = _odd_cloud(kind, n, scale, offset, seed)
    before = pts.copy()
    try:
        res = spec.func(pts, **_example(spec))
    except CLEAN:
        return
    assert np.array_equal(pts, before)
    for field in (spec.points_field if spec.kind == "coord" else None, spec.mask_field,
                  spec.scalar_field):
        if field:
            arr = np.asarray(getattr(res, field))
            assert len(arr) == n and (arr.dtype == bool or np.isfinite(arr).all()), field
    if spec.index_field:
        idx = np.asarray(getattr(res, spec.index_field))
        assert len(np.unique(idx)) == len(idx) and (idx >= 0).all() and (idx < n).all()


def _values(p):
    odd = st.sampled_from([None, True, False, "3", float("nan"), float("inf"), -1e300,
                           1e-300, 0, -1, 10**12, 2.5])
    if p.choices:
        return st.one_of(st.sampled_from(p.choices), odd)
    lo = -1e6 if p.low is None else p.low
    hi = 1e6 if p.high is None else p.high
    inside = st.floats(lo, hi, allow_nan=False) if p.kind is float else \
        st.integers(int(np.ceil(lo)), int(min(hi, lo + 64)))
    return st.one_of(inside, odd)


@pytest.mark.parametrize("spec", SPECS, ids=[s.command for s in SPECS])
@settings(max_examples=12, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_odd_parameters_run_or_are_refused_by_name(spec, data):
    p = data.draw(st.sampled_from(spec.params))
    value = data.draw(_values(p))
    pts = _odd_cloud("sphere", 300, 1.0, 0.0, 0)
    kw = {**_example(spec), p.name: value}
    try:
        spec.resolve(kw)
    except InvalidParameterError as exc:
        assert p.name in str(exc)
        return
    try:
        res = spec.func(pts, **kw)
    except InvalidParameterError as exc:
        # a value inside its declared range must not fail deep inside with an
        # internal function's message: the filter names its own parameter
        assert str(exc).startswith(spec.func.__name__), str(exc)
        return
    except PointCloudError as exc:
        assert str(exc)
        return
    assert res is not None


def test_no_temporary_file_is_left_when_a_write_fails(tmp_path):
    bad = Cloud(np.zeros((3, 3)), attributes={"obj": np.array(["a", "b", "c"], dtype=object)})
    with pytest.raises(CLEAN + (TypeError, ValueError)):
        formats.write_cloud(bad, tmp_path / "x.las")
    assert os.listdir(tmp_path) == []
