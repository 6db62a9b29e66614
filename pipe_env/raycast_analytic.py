"""Exact ray casting against the bore of a pipe network.

This module owns the analytic LiDAR backend: instead of the faceted CSG ray meshes
(:mod:`pipe_env.meshes`), every network element is described by the exact solids whose union is
the pipe's bore (the air inside the pipe), and a ray cast from inside the bore hits the wall where
it first leaves that union:

- straight runs: finite cylinders between their ports (for the numpy path, long runs are split
  into segments of at most ``segment_length`` so that its spatial culling stays tight);
- reducers: cone frustums between the two ports;
- closures: a cylinder whose inner cap is the end wall;
- mitre bends: two cylinders, each clipped by the bisector plane;
- junctions (tee, wye, cross): one cylinder from port to port for every straight way through and
  one from the centre to the port for every branch; their union leaves the holes where another
  bore is;
- long-radius bends: a torus sector (a quartic per ray) between the two port planes.

All quadric pieces (cylinders, cones) share one parameterisation, a frustum of a cone (slope 0: a
cylinder) along an axis, clipped by two planes. Each piece contributes, per ray, the interval of
ray parameters inside it (a torus sector up to two); the first exit from the union is found by
extending ``t`` from 0 while some interval contains it. Seams between pieces are shared planes,
so no ray can slip through them and no ray escapes a closed network.

Two implementations of the same arithmetic: :meth:`AnalyticBore.cast` (and
:meth:`AnalyticBore.cast_groups` for a sweep, one origin per plane), compiled per ray in
:mod:`pipe_env.raycast_kernels` (the backend); and :meth:`AnalyticBore.cast_numpy`, vectorised
over (ray, piece) pairs in numpy, the former backend kept as the reference the kernels are tested
against (same hits within rounding, about 1e-13 m).

Units: metres. Conventions: ``dist`` is ``inf`` where nothing is hit within ``cutoff`` and 0 where
the ray starts outside the bore (inside a wall or outside the network); ``normal`` is the unit
surface normal at the hit pointing out of the bore (into the wall).

The faceted meshes deviate from these surfaces by up to the tessellation tolerance of
:mod:`pipe_env.meshes` radially, which is why the two backends agree only within that tolerance
divided by the cosine of the incidence angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pipe_env.fittings import FittingGeometry
from pipe_env.network import PipeNetwork
from pipe_env.raycast_kernels import N_FIELDS, QUADRIC, TORUS, axial_safe_bands, cast_rays

#: Longest piece a straight run is split into, metres (tighter spatial culling).
SEGMENT_LENGTH = 0.25
#: Two intervals closer than this along a ray are treated as touching (seams between pieces), m.
SEAM_EPS = 1.0e-9
#: Surface codes of an interval end: the curved side of the piece, or one of its clip planes.
SIDE, PLANE0, PLANE1 = 0, 1, 2


@dataclass(frozen=True, eq=False)
class QuadricPieces:
    """K cone frustums (slope 0: cylinders), each clipped by two planes.

    The solid of piece k is ``{x : |x - p - s u|^2 <= (r0 + slope s)^2, x . n_i <= h_i}`` with
    ``s = (x - p) . u`` and the two planes ``(n_i, h_i)``. Lengths in metres.
    """

    origin: NDArray[np.float64]  # (K, 3) point p on the axis where the radius is r0
    axis: NDArray[np.float64]  # (K, 3) unit axis u
    radius0: NDArray[np.float64]  # (K,)
    slope: NDArray[np.float64]  # (K,) dr/ds
    plane_normals: NDArray[np.float64]  # (K, 2, 3) outward unit normals
    plane_offsets: NDArray[np.float64]  # (K, 2)
    bound_centre: NDArray[np.float64]  # (K, 3) bounding sphere
    bound_radius: NDArray[np.float64]  # (K,)
    element: NDArray[np.int64]  # (K,) index into AnalyticBore.elements

    def __len__(self) -> int:
        return int(len(self.radius0))


@dataclass(frozen=True, eq=False)
class TorusPieces:
    """T torus sectors (long-radius bends): points within ``minor`` of a circular arc.

    The arc has centre ``centre``, unit normal ``axis`` and radius ``major``; the sector is cut by
    two planes through the axis, ``x . n_i <= h_i``.
    """

    centre: NDArray[np.float64]  # (T, 3)
    axis: NDArray[np.float64]  # (T, 3)
    major: NDArray[np.float64]  # (T,)
    minor: NDArray[np.float64]  # (T,)
    plane_normals: NDArray[np.float64]  # (T, 2, 3)
    plane_offsets: NDArray[np.float64]  # (T, 2)
    bound_centre: NDArray[np.float64]  # (T, 3)
    bound_radius: NDArray[np.float64]  # (T,)
    element: NDArray[np.int64]  # (T,)

    def __len__(self) -> int:
        return int(len(self.major))


@dataclass(frozen=True, eq=False)
class RayHits:
    """Result of :meth:`AnalyticBore.cast` for N rays.

    Attributes:
        dist: (N,) distance to the wall along the unit direction, metres; ``inf``: no hit within
            the cutoff; 0: the ray starts outside the bore.
        normal: (N, 3) unit wall normal at the hit, pointing out of the bore (zeros: no hit).
        element: (N,) index into ``AnalyticBore.elements`` of the element hit (-1: none).
    """

    dist: NDArray[np.float64]
    normal: NDArray[np.float64]
    element: NDArray[np.int64]


class _PieceBuilder:
    def __init__(self) -> None:
        self.quadrics: list[tuple] = []
        self.tori: list[tuple] = []

    def frustum(
        self,
        p0: NDArray,
        p1: NDArray,
        r0: float,
        r1: float,
        element: int,
        start_plane: tuple[NDArray, float] | None = None,
        end_plane: tuple[NDArray, float] | None = None,
    ) -> None:
        """Frustum from p0 (radius r0) to p1 (radius r1); caps at p0 and p1 unless replaced by
        ``start_plane``/``end_plane`` given as (outward normal, offset)."""
        axis = p1 - p0
        length = float(np.linalg.norm(axis))
        u = axis / length
        slope = (r1 - r0) / length
        planes = [
            start_plane if start_plane is not None else (-u, float(-u @ p0)),
            end_plane if end_plane is not None else (u, float(u @ p1)),
        ]
        mid = 0.5 * (p0 + p1)
        bound = 0.5 * length + max(r0, r1)
        self.quadrics.append((p0, u, r0, slope, planes, mid, bound, element))

    def cylinder_between_planes(
        self,
        point: NDArray,
        u: NDArray,
        radius: float,
        planes: list[tuple[NDArray, float]],
        bound_centre: NDArray,
        bound_radius: float,
        element: int,
    ) -> None:
        self.quadrics.append((point, u, radius, 0.0, planes, bound_centre, bound_radius, element))

    def build(self) -> tuple[QuadricPieces, TorusPieces]:
        q = self.quadrics
        quadrics = QuadricPieces(
            origin=np.array([e[0] for e in q], dtype=float).reshape(-1, 3),
            axis=np.array([e[1] for e in q], dtype=float).reshape(-1, 3),
            radius0=np.array([e[2] for e in q], dtype=float),
            slope=np.array([e[3] for e in q], dtype=float),
            plane_normals=np.array([[pl[0] for pl in e[4]] for e in q], dtype=float).reshape(
                -1, 2, 3
            ),
            plane_offsets=np.array([[pl[1] for pl in e[4]] for e in q], dtype=float).reshape(-1, 2),
            bound_centre=np.array([e[5] for e in q], dtype=float).reshape(-1, 3),
            bound_radius=np.array([e[6] for e in q], dtype=float),
            element=np.array([e[7] for e in q], dtype=np.int64),
        )
        t = self.tori
        tori = TorusPieces(
            centre=np.array([e[0] for e in t], dtype=float).reshape(-1, 3),
            axis=np.array([e[1] for e in t], dtype=float).reshape(-1, 3),
            major=np.array([e[2] for e in t], dtype=float),
            minor=np.array([e[3] for e in t], dtype=float),
            plane_normals=np.array([[pl[0] for pl in e[4]] for e in t], dtype=float).reshape(
                -1, 2, 3
            ),
            plane_offsets=np.array([[pl[1] for pl in e[4]] for e in t], dtype=float).reshape(-1, 2),
            bound_centre=np.array([e[5] for e in t], dtype=float).reshape(-1, 3),
            bound_radius=np.array([e[6] for e in t], dtype=float),
            element=np.array([e[7] for e in t], dtype=np.int64),
        )
        return quadrics, tori


def _add_fitting(b: _PieceBuilder, g: FittingGeometry, element: int) -> None:
    if g.kind == "closure":
        p = g.ports[0]
        b.frustum(g.centre, p.position, p.radius, p.radius, element)
    elif g.kind == "reducer":
        a, c = g.ports
        b.frustum(a.position, c.position, a.radius, c.radius, element)
    elif g.kind == "bend" and g.style == "long":
        centre, normal, radius, angle = g.bend_arc()
        a, c = g.ports
        u0 = (a.position - centre) / radius
        u1 = (c.position - centre) / radius
        n0 = -np.cross(normal, u0)  # outward: against the direction of increasing sweep angle
        n1 = np.cross(normal, u1)
        planes = [(n0, float(n0 @ centre)), (n1, float(n1 @ centre))]
        mid = 0.5 * (a.position + c.position)
        bound = (
            0.5 * float(np.linalg.norm(c.position - a.position))
            + radius * (1.0 - math.cos(0.5 * angle))
            + a.radius
        )
        b.tori.append((centre, normal, radius, a.radius, planes, mid, bound, element))
    elif g.kind == "bend":
        a, c = g.ports
        r = a.radius
        half = 0.5 * g.deflection
        for p, q in ((a, c), (c, a)):
            m = p.axis - q.axis
            m = m / np.linalg.norm(m)
            planes = [(-m, float(-m @ g.centre)), (p.axis, float(p.axis @ p.position))]
            bound = p.leg + r * (1.0 + math.tan(half)) + 1e-6
            b.cylinder_between_planes(g.centre, p.axis, r, planes, g.centre, bound, element)
    else:  # junctions
        pairs = g.collinear_pairs()
        paired = {i for pair in pairs for i in pair}
        for i, j in pairs:
            pi, pj = g.ports[i], g.ports[j]
            b.frustum(pi.position, pj.position, pi.radius, pi.radius, element)
        for i, p in enumerate(g.ports):
            if i not in paired:
                b.frustum(g.centre, p.position, p.radius, p.radius, element)


def _pieces(
    network: PipeNetwork, segment_length: float
) -> tuple[QuadricPieces, TorusPieces, list[str]]:
    """The pieces of a validated network, runs split into at most ``segment_length`` (m)."""
    b = _PieceBuilder()
    elements: list[str] = []
    for r in network.runs:
        if network.straight_length(r.id) <= 1e-6:
            continue
        pa = network.geometry[r.a].port(r.id).position
        pb = network.geometry[r.b].port(r.id).position
        element = len(elements)
        elements.append(f"run:{r.id}")
        n_seg = max(1, math.ceil(float(np.linalg.norm(pb - pa)) / segment_length))
        cuts = [pa + (pb - pa) * (i / n_seg) for i in range(n_seg + 1)]
        for i in range(n_seg):
            b.frustum(cuts[i], cuts[i + 1], 0.5 * r.diameter, 0.5 * r.diameter, element)
    for f in network.fittings:
        element = len(elements)
        elements.append(f"fitting:{f.id}")
        _add_fitting(b, network.geometry[f.id], element)
    quadrics, tori = b.build()
    return quadrics, tori, elements


def _pack(
    quadrics: QuadricPieces, tori: TorusPieces
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """The pieces as the compiled kernels read them: a (K, 22) table (columns in
    :data:`pipe_env.raycast_kernels.FIELDS`), kinds and element ids; quadrics, then tori."""
    rows = []
    for pc in (quadrics, tori):
        rows.append(
            np.column_stack(
                [
                    pc.origin if isinstance(pc, QuadricPieces) else pc.centre,
                    pc.axis,
                    pc.radius0 if isinstance(pc, QuadricPieces) else pc.major,
                    pc.slope if isinstance(pc, QuadricPieces) else pc.minor,
                    pc.plane_normals[:, 0],
                    pc.plane_offsets[:, 0],
                    pc.plane_normals[:, 1],
                    pc.plane_offsets[:, 1],
                    pc.bound_centre,
                    pc.bound_radius,
                    np.zeros((len(pc), 2)),  # safe bands, below
                ]
            ).reshape(-1, N_FIELDS)
        )
    table = np.ascontiguousarray(np.concatenate(rows), dtype=np.float64)
    kind = np.concatenate(
        [np.full(len(quadrics), QUADRIC, dtype=np.int64), np.full(len(tori), TORUS, dtype=np.int64)]
    )
    table[:, N_FIELDS - 2 :] = axial_safe_bands(table, kind)
    element = np.ascontiguousarray(np.concatenate([quadrics.element, tori.element]), dtype=np.int64)
    return table, kind, element


class AnalyticBore:
    """The exact bore of a network as a union of convex quadric pieces and torus sectors.

    Build with :meth:`from_network`; cast with :meth:`cast`. ``elements`` names the network
    elements (``run:<id>``, ``fitting:<id>``) as :func:`pipe_env.world.network_meshes` does.
    """

    def __init__(
        self,
        quadrics: QuadricPieces,
        tori: TorusPieces,
        elements: list[str],
        kernel_pieces: tuple[QuadricPieces, TorusPieces] | None = None,
    ) -> None:
        """``quadrics``, ``tori``: the pieces of the numpy path (:meth:`cast_numpy`,
        :meth:`contains`); ``kernel_pieces``: the same solids as the compiled kernels read them
        (runs not split into segments: their broad phase is per ray), default the same pieces."""
        self.quadrics = quadrics
        self.tori = tori
        self.elements = elements
        kq, kt = kernel_pieces if kernel_pieces is not None else (quadrics, tori)
        self._table, self._kind, self._element = _pack(kq, kt)

    @classmethod
    def from_network(
        cls, network: PipeNetwork, segment_length: float = SEGMENT_LENGTH
    ) -> AnalyticBore:
        """Pieces of every run (with a straight part) and every fitting of ``network``.

        ``segment_length`` (m) splits long runs for the numpy path's culling; the compiled
        kernels read every run as one piece (they cull per ray)."""
        if not (math.isfinite(segment_length) and segment_length > 0):
            raise ValueError(f"segment_length = {segment_length!r} m is invalid; allowed > 0")
        network.validate()
        quadrics, tori, elements = _pieces(network, segment_length)
        kq, kt, _ = _pieces(network, math.inf)
        return cls(quadrics, tori, elements, (kq, kt))

    # ------------------------------------------------------------------ queries
    def contains(self, points: ArrayLike) -> NDArray[np.bool_]:
        """(N,) True where a (N, 3) point lies inside the bore (closed set)."""
        x = np.asarray(points, dtype=float).reshape(-1, 3)
        inside = np.zeros(len(x), dtype=bool)
        q = self.quadrics
        for k in range(len(q)):
            w = x - q.origin[k]
            s = w @ q.axis[k]
            rad2 = np.einsum("ij,ij->i", w, w) - s * s
            ok = rad2 <= (q.radius0[k] + q.slope[k] * s) ** 2
            ok &= (x @ q.plane_normals[k].T <= q.plane_offsets[k]).all(axis=1)
            inside |= ok
        t = self.tori
        for k in range(len(t)):
            w = x - t.centre[k]
            h = w @ t.axis[k]
            rho = np.sqrt(np.maximum(np.einsum("ij,ij->i", w, w) - h * h, 0.0))
            ok = (rho - t.major[k]) ** 2 + h * h <= t.minor[k] ** 2
            ok &= (x @ t.plane_normals[k].T <= t.plane_offsets[k]).all(axis=1)
            inside |= ok
        return inside

    def cast(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        cutoff: float = math.inf,
        normals: bool = True,
    ) -> RayHits:
        """Intersect N rays with the bore's wall (compiled kernels, one ray at a time).

        Args:
            origins: (N, 3) or (3,) ray origins, metres (world frame).
            directions: (N, 3) unit directions.
            cutoff: hits farther than this (m) are reported as ``inf``; pieces whose bounding
                sphere the ray does not reach within it are skipped (spatial culling).
            normals: compute the wall normals (else ``RayHits.normal`` is all zeros).
        """
        d = np.ascontiguousarray(np.asarray(directions, dtype=float).reshape(-1, 3))
        n = len(d)
        if not (cutoff > 0):
            raise ValueError(f"cutoff = {cutoff!r} m is invalid; allowed > 0")
        o_in = np.asarray(origins, dtype=float)
        if o_in.ndim == 1:
            if o_in.shape != (3,):
                raise ValueError(f"origins has shape {o_in.shape}; allowed (3,) or (N, 3)")
            o, per = o_in.reshape(1, 3), max(n, 1)
        else:
            o = o_in.reshape(-1, 3)
            if len(o) == 1:
                per = max(n, 1)
            elif len(o) == n:
                per = 1
            else:
                raise ValueError(f"origins has {len(o)} rows for {n} directions; allowed 1 or {n}")
        return self._cast_grouped(np.ascontiguousarray(o), per, d, float(cutoff), normals)

    def cast_groups(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        cutoff: float = math.inf,
        normals: bool = True,
    ) -> RayHits:
        """Intersect M groups of B rays, group ``m`` cast from ``origins[m]`` (a LiDAR sweep:
        one origin per plane) without repeating the origins per ray.

        Args:
            origins: (M, 3) origins, metres.
            directions: (M, B, 3) unit directions.
            cutoff, normals: as :meth:`cast`.

        Returns:
            :class:`RayHits` of the M * B rays, group-major.
        """
        o = np.ascontiguousarray(np.asarray(origins, dtype=float))
        d = np.asarray(directions, dtype=float)
        if o.ndim != 2 or o.shape[1] != 3 or d.ndim != 3 or d.shape[0] != len(o) or d.shape[2] != 3:
            raise ValueError(
                f"origins {o.shape} and directions {d.shape} are invalid; allowed (M, 3) and "
                "(M, B, 3)"
            )
        if not (cutoff > 0):
            raise ValueError(f"cutoff = {cutoff!r} m is invalid; allowed > 0")
        per = max(d.shape[1], 1)
        return self._cast_grouped(
            o, per, np.ascontiguousarray(d.reshape(-1, 3)), float(cutoff), normals
        )

    def _cast_grouped(
        self, origins: NDArray, per: int, d: NDArray, cutoff: float, normals: bool
    ) -> RayHits:
        n = len(d)
        dist = np.empty(n)
        normal = np.empty((n, 3))
        element = np.empty(n, dtype=np.int64)
        if n == 0:
            return RayHits(dist, normal, element)
        cast_rays(
            self._table,
            self._kind,
            self._element,
            origins,
            per,
            d,
            cutoff,
            normals,
            dist,
            normal,
            element,
        )
        return RayHits(dist, normal, element)

    def cast_numpy(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        cutoff: float = math.inf,
        normals: bool = True,
    ) -> RayHits:
        """Intersect N rays with the bore's wall: the vectorised numpy reference.

        The backend as it was before the compiled kernels, kept as an independent check of
        :meth:`cast` (same results within rounding) and as a benchmark reference.

        Args:
            origins: (N, 3) or (3,) ray origins, metres (world frame).
            directions: (N, 3) unit directions.
            cutoff: hits farther than this (m) are reported as ``inf``; pieces whose bounding
                sphere lies beyond it are skipped (spatial culling).
            normals: compute the wall normals (else ``RayHits.normal`` is all zeros).
        """
        d = np.asarray(directions, dtype=float).reshape(-1, 3)
        n = len(d)
        o_in = np.asarray(origins, dtype=float)
        if not (cutoff > 0):
            raise ValueError(f"cutoff = {cutoff!r} m is invalid; allowed > 0")
        dist = np.full(n, np.inf)
        normal = np.zeros((n, 3))
        element = np.full(n, -1, dtype=np.int64)
        if n == 0:
            return RayHits(dist, normal, element)
        o_full = np.broadcast_to(o_in, (n, 3))
        single = o_in.ndim == 1 or bool((o_full == o_full[0]).all())
        ref = o_full[0].copy()  # work relative to the first origin: small coordinates
        rays = _Rays(d, None if single else o_full - ref)
        parts: list[tuple[NDArray, NDArray, NDArray, NDArray, NDArray]] = []
        q, t = self.quadrics, self.tori
        nq = len(q)
        if nq:
            pairs = _candidates(rays, q.bound_centre - ref, q.bound_radius, cutoff)
            if pairs is not None:
                lo, hi, code = _quadric_intervals(q, ref, rays, pairs)
                parts.append((pairs.ri, pairs.ki, lo, hi, code))
        if len(t):
            pairs = _candidates(rays, t.bound_centre - ref, t.bound_radius, cutoff)
            if pairs is not None:
                for lo, hi, code in _torus_intervals(t, ref, rays, pairs):
                    parts.append((pairs.ri, pairs.ki + nq, lo, hi, code))
        if not parts:
            dist[:] = 0.0
            return RayHits(dist, normal, element)
        ri, ki, lo, hi, code = (np.concatenate(c) for c in zip(*parts))
        keep = hi > lo
        ri, ki, lo, hi, code = ri[keep], ki[keep], lo[keep], hi[keep], code[keep]
        exit_t = _union_exit(n, ri, lo, hi)
        dist[:] = exit_t
        # the interval that ended at the exit gives the piece and surface, hence the normal
        fi = np.flatnonzero(hi == exit_t[ri])
        chosen = np.full(n, -1, dtype=np.int64)
        chosen[ri[fi]] = fi
        chosen[exit_t <= 0.0] = -1
        hit_rays = np.flatnonzero(chosen >= 0)
        fi = chosen[hit_rays]
        element[hit_rays] = np.concatenate([q.element, t.element])[ki[fi]]
        if normals:
            hit_pts = o_full[hit_rays] + exit_t[hit_rays, None] * d[hit_rays]
            normal[hit_rays] = self._normals(ki[fi], code[fi], hit_pts)
        far = dist > cutoff
        dist[far] = np.inf
        normal[far] = 0.0
        element[far] = -1
        return RayHits(dist, normal, element)

    def _normals(self, piece: NDArray, code: NDArray, x: NDArray) -> NDArray[np.float64]:
        q, t = self.quadrics, self.tori
        nq = len(q)
        out = np.zeros((len(piece), 3))
        is_torus = piece >= nq
        for plane in (PLANE0, PLANE1):
            sel = (code == plane) & ~is_torus
            out[sel] = q.plane_normals[piece[sel], plane - PLANE0]
            sel = (code == plane) & is_torus
            out[sel] = t.plane_normals[piece[sel] - nq, plane - PLANE0]
        sel = (code == SIDE) & ~is_torus
        if sel.any():
            k = piece[sel]
            w = x[sel] - q.origin[k]
            u = q.axis[k]
            s = np.einsum("ij,ij->i", w, u)
            grad = w - (s + q.slope[k] * (q.radius0[k] + q.slope[k] * s))[:, None] * u
            out[sel] = grad
        sel = (code == SIDE) & is_torus
        if sel.any():
            k = piece[sel] - nq
            w = x[sel] - t.centre[k]
            ax = t.axis[k]
            h = np.einsum("ij,ij->i", w, ax)
            radial = w - h[:, None] * ax
            rho = np.linalg.norm(radial, axis=1)
            core = radial * (t.major[k] / np.maximum(rho, 1e-300))[:, None]
            out[sel] = w - core
        norm = np.linalg.norm(out, axis=1)
        return out / np.maximum(norm, 1e-300)[:, None]


class _Rays:
    """N rays; origins relative to a reference point (``o is None``: all at the reference)."""

    def __init__(self, d: NDArray, o: NDArray | None) -> None:
        self.n = len(d)
        self.d = np.ascontiguousarray(d)
        self.o = None if o is None else np.ascontiguousarray(o)
        self.single = o is None
        self.dx, self.dy, self.dz = (np.ascontiguousarray(d[:, i]) for i in range(3))
        if o is not None:
            self.ox, self.oy, self.oz = (np.ascontiguousarray(o[:, i]) for i in range(3))
            self.od = np.einsum("ij,ij->i", o, d)
            self.oo = np.einsum("ij,ij->i", o, o)


@dataclass(frozen=True, eq=False)
class _Pairs:
    """Candidate (ray, piece) pairs: ``near`` are the piece ids kept by culling, ``kk`` indexes
    ``near`` and ``ki = near[kk]`` the piece tables."""

    ri: NDArray[np.int64]
    kk: NDArray[np.int64]
    ki: NDArray[np.int64]
    near: NDArray[np.int64]
    counts: NDArray[np.int64]  # pairs per kept piece; pairs are sorted by kk

    def spread(self, values: NDArray) -> NDArray:
        """Per-piece ``values`` (K',) repeated for each pair (cheaper than a gather)."""
        return np.repeat(values, self.counts)

    def dots(self, rays: _Rays, vectors: NDArray) -> tuple[list[NDArray], list[NDArray]]:
        """Per pair, d . v_j and (several origins) o . v_j for the (K', m, 3) vectors of the
        kept pieces (gathered ray components times gathered piece components)."""
        v = np.ascontiguousarray(vectors.transpose(1, 2, 0))  # (m, 3, K')

        comps = [[self.spread(v[j, i]) for i in range(3)] for j in range(v.shape[0])]
        gx, gy, gz = rays.dx[self.ri], rays.dy[self.ri], rays.dz[self.ri]
        d_dots = [gx * c[0] + gy * c[1] + gz * c[2] for c in comps]
        o_dots: list[NDArray] = []
        if rays.o is not None:
            hx, hy, hz = rays.ox[self.ri], rays.oy[self.ri], rays.oz[self.ri]
            o_dots = [hx * c[0] + hy * c[1] + hz * c[2] for c in comps]
        return d_dots, o_dots


def _products(x: NDArray, vectors: NDArray) -> NDArray[np.float64]:
    """(K, N) dot products of (N, 3) rows with (K, 3) vectors.

    One matrix-vector product per vector: a single threaded BLAS matrix product of this shape
    stalls for milliseconds whenever the other cores are busy."""
    out = np.empty((len(vectors), len(x)))
    for i, v in enumerate(vectors):
        np.dot(x, v, out=out[i])
    return out


def _candidates(rays: _Rays, centres: NDArray, radii: NDArray, cutoff: float) -> _Pairs | None:
    """(ray, piece) pairs whose ray passes through the piece's bounding sphere.

    ``centres`` are relative to the reference origin. Pieces wholly beyond the cutoff from every
    origin are culled first (spatial culling)."""
    if rays.o is None:
        dist0 = np.linalg.norm(centres, axis=1)
        near = np.flatnonzero(dist0 - radii <= cutoff)
    else:
        lo, hi = rays.o.min(axis=0), rays.o.max(axis=0)
        gap = np.maximum(np.maximum(lo - centres, centres - hi), 0.0)
        near = np.flatnonzero(np.linalg.norm(gap, axis=1) - radii <= cutoff)
    if len(near) == 0:
        return None
    c, rad = centres[near], radii[near]
    cc = np.einsum("ij,ij->i", c, c)
    tc = _products(rays.d, c)  # (K', N) d . c
    if rays.o is None:
        # the ray meets the sphere iff d . c >= sqrt(|c|^2 - R^2) (always if it starts inside)
        outside = cc > rad * rad
        threshold = np.where(outside, np.sqrt(np.where(outside, cc - rad * rad, 0.0)), -np.inf)
        hit = tc >= threshold[:, None]
    else:
        tc -= rays.od[None, :]  # d . (c - o)
        dist2 = cc[:, None] - 2.0 * _products(rays.o, c) + rays.oo[None, :]
        hit = (dist2 - tc * tc <= (rad * rad)[:, None]) & (tc >= -rad[:, None])
    flat = np.flatnonzero(hit)
    if len(flat) == 0:
        return None
    kk, ri = np.divmod(flat, rays.n)
    counts = np.bincount(kk, minlength=len(near))
    return _Pairs(ri, kk, near[kk], near, counts)


def _clip(
    planes: list[tuple[NDArray, NDArray]], lo: NDArray, hi: NDArray
) -> tuple[NDArray, NDArray, NDArray]:
    """Clip intervals [lo, hi] (the side surface at hi) by planes given per pair as
    ``(d . n, h - o . n)`` (inside while ``t (d . n) <= h - o . n``); also the code of hi."""
    code = np.zeros(len(lo), dtype=np.int8)
    for i, (dn, gap) in enumerate(planes):
        with np.errstate(divide="ignore", invalid="ignore"):
            tp = gap / dn
        cut = (dn > 0.0) & (tp < hi)
        hi = np.where(cut, tp, hi)
        code[cut] = PLANE0 + i
        lo = np.where((dn < 0.0) & (tp > lo), tp, lo)
        lo = np.where((dn == 0.0) & (gap < 0.0), np.inf, lo)
    return lo, hi, code


def _plane_gaps(
    normals: NDArray, offsets: NDArray, ref: NDArray, pairs: _Pairs, o_dots: list[NDArray]
) -> list[NDArray]:
    """Per pair and plane, ``h - o . n`` with o relative to ``ref``."""
    out = []
    for i in range(2):
        h_rel = pairs.spread((offsets[:, i] - normals[:, i, :] @ ref)[pairs.near])
        out.append(h_rel - o_dots[i] if o_dots else h_rel)
    return out


def _quadric_intervals(
    q: QuadricPieces, ref: NDArray, rays: _Rays, pairs: _Pairs
) -> tuple[NDArray, NDArray, NDArray]:
    near, ri = pairs.near, pairs.ri
    p0 = q.origin[near] - ref
    axis = q.axis[near]
    vectors = np.stack([axis, p0, q.plane_normals[near, 0], q.plane_normals[near, 1]], axis=1)
    (du, dp, dn0, dn1), o_dots = pairs.dots(rays, vectors)
    # w = o - p0; with one origin (o = 0 after the shift) w = -p0 for every pair
    s0 = pairs.spread(-np.einsum("ij,ij->i", p0, axis))
    ww = pairs.spread(np.einsum("ij,ij->i", p0, p0))
    if o_dots:
        ou, op = o_dots[0], o_dots[1]
        s0 = s0 + ou
        wd = rays.od[ri] - dp
        ww = ww - 2.0 * op + rays.oo[ri]
    else:
        wd = -dp
    gaps = _plane_gaps(q.plane_normals, q.plane_offsets, ref, pairs, o_dots[2:])
    planes = [(dn0, gaps[0]), (dn1, gaps[1])]
    k = pairs.spread(q.slope[near])
    rs = pairs.spread(q.radius0[near]) + k * s0
    # f(t) = a t^2 + 2 b t + c <= 0 inside the (double) cone
    kdu = k * du
    a = 1.0 - du * du - kdu * kdu
    b = wd - s0 * du - kdu * rs
    c = ww - s0 * s0 - rs * rs
    disc = b * b - a * c
    sq = np.sqrt(np.maximum(disc, 0.0))
    qq = -(b + np.copysign(sq, b))
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = qq / a
        t2 = c / qq
    r_lo = np.minimum(t1, t2)
    r_hi = np.maximum(t1, t2)
    inf = np.inf
    pos = (a > 1e-12) & (disc >= 0.0)
    lo = np.where(pos, r_lo, inf)
    hi = np.where(pos, r_hi, -inf)
    tiny = np.abs(a) <= 1e-12
    if tiny.any():  # linear: a ray parallel to a cylinder is inside for all t or never
        with np.errstate(divide="ignore", invalid="ignore"):
            t_lin = -c / (2.0 * b)
        const_in = tiny & (np.abs(b) <= 1e-15) & (c <= 0.0)
        up = tiny & (b > 1e-15)
        down = tiny & (b < -1e-15)
        lo = np.where(const_in | up, -inf, np.where(down, t_lin, lo))
        hi = np.where(const_in | down, inf, np.where(up, t_lin, hi))
    all_in = (a < -1e-12) & (disc < 0.0)
    if all_in.any():
        lo = np.where(all_in, -inf, lo)
        hi = np.where(all_in, inf, hi)
    lo1, hi1, code1 = _clip(planes, lo, hi)
    # a < 0 (a cone crossed steeply): outside between the roots. Within the frustum's slab only
    # one of (-inf, r_lo] and [r_hi, inf) belongs to the right nappe, so clip both and keep one.
    neg = np.flatnonzero((a < -1e-12) & (disc >= 0.0))
    if len(neg):
        sub = [(dn[neg], gap[neg]) for dn, gap in planes]
        lo_a, hi_a, code_a = _clip(sub, np.full(len(neg), -inf), r_lo[neg])
        lo_b, hi_b, code_b = _clip(sub, r_hi[neg], np.full(len(neg), inf))
        use_a = hi_a > lo_a
        lo1[neg] = np.where(use_a, lo_a, lo_b)
        hi1[neg] = np.where(use_a, hi_a, hi_b)
        code1[neg] = np.where(use_a, code_a, code_b)
    return lo1, hi1, code1


def solve_depressed_quartic(p: NDArray, q: NDArray, s: NDArray) -> NDArray[np.float64]:
    """Real roots of ``x^4 + p x^2 + q x + s = 0``, vectorised: (M, 4), NaN for complex roots.

    Descartes' factorisation into two quadratics through the largest root of the resolvent
    cubic, then two Newton steps on the quartic for every real root.
    """
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    s = np.asarray(s, dtype=float)
    # resolvent cubic z^3 + 2p z^2 + (p^2 - 4s) z - q^2 = 0, largest real root z >= 0
    a2, a1, a0 = 2.0 * p, p * p - 4.0 * s, -q * q
    z = _largest_cubic_root(a2, a1, a0)
    for _ in range(2):  # polish
        f = ((z + a2) * z + a1) * z + a0
        fp = (3.0 * z + 2.0 * a2) * z + a1
        step = np.where(np.abs(fp) > 1e-300, f / np.where(fp == 0.0, 1.0, fp), 0.0)
        z = z - step
    z = np.maximum(z, 0.0)
    roots = np.full(p.shape + (4,), np.nan)
    scale = np.maximum(np.maximum(np.abs(p), np.sqrt(np.abs(s))), 1e-300)
    biq = z <= 1e-14 * scale
    # general case
    alpha = np.sqrt(z)
    with np.errstate(divide="ignore", invalid="ignore"):
        q_over_alpha = np.where(biq, 0.0, q / np.where(biq, 1.0, alpha))
    beta = 0.5 * (p + z - q_over_alpha)
    gamma = 0.5 * (p + z + q_over_alpha)
    d1 = z - 4.0 * beta
    d2 = z - 4.0 * gamma
    s1 = np.sqrt(np.maximum(d1, 0.0))
    s2 = np.sqrt(np.maximum(d2, 0.0))
    r = np.stack(
        [
            np.where(d1 >= 0, 0.5 * (-alpha - s1), np.nan),
            np.where(d1 >= 0, 0.5 * (-alpha + s1), np.nan),
            np.where(d2 >= 0, 0.5 * (alpha - s2), np.nan),
            np.where(d2 >= 0, 0.5 * (alpha + s2), np.nan),
        ],
        axis=-1,
    )
    # biquadratic: x^2 = (-p +- sqrt(p^2 - 4 s)) / 2
    dq = p * p - 4.0 * s
    sq = np.sqrt(np.maximum(dq, 0.0))
    y1 = np.where(dq >= 0, 0.5 * (-p - sq), np.nan)
    y2 = np.where(dq >= 0, 0.5 * (-p + sq), np.nan)
    rb = np.stack(
        [
            np.where(y1 >= 0, -np.sqrt(np.abs(y1)), np.nan),
            np.where(y1 >= 0, np.sqrt(np.abs(y1)), np.nan),
            np.where(y2 >= 0, -np.sqrt(np.abs(y2)), np.nan),
            np.where(y2 >= 0, np.sqrt(np.abs(y2)), np.nan),
        ],
        axis=-1,
    )
    roots = np.where(biq[..., None], rb, r)
    pe, qe, se = p[..., None], q[..., None], s[..., None]
    for _ in range(2):
        x = roots
        x2 = x * x
        f = (x2 + pe) * x2 + qe * x + se
        fp = (4.0 * x2 + 2.0 * pe) * x + qe
        ok = np.abs(fp) > 1e-12 * (np.abs(x) * scale[..., None] + 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            roots = np.where(ok, x - f / fp, x)
    return roots


def _largest_cubic_root(a: NDArray, b: NDArray, c: NDArray) -> NDArray[np.float64]:
    """Largest real root of ``z^3 + a z^2 + b z + c`` (vectorised)."""
    shift = a / 3.0
    p = b - a * shift
    q = 2.0 * shift**3 - shift * b + c
    half_q = 0.5 * q
    disc = half_q * half_q + (p / 3.0) ** 3
    sq = np.sqrt(np.maximum(disc, 0.0))
    one = np.cbrt(-half_q + sq) + np.cbrt(-half_q - sq)
    m = np.sqrt(np.maximum(-p / 3.0, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_arg = np.where(m > 0, -half_q / np.where(m > 0, m**3, 1.0), 0.0)
    three = 2.0 * m * np.cos(np.arccos(np.clip(cos_arg, -1.0, 1.0)) / 3.0)
    y = np.where(disc > 0, one, three)
    return y - shift


def _torus_intervals(
    t: TorusPieces, ref: NDArray, rays: _Rays, pairs: _Pairs
) -> list[tuple[NDArray, NDArray, NDArray]]:
    """Up to two intervals per (ray, torus sector) pair, clipped by the sector's planes."""
    near, ri = pairs.near, pairs.ri
    centre = t.centre[near] - ref
    axis = t.axis[near]
    vectors = np.stack([axis, centre, t.plane_normals[near, 0], t.plane_normals[near, 1]], axis=1)
    (e, dc, dn0, dn1), o_dots = pairs.dots(rays, vectors)
    big = pairs.spread(t.major[near])
    cn = pairs.spread(np.einsum("ij,ij->i", centre, axis))
    cc = pairs.spread(np.einsum("ij,ij->i", centre, centre))
    # w = o - centre; solve from the ray point closest to the centre, in units of R
    if o_dots:
        on, oc = o_dots[0], o_dots[1]
        t0 = dc - rays.od[ri]
        wn = on - cn
        ww = rays.oo[ri] - 2.0 * oc + cc
    else:
        t0 = dc
        wn = -cn
        ww = cc
    inv = 1.0 / big
    c = (wn + t0 * e) * inv
    qq = np.maximum(ww - t0 * t0, 0.0) * inv * inv
    rr = pairs.spread(t.minor[near]) * inv
    bb = qq + 1.0 - rr * rr
    p2 = 2.0 * bb - 4.0 * (1.0 - e * e)
    p1 = 8.0 * c * e
    p0 = bb * bb - 4.0 * (qq - c * c)
    roots = np.sort(solve_depressed_quartic(p2, p1, p0), axis=1)  # NaN sorts last
    roots = roots * big[:, None] + t0[:, None]
    gaps = _plane_gaps(t.plane_normals, t.plane_offsets, ref, pairs, o_dots[2:])
    planes = [(dn0, gaps[0]), (dn1, gaps[1])]
    out = []
    for j in (0, 2):
        lo, hi = roots[:, j], roots[:, j + 1]
        valid = np.isfinite(lo) & np.isfinite(hi)
        out.append(_clip(planes, np.where(valid, lo, np.inf), np.where(valid, hi, -np.inf)))
    return out


def _union_exit(n: int, ri: NDArray, lo: NDArray, hi: NDArray) -> NDArray[np.float64]:
    """First exit from the union of intervals per ray, starting at t = 0 (0: not inside).

    Each pass extends ``t`` of a ray to the farthest end of the intervals that contain it; only
    intervals reaching beyond the current ``t`` are kept for the next pass."""
    t = np.zeros(n)
    while len(ri):
        tr = t[ri]
        ext = (lo <= tr + SEAM_EPS) & (hi > tr)
        if not ext.any():
            break
        np.maximum.at(t, ri[ext], hi[ext])
        alive = hi > t[ri]
        ri, lo, hi = ri[alive], lo[alive], hi[alive]
    return t
