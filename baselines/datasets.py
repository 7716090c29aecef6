"""
datasets.py
-----------
Point clouds with ground truth for tests and benchmarks: analytic CAD solids and
smooth surfaces sampled with exact normals and sharp-edge / rim labels, the noise
models of thesis §4.5 and hole cutting.  Triangle-mesh ground truth and loaders
(pymeshlab's bundled samples, the optional shared model folder) are in
``meshes.py`` and re-exported here.

Nothing here needs the shared model folder at run time: the shared loader returns
``None`` (or raises, on request) when the folder is absent.

Conventions
-----------
* Every shape is sampled by rejection from parametric patches whose area element is
  known, so ``uniform=True`` gives exactly ``n`` i.i.d. points uniform by area.
* ``uniform=False`` multiplies the density by ``1 + 4 s`` where ``s`` in [0, 1] is
  the normalised coordinate along the shape's first canonical axis (x): the
  density varies linearly and smoothly 1:5 from the ``-x`` end to the ``+x`` end
  (the thesis' "irregular sampling", §4.5.3.1).
* The "dihedral angle" of an edge is the angle between the outward normals of the
  two faces that meet there (0° = flat, 90° = cube edge).  A point is ``sharp``
  when its distance to an edge whose angle exceeds ``sharp_angle_deg`` (default
  30°) is at most ``sharp_width`` (default 1) times h; distances are computed to
  the analytic edges (segments, circles, finely sampled polylines for the curved
  creases of "fandisk").
* ``rim`` marks points within ``rim_width`` (default 1.5) h of a surface boundary
  (open shapes, cut holes); closed shapes get an all-False ``rim``.
* h is :func:`pcprep.filters.neighbors.average_spacing` of the returned points.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from pcprep.filters._validation import (
    InvalidParameterError,
    PointCloudError,
    as_normals,
    as_points,
    check_choice,
    check_param,
    check_seed,
)
from pcprep.filters.neighbors import average_spacing

from ._sample import Sample, _segment_distance

log = logging.getLogger("pcprep")

SHAPES = ("cube", "octahedron", "block", "star", "fandisk", "sphere", "plane",
          "bumpy_plane", "disc")
#: shapes of the held-out cases only (CAD parts with concave creases and thin walls,
#: cylinder, frustum, torus, a sphere with features of several sizes)
HELD_OUT_SHAPES = ("bracket", "channel", "steps", "cylinder", "cone", "torus",
                   "bumpy_sphere")
ALL_SHAPES = SHAPES + HELD_OUT_SHAPES
NOISE_KINDS = ("normal", "random", "impulsive", "view")


# ---------------------------------------------------------------------------
# parametric patches: each draws candidates uniformly over its parameter box and
# returns an acceptance probability (0/1 for trimmed regions, area-element ratio
# for height fields), so that accepted points are uniform by area.

@dataclass(frozen=True)
class _Patch:
    area: float  # surface measure of the parameter box (times max area element)
    draw: Callable  # (m, rng) -> (points, normals, accept in [0, 1])


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _rect(origin, u, v, normal, keep=None) -> _Patch:
    """Parallelogram origin + s u + t v (s, t in [0, 1]), optionally trimmed by
    ``keep(points) -> bool``."""
    o, u, v = (np.asarray(a, dtype=np.float64) for a in (origin, u, v))
    nrm = _unit(normal)

    def draw(m, rng):
        st = rng.random((m, 2))
        p = o + st[:, :1] * u + st[:, 1:] * v
        acc = np.ones(m) if keep is None else keep(p).astype(np.float64)
        return p, np.broadcast_to(nrm, (m, 3)).copy(), acc

    return _Patch(float(np.linalg.norm(np.cross(u, v))), draw)


def _tri(a, b, c, normal) -> _Patch:
    """Triangle, sampled by folding the unit square (no rejection)."""
    a, b, c = (np.asarray(x, dtype=np.float64) for x in (a, b, c))
    nrm = _unit(normal)

    def draw(m, rng):
        st = rng.random((m, 2))
        flip = st.sum(axis=1) > 1.0
        st[flip] = 1.0 - st[flip]
        p = a + st[:, :1] * (b - a) + st[:, 1:] * (c - a)
        return p, np.broadcast_to(nrm, (m, 3)).copy(), np.ones(m)

    return _Patch(0.5 * float(np.linalg.norm(np.cross(b - a, c - a))), draw)


def _cylinder(center, e1, e2, axis, radius, theta, zrange, inward=False, keep=None):
    """Cylinder patch center + R (cos t e1 + sin t e2) + z axis, t in ``theta``,
    z in ``zrange``; the normal is radial (toward the axis when ``inward``)."""
    c, e1, e2, ax = (np.asarray(x, dtype=np.float64) for x in (center, e1, e2, axis))
    t0, t1 = theta
    z0, z1 = zrange

    def draw(m, rng):
        t = t0 + (t1 - t0) * rng.random(m)
        z = z0 + (z1 - z0) * rng.random(m)
        radial = np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2
        p = c + radius * radial + z[:, None] * ax
        nrm = -radial if inward else radial
        acc = np.ones(m) if keep is None else keep(p).astype(np.float64)
        return p, nrm, acc

    return _Patch(radius * (t1 - t0) * (z1 - z0), draw)


def _sphere(radius) -> _Patch:
    """Sphere by Archimedes' projection: uniform z and azimuth."""

    def draw(m, rng):
        z = 2.0 * rng.random(m) - 1.0
        phi = 2.0 * np.pi * rng.random(m)
        r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        nrm = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
        return radius * nrm, nrm, np.ones(m)

    return _Patch(4.0 * np.pi * radius**2, draw)


def _sample_patches(patches, n, rng, density=None, density_max=1.0):
    """Exactly ``n`` i.i.d. points from the union of ``patches``, uniform by area
    (times ``density(points)/density_max`` when given)."""
    area = np.array([p.area for p in patches])
    prob = area / area.sum()
    chunks_p, chunks_n = [], []
    got, rate = 0, 0.5
    while got < n:
        m = int(min(4_000_000, max(2048, 1.3 * (n - got) / max(rate, 0.02))))
        counts = rng.multinomial(m, prob)
        ps, ns, acc = [], [], []
        for patch, c in zip(patches, counts):
            if c:
                p, q, a = patch.draw(int(c), rng)
                ps.append(p)
                ns.append(q)
                acc.append(a)
        p, q, a = np.concatenate(ps), np.concatenate(ns), np.concatenate(acc)
        if density is not None:
            a = a * (density(p) / density_max)
        ok = rng.random(m) < a
        perm = rng.permutation(int(ok.sum()))
        chunks_p.append(p[ok][perm])
        chunks_n.append(q[ok][perm])
        got += int(ok.sum())
        rate = max(ok.mean(), 1e-3)
    return np.concatenate(chunks_p)[:n], np.concatenate(chunks_n)[:n]


# ---------------------------------------------------------------------------
# analytic edges

@dataclass
class _Edges:
    """Sharp-edge geometry: segments (a, b, angle) and full circles (c, axis, R,
    angle), angles in degrees between the adjacent outward normals."""

    seg_a: list = field(default_factory=list)
    seg_b: list = field(default_factory=list)
    seg_ang: list = field(default_factory=list)
    circles: list = field(default_factory=list)

    def segment(self, a, b, angle):
        self.seg_a.append(np.asarray(a, dtype=np.float64))
        self.seg_b.append(np.asarray(b, dtype=np.float64))
        self.seg_ang.append(float(angle))

    def polyline(self, pts, angles):
        pts = np.asarray(pts, dtype=np.float64)
        angles = np.broadcast_to(np.asarray(angles, dtype=np.float64), (len(pts) - 1,))
        for i in range(len(pts) - 1):
            self.segment(pts[i], pts[i + 1], angles[i])

    def circle(self, center, axis, radius, angle):
        self.circles.append((np.asarray(center, float), _unit(axis), float(radius),
                             float(angle)))

    def distance(self, points, min_angle_deg, step):
        """(n,) distance from each point to the nearest edge sharper than
        ``min_angle_deg`` (inf when there is none); segment candidates come from a
        KD-tree over the segments densified at ``step`` (see _segment_distance)."""
        out = np.full(len(points), np.inf)
        if self.seg_a:
            sel = np.array(self.seg_ang) > min_angle_deg
            if sel.any():
                out = _segment_distance(points, np.array(self.seg_a)[sel],
                                        np.array(self.seg_b)[sel], step, k=16)
        for c, ax, r, ang in self.circles:
            if ang > min_angle_deg:
                q = points - c
                z = q @ ax
                rad = np.linalg.norm(q - z[:, None] * ax, axis=1)
                out = np.minimum(out, np.hypot(rad - r, z))
        return out


# ---------------------------------------------------------------------------
# the shapes.  Each builder returns (patches, edges, boundary_distance or None,
# extra_fn or None); boundary_distance(points) gives the distance to the open
# border of open surfaces.

