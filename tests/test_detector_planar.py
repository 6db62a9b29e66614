"""The improved single-plane detector (``detect_planar(..., method="improved")``) next to thesis
Algorithm 1, and the option order every method shares."""

from __future__ import annotations

import math

import numpy as np
import pytest
from detector_scans import match, scan_layout

from detector import detect, detect_planar
from detector.options import option_order

PLANAR = [
    ("mitre_bend", 0.2, {"diameter": 0.06, "angle": math.pi / 2, "direction": math.pi}),
    ("mitre_bend", 0.3, {"diameter": 0.1, "angle": math.pi / 2, "direction": math.pi}),
    ("mitre_bend", 0.25, {"diameter": 0.1, "angle": math.pi / 4, "direction": 0.0}),
    ("t_junction", 0.2, {"diameter": 0.1, "direction": 0.0, "entry": "stem"}),
    ("closure", 0.3, {"diameter": 0.1}),
    ("reducer", 0.25, {"diameter_in": 0.1, "diameter_out": 0.07, "taper_length": 0.1}),
]


@pytest.mark.parametrize("layout, distance, params", PLANAR)
def test_improved_planar_ideal_sensor(layout, distance, params):
    scan, truth, d = scan_layout(layout, distance, planar=True, **params)
    det = detect_planar(scan, d, "improved")
    assert det.kind == truth[0].kind, det.describe()
    assert len(det.options) == len(truth), det.describe()
    for o, t in match(det.options, truth):
        assert abs(o.distance - t.distance) <= 0.01, (o, t)
        if t.kind != "closure":
            assert abs(o.diameter - t.diameter) <= 0.002, (o, t)
        assert abs(o.angle - t.angle) <= math.radians(1.0), (o, t)
    assert 0.0 < det.confidence <= 1.0


def test_improved_planar_beats_the_thesis_on_the_outgoing_diameter():
    # thesis Algorithm 1 reads the gap size as the diameter: far off for a 45 deg bend
    scan, truth, d = scan_layout(
        "mitre_bend", 0.3, planar=True, diameter=0.1, angle=math.pi / 4, direction=0.0
    )
    thesis = detect_planar(scan, d, "thesis")
    improved = detect_planar(scan, d, "improved")
    assert thesis.kind == improved.kind == "bend"
    err_t = abs(thesis.options[0].diameter - truth[0].diameter)
    err_i = abs(improved.options[0].diameter - truth[0].diameter)
    assert err_i < 0.002 < err_t


def test_improved_planar_straight_pipe_with_noise():
    for seed in range(3):
        scan, truth, d = scan_layout(
            "straight", 0.0, sensor="ydlidar_x4", seed=seed, planar=True, diameter=0.1
        )
        assert not truth
        assert detect_planar(scan, d, "improved").kind == "straight"


@pytest.mark.parametrize("method", ["thesis", "improved"])
def test_options_follow_option_order(method):
    scan, truth, d = scan_layout("cross_junction", 0.2, diameter=0.1, direction=0.9)
    det = detect(scan, d, method)
    assert len(det.options) >= 2
    assert det.options == sorted(det.options, key=option_order)
    assert det.options[0].is_straight_on
    planar = detect_planar(
        scan_layout("cross_junction", 0.2, planar=True, diameter=0.1, direction=0.0)[0],
        d,
        method,
    )
    assert planar.options == sorted(planar.options, key=option_order)


def test_planar_method_is_checked():
    scan, _, d = scan_layout("closure", 0.2, planar=True, diameter=0.1)
    with pytest.raises(ValueError, match="planar method"):
        detect_planar(scan, d, "magic")
    assert np.isfinite(detect_planar(scan, d, "improved").confidence)
