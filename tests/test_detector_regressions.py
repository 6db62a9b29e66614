"""Regressions of the improved detector: failure modes found in the accuracy study.

The corpus is data: ``tests/data/detector_regressions.yaml`` holds one case per failure mode
(layout, parameters, sensor, seed, expected kind and ways, tolerances, and why), each a cheap
scan of a canonical layout read by :func:`test_regression_case`. The few checks data cannot
express stay below as ordinary tests, grouped by concern: the robust fit, the fast paths, the
minimum range, and the bounds of what a scan shows.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from detector_scans import match, rot_tilt, scan_layout, wrap

from detector import Detection, detect
from detector.geometry import Pose
from detector.robust import robust_gauss_newton

CORPUS = Path(__file__).parent / "data" / "detector_regressions.yaml"
#: Keys a case may carry, and keys its ``expect`` may carry.
CASE_KEYS = {
    "id",
    "why",
    "layout",
    "distance",
    "sensor",
    "seed",
    "params",
    "misalignment",
    "clamp_error",
    "expect",
}
EXPECT_KEYS = {"kind", "ways", "same_kind", "within", "diagnostics"}
WITHIN_KEYS = {"distance", "diameter", "bend_radius", "angle_deg", "direction_deg"}
DIAGNOSTIC_OPS = {"eq", "ne", "lt", "gt", "truthy", "present", "default"}


def _radians(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` with each ``*_deg`` key (deg) replaced by the key without it, in radians."""
    out = {}
    for key, value in values.items():
        if key.endswith("_deg"):
            out[key[: -len("_deg")]] = math.radians(value)
        else:
            out[key] = value
    return out


def load_corpus(path: Path = CORPUS) -> list[dict[str, Any]]:
    """The regression cases of ``path``, checked for unknown keys and unique ids."""
    cases = yaml.safe_load(path.read_text())
    ids = [c["id"] for c in cases]
    assert len(ids) == len(set(ids)), "duplicate case ids"
    for c in cases:
        assert set(c) <= CASE_KEYS, (c["id"], set(c) - CASE_KEYS)
        assert set(c["expect"]) <= EXPECT_KEYS, (c["id"], set(c["expect"]) - EXPECT_KEYS)
        assert set(c["expect"].get("within", {})) <= WITHIN_KEYS, c["id"]
        for check in c["expect"].get("diagnostics", {}).values():
            assert set(check) <= DIAGNOSTIC_OPS, (c["id"], check)
    return cases


def _misalignment(spec: dict[str, Any] | None) -> Pose | None:
    """The sensor's pose in the body from a case's ``misalignment`` (position m, yaw and pitch
    rad), ``None`` when the case has none."""
    if spec is None:
        return None
    spec = _radians(spec)
    rotation = (
        rot_tilt(spec.get("yaw", 0.0), spec.get("pitch", 0.0))
        if "yaw" in spec or "pitch" in spec
        else np.eye(3)
    )
    return Pose(np.array(spec["position"], dtype=float), rotation)


def _check_diagnostic(det: Detection, name: str, check: dict[str, Any]) -> None:
    """One ``expect.diagnostics`` entry of a case against the detection's diagnostics."""
    present = name in det.diagnostics
    if "present" in check:
        assert present == check["present"], (name, det.describe())
    if not present and "default" not in check and set(check) - {"present", "ne"}:
        pytest.fail(f"diagnostic {name!r} missing: {det.describe()}")
    value = det.diagnostics.get(name, check.get("default"))
    if "eq" in check:
        assert value == check["eq"], (name, value, det.describe())
    if "ne" in check:
        assert value != check["ne"], (name, value, det.describe())
    if "lt" in check:
        assert value < check["lt"], (name, value, det.describe())
    if "gt" in check:
        assert value > check["gt"], (name, value, det.describe())
    if "truthy" in check:
        assert bool(value) == check["truthy"], (name, value, det.describe())


