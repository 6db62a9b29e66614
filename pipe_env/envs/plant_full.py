"""Full fidelity: the MuJoCo robot, the rotating LiDAR, the detector and the primitives' executor.

:class:`PhysicalPlant` implements the plant interface of :mod:`pipe_env.envs.plant` for real:

- ``advance``: the robot drives forward in stop-and-scan steps of ``scan_interval`` metres (the
  thesis's position-controlled servo sweep at each stop). Every sweep goes to the detector with
  the clamped diameter read from the robot's encoders; the detections are fused by
  :class:`detector.fusion.StructureTracker` with the robot's own sensor pose. The robot stops
  when a structure is confirmed with its reference point within the trigger distance, when the
  goal is reached, or - failing safe - when the sensor goes blind (too few returns to see the
  pipe ahead: the LS02 in a small pipe). A blind stop is offered as a dead end. A structure
  with a turning way confirmed closer than ``CLOSE_DECISION`` (first seen after a turn's
  run-out) is backed away from to the trigger distance and swept again before deciding. A structure
  first seen within the trigger distance is swept again in place until confirmed. After every
  sweep the robot steers onto the pipe axis the sweep measures (the improved fit's sensor
  offset and axis direction, whatever detector proposes the options). A goal between the robot
  and the structure it stopped for is driven up to.
- ``execute``: the chosen option becomes a primitive sequence
  (:func:`primitives.sequences.for_option`) that the executor runs with real contacts; a jam
  makes the robot back off to where it decided and sense again; backing out reverses along the
  driven path to the last junction. A goal the sequence drove over counts as reached.

With ``detector="ground_truth"`` the robot still drives and turns physically, but the options
come from the plant drawing at the pose where a real detector would have confirmed them (the
oracle ablation of the detection).

Sensing while driving is :class:`SweepSensing` (the executor's scan callback: goal, log, axis
following, cadence, stop/rescan verdicts) over a detector source: :class:`DetectorSource` (the
detector with the plant's tracker) or :class:`OracleSource` (the plant drawing).
:meth:`PhysicalPlant.close` releases the MuJoCo world; a closed plant builds it again on
:meth:`~PhysicalPlant.reset`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

import detector as detection
from detector.fusion import StructureTracker, TrackState
from detector.geometry import Pose
from detector.options import StructureOption, option_order
from detector.scan import Scan
from detector.validation import check_number, fail
from detector.vocab import DETECTORS, Method
from pipe_env.envs.fidelity import Fidelity
from pipe_env.envs.observations import SCAN_SHAPE
from pipe_env.envs.plant import (
    BACK_OUT,
    Decision,
    PlantOutcome,
    PlantStatus,
    detection_record,
    goal_edge_position,
)
from pipe_env.ground_truth import fitting_ahead, options_at
from pipe_env.lidar import LidarSpec
from pipe_env.network import PipeNetwork
from pipe_env.routing import EdgePosition, edge_length, edge_path, locate
from pipe_env.world import PipeWorld
from primitives.steps import SequenceStatus

#: Fewer valid returns than this in a sweep means the sensor cannot see the pipe ahead.
BLIND_RETURNS = 60
#: Consecutive blind sweeps before the robot stops (fail safe).
BLIND_SWEEPS = 2
#: ``advance`` drives in legs of at most this many metres (a long straight takes several; the
#: robot stops only for a structure, a dead end or the goal), metres.
MAX_DRIVE = 4.0
#: The goal counts as reached within this distance along the network, metres.
GOAL_TOLERANCE = 0.05
#: Sweeps in place to confirm a structure first seen within the trigger distance.
CONFIRM_RESCANS = 3
#: The robot steers at the pipe-axis point this far ahead of its sensor, m.
AXIS_LOOKAHEAD = 0.15
#: Sweep cadence: while the last sweep shows no structure (and no goal, no blind sweep) within
#: ``SPARSE_REACH`` ahead, the robot drives ``sparse_interval`` between sweeps; once one is
#: within reach, ``scan_interval`` (the trigger and confirmation rules use ``scan_interval``
#: whatever the cadence). Structures are seen from 1.2-2 m ahead (the detector on the study
#: layouts, 60-120 mm), so a sparse drive never carries the robot past the trigger distance
#: of a structure it could have seen, m.
SPARSE_REACH = 0.6
#: The executor's time compression k for ``physics="contact"`` (the default of
#: ``PhysicalPlant(time_compression=None)``): drives, rolls, folding the V, centring run k times
#: faster in physics, ``sim_time`` keeps the robot's nominal speeds (the rule:
#: ``primitives.executor.TIME_COMPRESSION``). ``physics="everywhere"`` (the reference) keeps
#: k = 1, so the contact/everywhere equivalence measures the compression too. Measured
#: (``benchmarks/physics_step_study.py --speedups 1 1.5 2 3 4``: tolerance cases, jam / no-jam
#: cases, ten seeded RoutePlanner episodes): every case holds up to k = 3, k = 4 fails a
#: tolerance case; the episodes succeed as often up to k = 3 but jam more from k = 2 (1, 4 and
#: 4 jams at k = 2, 3, 4, none at 1 and 1.5; at 4 modules are pushed off their paths). k = 1.5
#: passes everything with one grid step of margin (k = 2 passes every case).
TIME_COMPRESSION = 1.5
#: The default ``sparse_interval``: metres driven between sweeps while nothing is within
#: ``SPARSE_REACH`` (three times the default 5 cm ``scan_interval``; a sparse drive ends at
#: least 0.45 m before a structure first seen at the reach's edge), m.
SPARSE_INTERVAL = 0.15
#: A structure confirmed closer than this to the sensor (m) when the robot stops to decide is
#: backed away from (along the driven path) to the trigger distance and swept once more there
#: before deciding. It happens on a short run after a turn: the turn's run-out leaves the full
#: robot 0.2-0.35 m further than the fast plant, so the next fitting is first seen from a few
#: centimetres. The primitives plan from the trigger distance: a tight turn's arc starts
#: 0.65 D + 6.5 mm before the reference point, with the sensor 0.03 m ahead of the front
#: module, so from 2 cm before a 90 mm tee the arc starts 15 mm late and the front stalls at
#: the branch's far corner (held-out network 95: three jams at one spot). 0.1 m is the
#: tracker's ``near_distance`` (closer sweeps weigh no more) and clears the latest arc start
#: of the robot's largest pipes; normal decisions come at 0.15-0.225 m (a contested
#: structure one sweep later), so they are unchanged.
CLOSE_DECISION = 0.1
#: A structure confirmed within ``CLOSE_DECISION`` is backed away from only if a way on it
#: turns by at least this much (rad: the turn primitive's own limit, below which it drives
#: straight through). Driving through (straight on, a reducer) plans
#: from the option's distance wherever the robot stands, and from close up the detector's
#: phantoms (a 2 mm "reducer" just after a bend in a 60 mm pipe) move with the robot: backed
#: away from, one read 0.2 m ahead and the drive through it ran into the closure behind.
TURN_MIN_ANGLE = math.radians(3.0)


def scan_image(scan: Scan, shape: tuple[int, int] = SCAN_SHAPE) -> NDArray[np.float32]:
    """A low-resolution range image: planes x beams binned to ``shape``, the nearest return per
    bin divided by the sensor's maximum range; 1 where a bin has no return."""
    max_range = float(scan.spec.get("max_range", 2.0))
    r = np.where(scan.valid, np.minimum(scan.ranges / max_range, 1.0), 1.0)
    rows = np.array_split(np.arange(r.shape[0]), shape[0])
    cols = np.array_split(np.arange(r.shape[1]), shape[1])
    out = np.ones(shape, dtype=np.float32)
    for i, ri in enumerate(rows):
        if len(ri) == 0:
            continue
        block = r[ri]
        for j, cj in enumerate(cols):
            if len(cj):
                out[i, j] = float(block[:, cj].min())
    return out


