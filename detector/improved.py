"""The improved detector (``method="improved"``): model fitting in the pipe frame.

Where the thesis categorises points by radius and fits an ellipse to the outline of an opening,
this method fits the 3D geometry of the structure itself, using what the PIRATE knows: the
clamped diameter and (optionally) the sensor pose in the pipe.

1. **Pipe frame.** Every return is mapped into the pipe frame (the known ``sensor_in_pipe``
   pose, else the thesis's centred-and-aligned assumption), then the pipe axis is refined by a
   robust fit of a cylinder of the clamped radius to the wall points (4 parameters:
   cross-section offset and tilt, with a weak prior towards the known pose when the wall seen is
   short). This removes sensor misalignment (thesis 5.3) without any outside feedback; when the
   given pose already explains the wall before the structure, only the fit over that whole
   stretch of wall runs (from the given pose), not the first, wider one. A refinement is dropped
   when its cylinder misses its own wall returns by more than their noise explains, and the
   given pose stands when less than 5 cm of straight wall is in view before the structure and
   the pose explains it (near the start of a wide bend's arc a cylinder tilted about the nearest
   wall fits the arc), unless a refined axis explains as many returns and fits 10 cm or more of
   straight wall to a quarter of the scatter allowed (the given pose is then the misaligned one,
   its wall drifting off the tolerance a little way ahead). Of candidate poses explaining as
   many wall returns, the one that fits them most closely is kept (a cylinder tilted onto the
   first centimetres of a gentle taper or arc explains no more of them, only more loosely). A
   long bend's arc and a taper leave the wall so gently that the wall a pose was chosen on can
   reach a few centimetres into them: once one is fitted, the pose is chosen again on the wall
   ending 1 cm before its start (over one set of returns for every candidate pose) and the
   structure fitted again under it. The pipe's radius is measured from the wall (the wall just
   beyond the nearest returns, then the wall before the structure), within 3 mm of the clamp
   reading: the clamp's encoders read the diameter to a millimetre or two. When fewer returns
   than a region needs leave the wall tolerance under the given pose, or else under the refined
   axis, the scan is straight pipe and nothing else runs (the common case in a run).
2. **Classification.** Each return's radial residual ``r - D/2`` is compared with a per-point
   tolerance from the sensor model in ``scan.spec`` (range noise projected on the radius, plus a
   floor; for a noiseless sensor whose wall the refined axis fits to a fraction of a millimetre,
   the floor for returns beyond the wall shrinks towards that scatter (under the given pose
   too, when it is kept), down to 0.8 mm, so the openings of small pipes far ahead show).
   Non-wall returns are grouped into connected regions of the unrolled scan grid
   (:mod:`detector.grid`); regions too small or one azimuth wide are rejected as clutter. A
   region beyond the wall that goes all round is split into its deep parts when there are two
   or more (from a tee's narrower stem, the run's wall lies a step beyond the stem's all round
   and joins both ways on).
3. **Hypotheses.** Returns beyond the wall (``r > D/2``) are *lobes*: openings towards an
   outgoing pipe. Without lobes the structure is axisymmetric: an end wall (a plane
   perpendicular to the axis, kind ``closure``; flat to within the range noise and no better
   explained by a quadratic surface with a sag of millimetres, which tells it from the curved
   far wall of a pipe seen head-on) or a reducer (a cone from the wall radius to a new radius
   fitted as ``r(u)`` together with the wall just before it; a widening starts where the line
   through its cone's rings of beams meets the wall radius (under range noise, where the rings'
   medians leave the wall), or, its cone seen by one ring or none, in the middle of the interval
   the rings allow; an end wall seen through a narrowing, spread along the axis by the range
   noise, is left out of its fit and bounds the narrow radius from below). A far wall seen
   head-on is fitted as an outgoing pipe of the clamped radius with unknown roll, seen from
   inside; when it runs on evenly to both sides it is a pipe across (both ways open); when it
   looks flat within the range noise and only its curvature tells it from an end wall, it
   overrules the end wall only as a single turn. With lobes, each lobe is an outgoing pipe: a
   cylinder whose axis meets the incoming axis at the reference point ``(L, 0, 0)`` with
   deflection ``angle``, roll ``direction`` and radius ``rho``. Initial values come from a
   coarse grid over ``(L, angle)`` with the lobe's mean roll; all lobes are then refined jointly
   by Tukey-weighted Gauss-Newton on the returns of every lobe (each return assigned to the
   surface it fits best; with two lobes on opposite sides, to the branch of its own opening:
   fitted to the nearer of two cylinders, noisy returns at the openings' rims fall between them
   and the branches lean apart for them). Two lobes on opposite sides are also fitted as one
   pipe across (a single cylinder of the clamped radius, both its ways open), which is kept
   unless the two branches fit significantly better. A single lobe is also fitted as a
   long-radius bend (a torus of bend radius ``R_b`` between the two straight pipes, the
   reference point still where the straight axes meet) when the straight axes fit it loosely or
   leave more than 5 % of its returns out, and the better fit is kept. For a noiseless sensor
   the torus is then polished on returns spread evenly along the axis (the few returns from
   the far end of the arc fix its angle; an even subsample of all returns holds two or three
   of them). An arc that starts right ahead fills the view with curved wall, and an axis
   refined on the nearest wall-like returns is laid into it: when the torus fits the returns
   twice as closely under the given pose, the given pose stands.
4. **Straight on.** A junction continues straight when the incoming pipe's wall is seen again
   beyond the structure (more than two diameters past the reference point) around most of the
   circumference; its option has the clamped diameter. Its side branches are no wider than the
   run, and each cuts a hole in the run's wall (half-length ``rho / sin(angle)``, centred
   ``R cot(angle)`` past the reference point, ``asin(rho / R)`` wide on either side of its
   roll, which sizes a narrower branch); when the few returns through a far opening lead
   the fit away from the hole seen, the fit restarts from the hole and stays near it. Lobes
   that start well past the nearest one belong to a structure farther along the run. A side
   hole that only one ring of beams (or two or three) enters (a small pipe's branch seen far
   away, between rings) shows as a bump of returns a millimetre or two beyond the wall on
   those rings alone; its far side places and sizes the branch (:mod:`detector.grazing`)
   when nothing nearer was found, or when a junction's branch fit rests on a handful of
   returns.
   A junction's branches are held at the standard angle of fittings (90 deg for tees and
   crosses, 45 or 135 deg for laterals) when fitted within 25 deg of it and the returns do
   not reject it (likelihood ratio): a small opening far away shows a patch of the branch
   whose deflection trades against the reference point and the radius.
5. **Kind and confidence.** One way on -> ``bend``; two or more -> ``junction``. Confidence
   combines the number of supporting returns and the fit residual relative to the tolerance.
   Degenerate inputs (no returns, too few wall returns, fits that fail or leave the physical
   range) give ``straight`` with low confidence, never NaN. The exception is a scan that sees
   hardly anything ahead of the sensor where a straight pipe would show its wall to hundreds
   of beams: the pipe is blocked within the sensor's minimum range (an end wall 10 cm ahead of
   a 12 cm minimum range; anything else that near still lets beams on into the pipe beyond),
   reported as a ``closure`` no farther than where the wall ahead would start to show, with
   confidence 0.5.

Speed: a scan whose returns all lie on the wall under the given pose is straight pipe before
any fit. Returns are kept compact and component-first (one ``(3, 3) @ (3, N)`` product per
pose; their radii and tolerances cached per pose), the unrolled grid and beam directions are
cached per scan pattern, every fit uses a few hundred returns with analytic Jacobians, and the
robust fits anneal their cut-off over three iterations and then stop on a small cost change
(:func:`detector.robust.robust_gauss_newton`, Cholesky steps).

All lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from detector.detection import Detection
from detector.grazing import find_ring_holes
from detector.grid import build_grid, label_regions
from detector.options import StructureOption, option_order
from detector.robust import mad_sigma, robust_gauss_newton, tukey_cost, tukey_weights
from detector.scan import Scan
from detector.transforms import SensorInPipe, option_direction

X_AXIS = np.array([1.0, 0.0, 0.0])
#: Fits stop when no parameter moves by more than this (metres, radians): far below the
#: accuracy that matters, and most fits then end in a few iterations.
STEP_TOL = 1e-6
#: Fits shrink their robust cut-off over this many iterations, then run to convergence.
ANNEAL = 3
#: ... or once a step lowers the robust cost by less than this fraction.
COST_TOL = 1e-4
#: The wall's own radius replaces the clamped one when they differ by more than this, m.
RADIUS_DEAD_BAND = 0.00025
#: With the structure starting less than ``NO_WALL_VIEW`` (m) past the nearest returns, a
#: refined pipe axis replaces the given pose only when it explains this fraction (and ten)
#: more of the wall returns.
NO_WALL_VIEW = 0.01
GIVEN_POSE_MARGIN = 0.02
#: A scan whose beams would see a straight pipe's wall ahead of the sensor in at least
#: ``BLIND_MIN_EXPECTED`` returns, but sees at most ``BLIND_MAX_AHEAD`` of that many there, is
#: blocked ahead within the minimum range (an end wall 10 cm ahead of a sensor whose minimum
#: range is 12 cm); the end wall gets confidence ``BLIND_CONFIDENCE`` (its distance is a bound).
BLIND_MIN_EXPECTED = 200
BLIND_MAX_AHEAD = 0.01
BLIND_CONFIDENCE = 0.5
#: Deflections of standard branch fittings (tees and crosses, laterals either way), rad; a
#: junction's branch fitted within ``SNAP_WITHIN`` of one is held at it when the returns allow
#: (likelihood ratio at most ``SNAP_LR`` per branch) and it turns by at most
#: ``SNAP_MAX_TURN`` about the run; a radius held with it may move by ``SNAP_RADIUS`` of itself.
#: (A small branch's opening seen along the run from 20 cm under range noise is a few dozen
#: returns that a deflection 10-15 deg off fits as well: the returns, not the distance from
#: the standard angle, decide.)
STANDARD_BRANCH_ANGLES = np.radians([45.0, 90.0, 135.0])
SNAP_WITHIN = math.radians(25.0)
SNAP_LR = 6.0
SNAP_MAX_TURN = math.radians(3.0)
SNAP_RADIUS = 0.03
#: Less straight wall than this in view along the axis (m) before a structure: the given pose
#: stands when it explains that wall.
SHORT_WALL_VIEW = 0.05
#: ... unless a refined axis explains as many of those returns and fits at least
#: ``LONG_WALL_SPAN`` (m) of straight wall to within ``LONG_WALL_RMS`` of the scatter a straight
#: wall may show (a sensor misaligned by 20 % of D and 4 deg sees its wall drift off the
#: tolerance 12 cm ahead under the given pose).
LONG_WALL_SPAN = 0.1
LONG_WALL_RMS = 0.25
#: The wall this far along the axis beyond the nearest returns (m) gives the first estimate of
#: the pipe radius.
NEAR_WALL = 0.03
#: The pose of a long-radius bend or a reducer is chosen again on the wall ending this far
#: (m) before the fitted arc or taper starts, when it was chosen on wall returns past that.
GENTLE_START_MARGIN = 0.01
#: A single way on whose straight-axes fit leaves out more than this fraction of its returns
#: is also tried as a long-radius bend (as one that fits them loosely is).
TORUS_TRY_SUPPORT = 0.95
#: A long bend's torus under the given pose fitting this many times more closely (rms) than
#: under the refined one: the refinement was laid into the arc, the given pose stands.
TORUS_POSE_RATIO = 2.0
#: A long bend's angle is polished on returns spread along its arc only when their range noise
#: (median, plus 0.3 mm) is below this, m (a noiseless sensor's range resolution).
TORUS_POLISH_MAX_NOISE = 0.001
#: Returns of a widening this much (m; or three times their noise) short of the wider pipe's
#: radius lie on its cone, not on the wider pipe.
CONE_PLATEAU_MARGIN = 0.0015
#: A line along a widening's cone needs returns rising this much (m; or six times their noise)
#: from the wall to the wider pipe: two rings of beams, not the spread of one.
CONE_MIN_RISE = 0.002
#: The returns of a cone seen by several rings lie on its line to within this much (m, robust
#: standard deviation across it; or three times their noise).
CONE_LINE_SCATTER = 0.00015
#: Returns of a cone are binned this long (m along the axis) to find its first ring of beams
#: (or the first few, close together near the sensor).
CONE_FIRST_RING = 0.01
#: Fewer returns than this off the wall are stray, not a ring of beams on a cone, whose
#: returns cover this fraction of the azimuth at least.
CONE_MIN_RETURNS = 6
CONE_RING_COVERAGE = 0.75
#: The rings' hinge (:func:`_ring_hinge_start`) looks this far (m) before the first returns off
#: the wall; a ring rises when its median lies ``HINGE_MIN_SNR`` times its noise and at least
#: ``HINGE_MIN_RISE`` (m) off the wall.
HINGE_REACH = 0.15
HINGE_MIN_SNR = 4.0
HINGE_MIN_RISE = 0.0005
#: A region of returns beyond the wall covering this fraction of the azimuth goes all round.
ALL_ROUND = 0.75


@dataclass(frozen=True)
class ImprovedConfig:
    """Tuning of the improved detector. Lengths in metres, angles in radians.

    Attributes:
        tol_floor: smallest radial tolerance of a wall return.
        noise_k: tolerance = floor + ``noise_k`` x the return's radial noise (sensor model)
            + ``axis_slope`` x the return's distance along the axis (residual axis error).
        min_lobe_points: fewest returns beyond the wall in an opening.
        min_region_rows: fewest azimuth rows an anomaly region must span.
        min_anomaly_points: fewest non-wall returns for anything but ``straight``.
        horizon: returns farther along the axis are ignored.
        fit_points: returns used per structure fit (evenly subsampled).
        axis_points: wall returns used for the pipe-axis refinement.
        prior_offset, prior_tilt: prior standard deviation of the pipe-axis refinement.
        straight_on_coverage: fraction of the circumference on which the wall must be seen
            beyond a junction for a straight-on option.
        radius_lr_per_branch: likelihood-ratio threshold (per outgoing pipe) above which a
            free outgoing radius replaces the clamped one.
        max_radius_correction: largest change of the clamped radius that the wall returns
            may make (the encoders' error; the thesis checks the diameter to +-5 mm).
        far_wall_min_lean: a far wall seen head-on gives the way on only when its returns lie
            on average at least this many radii (of the clamped pipe) along the fitted axis
            from the axis' foot; nearer, the direction is undetermined and no turn is reported.
    """

    tol_floor: float = 0.002
    axis_slope: float = 0.002
    noise_k: float = 3.0
    min_lobe_points: int = 6
    min_region_rows: int = 3
    min_anomaly_points: int = 10
    horizon: float = 2.0
    fit_points: int = 300
    axis_points: int = 300
    prior_offset: float = 0.01
    prior_tilt: float = math.radians(3.0)
    straight_on_coverage: float = 0.5
    radius_lr_per_branch: float = 12.0
    max_radius_correction: float = 0.003
    far_wall_min_lean: float = 0.15


DEFAULT_CONFIG = ImprovedConfig()


# --------------------------------------------------------------------------- point cloud
@dataclass
class PipeCloud:
    """Returns of one scan in the pipe frame.

    The valid returns are kept compact, component-first (``(3, N)``), so a pose change is one
    dense ``(3, 3) @ (3, N)`` product; ``cell`` places each on the unrolled scan grid (cropped
    to the beam-angle columns that hold returns), whose ``(G, K)`` views (:attr:`valid`,
    :attr:`sigma_r`, :attr:`xyz`, :attr:`pts`) are built on demand for region labelling.
    """

    wraps: bool  # the grid's first and last rows are neighbours
    shape: tuple[int, int]  # (G, K) of the cropped grid
    cell: NDArray[np.intp]  # (N,) flat grid cell of each return
    sensor_v: NDArray[np.float64]  # (3, N) sensor frame
    sigma_v: NDArray[np.float64]  # (N,) radial noise of each return
    sigma_range_v: NDArray[np.float64]  # (N,) range noise of each return
    pose: SensorInPipe
    beam_step: float = 0.0  # angle between neighbouring beams of a plane, radians
    xyz_v: NDArray[np.float64] = field(init=False)  # (3, N) pipe frame
    thin: tuple[NDArray[np.float64], NDArray[np.float64]] | None = field(init=False, default=None)
    tol0: NDArray[np.float64] | None = field(init=False, default=None)  # floor + noise part
    floor: float | None = field(init=False, default=None)  # tolerance floor for the regions
    _valid: NDArray[np.bool_] | None = field(init=False, default=None)
    _sigma: NDArray[np.float64] | None = field(init=False, default=None)
    _xyz: NDArray[np.float64] | None = field(init=False, default=None)
    _r_v: NDArray[np.float64] | None = field(init=False, default=None)
    _tol_v: NDArray[np.float64] | None = field(init=False, default=None)

    @property
    def n(self) -> int:
        return int(self.cell.size)

    def _grid(self, values: NDArray, fill: float | bool) -> NDArray:
        g, k = self.shape
        if values.ndim == 1:
            out = np.full(g * k, fill, dtype=values.dtype)
            out[self.cell] = values
            return out.reshape(g, k)
        out = np.full((values.shape[0], g * k), fill, dtype=values.dtype)
        for row, vals in zip(out, values):  # (row by row: a faster scatter)
            row[self.cell] = vals
        return out.reshape(values.shape[0], g, k)

    @property
    def valid(self) -> NDArray[np.bool_]:
        """(G, K) True where the cell holds a return."""
        if self._valid is None:
            self._valid = self._grid(np.ones(self.n, dtype=bool), False)
        return self._valid

    @property
    def sigma_r(self) -> NDArray[np.float64]:
        """(G, K) radial noise of each return (0 where none)."""
        if self._sigma is None:
            self._sigma = self._grid(self.sigma_v, 0.0)
        return self._sigma

    @property
    def xyz(self) -> NDArray[np.float64]:
        """(3, G, K) pipe-frame points (0 where there is no return)."""
        if self._xyz is None:
            self._xyz = self._grid(self.xyz_v, 0.0)
        return self._xyz

    @property
    def pts(self) -> NDArray[np.float64]:
        """(G, K, 3) view of the pipe-frame points."""
        return self.xyz.transpose(1, 2, 0)

    def values(self, mask: NDArray[np.bool_], per_return: NDArray) -> NDArray:
        """Per-return values (``(N,)`` compact order) of the grid cells in ``mask``."""
        return per_return[np.flatnonzero(mask.reshape(-1)[self.cell])]

    def points(self, mask: NDArray[np.bool_]) -> NDArray[np.float64]:
        """(n, 3) pipe-frame points of the grid cells in ``mask`` (in grid order)."""
        idx = np.flatnonzero(mask.reshape(-1)[self.cell])
        return np.take(self.xyz_v, idx, axis=1).T

    def points_at(self, flat_cells: NDArray[np.intp]) -> NDArray[np.float64]:
        """(n, 3) pipe-frame points of the given flat grid cells."""
        return np.take(self.xyz.reshape(3, -1), flat_cells, axis=1).T

    def set_pose(self, pose: SensorInPipe) -> None:
        self.pose = pose
        self.xyz_v = _transform(pose, self.sensor_v)
        self._xyz = self._r_v = self._tol_v = None

    @property
    def r_v(self) -> NDArray[np.float64]:
        """(N,) distance of each return from the pipe axis under the current pose."""
        if self._r_v is None:
            self._r_v = np.sqrt(np.square(self.xyz_v[1]) + np.square(self.xyz_v[2]))
        return self._r_v

    def restore(self, pose: SensorInPipe, xyz_v: NDArray[np.float64]) -> None:
        """Go back to a pose whose points were computed before."""
        self.pose, self.xyz_v = pose, xyz_v
        self._xyz = self._r_v = self._tol_v = None


def _transform(pose: SensorInPipe, xyz: NDArray[np.float64]) -> NDArray[np.float64]:
    """Sensor-frame ``(3, N)`` coordinates into the pipe frame."""
    out = pose.rotation @ xyz
    out += pose.position[:, None]
    return out


#: Unrolled grid and beam directions per scan pattern (plane and beam angles), reused.
_PATTERNS: dict[bytes, tuple[bool, int, NDArray, NDArray, NDArray, NDArray, float]] = {}
#: The pattern of the last scan with its angles (consecutive scans share one).
_LAST_PATTERN: list[tuple[NDArray, NDArray, tuple] | None] = [None]


def _pattern(scan: Scan) -> tuple[bool, int, NDArray, NDArray, NDArray, NDArray, float]:
    """(wraps, K, flat scan index of each grid cell (G*K,), unit beam direction (3, G*K),
    |sin beta| and |cos beta| (2, G*K), the cells where the half-plane has no such beam, the
    angle between neighbouring beams) of the scan's angle pattern."""
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
    missing = grid.beam.reshape(-1) < 0
    beam = np.maximum(grid.beam, 0).reshape(-1)
    plane = grid.plane.reshape(-1)
    src = plane * scan.n_beams + beam
    dirs = scan.directions()[plane, beam].T  # (3, G*K)
    beta = scan.beam_angles[beam]
    trig = np.stack([np.abs(np.sin(beta)), np.abs(np.cos(beta))])
    hit = (
        grid.wraps,
        int(grid.beam.shape[1]),
        src,
        np.ascontiguousarray(dirs),
        trig,
        np.flatnonzero(missing),
        beam_step,
    )
    if len(_PATTERNS) >= 16:
        _PATTERNS.pop(next(iter(_PATTERNS)))
    _PATTERNS[key] = hit
    _LAST_PATTERN[0] = (scan.plane_angles.copy(), scan.beam_angles.copy(), hit)
    return hit


def _prepare(scan: Scan, pose: SensorInPipe, range_bias: float, cfg: ImprovedConfig) -> PipeCloud:
    wraps, k_cols, src, dirs, trig, src_missing, beam_step = _pattern(scan)
    ok = scan.valid.reshape(-1)[src]  # (missing cells point at a copy of a real one ...)
    ok[src_missing] = False  # (... and are dropped here)
    cell = np.flatnonzero(ok)
    pb = src[cell]
    ranges = np.maximum(scan.ranges.reshape(-1)[pb] - range_bias, 0.0)
    local = np.take(dirs, cell, axis=1)
    local *= ranges
    if scan.n_planes > 1 and float(np.ptp(scan.nominal_positions, axis=0).max()) > 1e-9:
        # continuous sweep: express every plane in the last plane's sensor frame (odometry)
        plane = pb // scan.n_beams
        world = np.einsum("nij,jn->in", scan.nominal_rotations[plane], local)
        world += scan.nominal_positions[plane].T
        local = scan.nominal_rotations[-1].T @ (world - scan.nominal_positions[-1][:, None])
    near = local[0] <= cfg.horizon
    if not near.all():
        keep = np.flatnonzero(near)
        cell, ranges, local = cell[keep], ranges[keep], np.take(local, keep, axis=1)
    tr = np.take(trig, cell, axis=1)
    # crop the grid to the beam-angle columns that hold returns
    g = src.size // max(k_cols, 1)
    row, col = np.divmod(cell, k_cols)
    if cell.size:
        k0, k1 = int(col.min()), int(col.max()) + 1
    else:
        k0, k1 = 0, 1
    shape = (g, k1 - k0)
    cell = row * shape[1] + (col - k0)
    spec = scan.spec or {}
    sig = float(spec.get("noise_sigma", 0.0))
    sig_rel = float(spec.get("noise_sigma_rel", 0.0))
    res = float(spec.get("range_resolution", 0.0))
    jitter = float(spec.get("angular_jitter", 0.0))
    if sig_rel != 0.0:
        sigma_range = np.sqrt(sig**2 + (sig_rel * ranges) ** 2 + (res**2) / 12.0)
    else:  # (the same numbers, without the per-return terms that vanish)
        sigma_range = np.full(ranges.size, math.sqrt(sig**2 + (res**2) / 12.0))
    sigma_r = sigma_range * tr[0]
    if jitter != 0.0:
        sigma_r += ranges * jitter * tr[1]
    cloud = PipeCloud(
        wraps, shape, cell, np.ascontiguousarray(local), sigma_r, sigma_range, pose, beam_step
    )
    cloud.set_pose(pose)
    return cloud


def _subsample(idx: NDArray[np.intp], n: int) -> NDArray[np.intp]:
    if idx.size <= n:
        return idx
    step = idx.size / n
    return idx[(np.arange(n) * step).astype(np.intp)]


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


def _pct(x: NDArray[np.float64], q: float) -> float:
    """``np.percentile(x, q)`` (linear interpolation) by partial sorting; 0 for empty input."""
    n = x.size
    if n == 0:
        return 0.0
    h = (n - 1) * q / 100.0
    lo = min(int(h), n - 1)
    if lo + 1 >= n:
        return float(np.partition(x, lo)[lo])
    part = np.partition(x, (lo, lo + 1))
    return float(part[lo] + (h - lo) * (part[lo + 1] - part[lo]))


# --------------------------------------------------------------------------- axis refinement
def _axis_pose(params: NDArray[np.float64], sensor_origin: NDArray[np.float64]) -> SensorInPipe:
    """Correction pose: pipe frame whose axis passes through (0, y0, z0) with slopes (a, b)."""
    y0, z0, a, b = (float(v) for v in params)
    n = math.sqrt(1.0 + a * a + b * b)
    d0, d1, d2 = 1.0 / n, a / n, b / n
    # rotation taking the new axis direction d to +x (minimal rotation about d x X)
    s = math.hypot(d1, d2)
    if s < 1e-12:
        rot = np.eye(3)
    else:
        k1, k2 = d2 / s, -d1 / s
        c1 = 1.0 - d0
        rot = np.array(
            [
                [1.0 - c1, -s * k2, s * k1],
                [s * k2, 1.0 + c1 * (k1 * k1 - 1.0), c1 * k1 * k2],
                [-s * k1, c1 * k1 * k2, 1.0 + c1 * (k2 * k2 - 1.0)],
            ]
        )
    origin = np.array([0.0, y0, z0])
    # new coordinates: rot @ (p - origin), shifted along x so the sensor origin is at u = 0
    pos = -(rot @ origin)
    pos[0] -= float(rot[0] @ (sensor_origin - origin))
    return SensorInPipe.trusted(pos, rot)


def _cyl_axis_residual(
    sub: NDArray[np.float64], big_r: float, x: NDArray[np.float64], want_jac: bool
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Residual (distance to the axis - R) of ``(3, N)`` points for the axis through
    (0, y0, z0) along (1, a, b), and its analytic Jacobian ``(N, 4)``."""
    y0, z0, a, b = (float(v) for v in x)
    n = math.sqrt(1.0 + a * a + b * b)
    qu = sub[0]
    qy = sub[1] - y0
    qz = sub[2] - z0
    t = (qu + a * qy + b * qz) * (1.0 / n)
    dist = qu * qu + qy * qy + qz * qz - t * t
    np.maximum(dist, 1e-18, out=dist)
    np.sqrt(dist, out=dist)
    res = dist - big_r
    if not want_jac:
        return res, None
    inv = 1.0 / dist
    jac = np.empty((4, qu.size))
    jac[0] = (t * (a / n) - qy) * inv
    jac[1] = (t * (b / n) - qz) * inv
    tn = t * (1.0 / n)
    jac[2] = tn * jac[0]
    jac[3] = tn * jac[1]
    return res, jac.T


def _refine_axis(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, u_max: float | None = None
) -> tuple[SensorInPipe, dict[str, Any]]:
    """Refine the pipe axis from the wall returns. Without ``u_max`` the nearest 60 % of the
    wall-like returns are used (a structure ahead is farther away); with it, every wall-like
    return before ``u_max`` (the start of the structure), which gives the tilt a long lever."""
    xyz = cloud.xyz_v
    info: dict[str, Any] = {"axis_points": 0}
    if xyz.shape[1] < 20:
        return cloud.pose, info
    r = cloud.r_v
    gate = max(0.35 * big_r, 0.01)
    cand = np.flatnonzero(np.abs(r - big_r) < gate)
    if cand.size < 20:
        return cloud.pose, info
    u = xyz[0, cand]
    if u_max is None:
        keep = max(400, int(0.6 * cand.size))
        if keep < cand.size:
            cut = float(np.partition(u, keep - 1)[keep - 1])
            cand = cand[u <= cut]
    else:
        cand = cand[u < u_max]
        if cand.size < 40:
            return cloud.pose, info
    sub = np.ascontiguousarray(xyz[:, _subsample(cand, cfg.axis_points)])
    # the tilt needs a lever arm: over a short stretch of wall it is not observable (and a
    # gentle taper would pass for a tilted wall), so it is held at the prior
    span = float(_pct(sub[0], 95) - _pct(sub[0], 5))
    tilt_sigma = cfg.prior_tilt if span >= 0.05 else math.radians(0.05)
    prior = np.array([cfg.prior_offset, cfg.prior_offset, tilt_sigma, tilt_sigma])
    info["axis_span"] = span
    x, res, w = robust_gauss_newton(
        None,
        np.zeros(4),
        np.full(4, 1e-5),
        c=gate,
        iterations=10,
        prior_sigma=prior,
        c_final=0.004,
        step_tol=STEP_TOL,
        anneal=ANNEAL,
        cost_tol=COST_TOL,
        resjac=lambda p: _cyl_axis_residual(sub, big_r, p, True),
    )
    info.update(
        axis_points=int((w > 0).sum()),
        axis_offset=[float(x[0]), float(x[1])],
        axis_tilt_deg=math.degrees(math.atan(math.hypot(x[2], x[3]))),
        axis_rms=float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9))),
    )
    if not np.all(np.isfinite(x)) or abs(x[0]) > big_r or abs(x[1]) > big_r:
        return cloud.pose, info
    if math.hypot(x[2], x[3]) > math.tan(math.radians(8.0)):
        return cloud.pose, info
    return _axis_pose(x, cloud.pose.position).compose(cloud.pose), info


# --------------------------------------------------------------------------- geometry helpers
def _dir(theta: float, phi: float) -> NDArray[np.float64]:
    st = math.sin(theta)
    return np.array([math.cos(theta), st * math.cos(phi), st * math.sin(phi)])


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


# --------------------------------------------------------------------------- main entry
def detect_improved(
    scan: Scan,
    clamped_diameter: float,
    sensor_in_pipe: object = None,
    config: ImprovedConfig = DEFAULT_CONFIG,
    range_bias: float | None = None,
    refine_axis: bool = True,
) -> Detection:
    """The improved detector on a full sweep (see module docstring).

    Args:
        scan: a rotating-LiDAR sweep (any number of planes).
        clamped_diameter: inner diameter from the clamping encoders, metres.
        sensor_in_pipe: known sensor pose in the pipe frame (:class:`SensorInPipe` or a
            ``(position, rotation)`` pair); ``None``: centred and aligned, refined from the scan.
        config: tuning.
        range_bias: calibrated constant range bias subtracted from every return, metres;
            default: ``scan.spec["bias"]`` (0 if absent).
        refine_axis: refine the pipe axis from the wall returns.
    """
    t0 = time.perf_counter()
    d_clamped = float(clamped_diameter)
    if not (math.isfinite(d_clamped) and d_clamped > 0.0):
        raise ValueError(f"clamped_diameter must be a positive length (m), got {clamped_diameter}")
    big_r = 0.5 * d_clamped
    pose0 = SensorInPipe.coerce(sensor_in_pipe)
    bias = float((scan.spec or {}).get("bias", 0.0)) if range_bias is None else float(range_bias)
    if not math.isfinite(bias):
        bias = 0.0
    diag: dict[str, Any] = {"method": "improved", "n_points": int(scan.n_valid)}
    # (the given pose, its points, the radius and the wall's extent the pose was chosen on)
    recheck: tuple[SensorInPipe, NDArray[np.float64], float, float] | None = None
    try:
        cloud = _prepare(scan, pose0, bias, config)
        reach = _blocked_within_min_range(scan, cloud, big_r)
        if reach is not None:
            diag["blocked_within_min_range"] = reach
            opt = StructureOption("closure", reach, 0.0, 0.0, 0.0, BLIND_CONFIDENCE)
            return _timed(Detection("closure", [opt], BLIND_CONFIDENCE, diag), t0)
        # the given pose and the clamp reading explain every return already: straight pipe,
        # nothing to measure or refine (the common case, kept cheap)
        if refine_axis:
            diag["axis_pass"] = 0
            straight = _intact(cloud, big_r, config, diag)
            if straight is not None:
                return _timed(_with_ring_holes(cloud, big_r, straight), t0)
        # the clamp's encoders read the diameter to a millimetre or two: the wall right around
        # the sensor (nearer than any structure in view) measures it first, the wall before
        # the structure again once the axis is refined
        u_nearest = _pct(cloud.xyz_v[0], 1.0)
        r_clamped = big_r
        big_r = _wall_radius(cloud, big_r, config, u_nearest + NEAR_WALL, diag)
        if refine_axis:
            if big_r != r_clamped:  # (straight pipe after all, at its measured radius?)
                straight = _intact(cloud, big_r, config, diag)
                if straight is not None:
                    return _timed(_with_ring_holes(cloud, big_r, straight), t0)
            diag.pop("axis_pass")
            candidates = [(pose0, {})]
            passes = [0]  # the pass each candidate pose comes from
            xyz_of = [cloud.xyz_v]
            u_start0 = _structure_start(cloud, big_r, config)
            moved = False
            first_pass = not _wall_consistent(cloud, big_r, config, u_start0)
            diag["axis_first_pass"] = first_pass
            if not first_pass:
                # the given pose explains the wall before the structure: only the second
                # pass (from that pose) refines it
                u_start = u_start0
            else:
                pose1, info1 = _refine_axis(cloud, big_r, config)
                candidates.append((pose1, info1))
                passes.append(1)
                cloud.set_pose(pose1)
                xyz_of.append(cloud.xyz_v)
                diag.update(info1)
                diag["axis_pass"] = 1
                straight = _intact(cloud, big_r, config, diag)
                if straight is not None:  # no return off the wall under the refined axis
                    return _timed(_with_ring_holes(cloud, big_r, straight), t0)
                for key in info1:
                    diag.pop(key)
                diag.pop("axis_pass")
                u_start = _structure_start(cloud, big_r, config)
                moved = _pose_moved(pose0, pose1, big_r)
            # does the given pose explain the wall before the structure (seen under it, within
            # the tolerance that found the structure's start)?
            n_ok, n_seen, _, _ = _wall_count(cloud, big_r, config, pose0, u_start0, tol_scale=2.0)
            given_fits = n_seen >= 40 and n_ok >= 0.9 * n_seen
            # second pass: all of the intact wall before the structure (not a thin ring of it
            # right before the structure when the given pose explains the wall: where a wide
            # arc starts, already curving, the ring pulls the axis off)
            pose2, info2 = _refine_axis(cloud, big_r, config, u_max=u_start)
            thin_ring = info2.get("axis_span", 1.0) < 0.02
            if info2.get("axis_points", 0) >= 40 and not (thin_ring and given_fits):
                info2["axis_wall_until"] = u_start
                candidates.append((pose2, info2))
                passes.append(2)
            # keep the pose that explains the most wall returns before the structure (a fit
            # pulled by the structure's own returns, e.g. tilted onto one side of a taper,
            # explains fewer of them)
            cloud.restore(pose0, xyz_of[0])
            u_near = min(u_start, u_start0) if moved else u_start
            counts = [_wall_count(cloud, big_r, config, p, u_near) for p, _ in candidates]
            scores = [c[0] for c in counts]
            # a refinement whose cylinder misses its own wall returns by several times their
            # noise fitted a curved wall (the arc of a wide bend filling the whole view): the
            # given pose stands when it explains the wall
            rms_cap = _straight_wall_rms(cloud)
            for k, (_, inf) in enumerate(candidates):
                if k and given_fits and inf.get("axis_rms", 0.0) > rms_cap:
                    scores[k] = -1
            # (of the poses explaining as many returns, the one that fits them most closely:
            # a cylinder tilted onto the start of a gentle taper explains no more of them, within
            # the tolerance, but fits them more loosely)
            tied = [k for k, sc in enumerate(scores) if sc == max(scores)]
            best = min(tied, key=lambda k: (counts[k][2], -k))
            if (
                best
                and u_start0 < u_nearest + NO_WALL_VIEW
                and scores[best] <= scores[0] + max(GIVEN_POSE_MARGIN * scores[0], 10)
            ):
                # no wall in view before the structure (the stem of a tee ending before the
                # nearest returns): a refinement that explains hardly more returns than the
                # given pose (a few of thousands) rests on the structure
                best = 0
            if best and given_fits and u_start0 - u_nearest < SHORT_WALL_VIEW:
                # hardly any straight wall in view before the structure: a refinement can only
                # lean on the structure (a cylinder tilted about the nearest wall, pivoting
                # onto the arc of a turn); the given pose stands, as it explains that wall,
                # unless a refinement explains as many returns and fits a long straight wall
                # to a fraction of its noise (then the given pose is the misaligned one, its
                # wall drifting off the tolerance some way ahead)
                long_straight = [
                    k
                    for k, sc in enumerate(scores)
                    if k
                    and sc >= scores[best] - max(GIVEN_POSE_MARGIN * scores[best], 2)
                    and candidates[k][1].get("axis_span", 0.0) >= LONG_WALL_SPAN
                    and candidates[k][1].get("axis_rms", 1.0) <= LONG_WALL_RMS * rms_cap
                ]
                best = long_straight[-1] if long_straight else 0
            pose, info = candidates[best]
            diag.update(info)
            diag["axis_pass"] = passes[best]
            if best < len(xyz_of):
                cloud.restore(pose, xyz_of[best])
            else:
                cloud.set_pose(pose)
            recheck = (pose0, xyz_of[0], big_r, u_near)
            big_r = _wall_radius(cloud, big_r, config, u_near, diag)
            # a noiseless wall fitted closely: the tolerance floor shrinks towards its scatter
            # (under the given pose, the wall returns' own scatter about it)
            rms = diag.get("wall_radius_rms", info.get("axis_rms", counts[best][3]))
            if rms is not None and float(_pct(cloud.sigma_v, 90.0)) < 0.0005:
                cloud.floor = _scatter_floor(config, rms)
                diag["tolerance_floor"] = cloud.floor
        # (what the pose and radius left in the diagnostics, for a fit again under a new pose)
        diag_pose = dict(diag) if recheck is not None else diag
        det = _detect_in_pipe_frame(cloud, big_r, config, diag)
        if recheck is not None:
            redone = _start_recheck(cloud, det, config, diag_pose, *recheck)
            if redone is not None:
                big_r, det = redone
            redone = _torus_pose_check(cloud, det, config, diag_pose, *recheck)
            if redone is not None:
                big_r, det = redone
        det = _with_ring_holes(cloud, big_r, det, config)
    except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:  # never crash/NaN
        diag["error"] = f"{type(exc).__name__}: {exc}"
        det = Detection.straight(confidence=0.0, **diag)
    return _timed(det, t0)


def _wall_radius(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, u_max: float, diag: dict[str, Any]
) -> float:
    """The pipe radius (m) the wall returns before ``u_max`` give under the current pose: their
    median distance from the axis, when at least 100 returns within ``max_radius_correction``
    (plus their tolerance) of the clamped radius ``big_r`` cover most of the circumference;
    ``big_r`` otherwise, and when they scatter about it by more than their noise explains (a
    curved wall: no straight pipe in view). Records ``wall_radius`` and the returns' scatter
    about it (``wall_radius_rms``, 1.4826 MAD, m) in ``diag``. Corrections below
    ``RADIUS_DEAD_BAND`` are not made (the clamp reading is as good as the fit there)."""
    xyz = cloud.xyz_v
    e = cloud.r_v - big_r
    sel = (xyz[0] < u_max) & (np.abs(e) <= cfg.max_radius_correction + _tolerance_v(cloud, cfg))
    n = int(np.count_nonzero(sel))
    if n < 100:
        return big_r
    e_sel = e[sel]
    de = float(np.median(e_sel))
    if not RADIUS_DEAD_BAND <= abs(de) <= cfg.max_radius_correction:
        return big_r
    if not _covers(xyz, np.flatnonzero(sel), 0.75):
        return big_r
    spread = float(mad_sigma(e_sel - de))
    if spread > _straight_wall_rms(cloud):  # not a straight wall about this axis
        return big_r
    diag["wall_radius"] = big_r + de
    diag["wall_radius_rms"] = spread
    return big_r + de


def _straight_wall_rms(cloud: PipeCloud) -> float:
    """Largest scatter (m) of wall returns about a straight cylinder that the returns' own
    noise explains: 4 x their median radial noise, at least 0.6 mm."""
    return max(4.0 * float(_pct(cloud.sigma_v, 50.0)), 0.0006)


def _wall_consistent(cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, u_max: float) -> bool:
    """Do at least 200 returns lie before ``u_max`` (at least 15 cm) along the axis, all but
    1 % of them within the wall tolerance under the current pose?"""
    if u_max < 0.15:  # (a short stretch of wall: the first pass's wider view helps)
        return False
    near = cloud.xyz_v[0] < u_max
    n_near = int(np.count_nonzero(near))
    if n_near < 200:
        return False
    e = cloud.r_v - big_r
    n_off = int(np.count_nonzero(near & (np.abs(e) > _tolerance_v(cloud, cfg))))
    return n_off <= 0.01 * n_near


def _with_ring_holes(
    cloud: PipeCloud, big_r: float, det: Detection, cfg: ImprovedConfig = DEFAULT_CONFIG
) -> Detection:
    """``det``, or a junction when one ring of beams enters side holes in the run's wall
    nearer than the structure found (more than a diameter before it and before the first
    returns off the wall, e.g. where a wide arc starts curving), or at the place of a junction
    whose branch fit the returns hardly support: a branch seen far away in a small pipe,
    between rings of beams (:mod:`detector.grazing`). Each branch leaves at the standard
    fitting angle (90, 45 or 135 deg) whose far side fits the bump best; the run goes on past
    them (the rings beyond lie on its wall)."""
    # (cheap tests first: too few returns beyond the wall at all, or nearer than the limit)
    beyond = cloud.r_v - big_r > np.maximum(0.00035, 4.0 * cloud.sigma_v)
    if np.count_nonzero(beyond) < 6:
        return det
    support = det.diagnostics.get("fit_support")
    weak = (
        det.kind == "junction"
        and support is not None
        and support < max(30, 0.5 * det.diagnostics.get("fit_points", 0))
    )
    if weak:
        # a junction whose branches the returns through its openings hardly support (most of
        # them outliers of the fit): the holes at its place, if a ring shows them, place it
        # (within two diameters of its place; the far sides lie up to a diameter farther on)
        before = det.distance + 4.0 * big_r
        beyond &= cloud.xyz_v[0] < before + 2.0 * big_r
        if np.count_nonzero(beyond) < 6:
            return det
    elif det.options:
        before = det.distance - 2.0 * big_r
        beyond &= cloud.xyz_v[0] < before
        if np.count_nonzero(beyond) < 6:
            return det
        before = min(before, _structure_start(cloud, big_r, cfg) - 2.0 * big_r)
        beyond &= cloud.xyz_v[0] < before
        if np.count_nonzero(beyond) < 6:
            return det
    else:
        before = float(np.max(cloud.xyz_v[0]))
    # the bumps are a fraction of a millimetre: only under a pose that fits the wall before
    # them that closely (a sensor millimetres off the axis, not refined away, bends every ring)
    near = cloud.xyz_v[0] < before
    e_near = (cloud.r_v - big_r)[near]
    if e_near.size < 50 or mad_sigma(e_near) > max(0.0003, 3.0 * _pct(cloud.sigma_v[near], 50.0)):
        return det
    # only the rings that hold such returns, and their neighbours
    cols = cloud.cell[beyond] % cloud.shape[1]
    c0, c1 = max(int(cols.min()) - 1, 0), min(int(cols.max()) + 2, cloud.shape[1])
    holes = find_ring_holes(
        cloud.xyz[:, :, c0:c1],
        cloud.valid[:, c0:c1],
        cloud.sigma_r[:, c0:c1],
        cloud.wraps,
        big_r,
        before,
        cloud.beam_step,
    )
    if not holes or (weak and len(holes) < sum(not o.is_straight_on for o in det.options)):
        return det  # (nothing, or fewer ways than the openings the fit had to explain)
    places = np.array([h.position for h in holes])
    position = float(np.mean(places))
    if float(np.ptp(places)) > big_r or (weak and abs(position - det.distance) > 3.0 * big_r):
        # the branches of one junction leave the run at one place, and the openings the fit
        # explained poorly are still the openings of that junction
        return det
    conf = min(_confidence(h.n, h.rms, 0.001) for h in holes)
    options = [StructureOption("junction", position, 2.0 * big_r, 0.0, 0.0, conf)]
    for h in holes:
        angle, direction = option_direction(_dir(h.angle, h.roll), cloud.pose)
        options.append(
            StructureOption("junction", h.position, 2.0 * h.radius, direction, angle, conf)
        )
    options.sort(key=option_order)
    diag = dict(det.diagnostics)
    diag.update(
        model="ring holes",
        ring_holes=[
            {
                "position": h.position,
                "radius": h.radius,
                "roll": h.roll,
                "angle": h.angle,
                "n": h.n,
                "rms": h.rms,
            }
            for h in holes
        ],
        replaced_kind=det.kind,
    )
    return Detection("junction", options, conf, diag)


def _timed(det: Detection, t0: float) -> Detection:
    """``det`` with the time since ``t0`` (seconds) in its diagnostics (a finite number added
    to the detection's own dictionary: nothing to check again)."""
    det.diagnostics["time_s"] = time.perf_counter() - t0
    return det


def _pose_moved(a: SensorInPipe, b: SensorInPipe, big_r: float) -> bool:
    """Do two poses differ by more than 2 % of the radius across or 0.2 deg in tilt?"""
    lateral = float(np.abs(a.position[1:] - b.position[1:]).max())
    tilt = float(np.abs(a.rotation[0] - b.rotation[0]).max())
    return lateral > 0.02 * big_r or tilt > math.radians(0.2)


def _scatter_floor(cfg: ImprovedConfig, rms: float) -> float:
    """Tolerance floor (m) for a noiseless wall fitted to ``rms`` (m): six times that
    scatter, from 0.8 mm up to the configured floor."""
    return min(cfg.tol_floor, max(0.0008, 6.0 * float(rms)))


def _thinned(
    cloud: PipeCloud, cfg: ImprovedConfig
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Every third valid return (sensor frame, ``(3, n)``) and its wall tolerance (m),
    computed once per cloud: enough to compare poses by."""
    if cloud.thin is None:
        cloud.thin = (
            np.ascontiguousarray(cloud.sensor_v[:, ::3]),
            cfg.tol_floor + cfg.noise_k * cloud.sigma_v[::3],
        )
    return cloud.thin


def _wall_count(
    cloud: PipeCloud,
    big_r: float,
    cfg: ImprovedConfig,
    pose: SensorInPipe,
    u_max: float,
    tol_scale: float = 1.0,
) -> tuple[int, int, float, float]:
    """Returns within ``tol_scale`` x the wall tolerance of the radius ``big_r`` under ``pose``,
    counting those nearer than ``u_max`` along the axis (all of them when fewer than 40 are),
    how many returns were counted (every third return), their truncated quadratic cost (the
    sum of ``min((e / tol)^2, 1)`` over them, ``e`` the distance from the wall, ``tol`` the
    tolerance: a return off the wall costs 1, one on it costs how far in the tolerance it
    lies), and the rms distance from the wall of those within the tolerance (m)."""
    sp, tol = _thinned(cloud, cfg)
    pts = _transform(pose, sp)
    e = np.sqrt(np.square(pts[1]) + np.square(pts[2])) - big_r
    near = pts[0] < u_max
    n_near = int(np.count_nonzero(near))
    if n_near < 40:
        near[:] = True
        n_near = int(near.size)
    return _wall_fit(e[near], tol_scale * tol[near], n_near)


def _wall_fit(
    e: NDArray[np.float64], tol: NDArray[np.float64], n: int
) -> tuple[int, int, float, float]:
    """``(n_ok, n, cost, rms)`` of returns ``e`` off the wall (m) with tolerances ``tol``
    (m): how many lie within their tolerance, ``n`` (passed through), the truncated quadratic
    cost ``sum min((e / tol)^2, 1)``, and the rms of ``e`` over those within (m)."""
    q = np.square(e / tol)
    ok = q <= 1.0
    n_ok = int(np.count_nonzero(ok))
    rms = math.sqrt(float(np.mean(np.square(e[ok])))) if n_ok else math.inf
    return n_ok, n, float(np.minimum(q, 1.0).sum()), rms


def _common_wall_fit(
    cloud: PipeCloud,
    big_r: float,
    cfg: ImprovedConfig,
    poses: list[SensorInPipe],
    u_max: float,
) -> list[tuple[int, int, float, float]]:
    """For each pose, what :func:`_wall_count` gives, over one set of returns for all: those
    nearer than ``u_max`` along the axis under every pose (a tilted pose would otherwise count
    returns the others leave out). Empty when fewer than 40 returns are in that set."""
    sp, tol = _thinned(cloud, cfg)
    pts = [_transform(p, sp) for p in poses]
    near = np.logical_and.reduce([q[0] < u_max for q in pts])
    n_near = int(np.count_nonzero(near))
    if n_near < 40:
        return []
    return [
        _wall_fit(np.sqrt(np.square(q[1][near]) + np.square(q[2][near])) - big_r, tol[near], n_near)
        for q in pts
    ]


def _gentle_start(det: Detection) -> float | None:
    """Where a structure that leaves the wall gradually starts, m along the axis: a long
    bend's arc (``bend_radius x tan(angle / 2)`` before its reference point), a reducer's
    taper; ``None`` for the others (their walls break off)."""
    if det.kind == "reducer" and det.options:
        return det.options[0].distance
    if det.kind == "bend" and len(det.options) == 1 and det.options[0].bend_radius > 0.0:
        opt = det.options[0]
        return opt.distance - opt.bend_radius * math.tan(0.5 * opt.angle)
    return None


def _start_recheck(
    cloud: PipeCloud,
    det: Detection,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    pose0: SensorInPipe,
    xyz0: NDArray[np.float64],
    big_r: float,
    wall_until: float,
) -> tuple[float, Detection] | None:
    """A long-radius bend's arc, or a gentle taper, leaves the straight wall so slowly that its
    first centimetres lie within the wall tolerance: the pose was chosen on wall returns up to
    ``wall_until`` (m along the axis), past where the fitted arc or taper starts, and an axis
    refined on them leans onto it (1-2 deg). Choose again on the wall before that start (the
    given pose, the chosen one, or the axis refined there): the most returns within the
    tolerance, then the closest fit. ``(radius, detection)`` under the new pose when it moved
    and the structure kept its kind, else ``None`` (the cloud keeps its pose)."""
    start = _gentle_start(det)
    if start is None or (det.kind == "reducer" and cloud.floor is None):
        # (a reducer under range noise: its tolerance is the noise's, and a pose chosen again
        # on less wall sizes the wider pipe no better)
        return None
    u_cap = start - GENTLE_START_MARGIN
    if u_cap >= wall_until:
        return None
    chosen, xyz_chosen = cloud.pose, cloud.xyz_v
    floor = cloud.floor
    refined, info = _refine_axis(cloud, big_r, cfg, u_max=u_cap)
    poses = [chosen, pose0] + ([refined] if info.get("axis_points", 0) >= 40 else [])
    fits = _common_wall_fit(cloud, big_r, cfg, poses, u_cap)
    if not fits:  # (too little wall before the arc to choose on)
        return None
    best = max(range(len(poses)), key=lambda k: (fits[k][0], -fits[k][2]))
    if best == 0 or not _pose_moved(chosen, poses[best], big_r):
        return None
    if best == 1:
        cloud.restore(pose0, xyz0)
        axis_info: dict[str, Any] = {"axis_pass": 0}
    else:
        cloud.set_pose(refined)
        axis_info = {**info, "axis_pass": 3, "axis_wall_until": u_cap}
    skip = ("axis_", "wall_radius", "tolerance_floor")
    sub = {k: v for k, v in diag_pose.items() if not k.startswith(skip)}
    sub.update(axis_info)
    radius = _wall_radius(cloud, big_r, cfg, u_cap, sub)
    if floor is not None:
        cloud.floor = _scatter_floor(cfg, sub.get("wall_radius_rms", fits[best][3]))
        sub["tolerance_floor"] = cloud.floor
    redone = _detect_in_pipe_frame(cloud, radius, cfg, sub)
    if redone.kind != det.kind:  # (the structure stands; so does the pose it was found under)
        cloud.restore(chosen, xyz_chosen)
        cloud.floor = floor
        return None
    redone.diagnostics["start_recheck"] = True
    return radius, redone


def _torus_pose_check(
    cloud: PipeCloud,
    det: Detection,
    cfg: ImprovedConfig,
    diag_pose: dict[str, Any],
    pose0: SensorInPipe,
    xyz0: NDArray[np.float64],
    big_r: float,
    wall_until: float,
) -> tuple[float, Detection] | None:
    """A long-radius bend whose arc starts a few centimetres ahead fills the view with curved
    wall: an axis refined on the nearest wall-like returns is a cylinder laid into the arc's
    start (up to 2 cm off centre), and the torus fitted under it misses its returns by a
    millimetre where the right pose leaves a tenth of that. When the pose moved from the given
    one and the bend's torus fits the returns under the given pose at most ``TORUS_POSE_RATIO``
    times as loosely (rms), the given pose and its detection stand. ``(radius, detection)``
    then, else ``None`` (the cloud keeps its pose)."""
    rms = det.diagnostics.get("torus_rms")
    if det.kind != "bend" or det.diagnostics.get("model") != "torus" or rms is None:
        return None
    chosen, xyz_chosen, floor = cloud.pose, cloud.xyz_v, cloud.floor
    if not _pose_moved(chosen, pose0, big_r):
        return None
    cloud.restore(pose0, xyz0)
    skip = ("axis_", "wall_radius", "tolerance_floor")
    sub = {k: v for k, v in diag_pose.items() if not k.startswith(skip)}
    sub["axis_pass"] = 0
    radius = _wall_radius(cloud, big_r, cfg, wall_until, sub)
    if floor is not None:
        n_ok, _, _, wall_rms = _wall_count(cloud, radius, cfg, pose0, wall_until)
        if n_ok:
            cloud.floor = _scatter_floor(cfg, sub.get("wall_radius_rms", wall_rms))
            sub["tolerance_floor"] = cloud.floor
    redone = _detect_in_pipe_frame(cloud, radius, cfg, sub)
    rms0 = redone.diagnostics.get("torus_rms")
    if (
        redone.kind == det.kind
        and redone.diagnostics.get("model") == "torus"
        and rms0 is not None
        and rms0 * TORUS_POSE_RATIO <= rms
    ):
        redone.diagnostics["torus_pose_check"] = {"chosen_rms": rms, "given_rms": rms0}
        return radius, redone
    cloud.restore(chosen, xyz_chosen)
    cloud.floor = floor
    return None


def _tolerance(cloud: PipeCloud, cfg: ImprovedConfig) -> NDArray[np.float64]:
    """(G, K) radial tolerance of each return: floor, sensor noise and residual axis error."""
    floor = cfg.tol_floor if cloud.floor is None else cloud.floor
    return floor + cfg.noise_k * cloud.sigma_r + cfg.axis_slope * np.abs(cloud.xyz[0])


def _tolerance_v(cloud: PipeCloud, cfg: ImprovedConfig) -> NDArray[np.float64]:
    """(N,) radial tolerance of each return (compact order) under the current pose."""
    if cloud.tol0 is None:
        cloud.tol0 = cfg.tol_floor + cfg.noise_k * cloud.sigma_v
    if cloud._tol_v is None:
        cloud._tol_v = cloud.tol0 + cfg.axis_slope * np.abs(cloud.xyz_v[0])
    return cloud._tol_v


def _intact(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, diag: dict[str, Any]
) -> Detection | None:
    """Straight pipe when fewer than ``min_anomaly_points`` returns leave the wall tolerance
    (no region of anomalies can reach that size, so the classification would find nothing
    else); ``None`` otherwise."""
    e = cloud.r_v - big_r
    tol = _tolerance_v(cloud, cfg)
    if cloud.n < cfg.min_anomaly_points or np.count_nonzero(np.abs(e) > tol) >= (
        cfg.min_anomaly_points
    ):
        return None
    n_beyond = int(np.count_nonzero(e > tol))
    n_inside = int(np.count_nonzero(e < -tol))
    n_wall = cloud.n - n_beyond - n_inside
    diag["pipe_axis_sensor"] = [float(v) for v in cloud.pose.rotation[0]]
    diag["sensor_offset_pipe"] = [float(v) for v in cloud.pose.position[1:]]
    diag.update(n_wall=n_wall, n_beyond=n_beyond, n_inside=n_inside, n_anomaly=0)
    conf = min(1.0, n_wall / 200.0) * n_wall / cloud.n
    return Detection.straight(confidence=conf, **diag)


def _blocked_within_min_range(scan: Scan, cloud: PipeCloud, big_r: float) -> float | None:
    """How far ahead (m) at most an end wall blocks the pipe within the sensor's minimum range,
    when hardly any return comes from ahead of the sensor although a straight pipe would show
    its wall to many beams there; ``None`` otherwise.

    Ahead of a sensor on the axis of a straight pipe of radius ``R``, a beam at angle ``beta``
    to the axis meets the wall at range ``R / sin(beta)``: beams whose range would lie within
    ``[min_range, max_range]`` return. A bend, a junction or a reducer near the sensor still
    sends beams on into the pipe beyond it; nothing ahead at all is an end wall nearer than
    ``sqrt(min_range^2 - R^2)``, where the wall ahead would start to show. That reach is
    returned: the end wall is no farther, its distance is not measured."""
    spec = scan.spec or {}
    min_range = float(spec.get("min_range", 0.0))
    max_range = float(spec.get("max_range", math.inf))
    if not (math.isfinite(min_range) and min_range > big_r):
        return None
    n_ahead = int(np.count_nonzero(cloud.xyz_v[0] > 0.0))
    if n_ahead > BLIND_MAX_AHEAD * scan.ranges.size:  # (more than any expected count allows)
        return None
    sb = np.abs(np.sin(scan.beam_angles))
    ahead = np.cos(scan.beam_angles) > 0.0
    with np.errstate(divide="ignore"):
        wall_range = big_r / sb
    seen = ahead & (wall_range >= min_range) & (wall_range <= max_range)
    expected = int(np.count_nonzero(seen)) * scan.n_planes
    if expected < BLIND_MIN_EXPECTED:
        return None
    if n_ahead > BLIND_MAX_AHEAD * expected:
        return None
    return math.sqrt(min_range * min_range - big_r * big_r)


def _structure_start(cloud: PipeCloud, big_r: float, cfg: ImprovedConfig) -> float:
    """Axial position where the wall stops being intact (first significant anomalies); the
    horizon when there are none."""
    xyz = cloud.xyz_v
    r = cloud.r_v
    tol = _tolerance_v(cloud, cfg)
    idx = np.flatnonzero(np.abs(r - big_r) > 2.0 * tol)  # returns off the wall
    if idx.size < cfg.min_anomaly_points:
        return cfg.horizon
    g, k = cloud.shape
    mask = np.zeros(g * k, dtype=bool)
    cells = cloud.cell[idx]
    mask[cells] = True
    labels, n_lab = label_regions(mask.reshape(g, k), cloud.wraps)
    lab = labels.reshape(-1)[cells]
    counts = np.bincount(lab, minlength=n_lab + 1)
    good = counts >= cfg.min_anomaly_points
    good[0] = False
    sel = idx[good[lab]]
    if not sel.size:
        return cfg.horizon
    u = xyz[0][sel]
    # where the beams of those returns crossed the wall radius (sensor near the axis)
    uc = u * big_r / np.maximum(r[sel], 1e-9)
    return float(_pct(np.minimum(u, uc), 1)) - 0.005


def _detect_in_pipe_frame(
    cloud: PipeCloud, big_r: float, cfg: ImprovedConfig, diag: dict[str, Any]
) -> Detection:
    valid = cloud.valid
    diag["pipe_axis_sensor"] = [float(v) for v in cloud.pose.rotation[0]]
    diag["sensor_offset_pipe"] = [float(v) for v in cloud.pose.position[1:]]
    r = np.sqrt(np.square(cloud.xyz[1]) + np.square(cloud.xyz[2]))
    # residual axis error grows with the distance along the axis
    tol = _tolerance(cloud, cfg)
    e = np.where(valid, r - big_r, 0.0)
    # (a lowered floor serves the openings only: returns beyond the wall)
    tol_in = tol if cloud.floor is None else tol + (cfg.tol_floor - cloud.floor)
    wall = valid & (e <= tol) & (e >= -tol_in)
    beyond = valid & (e > tol)
    inside = valid & (e < -tol_in)
    n_valid = int(valid.sum())
    diag.update(n_wall=int(wall.sum()), n_beyond=int(beyond.sum()), n_inside=int(inside.sum()))
    if n_valid < cfg.min_anomaly_points:
        diag["reason"] = "too few returns"
        return Detection.straight(confidence=0.0, **diag)
    # significant anomaly regions
    anomaly = beyond | inside
    labels, n_lab = label_regions(anomaly, cloud.wraps)
    keep = np.zeros_like(anomaly)
    if n_lab:
        counts, row_span = _region_stats(labels, n_lab)
        good = (counts >= cfg.min_anomaly_points) & (row_span >= cfg.min_region_rows)
        good[0] = False
        keep = good[labels] & anomaly
    n_keep = int(keep.sum())
    diag["n_anomaly"] = n_keep
    wall_frac = float(wall.sum()) / max(n_valid, 1)
    if n_keep < cfg.min_anomaly_points:
        conf = min(1.0, float(wall.sum()) / 200.0) * wall_frac
        return Detection.straight(confidence=conf, **diag)
    beyond_k = beyond & keep
    inside_k = inside & keep
    # regions with no inside returns keep their labels among the returns beyond the wall
    pre = None
    if n_lab:
        mixed = np.zeros(n_lab + 1, dtype=bool)
        mixed[labels[inside_k]] = True
        if not mixed[labels[beyond_k]].any():
            pre = (np.where(beyond_k, labels, 0), n_lab)
    lobes = _find_lobes(cloud, beyond_k, big_r, cfg, pre)
    diag["n_lobes"] = len(lobes)
    if lobes:
        # an expansion: returns beyond the wall all around and hardly any inside
        p_beyond = cloud.points(beyond_k)
        cov = _azimuth_coverage(p_beyond)
        uniform = _azimuth_uniformity(p_beyond)
        diag.update(beyond_coverage=cov, beyond_uniformity=uniform)
        # (inside returns count only near the start of the widening: an end wall far down
        # the wider pipe is not part of the structure)
        u_grid = cloud.xyz[0]
        u_start = _pct(u_grid[beyond_k], 5.0)
        inside_near = inside_k & (u_grid <= u_start + 4.0 * big_r)
        if uniform >= 0.3 and inside_near.sum() < 0.3 * beyond_k.sum():
            return _axisymmetric(cloud, big_r, inside_near, beyond_k, wall, tol, cfg, diag)
        return _branches(cloud, big_r, lobes, keep, wall, tol, cfg, diag)
    det = _axisymmetric(cloud, big_r, inside_k, beyond_k, wall, tol, cfg, diag)
    if det.diagnostics.get("axisymmetric_support", 1.0) >= 0.6:
        return det
    # neither an end wall nor a reducer: the far wall of a turn seen head-on (small pipes, far
    # away): fit an outgoing pipe to the inner returns with unknown roll
    pseudo = Lobe(inside_k, 0.0, int(inside_k.sum()))
    alt = _branches(cloud, big_r, [pseudo], keep, wall, tol, cfg, dict(diag), any_roll=True)
    if det.diagnostics.get("closure_tentative", False):
        # a wall that looks flat within the range noise but curves: the far wall of a turn
        # when the fit finds one way on; a pipe across (or a 90 deg turn: the same far wall)
        # is too ambiguous to overrule the end wall
        undetermined = alt.diagnostics.get("reason") == "far wall: way on undetermined"
        if undetermined or alt.kind == "junction":
            det.diagnostics["far_wall_way_undetermined"] = True
        return alt if alt.kind == "bend" else det
    if alt.kind != "straight" and alt.confidence > det.confidence:
        return alt
    return det


# --------------------------------------------------------------------------- lobes
@dataclass
class Lobe:
    mask: NDArray[np.bool_]
    roll: float
    n: int


def _find_lobes(
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
    counts, row_span = _region_stats(labels, n_lab)
    cand = np.flatnonzero((counts >= cfg.min_lobe_points) & (row_span >= cfg.min_region_rows))
    regions = [(labels == k, int(counts[k])) for k in cand[cand > 0].tolist()]
    regions = [part for m, n in regions for part in _split_all_round(cloud, m, n, big_r, cfg)]
    for m, n in regions:
        p = cloud.points(m)
        depth = float(_pct(np.sqrt(np.square(p[:, 1]) + np.square(p[:, 2])), 90)) - big_r
        floor = cfg.tol_floor if cloud.floor is None else cloud.floor
        if depth < max(3.0 * floor, 0.1 * big_r):
            continue  # a shallow sliver (seam leaks, noise), not an opening
        roll = math.atan2(float(p[:, 2].sum()), float(p[:, 1].sum()))
        lobes.append(Lobe(m, roll, n))
    # merge lobes within 45 deg of roll (an opening split by dropouts)
    lobes.sort(key=lambda lb: -lb.n)
    merged: list[Lobe] = []
    for lb in lobes:
        for mg in merged:
            if abs(_wrap(lb.roll - mg.roll)) < math.radians(45.0):
                mg.mask = mg.mask | lb.mask
                p = cloud.points(mg.mask)
                mg.roll = math.atan2(float(p[:, 2].sum()), float(p[:, 1].sum()))
                mg.n += lb.n
                break
        else:
            merged.append(Lobe(lb.mask.copy(), lb.roll, lb.n))
    # a lobe must be a real opening, not a sliver: compare with the largest
    if merged:
        biggest = max(m.n for m in merged)
        merged = [m for m in merged if m.n >= max(cfg.min_lobe_points, 0.05 * biggest)]
    return merged


def _split_all_round(
    cloud: PipeCloud, mask: NDArray[np.bool_], n: int, big_r: float, cfg: ImprovedConfig
) -> list[tuple[NDArray[np.bool_], int]]:
    """A region of returns beyond the wall that goes all round the axis, split into its deep
    parts when there are two or more: entering a wider run from a tee's stem, the run's wall
    lies a step beyond the stem's all round and joins the two ways on into one region; only
    along the run do the returns reach deep (beyond half the region's 90th-percentile depth).
    Otherwise the region as it is (``(mask, n)``)."""
    p = cloud.points(mask)
    if _azimuth_coverage(p) < ALL_ROUND:
        return [(mask, n)]
    depth = np.hypot(cloud.xyz[1][mask], cloud.xyz[2][mask]) - big_r
    deep = np.zeros_like(mask)
    deep[mask] = depth > 0.5 * float(_pct(depth, 90.0))
    labels, n_lab = label_regions(deep, cloud.wraps)
    if n_lab < 2:
        return [(mask, n)]
    counts, row_span = _region_stats(labels, n_lab)
    parts = np.flatnonzero((counts >= cfg.min_lobe_points) & (row_span >= cfg.min_region_rows))
    parts = parts[parts > 0]
    if parts.size < 2:
        return [(mask, n)]
    return [(labels == k, int(counts[k])) for k in parts.tolist()]


def _region_stats(labels: NDArray[np.int32], n_lab: int) -> tuple[NDArray, NDArray]:
    """(cells, grid rows spanned) of each label 0..n_lab of a labelled grid."""
    flat = labels.reshape(-1)
    nz = np.flatnonzero(flat)
    lab = flat[nz]
    counts = np.bincount(lab, minlength=n_lab + 1)
    occupied = np.zeros((n_lab + 1, labels.shape[0]), dtype=bool)
    occupied[lab, nz // labels.shape[1]] = True
    return counts, np.count_nonzero(occupied, axis=1)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


# --------------------------------------------------------------------------- axisymmetric
def _axisymmetric(
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
    contraction = bool(inside.sum() >= beyond.sum())
    anomaly = inside if contraction else beyond
    if anomaly.sum() < cfg.min_anomaly_points:
        return Detection.straight(confidence=0.3, **diag)
    p = cloud.points(anomaly)
    u = p[:, 0]
    r = np.sqrt(np.square(p[:, 1]) + np.square(p[:, 2]))
    tol_med = float(_pct(tol[anomaly], 50.0))
    # --- closure: a plane perpendicular to the axis, seen down to the centre
    if contraction:
        u_med = float(_pct(u, 50.0))
        tol_u = 0.003 + 2.0 * tol_med
        on_plane = np.abs(u - u_med) <= tol_u
        frac_plane = float(on_plane.mean())
        diag["closure_plane_fraction"] = frac_plane
        if np.count_nonzero(on_plane) >= cfg.min_anomaly_points:
            up = u[on_plane]
            dist = float(np.mean(up))
            spread = float(np.std(up))
            cov = _azimuth_coverage(p[on_plane])
            # a cap is flat: a plane (tilted by any residual axis error) must explain it to
            # within the range noise, where the far wall of a pipe seen head-on is curved
            # (an even sample of the wall: a few hundred returns pin a plane and a quadric)
            on_idx = np.flatnonzero(on_plane)
            pick = on_idx[_subsample(np.arange(on_idx.size), 2 * cfg.fit_points)]
            pp = p[pick]
            uq = pp[:, 0]
            design = np.stack([np.ones(uq.size), pp[:, 1], pp[:, 2]], axis=1)
            coef = np.linalg.lstsq(design, uq, rcond=None)[0]
            plane_rms = float(np.sqrt(np.mean((uq - design @ coef) ** 2)))
            noise_u = float(_pct(cloud.values(anomaly, cloud.sigma_range_v)[pick], 50.0))
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
            plane_seen = frac_plane >= 0.8 and float(_pct(r[on_plane], 5)) < 0.5 * big_r
            if not plane_seen:  # (not a cap seen head-on: only a clear curvature counts)
                diag["closure_curved"] = curved
            if plane_seen and spread <= 0.5 * tol_u and flat_plane:
                conf = _confidence(int(on_plane.sum()), spread, tol_u) * (0.5 + 0.5 * cov)
                opt = StructureOption("closure", dist, 0.0, 0.0, 0.0, conf)
                # (curved only by the quadratic test: an end wall unless the returns show a
                # turn; the caller decides)
                diag["closure_tentative"] = not flat
                return Detection("closure", [opt], conf, diag)
    # --- reducer: r(u) = R + (R2 - R) clip((u - L) / T, 0, 1)
    if contraction:
        u_cross = u
    else:
        u_cross = u * big_r / np.maximum(r, 1e-9)  # where the beams crossed the wall radius
    u_first = float(_pct(u_cross, 1))
    r2 = _radius_mode(r, r.size)
    # the start of a taper is one kink in r(u): it needs a denser sample than the other fits
    sub = _subsample(np.arange(u.size), 2 * cfg.fit_points)
    us, rs = u[sub], r[sub]
    n_lead = 0
    if contraction:
        # the wall just before the first returns off it: a gentle taper leaves the wall
        # tolerance only some way past its start, and the kink needs both sides
        pw = cloud.points(wall)
        lead = np.flatnonzero((pw[:, 0] > u_first - 0.15) & (pw[:, 0] < u_first))
        lead = lead[_subsample(np.arange(lead.size), cfg.fit_points // 2)]
        n_lead = int(lead.size)
        us = np.concatenate([us, pw[lead, 0]])
        rs = np.concatenate([rs, np.hypot(pw[lead, 1], pw[lead, 2])])
    t0 = max(0.01, float(_pct(u, 30)) - u_first)

    def resjac(x: NDArray) -> tuple[NDArray, NDArray]:
        big_l, t_len, rr2 = x
        t_len = max(t_len, 1e-4)
        raw = (us - big_l) / t_len
        frac = np.clip(raw, 0.0, 1.0)
        ramp = (raw > 0.0) & (raw < 1.0)
        jac = np.empty((us.size, 3))
        jac[:, 0] = np.where(ramp, (rr2 - big_r) / t_len, 0.0)
        jac[:, 1] = np.where(ramp, (rr2 - big_r) * raw / t_len, 0.0)
        jac[:, 2] = -frac
        return rs - (big_r + (rr2 - big_r) * frac), jac

    c_fin = max(2.0 * tol_med, 0.002)
    x, res, w = robust_gauss_newton(
        None,
        np.array([u_first, t0, r2]),
        np.array([1e-4, 1e-4, 1e-5]),
        c=max(4.0 * c_fin, 0.01),
        iterations=10,
        resjac=resjac,
        # a widening starts where the beams leave the incoming pipe: its end edge is seen
        # directly, the cone behind it mostly not
        lower=np.array([-0.2 if contraction else u_first, 0.002, 0.0]),
        upper=np.array([cfg.horizon if contraction else u_first, 1.0, 3.0 * big_r]),
        c_final=c_fin,
        step_tol=STEP_TOL,
        anneal=ANNEAL,
        cost_tol=COST_TOL,
    )
    if contraction:
        # an end wall far down the narrower pipe, seen through it, is no part of the taper:
        # its returns pull the plateau of the fit down (too narrow, the taper too long), all
        # the way onto the end wall when grazing beams lose the narrower pipe's own wall.
        # Without them, the taper ends where its returns end; the end wall, filling the
        # narrower pipe's cross-section, still bounds its radius from below.
        u_far = _pct(u, 97.0)
        # (under range noise the end wall's returns spread along the axis by their range
        # noise: a metre away, a centimetre and more either side)
        sig_range = cloud.values(anomaly, cloud.sigma_range_v)
        near_far = np.abs(u - u_far) <= 0.003 + 2.0 * tol_med
        spread_u = 3.0 * float(_pct(sig_range[near_far], 50.0)) if near_far.any() else 0.0
        window = 0.003 + 2.0 * tol_med + spread_u
        far = np.abs(u - u_far) <= window
        n_far = int(np.count_nonzero(far))
        far_s = np.concatenate([far[sub], np.zeros(n_lead, dtype=bool)])
        if (
            30 <= n_far <= 0.9 * u.size
            and float(_pct(r[far], 5)) < 0.3 * big_r
            and np.count_nonzero(~far_s) >= 50
            # (returns spread along a taper, not mostly on one wall: the far wall of a turn)
            and diag.get("closure_plane_fraction", 0.0) < 0.8
        ):
            # (the end wall lies inside the incoming pipe; the outermost of its returns,
            # beams along the narrower pipe's wall, bound that pipe's radius from below)
            r_end = float(_pct(r[far], 98.0))
            if float(_pct(r[far], 90.0)) < big_r - tol_med:
                us, rs = us[~far_s], rs[~far_s]
                # (started from the farthest returns left, on the narrower pipe: the first fit,
                # pulled onto the end wall, can hold the plateau at the end wall's bound)
                u_rest, r_rest = u[~far], r[~far]
                r2_far = float(_pct(r_rest[u_rest >= _pct(u_rest, 90.0)], 50.0))
                x, res, w = robust_gauss_newton(
                    None,
                    np.array([x[0], x[1], min(max(r2_far, r_end), big_r)]),
                    np.array([1e-4, 1e-4, 1e-5]),
                    c=max(4.0 * c_fin, 0.01),
                    iterations=10,
                    resjac=resjac,
                    lower=np.array([-0.2, 0.002, r_end]),
                    upper=np.array([cfg.horizon, 1.0, big_r]),
                    c_final=c_fin,
                    step_tol=STEP_TOL,
                    anneal=ANNEAL,
                    cost_tol=COST_TOL,
                )
                diag["reducer_end_wall_radius"] = r_end
    support = float((w > 0.1).mean())
    rms = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9)))
    big_l, t_len, r2 = (float(v) for v in x)
    if not contraction:
        big_l, along = _widening_start(cloud, big_r, r2, u_first, big_l)
        diag["widening_start_from_cone"] = bool(along)
    diag.update(reducer_r2=r2, reducer_taper=t_len, reducer_rms=rms, axisymmetric_support=support)
    cov = _azimuth_coverage(p)
    if not (math.isfinite(big_l) and math.isfinite(r2)):
        return Detection.straight(confidence=0.0, **diag)
    if r2 < 0.25 * big_r:
        # the pipe closes (a cap seen obliquely, or a cone to nothing): a closure at its start;
        # not when the end wall was found curved (the far wall of a pipe seen head-on)
        if diag.get("closure_curved", False):
            diag["axisymmetric_support"] = 0.0
            return Detection.straight(confidence=0.0, **diag)
        conf = 0.5 * _confidence(int(w.sum()), rms, c_fin) * cov
        opt = StructureOption("closure", max(big_l, 0.0), 0.0, 0.0, 0.0, conf)
        return Detection("closure", [opt], conf, diag)
    conf = _confidence(int((w > 0.1).sum()), rms, c_fin) * cov * min(1.0, support / 0.6)
    opt = StructureOption("reducer", max(big_l, 0.0), 2.0 * r2, 0.0, 0.0, conf)
    return Detection("reducer", [opt], conf, diag)


def _widening_start(
    cloud: PipeCloud, big_r: float, r2: float, u_first: float, default: float
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
    noise = float(_pct(sig, 50.0))
    rise = r2 - big_r
    margin = max(3.0 * noise, CONE_PLATEAU_MARGIN)
    plateau = e >= rise - margin
    u_f = float(_pct(u[plateau], 1.0)) if np.any(plateau) else u_first * r2 / big_r
    off_wall = np.maximum(0.00035, 4.0 * sig)
    on = (np.abs(e) <= off_wall) & (u < u_f)
    cone = (e > off_wall) & ~plateau & (u > min(u_first, u_f) - 0.1) & (u < u_f)
    # (rings all round: part rings off the wall on one side are a slightly tilted axis)
    cone[cone] = _full_rings(xyz[:, cone])
    n_cone = int(np.count_nonzero(cone))
    uc, ec = u[cone], e[cone]
    if n_cone >= 20 and float(_pct(ec, 95) - _pct(ec, 5)) > max(6.0 * noise, CONE_MIN_RISE):
        # (near its start the cone lies within the noise of the wall: the line alone places
        # the start, bounded by the beams' crossings)
        a_u, b_u = _robust_line(ec, uc)  # u = a + b e: the start at e = 0
        # (a cone: returns on one line to within their noise)
        if math.isfinite(a_u) and b_u > 0.0:
            scatter = mad_sigma(ec - (uc - a_u) / b_u)
            if scatter <= max(3.0 * noise, CONE_LINE_SCATTER):
                return min(u_first, max(u_first - 0.1, a_u)), True
    # (under range noise the first centimetres of the cone, per return, are the wall's: the
    # rings' medians are not)
    hinge = _ring_hinge_start(xyz, e, noise, u_first, u_f, rise - margin)
    if hinge is not None:
        return hinge, True
    hi = min(u_first, u_f)
    if n_cone:
        first = uc <= uc.min() + CONE_FIRST_RING
        hi = min(hi, float(uc.min()))
    before = on & (u < hi)
    if not np.any(before):
        return default, False
    lo = float(u[before].max())
    if n_cone:
        u_c, e_c = float(np.median(uc[first])), float(np.median(ec[first]))
        k = (rise - margin) / max(e_c, 1e-6)
        if k > 1.0:
            lo = max(lo, (k * u_c - u_f) / (k - 1.0))
    return (0.5 * (lo + hi) if lo <= hi else hi), False


def _ring_hinge_start(
    xyz: NDArray[np.float64],
    e: NDArray[np.float64],
    noise: float,
    u_first: float,
    u_f: float,
    e_max: float,
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
    win = (u > u_first - HINGE_REACH) & (u < u_f) & (e < e_max) & (e > -4.0 * noise - 0.00035)
    if np.count_nonzero(win) < 4 * CONE_MIN_RETURNS:
        return None
    p, ew = xyz[:, win], e[win]
    rings = _rings(p)
    if len(rings) < 4:
        return None
    ua = np.array([float(np.median(p[0, sel])) for sel in rings])
    ea = np.array([float(np.median(ew[sel])) for sel in rings])
    na = np.array([float(np.count_nonzero(sel)) for sel in rings])
    # (the median of n returns scatters by about 1.25 noise / sqrt(n))
    sig_b = 1.25 * max(noise, 1e-5) / np.sqrt(na)
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
    rising = (ua > big_l) & (b * (ua - big_l) > np.maximum(HINGE_MIN_SNR * sig_b, HINGE_MIN_RISE))
    # (two rings at least, a ring on the wall before: one ring split between two bins makes
    # no slope)
    if not rising.any() or np.ptp(ua[rising]) < CONE_FIRST_RING or not np.any(ua < big_l):
        return None
    return big_l


def _rings(p: NDArray[np.float64]) -> list[NDArray[np.bool_]]:
    """The ``(3, n)`` returns in each ``CONE_FIRST_RING`` long stretch of the axis that holds at
    least ``CONE_MIN_RETURNS`` of them covering at least ``CONE_RING_COVERAGE`` of the azimuth
    (a ring of beams all round, not a stray return or part of a ring), nearest first: one mask
    per ring."""
    if p.shape[1] < CONE_MIN_RETURNS:
        return []
    bins = np.floor((p[0] - p[0].min()) / CONE_FIRST_RING).astype(np.int64)
    counts = np.bincount(bins)
    out = []
    for k in np.flatnonzero(counts >= CONE_MIN_RETURNS):
        sel = bins == k
        if _azimuth_coverage(p[:, sel].T) >= CONE_RING_COVERAGE:
            out.append(sel)
    return out


def _full_rings(p: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which of the ``(3, n)`` returns lie in a ring of beams all round (:func:`_rings`)."""
    keep = np.zeros(p.shape[1], dtype=bool)
    for sel in _rings(p):
        keep |= sel
    return keep


def _radius_mode(r: NDArray, n: int) -> float:
    """Most frequent radius: 1 mm histogram peak refined by the median of its neighbourhood."""
    bins = np.floor(r / 0.001).astype(np.int64)
    lo = int(bins.min())
    cnt = np.bincount(bins - lo)
    smooth = np.convolve(cnt, np.ones(3), mode="same")
    peak = (int(np.argmax(smooth)) + lo + 0.5) * 0.001
    near = np.abs(r - peak) <= 0.002
    return float(_pct(r[near], 50.0)) if near.any() else float(peak)


def _robust_line(x: NDArray, y: NDArray) -> tuple[float, float]:
    """Robust fit ``y = a + b x`` (Tukey IRLS)."""
    w = np.ones_like(x)
    a, b = float(_pct(y, 50.0)), 0.0
    for _ in range(6):
        sw = w.sum()
        if sw <= 0:
            break
        xm = float((w * x).sum() / sw)
        ym = float((w * y).sum() / sw)
        sxx = float((w * (x - xm) ** 2).sum())
        if sxx <= 1e-18:
            break
        b = float((w * (x - xm) * (y - ym)).sum() / sxx)
        a = ym - b * xm
        res = y - (a + b * x)
        s = max(mad_sigma(res), 1e-4)
        w = tukey_weights(res, 4.685 * s)
    return a, b


def _covers(xyz: NDArray, idx: NDArray[np.intp], fraction: float, bins: int = 36) -> bool:
    """Do the ``(3, n)`` points ``idx`` cover at least ``fraction`` of the azimuth (as
    :func:`_azimuth_coverage`)? Every 16th of them is tried first: when those cover enough, so
    do all of them."""
    if idx.size >= 512:
        few = idx[::16]
        if _yz_coverage(xyz[1, few], xyz[2, few], bins) >= fraction:
            return True
    return _yz_coverage(xyz[1, idx], xyz[2, idx], bins) >= fraction


def _yz_coverage(y: NDArray, z: NDArray, bins: int) -> float:
    """Fraction of ``bins`` azimuth sectors occupied by points at cross-section ``(y, z)``."""
    phi = np.arctan2(z, y)
    k = np.floor((phi + math.pi) / (2 * math.pi) * bins).astype(int) % bins
    return float(np.count_nonzero(np.bincount(k, minlength=bins))) / bins


def _azimuth_coverage(p: NDArray, bins: int = 36) -> float:
    """Fraction of ``bins`` azimuth sectors that the ``(n, 3)`` points occupy."""
    return _yz_coverage(p[:, 1], p[:, 2], bins)


def _azimuth_uniformity(p: NDArray, bins: int = 12) -> float:
    """Smallest azimuth-bin count relative to the median bin count (1: even all around)."""
    if p.shape[0] == 0:
        return 0.0
    phi = np.arctan2(p[:, 2], p[:, 1])
    k = np.floor((phi + math.pi) / (2 * math.pi) * bins).astype(int) % bins
    cnt = np.bincount(k, minlength=bins)
    med = float(_pct(cnt, 50.0))
    return float(cnt.min()) / med if med > 0 else 0.0


def _confidence(n_support: int, rms: float, tol: float) -> float:
    c = (1.0 - math.exp(-n_support / 30.0)) * math.exp(-((rms / max(tol, 1e-6)) ** 2) / 4.0)
    return float(min(1.0, max(0.0, c)))


# --------------------------------------------------------------------------- bends/junctions
@dataclass
class BranchFit:
    theta: float
    phi: float
    rho: float
    rb: float = 0.0


def _line_points(p: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """(x, y, z, y^2 + z^2) of ``(N, 3)`` points as contiguous arrays, for :func:`_line_resjac`."""
    px, py, pz = (np.ascontiguousarray(p[:, k]) for k in range(3))
    return px, py, pz, py * py + pz * pz


def _line_resjac(
    pts: tuple[NDArray, NDArray, NDArray, NDArray], x: NDArray, n_l: int, want_jac: bool
) -> tuple[NDArray, NDArray | None]:
    """Residuals of points (:func:`_line_points`) to the nearest of ``n_l`` outgoing cylinders
    whose axes meet the incoming axis at ``(x[0], 0, 0)``; parameters per lobe:
    (theta, phi, rho)."""
    px, py, pz, r2 = pts
    qx = px - x[0]
    qq = qx * qx + r2
    if n_l == 1:
        th, ph, rho = float(x[1]), float(x[2]), float(x[3])
        ct, st, cp, sp = math.cos(th), math.sin(th), math.cos(ph), math.sin(ph)
        lat = py * cp + pz * sp
        t = ct * qx + st * lat
        dist = qq - t * t
        np.maximum(dist, 1e-18, out=dist)
        np.sqrt(dist, out=dist)
        res = dist - rho
        if not want_jac:
            return res, None
        g = t / dist
        jac = np.empty((4, px.size))
        jac[0] = ct * g - qx / dist
        jac[1] = (st * qx - ct * lat) * g
        jac[2] = (py * sp - pz * cp) * (st * g)
        jac[3] = -1.0
        return res, jac.T
    th, ph, rho = x[1::3], x[2::3], x[3::3]
    ct, st, cp, sp = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph)
    lat_all = cp[:, None] * py + sp[:, None] * pz  # (n_l, N)
    t_all = ct[:, None] * qx + st[:, None] * lat_all
    dist_all = qq - t_all * t_all
    np.maximum(dist_all, 1e-18, out=dist_all)
    np.sqrt(dist_all, out=dist_all)
    res_all = dist_all - rho[:, None]
    arg = np.argmin(np.abs(res_all), axis=0)  # each return on its nearest cylinder
    cols = np.arange(px.size)
    best = res_all[arg, cols]
    if not want_jac:
        return best, None
    t, dist, lat = t_all[arg, cols], dist_all[arg, cols], lat_all[arg, cols]
    ctk, stk, cpk, spk = ct[arg], st[arg], cp[arg], sp[arg]
    g = t / dist
    jac = np.zeros((px.size, 1 + 3 * n_l))
    jac[:, 0] = ctk * g - qx / dist
    k = 1 + 3 * arg
    jac[cols, k] = (stk * qx - ctk * lat) * g
    jac[cols, k + 1] = (py * spk - pz * cpk) * (stk * g)
    jac[cols, k + 2] = -1.0
    return best, jac


def _own_branch_resjac(
    pts: tuple[NDArray, NDArray, NDArray, NDArray], labels: NDArray[np.intp], n_l: int
) -> Callable[[NDArray], tuple[NDArray, NDArray]]:
    """Residuals and Jacobian (as :func:`_line_resjac`) of the returns to the outgoing cylinder
    of their own lobe: ``labels[i]`` (in ``0 .. n_l - 1``) is the lobe of return ``i``."""
    groups = [np.flatnonzero(labels == k) for k in range(n_l)]
    sub = [tuple(np.ascontiguousarray(a[g]) for a in pts) for g in groups]
    n = labels.size

    def resjac(v: NDArray) -> tuple[NDArray, NDArray]:
        res = np.empty(n)
        jac = np.zeros((n, v.size))
        for k, (g, pk) in enumerate(zip(groups, sub)):
            vk = np.concatenate([v[:1], v[1 + 3 * k : 4 + 3 * k]])
            r, jk = _line_resjac(pk, vk, 1, True)
            res[g] = r
            jac[g, 0] = jk[:, 0]
            jac[g, 1 + 3 * k : 4 + 3 * k] = jk[:, 1:]
        return res, jac

    return resjac


def _fit_axes(
    pts: NDArray[np.float64],
    x0: NDArray[np.float64],
    n: int,
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    c: float,
    c_final: float,
    iterations: int = 8,
    own: Callable[[NDArray], tuple[NDArray, NDArray]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Robust fit of ``n`` outgoing pipes (``[L, theta, phi, rho] x n``, the reference point
    shared) to the returns ``pts`` from ``x0`` within the bounds: Tukey cut-off shrinking from
    ``c`` to ``c_final`` (m). Each return is fitted to the nearest pipe, or with ``own`` (from
    :func:`_own_branch_resjac` on the same returns) to its own. Returns ``(x, residuals,
    weights)``."""
    if own is not None:
        resjac = own
    else:

        def resjac(v: NDArray) -> tuple[NDArray, NDArray]:
            return _line_resjac(pts, v, n, True)

    return robust_gauss_newton(
        None,
        x0,
        np.full(x0.size, 1e-5),
        c=c,
        iterations=iterations,
        lower=lower,
        upper=upper,
        c_final=c_final,
        step_tol=STEP_TOL,
        anneal=ANNEAL,
        cost_tol=COST_TOL,
        resjac=resjac,
    )


def _branches(
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
    unknown and searched too)."""
    lobes = _nearest_structure_lobes(cloud, lobes, big_r, diag)
    # returns of the outgoing pipes: the lobes, and the inner returns near them (the far wall
    # of a turn seen head-on), not far end walls of a run that goes on
    lobe_mask = np.zeros_like(keep)
    for lb in lobes:
        lobe_mask |= lb.mask
    u_all = cloud.xyz[0]
    u_hi = float(_pct(u_all[lobe_mask], 95)) + 2.0 * big_r if lobe_mask.any() else 0.0
    near_inside = keep & ~lobe_mask & (u_all <= u_hi)
    lobe_sub = [
        _subsample(np.flatnonzero(lb.mask.reshape(-1)), cfg.fit_points // 2) for lb in lobes
    ]
    lobe_idx = np.concatenate(lobe_sub)
    near_idx = _subsample(np.flatnonzero(near_inside.reshape(-1)), cfg.fit_points // 2)
    sub_idx = np.concatenate([lobe_idx, near_idx])
    if any_roll:
        sub_idx = _subsample(np.flatnonzero(keep.reshape(-1)), cfg.fit_points)
    p_all = np.ascontiguousarray(cloud.points_at(sub_idx))
    pts_all = _line_points(p_all)
    tol_med = float(_pct(tol.reshape(-1)[sub_idx], 50.0))
    noise_med = float(_pct(cloud.sigma_r.reshape(-1)[sub_idx], 50.0)) + 0.3e-3
    lobe_pts = []
    u_edge = math.inf
    for lb in lobes:
        lp = cloud.points(lb.mask)
        lp = lp[_subsample(np.arange(lp.shape[0]), 200)]
        lobe_pts.append(lp)
        # where the beams left the incoming cylinder (sensor near the axis)
        rr = np.sqrt(np.square(lp[:, 1]) + np.square(lp[:, 2]))
        uc = lp[:, 0] * big_r / np.maximum(rr, 1e-9)
        u_edge = min(u_edge, float(_pct(uc, 1)))
    # --- does the incoming pipe go on? Then this is a junction seen along its run: every
    # lobe is a side branch of a standard fitting (tee 90 deg, wye 45 deg), no wider than
    # the run
    straight_on, cov_on = _straight_on(cloud, big_r, u_edge + big_r, wall, cfg)
    diag["straight_on_coverage"] = cov_on
    # --- coarse grid per lobe over (L, theta) with the lobe's roll and radius R
    # one way on and no run going on: a bend, deflecting up to 90 deg (wye branches at 135 deg
    # come with a second way)
    bend_only = len(lobes) == 1 and not straight_on
    thetas = np.radians(np.arange(30.0, 101.0 if bend_only else 151.0, 7.5))
    l_grid = u_edge + np.linspace(0.0, 3.0 * big_r, 13)
    if any_roll:
        # the far wall of a turn lies past the turn's reference point
        u_near = min(float(lp[:, 0].min()) for lp in lobe_pts)
        l_grid = u_near + np.linspace(-4.0 * big_r, 0.0, 13)
    c0 = max(6.0 * tol_med, 0.006)
    total = np.zeros(l_grid.size)
    per_lobe = []
    rolls_of = []
    for lb, lp in zip(lobes, lobe_pts):
        rolls = np.radians(np.arange(0.0, 360.0, 20.0)) if any_roll else np.array([lb.roll])
        rolls_of.append(rolls)
        st = np.sin(thetas)
        dirs = np.stack(
            [
                np.tile(np.cos(thetas), rolls.size),
                (np.cos(rolls)[:, None] * st).reshape(-1),
                (np.sin(rolls)[:, None] * st).reshape(-1),
            ]
        )  # (3, RT)
        lq = lp[_subsample(np.arange(lp.shape[0]), 50 if any_roll else 60)]
        qx = lq[None, :, 0] - l_grid[:, None]  # (L, n)
        qq = qx * qx + (lq[:, 1] ** 2 + lq[:, 2] ** 2)[None, :]
        lat = lq[:, 1:] @ dirs[1:]  # (n, RT)
        t = qx[:, :, None] * dirs[0] + lat[None]  # (L, n, RT)
        # squared residual to the wall, capped (in place: these arrays are the largest here)
        sq = t * t
        np.subtract(qq[..., None], sq, out=sq)
        np.maximum(sq, 0.0, out=sq)
        np.sqrt(sq, out=sq)
        sq -= big_r
        np.square(sq, out=sq)
        np.minimum(sq, c0 * c0, out=sq)
        # the sensor sees every wall from inside its pipe: the wall normal (away from the
        # axis) must not face the sensor; a cylinder behind the returns (the same patch
        # seen from outside) is penalised like an outlier
        qp = qx * lq[None, :, 0] + (lq[:, 1] ** 2 + lq[:, 2] ** 2)[None, :]  # q . p
        dp = lq[:, 0:1] * dirs[0] + lat  # (n, RT): d . p
        t *= dp[None]
        np.subtract(qp[..., None], t, out=t)
        np.copyto(sq, c0 * c0, where=t < 0.0)
        cost = sq.mean(axis=1)  # (L, RT)
        per_lobe.append(cost)
        total += cost.min(axis=1)
    i_l = int(np.argmin(total))
    x0 = [float(l_grid[i_l])]
    for rolls, cost in zip(rolls_of, per_lobe):
        k = int(np.argmin(cost[i_l]))
        x0 += [float(thetas[k % thetas.size]), float(rolls[k // thetas.size]), big_r]
    n_l = len(lobes)
    x0a = np.array(x0)
    # physical ranges: bends deflect 30-90 deg, branches 45, 90 or 135 deg
    lower = np.array([-0.5] + [math.radians(25.0), -10.0, 0.25 * big_r] * n_l)
    # (a side branch of a run that goes on is no wider than the run)
    rho_max = 1.05 * big_r if straight_on else 2.5 * big_r
    th_max = math.radians(100.0 if bend_only else 150.0)
    upper = np.array([cfg.horizon] + [th_max, 10.0, rho_max] * n_l)
    hole = None
    if straight_on and not any_roll:
        prior = (x0a.copy(), lower.copy(), upper.copy())
        hole = _hole_prior(cloud, big_r, lobes, lobe_pts, wall, tol, u_edge, c0, *prior)
    c_fin = max(3.0 * tol_med, 0.003)

    # two openings on opposite sides (a tee from its stem, a wye from its branch, the side
    # pipes of a cross): each branch is fitted to the returns of its own opening (and an inner
    # return near them, on the far wall of a pipe across seen head-on, to the branch on its
    # side of the incoming axis). Two cylinders fitted to the nearer of them take in the
    # scatter of a noisy opening's rim between them, and lean apart by several degrees for it.
    own = None
    opposite = n_l == 2 and abs(_wrap(lobes[0].roll - lobes[1].roll)) > math.radians(150)
    if opposite and not any_roll:
        p_near = p_all[lobe_idx.size :]
        side = np.stack(
            [p_near[:, 1] * math.cos(lb.roll) + p_near[:, 2] * math.sin(lb.roll) for lb in lobes]
        )
        labels = np.concatenate(
            [np.full(ix.size, k) for k, ix in enumerate(lobe_sub)] + [np.argmax(side, axis=0)]
        )
        own = _own_branch_resjac(pts_all, labels, n_l)

    def free_fit(xs: NDArray, lo: NDArray, up: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        return _fit_axes(pts_all, xs, n_l, lo, up, c=2.0 * c0, c_final=c_fin, own=own)

    x, res, w = free_fit(x0a, lower, upper)
    if hole is not None and not _fits_hole(x, hole, big_r, lower, upper):
        # the returns through the openings led the fit astray (few and noisy, far away):
        # start again from the holes in the run's wall and stay near them
        x0a, lower, upper = prior
        x, res, w = free_fit(x0a, lower, upper)
        diag.update(hole_reference=float(prior[0][0]), hole_prior_used=True)
    # --- the outgoing radii: the clamped radius (a standard fitting) unless the returns
    # call for another one. A free radius is poorly observed from a partial view of an
    # opening under range noise, so it is kept only when it fits significantly better
    # (likelihood ratio against the residual noise, a few units per extra parameter).
    # (a far wall seen head-on is too small a part of a pipe to size it: clamped from the
    # coarse start)
    # (the standard radius of a side branch whose hole in the run's wall is clearly narrower
    # is the hole's)
    std_r = np.array([h[3] for h in hole]) if hole is not None else np.full(n_l, big_r)
    x_eq = x0a.copy() if any_roll else x.copy()
    x_eq[3::3] = std_r
    lo_eq, up_eq = lower.copy(), upper.copy()
    lo_eq[3::3] = std_r
    up_eq[3::3] = std_r
    if not any_roll and bool(np.all(np.abs(x[3::3] - std_r) <= 0.01 * big_r)):
        # the free fit found the clamped radius already: clamping it moves nothing that matters
        res_eq = _line_resjac(pts_all, x_eq, n_l, False)[0] if own is None else own(x_eq)[0]
        w_eq = tukey_weights(res_eq, c_fin)
    else:
        x_eq, res_eq, w_eq = _fit_axes(
            pts_all,
            x_eq,
            n_l,
            lo_eq,
            up_eq,
            c=2.0 * c0 if any_roll else 2.0 * c_fin,
            c_final=c_fin,
            iterations=12 if any_roll else 8,
            own=own,
        )
    if any_roll:
        # (a far wall seen head-on fits a pipe deflected by theta and its mirror image deflected
        # by pi - theta about nearly as well: the mirror of the solution is a second start)
        x_m = x_eq.copy()
        x_m[1], x_m[2] = math.pi - x_eq[1], x_eq[2] + math.pi
        x_m[1] = min(max(x_m[1], lo_eq[1]), up_eq[1])
        x_m, res_m, w_m = _fit_axes(
            pts_all,
            x_m,
            n_l,
            lo_eq,
            up_eq,
            c=2.0 * c_fin,
            c_final=c_fin,
        )
        if tukey_cost(res_m, c_fin) < tukey_cost(res_eq, c_fin):
            x_eq, res_eq, w_eq = x_m, res_m, w_m
    cost_free = tukey_cost(res, c_fin)
    cost_eq = tukey_cost(res_eq, c_fin)
    n_in = max(int((w > 0.1).sum()), 1)
    sigma2 = max(2.0 * cost_free / n_in, noise_med**2)
    lr = 2.0 * (cost_eq - cost_free) / sigma2
    diag.update(radius_lr=float(lr), radius_free=[float(v) for v in x[3::3]])
    # (a free fit that ends on the deflection bounds has not found a pipe: the radius traded
    # against the angle)
    th_lo, th_hi = lower[1] + math.radians(1.0), upper[1] - math.radians(1.0)
    free_on_bound = bool(np.any((x[1::3] <= th_lo) | (x[1::3] >= th_hi)))
    eq_on_bound = bool(np.any((x_eq[1::3] <= th_lo) | (x_eq[1::3] >= th_hi)))
    diag["radius_free_on_bound"] = free_on_bound
    weak = any_roll or bool(diag.get("hole_prior_used", False))  # too little to size a pipe
    if weak or lr <= cfg.radius_lr_per_branch * n_l or (free_on_bound and not eq_on_bound):
        x, res, w = x_eq, res_eq, w_eq
    if x is x_eq:
        diag["radius_model"] = "clamped" if bool(np.all(std_r == big_r)) else "hole"
    else:
        diag["radius_model"] = "free"
    across = None
    lo_b, up_b = (lo_eq, up_eq) if x is x_eq else (lower, upper)
    if opposite and not any_roll:
        # a pipe across? One straight axis through the reference point, fitted as one
        # cylinder of the standard radius, is kept unless the two branches fit significantly
        # better (likelihood ratio, as for the radii)
        k_main = 0 if lobes[0].n >= lobes[1].n else 1
        r_a = float(np.mean(std_r))  # (the side pipe of a cross may be narrower than the run)
        starts = [np.array([x[0], x[1 + 3 * k_main], x[2 + 3 * k_main], r_a])]
        if float(_dir(x[1], x[2]) @ _dir(x[4], x[5])) > -0.985:
            # (the branches not nearly in line: the pipe across may lie elsewhere)
            starts += [
                np.array([x[0], 0.5 * math.pi, lobes[k_main].roll, r_a]),
                np.array([u_edge + big_r, 0.5 * math.pi, lobes[k_main].roll, r_a]),
            ]
        best_a = None
        for xa0 in starts:
            xa, res_a, w_a = _fit_axes(
                pts_all,
                xa0,
                1,
                np.array([lower[0], math.radians(25.0), -10.0, r_a]),
                np.array([upper[0], math.radians(155.0), 10.0, r_a]),
                c=2.0 * c0,
                c_final=c_fin,
            )
            cost_a = tukey_cost(res_a, c_fin)
            if best_a is None or cost_a < best_a[0]:
                best_a = (cost_a, xa, res_a, w_a)
        cost_a, xa, res_a, w_a = best_a
        # (the two branches: three more deflection and roll parameters, two more radii)
        n_extra = 4 if diag["radius_model"] == "free" else 2
        lr_a = 2.0 * (cost_a - tukey_cost(res, c_fin)) / sigma2
        diag["across_lr"] = float(lr_a)
        if lr_a <= 0.5 * cfg.radius_lr_per_branch * max(n_extra, 1):
            across = xa
            x, res, w = xa, res_a, w_a
    if not any_roll and (across is not None or n_l >= 2 or straight_on):
        # a junction: its branches leave at the standard angles of fittings when the returns
        # allow it
        if across is not None:
            n_b = 1
            lo_b = np.array([lower[0], math.radians(25.0), -10.0, float(across[3])])
            up_b = np.array([upper[0], math.radians(155.0), 10.0, float(across[3])])
            own = None
        else:
            n_b = n_l
        x, res, w = _standard_angles(
            pts_all,
            x,
            res,
            w,
            n_b,
            lo_b,
            up_b,
            c_fin,
            sigma2,
            diag,
            radius_bounds=(lower[3::3], upper[3::3]) if across is None else None,
            own=own,
        )
        if across is not None:
            across = x
    rms = float(np.sqrt(np.sum(w * res**2) / max(w.sum(), 1e-9)))
    support = int((w > 0.1).sum())
    diag.update(fit_rms=rms, fit_support=support, fit_points=int(p_all.shape[0]))
    model = "straight_axes"
    if across is not None:
        model = "pipe_across"
        th_a, ph_a = float(across[1]), float(across[2])
        r_a = float(across[3])
        fits = [BranchFit(th_a, ph_a, r_a), BranchFit(math.pi - th_a, ph_a + math.pi, r_a)]
    else:
        fits = [BranchFit(x[1 + 3 * k], x[2 + 3 * k], x[3 + 3 * k]) for k in range(n_l)]
    if any_roll and w.sum() > 0:
        # a cylinder's axis has no sign: the way on is the half the returns lie along
        f = fits[0]
        along = (p_all - np.array([x[0], 0.0, 0.0])) @ _dir(f.theta, f.phi)
        ahead = float(np.sum(w * (along > 0.5 * big_r))) / max(float(w.sum()), 1e-9)
        behind = float(np.sum(w * (along < -0.5 * big_r))) / max(float(w.sum()), 1e-9)
        diag.update(far_wall_ahead=ahead, far_wall_behind=behind)
        flipped = BranchFit(math.pi - f.theta, f.phi + math.pi, f.rho)
        balanced = min(ahead, behind) >= 0.05 and min(ahead, behind) >= 0.5 * max(ahead, behind)
        if balanced and abs(f.theta - 0.5 * math.pi) < math.radians(20.0):
            # the far wall runs on evenly to both sides of the axis' foot: a pipe across,
            # both its ways open (a tee seen from its stem)
            fits = [f, flipped]
        else:
            # (the returns' mean position along the axis, from its foot, m)
            lean = float(np.sum(w * along)) / max(float(w.sum()), 1e-9)
            diag["far_wall_lean"] = lean / big_r
            if abs(lean) < cfg.far_wall_min_lean * big_r:
                # the far wall lies about evenly to both sides of the axis' foot (a turn by
                # about 90 deg seen head-on, its opening unseen): it shows a way on, not which
                # of the two; a guess would be the mirror image as often as not
                diag["reason"] = "far wall: way on undetermined"
                return Detection.straight(confidence=0.0, **diag)
            if lean < 0.0:
                fits = [flipped]
    big_l = float(x[0])
    # --- a single way on that the straight model explains poorly: a long-radius bend (torus)
    lower_bound = False
    # (or that leaves out more than a few of the returns: the first centimetres of a gentle
    # arc lie within the noise of a mitre's straight axes, its far part does not)
    loose = rms > 2.0 * noise_med or support < TORUS_TRY_SUPPORT * p_all.shape[0]
    if n_l == 1 and not straight_on and loose:
        # (polished on returns spread evenly along the axis: the few returns from the far end
        # of the arc fix its angle, and an even subsample of all returns holds hardly any of
        # them; not under range noise, see _fit_torus)
        p_fit = None
        if noise_med <= TORUS_POLISH_MAX_NOISE:
            arc_cells = np.flatnonzero((lobe_mask | near_inside).reshape(-1))
            spread = _spread_along_axis(arc_cells, u_all.reshape(-1)[arc_cells], cfg.fit_points)
            p_fit = np.ascontiguousarray(cloud.points_at(spread))
        tor = _fit_torus(p_all, big_r, big_l, fits[0], c0, c_fin, noise_med, p_fit)
        if tor is not None:
            xt, rms_t, sup_t, vis = tor
            diag.update(torus_rms=rms_t, torus_support=sup_t, torus_rb=float(xt[4]))
            if sup_t >= support * 0.98 and rms_t < rms * 0.85:
                big_l = float(xt[0])
                fits = [BranchFit(xt[1], xt[2], xt[3], xt[4])]
                rms, support = rms_t, sup_t
                model = "torus"
                # the end of the arc unseen: the angle is only a lower bound
                lower_bound = vis >= float(xt[1]) - math.radians(3.0)
                diag["torus_visible_arc_deg"] = math.degrees(vis)
    diag["model"] = model
    diag["angle_lower_bound"] = lower_bound
    if not (math.isfinite(big_l) and -0.5 <= big_l <= cfg.horizon):
        diag["reason"] = "fit left the physical range"
        return Detection.straight(confidence=0.0, **diag)
    conf = _confidence(support, rms, c_fin / 3.0) * (0.6 if lower_bound else 1.0)
    options: list[StructureOption] = []
    for f in fits:
        angle, direction = option_direction(_dir(f.theta, f.phi), cloud.pose)
        # a long bend's arc radius (torus model; 0 for the straight-axes model) for the turn
        radius = float(f.rb) if model == "torus" else 0.0
        options.append(
            StructureOption(
                "bend", big_l, 2.0 * float(f.rho), direction, angle, conf, bend_radius=radius
            )
        )
    if straight_on:
        options.append(StructureOption("junction", big_l, 2.0 * big_r, 0.0, 0.0, conf * cov_on))
    kind = "bend" if len(options) == 1 else "junction"
    options = [
        StructureOption(
            kind,
            o.distance,
            o.diameter,
            o.direction,
            o.angle,
            o.confidence,
            bend_radius=o.bend_radius if kind == "bend" else 0.0,
        )
        for o in options
    ]
    options.sort(key=option_order)
    return Detection(kind, options, conf, diag)


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
    radius_bounds: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    own: Callable[[NDArray], tuple[NDArray, NDArray]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The branch fit ``x`` (``[L, theta, phi, rho] x n_b``, its residuals and weights) with
    each deflection within ``SNAP_WITHIN`` of a standard fitting angle (tees and crosses
    90 deg, laterals 45 deg: :data:`STANDARD_BRANCH_ANGLES`) held at that angle and the rest
    refitted, when the returns do not reject it (likelihood ratio against the residual noise
    ``sigma2``, m^2, at most ``SNAP_LR`` per angle held). A small opening far away shows a
    patch of the branch's wall whose deflection trades against the reference point and the
    radius by a few degrees; a standard angle the patch fits as well is the better estimate.

    When the radii are held (``lower == upper``) and the held angle is rejected, it is tried
    once more with the radii free within ``radius_bounds`` (lower, upper per branch, m) but
    within ``SNAP_RADIUS`` of the held ones: a branch a millimetre narrower than the run, fitted
    at the run's radius, leans by a degree or two instead. ``own``: as for
    :func:`_fit_axes`."""
    idx, angles = [], []
    for k in range(n_b):
        th = float(x[1 + 3 * k])
        j = int(np.argmin(np.abs(STANDARD_BRANCH_ANGLES - th)))
        if 1e-6 < abs(STANDARD_BRANCH_ANGLES[j] - th) <= SNAP_WITHIN:
            idx.append(1 + 3 * k)
            angles.append(float(STANDARD_BRANCH_ANGLES[j]))
    if not idx:
        return x, res, w
    xs, lo, up = x.copy(), lower.copy(), upper.copy()
    xs[idx] = lo[idx] = up[idx] = angles
    xs = np.clip(xs, np.minimum(lo, xs), np.maximum(up, xs))
    x_s, res_s, w_s = _fit_axes(pts, xs, n_b, lo, up, c=2.0 * c_fin, c_final=c_fin, own=own)
    cost = tukey_cost(res, c_fin)

    def accepted(x_s: NDArray[np.float64], res_s: NDArray[np.float64]) -> bool:
        lr = 2.0 * (tukey_cost(res_s, c_fin) - cost) / max(sigma2, 1e-12)
        diag["standard_angle_lr"] = float(lr)
        # (held at the standard angle, the branch must stay where it was: a fit that turns it
        # about the run's axis to make up for the deflection rests on too few returns)
        turned = max(abs(_wrap(float(x_s[2 + 3 * k] - x[2 + 3 * k]))) for k in range(n_b))
        return lr <= SNAP_LR * len(idx) and turned <= SNAP_MAX_TURN

    if accepted(x_s, res_s):
        diag["standard_angles"] = len(idx)
        return x_s, res_s, w_s
    rho = slice(3, None, 3)
    if radius_bounds is not None and bool(np.all(lo[rho] >= up[rho])):
        held = x[rho]
        lo[rho] = np.maximum(radius_bounds[0], held * (1.0 - SNAP_RADIUS))
        up[rho] = np.minimum(radius_bounds[1], held * (1.0 + SNAP_RADIUS))
        x_r, res_r, w_r = _fit_axes(pts, x_s, n_b, lo, up, c=2.0 * c_fin, c_final=c_fin, own=own)
        if accepted(x_r, res_r):
            diag["standard_angles"] = len(idx)
            diag["standard_angles_radius_free"] = True
            return x_r, res_r, w_r
    return x, res, w


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
        spans.append((float(_pct(u, 2.0)), float(_pct(u, 98.0))))
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
    u_grid = cloud.xyz[0]
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
        lq = lp[_subsample(np.arange(lp.shape[0]), 100)]
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
        best = (float(cost[j]), float(ths[j]), float(ell_t[j]))
        assert best is not None
        thetas.append(best[1])
        ells.append(best[2])
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
    u = cloud.xyz[0]
    far = wall & (u > big_l + 4.0 * big_r)
    if far.sum() < 10:
        return False, 0.0
    cov = _azimuth_coverage(cloud.points(far))
    return cov >= cfg.straight_on_coverage, cov


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
    polished on the returns ``p_fit`` when given; returns (x, rms, support, largest arc angle
    seen), the last three over ``p``."""
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
    res_full = _torus_dist(p, x[0], x[1], x[2], x[4]) - x[3]
    _, ang = _torus_parts(p, x[0], x[1], x[2], x[4])
    ok = np.abs(res_full) < c_fin
    vis = float(np.max(ang[ok])) if ok.any() else 0.0
    sup_full = int(ok.sum() * (p.shape[0] / max(sub.shape[0], 1)) / (p.shape[0] / sub.shape[0]))
    rms_full = float(np.sqrt(np.mean(res_full[ok] ** 2))) if ok.any() else math.inf
    return x, rms_full, int(ok.sum()) if sup_full >= 0 else sup, vis
