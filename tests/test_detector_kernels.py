"""The compiled fit kernels (:mod:`detector.fit_kernels`) against numpy: each residual model and
its Jacobian against a numpy implementation of the same geometry, the compiled Gauss-Newton
loop against the numpy one (:func:`detector.robust.robust_gauss_newton`) on the same problems,
and the small linear solve against numpy's."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from detector import fit_kernels as fk
from detector.axis_fit import _axis_returns, _off_wall_entries, _radius_under_pose_error
from detector.grid import build_grid, label_regions
from detector.improved_config import DEFAULT_CONFIG
from detector.pipe_cloud import (
    _crop,
    _gather_cropped,
    _gather_returns,
    _masked_columns,
    _pattern,
    _radii,
    _scatter,
    _sloped_tolerance,
    _spread_exceeds,
    azimuth_coverage,
    column_medians,
    column_stats,
    even_indices,
    median_rise,
    partial_percentile,
    partial_percentiles,
    region_sizes,
    significant_regions,
)
from detector.robust import mad_sigma, median, robust_fit, robust_gauss_newton
from detector.scan import Scan


# --------------------------------------------------------------------------- numpy references
def cylinder_np(sub: np.ndarray, big_r: float, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance to the axis through (0, y0, z0) along (1, a, b), less ``big_r``; (N, 4)."""
    y0, z0, a, b = x
    n = math.sqrt(1.0 + a * a + b * b)
    qu, qy, qz = sub[0], sub[1] - y0, sub[2] - z0
    t = (qu + a * qy + b * qz) / n
    dist = np.sqrt(np.maximum(qu * qu + qy * qy + qz * qz - t * t, 1e-18))
    jac = np.empty((qu.size, 4))
    jac[:, 0] = (t * (a / n) - qy) / dist
    jac[:, 1] = (t * (b / n) - qz) / dist
    jac[:, 2] = t / n * jac[:, 0]
    jac[:, 3] = t / n * jac[:, 1]
    return dist - big_r, jac


