"""Side openings that one ring of beams (or two or three) enters: a branch's hole in the run's
wall seen far away, between rings of beams.

A beam at elevation ``beta`` from the axis meets the wall of a pipe of radius ``R`` at
``u = R / tan(beta)``; neighbouring beams (0.5 deg apart) meet it ``u^2 / R x beam step`` apart
along the axis: 4.9 cm at 40 cm in a 57 mm pipe, about as long as a 57 mm branch's hole. The one
ring of beams that enters such a hole does not reach far past the wall: it runs on, nearly
parallel to the axis, until it meets the branch's far side, ``sqrt(rho^2 - (R sin dphi)^2)`` past
the branch's axis at ``dphi`` from its roll, and returns there a millimetre or two outside the
run's wall radius (less than the wall tolerance, so the opening detector sees none of it),
though its range is up to a few centimetres long. Compared with the rings on either side,
which lie on the wall, the ring shows a bump of returns beyond the wall over a bounded range
of roll; the far-side positions of those returns give the branch's place along the axis, its
roll, its radius and which standard deflection (90, 45 or 135 deg) it leaves at. Under range
noise (along the beam, nearly along the axis) the far side's fit weighs each return by its
noise projected on the surface; where the run's wall lies beyond the sensor's largest
incidence, returns on its radius are the far side with no ring beyond to compare with.

Everything here works on the unrolled scan grid (:mod:`detector.grid`) in the pipe frame.
Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from detector.fit_kernels import MODEL_FAR_SIDE, far_side_residuals
from detector.geometry import wrap_angle
from detector.grid import label_regions
from detector.improved_config import DEFAULT_CONFIG, ImprovedConfig
from detector.robust import robust_fit

#: Deflections of standard branch fittings tried for the branch behind a hole, rad.
DEFLECTIONS = (0.5 * math.pi, 0.25 * math.pi, 0.75 * math.pi)


#: Forward-difference steps of the far side's fit (m, m, rad): position, radius, roll.
FAR_SIDE_FD_STEPS = (1e-4, 1e-4, 1e-3)


@dataclass(frozen=True)
class RingHole:
    """A side branch's hole found through one to three rings of beams.

    Attributes:
        position: along the run's axis where the branch's axis crosses it, m (pipe frame).
        radius: the branch's inner radius, m.
        roll: roll of the branch, atan2(z, y) in the pipe frame, rad.
        n: returns in the bump.
        rms: rms of the far-side fit, m.
        entry: along the axis where the ring's beams cross the run's wall, m.
        angle: the branch's deflection from the run's axis, rad.
    """

    position: float
    radius: float
    roll: float
    n: int
    rms: float
    entry: float
    angle: float = 0.5 * math.pi


def ring_steps(
    xyz: NDArray[np.float64], valid: NDArray[np.bool_], big_r: float
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Radial residual of each return (``(G, K)`` grid) from the wall line through the returns of
    the same row in the neighbouring columns (interpolated along the axis, so a pose slightly
    off, which moves the wall smoothly, cancels), and where that line exists."""
    u = xyz[0]
    e = np.hypot(xyz[1], xyz[2]) - big_r
    step = np.zeros_like(e)
    ok = np.zeros_like(valid)
    if e.shape[1] < 3:
        return step, ok
    u0, u1, u2 = u[:, :-2], u[:, 1:-1], u[:, 2:]
    e0, e2 = e[:, :-2], e[:, 2:]
    both = valid[:, :-2] & valid[:, 1:-1] & valid[:, 2:]
    span = u2 - u0
    both &= np.abs(span) > 1e-6
    t = np.where(both, (u1 - u0) / np.where(both, span, 1.0), 0.5)
    line = e0 + t * (e2 - e0)
    step[:, 1:-1] = np.where(both, e[:, 1:-1] - line, 0.0)
    ok[:, 1:-1] = both
    return step, ok


