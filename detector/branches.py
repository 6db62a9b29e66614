"""Openings and outgoing pipes for the improved detector (:mod:`detector.improved`): lobes
(regions of returns beyond the wall), outgoing cylinders fitted to them (bends and junctions,
a pipe across, the standard angles of fittings, the holes a run's side branches cut in its
wall, whether the run goes on straight), and a single way on tried as a long-radius bend
(:mod:`detector.long_bend`).

Lengths in metres, angles in radians.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from detector.detection import Detection
from detector.fit_kernels import MODEL_LINES, MODEL_OWN_LINES, coarse_branch_cost, residuals
from detector.geometry import wrap_angle
from detector.grid import label_regions
from detector.improved_config import ImprovedConfig
from detector.long_bend import fit_torus, spread_along_axis
from detector.options import StructureOption, option_order
from detector.outgoing import BranchFit
from detector.pipe_cloud import (
    PipeCloud,
    axis_direction,
    azimuth_coverage,
    azimuth_sectors,
    even_indices,
    even_subsample,
    fit_confidence,
    partial_percentile,
    region_floor,
    region_sizes,
)
from detector.robust import robust_fit, tukey_cost, tukey_weights
from detector.transforms import option_direction
from detector.vocab import Kind

#: Deflections of standard branch fittings (tees and crosses, laterals either way), rad; the
#: tuning of holding a branch at one is :class:`~detector.improved_config.ImprovedConfig`'s
#: ``snap_*`` fields.
STANDARD_BRANCH_ANGLES = np.radians([45.0, 90.0, 135.0])


# --------------------------------------------------------------------------- lobes
@dataclass
class Lobe:
    mask: NDArray[np.bool_]
    roll: float
    n: int


def find_lobes(
    cloud: PipeCloud,
    beyond: NDArray[np.bool_],
    big_r: float,
    cfg: ImprovedConfig,
    labelled: tuple[NDArray[np.int32], int] | None = None,
) -> list[Lobe]:
    """Openings: regions of returns beyond the wall (``labelled``: their regions, when known)."""
    labels, n_lab = label_regions(beyond, cloud.wraps) if labelled is None else labelled
    if n_lab == 0:
        return []
    lobes: list[Lobe] = []
    counts, row_span = region_sizes(labels, n_lab)
    cand = np.flatnonzero((counts >= cfg.min_lobe_points) & (row_span >= cfg.min_region_rows))
    found = [(labels == k, int(counts[k])) for k in cand[cand > 0].tolist()]
    regions = [part for m, n in found for part in _split_all_round(cloud, m, n, big_r, cfg)]
    for m, n, p_m in regions:
        p = cloud.points(m) if p_m is None else p_m
        depth = (
            float(partial_percentile(np.sqrt(np.square(p[:, 1]) + np.square(p[:, 2])), 90)) - big_r
        )
        floor = region_floor(cloud, cfg)
        if depth < max(3.0 * floor, 0.1 * big_r):
            continue  # a shallow sliver (seam leaks, noise), not an opening
        roll = _mean_roll(p)
        lobes.append(Lobe(m, roll, n))
    # merge lobes within 45 deg of roll (an opening split by dropouts)
    lobes.sort(key=lambda lb: -lb.n)
    merged: list[Lobe] = []
    for lb in lobes:
        for mg in merged:
            if abs(wrap_angle(lb.roll - mg.roll)) < math.radians(45.0):
                mg.mask = mg.mask | lb.mask
                p = cloud.points(mg.mask)
                mg.roll = _mean_roll(p)
                mg.n += lb.n
                break
        else:
            merged.append(Lobe(lb.mask.copy(), lb.roll, lb.n))
    # a lobe must be a real opening, not a sliver: compare with the largest
    if merged:
        biggest = max(m.n for m in merged)
        merged = [m for m in merged if m.n >= max(cfg.min_lobe_points, 0.05 * biggest)]
    return merged


def _mean_roll(p: NDArray[np.float64]) -> float:
    """The roll (rad) of the mean cross-section direction of the ``(n, 3)`` points ``p``."""
    return math.atan2(float(p[:, 2].sum()), float(p[:, 1].sum()))


#: A part of a region of returns beyond the wall: its grid mask, its number of returns and its
#: points (``(n, 3)``, in grid order) when they were gathered, else None.
RegionPart = tuple[NDArray[np.bool_], int, NDArray[np.float64] | None]


def _split_all_round(
    cloud: PipeCloud, mask: NDArray[np.bool_], n: int, big_r: float, cfg: ImprovedConfig
) -> list[RegionPart]:
    """A region of returns beyond the wall that goes all round the axis, split into its deep
    parts when there are two or more: entering a wider run from a tee's stem, the run's wall
    lies a step beyond the stem's all round and joins the two ways on into one region; only
    along the run do the returns reach deep (beyond half the region's 90th-percentile depth).
    Nearer the run, its wall also bulges out square to the run by up to the difference of the
    two radii, and those returns can reach that depth too: the parts then still join all round,
    and they are taken instead beyond the middle of the depth profile over the azimuth (see
    :func:`_profile_depth`), each with the returns of the region nearest it in roll (see
    :func:`_nearest_in_roll`). Otherwise the region as it is (``(mask, n)``). Each part comes
    with its points (:meth:`PipeCloud.points`) when they were gathered, else ``None``.
    ``mask`` holds only cells with a return (a labelled region of them)."""
    p = cloud.points(mask)
    if azimuth_coverage(p) < cfg.all_round:
        return [(mask, n, p)]
    depth = np.hypot(p[:, 1], p[:, 2]) - big_r
    parts = _deep_parts(cloud, mask, depth, 0.5 * float(partial_percentile(depth, 90.0)), cfg)
    if parts is None:
        middle = _profile_depth(p, depth, cfg.all_round_sectors, region_floor(cloud, cfg))
        parts = None if middle is None else _deep_parts(cloud, mask, depth, middle, cfg)
        if parts is not None:
            parts = _nearest_in_roll(mask, p, parts)
    return [(mask, n, p)] if parts is None else parts


def _deep_parts(
    cloud: PipeCloud,
    mask: NDArray[np.bool_],
    depth: NDArray[np.float64],
    threshold: float,
    cfg: ImprovedConfig,
) -> list[RegionPart] | None:
    """The connected parts (``(mask, n, None)``) of the returns of ``mask`` deeper than
    ``threshold`` m beyond the wall (``depth``, in the order of :meth:`PipeCloud.points`),
    when two or more are large enough to be openings; else None."""
    deep = np.zeros_like(mask)
    deep[mask] = depth > threshold
    labels, n_lab = label_regions(deep, cloud.wraps)
    if n_lab < 2:
        return None
    counts, row_span = region_sizes(labels, n_lab)
    parts = np.flatnonzero((counts >= cfg.min_lobe_points) & (row_span >= cfg.min_region_rows))
    parts = parts[parts > 0]
    if parts.size < 2:
        return None
    return [(labels == k, int(counts[k]), None) for k in parts.tolist()]


def _nearest_in_roll(
    mask: NDArray[np.bool_],
    p: NDArray[np.float64],
    parts: list[RegionPart],
) -> list[RegionPart]:
    """The whole region ``mask`` (its points ``p``, in grid order) shared out among its deep
    ``parts``: each return to the part whose mean roll is nearest its own. The shallow returns
    near the junction (the run's wall close to the stem) are what size the run and place the
    reference point; the deep parts alone leave the fit to trade one against the other."""
    roll = np.arctan2(p[:, 2], p[:, 1])
    centres = np.empty(len(parts))
    for j, (m, _, _) in enumerate(parts):
        own = m[mask]
        centres[j] = _mean_roll(p[own])
    owner = np.argmin(np.abs(wrap_angle(roll[:, None] - centres[None, :])), axis=1)
    cells = np.flatnonzero(mask)
    out: list[RegionPart] = []
    for j in range(len(parts)):
        part = np.zeros_like(mask)
        part.flat[cells[owner == j]] = True
        out.append((part, int(np.count_nonzero(owner == j)), p[owner == j]))
    return out


#: A sector of the depth profile counts with at least this many returns; the profile needs at
#: least half its sectors counted.
PROFILE_MIN_RETURNS = 3


def _profile_depth(
    p: NDArray[np.float64], depth: NDArray[np.float64], sectors: int, contrast: float
) -> float | None:
    """The middle (m) between the shallowest and the deepest of the deepest returns per
    azimuth sector (``sectors`` of them) of the ``(n, 3)`` points ``p`` with their ``depth``
    beyond the wall: from a narrower stem the ways along the run reach deepest, the bulge of
    the run's wall square to it only the difference of the radii. None if fewer than half the
    sectors hold :data:`PROFILE_MIN_RETURNS` returns, or if the deepest and the shallowest
    sector differ by no more than ``contrast`` m (an even region: no way stands out)."""
    k = azimuth_sectors(p, sectors)
    counts = np.bincount(k, minlength=sectors)
    deepest = np.full(sectors, -np.inf)
    np.maximum.at(deepest, k, depth)
    counted = counts >= PROFILE_MIN_RETURNS
    if 2 * int(counted.sum()) < sectors:
        return None
    lo, hi = float(deepest[counted].min()), float(deepest[counted].max())
    return 0.5 * (lo + hi) if hi - lo > contrast else None


# --------------------------------------------------------------------------- outgoing pipes
def _line_points(p: NDArray) -> NDArray[np.float64]:
    """(4, N) rows x, y, z, y^2 + z^2 of ``(N, 3)`` points: the returns of the outgoing-pipe
    models (:data:`detector.fit_kernels.MODEL_LINES`)."""
    out = np.empty((4, p.shape[0]))
    out[:3] = p.T
    np.add(np.square(out[1]), np.square(out[2]), out=out[3])
    return out


def _line_residuals(
    pts: NDArray[np.float64], x: NDArray[np.float64], own: NDArray[np.intp] | None
) -> NDArray[np.float64]:
    """Residuals of the returns ``pts`` (:func:`_line_points`) to the nearest outgoing
    cylinder of ``x`` (``[L, theta, phi, rho] x n``), or with ``own`` to their own lobe's."""
    if own is None:
        return residuals(MODEL_LINES, pts, x)
    return residuals(MODEL_OWN_LINES, pts, x, ipar=own)


def _fit_axes(
    pts: NDArray[np.float64],
    x0: NDArray[np.float64],
    n: int,
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    c: float,
    c_final: float,
    cfg: ImprovedConfig,
    iterations: int = 8,
    own: NDArray[np.intp] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Robust fit of ``n`` outgoing pipes (``[L, theta, phi, rho] x n``, the reference point
    shared) to the returns ``pts`` (:func:`_line_points`) from ``x0`` within the bounds: Tukey
    cut-off shrinking from ``c`` to ``c_final`` (m). Each return is fitted to the nearest pipe,
    or with ``own`` (the lobe of each return, ``0 .. n - 1``) to its own. Returns ``(x,
    residuals, weights)``."""
    return robust_fit(
        MODEL_LINES if own is None else MODEL_OWN_LINES,
        pts,
        x0,
        c=c,
        iterations=iterations,
        lower=lower,
        upper=upper,
        c_final=c_final,
        step_tol=cfg.fit_step_tol,
        anneal=cfg.fit_anneal,
        cost_tol=cfg.fit_cost_tol,
        ipar=own,
    )


@dataclass
class BranchProblem:
    """What every stage of :func:`detect_branches` works on: the returns the outgoing pipes are
    fitted to and the tolerances of the fit (lengths in m)."""

    cloud: PipeCloud
    big_r: float
    lobes: list[Lobe]
    cfg: ImprovedConfig
    diag: dict[str, Any]
    any_roll: bool
    #: the lobes' returns, and the inner returns near them (the far wall of a turn seen
    #: head-on), not far end walls of a run that goes on
    lobe_mask: NDArray[np.bool_]
    near_inside: NDArray[np.bool_]
    #: the flat indices of the returns fitted: each lobe's (``lobe_sub``, all of them
    #: ``lobe_idx``), then the inner returns near them
    lobe_sub: list[NDArray[np.intp]]
    lobe_idx: NDArray[np.intp]
    p_all: NDArray[np.float64]
    pts_all: NDArray[np.float64]
    tol_med: float
    noise_med: float
    #: a subsample of each lobe's returns, and where the beams left the incoming cylinder
    lobe_pts: list[NDArray[np.float64]]
    u_edge: float
    straight_on: bool = False
    cov_on: float = 0.0
    c0: float = 0.0
    c_fin: float = 0.0
    #: each fitted return's own opening (two openings on opposite sides), else None
    own: NDArray[np.intp] | None = None

    @property
    def n_l(self) -> int:
        """The number of outgoing pipes fitted (one per lobe)."""
        return len(self.lobes)

    def fit(
        self,
        x0: NDArray[np.float64],
        n: int,
        lower: NDArray[np.float64],
        upper: NDArray[np.float64],
        c: float,
        iterations: int = 8,
        own: NDArray[np.intp] | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """:func:`_fit_axes` of ``n`` pipes to the problem's returns, ending at ``c_fin``."""
        return _fit_axes(
            self.pts_all,
            x0,
            n,
            lower,
            upper,
            c=c,
            c_final=self.c_fin,
            cfg=self.cfg,
            iterations=iterations,
            own=own,
        )


def _outgoing_returns(
    cloud: PipeCloud,
    big_r: float,
    lobes: list[Lobe],
    keep: NDArray[np.bool_],
    tol: NDArray[np.float64],
    cfg: ImprovedConfig,
    diag: dict[str, Any],
    any_roll: bool,
) -> BranchProblem:
    """Lobes: the returns of the outgoing pipes (the lobes, and the inner returns near them),
    subsampled for the fit, with their median tolerance and range noise, and where the beams
    left the incoming cylinder."""
    lobe_mask = np.zeros_like(keep)
    for lb in lobes:
        lobe_mask |= lb.mask
    u_all = cloud.u_grid
    u_hi = float(partial_percentile(u_all[lobe_mask], 95)) + 2.0 * big_r if lobe_mask.any() else 0.0
    near_inside = keep & ~lobe_mask & (u_all <= u_hi)
    lobe_sub = [
        even_subsample(np.flatnonzero(lb.mask.reshape(-1)), cfg.fit_points // 2) for lb in lobes
    ]
    lobe_idx = np.concatenate(lobe_sub)
    near_idx = even_subsample(np.flatnonzero(near_inside.reshape(-1)), cfg.fit_points // 2)
    sub_idx = np.concatenate([lobe_idx, near_idx])
    if any_roll:
        sub_idx = even_subsample(np.flatnonzero(keep.reshape(-1)), cfg.far_wall_fit_points)
    p_all = np.ascontiguousarray(cloud.points_at(sub_idx))
    lobe_pts = []
    u_edge = math.inf
    for lb in lobes:
        lp = cloud.points(lb.mask)
        lp = lp[even_indices(lp.shape[0], 200)]
        lobe_pts.append(lp)
        # where the beams left the incoming cylinder (sensor near the axis)
        rr = np.sqrt(np.square(lp[:, 1]) + np.square(lp[:, 2]))
        uc = lp[:, 0] * big_r / np.maximum(rr, 1e-9)
        u_edge = min(u_edge, float(partial_percentile(uc, 1)))
    return BranchProblem(
        cloud=cloud,
        big_r=big_r,
        lobes=lobes,
        cfg=cfg,
        diag=diag,
        any_roll=any_roll,
        lobe_mask=lobe_mask,
        near_inside=near_inside,
        lobe_sub=lobe_sub,
        lobe_idx=lobe_idx,
        p_all=p_all,
        pts_all=_line_points(p_all),
        tol_med=float(partial_percentile(tol.reshape(-1)[sub_idx], 50.0)),
        noise_med=float(partial_percentile(cloud.sigma_r.reshape(-1)[sub_idx], 50.0)) + 0.3e-3,
        lobe_pts=lobe_pts,
        u_edge=u_edge,
    )


#: The coarse start's deflections (rad) with their cosines and sines: up to 100 deg for a bend
#: (``True``), 150 deg otherwise.
_COARSE_THETAS = {
    only: (t, np.cos(t), np.sin(t))
    for only, t in (
        (True, np.radians(np.arange(30.0, 101.0, 7.5))),
        (False, np.radians(np.arange(30.0, 151.0, 7.5))),
    )
}
#: The coarse start's rolls (rad) of a far wall seen head-on (its roll unknown).
_COARSE_ROLLS = np.radians(np.arange(0.0, 360.0, 20.0))


def _coarse_start(
    bp: BranchProblem,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Branch fit, start: a coarse grid per lobe over (L, theta) with the lobe's roll (every
    roll with ``any_roll``) and the clamped radius; returns the start ``[L, theta, phi, rho] x
    n`` and the bounds of the fit."""
    big_r = bp.big_r
    # one way on and no run going on: a bend, deflecting up to 90 deg (wye branches at 135 deg
    # come with a second way)
    bend_only = bp.n_l == 1 and not bp.straight_on
    thetas, cos_t, sin_t = _COARSE_THETAS[bend_only]
    l_grid = bp.u_edge + np.linspace(0.0, 3.0 * big_r, 13)
    if bp.any_roll:
        # the far wall of a turn lies past the turn's reference point
        u_near = min(float(lp[:, 0].min()) for lp in bp.lobe_pts)
        l_grid = u_near + np.linspace(-4.0 * big_r, 0.0, 13)
    total = np.zeros(l_grid.size)
    per_lobe = []
    rolls_of = []
    for lb, lp in zip(bp.lobes, bp.lobe_pts):
        rolls = _COARSE_ROLLS if bp.any_roll else np.array([lb.roll])
        rolls_of.append(rolls)
        dirs = np.empty((3, rolls.size * thetas.size))  # (3, RT): roll-major
        dirs[0] = np.tile(cos_t, rolls.size)
        dirs[1] = (np.cos(rolls)[:, None] * sin_t).reshape(-1)
        dirs[2] = (np.sin(rolls)[:, None] * sin_t).reshape(-1)
        lq = lp[even_indices(lp.shape[0], 50 if bp.any_roll else 60)]
        # the mean squared distance of the returns from the pipe's wall, capped; the sensor
        # sees every wall from inside its pipe: a cylinder behind the returns (the same patch
        # seen from outside) is penalised like an outlier
        cost = coarse_branch_cost(np.ascontiguousarray(lq), l_grid, dirs, big_r, bp.c0)
        per_lobe.append(cost)  # (L, RT)
        total += cost.min(axis=1)
    i_l = int(np.argmin(total))
    x0 = [float(l_grid[i_l])]
    for rolls, cost in zip(rolls_of, per_lobe):
        k = int(np.argmin(cost[i_l]))
        x0 += [float(thetas[k % thetas.size]), float(rolls[k // thetas.size]), big_r]
    n_l = bp.n_l
    # physical ranges: bends deflect 30-90 deg, branches 45, 90 or 135 deg
    lower = np.array([-0.5] + [bp.cfg.deflection_min, -10.0, 0.25 * big_r] * n_l)
    # (a side branch of a run that goes on is no wider than the run)
    rho_max = 1.05 * big_r if bp.straight_on else 2.5 * big_r
    th_max = math.radians(100.0) if bend_only else bp.cfg.deflection_max
    upper = np.array([bp.cfg.horizon] + [th_max, 10.0, rho_max] * n_l)
    return np.array(x0), lower, upper


def _own_openings(bp: BranchProblem) -> NDArray[np.intp] | None:
    """Side holes: with two openings on opposite sides (a tee from its stem, a wye from its
    branch, the side pipes of a cross), the opening each fitted return belongs to (an inner
    return near them, on the far wall of a pipe across seen head-on, to the branch on its side
    of the incoming axis); else None. Two cylinders fitted to the nearer of them take in the
    scatter of a noisy opening's rim between them, and lean apart by several degrees for it."""
    lobes = bp.lobes
    if not _opposite(bp):
        return None
    p_near = bp.p_all[bp.lobe_idx.size :]
    side = np.stack(
        [p_near[:, 1] * math.cos(lb.roll) + p_near[:, 2] * math.sin(lb.roll) for lb in lobes]
    )
    labels = np.concatenate(
        [np.full(ix.size, k) for k, ix in enumerate(bp.lobe_sub)] + [np.argmax(side, axis=0)]
    )
    return labels.astype(np.intp)


def _opposite(bp: BranchProblem) -> bool:
    """Two openings on opposite sides of the axis, each with its own roll (not ``any_roll``)?"""
    lobes = bp.lobes
    return (
        bp.n_l == 2
        and abs(wrap_angle(lobes[0].roll - lobes[1].roll)) > math.radians(150)
        and not bp.any_roll
    )


@dataclass
class RadiusChoice:
    """Branch fit, radii: the fit kept (``x``, its residuals and weights), its bounds, the
    clamped-radius fit ``x_eq`` and its bounds, the standard radii and the residual variance
    (m^2) the likelihood ratios are taken against."""

    x: NDArray[np.float64]
    res: NDArray[np.float64]
    w: NDArray[np.float64]
    lo_b: NDArray[np.float64]
    up_b: NDArray[np.float64]
    std_r: NDArray[np.float64]
    sigma2: float


def _choose_radius(
    bp: BranchProblem,
    free: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    x0a: NDArray[np.float64],
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    hole: list | None,
) -> RadiusChoice:
    """Branch fit, radii: the clamped radius (a standard fitting) unless the returns call for
    another one. A free radius is poorly observed from a partial view of an opening under range
    noise, so it is kept only when it fits significantly better (likelihood ratio against the
    residual noise, a few units per extra parameter). (A far wall seen head-on is too small a
    part of a pipe to size it: clamped from the coarse start.) (The standard radius of a side
    branch whose hole in the run's wall is clearly narrower is the hole's.)"""
    x, res, w = free
    big_r, n_l, c_fin, any_roll, diag = bp.big_r, bp.n_l, bp.c_fin, bp.any_roll, bp.diag
    std_r = np.array([h[3] for h in hole]) if hole is not None else np.full(n_l, big_r)
    x_eq = x0a.copy() if any_roll else x.copy()
    x_eq[3::3] = std_r
    lo_eq, up_eq = lower.copy(), upper.copy()
    lo_eq[3::3] = std_r
    up_eq[3::3] = std_r
    if not any_roll and bool(np.all(np.abs(x[3::3] - std_r) <= 0.01 * big_r)):
        # the free fit found the clamped radius already: clamping it moves nothing that matters
        res_eq = _line_residuals(bp.pts_all, x_eq, bp.own)
        w_eq = tukey_weights(res_eq, c_fin)
    else:
        x_eq, res_eq, w_eq = bp.fit(
            x_eq,
            n_l,
            lo_eq,
            up_eq,
            c=2.0 * bp.c0 if any_roll else 2.0 * c_fin,
            iterations=12 if any_roll else 8,
            own=bp.own,
        )
    if any_roll:
        # (a far wall seen head-on fits a pipe deflected by theta and its mirror image deflected
        # by pi - theta about nearly as well: the mirror of the solution is a second start)
        x_m = x_eq.copy()
        x_m[1], x_m[2] = math.pi - x_eq[1], x_eq[2] + math.pi
        x_m[1] = min(max(x_m[1], lo_eq[1]), up_eq[1])
        x_m, res_m, w_m = bp.fit(x_m, n_l, lo_eq, up_eq, c=2.0 * c_fin)
        if tukey_cost(res_m, c_fin) < tukey_cost(res_eq, c_fin):
            x_eq, res_eq, w_eq = x_m, res_m, w_m
    cost_free = tukey_cost(res, c_fin)
    cost_eq = tukey_cost(res_eq, c_fin)
    n_in = max(int((w > 0.1).sum()), 1)
    sigma2 = max(2.0 * cost_free / n_in, bp.noise_med**2)
    lr = 2.0 * (cost_eq - cost_free) / sigma2
    diag.update(radius_lr=float(lr), radius_free=[float(v) for v in x[3::3]])
    # (a free fit that ends on the deflection bounds has not found a pipe: the radius traded
    # against the angle)
    th_lo, th_hi = lower[1] + math.radians(1.0), upper[1] - math.radians(1.0)
    free_on_bound = bool(np.any((x[1::3] <= th_lo) | (x[1::3] >= th_hi)))
    eq_on_bound = bool(np.any((x_eq[1::3] <= th_lo) | (x_eq[1::3] >= th_hi)))
    diag["radius_free_on_bound"] = free_on_bound
    weak = any_roll or bool(diag.get("hole_prior_used", False))  # too little to size a pipe
    if weak or lr <= bp.cfg.radius_lr_per_branch * n_l or (free_on_bound and not eq_on_bound):
        diag["radius_model"] = "clamped" if bool(np.all(std_r == big_r)) else "hole"
        return RadiusChoice(x_eq, res_eq, w_eq, lo_eq, up_eq, std_r, sigma2)
    diag["radius_model"] = "free"
    return RadiusChoice(x, res, w, lower, upper, std_r, sigma2)


def _pipe_across(
    bp: BranchProblem,
    rc: RadiusChoice,
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
    """Side holes: one pipe across? One straight axis through the reference point, fitted as
    one cylinder of the standard radius, is kept (returned as its fit) unless the two
    branches fit significantly better (likelihood ratio, as for the radii): then None."""
    lobes, x, c_fin = bp.lobes, rc.x, bp.c_fin
    k_main = 0 if lobes[0].n >= lobes[1].n else 1
    r_a = float(np.mean(rc.std_r))  # (the side pipe of a cross may be narrower than the run)
    starts = [np.array([x[0], x[1 + 3 * k_main], x[2 + 3 * k_main], r_a])]
    if float(axis_direction(x[1], x[2]) @ axis_direction(x[4], x[5])) > -0.985:
        # (the branches not nearly in line: the pipe across may lie elsewhere)
        starts += [
            np.array([x[0], 0.5 * math.pi, lobes[k_main].roll, r_a]),
            np.array([bp.u_edge + bp.big_r, 0.5 * math.pi, lobes[k_main].roll, r_a]),
        ]
    best_a = None
    for xa0 in starts:
        xa, res_a, w_a = bp.fit(
            xa0,
            1,
            np.array([lower[0], math.radians(25.0), -10.0, r_a]),
            np.array([upper[0], math.radians(155.0), 10.0, r_a]),
            c=2.0 * bp.c0,
        )
        cost_a = tukey_cost(res_a, c_fin)
        if best_a is None or cost_a < best_a[0]:
            best_a = (cost_a, xa, res_a, w_a)
    assert best_a is not None
    cost_a, xa, res_a, w_a = best_a
    # (the two branches: three more deflection and roll parameters, two more radii)
    n_extra = 4 if bp.diag["radius_model"] == "free" else 2
    lr_a = 2.0 * (cost_a - tukey_cost(rc.res, c_fin)) / rc.sigma2
    bp.diag["across_lr"] = float(lr_a)
    if lr_a <= 0.5 * bp.cfg.radius_lr_per_branch * max(n_extra, 1):
        return xa, res_a, w_a
    return None


def _hold_standard_angles(
    bp: BranchProblem,
    rc: RadiusChoice,
    across: NDArray[np.float64] | None,
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Standard angles: a junction's branches (or its pipe across) leave at the standard
    angles of fittings when the returns allow it (:func:`_standard_angles`)."""
    if across is not None:
        n_b = 1
        lo_b = np.array([lower[0], math.radians(25.0), -10.0, float(across[3])])
        up_b = np.array([upper[0], math.radians(155.0), 10.0, float(across[3])])
        own = None
    else:
        n_b, lo_b, up_b, own = bp.n_l, rc.lo_b, rc.up_b, bp.own
    return _standard_angles(
        bp.pts_all,
        rc.x,
        rc.res,
        rc.w,
        n_b,
        lo_b,
        up_b,
        bp.c_fin,
        rc.sigma2,
        bp.diag,
        bp.cfg,
        radius_bounds=(lower[3::3], upper[3::3]) if across is None else None,
        own=own,
        run_radius=bp.big_r if bp.straight_on and across is None else None,
    )


def _far_wall_way(
    bp: BranchProblem, x: NDArray[np.float64], w: NDArray[np.float64], f: BranchFit
) -> list[BranchFit] | None:
    """Branch fit of a far wall (``any_roll``): a cylinder's axis has no sign, the way on is
    the half the returns lie along; both halves when the far wall runs on evenly to both
    sides (a pipe across), None when it shows a way on but not which of the two."""
    big_r, diag = bp.big_r, bp.diag
    along = (bp.p_all - np.array([x[0], 0.0, 0.0])) @ axis_direction(f.theta, f.phi)
    ahead = float(np.sum(w * (along > 0.5 * big_r))) / max(float(w.sum()), 1e-9)
    behind = float(np.sum(w * (along < -0.5 * big_r))) / max(float(w.sum()), 1e-9)
    diag.update(far_wall_ahead=ahead, far_wall_behind=behind)
    flipped = BranchFit(math.pi - f.theta, f.phi + math.pi, f.rho)
    balanced = min(ahead, behind) >= 0.05 and min(ahead, behind) >= 0.5 * max(ahead, behind)
    if balanced and abs(f.theta - 0.5 * math.pi) < math.radians(20.0):
        # the far wall runs on evenly to both sides of the axis' foot: a pipe across,
        # both its ways open (a tee seen from its stem)
        diag["across_balanced"] = True
        return [f, flipped]
    # (the returns' mean position along the axis, from its foot, m)
    lean = float(np.sum(w * along)) / max(float(w.sum()), 1e-9)
    diag["far_wall_lean"] = lean / big_r
    if abs(lean) < bp.cfg.far_wall_min_lean * big_r:
        # the far wall lies about evenly to both sides of the axis' foot (a turn by about
        # 90 deg seen head-on, its opening unseen): it shows a way on, not which of the two;
        # a guess would be the mirror image as often as not
        return None
    return [flipped] if lean < 0.0 else [f]


@dataclass
class OutgoingModel:
    """The outgoing pipes chosen: reference point ``big_l`` (m), the fits, the rms (m) and
    support of the fit, the model's name and whether a long bend's angle is a lower bound."""

    big_l: float
    fits: list[BranchFit]
    rms: float
    support: int
    model: str
    lower_bound: bool = False


def _try_long_bend(bp: BranchProblem, om: OutgoingModel) -> OutgoingModel:
    """Branch fit, long bends: a single way on that the straight model explains poorly (or
    that leaves out more than a few of the returns: the first centimetres of a gentle arc lie
    within the noise of a mitre's straight axes, its far part does not) is also fitted as a
    long-radius bend (torus), kept when it explains the returns clearly better."""
    loose = om.rms > 2.0 * bp.noise_med or om.support < bp.cfg.torus_try_support * bp.p_all.shape[0]
    if not (bp.n_l == 1 and not bp.straight_on and loose):
        return om
    # (polished on returns spread evenly along the axis: the few returns from the far end of
    # the arc fix its angle, and an even subsample of all returns holds hardly any of them;
    # not under range noise, see fit_torus)
    p_fit = None
    if bp.noise_med <= bp.cfg.torus_polish_max_noise:
        arc_cells = np.flatnonzero((bp.lobe_mask | bp.near_inside).reshape(-1))
        u_flat = bp.cloud.u_grid.reshape(-1)
        spread = spread_along_axis(arc_cells, u_flat[arc_cells], bp.cfg.fit_points)
        p_fit = np.ascontiguousarray(bp.cloud.points_at(spread))
    tor = fit_torus(
        bp.p_all, bp.big_r, om.big_l, om.fits[0], bp.c0, bp.c_fin, bp.noise_med, bp.cfg, p_fit
    )
    if tor is None:
        return om
    xt, rms_t, sup_t, vis = tor
    bp.diag.update(torus_rms=rms_t, torus_support=sup_t, torus_rb=float(xt[4]))
    if not (sup_t >= om.support * 0.98 and rms_t < om.rms * 0.85):
        return om
    bp.diag["torus_visible_arc_deg"] = math.degrees(vis)
    return OutgoingModel(
        float(xt[0]),
        [BranchFit(xt[1], xt[2], xt[3], xt[4])],
        rms_t,
        sup_t,
        "torus",
        # the end of the arc unseen: the angle is only a lower bound
        lower_bound=vis >= float(xt[1]) - math.radians(3.0),
    )


def _branch_detection(bp: BranchProblem, om: OutgoingModel) -> Detection:
    """The bend or junction of the outgoing pipes chosen (a way on along the run when the
    incoming pipe goes on), or straight pipe when the fit left the physical range."""
    diag = bp.diag
    diag["model"] = om.model
    diag["angle_lower_bound"] = om.lower_bound
    big_l = om.big_l
    if not (math.isfinite(big_l) and -0.5 <= big_l <= bp.cfg.horizon):
        diag["reason"] = "fit left the physical range"
        return Detection.straight(confidence=0.0, **diag)
    conf = fit_confidence(om.support, om.rms, bp.c_fin / 3.0) * (0.6 if om.lower_bound else 1.0)
    options: list[StructureOption] = []
    for f in om.fits:
        angle, direction = option_direction(axis_direction(f.theta, f.phi), bp.cloud.pose)
        # a long bend's arc radius (torus model; 0 for the straight-axes model) for the turn
        radius = float(f.rb) if om.model == "torus" else 0.0
        options.append(
            StructureOption(
                "bend", big_l, 2.0 * float(f.rho), direction, angle, conf, bend_radius=radius
            )
        )
    if bp.straight_on:
        options.append(
            StructureOption("junction", big_l, 2.0 * bp.big_r, 0.0, 0.0, conf * bp.cov_on)
        )
    kind = "bend" if len(options) == 1 else "junction"
    options = [
        StructureOption(
            kind,
            o.distance,
            o.diameter,
            o.direction,
            o.angle,
            o.confidence,
            bend_radius=o.bend_radius if kind == Kind.BEND else 0.0,
        )
        for o in options
    ]
    options.sort(key=option_order)
    return Detection(kind, options, conf, diag)


def detect_branches(
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
    unknown and searched too). The stages: the lobes' returns; does the incoming pipe go on;
    the branch fit (coarse start, hole prior, free fit, radii); side holes (each branch on its
    own opening, one pipe across); standard angles; a far wall's way on; long bends; the
    detection."""
    lobes = _nearest_structure_lobes(cloud, lobes, big_r, diag)
    bp = _outgoing_returns(cloud, big_r, lobes, keep, tol, cfg, diag, any_roll)
    # --- does the incoming pipe go on? Then this is a junction seen along its run: every
    # lobe is a side branch of a standard fitting (tee 90 deg, wye 45 deg), no wider than
    # the run
    bp.straight_on, bp.cov_on = _straight_on(cloud, big_r, bp.u_edge + big_r, wall, cfg)
    diag["straight_on_coverage"] = bp.cov_on
    bp.c0 = max(6.0 * bp.tol_med, 0.006)
    x0a, lower, upper = _coarse_start(bp)
    hole = None
    if bp.straight_on and not any_roll:
        prior = (x0a.copy(), lower.copy(), upper.copy())
        hole = _hole_prior(cloud, big_r, lobes, bp.lobe_pts, wall, tol, bp.u_edge, bp.c0, *prior)
    bp.c_fin = max(3.0 * bp.tol_med, 0.003)
    bp.own = _own_openings(bp)
    x, res, w = bp.fit(x0a, bp.n_l, lower, upper, c=2.0 * bp.c0, own=bp.own)
    if hole is not None and not _fits_hole(x, hole, big_r, lower, upper):
        # the returns through the openings led the fit astray (few and noisy, far away):
        # start again from the holes in the run's wall and stay near them
        x0a, lower, upper = prior
        x, res, w = bp.fit(x0a, bp.n_l, lower, upper, c=2.0 * bp.c0, own=bp.own)
        diag.update(hole_reference=float(prior[0][0]), hole_prior_used=True)
    rc = _choose_radius(bp, (x, res, w), x0a, lower, upper, hole)
    across = None
    if _opposite(bp):
        found = _pipe_across(bp, rc, lower, upper)
        if found is not None:
            across = found[0]
            rc.x, rc.res, rc.w = found
    x, res, w = rc.x, rc.res, rc.w
    if not any_roll and (across is not None or bp.n_l >= 2 or bp.straight_on):
        x, res, w = _hold_standard_angles(bp, rc, across, lower, upper)
        if across is not None:
            across = x
    rms = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9)))
    support = int((w > 0.1).sum())
    diag.update(fit_rms=rms, fit_support=support, fit_points=int(bp.p_all.shape[0]))
    if across is not None:
        th_a, ph_a, r_a = float(across[1]), float(across[2]), float(across[3])
        fits = [BranchFit(th_a, ph_a, r_a), BranchFit(math.pi - th_a, ph_a + math.pi, r_a)]
        model = "pipe_across"
    else:
        fits = [BranchFit(x[1 + 3 * k], x[2 + 3 * k], x[3 + 3 * k]) for k in range(bp.n_l)]
        model = "straight_axes"
    if any_roll and w.sum() > 0:
        way = _far_wall_way(bp, x, w, fits[0])
        if way is None:
            diag["reason"] = "far wall: way on undetermined"
            return Detection.straight(confidence=0.0, **diag)
        fits = way
    om = _try_long_bend(bp, OutgoingModel(float(x[0]), fits, rms, support, model))
    return _branch_detection(bp, om)


def _standard_angle_candidates(
    x: NDArray[np.float64], n_b: int, snap_within: float
) -> list[list[tuple[int, float, float]]]:
    """Standard angles: per branch of the fit ``x`` (``[L, theta, phi, rho] x n_b``) whose
    deflection lies within ``snap_within`` (rad) of standard ones and on none of them, the
    (parameter index, standard angle, offset) of each, nearest first (rad)."""
    options: list[list[tuple[int, float, float]]] = []
    for k in range(n_b):
        th = float(x[1 + 3 * k])
        near = sorted(
            (abs(float(a) - th), float(a))
            for a in STANDARD_BRANCH_ANGLES
            if abs(float(a) - th) <= snap_within
        )
        if near and near[0][0] > 1e-6:
            options.append([(1 + 3 * k, a, d) for d, a in near])
    return options


def _hole_shift(
    x: NDArray[np.float64],
    idx: list[int],
    angles: list[float],
    run_radius: float | None,
    cfg: ImprovedConfig,
) -> float | None:
    """Standard angles: the move (m) of the reference point that keeps the branches held at
    ``angles`` crossing the run's wall (radius ``run_radius``, m; None: no run goes on) where
    the free fit ``x`` has them, where their holes are; None when there is none to make."""
    # (a free deflection resting on the limits of any branch fit measured nothing: no hole to
    # keep; a hole's own bounds, a few degrees either side, are measured ones)
    if run_radius is None or any(
        x[i] <= cfg.deflection_min + math.radians(1.0)
        or x[i] >= cfg.deflection_max - math.radians(1.0)
        for i in idx
    ):
        return None
    shift = float(
        np.mean(
            [run_radius * (1.0 / math.tan(x[i]) - 1.0 / math.tan(a)) for i, a in zip(idx, angles)]
        )
    )
    return shift if abs(shift) > 1e-4 else None


def _standard_angles(
    pts: NDArray[np.float64],
    x: NDArray[np.float64],
    res: NDArray[np.float64],
    w: NDArray[np.float64],
    n_b: int,
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    c_fin: float,
    sigma2: float,
    diag: dict[str, Any],
    cfg: ImprovedConfig,
    radius_bounds: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    own: NDArray[np.intp] | None = None,
    run_radius: float | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The branch fit ``x`` (``[L, theta, phi, rho] x n_b``, its residuals and weights) with
    each deflection within ``cfg.snap_within`` of a standard fitting angle (tees and crosses
    90 deg, laterals 45 deg: :data:`STANDARD_BRANCH_ANGLES`) held at that angle and the rest
    refitted, when the returns do not reject it (likelihood ratio against the residual noise
    ``sigma2``, m^2, at most ``cfg.snap_lr`` per angle held). A small opening far away shows a
    patch of the branch's wall whose deflection trades against the reference point and the
    radius by a few degrees; a standard angle the patch fits as well is the better estimate.

    The standard angles are tried nearest first (a deflection halfway between two is tried
    at both); of those the returns do not reject, the one they fit best is kept.

    ``run_radius`` (m; a run that goes on): each held fit starts from the reference point that
    keeps the branch crossing the run's wall where the free fit has it, where its hole is
    (``L + R (cot theta - cot theta_standard)``), and, if the returns reject that, from the
    free fit's own reference point. A few returns far away trade the deflection against the
    reference point; held at another angle from the same reference point, the branch misses
    them all, and a robust fit started there has nothing to hold on to.

    When the radii are held (``lower == upper``) and the held angle is rejected, it is tried
    once more with the radii free within ``radius_bounds`` (lower, upper per branch, m) but
    within ``cfg.snap_radius`` of the held ones: a branch a millimetre narrower than the run, fitted
    at the run's radius, leans by a degree or two instead. ``own``: as for
    :func:`_fit_axes`."""
    options = _standard_angle_candidates(x, n_b, cfg.snap_within)
    if not options:
        return x, res, w
    cost = tukey_cost(res, c_fin)
    rho = slice(3, None, 3)

    def accepted(x_s: NDArray[np.float64], res_s: NDArray[np.float64], n_held: int) -> bool:
        lr = 2.0 * (tukey_cost(res_s, c_fin) - cost) / max(sigma2, 1e-12)
        diag["standard_angle_lr"] = float(lr)
        # (held at the standard angle, the branch must stay where it was: a fit that turns it
        # about the run's axis to make up for the deflection rests on too few returns)
        turned = max(abs(wrap_angle(float(x_s[2 + 3 * k] - x[2 + 3 * k]))) for k in range(n_b))
        return lr <= cfg.snap_lr * n_held and turned <= cfg.snap_max_turn

    Fit = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]

    def held_fit(held: tuple[tuple[int, float, float], ...]) -> tuple[Fit, bool] | None:
        """The fit with the deflections ``held`` (index, angle, offset) and whether its radii
        had to be freed; ``None`` when the returns reject it."""
        idx = [i for i, _, _ in held]
        angles = [a for _, a, _ in held]
        lo, up = lower.copy(), upper.copy()
        lo[idx] = up[idx] = angles
        starts = []
        shift = _hole_shift(x, idx, angles, run_radius, cfg)
        if shift is not None:
            xs = x.copy()
            xs[0] += shift
            starts.append(xs)
        xs = x.copy()
        starts.append(xs)
        for xs in starts:
            xs[idx] = angles
            xs = np.clip(xs, np.minimum(lo, xs), np.maximum(up, xs))
            fit = _fit_axes(pts, xs, n_b, lo, up, c=2.0 * c_fin, c_final=c_fin, cfg=cfg, own=own)
            if accepted(fit[0], fit[1], len(idx)):
                return fit, False
            if radius_bounds is not None and bool(np.all(lo[rho] >= up[rho])):
                lo_r, up_r = lo.copy(), up.copy()
                held_r = x[rho]
                lo_r[rho] = np.maximum(radius_bounds[0], held_r * (1.0 - cfg.snap_radius))
                up_r[rho] = np.minimum(radius_bounds[1], held_r * (1.0 + cfg.snap_radius))
                fit = _fit_axes(
                    pts, fit[0], n_b, lo_r, up_r, c=2.0 * c_fin, c_final=c_fin, cfg=cfg, own=own
                )
                if accepted(fit[0], fit[1], len(idx)):
                    return fit, True
        return None

    best: tuple[float, Fit, bool, int] | None = None
    combos = sorted(itertools.product(*options), key=lambda h: sum(d for _, _, d in h))
    for held in combos:
        found = held_fit(held)
        if found is not None:
            cost_held = tukey_cost(found[0][1], c_fin)
            if best is None or cost_held < best[0]:
                best = (cost_held, found[0], found[1], len(held))
    if best is None:
        return x, res, w
    diag["standard_angles"] = best[3]
    if best[2]:
        diag["standard_angles_radius_free"] = True
    return best[1]


def _nearest_structure_lobes(
    cloud: PipeCloud, lobes: list[Lobe], big_r: float, diag: dict[str, Any]
) -> list[Lobe]:
    """The lobes of the nearest structure: a lobe that starts more than four radii past the
    far end of the nearest lobe is an opening of another structure farther along the run
    (seen past this one), not a way on of this one."""
    if len(lobes) < 2:
        return lobes
    spans = []
    for lb in lobes:
        u = cloud.points(lb.mask)[:, 0]
        spans.append((float(partial_percentile(u, 2.0)), float(partial_percentile(u, 98.0))))
    first = min(range(len(lobes)), key=lambda i: spans[i][0])
    reach = spans[first][1] + 4.0 * big_r
    keep = [lb for lb, (u0, _) in zip(lobes, spans) if u0 <= reach]
    if len(keep) < len(lobes):
        diag["lobes_farther_on"] = len(lobes) - len(keep)
    return keep


def _hole_prior(
    cloud: PipeCloud,
    big_r: float,
    lobes: list[Lobe],
    lobe_pts: list[NDArray],
    wall: NDArray[np.bool_],
    tol: NDArray[np.float64],
    u_edge: float,
    c0: float,
    x0: NDArray,
    lower: NDArray,
    upper: NDArray,
) -> list[tuple[float, float, float, float]] | None:
    """Side branches of a run that goes on, seen far away: the few returns through an opening
    leave the branch's deflection and the reference point ill-determined, but the hole in the
    run's wall is plain. A branch of radius ``rho`` deflected by ``theta`` cuts a hole of
    half-length ``rho / sin(theta)`` centred ``R cot(theta)`` past the reference point, and
    ``asin(rho / R)`` wide on either side of its roll (a narrower branch: a narrower hole);
    the start (``x0``) and the bounds of the fit are set from it, in place. Returns the centre,
    half-length, how far off they may be seen, and the branch radius (``R`` unless the hole
    is clearly narrower) of each lobe's hole; ``None`` (nothing changed) when a hole is not
    found for every lobe."""
    u_grid = cloud.u_grid
    near_u = wall & (u_grid > u_edge - 2.0 * big_r) & (u_grid < u_edge + 8.0 * big_r)
    p_w = cloud.points(near_u)
    tol_w = float(np.median(tol[near_u])) if near_u.any() else 0.0
    u_w = p_w[:, 0]
    phi_w = np.arctan2(p_w[:, 2], p_w[:, 1])
    ths = np.radians(np.arange(30.0, 150.1, 2.5))
    sin_t, cos_t = np.sin(ths), np.cos(ths)
    ells, thetas, slack = [], [], []
    holes: list[tuple[float, float, float, float]] = []
    for lb, lp in zip(lobes, lobe_pts):
        ang = np.mod(phi_w - lb.roll + math.pi, 2.0 * math.pi) - math.pi
        near = np.abs(ang)
        us = np.sort(u_w[near < math.radians(15.0)])
        if us.size < 10:
            return None
        gaps = np.diff(us)
        # the widest gap for its place: far away the beams meet the wall sparsely, so a gap
        # is measured against the axial spacing of neighbouring beams there
        mid_u = 0.5 * (us[1:] + us[:-1])
        beam_spacing = np.maximum(mid_u * mid_u / big_r * cloud.beam_step, 1e-3)
        i = int(np.argmax(gaps / beam_spacing))
        if gaps[i] < 0.5 * big_r:
            return None
        half = 0.5 * float(gaps[i])
        centre = 0.5 * float(us[i] + us[i + 1])
        rho = _hole_radius(ang, u_w, centre, half, big_r, tol_w)
        if gaps[i] < rho:
            return None
        # each edge is known to within the axial spacing of neighbouring beams there
        step = centre * centre / big_r * cloud.beam_step
        spacing = float(np.median(gaps[max(0, i - 5) : i + 6]))  # of the returns seen
        # deflections along a grid: the reference point that puts the hole's centre where it
        # is seen, scored by the returns through the opening and by the hole length (returns
        # at the edges fall off the wall, so a hole may look longer, never shorter)
        ell_t = centre - big_r * cos_t / sin_t  # (T,)
        lq = lp[even_indices(lp.shape[0], 100)]
        qx = lq[None, :, 0] - ell_t[:, None]  # (T, n)
        lat = lq[:, 1] * math.cos(lb.roll) + lq[:, 2] * math.sin(lb.roll)  # (n,)
        t = qx * cos_t[:, None] + lat[None, :] * sin_t[:, None]
        qq = qx * qx + (lq[:, 1] ** 2 + lq[:, 2] ** 2)[None, :]
        res = np.sqrt(np.maximum(qq - t * t, 0.0)) - rho
        cost = np.minimum(res * res, c0 * c0).mean(axis=1)
        excess = np.maximum(0.0, rho / sin_t - half) / max(spacing, 0.005)
        cost += c0 * c0 * np.minimum(1.0, 0.25 * excess * excess)
        cost = np.where(ths > 0.5 * math.pi + 1e-6, cost / 0.7, cost)  # forward branches first
        j = int(np.argmin(cost))
        thetas.append(float(ths[j]))
        ells.append(float(ell_t[j]))
        slack.append(max(0.25 * big_r, 0.5 * step))
        holes.append((centre, half, slack[-1], rho))
    ell = float(np.mean(ells))
    d_ell = max(slack) + float(np.ptp(ells))
    x0[0] = ell
    lower[0], upper[0] = ell - d_ell, ell + d_ell
    for k, th in enumerate(thetas):
        x0[1 + 3 * k] = th
        x0[3 + 3 * k] = holes[k][3]
        lower[1 + 3 * k] = max(lower[1 + 3 * k], th - math.radians(7.5))
        upper[1 + 3 * k] = min(upper[1 + 3 * k], th + math.radians(7.5))
    return holes


def _hole_radius(
    ang: NDArray[np.float64],
    u: NDArray[np.float64],
    centre: float,
    half: float,
    big_r: float,
    tol: float,
) -> float:
    """Radius (m) of the branch whose hole in the run's wall (radius ``big_r``) is centred at
    ``centre`` along the axis, ``half`` long each way, from the hole's width around the
    branch's roll, measured between the nearest wall returns on either side (``ang``: their
    angles from the roll, rad; ``u``: along the axis) across its middle. A beam at angle
    ``phi`` from the roll meets the branch's wall ``rho / sin(phi)`` from the axis, within the
    wall tolerance ``tol`` of the run's wall (and so counted as wall) once
    ``sin(phi) >= rho / (R + tol)``: the nearest wall returns lie at that angle. ``big_r``
    unless the hole is clearly (10 %) narrower than a full-size branch's."""
    mid = np.abs(u - centre) < 0.4 * half
    a = ang[mid]
    left, right = a[a > 0.0], a[a < 0.0]
    if left.size == 0 or right.size == 0:
        return big_r
    width = 0.5 * float(left.min() - right.max())
    rho = (big_r + tol) * math.sin(min(width, 0.5 * math.pi))
    return max(rho, 0.25 * big_r) if rho < 0.9 * big_r else big_r


def _fits_hole(
    x: NDArray,
    holes: list[tuple[float, float, float, float]],
    big_r: float,
    lower: NDArray,
    upper: NDArray,
) -> bool:
    """Does a branch fit put every branch where its hole in the run's wall is seen, without
    resting on a deflection bound?"""
    for k, (centre, half, slack, rho) in enumerate(holes):
        th = float(x[1 + 3 * k])
        if th <= lower[1 + 3 * k] + math.radians(1.0) or th >= upper[1 + 3 * k] - math.radians(1.0):
            return False
        if abs(float(x[0]) + big_r / math.tan(th) - centre) > slack:
            return False
        if rho / math.sin(th) > half + slack:  # (a hole may look longer, never shorter)
            return False
    return True


def _straight_on(
    cloud: PipeCloud, big_r: float, big_l: float, wall: NDArray[np.bool_], cfg: ImprovedConfig
) -> tuple[bool, float]:
    """Is the incoming pipe's wall seen again well beyond the structure, all around?"""
    u = cloud.u_grid
    far = wall & (u > big_l + 4.0 * big_r)
    if far.sum() < 10:
        return False, 0.0
    cov = azimuth_coverage(cloud.points(far))
    return cov >= cfg.straight_on_coverage, cov
