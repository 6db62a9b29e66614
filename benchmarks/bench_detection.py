"""Accuracy study of the structure detectors: the thesis's method against the improved one.

Reproduces the thesis experiments (its table 4.1) and extends them:

- 2D (thesis Algorithm 1, horizontal plane): 90 deg mitre bends to the right in 60 and 100 mm
  pipes;
- 3D (thesis Algorithm 2 vs the improved method): a 45 % reduction over 20 cm in a 100 mm pipe,
  45 and 90 deg mitre bends and an X (cross) junction in 100 mm; plus T junctions (from the stem
  and along the run), Y junctions (along the run and from the branch), long-radius bends,
  closures, reducers, at every diameter of the robot's range with random roll directions;
- the sensor from 40 cm down to 10 cm before the structure (the thesis window), in the incoming
  pipe: a long bend's reference point (where its centrelines meet) lies ``R tan(angle / 2)``
  past the start of its arc, and positions inside the arc are skipped (the straight line of
  the incoming axis leaves the pipe there; the count is reported);
- the ideal sensor, then ``ydlidar_x4`` and ``ls02`` noise, then misalignment (sensor offset up to
  20 % of D and tilt up to 4 deg, thesis 5.3), then a clamped diameter off by up to 2 mm (the
  clamp's encoder error);
- false alarms on straight pipe;
- more long bends (three per diameter, from their own draw), whose far arc may be out of sight:
  their figures are also split by whether the returns reach the end of the arc (the angle is
  in the scan) or not (only a lower bound of it is).

Ground truth is ``PipeNetwork.structures_ahead`` at the true sensor pose. Per kind: the
classification accuracy (kind and number of ways on both right), mean and max |error| of
distance, diameter, angle and direction over correctly classified scans (direction only for ways
that deflect by more than 10 deg), false alarms per 1000 straight-pipe scans, and scans/s per
method (detection only, one core, same scans). Per sensor, over all kinds: how many correctly
classified scans are beyond the thesis's requirements (distance 2 cm, angle and direction
5 deg).

Writes ``results/detection/report.md`` (the tables), ``fig_5_2_estimates_vs_position.png`` and
``fig_5_3_misalignment.png``. ``--quick`` runs a small subset (about a minute). To iterate on
one kind: ``--kinds reducer --sensors ydlidar_x4,ls02 --parts accuracy`` runs the main 3D
tables only, for those rows and sensors (the layouts are drawn as in the full run, but the
scans' noise is drawn in a different order, so the figures are of the same cases, not the
same scans).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

if __name__ == "__main__":
    # The speed figure is per core: numerical libraries run one thread unless told otherwise
    # (set before numpy loads them; an explicit setting in the environment wins).
    for _threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_threads, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from detector import METHODS, detect, detect_planar  # noqa: E402
from detector.atomic import atomic_write_text  # noqa: E402
from detector.detection import Detection  # noqa: E402
from detector.geometry import Pose  # noqa: E402
from detector.options import StructureOption  # noqa: E402
from detector.scan import Scan  # noqa: E402
from pipe_env import layouts  # noqa: E402
from pipe_env.lidar import RotatingLidar  # noqa: E402
from pipe_env.plotting import save_figure  # noqa: E402
from pipe_env.world import build_world  # noqa: E402

DIAMETERS_FULL = (0.057, 0.075, 0.1, 0.125)
DIAMETERS_QUICK = (0.057, 0.1)
SENSORS = ("ideal", "ydlidar_x4", "ls02")
#: the study's parts, for ``--parts``
PARTS = ("planar", "accuracy", "misalignment", "clamp", "false-alarms", "long-bends", "speed")


@dataclass
class Case:
    """One layout to scan at several distances."""

    group: str  # row label of the table
    layout: str
    params: dict[str, Any]
    diameter: float  # clamped (incoming) diameter


@dataclass
class Record:
    method: str
    sensor: str
    group: str
    distance: float
    correct: bool
    truth_kind: str
    kind: str
    errors: dict[str, list[float]] = field(default_factory=dict)
    options: list[StructureOption] = field(default_factory=list)
    truth: list[StructureOption] = field(default_factory=list)
    #: a long bend's: do returns reach the end of its arc? (None for other layouts)
    arc_end_seen: bool | None = None


def start_of(net: Any) -> Pose:
    """The start pose of a layout's network (every layout sets one)."""
    if net.start_pose is None:
        raise ValueError(f"{net!r}: the layout has no start pose")
    return net.start_pose


def rot_from_tilt(yaw: float, pitch: float) -> np.ndarray:
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return rz @ ry


