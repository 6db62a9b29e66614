"""The ``pipenav`` command line.

Subcommands are thin: each parses arguments and calls the library function that owns the job.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def _demo(args: argparse.Namespace) -> int:
    from pipe_env.generator import NetworkConfig, generate_network
    from pipe_env.plotting import save_network_plot
    from pipe_env.rendering import WorldRenderer, save_image
    from pipe_env.world import build_world

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    config = NetworkConfig(
        n_fittings=args.fittings, planar=not args.three_d, allow_loops=args.loops
    )
    network = generate_network(config, np.random.default_rng(args.seed))
    t1 = time.perf_counter()
    world = build_world(network)
    t2 = time.perf_counter()
    network.save(out / "network.json")
    save_network_plot(network, out / "network.png")
    renderer = WorldRenderer(world, 800, 600)
    save_image(renderer.render("iso"), str(out / "render.png"))
    renderer.close()
    report = {
        "seed": args.seed,
        "network": repr(network),
        "pipe_length_m": round(network.total_length(), 3),
        "geoms": int(world.model.ngeom),
        "ray_mesh_triangles": int(world.triangle_count),
        "contact_pieces": int(world.contact_geom_count),
        "generate_s": round(t1 - t0, 3),
        "build_world_s": round(t2 - t1, 3),
        "files": ["network.json", "network.png", "render.png"],
    }
    (out / "report.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pipenav", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the main job on the embedded default")
    demo.add_argument("--out", default="results/demo", help="output folder")
    demo.add_argument("--seed", type=int, default=7)
    demo.add_argument("--fittings", type=int, default=8)
    demo.add_argument("--three-d", action="store_true", help="generate a 3D network")
    demo.add_argument("--loops", action="store_true", help="allow loops")
    demo.set_defaults(func=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
