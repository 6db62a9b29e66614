"""The pipe axis and its wall for the improved detector (:mod:`detector.improved`): the axis
refined by a robust fit of a cylinder to the wall returns, candidate poses compared by the wall
returns they explain, the pipe's radius measured from its wall, straight pipe told before any
other fit (every return on the wall), and where the structure starts along the axis.

Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from detector.detection import Detection
from detector.fit_kernels import MODEL_CYLINDER, wall_distances, wall_fit
from detector.grid import find_root, join_neighbours
from detector.improved_config import ImprovedConfig
from detector.pipe_cloud import (
    PipeCloud,
    covers_azimuth,
    partial_percentile,
    wall_tolerance,
)
from detector.robust import mad_sigma, median, robust_fit
from detector.transforms import SensorInPipe


# --------------------------------------------------------------------------- axis refinement
def axis_pose(params: NDArray[np.float64], sensor_origin: NDArray[np.float64]) -> SensorInPipe:
    """Correction pose: pipe frame whose axis passes through (0, y0, z0) with slopes (a, b)."""
    y0, z0, a, b = (float(v) for v in params)
    n = math.sqrt(1.0 + a * a + b * b)
    d0, d1, d2 = 1.0 / n, a / n, b / n
    # rotation taking the new axis direction d to +x (minimal rotation about d x X)
    s = math.hypot(d1, d2)
    if s < 1e-12:
        rot = np.eye(3)
    else:
        k1, k2 = d2 / s, -d1 / s
        c1 = 1.0 - d0
        rot = np.array(
            [
                [1.0 - c1, -s * k2, s * k1],
                [s * k2, 1.0 + c1 * (k1 * k1 - 1.0), c1 * k1 * k2],
                [-s * k1, c1 * k1 * k2, 1.0 + c1 * (k2 * k2 - 1.0)],
            ]
        )
    origin = np.array([0.0, y0, z0])
    # new coordinates: rot @ (p - origin), shifted along x so the sensor origin is at u = 0
    pos = -(rot @ origin)
    pos[0] -= float(rot[0] @ (sensor_origin - origin))
    return SensorInPipe.trusted(pos, rot)


def refine_wall_axis(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, u_max: float | None = None
) -> tuple[SensorInPipe, dict[str, Any]]:
    """Refine the pipe axis from the wall returns. Without ``u_max`` the nearest 60 % of the
    wall-like returns are used (a structure ahead is farther away); with it, every wall-like
    return before ``u_max`` (the start of the structure), which gives the tilt a long lever."""
    xyz = cloud.xyz_v
    info: dict[str, Any] = {"axis_points": 0}
    if xyz.shape[1] < 20:
        return cloud.pose, info
    gate = max(0.35 * big_r, 0.01)
    sub = _axis_returns(
        xyz, cloud.r_v, big_r, gate, math.nan if u_max is None else u_max, cfg.axis_points
    )
    if sub.shape[1] == 0:
        return cloud.pose, info
    # the tilt needs a lever arm: over a short stretch of wall it is not observable (and a
    # gentle taper would pass for a tilted wall), so it is held at the prior
    span = float(partial_percentile(sub[0], 95) - partial_percentile(sub[0], 5))
    tilt_sigma = cfg.prior_tilt if span >= 0.05 else math.radians(0.05)
    prior = np.array([cfg.prior_offset, cfg.prior_offset, tilt_sigma, tilt_sigma])
    info["axis_span"] = span
    x, res, w = robust_fit(
        MODEL_CYLINDER,
        sub,
        np.zeros(4),
        c=gate,
        iterations=10,
        prior_sigma=prior,
        c_final=0.004,
        step_tol=cfg.fit_step_tol,
        anneal=cfg.fit_anneal,
        cost_tol=cfg.fit_cost_tol,
        fpar=np.array([big_r]),
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
    return axis_pose(x, cloud.pose.position).compose(cloud.pose), info


@njit(cache=True)
def _axis_returns(xyz, r, big_r, gate, u_max, n_keep):
    """The wall-like returns (within ``gate`` of the radius ``big_r``, m) an axis refinement
    fits, ``(3, n)`` in their order: with ``u_max`` NaN, the nearest 60 % of them along the
    axis (at least 400); else those nearer than ``u_max`` (m); ``n_keep`` of them spread
    evenly when there are more (as :func:`detector.pipe_cloud.even_indices` picks them).
    None (``(3, 0)``) when fewer than 20, or 40 before ``u_max``, are left."""
    n = r.size
    cand = np.empty(n, dtype=np.intp)
    m = 0
    for i in range(n):
        if abs(r[i] - big_r) < gate:
            cand[m] = i
            m += 1
    if m < 20:
        return np.empty((3, 0))
    u = np.empty(m)
    for j in range(m):
        u[j] = xyz[0, cand[j]]
    if math.isnan(u_max):
        keep = max(400, int(0.6 * m))
        cut = np.inf
        if keep < m:
            cut = np.partition(u, keep - 1)[keep - 1]
        sel = u <= cut
    else:
        sel = u < u_max
        if np.count_nonzero(sel) < 40:
            return np.empty((3, 0))
    n_sel = np.count_nonzero(sel)
    n_out = min(n_sel, n_keep)
    step = n_sel / n_keep  # (even_indices: position int(i * step) of the selected ones)
    out = np.empty((3, n_out))
    k = 0  # (position among the selected returns)
    i = 0  # (next output column)
    for j in range(m):
        if sel[j]:
            if i < n_out and (n_sel <= n_keep or k == int(i * step)):
                out[0, i] = xyz[0, cand[j]]
                out[1, i] = xyz[1, cand[j]]
                out[2, i] = xyz[2, cand[j]]
                i += 1
            k += 1
    return out


def pose_moved(a: SensorInPipe, b: SensorInPipe, big_r: float) -> bool:
    """Do two poses differ by more than 2 % of the radius across or 0.2 deg in tilt?"""
    lateral = float(np.abs(a.position[1:] - b.position[1:]).max())
    tilt = float(np.abs(a.rotation[0] - b.rotation[0]).max())
    return lateral > 0.02 * big_r or tilt > math.radians(0.2)


# --------------------------------------------------------------------------- the wall
def measure_wall_radius(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, u_max: float, diag: dict[str, Any]
) -> float:
    """The pipe radius (m) the wall returns before ``u_max`` give under the current pose: their
    median distance from the axis, when at least 100 returns within ``max_radius_correction``
    (plus their tolerance) of the clamped radius ``big_r`` cover most of the circumference;
    ``big_r`` otherwise. When they scatter about it by more than a straight wall's noise
    explains, the pose may be a little off the axis: the radius is then their median distance
    with the pose error's first harmonic left out (:func:`_radius_under_pose_error`; recorded
    as ``wall_radius_pose_error``), if the harmonic is a small pose error and explains the
    scatter; ``big_r`` if not (a curved wall: no straight pipe in view). Records
    ``wall_radius`` and the returns' scatter about it (``wall_radius_rms``, 1.4826 MAD, m;
    with a pose error, about the axis that explains the wall, the pose the axis refinement
    goes on to fit) in ``diag``. Corrections below ``cfg.radius_dead_band`` are not made (the
    clamp reading is as good as the fit there)."""
    xyz = cloud.xyz_v
    idx, e_sel = _wall_returns(
        xyz[0], cloud.r_v, wall_tolerance(cloud, cfg), big_r, u_max, cfg.max_radius_correction
    )
    if idx.size < 100:
        return big_r
    de = median(e_sel)
    if not cfg.radius_dead_band <= abs(de) <= cfg.max_radius_correction:
        return big_r
    if not covers_azimuth(xyz, idx, 0.75):
        return big_r
    spread = float(mad_sigma(e_sel - de))
    limit = straight_wall_rms(cloud)
    if spread > limit:
        # (a pose a few tenths of a degree or a millimetre off the axis spreads the wall
        # about it as a first harmonic in the azimuth, growing along the axis: the radius is
        # what is left without it, when the wall is straight about the axis that explains)
        fitted = _radius_under_pose_error(xyz, idx, e_sel, big_r, cfg)
        if fitted is None or fitted[1] > limit:
            return big_r
        de, spread = fitted
        if not cfg.radius_dead_band <= abs(de) <= cfg.max_radius_correction:
            return big_r
        diag["wall_radius_pose_error"] = True
    diag["wall_radius"] = big_r + de
    diag["wall_radius_rms"] = spread
    return big_r + de


def _radius_under_pose_error(
    xyz: NDArray[np.float64],
    idx: NDArray[np.intp],
    e: NDArray[np.float64],
    big_r: float,
    cfg: ImprovedConfig,
) -> tuple[float, float] | None:
    """The wall returns ``idx`` of the ``(3, n)`` points, ``e`` (m) from the wall radius
    ``big_r`` (m), fitted as ``e = de + (a + b u) cos(phi) + (c + d u) sin(phi)`` (an axis off
    by a small offset ``(a, c)`` and tilt ``(b, d)``, to first order; ``u`` along the axis,
    ``phi`` the azimuth): ``de`` (median of what the harmonic leaves, m) and the scatter about
    it (1.4826 MAD, m); None when the fit needs a tilt beyond ``cfg.radius_pose_tilt`` (rad)
    or an offset beyond ``cfg.radius_pose_offset`` radii (returns of a structure, or too
    short a stretch of wall to tell a tilt from an offset)."""
    u = xyz[0, idx]
    phi = np.arctan2(xyz[2, idx], xyz[1, idx])
    c, s = np.cos(phi), np.sin(phi)
    design = np.stack([np.ones(u.size), c, s, u * c, u * s], axis=1)
    coef = np.linalg.lstsq(design, e, rcond=None)[0]
    if math.hypot(coef[3], coef[4]) > cfg.radius_pose_tilt:
        return None
    if math.hypot(coef[1], coef[2]) > cfg.radius_pose_offset * big_r:
        return None
    left = e - design[:, 1:] @ coef[1:]
    de = median(left)
    return de, float(mad_sigma(left - de))


@njit(cache=True)
def _wall_returns(u, r, tol, big_r, u_max, reach):
    """The returns nearer than ``u_max`` along the axis whose distance ``e`` from the wall of
    radius ``big_r`` is within ``reach`` plus their tolerance ``tol`` (m): their indices and
    ``e`` (m)."""
    n = r.size
    idx = np.empty(n, dtype=np.intp)
    e_sel = np.empty(n)
    m = 0
    for i in range(n):
        e = r[i] - big_r
        if u[i] < u_max and abs(e) <= reach + tol[i]:
            idx[m] = i
            e_sel[m] = e
            m += 1
    return idx[:m].copy(), e_sel[:m].copy()


def straight_wall_rms(cloud: PipeCloud) -> float:
    """Largest scatter (m) of wall returns about a straight cylinder that the returns' own
    noise explains: 4 x their median radial noise, at least 0.6 mm."""
    return max(4.0 * cloud.sigma_percentile(50.0), 0.0006)


def wall_consistent(cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, u_max: float) -> bool:
    """Do at least 200 returns lie before ``u_max`` (at least 15 cm) along the axis, all but
    1 % of them within the wall tolerance under the current pose?"""
    if u_max < 0.15:  # (a short stretch of wall: the first pass's wider view helps)
        return False
    n_near, n_off = _near_off_wall(
        cloud.xyz_v[0], cloud.r_v, wall_tolerance(cloud, cfg), big_r, u_max
    )
    if n_near < 200:
        return False
    return n_off <= 0.01 * n_near


@njit(cache=True)
def _near_off_wall(u, r, tol, big_r, u_max):
    """How many returns lie nearer than ``u_max`` along the axis, and how many of those lie
    off the wall of radius ``big_r`` by more than their tolerance ``tol`` (m)."""
    n_near = 0
    n_off = 0
    for i in range(u.size):
        if u[i] < u_max:
            n_near += 1
            if abs(r[i] - big_r) > tol[i]:
                n_off += 1
    return n_near, n_off


def scatter_floor(cfg: ImprovedConfig, rms: float) -> float:
    """Tolerance floor (m) for a noiseless wall fitted to ``rms`` (m): six times that
    scatter, from 0.8 mm up to the configured floor."""
    return min(cfg.tol_floor, max(0.0008, 6.0 * float(rms)))


def _thinned(
    cloud: PipeCloud, cfg: ImprovedConfig
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Every third valid return (sensor frame, ``(3, n)``) and its wall tolerance (m),
    computed once per cloud: enough to compare poses by."""
    if cloud.thin is None:
        cloud.thin = (
            np.ascontiguousarray(cloud.sensor_v[:, ::3]),
            cfg.tol_floor + cfg.noise_k * cloud.sigma_v[::3],
        )
    return cloud.thin


