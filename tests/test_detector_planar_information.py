"""The planar-information benchmark's core (benchmarks/planar_information.py) on one case."""

from __future__ import annotations

import math

import numpy as np

from benchmarks import planar_information as pi
from pipe_env.lidar import get_preset


def test_identical_profiles_are_not_separated_and_a_shift_is():
    spec = get_preset("ydlidar_x4")
    r = np.linspace(0.2, 0.4, 50)
    v = np.ones(50, dtype=bool)
    assert pi.separation(r, v, r, v, spec) == (0.0, 0.0, 0)
    d_prime, peak, n3 = pi.separation(r, v, r + 0.01, v, spec)
    # 1 cm against 1 % of 0.2-0.4 m (2-4 mm) on each of 50 beams
    assert 15.0 < d_prime < 40.0 and 2.0 < peak < 5.5 and 0 < n3 < 50
    lost = v.copy()
    lost[0] = False
    assert pi.separation(r, v, r, lost, spec)[0] == pi.LOST_BEAM_SIGMA


def test_mitre_60mm_core_measures_the_method_and_the_scan():
    case = pi.CASES[0]  # the 60 mm mitre, ideal sensor
    closure = [("closure at 0.430 m", "closure", {"diameter": 0.06, "distance": 0.43})]
    bend = [("bend 90 left", "mitre_bend", {**case.params, "direction": 0.0})]
    rows = pi.measure_case(case, draws=2, distances=[0.4, 0.1], alternatives=closure + bend)
    far, near = rows
    assert near.correct == 1.0 and near.wrong_kind == ""
    # the structure the method reads at 40 cm (a closure at the bend's far wall) differs from
    # the bend's returns by far more than the quantisation noise: the information is there
    assert far.alternative.startswith("closure") and far.d_prime > 4.0
    assert 0.0 <= far.best_error < 0.03 and math.isinf(far.d_moved) and far.n_beams >= 1
    assert pi.pass_from(rows) == (0.1 if far.correct < pi.PASS_SHARE else 0.4)
    assert "| mitre 90 deg, 60 mm, ideal | 0.40 |" in pi.table(rows)
