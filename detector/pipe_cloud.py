"""A scan's returns in the pipe frame (:class:`PipeCloud`) and the small helpers every part of
the improved detector (:mod:`detector.improved`) shares: the scan pattern's grid and beam
directions (cached), the returns' wall tolerance, percentiles and even subsamples, azimuth
coverage, the sizes of labelled regions, a fit's confidence, the most frequent radius, a robust
straight line, and when the robust fits stop (the improved planar method shares some of them).

Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import NDArray

from detector.grid import build_grid, label_grid, label_stats, region_stats
from detector.improved_config import ImprovedConfig
from detector.robust import mad_sigma, tukey_weights
from detector.scan import Scan, radial_noise, spec_value
from detector.transforms import SensorInPipe


@dataclass
class PipeCloud:
    """Returns of one scan in the pipe frame.

    The valid returns are kept compact, component-first (``(3, N)``), so a pose change is one
    dense ``(3, 3) @ (3, N)`` product; ``cell`` places each on the unrolled scan grid (cropped
    to the beam-angle columns that hold returns) and strictly ascends (raster order: the
    region labelling and :meth:`points_at` rely on it), whose ``(G, K)`` views (:attr:`valid`,
    :attr:`sigma_r`, :attr:`xyz`, :attr:`pts`) are built on demand for region labelling.
    """

    wraps: bool  # the grid's first and last rows are neighbours
    shape: tuple[int, int]  # (G, K) of the cropped grid
    cell: NDArray[np.intp]  # (N,) flat grid cell of each return, ascending (raster order)
    sensor_v: NDArray[np.float64]  # (3, N) sensor frame
    sigma_v: NDArray[np.float64]  # (N,) radial noise of each return
    sigma_range_v: NDArray[np.float64]  # (N,) range noise of each return
    pose: SensorInPipe
    beam_step: float = 0.0  # angle between neighbouring beams of a plane, radians
    #: the sensor's largest incidence (rad; pi/2: none) and its beam-angle jitter (rad)
    max_incidence: float = 0.5 * math.pi
    angular_jitter: float = 0.0
    xyz_v: NDArray[np.float64] = field(init=False)  # (3, N) pipe frame
    thin: tuple[NDArray[np.float64], NDArray[np.float64]] | None = field(init=False, default=None)
    tol0: NDArray[np.float64] | None = field(init=False, default=None)  # floor + noise part
    floor: float | None = field(init=False, default=None)  # tolerance floor for the regions
    _valid: NDArray[np.bool_] | None = field(init=False, default=None)
    _sigma: NDArray[np.float64] | None = field(init=False, default=None)
    _xyz: NDArray[np.float64] | None = field(init=False, default=None)
    _u: NDArray[np.float64] | None = field(init=False, default=None)
    _r_v: NDArray[np.float64] | None = field(init=False, default=None)
    _tol_v: NDArray[np.float64] | None = field(init=False, default=None)
    _sigma_pct: dict[float, float] = field(init=False, default_factory=dict)
    #: (points, radii, tolerances) under earlier poses (the same arrays, never changed)
    _stashed: list[tuple[NDArray, NDArray | None, NDArray | None]] = field(
        init=False, default_factory=list
    )

    @property
    def n(self) -> int:
        return int(self.cell.size)

    def grid(self, values: NDArray, fill: float | bool) -> NDArray:
        """Per-return ``values`` in compact order, ``(n,)`` or ``(c, n)``, scattered into the
        ``(G, K)`` (or ``(c, G, K)``) grid of this cloud's cells; cells without a return hold
        ``fill``."""
        g, k = self.shape
        if values.ndim == 1:
            return _scatter(values[None, :], self.cell, g * k, fill).reshape(g, k)
        return _scatter(values, self.cell, g * k, fill).reshape(values.shape[0], g, k)

    @property
    def valid(self) -> NDArray[np.bool_]:
        """(G, K) True where the cell holds a return."""
        if self._valid is None:
            self._valid = self.grid(np.ones(self.n, dtype=bool), False)
        return self._valid

    @property
    def sigma_r(self) -> NDArray[np.float64]:
        """(G, K) radial noise of each return (0 where none)."""
        if self._sigma is None:
            self._sigma = self.grid(self.sigma_v, 0.0)
        return self._sigma

    @property
    def xyz(self) -> NDArray[np.float64]:
        """(3, G, K) pipe-frame points (0 where there is no return)."""
        if self._xyz is None:
            self._xyz = self.grid(self.xyz_v, 0.0)
        return self._xyz

    @property
    def u_grid(self) -> NDArray[np.float64]:
        """(G, K) position of each return along the pipe axis (0 where there is no return):
        ``xyz[0]``, without the other two components when they are not built."""
        if self._xyz is not None:
            return self._xyz[0]
        if self._u is None:
            self._u = self.grid(self.xyz_v[0], 0.0)
        return self._u

    @property
    def pts(self) -> NDArray[np.float64]:
        """(G, K, 3) view of the pipe-frame points."""
        return self.xyz.transpose(1, 2, 0)

    def sigma_range_grid(self) -> NDArray[np.float64]:
        """(G, K) range noise of each return (0 where none), m."""
        return self.grid(self.sigma_range_v, 0.0)

    def sigma_percentile(self, q: float) -> float:
        """The ``q``-th percentile of the returns' radial noise (m; computed once; the
        percentiles of :data:`SIGMA_PERCENTILES` in one partial sort)."""
        v = self._sigma_pct.get(q)
        if v is None:
            if q in SIGMA_PERCENTILES and not self._sigma_pct:
                for qq, vq in zip(
                    SIGMA_PERCENTILES, partial_percentiles(self.sigma_v, SIGMA_PERCENTILES)
                ):
                    self._sigma_pct[qq] = vq
                return self._sigma_pct[q]
            v = self._sigma_pct[q] = partial_percentile(self.sigma_v, q)
        return v

    def values(self, mask: NDArray[np.bool_], per_return: NDArray) -> NDArray:
        """Per-return values (``(N,)`` compact order) of the grid cells in ``mask``."""
        return per_return[np.flatnonzero(mask.reshape(-1)[self.cell])]

    def points(self, mask: NDArray[np.bool_]) -> NDArray[np.float64]:
        """(n, 3) pipe-frame points of the grid cells in ``mask`` (in grid order; a view of a
        ``(3, n)`` array)."""
        return _masked_columns(np.ascontiguousarray(mask).reshape(-1), self.cell, self.xyz_v).T

    def points_at(self, flat_cells: NDArray[np.intp]) -> NDArray[np.float64]:
        """(n, 3) pipe-frame points of the given flat grid cells (valid cells of the grid,
        ``0 <= c < G * K``; 0 where a cell holds no return)."""
        if not self.n:
            return np.zeros((np.size(flat_cells), 3))
        # (the returns' cells ascend: each given cell's return found by bisection)
        at = np.minimum(np.searchsorted(self.cell, flat_cells), self.n - 1)
        pts = self.xyz_v[:, at]
        missing = self.cell[at] != flat_cells
        if missing.any():
            pts[:, missing] = 0.0
        return pts.T

    def set_pose(self, pose: SensorInPipe) -> None:
        self._stash()
        self.pose = pose
        self.xyz_v = _transform(pose, self.sensor_v)
        self._xyz = self._u = self._r_v = self._tol_v = None

    def _stash(self) -> None:
        """Keep the radii and tolerances computed under the current pose's points, for a
        :meth:`restore` of those points (the last :data:`STASHED_POSES` poses)."""
        if not hasattr(self, "xyz_v") or (self._r_v is None and self._tol_v is None):
            return
        kept = [e for e in self._stashed if e[0] is not self.xyz_v]
        kept.append((self.xyz_v, self._r_v, self._tol_v))
        self._stashed = kept[-STASHED_POSES:]

    @property
    def r_v(self) -> NDArray[np.float64]:
        """(N,) distance of each return from the pipe axis under the current pose."""
        if self._r_v is None:
            self._r_v = _radii(self.xyz_v)
        return self._r_v

    def restore(self, pose: SensorInPipe, xyz_v: NDArray[np.float64]) -> None:
        """Go back to a pose whose points were computed before (with their radii and
        tolerances, when they were computed and kept)."""
        self._stash()
        self.pose, self.xyz_v = pose, xyz_v
        self._xyz = self._u = self._r_v = self._tol_v = None
        for points, r_v, tol_v in self._stashed:
            if points is xyz_v:
                self._r_v, self._tol_v = r_v, tol_v
                break


@njit(cache=True)
def _scatter(values, cell, size, fill):
    """``(rows, size)`` of ``fill`` with ``values[:, i]`` at column ``cell[i]``."""
    rows = values.shape[0]
    out = np.empty((rows, size), dtype=values.dtype)
    out[:] = fill
    for r in range(rows):
        for i in range(cell.size):
            out[r, cell[i]] = values[r, i]
    return out


@njit(cache=True)
def _radii(xyz):
    """Distance of each ``(3, N)`` point from the x axis: ``sqrt(y^2 + z^2)``."""
    n = xyz.shape[1]
    out = np.empty(n)
    for i in range(n):
        out[i] = math.sqrt(xyz[1, i] * xyz[1, i] + xyz[2, i] * xyz[2, i])
    return out


@njit(cache=True)
def _masked_columns(mask, cell, xyz):
    """The columns ``i`` of ``xyz`` ((3, N)) whose grid cell ``cell[i]`` is set in the flat
    ``mask``, in their order: ``(3, n)``."""
    n = 0
    for i in range(cell.size):
        if mask[cell[i]]:
            n += 1
    out = np.empty((3, n))
    j = 0
    for i in range(cell.size):
        if mask[cell[i]]:
            out[0, j] = xyz[0, i]
            out[1, j] = xyz[1, i]
            out[2, j] = xyz[2, i]
            j += 1
    return out


def _transform(pose: SensorInPipe, xyz: NDArray[np.float64]) -> NDArray[np.float64]:
    """Sensor-frame ``(3, N)`` coordinates into the pipe frame."""
    out = pose.rotation @ xyz
    out += pose.position[:, None]
    return out


@dataclass(frozen=True, eq=False)
class ScanPattern:
    """A scan pattern's (plane and beam angles) unrolled grid and beam directions, computed once
    per pattern as small per-row, per-column, per-beam and per-plane tables: a gather over the
    grid (:func:`_gather_cropped`, :func:`_gather_returns`) reads them and the scan's own
    ranges, not per-cell arrays of the whole grid."""

    wraps: bool  # the grid's first and last rows are neighbours
    k_cols: int  # K, columns of the uncropped grid
    beam_step: float  # angle between neighbouring beams of a plane, radians
    row_plane: NDArray[np.intp]  # (G,) plane of each grid row
    row_kind: NDArray[np.intp]  # (G,) the row of col_beam that holds the row's beams
    col_beam: NDArray[np.intp]  # (U, K) beam of each column per kind of row (-1: none; U <= 2)
    cos_b: NDArray[np.float64]  # (B,) cos(beta) of each beam
    sin_b: NDArray[np.float64]  # (B,) sin(beta)
    cos_a: NDArray[np.float64]  # (P,) cos(alpha), alpha the plane's servo angle
    sin_a: NDArray[np.float64]  # (P,) sin(alpha)


#: Scan patterns by their plane and beam angles, reused.
_PATTERNS: dict[bytes, ScanPattern] = {}
#: The pattern of the last scan with its angles (consecutive scans share one).
_LAST_PATTERN: list[tuple[NDArray, NDArray, ScanPattern] | None] = [None]


def _pattern(scan: Scan) -> ScanPattern:
    """The :class:`ScanPattern` of the scan's plane and beam angles (cached)."""
    last = _LAST_PATTERN[0]
    if (
        last is not None
        and np.array_equal(last[0], scan.plane_angles)
        and np.array_equal(last[1], scan.beam_angles)
    ):
        return last[2]
    key = scan.plane_angles.tobytes() + b"|" + scan.beam_angles.tobytes()
    hit = _PATTERNS.get(key)
    if hit is not None:
        _LAST_PATTERN[0] = (scan.plane_angles.copy(), scan.beam_angles.copy(), hit)
        return hit
    grid = build_grid(scan)
    steps = np.abs(np.diff(np.sort(scan.beam_angles)))
    steps = steps[steps > 1e-9]
    beam_step = float(np.median(steps)) if steps.size else 0.0
    # (the tables hold the very numbers scan.directions() computes, numpy's sines and cosines
    # of the angles, so both forms give the same points to the last bit; the rows of one
    # half-plane kind share their columns' beams)
    beta = np.asarray(scan.beam_angles, dtype=float)
    alpha = np.asarray(scan.plane_angles, dtype=float)
    col_beam, row_kind = np.unique(grid.beam, axis=0, return_inverse=True)
    hit = ScanPattern(
        wraps=grid.wraps,
        k_cols=int(grid.beam.shape[1]),
        beam_step=beam_step,
        row_plane=np.ascontiguousarray(grid.plane[:, 0], dtype=np.intp),
        row_kind=np.ascontiguousarray(row_kind.reshape(-1), dtype=np.intp),
        col_beam=np.ascontiguousarray(col_beam, dtype=np.intp),
        cos_b=np.cos(beta),
        sin_b=np.sin(beta),
        cos_a=np.cos(alpha),
        sin_a=np.sin(alpha),
    )
    if len(_PATTERNS) >= 16:
        _PATTERNS.pop(next(iter(_PATTERNS)))
    _PATTERNS[key] = hit
    _LAST_PATTERN[0] = (scan.plane_angles.copy(), scan.beam_angles.copy(), hit)
    return hit


