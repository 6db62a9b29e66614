"""Running one scenario with one seed and reporting its verdict (:class:`ScenarioResult`).

``navigate`` mode drives the scenario's agent through its environment until the episode ends;
``detect`` mode sweeps the sensor along the incoming centreline and runs the detector at each
distance. The metrics a run measures (SI units: m, rad, s) are judged by the criteria table of
:mod:`agents.scenarios.criteria`. A run never raises for a failing robot or a crash: both are
a result (a crash as the ``runs_without_error`` criterion). Running many scenarios in worker
processes, with timeouts and reports, is :mod:`agents.scenario_runner`'s.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agents.scenarios.building import build_network, env_kwargs, sensor_settings
from agents.scenarios.criteria import CriterionResult, evaluate
from agents.scenarios.files import packaged_scenario_dir
from agents.scenarios.schema import DEFAULT_DETECT_DISTANCES, Scenario, ScenarioFieldError
from detector.vocab import Method, StrEnum
from pipe_env.network import PipeNetwork

__all__ = ["ScenarioResult", "error_result", "evaluate_criteria", "run_scenario"]

#: The option fields whose largest detection error a navigate run records (m, m, rad, rad).
ERROR_KEYS = ("distance", "diameter", "angle", "direction")


class ResultStatus(StrEnum):
    """The verdict of one scenario and seed, as reports show it."""

    PASSED = "passed"
    FAILED = "failed"
    ERROR = "error"  # the run itself failed: a broken file, a dead worker, a timeout
    EXPECTED_FAILURE = "expected_failure"  # failed, and marked known_failure
    UNEXPECTED_PASS = "unexpected_pass"  # passed, but marked known_failure
    NOT_RUN = "not_run"  # interrupted before it ran


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
    def status(self) -> ResultStatus:
        """The verdict (:class:`ResultStatus`)."""
        if self.not_run:
            return ResultStatus.NOT_RUN
        if self.error is not None:
            return ResultStatus.ERROR
        if self.expected_failure:
            return ResultStatus.EXPECTED_FAILURE
        if self.unexpected_pass:
            return ResultStatus.UNEXPECTED_PASS
        return ResultStatus.PASSED if self.passed else ResultStatus.FAILED

    def counts_as_failure(self, strict: bool = False) -> bool:
        """Whether this result fails the suite: errors and failures always; not run never;
        an expected failure or an unexpected pass only when ``strict``."""
        status = self.status
        if status in (ResultStatus.ERROR, ResultStatus.FAILED):
            return True
        if status in (ResultStatus.EXPECTED_FAILURE, ResultStatus.UNEXPECTED_PASS):
            return strict
        return False

    def replay_command(self) -> str:
        """The ``pipenav`` command that runs this scenario and seed again."""
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


def evaluate_criteria(sc: Scenario, metrics: dict[str, Any]) -> list[CriterionResult]:
    """Judge each criterion of ``sc`` on the measured ``metrics`` (see the criteria table)."""
    return evaluate(sc.criteria, metrics)


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


# ---------------------------------------------------------------------------- navigate
class _DetectionLog:
    """The largest detection error per option field (m, rad) and the kind verdicts seen."""

    def __init__(self) -> None:
        self.errors: dict[str, float] = {}
        self.kinds_ok: list[float] = []

    def note(self, info: dict[str, Any]) -> None:
        de = info.get("detection_error") or {}
        for k in ERROR_KEYS:
            if k in de:
                self.errors[k] = max(self.errors.get(k, 0.0), float(de[k]))
        if "kind_correct" in de:
            self.kinds_ok.append(float(de["kind_correct"]))


def _make_agent(sc: Scenario, env: Any) -> Any:
    """The scenario's scripted agent, or its learned policy (a path relative to the file)."""
    from agents.evaluate import PolicyAgent
    from agents.scripted import SCRIPTED_AGENTS, make_agent

    if sc.agent in SCRIPTED_AGENTS:
        return make_agent(sc.agent, env)
    path = Path(sc.agent)
    return PolicyAgent(path if path.is_absolute() else sc.base_dir / path, env)


def _run_navigate(sc: Scenario, net: PipeNetwork, seed: int) -> dict[str, Any]:
    import gymnasium as gym

    import pipe_env  # noqa: F401  (registers the environments)
    from pipe_env.envs import K_OPTIONS, PipeExploreEnv, PipeNavEnv, oracle_of

    env = gym.make(f"pipenav/{sc.env}", max_episode_steps=sc.max_decisions, **env_kwargs(sc, net))
    try:  # a full-fidelity world is released even when the agent or a step raises
        agent = _make_agent(sc, env)
        obs, info = env.reset(seed=seed)
        agent.reset()
        back_outs = 0
        log = _DetectionLog()
        log.note(info)
        done = False
        while not done:
            action = agent.act(obs, info)
            if action == K_OPTIONS - 1 and info["action_mask"][action]:
                back_outs += 1
            obs, _, term, trunc, info = env.step(action)
            log.note(info)
            done = term or trunc
        base = env.unwrapped
        assert isinstance(base, (PipeNavEnv, PipeExploreEnv)), type(base)
        path = oracle_of(env).driven_path()
        runs_visited = {net.nearest_centreline_point(p).run_id for p in path} - {None}
        fidelity = base.config.fidelity
    finally:
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
        "max_detection_error": {k: round(v, 5) for k, v in log.errors.items()},
        "classification": round(float(np.mean(log.kinds_ok)), 4) if log.kinds_ok else None,
        "runs_visited": sorted(runs_visited),
        "fidelity": fidelity,
    }


# ------------------------------------------------------------------------------ detect
def _run_detect(sc: Scenario, net: PipeNetwork, seed: int) -> dict[str, Any]:
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
    truth0 = net.structures_ahead(start, 10.0) if start is not None else []
    if start is None or not truth0:
        raise ScenarioFieldError(
            "network",
            sc.data["network"],
            "a network with a structure ahead of its start pose",
            "detect mode needs a structure ahead of the start pose",
            sc.source,
        )
    base = truth0[0].distance
    errors: dict[str, float] = {}
    correct = []
    settings = sc.data.get("detect", {})
    planar = bool(settings.get("planar", False))
    for d in settings.get("distances", DEFAULT_DETECT_DISTANCES):
        pose = start.translated(base - d)
        truth = net.structures_ahead(pose, 10.0)
        diameter = net.inner_diameter_at(pose.position)
        if sc.detector == Method.GROUND_TRUTH:
            options, kind = truth, truth[0].kind
        elif planar:
            scan = lidar.scan_plane(pose, 0.0, rng)
            found = detector.detect_planar(scan, diameter, method=sc.detector)
            options, kind = found.options, found.kind
        else:
            found = detector.detect(lidar.scan(pose, rng), diameter, method=sc.detector)
            options, kind = found.options, found.kind
        correct.append(float(kind == truth[0].kind))
        for key, err in option_errors(options, truth).items():
            errors[key] = max(errors.get(key, 0.0), err)
    return {
        "classification": round(float(np.mean(correct)), 4),
        "scans": len(correct),
        "max_detection_error": {k: round(v, 5) for k, v in errors.items()},
    }
