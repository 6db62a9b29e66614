"""The MuJoCo world of a pipe network, built with ``mujoco.MjSpec``.

Two geom groups line every pipe:

- ``WALL_GROUP``: one watertight CSG triangle mesh per run and per fitting
  (:mod:`pipe_env.meshes`), ``contype = conaffinity = 0``. These are what LiDAR rays hit
  (``mj_multiRay`` restricted to this group) and what renders show.
- ``CONTACT_GROUP``: convex pieces (:mod:`pipe_env.contact_walls`), invisible (alpha 0), which
  collide with geoms whose ``conaffinity`` has bit ``CONTACT_BIT`` set (the robot's).

Collision pairs near a moving body (:class:`NearContacts`): with all ~1,250 pieces colliding
automatically, MuJoCo's midphase tests every robot geom against every piece of the pipe around it
(long panels have large bounding spheres) at every physics step, about half of a step's cost. A
world with contact walls therefore also holds a pool of ``CONTACT_PAIR_POOL`` predefined geom
pairs (parked on two far-away dummy spheres). :class:`NearContacts` fills the pool with the pairs
(robot geom, wall piece) whose pieces lie within a reach of the geoms, with MuJoCo's own mixed
contact parameters, and switches the world body's automatic collisions off; it selects the
pairs again only when a geom can have come near a piece it is not paired with (each geom's
clearance, measured again first: moving along a pipe keeps it), and falls back to automatic
collisions if the pool is too small. The contacts are the same as the automatic ones (tests
compare them).

The wall geoms never move: MuJoCo poses them once, not at every physics step (its sleeping is
on, with every moving body kept awake; see :func:`_static_walls_posed_once`).

Open ends do not exist: every leaf of a network is a closure with an end wall, so rays cannot
escape. Callers can add bodies (a robot) through the ``customize`` hook before compilation.

Ray meshes on demand: a world for physics whose LiDAR casts rays analytically
(:mod:`pipe_env.raycast_analytic`) needs no ray meshes, and they are about half the cost of
building a world (the CSG and their compilation). ``build_world(..., ray_meshes=False)`` leaves
them out of the model; every other geom, body, joint and pair is the one of the world with them
(geom ids lower by the number of ray meshes, which come first), so the physics is the same bit
for bit. Their consumers (renders, MJCF export, the MuJoCo ray caster) ask
:meth:`PipeWorld.complete`: the same world with the ray meshes, built on first use, in this
world's state.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numba
import numpy as np
from numpy.typing import NDArray

from detector.validation import check_bool, check_number, fail
from pipe_env.contact_walls import BoxPanel, HullPiece, fitting_pieces, run_panels
from pipe_env.meshes import TriangleMesh, fitting_shell, run_shell, to_triangle_mesh
from pipe_env.network import PipeNetwork

WALL_GROUP = 1
CONTACT_GROUP = 2
#: contype bit of the contact walls; robot geoms set this bit in their conaffinity.
CONTACT_BIT = 1
WALL_RGBA = (0.62, 0.64, 0.68, 0.45)
#: The physics step, s (the default of :func:`build_world`'s ``timestep``). Measured with
#: ``benchmarks/physics_step_study.py``: 3 ms steps hold only up to 60 ms control periods (no
#: margin) and 4 ms or more let the robot's front into a bore it must stall before; 2 ms stays.
TIMESTEP = 0.002
#: Physics steps a world may be built with, s (a study of larger steps: see
#: ``benchmarks/physics_step_study.py``).
TIMESTEP_RANGE = (0.0005, 0.01)
#: Predefined geom pairs a world with contact walls holds for :class:`NearContacts`.
CONTACT_PAIR_POOL = 160
#: Names of the two far-away dummy spheres unused pairs point at.
_PARK = ("park:a", "park:b")


@dataclass(eq=False)
class PipeWorld:
    """A compiled MuJoCo world of a network.

    Attributes:
        network: the network it was built from.
        spec: the ``mujoco.MjSpec`` (kept for recompilation with extra bodies).
        model, data: the compiled model and its data.
        wall_group: geom group of the ray meshes.
        contact_group: geom group of the contact walls.
        wall_geoms: geom id -> network element id (``run:<id>`` or ``fitting:<id>``).
        triangle_count: triangles in all ray meshes.
        contact_geom_count: contact-wall geoms.
        has_ray_meshes: whether ``model`` holds the ray meshes (see :meth:`complete`).
    """

    network: PipeNetwork
    spec: mujoco.MjSpec
    model: mujoco.MjModel
    data: mujoco.MjData
    wall_group: int = WALL_GROUP
    contact_group: int = CONTACT_GROUP
    wall_geoms: dict[int, str] = field(default_factory=dict)
    triangle_count: int = 0
    contact_geom_count: int = 0
    has_ray_meshes: bool = True
    #: builds the same world with its ray meshes (a world built without them), and that world
    _rebuild: Callable[[], PipeWorld] | None = field(default=None, repr=False)
    _complete: PipeWorld | None = field(default=None, repr=False)

    def complete(self) -> PipeWorld:
        """This world with its ray meshes, in this world's state, for their consumers (renders,
        MJCF export, the MuJoCo ray caster).

        A world built with them (the default) returns itself. A world built with
        ``ray_meshes=False`` builds, on the first call, the same world (network, contact walls,
        ``customize``, timestep) with them, and keeps it; every call sets that world's state
        (time, ``qpos``, ``qvel``, ``act``, ``ctrl``, mocap poses) to this world's and runs
        ``mj_forward`` on it (the two models have the same bodies, joints and actuators)."""
        if self.has_ray_meshes:
            return self
        if self._complete is None:
            if self._rebuild is None:
                raise fail(
                    "ray_meshes",
                    False,
                    "a world built with ray meshes, or by build_world (which can rebuild it)",
                    "no ray meshes and no way to build them",
                    where="PipeWorld.complete",
                )
            self._complete = self._rebuild()
        full = self._complete
        src, dst = self.data, full.data
        dst.time = src.time
        for name in ("qpos", "qvel", "act", "ctrl", "mocap_pos", "mocap_quat"):
            getattr(dst, name)[:] = getattr(src, name)
        mujoco.mj_forward(full.model, dst)
        return full

    @property
    def ray_geomgroup(self) -> NDArray[np.uint8]:
        """Geom-group mask selecting only the ray meshes (for ``mj_ray``/``mj_multiRay``)."""
        mask = np.zeros(6, dtype=np.uint8)
        mask[self.wall_group] = 1
        return mask

    def reset(self) -> None:
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)


def network_meshes(network: PipeNetwork) -> list[TriangleMesh]:
    """CSG ray meshes of every run (with a straight part) and every fitting."""
    meshes = []
    for r in network.runs:
        if network.straight_length(r.id) <= 1e-6:
            continue
        pa = network.geometry[r.a].port(r.id).position
        pb = network.geometry[r.b].port(r.id).position
        meshes.append(to_triangle_mesh(f"run:{r.id}", run_shell(pa, pb, r.diameter)))
    for f in network.fittings:
        meshes.append(to_triangle_mesh(f"fitting:{f.id}", fitting_shell(network.geometry[f.id])))
    return meshes


def network_contact_pieces(
    network: PipeNetwork,
) -> list[tuple[str, list[HullPiece], list[BoxPanel]]]:
    """Contact pieces per element: (element id, hull pieces, box panels)."""
    out: list[tuple[str, list[HullPiece], list[BoxPanel]]] = []
    for r in network.runs:
        if network.straight_length(r.id) <= 1e-6:
            continue
        pa = network.geometry[r.a].port(r.id).position
        pb = network.geometry[r.b].port(r.id).position
        out.append((f"run:{r.id}", [], run_panels(pa, pb, r.diameter)))
    for f in network.fittings:
        hulls, boxes = fitting_pieces(network.geometry[f.id])
        out.append((f"fitting:{f.id}", hulls, boxes))
    return out


def _quat(rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rotation).ravel())
    return q


def build_world(
    network: PipeNetwork,
    *,
    contact_walls: bool = True,
    customize: Callable[[mujoco.MjSpec], None] | None = None,
    timestep: float = TIMESTEP,
    ray_meshes: bool = True,
) -> PipeWorld:
    """Compile ``network`` into a MuJoCo world (see module docstring).

    Args:
        network: a valid network (validated here).
        contact_walls: add the contact walls (skip them for sensing-only worlds).
        customize: called with the spec before compiling, to add bodies such as a robot.
        timestep: the physics step, s, in :data:`TIMESTEP_RANGE`.
        ray_meshes: add the ray meshes; False leaves them out (built on demand by
            :meth:`PipeWorld.complete`; see the module docstring).
    """
    timestep = check_number("timestep", timestep, *TIMESTEP_RANGE, unit="s", where="build_world")
    contact_walls = check_bool("contact_walls", contact_walls, where="build_world")
    ray_meshes = check_bool("ray_meshes", ray_meshes, where="build_world")
    network.validate()
    spec = mujoco.MjSpec()
    spec.modelname = f"pipenav_{network.name}"
    spec.option.timestep = timestep
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.6, 0.6, 0.6]
    spec.stat.extent = float(np.linalg.norm(np.subtract(*network.bounds()[::-1])))
    spec.stat.center = (0.5 * np.add(*network.bounds())).tolist()
    triangles = _add_ray_meshes(spec, network) if ray_meshes else 0
    n_contact = _add_contact_walls(spec, network) if contact_walls else 0
    if customize is not None:
        customize(spec)
    _static_walls_posed_once(spec)
    _no_island_discovery(spec)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    wall_geoms = {}
    for gid in range(model.ngeom if ray_meshes else 0):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, gid) or ""
        if name.startswith("wall:"):
            wall_geoms[gid] = name[len("wall:") :]
    rebuild = None
    if not ray_meshes:
        rebuild = functools.partial(
            build_world,
            network,
            contact_walls=contact_walls,
            customize=customize,
            timestep=timestep,
        )
    return PipeWorld(
        network,
        spec,
        model,
        data,
        WALL_GROUP,
        CONTACT_GROUP,
        wall_geoms,
        triangles,
        n_contact,
        has_ray_meshes=bool(ray_meshes),
        _rebuild=rebuild,
    )


def _add_ray_meshes(spec: mujoco.MjSpec, network: PipeNetwork) -> int:
    """Add the ray meshes (one mesh geom per element, ``WALL_GROUP``, no contacts) to the
    world body of ``spec``; returns their triangle count."""
    world = spec.worldbody
    triangles = 0
    for k, mesh in enumerate(network_meshes(network)):
        mname = f"wall_{k}"
        m = spec.add_mesh()
        m.name = mname
        m.uservert = mesh.vertices.ravel().tolist()
        m.userface = mesh.faces.ravel().tolist()
        g = world.add_geom()
        g.name = f"wall:{mesh.name}"
        g.type = mujoco.mjtGeom.mjGEOM_MESH
        g.meshname = mname
        g.group = WALL_GROUP
        g.contype = 0
        g.conaffinity = 0
        g.rgba = WALL_RGBA
        triangles += len(mesh.faces)
    return triangles


def _add_contact_walls(spec: mujoco.MjSpec, network: PipeNetwork) -> int:
    """Add the contact walls (box panels and hull pieces, element by element), the two parking
    spheres and the pool of predefined pairs to ``spec``; returns the contact geoms' count."""
    world = spec.worldbody
    box_type, mesh_type = mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_MESH
    n_contact = 0
    for _, hulls, boxes in network_contact_pieces(network):
        for box in boxes:
            g = world.add_geom()
            g.type = box_type
            g.size = box.half_size.tolist()
            g.pos = box.centre.tolist()
            g.quat = _quat(box.rotation).tolist()
            _contact_style(g)
            n_contact += 1
        for piece in hulls:
            mname = f"contact_{n_contact}"
            m = spec.add_mesh()
            m.name = mname
            m.uservert = piece.points.ravel().tolist()
            g = world.add_geom()
            g.type = mesh_type
            g.meshname = mname
            _contact_style(g)
            n_contact += 1
    for k, name in enumerate(_PARK):
        g = world.add_geom()
        g.name = name
        g.type = mujoco.mjtGeom.mjGEOM_SPHERE
        g.size = [1e-4, 0.0, 0.0]
        g.pos = [1e4 + 10.0 * k, 1e4, 1e4]
        g.group = 5
        g.contype = 0
        g.conaffinity = 0
        g.rgba = [0.0, 0.0, 0.0, 0.0]
    for _ in range(CONTACT_PAIR_POOL):
        pair = spec.add_pair()
        pair.geomname1, pair.geomname2 = _PARK
    return n_contact


