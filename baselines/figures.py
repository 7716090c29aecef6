"""
figures.py
----------
The report's rendered comparisons, one picture (or two) per filter family:
every method's output drawn with :mod:`render` (lit splats and shaded
surfaces, the same camera for every panel), laid out by matplotlib with the
colour bar's unit, the legend and a zoomed inset on a crease inside the
picture.  Each comparison also hands the report a *scene* (subsampled clouds
with their colours) for the interactive page.

The data of a comparison (filters, baselines, surface reconstructions) are
computed in one isolated child process per comparison (``run_isolated``), so a
crash inside MeshLab or CGAL loses one picture, never the report; the
rendering happens in the parent.

Sizes: quick mode draws a few thousand points per panel from pymeshlab's
sample meshes and generated parts; the full report uses more points and, when
``../shared/data/models`` is present, the gargoyle scan.
"""

from __future__ import annotations

import inspect
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import render

log = logging.getLogger("pcprep")

#: one panel of a comparison, in output pixels (4 columns make 2,080 px)
PANEL_W, PANEL_H = 520, 430
#: the inset's share of its panel, and the supersampling of every render
INSET_FRAC, SUPERSAMPLE = 0.44, 2
#: PNG colours kept (an adaptive palette keeps each picture a few hundred KB)
PALETTE = 256
#: error colour scale of the denoising pictures, in h
ERR_MAX_H = 1.0


@dataclass
class Panel:
    """What one panel shows: splats (``points``, ``normals``, per-point
    ``colours``, splat ``radius`` in world units) and/or a triangle ``mesh``
    ``(V, F, vertex_colours)``; ``failed`` is a message drawn instead.
    ``camera``, ``inset`` and ``outline`` override the picture's for this panel."""

    title: str
    points: np.ndarray | None = None
    normals: np.ndarray | None = None
    colours: np.ndarray | None = None
    radius: float = 1.0
    mesh: tuple | None = None
    failed: str | None = None
    camera: render.Camera | None = None
    inset: tuple | None = None
    outline: float | None = None


@dataclass
class Figure:
    """A rendered comparison: the report links ``path`` under ``title`` with
    ``caption``; ``scene`` feeds the interactive viewer."""

    family: str
    title: str
    path: Path
    caption: str
    scene: dict | None = None


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ---------------------------------------------------------------------------------------
# layout


def draw(panel: Panel, camera: render.Camera, outline: float | None) -> np.ndarray:
    """Render one panel with ``camera``."""
    canvas = render.Canvas(camera, SUPERSAMPLE)
    if panel.mesh is not None:
        V, F, col = panel.mesh
        canvas.mesh(V, F, col)
    if panel.points is not None:
        canvas.points(panel.points, panel.normals, panel.colours, panel.radius)
    return canvas.image(outline)


def visible_mask(camera: render.Camera, points, normals, radius: float, slack: float
                 ) -> np.ndarray:
    """Points not hidden behind another part of the cloud (within ``slack`` of
    the depth buffer at their pixel) and inside the image."""
    canvas = render.Canvas(camera, 1).points(points, normals, None, radius)
    x, y, z = camera.project(points)
    xi, yi = np.floor(x).astype(int), np.floor(y).astype(int)
    inside = (xi >= 0) & (yi >= 0) & (xi < camera.width) & (yi < camera.height)
    out = np.zeros(len(points), dtype=bool)
    out[inside] = z[inside] <= canvas.depth[yi[inside], xi[inside]] + slack
    return out


def pick_inset(camera: render.Camera, points, normals, score, candidates, h: float,
               half_width: float) -> np.ndarray:
    """The world point of the inset: among visible ``candidates`` whose inset
    box stays inside the image, the one with the highest ``score``."""
    vis = visible_mask(camera, points, normals, 1.2 * h, 1.5 * h)
    x, y, _ = camera.project(points)
    mx = half_width / camera.pixel
    my = mx * camera.height / camera.width
    inside = ((x > mx) & (x < camera.width - mx) & (y > my)
              & (y < camera.height - my))
    ok = vis & inside & np.asarray(candidates, bool)
    if not ok.any():
        ok = vis & inside
    if not ok.any():
        return camera.center
    s = np.where(ok, np.nan_to_num(np.asarray(score, float), nan=-np.inf), -np.inf)
    return np.asarray(points[int(np.argmax(s))], dtype=np.float64)


