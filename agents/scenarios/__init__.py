"""Autonomy scenarios: YAML files that fix a network, a sensor, a detector, an agent, seeds and
pass criteria, and the code that loads, validates, builds and runs one of them.

The package by concern (each module imports only those above it in this list):

- :mod:`~agents.scenarios.criteria`: the pass/fail criteria as a table (name, what a file
  gives, how a run measures it, how it is judged, its message);
- :mod:`~agents.scenarios.schema`: the :class:`Scenario` type, its errors and the validation
  of a scenario mapping;
- :mod:`~agents.scenarios.building`: the network, sensor and environment arguments of a
  scenario;
- :mod:`~agents.scenarios.files`: reading a file, the packaged library
  (``agents/scenarios/library/*.yaml``) and selecting files by glob;
- :mod:`~agents.scenarios.running`: one run with one seed and its :class:`ScenarioResult`.

Running many in worker processes with timeouts, JUnit XML and JSON is
:mod:`agents.scenario_runner`'s.

A scenario file::

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

Unknown keys are errors, and every error names the file, the field and what is allowed, in
:mod:`detector.validation`'s format: ``tee.yaml: criteria.max_jams = -1: out of range;
allowed: an integer at least 0``.
"""

from __future__ import annotations

from agents.scenarios.building import build_network, env_kwargs, sensor_settings
from agents.scenarios.criteria import (
    CRITERIA,
    CRITERION_KEYS,
    DETECTION_ERROR_CRITERIA,
    Criterion,
    CriterionResult,
)
from agents.scenarios.files import (
    discover,
    discover_with_errors,
    load_scenario,
    packaged_scenario_dir,
    scenario_files,
)
from agents.scenarios.running import (
    ResultStatus,
    ScenarioResult,
    error_result,
    evaluate_criteria,
    run_scenario,
)
from agents.scenarios.schema import (
    DEFAULT_TIMEOUT_S,
    Scenario,
    ScenarioError,
    ScenarioFieldError,
    parse_scenario,
)

__all__ = [
    "CRITERIA",
    "CRITERION_KEYS",
    "DEFAULT_TIMEOUT_S",
    "DETECTION_ERROR_CRITERIA",
    "Criterion",
    "CriterionResult",
    "Scenario",
    "ScenarioError",
    "ScenarioFieldError",
    "ResultStatus",
    "ScenarioResult",
    "build_network",
    "discover",
    "discover_with_errors",
    "env_kwargs",
    "error_result",
    "evaluate_criteria",
    "load_scenario",
    "packaged_scenario_dir",
    "parse_scenario",
    "run_scenario",
    "scenario_files",
    "sensor_settings",
]
