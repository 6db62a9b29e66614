"""The Gymnasium environments: API conformance, determinism, pickling, vector envs, masks."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import pipe_env
from agents import GoalGreedy, RandomAgent, RoutePlanner
from detector.validation import ArgumentError
from pipe_env import layouts
from pipe_env.envs import K_OPTIONS, OPTION_FEATURES

ENV_IDS = sorted(pipe_env.ENV_IDS)
SMALL = {"n_fittings": 6}


def rollout(env: gym.Env, seed: int, max_steps: int = 40, agent_seed: int = 0) -> list:
    agent = RandomAgent(env, seed=agent_seed)
    obs, info = env.reset(seed=seed)
    trace = [(obs["options"].tobytes(), obs["goal"].tobytes())]
    for _ in range(max_steps):
        obs, reward, term, trunc, info = env.step(agent.act(obs, info))
        trace.append((obs["options"].tobytes(), round(reward, 12), term, trunc, info["travelled"]))
        if term or trunc:
            break
    return trace


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_gymnasium_and_sb3_checkers_pass(env_id: str) -> None:
    env = gym.make(env_id, network_config=SMALL)
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(gym.make(env_id, network_config=SMALL).unwrapped, warn=True)


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("detector", ["ground_truth", "improved", "thesis"])
def test_same_seed_same_trajectory(env_id: str, detector: str) -> None:
    a = gym.make(env_id, detector=detector, network_config=SMALL)
    b = gym.make(env_id, detector=detector, network_config=SMALL)
    assert rollout(a, seed=5) == rollout(b, seed=5)
    assert rollout(a, seed=5) != rollout(a, seed=6)


def test_observations_stay_in_their_spaces_over_many_episodes() -> None:
    env = gym.make(
        "pipenav/PipeNav-v0",
        detector="thesis",
        network_config={"n_fittings": 12, "planar": False, "allow_loops": True},
    )
    agent = RandomAgent(env, seed=1)
    for ep in range(30):
        obs, info = env.reset(seed=ep)
        assert env.observation_space.contains(obs)
        done = False
        while not done:
            obs, reward, term, trunc, info = env.step(agent.act(obs, info))
            assert env.observation_space.contains(obs), obs
            assert np.isfinite(reward)
            done = term or trunc
    assert obs["options"].shape == (K_OPTIONS, len(OPTION_FEATURES))


def test_masked_action_is_a_penalised_no_op() -> None:
    env = gym.make(
        "pipenav/PipeNav-v0",
        network=layouts.t_junction(0.1).with_goals([[0, 0.6, 0]]),
        detector="ground_truth",
    )
    obs, info = env.reset(seed=0)
    mask = info["action_mask"]
    masked = int(np.flatnonzero(mask == 0)[0])
    before = env.unwrapped.plant.pose().position.copy()
    obs2, reward, term, trunc, info2 = env.step(masked)
    assert info2["invalid_action"] is True
    assert reward == pytest.approx(-0.5 - 0.05)  # invalid + time cost
    assert not term
    assert np.array_equal(env.unwrapped.plant.pose().position, before)
    assert np.array_equal(obs2["options"], obs["options"])  # the same decision again
    assert info2["decisions"] == info["decisions"]


def test_route_planner_reaches_the_goal_in_a_tee() -> None:
    net = layouts.t_junction(0.1, direction=0.0).with_goals([[0, 0.5, 0]])  # left branch
    env = gym.make("pipenav/PipeNav-v0", network=net, detector="ground_truth")
    agent = RoutePlanner(env)
    obs, info = env.reset(seed=0)
    assert info["decisions"] == 0
    obs, reward, term, trunc, info = env.step(agent.act(obs, info))
    assert term and info["is_success"]
    assert info["reward_terms"]["goal"] == 10.0
    assert info["reward_terms"]["progress"] > 0.5


def test_wrong_way_then_back_out() -> None:
    net = layouts.t_junction(0.1, direction=0.0).with_goals([[0, 0.5, 0]])
    env = gym.make("pipenav/PipeNav-v0", network=net, detector="ground_truth")
    obs, info = env.reset(seed=0)
    straight = 0  # the straight-on way leads to a closure
    obs, reward, term, trunc, info = env.step(straight)
    assert not term
    assert env.unwrapped.decision.kind == "closure"
    assert info["reward_terms"]["progress"] < 0
    assert not info["action_mask"][: K_OPTIONS - 1].any()  # a dead end: only back out
    obs, reward, term, trunc, info = env.step(K_OPTIONS - 1)
    assert env.unwrapped.decision.kind == "junction"  # back at the tee
    obs, reward, term, trunc, info = env.step(RoutePlanner(env).act(obs, info))
    assert term and info["is_success"]


def test_jams_with_a_badly_wrong_detector_and_terminate_after_max_jams() -> None:
    from pipe_env.envs.sensing_model import DetectionErrorModel

    net = layouts.mitre_bend(0.1).with_goals([[0.0, 0.5, 0.0]])
    env = gym.make(
        "pipenav/PipeNav-v0", network=net, detector="ground_truth", max_jams=2, auto_single=False
    ).unwrapped
    obs, info = env.reset(seed=0)
    env.plant.error_model = DetectionErrorModel("bad", direction_sigma=1.0)
    # the decision already sensed is exact; make it wrong by 90 deg
    from dataclasses import replace

    env.decision.options[0] = replace(env.decision.options[0], direction=np.pi / 2)
    obs, reward, term, trunc, info = env.step(0)
    assert info["jammed"] and info["jams"] == 1 and not term
    assert info["reward_terms"]["jam"] == -2.0
    env.decision.options[0] = replace(env.decision.options[0], direction=np.pi / 2)
    obs, reward, term, trunc, info = env.step(0)
    assert info["jams"] == 2 and term and not info["is_success"]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_pickle_round_trip_continues_identically(env_id: str) -> None:
    env = gym.make(env_id, network_config=SMALL)
    env.reset(seed=3)
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(5):
        mask = env.unwrapped.action_masks()
        action = int(np.flatnonzero(mask)[-1])
        r1 = env.step(action)
        r2 = clone.step(action)
        assert r1[0]["options"].tobytes() == r2[0]["options"].tobytes()
        assert r1[1] == r2[1] and r1[2] == r2[2]
        if r1[2] or r1[3]:
            break


def test_full_fidelity_env_refuses_to_pickle_mid_episode() -> None:
    """A live MuJoCo simulation cannot be pickled: a clear TypeError, not MuJoCo's own."""
    net = layouts.t_junction(0.1, direction=0.0, distance=0.3).with_goals([[0, 0.5, 0]])
    env = gym.make("pipenav/PipeNav-v0", network=net, fidelity="full", detector="ground_truth")
    clone = pickle.loads(pickle.dumps(env))  # before reset: only the constructor's arguments
    assert clone.unwrapped.fidelity == "full" and clone.unwrapped.plant is None
    env.reset(seed=0)
    with pytest.raises(TypeError, match=r"fidelity='full'.*cannot be pickled mid-episode"):
        pickle.dumps(env)
    env.close()


