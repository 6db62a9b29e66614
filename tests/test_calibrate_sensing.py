"""How the sensing calibration scores a fused estimate against the truth
(``benchmarks/calibrate_sensing.py``): gross errors, and long bends seen in part."""

from __future__ import annotations

import math

import pytest

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
    assert rec["shortfalls"] == [pytest.approx(math.radians(25.0))]
    model = cs.aggregate("x", [rec])
    assert model["lower_bound_rate"] == 1.0 and model["gross_rate"] == 0.0
    assert abs(model["lower_bound_sigma"] - math.radians(25.0)) < 1e-5


def test_a_short_reading_with_its_arc_elsewhere_is_no_lower_bound() -> None:
    truth = _bend(0.30, 90.0, 0.15)
    start = 0.30 - 0.15 * math.tan(math.radians(45.0))
    # its arc starting 3 cm late: gross, not a lower bound
    late = _bend(start + 0.03 + 0.15 * math.tan(math.radians(32.5)), 65.0, 0.15)
    rec = cs.score_sample("long_bend", 0.07, Detection("bend", [late], 1.0, {}), [truth])
    assert rec["lower_bound"] == 0 and rec["errors"][0][4]
    # another radius (half the true one): its angle is scored, a gross error
    other = _bend(0.25, 65.0, 0.075)
    rec = cs.score_sample("long_bend", 0.07, Detection("bend", [other], 1.0, {}), [truth])
    assert rec["lower_bound"] == 0 and rec["errors"][0][2] is not None and rec["errors"][0][4]
    assert cs.aggregate("x", [rec])["lower_bound_rate"] == 0.0


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


def test_the_fast_fidelity_reads_long_bends_short_as_calibrated() -> None:
    import numpy as np

    from pipe_env.envs.sensing_model import DetectionErrorModel

    model = DetectionErrorModel("m", lower_bound_rate=0.5, lower_bound_sigma=math.radians(20.0))
    truth = _bend(0.30, 90.0, 0.15)
    start = 0.30 - 0.15 * math.tan(math.radians(45.0))
    rng = np.random.default_rng(0)
    reads = [model.apply([truth], rng)[0] for _ in range(400)]
    short = [o for o in reads if o.angle < truth.angle - 1e-9]
    # about half read short, never long, each with its arc's start and radius kept
    assert 160 <= len(short) <= 240
    assert all(o.angle <= truth.angle + 1e-12 for o in reads)
    for o in short:
        assert o.angle >= math.radians(5.0) - 1e-12 and o.bend_radius == truth.bend_radius
        assert abs(o.distance - o.bend_radius * math.tan(0.5 * o.angle) - start) < 1e-12
    # a mitre bend (no radius) is never read short
    mitre = _bend(0.30, 90.0, 0.0)
    assert all(model.apply([mitre], rng)[0].angle == mitre.angle for _ in range(50))