def _build_cube():
    a = 0.5
    patches = []
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        for s in (-1.0, 1.0):
            o = np.zeros(3)
            o[i], o[j], o[k] = s * a, -a, -a
            u = np.zeros(3)
            u[j] = 2 * a
            v = np.zeros(3)
            v[k] = 2 * a
            nrm = np.zeros(3)
            nrm[i] = s
            patches.append(_rect(o, u, v, nrm))
    edges = _Edges()
    corners = np.array([[x, y, z] for x in (-a, a) for y in (-a, a) for z in (-a, a)])
    for i in range(8):
        for j in range(i + 1, 8):
            if np.count_nonzero(corners[i] != corners[j]) == 1:
                edges.segment(corners[i], corners[j], 90.0)
    return patches, edges, None, None


def _build_octahedron():
    patches = []
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            for sz in (-1.0, 1.0):
                patches.append(_tri([sx, 0, 0], [0, sy, 0], [0, 0, sz], [sx, sy, sz]))
    edges = _Edges()
    angle = np.degrees(np.arccos(1.0 / 3.0))  # 70.53°
    e = np.eye(3)
    for i in range(3):
        for j in range(i + 1, 3):
            for si in (-1.0, 1.0):
                for sj in (-1.0, 1.0):
                    edges.segment(si * e[i], sj * e[j], angle)
    return patches, edges, None, None


_BLOCK = dict(ax=1.0, ay=0.75, az=0.5, r=0.4)


def _build_block():
    """Box [-1,1]x[-0.75,0.75]x[-0.5,0.5] with a vertical (z) cylindrical through-
    hole of radius 0.4 at the centre; 12 box edges and the two hole rims are 90°."""
    ax, ay, az, r = (_BLOCK[k] for k in ("ax", "ay", "az", "r"))
    outside = lambda p: p[:, 0] ** 2 + p[:, 1] ** 2 >= r * r  # noqa: E731
    patches = [
        _rect([ax, -ay, -az], [0, 2 * ay, 0], [0, 0, 2 * az], [1, 0, 0]),
        _rect([-ax, -ay, -az], [0, 2 * ay, 0], [0, 0, 2 * az], [-1, 0, 0]),
        _rect([-ax, ay, -az], [2 * ax, 0, 0], [0, 0, 2 * az], [0, 1, 0]),
        _rect([-ax, -ay, -az], [2 * ax, 0, 0], [0, 0, 2 * az], [0, -1, 0]),
        _rect([-ax, -ay, az], [2 * ax, 0, 0], [0, 2 * ay, 0], [0, 0, 1], keep=outside),
        _rect([-ax, -ay, -az], [2 * ax, 0, 0], [0, 2 * ay, 0], [0, 0, -1], keep=outside),
        _cylinder([0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], r, (0.0, 2 * np.pi),
                  (-az, az), inward=True),
    ]
    edges = _Edges()
    corners = np.array([[x, y, z] for x in (-ax, ax) for y in (-ay, ay)
                        for z in (-az, az)])
    for i in range(8):
        for j in range(i + 1, 8):
            if np.count_nonzero(corners[i] != corners[j]) == 1:
                edges.segment(corners[i], corners[j], 90.0)
    edges.circle([0, 0, az], [0, 0, 1], r, 90.0)
    edges.circle([0, 0, -az], [0, 0, 1], r, 90.0)
    return patches, edges, None, None


def _star_polygon(tips=5, r_out=1.0, r_in=0.45):
    k = np.arange(2 * tips)
    ang = np.pi / 2 + k * np.pi / tips
    rad = np.where(k % 2 == 0, r_out, r_in)
    return np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])  # CCW


def _build_star():
    """Five-pointed star (outer radius 1, inner 0.45) extruded over z in
    [-0.25, 0.25]: flat top/bottom, ten side walls; creases at every polygon
    edge (90°) and at the convex tips and reflex notches (vertical edges)."""
    poly = _star_polygon()
    zt = 0.25
    m = len(poly)
    patches = []
    side_n = []
    for i in range(m):
        p, q = poly[i], poly[(i + 1) % m]
        patches.append(_tri([0, 0, zt], [p[0], p[1], zt], [q[0], q[1], zt], [0, 0, 1]))
        patches.append(_tri([0, 0, -zt], [p[0], p[1], -zt], [q[0], q[1], -zt],
                            [0, 0, -1]))
        d = q - p
        nrm = _unit([d[1], -d[0], 0.0])  # outward for a CCW polygon
        side_n.append(nrm)
        patches.append(_rect([p[0], p[1], -zt], [d[0], d[1], 0], [0, 0, 2 * zt], nrm))
    edges = _Edges()
    for i in range(m):
        p, q = poly[i], poly[(i + 1) % m]
        edges.segment([p[0], p[1], zt], [q[0], q[1], zt], 90.0)
        edges.segment([p[0], p[1], -zt], [q[0], q[1], -zt], 90.0)
        ang = np.degrees(np.arccos(np.clip(side_n[i - 1] @ side_n[i], -1, 1)))
        edges.segment([p[0], p[1], -zt], [p[0], p[1], zt], ang)
    return patches, edges, None, None


_FAN = dict(R=2.0, zc=-1.0, ax=1.0, ay=0.5, cut=1.3)


def _fan_top(x):
    return _FAN["zc"] + np.sqrt(_FAN["R"] ** 2 - x * x)


def _build_fandisk():
    """Fandisk-like part: block x in [-1,1], y in [-0.5,0.5], bottom z = 0, whose
    top is a cylinder of radius 2 with axis along y through (0, ., -1) (height 1 at
    x = 0, 0.732 at x = ±1), with the vertical corner edge at (+1, +0.5) cut by
    the slanted plane x + y = 1.3.  Creases: top/front and top/back 90°,
    top/±x sides 60°, top/cut 69-73° (a non-planar curve), cut/sides 45°, the
    other vertical and all bottom edges 90°.  The cylinder is a smooth curved
    face, so curvature alone must not flag it."""
    R, zc, ax, ay, cut = (_FAN[k] for k in ("R", "zc", "ax", "ay", "cut"))
    tmax = np.arcsin(ax / R)
    under = lambda p: p[:, 2] <= _fan_top(p[:, 0])  # noqa: E731
    incut = lambda p: p[:, 0] + p[:, 1] <= cut  # noqa: E731
    xc = cut - ay  # x where the cut meets the back face (0.8)
    yc = cut - ax  # y where the cut meets the +x face (0.3)
    patches = [
        # top cylinder: theta from the +z axis toward +x, axis along y
        _cylinder([0, 0, zc], [0, 0, 1], [1, 0, 0], [0, 1, 0], R, (-tmax, tmax),
                  (-ay, ay), keep=incut),
        _rect([-ax, -ay, 0], [2 * ax, 0, 0], [0, 0, 1], [0, -1, 0], keep=under),
        _rect([-ax, ay, 0], [ax + xc, 0, 0], [0, 0, 1], [0, 1, 0], keep=under),
        _rect([xc, ay, 0], [ax - xc, yc - ay, 0], [0, 0, 1], [1, 1, 0], keep=under),
        _rect([ax, -ay, 0], [0, yc + ay, 0], [0, 0, _fan_top(ax)], [1, 0, 0]),
        _rect([-ax, -ay, 0], [0, 2 * ay, 0], [0, 0, _fan_top(-ax)], [-1, 0, 0]),
        _rect([-ax, -ay, 0], [2 * ax, 0, 0], [0, 2 * ay, 0], [0, 0, -1], keep=incut),
    ]
    edges = _Edges()
    base = np.array([[-ax, -ay], [ax, -ay], [ax, yc], [xc, ay], [-ax, ay]])
    vert_ang = [90.0, 90.0, 45.0, 45.0, 90.0]
    for i in range(5):
        p, q = base[i], base[(i + 1) % 5]
        edges.segment([p[0], p[1], 0], [q[0], q[1], 0], 90.0)
        edges.segment([p[0], p[1], 0], [p[0], p[1], _fan_top(p[0])], vert_ang[i])
    xs = np.linspace(-ax, ax, 257)
    edges.polyline(np.column_stack([xs, np.full_like(xs, -ay), _fan_top(xs)]), 90.0)
    xs = np.linspace(-ax, xc, 231)
    edges.polyline(np.column_stack([xs, np.full_like(xs, ay), _fan_top(xs)]), 90.0)
    xs = np.linspace(xc, ax, 33)
    xm = 0.5 * (xs[1:] + xs[:-1])
    cut_ang = np.degrees(np.arccos((xm / R) / np.sqrt(2.0)))
    edges.polyline(np.column_stack([xs, cut - xs, _fan_top(xs)]), cut_ang)
    side_ang = np.degrees(np.arccos(ax / R))  # 60°
    edges.segment([ax, -ay, _fan_top(ax)], [ax, yc, _fan_top(ax)], side_ang)
    edges.segment([-ax, -ay, _fan_top(-ax)], [-ax, ay, _fan_top(-ax)], side_ang)
    return patches, edges, None, None


def _build_sphere():
    return [_sphere(1.0)], _Edges(), None, None


def _square_boundary(p):
    return np.minimum(1.0 - np.abs(p[:, 0]), 1.0 - np.abs(p[:, 1]))


