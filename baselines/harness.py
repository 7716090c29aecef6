"""
harness.py
----------
Crash-isolated benchmark harness: run one function per fresh process (so a
segfault in pymeshlab or CGAL becomes a recorded failure), time it, record its
peak memory, and write Markdown + JSON reports.

Typical use in a bench module::

    from pcprep.baselines import harness, meshlab
    out = harness.measure(meshlab.rimls, points, normals)      # Outcome
    if out.ok:
        smoothed, _ = out.value
    yard = harness.knn_pass_seconds(points)                     # float seconds
    table = harness.markdown_table(["n", "ours", "RIMLS"], rows,
                                   best={1: "min", 2: "min"})
    harness.write_report("denoise_speed", table,
                         {"rows": rows, "env": harness.environment_info()})

The function given to :func:`run_isolated` must be importable by the child
(defined at module level of an importable module, or in the ``__main__``
script guarded by ``if __name__ == "__main__":``); its arguments and return
value must be picklable.  NumPy arrays go through a temporary file with pickle
protocol 5, so the data are written and read once, without intermediate copies
(a 1M x 3 float64 array costs ~24 MB and a few ms each way).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import multiprocessing as mp
import os
import pickle
import platform
import resource
import shutil
import signal
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from pcprep.meshlab_bridge.convert import file_mode

log = logging.getLogger("pcprep")

#: default time limit of :func:`run_isolated`, seconds
DEFAULT_TIMEOUT = 600.0
#: default time limit of :func:`measure`, seconds (MeshLab MLS at 1M takes ~7 min)
MEASURE_TIMEOUT = 1800.0

_PICKLE_PROTOCOL = 5


@dataclass(frozen=True)
class Outcome:
    """Result of one isolated call.

    Attributes
    ----------
    ok : bool
        True when the function returned normally.
    value : Any
        Its return value (None on failure).
    error : str or None
        ``"<ExceptionType>: <message>"``, ``"crashed: signal 11 (SIGSEGV)"``,
        ``"timeout after 600s"``, ``"exited with code N"``; None when ok.
    seconds : float
        Wall time of the function call alone, measured inside the child with
        ``time.perf_counter`` (interpreter start, imports of the function's
        module and argument loading excluded).  NaN when the call did not finish.
    peak_mb : float
        Peak resident memory of the child process in MiB (``VmHWM`` of
        /proc/self/status, falling back to ``getrusage(RUSAGE_SELF).ru_maxrss``).
        It INCLUDES the Python interpreter, every imported library and the
        unpickled arguments (about 30-100 MB before any work); compare with
        ``start_mb``.  NaN when unknown (crash, timeout).  ``VmHWM`` is used
        because on Linux ``ru_maxrss`` of a spawned child starts at the
        PARENT's RSS (kept across fork + exec): with a 1.2 GB parent a 30 MB
        child reported 1.2 GB.
    start_mb : float
        Resident memory of the child just before the call (interpreter, imports
        of the function's module, arguments loaded); ``peak_mb - start_mb`` is
        a lower bound on the call's own working memory.
    """

    ok: bool
    value: Any
    error: str | None
    seconds: float
    peak_mb: float
    start_mb: float = math.nan

    def __str__(self) -> str:
        if self.ok:
            return f"ok ({self.seconds:.3g} s, {self.peak_mb:.0f} MB)"
        return str(self.error)

    def summary(self) -> dict:
        """JSON-friendly dict without the (possibly large) value."""
        return {"ok": self.ok, "error": self.error, "seconds": self.seconds,
                "peak_mb": self.peak_mb, "start_mb": self.start_mb}


# ----------------------------------------------------------------------------------------
# isolated execution
# ----------------------------------------------------------------------------------------

def _rss_mb(field: str) -> float:
    """``VmHWM`` / ``VmRSS`` of this process in MiB (NaN if /proc is unavailable)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


def _peak_mb() -> float:
    hwm = _rss_mb("VmHWM")
    if math.isnan(hwm):  # ru_maxrss is KiB on Linux, bytes on macOS
        ru = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        hwm = ru / (1024.0 * 1024.0) if sys.platform == "darwin" else ru / 1024.0
    return hwm


def _child_main(workdir: str) -> None:
    """Entry point of the child process: load the call, run it, store the outcome."""
    res_path = os.path.join(workdir, "result.pkl")
    try:
        with open(os.path.join(workdir, "call.pkl"), "rb") as f:
            fn, args, kwargs = pickle.load(f)
    except BaseException as exc:  # noqa: BLE001 - reported to the parent
        payload = ("err", f"{type(exc).__name__} while loading the call: {exc}",
                   traceback.format_exc(), math.nan, _peak_mb(), math.nan)
    else:
        start = _rss_mb("VmRSS")
        t0 = time.perf_counter()
        try:
            value = fn(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001
            dt = time.perf_counter() - t0
            payload = ("err", f"{type(exc).__name__}: {exc}", traceback.format_exc(),
                       dt, _peak_mb(), start)
        else:
            dt = time.perf_counter() - t0
            payload = ("ok", value, None, dt, _peak_mb(), start)
    tmp = res_path + ".tmp"
    try:
        with open(tmp, "wb") as f:
            pickle.dump(payload, f, protocol=_PICKLE_PROTOCOL)
    except BaseException as exc:  # noqa: BLE001 - e.g. an unpicklable return value
        with open(tmp, "wb") as f:
            pickle.dump(("err", f"{type(exc).__name__} while returning the result: {exc}",
                         traceback.format_exc(), payload[3], payload[4], payload[5]),
                        f, protocol=_PICKLE_PROTOCOL)
    os.replace(tmp, res_path)


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"SIG{signum}"


def run_isolated(fn: Callable, *args, timeout: float = DEFAULT_TIMEOUT,
                 **kwargs) -> Outcome:
    """Call ``fn(*args, **kwargs)`` in a fresh Python process and return its Outcome.

    Parameters
    ----------
    fn : callable
        A module-level function (picklable by reference).  Its module is
        imported in the child; nothing else of the parent's state is inherited
        (multiprocessing "spawn" context: a new interpreter).
    *args, **kwargs
        Arguments, pickled with protocol 5 through a temporary file.  The
        keyword ``timeout`` is reserved for the harness.
    timeout : float, default=600
        Seconds (wall time of the whole child, start-up included) after which
        the child is killed and the outcome is ``"timeout after Ns"``.

    Returns
    -------
    Outcome
        Never raises for failures of ``fn``: exceptions become
        ``ok=False, error="<Type>: <msg>"``, native crashes (negative exit code)
        ``error="crashed: signal 11 (SIGSEGV)"``.

    Notes
    -----
    The child's stdout/stderr go to the parent's.  Child processes started by
    ``fn`` itself are not killed on timeout.
    """
    name = getattr(fn, "__name__", repr(fn))
    workdir = tempfile.mkdtemp(prefix="pcprep_iso_")
    try:
        call_path = os.path.join(workdir, "call.pkl")
        with open(call_path, "wb") as f:
            pickle.dump((fn, args, kwargs), f, protocol=_PICKLE_PROTOCOL)
        ctx = mp.get_context("spawn")
        # not a daemon: the function may itself start processes (joblib, multiprocessing)
        proc = ctx.Process(target=_child_main, args=(workdir,), daemon=False,
                           name=f"pcprep-iso-{name}")
        proc.start()
        try:
            proc.join(timeout)
        except BaseException:  # e.g. KeyboardInterrupt: never leave the child behind
            proc.kill()
            proc.join(10.0)
            raise
        if proc.is_alive():
            proc.kill()
            proc.join(10.0)
            log.info("run_isolated: %s timed out after %gs", name, timeout)
            return Outcome(False, None, f"timeout after {timeout:g}s", math.nan, math.nan)
        code = proc.exitcode
        res_path = os.path.join(workdir, "result.pkl")
        if code is not None and code < 0:
            err = f"crashed: signal {-code} ({_signal_name(-code)})"
            log.info("run_isolated: %s %s", name, err)
            return Outcome(False, None, err, math.nan, math.nan)
        if not os.path.exists(res_path):
            return Outcome(False, None, f"exited with code {code} without a result",
                           math.nan, math.nan)
        try:
            with open(res_path, "rb") as f:
                status, value, tb, dt, peak, start = pickle.load(f)
        except Exception as exc:  # noqa: BLE001 - e.g. class not importable
            err = f"{type(exc).__name__} while reading the result: {exc}"
            return Outcome(False, None, err, math.nan, math.nan)
        if status == "ok":
            return Outcome(True, value, None, float(dt), float(peak), float(start))
        log.info("run_isolated: %s failed: %s\n%s", name, value, tb)
        return Outcome(False, None, str(value), float(dt), float(peak), float(start))
    finally:
        shutil.rmtree(workdir, ignore_errors=True)


def measure(fn: Callable, *args, timeout: float = MEASURE_TIMEOUT, **kwargs) -> Outcome:
    """:func:`run_isolated` with the benchmark time limit (30 min by default).

    ``Outcome.seconds`` is the call's wall time measured in the child and
    ``Outcome.peak_mb`` the child's peak RSS (interpreter and imports included).
    """
    return run_isolated(fn, *args, timeout=timeout, **kwargs)


class Seconds(float):
    """A float (seconds, NaN on failure) that also carries its :class:`Outcome`.

    ``knn_pass_seconds(P)`` can be used as a number, and
    ``knn_pass_seconds(P).outcome`` / ``.peak_mb`` give the details.
    """

    outcome: Outcome

    def __new__(cls, outcome: Outcome):
        obj = super().__new__(cls, outcome.seconds if outcome.ok else math.nan)
        obj.outcome = outcome
        return obj

    def __reduce__(self):
        return (type(self), (self.outcome,))

    @property
    def seconds(self) -> float:
        return float(self)

    @property
    def peak_mb(self) -> float:
        return self.outcome.peak_mb

    @property
    def ok(self) -> bool:
        return self.outcome.ok


def _knn_pass(points: np.ndarray, k: int) -> int:
    """One cKDTree build + k-NN query of every point (the speed yardstick)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    _, idx = tree.query(points, k=k, workers=-1)
    return int(idx.shape[0])


def knn_pass_seconds(points, k: int = 16, *, timeout: float = MEASURE_TIMEOUT) -> Seconds:
    """Wall time of one scipy ``cKDTree`` build + ``k``-NN query of all points
    (``workers=-1``), measured in an isolated child like :func:`measure`.

    Reference costs on this 2-core machine: ~0.4 s at 100K points, ~6.6 s at 1M.
    The result is a ``float`` subclass; ``.outcome`` holds the full Outcome.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    return Seconds(run_isolated(_knn_pass, pts, k, timeout=timeout))


# ----------------------------------------------------------------------------------------
# tables and reports
# ----------------------------------------------------------------------------------------

_FAIL_WORDS = ("crash", "fail", "timeout", "error", "n/a", "skipped")


def _is_number(x) -> bool:
    return (isinstance(x, (int, float, np.integer, np.floating))
            and not isinstance(x, (bool, np.bool_)))


def _cell_value(cell):
    """(numeric value or None, is_failure) of a table cell."""
    if isinstance(cell, Outcome):
        if not cell.ok:
            return None, True
        cell = cell.value
    if _is_number(cell):
        v = float(cell)
        return (v if math.isfinite(v) else None), False
    return None, isinstance(cell, str) and cell.lower().startswith(_FAIL_WORDS)


def _md_escape(text: str, width: int = 80) -> str:
    text = " ".join(str(text).split())
    if len(text) > width:
        text = text[: width - 1] + "…"
    return text.replace("|", "\\|")


def _format_cell(cell, fmt: str) -> str:
    if isinstance(cell, Outcome):
        if not cell.ok:
            return _md_escape(cell.error or "failed")
        cell = cell.value
    if cell is None:
        return "n/a"
    if isinstance(cell, (bool, np.bool_)):
        return "yes" if cell else "no"
    if isinstance(cell, (int, np.integer)):
        return f"{int(cell):d}"
    if isinstance(cell, (float, np.floating)):
        v = float(cell)
        return "nan" if math.isnan(v) else fmt.format(v)
    return _md_escape(cell)


def markdown_table(header: list[str], rows: list[list],
                   best: dict[int, str] | None = None, fmt: str = "{:.3g}") -> str:
    """GitHub Markdown table with the best value of each row in bold.

    Parameters
    ----------
    header : list of str
        Column titles.
    rows : list of list
        Cells: numbers (floats formatted with ``fmt``, integers in full), strings,
        ``None`` (shown ``n/a``) or :class:`Outcome` (its value when ok, else its
        error, e.g. ``crashed: signal 11 (SIGSEGV)``).  Failures are never left blank.
    best : dict of int to {"min", "max"}, optional
        Columns that compete: in every row, the smallest (``"min"``) or largest
        (``"max"``) finite numeric value among the columns tagged with that
        direction is bolded (all ties bolded).  Thesis tables compare methods
        across columns, one data set / parameter per row.  Failed and
        non-numeric cells never win.
    fmt : str
        Format of float cells.

    Returns
    -------
    str
        The table, ending with a newline.
    """
    best = dict(best or {})
    for col, how in best.items():
        if how not in ("min", "max"):
            raise ValueError(
                f"markdown_table: best[{col}] must be 'min' or 'max', got {how!r}")
        if not 0 <= col < len(header):
            raise ValueError(
                f"markdown_table: best column {col} outside 0..{len(header) - 1}")
    lines = ["| " + " | ".join(_md_escape(h, 200) for h in header) + " |",
             "|" + "|".join("---" for _ in header) + "|"]
    for r, row in enumerate(rows):
        if len(row) != len(header):
            raise ValueError(
                f"markdown_table: row {r} has {len(row)} cells, header {len(header)}")
        texts = [_format_cell(c, fmt) for c in row]
        for how in ("min", "max"):
            cols = [c for c, h in best.items() if h == how]
            vals = {c: _cell_value(row[c])[0] for c in cols}
            vals = {c: v for c, v in vals.items() if v is not None}
            if not vals:
                continue
            target = min(vals.values()) if how == "min" else max(vals.values())
            for c, v in vals.items():
                if v == target:
                    texts[c] = f"**{texts[c]}**"
        lines.append("| " + " | ".join(texts) + " |")
    return "\n".join(lines) + "\n"


def to_jsonable(obj):
    """Recursively convert NumPy types, dataclasses (Outcome: value dropped if it
    is an array), paths, sets and tuples into plain JSON types; NaN/Inf -> None."""
    if isinstance(obj, Outcome):
        d = obj.summary()
        v = obj.value
        # keep small scalar results only: arrays, tuples and result records
        # (per-point masks, clouds) would bloat the report's JSON
        small = isinstance(v, (bool, int, float, str, np.number, type(None)))
        d["value"] = to_jsonable(v) if small else None
        return to_jsonable(d)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name))
                for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (str, type(None))):
        return obj
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)


