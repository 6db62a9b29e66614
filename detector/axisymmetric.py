"""Axisymmetric structures for the improved detector (:mod:`detector.improved`): an end wall
(closure) or a reducer, whose cone ``r(u)`` is fitted together with the wall just before it,
and where a widening starts, from its cone's rings of beams.

Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from statistics import NormalDist
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from detector.detection import Detection
from detector.fit_kernels import MODEL_TAPER
from detector.improved_config import ImprovedConfig
from detector.options import StructureOption
from detector.pipe_cloud import (
    PipeCloud,
    azimuth_coverage,
    column_medians,
    column_stats,
    even_indices,
    fit_confidence,
    partial_percentile,
    radius_mode,
    robust_line,
)
from detector.robust import mad_sigma, robust_fit, tukey_cost


def _closure(
    cloud: PipeCloud,
    big_r: float,
    anomaly: NDArray[np.bool_],
    p: NDArray[np.float64],
    u: NDArray[np.float64],
    r: NDArray[np.float64],
    tol_med: float,
    cfg: ImprovedConfig,
    diag: dict[str, Any],
) -> Detection | None:
    """A closure: the returns inside the wall ``p`` (``anomaly``; ``u`` along the axis and
    ``r`` from it, m) on a plane perpendicular to the axis, seen down to the centre, flat to
    within the range noise (tolerance ``tol_med``, m); None when they are no end wall."""
    u_med = float(partial_percentile(u, 50.0))
    tol_u = 0.003 + 2.0 * tol_med
    on_plane = np.abs(u - u_med) <= tol_u
    frac_plane = float(on_plane.mean())
    diag["closure_plane_fraction"] = frac_plane
    if np.count_nonzero(on_plane) >= cfg.min_anomaly_points:
        up = u[on_plane]
        dist = float(np.mean(up))
        spread = float(np.std(up))
        cov = azimuth_coverage(p[on_plane])
        # a cap is flat: a plane (tilted by any residual axis error) must explain it to
        # within the range noise, where the far wall of a pipe seen head-on is curved
        # (an even sample of the wall: a few hundred returns pin a plane and a quadric)
        on_idx = np.flatnonzero(on_plane)
        pick = on_idx[even_indices(on_idx.size, 2 * cfg.fit_points)]
        pp = p[pick]
        uq = pp[:, 0]
        design = np.stack([np.ones(uq.size), pp[:, 1], pp[:, 2]], axis=1)
        coef = np.linalg.lstsq(design, uq, rcond=None)[0]
        plane_rms = float(np.sqrt(np.mean((uq - design @ coef) ** 2)))
        noise_u = float(partial_percentile(cloud.values(anomaly, cloud.sigma_range_v)[pick], 50.0))
        # under range noise a curved wall can pass for a plane: a quadratic surface must
        # not explain it significantly better with a sag of millimetres (a cap's sag is
        # the quantisation, a pipe's far wall sags by a good part of its radius)
        quad = np.concatenate([design, (pp[:, 1:, None] * pp[:, None, 1:]).reshape(-1, 4)], 1)
        coef_q = np.linalg.lstsq(quad, uq, rcond=None)[0]
        rss_q = float(np.sum((uq - quad @ coef_q) ** 2))
        rss_p = plane_rms**2 * uq.size
        lr_curv = uq.size * math.log(max(rss_p, 1e-30) / max(rss_q, 1e-30))
        sag = float(np.abs(quad[:, 3:] @ coef_q[3:]).max())
        curved = lr_curv > 25.0 and sag > 0.003
        flat_plane = plane_rms <= max(3.0 * noise_u, 0.001)
        flat = flat_plane and not curved
        diag["closure_curved"] = not flat
        diag.update(
            closure_rms=spread,
            closure_plane_rms=plane_rms,
            closure_sag=sag,
            closure_curvature_lr=lr_curv,
            closure_coverage=cov,
            axisymmetric_support=1.0 if flat else 0.0,
        )
        plane_seen = frac_plane >= 0.8 and float(partial_percentile(r[on_plane], 5)) < 0.5 * big_r
        if not plane_seen:  # (not a cap seen head-on: only a clear curvature counts)
            diag["closure_curved"] = curved
        if plane_seen and spread <= 0.5 * tol_u and flat_plane:
            conf = fit_confidence(int(on_plane.sum()), spread, tol_u) * (0.5 + 0.5 * cov)
            # (a curved wall is a turn's far wall, wider than the pipe on the turn's side)
            if flat:
                seen_through = _end_wall_seen_through(cloud, big_r, dist, tol_u, conf, cfg, diag)
                if seen_through is not None:
                    return seen_through
                profiled = _wall_profile_reducer(cloud, big_r, dist, tol_u, conf, cfg, diag)
                if profiled is not None:
                    return profiled
            opt = StructureOption("closure", dist, 0.0, 0.0, 0.0, conf)
            # (curved only by the quadratic test: an end wall unless the returns show a
            # turn; the caller decides)
            diag["closure_tentative"] = not flat
            return Detection("closure", [opt], conf, diag)
    return None


def _normal_cdf(z: float) -> float:
    """The standard normal distribution function at ``z``."""
    return 0.5 * math.erfc(-z / math.sqrt(2.0))


def _end_wall_rings(
    cloud: PipeCloud, slab: NDArray[np.bool_]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The rings of beams (one per beam-angle column of the scan grid) that return from the
    end wall's plane (``slab``, over the compact returns): per ring, the share of its beams
    that do, their median distance from the axis (m), its spread (m, 10th to 90th
    percentile: small for a ring about the axis, large for one tilted or shifted off it) and
    the median radial noise (m)."""
    g, k = cloud.shape
    k = max(k, 1)
    cols = cloud.cell[slab] % k
    shares, lo, med, hi, sigmas = column_stats(cols, cloud.r_v[slab], cloud.sigma_v[slab], k, g)
    return shares, med, hi - lo, sigmas


