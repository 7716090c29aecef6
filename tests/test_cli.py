"""The pcprep command line: info, filters, per-filter commands, errors."""

import subprocess
import sys

import numpy as np
import pytest

from pcprep.meshlab_bridge import registry
from pcprep.meshlab_bridge.cli import main
from pcprep.meshlab_bridge.convert import Cloud, load_cloud, save_cloud
from helpers import sphere_points
from helpers import SPECS


@pytest.fixture
def specs():
    registry.load_all()
    for s in SPECS.values():
        registry.register(s)
    yield
    for s in SPECS.values():
        registry.FILTERS.pop(s.name, None)


@pytest.fixture
def cloud_file(tmp_path):
    path = tmp_path / "in.ply"
    save_cloud(Cloud(sphere_points(800) * 5.0 + 100.0), str(path))
    return path


def test_info_reports_count_spacing_and_box(cloud_file, capsys):
    assert main(["info", str(cloud_file)]) == 0
    out = capsys.readouterr().out
    assert "points: 800" in out
    h = float(out.split("isolated points left out): ")[1].split()[0])
    assert 0.3 < h < 1.0
    assert "bounding box min: 95" in out


def test_filter_command_writes_every_point_in_order(specs, cloud_file, tmp_path):
    out = tmp_path / "out.ply"
    assert main(["_test_selection", str(cloud_file), str(out), "--k", "8", "--quiet"]) == 0
    got = load_cloud(str(out))
    src = load_cloud(str(cloud_file))
    assert np.array_equal(got.points, src.points)
    assert set(np.unique(got.quality)) <= {0.0, 1.0}
    assert np.array_equal(got.quality == 1.0, src.points[:, 2] > 0.5)


def test_new_layer_command_writes_kept_points(specs, cloud_file, tmp_path):
    out = tmp_path / "kept.ply"
    assert main(["_test_new_layer", str(cloud_file), str(out), "--quiet"]) == 0
    src = load_cloud(str(cloud_file)).points
    assert np.array_equal(load_cloud(str(out)).points, src[src[:, 2] > 0.5])


@pytest.mark.parametrize(
    "args, message",
    [
        (["--k", "1000"], "k must be in [4, 64]"),
        (["--k", "abc"], "invalid int value"),
    ],
)
def test_bad_parameters_fail_cleanly_without_output(specs, cloud_file, tmp_path, capfd, args, message):
    out = tmp_path / "o.ply"
    code = None
    try:
        code = main(["_test_coord", str(cloud_file), str(out), *args])
    except SystemExit as exc:  # argparse type errors
        code = exc.code
    assert code not in (0, None)
    err = capfd.readouterr().err
    assert message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_bad_input_files_fail_cleanly_without_output(specs, tmp_path, capsys):
    out = tmp_path / "o.ply"
    assert main(["_test_coord", str(tmp_path / "nope.ply"), str(out)]) == 1
    assert "no such file" in capsys.readouterr().err
    nan = tmp_path / "nan.xyz"
    pts = sphere_points(100)
    pts[3] = np.nan
    np.savetxt(nan, pts)
    assert main(["_test_coord", str(nan), str(out)]) == 1
    assert not out.exists()


def test_filters_listing_and_help_come_from_the_registry(specs, capsys):
    assert main(["filters"]) == 0
    out = capsys.readouterr().out
    assert "pcprep _test_coord  ->  _test_coord" in out
    with pytest.raises(SystemExit) as exc:
        main(["_test_coord", "--help"])
    assert exc.value.code == 0
    assert "normals [count]" in capsys.readouterr().out


def test_console_entry_point_runs_as_a_module(cloud_file):
    proc = subprocess.run([sys.executable, "-m", "pcprep.meshlab_bridge.cli", "info", str(cloud_file)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "points: 800" in proc.stdout


def test_scalar_command_writes_quality_and_colour_ramp(specs, tmp_path):
    src = sphere_points(500)
    save_cloud(Cloud(src), str(tmp_path / "unit.ply"))
    out = tmp_path / "s.ply"
    assert main(["_test_scalar", str(tmp_path / "unit.ply"), str(out), "--quiet"]) == 0
    got = load_cloud(str(out))
    hi, lo = np.argmax(src[:, 2]), np.argmin(src[:, 2])
    assert got.quality[hi] > got.quality[lo]
    assert not np.allclose(got.colors[hi], got.colors[lo])


def test_a_truncated_laz_is_reported_once_by_name(tmp_path):
    good, bad = tmp_path / "good.laz", tmp_path / "bad.laz"
    save_cloud(Cloud(sphere_points(200) * 5.0 + [4.5e5, 5.2e6, 100.0]), str(good))
    bad.write_bytes(good.read_bytes()[:-13])
    out = tmp_path / "o.laz"
    proc = subprocess.run([sys.executable, "-m", "pcprep.meshlab_bridge.cli", "outliers",
                           str(bad), str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1 and not out.exists()
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "bad.laz" in lines[0] and "truncated" in lines[0], lines
