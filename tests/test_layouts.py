"""Canonical layouts and the ground truth they produce (docs/design.md option definitions)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from detector.geometry import Pose, rotation_about, wrap_angle
from pipe_env import layouts

diameters = st.floats(0.057, 0.125)
distances = st.floats(0.1, 0.4)
directions = st.floats(-math.pi, math.pi)
angles = st.floats(math.radians(30), math.radians(90))


def close_dir(a: float, b: float) -> bool:
    return abs(wrap_angle(a - b)) < 1e-6


@settings(max_examples=40)
@given(d=diameters, a=angles, phi=directions, dist=distances, long=st.booleans())
def test_bend_truth_matches_parameters(
    d: float, a: float, phi: float, dist: float, long: bool
) -> None:
    # a long bend's arc starts its tangent length R tan(a/2) before the reference point: the
    # start pose must lie in the straight before it (else the layout rightly refuses it)
    assume(not long or dist > 2.0 * d * math.tan(a / 2) + 0.02)
    net = (
        layouts.long_bend(d, a, phi, dist, radius_factor=2.0)
        if long
        else layouts.mitre_bend(d, a, phi, dist)
    )
    (o,) = net.structures_ahead(net.start_pose)
    assert o.kind == "bend"
    assert o.distance == pytest.approx(dist)
    assert o.diameter == pytest.approx(d)
    assert o.angle == pytest.approx(a)
    assert close_dir(o.direction, phi)


@settings(max_examples=30)
@given(d=diameters, phi=directions, dist=distances, frac=st.floats(0.6, 1.0))
def test_tee_from_run_and_stem(d: float, phi: float, dist: float, frac: float) -> None:
    db = max(0.057, d * frac)
    run = layouts.t_junction(d, db, phi, dist, entry="run")
    straight, branch = run.structures_ahead(run.start_pose)
    assert straight.kind == branch.kind == "junction"
    assert straight.angle == pytest.approx(0.0, abs=1e-9) and straight.diameter == pytest.approx(d)
    assert branch.angle == pytest.approx(math.pi / 2) and branch.diameter == pytest.approx(db)
    assert close_dir(branch.direction, phi)
    stem = layouts.t_junction(d, db, phi, dist, entry="stem")
    opts = stem.structures_ahead(stem.start_pose)
    assert len(opts) == 2
    assert all(
        o.angle == pytest.approx(math.pi / 2) and o.diameter == pytest.approx(d) for o in opts
    )
    assert any(close_dir(o.direction, phi) for o in opts)
    assert any(close_dir(o.direction, phi + math.pi) for o in opts)


def test_wye_and_cross() -> None:
    y = layouts.y_junction(0.1, 0.08, direction=1.0)
    assert [round(math.degrees(o.angle)) for o in y.structures_ahead(y.start_pose)] == [0, 45]
    yb = layouts.y_junction(0.1, 0.08, direction=1.0, entry="branch")
    assert sorted(round(math.degrees(o.angle)) for o in yb.structures_ahead(yb.start_pose)) == [
        45,
        135,
    ]
    c = layouts.cross_junction(0.1, direction=0.3)
    opts = c.structures_ahead(c.start_pose)
    assert [round(math.degrees(o.angle)) for o in opts] == [0, 90, 90]
    assert sorted(round(math.degrees(o.direction)) for o in opts[1:]) == [-163, 17]


def test_reducer_closure_straight() -> None:
    r = layouts.reducer(0.1, 0.055, taper_length=0.2, distance=0.3)
    (o,) = r.structures_ahead(r.start_pose)
    assert (o.kind, o.distance, o.diameter) == ("reducer", pytest.approx(0.3), pytest.approx(0.055))
    c = layouts.closure(0.09, distance=0.25)
    (o,) = c.structures_ahead(c.start_pose)
    assert (o.kind, o.distance, o.diameter) == ("closure", pytest.approx(0.25), 0.0)
    s = layouts.straight(0.1, distance=3.0)
    assert s.structures_ahead(s.start_pose, 2.0) == []
    assert s.structures_ahead(s.start_pose, 4.0)[0].kind == "closure"


def test_direction_is_measured_in_the_sensor_frame() -> None:
    """Rolling the sensor by r shifts every option's direction by -r."""
    net = layouts.mitre_bend(0.1, math.radians(60), direction=0.5, distance=0.3)
    for roll in (0.3, -1.2, 2.5):
        pose = net.start_pose.rolled(roll)
        (o,) = net.structures_ahead(pose)
        assert close_dir(o.direction, 0.5 - roll)
        assert o.distance == pytest.approx(0.3)


def test_distance_is_along_the_pipe_axis_for_offset_and_tilted_sensors() -> None:
    net = layouts.mitre_bend(0.1, math.pi / 2, direction=0.0, distance=0.3)
    tilt = rotation_about([0, 0, 1], math.radians(4))
    pose = Pose(np.array([-0.3, 0.02, -0.01]), tilt)
    (o,) = net.structures_ahead(pose)
    assert o.distance == pytest.approx(0.3)
    # the tilt is about z, so the left/right direction sees it: outgoing +y stays "left" up to tilt
    assert abs(o.direction) < 1e-9


def test_start_pose_and_behind_room() -> None:
    for name in layouts.LAYOUTS:
        net = layouts.make_layout(name)
        entry = net.position("entry")
        assert net.start_pose.position[0] - entry[0] >= layouts.BEHIND
        assert np.allclose(net.start_pose.rotation, np.eye(3))


def test_bad_parameters_are_named() -> None:
    with pytest.raises(ValueError, match=r"layout: angle = 0.1: out of range"):
        layouts.mitre_bend(angle=0.1)
    with pytest.raises(ValueError, match=r"entry = 'side': not allowed; allowed: 'run'"):
        layouts.t_junction(entry="side")
    with pytest.raises(ValueError, match=r"layout = 'spiral': unknown; allowed: closure"):
        layouts.make_layout("spiral")
    with pytest.raises(
        ValueError, match=r"params = .*unexpected keyword.*allowed: the parameters of closure"
    ):
        layouts.make_layout("closure", angle=1.0)
