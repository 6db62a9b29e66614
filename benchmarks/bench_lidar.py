"""LiDAR ray-casting throughput: MuJoCo, the exact analytic backend, Embree (open3d), a bound.

Casts the rays of one scan plane (361 beams) and of a full rotating sweep (90 planes x 361
beams, the ideal sensor with the thesis's 2 deg servo steps) from the start pose of a T-junction
world (``pipe_env.layouts.t_junction``), and prints rays per second and ratios measured in the
same run:

- MuJoCo ``mj_multiRay`` on the world's own model (wall meshes plus contact walls), on a
  sensing-only model (wall meshes only), on the bore-facing faces only (the default backend of
  ``RotatingLidar``), and that split over two threads;
- the analytic backend (exact cylinders, cones, planes and tori; numpy);
- ``RotatingLidar.scan`` end to end (ray casting plus the noise model) with both backends;
- open3d's Embree ``RaycastingScene`` on the same meshes (``pipe_env.world.network_meshes``),
  if open3d is installed (it uses every core);
- the bound: the same rays against one infinite cylinder in numpy, in a straight pipe.

Each figure is the best of ``--repeat`` runs (wall clock); the methods take turns run by run, so
that changing load on the machine affects them alike and disturbs the best runs least.

Usage: python benchmarks/bench_lidar.py [--repeat N]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import mujoco
import numpy as np

from pipe_env import layouts
from pipe_env.lidar import RotatingLidar
from pipe_env.raycast_analytic import AnalyticBore
from pipe_env.raycast_mujoco import MujocoCaster
from pipe_env.world import build_world, network_meshes


def best_times(jobs: list[Callable[[], object]], repeat: int) -> list[float]:
    """Best wall-clock time of each job; the jobs take turns, ``repeat`` rounds."""
    for fn in jobs:
        fn()  # warm up
    best = [math.inf] * len(jobs)
    for _ in range(repeat):
        for i, fn in enumerate(jobs):
            t = time.perf_counter()
            fn()
            best[i] = min(best[i], time.perf_counter() - t)
    return best


def cylinder_bound(origin: np.ndarray, dirs: np.ndarray, radius: float) -> np.ndarray:
    """Distances from ``origin`` along ``dirs`` to an infinite cylinder about the x axis."""
    oy, oz = origin[1], origin[2]
    dy, dz = dirs[:, 1], dirs[:, 2]
    a = dy * dy + dz * dz
    b = oy * dy + oz * dz
    c = oy * oy + oz * oz - radius * radius
    with np.errstate(divide="ignore", invalid="ignore"):
        return (-b + np.sqrt(b * b - a * c)) / a


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15, help="runs per figure (best is kept)")
    args = parser.parse_args()
    repeat = max(1, args.repeat)

    net = layouts.t_junction(diameter=0.1, distance=0.4)
    world = build_world(net)  # with contact walls, as the robot environment builds it
    pose = net.start_pose
    lidar = RotatingLidar(world, "ideal")
    dirs_full = np.einsum("ij,pbj->pbi", pose.rotation, lidar.local_directions)
    dirs_plane = dirs_full[:1]
    origin = pose.position
    cutoff = lidar.cutoff
    n_full, n_plane = dirs_full.shape[0] * dirs_full.shape[1], dirs_plane.shape[1]

    methods: list[tuple[str, Callable[[], object], Callable[[], object]]] = []

    def measure(label: str, cast: Callable[[np.ndarray], object]) -> None:
        methods.append((label, lambda: cast(dirs_plane), lambda: cast(dirs_full)))

    def world_model_cast(d: np.ndarray) -> None:
        n = d.shape[0] * d.shape[1]
        geomid = np.empty(n, dtype=np.int32)
        dist = np.empty(n)
        mujoco.mj_multiRay(
            world.model,
            world.data,
            origin,
            np.ascontiguousarray(d).ravel(),
            world.ray_geomgroup,
            1,
            -1,
            geomid,
            dist,
            None,
            n,
            cutoff,
        )

    measure("MuJoCo mj_multiRay, world model (walls + contact walls)", world_model_cast)
    variants = [
        ("MuJoCo, sensing-only model (wall meshes)", MujocoCaster(world, inner_only=False)),
        ("MuJoCo, sensing-only, bore-facing faces (default)", MujocoCaster(world)),
        ("MuJoCo, sensing-only, bore-facing faces, 2 threads", MujocoCaster(world, threads=2)),
    ]
    for label, caster in variants:
        measure(label, lambda d, c=caster: c.cast(origin[None], d, cutoff))
    bore = AnalyticBore.from_network(net)
    measure(
        "analytic backend (exact; numpy)",
        lambda d: bore.cast(origin, d.reshape(-1, 3), cutoff, normals=False),
    )
    rng = np.random.default_rng(0)
    scan_mj = RotatingLidar(world, "ideal", backend="mujoco")
    scan_an = RotatingLidar(world, "ideal", backend="analytic")
    methods.append(
        (
            "RotatingLidar.scan, backend='mujoco' (with noise model)",
            lambda: scan_mj.scan_plane(pose, 0.0, rng),
            lambda: scan_mj.scan(pose, rng),
        )
    )
    methods.append(
        (
            "RotatingLidar.scan, backend='analytic' (with noise model)",
            lambda: scan_an.scan_plane(pose, 0.0, rng),
            lambda: scan_an.scan(pose, rng),
        )
    )

    embree_note = ""
    try:
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        for mesh in network_meshes(net):
            scene.add_triangles(
                o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                o3d.core.Tensor(mesh.faces.astype(np.uint32)),
            )

        def embree_cast(d: np.ndarray) -> None:
            flat = d.reshape(-1, 3)
            rays = np.hstack([np.broadcast_to(origin, flat.shape), flat]).astype(np.float32)
            scene.cast_rays(o3d.core.Tensor(rays))

        measure(f"Embree via open3d {o3d.__version__} RaycastingScene (all cores)", embree_cast)
    except Exception as exc:  # optional dependency (pip install open3d)
        embree_note = f"open3d not available ({type(exc).__name__}: {exc}); Embree row skipped"

    straight_origin = np.zeros(3)
    measure(
        "bound: numpy ray vs one infinite cylinder (straight pipe)",
        lambda d: cylinder_bound(straight_origin, d.reshape(-1, 3), 0.05),
    )

    t_plane = best_times([m[1] for m in methods], repeat)
    t_full = best_times([m[2] for m in methods], repeat)
    rows = [(m[0], tp, tf) for m, tp, tf in zip(methods, t_plane, t_full)]
    mj_ref = rows[0][2]
    default_mj = rows[2][2]
    embree = next((r[2] for r in rows if r[0].startswith("Embree")), None)
    print(
        f"LiDAR ray casting in a T-junction world ({world.triangle_count} ray-mesh triangles, "
        f"{world.model.ngeom} geoms), sensor {0.4:.1f} m before the junction;"
    )
    print(
        f"planar scan: {n_plane} rays; full scan: {dirs_full.shape[0]} planes x "
        f"{dirs_full.shape[1]} beams = {n_full} rays; best of {repeat} runs.\n"
    )
    head = (
        f"{'method':<62} {'plane ms':>9} {'plane Mray/s':>12} {'full ms':>8} "
        f"{'full Mray/s':>11} {'x world':>8} {'x default':>9} {'x Embree':>8}"
    )
    print(head)
    print("-" * len(head))
    for label, tp, tf in rows:
        ratio_e = f"{embree / tf:8.2f}" if embree else f"{'-':>8}"
        print(
            f"{label:<62} {tp * 1e3:9.3f} {n_plane / tp / 1e6:12.2f} {tf * 1e3:8.2f} "
            f"{n_full / tf / 1e6:11.2f} {mj_ref / tf:8.2f} {default_mj / tf:9.2f} {ratio_e}"
        )
    print(
        "\nx world / x default / x Embree: full-scan speed relative to mj_multiRay on the world "
        "model, to the default MuJoCo backend and to Embree (> 1: faster)."
    )
    target = n_full / 1e6 / default_mj
    print(
        f"Target >= 1 M rays/s through MuJoCo (full scan < 35 ms): default backend "
        f"{target:.2f} M rays/s, {default_mj * 1e3:.1f} ms; "
        f"best MuJoCo {n_full / 1e6 / min(r[2] for r in rows[:4]):.2f} M rays/s."
    )
    if embree_note:
        print(embree_note)


if __name__ == "__main__":
    main()
