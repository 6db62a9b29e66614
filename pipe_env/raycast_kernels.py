"""Compiled (numba) kernels of the analytic LiDAR backend: exact rays against the bore, ray by ray.

This module owns the per-ray arithmetic of :mod:`pipe_env.raycast_analytic`: the same pieces
(cone frustums, cylinders when the slope is 0, and torus sectors, each clipped by two planes),
the same interval formulas and the same union rule, evaluated one ray at a time in compiled code
instead of over (ray, piece) pair arrays in numpy. For the rays of one origin:

1. pieces whose bounding sphere lies beyond the cutoff are dropped;
2. when one piece's bounding sphere holds the origin (the usual case), that piece's interval is
   computed for all the rays at once in a loop without branches; a ray that leaves it through
   its side wall where no other piece reaches (its safe band, :func:`axial_safe_bands`) is
   done there;
3. otherwise the ray's exit from the union, as the numpy path defines it: ``t`` starts at 0 and
   extends to the farthest end of the intervals that contain it (``lo <= t + SEAM_EPS``,
   ``hi > t``) until none does. A piece's intervals are computed only when the point at ``t``
   lies in its (slightly inflated) bounding sphere, and for a torus near its tube (lazily,
   once); casting stops as soon as ``t`` passes the cutoff or leaves through a safe band;
4. the piece and surface whose interval ended at the exit give the hit's element and its
   outward normal.

Pieces are packed in one (K, 22) float64 table (:data:`FIELDS` gives the columns), quadrics
first, then tori, as the numpy path orders them. Units: metres.

Functions are compiled on first use and cached on disk (``cache=True``), so later processes load
them in well under a second.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

#: Columns of the packed piece table: point (axis point or torus centre), unit axis, radius0 or
#: major radius, slope or minor radius, the two clip planes (normal, offset), bounding sphere.
FIELDS: tuple[str, ...] = ("p", "p", "p", "u", "u", "u", "r", "k", "n0", "n0", "n0", "h0")
FIELDS += ("n1", "n1", "n1", "h1", "bc", "bc", "bc", "br", "safe0", "safe1")
N_FIELDS = len(FIELDS)
#: Columns of the axial band [safe0, safe1] of a quadric's side wall that no other piece's
#: bounding sphere reaches (see :func:`axial_safe_bands`).
_SAFE0, _SAFE1 = 20, 21
#: Margin of the safe bands, m (far above rounding and SEAM_EPS).
SAFE_MARGIN = 1.0e-6
#: Piece kinds (column of the kind array).
QUADRIC, TORUS = 0, 1
#: Two intervals closer than this along a ray are treated as touching, m (as the numpy path).
SEAM_EPS = 1.0e-9
SIDE, PLANE0, PLANE1 = 0, 1, 2
_INF = math.inf


def axial_safe_bands(table: NDArray[np.float64], kind: NDArray[np.int64]) -> NDArray[np.float64]:
    """(K, 2) for every quadric piece, an interval of the axial coordinate ``s = (x - p) . u``
    in which no other piece's bounding sphere (with a margin) reaches: a ray leaving the piece
    through its side wall there leaves the bore (no other piece can extend it), so the kernel
    stops without looking at the other pieces. The band is the widest gap between the other
    pieces' axial shadows (where a sphere (c_j, R_j + margin) can reach the wall); empty
    (lo > hi) if there is none, and for tori. Reads columns 0-19 of the packed table."""
    n = len(table)
    out = np.empty((n, 2))
    out[:, 0] = np.inf
    out[:, 1] = -np.inf
    for k in range(n):
        if kind[k] != QUADRIC:
            continue
        p, u = table[k, 0:3], table[k, 3:6]
        centre = float((table[k, 16:19] - p) @ u)
        reach = table[k, 19]
        # the widest the wall gets within the piece's bounding sphere
        wall = max(abs(table[k, 6] + table[k, 7] * (centre + e * reach)) for e in (-1.0, 1.0))
        edges = [(-np.inf, centre - reach)]  # (start, end) of the blocked stretches
        edges.append((centre + reach, np.inf))
        for j in range(n):
            if j == k:
                continue
            w = table[j, 16:19] - p
            along = float(w @ u)
            off_axis = float(np.sqrt(max(float(w @ w) - along * along, 0.0)))
            # the wall's circle at s is within R_j of c_j only if
            # (s - along)^2 + (off_axis - wall)^2 <= R_j^2 (wall points are within `wall` of
            # the axis, so the circle is no nearer than off_axis - wall)
            radius = table[j, 19] * (1 + 1e-9) + SAFE_MARGIN
            gap = max(off_axis - wall, 0.0)
            if gap < radius:
                half = float(np.sqrt(radius * radius - gap * gap)) + SAFE_MARGIN
                edges.append((along - half, along + half))
        edges.sort()
        best = (np.inf, -np.inf)
        end = -np.inf
        for start, stop in edges:
            if start > end and start - end > best[1] - best[0]:
                best = (end, start)
            end = max(end, stop)
        out[k] = best
    return out


@numba.njit(cache=True, error_model="numpy")
def _clip(
    dn0: float, g0: float, dn1: float, g1: float, lo: float, hi: float
) -> tuple[float, float, int]:
    """Clip ``[lo, hi]`` (side surface at ``hi``) by the planes ``t dn_i <= g_i``; hi's code.

    A plane's parameter ``g / dn`` is divided out only where it cuts (compared by products)."""
    code = SIDE
    if dn0 > 0.0:
        if g0 < hi * dn0:
            hi = g0 / dn0
            code = PLANE0
    elif dn0 < 0.0:
        if g0 < lo * dn0:
            lo = g0 / dn0
    elif g0 < 0.0:
        lo = _INF
    if dn1 > 0.0:
        if g1 < hi * dn1:
            hi = g1 / dn1
            code = PLANE1
    elif dn1 < 0.0:
        if g1 < lo * dn1:
            lo = g1 / dn1
    elif g1 < 0.0:
        lo = _INF
    return lo, hi, code