def thesis_cases() -> list[Case]:
    """Thesis table 4.1, 3D simulations (100 mm)."""
    d = 0.1
    return [
        Case(
            "thesis: reducer 45 % / 20 cm",
            "reducer",
            {"diameter_in": d, "diameter_out": 0.055, "taper_length": 0.2},
            d,
        ),
        Case(
            "thesis: mitre bend 45 deg",
            "mitre_bend",
            {"diameter": d, "angle": math.pi / 4, "direction": math.radians(136)},
            d,
        ),
        Case(
            "thesis: mitre bend 90 deg",
            "mitre_bend",
            {"diameter": d, "angle": math.pi / 2, "direction": math.radians(136)},
            d,
        ),
        Case("thesis: X junction", "cross_junction", {"diameter": d, "direction": 0.0}, d),
    ]


def extended_cases(rng: np.random.Generator, diameters: tuple[float, ...]) -> list[Case]:
    cases = []
    for d in diameters:

        def roll() -> float:
            return float(rng.uniform(-math.pi, math.pi))

        branch = float(rng.uniform(0.057, d)) if d > 0.06 else d
        if d < 0.075:  # expand from the smallest pipes, reduce the others
            other = round(min(0.125, d * float(rng.uniform(1.3, 1.6))), 4)
        else:
            other = max(0.057, round(d * float(rng.uniform(0.55, 0.8)), 4))
        cases += [
            Case("closure", "closure", {"diameter": d}, d),
            Case(
                "reducer",
                "reducer",
                {
                    "diameter_in": d,
                    "diameter_out": other,
                    "taper_length": float(rng.uniform(0.05, 0.2)),
                },
                d,
            ),
            Case(
                "mitre bend",
                "mitre_bend",
                {
                    "diameter": d,
                    "angle": float(rng.uniform(math.radians(30), math.radians(90))),
                    "direction": roll(),
                },
                d,
            ),
            Case(
                "long bend",
                "long_bend",
                {
                    "diameter": d,
                    "angle": float(rng.uniform(math.radians(30), math.radians(90))),
                    "direction": roll(),
                    "radius_factor": float(rng.uniform(1.0, 3.0)),
                },
                d,
            ),
            Case(
                "T junction (run)",
                "t_junction",
                {"diameter": d, "branch_diameter": branch, "direction": roll(), "entry": "run"},
                d,
            ),
            Case(
                "T junction (stem)",
                "t_junction",
                {"diameter": d, "branch_diameter": d, "direction": roll(), "entry": "stem"},
                d,
            ),
            Case(
                "Y junction (run)",
                "y_junction",
                {"diameter": d, "branch_diameter": branch, "direction": roll(), "entry": "run"},
                d,
            ),
            Case(
                "Y junction (branch)",
                "y_junction",
                {"diameter": d, "direction": roll(), "entry": "branch"},
                d,
            ),
            Case(
                "X junction",
                "cross_junction",
                {"diameter": d, "branch_diameter": branch, "direction": roll()},
                d,
            ),
        ]
    return cases


# ------------------------------------------------------------------------------ scoring
def truth_kind(truth: list[StructureOption]) -> str:
    return truth[0].kind if truth else "straight"


def match_options(
    est: list[StructureOption], truth: list[StructureOption]
) -> list[tuple[StructureOption, StructureOption]]:
    """Greedy pairing by angle and direction."""
    pairs = []
    left = list(est)
    for t in sorted(truth, key=lambda o: o.angle):
        if not left:
            break

        def cost(o: StructureOption, t: StructureOption = t) -> float:
            dd = abs(_wrap(o.direction - t.direction)) * min(math.sin(t.angle), 1.0)
            return abs(o.angle - t.angle) + dd

        best = min(left, key=cost)
        left.remove(best)
        pairs.append((best, t))
    return pairs


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def score(det: Detection, truth: list[StructureOption]) -> tuple[bool, dict[str, list[float]]]:
    tk = truth_kind(truth)
    correct = det.kind == tk and len(det.options) == len(truth)
    errs: dict[str, list[float]] = defaultdict(list)
    if not correct or not truth:
        return correct, errs
    for o, t in match_options(det.options, truth):
        errs["distance"].append(abs(o.distance - t.distance))
        if tk != "closure":
            errs["diameter"].append(abs(o.diameter - t.diameter))
        if tk in ("bend", "junction"):
            errs["angle"].append(abs(o.angle - t.angle))
            if t.angle > math.radians(10):
                errs["direction"].append(abs(_wrap(o.direction - t.direction)))
    return correct, errs


# ------------------------------------------------------------------------------ running
def arc_lead(case: Case) -> float:
    """How far before a long bend's reference point (where its centrelines meet) its arc
    starts, m (``radius x tan(angle / 2)``: up to 37.5 cm for a 90 deg, 3 D bend of 125 mm);
    0 for other layouts."""
    if case.layout != "long_bend":
        return 0.0
    p = case.params
    return float(p["radius_factor"] * p["diameter"] * math.tan(0.5 * p["angle"]))


#: A long bend's arc counts as seen to its end when returns reach within this of its angle.
ARC_END_MARGIN = math.radians(0.5)


