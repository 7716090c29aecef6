"""
bench_saliency.py
-----------------
Saliency benchmark (thesis ch.5): ROC AUC of ``saliency_sparse_mdl`` against
constructed ground truth, beside simple baselines, plus heat maps, a side
signal against per-face saliency maps of unknown origin, and the speed run.

Ground truth
    * CAD solids ("cube", "fandisk", "block", "star", "octahedron"):
      ``Sample.sharp`` = points within 1 h of an edge sharper than 30°.
    * "bumpy_plane": ``extra["salient"]`` = within 2σ of a bump or dent centre.
Conditions: clean; 0.3 h Gaussian noise along the normal ("0.3h"); the thesis'
Fig. 5.12 setting, 30 % random noise (σ = 0.3 h in a random direction).
A sensitivity table repeats the CAD AUCs with 2 h and 3 h bands around the same
edges (side information; the benchmark's truth stays the 1 h band).

Ours is run with its defaults (quantile accumulation), with the thesis' mean
accumulation, and with the thesis' product measure (5.7).

Baselines: surface variation λ0/Σλ of 16-NN PCA (thesis 2.5); curvature
magnitude √(k1²+k2²) of the same radius-3h quadric fit the filter uses; |K|;
the SDBS global score Sf of chapter 6 (``pcprep.filters.simplify.simplify_sdbs(...).score``)
when that module is importable.

``run`` writes reports/saliency.md, reports/saliency.json and
reports/img/saliency_*.png; ``run_speed`` writes reports/speed_saliency.md and
reports/speed_saliency.json.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np

from pcprep.baselines import harness
from pcprep.baselines.datasets import add_noise, load_shared_model, make_shape
from pcprep.filters.metrics import roc_auc
from pcprep.filters.neighbors import build_tree, knn, weighted_pca
from pcprep.filters.saliency import (local_frames_and_curvature, neighbourhoods,
                              saliency_sparse_mdl)

log = logging.getLogger("pcprep")

CAD = ("cube", "fandisk", "block", "star", "octahedron")
SMOOTH = ("bumpy_plane",)
CONDITIONS = (("clean", None, 0.0), ("0.3h", "normal", 0.3),
              ("30% random", "random", 0.3))
UNVERIFIED = ("armadillo", "bimba", "blade", "bunny", "bust", "fandisk", "gargoyle",
              "horse", "maxplanck")
THESIS_SECONDS_15K = 81.7
OURS = ("ours", "ours (mean accumulation)", "ours (thesis 5.7, mdl)")
BASELINES = ("surface variation", "curvature magnitude", "|K| (Gaussian)",
             "SDBS global score")
METHODS = OURS + BASELINES
#: half-widths (× h) of the sensitivity check of the CAD ground-truth band; the
#: official truth stays the 1 h band of ``Sample.sharp``
BANDS = (1.0, 2.0, 3.0)
BAND_METHODS = ("ours", "ours (mean accumulation)", "surface variation",
                "curvature magnitude")


# ----------------------------------------------------------------------------------------
# baselines

def _sdbs_score_fn():
    """The ch.6 SDBS global score Sf (6.10) as ``fn(points) -> (n,)``, or None when
    ``pcprep.filters.simplify`` is not available."""
    try:
        from pcprep.filters.simplify import simplify_sdbs
    except ImportError:
        return None

    def score(points):
        # Sf of every input point; the kept subset (ratio) does not affect it
        return simplify_sdbs(points, ratio=0.5, seed=0).score

    return score


def baseline_scores(points: np.ndarray, radius: float = 3.0) -> dict[str, np.ndarray]:
    """Simple per-point saliency baselines (higher = more salient)."""
    tree = build_tree(points)
    _, idx = knn(points, 16, tree=tree)
    out = {"surface variation": weighted_pca(points, idx).surface_variation}
    hood, h = neighbourhoods(points, radius, 48, tree)
    _, gauss, total = local_frames_and_curvature(points, hood, radius * h)
    out["curvature magnitude"] = total
    out["|K| (Gaussian)"] = np.abs(gauss)
    fn = _sdbs_score_fn()
    if fn is not None:
        try:
            out["SDBS global score"] = np.asarray(fn(points), dtype=np.float64)
        except Exception as exc:  # noqa: BLE001 - reported, not fatal
            log.info("bench_saliency: SDBS score failed: %s", exc)
    return out


# ----------------------------------------------------------------------------------------
# pictures

def _heatmap(path: Path, panels: list[tuple[str, np.ndarray, np.ndarray]], ncols: int = 3,
             max_points: int = 3000) -> Path:
    """Grid of point scatters coloured by score (each panel scaled between its 2nd
    and 98th percentiles for display), fixed view; about 600×400 px."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nrows = math.ceil(len(panels) / ncols)
    fig = plt.figure(figsize=(6.0, 2.0 * nrows), dpi=100)
    for i, (title, pts, vals) in enumerate(panels):
        ax = fig.add_subplot(nrows, ncols, i + 1, projection="3d")
        sel = np.arange(len(pts))
        if len(pts) > max_points:
            sel = np.random.default_rng(0).choice(len(pts), max_points, replace=False)
        p, v = pts[sel], vals[sel]
        lo, hi = (float(q) for q in np.percentile(vals, [2.0, 98.0]))
        col = np.clip((v - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)
        ax.scatter(*p.T, s=1.6, c=col, cmap="inferno", vmin=0, vmax=1, linewidths=0,
                   depthshade=False)
        lo3, hi3 = pts.min(axis=0), pts.max(axis=0)
        c, r = 0.5 * (lo3 + hi3), 0.5 * float(np.max(hi3 - lo3))
        for setlim, k in ((ax.set_xlim, 0), (ax.set_ylim, 1), (ax.set_zlim, 2)):
            setlim(c[k] - r, c[k] + r)
        ax.view_init(elev=28.0, azim=-58.0)
        ax.set_box_aspect((1, 1, 1))
        ax.set_axis_off()
        ax.set_title(title, fontsize=7)
    fig.subplots_adjust(left=0, right=1, top=0.92, bottom=0, wspace=0, hspace=0.12)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[:, :, :3]
    plt.close(fig)
    from PIL import Image  # matplotlib's own dependency

    # a 64-colour palette keeps the scatter pictures far below 150 KB
    Image.fromarray(rgb).quantize(colors=64).save(path, optimize=True)
    return path


# ----------------------------------------------------------------------------------------
# quality

def _truth(sample):
    return sample.extra["salient"] if sample.name == "bumpy_plane" else sample.sharp


def _evaluate(name: str, n: int, seed: int, conditions, img_dir: Path | None
              ) -> list[dict]:
    sample = make_shape(name, n=n, seed=seed)
    truth = _truth(sample)
    rows, pics_ours, pics_base = [], [], []
    for cond, kind, sigma in conditions:
        pts = sample.points if kind is None else add_noise(
            sample.points, sample.normals, sigma=sigma, h=sample.h, kind=kind,
            seed=seed + 1)
        t0 = time.perf_counter()
        ours = saliency_sparse_mdl(pts)
        dt = time.perf_counter() - t0
        mean_acc = saliency_sparse_mdl(pts, accumulation="mean")
        mdl = saliency_sparse_mdl(pts, measure="mdl")
        scores = {"ours": ours.saliency, "ours (mean accumulation)": mean_acc.saliency,
                  "ours (thesis 5.7, mdl)": mdl.saliency}
        scores.update(baseline_scores(pts))
        row = {"shape": name, "condition": cond, "n": len(pts),
               "positives": int(truth.sum()), "seconds_ours": dt}
        for m in METHODS:
            row[m] = roc_auc(scores[m], truth) if m in scores else None
        if name in CAD:
            # sensitivity only: AUC against wider bands around the same sharp edges
            ed = sample.extra["edge_distance"] / sample.h
            row["band_auc"] = {f"{w:g}h": {m: roc_auc(scores[m], ed <= w)
                                           for m in BAND_METHODS}
                               for w in BANDS}
        rows.append(row)
        pics_ours.append((f"ours, {cond} (AUC {row['ours']:.2f})", pts, ours.saliency))
        cm = scores["curvature magnitude"]
        title = f"curv. magnitude, {cond} ({row['curvature magnitude']:.2f})"
        pics_base.append((title, pts, cm))
        log.info("bench_saliency: %s %s ours AUC %.3f", name, cond, row["ours"])
    if img_dir is not None:
        _heatmap(img_dir / f"saliency_{name}.png", pics_ours + pics_base,
                 ncols=len(conditions))
    return rows


def _unverified(max_models: int | None = None) -> list[dict]:
    """Correlation with the per-face maps of unknown origin (side signal only)."""
    rows = []
    for name in UNVERIFIED[:max_models]:
        try:
            s = load_shared_model(f"saliency_unverified/{name}_decimated.obj")
        except Exception as exc:  # noqa: BLE001
            log.info("bench_saliency: %s not loaded: %s", name, exc)
            continue
        if s is None or "vertex_saliency" not in s.extra:
            continue
        ref = s.extra["vertex_saliency"]
        ours = saliency_sparse_mdl(s.points).saliency
        mean_acc = saliency_sparse_mdl(s.points, accumulation="mean").saliency
        base = baseline_scores(s.points)
        row = {"model": name, "n": len(s.points)}
        for m, v in [("ours", ours), ("ours (mean accumulation)", mean_acc)] + \
                list(base.items()):
            row[m] = float(np.corrcoef(v, ref)[0, 1])
        rows.append(row)
    return rows


def _auc_table(rows: list[dict]) -> str:
    methods = [m for m in METHODS if any(r.get(m) is not None for r in rows)]
    header = ["shape", "noise", "positives"] + methods
    body = [[r["shape"], r["condition"], r["positives"]] +
            [r.get(m) if r.get(m) is not None else "not available" for m in methods]
            for r in rows]
    best = {3 + i: "max" for i in range(len(methods))}
    return harness.markdown_table(header, body, best=best, fmt="{:.3f}")


def run(quick: bool = False, seed: int = 0, out_dir: str = "reports") -> dict:
    """Saliency quality benchmark → ``<out_dir>/saliency.md`` + ``.json`` and heat maps
    ``<out_dir>/img/saliency_<shape>.png``.

    ``quick``: cube and bumpy_plane, clean and 0.3 h, 8000 points, no unverified maps
    (about a minute).  Full: five CAD solids and the bumpy plane, three noise
    conditions, 20000 points, plus the unverified side signal.
    """
    out = harness.resolve_out_dir(out_dir)
    img = out / "img"
    shapes = ("cube", "bumpy_plane") if quick else CAD + SMOOTH
    conditions = CONDITIONS[:2] if quick else CONDITIONS
    n = 8000 if quick else 20000
    t0 = time.perf_counter()
    rows = []
    for name in shapes:
        rows += _evaluate(name, n, seed, conditions, img)
    unver = [] if quick else _unverified()
    sdbs = _sdbs_score_fn() is not None

    cad = [r for r in rows if r["shape"] in CAD]

    def _mean(rs, m):
        v = [r[m] for r in rs if r.get(m) is not None]
        return float(np.mean(v)) if v else None

    summary = {}
    for cond, _, _ in conditions:
        rs = [r for r in cad if r["condition"] == cond]
        summary[cond] = {m: _mean(rs, m) for m in METHODS}
    targets = {
        "cad_clean_min_auc": min((r["ours"] for r in cad if r["condition"] == "clean"),
                                 default=None),
        "cad_0.3h_min_auc": min((r["ours"] for r in cad if r["condition"] == "0.3h"),
                                default=None),
    }
    md = ["# Saliency (thesis ch. 5): ROC AUC against constructed ground truth", "",
          "Generated by `baselines/bench_saliency.py` "
          f"({'quick' if quick else 'full'} run, seed {seed}, {n} points per shape, "
          f"{time.perf_counter() - t0:.0f} s).", "",
          "Ground truth: CAD solids — points within 1 h of an edge sharper than 30° "
          "(`Sample.sharp`); bumpy plane — points within 2σ of a bump or dent centre. "
          "Noise: `0.3h` = Gaussian σ = 0.3 h along the normal; `30% random` = the "
          "thesis' Fig. 5.12 setting, σ = 0.3 h in a random direction.", "",
          "Methods: **ours** = `saliency_sparse_mdl` defaults (radius 3 h, 8 rays, "
          "λ = 0.9, residual measure, S_T accumulated as the 10 % quantile over the "
          "overlapping neighbourhoods); **ours (mean accumulation)** = the same with the "
          "thesis' mean accumulation (the previous default); **ours (thesis 5.7, mdl)** "
          "= the thesis' product N(‖α‖₀)·N(residual), default accumulation; surface "
          "variation = λ0/Σλ of 16-NN PCA; curvature "
          "magnitude = √(k1²+k2²) and |K| of the radius-3h quadric fit the filter itself "
          "uses; SDBS global score = Sf (6.10) of `simplify_sdbs` (ch. 6, defaults)"
          + ("." if sdbs else "— not available (`pcprep.filters.simplify` not importable)."),
          "",
          _auc_table(rows), "",
          "Mean AUC over the CAD solids:", ""]
    md.append(harness.markdown_table(
        ["noise"] + list(METHODS),
        [[c] + [summary[c][m] if summary[c][m] is not None else "not available"
                for m in METHODS] for c in summary],
        best={1 + i: "max" for i in range(len(METHODS))}, fmt="{:.3f}"))
    md += ["", f"Targets: AUC ≥ 0.85 clean (worst CAD shape: "
           f"{targets['cad_clean_min_auc']:.3f}) and ≥ 0.8 at 0.3 h (worst: "
           f"{targets['cad_0.3h_min_auc']:.3f}); above every simple baseline — see the "
           "bold entries: where a baseline is bold, the target is missed on that row.",
           ""]
    beaten = sorted({m for c in summary for m in BASELINES
                     if summary[c][m] is not None and summary[c]["ours"] is not None
                     and summary[c][m] > summary[c]["ours"]})
    smooth = [r for r in rows if r["shape"] in SMOOTH]
    smooth_wins = all(r["ours"] >= max(r[m] for m in BASELINES if r.get(m) is not None)
                      for r in smooth)
    smooth_text = ("above every baseline in every noise setting." if smooth_wins
                   else "not above every baseline.")
    gain = {c: summary[c]["ours"] - summary[c]["ours (mean accumulation)"]
            for c in summary if summary[c]["ours (mean accumulation)"] is not None}
    md += ["Findings (computed from the tables above):", "",
           "* CAD baselines with a higher mean AUC than ours in at least one noise "
           "setting: " + (", ".join(beaten) if beaten else "none") + ".  A straight "
           "sharp edge is not distinct from its surroundings along the edge: the rays "
           "along it end on neighbourhoods with the same descriptor, so the Lasso codes "
           "an edge neighbourhood almost as well as a flat one, and the residual rises "
           "only through the shrinkage (‖F̄‖ is shorter there) and the diversity of the "
           "atoms across the edge.  S_T is therefore high on a plateau about 2r wide "
           "around every edge, not on the 1 h band; point-wise curvature of a fit "
           "centred on the edge peaks on the band itself.",
           "* Accumulating S_T by a low quantile instead of the mean (a point is "
           "salient when nearly all neighbourhoods containing it are) narrows that "
           "plateau: mean CAD AUC change vs the mean accumulation: " +
           ", ".join(f"{c} {gain[c]:+.3f}" for c in gain) + ".",
           "* Bumps on a plane: ours is " + smooth_text + " Point-wise curvature and "
           "surface variation collapse under noise there.",
           "* The thesis' product with ‖α‖₀ (5.7) ranks below the residual alone: "
           "‖α‖₀ is larger on flat regions, where the centre lies between "
           "near-duplicate atoms, than on features (docstring Notes of "
           "`saliency_sparse_mdl`).", ""]
    banded = [r for r in cad if "band_auc" in r]
    if banded:
        md += ["Sensitivity of the CAD ranking to the ground-truth band (NOT the "
               "benchmark's truth, which stays the 1 h band): mean AUC over the CAD "
               "solids and all noise settings when the positives are the points within "
               "w h of a sharp edge.", ""]
        md.append(harness.markdown_table(
            ["band half-width"] + list(BAND_METHODS),
            [[w] + [float(np.mean([r["band_auc"][w][m] for r in banded]))
                    for m in BAND_METHODS] for w in banded[0]["band_auc"]],
            best={1 + i: "max" for i in range(len(BAND_METHODS))}, fmt="{:.3f}"))
        md.append("")
    if unver:
        md += ["## Side signal: per-face maps of unknown origin", "",
               "Pearson correlation of each score with the vertex average of the "
               "per-face values in `saliency_unverified/` (provenance unknown, NOT "
               "ground truth; shown only as a side signal).", ""]
        ms = [m for m in METHODS if m in unver[0]]
        mq = float(np.mean([r["ours"] for r in unver]))
        mm = float(np.mean([r["ours (mean accumulation)"] for r in unver]))
        md += [f"Mean correlation over the models: ours {mq:.3f}, ours (mean "
               f"accumulation) {mm:.3f}.  These maps are smooth; the quantile "
               "accumulation concentrates the score on the features themselves, the "
               "mean spreads it over about r (the trade-off of the default; "
               "`accumulation=\"mean\"` gives the thesis' accumulation).", ""]
        md.append(harness.markdown_table(["model", "n"] + ms,
                                         [[r["model"], r["n"]] + [r[m] for m in ms]
                                          for r in unver], fmt="{:.3f}"))
    md += ["", "Schelling-point data (thesis Table 5.1: AUC/NSS/LCC on SHREC 2007) is "
           "not in the shared data, so that protocol is not run.", ""]
    pics = sorted(img.glob("saliency_*.png"))
    for p in pics:
        if p.stem.startswith("saliency_") and p.stem[9:] in shapes:
            md.append(f"![{p.stem}](img/{p.name})")
    data = {"rows": rows, "summary_cad": summary, "targets": targets, "unverified": unver,
            "sdbs_available": sdbs, "quick": quick, "seed": seed, "n": n,
            "env": harness.environment_info()}
    harness.write_report("saliency", "\n".join(md), data, out_dir=out_dir)
    return data


# ----------------------------------------------------------------------------------------
# speed

def _time_saliency(points: np.ndarray) -> dict:
    """Run the filter once (in an isolated child); return small facts only."""
    res = saliency_sparse_mdl(points)
    return {"n": len(points), "unconverged": res.n_unconverged,
            "mean": float(res.saliency.mean())}


def run_speed(quick: bool = False, seed: int = 0, out_dir: str = "reports") -> dict:
    """Timing and peak memory at 15.5K and 1M points (quick: 15.5K and 100K), each in
    a fresh process; a k-NN pass (k = 16) on the same cloud is the yardstick."""
    sizes = (15_500, 100_000) if quick else (15_500, 1_000_000)
    rows = []
    for n in sizes:
        pts = make_shape("fandisk", n=n, seed=seed).points
        out = harness.measure(_time_saliency, pts)
        yard = harness.knn_pass_seconds(pts)
        limit = 3.0 if n <= 20_000 else 180.0
        rows.append({"n": n, "seconds": out.seconds if out.ok else None,
                     "peak_mb": out.peak_mb if out.ok else None,
                     "start_mb": out.start_mb, "ok": out.ok, "error": out.error,
                     "knn_seconds": float(yard), "ratio_to_knn":
                     out.seconds / float(yard) if out.ok and float(yard) > 0 else None,
                     "target_seconds": limit,
                     "thesis_seconds": THESIS_SECONDS_15K if n == 15_500 else None,
                     "speedup_vs_thesis": THESIS_SECONDS_15K / out.seconds
                     if out.ok and n == 15_500 else None})
        log.info("bench_saliency speed: n=%d %s", n, out)
    body = [[r["n"], r["seconds"] if r["ok"] else r["error"], r["peak_mb"],
             r["knn_seconds"], r["ratio_to_knn"], r["target_seconds"],
             r["speedup_vs_thesis"] if r["speedup_vs_thesis"] else "—"] for r in rows]
    md = ["# Saliency speed", "",
          "`saliency_sparse_mdl` with defaults on the fandisk shape, each size in a "
          "fresh process (`harness.measure`); peak RSS includes the interpreter and the "
          "input. "
          "Yardstick: one cKDTree build + 16-NN query of the same cloud. Thesis: 15.5K "
          "points in 81.7 s (MATLAB, i7-2670QM).", "",
          harness.markdown_table(["points", "seconds", "peak MB", "k-NN pass s",
                                  "× k-NN pass", "target s", "speed-up vs thesis"], body),
          "", "Targets: 15.5K points ≤ 3 s; 1M points ≤ 180 s and ≤ 1 GB."]
    data = {"rows": rows, "quick": quick, "seed": seed, "env": harness.environment_info()}
    harness.write_report("speed_saliency", "\n".join(md), data, out_dir=out_dir)
    return data
