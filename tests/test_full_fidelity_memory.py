"""Full fidelity holds one episode's worth of memory, whatever the number of episodes.

What a long soak showed growing or fragmenting the heap, pinned here without timing anything:
the executor's telemetry is one array per run (not five small arrays and a tuple per control
tick), placing the robot releases the driven path and the telemetry of the last episode, and
closing a plant releases its MuJoCo world (a plant used after closing builds it again).
"""

from __future__ import annotations

import gc
import tracemalloc
import weakref

import numpy as np
import pytest

from pipe_env import layouts
from pipe_env.envs.plant_full import PhysicalPlant
from primitives.executor import Executor
from primitives.path import MIN_CAPACITY
from primitives.sequences import go_straight
from primitives.telemetry import MIN_ROWS


def test_telemetry_is_one_array_per_run_and_cleared_when_placed() -> None:
    ex = Executor.for_network(layouts.straight(0.09, 2.0), lidar=None)
    out = ex.run(go_straight(0.3))
    ticks = len(out.telemetry["times"])
    assert out.status == "done" and ticks > 100
    assert len(ex.telemetry) == ticks
    assert ex.telemetry.capacity <= max(MIN_ROWS, 2 * ticks)
    assert out.telemetry["joint_angles"].shape == (ticks, len(ex.robot.joint_angles()))
    assert np.all(np.diff(out.telemetry["times"]) > 0)
    ex.place(layouts.straight(0.09, 2.0).start_pose, 0.09)
    assert len(ex.telemetry) < ticks


def test_placing_the_robot_releases_the_last_episodes_driven_path() -> None:
    net = layouts.straight(0.09, 3.0)
    ex = Executor.for_network(net, lidar=None, physics="everywhere")
    ex.run(go_straight(1.5))
    grown = ex.path.capacity
    assert grown > 2 * MIN_CAPACITY
    assert net.start_pose is not None
    ex.place(net.start_pose, 0.09)
    assert ex.path.capacity <= 2 * MIN_CAPACITY < grown
    assert ex.odometer == 0.0


def test_closing_a_plant_releases_its_world_and_reset_builds_it_again() -> None:
    net = layouts.t_junction(0.09, direction=0.0, distance=0.4)
    plant = PhysicalPlant(net, detector="ground_truth")
    dec, _ = plant.advance(None)
    assert dec is not None
    world = weakref.ref(plant.world)
    executor = weakref.ref(plant.executor)
    plant.close()
    gc.collect()
    assert world() is None and executor() is None
    assert plant.detection_log == [] and plant.last_scan is None
    with pytest.raises(RuntimeError, match="closed"):
        plant.pose()
    plant.reset(np.random.default_rng(1))
    dec, out = plant.advance(None)
    assert dec is not None and out.status != "jammed"


def test_plants_built_one_after_another_hold_no_more_python_memory() -> None:
    """Each plant closed before the next (what the environment does on a new network): the
    Python heap after the fourth is where it was after the second."""
    net = layouts.straight(0.09, 1.0)
    tracemalloc.start()
    try:
        traced = []
        for _ in range(4):
            plant = PhysicalPlant(net, detector="ground_truth")
            plant.advance(None)
            plant.close()
            del plant
            gc.collect()
            traced.append(tracemalloc.get_traced_memory()[0])
    finally:
        tracemalloc.stop()
    assert traced[3] - traced[1] < 256 * 1024, traced
