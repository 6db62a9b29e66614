"""LiDAR ray-casting throughput: the exact analytic backend against single-thread Embree.

Casts the rays of a full rotating sweep (the ideal sensor, 90 planes x 361 beams, the
thesis's 2 deg servo steps) from the start pose of two worlds, a T-junction and a long-radius
bend (``pipe_env.layouts``, 0.1 m pipes, 0.4 m ahead), and prints rays per second of, all
measured in the same run:

- the analytic backend (exact cylinders, cones, planes and tori; compiled per-ray kernels), the
  default of the closed loop;
- its former numpy implementation (``AnalyticBore.cast_numpy``, kept as the reference);
- MuJoCo ``mj_multiRay`` on the sensing-only, bore-facing meshes (``backend="mujoco"``);
- Embree on the same CSG meshes (``pipe_env.world.network_meshes``) through ``embreex``, one
  thread (it traces one ray at a time in the calling thread); float32 rays prepared outside
  the timing;
- ``RotatingLidar.scan`` end to end (directions, casting and the noise model) with the analytic
  backend, for the ideal sensor and the YDLidar X4 (which also needs the wall normals);

and the ratio of the analytic backend to Embree (the target: >= 1, goal 2). Each figure is the
best of ``--repeat`` runs of CPU time of this process (other processes on the machine disturb
it less than wall time); the methods take turns run by run.

Usage: python benchmarks/bench_lidar.py [--repeat N] [--write-docs]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipe_env import layouts  # noqa: E402
from pipe_env.lidar import RotatingLidar  # noqa: E402
from pipe_env.network import PipeNetwork  # noqa: E402
from pipe_env.raycast_analytic import AnalyticBore  # noqa: E402
from pipe_env.raycast_mujoco import MujocoCaster  # noqa: E402
from pipe_env.world import build_world, network_meshes  # noqa: E402

WORLDS: dict[str, Callable[[], PipeNetwork]] = {
    "T-junction": lambda: layouts.t_junction(diameter=0.1, distance=0.4),
    "long bend": lambda: layouts.long_bend(diameter=0.1, distance=0.4),
}
#: Row labels, in print order.
ANALYTIC = "analytic backend (compiled kernels)"
NUMPY = "analytic, former numpy path (reference)"
MUJOCO = "MuJoCo mj_multiRay, bore-facing meshes"
EMBREE = "Embree (embreex), 1 thread, same meshes"
SCAN_IDEAL = "RotatingLidar.scan, analytic, ideal"
SCAN_X4 = "RotatingLidar.scan, analytic, ydlidar_x4"


def best_times(jobs: dict[str, Callable[[], object]], repeat: int) -> dict[str, float]:
    """Best CPU time (s) of each job over ``repeat`` rounds in which the jobs take turns."""
    for fn in jobs.values():
        fn()  # warm up (and compile)
    best = dict.fromkeys(jobs, math.inf)
    for _ in range(repeat):
        for name, fn in jobs.items():
            t = time.process_time()
            fn()
            best[name] = min(best[name], time.process_time() - t)
    return best


def embree_scene(network: PipeNetwork) -> object | None:
    """An ``embreex`` scene of the network's CSG meshes, or None without embreex."""
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError:
        return None
    scene = rtcore_scene.EmbreeScene()
    for mesh in network_meshes(network):
        TriangleMesh(
            scene,
            np.ascontiguousarray(mesh.vertices, dtype=np.float32),
            np.ascontiguousarray(mesh.faces, dtype=np.int32),
        )
    return scene


