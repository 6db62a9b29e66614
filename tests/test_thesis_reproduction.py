"""The thesis reproduction (``benchmarks/thesis_reproduction.py``): its statistics, and the
thesis method's figures for the bend (thesis table 5.2) and the reduction (table 5.1) pinned
near the thesis's, so that a change to Algorithm 2 that moves them away from the thesis fails.

The experiments run as the script runs them (the table 4.2 LiDAR, 180 deg sweeps in 2 deg
steps, 5 cm increments): 4 + 12 sweeps for the bend, 5 + 8 for the reduction, a few seconds.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "thesis_reproduction.py"
_spec = importlib.util.spec_from_file_location("thesis_reproduction", _PATH)
tr = importlib.util.module_from_spec(_spec)
sys.modules["thesis_reproduction"] = tr  # (its dataclasses look their module up)
_spec.loader.exec_module(tr)


@pytest.fixture(scope="module")
def bend() -> dict:
    return tr.table_5_2(np.random.default_rng(0))


@pytest.fixture(scope="module")
def reduction() -> dict:
    return tr.table_5_1(np.random.default_rng(0))


def test_statistics_are_the_theses() -> None:
    s = tr.stat([1.0, 2.0, 4.0], [2.0, 2.0, 2.0], 4)
    assert s.mean == pytest.approx(7 / 3)
    assert s.std == pytest.approx(np.std([1.0, 2.0, 4.0], ddof=1))  # the sample std
    assert s.avg_err == pytest.approx(1.0)  # mean |error|
    assert s.max_err == pytest.approx(2.0)
    assert (s.n, s.n_total) == (3, 4)
    assert "(3 of 4)" in s.cell("msax")


@given(
    real=st.floats(-180, 180),
    errs=st.lists(st.floats(-170, 170), min_size=2, max_size=8),
    turns=st.integers(-2, 2),
)
def test_direction_errors_wrap(real: float, errs: list[float], turns: int) -> None:
    """A direction a whole turn away is the same direction: the statistics do not change."""
    est = [real + e for e in errs]
    a = tr.stat(est, [real] * len(est), len(est), angular=True)
    b = tr.stat([x + 360.0 * turns for x in est], [real] * len(est), len(est), angular=True)
    assert a.avg_err == pytest.approx(float(np.mean(np.abs(errs))), abs=1e-6)
    assert b.avg_err == pytest.approx(a.avg_err, abs=1e-6)
    assert b.std == pytest.approx(a.std, abs=1e-6)
    assert b.max_err == pytest.approx(a.max_err, abs=1e-6)


def test_bend_table_5_2_thesis_method(bend: dict) -> None:
    """Thesis table 5.2 (45 deg bend at 136 deg, 100 mm, 30-15 cm): distance error 4.04 cm,
    angle 45.87 deg (std 1.31, error 1.2), direction error 11.35 deg; first detected about 30
    cm before the bend. Ours: distance 4.0 cm (the same offset of the opening's centre), angle
    41 deg (std 1.6, error 3.8: our asin(minor / major) rule), direction 0.1 deg."""
    est = bend["est"]
    assert est.n_total == 4
    dist = est.stat("thesis", "distance")
    assert dist.n == 4  # identified as a bend at every place, as in the thesis
    assert abs(dist.avg_err - 4.04) <= 0.5  # cm
    ang = est.stat("thesis", "angle")
    assert ang.avg_err <= 5.0 and ang.std <= 3.0  # deg (thesis: 1.2 and 1.31)
    assert abs(ang.mean - 45.87) <= 6.0
    assert est.stat("thesis", "direction").avg_err <= 11.35  # no worse than the thesis
    first = max(bend["identified"]["thesis"])
    assert 25.0 <= first <= 35.0  # cm (thesis: about 30)


def test_reduction_table_5_1_thesis_method(reduction: dict) -> None:
    """Thesis table 5.1 (45 % reduction over 20 cm, 25-5 cm before its end): distance error
    1.88 cm, diameter 5.38 cm (std 0.1, error 0.12). Ours: 2.0 cm and 5.5 cm exactly."""
    est = reduction["est"]
    assert est.n_total == 5
    dist = est.stat("thesis", "distance")
    assert dist.n == 5  # a reducer at every place
    assert abs(dist.avg_err - 1.88) <= 0.75  # cm
    assert dist.max_err <= 4.0
    dia = est.stat("thesis", "diameter")
    assert abs(dia.mean - 5.38) <= 0.2 and dia.std <= 0.2 and dia.avg_err <= 0.3  # cm
    # detected late, as the thesis explains (its 5 cm; the error of step B is ours)
    first = reduction["first_detected_cm"]["thesis"]
    assert first is not None and first <= 20.0


def test_improved_method_on_the_same_scans(bend: dict) -> None:
    """The improved method on the thesis's bend, same scans: within millimetres and a
    fraction of a degree. (Inside the reduction's taper it has no start ahead to fit: its
    figures there are reported, not pinned.)"""
    est = bend["est"]
    assert est.stat("improved", "distance").max_err <= 0.5
    assert est.stat("improved", "angle").max_err <= 1.0
    assert est.stat("improved", "direction").max_err <= 1.0


def test_thesis_ideal_lidar_is_table_4_2() -> None:
    """The reproduction's LiDAR: 0.1-200 cm, 0.1 cm resolution, 180 deg, 0.5 deg."""
    spec = tr.THESIS_IDEAL
    assert spec.min_range == pytest.approx(0.001) and spec.max_range == pytest.approx(2.0)
    assert spec.range_resolution == pytest.approx(0.001)
    assert spec.fov == pytest.approx(math.pi) and spec.beam_step == pytest.approx(math.radians(0.5))
    assert spec.is_noiseless
