"""The pipe network model: fittings joined by straight runs, and its geometry queries.

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

This module owns :class:`PipeNetwork` (its data, lookups and derived geometry). The elements
and limits live in :mod:`pipe_env.network_elements`, the checks in
:mod:`pipe_env.network_validation`, the serialised form in :mod:`pipe_env.network_io` and the
queries (ground truth, centreline, geodesic distance) in their own modules; all sit below this
one and are exposed here as methods (``validate``, ``from_dict``, ``load``, ``save``, ...).
The generator (:mod:`pipe_env.generator`) sits above it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from detector.geometry import Pose
from detector.validation import check_vector, fail
from pipe_env.fittings import FittingGeometry, build_fitting
from pipe_env.network_elements import (
    NETWORK_DIAMETER_RANGE,
    SCHEMA_VERSION,
    Fitting,
    Run,
)
from pipe_env.network_io import (
    parse_spec,
    plain,
    read_spec_file,
    spec_errors,
    spec_from_text,
    spec_to_json,
    spec_to_yaml,
    write_spec_file,
)
from pipe_env.network_validation import check_topology, validate_network

if TYPE_CHECKING:
    from detector.options import StructureOption
    from pipe_env.centreline import Centreline, CentrelinePoint

__all__ = [
    "Fitting",
    "PipeNetwork",
    "Run",
]


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
            v = check_vector(f"goals[{i}]", g, 3, unit="m")
            goals.append((float(v[0]), float(v[1]), float(v[2])))
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
        check_topology(self)
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
    def validate(self, diameter_range: tuple[float, float] = NETWORK_DIAMETER_RANGE) -> None:
        """Check the whole network; raise :class:`~detector.validation.ArgumentError` (a
        ``ValueError``) naming the element by path and id, the value and what is allowed.

        Checks ids and references, fitting degrees and parameters, diameters within
        ``diameter_range`` (m), bend and junction angles, run lengths against their fittings'
        legs, clearance between pipes that do not share a fitting, the start pose and goals
        (see :mod:`pipe_env.network_validation`).
        """
        validate_network(self, diameter_range)

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
        """The network as written in a file (see the module docstring for the schema)."""
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
            d["metadata"] = plain(self.metadata)
        return d

    @classmethod
    def from_dict(
        cls, d: dict[str, Any], validate: bool = True, source: str | None = None
    ) -> PipeNetwork:
        """Inverse of :meth:`to_dict`; validates unless ``validate=False``.

        Every problem is a :class:`~pipe_env.network_io.NetworkSpecError` (a ``ValueError``)
        naming ``source`` (a file name) if given and the field's path (``start.forward``,
        ``goals[0]``, ``fittings[3] (id 'f3').position``).
        """
        with spec_errors(source):
            net = cls(*parse_spec(d))
            if validate:
                net.validate()
            return net
        raise AssertionError("unreachable")  # pragma: no cover (mypy: spec_errors re-raises)

    def to_json(self, **kwargs: Any) -> str:
        """JSON text; never NaN or Infinity (non-finite numbers are written as null)."""
        return spec_to_json(self.to_dict(), **kwargs)

    @classmethod
    def from_json(cls, text: str, validate: bool = True) -> PipeNetwork:
        """A network from JSON text (see :meth:`from_dict`)."""
        return cls.from_dict(spec_from_text(text, "json"), validate, "network")

    def to_yaml(self) -> str:
        """YAML text, keys in schema order."""
        return spec_to_yaml(self.to_dict())

    @classmethod
    def from_yaml(cls, text: str, validate: bool = True) -> PipeNetwork:
        """A network from YAML text (see :meth:`from_dict`)."""
        return cls.from_dict(spec_from_text(text, "yaml"), validate, "network")

    def save(self, path: str | Path) -> None:
        """Write JSON or YAML, chosen by the file suffix (.json, .yaml, .yml), atomically."""
        write_spec_file(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path, validate: bool = True) -> PipeNetwork:
        """Read a network file; every error is a ``ValueError`` naming the file and field."""
        return cls.from_dict(read_spec_file(path), validate, str(path))

    def derived(self, **changes: Any) -> PipeNetwork:
        """A copy with ``start_pose``, ``goals``, ``name`` or ``metadata`` changed, keeping the
        derived geometry already computed (it depends only on fittings and runs)."""
        allowed = {"start_pose", "goals", "name", "metadata"}
        unknown = sorted(set(changes) - allowed)
        if unknown:
            raise fail("derived()", unknown, ", ".join(sorted(allowed)), "cannot change")
        kwargs: dict[str, Any] = {
            "start_pose": self.start_pose,
            "goals": self.goals,
            "name": self.name,
            "metadata": self.metadata,
        }
        kwargs.update(changes)
        if "goals" in changes:
            kwargs["goals"] = tuple(tuple(g) for g in changes["goals"])
        net = type(self)(self.fittings, self.runs, **kwargs)
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
