"""
apply.py
--------
Run a registered pcprep filter on the current layer of a ``pymeshlab.MeshSet``,
leaving results where MeshLab users expect them.  The layer keeps its id, its
label and its place in the layer list, and every attribute it carries:

* ``coord``      positions and normals are replaced in place; the filter's mask
                 (denoising's edge points) becomes the vertex selection, the
                 vertex quality (1/0) and the custom attribute ``spec.attribute``.
* ``scalar``     the per-point value becomes the vertex quality, coloured with
                 MeshLab's quality ramp, and the custom attribute ``spec.attribute``.
* ``selection``  detections become the vertex selection, the quality (1/0) and the
                 attribute ``spec.attribute``; the continuous score is the
                 attribute ``<attribute>_score``.
* ``new_layer``  the kept input points form a new layer (a copy of the current
                 one with the other vertices removed, so every attribute is
                 carried) that becomes current, as pymeshlab's
                 ``generate_simplified_point_cloud`` does.

A quality the layer had before is kept as the custom attribute
``quality_before``.  pymeshlab offers no setter for vertex positions, so they
are written through MeshLab's own filters: a temporary layer at the same
positions carries each new coordinate as its quality, ``transfer_attributes_per_vertex``
copies it onto the layer (every vertex matches itself, at distance 0) and
``compute_coord_by_function`` / ``compute_normal_by_function_per_vertex`` move
it into place; the values are doubles throughout, so the result is bit-exact.
"""

from __future__ import annotations

import numpy as np

from pcprep.filters._validation import PointCloudError, as_points

from . import registry
from .convert import Cloud, MissingAttributeError, add_attribute, meshset_to_cloud  # noqa: F401


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
        default = "none" if p.default is None else repr(p.default)
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


def result_cloud(spec, cloud: Cloud, result, *, dst: str | None = None) -> Cloud:
    """The cloud a filter's result turns the input into (used by the CLI and
    by ``apply_filter``).  Every input attribute is kept (``new_layer``: on the
    kept rows).  The main per-point result goes to the attribute
    ``spec.attribute``; following MeshLab, a mask also becomes the quality
    (1/0) and a scalar the quality, the previous quality being kept as the
    attribute ``quality_before``.  A removal's or new layer's score becomes
    the quality only for display: written to a file ``dst`` whose format
    holds no quality (XYZ, OBJ, OFF, E57) it is left out, the kept rows
    being the result."""
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
    if spec.kind in ("new_layer", "remove"):
        idx = np.asarray(getattr(result, spec.index_field), dtype=np.int64)
        out = cloud.subset(idx)
        if spec.scalar_field and (dst is None or _holds_quality(dst)):
            score = np.asarray(getattr(result, spec.scalar_field), np.float64)[idx]
            out = _keep_quality(out).with_(quality=score)
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


def _holds_quality(dst: str) -> bool:
    from .formats import CAN_STORE, _ext

    return "quality" in CAN_STORE.get(_ext(dst), ())


def _keep_quality(cloud: Cloud) -> Cloud:
    if cloud.quality is None:
        return cloud
    return _with_attribute(cloud, "quality_before", cloud.quality)


def _with_mask_quality(cloud: Cloud, mask) -> Cloud:
    mask = np.asarray(mask, dtype=bool)
    return _keep_quality(cloud).with_(quality=mask.astype(np.float64))


