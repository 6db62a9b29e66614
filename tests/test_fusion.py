"""The multi-scan tracker: confirmation with hysteresis, trust weighting of nearer scans,
hand-over near the structure, re-expression relative to the latest pose, reset."""

from __future__ import annotations

import math

import numpy as np
import pytest

from detector import Detection, StructureOption
from detector.fusion import StructureTracker

EYE = np.eye(3)


def bend(distance, angle=math.pi / 2, direction=0.0, conf=0.9, diameter=0.1):
    return Detection(
        "bend", [StructureOption("bend", distance, diameter, direction, angle, conf)], conf
    )


def straight():
    return Detection.straight(confidence=0.9)


def drive(tracker, ref_x, positions, make):
    states = []
    for x in positions:
        states.append(tracker.update(make(ref_x - x), np.array([x, 0.0, 0.0]), EYE))
    return states


def test_confirms_after_consistent_detections_and_reports_relative_to_latest_pose():
    tr = StructureTracker(confirm_count=3)
    states = drive(tr, 1.0, [0.6, 0.62, 0.64, 0.66], lambda d: bend(d))
    assert [s.confirmed for s in states] == [False, False, True, True]
    last = states[-1]
    assert last.n_updates == 4
    assert last.detection.kind == "bend"
    assert last.detection.options[0].distance == pytest.approx(0.34, abs=1e-9)
    assert last.detection.options[0].angle == pytest.approx(math.pi / 2)
    assert 0.0 < last.confidence <= 1.0


def test_single_outlier_does_not_confirm_or_break_a_track():
    tr = StructureTracker()
    s = tr.update(bend(0.3), np.zeros(3), EYE)
    assert not s.confirmed
    # a straight reading far from the structure costs evidence but one miss keeps the track
    drive(tr, 0.3, [0.01, 0.02], lambda d: bend(d))
    s = tr.update(straight(), np.array([0.03, 0, 0]), EYE)
    assert s.confirmed and s.detection.kind == "bend"
    # many straight readings while it should be visible drop it (hysteresis)
    for x in np.linspace(0.04, 0.06, 8):
        s = tr.update(straight(), np.array([x, 0, 0]), EYE)
    assert not s.confirmed and s.detection.kind == "straight"


def test_nearer_scans_weigh_more():
    tr = StructureTracker()
    # far scan says the bend is 3 cm farther than it is; near scans are right
    tr.update(bend(0.43), np.array([0.0, 0, 0]), EYE)  # reference at 0.43
    for x in (0.25, 0.26, 0.27):
        s = tr.update(bend(0.40 - x), np.array([x, 0, 0]), EYE)  # reference at 0.40
    ref = s.reference_world[0]
    assert abs(ref - 0.40) < abs(ref - 0.43)
    # weight 1/d^4: the 43 cm scan counts ~1/70 of a 14 cm one (1/d^2 would leave 1 mm)
    assert abs(ref - 0.40) < 0.0005


def test_scan_weight_falls_with_the_fourth_power_of_the_distance():
    # the case of the module docstring: a few scans from about 45 cm place the structure 2 cm
    # too far, then scans from 20 cm see it right. Weighted 1/d^4 the far scans together
    # weigh 1/35 of the near ones and the fused reference point is 0.6 mm off; 1/d^2 would
    # leave it 2.9 mm off (1/d: 5.8 mm), enough to jam a turn into a small branch.
    tr = StructureTracker()
    for x in (0.0, 0.01, 0.02):
        tr.update(bend(0.47 - x), np.array([x, 0, 0]), EYE)  # reference at 0.47
    for x in (0.25, 0.26, 0.27):
        s = tr.update(bend(0.45 - x), np.array([x, 0, 0]), EYE)  # reference at 0.45
    err = s.reference_world[0] - 0.45
    assert s.confirmed
    assert 0.0 < err < 0.0015, err


