"""Structure of `pcprep report` on a tiny run: every harness appears, a failed
harness is shown as failed (never silently missing), pictures are linked, and
the HTML rendering holds the same tables."""

import types
from pathlib import Path

import numpy as np

from pcprep.baselines import figures, report
from pcprep.baselines.harness import markdown_table, write_report
from helpers import sphere_points


def _fake_bench(family, fail=False):
    def run(quick=False, seed=0, out_dir="reports"):
        if fail:
            raise RuntimeError("baseline exploded")
        table = markdown_table(["model", "ours", "baseline"], [["cube", 1.0 + seed, 2.0]],
                               best={1: "min", 2: "min"})
        write_report(family, f"# {family}\n\n{table}", {"quick": quick}, out_dir=out_dir)

    def run_speed(quick=False, seed=0, out_dir="reports"):
        write_report(f"speed_{family}", f"# speed {family}\n\n| n | s |\n|---|---|\n| 10 | 1 |\n",
                     {}, out_dir=out_dir)

    return types.SimpleNamespace(run=run, run_speed=run_speed)


def test_tiny_report_structure(tmp_path, monkeypatch):
    benches = {f"pcprep.baselines.bench_{f}": _fake_bench(f, fail=(f == "simplify"))
               for f in (*report.FAMILIES, *report.EXTRA)}
    real_import = report.import_module
    monkeypatch.setattr(report, "import_module",
                        lambda name: benches[name] if name in benches else real_import(name))

    def tiny_figures(img, seed=0):
        p = sphere_points(300)
        path = figures.panels(Path(img) / "tiny.png", [("a", p, p[:, 2]), ("b", p, None)])
        return [("tiny picture", path)], ["detection_figures: ValueError: no data"]

    monkeypatch.setattr(figures, "build_all", tiny_figures)
    md_path = report.build(quick=True, seed=0, out_dir=str(tmp_path))
    text = md_path.read_text()
    for family in report.FAMILIES:
        assert f"## {report.TITLES[family]}" in text
    assert "| [denoise](denoise.md) | ok |" in text
    assert "**simplify FAILED**: RuntimeError: baseline exploded" in text
    assert "| simplify | **FAILED**: RuntimeError: baseline exploded |" in text
    assert "| cube | **1** | 2 |" in text  # sub-report tables are embedded, best in bold
    assert "![tiny picture](img/tiny.png)" in text and (tmp_path / "img" / "tiny.png").exists()
    assert "picture **FAILED**: detection_figures" in text
    assert "## Machine and library versions" in text and "numpy" in text
    html = (tmp_path / "index.html").read_text()
    separators = [ln for ln in text.splitlines() if ln.startswith("|---")]
    assert html.count("<table>") == len(separators) >= 10
    assert '<img src="img/tiny.png" alt="tiny picture"' in html
    assert (tmp_path / "index.json").exists()


def test_markdown_to_html_escapes_and_keeps_structure():
    html = report.markdown_to_html("# A <b>\n\n| x | y |\n|---|---|\n| 1 | **2** |\n\n- one\n")
    assert "<h1>A &lt;b&gt;</h1>" in html
    assert "<td><strong>2</strong></td>" in html and "<li>one</li>" in html


def test_markdown_to_html_lets_no_script_through():
    """Names and paths in a report come from users' files: raw HTML, attribute
    quotes and script URLs must not become live markup."""
    html = report.markdown_to_html(
        '![x" onerror="alert(1)](a.png)\n\n[click](javascript:alert(1))\n\n'
        '<script>alert(1)</script>\n\n<img src=x onerror=alert(1)>\n\n'
        '[ok](denoise.html)\n')
    body = html.split("<body>", 1)[1]
    assert "<script" not in body and "<img src=x" not in body
    assert 'onerror="alert' not in body and "javascript:" not in body.replace(
        "[click](javascript:alert(1))", "")
    assert '<a href="denoise.html">ok</a>' in body
    assert '<img src="a.png" alt="x&quot; onerror=&quot;alert(1)"' in body


def test_panels_write_small_pictures(tmp_path):
    p = sphere_points(20000)
    path = figures.panels(tmp_path / "p.png", [("x", p, np.abs(p[:, 0]))] * 3, colorbar="v")
    assert path.exists() and path.stat().st_size < 200_000
