"""
tiles.py
--------
Clouds larger than one process: spatial tiles with a halo, run on Dask.

The cloud's positions are streamed once into a memory-mapped (n, 3) float64
array in a scratch folder (``ingest``); a uniform grid over its bounding box
cuts it into tiles of about ``target`` core points (``TileIndex``); every tile
runs on a Dask worker with the points of its box grown by a halo of ``w`` (its
*extended* region), and the results of its core rows go into memory maps in
the same folder (``_Runner.store``).  Every row lies in exactly one core.
Where the workers run on the driver's host and read its scratch folder (a
local cluster; detected), a task is told where its region lies and which
stored arrays to read and write, and the worker cuts, reads and writes
itself (each task first checks that it runs there, ``_at_home``, and hands
its I/O back to the driver where it does not); elsewhere the driver cuts
each region, sends its points and writes what comes back.  Either way the
driver's memory does not grow with the cloud, and the results are the same
bits.  A tile's rows lie scattered over the stored arrays when the input is
not in spatial order; they are read and written in blocks whose pages are
let go after each (``_gather``, ``_scatter``), so that no process holds a
share of an array that grows with the cloud.

Exactness.  A filter declares how many times a point's result reads its
neighbours' intermediate values (``hops``, in ``specs/*``); the halo starts at
``hops`` × ``HOP_H`` × h, and the tile function checks it
(``pcprep.filters.neighbors.tile_exact``): a core row whose neighbourhood chain
leaves the box makes the tile come back "not exact", and it is run again with a
wider halo: by the amount the tile says it fell short (``tile_miss``, where
only the rows' own balls count) or else ``GROW`` times.  Cloud-wide values are fitted once and broadcast:
h in a first pass over the tiles (the exact value, not a sample's: a
subsample's spacing is larger), the centre from the bounding box, F̄_g and the
maxima of saliency by a pass of sums, the statistical outlier threshold from
the scores of every row, and denoise's two inner-loop decisions by a plan
checked against the cloud-wide sums (``_denoise``).  docs/decisions/scale.md
has the derivations.

Input.  A run refuses what the one-piece run refuses, with its message: too
few points, all coincident or collinear (``_check_cloud``, before the index),
duplicate points (found by the first pass's tiles), bad input normals
(``_checked_normals``; normals are used as the one-piece run uses them).

Engine: ``dask.distributed``.  ``client=None`` starts a ``LocalCluster`` sized
by ``workers`` and ``memory_budget`` (closed at the end; a budget below
``MIN_BUDGET`` is refused); ``scheduler`` attaches to a running one.  A task
lost with its worker is run again by the scheduler (it writes the same values
again: nothing is lost or added), and every core row is counted exactly once
(checked); a task that kills every worker it is given (most often a tile too
big for the budget) ends the run with ``WorkersLostError``, which says so.
"""

from __future__ import annotations

import errno
import functools
import logging
import math
import mmap
import os
import shutil
import tempfile
import threading
from contextlib import contextmanager, suppress
from dataclasses import dataclass

import numpy as np

from pcprep.filters import progress
from pcprep.filters._validation import (InvalidParameterError, PointCloudError,
                                        _duplicate_pairs, check_extent, duplicate_error)
from pcprep.filters.neighbors import (SPACING_K, build_tree, knn, mean_std, quantile,
                                      spacing_from_rows, tile_miss)

log = logging.getLogger("pcprep")

#: rows per chunk of the streamed passes
CHUNK = 1 << 20
#: first guess of one neighbour step, in units of h (a 32-NN radius on a surface)
HOP_H = 4.0
#: a tile whose halo proved too narrow runs again with a halo this many times wider
GROW = 1.6
#: a tile that says how much its halo fell short runs again with the halo grown
#: by that much, times this margin
SHORT_MARGIN = 1.02
#: bytes per extended point a tile's task needs at most (denoise: neighbour lists,
#: its state and the chunk buffers), for ``tiles="auto"``
BYTES_PER_POINT = 4_000
#: tasks in flight per worker thread (the driver holds their inputs)
IN_FLIGHT = 2
#: bytes of a stored array's pages one scattered read or write may hold mapped
#: at once (``_gather``, ``_scatter``)
MAPPED_BYTES = 64 << 20


# ---------------------------------------------------------------------------
# the cloud on disk


@dataclass
class Source:
    """A cloud's positions on disk: ``xyz`` an (n, 3) float64 memory map."""

    xyz: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    path: str | None = None

    @property
    def n(self) -> int:
        return len(self.xyz)

    @property
    def centre(self) -> np.ndarray:
        """The bounding-box centre, the origin every filter works about."""
        return 0.5 * (self.lo + self.hi)


class ScratchSpaceError(OSError):
    """The scratch folder has no room for an array a run keeps there."""


def open_scratch(path: str, shape, dtype=np.float64) -> np.memmap:
    """A new zero-filled ``.npy`` memory map at ``path`` with its disk blocks
    reserved at once (``os.posix_fallocate``).  A memory map only takes disk
    blocks as its pages are written; on a full disk the kernel answers such a
    write with SIGBUS, and the process (or the worker) dies without a word.
    Reserved up front, a folder without room fails here instead, with
    ``ScratchSpaceError`` naming the folder, the size and the free space (the
    file is removed).  Where the platform or file system cannot reserve, the
    map is returned as it is."""
    arr = np.lib.format.open_memmap(path, mode="w+", dtype=dtype,
                                    shape=(shape,) if np.isscalar(shape) else tuple(shape))
    if not hasattr(os, "posix_fallocate"):
        return arr
    size = os.path.getsize(path)
    try:
        fd = os.open(path, os.O_RDWR)
        try:
            os.posix_fallocate(fd, 0, size)
        finally:
            os.close(fd)
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
            return arr  # the file system does not reserve: nothing to check
        del arr
        folder = os.path.dirname(os.path.abspath(path))
        free = shutil.disk_usage(folder).free
        with suppress(OSError):
            os.remove(path)
        raise ScratchSpaceError(
            exc.errno, f"the scratch folder {folder} has no room for "
            f"{os.path.basename(path)} ({size / 2**20:.0f} MiB; {free / 2**20:.0f} MiB "
            "free): give a folder with more room (scratch=, or --scratch for the "
            "command line)") from None
    return arr


def ingest(chunks, n: int, scratch: str) -> Source:
    """Write streamed ``(start, xyz)`` chunks into ``scratch/xyz.npy``; refuse
    non-finite rows (naming the first ones) and chunks that do not cover rows
    0…n−1 once each, in order (a count that does not match the data).  The
    tile index's compiled kernels load meanwhile (``_preload_index_kernels``)."""
    _preload_index_kernels()
    xyz = open_scratch(os.path.join(scratch, "xyz.npy"), (n, 3))
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    got = 0
    for start, block in chunks:
        block = np.asarray(block, dtype=np.float64)
        if start != got or start + len(block) > n:
            raise PointCloudError(f"the input's rows do not match its point count {n}: "
                                  f"rows {start}–{start + len(block) - 1} after {got} rows")
        got += len(block)
        if not np.isfinite(block).all():
            bad = ~np.isfinite(block).all(axis=1)
            rows = (np.flatnonzero(bad)[:10] + start).tolist()
            raise PointCloudError(f"non-finite coordinates in rows {rows}")
        xyz[start:start + len(block)] = block
        if len(block):  # column by column: an axis-0 reduction of (m, 3) is 7× slower
            lo = np.minimum(lo, [block[:, a].min() for a in range(3)])
            hi = np.maximum(hi, [block[:, a].max() for a in range(3)])
    if got != n:
        raise PointCloudError(f"the input holds {got} rows, not the {n} its point count "
                              "says")
    xyz.flush()
    return Source(xyz, lo, hi)


@functools.cache
def _preload_index_kernels() -> None:
    """Start loading ``build_index``'s compiled kernels on a thread, once per
    process: numba's first call in a process costs about 0.25 s, mostly in
    LLVM with the GIL released, so it overlaps the ingest's decoding instead
    of adding to the serial part of a run."""
    threading.Thread(target=_load_index_kernels, name="pcprep-preload", daemon=True).start()


def _load_index_kernels() -> None:
    """One call of each index kernel on one row (a failure is left to the
    index's own call to raise)."""
    from pcprep.filters import _kernels

    if not _kernels.ENABLED:
        return
    with suppress(Exception):
        one = np.zeros((1, 3))
        ids = np.zeros(1, dtype=np.int64)
        _kernels.cell_ids(one, np.zeros(3), np.ones(3), np.ones(3, dtype=np.int64), ids)
        _kernels.cell_fill(ids, one, 0, np.zeros(1, dtype=np.int64), ids.copy(), one.copy())


