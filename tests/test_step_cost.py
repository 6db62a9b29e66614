"""The physics step's settings chosen for its cost (``pipe_env.world``): island discovery off,
with the robot driving bit for bit as before; and the step-cost benchmark's per-state figures."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from benchmarks.bench_step_cost import SCENARIOS, VARIANTS, _summary, run_scenario
from pipe_env import layouts
from pipe_env.ground_truth import structures_ahead
from pipe_env.world import build_world
from primitives.executor import Executor
from primitives.sequences import for_option, go_straight

ISLAND = int(mujoco.mjtDisableBit.mjDSBL_ISLAND)


def _drive_and_turn(flags_on: int) -> tuple[str, np.ndarray, np.ndarray, float]:
    """A straight drive and the turn of a mitre bend, with the disable ``flags_on`` cleared
    (switched back on); returns the turn's status, qpos, the geoms' poses and the time."""
    net = layouts.mitre_bend(0.06, math.pi / 2, math.pi / 2)
    ex = Executor.for_network(net, lidar=None)
    ex.model.opt.disableflags &= ~flags_on
    start = net.start_pose
    assert start is not None
    ex.place(start, float(net.inner_diameter_at(start.position)))
    ex.run(go_straight(0.05))
    option = structures_ahead(net, ex.robot.sensor_pose(), 5.0)[0]
    out = ex.run(for_option(option, ex.robot.clamped_diameter()))
    return out.status, ex.data.qpos.copy(), ex.data.geom_xpos.copy(), ex.data.time


def test_a_robot_world_steps_without_island_discovery_and_with_gravity() -> None:
    ex = Executor.for_network(layouts.straight(0.1, 1.0), lidar=None)
    assert ex.model.opt.disableflags & ISLAND
    assert not ex.model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_GRAVITY)
    assert ex.world.spec.option.disableflags & ISLAND  # (kept on recompiling the spec)


def test_without_islands_the_robot_drives_bit_for_bit_as_with_them() -> None:
    base = _drive_and_turn(0)
    islands = _drive_and_turn(ISLAND)
    assert base[0] == islands[0] == "done" and base[3] == islands[3]
    assert np.array_equal(base[1], islands[1])
    assert np.array_equal(base[2], islands[2])


def test_a_world_without_islands_still_lets_an_unconstrained_body_fall() -> None:
    def ball(spec: mujoco.MjSpec) -> None:
        b = spec.worldbody.add_body()
        b.pos = [0.0, 0.0, 0.5]
        b.add_freejoint()
        g = b.add_geom()
        g.type = mujoco.mjtGeom.mjGEOM_SPHERE
        g.size = [0.01, 0.0, 0.0]
        g.mass = 0.1

    world = build_world(layouts.straight(0.1, 1.0), customize=ball)
    assert world.model.opt.disableflags & ISLAND
    z0 = world.data.qpos[2]
    mujoco.mj_step(world.model, world.data, nstep=50)
    assert world.data.qpos[2] < z0 - 1e-3


def test_the_step_cost_benchmark_counts_steps_contacts_and_rows_per_state() -> None:
    run = run_scenario(SCENARIOS[0], "model")
    states = _summary(run)
    assert {"clamp", "drive"} <= set(states)
    drive = states["drive"]
    assert drive["steps"] > 1000 and drive["us_per_step"] > 0.0
    assert drive["nefc"] >= 36  # six welds of six rows each, and the contacts' rows
    assert drive["niter"] >= 1.0
    assert run.status == "done" and len(run.front) > 0
    assert set(VARIANTS) >= {"model", "before"}
