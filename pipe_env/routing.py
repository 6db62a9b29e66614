"""Routes a forward-driving robot can take through a network.

The robot drives forward (sensor first) and can deflect by at most ``max_turn`` at a fitting
(90 deg for the PIRATE: a wye entered from its branch offers 45 and 135 deg, only the first is
drivable). A route is found by Dijkstra over directed run traversals: the state is "arrived at
fitting n through run r". Distances are along the centreline, metres.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from detector.geometry import clamp
from pipe_env.robot_limits import MAX_TURN

if TYPE_CHECKING:
    from detector.geometry import Pose
    from pipe_env.centreline import CentrelinePath, CentrelinePoint
    from pipe_env.network import PipeNetwork


@dataclass(frozen=True)
class EdgePosition:
    """A point on a run's edge: ``s`` metres along the centreline from fitting ``run.a``."""

    run_id: str
    s: float
    length: float


@dataclass(frozen=True)
class Route:
    """A drivable route: the fittings passed and the run taken out of each, and its length (m)."""

    nodes: tuple[str, ...]
    runs: tuple[str, ...]
    length: float


def leg_length(network: PipeNetwork, node_id: str, run_id: str) -> float:
    """Centreline length (m) from a fitting centre to its port (long bend: half its arc)."""
    g = network.geometry[node_id]
    if g.kind == "bend" and g.style == "long":
        _, _, radius, angle = g.bend_arc()
        return 0.5 * radius * angle
    return g.port(run_id).leg


def _cache(network: PipeNetwork) -> dict:
    """Per-network memo of derived routing data (networks are immutable)."""
    return network.__dict__.setdefault("_routing_cache", {})


def edge_length(network: PipeNetwork, run_id: str) -> float:
    """Centreline length (m) between the two fittings of a run, fitting halves included."""
    lengths = _cache(network).get("edge_length")
    if lengths is None:
        lengths = {
            r.id: leg_length(network, r.a, r.id)
            + network.straight_length(r.id)
            + leg_length(network, r.b, r.id)
            for r in network.runs
        }
        _cache(network)["edge_length"] = lengths
    return lengths[run_id]


def node_distances(network: PipeNetwork) -> tuple[dict[str, int], NDArray[np.float64]]:
    """All-pairs along-network distances (m) between fitting centres, and the id -> row map."""
    cache = _cache(network)
    if "node_distances" not in cache:
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import shortest_path

        index = {f.id: i for i, f in enumerate(network.fittings)}
        rows = [index[r.a] for r in network.runs]
        cols = [index[r.b] for r in network.runs]
        w = [max(edge_length(network, r.id), 1e-12) for r in network.runs]
        graph = coo_matrix((w, (rows, cols)), shape=(len(index), len(index))).tocsr()
        cache["node_distances"] = (index, shortest_path(graph, directed=False))
    return cache["node_distances"]


def edge_geodesic(network: PipeNetwork, a: EdgePosition, b: EdgePosition) -> float:
    """Along-network distance (m) between two edge positions (no turn constraint)."""
    if a.run_id == b.run_id:
        return abs(a.s - b.s)
    index, dist = node_distances(network)
    ra, rb = network.run_by_id[a.run_id], network.run_by_id[b.run_id]
    best = math.inf
    for na, da in ((ra.a, a.s), (ra.b, a.length - a.s)):
        for nb, db in ((rb.a, b.s), (rb.b, b.length - b.s)):
            best = min(best, da + float(dist[index[na], index[nb]]) + db)
    return best


def turn_angle(network: PipeNetwork, node_id: str, run_in: str, run_out: str) -> float:
    """Deflection (rad) when entering ``node_id`` by ``run_in`` and leaving by ``run_out``."""
    g = network.geometry[node_id]
    a, b = g.port(run_in).axis, g.port(run_out).axis
    return float(math.pi - math.acos(clamp(float(a @ b), -1.0, 1.0)))


def edge_position(network: PipeNetwork, cp: CentrelinePoint) -> EdgePosition:
    """Where a centreline point lies on its run's edge (see :class:`EdgePosition`)."""
    piece = cp.piece
    if piece.run_id is None:  # inside a long bend: attribute to the nearer port's run
        node = piece.node_id
        assert node is not None
        half = 0.5 * piece.length
        run_id = piece.v0[2] if cp.s <= half else piece.v1[2]
        # the edge starts at the arc's midpoint (see edge_path) and runs out to the port
        from_node = abs(cp.s - half)
        r = network.run_by_id[run_id]
        total = edge_length(network, run_id)
        return EdgePosition(run_id, from_node if node == r.a else total - from_node, total)
    r = network.run_by_id[piece.run_id]
    total = edge_length(network, r.id)
    if piece.node_id is None:  # the run's straight pipe, from r.a's port
        s = leg_length(network, r.a, r.id) + cp.s
    elif piece.node_id == r.a:  # leg from a's centre
        s = cp.s
    else:
        s = total - cp.s
    return EdgePosition(r.id, s, total)


