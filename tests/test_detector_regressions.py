"""Regressions of the improved detector: failure modes found in the accuracy study, each pinned
by one cheap scan (ideal sensor, 57 mm pipe, structure 30-40 cm ahead), and the fast paths."""

from __future__ import annotations

import math

import numpy as np
import pytest
from detector_scans import match, rot_tilt, scan_layout, wrap

from detector import Detection, StructureOption, detect
from detector.robust import robust_gauss_newton
from pipe_env.geometry import Pose


def _assert_ways_within(
    det: Detection,
    truth: list,
    n_ways: int,
    distance: float,
    diameter: float | None,
    angle_deg: float,
    direction_deg: float | None = None,
) -> None:
    """``det`` is a junction with ``n_ways`` ways on, each (matched to the truth) within
    ``distance`` and ``diameter`` (m, ``None``: not checked) and ``angle_deg`` and
    ``direction_deg`` (deg, ``None``: not checked) of its true way."""
    assert det.kind == "junction" and len(det.options) == n_ways, det.describe()
    for o, t in match(det.options, truth):
        assert abs(o.distance - t.distance) < distance, det.describe()
        if diameter is not None:
            assert abs(o.diameter - t.diameter) < diameter, det.describe()
        assert abs(o.angle - t.angle) < math.radians(angle_deg), det.describe()
        if direction_deg is not None:
            assert abs(wrap(o.direction - t.direction)) < math.radians(direction_deg)


def _long_bend_seen(
    distance: float, diameter: float, angle: float, direction: float, radius_factor: float
) -> tuple[Detection, StructureOption, StructureOption]:
    """A long bend's reference point ``distance`` m ahead (ideal sensor), detected: the
    detection (asserted a bend), its option and the true one."""
    scan, truth, d = scan_layout(
        "long_bend",
        distance,
        diameter=diameter,
        angle=angle,
        direction=direction,
        radius_factor=radius_factor,
    )
    det = detect(scan, d)
    assert det.kind == "bend", det.describe()
    ((o, t),) = match(det.options, truth)
    return det, o, t


def test_widening_with_an_end_wall_far_down_is_a_reducer():
    # the end wall of the wider pipe once counted as "inside" returns and turned the widening
    # into a junction; the start of the widening is the edge where the beams leave the
    # incoming pipe (within one beam step: 0.5 deg is ~2.7 cm along the axis here)
    scan, truth, d = scan_layout(
        "reducer", 0.3, diameter_in=0.057, diameter_out=0.08, taper_length=0.16
    )
    det = detect(scan, d)
    assert det.kind == "reducer", det.describe()
    assert abs(det.options[0].diameter - 0.08) < 0.002
    assert abs(det.options[0].distance - truth[0].distance) < 0.02


def test_curved_far_wall_seen_head_on_is_not_a_closure():
    # from the stem of a small tee far away only the back wall of the run is seen: nearly flat
    # in a 2.8 mm tolerance, it once passed for an end wall; it runs on evenly to both sides,
    # so both ways of the run are open
    scan, truth, d = scan_layout("t_junction", 0.4, diameter=0.057, direction=-2.5, entry="stem")
    det = detect(scan, d)
    assert det.kind == "junction" and len(det.options) == 2, det.describe()
    for o, t in match(det.options, truth):
        assert abs(o.distance - t.distance) < 0.01
        assert abs(o.angle - t.angle) < math.radians(1.0)
        assert abs(wrap(o.direction - t.direction)) < math.radians(2.0)


def test_far_wall_of_a_turn_gives_the_way_on_not_its_mirror():
    # a patch of the outgoing pipe fits a cylinder on either side of it; the sensor can only
    # see a wall from inside its pipe
    scan, truth, d = scan_layout(
        "mitre_bend", 0.35, diameter=0.057, angle=math.radians(75), direction=-2.9
    )
    det = detect(scan, d)
    assert det.kind == "bend", det.describe()
    ((o, t),) = match(det.options, truth)
    assert abs(o.distance - t.distance) < 0.01
    assert abs(o.angle - t.angle) < math.radians(1.0)
    assert abs(wrap(o.direction - t.direction)) < math.radians(2.0)


def test_small_end_wall_far_away_stays_a_closure():
    scan, truth, d = scan_layout("closure", 0.4, diameter=0.057)
    det = detect(scan, d)
    assert det.kind == "closure", det.describe()
    assert abs(det.options[0].distance - truth[0].distance) < 0.005
    assert det.diagnostics["closure_plane_rms"] < 0.001


def test_straight_pipe_takes_the_early_exit():
    # the nominal pose explains every return: nothing is refined
    scan, _, d = scan_layout("straight", 0.0, diameter=0.1)
    det = detect(scan, d)
    assert det.kind == "straight"
    assert det.diagnostics["axis_pass"] == 0 and det.diagnostics["n_anomaly"] == 0
    assert det.diagnostics["n_wall"] > 1000
    # an offset sensor: the returns leave the wall tolerance until the axis is refined
    offset = Pose(np.array([0.0, 0.01, 0.0]), np.eye(3))
    scan, _, d = scan_layout("straight", 0.0, diameter=0.1, misalignment=offset)
    det = detect(scan, d)
    assert det.kind == "straight"
    assert det.diagnostics["axis_pass"] == 1 and det.diagnostics["n_anomaly"] == 0
    assert abs(det.diagnostics["axis_offset"][0] + 0.01) < 0.001
    closure, _, d = scan_layout("closure", 0.3, diameter=0.1)
    assert detect(closure, d).kind == "closure"