def test_handover_keeps_the_confirmed_estimate_and_propagates_it_by_odometry():
    tr = StructureTracker(handover_distance=0.12)
    drive(tr, 0.5, [0.1, 0.15, 0.2, 0.25], lambda d: bend(d, direction=1.0))
    # too close: the detector now says straight or sees a closure-like wall
    s1 = tr.update(straight(), np.array([0.42, 0, 0]), EYE)
    closure = Detection("closure", [StructureOption("closure", 0.05, 0.0)], 0.8)
    s2 = tr.update(closure, np.array([0.44, 0, 0]), EYE)
    for s, x in ((s1, 0.42), (s2, 0.44)):
        assert s.confirmed and s.handed_over
        assert s.detection.kind == "bend"
        assert s.detection.options[0].distance == pytest.approx(0.5 - x, abs=1e-9)
        assert s.detection.options[0].direction == pytest.approx(1.0, abs=1e-9)


def test_direction_follows_the_robot_roll():
    tr = StructureTracker(confirm_count=1, confirm_evidence=0.5)
    tr.update(bend(0.3, direction=0.0), np.zeros(3), EYE)  # bend to the left (+y world)
    c, s = math.cos(math.pi / 2), math.sin(math.pi / 2)
    rolled = np.array([[1, 0, 0], [0, c, -s], [0, s, c]], float)  # robot rolled +90 deg
    st = tr.update(bend(0.28, direction=-math.pi / 2), np.array([0.02, 0, 0]), rolled)
    o = st.detection.options[0]
    assert o.direction == pytest.approx(-math.pi / 2, abs=1e-6)
    assert st.n_updates == 2


def test_junction_ways_are_fused_and_passing_ends_the_track():
    def junction(d):
        return Detection(
            "junction",
            [
                StructureOption("junction", d, 0.1, 0.0, 0.0, 0.9),
                StructureOption("junction", d, 0.08, 2.0, math.pi / 2, 0.9),
            ],
            0.9,
        )

    tr = StructureTracker()
    states = drive(tr, 0.4, [0.0, 0.05, 0.1], junction)
    assert states[-1].confirmed
    assert len(states[-1].detection.options) == 2
    assert states[-1].detection.options[1].diameter == pytest.approx(0.08)
    s = tr.update(straight(), np.array([0.5, 0, 0]), EYE)  # 10 cm past the junction
    assert not s.confirmed and s.detection.kind == "straight"


def test_a_different_structure_replaces_a_tentative_track():
    tr = StructureTracker()
    tr.update(bend(0.4), np.zeros(3), EYE)
    closure = Detection("closure", [StructureOption("closure", 0.2, 0.0)], 0.9)
    s = tr.update(closure, np.zeros(3), EYE)
    assert s.detection.kind == "closure"


def test_reset_and_validation():
    tr = StructureTracker()
    drive(tr, 0.4, [0.0, 0.05, 0.1], lambda d: bend(d))
    tr.reset()
    s = tr.update(straight(), np.zeros(3), EYE)
    assert not s.confirmed and s.n_updates == 0
    with pytest.raises(ValueError, match="sensor_position"):
        tr.update(straight(), np.array([np.nan, 0, 0]), EYE)
    with pytest.raises(ValueError, match="gate"):
        StructureTracker(gate=-1.0)


def closure(distance, conf=0.9):
    return Detection("closure", [StructureOption("closure", distance, 0.0, 0.0, 0.0, conf)], conf)


def tee(distance, conf=0.9, diameter=0.06):
    opts = [
        StructureOption("junction", distance, diameter, -math.pi / 2, math.pi / 2, conf),
        StructureOption("junction", distance, diameter, math.pi / 2, math.pi / 2, conf),
    ]
    return Detection("junction", opts, conf)


