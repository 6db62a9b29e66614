"""Autonomy scenarios: YAML files that fix a network, a sensor, a detector, an agent, seeds and
pass criteria, and the code that loads, validates and runs one of them.

A scenario file (packaged ones live in ``agents/scenarios/``)::

    name: tee_90mm_right            # optional, defaults to the file stem
    description: ...
    mode: navigate                  # navigate (an agent drives) | detect (sensor sweep only)
    env: PipeNav-v0                 # PipeNav-v0 | PipeExplore-v0 (navigate mode)
    network:                        # exactly one of layout / generator / file / inline
      layout: t_junction
      params: {diameter: 0.09, direction: 0.0}
    goal: [0.0, -0.5, 0.0]          # optional: replaces the network's goals (m), or
    goal: {way: 1, distance: 0.4}   #   along true way on #1 (ground-truth order: straight on
                                    #   first, then by direction) of the first structure ahead,
                                    #   this far from its centre (m)
    start: {position: [...], forward: [...]}   # optional start pose override
    sensor: {preset: ideal, overrides: {bias: 0.02}, misalignment: {offset: [0, 0.01, 0],
             tilt_deg: [0, 2, 0]}}
    detector: improved              # improved | thesis | ground_truth
    fidelity: full                  # full | fast
    agent: route_planner            # a scripted agent name or a model .zip path
    seeds: [0, 1]                   # or repetitions: 3 (seeds 0..2)
    max_decisions: 20
    detect: {distances: [0.4, 0.3, 0.2, 0.1], planar: false}   # detect mode: sensor positions
                                    # before the structure (m); planar: the 2D algorithm on one
                                    # horizontal plane
    known_failure: why it fails today  # optional: a documented gap; a failing run is reported
                                    # as an expected failure, a passing one is flagged (so the
                                    # note gets removed); ``--strict`` counts both as failures
    timeout_s: 600                  # optional: wall-clock limit of one run (s); a run that
                                    # exceeds it is an error testcase (default 1800 s)
    criteria:
      success: true                 # expected is_success
      max_jams: 0
      max_decisions: 10
      max_sim_time: 900             # s
      max_detection_error: {distance: 0.02, diameter: 0.005, angle_deg: 5, direction_deg: 5}
      min_classification: 0.9       # detect mode: fraction of scans with the right kind
      must_not_reach: r_out0        # a run the robot must never drive into
      min_back_outs: 1
      min_coverage: 0.9             # PipeExplore

Unknown keys are errors, and every error names the file, the key and what is allowed.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from detector.vocab import DETECTORS, Method
from pipe_env.envs.fidelity import Fidelity

SCENARIO_KEYS = {
    "name",
    "description",
    "mode",
    "env",
    "network",
    "goal",
    "start",
    "sensor",
    "detector",
    "fidelity",
    "agent",
    "seeds",
    "repetitions",
    "max_decisions",
    "detect",
    "criteria",
    "tags",
    "known_failure",
    "timeout_s",
    "auto_single",
}
#: Wall-clock limit of one scenario run when neither the file nor ``--timeout`` gives one, s.
DEFAULT_TIMEOUT_S = 1800.0
#: The largest seed a scenario may give.
MAX_SEED = 2**63 - 1
#: The largest ``timeout_s`` a file may give, s (one day).
MAX_TIMEOUT_S = 86400.0
MODES = ("navigate", "detect")
ENVS = ("PipeNav-v0", "PipeExplore-v0")
#: Scenario fidelities, its default (full) first: the order its errors list.
FIDELITIES: tuple[str, ...] = (Fidelity.FULL.value, Fidelity.FAST.value)
NETWORK_SOURCES = ("layout", "generator", "file", "inline")
SENSOR_KEYS = {"preset", "overrides", "misalignment"}
MISALIGNMENT_KEYS = {"offset", "tilt_deg"}
CRITERIA = {
    "success": bool,
    "max_jams": int,
    "max_decisions": int,
    "max_sim_time": float,
    "max_detection_error": dict,
    "min_classification": float,
    "must_not_reach": str,
    "min_back_outs": int,
    "min_coverage": float,
}
ERROR_FIELDS = {
    "distance": 1.0,
    "diameter": 1.0,
    "angle_deg": math.pi / 180,
    "direction_deg": math.pi / 180,
}


class ScenarioError(ValueError):
    """A scenario file is invalid; the message names the file, the key and what is allowed."""


@dataclass
class Scenario:
    """A validated scenario (see module docstring)."""

    name: str
    source: str
    data: dict[str, Any]
    description: str = ""
    mode: str = "navigate"
    env: str = "PipeNav-v0"
    detector: str = "improved"
    fidelity: str = "full"
    agent: str = "route_planner"
    seeds: list[int] = field(default_factory=lambda: [0])
    max_decisions: int = 32
    criteria: dict[str, Any] = field(default_factory=dict)
    tags: list[str] = field(default_factory=list)
    #: why the scenario is expected to fail today (a documented gap, not a skipped check: the
    #: test suite runs it and fails if it starts passing, so the note gets removed)
    known_failure: str | None = None
    #: wall-clock limit of one run, s (None: the runner's default)
    timeout_s: float | None = None
    #: the environment takes a single way on by itself (``auto_single`` of ``gym.make``); a
    #: single-structure layout whose goal lies past its only way sets it false, so that the
    #: episode starts at the decision instead of being over inside ``reset()``
    auto_single: bool = True

    @property
    def base_dir(self) -> Path:
        return Path(self.source).parent


def _fail(source: str, key: str, problem: str) -> ScenarioError:
    return ScenarioError(f"{source}: key '{key}': {problem}")


def _expect(source: str, key: str, value: Any, types: type | tuple, allowed: str) -> None:
    if isinstance(value, bool) and types in (int, float, (int, float)):
        raise _fail(source, key, f"got {value!r}; allowed: {allowed}")
    if not isinstance(value, types):
        raise _fail(source, key, f"got {value!r} ({type(value).__name__}); allowed: {allowed}")


def parse_scenario(data: Any, source: str) -> Scenario:
    """Validate a scenario mapping (from YAML) and return a :class:`Scenario`.

    Every problem is a :class:`ScenarioError` naming ``source`` and the key; nothing else
    escapes, whatever the mapping holds.
    """
    try:
        return _parse_scenario(data, source)
    except ScenarioError:
        raise
    except Exception as exc:  # a value of a shape no check anticipated: still name the file
        raise ScenarioError(f"{source}: invalid scenario ({type(exc).__name__}: {exc})") from None


def _number(value: Any) -> bool:
    """Whether ``value`` is a finite real number (an int too large for a float is not)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def _choice(source: str, key: str, value: Any, allowed: tuple[str, ...]) -> str:
    if not isinstance(value, str) or value not in allowed:
        raise _fail(source, key, f"got {value!r}; allowed: {allowed}")
    return value