_WHERE = "PhysicalPlant"


class PhysicalPlant:
    """Full-fidelity plant (see module docstring).

    Args:
        network: the network (with a start pose).
        detector: ``"improved"``, ``"thesis"`` or ``"ground_truth"``.
        trigger_distance: stop when a confirmed structure's reference point is this close, m.
        lidar: the sensor model.
        misalignment: true sensor pose relative to its nominal mount (None: perfect).
        scan_image: keep a low-resolution range image of the last sweep.
        lidar_backend: ``"analytic"`` (exact, fast; default) or ``"mujoco"`` ray casting.
        scan_interval: metres driven between sweeps once a structure is in reach (see
            ``SPARSE_REACH``).
        sparse_interval: metres driven between sweeps while none is (``scan_interval``: the
            fixed cadence).
        robot_config: the robot (None: the default :class:`~pipe_env.robot.RobotConfig`).
        physics: ``"contact"`` (physics where contact decides: straight drives away from
            fittings move the robot kinematically, clamped or with its V straight, see
            :meth:`primitives.executor.Executor.free_straight`) or ``"everywhere"`` (contact
            physics for every motion: the reference).
        timestep: the physics step, s (None: ``pipe_env.world.TIMESTEP``).
        control_dt: the executor's control period, s (None: ``primitives.executor.CONTROL_DT``).
        time_compression: the executor's time compression k, in [1, 8] (None:
            :data:`TIME_COMPRESSION` with ``physics="contact"``, 1 with ``"everywhere"``).
    """

    fidelity = Fidelity.FULL.value

    def __init__(
        self,
        network: PipeNetwork,
        detector: str = "improved",
        trigger_distance: float = 0.2,
        lidar: LidarSpec | str = "ideal",
        misalignment: Pose | None = None,
        scan_image: bool = False,
        lidar_backend: str = "analytic",
        scan_interval: float = 0.05,
        robot_config: Any = None,
        physics: str = "contact",
        sparse_interval: float = SPARSE_INTERVAL,
        timestep: float | None = None,
        control_dt: float | None = None,
        time_compression: float | None = None,
    ) -> None:
        from primitives.executor import PHYSICS_MODES

        if physics not in PHYSICS_MODES:
            raise fail("physics", physics, ", ".join(PHYSICS_MODES), where=_WHERE)

        if network.start_pose is None:
            raise fail("network.start_pose", None, "a Pose", "missing", where=_WHERE)
        if detector not in DETECTORS:
            raise fail("detector", detector, ", ".join(DETECTORS), where=_WHERE)
        self.network = network
        self.detector = detector
        self.trigger_distance = float(trigger_distance)
        self.keep_image = bool(scan_image)
        self.scan_interval = float(scan_interval)
        self.sparse_interval = check_number(
            "sparse_interval", sparse_interval, self.scan_interval, 0.5, "m", where=_WHERE
        )
        #: the longest drive ``advance`` makes without a decision: the network's centreline
        #: length plus a metre (further, the robot drove through a structure it did not see)
        self._limit = 1.0 + float(sum(edge_length(network, r.id) for r in network.runs))
        lidar_kwargs: dict[str, Any] = {"backend": lidar_backend}
        if misalignment is not None:
            lidar_kwargs["misalignment"] = misalignment
        self.physics = physics
        #: what proposes the options at every sweep: the detector or the ground-truth oracle
        self.source: OracleSource | DetectorSource = (
            OracleSource() if detector == Method.GROUND_TRUTH else DetectorSource(detector)
        )
        self._executor_args: dict[str, Any] = {
            "robot_config": robot_config,
            "lidar": lidar,
            "physics": physics,
            # the analytic LiDAR casts on the network itself: the world's ray meshes are built
            # only if a render or an export asks for them (``PipeWorld.complete``)
            "ray_meshes": lidar_backend == "mujoco",
            **lidar_kwargs,
        }
        # the physics step and control period: the executor's defaults unless given
        if timestep is not None:
            self._executor_args["timestep"] = timestep
        if control_dt is not None:
            self._executor_args["control_dt"] = control_dt
        if time_compression is None:
            time_compression = TIME_COMPRESSION if physics == "contact" else 1.0
        self._executor_args["time_compression"] = time_compression
        self._build()
        self.reset(np.random.default_rng(0))

    def _build(self) -> None:
        """Build the MuJoCo world with the robot (clamped at the start pose) and the LiDAR."""
        from primitives.executor import Executor

        self.executor = Executor.for_network(self.network, **self._executor_args)
        self.world: PipeWorld | None = self.executor.world
        self.robot = self.executor.robot
        self._started = False

    # ------------------------------------------------------------------ state
    def reset(self, rng: np.random.Generator) -> None:
        """Put the robot back at the network's start pose, clamped, with fresh logs."""
        start = self.network.start_pose
        assert start is not None
        if self.world is None:  # closed: built again
            self._build()
        if self._started:  # the executor placed the robot when it was built
            self.executor.place(start, float(self.network.inner_diameter_at(start.position)))
        self._started = True
        self.rng = rng
        self.tracker = StructureTracker()
        self._track_state: TrackState | None = None
        self.decision: Decision | None = None
        self.detection_log: list[dict] = []
        self.last_scan: Scan | None = None
        self.scan_image: NDArray[np.float32] | None = None
        self.travelled = 0.0
        self.sim_time = 0.0
        self._odometry_error = np.zeros(3)
        #: junctions passed: (odometer at the decision, node id, clamped diameter there, m);
        #: odometer: forward distance
        self.junctions: list[tuple[float, str, float]] = []
        self._odometer = 0.0
        self._start_diameter = self.read_clamp()
        self._decision_diameter = self._start_diameter

    def pose(self) -> Pose:
        """True sensor pose of the robot.

        Raises:
            RuntimeError: the plant is closed (:meth:`reset` builds it again).
        """
        if self.robot is None:
            raise RuntimeError("PhysicalPlant: the plant is closed; reset() builds it again")
        return self.robot.sensor_pose()

    def odometry_pose(self) -> Pose:
        """The sensor pose the robot believes: the true pose plus the odometry drift. Every
        motion of ``d`` metres adds an independent N(0, (0.01 m/sqrt(m) * sqrt(d))^2) error on
        each world axis (a random walk: the drift's std grows with the square root of the
        distance driven)."""
        p = self.pose()
        return Pose.trusted(p.position + self._odometry_error, p.rotation)

    @property
    def clamped_diameter(self) -> float:
        """The clamp encoders' reading (m) taken at the last decision (at the start before
        any): reading it draws no noise, so observing or rendering leaves the run as it is."""
        return self._decision_diameter

    def read_clamp(self) -> float:
        """A fresh reading of the clamp encoders (m, with their noise, from the plant's
        generator)."""
        return float(self.robot.clamped_diameter(self.rng))

    @property
    def state(self):
        """Edge state (run, position, heading) of the true sensor pose."""
        from pipe_env.envs.plant import EdgeState

        ep, towards = locate(self.network, self.pose())
        return EdgeState(ep.run_id, ep.s, towards)

    def edge_position(self) -> EdgePosition:
        ep, _ = locate(self.network, self.pose())
        return ep

    def waypoint(self) -> NDArray[np.float64]:
        """The robot's current place as a path waypoint (the sensor position, m)."""
        return self.pose().position.copy()

    def positions(self, waypoints: list[Any]) -> NDArray[np.float64]:
        return np.array([np.asarray(w, dtype=float) for w in waypoints]).reshape(-1, 3)

    def _account(self, outcome: Any, out: PlantOutcome) -> None:
        """Fold an executor outcome into the plant's clocks and the path."""
        d = abs(float(outcome.travelled))
        self.travelled += d
        self.sim_time += float(outcome.duration)
        out.distance += d
        out.sim_time += float(outcome.duration)
        self._odometry_error = self._odometry_error + self.rng.normal(
            0.0, 0.01 * math.sqrt(d) if d > 0 else 0.0, size=3
        )
        positions = outcome.telemetry["sensor_position"] if len(outcome.telemetry) else []
        step = max(1, len(positions) // 40)
        out.path += [np.asarray(p, dtype=float) for p in positions[::step]]
        out.path.append(self.pose().position.copy())

    # ------------------------------------------------------------------ sensing
    def _truth(self, pose: Pose) -> tuple[str, str, list[StructureOption]]:
        node, entry = fitting_ahead(self.network, pose)
        return node, entry, options_at(self.network, node, entry, pose)

    def _goal_edge(self, goal: Any) -> EdgePosition:
        """A goal point (or its edge position) as an edge position (memoised per network)."""
        if isinstance(goal, EdgePosition):
            return goal
        return goal_edge_position(self.network, np.asarray(goal, dtype=float))

    def _goal_reached(self, goal: Any) -> bool:
        if goal is None:
            return False
        gp = self._goal_edge(goal)
        here = self.edge_position()
        if here.run_id != gp.run_id:
            return False
        return abs(here.s - gp.s) <= GOAL_TOLERANCE + 0.5 * self.scan_interval

    def _follow_axis(self, scan: Scan, det: Any, clamped_diameter: float) -> None:
        """Steer the next drive onto the pipe axis the sweep shows (pure pursuit of the axis
        point ``AXIS_LOOKAHEAD`` ahead). The improved detector's pipe-frame fit gives the
        sensor's offset from the axis and the axis direction; the thesis method and the
        ground-truth oracle give none, so the improved fit runs for them too: driving is the
        same robot whatever detector proposes the options. Without it the robot drifts off
        the axis and noses down over a metre of pipe (tracking lag and wall contact; the
        modules are gravity-compensated), the clamp reading drops and the far wall looks like
        a turn."""
        if det is None or "sensor_offset_pipe" not in det.diagnostics:
            det = detection.detect(scan, clamped_diameter, method="improved")
        dg = det.diagnostics
        offset, axis = dg.get("sensor_offset_pipe"), dg.get("pipe_axis_sensor")
        if offset is None or axis is None:
            return
        a = np.asarray(axis, dtype=float)
        off = np.asarray(offset, dtype=float)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(off)) and a[0] > 0.99):
            return  # no trustworthy fit (over 8 deg of tilt is not a straight pipe)
        if float(np.hypot(*off)) > 0.3 * clamped_diameter:
            return
        target = AXIS_LOOKAHEAD * a / float(np.linalg.norm(a)) - np.array([0.0, *off])
        # a correction relative to the sensor: expressed in the world through the sensor's
        # actual orientation (the executor's frame), not the odometry's belief
        self.executor.aim(self.pose().rotation @ target)

    def _goal_ahead(self, goal: Any) -> float | None:
        """Signed distance (m) along the robot's run from the sensor to ``goal`` (positive
        ahead), or None if the goal is on another run."""
        if goal is None:
            return None
        gp = self._goal_edge(goal)
        here, towards = locate(self.network, self.pose())
        if here.run_id != gp.run_id:
            return None
        run = self.network.run_by_id[here.run_id]
        return gp.s - here.s if towards == run.b else here.s - gp.s

    def _drove_over_goal(self, goal: Any, outcome: Any) -> bool:
        """True if the sensor went over ``goal`` during ``outcome``'s motion (its recorded
        sensor path, and where it stands, pass within the goal's tolerance of the goal's point
        on the centreline) and stands at or past it on the goal's run. The path test keeps a
        robot stalled inside a junction, which ``locate`` may place on another run of it,
        from counting a goal it never reached."""
        if goal is None or not (self._goal_reached(goal) or self._goal_passed(goal)):
            return False
        gp = self._goal_edge(goal)
        point, _ = edge_path(self.network, gp.run_id).point_tangent(gp.s)
        path = [np.asarray(p, dtype=float) for p in outcome.telemetry.get("sensor_position", [])]
        path.append(self.pose().position)
        reach = GOAL_TOLERANCE + 0.5 * self.scan_interval
        return min(float(np.linalg.norm(p - point)) for p in path) <= reach

    def _goal_passed(self, goal: Any) -> bool:
        """True if ``goal`` lies on the run the robot is in, between the fitting it entered the
        run by and where it stands: a sequence (a turn's run-out) drove over it."""
        ahead = self._goal_ahead(goal)
        return ahead is not None and ahead <= GOAL_TOLERANCE + 0.5 * self.scan_interval

    def _sensing(self, goal: Any) -> SweepSensing:
        """The scan callback of one drive (or sense in place) towards ``goal``."""
        return SweepSensing(self, self.source, goal)

    def _cadence(self, seen: list[float], goal: Any, blind: bool) -> float:
        """The next drive's length, m: ``sparse_interval`` while no structure seen (``seen``:
        distances ahead, m), no goal and no blind sweep lie within ``SPARSE_REACH``;
        ``scan_interval`` otherwise."""
        if blind or any(d <= SPARSE_REACH for d in seen):
            return self.scan_interval
        ahead = self._goal_ahead(goal)
        if ahead is not None and ahead >= -GOAL_TOLERANCE and ahead <= SPARSE_REACH:
            return self.scan_interval
        return self.sparse_interval

    def advance(self, goal: Any = None) -> tuple[Decision | None, PlantOutcome]:
        """Drive and scan until a structure is confirmed, the goal is reached, or blind. A
        structure with a way turning by :data:`TURN_MIN_ANGLE` or more, confirmed closer
        than :data:`CLOSE_DECISION`, is backed away from to the trigger distance and swept
        again (once per call) before deciding."""
        out = PlantOutcome()
        # a long straight is normal pipe: the robot drives on in legs of MAX_DRIVE until a
        # structure, a dead end (blind) or the goal stops it, or it jams; the whole network's
        # pipe length bounds the drive (a robot cannot drive further without a structure)
        why, outcome, confirmed = self._drive(goal, out, self._limit)
        if (
            why == "confirmed"
            and confirmed[0] < CLOSE_DECISION < self.trigger_distance
            and any(o.angle >= TURN_MIN_ANGLE for o in confirmed[1])
        ):
            # sweep again from where the back-off ended, even if it stalled on the way (held-out
            # network 51, GoalGreedy: 21 cm back, then a probe jammed; deciding on the last
            # sweep's distances started the turn 21 cm early): the fused estimate is anchored
            # in the odometry frame, the new sweep re-expresses it from here
            self._back_off(self.trigger_distance - confirmed[0], out)
            why, outcome, _ = self._drive(goal, out, self._limit)
        ahead = self._goal_ahead(goal) if why in ("confirmed", "blind") else None
        if ahead is not None and 0.0 <= ahead <= self.trigger_distance + self.scan_interval:
            # the goal lies between the robot and the structure it stopped for (a goal near a
            # dead end): drive up to it, as the fast fidelity does
            from primitives.sequences import go_straight

            last = self.executor.run(go_straight(max(ahead, 0.001)), rng=self.rng)
            self._account(last, out)
            self._odometer += abs(float(last.travelled))
            why = "goal" if last.status == SequenceStatus.DONE else why
        if why == "goal":
            out.status = PlantStatus.GOAL
            return None, out
        if outcome.status == SequenceStatus.JAMMED:
            out.status = PlantStatus.JAMMED
            out.note = f"jammed while driving: {outcome.reason}"
        self.decision = self._decision(why)
        return self.decision, out

    def _drive(
        self, goal: Any, out: PlantOutcome, limit: float
    ) -> tuple[str | None, Any, tuple[float, list[StructureOption]]]:
        """Stop-and-scan forward in legs of ``MAX_DRIVE`` until a sweep stops the robot (the
        goal, a confirmed structure, blind), a jam, or ``limit`` metres driven. Returns why it
        stopped (None: none of those), the last drive's outcome and the distance (m, inf:
        none) and options of the confirmed structure the last sweep saw."""
        driven = 0.0
        while True:
            sensing = self._sensing(goal)
            leg = min(MAX_DRIVE, max(limit - driven, 0.0))
            outcome = self.executor.drive_until(
                sensing,
                leg,
                scan_interval=self.scan_interval,
                rng=self.rng,
                next_interval=sensing.next_interval,
            )
            self._account(outcome, out)
            self._odometer += abs(float(outcome.travelled))
            driven += abs(float(outcome.travelled))
            why = sensing.why
            if why is not None or outcome.status != SequenceStatus.DONE or driven >= limit - 1e-6:
                break
            if abs(float(outcome.travelled)) < 1e-6:
                break  # nothing driven (a zero-length leg): decide here
        return why, outcome, (sensing.confirmed, sensing.confirmed_options)

    def _back_off(self, distance: float, out: PlantOutcome) -> None:
        """Reverse ``distance`` m along the driven path (unclamped, clamped again at the
        diameter the encoders read here). The tracked structure is kept: its estimate is
        anchored in the odometry frame, so the next sweep re-expresses it from the new pose
        and adds its own reading (forgetting it threw away the sweeps from 0.2-0.5 m: a tee
        swept again from behind a turn's exit then confirmed as its branch alone). A jam on
        the way is reported in ``out`` like any other; the robot clamps where it stopped."""
        from primitives.sequences import back_out

        diameter = self.read_clamp()
        back = self.executor.run(back_out(distance, diameter=diameter), rng=self.rng)
        self._account(back, out)
        self._odometer -= abs(float(back.travelled))
        if back.status == SequenceStatus.JAMMED:
            # (a jam is a jam wherever it happens: the env counts it and senses again)
            out.status = PlantStatus.JAMMED
            out.note = f"jammed backing off a close structure: {back.reason}"
            # the jam skipped the back-out's clamping: clamp where it stopped, at the diameter
            # read before backing off, so the sweeps that follow get the pipe's diameter (an
            # open V reads 47-60 mm) and drive_until can re-centre
            from primitives.sequences import Sequence
            from primitives.steps import Clamp

            again = self.executor.run(Sequence("clamp", (Clamp(diameter),)), rng=self.rng)
            self._account(again, out)

    def _decision(self, why: str | None) -> Decision:
        pose = self.pose()
        self._decision_diameter = self.read_clamp()
        node, entry, truth = self._truth(pose)
        if why == "blind":
            dist = truth[0].distance if truth else 0.0
            options = [StructureOption("closure", max(dist, 0.0), 0.0, confidence=0.0)]
            return Decision(options, "closure", truth, node, entry, pose)
        if self.detector == Method.GROUND_TRUTH:
            return Decision(
                list(truth), truth[0].kind if truth else "straight", truth, node, entry, pose
            )
        state = self._track_state
        fused = state.detection if state is not None and state.confirmed else None
        if fused is None or not fused.options:
            last = self.detection_log[-1] if self.detection_log else None
            options = [StructureOption(**o) for o in last["options"]] if last else []
            kind = last["kind"] if last else "straight"
        else:
            options, kind = list(fused.options), fused.kind
        options.sort(key=option_order)
        return Decision(options, kind, truth, node, entry, pose)

    def resense(self) -> tuple[Decision, PlantOutcome]:
        """After a jam: sweep once more where the robot stands and decide on fresh sweeps. The
        fused estimate that jammed is forgotten (a phantom confirmed from a few places would
        otherwise be offered again however the new sweeps disagree)."""
        self.tracker.reset()
        self._track_state = None
        out = PlantOutcome()
        sensing = self._sensing(None)
        if self.executor.lidar is not None:
            from primitives.sequences import Sequence
            from primitives.steps import Sweep

            outcome = self.executor.run(
                Sequence("resense", (Sweep(),)), on_scan=sensing, rng=self.rng
            )
            self._account(outcome, out)
        self.decision = self._decision(sensing.why)
        return self.decision, out

    # ---------------------------------------------------------------- executing
    def execute(self, choice: StructureOption | str, goal: Any = None) -> PlantOutcome:
        """Run the sequence of the chosen option, or back out (``BACK_OUT``)."""
        from primitives.sequences import back_out, for_option

        if self.decision is None:
            raise RuntimeError("execute() needs a decision; call advance() first")
        dec = self.decision
        out = PlantOutcome()
        if isinstance(choice, str):
            if choice != BACK_OUT:
                raise fail("choice", choice, f"a StructureOption or {BACK_OUT!r}", where=_WHERE)
            return self._back_out(dec)
        odometer_at_decision = self._odometer
        sequence = for_option(choice, incoming_diameter=self.read_clamp())
        outcome = self.executor.run(sequence, rng=self.rng)
        self._account(outcome, out)
        self._odometer += abs(float(outcome.travelled))
        status = outcome.status
        if status != SequenceStatus.DONE and self._drove_over_goal(goal, outcome):
            # the sequence stopped (held-out network 99: a reducer's run-out driven into the
            # dead end 19 cm after it) after the sensor went over the goal: the robot got
            # there, as the fast fidelity's move ends at a goal just past the fitting
            self.tracker.reset()
            self._track_state = None
            self.decision = None
            out.status, out.note = PlantStatus.GOAL, f"reached the goal ({outcome.reason})"
            return out
        if status == SequenceStatus.JAMMED:
            # back off to where the robot decided, as an operator would, then sense again
            back = self.executor.run(
                back_out(
                    max(self._odometer - odometer_at_decision, 0.0),
                    diameter=self._decision_diameter,
                ),
                rng=self.rng,
            )
            self._account(back, out)
            self._odometer -= abs(float(back.travelled))
            out.status, out.note = PlantStatus.JAMMED, outcome.reason
            return out
        if status in (SequenceStatus.BLOCKED, SequenceStatus.DEAD_END):
            out.status, out.note = PlantStatus.BLOCKED, outcome.reason
            return out
        ways = [r for r in self.network.runs_at[dec.node_id] if r.id != dec.entry_run]
        if len(ways) > 1 and not (self.junctions and self.junctions[-1][1] == dec.node_id):
            self.junctions.append((odometer_at_decision, dec.node_id, self._decision_diameter))
        self.tracker.reset()
        self._track_state = None
        self.decision = None
        if self._goal_reached(goal) or self._goal_passed(goal):
            out.status = PlantStatus.GOAL
        return out

    def _back_out(self, dec: Decision) -> PlantOutcome:
        from primitives.sequences import back_out

        out = PlantOutcome(status=PlantStatus.BACK_OUT)
        while self.junctions and self.junctions[-1][1] == dec.node_id:
            self.junctions.pop()
        target = self.junctions[-1][0] if self.junctions else 0.0
        diameter = self.junctions[-1][2] if self.junctions else self._start_diameter
        distance = max(self._odometer - target, 0.0)
        if distance > 1e-3:
            outcome = self.executor.run(back_out(distance, diameter=diameter), rng=self.rng)
            self._account(outcome, out)
            self._odometer -= abs(float(outcome.travelled))
            if outcome.status != SequenceStatus.DONE:
                out.note = f"backing out ended {outcome.status}: {outcome.reason}"
                if outcome.status == SequenceStatus.JAMMED:
                    out.status = PlantStatus.JAMMED
        self.tracker.reset()
        self._track_state = None
        self.decision = None
        return out

    def watch_motion(self, on_tick: Callable[[float], None] | None) -> float | None:
        """Call ``on_tick(simulated time, s)`` at every control tick from now on (None: stop);
        returns the executor's simulated time, s."""
        self.executor.on_tick = on_tick
        return float(self.executor.time)

    def body_positions(self) -> NDArray[np.float64] | None:
        """World positions of the robot's modules, (N, 3) m."""
        assert self.world is not None
        return np.array(self.world.data.xpos[self.robot.body_ids])

    def close(self) -> None:
        """Release the MuJoCo world (model, data, contact pairs, the LiDAR's ray caster) and
        the episode's logs and last sweep; :meth:`reset` builds the world again if the plant
        is used after closing."""
        if self.executor is not None and self.executor.lidar is not None:
            self.executor.lidar.close()
        self.executor = None  # type: ignore[assignment]
        self.robot = None  # type: ignore[assignment]
        self.world = None
        self.tracker.reset()
        self._track_state = None
        self.decision = None
        self.detection_log = []
        self.last_scan = None
        self.scan_image = None


