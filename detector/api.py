"""The detector's entry points: :func:`detect` (full sweeps) and :func:`detect_planar` (one plane).

``method="thesis"`` runs the faithful reproduction of the thesis algorithms (Algorithm 2 for
sweeps, :mod:`detector.spatial`; Algorithm 1 for planes, :mod:`detector.planar`);
``method="improved"`` (the default for sweeps) runs :mod:`detector.improved` for sweeps and
:mod:`detector.planar_improved` for planes. Both return a
:class:`~detector.detection.Detection` and never NaN.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from detector.detection import Detection
from detector.improved import detect_improved
from detector.planar import detect_planar_thesis
from detector.planar_improved import detect_planar_improved
from detector.scan import Scan, spec_value
from detector.spatial import detect_spatial_thesis
from detector.validation import check_int, fail
from detector.vocab import Method

#: Methods of :func:`detect`.
METHODS: tuple[str, ...] = (Method.THESIS.value, Method.IMPROVED.value)
#: Methods of :func:`detect_planar`.
PLANAR_METHODS: tuple[str, ...] = (Method.THESIS.value, Method.IMPROVED.value)


#: Narrowest clamped diameter the detector accepts, metres.
MIN_CLAMPED_DIAMETER = 0.01
#: Widest clamped diameter the detector accepts, metres (narrower still when the scan's
#: sensor cannot see across it: ``2 x spec max_range``).
MAX_CLAMPED_DIAMETER = 2.0


def _check(scan: Any, clamped_diameter: Any) -> float:
    """``clamped_diameter`` (m) as a float, checked against the scan's sensor; ``scan`` must
    be a :class:`Scan`."""
    if not isinstance(scan, Scan):
        raise fail("scan", scan, "a detector.scan.Scan", f"a {type(scan).__name__}")
    hi = min(MAX_CLAMPED_DIAMETER, 2.0 * spec_value(scan.spec, "max_range", math.inf))
    why = (
        f"; the sensor's max_range is {spec_value(scan.spec, 'max_range', 0.0):g} m"
        if hi < MAX_CLAMPED_DIAMETER
        else ""
    )
    allowed = f"{MIN_CLAMPED_DIAMETER:g} to {hi:g} (m{why})"
    if isinstance(clamped_diameter, (bool, np.bool_)):
        raise fail("clamped_diameter", clamped_diameter, allowed, "not a number")
    try:
        d = float(clamped_diameter)
    except (TypeError, ValueError) as exc:
        raise fail("clamped_diameter", clamped_diameter, allowed, "not a number") from exc
    if not math.isfinite(d):
        raise fail("clamped_diameter", clamped_diameter, allowed, "not finite")
    if not MIN_CLAMPED_DIAMETER <= d <= hi:
        raise fail("clamped_diameter", clamped_diameter, allowed, "out of range")
    return d


def detect(
    scan: Scan,
    clamped_diameter: float,
    method: str = "improved",
    *,
    sensor_in_pipe: Any = None,
    **options: Any,
) -> Detection:
    """The structure ahead from a full rotating-LiDAR sweep.

    Args:
        scan: the sweep.
        clamped_diameter: inner diameter of the current pipe from the clamping encoders, m.
        method: ``"improved"`` (default) or ``"thesis"``.
        sensor_in_pipe: known sensor pose in the local pipe-axis frame (a
            :class:`~detector.transforms.SensorInPipe` or a ``(position (3,), rotation (3, 3))``
            pair); ``None`` assumes the sensor centred and aligned (the improved method still
            refines the axis from the scan).
        **options: method-specific keywords (see :func:`detector.improved.detect_improved` and
            :func:`detector.spatial.detect_spatial_thesis`).
    """
    d = _check(scan, clamped_diameter)
    if method == Method.IMPROVED:
        return detect_improved(scan, d, sensor_in_pipe=sensor_in_pipe, **options)
    if method == Method.THESIS:
        return detect_spatial_thesis(scan, d, sensor_in_pipe=sensor_in_pipe, **options)
    raise ValueError(f"method must be one of {METHODS}, got {method!r}")


def detect_planar(
    scan: Scan,
    clamped_diameter: float,
    method: str = "thesis",
    *,
    plane: int = 0,
    sensor_in_pipe: Any = None,
    **options: Any,
) -> Detection:
    """The structure ahead from one scan plane: thesis Algorithm 1 (``method="thesis"``, the
    default) or the improved line-fitting method (``method="improved"``,
    :mod:`detector.planar_improved`).

    Args:
        scan: a scan; plane ``plane`` is used (a single-plane scan by default).
        clamped_diameter: inner diameter of the current pipe, m.
        method: ``"thesis"`` or ``"improved"``.
        plane: index of the plane in ``scan``.
        sensor_in_pipe: known sensor pose in the pipe frame; ``None``: centred and aligned.
    """
    d = _check(scan, clamped_diameter)
    plane = check_int(
        "plane", plane, low=-scan.n_planes, high=scan.n_planes - 1, where="detect_planar"
    )
    if method == Method.THESIS:
        return detect_planar_thesis(scan, d, plane=plane, sensor_in_pipe=sensor_in_pipe, **options)
    if method == Method.IMPROVED:
        return detect_planar_improved(
            scan, d, plane=plane, sensor_in_pipe=sensor_in_pipe, **options
        )
    raise ValueError(f"planar method must be one of {PLANAR_METHODS}, got {method!r}")