def _end_wall_seen_through(
    cloud: PipeCloud,
    big_r: float,
    dist: float,
    tol_u: float,
    conf: float,
    cfg: ImprovedConfig,
    diag: dict[str, Any],
) -> Detection | None:
    """An end wall ``dist`` (m) ahead, flat to within ``tol_u`` (m), that is no cap of the
    incoming pipe (radius ``big_r``, m) but the end wall of a narrower or wider pipe seen
    through a reducer: a reducer then (its confidence ``conf`` halved), else None.

    Every return on the end wall's plane counts, whatever its class (a metre away the wall
    tolerance takes in the outer rings), ring of beams by ring. A cap fills the pipe: a beam
    aimed (nominally, the beam's jitter moves it by its radial noise) inside the rim returns
    from it, one aimed outside it does not (it grazes the wall on the way). So a ring that
    mostly returns from the plane from outside the rim, where a cap would return at most
    ``cfg.rim_cap_share`` of it or ``cfg.rim_share_excess`` less than it returns, means the
    pipe widens before the end wall; the ring after
    the outermost one returning, aimed inside the rim (a cap would return most of it) and
    hardly returning, means it narrows. From far away (or under a sensor that loses grazing
    returns) the reducer's own wall does not return: its start is bounded by the last wall
    return before it (the estimate) and, for a widening, by where the beams beyond the rim
    crossed the wall radius; its radius by the end wall's rings."""
    xyz, r_all = cloud.xyz_v, cloud.r_v
    u_all = xyz[0]
    slab = np.abs(u_all - dist) <= tol_u
    if not np.any(slab) or cloud.beam_step <= 0.0:
        return None
    shares, radii, spreads, sigmas = _end_wall_rings(cloud, slab)
    off = float(np.hypot(cloud.pose.position[1], cloud.pose.position[2]))
    rim = big_r - off - cfg.rim_margin  # (a beam aimed inside this meets a cap)
    # (only rings about the axis tell: a tilted or offset sensor's rings straddle the rim)
    round_ring = spreads <= cfg.rim_ring_spread * dist * cloud.beam_step + 2.6 * sigmas
    returning = shares >= cfg.rim_ring_share
    cap_share_out = np.array(
        [
            _normal_cdf((big_r + off + cfg.rim_margin - r) / max(sg, 1e-6))
            for r, sg in zip(radii, sigmas)
        ]
    )
    beyond_cap = (cap_share_out <= cfg.rim_cap_share) | (
        shares >= cap_share_out + cfg.rim_share_excess
    )
    wide = returning & round_ring & (radii > big_r) & beyond_cap
    wider = bool(np.any(wide))
    narrower = False
    if not wider and np.any(returning):
        j = int(np.argmax(np.where(returning, radii, -np.inf)))
        theta_next = math.atan2(radii[j], dist) + cloud.beam_step
        r_next = dist * math.tan(theta_next)
        # (the next ring's share on the plane, if any of it returns there)
        later = radii > radii[j] + 0.5 * dist * cloud.beam_step
        s_next = float(shares[later].max()) if np.any(later) else 0.0
        cap_next = _normal_cdf((rim - r_next) / max(float(sigmas[j]), 1e-6))
        narrower = (
            bool(round_ring[j]) and cap_next >= 0.5 and s_next <= cfg.rim_cap_share * cap_next
        )
        diag["end_wall_next_ring"] = {"radius": r_next, "share": s_next, "cap_share": cap_next}
    diag["end_wall_rings"] = int(np.count_nonzero(returning))
    if not (narrower or wider):
        return None
    # (the start: past the last return on the incoming wall before the end wall; a narrowing's
    # cone, where it returns, lies inside the wall: only returns within one noise of the wall
    # on that side count)
    dr = r_all - big_r
    inner = (4.0 if wider else 1.0) * cloud.sigma_v + cfg.rim_margin
    on_wall = (dr >= -inner) & (dr <= 4.0 * cloud.sigma_v + cfg.rim_margin) & (u_all < dist - tol_u)
    if not np.any(on_wall):  # (no wall before it to start from: nothing to say where)
        return None
    start = float(partial_percentile(u_all[on_wall], 99.0))
    # (a wall in view up to the end wall shows a cap, or a reducer, directly: the corner's
    # returns, on the wall beside the plane, are no view through anything)
    diag["end_wall_wall_gap"] = dist - start
    if dist - start < cfg.rim_wall_gap * big_r:
        return None
    if wider:
        r2 = _wider_rim(shares, radii, sigmas, cap_share_out, wide, round_ring, big_r, cloud, cfg)
        # (the beams beyond the rim crossed the wall radius before the widening ended; where
        # the wider pipe's own wall returns, its rings show where the wall left the radius)
        start = min(start, dist * big_r / r2)
        prof = wall_profile(cloud, big_r, dist, tol_u, cfg, diag)
        if prof is not None and prof.step > 0.0:
            start = min(start, prof.start)
    else:
        r2 = min(float(radii[returning].max()) + 0.5 * dist * cloud.beam_step, big_r)
        # (where the cone returns, within the wall's tolerance, the rings' medians show the
        # kink where it leaves the wall, as for a widening's cone, mirrored)
        noise = cloud.sigma_percentile(50.0)
        hinge = _ring_hinge_start(xyz, big_r - r_all, noise, start, dist - tol_u, big_r - r2, cfg)
        diag["end_wall_cone_hinge"] = hinge is not None
        if hinge is not None:
            start = hinge
    diag["end_wall_seen_through"] = "wider" if wider else "narrower"
    return _reducer_beyond(start, r2, conf, diag)


