"""Long-radius bends for the improved detector (:mod:`detector.improved`): the torus model (the
incoming axis up to the tangent point, an arc of bend radius ``R_b``, the outgoing axis; the
straight axes meet at the reference point), its robust fit, and the returns spread evenly along
the axis that a noiseless bend's fit is polished on.

Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from detector.pipe_cloud import ANNEAL, COST_TOL, STEP_TOL, _dir, _pct, _subsample
from detector.robust import robust_gauss_newton, tukey_cost

if TYPE_CHECKING:
    from detector.branches import BranchFit


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


def _torus_dist_batch(p: NDArray, params: NDArray) -> NDArray:
    """:func:`_torus_dist` for ``M`` parameter sets at once: ``params`` (M, 4) of
    ``(big_l, theta, phi, rb)``; returns (M, N)."""
    big_l, theta, phi, rb = (params[:, k : k + 1] for k in range(4))
    cp, sp = np.cos(phi), np.sin(phi)
    ct, st = np.cos(theta), np.sin(theta)
    px, py, pz = p[:, 0], p[:, 1], p[:, 2]
    qa = px - (big_l - rb * np.tan(0.5 * theta))
    qy = py - rb * cp
    qz = pz - rb * sp
    qw = -(qy * cp + qz * sp)
    qn = qz * cp - qy * sp
    d_arc = np.sqrt((np.sqrt(qa * qa + qw * qw) - rb) ** 2 + qn * qn)
    # outgoing straight axis through (big_l, 0, 0) along (ct, st cp, st sp)
    ox = px - big_l
    t = ox * ct + (py * cp + pz * sp) * st
    d_out = np.sqrt(np.maximum(ox * ox + py * py + pz * pz - t * t, 0.0))
    d_in = np.sqrt(py * py + pz * pz)
    # arc angle of the projection: < 0 before the tangent point, > theta past the arc end
    # (theta < pi), tested without arctan2
    past = (qa >= 0.0) & (ct * qa - st * qw > 0.0)
    return np.where(qa < 0.0, d_in, np.where(past, d_out, d_arc))


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
    d_arc = np.sqrt((np.sqrt(np.square(qa) + np.square(qw)) - rb) ** 2 + qn**2)
    d_out = _line_dist(p, np.array([big_l, 0.0, 0.0]), _dir(theta, phi))
    d_in = np.sqrt(np.square(p[:, 1]) + np.square(p[:, 2]))
    return np.where(ang < 0.0, d_in, np.where(ang > theta, d_out, d_arc)), ang


def _fit_torus(
    p: NDArray,
    big_r: float,
    big_l: float,
    f: BranchFit,
    c0: float,
    c_fin: float,
    noise: float,
    p_fit: NDArray | None = None,
) -> tuple[NDArray, float, int, float] | None:
    """Long-radius bend fit to the returns ``p`` from two bend-radius starts (the second is
    skipped when the first explains nearly every return within twice their ``noise``, m),
    polished on the returns ``p_fit`` when given. Returns (x, rms, support, largest arc angle
    seen): ``x`` polished, the rms (m) and support of the fit before the polish, the arc angle
    (rad) of the polished bend; the last three over ``p``."""
    sub = p[_subsample(np.arange(p.shape[0]), 300)]
    steps = np.vstack([np.zeros(4), np.diag(np.full(4, 1e-6))])  # (5, 4)
    cols = np.array([0, 1, 2, 4])

    def resjac_on(pts: NDArray) -> Callable[[NDArray], tuple[NDArray, NDArray]]:
        def resjac(x: NDArray) -> tuple[NDArray, NDArray]:
            # residual and forward-difference Jacobian from one batched evaluation
            dist = _torus_dist_batch(pts, x[cols] + steps)
            jac = np.empty((pts.shape[0], 5))
            jac[:, cols] = ((dist[1:] - dist[0]) / 1e-6).T
            jac[:, 3] = -1.0
            return dist[0] - x[3], jac

        return resjac

    resjac = resjac_on(sub)

    lower = np.array([-0.5, math.radians(5.0), -10.0, 0.5 * big_r, 0.2 * big_r])
    upper = np.array([3.0, math.radians(175.0), 10.0, 2.0 * big_r, 8.0 * big_r])
    best = None
    # starts: the straight-axes fit with a 1.75 D arc; and a 3 D arc of 60 deg starting where
    # the returns leave the incoming pipe (near the start of a wide arc the straight-axes fit
    # settles on a shallow deflection far too near)
    u_arc = float(_pct(sub[:, 0], 2.0))
    rb_wide = 3.0 * 2.0 * big_r
    starts = [
        np.array([big_l, f.theta, f.phi, big_r, 1.75 * 2.0 * big_r]),
        np.array(
            [
                u_arc + rb_wide * math.tan(math.radians(30.0)),
                math.radians(60.0),
                f.phi,
                big_r,
                rb_wide,
            ]
        ),
    ]
    for x0 in starts:
        x, res, w = robust_gauss_newton(
            None,
            x0,
            np.full(5, 1e-6),
            resjac=resjac,
            c=c0 * 2,
            iterations=20,  # (a narrow valley: length, angle and arc radius trade off)
            lower=lower,
            upper=upper,
            c_final=c_fin,
            step_tol=STEP_TOL,
            anneal=ANNEAL,
            cost_tol=COST_TOL,
        )
        rms = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9)))
        sup = int((w > 0.1).sum())
        if best is None or (sup, -rms) > (best[2], -best[1]):
            best = (x, rms, sup)
        if sup >= 0.98 * sub.shape[0] and rms <= min(0.3 * c_fin, 2.0 * noise):
            break  # (the first start explains nearly every return closely already)
    if best is None:
        return None
    x, rms, sup = best
    # the evidence for the model (rms and support over ``p``) is the fit's before any polish:
    # the polish refines a bend's parameters, it does not decide whether there is a bend
    res_full = _torus_dist(p, x[0], x[1], x[2], x[4]) - x[3]
    ok = np.abs(res_full) < c_fin
    n_ok = int(ok.sum())
    rms_full = float(np.sqrt(np.mean(res_full[ok] ** 2))) if n_ok else math.inf
    if p_fit is not None and p_fit.shape[0] >= 40:
        # polish on the returns spread along the axis, from the fit found, the pipe's radius
        # held: the far end of the arc, a few returns of hundreds, fixes the angle (kept when
        # it lowers the robust cost over them). The caller passes them for a noiseless sensor
        # only: under range noise those few far returns scatter by millimetres, and weighing
        # them as much as the wall near the sensor adds more scatter to the angle than it
        # takes bias out of it.
        spread = p_fit[_subsample(np.arange(p_fit.shape[0]), 300)]

        def spread_cost(xx: NDArray) -> float:
            return tukey_cost(_torus_dist(spread, xx[0], xx[1], xx[2], xx[4]) - xx[3], c_fin)

        x2, _, _ = robust_gauss_newton(
            None,
            x,
            np.full(5, 1e-6),
            resjac=resjac_on(spread),
            c=c_fin,
            iterations=10,
            prior_sigma=np.array([math.inf, math.inf, math.inf, 1e-9, math.inf]),  # (rho held)
            prior_mean=x,
            lower=lower,
            upper=upper,
            step_tol=STEP_TOL,
            cost_tol=COST_TOL,
        )
        if spread_cost(x2) < spread_cost(x):
            x = x2
            ok = np.abs(_torus_dist(p, x[0], x[1], x[2], x[4]) - x[3]) < c_fin
    _, ang = _torus_parts(p, x[0], x[1], x[2], x[4])
    vis = float(np.max(ang[ok])) if ok.any() else 0.0
    return x, rms_full, n_ok, vis


def _spread_along_axis(
    idx: NDArray[np.intp], u: NDArray[np.float64], n: int, bins: int = 20
) -> NDArray[np.intp]:
    """``n`` of the returns ``idx`` (all of them when there are fewer), spread evenly along the
    axis (``u``: their axial coordinates, m): each of ``bins`` equal stretches of their axial
    extent gives an equal share, or all its returns when it holds fewer (what it leaves goes to
    the fuller stretches), so a sparse far stretch weighs as much as the dense near wall."""
    if idx.size <= n:
        return idx
    lo, hi = float(u.min()), float(u.max())
    which = np.minimum(((u - lo) / max(hi - lo, 1e-9) * bins).astype(np.intp), bins - 1)
    order = np.argsort(which, kind="stable")
    counts = np.bincount(which, minlength=bins)
    take = np.zeros(bins, dtype=np.intp)
    left, sharing = n, int(np.count_nonzero(counts))
    for b in np.argsort(counts, kind="stable"):  # the sparsest stretches first
        if counts[b]:
            take[b] = min(int(counts[b]), left // sharing)
            left -= int(take[b])
            sharing -= 1
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    picked = [
        order[s0 + _subsample(np.arange(c), k)] for s0, c, k in zip(starts, counts, take) if k
    ]
    return idx[np.sort(np.concatenate(picked))]
