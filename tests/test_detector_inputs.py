"""Input checking of the detector: the scan's sensor description, the improved method's tuning,
the entry points' arguments and the containers' error messages; and the motion compensation
of a sweep whose believed pose changes."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from detector_scans import continuous_scan, rot_tilt

from detector import Detection, SensorInPipe, StructureOption, detect, detect_planar
from detector.fusion import StructureTracker
from detector.geometry import Pose
from detector.improved_config import DEFAULT_CONFIG, ImprovedConfig
from detector.scan import Scan
from pipe_env.lidar import PRESETS


def _scan(ranges=None, spec=None, **arrays) -> Scan:
    """A small scan of a 100 mm pipe (10 planes x 30 beams, sensor on the axis)."""
    beams = np.linspace(-1.4, 1.4, 30)
    planes = np.linspace(0.0, math.pi, 10, endpoint=False)
    if ranges is None:
        ranges = np.tile(np.minimum(0.05 / np.abs(np.sin(beams)), 2.5), (10, 1))
    p = ranges.shape[0]
    args = {
        "ranges": ranges,
        "valid": np.isfinite(ranges),
        "beam_angles": beams[: ranges.shape[1]],
        "plane_angles": planes[:p],
        "timestamps": np.arange(p, dtype=float),
        "positions": np.zeros((p, 3)),
        "rotations": np.tile(np.eye(3), (p, 1, 1)),
        "nominal_positions": np.zeros((p, 3)),
        "nominal_rotations": np.tile(np.eye(3), (p, 1, 1)),
        "spec": {} if spec is None else spec,
    }
    args.update(arrays)
    return Scan(**args)


# ------------------------------------------------------------------ the scan's sensor model
@pytest.mark.parametrize(
    "key, value",
    [
        ("noise_sigma", math.nan),
        ("angular_jitter", math.nan),
        ("noise_sigma_rel", math.nan),
        ("range_resolution", math.inf),
        ("noise_sigma", None),
        ("noise_sigma", -0.001),
        ("noise_sigma", True),
        ("bias", None),
        ("bias", math.inf),
        ("min_range", None),
        ("min_range", -0.1),
        ("max_range", math.nan),
        ("max_range", 0.0),
        ("noise_sigma", "0.002"),
    ],
)
def test_bad_sensor_numbers_are_rejected(key, value):
    # (they used to blind the detector: NaN noise made every tolerance NaN, so nothing left the
    # wall and the scan read "straight" with confidence 1; None raised a TypeError)
    with pytest.raises(ValueError, match=rf"Scan: spec\['{key}'\] = {re.escape(repr(value))}: "):
        _scan(spec={key: value})


def test_sensor_number_message_names_the_unit_and_the_range():
    with pytest.raises(ValueError) as err:
        _scan(spec={"noise_sigma": math.nan})
    assert str(err.value) == (
        "Scan: spec['noise_sigma'] = nan: not finite; allowed: a finite number >= 0 (m)"
    )


@pytest.mark.parametrize("value", [80.0, 90, -0.1, 0.0, math.nan, math.inf, "1.2", None, True])
def test_bad_max_incidence_is_rejected(value):
    # (degrees given as radians, 80, used to pass unchecked: the detector then took every
    # incidence as seen and never looked for returns beyond the grazing wall)
    with pytest.raises(
        ValueError, match=rf"Scan: spec\['max_incidence'\] = {re.escape(repr(value))}: "
    ):
        _scan(spec={"max_incidence": value})


def test_max_incidence_message_names_radians_and_the_range():
    with pytest.raises(ValueError) as err:
        _scan(spec={"max_incidence": 80})
    assert str(err.value) == (
        "Scan: spec['max_incidence'] = 80: out of range; allowed: above 0 to pi/2 (rad)"
    )
    for ok in (math.radians(80), 0.5 * math.pi, 1e-3):
        assert _scan(spec={"max_incidence": ok}).spec["max_incidence"] == ok


def test_spec_must_be_a_dictionary():
    with pytest.raises(ValueError, match=r"Scan: spec = .*: not a dict; allowed: a dict"):
        _scan(spec=["noise_sigma", 0.002])


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_sensor_preset_is_a_valid_spec(name):
    scan = _scan(spec=PRESETS[name].to_dict())
    assert "error" not in detect(scan, 0.1).diagnostics


def test_a_saved_scan_with_a_bad_spec_does_not_load(tmp_path):
    scan = _scan(spec={"noise_sigma": 0.002})
    scan.spec["noise_sigma"] = math.nan  # (changed after the checks)
    path = tmp_path / "bad.npz"
    scan.save(path)
    with pytest.raises(ValueError, match="noise_sigma"):
        Scan.load(path)


# ------------------------------------------------------------------ the improved tuning
@pytest.mark.parametrize(
    "field, value",
    [
        ("tol_floor", math.nan),
        ("tol_floor", 0.0),
        ("noise_k", -1.0),
        ("noise_k", math.inf),
        ("axis_slope", None),
        ("fit_points", 0),
        ("fit_points", 2.5),
        ("fit_points", True),
        ("axis_points", 0),
        ("min_anomaly_points", 0),
        ("min_lobe_points", -3),
        ("min_region_rows", 0),
        ("horizon", 0.0),
        ("prior_offset", 0.0),
        ("prior_tilt", math.nan),
        ("straight_on_coverage", 1.5),
        ("radius_lr_per_branch", math.inf),
        ("max_radius_correction", -0.001),
        ("far_wall_min_lean", math.nan),
    ],
)
def test_bad_tuning_is_rejected(field, value):
    # (tol_floor=NaN read every scan as straight with confidence 1; fit_points=0 divided by 0)
    with pytest.raises(ValueError, match=rf"ImprovedConfig: {field} = {value!r}: .*; allowed: "):
        ImprovedConfig(**{field: value})


def test_tuning_accepts_numpy_numbers_and_keeps_python_types():
    cfg = ImprovedConfig(fit_points=np.int64(200), tol_floor=np.float64(0.003))
    assert cfg.fit_points == 200 and type(cfg.fit_points) is int
    assert cfg.tol_floor == 0.003 and type(cfg.tol_floor) is float
    assert ImprovedConfig() == DEFAULT_CONFIG


# ------------------------------------------------------------------ entry points
def test_plane_must_be_an_integer_index():
    scan = _scan()
    for plane in (0.5, "0", None, True):
        with pytest.raises(ValueError, match=r"detect_planar: plane = .*: not an integer; allowed"):
            detect_planar(scan, 0.1, plane=plane)
    with pytest.raises(ValueError, match=r"plane = 10: out of range; allowed: an integer -10 to 9"):
        detect_planar(scan, 0.1, plane=10)
    assert detect_planar(scan, 0.1, "improved", plane=np.int64(-1)).kind == "straight"


@pytest.mark.parametrize("value", [True, np.True_])
def test_clamped_diameter_is_no_bool(value):
    with pytest.raises(ValueError, match=r"clamped_diameter = .*: not a number; allowed: 0\.01 to"):
        detect(_scan(), value)


# ------------------------------------------------------------------ containers' messages
def test_scan_array_messages_name_the_value_and_where():
    r = np.tile(np.linspace(0.2, 0.5, 30), (10, 1))
    # NaN, negative ranges and a finite range flagged invalid are no returns (REP 117)
    bad = r.copy()
    bad[3, 7] = math.nan
    bad[2, 5] = -0.25
    valid = np.ones(r.shape, dtype=bool)
    valid[4, 0] = False
    scan = _scan(bad, valid=valid)
    assert not scan.valid[3, 7] and not scan.valid[2, 5] and not scan.valid[4, 0]
    assert np.isinf(scan.ranges[[3, 2, 4], [7, 5, 0]]).all()
    assert scan.n_valid == r.size - 3
    assert scan.no_returns == {
        "flagged": 1,
        "nan": 1,
        "inf": 0,
        "zero": 0,
        "below_min_range": 1,
        "above_max_range": 0,
    }
    pos = np.zeros((10, 3))
    pos[6, 2] = math.inf
    with pytest.raises(
        ValueError, match=r"Scan: positions\[6, 2\] = inf: not finite; allowed: finite numbers"
    ):
        _scan(r, positions=pos)


def test_rotation_message_reports_orthogonality_and_determinant():
    with pytest.raises(
        ValueError, match=r"SensorInPipe: rotation = .*max \|R\^T R - I\| = 0\.21, det R = 1\.1"
    ):
        SensorInPipe(np.zeros(3), np.diag([1.0, 1.0, 1.1]))
    with pytest.raises(ValueError, match=r"max \|R\^T R - I\| = 0, det R = -1\)"):
        SensorInPipe(np.zeros(3), np.diag([1.0, 1.0, -1.0]))


def test_detection_names_the_bad_option():
    ok = StructureOption("bend", 0.2, 0.1, 0.0, 1.0)
    with pytest.raises(ValueError, match="got dict at index 1"):
        Detection("bend", [ok, ok.to_dict()], 1.0)


def test_tracker_rotation_message_gives_the_shape():
    with pytest.raises(ValueError, match=r"sensor_rotation must be .*got shape \(2, 2\)"):
        StructureTracker().update(Detection.straight(), np.zeros(3), np.eye(2))


def test_structure_option_takes_numpy_numbers_but_no_bools():
    o = StructureOption("bend", np.float32(0.25), np.float64(0.1), np.int64(1), np.float32(0.5))
    assert (o.distance, o.diameter, o.direction) == (0.25, 0.1, 1.0)
    assert all(type(v) is float for v in (o.distance, o.diameter, o.direction, o.angle))
    with pytest.raises(ValueError, match=r"StructureOption\.angle must be .*not a bool.*True"):
        StructureOption("bend", 0.2, 0.1, 0.0, True)


# ------------------------------------------------------------------ motion compensation
@pytest.mark.parametrize("yaw", [math.radians(3.0), math.radians(6.0)])
def test_sweep_yawing_in_place_is_compensated(yaw):
    # the robot turns on the spot during a continuous sweep: its believed orientation changes
    # with its position fixed, and the planes must still be brought into one frame (a straight
    # pipe read as a junction when only a changing position switched the compensation on)
    scan, _ = continuous_scan(
        "straight",
        lambda s: Pose(np.array([0.1, 0.0, 0.0]), rot_tilt(yaw * (s - 1.0), 0.0)),
        diameter=0.1,
    )
    assert np.ptp(scan.nominal_positions, axis=0).max() == 0.0
    det = detect(scan, 0.1)
    assert det.kind == "straight", det.describe()


@pytest.mark.parametrize(("lo", "hi"), [(85.0, 50.0), (60.0, 60.0)])
def test_improved_config_rejects_an_empty_outlet_band(lo: float, hi: float) -> None:
    """The outlet's percentile band must not be empty (it would switch the check off)."""
    with pytest.raises(ValueError, match=r"ImprovedConfig: outlet_from = .*outlet_until"):
        ImprovedConfig(outlet_from=lo, outlet_until=hi)
    assert ImprovedConfig(outlet_from=10.0, outlet_until=90.0).outlet_until == 90.0
