"""Derived geometry of one fitting: its ports, legs and bend parameters.

A fitting sits at a node of the network. Its geometry follows from the node position, the
directions to its neighbouring nodes and the diameters of the runs attached to it:

- each *port* is where a straight run meets the fitting; ``axis`` points outward from the node
  along the run, ``leg`` is the distance (m) from the node to the port plane;
- for bends and junctions the node is where the centrelines meet; for a reducer it is the middle
  of the taper; for a closure it is the inner face of the end wall.

Leg lengths are chosen so that each fitting's solid fits between its ports: a mitre needs
r*tan(theta/2) plus a stub, a long-radius bend its tangent length R*tan(theta/2), a junction the
extent of the cylinder intersection plus a stub.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

#: Fitting kinds and how many runs each joins.
FITTING_DEGREE: dict[str, int] = {
    "closure": 1,
    "reducer": 2,
    "bend": 2,
    "tee": 3,
    "wye": 3,
    "cross": 4,
}
JUNCTION_KINDS = ("tee", "wye", "cross")
BEND_STYLES = ("mitre", "long")
#: Straight stub of a fitting beyond its intersection region, as a fraction of its diameter.
STUB_FRACTION = 0.25
#: Angular tolerance for "collinear" and "perpendicular" port axes, radians.
AXIS_TOLERANCE = np.radians(0.5)


@dataclass(frozen=True, eq=False)
class Port:
    """Where a straight run meets a fitting.

    Attributes:
        run_id: the run attached here.
        axis: unit vector from the node outward along the run.
        diameter: inner diameter of the run, metres.
        leg: distance from the node to the port plane, metres.
        position: port centre in the world, metres.
    """

    run_id: str
    axis: NDArray[np.float64]
    diameter: float
    leg: float
    position: NDArray[np.float64]

    @property
    def radius(self) -> float:
        return 0.5 * self.diameter


@dataclass(frozen=True, eq=False)
class FittingGeometry:
    """Geometry of the fitting at one node (see module docstring). Lengths in metres."""

    node_id: str
    kind: str
    centre: NDArray[np.float64]
    ports: tuple[Port, ...]
    style: str | None = None
    bend_radius: float | None = None
    taper_length: float | None = None

    def port(self, run_id: str) -> Port:
        for p in self.ports:
            if p.run_id == run_id:
                return p
        raise KeyError(f"fitting {self.node_id!r} has no port for run {run_id!r}")

    @property
    def deflection(self) -> float:
        """Bend deflection angle, radians (0 for non-bends)."""
        if self.kind != "bend":
            return 0.0
        a, b = self.ports
        return float(np.pi - np.arccos(np.clip(a.axis @ b.axis, -1.0, 1.0)))

    def collinear_pairs(self) -> list[tuple[int, int]]:
        """Index pairs of ports whose axes are opposite (a straight way through the node)."""
        pairs = []
        for i in range(len(self.ports)):
            for j in range(i + 1, len(self.ports)):
                if self.ports[i].axis @ self.ports[j].axis < -np.cos(AXIS_TOLERANCE):
                    pairs.append((i, j))
        return pairs

    def reference_point(self, entry_run: str) -> NDArray[np.float64]:
        """Reference point of this structure for a robot arriving through ``entry_run``.

        The end wall (closure), the start of the taper on the arrival side (reducer), else the
        node where the centrelines meet.
        """
        if self.kind == "reducer":
            p = self.port(entry_run)
            return p.position.copy()
        return self.centre.copy()

    def bend_arc(self) -> tuple[NDArray[np.float64], NDArray[np.float64], float, float]:
        """For a long-radius bend: (arc centre, unit normal of the bend plane, radius, angle).

        The arc runs from the first port to the second, turning about ``normal`` by ``angle``.
        """
        if self.kind != "bend" or self.style != "long":
            raise ValueError(f"fitting {self.node_id!r} is not a long-radius bend")
        a, b = self.ports
        t_in = -a.axis
        t_out = b.axis
        normal = np.cross(t_in, t_out)
        normal /= np.linalg.norm(normal)
        towards_centre = np.cross(normal, t_in)
        assert self.bend_radius is not None
        centre = a.position + towards_centre * self.bend_radius
        return centre, normal, float(self.bend_radius), self.deflection


def _junction_extent(axis_i: NDArray, r_i: float, others: list[tuple[NDArray, float]]) -> float:
    """Distance along ``axis_i`` within which other tubes of the junction intersect tube i."""
    extent = 0.0
    for axis_j, r_j in others:
        c = float(np.clip(axis_i @ axis_j, -1.0, 1.0))
        if c < -np.cos(AXIS_TOLERANCE):  # collinear partner: no intersection along the axis
            continue
        s = np.sqrt(max(1.0 - c * c, 1e-12))
        extent = max(extent, r_j / s + r_i * abs(c) / s)
    return extent


def build_fitting(
    node_id: str,
    kind: str,
    centre: NDArray[np.float64],
    ports: list[tuple[str, NDArray[np.float64], float]],
    style: str | None = None,
    bend_radius: float | None = None,
    taper_length: float | None = None,
) -> FittingGeometry:
    """Fitting geometry from the node position and its ports ``(run_id, outward axis, diameter)``.

    Assumes the node was validated for its degree; angles are not checked here.
    """
    legs: list[float] = []
    if kind == "closure":
        legs = [STUB_FRACTION * ports[0][2]]
    elif kind == "reducer":
        half = 0.5 * float(taper_length or 0.0)
        legs = [half, half]
    elif kind == "bend":
        (_, a0, d0), (_, a1, _d1) = ports
        theta = np.pi - np.arccos(np.clip(a0 @ a1, -1.0, 1.0))
        half_tan = float(np.tan(theta / 2.0))
        if style == "long":
            legs = [float(bend_radius or 0.0) * half_tan] * 2
        else:
            r = 0.5 * d0
            legs = [r * half_tan + STUB_FRACTION * d0] * 2
    elif kind in JUNCTION_KINDS:
        for i, (_, ai, di) in enumerate(ports):
            others = [(aj, 0.5 * dj) for j, (_, aj, dj) in enumerate(ports) if j != i]
            legs.append(_junction_extent(ai, 0.5 * di, others) + STUB_FRACTION * di)
    else:
        raise ValueError(f"unknown fitting kind {kind!r} at node {node_id!r}")
    built = tuple(
        Port(run_id, axis, float(d), float(leg), centre + axis * leg)
        for (run_id, axis, d), leg in zip(ports, legs)
    )
    return FittingGeometry(node_id, kind, centre, built, style, bend_radius, taper_length)
