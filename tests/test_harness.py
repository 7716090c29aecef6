"""Tests of baselines/harness.py: isolation, crash/exception/timeout capture,
tables and atomic reports."""

from __future__ import annotations

import json
import math
import os
import signal
import time

import numpy as np
import pytest

from pcprep.baselines import harness
from pcprep.baselines.harness import Outcome, markdown_table, run_isolated, write_report


# --- module-level functions run in the child --------------------------------------------

def _double(x, *, offset=0.0):
    return 2.0 * x + offset


def _segfault():
    os.kill(os.getpid(), signal.SIGSEGV)


def _raise():
    raise ValueError("bad input 42")


def _sleep(seconds):
    time.sleep(seconds)
    return "woke"


def _exit3():
    os._exit(3)


def _alloc(mb):
    a = np.ones(int(mb * 2 ** 20 // 8))
    return float(a.sum())


_STATE: dict = {}


def _parent_marker():
    return dict(_STATE), os.getpid()


# --- run_isolated ---------------------------------------------------------------------

def test_returns_value_args_and_kwargs():
    x = np.random.default_rng(0).normal(size=(1000, 3))
    out = run_isolated(_double, x, offset=1.5)
    assert out.ok and out.error is None
    np.testing.assert_array_equal(out.value, 2.0 * x + 1.5)
    assert math.isfinite(out.seconds) and out.seconds >= 0
    assert out.peak_mb > 10 and out.start_mb <= out.peak_mb


def test_runs_in_a_fresh_process():
    _STATE["parent"] = 1
    out = run_isolated(_parent_marker)
    assert out.ok
    state, pid = out.value
    assert pid != os.getpid()
    assert state == {}  # spawn: the module is imported afresh, parent state not inherited


def test_large_array_round_trip():
    x = np.random.default_rng(1).random((1_000_000, 3))
    out = run_isolated(_double, x)
    assert out.ok
    np.testing.assert_array_equal(out.value, 2.0 * x)


def test_segfault_is_recorded_not_raised():
    out = run_isolated(_segfault)
    assert not out.ok and out.value is None
    assert out.error == "crashed: signal 11 (SIGSEGV)"
    assert math.isnan(out.seconds)
    # the harness is still usable after a crash
    assert run_isolated(_double, 1.0).value == 2.0


def test_exception_is_recorded():
    out = run_isolated(_raise)
    assert not out.ok
    assert out.error == "ValueError: bad input 42"
    assert math.isfinite(out.seconds)


def test_timeout_kills_child():
    t0 = time.perf_counter()
    out = run_isolated(_sleep, 60, timeout=2)
    assert not out.ok and out.error == "timeout after 2s"
    assert time.perf_counter() - t0 < 30


def test_exit_without_result():
    out = run_isolated(_exit3)
    assert not out.ok and out.error.startswith("exited with code 3")


def test_seconds_measured_inside_child():
    out = run_isolated(_sleep, 0.3)
    assert out.ok and out.value == "woke"
    assert 0.29 <= out.seconds < 5  # the sleep alone, no interpreter start (~0.2 s+)


def test_peak_memory_sees_allocation():
    small = run_isolated(_alloc, 1)
    big = run_isolated(_alloc, 300)
    assert small.ok and big.ok
    assert big.peak_mb - small.peak_mb > 250


def test_peak_memory_not_inherited_from_parent():
    ballast = np.ones(400 * 2 ** 20 // 8)  # 400 MB held by the parent
    out = run_isolated(_alloc, 1)
    assert out.ok and out.peak_mb < 300 < ballast.nbytes / 2 ** 20


def test_knn_pass_seconds():
    x = np.random.default_rng(2).random((2000, 3))
    s = harness.knn_pass_seconds(x, k=16)
    assert isinstance(s, float) and s.ok and s.outcome.value == 2000
    assert 0 < s == s.seconds and s.peak_mb > 0


def test_measure_is_run_isolated():
    out = harness.measure(_raise)
    assert not out.ok and out.error.startswith("ValueError")


# --- markdown_table -------------------------------------------------------------------

def _rows(md):
    lines = md.strip().splitlines()[2:]
    return [[c.strip() for c in line.strip("|").split("|")] for line in lines]


def test_table_bolds_best_per_row():
    md = markdown_table(["data", "ours", "meshlab", "cgal"],
                        [["cube", 0.5, 0.25, 1.0], ["star", 3.0, 2.0, 1.5]],
                        best={1: "min", 2: "min", 3: "min"})
    rows = _rows(md)
    assert rows[0] == ["cube", "0.5", "**0.25**", "1"]
    assert rows[1] == ["star", "3", "2", "**1.5**"]
    md = markdown_table(["d", "a", "b"], [["x", 0.9, 0.95]], best={1: "max", 2: "max"})
    assert _rows(md)[0] == ["x", "0.9", "**0.95**"]


def test_table_only_compares_given_columns_and_ties():
    md = markdown_table(["n", "a", "b"], [[100000, 7.0, 7.0]], best={1: "min", 2: "min"})
    assert _rows(md)[0] == ["100000", "**7**", "**7**"]  # ints in full; ties all bold


def test_table_shows_failures_never_bold():
    crash = Outcome(False, None, "crashed: signal 11 (SIGSEGV)", math.nan, math.nan)
    good = Outcome(True, 2.0, None, 0.1, 50.0)
    md = markdown_table(["d", "a", "b", "c", "e"],
                        [["x", crash, good, "failed: no normals", None]],
                        best={1: "min", 2: "min", 3: "min", 4: "min"})
    row = _rows(md)[0]
    assert row == ["x", "crashed: signal 11 (SIGSEGV)", "**2**", "failed: no normals",
                   "n/a"]
    assert all(cell for cell in row)


def test_table_escapes_pipes_and_rejects_bad_spec():
    md = markdown_table(["a"], [["x|y"]])
    assert "x\\|y" in md
    with pytest.raises(ValueError):
        markdown_table(["a", "b"], [[1, 2]], best={1: "best"})
    with pytest.raises(ValueError):
        markdown_table(["a", "b"], [[1]])


# --- write_report ---------------------------------------------------------------------

def test_write_report_json_safe(tmp_path):
    data = {"n": np.int64(5), "t": np.float32(0.5), "arr": np.arange(3), "nan": math.nan,
            "ok": np.bool_(True), 3: (1, 2),
            "out": Outcome(True, np.zeros(4), None, 1.0, 2.0)}
    md, js = write_report("r1", "# title", data, out_dir=tmp_path)
    assert md.read_text() == "# title\n"
    loaded = json.loads(js.read_text())
    assert loaded["n"] == 5 and loaded["arr"] == [0, 1, 2] and loaded["nan"] is None
    assert loaded["ok"] is True and loaded["3"] == [1, 2]
    assert loaded["out"]["ok"] is True and loaded["out"]["seconds"] == 1.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r1.json", "r1.md"]


def test_write_report_failure_keeps_old_files(tmp_path):
    write_report("r2", "old", {"v": 1}, out_dir=tmp_path)
    loop: list = []
    loop.append(loop)
    with pytest.raises((ValueError, RecursionError)):
        write_report("r2", "new", {"v": loop}, out_dir=tmp_path)
    assert (tmp_path / "r2.md").read_text() == "old\n"
    assert json.loads((tmp_path / "r2.json").read_text()) == {"v": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r2.json", "r2.md"]


def test_environment_info():
    env = harness.environment_info()
    assert env["cpu_count"] >= 1 and env["python"].count(".") == 2
    assert set(env["versions"]) >= {"numpy", "scipy", "scikit-learn", "pymeshlab", "cgal",
                                     "matplotlib"}
    assert env["versions"]["numpy"] == np.__version__
    json.dumps(harness.to_jsonable(env), allow_nan=False)


def test_single_node_speed_times_every_filter_against_one_knn_pass(tmp_path, monkeypatch):
    """``pcprep bench scale --speed``: one row per filter, each timed in its own
    process, its ratio the one to the 16-NN pass of the same run, both files
    written."""
    from pcprep.baselines import bench_scale

    monkeypatch.setattr(bench_scale, "QUICK_SIZES", (4000,))
    monkeypatch.setattr(bench_scale, "FILTERS", ("outliers", "simplify"))
    monkeypatch.setattr(bench_scale, "WARM_POINTS", 1000)
    out = bench_scale.run_speed(quick=True, out_dir=str(tmp_path))
    assert out["n"] == 4000 and out["knn16_s"] > 0
    assert [r["filter"] for r in out["rows"]] == ["outliers", "simplify"]
    # one pass before each filter and one at the end; the yardstick is their median
    assert len(out["knn16_passes_s"]) == 3
    assert out["knn16_s"] == pytest.approx(float(np.median(out["knn16_passes_s"])))
    for r in out["rows"]:
        assert r["ok"], r["error"]
        assert len(r["runs_s"]) == bench_scale.SPEED_REPEATS
        assert r["seconds"] == pytest.approx(float(np.median(r["runs_s"])))
        assert r["peak_mb"] > 0
        assert r["x_knn16"] == pytest.approx(r["seconds"] / out["knn16_s"])
    md = (tmp_path / "speed_scale.md").read_text()
    assert "| outliers |" in md and "| simplify |" in md
    assert json.loads((tmp_path / "speed_scale.json").read_text())["n"] == 4000


def test_scale_rows_are_the_median_run_and_the_speedup_the_ratio_of_medians():
    from pcprep.baselines import bench_scale

    one = [{"wall_s": w, "tag": i} for i, w in enumerate((9.0, 7.0, 8.0))]
    two = [{"wall_s": w, "tag": i} for i, w in enumerate((4.0, 5.0, 4.5))]
    m1, m2 = bench_scale._median_run(one), bench_scale._median_run(two)
    assert (m1["tag"], m1["wall_s"], m1["runs_wall_s"]) == (2, 8.0, [9.0, 7.0, 8.0])
    assert (m2["tag"], m2["wall_s"]) == (2, 4.5)
    s = {"speedup_2": m1["wall_s"] / m2["wall_s"],
         "speedup_2_pairs": [a / b for a, b in zip(m1["runs_wall_s"], m2["runs_wall_s"])]}
    assert bench_scale._speedup_text(s) == "1.78 (1.40–2.25)"
    assert bench_scale._speedup_text({"speedup_2": 1.5, "speedup_2_pairs": [1.5]}) == "1.50"


def test_scale_projection_is_amdahl_and_the_driver_bound_adds_its_pass_cpu():
    """T(P) = S·(10⁹/n) + (W − S)·(10⁹/n)/P; the driver-bound variant counts
    the driver's CPU seconds in the passes as serial too."""
    from pcprep.baselines.bench_scale import _project

    row = {"n": 1_000_000, "wall_s": 100.0, "serial_s": 10.0, "pass_cpu_s": 5.0}
    assert _project(row, 1) == pytest.approx(100.0 * 1000)
    assert _project(row, 10) == pytest.approx((10.0 + 90.0 / 10) * 1000)
    bound = _project(row, 10, driver_bound=True)
    assert bound == pytest.approx((15.0 + 85.0 / 10) * 1000)
    assert _project(row, 10**9) < _project(row, 10**9, driver_bound=True)