def test_nearer_disagreeing_scans_overrule_a_confirmed_far_reading():
    # a tee seen from its stem looks like a closure from far away (its far wall); from nearer,
    # alternating readings say junction: the nearer ones win
    tr = StructureTracker()
    ref = 1.0
    for x in (0.55, 0.6, 0.65):
        s = tr.update(closure(ref + 0.03 - x), np.array([x, 0.0, 0.0]), EYE)
    assert s.confirmed and s.detection.kind == "closure"
    s = tr.update(tee(ref - 0.7), np.array([0.7, 0.0, 0.0]), EYE)
    assert s.detection.kind == "closure"  # one nearer scan is not enough
    s = tr.update(closure(ref + 0.03 - 0.75), np.array([0.75, 0.0, 0.0]), EYE)
    s = tr.update(tee(ref - 0.8), np.array([0.8, 0.0, 0.0]), EYE)
    assert s.detection.kind == "junction"
    s = tr.update(tee(ref - 0.82), np.array([0.82, 0.0, 0.0]), EYE)
    assert s.confirmed and s.detection.kind == "junction"
    assert [round(o.direction, 6) for o in s.detection.options] == pytest.approx(
        [-math.pi / 2, math.pi / 2]
    )


def test_a_way_straight_on_has_direction_zero_after_fusion():
    def tee_run(d):
        opts = [
            StructureOption("junction", d, 0.1, 0.7, 0.01, 0.9),  # straight on, 0.6 deg off
            StructureOption("junction", d, 0.1, 1.0, math.pi / 2, 0.9),
        ]
        return Detection("junction", opts, 0.9)

    tr = StructureTracker()
    rot = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # rolled 90 deg
    for x in (0.6, 0.62, 0.64):
        s = tr.update(tee_run(1.0 - x), np.array([x, 0.0, 0.0]), rot)
    straight_on = [o for o in s.detection.options if o.angle < 0.02]
    assert len(straight_on) == 1 and straight_on[0].direction == 0.0


def _long_bend(radius: float):
    def make(distance: float) -> Detection:
        option = StructureOption("bend", distance, 0.1, 0.0, math.pi / 2, 0.9, bend_radius=radius)
        return Detection("bend", [option], 0.9)

    return make


def test_a_long_bends_radius_is_fused_and_kept_only_when_most_scans_give_it():
    tr = StructureTracker(confirm_count=3)
    radii = iter([0.30, 0.26, 0.28, 0.0])  # the last scan's fit did not resolve the arc
    s = None
    for x in (0.5, 0.52, 0.54, 0.56):
        s = tr.update(_long_bend(next(radii))(1.0 - x), np.array([x, 0.0, 0.0]), EYE)
    assert s is not None and s.confirmed
    assert 0.26 < s.detection.options[0].bend_radius < 0.30
    tr.reset()
    for x in (0.5, 0.52, 0.54, 0.56):  # mostly mitre-like fits: no radius to follow
        r = 0.3 if x == 0.5 else 0.0
        s = tr.update(_long_bend(r)(1.0 - x), np.array([x, 0.0, 0.0]), EYE)
    assert s.detection.options[0].bend_radius == 0.0


def _junction(distance, ways, conf=0.9, diameter=0.08):
    """A junction detection with one way per (angle, direction) in ``ways``, radians."""
    opts = [StructureOption("junction", distance, diameter, dr, a, conf) for a, dr in ways]
    return Detection("junction", opts, conf)


def test_one_near_scan_inventing_a_way_does_not_turn_a_bend_into_a_junction():
    # calibration case (long bend, 111 mm, X4): five scans from 42 to 26 cm agree on a 60 deg
    # bend; the last one, from 17 cm, adds a phantom way at 150 deg. Weighted 1/d^4 that one
    # scan outweighed the other five on the kind and kept its phantom way.
    tr = StructureTracker()
    for x in (0.58, 0.62, 0.67, 0.70, 0.74):
        s = tr.update(
            bend(1.0 - x, angle=math.radians(60), direction=1.1), np.array([x, 0, 0]), EYE
        )
    assert s.confirmed and s.detection.kind == "bend"
    near = _junction(0.17, [(math.radians(150), -2.3), (math.radians(50), 1.1)])
    s = tr.update(near, np.array([0.83, 0, 0]), EYE)
    assert s.confirmed and s.detection.kind == "bend"
    assert len(s.detection.options) == 1
    assert s.detection.options[0].direction == pytest.approx(1.1, abs=0.01)