def _parse_scenario(data: Any, source: str) -> Scenario:
    if not isinstance(data, dict):
        raise ScenarioError(
            f"{source}: a scenario must be a mapping of keys, got {type(data).__name__}"
        )
    unknown = sorted(str(k) for k in set(data) - SCENARIO_KEYS)
    if unknown:
        raise _fail(source, unknown[0], f"unknown key; allowed: {sorted(SCENARIO_KEYS)}")
    stem = Path(source).stem
    name = data.get("name", stem)
    _expect(source, "name", name, str, "a string")
    mode = data.get("mode", "navigate")
    _choice(source, "mode", mode, MODES)
    env = data.get("env", "PipeNav-v0")
    _choice(source, "env", env, ENVS)
    detector = data.get("detector", "improved")
    _choice(source, "detector", detector, DETECTORS)
    fidelity = data.get("fidelity", "full")
    _choice(source, "fidelity", fidelity, FIDELITIES)
    agent = data.get("agent", "route_planner")
    _expect(source, "agent", agent, str, "a scripted agent name or a model .zip path")
    from agents.scripted import SCRIPTED_AGENTS

    if agent not in SCRIPTED_AGENTS and not agent.endswith(".zip"):
        raise _fail(
            source,
            "agent",
            f"got {agent!r}; allowed: {sorted(SCRIPTED_AGENTS)} or a model .zip path",
        )
    if "seeds" in data and "repetitions" in data:
        raise _fail(source, "seeds", "give either 'seeds' or 'repetitions', not both")
    if "seeds" in data:
        seeds = data["seeds"]
        if not (
            isinstance(seeds, list)
            and seeds
            and all(
                isinstance(s, int) and not isinstance(s, bool) and 0 <= s <= MAX_SEED for s in seeds
            )
        ):
            raise _fail(
                source, "seeds", f"got {seeds!r}; allowed: a non-empty list of ints in [0, 2**63)"
            )
    else:
        reps = data.get("repetitions", 1)
        _expect(source, "repetitions", reps, int, "an int in [1, 100]")
        if not 1 <= reps <= 100:
            raise _fail(source, "repetitions", f"got {reps}; allowed: an int in [1, 100]")
        seeds = list(range(reps))
    max_decisions = data.get("max_decisions", 32)
    _expect(source, "max_decisions", max_decisions, int, "an int in [1, 1000]")
    if not 1 <= max_decisions <= 1000:
        raise _fail(source, "max_decisions", f"got {max_decisions}; allowed: [1, 1000]")
    _validate_network(data.get("network"), source)
    if "goal" in data:
        g = data["goal"]
        as_point = isinstance(g, list) and len(g) == 3 and all(_number(v) for v in g)
        as_way = (
            isinstance(g, dict)
            and set(g) == {"way", "distance"}
            and isinstance(g["way"], int)
            and not isinstance(g["way"], bool)
            and g["way"] >= 0
            and _number(g["distance"])
            and 0 < g["distance"] <= 20
        )
        if not (as_point or as_way):
            raise _fail(
                source,
                "goal",
                f"got {g!r}; allowed: three finite numbers (m) or "
                "{way: int >= 0, distance: m in (0, 20]}",
            )
    if "start" in data:
        st = data["start"]
        if not (
            isinstance(st, dict)
            and set(st) <= {"position", "forward", "up", "rotation"}
            and "position" in st
        ):
            raise _fail(
                source,
                "start",
                f"got {st!r}; allowed: a mapping with 'position' and "
                "'forward' (and optionally 'up') or 'rotation'",
            )
    _validate_sensor(data.get("sensor", {}), source)
    if mode == "detect":
        det = data.get("detect", {})
        if not isinstance(det, dict) or set(det) - {"distances", "planar"}:
            raise _fail(
                source, "detect", f"got {det!r}; allowed: a mapping with 'distances' and 'planar'"
            )
        if not isinstance(det.get("planar", False), bool):
            raise _fail(
                source,
                "detect.planar",
                "allowed: true (one horizontal plane, the 2D algorithm) or false (full sweep)",
            )
        dists = det.get("distances", [0.4, 0.3, 0.2, 0.1])
        if not (
            isinstance(dists, list) and dists and all(_number(v) and 0.0 <= v <= 5.0 for v in dists)
        ):
            raise _fail(
                source,
                "detect.distances",
                f"got {dists!r}; allowed: a list of distances in [0, 5] m",
            )
    elif "detect" in data:
        raise _fail(source, "detect", "only allowed with mode: detect")
    criteria = data.get("criteria", {})
    _validate_criteria(criteria, source)
    tags = data.get("tags", [])
    if not (isinstance(tags, list) and all(isinstance(t, str) for t in tags)):
        raise _fail(source, "tags", f"got {tags!r}; allowed: a list of strings")
    desc = data.get("description", "")
    _expect(source, "description", desc, str, "a string")
    known = data.get("known_failure")
    if known is not None and not (isinstance(known, str) and known.strip()):
        raise _fail(source, "known_failure", f"got {known!r}; allowed: a non-empty string")
    timeout = data.get("timeout_s")
    if timeout is not None:
        if not (_number(timeout) and 0 < timeout <= MAX_TIMEOUT_S):
            raise _fail(
                source, "timeout_s", f"got {timeout!r}; allowed: seconds in (0, {MAX_TIMEOUT_S:g}]"
            )
        timeout = float(timeout)
    auto_single = data.get("auto_single", True)
    _expect(source, "auto_single", auto_single, bool, "true or false")
    return Scenario(
        name,
        source,
        data,
        desc,
        mode,
        env,
        detector,
        fidelity,
        agent,
        seeds,
        max_decisions,
        criteria,
        tags,
        known,
        timeout,
        auto_single,
    )


