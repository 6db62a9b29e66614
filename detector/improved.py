"""The improved detector (``method="improved"``): model fitting in the pipe frame.

Where the thesis categorises points by radius and fits an ellipse to the outline of an opening,
this method fits the 3D geometry of the structure itself, using what the PIRATE knows: the
clamped diameter and (optionally) the sensor pose in the pipe.

1. **Pipe frame.** Every return is mapped into the pipe frame (the known ``sensor_in_pipe``
   pose, else the thesis's centred-and-aligned assumption), then the pipe axis is refined by a
   robust fit of a cylinder of the clamped radius to the wall points (4 parameters:
   cross-section offset and tilt, with a weak prior towards the known pose when the wall seen is
   short). This removes sensor misalignment (thesis 5.3) without any outside feedback; when the
   given pose already explains the wall before the structure, only the fit over that whole
   stretch of wall runs (from the given pose), not the first, wider one. A refinement is dropped
   when its cylinder misses its own wall returns by more than their noise explains, and the
   given pose stands when less than ``short_wall_view`` of straight wall is in view before the
   structure and the pose explains it (keeps ``short_wall_given_share`` of its returns within
   the tolerance; a sensor tilted a degree or two and a few millimetres off the axis keeps
   fewer, and a structure fitted where its wall drifts off is a phantom; near the start of a
   wide bend's arc a cylinder tilted about the nearest wall fits the arc), unless a refined
   axis explains as many returns and fits ``long_wall_span`` or more of straight wall to
   ``long_wall_rms`` of the scatter allowed (the given pose is then the misaligned one, its
   wall drifting off the tolerance a little way ahead). Of candidate poses explaining as
   many wall returns, the one that fits them most closely is kept (a cylinder tilted onto the
   first centimetres of a gentle taper or arc explains no more of them, only more loosely). A
   long bend's arc and a taper leave the wall so gently that the wall a pose was chosen on can
   reach a few centimetres into them: once one is fitted, the pose is chosen again on the wall
   ending 1 cm before its start (over one set of returns for every candidate pose) and the
   structure fitted again under it. The pipe's radius is measured from the wall (the wall just
   beyond the nearest returns, then the wall before the structure), within 3 mm of the clamp
   reading: the clamp's encoders read the diameter to a millimetre or two; a contraction's
   radius again on the wall before its fitted start, or the clamp's reading when too little
   wall lies there (under range noise the taper's first centimetres pass for wall). A pose
   refined onto a gentle taper under range noise, or onto the few centimetres of wall a long
   minimum range leaves before a turn, gives way to the given pose when the structure fits
   more closely under it. When fewer returns
   than a region needs leave the wall tolerance under the given pose, or else under the refined
   axis, the scan is straight pipe and nothing else runs (the common case in a run).
2. **Classification.** Each return's radial residual ``r - D/2`` is compared with a per-point
   tolerance from the sensor model in ``scan.spec`` (range noise projected on the radius, plus a
   floor; for a noiseless sensor whose wall the refined axis fits to a fraction of a millimetre,
   the floor for returns beyond the wall shrinks towards that scatter (under the given pose
   too, when it is kept), down to 0.8 mm, so the openings of small pipes far ahead show).
   Non-wall returns are grouped into connected regions of the unrolled scan grid
   (:mod:`detector.grid`); regions too small or one azimuth wide are rejected as clutter. A
   region beyond the wall that goes all round is split into its deep parts when there are two
   or more (from a tee's narrower stem, the run's wall lies a step beyond the stem's all round
   and joins both ways on).
3. **Hypotheses.** Returns beyond the wall (``r > D/2``) are *lobes*: openings towards an
   outgoing pipe. Without lobes the structure is axisymmetric: an end wall (a plane
   perpendicular to the axis, kind ``closure``; flat to within the range noise and no better
   explained by a quadratic surface with a sag of millimetres, which tells it from the curved
   far wall of a pipe seen head-on) or a reducer (a cone from the wall radius to a new radius
   fitted as ``r(u)`` together with the wall just before it; a widening starts where the line
   through its cone's rings of beams meets the wall radius (under range noise, where the rings'
   medians leave the wall), or, its cone seen by one ring or none, in the middle of the interval
   the rings allow; an end wall seen through a narrowing, spread along the axis by the range
   noise, is left out of its fit and bounds the narrow radius from below). A far wall seen
   head-on is fitted as an outgoing pipe of the clamped radius with unknown roll, seen from
   inside; when it runs on evenly to both sides it is a pipe across (both ways open); when it
   looks flat within the range noise and only its curvature tells it from an end wall, it
   overrules the end wall only as a single turn. With lobes, each lobe is an outgoing pipe: a
   cylinder whose axis meets the incoming axis at the reference point ``(L, 0, 0)`` with
   deflection ``angle``, roll ``direction`` and radius ``rho``. Initial values come from a
   coarse grid over ``(L, angle)`` with the lobe's mean roll; all lobes are then refined jointly
   by Tukey-weighted Gauss-Newton on the returns of every lobe (each return assigned to the
   surface it fits best; with two lobes on opposite sides, to the branch of its own opening:
   fitted to the nearer of two cylinders, noisy returns at the openings' rims fall between them
   and the branches lean apart for them). Two lobes on opposite sides are also fitted as one
   pipe across (a single cylinder of the clamped radius, both its ways open), which is kept
   unless the two branches fit significantly better. A single lobe is also fitted as a
   long-radius bend (a torus of bend radius ``R_b`` between the two straight pipes, the
   reference point still where the straight axes meet) when the straight axes fit it loosely or
   leave more than 5 % of its returns out, and the better fit is kept. For a noiseless sensor
   the torus is then polished on returns spread evenly along the axis (the few returns from
   the far end of the arc fix its angle; an even subsample of all returns holds two or three
   of them; the polish refines the bend, the unpolished fit decides whether there is one).
   An arc that starts right ahead fills the view with curved wall, and an axis refined on the
   nearest wall-like returns is laid into it: when the torus fits the returns
   ``torus_pose_ratio`` times as closely under the given pose, the given pose stands (as it
   does for a reducer fitting ``taper_pose_ratio`` times as closely, and for a turn right ahead
   found on less than ``short_wall_view`` of wall that fits as closely with no more ways on).
4. **Straight on.** A junction continues straight when the incoming pipe's wall is seen again
   beyond the structure (more than two diameters past the reference point) around most of the
   circumference; its option has the clamped diameter. Its side branches are no wider than the
   run, and each cuts a hole in the run's wall (half-length ``rho / sin(angle)``, centred
   ``R cot(angle)`` past the reference point, ``asin(rho / R)`` wide on either side of its
   roll, which sizes a narrower branch); when the few returns through a far opening lead
   the fit away from the hole seen, the fit restarts from the hole and stays near it. Lobes
   that start well past the nearest one belong to a structure farther along the run. A side
   hole that only one ring of beams (or two or three) enters (a small pipe's branch seen far
   away, between rings) shows as a bump of returns a millimetre or two beyond the wall on
   those rings alone; its far side places and sizes the branch (:mod:`detector.grazing`)
   when nothing nearer was found, or when a junction's branch fit rests on a handful of
   returns. A sensor that loses returns beyond its largest incidence sees no run wall past
   ``R tan(incidence)``: returns on the wall radius there come from a surface facing the
   sensor, a hole's far side, and count as a bump of their own.
   A junction's branches are held at the standard angle of fittings (90 deg for tees and
   crosses, 45 or 135 deg for laterals) when fitted within 25 deg of it and the returns do
   not reject it (likelihood ratio): a small opening far away shows a patch of the branch
   whose deflection trades against the reference point and the radius.
5. **Kind and confidence.** One way on -> ``bend``; two or more -> ``junction``. Confidence
   combines the number of supporting returns and the fit residual relative to the tolerance.
   Degenerate inputs (no returns, too few wall returns, fits that fail or leave the physical
   range) give ``straight`` with low confidence, never NaN. The exception is a scan that sees
   hardly anything ahead of the sensor where a straight pipe would show its wall to hundreds
   of beams: the pipe is blocked within the sensor's minimum range (an end wall 10 cm ahead of
   a 12 cm minimum range; anything else that near still lets beams on into the pipe beyond),
   reported as a ``closure`` no farther than where the wall ahead would start to show, with
   confidence 0.5.

Speed: a scan whose returns all lie on the wall under the given pose is straight pipe before
any fit. Returns are kept compact and component-first (one ``(3, 3) @ (3, N)`` product per
pose; their radii and tolerances cached per pose), the unrolled grid and beam directions are
cached per scan pattern, every fit uses a few hundred returns with analytic Jacobians, and the
robust fits anneal their cut-off over three iterations and then stop on a small cost change
(:func:`detector.robust.robust_gauss_newton`, Cholesky steps).

Modules: :mod:`detector.pipe_cloud` (the returns in the pipe frame, their tolerances, shared
helpers), :mod:`detector.axis_fit` (the axis refinement and the wall checks of step 1),
:mod:`detector.axisymmetric` (end walls and reducers), :mod:`detector.branches` (lobes,
outgoing pipes, junctions), :mod:`detector.long_bend` (the torus model) and
:mod:`detector.improved_config` (the tuning); this module chooses the pose, classifies the
returns and checks the pose again once a structure is fitted.

All lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.optimize import least_squares

from detector import fit_kernels
from detector.axis_fit import (
    axis_pose,
    common_wall_fit,
    count_wall_returns,
    measure_wall_radius,
    pose_moved,
    refine_wall_axis,
    scatter_floor,
    straight_wall_rms,
    structure_start,
    wall_consistent,
    wall_intact,
)
from detector.axisymmetric import detect_axisymmetric, wall_profile
from detector.branches import Lobe, detect_branches, find_lobes
from detector.detection import Detection
from detector.geometry import wrap_angle
from detector.grazing import find_ring_holes
from detector.improved_config import DEFAULT_CONFIG, ImprovedConfig
from detector.options import StructureOption, arc_start, option_order
from detector.pipe_cloud import (
    PipeCloud,
    axis_direction,
    azimuth_coverage,
    azimuth_uniformity,
    classify_counted,
    even_indices,
    fit_confidence,
    median_rise,
    partial_percentile,
    prepare_cloud,
    significant_regions,
    wall_tolerance,
)
from detector.robust import mad_sigma
from detector.scan import Scan
from detector.transforms import SensorInPipe, option_direction
from detector.validation import check_number
from detector.vocab import Kind


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
    d_clamped = check_number(
        "clamped_diameter",
        clamped_diameter,
        low=0.0,
        open_low=True,
        unit="m",
        where="detect_improved",
    )
    big_r = 0.5 * d_clamped
    pose0 = SensorInPipe.coerce(sensor_in_pipe)
    bias = float((scan.spec or {}).get("bias", 0.0)) if range_bias is None else float(range_bias)
    if not math.isfinite(bias):
        bias = 0.0
    diag: dict[str, Any] = {"method": "improved", "n_points": int(scan.n_valid)}
    try:
        cloud = prepare_cloud(scan, pose0, bias, config)
        reach = _blocked_within_min_range(scan, cloud, big_r, config)
        if reach is not None:
            diag["blocked_within_min_range"] = reach
            opt = StructureOption("closure", reach, 0.0, 0.0, 0.0, config.blind_confidence)
            return Detection("closure", [opt], config.blind_confidence, diag)
        # the given pose and the clamp reading explain every return already: straight pipe,
        # nothing to measure or refine (the common case, kept cheap)
        if refine_axis:
            diag["axis_pass"] = 0
            straight = wall_intact(cloud, big_r, config, diag)
            if straight is not None:
                return _with_ring_holes(cloud, big_r, straight)
        # the clamp's encoders read the diameter to a millimetre or two: the wall right around
        # the sensor (nearer than any structure in view) measures it first, the wall before
        # the structure again once the axis is refined
        u_nearest = partial_percentile(cloud.xyz_v[0], 1.0)
        r_clamped = big_r
        big_r = measure_wall_radius(cloud, big_r, config, u_nearest + config.near_wall, diag)
        given: GivenPose | None = None
        if refine_axis:
            chosen = _choose_pose(cloud, pose0, big_r, r_clamped, u_nearest, config, diag)
            if isinstance(chosen, Detection):
                return chosen
            big_r, given = chosen
        # (what the pose and radius left in the diagnostics, for a fit again under a new pose)
        diag_pose = dict(diag) if given is not None else diag
        det = _detect_in_pipe_frame(cloud, big_r, config, diag)
        if given is not None:
            big_r, det = _check_pose_again(cloud, det, config, diag_pose, given, big_r)
        det = _with_ring_holes(cloud, big_r, _with_opposite_way(cloud, big_r, det, config), config)
    except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:  # never crash/NaN
        diag["error"] = f"{type(exc).__name__}: {exc}"
        det = Detection.straight(confidence=0.0, **diag)
    return det


def _choose_pose(
    cloud: PipeCloud,
    pose0: SensorInPipe,
    big_r: float,
    r_clamped: float,
    u_nearest: float,
    config: ImprovedConfig,
    diag: dict[str, Any],
) -> Detection | tuple[float, GivenPose]:
    """Step 1 of the module docstring: the pose of the pipe axis (the given pose ``pose0`` or
    an axis refined from the wall), chosen by the wall returns it explains, with the pipe's
    radius measured on the wall before the structure (``big_r``: measured on the wall near the
    sensor, m; ``r_clamped``: the clamp's reading, m; ``u_nearest``: the nearest returns
    along the axis, m). The cloud is left under the chosen pose. Returns ``(radius, the given
    pose to check the choice against)``, or a straight pipe's detection when every return lies
    on the wall."""
    if big_r != r_clamped:  # (straight pipe after all, at its measured radius?)
        straight = wall_intact(cloud, big_r, config, diag)
        if straight is not None:
            return _with_ring_holes(cloud, big_r, straight)
    diag.pop("axis_pass")
    candidates: list[tuple[SensorInPipe, dict[str, Any]]] = [(pose0, {})]
    passes = [0]  # the pass each candidate pose comes from
    xyz_of = [cloud.xyz_v]
    u_start0 = structure_start(cloud, big_r, config)
    moved = False
    first_pass = not wall_consistent(cloud, big_r, config, u_start0)
    diag["axis_first_pass"] = first_pass
    if not first_pass:
        # the given pose explains the wall before the structure: only the second
        # pass (from that pose) refines it
        u_start = u_start0
    else:
        pose1, info1 = refine_wall_axis(cloud, big_r, config)
        candidates.append((pose1, info1))
        passes.append(1)
        cloud.set_pose(pose1)
        xyz_of.append(cloud.xyz_v)
        diag.update(info1)
        diag["axis_pass"] = 1
        straight = wall_intact(cloud, big_r, config, diag)
        if straight is not None:  # no return off the wall under the refined axis
            return _with_ring_holes(cloud, big_r, straight)
        for key in info1:
            diag.pop(key)
        diag.pop("axis_pass")
        u_start = structure_start(cloud, big_r, config)
        moved = pose_moved(pose0, pose1, big_r)
    # does the given pose explain the wall before the structure (seen under it, within
    # the tolerance that found the structure's start)?
    n_ok, n_seen, _, _ = count_wall_returns(cloud, big_r, config, pose0, u_start0, tol_scale=2.0)
    given_fits = n_seen >= 40 and n_ok >= 0.9 * n_seen
    # second pass: all of the intact wall before the structure (not a thin ring of it
    # right before the structure when the given pose explains the wall: where a wide
    # arc starts, already curving, the ring pulls the axis off)
    pose2, info2 = refine_wall_axis(cloud, big_r, config, u_max=u_start)
    thin_ring = info2.get("axis_span", 1.0) < 0.02
    if info2.get("axis_points", 0) >= 40 and not (thin_ring and given_fits):
        info2["axis_wall_until"] = u_start
        candidates.append((pose2, info2))
        passes.append(2)
    # keep the pose that explains the most wall returns before the structure (a fit
    # pulled by the structure's own returns, e.g. tilted onto one side of a taper,
    # explains fewer of them)
    cloud.restore(pose0, xyz_of[0])
    u_near = min(u_start, u_start0) if moved else u_start
    counts = [count_wall_returns(cloud, big_r, config, p, u_near) for p, _ in candidates]
    scores = [c[0] for c in counts]
    # a refinement whose cylinder misses its own wall returns by several times their
    # noise fitted a curved wall (the arc of a wide bend filling the whole view): the
    # given pose stands when it explains the wall
    rms_cap = straight_wall_rms(cloud)
    # (the given pose explains that wall only when it keeps most of those returns within
    # the tolerance itself, not just within twice it: a sensor tilted by a degree or two and
    # a few millimetres off the axis sees the wall drift off the tolerance a few centimetres
    # ahead, and a structure fitted there under it is a phantom)
    given_explains = given_fits and scores[0] >= config.short_wall_given_share * counts[0][1]
    for k, (_, inf) in enumerate(candidates):
        if k and given_explains and inf.get("axis_rms", 0.0) > rms_cap:
            scores[k] = -1
    # (of the poses explaining as many returns, the one that fits them most closely:
    # a cylinder tilted onto the start of a gentle taper explains no more of them, within
    # the tolerance, but fits them more loosely)
    tied = [k for k, sc in enumerate(scores) if sc == max(scores)]
    best = min(tied, key=lambda k: (counts[k][2], -k))
    if (
        best
        and u_start0 < u_nearest + config.pose_no_wall_view
        and scores[best] <= scores[0] + max(config.pose_given_margin * scores[0], 10)
    ):
        # no wall in view before the structure (the stem of a tee ending before the
        # nearest returns): a refinement that explains hardly more returns than the
        # given pose (a few of thousands) rests on the structure
        best = 0
    if best and given_fits and u_start0 - u_nearest < config.short_wall_view:
        # hardly any straight wall in view before the structure: a refinement can only
        # lean on the structure (a cylinder tilted about the nearest wall, pivoting
        # onto the arc of a turn); the given pose stands when it explains that wall,
        # unless a refinement explains as many returns and fits a long straight wall
        # to a fraction of its noise (then the given pose is the misaligned one, its
        # wall drifting off the tolerance some way ahead)
        long_straight = [
            k
            for k, sc in enumerate(scores)
            if k
            and sc >= scores[best] - max(config.pose_given_margin * scores[best], 2)
            and candidates[k][1].get("axis_span", 0.0) >= config.long_wall_span
            and candidates[k][1].get("axis_rms", 1.0) <= config.long_wall_rms * rms_cap
        ]
        best = long_straight[-1] if long_straight else (0 if given_explains else best)
    pose, info = candidates[best]
    diag.update(info)
    diag["axis_pass"] = passes[best]
    if best < len(xyz_of):
        cloud.restore(pose, xyz_of[best])
    else:
        cloud.set_pose(pose)
    given = GivenPose(pose0, xyz_of[0], big_r, u_near, r_clamped)
    big_r = measure_wall_radius(cloud, big_r, config, u_near, diag)
    # a noiseless wall fitted closely: the tolerance floor shrinks towards its scatter
    # (under the given pose, the wall returns' own scatter about it)
    rms = diag.get("wall_radius_rms", info.get("axis_rms", counts[best][3]))
    if rms is not None and cloud.sigma_percentile(90.0) < 0.0005:
        cloud.floor = scatter_floor(config, rms)
        diag["tolerance_floor"] = cloud.floor
    return big_r, given


def _blocked_within_min_range(
    scan: Scan, cloud: PipeCloud, big_r: float, cfg: ImprovedConfig
) -> float | None:
    """How far ahead (m) at most an end wall blocks the pipe within the sensor's minimum range,
    when hardly any return comes from ahead of the sensor although a straight pipe would show
    its wall to many beams there; ``None`` otherwise.

    Ahead of a sensor on the axis of a straight pipe of radius ``R``, a beam at angle ``beta``
    to the axis meets the wall at range ``R / sin(beta)``: beams whose range would lie within
    ``[min_range, max_range]`` return. A bend, a junction or a reducer near the sensor still
    sends beams on into the pipe beyond it; nothing ahead at all is an end wall nearer than
    ``sqrt(min_range^2 - R^2)``, where the wall ahead would start to show. That reach is
    returned: the end wall is no farther, its distance is not measured."""
    spec = scan.spec or {}
    min_range = float(spec.get("min_range", 0.0))
    max_range = float(spec.get("max_range", math.inf))
    if not (math.isfinite(min_range) and min_range > big_r):
        return None
    n_ahead = int(np.count_nonzero(cloud.xyz_v[0] > 0.0))
    if n_ahead > cfg.blind_max_ahead * scan.ranges.size:  # (more than any expected count allows)
        return None
    sb = np.abs(np.sin(scan.beam_angles))
    ahead = np.cos(scan.beam_angles) > 0.0
    with np.errstate(divide="ignore"):
        wall_range = big_r / sb
    seen = ahead & (wall_range >= min_range) & (wall_range <= max_range)
    expected = int(np.count_nonzero(seen)) * scan.n_planes
    if expected < cfg.blind_min_expected:
        return None
    if n_ahead > cfg.blind_max_ahead * expected:
        return None
    return math.sqrt(min_range * min_range - big_r * big_r)


def _with_ring_holes(
    cloud: PipeCloud, big_r: float, det: Detection, cfg: ImprovedConfig = DEFAULT_CONFIG
) -> Detection:
    """``det``, or a junction when one ring of beams enters side holes in the run's wall
    nearer than the structure found (more than a diameter before it and before the first
    returns off the wall, e.g. where a wide arc starts curving), or at the place of a junction
    whose branch fit the returns hardly support: a branch seen far away in a small pipe,
    between rings of beams (:mod:`detector.grazing`). Each branch leaves at the standard
    fitting angle (90, 45 or 135 deg) whose far side fits the bump best; the run goes on past
    them (the rings beyond lie on its wall)."""
    # (cheap tests first: too few returns beyond the wall at all, or nearer than the limit)
    beyond, n_beyond = _beyond_bump(
        cloud.r_v, cloud.sigma_v, big_r, cfg.hole_min_step, cfg.hole_noise_k
    )
    unseen = _past_incidence(cloud, big_r, cfg)
    if unseen is not None:
        beyond |= unseen
        n_beyond = int(np.count_nonzero(beyond))
    if n_beyond < 6:
        return det
    support = det.diagnostics.get("fit_support")
    weak = (
        det.kind == Kind.JUNCTION
        and support is not None
        and support < max(30, 0.5 * det.diagnostics.get("fit_points", 0))
    )
    if weak:
        # a junction whose branches the returns through its openings hardly support (most of
        # them outliers of the fit): the holes at its place, if a ring shows them, place it
        # (within two diameters of its place; the far sides lie up to a diameter farther on)
        before = det.distance + 4.0 * big_r
        beyond &= cloud.xyz_v[0] < before + 2.0 * big_r
        if np.count_nonzero(beyond) < 6:
            return det
    elif det.options:
        before = det.distance - 2.0 * big_r
        beyond &= cloud.xyz_v[0] < before
        if np.count_nonzero(beyond) < 6:
            return det
        before = min(before, structure_start(cloud, big_r, cfg) - 2.0 * big_r)
        beyond &= cloud.xyz_v[0] < before
        if np.count_nonzero(beyond) < 6:
            return det
    else:
        before = float(np.max(cloud.xyz_v[0]))
    # the bumps are a fraction of a millimetre: only under a pose that fits the wall before
    # them that closely (a sensor millimetres off the axis, not refined away, bends every ring)
    near = cloud.xyz_v[0] < before
    e_near = (cloud.r_v - big_r)[near]
    if e_near.size < 50 or mad_sigma(e_near) > max(
        0.0003, 3.0 * partial_percentile(cloud.sigma_v[near], 50.0)
    ):
        return det
    # only the rings that hold such returns, and their neighbours
    cols = cloud.cell[beyond] % cloud.shape[1]
    c0, c1 = max(int(cols.min()) - 1, 0), min(int(cols.max()) + 2, cloud.shape[1])
    holes = find_ring_holes(
        cloud.xyz[:, :, c0:c1],
        cloud.valid[:, c0:c1],
        cloud.sigma_r[:, c0:c1],
        cloud.wraps,
        big_r,
        before,
        cloud.beam_step,
        cfg,
        cloud.sigma_range_grid()[:, c0:c1],
        None if unseen is None else cloud.grid(unseen, False)[:, c0:c1],
    )
    if not holes or (weak and len(holes) < sum(not o.is_straight_on for o in det.options)):
        return det  # (nothing, or fewer ways than the openings the fit had to explain)
    places = np.array([h.position for h in holes])
    position = float(np.mean(places))
    if float(np.ptp(places)) > big_r or (weak and abs(position - det.distance) > 3.0 * big_r):
        # the branches of one junction leave the run at one place, and the openings the fit
        # explained poorly are still the openings of that junction
        return det
    conf = min(fit_confidence(h.n, h.rms, 0.001) for h in holes)
    options = [StructureOption("junction", position, 2.0 * big_r, 0.0, 0.0, conf)]
    for h in holes:
        angle, direction = option_direction(axis_direction(h.angle, h.roll), cloud.pose)
        options.append(
            StructureOption("junction", h.position, 2.0 * h.radius, direction, angle, conf)
        )
    options.sort(key=option_order)
    diag = dict(det.diagnostics)
    diag.update(
        model="ring holes",
        ring_holes=[
            {
                "position": h.position,
                "radius": h.radius,
                "roll": h.roll,
                "angle": h.angle,
                "n": h.n,
                "rms": h.rms,
            }
            for h in holes
        ],
        replaced_kind=det.kind,
    )
    return Detection("junction", options, conf, diag)


def _past_incidence(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig
) -> NDArray[np.bool_] | None:
    """Which returns (compact order) lie on the wall radius ``big_r`` (m, within
    ``cfg.hole_wall_band`` and ``cfg.hole_noise_k`` times their radial noise) where the beam
    would meet a straight wall beyond the sensor's largest incidence (plus
    ``cfg.incidence_jitter_k`` times its beam-angle jitter): no straight wall returns there,
    so they come from a surface facing the sensor, the far side of a hole in the wall (a
    branch far ahead of a sensor that loses the grazing wall around it). ``None`` when the
    sensor returns at any incidence."""
    limit = cloud.max_incidence + cfg.incidence_jitter_k * cloud.angular_jitter
    if limit >= 0.5 * math.pi:
        return None
    position = np.asarray(cloud.pose.position, dtype=float)
    return _past_incidence_kernel(
        cloud.xyz_v, cloud.r_v, cloud.sigma_v, position[0], position[1], position[2], big_r,
        cfg.hole_wall_band, cfg.hole_noise_k, math.cos(limit),
    )  # fmt: skip


@njit(cache=True)
def _past_incidence_kernel(xyz, r_v, sigma, p0, p1, p2, big_r, band, noise_k, cos_limit):
    """:func:`_past_incidence` for the points ``xyz`` ((3, N), pipe frame) at distances
    ``r_v`` from the axis, seen from the sensor at ``(p0, p1, p2)``: one pass."""
    n = r_v.size
    out = np.empty(n, dtype=np.bool_)
    for i in range(n):
        d0 = xyz[0, i] - p0
        d1 = xyz[1, i] - p1
        d2 = xyz[2, i] - p2
        r = max(r_v[i], 1e-12)
        # (the cosine of the incidence on a straight wall: the beam on the wall's normal)
        across = abs(d1 * xyz[1, i] + d2 * xyz[2, i]) / r
        length = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        on_wall = abs(r_v[i] - big_r) <= band + noise_k * sigma[i]
        out[i] = on_wall and d0 > 0.0 and across < cos_limit * length
    return out


@njit(cache=True)
def _beyond_bump(r, sigma, big_r, min_step, noise_k):
    """Which returns at distances ``r`` from the axis lie beyond the wall of radius ``big_r``
    by more than ``min_step`` and ``noise_k`` times their radial noise ``sigma`` (m), and how
    many."""
    out = np.empty(r.size, dtype=np.bool_)
    n = 0
    for i in range(r.size):
        out[i] = r[i] - big_r > max(min_step, noise_k * sigma[i])
        if out[i]:
            n += 1
    return out, n


# --------------------------------------------------------------------------- the pose again
@dataclass(frozen=True)
class GivenPose:
    """What a check of the chosen pose goes back to: the given pose, its points (``(3, N)``,
    pipe frame), the pipe radius (m), how far along the axis the wall the pose was chosen on
    reaches (m), and the clamp's reading of the radius (m)."""

    pose: SensorInPipe
    xyz: NDArray[np.float64]
    radius: float
    wall_until: float
    clamped_radius: float


