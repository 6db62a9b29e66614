"""Scripted agents that choose among the options a pipenav environment offers.

All are built with the environment they act in and choose with ``act(observation, info)``,
returning an action index (the options table row; the last row backs out).

- :class:`RoutePlanner`: the ideal operator. It knows the plant drawing and its true pose
  (through the environment's oracle, :mod:`pipe_env.envs.oracle`), plans the shortest drivable
  route to the goal and picks the detected option closest to the route's next pipe.
- :class:`GoalGreedy`: picks the option whose outgoing direction best matches the goal vector
  (from odometry), trying other ways at a junction it has come back to.
- :class:`LeftHand`: the wall follower for exploration: leftmost way first, the next one to
  the right on each return, back out at dead ends.
- :class:`RandomAgent`: a uniformly random valid action.

GoalGreedy and LeftHand remember nothing themselves: they read the ``taken`` column of the
options table, the robot's own odometry log of the ways it already took from here
(:mod:`pipe_env.envs.way_log`), and prefer ways not taken yet.
"""

from __future__ import annotations

import math
from typing import Any, cast

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from detector.options import option_vector
from pipe_env.envs.actions import BACK_ROW
from pipe_env.envs.observations import ANGLE, COS_DIR, SIN_DIR, TAKEN
from pipe_env.envs.oracle import oracle_of
from pipe_env.envs.plant import ExecutionTolerance
from pipe_env.robot_limits import ROBOT_DIAMETER_RANGE
from pipe_env.routing import route

BACK = BACK_ROW
#: A detected way counts as the planned one within this angle (the executor's match limit).
MATCH_ANGLE = ExecutionTolerance().match


def _mask(info: dict[str, Any], env: gym.Env) -> NDArray[np.bool_]:
    m = info.get("action_mask")
    if m is None:
        m = cast(Any, env.unwrapped).action_masks()
    return np.asarray(m, dtype=bool)


def _option_vectors(observation: dict[str, NDArray]) -> NDArray[np.float64]:
    """Outgoing axes (K, 3) in the robot frame from the options table."""
    t = np.asarray(observation["options"], dtype=float)
    angle, c, s = t[:, ANGLE], t[:, COS_DIR], t[:, SIN_DIR]
    return np.stack([np.cos(angle), np.sin(angle) * c, np.sin(angle) * s], axis=1)


class _Agent:
    def __init__(self, env: gym.Env) -> None:
        self.env = env

    def reset(self) -> None:
        """Forget per-episode memory (call at each episode start)."""

    def act(self, observation: dict[str, NDArray], info: dict[str, Any]) -> int:
        raise NotImplementedError


class RandomAgent(_Agent):
    """A uniformly random valid action, from its own seeded generator."""

    def __init__(self, env: gym.Env, seed: int = 0) -> None:
        super().__init__(env)
        self.rng = np.random.default_rng(seed)

    def act(self, observation: dict[str, NDArray], info: dict[str, Any]) -> int:
        valid = np.flatnonzero(_mask(info, self.env))
        return int(self.rng.choice(valid))


class RoutePlanner(_Agent):
    """The ideal operator: shortest drivable route on the plant drawing from the true pose."""

    def act(self, observation: dict[str, NDArray], info: dict[str, Any]) -> int:
        oracle = oracle_of(self.env)
        mask = _mask(info, self.env)
        dec = oracle.decision
        if dec is None or not mask[:BACK].any():
            return BACK
        network = oracle.network
        goal = network.goals[0] if network.goals else None
        if goal is None:
            return int(np.flatnonzero(mask)[0])
        planned = route(network, oracle.true_pose(), goal, diameter_range=ROBOT_DIAMETER_RANGE)
        if planned is None or not planned.nodes or planned.nodes[0] != dec.node_id:
            return BACK
        run_out = planned.runs[1]
        want = network.geometry[dec.node_id].port(run_out).axis
        best, best_sep = BACK, math.inf
        for i, o in enumerate(dec.options[:BACK]):
            if not mask[i]:
                continue
            v = dec.pose.rotation @ option_vector(o)
            sep = math.acos(max(-1.0, min(1.0, float(v @ want))))
            if sep < best_sep:
                best, best_sep = i, sep
        # no detected way near the planned one: back off and let the robot sense again
        return best if best_sep <= MATCH_ANGLE else BACK


def _prefer_untaken(ranked: list[int], observation: dict[str, NDArray]) -> int:
    """The first ranked row the robot has not taken from here yet; else the least taken one,
    unless backing out was taken less."""
    taken = np.asarray(observation["options"], dtype=float)[:, TAKEN]
    for i in ranked:
        if taken[i] == 0.0:
            return i
    least = min(ranked, key=lambda i: taken[i])
    return least if taken[least] < taken[BACK] else BACK


class GoalGreedy(_Agent):
    """The option pointing most towards the goal (robot frame, from odometry), preferring ways
    not taken from here before."""

    def act(self, observation: dict[str, NDArray], info: dict[str, Any]) -> int:
        mask = _mask(info, self.env)
        valid = [i for i in range(BACK) if mask[i]]
        if not valid:
            return BACK
        goal = np.asarray(observation["goal"], dtype=float)
        norm = float(np.linalg.norm(goal))
        vecs = _option_vectors(observation)
        if norm < 1e-9:
            return valid[0]
        score = vecs[valid] @ (goal / norm)
        ranked = [valid[i] for i in np.argsort(-score, kind="stable")]
        return _prefer_untaken(ranked, observation)


class LeftHand(_Agent):
    """Wall follower: the leftmost way not taken from here yet, then the next to the right."""

    def act(self, observation: dict[str, NDArray], info: dict[str, Any]) -> int:
        mask = _mask(info, self.env)
        valid = [i for i in range(BACK) if mask[i]]
        if not valid:
            return BACK
        vecs = _option_vectors(observation)
        yaw_left = np.arctan2(vecs[valid, 1], vecs[valid, 0])  # + to the left
        ranked = [valid[i] for i in np.argsort(-yaw_left, kind="stable")]
        return _prefer_untaken(ranked, observation)


SCRIPTED_AGENTS = {
    "route_planner": RoutePlanner,
    "goal_greedy": GoalGreedy,
    "left_hand": LeftHand,
    "random": RandomAgent,
}


def make_agent(name: str, env: gym.Env, **kwargs: Any) -> _Agent:
    """A scripted agent by name (see ``SCRIPTED_AGENTS``)."""
    if name not in SCRIPTED_AGENTS:
        raise ValueError(f"agent {name!r} is unknown; allowed: {sorted(SCRIPTED_AGENTS)}")
    return SCRIPTED_AGENTS[name](env, **kwargs)