@pytest.mark.parametrize("vectorization_mode", ["sync", "async"])
def test_make_vec(vectorization_mode: str) -> None:
    """Sub-environments seeded differently differ, the same seeds reproduce, and each
    sub-environment runs exactly as a single environment with its seed."""

    def trace(seeds: list[int]) -> list[tuple]:
        envs = gym.make_vec(
            "pipenav/PipeNav-v0",
            num_envs=2,
            vectorization_mode=vectorization_mode,
            network_config=SMALL,
        )
        obs, info = envs.reset(seed=seeds)
        assert obs["options"].shape == (2, K_OPTIONS, len(OPTION_FEATURES))
        out = [(obs["options"].copy(), obs["goal"].copy(), np.zeros(2))]
        for _ in range(5):
            obs, reward, term, trunc, info = envs.step(np.full(2, K_OPTIONS - 1))
            assert reward.shape == (2,)
            out.append((obs["options"].copy(), obs["goal"].copy(), reward.copy()))
        envs.close()
        return out

    first, again = trace([1, 2]), trace([1, 2])
    for (o1, g1, r1), (o2, g2, r2) in zip(first, again):
        assert np.array_equal(o1, o2) and np.array_equal(g1, g2) and np.array_equal(r1, r2)
    # seeds 1 and 2 draw different networks: the goals differ from the start
    assert not np.array_equal(first[0][1][0], first[0][1][1])
    single = gym.make("pipenav/PipeNav-v0", network_config=SMALL)
    obs, _ = single.reset(seed=1)
    assert np.array_equal(obs["options"], first[0][0][0])
    assert np.array_equal(obs["goal"], first[0][1][0])


