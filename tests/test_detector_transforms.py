"""Point transforms: polar to Cartesian, thesis eq. 2.2 and sensor-pose compensation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from detector.transforms import (
    SensorInPipe,
    option_direction,
    polar_to_cartesian,
    sensor_offset_radius,
)


def test_polar_to_cartesian():
    f, lat = polar_to_cartesian([1.0, 2.0], [0.0, math.pi / 2])
    assert np.allclose(f, [1.0, 0.0], atol=1e-12)
    assert np.allclose(lat, [0.0, 2.0])


def test_eq_2_2_matches_the_full_transform():
    rng = np.random.default_rng(0)
    lateral = rng.uniform(-0.06, 0.06, 50)
    alpha = rng.uniform(0, math.pi, 50)
    oy, oz = 0.01, -0.004
    r = sensor_offset_radius(lateral, alpha, oy, oz)
    pose = SensorInPipe(np.array([0.0, oy, oz]), np.eye(3))
    pts = np.stack([np.zeros(50), lateral * np.cos(alpha), lateral * np.sin(alpha)], axis=1)
    p = pose.to_pipe(pts)
    assert np.allclose(r, np.hypot(p[:, 1], p[:, 2]))
    # thesis form: offset x_P along one axis only
    assert np.allclose(
        sensor_offset_radius(lateral, alpha, oy),
        np.sqrt((lateral * np.sin(alpha)) ** 2 + (oy + lateral * np.cos(alpha)) ** 2),
    )


def test_sensor_in_pipe_round_trip_and_coercion():
    pose = SensorInPipe.from_offset_tilt(0.01, -0.02, math.radians(3), math.radians(-2))
    pts = np.random.default_rng(1).normal(size=(10, 3))
    assert np.allclose(pose.to_sensor(pose.to_pipe(pts)), pts)
    same = SensorInPipe.coerce((pose.position, pose.rotation))
    assert np.allclose(same.rotation, pose.rotation)
    assert SensorInPipe.coerce(None).is_identity
    with pytest.raises(ValueError, match="rotation"):
        SensorInPipe(np.zeros(3), np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="sensor_in_pipe"):
        SensorInPipe.coerce(42)


def test_option_direction_in_sensor_frame():
    ident = SensorInPipe.identity()
    angle, direction = option_direction([0.0, 0.0, 1.0], ident)
    assert angle == pytest.approx(math.pi / 2) and direction == pytest.approx(math.pi / 2)
    angle, direction = option_direction([1.0, 0.0, 0.0], ident)
    assert angle == 0.0 and direction == 0.0
    # sensor rolled by +90 deg about x: the pipe's up is the sensor's left... -> direction 0
    c, s = 0.0, 1.0
    rolled = SensorInPipe(np.zeros(3), np.array([[1, 0, 0], [0, c, -s], [0, s, c]], float))
    angle, direction = option_direction([0.0, 0.0, 1.0], rolled)
    assert direction == pytest.approx(0.0, abs=1e-12)
    assert option_direction([0.0, 0.0, 0.0], ident) == (0.0, 0.0)