class WallProfile(NamedTuple):
    """The wall's radial profile before an end wall (see :func:`wall_profile`), m: where it
    leaves the wall (``start``), the wall's own offset from the radius it was measured
    against (``offset``) and the step off it the rings show (``step``: > 0 wider)."""

    start: float
    offset: float
    step: float


def wall_profile(
    cloud: PipeCloud, big_r: float, dist: float, tol_u: float, cfg: ImprovedConfig, diag: dict
) -> WallProfile | None:
    """The step of the wall's radial profile before an end wall ``dist`` m ahead (flat to
    within ``tol_u`` m), when the rings of beams show one; else None.

    Under range noise a gentle cone and a pipe a few millimetres narrower or wider lie within
    the incoming wall's tolerance return by return. The median offset from the wall radius
    ``big_r`` of a ring of beams (one beam angle in every plane of the sweep: about a hundred
    returns, half a ring round the axis, those within ``cfg.profile_band`` radii of the wall;
    rings with returns from at least ``cfg.cone_ring_coverage`` of the planes) is good to a
    fraction of a millimetre: flat up to the end wall for a cap, off it past a reducer's
    start. The profile ``e(u) = e0 + s clip((u - L) / T, 0, 1)`` is fitted to the rings'
    median ``u`` and offset: a coarse-to-fine grid over the start
    ``L`` and the taper's length ``T``, the offset ``e0`` and the step ``s`` by weighted least
    squares (each ring weighted by its median's scatter, at least ``cfg.profile_ring_floor``;
    a taper running past the last ring counts the step seen up to it). A step when it is at
    least ``cfg.profile_min_step``, explains the rings better than a flat wall by
    ``cfg.profile_min_lr`` (chi-square) and at least ``cfg.profile_min_rings`` rings lie
    beyond half ``cfg.profile_min_step`` on its side. Records ``profile_step``,
    ``profile_start``, ``profile_lr`` and ``profile_rings_beyond`` in ``diag`` once fitted.
    ``start`` may lie before the first ring (a cone the sensor stands at)."""
    u_all = cloud.xyz_v[0]
    e_all = cloud.r_v - big_r
    sel = (u_all < dist - tol_u) & (np.abs(e_all) < cfg.profile_band * big_r)
    g, k = cloud.shape
    if np.count_nonzero(sel) < 4 * cfg.cone_min_returns or k == 0:
        return None
    # (a ring of beams: one beam angle in every plane of the sweep, half a ring round the
    # axis; per ring the share of planes returning, the median offset and the median u)
    counts, ea, ua = column_medians(cloud.cell[sel] % k, e_all[sel], u_all[sel], k)
    keep = counts >= cfg.cone_ring_coverage * max(g, 1)
    ua, ea, na = ua[keep], ea[keep], counts[keep].astype(float)
    if ua.size < cfg.profile_min_rings + 2 or float(np.ptp(ea)) < cfg.profile_min_step:
        return None
    noise = cloud.sigma_percentile(50.0)
    sig = np.maximum(_median_scatter(noise, na), cfg.profile_ring_floor)
    w = 1.0 / np.square(sig)
    # (the flat wall, at its own radius: the wall radius measured near the sensor may take
    # in the start of a cone the sensor stands at)
    sw, se, see = float(np.sum(w)), float(np.sum(w * ea)), float(np.sum(w * ea * ea))
    chi0 = see - se * se / sw
    u_lo, u_hi = float(ua.min()), float(ua.max())
    lengths = np.geomspace(0.005, max(u_hi - u_lo, 0.006), 25)
    # a coarse grid (starts every centimetre, every other length), then around its best
    # (starts every 2 mm, every length)
    n_min = cfg.profile_min_rings
    best = _profile_grid(ua, ea, w, np.arange(u_lo - 0.02, u_hi, 0.01), lengths[::2], n_min)
    j = 2 * best[2]
    around = lengths[max(j - 2, 0) : j + 3]
    starts = np.arange(best[1] - 0.01, best[1] + 0.0101, 0.002)
    best = _profile_grid(ua, ea, w, starts, around, n_min)
    chi, start, jj, e0, step = best
    if not math.isfinite(chi):  # (no start and length separates a step from the wall)
        return None
    length = float(around[jj])
    # (the step the rings show: a taper running past the last ring is seen only so far)
    s = step * min(1.0, max(u_hi - start, 0.0) / length)
    lr = chi0 - chi
    side = np.sign(s) * (ea - e0)
    beyond = int(np.count_nonzero((ua > start) & (side >= 0.5 * cfg.profile_min_step)))
    diag.update(profile_step=s, profile_start=start, profile_lr=lr, profile_rings_beyond=beyond)
    if abs(s) < cfg.profile_min_step or lr < cfg.profile_min_lr or beyond < cfg.profile_min_rings:
        return None
    return WallProfile(start, e0, s)


