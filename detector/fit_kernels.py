"""Compiled (numba) numerical kernels of the improved detector: the residual models its robust
fits use, with their Jacobians, and the whole Tukey-weighted Gauss-Newton loop of
:func:`detector.robust.robust_gauss_newton` in one compiled call.

The fits are small (150-750 residuals, 3-13 parameters) and many: in numpy their cost is the
fixed overhead of dozens of small array operations per iteration, not the arithmetic. Here one
call runs a whole fit. The loop is the same algorithm, step for step, as the numpy
:func:`~detector.robust.robust_gauss_newton` (which stays for fits with a Python residual and is
tested against this one); the models are those of :mod:`detector.axis_fit` (the pipe's wall),
:mod:`detector.branches` (outgoing pipes), :mod:`detector.long_bend` (the torus) and
:mod:`detector.axisymmetric` (a reducer's taper).

A model is named by one of the ``MODEL_*`` integers and reads its returns from ``data``
(rows of per-return values, component-first), its integer per-return values from ``ipar`` and
its scalar constants from ``fpar``:

- ``MODEL_CYLINDER``: distance to the axis through ``(0, y0, z0)`` along ``(1, a, b)`` less the
  radius; ``data`` = (u, y, z), ``fpar`` = (radius,), parameters ``(y0, z0, a, b)``.
- ``MODEL_LINES``: distance to the nearest of ``n`` outgoing cylinders whose axes meet the
  incoming axis at ``(L, 0, 0)`` less its radius; ``data`` = (x, y, z, y^2 + z^2),
  parameters ``(L, theta_1, phi_1, rho_1, ..., theta_n, phi_n, rho_n)``.
- ``MODEL_OWN_LINES``: as ``MODEL_LINES`` but each return to the cylinder of its own lobe,
  ``ipar[i]`` (``0 .. n - 1``).
- ``MODEL_TORUS``: distance to a long-radius bend's centreline less the pipe radius (forward
  differences of 1e-6 for the Jacobian); ``data`` = (x, y, z), parameters
  ``(L, theta, phi, rho, R_b)``.
- ``MODEL_TAPER``: a reducer's radius along the axis, ``r(u)`` from the wall radius to ``r2``
  over ``[L, L + T]``; ``data`` = (u, r), ``fpar`` = (wall radius,), parameters ``(L, T, r2)``.
- ``MODEL_FAR_SIDE``: a side hole's far side (:func:`detector.grazing.find_ring_holes`): the
  distance to a branch cylinder deflected by ``theta`` whose axis leaves the run's axis at
  ``x_a`` towards roll ``psi``, less its radius ``rho``, each weighted by its noise allowance;
  ``data`` = (u, r, phi, range, noise^2), ``fpar`` = (cos theta, sin theta, floor^2, and the
  forward-difference steps of the three parameters), parameters ``(x_a, rho, psi)``.

:func:`wall_distances` and :func:`wall_fit` measure how well a pose explains the wall;
:func:`coarse_branch_cost` scores the coarse grid an outgoing pipe's fit starts from.

Compiled on first use and cached on disk (``cache=True``). Lengths in metres, angles in
radians.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

MODEL_CYLINDER = 0
MODEL_LINES = 1
MODEL_OWN_LINES = 2
MODEL_TORUS = 3
MODEL_TAPER = 4
MODEL_FAR_SIDE = 5
#: Forward-difference step of the torus model's Jacobian (m, rad).
TORUS_FD_STEP = 1e-6


@njit(cache=True, fastmath=False)
def _cylinder(data, fpar, x, r, jt, want_jac):
    y0, z0, a, b = x[0], x[1], x[2], x[3]
    big_r = fpar[0]
    n = math.sqrt(1.0 + a * a + b * b)
    inv_n = 1.0 / n
    an, bn = a / n, b / n
    for i in range(data.shape[1]):
        qu = data[0, i]
        qy = data[1, i] - y0
        qz = data[2, i] - z0
        t = (qu + a * qy + b * qz) * inv_n
        dist = qu * qu + qy * qy + qz * qz - t * t
        if dist < 1e-18:
            dist = 1e-18
        dist = math.sqrt(dist)
        r[i] = dist - big_r
        if want_jac:
            inv = 1.0 / dist
            j0 = (t * an - qy) * inv
            j1 = (t * bn - qz) * inv
            tn = t * inv_n
            jt[0, i] = j0
            jt[1, i] = j1
            jt[2, i] = tn * j0
            jt[3, i] = tn * j1


@njit(cache=True)
def _line_one(px, py, pz, r2, x0, ct, st, cp, sp, rho):
    """(residual, d/dL, d/dtheta, d/dphi) of one return to one outgoing cylinder."""
    qx = px - x0
    qq = qx * qx + r2
    lat = py * cp + pz * sp
    t = ct * qx + st * lat
    dist = qq - t * t
    if dist < 1e-18:
        dist = 1e-18
    dist = math.sqrt(dist)
    g = t / dist
    return (
        dist - rho,
        ct * g - qx / dist,
        (st * qx - ct * lat) * g,
        (py * sp - pz * cp) * (st * g),
    )


@njit(cache=True)
def _lines(data, ipar, x, r, jt, want_jac, own):
    n_l = (x.size - 1) // 3
    ct = np.empty(n_l)
    st = np.empty(n_l)
    cp = np.empty(n_l)
    sp = np.empty(n_l)
    for k in range(n_l):
        ct[k] = math.cos(x[1 + 3 * k])
        st[k] = math.sin(x[1 + 3 * k])
        cp[k] = math.cos(x[2 + 3 * k])
        sp[k] = math.sin(x[2 + 3 * k])
    n_p = x.size
    for i in range(data.shape[1]):
        px, py, pz, r2 = data[0, i], data[1, i], data[2, i], data[3, i]
        if own:
            best = ipar[i]
            res, j0, j1, j2 = _line_one(
                px, py, pz, r2, x[0], ct[best], st[best], cp[best], sp[best], x[3 + 3 * best]
            )
        else:
            best = 0
            res, j0, j1, j2 = _line_one(px, py, pz, r2, x[0], ct[0], st[0], cp[0], sp[0], x[3])
            for k in range(1, n_l):
                rk, a0, a1, a2 = _line_one(
                    px, py, pz, r2, x[0], ct[k], st[k], cp[k], sp[k], x[3 + 3 * k]
                )
                if abs(rk) < abs(res):  # (the first of equals, as argmin)
                    best, res, j0, j1, j2 = k, rk, a0, a1, a2
        r[i] = res
        if want_jac:
            for p in range(n_p):
                jt[p, i] = 0.0
            jt[0, i] = j0
            jt[1 + 3 * best, i] = j1
            jt[2 + 3 * best, i] = j2
            jt[3 + 3 * best, i] = -1.0


@njit(cache=True)
def torus_distance(data, big_l, theta, phi, rb, out):
    """Distance of each return (``data`` rows x, y, z) to the centreline of a long-radius
    bend (the incoming axis up to the tangent point, an arc of radius ``rb`` turning by
    ``theta`` towards roll ``phi``, the outgoing axis; the straight axes meet at
    ``(big_l, 0, 0)``), into ``out``."""
    cp, sp = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    t1 = big_l - rb * math.tan(0.5 * theta)
    for i in range(data.shape[1]):
        px, py, pz = data[0, i], data[1, i], data[2, i]
        qa = px - t1
        if qa < 0.0:
            out[i] = math.sqrt(py * py + pz * pz)
            continue
        qy = py - rb * cp
        qz = pz - rb * sp
        qw = -(qy * cp + qz * sp)
        if ct * qa - st * qw > 0.0:  # past the end of the arc
            ox = px - big_l
            t = ox * ct + (py * cp + pz * sp) * st
            d2 = ox * ox + py * py + pz * pz - t * t
            out[i] = math.sqrt(d2) if d2 > 0.0 else 0.0
        else:
            qn = qz * cp - qy * sp
            e = math.sqrt(qa * qa + qw * qw) - rb
            out[i] = math.sqrt(e * e + qn * qn)


@njit(cache=True)
def _torus(data, x, r, jt, want_jac):
    n = data.shape[1]
    torus_distance(data, x[0], x[1], x[2], x[4], r)
    if want_jac:
        d_k = np.empty(n)
        cols = (0, 1, 2, 4)
        for k in range(4):
            xs = x.copy()
            xs[cols[k]] = x[cols[k]] + TORUS_FD_STEP
            torus_distance(data, xs[0], xs[1], xs[2], xs[4], d_k)
            row = cols[k]
            for i in range(n):
                jt[row, i] = (d_k[i] - r[i]) / TORUS_FD_STEP
        for i in range(n):
            jt[3, i] = -1.0
    rho = x[3]
    for i in range(n):
        r[i] -= rho


@njit(cache=True)
def _taper(data, fpar, x, r, jt, want_jac):
    big_l, t_len, rr2 = x[0], x[1], x[2]
    big_r = fpar[0]
    if t_len < 1e-4:
        t_len = 1e-4
    step = rr2 - big_r
    for i in range(data.shape[1]):
        raw = (data[0, i] - big_l) / t_len
        frac = min(max(raw, 0.0), 1.0)
        r[i] = data[1, i] - (big_r + step * frac)
        if want_jac:
            ramp = raw > 0.0 and raw < 1.0
            jt[0, i] = step / t_len if ramp else 0.0
            jt[1, i] = step * raw / t_len if ramp else 0.0
            jt[2, i] = -frac


@njit(cache=True)
def far_side_residuals(data, ct, st, floor2, x0, x1, x2, out):
    """The weighted residuals of :data:`MODEL_FAR_SIDE` at ``(x0, x1, x2)`` into ``out``:
    operation for operation those of :func:`detector.grazing._fit_far_side`'s numpy model."""
    for i in range(data.shape[1]):
        u = data[0, i]
        r = data[1, i]
        q = u - x0
        lat = r * math.cos(data[2, i] - x2)
        along = q * ct + lat * st
        d2 = q * q + r * r - along * along
        res = math.sqrt(max(d2, 0.0)) - x1
        dist = math.sqrt(max(d2, 1e-24))
        cos_inc = abs(u * (q - along * ct) + r * r - along * st * lat) / (dist * data[3, i])
        ci = min(cos_inc, 1.0)
        out[i] = res * math.sqrt(floor2 / (floor2 + data[4, i] * (ci * ci)))


