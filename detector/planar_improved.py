"""The improved single-plane detector (``detect_planar(..., method="improved")``).

Where thesis Algorithm 1 (:mod:`detector.planar`) thresholds forward jumps and reads the gap
size as the diameter, this method fits lines, using the clamped diameter:

1. **Plane frame.** The plane's returns are mapped into the pipe frame (known pose, else centred
   and aligned) and expressed as ``(u, v)``: ``u`` along the pipe axis, ``v`` signed across it
   in the plane (positive on the ``beta > 0`` side: the plane's sideways direction, roll
   ``alpha`` in the sensor frame, taken into the pipe frame with the pose).
2. **Walls.** A robust line is fitted to the wall returns of each side (``|v|`` near the clamped
   radius, before the structure); their mean offset and slope give the in-plane sensor offset
   and tilt, which are removed (the thesis assumes both zero), when the two lines are parallel
   and no wider apart than the diameter (else returns through an opening posed as a wall).
3. **Classes.** Returns are ``wall`` (``| |v| - R | <= tol``), ``beyond`` (farther from the
   axis) or ``inside``; ``tol`` follows the sensor noise model in ``scan.spec``.
4. **Openings.** A side with enough beyond returns has an outgoing pipe: a robust orthogonal line
   through them is that pipe's far wall; its direction gives the deflection angle. The far wall
   of a turn seen head on (inside returns, nearly parallel) gives the second wall and the
   outgoing diameter; without it the outgoing pipe has the clamped diameter. The outgoing axis
   is the mid-line (or the far wall moved in by the radius); where it crosses the incoming axis
   is the distance. Two openings, or a pipe that visibly goes on (returns on the incoming
   wall's line well beyond the structure, or far ahead near the axis, not on an outgoing
   pipe's walls), make a junction. Each return's residual is scaled to its own range noise
   (a wall seen head on takes the whole range error); where the incoming wall ends (between
   its last return and the first beam through the opening) must match the outgoing pipe's
   near wall, ``L - R tan(theta / 2)``: with it, every standard angle (45, 90, 135 deg) is
   tried, since a far opening's few returns fit them alike. A side with too few beyond
   returns for an opening still is one when they lie on the face seen ahead (an end wall
   never returns beyond the wall's line).
5. **No opening.** Inside returns on one line across the axis are a closure (end wall) at
   their mean ``u``; otherwise a reducer: the most frequent inner ``|v|`` is the new radius and
   a robust line ``|v|(u)`` through the taper gives where it starts. Beyond returns on both
   sides and nothing inside: an expansion.

Never NaN: degenerate inputs give ``straight`` with a low confidence. Metres and radians.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from detector.branches import STANDARD_BRANCH_ANGLES
from detector.detection import Detection
from detector.improved_config import ImprovedConfig
from detector.options import StructureOption
from detector.pipe_cloud import fit_confidence, radius_mode, robust_line
from detector.robust import mad_sigma, robust_gauss_newton, tukey_cost, tukey_weights
from detector.scan import Scan, corrected_ranges, radial_noise, spec_value
from detector.transforms import SensorInPipe, option_direction
from detector.vocab import Kind

#: Fewest beyond returns on a side for an opening.
MIN_OPENING_POINTS = 3
#: Fewest anomalous returns for anything but ``straight``.
MIN_ANOMALY_POINTS = 4
#: Standard fitting angles (rad) an outgoing pipe fitted within ``SNAP_WITHIN`` of is tried
#: held at, and held when the likelihood ratio against the free fit is at most ``SNAP_LR``.
STANDARD_ANGLES = tuple(float(a) for a in STANDARD_BRANCH_ANGLES)
SNAP_WITHIN = ImprovedConfig().snap_within
SNAP_LR = ImprovedConfig().snap_lr
#: An outgoing pipe fitted less deflected than this (rad) is no opening (the layouts' bends
#: turn by 30 deg or more; under range noise a few stray returns beyond one wall fit a pipe
#: leaving at 13-15 deg, whose distance spoiled a tee's).
MIN_DEFLECTION = math.radians(20.0)


def robust_tls_line(
    u: NDArray[np.float64], v: NDArray[np.float64], iterations: int = 8
) -> tuple[NDArray[np.float64], NDArray[np.float64], float, NDArray[np.float64]]:
    """Robust orthogonal line fit (Tukey-reweighted total least squares).

    Returns ``(point, direction, rms, weights)``: a point on the line, its unit direction
    ``(du, dv)`` with ``du >= 0``, the weighted RMS orthogonal residual (m) and the final
    weights.
    """
    p = np.stack([u, v], axis=1)
    w = np.ones(u.size)
    c = np.zeros(2)
    d = np.array([1.0, 0.0])
    res = np.zeros(u.size)
    for _ in range(iterations):
        sw = float(w.sum())
        if sw < 2.0:
            break
        c = (w[:, None] * p).sum(axis=0) / sw
        q = p - c
        cov = (w[:, None] * q).T @ q
        _, vec = np.linalg.eigh(cov)
        d = vec[:, 1]
        n = np.array([-d[1], d[0]])
        res = q @ n
        s = max(mad_sigma(res[w > 0]) if np.any(w > 0) else 0.0, 2e-4)
        w = tukey_weights(res, 4.685 * s)
    if d[0] < 0.0:
        d = -d
    rms = float(np.sqrt(np.sum(w * res**2) / max(float(w.sum()), 1e-9)))
    return c, d, rms, w


def _plane_lateral(pose: SensorInPipe, alpha: float) -> NDArray[np.float64]:
    """Unit pipe-frame direction across the pipe axis in the scan plane at servo angle
    ``alpha`` (radians): the plane's sideways direction (the ``beta > 0`` side, sensor frame)
    rotated into the pipe frame and made perpendicular to the axis."""
    e_sensor = np.array([0.0, math.cos(alpha), math.sin(alpha)])
    e = pose.rotation @ e_sensor
    e[0] = 0.0
    n = float(np.linalg.norm(e))
    if n < 1e-6:
        raise ValueError(
            f"scan plane at {alpha:.3f} rad is perpendicular to the pipe axis under the given "
            "sensor pose; it has no direction across the axis"
        )
    return e / n


def detect_planar_improved(
    scan: Scan,
    clamped_diameter: float,
    plane: int = 0,
    sensor_in_pipe: object = None,
    tol_floor: float = 0.002,
    noise_k: float = 3.0,
    refine_axis: bool = True,
) -> Detection:
    """The improved method on plane ``plane`` of ``scan`` (see the module docstring).

    Args:
        scan: a scan; only plane ``plane`` is used.
        clamped_diameter: inner diameter from the clamping encoders, metres.
        plane: index of the plane.
        sensor_in_pipe: known sensor pose in the pipe frame; ``None``: centred and aligned.
        tol_floor: smallest wall tolerance, metres.
        noise_k: tolerance = ``tol_floor`` + ``noise_k`` x the radial range noise.
        refine_axis: remove the in-plane offset and tilt fitted to the walls.
    """
    diag: dict[str, Any] = {"method": "improved-planar", "plane_angle": 0.0, "n_points": 0}
    try:
        det = _detect(
            scan, float(clamped_diameter), plane, sensor_in_pipe, tol_floor, noise_k,
            refine_axis, diag,
        )  # fmt: skip
    except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
        diag["error"] = f"{type(exc).__name__}: {exc}"
        det = Detection.straight(confidence=0.0, **diag)
    return det


def _detect(
    scan: Scan,
    d_clamped: float,
    plane: int,
    sensor_in_pipe: object,
    tol_floor: float,
    noise_k: float,
    refine_axis: bool,
    diag: dict[str, Any],
) -> Detection:
    big_r = 0.5 * d_clamped
    pose = SensorInPipe.coerce(sensor_in_pipe)
    alpha = float(scan.plane_angles[plane])
    diag["plane_angle"] = alpha
    valid = scan.valid[plane]
    beta = scan.beam_angles[valid]
    ranges = corrected_ranges(scan.ranges[plane][valid], spec_value(scan.spec, "bias", 0.0))
    diag["n_points"] = int(beta.size)
    if beta.size < MIN_ANOMALY_POINTS:
        diag["reason"] = "too few returns"
        return Detection.straight(confidence=0.0, **diag)
    pts = pose.to_pipe(scan.directions()[plane][valid] * ranges[:, None])
    e_lat = _plane_lateral(pose, alpha)
    u = pts[:, 0].copy()
    v = pts @ e_lat
    # per-return radial tolerance from the sensor model
    sig_range, sig_r = radial_noise(scan.spec, ranges, np.abs(np.sin(beta)), np.abs(np.cos(beta)))
    tol = tol_floor + noise_k * sig_r
    # --- in-plane offset and tilt from the two walls
    if refine_axis:
        frame = _wall_frame(u, v, big_r, float(np.median(tol)))
        if frame is not None:
            off, ang = frame
            ca, sa = math.cos(ang), math.sin(ang)
            u, v = ca * u + sa * (v - off), -sa * u + ca * (v - off)
            diag.update(plane_offset=off, plane_tilt_deg=math.degrees(ang))
    a = np.abs(v)
    e = a - big_r
    wall = np.abs(e) <= tol
    beyond = e > tol
    inside = e < -tol
    diag.update(n_wall=int(wall.sum()), n_beyond=int(beyond.sum()), n_inside=int(inside.sum()))
    if beyond.sum() + inside.sum() < MIN_ANOMALY_POINTS:
        conf = min(1.0, float(wall.sum()) / 40.0)
        return Detection.straight(confidence=conf, **diag)
    tol_med = float(np.median(tol))
    sides = []
    for sgn in (1.0, -1.0):
        m = beyond & (np.sign(v) == sgn)
        deep = m & (e > max(0.006, 0.1 * big_r))
        if m.sum() >= MIN_OPENING_POINTS and deep.sum() >= 2:
            sides.append((sgn, m))
    if sides and not (
        len(sides) == 2 and inside.sum() < 0.3 * beyond.sum() and _parallel(u, v, sides)
    ):
        return _openings(u, v, a, big_r, sides, inside, wall, e_lat, pose, tol_med, sig_range, diag)
    if not sides:
        side = _face_opening(u, v, beyond, inside, tol)
        if side is not None:
            det = _openings(
                u, v, a, big_r, [side], inside, wall, e_lat, pose, tol_med, sig_range, diag
            )
            if det.kind != Kind.STRAIGHT:
                diag["face_opening"] = True
                return det
    return detect_axisymmetric(u, a, big_r, inside, beyond, tol_med, diag)


def _face_opening(
    u: NDArray, v: NDArray, beyond: NDArray, inside: NDArray, tol: NDArray
) -> tuple[float, NDArray] | None:
    """A side opening too narrow for the count of :data:`MIN_OPENING_POINTS`: beyond returns
    of one side only, lying on the face seen ahead (inside returns on one line across the
    axis, within the tolerance). An end wall never returns beyond the wall's line, so such a
    return is a beam that went through an opening on that side and met the far wall of the
    turn seen head on (a 60 mm mitre 25-40 cm ahead shows 1-9 of them, 3-5 mm beyond the
    wall's line). ``(side, mask of its beyond returns)`` or ``None``."""
    if inside.sum() < MIN_ANOMALY_POINTS:
        return None
    face = float(np.median(u[inside]))
    near = np.abs(u[inside] - face) <= 0.003 + 2.0 * tol[inside]
    if near.mean() < 0.8:
        return None
    on_face = beyond & (np.abs(u - face) <= 0.003 + 2.0 * tol)
    signs = {float(x) for x in np.sign(v[on_face])}
    if len(signs) != 1 or np.any(beyond & ~on_face):
        return None
    sgn = signs.pop()
    return sgn, beyond & (np.sign(v) == sgn)


def _side_wall(u: NDArray, v: NDArray, sgn: float, big_r: float) -> tuple[float, float, float]:
    """Robust line ``v = a + b u`` through the nearest wall returns of side ``sgn``:
    ``(a, b, standard error of b)``; NaNs when the side has too few or too short a wall."""
    nan = (math.nan, math.nan, math.nan)
    m = (np.sign(v) == sgn) & (np.abs(np.abs(v) - big_r) < 0.3 * big_r)
    if m.sum() < 6:
        return nan
    order = np.argsort(u[m])
    keep = max(6, int(0.6 * order.size))
    um, vm = u[m][order][:keep], v[m][order][:keep]
    if float(um[-1] - um[0]) <= 0.02:
        return nan
    a, b = robust_line(um, vm, 1e-12, 2e-4)
    s = max(mad_sigma(vm - (a + b * um)), 2e-4)
    return a, b, s / math.sqrt(max(float(np.sum((um - um.mean()) ** 2)), 1e-12))


def _wall_frame(u: NDArray, v: NDArray, big_r: float, tol: float) -> tuple[float, float] | None:
    """The in-plane sensor offset (m) and tilt (rad) from the two incoming walls, or ``None``
    when they do not look like one pipe's walls: both lines must be parallel (slopes within
    three standard errors and 0.5 deg) and no farther apart than the diameter plus the
    tolerance (a plane through the pipe never sees its walls wider apart). Returns through an
    opening near the sensor (a tee's branch seen from 15-20 cm, whose far wall lies near the
    incoming wall's line) otherwise pass for a wall and tilt the frame by 1-3 deg."""
    a1, b1, s1 = _side_wall(u, v, 1.0, big_r)
    a2, b2, s2 = _side_wall(u, v, -1.0, big_r)
    if not all(math.isfinite(x) for x in (a1, b1, s1, a2, b2, s2)):
        return None
    if abs(b1 - b2) > 3.0 * math.hypot(s1, s2) + math.tan(math.radians(0.5)):
        return None
    if a1 - a2 > 2.0 * big_r + 3.0 * tol:
        return None
    off, slope = 0.5 * (a1 + a2), 0.5 * (b1 + b2)
    if abs(off) >= 0.5 * big_r or abs(slope) >= math.tan(math.radians(8.0)):
        return None
    return off, math.atan(slope)


def _parallel(u: NDArray, v: NDArray, sides: list) -> bool:
    """Both openings' far walls run along the axis (an expansion, not two branches)."""
    for _, m in sides:
        _, d, _, _ = robust_tls_line(u[m], v[m])
        if math.degrees(math.acos(min(1.0, abs(float(d[0]))))) > 20.0:
            return False
    return True


def _openings(
    u: NDArray,
    v: NDArray,
    a: NDArray,
    big_r: float,
    sides: list,
    inside: NDArray,
    wall: NDArray,
    e_lat: NDArray,
    pose: SensorInPipe,
    tol: float,
    sig_range: NDArray,
    diag: dict[str, Any],
) -> Detection:
    options: list[StructureOption] = []
    dists = []
    confs = []
    gap_diag = []
    explained = np.zeros(u.shape, dtype=bool)  # returns on an outgoing pipe's walls
    for sgn, m in sides:
        # the outgoing pipe: two walls at +-rho about an axis through (L, 0) deflected by
        # theta towards this side; its returns are the side's beyond returns and the inside
        # returns past the opening's start (the far wall of a turn seen head on)
        uc = u[m] * big_r / np.maximum(a[m], 1e-9)  # where the beams left the incoming wall
        u0 = float(np.percentile(uc, 2))
        sel = m | (inside & (u >= u0))
        pu, pv = u[sel], v[sel] * sgn
        corner = _corner(u[wall & (np.sign(v) == sgn) & (u < u0)], u0, tol)
        # a return's error lies along its beam: across a wall seen head on it is the whole
        # range noise (4.6 mm at 46 cm for the YDLidar X4), not the small radial tolerance;
        # its residual is scaled so that three of its sigmas meet the robust cut-off
        scale = np.minimum(1.0, max(tol, 0.0015) / np.maximum(3.0 * sig_range[sel], 1e-12))
        fit = _fit_outgoing(pu, pv, big_r, u0, tol, corner, scale)
        if fit is None:
            continue
        big_l, theta, rho, rms, n_sup = fit
        if not (math.isfinite(big_l) and -0.5 <= big_l <= 3.0) or theta < MIN_DEFLECTION:
            continue  # (a few stray returns beyond one wall fit a barely deflected pipe)
        conf = fit_confidence(n_sup, rms, max(tol, 1e-3), n_scale=10.0)
        # roll of the outgoing axis (in the plane, towards this side), in the sensor frame
        _, direction = option_direction(
            np.array([math.cos(theta), *(sgn * math.sin(theta) * e_lat[1:])]), pose
        )
        options.append(StructureOption("bend", big_l, 2.0 * rho, direction, theta, conf))
        dists.append(big_l)
        confs.append(conf)
        explained |= np.abs(_line_res(u, v * sgn, np.array([big_l, theta, rho]))) <= tol
        gap_diag.append({"side": sgn, "rms": rms, "support": n_sup, "rho": rho})
    diag["openings"] = gap_diag
    if not options:
        diag["reason"] = "no opening gave a physical outgoing axis"
        return Detection.straight(confidence=0.1, **diag)
    big_l = float(np.mean(dists))
    # straight on: the incoming walls seen again well beyond the structure, or a far centre;
    # returns on an outgoing pipe's walls do not count (under range noise those of a 45 deg
    # bend's outgoing wall, where it crosses the incoming wall's line, pass for that wall)
    central = (np.abs(v) <= 0.2 * big_r) & ~explained
    far_wall = wall & (u > big_l + 2.0 * big_r) & ~explained
    goes_on = bool(far_wall.sum() >= 3) or (
        bool(central.any()) and float(np.max(u[central])) > big_l + 3.0 * big_r
    )
    if goes_on:
        options.append(StructureOption("junction", big_l, 2.0 * big_r, 0.0, 0.0, min(confs)))
    kind = "bend" if len(options) == 1 else "junction"
    options = [
        StructureOption(kind, big_l if kind == Kind.JUNCTION else o.distance, o.diameter,
                        o.direction, o.angle, o.confidence)
        for o in options
    ]  # fmt: skip
    return Detection(kind, options, float(min(confs)), diag)


def _line_res(pu: NDArray, pv: NDArray, x: NDArray) -> NDArray:
    """Distance of points to the axis through ``(x[0], 0)`` at angle ``x[1]`` minus ``x[2]``."""
    qu = pu - x[0]
    return np.abs(qu * math.sin(x[1]) - pv * math.cos(x[1])) - x[2]


def _corner(u_wall: NDArray, u0: float, tol: float) -> tuple[float, float] | None:
    """Where the turn-side incoming wall ends, ``(u, sigma)`` in metres, or ``None`` when no
    wall return precedes the opening: between the last wall return before the opening and
    ``u0``, where the first beam through it crossed the wall's line (uniform between the two,
    plus the tolerance for the returns' own noise)."""
    if u_wall.size == 0:
        return None
    last = float(np.max(u_wall))
    gap = max(u0 - last, 0.0)
    return 0.5 * (last + u0), math.hypot(gap / math.sqrt(12.0), tol)


def _corner_penalty(x: NDArray, big_r: float, corner: tuple[float, float] | None) -> float:
    """Squared normalised miss of the outgoing pipe ``x = (L, theta, rho)``'s near wall, which
    meets the incoming wall at ``L - R tan(theta / 2)``, from the observed corner (0 without
    one)."""
    if corner is None:
        return 0.0
    pred = float(x[0]) - big_r * math.tan(0.5 * float(x[1]))
    return ((pred - corner[0]) / corner[1]) ** 2


def _fit_outgoing(
    pu: NDArray,
    pv: NDArray,
    big_r: float,
    u0: float,
    tol: float,
    corner: tuple[float, float] | None = None,
    scale: NDArray | None = None,
) -> tuple[float, float, float, float, int] | None:
    """Robust fit of the outgoing pipe's walls (side folded to ``v > 0``): ``(L, theta, rho,
    rms, support)``; the clamped radius unless a free one fits significantly better.
    ``corner``: the incoming wall's observed end (:func:`_corner`); ``scale``: per-return
    factors on the residuals (1: the tolerance fits the return's noise)."""
    if pu.size < 5:
        return None
    sc = np.ones(pu.size) if scale is None else scale

    def res_fn(x: NDArray) -> NDArray:
        return _line_res(pu, pv, x) * sc

    c0 = max(3.0 * tol, 0.004)
    thetas = np.radians(np.arange(15.0, 166.0, 5.0))
    l_grid = u0 + np.linspace(-0.5 * big_r, 3.0 * big_r, 15)
    qu = pu[None, :] - l_grid[:, None]  # (L, n)
    res = (
        np.abs(qu[:, :, None] * np.sin(thetas)[None, None, :] - pv[None, :, None] * np.cos(thetas))
        - big_r
    ) * sc[None, :, None]  # (L, n, T)
    cost = np.minimum(res * res, c0 * c0).mean(axis=1)
    # the turn-side incoming wall ends where the outgoing pipe's near wall meets it, at
    # L - R tan(theta / 2): this rules out the mirror solution behind a wall seen head on
    expect = l_grid[:, None] - big_r * np.tan(thetas / 2.0)[None, :]
    cost = np.where(np.abs(expect - u0) <= 0.6 * big_r, cost, np.inf)
    if not np.isfinite(cost).any():
        return None
    i_l, i_t = np.unravel_index(int(np.argmin(cost)), cost.shape)
    x0 = np.array([float(l_grid[i_l]), float(thetas[i_t]), big_r])
    c_fin = max(tol, 0.0015)
    lower = np.array([-0.5, math.radians(5.0), big_r])
    upper = np.array([3.0, math.radians(175.0), big_r])
    x_eq, r_eq, w_eq = robust_gauss_newton(
        res_fn, x0, np.array([1e-5, 1e-5, 1e-5]), c=2.0 * c0,
        iterations=10, lower=lower, upper=upper, c_final=c_fin,
    )  # fmt: skip
    lower[2], upper[2] = 0.4 * big_r, 1.6 * big_r
    x_fr, r_fr, w_fr = robust_gauss_newton(
        res_fn, x_eq, np.array([1e-5, 1e-5, 1e-5]), c=2.0 * c_fin,
        iterations=8, lower=lower, upper=upper, c_final=c_fin,
    )  # fmt: skip
    cost_eq, cost_fr = tukey_cost(r_eq, c_fin), tukey_cost(r_fr, c_fin)
    n_in = max(int((w_fr > 0.1).sum()), 1)
    sigma2 = max(2.0 * cost_fr / n_in, (0.3e-3) ** 2)
    lr = 2.0 * (cost_eq - cost_fr) / sigma2
    x, r, w = (x_fr, r_fr, w_fr) if lr > 12.0 else (x_eq, r_eq, w_eq)
    x, r, w = _snap_standard(
        res_fn, (x, r, w), c_fin, sigma2, lower, upper, free=lr > 12.0,
        corner=corner, big_r=big_r,
    )  # fmt: skip
    rms = float(np.sqrt(np.sum(w * r * r) / max(float(w.sum()), 1e-9)))
    if not np.all(np.isfinite(x)):
        return None
    return float(x[0]), float(x[1]), float(x[2]), rms, int((w > 0.1).sum())


def _snap_standard(
    res_fn: Any,
    fit: tuple[NDArray, NDArray, NDArray],
    c_fin: float,
    sigma2: float,
    lower: NDArray,
    upper: NDArray,
    free: bool,
    corner: tuple[float, float] | None = None,
    big_r: float = 0.0,
) -> tuple[NDArray, NDArray, NDArray]:
    """The outgoing pipe held at a standard fitting angle (45, 90 or 135 deg) when the
    returns allow it (likelihood ratio against the free fit at most ``SNAP_LR``): one plane's
    returns through a far opening fix the angle loosely (under YDLidar X4 noise a tee's branch
    40 cm ahead was fitted 45-135 deg), and the distance moves with it. The standard angle
    within ``SNAP_WITHIN`` of the free fit is tried; with the incoming wall's end seen
    (``corner``, see :func:`_corner`), every standard angle is, and the likelihood ratio
    counts how far each puts that end from where it was seen: the far wall's few returns
    alone fit 45, 90 and 135 deg alike, where the wall ends tells them apart.
    ``fit``: ``(x, residuals, weights)`` of the free fit, returned when no angle is held."""
    x, r, _ = fit
    theta = float(x[1])
    cands = [a for a in STANDARD_ANGLES if abs(a - theta) <= SNAP_WITHIN or corner is not None]
    pen_free = _corner_penalty(x, big_r, corner)
    best: tuple[float, tuple[NDArray, NDArray, NDArray]] | None = None
    for std in cands:
        if abs(std - theta) < 1e-9:
            return fit
        lo, hi = lower.copy(), upper.copy()
        lo[1] = hi[1] = std
        if not free:
            lo[2] = hi[2] = float(x[2])
        x0 = np.array([float(x[0]), std, float(x[2])])
        if corner is not None:
            x0[0] = _held_start(res_fn, x0, c_fin, sigma2, big_r, corner)
        x_s, r_s, w_s = robust_gauss_newton(
            res_fn, x0, np.array([1e-5, 1e-5, 1e-5]), c=2.0 * c_fin,
            iterations=8, lower=lo, upper=hi, c_final=c_fin,
        )  # fmt: skip
        if not np.all(np.isfinite(x_s)):
            continue
        lr = 2.0 * (tukey_cost(r_s, c_fin) - tukey_cost(r, c_fin)) / sigma2
        lr += _corner_penalty(x_s, big_r, corner) - pen_free
        if best is None or lr < best[0]:
            best = (lr, (x_s, r_s, w_s))
    return best[1] if best is not None and best[0] <= SNAP_LR else fit


def _held_start(
    res_fn: Any,
    x0: NDArray,
    c_fin: float,
    sigma2: float,
    big_r: float,
    corner: tuple[float, float],
) -> float:
    """Starting distance (m) of an outgoing pipe held at angle ``x0[1]`` and radius ``x0[2]``:
    the best, on a 1 mm grid within 1.5 R of where the observed corner puts it, of the robust
    cost of the returns plus the corner's miss (both in units of the noise); a start at the
    free fit's distance leaves a few far returns outside the cut-off and the fit stays
    there."""
    l_c = corner[0] + big_r * math.tan(0.5 * float(x0[1]))
    best_l, best = l_c, math.inf
    for big_l in np.arange(l_c - 1.5 * big_r, l_c + 1.5 * big_r, 0.001):
        q = np.array([float(big_l), float(x0[1]), float(x0[2])])
        cost = 2.0 * tukey_cost(res_fn(q), c_fin) / sigma2 + _corner_penalty(q, big_r, corner)
        if cost < best:
            best_l, best = float(big_l), cost
    return best_l


def detect_axisymmetric(
    u: NDArray,
    a: NDArray,
    big_r: float,
    inside: NDArray,
    beyond: NDArray,
    tol: float,
    diag: dict[str, Any],
) -> Detection:
    contraction = bool(inside.sum() >= beyond.sum())
    m = inside if contraction else beyond
    if m.sum() < MIN_ANOMALY_POINTS:
        return Detection.straight(confidence=0.3, **diag)
    um, am = u[m], a[m]
    if contraction:
        u_med = float(np.median(um))
        on = np.abs(um - u_med) <= 0.003 + 2.0 * tol
        if on.mean() >= 0.8 and float(np.min(am[on])) < 0.5 * big_r:
            up = um[on]
            conf = fit_confidence(int(on.sum()), float(np.std(up)), 0.003 + 2.0 * tol, n_scale=10.0)
            opt = StructureOption("closure", float(np.mean(up)), 0.0, 0.0, 0.0, conf)
            return Detection("closure", [opt], conf, diag)
    r2 = radius_mode(am)
    if r2 < 0.25 * big_r:
        conf = 0.3
        opt = StructureOption("closure", max(0.0, float(np.min(um))), 0.0, 0.0, 0.0, conf)
        return Detection("closure", [opt], conf, diag)
    # the taper: returns between the two radii; the line |v|(u) crosses R at its start
    lo, hi = min(r2, big_r) + tol, max(r2, big_r) - tol
    taper = (am > lo) & (am < hi)
    big_l = float(np.min(um))
    if taper.sum() >= 3:
        a0, b0 = robust_line(um[taper], am[taper], 1e-12, 2e-4)
        if abs(b0) > 1e-3:
            cand = (big_r - a0) / b0
            if math.isfinite(cand) and abs(cand - big_l) < 0.2:
                big_l = float(cand)
    diag.update(reducer_r2=r2, taper_points=int(taper.sum()))
    conf = fit_confidence(int(m.sum()), 0.0, tol, n_scale=10.0)
    opt = StructureOption("reducer", max(0.0, big_l), 2.0 * r2, 0.0, 0.0, conf)
    return Detection("reducer", [opt], conf, diag)
