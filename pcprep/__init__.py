"""
pcprep
======
Point-cloud pre-processing filters from the sparse-representation algorithms of
Leal Narváez (2020): denoising, saliency, SDBS simplification, sharp features and
hole boundaries, as NumPy functions, MeshSet filters and the ``pcprep`` command.

The sub-packages are ``pcprep.filters`` (arrays in and out),
``pcprep.meshlab_bridge`` (MeshSet, registry, command line) and
``pcprep.baselines`` (MeshLab and CGAL runners, benchmarks, report); the names a
user needs every day are re-exported here and load on first use, so
``import pcprep`` stays cheap.

>>> import pcprep
>>> "compute_scalar_saliency_sparse_mdl" in pcprep.filter_list()
True
"""

from __future__ import annotations

import os
from importlib import import_module

__version__ = "0.1.0"

# In a source checkout the sub-packages sit beside this folder (pyproject.toml
# maps them into the namespace at install time); let the same imports resolve
# there, so the tests run from a checkout with or without an install.
_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if not os.path.isdir(os.path.join(__path__[0], "filters")) and os.path.isfile(
        os.path.join(_root, "filters", "__init__.py")):
    __path__.append(_root)

#: public name -> module that defines it
_EXPORTS = {
    "PointCloudError": "pcprep.filters._validation",
    "InvalidParameterError": "pcprep.filters._validation",
    "MissingAttributeError": "pcprep.meshlab_bridge.convert",
    "average_spacing": "pcprep.filters.neighbors",
    "denoise_l1_tv": "pcprep.filters.denoise",
    "saliency_sparse_mdl": "pcprep.filters.saliency",
    "simplify_sdbs": "pcprep.filters.simplify",
    "detect_sharp_features": "pcprep.filters.sharp",
    "detect_hole_boundaries": "pcprep.filters.holes",
    "MeshSet": "pcprep.meshlab_bridge.meshset",
    "apply_filter": "pcprep.meshlab_bridge.apply",
    "filter_list": "pcprep.meshlab_bridge.apply",
    "print_filter_parameter_list": "pcprep.meshlab_bridge.apply",
    "filter_parameter_values": "pcprep.meshlab_bridge.apply",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'pcprep' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
