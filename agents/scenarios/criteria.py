"""The pass/fail criteria of a scenario, as a table: one :class:`Criterion` per criterion.

Each entry says what a scenario file may give for it (``kind``: true/false, a count, a number,
a run id), how the run's metrics measure it (``measure``), how the measurement is judged
against the file's threshold (``judge``), what a report shows (``show``) and the message of a
failure. :data:`CRITERIA` holds the plain criteria in the order they are evaluated and
reported; :data:`DETECTION_ERROR_CRITERIA` the fields of ``max_detection_error`` (limits in
m, and degrees for the angles; the metrics hold m and rad). The schema checks a file's
``criteria`` with :func:`check_criteria`; :func:`evaluate` judges a run.

Metrics (see :mod:`agents.scenarios.running`) are in SI units: ``sim_time_s`` in s,
``max_detection_error`` in m and rad.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from detector.validation import check_bool, check_int, check_number, fail

__all__ = [
    "CRITERIA",
    "CRITERION_KEYS",
    "DETECTION_ERROR_CRITERIA",
    "Criterion",
    "CriterionResult",
    "check_criteria",
    "evaluate",
]


@dataclass
class CriterionResult:
    """One criterion judged on one run: its name, verdict, the measured value (as shown in
    reports), the file's threshold and a one-line message."""

    criterion: str
    passed: bool
    measured: Any
    threshold: Any
    message: str


def _same(value: Any) -> Any:
    return value


@dataclass(frozen=True)
class Criterion:
    """One row of the criteria table."""

    #: the key in the file (``max_jams``; ``max_detection_error.angle_deg``)
    name: str
    #: what the file gives: ``bool``, ``int`` (>= 0), ``float`` (>= 0) or ``str``
    kind: type
    #: the measured value from the run's metrics and the threshold (SI units)
    measure: Callable[[Mapping[str, Any], Any], Any]
    #: whether the measured value meets the threshold
    judge: Callable[[Any, Any], bool]
    #: why a failing run fails
    message: str
    #: the measured value as reports show it (default: as measured)
    show: Callable[[Any], Any] = _same
    #: the message when nothing was measured (``None``: :attr:`message`)
    unmeasured: str | None = None

    def check(self, value: Any, where: str, field: str | None = None) -> None:
        """Raise an :class:`~detector.validation.ArgumentError` if ``value`` is not a valid
        threshold for this criterion (``field``: its path in the file)."""
        field = field or f"criteria.{self.name}"
        if self.kind is bool:
            check_bool(field, value, where=where)
        elif self.kind is int:
            check_int(field, value, low=0, where=where)
        elif self.kind is float:
            check_number(field, value, low=0.0, where=where)
        elif not isinstance(value, str):
            raise fail(field, value, "a run id (a string)", "not a string", where)

    def result(self, metrics: Mapping[str, Any], threshold: Any) -> CriterionResult:
        """This criterion judged on ``metrics`` against ``threshold``."""
        raw = self.measure(metrics, threshold)
        ok = bool(self.judge(raw, threshold))
        shown = self.show(raw)
        why = self.unmeasured if raw is None and self.unmeasured else self.message
        text = f"{self.name}: measured {shown}, threshold {threshold}" + ("" if ok else f" ({why})")
        return CriterionResult(self.name, ok, shown, threshold, text)


def _metric(key: str, default: Any = None) -> Callable[[Mapping[str, Any], Any], Any]:
    return lambda metrics, _threshold: metrics.get(key, default)


def _at_most(measured: Any, threshold: Any) -> bool:
    return bool((measured or 0) <= threshold)


def _at_least(measured: Any, threshold: Any) -> bool:
    return measured is not None and bool(measured >= threshold)


def _at_least_count(measured: Any, threshold: Any) -> bool:
    return bool((measured or 0) >= threshold)


def _reached(metrics: Mapping[str, Any], run: Any) -> str:
    return "reached" if run in metrics.get("runs_visited", []) else "not reached"


