"""
commands.py
-----------
The ``bench`` and ``report`` sub-commands of ``pcprep``.  The command line lives
in ``pcprep.meshlab_bridge`` and must not import this layer, so these commands
reach it through the ``pcprep.commands`` entry-point group (see pyproject.toml);
each entry is a function that adds its sub-parser.  The harness needs the
``report`` extra (CGAL's bindings, matplotlib): without it the commands say how
to install it instead of failing on an import deep inside a harness.
"""

from __future__ import annotations

from importlib import import_module
from importlib.util import find_spec

from pcprep.filters._validation import InvalidParameterError
from pcprep.meshlab_bridge.specs import FAMILIES

def benchmarked_families() -> tuple[str, ...]:
    """The families of ``FAMILIES`` that have a ``bench_<family>`` module."""
    return tuple(f for f in FAMILIES if find_spec(f"pcprep.baselines.bench_{f}") is not None)


#: modules of the ``report`` extra, checked before a harness starts
_EXTRA = ("CGAL", "matplotlib", "markdown_it")


def _check_extra() -> None:
    missing = []
    for mod in _EXTRA:
        try:
            import_module(mod)
        except ImportError:
            missing.append(mod)
    if missing:
        raise InvalidParameterError(
            f"the benchmarks need {', '.join(missing)}: install them with "
            "pip install 'pcprep[report]'")


def _out(args) -> str:
    """The output folder, checked before any harness runs: quick runs go to their
    own folder so they never overwrite a full run."""
    import os

    out = args.out if args.out is not None else ("reports/quick" if args.quick else "reports")
    if os.path.exists(out) and not os.path.isdir(out):
        raise InvalidParameterError(f"--out {out!r} is a file, not a folder")
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        raise InvalidParameterError(f"--out {out!r}: cannot create it ({exc.strerror})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InvalidParameterError(f"--out {out!r} is not writable")
    return out


def _run_bench(args) -> None:
    _check_extra()
    out = _out(args)
    mod = import_module(f"pcprep.baselines.bench_{args.family}")
    fn = mod.run_speed if args.speed else mod.run
    fn(quick=args.quick, seed=args.seed, out_dir=out)


def _run_report(args) -> None:
    _check_extra()
    out = _out(args)
    from . import report

    report.build(quick=args.quick, seed=args.seed, out_dir=out,
                 assemble_only=args.assemble_only, models=args.models)


def add_bench(sub) -> None:
    """``pcprep bench FAMILY``: one comparison harness, written under reports/."""
    bench = sub.add_parser("bench", help="run one comparison harness; writes reports/")
    bench.add_argument("family", choices=(*benchmarked_families(), "robustness", "scale",
                                          "memory", "departures"))
    bench.add_argument("--quick", action="store_true", help="small generated data, minutes")
    bench.add_argument("--speed", action="store_true", help="the speed benchmark instead")
    bench.add_argument("--out", default=None,
                       help="output folder (default: reports, or reports/quick with --quick)")
    bench.add_argument("--seed", type=int, default=0)
    bench.add_argument("--quiet", action="store_true")
    bench.set_defaults(_run=_run_bench)


def add_report(sub) -> None:
    """``pcprep report``: every harness, then reports/index.md and index.html."""
    rep = sub.add_parser("report", help="run every harness and write reports/index.md + .html")
    rep.add_argument("--quick", action="store_true",
                     help="generated and pymeshlab-shipped data only; a few minutes")
    rep.add_argument("--out", default=None,
                     help="output folder (default: reports, or reports/quick with --quick)")
    rep.add_argument("--models", default=None,
                     help="folder of the public models (default: $PCPREP_SHARED_MODELS, else "
                          "shared/data/models beside or above the current folder)")
    rep.add_argument("--assemble-only", action="store_true",
                     help="do not re-run the harnesses; assemble the index from the reports "
                          "already in the output folder")
    rep.add_argument("--seed", type=int, default=0)
    rep.add_argument("--quiet", action="store_true")
    rep.set_defaults(_run=_run_report)


def _run_sample(args) -> None:
    import numpy as np

    from pcprep.meshlab_bridge import formats
    from pcprep.meshlab_bridge.cloud import Cloud

    from .datasets import SHAPES, add_noise, make_shape

    if args.shape not in SHAPES:
        raise InvalidParameterError(f"sample: shape must be one of {', '.join(SHAPES)}, "
                                    f"got {args.shape!r}")
    formats.check_destination(args.output, needs=("normal",))
    s = make_shape(args.shape, n=args.n, seed=args.seed)
    pts = s.points
    if args.noise > 0:
        pts = add_noise(s.points, s.normals, sigma=args.noise, h=s.h, kind="normal",
                        seed=args.seed)
    attrs = {"sharp_truth": s.sharp.astype(np.uint8), "rim_truth": s.rim.astype(np.uint8)}
    formats.write_cloud(Cloud(np.asarray(pts, np.float64), s.normals, attributes=attrs),
                        args.output)


def add_sample(sub) -> None:
    """``pcprep sample SHAPE OUT``: a generated test cloud with its ground truth."""
    p = sub.add_parser("sample", help="write a generated CAD-like test cloud (with its "
                                      "sharp-edge and border truth as attributes)")
    p.add_argument("shape", help="cube, octahedron, block, star, fandisk, sphere, plane, "
                                 "bumpy_plane or disc")
    p.add_argument("output", help="output file (.ply, .las, .laz, .pcd, .xyz)")
    p.add_argument("--n", type=int, default=20000, help="number of points (default 20000)")
    p.add_argument("--noise", type=float, default=0.0,
                   help="Gaussian noise along the normals, in units of h (default 0)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(_run=_run_sample)
