"""The executor's per-tick targets, computed in batched passes, are bit for bit those of the
per-module helpers (``mju_mat2Quat``, ``DrivenPath.pose``, ``VClamp.leg_poses``)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from detector.geometry import rotation_about
from pipe_env import layouts
from pipe_env.robot import quat_of
from primitives.executor import Executor
from primitives.path import DrivenPath
from primitives.rotations import log_rotation, quats_into, rotation_angle, rx

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