def _build_plane():
    """Square patch [-1,1]^2 at z = 0, normal +z, open boundary."""
    return ([_rect([-1, -1, 0], [2, 0, 0], [0, 2, 0], [0, 0, 1])], _Edges(),
            _square_boundary, None)


def _build_disc():
    """Flat unit disc at z = 0, normal +z; its circle is the boundary."""
    keep = lambda p: p[:, 0] ** 2 + p[:, 1] ** 2 <= 1.0  # noqa: E731
    bd = lambda p: 1.0 - np.hypot(p[:, 0], p[:, 1])  # noqa: E731
    patch = _rect([-1, -1, 0], [2, 0, 0], [0, 2, 0], [0, 0, 1], keep=keep)
    return [patch], _Edges(), bd, None


#: bumps of "bumpy_plane": (cx, cy, amplitude, sigma); one is a dent
BUMPS = np.array([
    [-0.50, -0.40, 0.25, 0.15],
    [0.45, 0.50, 0.15, 0.12],
    [0.40, -0.45, -0.20, 0.16],
    [-0.40, 0.45, 0.10, 0.10],
])


def _bumps(x, y):
    """Height, gradient and per-bump normalised magnitude of the bump field."""
    dx = x[:, None] - BUMPS[:, 0]
    dy = y[:, None] - BUMPS[:, 1]
    g = np.exp(-(dx * dx + dy * dy) / (2 * BUMPS[:, 3] ** 2))  # (n, 4)
    z = (BUMPS[:, 2] * g).sum(axis=1)
    fx = (-BUMPS[:, 2] * g * dx / BUMPS[:, 3] ** 2).sum(axis=1)
    fy = (-BUMPS[:, 2] * g * dy / BUMPS[:, 3] ** 2).sum(axis=1)
    return z, fx, fy, g


def _build_bumpy_plane():
    """Square [-1,1]^2 height field z = sum_k a_k exp(-r_k^2 / (2 s_k^2)) with the
    four bumps of ``BUMPS`` (one a dent).  Ground truth: ``extra["saliency"]`` =
    max_k exp(-r_k^2/(2 s_k^2)) in [0, 1] and ``extra["salient"]`` = saliency >
    exp(-2) (within 2 s_k of a bump centre)."""
    # upper bound of |grad f| (triangle inequality over bumps, each |a|/s e^-1/2)
    gmax = float(np.sum(np.abs(BUMPS[:, 2]) / BUMPS[:, 3]) * np.exp(-0.5))
    jmax = np.sqrt(1.0 + gmax * gmax)

    def draw(m, rng):
        xy = 2.0 * rng.random((m, 2)) - 1.0
        z, fx, fy, _ = _bumps(xy[:, 0], xy[:, 1])
        jac = np.sqrt(1.0 + fx * fx + fy * fy)
        nrm = np.column_stack([-fx, -fy, np.ones(m)]) / jac[:, None]
        return np.column_stack([xy, z]), nrm, jac / jmax

    def extra(p):
        _, _, _, g = _bumps(p[:, 0], p[:, 1])
        sal = g.max(axis=1)
        return {"saliency": sal, "salient": sal > np.exp(-2.0)}

    return [_Patch(4.0 * jmax, draw)], _Edges(), _square_boundary, extra


# ---------------------------------------------------------------------------
# held-out shapes: never used to choose a default (docs/decisions/benchmarks.md)

def _in_polygon(xy, poly):
    """Even-odd point-in-polygon test of (m, 2) points against a closed polygon."""
    x, y = xy[:, 0], xy[:, 1]
    inside = np.zeros(len(xy), dtype=bool)
    for i in range(len(poly)):
        (x0, y0), (x1, y1) = poly[i], poly[(i + 1) % len(poly)]
        cross = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xi = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= cross & (x < xi)
    return inside


def _extrusion(poly, zt):
    """A simple CCW polygon extruded over z in [-zt, zt]: caps trimmed by the
    polygon, one wall per polygon edge; cap edges are 90° creases and every
    vertical edge has the turning angle of its polygon vertex (convex and
    concave vertices alike: the angle between the two walls' outward normals)."""
    poly = np.asarray(poly, dtype=np.float64)
    m = len(poly)
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    inside = lambda p: _in_polygon(p[:, :2], poly)  # noqa: E731
    span = hi - lo
    patches = [
        _rect([lo[0], lo[1], zt], [span[0], 0, 0], [0, span[1], 0], [0, 0, 1], keep=inside),
        _rect([lo[0], lo[1], -zt], [span[0], 0, 0], [0, span[1], 0], [0, 0, -1],
              keep=inside),
    ]
    side_n = []
    for i in range(m):
        p, q = poly[i], poly[(i + 1) % m]
        d = q - p
        nrm = _unit([d[1], -d[0], 0.0])  # outward for a CCW polygon
        side_n.append(nrm)
        patches.append(_rect([p[0], p[1], -zt], [d[0], d[1], 0], [0, 0, 2 * zt], nrm))
    edges = _Edges()
    for i in range(m):
        p, q = poly[i], poly[(i + 1) % m]
        edges.segment([p[0], p[1], zt], [q[0], q[1], zt], 90.0)
        edges.segment([p[0], p[1], -zt], [q[0], q[1], -zt], 90.0)
        ang = np.degrees(np.arccos(np.clip(side_n[i - 1] @ side_n[i], -1, 1)))
        edges.segment([p[0], p[1], -zt], [p[0], p[1], zt], ang)
    return patches, edges, None, None


#: profiles of the extruded held-out CAD parts (CCW, canonical x in [-1, 1])
PROFILES = {
    # L-section with walls 0.06 thick: one concave 90° crease along the inside
    "bracket": ([(-1.0, -0.7), (1.0, -0.7), (1.0, -0.64), (-0.94, -0.64), (-0.94, 0.7),
                 (-1.0, 0.7)], 0.4),
    # U-section with walls 0.08 thick: two concave creases, two thin flanges
    "channel": ([(-1.0, -0.5), (1.0, -0.5), (1.0, 0.5), (0.92, 0.5), (0.92, -0.42),
                 (-0.92, -0.42), (-0.92, 0.5), (-1.0, 0.5)], 0.5),
    # staircase: convex and concave creases alternate
    "steps": ([(-1.0, -0.5), (1.0, -0.5), (1.0, 0.5), (0.33, 0.5), (0.33, 0.1),
               (-0.33, 0.1), (-0.33, -0.2), (-1.0, -0.2)], 0.5),
}


def _build_profile(name):
    poly, zt = PROFILES[name]
    return lambda: _extrusion(poly, zt)


def _disc_cap(z, radius, normal_z):
    keep = lambda p: p[:, 0] ** 2 + p[:, 1] ** 2 <= radius * radius  # noqa: E731
    return _rect([-radius, -radius, z], [2 * radius, 0, 0], [0, 2 * radius, 0],
                 [0, 0, normal_z], keep=keep)


_CYL = dict(r=0.6, zt=0.6)


def _build_cylinder():
    """Closed cylinder of radius 0.6 over z in [-0.6, 0.6]; both rims 90°."""
    r, zt = _CYL["r"], _CYL["zt"]
    patches = [_cylinder([0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], r, (0.0, 2 * np.pi),
                         (-zt, zt)),
               _disc_cap(zt, r, 1.0), _disc_cap(-zt, r, -1.0)]
    edges = _Edges()
    edges.circle([0, 0, zt], [0, 0, 1], r, 90.0)
    edges.circle([0, 0, -zt], [0, 0, 1], r, 90.0)
    return patches, edges, None, None


_CONE = dict(r0=0.8, r1=0.3, zt=0.5)


def _build_cone():
    """Closed frustum: radius 0.8 at z = -0.5 to 0.3 at z = +0.5, with flat caps;
    rims of 116.6° (bottom) and 63.4° (top)."""
    r0, r1, zt = _CONE["r0"], _CONE["r1"], _CONE["zt"]
    slope = (r0 - r1) / (2 * zt)  # radius lost per unit height
    nr, nz = 1.0 / np.hypot(1.0, slope), slope / np.hypot(1.0, slope)
    side_len = np.hypot(2 * zt, r0 - r1)

    def draw(m, rng):
        # area element ∝ radius(t): accept with radius / r0
        t = rng.random(m)
        phi = 2.0 * np.pi * rng.random(m)
        rad = r0 + (r1 - r0) * t
        z = -zt + 2 * zt * t
        c, s = np.cos(phi), np.sin(phi)
        p = np.column_stack([rad * c, rad * s, z])
        nrm = np.column_stack([nr * c, nr * s, np.full(m, nz)])
        return p, nrm, rad / r0

    side = _Patch(2.0 * np.pi * r0 * side_len, draw)
    patches = [side, _disc_cap(zt, r1, 1.0), _disc_cap(-zt, r0, -1.0)]
    edges = _Edges()
    edges.circle([0, 0, -zt], [0, 0, 1], r0, np.degrees(np.arccos(-nz)))
    edges.circle([0, 0, zt], [0, 0, 1], r1, np.degrees(np.arccos(nz)))
    return patches, edges, None, None


_TORUS = dict(R=0.7, r=0.3)