def _validate_network(net: Any, source: str) -> None:
    if not isinstance(net, dict):
        raise _fail(
            source, "network", f"got {net!r}; allowed: a mapping with one of {NETWORK_SOURCES}"
        )
    given = [k for k in NETWORK_SOURCES if k in net]
    if len(given) != 1:
        raise _fail(source, "network", f"give exactly one of {NETWORK_SOURCES}, got {given}")
    allowed = {
        "layout": {"layout", "params"},
        "generator": {"generator", "seed"},
        "file": {"file"},
        "inline": {"inline"},
    }[given[0]]
    extra = sorted(set(net) - allowed)
    if extra:
        raise _fail(source, f"network.{extra[0]}", f"unknown key; allowed here: {sorted(allowed)}")
    if "layout" in net:
        from pipe_env.layouts import LAYOUTS

        if not isinstance(net["layout"], str) or net["layout"] not in LAYOUTS:
            raise _fail(
                source, "network.layout", f"got {net['layout']!r}; allowed: {sorted(LAYOUTS)}"
            )
        if not isinstance(net.get("params", {}), dict):
            raise _fail(source, "network.params", "allowed: a mapping of layout parameters")
    if "generator" in net:
        if not isinstance(net["generator"], dict):
            raise _fail(source, "network.generator", "allowed: a mapping of NetworkConfig fields")
        seed = net.get("seed", 0)
        if not (isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed <= MAX_SEED):
            raise _fail(source, "network.seed", f"got {seed!r}; allowed: an int in [0, 2**63)")
    if "file" in net and not isinstance(net["file"], str):
        raise _fail(source, "network.file", "allowed: a path (relative to the scenario file)")
    if "inline" in net and not isinstance(net["inline"], dict):
        raise _fail(source, "network.inline", "allowed: a network mapping (PipeNetwork.to_dict)")