@numba.njit(cache=True, error_model="numpy")
def _quadric_interval(
    a: float,
    b: float,
    c: float,
    dn0: float,
    g0: float,
    dn1: float,
    g1: float,
) -> tuple[float, float, int]:
    """The interval of ``a t^2 + 2 b t + c <= 0`` clipped by two planes (empty: lo >= hi)."""
    disc = b * b - a * c
    sq = math.sqrt(max(disc, 0.0))
    qq = -(b + math.copysign(sq, b))
    if a > 1e-12:
        if disc < 0.0:
            return _INF, -_INF, SIDE
        t1 = qq / a
        t2 = c / qq if qq != 0.0 else math.nan
        if t1 != t1 or t2 != t2:
            return _INF, -_INF, SIDE
        return _clip(dn0, g0, dn1, g1, min(t1, t2), max(t1, t2))
    if a >= -1e-12:  # linear: a ray parallel to a cylinder is inside for all t or never
        if b > 1e-15:
            return _clip(dn0, g0, dn1, g1, -_INF, -c / (2.0 * b))
        if b < -1e-15:
            return _clip(dn0, g0, dn1, g1, -c / (2.0 * b), _INF)
        if c <= 0.0:
            return _clip(dn0, g0, dn1, g1, -_INF, _INF)
        return _INF, -_INF, SIDE
    if disc < 0.0:  # a < 0: inside everywhere
        return _clip(dn0, g0, dn1, g1, -_INF, _INF)
    # a < 0 (a cone crossed steeply): outside between the roots; within the frustum's slab only
    # one of (-inf, r_lo] and [r_hi, inf) belongs to the right nappe
    t1 = qq / a
    t2 = c / qq if qq != 0.0 else math.nan
    if t1 != t1 or t2 != t2:
        return _INF, -_INF, SIDE
    r_lo = min(t1, t2)
    r_hi = max(t1, t2)
    lo_a, hi_a, code_a = _clip(dn0, g0, dn1, g1, -_INF, r_lo)
    if hi_a > lo_a:
        return lo_a, hi_a, code_a
    return _clip(dn0, g0, dn1, g1, r_hi, _INF)


@numba.njit(cache=True, error_model="numpy")
def largest_cubic_root(a: float, b: float, c: float) -> float:
    """Largest real root of ``z^3 + a z^2 + b z + c``."""
    shift = a / 3.0
    p = b - a * shift
    q = 2.0 * shift**3 - shift * b + c
    half_q = 0.5 * q
    disc = half_q * half_q + (p / 3.0) ** 3
    if disc > 0:
        sq = math.sqrt(disc)
        y = np.cbrt(-half_q + sq) + np.cbrt(-half_q - sq)
    else:
        m = math.sqrt(max(-p / 3.0, 0.0))
        cos_arg = -half_q / m**3 if m > 0 else 0.0
        y = 2.0 * m * math.cos(math.acos(min(max(cos_arg, -1.0), 1.0)) / 3.0)
    return y - shift