def prepare_cloud(
    scan: Scan, pose: SensorInPipe, range_bias: float, cfg: ImprovedConfig
) -> PipeCloud:
    pat = _pattern(scan)
    k_cols = pat.k_cols
    g = pat.row_plane.size
    valid, ranges_in = scan.valid.reshape(-1), scan.ranges.reshape(-1)
    tables = (
        scan.n_beams, pat.row_plane, pat.row_kind, pat.col_beam, pat.cos_b, pat.sin_b, pat.cos_a,
        pat.sin_a,
    )  # fmt: skip
    if _moves(scan):
        cell, pb, ranges, local, trig = _gather_returns(valid, ranges_in, *tables, range_bias)
        # continuous sweep: express every plane in the last plane's sensor frame (odometry)
        plane = pb // scan.n_beams
        world = np.einsum("nij,jn->in", scan.nominal_rotations[plane], local)
        world += scan.nominal_positions[plane].T
        local = scan.nominal_rotations[-1].T @ (world - scan.nominal_positions[-1][:, None])
        # (the returns within the horizon, on the grid cropped to the columns that hold
        # returns)
        cell, ranges, local, tr, k = _crop(cell, ranges, local, trig, k_cols, cfg.horizon)
    else:
        # (both steps in one pass: the sensor frame is the one frame of the sweep)
        cell, ranges, local, tr, k = _gather_cropped(
            valid, ranges_in, *tables, range_bias, cfg.horizon
        )
    shape = (g, k)
    sigma_range, sigma_r = radial_noise(scan.spec, ranges, tr[0], tr[1])
    cloud = PipeCloud(
        pat.wraps,
        shape,
        cell,
        np.ascontiguousarray(local),
        sigma_r,
        sigma_range,
        pose,
        pat.beam_step,
        spec_value(scan.spec, "max_incidence", 0.5 * math.pi),
        spec_value(scan.spec, "angular_jitter", 0.0),
    )
    cloud.set_pose(pose)
    return cloud


