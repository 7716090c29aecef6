"""
bench_scale.py
--------------
``pcprep bench scale``: tiled runs (meshlab_bridge/tiles.py) of generated
airborne-like LAZ clouds through the tiled filters, on local Dask clusters of
1 and 2 worker processes, each run in a fresh process: wall time by stage, peak
memory per worker and of the driver (its anonymous part apart), the scratch
folder's size, speed-up (at 10⁶ points the median of three runs each),
time per million points, the serial fraction (streamed ingest, tile index,
driver work between passes, streamed write) and, from it, the projected time of
a 10⁹-point job on 32 and 256 workers (Amdahl, assumptions in the report);
then, on 2 workers, larger terrains (peak memory per worker and time per 10⁶
points against N) and a cloud of copies of a real scan (``EXTRA``).
Writes scale.md and scale.json into the output folder (reports/, or reports/quick with --quick).
``pcprep bench scale --speed`` runs the single-node part alone (each filter in
one piece against one 16-NN pass, in minutes): speed_scale.md and .json.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
import time

import numpy as np

log = logging.getLogger("pcprep")

#: point counts of the full run and of --quick
SIZES = (1_000_000,)
QUICK_SIZES = (100_000,)
FILTERS = ("outliers", "denoise", "saliency", "features", "holes", "simplify")
#: parameters a filter needs beyond its defaults
PARAMS = {"simplify": {"ratio": 0.1}}
#: more clouds, on 2 workers only: (cloud, points, filters).  Larger terrains give
#: peak memory per worker and time per million points against N (flat when the
#: tiles keep their size); the scan is the real gargoyle point set of the shared
#: models, laid out in copies (run only when that folder is present)
EXTRA = (("terrain", 5_000_000, FILTERS),
         ("terrain", 20_000_000, FILTERS),
         ("scan", 1_000_000, FILTERS))
QUICK_EXTRA = (("terrain", 300_000, ("outliers",)), ("scan", 100_000, ("outliers",)))
#: the shared model the scan-derived cloud is made of
SCAN = "scans/gargoyle_points_95k.ply"
#: core points per tile
TILE = 200_000
QUICK_TILE = 25_000
#: seconds one tiled run may take (the 20M-point denoise takes about 25 min here)
RUN_TIMEOUT = 3 * 3600
#: runs per worker count at ``SIZES`` (1 and 2 workers alternating; the
#: median-time run is the row): a 1M-point run lasts 4–20 s, and single runs
#: of the short ones moved their speed-up by ±0.2
SPEEDUP_REPEATS = 3
#: 16-NN passes timed per cloud (the median is the yardstick)
KNN_REPEATS = 3


def _terrain_laz(path: str, n: int, seed: int) -> None:
    """Airborne-like ground: a rolling surface with roofs (sharp steps), 1 cm
    noise, intensity and classification; written in chunks."""
    import laspy

    g = np.random.default_rng(seed)
    side = np.sqrt(n) * 0.5  # about 4 points per m²
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.offsets = [500_000.0, 4_000_000.0, 0.0]
    header.scales = [1e-4, 1e-4, 1e-4]
    with laspy.open(path, mode="w", header=header, do_compress=True) as w:
        for s in range(0, n, 1 << 20):
            m = min(n, s + (1 << 20)) - s
            xy = g.uniform(0.0, side, (m, 2))
            z = 3.0 * np.sin(xy[:, 0] / 40.0) * np.cos(xy[:, 1] / 55.0)
            roof = (np.floor(xy[:, 0] / 30.0) + np.floor(xy[:, 1] / 30.0)) % 4 == 0
            z = z + np.where(roof & ((xy % 30.0) > 8.0).all(axis=1), 6.0, 0.0)
            z += 0.01 * g.normal(size=m)
            rec = laspy.ScaleAwarePointRecord.zeros(m, header=header)
            rec.x, rec.y, rec.z = xy[:, 0] + 500_000.0, xy[:, 1] + 4_000_000.0, z
            rec.intensity = g.integers(0, 4096, m)
            rec.classification = np.where(roof, 6, 2)
            w.write_points(rec)


def _scan_laz(path: str, n: int, seed: int) -> int | None:
    """A real scan laid out in copies: the shared gargoyle point set (95 435
    points, its own sampling and noise) turned about z at random and placed on
    a ground grid with a gap of a fifth of its size, whole copies until at least
    ``n`` points.  Returns the point count, or None without the shared models."""
    import laspy

    from pcprep.meshlab_bridge.formats import read_cloud

    from .meshes import shared_models_root

    src = shared_models_root() / SCAN
    if not src.is_file():
        return None
    pts = read_cloud(src).points
    pts = pts - pts.mean(axis=0)
    copies = -(-n // len(pts))
    side = int(np.ceil(np.sqrt(copies)))
    step = 1.2 * float(np.ptp(pts[:, :2], axis=0).max())
    g = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.offsets = [1000.0, 2000.0, 0.0]
    header.scales = [1e-4, 1e-4, 1e-4]
    with laspy.open(path, mode="w", header=header, do_compress=True) as w:
        for c in range(copies):
            a = g.uniform(0.0, 2.0 * np.pi)
            rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0],
                            [0.0, 0.0, 1.0]])
            q = pts @ rot.T + [1000.0 + step * (c % side), 2000.0 + step * (c // side), 0.0]
            rec = laspy.ScaleAwarePointRecord.zeros(len(q), header=header)
            rec.x, rec.y, rec.z = q[:, 0], q[:, 1], q[:, 2]
            w.write_points(rec)
    return copies * len(pts)


def _worker_peak_rss(client) -> list:
    """Peak resident memory of each worker process, MiB (``VmHWM``, which starts
    afresh at exec; ``ru_maxrss`` of a spawned worker would report its parent's
    RSS at the fork when that is larger)."""
    from .harness import _peak_mb

    return sorted(client.run(_peak_mb).values())


class _DriverPeak:
    """The driver's peak resident memory during a run, MiB: all of it (``VmRSS``)
    and its anonymous part (``RssAnon``), sampled every ``every`` seconds by a
    thread.  The anonymous part is what the driver needs; the rest are pages of
    the scratch memory maps and of the files, which the kernel writes back and
    drops when memory runs short."""

    def __init__(self, every: float = 0.05):
        self.every, self.rss, self.anon = every, 0.0, 0.0

    def _sample(self):
        from .harness import _rss_mb

        while not self._stop.wait(self.every):
            self.rss = max(self.rss, _rss_mb("VmRSS"))
            self.anon = max(self.anon, _rss_mb("RssAnon"))

    def __enter__(self):
        import threading

        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


def _knn16_seconds(path: str) -> float:
    from pcprep.filters.neighbors import build_tree
    from pcprep.meshlab_bridge.formats import stream

    pts = np.concatenate([b for _, b in stream.position_chunks(path)])
    pts -= pts.mean(axis=0)
    times = []
    for _ in range(KNN_REPEATS):
        t = time.perf_counter()
        tree = build_tree(pts)
        tree.query(pts, k=16, workers=-1)
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def _pin_workers(client) -> None:
    """Give each worker process a core of its own (Linux): its tasks run on
    one thread (``tiles._one_thread``), but without the pin the 1-worker run
    could still spread its process's other threads (Dask's event loop, the
    memory map's page faults) over the idle core; with it, the speed-up from
    1 to 2 workers is the one of adding a core."""
    if not hasattr(os, "sched_setaffinity"):
        return
    cores = sorted(os.sched_getaffinity(0))
    for i, addr in enumerate(sorted(client.scheduler_info()["workers"])):
        core = cores[i % len(cores)]
        client.run(os.sched_setaffinity, 0, {core}, workers=[addr])


#: points of the warm-up run before each timed one-piece run (``run`` and
#: ``run_speed``)
WARM_POINTS = 5000


def _warm_rows(points):
    """About ``WARM_POINTS`` rows of ``points``, evenly strided."""
    return points[::max(1, len(points) // WARM_POINTS)]


def _speed_filter(name: str, points) -> int:
    """One filter over ``points`` in one piece, with ``PARAMS`` (for
    :func:`harness.measure`: runs in a fresh process)."""
    from pcprep.meshlab_bridge import registry, tiles

    tiles._spec(registry, name).func(points, **PARAMS.get(name, {}))
    return len(points)


def _one_piece_seconds(path: str, name: str) -> float:
    """Wall time of the filter over the whole cloud in this process (no Dask),
    after a run on ``WARM_POINTS`` of the points: the first call after an
    install compiles the numba kernels (about 25 s for denoise), which is not
    the filter's cost (``run_speed`` warms up the same way)."""
    from pcprep.meshlab_bridge.formats import stream

    pts = np.concatenate([b for _, b in stream.position_chunks(path)])
    _speed_filter(name, _warm_rows(pts))
    t = time.perf_counter()
    _speed_filter(name, pts)
    return time.perf_counter() - t