def _validate_sensor(sensor: Any, source: str) -> None:
    from pipe_env.lidar import PRESETS, LidarSpec

    if not isinstance(sensor, dict):
        raise _fail(source, "sensor", f"got {sensor!r}; allowed: a mapping with {SENSOR_KEYS}")
    extra = sorted(set(sensor) - SENSOR_KEYS)
    if extra:
        raise _fail(source, f"sensor.{extra[0]}", f"unknown key; allowed: {sorted(SENSOR_KEYS)}")
    preset = sensor.get("preset", "ideal")
    if not isinstance(preset, str) or preset not in PRESETS:
        raise _fail(source, "sensor.preset", f"got {preset!r}; allowed: {sorted(PRESETS)}")
    overrides = sensor.get("overrides", {})
    if not isinstance(overrides, dict):
        raise _fail(source, "sensor.overrides", "allowed: a mapping of LidarSpec fields")
    fields = set(LidarSpec.__dataclass_fields__) - {"name"}
    bad = sorted(set(overrides) - fields)
    if bad:
        raise _fail(
            source, f"sensor.overrides.{bad[0]}", f"unknown field; allowed: {sorted(fields)}"
        )
    mis = sensor.get("misalignment", {})
    if not isinstance(mis, dict) or set(mis) - MISALIGNMENT_KEYS:
        raise _fail(
            source,
            "sensor.misalignment",
            f"got {mis!r}; allowed keys: {sorted(MISALIGNMENT_KEYS)} (offset in m, tilt in deg)",
        )
    for k in MISALIGNMENT_KEYS & set(mis):
        v = mis[k]
        if not (isinstance(v, list) and len(v) == 3 and all(_number(x) for x in v)):
            raise _fail(source, f"sensor.misalignment.{k}", f"got {v!r}; allowed: 3 numbers")


def _validate_criteria(criteria: Any, source: str) -> None:
    if not isinstance(criteria, dict):
        raise _fail(
            source, "criteria", f"got {criteria!r}; allowed: a mapping of {sorted(CRITERIA)}"
        )
    for key, value in criteria.items():
        if key not in CRITERIA:
            raise _fail(
                source, f"criteria.{key}", f"unknown criterion; allowed: {sorted(CRITERIA)}"
            )
        want = CRITERIA[key]
        if want is float:
            ok = _number(value) and value >= 0
        elif want is int:
            ok = isinstance(value, int) and not isinstance(value, bool) and value >= 0
        else:
            ok = isinstance(value, want)
        if not ok:
            raise _fail(
                source,
                f"criteria.{key}",
                f"got {value!r}; allowed: {want.__name__}"
                + (" >= 0" if want in (int, float) else ""),
            )
        if key == "max_detection_error":
            for f, v in value.items():
                if f not in ERROR_FIELDS:
                    raise _fail(
                        source,
                        f"criteria.max_detection_error.{f}",
                        f"unknown field; allowed: {sorted(ERROR_FIELDS)}",
                    )
                if not (_number(v) and v >= 0):
                    raise _fail(
                        source,
                        f"criteria.max_detection_error.{f}",
                        f"got {v!r}; allowed: a number >= 0",
                    )


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate one scenario file."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ScenarioError(f"{p}: cannot read the scenario file ({exc.strerror})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ScenarioError(
            f"{p}: not valid YAML{where}: {getattr(exc, 'problem', None) or exc}"
        ) from None
    scenario = parse_scenario(data, str(p))
    build_network(scenario)  # layout/generator parameters and goals are checked here too
    return scenario