def test_pinned_parameters_stay_put_and_the_fit_converges():
    rng = np.random.default_rng(0)
    x = np.linspace(0.0, 1.0, 200)
    y = 0.3 + 2.0 * x + rng.normal(0.0, 0.01, x.size)
    evals = []

    def resjac(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        evals.append(1)
        jac = np.stack([-np.ones_like(x), -x, -(x**2)], axis=1)
        return y - (p[0] + p[1] * x + p[2] * x**2), jac

    lower = np.array([-10.0, -10.0, 0.0])
    upper = np.array([10.0, 10.0, 0.0])  # the quadratic term is pinned at 0
    p, res, w = robust_gauss_newton(
        None,
        np.array([0.0, 0.0, 0.0]),
        np.full(3, 1e-6),
        c=5.0,
        iterations=20,
        lower=lower,
        upper=upper,
        c_final=0.05,
        step_tol=1e-9,
        anneal=3,
        cost_tol=1e-6,
        resjac=resjac,
    )
    assert p[2] == 0.0
    assert abs(p[0] - 0.3) < 0.01 and abs(p[1] - 2.0) < 0.02
    assert len(evals) < 15  # converged, not stopped by the iteration limit
    assert w.min() > 0.0


def test_noisy_tee_far_along_its_run_is_placed_by_the_hole_in_the_wall():
    # 40 cm ahead with range noise only a few dozen returns come through the opening; they
    # once pulled the branch back to 150 deg and the reference point 6.5 cm away
    scan, truth, d = scan_layout(
        "t_junction", 0.4, sensor="ydlidar_x4", seed=1, diameter=0.1, direction=0.76, entry="run"
    )
    det = detect(scan, d)
    assert det.kind == "junction" and len(det.options) == 2, det.describe()
    for o, t in match(det.options, truth):
        assert abs(o.distance - t.distance) < 0.02  # thesis requirement
        assert abs(o.angle - t.angle) < math.radians(10.0)
        assert abs(o.diameter - t.diameter) < 0.005


@pytest.mark.parametrize(
    ("distance", "seed", "params"),
    [
        # 35 deg at the free fit: held at 45 deg from the same reference point, the branch
        # missed the few returns through the opening (the held fit did not move; 3.3 cm off)
        (0.4, 35, {"diameter": 0.1, "branch_diameter": 0.066, "direction": 0.36}),
        # held at 45 deg from where its hole is, it fits them nearly as well: 2.5 cm -> 0.6 cm
        (0.325, 24, {"diameter": 0.075, "branch_diameter": 0.074, "direction": -0.48}),
    ],
)
def test_noisy_wye_far_along_its_run_is_held_at_45_deg_where_its_hole_is(
    distance: float, seed: int, params: dict
) -> None:
    # range noise, a run that goes on: the returns through the opening leave the deflection
    # and the reference point trading against each other, a standard angle is the estimate
    scan, truth, d = scan_layout(
        "y_junction", distance, sensor="ydlidar_x4", seed=seed, entry="run", **params
    )
    det = detect(scan, d)
    assert det.diagnostics.get("standard_angles") == 1, det.describe()
    _assert_ways_within(det, truth, 2, 0.02, None, 5.0, 5.0)  # the thesis requirements


def test_a_deflection_halfway_between_two_standard_angles_tries_both():
    # (ydlidar_x4) a 90 deg tee's branch seen at 67.5 deg through a far opening: 45 deg, the
    # first of the two nearest, did not fit, and 90 deg was never tried (22.5 deg and 2.6 cm
    # off; its direction, from a dozen returns, stays 5.4 deg off)
    scan, truth, d = scan_layout(
        "t_junction",
        0.375,
        sensor="ydlidar_x4",
        seed=68,
        diameter=0.1,
        branch_diameter=0.066,
        direction=0.61,
        entry="run",
    )
    det = detect(scan, d)
    _assert_ways_within(det, truth, 2, 0.02, None, 5.0)


def test_noisy_bend_far_away_does_not_turn_back():
    # a single way on with no run going on is a bend (at most 90 deg): the few noisy returns
    # through a far opening once settled on a 150 deg deflection 10 cm beyond the bend
    scan, truth, d = scan_layout(
        "mitre_bend", 0.4, sensor="ydlidar_x4", seed=1, diameter=0.1, angle=1.3026, direction=-0.44
    )
    det = detect(scan, d)
    assert det.kind == "bend", det.describe()
    ((o, t),) = match(det.options, truth)
    assert abs(o.distance - t.distance) < 0.02
    assert abs(o.angle - t.angle) < math.radians(5.0)
    assert abs(wrap(o.direction - t.direction)) < math.radians(5.0)


def test_noisy_far_wall_of_a_turn_is_not_an_end_wall():
    # under 1 % range noise the far wall of a small turn 40 cm ahead is flat to within the
    # noise; its curvature (a sag of about a centimetre) still tells it from a cap
    scan, truth, d = scan_layout(
        "mitre_bend",
        0.4,
        sensor="ydlidar_x4",
        diameter=0.057,
        angle=math.radians(75),
        direction=-2.9,
    )
    det = detect(scan, d)
    assert det.kind == "bend", det.describe()
    assert det.diagnostics["closure_sag"] > 0.005
    ((o, t),) = match(det.options, truth)
    assert abs(o.distance - t.distance) < 0.02
    assert abs(o.angle - t.angle) < math.radians(5.0)
    assert abs(wrap(o.direction - t.direction)) < math.radians(5.0)
    cap, truth, d = scan_layout("closure", 0.4, sensor="ydlidar_x4", diameter=0.057)
    det = detect(cap, d)
    assert det.kind == "closure" and det.diagnostics["closure_sag"] < 0.002


def test_noisy_taper_with_its_narrow_pipe_unseen_is_a_reducer():
    # grazing beams lose the narrower pipe's wall under ydlidar_x4: the end wall far down it
    # once stood in for that wall (a plateau far too narrow, a taper too long, or a bend),
    # and the first returns off the wall come well past the start of a gentle taper
    scan, truth, d = scan_layout(
        "reducer", 0.3, sensor="ydlidar_x4", diameter_in=0.1, diameter_out=0.055, taper_length=0.2
    )
    det = detect(scan, d)
    assert det.kind == "reducer", det.describe()
    assert abs(det.options[0].distance - truth[0].distance) < 0.02
    assert 0.03 < det.options[0].diameter < 0.075
    assert det.diagnostics["reducer_end_wall_radius"] > 0.015


def test_noisy_tee_seen_from_its_stem_is_one_pipe_across():
    # 40 cm ahead under range noise the two openings of the run are a few grazing returns each;
    # two free branches once settled on a 25 mm and a 65 mm pipe 120 deg off, where one pipe
    # across (both ways open) explains the returns better
    scan, truth, d = scan_layout(
        "t_junction",
        0.4,
        sensor="ydlidar_x4",
        seed=1,
        diameter=0.1,
        branch_diameter=0.1,
        direction=0.3,
        entry="stem",
    )
    det = detect(scan, d)
    assert det.kind == "junction" and len(det.options) == 2, det.describe()
    assert det.diagnostics["model"] == "pipe_across"
    for o, t in match(det.options, truth):
        assert abs(o.distance - t.distance) < 0.02
        assert abs(o.angle - t.angle) < math.radians(5.0)
        assert abs(wrap(o.direction - t.direction)) < math.radians(5.0)
        assert abs(o.diameter - t.diameter) < 0.002


def test_small_tee_far_along_its_run_is_seen_by_a_noiseless_sensor():
    # a 57 mm tee 30 cm ahead: the returns through its opening lie only a few millimetres
    # beyond the wall, inside the 2 mm tolerance floor; a noiseless sensor whose wall fits to a
    # tenth of a millimetre can afford a floor of one millimetre
    scan, truth, d = scan_layout(
        "t_junction", 0.3, diameter=0.057, branch_diameter=0.057, direction=-2.58, entry="run"
    )
    det = detect(scan, d)
    assert det.kind == "junction" and len(det.options) == 2, det.describe()
    assert det.diagnostics["tolerance_floor"] < 0.0015
    for o, t in match(det.options, truth):
        assert abs(o.distance - t.distance) < 0.01
        assert abs(o.angle - t.angle) < math.radians(1.0)
        assert abs(wrap(o.direction - t.direction)) < math.radians(2.0)


def test_first_axis_pass_only_when_the_given_pose_misses_the_wall():
    scan, truth, d = scan_layout("closure", 0.3, diameter=0.1)
    det = detect(scan, d)
    assert det.kind == "closure" and not det.diagnostics["axis_first_pass"]
    assert abs(det.options[0].distance - truth[0].distance) < 0.005
    offset = Pose(np.array([0.0, 0.01, 0.0]), np.eye(3))
    scan, truth, d = scan_layout("closure", 0.3, diameter=0.1, misalignment=offset)
    det = detect(scan, d)
    assert det.kind == "closure" and det.diagnostics["axis_first_pass"]
    assert abs(det.options[0].distance - truth[0].distance) < 0.005


def test_narrow_side_branch_is_sized_by_its_hole():
    # a 68 mm branch of a 100 mm run: the hole prior once assumed a full-size branch, pulled
    # the wye's 45 deg branch to 73 deg and the reference point 3.4 cm off, and clamped the
    # branch to the run's diameter; the hole's width around its roll sizes the branch
    for layout, distance, direction in (("y_junction", 0.3, 0.7071), ("t_junction", 0.2, -1.79)):
        scan, truth, d = scan_layout(
            layout, distance, diameter=0.1, branch_diameter=0.068, direction=direction, entry="run"
        )
        _assert_ways_within(detect(scan, d), truth, 2, 0.01, 0.002, 1.0)


def test_wide_bend_seen_from_just_before_its_arc_keeps_the_given_axis():
    # a 3 D bend whose arc starts 3-4 cm ahead: every return lies on the arc; the axis refined
    # from them was pulled 4-10 mm towards the turn and the bend came out at 27 deg instead of
    # its 50 deg in view. The given pose stands when the wall is no straight cylinder.
    scan, truth, d = scan_layout(
        "long_bend", 0.2, diameter=0.125, angle=1.0146, direction=2.5518, radius_factor=2.3947
    )
    det = detect(scan, d)
    assert det.kind == "bend", det.describe()
    ((o, t),) = match(det.options, truth)
    assert abs(o.bend_radius - t.bend_radius) < 0.01
    assert abs(o.angle - t.angle) < math.radians(8.0)
    assert abs(o.distance - t.distance) < 0.03
    scan, truth, d = scan_layout(
        "long_bend", 0.3, diameter=0.1, angle=1.4937, direction=1.5883, radius_factor=2.9549
    )
    det = detect(scan, d)
    assert det.kind == "bend", det.describe()
    ((o, t),) = match(det.options, truth)
    # no straight wall in view at all (the arc starts before the nearest returns): the end of
    # the arc is out of view, the angle is a lower bound, and flagged as one
    assert math.radians(45.0) < o.angle <= t.angle and det.diagnostics["angle_lower_bound"]
    assert o.bend_radius > 0.2


def _assert_ring_hole_junction(layout: str, distance: float, **params) -> None:
    """A 57 mm junction ``distance`` ahead is found through the holes rings of beams enter,
    and every way is placed to 5 mm, sized to 2 mm, deflected to 1 deg and rolled to 2 deg."""
    scan, truth, d = scan_layout(layout, distance, diameter=0.057, branch_diameter=0.057, **params)
    det = detect(scan, d)
    assert det.kind == "junction" and len(det.options) == len(truth), det.describe()
    assert det.diagnostics["model"] == "ring holes"
    for o, t in match(det.options, truth):
        assert abs(o.distance - t.distance) < 0.005
        assert abs(o.diameter - t.diameter) < 0.002
        assert abs(o.angle - t.angle) < math.radians(1.0)
        assert abs(wrap(o.direction - t.direction)) < math.radians(2.0)


def test_small_side_holes_between_two_rings_of_beams_are_found():
    # 40 cm before a 57 mm tee (or cross) the beams meet the wall 4.9 cm apart along the axis:
    # one ring of beams enters the 57 mm hole and meets the branch's far side only 1.5 mm
    # beyond the run's wall; the scan once read as the end wall of the run 65 cm farther on
    # (at 32.5 cm the ring's bump dips below the threshold in its middle: two bumps, one hole)
    _assert_ring_hole_junction("t_junction", 0.4, direction=-2.3262, entry="run")
    _assert_ring_hole_junction("cross_junction", 0.4, direction=0.0716)
    _assert_ring_hole_junction("t_junction", 0.325, direction=1.68203, entry="run")
    # (a 45 deg lateral: the far side of its hole tells it from a tee)
    _assert_ring_hole_junction("y_junction", 0.375, direction=-1.59625, entry="run")


def test_no_ring_holes_in_a_straight_pipe_seen_off_centre():
    # a sensor 0.8 mm off the axis and tilted 0.1 deg: every ring leaves the wall by up to a
    # millimetre, smoothly from ring to ring, which is no hole
    tilt = Pose(np.array([0.0, 0.0008, -0.0003]), rot_tilt(0.0, math.radians(0.1)))
    for d_pipe in (0.057, 0.1):
        scan, _, d = scan_layout("straight", 0.0, diameter=d_pipe, misalignment=tilt)
        det = detect(scan, d)
        assert det.kind == "straight", det.describe()


def test_gentle_widening_seen_by_one_ring_starts_before_that_ring():
    # a 57 mm pipe widening to 78 mm over 19 cm, 40 cm ahead: one ring of beams meets the cone,
    # 2 mm beyond the wall (within its tolerance), 3.8 cm past the start; the start was once
    # put after it (5.4 cm late). It lies between the last ring on the wall and that ring, and
    # early enough for the cone to reach the wide pipe before the next ring does.
    scan, truth, d = scan_layout(
        "reducer", 0.4, diameter_in=0.057, diameter_out=0.0784, taper_length=0.192
    )
    det = detect(scan, d)
    assert det.kind == "reducer", det.describe()
    assert abs(det.options[0].distance - truth[0].distance) < 0.015
    assert abs(det.options[0].diameter - 0.0784) < 0.002


@pytest.mark.parametrize(
    ("run_d", "branch_d", "direction", "distance", "max_dist", "max_angle_deg"),
    [
        # a 58 mm branch of a 100 mm run 40 cm ahead: the 47 returns through its opening fitted
        # a branch deflected by 86.7 deg just as well as by 90 (the deflection trades against
        # the reference point and the radius); fittings come at standard angles, which the
        # returns do not reject here
        (0.1, 0.05832527, 1.6318623, 0.4, 0.002, 0.5),
        # a 74.1 mm branch of a 75 mm run 35 cm ahead: held at the run's radius, the branch
        # leaned to 88.5 deg, and 90 deg at that radius was rejected; with its radius free by a
        # few per cent, 90 deg fits as well
        (0.075, 0.0741315, -1.2386797, 0.35, 0.003, 0.3),
    ],
)
def test_tee_branch_keeps_its_standard_angle(
    run_d: float,
    branch_d: float,
    direction: float,
    distance: float,
    max_dist: float,
    max_angle_deg: float,
) -> None:
    scan, truth, d = scan_layout(
        "t_junction",
        distance,
        diameter=run_d,
        branch_diameter=branch_d,
        direction=direction,
        entry="run",
    )
    det = detect(scan, d)
    _assert_ways_within(det, truth, 2, max_dist, 0.001, max_angle_deg)
    assert det.diagnostics.get("standard_angles") == 1


def test_tee_from_its_stem_with_no_stem_wall_in_view_keeps_the_given_axis():
    # 10 cm before a 125 mm tee from its stem, the stem ends 6 cm before the nearest returns:
    # no wall to refine the axis from. A cylinder tilted 4.3 deg about the run's walls
    # explained 3 more returns of 5,800 than the (right) given pose and turned the run
    # 4.3 deg; a refinement must explain clearly more than the given pose then.
    scan, truth, d = scan_layout(
        "t_junction", 0.1, diameter=0.125, branch_diameter=0.125, direction=-3.03555, entry="stem"
    )
    det = detect(scan, d)
    assert det.kind == "junction" and len(det.options) == 2, det.describe()
    assert det.diagnostics["axis_pass"] == 0
    for o, t in match(det.options, truth):
        assert abs(o.distance - t.distance) < 0.005
        assert abs(o.angle - t.angle) < math.radians(1.0)


def test_junction_fit_the_returns_hardly_support_gives_way_to_its_holes():
    # 35 cm before a 57 mm tee (and a cross): 30 returns beyond the wall through the opening,
    # none of them on the fitted branch, which came out at 45 deg, 31 mm and 6.8 cm early (the
    # cross: a pipe across tilted 55 deg); two rings enter the hole and place it exactly
    _assert_ring_hole_junction("t_junction", 0.35, direction=1.68203, entry="run")
    _assert_ring_hole_junction("cross_junction", 0.35, direction=2.93626)


def test_ring_bumps_of_a_sensor_off_the_axis_do_not_replace_a_junction():
    # a cross 35 cm ahead with the sensor 5 mm off the axis (not refined away): the junction's
    # fit was weak, and ring bumps were fitted as branches at 24 and 36 cm, 45 and 135 deg,
    # 12 cm apart; the branches of one junction leave the run at one place, near the fit's
    # (and at 5 mm off, 30-35 cm ahead, with no bumps at one place: the rings bend with the
    # offset, a pose that misses the wall by millimetres shows no sub-millimetre holes)
    for position, distance in (
        ((-0.00475269, 0.00155303), 0.35),
        ((0.00400901, -0.00298795), 0.35),
        ((0.00400901, -0.00298795), 0.3),
    ):
        offset = Pose(np.array([0.0, *position]), np.eye(3))
        scan, truth, d = scan_layout(
            "cross_junction", distance, diameter=0.1, direction=0.0, misalignment=offset
        )
        det = detect(scan, d)
        assert det.diagnostics.get("model") != "ring holes", det.describe()


def _reducer_within(
    distance: float, d_in: float, d_out: float, taper: float, max_dist: float, max_diam: float
) -> Detection:
    """The detection of a reducer ``distance`` (m) ahead, asserted to be one within
    ``max_dist`` (m) and ``max_diam`` (m) of the truth."""
    scan, truth, d = scan_layout(
        "reducer", distance, diameter_in=d_in, diameter_out=d_out, taper_length=taper
    )
    det = detect(scan, d)
    assert det.kind == "reducer", det.describe()
    assert abs(det.options[0].distance - truth[0].distance) < max_dist, det.describe()
    assert abs(det.options[0].diameter - d_out) < max_diam, det.describe()
    return det


def test_gentle_widening_seen_by_two_rings_starts_where_their_line_meets_the_wall():
    # a 57 mm pipe widening to 75.5 mm over 15.4 cm, 25 cm ahead: two rings of beams meet the
    # cone, 2.9 and 7.3 mm beyond the wall; the ring nearer the wider pipe was once taken for
    # it and the start put between rings (3.1 cm late). The line through both rings reaches
    # the wall radius at the start.
    det = _reducer_within(0.25, 0.057, 0.0755, 0.154, max_dist=0.003, max_diam=0.001)
    assert det.diagnostics["widening_start_from_cone"]


def test_axis_tilted_onto_a_gentle_taper_does_not_replace_the_given_pose():
    # the same widening 12.5 cm ahead: its first centimetres lie within the wall tolerance, and
    # a cylinder tilted 0.8 deg onto them explained as many wall returns as the given pose
    # (only more loosely) and won the tie: the start came out 2.8 cm late and the wider pipe
    # 81 mm. Of poses explaining as many returns, the closest fit is kept.
    det = _reducer_within(0.125, 0.057, 0.0755, 0.154, max_dist=0.003, max_diam=0.001)
    assert det.diagnostics.get("axis_tilt_deg", 0.0) < 0.1


def test_narrower_pipe_of_a_taper_is_sized_without_the_end_wall_down_it():
    # the thesis reducer (100 to 55 mm over 20 cm) 12.5 cm ahead: returns from the end wall far
    # down the 55 mm pipe pulled the fitted plateau to 52 mm
    _reducer_within(0.125, 0.1, 0.055, 0.2, max_dist=0.002, max_diam=0.0005)


def test_given_pose_kept_in_a_tie_narrows_the_tolerance_to_the_wall_scatter():
    # a 57 mm wye from its branch, 35 cm ahead: the given pose and a refined one explain the
    # same wall returns and the given one is kept; the tolerance must still shrink to the
    # wall's scatter under it (a 2 mm tolerance hides the second way: read as a bend)
    scan, truth, d = scan_layout(
        "y_junction", 0.35, diameter=0.057, direction=-1.4488051, entry="branch"
    )
    det = detect(scan, d)
    _assert_ways_within(det, truth, 2, 0.002, None, 0.5)
    assert det.diagnostics.get("tolerance_floor", 1.0) < 0.002


@pytest.mark.parametrize("distance", [0.2, 0.15])
def test_tee_entered_from_a_narrower_stem_keeps_both_ways(distance: float) -> None:
    # from a 57.3 mm stem into a 60.6 mm run, 15-20 cm ahead (where the robot decides): the
    # run's wall lies 1.7 mm beyond the stem's all round and joined both ways on into one
    # region of returns, fitted as one way (a bend, sometimes the wrong way round). Only along
    # the run do the returns reach deep: the region is split there.
    scan, truth, d = scan_layout(
        "t_junction",
        distance,
        diameter=0.0606,
        branch_diameter=0.0573,
        direction=-2.83,
        entry="stem",
    )
    _assert_ways_within(detect(scan, d), truth, 2, 0.003, 0.001, 0.5, direction_deg=1.0)


@pytest.mark.parametrize(
    ("distance", "diameter", "angle", "direction", "radius_factor"),
    [
        (0.25, 0.1, 0.8831, -2.7798, 2.7650),  # the axis leaned 1.2 deg onto the arc
        (0.175, 0.057, 0.5263, -0.4213, 2.7983),  # 1.5 deg, and the arc read as a mitre
    ],
)
def test_long_bend_axis_is_chosen_on_the_wall_before_its_arc(
    distance: float, diameter: float, angle: float, direction: float, radius_factor: float
) -> None:
    # the first centimetres of a gentle arc lie within the wall tolerance: the wall the pose
    # was chosen on reached 2-3 cm into the arc, and the axis refined on it leaned onto the
    # arc, tilting the bend's angle by as much
    det, o, t = _long_bend_seen(distance, diameter, angle, direction, radius_factor)
    assert abs(o.angle - t.angle) < math.radians(0.5), det.describe()
    assert abs(o.distance - t.distance) < 0.005, det.describe()
    assert abs(o.bend_radius - t.bend_radius) < 0.01, det.describe()


def test_long_bend_fit_runs_down_its_narrow_valley():
    # the reference point, the angle and the arc radius of a long bend trade off: ten
    # iterations stopped 7 mm short and 2.9 deg shallow, and that loose fit (1.5 mm rms)
    # passed for good enough to skip the second start
    det, o, t = _long_bend_seen(0.15, 0.125, 0.8817, -2.2754, 1.9355)
    assert abs(o.angle - t.angle) < math.radians(0.5), det.describe()
    assert abs(o.distance - t.distance) < 0.005, det.describe()
    assert det.diagnostics["torus_rms"] < 0.0005


def test_axis_chosen_past_a_gentle_taper_start_is_chosen_again_before_it():
    # the wall the pose was chosen on ran 5 cm into a 3.4 deg taper: the axis leaned onto it,
    # and the taper's own returns passed for wall, placing its start 1.3 cm early
    scan, truth, d = scan_layout(
        "reducer", 0.35, diameter_in=0.057, diameter_out=0.0755, taper_length=0.154
    )
    det = detect(scan, d)
    assert det.kind == "reducer", det.describe()
    assert abs(det.options[0].distance - truth[0].distance) < 0.008, det.describe()
    assert abs(det.options[0].diameter - 0.0755) < 0.001, det.describe()
    assert det.diagnostics.get("start_recheck") and det.diagnostics["axis_pass"] == 0


@pytest.mark.parametrize(
    ("diameter_in", "diameter_out", "distance"),
    [(0.108, 0.081, 0.25), (0.1, 0.075, 0.2), (0.125, 0.1, 0.25), (0.075, 0.057, 0.25)],
)
def test_noisy_narrowing_is_sized_without_the_end_wall_down_it(
    diameter_in: float, diameter_out: float, distance: float
) -> None:
    # (ydlidar_x4, 1 % range noise) the end wall a metre down the narrower pipe spreads a
    # centimetre either side along the axis: most of it stayed in the taper's fit and pulled
    # the narrower pipe 7-10 mm too narrow and its start up to 7 cm early; the fit without it
    # stayed at the end wall's bound it started from
    scan, truth, d = scan_layout(
        "reducer",
        distance,
        sensor="ydlidar_x4",
        diameter_in=diameter_in,
        diameter_out=diameter_out,
        taper_length=0.15,
    )
    det = detect(scan, d)
    assert det.kind == "reducer", det.describe()
    assert abs(det.options[0].diameter - diameter_out) < 0.002, det.describe()
    assert abs(det.options[0].distance - truth[0].distance) < 0.01, det.describe()


@pytest.mark.parametrize(("distance", "seed"), [(0.3, 0), (0.25, 1)])
def test_noisy_cross_branches_are_fitted_each_to_its_own_opening(distance: float, seed: int):
    # (ydlidar_x4) two branch cylinders fitted to whichever of them each return lies nearer
    # took the scatter of the openings' rims in between them: the branches leaned 10-15 deg
    # apart and the likelihood ratio then rejected the one pipe across that is the truth
    scan, truth, d = scan_layout(
        "cross_junction",
        distance,
        sensor="ydlidar_x4",
        seed=seed,
        diameter=0.075,
        branch_diameter=0.0741,
        direction=math.radians(26.1),
    )
    det = detect(scan, d)
    assert det.diagnostics["model"] == "pipe_across", det.describe()
    _assert_ways_within(det, truth, 3, 0.01, 0.002, 1.0, 3.0)


@pytest.mark.parametrize(
    ("layout", "distance", "seed", "params"),
    [
        ("t_junction", 0.2, 0, {"diameter": 0.057, "direction": 2.2166, "entry": "stem"}),
        ("y_junction", 0.3, 1, {"diameter": 0.1, "direction": 0.8116, "entry": "branch"}),
    ],
)
def test_noisy_junction_with_openings_on_both_sides_keeps_the_standard_radius(
    layout: str, distance: float, seed: int, params: dict
):
    # (ydlidar_x4) with the nearer-cylinder assignment the two free branches fitted 6-10 mm
    # wider than the run and a few millimetres off along it; the branches fitted to their own
    # openings do no better than one pipe across of the clamped diameter, which is kept
    scan, truth, d = scan_layout(layout, distance, sensor="ydlidar_x4", seed=seed, **params)
    det = detect(scan, d)
    assert det.diagnostics["model"] == "pipe_across", det.describe()
    _assert_ways_within(det, truth, 2, 0.005, 0.002, 1.0, 2.0)


@pytest.mark.parametrize("distance", [0.3, 0.2])
def test_noiseless_cross_side_pipes_are_coaxial(distance: float):
    # a 125 mm cross with 83.5 mm side pipes: the branches, fitted to the nearer of two
    # cylinders, came out 0.3-0.4 deg off their roll; each fitted to its own opening they are
    # within a few hundredths of a degree
    scan, truth, d = scan_layout(
        "cross_junction",
        distance,
        diameter=0.125,
        branch_diameter=0.0835,
        direction=math.radians(18.7),
    )
    _assert_ways_within(detect(scan, d), truth, 3, 0.002, 0.001, 0.1, 0.15)


def test_small_noisy_tee_branch_fitted_well_off_the_standard_angle_is_held_at_it():
    # (ydlidar_x4) a 57 mm tee 20 cm ahead along its run: the branch's opening is a few dozen
    # returns that a deflection of 74 deg fitted as well as 90; held only within 10 deg of
    # the standard angle it stayed at 74 deg, a centimetre early
    scan, truth, d = scan_layout(
        "t_junction", 0.2, sensor="ydlidar_x4", diameter=0.057, direction=1.6825
    )
    det = detect(scan, d)
    assert det.diagnostics.get("standard_angles") == 1, det.describe()
    _assert_ways_within(det, truth, 2, 0.005, 0.001, 1.0, 2.0)


@pytest.mark.parametrize("diameter", [0.057, 0.125])
def test_end_wall_within_the_minimum_range_is_a_closure(diameter: float) -> None:
    # (ydlidar_x4, minimum range 12 cm) 10 cm before an end wall every beam ahead meets it or
    # the wall before it inside the minimum range: no return at all, once read as straight
    # pipe. The end wall is no farther than where the wall ahead would start to show.
    scan, truth, d = scan_layout("closure", 0.1, sensor="ydlidar_x4", diameter=diameter)
    det = detect(scan, d)
    assert det.kind == "closure", det.describe()
    reach = math.sqrt(0.12**2 - (diameter / 2) ** 2)
    assert det.options[0].distance == pytest.approx(reach)
    assert truth[0].distance <= det.options[0].distance < truth[0].distance + 0.02
    # 5 cm farther back the wall ahead shows again: the end wall is measured as usual
    scan, truth, d = scan_layout("closure", 0.15, sensor="ydlidar_x4", diameter=diameter)
    det = detect(scan, d)
    assert det.kind == "closure" and "blocked_within_min_range" not in det.diagnostics
    assert abs(det.options[0].distance - truth[0].distance) < 0.01


@pytest.mark.parametrize("seed", [0, 1])
def test_noisy_gentle_widening_starts_where_the_rings_leave_the_wall(seed: int) -> None:
    # (ydlidar_x4) a 57-to-75.5 mm widening over 15 cm, 15 cm ahead: per return, the first
    # centimetres of the cone lie within the range noise of the wall, and the start came out
    # 4.6 cm late; the medians of the rings of beams rise off the wall where the cone starts
    scan, truth, d = scan_layout(
        "reducer",
        0.15,
        sensor="ydlidar_x4",
        seed=seed,
        diameter_in=0.057,
        diameter_out=0.0755,
        taper_length=0.15,
    )
    det = detect(scan, d)
    assert det.kind == "reducer", det.describe()
    assert det.diagnostics["widening_start_from_cone"]
    assert abs(det.options[0].distance - truth[0].distance) < 0.01, det.describe()
    assert abs(det.options[0].diameter - 0.0755) < 0.002


@pytest.mark.parametrize(
    ("layout", "distance", "params"),
    [
        ("closure", 0.35, {"diameter": 0.1}),
        ("mitre_bend", 0.3, {"diameter": 0.1, "angle": math.pi / 2, "direction": math.pi}),
        ("cross_junction", 0.4, {"diameter": 0.1, "direction": 0.0}),
    ],
)
def test_misaligned_sensor_takes_the_axis_that_fits_a_long_straight_wall(
    layout: str, distance: float, params: dict
) -> None:
    # (ideal sensor tilted by 4 deg and 5 mm off the axis: a case of the accuracy study's
    # misalignment sweep) under the given pose the wall drifts off the tolerance 12 cm ahead,
    # which looked like less than 5 cm of wall before a structure, so the given pose stood;
    # the refined axis fits 20 cm and more of straight wall to a tenth of a millimetre
    mis = Pose(np.array([0.0, -0.001852, -0.004644]), rot_tilt(0.0536507, -0.0446711))
    scan, truth, d = scan_layout(layout, distance, misalignment=mis, **params)
    det = detect(scan, d)
    assert det.diagnostics["axis_pass"] == 2, det.describe()
    assert len(det.options) == len(truth), det.describe()
    for o, t in match(det.options, truth):
        assert o.kind == t.kind and abs(o.distance - t.distance) < 0.005, det.describe()
        assert abs(o.angle - t.angle) < math.radians(1.0)


@pytest.mark.parametrize(
    ("distance", "diameter", "angle", "direction", "radius_factor"),
    [
        (0.2, 0.1, 1.2528, -1.2496, 2.7350),  # axis 16 mm off centre, the bend 7.3 deg short
        (0.15, 0.075, 1.0772, -3.0564, 2.8295),  # 2.8 deg short
    ],
)
def test_long_bend_starting_right_ahead_keeps_the_given_pose(
    distance: float, diameter: float, angle: float, direction: float, radius_factor: float
) -> None:
    # the arc starts 0.5-2.5 cm ahead and fills the view: the axis refined on the nearest
    # wall-like returns was a cylinder laid into the arc's start, and the torus fitted under it
    # missed its returns by 1.6 mm; under the given pose it fits them to 0.15 mm
    det, o, t = _long_bend_seen(distance, diameter, angle, direction, radius_factor)
    assert "torus_pose_check" in det.diagnostics, det.describe()
    assert abs(o.angle - t.angle) < math.radians(1.0), det.describe()
    assert abs(o.distance - t.distance) < 0.005, det.describe()


def test_long_bend_angle_is_polished_on_returns_spread_along_the_arc():
    # the returns from the last degrees of the arc are a few dozen of thousands, and an even
    # subsample of the returns holds two or three of them: the torus stopped 1.4 deg short
    det, o, t = _long_bend_seen(0.225, 0.1, 1.2528, -1.2496, 2.7350)
    assert abs(o.angle - t.angle) < math.radians(0.5), det.describe()
    assert abs(o.distance - t.distance) < 0.005, det.describe()


THESIS_REDUCER = {"diameter_in": 0.1, "diameter_out": 0.055, "taper_length": 0.2}


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_noisy_gentle_taper_keeps_the_given_pose(seed: int) -> None:
    """The thesis's reducer (100 to 55 mm over 20 cm) 15 cm ahead of a ydlidar_x4: its first
    centimetres lie within the range noise of the wall, an axis refined on that "wall" leaned
    2-4 deg onto the taper, and the taper came out as a 25 deg turn 70 cm ahead (or a reducer
    to 77 mm). The given pose's reducer fits its returns three to eight times as closely."""
    scan, truth, d = scan_layout("reducer", 0.15, "ydlidar_x4", seed=seed, **THESIS_REDUCER)
    det = detect(scan, d)
    assert det.kind == "reducer", det.describe()
    (o,) = det.options
    assert abs(o.diameter - truth[0].diameter) < 0.005, det.describe()
    assert abs(o.distance - truth[0].distance) < 0.01, det.describe()


@pytest.mark.parametrize(("distance", "within"), [(0.125, 0.005), (0.10, 0.02)])
def test_noisy_taper_radius_is_measured_before_the_taper(distance: float, within: float) -> None:
    """Under range noise the wall radius measured up to where the returns leave the wall took
    in the taper's first centimetres (48.9 mm for 50; 46.5 mm with no wall in view before the
    taper, 10 cm ahead of a 12 cm minimum range): the start moved on by 1 and 3 cm. Measured on
    the wall before the fitted start, or the clamp's reading when none is in view there."""
    for seed in (0, 1):
        scan, truth, d = scan_layout("reducer", distance, "ydlidar_x4", seed=seed, **THESIS_REDUCER)
        det = detect(scan, d)
        assert det.kind == "reducer", det.describe()
        assert abs(det.options[0].distance - truth[0].distance) < within, det.describe()


@pytest.mark.parametrize("distance", [0.35, 0.30])
def test_noisy_short_taper_is_fitted_apart_from_the_end_wall_seen_through_it(
    distance: float,
) -> None:
    """A 9 cm reducer from 75 to 58.6 mm, 30-35 cm ahead of a ydlidar_x4: beyond the taper the
    narrower pipe's wall grazes out of sight, and the next returns are the end wall a metre
    ahead. The fit with those returns, a long shallow taper reaching for them, left a minimum
    that the taper's own returns could not pull the refit out of: the start came out 7-40 cm
    late. The refit starts afresh from the returns left."""
    for seed in (0, 1, 2):
        scan, truth, d = scan_layout(
            "reducer",
            distance,
            "ydlidar_x4",
            seed=seed,
            diameter_in=0.075,
            diameter_out=0.0586,
            taper_length=0.0915,
        )
        det = detect(scan, d)
        assert det.kind == "reducer", det.describe()
        (o,) = det.options
        assert abs(o.distance - truth[0].distance) < 0.015, det.describe()
        assert abs(o.diameter - truth[0].diameter) < 0.003, det.describe()


@pytest.mark.parametrize(
    ("diameter", "angle_deg", "direction"),
    [(0.1, 45.0, 2.3736), (0.1, 36.7, 1.3177), (0.075, 66.5, -2.4546)],
)
def test_mitre_bend_right_ahead_of_a_long_minimum_range_is_no_junction(
    diameter: float, angle_deg: float, direction: float
) -> None:
    """A mitre bend 10 cm ahead of a ydlidar_x4 (minimum range 12 cm) leaves 1.5-3 cm of wall
    in view: an axis refined on it took in the outgoing pipe's first returns, moved 5-7 mm off
    the centre, and the bend's far side read as a second way on. Under the given pose the bend
    fits its returns more closely with one way."""
    for seed in (0, 1):
        scan, truth, d = scan_layout(
            "mitre_bend",
            0.10,
            "ydlidar_x4",
            seed=seed,
            diameter=diameter,
            angle=math.radians(angle_deg),
            direction=direction,
        )
        det = detect(scan, d)
        assert det.kind == "bend", det.describe()
        (o,) = det.options
        assert abs(o.distance - truth[0].distance) < 0.01, det.describe()
        assert abs(o.angle - truth[0].angle) < math.radians(2.0), det.describe()
