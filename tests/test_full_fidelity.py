"""Full-fidelity plant: the MuJoCo robot reaches a goal beyond a tee's branch."""

from __future__ import annotations

import pytest

from pipe_env import layouts
from pipe_env.plant_full import PhysicalPlant
from pipe_env.routing import EdgePosition, edge_length


@pytest.mark.parametrize("detector", ["ground_truth", "improved"])
def test_tee_branch_goal_is_reached(detector: str) -> None:
    net = layouts.t_junction(0.09, direction=0.0, distance=0.5)
    plant = PhysicalPlant(net, detector=detector)
    goal = EdgePosition("r_out1", 0.45, edge_length(net, "r_out1"))
    dec, out = plant.advance(goal)
    assert dec is not None and out.status != "jammed"
    branch = [o for o in dec.options if o.angle > 1.0]
    assert branch
    res = plant.execute(branch[0], goal)
    if res.status != "goal":
        _, res = plant.advance(goal)
    assert res.status == "goal"
    assert plant.edge_position().run_id == "r_out1"


@pytest.mark.parametrize("detector", ["ground_truth", "improved"])
def test_reducer_below_57_mm_is_blocked_before_the_robot_enters(detector: str) -> None:
    net = layouts.reducer(0.1, 0.045, taper_length=0.1, distance=0.5)
    plant = PhysicalPlant(net, detector=detector)
    dec, out = plant.advance(None)
    assert dec is not None and out.status != "jammed"
    assert plant.edge_position().run_id == "r_in"
    before = plant.pose().position.copy()
    # the sensed way on is narrower than the robot's range: every option is refused
    for option in dec.options:
        res = plant.execute(option)
        assert res.status == "blocked", (option, res.note)
        assert plant.pose().position == pytest.approx(before, abs=0.002)
    assert any(o.kind == "reducer" and o.diameter < 0.057 for o in dec.options)