def packaged_scenario_dir() -> Path:
    return Path(str(resources.files("agents") / "scenarios"))


def scenario_files(pattern: str = "*", directory: str | Path | None = None) -> list[Path]:
    """Packaged (or ``directory``'s) scenario files whose stem matches the glob ``pattern``.

    Only the names are read: a file the pattern does not select is never parsed. (A
    scenario's ``name`` defaults to its file stem; select a renamed one by its file stem.)
    """
    import fnmatch

    root = Path(directory) if directory is not None else packaged_scenario_dir()
    return [f for f in sorted(root.glob("*.yaml")) if fnmatch.fnmatch(f.stem, pattern)]


def discover_with_errors(
    pattern: str = "*", directory: str | Path | None = None
) -> tuple[list[Scenario], list[tuple[str, ScenarioError]]]:
    """The selected scenarios, and (file, error) for each selected file that does not load."""
    found: list[Scenario] = []
    broken: list[tuple[str, ScenarioError]] = []
    for f in scenario_files(pattern, directory):
        try:
            found.append(load_scenario(f))
        except ScenarioError as exc:
            broken.append((str(f), exc))
    return found, broken


def discover(pattern: str = "*", directory: str | Path | None = None) -> list[Scenario]:
    """Packaged (or ``directory``'s) scenarios whose file stem matches the glob ``pattern``;
    raises the :class:`ScenarioError` of the first selected file that does not load."""
    return [load_scenario(f) for f in scenario_files(pattern, directory)]


# ----------------------------------------------------------------------------- building
def build_network(sc: Scenario) -> Any:
    """The scenario's network with its start and goal overrides applied."""
    from pipe_env.layouts import make_layout
    from pipe_env.network import PipeNetwork
    from pipe_env.network_io import NetworkSpecError, parse_pose

    spec = sc.data["network"]
    try:
        if "layout" in spec:
            net = make_layout(spec["layout"], **spec.get("params", {}))
        elif "generator" in spec:
            from pipe_env.generator import NetworkConfig, generate_network

            net = generate_network(
                NetworkConfig.from_dict(spec["generator"]),
                np.random.default_rng(spec.get("seed", 0)),
            )
        elif "file" in spec:
            net = PipeNetwork.load(sc.base_dir / spec["file"])
        else:
            net = PipeNetwork.from_dict(copy.deepcopy(spec["inline"]))
        if "start" in sc.data:
            try:
                net = net.with_start(parse_pose(sc.data["start"], "start"))
            except NetworkSpecError as exc:
                key, _, problem = str(exc).partition(": ")
                raise _fail(sc.source, key, problem) from None
        if "goal" in sc.data:
            net = net.with_goals([_goal_point(net, sc.data["goal"], sc.source)])
        net.validate()
    except ScenarioError:
        raise
    except (ValueError, TypeError, KeyError, OSError) as exc:
        raise _fail(sc.source, "network", str(exc)) from None
    except Exception as exc:  # a value no check anticipated (e.g. an int too large for a float)
        raise _fail(sc.source, "network", f"invalid value ({type(exc).__name__})") from None
    return net


def _goal_point(net: Any, goal: Any, source: str) -> list[float]:
    """A goal given as a point, or as a distance along a true way on of the first structure."""
    if isinstance(goal, list):
        return [float(v) for v in goal]
    from detector.options import option_vector
    from pipe_env.ground_truth import fitting_ahead, options_at

    if net.start_pose is None:
        raise _fail(source, "goal", "a goal by way needs a start pose")
    node, entry = fitting_ahead(net, net.start_pose)
    ways = options_at(net, node, entry, net.start_pose)
    if goal["way"] >= len(ways) or ways[0].kind == "closure":
        raise _fail(
            source,
            "goal.way",
            f"got {goal['way']}; the structure ahead ({ways[0].kind}) has ways 0..{len(ways) - 1}",
        )
    axis = net.start_pose.rotation @ option_vector(ways[goal["way"]])
    return (net.geometry[node].centre + axis * float(goal["distance"])).tolist()