def arc_end_seen(case: Case, dist: float, scan: Scan) -> bool | None:
    """Do the returns of a long bend's scan (sensor centred and aligned, ``dist`` m before the
    reference point) reach the end of its arc? Short of it, the bend's angle is not in the
    scan: any larger angle fits the returns as well, and only a lower bound can be read.
    ``None`` for other layouts."""
    if case.layout != "long_bend":
        return None
    prm = case.params
    angle, roll = prm["angle"], prm["direction"]
    rb = prm["radius_factor"] * prm["diameter"]
    towards = np.array([0.0, math.cos(roll), math.sin(roll)])  # the turn's side
    centre = np.array([dist - rb * math.tan(0.5 * angle), 0.0, 0.0]) + rb * towards
    q = scan.points("sensor") - centre
    if not len(q):
        return False
    along = np.arctan2(q[:, 0], -(q @ towards))  # 0 where the arc starts
    return bool(along.max() >= angle - ARC_END_MARGIN)


class Runner:
    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.timings: dict[str, list[float]] = defaultdict(list)
        #: detection times (s) per (method, sensor) of the main 3D study's scans
        self.sensor_timings: dict[tuple[str, str], list[float]] = defaultdict(list)
        self.records: list[Record] = []
        self.scan_time = 0.0
        self.n_scans = 0
        self.skipped_in_arc = 0

    def lidar(self, net, sensor: str, misalignment: Pose | None = None) -> RotatingLidar:
        world = build_world(net, contact_walls=False)
        return RotatingLidar(world, sensor, misalignment=misalignment)

    def run_case(
        self,
        case: Case,
        sensor: str,
        distances: np.ndarray,
        table: str,
        misalignment: Pose | None = None,
        keep: bool = False,
        rng: np.random.Generator | None = None,
    ) -> list[Record]:
        """Scan ``case`` from each of ``distances`` (m) and score both methods; the scans draw
        their noise from ``rng`` (default: the runner's)."""
        rng = self.rng if rng is None else rng
        net = layouts.make_layout(case.layout, **case.params, distance=0.5)
        lid = self.lidar(net, sensor, misalignment)
        ref_x = start_of(net).position[0] + 0.5
        out = []
        for dist in distances:
            if dist < arc_lead(case):
                # the sensor would be inside the bend's arc, where the straight line of the
                # incoming axis leaves the pipe: not a place a robot can scan from
                self.skipped_in_arc += 1
                continue
            pose = Pose(np.array([ref_x - dist, 0.0, 0.0]), np.eye(3))
            t0 = time.perf_counter()
            scan = lid.scan(pose, rng)
            self.scan_time += time.perf_counter() - t0
            self.n_scans += 1
            true_pose = pose if misalignment is None else pose.compose(misalignment)
            truth = net.structures_ahead(true_pose)
            seen = arc_end_seen(case, float(dist), scan) if misalignment is None else None
            for method in METHODS:
                t0 = time.process_time()
                det = detect(scan, case.diameter, method)
                dt = time.process_time() - t0
                self.timings[method].append(dt)
                self.sensor_timings[(method, table)].append(dt)
                ok, errs = score(det, truth)
                rec = Record(
                    method,
                    table,
                    case.group,
                    float(dist),
                    ok,
                    truth_kind(truth),
                    det.kind,
                    errs,
                    det.options if keep else [],
                    truth if keep else [],
                    seen,
                )
                out.append(rec)
        self.records += out
        return out


def position_sweep(
    rng: np.random.Generator, distances: np.ndarray
) -> list[tuple[str, float, Detection, list[StructureOption]]]:
    """Estimates while approaching the thesis's 90 deg mitre bend (100 mm), turned to the right,
    with the ideal sensor from each of ``distances`` (m): ``(method, distance, detection,
    truth)`` for figure 5.2 only. The scans draw their noise from ``rng`` but come from their
    own runner: they enter neither the tables nor the speed figures."""
    case = Case(
        "thesis: mitre bend 90 deg",
        "mitre_bend",
        {"diameter": 0.1, "angle": math.pi / 2, "direction": math.pi},
        0.1,
    )
    records = Runner(rng).run_case(case, "ideal", distances, "ideal", keep=True)
    return [
        (
            r.method,
            r.distance,
            Detection(r.kind, r.options, 1.0) if r.options else Detection.straight(),
            r.truth,
        )
        for r in records
    ]