def lines_np(
    pts: np.ndarray, x: np.ndarray, own: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Distance to the nearest (or own) of the outgoing cylinders ``[L, theta, phi, rho] x n``."""
    px, py, pz, r2 = pts
    n_l = (x.size - 1) // 3
    th, ph, rho = x[1::3], x[2::3], x[3::3]
    ct, stt, cp, sp = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph)
    qx = px - x[0]
    lat = cp[:, None] * py + sp[:, None] * pz
    t = ct[:, None] * qx + stt[:, None] * lat
    dist = np.sqrt(np.maximum(qx * qx + r2 - t * t, 1e-18))
    res = dist - rho[:, None]
    arg = np.argmin(np.abs(res), axis=0) if own is None else own
    cols = np.arange(px.size)
    g = t[arg, cols] / dist[arg, cols]
    jac = np.zeros((px.size, 1 + 3 * n_l))
    jac[:, 0] = ct[arg] * g - qx / dist[arg, cols]
    k = 1 + 3 * arg
    jac[cols, k] = (stt[arg] * qx - ct[arg] * lat[arg, cols]) * g
    jac[cols, k + 1] = (py * sp[arg] - pz * cp[arg]) * (stt[arg] * g)
    jac[cols, k + 2] = -1.0
    return res[arg, cols], jac


def torus_dist_np(p: np.ndarray, big_l: float, theta: float, phi: float, rb: float) -> np.ndarray:
    """Distance from (N, 3) points to a long bend's centreline (numpy, angle-based)."""
    cp, sp = math.cos(phi), math.sin(phi)
    qa = p[:, 0] - (big_l - rb * math.tan(theta / 2.0))
    qy, qz = p[:, 1] - rb * cp, p[:, 2] - rb * sp
    qw = -(qy * cp + qz * sp)
    qn = qz * cp - qy * sp
    ang = np.arctan2(qa, qw)
    d_arc = np.sqrt((np.hypot(qa, qw) - rb) ** 2 + qn**2)
    d = np.array([math.cos(theta), math.sin(theta) * cp, math.sin(theta) * sp])
    q = p - np.array([big_l, 0.0, 0.0])
    t = q @ d
    d_out = np.sqrt(np.maximum(np.sum(q * q, axis=1) - t * t, 0.0))
    d_in = np.hypot(p[:, 1], p[:, 2])
    return np.where(ang < 0.0, d_in, np.where(ang > theta, d_out, d_arc))


def taper_np(
    us: np.ndarray, rs: np.ndarray, big_r: float, x: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A reducer's radius ramp from ``big_r`` to ``x[2]`` over ``[x[0], x[0] + x[1]]``."""
    big_l, t_len, rr2 = x
    t_len = max(t_len, 1e-4)
    raw = (us - big_l) / t_len
    frac = np.clip(raw, 0.0, 1.0)
    ramp = (raw > 0.0) & (raw < 1.0)
    jac = np.stack(
        [
            np.where(ramp, (rr2 - big_r) / t_len, 0.0),
            np.where(ramp, (rr2 - big_r) * raw / t_len, 0.0),
            -frac,
        ],
        axis=1,
    )
    return rs - (big_r + (rr2 - big_r) * frac), jac


def pipe_wall(rng: np.random.Generator, n: int, big_r: float, noise: float) -> np.ndarray:
    """(3, n) returns on the wall of a pipe along x (0-30 cm), offset and noisy."""
    ang = rng.uniform(0.0, 2.0 * math.pi, n)
    r = big_r + rng.normal(0.0, noise, n)
    return np.stack([rng.uniform(0.0, 0.3, n), r * np.cos(ang) + 0.002, r * np.sin(ang) - 0.001])


seeds = st.integers(0, 2**31 - 1)


# --------------------------------------------------------------------------- the models
@settings(max_examples=30, deadline=None)
@given(seeds)
def test_cylinder_model_matches_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    sub = pipe_wall(rng, 200, 0.05, 0.001)
    x = rng.normal(0.0, [0.005, 0.005, 0.05, 0.05])
    r, jac = fk.residuals_jacobian(fk.MODEL_CYLINDER, sub, x, fpar=np.array([0.05]))
    r_np, jac_np = cylinder_np(sub, 0.05, x)
    np.testing.assert_allclose(r, r_np, rtol=0, atol=1e-12)
    np.testing.assert_allclose(jac, jac_np, rtol=1e-9, atol=1e-11)


@settings(max_examples=30, deadline=None)
@given(seeds, st.integers(1, 4), st.booleans())
def test_line_models_match_numpy(seed: int, n_l: int, own: bool) -> None:
    rng = np.random.default_rng(seed)
    p = rng.normal(0.0, 0.05, (150, 3))
    pts = np.stack([p[:, 0], p[:, 1], p[:, 2], p[:, 1] ** 2 + p[:, 2] ** 2])
    x = np.concatenate(
        [[rng.uniform(-0.1, 0.4)]]
        + [[rng.uniform(0.4, 2.6), rng.uniform(-3, 3), rng.uniform(0.02, 0.06)] for _ in range(n_l)]
    )
    labels = rng.integers(0, n_l, p.shape[0]).astype(np.intp) if own else None
    model = fk.MODEL_OWN_LINES if own else fk.MODEL_LINES
    r, jac = fk.residuals_jacobian(model, pts, x, ipar=labels)
    r_np, jac_np = lines_np(pts, x, labels)
    np.testing.assert_allclose(r, r_np, rtol=0, atol=1e-12)
    np.testing.assert_allclose(jac, jac_np, rtol=1e-9, atol=1e-11)
    np.testing.assert_array_equal(fk.residuals(model, pts, x, ipar=labels), r)


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_torus_model_matches_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    big_l, theta, phi, rho, rb = (
        rng.uniform(0.1, 0.5),
        rng.uniform(0.3, 1.6),
        rng.uniform(-3, 3),
        0.05,
        rng.uniform(0.05, 0.4),
    )
    p = rng.normal(0.0, 0.1, (200, 3))
    p[:, 0] = rng.uniform(-0.1, 0.8, 200)
    x = np.array([big_l, theta, phi, rho, rb])
    r, jac = fk.residuals_jacobian(fk.MODEL_TORUS, np.ascontiguousarray(p.T), x)
    np.testing.assert_allclose(r, torus_dist_np(p, big_l, theta, phi, rb) - rho, atol=1e-12)
    # forward differences of the same distance
    for col in (0, 1, 2, 4):
        xs = x.copy()
        xs[col] += fk.TORUS_FD_STEP
        fd = (torus_dist_np(p, xs[0], xs[1], xs[2], xs[4]) - (r + rho)) / fk.TORUS_FD_STEP
        np.testing.assert_allclose(jac[:, col], fd, atol=1e-5)
    assert np.all(jac[:, 3] == -1.0)


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_taper_model_matches_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    us = rng.uniform(-0.1, 0.5, 120)
    rs = rng.uniform(0.02, 0.06, 120)
    x = np.array([rng.uniform(0.0, 0.3), rng.uniform(0.0, 0.2), rng.uniform(0.02, 0.06)])
    r, jac = fk.residuals_jacobian(fk.MODEL_TAPER, np.stack([us, rs]), x, fpar=np.array([0.05]))
    r_np, jac_np = taper_np(us, rs, 0.05, x)
    np.testing.assert_allclose(r, r_np, rtol=0, atol=1e-12)
    np.testing.assert_allclose(jac, jac_np, rtol=1e-9, atol=1e-11)


# --------------------------------------------------------------------------- the loop
@settings(max_examples=25, deadline=None)
@given(seeds, st.booleans(), st.booleans())
def test_compiled_loop_matches_numpy_loop(seed: int, prior: bool, bounded: bool) -> None:
    """The same fit, step for step: the compiled loop and the numpy one on the same residuals."""
    rng = np.random.default_rng(seed)
    sub = pipe_wall(rng, 250, 0.05, float(rng.uniform(0.0, 0.002)))
    sub[:, :25] *= 1.3  # (outliers)
    kw = {
        "c": 0.02,
        "iterations": 10,
        "c_final": 0.004,
        "step_tol": 1e-6,
        "anneal": 3,
        "cost_tol": 1e-4,
    }
    if prior:
        kw["prior_sigma"] = np.array([0.01, 0.01, 0.05, np.inf])
    if bounded:
        kw["lower"] = np.array([-0.01, -0.01, 0.0, -0.1])
        kw["upper"] = np.array([0.01, 0.01, 0.0, 0.1])  # (the third pinned)
    x0 = rng.normal(0.0, [0.002, 0.002, 0.0, 0.01])
    x_c, r_c, w_c = robust_fit(fk.MODEL_CYLINDER, sub, x0, fpar=np.array([0.05]), **kw)
    x_n, r_n, w_n = robust_gauss_newton(
        None, x0, np.full(4, 1e-5), resjac=lambda v: cylinder_np(sub, 0.05, v), **kw
    )
    np.testing.assert_allclose(x_c, x_n, rtol=0, atol=1e-10)
    np.testing.assert_allclose(r_c, r_n, rtol=0, atol=1e-10)
    np.testing.assert_allclose(w_c, w_n, rtol=0, atol=1e-8)


def test_compiled_loop_recovers_a_junction() -> None:
    """Two outgoing pipes fitted from a coarse start find the ones the returns lie on."""
    rng = np.random.default_rng(3)
    truth = np.array([0.3, math.radians(90), 0.4, 0.05, math.radians(45), 0.4 + math.pi, 0.04])
    pts = []
    for k in range(2):
        th, ph, rho = truth[1 + 3 * k : 4 + 3 * k]
        d = np.array([math.cos(th), math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph)])
        e1 = np.cross(d, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(d, e1)
        s = rng.uniform(0.06, 0.2, 150)
        a = rng.uniform(0, 2 * math.pi, 150)
        pts.append(
            np.array([truth[0], 0, 0])
            + s[:, None] * d
            + rho * np.cos(a)[:, None] * e1
            + rho * np.sin(a)[:, None] * e2
        )
    p = np.vstack(pts)
    data = np.stack([p[:, 0], p[:, 1], p[:, 2], p[:, 1] ** 2 + p[:, 2] ** 2])
    x0 = truth + np.array([0.02, 0.1, 0.1, 0.005, -0.1, 0.1, 0.005])
    x, res, w = robust_fit(fk.MODEL_LINES, data, x0, c=0.02, c_final=0.003, iterations=30)
    np.testing.assert_allclose(x, truth, atol=1e-6)
    assert float(np.abs(res).max()) < 1e-8


@pytest.mark.parametrize("n", [1, 3, 7, 13])
def test_solve_matches_numpy(n: int) -> None:
    rng = np.random.default_rng(n)
    m = rng.normal(size=(n, n))
    b = rng.normal(size=n)
    out = np.empty(n)
    spd = m @ m.T + n * np.eye(n)
    assert fk._solve(spd, b, out)
    np.testing.assert_allclose(out, np.linalg.solve(spd, b), rtol=1e-10)
    sym = m + m.T  # (indefinite: the LU path)
    assert fk._solve(sym, b, out)
    np.testing.assert_allclose(out, np.linalg.solve(sym, b), rtol=1e-8)
    if n > 1:
        singular = np.zeros((n, n))
        singular[0, 0] = 1.0
        assert not fk._solve(singular, b, out)


# --------------------------------------------------------------------------- region labels
def label_regions_ndimage(mask: np.ndarray, wraps: bool) -> tuple[np.ndarray, int]:
    """Reference labelling: scipy's 8-connected labels, regions touching across the row seam
    joined, numbered in the raster order of their first cell."""
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if n and wraps and mask.shape[0] >= 3:
        parent = np.arange(n + 1)

        def find(x: int) -> int:
            while parent[x] != x:
                x = parent[x]
            return x

        first, last = labels[0], labels[-1]
        for a, b in zip(
            np.concatenate([last, last[1:], last[:-1]]),
            np.concatenate([first, first[:-1], first[1:]]),
        ):
            if a and b:
                ra, rb = find(int(a)), find(int(b))
                parent[max(ra, rb)] = min(ra, rb)
        roots = np.array([find(i) for i in range(n + 1)])
        uniq, relabel = np.unique(roots, return_inverse=True)
        labels, n = relabel[labels], uniq.size - 1
    return labels.astype(np.int32), int(n)


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(1, 30), st.integers(1, 30), st.floats(0.05, 0.7), st.booleans())
def test_label_regions_matches_ndimage(
    seed: int, rows: int, cols: int, density: float, wraps: bool
) -> None:
    mask = np.random.default_rng(seed).random((rows, cols)) < density
    labels, n = label_regions(mask, wraps)
    ref, n_ref = label_regions_ndimage(mask, wraps)
    assert n == n_ref
    np.testing.assert_array_equal(labels, ref)


def coarse_cost_np(lq: np.ndarray, l_grid: np.ndarray, dirs: np.ndarray, big_r: float, c0: float):
    """Reference of :func:`detector.fit_kernels.coarse_branch_cost` in numpy."""
    qx = lq[None, :, 0] - l_grid[:, None]
    r2 = (lq[:, 1] ** 2 + lq[:, 2] ** 2)[None, :]
    lat = lq[:, 1:] @ dirs[1:]
    t = qx[:, :, None] * dirs[0] + lat[None]
    sq = np.minimum(
        (np.sqrt(np.maximum(qx[..., None] ** 2 + r2[..., None] - t * t, 0)) - big_r) ** 2, c0 * c0
    )
    dp = lq[:, 0:1] * dirs[0] + lat
    behind = (qx * lq[None, :, 0] + r2)[..., None] - t * dp[None] < 0.0
    return np.where(behind, c0 * c0, sq).mean(axis=1)


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_coarse_branch_cost_matches_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    lq = rng.normal(0.0, 0.05, (60, 3))
    lq[:, 0] += 0.2
    l_grid = np.linspace(0.1, 0.3, 13)
    th = rng.uniform(0.3, 2.6, 20)
    ph = rng.uniform(-3, 3, 20)
    dirs = np.stack([np.cos(th), np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph)])
    cost = fk.coarse_branch_cost(lq, l_grid, dirs, 0.05, 0.006)
    np.testing.assert_allclose(cost, coarse_cost_np(lq, l_grid, dirs, 0.05, 0.006), atol=1e-13)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=60))