def _atomic_write(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, file_mode())  # mkstemp creates 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def resolve_out_dir(out_dir: str | os.PathLike = "reports") -> Path:
    """Absolute output folder: a relative ``out_dir`` is taken from the current
    working directory (the installed package may live in site-packages, where
    reports must never be written)."""
    out = Path(out_dir)
    return out if out.is_absolute() else Path.cwd() / out


def write_report(name: str, markdown: str, data, out_dir: str | os.PathLike = "reports"
                 ) -> tuple[Path, Path]:
    """Write ``<out_dir>/<name>.md`` and ``<out_dir>/<name>.json`` atomically.

    A relative ``out_dir`` is resolved against the current working directory
    (see :func:`resolve_out_dir`).  ``data`` is
    converted with :func:`to_jsonable` (NumPy types, Outcomes, NaN -> null) and
    serialised before anything is written, so a failure leaves no partial file.
    Each file is written to a temporary name and moved into place with
    ``os.replace``.  Returns the two paths.
    """
    if not name or "/" in name or name.startswith("."):
        raise ValueError(f"write_report: bad report name {name!r}")
    out = resolve_out_dir(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    text = json.dumps(to_jsonable(data), indent=1, allow_nan=False, ensure_ascii=False)
    md_path, json_path = out / f"{name}.md", out / f"{name}.json"
    _atomic_write(json_path, text + "\n")
    _atomic_write(md_path, markdown if markdown.endswith("\n") else markdown + "\n")
    log.info("write_report: wrote %s and %s", md_path, json_path)
    return md_path, json_path


# ----------------------------------------------------------------------------------------
# environment
# ----------------------------------------------------------------------------------------

def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _ram_gb() -> float:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal:"):
                    return round(int(line.split()[1]) / 1024.0 ** 2, 1)
    except OSError:
        pass
    return math.nan


def environment_info() -> dict:
    """Machine and library versions for report headers (no heavy imports).

    Keys: ``platform``, ``machine``, ``cpu_model``, ``cpu_count``,
    ``cpu_affinity`` (cores usable by this process), ``ram_gb``, ``load_avg``
    (1/5/15-min load averages: timings on a shared machine are only comparable
    at similar load), ``python``,
    ``versions`` (numpy, scipy, scikit-learn, pymeshlab, cgal, matplotlib, numba;
    None when not installed) and ``timestamp_utc``.
    """
    from importlib import metadata

    versions = {}
    for dist in ("numpy", "scipy", "scikit-learn", "pymeshlab", "cgal", "matplotlib",
                 "numba"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = None
    try:
        affinity = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        affinity = os.cpu_count()
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        load = None
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_model": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpu_affinity": affinity,
        "ram_gb": _ram_gb(),
        "load_avg": load,
        "python": platform.python_version(),
        "versions": versions,
        "timestamp_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


# ----------------------------------------------------------------------------------------
# tuning / held-out splits and the thesis preset
# ----------------------------------------------------------------------------------------

#: the values of the ``"split"`` key of every case / row of a family report
SPLITS = ("tuning", "held-out")


def accepts_preset(fn: Callable) -> bool:
    """True when ``fn`` takes a ``preset`` parameter (``preset="thesis"`` runs the
    method as printed in the thesis); checked when a harness starts, so a filter
    that gains the parameter gets its "thesis preset" column without a change here."""
    import inspect

    try:
        return "preset" in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False


def split_summary(records: list, methods, value: Callable) -> dict:
    """Mean of ``value(record, method)`` per split and method over the finite
    values, the count of records behind each mean, and the gap (held-out minus
    tuning) per method; None where a split has no finite value."""
    out: dict = {"mean": {}, "count": {}, "gap": {}}
    for split in SPLITS:
        rs = [r for r in records if r.get("split") == split]
        out["count"][split] = len(rs)
        out["mean"][split] = {}
        for m in methods:
            vals = [value(r, m) for r in rs]
            vals = [float(v) for v in vals if v is not None and _is_number(v)
                    and math.isfinite(float(v))]
            out["mean"][split][m] = float(np.mean(vals)) if vals else None
    for m in methods:
        a, b = out["mean"]["tuning"][m], out["mean"]["held-out"][m]
        out["gap"][m] = None if a is None or b is None else b - a
    return out


def split_table(summary: dict, methods, how: str, fmt: str = "{:.3f}") -> str:
    """Markdown rows "tuning", "held-out" and "gap (held-out − tuning)" of a
    :func:`split_summary`, the best method of each mean row in bold (``how`` =
    "min" or "max"); a split without cases gets no row (and then no gap row)."""
    header = ["split (cases)"] + list(methods)
    present = [s for s in SPLITS if summary["count"][s]]
    rows = [[f"{s} ({summary['count'][s]})"] + [summary["mean"][s][m] for m in methods]
            for s in present]
    if not rows:
        return "No case ran.\n"
    body = markdown_table(header, rows, best={i + 1: how for i in range(len(methods))},
                          fmt=fmt)
    if len(present) < len(SPLITS):
        return body
    gap = markdown_table(header, [["gap (held-out − tuning)"]
                                  + [summary["gap"][m] for m in methods]], fmt=fmt)
    return body + gap.split("\n", 2)[2]
