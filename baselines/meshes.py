"""
meshes.py
---------
Triangle meshes as ground truth: vertex samples with area-weighted normals and
dihedral-angle sharp / boundary labels, uniform surface sampling with exact
distances to sharp and boundary edges, and loaders for pymeshlab's bundled
sample meshes and the optional shared model folder (``None`` when absent).
"""

from __future__ import annotations

import logging
import os
import pathlib
from dataclasses import replace

import numpy as np

from pcprep.filters._validation import (
    PointCloudError,
    as_points,
    check_choice,
    check_param,
    check_seed,
)
from pcprep.filters.neighbors import average_spacing

from ._sample import Sample, _segment_distance

log = logging.getLogger("pcprep")

#: the benchmark's truth rules (see ``datasets.sharp_truth`` / ``rim_truth``)
SHARP_POSITIVE_DEG = 40.0
SHARP_IGNORE_DEG = 20.0
RIM_BAND = 1.5
RIM_CARE = 2.5


# ---------------------------------------------------------------------------
# triangle meshes

def _mesh_arrays(V, F, func):
    V = as_points(V, func=func, name="V", min_points=3)
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0:
        raise PointCloudError(
            f"{func}: F must have shape (m, 3) with m > 0, got {F.shape}")
    if not np.issubdtype(F.dtype, np.integer):
        if not np.all(np.mod(F, 1) == 0):
            raise PointCloudError(f"{func}: F must hold integer vertex indices")
    F = F.astype(np.int64)
    if F.min() < 0 or F.max() >= len(V):
        raise PointCloudError(f"{func}: F holds indices outside [0, {len(V)})")
    return V, F


def _face_geometry(V, F):
    """Area-weighted face normals (2 area n), unit normals and areas."""
    cr = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    dbl = np.linalg.norm(cr, axis=1)
    unit = cr / np.maximum(dbl, 1e-300)[:, None]
    return cr, unit, 0.5 * dbl


def _edge_table(F):
    """Unique undirected edges, the faces of each (first two) and its face count."""
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    fid = np.tile(np.arange(len(F)), 3)
    e.sort(axis=1)
    uniq, inv, cnt = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    order = np.argsort(inv, kind="stable")
    first = np.searchsorted(inv[order], np.arange(len(uniq)))
    f0 = fid[order[first]]
    f1 = fid[order[np.minimum(first + 1, len(order) - 1)]]
    return uniq, f0, f1, cnt


def _edge_angles(F, unit):
    """Edges, dihedral (normal-to-normal) angle in degrees (nan on boundary /
    non-manifold edges) and the number of faces of each edge."""
    edges, f0, f1, cnt = _edge_table(F)
    cosang = np.clip(np.einsum("ij,ij->i", unit[f0], unit[f1]), -1.0, 1.0)
    ang = np.where(cnt == 2, np.degrees(np.arccos(cosang)), np.nan)
    return edges, ang, cnt


def second_row(F, mask, n: int, within=None) -> np.ndarray:
    """(n,) bool: the vertices joined by a mesh edge to a vertex of ``mask`` that
    are not in ``mask`` themselves (and are in ``within`` when given)."""
    F = np.asarray(F, dtype=np.int64)
    mask = np.asarray(mask, dtype=bool)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    out = np.zeros(n, dtype=bool)
    for a, b in ((0, 1), (1, 0)):
        out[e[mask[e[:, a]], b]] = True
    out &= ~mask
    if within is not None:
        out &= np.asarray(within, dtype=bool)
    return out