def test_median_is_numpys(values: list[float]) -> None:
    x = np.array(values)
    assert median(x) == float(np.median(x))
    assert mad_sigma(x) == float(1.4826 * np.median(np.abs(x - np.median(x))))


# --------------------------------------------------------------------------- cloud kernels
@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(1, 30), st.integers(1, 30), st.floats(0.05, 0.6), st.booleans())
def test_significant_regions_match_numpy(
    seed: int, rows: int, cols: int, density: float, wraps: bool
) -> None:
    """The compiled regions of returns off the wall against the numpy steps they replace."""
    rng = np.random.default_rng(seed)
    off = rng.random((rows, cols)) < density
    beyond = off & (rng.random((rows, cols)) < 0.7)
    inside = off & ~beyond
    min_points, min_rows = 4, 2
    labels, n, keep, n_keep, beyond_k, inside_k, pre = significant_regions(
        beyond, inside, wraps, min_points, min_rows
    )
    ref, n_ref = label_regions(beyond | inside, wraps)
    assert n == n_ref
    np.testing.assert_array_equal(labels, ref)
    keep_ref = np.zeros_like(off)
    if n_ref:
        counts, row_span = region_sizes(ref, n_ref)
        good = (counts >= min_points) & (row_span >= min_rows)
        good[0] = False
        keep_ref = good[ref] & off
    np.testing.assert_array_equal(keep, keep_ref)
    assert n_keep == int(keep_ref.sum())
    np.testing.assert_array_equal(beyond_k, beyond & keep_ref)
    np.testing.assert_array_equal(inside_k, inside & keep_ref)
    mixed = np.zeros(n_ref + 1, dtype=bool)
    mixed[ref[inside & keep_ref]] = True
    if n_ref and not mixed[ref[beyond & keep_ref]].any():
        assert pre is not None
        np.testing.assert_array_equal(pre, np.where(beyond & keep_ref, ref, 0))
    else:
        assert pre is None or not n_ref


