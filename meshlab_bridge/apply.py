"""
apply.py
--------
Run a registered pcprep filter on a ``pymeshlab.MeshSet``, leaving results
where MeshLab users expect them:

* ``coord``      positions and normals replaced in the current layer; the
                 filter's mask (e.g. denoising's edge points) becomes the vertex
                 selection and the vertex quality (1/0).
* ``scalar``     the per-point value in [0, 1] becomes vertex quality, coloured
                 with MeshLab's red-green-blue quality ramp.
* ``selection``  detections become the vertex selection and quality 1/0; the
                 continuous score is added as the custom vertex attribute
                 named after the result field (e.g. ``"score"``).
* ``new_layer``  the kept input points (every attribute carried) form a new
                 layer that becomes current, as pymeshlab's
                 ``generate_simplified_point_cloud`` does.

pymeshlab has no in-place setter for vertex positions, so a ``coord`` filter
replaces the current layer by a new one with the same label; its id changes
and is returned as ``"mesh_id"``.  MeshLab's selection filters read the vertex
quality, which is why selection filters also write the mask there; a previous
quality is kept as the custom attribute ``"quality_before"``.
"""

from __future__ import annotations

import numpy as np

from pcprep.filters._validation import PointCloudError, as_points

from . import registry
from .convert import Cloud, MissingAttributeError, cloud_to_mesh, meshset_to_cloud


def filter_list() -> list[str]:
    """Names of all registered pcprep filters, sorted."""
    return sorted(registry.load_all())


def print_filter_parameter_list(name: str) -> None:
    """Print a filter's parameters with defaults, ranges, units and help, as
    ``pymeshlab.print_filter_parameter_list`` does."""
    print(filter_parameter_text(name))  # noqa: T201 -- the function's purpose


def filter_parameter_values(name: str) -> dict:
    """Default value of every parameter of filter ``name``, as
    ``pymeshlab.MeshSet.filter_parameter_values`` gives them (``None`` = resolved
    from the data at call time)."""
    return registry.get(name).defaults()


def filter_parameter_text(name: str) -> str:
    spec = registry.get(name)
    lines = [f"{spec.name} ({spec.label})", "", spec.description, "", "Parameters:"]
    for p in spec.params:
        unit = f" [{registry.UNITS[p.unit]}]" if p.unit else ""
        rng = f" range {p.range_text()}" if p.range_text() else ""
        default = "auto" if p.default is None and p.optional else repr(p.default)
        lines.append(f"  {p.name} : {p.kind.__name__} = {default}{unit}{rng}")
        lines.append(f"      {p.help}")
    return "\n".join(lines)


def run_on_cloud(spec, cloud: Cloud, params: dict):
    """Validate ``params``, check requirements and call the filter's function."""
    resolved = spec.resolve(params)
    if len(cloud) == 0:
        raise PointCloudError(f"{spec.name}: the layer is empty (0 vertices)")
    as_points(cloud.points, func=spec.name)  # NaN/Inf rows named before any work
    if spec.uses_normals:
        return spec.func(cloud.points, normals=cloud.normals, **resolved)
    return spec.func(cloud.points, **resolved)


def result_cloud(spec, cloud: Cloud, result) -> Cloud:
    """The cloud a filter's result turns the input into (used by the CLI and
    by ``apply_filter``).  Every input attribute is kept (``new_layer``: on the
    kept rows).  The main per-point result goes to the attribute
    ``spec.attribute``; following MeshLab, a mask also becomes the quality
    (1/0) and a scalar the quality, the previous quality being kept as the
    attribute ``quality_before``."""
    if spec.kind == "coord":
        pts = np.asarray(getattr(result, spec.points_field), dtype=np.float64)
        nrm = getattr(result, spec.normals_field) if spec.normals_field else cloud.normals
        out = cloud.with_(points=pts, normals=None if nrm is None else np.asarray(nrm, np.float64))
        if spec.mask_field:
            mask = np.asarray(getattr(result, spec.mask_field), dtype=bool)
            out = _with_attribute(_with_mask_quality(out, mask), spec.attribute, mask)
        return out
    if spec.kind == "scalar":
        values = np.asarray(getattr(result, spec.scalar_field), dtype=np.float64)
        out = _keep_quality(cloud).with_(quality=values)
        return _with_attribute(out, spec.attribute, values)
    if spec.kind == "selection":
        mask = np.asarray(getattr(result, spec.mask_field), dtype=bool)
        out = _with_attribute(_with_mask_quality(cloud, mask), spec.attribute, mask)
        if spec.scalar_field:
            score = np.asarray(getattr(result, spec.scalar_field), np.float64)
            name = f"{spec.attribute}_{spec.scalar_field}" if spec.attribute else spec.scalar_field
            out = _with_attribute(out, name, score)
        return out
    if spec.kind == "new_layer":
        idx = np.asarray(getattr(result, spec.index_field), dtype=np.int64)
        out = cloud.subset(idx)
        if spec.scalar_field:
            out = out.with_(quality=np.asarray(getattr(result, spec.scalar_field), np.float64)[idx])
        return out
    raise PointCloudError(f"{spec.name}: kind {spec.kind!r} produces no cloud")


