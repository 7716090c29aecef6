"""
meshset.py
----------
``pcprep.MeshSet``: a ``pymeshlab.MeshSet`` on which pcprep's filters are
methods like MeshLab's own (``ms.apply_coord_denoise_l1_tv(lambda_tv=0.4)``,
``ms.generate_simplified_point_cloud_sdbs(ratio=0.1)``), and whose
``apply_filter``, ``filter_list``, ``print_filter_parameter_list``,
``filter_parameter_values`` and filter scripts cover both kinds of filters.

Filter scripts are MeshLab's ``.mlx`` XML: a ``<FilterScript>`` of
``<filter name="...">`` elements with ``<Param name= value= type=>`` children.
MeshLab names its filters by their GUI label ("Compute normals for point
sets"); pcprep's steps use their registry name (``apply_coord_denoise_l1_tv``)
and ``RichFloat``/``RichInt``/``RichBool``/``RichString`` parameters, so one
script can interleave both.  ``load_filter_script`` checks every step (pcprep's
parameters against their declarations, MeshLab's by letting pymeshlab load
each one) before ``apply_filter_script`` runs the first; ``save_filter_script``
writes every filter applied through this object, of both kinds, in order.
MeshLab itself cannot run the pcprep steps of such a script.
"""

from __future__ import annotations

import os
import re
import tempfile
import xml.etree.ElementTree as ET

import numpy as np
import pymeshlab

from pcprep.filters._validation import InvalidParameterError

from . import apply as _apply
from . import formats, registry
from .cloud import Cloud
from .convert import add_cloud_layer, face_attribute_columns, mesh_to_cloud

#: formats whose attributes pcprep keeps when a MeshSet loads or saves them
_OWN_FORMATS = (".ply", ".las", ".laz", ".pcd", ".xyz", ".e57")

_TYPES = {float: "RichFloat", int: "RichInt", bool: "RichBool", str: "RichString"}


def _is_pcprep(name: str) -> bool:
    filters = registry.load_all()
    return name in filters or any(s.command == name for s in filters.values())