def compose(path: Path, panels: list[Panel], camera: render.Camera, *, ncols: int,
            title: str | None = None, colorbar: tuple | None = None,
            legend: list[tuple[str, tuple]] | None = None, inset: tuple | None = None,
            outline: float | None = None, panel: tuple[int, int] | None = None) -> Path:
    """Lay out ``panels`` in a grid of ``panel`` = (width, height) pixels
    (default ``PANEL_W × PANEL_H``), each rendered with ``camera`` resized to
    it (or the panel's own camera), and write a PNG.

    ``colorbar`` is ``(cmap, vmin, vmax, label)``; ``legend`` a list of
    ``(label, rgb)``; ``inset`` ``(world_point, half_width)`` draws a zoomed
    view of that box in a corner of every panel and frames the box.
    """
    plt = _plt()
    from matplotlib.patches import Patch, Rectangle

    pw, ph = panel or (PANEL_W, PANEL_H)
    nrows = -(-len(panels) // ncols)
    head = 54 if title else 6
    foot = 86 if (colorbar or legend) else 6
    W, H = ncols * pw, nrows * ph + head + foot
    fig = plt.figure(figsize=(W / 100, H / 100), dpi=100)
    if title:
        fig.text(0.5, 1 - 30 / H, title, ha="center", va="center", fontsize=17,
                 weight="bold")
    iw, ih = int(pw * INSET_FRAC), int(ph * INSET_FRAC)
    for i, pn in enumerate(panels):
        cam = (pn.camera or camera).sized(pw, ph)
        box = pn.inset if pn.inset is not None else inset
        icam = None if box is None else cam.zoomed(box[0], box[1], iw, ih)
        line = pn.outline if pn.outline is not None else outline
        r, c = divmod(i, ncols)
        ax = fig.add_axes([c * pw / W, 1 - (head + (r + 1) * ph) / H,
                           pw / W, ph / H])
        ax.set_axis_off()
        if pn.failed is not None:
            ax.imshow(np.ones((ph, pw, 3)))
            ax.text(0.5, 0.5, pn.failed, transform=ax.transAxes, ha="center",
                    va="center", fontsize=10, color="0.3", wrap=True)
        else:
            ax.imshow(draw(pn, cam, line), interpolation="none")
            if icam is not None:
                x, y = cam.pixel_of(box[0])
                hx = box[1] / cam.pixel
                hy = hx * ih / iw
                ax.add_patch(Rectangle((x - hx, y - hy), 2 * hx, 2 * hy, fill=False,
                                       lw=1.6, ec="#1f77b4"))
                # the inset sits in the corner diagonally opposite its box
                ix0 = 0.01 if x > pw / 2 else 1 - INSET_FRAC - 0.01
                iy0 = 0.01 if y < ph / 2 else 1 - INSET_FRAC - 0.07
                iax = ax.inset_axes([ix0, iy0, INSET_FRAC, INSET_FRAC])
                iax.imshow(draw(pn, icam, line), interpolation="none")
                iax.set_xticks([])
                iax.set_yticks([])
                for sp in iax.spines.values():
                    sp.set_edgecolor("#1f77b4")
                    sp.set_linewidth(1.6)
        ax.text(0.02, 0.98, pn.title, transform=ax.transAxes, ha="left", va="top",
                fontsize=13, bbox=dict(boxstyle="round,pad=0.25", fc="white", ec="0.8",
                                       alpha=0.9))
    if colorbar is not None:
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize

        cmap, vmin, vmax, label = colorbar
        cax = fig.add_axes([0.55 if legend else 0.3, (foot - 34) / H, 0.4, 18 / H])
        cb = fig.colorbar(ScalarMappable(Normalize(vmin, vmax), cmap), cax=cax,
                          orientation="horizontal")
        cb.set_label(label, fontsize=12)
        cb.ax.tick_params(labelsize=11)
    if legend:
        handles = [Patch(fc=rgb, ec="0.3", label=lab) for lab, rgb in legend]
        fig.legend(handles=handles, loc="lower left", bbox_to_anchor=(0.01, 8 / H),
                   ncol=min(len(handles), 4), fontsize=12, frameon=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    _palette(path)
    return path


def _palette(path: Path) -> None:
    """Rewrite the PNG with an adaptive palette (lossless layout, a few hundred KB)."""
    from PIL import Image

    with Image.open(path) as im:
        q = im.convert("RGB").quantize(colors=PALETTE, method=Image.Quantize.MEDIANCUT,
                                       dither=Image.Dither.NONE)
    q.save(path, optimize=True)


# ---------------------------------------------------------------------------------------
# shared data steps (run in the isolated child)


def pca_normals(points, k: int = 16) -> np.ndarray:
    """Unoriented PCA normals, the same rule for every method's output."""
    from pcprep.filters.neighbors import pca_normals as _pca

    return _pca(np.asarray(points, dtype=np.float64), min(k, len(points) - 1), orient=False)


def poisson_surface(points, depth: int = 7, trim: float = 3.0, reference=None):
    """Screened Poisson reconstruction (pymeshlab) of ``points`` with MST-oriented
    PCA normals; faces with a vertex farther than ``trim`` h from every input
    point are cut, so open scans keep their holes and borders.  With
    ``reference`` (the method's input), output points farther than 6h from it
    are left out of the reconstruction (a stray point would inflate Poisson's
    octree and its run time; the splat panels still show every point).

    Returns ``(V, F)``.
    """
    import pymeshlab
    from scipy.spatial import cKDTree

    from pcprep.filters.neighbors import average_spacing, orient_normals_mst

    P = np.asarray(points, dtype=np.float64)
    P = P[np.isfinite(P).all(axis=1)]
    if reference is not None:
        R = np.asarray(reference, dtype=np.float64)
        d, _ = cKDTree(R).query(P)
        P = P[d <= 6.0 * average_spacing(R)]
    c = P.mean(axis=0)
    N = orient_normals_mst(P, pca_normals(P), k=10)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=P - c, v_normals_matrix=N), "cloud")
    # one thread: on a shared 2-core machine OpenMP's spinning threads cost more than
    # they give (a depth-7 bunny: 10 s with one thread, 40-100 s with two under load)
    ms.generate_surface_reconstruction_screened_poisson(depth=int(depth), preclean=False,
                                                        threads=1)
    m = ms.current_mesh()
    V = np.array(m.vertex_matrix(), dtype=np.float64) + c
    F = np.array(m.face_matrix(), dtype=np.int64).reshape(-1, 3)
    h = average_spacing(P)
    d, _ = cKDTree(P).query(V)
    far = d > trim * h
    F = F[~far[F].any(axis=1)]
    return V, F


