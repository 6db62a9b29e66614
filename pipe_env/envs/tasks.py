"""What an episode is for: the goal and coverage tasks (dm_control's ``Task``).

A task owns the part of an environment that differs between PipeNav and PipeExplore: what the
plant drives towards, the task's reward terms, when it ends an episode with success, and its
metrics in ``info``. The environment (:mod:`pipe_env.envs.env`) owns the decision loop and calls
the task at fixed points:

| call | when |
|---|---|
| :meth:`Task.initialize_episode` | after the plant's reset, before the first drive |
| :meth:`Task.after_drive` | after every drive to the next decision (True: the task is done) |
| :meth:`Task.sync` | after reset's drive to the first decision (the reward baseline) |
| :meth:`Task.record` | for every outcome of a drive or an action (its driven path) |
| :meth:`Task.reward_terms` | at the end of every executed (not masked) action |
| :meth:`Task.info` | for every ``info`` dict |

:class:`GoalTask` (PipeNav): reach the network's first goal; reward ``progress`` (decrease of
the along-network distance to the goal, m) and ``goal`` (the bonus on reaching it).
:class:`CoverageTask` (PipeExplore): see as much of the reachable pipe as possible; reward
``coverage`` (new pipe length covered by the scans, m); done when the covered fraction reaches
``coverage_done``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pipe_env.envs.plant import EdgeState, Plant, PlantOutcome, PlantStatus, goal_edge_position
from pipe_env.network import PipeNetwork
from pipe_env.robot_limits import MAX_TURN
from pipe_env.routing import (
    EdgePosition,
    edge_geodesic,
    edge_length,
    edge_position,
    locate,
    route,
    turn_angle,
)


class Task:
    """The base task: no goal, no reward terms, never done (see the module docstring)."""

    def initialize_episode(self, network: PipeNetwork, plant: Plant) -> None:
        """Set up the episode on ``network`` with the plant at its start."""

    def sync(self, plant: Plant) -> None:
        """Take the reward baseline (after reset's drive to the first decision)."""

    def after_drive(self, plant: Plant) -> bool:
        """Update after a drive to the next decision; True when the task is done (success)."""
        return False

    def record(self, outcome: PlantOutcome) -> None:
        """Account for an outcome's driven path."""

    def reward_terms(self, plant: Plant, success: bool) -> dict[str, float]:
        """The task's reward terms of an executed action (``success``: goal reached)."""
        return {}

    def info(self) -> dict[str, Any]:
        """The task's metrics for ``info``."""
        return {}

    @property
    def goal_point(self) -> NDArray[np.float64] | None:
        """The goal in the world frame (m), None without one."""
        return None

    @property
    def target(self) -> Any:
        """What the plant drives towards (the goal's edge position), None without a goal."""
        return None


class GoalTask(Task):
    """Reach the network's first goal (PipeNav).

    Args:
        reward_goal: the bonus on reaching the goal.
    """

    def __init__(self, reward_goal: float) -> None:
        self.reward_goal = reward_goal
        self.network: PipeNetwork | None = None
        self.goal: NDArray[np.float64] | None = None
        self.goal_edge: EdgePosition | None = None
        #: length of the shortest route from the start to the goal, m (nan: none)
        self.shortest_route = math.nan
        self._last_distance = math.nan

    def initialize_episode(self, network: PipeNetwork, plant: Plant) -> None:
        if not network.goals:
            raise ValueError("PipeNav needs a network with at least one goal")
        self.network = network
        self.goal = np.asarray(network.goals[0], dtype=float)
        self.goal_edge = goal_edge_position(network, self.goal)
        start = network.start_pose
        assert start is not None
        r = route(network, start, self.goal)
        self.shortest_route = float(r.length) if r is not None else float("nan")
        self._last_distance = self.distance(plant)

    def distance(self, plant: Plant) -> float:
        """The along-network distance from the robot to the goal, m."""
        assert self.network is not None and self.goal_edge is not None
        return edge_geodesic(self.network, plant.edge_position(), self.goal_edge)

    def sync(self, plant: Plant) -> None:
        self._last_distance = self.distance(plant)

    def reward_terms(self, plant: Plant, success: bool) -> dict[str, float]:
        now = self.distance(plant)
        terms = {"progress": float(self._last_distance - now)}
        self._last_distance = now
        if success:
            terms["goal"] = self.reward_goal
        return terms

    def info(self) -> dict[str, Any]:
        return {
            "shortest_route": self.shortest_route,
            "distance_to_goal": float(self._last_distance),
        }

    @property
    def goal_point(self) -> NDArray[np.float64] | None:
        return self.goal

    @property
    def target(self) -> Any:
        return self.goal_edge


class CoverageTask(Task):
    """Inspect as much of the reachable pipe as possible (PipeExplore).

    Args:
        coverage_done: covered fraction of the reachable pipe that ends the episode with
            success, in (0, 1].
        branch_view: how far the scans see into each pipe leaving the fitting ahead, m.
    """

    def __init__(self, coverage_done: float, branch_view: float) -> None:
        self.coverage_done = coverage_done
        self.branch_view = branch_view
        self.network: PipeNetwork | None = None
        #: covered spans (m along the run) per run id
        self.covered: dict[str, list[tuple[float, float]]] = {}
        #: centreline length of the runs the robot can reach (m) and their ids
        self.reachable_length = math.nan
        self.reachable_runs: set[str] = set()
        self.covered_total = 0.0
        self._last_cover = 0.0

    def initialize_episode(self, network: PipeNetwork, plant: Plant) -> None:
        self.network = network
        self.covered = {}
        self.reachable_length, self.reachable_runs = reachable_runs(network)
        self.covered_total = 0.0
        # the robot was put in through the pipe behind it: that part counts as inspected
        st = plant.state
        r = network.run_by_id[st.run_id]
        behind = 0.0 if st.towards == r.b else edge_length(network, r.id)
        self._cover(r.id, min(st.s, behind), max(st.s, behind))
        self._cover_from_here(plant)

    def sync(self, plant: Plant) -> None:
        self._last_cover = self.covered_total

    def after_drive(self, plant: Plant) -> bool:
        self._cover_from_here(plant)
        return self.covered_total >= self.coverage_done * self.reachable_length

    def reward_terms(self, plant: Plant, success: bool) -> dict[str, float]:
        new = self.covered_total - self._last_cover
        self._last_cover = self.covered_total
        return {"coverage": float(new)}

    def info(self) -> dict[str, Any]:
        total = self.reachable_length
        covered = float(self.covered_total)
        return {"covered": covered, "coverage": covered / total if total else 0.0}

    def _cover_from_here(self, plant: Plant) -> None:
        """The scans see the pipe between the robot and the fitting ahead, and a short way
        (``branch_view`` m) into each pipe leaving that fitting."""
        net = self.network
        assert net is not None
        st = plant.state
        r = net.run_by_id[st.run_id]
        end = edge_length(net, r.id) if st.towards == r.b else 0.0
        self._cover(r.id, min(st.s, end), max(st.s, end))
        for other in net.runs_at[st.towards]:
            if other.id == r.id:
                continue
            length = edge_length(net, other.id)
            view = min(self.branch_view, length)
            if other.a == st.towards:
                self._cover(other.id, 0.0, view)
            else:
                self._cover(other.id, length - view, length)

    def record(self, outcome: PlantOutcome) -> None:
        if outcome.status == PlantStatus.BACK_OUT:
            return  # reversing over pipe already seen
        net = self.network
        assert net is not None
        # (the kinematic plant's path holds edge states; the physical plant's, sensor
        # positions along the driven path, m)
        waypoints = [
            w if isinstance(w, EdgeState) else edge_position(net, net.centreline.nearest(w))
            for w in outcome.path
        ]
        for a, b in zip(waypoints[:-1], waypoints[1:]):
            if a.run_id == b.run_id:
                self._cover(a.run_id, min(a.s, b.s), max(a.s, b.s))
            else:
                self._cover_crossing(a, b)

    def _cover_crossing(self, a: EdgeState | EdgePosition, b: EdgeState | EdgePosition) -> None:
        """A step from one run to another: through a fitting, to its centre on one run, from
        it on the next (not neighbouring runs: nothing known in between)."""
        net = self.network
        assert net is not None
        crossing = self._crossing(a, b)
        if crossing is None:
            return
        left, entered = crossing
        ra = net.run_by_id[a.run_id]
        end_a = edge_length(net, ra.id) if left == ra.b else 0.0
        self._cover(ra.id, min(a.s, end_a), max(a.s, end_a))
        rb = net.run_by_id[b.run_id]
        start_b = edge_length(net, rb.id) if entered == rb.b else 0.0
        self._cover(rb.id, min(b.s, start_b), max(b.s, start_b))

    def _crossing(
        self, a: EdgeState | EdgePosition, b: EdgeState | EdgePosition
    ) -> tuple[str, str] | None:
        """The fittings through which a path leaves ``a``'s run and enters ``b``'s: from the
        headings of edge states, else the fitting the two runs share (``None``: none)."""
        net = self.network
        assert net is not None
        ra, rb = net.run_by_id[a.run_id], net.run_by_id[b.run_id]
        if isinstance(a, EdgeState) and isinstance(b, EdgeState):
            return a.towards, (rb.a if b.towards == rb.b else rb.b)
        shared = [n for n in (ra.a, ra.b) if n in (rb.a, rb.b)]
        return (shared[0], shared[0]) if shared else None

    def _cover(self, run_id: str, a: float, b: float) -> None:
        spans = self.covered.setdefault(run_id, [])
        spans.append((a, b))
        spans.sort()
        merged: list[tuple[float, float]] = []
        for lo, hi in spans:
            if merged and lo <= merged[-1][1] + 1e-9:
                merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
            else:
                merged.append((lo, hi))
        self.covered[run_id] = merged
        self.covered_total = sum(
            hi - lo
            for run in sorted(self.covered)
            if run in self.reachable_runs
            for lo, hi in self.covered[run]
        )


def reachable_runs(network: PipeNetwork, max_turn: float = MAX_TURN) -> tuple[float, set[str]]:
    """Runs a forward-driving robot can reach from the start, and their centreline length (m)."""
    start = network.start_pose
    assert start is not None
    ep, towards = locate(network, start)
    seen_runs = {ep.run_id}
    frontier = [(towards, ep.run_id)]
    seen = set(frontier)
    while frontier:
        node, run_in = frontier.pop()
        for r in network.runs_at[node]:
            if r.id == run_in or turn_angle(network, node, run_in, r.id) > max_turn:
                continue
            state = (r.other(node), r.id)
            seen_runs.add(r.id)
            if state not in seen:
                seen.add(state)
                frontier.append(state)
    # summed in a fixed order: set order varies between processes (hash seeds)
    return float(sum(edge_length(network, r) for r in sorted(seen_runs))), seen_runs
