"""
plots.py
--------
The report's two plots, drawn from the per-family JSON the harnesses wrote (so
``pcprep report --assemble-only`` redraws them without re-running anything):

- time against the number of points, log-log, for each filter, its timed
  peers and one k-NN pass (``speed_<family>.json``);
- quality against the noise level for every method: denoising MAD and SNR
  (``denoise.json``, noise along the normals), sharp-feature F1
  (``features.json``).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

log = logging.getLogger("pcprep")

#: how the speed records name pcprep's own run, per family
OURS_KEYS = {"ours", "sdbs", "seconds"}
#: keys of a k-NN pass (k = 16) in the speed records
KNN_KEYS = {"knn16", "knn_pass_s", "knn_seconds"}
LABELS = {"ours": "pcprep", "sdbs": "pcprep SDBS", "seconds": "pcprep",
          "sdbs_numpy": "pcprep SDBS (NumPy path)", "jet": "CGAL jet", "rimls": "RIMLS",
          "apss": "APSS", "bilateral": "CGAL bilateral", "poisson": "Poisson-disk",
          "hcs": "CGAL HCS", "grid": "CGAL grid", "wlop": "CGAL WLOP",
          "knn16": "one k-NN pass (k=16)", "knn_pass_s": "one k-NN pass (k=16)",
          "knn_seconds": "one k-NN pass (k=16)"}
FAMILY_TITLES = {"denoise": "denoising", "simplify": "simplification (SDBS)",
                 "features": "sharp features", "saliency": "saliency"}


def load_json(out: Path, name: str, quick: bool) -> dict | None:
    """``<out>/<name>.json`` (quick runs may be named ``<name>_quick.json``), or None."""
    for cand in ((f"{name}_quick", name) if quick else (name, f"{name}_quick")):
        p = Path(out) / f"{cand}.json"
        if p.is_file():
            try:
                return json.loads(p.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                log.warning("plots: %s unreadable: %s", p, exc)
                return None
    return None


def speed_records(data: dict | None) -> list[dict]:
    """The list of per-size records of a speed JSON (``records`` or ``rows``)."""
    if not data:
        return []
    recs = data.get("records", data.get("rows", []))
    return [r for r in recs if isinstance(r, dict) and "n" in r]


def _seconds(v) -> float | None:
    if isinstance(v, dict) and "seconds" in v:
        if v.get("ok", True) is False:
            return None
        s = v.get("seconds")
    elif isinstance(v, (int, float)) and not isinstance(v, bool):
        s = v
    else:
        return None
    return float(s) if s is not None and np.isfinite(s) and s > 0 else None


def speed_series(data: dict | None) -> dict[str, list[tuple[int, float]]]:
    """``{key: [(n, seconds), ...]}`` of every timed run in a speed JSON: the
    outcome records (dicts with ``seconds``), pcprep's ``seconds`` when the
    record has no outcome for it, and the k-NN pass."""
    series: dict[str, list] = {}
    for r in speed_records(data):
        n = int(r["n"])
        for k, v in r.items():
            if k in ("n", "count", "ratios") or k.endswith("_over_knn"):
                continue
            is_outcome = isinstance(v, dict) and "seconds" in v
            if not (is_outcome or k in KNN_KEYS or (k == "seconds" and "outcome" not in r)):
                continue
            if k == "outcome":
                k = "seconds"
            s = _seconds(v)
            if s is not None:
                series.setdefault(k, []).append((n, s))
    # the harness' warm re-run and the SDBS "with imports" copy are not separate methods
    for drop in ("warm_outcome", "sdbs_with_imports_s"):
        series.pop(drop, None)
    return series


def speed_plot(out: Path, img: Path, quick: bool) -> Path | None:
    """Time vs points, log-log, one panel per family."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fams = [(f, speed_series(load_json(out, f"speed_{f}", quick))) for f in FAMILY_TITLES]
    fams = [(f, s) for f, s in fams if s]
    if not fams:
        return None
    fig, axes = plt.subplots(1, len(fams), figsize=(5.0 * len(fams), 4.4), dpi=100,
                             squeeze=False)
    for ax, (fam, series) in zip(axes[0], fams):
        for k, pts in sorted(series.items(), key=lambda kv: (kv[0] not in OURS_KEYS,
                                                              kv[0] in KNN_KEYS, kv[0])):
            pts = sorted(pts)
            ours = k in OURS_KEYS
            knn = k in KNN_KEYS
            ax.loglog([p[0] for p in pts], [p[1] for p in pts],
                      "o-" if not knn else "s--", lw=2.6 if ours else 1.6,
                      color="#d62728" if ours else ("0.45" if knn else None),
                      label=LABELS.get(k, k), ms=6)
        ax.set_title(FAMILY_TITLES[fam], fontsize=13)
        ax.set_xlabel("points")
        ax.set_ylabel("seconds (wall)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=9, loc="upper left")
    fig.suptitle("Time against cloud size (log-log; each point one isolated run)",
                 fontsize=15)
    fig.tight_layout()
    path = Path(img) / "plot_speed.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def _mean_by(rows, key_x, key_m):
    acc: dict = {}
    for x, m, v in rows:
        if v is not None and np.isfinite(v):
            acc.setdefault(m, {}).setdefault(x, []).append(v)
    return {m: sorted((x, float(np.mean(vs))) for x, vs in d.items()) for m, d in acc.items()}


def denoise_curves(data: dict | None, metric: str) -> dict[str, list[tuple[float, float]]]:
    """Mean over models of ``metric`` against the noise level (noise along the
    normals, uniform sampling), per method and for the noisy input."""
    rows = []
    for c in (data or {}).get("cases", []):
        if c.get("kind") != "normal" or not c.get("uniform", True):
            continue
        x = float(c["sigma_h"])
        rows.append((x, "noisy input", (c.get("noisy") or {}).get(metric)))
        for m, rec in (c.get("methods") or {}).items():
            v = (((rec or {}).get("best") or {}).get(metric) or {}).get("value")
            rows.append((x, m, v))
    return _mean_by(rows, 0, 1)


def feature_curves(data: dict | None) -> dict[str, list[tuple[float, float]]]:
    """Mean sharp-feature F1 over the models against the noise level, per method."""
    rows = []
    for c in (data or {}).get("sharp", []):
        for m, rec in (c.get("results") or {}).items():
            rows.append((float(c.get("noise", 0.0)), m, (rec or {}).get("f1")))
    return _mean_by(rows, 0, 1)


def quality_plot(out: Path, img: Path, quick: bool) -> Path | None:
    """MAD and SNR (denoising) and F1 (sharp features) against the noise level."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    den = load_json(out, "denoise", quick)
    feat = load_json(out, "features", quick)
    panels = [("denoising: MAD of own normals (deg, lower is better)",
               denoise_curves(den, "mad_own"), "noise σ along the normals (× h)"),
              ("denoising: SNR (dB, higher is better)", denoise_curves(den, "snr"),
               "noise σ along the normals (× h)"),
              ("sharp features: F1 (higher is better)", feature_curves(feat),
               "noise σ along the normals (× h)")]
    panels = [p for p in panels if p[1]]
    if not panels:
        return None
    fig, axes = plt.subplots(1, len(panels), figsize=(6.6 * len(panels), 4.6), dpi=100,
                             squeeze=False)
    for ax, (title, curves, xlabel) in zip(axes[0], panels):
        for m, pts in sorted(curves.items(), key=lambda kv: (kv[0] != "ours", kv[0])):
            ours = m == "ours"
            noisy = m == "noisy input"
            ax.plot([p[0] for p in pts], [p[1] for p in pts], ":" if noisy else "o-",
                    lw=2.8 if ours else 1.5,
                    color="#d62728" if ours else ("k" if noisy else None),
                    label="pcprep" if ours else m.replace("_", " "), ms=6)
        ax.set_title(title, fontsize=13)
        ax.set_xlabel(xlabel)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=9)
    fig.suptitle("Quality against the noise level (mean over the benchmark's models; "
                 "each baseline at its best grid setting per case)", fontsize=14)
    fig.tight_layout()
    path = Path(img) / "plot_quality.png"
    fig.savefig(path)
    plt.close(fig)
    return path
