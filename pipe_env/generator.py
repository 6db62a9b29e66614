"""Procedural pipe networks: :class:`NetworkConfig` and :func:`generate_network`.

The generator grows a tree from an entry cap: it repeatedly picks an open pipe end, chooses a
fitting kind from the configured mix, places it a random straight run away and opens its
outgoing ports, checking clearance against everything placed so far. With ``allow_loops`` a tee
may become a rectangular bypass (two tees and two bends) that rejoins the main line, which makes
a loop with exactly consistent geometry. Remaining open ends get closures. A goal is put before
a closure that the robot can reach driving forward with turns of at most 90 deg.

All randomness comes from the ``rng`` passed in: the same seed gives the same network.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import InitVar, dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from detector.geometry import Pose, frame_from_forward, segment_distance
from detector.validation import check_bool, check_choice, check_int, check_number, fail
from pipe_env.fittings import build_fitting
from pipe_env.network import PipeNetwork
from pipe_env.network_elements import (
    BEND_ANGLE_RANGE,
    BEND_RADIUS_RANGE,
    NETWORK_DIAMETER_RANGE,
    WALL_CLEARANCE,
    Fitting,
    Run,
)
from pipe_env.robot_limits import ROBOT_DIAMETER_RANGE
from pipe_env.routing import route

KIND_CHOICES = ("mitre_bend", "long_bend", "tee", "wye", "cross", "reducer", "closure")
DEFAULT_KIND_WEIGHTS: dict[str, float] = {
    "mitre_bend": 1.0,
    "long_bend": 1.0,
    "tee": 1.0,
    "wye": 0.5,
    "cross": 0.4,
    "reducer": 0.5,
    "closure": 0.2,
}


class NetworkGenerationError(RuntimeError):
    """The generator could not place a valid network within its retry budget."""


#: The angle fields that took degrees before they took radians: old name -> new name.
DEPRECATED_DEGREE_FIELDS: dict[str, str] = {
    "bend_angle_range": "bend_deflection_range",
    "bend_angle_step": "bend_deflection_step",
    "roll_step": "roll_angle_step",
}


@dataclass(frozen=True)
class NetworkConfig:
    """Parameters of :func:`generate_network`. Lengths in metres, angles in radians.

    Attributes:
        n_fittings: fittings to place, not counting the end caps (1-200).
        kind_weights: relative frequency of each kind in ``KIND_CHOICES``.
        diameter_range: inner diameters drawn from this range, m.
        branch_same_diameter: probability that a junction branch keeps the main diameter.
        planar: keep the network horizontal (bends and branches turn left or right only).
        allow_loops: let tees grow into bypass loops.
        loop_probability: chance that a tee becomes a loop when loops are allowed.
        run_length_range: straight pipe length between fittings, m.
        first_run_length: straight pipe from the entry cap to the first fitting, m.
        start_offset: distance of the start pose from the entry cap, m.
        bend_deflection_range: bend deflections, rad (within pi/6 to pi/2, 30-90 deg).
        bend_deflection_step: snap bend deflections to multiples of this, rad (0: continuous).
        roll_angle_step: in 3D, snap roll directions to multiples of this, rad (0: continuous).
        bend_radius_range: long-bend radius, in diameters (within 1-3).
        taper_length_range: reducer taper length, m.
        min_diameter_change: smallest diameter change at a reducer, m.
        n_goals: goals to place (each before a reachable closure).
        max_extent: largest side of the box holding all fitting centres, m (None: unbounded).
        max_retries: whole-network attempts before giving up.

    Deprecated (for one version): ``bend_angle_range``, ``bend_angle_step`` and ``roll_step``
    in degrees are accepted with a ``FutureWarning`` and converted to the fields above.
    """

    n_fittings: int = 8
    kind_weights: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_KIND_WEIGHTS))
    diameter_range: tuple[float, float] = ROBOT_DIAMETER_RANGE
    branch_same_diameter: float = 0.6
    planar: bool = True
    allow_loops: bool = False
    loop_probability: float = 0.35
    run_length_range: tuple[float, float] = (0.4, 1.0)
    first_run_length: float = 1.2
    start_offset: float = 0.5
    bend_deflection_range: tuple[float, float] = BEND_ANGLE_RANGE
    bend_deflection_step: float = math.radians(15.0)
    roll_angle_step: float = math.radians(45.0)
    bend_radius_range: tuple[float, float] = BEND_RADIUS_RANGE
    taper_length_range: tuple[float, float] = (0.05, 0.2)
    min_diameter_change: float = 0.008
    n_goals: int = 1
    max_extent: float | None = None
    max_retries: int = 50
    # deprecated degree fields (see the class docstring); not stored
    bend_angle_range: InitVar[tuple[float, float] | None] = None
    bend_angle_step: InitVar[float | None] = None
    roll_step: InitVar[float | None] = None

    def __post_init__(
        self,
        bend_angle_range: tuple[float, float] | None,
        bend_angle_step: float | None,
        roll_step: float | None,
    ) -> None:
        old = {"bend_angle_range": bend_angle_range, "bend_angle_step": bend_angle_step}
        old["roll_step"] = roll_step
        for name, value in old.items():
            if value is not None:
                self._take_degrees(name, value)
        _check_counts(self)
        _check_pairs(self)
        _check_kind_weights(self)
        _check_lengths(self)

    def _take_degrees(self, old: str, value: Any) -> None:
        """Set the radian field from the deprecated degree field ``old``, warning once."""
        new = DEPRECATED_DEGREE_FIELDS[old]
        if getattr(self, new) != _FIELD_DEFAULTS[new]:
            raise fail(
                f"NetworkConfig.{old}",
                value,
                f"{new} (radians) alone; {old} (degrees) is deprecated",
                f"given with {new}",
            )
        warnings.warn(
            f"NetworkConfig.{old} (degrees) is deprecated and will be removed; use {new} "
            "(radians) instead",
            FutureWarning,  # shown by default: configs come from files, not from code
            stacklevel=4,
        )
        name = f"NetworkConfig.{old}"
        if new == "bend_deflection_range":
            low, high, _ = _PAIR_LIMITS[new]
            limits = (round(math.degrees(low), 6), round(math.degrees(high), 6))
            lo, hi = _pair(name, value, "deg", limits)
            object.__setattr__(self, new, (math.radians(lo), math.radians(hi)))
        else:
            low, high, _ = _NUMBER_LIMITS[new]
            number = check_number(name, value, math.degrees(low), math.degrees(high), "deg")
            object.__setattr__(self, new, math.radians(number))

    def to_dict(self) -> dict[str, Any]:
        """The config as plain values (the radian fields; ``from_dict`` reads it back)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = (
                dict(v) if isinstance(v, Mapping) else (list(v) if isinstance(v, tuple) else v)
            )
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> NetworkConfig:
        """A config from its :meth:`to_dict` form; the deprecated degree keys are accepted."""
        if not isinstance(d, Mapping):
            raise fail("NetworkConfig", d, "a mapping of NetworkConfig fields", "not a mapping")
        allowed = [f.name for f in fields(cls)] + list(DEPRECATED_DEGREE_FIELDS)
        unknown = sorted(str(k) for k in d if k not in allowed)
        if unknown:
            raise fail(f"NetworkConfig.{unknown[0]}", d[unknown[0]], ", ".join(allowed), "no key")
        kw: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        return cls(**kw)


