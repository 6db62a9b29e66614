"""Canonical single-structure networks for experiments and tests.

Every layout puts the structure's reference point at the world origin, the incoming pipe along
+x, and ``start_pose`` on the incoming centreline ``distance`` metres before the reference point
with the identity rotation (x forward, y left, z up). Outgoing pipes end in closures
``outlet_length`` metres beyond their fitting. Angles are radians; ``direction`` is the roll of
the outgoing axis as docs/design.md defines it (0 = left, pi/2 = up, pi = right), so the
ground-truth option of a layout reports exactly the parameters it was built with.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from detector.geometry import Pose, direction_from_angles
from detector.validation import check_choice, check_number, fail
from pipe_env.fittings import build_fitting
from pipe_env.network import Fitting, PipeNetwork, Run

#: Straight pipe kept behind the start pose so that the robot body fits, metres.
BEHIND = 0.6
X = np.array([1.0, 0.0, 0.0])


def _check(name: str, value: float, lo: float, hi: float, unit: str) -> None:
    check_number(name, value, lo, hi, unit, where="layout")


def _assemble(
    name: str,
    diameter_in: float,
    kind: str,
    centre: NDArray[np.float64],
    outs: list[tuple[NDArray[np.float64], float]],
    distance: float,
    outlet_length: float,
    params: dict[str, Any],
    metadata: dict[str, Any],
) -> PipeNetwork:
    """Entry cap -> fitting at ``centre`` -> one closure per outgoing axis."""
    _check("distance", distance, 0.0, 10.0, "m")
    _check("outlet_length", outlet_length, 0.05, 10.0, "m")
    ports = [("in", -X, diameter_in)] + [(f"o{i}", v, d) for i, (v, d) in enumerate(outs)]
    geo = build_fitting(
        "s",
        kind,
        centre,
        ports,
        params.get("style"),
        params.get("bend_radius"),
        params.get("taper_length"),
    )
    cap_leg = build_fitting("c", "closure", np.zeros(3), [("in", X, diameter_in)]).ports[0].leg
    ref = geo.reference_point("in")
    entry_x = ref[0] - distance - BEHIND - cap_leg
    entry_x = min(entry_x, centre[0] - geo.port("in").leg - 0.05 - cap_leg)
    fittings = [
        Fitting("entry", "closure", (entry_x, 0.0, 0.0)),
        Fitting("s", kind, tuple(centre), **params),
    ]
    runs = [Run("r_in", "entry", "s", diameter_in)]
    for i, (v, d) in enumerate(outs):
        leg_out = build_fitting("c", "closure", np.zeros(3), [("in", -v, d)]).ports[0].leg
        end = centre + v * (geo.port(f"o{i}").leg + outlet_length + leg_out)
        fittings.append(Fitting(f"out{i}", "closure", tuple(end)))
        runs.append(Run(f"r_out{i}", "s", f"out{i}", d))
    start = Pose(np.array([ref[0] - distance, 0.0, 0.0]), np.eye(3))
    net = PipeNetwork(tuple(fittings), tuple(runs), start, (), name, metadata)
    net.validate()
    return net


def straight(diameter: float = 0.1, distance: float = 3.0) -> PipeNetwork:
    """A straight pipe whose end wall is ``distance`` m ahead (beyond a 2 m sensor by default)."""
    _check("diameter", diameter, 0.02, 0.25, "m")
    _check("distance", distance, 0.05, 20.0, "m")
    cap_leg = 0.25 * diameter
    fittings = (
        Fitting("entry", "closure", (-BEHIND - cap_leg, 0.0, 0.0)),
        Fitting("end", "closure", (distance, 0.0, 0.0)),
    )
    runs = (Run("r_in", "entry", "end", diameter),)
    net = PipeNetwork(
        fittings,
        runs,
        Pose.identity(),
        (),
        "straight",
        {"diameter": diameter, "distance": distance},
    )
    net.validate()
    return net


def closure(diameter: float = 0.1, distance: float = 0.4) -> PipeNetwork:
    """A pipe ending in an end wall ``distance`` m ahead (the thesis's reduction to 0 mm)."""
    _check("diameter", diameter, 0.02, 0.25, "m")
    _check("distance", distance, 0.0, 10.0, "m")
    cap_leg = 0.25 * diameter
    fittings = (
        Fitting("entry", "closure", (-distance - BEHIND - cap_leg, 0.0, 0.0)),
        Fitting("s", "closure", (0.0, 0.0, 0.0)),
    )
    runs = (Run("r_in", "entry", "s", diameter),)
    start = Pose(np.array([-distance, 0.0, 0.0]), np.eye(3))
    net = PipeNetwork(
        fittings, runs, start, (), "closure", {"diameter": diameter, "distance": distance}
    )
    net.validate()
    return net


def reducer(
    diameter_in: float = 0.1,
    diameter_out: float = 0.055,
    taper_length: float = 0.2,
    distance: float = 0.4,
    outlet_length: float = 0.6,
) -> PipeNetwork:
    """A concentric reducer (or expander) whose taper starts ``distance`` m ahead."""
    _check("diameter_in", diameter_in, 0.02, 0.25, "m")
    _check("diameter_out", diameter_out, 0.02, 0.25, "m")
    _check("taper_length", taper_length, 0.005, 1.0, "m")
    centre = X * (0.5 * taper_length)
    return _assemble(
        "reducer",
        diameter_in,
        "reducer",
        centre,
        [(X.copy(), diameter_out)],
        distance,
        outlet_length,
        {"taper_length": taper_length},
        {
            "diameter_in": diameter_in,
            "diameter_out": diameter_out,
            "taper_length": taper_length,
            "distance": distance,
        },
    )


def mitre_bend(
    diameter: float = 0.1,
    angle: float = math.pi / 2,
    direction: float = 0.0,
    distance: float = 0.4,
    outlet_length: float = 0.6,
) -> PipeNetwork:
    """A sharp (mitre) bend turning ``angle`` towards roll ``direction``, ``distance`` m ahead."""
    _check("diameter", diameter, 0.02, 0.25, "m")
    _check("angle", angle, math.radians(30), math.radians(90), "rad")
    _check("direction", direction, -2 * math.pi, 2 * math.pi, "rad")
    out = direction_from_angles(angle, direction)
    return _assemble(
        "mitre_bend",
        diameter,
        "bend",
        np.zeros(3),
        [(out, diameter)],
        distance,
        outlet_length,
        {"style": "mitre"},
        {"diameter": diameter, "angle": angle, "direction": direction, "distance": distance},
    )


def long_bend(
    diameter: float = 0.1,
    angle: float = math.pi / 2,
    direction: float = 0.0,
    distance: float = 0.4,
    radius_factor: float = 1.5,
    outlet_length: float = 0.6,
) -> PipeNetwork:
    """A long-radius bend (radius ``radius_factor`` x diameter, 1-3) whose centrelines meet
    ``distance`` m ahead."""
    _check("diameter", diameter, 0.02, 0.25, "m")
    _check("angle", angle, math.radians(30), math.radians(90), "rad")
    _check("radius_factor", radius_factor, 1.0, 3.0, "D")
    _check("direction", direction, -2 * math.pi, 2 * math.pi, "rad")
    out = direction_from_angles(angle, direction)
    return _assemble(
        "long_bend",
        diameter,
        "bend",
        np.zeros(3),
        [(out, diameter)],
        distance,
        outlet_length,
        {"style": "long", "bend_radius": radius_factor * diameter},
        {
            "diameter": diameter,
            "angle": angle,
            "direction": direction,
            "distance": distance,
            "radius_factor": radius_factor,
        },
    )


def t_junction(
    diameter: float = 0.1,
    branch_diameter: float | None = None,
    direction: float = 0.0,
    distance: float = 0.4,
    entry: str = "run",
    outlet_length: float = 0.6,
) -> PipeNetwork:
    """A tee. ``entry="run"``: arrive along the run; ways on are straight and a 90 deg branch
    towards ``direction``. ``entry="stem"``: arrive up the branch (diameter ``branch_diameter``);
    the run's two ends lie towards ``direction`` and ``direction + pi``."""
    _check("diameter", diameter, 0.02, 0.25, "m")
    db = diameter if branch_diameter is None else branch_diameter
    _check("branch_diameter", db, 0.02, diameter, "m")
    _check("direction", direction, -2 * math.pi, 2 * math.pi, "rad")
    side = direction_from_angles(math.pi / 2, direction)
    meta = {
        "diameter": diameter,
        "branch_diameter": db,
        "direction": direction,
        "distance": distance,
        "entry": entry,
    }
    if entry == "run":
        outs = [(X.copy(), diameter), (side, db)]
        return _assemble(
            "t_junction", diameter, "tee", np.zeros(3), outs, distance, outlet_length, {}, meta
        )
    if entry == "stem":
        outs = [(side, diameter), (-side, diameter)]
        return _assemble(
            "t_junction", db, "tee", np.zeros(3), outs, distance, outlet_length, {}, meta
        )
    raise fail("t_junction.entry", entry, "'run', 'stem'")


def y_junction(
    diameter: float = 0.1,
    branch_diameter: float | None = None,
    direction: float = 0.0,
    distance: float = 0.4,
    entry: str = "run",
    outlet_length: float = 0.6,
) -> PipeNetwork:
    """A wye. ``entry="run"``: ways on are straight and a 45 deg branch towards ``direction``.
    ``entry="branch"``: arrive down the branch; ways on deflect by 45 deg (towards
    ``direction``) and 135 deg (towards ``direction + pi``)."""
    _check("diameter", diameter, 0.02, 0.25, "m")
    db = diameter if branch_diameter is None else branch_diameter
    _check("branch_diameter", db, 0.02, diameter, "m")
    _check("direction", direction, -2 * math.pi, 2 * math.pi, "rad")
    meta = {
        "diameter": diameter,
        "branch_diameter": db,
        "direction": direction,
        "distance": distance,
        "entry": entry,
    }
    if entry == "run":
        outs = [(X.copy(), diameter), (direction_from_angles(math.pi / 4, direction), db)]
        return _assemble(
            "y_junction", diameter, "wye", np.zeros(3), outs, distance, outlet_length, {}, meta
        )
    if entry == "branch":
        fwd = direction_from_angles(math.pi / 4, direction)
        outs = [(fwd, diameter), (-fwd, diameter)]
        return _assemble(
            "y_junction", db, "wye", np.zeros(3), outs, distance, outlet_length, {}, meta
        )
    raise fail("y_junction.entry", entry, "'run', 'branch'")


def cross_junction(
    diameter: float = 0.1,
    branch_diameter: float | None = None,
    direction: float = 0.0,
    distance: float = 0.4,
    outlet_length: float = 0.6,
) -> PipeNetwork:
    """A cross arrived at along its run: straight on, and branches towards ``direction`` and
    ``direction + pi``."""
    _check("diameter", diameter, 0.02, 0.25, "m")
    db = diameter if branch_diameter is None else branch_diameter
    _check("branch_diameter", db, 0.02, diameter, "m")
    _check("direction", direction, -2 * math.pi, 2 * math.pi, "rad")
    side = direction_from_angles(math.pi / 2, direction)
    outs = [(X.copy(), diameter), (side, db), (-side, db)]
    meta = {
        "diameter": diameter,
        "branch_diameter": db,
        "direction": direction,
        "distance": distance,
    }
    return _assemble(
        "cross_junction", diameter, "cross", np.zeros(3), outs, distance, outlet_length, {}, meta
    )


#: Layout builders by name, for configuration files and the CLI.
LAYOUTS: dict[str, Callable[..., PipeNetwork]] = {
    "straight": straight,
    "closure": closure,
    "reducer": reducer,
    "mitre_bend": mitre_bend,
    "long_bend": long_bend,
    "t_junction": t_junction,
    "y_junction": y_junction,
    "cross_junction": cross_junction,
}


def make_layout(name: str, **params: Any) -> PipeNetwork:
    """Build layout ``name`` with keyword ``params``; errors name the layout and the parameter."""
    check_choice("layout", name, sorted(LAYOUTS))
    try:
        return LAYOUTS[name](**params)
    except TypeError as exc:
        raise fail("params", params, f"the parameters of {name}", str(exc), "layout") from exc