def check_expectations(det: Detection, truth: list, expect: dict[str, Any]) -> None:
    """The detection ``det`` of a scan whose true options are ``truth`` meets ``expect``."""
    if "kind" in expect:
        assert det.kind == expect["kind"], det.describe()
    ways = expect.get("ways")
    if ways is not None:
        n = len(truth) if ways == "truth" else ways
        assert len(det.options) == n, det.describe()
    within = expect.get("within")
    if within or expect.get("same_kind"):
        pairs = match(det.options, truth)
        assert pairs, det.describe()
        for o, t in pairs:
            if expect.get("same_kind"):
                assert o.kind == t.kind, det.describe()
            for key in ("distance", "diameter", "bend_radius"):
                if key in (within or {}):
                    assert abs(getattr(o, key) - getattr(t, key)) < within[key], (
                        key,
                        det.describe(),
                    )
            if "angle_deg" in (within or {}):
                assert abs(o.angle - t.angle) < math.radians(within["angle_deg"]), det.describe()
            if "direction_deg" in (within or {}):
                off = abs(wrap(o.direction - t.direction))
                assert off < math.radians(within["direction_deg"]), det.describe()
    for name, check in expect.get("diagnostics", {}).items():
        _check_diagnostic(det, name, check)


CASES = load_corpus()


@pytest.mark.parametrize("case", CASES, ids=[c["id"] for c in CASES])
def test_regression_case(case: dict[str, Any]) -> None:
    scan, truth, d = scan_layout(
        case["layout"],
        case["distance"],
        sensor=case.get("sensor", "ideal"),
        seed=case.get("seed", 0),
        misalignment=_misalignment(case.get("misalignment")),
        **_radians(case.get("params", {})),
    )
    check_expectations(detect(scan, d + case.get("clamp_error", 0.0)), truth, case["expect"])


def test_corpus_checks_can_fail() -> None:
    # the checks of a case reject a detection they do not describe
    scan, truth, d = scan_layout("closure", 0.3, diameter=0.1)
    det = detect(scan, d)
    check_expectations(det, truth, {"kind": "closure", "ways": 1, "within": {"distance": 0.005}})
    for wrong in (
        {"kind": "bend"},
        {"ways": 2},
        {"within": {"distance": 1e-9}},
        {"diagnostics": {"no_such_entry": {"lt": 1.0}}},
        {"diagnostics": {"axis_first_pass": {"truthy": True}}},
    ):
        with pytest.raises((AssertionError, pytest.fail.Exception)):
            check_expectations(det, truth, wrong)


# --- the robust fit --------------------------------------------------------------------------


