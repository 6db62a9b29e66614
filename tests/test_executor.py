"""The executor: turns with ground-truth options pass; wrong options jam; refusals."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from pipe_env import layouts
from pipe_env.ground_truth import structures_ahead
from pipe_env.routing import locate
from primitives.executor import Executor
from primitives.sequences import Sequence, back_out, for_option, go_straight
from primitives.steps import Drive, Unclamp


def _turn(net, pick: int = -1, d_err: float = 0.0, dir_err: float = 0.0):
    ex = Executor.for_network(net, lidar=None)
    opts = structures_ahead(net, ex.robot.sensor_pose(), 5.0)
    if opts[0].distance > 0.2:
        ex.run(go_straight(opts[0].distance - 0.2))
    o = structures_ahead(net, ex.robot.sensor_pose(), 5.0)[pick]
    o = replace(o, distance=o.distance + d_err, direction=o.direction + dir_err)
    out = ex.run(for_option(o, incoming_diameter=ex.robot.clamped_diameter()))
    ep, _ = locate(net, ex.robot.sensor_pose())
    return out, ep.run_id


@pytest.mark.parametrize("diameter", [0.06, 0.09, 0.12])
def test_mitre_90_turn_passes(diameter: float) -> None:
    out, run = _turn(layouts.mitre_bend(diameter, math.pi / 2, 0.0))
    assert out.status == "done", out.reason
    assert run == "r_out0"


@pytest.mark.parametrize(
    ("make", "diameter", "direction_deg"),
    [(layouts.long_bend, 0.09, 225.0), (layouts.mitre_bend, 0.06, 90.0)],
)
def test_robot_is_centred_on_the_outgoing_axis_after_a_turn(make, diameter, direction_deg) -> None:
    net = make(diameter, math.pi / 2, math.radians(direction_deg))
    ex = Executor.for_network(net, lidar=None)
    o = structures_ahead(net, ex.robot.sensor_pose(), 5.0)[0]
    out = ex.run(for_option(o, incoming_diameter=ex.robot.clamped_diameter()))
    assert out.status == "done", out.reason
    # both chain ends on the axis (the walls alone leave them against a wall: 6-20 mm off)
    for i in (0, ex.config.n_modules - 1):
        p = ex.robot.module_pose(i).position
        assert net.centreline.nearest(p).distance < 0.002
    assert ex.robot.clamped_diameter() == pytest.approx(diameter, abs=0.001)


def test_tee_branch_passes() -> None:
    out, run = _turn(layouts.t_junction(0.09, direction=math.pi / 2))
    assert out.status == "done", out.reason
    assert run == "r_out1"


def test_direction_off_by_90_deg_jams() -> None:
    out, _ = _turn(layouts.mitre_bend(0.09, math.pi / 2, 0.0), dir_err=math.pi / 2)
    assert out.status in ("jammed", "blocked")


def test_reducer_below_57_mm_is_refused_before_entering() -> None:
    net = layouts.reducer(0.1, 0.045)
    ex = Executor.for_network(net, lidar=None)
    before = ex.robot.sensor_pose().position.copy()
    o = structures_ahead(net, ex.robot.sensor_pose(), 5.0)[0]
    out = ex.run(for_option(o, incoming_diameter=0.1))
    assert out.status == "blocked"
    assert ex.robot.sensor_pose().position == pytest.approx(before, abs=0.002)


def test_closure_is_a_dead_end() -> None:
    net = layouts.closure(0.09)
    ex = Executor.for_network(net, lidar=None)
    o = structures_ahead(net, ex.robot.sensor_pose(), 5.0)[0]
    assert ex.run(for_option(o)).status == "dead_end"


def test_sequences_round_trip_as_data() -> None:
    net = layouts.mitre_bend(0.09)
    o = structures_ahead(net, net.start_pose, 5.0)[0]
    seq = for_option(o, incoming_diameter=0.09)
    assert Sequence.from_dict(seq.to_dict()) == seq
    assert "take_turn" in str(seq) and "roll(" in str(seq)


def test_driving_into_a_45_mm_bore_jams_at_its_mouth() -> None:
    net = layouts.reducer(0.1, 0.045, taper_length=0.1, distance=0.5)
    ex = Executor.for_network(net, lidar=None)
    out = ex.run(Sequence("force_in", (Unclamp(), Drive(1.2))))
    assert out.status == "jammed"
    # the front module stalled in the taper: its front wheels never got into the 45 mm bore,
    # which starts where the taper ends (0.1 m)
    front = ex.robot.front_pose().position
    mouth = float(net.geometry["s"].reference_point("r_out0")[0])
    assert front[0] + 0.5 * ex.config.pitch < mouth
    assert out.travelled < 0.7


def test_after_a_jammed_turn_backing_out_reclamps_on_the_axis() -> None:
    net = layouts.mitre_bend(0.1, math.pi / 2, 0.0)
    ex = Executor.for_network(net, lidar=None)
    o = structures_ahead(net, ex.robot.sensor_pose(), 5.0)[0]
    # wrong roll direction: the turn jams with the front half rolled
    out = ex.run(for_option(replace(o, direction=o.direction + 1.7), incoming_diameter=0.1))
    assert out.status == "jammed"
    back = ex.run(back_out(out.travelled, diameter=0.1))
    assert back.status == "done", back.reason
    assert abs(ex.robot.roll_angle) < 0.05
    assert ex.robot.clamped_diameter() == pytest.approx(0.1, abs=0.0015)
    for i in (0, ex.config.n_modules - 1):
        assert net.centreline.nearest(ex.robot.module_pose(i).position).distance < 0.002


def test_drive_until_sweeps_again_in_place_on_rescan_up_to_the_cap() -> None:
    from primitives.executor import MAX_RESCANS

    ex = Executor.for_network(layouts.straight(0.09, 2.0), lidar="ideal")
    odometers: list[float] = []

    def on_scan(scan, state) -> str:
        odometers.append(round(state.odometer, 6))
        return "stop" if len(odometers) > 2 * (MAX_RESCANS + 1) else "rescan"

    out = ex.drive_until(on_scan, 1.0, scan_interval=0.02)
    assert out.status == "done"
    # every stop sweeps MAX_RESCANS + 1 times before the robot drives on
    per_stop = [odometers.count(v) for v in dict.fromkeys(odometers)]
    assert per_stop[:2] == [MAX_RESCANS + 1, MAX_RESCANS + 1]
    assert odometers[MAX_RESCANS + 1] == pytest.approx(odometers[0] + 0.02, abs=1e-6)


def test_aim_turns_the_drive_heading_by_at_most_its_limit() -> None:
    import numpy as np

    ex = Executor.for_network(layouts.straight(0.09, 1.0), lidar=None)
    x0 = ex.command.rotation[:, 0].copy()
    want = np.array([math.cos(0.2), math.sin(0.2), 0.0])
    want = ex.command.rotation @ want  # 11.5 deg to the left of the current heading
    turned = ex.aim(want, max_angle=math.radians(4.0))
    assert turned == pytest.approx(math.radians(4.0))
    heading = ex.command.rotation[:, 0]
    assert math.degrees(math.acos(float(heading @ x0))) == pytest.approx(4.0, abs=1e-6)
    assert ex.aim(ex.command.rotation[:, 0]) == 0.0
    with pytest.raises(ValueError, match="direction"):
        ex.aim(np.zeros(3))


def test_drive_until_recentres_when_the_clamp_reading_drops(monkeypatch) -> None:
    """A clamp reading 5 mm below the last clamping means the robot was pushed off the axis:
    it centres and clamps again before driving on (and not while the reading holds)."""
    ex = Executor.for_network(layouts.straight(0.09, 2.0), lidar="ideal")
    real_reading = ex.robot.clamped_diameter
    pushed = {"now": False}
    monkeypatch.setattr(
        ex.robot,
        "clamped_diameter",
        lambda rng=None: real_reading(rng) - (0.005 if pushed["now"] else 0.0),
    )
    centred = []
    real_centre = ex._centre
    monkeypatch.setattr(
        ex, "_centre", lambda step, rng: (centred.append(1), real_centre(step, rng))
    )
    sweeps = []

    def on_scan(scan, state) -> str:
        sweeps.append(state.odometer)
        pushed["now"] = len(sweeps) == 2  # pushed off after the second stop's sweep
        return "stop" if len(sweeps) == 4 else "continue"

    out = ex.drive_until(on_scan, 1.0, scan_interval=0.02)
    assert out.status == "done"
    assert len(centred) == 1
