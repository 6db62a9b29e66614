"""Checking a pipe network: ids and references, fittings, diameters, lengths, clearance, points.

This module owns :meth:`pipe_env.network.PipeNetwork.validate`'s rules. Every problem is a
:class:`~detector.validation.ArgumentError` (a ``ValueError``) in the project's one format,
naming the element by its path and id (``fittings[3] (id 'f3').position``,
``runs[2] (id 'r2').diameter``), the value and what is allowed. It works on the model passed
in and imports it for type checking only, so the model can call it without an import cycle.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from detector.geometry import segment_distance
from detector.validation import check_choice, check_number, fail
from pipe_env.fittings import AXIS_TOLERANCE, BEND_STYLES, FITTING_DEGREE, FittingGeometry
from pipe_env.network_elements import (
    BEND_ANGLE_RANGE,
    BEND_RADIUS_RANGE,
    MAX_EXTENT,
    MAX_TAPER_HALF_ANGLE,
    TAPER_LENGTH_RANGE,
    WALL_CLEARANCE,
    Fitting,
    Run,
)

if TYPE_CHECKING:
    from pipe_env.network import PipeNetwork

__all__ = ["check_extent", "check_topology", "fitting_path", "run_path", "validate_network"]

_ANGLE_TOL = math.degrees(AXIS_TOLERANCE)  # deg
#: Largest angle between the start pose's forward axis and the pipe axis, radians.
MAX_START_TILT = math.radians(30.0)


def fitting_path(index: int, f: Fitting) -> str:
    """``fittings[3] (id 'f3')``: where a fitting sits in a network file."""
    return f"fittings[{index}] (id {f.id!r})"


def run_path(index: int, r: Run) -> str:
    """``runs[2] (id 'r2')``: where a run sits in a network file."""
    return f"runs[{index}] (id {r.id!r})"


def _run_path_by_id(net: PipeNetwork, run_id: str) -> str:
    index = next(i for i, r in enumerate(net.runs) if r.id == run_id)
    return run_path(index, net.runs[index])


def validate_network(net: PipeNetwork, diameter_range: tuple[float, float]) -> None:
    """Check the whole network (see :meth:`pipe_env.network.PipeNetwork.validate`)."""
    check_extent(net)
    check_topology(net)
    lo, hi = diameter_range
    for i, r in enumerate(net.runs):
        check_number(f"{run_path(i, r)}.diameter", r.diameter, lo, hi, unit="m")
    for i, f in enumerate(net.fittings):
        _check_fitting(net, i, f)
    _check_run_lengths(net)
    _check_clearance(net)
    _check_points(net)


# ------------------------------------------------------------------------------ extent
def check_extent(net: PipeNetwork) -> None:
    """Fittings, goals and the start within :data:`MAX_EXTENT` of the origin, and run
    diameters finite (absurd geometry is rejected before any is derived)."""
    allowed = f"coordinates within ±{MAX_EXTENT:g} m"
    problem = "outside the allowed extent"
    for i, f in enumerate(net.fittings):
        if max(abs(v) for v in f.position) > MAX_EXTENT:
            raise fail(f"{fitting_path(i, f)}.position", list(f.position), allowed, problem)
    for i, g in enumerate(net.goals):
        if max(abs(v) for v in g) > MAX_EXTENT:
            raise fail(f"goals[{i}]", list(g), allowed, problem)
    start = net.start_pose
    if start is not None and np.max(np.abs(start.position)) > MAX_EXTENT:
        raise fail("start.position", start.position.tolist(), allowed, problem)
    for i, r in enumerate(net.runs):
        check_number(f"{run_path(i, r)}.diameter", r.diameter, unit="m")


# ---------------------------------------------------------------------------- topology
def check_topology(net: PipeNetwork) -> None:
    """Unique ids, known kinds, runs joining two distinct existing fittings once, and each
    fitting joined by as many runs as its kind takes."""
    if not net.runs:
        raise fail("runs", [], "at least one run (and its two fittings)", "empty")
    ids = _check_fitting_ids(net)
    _check_runs_refs(net, ids)
    for i, f in enumerate(net.fittings):
        degree = len(net.runs_at[f.id])
        want = FITTING_DEGREE[f.kind]
        if degree != want:
            raise fail(
                f"{fitting_path(i, f)}.kind",
                f.kind,
                f"a {f.kind} joins exactly {want} run(s)",
                f"joined by {degree} run(s)",
            )


def _check_fitting_ids(net: PipeNetwork) -> set[str]:
    ids: set[str] = set()
    for i, f in enumerate(net.fittings):
        if f.id in ids:
            raise fail(f"fittings[{i}].id", f.id, "an id used once", "used twice")
        ids.add(f.id)
        check_choice(f"{fitting_path(i, f)}.kind", f.kind, sorted(FITTING_DEGREE))
    return ids


def _check_runs_refs(net: PipeNetwork, fitting_ids: set[str]) -> None:
    run_ids: set[str] = set()
    pairs: set[frozenset[str]] = set()
    for i, r in enumerate(net.runs):
        path = run_path(i, r)
        if r.id in run_ids or r.id in fitting_ids:
            raise fail(f"runs[{i}].id", r.id, "an id used once", "used twice")
        run_ids.add(r.id)
        for end in ("a", "b"):
            ref = getattr(r, end)
            if ref not in fitting_ids:
                raise fail(
                    f"{path}.{end}",
                    ref,
                    "the id of a fitting of this network",
                    "not a fitting of this network (dangling reference)",
                )
        if r.a == r.b:
            raise fail(f"{path}.b", r.b, "a fitting other than a", "joins the fitting to itself")
        key = frozenset((r.a, r.b))
        if key in pairs:
            raise fail(
                f"{path}.b", r.b, "one run between two fittings", f"already joined to {r.a!r}"
            )
        pairs.add(key)
        if _node_distance(net, r) < 1e-6:
            raise fail(
                f"{path}.b", r.b, "fittings at distinct positions", f"at the position of {r.a!r}"
            )


def _node_distance(net: PipeNetwork, r: Run) -> float:
    return float(np.linalg.norm(net.position(r.b) - net.position(r.a)))


# ---------------------------------------------------------------------------- fittings
def _check_fitting(net: PipeNetwork, index: int, f: Fitting) -> None:
    path = fitting_path(index, f)
    if f.kind != "bend" and (f.style is not None or f.bend_radius is not None):
        key = "style" if f.style is not None else "bend_radius"
        raise fail(f"{path}.{key}", getattr(f, key), f"none on a {f.kind}", "applies to bends")
    if f.kind != "reducer" and f.taper_length is not None:
        raise fail(
            f"{path}.taper_length", f.taper_length, f"none on a {f.kind}", "applies to reducers"
        )
    g = net.geometry[f.id]
    if f.kind == "bend":
        _check_bend(net, path, f, g)
    elif f.kind == "reducer":
        _check_reducer(net, path, f, g)
    elif f.kind in ("tee", "wye", "cross"):
        _check_junction(net, path, f, g)


def _check_bend(net: PipeNetwork, path: str, f: Fitting, g: FittingGeometry) -> None:
    check_choice(f"{path}.style", f.style, BEND_STYLES)
    lo, hi = BEND_ANGLE_RANGE
    if not lo - 1e-6 <= g.deflection <= hi + 1e-6:
        raise fail(
            f"{path}.position",
            list(f.position),
            f"a deflection of {math.degrees(lo):.0f} to {math.degrees(hi):.0f} deg "
            f"({lo:.3f} to {hi:.3f} rad)",
            f"deflection {math.degrees(g.deflection):.2f} deg out of range",
        )
    d0, d1 = (p.diameter for p in g.ports)
    if abs(d0 - d1) > 1e-9:
        raise fail(
            f"{_run_path_by_id(net, g.ports[1].run_id)}.diameter",
            d1,
            f"{d0} m (a bend's two runs share one diameter)",
            "differs from the other run's",
        )
    if f.style == "long":
        rmin, rmax = BEND_RADIUS_RANGE
        ratio = (f.bend_radius or 0.0) / d0
        if f.bend_radius is None or not rmin - 1e-9 <= ratio <= rmax + 1e-9:
            raise fail(
                f"{path}.bend_radius",
                f.bend_radius,
                f"{rmin:g} to {rmax:g} D = {rmin * d0:.4f} to {rmax * d0:.4f} m",
                f"{ratio:.2f} D, out of range",
            )
    elif f.bend_radius is not None:
        raise fail(f"{path}.bend_radius", f.bend_radius, "none on a mitre bend", "not used")


def _check_reducer(net: PipeNetwork, path: str, f: Fitting, g: FittingGeometry) -> None:
    if not g.collinear_pairs():
        raise fail(
            f"{path}.position",
            list(f.position),
            f"positions making its two runs collinear (within {_ANGLE_TOL:g} deg)",
            "its runs are not collinear",
        )
    lo, hi = TAPER_LENGTH_RANGE
    taper = check_number(f"{path}.taper_length", f.taper_length, lo, hi, unit="m")
    d0, d1 = (p.diameter for p in g.ports)
    if abs(d0 - d1) < 1e-3:
        raise fail(
            f"{_run_path_by_id(net, g.ports[1].run_id)}.diameter",
            d1,
            f"a diameter at least 1 mm from the other run's {d0} m",
            "joins equal diameters: a reducer must change the diameter",
        )
    half_angle = math.atan2(abs(d0 - d1) / 2.0, taper)
    if half_angle > MAX_TAPER_HALF_ANGLE:
        shortest = abs(d0 - d1) / 2.0 / math.tan(MAX_TAPER_HALF_ANGLE)
        raise fail(
            f"{path}.taper_length",
            f.taper_length,
            f"at least {shortest:.4f} m (a taper half-angle of at most "
            f"{math.degrees(MAX_TAPER_HALF_ANGLE):.0f} deg)",
            f"taper half-angle {math.degrees(half_angle):.1f} deg",
        )


def _check_junction(net: PipeNetwork, path: str, f: Fitting, g: FittingGeometry) -> None:
    pairs = g.collinear_pairs()
    want_pairs = 2 if f.kind == "cross" else 1
    if len(pairs) != want_pairs:
        raise fail(
            f"{path}.position",
            list(f.position),
            f"{want_pairs} straight run(s) through a {f.kind} (collinear pairs of runs)",
            f"{len(pairs)} found",
        )
    for i, j in pairs:
        if abs(g.ports[i].diameter - g.ports[j].diameter) > 1e-9:
            raise fail(
                f"{_run_path_by_id(net, g.ports[j].run_id)}.diameter",
                g.ports[j].diameter,
                f"{g.ports[i].diameter} m (the run through {f.id!r} keeps one diameter)",
                f"differs from run {g.ports[i].run_id!r} on the run through",
            )
    main = pairs[0]
    for i in (i for i in range(len(g.ports)) if i not in main):
        _check_branch(net, f, g, i, main)
    if f.kind == "cross":
        a0, a1 = g.ports[pairs[0][0]].axis, g.ports[pairs[1][0]].axis
        ang = math.degrees(math.acos(float(np.clip(abs(a0 @ a1), 0, 1))))
        if abs(ang - 90.0) > _ANGLE_TOL:
            raise fail(
                f"{path}.position",
                list(f.position),
                f"its two runs through at 90 deg (within {_ANGLE_TOL:g} deg)",
                f"they meet at {ang:.2f} deg",
            )


def _check_branch(
    net: PipeNetwork, f: Fitting, g: FittingGeometry, i: int, main: tuple[int, int]
) -> None:
    port = g.ports[i]
    branch = _run_path_by_id(net, port.run_id)
    want = 45.0 if f.kind == "wye" else 90.0
    angle = min(
        math.degrees(math.acos(float(np.clip(port.axis @ g.ports[j].axis, -1, 1)))) for j in main
    )
    if abs(angle - want) > _ANGLE_TOL:
        other = net.run_by_id[port.run_id].other(f.id)
        raise fail(
            f"{branch}.{'a' if net.run_by_id[port.run_id].a == other else 'b'}",
            other,
            f"a fitting placed {want:.0f} deg (within {_ANGLE_TOL:g} deg) from the run "
            f"through {f.kind} {f.id!r}",
            f"branch at {angle:.2f} deg to the run through",
        )
    main_d = g.ports[main[0]].diameter
    if port.diameter > main_d + 1e-9:
        raise fail(
            f"{branch}.diameter",
            port.diameter,
            f"at most the run-through diameter {main_d} m of {f.kind} {f.id!r}",
            "branch wider than the run through",
        )


# ------------------------------------------------------------------ lengths, clearance
def _check_run_lengths(net: PipeNetwork) -> None:
    for i, r in enumerate(net.runs):
        need = net.geometry[r.a].port(r.id).leg + net.geometry[r.b].port(r.id).leg
        have = _node_distance(net, r)
        if have < need - 1e-9:
            raise fail(
                run_path(i, r),
                round(have, 6),
                f"at least {need:.4f} m between the centres of {r.a!r} and {r.b!r} (their legs)",
                f"too short for its fittings: {have:.4f} m between their centres",
            )


def _segments(net: PipeNetwork) -> list[tuple[Any, Any]]:
    seg = []
    for r in net.runs:
        a, b = net.position(r.a), net.position(r.b)
        d = (b - a) / np.linalg.norm(b - a)
        # a closure's end wall sits beyond its node by the wall thickness
        if net.fitting_by_id[r.a].kind == "closure":
            a = a - d * WALL_CLEARANCE
        if net.fitting_by_id[r.b].kind == "closure":
            b = b + d * WALL_CLEARANCE
        seg.append((a, b))
    return seg


def _check_clearance(net: PipeNetwork) -> None:
    runs = net.runs
    if len(runs) < 2:
        return
    seg = _segments(net)
    lo = np.array([np.minimum(a, b) for a, b in seg])
    hi = np.array([np.maximum(a, b) for a, b in seg])
    rad = np.array([0.5 * r.diameter + WALL_CLEARANCE for r in runs])
    for i in range(len(runs)):
        for j in range(i + 1, len(runs)):
            ri, rj = runs[i], runs[j]
            need = rad[i] + rad[j]
            if {ri.a, ri.b} & {rj.a, rj.b} or (
                np.any(lo[i] - need > hi[j]) or np.any(lo[j] - need > hi[i])
            ):
                continue
            dist = segment_distance(seg[i][0], seg[i][1], seg[j][0], seg[j][1])
            if dist < need:
                raise fail(
                    run_path(i, ri),
                    [ri.a, ri.b],
                    f"centrelines at least {need:.4f} m apart",
                    f"intersects {run_path(j, rj)} ({rj.a}-{rj.b}): centrelines {dist:.4f} m apart",
                )


# ------------------------------------------------------------------------------ points
def _check_points(net: PipeNetwork) -> None:
    start = net.start_pose
    if start is not None:
        loc = net.centreline.nearest(start.position)
        if loc.distance > 0.5 * loc.diameter:
            raise fail(
                "start.position",
                start.position.tolist(),
                f"inside the bore (within {0.5 * loc.diameter:.4f} m of the centreline)",
                f"{loc.distance:.4f} m from the nearest centreline",
            )
        cos = abs(float(start.forward @ loc.tangent))
        if cos < math.cos(MAX_START_TILT):
            raise fail(
                "start.forward",
                start.forward.tolist(),
                f"at most {math.degrees(MAX_START_TILT):.0f} deg off the pipe axis",
                f"{math.degrees(math.acos(min(cos, 1.0))):.1f} deg off the pipe axis",
            )
    for i, g in enumerate(net.goals):
        loc = net.centreline.nearest(np.asarray(g))
        if loc.distance > 0.5 * loc.diameter:
            raise fail(
                f"goals[{i}]",
                list(g),
                f"inside the bore (within {0.5 * loc.diameter:.4f} m of the centreline)",
                f"{loc.distance:.4f} m from the nearest centreline",
            )