def _one(path: str, dst: str, name: str, workers: int, tile: int) -> dict:
    from pcprep.meshlab_bridge import registry, tiles
    from pcprep.meshlab_bridge.formats import stream

    spec = tiles._spec(registry, name)
    scratch = tempfile.mkdtemp(prefix="pcprep-bench-")
    try:
        # the CLI's local cluster, one thread per worker: a worker is a core here
        with tiles.dask_client(workers=workers, threads=1) as client:
            _pin_workers(client)
            with _DriverPeak() as driver:
                t0 = time.perf_counter()
                n = stream.point_count(path)
                src = tiles.ingest(stream.position_chunks(path), n, scratch)
                t_in = time.perf_counter() - t0
                t1 = time.perf_counter()
                res = tiles.run_tiled(name, source=src, client=client, tiles=tile,
                                      scratch=scratch, params=PARAMS.get(name))
                t_run = time.perf_counter() - t1
                t2 = time.perf_counter()
                stream.write_streamed(spec, path, dst, res.fields, n=n)
                t_out = time.perf_counter() - t2
                st, h = res.stats, res.h
                disk = sum(e.stat().st_size for e in os.scandir(scratch) if e.is_file())
                res = src = None  # the memory maps close before the folder goes
            peaks = _worker_peak_rss(client)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    serial = t_in + st["time_index"] + st["time_driver"] + t_out
    wall = t_in + t_run + t_out
    return {"filter": name, "n": n, "workers": workers, "wall_s": wall, "ingest_s": t_in,
            "index_s": st["time_index"], "passes_s": st["time_passes"],
            "driver_s": st["time_driver"], "write_s": t_out, "serial_s": serial,
            "pass_cpu_s": sum(st["cpu_passes"].values()),
            "pass_cpu_main_s": sum(st["cpu_passes_main"].values()), "worker_io": st["worker_io"],
            "tiles": st["tiles"], "halo_max_h": st["halo_max"] / h,
            "repeats": {k: st[k] for k in ("denoise_runs", "greedy_passes") if k in st},
            "peak_worker_rss_mb": peaks, "driver_peak_rss_mb": driver.rss,
            "driver_peak_anon_mb": driver.anon, "scratch_b_per_pt": disk / n,
            "s_per_million": wall / (n / 1e6)}


