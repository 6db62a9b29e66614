"""The improved single-plane detector (``detect_planar(..., method="improved")``) next to thesis
Algorithm 1, and the option order every method shares."""

from __future__ import annotations

import math

import numpy as np
import pytest
from detector_scans import match, scan_layout, wrap

from detector import Detection, StructureOption, detect, detect_planar
from detector.geometry import Pose
from detector.options import option_order
from detector.scan import corrected_ranges, radial_noise
from pipe_env.lidar import PRESETS

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


@pytest.mark.parametrize("method, angle_tol", [("thesis", 10.0), ("improved", 1.0)])
def test_cross_junction_options_come_straight_on_first_then_by_roll(method, angle_tol):
    scan, truth, d = scan_layout("cross_junction", 0.2, diameter=0.1, direction=0.9)
    det = detect(scan, d, method)
    assert det.kind == "junction", det.describe()
    # straight on, then the branches by roll: down-right (0.9 - pi), then up-left (0.9)
    expected = [(0.0, 0.0), (math.pi / 2, 0.9 - math.pi), (math.pi / 2, 0.9)]
    assert len(det.options) == len(expected), det.describe()
    for o, (angle, direction) in zip(det.options, expected):
        assert abs(o.distance - 0.2) <= 0.01, o
        assert abs(o.angle - angle) <= math.radians(angle_tol), o
        if angle > 0.0:
            assert abs(wrap(o.direction - direction)) <= math.radians(2.0), o


def test_detection_sorts_its_options_straight_on_first_then_by_roll():
    ways = [(math.pi / 2, 2.0), (0.0, 0.0), (math.pi / 2, -1.0)]
    opts = [StructureOption("junction", 0.2, 0.1, d, a) for a, d in ways]
    det = Detection("junction", opts, 1.0)
    assert [(o.angle, o.direction) for o in det.options] == [ways[1], ways[2], ways[0]]
    assert [option_order(o) for o in det.options] == [(0, 0.0), (1, -1.0), (1, 2.0)]


def _planar_cross(distance):
    return scan_layout("cross_junction", distance, planar=True, diameter=0.1, direction=0.0)


@pytest.mark.parametrize("method, distance", [("thesis", 0.15), ("improved", 0.2)])
def test_planar_cross_junction_straight_on_left_right(method, distance):
    scan, truth, d = _planar_cross(distance)
    det = detect_planar(scan, d, method)
    assert det.kind == "junction", det.describe()
    # straight on, then left (roll 0), then right (roll pi)
    expected = [(0.0, 0.0), (math.pi / 2, 0.0), (math.pi / 2, math.pi)]
    assert len(det.options) == len(expected), det.describe()
    for o, (angle, direction) in zip(det.options, expected):
        assert abs(o.distance - distance) <= 0.01, o
        assert abs(o.angle - angle) <= math.radians(2.0), o
        if angle > 0.0:
            assert abs(wrap(o.direction - direction)) <= 1e-6, o


def test_thesis_planar_misses_a_cross_junction_whose_mean_diameter_matches():
    # thesis Algorithm 1 step B: from 20 cm the far wall seen through the junction pulls the
    # mean diameter of the two sides back to within 5 mm of the clamped one, so the plane
    # reads as straight pipe (a limitation of the thesis's method, kept as it describes it)
    scan, truth, d = _planar_cross(0.2)
    det = detect_planar(scan, d, "thesis")
    assert truth and det.kind == "straight"
    assert abs(det.diagnostics["d_lidar"] - d) <= 0.005


def test_planar_method_is_checked():
    scan, truth, d = scan_layout("closure", 0.2, planar=True, diameter=0.1)
    with pytest.raises(ValueError, match="planar method"):
        detect_planar(scan, d, "magic")
    det = detect_planar(scan, d, "improved")
    assert det.kind == "closure", det.describe()
    assert abs(det.options[0].distance - truth[0].distance) <= 0.01