@numba.njit(cache=True, error_model="numpy")
def depressed_quartic_roots(p: float, q: float, s: float) -> tuple[int, float, float, float, float]:
    """Real roots of ``x^4 + p x^2 + q x + s = 0``: their count and the roots, ascending (NaN
    after the last).

    The scalar twin of :func:`pipe_env.raycast_analytic.solve_depressed_quartic`: Descartes'
    factorisation through the largest root of the resolvent cubic, two Newton steps per root.
    """
    a2, a1, a0 = 2.0 * p, p * p - 4.0 * s, -q * q
    z = largest_cubic_root(a2, a1, a0)
    for _ in range(2):
        f = ((z + a2) * z + a1) * z + a0
        fp = (3.0 * z + 2.0 * a2) * z + a1
        if abs(fp) > 1e-300:
            z = z - f / fp
    z = max(z, 0.0)
    scale = max(max(abs(p), math.sqrt(abs(s))), 1e-300)
    nan = math.nan
    x0 = x1 = x2 = x3 = nan
    n = 0
    if z <= 1e-14 * scale:  # biquadratic: x^2 = (-p +- sqrt(p^2 - 4 s)) / 2
        dq = p * p - 4.0 * s
        if dq >= 0:
            sq = math.sqrt(dq)
            y1 = 0.5 * (-p - sq)
            y2 = 0.5 * (-p + sq)
            if y1 >= 0:
                r = math.sqrt(abs(y1))
                x0, x1 = -r, r
                n = 2
            if y2 >= 0:
                r = math.sqrt(abs(y2))
                if n == 0:
                    x0, x1 = -r, r
                else:
                    x2, x3 = -r, r
                n += 2
    else:
        alpha = math.sqrt(z)
        q_over_alpha = q / alpha
        beta = 0.5 * (p + z - q_over_alpha)
        gamma = 0.5 * (p + z + q_over_alpha)
        d1 = z - 4.0 * beta
        d2 = z - 4.0 * gamma
        if d1 >= 0:
            s1 = math.sqrt(d1)
            x0, x1 = 0.5 * (-alpha - s1), 0.5 * (-alpha + s1)
            n = 2
        if d2 >= 0:
            s2 = math.sqrt(d2)
            if n == 0:
                x0, x1 = 0.5 * (alpha - s2), 0.5 * (alpha + s2)
            else:
                x2, x3 = 0.5 * (alpha - s2), 0.5 * (alpha + s2)
            n += 2
    if n == 0:
        return 0, nan, nan, nan, nan
    x0 = _newton2(x0, p, q, s, scale)
    x1 = _newton2(x1, p, q, s, scale)
    if n == 2:
        return 2, min(x0, x1), max(x0, x1), nan, nan
    x2 = _newton2(x2, p, q, s, scale)
    x3 = _newton2(x3, p, q, s, scale)
    # sort four: min/max network
    a, b = min(x0, x1), max(x0, x1)
    c, d = min(x2, x3), max(x2, x3)
    lo, m1 = min(a, c), max(a, c)
    m2, hi = min(b, d), max(b, d)
    return 4, lo, min(m1, m2), max(m1, m2), hi


@numba.njit(cache=True, error_model="numpy")
def _newton2(x: float, p: float, q: float, s: float, scale: float) -> float:
    """Two guarded Newton steps on ``x^4 + p x^2 + q x + s`` from ``x``."""
    for _ in range(2):
        x2 = x * x
        f = (x2 + p) * x2 + q * x + s
        fp = (4.0 * x2 + 2.0 * p) * x + q
        if abs(fp) > 1e-12 * (abs(x) * scale + 1.0):
            x = x - f / fp
    return x


#: Columns of the per-origin table (:func:`_origin_table`).
_PX, _S0, _C, _RS, _G0, _G1, _BX, _BCC, _RAD2 = 0, 3, 4, 5, 6, 7, 8, 11, 12
_N_ORIGIN = 13