def source_from_array(points: np.ndarray, scratch: str) -> Source:
    """``ingest`` of an (n, 3) array or memory map, converted to float64 a
    chunk at a time (a float32 memory map is never copied whole)."""
    if not isinstance(points, np.ndarray):
        try:
            points = np.asarray(points, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise PointCloudError(f"points must be numeric, got {type(points).__name__}"
                                  ) from exc
    if points.dtype.kind not in "fiu":
        raise PointCloudError(f"points must be numeric, got an array of {points.dtype}")
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise PointCloudError(f"points must be a non-empty (n, 3) array, got {points.shape}")
    return ingest(((s, points[s:s + CHUNK]) for s in range(0, len(points), CHUNK)),
                  len(points), scratch)


# ---------------------------------------------------------------------------
# the tile index


@dataclass
class TileIndex:
    """A uniform grid over the bounding box; the non-empty cells are the tiles.

    Cells are ``sides`` long on each axis (``side``, the grid's nominal cell
    side, or less: see ``build_index``).  ``order`` lists the rows cell by cell
    (input order within a cell), and ``start[c]:start[c + 1]`` are cell ``c``'s;
    ``xyz`` holds the positions in that order, so that a tile's cells are read
    as contiguous stretches, whatever order the input came in.
    """

    lo: np.ndarray
    side: float
    sides: np.ndarray
    shape: tuple
    order: np.ndarray
    start: np.ndarray
    cells: np.ndarray  # non-empty cell ids
    coords: np.ndarray  # their (i, j, k)
    xyz: np.ndarray  # (n, 3) positions in ``order``

    def cell_box(self, c: int):
        ijk = np.array(np.unravel_index(c, self.shape))
        lo = self.lo + ijk * self.sides
        return lo, lo + self.sides

    def core_rows(self, c: int) -> np.ndarray:
        return np.asarray(self.order[self.start[c]:self.start[c + 1]])


def _cell_ids(xyz, lo, sides, shape) -> np.ndarray:
    """The C-order number of each row's grid cell, ⌊(x − lo) / side⌋ per
    axis clipped to the grid (``_kernels.cell_ids`` when compiled; this is
    its NumPy reference)."""
    from pcprep.filters import _kernels

    xyz = np.asarray(xyz, dtype=np.float64)
    if _kernels.ENABLED:
        out = np.empty(len(xyz), dtype=np.int64)  # noqa: NPY-empty -- every row written
        _kernels.cell_ids(xyz, np.asarray(lo, dtype=np.float64),
                          np.asarray(sides, dtype=np.float64),
                          np.asarray(shape, dtype=np.int64), out)
        return out
    ijk = np.floor((xyz - lo) / sides).astype(np.int64)
    ijk = np.clip(ijk, 0, np.array(shape) - 1)
    return np.ravel_multi_index(ijk.T, shape)


def _grid(src: Source, side: float, fit: bool = True) -> tuple:
    """The grid's shape and its cells' sides for a nominal cell ``side``: with
    ``fit`` the sides shrink so that the cells fill the bounding box exactly,
    since a last row of cells only a sliver wide would be a tile with a few core
    points and a full halo (its cost is the halo's, its output nearly nothing)."""
    ext = np.maximum(src.hi - src.lo, 1e-300)
    shape = np.maximum(1, np.ceil(ext / side))
    sides = ext / shape if fit else np.full(3, float(side))
    return tuple(int(v) for v in shape), sides


#: the finest grid the side search tries: this many cells on the longest axis
_MOST_CELLS = 2000


def _fit_side(src: Source, sample: np.ndarray, n: int, target: int) -> float:
    """The largest cell side whose fitted grid leaves at most ``target`` rows
    per non-empty cell on average (counted on ``sample``, scaled to ``n``).
    A fitted grid depends on the side only through its shape, ⌈ext_a / side⌉
    per axis, which changes only where the side crosses ext_a / k for an axis
    a and a count k: the search is a bisection over one side inside each
    interval between those points (occupancy grows as the side shrinks), so
    about 13 counts of the sample settle the grid exactly."""
    ext_all = np.maximum(src.hi - src.lo, 1e-300)
    finest = float(ext_all.max()) / _MOST_CELLS
    k = np.arange(1, _MOST_CELLS + 1)
    cuts = np.unique((ext_all[:, None] / k[None, :]).ravel())
    cuts = cuts[cuts >= finest]
    cand = np.sqrt(cuts[:-1] * cuts[1:])  # one side strictly inside each interval
    lo, hi = -1, len(cand)  # cand[lo] fits (lo = -1: none does; the finest grid)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        shape, sides = _grid(src, float(cand[mid]))
        if n / _occupied(_cell_ids(sample, src.lo, sides, shape), math.prod(shape)) > target:
            hi = mid
        else:
            lo = mid
    return float(cand[lo]) if lo >= 0 else finest


def _occupied(ids: np.ndarray, ncell: int) -> int:
    """How many distinct cells ``ids`` holds: by marking a byte per cell when
    the grid is at most 16 bytes per id, else by sorting (``np.unique`` hashes,
    several times slower on fine grids)."""
    if ncell <= 16 * len(ids):
        seen = np.zeros(ncell, dtype=bool)
        seen[ids] = True
        return int(np.count_nonzero(seen))
    s = np.sort(ids)
    return int(np.count_nonzero(s[1:] != s[:-1])) + 1 if len(s) else 0


def _fill_cells(ids, pts, row0: int, fill, order, xyz) -> None:
    """Place a chunk's rows (input rows ``row0 + i``, cells ``ids``) in cell
    order: row i goes to slot ``fill[ids[i]]`` of ``order`` and ``xyz``, which
    then moves on, so a cell's rows keep their input order
    (``_kernels.cell_fill`` when compiled; this is its NumPy reference)."""
    from pcprep.filters import _kernels

    if _kernels.ENABLED:
        _kernels.cell_fill(ids, pts, row0, fill, np.asarray(order), np.asarray(xyz))
        return
    srt = np.argsort(ids, kind="stable")
    uniq, first, cnt = np.unique(ids[srt], return_index=True, return_counts=True)
    for c, f, m in zip(uniq, first, cnt):
        rows = srt[f:f + m]
        order[fill[c]:fill[c] + m] = rows + row0
        xyz[fill[c]:fill[c] + m] = pts[rows]
        fill[c] += m


def build_index(src: Source, target: int, scratch: str, side: float | None = None
                ) -> TileIndex:
    """Tiles of about ``target`` core points: the grid side is chosen on a
    subsample (every m-th row) so that the non-empty cells hold at most
    ``target`` points on average; then one pass counts the rows per cell and a
    second writes their order and their positions in that order.  A ``side``
    given is kept as it is (cubic cells from the box's low corner, to align
    with a grid the data has); a chosen one is fitted to the box (``_grid``)."""
    n = src.n
    fit = side is None
    ext = float(np.max(src.hi - src.lo))
    if side is not None:
        if not side > 0:
            raise InvalidParameterError(f"grid_side must be positive, got {side!r}")
    elif n <= target or ext <= 0:
        side = max(ext, 1e-300) * (1 + 1e-9)
    else:
        step = max(1, n // 200_000)
        side = _fit_side(src, np.ascontiguousarray(src.xyz[::step]), n, target)
    shape, sides = _grid(src, side, fit)
    ncell = int(np.prod(shape))
    counts = np.zeros(ncell, dtype=np.int64)
    for s in range(0, n, CHUNK):
        counts += np.bincount(_cell_ids(src.xyz[s:s + CHUNK], src.lo, sides, shape),
                              minlength=ncell)
    start = np.zeros(ncell + 1, dtype=np.int64)
    np.cumsum(counts, out=start[1:])
    order = open_scratch(os.path.join(scratch, "order.npy"), n, np.int64)
    xyz = open_scratch(os.path.join(scratch, "xyz_cells.npy"), (n, 3))
    fill = start[:-1].copy()
    for s in range(0, n, CHUNK):
        pts = np.asarray(src.xyz[s:s + CHUNK], dtype=np.float64)
        _fill_cells(_cell_ids(pts, src.lo, sides, shape), pts, s, fill, order, xyz)
    cells = np.flatnonzero(counts)
    coords = np.array(np.unravel_index(cells, shape)).T
    return TileIndex(src.lo.copy(), float(side), sides, shape, order, start, cells, coords,
                     xyz)


def _spans(src: Source, index: TileIndex, c: int, halo: float):
    """Where the extended region of cell ``c`` lies in ``index.order``: one
    ``(is_core, start, end)`` row per cell near enough to reach the box of
    ``c`` grown by ``halo``, and that box (the cloud's outer sides stay open:
    ±inf).  A few hundred bytes that say which rows to read, so a task can
    cut its own points (``_cut``)."""
    lo, hi = index.cell_box(c)
    blo, bhi = lo - halo, hi + halo
    blo = np.where(blo <= src.lo, -np.inf, blo)
    bhi = np.where(bhi >= src.hi, np.inf, bhi)
    m = np.ceil(halo / index.sides)
    ijk = np.array(np.unravel_index(c, index.shape))
    near = index.cells[(np.abs(index.coords - ijk) <= m).all(axis=1)]
    spans = np.c_[near == c, index.start[near], index.start[near + 1]].astype(np.int64)
    return spans, blo, bhi


def _cut(xyz, order, spans, blo, bhi):
    """The rows of the extended region that ``_spans`` described, ascending,
    their positions and the core mask: a near cell's rows are kept where they
    lie in the box, the cell's own all.  ``xyz`` holds the positions in
    ``order`` (``TileIndex.xyz``): each cell is one contiguous read."""
    rows, pos, core = [], [], []
    for is_core, s, e in spans:  # each cell's rows are ascending, read once
        r = np.array(order[s:e])
        p = np.array(xyz[s:e])
        if not is_core:
            inside = ((p >= blo) & (p <= bhi)).all(axis=1)
            r, p = r[inside], p[inside]
        rows.append(r)
        pos.append(p)
        core.append(np.full(len(r), bool(is_core)))
    for a in (xyz, order):
        if isinstance(a, Stored):
            a.drop()
    rows = np.concatenate(rows)
    order = np.argsort(rows, kind="stable")  # merges the ascending runs
    return rows[order], np.concatenate(pos)[order], np.concatenate(core)[order]


# ---------------------------------------------------------------------------
# the engine


@contextmanager
def dask_client(client=None, *, workers: int | None = None, scheduler: str | None = None,
                memory_budget: str | int | None = None, threads: int | None = None):
    """The client to run on: ``client`` as given, one attached to ``scheduler``,
    or a new ``LocalCluster`` of ``workers`` processes (default: the cores) with
    ``memory_budget`` per worker (default: the machine's memory shared out)
    and ``threads`` each (default: the cores shared out among them; each
    thread runs one tile task on one core, ``_one_thread``); what this starts
    it closes."""
    local = {k: v for k, v in (("workers", workers), ("memory_budget", memory_budget),
                               ("threads", threads)) if v is not None}
    if local and (client is not None or scheduler is not None):
        raise InvalidParameterError(
            f"{' and '.join(local)} size a local cluster; a running one "
            f"({'client' if client is not None else 'scheduler'}) has its own workers")
    for name, v in (("workers", workers), ("threads", threads)):
        if v is not None and (not isinstance(v, (int, np.integer)) or isinstance(v, bool)
                              or v < 1):
            raise InvalidParameterError(f"{name} must be a positive count, got {v!r}")
    budget = worker_budget(memory_budget)
    if client is not None:
        yield client
        return
    import dask
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        from distributed.comm import get_address_host_port, normalize_address

        try:  # checked before a Client is made: one that fails leaves Dask's loop broken
            get_address_host_port(normalize_address(scheduler))
        except (ValueError, TypeError, AttributeError) as exc:
            raise InvalidParameterError(f"scheduler {scheduler!r}: {exc} (give an address "
                                        "such as tcp://host:8786)") from None
        with Client(scheduler) as c:  # an unreachable one: OSError, with the address
            _warm_workers(c)
            yield c
        return
    nw = workers or os.cpu_count() or 1
    per = threads or max(1, (os.cpu_count() or 1) // nw)  # the cores shared out, as Dask does
    for name in ("distributed", "tornado"):  # their lifecycle chatter is not ours to print
        logging.getLogger(name).setLevel(logging.WARNING)
    with dask.config.set(_quiet_monitors()), \
            LocalCluster(n_workers=nw, threads_per_worker=per, processes=True,
                         memory_limit=budget, dashboard_address=":0",
                         silence_logs=logging.ERROR) as cluster, Client(cluster) as c:
        log.info("dask: %d local worker(s) of %d thread(s); dashboard %s", nw, per,
                 c.dashboard_link)
        yield c


#: resident memory of a worker at rest once every filter's modules and compiled
#: kernels are loaded and it has run tiles (measured 227 MiB after small tiles,
#: 283 MiB after the test suite's: Python 3.11, NumPy, SciPy, numba, Dask, and
#: the heap its tasks leave), with a margin; the memory budget's part that tiles
#: cannot use
WORKER_AT_REST = 384 << 20
#: the smallest memory budget per worker ``dask_client`` accepts: a worker at rest
#: takes half of it, leaving the other half for tiles.  Below about
#: ``WORKER_AT_REST`` Dask's nanny restarts the idle worker for ever (it stops a
#: worker at 95 % of its budget, and a worker that dies with no task running is
#: not counted against any task), so the run would hang instead of failing
MIN_BUDGET = 2 * WORKER_AT_REST


def worker_budget(memory_budget) -> str | int:
    """``memory_budget`` as ``LocalCluster`` takes it: ``"auto"`` (the
    machine's memory shared out) for None or ``"auto"``, else bytes, from a
    positive int or a size Dask reads (``"4GB"``, ``"500MiB"``, ``"2e9"``);
    refused below ``MIN_BUDGET`` or unreadable, naming the value."""
    if memory_budget is None or memory_budget == "auto":
        return "auto"
    from dask.utils import parse_bytes

    what = f"memory_budget {memory_budget!r}"
    if isinstance(memory_budget, str):
        try:
            value = parse_bytes(memory_budget)
        except ValueError:
            raise InvalidParameterError(
                f"{what}: not a size (give bytes or a size such as 4GB or 500MiB)") from None
    elif isinstance(memory_budget, (int, np.integer)) and not isinstance(memory_budget, bool):
        value = int(memory_budget)
    else:
        raise InvalidParameterError(f"{what}: not a size (give bytes or a size such as 4GB)")
    if value < MIN_BUDGET:
        raise InvalidParameterError(
            f"{what} per worker is below the {MIN_BUDGET >> 20} MiB a worker needs: about "
            f"{WORKER_AT_REST >> 20} MiB at rest, the rest for its tiles")
    return value


#: Dask settings of the clusters ``dask_client`` starts, where the user has set
#: none: the workers' statistical profiler (a stack sample every 10 ms, for the
#: dashboard's profile page) off, the event-loop tick every 500 ms instead of
#: 20 ms and the system monitor every 5 s instead of 0.5 s.  Together they cost
#: about 7 % of a core per process at rest, which on a small machine the
#: workers lose to their own monitoring; the nanny's memory monitor, which
#: enforces the memory budget, keeps its 100 ms.
QUIET_MONITORS = {"distributed.worker.profile.enabled": False,
                  "distributed.admin.tick.interval": "500ms",
                  "distributed.admin.system-monitor.interval": "5s"}


def _quiet_monitors() -> dict:
    """``QUIET_MONITORS`` without the keys the user's Dask configuration (its
    YAML files and ``DASK_*`` environment variables) sets."""
    import dask

    user = dask.config.collect()
    return {k: v for k, v in QUIET_MONITORS.items()
            if dask.config.get(k, default=None, config=user) is None}


def _warm_workers(client) -> None:
    """Have every worker of a cluster attached by address load the tile tasks'
    modules and make numba's first call (about 0.8 s per process) now, while
    the driver reads the input and builds the index, instead of in its first
    task (``warmup``).  Not on the local clusters ``dask_client`` starts: their
    workers share the driver's cores, and there the warm-up slowed the ingest
    by more than it saved (docs/decisions/scale.md, twelfth round)."""
    from . import warmup

    client.run(warmup.start, wait=False)


def tile_target(tiles, client, n: int) -> int:
    """Core points per tile: ``tiles`` as an int, or from the memory budget
    (``"auto"``): a task's extended region (about twice its core) must fit
    its share of what a worker's memory limit leaves above ``WORKER_AT_REST``
    (a worker runs as many tasks at once as it has threads),
    ``BYTES_PER_POINT`` bytes per point."""
    if tiles is None or tiles == "auto":
        rooms = [((w.get("memory_limit") or 4 << 30) - WORKER_AT_REST) // w.get("nthreads", 1)
                 for w in _workers(client)]
        room = max(0, min(rooms, default=(4 << 30) - WORKER_AT_REST))
        return int(max(10_000, min(n, room // (2 * BYTES_PER_POINT))))
    t = int(tiles)
    if t < 1:
        raise InvalidParameterError(f"tiles must be 'auto' or a positive count, got {tiles!r}")
    return t


def _workers(client) -> list:
    """The scheduler's record of each of the client's workers."""
    return list(client.scheduler_info()["workers"].values())


def _slots(client) -> int:
    """Tasks the client's workers run at once: their threads."""
    return sum(w.get("nthreads", 1) for w in _workers(client))


def _worker_limit(client) -> int:
    """The smallest memory limit of the client's workers in bytes; 0 when
    none has one."""
    limits = [w.get("memory_limit") or 0 for w in _workers(client)]
    return min(limits) if limits and min(limits) > 0 else 0


class WorkersLostError(RuntimeError):
    """A tile's task killed every worker that ran it (Dask's ``KilledWorker``),
    which usually means a tile needs more memory than a worker's budget."""


def _lost_workers(command: str, limit: int, target: int) -> WorkersLostError:
    """The ``WorkersLostError`` of a ``KilledWorker`` in a run of tiles of
    ``target`` core points on workers of memory limit ``limit`` (as the run
    began: the workers being restarted are not listed): what was lost, the
    likely cause and the remedy."""
    import dask

    budget = f"{limit / 2**20:.0f} MiB per worker" if limit else "no limit set"
    tries = dask.config.get("distributed.scheduler.allowed-failures", 3) + 1
    return WorkersLostError(
        f"{command}: a tile's task killed each of the {tries} workers that ran it; the "
        f"usual cause is a tile that needs more memory than a worker has (memory budget: "
        f"{budget}, tiles of {target} core points): give smaller tiles (--tiles N, "
        f"tiles=N) or a larger memory budget (--memory-budget)")


def _submit(client, fn, *args, **kwargs):
    """``client.submit`` of a task that carries its inputs: its points, or
    where the workers share the scratch folder the paths of the stored arrays
    it reads (``Stored``).  They travel inside the task, not scattered
    beforehand: a scattered array dies with its worker, while a task that
    holds its data can be run again elsewhere, which is how a lost worker
    costs nothing.  Dask's warning about large task
    graphs is therefore expected here and not shown.  The task runs on one
    thread (``_one_thread``) and keeps ``fn``'s name in Dask's dashboard."""
    import uuid
    import warnings

    key = f"{getattr(fn, '__name__', 'task')}-{uuid.uuid4().hex}"
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sending large graph",
                                category=UserWarning)
        return client.submit(_one_thread, fn, *args, key=key, pure=False, **kwargs)


def _one_thread(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` with the kernels and tree queries on one thread
    (``_kernels.single_threaded``): on a worker, a task keeps one core busy,
    the worker's threads being the parallelism."""
    from pcprep.filters._kernels import single_threaded

    with single_threaded():
        return fn(*args, **kwargs)


class Stored:
    """A per-row array in the scratch folder, named by its path: what tiles
    read their inputs from and write their results into, on the workers when
    they share the driver's scratch folder (``_Runner.shared``), else on the
    driver.  It pickles
    as the path alone and maps the file on first use in each process; a
    worker drops its maps at the end of every task (``release``), so that the
    pages it touched do not stay in its resident memory, which Dask's memory
    monitor watches.  Tasks given the arrays themselves would carry copies:
    a memory map pickles as its contents."""

    _maps: dict = {}  # path -> this process's memory map of it

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        return Stored, (self.path,)

    @property
    def array(self) -> np.ndarray:
        a = Stored._maps.get(self.path)
        if a is None:
            a = Stored._maps[self.path] = np.load(self.path, mmap_mode="r+")
        return a

    def __getitem__(self, key):
        return self.array[key]

    def __setitem__(self, key, value):
        self.array[key] = value

    def drop(self) -> None:
        """Let go of the pages of this array the process has touched: they
        leave its resident memory and stay in the page cache, written or not
        (``MADV_DONTNEED`` on a shared file mapping keeps the file's contents
        up to date), so the next touch finds them there."""
        mm = getattr(Stored._maps.get(self.path), "_mmap", None)
        if mm is not None and hasattr(mmap, "MADV_DONTNEED"):
            mm.madvise(mmap.MADV_DONTNEED)

    @staticmethod
    def release() -> None:
        Stored._maps.clear()


def _blocks(idx: np.ndarray, a: np.ndarray):
    """Slices of ascending row numbers ``idx`` that touch at most
    ``MAPPED_BYTES`` of ``a``'s pages each (a row of ``a`` lies on one page,
    two at a page boundary)."""
    step = max(1, MAPPED_BYTES // max(mmap.PAGESIZE, a[:1].nbytes or 1))
    for s0 in range(0, max(len(idx), 1), step):
        yield slice(s0, s0 + step)


def _gather(a: Stored, idx: np.ndarray) -> np.ndarray:
    """``a[idx]`` for ascending ``idx``, read in blocks, each block's pages
    dropped after it (``Stored.drop``): rows of one tile lie scattered over
    the whole array when the input is not in spatial order, and a task that
    kept every page it touched would hold a share of the array that grows
    with the cloud, counted in its resident memory by the kernel and by
    Dask's memory monitor."""
    arr = a.array
    shape = (len(idx),) + arr.shape[1:]
    out = np.empty(shape, dtype=arr.dtype)  # noqa: NPY-empty -- every row written
    for b in _blocks(idx, arr):
        out[b] = arr[idx[b]]
        a.drop()
    return out


def _scatter(a: Stored, idx: np.ndarray, values: np.ndarray,
             column: int | None = None) -> None:
    """``a[idx] = values`` (of ``a[column]`` when given) for ascending
    ``idx``, by blocks as ``_gather`` reads."""
    arr = a.array if column is None else a.array[column]
    for b in _blocks(idx, arr):
        arr[idx[b]] = values[b]
        a.drop()


def _read(reads: dict | None, rows: np.ndarray, core: np.ndarray) -> dict:
    """A tile's per-row inputs: ``{arg: (stored, how)}`` gives ``arg`` the
    stored rows of the extended region (``how="rows"``) or, for
    ``"first_core"``, ``(i, stored[rows[i]])`` of the tile's first core row
    ``i``."""
    out = {}
    for arg, (src, how) in (reads or {}).items():
        if src is None:
            out[arg] = None
        elif how == "rows":
            out[arg] = _gather(src, rows)
        else:
            i = int(np.flatnonzero(core)[0])
            out[arg] = (i, np.array(src[rows[i]]))
    return out


def _finish(cell, rows, core, res, writes, reduce) -> dict:
    """A tile's exact result written where it goes: ``reduce(cell, rows,
    core, res)`` (the small part the driver gathers: sums, a sample of the
    overlap) into ``res["reduced"]``, then each ``(stored, key, how)`` of
    ``writes`` from ``res[key]`` into the rows of the core: ``how`` says
    whether ``res[key]`` holds the extended region's rows (``"ext"``), the
    core's (``"core"``) or the core's as a (d, m) block of columns
    (``"columns"``); a key whose value is None, or whose ``stored`` is None,
    is skipped.  The written keys leave ``res``: what remains is what the
    driver is sent."""
    if reduce is not None:
        res["reduced"] = reduce(cell, rows, core, res)
    r = rows[core]
    for dst, key, how in writes or ():
        v = res.pop(key)
        if v is None or dst is None:
            continue
        if how == "ext":
            _scatter(dst, r, v[core])
        elif how == "core":
            _scatter(dst, r, v)
        else:
            _store_columns(dst, r, v)
    return res


#: what a worker-I/O task returns when it runs where the scratch folder is
#: not (``_at_home``): the driver then does its I/O
ELSEWHERE = "elsewhere"


def _tile_task(fn, cell, xyz, order, spans, blo, bhi, args, reads, writes, reduce, home):
    """One tile, run where the scratch folder is shared: the worker cuts its
    extended region from the stored positions and index (``_cut``), reads
    its per-row inputs, runs ``fn`` and, when the tile is exact, writes its
    core rows' results (``_finish``).  A task run twice (its worker lost)
    writes the same values again.  A worker that is not where the folder is
    (``home``, see ``_at_home``) touches nothing and says so."""
    if not _at_home(home):
        return {"exact": False, ELSEWHERE: True}
    try:
        rows, pts, core = _cut(xyz, order, spans, blo, bhi)
        res = fn(pts, blo, bhi, core, **args, **_read(reads, rows, core))
        if "duplicate" in res:  # nothing written: the run stops
            return dict(res, duplicate=tuple(int(r) for r in rows[list(res["duplicate"])]))
        if res["exact"]:
            _finish(cell, rows, core, res, writes, reduce)
        return res
    finally:
        Stored.release()


def _rows_task(fn, read, s0, e, shared, arg, writes, home):
    """``fn`` on rows ``[s0, e)`` read from the stored array ``read[0]`` (as
    rows, or as a (d, m) block of columns when ``read[1] == "columns"``), its
    parts written into ``writes`` on the worker (``_map_rows``); ``ELSEWHERE``
    from a worker that is not where the folder is (``_at_home``)."""
    if not _at_home(home):
        return ELSEWHERE
    try:
        part = fn(_read_rows(read, s0, e), shared, arg)
        _write_rows(writes, s0, part)
    finally:
        Stored.release()


def _read_rows(read, s0, e):
    src, how = read
    out = np.ascontiguousarray(src[:, s0:e]) if how == "columns" else np.array(src[s0:e])
    src.drop()
    return out


def _write_rows(writes, s0, part) -> None:
    for dst, v in zip(writes, part if isinstance(part, tuple) else (part,)):
        dst[s0:s0 + len(v)] = v
        dst.drop()


def _probe(path: str):
    import socket

    try:
        with open(path) as f:
            return socket.gethostname(), f.read()
    except OSError:
        return socket.gethostname(), None


def _at_home(home) -> bool:
    """Whether this process runs on the host ``home = (host, path, token)``
    names and reads ``token`` in ``path`` (in the scratch folder).  Every
    worker-I/O task asks first: a worker that joined the cluster after
    ``_shares_scratch`` asked the others, from another host, must not write
    through a mapping of its own."""
    return _probe(home[1]) == (home[0], home[2])


def _shares_scratch(client, scratch: str):
    """``home`` for ``_at_home`` if every worker runs on this host and reads
    this scratch folder, else None: a file with a random token is written and
    each worker asked for its host name and the token it reads.  Only then
    may tasks write into the stored arrays (workers on other hosts reaching
    the folder over a network file system would write back whole pages, over
    other tiles' rows).  Where it says yes, the file stays for the tasks to
    check (``_Runner.close`` removes it)."""
    import secrets
    import socket

    token = secrets.token_hex(16)
    path = os.path.join(scratch, f"probe-{token}")
    with open(path, "w") as f:
        f.write(token)
    home = (socket.gethostname(), path, token)
    shared = False
    try:
        got = client.run(_probe, path)
        shared = bool(got) and all(v == (home[0], token) for v in got.values())
    finally:
        if not shared:
            with suppress(OSError):
                os.remove(path)
    return home if shared else None


def _in_folder(values, folder: str) -> bool:
    """Is ``values`` a whole float64 ``.npy`` memory map in ``folder``."""
    return (isinstance(values, np.memmap) and isinstance(values.base, mmap.mmap)
            and values.dtype == np.float64 and values.filename is not None
            and values.filename.endswith(".npy")
            and os.path.dirname(values.filename) == os.path.abspath(folder))


class _Runner:
    """One pass over the tiles: submit, collect, re-run a tile whose halo was
    too narrow with a wider one, and check that every core row came once.
    ``store`` gives the per-row arrays, on disk in the scratch folder.

    Where the workers share the scratch folder (``shared``: a local cluster,
    by default detected) a task is sent where its region lies (``_spans``)
    and the handles of the arrays it reads and writes (``Stored``), and the
    worker does the cutting, the reading and the writing; elsewhere the
    driver cuts each region, sends its points and writes the results.  Both
    run the same ``_cut``, ``_read`` and ``_finish``, so they give the same
    bits; the first keeps the driver's CPU, which the workers' cores share on
    one machine, out of the per-row work."""

    def __init__(self, client, src: Source, index: TileIndex, scratch: str, on_result=None,
                 shared: bool | None = None, func: str | None = "run_tiled"):
        self.client, self.src, self.index, self.func = client, src, index, func
        self.scratch, self.on_result = scratch, on_result
        mapped = isinstance(index.xyz, np.memmap) and isinstance(index.order, np.memmap)
        self.home = _shares_scratch(client, scratch) if mapped and shared is not False \
            else None
        if shared and not self.home:
            raise InvalidParameterError(f"worker_io: the workers do not all run on this host "
                                        f"with the scratch folder {scratch}")
        self.shared = bool(self.home)
        self.moved = 0  # worker-I/O tasks redone with the driver's I/O (``_at_home``)
        if self.shared:
            self.xyz_h, self.order_h = self.handle(index.xyz), self.handle(index.order)
        self.halo = {}  # cell -> the halo that proved wide enough
        self.times = {}  # pass label -> wall seconds
        self.cpu = {}  # pass label -> the driver's CPU seconds (all its threads)
        self.cpu_main = {}  # pass label -> of those, the calling thread's (pcprep's own work)
        self.passes = 0

    def store(self, name: str, shape, dtype=np.float64) -> np.ndarray:
        """A zero-filled memory map ``scratch/name.npy``: every per-row array
        the driver keeps lives on disk, so that the driver's own memory does not
        grow with the cloud (the kernel writes its pages back and drops them as
        memory runs short).  Whole-cloud reductions read it in place, so they
        give the one-piece run's values to the last bit."""
        path = os.path.join(self.scratch, name + ".npy")
        if os.path.exists(path):
            raise InvalidParameterError(f"scratch folder {self.scratch} already holds "
                                        f"{name}.npy (from another run?); give an empty one")
        return open_scratch(path, shape, dtype)

    def close(self) -> None:
        """Remove the file ``_at_home`` reads."""
        if self.home:
            with suppress(OSError):
                os.remove(self.home[1])

    def _moved(self, what: str) -> None:
        if not self.moved:
            log.warning("a worker does not share the scratch folder %s (another host?): "
                        "%s redone with the driver reading and writing", self.scratch, what)
        self.moved += 1

    @staticmethod
    def handle(arr):
        """The ``Stored`` handle of a stored array (None stays None)."""
        return None if arr is None else Stored(os.path.abspath(arr.filename))

    def on_disk(self, name: str, values: np.ndarray) -> np.ndarray:
        """``values`` copied into ``store(name)``, chunk by chunk (the
        temporary that made them is freed by the caller)."""
        out = self.store(name, values.shape, values.dtype)
        for s0 in range(0, len(values), CHUNK):
            out[s0:s0 + CHUNK] = values[s0:s0 + CHUNK]
        return out

    def stored(self, name: str, values: np.ndarray) -> np.ndarray:
        """``values`` as a stored array: itself where it is a whole float64
        ``.npy`` memory map in the scratch folder (the command line streams a
        file's normals there; a view's base is its parent map, not the file's),
        else ``on_disk(name, values)``."""
        return values if _in_folder(values, self.scratch) else self.on_disk(name, values)

    def rows_where(self, name: str, mask: np.ndarray, value: bool = True) -> np.ndarray:
        """The rows where ``mask`` is ``value``, ascending, into ``store(name)``
        (int64), chunk by chunk: ``np.flatnonzero`` with no temporary of the
        cloud's length."""
        def picks(s0):
            part = np.asarray(mask[s0:s0 + CHUNK])
            return part if value else ~part

        starts = range(0, len(mask), CHUNK)
        out = self.store(name, sum(int(np.count_nonzero(picks(s0))) for s0 in starts), np.int64)
        at = 0
        for s0 in starts:
            rows = np.flatnonzero(picks(s0)) + s0
            out[at:at + len(rows)] = rows
            at += len(rows)
        return out

    def map(self, name: str | None, fn, *arrays, dtype=np.float64, out=None) -> np.ndarray:
        """``fn(*chunks)`` over row chunks of ``arrays`` into ``store(name)``
        (or into ``out``): for element-wise rules, whose values do not depend
        on the chunking."""
        n = len(arrays[0])
        for s0 in range(0, n, CHUNK):
            part = fn(*(np.asarray(a[s0:s0 + CHUNK]) for a in arrays))
            if out is None:
                out = self.store(name, (n,) + part.shape[1:], dtype)
            out[s0:s0 + len(part)] = part
        return out

    def run(self, label: str, fn, halo: float, args: dict, writes=(), reads=None,
            reduce=None, collect=None) -> None:
        """``fn(points, lo, hi, core, **args, **inputs)`` on every tile, its
        ``inputs`` read from stored arrays as ``reads`` says (``_read``); each
        exact result's rows written as ``writes`` says and its small part made
        by ``reduce`` (``_finish``); ``collect(cell, res)`` then gets what
        remains of the result on the driver.  ``writes`` and ``reads`` name
        stored arrays (``store``).  A halo that proved too narrow for one tile
        is too narrow for the others of the same cloud as a rule, so the
        tiles not yet sent start at the widened halo (results are the same:
        every tile is checked)."""
        import time

        from dask.distributed import as_completed

        t0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
        writes = [(self.handle(a), key, how) for a, key, how in writes]
        reads = {k: (self.handle(a), how) for k, (a, how) in (reads or {}).items()}
        cells = [int(c) for c in self.index.cells]
        width = {c: max(halo, self.halo.get(c, 0.0)) for c in cells}
        floor = 0.0  # the widest halo a tile of this pass proved too narrow, grown
        self.passes += 1
        if self.passes == 1 and self.func:  # a filter's first pass also looks for duplicates
            fn = functools.partial(_with_duplicate_check, fn)
            args = dict(args, caller=self.func)
        seen = self.store(f"seen-{self.passes}", self.src.n, np.int8)
        queue = list(cells)
        direct = set()  # cells a worker away from the scratch folder sent back
        limit = IN_FLIGHT * max(1, _slots(self.client))
        futures = as_completed()
        meta = {}
        with progress.step(f"{label} tiles", len(cells)) as advance:
            def submit():
                while queue and futures.count() < limit:
                    c = queue.pop(0)
                    width[c] = max(width[c], floor)
                    spans, lo, hi = _spans(self.src, self.index, c, width[c])
                    if self.shared and c not in direct:
                        fut = _submit(self.client, _tile_task, fn, c, self.xyz_h,
                                      self.order_h, spans, lo, hi, args, reads, writes,
                                      reduce, self.home)
                        meta[fut.key] = (c, None, None)
                    else:
                        rows, pts, core = _cut(self.index.xyz, self.index.order, spans, lo,
                                               hi)
                        fut = _submit(self.client, fn, pts, lo, hi, core, **args,
                                      **_read(reads, rows, core))
                        meta[fut.key] = (c, rows, core)
                    futures.add(fut)
            submit()
            for fut in futures:
                c, rows, core = meta.pop(fut.key)
                res = fut.result()
                del fut
                if res.get(ELSEWHERE):
                    self._moved(f"{label}: tile {c}")
                    direct.add(c)
                    queue.insert(0, c)
                elif not res["exact"]:
                    if np.isinf(self.src.hi - self.src.lo).any() or \
                            width[c] > 4 * float(np.max(self.src.hi - self.src.lo)):
                        raise PointCloudError(f"{label}: tile {c} cannot be made exact")
                    short = res.get("short")
                    width[c] = (width[c] + short) * SHORT_MARGIN if short is not None \
                        else width[c] * GROW
                    floor = max(floor, width[c])
                    log.debug("%s: tile %d: halo widened to %.4g", label, c, width[c])
                    queue.insert(0, c)
                else:
                    if "duplicate" in res:
                        i, j = res["duplicate"] if rows is None else rows[list(res["duplicate"])]
                        raise duplicate_error(res["caller"], None, *sorted((int(i), int(j))))
                    self.halo[c] = width[c]
                    if rows is not None:  # the driver's I/O
                        _finish(c, rows, core, res, writes, reduce)
                    seen[self.index.core_rows(c)] += 1
                    if collect is not None:
                        collect(c, res)
                    advance()
                    if self.on_result is not None:
                        self.on_result(label, c)
                submit()
        self.times[label] = self.times.get(label, 0.0) + time.perf_counter() - t0
        self.cpu[label] = self.cpu.get(label, 0.0) + time.process_time() - c0
        self.cpu_main[label] = self.cpu_main.get(label, 0.0) + time.thread_time() - m0
        for s0 in range(0, self.src.n, CHUNK):
            part = np.asarray(seen[s0:s0 + CHUNK])
            if not (part == 1).all():
                bad = (np.flatnonzero(part != 1)[:10] + s0).tolist()
                raise RuntimeError(f"{label}: rows {bad} were written "
                                   f"{sorted(set(seen[bad].tolist()))} times")
        path, seen = seen.filename, None
        Stored.release()  # the driver's own maps of what it read or wrote for the tasks
        with suppress(OSError):  # where a mapped file cannot be removed, rmtree does it later
            os.remove(path)


# ---------------------------------------------------------------------------
# tile functions (run on the workers)


def _spacing_tile(points, lo, hi, core, *, centre, n_total, k=None):
    """Every row's mean distance to its ``SPACING_K`` nearest neighbours (the
    rows of h) and, with ``k``, to its k nearest ("mean": the statistical
    outlier score before its division by h, which reads no h, so one pass
    gives both).  One query of max(k, SPACING_K) neighbours: the first
    distances of a longer query are those of a shorter one, so the rows are
    the same bits either way."""
    x = points - centre
    kk = max(k or 0, SPACING_K) + 1
    if len(x) < min(kk, n_total):
        return {"exact": False}
    d, _ = knn(x, min(kk, len(x)))
    miss = tile_miss(x[core], d[core, -1], lo - centre, hi - centre)
    if miss is not None:
        return miss
    out = {"exact": True, "rows": d[:, 1:SPACING_K + 1].mean(axis=1)}
    if k is not None:
        out["mean"] = d[:, 1:k + 1].mean(axis=1)
    return out


def _outlier_tile(points, lo, hi, core, *, centre, h, n_total, method, k, radius,
                  min_neighbors, std_ratio):
    """Pass 2 of the radius outlier test: every row's neighbour count within
    r·h, which reads nothing beyond r·h.  (The statistical test is one pass,
    ``_spacing_tile`` with its k.)"""
    x = points - centre
    tree = build_tree(x)
    counts = tree.query_ball_point(x, r=radius * h, return_length=True, workers=1)
    score = np.asarray(counts, dtype=np.float64) - 1.0
    reach = np.full(int(core.sum()), radius * h)
    miss = tile_miss(x[core], reach, lo - centre, hi - centre)
    if miss is not None:
        return miss
    return {"exact": True, "score": score}


# ---------------------------------------------------------------------------
# the filters, tiled


@dataclass
class TiledResult:
    """Per-row results of a tiled run, in input order (arrays or memory maps),
    and the run's facts (``stats``: tiles, passes, re-runs, halos)."""

    fields: dict
    h: float
    stats: dict


def run_tiled(name: str, points=None, normals=None, *, source: Source | None = None,
              params: dict | None = None, client=None, tiles="auto",
              workers: int | None = None, scheduler: str | None = None,
              memory_budget=None, threads: int | None = None,
              scratch: str | None = None, on_result=None,
              grid_side: float | None = None, worker_io: bool | None = None) -> TiledResult:
    """Run registered filter ``name`` tile by tile on Dask; the result of every
    row is the one a run over the whole cloud gives (see the module docstring).

    Parameters
    ----------
    name : str
        A registered filter (``apply_coord_denoise_l1_tv``, its command
        ``denoise``, …) that has a tiled form (``specs/*`` declare ``TILED``).
    points : (n, 3) float, optional
        The cloud, or ``source`` (streamed positions on disk).
    normals : (n, 3) float, optional
        Input normals, for the filters that take them (denoise, saliency,
        simplify), used as their one-piece run uses them; an array or a
        memory map (the CLI streams a file's normals into one).
    params : dict
        The filter's parameters (checked as the filter checks them).
    client : dask.distributed.Client, optional
        Run on this client; else ``scheduler`` (address) or a new local cluster
        of ``workers`` processes with ``memory_budget`` and ``threads`` each
        (``dask_client``).
    tiles : "auto" or int
        Core points per tile (``auto``: from the memory budget).
    scratch : str, optional
        A folder for the positions, the tile index and every per-row array the
        driver gathers (memory maps), which then stay there and are what
        ``fields`` holds; without one, a temporary folder is used and removed,
        and ``fields`` come back as arrays in memory.
    on_result : callable, optional
        ``on_result(pass_label, cell)`` after each tile's result (tests).
    grid_side : float, optional
        The tile grid's cell side in input units, instead of one chosen from
        ``tiles`` (to align tiles with a grid the data already has).
    worker_io : bool, optional
        Whether the workers cut their tiles from the stored positions and
        write their rows' results into the stored arrays themselves, which
        needs every worker on this host with the scratch folder (``True``:
        checked, refused otherwise), or the driver does and tasks carry their
        points (``False``: any cluster).  By default, the first wherever it
        is possible.  The results are the same bits either way.
    """
    from . import registry

    spec = _spec(registry, name)
    resolved = spec.resolve(dict(params or {}))
    if resolved.pop("preset", None) is not None:
        raise InvalidParameterError(f"{spec.command}: preset is not available with tiles; "
                                    "give its parameters explicitly")
    if resolved.get("adaptive_radius"):
        raise InvalidParameterError(f"{spec.command}: adaptive_radius is not available "
                                    "with tiles (a radius per point has no fixed halo); "
                                    "run it in one piece")
    own = scratch is None
    scratch = tempfile.mkdtemp(prefix="pcprep-tiles-") if own else scratch
    try:
        if source is None:
            source = source_from_array(points, scratch)
        _check_cloud(spec, source, resolved)
        if normals is not None:
            normals = _checked_normals(spec, normals, source.n)
        check_scratch(scratch, scratch_need(
            spec.command, resolved, source.n, positions=False,
            normals=None if normals is None else
            "stored" if _in_folder(normals, scratch) else "copy"), spec.command)
        with dask_client(client, workers=workers, scheduler=scheduler,
                         memory_budget=memory_budget, threads=threads) as cl:
            import time

            from distributed import KilledWorker

            t0 = time.perf_counter()
            target = tile_target(tiles, cl, source.n)
            limit = _worker_limit(cl)
            index = build_index(source, target, scratch, side=grid_side)
            t_index = time.perf_counter() - t0
            log.info("%s: %d points in %d tiles (grid side %.4g)", spec.command, source.n,
                     len(index.cells), index.side)
            runner = _Runner(cl, source, index, scratch, on_result, shared=worker_io,
                             func=spec.func.__name__)
            t1 = time.perf_counter()
            try:
                in_pass = _SPACING_IN_PASS.get(spec.command, lambda prm: False)(resolved)
                h = None if in_pass else _fit_spacing(runner, source, index)
                out = _FAMILIES[spec.command](runner, source, normals, h, resolved)
            except KilledWorker as exc:
                raise _lost_workers(spec.command, limit, target) from exc
            finally:
                runner.close()
            total = time.perf_counter() - t1
            out.stats.update(time_index=t_index, time_passes=dict(runner.times),
                             cpu_passes=dict(runner.cpu),
                             cpu_passes_main=dict(runner.cpu_main),
                             time_driver=total - sum(runner.times.values()),
                             tiles=len(index.cells), grid_side=index.side,
                             worker_io=runner.shared, moved_to_driver_io=runner.moved,
                             grid_shape=index.shape, target=target,
                             halo_max=max(runner.halo.values()) if runner.halo else 0.0)
            if own:  # the scratch folder goes: the fields come back as arrays
                out.fields = {k: np.array(v) if isinstance(v, np.memmap) else v
                              for k, v in out.fields.items()}
            return out
    finally:
        if own:
            shutil.rmtree(scratch, ignore_errors=True)


def _min_points(command: str, prm: dict) -> int:
    """The fewest points the filter's one-piece run takes (its ``as_points``
    check; a test compares the two for every tiled filter)."""
    from pcprep.filters.neighbors import SPACING_K
    from pcprep.filters.saliency import MIN_POINTS

    return {"outliers": lambda: max(prm["k"], SPACING_K) + 1,
            "denoise": lambda: SPACING_K + 1, "saliency": lambda: MIN_POINTS,
            "features": lambda: prm["k_max"] + 1, "holes": lambda: prm["k_max"] + 1,
            "simplify": lambda: prm["k"] + 1}[command]()


def _check_cloud(spec, src: Source, prm: dict) -> None:
    """The one-piece run's refusals of a cloud, before any tile: too few points,
    all coincident, all collinear (on the same strided sample, with the mean
    and the largest coordinate of the whole cloud).  Duplicate points are
    looked for by the tiles of the first pass (``_with_duplicate_check``)."""
    func = spec.func.__name__
    need = _min_points(spec.command, prm)
    if src.n < need:
        raise PointCloudError(f"{func}: needs at least {need} points for its "
                              f"neighbourhoods, got {src.n}")
    sample = np.asarray(src.xyz[:: max(1, src.n // 200_000)])
    largest = float(max(np.abs(src.lo).max(), np.abs(src.hi).max()))
    check_extent(sample, _chunked_mean(src.xyz), largest, func=func)


def _with_duplicate_check(fn, points, lo, hi, core, *, caller, **kw):
    """``fn`` on a tile of a run's first pass, which also looks for exact
    duplicates among the tile's core rows (two equal points lie in the same
    cell, so every pair is seen by one tile): ``duplicate = (i, j)``, rows of
    ``points``, in the result."""
    res = fn(points, lo, hi, core, **kw)
    if res.get("exact"):
        at = np.flatnonzero(core)
        dup = _duplicate_pairs(np.asarray(points)[at])
        if dup is not None:
            res = dict(res, duplicate=(int(at[dup[1]]), int(at[dup[2]])), caller=caller)
    return res


def _checked_normals(spec, normals, n: int):
    """The input normals a tiled run of ``spec`` reads, refused as a one-piece
    run refuses them (a filter that takes none, a row count that is not the
    points', a non-finite or zero-length row), checked chunk by chunk so that a
    memory map stays on disk."""
    if not spec.uses_normals:
        raise InvalidParameterError(f"{spec.command}: takes no input normals")
    func = spec.func.__name__
    if np.ndim(normals) != 2 or np.shape(normals)[1] != 3 or len(normals) != n:
        raise PointCloudError(f"{func}: normals has shape {np.shape(normals)}; expected "
                              f"({n}, 3), one per point")
    for s0 in range(0, n, CHUNK):
        block = np.asarray(normals[s0:s0 + CHUNK], dtype=np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            bad = ~(np.linalg.norm(block, axis=1) >= 1e-12) | ~np.isfinite(block).all(axis=1)
        if bad.any():
            rows = np.flatnonzero(bad) + s0
            shown = ", ".join(map(str, rows[:5])) + (", …" if len(rows) > 5 else "")
            raise PointCloudError(f"{func}: normals has zero-length or non-finite rows "
                                  f"(rows {shown}); give those rows a normal, or pass no "
                                  "normals to have them estimated")
    return normals if isinstance(normals, np.memmap) else np.asarray(normals, np.float64)


def _spec(registry, name: str):
    specs = registry.load_all()
    for s in specs.values():
        if name in (s.name, s.command):
            if s.command not in _FAMILIES:
                raise InvalidParameterError(
                    f"{s.command}: no tiled form (tiled: {', '.join(sorted(_FAMILIES))})")
            return s
    raise InvalidParameterError(f"unknown filter {name!r}")


def _fit_spacing(runner: _Runner, src: Source, index: TileIndex) -> float:
    """h over the whole cloud from every row's mean 6-NN distance (pass 1)."""
    return _h_from_rows(_spacing_pass(runner, src, index))


def _spacing_pass(runner: _Runner, src: Source, index: TileIndex) -> np.ndarray:
    """Every row's mean distance to its ``SPACING_K`` nearest neighbours, by
    tiles (a first halo of a twentieth of a cell, widened where it falls short)."""
    rows6 = runner.store("spacing", src.n)
    runner.run("spacing", _spacing_tile, _first_halo(index),
               {"centre": src.centre, "n_total": src.n}, [(rows6, "rows", "ext")])
    runner.halo.clear()
    return rows6


def spacing_rows(source: Source, client, scratch: str, tiles="auto") -> np.ndarray:
    """Every row of ``source``'s mean distance to its ``SPACING_K`` nearest
    neighbours (the rows of ``neighbors.spacing_from_rows``: h and the
    isolated points), by tiles on ``client``, as a memory map in ``scratch``:
    the filters' first pass on its own, for ``pcprep info`` on a cloud larger
    than memory.  Each row's value is the one-piece ``neighbors.spacing_rows``
    value up to rounding (the tiles work about the box centre); duplicate
    points are not refused (they only make rows small)."""
    if source.n <= SPACING_K:
        raise PointCloudError(f"spacing: needs more than {SPACING_K} points, got {source.n}")
    index = build_index(source, tile_target(tiles, client, source.n), scratch)
    runner = _Runner(client, source, index, scratch, func=None)
    try:
        return _spacing_pass(runner, source, index)
    finally:
        runner.close()


def _first_halo(index: TileIndex) -> float:
    """The halo of a pass that runs before h is known: a twentieth of a cell
    (tiles whose neighbours reach farther say by how much and run again)."""
    return 0.05 * float(index.sides.max())


def _h_from_rows(rows6: np.ndarray) -> float:
    h = spacing_from_rows(rows6)
    if not np.isfinite(h) or h <= 0:
        raise PointCloudError("every point coincides with its neighbours (h = 0)")
    return h


def _outliers(runner, src, normals, h, prm) -> TiledResult:
    """Tiled outlier removal.  Statistical: one pass gives every row's mean
    6-NN distance (h) and its mean k-NN distance, whose division by h is the
    score (``h`` comes in None: see ``_SPACING_IN_PASS``).  Radius: the
    counts within r·h need h, so they are a second pass."""
    from .specs.outliers import tile_hops

    if h is None:
        rows6 = runner.store("spacing", src.n)
        mean = runner.store("outlier_mean", src.n)
        runner.run("spacing and outlier scores", _spacing_tile,
                   _first_halo(runner.index),
                   dict(centre=src.centre, n_total=src.n, k=prm["k"]),
                   [(rows6, "rows", "ext"), (mean, "mean", "ext")])
        h = _h_from_rows(rows6)
        score = runner.map("outlier_score", lambda m: m / h, mean)
        passes = 1
    else:  # radius
        passes = 2
        score = runner.store("outlier_score", src.n)
        args = dict(centre=src.centre, h=h, n_total=src.n, **prm)
        runner.run("outliers", _outlier_tile, (prm["radius"] + tile_hops(prm)) * h, args,
                   [(score, "score", "ext")])
    if prm["method"] == "statistical":
        mean, std = mean_std(score)  # np.mean and np.std's values, read in chunks
        threshold = mean + prm["std_ratio"] * std
        out = runner.map("outlier", lambda v: v > threshold, score, dtype=bool)
    else:
        threshold = float(prm["min_neighbors"])
        out = runner.map("outlier", lambda v: v < threshold, score, dtype=bool)
    keep_idx = runner.rows_where("keep_idx", out, False)
    removed_idx = runner.rows_where("removed_idx", out)
    return TiledResult({"keep_idx": keep_idx, "removed_idx": removed_idx, "score": score}, h,
                       {"threshold": threshold, "passes": passes})


def _denoise(runner, src, normals, h, prm) -> TiledResult:
    """Tiled denoise: the inner loop's cloud-wide decisions follow a plan
    (empty at first) and past it each tile's own answer; the sums every tile
    reports are added and the decisions replayed; at the first a tile took
    otherwise the plan is corrected and the run repeated."""
    from .specs.denoise import tile_hops

    hops = tile_hops(prm)
    n = src.n
    pos = runner.store("points", (n, 3))
    nrm = runner.store("normals", (n, 3))
    score = runner.store("edge_score", n)
    given = None if normals is None else runner.stored("given_normals", normals)
    plan: list = []
    runs = 0
    while True:
        runs += 1
        traces = {}
        align = []

        def collect(cell, res):
            traces[cell] = res["trace"]
            align.append(res["reduced"])

        args = dict(centre=src.centre, h=h, n_total=n, hops=hops, plan=tuple(plan), **prm)
        runner.run("denoise", _denoise_task, hops * HOP_H * h, args,
                   [(pos, "points", "ext"), (nrm, "normals", "ext"),
                    (score, "edge_score", "ext")],
                   reads={"normals": (given, "rows")}, reduce=_halo_sample, collect=collect)
        traces = [traces[c] for c in sorted(traces)]  # summed in cell order, every run
        wrong = _replay(traces, plan, n, prm["tol"])
        if wrong is None:
            break
        plan = wrong
        log.info("denoise: a tile missed decision %d; running again", len(plan) - 1)
    flips = 0
    if normals is None:
        flips = _align_signs(runner, src, nrm, align)
    edge = runner.map("edge_mask", lambda v: v < prm["edge_threshold"], score, dtype=bool)
    return TiledResult({"points": pos, "normals": nrm, "edge_mask": edge, "edge_score": score},
                       h, {"passes": 1 + runs, "denoise_runs": runs, "decisions": len(traces[0])
                           if traces else 0, "tiles_flipped": flips})


def _denoise_task(points, lo, hi, core, *, normals, **kw):
    from pcprep.filters.denoise import denoise_tile

    return denoise_tile(points, normals, lo, hi, core, **kw)


def _replay(traces, plan, n: int, tol: float):
    """The decisions the whole cloud takes from the tiles' summed traces (in
    the order given: the caller's cell order, so that the sums, and a decision
    on a near tie, are the same in every run); None
    if every tile took them, else the plan corrected up to the first decision a
    tile took otherwise (past it the tiles decide locally again).  Tiles that
    agree on every decision before the i-th reach the i-th at the same step of
    the loop, so their sums there add up to the whole cloud's."""
    if not traces:
        return None
    for i in range(max(len(t) for t in traces)):
        if any(len(t) <= i for t in traces):
            raise RuntimeError("denoise: tiles took different decision paths")
        kinds = {t[i][0] for t in traces}
        if len(kinds) != 1:
            raise RuntimeError("denoise: tiles took different decision paths")
        a = sum(t[i][1] for t in traces)
        b = sum(t[i][2] for t in traces)
        truth = a > b if kinds.pop() == "rise" else math.sqrt(a / n) < tol
        if any(t[i][3] != truth for t in traces):
            return [d[3] for d in traces[0][:i]] + [truth]
    return None


def _halo_sample(cell, rows, core, res, most: int = 4096):
    """The tile's cell and its rows outside the core whose result is exact,
    with the tile's normals: the overlap two tiles' orientations are compared
    on.  (The cell stands for its core rows, read again from the index when
    needed, so that the driver does not hold every row's number.)"""
    keep = np.flatnonzero(res["sure"] & ~core)
    if len(keep) > most:
        keep = keep[np.linspace(0, len(keep) - 1, most).astype(np.int64)]
    return cell, rows[keep], res["normals"][keep]


def _align_signs(runner, src, nrm, align) -> int:
    """Make the tiles' MST orientations agree: tiles that share exact rows vote
    on their relative sign; a maximum spanning tree of the votes, rooted at the
    tile that holds the highest point (whose own MST made its normal point to
    +z, as a one-piece run does), fixes a sign per tile.  Returns the number of
    tiles flipped.  The tiles are numbered by cell, not in the order their
    results came, so that ties in the spanning tree fall the same way in
    every run."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

    align = sorted(align, key=lambda a: a[0])  # tiles by cell, not by completion
    t = len(align)
    owner = runner.store(f"owner-{runner.passes}", src.n, np.int64)
    owner[:] = -1
    for i, (cell, _, _) in enumerate(align):
        owner[runner.index.core_rows(cell)] = i
    vi, vj, vv = [], [], []
    for i, (_, rows, nn) in enumerate(align):
        if len(rows) == 0:
            continue
        j = owner[rows]
        s = np.sign(np.einsum("ij,ij->i", nn, nrm[rows]))
        for jj in np.unique(j):
            if jj != i:
                vi.append(i)
                vj.append(int(jj))
                vv.append(float(s[j == jj].sum()))
    flip = np.ones(t)
    if vv:
        vv = np.array(vv)
        m = coo_matrix((vv, (vi, vj)), shape=(t, t)).tocsr()
        m = m + m.T
        big = float(np.abs(m.data).max()) + 1.0
        w = m.copy()
        w.data = big - np.abs(w.data) + 1e-9  # max |vote| spanning tree
        tree = minimum_spanning_tree(w)
        top = int(np.argmax(np.asarray(src.xyz[:, 2]))) if src.n else 0
        root = int(owner[top])
        order, pred = breadth_first_order(tree, root, directed=False,
                                          return_predecessors=True)
        for v in order[1:]:
            flip[v] = flip[pred[v]] * (1.0 if m[v, pred[v]] >= 0 else -1.0)
    for i, (cell, _, _) in enumerate(align):
        if flip[i] < 0:
            nrm[runner.index.core_rows(cell)] *= -1.0
    return int((flip < 0).sum())


def _saliency(runner, src, normals, h, prm) -> TiledResult:
    """Tiled saliency: a first pass stores every row's F̄⁴ and, once the
    tiles' orientations are made to agree (their normal blocks flipped with
    them), F̄_g is their mean in row order, summed as the one-piece run sums
    it, so that it is the same to the bit (a Lasso problem of near-duplicate
    atoms can take another code from a difference in the last bits); the
    coding pass gives the raw residuals and accumulations; the cloud-wide
    maxima normalise them."""
    from pcprep.filters.saliency import saliency_tile

    from .specs.saliency import tile_hops

    n = src.n
    nrm = runner.store("normals", (n, 3))
    fb4 = runner.store("fbar4", (n, 4))
    given = None if normals is None else runner.stored("given_normals", normals)
    signs, align = {}, []

    def collect_mean(cell, res):
        signs[cell], sample = res["reduced"]
        align.append(sample)

    base = dict(centre=src.centre, h=h, n_total=n, **prm)
    hops = tile_hops(prm)
    halo = (hops + 1) * max(prm["radius"], HOP_H) * h
    runner.run("saliency mean", saliency_tile, halo, dict(base, stage="mean", hops=hops),
               [(nrm, "normals", "ext"), (fb4, "fbar4", "ext")],
               reads={"normals": (given, "rows")}, reduce=_mean_reduce, collect=collect_mean)
    if given is None:  # given normals keep their signs, as in one piece
        _align_signs(runner, src, nrm, align)
        for cell, (row, first) in signs.items():  # F̄⁴'s normal block in the aligned signs
            if nrm[row] @ first < 0:
                rows = runner.index.core_rows(cell)
                fb4[rows, :3] = -fb4[rows, :3]
    total = None  # np.mean(axis=0) adds the rows one after another: so do the chunks
    for s0 in range(0, n, CHUNK):
        part = np.asarray(fb4[s0:s0 + CHUNK])
        total = np.add.reduce(part if total is None else np.vstack([total[None], part]), axis=0)
    fbar_g = total / n
    resid = runner.store("residual", n)
    sparsity = runner.store("sparsity", n, np.int64)
    acc = runner.store("accumulated", n)

    runner.run("saliency code", saliency_tile, halo,
               dict(base, stage="code", hops=hops, fbar_mean=fbar_g),
               [(resid, "residual", "ext"), (sparsity, "sparsity", "ext"),
                (acc, "accumulated", "ext")],
               # one core row's aligned normal fixes the tile's signs
               reads={"reference": (nrm, "first_core"), "normals": (given, "rows")})
    top_r = float(resid.max())
    top_s = float(sparsity.max()) if prm["measure"] == "mdl" else None
    top_a = float(acc.max())

    def ratio(v, top):
        return v / top if top > 0 else np.zeros(len(v))

    if top_s is None:
        s_t = runner.map("neighbourhood_saliency", lambda r: ratio(r, top_r), resid)
    else:
        s_t = runner.map("neighbourhood_saliency",
                         lambda s, r: ratio(s, top_s) * ratio(r, top_r), sparsity, resid)
    sal = runner.map("saliency", lambda a: ratio(a, top_a), acc)
    return TiledResult({"saliency": sal, "neighbourhood_saliency": s_t, "sparsity": sparsity,
                        "residual": resid, "normals": nrm}, h, {"passes": 3})


def _mean_reduce(cell, rows, core, res):
    """Saliency's first pass, per tile: the tile's first core row and that
    row's normal (the signs its F̄⁴ rows were taken in), and the overlap
    sample of ``_halo_sample``."""
    i0 = int(np.flatnonzero(core)[0])
    return ((int(rows[i0]), res["normals"][i0].copy()), _halo_sample(cell, rows, core, res))


# ---------------------------------------------------------------------------
# the feature detectors (chapter 7): features by tiles, the score model fitted
# once on the driver, rows scored in chunks, then the local or chain tests


def _knn_reach(k: int) -> float:
    """First guess of the distance to a point's k-th neighbour, in h (on a
    sampled surface, where h is the mean 6-NN distance), for the rows a tile's
    halo must cover: those on a crease or the cloud's rim, whose neighbours lie
    on one side, reach about 1.4 √k h (0.55 √k h is a row's mean on a random
    sample).  A guess too wide costs a few per cent more halo points, one too
    narrow a tile's run again, so it errs wide; tiles check it."""
    return 1.5 * math.sqrt(k)


def _feature_store(runner: _Runner, d: int, n: int) -> np.ndarray:
    """A (d, n) float64 memory map for every row's features, column by column
    so that the per-column statistics read contiguous memory."""
    return runner.store("features", (d, n))


def _store_columns(Fc: Stored, rows: np.ndarray, cols: np.ndarray) -> None:
    """``Fc[:, rows] = cols`` for a (d, m) block ``cols`` that a tile sent
    column by column, one column at a time (``_scatter``): each is then a
    contiguous read and one indexed write, where the 2-D assignment (or one
    from the transpose of an (m, d) block) walks the source with a stride and
    took 1.7–2× as long on the driver."""
    for j in range(len(cols)):
        _scatter(Fc, rows, cols[j], column=j)


def _score_task(Fc, model, cfg):
    """The scores of a chunk of rows sent column by column (``Fc`` (d, m)):
    the rows are laid out on the worker, so the driver only copies
    contiguous column stretches."""
    from pcprep.filters.multiscale import score_rows

    return score_rows(np.ascontiguousarray(Fc.T), model, cfg, overwrite=True).score


def _scores(runner: _Runner, Fc: np.ndarray, cfg) -> np.ndarray:
    """The code-length score of every row: the standardisation and the K-SVD
    dictionary fitted once on the driver from the stored features (the exact
    state of a one-piece run: medians and the content-ordered training rows of
    every row), broadcast, and the rows coded in chunks on the workers (a row's
    code depends on the row and the model only)."""
    import time

    from pcprep.filters.multiscale import fit_score_model

    t0 = time.perf_counter()
    F = Fc.T                                   # (n, d), columns contiguous
    n = len(F)
    with progress.step("score model", 1) as advance:
        model = fit_score_model(F, cfg)
        advance()
    t1 = time.perf_counter()
    score = runner.store("score", n)
    _map_rows(runner, "score rows", _score_task, (Fc, "columns"), model, cfg, [score])
    log.info("score model fitted on the driver in %.1f s (serial)", t1 - t0)
    return score


#: row chunks ``_map_rows`` gives each worker at least (when rows allow)
CHUNKS_PER_WORKER = 4


def _chunk_rows(n: int, workers: int) -> int:
    """Rows per chunk of ``_map_rows`` for ``workers`` worker threads
    (``_slots``): at most ``CHUNK // 4`` (the driver holds ``IN_FLIGHT``
    chunks per thread), and few enough that every thread gets
    ``CHUNKS_PER_WORKER`` of them, so that no worker idles while another
    codes the last big chunk (4 chunks of a 1M cloud went 3 to 1 on 2
    workers), and at least 4096 rows, where a task's overhead stays small.

    >>> _chunk_rows(1_000_000, 2), _chunk_rows(20_000_000, 2), _chunk_rows(5_000, 2)
    (125000, 262144, 4096)
    """
    return int(min(CHUNK // 4, max(4096, -(-n // (CHUNKS_PER_WORKER * workers)))))


def _map_rows(runner: _Runner, label: str, fn, read, shared, arg, writes) -> None:
    """``fn(rows, shared, arg)`` for row chunks ``[s0, e)`` of the stored array
    ``read[0]`` (``_read_rows``: rows, or a (d, m) block of columns for
    ``read[1] == "columns"``), each part (or tuple of parts) written into the
    stored arrays ``writes`` at ``s0``; run on the workers with ``shared`` (a
    model or a dictionary) broadcast once, ``IN_FLIGHT`` chunks per worker
    thread in flight.  Where the workers share the scratch folder they read and write
    the rows themselves (``_rows_task``), else the driver does.  The pass's
    wall time goes to ``runner.times[label]``, the driver's CPU time in it to
    ``runner.cpu[label]``."""
    import time

    from dask.distributed import as_completed

    t0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
    client = runner.client
    src, how = read
    n = src.shape[1] if how == "columns" else len(src)
    read = (runner.handle(src), how)
    writes = [runner.handle(a) for a in writes]
    [model] = client.scatter([shared], broadcast=True)
    nw = max(1, _slots(client))
    step = _chunk_rows(n, nw)
    starts = list(range(0, n, step))
    limit = IN_FLIGHT * nw
    futures, meta, direct = as_completed(), {}, set()
    with progress.step(label, len(starts)) as advance:
        def submit():
            while starts and futures.count() < limit:
                s0 = starts.pop(0)
                e = min(n, s0 + step)
                there = runner.shared and s0 not in direct
                if there:
                    fut = _submit(client, _rows_task, fn, read, s0, e, model, arg, writes,
                                  runner.home)
                else:
                    fut = _submit(client, fn, _read_rows(read, s0, e), model, arg)
                meta[fut.key] = (s0, there)
                futures.add(fut)
        submit()
        for fut in futures:
            (s0, there), part = meta.pop(fut.key), fut.result()
            del fut
            if there and part == ELSEWHERE:  # a worker-I/O chunk returns None or this
                runner._moved(f"{label}: rows {s0}..")
                direct.add(s0)
                starts.insert(0, s0)
                submit()
                continue
            if not there:
                _write_rows(writes, s0, part)
            del part
            advance()
            submit()
    Stored.release()
    runner.times[label] = time.perf_counter() - t0
    runner.cpu[label] = time.process_time() - c0
    runner.cpu_main[label] = time.thread_time() - m0


def _sharp(runner, src, normals, h, prm) -> TiledResult:
    """Tiled sharp features: the unscaled features and the 6-NN means of
    every row by tiles, h from those means (when the largest scale has more
    than 6 neighbours, as by default: ``h`` comes in None, see
    ``_SPACING_IN_PASS``; a first halo of a twentieth of a cell, else the
    largest scale's reach), the features scaled and the ridge factor taken
    on the driver, the score as in ``_scores``, the threshold from every
    score, the noise level from every row, then the gate and the
    localisation by tiles (a halo of their largest neighbourhood)."""
    from pcprep.filters import sharp
    from pcprep.filters.multiscale import scale_sizes

    cfg, stage = sharp.split_params(prm)
    n = src.n
    n_ks = len(scale_sizes(stage.k_min, stage.k_max, stage.n_scales))
    Fc = _feature_store(runner, 4 * n_ks, n)
    nrm = runner.store("normals", (n, 3))
    rows6 = runner.store("spacing", n) if h is None else None

    halo = _first_halo(runner.index) if h is None else _knn_reach(stage.k_max) * h
    runner.run("features", sharp.sharp_tile, halo,
               {"centre": src.centre, "h": None, "n_total": n, "params": prm,
                "stage": "features"},
               [(Fc, "features", "columns"), (nrm, "normals", "core"),
                (rows6, "spacing_rows", "core")])
    if h is None:
        h = _h_from_rows(rows6)
        runner.halo.clear()  # the first halo says nothing of the gates' reach
    ridge_pd = runner.store("ridge_pd", n)
    for s0 in range(0, n, CHUNK):  # in place, through (m, d) views of the columns
        rows_view = Fc[:, s0:s0 + CHUNK].T
        sharp.scale_features(rows_view, h)
        ridge_pd[s0:s0 + CHUNK] = sharp.ridge_factor(rows_view[:, 3::4][:, n_ks // 2:])
    base = dict(centre=src.centre, h=h, n_total=n, params=prm)
    sigma = sharp.cloud_state(np.asarray(Fc[0]))
    score = _scores(runner, Fc, stage)
    T = sharp.threshold(score, cfg, sharp.DEFAULT_RULES)
    mask = runner.map("score_mask", lambda v: v > T, score, dtype=bool)       # (7.11)
    ridge = runner.map("ridge", np.multiply, score, ridge_pd)
    final = runner.store("mask", n, bool)
    k = sharp.local_k(sigma, cfg, sharp.DEFAULT_RULES)
    runner.run("feature gates", sharp.sharp_tile, _knn_reach(k) * h,
               dict(base, stage="gates", sigma=sigma), [(final, "mask", "core")],
               reads={"mask": (mask, "rows"), "normals": (nrm, "rows"),
                      "ridge": (ridge, "rows")})
    log.info("features: threshold %.4g; %d of %d points after the gate and the "
             "localisation", T, int(final.sum()), n)
    quality = runner.map("quality", lambda v: v.astype(np.float64), final)
    return TiledResult({"mask": final, "score": score, "quality": quality},
                       h, {"threshold": T, "passes": 5, "noise": sigma})


def _holes(runner, src, normals, h, prm) -> TiledResult:
    """Tiled hole boundaries: the features and the point-wise quantities of
    every row by tiles, the score as in ``_scores``, the threshold and the
    point-wise tests from every row; the border chains (support, smallest
    hole, border row) are cloud-wide, so they run on the driver over the
    detected points and the border-row candidates only (their positions read
    from the memory map), which are a small part of the cloud."""
    from pcprep.filters import holes
    from pcprep.filters.multiscale import scale_sizes

    cfg, stage = holes.split_params(prm)
    rules = holes.DEFAULT_RULES
    n = src.n
    Fc = _feature_store(runner, 3 * len(scale_sizes(stage.k_min, stage.k_max,
                                                    stage.n_scales)), n)
    cols = {c: runner.store(c, n) for c in ("extent", "variation", "shift_mean",
                                            "border_distance", "gap")}

    runner.run("holes", holes.hole_tile, _knn_reach(stage.k_max) * h,
               dict(centre=src.centre, h=h, n_total=n, params=prm),
               [(Fc, "features", "columns")] + [(v, c, "core") for c, v in cols.items()])
    score = _scores(runner, Fc, stage)
    feats = holes.HoleFeatures(features=None, h=h, extent=cols["extent"],
                               variation=cols["variation"], near=None,
                               shift_mean=cols["shift_mean"], reach=None)
    centre = src.centre
    take = lambda rows: np.asarray(src.xyz[rows]) - centre  # noqa: E731
    mask, T = holes.select_borders(take, score, feats, cols["border_distance"]
                                   if rules.rim_distance else None,
                                   holes.rows_by_gap(take, cols["gap"]), cfg, rules,
                                   out=runner.store("mask", n, bool))
    quality = runner.map("quality", lambda v: v.astype(np.float64), mask)
    return TiledResult({"mask": mask, "score": score, "quality": quality},
                       h, {"threshold": T, "passes": 4})


# ---------------------------------------------------------------------------
# SDBS simplification (chapter 6)


def _chunked_mean(xyz: np.ndarray) -> np.ndarray:
    """The centroid of a memory-mapped cloud, summed chunk by chunk."""
    tot = np.zeros(3)
    for s0 in range(0, len(xyz), CHUNK):
        tot += np.asarray(xyz[s0:s0 + CHUNK]).sum(axis=0)
    return tot / len(xyz)


def _code_task(F, D, alpha):
    from pcprep.filters.simplify import code_rows

    return code_rows(F, D, alpha)


def _simplify(runner, src, normals, h, prm) -> TiledResult:
    """Tiled SDBS: the PCA features of every row by tiles; the feature scales,
    the K-SVD dictionary (on the seeded row subsample of a one-piece run) and
    the maxima of (6.10) on the driver; the Lasso codes in row chunks on the
    workers; then the δ search, each trial a greedy pass by tiles whose halo
    is three of the largest radii, and the exact count restored on the whole
    cloud (``simplify.removal``).  The greedy visit order is cloud-wide; a
    decision can differ from a one-piece run's only where a chain of earlier
    decisions crosses a halo, which the tests and docs/decisions/scale.md
    measure."""
    import time

    from pcprep.filters import simplify as sd
    from pcprep.filters import sparse

    n = src.n
    sd.size_params(prm["ratio"], prm["count"], prm["delta"], "simplify_sdbs")
    target = sd.target_count(prm["ratio"], prm["count"], n, "simplify_sdbs")
    k = prm["k"]
    centre = _chunked_mean(src.xyz)
    nrm = runner.store("normals", (n, 3))
    sigma = runner.store("sigma", n)
    rows6 = runner.store("rows6", n)

    given = None if normals is None else runner.stored("given_normals", normals)
    base = dict(centre=centre, h=h, n_total=n, k=k)
    runner.run("simplify features", sd.sdbs_tile, _knn_reach(max(k, sd.GRAPH_K)) * h,
               dict(base, stage="features"),
               [(nrm, "normals", "core"), (sigma, "sigma", "core"), (rows6, "rows6", "core")],
               reads={"normals": (given, "rows")})
    hs = spacing_from_rows(rows6)          # from the float32 lists, as one piece
    t0 = time.perf_counter()
    P = _Centred(src.xyz, centre)
    scales = sd.feature_scales(sigma, P, prm["feature_scale"])
    F = runner.store("sdbs_features", (n, 7))
    for s0 in range(0, n, CHUNK):
        F[s0:s0 + CHUNK] = sd.scale_features(nrm[s0:s0 + CHUNK], sigma[s0:s0 + CHUNK],
                                             P[s0:s0 + CHUNK], prm["feature_scale"], scales)
    nrm = sigma = None  # freed: the features are in F
    with progress.step("simplify dictionary", 1) as advance:
        D = sparse.ksvd(F, prm["n_atoms"], n_nonzero_coefs=min(3, 7, prm["n_atoms"]),
                        max_iter=prm["max_iter"], max_train=prm["max_train"],
                        seed=prm["seed"], code_all=False, order="rows").dictionary
        advance()
    log.info("simplify: scales and dictionary on the driver in %.1f s (serial)",
             time.perf_counter() - t0)
    nnz = runner.store("nnz", n, np.int64)
    res = runner.store("residual", n)
    _map_rows(runner, "simplify codes", _code_task, (F, "rows"), D, prm["alpha"], [nnz, res])
    maxima = sd.saliency_maxima(nnz, res)
    score = runner.map("score", lambda a, r: sd.normalised_saliency(a, r, maxima), nnz, res)
    unit = runner.map("unit", lambda r: hs * (np.maximum(r, 1e-3 * hs) / hs)
                      ** prm["density_adapt"], rows6)
    inv = runner.map("inverse_score", lambda v: 1.0 / np.maximum(v, prm["sf_floor"]), score)
    trials = []
    rho = runner.store("rho", n)  # one trial's radii at a time

    def run(dl):
        runner.map(None, lambda u, v: dl * u * v, unit, inv, out=rho)
        keep = runner.store(f"keep-{len(trials)}", n, bool)

        halo = 3.0 * quantile(rho, 0.999) + _knn_reach(sd.GRAPH_K) * hs
        runner.halo.clear()
        runner.run("simplify greedy", sd.sdbs_tile, halo, dict(base, stage="greedy"),
                   [(keep, "keep", "core")],
                   reads={"score": (score, "rows"), "rho": (rho, "rows")})
        trials.append(dl)
        return keep

    out = sd.removal(run, score, nnz, res, hs, n, target, prm["delta"], inv)
    return TiledResult({"keep_idx": runner.on_disk("keep_idx", out.keep_idx), "score": score}, hs,
                       {"delta": out.delta, "greedy_passes": len(trials),
                        "n_greedy": out.n_greedy, "passes": 2 + len(trials)})


class _Centred:
    """Rows of a memory-mapped cloud about ``centre``, read on demand."""

    def __init__(self, xyz, centre):
        self.xyz, self.centre = xyz, centre

    def __len__(self):
        return len(self.xyz)

    def __getitem__(self, key):
        return np.asarray(self.xyz[key]) - self.centre


_FAMILIES = {"denoise": _denoise, "outliers": _outliers, "saliency": _saliency,
             "features": _sharp, "holes": _holes, "simplify": _simplify}
#: the filters (by their parameters) whose first pass gives h as well, its
#: tiles needing no h: run_tiled hands these families h=None
_SPACING_IN_PASS = {"outliers": lambda prm: prm["method"] == "statistical",
                    "features": lambda prm: _sharp_k_max(prm) > SPACING_K}


def _sharp_k_max(prm: dict) -> int:
    from pcprep.filters import sharp

    return sharp.split_params(prm)[1].k_max


def scratch_need(command: str, prm: dict, n: int, *, positions: bool = True,
                 normals: str | None = None) -> int:
    """The bytes a tiled run of ``command`` (its resolved parameters ``prm``)
    on ``n`` points still has to put in its scratch folder, at the least: the
    tile index, every per-row array its family stores and, with
    ``positions``, the positions (not yet ingested).  ``normals``: None when
    the run is given no normals (then the tiles' signs are stored instead),
    ``"stored"`` when they are in the folder already, ``"copy"`` when they
    are copied there (``_Runner.stored``).  Left out are the
    arrays that may not be made or do not stay: a pass's 1-byte row count
    (removed after the pass) and SDBS's δ trials past the first (1 byte per
    row each).  So a folder with less free room than this cannot hold the
    run, and ``check_scratch`` refuses it before anything is read; one with
    more may still run short later, which ``open_scratch`` reports."""
    prm = {k: v for k, v in prm.items() if k != "preset"}  # refused by run_tiled
    row = 32 + 24 * positions  # the index's row order and cell-ordered positions
    given = {None: 0, "stored": 0, "copy": 24}[normals]
    signs = 8 if normals is None else 0  # the owner of every row, to align tile signs
    spacing = 8  # every family's mean 6-NN distances (h)
    if command == "outliers":  # the score, its mask and the two row lists (8 B in all)
        row += spacing + 8 * (prm["method"] == "statistical") + 8 + 1 + 8
    elif command == "denoise":  # points, normals, edge score and mask; tile signs
        row += spacing + 24 + 24 + 8 + 1 + given + signs
    elif command == "saliency":  # normals, F̄⁴; residual, sparsity, accumulation, saliencies
        row += spacing + 24 + 32 + given + signs + 5 * 8
    elif command == "features":  # four columns per scale; normals; ridge, score, masks
        from pcprep.filters import sharp
        from pcprep.filters.multiscale import scale_sizes

        stage = sharp.split_params(prm)[1]
        n_ks = len(scale_sizes(stage.k_min, stage.k_max, stage.n_scales))
        row += spacing + 32 * n_ks + 24 + 8 + 8 + 1 + 8 + 1 + 8
    elif command == "holes":  # three columns per scale; five point-wise columns; score
        from pcprep.filters import holes
        from pcprep.filters.multiscale import scale_sizes

        stage = holes.split_params(prm)[1]
        n_s = len(scale_sizes(stage.k_min, stage.k_max, stage.n_scales))
        row += spacing + 24 * n_s + 5 * 8 + 8 + 1 + 8
    elif command == "simplify":  # normals, σ, 6-NN rows, 7 features, codes, scores, radii
        from pcprep.filters import simplify as sd

        target = sd.target_count(prm["ratio"], prm["count"], n, "simplify_sdbs")
        row += spacing + given + 24 + 8 + 8 + 56 + 6 * 8 + (target is None or target < n)
        return row * n + 8 * (target or 0)  # the kept rows' list
    else:
        raise InvalidParameterError(f"unknown tiled filter {command!r}")
    return row * n


def check_scratch(folder: str, need: int, what: str) -> None:
    """Refuse a scratch folder with less free room than ``need`` bytes
    (``scratch_need``), naming both, before the run reads anything."""
    free = shutil.disk_usage(folder).free
    log.debug("%s: the scratch folder %s needs at least %.1f MiB more (%.1f MiB free)",
              what, folder, need / 2**20, free / 2**20)
    if free < need:
        raise ScratchSpaceError(
            errno.ENOSPC, f"{what}: the run needs at least {need / 2**20:,.1f} MiB in the "
            f"scratch folder {folder}, which has {free / 2**20:,.1f} MiB free: give a folder "
            "with more room (scratch=, or --scratch for the command line)")