def _static_walls_posed_once(spec: mujoco.MjSpec) -> None:
    """Let MuJoCo pose the static wall geoms once instead of at every physics step.

    With sleeping enabled, MuJoCo computes the poses of geoms on static bodies (the world
    body: every wall piece) once and skips them in the kinematics of later steps; with
    ~1,300 wall geoms that was about 40 % of an mj_step. Every moving body tree (the
    robot) is kept awake (``mjSLEEP_NEVER``), so nothing else changes: the dynamics are
    bit-for-bit those without sleeping (a test compares trajectories).
    """
    spec.option.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    for body in spec.worldbody.bodies:
        if body.joints:  # (a tree that can move; static and mocap bodies have no policy)
            body.sleep = mujoco.mjtSleepPolicy.mjSLEEP_NEVER


def _no_island_discovery(spec: mujoco.MjSpec) -> None:
    """Switch MuJoCo's constraint island discovery off.

    Islands let the solver treat independent groups of constrained bodies apart; a world has one
    moving tree (the robot, its modules held by welds to their targets), so there is one island
    and finding it is pure cost: about 4-10 % of an mj_step (``benchmarks/bench_step_cost.py``;
    one Newton iteration solves a step, so the solver's own settings change nothing). The
    trajectories are bit for bit those with islands (the benchmark and a test compare them);
    sleeping (:func:`_static_walls_posed_once`) works without islands.
    """
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ISLAND)


