"""The plant behind the environments: where the robot is, how it moves, what it senses.

An environment step is a decision. The plant answers two calls:

- :meth:`Plant.advance`: drive forward (sensing) until a structure is confirmed within the
  trigger distance, or the goal is reached; returns a :class:`Decision` (or None at the goal);
- :meth:`Plant.execute`: carry out the chosen action at the current decision: take one of the
  detected ways on, or back out to the last junction; returns an :class:`PlantOutcome`.

Both fidelities implement the typed :class:`Plant` protocol (the environment holds a
``Plant``; only its factory knows which). :class:`KinematicPlant` (``fidelity="fast"``, this
module) moves the robot along the centreline graph and senses by perturbing the true options
with a detector's measured error model (:mod:`pipe_env.envs.sensing_model`); whether a primitive
survives its option's errors follows the tolerances measured by the primitives' tolerance
study. It runs thousands of decisions per second for RL iterations. The full fidelity (MuJoCo
robot, rotating LiDAR, the detector and the primitives' executor) lives in
:mod:`pipe_env.envs.plant_full`.

Edge positions: the robot is on a run's edge at ``s`` metres (centreline) from fitting
``run.a``, heading towards fitting ``towards``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from detector.geometry import (
    Pose,
    clamp,
    frame_from_forward,
    norm3,
    wrap_angle,
)
from detector.options import StructureOption, arc_start, match_option, option_vector
from detector.scan import Scan
from detector.validation import check_number
from detector.vocab import DETECTORS, StrEnum
from pipe_env.envs.fidelity import Fidelity
from pipe_env.envs.sensing_model import DetectionErrorModel, error_model_for
from pipe_env.ground_truth import options_at
from pipe_env.network import PipeNetwork
from pipe_env.robot_limits import MAX_TURN, ROBOT_DIAMETER_RANGE, drivable
from pipe_env.routing import EdgePosition, edge_length, edge_path, edge_position, locate, turn_angle
from primitives.sequences import TURN_RADIUS_FACTOR

if TYPE_CHECKING:
    from pipe_env.world import PipeWorld

BACK_OUT = "back_out"

#: The full fidelity's drives to a structure that stall, per structure approached: 3 of 729
#: (``benchmarks/calibrate_fidelity.py --networks 200``, "drive jams per structure"; RoutePlanner
#: on the held-out 6-fitting 3D networks). The fast fidelity draws them at this rate.
DRIVE_JAM_RATE = 0.004


class PlantStatus(StrEnum):
    """How a plant's action or drive ended (:attr:`PlantOutcome.status`); not the executor's
    :class:`primitives.steps.SequenceStatus`, which the full plant maps onto these."""

    DONE = "done"
    JAMMED = "jammed"
    BLOCKED = "blocked"
    GOAL = "goal"
    BACK_OUT = "back_out"


@dataclass(frozen=True)
class ExecutionTolerance:
    """Largest option errors a turn primitive survives, measured by
    ``benchmarks/bench_primitives.py`` in full fidelity (90 deg mitre bends, the smallest over roll
    directions) at the diameters in ``diameters``; linear in the diameter between them and held
    beyond. Distances are fractions of the pipe diameter, angles radians.

    Attributes:
        diameters: where the tolerances were measured, metres.
        distance_early: the option's distance too short (the robot turns early).
        distance_late: the option's distance too long (it turns late).
        direction: roll direction error (weighted by sin(angle) when applied).
        angle_under: the option's deflection too small.
        angle_over: the option's deflection too large.
        match: largest angle between a chosen option's outgoing axis and the true way on for
            the option to be that way at all (else it is a phantom and the robot jams).
    """

    diameters: tuple[float, ...] = (0.060, 0.090, 0.120)
    distance_early: tuple[float, ...] = (0.19, 0.28, 0.28)
    distance_late: tuple[float, ...] = (0.19, 0.42, 0.52)
    direction: tuple[float, ...] = tuple(math.radians(a) for a in (14.1, 16.9, 19.7))
    angle_under: tuple[float, ...] = tuple(math.radians(a) for a in (18.7, 20.6, 20.6))
    angle_over: tuple[float, ...] = tuple(math.radians(a) for a in (9.4, 9.4, 9.4))
    match: float = math.radians(40.0)

    def at(self, diameter: float) -> dict[str, float]:
        """The tolerances in a pipe of ``diameter`` metres."""
        return dict(_tolerances_at(self, float(diameter)))


@lru_cache(maxsize=256)
def _tolerances_at(tol: ExecutionTolerance, diameter: float) -> tuple[tuple[str, float], ...]:
    """:meth:`ExecutionTolerance.at` memoised (a network has a handful of diameters)."""
    keys = ("distance_early", "distance_late", "direction", "angle_under", "angle_over")
    return tuple((k, float(np.interp(diameter, tol.diameters, getattr(tol, k)))) for k in keys)


@dataclass(frozen=True)
class EdgeState:
    """Where the robot is: ``s`` metres along run ``run_id``'s edge from ``run.a``."""

    run_id: str
    s: float
    towards: str


