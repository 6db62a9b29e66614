"""The improved detector under a clamped-diameter error: the clamp's encoders read the pipe
diameter to a millimetre or two (the full-fidelity robot's readings scatter by about that), and
a wrong radius once turned the whole wall of a gentle reducer into a taper."""

from __future__ import annotations

import math

import pytest
from detector_scans import match, scan_layout, wrap

from detector import detect

#: The small reducer of a generated network that the full-fidelity robot met 3 cm early.
SMALL_REDUCER = {"diameter_in": 0.0995, "diameter_out": 0.0876, "taper_length": 0.0838}


@pytest.mark.parametrize("clamp_error", [-0.002, 0.002])
def test_reducer_distance_survives_a_clamp_error(clamp_error: float) -> None:
    scan, truth, d = scan_layout("reducer", 0.4, **SMALL_REDUCER)
    det = detect(scan, d + clamp_error)
    assert det.kind == "reducer", det.describe()
    assert abs(det.options[0].distance - truth[0].distance) < 0.01
    assert abs(det.options[0].diameter - truth[0].diameter) < 0.002
    # the wall measured its own radius: within a fifth of a millimetre of the drawing
    assert abs(det.diagnostics["wall_radius"] - 0.5 * d) < 0.0002


def test_bend_diameter_is_the_walls_not_the_clamps() -> None:
    scan, truth, d = scan_layout(
        "mitre_bend", 0.3, diameter=0.1, angle=math.radians(60), direction=1.0
    )
    det = detect(scan, d - 0.0015)
    assert det.kind == "bend", det.describe()
    ((o, t),) = match(det.options, truth)
    assert abs(o.diameter - t.diameter) < 0.0005
    assert abs(o.distance - t.distance) < 0.01
    assert abs(o.angle - t.angle) < math.radians(1.0)
    assert abs(wrap(o.direction - t.direction)) < math.radians(2.0)


def test_exact_clamp_reading_is_kept() -> None:
    # within the dead band the clamp reading stands (no correction recorded)
    scan, _, d = scan_layout("mitre_bend", 0.3, diameter=0.1, angle=math.radians(60), direction=1.0)
    det = detect(scan, d)
    assert "wall_radius" not in det.diagnostics