@njit(cache=True)
def _gather_returns(
    valid, ranges, n_beams, row_plane, row_kind, col_beam, cos_b, sin_b, cos_a, sin_a, bias
):  # fmt: skip
    """The valid returns of the grid cells in raster order (the pattern's tables,
    :class:`ScanPattern`; cells without a beam are skipped): their cells, scan indices, ranges
    less ``bias`` (clamped at 0 m, as :func:`detector.scan.corrected_ranges`), sensor-frame
    points ``(3, n)`` and ``|sin|, |cos|`` of their beam angles ``(2, n)``."""
    g = row_plane.size
    k_cols = col_beam.shape[1]
    n = 0
    for row in range(g):
        base = row_plane[row] * n_beams
        for col in range(k_cols):
            b = col_beam[row_kind[row], col]
            if b >= 0 and valid[base + b]:
                n += 1
    cell = np.empty(n, dtype=np.intp)
    pb = np.empty(n, dtype=np.intp)
    rng = np.empty(n)
    local = np.empty((3, n))
    trig = np.empty((2, n))
    j = 0
    for row in range(g):
        p = row_plane[row]
        for col in range(k_cols):
            b = col_beam[row_kind[row], col]
            if b < 0 or not valid[p * n_beams + b]:
                continue
            r = max(ranges[p * n_beams + b] - bias, 0.0)
            cell[j] = row * k_cols + col
            pb[j] = p * n_beams + b
            rng[j] = r
            _put_point(local, trig, j, b, p, r, cos_b, sin_b, cos_a, sin_a)
            j += 1
    return cell, pb, rng, local, trig