def _gentle_start(det: Detection) -> float | None:
    """Where a structure that leaves the wall gradually starts, m along the axis: a long
    bend's arc (``bend_radius x tan(angle / 2)`` before its reference point), a reducer's
    taper; ``None`` for the others (their walls break off)."""
    if det.kind == Kind.REDUCER and det.options:
        return det.options[0].distance
    if det.kind == Kind.BEND and len(det.options) == 1 and det.options[0].bend_radius > 0.0:
        return arc_start(det.options[0])
    return None


def _pose_diagnostics(diag_pose: dict[str, Any], axis_info: dict[str, Any]) -> dict[str, Any]:
    """The diagnostics of the first pose choice with its pose, radius and floor entries
    replaced by ``axis_info`` (a detection again starts from them)."""
    skip = ("axis_", "wall_radius", "tolerance_floor")
    sub = {k: v for k, v in diag_pose.items() if not k.startswith(skip)}
    sub.update(axis_info)
    return sub


def _detect_again(
    cloud: PipeCloud,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    axis_info: dict[str, Any],
    big_r: float,
    wall_until: float,
    floor: float | None,
    wall_rms: Callable[[float], float],
) -> tuple[float, Detection]:
    """Detect again under the pose a check moved the cloud to: the diagnostics of the first
    pose choice (``diag_pose``) with its axis entries replaced by ``axis_info``, the radius
    measured on the wall before ``wall_until`` (m), and for a noiseless wall (a tolerance
    ``floor`` was set) the floor from the wall's scatter (``wall_rms(radius)``, m, when the
    radius fit measured none). Returns ``(radius, detection)``."""
    sub = _pose_diagnostics(diag_pose, axis_info)
    radius = measure_wall_radius(cloud, big_r, cfg, wall_until, sub)
    if floor is not None:
        rms = sub.get("wall_radius_rms")
        cloud.floor = scatter_floor(cfg, wall_rms(radius) if rms is None else rms)
        sub["tolerance_floor"] = cloud.floor
    return radius, _detect_in_pipe_frame(cloud, radius, cfg, sub)