def test_pinned_parameters_stay_put_and_the_fit_converges():
    rng = np.random.default_rng(0)
    x = np.linspace(0.0, 1.0, 200)
    y = 0.3 + 2.0 * x + rng.normal(0.0, 0.01, x.size)
    evals = []

    def resjac(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        evals.append(1)
        jac = np.stack([-np.ones_like(x), -x, -(x**2)], axis=1)
        return y - (p[0] + p[1] * x + p[2] * x**2), jac

    lower = np.array([-10.0, -10.0, 0.0])
    upper = np.array([10.0, 10.0, 0.0])  # the quadratic term is pinned at 0
    p, res, w = robust_gauss_newton(
        None,
        np.array([0.0, 0.0, 0.0]),
        np.full(3, 1e-6),
        c=5.0,
        iterations=20,
        lower=lower,
        upper=upper,
        c_final=0.05,
        step_tol=1e-9,
        anneal=3,
        cost_tol=1e-6,
        resjac=resjac,
    )
    assert p[2] == 0.0
    assert abs(p[0] - 0.3) < 0.01 and abs(p[1] - 2.0) < 0.02
    assert len(evals) < 15  # converged, not stopped by the iteration limit
    assert w.min() > 0.0


# --- fast paths ------------------------------------------------------------------------------


def test_straight_pipe_takes_the_early_exit():
    # the nominal pose explains every return: nothing is refined
    scan, _, d = scan_layout("straight", 0.0, diameter=0.1)
    det = detect(scan, d)
    assert det.kind == "straight"
    assert det.diagnostics["axis_pass"] == 0 and det.diagnostics["n_anomaly"] == 0
    assert det.diagnostics["n_wall"] > 1000
    # an offset sensor: the returns leave the wall tolerance until the axis is refined
    offset = Pose(np.array([0.0, 0.01, 0.0]), np.eye(3))
    scan, _, d = scan_layout("straight", 0.0, diameter=0.1, misalignment=offset)
    det = detect(scan, d)
    assert det.kind == "straight"
    assert det.diagnostics["axis_pass"] == 1 and det.diagnostics["n_anomaly"] == 0
    assert abs(det.diagnostics["axis_offset"][0] + 0.01) < 0.001
    closure, _, d = scan_layout("closure", 0.3, diameter=0.1)
    assert detect(closure, d).kind == "closure"


# --- the minimum range -----------------------------------------------------------------------


@pytest.mark.parametrize("diameter", [0.057, 0.125])
def test_end_wall_within_the_minimum_range_is_a_closure(diameter: float) -> None:
    # (ydlidar_x4, minimum range 12 cm) 10 cm before an end wall every beam ahead meets it or
    # the wall before it inside the minimum range: no return at all, once read as straight
    # pipe. The end wall is no farther than where the wall ahead would start to show.
    scan, truth, d = scan_layout("closure", 0.1, sensor="ydlidar_x4", diameter=diameter)
    det = detect(scan, d)
    assert det.kind == "closure", det.describe()
    reach = math.sqrt(0.12**2 - (diameter / 2) ** 2)
    assert det.options[0].distance == pytest.approx(reach)
    assert truth[0].distance <= det.options[0].distance < truth[0].distance + 0.02
    # 5 cm farther back the wall ahead shows again: the end wall is measured as usual
    scan, truth, d = scan_layout("closure", 0.15, sensor="ydlidar_x4", diameter=diameter)
    det = detect(scan, d)
    assert det.kind == "closure" and "blocked_within_min_range" not in det.diagnostics
    assert abs(det.options[0].distance - truth[0].distance) < 0.01


# --- what a scan does not show: bounds instead of values -------------------------------------


def test_long_bend_with_its_arc_end_out_of_view_gives_a_lower_bound():
    # no straight wall in view at all (the arc starts before the nearest returns): the end of
    # the arc is out of view, the angle is a lower bound, and flagged as one
    scan, truth, d = scan_layout(
        "long_bend", 0.3, diameter=0.1, angle=1.4937, direction=1.5883, radius_factor=2.9549
    )
    det = detect(scan, d)
    assert det.kind == "bend", det.describe()
    ((o, t),) = match(det.options, truth)
    assert math.radians(45.0) < o.angle <= t.angle and det.diagnostics["angle_lower_bound"]
    assert o.bend_radius > 0.2


def test_noisy_taper_with_its_narrow_pipe_unseen_is_a_reducer():
    # grazing beams lose the narrower pipe's wall under ydlidar_x4: the end wall far down it
    # once stood in for that wall (a plateau far too narrow, a taper too long, or a bend),
    # and the first returns off the wall come well past the start of a gentle taper; the
    # narrower pipe's diameter is only bounded
    scan, truth, d = scan_layout(
        "reducer", 0.3, sensor="ydlidar_x4", diameter_in=0.1, diameter_out=0.055, taper_length=0.2
    )
    det = detect(scan, d)
    assert det.kind == "reducer", det.describe()
    assert abs(det.options[0].distance - truth[0].distance) < 0.02
    assert 0.03 < det.options[0].diameter < 0.075
    assert det.diagnostics["reducer_end_wall_radius"] > 0.015
