"""`pcprep report` on a tiny run: the summary opens the index and is computed
from the harness JSON (held-out beside tuning), a failed harness is shown as
failed, pictures and per-harness HTML pages are linked, the HTML escapes what
it embeds; the renderer draws what it is given (known answers), the plots and
the viewer's payload carry the numbers they were given."""

import base64
import json
import types
from pathlib import Path

import numpy as np
import pytest

from pcprep.baselines import figures, plots, render, report, summary, viewer
from pcprep.baselines.harness import markdown_table, write_report
from helpers import sphere_points


def _denoise_json(splits=None):
    """Four cases: ours 5 / 6.5 / 7 / 4 deg against a best baseline of 6 deg each."""
    cases = []
    for i, ours in enumerate((5.0, 6.5, 7.0, 4.0)):
        c = {"model": f"m{i}", "condition": "normal 0.1h", "kind": "normal", "sigma_h": 0.1,
             "uniform": True, "noisy": {"mad_own": 9.0, "snr": 30.0},
             "methods": {"ours": {"best": {"mad_own": {"value": ours},
                                           "snr": {"value": 40.0}}},
                         "APSS": {"best": {"mad_own": {"value": 6.0}, "snr": {"value": 41.0}}},
                         "jet": {"best": {"mad_own": {"value": None},
                                          "snr": {"value": 39.0}}}}}
        if splits is not None:
            c["split"] = splits[i]
        cases.append(c)
    return {"cases": cases, "notes": "Where ours loses, and why. Because of m1."}


def _fake_bench(family, fail=False):
    def run(quick=False, seed=0, out_dir="reports"):
        if fail:
            raise RuntimeError("baseline exploded")
        table = markdown_table(["model", "ours", "baseline"], [["cube", 1.0 + seed, 2.0]],
                               best={1: "min", 2: "min"})
        data = _denoise_json(["tuning", "tuning", "held-out", "held-out"]) \
            if family == "denoise" else {"quick": quick}
        write_report(family, f"# {family}\n\nSee [the speed page](speed_{family}.md).\n\n"
                     f"{table}", data, out_dir=out_dir)

    def run_speed(quick=False, seed=0, out_dir="reports"):
        data = {"records": [{"n": 1000, "ours": {"ok": True, "seconds": 2.0},
                             "jet": {"ok": True, "seconds": 1.0},
                             "knn16": {"ok": True, "seconds": 0.5}}]}
        write_report(f"speed_{family}", f"# speed {family}\n\n| n | s |\n|---|---|\n| 10 | 1 |\n",
                     data, out_dir=out_dir)

    return types.SimpleNamespace(run=run, run_speed=run_speed)


def tiny_build_all(img, seed=0, quick=True):
    """One real composed picture and its scene (a 300-point sphere)."""
    p = sphere_points(300)
    cam = render.Camera.fit(p, figures.PANEL_W, figures.PANEL_H)
    col = render.scalar_colours(p[:, 2], "viridis", -1, 1)
    path = figures.compose(Path(img) / "tiny.png",
                           [figures.Panel("a", p, p, col, 0.12), figures.Panel("b", p, p, None, 0.12)],
                           cam, ncols=2, colorbar=("viridis", -1, 1, "height (× h)"),
                           legend=[("thing", (1, 0, 0))])
    sc = figures.scene("tiny <scene>", [("a</script>", p, col), ("b", p, col)], 0.1)
    return ([figures.Figure("denoise", "tiny picture", path, "A caption.", sc)],
            ["detection_figures: ValueError: no data"])


@pytest.fixture
def tiny_report(tmp_path, monkeypatch):
    benches = {f"pcprep.baselines.bench_{f}": _fake_bench(f, fail=(f == "simplify"))
               for f in (*report.FAMILIES, *report.EXTRA)}
    real_import = report.import_module
    monkeypatch.setattr(report, "import_module",
                        lambda name: benches[name] if name in benches else real_import(name))
    monkeypatch.setattr(figures, "build_all", tiny_build_all)
    md_path = report.build(quick=True, seed=0, out_dir=str(tmp_path))
    return tmp_path, md_path.read_text()