def _try(fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs), None
    except Exception as exc:  # noqa: BLE001 - one method failing costs one panel
        return None, f"{type(exc).__name__}: {exc}"


def _accepts_preset(func) -> bool:
    try:
        return "preset" in inspect.signature(func).parameters
    except (TypeError, ValueError):
        return False


def _denoise_baseline(method: str, noisy, nin, prm: dict):
    from pcprep.baselines import cgal, meshlab

    if method == "APSS":
        return meshlab.apss(noisy, nin, **prm)[0]
    if method == "RIMLS":
        return meshlab.rimls(noisy, nin, **prm)[0]
    if method == "CGAL bilateral":
        return cgal.bilateral(noisy, nin, **prm)[0]
    if method == "CGAL jet":
        return cgal.jet_smooth(noisy, **prm)
    raise ValueError(method)


#: the baselines' grids for the pictures (best by MSE to the clean cloud when one exists)
DENOISE_GRIDS = {
    "APSS": [dict(filterscale=fs, sphericalparameter=sp) for fs in (2.0, 4.0)
             for sp in (0.0, 1.0)],
    "RIMLS": [dict(filterscale=fs, sigman=sn) for fs in (2.0, 4.0) for sn in (0.5, 1.0)],
    "CGAL bilateral": [dict(k=k, sharpness_angle=30.0, iterations=it) for k in (16, 32)
                       for it in (1, 3)],
    "CGAL jet": [dict(k=k) for k in (12, 24)],
}


def bpa_surface(points):
    """MeshLab's ball pivoting (radius guessed by MeshLab) with MST-oriented PCA
    normals: it interpolates the points, so what a method kept or moved shows."""
    from pcprep.baselines import meshlab
    from pcprep.filters.neighbors import orient_normals_mst

    P = np.asarray(points, dtype=np.float64)
    P = P[np.isfinite(P).all(axis=1)]
    N = orient_normals_mst(P, pca_normals(P, 12), k=10)
    return meshlab.ball_pivoting(P, N)


def denoise_outputs(noisy, clean=None, surfaces: bool = True, depth: int = 7,
                    surface: str = "poisson") -> dict:
    """Every denoiser's output on ``noisy`` (meant for an isolated child).

    Ours runs with its defaults and, when the filter accepts it, with
    ``preset="thesis"``.  Each baseline gets PCA normals (k = 16, MST-oriented)
    and, when ``clean`` is given, its best setting by MSE over
    ``DENOISE_GRIDS``; without ground truth its first setting.  ``surface`` is
    ``"poisson"`` (screened Poisson at ``depth``) or ``"bpa"``.  Returns
    ``{name: {"points", "params", "error", "surface"}}`` in panel order.
    """
    from pcprep.filters.neighbors import orient_normals_mst
    from pcprep.meshlab_bridge import registry

    spec = registry.get("denoise")
    noisy = np.asarray(noisy, dtype=np.float64)
    nin = orient_normals_mst(noisy, pca_normals(noisy), k=10)
    out = {"noisy": {"points": noisy, "params": None, "error": None}}
    res, err = _try(spec.func, noisy)
    out["ours (defaults)"] = {"points": None if res is None else getattr(res, spec.points_field),
                              "params": "defaults", "error": err}
    if _accepts_preset(spec.func):
        res, err = _try(spec.func, noisy, preset="thesis")
        out["ours (thesis preset)"] = {
            "points": None if res is None else getattr(res, spec.points_field),
            "params": "preset=thesis", "error": err}
    for method, grid in DENOISE_GRIDS.items():
        best = {"points": None, "params": None, "error": "no setting ran"}
        best_mse = np.inf
        for prm in (grid if clean is not None else grid[:1]):
            P, err = _try(_denoise_baseline, method, noisy, nin, prm)
            if P is None or not np.isfinite(P).all():
                best["error"] = err or "non-finite output"
                continue
            mse = float(np.mean(np.sum((P - clean) ** 2, axis=1))) if clean is not None else 0.0
            if mse < best_mse:
                best, best_mse = {"points": P, "params": prm, "error": None}, mse
        out[method] = best
    if surfaces:
        if clean is not None:
            out["clean"] = {"points": np.asarray(clean, dtype=np.float64), "params": None,
                            "error": None}
        for rec in out.values():
            if rec["points"] is not None:
                if surface == "bpa":
                    rec["surface"], rec["surface_error"] = _try(bpa_surface, rec["points"])
                else:
                    rec["surface"], rec["surface_error"] = _try(
                        poisson_surface, rec["points"], depth, reference=noisy)
    return out


# ---------------------------------------------------------------------------------------
# colours and scenes


def _err_colours(values, vmax: float, cmap: str = "magma_r"):
    return render.scalar_colours(values, cmap, 0.0, vmax)


def _subsample(n: int, cap: int, seed: int = 0) -> np.ndarray:
    if n <= cap:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, cap, replace=False))


