"""
cli.py
------
The ``pcprep`` command line, generated from the filter registry.

    pcprep info FILE
    pcprep filters
    pcprep denoise|features|holes|saliency IN OUT [--param value ...]
    pcprep simplify IN OUT (--ratio R | --count N) [--param value ...]
    pcprep bench FAMILY [--quick] [--speed]      (from pcprep.baselines)
    pcprep report [--quick]                      (from pcprep.baselines)

Errors print one line on stderr and exit with status 1 (2 for usage errors);
no output file is written unless the whole run succeeded.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

import numpy as np

from pcprep.filters._validation import InvalidParameterError, PointCloudError

from . import registry
from .convert import MissingAttributeError, load_cloud, save_cloud
from .tiles import WorkersLostError

log = logging.getLogger("pcprep")

class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2, like argparse but no usage dump
        self.exit(2, f"pcprep: error: {message}\n")


def _bool(text: str) -> bool:
    low = text.strip().lower()
    if low in ("1", "true", "yes", "on"):
        return True
    if low in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true/false, got {text!r}")


def _add_filter_command(sub, spec) -> None:
    first = spec.description.split(". ")[0].rstrip(".") + "."
    p = sub.add_parser(spec.command, help=spec.label, description=f"{spec.label}. {first}")
    p.add_argument("paths", nargs="+", metavar="PATH",
                   help="IN OUT, or several inputs with --out-dir.  Inputs: PLY, LAS, LAZ, "
                        "PCD, E57, XYZ, OBJ, OFF (or another format pymeshlab reads); outputs: "
                        "PLY, LAS, LAZ or PCD keep every attribute, XYZ, OBJ, OFF and E57 "
                        "only some")
    p.add_argument("--out-dir", default=None, metavar="DIR",
                   help="write each input's result to DIR under the input's name; a file "
                        "that fails is reported and the others go on")
    p.add_argument("--format", default=None, metavar="EXT",
                   help="with --out-dir: the output format (e.g. ply, laz); default: the "
                        "input's")
    for prm in spec.params:
        kind = _bool if prm.kind is bool else prm.kind
        unit = f" [{registry.UNITS[prm.unit]}]" if prm.unit else ""
        rng = f" range {prm.range_text()}." if prm.range_text() else ""
        default = "none" if prm.default is None else prm.default
        p.add_argument(
            f"--{prm.name.replace('_', '-')}", dest=prm.name, type=kind, default=None,
            choices=prm.choices or None, metavar=prm.name.upper() if not prm.choices else None,
            help=(f"{prm.help.rstrip('.')}{unit}.{rng} Default: {default}.").replace("%", "%%"),
        )
    p.add_argument("--drop-nonfinite", action="store_true",
                   help="drop rows whose coordinates hold NaN or Inf (their indices are "
                        "reported) instead of refusing the file")
    _add_drop_options(p, "the result")
    p.add_argument("--save-mlx", default=None, metavar="PATH",
                   help="also write this step as a MeshLab filter script (.mlx) that "
                        "pcprep run and pcprep.MeshSet replay")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    _add_scale_options(p, "the result equals the one-piece run's")
    p.set_defaults(_spec=spec)


def _add_drop_options(p, result: str) -> None:
    """The options that accept, by name, a loss a write refuses by default
    (``formats.check_faces``, ``formats.check_elements``), for ``result``
    (what the command writes)."""
    p.add_argument("--drop-faces", action="store_true",
                   help=f"write {result} as vertices without faces (needed to write a mesh "
                        "as LAS, LAZ, PCD, XYZ or E57, which store points alone)")
    p.add_argument("--drop-face-properties", action="store_true",
                   help=f"write {result}'s faces without what they carry besides their "
                        "vertices (face colours, texture coordinates, materials): needed "
                        "where pcprep cannot keep it (OBJ materials, OFF colour-map "
                        "indices, face properties written to OBJ, all but a colour to OFF)")
    p.add_argument("--drop-elements", action="store_true",
                   help=f"write {result} without the input PLY's elements besides its "
                        "vertices and faces (edges, cameras, range grids, …) or the input "
                        "OBJ's polylines and point groups (l, p), which other formats "
                        "cannot hold and a removal would leave a range grid pointing at "
                        "the wrong rows")


def _add_scale_options(p, same: str) -> None:
    big = p.add_argument_group(
        "large clouds (any of these runs tile by tile with a halo on Dask; needs pcprep[scale])")
    big.add_argument("--tiles", default=None, type=_tiles, metavar="auto|N",
                     help="run tile by tile: N core points per tile, or auto (from the "
                          f"memory budget); {same}")
    big.add_argument("--workers", default=None, type=int, metavar="K",
                     help="worker processes of the local Dask cluster (default: the cores), "
                          "the cores shared out among them as threads, each running one "
                          "tile at a time on one core")
    big.add_argument("--scheduler", default=None, metavar="ADDRESS",
                     help="attach to a running Dask scheduler instead of a local cluster")
    big.add_argument("--memory-budget", default=None, metavar="BYTES",
                     help="memory limit per local worker (e.g. 4GB, at least 768MiB; "
                          "default: the machine's memory shared out)")
    big.add_argument("--scratch", default=None, metavar="DIR",
                     help="folder for a tiled run's per-point arrays, in a subfolder removed "
                          "at the end (about 80-450 bytes per point, checked before the "
                          "run starts; default: the system's temporary folder, TMPDIR)")
    big.add_argument("--worker-io", default=None, choices=("auto", "on", "off"),
                     help="on: the workers cut their tiles from the scratch folder and "
                          "write their results into it (every worker on this host; "
                          "checked); off: the driver does, for any cluster; auto "
                          "(default): on wherever possible.  Same results either way")


def _scratch_folder(base: str | None, prefix: str) -> str:
    """A new subfolder of ``base`` (``--scratch``; default the system's
    temporary folder) for a tiled run's arrays, or an error naming ``base``."""
    import tempfile

    where = base if base is not None else tempfile.gettempdir()
    if not os.path.isdir(where):
        raise InvalidParameterError(f"--scratch: {where} is not a folder")
    try:
        return tempfile.mkdtemp(prefix=prefix, dir=where)
    except OSError as exc:
        raise InvalidParameterError(f"--scratch: cannot make a folder in {where} "
                                    f"({exc.strerror})") from None