def _profile_grid(
    ua: NDArray[np.float64],
    ea: NDArray[np.float64],
    w: NDArray[np.float64],
    starts: NDArray[np.float64],
    lengths: NDArray[np.float64],
    min_past: int,
) -> tuple[float, float, int, float, float]:
    """The best of the profiles ``e0 + s clip((u - L) / T, 0, 1)`` over the grid of starts
    ``L`` and lengths ``T`` (m) for the rings at ``ua`` (m) with offsets ``ea`` (m) and weights
    ``w``: ``(chi-square, L, index of T, e0, s)``; ``e0`` and ``s`` by weighted least squares;
    only starts with at least ``min_past`` rings past them count (chi-square inf when none
    does)."""
    sw, se, see = float(np.sum(w)), float(np.sum(w * ea)), float(np.sum(w * ea * ea))
    bb = np.clip((ua[None, None, :] - starts[:, None, None]) / lengths[None, :, None], 0.0, 1.0)
    wb = w * bb
    sb, sbb, sbe = np.sum(wb, axis=2), np.sum(wb * bb, axis=2), np.sum(wb * ea, axis=2)
    det = sw * sbb - sb * sb
    ok = det > 1e-9 * sw * np.maximum(sbb, 1e-30)
    det = np.where(ok, det, 1.0)
    off = (sbb * se - sb * sbe) / det
    step = (sw * sbe - sb * se) / det
    # (a step needs ``min_past`` rings past its start: fewer are fitted exactly by any step)
    past = np.count_nonzero(ua[None, :] > starts[:, None], axis=1) >= min_past
    chi = np.where(ok & past[:, None], see - off * se - step * sbe, np.inf)
    i, j = np.unravel_index(int(np.argmin(chi)), chi.shape)
    return float(chi[i, j]), float(starts[i]), int(j), float(off[i, j]), float(step[i, j])


def _wall_profile_reducer(
    cloud: PipeCloud,
    big_r: float,
    dist: float,
    tol_u: float,
    conf: float,
    cfg: ImprovedConfig,
    diag: dict[str, Any],
) -> Detection | None:
    """A reducer whose far end wall (``dist`` m ahead, flat to within ``tol_u`` m) is seen
    past it, found by the wall's radial profile (:func:`wall_profile`): the structure looked
    like a cap of the incoming pipe (radius ``big_r``, m), as the end wall beyond outnumbers
    the returns off the wall. Its confidence is ``conf`` halved; None without a step. Records
    ``end_wall_profile`` (``wider`` or ``narrower``) and ``reducer_r2`` (m)."""
    prof = wall_profile(cloud, big_r, dist, tol_u, cfg, diag)
    if prof is None:
        return None
    diag["end_wall_profile"] = "wider" if prof.step > 0.0 else "narrower"
    return _reducer_beyond(prof.start, big_r + prof.offset + prof.step, conf, diag)


def _reducer_beyond(start: float, r2: float, conf: float, diag: dict[str, Any]) -> Detection:
    """A reducer starting ``start`` m ahead (0 if behind) to radius ``r2`` (m, recorded as
    ``reducer_r2``), found past an end wall that passed for a cap: the end wall's confidence
    ``conf`` halved."""
    diag["reducer_r2"] = r2
    opt = StructureOption("reducer", max(start, 0.0), 2.0 * r2, 0.0, 0.0, 0.5 * conf)
    return Detection("reducer", [opt], 0.5 * conf, diag)


def _median_scatter(noise: float, n: NDArray[np.float64]) -> NDArray[np.float64]:
    """How much the median of ``n`` returns of radial noise ``noise`` (m) scatters, m: about
    1.25 noise / sqrt(n)."""
    return 1.25 * max(noise, 1e-5) / np.sqrt(n)