def scene(title: str, clouds: list[tuple[str, np.ndarray, np.ndarray]], h: float,
          cap: int = 8000, seed: int = 0, note: str = "", up_axis: int = 2) -> dict:
    """A viewer scene: each cloud subsampled to at most ``cap`` points (the same
    subset when clouds are in the same point order), colours as 0-255 RGB."""
    out = []
    for label, pts, col in clouds:
        pts = np.asarray(pts, dtype=np.float64)
        sub = _subsample(len(pts), cap, seed)
        c = np.asarray(col, dtype=np.float64)
        if c.ndim == 1:
            c = np.tile(c[:3], (len(pts), 1))
        out.append({"label": label, "points": pts[sub],
                    "colours": np.clip(np.round(c[sub, :3] * 255), 0, 255).astype(np.uint8)})
    return {"title": title, "clouds": out, "h": float(h), "note": note, "up_axis": up_axis}


def _iso(fn, *args, **kwargs):
    from pcprep.baselines.harness import run_isolated

    out = run_isolated(fn, *args, timeout=1200.0, **kwargs)
    if not out.ok:
        raise RuntimeError(f"{getattr(fn, '__name__', fn)}: {out.error}")
    return out.value


# ---------------------------------------------------------------------------------------
# denoising


def _cad_part(quick: bool, n: int, seed: int):
    """The CAD part of the denoising and detection pictures: the shared fandisk
    mesh sampled uniformly (full report, when present), else the generated one."""
    from pcprep.baselines.datasets import make_shape

    if not quick:
        try:
            from pcprep.baselines.meshes import load_shared_model, sample_mesh_surface

            m = load_shared_model("cad/fandisk_clean.obj")
            if m is not None and m.faces is not None:
                s = sample_mesh_surface(m.points, m.faces, n=n, seed=seed, name="fandisk")
                return s, "the fandisk CAD mesh, sampled uniformly"
        except Exception as exc:  # noqa: BLE001 - fall back to the generated part
            log.info("figures: shared fandisk not used: %s", exc)
    return make_shape("fandisk", n=n, seed=seed), "a generated fandisk-like part"


def _real_scan(quick: bool, n: int, seed: int):
    """A real scan with its natural noise: the gargoyle point scan (full report,
    when present), else pymeshlab's face range map."""
    from pcprep.baselines.meshes import load_mesh_file, load_sample_mesh, shared_models_root

    s = None
    if not quick:
        try:
            p = shared_models_root() / "scans" / "gargoyle_points_95k.ply"
            if p.is_file():
                s = load_mesh_file(p, name="gargoyle")
                label = "the gargoyle point scan (95K points, natural noise)"
        except Exception as exc:  # noqa: BLE001
            log.info("figures: gargoyle not used: %s", exc)
    if s is None:
        s = load_sample_mesh("face")
        label = "pymeshlab's face range map (a raw range scan, natural noise)"
    sub = _subsample(len(s.points), n, seed)
    return s.points[sub], label


def denoise_figures(img: Path, seed: int = 0, quick: bool = True) -> list[Figure]:
    """CAD part with 0.3h noise along the normals (error-coloured splats and
    Poisson surfaces) and a real scan with its own noise (Poisson surfaces)."""
    from scipy.spatial import cKDTree

    from pcprep.baselines.datasets import add_noise

    n = 8000 if quick else 16000
    part, part_label = _cad_part(quick, n, seed)
    h = part.h
    noisy = add_noise(part.points, part.normals, sigma=0.3, h=h, kind="normal", seed=seed)
    outs = _iso(denoise_outputs, noisy, part.points, True, 7 if quick else 8)
    order = [k for k in outs if k != "clean"]
    errs = {k: (np.linalg.norm(outs[k]["points"] - part.points, axis=1) / h
                if outs[k]["points"] is not None else None) for k in order}
    cam = render.Camera.fit(part.points, PANEL_W, PANEL_H, elev=28, azim=-58)
    # inset: the visible crease point where the methods' local errors spread most
    tree = cKDTree(part.points)
    _, nb = tree.query(part.points, k=24)
    local = np.array([errs[k][nb].mean(axis=1) for k in order if errs[k] is not None])
    spread = local.max(axis=0) - local.min(axis=0)
    half = 9.0 * h
    where = pick_inset(cam, part.points, part.normals, spread,
                       part.sharp if part.sharp is not None else np.ones(n, bool), h, half)
    splats, surfs, clouds = [], [], []
    for k in order:
        rec = outs[k]
        if rec["points"] is None:
            splats.append(Panel(k, failed=f"{k}: {rec['error']}"))
            surfs.append(Panel(k, failed=f"{k}: {rec['error']}"))
            continue
        col = _err_colours(errs[k], ERR_MAX_H)
        splats.append(Panel(k, rec["points"], pca_normals(rec["points"]), col, 1.2 * h))
        clouds.append((k, rec["points"], col))
        if rec.get("surface") is not None:
            surfs.append(Panel(k, mesh=(*rec["surface"], None)))
        else:
            surfs.append(Panel(k, failed=f"{k}: {rec.get('surface_error')}"))
    if outs.get("clean", {}).get("surface") is not None:
        surfs.append(Panel("clean (truth)", mesh=(*outs["clean"]["surface"], None)))
    splats.append(Panel("clean (truth)", part.points, part.normals,
                        _err_colours(np.zeros(n), ERR_MAX_H), 1.2 * h))
    cbar = ("magma_r", 0.0, ERR_MAX_H, "distance to the clean point / surface (× h)")
    params = "; ".join(f"{k}: {outs[k]['params']}" for k in order
                       if isinstance(outs[k]["params"], dict))
    cap = (f"{part_label.capitalize()}, {n} points, Gaussian noise of 0.3h along the normals. "
           "Splats are shaded by PCA normals of each output (k = 16, the same rule for every "
           "method) and coloured by each point's distance to its clean position; the inset "
           "zooms on the crease where the methods' errors differ most. Baselines: best "
           f"setting by MSE over a small grid ({params}); ours: its defaults.")
    figs = [Figure("denoise", "Denoising a CAD part: error per point",
                   compose(img / "denoise_cad_points.png", splats, cam, ncols=4,
                           title="Denoising, 0.3h noise: distance to the clean point",
                           colorbar=cbar, inset=(where, half), outline=4 * h),
                   cap, scene("Denoising a CAD part (colour = error, 0 to 1 h)",
                              [("clean (truth)", part.points,
                                _err_colours(np.zeros(n), ERR_MAX_H))] + clouds, h)),
            Figure("denoise", "Denoising a CAD part: reconstructed surfaces",
                   compose(img / "denoise_cad_surfaces.png", surfs, cam, ncols=4,
                           title="Denoising, 0.3h noise: screened Poisson surface of "
                                 "each output", inset=(where, half), outline=4 * h),
                   "The same outputs reconstructed with pymeshlab's screened Poisson "
                   f"(depth {7 if quick else 8}, PCA normals oriented by a spanning tree, "
                   "faces farther than 2h from the cloud cut); flat shading shows the "
                   "roughness the noise leaves.")]
    figs.append(_denoise_scan(img, seed, quick))
    return figs