def _mesh_sharp_truth(V, F) -> tuple[np.ndarray, np.ndarray]:
    """``(positive, care)`` of a mesh's vertices: positive = a vertex of an edge of
    dihedral angle >= 40°; negative = neither a vertex of an edge of >= 20° nor
    joined by a mesh edge to one; the rest "don't care"."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    _, unit, _ = _face_geometry(V, F)
    edges, ang, _ = _edge_angles(F, unit)
    a = np.nan_to_num(ang, nan=-1.0)
    pos = np.zeros(len(V), dtype=bool)
    pos[edges[a >= SHARP_POSITIVE_DEG].ravel()] = True
    near = np.zeros(len(V), dtype=bool)
    near[edges[a >= SHARP_IGNORE_DEG].ravel()] = True
    neg = ~near & ~second_row(F, near, len(V))
    return pos, pos | neg


def mesh_sample(V, F, *, sharp_angle_deg: float = 30.0, name: str = "mesh",
                drop_unreferenced: bool = True, merge_duplicates: bool = True) -> Sample:
    """The vertices of a triangle mesh as a Sample with normals and labels.

    Parameters
    ----------
    V : (n, 3) float
        Vertices.
    F : (m, 3) int
        Triangles (consistently oriented for meaningful dihedral angles).
    sharp_angle_deg : float, default=30
        An edge shared by two faces whose normals differ by more than this is sharp.
    name : str
    drop_unreferenced : bool, default=True
        Remove vertices used by no face (they have no normal);
        ``extra["vertex_idx"]`` maps the kept vertices to the input.
    merge_duplicates : bool, default=True
        Merge vertices at exactly the same position (as MeshLab's
        ``meshing_remove_duplicate_vertices`` does; pcprep's filters reject
        duplicate points); faces that collapse are dropped.

    Returns
    -------
    Sample
        normals: area-weighted vertex normals; sharp: vertex on a sharp edge;
        rim: vertex on a boundary edge (an edge with a single face);
        ``extra["nonmanifold"]``: vertex on an edge with more than two faces;
        ``extra["sharp_pos"]`` / ``["sharp_care"]`` / ``["rim_care"]``: the
        benchmark's truth rules (``datasets.sharp_truth`` / ``rim_truth``).
    """
    func = "mesh_sample"
    V, F = _mesh_arrays(V, F, func)
    sharp_angle_deg = check_param(sharp_angle_deg, func=func, name="sharp_angle_deg",
                                  low=0.0, high=180.0, unit="deg")
    vidx = np.arange(len(V))
    if drop_unreferenced:
        used = np.zeros(len(V), dtype=bool)
        used[F.ravel()] = True
        if not used.all():
            vidx = np.flatnonzero(used)
            remap = np.full(len(V), -1, dtype=np.int64)
            remap[vidx] = np.arange(len(vidx))
            V, F = V[vidx], remap[F]
    if merge_duplicates:
        _, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
        if len(first) < len(V):
            log.info("mesh_sample: merged %d duplicate vertices", len(V) - len(first))
            order = np.sort(first)  # keep the first occurrence, in input order
            rank = np.empty(len(first), dtype=np.int64)
            rank[np.argsort(first)] = np.arange(len(first))
            F = rank[inverse.ravel()][F]
            F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
            V, vidx = V[order], vidx[order]
    cr, unit, _ = _face_geometry(V, F)
    vn = np.zeros_like(V)
    for j in range(3):
        np.add.at(vn, F[:, j], cr)
    length = np.linalg.norm(vn, axis=1)
    bad = length < 1e-300
    vn = np.where(bad[:, None], 0.0, vn / np.where(bad, 1.0, length)[:, None])
    if bad.any():
        log.info("mesh_sample: %d vertices without a normal (zero area / unused)",
                 bad.sum())
    edges, ang, cnt = _edge_angles(F, unit)
    boundary = cnt == 1
    sharp = np.zeros(len(V), dtype=bool)
    sharp[edges[np.nan_to_num(ang, nan=-1.0) > sharp_angle_deg].ravel()] = True
    rim = np.zeros(len(V), dtype=bool)
    rim[edges[boundary].ravel()] = True
    nonman = np.zeros(len(V), dtype=bool)
    nonman[edges[cnt > 2].ravel()] = True
    pos, care = _mesh_sharp_truth(V, F)
    extra = {"vertex_idx": vidx, "nonmanifold": nonman, "zero_normal": bad,
             "sharp_pos": pos, "sharp_care": care,
             "rim_care": ~second_row(F, rim, len(V))}
    return Sample(V, vn, sharp, rim, average_spacing(V), name, F, extra)


def _corner_normals(V, F, cr, unit, smooth_angle_deg):
    """(m, 3, 3) per-corner normals: area-weighted mean of the normals of the faces
    around the corner's vertex that lie within ``smooth_angle_deg`` of the face's
    own normal (auto-smoothing groups, so creases stay sharp)."""
    m = len(F)
    corner_v = F.ravel()  # corner c = 3 f + j
    corner_f = np.repeat(np.arange(m), 3)
    order = np.argsort(corner_v, kind="stable")
    sv = corner_v[order]
    start = np.searchsorted(sv, np.arange(len(V)))
    stop = np.searchsorted(sv, np.arange(len(V)), side="right")
    val = stop[corner_v] - start[corner_v]  # faces around each corner's vertex
    cos_t = np.cos(np.radians(smooth_angle_deg))
    out = np.zeros((3 * m, 3))
    for s in range(0, 3 * m, 262_144):
        e = min(3 * m, s + 262_144)
        rep = np.repeat(np.arange(s, e), val[s:e])
        offs = np.arange(len(rep)) - np.repeat(np.cumsum(val[s:e]) - val[s:e], val[s:e])
        g = corner_f[order[start[corner_v[rep]] + offs]]
        w = (np.einsum("ij,ij->i", unit[g], unit[corner_f[rep]]) >= cos_t)
        acc = np.zeros((e - s, 3))
        np.add.at(acc, rep - s, cr[g] * w[:, None])
        out[s:e] = acc
    length = np.linalg.norm(out, axis=1, keepdims=True)
    fallback = unit[corner_f]
    out = np.where(length > 1e-300, out / np.maximum(length, 1e-300), fallback)
    return out.reshape(m, 3, 3)


def sample_mesh_surface(V, F, n: int = 20000, seed: int | None = 0, *,
                        sharp_angle_deg: float = 30.0, sharp_width: float = 1.0,
                        rim_width: float = 1.5, normals: str = "auto",
                        name: str = "mesh", sampling: str = "random") -> Sample:
    """Draw ``n`` points uniformly (by area) on a triangle mesh, with labels.

    Parameters
    ----------
    V : (nv, 3) float
    F : (m, 3) int
    n : int, default=20000
        Exact number of points.
    seed : int or None, default=0
    sharp_angle_deg : float, default=30
        Mesh edges whose adjacent face normals differ by more than this are sharp.
    sharp_width : float, default=1
        A point is sharp when within ``sharp_width`` h of a sharp mesh edge.
    rim_width : float, default=1.5
        A point is on the rim when within ``rim_width`` h of a boundary edge.
    normals : {"auto", "face", "interpolated"}
        "face": the flat face normal; "interpolated": barycentric interpolation
        of area-weighted vertex normals (Phong); "auto": the same interpolation
        but each corner averages only the faces within ``sharp_angle_deg`` of its
        own face, so creases stay sharp and curved parts stay smooth.
    sampling : {"random", "blue", "rows", "aniso"}, default="random"
        "random": i.i.d. by area; the others as in ``datasets.make_shape`` (blue
        noise from 5n random candidates, merged range scans from 12n).

    Returns
    -------
    Sample
        ``extra``: ``face_index`` (n,), ``barycentric`` (n, 3), ``edge_distance``,
        ``boundary_distance``.  h is the average spacing of the sampled points.
    """
    func = "sample_mesh_surface"
    V, F = _mesh_arrays(V, F, func)
    n = check_param(n, func=func, name="n", kind=int, low=7, unit="count")
    seed = check_seed(seed, func=func)
    sharp_angle_deg = check_param(sharp_angle_deg, func=func, name="sharp_angle_deg",
                                  low=0.0, high=180.0, unit="deg")
    sharp_width = check_param(sharp_width, func=func, name="sharp_width", low=0.0,
                              unit="h")
    rim_width = check_param(rim_width, func=func, name="rim_width", low=0.0, unit="h")
    normals = check_choice(normals, func=func, name="normals",
                           choices=("auto", "face", "interpolated"))
    sampling = check_choice(sampling, func=func, name="sampling",
                            choices=("random", "blue", "rows", "aniso"))
    cr, unit, area = _face_geometry(V, F)
    if area.sum() <= 0:
        raise PointCloudError(f"{func}: the mesh has zero total area")
    target = n
    n = {"random": 1, "blue": 5}.get(sampling, 12) * n
    rng = np.random.default_rng(seed)
    fi = rng.choice(len(F), size=n, p=area / area.sum())
    st = rng.random((n, 2))
    flip = st.sum(axis=1) > 1.0
    st[flip] = 1.0 - st[flip]
    bary = np.column_stack([1.0 - st.sum(axis=1), st])
    tri = V[F[fi]]  # (n, 3, 3)
    pts = np.einsum("nj,njd->nd", bary, tri)
    if normals == "face":
        nrm = unit[fi]
    else:
        ang = sharp_angle_deg if normals == "auto" else 180.0
        cn = _corner_normals(V, F, cr, unit, ang)
        nrm = np.einsum("nj,njd->nd", bary, cn[fi])
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.where(length > 1e-12, nrm / np.maximum(length, 1e-300), unit[fi])
    view_dir = None
    if sampling != "random":
        from .datasets import _blue_noise, _range_scans

        if sampling == "blue":
            keep = _blue_noise(pts, target, rng)
        else:
            keep, view_dir = _range_scans(pts, nrm, target, rng,
                                          3.0 if sampling == "aniso" else 1.0)
        pts, nrm, fi, bary = pts[keep], nrm[keep], fi[keep], bary[keep]
    h = average_spacing(pts)
    edges, eang, cnt = _edge_angles(F, unit)
    boundary = cnt == 1
    sel = np.nan_to_num(eang, nan=-1.0) > sharp_angle_deg
    step = 0.25 * h
    ed = _segment_distance(pts, V[edges[sel, 0]], V[edges[sel, 1]], step)
    bd = _segment_distance(pts, V[edges[boundary, 0]], V[edges[boundary, 1]], step)
    a = np.nan_to_num(eang, nan=-1.0)
    d40 = _segment_distance(pts, V[edges[a >= SHARP_POSITIVE_DEG, 0]],
                            V[edges[a >= SHARP_POSITIVE_DEG, 1]], step)
    d20 = _segment_distance(pts, V[edges[a >= SHARP_IGNORE_DEG, 0]],
                            V[edges[a >= SHARP_IGNORE_DEG, 1]], step)
    pos = d40 <= sharp_width * h
    extra = {"face_index": fi, "barycentric": bary, "edge_distance": ed,
             "boundary_distance": bd, "sharp_pos": pos,
             "sharp_care": pos | (d20 > 2.0 * sharp_width * h),
             "rim_care": (bd <= RIM_BAND * h) | (bd > RIM_CARE * h),
             "sampling": sampling}
    if view_dir is not None:
        extra["view_dir"] = view_dir
    return Sample(pts, nrm, ed <= sharp_width * h, bd <= rim_width * h, h, name, None,
                  extra)


# ---------------------------------------------------------------------------
# loaders

def pymeshlab_sample_dir() -> pathlib.Path | None:
    """Folder of pymeshlab's bundled test meshes, or None when unavailable.

    It holds (pymeshlab 2023.12): airplane.obj, bone.ply, bunny.obj (bunny,
    ~35k vertices), bunny10k_textured.obj, chameleon.pts (points only),
    colored_airplane.ply, cow.obj, cube.obj (12 triangles) and
    rangemaps/face000.ply (a range scan of a face).
    """
    try:
        import pymeshlab
    except ImportError:
        return None
    d = pathlib.Path(pymeshlab.__file__).parent / "tests" / "sample_meshes"
    return d if d.is_dir() else None


SAMPLE_MESHES = {
    "airplane": "airplane.obj", "bone": "bone.ply", "bunny": "bunny.obj",
    "bunny10k": "bunny10k_textured.obj", "chameleon": "chameleon.pts",
    "colored_airplane": "colored_airplane.ply", "cow": "cow.obj", "cube": "cube.obj",
    "face": "rangemaps/face000.ply",
}


def load_mesh_file(path, *, sharp_angle_deg: float = 30.0, name: str | None = None
                   ) -> Sample:
    """Load a mesh or point file (pymeshlab formats; PLY2 read here) as a Sample.

    Meshes go through :func:`mesh_sample` (vertex normals, sharp, rim).  Files
    without faces give the stored points with ``sharp = rim = None`` and the
    stored normals when every one is non-zero; otherwise the normals are all
    zero (nothing is estimated) and ``extra["has_normals"]`` is False.
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"load_mesh_file: no such file {path}")
    name = name or path.stem
    if path.suffix.lower() == ".ply2":
        V, F = _read_ply2(path)
        return mesh_sample(V, F, sharp_angle_deg=sharp_angle_deg, name=name)
    import pymeshlab  # only needed for the formats it reads

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    m = ms.current_mesh()
    V = np.array(m.vertex_matrix(), dtype=np.float64)
    F = np.array(m.face_matrix(), dtype=np.int64) if m.face_number() else None
    if F is not None and len(F):
        return mesh_sample(V, F, sharp_angle_deg=sharp_angle_deg, name=name)
    N = np.array(m.vertex_normal_matrix(), dtype=np.float64)
    length = np.linalg.norm(N, axis=1)
    has = bool((length > 1e-12).all())
    if has:
        N = N / length[:, None]
    else:
        N = np.zeros_like(V)
    return Sample(V, N, None, None, average_spacing(V), name, None, {"has_normals": has})