#: The plain criteria, in the order they are evaluated and reported.
CRITERIA: dict[str, Criterion] = {
    c.name: c
    for c in (
        Criterion(
            "success",
            bool,
            _metric("is_success"),
            lambda measured, expected: measured == expected,
            "the episode outcome differs",
        ),
        Criterion("max_jams", int, _metric("jams"), _at_most, "too many jams"),
        Criterion("max_decisions", int, _metric("decisions"), _at_most, "too many decisions"),
        Criterion("max_sim_time", float, _metric("sim_time_s"), _at_most, "too slow"),
        Criterion("min_back_outs", int, _metric("back_outs"), _at_least_count, "did not back out"),
        Criterion(
            "min_coverage",
            float,
            lambda metrics, _threshold: metrics.get("coverage") or 0.0,
            _at_least,
            "too little",
        ),
        Criterion(
            "min_classification",
            float,
            _metric("classification"),
            _at_least,
            "structures misclassified",
        ),
        Criterion(
            "must_not_reach",
            str,
            _reached,
            lambda measured, _run: measured == "not reached",
            "the robot entered a pipe it must not",
        ),
    )
}


def _detection_error(field: str, scale: float) -> Criterion:
    """The ``max_detection_error.<field>`` criterion: the largest error of the options'
    ``field`` (metrics in m or rad; ``scale`` converts the file's unit to them)."""
    key = field.removesuffix("_deg")
    return Criterion(
        f"max_detection_error.{field}",
        float,
        lambda metrics, _threshold: metrics.get("max_detection_error", {}).get(key),
        lambda measured, limit: measured is not None and measured <= limit * scale,
        "detection error too large",
        show=lambda measured: None if measured is None else round(measured / scale, 4),
        unmeasured="no detection was measured",
    )


#: The fields of ``max_detection_error``: limits in m (distance, diameter) and degrees.
DETECTION_ERROR_CRITERIA: dict[str, Criterion] = {
    field: _detection_error(field, scale)
    for field, scale in (
        ("distance", 1.0),
        ("diameter", 1.0),
        ("angle_deg", math.pi / 180),
        ("direction_deg", math.pi / 180),
    )
}
#: Every key a file's ``criteria`` may hold.
CRITERION_KEYS: tuple[str, ...] = (*CRITERIA, "max_detection_error")


def check_criteria(criteria: Any, where: str) -> None:
    """Raise an :class:`~detector.validation.ArgumentError` (field ``criteria.<key>``) for the
    first invalid entry of a file's ``criteria`` mapping."""
    allowed = ", ".join(sorted(CRITERION_KEYS))
    if not isinstance(criteria, dict):
        raise fail("criteria", criteria, f"a mapping of {allowed}", "not a mapping", where)
    for key, value in criteria.items():
        if key in CRITERIA:
            CRITERIA[key].check(value, where)
        elif key == "max_detection_error":
            _check_detection_limits(value, where)
        else:
            raise fail(f"criteria.{key}", value, allowed, "unknown criterion", where)


def _check_detection_limits(limits: Any, where: str) -> None:
    allowed = ", ".join(sorted(DETECTION_ERROR_CRITERIA))
    if not isinstance(limits, dict):
        raise fail(
            "criteria.max_detection_error",
            limits,
            f"a mapping of {allowed} to limits >= 0 (m, deg)",
            "not a mapping",
            where,
        )
    for field, limit in limits.items():
        name = f"criteria.max_detection_error.{field}"
        if field not in DETECTION_ERROR_CRITERIA:
            raise fail(name, limit, allowed, "unknown field", where)
        DETECTION_ERROR_CRITERIA[field].check(limit, where, name)


def evaluate(criteria: Mapping[str, Any], metrics: Mapping[str, Any]) -> list[CriterionResult]:
    """Judge each criterion of a (validated) ``criteria`` mapping on a run's ``metrics``: the
    plain criteria in table order, then the detection-error limits in the file's order."""
    out = [c.result(metrics, criteria[name]) for name, c in CRITERIA.items() if name in criteria]
    for field, limit in criteria.get("max_detection_error", {}).items():
        out.append(DETECTION_ERROR_CRITERIA[field].result(metrics, limit))
    return out