_FIELD_DEFAULTS: dict[str, Any] = {
    "bend_deflection_range": BEND_ANGLE_RANGE,
    "bend_deflection_step": math.radians(15.0),
    "roll_angle_step": math.radians(45.0),
}
#: (low, high, unit) of each pair field ``(lo, hi)``; bend deflections allow 1e-9 rad slack
#: so that ``math.pi / 6`` and ``math.radians(30)`` both pass.
_PAIR_LIMITS: dict[str, tuple[float, float, str]] = {
    "diameter_range": (*NETWORK_DIAMETER_RANGE, "m"),
    "run_length_range": (0.05, 20.0, "m"),
    "bend_deflection_range": (BEND_ANGLE_RANGE[0] - 1e-9, BEND_ANGLE_RANGE[1] + 1e-9, "rad"),
    "bend_radius_range": (*BEND_RADIUS_RANGE, "D"),
    "taper_length_range": (0.005, 1.0, "m"),
}
#: (low, high, unit) of each number field.
_NUMBER_LIMITS: dict[str, tuple[float, float, str]] = {
    "branch_same_diameter": (0.0, 1.0, ""),
    "loop_probability": (0.0, 1.0, ""),
    "first_run_length": (0.1, 20.0, "m"),
    "start_offset": (0.1, 20.0, "m"),
    "bend_deflection_step": (0.0, math.radians(60.0), "rad"),
    "roll_angle_step": (0.0, math.pi, "rad"),
}
_INT_LIMITS: dict[str, tuple[int, int]] = {
    "n_fittings": (1, 200),
    "n_goals": (0, 10),
    "max_retries": (1, 10_000),
}