@dataclass
class Reading:
    """What a detector source made of one sweep.

    Attributes:
        options: the options to log (the fused estimate once confirmed), with their ``kind``.
        seen: distances (m) of everything seen ahead (for the sweep cadence).
        confirmed: distance (m) of the nearest confirmed structure's reference point (inf:
            none).
        unconfirmed: distance (m) of the nearest structure this sweep sees, confirmed or not
            (inf: none); one within the trigger distance is swept again before driving on.
        fit: the sweep's detection with the pipe-frame fit (None: the plant fits one).
        track: the tracker's state after the sweep (None: no tracker).
        can_be_blind: True if too few returns make the sweep blind (a real sensor).
    """

    options: list[StructureOption]
    kind: str
    seen: list[float]
    confirmed: float = math.inf
    unconfirmed: float = math.inf
    fit: Any = None
    track: TrackState | None = None
    can_be_blind: bool = False


class OracleSource:
    """Options from the plant drawing at the robot's pose (the oracle ablation of detection):
    a structure counts as confirmed as soon as its reference point is seen."""

    method = Method.GROUND_TRUTH

    def read(
        self, scan: Scan, clamped_diameter: float, truth: list[StructureOption], tracker: Any
    ) -> Reading:
        """The reading of ``scan`` (the drawing's options ``truth`` at its pose)."""
        del scan, clamped_diameter, tracker
        ref = truth[0].distance if truth else math.inf
        kind = truth[0].kind if truth else "straight"
        return Reading(list(truth), kind, [ref], confirmed=ref)


