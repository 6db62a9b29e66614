"""The improved detector (``method="improved"``): model fitting in the pipe frame.

Where the thesis categorises points by radius and fits an ellipse to the outline of an opening,
this method fits the 3D geometry of the structure itself, using what the PIRATE knows: the
clamped diameter and (optionally) the sensor pose in the pipe.

1. **Pipe frame.** Every return is mapped into the pipe frame (the known ``sensor_in_pipe`` pose,
   else the thesis's centred-and-aligned assumption), then the pipe axis is refined by a robust
   fit of a cylinder of the clamped radius to the wall points (4 parameters: cross-section
   offset and tilt, with a weak prior towards the known pose when the wall seen is short). This
   removes sensor misalignment (thesis 5.3) without any outside feedback.
2. **Classification.** Each return's radial residual ``r - D/2`` is compared with a per-point
   tolerance from the sensor model in ``scan.spec`` (range noise projected on the radius, plus a
   floor). Non-wall returns are grouped into connected regions of the unrolled scan grid
   (:mod:`detector.grid`); regions too small or one azimuth wide are rejected as clutter.
3. **Hypotheses.** Returns beyond the wall (``r > D/2``) are *lobes*: openings towards an
   outgoing pipe. Without lobes the structure is axisymmetric: an end wall (a plane
   perpendicular to the axis, kind ``closure``) or a reducer (a cone from the wall radius to a new
   radius: the most frequent inner radius is the new pipe, a robust line ``u = a + b r``
   through the taper returns gives the start of the taper). With lobes, each lobe is an outgoing
   pipe: a cylinder whose axis meets the incoming axis at the reference point ``(L, 0, 0)`` with
   deflection ``angle``, roll ``direction`` and radius ``rho``. Initial values come from a coarse
   grid over ``(L, angle)`` with the lobe's mean roll; all lobes are then refined jointly by
   Tukey-weighted Gauss-Newton on the returns of every lobe (each return assigned to the surface
   it fits best). A single lobe is also fitted as a long-radius bend (a torus of bend radius
   ``R_b`` between the two straight pipes, the reference point still where the straight axes
   meet) and the better fit is kept.
4. **Straight on.** A junction continues straight when the incoming pipe's wall is seen again
   beyond the structure (more than two diameters past the reference point) around most of the
   circumference; its option has the clamped diameter.
5. **Kind and confidence.** One way on -> ``bend``; two or more -> ``junction``. Confidence
   combines the number of supporting returns and the fit residual relative to the tolerance.
   Degenerate inputs (no returns, too few wall returns, fits that fail or leave the physical
   range) give ``straight`` with low confidence, never NaN.

All lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from detector.detection import Detection
from detector.grid import ScanGrid, build_grid, label_regions
from detector.options import StructureOption, option_order
from detector.robust import mad_sigma, robust_gauss_newton, tukey_cost, tukey_weights
from detector.scan import Scan
from detector.transforms import SensorInPipe, option_direction

X_AXIS = np.array([1.0, 0.0, 0.0])


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
    """

    tol_floor: float = 0.002
    axis_slope: float = 0.002
    noise_k: float = 3.0
    min_lobe_points: int = 6
    min_region_rows: int = 3
    min_anomaly_points: int = 10
    horizon: float = 2.0
    fit_points: int = 500
    axis_points: int = 600
    prior_offset: float = 0.01
    prior_tilt: float = math.radians(3.0)
    straight_on_coverage: float = 0.5
    radius_lr_per_branch: float = 12.0


DEFAULT_CONFIG = ImprovedConfig()


# --------------------------------------------------------------------------- point cloud
@dataclass
class PipeCloud:
    """Returns of one scan in the pipe frame, on the unrolled grid."""

    grid: ScanGrid
    sensor_pts: NDArray[np.float64]  # (G, K, 3) sensor frame (0 where invalid)
    valid: NDArray[np.bool_]  # (G, K)
    sigma_r: NDArray[np.float64]  # (G, K) radial noise of each return
    pose: SensorInPipe
    pts: NDArray[np.float64] = field(init=False)  # (G, K, 3) pipe frame
    thin: tuple[NDArray[np.float64], NDArray[np.float64]] | None = field(init=False, default=None)

    def set_pose(self, pose: SensorInPipe) -> None:
        self.pose = pose
        flat = self.sensor_pts.reshape(-1, 3)
        pts = (flat @ pose.rotation.T + pose.position).reshape(self.sensor_pts.shape)
        pts *= self.valid[..., None]  # 0 where invalid
        self.pts = pts

    def restore(self, pose: SensorInPipe, pts: NDArray[np.float64]) -> None:
        """Go back to a pose whose points were computed before."""
        self.pose, self.pts = pose, pts


