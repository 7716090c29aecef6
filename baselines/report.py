"""
report.py
---------
``pcprep report``: run every comparison harness (denoise, simplify,
features/holes, saliency; quality and speed), render the pictures, and write
``reports/index.md`` plus an offline HTML rendering ``reports/index.html``.

A harness that fails is shown as failed in the index, with its error, never
silently dropped.  ``quick=True`` uses small generated data and pymeshlab's
sample meshes only (a few minutes on 2 cores); the full run also uses
``../shared/data/models`` when present.
"""

from __future__ import annotations

import html
import logging
import re
import time
import traceback
from importlib import import_module
from importlib.util import find_spec
from pathlib import Path

from pcprep.meshlab_bridge.specs import FAMILIES

from .harness import environment_info, resolve_out_dir, to_jsonable, write_report

log = logging.getLogger("pcprep")

#: benchmarks that are not a filter family: run once, no speed part
EXTRA = ("robustness",)
TITLES = {
    "robustness": "Robustness: bad and odd input",
    "outliers": "Outlier removal (not in the thesis)",
    "denoise": "Denoising (thesis ch. 4)",
    "simplify": "Simplification, SDBS (thesis ch. 6)",
    "features": "Sharp features and hole boundaries (thesis ch. 7)",
    "saliency": "Saliency (thesis ch. 5)",
}


def _run_step(family: str, speed: bool, quick: bool, seed: int, out_dir: str) -> dict:
    name = f"speed_{family}" if speed else family
    t0 = time.perf_counter()
    try:
        try:
            mod = import_module(f"pcprep.baselines.bench_{family}")
        except ModuleNotFoundError as exc:
            if exc.name != f"pcprep.baselines.bench_{family}":
                raise
            log.info("report: the %s family has no benchmark", family)
            return {"name": name, "status": "no benchmark", "error": None, "seconds": 0.0}
        fn = mod.run_speed if speed else mod.run
        log.info("report: running %s%s", name, " (quick)" if quick else "")
        fn(quick=quick, seed=seed, out_dir=out_dir)
        status, error = "ok", None
    except Exception as exc:  # one harness failing must not take the report down
        status = "failed"
        error = f"{type(exc).__name__}: {exc}"
        log.warning("report: %s failed: %s", name, error)
        log.debug(traceback.format_exc())
    return {"name": name, "status": status, "error": error,
            "seconds": round(time.perf_counter() - t0, 1)}


def _report_file(out: Path, name: str, quick: bool) -> Path:
    """The Markdown a harness wrote: some name their quick runs ``<name>_quick``."""
    if quick and (out / f"{name}_quick.md").exists():
        return out / f"{name}_quick.md"
    return out / f"{name}.md"


def _demote(md: str, levels: int = 1) -> str:
    """Push every Markdown heading down ``levels`` levels."""
    return re.sub(r"^(#{1,5}) ", lambda m: "#" * (len(m.group(1)) + levels) + " ", md,
                  flags=re.M)


def _thesis_section() -> str:
    try:
        tables = import_module("pcprep.baselines.thesis_tables")
    except ImportError:
        return ""
    names = list(tables.TABLES)
    parts = []
    for n in names:
        try:
            parts.append(tables.table_markdown(n))
        except Exception as exc:  # a garbled table is reported, not fatal
            parts.append(f"(table {n} could not be rendered: {exc})\n")
    if not parts:
        return ""
    return ("## The thesis' published figures\n\nThese are the thesis' own numbers on its own "
            "data (MATLAB implementations, other machines); they are shown for orientation, "
            "not re-run here.\n\n" + "\n".join(parts))