class DetectorSource:
    """Options from a detector (``"improved"`` or ``"thesis"``) fused over sweeps by the
    plant's :class:`~detector.fusion.StructureTracker`."""

    def __init__(self, method: str) -> None:
        self.method = method

    def read(
        self,
        scan: Scan,
        clamped_diameter: float,
        truth: list[StructureOption],
        tracker: StructureTracker,
    ) -> Reading:
        """The reading of ``scan`` with the clamp reading ``clamped_diameter`` (m)."""
        del truth
        det = detection.detect(scan, clamped_diameter, method=self.method)
        track = tracker.update(det, scan.nominal_positions[-1], scan.nominal_rotations[-1])
        fused = track.detection if track.confirmed else det
        confirmed = math.inf
        if track.confirmed and track.detection.options:
            confirmed = min(o.distance for o in track.detection.options)
        return Reading(
            list(fused.options),
            fused.kind,
            [o.distance for o in det.options] + [o.distance for o in fused.options],
            confirmed=confirmed,
            unconfirmed=min((o.distance for o in det.options), default=math.inf),
            fit=det,
            track=track,
            can_be_blind=True,
        )


class SweepSensing:
    """The scan callback of one drive towards a goal (see :meth:`PhysicalPlant.advance`).

    At every sweep: stop at the goal; else read the sweep with the plant's detector source, log
    it, steer onto the measured pipe axis, choose the next drive's length (``next_interval``),
    and stop (``why``: ``"blind"`` after ``BLIND_SWEEPS`` blind sweeps, ``"confirmed"`` with a
    confirmed structure within the trigger distance), sweep again in place (a structure seen
    within it but not yet confirmed, at most ``CONFIRM_RESCANS`` times) or drive on.
    """

    def __init__(self, plant: PhysicalPlant, source: OracleSource | DetectorSource, goal: Any):
        self.plant = plant
        self.source = source
        self.goal = goal
        #: why the drive stopped: ``"goal"``, ``"confirmed"``, ``"blind"`` or None
        self.why: str | None = None
        #: distance (m) and options of the confirmed structure the last sweep saw (inf, [])
        self.confirmed = math.inf
        self.confirmed_options: list[StructureOption] = []
        self.interval = plant.scan_interval
        self.blind = 0
        self.rescans = 0
        self.t_start = plant.executor.time  # the plant's clock catches up after the motion

    def next_interval(self) -> float:
        """The next drive's length, m (the cadence the last sweep chose)."""
        return float(self.interval)

    def __call__(self, scan: Scan, state: Any) -> str:
        """The verdict on ``scan`` (``state``: the executor's state at the sweep)."""
        plant = self.plant
        plant.last_scan = scan
        if plant.keep_image:
            plant.scan_image = scan_image(scan)
        now = plant.sim_time + (state.time - self.t_start)
        node, _, truth = plant._truth(plant.pose())
        if plant._goal_reached(self.goal):
            self.why = "goal"
            return "stop"
        diameter = float(state.clamped_diameter)
        reading = self.source.read(scan, diameter, truth, plant.tracker)
        self.confirmed = reading.confirmed
        self.confirmed_options = reading.options if math.isfinite(reading.confirmed) else []
        plant._follow_axis(scan, reading.fit, diameter)
        if reading.track is not None:
            plant._track_state = reading.track
        plant.detection_log.append(
            detection_record(now, node, truth, reading.options, reading.kind)
        )
        if reading.can_be_blind:
            self.blind = self.blind + 1 if scan.n_valid < BLIND_RETURNS else 0
        self.interval = plant._cadence(reading.seen, self.goal, blind=self.blind > 0)
        return self._verdict(reading)

    def _verdict(self, reading: Reading) -> str:
        if self.blind >= BLIND_SWEEPS:
            self.why = "blind"
            return "stop"
        window = self.plant.trigger_distance + 0.5 * self.plant.scan_interval
        if reading.confirmed <= window:
            self.why = "confirmed"
            return "stop"
        # a structure seen within the trigger distance but not confirmed yet (a short run
        # after a fitting): sweep again in place rather than drive into it unconfirmed
        if reading.unconfirmed <= window and self.rescans < CONFIRM_RESCANS:
            self.rescans += 1
            return "rescan"
        self.rescans = 0
        return "continue"
