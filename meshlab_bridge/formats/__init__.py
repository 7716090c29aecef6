"""
formats
-------
Point-cloud files in and out with nothing lost: every per-point attribute, the
header (LAS point format, scale/offset, CRS and other VLRs; PLY comments and
property types) and the row order survive a read and a write.

``read_cloud(path)`` returns a ``Cloud``; ``write_cloud(cloud, path)`` writes it
atomically (a temporary file in the destination folder renamed into place);
``check_destination(path, ...)`` says before any work whether a destination can
hold a result (folder writable, format able to store the attributes required,
at full precision).  A non-finite coordinate is never dropped silently: reading
refuses the file, naming the rows, unless ``nonfinite="drop"`` asks to drop
them, and then the dropped row indices are kept in ``cloud.meta["dropped_rows"]``.

Formats: PLY (plyfile: any vertex properties, faces, ASCII and binary), LAS and
LAZ 1.2–1.4 (laspy with the lazrs backend), XYZ, OBJ and OFF (read and written
here, at full precision), PCD as PCL writes it (ASCII and binary) and E57
(pye57).  pymeshlab reads the other mesh formats it knows (STL, PTX, …); pcprep
does not write those, because they cannot hold per-vertex results at full
precision.
"""

from __future__ import annotations

import os
import shutil
import signal
import tempfile
from contextlib import contextmanager, suppress

import numpy as np

from pcprep.filters._validation import PointCloudError

from ..cloud import Cloud
from . import text

#: extension -> module that reads and writes it
_MODULES = {
    ".ply": "ply", ".las": "las", ".laz": "las", ".xyz": "text", ".obj": "text",
    ".off": "text", ".pcd": "pcd", ".e57": "e57",
}
#: formats read through pymeshlab only (never written: see the module docstring)
_PYMESHLAB_ONLY = (".stl", ".ptx", ".pts", ".vmi", ".gltf", ".glb", ".3ds", ".wrl",
                   ".dae", ".ctm", ".x3d", ".asc", ".apts", ".nvm", ".out", ".tri")
#: what each writable format can store, besides positions
CAN_STORE = {
    ".ply": {"normal", "color", "quality", "attributes", "faces"},
    ".las": {"normal", "color", "quality", "attributes"},
    ".laz": {"normal", "color", "quality", "attributes"},
    ".pcd": {"normal", "color", "quality", "attributes"},
    ".e57": {"color"},
    ".xyz": {"normal"},
    ".obj": {"normal", "color", "faces"},
    ".off": {"normal", "color", "faces"},
}


#: the face attributes each format that stores faces writes (PLY: any)
FACE_ATTRIBUTES = {".off": text.OFF_FACE, ".obj": text.OBJ_FACE}


def _module(ext: str):
    from importlib import import_module

    return import_module(f"{__name__}.{_MODULES[ext]}")


def _ext(path) -> str:
    return os.path.splitext(os.fspath(path))[1].lower()


def read_cloud(path, *, nonfinite: str = "error") -> Cloud:
    """Read a point-cloud or mesh file with every per-vertex attribute.

    Parameters
    ----------
    path : str or path-like
    nonfinite : {"error", "drop"}, default="error"
        Rows whose coordinates hold NaN or Inf raise ``PointCloudError`` naming
        them; with ``"drop"`` they are removed and their indices (into the file)
        stored in ``cloud.meta["dropped_rows"]``; a face that uses one of them
        is removed with it, the others renumbered (``Cloud.subset``).

    Raises
    ------
    PointCloudError
        The file is missing, a folder, unreadable, truncated, holds more or
        fewer rows than its header declares, no vertices, or non-finite
        coordinates (with ``nonfinite="error"``).
    """
    path = os.fspath(path)
    if nonfinite not in ("error", "drop"):
        raise PointCloudError(f"read_cloud: nonfinite must be 'error' or 'drop', got {nonfinite!r}")
    if os.path.isdir(path):
        raise PointCloudError(f"cannot read {path!r}: it is a folder, not a file")
    if not os.path.isfile(path):
        raise PointCloudError(f"cannot read {path!r}: no such file")
    if not os.access(path, os.R_OK):
        raise PointCloudError(f"cannot read {path!r}: permission denied")
    ext = _ext(path)
    try:
        if ext in _MODULES:
            cloud = _module(ext).read(path)
        elif ext in _PYMESHLAB_ONLY:
            cloud = _read_pymeshlab(path)
        else:
            raise PointCloudError(
                f"cannot read {path!r}: unknown format {ext or '(no extension)'}; pcprep reads "
                f"{', '.join(sorted({*_MODULES, *_PYMESHLAB_ONLY}))}")
    except PointCloudError:
        raise
    except (ValueError, OSError, KeyError, IndexError, EOFError) as exc:
        raise PointCloudError(f"cannot read {path!r}: {_first_line(exc)}") from exc
    if len(cloud) == 0:
        raise PointCloudError(f"cannot read {path!r}: the file holds no vertices")
    return _nonfinite(cloud, path, nonfinite)


