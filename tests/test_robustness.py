"""Regression tests for silently wrong answers: one far outlier must not move h,
the unit of every length; a second copy of the cloud far away must not change
the first copy's result."""

import numpy as np
import pytest

import pcprep
from pcprep.baselines.datasets import add_noise, make_shape
from pcprep.filters.neighbors import average_spacing


@pytest.fixture(scope="module")
def noisy_fandisk():
    s = make_shape("fandisk", n=6000, seed=0)
    return s, add_noise(s.points, s.normals, sigma=0.2, h=s.h, kind="normal", seed=1)


def test_one_far_outlier_does_not_move_h():
    cube = make_shape("cube", n=3000, seed=0).points
    far = np.r_[cube, [[1e9, 0.0, 0.0]]]
    assert average_spacing(far) == pytest.approx(average_spacing(cube), rel=1e-9)
    assert average_spacing(cube) == pytest.approx(0.0434, abs=1e-4)


def test_every_filter_keeps_its_unit_with_a_far_outlier():
    s = make_shape("cube", n=3000, seed=0)
    far = np.r_[s.points, [[1e9, 0.0, 0.0]]]
    base = pcprep.detect_sharp_features(s.points).mask
    with_outlier = pcprep.detect_sharp_features(far).mask[:-1]
    inter = np.count_nonzero(base & with_outlier)
    assert inter / max(np.count_nonzero(base | with_outlier), 1) > 0.95
    sal0 = pcprep.saliency_sparse_mdl(s.points).saliency
    sal1 = pcprep.saliency_sparse_mdl(far).saliency[:-1]
    assert np.corrcoef(sal0, sal1)[0, 1] > 0.99


@pytest.mark.parametrize("offset", [1e6, 1e7])
def test_denoise_error_does_not_depend_on_a_far_copy(noisy_fandisk, offset):
    s, noisy = noisy_fandisk
    alone = pcprep.denoise_l1_tv(noisy)
    e_alone = np.linalg.norm(alone.points - s.points, axis=1).mean() / s.h
    two = pcprep.denoise_l1_tv(np.r_[noisy, noisy + [offset, 0.0, 0.0]])
    e_two = np.linalg.norm(two.points[:len(noisy)] - s.points, axis=1).mean() / s.h
    assert e_alone < 0.1 and abs(e_two - e_alone) < 0.01 * e_alone


def test_info_reports_the_isolated_points(tmp_path, capsys):
    from pcprep.meshlab_bridge.cli import main
    from pcprep.meshlab_bridge.convert import Cloud, save_cloud

    cube = make_shape("cube", n=3000, seed=0).points
    save_cloud(Cloud(np.r_[cube, [[1e9, 0.0, 0.0], [0.0, 5.0, 0.0]]]), str(tmp_path / "c.ply"))
    assert main(["info", str(tmp_path / "c.ply")]) == 0
    out = capsys.readouterr().out
    assert "pcprep outliers removes them): 2" in out
    assert f"left out): {average_spacing(cube):.6g}" in out


def test_bench_and_report_check_their_folder_before_any_work(tmp_path, capsys):
    from pcprep.meshlab_bridge.cli import main

    afile = tmp_path / "file"
    afile.write_text("x")
    for cmd in (["bench", "denoise", "--quick"], ["report", "--quick"]):
        assert main([*cmd, "--out", str(afile)]) == 1
        assert "is a file" in capsys.readouterr().err
        assert main([*cmd, "--out", str(afile / "sub")]) == 1
        assert "cannot create" in capsys.readouterr().err


def test_an_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    from pcprep.meshlab_bridge import formats
    from pcprep.meshlab_bridge.cloud import Cloud
    from pcprep.meshlab_bridge.formats import ply

    def interrupted(cloud, path):
        with open(path, "wb") as f:
            f.write(b"partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(ply, "write", interrupted)
    with pytest.raises(KeyboardInterrupt):
        formats.write_cloud(Cloud(np.eye(3)), tmp_path / "x.ply")
    assert list(tmp_path.iterdir()) == []


def test_the_robustness_bench_finds_no_wrong_answer_in_files_or_destinations():
    from pcprep.baselines.bench_robustness import _destinations, _files

    for key, counts in {**_files(0), **_destinations()}.items():
        assert counts.get("wrong", 0) == 0 and counts.get("crashed", 0) == 0, key