@njit(cache=True)
def _put_point(local, trig, j, b, p, r, cos_b, sin_b, cos_a, sin_a):
    """Column ``j`` of ``local`` ((3, n)): the point at range ``r`` of beam ``b`` of plane
    ``p``, in the products' order of :func:`detector.scan.beam_directions` (the same numbers to
    the last bit); of ``trig`` ((2, n)): ``|sin|, |cos|`` of the beam angle."""
    local[0, j] = cos_b[b] * r
    local[1, j] = (sin_b[b] * cos_a[p]) * r
    local[2, j] = (sin_b[b] * sin_a[p]) * r
    trig[0, j] = abs(sin_b[b])
    trig[1, j] = abs(cos_b[b])


@njit(cache=True)
def _crop(cell, ranges, local, trig, k_cols, horizon):
    """The returns (cells on a grid ``k_cols`` wide, ranges, points ``(3, n)``, ``|sin|, |cos|``
    of their beam angles ``(2, n)``) nearer than ``horizon`` along the sensor's axis, with
    their cells on the grid cropped to the beam-angle columns that hold returns; and the
    cropped grid's width."""
    n = cell.size
    m = 0
    k0 = k_cols
    k1 = -1
    for i in range(n):
        if local[0, i] <= horizon:
            m += 1
            col = cell[i] % k_cols
            k0 = min(k0, col)
            k1 = max(k1, col)
    if m == 0:
        k0, k1 = 0, 0
    width = k1 + 1 - k0
    out_cell = np.empty(m, dtype=np.intp)
    out_range = np.empty(m)
    out_local = np.empty((3, m))
    out_trig = np.empty((2, m))
    j = 0
    for i in range(n):
        if local[0, i] <= horizon:
            row = cell[i] // k_cols
            out_cell[j] = row * width + (cell[i] - row * k_cols - k0)
            out_range[j] = ranges[i]
            out_local[0, j] = local[0, i]
            out_local[1, j] = local[1, i]
            out_local[2, j] = local[2, i]
            out_trig[0, j] = trig[0, i]
            out_trig[1, j] = trig[1, i]
            j += 1
    return out_cell, out_range, out_local, out_trig, width


def _moves(scan: Scan) -> bool:
    """Does the believed (nominal) sensor pose change during the sweep (position or
    orientation, by more than 1e-9)? Then the planes are motion-compensated into the last
    plane's frame."""
    if scan.n_planes < 2:
        return False
    return _spread_exceeds(
        scan.nominal_positions.reshape(scan.n_planes, -1), 1e-9
    ) or _spread_exceeds(scan.nominal_rotations.reshape(scan.n_planes, -1), 1e-9)


@njit(cache=True)
def _spread_exceeds(values, tol):
    """Does any column of the (n, m) ``values`` span more than ``tol`` (``np.ptp`` along the
    first axis)?"""
    n, m = values.shape
    for j in range(m):
        lo = values[0, j]
        hi = values[0, j]
        for i in range(1, n):
            v = values[i, j]
            if v < lo:
                lo = v
            if v > hi:
                hi = v
        if hi - lo > tol:
            return True
    return False