def _wider_rim(
    shares: NDArray[np.float64],
    radii: NDArray[np.float64],
    sigmas: NDArray[np.float64],
    cap_shares: NDArray[np.float64],
    wide: NDArray[np.bool_],
    round_ring: NDArray[np.bool_],
    big_r: float,
    cloud: PipeCloud,
    cfg: ImprovedConfig,
) -> float:
    """The radius (m, at least the incoming pipe's ``big_r``) of a wider pipe's end wall seen
    through a widening, from its rings of beams (``shares``, median ``radii``, radial noise
    ``sigmas``; ``cap_shares``: what a cap of the incoming pipe would return of each;
    ``wide``: the rings judged to lie beyond its rim; ``round_ring``: the rings lying round
    the axis). A ring that returns most of its
    beams lies inside the rim. A round one that returns fewer than half, but at least
    ``cfg.hole_min_returns`` beams more than a cap would, straddles it: its beams return
    where the angular jitter bends them inside the rim, so the rim lies ``sigma Phi^-1(share)``
    from the ring's radius (``Phi``: the normal CDF)."""
    g = max(cloud.shape[0], 1)
    rim = 0.0
    for j in np.flatnonzero(round_ring & (radii >= float(radii[wide].min()))):
        share = float(shares[j])
        if share >= 0.5:
            if wide[j]:
                rim = max(rim, float(radii[j]))
        elif (share - float(cap_shares[j])) * g >= cfg.hole_min_returns:
            rim = max(rim, float(radii[j]) + float(sigmas[j]) * NormalDist().inv_cdf(share))
    rim = rim if rim > 0.0 else float(radii[wide].max())
    # (a ring just past the incoming rim, straddling it, places no wider rim inside that)
    return max(rim, big_r)


def _refit_without_end_wall(
    cloud: PipeCloud,
    big_r: float,
    anomaly: NDArray[np.bool_],
    u: NDArray[np.float64],
    r: NDArray[np.float64],
    sub: NDArray[np.intp],
    n_lead: int,
    us: NDArray[np.float64],
    rs: NDArray[np.float64],
    x: NDArray[np.float64],
    u_first: float,
    tol_med: float,
    c_fin: float,
    cfg: ImprovedConfig,
    diag: dict[str, Any],
    fit: Callable[..., tuple[NDArray, NDArray, NDArray]],
) -> tuple[NDArray, NDArray, NDArray] | None:
    """A narrowing's taper refitted without the end wall far down the narrower pipe (its
    returns ``u``, ``r`` (m), the fitted ones ``us``, ``rs``: the subsample ``sub`` and
    ``n_lead`` wall returns before it; ``x`` the first fit, ``fit`` the taper fit): the refit
    ``(x, residuals, weights)``, or None when no end wall is seen through the taper."""
    u_far = partial_percentile(u, 97.0)
    # (under range noise the end wall's returns spread along the axis by their range
    # noise: a metre away, a centimetre and more either side)
    sig_range = cloud.values(anomaly, cloud.sigma_range_v)
    near_far = np.abs(u - u_far) <= 0.003 + 2.0 * tol_med
    spread_u = 3.0 * float(partial_percentile(sig_range[near_far], 50.0)) if near_far.any() else 0.0
    window = 0.003 + 2.0 * tol_med + spread_u
    far = np.abs(u - u_far) <= window
    n_far = int(np.count_nonzero(far))
    far_s = np.concatenate([far[sub], np.zeros(n_lead, dtype=bool)])
    if (
        30 <= n_far <= 0.9 * u.size
        and float(partial_percentile(r[far], 5)) < 0.3 * big_r
        and np.count_nonzero(~far_s) >= 50
        # (returns spread along a taper, not mostly on one wall: the far wall of a turn)
        and diag.get("closure_plane_fraction", 0.0) < 0.8
    ):
        # (the end wall lies inside the incoming pipe; the outermost of its returns,
        # beams along the narrower pipe's wall, bound that pipe's radius from below)
        r_end = float(partial_percentile(r[far], 98.0))
        if float(partial_percentile(r[far], 90.0)) < big_r - tol_med:
            us, rs = us[~far_s], rs[~far_s]
            # (from two starts, the lower robust cost kept, both with the plateau from the
            # farthest returns left, on the narrower pipe (the first fit, pulled onto the
            # end wall, can hold the plateau at the end wall's bound): the first fit's
            # start and length; and the first returns off the wall with a length from the
            # returns left, since the first fit's long shallow taper reaching for the end
            # wall can leave a minimum that the taper's own returns cannot pull the refit
            # out of: a 9 cm taper 30 cm ahead came out starting 40 cm late)
            u_rest, r_rest = u[~far], r[~far]
            r2_far = min(
                max(
                    float(
                        partial_percentile(r_rest[u_rest >= partial_percentile(u_rest, 90.0)], 50.0)
                    ),
                    r_end,
                ),
                big_r,
            )
            t_fresh = max(0.01, float(partial_percentile(u_rest, 30)) - u_first)
            best = None
            for k, start in enumerate(((x[0], x[1], r2_far), (u_first, t_fresh, r2_far))):
                refit = fit(
                    us,
                    rs,
                    np.array(start),
                    np.array([-0.2, 0.002, r_end]),
                    np.array([cfg.horizon, 1.0, big_r]),
                )
                cost = tukey_cost(refit[1], c_fin)
                if best is None or cost < best[0]:
                    best = (cost, refit)
                    diag["reducer_refit_start"] = ("first fit", "returns left")[k]
            diag["reducer_end_wall_radius"] = r_end
            assert best is not None  # (the loop above always keeps its first refit)
            return best[1]
    return None