def _contact_style(g: mujoco.MjsGeom) -> None:
    g.group = CONTACT_GROUP
    g.contype = CONTACT_BIT
    g.conaffinity = 0
    g.rgba = [0.3, 0.5, 0.8, 0.0]
    g.friction = [0.6, 0.005, 0.0001]


class NearContacts:
    """Collides ``geoms`` (a moving body's, e.g. the robot's) only with the contact-wall pieces
    near them, through the world's pool of predefined pairs (see the module docstring).

    Call :meth:`update` before every physics interval (e.g. a control tick) and after moving the
    geoms by hand. A piece is paired with a geom when the piece's bounding box (in its own frame)
    lies within ``reach`` of the geom's bounding sphere. Every selection also notes each geom's
    clearance: the distance from its bounding sphere to the nearest piece it is not paired with
    (more than ``reach``; the pieces beyond the coarse selection count at their bound), less the
    pairs' contact margin. A geom can touch an unpaired piece only after moving by its
    clearance. Before any geom can have moved by its clearance since the last measurement,
    judged from the largest motion of any geom over the last interval (``guard`` times it, plus
    ``slack``), the clearances are measured again with the pairs kept (``remeasures``); only if a
    geom has come within that guarded motion plus another ``slack`` of a piece it is not
    paired with are the pairs selected again (``selections``). Driving along a pipe the geoms move
    along the panels, not towards them, so pairs are selected again mostly when a new piece (a
    fitting's) comes near. If a geom still moved further than its clearance over an interval,
    ``overruns`` counts it (a contact could have been missed). Pairs kept from a selection
    whose pieces have moved away change no contact (a pair of geoms apart has none). More
    pairs than the pool holds: automatic collisions (``fallbacks``) until the geoms have moved
    by ``reach``.

    Args:
        world: a world built with contact walls.
        geoms: geom ids of the moving body.
        reach: selection distance, m.
    """

    def __init__(
        self,
        world: PipeWorld,
        geoms: NDArray[np.int_],
        reach: float = 0.006,
        guard: float = 2.0,
        slack: float = 0.001,
    ) -> None:
        m, d = world.model, world.data
        if m.npair < CONTACT_PAIR_POOL:
            raise ValueError(
                f"the world holds {m.npair} predefined pairs; NearContacts needs "
                f"{CONTACT_PAIR_POOL} (a world built with contact_walls=True)"
            )
        check_number("reach", reach, 0.001, 0.1, "m", where="NearContacts")
        self.world = world
        self.model = m
        self.geoms = np.asarray(geoms, dtype=int)
        self.reach = float(reach)
        self.guard = float(guard)
        self.slack = float(slack)
        walls = np.flatnonzero(
            (m.geom_group == world.contact_group) & ((m.geom_contype & CONTACT_BIT) != 0)
        )
        if not np.all(m.geom_bodyid[walls] == 0):
            raise ValueError("NearContacts needs the contact walls in the world body")
        self.walls = walls
        rot = d.geom_xmat[walls].reshape(-1, 3, 3).copy()
        self._rot = rot
        self._centre = d.geom_xpos[walls] + np.einsum("kij,kj->ki", rot, m.geom_aabb[walls, :3])
        self._half = m.geom_aabb[walls, 3:].copy()
        self._bound = np.linalg.norm(self._half, axis=1)
        self._radius = m.geom_rbound[self.geoms].copy()
        self._pool = np.arange(CONTACT_PAIR_POOL)
        self._park = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n) for n in _PARK]
        self._auto_contype = int(CONTACT_BIT)
        # with pairs only, the geoms' bodies need no broad phase either
        self._bodies = np.unique(m.geom_bodyid[self.geoms])
        self._bodies = self._bodies[self._bodies > 0]
        # as compiled: the union of the body's geoms' bits (another instance may have zeroed it)
        self._auto_conaffinity = np.array(
            [np.bitwise_or.reduce(m.geom_conaffinity[m.geom_bodyid == b]) for b in self._bodies],
            dtype=m.body_conaffinity.dtype,
        )
        self._anchor: NDArray[np.float64] | None = None
        self._last: NDArray[np.float64] | None = None
        self._motion = 0.0
        #: each geom's clearance at the last selection, m (``reach`` after a fallback)
        self._clearance = np.full(len(self.geoms), self.reach)
        #: the largest contact margin of a (geom, piece) pair, m
        self._margin = float(m.geom_margin[self.geoms].max(initial=0.0)) + float(
            m.geom_margin[walls].max(initial=0.0)
        )
        self._pairs: tuple[NDArray[np.int_], NDArray[np.int_]] | None = None
        # the coarse selection: (geom positions when made, piece indices, their centres,
        # rotations and half sizes)
        self._coarse: (
            tuple[
                NDArray[np.float64],
                NDArray[np.intp],
                NDArray[np.float64],
                NDArray[np.float64],
                NDArray[np.float64],
            ]
            | None
        ) = None
        #: which (geom, coarse piece) the pairs hold, (G, K)
        self._paired: NDArray[np.bool_] | None = None
        self.n_pairs = 0
        #: pair selections; clearances measured again with the pairs kept
        self.remeasures = 0
        self.selections = 0
        self.fallbacks = 0
        self.overruns = 0

    def disable(self) -> None:
        """Back to automatic collisions with every piece (the pool parked)."""
        m = self.model
        m.pair_geom1[self._pool] = self._park[0]
        m.pair_geom2[self._pool] = self._park[1]
        m.body_contype[0] = self._auto_contype
        m.body_conaffinity[self._bodies] = self._auto_conaffinity
        self._anchor = None
        self._last = None
        self._pairs = None
        self._paired = None
        self.n_pairs = 0

    def forget(self) -> None:
        """Forget the geoms' motion history (the robot was placed anew): the next
        :meth:`update` selects from scratch, as on a new instance."""
        self._anchor = None
        self._last = None
        self._motion = 0.0
        self._coarse = None

    def update(self, data: mujoco.MjData, force: bool = False) -> None:
        """Select the pairs again if the geoms may come within reach of unpaired pieces before
        the next call (``data.geom_xpos`` must be current); always with ``force``."""
        xp = data.geom_xpos[self.geoms]
        last, anchor = self._last, self._anchor
        self._last = xp
        if last is None or anchor is None:
            if last is not None:
                self._motion = _moved(xp, last)
            self._select(xp)
            return
        motion, overrun, select = _motion_check(
            xp, last, anchor, self._clearance, self.guard, self.slack
        )
        self._motion = motion
        if force:
            self._select(xp)
            return
        on_pairs = self.model.body_contype[0] == 0
        if overrun and on_pairs:
            self.overruns += 1  # on pairs (not fallen back), a contact may have been missed
        if select and not (on_pairs and self._remeasure(xp)):
            self._select(xp)

    def _remeasure(self, xp: NDArray[np.float64]) -> bool:
        """Measure the clearances of the current pairs again at ``xp`` (the geoms moved, but
        maybe along the pieces, not towards them); True, and the pairs kept, if every geom
        stays further than the guarded motion plus another ``slack`` from the pieces it is not
        paired with; False if the pairs must be selected again."""
        if self._coarse is None or self._paired is None:
            return False
        if _moved(xp, self._coarse[0]) > _COARSE - self.reach:
            return False  # the coarse pieces no longer hold every piece near the geoms
        _, _, centre, rot, half = self._coarse
        clearance = self._clearances(xp, _box_distances2(xp, rot, centre, half), self._paired)
        ahead = self.guard * self._motion + self.slack
        if not bool(np.all(clearance >= ahead + self.slack)):
            return False
        self._clearance = clearance
        self._anchor = xp
        self.remeasures += 1
        return True

    def _select(self, xp: NDArray[np.float64]) -> None:
        m = self.model
        self.selections += 1
        r = self._radius + self.reach
        if self._coarse is None or _moved(xp, self._coarse[0]) > _COARSE - self.reach:
            # the pieces whose bounding spheres meet the geoms' box grown by _COARSE: kept until
            # a geom has moved further than that
            c, b = self._centre, self._bound
            lo = (xp - r[:, None]).min(axis=0) - _COARSE
            hi = (xp + r[:, None]).max(axis=0) + _COARSE
            near = np.flatnonzero(((c + b[:, None] >= lo) & (c - b[:, None] <= hi)).all(axis=1))
            self._coarse = (xp, near, c[near], self._rot[near], self._half[near])
        _, near, centre, rot, half = self._coarse
        dist2 = _box_distances2(xp, rot, centre, half)  # (G, K)
        paired = dist2 <= (r * r)[:, None]
        gi, ki = np.nonzero(paired)
        pieces = near[ki]
        n = len(gi)
        if n > len(self._pool):
            self.fallbacks += 1
            self.disable()
            self._anchor = xp
            self._last = xp
            self._clearance = np.full(len(self.geoms), self.reach)
            self._paired = None
            return
        self._clearance = self._clearances(xp, dist2, paired)
        self._paired = paired
        g1 = self.geoms[gi]
        g2 = self.walls[pieces]
        # MuJoCo's order of automatic contacts: by body pair, then geom ids
        order = np.lexsort((g2, g1, m.geom_bodyid[g1]))
        g1, g2 = g1[order], g2[order]
        if self._pairs is None or not (
            len(self._pairs[0]) == n
            and np.array_equal(self._pairs[0], g1)
            and np.array_equal(self._pairs[1], g2)
        ):
            idx = self._pool[:n]
            m.pair_geom1[idx] = g1
            m.pair_geom2[idx] = g2
            _mix_params(m, idx, g1, g2)
            m.pair_geom1[self._pool[n:]] = self._park[0]
            m.pair_geom2[self._pool[n:]] = self._park[1]
            self._pairs = (g1, g2)
        m.body_contype[0] = 0
        m.body_conaffinity[self._bodies] = 0
        self.n_pairs = n
        self._anchor = xp

    def _clearances(
        self, xp: NDArray[np.float64], dist2: NDArray[np.float64], paired: NDArray[np.bool_]
    ) -> NDArray[np.float64]:
        """Each geom's distance (m) from its bounding sphere to the nearest piece it is not
        paired with, less the contact margin: of the coarse pieces (``dist2``: squared
        distances of the geoms' centres from their boxes, (G, K)) and, for the pieces beyond
        them, the coarse selection's bound (more than ``reach + _COARSE`` from every geom when
        made, less how far the geom has moved since)."""
        assert self._coarse is not None
        beyond = self.reach + _COARSE - _distances(xp, self._coarse[0])
        if dist2.size:
            unpaired = np.where(paired, np.inf, dist2).min(axis=1)
            beyond = np.minimum(beyond, np.sqrt(unpaired) - self._radius)
        return np.asarray(beyond - self._margin)


