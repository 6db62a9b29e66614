"""Thesis Algorithm 2: structure detection from a full rotating-LiDAR sweep (thesis 3.2.2).

Steps, as the thesis gives them:

A. Transform every return to Cartesian coordinates (3D, through the servo angle).
B. The radius of each area (half-plane I and II of every servo position; thesis eq. 2.2 for an
   off-centre sensor) is compared with the clamped radius; a structure is possible when the
   mean radius differs by more than the error for multiple areas.
C.1 Points of interest: inliers (``r < D/2 - margin``), outliers (``r > D/2 + margin``) and
   the outline: points on the wall (``|r - D/2| <= margin``) around the outliers.
C.2 Type: no outline -> type 1 (reducer / closure); one outline and inliers -> type 2 (bend);
   several outlines and inliers -> type 3 (junction); otherwise -> type 4 (junction with an
   extra option to keep going straight).
C.3 Properties: type 1 from the inliers/outliers; types 2-4 from an ellipse (Halir-Flusser,
   :mod:`detector.ellipse`) fitted to each outline: the forward coordinate of the ellipse
   centre is the distance, the roll of the centre the direction, the axes give size and angle.

Readings of the thesis's text where it is vague (documented choices):

- Error of step B: 2.5 mm on the radius (the +-5 mm diameter tolerance of Algorithm 1);
  "multiple areas": at least two. The categorisation margin is also 2.5 mm.
- "Around the outliers": wall points that are 8-neighbours of an outlier in the unrolled scan
  grid (:mod:`detector.grid`). Outliers are grouped into connected regions (one opening each);
  a region needs ``min_region`` points and its outline ``5`` points (an ellipse's minimum) to
  count as an outline.
- The ellipse is fitted in the best-fit plane of the outline (principal components), with the
  first in-plane axis along the pipe axis's projection; its centre is mapped back to 3D.
- Angle: the outline lies on the pipe wall around the opening; seen along the radial direction
  of the opening (the best-fit plane), a branch or outgoing pipe at deflection ``angle`` leaves
  an opening about ``D / sin(angle)`` long and ``D`` wide, so ``angle = asin(b / a)`` for every
  type (at most 90 deg, the thesis's assumption ii). For a bend the opening runs from the mitre
  cut to where the outgoing pipe leaves the incoming pipe's cylinder, so its centre lies
  ``R cot(angle)`` beyond the reference point: the thesis's 4 cm distance error at a 45 deg
  bend in a 10 cm pipe (its table 5.2) is this offset.
- Diameter: type 2 keeps the clamped diameter (thesis 5.1.2: "the diameter is assumed to
  remain the same"); types 3 and 4 use twice the semi-minor axis.
- Straight-on option: always for type 4; for type 3 when inliers lie beyond every outline by
  more than one clamped diameter (the far end of a run that goes on), which is how the
  thesis's cross-junction got its third, straight-on option (thesis 5.1.2).
- Type 1: if the inliers lie within 1 cm of one axial position and reach below half the
  radius, the pipe is closed there (the thesis's "reduction to 0 mm", kind ``closure``).
  Otherwise the new diameter is "the smallest diameter detected" (thesis 5.1.2) on a pipe
  wall: the smallest inlier radius (1 mm bins) whose points spread along the axis (more than
  1 cm, 10th-90th percentile), so that an end wall seen down the narrower pipe, whose every
  radius lies at one axial position, is not taken for it; the distance is the smallest
  forward distance of points at that radius (the end of the taper, thesis table 5.1). Without
  inliers, the outliers' most frequent radius is used (an expansion).
- The sensor's known constant range error (``bias`` of the scan's sensor description) is
  removed before step A: the thesis took the LS02's 2 cm error "into consideration in the 3D
  detection algorithm" (5.2.2).
- The thesis method has no confidence: 1 when it decided from enough points, 0 for a scan too
  sparse to decide.

Units: metres and radians.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from detector.detection import Detection
from detector.ellipse import Ellipse, fit_ellipse
from detector.grid import build_grid, dilate, label_regions
from detector.options import StructureOption, option_order
from detector.scan import Scan, corrected_ranges, radial_noise, spec_value
from detector.transforms import SensorInPipe, option_direction

#: Step B error and the categorisation margin, metres (radius).
RADIUS_ERROR = 0.0025
#: Fewest outliers in an opening region.
MIN_REGION = 5
#: Fewest outline points for an ellipse.
MIN_OUTLINE = 5
#: Type 1: fewest points at a radius to count as a wall, and the axial spread (m) above which
#: they lie on a pipe wall rather than on an end wall facing the sensor.
MIN_WALL_POINTS = 20
END_WALL_SPREAD = 0.01
#: Openings (outlier regions) examined per sweep, the largest first.
MAX_REGIONS = 16


def _ellipse_3d(points: NDArray[np.float64]) -> dict[str, Any] | None:
    """Ellipse fitted to 3D outline points in their best-fit plane."""
    c = points.mean(axis=0)
    q = points - c
    _, _, vt = np.linalg.svd(q, full_matrices=False)
    normal = vt[2]
    e1 = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    if np.linalg.norm(e1) < 1e-6:
        e1 = vt[0]
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    fit = fit_ellipse(q @ e1, q @ e2)
    if not isinstance(fit, Ellipse):  # (an EllipseFitFailure)
        return None
    centre = c + fit.centre[0] * e1 + fit.centre[1] * e2
    return {
        "centre": centre,
        "a": fit.semi_major,
        "b": fit.semi_minor,
        "ratio": fit.axis_ratio,
        "rms": fit.rms_residual,
        "normal": normal,
        "n": fit.n_points,
        "orientation": fit.orientation,
        "tilt": math.acos(min(1.0, abs(float(normal[0])))),
    }


def detect_spatial_thesis(
    scan: Scan,
    clamped_diameter: float,
    sensor_in_pipe: object = None,
    radius_error: float = RADIUS_ERROR,
    margin: float = RADIUS_ERROR,
    min_region: int = MIN_REGION,
    min_areas: int = 2,
) -> Detection:
    """Thesis Algorithm 2 on a full sweep.

    Args:
        scan: a full rotating-LiDAR sweep.
        clamped_diameter: inner diameter from the clamping encoders, metres.
        sensor_in_pipe: known sensor pose in the pipe frame; ``None`` = centred and aligned.
        radius_error: step B error on the mean radius of an area, metres.
        margin: categorisation margin, metres.
        min_region: fewest outliers in an opening.
        min_areas: areas whose radius must differ for a structure.
    """
    t0 = time.perf_counter()
    pose = SensorInPipe.coerce(sensor_in_pipe)
    big_r = 0.5 * float(clamped_diameter)
    grid = build_grid(scan)
    # thesis 5.2.2: the sensor's constant measurement error "is taken into consideration in
    # the 3D detection algorithm": the known range bias of the scan's sensor is removed
    bias = spec_value(scan.spec, "bias", 0.0)
    ranges = corrected_ranges(scan.ranges, bias) if bias else scan.ranges
    local = scan.directions() * np.where(scan.valid, ranges, 0.0)[..., None]
    pts = pose.to_pipe(local.reshape(-1, 3)).reshape(local.shape)
    radius = np.sqrt(np.square(pts[..., 1]) + np.square(pts[..., 2]))
    valid_g = grid.take(scan.valid, fill=False).astype(bool)
    r_g = np.where(valid_g, grid.take(radius, fill=0.0), np.nan)
    diag: dict[str, Any] = {"method": "thesis", "n_points": int(scan.n_valid)}
    # B. mean radius per area (row of the grid)
    counts = valid_g.sum(axis=1)
    with np.errstate(invalid="ignore"):
        mean_r = np.nansum(np.where(valid_g, r_g, 0.0), axis=1) / np.maximum(counts, 1)
    changed = (counts > 0) & (np.abs(mean_r - big_r) > radius_error)
    diag["areas_changed"] = int(changed.sum())
    diag["areas_with_points"] = int((counts > 0).sum())
    if (counts > 0).sum() < min_areas:
        diag["time_s"] = time.perf_counter() - t0
        diag["reason"] = "too few areas with returns"
        return Detection.straight(confidence=0.0, **diag)
    if changed.sum() < min_areas:
        diag["time_s"] = time.perf_counter() - t0
        return Detection.straight(confidence=1.0, **diag)
    # C.1 categories
    inl = valid_g & (r_g < big_r - margin)
    outl = valid_g & (r_g > big_r + margin)
    wall = valid_g & ~inl & ~outl
    labels, n_reg = label_regions(outl, grid.wraps)
    p_g = np.stack([grid.take(pts[..., i], fill=0.0) for i in range(3)], axis=-1)
    outlines: list[NDArray[np.float64]] = []
    sizes = np.bincount(labels.ravel(), minlength=n_reg + 1)
    big = np.flatnonzero(sizes[1:] >= min_region) + 1
    # bounded work: only the MAX_REGIONS largest openings (a fitting has at most four; a
    # scan of scattered far returns has hundreds, each an outline and an ellipse fit)
    big = np.sort(big[np.argsort(-sizes[big], kind="stable")[:MAX_REGIONS]])
    for k in big:
        region = labels == k
        ring = dilate(region, grid.wraps) & wall
        if ring.sum() >= MIN_OUTLINE:
            outlines.append(p_g[ring])
    diag["n_inliers"] = int(inl.sum())
    diag["n_outliers"] = int(outl.sum())
    diag["n_outline"] = int(sum(len(o) for o in outlines))
    diag["n_outlines"] = len(outlines)
    has_inliers = bool(inl.any())
    # C.2 type
    if not outlines:
        ptype = 1
    elif len(outlines) == 1 and has_inliers:
        ptype = 2
    elif len(outlines) > 1 and has_inliers:
        ptype = 3
    else:
        ptype = 4
    diag["type"] = ptype
    # C.3 properties
    if ptype == 1:
        sigma = range_sigma(scan.spec, np.linalg.norm(p_g - pose.position, axis=-1))
        det = _type1(p_g, r_g, inl, outl, big_r, margin, diag, sigma)
        diag["time_s"] = time.perf_counter() - t0
        return det.with_diagnostics(time_s=time.perf_counter() - t0)
    kind = "bend" if ptype == 2 else "junction"
    options: list[StructureOption] = []
    ellipses = []
    for ring_pts in outlines:
        e = _ellipse_3d(ring_pts)
        if e is None:
            continue
        ratio = min(1.0, max(0.0, e["ratio"]))
        angle = math.asin(ratio)
        diameter = clamped_diameter if ptype == 2 else 2.0 * e["b"]
        centre = e["centre"]
        direction = option_direction(
            np.array([0.0, centre[1], centre[2]]) + np.array([1e-12, 0.0, 0.0]), pose
        )[1]
        options.append(
            StructureOption(kind, float(centre[0]), float(diameter), direction, angle, 1.0)
        )
        ellipses.append({k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in e.items()})
    diag["ellipses"] = ellipses
    if not options:
        diag["reason"] = "no outline gave an ellipse"
        diag["time_s"] = time.perf_counter() - t0
        return Detection.straight(confidence=0.0, **diag)
    straight_on = ptype == 4
    if ptype == 3:
        far = max(float(o[:, 0].max()) for o in outlines)
        straight_on = bool(np.any(p_g[inl][:, 0] > far + clamped_diameter))
    if straight_on:
        dist = float(np.mean([o.distance for o in options]))
        options.append(StructureOption("junction", dist, clamped_diameter, 0.0, 0.0, 1.0))
    options.sort(key=option_order)
    diag["time_s"] = time.perf_counter() - t0
    return Detection(kind, options, 1.0, diag)


def range_sigma(spec: dict[str, Any] | None, ranges: NDArray) -> NDArray[np.float64]:
    """Range noise (1 sigma, m) of returns at ``ranges`` (m, any shape) under the sensor
    description ``spec`` (:func:`detector.scan.radial_noise`; 0 for a noiseless sensor)."""
    flat = np.asarray(ranges, dtype=float).reshape(-1)
    ones = np.ones_like(flat)
    sigma, _ = radial_noise(spec, flat, ones, ones)
    return sigma.reshape(np.shape(ranges))


def _type1(
    p_g: NDArray,
    r_g: NDArray,
    inl: NDArray,
    outl: NDArray,
    big_r: float,
    margin: float,
    diag: dict[str, Any],
    sigma: NDArray,
) -> Detection:
    """Thesis type 1: reduction (diameter, distance) or closure. ``sigma``: the range noise
    (1 sigma, m) of every grid cell's return."""
    if inl.any():
        u = p_g[inl][:, 0]
        r = r_g[inl]
        spread = float(np.percentile(u, 90) - np.percentile(u, 10))
        if spread <= 0.01 and float(r.min()) < 0.5 * big_r:
            opt = StructureOption("closure", float(np.median(u)), 0.0, 0.0, 0.0, 1.0)
            return Detection("closure", [opt], 1.0, diag)
        r_new = _smallest_wall_radius(u, r, margin, sigma[inl])
        at = np.abs(r - r_new) <= margin
        opt = StructureOption("reducer", float(u[at].min()), 2.0 * r_new, 0.0, 0.0, 1.0)
        return Detection("reducer", [opt], 1.0, diag)
    if outl.any():
        u = p_g[outl][:, 0]
        r = r_g[outl]
        r_new = _mode(r, margin)
        at = np.abs(r - r_new) <= margin
        opt = StructureOption("reducer", float(u[at].min()), 2.0 * r_new, 0.0, 0.0, 1.0)
        return Detection("reducer", [opt], 1.0, diag)
    return Detection.straight(confidence=0.5, **diag)


