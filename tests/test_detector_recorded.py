"""The improved detector on sweeps recorded in full-fidelity episodes (``tests/data``): cases
where the robot's own scans showed a failure the layout scans of the accuracy study did not."""

from __future__ import annotations

import math
from pathlib import Path

from detector import detect
from detector.scan import Scan

DATA = Path(__file__).parent / "data"


def test_wide_bend_just_ahead_keeps_the_given_axis() -> None:
    # long_bend_90mm: 60 deg, R = 2 D, the sensor 10 cm before the arc and 20 cm before the
    # reference point; the wall in view is almost all arc. A cylinder tilted by 7 deg about
    # the nearest wall, 11.6 mm off, explained a few more returns and turned the bend into
    # 53 deg; the sensor was in fact centred (0.2 mm, 0.3 deg).
    scan = Scan.load(DATA / "long_bend_90mm_10cm_before_its_arc.npz")
    det = detect(scan, 0.0902)
    assert det.kind == "bend", det.describe()
    (o,) = det.options
    assert det.diagnostics["axis_pass"] == 0
    assert abs(o.distance - 0.20) < 0.01
    assert abs(o.angle - math.radians(60.0)) < math.radians(2.0)
    assert abs(o.bend_radius - 0.18) < 0.01


def test_opening_of_a_tee_farther_along_the_run_is_no_way_on() -> None:
    # loops_network_3d: a cross 18.5 cm ahead in a 112 mm pipe, and 0.85-1.1 m ahead a tee of
    # the loop's bypass seen past it; its opening once became a fourth way on, 30 deg up,
    # which the route planner took and jammed in
    scan = Scan.load(DATA / "cross_with_a_tee_farther_on_112mm.npz")
    det = detect(scan, 0.1125)
    assert det.kind == "junction", det.describe()
    assert len(det.options) == 3, det.describe()
    assert det.diagnostics["lobes_farther_on"] == 1
    angles = sorted(round(math.degrees(o.angle)) for o in det.options)
    assert angles == [0, 90, 90]
