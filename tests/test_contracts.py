"""Contract tests run over every registered filter (in the spirit of
scikit-learn's parametrize_with_checks): parameters documented and checked,
bad clouds rejected, inputs untouched, outputs finite and deterministic, and
the MeshSet bridge and the CLI give the same answer as the NumPy function."""

import argparse
import importlib
import inspect

import numpy as np
import pymeshlab
import pytest

from pcprep.baselines.datasets import cut_holes, make_shape
from pcprep.filters.metrics import precision_recall_f1
from pcprep import InvalidParameterError, PointCloudError
from pcprep.meshlab_bridge import registry
from pcprep.meshlab_bridge.apply import apply_filter
from pcprep.filters import docstring_parameters
from pcprep.meshlab_bridge.cli import build_parser, main
from pcprep.meshlab_bridge.convert import Cloud, load_cloud, save_cloud

SPECS = sorted(registry.load_all().values(), key=lambda s: s.name)
IDS = [s.command for s in SPECS]
N = 1500


@pytest.fixture(scope="module")
def part():
    return make_shape("cube", n=N, seed=3, rotate=True)


@pytest.fixture(scope="module")
def fixtures():
    """Something to find and something not to: a CAD part (sharp edges, no
    border), an open plane with three holes (borders, no edge) and a sphere
    (neither); each with its truth for the two detectors."""
    cube = make_shape("cube", n=4000, seed=3, rotate=True)
    holed = cut_holes(make_shape("plane", n=4000, seed=4), n_holes=3, radius=6.0, seed=5)
    sphere = make_shape("sphere", n=4000, seed=6)
    return {"cube": cube, "holed plane": holed, "sphere": sphere}


#: detector command -> (truth attribute of a Sample, fixture where it has positives)
_DETECTORS = {"features": ("sharp", "cube"), "holes": ("rim", "holed plane")}


def _example(spec):
    return dict(spec.example)


def _call(spec, points, normals=None, **params):
    kw = {**_example(spec), "seed": 0, **params} if "seed" in {p.name for p in spec.params} \
        else {**_example(spec), **params}
    if spec.uses_normals:
        return spec.func(points, normals=normals, **kw)
    return spec.func(points, **kw)


def _outputs(spec, res):
    fields = [spec.points_field if spec.kind == "coord" else None, spec.normals_field
              if spec.kind == "coord" else None, spec.mask_field, spec.scalar_field,
              spec.index_field]
    return {f: np.asarray(getattr(res, f)) for f in fields if f}