def _build_torus():
    """Torus of radii 0.7 / 0.3 around z; smooth, no edge, curvature up to 1/0.3
    and negative Gaussian curvature on the inside."""
    R, r = _TORUS["R"], _TORUS["r"]

    def draw(m, rng):
        u = 2.0 * np.pi * rng.random(m)
        v = 2.0 * np.pi * rng.random(m)
        cu, su, cv, sv = np.cos(u), np.sin(u), np.cos(v), np.sin(v)
        nrm = np.column_stack([cv * cu, cv * su, sv])
        p = np.column_stack([(R + r * cv) * cu, (R + r * cv) * su, r * sv])
        return p, nrm, (R + r * cv) / (R + r)

    return [_Patch(4.0 * np.pi ** 2 * r * (R + r), draw)], _Edges(), None, None


#: features of "bumpy_sphere": (unit direction, amplitude, angular sigma); bumps,
#: dents and narrow protrusions of several sizes on the unit sphere
SPHERE_BUMPS = (
    ((0.0, 0.0, 1.0), 0.20, 0.25),     # wide bump
    ((1.0, 0.0, 0.0), 0.12, 0.12),     # medium bump
    ((0.0, 1.0, 0.0), -0.15, 0.18),    # wide dent
    ((-1.0, 0.0, 0.0), -0.08, 0.08),   # small dent
    ((0.0, 0.0, -1.0), 0.30, 0.07),    # narrow protrusion
    ((0.0, -1.0, 0.0), 0.06, 0.05),    # small bump
    ((0.577, 0.577, -0.577), 0.22, 0.06),  # narrow protrusion
)


def _sphere_bumps(u):
    """Radius r(u), its tangential gradient and each feature's magnitude
    exp(-θ²/(2s²)) for unit directions u (n, 3)."""
    r = np.ones(len(u))
    grad = np.zeros_like(u)
    mags = []
    for c, a, s in SPHERE_BUMPS:
        c = _unit(c)
        cos_t = np.clip(u @ c, -1.0, 1.0)
        th = np.arccos(cos_t)
        g = np.exp(-th * th / (2 * s * s))
        r += a * g
        sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
        safe = sin_t > 1e-12
        e_th = np.zeros_like(u)  # unit tangent at u pointing away from c
        e_th[safe] = (u[safe] * cos_t[safe, None] - c) / sin_t[safe, None]
        grad += (-a * th * g / (s * s))[:, None] * e_th
        mags.append(g)
    return r, grad, np.column_stack(mags)


def _build_bumpy_sphere():
    """Unit sphere carrying the bumps, dents and protrusions of ``SPHERE_BUMPS``
    (radial height field r(u) = 1 + Σ a exp(-θ²/(2s²))).  Ground truth:
    ``extra["saliency"]`` = the largest feature magnitude and ``extra["salient"]``
    = within 2s of a feature centre."""
    amp = sum(abs(a) for _, a, _ in SPHERE_BUMPS)
    rmax = 1.0 + amp
    gmax = sum(abs(a) / s * np.exp(-0.5) for _, a, s in SPHERE_BUMPS)
    jmax = rmax * np.sqrt(rmax ** 2 + gmax ** 2)

    def draw(m, rng):
        z = 2.0 * rng.random(m) - 1.0
        phi = 2.0 * np.pi * rng.random(m)
        rr = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        u = np.column_stack([rr * np.cos(phi), rr * np.sin(phi), z])
        r, grad, _ = _sphere_bumps(u)
        nrm = r[:, None] * u - grad
        length = np.linalg.norm(nrm, axis=1)
        # area element of p(u) = r(u) u over the unit sphere: r sqrt(r² + |∇r|²)
        jac = r * np.sqrt(r * r + (grad * grad).sum(axis=1))
        return r[:, None] * u, nrm / length[:, None], jac / jmax

    def extra(p):
        u = p / np.linalg.norm(p, axis=1, keepdims=True)
        _, _, g = _sphere_bumps(u)
        sal = g.max(axis=1)
        return {"saliency": sal, "salient": sal > np.exp(-2.0)}

    return [_Patch(4.0 * np.pi * jmax, draw)], _Edges(), None, extra


_BUILDERS = {
    "cube": _build_cube, "octahedron": _build_octahedron, "block": _build_block,
    "star": _build_star, "fandisk": _build_fandisk, "sphere": _build_sphere,
    "plane": _build_plane, "bumpy_plane": _build_bumpy_plane, "disc": _build_disc,
    "bracket": _build_profile("bracket"), "channel": _build_profile("channel"),
    "steps": _build_profile("steps"), "cylinder": _build_cylinder, "cone": _build_cone,
    "torus": _build_torus, "bumpy_sphere": _build_bumpy_sphere,
}


def _rigid_motion(seed):
    rng = np.random.default_rng(None if seed is None else [seed, 7919])
    rot = Rotation.random(random_state=rng).as_matrix()
    return rot, rng.uniform(-1.0, 1.0, 3)


#: sampling styles of ``make_shape``: i.i.d. by area ("random"), its 1:5 and 1:10
#: linear density gradients ("gradient" is 1:10), blue noise like a scanner's
#: resampling ("blue"), registered range-grid scans with square pixels ("rows") and
#: with 1:3 pixels (anisotropic spacing, "aniso")
SAMPLINGS = ("random", "gradient", "blue", "rows", "aniso")
#: the truth rule of sharp edges: positive within the band of an edge of at least
#: SHARP_POSITIVE_DEG, negative when no edge of at least SHARP_IGNORE_DEG lies within
#: two bands, "don't care" otherwise (docs/decisions/benchmarks.md)
SHARP_POSITIVE_DEG = 40.0
SHARP_IGNORE_DEG = 20.0
#: the truth rule of borders (units of h on random samples): positive within
#: RIM_BAND, "don't care" out to RIM_CARE
RIM_BAND = 1.5
RIM_CARE = 2.5


