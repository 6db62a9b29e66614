"""The environments' parts: config, observation and action types, tasks, the network hook, the
oracle and the class docstrings."""

from __future__ import annotations

import dataclasses
import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import pipe_env
from agents.scripted import RoutePlanner
from detector.validation import ArgumentError
from pipe_env import layouts
from pipe_env.envs import PipeExploreEnv, PipeNavEnv
from pipe_env.envs.actions import BACK_ROW, K_OPTIONS, OptionAction
from pipe_env.envs.config import EnvConfig, ExploreConfig, NavConfig
from pipe_env.envs.observations import OPTION_COLUMNS, OPTION_FEATURES, DecisionObservation, column
from pipe_env.envs.oracle import Oracle, oracle_of
from pipe_env.envs.tasks import CoverageTask, GoalTask
from pipe_env.network import PipeNetwork


def _tee() -> PipeNetwork:
    """A tee with the goal in its left branch."""
    return layouts.t_junction(0.1, direction=0.0).with_goals([[0, 0.5, 0]])


#: The keyword arguments of gymnasium.make and their defaults before the configs existed.
SHARED_DEFAULTS = {
    "network_config": None,
    "network": None,
    "detector": "improved",
    "fidelity": "fast",
    "lidar": "ideal",
    "misalignment": None,
    "render_mode": None,
    "trigger_distance": 0.2,
    "auto_single": True,
    "max_jams": 3,
    "scan_image": False,
    "reward_invalid": -0.5,
    "reward_jam": -2.0,
    "reward_time": -0.05,
    "network_pool": None,
    "pool_seed": 0,
    "physics": "contact",
}


def _defaults(cls: type[EnvConfig]) -> dict[str, object]:
    return {f.name: f.default for f in dataclasses.fields(cls)}


def test_config_fields_are_the_make_arguments_with_their_defaults() -> None:
    assert _defaults(EnvConfig) == SHARED_DEFAULTS
    assert _defaults(NavConfig) == {**SHARED_DEFAULTS, "reward_goal": 10.0}
    assert _defaults(ExploreConfig) == {
        **SHARED_DEFAULTS,
        "coverage_done": 0.98,
        "branch_view": 0.3,
    }