def _denoise_scan(img: Path, seed: int, quick: bool) -> Figure:
    from pcprep.filters.neighbors import average_spacing

    pts, label = _real_scan(quick, 12000 if quick else 30000, seed)
    h = average_spacing(pts)
    outs = _iso(denoise_outputs, pts, None, True, surface="bpa")
    cam = _front_camera(pts)
    panels, clouds = [], []
    move = {}
    for k, rec in outs.items():
        if rec["points"] is None:
            panels.append(Panel(k, failed=f"{k}: {rec['error']}"))
            continue
        move[k] = np.linalg.norm(rec["points"] - pts, axis=1) / h
        col = render.scalar_colours(move[k], "viridis", 0.0, 1.0)
        clouds.append((k, rec["points"], col))
        if rec.get("surface") is not None:
            V, F = rec["surface"]
            panels.append(Panel(k, mesh=(V, F, None)))
        else:
            panels.append(Panel(k, failed=f"{k}: {rec.get('surface_error')}"))
    cv = cam.sized(PANEL_W, PANEL_H)
    half = 0.09 * cv.half_width * 2
    # inset: the most curved part of the central half of the scan (eyes, nose, mouth)
    from pcprep.filters.neighbors import knn, weighted_pca

    _, nb = knn(pts, 16)
    curv = weighted_pca(pts, nb).surface_variation
    q = (pts - pts.mean(axis=0)) @ np.c_[cv.right, cv.up]
    central = (np.abs(q) < 0.5 * np.abs(q).max(axis=0)).all(axis=1)
    curv = curv[nb].mean(axis=1)
    where = pick_inset(cv, pts, None, curv, central, h, half)
    return Figure("denoise", "Denoising a real scan: reconstructed surfaces",
                  compose(img / "denoise_scan_surfaces.png", panels, cv, ncols=4,
                          title="Denoising a real scan (its own noise): ball-pivoting "
                                "surface of each output",
                          inset=(where, half), outline=6 * h),
                  f"{label.capitalize()}, {len(pts)} points. No ground truth, so each "
                  "baseline runs with its first grid setting (no tuning possible) and ours "
                  "with its defaults. Surfaces: MeshLab's ball pivoting, which interpolates "
                  "the points, so the roughness left shows; flat-shaded, the same camera "
                  "for every panel.",
                  scene("Denoising a real scan (colour = displacement, 0 to 1 h)", clouds, h,
                        up_axis=1))


def _front_camera(pts, size: tuple[int, int] = (PANEL_W, PANEL_H)) -> render.Camera:
    """A camera looking along the cloud's least-spread direction (a range scan's
    viewing direction), up = its most-spread direction."""
    P = np.asarray(pts, dtype=np.float64)
    c = P.mean(axis=0)
    _, _, vt = np.linalg.svd(P - c, full_matrices=False)
    back, up = vt[2], vt[0]
    if back @ np.array([0.0, 0.0, 1.0]) < 0 and abs(back[2]) > 0.5:
        back = -back
    right = np.cross(up, back)
    q = (P - c) @ np.c_[right, up]
    ext = np.percentile(np.abs(q), 99.5, axis=0)  # stray range-map samples left out
    half = 1.06 * max(ext[0], ext[1] * size[0] / size[1])
    return render.Camera(c, right, up, back, float(half), int(size[0]), int(size[1]))


