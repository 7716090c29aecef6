"""
bench_departures.py
-------------------
Each default that departs from the thesis, and its held-out gain (issue #19).

For every filter with ``preset="thesis"``, a departure is one parameter (or one
coupled group, e.g. σ_d with the radius) whose default differs from the preset's
value, or one step of the detectors that the thesis does not have (their private
rules).  Each departure is reverted alone to the thesis' form, everything else at
the defaults, on the family's held-out cases (``datasets.HELD_OUT``); the
family's headline metric is compared with the defaults' and with the whole
preset.  The gain is what the default buys on data it was not chosen on
(positive: the default is better).  The held-out cases are only scored here;
nothing is chosen from this table.

``run`` writes reports/departures.md and reports/departures.json.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np

from pcprep.baselines import bench_denoise, bench_features, bench_saliency, datasets, harness
from pcprep.filters import denoise, holes, saliency, sharp, simplify
from pcprep.filters.metrics import mad_degrees, precision_recall_f1, roc_auc, \
    simplification_error, snr_db

log = logging.getLogger("pcprep")

#: parameters reverted together: one departure, several values
COUPLED = {
    "denoise": (("sigma_d", "radius"),),
    "sharp": (("coder", "alpha"),),
    "holes": (("coder", "alpha"),),
    "saliency": (("adaptive_radius", "radius", "k_max"),),
}
#: private steps whose departure a parameter already reverts (sharp: the angle
#: gate is min_angle=0), or that act only with another step off (holes: the second
#: Otsu split replaces the strip test)
COVERED = {"sharp": ("angle_gate",), "holes": ("second_split",)}
#: rate of the simplification runs (Table 6.2's middle rate)
SIMPLIFY_RATE = 0.10


def _signature_defaults(fn) -> dict:
    return {p.name: p.default for p in fn.params if p.name != "preset"}


def departures(family: str, fn, thesis: dict, default_rules=None, thesis_rules=None):
    """``[(label, params, rules)]``: the parameters whose default differs from the
    thesis' value (coupled ones together), then the private rules that the thesis
    switches off, each reverted alone."""
    defaults = _signature_defaults(fn)
    differ = [k for k, v in thesis.items() if k in defaults and defaults[k] != v]
    out, seen = [], set()
    for group in COUPLED.get(family, ()):
        if any(k in differ for k in group):
            keys = [k for k in group if k in thesis]
            out.append((", ".join(f"{k}={thesis[k]!r}" for k in keys),
                        {k: thesis[k] for k in keys}, None))
            seen.update(keys)
    for k in differ:
        if k not in seen:
            out.append((f"{k}={thesis[k]!r}", {k: thesis[k]}, None))
    if default_rules is not None:
        for f in default_rules.__dataclass_fields__:
            if f in COVERED.get(family, ()):
                continue
            if getattr(default_rules, f) != getattr(thesis_rules, f):
                out.append((f"step {f} off", {}, replace(default_rules,
                                                         **{f: getattr(thesis_rules, f)})))
    return out


# ------------------------------------------------------------------ the families
def _denoise_cases(quick):
    for spec in datasets.held_out_cases("denoise", quick):
        c = bench_denoise._held_out_case(spec, 4000 if quick else None)
        if c is not None:
            yield spec["case"], c


def _denoise_score(c, params, rules):
    res = denoise.denoise_l1_tv(c["noisy"], **params)
    m = len(c["points"])
    return {"mad": mad_degrees(c["normals"], res.normals[:m]),
            "snr": snr_db(c["points"], res.points[:m])}


def _detector_cases(family, quick):
    truth = datasets.sharp_truth if family == "sharp" else datasets.rim_truth
    for spec, c in bench_features._held_out(family, quick):
        pos, care = truth(c["sample"])
        m = len(c["points"]) - len(pos)
        c = dict(c, pos=np.r_[pos, np.zeros(m, bool)], care=np.r_[care, np.zeros(m, bool)])
        yield spec["case"] + (f" ({spec['sigma']:g}h)" if spec["noise"] else ""), c


def _detector_score(module):
    def score(c, params, rules):
        kw = dict(params, seed=0)
        res = (module._detect(c["points"], rules=rules, **kw) if rules is not None
               else getattr(module, _PUBLIC[module.__name__])(c["points"], **kw))
        care = c["care"]
        return {"f1": precision_recall_f1(res.mask[care], c["pos"][care])[2]}
    return score


_PUBLIC = {sharp.__name__: "detect_sharp_features", holes.__name__: "detect_hole_boundaries"}


def _saliency_cases(quick):
    for spec in datasets.held_out_cases("saliency", quick):
        c = datasets.build_case(spec, n=8000 if quick else None)
        if c is not None:
            yield spec["case"], dict(c, truth=bench_saliency._truth(c["sample"]))


def _saliency_score(c, params, rules):
    sal = saliency.saliency_sparse_mdl(c["points"], **params).saliency
    return {"auc": roc_auc(sal[:len(c["truth"])], c["truth"])}


def _simplify_cases(quick):
    for spec in datasets.held_out_cases("simplify", quick):
        c = datasets.build_case(spec)
        if c is not None:
            P = np.ascontiguousarray(c["points"], dtype=np.float64)
            yield spec["case"], dict(P=P, count=int(round(SIMPLIFY_RATE * len(P))))


def _simplify_score(c, params, rules):
    res = simplify.simplify_sdbs(c["P"], count=c["count"], **params)
    return {"davg": simplification_error(c["P"], c["P"][res.keep_idx], k=10)[1]}


FAMILIES = {
    "denoise": dict(fn=denoise.denoise_l1_tv, thesis=denoise.THESIS, cases=_denoise_cases,
                    score=_denoise_score,
                    metrics=(("mad", "MAD of the output normals (deg)", "min"),
                             ("snr", "SNR (dB)", "max"))),
    "sharp": dict(fn=sharp.detect_sharp_features, thesis=sharp.THESIS,
                  rules=(sharp.DEFAULT_RULES, sharp.THESIS_RULES),
                  cases=lambda q: _detector_cases("sharp", q), score=_detector_score(sharp),
                  metrics=(("f1", "F1", "max"),)),
    "holes": dict(fn=holes.detect_hole_boundaries, thesis=holes.THESIS,
                  rules=(holes.DEFAULT_RULES, holes.THESIS_RULES),
                  cases=lambda q: _detector_cases("holes", q), score=_detector_score(holes),
                  metrics=(("f1", "F1", "max"),)),
    "saliency": dict(fn=saliency.saliency_sparse_mdl, thesis=saliency.THESIS,
                     cases=_saliency_cases, score=_saliency_score,
                     metrics=(("auc", "ROC AUC", "max"),)),
    "simplify": dict(fn=simplify.simplify_sdbs, thesis=simplify.THESIS,
                     cases=_simplify_cases, score=_simplify_score,
                     metrics=(("davg", f"Δavg at {SIMPLIFY_RATE:.0%}, relative to the "
                               "defaults' on each case", "min"),), relative=True),
}


def _family(name: str, fam: dict, quick: bool) -> dict:
    deps = departures(name, fam["fn"], fam["thesis"], *fam.get("rules", (None, None)))
    variants = [("defaults", {}, None)] + deps + [("thesis preset", {"preset": "thesis"}, None)]
    cases = []
    for case, c in fam["cases"](quick):
        row = {"case": case, "values": {}}
        for label, params, rules in variants:
            try:
                row["values"][label] = {k: float(v) for k, v in
                                        fam["score"](c, params, rules).items()}
            except Exception as exc:  # noqa: BLE001 - recorded, the others go on
                row["values"][label] = None
                row.setdefault("errors", {})[label] = f"{type(exc).__name__}: {exc}"
        base = row["values"].get("defaults")
        if fam.get("relative") and base:
            row["values"] = {k: None if v is None else {m: v[m] / base[m] for m in v}
                             for k, v in row["values"].items()}
        log.info("bench_departures: %s %s: %s", name, case, row["values"])
        cases.append(row)
    summary = []
    for label, params, rules in variants:
        s = {"departure": label, "thesis_values": params, "metrics": {}}
        for key, _, better in fam["metrics"]:
            sign = 1.0 if better == "max" else -1.0
            vals = [(r["values"]["defaults"][key], r["values"][label][key]) for r in cases
                    if r["values"].get("defaults") and r["values"].get(label)]
            mean = float(np.mean([v for _, v in vals])) if vals else None
            base = float(np.mean([d for d, _ in vals])) if vals else None
            # the default's gain over this row, in the metric's unit (positive:
            # the default is better), and the cases where the default is better
            s["metrics"][key] = {
                "mean": mean, "cases": len(vals),
                "gain_of_default": None if label == "defaults" or mean is None
                else sign * (base - mean) + 0.0,
                "defaults_better_in": sum(sign * (d - v) > 0 for d, v in vals)}
        summary.append(s)
    return {"metrics": fam["metrics"], "cases": cases, "summary": summary}


def _markdown(data: dict) -> list[str]:
    md = ["# Departures from the thesis, and their held-out gain", "",
          f"{'Quick' if data['quick'] else 'Full'} run, {data['seconds'] / 60:.1f} min.", "",
          "Each row reverts one default that departs from the thesis (a parameter whose "
          "default differs from `preset=\"thesis\"`, parameters that only act together "
          "in one row, or a step the thesis does not have) to the thesis' form, "
          "everything else at the defaults, on the held-out cases of the family "
          "(`datasets.HELD_OUT`: shapes, samplings, noise and seeds the defaults were "
          "not chosen on).  Gain = what the default buys over that row, in the "
          "metric's unit (positive: the default is better); \"better in\" counts the "
          "held-out cases where the default wins.  The last row reverts everything at "
          "once (the preset).  Nothing is chosen from this table: it is the "
          "justification, or the lack of one, for each departure.", ""]
    for name, fam in data["families"].items():
        metrics = fam["metrics"]
        md += [f"## {name}", "", "Metrics: " + "; ".join(
            f"{label} ({'higher' if better == 'max' else 'lower'} is better)"
            for _, label, better in metrics)
            + f"; {len(fam['cases'])} held-out cases.", ""]
        header = ["reverted to the thesis"]
        for _, label, _ in metrics:
            header += [f"{label}: held-out mean", "gain of the default", "default better in"]
        body = []
        for s in fam["summary"]:
            row = [s["departure"]]
            for key, _, _ in metrics:
                m = s["metrics"][key]
                row += [m["mean"], "-" if m["gain_of_default"] is None
                        else m["gain_of_default"],
                        "-" if s["departure"] == "defaults"
                        else f"{m['defaults_better_in']} of {m['cases']}"]
            body.append(row)
        md += [harness.markdown_table(header, body, fmt="{:.4g}"), ""]
        unjustified = [s["departure"] for s in fam["summary"][1:-1]
                       if all(s["metrics"][k]["gain_of_default"] is not None
                              and s["metrics"][k]["gain_of_default"] <= 0
                              for k, _, _ in metrics)]
        if unjustified:
            md += ["No held-out gain on any metric (the thesis' form scores as well or "
                   "better): " + "; ".join(f"`{u}`" for u in unjustified) + ".", ""]
    return md


def run(quick: bool = False, seed: int = 0, out_dir: str = "reports",
        families=None) -> dict:
    """The departures of every family (or of ``families``) →
    ``<out_dir>/departures.md`` and ``.json``."""
    t0 = time.perf_counter()
    with bench_features._blas_one_thread():
        fams = {name: _family(name, FAMILIES[name], quick)
                for name in (families or FAMILIES)}
    data = {"families": fams, "quick": quick, "seed": seed,
            "seconds": time.perf_counter() - t0, "env": harness.environment_info()}
    harness.write_report("departures", "\n".join(_markdown(data)), data, out_dir=out_dir)
    return data
