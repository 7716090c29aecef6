"""
convert.py
----------
Lossless conversion between pymeshlab meshes and NumPy arrays.

A ``Cloud`` (``cloud.py``) holds everything pcprep reads from a file or a
MeshLab layer; files are read and written by ``formats``.  pymeshlab stores
doubles, so float64 arrays round-trip bit-exactly; a layer holds custom
attributes only as float64 scalars, so other dtypes are converted (integers up
to 2**53 exactly).
"""

from __future__ import annotations


import numpy as np

from pcprep.filters._validation import PointCloudError

from . import formats
from .cloud import Cloud
from .formats import file_mode  # noqa: F401  (re-exported for the harness)


class MissingAttributeError(ValueError):
    """A filter needs a per-vertex attribute (e.g. normals) the layer lacks."""


def mesh_to_cloud(mesh, attributes: tuple[str, ...] = ()) -> Cloud:
    """Copy a ``pymeshlab.Mesh`` into a ``Cloud``.

    ``attributes`` names custom per-vertex scalar attributes to carry (pymeshlab
    cannot list them).  A layer built from Python always has normals, colours
    and quality, so what carries no information counts as absent: normals that
    are zero on every row, one colour on every vertex, quality zero everywhere.
    Normals zero on some rows only are kept (the filters then name those rows).
    """
    pts = np.array(mesh.vertex_matrix(), dtype=np.float64)
    nrm = np.array(mesh.vertex_normal_matrix(), dtype=np.float64)
    if nrm.shape != pts.shape or (np.abs(nrm) < 1e-300).all():
        nrm = None
    colors = np.array(mesh.vertex_color_matrix(), dtype=np.float64) if mesh.has_vertex_color() else None
    if colors is not None and len(colors) and (colors == colors[0]).all():
        colors = None
    quality = np.array(mesh.vertex_scalar_array(), dtype=np.float64) if mesh.has_vertex_scalar() else None
    if quality is not None and not quality.any():
        quality = None
    faces = None
    if mesh.face_number() > 0:
        faces = np.array(mesh.face_matrix(), dtype=np.int64)
    attrs = {}
    for name in attributes:
        try:
            attrs[name] = np.array(mesh.vertex_custom_scalar_attribute_array(name), dtype=np.float64)
        except Exception as exc:  # pymeshlab raises its own exception type
            raise MissingAttributeError(f"layer has no custom vertex attribute {name!r}") from exc
    return Cloud(pts, nrm, colors, quality, faces, attrs, label=str(mesh.label()))


def cloud_to_mesh(cloud: Cloud):
    """Build a ``pymeshlab.Mesh`` from a ``Cloud`` (every attribute kept).  To
    put it in a MeshSet that will run expression filters, use
    ``add_cloud_layer`` instead (see there)."""
    import pymeshlab

    for name, values in cloud.attributes.items():  # before any layer is made
        _check_scalar(name, np.asarray(values))
    kwargs = {"vertex_matrix": np.ascontiguousarray(cloud.points, dtype=np.float64)}
    if cloud.faces is not None and len(cloud.faces):
        kwargs["face_matrix"] = np.ascontiguousarray(cloud.faces, dtype=np.int32)
    if cloud.normals is not None:
        kwargs["v_normals_matrix"] = np.ascontiguousarray(cloud.normals, dtype=np.float64)
    if cloud.colors is not None:
        kwargs["v_color_matrix"] = np.ascontiguousarray(cloud.colors, dtype=np.float64)
    if cloud.quality is not None:
        kwargs["v_scalar_array"] = np.ascontiguousarray(cloud.quality, dtype=np.float64)
    mesh = pymeshlab.Mesh(**kwargs)
    for name, values in cloud.attributes.items():
        add_attribute(mesh, name, values)
    add_face_attributes(mesh, cloud)
    return mesh


def add_attribute(mesh, name: str, values) -> None:
    """Attach a per-point attribute to ``mesh``: an (n, 3) array as a custom point
    attribute, anything else as float64 scalar columns (``name``, or ``name_k``
    for the k-th column of a wider array)."""
    values = np.asarray(values)
    _check_scalar(name, values)
    if values.ndim == 2 and values.shape[1] == 3:
        mesh.add_vertex_custom_point_attribute(np.ascontiguousarray(values, np.float64), name)
        return
    for key, col in _scalar_columns(name, values):
        mesh.add_vertex_custom_scalar_attribute(col, key)


def add_face_attributes(mesh, cloud: Cloud) -> None:
    """Attach ``cloud``'s face attributes to ``mesh`` (which holds its faces)
    as float64 custom face scalars, ``name`` or ``name_k`` for the k-th
    column of an (f, k) one: MeshLab keeps a face's custom attributes with
    the face through its own filters (a removal drops them with the face)."""
    for name, values in cloud.face_attributes.items():
        for key, col in _scalar_columns(name, np.asarray(values)):
            mesh.add_face_custom_scalar_attribute(col, key)


