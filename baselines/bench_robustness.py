"""
bench_robustness.py
-------------------
``pcprep bench robustness``: bad and odd input tried against the readers, every
registered filter and the command line, and each outcome classified.  A case
passes when it ends in a whole result (every row, finite values, nothing moved
that should not be) or in one of pcprep's own errors; it fails when the answer
is silently wrong (a row dropped or altered, a non-finite output), when another
exception escapes, or when a refused output leaves a file behind.

The cases are generated from a fixed seed, so anyone re-running the command gets
the same table; the property-based tests (tests/test_fuzz.py) draw further cases
of the same kinds.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
import time
from collections import Counter

import numpy as np

from pcprep.filters._validation import InvalidParameterError, PointCloudError
from pcprep.meshlab_bridge import formats, registry
from pcprep.meshlab_bridge.cloud import Cloud

from . import harness

CLEAN = (PointCloudError, InvalidParameterError)
OUTCOMES = ("whole", "refused", "wrong", "crashed")


# --- files ---------------------------------------------------------------------------

def _text_cases(g):
    """(name, extension, content, expected points or None) for corrupt text files."""
    good = g.normal(size=(6, 3))
    rows = [" ".join(repr(float(v)) for v in r) for r in good]
    bad_rows = {
        "nan row": rows[:2] + ["nan nan nan"] + rows[3:],
        "inf row": rows[:3] + ["inf 0 0"] + rows[4:],
        "word row": rows[:1] + ["abc def ghi"] + rows[2:],
        "short row": rows[:4] + ["1 2"] + rows[5:],
    }
    out = []
    for ext in (".xyz", ".obj", ".off", ".ply", ".pcd"):
        out.append(("intact", ext, _wrap(ext, rows, 6), good))
        for name, body in bad_rows.items():
            out.append((name, ext, _wrap(ext, body, 6), None))
        if ext in (".off", ".ply", ".pcd"):
            out.append(("header declares fewer", ext, _wrap(ext, rows, 4), None))
            out.append(("header declares more", ext, _wrap(ext, rows, 8), None))
        out.append(("empty file", ext, "", None))
    return out


def _wrap(ext, rows, declared):
    body = "\n".join(rows) + "\n"
    if ext == ".xyz":
        return body
    if ext == ".obj":
        return "".join(f"v {r}\n" for r in rows)
    if ext == ".off":
        return f"OFF\n{declared} 0 0\n{body}"
    if ext == ".ply":
        return ("ply\nformat ascii 1.0\nelement vertex "
                f"{declared}\nproperty double x\nproperty double y\nproperty double z\n"
                f"end_header\n{body}")
    return ("VERSION 0.7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {declared}\nHEIGHT 1\nPOINTS {declared}\nDATA ascii\n{body}")


def _binary_cases(g, folder):
    """Truncated and padded binary PLY and LAS files (expected None) and intact ones."""
    pts = g.normal(size=(50, 3)) + [4.5e5, 5.2e6, 100.0]
    out = []
    for ext in (".ply", ".las", ".laz", ".pcd"):
        path = os.path.join(folder, f"good{ext}")
        formats.write_cloud(Cloud(pts), path)
        data = open(path, "rb").read()
        exact = ext in (".ply", ".pcd")
        out.append(("intact", ext, data, pts if exact else "las"))
        for cut, what in ((1, "1 byte"), (13, "13 bytes"), (len(data) // 2, "half")):
            out.append((f"truncated by {what}", ext, data[:-cut], None))
        out.append(("padded with 24 bytes", ext, data + bytes(24), None if exact else "any"))
    return out


def _classify_read(path, expected):
    try:
        cloud = formats.read_cloud(path)
    except CLEAN:
        return "refused" if expected is None or isinstance(expected, str) and expected == "any" \
            else "wrong"
    except Exception:  # noqa: BLE001 -- the point of the bench
        return "crashed"
    if isinstance(expected, str):  # LAS: quantised coordinates, check count only
        return "whole" if len(cloud) == 50 else "wrong"
    if expected is None:
        return "wrong"
    return "whole" if np.array_equal(cloud.points, expected) else "wrong"


def _files(seed):
    g = np.random.default_rng(seed)
    tally: dict[str, Counter] = {}
    with tempfile.TemporaryDirectory() as folder:
        cases = [(n, e, c.encode(), x) for n, e, c, x in _text_cases(g)]
        cases += _binary_cases(g, folder)
        for name, ext, content, expected in cases:
            path = os.path.join(folder, f"case{ext}")
            with open(path, "wb") as f:
                f.write(content)
            tally.setdefault(f"files: {name}", Counter())[_classify_read(path, expected)] += 1
    return tally


# --- clouds and parameters -----------------------------------------------------------

def odd_cloud(kind, n, scale, offset, g):
    """An odd cloud of ``n`` points: "sphere", "plane", "line", "clusters",
    "far outlier" or "duplicates", scaled and moved; ``g`` a NumPy Generator."""
    if kind == "sphere":
        p = g.normal(size=(n, 3))
        p /= np.linalg.norm(p, axis=1)[:, None]
    elif kind == "plane":
        p = np.c_[g.uniform(size=(n, 2)), np.zeros(n)]
    elif kind == "line":
        p = np.outer(g.uniform(size=n), [1.0, 2.0, 3.0])
    elif kind == "clusters":
        p = np.repeat(g.normal(size=(4, 3)) * 10, n // 4 + 1, axis=0)[:n]
        p = p + 1e-3 * g.normal(size=p.shape)
    elif kind == "far outlier":
        p = g.normal(size=(n, 3))
        p /= np.linalg.norm(p, axis=1)[:, None]
        p[-1] = [1e9, 0.0, 0.0]
    else:  # duplicates
        p = g.normal(size=(n, 3))
        p[n // 2:] = p[: n - n // 2]
    return p * scale + offset


def _classify_call(spec, pts, kw):
    before = pts.copy()
    try:
        res = spec.func(pts, **kw)
    except CLEAN:
        return "refused"
    except Exception:  # noqa: BLE001
        return "crashed"
    if not np.array_equal(pts, before):
        return "wrong"
    n = len(pts)
    for field in (spec.points_field if spec.kind == "coord" else None, spec.mask_field,
                  spec.scalar_field):
        if field:
            arr = np.asarray(getattr(res, field))
            if len(arr) != n or (arr.dtype != bool and not np.isfinite(arr).all()):
                return "wrong"
    if spec.index_field:
        idx = np.asarray(getattr(res, spec.index_field))
        if len(np.unique(idx)) != len(idx) or (idx < 0).any() or (idx >= n).any():
            return "wrong"
    return "whole"


def _clouds(seed, quick):
    g = np.random.default_rng(seed)
    kinds = ("sphere", "plane", "line", "clusters", "duplicates", "far outlier")
    sizes = (3, 60, 600) if quick else (3, 12, 60, 600, 3000)
    tally: dict[str, Counter] = {}
    for spec in sorted(registry.load_all().values(), key=lambda s: s.command):
        key = f"odd clouds: {spec.command}"
        for kind in kinds:
            for n in sizes:
                for scale, offset in ((1.0, 0.0), (1e-6, 0.0), (1e6, 5e6)):
                    pts = odd_cloud(kind, n, scale, offset, g)
                    tally.setdefault(key, Counter())[
                        _classify_call(spec, pts, dict(spec.example))] += 1
    return tally


_ODD = (None, True, "3", float("nan"), float("inf"), -1e300, 1e-300, 0, -1, 10**12, 2.5)


def _parameters(seed):
    g = np.random.default_rng(seed)
    pts = odd_cloud("sphere", 400, 1.0, 0.0, g)
    tally: dict[str, Counter] = {}
    for spec in sorted(registry.load_all().values(), key=lambda s: s.command):
        key = f"odd parameters: {spec.command}"
        for p in spec.params:
            values = list(_ODD)
            if p.low is not None:
                values.append(p.low)
            if p.high is not None:
                values.append(p.high)
            for v in values:
                kw = {**spec.example, p.name: v}
                try:
                    spec.resolve(kw)
                except InvalidParameterError as exc:
                    out = "refused" if p.name in str(exc) else "wrong"
                else:
                    out = _classify_call(spec, pts, kw)
                tally.setdefault(key, Counter())[out] += 1
    return tally


# --- the command line ----------------------------------------------------------------

def _destinations():
    from pcprep.meshlab_bridge.cli import main

    tally: dict[str, Counter] = {}
    with tempfile.TemporaryDirectory() as folder:
        src = os.path.join(folder, "in.ply")
        g = np.random.default_rng(0)
        p = g.normal(size=(500, 3))
        formats.write_cloud(Cloud(p / np.linalg.norm(p, axis=1)[:, None]), src)
        outs = [os.path.join(folder, f"out{e}") for e in
                (".stl", ".dxf", ".u3d", ".wrl", "", ".e57x")]
        outs += [os.path.join(folder, "missing", "o.ply"), folder]
        for dst in outs:
            before = set(os.listdir(folder))
            try:
                with contextlib.redirect_stderr(io.StringIO()):  # the expected refusals
                    code = main(["saliency", src, dst, "--quiet"])
                out = "refused" if code == 1 else "wrong"
            except SystemExit as exc:
                out = "refused" if exc.code else "wrong"
            except Exception:  # noqa: BLE001
                out = "crashed"
            if set(os.listdir(folder)) != before:
                out = "wrong"  # a refused output must leave nothing behind
            tally.setdefault("command line: unusable destinations", Counter())[out] += 1
    return tally


def run(quick: bool = False, seed: int = 0, out_dir: str = "reports") -> dict:
    """Run every case and write ``robustness.md`` / ``robustness.json``."""
    t0 = time.perf_counter()
    tally = {}
    for part in (_files(seed), _clouds(seed, quick), _parameters(seed), _destinations()):
        tally.update(part)
    rows = ["| cases | tried | " + " | ".join(OUTCOMES) + " |", "|---|---|---|---|---|---|"]
    total = Counter()
    for key, counts in tally.items():
        total.update(counts)
        rows.append(f"| {key} | {sum(counts.values())} | "
                    + " | ".join(str(counts.get(o, 0)) for o in OUTCOMES) + " |")
    rows.append(f"| **all** | **{sum(total.values())}** | "
                + " | ".join(f"**{total.get(o, 0)}**" for o in OUTCOMES) + " |")
    md = ["# Robustness: bad and odd input", "",
          f"{'Quick' if quick else 'Full'} run, seed {seed}, "
          f"{time.perf_counter() - t0:.0f} s.  Each case ends *whole* (every row, finite "
          "values, the input untouched), *refused* (pcprep's own error naming the problem), "
          "*wrong* (a silently wrong answer, or a refused output that left a file) or "
          "*crashed* (another exception).  Re-run with `pcprep bench robustness`.", "",
          *rows, ""]
    data = {"quick": quick, "seed": seed, "cases": {k: dict(v) for k, v in tally.items()},
            "total": dict(total)}
    harness.write_report("robustness", "\n".join(md), data, out_dir=out_dir)
    return data


def run_speed(quick: bool = False, seed: int = 0, out_dir: str = "reports") -> dict:
    """The robustness bench has no speed part; run the cases."""
    return run(quick=quick, seed=seed, out_dir=out_dir)
