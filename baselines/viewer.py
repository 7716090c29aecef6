"""
viewer.py
---------
The interactive part of the report page: each comparison's clouds embedded in
the HTML (subsampled, positions as base64 Float32, colours as RGB bytes) with
a small WebGL viewer (``viewer_assets/viewer.js``, inlined) that draws them side by
side with one shared camera.  Nothing is fetched, so the page works from the
file system with no network.
"""

from __future__ import annotations

import base64
import html
import json
from importlib import resources

import numpy as np

#: at most this many points per cloud in the page (keeps a report page a few MB)
MAX_POINTS = 8000


def asset(name: str) -> str:
    """The text of a file in ``viewer_assets/`` (installed as package data)."""
    return resources.files("pcprep.baselines").joinpath("viewer_assets", name).read_text(
        encoding="utf-8")


def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a).tobytes()).decode("ascii")


def _to_view(points: np.ndarray, up_axis: int) -> np.ndarray:
    """World coordinates → the viewer's (y up, z towards the viewer)."""
    if up_axis == 2:
        return np.c_[points[:, 0], points[:, 2], -points[:, 1]]
    if up_axis == 0:
        return np.c_[points[:, 1], points[:, 0], -points[:, 2]]
    return points


def payload(scene: dict, max_points: int = MAX_POINTS, columns: int = 4) -> dict:
    """One scene (``figures.scene``) as the viewer's JSON: every cloud centred
    and scaled by the same amount (the scene's common bounding box), so the
    panels line up; clouds subsampled to ``max_points`` with one seeded subset
    per cloud size."""
    clouds = scene["clouds"]
    up = int(scene.get("up_axis", 2))
    allp = np.vstack([np.asarray(c["points"], dtype=np.float64) for c in clouds])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    centre, half = 0.5 * (lo + hi), max(0.5 * float(np.max(hi - lo)), 1e-300)
    out = []
    for c in clouds:
        P = np.asarray(c["points"], dtype=np.float64)
        col = np.asarray(c["colours"], dtype=np.uint8).reshape(len(P), 3)
        if len(P) > max_points:
            sub = np.sort(np.random.default_rng(len(P)).choice(len(P), max_points,
                                                               replace=False))
            P, col = P[sub], col[sub]
        V = _to_view((P - centre) / half, up).astype("<f4")
        out.append({"label": str(c["label"]), "n": int(len(P)), "positions": _b64(V),
                    "colours": _b64(col)})
    n = max(len(c["points"]) for c in clouds) if clouds else 1
    size = float(np.clip(900.0 / np.sqrt(min(n, max_points)) / max(columns, 1) * 1.6, 1.5, 7))
    return {"title": str(scene.get("title", "")), "clouds": out,
            "columns": min(columns, len(out)) or 1, "point_size": size}


def block(scene: dict, ident: str, max_points: int = MAX_POINTS) -> str:
    """The HTML of one viewer (a div with its data); the script is added once per page
    by :func:`script`."""
    data = json.dumps(payload(scene, max_points), separators=(",", ":"))
    data = data.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")
    note = html.escape(scene.get("note", "") or "")
    return (f"<div class='pcv' id='{html.escape(ident, quote=True)}'>"
            f"<script type='application/json'>{data}</script></div>"
            + (f"<p class='pcv-note'>{note}</p>" if note else ""))


def style() -> str:
    return f"<style>{asset('viewer.css')}</style>"


def script() -> str:
    return f"<script>{asset('viewer.js')}</script>"
