"""docs/adding_a_filter.md: the two files it shows, installed as written, give a
working sixth filter with its CLI command, MeshSet use, table row and contract."""

import doctest
import importlib.util
import re
import sys
from pathlib import Path

import numpy as np
import pymeshlab
import pytest

import pcprep
from pcprep import InvalidParameterError
from pcprep.baselines.datasets import make_shape
from pcprep.meshlab_bridge import registry
from pcprep.meshlab_bridge.cli import build_parser, main
from pcprep.meshlab_bridge.convert import Cloud, load_cloud, save_cloud
from pcprep.meshlab_bridge.docs import filter_table_markdown

import test_contracts as contract

DOC = Path(__file__).resolve().parent.parent / "docs" / "adding_a_filter.md"
NAME = "compute_scalar_surface_variation"


def _code(title):
    """The python block under the section whose heading names ``title``."""
    text = DOC.read_text(encoding="utf-8")
    section = text[text.index(f"`{title}`"):]
    return re.search(r"```python\n(.*?)```", section, flags=re.S).group(1)


def _install(modname, code, tmp_path):
    path = tmp_path / (modname.rsplit(".", 1)[-1] + ".py")
    path.write_text(code, encoding="utf-8")
    spec = importlib.util.spec_from_file_location(modname, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[modname] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("example")
    registry.load_all()
    algo = _install("pcprep.filters.roughness", _code("filters/roughness.py"), tmp)
    import pcprep.filters
    pcprep.filters.roughness = algo
    _install("pcprep.meshlab_bridge.specs.roughness",
             _code("meshlab_bridge/specs/roughness.py"), tmp)
    yield algo
    registry.FILTERS.pop(NAME, None)
    for mod in ("pcprep.filters.roughness", "pcprep.meshlab_bridge.specs.roughness"):
        sys.modules.pop(mod, None)
    del pcprep.filters.roughness


def test_the_algorithm_module_computes_the_surface_variation(example):
    assert doctest.testmod(example).failed == 0
    g = np.random.default_rng(1)
    blob = g.normal(size=(2000, 3))
    var = example.surface_variation(blob, k=64).variation
    assert 0.2 < np.median(var) <= 1 / 3 + 1e-12  # isotropic: close to 1/3
    with pytest.raises(InvalidParameterError, match=r"k must be in \[4, 256\]"):
        example.surface_variation(blob, k=2)
    with pytest.raises(InvalidParameterError, match="unknown parameter"):
        example.surface_variation(blob, kk=8)


def test_registry_cli_meshset_and_table_follow(example, tmp_path):
    spec = registry.get("variation")
    assert spec.name == NAME and [p.name for p in spec.params] == ["k"]
    assert pcprep.filter_parameter_values(NAME) == {"k": 16}
    assert NAME in pcprep.filter_list()
    assert "`pcprep variation` | `compute_scalar_surface_variation`" in filter_table_markdown()
    sub = next(a for a in build_parser()._actions if hasattr(a, "choices") and a.choices
               and "variation" in a.choices)
    help_text = sub.choices["variation"].format_help()
    assert "Neighbours of each point, the point itself included [count]" in " ".join(
        help_text.split())

    cube = make_shape("cube", n=3000, seed=0)
    direct = example.surface_variation(cube.points, k=24).variation
    src, dst = tmp_path / "in.ply", tmp_path / "out.ply"
    save_cloud(Cloud(cube.points, cube.normals), str(src))
    assert main(["variation", str(src), str(dst), "--k", "24", "--quiet"]) == 0
    np.testing.assert_allclose(load_cloud(str(dst)).quality, direct, atol=1e-6)

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=cube.points), "cube")
    pcprep.apply_filter(ms, NAME, k=24)
    np.testing.assert_allclose(ms.current_mesh().vertex_scalar_array(), direct)
    # corners and edges vary more than the faces
    assert direct[cube.sharp].mean() > 5 * direct[~cube.sharp].mean()


def test_the_contract_tests_cover_the_new_filter(example, part=None):
    spec = registry.get("variation")
    part = make_shape("cube", n=contract.N, seed=3, rotate=True)
    contract.test_parameters_are_declared_once(spec)
    contract.test_out_of_range_values_are_rejected_by_name(spec, part)
    contract.test_bad_clouds_raise_point_cloud_error(spec, part)
    contract.test_inputs_untouched_outputs_finite_and_deterministic(spec, part)
    contract.test_meshset_bridge_equals_numpy(spec, part)
    contract.test_far_from_origin_coordinates_keep_their_precision(spec, part)
