"""Calibrate the fast fidelity's sensing models against the real detector.

For each detector ("improved", "thesis") and LiDAR preset ("ideal", "ydlidar_x4", "ls02"), drive
a sensor along the incoming centreline of random single-structure layouts (every kind, diameters
57-125 mm, random roll directions), scanning every ``--step`` metres from 45 cm down to the
trigger distance, fuse the detections with ``detector.fusion.StructureTracker`` exactly as the
full-fidelity closed loop does, and compare the estimate at the trigger distance with ground
truth. The error statistics become :class:`pipe_env.envs.sensing_model.DetectionErrorModel` entries
written to ``pipe_env/data/sensing_models.json`` (``--write``), which the fast fidelity loads.

Usage: python benchmarks/calibrate_sensing.py [--samples 60] [--write]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

import detector
from detector.atomic import atomic_write_text
from detector.fusion import StructureTracker
from detector.options import match_option
from pipe_env import layouts
from pipe_env.lidar import RotatingLidar
from pipe_env.world import build_world

OUT = Path(__file__).resolve().parents[1] / "pipe_env" / "data" / "sensing_models.json"
#: An estimate beyond the thesis requirements (2 cm, 5 deg; 5 mm for the diameter) is a gross
#: error; the fast fidelity draws gross and ordinary errors from separate gaussians.
GROSS = {
    "distance": 0.02,
    "diameter": 0.005,
    "angle": math.radians(5.0),
    "direction": math.radians(5.0),
}
KINDS = ("mitre_bend", "long_bend", "tee_run", "tee_stem", "wye_run", "cross", "reducer", "closure")


def random_layout(kind: str, rng: np.random.Generator, start: float):
    d = float(rng.uniform(0.057, 0.125))
    phi = float(rng.uniform(-math.pi, math.pi))
    if kind == "mitre_bend":
        return layouts.mitre_bend(d, math.radians(rng.choice([30, 45, 60, 90])), phi, start)
    if kind == "long_bend":
        return layouts.long_bend(
            d,
            math.radians(rng.choice([30, 45, 60, 90])),
            phi,
            start,
            radius_factor=float(rng.uniform(1.0, 3.0)),
        )
    if kind == "tee_run":
        return layouts.t_junction(d, d * float(rng.uniform(0.7, 1.0)), phi, start)
    if kind == "tee_stem":
        return layouts.t_junction(d, d * float(rng.uniform(0.7, 1.0)), phi, start, entry="stem")
    if kind == "wye_run":
        return layouts.y_junction(d, d * float(rng.uniform(0.7, 1.0)), phi, start)
    if kind == "cross":
        return layouts.cross_junction(d, d * float(rng.uniform(0.7, 1.0)), phi, start)
    if kind == "reducer":
        out = float(np.clip(d + rng.choice([-1, 1]) * rng.uniform(0.01, 0.03), 0.057, 0.125))
        if abs(out - d) < 0.005:
            out = d - 0.01 if d > 0.07 else d + 0.01
        return layouts.reducer(d, out, float(rng.uniform(0.05, 0.2)), start)
    return layouts.closure(d, start)


def approach(net, lidar, method, rng, trigger: float, step: float):
    """Fused detection at the trigger distance and the truth there. A long bend whose arc
    starts farther out than the trigger distance (its reference point, where the centrelines
    meet, lies ``R tan(angle / 2)`` past the arc's start) is approached to 1 cm before its
    arc: the straight line of the incoming axis leaves the pipe inside the arc."""
    tracker = StructureTracker()
    ahead = net.structures_ahead(net.start_pose, 10.0)[0]
    base = ahead.distance
    stop = max(trigger, ahead.bend_radius * math.tan(0.5 * ahead.angle) + 0.01)
    state = None
    for d in np.arange(max(0.45, stop + 3 * step), stop - 1e-9, -step):
        pose = net.start_pose.translated(base - d)
        scan = lidar.scan(pose, rng)
        det = detector.detect(scan, net.inner_diameter_at(pose.position), method=method)
        state = tracker.update(det, pose.position, pose.rotation)
    pose = net.start_pose.translated(base - stop)
    truth = net.structures_ahead(pose, 10.0)
    fused = state.detection if state is not None and state.confirmed else None
    return fused, truth


def calibrate(
    method: str, preset: str, samples: int, seed: int, trigger: float, step: float
) -> dict:
    rng = np.random.default_rng(seed)
    errs = {"distance": [], "diameter": [], "angle": [], "direction": []}
    gross: list[bool] = []  # per matched way on: beyond the thesis requirements
    gross_dir: list[bool] = []  # the same, for the ways whose direction is defined
    n_struct = n_kind_ok = n_missed_ways = n_true_ways = n_phantoms = n_unconfirmed = 0
    confidences = []
    for i in range(samples):
        kind = KINDS[i % len(KINDS)]
        net = random_layout(kind, rng, 0.5)
        lidar = RotatingLidar(build_world(net, contact_walls=False), preset, backend="analytic")
        fused, truth = approach(net, lidar, method, rng, trigger, step)
        n_struct += 1
        n_true_ways += len(truth)
        if fused is None or not fused.options:
            n_unconfirmed += 1
            n_missed_ways += len(truth)
            continue
        n_kind_ok += fused.kind == truth[0].kind
        matched = set()
        for o in fused.options:
            k, sep = match_option(o, truth)
            if sep > math.radians(40) or k in matched:
                n_phantoms += 1
                continue
            matched.add(k)
            t = truth[k]
            confidences.append(o.confidence)
            errs["distance"].append(o.distance - t.distance)
            errs["diameter"].append(o.diameter - t.diameter)
            errs["angle"].append(o.angle - t.angle)
            bad = (
                abs(o.distance - t.distance) > GROSS["distance"]
                or abs(o.diameter - t.diameter) > GROSS["diameter"]
                or abs(o.angle - t.angle) > GROSS["angle"]
            )
            if t.angle > math.radians(10):
                e_dir = (o.direction - t.direction + math.pi) % (2 * math.pi) - math.pi
                errs["direction"].append(e_dir)
                bad = bad or abs(e_dir) > GROSS["direction"]
                gross_dir.append(bad)
            gross.append(bad)
        n_missed_ways += len(truth) - len(matched)
    gross_flags = np.array(gross, dtype=bool)

    def rms(values: list[float], flags: np.ndarray, want: bool) -> float:
        v = np.asarray(values, dtype=float)[flags == want] if values else np.zeros(0)
        return round(float(np.sqrt(np.mean(np.square(v)))), 5) if v.size else 0.0

    dir_flags = np.array(gross_dir, dtype=bool)
    return {
        "name": f"{method}/{preset}",
        "distance_sigma": rms(errs["distance"], gross_flags, False),
        "diameter_sigma": rms(errs["diameter"], gross_flags, False),
        "angle_sigma": rms(errs["angle"], gross_flags, False),
        "direction_sigma": rms(errs["direction"], dir_flags, False),
        "gross_rate": round(float(gross_flags.mean()) if gross_flags.size else 0.0, 4),
        "gross_distance_sigma": rms(errs["distance"], gross_flags, True),
        "gross_diameter_sigma": rms(errs["diameter"], gross_flags, True),
        "gross_angle_sigma": rms(errs["angle"], gross_flags, True),
        "gross_direction_sigma": rms(errs["direction"], dir_flags, True),
        "miss_rate": round((n_missed_ways) / max(n_true_ways, 1), 4),
        "phantom_rate": round(n_phantoms / max(n_struct, 1), 4),
        "misclass_rate": round(1.0 - n_kind_ok / max(n_struct - n_unconfirmed, 1), 4),
        "confidence": round(float(np.mean(confidences)) if confidences else 0.5, 3),
        "structures": n_struct,
        "unconfirmed": n_unconfirmed,
        "max_abs": {k: round(float(np.max(np.abs(v))), 5) if v else 0.0 for k, v in errs.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--samples", type=int, default=48, help="structures per combination")
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--trigger", type=float, default=0.2, help="decision distance, m")
    parser.add_argument("--step", type=float, default=0.05, help="scan spacing, m")
    parser.add_argument("--write", action="store_true", help=f"write {OUT.name}")
    args = parser.parse_args()
    models = {}
    print(
        "| detector/preset | dist rms cm | diam rms mm | angle rms deg | dir rms deg | gross | "
        "miss | phantom | misclass | unconfirmed | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for method in ("improved", "thesis"):
        for preset in ("ideal", "ydlidar_x4", "ls02"):
            t0 = time.perf_counter()
            m = calibrate(method, preset, args.samples, args.seed, args.trigger, args.step)
            models[m["name"]] = m
            print(
                f"| {m['name']} | {m['distance_sigma'] * 100:.2f} | "
                f"{m['diameter_sigma'] * 1000:.1f} | {math.degrees(m['angle_sigma']):.2f} | "
                f"{math.degrees(m['direction_sigma']):.2f} | {m['gross_rate']:.3f} | "
                f"{m['miss_rate']:.3f} | "
                f"{m['phantom_rate']:.3f} | {m['misclass_rate']:.3f} | "
                f"{m['unconfirmed']}/{m['structures']} | {time.perf_counter() - t0:.0f} |",
                flush=True,
            )
    if args.write:
        OUT.parent.mkdir(parents=True, exist_ok=True)
        doc = {
            "about": "fast-fidelity sensing models calibrated by benchmarks/"
            "calibrate_sensing.py (fused detections at the trigger distance)",
            "samples": args.samples,
            "seed": args.seed,
            "trigger": args.trigger,
            "step": args.step,
            "models": models,
        }
        atomic_write_text(OUT, json.dumps(doc, indent=1, allow_nan=False))
        print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