def _start_recheck(
    cloud: PipeCloud,
    det: Detection,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    given: GivenPose,
    big_r: float,
) -> tuple[float, Detection] | None:
    """A long-radius bend's arc, or a gentle taper, leaves the straight wall so slowly that its
    first centimetres lie within the wall tolerance: the pose was chosen on wall returns up to
    ``wall_until`` (m along the axis), past where the fitted arc or taper starts, and an axis
    refined on them leans onto it (1-2 deg). Choose again on the wall before that start (the
    given pose, the chosen one, or the axis refined there): the most returns within the
    tolerance, then the closest fit. ``(radius, detection)`` under the new pose when it moved
    and the structure kept its kind, else ``None`` (the cloud keeps its pose)."""
    pose0, xyz0, big_r, wall_until = given.pose, given.xyz, given.radius, given.wall_until
    start = _gentle_start(det)
    if start is None or (det.kind == Kind.REDUCER and cloud.floor is None):
        # (a reducer under range noise: its tolerance is the noise's, and a pose chosen again
        # on less wall sizes the wider pipe no better)
        return None
    u_cap = start - cfg.gentle_start_margin
    if u_cap >= wall_until:
        return None
    chosen, xyz_chosen = cloud.pose, cloud.xyz_v
    floor = cloud.floor
    refined, info = refine_wall_axis(cloud, big_r, cfg, u_max=u_cap)
    poses = [chosen, pose0] + ([refined] if info.get("axis_points", 0) >= 40 else [])
    fits = common_wall_fit(cloud, big_r, cfg, poses, u_cap)
    if not fits:  # (too little wall before the arc to choose on)
        return None
    best = max(range(len(poses)), key=lambda k: (fits[k][0], -fits[k][2]))
    if best == 0 or not pose_moved(chosen, poses[best], big_r):
        return None
    if best == 1:
        cloud.restore(pose0, xyz0)
        axis_info: dict[str, Any] = {"axis_pass": 0}
    else:
        cloud.set_pose(refined)
        axis_info = {**info, "axis_pass": 3, "axis_wall_until": u_cap}
    wall_rms = fits[best][3]
    radius, redone = _detect_again(
        cloud, cfg, diag_pose, axis_info, big_r, u_cap, floor, lambda _: wall_rms
    )
    if redone.kind != det.kind:  # (the structure stands; so does the pose it was found under)
        cloud.restore(chosen, xyz_chosen)
        cloud.floor = floor
        return None
    redone.diagnostics["start_recheck"] = True
    return radius, redone