def _with_attribute(cloud: Cloud, name: str | None, values: np.ndarray) -> Cloud:
    """Add ``values`` as attribute ``name``, or ``name_2``, ``name_3``, … when the
    cloud already has one of that name (nothing is overwritten)."""
    if name is None:
        return cloud
    attrs = dict(cloud.attributes)
    key, k = name, 1
    while key in attrs:
        k += 1
        key = f"{name}_{k}"
    attrs[key] = values
    return cloud.with_(attributes=attrs)


def _keep_quality(cloud: Cloud) -> Cloud:
    if cloud.quality is None:
        return cloud
    return _with_attribute(cloud, "quality_before", cloud.quality)


def _with_mask_quality(cloud: Cloud, mask) -> Cloud:
    mask = np.asarray(mask, dtype=bool)
    return _keep_quality(cloud).with_(quality=mask.astype(np.float64))


def apply_filter(ms, name: str, **params) -> dict:
    """Apply the pcprep filter ``name`` (registry name or CLI command) to the
    current layer of ``ms``.

    Returns a dict of named outputs, as pymeshlab's ``apply_filter`` does:
    ``"mesh_id"`` (the layer holding the result), the resolved parameters
    (``"params"``), and per kind ``"selected"`` (count) or ``"kept"`` (count).
    The function's full result object is under ``"result"``.
    """
    spec = registry.get(name)
    attrs = tuple(params.pop("_attributes", ()))
    cloud = meshset_to_cloud(ms, attrs)
    result = run_on_cloud(spec, cloud, params)
    out_cloud = result_cloud(spec, cloud, result)
    label = ms.current_mesh().label()
    outputs = {"result": result, "params": spec.resolve(params)}
    if spec.kind in ("coord", "scalar", "selection"):
        old_id = ms.current_mesh_id()
        _add_layer(ms, out_cloud, label, select=spec.mask_field is not None,
                   ramp=spec.kind == "scalar")
        new_id = ms.current_mesh_id()
        ms.set_current_mesh(old_id)
        ms.delete_current_mesh()
        ms.set_current_mesh(new_id)
        ms.current_mesh().set_label(label)  # MeshLab suffixed it while both existed
        outputs["mesh_id"] = new_id
        if spec.mask_field:
            outputs["selected"] = int(np.count_nonzero(getattr(result, spec.mask_field)))
    elif spec.kind == "new_layer":
        _add_layer(ms, out_cloud, f"{label} ({spec.command})", select=False, ramp=False)
        outputs["mesh_id"] = ms.current_mesh_id()
        outputs["kept"] = len(out_cloud)
    return outputs


def _add_layer(ms, cloud: Cloud, label: str, *, select: bool, ramp: bool) -> None:
    """Add ``cloud`` as a new current layer.  Custom attributes are attached
    after MeshLab's expression/selection filters have run, because
    Python-added attributes make those filters crash (BASELINES.md §0.7)."""
    attrs = cloud.attributes
    ms.add_mesh(cloud_to_mesh(cloud.with_(attributes={})), label, set_as_current=True)
    if select:
        # the bounds are clamped to the quality range, so an all-zero mask
        # would select everything: clear the selection explicitly instead
        if cloud.quality is not None and (cloud.quality > 0.5).any():
            ms.compute_selection_by_scalar_per_vertex(minq=0.5, maxq=1.5)
        else:
            ms.set_selection_none()
    if ramp:
        ms.compute_color_from_scalar_per_vertex(minval=0.0, maxval=1.0)
    mesh = ms.current_mesh()
    for key, values in attrs.items():
        mesh.add_vertex_custom_scalar_attribute(np.ascontiguousarray(values, np.float64), key)