def _prepare(scan: Scan, pose: SensorInPipe, range_bias: float, cfg: ImprovedConfig) -> PipeCloud:
    grid = build_grid(scan)
    ranges = np.where(scan.valid, scan.ranges - range_bias, 0.0)
    ranges = np.maximum(ranges, 0.0)
    local = scan.directions() * ranges[..., None]
    if scan.n_planes > 1 and not np.allclose(scan.nominal_positions, scan.nominal_positions[0]):
        # continuous sweep: express every plane in the last plane's sensor frame (odometry)
        world = (
            np.einsum("pij,pbj->pbi", scan.nominal_rotations, local)
            + scan.nominal_positions[:, None, :]
        )
        local = (world - scan.nominal_positions[-1]) @ scan.nominal_rotations[-1]
    spec = scan.spec or {}
    sig = float(spec.get("noise_sigma", 0.0))
    sig_rel = float(spec.get("noise_sigma_rel", 0.0))
    res = float(spec.get("range_resolution", 0.0))
    sigma_range = np.sqrt(sig**2 + (sig_rel * ranges) ** 2 + (res**2) / 12.0)
    sin_b = np.abs(np.sin(scan.beam_angles))[None, :]
    jitter = float(spec.get("angular_jitter", 0.0))
    sigma_r = sigma_range * sin_b + ranges * jitter * np.abs(np.cos(scan.beam_angles))[None, :]
    valid = grid.take(scan.valid, fill=False).astype(bool)
    horizon_ok = grid.take(local[..., 0], fill=0.0) <= cfg.horizon
    valid &= horizon_ok
    sensor_pts = np.stack([grid.take(local[..., i], fill=0.0) for i in range(3)], axis=-1)
    cloud = PipeCloud(grid, sensor_pts, valid, grid.take(sigma_r, fill=0.0), pose)
    cloud.set_pose(pose)
    return cloud


def _subsample(idx: NDArray[np.intp], n: int) -> NDArray[np.intp]:
    if idx.size <= n:
        return idx
    step = idx.size / n
    return idx[(np.arange(n) * step).astype(np.intp)]


# --------------------------------------------------------------------------- axis refinement
def _axis_pose(params: NDArray[np.float64], sensor_origin: NDArray[np.float64]) -> SensorInPipe:
    """Correction pose: pipe frame whose axis passes through (0, y0, z0) with slopes (a, b)."""
    y0, z0, a, b = params
    d = np.array([1.0, a, b])
    d /= np.linalg.norm(d)
    # rotation taking the new axis direction d to +x (minimal rotation)
    v = np.cross(d, X_AXIS)
    s = float(np.linalg.norm(v))
    c = float(d @ X_AXIS)
    if s < 1e-12:
        rot = np.eye(3)
    else:
        k = v / s
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        rot = np.eye(3) + s * kx + (1.0 - c) * (kx @ kx)
    origin = np.array([0.0, y0, z0])
    # new coordinates: rot @ (p - origin), shifted along x so the sensor origin is at u = 0
    pos = -rot @ origin
    pos[0] -= float((rot @ (sensor_origin - origin))[0])
    return SensorInPipe(pos, rot)