def make_shape(name: str, n: int = 20000, seed: int | None = 0, uniform: bool = True,
               rotate: bool = False, scale: float = 1.0, *, sharp_angle_deg: float = 30.0,
               sharp_width: float = 1.0, rim_width: float = 1.5,
               sampling: str = "random") -> Sample:
    """Sample a synthetic shape with exact normals and feature labels.

    Parameters
    ----------
    name : str
        One of ``SHAPES`` or ``HELD_OUT_SHAPES`` (canonical frame, before
        ``rotate``/``scale``):

        * "cube": side 1, centred; 12 edges at 90°.
        * "octahedron": vertices ±e_i; 12 edges at 70.5°.
        * "block": box 2 x 1.5 x 1 with a z-axis through-hole of radius 0.4;
          12 box edges and the 2 hole rims at 90°.
        * "star": 5-pointed star (radii 1 / 0.45) extruded over z in [-0.25, 0.25];
          cap edges 90°, tips 134.8°, notches 62.8°.
        * "fandisk": block [-1,1] x [-0.5,0.5] with a cylindrical top (R = 2) and
          a vertical corner cut x + y = 1.3 (creases of 45° to 90°, see
          ``_build_fandisk``).
        * "sphere": radius 1.  "plane": square [-1,1]^2 at z = 0 (open).
        * "bumpy_plane": the square with the Gaussian bumps of ``BUMPS``.
        * "disc": unit disc at z = 0 (open).
        * held out: "bracket" (L-section, walls 0.06 thick), "channel" (U-section,
          walls 0.08), "steps" (staircase) -- extrusions of ``PROFILES`` with
          concave creases; "cylinder" (r 0.6, height 1.2, closed), "cone"
          (closed frustum, radii 0.8 / 0.3), "torus" (radii 0.7 / 0.3),
          "bumpy_sphere" (the bumps, dents and protrusions of ``SPHERE_BUMPS``).
    n : int, default=20000
        Number of points (>= 7): exact for "random", "gradient" and "blue"; the
        range-grid samplings ("rows", "aniso") choose their pixel pitch so that
        the count is within about 1 % of n.
    seed : int or None, default=0
        Sampling seed.  The rigid motion of ``rotate`` uses its own stream, so the
        same seed gives the same canonical points with or without it.
    uniform : bool, default=True
        Uniform by area; otherwise density 1:5 linear along canonical x (module
        notes).  Only with ``sampling="random"``.
    rotate : bool, default=False
        Apply a random rotation and a translation in [-1, 1]^3 (seeded).
    scale : float, default=1.0
        Multiplies all coordinates (after the motion); h scales with it.
    sharp_angle_deg : float, default=30
        Edges whose dihedral (normal-to-normal) angle exceeds this are sharp.
    sharp_width : float, default=1
        Band half-width around sharp edges, in units of h.
    rim_width : float, default=1.5
        Band width inside open boundaries, in units of h.
    sampling : {"random", "gradient", "blue", "rows", "aniso"}, default="random"
        * "random": i.i.d. uniform by area (or 1:5 with ``uniform=False``).
        * "gradient": density 1:10 linear along canonical x.
        * "blue": blue noise: greedy dart throwing over 5n random candidates
          with the largest exclusion radius that keeps n of them (no two points
          closer than that radius, like a scanner's resampled output).
        * "rows": six orthographic range scans along ± the axes of a seeded
          frame, square pixels; each pixel keeps the visible candidate nearest
          its centre (faces seen at more than 78° are not scanned), so points lie
          in rows on the true surface; the scans are merged.
        * "aniso": as "rows" with pixels 3 times longer in one direction
          (spacing 1:3 along and across the rows).

    Returns
    -------
    Sample
        ``extra["edge_distance"]`` holds each point's distance to the nearest sharp
        edge (in output units, inf when none) and ``extra["boundary_distance"]`` the
        distance to the open border for open shapes.  The benchmark truths
        (``sharp_truth`` / ``rim_truth``) come from ``extra["sharp_pos"]``,
        ``extra["sharp_care"]`` and ``extra["rim_care"]``; ``extra["view_dir"]``
        is the unit ray each point was seen along (the scan's for "rows" and
        "aniso", else from one seeded eye 3 diagonals away), for
        ``add_noise(kind="view")``.

    Examples
    --------
    >>> s = make_shape("cube", n=2000, seed=0)
    >>> s.points.shape, float(abs(s.points).max(axis=1).min())
    ((2000, 3), 0.5)
    >>> noisy = add_noise(s.points, s.normals, sigma=0.3, h=s.h, kind="normal", seed=1)
    """
    func = "make_shape"
    check_choice(name, func=func, name="name", choices=ALL_SHAPES)
    n = check_param(n, func=func, name="n", kind=int, low=7, unit="count")
    seed = check_seed(seed, func=func)
    uniform = check_param(uniform, func=func, name="uniform", kind=bool)
    rotate = check_param(rotate, func=func, name="rotate", kind=bool)
    scale = check_param(scale, func=func, name="scale", low=0.0, closed="neither")
    sharp_angle_deg = check_param(sharp_angle_deg, func=func, name="sharp_angle_deg",
                                  low=0.0, high=180.0, unit="deg")
    sharp_width = check_param(sharp_width, func=func, name="sharp_width", low=0.0,
                              unit="h")
    rim_width = check_param(rim_width, func=func, name="rim_width", low=0.0, unit="h")
    sampling = check_choice(sampling, func=func, name="sampling", choices=SAMPLINGS)
    if not uniform and sampling != "random":
        raise InvalidParameterError(
            f"{func}: uniform=False is the 1:5 random sampling; got sampling={sampling!r}")

    patches, edges, boundary, extra_fn = _BUILDERS[name]()
    rng = np.random.default_rng(seed)
    density = None
    view_dir = None
    if not uniform or sampling == "gradient":
        ratio = 5.0 if not uniform else 10.0
        hi = _x_half_extent(name)
        lo = -hi

        def density(p):
            return 1.0 + (ratio - 1.0) * np.clip((p[:, 0] - lo) / (hi - lo), 0.0, 1.0)

        pts, nrm = _sample_patches(patches, n, rng, density, ratio)
    elif sampling == "random":
        pts, nrm = _sample_patches(patches, n, rng)
    elif sampling == "blue":
        cand, cn = _sample_patches(patches, 5 * n, rng)
        keep = _blue_noise(cand, n, rng)
        pts, nrm = cand[keep], cn[keep]
    else:
        cand, cn = _sample_patches(patches, 12 * n, rng)
        keep, view_dir = _range_scans(cand, cn, n, rng, 3.0 if sampling == "aniso" else 1.0)
        pts, nrm = cand[keep], cn[keep]
    if view_dir is None:
        view_dir = _eye_rays(pts, rng)
    n = len(pts)
    h0 = average_spacing(pts)
    step = 0.25 * h0
    ed = edges.distance(pts, sharp_angle_deg, step)
    sharp = ed <= sharp_width * h0
    d40 = edges.distance(pts, SHARP_POSITIVE_DEG - 1e-9, step)
    d20 = edges.distance(pts, SHARP_IGNORE_DEG - 1e-9, step)
    extra = {"edge_distance": ed * scale}
    extra.update(_sharp_band_truth(d40 / h0, d20 / h0))
    if boundary is not None:
        bd = boundary(pts)
        rim = bd <= rim_width * h0
        extra["boundary_distance"] = bd * scale
        extra["rim_care"] = (bd <= RIM_BAND * h0) | (bd > RIM_CARE * h0)
    else:
        rim = np.zeros(n, dtype=bool)
        extra["rim_care"] = np.ones(n, dtype=bool)
    if extra_fn is not None:
        extra.update(extra_fn(pts))
    if density is not None:
        extra["density"] = density(pts) / (5.0 if not uniform else 10.0)
    if rotate:
        rot, t = _rigid_motion(seed)
        pts = pts @ rot.T + t
        nrm = nrm @ rot.T
        view_dir = view_dir @ rot.T
        extra["rotation"], extra["translation"] = rot, t * scale
    extra["view_dir"] = view_dir
    extra["sampling"] = sampling
    pts = pts * scale
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    h = h0 * scale  # distances are invariant to the rigid motion
    log.info("make_shape(%s, %s): n=%d h=%.4g sharp=%d rim=%d", name, sampling, n, h,
             sharp.sum(), rim.sum())
    return Sample(pts, nrm, sharp, rim, h, name, None, extra)


def _sharp_band_truth(d40_h, d20_h, band: float = 1.0) -> dict:
    """``sharp_pos`` / ``sharp_care`` of the benchmark's sharp truth from the
    distances (in h) to the edges of at least 40° and of at least 20°."""
    pos = d40_h <= band
    neg = d20_h > 2.0 * band
    return {"sharp_pos": pos, "sharp_care": pos | neg}


def _x_half_extent(name):
    """Half extent along canonical x (all shapes are symmetric about x = 0)."""
    if name == "cube":
        return 0.5
    if name == "star":
        return float(np.abs(_star_polygon()[:, 0]).max())
    if name == "cylinder":
        return _CYL["r"]
    if name == "cone":
        return _CONE["r0"]
    return 1.0


# ---------------------------------------------------------------------------
# sampling styles

def _blue_noise(cand, n, rng) -> np.ndarray:
    """Indices of ``n`` candidates kept by greedy dart throwing (random order) with
    an exclusion radius that keeps between n and 1.01 n; the last accepted darts
    beyond n are dropped (at most 1 % of the points)."""
    order = rng.permutation(len(cand))
    tree = cKDTree(cand)
    h_c = average_spacing(cand)

    def throw(r):
        nbrs = tree.query_ball_point(cand[order], r, workers=-1)
        taken = np.zeros(len(cand), dtype=bool)
        out = []
        for i, nb in zip(order, nbrs):
            if not taken[i]:
                out.append(i)
                taken[nb] = True
        return np.array(out)

    # the kept count falls as 1/r^2; secant steps on that law from 1.6 h_c (about
    # n kept out of 5n candidates), keeping the smallest excess above n
    r, best = 1.6 * h_c, None
    for _ in range(12):
        got = throw(r)
        if len(got) >= n and (best is None or len(got) < len(best)):
            best = got
        if n <= len(got) <= 1.01 * n:
            break
        r *= np.sqrt(len(got) / (1.005 * n))
    if best is None:
        raise InvalidParameterError(f"make_shape: blue noise cannot keep {n} points")
    return np.sort(best[:n])


def _range_scans(cand, cn, n, rng, aspect) -> tuple[np.ndarray, np.ndarray]:
    """Six merged orthographic range scans of a dense candidate cloud (see
    ``make_shape``'s "rows"): indices of the kept candidates and each one's ray."""
    frame = Rotation.random(random_state=rng).as_matrix()
    views = [(s * frame[:, k], frame[:, (k + 1) % 3], frame[:, (k + 2) % 3])
             for k in range(3) for s in (1.0, -1.0)]
    h_c = average_spacing(cand)

    def scan(pitch):
        seen, rays = [], []
        for d, u, w in views:
            cos = cn @ d
            idx = np.flatnonzero(cos < -0.2)  # facing the scanner, not grazing
            if len(idx) == 0:
                continue
            q = cand[idx]
            a, b = q @ u / pitch, q @ w / (aspect * pitch)
            off = np.hypot(a - np.floor(a) - 0.5, b - np.floor(b) - 0.5)
            ia, ib = np.floor(a).astype(np.int64), np.floor(b).astype(np.int64)
            ia -= ia.min()
            ib -= ib.min()
            key = ia * (ib.max() + 1) + ib
            depth = q @ d
            # the surface nearest the scanner in each pixel: candidates within
            # the depth a slanted pixel spans of the front-most one
            o = np.lexsort((depth, key))
            first = np.flatnonzero(np.r_[True, key[o][1:] != key[o][:-1]])
            front = np.empty(key.max() + 1)
            front[key[o][first]] = depth[o][first]
            tan = np.sqrt(np.maximum(1.0 - cos[idx] ** 2, 0.0)) / np.abs(cos[idx])
            ok = depth <= front[key] + 1.5 * aspect * pitch * np.maximum(tan, 1.0)
            j = np.flatnonzero(ok)
            o = np.lexsort((off[j], key[j]))
            kj = key[j][o]
            pick = j[o][np.r_[True, kj[1:] != kj[:-1]]]
            seen.append(idx[pick])
            rays.append(np.broadcast_to(d, (len(pick), 3)))
        s = np.concatenate(seen)
        r = np.concatenate(rays)
        _, first = np.unique(s, return_index=True)  # a candidate seen twice: first view
        return s[first], r[first]

    lo, hi = 0.5 * h_c, 40.0 * h_c
    for _ in range(30):
        mid = np.sqrt(lo * hi)
        keep, rays = scan(mid)
        if abs(len(keep) - n) <= 0.01 * n:
            break
        lo, hi = (mid, hi) if len(keep) > n else (lo, mid)
    if len(keep) < 7:
        raise InvalidParameterError(f"make_shape: range scans cannot keep {n} points")
    return keep, np.array(rays)