@numba.njit(cache=True, error_model="numpy")
def _origin_table(
    pieces: NDArray[np.float64],
    kind: NDArray[np.int64],
    ox: float,
    oy: float,
    oz: float,
    out: NDArray[np.float64],
) -> None:
    """Per-piece constants of rays from the origin ``o``: the point p - o; s0 = -(p - o) . u;
    the constant term (quadrics: |p - o|^2 - s0^2 - rs^2 with rs = r0 + slope s0; tori:
    |c - o|^2); rs; the plane gaps h_i - n_i . o; the bounding centre - o, its squared norm and
    the squared (slightly inflated) bounding radius."""
    for k in range(pieces.shape[0]):
        px = pieces[k, 0] - ox
        py = pieces[k, 1] - oy
        pz = pieces[k, 2] - oz
        s0 = -(px * pieces[k, 3] + py * pieces[k, 4] + pz * pieces[k, 5])
        pp = px * px + py * py + pz * pz
        out[k, 0] = px
        out[k, 1] = py
        out[k, 2] = pz
        out[k, _S0] = s0
        if kind[k] == QUADRIC:
            rs = pieces[k, 6] + pieces[k, 7] * s0
            out[k, _C] = pp - s0 * s0 - rs * rs
            out[k, _RS] = rs
        else:
            out[k, _C] = pp
            out[k, _RS] = 0.0
        out[k, _G0] = pieces[k, 11] - (pieces[k, 8] * ox + pieces[k, 9] * oy + pieces[k, 10] * oz)
        out[k, _G1] = pieces[k, 15] - (pieces[k, 12] * ox + pieces[k, 13] * oy + pieces[k, 14] * oz)
        bx = pieces[k, 16] - ox
        by = pieces[k, 17] - oy
        bz = pieces[k, 18] - oz
        out[k, 8] = bx
        out[k, 9] = by
        out[k, 10] = bz
        out[k, _BCC] = bx * bx + by * by + bz * bz
        r = pieces[k, 19] * (1.0 + 1e-9) + 1e-9  # inflated against rounding
        out[k, _RAD2] = r * r


@numba.njit(cache=True, error_model="numpy", inline="always")
def _piece_intervals(
    pieces: NDArray[np.float64],
    kind: NDArray[np.int64],
    table: NDArray[np.float64],
    k: int,
    dx: float,
    dy: float,
    dz: float,
) -> tuple[int, float, float, int, float, float, int]:
    """The (up to two) non-empty intervals of piece ``k`` along the ray ``o + t d``: their count
    and (lo, hi, code of hi) of each."""
    du = dx * pieces[k, 3] + dy * pieces[k, 4] + dz * pieces[k, 5]
    dp = dx * table[k, 0] + dy * table[k, 1] + dz * table[k, 2]
    dn0 = dx * pieces[k, 8] + dy * pieces[k, 9] + dz * pieces[k, 10]
    dn1 = dx * pieces[k, 12] + dy * pieces[k, 13] + dz * pieces[k, 14]
    g0 = table[k, _G0]
    g1 = table[k, _G1]
    s0 = table[k, _S0]
    if kind[k] == QUADRIC:
        slope = pieces[k, 7]
        kdu = slope * du
        a = 1.0 - du * du - kdu * kdu
        b = -dp - s0 * du - kdu * table[k, _RS]
        lo, hi, code = _quadric_interval(a, b, table[k, _C], dn0, g0, dn1, g1)
        if hi > lo:
            return 1, lo, hi, code, 0.0, 0.0, SIDE
        return 0, 0.0, 0.0, SIDE, 0.0, 0.0, SIDE
    # torus sector: solve from the ray point closest to the centre, in units of the major radius
    big = pieces[k, 6]
    t0 = dp
    inv = 1.0 / big
    cc = (s0 + t0 * du) * inv
    qq = max(table[k, _C] - t0 * t0, 0.0) * inv * inv
    rr = pieces[k, 7] * inv
    bb = qq + 1.0 - rr * rr
    p2 = 2.0 * bb - 4.0 * (1.0 - du * du)
    p1 = 8.0 * cc * du
    p0 = bb * bb - 4.0 * (qq - cc * cc)
    nr, x0, x1, x2, x3 = depressed_quartic_roots(p2, p1, p0)
    m = 0
    lo_a = hi_a = lo_b = hi_b = 0.0
    code_a = code_b = SIDE
    if nr >= 2:
        lo, hi, code = _clip(dn0, g0, dn1, g1, x0 * big + t0, x1 * big + t0)
        if hi > lo:
            lo_a, hi_a, code_a = lo, hi, code
            m = 1
    if nr == 4:
        lo, hi, code = _clip(dn0, g0, dn1, g1, x2 * big + t0, x3 * big + t0)
        if hi > lo:
            if m == 0:
                lo_a, hi_a, code_a = lo, hi, code
            else:
                lo_b, hi_b, code_b = lo, hi, code
            m += 1
    return m, lo_a, hi_a, code_a, lo_b, hi_b, code_b


