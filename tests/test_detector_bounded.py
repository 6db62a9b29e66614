"""Bounded work on any finite input: the scan's own checks (REP 117 no returns, proper rotations,
angles, range limits), the clamped diameter's plausibility, and the detector's memory on scans
with far returns."""

from __future__ import annotations

import dataclasses
import math
import tracemalloc

import numpy as np
import pytest
from detector_scans import scan_layout
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from detector import detect
from detector.pipe_cloud import partial_percentile, radius_mode
from detector.scan import MAX_RANGE_LIMIT, Scan

#: A detector step may use this much memory per scan (tracemalloc peak), bytes.
PEAK_LIMIT = 16e6


def _args(ranges: np.ndarray, **changes) -> dict:
    p, b = ranges.shape
    args = {
        "ranges": ranges,
        "valid": np.isfinite(ranges),
        "beam_angles": np.linspace(-1.4, 1.4, b),
        "plane_angles": np.linspace(0.0, math.pi, p, endpoint=False),
        "timestamps": np.arange(p, dtype=float),
        "positions": np.zeros((p, 3)),
        "rotations": np.tile(np.eye(3), (p, 1, 1)),
        "nominal_positions": np.zeros((p, 3)),
        "nominal_rotations": np.tile(np.eye(3), (p, 1, 1)),
        "spec": {"min_range": 0.1, "max_range": 2.0},
    }
    args.update(changes)
    return args


def test_returns_outside_the_spec_limits_are_no_returns():
    r = np.full((4, 6), 0.5)
    r[0, 0], r[1, 1], r[2, 2] = 2.5, 0.05, 1e8  # beyond max_range, below min_range, far
    scan = Scan(**_args(r))
    assert scan.n_valid == r.size - 3
    assert np.isinf(scan.ranges[[0, 1, 2], [0, 1, 2]]).all()
    assert scan.no_returns["above_max_range"] == 2
    assert scan.no_returns["below_min_range"] == 1
    # without a spec limit, returns beyond a kilometre are none either
    r[3, 3] = 1e300
    scan = Scan(**_args(r, spec={}))
    assert not scan.valid[3, 3] and not scan.valid[2, 2] and scan.valid[0, 0]
    assert scan.ranges[scan.valid].max() < MAX_RANGE_LIMIT


@pytest.mark.parametrize("value", [0.0, math.nan, -math.inf])
def test_zero_nan_and_minus_inf_are_no_returns(value):
    r = np.full((4, 6), 0.5)
    r[1, 2] = value
    scan = Scan(**_args(r, valid=np.ones(r.shape, dtype=bool)))
    assert not scan.valid[1, 2] and scan.ranges[1, 2] == math.inf
    assert scan.n_valid == r.size - 1
    assert sum(scan.no_returns.values()) == 1


def test_zero_no_returns_detect_as_inf():
    # many LiDAR SDKs write 0.0 for "no return"; it used to read as a return at the sensor
    scan, _, d = scan_layout("closure", 0.4, sensor="ydlidar_x4", seed=1)
    zeros = np.where(scan.valid, scan.ranges, 0.0)
    as_zero = dataclasses.replace(scan, ranges=zeros, valid=np.ones(zeros.shape, dtype=bool))
    assert as_zero.no_returns["zero"] == zeros.size - scan.n_valid > 0
    for method in ("improved", "thesis"):
        assert _same(detect(as_zero, d, method), detect(scan, d, method))


def _same(a, b) -> bool:
    """The same detection (diagnostics hold timings)."""
    return (a.kind, a.options, a.confidence) == (b.kind, b.options, b.confidence)


def test_rotations_must_be_rotations():
    r = np.full((3, 5), 0.5)
    rot = np.tile(np.eye(3), (3, 1, 1))
    rot[1] = np.diag([1.0, 1.0, 1.1])
    with pytest.raises(ValueError, match=r"Scan: rotations\[1\] = .*not a rotation .*det R = 1\.1"):
        Scan(**_args(r, rotations=rot))
    rot[1] = np.diag([1.0, 1.0, -1.0])  # a reflection
    with pytest.raises(ValueError, match=r"Scan: nominal_rotations\[1\] = .*det R = -1"):
        Scan(**_args(r, nominal_rotations=rot))
    rot[1] = np.eye(3) + 1e-9  # within the tolerance
    assert Scan(**_args(r, rotations=rot)).n_valid == r.size