@dataclass
class Decision:
    """A decision point: the structure the robot stopped before and what it sensed.

    Attributes:
        options: detected ways on (sorted straight-on first, then by direction).
        kind: the detected kind of the structure.
        truth: ground-truth options of the structure at the same pose.
        node_id, entry_run: the true fitting ahead and the run the robot is in (diagnostics).
        pose: the true sensor pose when deciding.
    """

    options: list[StructureOption]
    kind: str
    truth: list[StructureOption]
    node_id: str
    entry_run: str
    pose: Pose

    @property
    def dead_end(self) -> bool:
        return self.kind == "closure" or not any(drivable(o) for o in self.options)


@dataclass
class PlantOutcome:
    """What an action or a drive did. Distances in metres, times in seconds."""

    status: PlantStatus = PlantStatus.DONE
    distance: float = 0.0
    sim_time: float = 0.0
    #: consecutive waypoints of the motion (see ``positions``)
    path: list[EdgeState | NDArray[np.float64]] = field(default_factory=list)
    note: str = ""


@runtime_checkable
class Plant(Protocol):
    """What an environment drives: one decision at a time (both fidelities).

    Attributes:
        fidelity: ``"fast"`` or ``"full"``.
        network: the network the plant simulates (a plant is built once per network and
            :meth:`reset` between episodes on it).
        decision: the pending decision (None after an executed action, before ``advance``).
        detection_log: one record per detection (:func:`detection_record`).
        travelled: distance driven since the reset, m.
        sim_time: simulated time since the reset, s.
        scan_image: low-resolution range image of the last sweep (full fidelity with
            ``scan_image=True``), else None.
        world: the MuJoCo world the robot moves in (full fidelity), else None.
        last_scan: the last LiDAR sweep (full fidelity, after one), else None.
    """

    fidelity: str
    network: PipeNetwork
    decision: Decision | None
    detection_log: list[dict]
    travelled: float
    sim_time: float
    scan_image: NDArray[np.float32] | None
    world: PipeWorld | None
    last_scan: Scan | None

    def reset(self, rng: np.random.Generator) -> None:
        """Put the robot at the network's start pose with fresh logs, drawing from ``rng``."""
        ...

    def advance(self, goal: Any = None) -> tuple[Decision | None, PlantOutcome]:
        """Drive to the next decision (None and status ``goal`` if the goal comes first)."""
        ...

    def execute(self, choice: StructureOption | str, goal: Any = None) -> PlantOutcome:
        """Carry out ``choice`` (an option of the pending decision, or ``BACK_OUT``)."""
        ...

    def resense(self) -> tuple[Decision, PlantOutcome]:
        """Sense again where the robot stands (after a jam)."""
        ...

    def pose(self) -> Pose:
        """The true sensor pose."""
        ...

    def odometry_pose(self) -> Pose:
        """The sensor pose the robot believes (odometry drift included)."""
        ...

    @property
    def clamped_diameter(self) -> float:
        """The clamp encoders' reading at the last decision, m."""
        ...

    @property
    def state(self) -> EdgeState:
        """Edge state (run, position, heading) of the true pose."""
        ...

    def edge_position(self) -> EdgePosition:
        """Edge position of the true pose."""
        ...

    def waypoint(self) -> Any:
        """The robot's current place as a path waypoint (see :meth:`positions`)."""
        ...

    def positions(self, waypoints: list[Any]) -> NDArray[np.float64]:
        """Waypoints as (N, 3) world positions, m."""
        ...

    def watch_motion(self, on_tick: Callable[[float], None] | None) -> float | None:
        """Call ``on_tick(simulated time, s)`` at every control tick of the motion from now on
        (None: stop); returns the current simulated time, or None for a plant without
        continuous motion (fast fidelity), which never calls it."""
        ...

    def body_positions(self) -> NDArray[np.float64] | None:
        """World positions of the robot's modules, (N, 3) m (full fidelity), else None."""
        ...

    def close(self) -> None:
        """Release what the plant holds."""
        ...


