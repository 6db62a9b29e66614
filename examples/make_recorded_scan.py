"""Record the example scan: one simulated sweep of a noisy LiDAR before a tee, saved as npz.

A 100 mm tee entered along its run, its branch to the left, the sensor 30 cm before the
junction's reference point; the ``ydlidar_x4`` preset (range noise, dropouts, minimum range)
sweeps its plane through 180 deg in 2 deg steps. The true structure goes into the scan's
``metadata`` so that a reader can compare. ``examples/detect_recorded_scan.py`` reads the file
as it would read a scan recorded on the robot.

Usage: python examples/make_recorded_scan.py [--out examples/data/tee_100mm_ydlidar_x4.npz]
       [--seed 3] [--quick]   (--quick writes to a temporary folder unless --out is given)
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from detector.atomic import atomic_write_bytes
from pipe_env import layouts
from pipe_env.ground_truth import structures_ahead
from pipe_env.lidar import RotatingLidar
from pipe_env.world import build_world

DEFAULT_OUT = Path(__file__).resolve().parent / "data" / "tee_100mm_ydlidar_x4.npz"
DIAMETER = 0.1  # m
DISTANCE = 0.3  # m, sensor to the tee's reference point


def record(out: Path, seed: int) -> Path:
    """Simulate the sweep and write it to ``out`` (written whole or not at all)."""
    network = layouts.t_junction(DIAMETER, direction=0.0, distance=DISTANCE)
    world = build_world(network, contact_walls=False)
    lidar = RotatingLidar(world, "ydlidar_x4", backend="analytic")
    pose = network.start_pose
    scan = lidar.scan(pose, np.random.default_rng(seed))
    truth = [o.to_dict() for o in structures_ahead(network, pose, 5.0)]
    scan = replace(
        scan,
        metadata={
            **scan.metadata,
            "seed": seed,
            "layout": "t_junction",
            "clamped_diameter": DIAMETER,
            "truth": truth,
        },
    )
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder) / out.name
        scan.save(tmp)
        atomic_write_bytes(out, tmp.read_bytes())
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=None, help=f"npz file ({DEFAULT_OUT.name})")
    parser.add_argument("--seed", type=int, default=3, help="noise seed (3)")
    parser.add_argument("--quick", action="store_true", help="write to a temporary folder")
    args = parser.parse_args(argv)
    if args.out is not None:
        out = args.out
    elif args.quick:
        out = Path(tempfile.mkdtemp(prefix="pipenav-scan-")) / DEFAULT_OUT.name
    else:
        out = DEFAULT_OUT
    path = record(out, args.seed)
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