def _pair(name: str, value: Any, unit: str, limits: tuple[float, float] | None = None) -> Any:
    """``value`` as ``(lo, hi)`` floats with lo <= hi, each within ``limits`` if given."""
    low, high = limits if limits is not None else (None, None)
    allowed = f"two numbers lo <= hi ({unit})"
    if limits is not None:
        allowed = f"two numbers lo <= hi within {low:g} to {high:g} ({unit})"
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise fail(name, value, allowed, "not two numbers")
    lo = check_number(f"{name}[0]", value[0], low, high, unit)
    hi = check_number(f"{name}[1]", value[1], low, high, unit)
    if lo > hi:
        raise fail(name, value, allowed, "lo above hi")
    return (lo, hi)


def _check_counts(cfg: NetworkConfig) -> None:
    for name, (lo, hi) in _INT_LIMITS.items():
        check_int(f"NetworkConfig.{name}", getattr(cfg, name), lo, hi)
    for name in ("planar", "allow_loops"):
        check_bool(f"NetworkConfig.{name}", getattr(cfg, name))


def _check_pairs(cfg: NetworkConfig) -> None:
    for name, (lo, hi, unit) in _PAIR_LIMITS.items():
        value = _pair(f"NetworkConfig.{name}", getattr(cfg, name), unit, (lo, hi))
        object.__setattr__(cfg, name, value)


def _check_kind_weights(cfg: NetworkConfig) -> None:
    name = "NetworkConfig.kind_weights"
    allowed = f"a mapping of {', '.join(KIND_CHOICES)} to weights >= 0, some non-closure > 0"
    if not isinstance(cfg.kind_weights, Mapping):
        raise fail(name, cfg.kind_weights, allowed, "not a mapping")
    weights = dict(cfg.kind_weights)
    for kind, w in weights.items():
        check_choice(f"{name} key", kind, KIND_CHOICES)
        weights[kind] = check_number(f"{name}[{kind!r}]", w, low=0.0)
    if sum(w for k, w in weights.items() if k != "closure") <= 0:
        raise fail(name, weights, allowed, "no non-closure kind has weight")
    object.__setattr__(cfg, "kind_weights", weights)


def _check_lengths(cfg: NetworkConfig) -> None:
    for name, (lo, hi, unit) in _NUMBER_LIMITS.items():
        value = check_number(f"NetworkConfig.{name}", getattr(cfg, name), lo, hi, unit)
        object.__setattr__(cfg, name, value)
    if cfg.start_offset >= cfg.first_run_length:
        raise fail(
            "NetworkConfig.start_offset",
            cfg.start_offset,
            f"below first_run_length = {cfg.first_run_length:g} m",
            "the start would lie beyond the first run",
        )
    d0, d1 = cfg.diameter_range
    width = max(d1 - d0, 0.001)
    check_number("NetworkConfig.min_diameter_change", cfg.min_diameter_change, 0.001, width, "m")
    if cfg.max_extent is not None:
        extent = check_number(
            "NetworkConfig.max_extent", cfg.max_extent, cfg.first_run_length, 1000.0, "m", True
        )
        object.__setattr__(cfg, "max_extent", extent)


