"""Ground truth: the structure ahead of a pose and its options, as docs/design.md defines them.

For a pose on or near a centreline, the fitting ahead is the one the pose is heading towards
along its run. Its options (one per way on) carry the distance along the incoming pipe axis from
the pose origin to the reference point, the outgoing diameter, the deflection angle and the roll
direction of the outgoing axis measured in the pose's frame (atan2(z, y), 0 = left, pi/2 = up).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from detector.geometry import Pose, clamp, norm3
from detector.options import StructureOption, option_order
from pipe_env.routing import locate

if TYPE_CHECKING:
    from pipe_env.network import PipeNetwork

#: Option kind reported for each fitting kind.
OPTION_KIND = {
    "closure": "closure",
    "reducer": "reducer",
    "bend": "bend",
    "tee": "junction",
    "wye": "junction",
    "cross": "junction",
}


def option_angles(
    incoming: NDArray[np.float64], outgoing: NDArray[np.float64], pose: Pose
) -> tuple[float, float]:
    """(angle, direction) of ``outgoing`` relative to the ``incoming`` axis, in ``pose``'s frame.

    The roll direction uses the part of ``outgoing`` perpendicular to the incoming axis,
    expressed in the pose's y (left) and z (up) axes; it is 0 for a way straight on.
    """
    t = incoming / norm3(incoming)
    o = outgoing / norm3(outgoing)
    angle = math.acos(clamp(float(t @ o), -1.0, 1.0))
    perp = o - (o @ t) * t
    if norm3(perp) < 1e-9:
        return angle, 0.0
    return angle, math.atan2(float(perp @ pose.up), float(perp @ pose.left))


def fitting_ahead(network: PipeNetwork, pose: Pose) -> tuple[str, str]:
    """(fitting id, entry run id) of the fitting ``pose`` is heading towards."""
    ep, towards = locate(network, pose)
    return towards, ep.run_id


def ways_at(
    network: PipeNetwork, node_id: str, entry_run: str, pose: Pose
) -> list[tuple[StructureOption, str]]:
    """Each way on at fitting ``node_id`` for a robot arriving by ``entry_run``, seen from
    ``pose``: its option and the run it leads into, in the fitting's port order. A closure has
    one option with diameter 0 and no run (``""``)."""
    g = network.geometry[node_id]
    travel = -g.port(entry_run).axis
    ref = g.reference_point(entry_run)
    distance = float((ref - pose.position) @ travel)
    kind = OPTION_KIND[g.kind]
    if g.kind == "closure":
        return [(StructureOption("closure", distance, 0.0, 0.0, 0.0), "")]
    bend_radius = float(g.bend_radius or 0.0) if g.kind == "bend" and g.style == "long" else 0.0
    ways = []
    for p in g.ports:
        if p.run_id == entry_run:
            continue
        angle, direction = option_angles(travel, p.axis, pose)
        option = StructureOption(
            kind, distance, p.diameter, direction, angle, bend_radius=bend_radius
        )
        ways.append((option, p.run_id))
    return ways


def options_at(
    network: PipeNetwork, node_id: str, entry_run: str, pose: Pose
) -> list[StructureOption]:
    """The options of fitting ``node_id`` for a robot arriving by ``entry_run``, seen from ``pose``.

    Sorted straight-on first, then by direction. One option per way on; a closure has one
    option with diameter 0.
    """
    return sorted((o for o, _ in ways_at(network, node_id, entry_run, pose)), key=option_order)


def structures_ahead(
    network: PipeNetwork, pose: Pose, max_distance: float = 2.0
) -> list[StructureOption]:
    """Options of the nearest structure ahead of ``pose`` within ``max_distance`` metres.

    Empty when the reference point of the fitting ahead is farther than ``max_distance``.
    """
    if not (math.isfinite(max_distance) and max_distance > 0.0):
        raise ValueError(f"max_distance must be a positive finite length (m), got {max_distance}")
    node_id, entry_run = fitting_ahead(network, pose)
    options = options_at(network, node_id, entry_run, pose)
    if not options or options[0].distance > max_distance:
        return []
    return options
