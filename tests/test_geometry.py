"""Poses, frames and the angle conventions of docs/design.md."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from detector.geometry import (
    Pose,
    angles_from_direction,
    direction_from_angles,
    frame_from_forward,
    rotation_about,
    segment_distance,
    wrap_angle,
)

unit_floats = st.floats(-1.0, 1.0, allow_nan=False)


def test_pose_rejects_nan_and_bad_rotation() -> None:
    with pytest.raises(ValueError, match="position must be finite"):
        Pose(np.array([np.nan, 0, 0]), np.eye(3))
    with pytest.raises(ValueError, match="rotation"):
        Pose(np.zeros(3), np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        Pose(np.zeros(2), np.eye(3))


def test_direction_convention() -> None:
    # docs/design.md: 0 = left (+y), pi/2 = up (+z), pi = right, -pi/2 = down
    assert np.allclose(direction_from_angles(math.pi / 2, 0.0), [0, 1, 0], atol=1e-12)
    assert np.allclose(direction_from_angles(math.pi / 2, math.pi / 2), [0, 0, 1], atol=1e-12)
    assert np.allclose(direction_from_angles(math.pi / 2, math.pi), [0, -1, 0], atol=1e-12)
    assert np.allclose(direction_from_angles(math.pi / 2, -math.pi / 2), [0, 0, -1], atol=1e-12)


@given(st.floats(0.01, math.pi - 0.01), st.floats(-math.pi, math.pi))
def test_angles_round_trip(angle: float, direction: float) -> None:
    a, d = angles_from_direction(direction_from_angles(angle, direction))
    assert a == pytest.approx(angle, abs=1e-9)
    assert wrap_angle(d - direction) == pytest.approx(0.0, abs=1e-9)


@given(unit_floats, unit_floats, unit_floats)
def test_frame_from_forward_is_roll_zero(x: float, y: float, z: float) -> None:
    v = np.array([x, y, z])
    if np.linalg.norm(v) < 1e-3:
        return
    r = frame_from_forward(v)
    assert np.allclose(r.T @ r, np.eye(3), atol=1e-9)
    assert np.linalg.det(r) == pytest.approx(1.0)
    assert np.allclose(r[:, 0], v / np.linalg.norm(v))
    if abs(v[2]) / np.linalg.norm(v) < 0.99:
        # roll zero: the left axis is horizontal and the up axis points up
        assert abs(r[2, 1]) < 1e-9
        assert r[2, 2] > 0


def test_compose_inverse_and_points() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = Pose(rng.normal(size=3), rotation_about(rng.normal(size=3), rng.uniform(-3, 3)))
        b = Pose(rng.normal(size=3), rotation_about(rng.normal(size=3), rng.uniform(-3, 3)))
        pts = rng.normal(size=(5, 3))
        assert np.allclose(
            a.compose(b).transform_points(pts), a.transform_points(b.transform_points(pts))
        )
        assert a.compose(a.inverse()).allclose(Pose.identity())
        assert np.allclose(a.inverse_transform_points(a.transform_points(pts)), pts)


def test_rolled_and_translated() -> None:
    p = Pose.identity().rolled(math.pi / 2)
    assert np.allclose(p.left, [0, 0, 1], atol=1e-12)  # left axis rolled up
    assert np.allclose(Pose.identity().translated(0.3).position, [0.3, 0, 0])


def test_segment_distance_cases() -> None:
    o = np.zeros(3)
    x = np.array([1.0, 0, 0])
    assert segment_distance(o, x, np.array([0.5, 1, 0]), np.array([0.5, 2, 0])) == pytest.approx(
        1.0
    )
    assert segment_distance(o, x, np.array([2.0, 0, 0]), np.array([3.0, 0, 0])) == pytest.approx(
        1.0
    )
    assert segment_distance(o, x, np.array([0.5, -1, 1]), np.array([0.5, 1, 1])) == pytest.approx(
        1.0
    )
    assert segment_distance(o, o, x, x) == pytest.approx(1.0)