def test_masks_reach_maskable_ppo_through_subproc_vec_env() -> None:
    from sb3_contrib.common.maskable.utils import get_action_masks
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    # "module:id" makes the worker processes import pipe_env (which registers the ids)
    venv = make_vec_env(
        "pipe_env:pipenav/PipeNav-v0",
        n_envs=2,
        vec_env_cls=SubprocVecEnv,
        seed=0,
        env_kwargs={"network_config": SMALL},
    )
    venv.reset()
    masks = get_action_masks(venv)
    assert masks.shape == (2, K_OPTIONS) and masks[:, -1].all()
    venv.close()


def test_render_modes(needs_gl: str) -> None:
    env = gym.make("pipenav/PipeNav-v0", network_config=SMALL, render_mode="ansi")
    env.reset(seed=0)
    text = env.render()
    assert "back out" in text and "structure ahead" in text
    env = gym.make("pipenav/PipeNav-v0", network_config=SMALL, render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.std() > 1
    env.close()


def test_explore_env_rewards_new_coverage_and_finishes() -> None:
    from agents import LeftHand

    env = gym.make(
        "pipenav/PipeExplore-v0", network_config={"n_fittings": 5}, detector="ground_truth"
    )
    agent = LeftHand(env)
    obs, info = env.reset(seed=4)
    total = info["covered"]
    done = False
    while not done:
        obs, reward, term, trunc, info = env.step(agent.act(obs, info))
        assert reward == pytest.approx(info["reward_terms"]["coverage"] - 0.05)
        total += info["reward_terms"]["coverage"]
        done = term or trunc
    assert info["covered"] == pytest.approx(total)
    assert info["coverage"] >= 0.98 and info["is_success"]


BAD_ARGUMENTS = [
    ("PipeNav-v0", "network_config", "big", "a NetworkConfig, its dict or None"),
    ("PipeNav-v0", "pool_seed", "a", "an integer at least 0"),
    ("PipeNav-v0", "pool_seed", -1, "an integer at least 0"),
    ("PipeNav-v0", "max_jams", "x", "an integer at least 1"),
    ("PipeNav-v0", "max_jams", 0, "an integer at least 1"),
    ("PipeNav-v0", "max_jams", True, "an integer at least 1"),
    ("PipeNav-v0", "trigger_distance", "far", "above 0 to 1 (m)"),
    ("PipeNav-v0", "trigger_distance", -1.0, "above 0 to 1 (m)"),
    ("PipeNav-v0", "trigger_distance", 0.0, "above 0 to 1 (m)"),
    ("PipeNav-v0", "trigger_distance", 1.5, "above 0 to 1 (m)"),
    ("PipeNav-v0", "reward_jam", float("nan"), "a finite number"),
    ("PipeNav-v0", "reward_invalid", float("inf"), "a finite number"),
    ("PipeNav-v0", "reward_time", "cheap", "a finite number"),
    ("PipeNav-v0", "reward_time", False, "a finite number"),
    ("PipeNav-v0", "reward_goal", float("nan"), "0 to 1000"),
    ("PipeNav-v0", "network_pool", True, "an integer at least 1"),
    ("PipeNav-v0", "network_pool", 0, "an integer at least 1"),
    ("PipeNav-v0", "auto_single", "no", "true or false"),
    ("PipeNav-v0", "scan_image", 1, "true or false"),
    ("PipeNav-v0", "detector", "oracle", "improved, thesis, ground_truth"),
    ("PipeNav-v0", "fidelity", "medium", "fast, full"),
    ("PipeNav-v0", "lidar", "foo", "a preset name (ideal, ls02, ydlidar_x4)"),
    ("PipeNav-v0", "network", 3, "a PipeNetwork, a dict or a file path"),
    ("PipeExplore-v0", "coverage_done", 5.0, "above 0 to 1"),
    ("PipeExplore-v0", "coverage_done", 0.0, "above 0 to 1"),
    ("PipeExplore-v0", "branch_view", -0.1, "at least 0 (m)"),
    ("PipeExplore-v0", "trigger_distance", -1.0, "above 0 to 1 (m)"),
]


@pytest.mark.parametrize(("env", "name", "value", "allowed"), BAD_ARGUMENTS)
def test_bad_make_arguments_are_rejected_naming_the_argument(
    env: str, name: str, value: object, allowed: str
) -> None:
    with pytest.raises(ValueError) as err:
        gym.make(f"pipenav/{env}", **{name: value})
    message = str(err.value)
    assert message.startswith(f"{env}: {name} = {value!r}: "), message
    assert isinstance(err.value, ArgumentError) and err.value.field == name
    assert f"; allowed: {allowed}" in message or allowed in err.value.allowed, message


def test_a_bad_network_config_field_is_named_by_its_path() -> None:
    with pytest.raises(ArgumentError) as err:
        gym.make("pipenav/PipeNav-v0", network_config={"n_fittings": -1})
    assert err.value.field == "network_config.n_fittings"
    assert str(err.value) == (
        "PipeNav-v0: network_config.n_fittings = -1: out of range; allowed: an integer 1 to 200"
    )


def test_good_make_arguments_are_kept() -> None:
    from pipe_env.generator import NetworkConfig

    env = gym.make(
        "pipenav/PipeNav-v0",
        network_config=NetworkConfig(n_fittings=6),
        trigger_distance=1,
        max_jams=np.int64(2),
        reward_jam=-1,
        network_pool=5,
        pool_seed=np.int64(3),
    ).unwrapped
    assert env.trigger_distance == 1.0 and isinstance(env.trigger_distance, float)
    assert env.max_jams == 2 and type(env.max_jams) is int
    assert env.reward_jam == -1.0 and env.network_pool == 5 and env.pool_seed == 3


def test_goal_greedy_and_bad_options_are_rejected() -> None:
    with pytest.raises(ValueError, match="detector = 'oracle': unknown; allowed: improved"):
        gym.make("pipenav/PipeNav-v0", detector="oracle")
    with pytest.raises(ValueError, match="fidelity = 'medium': unknown; allowed: fast, full"):
        gym.make("pipenav/PipeNav-v0", fidelity="medium")
    env = gym.make("pipenav/PipeNav-v0", network_config=SMALL)
    agent = GoalGreedy(env)
    obs, info = env.reset(seed=0)
    assert 0 <= agent.act(obs, info) < K_OPTIONS


def test_noisy_ninety_degree_ways_stay_drivable(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ordinary sensing noise must not mask a true 90 deg way (regression: about half were
    masked). The thesis's published accuracy stands for ordinary noise here."""
    from dataclasses import replace

    import pipe_env.envs.env
    from detector.options import match_option
    from pipe_env.envs.sensing_model import THESIS_LITERATURE_MODEL
    from pipe_env.robot_limits import drivable

    monkeypatch.setattr(pipe_env.envs.env, "error_model_for", lambda *a: THESIS_LITERATURE_MODEL)
    net = layouts.t_junction(0.1).with_goals([[0, 0.5, 0]])
    env = gym.make("pipenav/PipeNav-v0", network=net, detector="thesis")
    masked = 0
    for seed in range(60):
        obs, info = env.reset(seed=seed)
        dec = env.unwrapped.decision
        real = [i for i, o in enumerate(dec.options) if match_option(o, dec.truth)[1] < 0.2]
        masked += sum(not info["action_mask"][i] for i in real if dec.options[i].angle > 1.0)
    assert masked == 0
    o = env.unwrapped.decision.options[-1]
    assert drivable(replace(o, angle=np.radians(93.0)))
    assert not drivable(replace(o, angle=np.radians(135.0)))
    assert not drivable(replace(o, diameter=0.050))


def test_the_mask_and_the_full_fidelity_refusal_share_the_turn_limit() -> None:
    """A way sensed beyond the turn the robot attempts is masked, and the sequence built for
    it halts naming that limit (100 deg: 90 deg fittings plus sensing noise)."""
    from detector.options import StructureOption
    from pipe_env.robot_limits import drivable
    from primitives.sequences import MAX_TURN_ATTEMPT, for_option
    from primitives.steps import Halt

    limit = round(np.degrees(MAX_TURN_ATTEMPT))
    near = StructureOption("bend", 0.2, 0.1, direction=0.0, angle=np.radians(limit - 1))
    beyond = StructureOption("bend", 0.2, 0.1, direction=0.0, angle=np.radians(limit + 5))
    assert drivable(near) and not any(isinstance(s, Halt) for s in for_option(near).steps)
    assert not drivable(beyond)
    halts = [s for s in for_option(beyond).steps if isinstance(s, Halt)]
    assert len(halts) == 1 and halts[0].status == "blocked"
    assert halts[0].reason == f"turn of {limit + 5} deg exceeds the {limit} deg the robot attempts"


def test_goal_just_past_a_fitting_is_reached() -> None:
    net = layouts.t_junction(0.12, direction=0.0).with_goals([[0, 0.10, 0]])
    env = gym.make("pipenav/PipeNav-v0", network=net, detector="ground_truth", max_episode_steps=5)
    obs, info = env.reset(seed=0)
    obs, reward, term, trunc, info = env.step(RoutePlanner(env).act(obs, info))
    assert term and info["is_success"] and not trunc


def test_route_planner_backs_out_when_the_planned_way_is_not_detected() -> None:
    from dataclasses import replace

    net = layouts.t_junction(0.1, direction=0.0).with_goals([[0, 0.5, 0]])
    env = gym.make("pipenav/PipeNav-v0", network=net, detector="ground_truth")
    obs, info = env.reset(seed=0)
    dec = env.unwrapped.decision
    dec.options[:] = [o for o in dec.options if o.angle < 0.1]  # the branch was missed
    assert RoutePlanner(env).act(obs, info) == K_OPTIONS - 1
    dec.options.append(replace(dec.options[0], angle=np.pi / 2, direction=0.02))
    assert RoutePlanner(env).act(obs, info) == 1


def test_goal_greedy_and_left_hand_choose_sensibly() -> None:
    from agents import LeftHand

    for direction, goal in ((0.0, [0, 0.5, 0]), (np.pi, [0, -0.5, 0])):
        net = layouts.cross_junction(0.1, direction=0.0).with_goals([goal])
        env = gym.make("pipenav/PipeNav-v0", network=net, detector="ground_truth")
        obs, info = env.reset(seed=0)
        options = env.unwrapped.decision.options
        chosen = options[GoalGreedy(env).act(obs, info)]
        assert abs(np.cos(chosen.direction - direction)) > 0.99 and chosen.angle > 1.5
        left = options[LeftHand(env).act(obs, info)]
        assert abs(left.direction) < 0.01 and left.angle > 1.5  # the left branch first


def test_taken_feature_remembers_ways_at_a_junction() -> None:
    net = layouts.t_junction(0.1, direction=0.0).with_goals([[0, 0.5, 0]])
    env = gym.make("pipenav/PipeNav-v0", network=net, detector="ground_truth")
    obs, info = env.reset(seed=3)
    taken = OPTION_FEATURES.index("taken")
    assert not obs["options"][:, taken].any()
    obs, *_ = env.step(0)  # straight on: a dead end
    obs, *_ = env.step(K_OPTIONS - 1)  # back out to the tee, which is sensed again
    straight = next(i for i, o in enumerate(env.unwrapped.decision.options) if o.angle < 0.2)
    branch = next(i for i, o in enumerate(env.unwrapped.decision.options) if o.angle > 1.0)
    assert obs["options"][straight, taken] == pytest.approx(1 / 3)
    assert obs["options"][branch, taken] == 0.0


def test_explore_is_deterministic_across_processes() -> None:
    import subprocess
    import sys

    code = (
        "import gymnasium as gym, pipe_env, hashlib;"
        "from agents import LeftHand;"
        "env = gym.make('pipenav/PipeExplore-v0', network_config={'n_fittings': 8});"
        "a = LeftHand(env); obs, info = env.reset(seed=9); h = [];"
        "done = False\n"
        "while not done:\n"
        "    obs, r, t, tr, info = env.step(a.act(obs, info))\n"
        "    h.append(repr((r, info['coverage']))); done = t or tr\n"
        "print(hashlib.sha1(''.join(h).encode()).hexdigest())"
    )
    out = set()
    for hash_seed in ("1", "2", "3"):
        proc = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            env={**__import__("os").environ, "PYTHONHASHSEED": hash_seed},
            timeout=120,
        )
        assert proc.returncode == 0, proc.stderr
        out.add(proc.stdout.strip())
    assert len(out) == 1


def test_an_automatic_way_that_jams_is_sensed_again(monkeypatch: pytest.MonkeyPatch) -> None:
    """The environment took a single way by itself and it jammed: the robot backed off and
    the agent decides on fresh sweeps (the estimate that jammed is not offered again, where
    the fast fidelity would jam on it once more)."""
    from pipe_env.envs.plant import KinematicPlant

    resensed = []
    original = KinematicPlant.resense

    def counting(self: KinematicPlant):  # noqa: ANN202
        resensed.append(self.decision)
        return original(self)

    monkeypatch.setattr(KinematicPlant, "resense", counting)
    env = gym.make("pipenav/PipeNav-v0", detector="improved", lidar="ydlidar_x4")
    # (the first seed whose first single way jams: which one depends on the error models)
    for seed in range(100):
        resensed.clear()
        obs, info = env.reset(seed=seed)
        if info.get("auto_jammed"):
            break
    assert info.get("auto_jammed"), "no seed in 0-99 jams on its first single way"
    assert len(resensed) == 1
    offered = env.unwrapped.decision
    assert offered is not resensed[0] and offered.options


def test_full_fidelity_run_is_unchanged_by_rendering() -> None:
    """Observing or rendering reads the clamp encoders without drawing from the plant's
    random generator: the physical run stays the same."""
    net = layouts.t_junction(0.1, direction=0.0, distance=0.4).with_goals([[0, 0.5, 0]])
    runs = []
    for renders in (0, 3):
        env = gym.make(
            "pipenav/PipeNav-v0",
            network=net,
            fidelity="full",
            detector="improved",
            render_mode="ansi",
        )
        obs, info = env.reset(seed=0)
        for _ in range(renders):
            env.render()
        obs, reward, term, trunc, info = env.step(0)
        runs.append((obs["proprio"].tobytes(), obs["goal"].tobytes(), reward, info["travelled"]))
    assert runs[0] == runs[1]


def test_explore_env_runs_in_full_fidelity() -> None:
    """The physical plant's path is sensor positions: coverage maps them onto the network."""
    net = layouts.t_junction(0.1, direction=0.0, distance=0.3)
    env = gym.make("pipenav/PipeExplore-v0", network=net, fidelity="full", detector="ground_truth")
    obs, info = env.reset(seed=0)
    assert 0.0 < info["coverage"] < 1.0
    covered = info["covered"]
    obs, reward, term, trunc, info = env.step(int(np.flatnonzero(info["action_mask"])[0]))
    assert info["covered"] > covered and info["reward_terms"]["coverage"] > 0.0