def test_config_is_frozen_and_converts_values() -> None:
    cfg = NavConfig(network_config={"n_fittings": 5}, max_jams=np.int64(2), reward_jam=-1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.max_jams = 4  # type: ignore[misc]
    assert type(cfg.max_jams) is int and type(cfg.reward_jam) is float
    assert cfg.generator.n_fittings == 5 and cfg.lidar_spec.name == "ideal"
    env = gym.make("pipenav/PipeNav-v0", max_jams=2).unwrapped
    assert isinstance(env, PipeNavEnv) and env.config.max_jams == 2 and env.max_jams == 2


def test_config_errors_name_the_env_and_unknown_arguments_fail() -> None:
    with pytest.raises(ArgumentError) as err:
        ExploreConfig(max_jams=0)
    assert err.value.where == "PipeExplore-v0" and err.value.field == "max_jams"
    with pytest.raises(ArgumentError, match=r"^PipeNav-v0: network_config.n_goals = 0"):
        NavConfig(network_config={"n_goals": 0})
    ExploreConfig(network_config={"n_goals": 0})  # exploring needs no goal
    with pytest.raises(TypeError, match="reward_goal"):
        gym.make("pipenav/PipeExplore-v0", reward_goal=1.0)


def test_option_columns_are_named_and_bound_the_space() -> None:
    # the observation's column order is part of the API: trained policies depend on it
    assert OPTION_FEATURES == (
        "valid", "straight", "reducer", "closure", "bend", "junction", "back_out", "distance",
        "diameter", "cos_direction", "sin_direction", "angle", "confidence", "taken",
        "goal_alignment",
    )  # fmt: skip
    assert OPTION_FEATURES == tuple(c.name for c in OPTION_COLUMNS)
    assert [column(n) for n in OPTION_FEATURES] == list(range(len(OPTION_COLUMNS)))
    with pytest.raises(KeyError):
        column("speed")
    space = DecisionObservation(scan_image=False).space()
    assert set(space.spaces) == {"options", "goal", "proprio"}
    box = space["options"]
    assert box.shape == (K_OPTIONS, len(OPTION_COLUMNS))
    assert np.all(box.low == np.array([c.low for c in OPTION_COLUMNS], np.float32))
    assert np.all(box.high == np.array([c.high for c in OPTION_COLUMNS], np.float32))
    assert "scan" in DecisionObservation(scan_image=True).space().spaces


def test_observation_columns_hold_what_their_names_say() -> None:
    env = gym.make("pipenav/PipeNav-v0", network=_tee())
    obs, info = env.reset(seed=0)
    table = obs["options"]
    back = table[BACK_ROW]
    assert back[column("back_out")] == 1.0 and back[column("angle")] == np.float32(math.pi)
    dec = oracle_of(env).decision
    assert dec is not None
    for i, o in enumerate(dec.options[:BACK_ROW]):
        assert table[i, column(str(o.kind))] == 1.0
        assert table[i, column("diameter")] == np.float32(min(o.diameter, 0.3))
        assert table[i, column("valid")] == info["action_mask"][i]


INTEGERS_OUTSIDE = st.one_of(st.integers(max_value=-1), st.integers(min_value=K_OPTIONS))
NOT_INTEGERS = st.one_of(
    st.floats(), st.booleans(), st.text(max_size=3), st.none(), st.lists(st.integers(0, 5))
)


@settings(max_examples=60, deadline=None)
@given(st.one_of(INTEGERS_OUTSIDE, NOT_INTEGERS))
def test_action_type_refuses_anything_but_an_integer_of_the_space(action: object) -> None:
    with pytest.raises(ArgumentError) as err:
        OptionAction().check(action)
    assert err.value.field == "action"


@given(st.integers(0, K_OPTIONS - 1), st.sampled_from([int, np.int64, np.uint8, np.array]))
def test_action_type_accepts_integers_of_the_space(row: int, kind: type) -> None:
    assert OptionAction().check(kind(row)) == row


def test_action_mask_without_a_decision_allows_only_backing_out() -> None:
    mask = OptionAction().mask(None)
    assert mask.tolist() == [False] * (K_OPTIONS - 1) + [True]


def test_envs_use_their_tasks() -> None:
    nav = gym.make("pipenav/PipeNav-v0", network_config={"n_fittings": 6}).unwrapped
    explore = gym.make("pipenav/PipeExplore-v0", network_config={"n_fittings": 6}).unwrapped
    assert isinstance(nav.task, GoalTask) and isinstance(explore.task, CoverageTask)
    nav.reset(seed=1)
    explore.reset(seed=1)
    assert nav.goal_point is not None and np.array_equal(nav.goal_point, nav.task.goal)
    assert explore.goal_point is None and explore.task.covered_total > 0.0
    _, _, _, _, info = explore.step(BACK_ROW)
    assert info["covered"] == explore.task.covered_total


class _OneNetworkEnv(PipeNavEnv):
    """A subclass that supplies its own networks through the one hook."""

    def _gen_network(self) -> PipeNetwork:
        return _tee()


def test_the_network_hook_supplies_each_episode() -> None:
    env = _OneNetworkEnv()
    for seed in range(3):
        env.reset(seed=seed)
        assert env.network is not None and len(env.network.fittings) == len(_tee().fittings)


def test_oracle_gives_what_agents_may_know() -> None:
    env = gym.make("pipenav/PipeNav-v0", network=_tee())
    oracle = oracle_of(env)
    assert isinstance(oracle, Oracle) and oracle is env.unwrapped.oracle
    with pytest.raises(RuntimeError, match="after reset"):
        _ = oracle.network
    env.reset(seed=0)
    base = env.unwrapped
    assert oracle.network is base.network and oracle.decision is base.decision
    assert np.array_equal(oracle.true_pose().position, base.plant.pose().position)
    assert oracle.goal is not None and np.array_equal(oracle.goal, base.network.goals[0])
    assert oracle.last_scan is None  # fast fidelity
    assert oracle.driven_path().shape[1] == 3 and len(oracle.decision_points) == 1
    with pytest.raises(TypeError, match="not a pipenav environment"):
        oracle_of(gym.make("CartPole-v1"))


def test_oracle_survives_pickling_and_the_route_planner_uses_it() -> None:
    env = gym.make("pipenav/PipeNav-v0", network=_tee(), detector="ground_truth")
    obs, info = env.reset(seed=0)
    clone = pickle.loads(pickle.dumps(env))
    assert oracle_of(clone).network is clone.unwrapped.network
    agent = RoutePlanner(env)
    done = False
    while not done:
        obs, _, term, trunc, info = env.step(agent.act(obs, info))
        done = term or trunc
    assert info["is_success"]


SECTIONS = ("## Action space", "## Observation space", "## Rewards", "## Episode end")


@pytest.mark.parametrize(
    ("cls", "config"), [(PipeNavEnv, NavConfig), (PipeExploreEnv, ExploreConfig)]
)
def test_env_docstrings_table_spaces_rewards_end_and_every_argument(
    cls: type, config: type[EnvConfig]
) -> None:
    doc = cls.__doc__ or ""
    for section in (*SECTIONS, "## Arguments"):
        assert section in doc, section
    for name in config.argument_names():
        assert f"``{name}``" in doc, name
    for name in OPTION_FEATURES:
        assert f"``{name}``" in doc, name
    assert "|---|" in doc


def test_every_registered_env_is_a_documented_decision_env() -> None:
    for env_id in pipe_env.ENV_IDS:
        env = gym.make(env_id).unwrapped
        assert env.config.env_name == env_id.split("/")[1]