def sensor_settings(sc: Scenario) -> tuple[Any, Any]:
    """(LidarSpec, misalignment Pose or None) of the scenario."""
    from detector.geometry import Pose, rotation_about
    from pipe_env.lidar import get_preset

    sensor = sc.data.get("sensor", {})
    spec = get_preset(sensor.get("preset", "ideal"))
    try:
        if sensor.get("overrides"):
            spec = spec.with_(**sensor["overrides"])
    except (ValueError, TypeError) as exc:
        raise _fail(sc.source, "sensor.overrides", str(exc)) from None
    except Exception as exc:  # e.g. an int too large for a float
        raise _fail(
            sc.source, "sensor.overrides", f"invalid value ({type(exc).__name__})"
        ) from None
    mis = sensor.get("misalignment")
    pose = None
    if mis:
        offset = np.asarray(mis.get("offset", [0, 0, 0]), dtype=float)
        roll, pitch, yaw = np.radians(mis.get("tilt_deg", [0, 0, 0]))
        rot = (
            rotation_about([0, 0, 1], yaw)
            @ rotation_about([0, 1, 0], pitch)
            @ rotation_about([1, 0, 0], roll)
        )
        pose = Pose(offset, rot)
    return spec, pose


# ------------------------------------------------------------------------------ running
@dataclass
class CriterionResult:
    criterion: str
    passed: bool
    measured: Any
    threshold: Any
    message: str


@dataclass
class ScenarioResult:
    """The verdict and measurements of one scenario run with one seed."""

    scenario: str
    seed: int
    passed: bool
    criteria: list[CriterionResult]
    metrics: dict[str, Any]
    timings: dict[str, float]
    source: str
    error: str | None = None
    #: the scenario's ``known_failure`` note (None: it is expected to pass)
    known_failure: str | None = None
    #: the run never started (the suite was interrupted first)
    not_run: bool = False

    @property
    def failures(self) -> list[CriterionResult]:
        return [c for c in self.criteria if not c.passed]

    @property
    def expected_failure(self) -> bool:
        """A scenario marked ``known_failure`` that failed its criteria (an error is not
        expected: it stays an error)."""
        return (
            bool(self.known_failure)
            and not self.passed
            and not self.not_run
            and (self.error is None)
        )

    @property
    def unexpected_pass(self) -> bool:
        """A scenario marked ``known_failure`` that passed: its note should be removed."""
        return bool(self.known_failure) and self.passed

    @property
    def status(self) -> str:
        """One of ``passed``, ``failed``, ``error``, ``expected_failure``,
        ``unexpected_pass``, ``not_run``."""
        if self.not_run:
            return "not_run"
        if self.error is not None:
            return "error"
        if self.expected_failure:
            return "expected_failure"
        if self.unexpected_pass:
            return "unexpected_pass"
        return "passed" if self.passed else "failed"

    def counts_as_failure(self, strict: bool = False) -> bool:
        """Whether this result fails the suite: errors and failures always; not run never;
        an expected failure or an unexpected pass only when ``strict``."""
        status = self.status
        if status in ("error", "failed"):
            return True
        if status in ("expected_failure", "unexpected_pass"):
            return strict
        return False

    def replay_command(self) -> str:
        cmd = f"pipenav scenarios run '{self.scenario}' --seed {self.seed}"
        folder = Path(self.source).parent
        if folder.resolve() != packaged_scenario_dir().resolve():
            cmd += f" --dir '{folder}'"
        return cmd

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario,
            "seed": self.seed,
            "passed": self.passed,
            "source": self.source,
            "error": self.error,
            "criteria": [c.__dict__ for c in self.criteria],
            "metrics": self.metrics,
            "timings": self.timings,
            "replay": None if self.passed or self.not_run else self.replay_command(),
            "status": self.status,
            "known_failure": self.known_failure,
            "expected_failure": self.expected_failure,
            "unexpected_pass": self.unexpected_pass,
        }