def apply_filter(ms, name: str, *, carry: tuple[str, ...] = (),
                 carry_faces: tuple[str, ...] = (), **params) -> dict:
    """Apply the pcprep filter ``name`` (registry name or CLI command) to the
    current layer of ``ms``.

    Returns a dict of named outputs, as pymeshlab's ``apply_filter`` does:
    ``"mesh_id"`` (the layer holding the result: the same layer, or the new one
    for ``new_layer`` filters), the resolved parameters (``"params"``), and per
    kind ``"selected"`` (count) or ``"kept"`` (count).  The function's full
    result object is under ``"result"``; the names of the custom attributes it
    added are under ``"attributes"``.  ``carry`` names custom attributes of the
    layer that a ``new_layer`` filter copies to its kept rows (pymeshlab cannot
    list a layer's custom attributes, and MeshLab's layer copy drops them;
    ``pcprep.MeshSet`` passes the ones it knows); ``carry_faces`` names the
    custom face scalars it copies to the faces whose vertices are all kept.
    """
    spec = registry.get(name)
    resolved = spec.resolve(params)  # parameter errors before touching the layer
    cloud = meshset_to_cloud(ms)
    result = run_on_cloud(spec, cloud, params)
    out = result_cloud(spec, cloud, result)
    outputs = {"result": result, "params": resolved}
    layer = ms.current_mesh_id()
    if spec.kind == "new_layer":
        idx = np.asarray(getattr(result, spec.index_field), dtype=np.int64)
        source = ms.current_mesh()
        kept = {k: np.array(source.vertex_custom_scalar_attribute_array(k))[idx]
                for k in carry if _has_attribute(source, k)}
        faces_kept = _kept_face_values(source, idx, carry_faces)
        _subset_layer(ms, layer, idx, f"{source.label()} ({spec.command})")
        mesh = ms.current_mesh()
        for key, values in kept.items():
            if not _has_attribute(mesh, key):
                add_attribute(mesh, key, values)
        for key, values in faces_kept.items():
            if len(values) == mesh.face_number():  # else the layer names them lost
                mesh.add_face_custom_scalar_attribute(values, key)
        outputs.update(mesh_id=ms.current_mesh_id(), kept=len(idx), attributes=[])
        return outputs
    if spec.kind == "remove":
        idx = np.asarray(getattr(result, spec.index_field), dtype=np.int64)
        _remove_rows(ms, layer, idx)
        outputs.update(mesh_id=layer, kept=len(idx), removed=len(cloud) - len(idx),
                       attributes=[])
        return outputs
    if spec.kind == "coord":
        _set_positions(ms, layer, out.points, out.normals)
    if out.quality is not None:
        _set_quality(ms, layer, out.quality)
    if spec.mask_field:
        _select(ms, np.asarray(getattr(result, spec.mask_field), dtype=bool))
        outputs["selected"] = int(np.count_nonzero(getattr(result, spec.mask_field)))
    if spec.kind == "scalar":
        _call(ms, "compute_color_from_scalar_per_vertex", minval=0.0, maxval=1.0)
    # custom attributes last: MeshLab's expression filters must not meet
    # attributes added from Python (some of them crash on those)
    mesh = ms.current_mesh()
    outputs["attributes"] = []
    for key, values in out.attributes.items():
        if key not in cloud.attributes:
            free = _free_name(mesh, key)
            add_attribute(mesh, free, np.asarray(values))
            outputs["attributes"].append(free)
    outputs["mesh_id"] = layer
    return outputs


def _call(ms, name: str, **params):
    """A MeshLab filter, bypassing ``pcprep.MeshSet``'s recording."""
    import pymeshlab

    return pymeshlab.MeshSet.apply_filter(ms, name, **params)


def _carrier(ms, layer: int, values: np.ndarray) -> None:
    """Copy ``values`` into the quality of layer ``layer`` (see the module notes)."""
    import pymeshlab

    pts = np.array(ms.mesh(layer).vertex_matrix())
    # every vertex finds itself at distance 0; the bound only has to be a
    # positive number whose square does not underflow
    bound = 1e-9 * max(float(np.ptp(pts, axis=0).max()), 1e-100)
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=pts, v_scalar_array=np.ascontiguousarray(
        values, dtype=np.float64)), "pcprep-carrier", set_as_current=True)
    carrier = ms.current_mesh_id()
    ms.set_current_mesh(layer)
    try:
        _call(ms, "transfer_attributes_per_vertex", sourcemesh=carrier, targetmesh=layer,
              vertexsampling=True, colortransfer=False, qualitytransfer=True,
              upperbound=pymeshlab.PureValue(bound))
    finally:
        ms.set_current_mesh(carrier)
        ms.delete_current_mesh()
        ms.set_current_mesh(layer)