def _cyl_axis_residual(
    sub: NDArray[np.float64], big_r: float, x: NDArray[np.float64], want_jac: bool
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Residual (distance to the axis - R) of points for the axis through (0, y0, z0) along
    (1, a, b), and its analytic Jacobian."""
    y0, z0, a, b = x
    n = math.sqrt(1.0 + a * a + b * b)
    d = np.array([1.0, a, b]) / n
    q = sub - np.array([0.0, y0, z0])
    t = q @ d
    dist = np.sqrt(np.maximum(np.einsum("ij,ij->i", q, q) - t * t, 1e-18))
    res = dist - big_r
    if not want_jac:
        return res, None
    jac = np.empty((sub.shape[0], 4))
    jac[:, 0] = (t * d[1] - q[:, 1]) / dist
    jac[:, 1] = (t * d[2] - q[:, 2]) / dist
    dda = (np.array([0.0, 1.0, 0.0]) - d * d[1]) / n
    ddb = (np.array([0.0, 0.0, 1.0]) - d * d[2]) / n
    jac[:, 2] = -t * (q @ dda) / dist
    jac[:, 3] = -t * (q @ ddb) / dist
    return res, jac


def _refine_axis(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, u_max: float | None = None
) -> tuple[SensorInPipe, dict[str, Any]]:
    """Refine the pipe axis from the wall returns. Without ``u_max`` the nearest 60 % of the
    wall-like returns are used (a structure ahead is farther away); with it, every wall-like
    return before ``u_max`` (the start of the structure), which gives the tilt a long lever."""
    pts = cloud.pts[cloud.valid]
    info: dict[str, Any] = {"axis_points": 0}
    if pts.shape[0] < 20:
        return cloud.pose, info
    r = np.hypot(pts[:, 1], pts[:, 2])
    gate = max(0.35 * big_r, 0.01)
    cand = np.flatnonzero(np.abs(r - big_r) < gate)
    if cand.size < 20:
        return cloud.pose, info
    cand = cand[np.argsort(pts[cand, 0], kind="stable")]
    if u_max is None:
        cand = cand[: max(400, int(0.6 * cand.size))]
    else:
        cand = cand[pts[cand, 0] < u_max]
        if cand.size < 40:
            return cloud.pose, info
    sub = pts[_subsample(cand, cfg.axis_points)]
    # the tilt needs a lever arm: over a short stretch of wall it is not observable (and a
    # gentle taper would pass for a tilted wall), so it is held at the prior
    span = float(np.percentile(sub[:, 0], 95) - np.percentile(sub[:, 0], 5))
    tilt_sigma = cfg.prior_tilt if span >= 0.05 else math.radians(0.05)
    prior = np.array([cfg.prior_offset, cfg.prior_offset, tilt_sigma, tilt_sigma])
    info["axis_span"] = span
    x, res, w = robust_gauss_newton(
        lambda p: _cyl_axis_residual(sub, big_r, p, False)[0],
        np.zeros(4),
        np.full(4, 1e-5),
        c=gate,
        iterations=10,
        prior_sigma=prior,
        c_final=0.004,
        jacobian=lambda p: _cyl_axis_residual(sub, big_r, p, True)[1],
    )
    info.update(
        axis_points=int((w > 0).sum()),
        axis_offset=[float(x[0]), float(x[1])],
        axis_tilt_deg=math.degrees(math.atan(math.hypot(x[2], x[3]))),
        axis_rms=float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9))),
    )
    if not np.all(np.isfinite(x)) or abs(x[0]) > big_r or abs(x[1]) > big_r:
        return cloud.pose, info
    if math.hypot(x[2], x[3]) > math.tan(math.radians(8.0)):
        return cloud.pose, info
    return _axis_pose(x, cloud.pose.position).compose(cloud.pose), info


# --------------------------------------------------------------------------- geometry helpers
def _dir(theta: float, phi: float) -> NDArray[np.float64]:
    st = math.sin(theta)
    return np.array([math.cos(theta), st * math.cos(phi), st * math.sin(phi)])


def _line_dist(p: NDArray, c: NDArray, d: NDArray) -> NDArray:
    q = p - c
    t = q @ d
    return np.sqrt(np.maximum(np.einsum("ij,ij->i", q, q) - t * t, 0.0))


def _torus_dist(p: NDArray, big_l: float, theta: float, phi: float, rb: float) -> NDArray:
    """Distance from points to the centreline of a long-radius bend: the incoming axis up to the
    tangent point, an arc of radius ``rb`` turning by ``theta`` towards roll ``phi``, then the
    outgoing straight axis. The straight axes meet at ``(big_l, 0, 0)``."""
    d, _ = _torus_parts(p, big_l, theta, phi, rb)
    return d


def _torus_parts(
    p: NDArray, big_l: float, theta: float, phi: float, rb: float
) -> tuple[NDArray, NDArray]:
    """(distance to the bend centreline, arc angle of each point's projection)."""
    cp, sp = math.cos(phi), math.sin(phi)
    t1 = big_l - rb * math.tan(theta / 2.0)
    qa = p[:, 0] - t1
    py = p[:, 1] - rb * cp
    pz = p[:, 2] - rb * sp
    qw = -(py * cp + pz * sp)
    qn = pz * cp - py * sp
    ang = np.arctan2(qa, qw)  # 0 at the tangent point on the incoming axis
    d_arc = np.sqrt((np.hypot(qa, qw) - rb) ** 2 + qn**2)
    d_out = _line_dist(p, np.array([big_l, 0.0, 0.0]), _dir(theta, phi))
    d_in = np.hypot(p[:, 1], p[:, 2])
    return np.where(ang < 0.0, d_in, np.where(ang > theta, d_out, d_arc)), ang


# --------------------------------------------------------------------------- main entry
def detect_improved(
    scan: Scan,
    clamped_diameter: float,
    sensor_in_pipe: object = None,
    config: ImprovedConfig = DEFAULT_CONFIG,
    range_bias: float | None = None,
    refine_axis: bool = True,
) -> Detection:
    """The improved detector on a full sweep (see module docstring).

    Args:
        scan: a rotating-LiDAR sweep (any number of planes).
        clamped_diameter: inner diameter from the clamping encoders, metres.
        sensor_in_pipe: known sensor pose in the pipe frame (:class:`SensorInPipe` or a
            ``(position, rotation)`` pair); ``None``: centred and aligned, refined from the scan.
        config: tuning.
        range_bias: calibrated constant range bias subtracted from every return, metres;
            default: ``scan.spec["bias"]`` (0 if absent).
        refine_axis: refine the pipe axis from the wall returns.
    """
    t0 = time.perf_counter()
    d_clamped = float(clamped_diameter)
    if not (math.isfinite(d_clamped) and d_clamped > 0.0):
        raise ValueError(f"clamped_diameter must be a positive length (m), got {clamped_diameter}")
    big_r = 0.5 * d_clamped
    pose0 = SensorInPipe.coerce(sensor_in_pipe)
    bias = float((scan.spec or {}).get("bias", 0.0)) if range_bias is None else float(range_bias)
    if not math.isfinite(bias):
        bias = 0.0
    diag: dict[str, Any] = {"method": "improved", "n_points": int(scan.n_valid)}
    try:
        cloud = _prepare(scan, pose0, bias, config)
        if refine_axis:
            candidates = [(pose0, {})]
            pts_of = [cloud.pts]
            pose1, info1 = _refine_axis(cloud, big_r, config)
            candidates.append((pose1, info1))
            cloud.set_pose(pose1)
            pts_of.append(cloud.pts)
            # second pass: all of the intact wall before the structure
            u_start = _structure_start(cloud, big_r, config)
            pose2, info2 = _refine_axis(cloud, big_r, config, u_max=u_start)
            if info2.get("axis_points", 0) >= 40:
                info2["axis_wall_until"] = u_start
                candidates.append((pose2, info2))
            # keep the pose that explains the most wall returns before the structure (a fit
            # pulled by the structure's own returns, e.g. tilted onto one side of a taper,
            # explains fewer of them)
            cloud.restore(pose0, pts_of[0])
            u_near = min(u_start, _structure_start(cloud, big_r, config))
            scores = [_wall_count(cloud, big_r, config, p, u_near) for p, _ in candidates]
            best = int(np.argmax(np.array(scores) + 1e-3 * np.arange(len(scores))))
            pose, info = candidates[best]
            diag.update(info)
            diag["axis_pass"] = best
            if best < len(pts_of):
                cloud.restore(pose, pts_of[best])
            else:
                cloud.set_pose(pose)
        det = _detect_in_pipe_frame(cloud, big_r, config, diag)
    except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:  # never crash/NaN
        diag["error"] = f"{type(exc).__name__}: {exc}"
        det = Detection.straight(confidence=0.0, **diag)
    return det.with_diagnostics(time_s=time.perf_counter() - t0)


def _wall_count(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, pose: SensorInPipe, u_max: float
) -> int:
    """Returns within the wall tolerance of the clamped radius under ``pose``, counting those
    nearer than ``u_max`` along the axis (all of them when fewer than 100 are)."""
    if cloud.thin is None:  # every third valid return and its tolerance, computed once
        cloud.thin = (
            cloud.sensor_pts[cloud.valid][::3],
            cfg.tol_floor + cfg.noise_k * cloud.sigma_r[cloud.valid][::3],
        )
    sp, tol = cloud.thin
    pts = sp @ pose.rotation.T + pose.position
    r = np.hypot(pts[:, 1], pts[:, 2])
    ok = np.abs(r - big_r) <= tol
    near = pts[:, 0] < u_max
    if np.count_nonzero(near) >= 40:
        ok &= near
    return int(np.count_nonzero(ok))


def _structure_start(cloud: PipeCloud, big_r: float, cfg: ImprovedConfig) -> float:
    """Axial position where the wall stops being intact (first significant anomalies); the
    horizon when there are none."""
    pts = cloud.pts
    r = np.hypot(pts[..., 1], pts[..., 2])
    tol = cfg.tol_floor + cfg.noise_k * cloud.sigma_r + cfg.axis_slope * np.abs(pts[..., 0])
    anomaly = cloud.valid & (np.abs(r - big_r) > 2.0 * tol)
    labels, n_lab = label_regions(anomaly, cloud.grid.wraps)
    if n_lab == 0:
        return cfg.horizon
    counts = np.bincount(labels[anomaly], minlength=n_lab + 1)
    good = counts >= cfg.min_anomaly_points
    good[0] = False
    sel = good[labels] & anomaly
    if not sel.any():
        return cfg.horizon
    u = pts[..., 0][sel]
    # where the beams of those returns crossed the wall radius (sensor near the axis)
    uc = u * big_r / np.maximum(r[sel], 1e-9)
    return float(np.percentile(np.minimum(u, uc), 1)) - 0.005


def _detect_in_pipe_frame(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, diag: dict[str, Any]
) -> Detection:
    valid = cloud.valid
    pts = cloud.pts
    diag["pipe_axis_sensor"] = [float(v) for v in cloud.pose.rotation[0]]
    r = np.hypot(pts[..., 1], pts[..., 2])
    # residual axis error grows with the distance along the axis
    tol = cfg.tol_floor + cfg.noise_k * cloud.sigma_r + cfg.axis_slope * np.abs(pts[..., 0])
    e = np.where(valid, r - big_r, 0.0)
    wall = valid & (np.abs(e) <= tol)
    beyond = valid & (e > tol)
    inside = valid & (e < -tol)
    n_valid = int(valid.sum())
    diag.update(n_wall=int(wall.sum()), n_beyond=int(beyond.sum()), n_inside=int(inside.sum()))
    if n_valid < cfg.min_anomaly_points:
        diag["reason"] = "too few returns"
        return Detection.straight(confidence=0.0, **diag)
    # significant anomaly regions
    anomaly = beyond | inside
    labels, n_lab = label_regions(anomaly, cloud.grid.wraps)
    keep = np.zeros_like(anomaly)
    if n_lab:
        rows = np.nonzero(anomaly)[0]
        lab = labels[anomaly]
        counts = np.bincount(lab, minlength=n_lab + 1)
        # rows spanned per label
        spans = np.zeros((n_lab + 1, anomaly.shape[0]), dtype=bool)
        spans[lab, rows] = True
        row_span = spans.sum(axis=1)
        good = (counts >= cfg.min_anomaly_points) & (row_span >= cfg.min_region_rows)
        good[0] = False
        keep = good[labels] & anomaly
    n_keep = int(keep.sum())
    diag["n_anomaly"] = n_keep
    wall_frac = float(wall.sum()) / max(n_valid, 1)
    if n_keep < cfg.min_anomaly_points:
        conf = min(1.0, float(wall.sum()) / 200.0) * wall_frac
        return Detection.straight(confidence=conf, **diag)
    beyond_k = beyond & keep
    inside_k = inside & keep
    lobes = _find_lobes(cloud, beyond_k, big_r, cfg)
    diag["n_lobes"] = len(lobes)
    if lobes:
        # an expansion: returns beyond the wall all around and hardly any inside
        cov = _azimuth_coverage(pts[beyond_k])
        uniform = _azimuth_uniformity(pts[beyond_k])
        diag.update(beyond_coverage=cov, beyond_uniformity=uniform)
        if uniform >= 0.3 and inside_k.sum() < 0.3 * beyond_k.sum():
            return _axisymmetric(cloud, big_r, inside_k, beyond_k, wall, tol, cfg, diag)
        return _branches(cloud, big_r, lobes, keep, wall, tol, cfg, diag)
    det = _axisymmetric(cloud, big_r, inside_k, beyond_k, wall, tol, cfg, diag)
    if det.diagnostics.get("axisymmetric_support", 1.0) >= 0.6:
        return det
    # neither an end wall nor a reducer: the far wall of a turn seen head-on (small pipes, far
    # away): fit an outgoing pipe to the inner returns with unknown roll
    pseudo = Lobe(inside_k, 0.0, int(inside_k.sum()))
    alt = _branches(cloud, big_r, [pseudo], keep, wall, tol, cfg, dict(diag), any_roll=True)
    if alt.kind != "straight" and alt.confidence > det.confidence:
        return alt
    return det


# --------------------------------------------------------------------------- lobes
@dataclass
class Lobe:
    mask: NDArray[np.bool_]
    roll: float
    n: int


def _find_lobes(
    cloud: PipeCloud, beyond: NDArray[np.bool_], big_r: float, cfg: ImprovedConfig
) -> list[Lobe]:
    labels, n_lab = label_regions(beyond, cloud.grid.wraps)
    if n_lab == 0:
        return []
    pts = cloud.pts
    lobes: list[Lobe] = []
    for k in range(1, n_lab + 1):
        m = labels == k
        n = int(m.sum())
        if n < cfg.min_lobe_points:
            continue
        nrows = int(np.any(m, axis=1).sum())
        if nrows < cfg.min_region_rows:
            continue
        p = pts[m]
        depth = float(np.percentile(np.hypot(p[:, 1], p[:, 2]), 90)) - big_r
        if depth < max(0.006, 0.1 * big_r):
            continue  # a shallow sliver (seam leaks, noise), not an opening
        roll = math.atan2(float(p[:, 2].sum()), float(p[:, 1].sum()))
        lobes.append(Lobe(m, roll, n))
    # merge lobes within 45 deg of roll (an opening split by dropouts)
    lobes.sort(key=lambda lb: -lb.n)
    merged: list[Lobe] = []
    for lb in lobes:
        for mg in merged:
            if abs(_wrap(lb.roll - mg.roll)) < math.radians(45.0):
                mg.mask = mg.mask | lb.mask
                p = pts[mg.mask]
                mg.roll = math.atan2(float(p[:, 2].sum()), float(p[:, 1].sum()))
                mg.n += lb.n
                break
        else:
            merged.append(Lobe(lb.mask.copy(), lb.roll, lb.n))
    # a lobe must be a real opening, not a sliver: compare with the largest
    if merged:
        biggest = max(m.n for m in merged)
        merged = [m for m in merged if m.n >= max(cfg.min_lobe_points, 0.05 * biggest)]
    return merged


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


# --------------------------------------------------------------------------- axisymmetric
def _axisymmetric(
    cloud: PipeCloud,
    big_r: float,
    inside: NDArray[np.bool_],
    beyond: NDArray[np.bool_],
    wall: NDArray[np.bool_],
    tol: NDArray[np.float64],
    cfg: ImprovedConfig,
    diag: dict[str, Any],
) -> Detection:
    """End wall (closure) or reducer/expander: the structure is (nearly) axisymmetric."""
    pts = cloud.pts
    contraction = bool(inside.sum() >= beyond.sum())
    anomaly = inside if contraction else beyond
    if anomaly.sum() < cfg.min_anomaly_points:
        return Detection.straight(confidence=0.3, **diag)
    p = pts[anomaly]
    u = p[:, 0]
    r = np.hypot(p[:, 1], p[:, 2])
    tol_med = float(np.median(tol[anomaly]))
    # --- closure: a plane perpendicular to the axis, seen down to the centre
    if contraction:
        u_med = float(np.median(u))
        tol_u = 0.003 + 2.0 * tol_med
        on_plane = np.abs(u - u_med) <= tol_u
        frac_plane = float(on_plane.mean())
        diag["closure_plane_fraction"] = frac_plane
        if frac_plane >= 0.8 and float(np.percentile(r[on_plane], 5)) < 0.5 * big_r:
            up = u[on_plane]
            dist = float(np.mean(up))
            spread = float(np.std(up))
            cov = _azimuth_coverage(p[on_plane])
            diag.update(closure_rms=spread, closure_coverage=cov, axisymmetric_support=1.0)
            if spread <= 0.5 * tol_u:
                conf = _confidence(int(on_plane.sum()), spread, tol_u) * (0.5 + 0.5 * cov)
                opt = StructureOption("closure", dist, 0.0, 0.0, 0.0, conf)
                return Detection("closure", [opt], conf, diag)
    # --- reducer: r(u) = R + (R2 - R) clip((u - L) / T, 0, 1)
    if contraction:
        u_cross = u
    else:
        u_cross = u * big_r / np.maximum(r, 1e-9)  # where the beams crossed the wall radius
    u_first = float(np.percentile(u_cross, 1))
    r2 = _radius_mode(r, r.size)
    sub = _subsample(np.arange(u.size), cfg.fit_points)
    us, rs = u[sub], r[sub]
    t0 = max(0.01, float(np.percentile(u, 30)) - u_first)

    def resid(x: NDArray) -> NDArray:
        big_l, t_len, rr2 = x
        frac = np.clip((us - big_l) / max(t_len, 1e-4), 0.0, 1.0)
        return rs - (big_r + (rr2 - big_r) * frac)

    c_fin = max(2.0 * tol_med, 0.002)
    x, res, w = robust_gauss_newton(
        resid,
        np.array([u_first, t0, r2]),
        np.array([1e-4, 1e-4, 1e-5]),
        c=max(4.0 * c_fin, 0.01),
        iterations=15,
        lower=np.array([-0.2, 0.002, 0.0]),
        upper=np.array([cfg.horizon, 1.0, 3.0 * big_r]),
        c_final=c_fin,
    )
    support = float((w > 0.1).mean())
    rms = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9)))
    big_l, t_len, r2 = (float(v) for v in x)
    diag.update(reducer_r2=r2, reducer_taper=t_len, reducer_rms=rms, axisymmetric_support=support)
    cov = _azimuth_coverage(p)
    if not (math.isfinite(big_l) and math.isfinite(r2)):
        return Detection.straight(confidence=0.0, **diag)
    if r2 < 0.25 * big_r:
        # the pipe closes (a cap seen obliquely, or a cone to nothing): a closure at its start
        conf = 0.5 * _confidence(int(w.sum()), rms, c_fin) * cov
        opt = StructureOption("closure", max(big_l, 0.0), 0.0, 0.0, 0.0, conf)
        return Detection("closure", [opt], conf, diag)
    conf = _confidence(int((w > 0.1).sum()), rms, c_fin) * cov * min(1.0, support / 0.6)
    opt = StructureOption("reducer", max(big_l, 0.0), 2.0 * r2, 0.0, 0.0, conf)
    return Detection("reducer", [opt], conf, diag)