def _read_ply2(path):
    """PLY2 text format: nv, nf, nv lines "x y z", nf lines "3 a b c"."""
    tok = pathlib.Path(path).read_text().split()
    nv, nf = int(tok[0]), int(tok[1])
    V = np.array(tok[2:2 + 3 * nv], dtype=np.float64).reshape(nv, 3)
    F = np.array(tok[2 + 3 * nv:2 + 3 * nv + 4 * nf], dtype=np.int64).reshape(nf, 4)
    if (F[:, 0] != 3).any():
        raise PointCloudError(f"load_mesh_file: {path} has non-triangle faces")
    return V, F[:, 1:]


def load_sample_mesh(name: str, *, sharp_angle_deg: float = 30.0) -> Sample:
    """One of pymeshlab's bundled sample meshes (``SAMPLE_MESHES``) as a Sample.

    Raises ``FileNotFoundError`` when pymeshlab or the file is not available.
    """
    check_choice(name, func="load_sample_mesh", name="name", choices=tuple(SAMPLE_MESHES))
    d = pymeshlab_sample_dir()
    if d is None or not (d / SAMPLE_MESHES[name]).is_file():
        raise FileNotFoundError(
            f"load_sample_mesh: pymeshlab sample {name!r} not available")
    return load_mesh_file(d / SAMPLE_MESHES[name], sharp_angle_deg=sharp_angle_deg,
                          name=name)


