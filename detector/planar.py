"""Thesis Algorithm 1: structure detection from one LiDAR plane (thesis section 3.2.2).

Steps, as the thesis gives them:

A. Transform the returns to Cartesian coordinates in the plane and split them into the two
   sides (``beta > 0`` and ``beta < 0``); each side is ordered from the sensor outwards.
B. The pipe diameter seen by the LiDAR, ``d_lidar`` = mean radius of the left side + mean radius
   of the right side (each radius about the pipe axis, thesis eq. 2.2 for an off-centre
   sensor), is compared with the clamped diameter: within +-5 mm means "keep going straight".
C. Otherwise ``gapDetection`` runs on each side: a gap starts where the forward coordinate of
   consecutive points jumps by at least the smallest pipe the PIRATE can enter (57 mm) and the
   later point lies outside the pipe radius. The points in the gap are the following points
   outside the radius (+ the error margin). Gap size = forward distance between the wall points
   before and after the gap; gap entrance = the middle between them; gap angle = slope of the
   line fitted through the points in the gap. A side without a gap reports the slope of its
   wall instead ("pipe angle").
D. The number of gaps and the properties of each.

Readings of the thesis's text where it is vague (documented choices):

- The gap condition "x-data > d_clamped / 2" is applied with the error margin (the point after
  the jump lies more than the margin outside the radius): without it, quantisation noise on the
  grazing far wall of small pipes (where consecutive wall points are several cm apart) makes
  empty "gaps"; a gap always contains at least one point.
- "linear regression" for the slopes is the orthogonal (total least squares) line fit, so a gap
  at 90 deg (points at constant forward distance) has a well-defined slope; the angle reported
  is that of the line to the forward axis, in [0, 90] deg.
- One gap gives a bend, two or more a junction. The straight-on option of a junction is added
  when the central beams (within 1 deg of forward) return beyond every gap's far edge plus one
  clamped diameter, i.e. the pipe visibly goes on.
- No gap but a diameter change: the central return is "the distance to a possible obstruction".
  If the points inside the pipe radius all lie within 2 cm of that distance, the pipe is closed
  there (kind ``closure``). Otherwise it is a reducer: as in the thesis's 3D algorithm the
  smallest radius detected gives the new diameter, and the distance is the smallest forward
  distance at which that radius is seen (the end of the taper, the thesis's own quantity).
  Without inliers (an expansion) the median radius of the outliers gives the new diameter.
- The direction of an option is the plane's roll angle: ``alpha`` for the ``beta > 0`` side,
  ``alpha + pi`` for the other.
- The thesis method has no confidence measure: it reports 1 when it decided from enough points
  and 0 for a scan too sparse to decide (fewer than ``min_points`` returns per side).

Units: metres and radians.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from detector.detection import Detection
from detector.options import StructureOption
from detector.scan import Scan
from detector.transforms import SensorInPipe

#: Thesis: a diameter within +-5 mm of the clamped one means straight pipe.
DIAMETER_TOLERANCE = 0.005
#: Thesis: the smallest pipe the PIRATE can enter; the minimum forward jump of a gap.
MIN_GAP = 0.057
#: Points per side below which the thesis method does not decide.
MIN_POINTS = 5


@dataclass(frozen=True)
class Gap:
    """One gap found by ``gapDetection`` on one side. Metres and radians."""

    size: float
    entrance: float
    angle: float
    n_points: int
    far_edge: float


def line_angle(forward: NDArray, lateral: NDArray) -> float:
    """Angle (radians, [0, pi/2]) to the forward axis of the orthogonal regression line."""
    if forward.size < 2:
        return 0.0
    pts = np.stack([forward - forward.mean(), lateral - lateral.mean()], axis=1)
    cov = pts.T @ pts
    if not np.all(np.isfinite(cov)) or np.trace(cov) <= 0.0:
        return 0.0
    w, v = np.linalg.eigh(cov)
    d = v[:, 1]
    return float(math.acos(min(1.0, abs(float(d[0])))))


def gap_detection(
    forward: NDArray, radius: NDArray, pipe_radius: float, tol: float, min_gap: float = MIN_GAP
) -> tuple[list[Gap], float]:
    """Thesis ``gapDetection`` on one side.

    Args:
        forward: forward coordinate of the side's points, ordered from the sensor outwards
            (decreasing ``|beta|``), metres.
        radius: distance of each point from the pipe axis, metres.
        pipe_radius: half the clamped diameter, metres.
        tol: the error margin, metres.

    Returns:
        ``(gaps, pipe_angle)``: the gaps and the slope angle of the wall points (radians).
    """
    n = forward.size
    gaps: list[Gap] = []
    i = 0
    while i < n - 1:
        if forward[i + 1] - forward[i] >= min_gap and radius[i + 1] > pipe_radius + tol:
            j = i + 1
            while j < n and radius[j] > pipe_radius + tol:
                j += 1
            inside = slice(i + 1, j)
            before = forward[i]
            after = forward[j] if j < n else forward[j - 1]
            lat = radius[inside]
            fwd = forward[inside]
            gaps.append(
                Gap(
                    size=float(after - before),
                    entrance=float(0.5 * (before + after)),
                    angle=line_angle(fwd, lat),
                    n_points=int(j - i - 1),
                    far_edge=float(after),
                )
            )
            i = max(j, i + 1)
        else:
            i += 1
    wall = np.abs(radius - pipe_radius) <= tol
    return gaps, line_angle(forward[wall], radius[wall])


def detect_planar_thesis(
    scan: Scan,
    clamped_diameter: float,
    plane: int = 0,
    sensor_in_pipe: object = None,
    tolerance: float = DIAMETER_TOLERANCE,
    min_gap: float = MIN_GAP,
    min_points: int = MIN_POINTS,
) -> Detection:
    """Thesis Algorithm 1 on plane ``plane`` of ``scan``.

    Args:
        scan: a scan; only plane ``plane`` is used.
        clamped_diameter: the pipe's inner diameter from the clamping encoders, metres.
        plane: index of the plane to use.
        sensor_in_pipe: known sensor pose in the pipe frame (:class:`SensorInPipe` or a
            ``(position, rotation)`` pair); ``None`` = centred and aligned (thesis).
        tolerance: the +-diameter tolerance of step B and the margin of gap points, metres.
        min_gap: minimum forward jump of a gap, metres.
        min_points: returns per side needed to decide.
    """
    t0 = time.perf_counter()
    pose = SensorInPipe.coerce(sensor_in_pipe)
    big_r = 0.5 * float(clamped_diameter)
    valid = scan.valid[plane]
    beta = scan.beam_angles[valid]
    dirs = scan.directions()[plane][valid]
    pts = pose.to_pipe(dirs * scan.ranges[plane][valid][:, None])
    forward = pts[:, 0]
    radius = np.sqrt(np.square(pts[:, 1]) + np.square(pts[:, 2]))
    alpha = float(scan.plane_angles[plane])
    sides = {"left": beta > 0, "right": beta < 0}
    diag: dict = {"method": "thesis-planar", "plane_angle": alpha, "n_points": int(beta.size)}
    counts = {k: int(m.sum()) for k, m in sides.items()}
    diag["points_per_side"] = counts
    if min(counts.values()) < min_points:
        diag["reason"] = "too few returns on a side"
        diag["time_s"] = time.perf_counter() - t0
        return Detection.straight(confidence=0.0, **diag)
    # B. diameter check
    d_lidar = float(radius[sides["left"]].mean() + radius[sides["right"]].mean())
    diag["d_lidar"] = d_lidar
    if abs(d_lidar - clamped_diameter) <= tolerance:
        diag["time_s"] = time.perf_counter() - t0
        return Detection.straight(confidence=1.0, **diag)
    # C. gap detection per side, points ordered from the sensor outwards
    options: list[StructureOption] = []
    gaps_all: list[Gap] = []
    gap_diag = {}
    for name, mask in sides.items():
        idx = np.flatnonzero(mask)
        order = idx[np.argsort(-np.abs(beta[idx]), kind="stable")]
        gaps, wall_angle = gap_detection(forward[order], radius[order], big_r, tolerance, min_gap)
        direction = alpha if name == "left" else alpha + math.pi
        gap_diag[name] = {
            "gaps": [g.__dict__ for g in gaps],
            "pipe_angle_deg": math.degrees(wall_angle),
        }
        for g in gaps:
            gaps_all.append(g)
            options.append(
                StructureOption(
                    "bend",
                    g.entrance,
                    max(0.0, g.size),
                    direction,
                    min(math.pi, max(0.0, g.angle)),
                    1.0,
                )
            )
    diag["gap_detection"] = gap_diag
    central = np.abs(beta) <= math.radians(1.0) + 1e-9
    central_return = float(forward[central].min()) if central.any() else math.inf
    diag["central_return"] = central_return
    if options:
        kind = "bend" if len(options) == 1 else "junction"
        far = max(g.far_edge for g in gaps_all)
        if math.isfinite(central_return) is False or central_return > far + clamped_diameter:
            kind = "junction"
            dist = float(np.mean([o.distance for o in options]))
            options.append(StructureOption("junction", dist, clamped_diameter, 0.0, 0.0, 1.0))
        options = [
            StructureOption(kind, o.distance, o.diameter, o.direction, o.angle, 1.0)
            for o in options
        ]
        diag["time_s"] = time.perf_counter() - t0
        return Detection(kind, options, 1.0, diag)
    # no gap: obstruction or reducer
    inliers = radius < big_r - tolerance
    outliers = radius > big_r + tolerance
    diag["n_inliers"] = int(inliers.sum())
    diag["n_outliers"] = int(outliers.sum())
    if inliers.any():
        if math.isfinite(central_return) and np.all(
            np.abs(forward[inliers] - central_return) <= 0.02
        ):
            opt = StructureOption("closure", central_return, 0.0, 0.0, 0.0, 1.0)
            diag["time_s"] = time.perf_counter() - t0
            return Detection("closure", [opt], 1.0, diag)
        body = inliers & (forward < central_return - 0.02)
        if not body.any():
            body = inliers
        r_min = float(radius[body].min())
        at_min = body & (radius <= r_min + tolerance)
        dist = float(forward[at_min].min())
        opt = StructureOption("reducer", dist, 2.0 * r_min, 0.0, 0.0, 1.0)
        diag["time_s"] = time.perf_counter() - t0
        return Detection("reducer", [opt], 1.0, diag)
    if outliers.any():
        r_new = float(np.median(radius[outliers]))
        dist = float(forward[outliers].min())
        opt = StructureOption("reducer", dist, 2.0 * r_new, 0.0, 0.0, 1.0)
        diag["time_s"] = time.perf_counter() - t0
        return Detection("reducer", [opt], 1.0, diag)
    diag["time_s"] = time.perf_counter() - t0
    return Detection.straight(confidence=0.5, **diag)