def _torus_pose_check(
    cloud: PipeCloud,
    det: Detection,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    given: GivenPose,
    big_r: float,
) -> tuple[float, Detection] | None:
    """A long-radius bend whose arc starts a few centimetres ahead fills the view with curved
    wall: an axis refined on the nearest wall-like returns is a cylinder laid into the arc's
    start (up to 2 cm off centre), and the torus fitted under it misses its returns by a
    millimetre where the right pose leaves a tenth of that. When the pose moved from the given
    one and the bend's torus fits the returns under the given pose at most
    ``cfg.torus_pose_ratio`` times as loosely (rms), the given pose and its detection stand.
    ``(radius, detection)`` then, else ``None`` (the cloud keeps its pose)."""
    rms = det.diagnostics.get("torus_rms")
    if det.kind != Kind.BEND or det.diagnostics.get("model") != "torus" or rms is None:
        return None

    def stands(redone: Detection) -> float | None:
        rms0 = redone.diagnostics.get("torus_rms")
        ok = (
            redone.kind == det.kind
            and redone.diagnostics.get("model") == "torus"
            and rms0 is not None
            and rms0 * cfg.torus_pose_ratio <= rms
        )
        return rms0 if ok else None

    return _given_pose_again(cloud, cfg, diag_pose, given, "torus_pose_check", rms, stands)