class KinematicPlant:
    """Fast fidelity: kinematic motion on the centreline and modelled sensing.

    Args:
        network: the network (with a start pose).
        detector: ``"ground_truth"``, ``"improved"`` or ``"thesis"`` (its error model).
        trigger_distance: stop this far before a structure's reference point, metres.
        tolerance: what a primitive survives.
        speed: driving speed for simulated time, m/s.
        decision_time: simulated seconds spent sensing and confirming per structure.
        odometry_noise: odometry drift, m/sqrt(m): every motion of ``d`` metres adds an
            independent N(0, (odometry_noise * sqrt(d))^2) error on each world axis (a random
            walk: the drift's std grows with the square root of the distance driven).
        jam_time: simulated seconds a jam costs (stall, detection of it, reversing).
        drive_jam_rate: probability that the drive to a structure stalls (the robot then
            decides where it stands, as the full fidelity does, after ``jam_time``); default
            :data:`DRIVE_JAM_RATE`, the full fidelity's own rate.
    """

    fidelity = Fidelity.FAST.value
    #: no sweeps and no MuJoCo world in the fast fidelity (the :class:`Plant` protocol's)
    scan_image: NDArray[np.float32] | None = None
    world: PipeWorld | None = None
    last_scan: Scan | None = None

    def __init__(
        self,
        network: PipeNetwork,
        detector: str = "improved",
        trigger_distance: float = 0.2,
        tolerance: ExecutionTolerance | None = None,
        speed: float = 0.05,
        decision_time: float = 12.0,
        odometry_noise: float = 0.01,
        error_model: DetectionErrorModel | None = None,
        jam_time: float = 10.0,
        drive_jam_rate: float = DRIVE_JAM_RATE,
    ) -> None:
        if network.start_pose is None:
            raise ValueError("the network has no start_pose; the robot needs one")
        if detector not in DETECTORS:
            raise ValueError(f"detector {detector!r} is unknown; allowed: {DETECTORS}")
        self.network = network
        self.detector = detector
        self.error_model = error_model or error_model_for(detector)
        self.trigger_distance = float(trigger_distance)
        self.tolerance = tolerance or ExecutionTolerance()
        self.speed = float(speed)
        self.decision_time = float(decision_time)
        self.odometry_noise = float(odometry_noise)
        self.jam_time = float(jam_time)
        self.drive_jam_rate = check_number(
            "drive_jam_rate", drive_jam_rate, low=0.0, high=1.0, where="KinematicPlant"
        )
        start = network.start_pose
        ep, towards = locate(network, start)
        self._start_state = EdgeState(ep.run_id, ep.s, towards)
        self.reset(np.random.default_rng(0))

    # ------------------------------------------------------------------ state
    def reset(self, rng: np.random.Generator) -> None:
        """Put the robot at the network's start pose."""
        self.rng = rng
        self._pose_memo: tuple[EdgeState, Pose] | None = None
        self.state = self._start_state
        #: junctions passed: (state at the decision, node id, index into ``forward_path``)
        self.junctions: list[tuple[EdgeState, str, int]] = []
        #: the forward drive since the start: waypoints and cumulative distance (m); backing
        #: out reverses along it
        self.forward_path: list[EdgeState] = [self.state]
        self.forward_odometer: list[float] = [0.0]
        #: one record per detection: true distance to the structure, estimate and truth
        self.detection_log: list[dict] = []
        self.decision: Decision | None = None
        self.odometry_error = np.zeros(3)
        self.travelled = 0.0
        self.sim_time = 0.0

    def pose(self) -> Pose:
        """True sensor pose: on the centreline, facing the travel direction, roll zero."""
        return self._pose_of(self.state)

    def _pose_of(self, st: EdgeState) -> Pose:
        cached = self._pose_memo
        if cached is not None and cached[0] == st:
            return cached[1]
        path = edge_path(self.network, st.run_id)
        p, t = path.point_tangent(st.s)
        r = self.network.run_by_id[st.run_id]
        pose = Pose.trusted(p, frame_from_forward(t if st.towards == r.b else -t))
        self._pose_memo = (st, pose)
        return pose

    def waypoint(self) -> EdgeState:
        """The robot's current place as a path waypoint."""
        return self.state

    def positions(self, waypoints: list[EdgeState]) -> NDArray[np.float64]:
        """World positions (N, 3) of edge-state waypoints, metres."""
        pts = [edge_path(self.network, w.run_id).point_tangent(w.s)[0] for w in waypoints]
        return np.array(pts).reshape(-1, 3)

    def edge_position(self) -> EdgePosition:
        """The robot's true position on its run's edge."""
        st = self.state
        return EdgePosition(st.run_id, st.s, edge_length(self.network, st.run_id))

    def odometry_pose(self) -> Pose:
        """The pose the robot believes: true pose plus accumulated odometry drift."""
        p = self.pose()
        return Pose.trusted(p.position + self.odometry_error, p.rotation)

    @property
    def clamped_diameter(self) -> float:
        """Inner diameter at the robot (m); exact in the fast fidelity."""
        return edge_path(self.network, self.state.run_id).diameter_at(self.state.s)

    def _ahead(self, st: EdgeState) -> float:
        """Centreline distance from ``st`` to the centre of the fitting ahead."""
        length = edge_length(self.network, st.run_id)
        r = self.network.run_by_id[st.run_id]
        return length - st.s if st.towards == r.b else st.s

    def _move(self, st: EdgeState, distance: float) -> EdgeState:
        r = self.network.run_by_id[st.run_id]
        s = st.s + distance if st.towards == r.b else st.s - distance
        return EdgeState(st.run_id, clamp(s, 0.0, edge_length(self.network, r.id)), st.towards)

    def _record_motion(
        self,
        distance: float,
        out: PlantOutcome,
        start: EdgeState,
        end: EdgeState,
        path: bool = True,
    ) -> None:
        d = abs(distance)
        self.travelled += d
        out.distance += d
        t = d / self.speed
        out.sim_time += t
        self.sim_time += t
        self.odometry_error = self.odometry_error + self.rng.normal(
            0.0, self.odometry_noise * math.sqrt(d) if d > 0 else 0.0, size=3
        )
        if path:
            out.path += [start, end]

    # ------------------------------------------------------------------ driving
    def advance(
        self, goal: NDArray[np.float64] | EdgePosition | None = None
    ) -> tuple[Decision | None, PlantOutcome]:
        """Drive forward to the next decision point, or to ``goal`` (a point, or its edge
        position) if it comes first."""
        out = PlantOutcome()
        st = self.state
        node = st.towards
        g = self.network.geometry[node]
        pose = self.pose()
        ref_distance = float(
            (g.reference_point(st.run_id) - pose.position) @ -g.port(st.run_id).axis
        )
        move = max(0.0, ref_distance - self.trigger_distance)
        if goal is not None:
            to_goal = self._goal_ahead(goal, st, move)
            if to_goal is not None:
                end = self._move(st, to_goal)
                self._record_motion(to_goal, out, st, end)
                self._forward(end, to_goal)
                self.state = end
                out.status = PlantStatus.GOAL
                return None, out
        end = self._move(st, move)
        self._record_motion(move, out, st, end)
        self._forward(end, move)
        self.state = end
        # (no draw at rate 0, nor for a robot already at its decision point: seeded episodes
        # without drive jams keep the draws they had before the model)
        if self.drive_jam_rate > 0.0 and move > 0.0 and self.rng.random() < self.drive_jam_rate:
            # stalled on the way (the full loop's drive jams: a module pushed off its path,
            # the front lagging its target): it costs the jam, and the robot senses where it
            # stands, here
            out.status = PlantStatus.JAMMED
            out.note = "jammed while driving (modelled, see DRIVE_JAM_RATE)"
            out.sim_time += self.jam_time
            self.sim_time += self.jam_time
        self.decision = self._sense(node, st.run_id, out)
        return self.decision, out

    def _forward(self, end: EdgeState, distance: float) -> None:
        self.forward_path.append(end)
        self.forward_odometer.append(self.forward_odometer[-1] + abs(distance))

    def _sense(self, node: str, entry_run: str, out: PlantOutcome) -> Decision:
        """Sense the structure ahead from the current pose (one fused detection)."""
        pose = self.pose()
        truth = options_at(self.network, node, entry_run, pose)
        sensed = self.error_model.apply(truth, self.rng)
        kind = sensed[0].kind if sensed else "straight"
        self.detection_log.append(detection_record(self.sim_time, node, truth, sensed, kind))
        out.sim_time += self.decision_time
        self.sim_time += self.decision_time
        return Decision(sensed, kind, truth, node, entry_run, pose)

    def resense(self) -> tuple[Decision, PlantOutcome]:
        """Sense the structure ahead again from where the robot stands (after a jam)."""
        if self.decision is None:
            raise RuntimeError("resense() needs a pending decision")
        out = PlantOutcome()
        self.decision = self._sense(self.decision.node_id, self.decision.entry_run, out)
        return self.decision, out

    def _goal_ahead(self, goal: NDArray | EdgePosition, st: EdgeState, move: float) -> float | None:
        """Distance ahead to the goal if it lies on this edge within ``move`` (plus the
        trigger distance, since the robot would see it), else None."""
        gp = goal if isinstance(goal, EdgePosition) else goal_edge_position(self.network, goal)
        if gp.run_id != st.run_id:
            return None
        r = self.network.run_by_id[st.run_id]
        ahead = gp.s - st.s if st.towards == r.b else st.s - gp.s
        if -1e-9 <= ahead <= move + self.trigger_distance:
            return max(ahead, 0.0)
        return None

    # ---------------------------------------------------------------- executing
    def execute(
        self, choice: StructureOption | str, goal: NDArray | EdgePosition | None = None
    ) -> PlantOutcome:
        """Take the chosen detected way on, or back out (``BACK_OUT``). A jam leaves the robot
        before the structure (it stalled there and backed off) and costs ``jam_time``; a
        ``goal`` just past the fitting on the way taken ends the move there."""
        out = self._execute(choice, goal)
        if out.status == PlantStatus.JAMMED:
            out.sim_time += self.jam_time
            self.sim_time += self.jam_time
        return out

    def _execute(
        self, choice: StructureOption | str, goal: NDArray | EdgePosition | None
    ) -> PlantOutcome:
        if self.decision is None:
            raise RuntimeError("execute() needs a decision; call advance() first")
        dec = self.decision
        if isinstance(choice, str):
            if choice != BACK_OUT:
                raise ValueError(
                    f"choice must be a StructureOption or {BACK_OUT!r}, got {choice!r}"
                )
            return self._back_out(dec)
        out = PlantOutcome()
        if not drivable(choice):
            out.status, out.note = PlantStatus.BLOCKED, "refused: outside the robot's range"
            return out
        k, sep = match_option(choice, dec.truth)
        true = dec.truth[k]
        diameter = self.clamped_diameter
        tol = self.tolerance
        if sep > tol.match:
            out.status, out.note = (
                PlantStatus.JAMMED,
                f"no way on within {math.degrees(sep):.0f} deg",
            )
            return out
        lim = tol.at(diameter)
        d_err = (choice.distance - true.distance) / max(diameter, 1e-3)
        a_err = choice.angle - true.angle
        if true.bend_radius > 0.0 and choice.bend_radius > TURN_RADIUS_FACTOR * diameter:
            # a long bend (followed on its own arc, see primitives.sequences.take_turn): the
            # turn starts where the arc does and follows its walls to its end (it complies
            # with them), so an angle read short (a lower bound, seen short of the arc's end)
            # is no error; where the arc starts is what must be right
            d_err = (arc_start(choice) - arc_start(true)) / max(diameter, 1e-3)
            a_err = max(a_err, 0.0)
        checks = (
            ("distance (early, fraction of D)", -d_err, lim["distance_early"]),
            ("distance (late, fraction of D)", d_err, lim["distance_late"]),
            (
                "direction",
                abs(wrap_angle(choice.direction - true.direction)) * math.sin(true.angle),
                lim["direction"],
            ),
            ("angle (under)", -a_err, lim["angle_under"]),
            ("angle (over)", a_err, lim["angle_over"]),
        )
        lo, hi = ROBOT_DIAMETER_RANGE
        if not lo <= true.diameter <= hi:
            out.status, out.note = (
                PlantStatus.JAMMED,
                "the pipe is narrower/wider than the robot's range",
            )
            return out
        for key, value, limit in checks:
            if value > limit:
                out.status, out.note = PlantStatus.JAMMED, f"{key} error {value:.3f} > {limit:.3f}"
                return out
        node = dec.node_id
        runs = [r for r in self.network.runs_at[node] if r.id != dec.entry_run]
        g = self.network.geometry[node]
        # the run whose outgoing axis is the matched true way on
        want = _world_vector(true, dec.pose)
        run_out = min(runs, key=lambda r: norm3(g.port(r.id).axis - want))
        if turn_angle(self.network, node, dec.entry_run, run_out.id) > MAX_TURN:
            out.status, out.note = PlantStatus.JAMMED, "turn sharper than the robot can take"
            return out
        if len(runs) > 1 and not (self.junctions and self.junctions[-1][1] == node):
            self.junctions.append((self.state, node, len(self.forward_path) - 1))
        start = self.state
        into = self._ahead(start)
        length = edge_length(self.network, run_out.id)
        past = min(g.port(run_out.id).leg + 0.05, 0.5 * length)
        if goal is not None:  # a goal between the fitting and where the move would end
            gp = goal if isinstance(goal, EdgePosition) else goal_edge_position(self.network, goal)
            from_node = gp.s if run_out.a == node else length - gp.s
            if gp.run_id == run_out.id and 0.0 <= from_node <= past:
                past = from_node
                out.status = PlantStatus.GOAL
        s_new = past if run_out.a == node else length - past
        entry = self.network.run_by_id[start.run_id]
        at_node = EdgeState(
            start.run_id, edge_length(self.network, entry.id) if node == entry.b else 0.0, node
        )
        self.state = EdgeState(run_out.id, s_new, run_out.other(node))
        self._record_motion(into + past, out, start, self.state, path=False)
        out.path += [start, at_node, self.state]
        self._forward(at_node, into)
        self._forward(self.state, past)
        self.decision = None
        return out

    def _back_out(self, dec: Decision) -> PlantOutcome:
        """Reverse along the forward path to the last junction passed (to the one before it when
        deciding at that junction again), or to the start."""
        out = PlantOutcome(status=PlantStatus.BACK_OUT)
        while self.junctions and self.junctions[-1][1] == dec.node_id:
            self.junctions.pop()
        index = self.junctions[-1][2] if self.junctions else 0
        target = self.junctions[-1][0] if self.junctions else self._start_state
        dist = self.forward_odometer[-1] - self.forward_odometer[index]
        out.path += self.forward_path[index:][::-1]
        self._record_motion(dist, out, self.state, target, path=False)
        del self.forward_path[index + 1 :]
        del self.forward_odometer[index + 1 :]
        self.state = target
        self.decision = None
        return out

    def watch_motion(self, on_tick: Callable[[float], None] | None) -> float | None:
        """Kinematic plants jump between decisions: no ticks to watch (None)."""
        return None

    def body_positions(self) -> NDArray[np.float64] | None:
        """No robot bodies in the fast fidelity (None)."""
        return None

    def close(self) -> None:
        """Nothing to release (the plant interface's close)."""


def detection_record(
    time_s: float,
    node: str,
    truth: list[StructureOption],
    options: list[StructureOption],
    kind: str,
) -> dict:
    """A plain-data record of one detection for episode logs and plots."""
    return {
        "time": round(float(time_s), 4),
        "node": node,
        "true_distance": float(truth[0].distance) if truth else None,
        "true_kind": truth[0].kind if truth else "straight",
        "kind": kind,
        "options": [o.to_dict() for o in options],
        "truth": [o.to_dict() for o in truth],
    }


def goal_edge_position(network: PipeNetwork, goal: NDArray[np.float64]) -> EdgePosition:
    """Edge position of a goal point (memoised per network and goal)."""
    cache = network.__dict__.setdefault("_goal_edges", {})
    key = tuple(float(v) for v in goal)
    if key not in cache:
        cache[key] = edge_position(network, network.centreline.nearest(np.asarray(goal, float)))
    return cache[key]


def _world_vector(option: StructureOption, pose: Pose) -> NDArray[np.float64]:
    """World direction of a (true) option's outgoing axis."""
    return pose.rotation @ option_vector(option)