def test_angles_in_range_and_limits_ordered():
    r = np.full((3, 5), 0.5)
    with pytest.raises(
        ValueError, match=r"Scan: plane_angles\[1\] = 100\.0: out of range; allowed: angles in"
    ):
        Scan(**_args(r, plane_angles=np.array([0.0, 100.0, 0.2])))
    with pytest.raises(ValueError, match=r"Scan: beam_angles\[1\] = nan: not finite"):
        Scan(**_args(r, beam_angles=np.array([0.0, math.nan, 0.1, 0.2, 0.3])))
    with pytest.raises(ValueError, match=r"Scan: spec\['min_range'\] = 2\.0: not below max_range"):
        Scan(**_args(r, spec={"min_range": 2.0, "max_range": 1.0}))


@pytest.mark.parametrize(
    "spec, diameter, allowed",
    [
        ({}, 0.005, r"0\.01 to 2 \(m\)"),
        ({"max_range": 0.3}, 0.8, r"0\.01 to 0\.6 \(m; the sensor's max_range is 0\.3 m\)"),
        ({}, 1e300, r"0\.01 to 2 \(m\)"),
    ],
)
def test_implausible_clamped_diameter_is_an_error(spec, diameter, allowed):
    scan = Scan(**_args(np.full((3, 5), 0.2), spec=spec))
    with pytest.raises(
        ValueError, match=rf"clamped_diameter = .*: out of range; allowed: {allowed}"
    ):
        detect(scan, diameter)


def _dense_mode(r: np.ndarray) -> float:
    """The radius mode as it was: every 1 mm bin from the smallest radius to the largest."""
    bins = np.floor(r / 0.001).astype(np.int64)
    lo = int(bins.min())
    smooth = np.convolve(np.bincount(bins - lo), np.ones(3), mode="same")
    peak = (int(np.argmax(smooth)) + lo + 0.5) * 0.001
    near = np.abs(r - peak) <= 0.002
    return float(partial_percentile(r[near], 50.0)) if near.any() else float(peak)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(0.0, 0.2, allow_nan=False), min_size=1, max_size=80),
    st.sampled_from([None, 3, 4]),
)
def test_radius_mode_is_the_dense_histograms(radii, decimals):
    r = np.array(radii)
    if decimals is not None:
        r = np.round(r, decimals)  # (ties between bins)
    assert radius_mode(r) == _dense_mode(r)


def test_radius_mode_memory_does_not_grow_with_the_span():
    # a return 10 km out used to allocate a 1 mm histogram across the whole span (80 MB here;
    # 30-44 GiB for the ranges x 1e8 the fuzzing found)
    r = np.r_[np.full(200, 0.05), 1e4]
    tracemalloc.start()
    try:
        mode = radius_mode(r)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert abs(mode - 0.05) < 1e-3
    assert peak < 1e6, peak


@pytest.mark.parametrize("method", ["improved", "thesis"])
def test_a_closure_at_1e300_m_is_no_certain_closure(method):
    scan, _, d = scan_layout("closure", 0.4)
    far = dataclasses.replace(scan, ranges=scan.ranges * 1e300 / 0.4, spec={})
    det = detect(far, d, method)
    assert not (det.kind == "closure" and det.confidence >= 1.0), det.describe()
    assert all(o.distance <= MAX_RANGE_LIMIT for o in det.options)


_LAYOUTS = ["closure", "t_junction", "reducer", "mitre_bend"]


@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(
    layout=st.sampled_from(_LAYOUTS),
    method=st.sampled_from(["improved", "thesis"]),
    scale=st.floats(1.0, 1e300),
    fraction=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**16),
    keep_spec=st.booleans(),
)
def test_far_returns_take_bounded_memory(layout, method, scale, fraction, seed, keep_spec):
    scan, _, d = scan_layout(layout, 0.4)
    rng = np.random.default_rng(seed)
    pick = rng.random(scan.ranges.shape) < fraction
    ranges = np.where(pick & scan.valid, scan.ranges * scale, scan.ranges)
    far = dataclasses.replace(scan, ranges=ranges, spec=scan.spec if keep_spec else {})
    tracemalloc.start()
    try:
        det = detect(far, d, method)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < PEAK_LIMIT, (layout, method, scale, fraction, peak)
    assert 0.0 <= det.confidence <= 1.0
    assert all(o.distance <= MAX_RANGE_LIMIT for o in det.options)


def test_thesis_method_examines_a_bounded_number_of_openings():
    # scattered far returns made hundreds of outlier regions, each dilated over the whole
    # grid and fitted with an ellipse: seconds per sweep
    from detector.spatial import MAX_REGIONS

    scan, _, d = scan_layout("t_junction", 0.4)
    pick = (np.random.default_rng(0).random(scan.ranges.shape) < 0.2) & scan.valid
    far = dataclasses.replace(scan, ranges=np.where(pick, scan.ranges * 100.0, scan.ranges))
    det = detect(dataclasses.replace(far, spec={}), d, "thesis")
    assert det.diagnostics["n_outlines"] <= MAX_REGIONS
