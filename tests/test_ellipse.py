"""Halir-Flusser ellipse fitting: noisy synthetic ellipses and degenerate inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from detector.ellipse import Ellipse, EllipseFitFailure, fit_ellipse


def _points(cx, cy, a, b, theta, n, rng, noise=0.0, arc=2 * math.pi):
    t = rng.uniform(0.0, arc, n)
    x = a * np.cos(t)
    y = b * np.sin(t)
    c, s = math.cos(theta), math.sin(theta)
    px = cx + c * x - s * y + rng.normal(0.0, noise, n)
    py = cy + s * x + c * y + rng.normal(0.0, noise, n)
    return px, py


def _angle_diff(a: float, b: float) -> float:
    d = (a - b) % math.pi
    return min(d, math.pi - d)


@pytest.mark.parametrize(
    "cx, cy, a, b, theta",
    [
        (0.0, 0.0, 1.0, 0.5, 0.0),
        (0.3, -0.2, 0.05, 0.03, 0.7),
        (120.0, 40.0, 8.0, 2.0, -1.2),
        (0.0, 0.4, 0.07, 0.05, 1.5),
    ],
)
def test_recovers_noisy_ellipse(cx, cy, a, b, theta):
    rng = np.random.default_rng(1)
    noise = 0.005 * a
    x, y = _points(cx, cy, a, b, theta, 300, rng, noise)
    fit = fit_ellipse(x, y)
    assert isinstance(fit, Ellipse) and fit.ok
    assert np.allclose(fit.centre, [cx, cy], atol=0.02 * a)
    assert fit.semi_major == pytest.approx(a, rel=0.02)
    assert fit.semi_minor == pytest.approx(b, rel=0.03)
    assert _angle_diff(fit.orientation, theta) < math.radians(2.0)
    assert -math.pi / 2 < fit.orientation <= math.pi / 2
    assert fit.rms_residual < 3 * noise


def test_exact_circle_and_partial_arc():
    rng = np.random.default_rng(2)
    x, y = _points(0.3, 0.0, 0.05, 0.05, 0.0, 40, rng)
    fit = fit_ellipse(x, y)
    assert fit.ok and fit.axis_ratio == pytest.approx(1.0, abs=1e-6)
    # a 120 deg arc of an ellipse still gives it back without noise
    x, y = _points(1.0, 2.0, 3.0, 1.0, 0.4, 60, rng, arc=2 * math.pi / 3)
    fit = fit_ellipse(x, y)
    assert fit.ok
    assert np.allclose(fit.centre, [1.0, 2.0], atol=1e-6)
    assert fit.semi_major == pytest.approx(3.0, rel=1e-6)


@pytest.mark.parametrize(
    "x, y, reason",
    [
        ([], [], "at least"),
        ([0, 1, 2], [0, 1, 2], "at least"),
        ([0, 1, 2, 3, 4, 5], [0, 2, 4, 6, 8, 10], "collinear"),
        ([1.0] * 8, [2.0] * 8, "coincide"),
        ([np.nan] * 8, [1.0] * 8, "at least"),
        ([0, 1, 2], [0, 1], "differ"),
    ],
)
def test_degenerate_inputs_fail_clearly(x, y, reason):
    fit = fit_ellipse(x, y)
    assert isinstance(fit, EllipseFitFailure)
    assert not fit.ok
    assert reason in fit.reason


def test_hyperbola_points_fail():
    t = np.linspace(-2, 2, 30)
    fit = fit_ellipse(np.cosh(t), np.sinh(t))
    # one branch of a hyperbola: no ellipse, or at least never a non-finite one
    if fit.ok:
        assert np.all(np.isfinite(fit.centre)) and fit.semi_minor > 0
    else:
        assert fit.reason


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(-1e3, 1e3, allow_nan=False), st.floats(-1e3, 1e3, allow_nan=False)),
        min_size=0,
        max_size=40,
    )
)
def test_never_garbage(points):
    x = [p[0] for p in points]
    y = [p[1] for p in points]
    fit = fit_ellipse(x, y)
    if fit.ok:
        assert np.all(np.isfinite(fit.centre))
        assert math.isfinite(fit.semi_major) and math.isfinite(fit.semi_minor)
        assert fit.semi_major >= fit.semi_minor > 0
        assert math.isfinite(fit.orientation) and math.isfinite(fit.rms_residual)
    else:
        assert isinstance(fit.reason, str) and fit.reason