def _roll(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@pytest.mark.parametrize("roll", [0.5, math.pi / 2, math.pi])
def test_improved_planar_with_a_known_rolled_sensor(roll):
    # the sensor rolled about the pipe axis, its pose given: the plane's sideways direction
    # must be taken into the pipe frame with the points (a straight pipe read as a reducer
    # to 88 mm at 0.5 rad, a closure at 90 deg, when it was not)
    pose = (np.zeros(3), _roll(roll))
    mis = Pose(np.zeros(3), _roll(roll))
    for layout, distance in (("straight", 0.0), ("closure", 0.3)):
        scan, truth, d = scan_layout(layout, distance, planar=True, misalignment=mis, diameter=0.1)
        det = detect_planar(scan, d, "improved", sensor_in_pipe=pose)
        assert det.kind == ("closure" if truth else "straight"), det.describe()
        if truth:
            assert abs(det.options[0].distance - truth[0].distance) <= 0.01, det.describe()


def test_improved_planar_bend_with_a_known_rolled_sensor():
    # a bend up (world) lies in the plane of a sensor rolled by 90 deg: to its left (roll 0)
    scan, truth, d = scan_layout(
        "mitre_bend", 0.3, planar=True, misalignment=Pose(np.zeros(3), _roll(math.pi / 2)),
        diameter=0.1, angle=math.pi / 2, direction=math.pi / 2,
    )  # fmt: skip
    det = detect_planar(scan, d, "improved", sensor_in_pipe=(np.zeros(3), _roll(math.pi / 2)))
    assert det.kind == "bend", det.describe()
    (o,) = det.options
    assert abs(wrap(o.direction - truth[0].direction)) <= 1e-6 and abs(truth[0].direction) < 1e-6
    assert abs(o.distance - truth[0].distance) <= 0.01
    assert abs(o.angle - truth[0].angle) <= math.radians(1.0)


def test_improved_planar_reads_range_quantisation_as_uniform_error():
    # a sensor quantising ranges to 3 mm: the error is uniform, of standard deviation
    # 3 mm / sqrt(12) (the 3D method's model), not 3 mm; taken as 3 mm, the tolerance hid the
    # start of the taper and the reducer was placed 2.5 cm too far
    spec = PRESETS["ideal"].with_(range_resolution=0.003, name="coarse")
    scan, truth, d = scan_layout(
        "reducer", 0.25, sensor=spec, planar=True,
        diameter_in=0.1, diameter_out=0.085, taper_length=0.05,
    )  # fmt: skip
    det = detect_planar(scan, d, "improved")
    assert det.kind == "reducer", det.describe()
    assert abs(det.options[0].distance - truth[0].distance) <= 0.01, det.describe()
    assert abs(det.options[0].diameter - truth[0].diameter) <= 0.002, det.describe()


def test_shared_sensor_noise_model():
    spec = {"noise_sigma": 0.002, "range_resolution": 0.005, "angular_jitter": 0.001}
    ranges = corrected_ranges(np.array([0.01, 0.5, 1.0]), 0.02)
    assert ranges.tolist() == [0.0, 0.48, 0.98]  # (never below 0 m)
    s, c = np.array([1.0, 0.6, 0.0]), np.array([0.0, 0.8, 1.0])
    sigma_range, sigma_r = radial_noise(spec, ranges, s, c)
    expected = math.sqrt(0.002**2 + 0.005**2 / 12.0)
    assert sigma_range == pytest.approx([expected] * 3)
    assert sigma_r == pytest.approx(expected * s + ranges * 0.001 * c)
    rel = radial_noise({"noise_sigma_rel": 0.01}, ranges, s, c)[0]
    assert rel == pytest.approx(0.01 * ranges)


@pytest.mark.parametrize("distance", [0.4, 0.3, 0.2, 0.15])
def test_improved_planar_tee_under_ydlidar_noise(distance):
    # the thesis's practical 2D tee (11.8 cm pipe, YDLidar X4): from 30-40 cm the branch shows
    # 3-8 returns on its far wall, which fit 45, 90 and 135 deg alike; where the incoming
    # wall ends tells them apart (the branch was fitted 45-135 deg, 5-7 cm off). From 15-20 cm
    # the branch's far wall lies near the incoming wall's line and tilted the wall frame (read
    # as a reducer at 15 cm)
    for seed in range(6):
        scan, truth, d = scan_layout(
            "t_junction", distance, sensor="ydlidar_x4", seed=seed, planar=True,
            diameter=0.118, direction=0.0,
        )  # fmt: skip
        det = detect_planar(scan, d, "improved")
        assert det.kind == "junction", det.describe()
        assert len(det.options) == len(truth) == 2, det.describe()
        for o, t in match(det.options, truth):
            assert abs(o.distance - t.distance) <= 0.02, (seed, o, t)
            assert abs(o.angle - t.angle) <= math.radians(5.0), (seed, o, t)
            assert abs(wrap(o.direction - t.direction)) <= math.radians(5.0), (seed, o, t)


@pytest.mark.parametrize("distance", [0.4, 0.35, 0.3, 0.25])
def test_improved_planar_narrow_mitre_opening(distance):
    # the thesis's 2D mitre (90 deg, 60 mm, ideal sensor): 25-40 cm ahead the opening shows
    # 1-9 returns 3-5 mm beyond the wall's line, on the face seen ahead; an end wall has none
    # there (read as a closure at the far wall before)
    scan, truth, d = scan_layout(
        "mitre_bend", distance, planar=True, diameter=0.06, angle=math.pi / 2, direction=math.pi
    )
    det = detect_planar(scan, d, "improved")
    assert det.kind == "bend", det.describe()
    (o,) = det.options
    assert abs(o.distance - truth[0].distance) <= 0.01, det.describe()
    assert abs(o.angle - truth[0].angle) <= math.radians(1.0), det.describe()
    assert abs(wrap(o.direction - truth[0].direction)) <= 1e-6, det.describe()


@pytest.mark.parametrize("sensor", ["ydlidar_x4", "ls02"])
def test_improved_planar_noisy_closure_shows_no_face_opening(sensor):
    # range noise puts no return beyond the wall's line on one side of an end wall only
    for distance in (0.4, 0.2):
        for seed in range(4):
            scan, truth, d = scan_layout(
                "closure", distance, sensor=sensor, seed=seed, planar=True, diameter=0.06
            )
            det = detect_planar(scan, d, "improved")
            assert det.kind == "closure", (seed, det.describe())
            assert abs(det.options[0].distance - truth[0].distance) <= 0.02, det.describe()