def test_tiny_report_structure(tiny_report):
    out, text = tiny_report
    # the summary comes first, the machine last
    order = [text.index(h) for h in ("## Summary", "## Pictures", "## Interactive 3-D views",
                                     "## Detailed reports", "## Machine and library versions")]
    assert order == sorted(order)
    assert "| [denoise](denoise.html) | ok |" in text
    assert "| simplify | **FAILED**: RuntimeError: baseline exploded |" in text
    assert "[![tiny picture](img/tiny.png)](img/tiny.png)" in text
    assert (out / "img" / "tiny.png").exists()
    assert "picture **FAILED**: detection_figures" in text
    assert "numpy" in text.split("## Machine and library versions")[1]
    # every harness report has its HTML page, whose links point to HTML pages
    page = (out / "denoise.html").read_text()
    assert '<a href="speed_denoise.html">' in page and "<td><strong>1</strong></td>" in page
    assert (out / "speed_denoise.html").exists() and not (out / "simplify.html").exists()
    html = (out / "index.html").read_text()
    assert '<a href="denoise.html">denoise</a>' in html and ".md\"" not in html
    assert "<nav class='toc'>" in html and "<h2 id='summary'>Summary</h2>" in html
    assert html.count("class='pcv'") == 1 and "new Float32Array" in html
    # embedded labels cannot close the script element they sit in
    assert "a</script>" not in html and "a\\u003c/script\\u003e" in html
    assert '<img src="img/tiny.png" alt="tiny picture"' in html
    assert "PCPREP-VIEWERS-HERE" not in html
    data = json.loads((out / "index.json").read_text())
    assert data["summary"][0]["filter"] == "denoise"


