"""Small robust least-squares tools shared by the improved detector: Tukey-weighted
Gauss-Newton (Levenberg-Marquardt damped), and robust statistics.

:func:`robust_fit` runs the fit on one of the compiled residual models of
:mod:`detector.fit_kernels` (the detector's own fits: the whole loop in one compiled call);
:func:`robust_gauss_newton` is the same loop in numpy for a residual given as a Python function
(with a numeric Jacobian unless one is given). The two are tested against each other.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dgesv as _dgesv
from scipy.linalg.lapack import dposv as _dposv

from detector import fit_kernels


def tukey_weights(res: NDArray[np.float64], c: float) -> NDArray[np.float64]:
    """Tukey biweight: ``(1 - (r/c)^2)^2`` inside ``|r| < c``, 0 outside."""
    w = 1.0 - np.square(res) * (1.0 / (c * c))
    np.maximum(w, 0.0, out=w)
    w *= w
    return w


def median(x: NDArray[np.float64]) -> float:
    """``np.median`` of finite (n,) values, the same number, by partial sorting (without
    ``np.median``'s checks and copies); 0 for empty input."""
    n = x.size
    if n == 0:
        return 0.0
    h = n // 2
    if n % 2:
        return float(np.partition(x, h)[h])
    part = x.copy()  # (np.partition's copy and sort, without its wrappers)
    part.partition((h - 1, h))
    return float((part[h - 1] + part[h]) / 2.0)


def mad_sigma(x: NDArray[np.float64]) -> float:
    """Robust standard deviation (1.4826 x median absolute deviation) of finite values; 0 for
    empty input."""
    if x.size == 0:
        return 0.0
    return float(1.4826 * median(np.abs(x - median(x))))


def _residuals_and_jacobian(
    residual: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None,
    jacobian: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None,
    eps: NDArray[np.float64],
    n_p: int,
) -> Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """``x -> (residuals, Jacobian)`` of :func:`robust_gauss_newton` from ``residual`` and the
    analytic ``jacobian``, or forward differences over the ``n_p`` parameters with the steps
    ``eps`` when it is None."""
    if residual is None:
        raise ValueError("robust_gauss_newton needs residual or resjac")
    res_fn = residual

    def resjac(xv: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        rv = res_fn(xv)
        if jacobian is not None:
            return rv, jacobian(xv)
        jv = np.empty((rv.size, n_p))
        for k in range(n_p):
            xk = xv.copy()
            xk[k] += eps[k]
            jv[:, k] = (res_fn(xk) - rv) / eps[k]
        return rv, jv

    return resjac


def _prior_precision(
    x0: NDArray[np.float64],
    prior_sigma: NDArray[np.float64] | None,
    prior_mean: NDArray[np.float64] | None,
    data_sigma: float,
) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """The gaussian prior of :func:`robust_gauss_newton` as (precision relative to one
    residual's, mean), or ``(None, None)`` without one."""
    if prior_sigma is None:
        return None, None
    pm = x0 if prior_mean is None else prior_mean
    inv = np.where(np.isfinite(prior_sigma), np.square(data_sigma / np.asarray(prior_sigma)), 0.0)
    return inv, pm


def _bounds(
    lower: NDArray[np.float64] | None, upper: NDArray[np.float64] | None
) -> tuple[NDArray[np.intp] | None, NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """(indices of the parameters pinned by their bounds or None, lower, upper as floats)."""
    fixed = None
    if lower is not None and upper is not None:
        pinned = np.asarray(lower, dtype=float) >= np.asarray(upper, dtype=float)
        if pinned.any():
            fixed = np.flatnonzero(pinned)
    lo = None if lower is None else np.asarray(lower, dtype=float)
    up = None if upper is None else np.asarray(upper, dtype=float)
    return fixed, lo, up


def robust_gauss_newton(
    residual: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None,
    x0: NDArray[np.float64],
    scales: NDArray[np.float64],
    c: float,
    iterations: int = 10,
    prior_sigma: NDArray[np.float64] | None = None,
    prior_mean: NDArray[np.float64] | None = None,
    lower: NDArray[np.float64] | None = None,
    upper: NDArray[np.float64] | None = None,
    c_final: float | None = None,
    data_sigma: float = 1e-3,
    jacobian: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
    step_tol: float = 1e-7,
    resjac: Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64]]]
    | None = None,
    anneal: int | None = None,
    cost_tol: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Minimise ``sum rho_c(residual(x))`` (+ a gaussian prior) by reweighted Gauss-Newton.

    Args:
        residual: parameters -> (N,) residuals (may be ``None`` when ``resjac`` is given).
        x0: start parameters.
        scales: finite-difference step per parameter (also its natural scale).
        c: Tukey cut-off at the start, in residual units; it shrinks geometrically to
            ``c_final`` (default ``c``) over the iterations.
        prior_sigma, prior_mean: optional independent gaussian prior per parameter
            (``inf`` sigma = none).
        data_sigma: standard deviation of one residual, which weighs the data against the
            prior (MAP estimate).
        jacobian: optional analytic Jacobian ``x -> (N, n_params)``; numeric otherwise.
        step_tol: stop when every parameter step is below this.
        resjac: optional ``x -> (residuals, Jacobian)`` in one call (the cheapest form: every
            accepted trial point brings its own Jacobian); replaces ``residual`` and
            ``jacobian``.
        anneal: iterations over which the cut-off shrinks from ``c`` to ``c_final`` (default:
            all of them); after that the fit runs at ``c_final`` until it converges.
        cost_tol: also stop (once annealed) when an accepted step lowers the weighted cost
            by less than this fraction.
        lower, upper: box bounds (clipped after every step).

    Returns:
        ``(x, residuals, weights)`` at the solution.
    """
    x = np.asarray(x0, dtype=float).copy()
    n_p = x.size
    eps = np.asarray(scales, dtype=float)
    cf = c if c_final is None else c_final
    lam = 1e-3
    if resjac is None:
        resjac = _residuals_and_jacobian(residual, jacobian, eps, n_p)
    inv, pm = _prior_precision(x0, prior_sigma, prior_mean, data_sigma)
    # parameters pinned by their bounds take no part in the steps
    fixed, lo, up = _bounds(lower, upper)
    r, jac = resjac(x)
    jt = jac.T  # (n_p, N): component-first (the analytic Jacobians are built that way)
    n_anneal = max(1, iterations - 1 if anneal is None else anneal)
    ratio = cf / c
    step_diag = n_p + 1  # stride of the diagonal in a flattened (n_p, n_p) matrix
    w = np.empty_like(r)
    jw = np.empty((n_p, r.size))
    for it in range(iterations):
        ci = c * ratio ** (min(it, n_anneal) / n_anneal)
        r2 = r * r
        # Tukey weights, as tukey_weights(r, ci)
        np.multiply(r2, -1.0 / (ci * ci), out=w)
        w += 1.0
        np.maximum(w, 0.0, out=w)
        w *= w
        if float(w.sum()) < n_p + 1:
            break
        np.multiply(jt, w, out=jw)
        h = jw @ jt.T
        g = jw @ r
        h_diag = h.reshape(-1)[::step_diag]  # (a view)
        if inv is not None:
            h_diag += inv
            g += inv * (x - pm)
        if fixed is not None:
            h[fixed, :] = 0.0
            h[:, fixed] = 0.0
            h[fixed, fixed] = 1.0
            g[fixed] = 0.0
        cost0 = float(np.dot(w, r2))
        hd = h_diag + 1e-12
        step_ok = False
        for _ in range(4):
            a = h.copy()
            a.reshape(-1)[::step_diag] += lam * hd
            dx = _solve_spd(a, g)
            if dx is None:
                lam *= 10.0
                continue
            xn = x - dx
            if lo is not None:
                np.maximum(xn, lo, out=xn)
            if up is not None:
                np.minimum(xn, up, out=xn)
            rn, jn = resjac(xn)
            cost1 = float(np.dot(w, rn * rn))
            if not math.isfinite(cost1):
                lam *= 10.0
                continue
            if cost1 <= cost0 * (1.0 + 1e-9) or lam > 1e3:
                dx = xn - x  # the step taken (bounds may have clipped it)
                x, r, jt = xn, rn, jn.T
                lam = max(lam / 3.0, 1e-6)
                step_ok = True
                break
            lam *= 10.0
        if not step_ok or dx is None:
            break
        if float(np.abs(dx).max()) < step_tol:
            break
        if it >= n_anneal and cost1 >= cost0 * (1.0 - cost_tol):
            break
    w = tukey_weights(r, cf)
    return x, r, w


def robust_fit(
    model: int,
    data: NDArray[np.float64],
    x0: NDArray[np.float64],
    c: float,
    iterations: int = 10,
    prior_sigma: NDArray[np.float64] | None = None,
    prior_mean: NDArray[np.float64] | None = None,
    lower: NDArray[np.float64] | None = None,
    upper: NDArray[np.float64] | None = None,
    c_final: float | None = None,
    data_sigma: float = 1e-3,
    step_tol: float = 1e-7,
    anneal: int | None = None,
    cost_tol: float = 0.0,
    ipar: NDArray[np.intp] | None = None,
    fpar: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:func:`robust_gauss_newton` on the compiled residual model ``model`` (one of
    ``detector.fit_kernels.MODEL_*``, with its returns ``data`` (rows, N), per-return integers
    ``ipar`` and constants ``fpar``; see :mod:`detector.fit_kernels`). The other arguments are
    those of :func:`robust_gauss_newton`. Returns ``(x, residuals, weights)``: one compiled
    call (:func:`detector.fit_kernels.robust_fit_kernel`)."""
    x0 = np.asarray(x0, dtype=float)
    cf = c if c_final is None else c_final
    n_anneal = max(1, iterations - 1 if anneal is None else anneal)
    given = fit_kernels.NOT_GIVEN
    return fit_kernels.robust_fit_kernel(
        model,
        np.ascontiguousarray(data, dtype=float),
        fit_kernels.NO_INTS if ipar is None else np.ascontiguousarray(ipar, dtype=np.intp),
        fit_kernels.NO_FLOATS if fpar is None else np.ascontiguousarray(fpar, dtype=float),
        x0,
        float(c),
        float(cf),
        int(iterations),
        int(n_anneal),
        float(step_tol),
        float(cost_tol),
        given if prior_sigma is None else np.asarray(prior_sigma, dtype=float),
        given if prior_mean is None else np.asarray(prior_mean, dtype=float),
        float(data_sigma),
        given if lower is None else np.asarray(lower, dtype=float),
        given if upper is None else np.asarray(upper, dtype=float),
    )


def _solve_spd(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Solution of ``a x = b`` for a small symmetric positive definite ``a`` (Cholesky;
    LU when ``a`` is not positive definite); ``None`` when ``a`` is singular."""
    _, sol, info = _dposv(a, b)
    if info == 0:
        return sol
    _, _, sol, info = _dgesv(a, b)
    return sol if info == 0 else None


def tukey_cost(res: NDArray[np.float64], c: float) -> float:
    """Total Tukey biweight loss ``sum rho_c(r)`` (``r^2 / 2`` near 0, ``c^2 / 6`` beyond ``c``),
    in squared residual units."""
    u2 = np.minimum(np.square(res / c), 1.0)
    return float(np.sum((c * c / 6.0) * (1.0 - (1.0 - u2) ** 3)))
