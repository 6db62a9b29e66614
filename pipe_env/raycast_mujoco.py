"""Batched LiDAR ray casting through MuJoCo (``mujoco.mj_multiRay``) on a sensing-only model.

This module owns the MuJoCo backend of :class:`pipe_env.lidar.RotatingLidar`. It casts against
the world's wall meshes (geom group ``world.wall_group``), but in a model of its own that holds
only those meshes, because measurements showed where ``mj_multiRay``'s time goes:

- every ray loops over every geom of the model to test its group and bounding angles, so the
  hundreds of invisible contact-wall geoms of a :class:`pipe_env.world.PipeWorld` cost time even
  though they are not in the ray group; the sensing model has one geom per run and fitting;
- each mesh is traversed through its bounding-volume hierarchy without pruning by the nearest
  hit so far, so every triangle box the ray crosses costs a test. A ray from inside the bore can
  only ever hit the bore-facing (inner) surface of a shell, so with ``inner_only`` the outer
  surface is dropped (about half of the triangles); the hits of rays that start inside the bore
  are unchanged;
- ``mj_multiRay`` releases the GIL, so ``threads > 1`` splits a batch over threads, each with its
  own ``MjData`` (useful when cores are free; results are identical).

Edge guard: MuJoCo's ray-triangle test is not watertight. A ray that meets a mesh exactly on an
edge shared by two triangles can be rejected by both and leak through the wall. That is not a
rare accident here: a sensor on a pipe's axis with its scan plane at roll 0 sends whole planes of
beams exactly along the tessellation's vertex lines (measured: tens to hundreds of leaked rays
per 90 x 361 sweep). Every direction is therefore tilted by a fixed, deterministic angle of
``EDGE_GUARD`` radians (a fixed pattern, not random draws), which moves the hit by at most
``EDGE_GUARD * range`` (4 micrometres at 2 m) and takes rays off the exact edges.

Distances are metres; ``inf`` means no hit within the cutoff. Normals are unit vectors pointing
into the wall (away from the ray's origin side), as :mod:`pipe_env.raycast_analytic` reports.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np
from numpy.typing import NDArray

from pipe_env.meshes import WALL
from pipe_env.world import PipeWorld

#: Tilt of every ray direction that keeps rays off exact mesh edges, radians (see module doc).
EDGE_GUARD = 2.0e-6
#: Probe offset off a face in ``inner_only`` mode, metres (below the shell thickness ``WALL``).
_PROBE = 0.001


def sensing_model(world: PipeWorld, inner_only: bool = True) -> mujoco.MjModel:
    """A model holding only the world's static ray meshes (one geom each, group ``wall_group``).

    Args:
        world: the world whose wall meshes are copied (from its ``MjSpec``; nothing is re-meshed).
        inner_only: keep only the faces that face the bore (see module docstring).
    """
    world = world.complete()  # (a world built without ray meshes: with them)
    bore = None
    if inner_only:
        from pipe_env.raycast_analytic import AnalyticBore

        bore = AnalyticBore.from_network(world.network)
    meshes = {m.name: m for m in world.spec.meshes}
    spec = mujoco.MjSpec()
    spec.modelname = "pipenav_sensing"
    count = 0
    for geom in world.spec.worldbody.geoms:
        if geom.group != world.wall_group or geom.type != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        src = meshes[geom.meshname]
        verts = np.asarray(src.uservert, dtype=float).reshape(-1, 3)
        faces = np.asarray(src.userface, dtype=np.int64).reshape(-1, 3)
        if bore is not None:
            faces = faces[_bore_facing(verts, faces, bore, geom)]
            if len(faces) == 0:
                continue
            used = np.unique(faces)
            remap = np.full(len(verts), -1, dtype=np.int64)
            remap[used] = np.arange(len(used))
            verts, faces = verts[used], remap[faces]
        mesh = spec.add_mesh()
        mesh.name = f"ray_{count}"
        mesh.uservert = verts.ravel().tolist()
        mesh.userface = faces.ravel().tolist()
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
        g = spec.worldbody.add_geom()
        g.name = geom.name
        g.type = mujoco.mjtGeom.mjGEOM_MESH
        g.meshname = mesh.name
        g.pos = list(geom.pos)
        g.quat = list(geom.quat)
        g.group = world.wall_group
        g.contype = 0
        g.conaffinity = 0
        count += 1
    if count == 0:
        raise ValueError("the world has no static wall meshes to cast rays against")
    return spec.compile()


def _bore_facing(verts: NDArray, faces: NDArray, bore, geom: mujoco.MjsGeom) -> NDArray:
    """Mask of the faces to keep: all but those provably on a shell's outer side.

    A face is dropped only when a probe just outside it (along its outward normal) lies outside
    the bore while a probe through the shell behind it (``WALL`` + 1 mm inwards) lies inside:
    the outer surface of a shell around a bore. CSG leaves sliver faces where two solids overlap
    (a mitre's seam, a hole rim) that bound the mesh's bore although no probe off them lies in
    the exact bore; such faces fail the test and are kept, so no ray leaks through them.
    """
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1)
    ok = length > 0
    normal[ok] /= length[ok, None]
    centroid = tri.mean(axis=1)
    rot9 = np.zeros(9)
    mujoco.mju_quat2Mat(rot9, np.asarray(geom.quat, dtype=float))
    rot = rot9.reshape(3, 3)
    pos = np.asarray(geom.pos, dtype=float)
    outside = ~bore.contains((centroid + _PROBE * normal) @ rot.T + pos)
    behind = bore.contains((centroid - (WALL + _PROBE) * normal) @ rot.T + pos)
    return ~(ok & outside & behind)


class MujocoCaster:
    """Casts ray batches with ``mj_multiRay`` on a sensing-only model of a world.

    Args:
        world: the world to scan.
        inner_only: drop shell faces a ray from inside the bore cannot reach.
        threads: split large batches over this many threads (``mj_multiRay`` releases the GIL).
        sensing_only: cast on a model with only the wall meshes (else on ``world.model`` itself).
        edge_guard: tilt directions by ``EDGE_GUARD`` so no ray runs exactly along a mesh edge.
    """

    def __init__(
        self,
        world: PipeWorld,
        inner_only: bool = True,
        threads: int = 1,
        sensing_only: bool = True,
        edge_guard: bool = True,
    ) -> None:
        if not (isinstance(threads, int) and 1 <= threads <= 64):
            raise ValueError(f"threads = {threads!r} is invalid; allowed an int in [1, 64]")
        if not sensing_only and inner_only:
            raise ValueError("inner_only needs sensing_only=True (it edits the meshes)")
        if sensing_only:
            self.model = sensing_model(world, inner_only)
        else:
            self.model = world.complete().model
        self.datas = [mujoco.MjData(self.model) for _ in range(threads)]
        for d in self.datas:
            mujoco.mj_forward(self.model, d)
        self.geomgroup = world.ray_geomgroup
        self.threads = threads
        self.edge_guard = edge_guard
        self._guard: NDArray[np.float64] | None = None
        self._dist: NDArray[np.float64] | None = None
        self._geomid: NDArray[np.int32] | None = None
        self._normal: NDArray[np.float64] | None = None
        self._pool = ThreadPoolExecutor(threads) if threads > 1 else None

    def cast(
        self,
        origins: NDArray[np.float64],
        directions: NDArray[np.float64],
        cutoff: float,
        normals: bool = False,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Cast P groups of B rays, group p from ``origins[p]``.

        Args:
            origins: (P, 3) world positions, metres.
            directions: (P, B, 3) unit world directions.
            cutoff: geoms farther than this are skipped; hits beyond it are reported as ``inf``.
            normals: also return (P, B, 3) unit normals pointing into the wall.
        Returns:
            (P, B) distances (``inf``: no hit) and the normals or None.
        """
        origins = np.ascontiguousarray(origins, dtype=float).reshape(-1, 3)
        p, b = directions.shape[:2]
        vec = np.ascontiguousarray(directions, dtype=float).reshape(p * b, 3)
        if self.edge_guard:
            vec = vec + EDGE_GUARD * self._guard_pattern(p * b)
            vec /= np.linalg.norm(vec, axis=1)[:, None]
        dist, geomid, nrm_buf = self._buffers(p * b)
        nrm = nrm_buf if normals else None
        same = bool((origins == origins[0]).all())
        # jobs: (origin, ray slice); one origin -> one call per thread
        if same:
            bounds = np.linspace(0, p * b, self.threads + 1).astype(int)
            jobs = [(origins[0], bounds[i], bounds[i + 1]) for i in range(self.threads)]
        else:
            jobs = [(origins[k], k * b, (k + 1) * b) for k in range(p)]

        def run(job_ids: list[int], data: mujoco.MjData) -> None:
            for j in job_ids:
                pnt, lo, hi = jobs[j]
                if hi <= lo:
                    continue
                mujoco.mj_multiRay(
                    self.model,
                    data,
                    pnt,
                    vec[lo:hi].ravel(),
                    self.geomgroup,
                    1,
                    -1,
                    geomid[lo:hi],
                    dist[lo:hi],
                    nrm[lo:hi].ravel() if nrm is not None else None,
                    hi - lo,
                    cutoff,
                )

        if self._pool is None or len(jobs) == 1:
            run(list(range(len(jobs))), self.datas[0])
        else:
            split = np.array_split(np.arange(len(jobs)), self.threads)
            list(self._pool.map(run, [s.tolist() for s in split], self.datas))
        hit = (dist >= 0.0) & (dist <= cutoff)
        out = np.where(hit, dist, math.inf).reshape(p, b)
        if nrm is None:
            return out, None
        # MuJoCo reports the face normal; orient it into the wall (along the ray)
        sign = np.where(np.einsum("ij,ij->i", nrm, vec) < 0.0, -1.0, 1.0)
        out_n = nrm * np.where(hit, sign, 0.0)[:, None]
        return out, out_n.reshape(p, b, 3)

    def _buffers(self, n: int) -> tuple[NDArray, NDArray, NDArray]:
        """Output buffers for n rays, reused across calls (grown when needed)."""
        if self._dist is None or len(self._dist) < n:
            self._dist = np.empty(n)
            self._geomid = np.empty(n, dtype=np.int32)
            self._normal = np.empty((n, 3))
        assert self._geomid is not None and self._normal is not None
        return self._dist[:n], self._geomid[:n], self._normal[:n]

    def _guard_pattern(self, n: int) -> NDArray[np.float64]:
        """(n, 3) fixed unit vectors (golden-angle spiral), the same for every call."""
        if self._guard is None or len(self._guard) < n:
            i = np.arange(max(n, 1024), dtype=float)
            z = 1.0 - 2.0 * ((i * 0.6180339887498949) % 1.0)
            phi = i * 2.399963229728653
            rho = np.sqrt(1.0 - z * z)
            self._guard = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
        return self._guard[:n]

    def __getstate__(self) -> dict:
        """Picklable (for subprocess vector envs): the thread pool is recreated on load."""
        state = self.__dict__.copy()
        state["_pool"] = None
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if self.threads > 1:
            self._pool = ThreadPoolExecutor(self.threads)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None
