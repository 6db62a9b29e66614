"""The PIRATE-like robot: its MuJoCo bodies, its clamping geometry and its encoders.

Body (thesis 1.2, 3.1.2): a chain of ``RobotConfig.n_modules`` (>= 4) modules, 47 mm across
their wheels (the thesis's 45 mm module body with the wheels standing 1 mm proud, so the robot
cannot squeeze into a 45 mm bore: it jams at its mouth), ``pitch`` metres from joint to joint.
Between consecutive modules sits a bending joint (two hinges, ``bend_<j>_y`` and
``bend_<j>_z``, j = 1 .. n-1); the joint in the middle of the chain also carries the roll joint
``roll`` (a hinge about the chain axis), so the front half (with the front module, the LiDAR
mount and the first bending joint) can turn its bending plane towards a branch. Wheels are small
spheres at both ends of every module, on the four sides. The front module carries the LiDAR at
its front face (``RobotConfig.lidar_offset``).

Clamping (PIRATE V-shape): the two legs (``leg_modules`` modules each, held straight) either
side of the middle joint fold into a V in
the robot's x-z plane; the wheels at the apex press on one wall while the chain ends, held on the
pipe axis by the drive (see below), oppose them (they stand in for the PIRATE's wheels on the
other wall). Clamping is force controlled: the V folds until the apex wheels touch the wall with
``clamp_force`` and is then held a small preload beyond the touching shape (the executor's
``CLAMP_PRELOAD``). One robot covers 57-125 mm by changing the V half-angle ``alpha``:
``D = 2 (leg_length sin(alpha) + wheel_offset cos(alpha) + wheel_radius)``. The clamped diameter is
read back from the joint angles alone (:meth:`Robot.clamped_diameter`): forward kinematics of the
chain gives the apex wheels' distance from the line through the two end modules, so a front
module tilted by the clamping reaction does not bias it; every hinge encoder carries gaussian
noise (``encoder_noise``, radians).

Drive model (and why): the front module is pulled by a soft weld to a mocap "drive target", and
every follower module by a soft weld to the pose the front module had when it was at the
follower's place (follow-the-leader: PIRATE's joints bend as each module passes a corner). The
executor (:mod:`primitives.executor`) moves the drive target at a fixed control rate: forward
along the front module's heading, turning by the commanded bend, and re-anchored every tick
to where the walls let the front module actually be (its lateral offset and, partly, its
heading). The welds are softer than the contacts, so

- a slightly-off command is guided by the walls (the front slides and turns along them, the
  followers trace the front's real path);
- a command that drives into a wall makes the front module lag its target: past
  ``jam_lag`` (or a follower past ``jam_tracking``, or the walls forcing the steering front
  more than ``jam_steer`` / ``jam_hold`` off its commanded heading, or a turn ending more than
  ``jam_heading`` off it) the executor stops and reports a jam; a wall is never tunnelled
  because the pull is bounded by the lag limit.

Wheel-driven propulsion with friction was not chosen: it needs small time steps and careful
friction tuning to be stable in 57 mm pipes, and ~30 scenario runs per CI build need episodes
of a few wall seconds. The welds give a deterministic, fast robot (2 ms steps, 50 Hz control)
whose failures (stall, blocked bend) still come from real contacts.

Contacts: robot geoms have ``contype = 0`` and ``conaffinity = CONTACT_BIT``, so they collide
only with the contact walls (never with each other, never with the ray meshes), in their own geom
group ``ROBOT_GROUP``. The executor collides them with the wall pieces near them only
(:class:`pipe_env.world.NearContacts`: the same contacts, about half the cost of a physics step).
Gravity is compensated on the robot's bodies (the clamp carries it).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields

import mujoco
import numba
import numpy as np
from numpy.typing import NDArray

from detector.geometry import Pose
from detector.validation import fail
from pipe_env.robot_limits import ROBOT_DIAMETER_RANGE
from pipe_env.world import CONTACT_BIT

ROBOT_GROUP = 3
PREFIX = "robot/"


@dataclass(frozen=True)
class RobotConfig:
    """Robot geometry, compliance and limits. Lengths in metres, angles in radians.

    Attributes:
        n_modules: modules in the chain (>= 4).
        pitch: joint-to-joint length of a module.
        width: module diameter across the wheels (thesis 3.1.2: a 45 mm module; its wheels
            stand 1 mm proud).
        wheel_radius: radius of the wheel spheres.
        lidar_offset: LiDAR origin ahead of the front module's centre, along its axis.
        module_mass: mass of one module, kg.
        drive_solref: weld (time constant s, damping ratio) of the drive target; softer than
            the contacts (0.02 s) so walls win.
        follow_solref: weld of the follower modules to their follow-the-leader poses.
        joint_damping: damping of every joint, N m s / rad.
        clamp_force: the V stops folding when its apex wheels press the wall this hard, N.
        encoder_noise: standard deviation of the joint encoders, rad.
        jam_lag: the front module lagging its drive target by more than this is a jam, m.
        jam_tracking: a follower further than this from its follow-the-leader pose is a jam, m.
        jam_heading: a turn ending more than this off its commanded heading is a jam, rad.
        jam_steer: on a turn's arc (steering joint bent), the walls forcing the front module
            more than this off its commanded heading stall the steering joint: a jam, rad.
        jam_hold: the same while holding the turn's heading after the arc (joint straight,
            stiffer), rad.
        diameter_range: the pipe diameters the robot can clamp in, m.
    """

    n_modules: int = 6
    pitch: float = 0.045
    width: float = 0.047
    wheel_radius: float = 0.0055
    lidar_offset: float = 0.03
    module_mass: float = 0.25
    drive_solref: tuple[float, float] = (0.02, 1.0)
    follow_solref: tuple[float, float] = (0.02, 1.0)
    joint_damping: float = 0.02
    clamp_force: float = 0.5
    encoder_noise: float = math.radians(0.2)
    jam_lag: float = 0.012
    jam_tracking: float = 0.02
    jam_heading: float = math.radians(30.0)
    jam_steer: float = math.radians(25.0)
    jam_hold: float = math.radians(21.0)
    diameter_range: tuple[float, float] = ROBOT_DIAMETER_RANGE

    def __post_init__(self) -> None:
        def need(ok: bool, name: str, allowed: str) -> None:
            if not ok:
                raise fail(f"RobotConfig.{name}", getattr(self, name), allowed)

        def num(v: object) -> bool:
            return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)

        need(
            isinstance(self.n_modules, int)
            and not isinstance(self.n_modules, bool)
            and 4 <= self.n_modules <= 8,
            "n_modules",
            "an int in [4, 8]",
        )
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "n_modules":
                continue
            if isinstance(v, tuple):
                need(len(v) == 2 and all(num(x) for x in v), f.name, "two finite numbers")
            else:
                need(num(v), f.name, "a finite number")
        need(0.03 <= self.pitch <= 0.15, "pitch", "[0.03, 0.15] m")
        need(0.02 <= self.width <= 0.056, "width", "[0.02, 0.056] m (fits a 57 mm pipe)")
        need(0.001 <= self.wheel_radius <= 0.25 * self.width, "wheel_radius", "[1 mm, width/4]")
        need(0.0 <= self.lidar_offset <= 0.1, "lidar_offset", "[0, 0.1] m")
        need(0.01 <= self.module_mass <= 10.0, "module_mass", "[0.01, 10] kg")
        for name in ("drive_solref", "follow_solref"):
            tc, dr = getattr(self, name)
            need(0.004 <= tc <= 1.0 and 0.1 <= dr <= 10.0, name, "([0.004, 1] s, [0.1, 10])")
        need(0.0 <= self.joint_damping <= 10.0, "joint_damping", "[0, 10] N m s/rad")
        need(0.01 <= self.clamp_force <= 100.0, "clamp_force", "[0.01, 100] N")
        need(0.0 <= self.encoder_noise <= math.radians(5), "encoder_noise", "[0, 5 deg] rad")
        need(0.001 <= self.jam_lag <= 0.1, "jam_lag", "[0.001, 0.1] m")
        need(0.001 <= self.jam_tracking <= 0.1, "jam_tracking", "[0.001, 0.1] m")
        need(
            math.radians(1) <= self.jam_heading <= math.radians(90),
            "jam_heading",
            "[1, 90] deg in rad",
        )
        for name in ("jam_steer", "jam_hold"):
            need(
                math.radians(1) <= getattr(self, name) <= math.radians(180),
                name,
                "[1, 180] deg in rad",
            )
        lo, hi = self.diameter_range
        need(self.width < lo < hi <= 0.3, "diameter_range", "width < low < high <= 0.3 m")
        need(
            self.max_clamp_diameter >= hi,
            "pitch",
            f"a pitch whose V reaches the largest diameter {hi} m",
        )

    # ---------------------------------------------------------------- geometry
    @property
    def wheel_offset(self) -> float:
        """Radial position of the wheel centres, m."""
        return 0.5 * self.width - self.wheel_radius

    @property
    def body_radius(self) -> float:
        """Radius of a module's capsule (inside the wheels), m."""
        return self.wheel_offset + 0.3 * self.wheel_radius

    @property
    def length(self) -> float:
        """Robot length from the rear of the last module to the LiDAR, m."""
        return self.n_modules * self.pitch - 0.5 * self.pitch + self.lidar_offset + 0.5 * self.pitch

    @property
    def leg_modules(self) -> int:
        """Modules in each leg of the clamping V."""
        return max(1, (self.n_modules - 2) // 2)

    @property
    def leg_length(self) -> float:
        """Joint-to-joint length of a leg of the V, m."""
        return self.leg_modules * self.pitch

    @property
    def middle_joint(self) -> int:
        """Index (1-based) of the joint carrying the roll joint and the V apex."""
        return self.n_modules // 2

    def clamp_diameter_at(self, alpha: float) -> float:
        """Pipe diameter a V of half-angle ``alpha`` (rad) spans, m."""
        return 2.0 * (
            self.leg_length * math.sin(alpha)
            + self.wheel_offset * math.cos(alpha)
            + self.wheel_radius
        )

    @property
    def max_clamp_diameter(self) -> float:
        return self.clamp_diameter_at(math.radians(75.0))

    def clamp_angle(self, diameter: float) -> float:
        """V half-angle (rad) that spans ``diameter`` metres (0 for a pipe the robot fills)."""
        if diameter <= self.width:
            return 0.0
        lo, hi = 0.0, math.radians(75.0)
        if self.clamp_diameter_at(hi) <= diameter:
            return hi
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            if self.clamp_diameter_at(mid) < diameter:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def to_dict(self) -> dict:
        return asdict(self)


class Robot:
    """The robot inside a compiled world: body ids, sensor pose, encoders.

    Build it with :func:`add_robot` (a ``customize`` hook for
    :func:`pipe_env.world.build_world`), then :meth:`bind` it to the compiled world.
    """

    def __init__(self, config: RobotConfig | None = None) -> None:
        if config is not None and not isinstance(config, RobotConfig):
            raise fail("config", config, "a RobotConfig", f"a {type(config).__name__}")
        self.config = config or RobotConfig()
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None

    # ------------------------------------------------------------------ names
    @staticmethod
    def module_name(i: int) -> str:
        return f"{PREFIX}module{i}"

    @staticmethod
    def target_name(i: int) -> str:
        return f"{PREFIX}target{i}"

    def joint_names(self) -> list[str]:
        """Hinge joint names from front to rear."""
        names = []
        for j in range(1, self.config.n_modules):
            if j == self.config.middle_joint:
                names.append(f"{PREFIX}roll")
            names += [f"{PREFIX}bend_{j}_y", f"{PREFIX}bend_{j}_z"]
        return names

    # ------------------------------------------------------------------ build
    def customize(self, spec: mujoco.MjSpec) -> None:
        """Add the robot's bodies, mocap drive targets and welds to ``spec``."""
        c = self.config
        spec.option.gravity = [0.0, 0.0, -9.81]
        parent = spec.worldbody
        r = c.body_radius
        half = max(0.5 * c.pitch - r - 0.002, 0.001)
        inertia_r = 0.5 * c.width
        for i in range(c.n_modules):
            b = parent.add_body()
            b.name = self.module_name(i)
            b.gravcomp = 1.0
            b.mass = c.module_mass
            b.inertia = [
                0.5 * c.module_mass * inertia_r**2,
                c.module_mass * (3 * inertia_r**2 + c.pitch**2) / 12,
                c.module_mass * (3 * inertia_r**2 + c.pitch**2) / 12,
            ]
            b.explicitinertial = True
            if i == 0:
                j = b.add_freejoint()
                j.name = f"{PREFIX}free"
            else:
                b.pos = [-c.pitch, 0.0, 0.0]
                if i == c.middle_joint:
                    self._hinge(b, f"{PREFIX}roll", [1, 0, 0], 0.5 * c.pitch, c.joint_damping)
                self._hinge(b, f"{PREFIX}bend_{i}_y", [0, 1, 0], 0.5 * c.pitch, c.joint_damping)
                self._hinge(b, f"{PREFIX}bend_{i}_z", [0, 0, 1], 0.5 * c.pitch, c.joint_damping)
            g = b.add_geom()
            g.name = f"{PREFIX}body{i}"
            g.type = mujoco.mjtGeom.mjGEOM_CAPSULE
            g.fromto = [-half, 0, 0, half, 0, 0]
            g.size = [r, 0, 0]
            self._style(g, (0.85, 0.45, 0.1, 1.0) if i == 0 else (0.9, 0.7, 0.2, 1.0))
            for end in (-1, 1):
                x = end * 0.5 * c.pitch
                for k, (dy, dz) in enumerate(((1, 0), (0, 1), (-1, 0), (0, -1))):
                    w = b.add_geom()
                    w.name = f"{PREFIX}wheel{i}_{'f' if end > 0 else 'r'}{k}"
                    w.type = mujoco.mjtGeom.mjGEOM_SPHERE
                    w.size = [c.wheel_radius, 0, 0]
                    w.pos = [x, dy * c.wheel_offset, dz * c.wheel_offset]
                    self._style(w, (0.15, 0.15, 0.15, 1.0))
            parent = b
        for i in range(c.n_modules):
            t = spec.worldbody.add_body()
            t.name = self.target_name(i)
            t.mocap = True
            e = spec.add_equality()
            e.name = f"{PREFIX}weld{i}"
            e.type = mujoco.mjtEq.mjEQ_WELD
            e.objtype = mujoco.mjtObj.mjOBJ_BODY
            e.name1 = self.module_name(i)
            e.name2 = self.target_name(i)
            data = np.zeros(12)
            data[6] = 1.0
            data[10] = 1.0
            e.data = data.tolist()
            e.solref = list(c.drive_solref if i == 0 else c.follow_solref)

    @staticmethod
    def _hinge(b: mujoco.MjsBody, name: str, axis: list[int], x: float, damping: float) -> None:
        j = b.add_joint()
        j.name = name
        j.type = mujoco.mjtJoint.mjJNT_HINGE
        j.axis = axis
        j.pos = [x, 0.0, 0.0]
        j.damping = [damping, 0.0, 0.0]
        j.armature = 1e-4

    @staticmethod
    def _style(g: mujoco.MjsGeom, rgba: tuple[float, ...]) -> None:
        g.contype = 0
        g.conaffinity = CONTACT_BIT
        g.group = ROBOT_GROUP
        g.rgba = list(rgba)
        g.friction = [0.05, 0.005, 0.0001]
        g.condim = 3
        g.solref = [0.005, 1.0]
        g.solmix = 100.0

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Look up ids in the compiled model."""
        c = self.config
        self.model, self.data = model, data
        self.body_ids = np.array(
            [
                mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, self.module_name(i))
                for i in range(c.n_modules)
            ]
        )
        self.mocap_ids = np.array(
            [
                model.body_mocapid[
                    mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, self.target_name(i))
                ]
                for i in range(c.n_modules)
            ]
        )
        jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.joint_names()]
        self.joint_qpos = np.array([model.jnt_qposadr[j] for j in jids])
        free = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{PREFIX}free")
        self.free_qpos = int(model.jnt_qposadr[free])
        self.free_dof = int(model.jnt_dofadr[free])
        self.geom_ids = np.array(
            [g for g in range(model.ngeom) if model.geom_bodyid[g] in set(self.body_ids.tolist())]
        )
        self._robot_geom = np.zeros(model.ngeom, dtype=bool)
        self._robot_geom[self.geom_ids] = True
        j = c.middle_joint
        # the V's apex: the wheels at the rear of module j-1 and the front of module j (the
        # V folds towards any side; towards -z in the path frame when clamping)
        apex = [f"{PREFIX}wheel{j - 1}_r{k}" for k in range(4)]
        apex += [f"{PREFIX}wheel{j}_f{k}" for k in range(4)]
        #: side of each apex wheel (0: +y, 1: +z, 2: -y, 3: -z in its module), -1 elsewhere
        self._apex_side = np.full(model.ngeom, -1, dtype=int)
        for n in apex:
            self._apex_side[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n)] = int(n[-1])
        self._roll_qpos = int(
            model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{PREFIX}roll")]
        )

    def _need_bound(self) -> mujoco.MjData:
        if self.data is None:
            raise RuntimeError("the robot is not in a compiled world yet; call bind()")
        return self.data

    # ------------------------------------------------------------------ state
    def module_pose(self, i: int) -> Pose:
        """World pose of module ``i`` (0 = front)."""
        d = self._need_bound()
        b = self.body_ids[i]
        return Pose.trusted(d.xpos[b].copy(), d.xmat[b].reshape(3, 3).copy())

    def front_pose(self) -> Pose:
        """World pose of the front module's centre (the LiDAR carrier)."""
        return self.module_pose(0)

    @property
    def lidar_mount(self) -> Pose:
        """Nominal LiDAR pose in the front module's frame."""
        return Pose.trusted(np.array([self.config.lidar_offset, 0.0, 0.0]), np.eye(3))

    def sensor_pose(self) -> Pose:
        """Nominal LiDAR pose in the world (front module pose composed with the mount)."""
        f = self.front_pose()
        return Pose.trusted(f.position + self.config.lidar_offset * f.rotation[:, 0], f.rotation)

    def joint_angles(self) -> NDArray[np.float64]:
        """Hinge angles in :meth:`joint_names` order, rad."""
        d = self._need_bound()
        return d.qpos[self.joint_qpos].copy()

    @property
    def roll_angle(self) -> float:
        """Angle of the middle roll joint, rad."""
        return float(self._need_bound().qpos[self._roll_qpos])

    def clamped_diameter(self, rng: np.random.Generator | None = None) -> float:
        """Pipe diameter spanned by the clamping V, m, read from the joint encoders alone.

        Forward kinematics of the chain (module pitch, joint anchors, wheel offsets) from the
        hinge angles gives the apex wheels' distance from the line through the two end
        modules' centres (which the drive holds on the pipe axis); the diameter is twice that
        distance plus the wheel radius. The line, not the front module's axis, is the
        reference, so a tilted front module does not bias the reading. With ``rng``, every
        hinge angle carries gaussian encoder noise (``encoder_noise``, rad)."""
        d = self._need_bound()
        q = d.qpos[self.joint_qpos].astype(float)
        c = self.config
        if rng is not None and c.encoder_noise > 0:
            q = q + rng.normal(0.0, c.encoder_noise, size=q.shape)
        return self.diameter_from_angles(q)

    def diameter_from_angles(self, angles: NDArray[np.float64]) -> float:
        """Clamped diameter (m) of the V described by hinge ``angles`` (:meth:`joint_names`
        order, rad): forward kinematics, see :meth:`clamped_diameter`."""
        c = self.config
        pos, rot = chain_kinematics(c, np.asarray(angles, dtype=float))
        a, b = pos[0], pos[-1]
        axis = b - a
        n = float(np.linalg.norm(axis))
        axis = axis / n if n > 1e-9 else np.array([-1.0, 0.0, 0.0])
        j = c.middle_joint
        best = 0.0
        for i, end in ((j - 1, -1.0), (j, 1.0)):
            for dy, dz in ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)):
                local = np.array([end * 0.5 * c.pitch, dy * c.wheel_offset, dz * c.wheel_offset])
                rel = pos[i] + rot[i] @ local - a
                best = max(best, float(np.linalg.norm(rel - (rel @ axis) * axis)))
        return 2.0 * max(best + c.wheel_radius, 0.5 * c.width)

    def apex_force(self, side: int = 3) -> float:
        """Normal force on the V's apex wheels on ``side`` (0: +y, 1: +z, 2: -y, 3: -z, the
        clamping side) against the wall, N."""
        m, d = self.model, self._need_bound()
        total = 0.0
        f6 = np.zeros(6)
        for k in range(d.ncon):
            con = d.contact[k]
            if self._apex_side[con.geom1] == side or self._apex_side[con.geom2] == side:
                mujoco.mj_contactForce(m, d, k, f6)
                total += abs(f6[0])
        return total

    def contact_force(self) -> float:
        """Sum of the normal forces of the robot's contacts with the walls, N (in one compiled
        pass over the contacts: ``mj_contactForce``'s normal force, bit for bit)."""
        d = self._need_bound()
        if d.ncon == 0:
            return 0.0
        con = d.contact
        pyramidal = d.model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
        return _normal_force_sum(
            con.geom, con.efc_address, con.dim, d.efc_force, self._robot_geom, pyramidal
        )


