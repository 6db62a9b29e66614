"""Long-radius bends for the improved detector (:mod:`detector.improved`): the torus model (the
incoming axis up to the tangent point, an arc of bend radius ``R_b``, the outgoing axis; the
straight axes meet at the reference point), its robust fit, and the returns spread evenly along
the axis that a noiseless bend's fit is polished on.

Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from detector.fit_kernels import MODEL_TORUS, torus_distance
from detector.improved_config import ImprovedConfig
from detector.outgoing import BranchFit
from detector.pipe_cloud import even_indices, partial_percentile
from detector.robust import robust_fit, tukey_cost


def _torus_dist(p: NDArray, big_l: float, theta: float, phi: float, rb: float) -> NDArray:
    """Distance (m) from the ``(N, 3)`` points to the centreline of a long-radius bend: the
    incoming axis up to the tangent point, an arc of radius ``rb`` turning by ``theta`` towards
    roll ``phi``, then the outgoing straight axis. The straight axes meet at ``(big_l, 0, 0)``
    (:func:`detector.fit_kernels.torus_distance`)."""
    out = np.empty(p.shape[0])
    torus_distance(np.ascontiguousarray(p.T), big_l, theta, phi, rb, out)
    return out


def _arc_angle(p: NDArray, big_l: float, theta: float, phi: float, rb: float) -> NDArray:
    """Arc angle (rad) of each ``(N, 3)`` point's projection on the bend of
    :func:`_torus_dist`: 0 at the tangent point on the incoming axis, ``theta`` at the arc's
    end."""
    cp, sp = math.cos(phi), math.sin(phi)
    t1 = big_l - rb * math.tan(theta / 2.0)
    qa = p[:, 0] - t1
    qw = -((p[:, 1] - rb * cp) * cp + (p[:, 2] - rb * sp) * sp)
    return np.arctan2(qa, qw)


def fit_torus(
    p: NDArray,
    big_r: float,
    big_l: float,
    f: BranchFit,
    c0: float,
    c_fin: float,
    noise: float,
    cfg: ImprovedConfig,
    p_fit: NDArray | None = None,
) -> tuple[NDArray, float, int, float] | None:
    """Long-radius bend fit to the returns ``p`` from two bend-radius starts (the second is
    skipped when the first explains nearly every return within twice their ``noise``, m),
    polished on the returns ``p_fit`` when given. Returns (x, rms, support, largest arc angle
    seen): ``x`` polished, the rms (m) and support of the fit before the polish, the arc angle
    (rad) of the polished bend; the last three over ``p``."""
    sub = p[even_indices(p.shape[0], 300)]
    data = np.ascontiguousarray(sub.T)

    lower = np.array([-0.5, math.radians(5.0), -10.0, 0.5 * big_r, 0.2 * big_r])
    upper = np.array([3.0, math.radians(175.0), 10.0, 2.0 * big_r, 8.0 * big_r])
    best = None
    # starts: the straight-axes fit with a 1.75 D arc; and a 3 D arc of 60 deg starting where
    # the returns leave the incoming pipe (near the start of a wide arc the straight-axes fit
    # settles on a shallow deflection far too near)
    u_arc = float(partial_percentile(sub[:, 0], 2.0))
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
        x, res, w = robust_fit(
            MODEL_TORUS,
            data,
            x0,
            c=c0 * 2,
            iterations=20,  # (a narrow valley: length, angle and arc radius trade off)
            lower=lower,
            upper=upper,
            c_final=c_fin,
            step_tol=cfg.fit_step_tol,
            anneal=cfg.fit_anneal,
            cost_tol=cfg.fit_cost_tol,
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
        spread = p_fit[even_indices(p_fit.shape[0], 300)]

        def spread_cost(xx: NDArray) -> float:
            return tukey_cost(_torus_dist(spread, xx[0], xx[1], xx[2], xx[4]) - xx[3], c_fin)

        x2, _, _ = robust_fit(
            MODEL_TORUS,
            np.ascontiguousarray(spread.T),
            x,
            c=c_fin,
            iterations=10,
            prior_sigma=np.array([math.inf, math.inf, math.inf, 1e-9, math.inf]),  # (rho held)
            prior_mean=x,
            lower=lower,
            upper=upper,
            step_tol=cfg.fit_step_tol,
            cost_tol=cfg.fit_cost_tol,
        )
        if spread_cost(x2) < spread_cost(x):
            x = x2
            ok = np.abs(_torus_dist(p, x[0], x[1], x[2], x[4]) - x[3]) < c_fin
    ang = _arc_angle(p, x[0], x[1], x[2], x[4])
    vis = float(np.max(ang[ok])) if ok.any() else 0.0
    return x, rms_full, n_ok, vis


def spread_along_axis(
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
    picked = [order[s0 + even_indices(c, int(k))] for s0, c, k in zip(starts, counts, take) if k]
    return idx[np.sort(np.concatenate(picked))]