def test_one_near_scan_missing_a_branch_does_not_drop_the_junction():
    # calibration case (tee from its stem, 77 mm, X4): four scans from 47 to 30 cm see both
    # branches; one from 21 cm reads a bend with a wrong direction. Weighted 1/d^4 it alone
    # decided the kind (bend) and its way replaced both branches.
    tr = StructureTracker()
    branches = [(math.pi / 2, -0.92), (math.pi / 2, 2.22)]
    for x in (0.53, 0.60, 0.65, 0.70):
        s = tr.update(_junction(1.0 - x, branches), np.array([x, 0, 0]), EYE)
    assert s.confirmed and s.detection.kind == "junction"
    s = tr.update(bend(0.21, direction=-2.81), np.array([0.75, 0, 0]), EYE)
    assert s.detection.kind == "junction"
    dirs = sorted(o.direction for o in s.detection.options)
    assert dirs == pytest.approx([-0.92, 2.22], abs=0.05)


def test_a_branch_the_far_scans_missed_is_kept_once_near_scans_see_it():
    # the counterpart: three far scans read a tee's branch at 50 deg, two nearer ones at
    # 90 deg: the nearer reading supersedes the far one (which, seen three times, would be
    # kept were it not another reading of the same branch); a way seen by one scan only is
    # kept while the track has one scan
    tr = StructureTracker()
    run = (0.0, 0.0)
    branch = (math.pi / 2, 0.5)
    s = tr.update(_junction(0.45, [run, branch]), np.array([0.0, 0, 0]), EYE)
    assert len(s.detection.options) == 2
    tr.reset()
    for x in (0.55, 0.6, 0.65):  # the branch read at 50 deg: a way of its own (gate 25 deg)
        tr.update(_junction(1.0 - x, [run, (math.radians(50), 0.5)]), np.array([x, 0, 0]), EYE)
    for x in (0.75, 0.8):
        s = tr.update(_junction(1.0 - x, [run, branch]), np.array([x, 0, 0]), EYE)
    angles = sorted(round(math.degrees(o.angle)) for o in s.detection.options)
    assert angles == [0, 90]


def test_way_parameters_are_validated():
    with pytest.raises(ValueError, match="way_min_hits"):
        StructureTracker(way_min_hits=0)
    with pytest.raises(ValueError, match="way_keep_hits"):
        StructureTracker(way_keep_hits=0)
    with pytest.raises(ValueError, match="way_share"):
        StructureTracker(way_share=1.5)


def test_a_branch_seen_consistently_is_kept_when_near_scans_lose_it():
    # calibration case (tee from its stem, 85 mm, X4): scans from 47, 40 and 35 cm see both
    # branches, those from 30, 25 and 20 cm only one (the detector loses the other close up).
    # Three consistent sightings keep the branch: the tee stays a junction.
    tr = StructureTracker()
    branches = [(math.pi / 2, -1.03), (math.pi / 2, 2.13)]
    for x in (0.53, 0.60, 0.65):
        tr.update(_junction(1.0 - x, branches), np.array([x, 0, 0]), EYE)
    for x in (0.70, 0.75, 0.80):
        s = tr.update(bend(1.0 - x, direction=2.13), np.array([x, 0, 0]), EYE)
    assert s.confirmed and s.detection.kind == "junction"
    dirs = sorted(o.direction for o in s.detection.options)
    assert dirs == pytest.approx([-1.03, 2.13], abs=0.01)
    tr = StructureTracker(way_keep_hits=4)  # without the rule: a bend
    for x in (0.53, 0.60, 0.65):
        tr.update(_junction(1.0 - x, branches), np.array([x, 0, 0]), EYE)
    for x in (0.70, 0.75, 0.80):
        s = tr.update(bend(1.0 - x, direction=2.13), np.array([x, 0, 0]), EYE)
    assert s.detection.kind == "bend"