def _eye_rays(points, rng) -> np.ndarray:
    """Unit rays from one seeded eye three bounding-box diagonals away."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    u = rng.normal(size=3)
    eye = 0.5 * (lo + hi) + 3.0 * float(np.linalg.norm(hi - lo)) * u / np.linalg.norm(u)
    d = points - eye
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def sharp_truth(sample: Sample) -> tuple[np.ndarray, np.ndarray]:
    """The benchmark's sharp-edge truth of a Sample: ``(positive, care)``.

    A point is positive when its nearest edge of dihedral angle >= 40° lies
    within the band (1h on random samples; on mesh vertices: a vertex of such an
    edge), negative when no edge of >= 20° lies within two bands (mesh vertices:
    neither a vertex of such an edge nor joined by a mesh edge to one), and
    "don't care" otherwise; ``care`` is False on the don't-care points, which
    precision and recall leave out.  This keeps a tessellated continuum of
    20-40° edges (fillets, blends) out of the score instead of cutting it at one
    angle.
    """
    if "sharp_pos" in sample.extra:
        return (np.asarray(sample.extra["sharp_pos"], bool),
                np.asarray(sample.extra["sharp_care"], bool))
    if sample.faces is None:
        raise InvalidParameterError(f"sharp_truth: {sample.name} has no edge geometry")
    from .meshes import _mesh_sharp_truth

    pos, care = _mesh_sharp_truth(sample.points, sample.faces)
    return pos, care


def rim_truth(sample: Sample) -> tuple[np.ndarray, np.ndarray]:
    """The benchmark's border truth of a Sample: ``(positive, care)``: the rim
    (band of 1.5h on random samples, border vertex row on meshes) and "don't
    care" out to 2.5h / the second vertex row, for cut and natural borders."""
    pos = (np.zeros(len(sample.points), bool) if sample.rim is None
           else np.asarray(sample.rim, bool))
    care = sample.extra.get("rim_care")
    if care is None and sample.faces is not None:
        from .meshes import second_row

        care = ~second_row(sample.faces, pos, len(pos))
    if care is None:
        care = np.ones(len(pos), dtype=bool)
    return pos, np.asarray(care, bool) | pos


# ---------------------------------------------------------------------------
# noise

def add_noise(points, normals=None, sigma: float = 0.2, h: float | None = None,
              kind: str = "normal", seed: int | None = 0, *, fraction: float = 0.5,
              directions=None) -> np.ndarray:
    """Return a noisy copy of ``points`` (thesis §4.5 noise models).

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float, optional
        Required for ``kind="normal"`` and ``"impulsive"``; normalised here.
    sigma : float, default=0.2
        Noise level in units of h.
    h : float, optional
        Average spacing; computed from ``points`` when None.
    kind : {"normal", "random", "impulsive"}
        * ``"normal"``: p + ε n with ε ~ N(0, (σh)^2) per point.
        * ``"random"``: p + ε u with u uniform on the unit sphere and ε ~ N(0,
          (σh)^2) per point, so the displacement length has RMS σh in a random
          direction (its normal component has RMS σh/√3).
        * ``"impulsive"``: a random ``fraction`` of the points (exactly
          round(fraction n), default 50 %) get p + ε n with ε ~ N(0, (σh)^2); the
          others are untouched.  The thesis uses "impulsive noise σ = 0.5h along
          the normal" on the Twelve model (Fig. 4.11) without a definition; the
          default reproduces the public file of that name
          (``cad/twelve_noisy_impulsive_0.5.obj`` against ``twelve_clean.obj``:
          50.0 % of the vertices moved, along the normal, Gaussian with std 0.51
          mean edge lengths; 2.3 % moved by more than one edge length).  Use e.g.
          ``fraction=0.1`` with a larger σ for sparser, stronger impulses.
        * ``"view"``: p + ε d with d the unit ray the point was seen along
          (``directions``, e.g. ``Sample.extra["view_dir"]``) and ε ~ N(0, (σh)^2):
          the depth error of a range scanner.
    seed : int or None, default=0
    fraction : float, default=0.5
        Share of points hit by impulsive noise, in (0, 1].
    directions : (n, 3) float, optional
        The rays of ``kind="view"`` (normalised here).

    Returns
    -------
    noisy : (n, 3) float
        A new array; the inputs are not modified.
    """
    func = "add_noise"
    pts = as_points(points, func=func)
    kind = check_choice(kind, func=func, name="kind", choices=NOISE_KINDS)
    sigma = check_param(sigma, func=func, name="sigma", low=0.0, unit="h")
    fraction = check_param(fraction, func=func, name="fraction", low=0.0, high=1.0,
                           closed="right")
    seed = check_seed(seed, func=func)
    if h is None:
        h = average_spacing(pts)
    else:
        h = check_param(h, func=func, name="h", low=0.0, closed="neither")
    if kind in ("normal", "impulsive"):
        if normals is None:
            raise PointCloudError(f"{func}: kind={kind!r} needs normals")
        nrm = as_normals(normals, len(pts), func=func)
    if kind == "view":
        if directions is None:
            raise PointCloudError(f"{func}: kind='view' needs directions")
        nrm = as_normals(directions, len(pts), func=func)
    rng = np.random.default_rng(seed)
    n = len(pts)
    eps = rng.normal(0.0, sigma * h, n)
    if kind in ("normal", "view"):
        return pts + eps[:, None] * nrm
    if kind == "random":
        u = rng.normal(size=(n, 3))
        u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
        return pts + eps[:, None] * u
    hit = np.zeros(n, dtype=bool)
    hit[rng.choice(n, size=max(1, int(round(fraction * n))), replace=False)] = True
    return pts + np.where(hit, eps, 0.0)[:, None] * nrm