def test_registry_has_the_thesis_filters():
    assert {"denoise", "simplify", "features", "holes", "saliency"} <= set(IDS)


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_parameters_are_declared_once(spec):
    """Signature, spec, docstring and CLI flags name the same parameters with the
    same defaults (the README table is checked against the spec in test_readme)."""
    sig = inspect.signature(spec.func)
    keyword = {n: q.default for n, q in sig.parameters.items() if q.kind is q.KEYWORD_ONLY}
    assert [p.name for p in spec.params] == list(keyword)
    assert {p.name: p.default for p in spec.params} == keyword
    docs = docstring_parameters(spec.func.__doc__)
    for p in spec.params:
        assert docs[p.name][1] == p.help and p.help, p.name
        if p.name.endswith("_deg"):
            assert p.unit == "deg", p.name
    spec.resolve(_example(spec))
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    flags = {a.dest: a for a in sub.choices[spec.command]._actions if a.option_strings}
    assert set(flags) - {"help", "quiet", "drop_nonfinite", "drop_faces",
                         "drop_face_properties", "drop_elements", "out_dir", "format",
                         "save_mlx", "tiles", "workers", "scheduler", "memory_budget",
                         "worker_io", "scratch"} == set(keyword)
    for p in spec.params:
        assert f"--{p.name.replace('_', '-')}" in flags[p.name].option_strings
        assert tuple(flags[p.name].choices or ()) == p.choices
    assert spec.description.count("(") >= 1  # cites equations / chapter


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_out_of_range_values_are_rejected_by_name(spec, part):
    for p in spec.params:
        if p.kind not in (int, float) or p.choices:
            continue
        bad = None
        if p.low is not None:
            bad = p.low - 1 if p.kind is int else p.low - 1e-3 * max(1.0, abs(p.low))
        elif p.high is not None:
            bad = p.high + 1
        if bad is None:
            continue
        with pytest.raises(InvalidParameterError, match=p.name):
            _call(spec, part.points, part.normals, **{p.name: bad})


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_bad_clouds_raise_point_cloud_error(spec, part):
    bad_nan = part.points.copy()
    bad_nan[7, 1] = np.nan
    t = np.linspace(0, 1, 400)[:, None]
    for cloud, msg in (
        (np.zeros((0, 3)), "empty"),
        (bad_nan, "NaN"),
        (part.points[:5], "at least"),
        (t * [1.0, 2.0, 3.0], "collinear"),
        (np.ones((300, 3)), "coincide"),
        (np.r_[part.points, part.points[:3]], "duplicate"),
    ):
        with pytest.raises(PointCloudError, match=msg):
            _call(spec, cloud, None)


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_inputs_untouched_outputs_finite_and_deterministic(spec, part):
    pts, nrm = part.points.copy(), part.normals.copy()
    a = _outputs(spec, _call(spec, pts, nrm))
    assert np.array_equal(pts, part.points) and np.array_equal(nrm, part.normals)
    b = _outputs(spec, _call(spec, pts, nrm))
    for key, val in a.items():
        if val.dtype.kind == "f":
            assert np.isfinite(val).all(), key
        assert np.array_equal(val, b[key]), key
    if spec.kind in ("coord", "scalar", "selection"):
        assert all(len(v) == N for v in a.values())
    if spec.scalar_field and spec.kind == "scalar":
        s = a[spec.scalar_field]
        assert s.min() >= 0.0 and s.max() <= 1.0


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_meshset_bridge_equals_numpy(spec, part):
    nrm = part.normals if spec.uses_normals else None
    direct = _outputs(spec, _call(spec, part.points, nrm))
    ms = pymeshlab.MeshSet()
    kw = {"vertex_matrix": part.points}
    if nrm is not None:
        kw["v_normals_matrix"] = nrm
    ms.add_mesh(pymeshlab.Mesh(**kw), "part")
    params = {**_example(spec)}
    if "seed" in {p.name for p in spec.params}:
        params["seed"] = 0
    out = apply_filter(ms, spec.name, **params)
    m = ms.current_mesh()
    if spec.kind == "coord":
        assert np.array_equal(m.vertex_matrix(), direct[spec.points_field])
    if spec.mask_field:
        assert np.array_equal(m.vertex_selection_array(), direct[spec.mask_field].astype(bool))
    if spec.kind == "scalar":
        assert np.allclose(m.vertex_scalar_array(), direct[spec.scalar_field])
    if spec.kind == "new_layer":
        assert ms.mesh_number() == 2 and out["kept"] == len(direct[spec.index_field])
        assert np.array_equal(m.vertex_matrix(), part.points[direct[spec.index_field]])
    if spec.kind == "remove":
        assert ms.mesh_number() == 1 and out["mesh_id"] == 0
        assert np.array_equal(m.vertex_matrix(), part.points[direct[spec.index_field]])


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_cli_writes_the_documented_output(spec, part, tmp_path):
    src = tmp_path / "in.ply"
    save_cloud(Cloud(part.points, part.normals), str(src))
    dst = tmp_path / "out.ply"
    args = [spec.command, str(src), str(dst), "--quiet"]
    for k, v in _example(spec).items():
        args += [f"--{k.replace('_', '-')}", str(v)]
    assert main(args) == 0
    got = load_cloud(str(dst))
    direct = _outputs(spec, _call(spec, part.points, part.normals if spec.uses_normals else None))
    if spec.kind in ("new_layer", "remove"):
        assert np.array_equal(got.points, part.points[direct[spec.index_field]])
    else:
        assert len(got) == N
    if spec.kind == "selection":
        assert np.array_equal(got.quality, direct[spec.mask_field].astype(float))
    if spec.kind == "scalar":
        assert np.allclose(got.quality, direct[spec.scalar_field], atol=1e-6)


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_far_from_origin_coordinates_keep_their_precision(spec, part):
    """A cloud 1e6 away from the origin (UTM-like) gives the same answer as at
    the origin: filters work on centred coordinates."""
    offset = np.array([4.5e6, -2.5e6, 1.0e6])
    near = _outputs(spec, _call(spec, part.points, part.normals))
    far = _outputs(spec, _call(spec, part.points + offset, part.normals))
    for key, val in near.items():
        if spec.kind == "coord" and key == spec.points_field:
            err = np.linalg.norm(far[key] - offset - val, axis=1)
            assert np.percentile(err, 99) < 1e-3 * part.h and err.max() < 0.05 * part.h, key
        elif val.dtype == bool or val.dtype.kind in "iu":
            assert np.mean(far[key] == val) > 0.97, key
        else:
            assert np.allclose(far[key], val, atol=1e-6, rtol=1e-6) or \
                np.corrcoef(far[key].ravel(), val.ravel())[0, 1] > 0.95, key


