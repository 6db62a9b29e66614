"""PipeCloud's pose stash (radii kept per pose for a restore) and the improved detector's look
past the sensor's largest incidence (``_past_incidence``), on small synthetic clouds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from detector.improved import _past_incidence
from detector.improved_config import DEFAULT_CONFIG
from detector.pipe_cloud import STASHED_POSES, PipeCloud, _radii
from detector.transforms import SensorInPipe

R = 0.05  # the run's radius, m


def _cloud(
    sensor_v: np.ndarray, max_incidence: float = 0.5 * math.pi, angular_jitter: float = 0.0
) -> PipeCloud:
    n = sensor_v.shape[1]
    cloud = PipeCloud(
        False,
        (1, n),
        np.arange(n, dtype=np.intp),
        np.ascontiguousarray(sensor_v, dtype=float),
        np.zeros(n),
        np.zeros(n),
        SensorInPipe(),
        0.0,
        max_incidence,
        angular_jitter,
    )
    cloud.set_pose(SensorInPipe())
    return cloud


def _pose(dy: float, dz: float, yaw: float) -> SensorInPipe:
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return SensorInPipe(np.array([0.0, dy, dz]), rot)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n_poses=st.integers(1, 2 * STASHED_POSES),
    back=st.integers(0, 2 * STASHED_POSES - 1),
)
def test_a_restored_pose_has_the_radii_of_its_points(seed: int, n_poses: int, back: int) -> None:
    rng = np.random.default_rng(seed)
    cloud = _cloud(rng.normal(0.0, 0.1, (3, 40)))
    seen = []
    for _ in range(n_poses):
        pose = _pose(*rng.uniform(-0.01, 0.01, 2), rng.uniform(-0.2, 0.2))
        cloud.set_pose(pose)
        r = cloud.r_v  # (computed, so the next pose change stashes it)
        seen.append((pose, cloud.xyz_v, r.copy()))
    pose, xyz_v, r_then = seen[max(0, len(seen) - 1 - back)]
    cloud.set_pose(_pose(0.0, 0.0, 0.3))
    _ = cloud.r_v
    cloud.restore(pose, xyz_v)
    assert cloud.pose is pose and cloud.xyz_v is xyz_v
    np.testing.assert_array_equal(cloud.r_v, _radii(xyz_v))
    np.testing.assert_array_equal(cloud.r_v, r_then)


def test_restore_reuses_the_stashed_radii_of_a_recent_pose() -> None:
    cloud = _cloud(np.random.default_rng(3).normal(0.0, 0.1, (3, 30)))
    first = _pose(0.002, -0.001, 0.1)
    cloud.set_pose(first)
    xyz_v, r_v = cloud.xyz_v, cloud.r_v
    cloud.set_pose(_pose(-0.003, 0.0, -0.1))
    assert cloud.r_v is not r_v
    cloud.restore(first, xyz_v)
    assert cloud.r_v is r_v  # the stashed array, not recomputed


def _wall(x: list[float], r: float = R) -> np.ndarray:
    """Returns at axial distances ``x`` (m) on a circle of radius ``r`` about the axis, the
    sensor on the axis (its frame the pipe frame)."""
    a = np.linspace(0.0, 2.0 * math.pi, len(x), endpoint=False)
    return np.array([x, r * np.cos(a), r * np.sin(a)])


def test_past_incidence_flags_wall_returns_a_straight_wall_cannot_give() -> None:
    # incidence on a straight wall: atan(x / R); 63, 84, 84 (off the wall), 84 (behind), 87 deg
    x = [0.1, 0.5, 0.5, -0.5, 1.0]
    pts = _wall(x)
    pts[1:, 2] *= 0.06 / R  # (a return 1 cm beyond the wall: not on the wall radius)
    cloud = _cloud(pts, max_incidence=math.radians(80))
    got = _past_incidence(cloud, R, DEFAULT_CONFIG)
    assert got is not None
    assert got.tolist() == [False, True, False, False, True]


def test_past_incidence_adds_the_beam_angle_jitter_to_the_limit() -> None:
    # 80 deg plus 3 x 2 deg of jitter: 86 deg; 84 deg is within it, 87 beyond
    cloud = _cloud(
        _wall([0.5, 1.0]), max_incidence=math.radians(80), angular_jitter=math.radians(2)
    )
    assert DEFAULT_CONFIG.incidence_jitter_k == pytest.approx(3.0)
    got = _past_incidence(cloud, R, DEFAULT_CONFIG)
    assert got is not None and got.tolist() == [False, True]


@pytest.mark.parametrize("max_incidence, jitter", [(0.5 * math.pi, 0.0), (math.radians(85), 0.03)])
def test_past_incidence_is_none_when_the_sensor_returns_at_any_incidence(
    max_incidence: float, jitter: float
) -> None:
    cloud = _cloud(_wall([0.5, 1.0]), max_incidence=max_incidence, angular_jitter=jitter)
    assert _past_incidence(cloud, R, DEFAULT_CONFIG) is None


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(0, 60), n_ask=st.integers(0, 40))
def test_points_at_finds_each_cell_with_or_without_the_grid(seed: int, n: int, n_ask: int) -> None:
    """A return's point by its cell, found by bisection in the ascending cells, is the grid's
    point there (0 where the cell holds no return), before and after the grid is built; the
    axial grid alone is the point grid's first component."""
    rng = np.random.default_rng(seed)
    g, k = 4, 30
    cell = np.sort(rng.choice(g * k, size=min(n, g * k), replace=False)).astype(np.intp)
    cloud = PipeCloud(
        False,
        (g, k),
        cell,
        rng.normal(size=(3, cell.size)),
        np.zeros(cell.size),
        np.zeros(cell.size),
        SensorInPipe(),
    )
    pose = _pose(*rng.normal(scale=0.01, size=2), float(rng.normal(scale=0.1)))
    cloud.set_pose(pose)
    ask = rng.integers(0, g * k, size=n_ask).astype(np.intp)
    bisected = cloud.points_at(ask).copy()
    u_alone = cloud.u_grid.copy()
    grid = cloud.xyz.reshape(3, -1)[:, ask].T  # (builds the grid)
    np.testing.assert_array_equal(u_alone, cloud.xyz[0])
    np.testing.assert_array_equal(bisected, grid)
    np.testing.assert_array_equal(cloud.points_at(ask), grid)
    np.testing.assert_array_equal(cloud.u_grid, cloud.xyz[0])