def _given_pose_again(
    cloud: PipeCloud,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    given: GivenPose,
    check: str,
    chosen_rms: float,
    stands: Callable[[Detection], float | None],
) -> tuple[float, Detection] | None:
    """Detect again under the given pose when the chosen pose moved from it: ``(radius,
    detection)`` when ``stands(detection)`` gives the given pose's fit rms (m; ``None``: the
    chosen pose stands), recorded with ``chosen_rms`` under ``check`` in its diagnostics; else
    ``None`` with the cloud back under the chosen pose."""
    pose0, xyz0, big_r, wall_until = given.pose, given.xyz, given.radius, given.wall_until
    chosen, xyz_chosen, floor = cloud.pose, cloud.xyz_v, cloud.floor
    if not pose_moved(chosen, pose0, big_r):
        return None
    cloud.restore(pose0, xyz0)
    radius, redone = _detect_again(
        cloud,
        cfg,
        diag_pose,
        {"axis_pass": 0},
        big_r,
        wall_until,
        floor,
        lambda r: count_wall_returns(cloud, r, cfg, pose0, wall_until)[3],
    )
    given_rms = stands(redone)
    if given_rms is not None:
        redone.diagnostics[check] = {"chosen_rms": chosen_rms, "given_rms": given_rms}
        return radius, redone
    cloud.restore(chosen, xyz_chosen)
    cloud.floor = floor
    return None


def _fit_rms(det: Detection) -> float | None:
    """How closely the model of ``det`` fits its returns (rms, m): a reducer's taper, a turn's
    or junction's axes; ``None`` for the others."""
    if det.kind not in (Kind.REDUCER, Kind.BEND, Kind.JUNCTION):
        return None
    key = "reducer_rms" if det.kind == Kind.REDUCER else "fit_rms"
    rms = det.diagnostics.get(key)
    return float(rms) if rms is not None else None


def _taper_pose_check(
    cloud: PipeCloud,
    det: Detection,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    given: GivenPose,
    big_r: float,
) -> tuple[float, Detection] | None:
    """Under range noise the first centimetres of a gentle taper lie within the wall
    tolerance, so the wall the pose was chosen on runs onto it, and an axis refined there leans
    onto its near side (0.3-4 deg): the narrower pipe comes out too wide (60-77 mm for 55), or
    the taper's far side passes for a turn that fits half its returns. When the pose moved
    from the given one and found a reducer, or a turn or junction keeping less than
    ``cfg.taper_pose_poor_support`` of its returns, detect again under the given pose: its
    reducer stands when it keeps ``cfg.taper_pose_min_support`` of its returns and fits them at
    least ``cfg.taper_pose_ratio`` times as closely (rms). ``(radius, detection)`` then, else
    ``None`` (the cloud keeps its pose)."""
    rms = _fit_rms(det)
    if rms is None or det.diagnostics.get("start_recheck"):
        return None
    if det.kind != Kind.REDUCER and _fit_share(det) >= cfg.taper_pose_poor_support:
        return None

    def stands(redone: Detection) -> float | None:
        rms0 = _fit_rms(redone)
        ok = (
            redone.kind == Kind.REDUCER
            and rms0 is not None
            and redone.diagnostics.get("axisymmetric_support", 0.0) >= cfg.taper_pose_min_support
            and rms0 * cfg.taper_pose_ratio <= rms
        )
        return rms0 if ok else None

    return _given_pose_again(cloud, cfg, diag_pose, given, "taper_pose_check", rms, stands)


def _short_wall_pose_check(
    cloud: PipeCloud,
    det: Detection,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    given: GivenPose,
    big_r: float,
) -> tuple[float, Detection] | None:
    """A structure right ahead of a sensor with a long minimum range leaves a few centimetres
    of wall in view (a mitre bend 10 cm ahead of a ydlidar_x4, 12 cm): an axis refined on them
    takes in the outgoing pipe's first returns and moves 5-7 mm off the centre, and the bend's
    far side then reads as a second way on (a pipe across). When the pose moved from the given
    one on less than ``cfg.short_wall_view`` of wall and found a turn or a junction, detect
    again under the given pose: its turn or junction stands when it has no more ways on and fits
    its returns at least as closely (rms), keeping as large a share of them (less
    ``cfg.short_wall_share_slack``). ``(radius, detection)`` then, else ``None`` (the cloud
    keeps its pose)."""
    rms = _fit_rms(det)
    span = det.diagnostics.get("axis_span")
    if det.kind not in (Kind.BEND, Kind.JUNCTION) or rms is None or span is None:
        return None
    if span >= cfg.short_wall_view or det.diagnostics.get("axis_pass", 0) == 0:
        return None
    if det.diagnostics.get("start_recheck") or det.diagnostics.get("model") == "torus":
        return None  # (chosen again on the wall before its arc; a torus has its own check)

    def stands(redone: Detection) -> float | None:
        rms0 = _fit_rms(redone)
        ok = (
            redone.kind in (Kind.BEND, Kind.JUNCTION)
            and rms0 is not None
            and len(redone.options) <= len(det.options)
            and rms0 <= rms
            and _fit_share(redone) >= _fit_share(det) - cfg.short_wall_share_slack
        )
        return rms0 if ok else None

    return _given_pose_again(cloud, cfg, diag_pose, given, "short_wall_pose_check", rms, stands)


