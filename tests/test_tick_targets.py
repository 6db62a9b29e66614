"""The executor's per-tick work, batched or compiled, is bit for bit that of the per-module
helpers it replaced (``mju_mat2Quat``, ``DrivenPath.pose``, ``VClamp.leg_poses``,
``mj_contactForce``)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from detector.geometry import rotation_about
from pipe_env import layouts
from pipe_env.ground_truth import structures_ahead
from pipe_env.robot import quat_of
from primitives.executor import Executor, _Jam
from primitives.path import DrivenPath
from primitives.rotations import log_rotation, quats_into, rotation_angle, rx
from primitives.sequences import for_option, go_straight

_unit = st.floats(-1.0, 1.0, allow_nan=False)


def _rotation(v: tuple[float, float, float], angle: float) -> np.ndarray:
    axis = np.array(v) if np.linalg.norm(v) > 1e-3 else np.array([0.0, 0.0, 1.0])
    return rotation_about(axis, angle)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(st.tuples(_unit, _unit, _unit), st.floats(-math.pi, math.pi)),
        min_size=1,
        max_size=8,
    ),
    st.floats(0.0, 1e-6),
)
def test_batched_quaternions_are_mujocos(rots: list, noise: float) -> None:
    r = np.array([_rotation(v, a) for v, a in rots])
    r = r + noise * np.sin(np.arange(r.size)).reshape(r.shape)  # slightly off-orthonormal too
    out = np.zeros((len(r), 4))
    quats_into(r, out)
    for i in range(len(r)):
        ref = np.zeros(4)
        mujoco.mju_mat2Quat(ref, r[i].ravel())
        assert np.array_equal(out[i], ref), (r[i], out[i], ref)


def test_batched_quaternions_take_every_branch() -> None:
    r = np.array([np.eye(3), rx(math.pi), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])])
    out = np.zeros((4, 4))
    quats_into(r, out)
    assert np.array_equal(out, np.array([quat_of(m) for m in r]))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=10), st.integers(0, 2**31 - 1))
def test_batched_path_lookup_is_pose(s: list[float], seed: int) -> None:
    rng = np.random.default_rng(seed)
    path = DrivenPath()
    n = int(rng.integers(1, 40))
    hs = np.sort(rng.uniform(-2.0, 2.0, n))
    hs[rng.random(n) < 0.1] = hs[0]  # repeated odometers
    path.push_many(np.sort(hs), rng.normal(size=(n, 3)), rng.normal(size=(n, 3, 3)))
    q = np.array(s)
    pos, rot = np.zeros((len(q), 3)), np.zeros((len(q), 3, 3))
    path.poses_into(q, pos, rot)
    for i, si in enumerate(q):
        p, r = path.pose(float(si))
        assert np.array_equal(pos[i], p) and np.array_equal(rot[i], r)


def test_angle_only_is_log_rotations_angle() -> None:
    rng = np.random.default_rng(5)
    for _ in range(500):
        r = rotation_about(rng.normal(size=3), float(rng.uniform(0, math.pi)))
        r = r + rng.normal(0.0, 1e-9, (3, 3))
        assert rotation_angle(r) == log_rotation(r)[0]


def _reference_targets(ex: Executor) -> tuple[np.ndarray, np.ndarray]:
    """The targets as the executor set them module by module before batching."""
    cmd, c = ex.command, ex.config
    pos, quat = [cmd.position.copy()], [quat_of(cmd.rotation)]
    legs = ex.vclamp.leg_poses(ex.path, ex.odometer)
    for i in range(1, c.n_modules):
        if i in legs:
            p, r = legs[i]
        else:
            s_i = ex.odometer - ex._offsets[i]
            shift = ex.vclamp.shortening if ex.vclamp.behind(i) else 0.0
            p, r = ex.path.pose(s_i + shift)
        if cmd.roll != 0.0 and i < c.middle_joint:
            r = r @ rx(cmd.roll)
        off = cmd.bend_offsets.get(i)
        if off:
            r = r @ rotation_about([0.0, 0.0, 1.0], off)
        pos.append(p)
        quat.append(quat_of(r))
    return np.array(pos), np.array(quat)


def test_batched_targets_are_the_per_module_ones() -> None:
    ex = Executor.for_network(layouts.t_junction(0.09, direction=math.pi / 2), lidar=None)
    rng = np.random.default_rng(2)
    ids = ex.robot.mocap_ids
    for trial in range(400):
        ex.odometer = float(rng.uniform(-1.5, 0.5))
        ex.vclamp.alpha = float(rng.choice([0.0, rng.uniform(0.0, 1.2)]))
        ex.vclamp.side = int(rng.integers(0, 4))
        ex.command.roll = float(rng.choice([0.0, rng.uniform(-3.0, 3.0)]))
        ex.command.bend_offsets = {int(rng.integers(2, 6)): float(rng.uniform(-0.5, 0.5))}
        ex.command.rotation = rotation_about(rng.normal(size=3), float(rng.uniform(0, 3)))
        ex.command.position = rng.normal(size=3)
        ex._set_targets()
        pos, quat = _reference_targets(ex)
        assert np.array_equal(ex.data.mocap_pos[ids], pos), trial
        assert np.array_equal(ex.data.mocap_quat[ids], quat), trial


def _reference_contact_force(ex: Executor) -> float:
    """The robot's contact force as ``mj_contactForce``, contact by contact."""
    m, d, robot = ex.model, ex.data, ex.robot
    total, f6 = 0.0, np.zeros(6)
    for k in range(d.ncon):
        con = d.contact[k]
        if con.geom1 in robot.geom_ids or con.geom2 in robot.geom_ids:
            mujoco.mj_contactForce(m, d, k, f6)
            total += abs(f6[0])
    return total


@pytest.mark.parametrize("cone", [mujoco.mjtCone.mjCONE_PYRAMIDAL, mujoco.mjtCone.mjCONE_ELLIPTIC])
def test_contact_force_is_mj_contact_forces_sum(cone: int) -> None:
    ex = Executor.for_network(layouts.mitre_bend(0.06, math.pi / 2, math.pi / 2), lidar=None)
    ex.model.opt.cone = cone
    rows: list[tuple[float, float, int]] = []
    ex.on_tick = lambda t: rows.append(
        (ex.robot.contact_force(), _reference_contact_force(ex), ex.data.ncon)
    )
    ex.run(go_straight(0.05))
    option = structures_ahead(ex.world.network, ex.robot.sensor_pose(), 5.0)[0]
    ex.run(for_option(option, incoming_diameter=ex.robot.clamped_diameter()))
    assert len(rows) > 300 and max(n for _, _, n in rows) >= 2
    assert sum(1 for f, _, _ in rows if f > 0) >= 20
    assert all(f == ref for f, ref, _ in rows)


def test_a_follower_pushed_off_its_target_jams_naming_it() -> None:
    ex = Executor.for_network(layouts.straight(0.1), lidar=None)
    ex._check_tracking()  # on its targets: nothing
    ex.data.xpos[ex.robot.body_ids[3]] += [0.0, 0.0, 2.0 * ex.config.jam_tracking]
    with pytest.raises(_Jam, match="module 3 is pushed"):
        ex._check_tracking()