#: :class:`NearContacts` narrows the pieces to those within this of the geoms first, m.
_COARSE = 0.05


@numba.njit(cache=True, error_model="numpy")
def _motion_check(
    xp: NDArray[np.float64],
    last: NDArray[np.float64],
    anchor: NDArray[np.float64],
    clearance: NDArray[np.float64],
    guard: float,
    slack: float,
) -> tuple[float, bool, bool]:
    """The geoms at ``xp`` (G, 3), at ``last`` an interval ago and at ``anchor`` at the last
    selection: (the largest motion over the interval m, whether a geom has moved further than
    its clearance since the selection, whether one can before the next interval ends: moved +
    ``guard`` * motion + ``slack`` beyond its clearance)."""
    motion2 = 0.0
    for g in range(xp.shape[0]):
        d0, d1, d2 = xp[g, 0] - last[g, 0], xp[g, 1] - last[g, 1], xp[g, 2] - last[g, 2]
        motion2 = max(motion2, d0 * d0 + d1 * d1 + d2 * d2)
    motion = math.sqrt(motion2)
    ahead = guard * motion + slack
    overrun, select = False, False
    for g in range(xp.shape[0]):
        d0, d1, d2 = xp[g, 0] - anchor[g, 0], xp[g, 1] - anchor[g, 1], xp[g, 2] - anchor[g, 2]
        moved = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        overrun = overrun or moved > clearance[g]
        select = select or moved + ahead > clearance[g]
    return motion, overrun, select