# ---------------------------------------------------------------------------------------
# simplification

#: the simplification picture's methods, in panel order (runners of bench_simplify)
SIMPLIFY_METHODS = ("SDBS", "Poisson-disk", "CGAL grid", "CGAL HCS", "CGAL WLOP")


def simplify_outputs(points, count: int, seed: int, depth: int = 7) -> dict:
    """Each simplifier's points at ``count`` and the ball-pivoting surface of
    each (meant for an isolated child).  SDBS runs with its defaults;
    the CGAL grid and hierarchy sizes are searched to meet the count."""
    from pcprep.baselines import bench_simplify

    P = np.asarray(points, dtype=np.float64)
    out = {"original": {"points": P, "error": None}}
    for name in SIMPLIFY_METHODS:
        Q, err = _try(bench_simplify.RUNNERS[name], P, count, seed)
        out[name] = {"points": Q, "error": err}
    for name, rec in out.items():
        if rec["points"] is not None and name != "original":
            rec["surface"], rec["surface_error"] = _try(bpa_surface, rec["points"])
    return out


def _plane_distance(tree, points, normals, V) -> np.ndarray:
    """Distance of ``V`` to the tangent plane of its nearest point of ``points``
    (a surface distance, not the distance to the nearest sample)."""
    _, i = tree.query(V)
    return np.abs(np.einsum("ij,ij->i", V - points[i], normals[i]))


def _face_deviation(tree, points, normals, V, F) -> np.ndarray:
    """Per face: the largest distance to the original surface of its centroid and
    edge midpoints (an interpolating surface's vertices are the kept points, at
    distance 0; its faces are where it departs from the original)."""
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    probes = ((A + B + C) / 3, (A + B) / 2, (B + C) / 2, (C + A) / 2)
    return np.max([_plane_distance(tree, points, normals, q) for q in probes], axis=0)


def _per_face(V, F, colours):
    """A mesh whose faces carry one colour each (corners split)."""
    F = np.asarray(F, dtype=np.int64)
    V2 = np.asarray(V, dtype=np.float64)[F.ravel()]
    return V2, np.arange(len(V2)).reshape(-1, 3), np.repeat(colours, 3, axis=0)


def simplify_figures(img: Path, seed: int = 0, quick: bool = True) -> list[Figure]:
    """The bunny at 10 % by every method: the kept points, and the ball-pivoting
    surface of each coloured by its distance Δ to the original surface."""
    from scipy.spatial import cKDTree

    from pcprep.baselines.meshes import load_sample_mesh

    bunny = load_sample_mesh("bunny")
    P, h = bunny.points, bunny.h
    count = int(round(0.1 * len(P)))
    outs = _iso(simplify_outputs, P, count, seed)
    outs["original"]["surface"] = (P, bunny.faces)
    pw, ph = 400, 400
    cam = render.Camera.fit(P, pw, ph, elev=12, azim=20, up_axis=1)
    tree = cKDTree(P)
    N = bunny.normals
    dmax = 1.0
    top, bottom, clouds, cov = [], [], [], {}
    for name, rec in outs.items():
        Q = rec["points"]
        label = name if name == "original" else f"{name} ({0 if Q is None else len(Q)})"
        if Q is None:
            top.append(Panel(name, failed=f"{name}: {rec['error']}"))
            bottom.append(Panel(name, failed=f"{name}: {rec['error']}"))
            continue
        r = 1.2 * h * np.sqrt(len(P) / len(Q))
        top.append(Panel(label, Q, pca_normals(Q, 12), (0.80, 0.62, 0.42), r))
        clouds.append((label, Q, np.tile([0.8, 0.62, 0.42], (len(Q), 1))))
        if rec.get("surface") is not None:
            V, F = rec["surface"]
            d = _face_deviation(tree, P, N, V, F) / h
            cov[name] = float(np.mean(d))
            bottom.append(Panel(f"{name}: mesh" if name == "original" else
                                f"{name}: surface", mesh=_per_face(V, F, render.scalar_colours(
                                    d, "viridis", 0.0, dmax))))
        else:
            bottom.append(Panel(name, failed=f"{name}: {rec.get('surface_error')}"))
    # inset: around the ear tips / face, the visible point where the surfaces differ most
    half = 0.16 * cam.half_width
    x, y, _ = cam.project(P)
    score = -y  # the highest visible detail (the ears) unless a better one shows
    where = pick_inset(cam, P, N, score, np.ones(len(P), bool), h, half)
    path = compose(img / "simplify_bunny.png", top + bottom, cam, ncols=len(top),
                   title=f"Simplifying the bunny to {count} points (10 %): kept points and "
                         "their ball-pivoting surfaces",
                   colorbar=("viridis", 0.0, dmax,
                             "Δ: distance to the original surface (× h of the original)"),
                   inset=(where, half), outline=5 * h, panel=(pw, ph))
    mean_d = ", ".join(f"{k} {v:.2f}h" for k, v in cov.items())
    return [Figure("simplify", "Simplification: kept points and reconstructed surfaces", path,
                   f"pymeshlab's bunny ({len(P)} points) simplified to {count} points by each "
                   "method (SDBS with its defaults; CGAL grid and hierarchy sizes searched "
                   "to meet the count; WLOP's percentage set to it). Top: the kept points as "
                   "splats; bottom: MeshLab's ball-pivoting surface of each (the original: "
                   "its own mesh), coloured by the distance of each surface point to the "
                   f"original surface (each face: the largest of its centroid's and edge "
                   f"midpoints' distances; mean over faces: {mean_d}).",
                   scene(f"Simplification to {count} points", clouds, h, up_axis=1))]


