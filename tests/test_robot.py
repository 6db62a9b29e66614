"""The robot model: configuration checks, placement, clamping read-back, straight driving."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipe_env import layouts
from pipe_env.robot import RobotConfig
from primitives.executor import Executor
from primitives.sequences import go_straight


def test_config_errors_name_field_value_and_range() -> None:
    with pytest.raises(ValueError, match=r"RobotConfig.n_modules = 3: .*\[4, 8\]"):
        RobotConfig(n_modules=3)
    with pytest.raises(ValueError, match=r"width = 0.07"):
        RobotConfig(width=0.07)
    with pytest.raises(ValueError, match=r"RobotConfig.jam_steer = 0.0: .*\[1, 180\] deg"):
        RobotConfig(jam_steer=0.0)


def test_one_robot_spans_57_to_125_mm() -> None:
    c = RobotConfig()
    assert c.clamp_diameter_at(0.0) < 0.057
    assert c.max_clamp_diameter >= 0.125
    for d in (0.057, 0.09, 0.125):
        assert c.clamp_diameter_at(c.clamp_angle(d)) == pytest.approx(d, abs=1e-6)


@pytest.mark.parametrize("diameter", [0.057, 0.075, 0.1, 0.125])
def test_clamped_diameter_reads_the_bore_within_a_millimetre(diameter: float) -> None:
    ex = Executor.for_network(layouts.straight(diameter, 1.0), lidar=None)
    assert ex.robot.clamped_diameter() == pytest.approx(diameter, abs=0.001)
    rng = np.random.default_rng(1)
    noisy = np.array([ex.robot.clamped_diameter(rng) for _ in range(200)])
    # encoder noise: visible, unbiased, about half a millimetre for 0.2 deg per hinge
    assert 0.0002 < float(np.std(noisy)) < 0.0012
    assert float(np.mean(noisy)) == pytest.approx(diameter, abs=0.001)
    # the clamp presses the wall with a moderate force, not the welds' full pull
    assert 0.0 < ex.robot.apex_force() < 60.0


def test_diameter_reading_ignores_the_front_module_tilt() -> None:
    ex = Executor.for_network(layouts.straight(0.1, 1.0), lidar=None)
    q = ex.robot.joint_angles()
    before = ex.robot.diameter_from_angles(q)
    # bending the first joint only tilts the front module relative to the V
    q2 = q.copy()
    q2[0] += math.radians(3.0)
    assert ex.robot.diameter_from_angles(q2) == pytest.approx(before, abs=0.0015)
    # folding the apex further widens the reading
    apex = ex.robot.joint_names().index("robot/bend_3_y")
    q3 = q.copy()
    q3[apex] += math.radians(4.0)
    assert ex.robot.diameter_from_angles(q3) > before + 0.002


@pytest.mark.parametrize("diameter", [0.06, 0.12])
def test_placed_robot_reads_its_pipe_and_drives_one_metre(diameter: float) -> None:
    ex = Executor.for_network(layouts.straight(diameter, 3.0), lidar=None)
    assert ex.robot.sensor_pose().position == pytest.approx([0, 0, 0], abs=0.003)
    assert ex.robot.clamped_diameter() == pytest.approx(diameter, abs=0.001)
    out = ex.run(go_straight(1.0))
    assert out.status == "done"
    assert out.travelled == pytest.approx(1.0, abs=0.01)
    p = ex.robot.sensor_pose()
    assert p.position[0] == pytest.approx(1.0, abs=0.01)
    assert math.degrees(math.acos(min(1.0, p.forward[0]))) < 5.0
    assert ex.robot.clamped_diameter() == pytest.approx(diameter, abs=0.001)
    assert set(out.telemetry) >= {"times", "sensor_position", "poses", "contact_force"}