def _nonfinite(cloud: Cloud, path: str, policy: str) -> Cloud:
    bad = ~np.isfinite(cloud.points).all(axis=1)
    if not bad.any():
        return cloud
    rows = np.flatnonzero(bad)
    shown = ", ".join(map(str, rows[:5])) + (", …" if len(rows) > 5 else "")
    if policy == "error":
        raise PointCloudError(
            f"cannot read {path!r}: {len(rows)} row(s) hold NaN or Inf coordinates "
            f"(rows {shown}); remove them, or read with nonfinite='drop' "
            "(CLI: --drop-nonfinite) to drop them and report their indices")
    keep = np.flatnonzero(~bad)
    out = cloud.subset(keep)  # a face that uses a dropped row goes with it
    return out.with_(meta={**out.meta, "dropped_rows": rows})


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def check_destination(path, *, needs: tuple[str, ...] = (), source=None) -> None:
    """Refuse, before any work, a destination that cannot take the result.

    ``needs`` names what the result must keep (``"normal"``, ``"color"``,
    ``"quality"``, ``"attributes"``, ``"faces"``).  The folder must exist and be
    writable, the format must be one pcprep writes and able to store ``needs``,
    and ``path`` must not be a folder.  Writing over ``source`` is allowed (the
    output replaces it atomically).
    """
    path = os.fspath(path)
    ext = _ext(path)
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise PointCloudError(f"cannot write {path!r}: it is a folder")
    if not ext:
        raise PointCloudError(f"cannot write {path!r}: the file name needs an extension "
                              f"({', '.join(sorted(CAN_STORE))})")
    if ext not in CAN_STORE:
        raise PointCloudError(
            f"cannot write {path!r}: pcprep does not write {ext} files (they cannot hold "
            f"per-point results at full precision); use one of {', '.join(sorted(CAN_STORE))}")
    missing = [n for n in needs if n not in CAN_STORE[ext]]
    if missing:
        raise PointCloudError(
            f"cannot write {path!r}: the {ext} format cannot store per-vertex "
            f"{' and '.join(missing)}; use .ply, .las/.laz or .pcd")
    if not os.path.isdir(folder):
        raise PointCloudError(f"cannot write {path!r}: folder {folder!r} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PointCloudError(f"cannot write {path!r}: folder {folder!r} is not writable")
    if ext == ".e57":
        _module(ext).check_available(path)


def check_cloud(cloud: Cloud, path, *, needs: tuple[str, ...] = ()) -> None:
    """Refuse a destination that would lose part of ``cloud`` (its normals,
    colours, quality, named attributes or faces) or its coordinates'
    precision; run it on the input, before a filter starts, and again when
    writing."""
    path = os.fspath(path)
    check_destination(path, needs=needs)
    check_kept(cloud, path)
    if _ext(path) == ".e57":
        from .e57 import check_precision

        check_precision(cloud, path)


def check_kept(cloud: Cloud, path: str) -> None:
    """Refuse a format that cannot store ``cloud``'s normals, colours, quality,
    named attributes or faces (``check_cloud`` without the folder and
    precision tests: a streamed writer runs it on every block)."""
    ext = _ext(path)
    have = {"normal": cloud.normals is not None, "color": cloud.colors is not None,
            "quality": cloud.quality is not None, "attributes": bool(cloud.attributes)}
    if ext == ".e57":  # its own fields, and the colours it was read with, go back
        from .e57 import _RGB, _WRITABLE

        have["attributes"] = any(k not in (*_WRITABLE, *_RGB, "scan_index")
                                 for k in cloud.attributes)
    lists = [k for k, v in cloud.attributes.items() if np.asarray(v).dtype == object]
    if lists and ext != ".ply":
        raise PointCloudError(
            f"cannot write {path!r}: the input's per-vertex {', '.join(lists)} hold a list "
            f"per point (a PLY list property), which only .ply stores")
    lost = [k for k, v in have.items() if v and k not in CAN_STORE[ext]]
    if lost:
        what = ", ".join(sorted(cloud.attributes)) if lost == ["attributes"] else " and ".join(
            {"normal": "normals", "color": "colours", "quality": "quality values",
             "attributes": f"attributes ({', '.join(sorted(cloud.attributes))})"}[k]
            for k in lost)
        raise PointCloudError(
            f"cannot write {path!r}: the {ext} format cannot store the input's per-vertex "
            f"{what}; use .ply, .las/.laz or .pcd, which keep every attribute")
    named = cloud.meta.get("obj", {})
    chains = [k for k in text.OBJ_CHAINS.values() if named.get(k)]
    if chains and ext != ".obj":
        raise PointCloudError(
            f"cannot write {path!r}: the input OBJ's {' and '.join(chains)} (l, p lines) "
            f"have no place in a {ext} file; drop them explicitly (CLI: --drop-elements; "
            "Python: formats.drop_elements(cloud))")
    check_faces(0 if cloud.faces is None else len(cloud.faces), path,
                cloud.meta.get("face_properties", ()), tuple(cloud.face_attributes),
                tuple(k for k in cloud.face_attributes if k in named))
    info = cloud.meta.get("ply", {})
    others = list(info.get("other_elements", {}).values())
    if others:
        from .ply import kept_elements

        kept = {el.name for el in kept_elements(others, len(cloud), info)} if ext == ".ply" \
            else set()
        check_elements([el.name for el in others if el.name not in kept], path)


def check_elements(lost, path) -> None:
    """Refuse a write that would leave out the PLY elements named ``lost``
    (besides the vertices and faces: edges, cameras, range grids, …): a
    format other than PLY has no place for them, and after a removal an
    element that refers to vertex rows by a list (a range grid), or where
    the removal's kept rows are not known (``ply.kept_elements``), would
    refer to the wrong ones.  Dropping them is the user's call
    (``--drop-elements``, ``drop_elements(cloud)``)."""
    if lost:
        why = ("refer to vertex rows the result no longer has" if _ext(path) == ".ply"
               else f"have no place in a {_ext(path)} file")
        raise PointCloudError(
            f"cannot write {os.fspath(path)!r}: the input's PLY element(s) "
            f"{', '.join(lost)} {why}; drop them explicitly (CLI: --drop-elements; "
            "Python: formats.drop_elements(cloud))")


def drop_elements(cloud: Cloud) -> Cloud:
    """``cloud`` to be written without the PLY elements it was read with
    besides its vertices and faces (``check_elements``), or an OBJ's
    polylines and point groups."""
    meta = cloud.meta
    if meta.get("ply", {}).get("other_elements"):
        meta = {**meta, "ply": {**meta["ply"], "other_elements": {}}}
    if any(meta.get("obj", {}).get(k) for k in text.OBJ_CHAINS.values()):
        meta = {**meta, "obj": {k: v for k, v in meta["obj"].items()
                                if k not in text.OBJ_CHAINS.values()}}
    return cloud if meta is cloud.meta else cloud.with_(meta=meta)


def check_faces(count: int, path, properties=(), kept=(), named=()) -> None:
    """Refuse to write ``count`` faces to a format that stores points alone
    (LAS, LAZ, PCD, XYZ, E57); faces that carry ``properties`` (what the
    reader found on the faces besides their vertices and could not keep:
    OBJ texture coordinates on some faces only or with a w, OBJ normals per
    corner, an OFF colour-map index, a PLY list whose length is not a
    number of values per corner); and faces with the
    attributes ``kept`` (``Cloud.face_attributes``: PLY face colours,
    quality, texture coordinates, …) to a format that does not hold them
    (``_unwritable``; ``named``: those that index names an OBJ file gave,
    its objects, groups, materials and smoothing groups, which only OBJ
    holds): each would lose part of the mesh without a word.
    Dropping them is the user's call, made explicitly (``--drop-faces``,
    ``--drop-face-properties``, MeshLab's Remove All Faces, or in Python
    ``cloud.with_(faces=None)`` and ``drop_face_properties(cloud)``)."""
    ext = _ext(path)
    if not count:
        return
    if "faces" not in CAN_STORE.get(ext, ()):
        raise PointCloudError(
            f"cannot write {os.fspath(path)!r}: the {ext} format stores points alone and "
            f"would lose the input's {count} faces; write .ply, .obj or .off to keep them, "
            "or drop them explicitly (CLI: --drop-faces; MeshLab: Remove All Faces, "
            "meshing_remove_all_faces; Python: cloud.with_(faces=None))")
    lost = list(properties) + _unwritable(kept, named, ext)
    if lost:
        why = ("which pcprep does not keep" if properties
               else f"which pcprep does not write to {ext} files")
        raise PointCloudError(
            f"cannot write {os.fspath(path)!r}: the input's faces carry "
            f"{', '.join(lost)}, {why}; drop them explicitly to "
            "write the faces without them (CLI: --drop-face-properties; Python: "
            "formats.drop_face_properties(cloud)), or the vertices alone (--drop-faces)")


def _unwritable(names, named, ext: str) -> list:
    """The face attributes ``names`` a file of type ``ext`` cannot hold: for
    PLY those ``named`` (indices of an OBJ's names, which PLY has no place
    for); for OFF all but a whole colour (red, green, blue, and alpha or
    not), and all of a partial one; for OBJ all but texture coordinates and
    the ``named`` objects, groups, materials and smoothing groups."""
    if ext == ".ply":
        return list(named)
    can = FACE_ATTRIBUTES.get(ext, ())
    lost = [k for k in names if k not in can or (ext == ".obj" and k != "texcoord"
                                                 and k not in named)]
    if ext == ".off" and not lost and names and not {"red", "green", "blue"} <= set(names):
        return list(names)
    return lost


def drop_face_properties(cloud: Cloud) -> Cloud:
    """``cloud`` whose faces are to be written without what the reader found
    on them (``check_faces``): its face attributes and the properties it
    could not keep; the faces themselves stay."""
    return cloud.with_(meta={**cloud.meta, "face_properties": ()}, face_attributes={})


def write_cloud(cloud: Cloud, path, *, needs: tuple[str, ...] = ()) -> None:
    """Write ``cloud`` to ``path`` atomically in the format its extension names.

    Every attribute the format can store is written, at full precision; a
    temporary file in the same folder is renamed over ``path`` only once
    complete, and removed on any error or on SIGINT/SIGTERM, so a failure never
    leaves a partial or stray file.
    """
    path = os.fspath(path)
    check_cloud(cloud, path, needs=needs)
    ext = _ext(path)
    mod = _module(ext)
    with _temporary(path) as tmp:
        mod.write(cloud, tmp)


@contextmanager
def _temporary(path: str):
    """A temporary file beside ``path``, moved over it on success and removed
    on failure or interruption."""
    folder = os.path.dirname(os.path.abspath(path))
    ext = _ext(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=".pcprep-", suffix=ext, dir=folder)
    except OSError as exc:
        raise PointCloudError(f"cannot write {path!r}: {exc.strerror or exc}") from exc
    os.close(fd)

    def _cleanup(signum, frame):
        if os.path.exists(tmp):
            os.unlink(tmp)
        previous = old[signum]
        if callable(previous):
            previous(signum, frame)
        raise KeyboardInterrupt if signum == signal.SIGINT else SystemExit(128 + signum)

    old = {}
    main_thread = _in_main_thread()
    if main_thread:
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, _cleanup)
    try:
        yield tmp
        os.chmod(tmp, file_mode())  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, (PointCloudError, KeyboardInterrupt, SystemExit)):
            raise
        if isinstance(exc, (OSError, ValueError, TypeError)):
            raise PointCloudError(f"cannot write {path!r}: {_first_line(exc)}") from exc
        if isinstance(exc, _codec_errors()):  # their message does not say why: the room does
            free = shutil.disk_usage(folder).free
            raise PointCloudError(f"cannot write {path!r}: {_first_line(exc)} ({folder} has "
                                  f"{free / 2**20:.1f} MiB free)") from exc
        raise
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _codec_errors() -> tuple:
    """What LAS/LAZ writing raises when the file cannot be written: lazrs
    reports a failed write (a full disk among them) as ``LazrsError``, a
    RuntimeError, and laspy its own errors as ``LaspyException``."""
    errors = []
    with suppress(ImportError):
        from lazrs import LazrsError
        errors.append(LazrsError)
    with suppress(ImportError):
        from laspy.errors import LaspyException
        errors.append(LaspyException)
    return tuple(errors)


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def file_mode() -> int:
    """Permissions of a newly created file under the current umask (0644 usually)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _read_pymeshlab(path: str) -> Cloud:
    import pymeshlab

    from ..convert import mesh_to_cloud

    ms = pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(path)
    except Exception as exc:  # pymeshlab raises its own exception type
        raise PointCloudError(f"cannot read {path!r}: {_first_line(exc)}") from exc
    cloud = mesh_to_cloud(ms.current_mesh())
    return cloud.with_(label=os.path.basename(path), meta={"format": _ext(path)})