def add_outliers(points, fraction: float = 0.02, seed: int | None = 0, *,
                 margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Append ``round(fraction n)`` outliers drawn uniformly in the bounding box
    grown by ``margin`` diagonals on every side.

    Returns
    -------
    points : (n + m, 3) float
        The input rows first, then the outliers (a new array).
    is_outlier : (n + m,) bool
    """
    func = "add_outliers"
    pts = as_points(points, func=func)
    fraction = check_param(fraction, func=func, name="fraction", low=0.0, high=1.0,
                           closed="right")
    margin = check_param(margin, func=func, name="margin", low=0.0)
    seed = check_seed(seed, func=func)
    rng = np.random.default_rng([0 if seed is None else seed, 4099])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = margin * float(np.linalg.norm(hi - lo))
    m = max(1, int(round(fraction * len(pts))))
    out = lo - pad + (hi - lo + 2 * pad) * rng.random((m, 3))
    flag = np.r_[np.zeros(len(pts), bool), np.ones(m, bool)]
    return np.vstack([pts, out]), flag


# ---------------------------------------------------------------------------
# holes

def cut_holes(sample: Sample, n_holes: int = 3, radius: float = 8.0, seed: int | None = 0,
              *, rim_width: float = 1.5, centers=None) -> Sample:
    """Remove ``n_holes`` balls from a sample and label the new rims.

    Parameters
    ----------
    sample : Sample
        Usually from :func:`make_shape` (a closed or open surface).
    n_holes : int, default=3
    radius : float, default=8.0
        Ball radius in units of ``sample.h``.
    seed : int or None, default=0
    rim_width : float, default=1.5
        Rim band width in units of h.
    centers : (k, 3) float, optional
        Explicit hole centres (then ``n_holes`` and ``seed`` are not used), e.g.
        on sharp edges to test rims that cross a crease.

    Returns
    -------
    Sample
        The remaining points (input order kept); ``extra["rim_care"]`` is False
        on the "don't care" ring of the benchmark's border truth (beyond the
        band out to 2.5h on samples, the second vertex row on meshes; see
        ``rim_truth``); ``rim`` = old rim OR the new
        rims: on a sample with faces (mesh vertices) the kept vertices that
        share a mesh edge with a removed one (one row, like a mesh's own
        boundary-edge vertices), otherwise the points within ``radius +
        rim_width`` h of a hole centre, i.e. within ``rim_width`` h of a
        removed ball's surface (a band).  ``extra["rim_band"]`` is the band
        rule for every sample.  ``extra["keep_idx"]`` (indices into the input),
        ``extra["hole_centers"]`` (k, 3) and ``extra["hole_rim"]`` (the new rims
        only) are added; per-point extras are subset, and
        ``extra["boundary_distance"]`` becomes the distance to the nearest open
        border or removed ball surface.  ``h`` is recomputed.

    Notes
    -----
    Centres are drawn from the sample's points, preferring points farther than
    ``radius + 2`` h from sharp edges and open boundaries (so a hole does not
    swallow a crease or merge with the border) and at least ``2 radius + 4`` h from
    each other; when too few such points exist the constraints are relaxed
    (logged), in that order: spacing, then the sharp/boundary distance.
    """
    func = "cut_holes"
    if not isinstance(sample, Sample):
        raise InvalidParameterError(
            f"{func}: sample must be a Sample, got {type(sample).__name__}")
    n_holes = check_param(n_holes, func=func, name="n_holes", kind=int, low=1,
                          unit="count")
    radius = check_param(radius, func=func, name="radius", low=0.0, closed="neither",
                         unit="h")
    rim_width = check_param(rim_width, func=func, name="rim_width", low=0.0, unit="h")
    seed = check_seed(seed, func=func)
    pts = sample.points
    n = len(pts)
    h = sample.h
    r = radius * h
    if centers is not None:
        C = as_points(centers, func=func, name="centers", min_points=1)
    else:
        C = _place_holes(sample, n_holes, r, seed, func)
    d, _ = cKDTree(C).query(pts, k=1, workers=-1)
    keep = d >= r
    if keep.sum() < 7:
        raise InvalidParameterError(
            f"{func}: radius={radius} h removes almost every point")
    hole_rim = (d < r + rim_width * h)[keep]
    old_rim = (sample.rim[keep] if sample.rim is not None
               else np.zeros(int(keep.sum()), dtype=bool))
    extra = {}
    for key, val in sample.extra.items():
        if isinstance(val, np.ndarray) and val.shape[:1] == (n,):
            extra[key] = val[keep]
        else:
            extra[key] = val
    keep_idx = np.flatnonzero(keep)
    if "keep_idx" in sample.extra:
        keep_idx = np.asarray(sample.extra["keep_idx"])[keep_idx]
    band = old_rim | hole_rim
    hole_far = (d >= r + RIM_CARE * h)[keep]
    old_care = sample.extra.get("rim_care")
    if old_care is not None:
        old_care = np.asarray(old_care, bool)[keep]
    elif sample.faces is not None and sample.rim is not None:
        from .meshes import second_row

        old_care = ~second_row(sample.faces, np.asarray(sample.rim, bool), n)[keep]
    else:
        old_care = np.ones(int(keep.sum()), dtype=bool)
    care = band | (old_care & hole_far)
    if sample.faces is not None:
        # mesh vertices: the rim is the first row of kept vertices, those that
        # share a mesh edge with a removed one (as a mesh's own border is the
        # vertices of its boundary edges)
        Fc = np.asarray(sample.faces)
        e = np.concatenate([Fc[:, [0, 1]], Fc[:, [1, 2]], Fc[:, [2, 0]]])
        cut = keep[e[:, 0]] != keep[e[:, 1]]
        row = np.zeros(n, dtype=bool)
        row[e[cut].ravel()] = True
        row &= keep
        hole_rim = row[keep]
        from .meshes import second_row

        ring2 = second_row(Fc, row, n, within=keep)
        care = (old_rim | hole_rim) | (old_care & ~ring2[keep])
    bd = d[keep] - r  # distance to the nearest removed ball's surface
    if "boundary_distance" in extra:
        bd = np.minimum(bd, extra["boundary_distance"])
    extra.update(keep_idx=keep_idx, hole_centers=C, hole_rim=hole_rim,
                 boundary_distance=bd, rim_band=band, rim_care=care)
    new_pts = pts[keep]
    return Sample(new_pts, sample.normals[keep],
                  None if sample.sharp is None else sample.sharp[keep],
                  old_rim | hole_rim, average_spacing(new_pts), sample.name + "_holes",
                  None, extra)


def centres_beside_edges(sample: Sample, n_holes: int, radius: float, gap: float = 1.5,
                         seed: int | None = 0) -> np.ndarray:
    """``n_holes`` centres for ``cut_holes(..., centers=...)`` whose rims pass
    ``gap`` h beside a sharp edge without reaching it (a point at ``radius +
    gap`` h, within 0.3h, from an edge of the shape's ``edge_distance``), at
    least ``2 radius + 4`` h apart: the rim runs along a crease, the case a
    flatness test of the border gets wrong."""
    func = "centres_beside_edges"
    if "edge_distance" not in sample.extra:
        raise InvalidParameterError(f"{func}: the sample has no edge distances")
    ed = np.asarray(sample.extra["edge_distance"]) / sample.h
    near = np.flatnonzero(np.abs(ed - (radius + gap)) < 0.3)
    rng = np.random.default_rng(seed)
    out: list[np.ndarray] = []
    for i in rng.permutation(near):
        if all(np.linalg.norm(sample.points[i] - c) >= (2 * radius + 4) * sample.h
               for c in out):
            out.append(sample.points[i])
            if len(out) == n_holes:
                break
    if len(out) < n_holes:
        raise InvalidParameterError(f"{func}: cannot place {n_holes} holes")
    return np.array(out)


def _place_holes(sample: Sample, n_holes: int, r: float, seed, func: str) -> np.ndarray:
    """Hole centres for ``cut_holes`` (placement rules in its Notes)."""
    pts, h, n = sample.points, sample.h, len(sample.points)
    # distance to features that a hole should avoid
    avoid = np.full(n, np.inf)
    for key, mask in (("edge_distance", sample.sharp), ("boundary_distance", sample.rim)):
        if key in sample.extra:
            avoid = np.minimum(avoid, np.asarray(sample.extra[key], dtype=np.float64))
        elif mask is not None and mask.any():
            d, _ = cKDTree(pts[mask]).query(pts, k=1, workers=-1)
            avoid = np.minimum(avoid, d)
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    centres: list[np.ndarray] = []
    for relax in range(3):
        min_avoid = (r + 2.0 * h) if relax < 2 else 0.0
        min_sep = (2.0 * r + 4.0 * h) if relax == 0 else 0.0
        centres = []
        for i in order[avoid[order] > min_avoid]:
            if all(np.linalg.norm(pts[i] - c) >= min_sep for c in centres):
                centres.append(pts[i])
                if len(centres) == n_holes:
                    break
        if len(centres) == n_holes:
            break
        log.info("cut_holes: relaxing placement constraints (level %d)", relax + 1)
    if len(centres) < n_holes:
        raise InvalidParameterError(f"{func}: cannot place {n_holes} holes in {n} points")
    return np.array(centres)


# Mesh-based ground truth lives in meshes.py; re-exported here so that one import
# serves tests and benchmarks.
from .meshes import (  # noqa: E402,F401
    SAMPLE_MESHES,
    load_mesh_file,
    load_sample_mesh,
    load_shared_model,
    mesh_sample,
    pymeshlab_sample_dir,
    sample_mesh_surface,
    shared_models_root,
    use_models_root,
    models_hint,
)


# ---------------------------------------------------------------------------
# the held-out cases: fixed before any default is chosen on them, never used to
# choose one (docs/decisions/benchmarks.md).  Each family's tuning cases are the
# cases its harness ran before this set existed.

#: seeds of the held-out cases start here (the tuning cases use seed 0 and 1)
HELD_OUT_SEED = 1000


def _c(case, source, sampling="random", n=6000, noise=None, sigma=0.0, outliers=0.0,
       holes=None, seed=0):
    return dict(case=case, source=source, sampling=sampling, n=n, noise=noise,
                sigma=sigma, outliers=outliers, holes=holes, seed=HELD_OUT_SEED + seed)


#: family -> held-out case specifications.  ``source``: ``shape:NAME``
#: (``make_shape``), ``surface:REL`` (``sample_mesh_surface`` of a shared mesh),
#: ``vertices:REL`` (the shared mesh's own vertices, with their natural noise),
#: ``points:REL`` (a shared point file); ``noise``: None or an ``add_noise``
#: kind, σ in h; ``outliers``: share of ``add_outliers``; ``holes``: ``(count,
#: radius in h, "random" | "beside_creases")``; ``quick``: in the quick run.
HELD_OUT = {
    "denoise": (
        _c("bracket, blue noise, view rays 0.2h", "shape:bracket", "blue", noise="view",
           sigma=0.2, seed=1),
        _c("channel, range rows, view rays 0.3h", "shape:channel", "rows", noise="view",
           sigma=0.3, seed=2),
        _c("steps, anisotropic 1:3, normal 0.2h", "shape:steps", "aniso", noise="normal",
           sigma=0.2, seed=3),
        _c("cylinder, gradient 1:10, random 0.3h", "shape:cylinder", "gradient",
           noise="random", sigma=0.3, seed=4),
        _c("cone, blue noise, normal 0.3h", "shape:cone", "blue", noise="normal",
           sigma=0.3, seed=5),
        _c("torus, range rows, view rays 0.2h", "shape:torus", "rows", noise="view",
           sigma=0.2, seed=6),
        _c("bracket, random, normal 0.2h + 2% outliers", "shape:bracket", noise="normal",
           sigma=0.2, outliers=0.02, seed=7),
        _c("torus, blue noise, normal 0.1h + 5% outliers", "shape:torus", "blue",
           noise="normal", sigma=0.1, outliers=0.05, seed=8),
        _c("armadillo scan, random, normal 0.2h", "surface:scans/armadillo_43k.obj",
           noise="normal", sigma=0.2, seed=9),
        _c("bimba scan, range rows, view rays 0.2h", "surface:scans/bimba_23k.obj",
           "rows", noise="view", sigma=0.2, seed=10),
        _c("horse scan, blue noise, normal 0.3h", "surface:scans/horse.ply", "blue",
           noise="normal", sigma=0.3, seed=11),
        _c("twirl (CAD), anisotropic 1:3, view rays 0.3h", "surface:cad/twirl_clean.off",
           "aniso", noise="view", sigma=0.3, seed=12),
    ),
    "sharp": (
        _c("bracket, blue noise", "shape:bracket", "blue", n=20000, seed=21),
        _c("bracket, blue noise", "shape:bracket", "blue", n=20000, noise="normal",
           sigma=0.3, seed=21),
        _c("channel, range rows", "shape:channel", "rows", n=20000, seed=22),
        _c("channel, range rows", "shape:channel", "rows", n=20000, noise="view",
           sigma=0.3, seed=22),
        _c("steps, anisotropic 1:3", "shape:steps", "aniso", n=20000, seed=23),
        _c("steps, anisotropic 1:3", "shape:steps", "aniso", n=20000, noise="normal",
           sigma=0.3, seed=23),
        _c("cylinder, gradient 1:10", "shape:cylinder", "gradient", n=20000, seed=24),
        _c("cylinder, gradient 1:10", "shape:cylinder", "gradient", n=20000,
           noise="normal", sigma=0.3, seed=24),
        _c("cone, blue noise", "shape:cone", "blue", n=20000, seed=25),
        _c("cone, blue noise", "shape:cone", "blue", n=20000, noise="view", sigma=0.3,
           seed=25),
        _c("twirl (CAD mesh vertices)", "vertices:cad/twirl_clean.off", seed=26),
        _c("twirl (CAD mesh vertices)", "vertices:cad/twirl_clean.off", noise="normal",
           sigma=0.3, seed=26),
        _c("bracket, random, 0.1h + 2% outliers", "shape:bracket", n=20000,
           noise="normal", sigma=0.1, outliers=0.02, seed=27),
    ),
    "smooth": (
        _c("torus, blue noise", "shape:torus", "blue", n=20000, seed=31),
        _c("torus, blue noise", "shape:torus", "blue", n=20000, noise="normal",
           sigma=0.3, seed=31),
        _c("bumpy sphere, range rows", "shape:bumpy_sphere", "rows", n=20000, seed=32),
    ),
    "holes": (
        _c("bracket, blue noise, 3 holes", "shape:bracket", "blue", n=20000,
           holes=(3, 8.0, "random"), seed=41),
        _c("channel, range rows, 3 holes", "shape:channel", "rows", n=20000,
           holes=(3, 8.0, "random"), seed=42),
        _c("steps, blue noise, 3 holes beside creases", "shape:steps", "blue", n=20000,
           holes=(3, 8.0, "beside_creases"), seed=43),
        _c("cone, range rows, 3 holes beside creases", "shape:cone", "rows", n=20000,
           holes=(3, 8.0, "beside_creases"), seed=44),
        _c("cylinder, gradient 1:10, 3 holes", "shape:cylinder", "gradient", n=20000,
           holes=(3, 8.0, "random"), seed=45),
        _c("torus, anisotropic 1:3, 3 holes", "shape:torus", "aniso", n=20000,
           holes=(3, 8.0, "random"), seed=46),
        _c("bracket, random, 0.1h, 3 holes beside creases", "shape:bracket", n=20000,
           noise="normal", sigma=0.1, holes=(3, 8.0, "beside_creases"), seed=47),
        _c("armadillo scan vertices, 3 holes", "vertices:scans/armadillo_43k.obj",
           holes=(3, 8.0, "random"), seed=48),
        _c("bimba scan vertices, 3 holes", "vertices:scans/bimba_23k.obj",
           holes=(3, 8.0, "random"), seed=49),
    ),
    "closed": (
        _c("channel, blue noise", "shape:channel", "blue", n=20000, seed=51),
        _c("bracket, anisotropic 1:3", "shape:bracket", "aniso", n=20000, seed=52),
        _c("torus, range rows", "shape:torus", "rows", n=20000, seed=53),
        _c("cylinder, blue noise, 0.3h", "shape:cylinder", "blue", n=20000,
           noise="normal", sigma=0.3, seed=54),
        _c("horse scan vertices", "vertices:scans/horse.ply", seed=55),
    ),
    "saliency": (
        _c("bumpy sphere, random", "shape:bumpy_sphere", n=20000, seed=61),
        _c("bumpy sphere, blue noise, 0.3h", "shape:bumpy_sphere", "blue", n=20000,
           noise="normal", sigma=0.3, seed=62),
        _c("bumpy sphere, range rows, view rays 0.3h", "shape:bumpy_sphere", "rows",
           n=20000, noise="view", sigma=0.3, seed=63),
        _c("bracket, blue noise", "shape:bracket", "blue", n=20000, seed=64),
        _c("channel, range rows, view rays 0.3h", "shape:channel", "rows", n=20000,
           noise="view", sigma=0.3, seed=65),
        _c("cone, gradient 1:10", "shape:cone", "gradient", n=20000, seed=66),
    ),
    "simplify": (
        _c("bimba scan", "vertices:scans/bimba_23k.obj", seed=71),
        _c("gargoyle raw scan points (30,000 of 95,435)",
           "points:scans/gargoyle_points_95k.ply", n=30000, seed=72),
        _c("twirl (CAD)", "vertices:cad/twirl_clean.off", seed=73),
        _c("bracket, blue noise", "shape:bracket", "blue", n=20000, seed=74),
        _c("torus, range rows", "shape:torus", "rows", n=20000, seed=75),
        _c("cylinder, gradient 1:10, normal 0.2h", "shape:cylinder", "gradient",
           n=20000, noise="normal", sigma=0.2, seed=76),
    ),
}
#: the held-out cases each quick run includes (family -> indices into HELD_OUT)
HELD_OUT_QUICK = {"denoise": (0,), "sharp": (0, 3), "smooth": (), "holes": (2,),
                  "closed": (0,), "saliency": (1,), "simplify": (3,)}


def held_out_cases(family: str, quick: bool = False) -> tuple[dict, ...]:
    """The held-out case specifications of ``family`` (``HELD_OUT``); the quick
    subset when ``quick``."""
    check_choice(family, func="held_out_cases", name="family", choices=tuple(HELD_OUT))
    cases = HELD_OUT[family]
    if quick:
        return tuple(cases[i] for i in HELD_OUT_QUICK[family])
    return cases


def build_case(spec: dict, *, n: int | None = None) -> dict | None:
    """Clean sample and input points of one held-out case (``HELD_OUT``).

    Returns None when its shared file is absent.  Keys: ``sample`` (the clean
    Sample, holes cut), ``points`` (the input: noisy, outliers appended last),
    ``is_outlier`` (bool, len(points)), ``source``.  ``n`` overrides the
    specification's point count (tiny test runs).
    """
    func = "build_case"
    kind, _, ref = spec["source"].partition(":")
    seed = spec["seed"]
    count = spec["n"] if n is None else n
    if kind == "shape":
        s = make_shape(ref, n=count, seed=seed, sampling=spec["sampling"])
    elif kind in ("surface", "vertices", "points"):
        m = load_shared_model(ref)
        if m is None:
            return None
        if kind == "surface":
            s = sample_mesh_surface(m.points, m.faces, n=count, seed=seed,
                                    sampling=spec["sampling"], name=ref)
        elif kind == "vertices":
            s = m
        else:
            idx = np.sort(np.random.default_rng(seed).choice(
                len(m.points), size=min(count, len(m.points)), replace=False))
            s = Sample(m.points[idx], m.normals[idx], None, None,
                       average_spacing(m.points[idx]), ref, None, {})
    else:
        raise InvalidParameterError(f"{func}: unknown source {spec['source']!r}")
    if spec["holes"] is not None:
        k, radius, place = spec["holes"]
        centres = (centres_beside_edges(s, k, radius, seed=seed)
                   if place == "beside_creases" else None)
        s = cut_holes(s, n_holes=k, radius=radius, seed=seed, centers=centres)
    pts = s.points
    if spec["noise"] is not None and spec["sigma"] > 0:
        dirs = s.extra.get("view_dir")
        if spec["noise"] == "view" and dirs is None:
            dirs = _eye_rays(s.points, np.random.default_rng([seed, 3]))
        pts = add_noise(s.points, s.normals, sigma=spec["sigma"], h=s.h,
                        kind=spec["noise"], seed=seed + 1, directions=dirs)
    out = np.zeros(len(pts), dtype=bool)
    if spec["outliers"] > 0:
        pts, out = add_outliers(pts, spec["outliers"], seed=seed + 2)
    return dict(sample=s, points=pts, is_outlier=out, source=spec["source"])