def error_result(
    source: str, seed: int, message: str, name: str | None = None, not_run: bool = False
) -> ScenarioResult:
    """The result of a run the runner could not complete (a scenario file that does not load,
    a worker that died, a timeout) or never started (``not_run``)."""
    name = name or Path(source).stem
    criteria = (
        []
        if not_run
        else [CriterionResult("runs_without_error", False, message, "no error", message)]
    )
    return ScenarioResult(
        name,
        seed,
        False,
        criteria,
        {},
        {"setup_s": 0.0, "run_s": 0.0},
        source,
        None if not_run else message,
        not_run=not_run,
    )


def run_scenario(sc: Scenario, seed: int) -> ScenarioResult:
    """Run one scenario with one seed; never raises for a failing robot, only reports."""
    t0 = time.perf_counter()
    try:
        net = build_network(sc)
        t1 = time.perf_counter()
        metrics = (
            _run_detect(sc, net, seed) if sc.mode == "detect" else _run_navigate(sc, net, seed)
        )
        error = None
    except Exception as exc:  # a crash or a bad parameter is a failed run with its reason
        t1 = time.perf_counter()
        metrics, error = {}, f"{type(exc).__name__}: {exc}"
    t2 = time.perf_counter()
    criteria = [] if error else evaluate_criteria(sc, metrics)
    if error:
        criteria.append(
            CriterionResult(
                "runs_without_error", False, error, "no error", f"the run raised {error}"
            )
        )
    return ScenarioResult(
        sc.name,
        seed,
        all(c.passed for c in criteria),
        criteria,
        metrics,
        {"setup_s": round(t1 - t0, 3), "run_s": round(t2 - t1, 3)},
        sc.source,
        error,
        sc.known_failure,
    )


def _env_kwargs(sc: Scenario, net: Any) -> dict[str, Any]:
    spec, mis = sensor_settings(sc)
    return {
        "network": net,
        "detector": sc.detector,
        "fidelity": sc.fidelity,
        "lidar": spec,
        "misalignment": mis,
        "auto_single": sc.auto_single,
    }


def _run_navigate(sc: Scenario, net: Any, seed: int) -> dict[str, Any]:
    import gymnasium as gym

    import pipe_env  # noqa: F401
    from agents.evaluate import PolicyAgent
    from agents.scripted import SCRIPTED_AGENTS, make_agent
    from pipe_env.envs import K_OPTIONS

    env = gym.make(f"pipenav/{sc.env}", max_episode_steps=sc.max_decisions, **_env_kwargs(sc, net))
    if sc.agent in SCRIPTED_AGENTS:
        agent: Any = make_agent(sc.agent, env)
    else:
        path = Path(sc.agent)
        agent = PolicyAgent(path if path.is_absolute() else sc.base_dir / path, env)
    obs, info = env.reset(seed=seed)
    agent.reset()
    back_outs = 0
    errors: dict[str, float] = {}
    kinds_ok: list[float] = []
    runs_visited: set[str] = set()

    def note(info: dict[str, Any]) -> None:
        de = info.get("detection_error") or {}
        for k in ("distance", "diameter", "angle", "direction"):
            if k in de:
                errors[k] = max(errors.get(k, 0.0), float(de[k]))
        if "kind_correct" in de:
            kinds_ok.append(float(de["kind_correct"]))

    note(info)
    done = False
    while not done:
        action = agent.act(obs, info)
        if action == K_OPTIONS - 1 and info["action_mask"][action]:
            back_outs += 1
        obs, _, term, trunc, info = env.step(action)
        note(info)
        done = term or trunc
    plant = env.unwrapped.plant
    for p in env.unwrapped.path:
        run = net.nearest_centreline_point(p).run_id
        if run is not None:
            runs_visited.add(run)
    env.close()
    return {
        "is_success": bool(info["is_success"]),
        "jams": int(info["jams"]),
        "decisions": int(info["decisions"]),
        "sim_time_s": round(float(info["sim_time"]), 3),
        "travelled_m": round(float(info["travelled"]), 4),
        "back_outs": back_outs,
        # None outside PipeExplore (JSON has no NaN)
        "coverage": round(float(info["coverage"]), 4) if "coverage" in info else None,
        "max_detection_error": {k: round(v, 5) for k, v in errors.items()},
        "classification": round(float(np.mean(kinds_ok)), 4) if kinds_ok else None,
        "runs_visited": sorted(runs_visited),
        "fidelity": getattr(plant, "fidelity", sc.fidelity),
    }