@njit(cache=True)
def _far_side(data, fpar, x, r, jt, want_jac):
    ct, st, floor2 = fpar[0], fpar[1], fpar[2]
    far_side_residuals(data, ct, st, floor2, x[0], x[1], x[2], r)
    if want_jac:
        n = data.shape[1]
        d_k = np.empty(n)
        for k in range(3):
            xs = x.copy()
            step = fpar[3 + k]
            xs[k] = x[k] + step
            far_side_residuals(data, ct, st, floor2, xs[0], xs[1], xs[2], d_k)
            for i in range(n):
                jt[k, i] = (d_k[i] - r[i]) / step


@njit(cache=True)
def model_eval(model, data, ipar, fpar, x, r, jt, want_jac):
    """Residuals of ``model`` at ``x`` into ``r`` (N,) and, with ``want_jac``, its Jacobian
    into ``jt`` (n_params, N)."""
    if model == MODEL_CYLINDER:
        _cylinder(data, fpar, x, r, jt, want_jac)
    elif model == MODEL_LINES:
        _lines(data, ipar, x, r, jt, want_jac, False)
    elif model == MODEL_OWN_LINES:
        _lines(data, ipar, x, r, jt, want_jac, True)
    elif model == MODEL_TORUS:
        _torus(data, x, r, jt, want_jac)
    elif model == MODEL_FAR_SIDE:
        _far_side(data, fpar, x, r, jt, want_jac)
    else:
        _taper(data, fpar, x, r, jt, want_jac)


