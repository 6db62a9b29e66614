"""Physics where contact decides: kinematic straights, the sweep cadence, the cached model."""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import pipe_env  # noqa: F401
from pipe_env import layouts
from pipe_env.envs.env import PipeNavEnv
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
    """The rule: within a diameter of a fitting, no kinematic motion;
    the reference mode never glides."""
    net = layouts.mitre_bend(0.1, math.pi / 2, 0.0, distance=0.15)
    ex = Executor.for_network(net, lidar=None, physics="contact")
    assert ex.free_straight(0.05) is None  # the sensor would come near it
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
    assert isinstance(base, PipeNavEnv)
    env.reset(seed=4)
    plant = base.plant
    assert isinstance(plant, PhysicalPlant) and plant.world is not None
    model = plant.world.model
    env.step(int(np.flatnonzero(base.action_masks())[0]))
    obs, _ = env.reset(seed=5)
    assert plant.world is not None and plant.world.model is model
    assert base.plant is plant
    assert isinstance(model, mujoco.MjModel)
    fresh = gym.make("pipenav/PipeNav-v0", fidelity="full", network=net, detector="ground_truth")
    obs2, _ = fresh.reset(seed=5)
    fresh_env = fresh.unwrapped
    assert isinstance(fresh_env, PipeNavEnv) and fresh_env.plant is not None
    for k in obs:
        assert np.array_equal(obs[k], obs2[k]), k
    assert np.array_equal(base.plant.pose().position, fresh_env.plant.pose().position)


def test_the_free_run_ends_the_clearance_inside_the_port_plane() -> None:
    """The kinematic rule's span: the sensor may glide up to ``KINEMATIC_CLEARANCE`` diameters
    short of the bend's port plane, and no further."""
    from pipe_env.routing import edge_length, leg_length, locate
    from primitives.executor import KINEMATIC_CLEARANCE, KINEMATIC_MARGIN

    net = layouts.mitre_bend(0.1, math.pi / 2, 0.0, distance=1.0)
    ex = Executor.for_network(net, lidar=None, physics="contact")
    span = ex.free_span()
    assert span is not None
    axis, back, ahead = span
    ep, towards = locate(net, ex.robot.sensor_pose())
    run = net.run_by_id[ep.run_id]
    assert towards == run.b
    port = edge_length(net, run.id) - leg_length(net, run.b, run.id)
    assert ahead == pytest.approx(port - (KINEMATIC_CLEARANCE * 0.1 + KINEMATIC_MARGIN) - ep.s)
    assert back >= 0.0
    assert ex.free_straight(ahead - 1e-4) is not None
    assert ex.free_straight(ahead + 1e-4) is None
    assert Executor.for_network(net, lidar=None, physics="everywhere").free_span() is None


def _drive_both(steps: tuple) -> dict[str, Executor]:
    from primitives.sequences import Sequence

    net = layouts.mitre_bend(0.09, math.pi / 2, 0.0, distance=1.0)
    out = {}
    for physics in ("everywhere", "contact"):
        ex = Executor.for_network(net, lidar=None, physics=physics, time_compression=1.5)
        res = ex.run(Sequence("test", steps))
        assert res.status == "done", res.reason
        out[physics] = ex
    return out


def test_a_drive_leaving_the_free_run_glides_to_its_end_then_runs_physics() -> None:
    """A clamped drive from the free run up to 4 cm before the bend: the contact mode glides
    the free part and drives the rest physically, ending where the reference does (1 mm)."""
    from primitives.steps import Drive

    probe = Executor.for_network(
        layouts.mitre_bend(0.09, math.pi / 2, 0.0, distance=1.0), lidar=None, physics="contact"
    )
    span = probe.free_span()
    assert span is not None
    run = _drive_both((Drive(span[2] + 0.05),))
    ref, new = run["everywhere"], run["contact"]
    assert new.kinematic_ticks > 0 and new.physics_ticks < 0.6 * ref.physics_ticks
    a, b = ref.robot.sensor_pose(), new.robot.sensor_pose()
    assert float(np.linalg.norm(a.position - b.position)) < 0.001
    assert new.time == pytest.approx(ref.time, abs=0.1)


