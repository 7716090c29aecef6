"""
convert.py
----------
Lossless conversion between pymeshlab meshes and NumPy arrays.

A ``Cloud`` holds everything pcprep reads from or writes to a MeshLab layer:
positions, normals, colours, quality, faces and named custom per-vertex
scalars.  pymeshlab stores doubles, so float64 arrays round-trip bit-exactly.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import numpy as np

from pcprep.filters._validation import PointCloudError


class MissingAttributeError(ValueError):
    """A filter needs a per-vertex attribute (e.g. normals) the layer lacks."""


@dataclass(frozen=True)
class Cloud:
    """Arrays of one MeshLab layer.

    Attributes
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64 or None
        None when the layer has no usable normals (pymeshlab reports zero
        vectors for clouds loaded without normals).
    colors : (n, 4) float64 in [0, 1] or None
    quality : (n,) float64 or None
    faces : (f, 3) int or None
    attributes : dict of str -> (n,) float64
        Custom per-vertex scalar attributes carried through.
    label : str
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    quality: np.ndarray | None = None
    faces: np.ndarray | None = None
    attributes: dict = field(default_factory=dict)
    label: str = ""

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, idx: np.ndarray) -> "Cloud":
        """The cloud restricted to vertices ``idx`` (faces dropped)."""
        take = (lambda a: None if a is None else a[idx])
        return Cloud(
            points=self.points[idx],
            normals=take(self.normals),
            colors=take(self.colors),
            quality=take(self.quality),
            faces=None,
            attributes={k: v[idx] for k, v in self.attributes.items()},
            label=self.label,
        )

    def with_(self, **changes) -> "Cloud":
        return replace(self, **changes)


def mesh_to_cloud(mesh, attributes: tuple[str, ...] = ()) -> Cloud:
    """Copy a ``pymeshlab.Mesh`` into a ``Cloud``.

    ``attributes`` names custom per-vertex scalar attributes to carry (pymeshlab
    cannot list them).  Normals that are all zero count as absent.
    """
    pts = np.array(mesh.vertex_matrix(), dtype=np.float64)
    nrm = np.array(mesh.vertex_normal_matrix(), dtype=np.float64)
    if nrm.shape != pts.shape or not np.isfinite(nrm).all() or (
        np.linalg.norm(nrm, axis=1) < 1e-12
    ).any():
        nrm = None
    colors = np.array(mesh.vertex_color_matrix(), dtype=np.float64) if mesh.has_vertex_color() else None
    quality = np.array(mesh.vertex_scalar_array(), dtype=np.float64) if mesh.has_vertex_scalar() else None
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
    """Build a ``pymeshlab.Mesh`` from a ``Cloud`` (every attribute kept)."""
    import pymeshlab

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
        mesh.add_vertex_custom_scalar_attribute(np.ascontiguousarray(values, dtype=np.float64), name)
    return mesh


def meshset_to_cloud(ms, attributes: tuple[str, ...] = ()) -> Cloud:
    """The current layer of a ``MeshSet`` as a ``Cloud``."""
    if ms.mesh_number() == 0:
        raise PointCloudError("the MeshSet has no layer")
    return mesh_to_cloud(ms.current_mesh(), attributes)


def load_cloud(path: str) -> Cloud:
    """Read any format pymeshlab reads (PLY, OBJ, OFF, XYZ, PTS, E57, …).

    Raises ``PointCloudError`` naming the file when it cannot be read or holds
    no vertices.
    """
    import os

    import pymeshlab

    if not os.path.isfile(path):
        raise PointCloudError(f"cannot read {path!r}: no such file")
    if os.path.splitext(path)[1].lower() == ".xyz":
        return _load_xyz(path)
    ms = pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(str(path))
    except Exception as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PointCloudError(f"cannot read {path!r}: {msg}") from exc
    cloud = meshset_to_cloud(ms)
    if len(cloud) == 0:
        raise PointCloudError(f"cannot read {path!r}: the file holds no vertices")
    return cloud


