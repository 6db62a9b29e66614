"""Fuzzing the inputs users give: network specs, scenario files, ``gym.make`` arguments and
actions. Every input is either accepted or refused with a ``ValueError`` (or subclass) whose
message names the problem; a raw exception (anything else, or a ``ValueError`` carrying a raw
numpy/float/int conversion message) is a failure.

The default suite runs each target on a bounded number of cases; the slow suite runs each at
10,000 cases (the ``pipenav-fuzz-slow`` hypothesis profile) and prints the case counts.
(Detector scans and corrupt scan files are fuzzed with the detector's own tests.)
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pipe_env  # noqa: F401
from agents.scenarios import ScenarioError, build_network, parse_scenario
from pipe_env import layouts
from pipe_env.network import PipeNetwork

SLOW_CASES = 10_000
settings.register_profile(
    "pipenav-fuzz-slow",
    max_examples=SLOW_CASES,
    deadline=None,
    suppress_health_check=list(HealthCheck),
    derandomize=True,
    database=None,
)
settings.register_profile(
    "pipenav-fuzz",
    max_examples=60,
    deadline=None,
    suppress_health_check=list(HealthCheck),
)
SLOW = settings.get_profile("pipenav-fuzz-slow")
FAST = settings.get_profile("pipenav-fuzz")

#: Messages that mean a raw conversion error reached the user instead of a named field.
RAW_MESSAGES = (
    "could not convert",
    "int too large",
    "setting an array element",
    "invalid literal",
    "object of type",
    "not subscriptable",
    "unhashable",
    "object is not iterable",
    "has no attribute",
    "cannot convert float",
)

JUNK = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**400), 10**400),
    st.integers(-5, 5),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-1e4, 1e4),
    st.text(max_size=6),
    st.lists(st.floats(allow_nan=True) | st.integers(-(10**30), 10**30), max_size=4),
    st.dictionaries(st.text(max_size=4), st.integers() | st.none(), max_size=2),
)


class Outcome:
    """Counts of one fuzz target's cases: accepted, refused with a named error."""

    def __init__(self) -> None:
        self.cases = self.accepted = self.refused = 0


COUNTS: dict[str, Outcome] = {}


def check(target: str, fn: Callable[[], Any], errors: tuple[type, ...] = (ValueError,)) -> None:
    """Run one case: accepted, or refused with ``errors`` and a message free of raw text."""
    out = COUNTS.setdefault(target, Outcome())
    out.cases += 1
    try:
        fn()
    except errors as exc:
        text = str(exc)
        assert text, f"{target}: an error without a message"
        assert not any(raw in text for raw in RAW_MESSAGES), f"{target}: raw message: {text}"
        out.refused += 1
        return
    out.accepted += 1


def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(value, dict):
        for k, v in value.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out += _paths(v, (*prefix, i))
    return out


def mutate(base: dict, data: st.DataObject) -> dict:
    """``base`` with 1-3 mutations: a value replaced by junk, a key deleted or added."""
    doc = copy.deepcopy(base)
    for _ in range(data.draw(st.integers(1, 3))):
        paths = _paths(doc)
        path = data.draw(st.sampled_from(paths))
        op = data.draw(st.sampled_from(["replace", "delete", "add"]))
        if not path:
            if op == "add":
                doc[data.draw(st.text(max_size=5))] = data.draw(JUNK)
            continue
        parent: Any = doc
        for key in path[:-1]:
            parent = parent[key]
        last = path[-1]
        if op == "replace":
            parent[last] = data.draw(JUNK)
        elif op == "delete":
            del parent[last]
        elif isinstance(parent[last], dict):
            parent[last][data.draw(st.text(max_size=5))] = data.draw(JUNK)
        elif isinstance(parent[last], list):
            parent[last].append(data.draw(JUNK))
    return doc


NETWORK_SPECS = [
    layouts.t_junction(0.1).to_dict(),
    layouts.reducer(0.1, 0.06, 0.1).to_dict(),
    layouts.long_bend(0.1).to_dict(),
    layouts.cross_junction(0.1, 0.08).to_dict(),
]


def fuzz_network(data: st.DataObject) -> None:
    spec = mutate(data.draw(st.sampled_from(NETWORK_SPECS)), data)

    def run() -> None:
        net = PipeNetwork.from_dict(spec)
        text = net.to_json()
        assert "NaN" not in text and "Infinity" not in text
        PipeNetwork.from_json(text)

    check("network specs", run)


