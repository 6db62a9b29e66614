"""Physics where contact decides: kinematic straights, the sweep cadence, the cached model."""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import pipe_env  # noqa: F401
from pipe_env import layouts
from pipe_env.envs.plant import KinematicPlant, Plant
from pipe_env.envs.plant_full import PhysicalPlant
from primitives.executor import Executor


def test_physics_mode_is_checked() -> None:
    net = layouts.straight(0.1, distance=1.0)
    with pytest.raises(ValueError, match="physics"):
        Executor.for_network(net, lidar=None, physics="sometimes")
    with pytest.raises(ValueError, match="physics"):
        gym.make("pipenav/PipeNav-v0", fidelity="full", physics="sometimes")


def test_a_straight_away_from_fittings_is_driven_kinematically_as_physics_would() -> None:
    """2 m of 90 mm pipe to a bend, the robot steering by its sweeps: the contact mode glides
    where the rule allows and decides where the all-physics reference decides (within 1 mm and
    0.1 deg), clamped the same, at the same simulated time (to the rounding of its motions to
    whole time-compressed ticks: the contact mode runs compressed, the reference does not)."""
    net = layouts.mitre_bend(0.09, math.pi / 2, 0.0, distance=2.0)
    plants = {}
    for physics in ("everywhere", "contact"):
        plant = PhysicalPlant(net, detector="ground_truth", physics=physics)
        dec, out = plant.advance(None)
        assert dec is not None and dec.kind == "bend" and out.status == "done"
        plants[physics] = plant
    ref, new = plants["everywhere"], plants["contact"]
    assert ref.executor.kinematic_ticks == 0
    assert new.executor.kinematic_ticks > 0.3 * ref.executor.physics_ticks
    assert new.executor.physics_ticks < 0.5 * ref.executor.physics_ticks
    a, b = ref.pose(), new.pose()
    assert float(np.linalg.norm(a.position - b.position)) < 0.001
    cos = float(np.clip(a.rotation[:, 0] @ b.rotation[:, 0], -1.0, 1.0))
    assert math.degrees(math.acos(cos)) < 0.1
    assert new.robot.clamped_diameter() == pytest.approx(ref.robot.clamped_diameter(), abs=5e-4)
    assert new.sim_time == pytest.approx(ref.sim_time, rel=1e-3)


def test_near_a_fitting_physics_runs() -> None:
    """The rule: within a diameter plus the robot's length of a fitting, no kinematic motion;
    the reference mode never glides."""
    net = layouts.mitre_bend(0.1, math.pi / 2, 0.0, distance=0.15)
    ex = Executor.for_network(net, lidar=None, physics="contact")
    assert ex.free_straight(0.05) is None  # the sensor would come within a diameter of it
    far = layouts.mitre_bend(0.1, math.pi / 2, 0.0, distance=2.0)
    ex = Executor.for_network(far, lidar=None, physics="contact")
    axis = ex.free_straight(0.05)
    assert axis is not None and float(axis @ ex.robot.sensor_pose().forward) > 0.999
    assert ex.free_straight(1.9) is None  # would end next to the bend
    assert Executor.for_network(far, lidar=None).free_straight(0.05) is None


def test_sparse_sweeps_while_nothing_is_in_reach() -> None:
    """A 3 m straight to a bend: the sparse cadence sweeps far fewer times and stops at the
    same structure as the fixed 5 cm cadence."""
    net = layouts.mitre_bend(0.1, math.pi / 2, 0.0, distance=3.0)
    stops = {}
    for sparse in (0.05, 0.15):
        plant = PhysicalPlant(net, detector="ground_truth", sparse_interval=sparse)
        dec, out = plant.advance(None)
        assert dec is not None and dec.kind == "bend" and out.status == "done"
        stops[sparse] = (len(plant.detection_log), plant.edge_position().s)
    assert stops[0.15][0] < 0.6 * stops[0.05][0]
    assert stops[0.15][1] == pytest.approx(stops[0.05][1], abs=0.03)
    with pytest.raises(ValueError, match="sparse_interval"):
        PhysicalPlant(net, sparse_interval=0.01)


def test_both_plants_are_plants() -> None:
    net = layouts.straight(0.1, distance=1.0)
    assert isinstance(KinematicPlant(net), Plant)
    assert isinstance(PhysicalPlant(net, detector="ground_truth"), Plant)


def test_the_model_is_built_once_per_network_and_reset_between_episodes() -> None:
    """Episodes on the same network reuse the plant (its compiled model); a reset on it gives
    the episode a fresh plant gives (same observation, same pose)."""
    net = layouts.t_junction(0.1, direction=0.0, distance=0.3).with_goals([[0, 0.5, 0]])
    env = gym.make("pipenav/PipeNav-v0", fidelity="full", network=net, detector="ground_truth")
    base = env.unwrapped
    env.reset(seed=4)
    plant, model = base.plant, base.plant.world.model
    env.step(int(np.flatnonzero(base.action_masks())[0]))
    obs, _ = env.reset(seed=5)
    assert base.plant is plant and base.plant.world.model is model
    assert isinstance(model, mujoco.MjModel)
    fresh = gym.make("pipenav/PipeNav-v0", fidelity="full", network=net, detector="ground_truth")
    obs2, _ = fresh.reset(seed=5)
    for k in obs:
        assert np.array_equal(obs[k], obs2[k]), k
    assert np.array_equal(base.plant.pose().position, fresh.unwrapped.plant.pose().position)