def detect_axisymmetric(
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
    contraction = bool(np.count_nonzero(inside) >= np.count_nonzero(beyond))
    anomaly = inside if contraction else beyond
    if np.count_nonzero(anomaly) < cfg.min_anomaly_points:
        return Detection.straight(confidence=0.3, **diag)
    p = cloud.points(anomaly)
    u = p[:, 0]
    r = np.sqrt(np.square(p[:, 1]) + np.square(p[:, 2]))
    tol_med = float(partial_percentile(tol[anomaly], 50.0))
    # --- closure: a plane perpendicular to the axis, seen down to the centre
    if contraction:
        closure = _closure(cloud, big_r, anomaly, p, u, r, tol_med, cfg, diag)
        if closure is not None:
            return closure
    # --- reducer: r(u) = R + (R2 - R) clip((u - L) / T, 0, 1)
    if contraction:
        u_cross = u
    else:
        u_cross = u * big_r / np.maximum(r, 1e-9)  # where the beams crossed the wall radius
    u_first = float(partial_percentile(u_cross, 1))
    r2 = radius_mode(r)
    # the start of a taper is one kink in r(u): it needs a denser sample than the other fits
    sub = even_indices(u.size, 2 * cfg.fit_points)
    us, rs = u[sub], r[sub]
    n_lead = 0
    if contraction:
        # the wall just before the first returns off it: a gentle taper leaves the wall
        # tolerance only some way past its start, and the kink needs both sides
        pw = cloud.points(wall)
        lead = np.flatnonzero((pw[:, 0] > u_first - 0.15) & (pw[:, 0] < u_first))
        lead = lead[even_indices(lead.size, cfg.fit_points // 2)]
        n_lead = int(lead.size)
        us = np.concatenate([us, pw[lead, 0]])
        rs = np.concatenate([rs, np.hypot(pw[lead, 1], pw[lead, 2])])
    t0 = max(0.01, float(partial_percentile(u, 30)) - u_first)

    def fit(
        us: NDArray, rs: NDArray, start: NDArray, lower: NDArray, upper: NDArray
    ) -> tuple[NDArray, NDArray, NDArray]:
        """The taper ``r(u)`` fitted to the returns at ``us`` (m along the axis), ``rs`` (m from
        it) from ``start`` within the bounds: ``(x, residuals, weights)``."""
        return robust_fit(
            MODEL_TAPER,
            np.stack([us, rs]),
            start,
            c=max(4.0 * c_fin, 0.01),
            iterations=10,
            lower=lower,
            upper=upper,
            c_final=c_fin,
            step_tol=cfg.fit_step_tol,
            anneal=cfg.fit_anneal,
            cost_tol=cfg.fit_cost_tol,
            fpar=np.array([big_r]),
        )

    c_fin = max(2.0 * tol_med, 0.002)
    x, res, w = fit(
        us,
        rs,
        np.array([u_first, t0, r2]),
        # a widening starts where the beams leave the incoming pipe: its end edge is seen
        # directly, the cone behind it mostly not
        np.array([-0.2 if contraction else u_first, 0.002, 0.0]),
        np.array([cfg.horizon if contraction else u_first, 1.0, 3.0 * big_r]),
    )
    if contraction:
        # an end wall far down the narrower pipe, seen through it, is no part of the taper:
        # its returns pull the plateau of the fit down (too narrow, the taper too long), all
        # the way onto the end wall when grazing beams lose the narrower pipe's own wall.
        # Without them, the taper ends where its returns end; the end wall, filling the
        # narrower pipe's cross-section, still bounds its radius from below.
        refit = _refit_without_end_wall(
            cloud,
            big_r,
            anomaly,
            u,
            r,
            sub,
            n_lead,
            us,
            rs,
            x,
            u_first,
            tol_med,
            c_fin,
            cfg,
            diag,
            fit,
        )
        if refit is not None:
            x, res, w = refit
    support = float((w > 0.1).mean())
    rms = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9)))
    big_l, t_len, r2 = (float(v) for v in x)
    if not contraction:
        big_l, along = _widening_start(cloud, big_r, r2, u_first, big_l, cfg)
        diag["widening_start_from_cone"] = bool(along)
    diag.update(reducer_r2=r2, reducer_taper=t_len, reducer_rms=rms, axisymmetric_support=support)
    cov = azimuth_coverage(p)
    if not (math.isfinite(big_l) and math.isfinite(r2)):
        return Detection.straight(confidence=0.0, **diag)
    if r2 < 0.25 * big_r:
        # the pipe closes (a cap seen obliquely, or a cone to nothing): a closure at its start;
        # not when the end wall was found curved (the far wall of a pipe seen head-on)
        if diag.get("closure_curved", False):
            diag["axisymmetric_support"] = 0.0
            return Detection.straight(confidence=0.0, **diag)
        conf = 0.5 * fit_confidence(int(w.sum()), rms, c_fin) * cov
        opt = StructureOption("closure", max(big_l, 0.0), 0.0, 0.0, 0.0, conf)
        return Detection("closure", [opt], conf, diag)
    conf = fit_confidence(int((w > 0.1).sum()), rms, c_fin) * cov * min(1.0, support / 0.6)
    opt = StructureOption("reducer", max(big_l, 0.0), 2.0 * r2, 0.0, 0.0, conf)
    return Detection("reducer", [opt], conf, diag)


