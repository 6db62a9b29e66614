"""How the sensing calibration scores a fused estimate against the truth
(``benchmarks/calibrate_sensing.py``): gross errors, and long bends seen in part."""

from __future__ import annotations

import math

from benchmarks import calibrate_sensing as cs
from detector.detection import Detection
from detector.options import StructureOption


def _bend(distance: float, angle_deg: float, radius: float) -> StructureOption:
    return StructureOption(
        "bend", distance, 0.07, direction=0.5, angle=math.radians(angle_deg), bend_radius=radius
    )


def test_a_long_bend_read_short_of_its_angle_is_scored_at_its_arc_start() -> None:
    # a 90 deg, R = 0.15 m bend seen in part as 65 deg: the reference point reads
    # R (tan 45 - tan 32.5) = 54 mm nearer, the arc's start is right
    truth = _bend(0.30, 90.0, 0.15)
    start = 0.30 - 0.15 * math.tan(math.radians(45.0))
    read = _bend(start + 0.15 * math.tan(math.radians(32.5)), 65.0, 0.15)
    rec = cs.score_sample("long_bend", 0.07, Detection("bend", [read], 1.0, {}), [truth])
    assert rec["matched"] == 1 and rec["lower_bound"] == 1
    ((e_dist, e_diam, e_ang, e_dir, bad, _),) = rec["errors"]
    assert abs(e_dist) < 1e-12 and e_ang is None and not bad
    model = cs.aggregate("x", [rec])
    assert model["lower_bound_rate"] == 1.0 and model["gross_rate"] == 0.0


def test_a_long_bend_read_beyond_its_angle_or_a_mitre_read_short_stays_gross() -> None:
    over = _bend(0.32, 100.0, 0.15)
    rec = cs.score_sample(
        "long_bend", 0.07, Detection("bend", [over], 1.0, {}), [_bend(0.30, 90.0, 0.15)]
    )
    assert rec["lower_bound"] == 0 and rec["errors"][0][4]
    # a mitre bend (no radius) read 20 deg short is a gross angle error
    short = _bend(0.30, 70.0, 0.0)
    rec = cs.score_sample(
        "mitre_bend", 0.07, Detection("bend", [short], 1.0, {}), [_bend(0.30, 90.0, 0.0)]
    )
    assert rec["lower_bound"] == 0
    ((_, _, e_ang, _, bad, _),) = rec["errors"]
    assert e_ang is not None and bad
    assert cs.aggregate("x", [rec])["gross_rate"] == 1.0
