"""The executor: runs primitive sequences on the MuJoCo robot at a fixed control rate.

It owns the robot's drive state (see the drive model in :mod:`pipe_env.robot`), held in named
parts: :class:`~primitives.command.DriveCommand` (``Executor.command``: drive target, commanded
heading, steering, roll, bends), :class:`~primitives.vclamp.VClamp` (``Executor.vclamp``: the
clamping V's angle and side), :class:`~primitives.path.DrivenPath` (``Executor.path``) and
:class:`~primitives.telemetry.Telemetry` (``Executor.telemetry``: the current run's rows):

- the drive target of the front module, moved every control tick (``CONTROL_DT``) forward along
  the front's heading, turned by the steering bend, and re-anchored to where the walls let the
  front module be (lateral offsets beyond ``ANCHOR_POS``; heading beyond ``ANCHOR_ROT`` on an
  arc, ``ANCHOR_ROT_STRAIGHT`` driving straight): walls guide a slightly-off command. Coming
  out of a turn's arc the target keeps the turn's commanded heading (open loop) until the robot
  centres or clamps;
- the driven path: the drive target's poses by odometer, stored in the rear half's frame (the
  commanded roll of the front half removed); every follower module is welded to the pose the
  front had at its place (follow-the-leader; front-half modules rolled by the current roll),
  folded into the clamping V when clamped; reversing retraces this path;
- centring (:class:`~primitives.steps.Centre`): the V folds towards the four sides in turn until
  its apex touches a wall; the two planes' touching depths give the ends' offset from the pipe
  axis, and the robot (with the driven path under it) is moved onto the axis;
- the commanded heading (open loop), which :class:`~primitives.steps.CheckHeading` compares with
  the real one at the end of a turn.

Outcomes: ``done``; ``jammed`` (front lagging its target by more than ``jam_lag``: a stall; a
follower off its pose by more than ``jam_tracking``; a heading check failed); ``blocked`` /
``dead_end`` (a :class:`~primitives.steps.Halt`: refused before moving). Telemetry (times,
sensor positions, front poses, contact forces, joint angles, lag) is kept per control tick and
can be saved (:meth:`SequenceOutcome.save`, npz) and plotted (:meth:`SequenceOutcome.plot`).

Scans are stop-and-scan: the robot stands still, the clock advances by the sweep's duration.

Physics: before every control tick the robot's collision pairs are brought up to date with the
wall pieces near it (:class:`pipe_env.world.NearContacts`; the same contacts as MuJoCo's
automatic collisions against every piece, at about half the cost of a step);
:meth:`Executor.use_near_contacts` switches back to the automatic collisions.

Time compression (``time_compression``, k; see :data:`TIME_COMPRESSION`): the quasi-static
motions run k times faster in physics while the clock keeps the robot's nominal speeds; the
executor's default is k = 1, the full-fidelity plant's for ``physics="contact"`` is set in
:mod:`pipe_env.envs.plant_full`.

Per control tick the executor's own work is batched: every module's target (the followers'
driven-path poses, the V's legs, the rolls, the quaternions) in one pass over preallocated
arrays with compiled kernels, bit for bit what the per-module helpers computed; telemetry rows
are written in place.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numba
import numpy as np
from numpy.typing import NDArray

from detector.geometry import Pose, rotation_about
from detector.scan import Scan
from detector.validation import check_number
from pipe_env.lidar import LidarSpec, RotatingLidar
from pipe_env.network import PipeNetwork
from pipe_env.robot import Robot, RobotConfig, quat_of
from pipe_env.world import CONTACT_PAIR_POOL, TIMESTEP, NearContacts, PipeWorld, build_world
from primitives.command import DriveCommand
from primitives.path import DrivenPath
from primitives.rotations import orthonormal, quats_into, rx, rz
from primitives.sequences import Sequence
from primitives.steps import (
    Bend,
    Centre,
    CheckHeading,
    Clamp,
    Drive,
    Halt,
    Roll,
    SequenceStatus,
    Step,
    Stop,
    Sweep,
    Unclamp,
)
from primitives.telemetry import Telemetry
from primitives.vclamp import CLAMP_SIDE, VClamp

__all__ = ["Executor", "SequenceOutcome"]

#: Control period, s (50 Hz; 10 physics steps of ``pipe_env.world.TIMESTEP``): the default of
#: the executor's ``control_dt``. Everything the executor does per control tick is set in SI
#: units (speeds, rates, durations, the jam thresholds in metres) and converted with the period
#: in use. Measured (``benchmarks/physics_step_study.py``: tolerance cases, jam / no-jam cases
#: and seeded RoutePlanner episodes on a grid of 2-8 ms steps and 20-100 ms periods): every
#: outcome holds at 2 ms steps up to 100 ms periods, but from 40 ms the near-contact selection
#: overruns its reach within a tick (the V folding at ``CLAMP_RATE`` moves its apex about
#: 0.1 m/s, ``NEAR_REACH`` in 60 ms): contacts could be missed. Since the near contacts are
#: selected within a period (``NEAR_INTERVAL``) every case holds up to 60 ms, but seeded episodes
#: at 40 ms jam more than at 20 ms (with time compression 1.5). 20 ms stays.
CONTROL_DT = 0.02
#: Control periods an executor may run at, s.
CONTROL_DT_RANGE = (0.001, 0.2)
#: Time compression (the executor's ``time_compression``, k): the quasi-static motions (straight
#: drives, reversing, rolls, folding and straightening the V, centring probes and shifts) run k
#: times faster in physics than the robot's nominal speeds and rates, while the executor's clock
#: (``Executor.time``, and so the plant's ``sim_time``) keeps the nominal speeds: the robot's
#: real time is what users see; physics integrates the same path in k times fewer steps. Settling
#: (after every motion, and :class:`~primitives.steps.Stop`) is not compressed: it is the time
#: the dynamics need to come to rest, so it runs its full duration in physics and on the clock.
#: A turn's arc and the drive holding the turn's heading after it are not compressed: there the
#: walls set the front's heading, a contact-dynamic motion (measured: compressed 1.5 times, turns
#: in 57-60 mm pipes stall their steering). Durations that bound a motion (``CLAMP_TIMEOUT``) are
#: nominal. A motion's clock is its ticks times their nominal time (uncompressed, a motion is
#: rounded up to whole control periods; compressed, up to k periods). The jam lag keeps its
#: meaning (see :attr:`Executor.jam_lag`); the near contacts are selected as often per metre
#: moved (see :attr:`Executor.near_steps`). The executor's default
#: is 1 (no compression); the plant's default for ``physics="contact"`` is
#: ``pipe_env.envs.plant_full.TIME_COMPRESSION``.
TIME_COMPRESSION = 1.0
#: Straightening the V (an unclamping, a centring probe letting go of the wall) runs this many
#: times the time compression k in physics when the executor compresses time (k > 1; at k = 1,
#: the reference, nothing is compressed). Straightening takes the apex wheels off the wall:
#: contact only ends, nothing the walls decide is integrated faster, and the V's joints follow
#: their targets as at any other rate (the legs' tips move 0.3 m/s at 3 x ``CLAMP_RATE``, a
#: follower trails about 9 mm, within ``RobotConfig.jam_tracking``). At the plant's k = 1.5
#: the V straightens at k = 3, the largest compression every tolerance and jam case of
#: ``benchmarks/physics_step_study.py`` holds at for every motion. Measured
#: (``benchmarks/bench_full_fidelity.py --phases``): straightening after the centring probes
#: was 12 % of the physics ticks per decision. The one exception to ``NEAR_INTERVAL``: the
#: near-contact chunks are sized from ``motion_dt``, so a straightening tick at k = 1.5 moves
#: 60 ms of nominal motion in two 30 ms chunks, beyond the 25 ms interval. It is safe:
#: straightening moves the robot's geoms away from the walls (the apex wheels lift off), so no
#: wall piece the selection missed can be reached within the tick.
RELEASE_COMPRESSION = 2.0
#: A driven front trails its drive target by about this much time of travel at its physical
#: speed (the weld's tracking delay; measured right after a 20 ms tick, 2 ms steps, a clamped
#: straight drive: 1.57 mm at 0.05 m/s, 3.1 mm at 0.1, 4.7 at 0.15, 6.2 at 0.2), s.
TRACKING_DELAY = 0.031
#: Time compressions an executor may run at.
TIME_COMPRESSION_RANGE = (1.0, 8.0)
#: V folding/straightening rate, rad/s.
CLAMP_RATE = math.radians(60.0)
#: Slow folding rate near the expected wall, rad/s.
CLAMP_RATE_SLOW = math.radians(12.0)
#: The V folds fast until this far short of the commanded diameter and searches up to this far
#: beyond it, m.
CLAMP_SEARCH = 0.008
#: Once touching, the V is held at the touching diameter plus this, m (the clamping preload).
CLAMP_PRELOAD = 0.001
#: Centring probes at most this many times (a robot against a wall needs two).
CENTRE_ROUNDS = 3
#: Centring moves the robot sideways at most this fast, m/s.
SHIFT_SPEED = 0.05
#: Behind the robot's rear, a centring shift of the driven path fades out over this, m.
SHIFT_BLEND = 0.1
#: Driven-path samples are kept this far apart, m.
PATH_STEP = 0.0005

#: Driving with ``drive_until``: when the clamp encoders read this much less than at the last
#: clamping, the robot has been pushed off the axis (an opening passed without stopping, a
#: wheel dropped into it); it centres and clamps again before driving on, m. Measured at every
#: sweep of seeded RoutePlanner episodes (held-out networks 0-7): the reading stays within 1 mm
#: of the last clamping's (3 mm once); held-out network 51 (116 mm) dropped 3.9 mm in one 5 cm
#: drive towards a wye, short of the former 4 mm, and the sweeps from there, taken with the
#: given diameter 4 mm short, showed a phantom junction 20 cm closer (three jams, no goal).
RECENTRE_DROP = 0.0025
#: ``drive_until`` sweeps at most this many times in a row without driving (``"rescan"``).
MAX_RESCANS = 4

#: The robot's collision pairs are selected again once it can have moved this near an unpaired
#: wall piece, m (:class:`pipe_env.world.NearContacts`'s ``reach``). Measured: 12 mm selects a
#: third as often as 6 mm for the same contacts (a t-junction turn: 169 selections instead of
#: 585, bit-identical poses) but overflows the 160-pair pool in a mitre turn (automatic
#: collisions then, slower), and the physics step costs the same; 6 mm stays.
NEAR_REACH = 0.006
#: The near contacts are selected again at least every this much nominal motion within a
#: control period (a long or time-compressed period is stepped in chunks), s: at 20 ms periods
#: the selection never overruns its reach, at 40 ms in one chunk it does (the V folding at
#: ``CLAMP_RATE``).
NEAR_INTERVAL = 0.025
#: Physics modes. ``"contact"``: a clamped (or unclamped, its V straight) robot driving
#: straight (forward or back) in a run, away from fittings (see :meth:`Executor.free_straight`),
#: moves kinematically along the pipe axis with the shape, clamp, offset and roll physics gave
#: it,
#: then settles physically (a drive leaving the free run glides to its end, see
#: ``KINEMATIC_SPLIT``); contact
#: physics runs for everything else. ``"everywhere"``: contact physics for every motion (the
#: reference the ``"contact"`` mode is measured against).
PHYSICS_MODES = ("contact", "everywhere")
#: Kinematic motion keeps the robot's body (from its rear to the sensor, its foremost point)
#: at least this fraction of the run's inner diameter inside both port planes of its run (see
#: ``free_straight``): a whole diameter, so no module, wheel or V apex nor the near contacts'
#: reach comes near a fitting. Tried: a quarter diameter (inside the port planes a run's wall
#: is a plain cylinder; wheels and reach stay 11.5 mm clear of them) moves more of the sensing
#: drives near fittings to the kinematic path and passed the equivalence run (24 networks), but
#: the sub-millimetre pose differences of the glides near a tee changed a seeded thesis-detector
#: decision (``tests/test_full_fidelity_digest.py``: the branch no longer seen); kept at 1.
KINEMATIC_CLEARANCE = 1.0
#: ... plus this, m.
KINEMATIC_MARGIN = 0.0
#: A straight drive that starts in the free run and leaves it (a drive through a fitting, a
#: reducer, or up to a turn's arc, see :meth:`Executor.free_span`) glides to the free run's end
#: and runs contact physics from there, if that glide is at least this long, m: a glide costs
#: its settle (``SETTLE_TIME``, 3 control ticks), 2 cm of drive 13 ticks at the plant's k = 1.5.
#: Measured (``benchmarks/bench_full_fidelity.py --phases``): straight drives of the sequences
#: (mostly unclamped, through fittings) were 24 % of the physics ticks per decision.
KINEMATIC_SPLIT = 0.02
#: Kinematic motion needs the sensor within this fraction of the pipe's diameter of the run's
#: axis and its heading within ``KINEMATIC_TILT`` of it (a robot well placed in the pipe).
KINEMATIC_OFFSET = 0.15
KINEMATIC_TILT = math.radians(5.0)
#: A clamped straight drive of 5 cm falls this much short of its command, m; the executor
#: measures it again on every such physical drive. It depends on the control period (the lag
#: a tick leaves): measured 0.12-0.14 mm in 60-120 mm pipes at 20 ms (0-0.08 mm at 40-60 ms).
DEFAULT_SHORTFALL = 0.00013
#: Larger shortfalls (a drive pushing against something) are not taken as the straight's, m.
MAX_SHORTFALL = 0.002
#: Physics run this long after every drive (and kinematic motion) to let the robot settle, s.
SETTLE_TIME = 0.06
#: ... and this long after a roll, a bend of a joint, a clamping, an unclamping and a
#: centring shift, s.
ROLL_SETTLE = 0.06
BEND_SETTLE = 0.1
CLAMP_SETTLE = 0.16
UNCLAMP_SETTLE = 0.04
SHIFT_SETTLE = 0.1
#: Clamping gives up folding the V after this long, s.
CLAMP_TIMEOUT = 8.0
#: A complying drive (``Drive.comply``, out of a long bend's arc) lets the walls set the heading
#: once they hold the front this far off the turn's heading, rad. It was ``jam_hold`` (21 deg):
#: held-out network 23's walls held the front 20.5 deg off a 70 deg turn in a 90 deg bend for
#: the whole run-out, the driven path (which the rear modules follow) went on at 70 deg and
#: the rear modules ended bent against the walls (there and in its next bend, 67 deg of 75, at
#: 7.9 deg): the clamp read 87 mm in a 95 mm pipe, the next sweeps showed a phantom junction
#: and the back-out jammed. Transients coming off the arc reach 2.5 deg. (Counting the
#: run-out from where the walls stop turning the front was tried too: not needed once they
#: take over early, and a tee 40 cm after a bend turned the front again late in the run-out,
#: which then drove the robot into it.)
COMPLY_ONSET = math.radians(4.0)

#: The executor's outcome statuses as plain strings, in :class:`SequenceStatus` order.
STATUSES: tuple[str, ...] = tuple(s.value for s in SequenceStatus)
#: What a scan callback may answer: ``"stop"`` ends the sequence or drive; ``"continue"`` goes
#: on; ``"rescan"`` (``drive_until`` only; elsewhere it means continue) sweeps again in place
#: before driving, e.g. to confirm a structure seen close ahead.
SCAN_VERDICTS = ("stop", "continue", "rescan")

OnScan = Callable[[Scan, "ExecutorState"], str]


@dataclass
class ExecutorState:
    """What the robot knows about itself (passed to scan callbacks).

    Attributes:
        time: simulated time since the executor was created, s.
        odometer: signed distance driven along the path, m.
        clamped_diameter: pipe diameter read from the clamp's encoders, m.
        sensor_pose: nominal LiDAR pose in the world.
    """

    time: float
    odometer: float
    clamped_diameter: float
    sensor_pose: Pose


@dataclass
class SequenceOutcome:
    """What a sequence (or a drive) did. Distances in metres, times in seconds.

    Attributes:
        status: ``done``, ``jammed``, ``blocked`` or ``dead_end``.
        reason: why it ended (empty when done as planned).
        travelled: distance the front module moved along its path (absolute), m.
        duration: simulated time, s.
        telemetry: per control tick: ``times`` (N,), ``sensor_position`` (N, 3), ``poses``
            (N, 7: front position and quaternion w, x, y, z), ``contact_force`` (N,) N,
            ``joint_angles`` (N, J) rad, ``lag`` (N,) m.
        sequence: name of the sequence run.
    """

    status: SequenceStatus = SequenceStatus.DONE
    reason: str = ""
    travelled: float = 0.0
    duration: float = 0.0
    telemetry: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    sequence: str = ""

    def save(self, path: str | Path) -> None:
        """Save status and telemetry as an ``.npz`` file."""
        from detector.atomic import atomic_open

        target = str(path) if str(path).endswith(".npz") else f"{path}.npz"
        with atomic_open(target, "wb") as handle:
            self._savez(handle)

    def _savez(self, handle: Any) -> None:
        arrays: dict[str, Any] = {
            "status": np.array(self.status),
            "reason": np.array(self.reason),
            "travelled": np.array(self.travelled),
            "duration": np.array(self.duration),
            "sequence": np.array(self.sequence),
            **self.telemetry,
        }
        np.savez(handle, **arrays)

    def plot(self, path: str | Path | None = None) -> Any:
        """Contact force, lag and joint angles over time (matplotlib figure; saved if ``path``)."""
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
        t = self.telemetry.get("times", np.zeros(0))
        if len(t):
            ax[0].plot(t, self.telemetry["contact_force"])
            ax[1].plot(t, 1000 * self.telemetry["lag"])
            ax[2].plot(t, np.degrees(self.telemetry["joint_angles"]))
        ax[0].set_ylabel("contact force (N)")
        ax[1].set_ylabel("lag (mm)")
        ax[2].set_ylabel("joint angles (deg)")
        ax[2].set_xlabel("time (s)")
        ax[0].set_title(f"{self.sequence}: {self.status} {self.reason}")
        fig.tight_layout()
        if path is not None:
            from pipe_env.plotting import save_figure

            save_figure(fig, path)
        return fig


class _Jam(Exception):
    pass


@numba.njit(cache=True, error_model="numpy")
def _worst_tracking(
    xpos: NDArray[np.float64],
    bodies: NDArray[np.intp],
    mocap_pos: NDArray[np.float64],
    mocap: NDArray[np.intp],
) -> tuple[float, int]:
    """The largest squared distance (m^2) of ``bodies`` from their mocap targets ``mocap``, and
    its index (the first of equals); (0, -1) without bodies."""
    worst, at = 0.0, -1
    for i in range(bodies.shape[0]):
        b, t = bodies[i], mocap[i]
        d0 = xpos[b, 0] - mocap_pos[t, 0]
        d1 = xpos[b, 1] - mocap_pos[t, 1]
        d2 = xpos[b, 2] - mocap_pos[t, 2]
        err2 = d0 * d0 + d1 * d1 + d2 * d2
        if at < 0 or err2 > worst:
            worst, at = err2, i
    return worst, at


class _Halt(Exception):
    def __init__(self, status: str, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


class _ScanStop(Exception):
    pass


class Executor:
    """Runs sequences on ``robot`` in ``world``; ``lidar`` scans on :class:`Sweep` steps.

    Args:
        world: a world built with the robot (``build_world(..., customize=robot.customize)``).
        robot: the robot (bound to ``world`` here if it is not yet).
        lidar: the rotating LiDAR (its ``mount`` should be ``robot.lidar_mount``), or None.
        physics: one of :data:`PHYSICS_MODES`.
        control_dt: the control period, s, in :data:`CONTROL_DT_RANGE`; rounded to a whole
            number of the world's physics steps (``control_dt`` holds the period in use).
        time_compression: k in :data:`TIME_COMPRESSION_RANGE`: quasi-static motions run k
            times faster in physics, the clock keeps their nominal durations (see
            :data:`TIME_COMPRESSION`).
    """

    def __init__(
        self,
        world: PipeWorld,
        robot: Robot,
        lidar: RotatingLidar | None = None,
        physics: str = "everywhere",
        control_dt: float = CONTROL_DT,
        time_compression: float = TIME_COMPRESSION,
    ) -> None:
        control_dt = check_number(
            "control_dt", control_dt, *CONTROL_DT_RANGE, unit="s", where="Executor"
        )
        time_compression = check_number(
            "time_compression", time_compression, *TIME_COMPRESSION_RANGE, where="Executor"
        )
        if physics not in PHYSICS_MODES:
            raise ValueError(f"physics = {physics!r} is invalid; allowed: {PHYSICS_MODES}")
        if not isinstance(world, PipeWorld):
            raise ValueError(f"world must be a PipeWorld, got {type(world).__name__}")
        if not isinstance(robot, Robot):
            raise ValueError(f"robot must be a pipe_env.robot.Robot, got {type(robot).__name__}")
        if robot.model is not world.model:
            robot.bind(world.model, world.data)
        self.world = world
        self.robot = robot
        self.lidar = lidar
        self.model = world.model
        self.data = world.data
        self.config = robot.config
        #: physics steps per control tick, and the control period in use (a whole number of
        #: physics steps), s
        self.substeps = max(1, int(round(control_dt / self.model.opt.timestep)))
        self.control_dt = self.substeps * self.model.opt.timestep
        #: the time compression k, and the nominal (clock) time of one motion tick: a motion
        #: tick advances the robot by its nominal speed times ``motion_dt`` in ``control_dt``
        #: of physics, s
        self.time_compression = float(time_compression)
        self.motion_dt = self.time_compression * self.control_dt
        #: the nominal time of one tick straightening the V (see :data:`RELEASE_COMPRESSION`), s
        release = RELEASE_COMPRESSION if self.time_compression > 1.0 else 1.0
        self.release_dt = release * self.motion_dt
        #: physics steps between two near-contact selections within a control period: the
        #: period split as evenly as possible into the fewest chunks of at most
        #: ``NEAR_INTERVAL`` of nominal motion each (a motion moves the robot's geoms no further
        #: between two selections than in one uncompressed 20-25 ms period, which the
        #: selection's reach is set for; the whole period at the defaults). Sized from
        #: ``motion_dt``: a straightening tick (``release_dt``, see :data:`RELEASE_COMPRESSION`)
        #: exceeds ``NEAR_INTERVAL`` per chunk, safe since straightening moves geoms away from
        #: the walls
        chunks = max(1, math.ceil(self.motion_dt / NEAR_INTERVAL - 1e-9))
        chunks = min(chunks, self.substeps)
        base, extra = divmod(self.substeps, chunks)
        self.near_steps = tuple(base + (i < extra) for i in range(chunks))
        self.physics = physics
        #: the extra tracking lag of the drive running now (see :attr:`jam_lag`), m
        self._lag_allowance = 0.0
        #: how far the last clamped straight physical drive fell short of its command, m
        self._shortfall = DEFAULT_SHORTFALL
        #: control ticks run with physics, and driven kinematically (``physics="contact"``)
        self.physics_ticks = 0
        self.kinematic_ticks = 0
        self.time = 0.0
        #: called with the simulated time (s) after every control period, or None (video frames)
        self.on_tick: Callable[[float], None] | None = None
        self.odometer = 0.0
        # follower offsets behind the front module's centre along the path, m
        self._offsets = self.config.pitch * np.arange(self.config.n_modules)
        # the per-tick targets of every module (position m, rotation, quaternion; one more
        # row: the driven path at the V's front joint), the followers' odometers (and that
        # joint's), which followers are behind the V, and the modules' mocap ids
        n = self.config.n_modules
        self._target_pos = np.zeros((n + 1, 3))
        self._target_rot = np.zeros((n + 1, 3, 3))
        self._target_quat = np.zeros((n, 4))
        self._target_s = np.zeros(n)
        self._mocap = np.asarray(robot.mocap_ids, dtype=np.intp)
        self._follower_bodies = np.asarray(robot.body_ids[1:], dtype=np.intp)
        self._follower_mocap = self._mocap[1:].copy()
        #: the parts of the executor's state: the drive command, the clamping V, the driven
        #: path and the current run's telemetry
        self.command = DriveCommand()
        self.vclamp = VClamp(self.config)
        # (rows of the followers' odometers; the last row, the V's front joint, is not behind)
        self._behind = np.array([self.vclamp.behind(i) for i in range(1, n)] + [False])
        self._mocap_views = self._mocap_target_views()
        self.path = DrivenPath()
        self.telemetry = Telemetry()
        #: distance moved by the current run (sequence or drive), m
        self._travelled = 0.0
        #: the robot collides only with the wall pieces near it (``None``: with all of them,
        #: MuJoCo's automatic collisions; the same contacts, slower)
        self.near: NearContacts | None = None
        if world.contact_geom_count and world.model.npair >= CONTACT_PAIR_POOL:
            self.near = NearContacts(world, robot.geom_ids, reach=NEAR_REACH)
        start = world.network.start_pose
        if start is not None:
            self.place(start, float(world.network.inner_diameter_at(start.position)))

    @classmethod
    def for_network(
        cls,
        network: PipeNetwork,
        robot_config: RobotConfig | None = None,
        lidar: LidarSpec | str | None = "ideal",
        physics: str = "everywhere",
        timestep: float = TIMESTEP,
        control_dt: float = CONTROL_DT,
        time_compression: float = TIME_COMPRESSION,
        ray_meshes: bool = True,
        **lidar_kwargs: Any,
    ) -> Executor:
        """Build the world of ``network`` with the robot and the LiDAR, the robot clamped at
        the network's start pose; ``physics`` is one of :data:`PHYSICS_MODES`; ``timestep``
        the physics step, s (:func:`pipe_env.world.build_world`); ``control_dt`` the control
        period, s; ``time_compression`` the time compression k (see :data:`TIME_COMPRESSION`);
        ``ray_meshes``: build the world's ray meshes now (False: on demand, for a LiDAR with the
        analytic backend; see :func:`pipe_env.world.build_world`)."""
        if network.start_pose is None:
            raise ValueError("network.start_pose is None; the robot needs a start pose")
        robot = Robot(robot_config)
        world = build_world(
            network,
            contact_walls=True,
            customize=robot.customize,
            timestep=timestep,
            ray_meshes=ray_meshes,
        )
        robot.bind(world.model, world.data)
        sensor = None
        if lidar is not None:
            kwargs = {"mount": robot.lidar_mount, **lidar_kwargs}
            sensor = RotatingLidar(world, lidar, **kwargs)
        return cls(
            world,
            robot,
            sensor,
            physics=physics,
            control_dt=control_dt,
            time_compression=time_compression,
        )

    # ------------------------------------------------------------------ placing
    def place(self, pose: Pose, diameter: float) -> None:
        """Put the robot straight with its LiDAR at ``pose`` and clamp it at ``diameter`` m."""
        if not isinstance(pose, Pose):
            raise ValueError(f"pose must be a detector.geometry.Pose, got {type(pose).__name__}")
        lo, hi = self.config.diameter_range
        if not (isinstance(diameter, (int, float)) and lo - 0.005 <= diameter <= hi + 0.005):
            raise ValueError(
                f"diameter = {diameter!r} is invalid; allowed: the robot's range [{lo}, {hi}] m"
            )
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        rot = np.asarray(pose.rotation, dtype=float)
        front = np.asarray(pose.position, dtype=float) - self.config.lidar_offset * rot[:, 0]
        q = self.robot.free_qpos
        d.qpos[q : q + 3] = front
        d.qpos[q + 3 : q + 7] = quat_of(rot)
        d.qpos[self.robot.joint_qpos] = 0.0
        d.qvel[:] = 0.0
        # the driven path so far: straight behind the front module
        length = self._offsets[-1] + 1.0
        s = np.linspace(-length, 0.0, int(length / 0.01) + 1)
        self.path.clear()
        self.path.push_many(s, front[None, :] + s[:, None] * rot[:, 0][None, :], rot)
        self.odometer = 0.0
        self.vclamp.alpha = 0.0
        self.command.reset(front, rot)
        self._set_targets()
        if self.near is not None:
            mujoco.mj_kinematics(m, d)
            self.near.forget()
            self.near.update(d, force=True)
        mujoco.mj_forward(m, d)
        self._shortfall = DEFAULT_SHORTFALL
        self.telemetry = Telemetry()
        try:
            self._clamp(float(diameter))
        except _Jam:
            pass

    # ------------------------------------------------------------------ targets
    def _set_targets(self) -> None:
        """Drive target of the front; follow-the-leader (and V) targets of the followers.

        All modules' targets in one pass over preallocated arrays: the followers' driven-path
        poses in one batched lookup, the V's legs over them, the front half's commanded roll in
        one batched product, every quaternion in one batched conversion (bit for bit
        ``mju_mat2Quat``'s), and one write of the mocap poses."""
        cmd = self.command
        pos, rot, quat = self._target_pos, self._target_rot, self._target_quat
        pos[0] = cmd.position
        rot[0] = cmd.rotation
        # the driven path keeps the rear half's frames; modules behind the V follow it
        # ``shortening`` further back; the last row: the path at the joint at the V's front
        s = self._target_s
        np.subtract(self.odometer, self._offsets[1:], out=s[:-1])
        s[self._behind] += self.vclamp.shortening
        s[-1] = self.vclamp.apex_odometer(self.odometer)
        self.path.poses_into(s, pos[1:], rot[1:])
        self.vclamp.leg_targets(pos[-1], rot[-1], pos, rot)
        if cmd.roll != 0.0:  # the front half (modules before the roll joint) is rolled
            front = slice(1, self.config.middle_joint)
            rot[front] = rot[front] @ rx(cmd.roll)
        n = len(quat)
        for i, off in cmd.bend_offsets.items():
            if off and 1 <= i < n:
                rot[i] = rot[i] @ rotation_about([0.0, 0.0, 1.0], off)
        quats_into(rot[:n], quat)
        mocap_pos, mocap_quat = self._mocap_views
        if mocap_pos is not None and mocap_quat is not None:
            np.copyto(mocap_pos, pos[:n])
            np.copyto(mocap_quat, quat)
        else:
            self.data.mocap_pos[self._mocap] = pos[:n]
            self.data.mocap_quat[self._mocap] = quat

    def _mocap_target_views(self) -> tuple[NDArray | None, NDArray | None]:
        """Views of the modules' rows of ``data.mocap_pos`` and ``data.mocap_quat`` when their
        mocap ids are consecutive (written in place every tick), else (None, None)."""
        ids = self._mocap
        if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
            rows = slice(int(ids[0]), int(ids[0]) + len(ids))
            return self.data.mocap_pos[rows], self.data.mocap_quat[rows]
        return None, None

    # ------------------------------------------------------------------ stepping
    def use_near_contacts(self, on: bool) -> None:
        """Collide the robot with the wall pieces near it only (True, the default) or with all
        of them through MuJoCo's automatic collisions (False: the reference, slower)."""
        if on and self.near is None:
            if not (self.world.contact_geom_count and self.model.npair >= CONTACT_PAIR_POOL):
                raise ValueError("this world has no contact pair pool; near contacts need one")
            self.near = NearContacts(self.world, self.robot.geom_ids, reach=NEAR_REACH)
            mujoco.mj_kinematics(self.model, self.data)
            self.near.update(self.data, force=True)
        elif not on and self.near is not None:
            self.near.disable()
            self.near = None

    def _physics(self) -> None:
        """One control period of physics steps, in the chunks of ``near_steps`` with the pairs
        near the robot selected before each."""
        if self.near is None:
            mujoco.mj_step(self.model, self.data, nstep=self.substeps)
        else:
            for n in self.near_steps:
                self.near.update(self.data)
                mujoco.mj_step(self.model, self.data, nstep=n)
        self.physics_ticks += 1

    def _tick(self, lag_axis: NDArray | None = None, clock: float | None = None) -> float:
        """Advance one control period of physics with the current targets, the clock by
        ``clock`` s (None: the period; a motion tick: ``motion_dt``); returns the front's lag,
        m."""
        self._physics()
        self.time += self.control_dt if clock is None else clock
        if self.on_tick is not None:
            self.on_tick(self.time)
        d = self.data
        front = d.xpos[self.robot.body_ids[0]]
        diff = self.command.position - front
        lag = float(diff @ lag_axis) if lag_axis is not None else math.sqrt(diff.dot(diff))
        self.telemetry.record(self.time, self.data, self.robot, lag)
        if not np.isfinite(d.qpos).all():
            raise _Jam("the simulation diverged")
        if lag > self.jam_lag:
            raise _Jam(f"stalled: the front lags its drive target by {lag * 1000:.1f} mm")
        self._check_tracking()
        return lag

    @property
    def jam_lag(self) -> float:
        """The front's lag behind its drive target beyond which a drive has stalled, m.

        ``RobotConfig.jam_lag`` means how far the front may fall behind the free tracking
        lag of a drive at the robot's nominal speed. Compressed k times, a drive moves k times
        faster in physics and its front trails by k times the free tracking lag
        (``TRACKING_DELAY`` of travel at the physical speed); the threshold grows by that
        extra, ``(k - 1) * speed * TRACKING_DELAY``, so a stall is still called when the front
        has fallen ``jam_lag`` behind where a freely driving robot would be (the same margin
        over the free lag as at k = 1; at k = 1 the threshold is ``jam_lag`` itself)."""
        return self.config.jam_lag + self._lag_allowance

    @staticmethod
    def _speed_lag(speed: float, k: float) -> float:
        """The extra tracking lag a drive at ``speed`` m/s has compressed ``k`` times (see
        :attr:`jam_lag`), m."""
        return (k - 1.0) * abs(speed) * TRACKING_DELAY

    def _check_tracking(self) -> None:
        """Jam if a follower module is further than ``jam_tracking`` off its target."""
        d = self.data
        err2, k = _worst_tracking(d.xpos, self._follower_bodies, d.mocap_pos, self._follower_mocap)
        if math.sqrt(err2) > self.config.jam_tracking:
            raise _Jam(f"module {k + 1} is pushed {math.sqrt(err2) * 1000:.1f} mm off its path")

    def _front_pose(self) -> tuple[NDArray, NDArray]:
        b = self.robot.body_ids[0]
        return self.data.xpos[b].copy(), self.data.xmat[b].reshape(3, 3).copy()

    def _anchor(self) -> None:
        """Let the drive target follow the walls' guidance beyond the dead bands."""
        p, r = self._front_pose()
        self.command.anchor(p, r)

    # ------------------------------------------------------------------ primitives
    def _drive(self, step: Drive) -> None:
        if step.distance < 0:
            self._reverse(-step.distance, step.speed)
            return
        span = self.free_span()
        if span is not None:
            axis, _, ahead = span
            if step.distance <= ahead:
                self._glide(step.distance, step.speed, axis)
                return
            if ahead >= KINEMATIC_SPLIT:
                # the drive leaves the free run: glide up to its end, physics from there
                self._glide(ahead, step.speed, axis)
                step = Drive(step.distance - ahead, step.speed, step.comply)
        self.path.truncate(self.odometer)
        p, r = self._front_pose()
        start, heading = p.copy(), r[:, 0].copy()
        cmd = self.command
        straight = cmd.curvature == 0.0 and self.vclamp.alpha > 0.0 and not cmd.hold_heading
        self.command.position, self.command.rotation = p.copy(), orthonormal(self.command.rotation)
        remaining = step.distance
        # a turn's arc and the drive holding its heading after it are not compressed: there the
        # walls set the front's heading (contact dynamics, not a quasi-static motion)
        k = self.time_compression if cmd.curvature == 0.0 and not cmd.hold_heading else 1.0
        ds_tick = step.speed * k * self.control_dt
        complying = False
        self._lag_allowance = self._speed_lag(step.speed, k)
        while remaining > 1e-9:
            ds = min(ds_tick, remaining)
            remaining -= ds
            self._anchor()
            self.command.position = self.command.position + ds * self.command.rotation[:, 0]
            if self.command.curvature != 0.0:
                turn = rz(self.command.curvature * ds)
                self.command.rotation = self.command.rotation @ turn
                self.command.heading = self.command.heading @ turn
            self.odometer += ds
            self._travelled += ds
            rear_frame = cmd.rotation @ rx(-cmd.roll) if cmd.roll != 0.0 else cmd.rotation
            self.path.push(self.odometer, self.command.position.copy(), rear_frame.copy())
            self._set_targets()
            try:
                self._tick(self.command.rotation[:, 0], k * self.control_dt)
                if step.comply and cmd.curvature == 0.0 and (complying or cmd.hold_heading):
                    complying = complying or self._steer_error() > min(
                        COMPLY_ONSET, self.config.jam_hold
                    )
                    if complying:  # the bend goes on: the walls set the heading
                        self.command.hold_heading = False
                        self.command.heading = self._front_pose()[1]
                if self.command.curvature != 0.0 or self.command.hold_heading:
                    self._check_steer()
            except _Jam:
                # the robot is where it stalled: the driven path ends there
                p, _ = self._front_pose()
                lag = float((self.command.position - p) @ self.command.rotation[:, 0])
                self.odometer -= max(lag, 0.0)
                self._travelled -= max(lag, 0.0)
                self.path.truncate(self.odometer)
                raise
        self._lag_allowance = 0.0
        self._settle(self._ticks(SETTLE_TIME))
        if straight and step.distance >= 0.01:
            # what a clamped straight drive falls short of its command (the drive's lag not
            # recovered when the next drive starts from where the front is): kinematic
            # drives reproduce the latest measurement
            advance = float((self._front_pose()[0] - start) @ heading)
            self._shortfall = min(max(step.distance - advance, 0.0), MAX_SHORTFALL)

    def _reverse(self, distance: float, speed: float) -> None:
        axis = self.free_straight(-distance)
        if axis is not None:
            self._glide(-distance, speed, axis)
            return
        remaining = distance
        ds_tick = speed * self.motion_dt
        self._lag_allowance = self._speed_lag(speed, self.time_compression)
        while remaining > 1e-9:
            ds = min(ds_tick, remaining)
            remaining -= ds
            self.odometer -= ds
            self._travelled += ds
            self.command.position, self.command.rotation = self.path.pose(self.odometer)
            self.command.position = self.command.position.copy()
            if self.command.roll != 0.0:
                self.command.rotation = self.command.rotation @ rx(self.command.roll)
            self._set_targets()
            self._tick(None, self.motion_dt)
        self._lag_allowance = 0.0
        self.command.heading = self.command.rotation.copy()
        self._settle(self._ticks(SETTLE_TIME))

    # ------------------------------------------------------------ kinematic motion
    def free_straight(self, distance: float) -> NDArray[np.float64] | None:
        """The rule of ``physics="contact"``: the run's unit axis (world, the way the robot
        faces) if driving ``distance`` m (negative: backwards) is a straight drive in a run,
        away from fittings, of a clamped robot or one with its V straight; None if contact
        physics must run.

        Away from fittings: before and after the motion the whole robot (from its rear,
        ``RobotConfig.length`` behind the sensor, to the sensor) lies more than
        ``KINEMATIC_CLEARANCE`` of the run's inner diameter (+ ``KINEMATIC_MARGIN``) inside
        both port planes of its run, so no module, wheel or V apex (nor the near contacts'
        reach) comes near a fitting, a taper or a junction's opening. Straight drive: the V
        folded on its clamping side (clamped) or straight (unclamped: the welds hold every
        module on the driven path as they do clamped), no steering bend, no roll, no bent
        joint, no held turn heading, and the sensor within ``KINEMATIC_OFFSET`` diameters of
        the axis, its heading within ``KINEMATIC_TILT`` of it. Everything else (approaches,
        turns, junctions, reducers, clamping, centring, back-outs near fittings, jams) runs
        contact physics."""
        span = self.free_span()
        if span is None or not math.isfinite(distance):
            return None
        axis, back, ahead = span
        return axis if -back <= distance <= ahead else None

    def free_span(self) -> tuple[NDArray[np.float64], float, float] | None:
        """The run's unit axis (see :meth:`free_straight`) with how far the robot may move
        kinematically backwards and forwards from where it is (both >= 0), m; None if it may
        not move kinematically at all."""
        if self.physics != "contact":
            return None
        v = self.vclamp
        if (
            not (v.alpha == 0.0 or (v.alpha > 0.0 and v.side == CLAMP_SIDE))
            or self.command.curvature != 0.0
            or self.command.roll != 0.0
            or self.command.hold_heading
            or self.command.bent
        ):
            return None
        from pipe_env.routing import edge_length, leg_length, locate

        net = self.world.network
        pose = self.robot.sensor_pose()
        ep, towards = locate(net, pose)
        run = net.run_by_id[ep.run_id]
        axis = net.position(run.b) - net.position(run.a)
        axis = axis / float(np.linalg.norm(axis))
        sign = 1.0 if towards == run.b else -1.0
        axis = sign * axis
        diameter = float(run.diameter)
        cp = net.centreline.nearest(pose.position)
        if cp.distance > KINEMATIC_OFFSET * diameter:
            return None
        if float(pose.forward @ axis) < math.cos(KINEMATIC_TILT):
            return None
        # the robot's body, from its rear (``length`` behind the sensor) to the sensor, must
        # stay more than the clearance inside both port planes [lo, hi] of the run
        clearance = KINEMATIC_CLEARANCE * diameter + KINEMATIC_MARGIN
        lo = leg_length(net, run.a, run.id) + clearance
        hi = edge_length(net, run.id) - leg_length(net, run.b, run.id) - clearance
        length = self.config.length
        if sign > 0:  # facing b: the sensor may go up to hi, the rear down to lo
            ahead, back = hi - ep.s, ep.s - length - lo
        else:  # facing a: the sensor may go down to lo, the rear up to hi
            ahead, back = ep.s - lo, hi - length - ep.s
        if ahead < 0.0 or back < 0.0:
            return None
        return axis, back, ahead

    def _glide(self, distance: float, speed: float, axis: NDArray[np.float64]) -> None:
        """Move the robot (clamped, or unclamped with its V straight) ``distance`` m
        (negative: backwards) along the unit world ``axis`` kinematically: every body, drive
        target and the driven path translate together (joint angles, clamp, offset and roll as
        physics left them), the clock advances
        by the drive's duration, and the robot settles for ``SETTLE_TIME`` s of physics."""
        m, d = self.model, self.data
        step = abs(distance)
        n_ticks = max(1, int(math.ceil(step / (speed * self.motion_dt) - 1e-9)))
        q = self.robot.free_qpos
        if distance > 0:
            # the robot advances what a physical drive of this length does (see ``_drive``)
            move = (distance - min(self._shortfall, 0.5 * distance)) * axis
            self.path.truncate(self.odometer)
            self.command.rotation = orthonormal(self.command.rotation)
            s = self.odometer + distance * np.arange(1, n_ticks + 1) / n_ticks
            frac = (s - self.odometer) / distance
            p = self.command.position[None, :] + frac[:, None] * move[None, :]
            self.path.push_many(s, p, np.broadcast_to(self.command.rotation, (n_ticks, 3, 3)))
            self.command.position = self.command.position + move
            self.odometer += distance
        else:
            self.odometer += distance
            target, rot = self.path.pose(self.odometer)
            move = target - self.command.position
            self.command.position, self.command.rotation = target.copy(), rot.copy()
            self.command.heading = self.command.rotation.copy()
        self._travelled += step
        d.qpos[q : q + 3] += move
        self._set_targets()
        mujoco.mj_kinematics(m, d)
        if self.near is not None:
            self.near.update(d, force=True)
        self.time += n_ticks * self.motion_dt
        self.kinematic_ticks += n_ticks
        if self.on_tick is not None:  # (one frame of the glide for videos)
            self.on_tick(self.time)
        self.telemetry.record(self.time, self.data, self.robot, 0.0)
        self._settle(self._ticks(SETTLE_TIME))

    def _ticks(self, duration: float) -> int:
        """Control ticks (at least one) that last about ``duration`` s."""
        return max(1, int(round(duration / self.control_dt)))

    def _settle(self, ticks: int) -> None:
        for _ in range(ticks):
            self._tick(None)

    def _roll(self, step: Roll) -> None:
        total = step.angle
        if abs(total) < 1e-9:
            return
        n_ticks = max(1, int(math.ceil(abs(total) / (step.rate * self.motion_dt))))
        inc = total / n_ticks
        for _ in range(n_ticks):
            turn = rx(inc)
            self.command.rotation = self.command.rotation @ turn
            self.command.heading = self.command.heading @ turn
            self.command.roll += inc
            self._set_targets()
            self._tick(None, self.motion_dt)
        self._settle(self._ticks(ROLL_SETTLE))

    def _roll_home(self) -> None:
        """Roll the front half back in line with the rear half (the V needs both halves in
        one plane), e.g. after a turn that jammed while rolled."""
        if abs(self.command.roll) > 1e-9:
            self._roll(Roll(-self.command.roll))
            self.command.roll = 0.0

    def _bend(self, step: Bend) -> None:
        c = self.config
        if step.joint >= c.n_modules:
            raise ValueError(f"Bend.joint = {step.joint} is invalid; allowed: 1..{c.n_modules - 1}")
        if step.joint == 1:
            if self.command.curvature != 0.0 and step.angle == 0.0:
                self.command.hold_heading = True  # out of the arc: drive on in the turn's heading
            self.command.curvature = 2.0 * math.sin(0.5 * step.angle) / c.pitch
        else:
            self.command.bend_offsets[step.joint] = step.angle
            self._set_targets()
            self._settle(self._ticks(BEND_SETTLE))

    def _clamp(self, diameter: float) -> None:
        """Fold the V: fast to ``CLAMP_SEARCH`` short of ``diameter``, then slowly until the
        apex wheels touch the wall (``clamp_force``); then hold it where it touched plus
        ``CLAMP_PRELOAD`` (force control: the preload, not the commanded diameter, sets the
        force, so a wrong commanded diameter does not crush the wall)."""
        c = self.config
        self.command.hold_heading = False
        self._roll_home()
        if self.vclamp.side != CLAMP_SIDE:
            self._unclamp()
            self.vclamp.side = CLAMP_SIDE
        a_goal = c.clamp_angle(diameter + CLAMP_SEARCH)
        a_fast = c.clamp_angle(diameter - CLAMP_SEARCH)
        self.vclamp.alpha = min(self.vclamp.alpha, a_fast)
        touched = False
        for _ in range(max(1, int(round(CLAMP_TIMEOUT / self.motion_dt)))):
            self._set_targets()
            self._tick(None, self.motion_dt)
            if self.robot.apex_force(CLAMP_SIDE) >= c.clamp_force:
                touched = True
                break
            if self.vclamp.alpha >= a_goal:
                break
            rate = CLAMP_RATE if self.vclamp.alpha < a_fast else CLAMP_RATE_SLOW
            self.vclamp.alpha = min(self.vclamp.alpha + rate * self.motion_dt, a_goal)
        if touched:
            self.vclamp.alpha = c.clamp_angle(self.robot.clamped_diameter() + CLAMP_PRELOAD)
            self._set_targets()
        self._settle(self._ticks(CLAMP_SETTLE))

    def _unclamp(self, settle_straight: bool = False) -> None:
        """Straighten the V (compressed by :data:`RELEASE_COMPRESSION`) and settle; a V
        already straight moves nothing and settles nothing, unless ``settle_straight`` (a
        centring probe about to fold the V, see :meth:`_probe`)."""
        if self.vclamp.alpha <= 0.0:
            if settle_straight:
                self._settle(self._ticks(UNCLAMP_SETTLE))
            return
        rate = CLAMP_RATE * self.release_dt
        while self.vclamp.alpha > 0:
            self.vclamp.alpha = max(0.0, self.vclamp.alpha - rate)
            self._set_targets()
            self._tick(None, self.release_dt)
        self._settle(self._ticks(UNCLAMP_SETTLE))

    def _probe(self, side: int, rng: np.random.Generator) -> float | None:
        """Fold the V towards ``side`` (see :data:`primitives.vclamp.V_SIDES`) until its apex
        touches the wall; returns the encoders' distance from the end modules' line to that
        wall (m), or None if the V folded fully without touching; the V is straightened
        again."""
        c = self.config
        # the robot settles before the V folds, straight or not (the probe's pose as the
        # reference's, which settled every unclamping): a probe near an opening is sensitive
        # to sub-millimetre pose differences; folding where a module's body or a side wheel,
        # not the apex wheels, meets an opening's edge, it does not register the touch and
        # folds on until the module is pushed off its path (held-out network 69: without
        # this settle a probe past a junction jammed, module 4 pushed 22 mm off its path)
        self._unclamp(settle_straight=True)
        self.vclamp.side = side
        a_max = math.radians(75.0)
        h = None
        while self.vclamp.alpha < a_max:
            self.vclamp.alpha = min(self.vclamp.alpha + CLAMP_RATE * self.motion_dt, a_max)
            self._set_targets()
            self._tick(None, self.motion_dt)
            if self.robot.apex_force(side) >= c.clamp_force:
                h = 0.5 * self.robot.clamped_diameter(rng)
                break
        self._unclamp()
        self.vclamp.side = CLAMP_SIDE
        return h

    def _centre(self, step: Centre, rng: np.random.Generator) -> None:
        """Probe both walls in two planes and move the robot onto the pipe axis; again if the
        robot was so far off that a probe found the wall already touching (saturated)."""
        c = self.config
        self.command.hold_heading = False
        self._roll_home()
        for _ in range(CENTRE_ROUNDS):
            probes = [self._probe(side, rng) for side in range(4)]
            h = [float(v) for v in probes if v is not None]
            if len(h) < len(probes):
                return  # an opening (a junction, a wider pipe): no axis to centre on
            hy0, hz0, hy1, hz1 = h
            _, r = self.path.pose(self.odometer)
            # the ends' line sits off the axis by e; folding towards n the apex meets the wall
            # at R - e.n: side 0 (+y) / 2 (-y) and 1 (+z) / 3 (-z)
            offset = 0.5 * (hy1 - hy0) * r[:, 1] + 0.5 * (hz1 - hz0) * r[:, 2]
            dist = float(np.linalg.norm(offset))
            if dist < step.tolerance:
                return
            self._shift(-offset / dist * min(dist, step.max_shift))
            saturated = min(h) <= 0.5 * c.width + 0.002
            if not saturated and dist < 0.003:
                return

    def _shift(self, move: NDArray) -> None:
        """Translate the robot (its drive target and the driven path under it) by ``move`` m,
        gradually; the path behind the robot blends back to where it was."""
        c = self.config
        hs = self.path.s
        rear = self.odometer - self._offsets[-1] - 0.5 * c.pitch
        w = np.clip((hs - (rear - SHIFT_BLEND)) / SHIFT_BLEND, 0.0, 1.0)
        sel = np.nonzero(w > 0)[0]
        shift_step = SHIFT_SPEED * self.motion_dt
        n_ticks = max(1, int(math.ceil(float(np.linalg.norm(move)) / shift_step)))
        inc = move / n_ticks
        for _ in range(n_ticks):
            self.path.shift(sel, w[sel], inc)
            self.command.position = self.command.position + inc
            self._set_targets()
            self._tick(None, self.motion_dt)
        self._settle(self._ticks(SHIFT_SETTLE))

    def _steer_error(self) -> float:
        """Angle between the front's heading and the commanded heading, rad."""
        r = self.data.xmat[self.robot.body_ids[0]].reshape(3, 3)
        return math.acos(max(-1.0, min(1.0, float(r[:, 0] @ self.command.heading[:, 0]))))

    def _check_steer(self) -> None:
        """Steering: jam if the walls force the front too far off its commanded heading."""
        err = self._steer_error()
        limit = self.config.jam_steer if self.command.curvature != 0.0 else self.config.jam_hold
        if err > limit:
            raise _Jam(
                f"the steering stalled: the walls force the front {math.degrees(err):.0f} deg "
                "off its commanded heading"
            )

    def _check_heading(self, step: CheckHeading) -> None:
        _, r = self._front_pose()
        cosang = float(np.clip(r[:, 0] @ self.command.heading[:, 0], -1.0, 1.0))
        err = math.acos(cosang)
        if err > step.tolerance:
            raise _Jam(
                f"the turn was blocked: heading {math.degrees(err):.0f} deg off the commanded one"
            )

    def _scan(self, on_scan: OnScan | None, rng: np.random.Generator) -> str:
        """Sweep once and ask ``on_scan``; returns its verdict (``"continue"`` without one)."""
        if self.lidar is None:
            return "continue"
        scan = self.lidar.scan(self.robot.front_pose(), rng, t0=self.time)
        self.time += self.lidar.sweep_duration
        if on_scan is None:
            return "continue"
        verdict = on_scan(scan, self.state(rng))
        if verdict not in SCAN_VERDICTS:
            raise ValueError(f"on_scan returned {verdict!r}; allowed: {SCAN_VERDICTS}")
        if verdict == "stop":
            raise _ScanStop()
        return verdict

    def aim(self, direction: NDArray[np.float64], max_angle: float = math.radians(4.0)) -> float:
        """Between drives (a scan callback): turn the drive heading towards the world
        ``direction`` by at most ``max_angle`` rad, keeping its roll; returns the angle turned.
        A robot following the pipe axis it measures (see ``PhysicalPlant``) uses this."""
        d = np.asarray(direction, dtype=float)
        n = float(np.linalg.norm(d))
        if not (math.isfinite(n) and n > 1e-9):
            raise ValueError(f"direction must be a finite non-zero 3-vector, got {d.tolist()}")
        return self.command.aim(d / n, max_angle)

    def state(self, rng: np.random.Generator | None = None) -> ExecutorState:
        return ExecutorState(
            self.time, self.odometer, self.robot.clamped_diameter(rng), self.robot.sensor_pose()
        )

    # ------------------------------------------------------------------ running
    def _begin(self) -> tuple[float, float]:
        self.telemetry = Telemetry()
        self._travelled = 0.0
        return self.time, self.odometer

    def _outcome(
        self, status: SequenceStatus, reason: str, t0: float, name: str
    ) -> SequenceOutcome:
        tele = self.telemetry.arrays()
        return SequenceOutcome(status, reason, self._travelled, self.time - t0, tele, name)

    def run(
        self,
        sequence: Sequence,
        on_scan: OnScan | None = None,
        rng: np.random.Generator | None = None,
    ) -> SequenceOutcome:
        """Execute ``sequence``; ``on_scan`` is called after each :class:`Sweep` step and may
        return ``"stop"`` to end the sequence early (status ``done``)."""
        if not isinstance(sequence, Sequence):
            raise ValueError(f"sequence must be a Sequence, got {type(sequence).__name__}")
        rng = rng if rng is not None else np.random.default_rng(0)
        t0, _ = self._begin()
        p, r = self._front_pose()
        self.command.heading = r.copy()
        self.command.hold_heading = False
        try:
            for step in sequence.steps:
                self._do(step, on_scan, rng)
        except _Jam as exc:
            self._stop_here()
            return self._outcome(SequenceStatus.JAMMED, str(exc), t0, sequence.name)
        except _Halt as h:
            return self._outcome(SequenceStatus(h.status), h.reason, t0, sequence.name)
        except _ScanStop:
            return self._outcome(SequenceStatus.DONE, "stopped by a scan", t0, sequence.name)
        return self._outcome(SequenceStatus.DONE, "", t0, sequence.name)

    def _do(self, step: Step, on_scan: OnScan | None, rng: np.random.Generator) -> None:
        if isinstance(step, Drive):
            self._drive(step)
        elif isinstance(step, Stop):
            self._settle(self._ticks(step.duration))
        elif isinstance(step, Roll):
            self._roll(step)
        elif isinstance(step, Bend):
            self._bend(step)
        elif isinstance(step, Clamp):
            self._clamp(step.diameter)
        elif isinstance(step, Unclamp):
            self._unclamp()
        elif isinstance(step, Centre):
            self._centre(step, rng)
        elif isinstance(step, Sweep):
            self._scan(on_scan, rng)
        elif isinstance(step, CheckHeading):
            self._check_heading(step)
        elif isinstance(step, Halt):
            raise _Halt(step.status, step.reason)
        else:
            raise ValueError(f"unknown primitive {step!r}")

    def _stop_here(self) -> None:
        """After a jam: hold the targets where the robot is (it stops pushing)."""
        self._lag_allowance = 0.0
        p, r = self._front_pose()
        self.command.position, self.command.rotation = p, r
        self.command.curvature = 0.0
        self.command.hold_heading = False
        d = self.data
        d.mocap_pos[self.robot.mocap_ids[0]] = p
        d.mocap_quat[self.robot.mocap_ids[0]] = quat_of(r)
        self._physics()
        self.time += self.substeps * self.model.opt.timestep

    def drive_until(
        self,
        on_scan: OnScan,
        max_distance: float,
        scan_interval: float = 0.05,
        rng: np.random.Generator | None = None,
        speed: float = 0.05,
        next_interval: Callable[[], float] | None = None,
    ) -> SequenceOutcome:
        """Stop-and-scan forward: sweep, ask ``on_scan``, drive ``scan_interval`` m, repeat,
        until ``on_scan`` says ``"stop"``, ``max_distance`` m are driven, or a jam.
        ``next_interval`` (called after every sweep's verdict) may choose each drive's length
        instead of ``scan_interval`` (m, in [1 mm, 1 m]).

        ``"rescan"`` sweeps again where the robot stands (at most ``MAX_RESCANS`` times in a
        row). At every stop the clamp encoders are read: below the reading of the last
        clamping by more than ``RECENTRE_DROP``, the robot centres and clamps again (a clamped
        robot is kept on the axis by its V; one pushed off it folds the V further)."""
        if not (math.isfinite(max_distance) and max_distance >= 0):
            raise ValueError(f"max_distance = {max_distance!r} is invalid; allowed: >= 0 m")
        if not (math.isfinite(scan_interval) and 0.001 <= scan_interval <= 1.0):
            raise ValueError(f"scan_interval = {scan_interval!r} is invalid; allowed [1 mm, 1 m]")
        rng = rng if rng is not None else np.random.default_rng(0)
        t0, odo0 = self._begin()
        clamped = self.vclamp.alpha > 0.0
        reference = self.robot.clamped_diameter() if clamped else 0.0
        try:
            while True:
                if clamped and self.robot.clamped_diameter() < reference - RECENTRE_DROP:
                    self._centre(Centre(), rng)
                    self._clamp(reference)
                    reference = self.robot.clamped_diameter()
                for _ in range(MAX_RESCANS + 1):
                    if self._scan(on_scan, rng) != "rescan":
                        break
                left = max_distance - (self.odometer - odo0)
                if left <= 1e-6:
                    return self._outcome(
                        SequenceStatus.DONE, "max distance driven", t0, "drive_until"
                    )
                interval = scan_interval
                if next_interval is not None:
                    interval = float(next_interval())
                    if not (math.isfinite(interval) and 0.001 <= interval <= 1.0):
                        raise ValueError(
                            f"next_interval() = {interval!r} is invalid; allowed [1 mm, 1 m]"
                        )
                self._drive(Drive(min(interval, left), speed))
        except _Jam as exc:
            self._stop_here()
            return self._outcome(SequenceStatus.JAMMED, str(exc), t0, "drive_until")
        except _ScanStop:
            return self._outcome(SequenceStatus.DONE, "stopped by a scan", t0, "drive_until")