def test_an_unclamped_robot_glides_in_the_free_run_as_physics_moves_it() -> None:
    """Unclamped (the V straight), a straight drive in the free run is kinematic too, and
    clamping after it finds the same pipe (0.5 mm) at the same place (1 mm)."""
    from primitives.steps import Clamp, Drive, Unclamp

    run = _drive_both((Unclamp(), Drive(0.3), Clamp(0.09)))
    ref, new = run["everywhere"], run["contact"]
    assert new.kinematic_ticks > 0 and new.physics_ticks < 0.6 * ref.physics_ticks
    a, b = ref.robot.sensor_pose(), new.robot.sensor_pose()
    assert float(np.linalg.norm(a.position - b.position)) < 0.001
    assert new.robot.clamped_diameter() == pytest.approx(ref.robot.clamped_diameter(), abs=5e-4)


def test_straightening_the_v_is_compressed_and_a_straight_v_settles_nothing() -> None:
    """Compressed (k > 1), the V straightens at ``RELEASE_COMPRESSION`` x k, the clock at the
    nominal rate; uncompressed (the reference) at the nominal rate; a V already straight
    runs no physics and takes no time."""
    from primitives.executor import CLAMP_RATE, RELEASE_COMPRESSION, UNCLAMP_SETTLE
    from primitives.sequences import Sequence
    from primitives.steps import Unclamp

    net = layouts.straight(0.09, distance=1.0)
    for k, release in ((1.0, 1.0), (1.5, RELEASE_COMPRESSION * 1.5)):
        ex = Executor.for_network(net, lidar=None, time_compression=k)
        assert ex.release_dt == pytest.approx(release * ex.control_dt)
        alpha, ticks, t0 = ex.vclamp.alpha, ex.physics_ticks, ex.time
        assert alpha > 0.0
        ex.run(Sequence("release", (Unclamp(),)))
        folding = math.ceil(alpha / (CLAMP_RATE * ex.release_dt) - 1e-9)
        settle = round(UNCLAMP_SETTLE / ex.control_dt)
        assert ex.physics_ticks - ticks == folding + settle
        assert ex.time - t0 == pytest.approx(folding * ex.release_dt + settle * ex.control_dt)
        ticks, t0 = ex.physics_ticks, ex.time
        ex.run(Sequence("release", (Unclamp(),)))
        assert (ex.physics_ticks, ex.time) == (ticks, t0)
        # a centring probe's straightening settles a straight V before folding it
        ex._unclamp(settle_straight=True)
        assert ex.physics_ticks - ticks == settle
        assert ex.time - t0 == pytest.approx(settle * ex.control_dt)


def test_each_centring_probe_settles_the_robot_before_folding_the_v() -> None:
    """Between two probes of a centring the V rests straight for the previous probe's
    straightening settle plus the next probe's own (``UNCLAMP_SETTLE`` each): the fold starts
    from a robot at rest, as in the reference (held-out network 69 jammed without it)."""
    from primitives.executor import UNCLAMP_SETTLE
    from primitives.sequences import Sequence
    from primitives.steps import Centre

    net = layouts.straight(0.09, distance=1.0)
    ex = Executor.for_network(net, lidar=None, time_compression=1.5)
    alphas: list[float] = []
    tick = ex._tick

    def logged(lag_axis: np.ndarray | None = None, clock: float | None = None) -> float:
        lag = tick(lag_axis, clock)
        alphas.append(ex.vclamp.alpha)
        return lag

    ex._tick = logged  # type: ignore[method-assign]
    ex.run(Sequence("centre", (Centre(),)))
    straight = np.asarray(alphas) == 0.0
    # the runs of straight-V ticks between two folds (the first fold starts from the clamp)
    runs, n, folded = [], 0, False
    for s in straight:
        if s:
            n += 1
            continue
        if folded and n:
            runs.append(n)
        folded, n = True, 0
    # the first run: the clamped V straightened and settled once before the first probe
    assert len(runs) >= 4
    assert min(runs[1:]) >= 2 * round(UNCLAMP_SETTLE / ex.control_dt)