def save_cloud(cloud: Cloud, path: str, *, require: tuple[str, ...] = (),
               ramp: bool = False) -> None:
    """Write ``cloud`` atomically: a temporary file in the same folder is
    renamed over ``path`` only once fully written, so a failure never leaves a
    partial output.  Normals, colours and quality are saved where the format
    supports them; names in ``require`` (``"normal"``, ``"color"``,
    ``"quality"``) must be stored, or ``PointCloudError`` says the format
    cannot hold them and nothing is written.  ``ramp`` colours the vertices
    from their quality in [0, 1] with MeshLab's quality ramp.
    """
    import os
    import tempfile

    import pymeshlab

    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise PointCloudError(f"cannot write {path!r}: folder {folder!r} does not exist")
    ext = os.path.splitext(path)[1]
    if ext.lower() == ".xyz":
        _save_xyz(cloud, path, folder, require)
        return
    if not ext:
        raise PointCloudError(f"cannot write {path!r}: the file name needs an extension (.ply, .obj, …)")
    if ext.lower() == ".e57":
        _check_float32(cloud, path)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(cloud_to_mesh(cloud), cloud.label or "cloud")
    if ramp and cloud.quality is not None:
        ms.compute_color_from_scalar_per_vertex(minval=0.0, maxval=1.0)
        cloud = cloud.with_(colors=np.zeros((len(cloud), 4)))  # colours are now saved
    fd, tmp = tempfile.mkstemp(prefix=".pcprep-", suffix=ext, dir=folder)
    os.close(fd)
    try:
        dropped = _save_current(ms, tmp, cloud)
        missing = [r for r in require if f"save_vertex_{r}" in dropped]
        if missing:
            raise PointCloudError(
                f"cannot write {path!r}: the {ext} format cannot store per-vertex "
                f"{' and '.join(missing)}; use .ply"
            )
        os.chmod(tmp, file_mode())  # mkstemp creates 0600
        os.replace(tmp, path)
    except Exception as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, PointCloudError):
            raise
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PointCloudError(f"cannot write {path!r}: {msg}") from exc


def file_mode() -> int:
    """Permissions of a newly created file under the current umask (0644 usually)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _check_float32(cloud: Cloud, path: str) -> None:
    """pymeshlab writes E57 coordinates as float32: refuse when that would move
    points by more than 1e-6 of the cloud's extent (e.g. UTM offsets)."""
    pts = cloud.points
    err = float(np.abs(pts.astype(np.float32).astype(np.float64) - pts).max())
    extent = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    if err > 1e-6 * max(extent, 1e-300):
        raise PointCloudError(
            f"cannot write {path!r}: the E57 writer stores float32 coordinates, which would "
            f"move points by up to {err:.3g} (cloud extent {extent:.3g}); use .ply"
        )


def _save_current(ms, path: str, cloud: Cloud) -> set:
    """Save the current layer with every attribute the format accepts and
    return the set of options the format refused."""
    wanted = {
        "save_vertex_normal": cloud.normals is not None,
        "save_vertex_color": cloud.colors is not None,
        "save_vertex_quality": cloud.quality is not None,
    }
    refused: set = set()
    while True:
        try:
            ms.save_current_mesh(path, **{k: v for k, v in wanted.items() if k not in refused})
            return {k for k in refused if wanted[k]}
        except Exception as exc:
            text = str(exc)
            bad = [k for k in wanted if k not in refused and k in text]
            if not bad:
                raise
            refused.update(bad)


# pymeshlab's XYZ reader silently skips rows it cannot parse (a NaN row vanishes,
# shifting every later index) and its writer keeps only 6 decimals, so pcprep
# reads and writes this one text format itself: full precision, every row kept.

def _load_xyz(path: str) -> Cloud:
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = np.loadtxt(path, dtype=np.float64, ndmin=2, comments="#")
    except (ValueError, OSError) as exc:
        raise PointCloudError(f"cannot read {path!r}: {str(exc).splitlines()[0]}") from exc
    if data.size == 0:
        raise PointCloudError(f"cannot read {path!r}: the file holds no vertices")
    if data.shape[1] not in (3, 6):
        raise PointCloudError(
            f"cannot read {path!r}: expected 3 (x y z) or 6 (x y z nx ny nz) columns, "
            f"got {data.shape[1]}"
        )
    normals = data[:, 3:6].copy() if data.shape[1] == 6 else None
    if normals is not None and (np.linalg.norm(normals, axis=1) < 1e-12).any():
        normals = None
    return Cloud(np.ascontiguousarray(data[:, :3]), normals, label=os.path.basename(path))


def _save_xyz(cloud: Cloud, path: str, folder: str, require: tuple[str, ...]) -> None:
    import os
    import tempfile

    missing = [r for r in require if r in ("quality", "color")]
    if missing:
        raise PointCloudError(
            f"cannot write {path!r}: the .xyz format cannot store per-vertex "
            f"{' and '.join(missing)}; use .ply"
        )
    cols = cloud.points if cloud.normals is None else np.c_[cloud.points, cloud.normals]
    fd, tmp = tempfile.mkstemp(prefix=".pcprep-", suffix=".xyz", dir=folder)
    os.close(fd)
    try:
        np.savetxt(tmp, cols, fmt="%.17g")
        os.chmod(tmp, file_mode())
        os.replace(tmp, path)
    except OSError as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise PointCloudError(f"cannot write {path!r}: {exc}") from exc