@numba.njit(cache=True, error_model="numpy")
def _box_distances2(
    xp: NDArray[np.float64],
    rot: NDArray[np.float64],
    centre: NDArray[np.float64],
    half: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Squared distances (G, K) of points ``xp`` (G, 3) from boxes of centres ``centre`` (K, 3),
    rotations ``rot`` (K, 3, 3) and half sizes ``half`` (K, 3), m^2."""
    out = np.empty((xp.shape[0], rot.shape[0]))
    for k in range(rot.shape[0]):
        for g in range(xp.shape[0]):
            v0 = xp[g, 0] - centre[k, 0]
            v1 = xp[g, 1] - centre[k, 1]
            v2 = xp[g, 2] - centre[k, 2]
            total = 0.0
            for i in range(3):
                local = v0 * rot[k, 0, i] + v1 * rot[k, 1, i] + v2 * rot[k, 2, i]
                excess = abs(local) - half[k, i]
                if excess > 0.0:
                    total += excess * excess
            out[g, k] = total
    return out


def _distances(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distances between corresponding rows of two (n, 3) arrays."""
    dv = a - b
    return np.sqrt(np.einsum("ij,ij->i", dv, dv))


def _moved(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Largest distance between corresponding rows of two (n, 3) arrays."""
    dv = a - b
    return math.sqrt(float(np.einsum("ij,ij->i", dv, dv).max()))


def _mix_params(m: mujoco.MjModel, idx: NDArray, g1: NDArray, g2: NDArray) -> None:
    """Set pairs ``idx`` to the contact parameters MuJoCo mixes for automatic contacts of geoms
    ``g1`` and ``g2`` (equal priorities: condim max, solref/solimp mixed by solmix, friction
    max; margin and gap summed)."""
    if np.any(m.geom_priority[g1] != m.geom_priority[g2]):
        raise ValueError("NearContacts supports geoms of equal priority only")
    s1, s2 = m.geom_solmix[g1], m.geom_solmix[g2]
    mix = np.where(
        (s1 >= mujoco.mjMINVAL) & (s2 >= mujoco.mjMINVAL),
        s1 / np.maximum(s1 + s2, mujoco.mjMINVAL),
        np.where(
            (s1 < mujoco.mjMINVAL) & (s2 < mujoco.mjMINVAL),
            0.5,
            np.where(s1 < mujoco.mjMINVAL, 0.0, 1.0),
        ),
    )[:, None]
    r1, r2 = m.geom_solref[g1], m.geom_solref[g2]
    both = (r1[:, :1] > 0) & (r2[:, :1] > 0)
    m.pair_solref[idx] = np.where(both, mix * r1 + (1 - mix) * r2, np.minimum(r1, r2))
    m.pair_solimp[idx] = mix * m.geom_solimp[g1] + (1 - mix) * m.geom_solimp[g2]
    fr = np.maximum(m.geom_friction[g1], m.geom_friction[g2])
    m.pair_friction[idx] = fr[:, [0, 0, 1, 2, 2]]
    m.pair_dim[idx] = np.maximum(m.geom_condim[g1], m.geom_condim[g2])
    m.pair_margin[idx] = m.geom_margin[g1] + m.geom_margin[g2]
    m.pair_gap[idx] = m.geom_gap[g1] + m.geom_gap[g2]
    m.pair_solreffriction[idx] = 0.0
