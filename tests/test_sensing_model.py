"""The fast fidelity's sensing models: calibrated per detector and LiDAR preset, loaded from the
packaged data file, applied reproducibly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from detector.options import StructureOption
from pipe_env.envs.sensing_model import (
    DETECTORS,
    THESIS_LITERATURE_MODEL,
    calibrated_models,
    error_model_for,
)
from pipe_env.lidar import PRESETS, LidarSpec


def test_every_detector_and_preset_has_a_calibrated_model() -> None:
    models = calibrated_models()
    for det in ("improved", "thesis"):
        for preset in ("ideal", "ydlidar_x4", "ls02"):
            assert f"{det}/{preset}" in models
            assert error_model_for(det, preset) is models[f"{det}/{preset}"]
            assert error_model_for(det, PRESETS[preset]) is models[f"{det}/{preset}"]
    # noisier sensors are not modelled as more accurate than the ideal one
    ideal, noisy = error_model_for("improved", "ideal"), error_model_for("improved", "ls02")
    assert noisy.distance_sigma + noisy.misclass_rate > ideal.distance_sigma + ideal.misclass_rate


def test_ground_truth_is_exact_and_unknown_sensors_fall_back() -> None:
    assert error_model_for("ground_truth", "ls02").exact
    custom = LidarSpec(name="my_sensor")
    assert error_model_for("improved", custom) is calibrated_models()["improved/ideal"]
    assert error_model_for("thesis", custom) is THESIS_LITERATURE_MODEL
    with pytest.raises(ValueError, match="detector = 'oracle': not allowed; allowed: improved"):
        error_model_for("oracle")
    assert set(DETECTORS) == {"improved", "thesis", "ground_truth"}


def test_a_model_perturbs_reproducibly_and_sorted() -> None:
    truth = [
        StructureOption("junction", 0.2, 0.1, 0.0, 0.0, 1.0),
        StructureOption("junction", 0.2, 0.08, math.pi / 2, math.pi / 2, 1.0),
    ]
    model = error_model_for("thesis", "ydlidar_x4")
    a = model.apply(truth, np.random.default_rng(3))
    b = model.apply(truth, np.random.default_rng(3))
    assert a == b
    assert a != truth


def test_gross_errors_come_at_their_rate_with_their_own_spread() -> None:
    from pipe_env.envs.sensing_model import DetectionErrorModel

    truth = [StructureOption("bend", 0.2, 0.1, 0.5, math.pi / 2, 1.0)]
    model = DetectionErrorModel(
        "mix", distance_sigma=0.001, gross_rate=0.25, gross_distance_sigma=1.0
    )
    rng = np.random.default_rng(0)
    err = np.array([model.apply(truth, rng)[0].distance - 0.2 for _ in range(4000)])
    gross = np.abs(err) > 0.01
    assert gross.mean() == pytest.approx(0.25, abs=0.03)  # |N(0, 1)| > 1 cm: 99 %
    assert np.std(err[~gross]) == pytest.approx(0.001, rel=0.1)
    with pytest.raises(ValueError, match="gross_rate"):
        DetectionErrorModel("bad", gross_rate=1.5)
