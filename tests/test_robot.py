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
    with pytest.raises(ValueError, match=r"n_modules = 3 .*\[4, 8\]"):
        RobotConfig(n_modules=3)
    with pytest.raises(ValueError, match=r"width = 0.07"):
        RobotConfig(width=0.07)


def test_one_robot_spans_57_to_125_mm() -> None:
    c = RobotConfig()
    assert c.clamp_diameter_at(0.0) < 0.057
    assert c.max_clamp_diameter >= 0.125
    for d in (0.057, 0.09, 0.125):
        assert c.clamp_diameter_at(c.clamp_angle(d)) == pytest.approx(d, abs=1e-6)


@pytest.mark.parametrize("diameter", [0.06, 0.12])
def test_placed_robot_reads_its_pipe_and_drives_one_metre(diameter: float) -> None:
    ex = Executor.for_network(layouts.straight(diameter, 3.0), lidar=None)
    assert ex.robot.sensor_pose().position == pytest.approx([0, 0, 0], abs=0.003)
    assert ex.robot.clamped_diameter() == pytest.approx(diameter, abs=0.01)
    rng = np.random.default_rng(1)
    noisy = [ex.robot.clamped_diameter(rng) for _ in range(20)]
    assert np.std(noisy) > 0
    out = ex.run(go_straight(1.0))
    assert out.status == "done"
    assert out.travelled == pytest.approx(1.0, abs=0.01)
    p = ex.robot.sensor_pose()
    assert p.position[0] == pytest.approx(1.0, abs=0.01)
    assert math.degrees(math.acos(min(1.0, p.forward[0]))) < 5.0
    assert set(out.telemetry) >= {"times", "sensor_position", "poses", "contact_force"}
