"""pcprep.MeshSet: pcprep filters as MeshSet methods beside MeshLab's, layers that
keep their id and place, and .mlx scripts that mix both kinds of filters."""

import numpy as np
import pymeshlab
import pytest

import pcprep
from pcprep import InvalidParameterError
from pcprep.baselines.datasets import make_shape
from pcprep.meshlab_bridge.cli import main
from pcprep.meshlab_bridge.convert import Cloud, load_cloud, save_cloud


@pytest.fixture(scope="module")
def part():
    return make_shape("fandisk", n=3000, seed=0)


def _meshset(part):
    ms = pcprep.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=part.points[:50] + 10.0), "first")
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=part.points, v_normals_matrix=part.normals),
                "scan")
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=part.points[:40] - 10.0), "last")
    ms.set_current_mesh(1)
    return ms


def _layers(ms):
    return [(i, ms.mesh(i).label()) for i in range(20) if ms.mesh_id_exists(i)]


@pytest.mark.parametrize("method, kw", [
    ("apply_coord_denoise_l1_tv", {"n_iter": 1}),
    ("compute_scalar_saliency_sparse_mdl", {}),
    ("compute_selection_sharp_features_sparse", {}),
    ("compute_selection_hole_boundaries_sparse", {}),
])
def test_per_point_filters_keep_the_layer_id_label_and_place(part, method, kw):
    ms = _meshset(part)
    before = _layers(ms)
    out = getattr(ms, method)(**kw)
    assert ms.current_mesh_id() == 1 and out["mesh_id"] == 1
    assert _layers(ms) == before
    ms.set_current_mesh(0)  # the layer list is intact: other ids still work
    assert ms.current_mesh().vertex_number() == 50
    ms.set_current_mesh(1)
    assert ms.current_mesh().vertex_number() == len(part.points)


def test_coord_filter_writes_positions_and_normals_bit_exactly(part):
    ms = _meshset(part)
    ref = pcprep.denoise_l1_tv(part.points, part.normals, n_iter=1)
    ms.apply_coord_denoise_l1_tv(n_iter=1)
    m = ms.current_mesh()
    assert np.array_equal(m.vertex_matrix(), ref.points)
    assert np.array_equal(m.vertex_normal_matrix(), ref.normals)
    assert m.selected_vertex_number() == int(ref.edge_mask.sum())


def test_native_filters_and_queries_cover_both_kinds(part):
    ms = _meshset(part)
    ms.compute_normal_for_point_clouds(k=12)  # a MeshLab filter on the same object
    names = ms.filter_list()
    assert "compute_normal_for_point_clouds" in names
    assert "generate_simplified_point_cloud_sdbs" in names
    assert ms.filter_parameter_values("generate_simplified_point_cloud_sdbs")["k"] == 16
    assert "k" in ms.filter_parameter_values("compute_normal_for_point_clouds")
    out = ms.generate_simplified_point_cloud_sdbs(ratio=0.2)
    assert ms.current_mesh_id() == out["mesh_id"] and ms.mesh_number() == 4
    assert ms.current_mesh().vertex_number() == out["kept"] == 600
    assert ms.mesh(1).vertex_number() == len(part.points)  # the source layer stays


def test_previous_quality_and_attributes_are_kept(part):
    ms = pcprep.MeshSet()
    q = np.linspace(0, 1, len(part.points))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=part.points, v_scalar_array=q), "scan")
    ms.current_mesh().add_vertex_custom_scalar_attribute(np.arange(len(q), dtype=float), "tag")
    ms.compute_scalar_saliency_sparse_mdl()
    m = ms.current_mesh()
    assert np.array_equal(m.vertex_custom_scalar_attribute_array("quality_before"), q)
    assert np.array_equal(m.vertex_custom_scalar_attribute_array("tag"), np.arange(len(q)))
    ms.compute_scalar_saliency_sparse_mdl()  # again: nothing overwritten
    assert np.array_equal(m.vertex_custom_scalar_attribute_array("quality_before"), q)
    assert ms.current_mesh().vertex_custom_scalar_attribute_array("quality_before_2").max() <= 1


_SCRIPT = """<!DOCTYPE FilterScript>
<FilterScript>
 <filter name="apply_coord_denoise_l1_tv">
  <Param name="n_iter" value="1" type="RichInt"/>
 </filter>
 <filter name="Compute normals for point sets">
  <Param name="K" value="12" type="RichInt"/>
  <Param name="smoothIter" value="0" type="RichInt"/>
  <Param name="flipFlag" value="false" type="RichBool"/>
  <Param name="viewPos" x="0" y="0" z="0" type="RichPosition"/>
 </filter>
 <filter name="generate_simplified_point_cloud_sdbs">
  <Param name="ratio" value="{ratio}" type="RichFloat"/>
 </filter>
</FilterScript>
"""