def _widening_start(
    cloud: PipeCloud, big_r: float, r2: float, u_first: float, default: float, cfg: ImprovedConfig
) -> tuple[float, bool]:
    """Start of a widening (m along the axis) to radius ``r2`` and whether its cone was seen
    by two or more rings of beams.

    ``u_first``: where the first beams that reach the wider pipe crossed the wall radius
    ``big_r``. The start lies between the last beams on the wall and the first past it. The
    cone's returns (off the wall by more than their noise, short of ``r2``):

    - rising over two or more rings of beams, their line reaches the wall radius at the start;
    - from one ring ``(u_c, r_c)``, its slope is unknown, but the cone through it must reach
      the wider pipe (``r2`` less a margin for the returns counted on it) before the first
      returns on the wider pipe (at ``u_f``): ``L >= (k u_c - u_f) / (k - 1)`` with
      ``k = (r2 - margin - R) / (r_c - R)``.

    Without a line, the middle of the interval left is the estimate. ``default`` when no wall
    is in view before it.
    """
    xyz, sig = cloud.xyz_v, cloud.sigma_v
    u = xyz[0]
    e = cloud.r_v - big_r
    noise = float(partial_percentile(sig, 50.0))
    rise = r2 - big_r
    margin = max(3.0 * noise, cfg.cone_plateau_margin)
    plateau = e >= rise - margin
    u_f = float(partial_percentile(u[plateau], 1.0)) if np.any(plateau) else u_first * r2 / big_r
    off_wall = np.maximum(0.00035, 4.0 * sig)
    on = (np.abs(e) <= off_wall) & (u < u_f)
    cone = (e > off_wall) & ~plateau & (u > min(u_first, u_f) - 0.1) & (u < u_f)
    # (rings all round: part rings off the wall on one side are a slightly tilted axis)
    cone[cone] = _full_rings(xyz[:, cone], cfg)
    n_cone = int(np.count_nonzero(cone))
    uc, ec = u[cone], e[cone]
    if n_cone >= 20 and float(partial_percentile(ec, 95) - partial_percentile(ec, 5)) > max(
        6.0 * noise, cfg.cone_min_rise
    ):
        # (near its start the cone lies within the noise of the wall: the line alone places
        # the start, bounded by the beams' crossings)
        a_u, b_u = robust_line(ec, uc, 1e-18, 1e-4)  # u = a + b e: the start at e = 0
        # (a cone: returns on one line to within their noise)
        if math.isfinite(a_u) and b_u > 0.0:
            scatter = mad_sigma(ec - (uc - a_u) / b_u)
            if scatter <= max(3.0 * noise, cfg.cone_line_scatter):
                return min(u_first, max(u_first - 0.1, a_u)), True
    # (under range noise the first centimetres of the cone, per return, are the wall's: the
    # rings' medians are not)
    hinge = _ring_hinge_start(xyz, e, noise, u_first, u_f, rise - margin, cfg)
    if hinge is not None:
        return hinge, True
    hi = min(u_first, u_f)
    if n_cone:
        first = uc <= uc.min() + cfg.cone_first_ring
        hi = min(hi, float(uc.min()))
    before = on & (u < hi)
    if not np.any(before):
        return default, False
    lo = float(u[before].max())
    hi = min(hi, _next_beam_crossing(cloud, big_r, lo))
    if n_cone:
        u_c, e_c = float(np.median(uc[first])), float(np.median(ec[first]))
        k = (rise - margin) / max(e_c, 1e-6)
        if k > 1.0:
            lo = max(lo, (k * u_c - u_f) / (k - 1.0))
    return (0.5 * (lo + hi) if lo <= hi else hi), False