#: set by ``use_models_root`` (``pcprep report --models``); wins over the search
_MODELS_ROOT: pathlib.Path | None = None


def use_models_root(path) -> pathlib.Path:
    """Make ``path`` the shared model folder for this process (it must exist)."""
    global _MODELS_ROOT
    root = pathlib.Path(path).expanduser().resolve()
    if not root.is_dir():
        raise FileNotFoundError(f"models folder {root} does not exist")
    _MODELS_ROOT = root
    return root


def _candidates() -> list[pathlib.Path]:
    # the current folder and its parents first: an installed (non-editable)
    # package lives in site-packages, so only the folder the user runs from can
    # say which checkout the report belongs to; the source tree last
    here = pathlib.Path.cwd().resolve()
    out = [d / "shared" / "data" / "models" for d in (here, *here.parents)]
    out.append(pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data"
               / "models")
    return out


def shared_models_root() -> pathlib.Path:
    """Root of the optional shared model folder.

    In order: the folder given to ``use_models_root`` (``pcprep report
    --models``), ``$PCPREP_SHARED_MODELS``, then the first existing
    ``shared/data/models`` in the current folder or one of its parents (so
    ``../shared/data/models`` is found when run from a checkout beside it), then
    beside the source tree.  When none exists, the first candidate is returned
    (loads then find nothing; ``models_hint`` says how to point at the folder).
    """
    if _MODELS_ROOT is not None:
        return _MODELS_ROOT
    env = os.environ.get("PCPREP_SHARED_MODELS")
    if env:
        return pathlib.Path(env)
    cands = _candidates()
    return next((c for c in cands if c.is_dir()), cands[0])