def find_ring_holes(
    xyz: NDArray[np.float64],
    valid: NDArray[np.bool_],
    sigma_r: NDArray[np.float64],
    wraps: bool,
    big_r: float,
    before: float,
    beam_step: float,
    cfg: ImprovedConfig = DEFAULT_CONFIG,
    sigma_range: NDArray[np.float64] | None = None,
    unseen_wall: NDArray[np.bool_] | None = None,
) -> list[RingHole]:
    """Side holes that one ring of beams (or two or three) enters, nearer than ``before``
    along the axis, where the rings meet the wall sparsely (``cfg.hole_sparse_rings``).

    Args:
        xyz: (3, G, K) pipe-frame returns on the unrolled grid.
        valid: (G, K) where a return is.
        sigma_r: (G, K) radial noise of each return, m.
        wraps: whether the grid's rows wrap around the circumference.
        big_r: the run's radius, m.
        before: only holes whose ring meets the wall nearer than this, m.
        beam_step: angle between neighbouring beams of a plane, rad.
        cfg: tuning (the ``hole_*`` fields).
        sigma_range: (G, K) range noise of each return, m (``None``: none); a far side's fit
            may miss its returns by ``cfg.hole_fit_noise_k`` times it (range noise lies along
            the beam, nearly along the axis, and moves the far-side returns by that much).
        unseen_wall: (G, K) returns on the wall radius where no straight wall would return
            (beyond the sensor's largest incidence; ``None``: none): a hole's far side facing
            the sensor, bumps of their own whose rings beyond show nothing.
    """
    step, ok = ring_steps(xyz, valid, big_r)
    thr = np.maximum(cfg.hole_min_step, cfg.hole_noise_k * sigma_r)
    bump = ok & (step > thr) & (xyz[0] < before)
    unseen = None if unseen_wall is None else unseen_wall & valid & (xyz[0] < before)
    # (cheap exit: a return both a bump and unseen counts once; the count below only shrinks
    # from here, so this exit never drops a hole the full test would keep)
    n_any = np.count_nonzero(bump if unseen is None else bump | unseen)
    if n_any < cfg.hole_min_returns:
        return []
    # ... between rings that lie on the wall (the run goes on past the hole)
    on_wall = (
        np.abs(np.hypot(xyz[1], xyz[2]) - big_r) <= cfg.hole_wall_band + cfg.hole_noise_k * sigma_r
    )
    bump[:, 1:-1] &= on_wall[:, :-2] & on_wall[:, 2:]
    if unseen is not None:
        bump |= unseen
    if np.count_nonzero(bump) < cfg.hole_min_returns:
        return []
    labels, n_lab = label_regions(bump, wraps)
    g = valid.shape[0]
    # the bumps at one roll (on one ring, or on two or three neighbouring rings that a longer
    # hole lets in) are one hole
    groups: list[tuple[float, list[NDArray[np.intp]], list[NDArray[np.intp]]]] = []
    for lab in range(1, n_lab + 1):
        rows, cols = np.nonzero(labels == lab)
        phi = np.arctan2(xyz[2, rows, cols], xyz[1, rows, cols])
        centre = math.atan2(float(np.sin(phi).sum()), float(np.cos(phi).sum()))
        for c, rs, cs in groups:
            if abs(wrap_angle(centre - c)) < cfg.hole_merge_roll:
                rs.append(rows)
                cs.append(cols)
                break
        else:
            groups.append((centre, [rows], [cols]))
    # each group's fit places its branch; groups whose branches agree (a bump split where the
    # ring's step dips below the threshold) are one hole, fitted together
    fitted: list[tuple[RingHole, NDArray[np.intp], NDArray[np.intp]]] = []
    for _, rs, cs in groups:
        rows, cols = np.concatenate(rs), np.concatenate(cs)
        hole = _accepted(xyz, rows, cols, g, big_r, cfg, sigma_range)
        if hole is None:
            continue
        for k, (other, r_o, c_o) in enumerate(fitted):
            if (
                abs(wrap_angle(hole.roll - other.roll)) < cfg.hole_merge_roll
                and abs(hole.position - other.position) < big_r
            ):
                rows, cols = np.concatenate([r_o, rows]), np.concatenate([c_o, cols])
                merged = _accepted(xyz, rows, cols, g, big_r, cfg, sigma_range)
                if merged is not None:
                    fitted[k] = (merged, rows, cols)
                break
        else:
            fitted.append((hole, rows, cols))
    # (where neighbouring rings meet the wall densely, an opening leaves the wall by more than
    # its tolerance and the regular detector sees it: a bump there is something else)
    return [
        h
        for h, _, _ in fitted
        if h.entry < before
        and h.entry * h.entry / big_r * beam_step >= cfg.hole_sparse_rings * big_r
    ]


def _accepted(
    xyz: NDArray[np.float64],
    rows: NDArray[np.intp],
    cols: NDArray[np.intp],
    g: int,
    big_r: float,
    cfg: ImprovedConfig,
    sigma_range: NDArray[np.float64] | None = None,
) -> RingHole | None:
    """The hole fitted to the bump returns at ``(rows, cols)`` of a grid of ``g`` rows, if the
    bump is one: enough returns and rows, on at most ``cfg.hole_max_rings`` rings, not all
    around (``sigma_range``: the (G, K) range noise of the returns, m, or ``None``)."""
    n_rows = np.unique(rows).size
    if rows.size < cfg.hole_min_returns or n_rows < cfg.hole_min_returns:
        return None
    if np.ptp(cols) > cfg.hole_max_rings - 1:
        return None  # a long opening: the regular detector's
    if n_rows * 2.0 * math.pi / g > cfg.hole_max_roll_span:
        return None  # (almost) all around: a widening, not a side hole
    noise = None if sigma_range is None else sigma_range[rows, cols]
    return _fit_far_side(xyz[:, rows, cols], big_r, cfg, noise)


