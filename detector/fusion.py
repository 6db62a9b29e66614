"""Multi-scan fusion: a tracker that turns per-scan detections into one confirmed structure.

While the robot drives towards a structure it scans it many times; single scans can be wrong
(noise, a first glimpse from far away) and, very close to the structure, the detector no longer
sees its outline (thesis 5.1.2: a bend seen from too close becomes a "type 1"). The tracker:

- **Anchors estimates in the odometry frame.** Each detection arrives with the robot's believed
  sensor pose (``sensor_position`` (3,), ``sensor_rotation`` (3, 3) world-from-sensor). Its
  reference point becomes a world point (sensor origin + distance along the pipe axis) and each
  way on a world direction (its angle is the deflection from the fitted pipe axis, its
  direction the roll about that axis, as :mod:`detector.options` defines them). Estimates
  from different scans can then be compared and averaged, and the fused structure is
  re-expressed relative to the latest pose (distance along the axis from the current sensor
  origin, direction as atan2(z, y) in the current sensor frame).
- **Weights nearer scans more** (thesis 5.3's trust factor): a scan's weight is its confidence
  divided by ``max(distance, near_distance)^4``, an inverse-variance weight: the beams of a
  sweep meet the wall ``distance^2 / R`` x the beam step apart along the axis, so the error of
  an edge or a reference point grows with the square of the distance. A scan at 20 cm counts
  16 times as much as one at 40 cm (with the square, a few scans from 45 cm placed a 60 mm tee
  4 mm too far, enough for the turn into its branch to jam).
- **Reports the ways on that enough scans saw.** A way is reported when the scans that saw it
  number at least ``way_min_hits`` (all of the track's scans if it has fewer) and carry at least
  ``way_share`` of the track's trust weight, or number ``way_keep_hits`` from within
  ``way_keep_reach`` (unless it lies within twice ``direction_gate`` of a way reported for its
  weight: another reading of the same way). A single near scan outweighs several far ones, so
  alone it decided which ways exist: a phantom way in the last scan turned a long bend into a
  junction, a misread branch turned a tee into a bend. Close up the detector loses a tee's
  branch seen from its stem more often than it invents one consistently over three scans.
- **Associates** a detection with the track when its kind family (closure, reducer, bend or
  junction) agrees and its reference point lies within ``gate`` (+ ``gate_growth`` times the
  distance) of the track's. Ways on are matched by direction (within ``direction_gate``).
- **Confirms with hysteresis.** Each consistent detection adds its confidence to the track's
  evidence, each inconsistent or straight detection (while the structure should be visible)
  removes ``miss_penalty``. A track is *confirmed* once its evidence reaches ``confirm_evidence``
  from at least ``confirm_count`` consistent detections; it is dropped only when its evidence
  falls to zero (a confirmed track first has to lose it all, a tentative one is replaced by a
  better-supported newcomer).
- **Confirms from one place only what was seen there from elsewhere.** A new track is
  *contested* unless scans from other places saw a structure at its reference point (within
  the gate) and none saw one beyond it (a structure appearing short of where the robot saw one
  on its way); only scans that saw their structure within ``contest_range`` count. A contested
  track's detections must come from at least ``contested_places`` places ``place_spacing``
  apart to confirm it. Sweeps repeated where the robot stands (rescans before a near
  structure) repeat a detector's systematic error (a long bend's exit or straight approach read
  as a junction 10 cm ahead), so alone they confirm only what the robot saw on its way there.
- **Lets nearer scans overrule.** Disagreeing detections are fused into a *challenger* track; once
  the challenger has ``confirm_count - 1`` consistent detections and more trust weight than the
  track (nearer scans weigh more), it replaces the track: a tee seen from its stem that looked
  like a closure from 45 cm is a junction once the scans from 30 and 20 cm agree on it.
  A reducer challenger does not replace a confirmed junction: from close up a branch's mouth
  beside the way straight on reads as a widening (a 78 mm wye seen from 37 and 32 cm read as a
  reducer to 118 mm from 26 and 20 cm, and the robot drove past the branch by itself).
- **Hands over** near the structure: when the fused reference point is closer than
  ``handover_distance`` (the detector's blind zone, about one diameter), detections that
  disagree ("straight", a closure-like reading, or nothing) are ignored; the confirmed estimate
  is kept and propagated by odometry (its world anchor stays, the reported distance shrinks as
  the robot moves).
- **Finishes** a track once the sensor has passed its reference point by ``pass_margin``; the
  tracker is then empty, ready for the next structure.

Units: metres and radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from detector.detection import Detection
from detector.options import StructureOption, option_order
from detector.validation import check_int, check_number
from detector.vocab import Kind

#: Ways on deflected less than this count as straight on (their direction is 0), radians.
STRAIGHT_ON = math.radians(2.0)

#: A scan's trust weight (geometry) is its confidence over its distance to this power
#: (dimensionless): an inverse-variance weight, see the module docstring.
TRUST_POWER = 4
#: Confidences below this (dimensionless) count as this in the trust weight.
MIN_CONFIDENCE = 1e-3

_FAMILY = {"closure": "end", "reducer": "reducer", "bend": "turn", "junction": "turn"}


@dataclass(eq=False)
class _Way:
    """One way on of a track, in the world frame, as weighted sums."""

    vec_sum: NDArray[np.float64]  # weighted sum of unit outgoing directions (world)
    diam_sum: float
    weight: float
    hits: int
    #: scans within ``way_keep_reach`` that saw this way
    near_hits: int = 0
    radius_sum: float = 0.0  # weighted sum of long-bend radii, over the scans that gave one
    radius_weight: float = 0.0

    def add(
        self, v: NDArray[np.float64], diameter: float, radius: float, w: float, near: bool
    ) -> None:
        self.vec_sum = self.vec_sum + v * w
        self.diam_sum += diameter * w
        self.weight += w
        self.hits += 1
        self.near_hits += int(near)
        if radius > 0.0:
            self.radius_sum += radius * w
            self.radius_weight += w

    @property
    def direction(self) -> NDArray[np.float64]:
        n = float(np.linalg.norm(self.vec_sum))
        return self.vec_sum / n if n > 0 else np.array([1.0, 0.0, 0.0])

    @property
    def diameter(self) -> float:
        return self.diam_sum / self.weight if self.weight > 0 else 0.0

    @property
    def bend_radius(self) -> float:
        """A long bend's radius (m) if the scans giving one carry half the weight, else 0."""
        if self.radius_weight <= 0.0 or 2.0 * self.radius_weight < self.weight:
            return 0.0
        return self.radius_sum / self.radius_weight