def _smallest_wall_radius(u: NDArray, r: NDArray, margin: float, sigma: NDArray) -> float:
    """The smallest radius detected on a pipe wall (thesis 5.1.2: "the smallest diameter
    detected"), metres: the smallest 1 mm radius bin whose points (within ``margin``) are at
    least :data:`MIN_WALL_POINTS` and spread along the axis (10th to 90th percentile) by more
    than :data:`END_WALL_SPREAD` and than 3 times their median range noise ``sigma`` (m), so
    that a wall facing the sensor (an end wall beyond the narrower pipe, whose every radius
    lies at one axial position, blurred only by the noise) is not taken for the narrower pipe.
    The median radius of that bin's points; the most frequent radius when no bin qualifies."""
    bins = np.floor(r / 0.001).astype(int)
    for b in np.unique(bins):
        near = np.abs(r - (b + 0.5) * 0.001) <= margin
        if near.sum() < MIN_WALL_POINTS:
            continue
        uu = u[near]
        spread = float(np.percentile(uu, 90) - np.percentile(uu, 10))
        if spread > max(END_WALL_SPREAD, 3.0 * float(np.median(sigma[near]))):
            return float(np.median(r[near]))
    return _mode(r, margin)


def _mode(r: NDArray, margin: float) -> float:
    """Most frequent radius (1 mm bins), refined as the median of the points near it."""
    bins = np.floor(r / 0.001).astype(int)
    vals, cnt = np.unique(bins, return_counts=True)
    centre = (vals[np.argmax(cnt)] + 0.5) * 0.001
    near = np.abs(r - centre) <= margin
    return float(np.median(r[near])) if near.any() else float(centre)