def _outlet_pose(cloud: PipeCloud, big_r: float, cfg: ImprovedConfig) -> SensorInPipe | None:
    """The pipe axis from the narrower pipe beyond a contraction: a cylinder of free radius
    fitted (robust least squares, soft cut-off ``cfg.outlet_fit_scale``) to the returns inside
    the wall of radius ``big_r`` (m) between the percentiles ``cfg.outlet_from`` and
    ``cfg.outlet_until`` of their distance along the axis (past the taper, short of what lies
    beyond the pipe), at most ``cfg.axis_points`` of them, chosen again under the fitted axis
    and fitted again
    (``cfg.outlet_fits`` fits: under a tilted axis part of the narrower pipe's wall lies beyond
    the wall radius, and the first fit leans away from it). ``None`` when fewer than
    ``cfg.outlet_min_returns`` returns lie there or the fit leaves the physical range (a radius
    not below ``big_r``, off the incoming axis by more than the pipe's radius, tilted by more
    than ``cfg.outlet_max_tilt``). Leaves the cloud under the fitted axis (or a part of the way
    there)."""
    start = cloud.pose
    for _ in range(cfg.outlet_fits):
        x = _outlet_fit(cloud, big_r, cfg)
        if x is None:
            return None
        cloud.set_pose(axis_pose(x[:4], cloud.pose.position).compose(cloud.pose))
    pose = cloud.pose
    # (the physical range: relative to the pose the check started from)
    axis = pose.rotation[0] @ start.rotation[0]
    if axis < math.cos(cfg.outlet_max_tilt):
        return None
    return pose


def _outlet_fit(cloud: PipeCloud, big_r: float, cfg: ImprovedConfig) -> NDArray[np.float64] | None:
    """One fit of :func:`_outlet_pose` under the cloud's pose: ``(y0, z0, a, b, radius)``
    (the correction's axis offset, m, and slopes, and the narrower pipe's radius, m)."""
    u, r = cloud.xyz_v[0], cloud.r_v
    inside = r < big_r - wall_tolerance(cloud, cfg)
    if np.count_nonzero(inside) < 2 * cfg.outlet_min_returns:
        return None
    # (not the farthest returns: an end wall or a structure down the narrower pipe)
    u_in = u[inside]
    far = (
        inside
        & (u > partial_percentile(u_in, cfg.outlet_from))
        & (u < partial_percentile(u_in, cfg.outlet_until))
    )
    sub = cloud.xyz_v[:, far]
    sub = sub[:, even_indices(sub.shape[1], cfg.axis_points)]
    if sub.shape[1] < cfg.outlet_min_returns:
        return None
    # the distance to the axis through (0, y0, z0) along (1, a, b) less the radius: the
    # compiled wall-cylinder model, its radius a fifth parameter (d r / d radius = -1)
    data = np.ascontiguousarray(sub)
    n = data.shape[1]
    res, jt = np.empty(n), np.empty((5, n))
    jt[4] = -1.0

    def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
        fit_kernels.model_eval(
            fit_kernels.MODEL_CYLINDER, data, fit_kernels.NO_INTS, x[4:5], x[:4], res, jt, False
        )
        return res.copy()

    def jacobian(x: NDArray[np.float64]) -> NDArray[np.float64]:
        fit_kernels.model_eval(
            fit_kernels.MODEL_CYLINDER, data, fit_kernels.NO_INTS, x[4:5], x[:4], res, jt, True
        )
        return jt.T.copy()

    x0 = np.array([0.0, 0.0, 0.0, 0.0, float(np.median(np.hypot(sub[1], sub[2])))])
    fit = least_squares(residuals, x0, jac=jacobian, loss="soft_l1", f_scale=cfg.outlet_fit_scale)
    x = fit.x
    if not (fit.success and np.all(np.isfinite(x)) and 0.0 < x[4] < big_r):
        return None
    if math.hypot(x[0], x[1]) > big_r or math.hypot(x[2], x[3]) > math.tan(cfg.outlet_max_tilt):
        return None
    return x


def _outlet_pose_check(
    cloud: PipeCloud,
    det: Detection,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    given: GivenPose,
    big_r: float,
) -> tuple[float, Detection] | None:
    """A sensor tilted by 2-3 deg a few centimetres before a concentric contraction sees no
    wall before its taper (the minimum range): neither the given pose nor an axis refined on
    the taper is the pipe's, and under them one side of the cone and of the narrower pipe lies
    beyond the wall radius and the other inside, which reads as a 25 deg turn keeping a fraction
    of its returns. The narrower pipe is coaxial with the incoming one: when a turn (or a
    junction) keeps less than ``cfg.taper_pose_poor_support`` of its returns and most of the
    returns off the wall lie inside it, the axis is fitted to the narrower pipe
    (:func:`_outlet_pose`) and the structure detected again; its reducer stands when it keeps
    ``cfg.taper_pose_min_support`` of its returns and fits them at least as closely (rms).
    ``(radius, detection)`` then, else ``None`` (the cloud keeps its pose)."""
    rms = _fit_rms(det)
    g = det.diagnostics
    if det.kind not in (Kind.BEND, Kind.JUNCTION) or rms is None:
        return None
    if _fit_share(det) >= cfg.taper_pose_poor_support:
        return None
    if g.get("n_inside", 0) < cfg.outlet_inside_share * (
        g.get("n_inside", 0) + g.get("n_beyond", 0)
    ):
        return None
    chosen, xyz_chosen, floor = cloud.pose, cloud.xyz_v, cloud.floor
    if _outlet_pose(cloud, big_r, cfg) is None:
        cloud.restore(chosen, xyz_chosen)
        return None
    sub = _pose_diagnostics(diag_pose, {"axis_pass": 4})
    if floor is not None:
        sub["tolerance_floor"] = floor
    redone = _detect_in_pipe_frame(cloud, big_r, cfg, sub)
    rms0 = _fit_rms(redone)
    if (
        redone.kind == Kind.REDUCER
        and rms0 is not None
        and rms0 <= rms
        and redone.diagnostics.get("axisymmetric_support", 0.0) >= cfg.taper_pose_min_support
    ):
        redone.diagnostics["outlet_pose_check"] = {"chosen_rms": rms, "outlet_rms": rms0}
        return big_r, redone
    cloud.restore(chosen, xyz_chosen)
    cloud.floor = floor
    return None


def _fit_share(det: Detection) -> float:
    """The share of its returns a turn's or junction's fit keeps (0 when unknown)."""
    g = det.diagnostics
    return float(g.get("fit_support", 0)) / max(float(g.get("fit_points", 1)), 1.0)


def _taper_radius_check(
    cloud: PipeCloud,
    det: Detection,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    given: GivenPose,
    big_r: float,
) -> tuple[float, Detection] | None:
    """Under range noise the first centimetres of a gentle contraction lie within the wall
    tolerance, and the pipe radius measured on the wall up to where the returns leave it takes
    them in: it comes out short (by up to 3.5 mm in a 100 mm pipe), and the taper's fitted start
    moves on (1-3 cm). Measure the radius again on the wall before the fitted start (the
    clamp's reading, m, when too little wall lies there) and detect again.
    ``(radius, detection)`` when the radius changed and the structure is still a reducer, else
    ``None`` (the detection under radius ``big_r`` stands)."""
    if det.kind != Kind.REDUCER or not det.options or det.diagnostics.get("start_recheck"):
        return None
    opt = det.options[0]
    if opt.diameter >= 2.0 * big_r:  # (a widening: its start is where the beams leave the wall)
        return None
    u_cap = opt.distance - cfg.gentle_start_margin
    # (the pose and the tolerance floor stand: only the radius is measured again)
    records = ("axis_", "tolerance_", "taper_pose_check", "short_wall_pose_check")
    sub = _pose_diagnostics(
        diag_pose, {k: v for k, v in det.diagnostics.items() if k.startswith(records)}
    )
    radius = measure_wall_radius(cloud, given.clamped_radius, cfg, u_cap, sub)
    if abs(radius - big_r) < cfg.radius_dead_band:
        return None
    redone = _detect_in_pipe_frame(cloud, radius, cfg, sub)
    if redone.kind != Kind.REDUCER:
        return None
    redone.diagnostics["taper_radius_check"] = {"radius_before": big_r, "radius": radius}
    return radius, redone


#: A check of the chosen pose: ``(cloud, detection, config, diagnostics of the pose choice,
#: the given pose, the pipe radius (m))`` -> ``(radius, detection)`` found again under another
#: pose or radius, or ``None`` when the detection stands.
PoseCheck = Callable[
    [PipeCloud, Detection, ImprovedConfig, dict[str, Any], GivenPose, float],
    "tuple[float, Detection] | None",
]

