"""
report.py
---------
``pcprep report``: run every comparison harness (denoise, simplify,
features/holes, saliency; quality and speed), render the pictures, and write
``reports/index.md`` plus an offline HTML page ``reports/index.html`` (a
summary first, the pictures, 3-D viewers, and one HTML page per harness
report).

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
EXTRA = ("robustness", "departures")
TITLES = {
    "robustness": "Robustness: bad and odd input",
    "departures": "Departures from the thesis and their held-out gain",
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


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"


def build(quick: bool = False, seed: int = 0, out_dir: str = "reports",
          assemble_only: bool = False, models: str | None = None) -> Path:
    """Run every harness and write ``index.md`` / ``index.html`` into ``out_dir``.

    The index opens with the summary table (``summary.py``), then the rendered
    comparisons (``figures.py``), the plots (``plots.py``), the interactive 3-D
    views (``index.html`` only) and links to one HTML page per harness report;
    run times and the machine come last.  With ``assemble_only`` no harness is
    re-run: the index is assembled from the per-harness reports already in
    ``out_dir`` (those missing are shown as missing) and the pictures are
    rendered.  ``models`` is the folder of the public models (see
    ``datasets.shared_models_root`` for where it is looked up otherwise).
    Returns the path of ``index.md``.
    """
    from . import datasets, figures, plots, summary

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
    t_fig = time.perf_counter()
    figs, fig_failures = figures.build_all(out / "img", seed=seed, quick=quick)
    plot_paths = []
    for fn in (plots.speed_plot, plots.quality_plot):
        try:
            p = fn(out, out / "img", quick)
            if p is not None:
                plot_paths.append(p)
        except Exception as exc:  # a plot must never take the report down
            fig_failures.append(f"{fn.__name__}: {type(exc).__name__}: {exc}")
    fig_seconds = time.perf_counter() - t_fig
    rows = summary.headlines(out, quick)
    total = time.perf_counter() - t0
    mode = "quick" if quick else "full"

    pages = _family_pages(out, steps, quick)
    md, sections = _index_markdown(out, mode, seed, assemble_only, total, env, steps, figs,
                                   fig_failures, plot_paths, rows, pages, quick)
    text = "\n".join(md) + "\n"
    data = {"mode": mode, "seed": seed, "environment": env, "steps": steps,
            "summary": summary.to_json(rows),
            "figures": [f"img/{Path(f.path).name}" for f in figs]
            + [f"img/{p.name}" for p in plot_paths],
            "figure_failures": fig_failures, "figure_seconds": fig_seconds,
            "total_seconds": total}
    md_path, _ = write_report("index", text, to_jsonable(data), out_dir=str(out))
    viewers = [(f"viewer-{i}", f.scene) for i, f in enumerate(figs) if f.scene]
    (out / "index.html").write_text(
        index_html(text, sections, viewers), encoding="utf-8")
    log.info("report: wrote %s and index.html in %.1f min (pictures %.0f s)", md_path,
             total / 60, fig_seconds)
    return md_path


def _family_pages(out: Path, steps: list[dict], quick: bool) -> dict[str, str]:
    """Write an HTML page beside every harness report (and the thesis' tables);
    returns ``{report name: page file name}``."""
    pages = {}
    for s in steps:
        if s["status"] != "ok":
            continue
        src = _report_file(out, s["name"], quick)
        if not src.exists():
            continue
        page = src.with_suffix(".html")
        body = src.read_text(encoding="utf-8")
        page.write_text(markdown_to_html(
            f"[← back to the report](index.html)\n\n{body}", title=s["name"]),
            encoding="utf-8")
        pages[s["name"]] = page.name
    thesis = _thesis_section()
    if thesis:
        (out / "thesis.html").write_text(markdown_to_html(
            "[← back to the report](index.html)\n\n" + thesis,
            title="The thesis' published figures"), encoding="utf-8")
        pages["thesis"] = "thesis.html"
    return pages


def _index_markdown(out, mode, seed, assemble_only, total, env, steps, figs, fig_failures,
                    plot_paths, rows, pages, quick):
    """The index as Markdown lines, and its ``(anchor, title)`` sections."""
    from . import summary

    sections = []

    def section(title):
        sections.append((_slug(title), title))
        md.extend([f"## {title}", ""])

    md = ["# pcprep comparison report", ""]
    if assemble_only:
        md.append("Assembled from the per-harness reports in this folder (each states its "
                  f"own mode and settings); pictures rendered now with seed {seed}.")
    else:
        md.append(f"Mode: **{mode}** ({'small generated data and pymeshlab samples' if quick else 'every model'}), "
                  f"seed {seed}, {total / 60:.1f} min on this machine.")
    md.append("")
    section("Summary")
    missing = [s["name"] for s in steps if s["status"] == "failed"]
    md.append(summary.markdown(rows, [f"{m} ({next(s['error'] for s in steps if s['name'] == m)})"
                                      for m in missing]))
    section("Pictures")
    by_family: dict[str, list] = {}
    for f in figs:
        by_family.setdefault(f.family, []).append(f)
    for fam, items in by_family.items():
        md.append(f"### {TITLES.get(fam, fam)}")
        md.append("")
        for f in items:
            rel = Path(f.path).relative_to(out).as_posix()
            md += [f"**{f.title}**", "", f"[![{f.title}]({rel})]({rel})", "", f.caption, ""]
    if plot_paths:
        md += ["### Time and quality curves", ""]
        for p in plot_paths:
            rel = p.relative_to(out).as_posix()
            md += [f"![{p.stem}]({rel})", ""]
        md += ["Time: wall seconds of one isolated run per size, from the speed benchmarks. "
               "Quality: means over the benchmark's models at each noise level (denoising: "
               "noise along the normals), each baseline at its best grid setting per case.", ""]
    for fail in fig_failures:
        md.append(f"- picture **FAILED**: {fail}")
    if fig_failures:
        md.append("")
    section("Interactive 3-D views")
    md.append("The HTML version of this page (index.html) shows every comparison above in a "
              "3-D viewer: drag to rotate all panels of a comparison together, scroll to "
              "zoom.")
    md.append("")
    md.append(VIEWER_MARK)
    md.append("")
    section("Detailed reports")
    md.append("| report | status | time (s) |")
    md.append("|---|---|---|")
    for s in steps:
        status = (s["status"] if s["status"] in ("ok", "no benchmark")
                  else f"**FAILED**: {s['error']}")
        link = f"[{s['name']}]({pages[s['name']]})" if s["name"] in pages else s["name"]
        md.append(f"| {link} | {status} | {s['seconds']:.1f} |")
    md.append("")
    if "thesis" in pages:
        md.append("The thesis' own published numbers (its data, its MATLAB code), for "
                  f"orientation: [thesis tables]({pages['thesis']}).")
        md.append("")
    section("Machine and library versions")
    md.append("Rerunning with the same mode and seed reproduces every quality number; times "
              "and memory vary with machine load.")
    md.append("")
    for k, v in env.items():
        md.append(f"- {k}: {v}")
    md.append("")
    return md, sections


#: where the index's HTML version puts the 3-D viewers (a paragraph of its own)
VIEWER_MARK = "PCPREP-VIEWERS-HERE"


def index_html(md: str, sections: list[tuple[str, str]], viewers: list[tuple[str, dict]]
               ) -> str:
    """The index page: the Markdown rendered (escaped, see ``markdown_to_html``),
    headings given anchors, a table of contents, and the 3-D viewers."""
    from . import viewer

    page = markdown_to_html(md, title="pcprep comparison report",
                            head=viewer.style())
    for anchor, title in sections:
        page = page.replace(f"<h2>{html.escape(title)}</h2>",
                            f"<h2 id='{anchor}'>{html.escape(title)}</h2>", 1)
    toc = "<nav class='toc'><strong>Contents</strong><ol>" + "".join(
        f"<li><a href='#{a}'>{html.escape(t)}</a></li>" for a, t in sections) + "</ol></nav>"
    page = page.replace("</h1>", "</h1>\n" + toc, 1)
    blocks = []
    for ident, scene in viewers:
        blocks.append(f"<h3>{html.escape(scene.get('title', ''))}</h3>"
                      + viewer.block(scene, ident))
    body = "".join(blocks) if blocks else "<p>No comparison was rendered.</p>"
    page = page.replace(f"<p>{VIEWER_MARK}</p>", body + viewer.script(), 1)
    return page


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
1.4em}nav.toc{background:#f7f7f7;border:1px solid #ddd;padding:.5em 1em;display:inline-block}
nav.toc ol{margin:.3em 0}body{max-width:1500px}img{display:block;margin:.5em 0}"""


def markdown_to_html(md: str, title: str = "report", head: str = "") -> str:
    """Render Markdown as a standalone HTML page that opens offline; relative
    links to a report's ``.md`` point to its ``.html`` page.  ``head`` is
    trusted markup (the viewer's style) put in the page's head."""
    from markdown_it import MarkdownIt

    body = MarkdownIt("commonmark", {"html": False}).enable("table").render(md)
    body = re.sub(r'href="([\w./-]+)\.md"', r'href="\1.html"', body)
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            f"</title><style>{_CSS}</style>{head}</head><body>\n{body}</body></html>")