def summarise(records: list[Record], title: str) -> str:
    groups: dict[tuple[str, str], list[Record]] = defaultdict(list)
    order: list[str] = []
    for r in records:
        groups[(r.group, r.method)].append(r)
        if r.group not in order:
            order.append(r.group)
    lines = [
        f"### {title}",
        "",
        "| structure | method | scans | class. % | dist mean/max cm | diam mean/max mm "
        "| angle mean/max deg | dir mean/max deg |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for g in order:
        for m in METHODS:
            rs = groups.get((g, m), [])
            if not rs:
                continue
            acc = 100.0 * np.mean([r.correct for r in rs])
            cells = []
            for key, scale in (
                ("distance", 100),
                ("diameter", 1000),
                ("angle", None),
                ("direction", None),
            ):
                vals = [v for r in rs for v in r.errors.get(key, [])]
                if not vals:
                    cells.append("-")
                    continue
                arr = np.array(vals)
                arr = arr * scale if scale else np.degrees(arr)
                fmt = "{:.2f} / {:.2f}" if key == "distance" else "{:.1f} / {:.1f}"
                cells.append(fmt.format(arr.mean(), arr.max()))
            lines.append(f"| {g} | {m} | {len(rs)} | {acc:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def overall(records: list[Record]) -> dict[str, dict[str, float]]:
    out = {}
    for m in METHODS:
        rs = [r for r in records if r.method == m and r.truth_kind != "straight"]
        if not rs:
            continue
        d = {"classification": 100.0 * float(np.mean([r.correct for r in rs]))}
        scored = [r for r in rs if r.correct]
        d["scored"] = len(scored)
        d["beyond_requirements"] = sum(beyond_requirements(r) for r in scored)
        for key in ("distance", "diameter", "angle", "direction"):
            vals = [v for r in rs for v in r.errors.get(key, [])]
            d[key + "_mean"] = float(np.mean(vals)) if vals else float("nan")
            d[key + "_max"] = float(np.max(vals)) if vals else float("nan")
        out[m] = d
    return out


#: The thesis's requirements for a detection (its table 6.1): distance within 2 cm, angle and
#: direction within 5 deg.
REQUIRED_DISTANCE = 0.02
REQUIRED_ANGLE = math.radians(5.0)


def beyond_requirements(record: Record) -> bool:
    """Is a correctly classified detection's distance, angle or direction error beyond the
    thesis's requirements (:data:`REQUIRED_DISTANCE`, :data:`REQUIRED_ANGLE`)?"""
    e = record.errors
    return (
        max(e.get("distance", []), default=0.0) > REQUIRED_DISTANCE
        or max(e.get("angle", []) + e.get("direction", []), default=0.0) > REQUIRED_ANGLE
    )


def overall_table(records: list[Record], title: str) -> str:
    o = overall(records)
    lines = [
        f"**{title}, all kinds**",
        "",
        "| method | class. % | dist mean/max cm | diam mean/max mm | angle mean/max deg "
        "| dir mean/max deg | beyond 2 cm / 5 deg |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for m, d in o.items():
        lines.append(
            f"| {m} | {d['classification']:.1f} | {100 * d['distance_mean']:.2f} / "
            f"{100 * d['distance_max']:.2f} | {1000 * d['diameter_mean']:.1f} / "
            f"{1000 * d['diameter_max']:.1f} | {math.degrees(d['angle_mean']):.1f} / "
            f"{math.degrees(d['angle_max']):.1f} | {math.degrees(d['direction_mean']):.1f} / "
            f"{math.degrees(d['direction_max']):.1f} | "
            f"{d['beyond_requirements']} of {d['scored']} |"
        )
    return "\n".join(lines)


# ------------------------------------------------------------------------------ experiments
def planar_study(rng: np.random.Generator, distances: np.ndarray) -> tuple[str, list]:
    """Thesis 2D: 90 deg mitre to the right in 60 and 100 mm, horizontal plane."""
    rows = []
    series = []
    for d in (0.06, 0.1):
        net = layouts.mitre_bend(diameter=d, angle=math.pi / 2, direction=math.pi, distance=0.5)
        lid = RotatingLidar(build_world(net, contact_walls=False), "ideal")
        ref_x = start_of(net).position[0] + 0.5
        recs = []
        for dist in distances:
            pose = Pose(np.array([ref_x - dist, 0.0, 0.0]), np.eye(3))
            scan = lid.scan_plane(pose, 0.0, rng)
            truth = net.structures_ahead(pose)
            for method in METHODS:
                det = detect_planar(scan, d, method)
                ok, errs = score(det, truth)
                recs.append(
                    Record(
                        method,
                        "ideal",
                        f"2D mitre 90 deg, {d * 1000:.0f} mm",
                        float(dist),
                        ok,
                        "bend",
                        det.kind,
                        errs,
                    )
                )
                if method == "thesis":
                    series.append((d, float(dist), det))
        rows += recs
    lines = [
        "### 2D (thesis Algorithm 1 and the improved planar method), ideal sensor, horizontal "
        "plane",
        "",
        "| structure | method | scans | class. % | dist mean/max cm | diam mean/max mm "
        "| angle mean/max deg |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    by: dict[tuple[str, str], list[Record]] = defaultdict(list)
    for r in rows:
        by[(r.group, r.method)].append(r)
    for (g, m), rs in by.items():
        acc = 100 * np.mean([r.correct for r in rs])
        cells = []
        for key, scale in (("distance", 100), ("diameter", 1000), ("angle", None)):
            vals = [v for r in rs for v in r.errors.get(key, [])]
            if not vals:
                cells.append("-")
                continue
            a = np.array(vals) * scale if scale else np.degrees(np.array(vals))
            cells.append(f"{a.mean():.2f} / {a.max():.2f}")
        lines.append(f"| {g} | {m} | {len(rs)} | {acc:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines), series


def straight_false_alarms(runner: Runner, sensors: list[str], n: int, diameters) -> str:
    lines = [
        "### False alarms on straight pipe",
        "",
        "| sensor | method | scans | false alarms | per 1000 scans |",
        "|---|---|---:|---:|---:|",
    ]
    for sensor in sensors:
        counts = {m: 0 for m in METHODS}
        total = 0
        per_d = max(1, n // len(diameters))
        for d in diameters:
            net = layouts.straight(diameter=d, distance=3.0)
            lid = runner.lidar(net, sensor)
            for _ in range(per_d):
                x = float(runner.rng.uniform(-0.3, 0.5))
                roll = float(runner.rng.uniform(-math.pi, math.pi))
                c, s = math.cos(roll), math.sin(roll)
                rot = np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=float)
                t0 = time.perf_counter()
                scan = lid.scan(Pose(np.array([x, 0.0, 0.0]), rot), runner.rng)
                runner.scan_time += time.perf_counter() - t0
                runner.n_scans += 1
                total += 1
                for m in METHODS:
                    t0 = time.process_time()
                    det = detect(scan, d, m)
                    runner.timings[m].append(time.process_time() - t0)
                    counts[m] += det.kind != "straight"
        for m in METHODS:
            lines.append(
                f"| {sensor} | {m} | {total} | {counts[m]} | "
                f"{1000.0 * counts[m] / max(total, 1):.1f} |"
            )
    return "\n".join(lines)


def misalignment_study(
    runner: Runner, distances: np.ndarray, offsets: list[float], tilts: list[float]
) -> tuple[str, list]:
    """Thesis 5.3: sensor offset (fraction of D) and tilt (deg), 90 deg bend and cross, 100 mm."""
    cases = [
        Case(
            "mitre bend 90 deg",
            "mitre_bend",
            {"diameter": 0.1, "angle": math.pi / 2, "direction": math.pi},
            0.1,
        ),
        Case("X junction", "cross_junction", {"diameter": 0.1, "direction": 0.0}, 0.1),
        Case("closure", "closure", {"diameter": 0.1}, 0.1),
    ]
    recs: list[Record] = []
    sweep = []
    for frac in offsets:
        for tilt in tilts:
            ang = float(runner.rng.uniform(-math.pi, math.pi))
            off = np.array([0.0, math.cos(ang), math.sin(ang)]) * frac * 0.1
            tdir = float(runner.rng.uniform(-math.pi, math.pi))
            rot = rot_from_tilt(
                math.radians(tilt) * math.cos(tdir), math.radians(tilt) * math.sin(tdir)
            )
            mis = Pose(off, rot)
            for case in cases:
                rs = runner.run_case(case, "ideal", distances, "misaligned", mis)
                for r in rs:
                    r.group = f"{case.group}"
                recs += rs
                sweep += [(frac, tilt, r) for r in rs]
    text = summarise(
        recs,
        f"Misalignment (offset up to {100 * max(offsets):.0f} % of D, tilt "
        f"up to {max(tilts):.0f} deg), ideal sensor, 100 mm",
    )
    return text, sweep


def long_bend_study(
    runner: Runner,
    rng: np.random.Generator,
    sensors: list[str],
    distances: np.ndarray,
    diameters: tuple[float, ...],
    per_diameter: int,
) -> str:
    """More long bends than the main study's one per diameter, from their own draw (so the
    main study's cases and figures stay as they are): deflection 30-90 deg, bend radius 1-3 D,
    random roll. A long bend's far arc can be out of sight; the detector then flags its angle
    as a lower bound (``angle_lower_bound``), and the error is scored all the same."""
    cases = []
    for d in diameters:
        for _ in range(per_diameter):
            angle = float(rng.uniform(math.radians(30), math.radians(90)))
            factor = float(rng.uniform(1.0, 3.0))
            params = {
                "diameter": d,
                "angle": angle,
                "direction": float(rng.uniform(-math.pi, math.pi)),
                "radius_factor": factor,
            }
            name = f"long bend {1000 * d:.0f} mm, {math.degrees(angle):.0f} deg, R {factor:.1f} D"
            cases.append(Case(name, "long_bend", params, d))
    text = []
    for sensor in sensors:
        recs = []
        for case in cases:
            recs += runner.run_case(case, sensor, distances, f"long bends, {sensor}")
        text.append(overall_table(recs, f"Long bends ({len(cases)} more), {sensor} sensor"))
        for seen, label in ((True, "returns reach the arc's end"), (False, "the arc's end unseen")):
            part = [r for r in recs if r.arc_end_seen is seen]
            n = len(part) // len(METHODS)
            text.append(overall_table(part, f"Long bends, {sensor} sensor, {label} ({n} scans)"))
        text.append(summarise(recs, f"Long bends ({len(cases)} more), {sensor} sensor, 40-10 cm"))
    return "\n\n".join(text)


def clamp_error_study(runner: Runner, distances: np.ndarray, errors_mm: list[float]) -> str:
    """The clamped diameter off by ``errors_mm`` (the clamp's encoder error), ideal sensor,
    100 mm: a gentle reducer (the kind a wrong radius hurts most), a bend, a tee, a cap."""
    cases = [
        Case(
            "reducer 100 to 88 mm / 8 cm",
            "reducer",
            {"diameter_in": 0.1, "diameter_out": 0.088, "taper_length": 0.08},
            0.1,
        ),
        Case(
            "mitre bend 60 deg",
            "mitre_bend",
            {"diameter": 0.1, "angle": math.radians(60), "direction": 1.0},
            0.1,
        ),
        Case("T junction (run)", "t_junction", {"diameter": 0.1, "direction": -2.0}, 0.1),
        Case("closure", "closure", {"diameter": 0.1}, 0.1),
    ]
    recs: list[Record] = []
    for err in errors_mm:
        for case in cases:
            c = Case(case.group, case.layout, case.params, case.diameter + 1e-3 * err)
            recs += runner.run_case(c, "ideal", distances, "clamp error")
    return summarise(
        recs,
        f"Clamped diameter off by {', '.join(f'{e:+g}' for e in errors_mm)} mm, ideal sensor, "
        "100 mm",
    )


def plots(out: Path, series_3d: list, sweep: list, planar: list) -> list[str]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover
        return []
    written = []
    # figure 5.2: estimates vs position (90 deg bend to the right, 100 mm)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for method, style in (("thesis", "o--"), ("improved", "s-")):
        pts = [(dist, det) for m, dist, det, truth in series_3d if m == method]
        dist = np.array([p[0] for p in pts])
        est_d = [p[1].options[0].distance if p[1].options else np.nan for p in pts]
        est_a = [max((math.degrees(o.angle) for o in p[1].options), default=np.nan) for p in pts]
        est_dia = [p[1].options[0].diameter * 1000 if p[1].options else np.nan for p in pts]
        axes[0].plot(100 * dist, 100 * np.array(est_d), style, label=method)
        axes[1].plot(100 * dist, est_dia, style, label=method)
        axes[2].plot(100 * dist, est_a, style, label=method)
    dd = np.array([p[1] for p in series_3d if p[0] == "thesis"])
    axes[0].plot(100 * dd, 100 * dd, "k:", label="truth")
    axes[1].axhline(100, color="k", ls=":", label="truth")
    axes[2].axhline(90, color="k", ls=":", label="truth")
    for d, dist, det in planar:
        if d == 0.1 and det.options:
            axes[0].plot(
                100 * dist,
                100 * det.options[0].distance,
                "^",
                color="gray",
                label="thesis 2D" if dist == planar[0][1] else None,
            )
    axes[0].set(
        xlabel="true distance to the bend [cm]", ylabel="estimated distance [cm]", title="Distance"
    )
    axes[1].set(xlabel="true distance [cm]", ylabel="diameter [mm]", title="Outgoing diameter")
    axes[2].set(xlabel="true distance [cm]", ylabel="angle [deg]", title="Bend angle")
    for a in axes:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
        a.invert_xaxis()
    fig.suptitle(
        "Estimates while approaching a 90 deg mitre bend to the right (100 mm, "
        "ideal sensor; cf. thesis fig. 5.2)"
    )
    fig.tight_layout()
    p = out / "fig_5_2_estimates_vs_position.png"
    save_figure(fig, p, dpi=110)
    plt.close(fig)
    written.append(str(p))
    # figure 5.3: misalignment sweep
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for method, style in (("thesis", "o--"), ("improved", "s-")):
        for key, ax, scale, unit in (
            ("distance", axes[0], 100, "cm"),
            ("angle", axes[1], None, "deg"),
            ("direction", axes[2], None, "deg"),
        ):
            xs, ys = [], []
            for frac in sorted({s[0] for s in sweep}):
                vals = [
                    v
                    for f, _, r in sweep
                    if f == frac and r.method == method
                    for v in r.errors.get(key, [])
                ]
                acc = [r.correct for f, _, r in sweep if f == frac and r.method == method]
                if vals:
                    xs.append(100 * frac)
                    arr = np.array(vals)
                    ys.append(float(np.mean(arr * scale if scale else np.degrees(arr))))
                elif acc:
                    xs.append(100 * frac)
                    ys.append(np.nan)
            ax.plot(xs, ys, style, label=method)
            ax.set(
                xlabel="sensor offset [% of D] (tilt up to 4 deg)",
                ylabel=f"mean |{key} error| [{unit}]",
                title=key.capitalize(),
            )
    for a in axes:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle("Misalignment sweep (cf. thesis fig. 5.3): 90 deg bend, X junction, closure")
    fig.tight_layout()
    p = out / "fig_5_3_misalignment.png"
    save_figure(fig, p, dpi=110)
    plt.close(fig)
    written.append(str(p))
    return written


#: Layouts the warm-up detects on (the compiled kernels of straight pipe, turns, long bends,
#: junctions and reducers), 100 mm, 25 cm ahead.
WARM_UP_LAYOUTS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("straight", {}),
    ("mitre_bend", {"angle": math.pi / 2, "direction": 0.5}),
    ("long_bend", {"angle": math.pi / 3, "direction": 0.5, "radius_factor": 2.0}),
    ("t_junction", {"branch_diameter": 0.075, "direction": 0.5, "entry": "run"}),
    ("reducer", {"diameter_in": 0.1, "diameter_out": 0.06, "taper_length": 0.1}),
)


def warm_up() -> None:
    """Detect once with each method on a scan of each of :data:`WARM_UP_LAYOUTS` (ideal
    sensor, its own seed), untimed: the compiled kernels load (or compile) on their first call
    with each argument type, and the study's speed figures are per scan, not per process."""
    rng = np.random.default_rng(0)
    for layout, params in WARM_UP_LAYOUTS:
        if layout == "straight":
            net = layouts.straight(diameter=0.1, distance=1.0)
            pose = Pose(np.zeros(3), np.eye(3))
        else:
            args = params if layout == "reducer" else {"diameter": 0.1, **params}
            net = layouts.make_layout(layout, **args, distance=0.5)
            pose = Pose(start_of(net).position + np.array([0.25, 0.0, 0.0]), np.eye(3))
        lid = RotatingLidar(build_world(net, contact_walls=False), "ideal")
        scan = lid.scan(pose, rng)
        for m in METHODS:
            detect(scan, 0.1, m)


def speed_table(runner: Runner, sensors: list[str]) -> str:
    """Detection speed (scans/s per core: the process's CPU time, one thread) of both methods
    on the same scans in one run, with the ratio improved / thesis: over every scan of the
    study, and over the main 3D study's scans per sensor (every kind, 40-10 cm). CPU time, not
    wall time: on a shared machine the wall clock also counts the other processes' turns."""
    lines = [
        "### Speed (detection only, scans/s per core: CPU time of one thread)",
        "",
        "| scans | thesis scans/s | improved scans/s | improved / thesis |",
        "|---|---:|---:|---:|",
    ]

    def row(label: str, t_thesis: list[float], t_improved: list[float]) -> None:
        rate = [len(t) / max(float(np.sum(t)), 1e-9) for t in (t_thesis, t_improved)]
        lines.append(
            f"| {label} ({len(t_improved)}) | {rate[0]:.0f} | {rate[1]:.0f} | "
            f"{rate[1] / max(rate[0], 1e-9):.2f} |"
        )

    row("all", runner.timings["thesis"], runner.timings["improved"])
    for sensor in sensors:
        row(
            f"3D, {sensor}",
            runner.sensor_timings[("thesis", sensor)],
            runner.sensor_timings[("improved", sensor)],
        )
    lines.append("")
    lines.append(
        f"Scan simulation: {runner.n_scans / max(runner.scan_time, 1e-9):.1f} scans/s "
        f"({runner.n_scans} scans)."
    )
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line: ``kinds``, ``sensors`` (lists) and ``parts`` (a set) checked."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small run (about a minute)")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out", default="results/detection")
    ap.add_argument(
        "--write-docs", action="store_true", help="write the figures into docs/benchmarks.md"
    )
    ap.add_argument(
        "--kinds",
        default="",
        help="comma-separated layouts or row labels of the 3D study to run (e.g. reducer,closure;"
        " default: all)",
    )
    ap.add_argument(
        "--sensors", default=",".join(SENSORS), help=f"comma-separated subset of {SENSORS}"
    )
    ap.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated subset of {PARTS}")
    args = ap.parse_args(argv)
    args.kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    args.sensors = [k.strip() for k in args.sensors.split(",") if k.strip()]
    args.parts = {k.strip() for k in args.parts.split(",") if k.strip()}
    for name, given, allowed in (
        ("--sensors", args.sensors, SENSORS),
        ("--parts", args.parts, PARTS),
    ):
        bad = sorted(set(given) - set(allowed))
        if bad or not given:
            ap.error(f"{name} = {','.join(bad) or '(empty)'}: unknown; allowed: {allowed}")
    partial = args.kinds or len(args.sensors) < len(SENSORS) or len(args.parts) < len(PARTS)
    if args.write_docs and partial:
        ap.error("--write-docs = given with --kinds/--sensors/--parts; allowed: full runs only")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    kinds, sensors, parts = args.kinds, args.sensors, args.parts
    t_start = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    quick = args.quick
    distances = np.linspace(0.40, 0.10, 4 if quick else 13)
    diameters = DIAMETERS_QUICK if quick else DIAMETERS_FULL
    runner = Runner(rng)
    warm_up()
    sections = []
    # 2D
    # (run whichever parts are asked for: its scans draw from ``rng`` before the cases do)
    text2d, planar_series = planar_study(rng, np.linspace(0.40, 0.10, 7 if quick else 31))
    if "planar" in parts:
        sections.append(text2d)
    # 3D thesis cases and extended cases, per sensor (every case is drawn, whichever run)
    cases = thesis_cases() + extended_cases(rng, diameters)
    if kinds:
        cases = [c for c in cases if any(k in (c.layout, c.group) for k in kinds)]
    series_3d: list = []
    for sensor in sensors if "accuracy" in parts else []:
        recs = []
        for case in cases:
            if sensor == "ideal" and case.group == "thesis: mitre bend 90 deg":
                # the approach of figure 5.2 (in no table) draws where it always has, so the
                # other cases' draws stay as they were; the table's case, like every other row,
                # from the standard distances, draws apart (the ideal sensor adds no noise)
                series_3d = position_sweep(runner.rng, np.linspace(0.40, 0.10, 31))
                own = np.random.default_rng([args.seed, 3])
                recs += runner.run_case(case, sensor, distances, sensor, rng=own)
            else:
                recs += runner.run_case(case, sensor, distances, sensor)
        sections.append(overall_table(recs, f"3D, {sensor} sensor, 40-10 cm"))
        sections.append(summarise(recs, f"3D per structure, {sensor} sensor, 40-10 cm"))
    # misalignment
    sweep: list = []
    if "misalignment" in parts:
        offsets = [0.0, 0.1, 0.2] if quick else [0.0, 0.05, 0.1, 0.15, 0.2]
        tilts = [0.0, 4.0] if quick else [0.0, 2.0, 4.0]
        mis_text, sweep = misalignment_study(
            runner, np.linspace(0.40, 0.10, 3 if quick else 7), offsets, tilts
        )
        sections.append(mis_text)
    # clamped-diameter (encoder) error
    if "clamp" in parts:
        sections.append(
            clamp_error_study(
                runner, np.linspace(0.40, 0.10, 3 if quick else 7), [-2.0, -1.0, 1.0, 2.0]
            )
        )
    # false alarms
    if "false-alarms" in parts:
        sections.append(straight_false_alarms(runner, sensors, 60 if quick else 400, diameters))
    # more long bends, from their own draw (the cases above stay as they were)
    if "long-bends" in parts:
        sections.append(
            long_bend_study(
                runner,
                np.random.default_rng([args.seed, 2]),
                sensors,
                distances,
                diameters,
                1 if quick else 3,
            )
        )
    speed = speed_table(runner, sensors) if "speed" in parts else ""
    if speed:
        sections.append(speed)
    sections.append(
        f"Long-bend positions skipped (the sensor would be inside the arc): {runner.skipped_in_arc}"
    )
    figs = plots(out, series_3d, sweep, planar_series) if parts == set(PARTS) else []
    elapsed = time.perf_counter() - t_start
    header = (
        f"# Detection accuracy study ({'quick' if quick else 'full'} run, seed "
        f"{args.seed}, {elapsed / 60:.1f} min, "
        f"threads={os.environ.get('OMP_NUM_THREADS', 'default')})\n"
    )
    report = header + "\n\n".join(sections) + "\n"
    atomic_write_text(out / "report.md", report)
    print(report)
    if args.write_docs:
        from benchmarks.report import write_section

        summary = [s for s in sections if s.startswith("**3D,")]
        # (where the report goes changes no figure)
        given = [a for a in (sys.argv[1:] if argv is None else argv) if a != "--write-docs"]
        given = [
            a
            for a, b in zip(given, ["", *given])
            if a != "--out" and b != "--out" and not a.startswith("--out=")
        ]
        command = " ".join(["python benchmarks/bench_detection.py", *given])
        write_section(
            "detection",
            f"`{command}`\n\nDetection speed of both methods in the same run, and the "
            "accuracy per sensor over all kinds (40-10 cm); the full tables are in the "
            "script's report.\n\n" + "\n\n".join([speed, *summary]),
        )
    for f in figs:
        print("wrote", f)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