def _next_beam_crossing(cloud: PipeCloud, big_r: float, u_last: float) -> float:
    """Where (m along the axis) the beam after the one that returned from the wall at
    ``u_last`` would have met the wall of radius ``big_r``, had the wall gone on: the wall
    ends before it when that beam would have met it within the sensor's
    ``max_incidence`` (its return would be there). ``inf`` when the beam's incidence there
    lies beyond it (the wall may go on unseen) or the sweep's beam step is unknown."""
    if cloud.beam_step <= 0.0 or u_last <= 0.0:
        return math.inf
    # (a beam jittered towards the axis meets the wall farther on: one step plus one jitter
    # sigma keeps the bound on the safe side for most beams, not for all)
    step = cloud.beam_step + cloud.angular_jitter
    alpha = math.atan2(big_r, u_last) - step  # the next beam's angle off the axis
    if alpha <= 0.5 * math.pi - cloud.max_incidence:
        return math.inf
    return big_r / math.tan(alpha)


def _ring_hinge_start(
    xyz: NDArray[np.float64],
    e: NDArray[np.float64],
    noise: float,
    u_first: float,
    u_f: float,
    e_max: float,
    cfg: ImprovedConfig,
) -> float | None:
    """Start of a widening (m along the axis) from the rings of beams before the wider pipe,
    each ring's median offset from the wall radius (``e``, m) against its position: flat on
    the wall, then rising along the cone. The kink of that hinge is the start, when at least
    two rings rise past it by more than their noise and at least one lies flat before it;
    ``None`` otherwise. Per return, the first centimetres of a gentle cone lie within a few
    times the range noise of the wall; the median of a ring of a hundred returns does not.

    ``u_first``: where the first returns off the wall crossed the wall radius (the start lies
    before it); ``u_f``: where the wider pipe's returns begin; ``e_max``: offsets beyond this
    are on the wider pipe, not the cone; ``noise``: the returns' median radial noise, m."""
    u = xyz[0]
    win = (u > u_first - cfg.hinge_reach) & (u < u_f) & (e < e_max) & (e > -4.0 * noise - 0.00035)
    if np.count_nonzero(win) < 4 * cfg.cone_min_returns:
        return None
    p, ew = xyz[:, win], e[win]
    rings = _rings(p, cfg)
    if len(rings) < 4:
        return None
    ua = np.array([float(np.median(p[0, sel])) for sel in rings])
    ea = np.array([float(np.median(ew[sel])) for sel in rings])
    na = np.array([float(np.count_nonzero(sel)) for sel in rings])
    sig_b = _median_scatter(noise, na)
    wts = 1.0 / np.square(sig_b)
    # the hinge's kink on a 1 mm grid: for each, the weighted least-squares slope of the rings
    # past it, and the misfit (a kink no ring rises past, or that falls, is no hinge)
    grid = np.arange(float(ua.min()), min(u_first, float(ua.max())), 0.001)
    if grid.size == 0:
        return None
    x = np.maximum(ua[None, :] - grid[:, None], 0.0)  # (G, rings)
    sxx = np.sum(wts * x * x, axis=1)
    b = np.sum(wts * x * ea, axis=1) / np.where(sxx > 0.0, sxx, 1.0)
    chi2 = np.sum(wts * np.square(ea - b[:, None] * x), axis=1)
    chi2 = np.where((sxx > 0.0) & (b > 0.0), chi2, np.inf)
    j = int(np.argmin(chi2))
    if not math.isfinite(float(chi2[j])):
        return None
    big_l, b = float(grid[j]), float(b[j])
    rising = (ua > big_l) & (
        b * (ua - big_l) > np.maximum(cfg.hinge_min_snr * sig_b, cfg.hinge_min_rise)
    )
    # (two rings at least, a ring on the wall before: one ring split between two bins makes
    # no slope)
    if not rising.any() or np.ptp(ua[rising]) < cfg.cone_first_ring or not np.any(ua < big_l):
        return None
    return big_l


def _rings(p: NDArray[np.float64], cfg: ImprovedConfig) -> list[NDArray[np.bool_]]:
    """The ``(3, n)`` returns in each ``cfg.cone_first_ring`` long stretch of the axis that
    holds at least ``cfg.cone_min_returns`` of them covering at least
    ``cfg.cone_ring_coverage`` of the azimuth (a ring of beams all round, not a stray return or
    part of a ring), nearest first: one mask per ring."""
    if p.shape[1] < cfg.cone_min_returns:
        return []
    span = np.clip(p[0] - p[0].min(), 0.0, 1e12)
    bins = np.floor(span / cfg.cone_first_ring).astype(np.int64)
    vals, counts = np.unique(bins, return_counts=True)  # (occupied bins only: bounded work)
    out = []
    for k in vals[counts >= cfg.cone_min_returns]:
        sel = bins == k
        if azimuth_coverage(p[:, sel].T) >= cfg.cone_ring_coverage:
            out.append(sel)
    return out


def _full_rings(p: NDArray[np.float64], cfg: ImprovedConfig) -> NDArray[np.bool_]:
    """Which of the ``(3, n)`` returns lie in a ring of beams all round (:func:`_rings`)."""
    keep = np.zeros(p.shape[1], dtype=bool)
    for sel in _rings(p, cfg):
        keep |= sel
    return keep