def _separation(a: _Way, b: _Way) -> float:
    """Angle between the directions of two ways, radians."""
    return math.acos(max(-1.0, min(1.0, float(a.direction @ b.direction))))


def _new_way(v: NDArray[np.float64], diameter: float, radius: float, w: float, near: bool) -> _Way:
    way = _Way(np.zeros(3), 0.0, 0.0, 0)
    way.add(v, diameter, radius, w, near)
    return way


@dataclass
class _Track:
    family: str
    ref_sum: NDArray[np.float64]
    axis_sum: NDArray[np.float64]
    weight: float
    ways: list[_Way]
    kind_weight: dict[str, float]
    evidence: float = 0.0
    hits: int = 0
    confirmed: bool = False
    #: sensor positions (odometry frame) the detections came from, one per place
    places: list[NDArray[np.float64]] = field(default_factory=list)
    #: places needed to confirm (more for a contested track)
    min_places: int = 1

    def seen_from(self, pos: NDArray[np.float64], spacing: float) -> None:
        """Count ``pos`` as a new place unless it is within ``spacing`` of a known one."""
        if all(float(np.linalg.norm(pos - p)) > spacing for p in self.places):
            self.places.append(pos.copy())

    @property
    def reference(self) -> NDArray[np.float64]:
        return self.ref_sum / self.weight

    @property
    def axis(self) -> NDArray[np.float64]:
        n = float(np.linalg.norm(self.axis_sum))
        return self.axis_sum / n if n > 0 else np.array([1.0, 0.0, 0.0])

    @property
    def kind(self) -> str:
        return max(self.kind_weight.items(), key=lambda kv: kv[1])[0]