def test_summary_puts_held_out_beside_tuning(tiny_report):
    _, text = tiny_report
    row = next(ln for ln in text.splitlines() if ln.startswith("| denoise |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    # held-out: ours 7 vs 6 (loss), 4 vs 6 (win); tuning: 5 vs 6 (win), 6.5 vs 6 (loss)
    assert cells[2] == "1 wins / 1 losses of 2; mean 5.5 vs 6"
    assert cells[3] == "1 wins / 1 losses of 2; mean 5.75 vs 6"
    assert "2.0× the time of the fastest peer (CGAL jet), 4.0× one k-NN pass at 1,000 points" \
        in cells[4]
    assert cells[5].startswith("Mixed: better in 1 of 2 held-out cases")
    assert "Why, in the harness' words: Because of m1." in text


def test_summary_without_split_says_no_held_out_cases(tmp_path):
    (tmp_path / "denoise.json").write_text(json.dumps(_denoise_json()))
    rows = summary.headlines(tmp_path, quick=False)
    assert [h.filter for h in rows] == ["denoise"]
    md = summary.markdown(rows)
    assert "| no held-out cases yet | 2 wins / 2 losses of 4; mean 5.62 vs 6 |" in md
    assert "Mixed: better in 2 of 4 tuning cases" in md
    # the losing model is named with the baseline that beat it
    assert "m1 (1 of 1; beaten by APSS)" in md
    t = rows[0].tally(rows[0].cases)
    assert (t["wins"], t["losses"], t["ties"]) == (2, 2, 0)


def test_summary_of_higher_is_better_and_relative_metrics():
    feat = {"sharp": [{"data": "cube", "noise": 0.0, "results": {
        "ours": {"f1": 0.9}, "ours_raw": {"f1": 0.99}, "a": {"f1": 0.8}, "b": {"f1": 0.95}}}]}
    cases = summary.sharp_cases(feat)
    assert len(cases) == 1 and cases[0].best == 0.95 and cases[0].best_name == "b"
    simp = {"cases": [{"model": "x", "rate": 0.1, "methods": {
        "SDBS": {"davg": 2.0}, "Poisson-disk": {"davg": 4.0},
        "CGAL grid": {"davg": 1.0, "outcome": {"ok": False}},
        "MeshLab simplified": {"davg": 0.1}}}]}
    h = summary.Headline("s", "d", True, summary.simplify_cases(simp), relative=True)
    assert h.cases[0].best_name == "Poisson-disk"  # a failed run and MeshLab's count-less one skip
    assert h.tally(h.cases)["ratio_geomean"] == pytest.approx(0.5)


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


# ---------------------------------------------------------------------------------------
# the renderer


def _cam(size=64):
    return render.Camera(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                         np.array([0, 0, 1.0]), 1.0, size, size)


def test_a_splat_covers_its_disc_and_nothing_else():
    cam = _cam(64)  # 2 world units over 64 px: 1 px = 1/32
    img = render.render_points(cam, [[0.0, 0.0, 0.0]], [[0, 0, 1.0]], (1.0, 0.0, 0.0),
                               radius=10 / 32, supersample=1)
    yy, xx = np.mgrid[0:64, 0:64]
    r = np.hypot(xx + 0.5 - 32, yy + 0.5 - 32)
    red = (img[..., 0] > 0.5) & (img[..., 1] < 0.3)
    assert red[r < 9].all() and not red[r > 11].any()
    assert (img[r > 11] == 1.0).all()  # background untouched


def test_the_nearer_point_wins_and_light_falls_on_the_lit_side():
    cam = _cam(32)
    pts = [[0, 0, -0.5], [0, 0, 0.5]]  # the second is nearer (z towards the viewer)
    img = render.render_points(cam, pts, [[0, 0, 1.0]] * 2, np.array([[1, 0, 0], [0, 0, 1.0]]),
                               radius=0.3, supersample=1)
    assert img[16, 16, 2] > 0.5 and img[16, 16, 0] < 0.3
    key = render._KEY / np.linalg.norm(render._KEY)
    lit = render.render_points(cam, [[0, 0, 0]], [key], (0.8, 0.8, 0.8), 0.3, 1)[16, 16, 0]
    grazing = render.render_points(cam, [[0, 0, 0]], [[key[1], -key[0], 0]], (0.8, 0.8, 0.8),
                                   0.3, 1)[16, 16, 0]
    assert lit > grazing + 0.2


def test_a_triangle_covers_its_area():
    cam = _cam(200)
    V = np.array([[-0.8, -0.8, 0], [0.8, -0.8, 0], [-0.8, 0.8, 0]])
    c = render.Canvas(cam, 1).mesh(V, [[0, 1, 2]])
    # area 1.28 of the 4 world units the image spans
    assert c.coverage == pytest.approx(1.28 / 4, rel=0.03)


def test_one_camera_frames_every_cloud_the_same_way():
    p = sphere_points(500) * 3 + 7
    cam = render.Camera.fit(p, 300, 200, elev=20, azim=30)
    x, y, _ = cam.project(p)
    assert x.min() >= 0 and x.max() <= 300 and y.min() >= 0 and y.max() <= 200
    assert max(x.max() - x.min(), (y.max() - y.min()) * 1.5) > 0.85 * 300  # fills the frame
    q = p[::-1].copy()
    assert np.allclose(np.sort(cam.project(q)[0]), np.sort(x))


def test_gaps_between_splats_show_the_front_surface():
    """A sparse front plane over a dense red back plane: after gap filling the
    back shows through far less than before."""
    rng = np.random.default_rng(0)
    front = np.c_[rng.uniform(-1, 1, (400, 2)), np.full(400, 0.5)]
    back = np.c_[rng.uniform(-1, 1, (4000, 2)), np.full(4000, -0.5)]
    cam = _cam(200)
    col = np.r_[np.tile([0.2, 0.2, 0.9], (400, 1)), np.tile([0.9, 0.1, 0.1], (4000, 1))]

    def red_share(outline):
        c = render.Canvas(cam, 1).points(np.r_[front, back], np.tile([0, 0, 1.0], (4400, 1)),
                                         col, radius=0.06)
        img = c.image(outline)[30:170, 30:170]
        return float(((img[..., 0] > 0.4) & (img[..., 2] < 0.3)).mean())

    assert red_share(None) > 0.05 and red_share(0.3) < 0.3 * red_share(None)


def test_composed_pictures_are_wide_with_colour_bar_and_legend(tmp_path):
    from PIL import Image

    p = sphere_points(2000)
    cam = render.Camera.fit(p, figures.PANEL_W, figures.PANEL_H)
    panels = [figures.Panel(t, p, p, None, 0.08) for t in "abc"] + [figures.Panel("d", failed="x")]
    path = figures.compose(tmp_path / "c.png", panels, cam, ncols=4, title="T",
                           colorbar=("magma", 0, 1, "error (× h)"),
                           legend=[("true positive", (1, 0, 0))], inset=(p[0], 0.3))
    with Image.open(path) as im:
        a = np.asarray(im.convert("RGB"))
    assert a.shape[1] == 4 * figures.PANEL_W >= 1600
    panel = a[60:60 + figures.PANEL_H, :figures.PANEL_W]
    assert (panel.min(axis=2) < 200).mean() > 0.15  # the sphere is drawn, not blank
    assert path.stat().st_size < 1_500_000


# ---------------------------------------------------------------------------------------
# plots and the viewer's payload


def test_speed_series_reads_outcomes_and_knn():
    data = {"records": [{"n": 10, "ours": {"ok": True, "seconds": 1.0},
                         "rimls": {"ok": False, "seconds": 9.0}, "knn16": {"seconds": 0.1},
                         "ratios": {"x": 1}},
                        {"n": 100, "ours": {"ok": True, "seconds": 5.0}}]}
    s = plots.speed_series(data)
    assert s == {"ours": [(10, 1.0), (100, 5.0)], "knn16": [(10, 0.1)]}
    rows = {"rows": [{"n": 10, "seconds": 2.0, "knn_seconds": 0.5, "outcome": {"seconds": 2.1}}]}
    assert plots.speed_series(rows) == {"seconds": [(10, 2.1)], "knn_seconds": [(10, 0.5)]}


def test_quality_curves_average_over_models(tmp_path):
    den = _denoise_json()
    curves = plots.denoise_curves(den, "mad_own")
    assert curves["ours"] == [(0.1, pytest.approx(5.625))]
    assert curves["APSS"] == [(0.1, 6.0)] and "jet" not in curves
    (tmp_path / "denoise.json").write_text(json.dumps(den))
    path = plots.quality_plot(tmp_path, tmp_path, quick=False)
    assert path.exists() and path.stat().st_size > 10_000


def test_viewer_payload_round_trips_the_points():
    p = sphere_points(50) * 2 + 3
    col = np.tile([0.0, 0.5, 1.0], (50, 1))
    sc = figures.scene("s", [("x", p, col)], 0.1, up_axis=1)
    pay = viewer.payload(sc)
    c = pay["clouds"][0]
    V = np.frombuffer(base64.b64decode(c["positions"]), dtype="<f4").reshape(-1, 3)
    lo, hi = p.min(axis=0), p.max(axis=0)
    expect = (p - 0.5 * (lo + hi)) / (0.5 * np.max(hi - lo))
    assert np.allclose(V, expect, atol=1e-6) and np.abs(V).max() <= 1.0 + 1e-6
    rgb = np.frombuffer(base64.b64decode(c["colours"]), dtype=np.uint8).reshape(-1, 3)
    assert (rgb == [0, 128, 255]).all()
    many = figures.scene("s", [("x", sphere_points(20000), np.zeros((20000, 3)))], 0.1)
    assert viewer.payload(many, max_points=1000)["clouds"][0]["n"] == 1000
