"""Watertight CSG meshes (manifold3d) of each run and fitting, the surfaces LiDAR rays hit.

Each piece is a solid shell: the union of its outer solids minus the union of its inner (bore)
solids, so junctions get clean holes and no zero-thickness membranes. Inner solids reach a little
past the ports so the shells are open there; each run's shell reaches ``OVERLAP`` past its ports
into the neighbouring fittings so that no ray can slip through a seam plane.

Facets: a circle of radius r is a polygon of n sides whose vertices sit at
r * 2 / (1 + cos(pi / n)), so the faceted wall deviates from the true one by at most
+-``TESSELLATION_TOL`` (the error is split evenly inside and outside, not all inside).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import manifold3d as m3
import numpy as np
from numpy.typing import NDArray

from detector.geometry import frame_from_forward
from pipe_env.fittings import FittingGeometry

#: Shell thickness of the ray meshes, metres (only the inner surface matters for rays).
WALL = 0.004
#: How far a run's shell reaches past its ports into the fittings, metres.
OVERLAP = 0.001
#: Largest radial deviation of a faceted wall from the true surface, metres.
TESSELLATION_TOL = 1.0e-4
_PIERCE = WALL + 0.003  # inner solids reach this far past a port
_SEAM = 1.0e-4  # overlap of the two halves of a mitre across their cut plane


@dataclass(frozen=True, eq=False)
class TriangleMesh:
    """A named triangle mesh: (V, 3) vertices in metres (world frame) and (F, 3) faces."""

    name: str
    vertices: NDArray[np.float64]
    faces: NDArray[np.int32]


def circle_segments(radius: float, tol: float = TESSELLATION_TOL) -> int:
    """Polygon sides so a circle of ``radius`` (m) is within +-``tol`` (m) of the true circle.

    Always odd: a regular polygon with an odd number of sides has no diagonal through its
    centre, so a ray along a pipe axis never meets an end wall exactly on a triangle edge
    (where ray-triangle tests may miss it).
    """
    # vertices at r k with k = 2 / (1 + cos(pi/n)) deviate by r (1 - cos(pi/n)) / (1 + cos(pi/n))
    # both ways; that is tol when cos(pi/n) = (r - tol) / (r + tol)
    r = max(radius, 1e-6)
    c = (r - tol) / (r + tol)
    n = math.ceil(math.pi / math.acos(max(min(c, 1.0 - 1e-12), -1.0)))
    n = int(min(max(n, 25), 161))
    return n if n % 2 else n + 1


def polygon_radius(radius: float, n: int) -> float:
    """Vertex radius of an n-gon whose facets straddle the true circle of ``radius`` evenly."""
    return 2.0 * radius / (1.0 + math.cos(math.pi / n))


def _placement(origin: NDArray, axis: NDArray, phase: float = 0.0) -> NDArray[np.float64]:
    """3x4 transform taking local +z to ``axis``, the local origin to ``origin``, and local +x to
    the roll-zero left axis turned by ``phase`` radians about ``axis``."""
    frame = frame_from_forward(axis)
    c, s = math.cos(phase), math.sin(phase)
    u = c * frame[:, 1] + s * frame[:, 2]
    v = -s * frame[:, 1] + c * frame[:, 2]
    rot = np.column_stack([u, v, frame[:, 0]])
    return np.column_stack([rot, origin])


def _tube(
    p0: NDArray, p1: NDArray, r0: float, r1: float, n: int, ext0: float = 0.0, ext1: float = 0.0
) -> m3.Manifold:
    """Solid cone/cylinder from p0 (radius r0) to p1 (radius r1), continued (radius extrapolated
    linearly) ``ext0``/``ext1`` metres beyond its ends.

    Built with ``Manifold.cylinder``, whose end caps have no vertex on the axis; the vertices
    are turned by 0.3 of a facet so that no triangle edge lies in a horizontal or vertical plane
    through the axis (the planes of symmetric scans) where ray-triangle tests can miss exactly.
    """
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    axis = axis / length
    k = polygon_radius(1.0, n)
    slope = (r1 - r0) / length
    lo, hi = r0 - slope * ext0, r1 + slope * ext1
    solid = m3.Manifold.cylinder(length + ext0 + ext1, lo * k, hi * k, n)
    start = p0 - axis * ext0
    return solid.transform(_placement(start, axis, 0.3 * 2.0 * math.pi / n))


def _shell(outer: list[m3.Manifold], inner: list[m3.Manifold]) -> m3.Manifold:
    o = m3.Manifold.batch_boolean(outer, m3.OpType.Add) if len(outer) > 1 else outer[0]
    i = m3.Manifold.batch_boolean(inner, m3.OpType.Add) if len(inner) > 1 else inner[0]
    return o - i


def run_shell(p0: NDArray, p1: NDArray, diameter: float) -> m3.Manifold:
    """Shell of a straight run between port centres p0 and p1 (m), overlapping past both."""
    r = 0.5 * diameter
    n = circle_segments(r)
    outer = _tube(p0, p1, r + WALL, r + WALL, n, OVERLAP, OVERLAP)
    inner = _tube(p0, p1, r, r, n, _PIERCE, _PIERCE)
    return outer - inner


def fitting_shell(g: FittingGeometry) -> m3.Manifold:
    """Shell of one fitting from its derived geometry (see :mod:`pipe_env.fittings`)."""
    if g.kind == "closure":
        p = g.ports[0]
        n = circle_segments(p.radius)
        outer = _tube(g.centre - p.axis * WALL, p.position, p.radius + WALL, p.radius + WALL, n)
        inner = _tube(g.centre, p.position, p.radius, p.radius, n, 0.0, _PIERCE)
        return outer - inner
    if g.kind == "reducer":
        a, b = g.ports
        n = circle_segments(max(a.radius, b.radius))
        outer = _tube(a.position, b.position, a.radius + WALL, b.radius + WALL, n)
        inner = _tube(a.position, b.position, a.radius, b.radius, n, _PIERCE, _PIERCE)
        return outer - inner
    if g.kind == "bend" and g.style == "long":
        return _long_bend_shell(g)
    if g.kind == "bend":
        return _mitre_shell(g)
    return _junction_shell(g)


def _mitre_shell(g: FittingGeometry) -> m3.Manifold:
    a, b = g.ports
    n = circle_segments(a.radius)
    half = 0.5 * g.deflection
    reach = (a.radius + WALL) * math.tan(half) + 0.01  # past the centre, to be trimmed
    outer, inner = [], []
    for p, q in ((a, b), (b, a)):
        normal = p.axis - q.axis
        normal = normal / np.linalg.norm(normal)
        # each half reaches _SEAM past the cut plane: coplanar halves would leave a membrane
        offset = float(normal @ g.centre) - _SEAM
        far = g.centre - p.axis * reach
        outer.append(
            _tube(far, p.position, p.radius + WALL, p.radius + WALL, n).trim_by_plane(
                normal.tolist(), offset
            )
        )
        inner.append(
            _tube(far, p.position, p.radius, p.radius, n, 0.0, _PIERCE).trim_by_plane(
                normal.tolist(), offset
            )
        )
    return _shell(outer, inner)


def _long_bend_shell(g: FittingGeometry) -> m3.Manifold:
    a, _ = g.ports
    centre, normal, radius, angle = g.bend_arc()
    n = circle_segments(a.radius)
    k = polygon_radius(1.0, n)
    sweep_tol = TESSELLATION_TOL
    outer_r = radius + a.radius + WALL
    step = 2.0 * math.acos(max(1.0 - sweep_tol / outer_r, -1.0))
    segments = int(min(max(math.ceil(2 * math.pi / step), 64), 2048))

    def ring(r_tube: float) -> m3.CrossSection:
        return m3.CrossSection.circle(r_tube, n).translate((radius, 0.0))

    annulus = ring(a.radius + WALL) - ring(a.radius * k)
    shell = m3.Manifold.revolve(annulus, segments, math.degrees(angle))
    u0 = (a.position - centre) / radius
    t_in = np.cross(normal, u0)
    rot = np.column_stack([u0, t_in, normal])
    return shell.transform(np.column_stack([rot, centre]))


def _junction_shell(g: FittingGeometry) -> m3.Manifold:
    # A run through the junction is one tube from port to port: two tubes meeting at the centre
    # would leave coplanar discs there, which CSG turns into a membrane across the bore.
    outer, inner = [], []
    pairs = g.collinear_pairs()
    paired = {i for pair in pairs for i in pair}
    spans = [(g.ports[i].position, g.ports[j].position, g.ports[i].radius) for i, j in pairs]
    spans += [(g.centre, p.position, p.radius) for i, p in enumerate(g.ports) if i not in paired]
    for start, end, r in spans:
        n = circle_segments(r)
        ext0 = _PIERCE if start is not g.centre else 0.0
        outer.append(_tube(start, end, r + WALL, r + WALL, n))
        inner.append(_tube(start, end, r, r, n, ext0, _PIERCE))
    return _shell(outer, inner)


def to_triangle_mesh(name: str, solid: m3.Manifold) -> TriangleMesh:
    """Vertices and faces of a manifold solid; raises if the CSG produced nothing."""
    if solid.is_empty():
        raise ValueError(f"mesh {name!r}: the CSG result is empty")
    mesh = solid.to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=float)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int32)
    return TriangleMesh(name, verts, faces)