def locate(network: PipeNetwork, pose: Pose) -> tuple[EdgePosition, str]:
    """Edge position of ``pose`` and the fitting it is heading towards."""
    cp = network.centreline.nearest(pose.position)
    ep = edge_position(network, cp)
    r = network.run_by_id[ep.run_id]
    axis = network.position(r.b) - network.position(r.a)
    towards = r.b if float(pose.forward @ axis) >= 0.0 else r.a
    return ep, towards


def route(
    network: PipeNetwork,
    pose: Pose,
    goal: ArrayLike,
    max_turn: float = MAX_TURN,
    diameter_range: tuple[float, float] | None = None,
) -> Route | None:
    """Shortest drivable route from ``pose`` (driving forward) to the point nearest ``goal``.

    Returns None when the goal cannot be reached without a deflection above ``max_turn`` or,
    with ``diameter_range`` (m), without entering a pipe outside it (the robot's clamping
    range; default: the network's own range, i.e. no restriction).
    """
    start, towards = locate(network, pose)
    goal_pos = edge_position(network, network.centreline.nearest(np.asarray(goal, float)))
    return route_between(network, start, towards, goal_pos, max_turn, diameter_range)


def route_between(
    network: PipeNetwork,
    start: EdgePosition,
    towards: str,
    goal: EdgePosition,
    max_turn: float = MAX_TURN,
    diameter_range: tuple[float, float] | None = None,
) -> Route | None:
    """Dijkstra core of :func:`route` on edge positions."""
    lo, hi = diameter_range if diameter_range is not None else (0.0, math.inf)
    r0 = network.run_by_id[start.run_id]
    best_len = math.inf
    best: tuple[tuple[str, ...], tuple[str, ...]] | None = None
    if goal.run_id == start.run_id:
        ahead = goal.s - start.s if towards == r0.b else start.s - goal.s
        if ahead >= 0.0:
            best_len, best = ahead, ((), (start.run_id,))
    first = start.length - start.s if towards == r0.b else start.s
    heap: list[tuple[float, int, str, str, tuple[str, ...], tuple[str, ...]]] = [
        (first, 0, towards, start.run_id, (), (start.run_id,))
    ]
    settled: set[tuple[str, str]] = set()
    counter = 1
    while heap:
        cost, _, node, run_in, nodes, runs = heapq.heappop(heap)
        if cost >= best_len or (node, run_in) in settled:
            continue
        settled.add((node, run_in))
        for run_out in network.runs_at[node]:
            if run_out.id == run_in:
                continue
            if turn_angle(network, node, run_in, run_out.id) > max_turn:
                continue
            if not lo <= run_out.diameter <= hi:
                continue
            if run_out.id == goal.run_id:
                extra = goal.s if node == run_out.a else goal.length - goal.s
                if cost + extra < best_len:
                    best_len = cost + extra
                    best = (nodes + (node,), runs + (run_out.id,))
            nxt = run_out.other(node)
            heapq.heappush(
                heap,
                (
                    cost + edge_length(network, run_out.id),
                    counter,
                    nxt,
                    run_out.id,
                    nodes + (node,),
                    runs + (run_out.id,),
                ),
            )
            counter += 1
    if best is None:
        return None
    return Route(best[0], best[1], float(best_len))


def edge_path(network: PipeNetwork, run_id: str) -> CentrelinePath:
    """The centreline of a run's edge from fitting ``run.a``'s centre to ``run.b``'s centre.

    A long-radius bend contributes half its arc at that end (its centre is off the
    centreline); other fittings contribute their straight leg.
    """
    from pipe_env.centreline import CentrelinePath

    cache = network.__dict__.setdefault("_edge_paths", {})
    if run_id in cache:
        return cache[run_id]
    r = network.run_by_id[run_id]
    cl = network.centreline
    segs = []
    for node, at_start in ((r.a, True), (r.b, False)):
        g = network.geometry[node]
        if g.kind == "bend" and g.style == "long":
            arc = next(p for p in cl.pieces if p.kind == "arc" and p.node_id == node)
            port_end = 0.0 if arc.v0 == ("p", node, run_id) else arc.length
            seg = (arc, 0.5 * arc.length, port_end)
        else:
            leg = next(p for p in cl.pieces if p.node_id == node and p.run_id == run_id)
            seg = (leg, 0.0, leg.length)
        segs.append(seg if at_start else (seg[0], seg[2], seg[1]))
    run_piece = next(p for p in cl.pieces if p.run_id == run_id and p.node_id is None)
    path = CentrelinePath([segs[0], (run_piece, 0.0, run_piece.length), segs[1]])
    cache[run_id] = path
    return path