@numba.njit(cache=True, error_model="numpy")
def _first_quadric(
    pieces: NDArray[np.float64],
    table: NDArray[np.float64],
    k: int,
    dirs: NDArray[np.float64],
    start: int,
    stop: int,
    lo_out: NDArray[np.float64],
    hi_out: NDArray[np.float64],
    code_out: NDArray[np.int64],
    ok_out: NDArray[np.bool_],
    cutoff: float,
    done_out: NDArray[np.bool_],
    want_normals: bool,
    origin: NDArray[np.float64],
    normal: NDArray[np.float64],
) -> None:
    """The interval of quadric piece ``k`` for rays ``start:stop`` from the table's origin, as
    :func:`_piece_intervals` computes it, without branches. ``ok_out`` is False where the
    general case does not apply (a nearly tangent or steep ray: the caller recomputes)."""
    ux, uy, uz = pieces[k, 3], pieces[k, 4], pieces[k, 5]
    px, py, pz = table[k, 0], table[k, 1], table[k, 2]
    n0x, n0y, n0z = pieces[k, 8], pieces[k, 9], pieces[k, 10]
    n1x, n1y, n1z = pieces[k, 12], pieces[k, 13], pieces[k, 14]
    g0 = table[k, _G0]
    g1 = table[k, _G1]
    s0 = table[k, _S0]
    c = table[k, _C]
    rs = table[k, _RS]
    slope = pieces[k, 7]
    safe0 = pieces[k, _SAFE0]
    safe1 = pieces[k, _SAFE1]
    for i in range(start, stop):
        dx = dirs[i, 0]
        dy = dirs[i, 1]
        dz = dirs[i, 2]
        du = dx * ux + dy * uy + dz * uz
        dp = dx * px + dy * py + dz * pz
        dn0 = dx * n0x + dy * n0y + dz * n0z
        dn1 = dx * n1x + dy * n1y + dz * n1z
        kdu = slope * du
        a = 1.0 - du * du - kdu * kdu
        b = -dp - s0 * du - kdu * rs
        disc = b * b - a * c
        sq = math.sqrt(max(disc, 0.0))
        qq = -(b + math.copysign(sq, b))
        t1 = qq / a
        t2 = c / qq
        lo = min(t1, t2)
        hi = max(t1, t2)
        code = SIDE
        # the planes as _clip does it, with selects
        tp = g0 / dn0
        cut = (dn0 > 0.0) & (g0 < hi * dn0)
        hi = tp if cut else hi
        code = PLANE0 if cut else code
        lo = tp if (dn0 < 0.0) & (g0 < lo * dn0) else lo
        lo = _INF if (dn0 == 0.0) & (g0 < 0.0) else lo
        tp = g1 / dn1
        cut = (dn1 > 0.0) & (g1 < hi * dn1)
        hi = tp if cut else hi
        code = PLANE1 if cut else code
        lo = tp if (dn1 < 0.0) & (g1 < lo * dn1) else lo
        lo = _INF if (dn1 == 0.0) & (g1 < 0.0) else lo
        lo_out[i - start] = lo
        hi_out[i - start] = hi
        code_out[i - start] = code
        ok = (a > 1e-12) & (disc >= 0.0) & (qq != 0.0)
        ok_out[i - start] = ok
        # done: the ray starts inside and leaves through the side wall where no other piece
        # reaches (the union's exit, as the general loop would find it)
        s_axial = hi * du + s0
        done = (
            ok
            & (code == SIDE)
            & (lo <= SEAM_EPS)
            & (hi > 0.0)
            & (hi <= cutoff)
            & (s_axial >= safe0)
            & (s_axial <= safe1)
        )
        done_out[i - start] = done
        if want_normals and done:  # as _normal computes it
            wx = origin[0] + hi * dx - pieces[k, 0]
            wy = origin[1] + hi * dy - pieces[k, 1]
            wz = origin[2] + hi * dz - pieces[k, 2]
            sw = wx * ux + wy * uy + wz * uz
            f = sw + slope * (pieces[k, 6] + slope * sw)
            nx, ny, nz = wx - f * ux, wy - f * uy, wz - f * uz
            norm = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
            normal[i, 0] = nx / norm
            normal[i, 1] = ny / norm
            normal[i, 2] = nz / norm


