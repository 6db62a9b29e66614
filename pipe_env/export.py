"""A generated network out to the user's own tools: the pipe walls as one watertight mesh
(STL, OBJ, GLB, PLY through ``trimesh``) and the MuJoCo world as MJCF.

The walls are the ray meshes of :mod:`pipe_env.meshes` (the surfaces the simulated LiDAR
hits), joined by a CSG union (manifold3d) into one closed solid: a shell of
:data:`pipe_env.meshes.WALL` thickness whose inner surface is the bore, with every open end
capped by its closure. Coordinates are the network's (world) frame, metres.

The MJCF is ``mujoco.MjSpec.to_xml()`` of the world :func:`pipe_env.world.build_world`
compiles (optionally with the robot and a keyframe of its start state), with the wall meshes'
vertices embedded, so the one file loads with ``mujoco.MjModel.from_xml_path`` and opens in
MuJoCo's viewer (``python -m mujoco.viewer --mjcf FILE``). Every file is written atomically.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import manifold3d as m3
import numpy as np

from detector.atomic import atomic_write_bytes, atomic_write_text
from pipe_env.meshes import fitting_shell, run_shell
from pipe_env.network import PipeNetwork
from pipe_env.world import PipeWorld, build_world

#: Edges of the union shorter than this are collapsed, metres: STL stores float32
#: coordinates (about 0.2 um at 2 m), and readers weld vertices closer than about 1e-8 m, so a
#: shorter edge would leave a hole or a sliver that is no longer watertight.
MIN_EDGE = 1e-5
#: Mesh formats :func:`export_mesh` writes, by file suffix.
MESH_FORMATS: dict[str, str] = {".stl": "stl", ".obj": "obj", ".glb": "glb", ".ply": "ply"}


def wall_solid(network: PipeNetwork) -> m3.Manifold:
    """The union of every run's and fitting's wall shell (one closed manifold solid)."""
    network.validate()
    solids = []
    for r in network.runs:
        if network.straight_length(r.id) <= 1e-6:
            continue
        pa = network.geometry[r.a].port(r.id).position
        pb = network.geometry[r.b].port(r.id).position
        solids.append(run_shell(pa, pb, r.diameter))
    for f in network.fittings:
        solids.append(fitting_shell(network.geometry[f.id]))
    solid = m3.Manifold.batch_boolean(solids, m3.OpType.Add)
    if solid.is_empty():
        raise ValueError(f"network {network.name!r}: the union of its walls is empty")
    return solid


def wall_mesh(network: PipeNetwork) -> Any:
    """The walls of ``network`` as one watertight ``trimesh.Trimesh`` (metres, world frame)."""
    import trimesh

    mesh = wall_solid(network).to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=float)[:, :3]
    faces = _collapse_short_edges(verts, np.asarray(mesh.tri_verts, dtype=np.int64), MIN_EDGE)
    verts = _part_touching_sheets(verts, faces, MIN_EDGE)
    out = trimesh.Trimesh(verts, faces, process=True)
    if not out.is_watertight:
        raise ValueError(f"network {network.name!r}: its wall mesh is not watertight")
    out.metadata["name"] = network.name
    return out


def _collapse_short_edges(verts: np.ndarray, faces: np.ndarray, min_edge: float) -> np.ndarray:
    """``faces`` with every edge shorter than ``min_edge`` (m) collapsed onto one of its
    vertices and the triangles it flattened removed (unused vertices stay)."""
    parent = np.arange(len(verts))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = int(parent[i])
        return i

    for _ in range(5):
        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        short = np.linalg.norm(verts[e[:, 0]] - verts[e[:, 1]], axis=1) < min_edge
        if not short.any():
            break
        for a, b in e[short]:
            ra, rb = root(int(a)), root(int(b))
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
        roots = np.array([root(i) for i in range(len(verts))])
        faces = roots[faces]
        keep = (
            (faces[:, 0] != faces[:, 1])
            & (faces[:, 1] != faces[:, 2])
            & (faces[:, 2] != faces[:, 0])
        )
        faces = faces[keep]
    return faces


def _part_touching_sheets(verts: np.ndarray, faces: np.ndarray, gap: float) -> np.ndarray:
    """``verts`` with the distinct vertices that lie within ``gap`` (m) of each other (where
    two pipes' walls touch from outside: the union keeps them apart, a file reader welds
    them into edges of four triangles) each moved ``gap`` into its own wall."""
    import trimesh
    from scipy.spatial import cKDTree

    used = np.unique(faces)
    pairs = cKDTree(verts[used]).query_pairs(gap, output_type="ndarray")
    if pairs.size == 0:
        return verts
    normals = trimesh.Trimesh(verts, faces, process=False).vertex_normals
    out = verts.copy()
    moved = used[np.unique(pairs)]
    out[moved] -= gap * normals[moved]
    return out


def export_mesh(network: PipeNetwork, path: str | Path) -> Path:
    """Write the walls of ``network`` to ``path`` in the format its suffix names
    (:data:`MESH_FORMATS`), atomically. Returns the path."""
    target = Path(path)
    fmt = MESH_FORMATS.get(target.suffix.lower())
    if fmt is None:
        raise ValueError(
            f"mesh file {str(target)!r}: suffix {target.suffix!r} is not allowed; use one of "
            f"{sorted(MESH_FORMATS)}"
        )
    data = wall_mesh(network).export(file_type=fmt)
    atomic_write_bytes(target, data if isinstance(data, bytes) else str(data).encode())
    return target


def mjcf_text(world: PipeWorld, keyframe: Mapping[str, Any] | None = None) -> str:
    """The MJCF of a built world (its ``MjSpec``), meshes embedded.

    Args:
        world: from :func:`pipe_env.world.build_world` (with or without a robot).
        keyframe: optional state to store as the keyframe ``"start"``: any of ``qpos``,
            ``qvel``, ``mocap_pos``, ``mocap_quat`` (arrays of the compiled model's sizes).
    """
    spec = world.complete().spec  # (a world built without ray meshes: with them)
    if keyframe:
        key = spec.add_key()
        key.name = "start"
        # (MjsKey names the mocap state mpos and mquat)
        for name, attr in (
            ("qpos", "qpos"),
            ("qvel", "qvel"),
            ("mocap_pos", "mpos"),
            ("mocap_quat", "mquat"),
        ):
            if name in keyframe:
                setattr(key, attr, np.asarray(keyframe[name], dtype=float).ravel().tolist())
    try:
        return spec.to_xml()
    finally:
        if keyframe:
            spec.delete(key)


def export_mjcf(
    network: PipeNetwork | PipeWorld,
    path: str | Path,
    *,
    contact_walls: bool = True,
    keyframe: Mapping[str, Any] | None = None,
) -> Path:
    """Write the MuJoCo world of ``network`` (or an already built world, e.g. one with the
    robot) as one MJCF file, atomically. Returns the path."""
    world = (
        network
        if isinstance(network, PipeWorld)
        else build_world(network, contact_walls=contact_walls)
    )
    target = Path(path)
    atomic_write_text(target, mjcf_text(world, keyframe))
    return target


def mesh_report(path: str | Path) -> dict[str, Any]:
    """Facts about a written mesh file for people and tests: triangles, watertight, volume
    (m^3), bounds (m)."""
    import trimesh

    data = Path(path).read_bytes()
    fmt = MESH_FORMATS.get(Path(path).suffix.lower(), "stl")
    loaded = trimesh.load(io.BytesIO(data), file_type=fmt, force="mesh")
    if not isinstance(loaded, trimesh.Trimesh):  # force="mesh" makes one; narrows the type
        raise ValueError(f"{path}: not a triangle mesh ({type(loaded).__name__})")
    return {
        "triangles": int(len(loaded.faces)),
        "watertight": bool(loaded.is_watertight),
        "volume_m3": float(loaded.volume),
        "bounds_m": np.asarray(loaded.bounds).tolist(),
    }