def _tiles(text: str):
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected auto or a positive count, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="pcprep", description=(
        "Sparse-representation point-cloud pre-processing (Leal Narváez 2020): denoising, "
        "saliency, simplification, sharp features and hole boundaries, benchmarked against "
        "MeshLab and CGAL."))
    from pcprep import __version__

    parser.add_argument("--version", action="version", version=f"pcprep {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    info = sub.add_parser("info", help="point count, spacing h, bounding box, attributes")
    info.add_argument("input")
    info.add_argument("--quiet", action="store_true", help="no progress messages")
    _add_scale_options(info, "the file is read in blocks, never whole (LAS, LAZ, PLY of "
                             "vertices alone, PCD, XYZ, E57)")
    sub.add_parser("filters", help="list the filters and their parameters")
    run = sub.add_parser("run", help="run a MeshLab filter script (.mlx) that may mix "
                                     "MeshLab's and pcprep's filters")
    run.add_argument("script", help="the .mlx filter script")
    run.add_argument("input", help="input file")
    run.add_argument("output", help="output file (the current layer at the end)")
    run.add_argument("--save-mlx", default=None, metavar="PATH",
                     help="also write the pipeline that ran, as .mlx")
    run.add_argument("--drop-nonfinite", action="store_true",
                     help="drop rows whose coordinates hold NaN or Inf (indices reported)")
    _add_drop_options(run, "the last layer")
    run.add_argument("--quiet", action="store_true", help="no progress messages")
    for spec in sorted(registry.load_all().values(), key=lambda s: s.command):
        _add_filter_command(sub, spec)
    for command in _plugin_commands():
        command(sub)
    return parser


def _cmd_info(path: str) -> None:
    from pcprep.filters.neighbors import SPACING_K, spacing_rows

    from .cloud import describe

    cloud = load_cloud(path, nonfinite="drop")
    pts = cloud.points
    dropped = cloud.meta.get("dropped_rows", ())
    rows = spacing_rows(pts) if len(pts) > SPACING_K else None
    extent = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else None
    _print_info(path, cloud.meta, len(pts) + len(dropped), dropped, extent, rows,
                describe(cloud), None if cloud.faces is None else len(cloud.faces),
                tuple(cloud.face_attributes))


def _faces_kept(tri, dropped: list) -> int | None:
    """How many of the triangles ``tri`` (``mesh_tail``'s) use none of the
    ``dropped`` rows, counted in blocks: the faces the whole read keeps
    (None where it keeps none, as ``Cloud.subset`` leaves no faces)."""
    from .formats import stream

    gone = np.unique(np.asarray(dropped, dtype=np.int64))
    kept = sum(int(np.count_nonzero(~np.isin(tri[s:s + stream.CHUNK], gone).any(axis=1)))
               for s in range(0, len(tri), stream.CHUNK)) if len(gone) else len(tri)
    return kept or None


def _print_info(path, meta, n, dropped, extent, rows, fields, faces, kept=None) -> None:
    """What ``pcprep info`` prints, from the file's ``meta``, its row count,
    the non-finite rows left out, the finite rows' bounding box, their
    spacing rows (``neighbors.spacing_rows``), ``describe``'s fields, the
    face count and the face attributes ``kept`` (by default those a PLY's
    header names, for a mesh read in blocks)."""
    from pcprep.filters.neighbors import (ISOLATED_FACTOR, SPACING_K, count_isolated,
                                          spacing_from_rows)

    lines = [f"file: {path}", f"format: {meta.get('format', '?')}", f"points: {n}"]
    if len(dropped):
        shown = ", ".join(map(str, dropped[:5])) + (", …" if len(dropped) > 5 else "")
        lines.append(f"non-finite points: {len(dropped)} (rows {shown})")
    else:
        lines.append("non-finite points: 0")
    if faces is not None:
        lost = meta.get("face_properties", ())
        if kept is None:
            kept = [k for k in meta.get("ply", {}).get("face_types", {}) if k not in lost]
        notes = ([f"with {', '.join(kept)}"] if kept else []) + (
            [f"carrying {', '.join(lost)}, which pcprep does not write"] if lost else [])
        lines.append(f"faces: {faces}" + (f" ({'; '.join(notes)})" if notes else ""))
    if rows is not None:
        iso = count_isolated(rows)
        lines.append(f"spacing h (mean distance to the {SPACING_K} nearest, isolated points "
                     f"left out): {spacing_from_rows(rows):.6g}")
        lines.append(f"isolated points (mean neighbour distance > {ISOLATED_FACTOR:g}x the "
                     f"median; pcprep outliers removes them): {iso}")
    if extent is not None:
        lo, hi = extent
        lines.append(f"bounding box min: {' '.join(f'{v:.17g}' for v in lo)}")
        lines.append(f"bounding box max: {' '.join(f'{v:.17g}' for v in hi)}")
        lines.append(f"diagonal: {float(np.linalg.norm(hi - lo)):.6g}")
    if "crs" in meta:
        lines.append(f"CRS: {meta['crs']}")
    header = meta.get("las_header")
    if header is not None:
        lines.append(f"LAS {header.version}, point format {header.point_format.id}, "
                     f"scale {[float(v) for v in header.scales]}, "
                     f"offset {[float(v) for v in header.offsets]}, "
                     f"{len(header.vlrs)} VLR(s)")
    lines.append("attributes:")
    for name, dtype, rng in fields:
        lines.append(f"  {name:<24} {dtype:<10} {rng}")
    sys.stdout.write("\n".join(lines) + "\n")


def _cmd_info_tiled(args) -> None:
    """``pcprep info`` of a cloud larger than memory: one pass over the
    file's blocks for the counts, the non-finite rows, the bounding box and
    every field's range (``FieldRanges``), which also writes the finite
    positions to the scratch folder (the file is decoded once), then the
    spacing rows by tiles on Dask (``tiles.spacing_rows``).  Formats read
    whole are read whole."""
    import shutil

    from pcprep.filters.neighbors import SPACING_K

    from . import tiles
    from .cloud import FieldRanges
    from .formats import stream

    path = args.input
    _require_dask("info")
    blocks = stream._block_reader(path)
    if blocks is None:
        log.info("info: %s is read whole (its format is not read in blocks)", path)
        _cmd_info(path)
        return
    meta, n, dropped, ranges = {}, 0, [], FieldRanges()
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    scratch = _scratch_folder(args.scratch, "pcprep-info-")
    try:
        finite_path = os.path.join(scratch, "finite.raw")
        with open(finite_path, "wb") as finite_out:
            for start, block in blocks(stream.CHUNK):
                meta, n = meta or block.meta, start + len(block)
                bad = ~np.isfinite(block.points).all(axis=1)
                if bad.any():
                    dropped.extend((start + np.flatnonzero(bad)).tolist())
                    block = block.subset(np.flatnonzero(~bad), keep_faces=False)
                ranges.add(block)
                if len(block):
                    lo = np.minimum(lo, block.points.min(axis=0))
                    hi = np.maximum(hi, block.points.max(axis=0))
                    finite_out.write(np.ascontiguousarray(block.points, np.float64).tobytes())
        finite = n - len(dropped)
        rows = None
        if finite > SPACING_K:
            xyz = np.memmap(finite_path, dtype=np.float64, mode="r", shape=(finite, 3))
            with tiles.dask_client(workers=args.workers, scheduler=args.scheduler,
                                   memory_budget=args.memory_budget) as client:
                src = tiles.ingest(((s, xyz[s:s + stream.CHUNK])
                                    for s in range(0, finite, stream.CHUNK)), finite, scratch)
                del xyz
                rows = tiles.spacing_rows(src, client, scratch, args.tiles)
        tri = (stream.mesh_tail(path) or (None,))[0]  # a mesh read in blocks
        faces = None if tri is None else _faces_kept(tri, dropped)
        _print_info(path, meta, n, dropped, (lo, hi) if finite else None, rows,
                    ranges.rows(), faces)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _cmd_filters() -> None:
    from .apply import filter_parameter_text

    out = []
    for name in sorted(registry.load_all()):
        spec = registry.FILTERS[name]
        out.append(f"pcprep {spec.command}  ->  {name}")
        out.append(filter_parameter_text(name))
        out.append("")
    sys.stdout.write("\n".join(out))


#: what each kind of filter needs the output format to store
_NEEDS = {"coord": ("normal",), "scalar": ("quality", "attributes"),
          "selection": ("quality", "attributes"), "new_layer": (), "remove": ()}


def _jobs(args) -> list[tuple[str, str]]:
    """(input, output) pairs from ``IN OUT`` or ``IN... --out-dir DIR``."""
    from . import formats

    if args.out_dir is None:
        if len(args.paths) != 2:
            raise InvalidParameterError(
                f"{args.command}: give IN OUT, or several inputs with --out-dir DIR "
                f"(got {len(args.paths)} path(s))")
        if args.format is not None:
            raise InvalidParameterError(f"{args.command}: --format needs --out-dir")
        return [(args.paths[0], args.paths[1])]
    parent = os.path.dirname(os.path.abspath(args.out_dir))
    if not os.path.isdir(args.out_dir):
        if not os.path.isdir(parent):
            raise PointCloudError(f"--out-dir {args.out_dir!r}: folder {parent!r} does not exist")
        os.mkdir(args.out_dir)
    jobs = []
    for path in args.paths:
        stem, ext = os.path.splitext(os.path.basename(path))
        ext = "." + args.format.lstrip(".").lower() if args.format else ext
        jobs.append((path, os.path.join(args.out_dir, stem + ext)))
    outs = [o for _, o in jobs]
    twice = sorted({o for o in outs if outs.count(o) > 1})
    if twice:
        raise InvalidParameterError(f"two inputs would write the same file: {', '.join(twice)}")
    formats.check_destination(jobs[0][1])  # the folder and format, before any work
    return jobs


def _cmd_filter(args) -> int:
    spec = args._spec
    params = {p.name: getattr(args, p.name) for p in spec.params
              if getattr(args, p.name) is not None}
    spec.resolve(params)  # parameter errors before reading any file
    jobs = _jobs(args)
    if args.save_mlx:
        from .meshset import pcprep_step_script

        pcprep_step_script(spec, spec.resolve(params), args.save_mlx)
    if _tiled(args):
        for src, dst in jobs:
            _filter_file_tiled(spec, params, src, dst, args)
        return 0
    if len(jobs) == 1 and args.out_dir is None:
        _filter_file(spec, params, *jobs[0], args)
        return 0
    failed = []
    for src, dst in jobs:
        try:
            _filter_file(spec, params, src, dst, args)
        except (PointCloudError, InvalidParameterError, MissingAttributeError, OSError) as exc:
            log.error("%s: failed: %s", src, exc)
            failed.append((src, str(exc)))
    done = len(jobs) - len(failed)
    log.warning("%s: %d of %d file(s) done%s", spec.command, done, len(jobs),
                "" if not failed else "; failed: " + ", ".join(src for src, _ in failed))
    return 1 if failed else 0


def _filter_file(spec, params: dict, src: str, dst: str, args) -> None:
    from . import formats
    from .apply import result_cloud, run_on_cloud

    needs = _NEEDS[spec.kind]
    formats.check_destination(dst, needs=needs)  # before any work
    cloud = load_cloud(src, nonfinite="drop" if args.drop_nonfinite else "error")
    cloud = _dropped(cloud, args)
    dropped = cloud.meta.get("dropped_rows", ())
    if len(dropped):
        log.warning("%s: dropped %d row(s) with non-finite coordinates: %s", src,
                    len(dropped), ", ".join(map(str, dropped)))
    formats.check_cloud(cloud, dst, needs=needs)
    log.info("%s: %d points from %s", spec.command, len(cloud), src)
    result = run_on_cloud(spec, cloud, params)
    out = result_cloud(spec, cloud, result, dst=dst)
    if spec.kind == "remove":
        gone = np.setdiff1d(np.arange(len(cloud)), getattr(result, spec.index_field))
        shown = ", ".join(map(str, gone[:20])) + (", …" if len(gone) > 20 else "")
        log.warning("%s: removed %d of %d points%s", src, len(gone), len(cloud),
                    f" (rows {shown})" if len(gone) else "")
    save_cloud(out, dst, require=needs, ramp=spec.kind == "scalar")
    log.info("%s: wrote %d points to %s", spec.command, len(out), dst)


def _dropped(cloud, args):
    """``cloud`` without its faces (``--drop-faces``), their properties
    (``--drop-face-properties``) or a PLY's other elements
    (``--drop-elements``), as the user asked."""
    from .formats import stream

    return stream._dropped(cloud, args.drop_faces, args.drop_face_properties,
                           args.drop_elements)


def _tiled(args) -> bool:
    """Any of the large-cloud options asks for a tiled run."""
    return any(getattr(args, a, None) is not None
               for a in ("tiles", "workers", "scheduler", "memory_budget", "worker_io",
                         "scratch"))


def _require_dask(command: str) -> None:
    try:
        import distributed  # noqa: F401
    except ImportError as exc:
        raise InvalidParameterError(
            f"{command}: --tiles/--workers/--scheduler need Dask: pip install "
            "'pcprep[scale]'") from exc


def _filter_file_tiled(spec, params: dict, src: str, dst: str, args) -> None:
    """``_filter_file`` for a cloud larger than memory: positions (and, for a
    filter that uses them, the file's normals) streamed into scratch memory
    maps, the filter run tile by tile on Dask, the result streamed out with
    every attribute (meshlab_bridge/tiles.py)."""
    import shutil

    from . import formats, tiles
    from .formats import stream

    _require_dask(spec.command)
    if args.drop_nonfinite:
        raise InvalidParameterError(f"{spec.command}: --drop-nonfinite is not available "
                                    "with tiles")
    needs = _NEEDS[spec.kind]
    formats.check_destination(dst, needs=needs)
    drops = {"drop_faces": args.drop_faces, "drop_face_properties": args.drop_face_properties,
             "drop_elements": args.drop_elements}
    stream.check_fields(src, dst, **drops)  # before any work
    tiles._spec(registry, spec.name)  # a filter without a tiled form: refused here
    scratch = _scratch_folder(args.scratch, "pcprep-tiles-")
    try:
        n = stream.point_count(src)
        # the room for every array before anything is read (its normals, if the
        # file has them, are counted by run_tiled once they are read)
        tiles.check_scratch(scratch, tiles.scratch_need(spec.command, spec.resolve(dict(params)),
                                                        n), spec.command)
        # the cluster before the ingest: an attached one's workers warm up meanwhile
        with tiles.dask_client(workers=args.workers, scheduler=args.scheduler,
                               memory_budget=args.memory_budget) as client:
            source = tiles.ingest(stream.position_chunks(src), n, scratch)
            normals = None
            if spec.uses_normals:  # used as the one-piece run uses them
                normals = stream.normals_into(src, n, os.path.join(scratch, "input_normals.npy"))
            log.info("%s: %d points from %s (tiled%s)", spec.command, n, src,
                     ", with its normals" if normals is not None else "")
            res = tiles.run_tiled(spec.name, source=source, normals=normals, params=params,
                                  tiles=args.tiles, client=client, scratch=scratch,
                                  worker_io={"on": True, "off": False}.get(args.worker_io))
        written = stream.write_streamed(spec, src, dst, res.fields, n=n, **drops)
        log.info("%s: wrote %d points to %s (%d tiles, halo up to %.3g)", spec.command,
                 written, dst, res.stats["tiles"], res.stats["halo_max"])
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _cmd_run(args) -> None:
    from . import formats
    from .meshset import MeshSet

    ms = MeshSet()
    ms.load_filter_script(args.script)  # every step checked before anything runs
    formats.check_destination(args.output)
    if args.save_mlx:
        formats.check_destination(args.save_mlx + ".ply")  # its folder is writable
    cloud = load_cloud(args.input, nonfinite="drop" if args.drop_nonfinite else "error")
    # faces checked on the result only: the script may remove or make them
    formats.check_cloud(_dropped(cloud, args).with_(faces=None), args.output)
    ms.add_cloud(cloud)
    ms.apply_filter_script()
    out = _dropped(ms.current_cloud(), args)
    save_cloud(out, args.output)
    if args.save_mlx:
        ms.save_filter_script(args.save_mlx)
    log.info("run: %d steps, wrote %d points to %s", len(ms._loaded), len(out), args.output)


def _plugin_commands() -> list:
    """Sub-commands contributed by other layers through the ``pcprep.commands``
    entry-point group (``bench`` and ``report`` come from ``pcprep.baselines``),
    so this module never imports the layer above it."""
    from importlib.metadata import entry_points

    return [ep.load() for ep in sorted(entry_points(group="pcprep.commands"),
                                       key=lambda ep: ep.name)]


class _Bars:
    """Progress listener for a terminal: one tqdm bar per running step, shown
    only once the step has taken a second (tqdm's ``delay``)."""

    def __init__(self):
        from tqdm import tqdm

        self._tqdm = tqdm
        self._bars: dict = {}

    def __call__(self, name: str, done: int, total: int) -> None:
        bar = self._bars.get(name)
        if done < 0:
            if bar is not None:
                bar.close()
                del self._bars[name]
            return
        if bar is None:
            bar = self._bars[name] = self._tqdm(total=total, desc=f"pcprep: {name}",
                                                delay=1.0, leave=False, file=sys.stderr,
                                                dynamic_ncols=True)
        bar.update(done - bar.n)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    quiet = getattr(args, "quiet", False)
    logging.basicConfig(format="pcprep: %(message)s", stream=sys.stderr,
                        level=logging.WARNING if quiet else logging.INFO)
    # laspy logs each LAZ backend's failure before it raises; the exception
    # reaches the user once, as pcprep's own error naming the file
    logging.getLogger("laspy").setLevel(logging.CRITICAL)
    from pcprep.filters import progress as _progress

    bars = sys.stderr.isatty() and not quiet
    previous = _progress.set_listener(_Bars() if bars else None)
    with _log_through_bars(bars):
        return _dispatch(args, previous)


def _log_through_bars(bars: bool):
    """While bars are shown, log lines are printed above them, not through them."""
    if not bars:
        from contextlib import nullcontext

        return nullcontext()
    from tqdm.contrib.logging import logging_redirect_tqdm

    return logging_redirect_tqdm()


def _dispatch(args, previous) -> int:
    from pcprep.filters import progress as _progress

    try:
        if args.command == "info" and _tiled(args):
            _cmd_info_tiled(args)
        elif args.command == "info":
            _cmd_info(args.input)
        elif args.command == "filters":
            _cmd_filters()
        elif args.command == "run":
            _cmd_run(args)
        elif hasattr(args, "_run"):
            args._run(args)
        else:
            return _cmd_filter(args)
    except (PointCloudError, InvalidParameterError, MissingAttributeError,
            WorkersLostError) as exc:
        sys.stderr.write(f"pcprep: error: {exc}\n")
        return 1
    except OSError as exc:  # unreadable input, unwritable output, missing folder
        sys.stderr.write(f"pcprep: error: {exc}\n")
        return 1
    except MemoryError:
        sys.stderr.write("pcprep: error: out of memory\n")
        return 1
    except KeyboardInterrupt:
        sys.stderr.write("pcprep: interrupted\n")
        return 130
    finally:
        _progress.set_listener(previous)
    return 0


if __name__ == "__main__":
    sys.exit(main())