def count_wall_returns(
    cloud: PipeCloud,
    big_r: float,
    cfg: ImprovedConfig,
    pose: SensorInPipe,
    u_max: float,
    tol_scale: float = 1.0,
) -> tuple[int, int, float, float]:
    """Returns within ``tol_scale`` x the wall tolerance of the radius ``big_r`` under ``pose``,
    counting those nearer than ``u_max`` along the axis (all of them when fewer than 40 are),
    how many returns were counted (every third return), their truncated quadratic cost (the
    sum of ``min((e / tol)^2, 1)`` over them, ``e`` the distance from the wall, ``tol`` the
    tolerance: a return off the wall costs 1, one on it costs how far in the tolerance it
    lies), and the rms distance from the wall of those within the tolerance (m)."""
    sp, tol = _thinned(cloud, cfg)
    u, e = wall_distances(sp, pose.rotation, pose.position, big_r)
    near = u < u_max
    n_near = int(np.count_nonzero(near))
    if n_near < 40:
        near[:] = True
        n_near = int(near.size)
    n_ok, cost, rms = wall_fit(e, tol, near, tol_scale)
    return n_ok, n_near, cost, rms


def common_wall_fit(
    cloud: PipeCloud,
    big_r: float,
    cfg: ImprovedConfig,
    poses: list[SensorInPipe],
    u_max: float,
) -> list[tuple[int, int, float, float]]:
    """For each pose, what :func:`count_wall_returns` gives, over one set of returns for all: those
    nearer than ``u_max`` along the axis under every pose (a tilted pose would otherwise count
    returns the others leave out). Empty when fewer than 40 returns are in that set."""
    sp, tol = _thinned(cloud, cfg)
    walls = [wall_distances(sp, p.rotation, p.position, big_r) for p in poses]
    near = np.logical_and.reduce([u < u_max for u, _ in walls])
    n_near = int(np.count_nonzero(near))
    if n_near < 40:
        return []
    fits = []
    for _, e in walls:
        n_ok, cost, rms = wall_fit(e, tol, near, 1.0)
        fits.append((n_ok, n_near, cost, rms))
    return fits