@njit(cache=True)
def _gather_cropped(
    valid, ranges, n_beams, row_plane, row_kind, col_beam, cos_b, sin_b, cos_a, sin_a, bias,
    horizon,
):  # fmt: skip
    """:func:`_gather_returns` then :func:`_crop` in one pass over the grid, row by row, for a
    sweep whose planes share one sensor frame (the directions from the pattern's per-beam and
    per-plane tables, :class:`ScanPattern`): the returns nearer than ``horizon`` along the
    sensor's axis, their cells on the grid cropped to the columns that hold them, ranges,
    points ``(3, n)`` and ``|sin|, |cos|`` of their beam angles ``(2, n)``; and the cropped
    grid's width."""
    g = row_plane.size
    k_cols = col_beam.shape[1]
    m = g * k_cols
    kept = np.empty(m, dtype=np.intp)
    r_kept = np.empty(m)
    n = 0
    k0 = k_cols
    k1 = -1
    for row in range(g):
        kind = row_kind[row]
        base = row_plane[row] * n_beams
        for col in range(k_cols):
            b = col_beam[kind, col]
            if b < 0 or not valid[base + b]:
                continue
            r = max(ranges[base + b] - bias, 0.0)
            if cos_b[b] * r <= horizon:
                kept[n] = row * k_cols + col
                r_kept[n] = r
                n += 1
                k0 = min(k0, col)
                k1 = max(k1, col)
    if n == 0:
        k0, k1 = 0, 0
    width = k1 + 1 - k0
    out_cell = np.empty(n, dtype=np.intp)
    out_local = np.empty((3, n))
    out_trig = np.empty((2, n))
    for j in range(n):
        c = kept[j]
        r = r_kept[j]
        row = c // k_cols
        col = c - row * k_cols
        p = row_plane[row]
        b = col_beam[row_kind[row], col]
        out_cell[j] = row * width + (col - k0)
        _put_point(out_local, out_trig, j, b, p, r, cos_b, sin_b, cos_a, sin_a)
    out_range = r_kept[:n].copy()
    return out_cell, out_range, out_local, out_trig, width


def classify_returns(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig
) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_]]:
    """The returns on the grid, by their distance ``e`` from the wall of radius ``big_r`` (m)
    under the current pose: ``(tol, wall, beyond, inside)``, the (G, K) radial tolerance of
    each return (floor, sensor noise and residual axis error: as :func:`wall_tolerance`; the
    floor where there is no return) and the masks of ``-tol_in <= e <= tol``, ``e > tol`` and
    ``e < -tol_in``, where ``tol_in`` is ``tol`` less any lowering of the floor (a lowered
    floor serves the openings only: returns beyond the wall)."""
    return classify_counted(cloud, big_r, cfg)[:4]


def region_floor(cloud: PipeCloud, cfg: ImprovedConfig) -> float:
    """The tolerance floor of the regions beyond the wall, m: the cloud's lowered one
    (:attr:`PipeCloud.floor`) when set, else ``cfg.tol_floor``."""
    return cfg.tol_floor if cloud.floor is None else cloud.floor


def classify_counted(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig
) -> tuple[
    NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_], int, int, int
]:
    """:func:`classify_returns` and how many returns lie on the wall, beyond it and inside it:
    ``(tol, wall, beyond, inside, n_wall, n_beyond, n_inside)``."""
    floor = region_floor(cloud, cfg)
    lift = 0.0 if cloud.floor is None else cfg.tol_floor - cloud.floor
    g, k = cloud.shape
    return _classify_kernel(
        cloud.cell, g, k, cloud.r_v, cloud.sigma_v, cloud.xyz_v[0], big_r, floor,
        cfg.noise_k, cfg.axis_slope, lift,
    )  # fmt: skip


@njit(cache=True)
def _classify_kernel(cell, g, k, r_v, sigma_v, u_v, big_r, floor, noise_k, slope, lift):
    tol = np.full((g, k), floor + noise_k * 0.0 + slope * 0.0)
    wall = np.zeros((g, k), dtype=np.bool_)
    beyond = np.zeros((g, k), dtype=np.bool_)
    inside = np.zeros((g, k), dtype=np.bool_)
    n_wall = 0
    n_beyond = 0
    n_inside = 0
    for i in range(cell.size):
        row = cell[i] // k
        col = cell[i] - row * k
        t = floor + noise_k * sigma_v[i] + slope * abs(u_v[i])
        tol[row, col] = t
        e = r_v[i] - big_r
        t_in = t + lift
        if e > t:
            beyond[row, col] = True
            n_beyond += 1
        elif e < -t_in:
            inside[row, col] = True
            n_inside += 1
        elif e <= t and e >= -t_in:
            wall[row, col] = True
            n_wall += 1
    return tol, wall, beyond, inside, n_wall, n_beyond, n_inside


def significant_regions(
    beyond: NDArray[np.bool_],
    inside: NDArray[np.bool_],
    wraps: bool,
    min_points: int,
    min_rows: int,
) -> tuple[
    NDArray[np.int32],
    int,
    NDArray[np.bool_],
    int,
    NDArray[np.bool_],
    NDArray[np.bool_],
    NDArray[np.int32] | None,
]:
    """The regions of returns off the wall (``beyond | inside``, (G, K) masks) large enough to
    be a structure: at least ``min_points`` cells spanning at least ``min_rows`` rows of the
    grid (8-neighbourhood, joined across the row seam when the grid ``wraps`` and has three
    rows or more: :func:`detector.grid.label_regions`). Returns ``(labels, n, keep, n_keep,
    beyond_kept, inside_kept, labels_beyond)``: the labelling of every region (1..n), the
    cells of the significant ones and their count, those beyond and inside the wall, and the
    labels of the cells beyond the wall (0 elsewhere) when no significant region holds cells
    both beyond and inside it (else ``None``). One compiled pass."""
    labels, n_lab, keep, n_keep, beyond_k, inside_k, pre, unmixed = _significant_regions(
        np.ascontiguousarray(beyond),
        np.ascontiguousarray(inside),
        bool(wraps) and beyond.shape[0] >= 3,
        int(min_points),
        int(min_rows),
    )
    return labels, int(n_lab), keep, int(n_keep), beyond_k, inside_k, (pre if unmixed else None)