#: The checks of the chosen pose, in order; each sees the detection the ones before left.
POSE_CHECKS: tuple[tuple[str, PoseCheck], ...] = (
    ("start_recheck", _start_recheck),
    ("torus_pose_check", _torus_pose_check),
    ("taper_pose_check", _taper_pose_check),
    ("short_wall_pose_check", _short_wall_pose_check),
    ("outlet_pose_check", _outlet_pose_check),
    ("taper_radius_check", _taper_radius_check),
)


def _check_pose_again(
    cloud: PipeCloud,
    det: Detection,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    given: GivenPose,
    big_r: float,
) -> tuple[float, Detection]:
    """The detection ``det`` (radius ``big_r``, m) after the checks of :data:`POSE_CHECKS`:
    ``(radius, detection)``."""
    for _, check in POSE_CHECKS:
        redone = check(cloud, det, cfg, diag_pose, given, big_r)
        if redone is not None:
            big_r, det = redone
    return big_r, det


# --------------------------------------------------------------------------- classification
def _detect_in_pipe_frame(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, diag: dict[str, Any]
) -> Detection:
    diag["pipe_axis_sensor"] = [float(v) for v in cloud.pose.rotation[0]]
    diag["sensor_offset_pipe"] = [float(v) for v in cloud.pose.position[1:]]
    # (the tolerance: the residual axis error grows with the distance along the axis)
    tol, wall, beyond, inside, n_wall, n_beyond, n_inside = classify_counted(cloud, big_r, cfg)
    n_valid = cloud.n
    diag.update(n_wall=n_wall, n_beyond=n_beyond, n_inside=n_inside)
    if n_valid < cfg.min_anomaly_points:
        diag["reason"] = "too few returns"
        return Detection.straight(confidence=0.0, **diag)
    # significant anomaly regions (regions with no inside returns keep their labels among the
    # returns beyond the wall: ``pre``)
    _, n_lab, keep, n_keep, beyond_k, inside_k, pre_labels = significant_regions(
        beyond, inside, cloud.wraps, cfg.min_anomaly_points, cfg.min_region_rows
    )
    diag["n_anomaly"] = n_keep
    wall_frac = float(n_wall) / max(n_valid, 1)
    if n_keep < cfg.min_anomaly_points:
        conf = min(1.0, float(n_wall) / 200.0) * wall_frac
        return Detection.straight(confidence=conf, **diag)
    pre = None if pre_labels is None else (pre_labels, n_lab)
    lobes = find_lobes(cloud, beyond_k, big_r, cfg, pre)
    diag["n_lobes"] = len(lobes)
    if lobes:
        # an expansion: returns beyond the wall all around and hardly any inside
        p_beyond = cloud.points(beyond_k)
        cov = azimuth_coverage(p_beyond)
        uniform = azimuth_uniformity(p_beyond)
        diag.update(beyond_coverage=cov, beyond_uniformity=uniform)
        # (inside returns count only near the start of the widening: an end wall far down
        # the wider pipe is not part of the structure)
        u_grid = cloud.u_grid
        u_start = partial_percentile(u_grid[beyond_k], 5.0)
        inside_near = inside_k & (u_grid <= u_start + 4.0 * big_r)
        if uniform >= 0.3 and np.count_nonzero(inside_near) < 0.3 * np.count_nonzero(beyond_k):
            return detect_axisymmetric(cloud, big_r, inside_near, beyond_k, wall, tol, cfg, diag)
        if _shallow_widening(cloud, big_r, lobes, inside_k, cfg, diag):
            # (with every inside return: the wider pipe's end wall, far down it, is what
            # takes the structure to the end wall's test and the wall's profile there)
            return detect_axisymmetric(cloud, big_r, inside_k, beyond_k, wall, tol, cfg, diag)
        return detect_branches(cloud, big_r, lobes, keep, wall, tol, cfg, diag)
    det = detect_axisymmetric(cloud, big_r, inside_k, beyond_k, wall, tol, cfg, diag)
    if det.diagnostics.get("axisymmetric_support", 1.0) >= 0.6:
        return det
    # neither an end wall nor a reducer: the far wall of a turn seen head-on (small pipes, far
    # away): fit an outgoing pipe to the inner returns with unknown roll
    pseudo = Lobe(inside_k, 0.0, int(np.count_nonzero(inside_k)))
    alt = detect_branches(cloud, big_r, [pseudo], keep, wall, tol, cfg, dict(diag), any_roll=True)
    if det.diagnostics.get("closure_tentative", False):
        # a wall that looks flat within the range noise but curves: the far wall of a turn
        # when the fit finds one way on; a pipe across (or a 90 deg turn: the same far wall)
        # is too ambiguous to overrule the end wall
        undetermined = alt.diagnostics.get("reason") == "far wall: way on undetermined"
        if undetermined or alt.kind == Kind.JUNCTION:
            det.diagnostics["far_wall_way_undetermined"] = True
        if alt.kind == Kind.BEND:
            return alt
        if (
            alt.kind == Kind.JUNCTION
            and alt.diagnostics.get("across_balanced", False)
            and det.diagnostics.get("closure_curvature_lr", 0.0) >= cfg.across_min_curvature_lr
            and _across_sides_open(cloud, big_r, alt, cfg)
        ):
            return alt
        return det
    if alt.kind != Kind.STRAIGHT and alt.confidence > det.confidence:
        return alt
    return det


def _shallow_widening(
    cloud: PipeCloud,
    big_r: float,
    lobes: list[Lobe],
    inside: NDArray[np.bool_],
    cfg: ImprovedConfig,
    diag: dict[str, Any],
) -> bool:
    """Are the ``lobes`` beyond the wall patches of a wider pipe's wall rather than branch
    openings? Under range noise a pipe a few millimetres wider lies mostly within the wall
    tolerance and the noise pushes patches of it past: lobes no deeper than the widening, on
    a wall whose radial profile (:func:`detector.axisymmetric.wall_profile`, up to the end
    wall the ``inside`` returns show, if any) steps out all round. A branch opening moves
    no ring's median by millimetres, and its returns reach deeper than such a step: the
    lobes' 90th percentile beyond the wall must stay within ``cfg.profile_min_step`` of the
    step. A cheap look comes first: past the lobes' start, the median offset of the returns
    within ``cfg.profile_band`` radii of the wall must lie out by half ``cfg.profile_min_step``
    from the one before it. Records ``lobes_shallow_widening`` when the profile was fitted."""
    u_inside = cloud.values(inside, cloud.xyz_v[0])
    dist = float(partial_percentile(u_inside, 5.0)) if u_inside.size else math.inf
    mask = np.zeros_like(lobes[0].mask)
    for lobe in lobes:
        mask |= lobe.mask
    # (first a cheap look: past the lobes' start the wall's returns, lobes and all, must lie
    # out by half a step or more, where the run goes on past a branch's opening)
    u_lobes = float(partial_percentile(cloud.values(mask, cloud.xyz_v[0]), 5.0))
    n_past, rise = median_rise(
        cloud.xyz_v[0], cloud.r_v, big_r, cfg.profile_band * big_r, u_lobes, dist
    )
    if n_past < 4 * cfg.cone_min_returns or rise < 0.5 * cfg.profile_min_step:
        return False
    depth = float(partial_percentile(cloud.values(mask, cloud.r_v), 90.0)) - big_r
    prof = wall_profile(cloud, big_r, dist, 0.0, cfg, {})
    if prof is None or prof.step <= 0.0:
        return False
    shallow = depth <= prof.offset + prof.step + cfg.profile_min_step
    diag["lobes_shallow_widening"] = shallow
    return shallow