def test_a_second_way_only_far_scans_saw_is_dropped_when_near_scans_see_a_bend():
    # closed-loop case (100 mm mitre bend at the end of an 8 m straight, ideal sensor): the
    # sparse sweeps from 1.16 to 0.71 m read the bend's far wall as a second way on, four times
    # in a row; every scan from 0.66 m on sees the bend alone. Far sightings do not count
    # towards ``way_keep_hits``, so the bend stays a bend.
    tr = StructureTracker()
    ways = [(math.pi / 2, 0.0), (math.pi / 2, math.pi)]
    for x in (0.0, 0.15, 0.30, 0.45):
        tr.update(_junction(1.16 - x, ways), np.array([x, 0, 0]), EYE)
    for x in (0.50, 0.65, 0.70, 0.75, 0.80, 0.85, 0.90, 0.95):
        s = tr.update(bend(1.16 - x, direction=0.0), np.array([x, 0, 0]), EYE)
    assert s.confirmed and s.detection.kind == "bend"
    assert [round(o.direction, 3) for o in s.detection.options] == [0.0]
    tr = StructureTracker(way_keep_reach=2.0)  # every sighting counted: the phantom stays
    for x in (0.0, 0.15, 0.30, 0.45):
        tr.update(_junction(1.16 - x, ways), np.array([x, 0, 0]), EYE)
    for x in (0.50, 0.65, 0.70, 0.75, 0.80, 0.85, 0.90, 0.95):
        s = tr.update(bend(1.16 - x, direction=0.0), np.array([x, 0, 0]), EYE)
    assert len(s.detection.options) == 2


def _reducer(distance, diameter, conf=0.9):
    return Detection(
        "reducer", [StructureOption("reducer", distance, diameter, 0.0, 0.0, conf)], conf
    )


def test_a_confirmed_junction_is_not_overruled_by_a_near_reducer_reading():
    # closed-loop case (held-out network 64, 78 mm wye with a 45 deg branch, improved
    # detector): sweeps from 66, 62, 37 and 32 cm see the wye; from 26 and 20 cm its branch
    # mouth beside the way straight on reads as a widening, a reducer to 118 mm. The nearer
    # reducer scans outweighed the junction and the robot drove past the branch by itself.
    ways = [(0.0, 0.0), (math.pi / 4, math.pi)]
    positions = (0.0, 0.04, 0.29, 0.34)
    distances = (0.66, 0.62, 0.37, 0.32)
    near = ((0.40, 0.26), (0.46, 0.20))

    def run(tr):
        for x, d in zip(positions, distances, strict=True):
            s = tr.update(_junction(d, ways, diameter=0.078), np.array([x, 0, 0]), EYE)
        assert s.confirmed and s.detection.kind == "junction"
        for x, d in near:
            s = tr.update(_reducer(d, 0.118), np.array([x, 0, 0]), EYE)
        return s

    s = run(StructureTracker())
    assert s.confirmed and s.detection.kind == "junction"
    assert sorted(round(o.angle, 3) for o in s.detection.options) == [0.0, round(math.pi / 4, 3)]
    # a reducer seen from near still replaces a confirmed bend (one way on: no branch to keep)
    tr = StructureTracker()
    for x, d in zip(positions, distances, strict=True):
        tr.update(bend(d, angle=0.3, diameter=0.078), np.array([x, 0, 0]), EYE)
    for x, d in near:
        s = tr.update(_reducer(d, 0.118), np.array([x, 0, 0]), EYE)
    assert s.detection.kind == "reducer"