def wall_intact(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, diag: dict[str, Any]
) -> Detection | None:
    """Straight pipe when fewer than ``min_anomaly_points`` returns leave the wall tolerance
    (no region of anomalies can reach that size, so the classification would find nothing
    else); ``None`` otherwise."""
    if cloud.n < cfg.min_anomaly_points:
        return None
    n_beyond, n_inside = _off_wall_counts(cloud.r_v, wall_tolerance(cloud, cfg), big_r)
    if n_beyond + n_inside >= cfg.min_anomaly_points:
        return None
    n_wall = cloud.n - n_beyond - n_inside
    diag["pipe_axis_sensor"] = [float(v) for v in cloud.pose.rotation[0]]
    diag["sensor_offset_pipe"] = [float(v) for v in cloud.pose.position[1:]]
    diag.update(n_wall=n_wall, n_beyond=n_beyond, n_inside=n_inside, n_anomaly=0)
    conf = min(1.0, n_wall / 200.0) * n_wall / cloud.n
    return Detection.straight(confidence=conf, **diag)


@njit(cache=True)
def _off_wall_counts(r, tol, big_r):
    """How many returns at distances ``r`` from the axis lie beyond the wall of radius
    ``big_r`` by more than their tolerance ``tol``, and how many inside it (m)."""
    n_beyond = 0
    n_inside = 0
    for i in range(r.size):
        e = r[i] - big_r
        if e > tol[i]:
            n_beyond += 1
        elif e < -tol[i]:
            n_inside += 1
    return n_beyond, n_inside


