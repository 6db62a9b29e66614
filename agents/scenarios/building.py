"""Building what a scenario runs on: its network (with the start and goal overrides applied),
its sensor (LiDAR spec and misalignment pose) and the environment's arguments.

What only building can check (layout parameters, generator fields, a network file, a start
pose, a goal by way) fails as a :class:`~agents.scenarios.schema.ScenarioFieldError` naming
the scenario file and the field (``network.params.diameter``, ``goal.way``); an error of a
lower layer in :mod:`detector.validation`'s format keeps its field under the scenario's key.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from agents.scenarios.schema import NETWORK_SOURCES, Scenario, ScenarioError, ScenarioFieldError
from detector.geometry import Pose, rotation_about
from detector.validation import ArgumentError
from pipe_env.lidar import LidarSpec, get_preset
from pipe_env.network import PipeNetwork

__all__ = ["build_network", "env_kwargs", "sensor_settings"]


def _field_error(
    exc: Exception, source: str, field_path: str, value: Any, allowed: str
) -> ScenarioFieldError:
    """``exc`` (raised while building ``field_path`` from ``value``) as an error of the
    scenario file; a lower layer's own "...; allowed: ..." replaces ``allowed``."""
    if isinstance(exc, ArgumentError):
        return ScenarioFieldError.of(exc, source, prefix=field_path)
    if isinstance(exc, (ValueError, TypeError, KeyError, OSError)):
        problem, _, own = str(exc).partition("; allowed: ")
        allowed = own or allowed
    else:  # a value no check anticipated (e.g. an int too large for a float)
        problem = f"invalid value ({type(exc).__name__})"
    return ScenarioFieldError(field_path, value, allowed, problem, source)


def _network_of(sc: Scenario) -> PipeNetwork:
    """The network the scenario names, before its start and goal overrides."""
    from pipe_env.generator import NetworkConfig, generate_network
    from pipe_env.layouts import make_layout

    spec = sc.data["network"]
    if "layout" in spec:
        params = spec.get("params", {})
        try:
            return make_layout(spec["layout"], **params)
        except Exception as exc:
            allowed = f"the parameters of layout {spec['layout']}"
            raise _field_error(exc, sc.source, "network.params", params, allowed) from None
    if "generator" in spec:
        try:
            config = NetworkConfig.from_dict(spec["generator"])
            return generate_network(config, np.random.default_rng(spec.get("seed", 0)))
        except Exception as exc:
            allowed = "NetworkConfig fields that generate a network"
            raise _field_error(
                exc, sc.source, "network.generator", spec["generator"], allowed
            ) from None
    if "file" in spec:
        try:
            return PipeNetwork.load(sc.base_dir / spec["file"])
        except Exception as exc:
            allowed = "a network file (relative to the scenario file)"
            raise _field_error(exc, sc.source, "network.file", spec["file"], allowed) from None
    try:
        return PipeNetwork.from_dict(copy.deepcopy(spec["inline"]))
    except Exception as exc:
        allowed = "a network mapping (PipeNetwork.to_dict)"
        raise _field_error(exc, sc.source, "network.inline", "{...}", allowed) from None


def _with_start(sc: Scenario, net: PipeNetwork) -> PipeNetwork:
    from pipe_env.network_io import parse_pose

    start = sc.data["start"]
    try:
        return net.with_start(parse_pose(start, "start"))
    except ArgumentError as exc:
        raise ScenarioFieldError.of(exc, sc.source) from None
    except Exception as exc:
        raise _field_error(exc, sc.source, "start", start, "a start pose") from None


def build_network(sc: Scenario) -> PipeNetwork:
    """The scenario's network with its start and goal overrides applied and validated.

    Raises :class:`~agents.scenarios.schema.ScenarioError` (naming the file and the field)
    and nothing else, whatever the parameters hold.
    """
    try:
        net = _network_of(sc)
        if "start" in sc.data:
            net = _with_start(sc, net)
        if "goal" in sc.data:
            net = net.with_goals([_goal_point(net, sc.data["goal"], sc.source)])
        net.validate()
    except ScenarioError:
        raise
    except Exception as exc:
        spec = sc.data["network"]
        kind = next(k for k in NETWORK_SOURCES if k in spec)
        value = spec[kind] if kind in ("layout", "file") else kind
        raise _field_error(exc, sc.source, "network", value, "a valid network") from None
    return net


def _goal_point(net: PipeNetwork, goal: Any, source: str) -> list[float]:
    """A goal given as a point, or as a distance along a true way on of the first structure
    (ways in ground-truth order: straight on first, then by direction), m."""
    from detector.options import option_vector
    from pipe_env.ground_truth import fitting_ahead, options_at

    if isinstance(goal, list):
        return [float(v) for v in goal]
    if net.start_pose is None:
        raise ScenarioFieldError(
            "goal", goal, "a goal point (m)", "a goal by way needs a start pose", source
        )
    try:
        node, entry = fitting_ahead(net, net.start_pose)
        ways = options_at(net, node, entry, net.start_pose)
    except Exception as exc:
        raise _field_error(exc, source, "goal", goal, "a way of the structure ahead") from None
    if goal["way"] >= len(ways) or ways[0].kind == "closure":
        allowed = f"0 to {len(ways) - 1} (the ways of the {ways[0].kind} ahead)"
        if ways[0].kind == "closure":
            allowed = "none: the structure ahead is a closure"
        raise ScenarioFieldError("goal.way", goal["way"], allowed, "no such way", source)
    axis = net.start_pose.rotation @ option_vector(ways[goal["way"]])
    return (net.geometry[node].centre + axis * float(goal["distance"])).tolist()


def sensor_settings(sc: Scenario) -> tuple[LidarSpec, Pose | None]:
    """The scenario's LiDAR spec (preset with overrides) and its misalignment pose (None:
    mounted as designed); tilts are given in degrees, offsets in m."""
    sensor = sc.data.get("sensor", {})
    spec = get_preset(sensor.get("preset", "ideal"))
    overrides = sensor.get("overrides")
    if overrides:
        try:
            spec = spec.with_(**overrides)
        except Exception as exc:
            raise _field_error(
                exc, sc.source, "sensor.overrides", overrides, "LidarSpec fields"
            ) from None
    mis = sensor.get("misalignment")
    if not mis:
        return spec, None
    offset = np.asarray(mis.get("offset", [0, 0, 0]), dtype=float)
    roll, pitch, yaw = np.radians(mis.get("tilt_deg", [0, 0, 0]))
    rot = (
        rotation_about([0, 0, 1], yaw)
        @ rotation_about([0, 1, 0], pitch)
        @ rotation_about([1, 0, 0], roll)
    )
    return spec, Pose(offset, rot)


def env_kwargs(sc: Scenario, net: PipeNetwork) -> dict[str, Any]:
    """The ``gym.make`` arguments of the scenario's environment on ``net``."""
    spec, mis = sensor_settings(sc)
    return {
        "network": net,
        "detector": sc.detector,
        "fidelity": sc.fidelity,
        "lidar": spec,
        "misalignment": mis,
        "auto_single": sc.auto_single,
    }