@pytest.mark.parametrize("command", sorted(_DETECTORS))
def test_detectors_find_their_features_and_nothing_where_there_is_none(command, fixtures):
    spec = registry.get(command)
    truth_field, positive = _DETECTORS[command]
    for name, sample in fixtures.items():
        mask = np.asarray(getattr(_call(spec, sample.points), spec.mask_field))
        truth = getattr(sample, truth_field)
        if name == positive:
            assert precision_recall_f1(mask, truth)[2] > 0.8, name
        else:
            assert not truth.any()
            assert mask.mean() < 0.03, (name, mask.mean())


# --------------------------------------------------------------------------- presets
def _preset_specs():
    from pcprep.meshlab_bridge.registry import load_all

    return [s for s in load_all().values() if getattr(s.func, "presets", None)]


@pytest.mark.parametrize("spec", _preset_specs(), ids=lambda s: s.command)
def test_thesis_preset_sets_its_values_and_explicit_arguments_win(spec):
    """``preset="thesis"`` fills the parameters the caller left out, through a
    direct call's resolution and the bridge's alike; a given value wins."""
    table = spec.func.presets["thesis"]
    assert table, spec.name
    resolved = spec.resolve({"preset": "thesis"})
    for key, value in table.items():
        assert resolved[key] == value, key
    key, value = next(iter(table.items()))
    default = next(p.default for p in spec.params if p.name == key)
    assert spec.resolve({"preset": "thesis", key: default})[key] == default
    assert spec.resolve({})["preset"] is None
    with pytest.raises(InvalidParameterError, match="preset"):
        spec.resolve({"preset": "paper"})


@pytest.mark.parametrize("spec", _preset_specs(), ids=lambda s: s.command)
def test_thesis_preset_call_equals_the_call_with_its_values(spec):
    s = make_shape("fandisk", n=1500, seed=4)
    kw = dict(spec.example)
    if spec.command == "simplify":
        kw.setdefault("ratio", 0.2)
    table = spec.func.presets["thesis"]
    a = spec.func(s.points, preset="thesis", **kw)
    module = importlib.import_module(spec.func.__module__)
    if hasattr(module, "THESIS_RULES"):  # the preset also switches the added steps off
        b = module._detect(s.points, rules=module.THESIS_RULES, **{**table, **kw})
    else:
        b = spec.func(s.points, **{**table, **kw})
    c = spec.func(s.points, **kw)
    field = spec.index_field or spec.mask_field or spec.scalar_field or "points"
    va, vb, vc = (np.asarray(getattr(r, field)) for r in (a, b, c))
    assert np.array_equal(va, vb)
    assert va.shape != vc.shape or not np.array_equal(va, vc)  # the preset changes the run