def _radius_mode(r: NDArray, n: int) -> float:
    """Most frequent radius: 1 mm histogram peak refined by the median of its neighbourhood."""
    bins = np.floor(r / 0.001).astype(np.int64)
    lo = int(bins.min())
    cnt = np.bincount(bins - lo)
    smooth = np.convolve(cnt, np.ones(3), mode="same")
    peak = (int(np.argmax(smooth)) + lo + 0.5) * 0.001
    near = np.abs(r - peak) <= 0.002
    return float(np.median(r[near])) if near.any() else float(peak)


def _robust_line(x: NDArray, y: NDArray) -> tuple[float, float]:
    """Robust fit ``y = a + b x`` (Tukey IRLS)."""
    w = np.ones_like(x)
    a, b = float(np.median(y)), 0.0
    for _ in range(6):
        sw = w.sum()
        if sw <= 0:
            break
        xm = float((w * x).sum() / sw)
        ym = float((w * y).sum() / sw)
        sxx = float((w * (x - xm) ** 2).sum())
        if sxx <= 1e-18:
            break
        b = float((w * (x - xm) * (y - ym)).sum() / sxx)
        a = ym - b * xm
        res = y - (a + b * x)
        s = max(mad_sigma(res), 1e-4)
        w = tukey_weights(res, 4.685 * s)
    return a, b


