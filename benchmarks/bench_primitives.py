"""Tolerance study and speed of the motion primitives (issue 5, item 6).

1. Tolerances: per pipe diameter (60, 90, 120 mm by default), the largest error in a ground-truth
   option that ``take_turn`` still survives (status ``done`` and the robot in the right outgoing
   pipe), found by bisection separately for each sign of the error and for a few roll
   directions of a 90 deg mitre bend (and a long bend with ``--long``). Errors studied:
   ``distance`` (m; also printed as a fraction of the diameter), ``direction`` (roll, deg) and
   ``angle`` (deflection, deg). The table reports, per error and sign, the smallest survived
   bound over the roll directions (what the detector must guarantee everywhere). These are the
   detector's real requirements; the fast plant's ``ExecutionTolerance`` should follow them.
2. Speed: simulated seconds per wall second for driving 1 m and for a 90 deg mitre turn, with
   and without scanning (scanning: a stop-and-scan sweep of the ideal LiDAR, analytic ray
   casting, every 5 cm driven; no detection).

Bisection assumes survival is monotonic in the error's size; each bound is the largest tested
error that survived with the next tested one failing (resolution ``hi / 2**iterations``).

Usage: python benchmarks/bench_primitives.py [--diameters 0.06 0.09 0.12] [--directions 0 135]
       [--iterations 5] [--long] [--skip-tolerance] [--skip-speed] [--write-docs]
       (--write-docs: also write the "primitives" section of docs/benchmarks.md)
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from detector.options import StructureOption
from pipe_env import layouts
from pipe_env.ground_truth import structures_ahead
from pipe_env.network import PipeNetwork
from pipe_env.routing import locate
from primitives.executor import Executor
from primitives.sequences import Sequence, go_straight, take_turn
from primitives.steps import Drive, Step, Sweep

#: Largest error tried per field, as a function of the diameter (the first bisection bound).
SEARCH_MAX: dict[str, Callable[[float], float]] = {
    "distance": lambda d: 1.5 * d,
    "direction": lambda d: math.radians(90.0),
    "angle": lambda d: math.radians(60.0),
}
SCAN_EVERY = 0.05  # m
#: Everything printed, kept for ``--write-docs``.
OUTPUT: list[str] = []


def emit(line: str = "") -> None:
    """Print ``line`` and keep it for the docs section."""
    print(line, flush=True)
    OUTPUT.append(line)


def survives(net: PipeNetwork, field: str, error: float, **executor_args: Any) -> bool:
    """Whether take_turn with the first true option's ``field`` off by ``error`` passes;
    ``executor_args`` go to :meth:`Executor.for_network` (e.g. ``timestep``, ``control_dt``)."""
    ex = Executor.for_network(net, lidar=None, **executor_args)
    true = structures_ahead(net, ex.robot.sensor_pose(), 5.0)[0]
    value = getattr(true, field) + error
    if field == "angle" and value < 0:
        value = 0.0
    option: StructureOption = replace(true, **{field: value})
    out = ex.run(take_turn(option, ex.robot.clamped_diameter()))
    if out.status != "done":
        return False
    ep, _ = locate(net, ex.robot.sensor_pose())
    return ep.run_id == "r_out0"


def bound(net: PipeNetwork, field: str, sign: float, hi: float, iterations: int) -> float:
    """Largest |error| (with ``sign``) that survives, by bisection on [0, hi]."""
    if not survives(net, field, 0.0):
        return float("nan")
    if survives(net, field, sign * hi):
        return hi
    lo = 0.0
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if survives(net, field, sign * mid):
            lo = mid
        else:
            hi = mid
    return lo


def tolerance_table(args: argparse.Namespace) -> None:
    styles = ["mitre"] + (["long"] if args.long else [])
    emit("Tolerance study: largest option error take_turn survives (90 deg bends)")
    emit(
        f"roll directions {args.directions} deg, {args.iterations} bisection steps; "
        "min over directions (per direction in brackets)"
    )
    header = (
        f"{'bend':6s} {'D mm':>5s}  {'distance -':>16s} {'distance +':>16s}  "
        f"{'direction -':>11s} {'direction +':>11s}  {'angle -':>8s} {'angle +':>8s}"
    )
    emit(header)
    for style in styles:
        make = layouts.mitre_bend if style == "mitre" else layouts.long_bend
        for d in args.diameters:
            cells = {}
            for field in ("distance", "direction", "angle"):
                for sign in (-1.0, 1.0):
                    per_dir = []
                    for r in args.directions:
                        net = make(d, math.pi / 2, math.radians(r))
                        per_dir.append(
                            bound(net, field, sign, SEARCH_MAX[field](d), args.iterations)
                        )
                    cells[(field, sign)] = per_dir
            row = f"{style:6s} {d * 1000:5.0f}  "
            for sign in (-1.0, 1.0):
                v = min(cells[("distance", sign)])
                row += f"{v * 1000:5.1f} mm {v / d:4.2f}D "
            row += " "
            for field in ("direction", "angle"):
                for sign in (-1.0, 1.0):
                    v = min(cells[(field, sign)])
                    row += f"{math.degrees(v):7.1f}d   "[:12]
                row += " "
            emit(row.rstrip())
            detail = "        per direction: " + "; ".join(
                f"{f} {'+' if s > 0 else '-'} "
                + "/".join(
                    f"{v * 1000:.0f}mm" if f == "distance" else f"{math.degrees(v):.0f}d"
                    for v in vs
                )
                for (f, s), vs in cells.items()
            )
            emit(detail)


def with_scans(seq: Sequence) -> Sequence:
    """``seq`` with a stop-and-scan sweep every ``SCAN_EVERY`` m of forward driving."""
    steps: list[Step] = []
    for s in seq.steps:
        if isinstance(s, Drive) and s.distance > 0:
            left = s.distance
            while left > 1e-9:
                piece = min(SCAN_EVERY, left)
                steps += [Sweep(), Drive(piece, s.speed)]
                left -= piece
        else:
            steps.append(s)
    return Sequence(seq.name + "+scan", tuple(steps))


def speed_table(diameter: float) -> None:
    emit()
    emit(f"Speed (simulated s per wall s), {diameter * 1000:.0f} mm pipe, ideal LiDAR sweeps")
    straight = layouts.straight(diameter, 2.0)
    mitre = layouts.mitre_bend(diameter, math.pi / 2, 0.0)
    cases = []
    for scan in (False, True):
        ex = Executor.for_network(straight, lidar="ideal")
        seq = go_straight(1.0)
        cases.append(("drive 1 m", scan, ex, with_scans(seq) if scan else seq))
        ex = Executor.for_network(mitre, lidar="ideal")
        o = structures_ahead(mitre, ex.robot.sensor_pose(), 5.0)[0]
        seq = take_turn(o, ex.robot.clamped_diameter())
        cases.append(("90 deg mitre turn", scan, ex, with_scans(seq) if scan else seq))
    emit(
        f"{'motion':18s} {'scanning':9s} {'status':7s} {'sim s':>7s} {'wall s':>7s} "
        f"{'sim/wall':>9s} {'sweeps':>6s}"
    )
    for name, scan, ex, seq in sorted(cases, key=lambda c: (c[0], c[1])):
        t0 = time.perf_counter()
        out = ex.run(seq)
        wall = time.perf_counter() - t0
        sweeps = sum(isinstance(s, Sweep) for s in seq.steps)
        emit(
            f"{name:18s} {'yes' if scan else 'no':9s} {out.status:7s} {out.duration:7.2f} "
            f"{wall:7.2f} {out.duration / wall:9.2f} {sweeps:6d}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--diameters", type=float, nargs="+", default=[0.06, 0.09, 0.12])
    parser.add_argument("--directions", type=float, nargs="+", default=[0.0, 135.0])
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--long", action="store_true", help="also long-radius bends")
    parser.add_argument("--skip-tolerance", action="store_true")
    parser.add_argument("--skip-speed", action="store_true")
    parser.add_argument(
        "--write-docs", action="store_true", help="write the tables to docs/benchmarks.md"
    )
    args = parser.parse_args()
    t0 = time.perf_counter()
    if not args.skip_tolerance:
        tolerance_table(args)
    if not args.skip_speed:
        speed_table(0.09)
    print(f"\ntotal wall time {time.perf_counter() - t0:.0f} s")
    if args.write_docs:
        sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
        from benchmarks.report import write_section

        argv = [a for a in sys.argv[1:] if a != "--write-docs"]
        command = " ".join(["python benchmarks/bench_primitives.py", *argv])
        text = "\n".join([f"`{command}`", "", "```", *OUTPUT, "```"])
        print(f"wrote {write_section('primitives', text)}")


if __name__ == "__main__":
    main()