class MeshSet(pymeshlab.MeshSet):
    """A MeshLab ``MeshSet`` that also runs pcprep's filters (see the module notes)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._record: list[ET.Element] = []
        self._loaded: list[tuple[str, object]] = []
        self._busy = False
        #: layer id -> (attribute name -> dtype, file meta, face attribute name ->
        #: (dtype, columns or None)) for layers pcprep knows
        self._layers: dict[int, tuple[dict, dict, dict]] = {}

    # -- filters ----------------------------------------------------------------
    def apply_filter(self, filter_name: str, **params):
        """Run a pcprep or a MeshLab filter on the current layer and record it."""
        if self._busy:  # a MeshLab step inside a pcprep filter: not a pipeline step
            return super().apply_filter(filter_name, **params)
        if _is_pcprep(filter_name):
            spec = registry.get(filter_name)
            source = self.current_mesh_id()
            attrs, meta, faces = self._layers.get(source, ({}, {}, {}))
            count = self.current_mesh().vertex_number()
            self._busy = True
            try:
                columns = tuple(c for k, (_, w) in faces.items()
                                for c in face_attribute_columns(k, w))
                out = _apply.apply_filter(self, spec.name, carry=tuple(attrs),
                                          carry_faces=columns, **params)
            finally:
                self._busy = False
                self.clear_filter_script()  # the MeshLab steps pcprep used internally
            added = {k: np.dtype(np.float64) for k in out["attributes"]}
            if spec.kind in ("remove", "new_layer"):
                meta = _kept_rows(meta, count,
                                  np.asarray(getattr(out["result"], spec.index_field)))
            self._layers[out["mesh_id"]] = ({**attrs, **added}, meta, faces)
            self._record.append(_pcprep_element(spec, out["params"]))
            return out
        self.clear_filter_script()
        out = super().apply_filter(filter_name, **params)
        self._record.extend(_meshlab_elements(self))
        self.clear_filter_script()
        return out

    def filter_list(self) -> list[str]:
        """Every filter this MeshSet runs: MeshLab's and pcprep's."""
        return sorted(set(pymeshlab.filter_list()) | set(registry.load_all()))

    def print_filter_parameter_list(self, filter_name: str) -> None:
        if _is_pcprep(filter_name):
            _apply.print_filter_parameter_list(filter_name)
        else:
            pymeshlab.print_filter_parameter_list(filter_name)

    def filter_parameter_values(self, filter_name: str, *args, **kwargs) -> dict:
        if _is_pcprep(filter_name):
            return _apply.filter_parameter_values(filter_name)
        return super().filter_parameter_values(filter_name, *args, **kwargs)

    # -- files ----------------------------------------------------------------------
    def load_new_mesh(self, file_name, *args, **kwargs):
        """Load a file as a new current layer.  PLY, LAS, LAZ, PCD, XYZ and E57
        go through pcprep's readers, so every per-point attribute becomes a
        custom attribute of the layer and ``save_current_mesh`` writes them back
        with their types and the file's header; other formats load as in
        pymeshlab."""
        path = os.fspath(file_name)
        if os.path.splitext(path)[1].lower() not in _OWN_FORMATS:
            return super().load_new_mesh(path, *args, **kwargs)
        self.add_cloud(formats.read_cloud(path), os.path.basename(path))
        return None

    def add_cloud(self, cloud: Cloud, label: str = "") -> int:
        """Add a ``Cloud`` as a new current layer whose attributes pcprep tracks."""
        layer = add_cloud_layer(self, cloud, label or cloud.label)
        faces = {k: (v.dtype, None if v.ndim == 1 else v.shape[1])
                 for k, v in cloud.face_attributes.items()}
        self._layers[layer] = ({k: v.dtype for k, v in cloud.attributes.items()}, cloud.meta,
                               faces)
        return layer

    def save_current_mesh(self, file_name, *args, **kwargs):
        """Save the current layer.  PLY, LAS, LAZ, PCD and XYZ go through
        pcprep's writers with every attribute pcprep knows the layer to have
        (those it read and those its filters added), in their types, atomically;
        other formats save as in pymeshlab."""
        path = os.fspath(file_name)
        if os.path.splitext(path)[1].lower() not in _OWN_FORMATS:
            return super().save_current_mesh(path, *args, **kwargs)
        formats.write_cloud(self.current_cloud(), path)
        return None

    def current_cloud(self) -> Cloud:
        """The current layer as a ``Cloud`` with the attributes pcprep knows.
        A face attribute the layer no longer holds (a MeshLab filter that
        rebuilt the faces, or a layer copy, dropped it) is named in
        ``meta["face_properties"]``, so a write of the faces refuses to lose
        it without a word (``formats.check_faces``)."""
        attrs, meta, faces = self._layers.get(self.current_mesh_id(), ({}, {}, {}))
        mesh = self.current_mesh()
        names = tuple(k for k in attrs if _apply._has_attribute(mesh, k))
        cloud = mesh_to_cloud(mesh, names)
        typed = {k: _restore(v, attrs[k]) for k, v in cloud.attributes.items()}
        values, lost = {}, []
        for name, (dtype, width) in faces.items() if cloud.faces is not None else ():
            try:
                cols = [np.array(mesh.face_custom_scalar_attribute_array(c), np.float64)
                        for c in face_attribute_columns(name, width)]
            except Exception:  # pymeshlab raises its own type for a missing attribute
                lost.append(name)
                continue
            v = cols[0] if width is None else (np.column_stack(cols) if cols else
                                               np.empty((len(cloud.faces), 0)))
            values[name] = _restore(v, dtype)
        if lost:
            meta = {**meta, "face_properties": (*meta.get("face_properties", ()), *lost)}
        return cloud.with_(attributes=typed, meta=meta, face_attributes=values)

    # -- filter scripts ---------------------------------------------------------
    def load_filter_script(self, path) -> None:
        """Read and check a ``.mlx`` script of MeshLab and pcprep steps; nothing
        runs until ``apply_filter_script``."""
        try:
            root = ET.parse(os.fspath(path)).getroot()
        except (ET.ParseError, OSError) as exc:
            raise InvalidParameterError(f"cannot read filter script {path!r}: {exc}") from exc
        if root.tag != "FilterScript":
            raise InvalidParameterError(f"{path!r} is not a MeshLab filter script "
                                        f"(root element {root.tag!r})")
        steps = []
        for el in root:
            name = el.get("name", "")
            if el.tag == "filter" and _is_pcprep(name):
                spec = registry.get(name)
                given = {p.get("name"): _value(spec, p) for p in el.findall("Param")}
                spec.resolve(given)  # every error before the first step runs
                steps.append(("pcprep", (spec.name, given)))
            elif el.tag in ("filter", "xmlfilter"):
                _check_meshlab(self, el, path)
                steps.append(("meshlab", el))
            else:
                raise InvalidParameterError(f"{path!r}: unexpected element <{el.tag}>")
        self._loaded = steps

    def apply_filter_script(self) -> None:
        """Run the loaded script's steps in order on the current layer."""
        for kind, step in self._loaded:
            if kind == "pcprep":
                name, params = step
                self.apply_filter(name, **params)
            else:
                _run_meshlab(self, step)
                self._record.append(step)

    def save_filter_script(self, path) -> None:
        """Write every filter applied through this object, in order, as ``.mlx``."""
        root = ET.Element("FilterScript")
        root.extend(self._record)
        ET.indent(root, space=" ")
        with open(os.fspath(path), "w", encoding="utf-8") as f:
            f.write("<!DOCTYPE FilterScript>\n")
            f.write(ET.tostring(root, encoding="unicode"))
            f.write("\n")

    def clear_recorded_script(self) -> None:
        self._record = []