# ---------------------------------------------------------------------------------------
# sharp features and holes

#: true positive / false positive / missed / other, the legend of every detection panel
TP, FP, FN, TN = (0.85, 0.10, 0.10), (1.0, 0.62, 0.0), (0.10, 0.35, 0.95), (0.80, 0.80, 0.78)
DETECTION_LEGEND = [("true positive", TP), ("false positive", FP), ("missed", FN),
                    ("not a feature", TN)]


def detection_colours(mask, truth) -> np.ndarray:
    """TP red, FP orange, missed blue, the rest light grey."""
    mask, truth = np.asarray(mask, bool), np.asarray(truth, bool)
    col = np.tile(TN, (len(mask), 1))
    col[mask & truth] = TP
    col[mask & ~truth] = FP
    col[~mask & truth] = FN
    return col


def detection_outputs(points, family: str, baselines: tuple, seed: int) -> dict:
    """Masks of ours (the registry's filter, defaults) and of the classic
    detectors (meant for an isolated child)."""
    from pcprep.baselines import classic
    from pcprep.meshlab_bridge import registry

    spec = registry.get(family)
    out = {}
    res, err = _try(spec.func, points, seed=seed)
    out["ours"] = {"mask": None if res is None else np.asarray(getattr(res, spec.mask_field),
                                                               bool), "error": err}
    for name in baselines:
        res, err = _try(classic.run_method, name, points)
        out[name.replace("_", " ")] = {"mask": None if res is None else np.asarray(res.mask,
                                                                                  bool),
                                       "error": err}
    return out


def _f1(mask, truth) -> float:
    tp = float(np.sum(mask & truth))
    den = float(np.sum(mask) + np.sum(truth))
    return 2 * tp / den if den else 1.0


def detection_figures(img: Path, seed: int = 0, quick: bool = True) -> list[Figure]:
    """Sharp features on the CAD part (0.1h noise) and hole rims on pymeshlab's
    bunny seen from below, every detector beside ours."""
    from pcprep.baselines.datasets import add_noise
    from pcprep.baselines.meshes import load_sample_mesh

    n = 12000 if quick else 20000
    part, part_label = _cad_part(quick, n, seed)
    h = part.h
    pts = add_noise(part.points, part.normals, sigma=0.1, h=h, kind="normal", seed=seed)
    sharp = _iso(detection_outputs, pts, "features", ("surface_variation", "normal_variation",
                                                      "projected_distance"), seed)
    cam = render.Camera.fit(pts, PANEL_W, PANEL_H, elev=28, azim=-58)
    truth = np.asarray(part.sharp, bool)
    panels, clouds, f1s = [], [], {}
    disagree = np.zeros(n)
    for name, rec in sharp.items():
        if rec["mask"] is None:
            panels.append(Panel(name, failed=f"{name}: {rec['error']}"))
            continue
        f1s[name] = _f1(rec["mask"], truth)
        col = detection_colours(rec["mask"], truth)
        panels.append(Panel(f"{name} (F1 {f1s[name]:.2f})", pts, part.normals, col, 1.2 * h))
        clouds.append((name, pts, col))
        disagree += rec["mask"] != truth
    half = 10.0 * h
    where = pick_inset(cam, pts, part.normals, disagree, truth, h, half)
    figs = [Figure("features", "Sharp features on a CAD part",
                   compose(img / "features_cad.png", panels, cam, ncols=4,
                           title="Sharp features, CAD part with 0.1h noise",
                           legend=DETECTION_LEGEND, inset=(where, half), outline=4 * h),
                   f"{part_label.capitalize()}, {n} points, Gaussian noise of 0.1h along the "
                   "normals; truth = points within 1h of an edge sharper than 30°. Each "
                   "detector with its defaults; F1 against that truth in each title.",
                   scene("Sharp features (red TP, orange FP, blue missed)", clouds, h))]
    bunny = load_sample_mesh("face")  # a raw range scan: its holes are real
    bh = bunny.h
    holes = _iso(detection_outputs, bunny.points, "holes", ("angle_gap",), seed)
    rim = np.asarray(bunny.rim, bool)
    bcam = _front_camera(bunny.points, (800, 620))
    hp, hc = [], []
    for name, rec in holes.items():
        if rec["mask"] is None:
            hp.append(Panel(name, failed=f"{name}: {rec['error']}"))
            continue
        col = detection_colours(rec["mask"], rim)
        f1 = _f1(rec["mask"], rim)
        hp.append(Panel(f"{name} (F1 {f1:.2f})", bunny.points, bunny.normals, col, 1.2 * bh))
        hc.append((name, bunny.points, col))
    half = 0.22 * bcam.half_width
    where = pick_inset(bcam, bunny.points, bunny.normals, np.ones(len(rim)), rim, bh, half)
    figs.append(Figure(
        "features", "Hole boundaries on a real scan",
        compose(img / "holes_scan.png", hp, bcam, ncols=len(hp),
                title="Hole boundaries on a raw range scan (its holes are real)",
                legend=DETECTION_LEGEND, inset=(where, half),
                outline=5 * bh, panel=(800, 620)),
        f"pymeshlab's face range map ({len(rim)} points), a raw scan with the holes "
        "and ragged border scanning leaves; truth = the vertices on the mesh's boundary "
        f"edges ({int(rim.sum())} points). Ours and the angle-gap detector with their "
        "defaults.",
        scene("Hole boundaries (red TP, orange FP, blue missed)", hc, bh, up_axis=1)))
    return figs