def _set_quality(ms, layer: int, values: np.ndarray) -> None:
    _carrier(ms, layer, values)


def _set_positions(ms, layer: int, points: np.ndarray, normals: np.ndarray | None) -> None:
    for j, c in enumerate("xyz"):
        _carrier(ms, layer, points[:, j])
        _call(ms, "compute_coord_by_function", **{k: ("q" if k == c else k) for k in "xyz"})
    if normals is not None:
        for j, c in enumerate("xyz"):
            _carrier(ms, layer, normals[:, j])
            _call(ms, "compute_normal_by_function_per_vertex",
                  **{k: ("q" if k == c else "n" + k) for k in "xyz"})


def _select(ms, mask: np.ndarray) -> None:
    """Vertex selection = ``mask`` (the quality holds the mask as 1/0 here)."""
    if mask.any():
        _call(ms, "compute_selection_by_scalar_per_vertex", minq=0.5, maxq=1.5)
    else:  # the bounds are clamped to the quality range: 0/0 would select all
        _call(ms, "set_selection_none")


def _remove_rows(ms, layer: int, idx: np.ndarray) -> None:
    """Keep only rows ``idx`` (increasing) of ``layer``, in place."""
    mesh = ms.mesh(layer)
    quality = np.array(mesh.vertex_scalar_array()) if mesh.has_vertex_scalar() else None
    mask = np.ones(mesh.vertex_number(), dtype=bool)
    mask[idx] = False
    if not mask.any():
        return
    _carrier(ms, layer, mask.astype(np.float64))
    _select(ms, mask)
    _call(ms, "meshing_remove_selected_vertices")
    if quality is not None:
        _carrier(ms, layer, quality[idx])


def _subset_layer(ms, layer: int, idx: np.ndarray, label: str) -> None:
    """A new current layer holding rows ``idx`` of ``layer`` with every
    attribute: a copy of the layer minus the other vertices (order kept)."""
    n = ms.mesh(layer).vertex_number()
    mask = np.ones(n, dtype=bool)
    mask[idx] = False
    if not np.all(np.diff(idx) > 0):
        raise PointCloudError("internal: kept indices must be increasing")
    _call(ms, "generate_copy_of_current_mesh")
    copy = ms.current_mesh_id()
    had_quality = ms.current_mesh().has_vertex_scalar()
    quality = np.array(ms.current_mesh().vertex_scalar_array()) if had_quality else None
    _carrier(ms, copy, mask.astype(np.float64))
    _select(ms, mask)
    if mask.any():
        _call(ms, "meshing_remove_selected_vertices")
    if quality is not None:
        _carrier(ms, copy, quality[idx])
    ms.current_mesh().set_label(label)


def _kept_face_values(mesh, idx: np.ndarray, names: tuple[str, ...]) -> dict:
    """The custom face scalars ``names`` of ``mesh`` on the faces whose three
    vertices are among the rows ``idx``, in face order: those MeshLab's
    vertex removal keeps, in its order (as ``Cloud.subset`` keeps them)."""
    if not names or not mesh.face_number():
        return {}
    inside = np.zeros(mesh.vertex_number(), dtype=bool)
    inside[idx] = True
    whole = inside[np.array(mesh.face_matrix())].all(axis=1)
    out = {}
    for name in names:
        try:
            out[name] = np.ascontiguousarray(
                np.array(mesh.face_custom_scalar_attribute_array(name))[whole], np.float64)
        except Exception:  # pymeshlab raises its own type for a missing attribute
            pass
    return out


def _has_attribute(mesh, name: str) -> bool:
    for getter in (mesh.vertex_custom_scalar_attribute_array,
                   mesh.vertex_custom_point_attribute_matrix):
        try:
            getter(name)
            return True
        except Exception:  # pymeshlab raises its own type for a missing attribute
            pass
    return False


def _free_name(mesh, name: str) -> str:
    """``name``, or ``name_2``, ``name_3``, … if the layer has it already."""
    key, k = name, 1
    while _has_attribute(mesh, key):
        k += 1
        key = f"{name}_{k}"
    return key