def measure_world(name: str, repeat: int) -> tuple[dict[str, float], int, str]:
    """Seconds per sweep of every method in one world, the ray count and a check line."""
    net = WORLDS[name]()
    world = build_world(net, contact_walls=False)
    pose = net.start_pose
    lidar = RotatingLidar(world, "ideal", backend="analytic")
    x4 = RotatingLidar(world, "ydlidar_x4", backend="analytic")
    dirs = np.einsum("ij,pbj->pbi", pose.rotation, lidar.local_directions)
    flat = np.ascontiguousarray(dirs.reshape(-1, 3))
    origin = pose.position.copy()
    cutoff = lidar.cutoff
    bore = AnalyticBore.from_network(net)
    caster = MujocoCaster(world)
    rng = np.random.default_rng(0)
    jobs: dict[str, Callable[[], object]] = {
        ANALYTIC: lambda: bore.cast(origin, flat, cutoff, normals=False),
        NUMPY: lambda: bore.cast_numpy(origin, flat, cutoff, normals=False),
        MUJOCO: lambda: caster.cast(origin[None], dirs, cutoff),
        SCAN_IDEAL: lambda: lidar.scan(pose, rng),
        SCAN_X4: lambda: x4.scan(pose, rng),
    }
    scene = embree_scene(net)
    check = "embreex not installed (pip install embreex): no Embree row"
    if scene is not None:
        o32 = np.ascontiguousarray(np.broadcast_to(origin, flat.shape), dtype=np.float32)
        d32 = np.ascontiguousarray(flat, dtype=np.float32)
        jobs[EMBREE] = lambda: scene.run(o32, d32, query="DISTANCE")  # type: ignore[attr-defined]
        exact = bore.cast(origin, flat, cutoff, normals=False).dist
        mesh = np.asarray(scene.run(o32, d32, query="DISTANCE"), dtype=float)  # type: ignore[attr-defined]
        both = np.isfinite(exact) & (mesh < 1e30)
        diff = np.abs(mesh[both] - exact[both])
        check = (
            f"Embree's mesh ranges vs the exact ones: median {np.median(diff) * 1e3:.3f} mm, "
            f"{np.mean(diff <= 1e-3) * 100:.1f} % within 1 mm (facets and creases)"
        )
    order = [ANALYTIC, NUMPY, MUJOCO, EMBREE, SCAN_IDEAL, SCAN_X4]
    best = best_times({k: jobs[k] for k in order if k in jobs}, repeat)
    return best, len(flat), check


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15, help="runs per figure (best is kept)")
    parser.add_argument(
        "--write-docs", action="store_true", help="write the figures to docs/benchmarks.md"
    )
    args = parser.parse_args()
    if args.repeat < 1:
        raise SystemExit(f"--repeat = {args.repeat} is invalid; allowed >= 1")

    results = {name: measure_world(name, args.repeat) for name in WORLDS}
    n_rays = next(iter(results.values()))[1]
    lines = [
        f"One full sweep of the ideal sensor (90 planes x 361 beams = {n_rays} rays) from the "
        "start pose, 0.4 m before the structure, 0.1 m pipes; best of "
        f"{args.repeat} runs (CPU time).",
        "",
        "| method | " + " | ".join(f"{w} M rays/s | {w} ms" for w in WORLDS) + " |",
        "|---|" + "---:|---:|" * len(WORLDS),
    ]
    labels = [ANALYTIC, NUMPY, MUJOCO, EMBREE, SCAN_IDEAL, SCAN_X4]
    for label in labels:
        if all(label in r[0] for r in results.values()):
            cells = []
            for best, n, _ in results.values():
                cells.append(f"{n / best[label] / 1e6:.2f} | {best[label] * 1e3:.2f}")
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("")
    for world, (best, _, check) in results.items():
        if EMBREE in best:
            ratio = best[EMBREE] / best[ANALYTIC]
            verdict = "met" if ratio >= 1.0 else "NOT met"
            goal = ", goal 2x met" if ratio >= 2.0 else ""
            lines.append(
                f"- {world}: analytic backend / Embree = **{ratio:.2f}x** (target >= 1.0x "
                f"{verdict}{goal}); former numpy path / Embree = "
                f"{best[EMBREE] / best[NUMPY]:.2f}x. {check}."
            )
        else:
            lines.append(f"- {world}: {check}.")
    text = "\n".join(lines)
    print(text)
    if args.write_docs:
        from benchmarks.report import write_section

        command = " ".join(["python benchmarks/bench_lidar.py", *sys.argv[1:]])
        command = command.replace(" --write-docs", "")
        path = write_section("lidar", f"`{command}`\n\n{text}")
        print(f"\nwrote section 'lidar' of {path}")


if __name__ == "__main__":
    main()