def off_wall_entries_np(cell, g, k, wraps, u, r, tol, big_r, min_points):
    """Reference of :func:`detector.axis_fit._off_wall_entries`: the whole grid labelled by
    scipy (independent of the compiled labelling both share)."""
    off = np.abs(r - big_r) > 2.0 * tol
    n_off = int(off.sum())
    if n_off < min_points:
        return n_off, np.empty(0)
    mask = np.zeros(g * k, dtype=bool)
    mask[cell[off]] = True
    labels, n = label_regions_ndimage(mask.reshape(g, k), wraps)
    lab = labels.reshape(-1)[cell]
    counts = np.bincount(lab[off], minlength=n + 1)
    big = off & (counts[lab] >= min_points)
    return n_off, np.minimum(u[big], u[big] * big_r / np.maximum(r[big], 1e-9))


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(1, 25), st.integers(1, 25), st.booleans(), st.integers(1, 8))
def test_off_wall_entries_match_the_whole_grid_labelled(
    seed: int, rows: int, cols: int, wraps: bool, min_points: int
) -> None:
    rng = np.random.default_rng(seed)
    cell = np.flatnonzero(rng.random(rows * cols) < 0.8)
    n = cell.size
    u = rng.uniform(0.0, 1.0, n)
    r = 0.05 + rng.normal(0.0, 0.004, n)
    tol = np.full(n, 0.002)
    got = _off_wall_entries(cell, rows, cols, wraps and rows >= 3, u, r, tol, 0.05, min_points)
    ref = off_wall_entries_np(cell, rows, cols, wraps and rows >= 3, u, r, tol, 0.05, min_points)
    assert got[0] == ref[0]
    np.testing.assert_array_equal(got[1], ref[1])


