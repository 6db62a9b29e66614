"""Regression: a far wall seen head-on that does not tell which way the turn goes is no turn.

The LS02 in a 60 mm pipe sees a 90 deg bend 35-40 cm ahead only as the far wall of the
outgoing pipe, with no returns through its opening. That wall is curved (so not an end wall),
but a cylinder's axis has no sign and, for a 90 deg turn, the wall lies about evenly to both
sides of the axis' foot: its direction once came out mirrored (180 deg off, confidence 1), and
the robot turned the wrong way and jammed.
"""

from __future__ import annotations

import math

from detector_scans import scan_layout, wrap

from detector import detect

BEND = {"diameter": 0.06, "angle": math.pi / 2, "direction": 0.0}


def test_far_wall_of_a_square_turn_gives_no_direction():
    # (seeds 0 and 3 at 40 cm and 1 at 35 cm gave the mirrored direction)
    for dist, seed in ((0.40, 0), (0.40, 3), (0.35, 1)):
        scan, truth, d = scan_layout("mitre_bend", dist, sensor="ls02", seed=seed, **BEND)
        det = detect(scan, d)
        assert det.kind not in ("bend", "junction"), (dist, seed, det.describe())
        assert det.diagnostics.get("far_wall_way_undetermined"), (dist, seed, det.diagnostics)
        assert det.kind in ("closure", "straight")


def test_square_turn_seen_through_its_opening_keeps_its_direction():
    # nearer, the returns through the opening give the way on: the refusal does not get in
    # the way of the turn
    scan, truth, d = scan_layout("mitre_bend", 0.15, sensor="ls02", seed=0, **BEND)
    det = detect(scan, d)
    assert det.kind == "bend", det.describe()
    assert abs(wrap(det.options[0].direction - truth[0].direction)) < math.radians(10.0)
    assert abs(det.options[0].angle - truth[0].angle) < math.radians(5.0)


def test_far_wall_of_a_shallower_turn_still_gives_its_direction():
    # a 75 deg turn's far wall lies mostly along the way on: decisive, reported
    scan, truth, d = scan_layout(
        "mitre_bend", 0.35, diameter=0.057, angle=math.radians(75), direction=-2.9
    )
    det = detect(scan, d)
    assert det.kind == "bend", det.describe()
    assert det.diagnostics["far_wall_lean"] > 0.15
    assert abs(wrap(det.options[0].direction - truth[0].direction)) < math.radians(2.0)
