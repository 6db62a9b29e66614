"""The MuJoCo world of a pipe network, built with ``mujoco.MjSpec``.

Two geom groups line every pipe:

- ``WALL_GROUP``: one watertight CSG triangle mesh per run and per fitting
  (:mod:`pipe_env.meshes`), ``contype = conaffinity = 0``. These are what LiDAR rays hit
  (``mj_multiRay`` restricted to this group) and what renders show.
- ``CONTACT_GROUP``: convex pieces (:mod:`pipe_env.contact_walls`), invisible (alpha 0), which
  collide with geoms whose ``conaffinity`` has bit ``CONTACT_BIT`` set (the robot's).

Open ends do not exist: every leaf of a network is a closure with an end wall, so rays cannot
escape. Callers can add bodies (a robot) through the ``customize`` hook before compilation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np
from numpy.typing import NDArray

from pipe_env.contact_walls import BoxPanel, HullPiece, fitting_pieces, run_panels
from pipe_env.meshes import TriangleMesh, fitting_shell, run_shell, to_triangle_mesh
from pipe_env.network import PipeNetwork

WALL_GROUP = 1
CONTACT_GROUP = 2
#: contype bit of the contact walls; robot geoms set this bit in their conaffinity.
CONTACT_BIT = 1
WALL_RGBA = (0.62, 0.64, 0.68, 0.45)
TIMESTEP = 0.002


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
    out = []
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
) -> PipeWorld:
    """Compile ``network`` into a MuJoCo world (see module docstring).

    Args:
        network: a valid network (validated here).
        contact_walls: add the contact walls (skip them for sensing-only worlds).
        customize: called with the spec before compiling, to add bodies such as a robot.
    """
    network.validate()
    spec = mujoco.MjSpec()
    spec.modelname = f"pipenav_{network.name}"
    spec.option.timestep = TIMESTEP
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.6, 0.6, 0.6]
    spec.stat.extent = float(np.linalg.norm(np.subtract(*network.bounds()[::-1])))
    spec.stat.center = (0.5 * np.add(*network.bounds())).tolist()
    world = spec.worldbody
    names: list[str] = []
    triangles = 0
    for mesh in network_meshes(network):
        mname = f"wall_{len(names)}"
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
        names.append(mesh.name)
        triangles += len(mesh.faces)
    n_contact = 0
    if contact_walls:
        for element, hulls, boxes in network_contact_pieces(network):
            for box in boxes:
                g = world.add_geom()
                g.type = mujoco.mjtGeom.mjGEOM_BOX
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
                g.type = mujoco.mjtGeom.mjGEOM_MESH
                g.meshname = mname
                _contact_style(g)
                n_contact += 1
            del element
    if customize is not None:
        customize(spec)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    wall_geoms = {}
    for gid in range(model.ngeom):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, gid) or ""
        if name.startswith("wall:"):
            wall_geoms[gid] = name[len("wall:") :]
    return PipeWorld(
        network, spec, model, data, WALL_GROUP, CONTACT_GROUP, wall_geoms, triangles, n_contact
    )


def _contact_style(g: mujoco.MjsGeom) -> None:
    g.group = CONTACT_GROUP
    g.contype = CONTACT_BIT
    g.conaffinity = 0
    g.rgba = [0.3, 0.5, 0.8, 0.0]
    g.friction = [0.6, 0.005, 0.0001]
