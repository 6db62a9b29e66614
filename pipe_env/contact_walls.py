"""Contact walls: convex pieces lining every pipe, the surfaces the robot body touches.

MuJoCo collides a mesh by its convex hull, and the hull of a pipe fills its bore, so the robot
cannot collide with the ray meshes. Instead each pipe wall is cut into convex pieces:

- straight runs: long box panels, ``SECTORS`` around, overlapping their neighbours;
- fittings: slabs (angular sector x axial slice x wall thickness) given as point sets, whose
  convex hull MuJoCo computes. Wall points inside another pipe's bore (a junction's hole) or past
  a mitre's cut plane do not exist; validity is sampled every ``MIN_SLICE`` along the axis, so
  the pieces follow such boundaries within a few millimetres.

The inner face of every piece straddles the true wall (chord error split evenly), so the
surface is within about +-0.3 mm of the analytic wall for 125 mm pipes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from detector.geometry import frame_from_forward
from pipe_env.fittings import FittingGeometry

#: Pieces around the circumference.
SECTORS = 24
#: Radial thickness of the contact walls, metres (thick enough that nothing tunnels through).
THICKNESS = 0.012
#: Axial length of fitting slices before boundary refinement, and the finest split, metres.
MAX_SLICE = 0.05
MIN_SLICE = 0.003
#: Largest chord sag along a long bend's arc, metres (split evenly inside and outside).
ARC_SAG = 0.001
#: How far contact pieces overlap their neighbours along a pipe, metres.
SEAM_OVERLAP = 0.002

Keep = Callable[[NDArray[np.float64]], NDArray[np.bool_]]


@dataclass(frozen=True, eq=False)
class BoxPanel:
    """A box geom: centre (m), rotation (3x3, columns = box axes), half sizes (m)."""

    centre: NDArray[np.float64]
    rotation: NDArray[np.float64]
    half_size: NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class HullPiece:
    """A convex piece given by points (k, 3) in metres; its convex hull is the geom."""

    points: NDArray[np.float64]


def _chord_radius(radius: float, facet_angle: float) -> float:
    """Vertex radius so that chords of ``facet_angle`` straddle a circle of ``radius`` evenly."""
    return 2.0 * radius / (1.0 + math.cos(0.5 * facet_angle))


def run_panels(p0: NDArray, p1: NDArray, diameter: float) -> list[BoxPanel]:
    """Box panels lining a straight pipe from p0 to p1 (port centres, m).

    All ``SECTORS`` panels in one pass of array arithmetic: element for element the same
    operations, in the same order, as one panel at a time (the world's digests pin the bits)."""
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    axis = axis / length
    frame = frame_from_forward(axis)
    u, v = frame[:, 1], frame[:, 2]
    r = 0.5 * diameter
    delta = 2 * math.pi / SECTORS
    # flat face at the mean of chord and arc distance: +-r(1-cos(delta/2))/2 from the true wall
    face = r * (1.0 + math.cos(0.5 * delta)) / 2.0
    half_width = face * math.tan(0.5 * delta) * 1.15 + 0.0005
    half_len = 0.5 * length + SEAM_OVERLAP
    mid = 0.5 * (p0 + p1)
    phis = [(j + 0.5) * delta for j in range(SECTORS)]
    cos = np.array([math.cos(phi) for phi in phis])[:, None]
    sin = np.array([math.sin(phi) for phi in phis])[:, None]
    normal = cos * u + sin * v  # (S, 3)
    tangent = np.cross(normal, axis)
    rot = np.stack([np.broadcast_to(axis, normal.shape), tangent, normal], axis=2)
    centre = mid + normal * (face + 0.5 * THICKNESS)
    half = np.array([half_len, half_width, 0.5 * THICKNESS])
    return [BoxPanel(centre[j], rot[j], half.copy()) for j in range(SECTORS)]


def _tube_pieces(
    origin: NDArray,
    axis: NDArray,
    radius_at: Callable[[NDArray], NDArray],
    s0: float,
    s1: float,
    keep: Keep | None,
) -> list[HullPiece]:
    """Hull pieces lining a straight (possibly conical) tube between s0 and s1 along ``axis``.

    ``radius_at(s)`` gives the inner radius at axial positions ``s``; ``keep(points)`` says which
    wall points exist (None: all do). Validity is sampled on a grid (``MIN_SLICE`` along the
    axis); runs of fully valid cells merge into one piece per sector, and cells cut by a boundary
    become pieces of their valid corners.
    """
    frame = frame_from_forward(axis)
    u, v = frame[:, 1], frame[:, 2]
    delta = 2 * math.pi / SECTORS
    k_in = _chord_radius(1.0, delta)
    phis = np.arange(SECTORS + 1) * delta
    dirs = np.cos(phis)[:, None] * u + np.sin(phis)[:, None] * v  # (S+1, 3)

    def wall_points(s: NDArray) -> NDArray:
        """(2, S+1, len(s), 3): inner and outer wall points on each sector edge line."""
        rad = radius_at(s)
        base = origin + s[:, None] * axis
        inner = base[None] + dirs[:, None, :] * (rad * k_in)[None, :, None]
        outer = base[None] + dirs[:, None, :] * (rad + THICKNESS)[None, :, None]
        return np.stack([inner, outer])

    if keep is None:
        pts = wall_points(np.array([s0, s1]))
        return [HullPiece(pts[:, j : j + 2].reshape(-1, 3)) for j in range(SECTORS)]
    n = max(1, math.ceil((s1 - s0) / MIN_SLICE))
    s = np.linspace(s0, s1, n + 1)
    pts = wall_points(s)
    valid = keep(pts.reshape(-1, 3)).reshape(pts.shape[:3])
    # (S, n) every / any corner of cell k of sector j valid; Python lists for the scan below
    # (asarray: reductions type as scalar | array)
    lo_all, hi_all = (
        np.asarray(valid[:, :, :-1].all(axis=0)),
        np.asarray(valid[:, :, 1:].all(axis=0)),
    )
    lo_any, hi_any = (
        np.asarray(valid[:, :, :-1].any(axis=0)),
        np.asarray(valid[:, :, 1:].any(axis=0)),
    )
    cells_all = (lo_all[:-1] & lo_all[1:] & hi_all[:-1] & hi_all[1:]).tolist()
    cells_any = (lo_any[:-1] | lo_any[1:] | hi_any[:-1] | hi_any[1:]).tolist()
    sl = s.tolist()
    pieces: list[HullPiece] = []
    for j in range(SECTORS):
        cell_all, cell_any = cells_all[j], cells_any[j]
        k = 0
        while k < n:
            if cell_all[k]:
                m = k
                while m + 1 < n and cell_all[m + 1] and sl[m + 2] - sl[k] <= MAX_SLICE:
                    m += 1
                pieces.append(HullPiece(pts[:, j : j + 2, [k, m + 1]].reshape(-1, 3)))
                k = m + 1
                continue
            if cell_any[k]:
                sel = pts[:, j : j + 2, k : k + 2][valid[:, j : j + 2, k : k + 2]]
                if len(sel) >= 4:
                    pieces.append(HullPiece(sel))
            k += 1
    return [p for p, ok in zip(pieces, _have_volume([p.points for p in pieces])) if ok]


def _have_volume(point_sets: list[NDArray]) -> list[bool]:
    """Whether each point set (k, 3) spans a volume: its smallest singular value about its
    mean is above 10 um. Sets of equal size are tested in one batched SVD (per set the same
    LAPACK call as one at a time)."""
    out = [False] * len(point_sets)
    by_size: dict[int, list[int]] = {}
    for i, pts in enumerate(point_sets):
        by_size.setdefault(len(pts), []).append(i)
    for size, idx in by_size.items():
        if size < 3:
            continue  # fewer than 3 singular values: no volume
        stack = np.stack([point_sets[i] for i in idx])
        centred = stack - stack.mean(axis=1, keepdims=True)
        sv = np.linalg.svd(centred, compute_uv=False)
        for i, ok in zip(idx, sv[:, 2] > 1e-5):
            out[i] = bool(ok)
    return out


def _const(r: float) -> Callable[[NDArray], NDArray]:
    return lambda s: np.full_like(s, r, dtype=float)


def _outside_bore(centre: NDArray, axis: NDArray, radius: float, half_line: bool) -> Keep:
    """Keep points outside a bore of ``radius`` around a line (or half-line from ``centre``)."""

    def keep(pts: NDArray) -> NDArray:
        rel = pts - centre
        t = rel @ axis
        if half_line:
            t = np.maximum(t, 0.0)
        d = np.linalg.norm(rel - t[:, None] * axis, axis=1)
        return d >= radius - 1e-4

    return keep


def _all_of(keeps: list[Keep]) -> Keep | None:
    if not keeps:
        return None

    def keep(pts: NDArray) -> NDArray:
        mask = np.ones(len(pts), dtype=bool)
        for k in keeps:
            mask &= k(pts)
        return mask

    return keep


def fitting_pieces(g: FittingGeometry) -> tuple[list[HullPiece], list[BoxPanel]]:
    """Contact pieces lining one fitting, from its port planes inwards."""
    if g.kind == "closure":
        p = g.ports[0]
        pieces = _tube_pieces(
            g.centre, p.axis, _const(p.radius), -THICKNESS, p.leg + SEAM_OVERLAP, None
        )
        frame = frame_from_forward(p.axis)
        wall = BoxPanel(
            g.centre - p.axis * (0.5 * THICKNESS),
            frame,
            np.array([0.5 * THICKNESS, p.radius + THICKNESS, p.radius + THICKNESS]),
        )
        return pieces, [wall]
    if g.kind == "reducer":
        a, b = g.ports
        axis = b.axis
        length = a.leg + b.leg

        def radius_at(s: NDArray) -> NDArray:
            f = np.clip(s / length, 0.0, 1.0)
            return a.radius + (b.radius - a.radius) * f

        return _tube_pieces(
            a.position, axis, radius_at, -SEAM_OVERLAP, length + SEAM_OVERLAP, None
        ), []
    if g.kind == "bend" and g.style == "long":
        return _torus_pieces(g), []
    if g.kind == "bend":
        pieces = []
        for p, q in ((g.ports[0], g.ports[1]), (g.ports[1], g.ports[0])):
            normal = p.axis - q.axis
            normal = normal / np.linalg.norm(normal)
            reach = (p.radius + THICKNESS) * math.tan(0.5 * g.deflection) + 0.01

            def keep(pts: NDArray, n: NDArray = normal) -> NDArray:
                return (pts - g.centre) @ n >= -1e-5

            pieces += _tube_pieces(
                g.centre, p.axis, _const(p.radius), -reach, p.leg + SEAM_OVERLAP, keep
            )
        return pieces, []
    return _junction_pieces(g), []


def _junction_pieces(g: FittingGeometry) -> list[HullPiece]:
    pieces: list[HullPiece] = []
    pairs = g.collinear_pairs()
    in_pair = {i for pair in pairs for i in pair}
    tubes: list[tuple[int, int | None]] = [(i, j) for i, j in pairs]
    tubes += [(i, None) for i in range(len(g.ports)) if i not in in_pair]
    for i, j in tubes:
        p = g.ports[i]
        members = {i} if j is None else {i, j}
        cutters = []
        for k, q in enumerate(g.ports):
            if k in members:
                continue
            partner = next((b if a == k else a for a, b in pairs if k in (a, b)), None)
            # a port that is part of a run through cuts a full-line bore, a branch a half-line
            cutters.append(_outside_bore(g.centre, q.axis, q.radius, half_line=partner is None))
        keep = _all_of(cutters)
        lo = -(g.ports[j].leg + SEAM_OVERLAP) if j is not None else 0.0
        pieces += _tube_pieces(g.centre, p.axis, _const(p.radius), lo, p.leg + SEAM_OVERLAP, keep)
    return pieces


@dataclass(frozen=True)
class BendSlices:
    """How a long bend's wall is sliced into hull pieces: the arc's ``centre`` (m), unit
    ``normal``, radius ``bend_r`` and the pipe radius ``r`` (m); the slice boundaries ``psis``
    along the arc (rad from port ``a``, padded by ``SEAM_OVERLAP`` at both ends); the in-plane
    unit vectors ``u0`` (towards port ``a``) and ``w0``."""

    centre: NDArray[np.float64]
    normal: NDArray[np.float64]
    bend_r: float
    r: float
    psis: NDArray[np.float64]
    u0: NDArray[np.float64]
    w0: NDArray[np.float64]


def bend_slices(g: FittingGeometry) -> BendSlices:
    """The slicing of long bend ``g``'s wall (see :class:`BendSlices`)."""
    a, _ = g.ports
    centre, normal, bend_r, angle = g.bend_arc()
    r = a.radius
    # slices along the arc: chord sag at the outer wall at most ARC_SAG, split evenly in and out
    step = 2.0 * math.acos(1.0 - ARC_SAG / (bend_r + r))
    n_arc = max(2, math.ceil(angle / step))
    psis = np.linspace(0.0, angle, n_arc + 1)
    pad = SEAM_OVERLAP / bend_r
    psis[0] -= pad
    psis[-1] += pad
    u0 = (a.position - centre) / bend_r
    return BendSlices(centre, normal, bend_r, r, psis, u0, np.cross(normal, u0))


def _torus_pieces(g: FittingGeometry) -> list[HullPiece]:
    sl = bend_slices(g)
    centre, normal, bend_r, r, psis = sl.centre, sl.normal, sl.bend_r, sl.r, sl.psis
    u0, w0 = sl.u0, sl.w0
    delta = 2 * math.pi / SECTORS
    k_in = _chord_radius(1.0, delta)
    k_arc = _chord_radius(1.0, psis[1] - psis[0])
    # every (arc slice, sector) at once; element for element the operations of one at a time
    ends = np.stack([psis[:-1], psis[1:]], axis=1)  # (A, 2) arc positions of each slice
    radial = np.cos(ends)[:, :, None] * u0 + np.sin(ends)[:, :, None] * w0  # (A, 2, 3)
    lims = np.stack([np.arange(SECTORS) * delta, np.arange(1, SECTORS + 1) * delta], axis=1)
    cos, sin = np.cos(lims), np.sin(lims)  # (S, 2) sector edge angles
    # cross-section frame at each arc position: radial outward and the bend normal; (A, S, 2, 2, 3)
    dirs = (
        cos[None, :, None, :, None] * radial[:, None, :, None, :]
        + sin[None, :, None, :, None] * normal
    )
    ring = bend_r * radial[:, None, :, None, :]
    inner = ring + dirs * (r * k_in)
    outer = ring + dirs * (r + THICKNESS)
    # scale about the arc centre so chords along the arc straddle the true wall
    n_arc, n_pts = len(ends), 8
    pts = np.concatenate(
        [inner.reshape(n_arc, SECTORS, 4, 3), outer.reshape(n_arc, SECTORS, 4, 3)], axis=2
    )
    pts = centre + k_arc * pts.reshape(n_arc * SECTORS, n_pts, 3)
    return [HullPiece(p) for p in pts]