def build(quick: bool = False, seed: int = 0, out_dir: str = "reports",
          assemble_only: bool = False, models: str | None = None) -> Path:
    """Run every harness and write ``index.md`` / ``index.html`` into ``out_dir``.

    With ``assemble_only`` no harness is re-run: the index is assembled from
    the per-harness reports already in ``out_dir`` (those missing are shown as
    missing) and only the pictures are rendered.  ``models`` is the folder of the
    public models (see ``datasets.shared_models_root`` for where it is looked up
    otherwise).  Returns the path of ``index.md``.
    """
    from . import datasets, figures

    if models is not None:
        datasets.use_models_root(models)
    hint = datasets.models_hint()
    if hint and not quick:
        log.warning("report: %s", hint)

    out = resolve_out_dir(out_dir)
    (out / "img").mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    env = environment_info()
    steps = []
    for family in (*FAMILIES, *EXTRA):
        for speed in (False, True) if family not in EXTRA else (False,):
            if assemble_only and find_spec(f"pcprep.baselines.bench_{family}") is None:
                steps.append({"name": family, "status": "no benchmark", "error": None,
                              "seconds": 0.0})
            elif assemble_only:
                name = f"speed_{family}" if speed else family
                there = _report_file(out, name, quick).exists()
                steps.append({"name": name, "status": "ok" if there else "failed",
                              "error": None if there else "no report in this folder (not run)",
                              "seconds": 0.0})
            else:
                steps.append(_run_step(family, speed, quick, seed, str(out)))
            if steps[-1]["status"] == "no benchmark":
                break  # one row says so; no speed row
    figs, fig_failures = figures.build_all(out / "img", seed=seed)
    total = time.perf_counter() - t0

    md = ["# pcprep comparison report", ""]
    mode = "quick" if quick else "full"
    if assemble_only:
        md.append("Assembled from the per-harness reports in this folder; each states its own "
                  f"mode and settings. Pictures rendered now (seed {seed}).")
    else:
        md.append(f"Mode: **{mode}**, seed {seed}, total time {total / 60:.1f} min.")
    md.append("Rerunning with the same mode and seed reproduces every quality number; times "
              "and memory vary with machine load.")
    md.append("")
    md.append("## Machine and library versions")
    md.append("")
    for k, v in env.items():
        md.append(f"- {k}: {v}")
    md.append("")
    md.append("## Harness runs")
    md.append("")
    md.append("| report | status | time (s) |")
    md.append("|---|---|---|")
    for s in steps:
        status = (s["status"] if s["status"] in ("ok", "no benchmark")
                  else f"**FAILED**: {s['error']}")
        link = (f"[{s['name']}]({_report_file(out, s['name'], quick).name})"
                if s["status"] == "ok" else s["name"])
        md.append(f"| {link} | {status} | {s['seconds']:.1f} |")
    md.append("")
    if figs or fig_failures:
        md.append("## Pictures")
        md.append("")
        for title, path in figs:
            rel = Path(path).relative_to(out)
            md.append(f"**{title}**")
            md.append("")
            md.append(f"![{title}]({rel.as_posix()})")
            md.append("")
        for fail in fig_failures:
            md.append(f"- picture **FAILED**: {fail}")
        md.append("")
    for family in (*FAMILIES, *EXTRA):
        md.append(f"## {TITLES.get(family, family)}")
        md.append("")
        for name in (family,) if family in EXTRA else (family, f"speed_{family}"):
            path = _report_file(out, name, quick)
            step = next((s for s in steps if s["name"] == name), None)
            if step is None:
                continue
            if step["status"] == "no benchmark":
                md.append(f"{name}: this family has no benchmark.")
                md.append("")
            elif step["status"] != "ok":
                md.append(f"**{name} FAILED**: {step['error']}")
                md.append("")
            elif path.exists():
                md.append(_demote(path.read_text(encoding="utf-8"), 2))
                md.append("")
    thesis = _thesis_section()
    if thesis:
        md.append(thesis)
    text = "\n".join(md) + "\n"
    data = {"mode": "quick" if quick else "full", "seed": seed, "environment": env,
            "steps": steps, "figures": [f"img/{p.name}" for _, p in figs],
            "figure_failures": fig_failures, "total_seconds": total}
    md_path, _ = write_report("index", text, to_jsonable(data), out_dir=str(out))
    (out / "index.html").write_text(markdown_to_html(text, title="pcprep comparison report"),
                                    encoding="utf-8")
    log.info("report: wrote %s and index.html in %.1f min", md_path, total / 60)
    return md_path


# ---------------------------------------------------------------------------------------
# Markdown → HTML with markdown-it-py (CommonMark + tables): raw HTML in the text is
# escaped and unsafe link targets (javascript:, vbscript:, data: other than images) are
# not made links, so a report built from other people's names and files cannot inject
# script into the page
# ---------------------------------------------------------------------------------------

_CSS = """body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;
color:#222}table{border-collapse:collapse;margin:1em 0;font-size:13px}td,th{border:1px solid
#ccc;padding:3px 7px;text-align:right}th{background:#f3f3f3}td:first-child,th:first-child{
text-align:left}img{max-width:100%}code{background:#f3f3f3;padding:0 3px}h1,h2,h3{margin-top:
1.4em}"""


def markdown_to_html(md: str, title: str = "report") -> str:
    """Render Markdown as a standalone HTML page that opens offline."""
    from markdown_it import MarkdownIt

    body = MarkdownIt("commonmark", {"html": False}).enable("table").render(md)
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            f"</title><style>{_CSS}</style></head><body>\n{body}</body></html>")