def _azimuth_coverage(p: NDArray, bins: int = 36) -> float:
    phi = np.arctan2(p[:, 2], p[:, 1])
    k = np.floor((phi + math.pi) / (2 * math.pi) * bins).astype(int) % bins
    return float(np.count_nonzero(np.bincount(k, minlength=bins))) / bins


def _azimuth_uniformity(p: NDArray, bins: int = 12) -> float:
    """Smallest azimuth-bin count relative to the median bin count (1: even all around)."""
    if p.shape[0] == 0:
        return 0.0
    phi = np.arctan2(p[:, 2], p[:, 1])
    k = np.floor((phi + math.pi) / (2 * math.pi) * bins).astype(int) % bins
    cnt = np.bincount(k, minlength=bins)
    med = float(np.median(cnt))
    return float(cnt.min()) / med if med > 0 else 0.0


def _confidence(n_support: int, rms: float, tol: float) -> float:
    c = (1.0 - math.exp(-n_support / 30.0)) * math.exp(-((rms / max(tol, 1e-6)) ** 2) / 4.0)
    return float(min(1.0, max(0.0, c)))


# --------------------------------------------------------------------------- bends/junctions
@dataclass
class BranchFit:
    theta: float
    phi: float
    rho: float
    rb: float = 0.0


def _line_resjac(
    p: NDArray, x: NDArray, n_l: int, want_jac: bool
) -> tuple[NDArray, NDArray | None]:
    """Residuals of points to the nearest of ``n_l`` outgoing cylinders whose axes meet the
    incoming axis at ``(x[0], 0, 0)``; parameters per lobe: (theta, phi, rho)."""
    q = p - np.array([x[0], 0.0, 0.0])
    qq = np.einsum("ij,ij->i", q, q)
    best = np.full(p.shape[0], np.inf)
    arg = np.zeros(p.shape[0], dtype=np.intp)
    parts = []
    for k in range(n_l):
        th, ph, rho = x[1 + 3 * k : 4 + 3 * k]
        d = _dir(th, ph)
        t = q @ d
        dist = np.sqrt(np.maximum(qq - t * t, 1e-18))
        res = dist - rho
        better = np.abs(res) < np.abs(best)
        best = np.where(better, res, best)
        arg = np.where(better, k, arg)
        parts.append((d, t, dist, th, ph))
    if not want_jac:
        return best, None
    jac = np.zeros((p.shape[0], 1 + 3 * n_l))
    for k, (d, t, dist, th, ph) in enumerate(parts):
        m = arg == k
        if not m.any():
            continue
        qk, tk, dk = q[m], t[m], dist[m]
        d_th = np.array([-math.sin(th), math.cos(th) * math.cos(ph), math.cos(th) * math.sin(ph)])
        d_ph = np.array([0.0, -math.sin(th) * math.sin(ph), math.sin(th) * math.cos(ph)])
        jac[m, 0] = (tk * d[0] - qk[:, 0]) / dk
        jac[m, 1 + 3 * k] = -tk * (qk @ d_th) / dk
        jac[m, 2 + 3 * k] = -tk * (qk @ d_ph) / dk
        jac[m, 3 + 3 * k] = -1.0
    return best, jac