def _one_fresh(path: str, dst: str, name: str, workers: int, tile: int) -> dict:
    """``_one`` in a fresh process, so that the driver's memory is that run's
    alone (a process keeps the heap of the runs before it)."""
    from .harness import run_isolated

    out = run_isolated(_one, path, dst, name, workers, tile, timeout=RUN_TIMEOUT)
    if not out.ok:
        raise RuntimeError(f"scale: {name} on {path} with {workers} worker(s): {out.error}")
    return out.value


def _median_run(runs: list) -> dict:
    """The run of median wall time, with every run's wall time in ``runs_wall_s``."""
    walls = [r["wall_s"] for r in runs]
    return dict(runs[int(np.argsort(walls)[(len(runs) - 1) // 2])], runs_wall_s=walls)


def _project(row1: dict, workers: int, n_target: float = 1e9, *,
             driver_bound: bool = False) -> float:
    """Amdahl with the serial part scaling with n (one streamed pass over the data
    at this machine's rate) and the parallel part with n / workers.  With
    ``driver_bound`` the driver's CPU time during the tile passes (cutting the
    tiles, gathering every row's result into the memory maps: work that does
    not divide over the workers) counts as serial too, a bound for many
    workers."""
    scale = n_target / row1["n"]
    serial = row1["serial_s"] + (row1["pass_cpu_s"] if driver_bound else 0.0)
    parallel = max(row1["wall_s"] - serial, 0.0) * scale
    return serial * scale + parallel / workers


def run(quick: bool = False, seed: int = 0, out_dir: str = "reports") -> dict:
    sizes = QUICK_SIZES if quick else SIZES
    tile = QUICK_TILE if quick else TILE
    work = tempfile.mkdtemp(prefix="pcprep-scale-")
    rows, knn, whole = [], {}, {}
    try:
        for n in sizes:
            path = os.path.join(work, f"terrain_{n}.laz")
            _terrain_laz(path, n, seed)
            knn[n] = _knn16_seconds(path)
            for name in FILTERS:
                log.warning("scale: %s, %d points, one piece", name, n)
                whole[(name, n)] = _one_piece_seconds(path, name)
                runs = {1: [], 2: []}
                for rep in range(1 if quick else SPEEDUP_REPEATS):
                    for workers in (1, 2):
                        log.warning("scale: %s, %d points, %d worker(s), run %d", name, n,
                                    workers, rep + 1)
                        runs[workers].append(_one_fresh(path, os.path.join(work, "out.laz"),
                                                        name, workers, tile))
                rows += [_median_run(runs[1]), _median_run(runs[2])]
            os.remove(path)
        for cloud, n, names in (QUICK_EXTRA if quick else EXTRA):
            path = os.path.join(work, f"{cloud}_{n}.laz")
            if cloud == "scan":
                if _scan_laz(path, n, seed) is None:
                    log.warning("scale: no shared models; the scan-derived cloud is skipped")
                    continue
            else:
                _terrain_laz(path, n, seed)
            for name in names:
                log.warning("scale: %s, %s of %d points, 2 workers", name, cloud, n)
                rows.append(dict(_one_fresh(path, os.path.join(work, "out.laz"), name, 2,
                                            tile), cloud=cloud))
            os.remove(path)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    summary = []
    for name in FILTERS:
        for n in sizes:
            one = next(r for r in rows if r["filter"] == name and r["n"] == n
                       and r["workers"] == 1)
            two = next(r for r in rows if r["filter"] == name and r["n"] == n
                       and r["workers"] == 2)
            pairs = [a / b for a, b in zip(one["runs_wall_s"], two["runs_wall_s"])]
            summary.append({"filter": name, "n": n, "speedup_2": one["wall_s"] / two["wall_s"],
                            "speedup_2_pairs": pairs,
                            "serial_fraction": one["serial_s"] / one["wall_s"],
                            "x_knn16": one["wall_s"] / knn[n],
                            "one_piece_s": whole[(name, n)],
                            "one_piece_x_knn16": whole[(name, n)] / knn[n],
                            "proj_1e9_32_h": _project(one, 32) / 3600,
                            "proj_1e9_256_h": _project(one, 256) / 3600,
                            "driver_pass_cpu_s": one["pass_cpu_s"],
                            "driver_pass_cpu_main_s": one["pass_cpu_main_s"],
                            "proj_1e9_256_driver_h": _project(one, 256,
                                                              driver_bound=True) / 3600})
    growth = []
    for r in rows:
        if r.get("cloud", "terrain") != "terrain" or r["n"] in sizes or r["workers"] != 2:
            continue
        base = next(b for b in rows if b["filter"] == r["filter"] and b["workers"] == 2
                    and b["n"] == sizes[-1])
        growth.append({"filter": r["filter"], "n": r["n"], "n0": base["n"],
                       "rss_ratio": max(r["peak_worker_rss_mb"]) /
                       max(base["peak_worker_rss_mb"]),
                       "time_ratio": r["s_per_million"] / base["s_per_million"],
                       "driver_anon_ratio": r["driver_peak_anon_mb"] /
                       base["driver_peak_anon_mb"],
                       "driver_anon_b_per_pt": (r["driver_peak_anon_mb"] -
                                                base["driver_peak_anon_mb"]) * 2**20 /
                       (r["n"] - base["n"])})
    out = {"rows": rows, "summary": summary, "growth": growth, "knn16_s": knn, "tile": tile,
           "params": PARAMS,
           "cpus": os.cpu_count()}
    with open(os.path.join(out_dir, "scale.json"), "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1, default=float)
    with open(os.path.join(out_dir, "scale.md"), "w", encoding="utf-8") as f:
        f.write(_markdown(out))
    return out


#: timed runs per filter in ``run_speed`` (the median is reported)
SPEED_REPEATS = 3


def run_speed(quick: bool = False, seed: int = 0, out_dir: str = "reports") -> dict:
    """``pcprep bench scale --speed``: the single-node part alone.  Every tiled
    filter over the whole generated terrain of 1M points (100K with --quick) in
    one piece, ``SPEED_REPEATS`` times, each in a fresh process
    (:func:`harness.measure`: wall time of the call, the compiled kernels'
    cache load included, and peak RSS), against one 16-NN pass of the same
    cloud (cKDTree build + query, all cores) in the same run.  The yardstick is
    the median of the passes taken before each filter's runs and once more at
    the end, so that it sees the machine in the same states as the filters; a
    filter's time is the median of its runs.  On this machine a single pass
    varied by ±10 % between runs and a filter by up to ±8 %, so one run of each
    moved a ratio across the 4× target.  Each filter's timed runs follow a run
    on ``WARM_POINTS`` of the points in its own process, which fills numba's
    on-disk cache: a first run after an install compiles the kernels (about
    25 s for denoise), once.  Writes speed_scale.md and speed_scale.json."""
    from . import harness

    n = QUICK_SIZES[0] if quick else SIZES[0]
    work = tempfile.mkdtemp(prefix="pcprep-speed-")
    try:
        path = os.path.join(work, f"terrain_{n}.laz")
        _terrain_laz(path, n, seed)
        from pcprep.meshlab_bridge.formats import stream

        pts = np.concatenate([b for _, b in stream.position_chunks(path)])
    finally:
        shutil.rmtree(work, ignore_errors=True)
    passes = []
    rows = []
    for name in FILTERS:
        passes.append(float(harness.knn_pass_seconds(pts, 16)))
        harness.measure(_speed_filter, name, _warm_rows(pts))
        runs = [harness.measure(_speed_filter, name, pts) for _ in range(SPEED_REPEATS)]
        bad = next((o for o in runs if not o.ok), None)
        secs = [o.seconds for o in runs] if bad is None else []
        rows.append({"filter": name, "n": n, "ok": bad is None,
                     "error": None if bad is None else bad.error,
                     "seconds": float(np.median(secs)) if secs else None,
                     "runs_s": secs,
                     "peak_mb": max(o.peak_mb for o in runs) if secs else None})
        log.info("bench_scale speed: %s %s", name, runs)
    passes.append(float(harness.knn_pass_seconds(pts, 16)))
    knn = float(np.median(passes))
    for r in rows:
        r["x_knn16"] = r["seconds"] / knn if r["ok"] else None
    out = {"n": n, "knn16_s": knn, "knn16_passes_s": passes, "rows": rows,
           "repeats": SPEED_REPEATS, "params": PARAMS, "cpus": os.cpu_count(),
           "target_x_knn16": 4.0}
    md = ["# Single-node speed: each filter in one piece", "",
          f"Generated airborne-like terrain of {n:,} points (the `pcprep bench scale` "
          f"cloud), each filter with its defaults ({PARAMS} beyond them) over the whole "
          f"cloud in one process, {SPEED_REPEATS} times, each in a fresh process after "
          "a warm-up run that fills the compiled kernels' cache: the median wall time "
          "of the call (the cache load included), every run's time, and the largest "
          "peak RSS (interpreter and input included), on "
          f"{os.cpu_count()} cores.  Yardstick, same run: one cKDTree build + 16-NN "
          f"query of the same cloud with all cores, before each filter and at the end; "
          f"their median {knn:.2f} s (passes: "
          f"{', '.join(f'{p:.2f}' for p in passes)} s).  Target: within 4× that pass.",
          "",
          "| filter | seconds (median) | runs s | peak MB | × one 16-NN pass |",
          "|---|---|---|---|---|"]
    for r in rows:
        if r["ok"]:
            md.append(f"| {r['filter']} | {r['seconds']:.2f} | "
                      f"{', '.join(f'{t:.2f}' for t in r['runs_s'])} | "
                      f"{r['peak_mb']:.0f} | {r['x_knn16']:.2f} |")
        else:
            md.append(f"| {r['filter']} | failed: {r['error']} | | | |")
    harness.write_report("speed_scale", "\n".join(md) + "\n", out, out_dir)
    return out


def _repeats_text(out: dict) -> str:
    runs = max(len(r.get("runs_wall_s", [])) for r in out["rows"])
    knn = (f"The 16-NN yardstick is the median of {KNN_REPEATS} passes over the same "
           "points.  ")
    if runs < 2:
        return knn + "One run per row.\n"
    return (knn + f"At the points of the speed-up, each worker count ran {runs} times, 1 "
            "and 2 workers alternating: its row is the run of median wall time, the "
            "speed-up is the ratio of the two medians and, in brackets, its range over "
            "the pairs of runs.  The other rows are one run each.\n")


def _speedup_text(s: dict) -> str:
    pairs = s.get("speedup_2_pairs", [])
    if len(pairs) < 2:
        return f"{s['speedup_2']:.2f}"
    return f"{s['speedup_2']:.2f} ({min(pairs):.2f}–{max(pairs):.2f})"


def _markdown(out: dict) -> str:
    lines = ["# Scale: tiled runs on Dask", "",
             f"Generated airborne-like LAZ (rolling ground, roofs with sharp steps, 1 cm "
             f"noise) and, marked (scan), the shared gargoyle point set ({SCAN}, a "
             f"real scan of 95,435 points) laid out in copies on a ground grid; "
             f"{out['tile']} core points per tile; LocalCluster of 1 and 2 worker "
             f"processes (1 thread each, each pinned to a core of its own) on a "
             f"{out['cpus']}-core machine; the one-piece run uses every core and "
             f"follows a warm-up run on {WARM_POINTS:,} of the points that fills the "
             "compiled kernels' cache.  Wall time includes the streamed read into the "
             "scratch memory map, the "
             "tile index, the exact h pass, the filter's passes and the streamed write.  "
             "Tiled runs use the default I/O, which on a local cluster is the workers' "
             "own: each cuts its tile from the scratch memory maps and writes its rows "
             "into them.", "",
             "Each run is a fresh process (the driver) with its own cluster.  Driver "
             "memory is sampled every 50 ms: all of it and, in brackets, its "
             "anonymous part (the rest are pages of the scratch memory maps and the "
             "files, which the kernel writes back and drops as memory runs short); "
             "both include the interpreter, the imports and one streamed chunk of "
             "the write (2¹⁸ rows with every attribute).", "",
             _repeats_text(out),
             "| filter | points | workers | tiles | wall s | s / 10⁶ pts | serial s | "
             "peak RSS per worker MB | driver peak MB (anonymous) | scratch disk B / pt | "
             "widest halo (h) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in out["rows"]:
        what = "" if r.get("cloud", "terrain") == "terrain" else f" ({r['cloud']})"
        lines.append(f"| {r['filter']}{what} | {r['n']:,} | {r['workers']} | {r['tiles']} | "
                     f"{r['wall_s']:.1f} | {r['s_per_million']:.1f} | {r['serial_s']:.1f} | "
                     f"{', '.join(f'{p:.0f}' for p in r['peak_worker_rss_mb'])} | "
                     f"{r['driver_peak_rss_mb']:.0f} ({r['driver_peak_anon_mb']:.0f}) | "
                     f"{r['scratch_b_per_pt']:.0f} | {r['halo_max_h']:.0f} |")
    lines += ["", "| filter | points | one piece s | one piece × one 16-NN pass | "
              "speed-up 1→2 workers | serial fraction | "
              "× one 16-NN pass (1 worker, tiled) | 10⁹ pts on 32 workers (h) | "
              "on 256 workers (h) | driver CPU in the passes s (its main thread) | "
              "on 256 workers, that CPU serial (h) |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in out["summary"]:
        lines.append(f"| {s['filter']} | {s['n']:,} | {s['one_piece_s']:.1f} | "
                     f"{s['one_piece_x_knn16']:.1f} | {_speedup_text(s)} | "
                     f"{s['serial_fraction']:.3f} | {s['x_knn16']:.1f} | "
                     f"{s['proj_1e9_32_h']:.2f} | {s['proj_1e9_256_h']:.2f} | "
                     f"{s['driver_pass_cpu_s']:.1f} ({s['driver_pass_cpu_main_s']:.1f}) | "
                     f"{s['proj_1e9_256_driver_h']:.2f} |")
    if out.get("growth"):
        lines += ["", "Against N (2 workers, same tile size): the larger cloud's peak RSS "
                  "per worker, time per 10⁶ points and the driver's anonymous peak over "
                  "those of the smaller, and the driver's anonymous bytes per added point.",
                  "", "| filter | points | vs points | peak RSS per worker, ratio | "
                  "s / 10⁶ pts, ratio | driver anonymous, ratio | "
                  "driver anonymous, B per added point |", "|---|---|---|---|---|---|---|"]
        for g in out["growth"]:
            lines.append(f"| {g['filter']} | {g['n']:,} | {g['n0']:,} | "
                         f"{g['rss_ratio']:.2f} | {g['time_ratio']:.2f} | "
                         f"{g['driver_anon_ratio']:.2f} | {g['driver_anon_b_per_pt']:.0f} |")
    lines += ["", "Projection (Amdahl): T(P) = S·(10⁹/n) + (W − S)·(10⁹/n)/P, with S the "
              "serial seconds and W the wall seconds of the 1-worker run at n points.  "
              "Assumed: the serial part (streamed read and write, index, driver) runs at "
              "this machine's single-stream rate and grows linearly with n; the parallel "
              "part grows linearly with n (tiles are independent, the halo fraction is "
              "that of these tiles) and divides evenly over P workers of this machine's "
              "per-core speed; no network or shared-filesystem limit.  The driver's "
              "cloud-wide fits (score models, dictionaries, thresholds, border chains) "
              "count as serial.  The driver also works during the tile passes (it sends "
              "each tile's cell, counts the rows written, gathers the tiles' sums and "
              "overlap samples); that does not divide over the workers, so the last "
              "column counts the driver's CPU seconds in the passes (process time, all "
              "its threads) as serial too: the bound when workers are many.  In brackets, "
              "the part of its main thread, which is pcprep's own work (cutting, "
              "gathering, bookkeeping); the rest is Dask's event loop, which on a local "
              "cluster runs the scheduler in the driver's process and on a real one "
              "runs on the scheduler's host.", ""]
    return "\n".join(lines)