def face_attribute_columns(name: str, width: int | None) -> list[str]:
    """The custom face scalars ``add_face_attributes`` names for attribute
    ``name`` of ``width`` columns (None: one value per face)."""
    return [name] if width is None else [f"{name}_{k}" for k in range(width)]


def _check_scalar(name: str, values: np.ndarray) -> None:
    if values.dtype == object:
        raise PointCloudError(f"per-vertex {name!r} holds a list per point (a PLY list "
                              "property), which a MeshLab layer has no attribute for; "
                              "pcprep keeps it in its filter commands from PLY to PLY")


def _scalar_columns(name: str, values: np.ndarray):
    """A per-point attribute as float64 scalar columns (``name``, or ``name_k``)."""
    if values.ndim == 1:
        return [(name, np.ascontiguousarray(values, dtype=np.float64))]
    return [(f"{name}_{k}", np.ascontiguousarray(values[:, k], dtype=np.float64))
            for k in range(values.shape[1])]


def add_cloud_layer(ms, cloud: Cloud, label: str = "") -> int:
    """Add ``cloud`` to ``ms`` as a new current layer and return its id.

    Custom attributes are attached after the layer is in the MeshSet: a layer
    made from a ``Mesh`` that already carried Python-added attributes crashes
    MeshLab's expression filters (``compute_coord_by_function`` and the like).
    """
    for name, values in cloud.attributes.items():  # before the layer is added
        _check_scalar(name, np.asarray(values))
    ms.add_mesh(cloud_to_mesh(cloud.with_(attributes={}, face_attributes={})),
                label or cloud.label or "cloud")
    mesh = ms.current_mesh()
    for name, values in cloud.attributes.items():
        add_attribute(mesh, name, values)
    add_face_attributes(mesh, cloud)
    return ms.current_mesh_id()


def meshset_to_cloud(ms, attributes: tuple[str, ...] = ()) -> Cloud:
    """The current layer of a ``MeshSet`` as a ``Cloud``."""
    if ms.mesh_number() == 0:
        raise PointCloudError("the MeshSet has no layer")
    return mesh_to_cloud(ms.current_mesh(), attributes)


def load_cloud(path, *, nonfinite: str = "error") -> Cloud:
    """Read a file with every per-vertex attribute (see ``formats.read_cloud``)."""
    return formats.read_cloud(path, nonfinite=nonfinite)


def save_cloud(cloud: Cloud, path, *, require: tuple[str, ...] = (),
               ramp: bool = False) -> None:
    """Write ``cloud`` atomically with every attribute (see ``formats.write_cloud``).

    ``require`` names what the format must store (``"normal"``, ``"color"``,
    ``"quality"``, ``"attributes"``), or ``PointCloudError`` says it cannot and
    nothing is written.  ``ramp`` colours the vertices from their quality in
    [0, 1] with MeshLab's red-green-blue quality ramp.
    """
    if ramp and cloud.quality is not None:
        cloud = cloud.with_(colors=quality_ramp(cloud.quality))
    formats.write_cloud(cloud, path, needs=tuple(require))


#: the ramp's colours in order (RGBA, 0-255): red, yellow, green, cyan, blue
_RAMP = np.array([[255, 0, 0, 255], [255, 255, 0, 255], [0, 255, 0, 255],
                  [0, 255, 255, 255], [0, 0, 255, 255]], dtype=np.float32)


def quality_ramp(quality: np.ndarray) -> np.ndarray:
    """MeshLab's quality colour ramp over [0, 1] (RGBA in [0, 1]).

    The rule of vcg's ``Color4::SetColorRamp`` (what MeshLab's "Colorize by
    vertex Quality" applies), in its single-precision arithmetic: below 0
    red; then four quarters, each a linear blend red → yellow → green → cyan
    → blue at ``x = w / step`` (``w`` the value less the quarters passed,
    ``step`` = 1/4), truncated to 8 bits; at or past 1 (and NaN) blue.  Done
    here in NumPy instead of through a pymeshlab MeshSet, which took 0.3 s per
    10⁶ rows of every streamed write (and aborts the process on ±inf); a test
    compares the two bit for bit.
    """
    f32 = np.float32
    v = np.asarray(quality, dtype=np.float64).astype(f32)
    step = (f32(1.0) - f32(0.0)) / f32(4.0)
    w = [v - f32(0.0)]
    for _ in range(3):
        w.append(w[-1] - step)
    seg = np.full(len(v), 4, dtype=np.intp)          # past the last quarter: blue
    for i in (3, 2, 1, 0):                           # the first quarter that holds it
        seg[w[i] < step] = i
    below = v < f32(0.0)
    seg[below] = 0
    x = np.choose(np.minimum(seg, 3), w) / step
    x[(seg == 4) | below] = 0.0                      # a plain colour, not a blend
    a = _RAMP[seg]
    b = _RAMP[np.minimum(seg + 1, 4)]
    x = x[:, None]
    rgba = (b * x + a * (f32(1.0) - x)).astype(np.uint8)
    return rgba.astype(np.float64) / 255.0