@njit(cache=True)
def _significant_regions(beyond, inside, wraps, min_points, min_rows):
    g, k = beyond.shape
    anomaly = np.empty((g, k), dtype=np.bool_)
    for r in range(g):
        for c in range(k):
            anomaly[r, c] = beyond[r, c] or inside[r, c]
    labels, n_lab = label_grid(anomaly, wraps)
    keep = np.zeros((g, k), dtype=np.bool_)
    beyond_k = np.zeros((g, k), dtype=np.bool_)
    inside_k = np.zeros((g, k), dtype=np.bool_)
    pre = np.zeros((g, k), dtype=np.int32)
    n_keep = 0
    if n_lab == 0:
        return labels, n_lab, keep, n_keep, beyond_k, inside_k, pre, False
    counts, rows = label_stats(labels, n_lab)
    good = np.zeros(n_lab + 1, dtype=np.bool_)
    for lab in range(1, n_lab + 1):
        good[lab] = counts[lab] >= min_points and rows[lab] >= min_rows
    mixed = np.zeros(n_lab + 1, dtype=np.bool_)
    for r in range(g):
        for c in range(k):
            lab = labels[r, c]
            if good[lab]:
                keep[r, c] = True
                n_keep += 1
                if inside[r, c]:
                    inside_k[r, c] = True
                    mixed[lab] = True
                elif beyond[r, c]:
                    beyond_k[r, c] = True
    unmixed = True
    for r in range(g):
        for c in range(k):
            if beyond_k[r, c]:
                if mixed[labels[r, c]]:
                    unmixed = False
                pre[r, c] = labels[r, c]
    return labels, n_lab, keep, n_keep, beyond_k, inside_k, pre, unmixed


def wall_tolerance(cloud: PipeCloud, cfg: ImprovedConfig) -> NDArray[np.float64]:
    """(N,) radial tolerance of each return (compact order) under the current pose."""
    if cloud.tol0 is None:
        cloud.tol0 = cfg.tol_floor + cfg.noise_k * cloud.sigma_v
    if cloud._tol_v is None:
        cloud._tol_v = _sloped_tolerance(cloud.tol0, cfg.axis_slope, cloud.xyz_v[0])
    return cloud._tol_v


@njit(cache=True)
def _sloped_tolerance(tol0, slope, u):
    """``tol0 + slope |u|`` (m), elementwise."""
    out = np.empty(u.size)
    for i in range(u.size):
        out[i] = tol0[i] + slope * abs(u[i])
    return out


def even_subsample(idx: NDArray[np.intp], n: int) -> NDArray[np.intp]:
    if idx.size <= n:
        return idx
    step = idx.size / n
    return idx[(np.arange(n) * step).astype(np.intp)]


def even_indices(m: int, n: int) -> NDArray[np.intp]:
    """``even_subsample(np.arange(m), n)`` without the ``m`` indices: the positions of ``n``
    of ``m`` items spread evenly (all ``m`` when there are no more than ``n``)."""
    if m <= n:
        return np.arange(m)
    return (np.arange(n) * (m / n)).astype(np.intp)


def partial_percentile(x: NDArray[np.float64], q: float) -> float:
    """``np.percentile(x, q)`` (linear interpolation) by partial sorting; 0 for empty input."""
    n = x.size
    if n == 0:
        return 0.0
    h = (n - 1) * q / 100.0
    lo = min(int(h), n - 1)
    if lo + 1 >= n:
        return float(np.partition(x, lo)[lo])
    part = x.copy()  # (np.partition's copy and sort, without its wrappers)
    part.partition((lo, lo + 1))
    return float(part[lo] + (h - lo) * (part[lo + 1] - part[lo]))


def partial_percentiles(x: NDArray[np.float64], qs: tuple[float, ...]) -> list[float]:
    """:func:`partial_percentile` of ``x`` at each of ``qs`` (the same numbers), from one
    partial sort."""
    n = x.size
    if n == 0:
        return [0.0 for _ in qs]
    spots = []
    for q in qs:
        h = (n - 1) * q / 100.0
        lo = min(int(h), n - 1)
        spots.append((h, lo))
    kth = sorted({k for _, lo in spots for k in (lo, lo + 1) if k < n})
    part = x.copy()
    part.partition(kth)
    out = []
    for h, lo in spots:
        if lo + 1 >= n:
            out.append(float(part[lo]))
        else:
            out.append(float(part[lo] + (h - lo) * (part[lo + 1] - part[lo])))
    return out


#: How many earlier poses' radii and tolerances a cloud keeps (:meth:`PipeCloud.restore`).
STASHED_POSES = 4

#: The percentiles of the returns' radial noise the detector reads
#: (:meth:`PipeCloud.sigma_percentile`).
SIGMA_PERCENTILES = (50.0, 90.0)


def axis_direction(theta: float, phi: float) -> NDArray[np.float64]:
    st = math.sin(theta)
    return np.array([math.cos(theta), st * math.cos(phi), st * math.sin(phi)])


