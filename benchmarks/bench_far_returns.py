"""Bounded work on far returns: the detector's time and peak memory on scans whose returns are
scaled far out (x 1e2 ... x 1e300, all finite, no spec limits), against the same scan as
recorded, measured in the same run.

Prints, per layout and method, the reference (time, tracemalloc peak) and the worst ratio
over the scalings and the fractions of returns scaled. Run:
``python benchmarks/bench_far_returns.py``.
"""

from __future__ import annotations

import dataclasses
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from detector_scans import scan_layout  # noqa: E402

from detector import detect  # noqa: E402

LAYOUTS = ("closure", "straight", "reducer", "mitre_bend", "t_junction")
SCALES = (1e2, 1e4, 1e8, 1e300)
FRACTIONS = (0.01, 0.2, 1.0)


def _measure(scan, d: float, method: str) -> tuple[float, float]:
    """(seconds, peak bytes) of one detection."""
    tracemalloc.start()
    t0 = time.perf_counter()
    detect(scan, d, method)
    dt = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return dt, peak


def main() -> int:
    rng = np.random.default_rng(0)
    print("| layout | method | reference ms | reference MB | worst far ms | worst far MB |")
    print("|---|---|---|---|---|---|")
    worst_t = worst_m = 0.0
    for layout in LAYOUTS:
        scan, _, d = scan_layout(layout, 0.4)
        base = dataclasses.replace(scan, spec={})
        for method in ("improved", "thesis"):
            detect(base, d, method)  # (warm up: imports, compiled kernels)
            ref_t, ref_m = _measure(base, d, method)
            far_t = far_m = 0.0
            for scale in SCALES:
                for frac in FRACTIONS:
                    pick = (rng.random(scan.ranges.shape) < frac) & scan.valid
                    far = dataclasses.replace(
                        base, ranges=np.where(pick, scan.ranges * scale, scan.ranges)
                    )
                    t, m = _measure(far, d, method)
                    far_t, far_m = max(far_t, t), max(far_m, m)
            worst_t, worst_m = max(worst_t, far_t), max(worst_m, far_m)
            print(
                f"| {layout} | {method} | {ref_t * 1e3:.1f} | {ref_m / 1e6:.2f} | "
                f"{far_t * 1e3:.1f} | {far_m / 1e6:.2f} |"
            )
    print(f"worst over all far scans: {worst_t * 1e3:.1f} ms, {worst_m / 1e6:.2f} MB peak")
    return 0


if __name__ == "__main__":
    sys.exit(main())