def _fit_far_side(
    p: NDArray[np.float64],
    big_r: float,
    cfg: ImprovedConfig,
    sigma_range: NDArray[np.float64] | None = None,
) -> RingHole | None:
    """Fit a branch to the far-side returns ``p`` (3, n): a cylinder of radius ``rho`` whose
    axis leaves the run's axis at ``position``, deflected by a standard fitting angle (90 deg
    first, then 45 and 135 deg: the patch a ring sees cannot measure the deflection, only tell
    these apart) towards ``roll``; the deflection whose returns lie closest to it for their
    noise wins, if they lie within it. Each return's distance from the surface is measured
    against ``cfg.hole_max_fit_rms`` (m) and ``cfg.hole_fit_noise_k`` times its range noise
    (``sigma_range``, (n,) m; ``None``: none) projected on the surface's normal (the cosine of
    the incidence): the range noise lies along the beam, which meets a 90 deg branch's far side
    head-on and the inclined far sides of 45 and 135 deg fittings obliquely, moving their
    returns less across them. The returns are weighted by ``cfg.hole_max_fit_rms`` over that
    allowance, and their weighted rms must be at most ``cfg.hole_max_fit_rms`` (without range
    noise: their rms). Another deflection replaces 90 deg only when its weighted rms is below
    ``cfg.hole_deflection_ratio`` times that of 90 deg. The fit starts from a branch of
    ``cfg.hole_start_radius`` radii and may turn by ``cfg.hole_roll_reach`` from the returns'
    roll."""
    u = p[0]
    r = np.hypot(p[1], p[2])
    phi = np.arctan2(p[2], p[1])
    rng = np.hypot(u, r)  # (the beams leave the sensor, near the axis at u = 0)
    floor2 = cfg.hole_max_fit_rms**2
    noise2 = (
        np.zeros_like(u) if sigma_range is None else np.square(cfg.hole_fit_noise_k * sigma_range)
    )
    data = np.ascontiguousarray(np.stack([u, r, phi, rng, noise2]))
    bare = data.copy()
    bare[4] = 0.0
    raw = np.empty(u.size)
    # roll: the circular mean weighted by how far along each return went
    w = u - float(u.min()) + 1e-4
    roll0 = math.atan2(float(np.sum(w * np.sin(phi))), float(np.sum(w * np.cos(phi))))
    best: RingHole | None = None
    best_ratio = math.inf
    square_fits = False  # (the 90 deg fit was accepted)
    for theta in DEFLECTIONS:
        ct, st = math.cos(theta), math.sin(theta)
        rho0 = cfg.hole_start_radius * big_r
        # (the far side lies about rho / sin(theta) past where the axis crosses the wall)
        x_start = float(np.median(u)) - rho0 / st - big_r * ct / st
        x0 = np.array([x_start, rho0, roll0])

        lower = np.array([x_start - 3.0 * big_r, 0.2 * big_r, roll0 - cfg.hole_roll_reach])
        upper = np.array([x_start + 3.0 * big_r, 1.05 * big_r, roll0 + cfg.hole_roll_reach])
        fpar = np.array([ct, st, floor2, *FAR_SIDE_FD_STEPS])
        x, res, _ = robust_fit(
            MODEL_FAR_SIDE,
            data,
            x0,
            c=0.01,
            c_final=0.003,
            iterations=30,
            lower=lower,
            upper=upper,
            step_tol=1e-7,
            fpar=fpar,
        )
        if not np.all(np.isfinite(x)):
            continue
        ratio = float(np.sqrt(np.mean(np.square(res)))) / cfg.hole_max_fit_rms
        if square_fits:
            # (a tee's or a cross's 90 deg, tried first, stands unless another fits clearly
            # better: the deflection trades against the branch's place along the axis, and
            # under range noise the fits differ by a few per cent)
            ratio /= cfg.hole_deflection_ratio
        if ratio > 1.0 or (best is not None and ratio >= best_ratio):
            continue
        best_ratio = ratio
        square_fits = square_fits or theta == DEFLECTIONS[0]
        # (the unweighted distances: the same model without range noise)
        far_side_residuals(bare, ct, st, floor2, x[0], x[1], x[2], raw)
        rms = float(np.sqrt(np.mean(np.square(raw))))
        entry = float(np.median(u * big_r / np.maximum(r, 1e-9)))
        best = RingHole(
            float(x[0]), float(x[1]), wrap_angle(float(x[2])), int(u.size), rms, entry, theta
        )
    return best