@numba.njit(cache=True, error_model="numpy")
def cast_rays(
    pieces: NDArray[np.float64],
    kind: NDArray[np.int64],
    element: NDArray[np.int64],
    origins: NDArray[np.float64],
    per_origin: int,
    dirs: NDArray[np.float64],
    cutoff: float,
    want_normals: bool,
    dist: NDArray[np.float64],
    normal: NDArray[np.float64],
    hit_element: NDArray[np.int64],
) -> None:
    """Cast N rays against the bore; ray ``i`` starts at ``origins[i // per_origin]``.

    Writes ``dist`` (N,) (``inf``: no wall within ``cutoff``; 0: the ray starts outside the
    bore), ``normal`` (N, 3) (outward unit normals if ``want_normals``, else zeros) and
    ``hit_element`` (N,) (-1: none), as :meth:`pipe_env.raycast_analytic.AnalyticBore.cast`.

    The work is done origin by origin, in passes over that origin's rays (the helpers take
    their arrays once per origin, not once per ray: passing an array costs reference counting):
    the pieces in reach (:func:`_select_pieces`), the batched first piece
    (:func:`_first_quadric`), each ray's exit from the union (:func:`_trace_rays`) and the
    results (:func:`_write_hits`).
    """
    n_rays = dirs.shape[0]
    n_pieces = pieces.shape[0]
    table = np.empty((n_pieces, _N_ORIGIN))
    active = np.empty(n_pieces, dtype=np.int64)  # pieces within the cutoff of the origin
    at_origin = np.empty(n_pieces, dtype=np.bool_)  # bounding sphere contains the origin
    stamp = np.full(n_pieces, -1, dtype=np.int64)  # last ray whose intervals were computed
    n_iv = np.zeros(n_pieces, dtype=np.int64)
    iv_lo = np.empty((n_pieces, 2))
    iv_hi = np.empty((n_pieces, 2))
    iv_code = np.empty((n_pieces, 2), dtype=np.int64)
    # per ray of one origin: the batched first piece's interval; the rays traced through the
    # union, their exits' pieces and surface codes
    n_batch = max(min(per_origin, n_rays), 0)
    b_lo = np.empty(n_batch)
    b_hi = np.empty(n_batch)
    b_code = np.empty(n_batch, dtype=np.int64)
    b_ok = np.zeros(n_batch, dtype=np.bool_)
    b_done = np.zeros(n_batch, dtype=np.bool_)
    traced = np.empty(n_batch, dtype=np.int64)
    exit_piece = np.empty(n_batch, dtype=np.int64)
    exit_code = np.empty(n_batch, dtype=np.int64)
    if not want_normals:
        normal[:] = 0.0
    for oi in range(origins.shape[0]):
        _origin_table(pieces, kind, origins[oi, 0], origins[oi, 1], origins[oi, 2], table)
        n_active, n_at, first = _select_pieces(table, cutoff, active, at_origin)
        start = oi * per_origin
        stop = min(start + per_origin, n_rays)
        # Usually one piece holds the origin and every ray starts by crossing it: its interval
        # for all the rays at once, in a loop without branches (vectorised, no mispredictions)
        batched = n_at == 1 and kind[first] == QUADRIC and stop > start
        if batched:
            _first_quadric(
                pieces,
                table,
                first,
                dirs,
                start,
                stop,
                b_lo,
                b_hi,
                b_code,
                b_ok,
                cutoff,
                b_done,
                want_normals,
                origins[oi],
                normal,
            )
        n_traced = _trace_rays(
            pieces,
            kind,
            element,
            table,
            active,
            at_origin,
            n_active,
            dirs,
            start,
            stop,
            cutoff,
            first if batched else -1,
            b_lo,
            b_hi,
            b_code,
            b_ok,
            b_done,
            stamp,
            n_iv,
            iv_lo,
            iv_hi,
            iv_code,
            dist,
            hit_element,
            traced,
            exit_piece,
            exit_code,
        )
        _write_hits(
            pieces,
            kind,
            element,
            origins[oi],
            dirs,
            cutoff,
            want_normals,
            n_traced,
            traced,
            exit_piece,
            exit_code,
            dist,
            normal,
            hit_element,
        )


@numba.njit(cache=True, error_model="numpy")
def _select_pieces(
    table: NDArray[np.float64],
    cutoff: float,
    active: NDArray[np.int64],
    at_origin: NDArray[np.bool_],
) -> tuple[int, int, int]:
    """Fill ``active`` with the pieces whose bounding sphere comes within ``cutoff`` of the
    table's origin (and ``at_origin`` with whether it contains the origin); returns their count,
    the count of those containing the origin and the last such piece (-1: none)."""
    n_active = 0
    n_at = 0
    first = -1
    for k in range(table.shape[0]):
        rad = math.sqrt(table[k, _RAD2])
        if math.sqrt(table[k, _BCC]) - rad <= cutoff + SEAM_EPS:
            active[n_active] = k
            at_origin[n_active] = table[k, _BCC] <= table[k, _RAD2]
            if at_origin[n_active]:
                n_at += 1
                first = k
            n_active += 1
    return n_active, n_at, first


@numba.njit(cache=True, error_model="numpy")
def _within_sphere(t: float, tc: float, bcc: float, rad2: float) -> bool:
    """Whether the point at ``t`` on a ray lies in a piece's (inflated) bounding sphere: ``tc``
    is the ray's direction . (centre - origin), ``bcc`` and ``rad2`` the squared distance
    from the origin to the centre and the squared radius."""
    return not (t * (t - 2.0 * tc) + bcc > rad2)