def structure_start(cloud: PipeCloud, big_r: float, cfg: ImprovedConfig) -> float:
    """Axial position where the wall stops being intact (first significant anomalies: regions
    of at least ``min_anomaly_points`` returns off the wall by more than twice their
    tolerance); the horizon when there are none."""
    g, k = cloud.shape
    n_off, entry = _off_wall_entries(
        cloud.cell,
        g,
        k,
        cloud.wraps and g >= 3,
        cloud.xyz_v[0],
        cloud.r_v,
        wall_tolerance(cloud, cfg),
        big_r,
        cfg.min_anomaly_points,
    )
    if n_off < cfg.min_anomaly_points or not entry.size:
        return cfg.horizon
    return float(partial_percentile(entry, 1)) - 0.005


@njit(cache=True)
def _off_wall_entries(cell, g, k, wraps, u, r, tol, big_r, min_points):
    """How many returns lie off the wall by more than twice their tolerance, and for those in
    regions (8-neighbourhood on the grid, joined across the row seam when ``wraps``: as
    :func:`detector.grid.label_grid`) of at least ``min_points`` of them, where along the axis
    each entered the structure: ``min(u, u R / r)``, where its beam crossed the wall radius
    (sensor near the axis). The regions are found among the returns off the wall alone
    (union-find over them, not over the whole grid); ``cell`` must strictly ascend (as a
    :class:`~detector.pipe_cloud.PipeCloud`'s cells do)."""
    n = cell.size
    off = np.empty(n, dtype=np.bool_)
    n_off = 0
    for i in range(n):
        off[i] = abs(r[i] - big_r) > 2.0 * tol[i]
        if off[i]:
            n_off += 1
    if n_off < min_points:
        return n_off, np.empty(0)
    # the off-wall returns and their grid cells (ascending, as the returns' cells ascend)
    idx = np.empty(n_off, dtype=np.int64)
    oc = np.empty(n_off, dtype=np.int64)
    m = 0
    for i in range(n):
        if off[i]:
            idx[m] = i
            oc[m] = cell[i]
            m += 1
    parent = np.arange(n_off)
    join_neighbours(oc, parent, g, k, wraps and g > 1)
    counts = np.zeros(n_off, dtype=np.int64)
    for j in range(n_off):
        counts[find_root(parent, j)] += 1
    out = np.empty(n_off)
    m = 0
    for j in range(n_off):
        if counts[find_root(parent, j)] >= min_points:
            i = idx[j]
            uc = u[i] * big_r / max(r[i], 1e-9)
            out[m] = min(u[i], uc)
            m += 1
    return n_off, out[:m]
