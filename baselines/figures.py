"""
figures.py
----------
The report's pictures, rendered headless with matplotlib's Agg backend from
data the project generates or pymeshlab ships: denoising side by side
(coloured by error), ball-pivoting reconstructions of denoised clouds,
simplified clouds beside Poisson-disk, detected sharp features and hole rims.
(Saliency heat maps are written by ``bench_saliency``.)

Every picture is small (about 900×300 px, tens of KB) so the repository stays
light.  Filters are looked up through the registry, baselines run isolated.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

log = logging.getLogger("pcprep")

#: figure size in inches at DPI; keeps each PNG well under 150 KB
PANEL_IN = 2.6
DPI = 90
#: at most this many points are drawn per panel (a seeded, fixed subset)
MAX_DRAWN = 3500


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _view(ax, pts, elev=28.0, azim=-58.0):
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    c, r = 0.5 * (lo + hi), 0.36 * float(np.max(hi - lo))  # zoomed: axes are hidden
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    try:
        ax.set_box_aspect((1, 1, 1))
    except AttributeError:  # very old matplotlib
        pass


def panels(path: Path, items: list[tuple], *, cmap="viridis", vmin=None, vmax=None,
           size=1.0, colorbar: str | None = None, elev=28.0, azim=-58.0) -> Path:
    """Render point clouds side by side.

    ``items`` are ``(title, points, values)``; values are scalars mapped
    through ``cmap`` (shared ``vmin``/``vmax``), a (n, 3|4) colour array, or
    None (grey).  A triangle mesh is drawn when an item is ``(title, points,
    None, faces)``.
    """
    plt = _plt()
    n = len(items)
    fig = plt.figure(figsize=(PANEL_IN * n, PANEL_IN + (0.35 if colorbar else 0.0)), dpi=DPI)
    ref = np.vstack([it[1] for it in items])
    sc = None
    for i, it in enumerate(items):
        title, pts, vals = it[0], it[1], it[2]
        if (len(it) < 4 or it[3] is None) and len(pts) > MAX_DRAWN:
            sub = np.random.default_rng(0).choice(len(pts), MAX_DRAWN, replace=False)
            pts = pts[sub]
            vals = None if vals is None else np.asarray(vals)[sub]
        ax = fig.add_subplot(1, n, i + 1, projection="3d")
        if len(it) > 3 and it[3] is not None:
            from mpl_toolkits.mplot3d.art3d import Poly3DCollection

            faces = it[3]
            tri = pts[faces]
            nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
            light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
            shade = 0.35 + 0.65 * np.abs(nrm @ light)
            coll = Poly3DCollection(tri, facecolors=np.c_[shade, shade, shade * 0.95],
                                    edgecolors="none", linewidths=0)
            ax.add_collection3d(coll)
        elif vals is None:
            ax.scatter(*pts.T, s=size, c="0.45", linewidths=0, depthshade=True)
        elif np.ndim(vals) == 2:
            ax.scatter(*pts.T, s=size, c=vals, linewidths=0, depthshade=False)
        else:
            sc = ax.scatter(*pts.T, s=size, c=vals, cmap=cmap, vmin=vmin, vmax=vmax,
                            linewidths=0, depthshade=False)
        _view(ax, ref, elev, azim)
        ax.set_title(title, fontsize=9)
    if colorbar and sc is not None:
        cax = fig.add_axes([0.3, 0.06, 0.4, 0.03])
        cb = fig.colorbar(sc, cax=cax, orientation="horizontal")
        cb.set_label(colorbar, fontsize=8)
        cb.ax.tick_params(labelsize=7)
    fig.subplots_adjust(left=0, right=1, top=0.9, bottom=0.12 if colorbar else 0, wspace=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _mask_colours(mask, truth=None):
    """Grey for negatives, red for detections; with ``truth`` false positives
    are orange and misses blue."""
    col = np.tile([0.75, 0.75, 0.75, 1.0], (len(mask), 1))
    if truth is None:
        col[mask] = [0.85, 0.1, 0.1, 1.0]
        return col
    col[mask & truth] = [0.85, 0.1, 0.1, 1.0]
    col[mask & ~truth] = [1.0, 0.6, 0.0, 1.0]
    col[~mask & truth] = [0.1, 0.3, 0.9, 1.0]
    return col


def _spec(command):
    from pcprep.meshlab_bridge import registry

    return registry.get(command)


def denoise_figures(img: Path, seed: int = 0, n: int = 8000) -> list[tuple[str, Path]]:
    """Noisy / ours / APSS / RIMLS / CGAL bilateral on a noisy fandisk-like
    part, coloured by distance to the clean point (in h); plus ball-pivoting
    reconstructions of the noisy and denoised clouds."""
    from pcprep.baselines import cgal, meshlab
    from pcprep.baselines.datasets import add_noise, make_shape
    from pcprep.baselines.harness import run_isolated
    from pcprep.filters.neighbors import orient_normals_mst, pca_normals

    clean = make_shape("fandisk", n=n, seed=seed)
    noisy = add_noise(clean.points, clean.normals, sigma=0.3, h=clean.h, kind="normal", seed=seed)
    nn = orient_normals_mst(noisy, pca_normals(noisy, 16, orient=False), k=10)
    spec = _spec("denoise")
    ours = getattr(spec.func(noisy, normals=nn), spec.points_field)
    runs = {
        "APSS": run_isolated(meshlab.apss, noisy, nn, filterscale=4.0),
        "RIMLS": run_isolated(meshlab.rimls, noisy, nn, filterscale=4.0),
        "CGAL bilateral": run_isolated(cgal.bilateral, noisy, nn, k=24, iterations=2),
    }

    def err(p):
        return np.linalg.norm(p - clean.points, axis=1) / clean.h

    items = [("noisy (0.3h along normals)", noisy, err(noisy)), ("pcprep L1-TV", ours, err(ours))]
    for name, out in runs.items():
        if out.ok:
            items.append((name, out.value[0], err(out.value[0])))
        else:
            items.append((f"{name}: {out.error}", noisy, None))
    out_paths = [("Denoising, coloured by distance to the clean surface point",
                  panels(img / "denoise_fandisk.png", items, cmap="magma_r", vmin=0, vmax=0.6,
                         colorbar="error (× h)", size=0.6))]
    recon = []
    for title, pts in (("noisy", noisy), ("pcprep L1-TV", ours)):
        nrm = orient_normals_mst(pts, pca_normals(pts, 16, orient=False), k=10)
        r = run_isolated(meshlab.ball_pivoting, pts, nrm)
        if r.ok:
            recon.append((f"BPA of {title}", r.value[0], None, r.value[1]))
        else:
            recon.append((f"BPA of {title}: {r.error}", pts, None))
    out_paths.append(("MeshLab ball pivoting of the noisy and denoised clouds",
                      panels(img / "denoise_bpa.png", recon)))
    return out_paths


def simplify_figures(img: Path, seed: int = 0) -> list[tuple[str, Path]]:
    """pcprep SDBS beside MeshLab Poisson-disk at 5 % and 20 % on the bunny."""
    from pcprep.baselines import meshlab
    from pcprep.baselines.datasets import load_sample_mesh
    from pcprep.baselines.harness import run_isolated

    bunny = load_sample_mesh("bunny")
    pts = bunny.points
    spec = _spec("simplify")
    items = []
    for ratio in (0.05, 0.2):
        res = spec.func(pts, ratio=ratio, seed=seed)
        keep = getattr(res, spec.index_field)
        items.append((f"pcprep SDBS {ratio:.0%} ({len(keep)})", pts[keep], None))
        pd = run_isolated(meshlab.poisson_disk_exact, pts, int(round(ratio * len(pts))))
        if pd.ok:
            items.append((f"Poisson-disk {ratio:.0%} ({len(pd.value)})", pts[pd.value], None))
        else:
            items.append((f"Poisson-disk: {pd.error}", pts, None))
    return [("Simplified bunny (pymeshlab sample mesh): SDBS vs MeshLab Poisson-disk",
             panels(img / "simplify_bunny.png", items, size=0.8, elev=10, azim=-80))]


def detection_figures(img: Path, seed: int = 0, n: int = 12000) -> list[tuple[str, Path]]:
    """Detected sharp features (fandisk, clean and 0.3h) and hole rims (a
    sphere with cut holes).  Red = correct, orange = false positive, blue = miss."""
    from pcprep.baselines.datasets import add_noise, cut_holes, make_shape

    feat = _spec("features")
    part = make_shape("fandisk", n=n, seed=seed)
    items = []
    for sigma in (0.0, 0.3):
        pts = part.points if sigma == 0 else add_noise(part.points, part.normals, sigma=sigma,
                                                        h=part.h, kind="normal", seed=seed)
        res = feat.func(pts, seed=seed)
        mask = np.asarray(getattr(res, feat.mask_field), bool)
        items.append((f"sharp features, noise {sigma:g}h", pts, _mask_colours(mask, part.sharp)))
    holes = _spec("holes")
    holed = cut_holes(make_shape("sphere", n=n, seed=seed), n_holes=3, radius=8.0, seed=seed)
    res = holes.func(holed.points, seed=seed)
    mask = np.asarray(getattr(res, holes.mask_field), bool)
    items.append(("hole rims", holed.points, _mask_colours(mask, holed.rim)))
    return [("Detections (red correct, orange false positive, blue missed)",
             panels(img / "detections.png", items, size=0.8))]


def build_all(img: Path, seed: int = 0) -> tuple[list[tuple[str, Path]], list[str]]:
    """Render every figure; a figure that fails is reported, not fatal.

    Returns ``(figures, failures)``.
    """
    figs, failures = [], []
    for fn in (denoise_figures, simplify_figures, detection_figures):
        try:
            log.info("report: rendering %s", fn.__name__)
            figs.extend(fn(img, seed=seed))
        except Exception as exc:  # a figure must never take the report down
            log.warning("report: %s failed: %s", fn.__name__, exc)
            failures.append(f"{fn.__name__}: {type(exc).__name__}: {exc}")
    return figs, failures