# ---------------------------------------------------------------------------------------
# saliency

#: saliency panels are smaller: up to seven methods side by side
SAL_PANEL = (400, 330)


def saliency_outputs(points) -> dict:
    """Ours (the registry's filter, defaults) and the comparison scores of
    ``bench_saliency.baseline_scores`` (meant for an isolated child)."""
    from pcprep.baselines import bench_saliency
    from pcprep.meshlab_bridge import registry

    spec = registry.get("saliency")
    out = {}
    res, err = _try(spec.func, points)
    out["ours"] = {"score": None if res is None else np.asarray(getattr(res, spec.scalar_field),
                                                                float), "error": err}
    base, err = _try(bench_saliency.baseline_scores, points)
    for name, v in (base or {}).items():
        out[name] = {"score": np.asarray(v, float), "error": None}
    if base is None:
        out["comparison scores"] = {"score": None, "error": err}
    return out


def _ranked(score) -> np.ndarray:
    """A score scaled to [0, 1] between its 2nd and 98th percentiles."""
    s = np.asarray(score, dtype=np.float64)
    lo, hi = np.nanpercentile(s, [2, 98])
    return np.clip((s - lo) / max(hi - lo, 1e-300), 0.0, 1.0)


def saliency_figures(img: Path, seed: int = 0, quick: bool = True) -> list[Figure]:
    """Heat maps of ours and every comparison score on the CAD part and on
    pymeshlab's bunny scan."""
    from pcprep.baselines.meshes import load_sample_mesh

    part, part_label = _cad_part(quick, 10000 if quick else 20000, seed)
    bunny = load_sample_mesh("bunny")
    sub = _subsample(len(bunny.points), 12000 if quick else 24000, seed)
    scan_pts = bunny.points[sub]
    scan_nrm = bunny.normals[sub]
    from pcprep.filters.neighbors import average_spacing

    rows = [("CAD part", part.points, part.normals, part.h,
             render.Camera.fit(part.points, *SAL_PANEL, elev=28, azim=-58)),
            ("bunny scan", scan_pts, scan_nrm, average_spacing(scan_pts),
             render.Camera.fit(scan_pts, *SAL_PANEL, elev=12, azim=20, up_axis=1))]
    panels, scenes, ncols = [], [], 0
    results = [_iso(saliency_outputs, pts) for _, pts, _, _, _ in rows]
    ncols = max(len(r) for r in results)
    for (label, pts, nrm, h, cam), res in zip(rows, results):
        clouds = []
        for name, rec in res.items():
            if rec["score"] is None:
                panels.append(Panel(f"{label}: {name}", failed=f"{name}: {rec['error']}"))
                continue
            col = render.scalar_colours(_ranked(rec["score"]), "inferno", 0.0, 1.0)
            panels.append(Panel(f"{name}", pts, nrm, col, 1.2 * h, camera=cam,
                                outline=4 * h))
            clouds.append((name, pts, col))
        while len(panels) % ncols:
            panels.append(Panel("", failed=""))
        scenes.append(scene(f"Saliency on the {label} (colour = score, scaled per method)",
                            clouds, h))
    path = compose(img / "saliency.png", panels, rows[0][4], ncols=ncols,
                   title="Saliency: top row the CAD part, bottom row pymeshlab's bunny scan",
                   colorbar=("inferno", 0.0, 1.0,
                             "score, scaled per panel from its 2nd (0) to its 98th (1) "
                             "percentile"), panel=SAL_PANEL)
    return [Figure("saliency", "Saliency heat maps", path,
                   f"Top: {part_label}; bottom: pymeshlab's bunny ({len(scan_pts)} points). "
                   "Ours with its defaults beside the comparison scores of the saliency "
                   "benchmark; each panel's colours span its own score range, so the maps "
                   "compare where each method puts its highest scores.",
                   scenes[0] if scenes else None)]


# ---------------------------------------------------------------------------------------


#: every rendered comparison, in report order
RENDERERS = ("denoise_figures", "simplify_figures", "detection_figures", "saliency_figures")


def build_all(img: Path, seed: int = 0, quick: bool = True) -> tuple[list[Figure], list[str]]:
    """Render every comparison; one that fails is reported, never fatal.

    Returns ``(figures, failures)``.
    """
    import time

    figs, failures = [], []
    for name in RENDERERS:
        t0 = time.perf_counter()
        try:
            log.info("report: rendering %s", name)
            figs.extend(globals()[name](Path(img), seed=seed, quick=quick))
        except Exception as exc:  # a picture must never take the report down
            log.warning("report: %s failed: %s", name, exc)
            failures.append(f"{name}: {type(exc).__name__}: {exc}")
        log.info("report: %s took %.1f s", name, time.perf_counter() - t0)
    return figs, failures
