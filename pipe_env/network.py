"""The pipe network model: fittings joined by straight runs, with validation and (de)serialisation.

A network is a 3D graph. Each node is a *fitting* at a world position (metres); each edge is a
straight *run* of one inner diameter between two fittings. Fitting shapes are derived from the
node positions (see :mod:`pipe_env.fittings`), so a network written by hand only needs node
positions, kinds, a few parameters and run diameters::

    {"version": 1,
     "fittings": [{"id": "in", "kind": "closure", "position": [0, 0, 0]},
                  {"id": "b", "kind": "bend", "position": [1, 0, 0], "style": "mitre"},
                  {"id": "out", "kind": "closure", "position": [1, 1, 0]}],
     "runs": [{"id": "r0", "a": "in", "b": "b", "diameter": 0.1},
              {"id": "r1", "a": "b", "b": "out", "diameter": 0.1}],
     "start": {"position": [0.5, 0, 0], "forward": [1, 0, 0]},
     "goals": [[1, 0.8, 0]]}

Fitting kinds: ``closure`` (end wall or obstacle, one run), ``reducer`` (two collinear runs of
different diameters; ``taper_length``), ``bend`` (two runs, deflection 30-90 deg; ``style``
``mitre`` or ``long`` with ``bend_radius`` 1-3 D), ``tee`` (run through plus a 90 deg branch),
``wye`` (run through plus a 45 deg branch) and ``cross`` (two perpendicular runs through).

Queries (ground truth, centreline, geodesic distance) live in their own modules and are exposed
here as methods.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from detector.geometry import Pose, segment_distance
from pipe_env.fittings import (
    AXIS_TOLERANCE,
    BEND_STYLES,
    FITTING_DEGREE,
    FittingGeometry,
    build_fitting,
)

if TYPE_CHECKING:
    from detector.options import StructureOption
    from pipe_env.centreline import Centreline, CentrelinePoint
    from pipe_env.generator import NetworkConfig

SCHEMA_VERSION = 1
#: Inner diameters a network may contain, metres. Wider than the robot's 57-125 mm so that
#: networks can hold pipes the robot must refuse (a reducer to 40 mm) or the thesis's 20 cm rig.
NETWORK_DIAMETER_RANGE = (0.020, 0.250)
BEND_ANGLE_RANGE = (math.radians(30.0), math.radians(90.0))
BEND_RADIUS_RANGE = (1.0, 3.0)  # long-radius bends, in diameters
TAPER_LENGTH_RANGE = (0.005, 1.0)  # metres
MAX_TAPER_HALF_ANGLE = math.radians(60.0)
#: Wall thickness assumed when checking clearance between non-adjacent pipes, metres.
WALL_CLEARANCE = 0.005
#: Largest coordinate of a fitting, goal or start position, metres (absurd geometry beyond it
#: is rejected by :meth:`PipeNetwork.validate`).
MAX_EXTENT = 1000.0
_ANGLE_TOL = math.degrees(AXIS_TOLERANCE)


@dataclass(frozen=True)
class Fitting:
    """A node of the network (see module docstring). Positions in metres."""

    id: str
    kind: str
    position: tuple[float, float, float]
    style: str | None = None
    bend_radius: float | None = None
    taper_length: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "id", str(self.id))
        try:
            pos = tuple(float(v) for v in self.position)
        except (TypeError, ValueError, OverflowError) as exc:
            raise ValueError(
                f"fitting {self.id!r}: position must be three numbers, got {self.position!r}"
            ) from exc
        if len(pos) != 3 or not all(math.isfinite(v) for v in pos):
            raise ValueError(
                f"fitting {self.id!r}: position must be three finite numbers, got {self.position!r}"
            )
        object.__setattr__(self, "position", pos)
        if not isinstance(self.kind, str):
            raise ValueError(f"fitting {self.id!r}: kind must be a string, got {self.kind!r}")
        if self.style is not None and not isinstance(self.style, str):
            raise ValueError(f"fitting {self.id!r}: style must be a string, got {self.style!r}")
        for key in ("bend_radius", "taper_length"):
            value = getattr(self, key)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
                raise ValueError(
                    f"fitting {self.id!r}: {key} must be a number in metres, got {value!r}"
                )
            object.__setattr__(self, key, float(value))
        if self.kind == "bend" and self.style is None:
            object.__setattr__(self, "style", "mitre")

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"id": self.id, "kind": self.kind, "position": list(self.position)}
        for key in ("style", "bend_radius", "taper_length"):
            if getattr(self, key) is not None:
                d[key] = getattr(self, key)
        return d


@dataclass(frozen=True)
class Run:
    """A straight pipe between fittings ``a`` and ``b`` with one inner ``diameter`` (metres)."""

    id: str
    a: str
    b: str
    diameter: float

    def __post_init__(self) -> None:
        for key in ("id", "a", "b"):
            object.__setattr__(self, key, str(getattr(self, key)))
        try:
            if isinstance(self.diameter, (bool, str)):
                raise TypeError
            object.__setattr__(self, "diameter", float(self.diameter))
        except (TypeError, ValueError, OverflowError) as exc:
            raise ValueError(
                f"run {self.id!r}: diameter must be a number in metres, got {self.diameter!r}"
            ) from exc

    def other(self, node_id: str) -> str:
        return self.b if node_id == self.a else self.a

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "a": self.a, "b": self.b, "diameter": self.diameter}


@dataclass(frozen=True, eq=False)
class PipeNetwork:
    """A pipe network: fittings, runs, an optional start pose and goal points.

    Build one by hand, with :func:`pipe_env.generator.generate_network`, or from
    :mod:`pipe_env.layouts`. Call :meth:`validate` before trusting a hand-written one; every
    query validates lazily on first use.
    """

    fittings: tuple[Fitting, ...]
    runs: tuple[Run, ...]
    start_pose: Pose | None = None
    goals: tuple[tuple[float, float, float], ...] = ()
    name: str = "network"
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "fittings", tuple(self.fittings))
        object.__setattr__(self, "runs", tuple(self.runs))
        goals = []
        for i, g in enumerate(self.goals):
            try:
                arr = np.asarray(g, dtype=float)
            except (TypeError, ValueError, OverflowError):
                arr = np.full(1, np.nan)
            if arr.shape != (3,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"goals[{i}] must be three finite numbers (m), got {g!r}")
            goals.append(tuple(float(v) for v in arr))
        object.__setattr__(self, "goals", tuple(goals))

    # ------------------------------------------------------------------ lookup
    @cached_property
    def fitting_by_id(self) -> dict[str, Fitting]:
        return {f.id: f for f in self.fittings}

    @cached_property
    def run_by_id(self) -> dict[str, Run]:
        return {r.id: r for r in self.runs}

    @cached_property
    def runs_at(self) -> dict[str, list[Run]]:
        """Runs attached to each fitting id, in the order they appear in ``runs``."""
        table: dict[str, list[Run]] = {f.id: [] for f in self.fittings}
        for r in self.runs:
            for end in (r.a, r.b):
                if end in table:
                    table[end].append(r)
        return table

    def position(self, node_id: str) -> NDArray[np.float64]:
        return np.asarray(self.fitting_by_id[node_id].position, dtype=float)

    @cached_property
    def geometry(self) -> dict[str, FittingGeometry]:
        """Derived :class:`FittingGeometry` per fitting id (validates the topology first)."""
        self._validate_topology()
        return {f.id: self._build_geometry(f) for f in self.fittings}

    def _build_geometry(self, f: Fitting) -> FittingGeometry:
        centre = self.position(f.id)
        ports = []
        for r in self.runs_at[f.id]:
            other = self.position(r.other(f.id))
            axis = other - centre
            axis = axis / np.linalg.norm(axis)
            ports.append((r.id, axis, r.diameter))
        return build_fitting(f.id, f.kind, centre, ports, f.style, f.bend_radius, f.taper_length)

    def straight_length(self, run_id: str) -> float:
        """Length of a run's straight pipe between its fittings' port planes, metres."""
        r = self.run_by_id[run_id]
        legs = self.geometry[r.a].port(r.id).leg + self.geometry[r.b].port(r.id).leg
        return self._node_distance(r) - legs

    def _node_distance(self, r: Run) -> float:
        return float(np.linalg.norm(self.position(r.b) - self.position(r.a)))

    @property
    def closures(self) -> list[str]:
        return [f.id for f in self.fittings if f.kind == "closure"]

    # -------------------------------------------------------------- validation
    def _validate_topology(self) -> None:
        if not self.runs:
            raise ValueError("a network needs at least one run (and its two fittings)")
        ids: set[str] = set()
        for f in self.fittings:
            if f.id in ids:
                raise ValueError(f"fitting id {f.id!r} is used twice; ids must be unique")
            ids.add(f.id)
            if f.kind not in FITTING_DEGREE:
                raise ValueError(
                    f"fitting {f.id!r}: kind {f.kind!r} is unknown; allowed: "
                    f"{sorted(FITTING_DEGREE)}"
                )
        run_ids: set[str] = set()
        pairs: set[frozenset[str]] = set()
        for r in self.runs:
            if r.id in run_ids or r.id in ids:
                raise ValueError(f"run id {r.id!r} is used twice; ids must be unique")
            run_ids.add(r.id)
            for end in ("a", "b"):
                ref = getattr(r, end)
                if ref not in ids:
                    raise ValueError(
                        f"run {r.id!r}: end {end}={ref!r} is not a fitting of this network "
                        "(dangling reference)"
                    )
            if r.a == r.b:
                raise ValueError(f"run {r.id!r} joins fitting {r.a!r} to itself")
            key = frozenset((r.a, r.b))
            if key in pairs:
                raise ValueError(f"run {r.id!r}: fittings {r.a!r} and {r.b!r} are already joined")
            pairs.add(key)
            if self._node_distance(r) < 1e-6:
                raise ValueError(f"run {r.id!r}: fittings {r.a!r} and {r.b!r} are at one position")
        for f in self.fittings:
            degree = len(self.runs_at[f.id])
            if degree != FITTING_DEGREE[f.kind]:
                raise ValueError(
                    f"fitting {f.id!r} ({f.kind}) has {degree} runs; a {f.kind} joins exactly "
                    f"{FITTING_DEGREE[f.kind]}"
                )

    def validate(self, diameter_range: tuple[float, float] = NETWORK_DIAMETER_RANGE) -> None:
        """Check the whole network; raise ``ValueError`` naming the element, value and range.

        Checks ids and references, fitting degrees and parameters, diameters within
        ``diameter_range`` (m), bend and junction angles, run lengths against their fittings'
        legs, clearance between pipes that do not share a fitting, the start pose and goals.
        """
        self._validate_extent()
        self._validate_topology()
        lo, hi = diameter_range
        for r in self.runs:
            if not (math.isfinite(r.diameter) and lo <= r.diameter <= hi):
                raise ValueError(
                    f"run {r.id!r}: diameter {r.diameter!r} m is outside the allowed range "
                    f"[{lo}, {hi}] m"
                )
        for f in self.fittings:
            self._validate_fitting(f)
        for r in self.runs:
            need = self.geometry[r.a].port(r.id).leg + self.geometry[r.b].port(r.id).leg
            have = self._node_distance(r)
            if have < need - 1e-9:
                raise ValueError(
                    f"run {r.id!r} between {r.a!r} and {r.b!r} is {have:.4f} m between fitting "
                    f"centres but its fittings need at least {need:.4f} m (too short for them)"
                )
        self._validate_clearance()
        self._validate_points()

    def _validate_extent(self) -> None:
        """Fittings, goals and the start within :data:`MAX_EXTENT` of the origin, and run
        diameters finite (absurd geometry is rejected before any is derived)."""
        for i, f in enumerate(self.fittings):
            if max(abs(v) for v in f.position) > MAX_EXTENT:
                raise ValueError(
                    f"fittings[{i}].position: fitting {f.id!r} at {list(f.position)} m is "
                    f"outside the allowed extent; allowed: coordinates within +-{MAX_EXTENT:g} m"
                )
        for i, g in enumerate(self.goals):
            if max(abs(v) for v in g) > MAX_EXTENT:
                raise ValueError(
                    f"goals[{i}]: {list(g)} m is outside the allowed extent; allowed: "
                    f"coordinates within +-{MAX_EXTENT:g} m"
                )
        if self.start_pose is not None and np.max(np.abs(self.start_pose.position)) > MAX_EXTENT:
            raise ValueError(
                f"start.position: {self.start_pose.position.tolist()} m is outside the allowed "
                f"extent; allowed: coordinates within +-{MAX_EXTENT:g} m"
            )
        for i, r in enumerate(self.runs):
            if not math.isfinite(r.diameter):
                raise ValueError(
                    f"runs[{i}].diameter: run {r.id!r} has diameter {r.diameter!r}; allowed: a "
                    "finite number of metres"
                )

    def _validate_fitting(self, f: Fitting) -> None:
        g = self.geometry[f.id]
        ports = g.ports
        diam = [p.diameter for p in ports]
        label = f"fitting {f.id!r} ({f.kind})"
        if f.kind != "bend" and (f.style is not None or f.bend_radius is not None):
            raise ValueError(f"{label}: style and bend_radius apply only to bends")
        if f.kind != "reducer" and f.taper_length is not None:
            raise ValueError(f"{label}: taper_length applies only to reducers")
        if f.kind == "bend":
            if f.style not in BEND_STYLES:
                raise ValueError(f"{label}: style {f.style!r} is not one of {BEND_STYLES}")
            theta = g.deflection
            lo, hi = BEND_ANGLE_RANGE
            if not lo - 1e-6 <= theta <= hi + 1e-6:
                raise ValueError(
                    f"{label}: deflection {math.degrees(theta):.2f} deg is outside the allowed "
                    f"range [{math.degrees(lo):.0f}, {math.degrees(hi):.0f}] deg"
                )
            if abs(diam[0] - diam[1]) > 1e-9:
                raise ValueError(f"{label}: both runs must have one diameter, got {diam} m")
            if f.style == "long":
                rmin, rmax = BEND_RADIUS_RANGE
                ratio = (f.bend_radius or 0.0) / diam[0]
                if f.bend_radius is None or not rmin - 1e-9 <= ratio <= rmax + 1e-9:
                    raise ValueError(
                        f"{label}: bend_radius {f.bend_radius!r} m is {ratio:.2f} D; allowed "
                        f"[{rmin}, {rmax}] D = [{rmin * diam[0]:.4f}, {rmax * diam[0]:.4f}] m"
                    )
            elif f.bend_radius is not None:
                raise ValueError(f"{label}: a mitre bend takes no bend_radius")
        elif f.kind == "reducer":
            if not g.collinear_pairs():
                raise ValueError(
                    f"{label}: its two runs must be collinear (within {_ANGLE_TOL} deg)"
                )
            lo, hi = TAPER_LENGTH_RANGE
            if f.taper_length is None or not lo <= f.taper_length <= hi:
                raise ValueError(
                    f"{label}: taper_length {f.taper_length!r} m is outside [{lo}, {hi}] m"
                )
            if abs(diam[0] - diam[1]) < 1e-3:
                raise ValueError(
                    f"{label}: joins equal diameters {diam} m; a reducer must change the diameter "
                    "by at least 1 mm"
                )
            half_angle = math.atan2(abs(diam[0] - diam[1]) / 2.0, f.taper_length)
            if half_angle > MAX_TAPER_HALF_ANGLE:
                raise ValueError(
                    f"{label}: taper half-angle {math.degrees(half_angle):.1f} deg exceeds "
                    f"{math.degrees(MAX_TAPER_HALF_ANGLE):.0f} deg; lengthen taper_length"
                )
        elif f.kind in ("tee", "wye", "cross"):
            self._validate_junction(f, g)

    def _validate_junction(self, f: Fitting, g: FittingGeometry) -> None:
        label = f"fitting {f.id!r} ({f.kind})"
        pairs = g.collinear_pairs()
        want_pairs = 2 if f.kind == "cross" else 1
        if len(pairs) != want_pairs:
            raise ValueError(
                f"{label}: needs {want_pairs} straight run(s) through it (collinear port pairs), "
                f"found {len(pairs)}"
            )
        main = pairs[0]
        for i, j in pairs:
            if abs(g.ports[i].diameter - g.ports[j].diameter) > 1e-9:
                raise ValueError(
                    f"{label}: the run through ({g.ports[i].run_id!r}, {g.ports[j].run_id!r}) must "
                    f"keep one diameter, got {g.ports[i].diameter} and {g.ports[j].diameter} m"
                )
        branch_idx = [i for i in range(len(g.ports)) if i not in main]
        want = 45.0 if f.kind == "wye" else 90.0
        for i in branch_idx:
            angles = sorted(
                math.degrees(math.acos(float(np.clip(g.ports[i].axis @ g.ports[j].axis, -1, 1))))
                for j in main
            )
            if abs(angles[0] - want) > _ANGLE_TOL:
                raise ValueError(
                    f"{label}: branch {g.ports[i].run_id!r} is at {angles[0]:.2f} deg to the run "
                    f"through; a {f.kind} needs {want:.0f} deg (within {_ANGLE_TOL} deg)"
                )
            if g.ports[i].diameter > g.ports[main[0]].diameter + 1e-9:
                raise ValueError(
                    f"{label}: branch {g.ports[i].run_id!r} diameter {g.ports[i].diameter} m "
                    f"exceeds the run-through diameter {g.ports[main[0]].diameter} m"
                )
        if f.kind == "cross":
            a0, a1 = g.ports[pairs[0][0]].axis, g.ports[pairs[1][0]].axis
            ang = math.degrees(math.acos(float(np.clip(abs(a0 @ a1), 0, 1))))
            if abs(ang - 90.0) > _ANGLE_TOL:
                raise ValueError(f"{label}: its two runs through meet at {ang:.2f} deg, need 90")

    def _validate_clearance(self) -> None:
        runs = self.runs
        if len(runs) < 2:
            return
        seg = []
        for r in runs:
            a, b = self.position(r.a), self.position(r.b)
            d = (b - a) / np.linalg.norm(b - a)
            # a closure's end wall sits beyond its node by the wall thickness
            if self.fitting_by_id[r.a].kind == "closure":
                a = a - d * WALL_CLEARANCE
            if self.fitting_by_id[r.b].kind == "closure":
                b = b + d * WALL_CLEARANCE
            seg.append((a, b))
        lo = np.array([np.minimum(a, b) for a, b in seg])
        hi = np.array([np.maximum(a, b) for a, b in seg])
        rad = np.array([0.5 * r.diameter + WALL_CLEARANCE for r in runs])
        for i in range(len(runs)):
            for j in range(i + 1, len(runs)):
                ri, rj = runs[i], runs[j]
                if {ri.a, ri.b} & {rj.a, rj.b}:
                    continue
                need = rad[i] + rad[j]
                if np.any(lo[i] - need > hi[j]) or np.any(lo[j] - need > hi[i]):
                    continue
                dist = segment_distance(seg[i][0], seg[i][1], seg[j][0], seg[j][1])
                if dist < need:
                    raise ValueError(
                        f"runs {ri.id!r} ({ri.a}-{ri.b}) and {rj.id!r} ({rj.a}-{rj.b}) intersect: "
                        f"their centrelines are {dist:.4f} m apart, need at least {need:.4f} m"
                    )

    def _validate_points(self) -> None:
        if self.start_pose is not None:
            loc = self.centreline.nearest(self.start_pose.position)
            if loc.distance > 0.5 * loc.diameter:
                raise ValueError(
                    f"start_pose position {self.start_pose.position.tolist()} is {loc.distance:.4f}"
                    f" m from the nearest centreline; it must lie inside the bore (< "
                    f"{0.5 * loc.diameter:.4f} m)"
                )
            cos = abs(float(self.start_pose.forward @ loc.tangent))
            if cos < math.cos(math.radians(30.0)):
                raise ValueError(
                    f"start_pose forward axis is {math.degrees(math.acos(min(cos, 1.0))):.1f} deg"
                    " off the pipe axis; allowed at most 30 deg"
                )
        for i, g in enumerate(self.goals):
            loc = self.centreline.nearest(np.asarray(g))
            if loc.distance > 0.5 * loc.diameter:
                raise ValueError(
                    f"goals[{i}] {list(g)} is {loc.distance:.4f} m from the nearest centreline; "
                    f"it must lie inside the bore (< {0.5 * loc.diameter:.4f} m)"
                )

    # ---------------------------------------------------------------- queries
    @cached_property
    def centreline(self) -> Centreline:
        """The centreline graph (lines and arcs) used by all along-network queries."""
        from pipe_env.centreline import Centreline

        return Centreline(self)

    def structures_ahead(self, pose: Pose, max_distance: float = 2.0) -> list[StructureOption]:
        """Ground truth: the options of the nearest structure ahead of ``pose``.

        One :class:`~detector.options.StructureOption` per way on, with distance, diameter,
        angle and direction as docs/design.md defines them, measured in ``pose``'s frame. Empty
        if no structure's reference point lies within ``max_distance`` metres ahead.
        """
        from pipe_env.ground_truth import structures_ahead

        return structures_ahead(self, pose, max_distance)

    def nearest_centreline_point(self, point: ArrayLike) -> CentrelinePoint:
        """Nearest point on the centreline to ``point`` (m), with tangent and local diameter."""
        return self.centreline.nearest(np.asarray(point, dtype=float))

    def inner_diameter_at(self, point: ArrayLike) -> float:
        """Inner diameter (m) of the pipe at the centreline point nearest to ``point``."""
        return self.nearest_centreline_point(point).diameter

    def geodesic_distance(self, p: ArrayLike, q: ArrayLike) -> float:
        """Along-network distance (m) between the centreline points nearest to ``p`` and ``q``."""
        return self.centreline.geodesic_distance(np.asarray(p, float), np.asarray(q, float))

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Axis-aligned bounds (min, max) of the network's pipes, metres."""
        pts = np.array([f.position for f in self.fittings])
        margin = max(r.diameter for r in self.runs) if self.runs else 0.1
        return pts.min(axis=0) - margin, pts.max(axis=0) + margin

    def total_length(self) -> float:
        """Total centreline length of the network, metres."""
        return self.centreline.total_length

    # ---------------------------------------------------------- serialisation
    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "version": SCHEMA_VERSION,
            "name": self.name,
            "fittings": [f.to_dict() for f in self.fittings],
            "runs": [r.to_dict() for r in self.runs],
            "goals": [list(g) for g in self.goals],
        }
        if self.start_pose is not None:
            d["start"] = self.start_pose.to_dict()
        if self.metadata:
            d["metadata"] = _plain(self.metadata)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], validate: bool = True) -> PipeNetwork:
        """Inverse of :meth:`to_dict`; validates unless ``validate=False``.

        Every problem is a :class:`~pipe_env.network_io.NetworkSpecError` (a ``ValueError``)
        naming the field's path (``fittings[3].position``, ``start.forward``, ``goals[0]``).
        """
        from pipe_env.network_io import parse_spec

        return parse_spec(d, validate=validate)

    def to_json(self, **kwargs: Any) -> str:
        """JSON text; never NaN or Infinity (non-finite numbers are written as null)."""
        from pipe_env.network_io import finite_json

        kwargs["allow_nan"] = False
        return json.dumps(finite_json(self.to_dict()), **kwargs)

    @classmethod
    def from_json(cls, text: str, validate: bool = True) -> PipeNetwork:
        from pipe_env.network_io import network_from_text

        return network_from_text(text, "json", validate=validate)

    def to_yaml(self) -> str:
        import yaml

        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    @classmethod
    def from_yaml(cls, text: str, validate: bool = True) -> PipeNetwork:
        from pipe_env.network_io import network_from_text

        return network_from_text(text, "yaml", validate=validate)

    def save(self, path: str | Path) -> None:
        """Write JSON or YAML, chosen by the file suffix (.json, .yaml, .yml), atomically."""
        from pipe_env.network_io import save_network

        save_network(self, path)

    @classmethod
    def load(cls, path: str | Path, validate: bool = True) -> PipeNetwork:
        """Read a network file; every error is a ``ValueError`` naming the file and field."""
        from pipe_env.network_io import load_network

        return load_network(path, validate=validate)

    def derived(self, **changes: Any) -> PipeNetwork:
        """A copy with ``start_pose``, ``goals``, ``name`` or ``metadata`` changed, keeping the
        derived geometry already computed (it depends only on fittings and runs)."""
        allowed = {"start_pose", "goals", "name", "metadata"}
        unknown = sorted(set(changes) - allowed)
        if unknown:
            raise ValueError(f"derived() cannot change {unknown}; allowed: {sorted(allowed)}")
        kwargs = {
            "start_pose": self.start_pose,
            "goals": self.goals,
            "name": self.name,
            "metadata": self.metadata,
        }
        kwargs.update(changes)
        if "goals" in changes:
            kwargs["goals"] = tuple(tuple(g) for g in changes["goals"])
        net = PipeNetwork(self.fittings, self.runs, **kwargs)
        for key in (
            "fitting_by_id",
            "run_by_id",
            "runs_at",
            "geometry",
            "centreline",
            "_routing_cache",
            "_edge_paths",
            "_goal_edges",
        ):
            if key in self.__dict__:
                net.__dict__[key] = self.__dict__[key]
        return net

    def with_start(self, pose: Pose | None) -> PipeNetwork:
        return self.derived(start_pose=pose)

    def with_goals(self, goals: Iterable[Sequence[float]]) -> PipeNetwork:
        return self.derived(goals=goals)

    def __repr__(self) -> str:
        kinds: dict[str, int] = {}
        for f in self.fittings:
            kinds[f.kind] = kinds.get(f.kind, 0) + 1
        return f"PipeNetwork({self.name!r}, runs={len(self.runs)}, fittings={kinds})"


def _plain(value: Any) -> Any:
    """Convert numpy scalars/arrays inside metadata to JSON/YAML-safe Python values."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def generate_network(config: NetworkConfig, rng: np.random.Generator) -> PipeNetwork:
    """Generate a random valid network; see :func:`pipe_env.generator.generate_network`."""
    from pipe_env.generator import generate_network as _generate

    return _generate(config, rng)


def __getattr__(name: str) -> Any:
    # NetworkConfig lives with the generator; re-exported here under the name users expect.
    if name == "NetworkConfig":
        from pipe_env.generator import NetworkConfig

        return NetworkConfig
    raise AttributeError(name)
