"""
summary.py
----------
The report's opening table, computed from the per-family JSON the harnesses
wrote: for each filter its headline metric against the best baseline case by
case (wins, losses, ties and the means), on held-out cases where the harness
marks them (``"split": "held-out"``; a case without the key is a tuning
case) beside the tuning cases; its speed against the fastest timed peer and
against one k-NN pass; and a one-line verdict.  Then "where pcprep loses":
the models with the most losses, with the harness' own explanation when it
wrote one.

Nothing here is typed in by hand: every number is read from the JSON, so a
re-run of a harness changes the summary with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from .plots import KNN_KEYS, OURS_KEYS, load_json, speed_records, speed_series

SPLITS = ("held-out", "tuning")


@dataclass
class Case:
    """One benchmark case: ours and the best baseline on the headline metric."""

    model: str
    condition: str
    ours: float
    best: float
    best_name: str
    split: str


@dataclass
class Headline:
    """One filter's row of the summary."""

    filter: str
    metric: str
    lower_is_better: bool
    cases: list[Case] = field(default_factory=list)
    speed: str = "not timed"
    speed_ratios: dict = field(default_factory=dict)
    why: str = ""
    #: metric in model units: compare per-case ratios, not means across models
    relative: bool = False

    def split(self, name: str) -> list[Case]:
        return [c for c in self.cases if c.split == name]

    def better(self, a: float, b: float) -> bool:
        return a < b if self.lower_is_better else a > b

    def tally(self, cases: list[Case]) -> dict:
        """Wins, losses and ties of ours against the best baseline, and the means."""
        w = sum(self.better(c.ours, c.best) for c in cases)
        lo = sum(self.better(c.best, c.ours) for c in cases)
        ratios = [c.ours / c.best for c in cases if c.best > 0 and c.ours > 0]
        geo = math.exp(_mean([math.log(r) for r in ratios])) if ratios else math.nan
        return {"n": len(cases), "wins": w, "losses": lo, "ties": len(cases) - w - lo,
                "ours": _mean([c.ours for c in cases]), "best": _mean([c.best for c in cases]),
                "ratio_geomean": geo}

    @property
    def headline_split(self) -> str:
        return "held-out" if self.split("held-out") else "tuning"

    def verdict(self) -> str:
        if not self.cases:
            return "no benchmark cases"
        t = self.tally(self.split(self.headline_split))
        where = "held-out" if self.headline_split == "held-out" else "tuning"
        mean_better = (t["ratio_geomean"] < 1 if self.relative
                       else self.better(t["ours"], t["best"]))
        if t["wins"] > t["losses"] and mean_better:
            word = "Ahead"
        elif t["wins"] < t["losses"] and not mean_better:
            word = "Behind"
        else:
            word = "Mixed"
        r = self.speed_ratios.get("over_fastest_peer")
        pace = ("no timed peer" if r is None else
                "faster than the fastest peer" if r < 1 else
                f"{r:.1f}× slower than the fastest peer")
        return f"{word}: better in {t['wins']} of {t['n']} {where} cases; {pace}."


def _mean(xs) -> float:
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return sum(xs) / len(xs) if xs else math.nan


def _num(v) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _best_of(values: dict, lower: bool) -> tuple[float | None, str]:
    vals = {k: v for k, v in values.items() if v is not None}
    if not vals:
        return None, ""
    name = (min if lower else max)(vals, key=vals.get)
    return vals[name], name


def _split(rec: dict) -> str:
    s = rec.get("split", "tuning")
    return "held-out" if s in ("held-out", "heldout", "held_out", "test") else "tuning"


# ---------------------------------------------------------------------------------------
# per family: the cases of the headline metric


def denoise_cases(data: dict) -> list[Case]:
    """MAD of each method's own normals (deg, lower is better); jet outputs none."""
    out = []
    for c in data.get("cases", []):
        methods = c.get("methods") or {}

        def val(m):
            return _num((((methods.get(m) or {}).get("best") or {}).get("mad_own") or {})
                        .get("value"))

        ours = val("ours")
        best, name = _best_of({m: val(m) for m in methods if not m.startswith("ours")}, True)
        if ours is not None and best is not None:
            out.append(Case(str(c.get("model")), str(c.get("condition")), ours, best, name,
                            _split(c)))
    return out


#: simplification baselines that meet the asked count (MeshLab's "simplified cloud" does not)
SIMPLIFY_PEERS = ("Poisson-disk", "CGAL grid", "CGAL HCS", "CGAL WLOP")


def simplify_cases(data: dict) -> list[Case]:
    """Δavg, the mean distance of the original points to the simplified surface (lower is
    better), SDBS against the count-matched baselines."""
    out = []
    for c in data.get("cases", []):
        methods = c.get("methods") or {}

        def val(m):
            rec = methods.get(m) or {}
            if not (rec.get("outcome") or {}).get("ok", True):
                return None
            return _num(rec.get("davg"))

        ours = val("SDBS")
        best, name = _best_of({m: val(m) for m in SIMPLIFY_PEERS if m in methods}, True)
        if ours is not None and best is not None:
            cond = f"{float(c.get('rate', 0)):.0%}" if c.get("rate") is not None else ""
            out.append(Case(str(c.get("model")), cond, ours, best, name, _split(c)))
    return out