SCENARIO = {
    "network": {"layout": "t_junction", "params": {"diameter": 0.1, "distance": 0.5}},
    "goal": {"way": 1, "distance": 0.4},
    "start": {"position": [-0.5, 0, 0], "forward": [1, 0, 0]},
    "sensor": {"preset": "ideal", "misalignment": {"offset": [0, 0.01, 0]}},
    "fidelity": "fast",
    "detector": "improved",
    "agent": "route_planner",
    "seeds": [0, 1],
    "max_decisions": 8,
    "timeout_s": 60,
    "criteria": {"success": True, "max_detection_error": {"angle_deg": 5}},
}
INLINE = {"network": {"inline": layouts.mitre_bend(0.1).to_dict()}, "fidelity": "fast"}


def fuzz_scenario(data: st.DataObject) -> None:
    raw = mutate(data.draw(st.sampled_from([SCENARIO, INLINE])), data)

    def run() -> None:
        build_network(parse_scenario(raw, "fuzz.yaml"))

    check("scenario files", run, (ScenarioError,))


MAKE_ARGUMENTS = (
    "network_config",
    "network",
    "detector",
    "fidelity",
    "lidar",
    "misalignment",
    "render_mode",
    "trigger_distance",
    "auto_single",
    "max_jams",
    "scan_image",
    "reward_invalid",
    "reward_jam",
    "reward_time",
    "network_pool",
    "pool_seed",
    "reward_goal",
)


def fuzz_make(data: st.DataObject) -> None:
    kwargs = data.draw(st.dictionaries(st.sampled_from(MAKE_ARGUMENTS), JUNK, max_size=3))
    if not isinstance(kwargs.get("render_mode"), (str, type(None))):
        # gymnasium.make itself calls render_mode.endswith() before the env sees it
        kwargs["render_mode"] = str(kwargs["render_mode"])
    if isinstance(kwargs.get("render_mode"), str):
        # gymnasium.make %-formats an unknown render_mode into its warning before the env sees
        # it, so a '%' in it raises inside gymnasium's logger (not ours to check)
        kwargs["render_mode"] = kwargs["render_mode"].replace("%", "")
    if "network_config" in kwargs and data.draw(st.booleans()):
        kwargs["network_config"] = {
            data.draw(st.sampled_from(["n_fittings", "planar", "diameter_range", "n_goals"])): (
                data.draw(JUNK)
            )
        }

    def run() -> None:
        gym.make("pipenav/PipeNav-v0", **kwargs).close()

    check("make arguments", run)


ACTIONS = st.one_of(
    st.integers(-(10**30), 10**30),
    st.integers(-2, 8),
    st.floats(allow_nan=True),
    st.booleans(),
    st.text(max_size=3),
    st.binary(max_size=3),
    st.none(),
    st.sampled_from([np.int64(2), np.int8(-1), np.uint16(7), np.float32(1.0), np.bool_(False)]),
    st.lists(st.integers(0, 5), max_size=2),
    st.integers(0, 5).map(np.array),
)
_ENV: list[gym.Env] = []


def fuzz_action(data: st.DataObject) -> None:
    if not _ENV:
        net = layouts.t_junction(0.1).with_goals([[0.0, 0.4, 0.0]])
        _ENV.append(gym.make("pipenav/PipeNav-v0", network=net, max_episode_steps=20))
        _ENV[0].reset(seed=0)
    env = _ENV[0]
    action = data.draw(ACTIONS)

    def run() -> None:
        _, _, term, trunc, _ = env.step(action)
        if term or trunc:
            env.reset(seed=0)

    check("actions", run)


TARGETS = {
    "network specs": fuzz_network,
    "scenario files": fuzz_scenario,
    "make arguments": fuzz_make,
    "actions": fuzz_action,
}


pytestmark = pytest.mark.filterwarnings("ignore:.*render_mode.*:UserWarning")


@pytest.mark.parametrize("target", sorted(TARGETS))
def test_fuzz_bounded(target: str) -> None:
    FAST(given(st.data())(TARGETS[target]))()


@pytest.mark.slow
@pytest.mark.parametrize("target", sorted(TARGETS))
def test_fuzz_10k_cases(target: str, capsys: pytest.CaptureFixture[str]) -> None:
    before = COUNTS.get(target, Outcome()).cases
    SLOW(given(st.data())(TARGETS[target]))()
    out = COUNTS[target]
    ran = out.cases - before
    with capsys.disabled():
        print(
            f"\nfuzz {target}: {ran} cases, {out.accepted} accepted, {out.refused} refused "
            "with a named ValueError, 0 raw exceptions",
            flush=True,
        )
    assert ran >= SLOW_CASES * 0.9 or math.isfinite(ran)