def region_sizes(labels: NDArray[np.int32], n_lab: int) -> tuple[NDArray, NDArray]:
    """(cells, grid rows spanned) of each label 0..n_lab of a labelled grid
    (:func:`detector.grid.region_stats`)."""
    return region_stats(labels, n_lab)


def covers_azimuth(xyz: NDArray, idx: NDArray[np.intp], fraction: float, bins: int = 36) -> bool:
    """Do the ``(3, n)`` points ``idx`` cover at least ``fraction`` of the azimuth (as
    :func:`azimuth_coverage`)? Every 16th of them is tried first: when those cover enough, so
    do all of them."""
    if idx.size >= 512:
        few = idx[::16]
        if _yz_coverage(xyz[1, few], xyz[2, few], bins) >= fraction:
            return True
    return _yz_coverage(xyz[1, idx], xyz[2, idx], bins) >= fraction


def _yz_coverage(y: NDArray, z: NDArray, bins: int) -> float:
    """Fraction of ``bins`` azimuth sectors occupied by points at cross-section ``(y, z)``
    (numpy's arctan2, whose last bits differ from the C library's, then one compiled pass)."""
    return float(_phi_coverage(np.arctan2(z, y), bins))


@njit(cache=True)
def _phi_coverage(phi, bins):
    """Fraction of ``bins`` sectors of ``[-pi, pi]`` that the angles ``phi`` occupy."""
    occupied = np.zeros(bins, dtype=np.bool_)
    n_occupied = 0
    for i in range(phi.size):
        k = int(math.floor((phi[i] + math.pi) / (2 * math.pi) * bins)) % bins
        if not occupied[k]:
            occupied[k] = True
            n_occupied += 1
    return n_occupied / bins


def azimuth_coverage(p: NDArray, bins: int = 36) -> float:
    """Fraction of ``bins`` azimuth sectors that the ``(n, 3)`` points occupy."""
    return _yz_coverage(p[:, 1], p[:, 2], bins)


def azimuth_sectors(p: NDArray, bins: int) -> NDArray[np.intp]:
    """The azimuth sector (``0 .. bins - 1``, sector 0 from -pi) of each of the ``(n, 3)``
    pipe-frame points, by the roll of its cross-section ``(y, z)``."""
    phi = np.arctan2(p[:, 2], p[:, 1])
    return np.floor((phi + math.pi) / (2 * math.pi) * bins).astype(np.intp) % bins


def azimuth_uniformity(p: NDArray, bins: int = 12) -> float:
    """Smallest azimuth-bin count relative to the median bin count (1: even all around)."""
    if p.shape[0] == 0:
        return 0.0
    cnt = np.bincount(azimuth_sectors(p, bins), minlength=bins)
    med = float(partial_percentile(cnt.astype(np.float64), 50.0))
    return float(cnt.min()) / med if med > 0 else 0.0


def fit_confidence(n_support: int, rms: float, tol: float, n_scale: float = 30.0) -> float:
    """Confidence in [0, 1] of a fit to ``n_support`` returns with residual ``rms`` against
    the tolerance ``tol`` (m): it saturates with the support (``1 - exp(-n / n_scale)``) and
    falls as the rms approaches the tolerance."""
    c = (1.0 - math.exp(-n_support / n_scale)) * math.exp(-((rms / max(tol, 1e-6)) ** 2) / 4.0)
    return float(min(1.0, max(0.0, c)))


def radius_mode(r: NDArray[np.float64]) -> float:
    """Most frequent radius (m): 1 mm histogram peak refined by the median of its
    neighbourhood (2 mm either side).

    Only the occupied bins and their neighbours are counted (not every bin from the smallest
    radius to the largest), so the work and memory grow with the returns, not with the
    radii's span."""
    bins = np.floor(np.clip(r, -1e12, 1e12) / 0.001).astype(np.int64)
    vals, cnt = np.unique(bins, return_counts=True)
    # the 3-bin sum at each occupied bin and its neighbours; the smallest bin among equal sums
    # wins, as a dense histogram's argmax would pick it
    cand = np.unique(np.concatenate([vals - 1, vals, vals + 1]))
    cand = cand[(cand >= vals[0]) & (cand <= vals[-1])]
    cum = np.concatenate([[0], np.cumsum(cnt)])
    smooth = (
        cum[np.searchsorted(vals, cand + 1, side="right")]
        - cum[np.searchsorted(vals, cand - 1, side="left")]
    )
    peak = (int(cand[int(np.argmax(smooth))]) + 0.5) * 0.001
    near = np.abs(r - peak) <= 0.002
    return float(partial_percentile(r[near], 50.0)) if near.any() else float(peak)