def _run_detect(sc: Scenario, net: Any, seed: int) -> dict[str, Any]:
    """Sweep the sensor along the incoming centreline and detect at each distance."""
    import detector
    from detector.options import option_errors
    from pipe_env.lidar import RotatingLidar
    from pipe_env.world import build_world

    spec, mis = sensor_settings(sc)
    world = build_world(net, contact_walls=False)
    lidar = RotatingLidar(world, spec, misalignment=mis)
    rng = np.random.default_rng(seed)
    start = net.start_pose
    truth0 = net.structures_ahead(start, 10.0)
    if not truth0:
        raise _fail(sc.source, "network", "detect mode needs a structure ahead of the start pose")
    base = truth0[0].distance
    errors: dict[str, float] = {}
    correct = []
    planar = bool(sc.data.get("detect", {}).get("planar", False))
    for d in sc.data.get("detect", {}).get("distances", [0.4, 0.3, 0.2, 0.1]):
        pose = start.translated(base - d)
        truth = net.structures_ahead(pose, 10.0)
        diameter = net.inner_diameter_at(pose.position)
        if sc.detector == Method.GROUND_TRUTH:
            options, kind = truth, truth[0].kind
        elif planar:
            det = detector.detect_planar(
                lidar.scan_plane(pose, 0.0, rng), diameter, method=sc.detector
            )
            options, kind = det.options, det.kind
        else:
            det = detector.detect(lidar.scan(pose, rng), diameter, method=sc.detector)
            options, kind = det.options, det.kind
        correct.append(float(kind == truth[0].kind))
        for key, err in option_errors(options, truth).items():
            errors[key] = max(errors.get(key, 0.0), err)
    return {
        "classification": round(float(np.mean(correct)), 4),
        "scans": len(correct),
        "max_detection_error": {k: round(v, 5) for k, v in errors.items()},
    }


def evaluate_criteria(sc: Scenario, m: dict[str, Any]) -> list[CriterionResult]:
    """Check each criterion of ``sc`` against the measured metrics ``m``."""
    out: list[CriterionResult] = []

    def check(name: str, ok: bool, measured: Any, threshold: Any, text: str) -> None:
        msg = f"{name}: measured {measured}, threshold {threshold}" + ("" if ok else f" ({text})")
        out.append(CriterionResult(name, bool(ok), measured, threshold, msg))

    c = sc.criteria
    if "success" in c:
        check(
            "success",
            m.get("is_success") == c["success"],
            m.get("is_success"),
            c["success"],
            "the episode outcome differs",
        )
    if "max_jams" in c:
        check(
            "max_jams",
            m.get("jams", 0) <= c["max_jams"],
            m.get("jams"),
            c["max_jams"],
            "too many jams",
        )
    if "max_decisions" in c:
        check(
            "max_decisions",
            m.get("decisions", 0) <= c["max_decisions"],
            m.get("decisions"),
            c["max_decisions"],
            "too many decisions",
        )
    if "max_sim_time" in c:
        check(
            "max_sim_time",
            m.get("sim_time_s", 0.0) <= c["max_sim_time"],
            m.get("sim_time_s"),
            c["max_sim_time"],
            "too slow",
        )
    if "min_back_outs" in c:
        check(
            "min_back_outs",
            m.get("back_outs", 0) >= c["min_back_outs"],
            m.get("back_outs"),
            c["min_back_outs"],
            "did not back out",
        )
    if "min_coverage" in c:
        cov = m.get("coverage") or 0.0
        check("min_coverage", cov >= c["min_coverage"], cov, c["min_coverage"], "too little")
    if "min_classification" in c:
        cl = m.get("classification")
        check(
            "min_classification",
            cl is not None and cl >= c["min_classification"],
            cl,
            c["min_classification"],
            "structures misclassified",
        )
    if "must_not_reach" in c:
        reached = c["must_not_reach"] in m.get("runs_visited", [])
        check(
            "must_not_reach",
            not reached,
            "reached" if reached else "not reached",
            c["must_not_reach"],
            "the robot entered a pipe it must not",
        )
    for f, limit in c.get("max_detection_error", {}).items():
        key = f.removesuffix("_deg")
        scale = ERROR_FIELDS[f]
        measured = m.get("max_detection_error", {}).get(key)
        shown = None if measured is None else round(measured / scale, 4)
        check(
            f"max_detection_error.{f}",
            measured is not None and measured <= limit * scale,
            shown,
            limit,
            "detection error too large" if measured is not None else "no detection was measured",
        )
    return out