def _random_sweep(rng: np.random.Generator) -> Scan:
    """A still sweep of random ranges and returns over a random pattern: 2-9 planes over the
    half turn (evenly or not), 3-20 beams forward of the sensor, symmetric or not (so some
    half-planes lack beams), the forward beam or not."""
    p = int(rng.integers(2, 10))
    planes = np.sort(rng.uniform(0.0, math.pi, p)) if rng.random() < 0.5 else None
    if planes is None:
        planes = np.linspace(0.0, math.pi, p, endpoint=False)
    b = int(rng.integers(3, 21))
    beams = np.sort(rng.uniform(-1.5, 1.5, b))
    if rng.random() < 0.3:
        beams[int(rng.integers(b))] = 0.0
        beams = np.unique(beams)
    ranges = rng.uniform(0.0, 2.0, (p, beams.size))
    ranges[rng.random(ranges.shape) < 0.2] = np.inf
    return Scan(
        ranges=ranges,
        valid=np.isfinite(ranges),
        beam_angles=beams,
        plane_angles=planes,
        timestamps=np.arange(p, dtype=float),
        positions=np.zeros((p, 3)),
        rotations=np.tile(np.eye(3), (p, 1, 1)),
        nominal_positions=np.zeros((p, 3)),
        nominal_rotations=np.tile(np.eye(3), (p, 1, 1)),
    )