@numba.njit(cache=True, error_model="numpy")
def _within_tube(
    t: float, du: float, dc: float, s0: float, cc: float, major: float, minor: float
) -> bool:
    """Whether the point at ``t`` on a ray lies within reach of a torus's tube: ``du``, ``dc``
    are the direction . axis and . (centre - origin), ``s0`` and ``cc`` the origin's axial
    coordinate and squared distance to the centre (:func:`_origin_table`)."""
    h = t * du + s0
    w2 = t * (t - 2.0 * dc) + cc
    rho = math.sqrt(max(w2 - h * h, 0.0)) - major
    reach = minor + SAFE_MARGIN
    return not (rho * rho + h * h > reach * reach)


@numba.njit(cache=True, error_model="numpy")
def _within_safe_band(s_axial: float, safe0: float, safe1: float) -> bool:
    """Whether a quadric's side wall at axial coordinate ``s_axial`` is in its safe band."""
    return safe0 <= s_axial <= safe1


@numba.njit(cache=True, error_model="numpy")
def _trace_rays(
    pieces: NDArray[np.float64],
    kind: NDArray[np.int64],
    element: NDArray[np.int64],
    table: NDArray[np.float64],
    active: NDArray[np.int64],
    at_origin: NDArray[np.bool_],
    n_active: int,
    dirs: NDArray[np.float64],
    start: int,
    stop: int,
    cutoff: float,
    first: int,
    b_lo: NDArray[np.float64],
    b_hi: NDArray[np.float64],
    b_code: NDArray[np.int64],
    b_ok: NDArray[np.bool_],
    b_done: NDArray[np.bool_],
    stamp: NDArray[np.int64],
    n_iv: NDArray[np.int64],
    iv_lo: NDArray[np.float64],
    iv_hi: NDArray[np.float64],
    iv_code: NDArray[np.int64],
    dist: NDArray[np.float64],
    hit_element: NDArray[np.int64],
    traced: NDArray[np.int64],
    exit_piece: NDArray[np.int64],
    exit_code: NDArray[np.int64],
) -> int:
    """Each ray's exit from the union, for rays ``start:stop`` of one origin.

    A ray that the batched first piece ``first`` (-1: none) finished gets its ``dist`` and
    ``hit_element`` (its normal is written, or zeroed, already). The others are traced: their
    count is returned, their indices are in ``traced``, their exits ``t`` in ``dist`` and the
    piece and surface whose interval ended there in ``exit_piece``, ``exit_code`` (-1 and SIDE:
    none), for :func:`_write_hits`.

    ``t`` starts at 0 and extends to the farthest end of the intervals that contain it
    (``lo <= t + SEAM_EPS``, ``hi > t``) until none does. A piece's intervals (cached per ray
    in ``stamp``, ``n_iv``, ``iv_*``) are computed once its (inflated) bounding sphere contains
    the point at ``t``: an interval with ``lo <= t + SEAM_EPS < ...`` and ``hi > t`` needs it.
    """
    n_traced = 0
    for i in range(start, stop):
        dx = dirs[i, 0]
        dy = dirs[i, 1]
        dz = dirs[i, 2]
        if first >= 0 and b_done[i - start]:  # normal written by _first_quadric
            dist[i] = b_hi[i - start]
            hit_element[i] = element[first]
            continue
        if first >= 0 and b_ok[i - start]:
            stamp[first] = i
            n_iv[first] = 1 if b_hi[i - start] > b_lo[i - start] else 0
            iv_lo[first, 0] = b_lo[i - start]
            iv_hi[first, 0] = b_hi[i - start]
            iv_code[first, 0] = b_code[i - start]
        t = 0.0
        last = -1
        last_code = SIDE
        while True:
            new_t = t
            best = -1
            best_code = SIDE
            for j in range(n_active):
                k = active[j]
                if stamp[k] != i:
                    # within the piece's bounding sphere (at t = 0: it holds the origin)?
                    if not (
                        at_origin[j]
                        if t == 0.0
                        else _within_sphere(
                            t,
                            dx * table[k, 8] + dy * table[k, 9] + dz * table[k, 10],
                            table[k, _BCC],
                            table[k, _RAD2],
                        )
                    ):
                        continue
                    if (
                        t != 0.0
                        and kind[k] == TORUS
                        and not _within_tube(
                            t,
                            dx * pieces[k, 3] + dy * pieces[k, 4] + dz * pieces[k, 5],
                            dx * table[k, 0] + dy * table[k, 1] + dz * table[k, 2],
                            table[k, _S0],
                            table[k, _C],
                            pieces[k, 6],
                            pieces[k, 7],
                        )
                    ):
                        continue
                    nv, la, ha, ca, lb, hb, cb = _piece_intervals(
                        pieces, kind, table, k, dx, dy, dz
                    )
                    stamp[k] = i
                    n_iv[k] = nv
                    iv_lo[k, 0] = la
                    iv_hi[k, 0] = ha
                    iv_code[k, 0] = ca
                    iv_lo[k, 1] = lb
                    iv_hi[k, 1] = hb
                    iv_code[k, 1] = cb
                for v in range(n_iv[k]):
                    hi = iv_hi[k, v]
                    if hi >= new_t and hi > t and iv_lo[k, v] <= t + SEAM_EPS:
                        # the farthest end; on a tie the last piece in order (numpy path)
                        if hi > new_t or k >= best:
                            new_t = hi
                            best = k
                            best_code = iv_code[k, v]
            if new_t == t:
                break
            t = new_t
            last = best
            last_code = best_code
            if t > cutoff:
                break
            # through the side wall where no other piece reaches: out of the bore
            if (
                last_code == SIDE
                and kind[last] == QUADRIC
                and _within_safe_band(
                    t * (dx * pieces[last, 3] + dy * pieces[last, 4] + dz * pieces[last, 5])
                    + table[last, _S0],
                    pieces[last, _SAFE0],
                    pieces[last, _SAFE1],
                )
            ):
                break
        dist[i] = t
        traced[n_traced] = i
        exit_piece[n_traced] = last
        exit_code[n_traced] = last_code
        n_traced += 1
    return n_traced


