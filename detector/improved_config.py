"""Tuning of the improved detector (:mod:`detector.improved`): one frozen dataclass shared by
its modules.

Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields

from detector.validation import fail


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
        across_side_band, across_side_roll, across_wall_k: ... and when neither way is closed:
            the side away from a 90 deg turn (whose far wall is the same) shows the incoming
            wall running on past the reference point, in returns within ``across_side_roll``
            (rad) of the way's roll, within ``across_side_band`` radii of it along the axis,
            within ``across_wall_k`` times their radial noise of the wall ...
        across_view_band: ... and the scan sees the wall near the structure on both sides
            (within this many radii before the reference point, a radius short of it).
        far_wall_fit_points: returns used to fit a far wall seen head-on as an outgoing pipe
            of unknown roll (its roll rests on the wall's curvature alone, which range noise
            blurs: more returns than ``fit_points``).
        across_min_curvature_lr: a far wall seen head-on that runs on evenly to both sides of
            the axis' foot (a pipe across: a tee seen from its stem) replaces an end wall that
            looks flat within the range noise when the wall's curvature is at least this
            likely (likelihood ratio of a quadratic surface over a plane): an end wall is
            flat, so a wall that curves this clearly is not one.
        opposite_max_off_square, opposite_side_roll, opposite_noise_k, opposite_min_share,
            opposite_baseline_factor, opposite_wall_share: a turn or junction with one way
            leaving at 90 deg (within ``opposite_max_off_square`` rad) gains the way opposite
            it (a cross, or a tee from its stem, one of whose openings the fit missed) when,
            within ``opposite_side_roll`` (rad) of the opposite roll and a branch radius of
            the place along the axis, at least ``hole_min_returns`` twice, and
            ``opposite_min_share`` of what the found way's side holds, of the returns lie
            beyond the wall by ``opposite_noise_k`` times their radial noise (and
            ``hole_min_step``; when the sides square to the way hold beyond it, on average,
            ``opposite_min_share`` of what the way's side holds, and ``hole_min_returns``
            twice, as from a stem narrower than the run, beyond the 95th percentile of their
            depth), and ``opposite_baseline_factor`` times (one more than) what the sides
            square to the way hold; and the wall on the opposite side ends before the place:
            it keeps at most ``opposite_wall_share`` of the returns the square sides keep on
            the wall there (a turn's outer side runs on to the far wall).
        opposite_max_off_oblique: a single way within this angle (rad) of 45 deg (a Y
            entered from its branch) gains its backward way, at the supplementary
            deflection, by the same test; where neither square side shows a wall near the
            place (past the sensor's incidence limit), the wall test is not made and the
            opposite side only has to be as bare. A way within both windows counts as square.
        all_round: a region of returns beyond the wall covering this fraction of the azimuth
            goes all round the axis (and is split into its deep parts).
        all_round_sectors: ... when its deep parts (beyond half the region's 90th-percentile
            depth) still join all round, the depth is profiled over this many azimuth sectors
            and the parts are taken beyond the middle of the shallowest and deepest sector.
        snap_within: a junction's branch fitted within this angle of a standard fitting angle
            (tees and crosses 90 deg, laterals 45 or 135 deg) is tried held at it.
        snap_lr: ... and held when the returns allow it: likelihood ratio at most this per
            branch held (under range noise the few dozen returns through a far opening reject
            a standard angle held where the branch's hole is at ratios of 7-9 now and then).
        snap_max_turn: ... and when it turns the branch by at most this about the run.
        snap_radius: a radius held with a standard angle may move by this fraction of itself.
        deflection_min, deflection_max: the deflections an outgoing pipe's fit may take (a
            bend's: at most 100 deg).
        torus_try_support: a single way on whose straight-axes fit leaves out more than this
            fraction of its returns is also tried as a long-radius bend (as one that fits them
            loosely is).
        torus_polish_max_noise: a long bend's angle is polished on returns spread along its arc
            only when their range noise (median, plus 0.3 mm) is below this (a noiseless
            sensor's range resolution).
        cone_plateau_margin: returns of a widening this much (or three times their noise)
            short of the wider pipe's radius lie on its cone, not on the wider pipe.
        cone_min_rise: a line along a widening's cone needs returns rising this much (or six
            times their noise) from the wall to the wider pipe: two rings of beams, not the
            spread of one.
        cone_line_scatter: the returns of a cone seen by several rings lie on its line to
            within this much (robust standard deviation across it; or three times their noise).
        cone_first_ring: returns of a cone are binned this long along the axis to find its
            first ring of beams (or the first few, close together near the sensor).
        cone_min_returns: fewer returns than this off the wall are stray, not a ring of beams
            on a cone, whose returns cover ``cone_ring_coverage`` of the azimuth at least.
        hinge_reach: the rings' hinge looks this far before the first returns off the wall; a
            ring rises when its median lies ``hinge_min_snr`` times its noise and at least
            ``hinge_min_rise`` off the wall.
        pose_no_wall_view: with the structure starting less than this (m) past the nearest
            returns, a refined pipe axis replaces the given pose only when it explains
            ``pose_given_margin`` (a fraction, and ten) more of the wall returns.
        blind_min_expected, blind_max_ahead, blind_confidence: a scan whose beams would see a
            straight pipe's wall ahead of the sensor in at least ``blind_min_expected``
            returns, but sees at most ``blind_max_ahead`` (a fraction) of that many there, is
            blocked ahead within the minimum range (an end wall 10 cm ahead of a sensor whose
            minimum range is 12 cm); the end wall gets confidence ``blind_confidence`` (its
            distance is a bound).
        short_wall_view: less straight wall than this in view along the axis (m) before a
            structure: the given pose stands when it explains that wall ...
        long_wall_span, long_wall_rms: ... unless a refined axis explains as many of those
            returns and fits at least ``long_wall_span`` (m) of straight wall to within
            ``long_wall_rms`` of the scatter a straight wall may show (a sensor misaligned by
            20 % of D and 4 deg sees its wall drift off the tolerance 12 cm ahead under the
            given pose).
        short_wall_given_share: the given pose explains the wall before a structure (and
            stands against a refinement on a short view of it, or one fitting it loosely)
            only when it keeps at least this share of those wall returns within the wall
            tolerance: a sensor tilted by 1.3 deg and 2 mm off the axis keeps two in five of
            them, the rest within twice the tolerance, and under it a straight pipe (or a
            concentric reducer) showed a 25 deg bend 5 to 10 cm ahead; a sensor centred
            before the arc of a wide bend keeps all but a few.
        outlet_inside_share, outlet_min_returns, outlet_fit_scale, outlet_fits, outlet_from,
            outlet_until: a turn or junction keeping less than ``taper_pose_poor_support``
            of its returns, with at least ``outlet_inside_share`` of the returns off the wall
            inside it, is looked at again under the axis of the narrower pipe beyond: a
            cylinder of free radius fitted to the inside returns between the percentiles
            ``outlet_from`` and ``outlet_until`` (%) of their distance along the axis (past
            the taper, short of an end wall down the pipe), at least ``outlet_min_returns``
            of them, with a soft cut-off at ``outlet_fit_scale`` (m); the returns chosen
            again under the fitted axis and fitted again, ``outlet_fits`` fits in all; a fit
            whose axis is more than ``outlet_max_tilt`` (rad) off the sensor's or passes
            farther than the wall radius from it is not the pipe's. A
            sensor tilted 2-3 deg right before a concentric contraction sees no wall before
            its taper, and under its given pose the reducer read as a 25 deg turn.
        near_wall: the wall this far along the axis beyond the nearest returns (m) gives the
            first estimate of the pipe radius.
        gentle_start_margin: the pose of a long-radius bend or a reducer is chosen again on the
            wall ending this far (m) before the fitted arc or taper starts, when it was chosen
            on wall returns past that.
        torus_pose_ratio: a long bend's torus under the given pose fitting this many times more
            closely (rms, before any polish) than under the refined one: the refinement was laid
            into the arc, the given pose stands (under range noise both fit to the noise, and
            the ratio stays near 1).
        taper_pose_ratio: a reducer under the given pose fitting its returns this many times
            more closely (rms) than the structure found under a refined pose: the refinement
            leaned onto the taper, the given pose stands ...
        taper_pose_poor_support: ... when the structure under the refined pose is a reducer,
            or a turn whose fit keeps less than this fraction of its returns ...
        taper_pose_min_support: ... and the given pose's reducer keeps at least this fraction
            of its returns.
        short_wall_share_slack: a turn under the given pose may keep this much less of a share
            of its returns than the junction found under a pose refined on a short wall.
        radius_dead_band: the wall's own radius replaces the clamped one only when they differ
            by more than this (m; the clamp reading is as good as the fit within it).
        fit_step_tol: the robust fits stop when no parameter moves by more than this (m, rad):
            far below the accuracy that matters, and most fits then end in a few iterations.
        fit_anneal: the robust fits shrink their cut-off over this many iterations, then run
            to convergence ...
        fit_cost_tol: ... or until a step lowers the robust cost by less than this fraction.
        rim_ring_share, rim_cap_share, rim_share_excess, rim_margin: an end wall seen
            head-on is no cap of the incoming pipe
            (:func:`detector.axisymmetric._end_wall_seen_through`) when a ring of beams (at
            least ``rim_ring_share`` of its beams on the plane) returns from outside the rim
            where a cap would return at most ``rim_cap_share`` of it, or ``rim_share_excess``
            less than the ring does (a cap returns a ring aimed outside its rim only where the
            beams' angular jitter bends them inside it; that share is known, and a ring of a
            hundred-odd beams measures it to a few hundredths), or the ring after the
            outermost returning one, aimed inside the rim (a cap would return at least half
            of it), returns at most ``rim_cap_share`` times what a cap would; the rim
            less ``rim_margin`` (m) and the sensor's offset from the axis. It is a reducer
            then, seen through from too far for its own wall to return. Only rings spread
            across the axis by at most ``rim_ring_spread`` beam spacings (plus their noise)
            count: a tilted or offset sensor's rings straddle the rim; and only when the last
            return on the incoming wall lies at least ``rim_wall_gap`` radii before the end
            wall (a wall in view up to it shows a cap or a reducer directly).
        radius_pose_tilt, radius_pose_offset: the wall radius is measured about the pose in
            use; when the wall returns scatter about it more than a straight wall's noise
            explains, the pose may be off by a little: the first harmonic of the scatter in
            the azimuth (an offset, and a tilt growing along the axis) is fitted and left out,
            if it needs no more tilt than ``radius_pose_tilt`` (rad) and no more offset than
            ``radius_pose_offset`` radii (:func:`detector.axis_fit.measure_wall_radius`).
        profile_band, profile_ring_floor, profile_min_step, profile_min_lr, profile_min_rings:
            an end wall that passes for a cap (or is seen through a widening) is the far end
            of a reducer when the wall before it shows a step in its radial profile
            (:func:`detector.axisymmetric.wall_profile`): the median offset from the wall
            radius of each ring of beams (returns within ``profile_band`` radii of the wall;
            each ring's scatter taken as at least ``profile_ring_floor``, m: the medians of
            far rings wander by a few tenths of a millimetre) fitted with a step along a
            cone; a step of at least ``profile_min_step`` (m), better than a flat wall by
            ``profile_min_lr`` (chi-square), with at least ``profile_min_rings`` rings past
            half ``profile_min_step`` on its side.
        hole_min_step, hole_noise_k: a return enters a side hole that one ring of beams sees
            (:mod:`detector.grazing`) when it lies this far (m) beyond the wall line through
            the rings on either side, and at least ``hole_noise_k`` times its radial noise.
        hole_wall_band: the rings on either side of such a bump must lie on the wall: within
            this (m, plus ``hole_noise_k`` times their radial noise) of the run's radius.
        hole_min_returns: fewest returns (and rows of roll) in one hole's bump.
        hole_sparse_rings: holes are sought only where neighbouring rings meet the wall at
            least this many radii apart along the axis (``u^2 / R x beam step``).
        hole_max_rings: most rings of beams a hole's bump may span.
        hole_max_roll_span: a bump around more than this much of the circumference (rad) is no
            side hole.
        hole_max_fit_rms, hole_fit_noise_k: a hole's far-side fit is accepted when its returns
            lie within ``hole_max_fit_rms`` (m) and ``hole_fit_noise_k`` times their range noise
            projected on the far side's normal (rms of the ratios at most 1): the range noise
            lies along the beam and moves a return across a surface by the cosine of the
            incidence of it.
        hole_deflection_ratio: ... a branch at 45 or 135 deg replaces one at 90 deg (tees and
            crosses, tried first) only when its fit's rms is below this fraction of the 90 deg
            one's: the patch of far side a ring sees trades the deflection against the
            branch's place along the axis, and under range noise the fits differ by a few per
            cent.
        incidence_jitter_k: returns on the wall radius whose beams would meet a straight wall
            beyond the sensor's largest incidence plus this many times its beam-angle jitter
            come from a surface facing the sensor: the far side of a hole in the wall.
        hole_start_radius: a hole's far-side fit starts from a branch of this fraction of the
            run's radius ...
        hole_roll_reach: ... and may turn its roll by at most this (rad) from the roll the
            returns point to.
        hole_merge_roll: holes (and bumps) this close in roll (rad) on neighbouring rings are
            one hole.
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
    across_min_curvature_lr: float = 100.0
    far_wall_fit_points: int = 1200
    across_side_band: float = 0.6
    across_side_roll: float = math.radians(45.0)
    across_wall_k: float = 3.0
    across_view_band: float = 2.5
    opposite_max_off_square: float = math.radians(15.0)
    opposite_max_off_oblique: float = math.radians(15.0)
    opposite_side_roll: float = math.radians(30.0)
    opposite_noise_k: float = 3.0
    opposite_min_share: float = 0.5
    opposite_baseline_factor: float = 4.0
    opposite_wall_share: float = 0.5
    all_round: float = 0.75
    all_round_sectors: int = 24
    snap_within: float = math.radians(25.0)
    snap_lr: float = 10.0
    snap_max_turn: float = math.radians(3.0)
    snap_radius: float = 0.03
    deflection_min: float = math.radians(25.0)
    deflection_max: float = math.radians(150.0)
    torus_try_support: float = 0.95
    torus_polish_max_noise: float = 0.001
    cone_plateau_margin: float = 0.0015
    cone_min_rise: float = 0.002
    cone_line_scatter: float = 0.00015
    cone_first_ring: float = 0.01
    cone_min_returns: int = 6
    cone_ring_coverage: float = 0.75
    hinge_reach: float = 0.15
    hinge_min_snr: float = 4.0
    hinge_min_rise: float = 0.0005
    pose_no_wall_view: float = 0.01
    pose_given_margin: float = 0.02
    blind_min_expected: int = 200
    blind_max_ahead: float = 0.01
    blind_confidence: float = 0.5
    short_wall_view: float = 0.05
    long_wall_span: float = 0.1
    long_wall_rms: float = 0.25
    short_wall_given_share: float = 0.8
    outlet_inside_share: float = 0.6
    outlet_min_returns: int = 100
    outlet_fit_scale: float = 0.002
    outlet_fits: int = 2
    outlet_from: float = 50.0
    outlet_until: float = 85.0
    outlet_max_tilt: float = math.radians(8.0)
    near_wall: float = 0.03
    gentle_start_margin: float = 0.01
    torus_pose_ratio: float = 1.5
    taper_pose_ratio: float = 1.25
    taper_pose_poor_support: float = 0.6
    taper_pose_min_support: float = 0.9
    short_wall_share_slack: float = 0.02
    radius_dead_band: float = 0.00025
    fit_step_tol: float = 1e-6
    fit_anneal: int = 3
    fit_cost_tol: float = 1e-4
    rim_ring_share: float = 0.3
    rim_cap_share: float = 0.25
    rim_share_excess: float = 0.2
    rim_margin: float = 0.0005
    rim_ring_spread: float = 0.5
    rim_wall_gap: float = 1.0
    radius_pose_tilt: float = math.radians(2.0)
    radius_pose_offset: float = 0.05
    profile_band: float = 0.4
    profile_ring_floor: float = 0.0003
    profile_min_step: float = 0.002
    profile_min_lr: float = 25.0
    profile_min_rings: int = 3
    hole_min_step: float = 0.00035
    hole_noise_k: float = 3.0
    hole_wall_band: float = 0.002
    hole_min_returns: int = 6
    hole_sparse_rings: float = 0.25
    hole_max_rings: int = 3
    hole_max_roll_span: float = math.radians(200.0)
    hole_max_fit_rms: float = 0.002
    hole_fit_noise_k: float = 2.0
    hole_deflection_ratio: float = 0.8
    incidence_jitter_k: float = 3.0
    hole_start_radius: float = 0.8
    hole_roll_reach: float = 0.6
    hole_merge_roll: float = math.radians(45.0)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            kind, low, low_included, high, allowed = _ALLOWED[f.name]
            ok = isinstance(value, numbers.Integral if kind is int else numbers.Real)
            ok = ok and not isinstance(value, bool)
            if ok:
                v = kind(value)
                ok = math.isfinite(v) and (v >= low if low_included else v > low) and v <= high
            if not ok:
                raise fail(f.name, value, allowed, "out of range or wrong type", "ImprovedConfig")
            object.__setattr__(self, f.name, kind(value))
        if self.outlet_from >= self.outlet_until:
            raise fail(
                "outlet_from",
                self.outlet_from,
                f"a number below outlet_until ({self.outlet_until})",
                "the outlet's percentile band is empty",
                "ImprovedConfig",
            )


#: Allowed values of each :class:`ImprovedConfig` field: (type, lower bound, lower bound
#: allowed, upper bound, description).
_ALLOWED: dict[str, tuple[type, float, bool, float, str]] = {
    "tol_floor": (float, 0.0, False, 1.0, "a number in (0, 1] m"),
    "axis_slope": (float, 0.0, True, 1.0, "a number in [0, 1] (m per m)"),
    "noise_k": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "min_lobe_points": (int, 1, True, math.inf, "an integer >= 1"),
    "min_region_rows": (int, 1, True, math.inf, "an integer >= 1"),
    "min_anomaly_points": (int, 1, True, math.inf, "an integer >= 1"),
    "horizon": (float, 0.0, False, 100.0, "a number in (0, 100] m"),
    "fit_points": (int, 10, True, math.inf, "an integer >= 10"),
    "axis_points": (int, 10, True, math.inf, "an integer >= 10"),
    "prior_offset": (float, 0.0, False, 1.0, "a number in (0, 1] m"),
    "prior_tilt": (float, 0.0, False, math.pi / 2, "a number in (0, pi/2] rad"),
    "straight_on_coverage": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "radius_lr_per_branch": (float, 0.0, True, math.inf, "a finite number >= 0"),
    "max_radius_correction": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "far_wall_min_lean": (float, 0.0, True, 100.0, "a number in [0, 100] (radii)"),
    "across_side_band": (float, 0.0, False, 10.0, "a number in (0, 10] (radii)"),
    "across_side_roll": (float, 0.0, False, math.pi, "an angle in (0, pi] rad"),
    "across_wall_k": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "across_view_band": (float, 1.0, False, 100.0, "a number in (1, 100] (radii)"),
    "far_wall_fit_points": (int, 10, True, 100000, "an integer in [10, 100000]"),
    "across_min_curvature_lr": (float, 0.0, True, 1e6, "a number in [0, 1e6]"),
    "opposite_max_off_square": (float, 0.0, True, math.pi / 2, "an angle in [0, pi/2] rad"),
    "opposite_max_off_oblique": (float, 0.0, True, math.pi / 8, "an angle in [0, pi/8] rad"),
    "opposite_side_roll": (float, 0.0, False, math.pi / 2, "an angle in (0, pi/2] rad"),
    "opposite_noise_k": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "opposite_min_share": (float, 0.0, True, 10.0, "a number in [0, 10]"),
    "opposite_baseline_factor": (float, 0.0, True, 1000.0, "a number in [0, 1000]"),
    "opposite_wall_share": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "all_round": (float, 0.0, False, 1.0, "a number in (0, 1]"),
    "all_round_sectors": (int, 4, True, 360, "an integer in [4, 360]"),
    "snap_within": (float, 0.0, True, math.pi / 2, "a number in [0, pi/2] rad"),
    "snap_lr": (float, 0.0, True, math.inf, "a finite number >= 0"),
    "snap_max_turn": (float, 0.0, True, math.pi, "a number in [0, pi] rad"),
    "snap_radius": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "deflection_min": (float, 0.0, True, math.pi / 2, "a number in [0, pi/2] rad"),
    "deflection_max": (float, math.pi / 2, True, math.pi, "a number in [pi/2, pi] rad"),
    "torus_try_support": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "torus_polish_max_noise": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "cone_plateau_margin": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "cone_min_rise": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "cone_line_scatter": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "cone_first_ring": (float, 0.0, False, 1.0, "a number in (0, 1] m"),
    "cone_min_returns": (int, 1, True, math.inf, "an integer >= 1"),
    "cone_ring_coverage": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "hinge_reach": (float, 0.0, True, 10.0, "a number in [0, 10] m"),
    "hinge_min_snr": (float, 0.0, True, math.inf, "a finite number >= 0"),
    "hinge_min_rise": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "pose_no_wall_view": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "pose_given_margin": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "blind_min_expected": (int, 1, True, math.inf, "an integer >= 1"),
    "blind_max_ahead": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "blind_confidence": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "short_wall_view": (float, 0.0, True, 10.0, "a number in [0, 10] m"),
    "long_wall_span": (float, 0.0, True, 10.0, "a number in [0, 10] m"),
    "long_wall_rms": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "short_wall_given_share": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "outlet_inside_share": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "outlet_min_returns": (int, 1, True, math.inf, "an integer >= 1"),
    "outlet_fit_scale": (float, 0.0, False, 1.0, "a number in (0, 1] m"),
    "outlet_fits": (int, 1, True, 10, "an integer in [1, 10]"),
    "outlet_from": (float, 0.0, True, 100.0, "a number in [0, 100] (%)"),
    "outlet_until": (float, 0.0, True, 100.0, "a number in [0, 100] (%)"),
    "outlet_max_tilt": (float, 0.0, False, math.pi / 2, "a number in (0, pi/2] rad"),
    "near_wall": (float, 0.0, True, 10.0, "a number in [0, 10] m"),
    "gentle_start_margin": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "torus_pose_ratio": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "taper_pose_ratio": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "taper_pose_poor_support": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "taper_pose_min_support": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "short_wall_share_slack": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "radius_dead_band": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "fit_step_tol": (float, 0.0, False, 1.0, "a number in (0, 1] (m, rad)"),
    "fit_anneal": (int, 1, True, math.inf, "an integer >= 1"),
    "fit_cost_tol": (float, 0.0, True, 1.0, "a number in [0, 1]"),
    "rim_ring_share": (float, 0.0, False, 1.0, "a number in (0, 1]"),
    "rim_cap_share": (float, 0.0, True, 0.5, "a number in [0, 0.5]"),
    "rim_share_excess": (float, 0.0, False, 1.0, "a number in (0, 1]"),
    "rim_margin": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "rim_ring_spread": (float, 0.0, True, 100.0, "a number in [0, 100] (beam spacings)"),
    "rim_wall_gap": (float, 0.0, True, 1000.0, "a number in [0, 1000] (radii)"),
    "radius_pose_tilt": (float, 0.0, True, 0.5 * math.pi, "a number in [0, pi/2] rad"),
    "radius_pose_offset": (float, 0.0, True, 1.0, "a number in [0, 1] (radii)"),
    "profile_band": (float, 0.0, False, 1.0, "a number in (0, 1] (radii)"),
    "profile_ring_floor": (float, 0.0, False, 1.0, "a number in (0, 1] m"),
    "profile_min_step": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "profile_min_lr": (float, 0.0, True, math.inf, "a finite number >= 0"),
    "profile_min_rings": (int, 1, True, math.inf, "an integer >= 1"),
    "hole_min_step": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "hole_noise_k": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "hole_wall_band": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "hole_min_returns": (int, 1, True, math.inf, "an integer >= 1"),
    "hole_sparse_rings": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "hole_max_rings": (int, 1, True, math.inf, "an integer >= 1"),
    "hole_max_roll_span": (float, 0.0, True, 2.0 * math.pi, "a number in [0, 2 pi] rad"),
    "hole_max_fit_rms": (float, 0.0, True, 1.0, "a number in [0, 1] m"),
    "hole_fit_noise_k": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "hole_deflection_ratio": (float, 0.0, False, 1.0, "a number in (0, 1]"),
    "incidence_jitter_k": (float, 0.0, True, 100.0, "a number in [0, 100]"),
    "hole_start_radius": (float, 0.2, True, 1.05, "a number in [0.2, 1.05] (radii)"),
    "hole_roll_reach": (float, 0.0, True, math.pi, "a number in [0, pi] rad"),
    "hole_merge_roll": (float, 0.0, True, math.pi, "a number in [0, pi] rad"),
}


DEFAULT_CONFIG = ImprovedConfig()