@settings(max_examples=60, deadline=None)
@given(seeds, st.floats(0.0, 0.01), st.floats(0.05, 3.0))
def test_gather_cropped_matches_gather_then_crop(seed: int, bias: float, horizon: float) -> None:
    """The gather over the pattern's tables gives the scan's own beam directions times the
    corrected ranges (numpy, over the unrolled grid: to the last bit), cells in raster order
    without the cells that have no beam; and the still sweep's one pass gives the two passes
    (gather, then crop to the horizon)."""
    scan = _random_sweep(np.random.default_rng(seed))
    pat = _pattern(scan)
    tables = (
        scan.n_beams, pat.row_plane, pat.row_kind, pat.col_beam, pat.cos_b, pat.sin_b,
        pat.cos_a, pat.sin_a,
    )  # fmt: skip
    valid, ranges = scan.valid.reshape(-1), scan.ranges.reshape(-1)
    cell, pb, rng_v, local, trig = _gather_returns(valid, ranges, *tables, bias)
    grid = build_grid(scan)
    beam, plane = grid.beam.reshape(-1), grid.plane.reshape(-1)
    kept = np.flatnonzero((beam >= 0) & scan.valid[plane, np.maximum(beam, 0)])
    np.testing.assert_array_equal(cell, kept)
    np.testing.assert_array_equal(pb, plane[kept] * scan.n_beams + beam[kept])
    r_ref = np.maximum(scan.ranges[plane[kept], beam[kept]] - bias, 0.0)
    np.testing.assert_array_equal(rng_v, r_ref)
    np.testing.assert_array_equal(local, scan.directions()[plane[kept], beam[kept]].T * r_ref)
    beta = scan.beam_angles[beam[kept]]
    np.testing.assert_array_equal(trig, np.stack([np.abs(np.sin(beta)), np.abs(np.cos(beta))]))
    ref = _crop(cell, rng_v, local, trig, pat.k_cols, horizon)
    got = _gather_cropped(valid, ranges, *tables, bias, horizon)
    for a, b in zip(got[:4], ref[:4]):
        np.testing.assert_array_equal(a, b)
    assert got[4] == ref[4]
    assert np.all(np.diff(got[0]) > 0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=0, max_size=80))