def _branches(
    cloud: PipeCloud,
    big_r: float,
    lobes: list[Lobe],
    keep: NDArray[np.bool_],
    wall: NDArray[np.bool_],
    tol: NDArray[np.float64],
    cfg: ImprovedConfig,
    diag: dict[str, Any],
    any_roll: bool = False,
) -> Detection:
    """Bends and junctions: one outgoing pipe per lobe (``any_roll``: the lobe's roll is
    unknown and searched too)."""
    pts = cloud.pts
    flat = pts.reshape(-1, 3)
    # returns of the outgoing pipes: the lobes, and the inner returns near them (the far wall
    # of a turn seen head-on), not far end walls of a run that goes on
    lobe_mask = np.zeros_like(keep)
    for lb in lobes:
        lobe_mask |= lb.mask
    u_all = pts[..., 0]
    u_hi = float(np.percentile(u_all[lobe_mask], 95)) + 2.0 * big_r if lobe_mask.any() else 0.0
    near_inside = keep & ~lobe_mask & (u_all <= u_hi)
    lobe_idx = np.concatenate(
        [_subsample(np.flatnonzero(lb.mask.reshape(-1)), cfg.fit_points // 2) for lb in lobes]
    )
    near_idx = _subsample(np.flatnonzero(near_inside.reshape(-1)), cfg.fit_points // 2)
    sub_idx = np.concatenate([lobe_idx, near_idx])
    if any_roll:
        sub_idx = _subsample(np.flatnonzero(keep.reshape(-1)), cfg.fit_points)
    p_all = flat[sub_idx]
    tol_med = float(np.median(tol.reshape(-1)[sub_idx]))
    noise_med = float(np.median(cloud.sigma_r.reshape(-1)[sub_idx])) + 0.3e-3
    lobe_pts = []
    u_edge = math.inf
    for lb in lobes:
        lp = pts[lb.mask]
        lp = lp[_subsample(np.arange(lp.shape[0]), 200)]
        lobe_pts.append(lp)
        # where the beams left the incoming cylinder (sensor near the axis)
        rr = np.hypot(lp[:, 1], lp[:, 2])
        uc = lp[:, 0] * big_r / np.maximum(rr, 1e-9)
        u_edge = min(u_edge, float(np.percentile(uc, 1)))
    # --- does the incoming pipe go on? Then this is a junction seen along its run: every
    # lobe is a side branch of a standard fitting (tee 90 deg, wye 45 deg), no wider than
    # the run
    straight_on, cov_on = _straight_on(cloud, big_r, u_edge + big_r, wall, cfg)
    diag["straight_on_coverage"] = cov_on
    # --- coarse grid per lobe over (L, theta) with the lobe's roll and radius R
    thetas = np.radians(np.arange(30.0, 151.0, 7.5))
    l_grid = u_edge + np.linspace(0.0, 3.0 * big_r, 13)
    c0 = max(6.0 * tol_med, 0.006)
    total = np.zeros(l_grid.size)
    per_lobe = []
    rolls_of = []
    for lb, lp in zip(lobes, lobe_pts):
        rolls = np.radians(np.arange(0.0, 360.0, 15.0)) if any_roll else np.array([lb.roll])
        rolls_of.append(rolls)
        dirs = np.stack([_dir(float(t), float(ro)) for ro in rolls for t in thetas])  # (RT, 3)
        q = lp[None, :, :] - np.stack([l_grid, 0 * l_grid, 0 * l_grid], axis=1)[:, None, :]
        qq = np.einsum("lnk,lnk->ln", q, q)
        t = q @ dirs.T  # (L, n, T)
        res = np.sqrt(np.maximum(qq[..., None] - t * t, 0.0)) - big_r
        cost = np.minimum(res * res, c0 * c0).mean(axis=1)  # (L, T)
        per_lobe.append(cost)
        total += cost.min(axis=1)
    i_l = int(np.argmin(total))
    x0 = [float(l_grid[i_l])]
    for rolls, cost in zip(rolls_of, per_lobe):
        k = int(np.argmin(cost[i_l]))
        x0 += [float(thetas[k % thetas.size]), float(rolls[k // thetas.size]), big_r]
    n_l = len(lobes)
    x0a = np.array(x0)
    # physical ranges: bends deflect 30-90 deg, branches 45, 90 or 135 deg
    lower = np.array([-0.5] + [math.radians(25.0), -10.0, 0.25 * big_r] * n_l)
    upper = np.array([cfg.horizon] + [math.radians(150.0), 10.0, 2.5 * big_r] * n_l)
    c_fin = max(3.0 * tol_med, 0.003)
    x, res, w = robust_gauss_newton(
        lambda v: _line_resjac(p_all, v, n_l, False)[0],
        x0a,
        np.full(x0a.size, 1e-5),
        c=2.0 * c0,
        iterations=12,
        lower=lower,
        upper=upper,
        c_final=c_fin,
        jacobian=lambda v: _line_resjac(p_all, v, n_l, True)[1],
    )
    # --- the outgoing radii: the clamped radius (a standard fitting) unless the returns
    # call for another one. A free radius is poorly observed from a partial view of an
    # opening under range noise, so it is kept only when it fits significantly better
    # (likelihood ratio against the residual noise, a few units per extra parameter).
    x_eq = x.copy()
    x_eq[3::3] = big_r
    lo_eq, up_eq = lower.copy(), upper.copy()
    lo_eq[3::3] = big_r
    up_eq[3::3] = big_r
    x_eq, res_eq, w_eq = robust_gauss_newton(
        lambda v: _line_resjac(p_all, v, n_l, False)[0],
        x_eq,
        np.full(x_eq.size, 1e-5),
        c=2.0 * c_fin,
        iterations=8,
        lower=lo_eq,
        upper=up_eq,
        c_final=c_fin,
        jacobian=lambda v: _line_resjac(p_all, v, n_l, True)[1],
    )
    cost_free = tukey_cost(res, c_fin)
    cost_eq = tukey_cost(res_eq, c_fin)
    n_in = max(int((w > 0.1).sum()), 1)
    sigma2 = max(2.0 * cost_free / n_in, noise_med**2)
    lr = 2.0 * (cost_eq - cost_free) / sigma2
    diag.update(radius_lr=float(lr), radius_free=[float(v) for v in x[3::3]])
    if lr <= cfg.radius_lr_per_branch * n_l:
        x, res, w = x_eq, res_eq, w_eq
    diag["radius_model"] = "clamped" if x is x_eq else "free"
    rms = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9)))
    support = int((w > 0.1).sum())
    diag.update(fit_rms=rms, fit_support=support, fit_points=int(p_all.shape[0]))
    model = "straight_axes"
    fits = [BranchFit(x[1 + 3 * k], x[2 + 3 * k], x[3 + 3 * k]) for k in range(n_l)]
    big_l = float(x[0])
    # --- a single way on that the straight model explains poorly: a long-radius bend (torus)
    lower_bound = False
    if n_l == 1 and not straight_on and rms > 2.0 * noise_med:
        tor = _fit_torus(p_all, big_r, big_l, fits[0], c0, c_fin)
        if tor is not None:
            xt, rms_t, sup_t, vis = tor
            diag.update(torus_rms=rms_t, torus_support=sup_t, torus_rb=float(xt[4]))
            if sup_t >= support * 0.98 and rms_t < rms * 0.85:
                big_l = float(xt[0])
                fits = [BranchFit(xt[1], xt[2], xt[3], xt[4])]
                rms, support = rms_t, sup_t
                model = "torus"
                # the end of the arc unseen: the angle is only a lower bound
                lower_bound = vis >= float(xt[1]) - math.radians(3.0)
                diag["torus_visible_arc_deg"] = math.degrees(vis)
    diag["model"] = model
    diag["angle_lower_bound"] = lower_bound
    if not (math.isfinite(big_l) and -0.5 <= big_l <= cfg.horizon):
        diag["reason"] = "fit left the physical range"
        return Detection.straight(confidence=0.0, **diag)
    conf = _confidence(support, rms, c_fin / 3.0) * (0.6 if lower_bound else 1.0)
    options: list[StructureOption] = []
    for f in fits:
        angle, direction = option_direction(_dir(f.theta, f.phi), cloud.pose)
        options.append(StructureOption("bend", big_l, 2.0 * float(f.rho), direction, angle, conf))
    if straight_on:
        options.append(StructureOption("junction", big_l, 2.0 * big_r, 0.0, 0.0, conf * cov_on))
    kind = "bend" if len(options) == 1 else "junction"
    options = [
        StructureOption(kind, o.distance, o.diameter, o.direction, o.angle, o.confidence)
        for o in options
    ]
    options.sort(key=option_order)
    return Detection(kind, options, conf, diag)


def _straight_on(
    cloud: PipeCloud, big_r: float, big_l: float, wall: NDArray[np.bool_], cfg: ImprovedConfig
) -> tuple[bool, float]:
    """Is the incoming pipe's wall seen again well beyond the structure, all around?"""
    u = cloud.pts[..., 0]
    far = wall & (u > big_l + 4.0 * big_r)
    if far.sum() < 10:
        return False, 0.0
    cov = _azimuth_coverage(cloud.pts[far])
    return cov >= cfg.straight_on_coverage, cov


def _fit_torus(
    p: NDArray, big_r: float, big_l: float, f: BranchFit, c0: float, c_fin: float
) -> tuple[NDArray, float, int, float] | None:
    """Long-radius bend fit from two bend-radius starts; returns (x, rms, support,
    largest arc angle seen)."""
    sub = p[_subsample(np.arange(p.shape[0]), 300)]

    def resid(x: NDArray) -> NDArray:
        return _torus_dist(sub, x[0], x[1], x[2], x[4]) - x[3]

    lower = np.array([-0.5, math.radians(5.0), -10.0, 0.5 * big_r, 0.2 * big_r])
    upper = np.array([3.0, math.radians(175.0), 10.0, 2.0 * big_r, 8.0 * big_r])
    best = None
    for rb_factor in (1.25, 2.5):
        x0 = np.array([big_l, f.theta, f.phi, big_r, rb_factor * 2.0 * big_r])
        x, res, w = robust_gauss_newton(
            resid,
            x0,
            np.full(5, 1e-6),
            c=c0 * 2,
            iterations=10,
            lower=lower,
            upper=upper,
            c_final=c_fin,
        )
        rms = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9)))
        sup = int((w > 0.1).sum())
        if best is None or (sup, -rms) > (best[2], -best[1]):
            best = (x, rms, sup)
    if best is None:
        return None
    x, rms, sup = best
    res_full = _torus_dist(p, x[0], x[1], x[2], x[4]) - x[3]
    _, ang = _torus_parts(p, x[0], x[1], x[2], x[4])
    ok = np.abs(res_full) < c_fin
    vis = float(np.max(ang[ok])) if ok.any() else 0.0
    sup_full = int(ok.sum() * (p.shape[0] / max(sub.shape[0], 1)) / (p.shape[0] / sub.shape[0]))
    rms_full = float(np.sqrt(np.mean(res_full[ok] ** 2))) if ok.any() else math.inf
    return x, rms_full, int(ok.sum()) if sup_full >= 0 else sup, vis
