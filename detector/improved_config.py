"""Tuning of the improved detector (:mod:`detector.improved`): one frozen dataclass shared by
its modules.

Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


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


DEFAULT_CONFIG = ImprovedConfig()