def _kept_rows(meta: dict, count: int, idx: np.ndarray) -> dict:
    """A layer's file ``meta`` after a pcprep removal that kept rows ``idx``
    of its ``count`` vertices: the file's rows that remain
    (``info["kept_rows"]``, as ``Cloud.subset`` records them), so that the
    save renumbers the PLY's edges (``ply.kept_elements``).  Recorded only
    where the layer still held the rows pcprep last knew of; after a MeshLab
    filter that changed them, the rows are not known and the save refuses
    to write the edges wrong (``formats.check_elements``)."""
    info = meta.get("ply", {})
    if not info.get("other_elements"):
        return meta
    rows = info.get("kept_rows")
    if count != (info.get("n_vertices") if rows is None else len(rows)):
        return {**meta, "ply": {**info, "kept_rows": None}}
    idx = np.asarray(idx, dtype=np.int64)
    return {**meta, "ply": {**info, "kept_rows": idx if rows is None else rows[idx]}}


def _restore(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """A layer's float64 attribute back in its file type when it fits exactly."""
    dtype = np.dtype(dtype)
    if dtype == values.dtype:
        return values
    cast = values.astype(dtype)
    return cast if np.array_equal(cast.astype(values.dtype), values) else values


def _value(spec, param: ET.Element):
    name, text = param.get("name"), param.get("value")
    p = spec.param(name)
    if text is None:
        raise InvalidParameterError(f"{spec.name}: parameter {name!r} has no value")
    if p.kind is bool:
        if text.lower() not in ("true", "false", "1", "0"):
            raise InvalidParameterError(f"{spec.name}: {name} must be true or false, got {text!r}")
        return text.lower() in ("true", "1")
    try:
        return p.kind(text) if p.kind is not int else int(float(text))
    except ValueError:
        raise InvalidParameterError(f"{spec.name}: {name} must be a {p.kind.__name__}, "
                                    f"got {text!r}") from None


def pcprep_step_script(spec, params: dict, path) -> None:
    """Write one pcprep step as a ``.mlx`` filter script."""
    ms = MeshSet()
    ms._record.append(_pcprep_element(spec, params))
    ms.save_filter_script(path)


def _pcprep_element(spec, params: dict) -> ET.Element:
    el = ET.Element("filter", name=spec.name)
    for p in spec.params:
        value = params.get(p.name)
        if value is None:  # resolved from the data at run time
            continue
        text = ("true" if value else "false") if p.kind is bool else repr(value) \
            if p.kind is float else str(value)
        ET.SubElement(el, "Param", name=p.name, value=text, type=_TYPES[p.kind],
                      description=p.name, tooltip=p.help)
    return el


def _meshlab_elements(ms) -> list[ET.Element]:
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "step.mlx")
        pymeshlab.MeshSet.save_filter_script(ms, path)
        return list(ET.parse(path).getroot())


def _write_single(el: ET.Element, path: str) -> None:
    root = ET.Element("FilterScript")
    root.append(el)
    with open(path, "w", encoding="utf-8") as f:
        f.write("<!DOCTYPE FilterScript>\n" + ET.tostring(root, encoding="unicode"))


def _python_names() -> dict[str, str]:
    """MeshLab filter label (snake-cased, as pymeshlab once named filters) ->
    pymeshlab name, from the table pymeshlab ships (``keys.txt``)."""
    table = os.path.join(os.path.dirname(pymeshlab.__file__), "keys.txt")
    names = {}
    with open(table, encoding="utf-8") as f:
        for line in f:
            parts = line.split()
            if len(parts) == 2:
                names[parts[0]] = parts[1]
    return names


def _snake(label: str) -> str:
    return re.sub(r"[^0-9a-z]+", "_", label.lower()).strip("_")


def _check_meshlab(ms, el: ET.Element, path) -> None:
    """A MeshLab step must name a filter pymeshlab has, with parameters it knows."""
    label = el.get("name", "")
    names = _python_names()
    pyname = names.get(_snake(label), label if label in pymeshlab.filter_list() else None)
    if pyname is None:
        raise InvalidParameterError(f"{path!r}: MeshLab has no filter named {label!r}")
    probe = pymeshlab.MeshSet()
    probe.create_cube()
    try:
        known = set(probe.filter_parameter_values(pyname))
    except pymeshlab.PyMeshLabException:
        return  # defaults need another kind of input: names checked only
    for p in el.findall("Param"):
        if p.get("name", "").lower() not in known:
            raise InvalidParameterError(
                f"{path!r}: MeshLab filter {label!r} has no parameter {p.get('name')!r}; "
                f"known: {', '.join(sorted(known))}")


def _run_meshlab(ms, el: ET.Element) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        single = os.path.join(tmp, "step.mlx")
        _write_single(el, single)
        pymeshlab.MeshSet.load_filter_script(ms, single)
        pymeshlab.MeshSet.apply_filter_script(ms)
        ms.clear_filter_script()


def _bind(name: str):
    def method(self, **params):
        out = self.apply_filter(name, **params)
        return out or None

    method.__name__ = name
    method.__doc__ = f"pcprep filter ``{name}``: see ``print_filter_parameter_list``."
    return method


for _name in registry.load_all():
    setattr(MeshSet, _name, _bind(_name))