@dataclass(frozen=True)
class TrackState:
    """What the tracker believes after an update.

    Attributes:
        confirmed: a structure is confirmed ahead.
        detection: the fused detection relative to the latest sensor pose (``straight`` when no
            structure is tracked).
        confidence: in [0, 1], the track's evidence relative to the confirmation threshold.
        n_updates: consistent detections fused into the current track.
        handed_over: the structure is too close to be seen; the estimate is propagated by
            odometry.
        reference_world: (3,) fused reference point in the odometry frame, or None.
    """

    confirmed: bool
    detection: Detection
    confidence: float
    n_updates: int
    handed_over: bool = False
    reference_world: NDArray[np.float64] | None = None
    info: dict[str, Any] = field(default_factory=dict)


class StructureTracker:
    """Fuses per-scan detections of the structure ahead (see module docstring).

    Args:
        confirm_count: consistent detections needed to confirm.
        confirm_evidence: evidence (sum of confidences minus penalties) needed to confirm.
        miss_penalty: evidence lost per inconsistent or straight detection.
        gate: association distance of reference points, metres (+ ``gate_growth`` times the
            distance).
        direction_gate: association angle of ways on, radians.
        near_distance: distances below this weigh like this one, metres.
        handover_distance: closer than this, disagreeing detections are ignored, metres.
        pass_margin: the track ends once the sensor is this far past the reference point, m.
        contested_places: distinct places a contested track's consistent detections must come
            from to confirm it (at most ``confirm_count``); see the module docstring.
        place_spacing: sensor positions closer than this count as one place, m.
        contest_range: earlier scans contest a new track with structures they saw at most this
            far ahead, m.
        way_min_hits: scans that must have seen a way on for it to be reported (fewer if the
            track has fewer scans).
        way_share: share of the track's trust weight (0-1] the scans that saw a way must carry.
        way_keep_hits: a way seen by this many scans is reported whatever its share.
        way_keep_reach: only scans of a structure at most this far ahead count towards
            ``way_keep_hits``, m: from farther, a mitre bend's far wall can read as a second
            way on for several scans in a row (a bend at the end of a long straight, swept
            from 1.2 m).
        gate_growth: the association gates grow by this many metres per metre of distance.
    """

    def __init__(
        self,
        confirm_count: int = 3,
        confirm_evidence: float = 1.5,
        miss_penalty: float = 0.5,
        gate: float = 0.05,
        direction_gate: float = math.radians(25.0),
        near_distance: float = 0.1,
        handover_distance: float = 0.12,
        pass_margin: float = 0.05,
        contested_places: int = 2,
        place_spacing: float = 0.01,
        contest_range: float = 0.5,
        way_min_hits: int = 2,
        way_share: float = 0.5,
        way_keep_hits: int = 3,
        way_keep_reach: float = 0.5,
        gate_growth: float = 0.1,
    ) -> None:
        where = "StructureTracker"
        for name, value, unit in (
            ("confirm_evidence", confirm_evidence, ""),
            ("miss_penalty", miss_penalty, ""),
            ("gate", gate, "m"),
            ("direction_gate", direction_gate, "rad"),
            ("near_distance", near_distance, "m"),
            ("handover_distance", handover_distance, "m"),
            ("pass_margin", pass_margin, "m"),
            ("place_spacing", place_spacing, "m"),
            ("contest_range", contest_range, "m"),
            ("gate_growth", gate_growth, "m/m"),
            ("way_keep_reach", way_keep_reach, "m"),
        ):
            check_number(name, value, 0.0, None, unit, open_low=True, where=where)
        self.confirm_count = check_int("confirm_count", confirm_count, 1, where=where)
        self.way_min_hits = check_int("way_min_hits", way_min_hits, 1, where=where)
        self.way_keep_hits = check_int("way_keep_hits", way_keep_hits, 1, where=where)
        self.way_share = check_number("way_share", way_share, 0.0, 1.0, open_low=True, where=where)
        self.gate_growth = float(gate_growth)
        self.way_keep_reach = float(way_keep_reach)
        contested_places = check_int("contested_places", contested_places, 1, where=where)
        self.contested_places = int(contested_places)
        self.place_spacing = float(place_spacing)
        self.contest_range = float(contest_range)
        #: (sensor position, reference point) of the scans that saw a structure since reset
        self._seen: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
        self.confirm_evidence = float(confirm_evidence)
        self.miss_penalty = float(miss_penalty)
        self.gate = float(gate)
        self.direction_gate = float(direction_gate)
        self.near_distance = float(near_distance)
        self.handover_distance = float(handover_distance)
        self.pass_margin = float(pass_margin)
        self._track: _Track | None = None
        self._challenger: _Track | None = None
        self._last_pose: tuple[NDArray, NDArray] | None = None

    def reset(self) -> None:
        """Forget the tracked structure."""
        self._track = None
        self._challenger = None
        self._last_pose = None
        self._seen = []

    # ---------------------------------------------------------------- update
    def update(
        self, detection: Detection, sensor_position: ArrayLike, sensor_rotation: ArrayLike
    ) -> TrackState:
        """Fuse one detection made at the given believed sensor pose (world-from-sensor)."""
        pos = np.asarray(sensor_position, dtype=float).reshape(-1)
        rot = np.asarray(sensor_rotation, dtype=float)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ValueError(f"sensor_position must be 3 finite numbers, got {pos!r}")
        if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
            raise ValueError(
                f"sensor_rotation must be a finite 3x3 matrix, got shape {rot.shape}"
                + ("" if rot.shape != (3, 3) else f" with non-finite entries {rot.tolist()}")
            )
        if not isinstance(detection, Detection):
            raise ValueError(f"detection must be a Detection, got {type(detection).__name__}")
        self._last_pose = (pos, rot)
        tr = self._track
        # finished: the sensor passed the structure
        if tr is not None and self._distance(tr, pos) < -self.pass_margin:
            self._track = tr = None
            self._challenger = None
        handed_over = False
        if detection.kind == Kind.STRAIGHT or not detection.options:
            if tr is not None:
                if self._distance(tr, pos) <= self.handover_distance and tr.confirmed:
                    handed_over = True
                else:
                    tr.evidence -= self.miss_penalty
                    if tr.evidence <= 0.0:
                        self._track = tr = None
            return self._state(handed_over)
        obs = self._observation(detection, pos, rot)
        handed_over = self._update_with(obs, pos)
        if float((obs["near_ref"] - pos) @ obs["axis"]) <= self.contest_range:
            self._seen.append((pos.copy(), obs["near_ref"].copy()))
        return self._state(handed_over)

    def _update_with(self, obs: dict[str, Any], pos: NDArray[np.float64]) -> bool:
        """Associate a structure detection with the track, the challenger or a new track;
        True if the track was handed over (the detection ignored near the structure)."""
        tr = self._track
        handed_over = False
        if tr is None:
            self._track = self._new_track(obs)
        elif self._consistent(tr, obs):
            self._fuse(tr, obs)
        else:
            near = self._distance(tr, pos) <= self.handover_distance
            if tr.confirmed and near:
                handed_over = True  # too close to see it: keep the confirmed estimate
            else:
                tr.evidence -= self.miss_penalty
                challenger = self._challenge(obs)
                if tr.evidence <= 0.0 or (not tr.confirmed and obs["weight"] > tr.weight):
                    self._track = self._new_track(obs)
                    self._challenger = None
                elif (
                    challenger.hits >= self.confirm_count - 1
                    and challenger.weight > tr.weight
                    and not self._keeps_branch(tr, challenger)
                ):
                    self._track = challenger
                    self._challenger = None
        tr = self._track
        if tr is not None and not tr.confirmed:
            tr.confirmed = (
                tr.hits >= self.confirm_count
                and tr.evidence >= self.confirm_evidence
                and len(tr.places) >= min(tr.min_places, self.confirm_count)
            )
        return handed_over

    # ---------------------------------------------------------------- internals
    def _challenge(self, obs: dict[str, Any]) -> _Track:
        """Fuse a detection that disagrees with the track into the challenger track."""
        ch = self._challenger
        if ch is None or not self._consistent(ch, obs):
            ch = self._challenger = self._new_track(obs)
        else:
            self._fuse(ch, obs)
        return ch

    def _observation(self, det: Detection, pos: NDArray, rot: NDArray) -> dict[str, Any]:
        axis_s = np.asarray(det.diagnostics.get("pipe_axis_sensor") or [1.0, 0.0, 0.0], float)
        if axis_s.shape != (3,) or not np.all(np.isfinite(axis_s)):
            axis_s = np.array([1.0, 0.0, 0.0])
        axis_s = axis_s / np.linalg.norm(axis_s)
        dist = float(np.mean([o.distance for o in det.options]))
        axis_w = rot @ axis_s
        ref = pos + dist * axis_w
        # an option's angle is its deflection from the incoming pipe's axis, not from the
        # sensor's x axis (a sensor tilted in the pipe would add its tilt to every turn); its
        # direction is the roll about that axis, zero towards the sensor's y
        e_y = np.array([0.0, 1.0, 0.0]) - axis_s[1] * axis_s
        e_y /= np.linalg.norm(e_y)
        e_z = np.cross(axis_s, e_y)
        ways = []
        for o in det.options:
            v = math.cos(o.angle) * axis_s + math.sin(o.angle) * (
                math.cos(o.direction) * e_y + math.sin(o.direction) * e_z
            )
            ways.append((rot @ v, o.diameter, o.bend_radius))
        conf = max(det.confidence, MIN_CONFIDENCE)
        w = conf / max(abs(dist), self.near_distance) ** TRUST_POWER
        return {
            "family": _FAMILY.get(det.kind, det.kind),
            "kind": det.kind,
            "ref": ref,
            "axis": axis_w,
            "ways": ways,
            "weight": w,
            "confidence": det.confidence,
            "distance": dist,
            "pos": pos,
            # the nearest way's reference point (a thesis detection may place ways apart)
            "near_ref": pos + min(o.distance for o in det.options) * axis_w,
        }

    def _keeps_branch(self, tr: _Track, challenger: _Track) -> bool:
        """True if ``tr`` is a confirmed junction (more than one way on reported) and
        ``challenger`` a reducer: from close up a branch's mouth beside the way straight on
        reads as a widening of the pipe, so nearer reducer scans do not overrule the junction
        (its evidence still drains with every scan that disagrees)."""
        return (
            tr.confirmed
            and tr.family == _FAMILY["junction"]
            and challenger.family == _FAMILY["reducer"]
            and len(self._kept_ways(tr)) > 1
        )

    def _contested(self, obs: dict[str, Any]) -> bool:
        """True unless scans from another place saw a structure where this one is and none
        saw one beyond it."""
        gate = self.gate + self.gate_growth * abs(obs["distance"])
        elsewhere = [
            float((ref - obs["near_ref"]) @ obs["axis"])
            for p, ref in self._seen
            if float(np.linalg.norm(p - obs["pos"])) > self.place_spacing
        ]
        return not any(abs(d) <= gate for d in elsewhere) or any(d > gate for d in elsewhere)

    def _new_track(self, obs: dict[str, Any]) -> _Track:
        w = obs["weight"]
        return _Track(
            family=obs["family"],
            ref_sum=obs["ref"] * w,
            axis_sum=obs["axis"] * w,
            weight=w,
            ways=[_new_way(v, d, rb, w, self._near(obs)) for v, d, rb in obs["ways"]],
            kind_weight={obs["kind"]: w},
            evidence=obs["confidence"],
            hits=1,
            places=[obs["pos"].copy()],
            min_places=self.contested_places if self._contested(obs) else 1,
        )

    def _consistent(self, tr: _Track, obs: dict[str, Any]) -> bool:
        if tr.family != obs["family"]:
            return False
        gate = self.gate + self.gate_growth * abs(obs["distance"])
        return float(np.linalg.norm(obs["ref"] - tr.reference)) <= gate

    def _fuse(self, tr: _Track, obs: dict[str, Any]) -> None:
        w = obs["weight"]
        tr.ref_sum = tr.ref_sum + obs["ref"] * w
        tr.axis_sum = tr.axis_sum + obs["axis"] * w
        tr.weight += w
        tr.kind_weight[obs["kind"]] = tr.kind_weight.get(obs["kind"], 0.0) + w
        tr.evidence += obs["confidence"]
        tr.hits += 1
        tr.seen_from(obs["pos"], self.place_spacing)
        for v, d, rb in obs["ways"]:
            best, best_ang = None, math.inf
            for way in tr.ways:
                ang = math.acos(max(-1.0, min(1.0, float(way.direction @ v))))
                if ang < best_ang:
                    best, best_ang = way, ang
            if best is not None and best_ang <= self.direction_gate:
                best.add(v, d, rb, w, self._near(obs))
            else:
                tr.ways.append(_new_way(v, d, rb, w, self._near(obs)))

    def _near(self, obs: dict[str, Any]) -> bool:
        """Whether a scan is near enough for its ways to count towards ``way_keep_hits``."""
        return abs(float(obs["distance"])) <= self.way_keep_reach

    def _kept_ways(self, tr: _Track) -> list[_Way]:
        """The ways on a track reports: those seen by at least ``way_min_hits`` of its scans
        (all of them if it has fewer) whose scans carry at least ``way_share`` of the track's
        trust weight, and those seen by ``way_keep_hits`` scans within ``way_keep_reach``
        however many missed them
        (unless within twice ``direction_gate`` of a way kept for its weight). A way
        glimpsed from far away is dropped once nearer scans disagree; a way one near scan
        invents is dropped while the other scans do not see it; a branch seen consistently
        is kept when the detector loses it close up (a tee seen from its stem). If none
        qualifies, the way with the most weight."""
        if len(tr.ways) == 1:
            return list(tr.ways)
        need = min(self.way_min_hits, tr.hits)
        weighty = [w for w in tr.ways if w.weight >= self.way_share * tr.weight and w.hits >= need]
        # a way kept for its hits alone must not be another reading of a weighty one (a branch
        # seen at 60 deg from far, at 90 deg from near: the nearer reading supersedes)
        seen = [
            w
            for w in tr.ways
            if w not in weighty
            and w.near_hits >= self.way_keep_hits
            and all(_separation(w, v) > 2.0 * self.direction_gate for v in weighty)
        ]
        return weighty + seen or [max(tr.ways, key=lambda w: w.weight)]

    def _distance(self, tr: _Track, pos: NDArray) -> float:
        return float((tr.reference - pos) @ tr.axis)

    def _state(self, handed_over: bool) -> TrackState:
        tr = self._track
        if tr is None or self._last_pose is None:
            return TrackState(False, Detection.straight(confidence=0.5), 0.0, 0, False, None)
        pos, rot = self._last_pose
        dist = self._distance(tr, pos)
        ways = self._kept_ways(tr)
        kind = tr.kind
        if kind in (Kind.BEND, Kind.JUNCTION):
            kind = "junction" if len(ways) > 1 else "bend"
        opts = []
        conf = min(1.0, tr.evidence / self.confirm_evidence)
        for way in ways:
            v_s = rot.T @ way.direction
            axis_s = rot.T @ tr.axis
            angle = math.acos(max(-1.0, min(1.0, float(v_s @ axis_s))))
            perp = v_s - (v_s @ axis_s) * axis_s
            # a way straight on has no direction (0 by convention)
            direction = math.atan2(float(perp[2]), float(perp[1])) if angle > STRAIGHT_ON else 0.0
            if kind == Kind.CLOSURE:
                angle, direction = 0.0, 0.0
            diameter = 0.0 if kind == Kind.CLOSURE else max(0.0, way.diameter)
            radius = way.bend_radius if kind == Kind.BEND else 0.0
            opts.append(
                StructureOption(kind, dist, diameter, direction, angle, conf, bend_radius=radius)
            )
        opts.sort(key=option_order)
        det = Detection(
            kind,
            opts,
            conf,
            {
                "fused_scans": tr.hits,
                "evidence": tr.evidence,
                "handed_over": handed_over,
                "track_weight": tr.weight,
            },
        )
        return TrackState(tr.confirmed, det, conf, tr.hits, handed_over, tr.reference.copy())
