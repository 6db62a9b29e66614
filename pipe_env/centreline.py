"""The centreline of a network as a graph of straight lines and circular arcs.

Pieces: each straight run (port to port), each fitting leg (node centre to port; for bends,
junctions, reducers and closures) and each long-radius bend (an arc from port to port). Graph
vertices are fitting centres and ports. The class answers the along-network questions: nearest
centreline point, local inner diameter, geodesic distance, and poses along a path.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path

from detector.geometry import Pose, clamp, cross, frame_from_forward, norm3

if TYPE_CHECKING:
    from pipe_env.network import PipeNetwork

Vertex = tuple[str, ...]


@dataclass(frozen=True, eq=False)
class Piece:
    """One straight line or circular arc of the centreline. Lengths and diameters in metres.

    ``run_id`` is the run a line belongs to (its straight pipe or a fitting leg along it);
    ``node_id`` the fitting a leg or arc belongs to (None for a run's straight pipe).
    """

    index: int
    kind: str
    v0: Vertex
    v1: Vertex
    p0: NDArray[np.float64]
    p1: NDArray[np.float64]
    length: float
    d0: float
    d1: float
    run_id: str | None
    node_id: str | None
    arc_centre: NDArray[np.float64] | None = None
    arc_normal: NDArray[np.float64] | None = None
    arc_radius: float = 0.0
    arc_angle: float = 0.0

    def point_tangent(self, s: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Point and unit tangent (from p0 towards p1) at arc length ``s`` from p0."""
        s = clamp(s, 0.0, self.length)
        if self.kind == "line":
            if self.length < 1e-12:
                return self.p0.copy(), np.zeros(3)
            t = (self.p1 - self.p0) / self.length
            return self.p0 + t * s, t
        assert self.arc_centre is not None and self.arc_normal is not None
        phi = s / self.arc_radius
        # Rodrigues' rotation of the start radius about the arc normal (unit) by phi
        k = self.arc_normal / norm3(self.arc_normal)
        u = self.p0 - self.arc_centre
        c, sn = math.cos(phi), math.sin(phi)
        radial = u * c + cross(k, u) * sn + k * (float(k @ u) * (1.0 - c))
        point = self.arc_centre + radial
        tangent = cross(k, radial)
        return point, tangent / norm3(tangent)

    def project(self, point: NDArray[np.float64]) -> float:
        """Arc length of the piece point closest to ``point``."""
        if self.kind == "line":
            if self.length < 1e-12:
                return 0.0
            t = (self.p1 - self.p0) / self.length
            return clamp(float((point - self.p0) @ t), 0.0, self.length)
        assert self.arc_centre is not None and self.arc_normal is not None
        u = self.p0 - self.arc_centre
        u /= norm3(u)
        w = cross(self.arc_normal, u)
        rel = point - self.arc_centre
        phi = float(np.arctan2(rel @ w, rel @ u))
        if phi < 0.0:  # outside the arc: snap to the angularly nearer end
            phi = self.arc_angle if phi < -np.pi + 0.5 * self.arc_angle else 0.0
        return min(phi, self.arc_angle) * self.arc_radius

    def diameter_at(self, s: float) -> float:
        if self.length < 1e-12:
            return self.d0
        f = clamp(s / self.length, 0.0, 1.0)
        return self.d0 + (self.d1 - self.d0) * f


@dataclass(frozen=True, eq=False)
class CentrelinePoint:
    """A point on the centreline: the piece, arc length along it and local properties (m)."""

    piece: Piece
    s: float
    point: NDArray[np.float64]
    tangent: NDArray[np.float64]
    distance: float
    diameter: float

    @property
    def run_id(self) -> str | None:
        return self.piece.run_id


class Centreline:
    """Centreline graph of a :class:`~pipe_env.network.PipeNetwork` (see module docstring)."""

    def __init__(self, network: PipeNetwork) -> None:
        self.network = network
        pieces: list[Piece] = []

        def add(
            kind: str,
            v0: Vertex,
            v1: Vertex,
            p0: NDArray,
            p1: NDArray,
            d0: float,
            d1: float,
            run_id: str | None,
            node_id: str | None,
            arc_centre: NDArray[np.float64] | None = None,
            arc_normal: NDArray[np.float64] | None = None,
            arc_radius: float = 0.0,
            arc_angle: float = 0.0,
        ) -> None:
            length = norm3(p1 - p0) if kind == "line" else float(arc_radius * arc_angle)
            pieces.append(
                Piece(
                    len(pieces),
                    kind,
                    v0,
                    v1,
                    p0,
                    p1,
                    length,
                    d0,
                    d1,
                    run_id,
                    node_id,
                    arc_centre,
                    arc_normal,
                    arc_radius,
                    arc_angle,
                )
            )

        for node_id, g in network.geometry.items():
            if g.kind == "bend" and g.style == "long":
                a, b = g.ports
                centre, normal, radius, angle = g.bend_arc()
                add(
                    "arc",
                    ("p", node_id, a.run_id),
                    ("p", node_id, b.run_id),
                    a.position,
                    b.position,
                    a.diameter,
                    b.diameter,
                    None,
                    node_id,
                    arc_centre=centre,
                    arc_normal=normal,
                    arc_radius=radius,
                    arc_angle=angle,
                )
                continue
            mid = float(np.mean([p.diameter for p in g.ports])) if g.kind == "reducer" else None
            for p in g.ports:
                d_centre = mid if mid is not None else p.diameter
                add(
                    "line",
                    ("c", node_id),
                    ("p", node_id, p.run_id),
                    g.centre,
                    p.position,
                    d_centre,
                    p.diameter,
                    p.run_id,
                    node_id,
                )
        for r in network.runs:
            pa = network.geometry[r.a].port(r.id).position
            pb = network.geometry[r.b].port(r.id).position
            add(
                "line",
                ("p", r.a, r.id),
                ("p", r.b, r.id),
                pa,
                pb,
                r.diameter,
                r.diameter,
                r.id,
                None,
            )
        self.pieces: tuple[Piece, ...] = tuple(pieces)
        verts: dict[Vertex, int] = {}
        for pc in pieces:
            for v in (pc.v0, pc.v1):
                verts.setdefault(v, len(verts))
        self.vertex_index = verts
        rows = [verts[pc.v0] for pc in pieces]
        cols = [verts[pc.v1] for pc in pieces]
        w = [max(pc.length, 1e-12) for pc in pieces]
        graph = coo_matrix((w, (rows, cols)), shape=(len(verts), len(verts))).tocsr()
        self._dist, self._pred = shortest_path(graph, directed=False, return_predecessors=True)
        lines = [pc for pc in pieces if pc.kind == "line"]
        self._line_idx = np.array([pc.index for pc in lines], dtype=int)
        self._p0 = np.array([pc.p0 for pc in lines])
        self._len = np.array([pc.length for pc in lines])
        with np.errstate(invalid="ignore", divide="ignore"):
            u = np.array([pc.p1 - pc.p0 for pc in lines]) / self._len[:, None]
        self._u = np.nan_to_num(u)
        self._arcs = [pc for pc in pieces if pc.kind == "arc"]

    @property
    def total_length(self) -> float:
        return float(sum(pc.length for pc in self.pieces))

    def nearest(self, point: NDArray[np.float64]) -> CentrelinePoint:
        """Nearest centreline point to ``point`` (m). Ties prefer the first piece found."""
        x = np.asarray(point, dtype=float)
        rel = x - self._p0
        t = np.clip(np.einsum("ij,ij->i", rel, self._u), 0.0, self._len)
        d = np.linalg.norm(rel - self._u * t[:, None], axis=1)
        k = int(np.argmin(d))
        best_piece, best_s, best_d = self.pieces[int(self._line_idx[k])], float(t[k]), float(d[k])
        for arc in self._arcs:
            s = arc.project(x)
            p, _ = arc.point_tangent(s)
            dist = norm3(x - p)
            if dist < best_d - 1e-12:
                best_piece, best_s, best_d = arc, s, dist
        return self.point_on(best_piece, best_s, x)

    def point_on(self, piece: Piece, s: float, query: NDArray | None = None) -> CentrelinePoint:
        p, tangent = piece.point_tangent(s)
        dist = norm3(query - p) if query is not None else 0.0
        return CentrelinePoint(piece, float(s), p, tangent, dist, piece.diameter_at(s))

    def vertex_distance(self, a: Vertex, b: Vertex) -> float:
        return float(self._dist[self.vertex_index[a], self.vertex_index[b]])

    def geodesic_distance(self, p: NDArray[np.float64], q: NDArray[np.float64]) -> float:
        """Along-network distance (m) between the centreline points nearest to ``p`` and ``q``."""
        a, b = self.nearest(p), self.nearest(q)
        return self.distance_between(a, b)

    def distance_between(self, a: CentrelinePoint, b: CentrelinePoint) -> float:
        if a.piece is b.piece:
            return abs(a.s - b.s)
        best = np.inf
        ends_a = ((a.piece.v0, a.s), (a.piece.v1, a.piece.length - a.s))
        ends_b = ((b.piece.v0, b.s), (b.piece.v1, b.piece.length - b.s))
        for va, da in ends_a:
            ia = self.vertex_index[va]
            for vb, db in ends_b:
                best = min(best, da + float(self._dist[ia, self.vertex_index[vb]]) + db)
        return float(best)

    def path_between(self, p: NDArray[np.float64], q: NDArray[np.float64]) -> CentrelinePath:
        """Shortest centreline path from the point nearest ``p`` to the point nearest ``q``."""
        a, b = self.nearest(p), self.nearest(q)
        if a.piece is b.piece:
            return CentrelinePath([(a.piece, a.s, b.s)])
        best: tuple[float, Vertex, Vertex] | None = None
        for va, da in ((a.piece.v0, a.s), (a.piece.v1, a.piece.length - a.s)):
            for vb, db in ((b.piece.v0, b.s), (b.piece.v1, b.piece.length - b.s)):
                total = da + self.vertex_distance(va, vb) + db
                if best is None or total < best[0]:
                    best = (total, va, vb)
        assert best is not None
        _, va, vb = best
        segments: list[tuple[Piece, float, float]] = [
            (a.piece, a.s, 0.0 if va == a.piece.v0 else a.piece.length)
        ]
        for piece, forward in self._vertex_path(va, vb):
            segments.append((piece, 0.0, piece.length) if forward else (piece, piece.length, 0.0))
        segments.append((b.piece, 0.0 if vb == b.piece.v0 else b.piece.length, b.s))
        return CentrelinePath([seg for seg in segments if abs(seg[1] - seg[2]) > 1e-12])

    def _vertex_path(self, va: Vertex, vb: Vertex) -> list[tuple[Piece, bool]]:
        ia, ib = self.vertex_index[va], self.vertex_index[vb]
        inv = {i: v for v, i in self.vertex_index.items()}
        chain = [ib]
        while chain[-1] != ia:
            prev = int(self._pred[ia, chain[-1]])
            if prev < 0:
                raise ValueError(f"no centreline path between {va} and {vb}")
            chain.append(prev)
        chain.reverse()
        out: list[tuple[Piece, bool]] = []
        for i, j in zip(chain[:-1], chain[1:]):
            vi, vj = inv[i], inv[j]
            cands = [pc for pc in self.pieces if {pc.v0, pc.v1} == {vi, vj}]
            piece = min(cands, key=lambda pc: pc.length)
            out.append((piece, piece.v0 == vi))
        return out


class CentrelinePath:
    """A walk along the centreline: a list of ``(piece, s_from, s_to)`` segments."""

    def __init__(self, segments: list[tuple[Piece, float, float]]) -> None:
        self.segments = segments
        self.lengths = np.array([abs(b - a) for _, a, b in segments])
        self.cumulative = np.concatenate([[0.0], np.cumsum(self.lengths)])
        self._starts = [float(c) for c in self.cumulative[:-1]]
        self._length = float(self.cumulative[-1])

    @property
    def length(self) -> float:
        return self._length

    def _locate(self, s: float) -> tuple[Piece, float, bool]:
        """(piece, arc length on the piece, walking the piece forwards) at path length ``s``."""
        s = clamp(s, 0.0, self._length)
        k = max(bisect_right(self._starts, s) - 1, 0)
        piece, a, b = self.segments[k]
        forwards = b >= a
        offset = s - self._starts[k]
        return piece, (a + offset if forwards else a - offset), forwards

    def point_tangent(self, s: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Point and travel-direction tangent at arc length ``s`` (m) along the path."""
        piece, local, forwards = self._locate(s)
        p, t = piece.point_tangent(local)
        return p, t if forwards else -t

    def diameter_at(self, s: float) -> float:
        """Inner diameter (m) at arc length ``s`` along the path."""
        piece, local, _ = self._locate(s)
        return piece.diameter_at(local)

    def pose_at(self, s: float, up_hint: NDArray | None = None) -> Pose:
        """Pose on the path at arc length ``s``: x along the travel direction, roll zero."""
        p, t = self.point_tangent(s)
        return Pose.trusted(p, frame_from_forward(t, up_hint))