def _degrees(angle: float) -> float:
    """``angle`` (rad) in degrees, snapped to 1e-9 deg. The generator samples angles on the
    degree grid it always used, so that a seed gives the same network, bit for bit, as when
    the config took degrees (``radians(30)`` and ``pi / 6`` both give exactly 30.0)."""
    return round(math.degrees(angle), 9)


class _PlacementFailed(Exception):
    pass


@dataclass
class _OpenEnd:
    node: str
    port_position: NDArray[np.float64]
    direction: NDArray[np.float64]
    diameter: float


@dataclass
class _Segment:
    a: NDArray[np.float64]
    b: NDArray[np.float64]
    radius: float
    nodes: frozenset[str]


class _Builder:
    """One attempt at growing a network (see module docstring)."""

    def __init__(self, config: NetworkConfig, rng: np.random.Generator) -> None:
        self.cfg = config
        self.rng = rng
        self.fittings: list[Fitting] = []
        self.runs: list[Run] = []
        self.segments: list[_Segment] = []
        self.open: list[_OpenEnd] = []
        kinds = [k for k in KIND_CHOICES if config.kind_weights.get(k, 0.0) > 0]
        w = np.array([config.kind_weights[k] for k in kinds], dtype=float)
        self.kinds, self.kind_p = kinds, w / w.sum()

    # ------------------------------------------------------------ primitives
    def _node_id(self) -> str:
        return f"n{len(self.fittings)}"

    def _add_fitting(self, kind: str, pos: NDArray, **params: Any) -> str:
        nid = self._node_id()
        position = (float(pos[0]), float(pos[1]), float(pos[2]))
        self.fittings.append(Fitting(nid, kind, position, **params))
        return nid

    def _add_run(self, a: str, b: str, pa: NDArray, pb: NDArray, diameter: float) -> None:
        self.runs.append(Run(f"r{len(self.runs)}", a, b, diameter))
        self.segments.append(_Segment(pa, pb, 0.5 * diameter + WALL_CLEARANCE, frozenset((a, b))))

    def _clear(self, a: NDArray, b: NDArray, radius: float, touching: set[str]) -> bool:
        """True if segment a-b with ``radius`` keeps clearance from all placed pipes and stays
        within ``max_extent``."""
        if self.cfg.max_extent is not None:
            pts = np.array([f.position for f in self.fittings] + [a, b])
            if np.any(np.ptp(pts, axis=0) > self.cfg.max_extent):
                return False
        for s in self.segments:
            if s.nodes & touching:
                continue
            if segment_distance(a, b, s.a, s.b) < radius + s.radius + 0.01:
                return False
        return True

    def _diameter(self) -> float:
        lo, hi = self.cfg.diameter_range
        return float(np.round(self.rng.uniform(lo, hi), 4))

    def _run_length(self) -> float:
        return float(self.rng.uniform(*self.cfg.run_length_range))

    def _roll(self) -> float:
        if self.cfg.planar:
            return float(self.rng.choice([0.0, math.pi]))
        step = _degrees(self.cfg.roll_angle_step)
        if step > 0:
            n = max(int(round(360.0 / step)), 1)
            return math.radians(step) * int(self.rng.integers(n))
        return float(self.rng.uniform(-math.pi, math.pi))

    def _bend_angle(self) -> float:
        a0, a1 = (_degrees(a) for a in self.cfg.bend_deflection_range)
        step = _degrees(self.cfg.bend_deflection_step)
        if step > 0:
            choices = np.arange(math.ceil(a0 / step) * step, a1 + 1e-9, step)
            if len(choices):
                return math.radians(float(self.rng.choice(choices)))
        return math.radians(float(self.rng.uniform(a0, a1)))

    @staticmethod
    def _deflect(direction: NDArray, angle: float, roll: float) -> NDArray:
        frame = frame_from_forward(direction)
        v = frame @ np.array(
            [math.cos(angle), math.sin(angle) * math.cos(roll), math.sin(angle) * math.sin(roll)]
        )
        return v / np.linalg.norm(v)

    # -------------------------------------------------------------- fittings
    def _place(self, end: _OpenEnd, kind: str, run_len: float | None = None) -> int:
        """Place one fitting kind at ``end``, ``run_len`` m of straight pipe away (random if
        None); return the number of fittings added (0 if it did not fit)."""
        x = end.direction
        d = end.diameter
        params: dict[str, Any] = {}
        outs: list[tuple[NDArray, float]] = []
        fkind = kind
        if kind in ("mitre_bend", "long_bend"):
            fkind = "bend"
            outs = [(self._deflect(x, self._bend_angle(), self._roll()), d)]
            params["style"] = "mitre" if kind == "mitre_bend" else "long"
            if kind == "long_bend":
                params["bend_radius"] = float(
                    np.round(self.rng.uniform(*self.cfg.bend_radius_range) * d, 4)
                )
        elif kind in ("tee", "wye", "cross"):
            db = (
                d
                if self.rng.random() < self.cfg.branch_same_diameter
                else float(np.round(self.rng.uniform(self.cfg.diameter_range[0], d), 4))
            )
            roll = self._roll()
            branch_angle = math.radians(45.0 if kind == "wye" else 90.0)
            outs = [(x, d), (self._deflect(x, branch_angle, roll), db)]
            if kind == "cross":
                outs.append((self._deflect(x, branch_angle, roll + math.pi), db))
        elif kind == "reducer":
            lo, hi = self.cfg.diameter_range
            choices = [
                v for v in np.linspace(lo, hi, 41) if abs(v - d) >= self.cfg.min_diameter_change
            ]
            if not choices:
                return 0
            new_d = float(np.round(self.rng.choice(choices), 4))
            params["taper_length"] = float(
                np.round(self.rng.uniform(*self.cfg.taper_length_range), 4)
            )
            outs = [(x, new_d)]
        elif kind == "closure":
            outs = []
        ports = [("in", -x, d)] + [(f"o{i}", v, dd) for i, (v, dd) in enumerate(outs)]
        geo = build_fitting(
            "new",
            fkind,
            np.zeros(3),
            ports,
            params.get("style"),
            params.get("bend_radius"),
            params.get("taper_length"),
        )
        if run_len is None:
            run_len = self._run_length()
        centre = end.port_position + x * (run_len + geo.port("in").leg)
        if not self._clear(end.port_position, centre, 0.5 * d + WALL_CLEARANCE, {end.node}):
            return 0
        for i, (v, dd) in enumerate(outs):
            probe_len = geo.port(f"o{i}").leg + self.cfg.run_length_range[0] + 0.5 * dd
            if not self._clear(centre, centre + v * probe_len, 0.5 * dd + WALL_CLEARANCE, set()):
                return 0
        nid = self._add_fitting(fkind, centre, **params)
        self._add_run(end.node, nid, self._node_pos(end.node), centre, d)
        for i, (v, dd) in enumerate(outs):
            self.open.append(_OpenEnd(nid, centre + v * geo.port(f"o{i}").leg, v, dd))
        return 1

    def _node_pos(self, nid: str) -> NDArray:
        return np.asarray(self.fittings[int(nid[1:])].position, dtype=float)

    def _place_loop(self, end: _OpenEnd) -> int:
        """A rectangular bypass: tee A and tee B on the main line, bends C and D beside it."""
        x, d = end.direction, end.diameter
        db = (
            d
            if self.rng.random() < self.cfg.branch_same_diameter
            else float(np.round(self.rng.uniform(self.cfg.diameter_range[0], d), 4))
        )
        u = self._deflect(x, math.pi / 2, self._roll())
        tee_ports = [("back", -x, d), ("fwd", x, d), ("side", u, db)]
        tee = build_fitting("tee", "tee", np.zeros(3), tee_ports)
        style = "long" if self.rng.random() < 0.5 else "mitre"
        radius = float(np.round(self.rng.uniform(*self.cfg.bend_radius_range) * db, 4))
        bend = build_fitting(
            "bend",
            "bend",
            np.zeros(3),
            [("a", -u, db), ("b", x, db)],
            style,
            radius if style == "long" else None,
        )
        min_run = self.cfg.run_length_range[0]
        width = max(
            self._run_length(),
            2 * bend.ports[0].leg + min_run,
            tee.port("fwd").leg + tee.port("back").leg + min_run,
        )
        height = max(self._run_length(), tee.port("side").leg + bend.ports[0].leg + min_run)
        a = end.port_position + x * (self._run_length() + tee.port("back").leg)
        b = a + x * width
        c = a + u * height
        dd = b + u * height
        radius_main = 0.5 * d + WALL_CLEARANCE
        radius_side = 0.5 * db + WALL_CLEARANCE
        if not self._clear(end.port_position, b, radius_main, {end.node}):
            return 0
        if not self._clear(c, dd, radius_side, set()) or not self._clear(a, c, radius_side, set()):
            return 0
        probe = b + x * (tee.port("fwd").leg + min_run + 0.5 * d)
        if not self._clear(dd, b, radius_side, set()) or not self._clear(
            b, probe, radius_main, set()
        ):
            return 0
        ida = self._add_fitting("tee", a)
        self._add_run(end.node, ida, self._node_pos(end.node), a, d)
        idb = self._add_fitting("tee", b)
        self._add_run(ida, idb, a, b, d)
        bend_params: dict[str, Any] = {"style": style}
        if style == "long":
            bend_params["bend_radius"] = radius
        idc = self._add_fitting("bend", c, **bend_params)
        self._add_run(ida, idc, a, c, db)
        idd = self._add_fitting("bend", dd, **bend_params)
        self._add_run(idc, idd, c, dd, db)
        self._add_run(idd, idb, dd, b, db)
        self.open.append(_OpenEnd(idb, b + x * tee.port("fwd").leg, x, d))
        return 4

    def _cap(self, end: _OpenEnd) -> None:
        geo = build_fitting("cap", "closure", np.zeros(3), [("in", -end.direction, end.diameter)])
        leg = geo.ports[0].leg
        x = end.direction
        for run_len in (self._run_length(), self.cfg.run_length_range[0], 0.1):
            centre = end.port_position + x * (run_len + leg)
            if self._clear(
                end.port_position,
                centre + x * WALL_CLEARANCE,
                0.5 * end.diameter + WALL_CLEARANCE,
                {end.node},
            ):
                nid = self._add_fitting("closure", centre)
                self._add_run(end.node, nid, self._node_pos(end.node), centre, end.diameter)
                return
        raise _PlacementFailed("no room to cap an open end")

    # ----------------------------------------------------------------- build
    def build(self) -> PipeNetwork:
        cfg = self.cfg
        d0 = self._diameter()
        entry = self._add_fitting("closure", np.zeros(3))
        x = np.array([1.0, 0.0, 0.0])
        entry_leg = build_fitting("e", "closure", np.zeros(3), [("in", x, d0)]).ports[0].leg
        # the first run has a fixed length so that the robot fits behind the start pose
        first = _OpenEnd(entry, x * entry_leg, x, d0)
        placed = 0
        for _ in range(10):
            placed = self._place(first, self._choose_kind(0), run_len=cfg.first_run_length)
            if placed:
                break
        if placed == 0:
            raise _PlacementFailed("no room for the first fitting")
        while placed < cfg.n_fittings and self.open:
            idx = int(self.rng.integers(len(self.open)))
            end = self.open.pop(idx)
            kind = self._choose_kind(n_open_after=len(self.open))
            added = 0
            for _ in range(6):
                if kind == "tee" and cfg.allow_loops and self.rng.random() < cfg.loop_probability:
                    added = self._place_loop(end)
                else:
                    added = self._place(end, kind)
                if added:
                    break
                kind = self._choose_kind(n_open_after=len(self.open))
            if added:
                placed += added
            else:
                self._cap(end)
        if placed < cfg.n_fittings:
            raise _PlacementFailed(f"placed {placed} of {cfg.n_fittings} fittings")
        while self.open:
            self._cap(self.open.pop(0))
        start = Pose.from_forward(x * (entry_leg + cfg.start_offset), x)
        net = PipeNetwork(tuple(self.fittings), tuple(self.runs), start, (), "generated")
        goals = self._goals(net)
        return net.with_goals(goals)

    def _choose_kind(self, n_open_after: int) -> str:
        for _ in range(20):
            kind = str(self.rng.choice(self.kinds, p=self.kind_p))
            # never close the last open end while fittings remain to place
            if kind == "closure" and n_open_after == 0:
                continue
            return kind
        return "mitre_bend" if "mitre_bend" in self.kinds else self.kinds[0]

    def _goals(self, net: PipeNetwork) -> list[tuple[float, float, float]]:
        if self.cfg.n_goals == 0:
            return []
        assert net.start_pose is not None
        candidates: list[tuple[float, float, float]] = []
        unseen = decision_free_closures(net)
        for f in net.fittings[1:]:
            if f.kind != "closure" or f.id in unseen:
                continue
            run = net.runs_at[f.id][0]
            g = net.geometry[f.id]
            inward = g.ports[0].axis
            back = min(0.25, 0.5 * max(net.straight_length(run.id), 0.0) + g.ports[0].leg)
            point = g.centre + inward * back
            r = route(net, net.start_pose, point)
            if r is not None:
                candidates.append((float(point[0]), float(point[1]), float(point[2])))
        if len(candidates) < self.cfg.n_goals:
            raise _PlacementFailed(
                "too few reachable goals (a goal must need a decision: the closure that the "
                "start reaches through bends and reducers alone does not count)"
            )
        pick = self.rng.choice(len(candidates), size=self.cfg.n_goals, replace=False)
        return [candidates[int(i)] for i in sorted(pick)]


