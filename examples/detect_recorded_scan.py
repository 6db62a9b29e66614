"""Detection on a recorded scan: the detector package needs neither MuJoCo nor the simulator.

Loads a sweep saved with ``Scan.save`` (here ``examples/data/tee_100mm_ydlidar_x4.npz``, made
by ``examples/make_recorded_scan.py``), runs the improved method and the thesis method on it
with the clamped diameter, and prints their options next to the truth stored in the scan's
metadata (when there is one). Distances in cm, angles in degrees.

Usage: python examples/detect_recorded_scan.py [SCAN.npz] [--clamped-diameter 0.1] [--quick]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from detector import StructureOption, detect
from detector.scan import Scan

DEFAULT_SCAN = Path(__file__).resolve().parent / "data" / "tee_100mm_ydlidar_x4.npz"


def describe(option: StructureOption) -> str:
    """One option for people: kind, distance (cm), diameter (mm), angle and direction (deg)."""
    return (
        f"{option.kind:9s} {option.distance * 100:6.1f} cm  {option.diameter * 1000:5.1f} mm  "
        f"angle {math.degrees(option.angle):6.1f} deg  "
        f"direction {math.degrees(option.direction):6.1f} deg"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scan", nargs="?", type=Path, default=DEFAULT_SCAN, help="a .npz scan")
    parser.add_argument(
        "--clamped-diameter",
        type=float,
        default=None,
        help="pipe diameter from the clamp, m (default: the scan's metadata, else 0.1)",
    )
    parser.add_argument("--quick", action="store_true", help="(the same: one scan is quick)")
    args = parser.parse_args(argv)

    scan = Scan.load(args.scan)
    clamped = args.clamped_diameter or float(scan.metadata.get("clamped_diameter", 0.1))
    print(
        f"{args.scan.name}: {scan.n_planes} planes x {scan.n_beams} beams, "
        f"{scan.n_valid} returns, clamped diameter {clamped * 1000:.0f} mm"
    )
    for method in ("improved", "thesis"):
        det = detect(scan, clamped, method=method)
        print(f"{method}: {det.kind} (confidence {det.confidence:.2f})")
        for option in det.options:
            print("   ", describe(option))
    truth = scan.metadata.get("truth")
    if truth:
        print("truth:")
        for row in truth:
            print("   ", describe(StructureOption.from_dict(row)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