def robust_line(
    x: NDArray[np.float64], y: NDArray[np.float64], sxx_floor: float, sigma_floor: float
) -> tuple[float, float]:
    """Robust fit ``y = a + b x`` (Tukey IRLS, 6 iterations): ``(a, b)``.

    Args:
        x, y: (n,) the points.
        sxx_floor: the fit stops (keeping the last line; ``(median(y), 0)`` at first) when the
            weighted spread ``sum w (x - mean x)^2`` is no larger, units of ``x`` squared.
        sigma_floor: smallest robust standard deviation of the residuals for the Tukey cut-off,
            units of ``y``.
    """
    w = np.ones_like(x)
    a, b = float(partial_percentile(y, 50.0)), 0.0
    for _ in range(6):
        sw = w.sum()
        if sw <= 0:
            break
        xm = float((w * x).sum() / sw)
        ym = float((w * y).sum() / sw)
        sxx = float((w * (x - xm) ** 2).sum())
        if sxx <= sxx_floor:
            break
        b = float((w * (x - xm) * (y - ym)).sum() / sxx)
        a = ym - b * xm
        res = y - (a + b * x)
        s = max(mad_sigma(res), sigma_floor)
        w = tukey_weights(res, 4.685 * s)
    return a, b


@njit(cache=True)
def _sorted_percentile(s, q):
    """``np.percentile`` (linear interpolation, numpy's own rounding) of the sorted ``s`` at
    ``q`` (percent); ``s`` must hold one value or more."""
    n = s.size
    v = (n - 1) * (q / 100.0)
    if v >= n - 1:
        return s[n - 1]
    lo = math.floor(v)
    i = int(lo)
    g = v - lo
    a, b = s[i], s[i + 1]
    d = b - a
    if g >= 0.5:
        return b - d * (1.0 - g)
    return a + d * g


@njit(cache=True)
def _sorted_median(s):
    """``np.median`` of the sorted ``s`` (one value or more)."""
    n = s.size
    h = n // 2
    if n % 2:
        return s[h]
    return (s[h - 1] + s[h]) / 2.0


@njit(cache=True)
def _by_column(cols, k):
    """The values' order grouped by column of the scan grid (``0 <= cols < k``; no bounds
    check), stable within a column: ``(count per column, start of each column's group in the
    order, order)``."""
    count = np.zeros(k, dtype=np.int64)
    for i in range(cols.size):
        count[cols[i]] += 1
    start = np.zeros(k + 1, dtype=np.int64)
    for c in range(k):
        start[c + 1] = start[c] + count[c]
    fill = start[:k].copy()
    order = np.empty(cols.size, dtype=np.int64)
    for i in range(cols.size):
        c = cols[i]
        order[fill[c]] = i
        fill[c] += 1
    return count, start, order


@njit(cache=True)
def column_medians(cols, a, b, k):
    """Per column of the scan grid (``0 <= cols < k``, not checked) that holds values, in
    increasing order: how many it holds and the medians of its ``a`` and of its ``b`` (as
    ``np.median`` gives them: a selection per column, no sort). Returns
    ``(counts, a50, b50)``."""
    count, start, order = _by_column(cols, k)
    a_by = a[order]
    b_by = b[order]
    m = np.count_nonzero(count)
    counts = np.empty(m, dtype=np.int64)
    a50 = np.empty(m)
    b50 = np.empty(m)
    j = 0
    for c in range(k):
        if count[c] == 0:
            continue
        counts[j] = count[c]
        a50[j] = np.median(a_by[start[c] : start[c + 1]])
        b50[j] = np.median(b_by[start[c] : start[c + 1]])
        j += 1
    return counts, a50, b50


@njit(cache=True)
def column_stats(cols, r, sigma, k, g):
    """Per column of the scan grid (``0 <= cols < k``, not checked) that holds values, in
    increasing order: the share of the grid's ``g`` rows it holds, the 10th, 50th and 90th
    percentiles of its ``r`` and the median of its ``sigma`` (as ``np.percentile`` and
    ``np.median`` give them). Returns ``(shares, r10, r50, r90, sigma50)``."""
    count, start, order = _by_column(cols, k)
    r_by = r[order]
    s_by = sigma[order]
    m = np.count_nonzero(count)
    shares = np.empty(m)
    r10 = np.empty(m)
    r50 = np.empty(m)
    r90 = np.empty(m)
    sig50 = np.empty(m)
    j = 0
    denom = max(g, 1)
    for c in range(k):
        if count[c] == 0:
            continue
        rs = np.sort(r_by[start[c] : start[c + 1]])
        ss = np.sort(s_by[start[c] : start[c + 1]])
        shares[j] = count[c] / denom
        r10[j] = _sorted_percentile(rs, 10.0)
        r50[j] = _sorted_percentile(rs, 50.0)
        r90[j] = _sorted_percentile(rs, 90.0)
        sig50[j] = _sorted_median(ss)
        j += 1
    return shares, r10, r50, r90, sig50


@njit(cache=True)
def median_rise(u, r, big_r, band, u_from, u_to):
    """Of the returns within ``band`` (m) of the wall radius ``big_r`` (m; ``u`` along the
    axis, ``r`` from it, m): how many lie in ``[u_from, u_to)`` and how far the median offset
    from ``big_r`` of those lies out from that of the ones before ``u_from`` (m; 0 when either
    group is empty). Returns ``(count, rise)``."""
    past = np.empty(u.size)
    before = np.empty(u.size)
    n_p = 0
    n_b = 0
    for i in range(u.size):
        e = r[i] - big_r
        if abs(e) >= band:
            continue
        if u[i] < u_from:
            before[n_b] = e
            n_b += 1
        elif u[i] < u_to:
            past[n_p] = e
            n_p += 1
    if n_p == 0 or n_b == 0:
        return n_p, 0.0
    return n_p, np.median(past[:n_p]) - np.median(before[:n_b])