def test_partial_percentiles_are_numpys(values: list[float]) -> None:
    x = np.array(values, dtype=float)
    qs = (1.0, 50.0, 90.0, 100.0)
    got = partial_percentiles(x, qs)
    for q, v in zip(qs, got):
        assert v == partial_percentile(x, q)
        if x.size:
            assert v == pytest.approx(float(np.percentile(x, q)), rel=1e-12, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(seeds, st.integers(1, 6), st.floats(0.0, 1e-8))
def test_spread_exceeds_is_ptp(seed: int, n: int, spread: float) -> None:
    v = np.random.default_rng(seed).normal(size=(n, 9)) * spread
    assert _spread_exceeds(v, 1e-9) == bool(np.ptp(v, axis=0).max() > 1e-9)


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(0, 300), st.sampled_from([12, 36, 72]))
def test_azimuth_coverage_matches_numpy(seed: int, n: int, bins: int) -> None:
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p[: n // 3, 1] = 0.0  # (angles on the sector edges: +-pi/2, 0, pi)
    phi = np.arctan2(p[:, 2], p[:, 1])
    k = np.floor((phi + math.pi) / (2 * math.pi) * bins).astype(int) % bins
    ref = float(np.count_nonzero(np.bincount(k, minlength=bins))) / bins
    assert azimuth_coverage(p, bins) == ref


@settings(max_examples=40, deadline=None)
@given(seeds, st.floats(0.0, 1.0))
def test_masked_columns_are_numpys(seed: int, density: float) -> None:
    rng = np.random.default_rng(seed)
    cell = np.flatnonzero(rng.random(200) < 0.7)
    xyz = rng.normal(size=(3, cell.size))
    mask = rng.random(200) < density
    ref = np.take(xyz, np.flatnonzero(mask[cell]), axis=1)
    np.testing.assert_array_equal(_masked_columns(mask, cell, xyz), ref)


@settings(max_examples=30, deadline=None)
@given(seeds, st.integers(0, 200))
def test_radii_and_sloped_tolerance_are_numpys(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(3, n))
    tol0 = rng.random(n)
    np.testing.assert_array_equal(_radii(xyz), np.sqrt(np.square(xyz[1]) + np.square(xyz[2])))
    np.testing.assert_array_equal(
        _sloped_tolerance(tol0, 0.002, xyz[0]), tol0 + 0.002 * np.abs(xyz[0])
    )


@settings(max_examples=30, deadline=None)
@given(seeds, st.integers(1, 3))
def test_scatter_is_numpys(seed: int, rows: int) -> None:
    rng = np.random.default_rng(seed)
    cell = np.flatnonzero(rng.random(100) < 0.6)
    values = rng.normal(size=(rows, cell.size))
    ref = np.full((rows, 100), 0.0)
    ref[:, cell] = values
    np.testing.assert_array_equal(_scatter(values, cell, 100, 0.0), ref)
    flags = _scatter(np.ones((1, cell.size), dtype=bool), cell, 100, False)
    np.testing.assert_array_equal(flags[0], np.isin(np.arange(100), cell))


def column_stats_np(
    cols: np.ndarray, r: np.ndarray, sigma: np.ndarray, g: int
) -> tuple[np.ndarray, ...]:
    """Per column that holds values: share of ``g`` rows, 10/50/90th percentile of ``r``,
    median of ``sigma`` (the numpy loop :func:`column_stats` replaces)."""
    out: list[list[float]] = [[], [], [], [], []]
    for c in np.unique(cols):
        sel = cols == c
        lo, med, hi = np.percentile(r[sel], [10.0, 50.0, 90.0])
        for k, v in enumerate(
            (float(np.count_nonzero(sel)) / max(g, 1), lo, med, hi, np.median(sigma[sel]))
        ):
            out[k].append(float(v))
    return tuple(np.array(v) for v in out)


@settings(max_examples=80, deadline=None)
@given(seeds, st.integers(1, 300), st.integers(1, 40), st.integers(0, 6))
def test_column_stats_are_numpys(seed: int, n: int, k: int, decimals: int) -> None:
    rng = np.random.default_rng(seed)
    cols = rng.integers(0, k, n).astype(np.intp)
    r = rng.random(n) * rng.random()
    sigma = np.round(rng.random(n), decimals)  # (ties at the median)
    g = int(rng.integers(0, 100))
    got = column_stats(cols, r, sigma, k, g)
    for a, b in zip(got, column_stats_np(cols, r, sigma, g)):
        np.testing.assert_array_equal(a, b)


@settings(max_examples=80, deadline=None)
@given(seeds, st.integers(0, 400), st.integers(1, 40), st.integers(0, 6))
def test_column_medians_are_numpys(seed: int, n: int, k: int, decimals: int) -> None:
    rng = np.random.default_rng(seed)
    cols = rng.integers(0, k, n).astype(np.intp)
    a = np.round(rng.normal(size=n), decimals)  # (ties)
    b = rng.random(n)
    counts, a50, b50 = column_medians(cols, a, b, k)
    present = np.unique(cols)
    np.testing.assert_array_equal(counts, [np.count_nonzero(cols == c) for c in present])
    np.testing.assert_array_equal(a50, [np.median(a[cols == c]) for c in present])
    np.testing.assert_array_equal(b50, [np.median(b[cols == c]) for c in present])


@settings(max_examples=80, deadline=None)
@given(seeds, st.integers(0, 400), st.floats(-0.1, 0.6), st.floats(0.0, 0.8))
def test_median_rise_is_numpys(seed: int, n: int, u_from: float, extent: float) -> None:
    rng = np.random.default_rng(seed)
    u = rng.random(n) * 0.8
    r = 0.05 + rng.normal(0.0, 0.004, n)
    band = 0.006
    u_to = u_from + extent
    count, rise = median_rise(u, r, 0.05, band, u_from, u_to)
    e = r - 0.05
    near = np.abs(e) < band
    past = near & (u >= u_from) & (u < u_to)
    before = near & (u < u_from)
    assert count == np.count_nonzero(past)
    want = np.median(e[past]) - np.median(e[before]) if past.any() and before.any() else 0.0
    assert rise == pytest.approx(want, abs=1e-15)


@pytest.mark.parametrize("tilt", [0.0, 0.003, 0.006])
def test_radius_under_pose_error_leaves_out_a_small_tilt_and_offset(tilt: float) -> None:
    # returns on a 50 mm wall about an axis offset by 0.4 mm and tilted by ``tilt`` (rad)
    # from the pose they are measured under, the pipe 0.6 mm wider than the clamp's reading
    rng = np.random.default_rng(1)
    u = rng.uniform(0.08, 0.4, 3000)
    phi = rng.uniform(-np.pi, np.pi, 3000)
    centre = np.stack([0.0004 + tilt * u, -0.0002 + 0.5 * tilt * u])
    yz = centre + 0.0506 * np.stack([np.cos(phi), np.sin(phi)])
    xyz = np.vstack([u, yz])
    e = np.hypot(yz[0], yz[1]) - 0.05
    fitted = _radius_under_pose_error(xyz, np.arange(u.size), e, 0.05, DEFAULT_CONFIG)
    assert fitted is not None
    de, spread = fitted
    # (to first order: the offset's square over the diameter, 0.05 mm at 2.4 mm, is left)
    assert de == pytest.approx(0.0006, abs=1e-4)
    assert spread < 1e-4
    # a tilt beyond radius_pose_tilt is no small pose error
    steep = replace(DEFAULT_CONFIG, radius_pose_tilt=0.5 * max(tilt, 1e-4))
    assert (_radius_under_pose_error(xyz, np.arange(u.size), e, 0.05, steep) is None) == (tilt > 0)


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(0, 3000), st.integers(10, 600), st.booleans())
def test_axis_returns_spread_evenly_as_even_indices(
    seed: int, n: int, n_keep: int, nearest: bool
) -> None:
    """The axis refinement's returns, ``n_keep`` of them picked in the compiled pass, are the
    ones :func:`even_indices` picks from all of them."""
    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(3, n))
    r = np.hypot(xyz[1], xyz[2])
    u_max = math.nan if nearest else float(rng.normal())
    every = _axis_returns(xyz, r, 1.0, 0.5, u_max, 10**9)
    ref = every[:, even_indices(every.shape[1], n_keep)]
    np.testing.assert_array_equal(_axis_returns(xyz, r, 1.0, 0.5, u_max, n_keep), ref)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    theta=st.sampled_from([math.pi / 2, math.pi / 4, 3 * math.pi / 4]),
)
def test_far_side_residuals_match_the_numpy_model(seed: int, theta: float) -> None:
    """The compiled far-side model (a side hole's branch cylinder, noise-weighted) equals its
    formula in numpy on random returns and parameters."""
    from detector.fit_kernels import far_side_residuals

    rng = np.random.default_rng(seed)
    n = 50
    u = rng.uniform(0.05, 0.4, n)
    r = rng.uniform(0.02, 0.06, n)
    phi = rng.uniform(-math.pi, math.pi, n)
    rg = np.hypot(u, r)
    noise2 = np.square(rng.uniform(0.0, 0.004, n))
    x = np.array([rng.uniform(0.0, 0.3), rng.uniform(0.01, 0.05), rng.uniform(-3, 3)])
    ct, st_ = math.cos(theta), math.sin(theta)
    floor2 = 0.002**2
    q = u - x[0]
    lat = r * np.cos(phi - x[2])
    along = q * ct + lat * st_
    d2 = q * q + r * r - along * along
    dist = np.sqrt(np.maximum(d2, 1e-24))
    cos_inc = np.abs(u * (q - along * ct) + r * r - along * st_ * lat) / (dist * rg)
    scale = np.sqrt(floor2 / (floor2 + noise2 * np.square(np.minimum(cos_inc, 1.0))))
    expected = (np.sqrt(np.maximum(d2, 0.0)) - x[1]) * scale
    out = np.empty(n)
    data = np.ascontiguousarray(np.stack([u, r, phi, rg, noise2]))
    far_side_residuals(data, ct, st_, floor2, x[0], x[1], x[2], out)
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-15)