def test_a_script_mixing_both_kinds_equals_the_steps_one_by_one(part, tmp_path):
    path = tmp_path / "p.mlx"
    path.write_text(_SCRIPT.format(ratio=0.25))
    scripted = _meshset(part)
    scripted.load_filter_script(str(path))
    scripted.apply_filter_script()
    by_hand = _meshset(part)
    by_hand.apply_coord_denoise_l1_tv(n_iter=1)
    by_hand.compute_normal_for_point_clouds(k=12, smoothiter=0)
    by_hand.generate_simplified_point_cloud_sdbs(ratio=0.25)
    assert np.array_equal(scripted.current_mesh().vertex_matrix(),
                          by_hand.current_mesh().vertex_matrix())
    assert np.array_equal(scripted.current_mesh().vertex_normal_matrix(),
                          by_hand.current_mesh().vertex_normal_matrix())
    # the recorded pipeline, saved and replayed, gives the same answer again
    saved = tmp_path / "saved.mlx"
    scripted.save_filter_script(str(saved))
    text = saved.read_text()
    assert text.count("<filter") == 3 and "Compute normals for point sets" in text
    replay = _meshset(part)
    replay.load_filter_script(str(saved))
    replay.apply_filter_script()
    assert np.array_equal(replay.current_mesh().vertex_matrix(),
                          by_hand.current_mesh().vertex_matrix())


@pytest.mark.parametrize("bad, match", [
    (_SCRIPT.format(ratio=7.0), "ratio"),
    (_SCRIPT.format(ratio=0.2).replace("Compute normals for point sets", "No such filter"),
     "No such filter"),
    ("<notascript/>", "not a MeshLab filter script"),
])
def test_scripts_are_checked_before_the_first_step_runs(part, tmp_path, bad, match):
    path = tmp_path / "bad.mlx"
    path.write_text(bad)
    ms = _meshset(part)
    with pytest.raises(InvalidParameterError, match=match):
        ms.load_filter_script(str(path))
    assert np.array_equal(ms.current_mesh().vertex_matrix(), part.points)


def test_cli_run_keeps_attributes_and_saves_the_pipeline(part, tmp_path):
    src = tmp_path / "in.ply"
    tag = np.arange(len(part.points), dtype=np.uint16)
    save_cloud(Cloud(part.points, part.normals, attributes={"tag": tag}), str(src))
    (tmp_path / "p.mlx").write_text(_SCRIPT.format(ratio=0.5))
    out, mlx = tmp_path / "out.ply", tmp_path / "ran.mlx"
    assert main(["run", str(tmp_path / "p.mlx"), str(src), str(out), "--save-mlx", str(mlx),
                 "--quiet"]) == 0
    got = load_cloud(str(out))
    assert len(got) == len(part.points) // 2
    assert got.attributes["tag"].dtype == np.uint16
    assert len(np.unique(got.attributes["tag"])) == len(got)
    assert mlx.read_text().count("<filter") == 3


def test_a_mesh_layer_is_saved_as_points_alone_only_when_asked(part, tmp_path, capsys):
    # a script may make or remove faces, so pcprep run checks the faces of the
    # result, not the input's; MeshSet's save refuses like the CLI, and
    # MeshLab's Remove All Faces is how a MeshSet user asks for points alone
    i = np.arange(1, len(part.points) - 1)
    fan = np.c_[np.zeros_like(i), i, i + 1]
    src = tmp_path / "mesh.ply"
    save_cloud(Cloud(part.points, faces=fan), str(src))
    denoise = _SCRIPT.split("<filter name=\"Compute")[0] + "</FilterScript>\n"
    for name, script in (("keeps.mlx", denoise), ("points.mlx", _SCRIPT.format(ratio=0.5))):
        (tmp_path / name).write_text(script)
    args = ["run", str(tmp_path / "keeps.mlx"), str(src), str(tmp_path / "out.las"), "--quiet"]
    assert main(args) == 1
    assert f"{len(fan)} faces" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keeps.mlx", "mesh.ply", "points.mlx"]
    assert main([*args, "--drop-faces"]) == 0
    assert load_cloud(str(tmp_path / "out.las")).faces is None
    # simplification makes a new layer of points: nothing to drop, no flag needed
    args[1:4] = [str(tmp_path / "points.mlx"), str(src), str(tmp_path / "simple.las")]
    assert main(args) == 0
    assert len(load_cloud(str(tmp_path / "simple.las"))) == len(part.points) // 2
    # a PLY's camera has no place in LAS: refused before the script runs
    save_cloud(Cloud(part.points, meta={"ply": {"other_elements": {"camera": _camera()}}}),
               str(tmp_path / "cam.ply"))
    args[2:4] = [str(tmp_path / "cam.ply"), str(tmp_path / "cam.las")]
    assert main(args) == 1
    assert "element(s) camera have no place" in capsys.readouterr().err
    assert main([*args, "--drop-elements"]) == 0
    ms = pcprep.MeshSet()
    ms.load_new_mesh(str(src))
    with pytest.raises(pcprep.PointCloudError, match=f"{len(fan)} faces"):
        ms.save_current_mesh(str(tmp_path / "ms.xyz"))
    ms.meshing_remove_all_faces()
    ms.save_current_mesh(str(tmp_path / "ms.xyz"))
    assert np.allclose(load_cloud(str(tmp_path / "ms.xyz")).points, part.points)


