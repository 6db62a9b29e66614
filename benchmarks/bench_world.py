"""Benchmark: generate, validate and build the MuJoCo world of a 20-fitting network.

Prints per-phase times (median over seeds), geom and triangle counts, and the ratio to a
reference measured in the same run (building the world of a single straight pipe), since
absolute times vary between machines. Target from the issue: under 2 s in total.

Phases: the ray meshes' CSG, the contact pieces, MuJoCo's compilation of the world with and
without the ray meshes, and ``build_world`` with them (the default) and without them
(``ray_meshes=False``: the full-fidelity plant's world, whose LiDAR casts analytically; the ray
meshes are built on demand).

Usage: python benchmarks/bench_world.py [--fittings 20] [--seeds 5] [--three-d] [--loops]
       [--write-docs]   (--write-docs: also write the "world" section of docs/benchmarks.md)
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

from pipe_env import layouts
from pipe_env.generator import NetworkConfig, generate_network
from pipe_env.world import build_world, network_contact_pieces, network_meshes


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--fittings", type=int, default=20)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--three-d", action="store_true")
    parser.add_argument("--loops", action="store_true")
    parser.add_argument(
        "--write-docs", action="store_true", help="write the tables to docs/benchmarks.md"
    )
    args = parser.parse_args()

    reference = statistics.median(timed(build_world, layouts.straight(0.1))[1] for _ in range(5))
    cfg = NetworkConfig(n_fittings=args.fittings, planar=not args.three_d, allow_loops=args.loops)
    rows = []
    for seed in range(args.seeds):
        net, t_gen = timed(generate_network, cfg, np.random.default_rng(seed))
        _, t_val = timed(net.validate)
        fresh = type(net).from_dict(net.to_dict(), validate=False)  # no cached geometry
        _, t_mesh = timed(network_meshes, fresh)
        _, t_contact = timed(network_contact_pieces, fresh)
        world, t_build = timed(build_world, fresh)
        _, t_compile = timed(world.spec.compile)
        lean_net = type(net).from_dict(net.to_dict(), validate=False)
        lean, t_lean = timed(build_world, lean_net, ray_meshes=False)
        _, t_lean_compile = timed(lean.spec.compile)
        rows.append(
            {
                "generate": t_gen,
                "validate": t_val,
                "ray meshes": t_mesh,
                "contact pieces": t_contact,
                "mujoco compile": t_compile,
                "mujoco compile, no ray meshes": t_lean_compile,
                "build_world": t_build,
                "build_world, ray meshes on demand": t_lean,
                "total": t_gen + t_build,
                "geoms": world.model.ngeom,
                "triangles": world.triangle_count,
                "contact geoms": world.contact_geom_count,
                "fittings": len(net.fittings),
                "runs": len(net.runs),
            }
        )
    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    lines = [
        f"pipenav world benchmark: {args.fittings} fittings (+ end caps), "
        f"{'3D' if args.three_d else 'planar'}{', loops' if args.loops else ''}, "
        f"{args.seeds} seeds, mujoco {mujoco.__version__}",
        "",
        f"reference: build_world(straight pipe) = {reference * 1000:.1f} ms",
        "",
        "| phase | median s | x reference |",
        "|---|---|---|",
    ]
    for k in (
        "generate",
        "validate",
        "ray meshes",
        "contact pieces",
        "mujoco compile",
        "mujoco compile, no ray meshes",
        "build_world",
        "build_world, ray meshes on demand",
        "total",
    ):
        lines.append(f"| {k} | {med[k]:.3f} | {med[k] / reference:.1f} |")
    lines.append(f"| fittings incl. caps / runs | {med['fittings']:.0f} / {med['runs']:.0f} | |")
    lines.append(
        f"| geoms / ray-mesh triangles / contact geoms | {med['geoms']:.0f} / "
        f"{med['triangles']:.0f} / {med['contact geoms']:.0f} | |"
    )
    worst = max(r["total"] for r in rows)
    verdict = "met" if worst < 2.0 else "NOT met"
    lines += ["", f"target: generate + validate + build < 2 s: worst {worst:.3f} s -> {verdict}"]
    print("\n".join(line for line in lines if line))
    if args.write_docs:
        sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
        from benchmarks.report import write_section

        argv = [a for a in sys.argv[1:] if a != "--write-docs"]
        command = " ".join(["python benchmarks/bench_world.py", *argv])
        path = write_section("world", "\n".join([f"`{command}`", "", *lines]))
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
