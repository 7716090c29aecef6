"""MeshSet conversion and apply_filter, on a tiny filter declared here, plus
contract tests over every registered filter."""

import numpy as np
import pymeshlab
import pytest

from pcprep import InvalidParameterError, PointCloudError
from pcprep.meshlab_bridge import registry
from pcprep.meshlab_bridge.apply import apply_filter, filter_list, filter_parameter_text
from pcprep.meshlab_bridge.convert import Cloud, cloud_to_mesh, mesh_to_cloud, save_cloud, load_cloud
from helpers import SPECS, sphere_points


# --- conversion ----------------------------------------------------------------------

def _full_cloud(n=200, seed=0):
    g = np.random.default_rng(seed)
    pts = g.normal(size=(n, 3)) * 1e3 + 1e6  # UTM-like offsets
    nrm = g.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    col = g.random((n, 4))
    q = g.normal(size=n)
    return Cloud(pts, nrm, col, q, None, {"intensity": g.random(n)}, label="scan")


def test_mesh_round_trip_is_bit_exact():
    c = _full_cloud()
    back = mesh_to_cloud(cloud_to_mesh(c), attributes=("intensity",))
    assert np.array_equal(back.points, c.points)
    assert np.array_equal(back.normals, c.normals)
    assert np.array_equal(back.quality, c.quality)
    assert np.allclose(back.colors, c.colors, atol=1 / 255)  # MeshLab stores 8-bit colour
    assert np.array_equal(back.attributes["intensity"], c.attributes["intensity"])


def test_zero_normals_count_as_absent():
    m = pymeshlab.Mesh(vertex_matrix=sphere_points(50))
    assert mesh_to_cloud(m).normals is None


def test_ply_file_round_trip_keeps_precision(tmp_path):
    c = _full_cloud()
    path = tmp_path / "x.ply"
    save_cloud(c.with_(attributes={}), str(path))
    back = load_cloud(str(path))
    assert np.array_equal(back.points, c.points)
    assert np.allclose(back.normals, c.normals, atol=1e-6)
    assert np.allclose(back.quality, c.quality, atol=1e-6)


def test_unreadable_and_truncated_files_are_named(tmp_path):
    with pytest.raises(PointCloudError, match="no such file"):
        load_cloud(str(tmp_path / "missing.ply"))
    c = _full_cloud()
    good = tmp_path / "good.ply"
    save_cloud(c.with_(attributes={}), str(good))
    bad = tmp_path / "bad.ply"
    bad.write_bytes(good.read_bytes()[:700])
    with pytest.raises(PointCloudError, match="bad.ply"):
        load_cloud(str(bad))
    junk = tmp_path / "junk.ply"
    junk.write_text("this is not a ply file\n")
    with pytest.raises(PointCloudError, match="junk.ply"):
        load_cloud(str(junk))


def test_save_refuses_formats_that_lose_required_attributes(tmp_path):
    c = _full_cloud()
    out = tmp_path / "y.obj"
    with pytest.raises(PointCloudError, match="quality"):
        save_cloud(c.with_(attributes={}), str(out), require=("quality",))
    assert not out.exists()
    assert not list(tmp_path.iterdir())  # no temporary file left behind


# --- apply_filter on filters declared in helpers.py ---------------------------------

@pytest.fixture
def test_specs():
    registry.load_all()
    for s in SPECS.values():
        registry.register(s)
    yield SPECS
    for s in SPECS.values():
        registry.FILTERS.pop(s.name, None)


def _meshset(pts, quality=None):
    ms = pymeshlab.MeshSet()
    kw = {"vertex_matrix": pts}
    if quality is not None:
        kw["v_scalar_array"] = quality
    ms.add_mesh(pymeshlab.Mesh(**kw), "scan")
    return ms


def test_coord_filter_replaces_positions_and_selects_mask(test_specs):
    pts = sphere_points(600)
    ms = _meshset(pts, quality=np.full(600, 7.0))
    out = apply_filter(ms, "_test_coord", k=10)
    m = ms.current_mesh()
    assert ms.mesh_number() == 1 and m.label() == "scan"
    assert np.array_equal(m.vertex_matrix(), 2.0 * pts)
    sel = m.vertex_selection_array()
    assert np.array_equal(sel, pts[:, 2] > 0.5)
    assert out["selected"] == int((pts[:, 2] > 0.5).sum())
    assert np.array_equal(m.vertex_custom_scalar_attribute_array("quality_before"), np.full(600, 7.0))


def test_selection_filter_with_empty_mask_selects_nothing(test_specs):
    pts = sphere_points(300) * [1, 1, 0.1]  # z never exceeds 0.5
    ms = _meshset(pts)
    apply_filter(ms, "_test_selection")
    assert ms.current_mesh().selected_vertex_number() == 0
    assert np.allclose(ms.current_mesh().vertex_custom_scalar_attribute_array("score"),
                       np.clip(pts[:, 2], 0, 1))