def _camera():
    from plyfile import PlyElement

    cam = np.zeros(1, dtype=[("focal", "f4")])
    cam["focal"] = 35.0
    return PlyElement.describe(cam, "camera")


def test_face_attributes_ride_through_meshlab_and_pcprep_filters(part, tmp_path, monkeypatch):
    # a PLY's face colour, quality and texture coordinates become custom face
    # attributes of the layer: MeshLab's filters and pcprep's removal and new
    # layer carry them with their faces, and the save writes them back in
    # their types; one the layer lost is named, not dropped without a word
    from scipy.spatial import Delaunay

    from pcprep.meshlab_bridge import apply as _apply

    pts = part.points.copy()
    tri = Delaunay(pts[:, :2]).simplices.astype(np.int64)
    g = np.random.default_rng(5)
    values = {"red": (np.arange(len(tri)) % 256).astype(np.uint8),
              "quality": g.random(len(tri)).astype(np.float32),
              "texcoord": g.random((len(tri), 6)).astype(np.float32)}
    pts[:3] += 50.0 * part.normals[:3]  # three far points the outlier filter removes
    src = tmp_path / "mesh.ply"
    save_cloud(Cloud(pts, faces=tri, face_attributes=values), str(src))
    cloud = load_cloud(str(src))
    ms = pcprep.MeshSet()
    ms.load_new_mesh(str(src))
    ms.meshing_invert_face_orientation()  # MeshLab's: the faces' order and values stay
    ms.save_current_mesh(str(tmp_path / "same.ply"))
    same = load_cloud(str(tmp_path / "same.ply"))
    assert np.array_equal(same.faces, cloud.faces[:, [1, 0, 2]])
    for k, v in cloud.face_attributes.items():
        assert np.array_equal(v, values[k])
        assert np.array_equal(same.face_attributes[k], v)
        assert same.face_attributes[k].dtype == v.dtype
    out = ms.apply_filter("meshing_remove_point_outliers")
    assert out["removed"] >= 3
    ms.save_current_mesh(str(tmp_path / "removed.ply"))
    got = load_cloud(str(tmp_path / "removed.ply"))
    keep = np.flatnonzero(np.isin(pts, got.points).all(axis=1))
    ref = same.subset(keep)
    assert len(got.faces) == len(ref.faces) < len(tri)
    for k, v in ref.face_attributes.items():
        assert np.array_equal(got.face_attributes[k], v)
    for lose in (False, True):
        ms = pcprep.MeshSet()
        ms.load_new_mesh(str(src))
        if lose:  # a layer that did not keep them: refused, naming them
            monkeypatch.setattr(_apply, "_kept_face_values", lambda *a: {})
        ms.apply_filter("generate_simplified_point_cloud_sdbs", ratio=0.5)
        dst = tmp_path / f"simple{lose}.ply"
        if lose:
            with pytest.raises(pcprep.PointCloudError, match="faces carry red, quality, texcoord"):
                ms.save_current_mesh(str(dst))
            assert not dst.exists()
            continue
        ms.save_current_mesh(str(dst))
        simple = load_cloud(str(dst))
        ref = cloud.subset(np.flatnonzero(np.isin(pts, simple.points).all(axis=1)))
        assert np.array_equal(simple.faces, ref.faces) and len(ref.faces)
        for k, v in ref.face_attributes.items():
            assert np.array_equal(simple.face_attributes[k], v)