def _across_sides_open(cloud: PipeCloud, big_r: float, alt: Detection, cfg: ImprovedConfig) -> bool:
    """Does the pipe across ``alt`` (a far wall seen head-on, both ways open) leave both its
    ways open? The far wall of a pipe across (a tee seen from its stem) and of a 90 deg turn
    is the same surface; they differ next to it: towards each way of a pipe across the
    incoming wall ends ``R |cos dphi|`` before the reference point (``dphi`` from the way's
    roll), while on the side away from a turn it runs on to ``R cos dphi`` past it. A side is
    closed when at least ``cfg.hole_min_returns`` returns within ``cfg.across_side_roll`` of
    its roll, within ``cfg.across_side_band`` radii of the reference point along the axis,
    lie on the wall (within ``cfg.across_wall_k`` times their radial noise, plus
    ``cfg.hole_min_step``). Only a wall the scan sees near the structure can show that: as
    many returns on the wall within ``cfg.across_view_band`` radii before it (and a radius
    short of it) on both sides, else the ways stay undecided (a sensor whose beams meet the
    wall that far ahead beyond its largest incidence sees neither)."""
    big_l = alt.distance
    u = cloud.xyz_v[0]
    phi = np.arctan2(cloud.xyz_v[2], cloud.xyz_v[1])
    past = np.abs(u - big_l) < cfg.across_side_band * big_r
    view = (u > big_l - cfg.across_view_band * big_r) & (u < big_l - big_r)
    on_wall = np.abs(cloud.r_v - big_r) <= cfg.hole_min_step + cfg.across_wall_k * cloud.sigma_v
    ways = [o for o in alt.options if not o.is_straight_on]
    if len(ways) != 2:
        return False
    for o in ways:
        roll = _way_roll(cloud, o)
        near_roll = np.abs(wrap_angle(phi - roll)) < cfg.across_side_roll
        if np.count_nonzero(past & on_wall & near_roll) >= cfg.hole_min_returns:
            return False
        if np.count_nonzero(view & on_wall & near_roll) < cfg.hole_min_returns:
            return False
    return True


def _way_roll(cloud: PipeCloud, option: StructureOption) -> float:
    """The roll (rad, about the pipe axis from the pipe frame's y axis) towards which the way
    ``option`` leaves, in the cloud's pipe frame (options give their direction in the sensor's
    frame)."""
    y_axis, z_axis = cloud.pose.rotation[:, 1], cloud.pose.rotation[:, 2]
    perp = math.cos(option.direction) * y_axis + math.sin(option.direction) * z_axis
    return math.atan2(float(perp[2]), float(perp[1]))


def _opposite_wall_open(
    n_opposite: int, n_square: tuple[int, int], at_square: bool, cfg: ImprovedConfig
) -> bool:
    """Does the wall on the side opposite a found way end before the place, as an opening's
    does, where a turn's outer wall runs on? ``n_opposite`` and ``n_square`` count the returns
    on the wall just before the place on the opposite side and on each side square to the way.
    The opposite side keeps at most ``cfg.opposite_wall_share`` of what the square sides keep
    (the fewer of the two, at least ``hole_min_returns`` twice: the test needs a wall in view).
    Opposite a 45 deg way the turn's outer wall leans in towards the axis and returns nothing
    beyond it: where neither square side shows that much wall (the sensor's incidence limit),
    the wall test is not made, and the opposite side only has to be as bare (at most
    ``opposite_wall_share`` of ``hole_min_returns`` twice)."""
    seen = 2 * cfg.hole_min_returns
    if min(n_square) >= seen:
        return n_opposite <= cfg.opposite_wall_share * min(n_square)
    if at_square or max(n_square) >= seen:
        return False
    return n_opposite <= cfg.opposite_wall_share * seen


def _with_opposite_way(
    cloud: PipeCloud, big_r: float, det: Detection, cfg: ImprovedConfig
) -> Detection:
    """``det``, or a junction with one more way: the way opposite a single way that leaves at
    90 deg (a cross or a tee from its stem whose other opening the branch fit missed, its
    returns a few millimetres beyond the wall that no region of the classification held)
    when that side shows the opening too. Near the place (a branch radius before and after
    it along the axis; ``cfg.opposite_side_roll`` of the roll) returns beyond the wall by more
    than their noise lie on the opposite side at least half as many as on the found way's and
    many more than on the sides square to it, and the wall there ends before the place, where
    a turn's outer wall runs on to its far wall (``cfg.opposite_*``). When each square side
    holds about as many returns beyond the wall as the way's (a stem narrower than the run:
    the run's wall lies beyond the stem's all round), only returns deeper than the 95th
    percentile of theirs count (the baseline test then holds by construction; the wall test
    still tells a turn). The new way mirrors the found one: same place, deflection and
    diameter. A single way at 45 deg (a Y entered from its branch, whose backward way at 135
    deg shows only as returns beyond the wall through its opening) gains that way by the same
    test, at the supplementary deflection (:func:`_opposite_wall_open`)."""
    if det.kind not in (Kind.JUNCTION, Kind.BEND) or det.diagnostics.get("model") == "torus":
        return det
    ways = [o for o in det.options if not o.is_straight_on]
    if len(ways) != 1:
        return det
    way = ways[0]
    at_square = abs(way.angle - 0.5 * math.pi) <= cfg.opposite_max_off_square
    oblique = abs(way.angle - 0.25 * math.pi) <= cfg.opposite_max_off_oblique
    if not (at_square or oblique):
        return det
    rho = 0.5 * way.diameter
    # (every count below is of returns within a branch radius of the place along the axis)
    u_all = cloud.xyz_v[0]
    near = np.flatnonzero((u_all > way.distance - rho) & (u_all < way.distance + rho))
    u = u_all[near]
    phi = np.arctan2(cloud.xyz_v[2, near], cloud.xyz_v[1, near])
    e = cloud.r_v[near] - big_r
    noise = np.maximum(cfg.hole_min_step, cfg.opposite_noise_k * cloud.sigma_v[near])
    on_wall_before = (u < way.distance) & (np.abs(e) <= noise)
    roll = _way_roll(cloud, way)

    # the windows of roll: the way's, the opposite one's and the two square to them
    rel = np.abs(wrap_angle(phi - roll))
    way_w = rel < cfg.opposite_side_roll
    opposite_w = rel > math.pi - cfg.opposite_side_roll
    square_ws = [
        np.abs(wrap_angle(phi - roll - s)) < cfg.opposite_side_roll
        for s in (0.5 * math.pi, -0.5 * math.pi)
    ]
    square_w = (square_ws[0] | square_ws[1]) & ~way_w & ~opposite_w  # (should they overlap)
    # (from a stem narrower than the run, the run's wall lies beyond the stem's all round:
    # the ways are what goes deeper than the sides square to them reach)
    beyond_wall = e > noise
    square_beyond = beyond_wall & square_w
    n_way = int(np.count_nonzero(beyond_wall & way_w))
    n_square = int(np.count_nonzero(square_beyond))
    depth = noise
    if n_square >= 2 * cfg.hole_min_returns and n_square >= cfg.opposite_min_share * 2 * n_way:
        depth = np.maximum(noise, partial_percentile(e[square_beyond], 95.0))
    beyond = e > depth

    def side(window: NDArray[np.bool_]) -> tuple[int, int]:
        return int(np.count_nonzero(beyond & window)), int(
            np.count_nonzero(on_wall_before & window)
        )

    found, opposite = side(way_w), side(opposite_w)
    square = [side(w) for w in square_ws]
    baseline = max(s[0] for s in square)
    det.diagnostics["opposite_way_counts"] = {
        "found": found,
        "opposite": opposite,
        "square": square,
    }
    if not (
        opposite[0]
        >= max(
            2 * cfg.hole_min_returns,
            cfg.opposite_min_share * found[0],
            cfg.opposite_baseline_factor * (baseline + 1),
        )
        and _opposite_wall_open(opposite[1], (square[0][1], square[1][1]), at_square, cfg)
    ):
        return det
    options = [replace(o, kind="junction") for o in det.options]
    # (a Y entered from a branch: the run's other end leaves backwards, at the supplement)
    angle = way.angle if at_square else math.pi - way.angle
    options.append(
        replace(way, kind="junction", direction=wrap_angle(way.direction + math.pi), angle=angle)
    )
    options.sort(key=option_order)
    diag = dict(det.diagnostics)
    diag.update(opposite_way=True, replaced_kind=det.kind)
    return Detection("junction", options, det.confidence, diag)