def test_scalar_filter_writes_quality_and_colour_ramp(test_specs):
    pts = sphere_points(400)
    ms = _meshset(pts)
    apply_filter(ms, "_test_scalar")
    m = ms.current_mesh()
    assert np.allclose(m.vertex_scalar_array(), np.clip(pts[:, 2], 0, 1))
    col = m.vertex_color_matrix()
    hi, lo = np.argmax(pts[:, 2]), np.argmin(pts[:, 2])
    assert not np.allclose(col[hi], col[lo])


def test_new_layer_filter_adds_current_layer_with_kept_points(test_specs):
    pts = sphere_points(500)
    ms = _meshset(pts, quality=np.arange(500.0))
    out = apply_filter(ms, "_test_new_layer")
    assert ms.mesh_number() == 2 and out["mesh_id"] == ms.current_mesh_id()
    keep = np.flatnonzero(pts[:, 2] > 0.5)
    assert np.array_equal(ms.current_mesh().vertex_matrix(), pts[keep])
    assert np.array_equal(ms.current_mesh().vertex_scalar_array(), keep.astype(float))
    assert np.array_equal(ms.mesh(0).vertex_matrix(), pts)  # the input layer is untouched


def test_apply_filter_validates_before_touching_the_meshset(test_specs):
    pts = sphere_points(300)
    ms = _meshset(pts)
    with pytest.raises(InvalidParameterError, match="k must be in"):
        apply_filter(ms, "_test_coord", k=1000)
    with pytest.raises(InvalidParameterError, match="unknown parameter"):
        apply_filter(ms, "_test_coord", kk=3)
    assert ms.mesh_number() == 1 and np.array_equal(ms.current_mesh().vertex_matrix(), pts)
    with pytest.raises(InvalidParameterError, match="unknown filter"):
        apply_filter(ms, "no_such_filter")


def test_parameter_text_lists_units_and_ranges(test_specs):
    text = filter_parameter_text("_test_coord")
    assert "k : int = 12 [count] range [4, 64]" in text
    assert "_test_coord" in filter_list()


def test_xyz_round_trip_is_full_precision_and_rejects_nan_rows(tmp_path):
    c = _full_cloud()
    path = tmp_path / "c.xyz"
    save_cloud(c.with_(colors=None, quality=None, attributes={}), str(path))
    back = load_cloud(str(path))
    assert np.array_equal(back.points, c.points) and np.array_equal(back.normals, c.normals)
    bad = tmp_path / "nan.xyz"
    bad.write_text("0 0 0\nnan 1 2\n1 1 1\n")
    with pytest.raises(PointCloudError, match=r"1 row\(s\) hold NaN or Inf.*rows 1\)"):
        load_cloud(str(bad))
    back = load_cloud(str(bad), nonfinite="drop")
    assert len(back) == 2 and list(back.meta["dropped_rows"]) == [1]


def test_e57_round_trip_and_float32_guard(tmp_path):
    pts = sphere_points(300)
    path = tmp_path / "c.e57"
    save_cloud(Cloud(pts), str(path))
    assert np.allclose(load_cloud(str(path)).points, pts, rtol=0, atol=1e-6)
    far = tmp_path / "far.e57"
    with pytest.raises(PointCloudError, match="float32"):
        save_cloud(Cloud(pts + 1e6), str(far))
    assert not far.exists()


def test_written_files_get_normal_permissions(tmp_path):
    import os

    save_cloud(Cloud(sphere_points(50)), str(tmp_path / "p.ply"))
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "p.ply").stat().st_mode & 0o777 == 0o666 & ~mask


def test_quality_ramp_equals_meshlabs_bit_for_bit():
    # the NumPy ramp against MeshLab's own filter on the same values: the
    # quarter ends and their float neighbours, ±0, values outside [0, 1], and
    # a dense random sample (8-bit truncation of single-precision blends)
    from pcprep.meshlab_bridge.convert import quality_ramp

    g = np.random.default_rng(4)
    ends = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
    q = np.concatenate([ends, np.nextafter(ends, -1), np.nextafter(ends, 2),
                        np.nextafter(np.float32(ends), np.float32(2)).astype(float),
                        [-0.0, -1e-300, -3.0, 7.5, 1e30, -1e30],
                        g.random(200_000), g.uniform(-0.2, 1.2, 20_000),
                        np.linspace(0.0, 1.0, 4097)])
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.c_[np.arange(len(q)), np.zeros((len(q), 2))],
                               v_scalar_array=q))
    ms.compute_color_from_scalar_per_vertex(minval=0.0, maxval=1.0)
    ref = ms.current_mesh().vertex_color_matrix()
    got = quality_ramp(q)
    assert got.shape == ref.shape == (len(q), 4)
    assert np.array_equal(got, ref)
    assert len(np.unique(got, axis=0)) > 1000  # the blends, not a few plain colours
