"""The environments' observations, rewards and masks are pinned by recorded seeded rollouts.

The traces were first recorded before the environments were split into a config, observation
and action types and tasks; the split must not change them. Regenerate (only for an intended
change of behaviour, saying so in the commit) by running this file as a script.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from recorded import mismatches

import pipe_env  # noqa: F401  (registers the environments)
from agents.scripted import GoalGreedy, LeftHand, RandomAgent, RoutePlanner

#: (env id, make kwargs, agent, seeds)
CASES: dict[str, tuple[str, dict, str, tuple[int, ...]]] = {
    "nav_improved_random": (
        "pipenav/PipeNav-v0",
        {"network_config": {"n_fittings": 8}},
        "random",
        (0, 1, 2),
    ),
    "nav_thesis_greedy": (
        "pipenav/PipeNav-v0",
        {"detector": "thesis", "network_config": {"n_fittings": 10, "planar": False}},
        "goal_greedy",
        (3, 4),
    ),
    "nav_truth_pool_scan": (
        "pipenav/PipeNav-v0",
        {"detector": "ground_truth", "network_pool": 5, "pool_seed": 2, "scan_image": True},
        "random",
        (5, 6),
    ),
    "nav_route_planner": (
        "pipenav/PipeNav-v0",
        {"network_config": {"n_fittings": 10, "allow_loops": True}},
        "route_planner",
        (10, 11),
    ),
    "nav_full_route_planner": (
        "pipenav/PipeNav-v0",
        {"fidelity": "full", "scan_image": True, "network_config": {"n_fittings": 3}},
        "route_planner",
        (12,),
    ),
    "explore_left_hand": (
        "pipenav/PipeExplore-v0",
        {"network_config": {"n_fittings": 8, "allow_loops": True}},
        "left_hand",
        (7, 8),
    ),
    "explore_random_no_auto": (
        "pipenav/PipeExplore-v0",
        {"auto_single": False, "network_config": {"n_fittings": 6}},
        "random",
        (9,),
    ),
}

AGENTS = {
    "random": RandomAgent,
    "goal_greedy": GoalGreedy,
    "left_hand": LeftHand,
    "route_planner": RoutePlanner,
}

#: The recorded traces (one set of arrays per case: ``python tests/test_env_golden.py`` writes
#: them). They were pinned as sha256 digests of the raw bytes until another machine's
#: arithmetic moved the last bits (see :mod:`recorded`). The discrete parts must match exactly
#: and the floats to ``RTOL``/``ATOL`` (the reward terms as :mod:`recorded` compares them).
TRACES = Path(__file__).parent / "data" / "golden_traces.npz"
#: Tolerances of the floats (observations are float32: a relative 1e-5 is ~80 ulps).
RTOL, ATOL = 1e-5, 1e-6


def record_trace(case: str, max_steps: int = 40) -> dict[str, np.ndarray]:
    """The observations, rewards, flags, masks and reward terms of the case's rollouts, as
    arrays named ``<field>``: one row per step over all its seeds (the reset's row first,
    with reward 0 and no flags)."""
    env_id, kwargs, agent_name, seeds = CASES[case]
    env = gym.make(env_id, **kwargs)
    rows: dict[str, list[Any]] = {}

    def add(obs: dict, reward: float, flags: tuple[bool, bool], info: dict, masks: Any) -> None:
        for key in sorted(obs):
            rows.setdefault(f"obs/{key}", []).append(np.asarray(obs[key], dtype=np.float64))
        rows.setdefault("reward", []).append(float(reward))
        rows.setdefault("flags", []).append(flags)
        rows.setdefault("info_mask", []).append(np.asarray(info["action_mask"], dtype=bool))
        rows.setdefault("env_mask", []).append(np.asarray(masks, dtype=bool))
        terms = info.get("reward_terms", {})
        extra = {k: info[k] for k in ("coverage", "distance_to_goal", "jams") if k in info}
        numbers = {**{f"term/{k}": v for k, v in terms.items()}, **extra}
        rows.setdefault("numbers", []).append(json.dumps(numbers, sort_keys=True))

    for seed in seeds:
        agent = AGENTS[agent_name](env) if agent_name != "random" else RandomAgent(env, seed=seed)
        obs, info = env.reset(seed=seed)
        add(obs, 0.0, (False, False), {**info, "reward_terms": {}}, info["action_mask"])
        for _ in range(max_steps):
            obs, reward, term, trunc, info = env.step(agent.act(obs, info))
            add(obs, reward, (term, trunc), info, env.unwrapped.action_masks())
            if term or trunc:
                break
    env.close()
    return {k: np.asarray(v) for k, v in rows.items()}


def differences(case: str, got: dict[str, np.ndarray], want: dict[str, np.ndarray]) -> list[str]:
    """Where the trace ``got`` departs from ``want``: field names, the first step that
    differs and by how much (empty when they agree)."""
    out = []
    if sorted(got) != sorted(want):
        return [f"{case}: fields {sorted(got)} != {sorted(want)}"]
    for key in sorted(want):
        a, b = got[key], want[key]
        if a.shape != b.shape:
            out.append(f"{case}/{key}: shape {a.shape} != {b.shape} (steps differ)")
            continue
        if key == "numbers":
            close = np.array([not mismatches(json.loads(x), json.loads(y)) for x, y in zip(a, b)])
        elif a.dtype.kind == "f":
            near = np.isclose(a, b, rtol=RTOL, atol=ATOL, equal_nan=True)
            close = near.reshape(len(a), -1).all(axis=1)
        else:
            close = (a == b).reshape(len(a), -1).all(axis=1)
        if not close.all():
            step = int(np.flatnonzero(~close)[0])
            out.append(f"{case}/{key}: step {step}: {a[step]!r} != {b[step]!r}")
    return out


def _load(case: str) -> dict[str, np.ndarray]:
    with np.load(TRACES) as data:
        return {k.split(":", 1)[1]: data[k] for k in data.files if k.split(":", 1)[0] == case}


#: cases over ~10 s (full fidelity)
SLOW = {"nav_full_route_planner"}


@pytest.mark.parametrize(
    "case", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW else c for c in sorted(CASES)]
)
def test_seeded_rollouts_repeat_the_recorded_traces(case: str) -> None:
    assert differences(case, record_trace(case), _load(case)) == []


def test_a_changed_trace_is_caught() -> None:
    """The comparison fails on a float moved beyond its tolerance, a flipped mask bit and a
    changed reward term (the case's recorded trace against edited copies of itself)."""
    want = _load("nav_improved_random")
    moved = {k: v.copy() for k, v in want.items()}
    moved["obs/proprio"][3, 0] += 1e-3
    masked = {k: v.copy() for k, v in want.items()}
    masked["env_mask"][2, 0] = ~masked["env_mask"][2, 0]
    termed = {k: v.copy() for k, v in want.items()}
    numbers = json.loads(str(termed["numbers"][1]))
    key = next(k for k, v in numbers.items() if isinstance(v, float))
    numbers[key] += 1e-3
    termed["numbers"][1] = json.dumps(numbers, sort_keys=True)
    assert differences("c", want, want) == []
    for edited, field in ((moved, "obs/proprio"), (masked, "env_mask"), (termed, "numbers")):
        found = differences("c", edited, want)
        assert len(found) == 1 and found[0].startswith(f"c/{field}: step")


if __name__ == "__main__":
    arrays = {f"{name}:{k}": v for name in sorted(CASES) for k, v in record_trace(name).items()}
    np.savez_compressed(TRACES, **arrays)
    print(f"wrote {TRACES} ({TRACES.stat().st_size} bytes)")