def models_hint() -> str | None:
    """A sentence for the log when no shared model folder is found, else None."""
    root = shared_models_root()
    if root.is_dir():
        return None
    return (f"no shared model folder at {root}: the full benchmarks use generated and "
            "pymeshlab-shipped data only; point them at the models with "
            "pcprep report --models DIR or PCPREP_SHARED_MODELS=DIR")


def load_shared_model(relpath: str, *, root=None, required: bool = False,
                      sharp_angle_deg: float = 30.0) -> Sample | None:
    """Load ``<root>/<relpath>`` (e.g. ``"cad/fandisk_clean.obj"``) as a Sample.

    Returns None when the file is absent (raises ``FileNotFoundError`` instead when
    ``required``).  When a sibling ``<stem>_face_saliency.txt`` exists (the
    ``saliency_unverified/`` models), ``extra["face_saliency"]`` (per face) and
    ``extra["vertex_saliency"]`` (mean over incident faces) are added.
    Formats are whatever pymeshlab reads (obj, off, ply, xyz, ...).
    """
    base = pathlib.Path(root) if root is not None else shared_models_root()
    path = base / relpath
    if not path.is_file():
        if required:
            raise FileNotFoundError(f"load_shared_model: {path} not found (set "
                                    "PCPREP_SHARED_MODELS to the models folder)")
        return None
    sample = load_mesh_file(path, sharp_angle_deg=sharp_angle_deg)
    sal = path.with_name(path.stem + "_face_saliency.txt")
    if sal.is_file() and sample.faces is not None:
        fs = np.loadtxt(sal, dtype=np.float64).reshape(-1)
        if len(fs) == len(sample.faces):
            F = sample.faces
            acc = np.zeros(len(sample.points))
            cnt = np.zeros(len(sample.points))
            for j in range(3):
                np.add.at(acc, F[:, j], fs)
                np.add.at(cnt, F[:, j], 1.0)
            extra = dict(sample.extra, face_saliency=fs,
                         vertex_saliency=acc / np.maximum(cnt, 1.0))
            sample = replace(sample, extra=extra)
        else:
            log.info("load_shared_model: %s has %d values for %d faces; ignored",
                     sal.name, len(fs), len(sample.faces))
    return sample
