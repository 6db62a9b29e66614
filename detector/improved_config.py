"""Tuning of the improved detector (:mod:`detector.improved`): one frozen dataclass shared by
its modules.

Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class ImprovedConfig:
    """Tuning of the improved detector. Lengths in metres, angles in radians.

    Attributes:
        tol_floor: smallest radial tolerance of a wall return.
        noise_k: tolerance = floor + ``noise_k`` x the return's radial noise (sensor model)
            + ``axis_slope`` x the return's distance along the axis (residual axis error).
        min_lobe_points: fewest returns beyond the wall in an opening.
        min_region_rows: fewest azimuth rows an anomaly region must span.
        min_anomaly_points: fewest non-wall returns for anything but ``straight``.
        horizon: returns farther along the axis are ignored.
        fit_points: returns used per structure fit (evenly subsampled).
        axis_points: wall returns used for the pipe-axis refinement.
        prior_offset, prior_tilt: prior standard deviation of the pipe-axis refinement.
        straight_on_coverage: fraction of the circumference on which the wall must be seen
            beyond a junction for a straight-on option.
        radius_lr_per_branch: likelihood-ratio threshold (per outgoing pipe) above which a
            free outgoing radius replaces the clamped one.
        max_radius_correction: largest change of the clamped radius that the wall returns
            may make (the encoders' error; the thesis checks the diameter to +-5 mm).
        far_wall_min_lean: a far wall seen head-on gives the way on only when its returns lie
            on average at least this many radii (of the clamped pipe) along the fitted axis
            from the axis' foot; nearer, the direction is undetermined and no turn is reported.
    """

    tol_floor: float = 0.002
    axis_slope: float = 0.002
    noise_k: float = 3.0
    min_lobe_points: int = 6
    min_region_rows: int = 3
    min_anomaly_points: int = 10
    horizon: float = 2.0
    fit_points: int = 300
    axis_points: int = 300
    prior_offset: float = 0.01
    prior_tilt: float = math.radians(3.0)
    straight_on_coverage: float = 0.5
    radius_lr_per_branch: float = 12.0
    max_radius_correction: float = 0.003
    far_wall_min_lean: float = 0.15

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            kind, low, low_included, high, allowed = _ALLOWED[f.name]
            ok = isinstance(value, numbers.Integral if kind is int else numbers.Real)
            ok = ok and not isinstance(value, bool)
            if ok:
                v = kind(value)
                ok = math.isfinite(v) and (v >= low if low_included else v > low) and v <= high
            if not ok:
                raise ValueError(f"ImprovedConfig.{f.name} must be {allowed}, got {value!r}")
            object.__setattr__(self, f.name, kind(value))


#: Allowed values of each :class:`ImprovedConfig` field: (type, lower bound, lower bound
#: allowed, upper bound, description).
_ALLOWED: dict[str, tuple[type, float, bool, float, str]] = {
    "tol_floor": (float, 0.0, False, 1.0, "a number in (0, 1] m"),
    "axis_slope": (float, 0.0, True, 1.0, "a number in [0, 1] (m per m)"),
    "noise_k": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "min_lobe_points": (int, 1, True, math.inf, "an integer >= 1"),
    "min_region_rows": (int, 1, True, math.inf, "an integer >= 1"),
    "min_anomaly_points": (int, 1, True, math.inf, "an integer >= 1"),
    "horizon": (float, 0.0, False, 100.0, "a number in (0, 100] m"),
    "fit_points": (int, 10, True, math.inf, "an integer >= 10"),
    "axis_points": (int, 10, True, math.inf, "an integer >= 10"),
    "prior_offset": (float, 0.0, False, 1.0, "a number in (0, 1] m"),
    "prior_tilt": (float, 0.0, False, math.pi / 2, "a number in (0, pi/2] rad"),
    "straight_on_coverage": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "radius_lr_per_branch": (float, 0.0, True, math.inf, "a finite number >= 0"),
    "max_radius_correction": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "far_wall_min_lean": (float, 0.0, True, 100.0, "a number in [0, 100] (radii)"),
}


DEFAULT_CONFIG = ImprovedConfig()