def _detection_cases(rows: list, key: str = "f1") -> list[Case]:
    out = []
    for c in rows:
        res = c.get("results") or {}
        ours = _num((res.get("ours") or {}).get(key))
        best, name = _best_of({m: _num((r or {}).get(key)) for m, r in res.items()
                               if not m.startswith("ours")}, False)
        if ours is not None and best is not None:
            cond = f"noise {c['noise']:g}h" if "noise" in c else ""
            out.append(Case(str(c.get("data")), cond, ours, best, name, _split(c)))
    return out


def sharp_cases(data: dict) -> list[Case]:
    """Sharp-feature F1 (higher is better) against the classic detectors."""
    return _detection_cases(data.get("sharp", []))


def hole_cases(data: dict) -> list[Case]:
    """Hole-rim F1 (higher is better) against the angle-gap detector."""
    return _detection_cases(data.get("holes", []))


#: keys of a saliency row that are not a method's AUC
_SALIENCY_META = {"shape", "condition", "n", "positives", "seconds_ours", "band_auc", "split",
                  "model", "seconds"}


def saliency_cases(data: dict) -> list[Case]:
    """ROC AUC of the score against the salient truth (higher is better)."""
    out = []
    for r in data.get("rows", []):
        ours = _num(r.get("ours"))
        best, name = _best_of({k: _num(v) for k, v in r.items()
                               if k not in _SALIENCY_META and not k.startswith("ours")}, False)
        if ours is not None and best is not None:
            out.append(Case(str(r.get("shape")), str(r.get("condition", "")), ours, best, name,
                            _split(r)))
    return out


# ---------------------------------------------------------------------------------------
# speed


def speed_summary(data: dict | None) -> tuple[str, dict]:
    """At the largest size timed: ours over the fastest peer and over one k-NN pass."""
    recs = speed_records(data)
    series = speed_series(data)
    if not recs or not series:
        return "not timed", {}
    ours_key = next((k for k in series if k in OURS_KEYS), None)
    if ours_key is None:
        return "not timed", {}
    n = max(p[0] for p in series[ours_key])
    at = {k: dict(v).get(n) for k, v in series.items()}
    ours = at[ours_key]
    peers = {k: v for k, v in at.items()
             if v is not None and k not in OURS_KEYS and k not in KNN_KEYS
             and not k.startswith("sdbs")}
    knn = next((at[k] for k in at if k in KNN_KEYS and at[k] is not None), None)
    ratios = {"n": n, "seconds": ours}
    parts = []
    if peers:
        fastest = min(peers, key=peers.get)
        ratios["fastest_peer"] = fastest
        ratios["over_fastest_peer"] = ours / peers[fastest]
        parts.append(f"{ours / peers[fastest]:.1f}× the time of the fastest peer "
                     f"({_peer_label(fastest)})")
    else:
        parts.append("no peer timed")
    if knn:
        ratios["over_knn"] = ours / knn
        parts.append(f"{ours / knn:.1f}× one k-NN pass")
    return f"{', '.join(parts)} at {n:,} points", ratios


def _peer_label(key: str) -> str:
    from .plots import LABELS

    return LABELS.get(key, key)