@njit(cache=True)
def _cholesky(a, low):
    """The Cholesky factor of a small symmetric ``a`` into ``low`` (lower triangle; ``low``
    zeroed by the caller). False when ``a`` is not positive definite."""
    n = a.shape[0]
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= low[j, k] * low[j, k]
        if not s > 0.0:  # (also NaN)
            return False
        d = math.sqrt(s)
        low[j, j] = d
        for i in range(j + 1, n):
            s = a[i, j]
            for k in range(j):
                s -= low[i, k] * low[j, k]
            low[i, j] = s / d
    return True


@njit(cache=True)
def _cholesky_solve(low, b, out):
    """``low low^T out = b`` by forward then back substitution."""
    n = b.size
    y = np.empty(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= low[i, k] * y[k]
        y[i] = s / low[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= low[k, i] * out[k]
        out[i] = s / low[i, i]


@njit(cache=True)
def _lu_solve(a, b, out):
    """``a out = b`` by LU with partial pivoting (``a``, ``b`` left unchanged). False when
    ``a`` is singular."""
    n = b.size
    m = a.copy()
    v = b.copy()
    for j in range(n):
        piv = j
        big = abs(m[j, j])
        for i in range(j + 1, n):
            if abs(m[i, j]) > big:
                big = abs(m[i, j])
                piv = i
        if m[piv, j] == 0.0:
            return False
        if piv != j:
            for k in range(n):
                m[j, k], m[piv, k] = m[piv, k], m[j, k]
            v[j], v[piv] = v[piv], v[j]
        for i in range(j + 1, n):
            f = m[i, j] / m[j, j]
            for k in range(j, n):
                m[i, k] -= f * m[j, k]
            v[i] -= f * v[j]
    for i in range(n - 1, -1, -1):
        s = v[i]
        for k in range(i + 1, n):
            s -= m[i, k] * out[k]
        out[i] = s / m[i, i]
    return True


@njit(cache=True)
def _solve(a, b, out):
    """``a out = b`` for a small symmetric ``a``: Cholesky, or LU with partial pivoting when
    ``a`` is not positive definite. False when ``a`` is singular."""
    n = b.size
    low = np.zeros((n, n))
    if _cholesky(a, low):
        _cholesky_solve(low, b, out)
        return True
    return _lu_solve(a, b, out)


@njit(cache=True)
def _tukey_weights(r, k2, w):
    """Tukey's biweight of each residual into ``w`` (``k2 = -1 / c^2``); returns
    ``(sum of weights, weighted cost)``."""
    w_sum = 0.0
    cost = 0.0
    for i in range(r.size):
        r2 = r[i] * r[i]
        wi = r2 * k2 + 1.0
        if wi < 0.0:
            wi = 0.0
        wi *= wi
        w[i] = wi
        w_sum += wi
        cost += wi * r2
    return w_sum, cost


@njit(cache=True)
def _normal_equations(jt, w, r, jw, h, g):
    """The weighted normal equations ``h = J^T W J`` and ``g = J^T W r`` (``jw``: scratch)."""
    n_p, n = jt.shape
    for p in range(n_p):
        for i in range(n):
            jw[i] = jt[p, i] * w[i]
        s = 0.0
        for i in range(n):
            s += jw[i] * r[i]
        g[p] = s
        for q in range(p + 1):
            s = 0.0
            for i in range(n):
                s += jw[i] * jt[q, i]
            h[p, q] = s
            h[q, p] = s


@njit(cache=True)
def _add_prior_and_pins(h, g, x, inv_prior, prior_mean, fixed, any_fixed):
    """The gaussian prior's terms, then the pinned parameters' rows and columns cleared."""
    n_p = x.size
    for p in range(n_p):
        h[p, p] += inv_prior[p]
        g[p] += inv_prior[p] * (x[p] - prior_mean[p])
    if not any_fixed:
        return
    for p in range(n_p):
        if fixed[p]:
            for q in range(n_p):
                h[p, q] = 0.0
                h[q, p] = 0.0
            h[p, p] = 1.0
            g[p] = 0.0


@njit(cache=True)
def _clipped_step(x, dx, lower, upper, xn):
    """``x - dx`` clipped to the bounds, into ``xn``."""
    for p in range(x.size):
        v = x[p] - dx[p]
        if v < lower[p]:
            v = lower[p]
        if v > upper[p]:
            v = upper[p]
        xn[p] = v


@njit(cache=True)
def _weighted_cost(w, r):
    """``sum w r^2``."""
    cost = 0.0
    for i in range(r.size):
        cost += w[i] * (r[i] * r[i])
    return cost


@njit(cache=True)
def _max_abs(v):
    """The largest ``|v_i|``."""
    big = 0.0
    for p in range(v.size):
        big = max(big, abs(v[p]))
    return big


@njit(cache=True)
def _damped_step(model, data, ipar, fpar, x, h, g, w, cost0, lam, lower, upper, rn, jn, a, work):
    """Up to four Levenberg-Marquardt tries from ``x``: the first that lowers the weighted
    cost (or any once ``lam > 1e3``) is taken. On success ``x`` is moved, ``dx`` (``work[1]``)
    holds the step actually taken, and ``rn``/``jn`` hold the residuals and Jacobian at the
    new ``x``; ``a`` is scratch. Returns ``(taken, lam, cost at the last try)``."""
    n_p = x.size
    hd = work[0]
    dx = work[1]
    xn = work[2]
    for p in range(n_p):
        hd[p] = h[p, p] + 1e-12
    cost1 = 0.0
    for _ in range(4):
        for p in range(n_p):
            for q in range(n_p):
                a[p, q] = h[p, q]
            a[p, p] += lam * hd[p]
        if not _solve(a, g, dx):
            lam *= 10.0
            continue
        _clipped_step(x, dx, lower, upper, xn)
        model_eval(model, data, ipar, fpar, xn, rn, jn, True)
        cost1 = _weighted_cost(w, rn)
        if not math.isfinite(cost1):
            lam *= 10.0
            continue
        if cost1 <= cost0 * (1.0 + 1e-9) or lam > 1e3:
            for p in range(n_p):
                dx[p] = xn[p] - x[p]
                x[p] = xn[p]
            return True, max(lam / 3.0, 1e-6), cost1
        lam *= 10.0
    return False, lam, cost1


@njit(cache=True)
def gauss_newton(
    model,
    data,
    ipar,
    fpar,
    x0,
    c,
    c_final,
    iterations,
    n_anneal,
    step_tol,
    cost_tol,
    inv_prior,
    prior_mean,
    lower,
    upper,
    fixed,
):
    """The loop of :func:`detector.robust.robust_gauss_newton` on a compiled model: returns
    ``(x, residuals)`` at the solution. ``inv_prior`` (n,): the prior's weight per parameter
    (0: none); ``lower``/``upper`` (n,): bounds (``-inf``/``inf``: none); ``fixed`` (n,): the
    parameters pinned by their bounds, left out of the steps."""
    n_p = x0.size
    n = data.shape[1]
    x = x0.copy()
    r = np.empty(n)
    jt = np.empty((n_p, n))
    rn = np.empty(n)
    jn = np.empty((n_p, n))
    model_eval(model, data, ipar, fpar, x, r, jt, True)
    lam = 1e-3
    ratio = c_final / c
    w = np.empty(n)
    jw = np.empty(n)
    h = np.empty((n_p, n_p))
    g = np.empty(n_p)
    a = np.empty((n_p, n_p))
    work = np.empty((3, n_p))  # diagonal of h, step, trial point
    any_fixed = False
    for p in range(n_p):
        any_fixed = any_fixed or fixed[p]
    for it in range(iterations):
        ci = c * ratio ** (min(it, n_anneal) / n_anneal)
        w_sum, cost0 = _tukey_weights(r, -1.0 / (ci * ci), w)
        if w_sum < n_p + 1:
            break
        _normal_equations(jt, w, r, jw, h, g)
        _add_prior_and_pins(h, g, x, inv_prior, prior_mean, fixed, any_fixed)
        taken, lam, cost1 = _damped_step(
            model, data, ipar, fpar, x, h, g, w, cost0, lam, lower, upper, rn, jn, a, work
        )
        if not taken:
            break
        r, rn = rn, r
        jt, jn = jn, jt
        if _max_abs(work[1]) < step_tol:
            break
        if it >= n_anneal and cost1 >= cost0 * (1.0 - cost_tol):
            break
    return x, r


@njit(cache=True)
def robust_fit_kernel(
    model,
    data,
    ipar,
    fpar,
    x0,
    c,
    c_final,
    iterations,
    n_anneal,
    step_tol,
    cost_tol,
    prior_sigma,
    prior_mean,
    data_sigma,
    lower,
    upper,
):
    """:func:`gauss_newton` with the prior, bounds and pinned parameters of
    :func:`detector.robust.robust_fit` set up here and Tukey's weights at the solution (cut-off
    ``c_final``): returns ``(x, residuals, weights)``. An empty ``prior_sigma``: no prior; an
    empty ``prior_mean``: the prior is centred on ``x0``; an empty ``lower`` or ``upper``: no
    bound on that side (parameters are pinned only when both are given)."""
    n_p = x0.size
    inv = np.zeros(n_p)
    pm = np.zeros(n_p)
    if prior_sigma.size:
        for p in range(n_p):
            pm[p] = prior_mean[p] if prior_mean.size else x0[p]
            q = data_sigma / prior_sigma[p]
            inv[p] = q * q if math.isfinite(prior_sigma[p]) else 0.0
    lo = np.full(n_p, -np.inf)
    up = np.full(n_p, np.inf)
    fixed = np.zeros(n_p, dtype=np.bool_)
    if lower.size:
        lo[:] = lower
    if upper.size:
        up[:] = upper
    if lower.size and upper.size:
        for p in range(n_p):
            fixed[p] = lo[p] >= up[p]
    x, r = gauss_newton(
        model,
        data,
        ipar,
        fpar,
        x0,
        c,
        c_final,
        iterations,
        n_anneal,
        step_tol,
        cost_tol,
        inv,
        pm,
        lo,
        up,
        fixed,
    )
    w = np.empty(r.size)
    k = 1.0 / (c_final * c_final)
    for i in range(r.size):
        wi = 1.0 - (r[i] * r[i]) * k
        if wi < 0.0:
            wi = 0.0
        w[i] = wi * wi
    return x, r, w


@njit(cache=True)
def coarse_branch_cost(lq, l_grid, dirs, big_r, c0):
    """The coarse start of an outgoing pipe: for each reference point ``l_grid[l]`` (m along the
    incoming axis) and direction ``dirs[:, j]`` (unit, (3, M)), the mean over the returns ``lq``
    ((n, 3)) of the squared distance from the pipe's wall (radius ``big_r``), capped at
    ``c0^2``; a return that would see the wall from outside (its normal facing the sensor at
    the origin) costs ``c0^2``. Returns (L, M)."""
    n = lq.shape[0]
    n_l = l_grid.size
    m = dirs.shape[1]
    cap = c0 * c0
    cost = np.zeros((n_l, m))
    for i in range(n):
        px, py, pz = lq[i, 0], lq[i, 1], lq[i, 2]
        r2 = py * py + pz * pz
        for j in range(m):
            lat = py * dirs[1, j] + pz * dirs[2, j]
            dp = px * dirs[0, j] + lat
            for k in range(n_l):
                qx = px - l_grid[k]
                t = qx * dirs[0, j] + lat
                d2 = qx * qx + r2 - t * t
                e = (math.sqrt(d2) if d2 > 0.0 else 0.0) - big_r
                sq = e * e
                if sq > cap or qx * px + r2 - t * dp < 0.0:
                    sq = cap
                cost[k, j] += sq
    for k in range(n_l):
        for j in range(m):
            cost[k, j] /= n
    return cost


@njit(cache=True)
def wall_distances(sp, rot, pos, big_r):
    """The returns ``sp`` ((3, n), sensor frame) under the pose ``(rot, pos)``: their position
    along the pipe axis and their distance from the wall of radius ``big_r`` (m), both (n,)."""
    n = sp.shape[1]
    u = np.empty(n)
    e = np.empty(n)
    for i in range(n):
        x, y, z = sp[0, i], sp[1, i], sp[2, i]
        u[i] = rot[0, 0] * x + rot[0, 1] * y + rot[0, 2] * z + pos[0]
        py = rot[1, 0] * x + rot[1, 1] * y + rot[1, 2] * z + pos[1]
        pz = rot[2, 0] * x + rot[2, 1] * y + rot[2, 2] * z + pos[2]
        e[i] = math.sqrt(py * py + pz * pz) - big_r
    return u, e


@njit(cache=True)
def wall_fit(e, tol, near, tol_scale):
    """Of the returns ``near`` (a mask) at distances ``e`` (m) from the wall, with tolerances
    ``tol_scale`` x ``tol`` (m): how many lie within their tolerance, the truncated quadratic
    cost ``sum min((e / tol)^2, 1)``, and the rms of ``e`` over those within (m; ``inf`` when
    none)."""
    n_ok = 0
    cost = 0.0
    sq = 0.0
    for i in range(e.size):
        if not near[i]:
            continue
        q = e[i] / (tol_scale * tol[i])
        q *= q
        if q <= 1.0:
            n_ok += 1
            sq += e[i] * e[i]
            cost += q
        else:
            cost += 1.0
    rms = math.sqrt(sq / n_ok) if n_ok else math.inf
    return n_ok, cost, rms


def residuals(
    model: int,
    data: NDArray[np.float64],
    x: NDArray[np.float64],
    ipar: NDArray[np.intp] | None = None,
    fpar: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """(N,) residuals of ``model`` at ``x`` (see the module docstring)."""
    n = data.shape[1]
    r = np.empty(n)
    jt = np.empty((1, 1))
    model_eval(
        model,
        data,
        NO_INTS if ipar is None else ipar,
        NO_FLOATS if fpar is None else fpar,
        np.asarray(x, dtype=float),
        r,
        jt,
        False,
    )
    return r


def residuals_jacobian(
    model: int,
    data: NDArray[np.float64],
    x: NDArray[np.float64],
    ipar: NDArray[np.intp] | None = None,
    fpar: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(residuals (N,), Jacobian (N, n_params))`` of ``model`` at ``x``."""
    x = np.asarray(x, dtype=float)
    n = data.shape[1]
    r = np.empty(n)
    jt = np.empty((x.size, n))
    model_eval(
        model,
        data,
        NO_INTS if ipar is None else ipar,
        NO_FLOATS if fpar is None else fpar,
        x,
        r,
        jt,
        True,
    )
    return r, jt.T


#: ``ipar`` and ``fpar`` of a model that reads none.
NO_INTS = np.zeros(0, dtype=np.intp)
NO_FLOATS = np.zeros(1)
#: An empty array: an argument of :func:`robust_fit_kernel` not given.
NOT_GIVEN = np.zeros(0)