@numba.njit(cache=True, error_model="numpy")
def _normal_force_sum(
    geom: NDArray[np.int32],
    efc_address: NDArray[np.int32],
    dim: NDArray[np.int32],
    efc_force: NDArray[np.float64],
    selected: NDArray[np.bool_],
    pyramidal: bool,
) -> float:
    """Sum of the absolute normal forces (N) of the contacts (``geom`` (C, 2), their
    ``efc_address`` and ``dim``) with a ``selected`` geom, in contact order: the normal force
    as ``mj_contactForce`` computes it (a pyramidal cone's edge forces summed in order; an
    elliptic cone's first component; none for a contact without constraint rows)."""
    total = 0.0
    for k in range(geom.shape[0]):
        if not (selected[geom[k, 0]] or selected[geom[k, 1]]):
            continue
        adr = efc_address[k]
        normal = 0.0
        if adr >= 0:
            if pyramidal and dim[k] > 1:
                for i in range(2 * (dim[k] - 1)):
                    normal += efc_force[adr + i]
            else:
                normal = efc_force[adr]
        total += abs(normal)
    return total


def chain_kinematics(
    config: RobotConfig, angles: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Module centres (n, 3) and rotations (n, 3, 3) in the front module's frame for hinge
    ``angles`` (:meth:`Robot.joint_names` order, rad), as MuJoCo composes the hinges."""
    c = config
    n = c.n_modules
    pos = np.zeros((n, 3))
    rot = np.zeros((n, 3, 3))
    rot[0] = np.eye(3)
    anchor_local = np.array([0.5 * c.pitch, 0.0, 0.0])
    k = 0
    for i in range(1, n):
        r = rot[i - 1].copy()
        p = pos[i - 1] + r @ np.array([-c.pitch, 0.0, 0.0])
        axes = ([0] if i == c.middle_joint else []) + [1, 2]
        for ax in axes:
            anchor = p + r @ anchor_local
            r = r @ _axis_rot(ax, float(angles[k]))
            k += 1
            p = anchor - r @ anchor_local
        pos[i], rot[i] = p, r
    return pos, rot


def _axis_rot(axis: int, a: float) -> NDArray[np.float64]:
    c, s = math.cos(a), math.sin(a)
    if axis == 0:
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    if axis == 1:
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quat_of(rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    """MuJoCo quaternion (w, x, y, z) of a rotation matrix."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rotation, dtype=float).ravel())
    return q