def _quality_run_speed(rows: list) -> tuple[str, dict]:
    """Median over the quality cases of ours' time over the fastest other
    detector's (features and holes record every detector's seconds)."""
    ratios = []
    for c in rows:
        res = c.get("results") or {}
        ours = _num((res.get("ours") or {}).get("seconds"))
        peers = [_num((r or {}).get("seconds")) for m, r in res.items() if not m.startswith("ours")]
        peers = [p for p in peers if p]
        if ours and peers:
            ratios.append(ours / min(peers))
    if not ratios:
        return "not timed", {}
    ratios.sort()
    med = ratios[len(ratios) // 2]
    return (f"{med:.1f}× the time of the fastest peer (median over the quality cases)",
            {"over_fastest_peer": med})


# ---------------------------------------------------------------------------------------


def headlines(out: Path, quick: bool) -> list[Headline]:
    """Every filter's summary row, read from the JSON in ``out``."""
    rows = []
    den = load_json(out, "denoise", quick)
    if den is not None:
        h = Headline("denoise", "MAD of own normals (deg)", True, denoise_cases(den))
        h.speed, h.speed_ratios = speed_summary(load_json(out, "speed_denoise", quick))
        notes = den.get("notes")
        if isinstance(notes, str) and "Where ours loses" in notes:
            h.why = notes.split("Where ours loses, and why.", 1)[-1].strip()
        rows.append(h)
    simp = load_json(out, "simplify", quick)
    if simp is not None:
        h = Headline("simplify (SDBS)", "Δavg (mean distance to the simplified surface)",
                     True, simplify_cases(simp), relative=True)
        h.speed, h.speed_ratios = speed_summary(load_json(out, "speed_simplify", quick))
        rows.append(h)
    feat = load_json(out, "features", quick)
    if feat is not None:
        h = Headline("features (sharp edges)", "F1", False, sharp_cases(feat))
        sp = load_json(out, "speed_features", quick)
        h.speed, h.speed_ratios = speed_summary(sp)
        if "no peer timed" in h.speed or h.speed == "not timed":
            q, qr = _quality_run_speed(feat.get("sharp", []))
            if qr:
                knn = h.speed.split(", ", 1)[-1] if "k-NN" in h.speed else ""
                h.speed = q + (f"; {knn}" if knn else "")
                h.speed_ratios = {**h.speed_ratios, **qr}
        rows.append(h)
        h = Headline("holes (hole boundaries)", "F1", False, hole_cases(feat))
        h.speed, h.speed_ratios = _quality_run_speed(feat.get("holes", []))
        rows.append(h)
    sal = load_json(out, "saliency", quick)
    if sal is not None:
        h = Headline("saliency", "ROC AUC", False, saliency_cases(sal))
        h.speed, h.speed_ratios = speed_summary(load_json(out, "speed_saliency", quick))
        rows.append(h)
    return rows


def _fmt(v: float, lower: bool) -> str:
    if v is None or not math.isfinite(v):
        return "n/a"
    return f"{v:.3g}" if abs(v) >= 0.01 or v == 0 else f"{v:.2e}"


def _cell(h: Headline, split: str) -> str:
    cases = h.split(split)
    if not cases:
        return "no held-out cases yet" if split == "held-out" else "none"
    t = h.tally(cases)
    head = (f"{t['wins']} wins / {t['losses']} losses"
            + (f" / {t['ties']} ties" if t["ties"] else "") + f" of {t['n']}; ")
    if h.relative:
        return head + f"ours ÷ best, geometric mean {t['ratio_geomean']:.3f}"
    return head + (f"mean {_fmt(t['ours'], h.lower_is_better)} vs "
                   f"{_fmt(t['best'], h.lower_is_better)}")


def markdown(rows: list[Headline], missing: list[str] = ()) -> str:
    """The summary table and the "where pcprep loses" list, as Markdown."""
    if not rows:
        return "No harness results in this folder yet: the summary needs them.\n"
    table = _table(
        ["filter", "headline metric", "held-out: ours vs best baseline",
         "tuning: ours vs best baseline", "speed", "verdict"],
        [[h.filter, h.metric + (" ↓" if h.lower_is_better else " ↑"), _cell(h, "held-out"),
          _cell(h, "tuning"), h.speed, h.verdict()] for h in rows])
    md = [table, "",
          "Each cell compares pcprep (defaults) with the best baseline of each case (each "
          "baseline at its best grid setting for that case); ↓ lower is better, ↑ higher. "
          "Held-out cases are those the harness marks as not used to choose pcprep's "
          "defaults; speed is at the largest size timed, from the speed benchmarks."]
    for m in missing:
        md.append(f"- {m}: no results in this folder.")
    md += ["", "### Where pcprep loses, and why", ""]
    for h in rows:
        split = h.headline_split
        losses = [c for c in h.split(split) if h.better(c.best, c.ours)]
        if not losses:
            md.append(f"- **{h.filter}**: no loss on the {split} cases.")
            continue
        by_model: dict[str, list[Case]] = {}
        for c in losses:
            by_model.setdefault(c.model, []).append(c)
        worst = sorted(by_model.items(), key=lambda kv: -len(kv[1]))[:4]
        total = {m: sum(1 for c in h.split(split) if c.model == m) for m, _ in worst}
        parts = []
        for m, cs in worst:
            names = sorted({c.best_name for c in cs})
            parts.append(f"{m} ({len(cs)} of {total[m]}; beaten by {', '.join(names)})")
        md.append(f"- **{h.filter}** loses {len(losses)} of {len(h.split(split))} {split} "
                  f"cases on {h.metric}, most on: " + "; ".join(parts) + ".")
        if h.why:
            md.append(f"  Why, in the harness' words: {h.why}")
    return "\n".join(md) + "\n"


def _table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table whose cells are kept whole (pipes escaped)."""
    def esc(x):
        return str(x).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(map(esc, header)) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(map(esc, r)) + " |" for r in rows]
    return "\n".join(lines)


def to_json(rows: list[Headline]) -> list[dict]:
    """The summary as data (kept in ``index.json``)."""
    out = []
    for h in rows:
        out.append({"filter": h.filter, "metric": h.metric,
                    "lower_is_better": h.lower_is_better,
                    **{s: h.tally(h.split(s)) for s in SPLITS},
                    "speed": h.speed, "speed_ratios": h.speed_ratios, "verdict": h.verdict()})
    return out