@numba.njit(cache=True, error_model="numpy")
def _write_hits(
    pieces: NDArray[np.float64],
    kind: NDArray[np.int64],
    element: NDArray[np.int64],
    origin: NDArray[np.float64],
    dirs: NDArray[np.float64],
    cutoff: float,
    want_normals: bool,
    n_traced: int,
    traced: NDArray[np.int64],
    exit_piece: NDArray[np.int64],
    exit_code: NDArray[np.int64],
    dist: NDArray[np.float64],
    normal: NDArray[np.float64],
    hit_element: NDArray[np.int64],
) -> None:
    """The results of the rays :func:`_trace_rays` traced, from their exits (the distances are
    in ``dist`` already): beyond ``cutoff``, no hit; at 0, the ray starts outside the bore;
    else the piece and surface whose interval ended at the exit."""
    for n in range(n_traced):
        i = traced[n]
        t = dist[i]
        normal[i, 0] = 0.0
        normal[i, 1] = 0.0
        normal[i, 2] = 0.0
        if t > cutoff:
            dist[i] = _INF
            hit_element[i] = -1
            continue
        if t <= 0.0:
            hit_element[i] = -1
            continue
        last = exit_piece[n]
        hit_element[i] = element[last]
        if want_normals:
            _normal(
                pieces,
                kind,
                last,
                exit_code[n],
                origin[0],
                origin[1],
                origin[2],
                dirs[i, 0],
                dirs[i, 1],
                dirs[i, 2],
                t,
                normal[i],
            )


@numba.njit(cache=True, error_model="numpy", inline="always")
def _normal(
    pieces: NDArray[np.float64],
    kind: NDArray[np.int64],
    k: int,
    code: int,
    ox: float,
    oy: float,
    oz: float,
    dx: float,
    dy: float,
    dz: float,
    t: float,
    out: NDArray[np.float64],
) -> None:
    """The outward unit normal of piece ``k``'s surface ``code`` at ``o + t d`` into ``out``."""
    if code == PLANE0:
        nx, ny, nz = pieces[k, 8], pieces[k, 9], pieces[k, 10]
    elif code == PLANE1:
        nx, ny, nz = pieces[k, 12], pieces[k, 13], pieces[k, 14]
    else:
        wx = ox + t * dx - pieces[k, 0]
        wy = oy + t * dy - pieces[k, 1]
        wz = oz + t * dz - pieces[k, 2]
        ux, uy, uz = pieces[k, 3], pieces[k, 4], pieces[k, 5]
        s = wx * ux + wy * uy + wz * uz
        if kind[k] == QUADRIC:  # the gradient of the cone's implicit function
            slope = pieces[k, 7]
            f = s + slope * (pieces[k, 6] + slope * s)
            nx, ny, nz = wx - f * ux, wy - f * uy, wz - f * uz
        else:  # away from the nearest point of the torus's core circle
            rx, ry, rz = wx - s * ux, wy - s * uy, wz - s * uz
            rho = math.sqrt(rx * rx + ry * ry + rz * rz)
            g = pieces[k, 6] / max(rho, 1e-300)
            nx, ny, nz = wx - g * rx, wy - g * ry, wz - g * rz
    norm = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
    out[0] = nx / norm
    out[1] = ny / norm
    out[2] = nz / norm