def decision_free_closures(net: PipeNetwork) -> set[str]:
    """Closures the robot reaches from the start pose without a decision: the chain of bends
    and reducers (single ways, taken automatically) ahead of the start ends there. A goal
    before one of them would be reached inside ``reset()``, so none is placed there."""
    if net.start_pose is None:
        return set()
    run_id = net.nearest_centreline_point(net.start_pose.position).run_id
    if run_id is None or run_id not in net.run_by_id:
        return set()
    run = net.run_by_id[run_id]
    start = net.start_pose
    ahead = max(
        (run.a, run.b), key=lambda f: float((net.position(f) - start.position) @ start.forward)
    )
    seen: set[str] = set()
    while ahead not in seen:
        seen.add(ahead)
        kind = net.fitting_by_id[ahead].kind
        if kind == "closure":
            return {ahead}
        if kind not in ("bend", "reducer"):
            return set()
        run = next(r for r in net.runs_at[ahead] if r.id != run.id)
        ahead = run.other(ahead)
    return set()


def generate_network(config: NetworkConfig, rng: np.random.Generator) -> PipeNetwork:
    """Generate a valid random network from ``config`` using only ``rng``.

    Retries whole networks up to ``config.max_retries`` times, then raises
    :class:`NetworkGenerationError` naming the configuration to relax.
    """
    if not isinstance(rng, np.random.Generator):
        raise fail("rng", rng, "a numpy.random.Generator", f"a {type(rng).__name__}")
    last = ""
    for _ in range(config.max_retries):
        try:
            net = _Builder(config, rng).build()
            net.validate(NETWORK_DIAMETER_RANGE)
        except (_PlacementFailed, ValueError) as exc:
            last = str(exc)
            continue
        return net.derived(name="generated", metadata={"generator": config.to_dict()})
    raise NetworkGenerationError(
        f"could not generate a network with n_fittings={config.n_fittings} in "
        f"{config.max_retries} attempts (last problem: {last}); lower n_fittings, widen "
        "run_length_range or allow 3D (planar=False)"
    )
