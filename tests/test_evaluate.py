"""The held-out evaluation: every agent meets the same networks with the same sensing noise,
the learned policy through sb3-contrib's ``evaluate_policy`` as the scripted ones through
their loop."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pytest

import agents
from agents.evaluate import (
    EVAL_POOL_SEED,
    PolicyAgent,
    SequentialNetworks,
    _summarise,
    evaluate,
    held_out_networks,
)
from pipe_env.generator import NetworkConfig

SHIPPED_POLICY = Path(agents.__file__).parent / "maskable_ppo_policy.zip"


def _loop(env: gym.Env, actor: object, n: int) -> list[dict]:
    infos = []
    for _ in range(n):
        obs, info = env.reset()
        done = False
        while not done:
            obs, _, term, trunc, info = env.step(actor.act(obs, info))
            done = term or trunc
        infos.append(info)
    return infos


def test_learned_policy_is_evaluated_on_the_scripted_agents_episodes() -> None:
    """sb3's automatic resets pass no seed: the evaluation seeds each episode itself, so the
    policy's figures through ``evaluate_policy`` equal those of the same policy acting
    through the scripted agents' loop, episode for episode."""
    n = 6
    via_sb3 = evaluate(str(SHIPPED_POLICY), n_episodes=n)
    cfg = NetworkConfig()
    env = SequentialNetworks(
        gym.make("pipenav/PipeNav-v0", network_config=cfg),
        held_out_networks(cfg, n, EVAL_POOL_SEED),
        EVAL_POOL_SEED,
    )
    looped = _summarise(str(SHIPPED_POLICY), _loop(env, PolicyAgent(SHIPPED_POLICY), n), 0.0)
    for field in ("episodes", "success_rate", "jams_per_episode", "decisions_per_episode"):
        assert getattr(via_sb3, field) == getattr(looped, field), field
    assert via_sb3.sim_seconds_per_episode == looped.sim_seconds_per_episode


def test_scripted_evaluation_is_repeatable_and_sane() -> None:
    a = evaluate("route_planner", n_episodes=5)
    b = evaluate("route_planner", n_episodes=5)
    assert a.to_dict() | {"wall_seconds": 0} == b.to_dict() | {"wall_seconds": 0}
    assert a.episodes == 5 and a.success_rate >= 0.8 and a.decisions_per_episode >= 1.0


def test_parallel_evaluation_gives_the_sequential_figures() -> None:
    """Two episodes in two worker processes: the same networks and seeds as one process."""
    sequential = evaluate("route_planner", n_episodes=2)
    done: list[int] = []
    parallel = evaluate(
        "route_planner", n_episodes=2, jobs=2, on_episode=lambda d, n: done.append(d)
    )
    assert parallel.to_dict() | {"wall_seconds": 0} == sequential.to_dict() | {"wall_seconds": 0}
    assert done == [1, 2]


def test_bad_parallel_arguments_name_the_field() -> None:
    with pytest.raises(ValueError, match="jobs = 0"):
        evaluate("route_planner", n_episodes=2, jobs=0)
    with pytest.raises(ValueError, match="backend = 'threads'"):
        evaluate("route_planner", n_episodes=2, jobs=2, backend="threads")


@pytest.mark.slow
def test_parallel_full_fidelity_evaluation_gives_the_sequential_figures() -> None:
    """The MuJoCo loop in two worker processes: the same outcomes as in one."""
    kwargs = {
        "fidelity": "full",
        "network_config": {"n_fittings": 3, "planar": True, "allow_loops": False},
        "max_episode_steps": 6,
    }
    sequential = evaluate("route_planner", n_episodes=2, env_kwargs=kwargs)
    parallel = evaluate("route_planner", n_episodes=2, env_kwargs=kwargs, jobs=2)
    assert parallel.to_dict() | {"wall_seconds": 0} == sequential.to_dict() | {"wall_seconds": 0}
