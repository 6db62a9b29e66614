"""Where full-fidelity wall time goes, per decision, and what a MuJoCo step is made of.

Runs the full-fidelity environment (MuJoCo robot, rotating LiDAR, improved detector) on seeded
6-fitting networks with random valid actions (as ``bench_agents.py`` measures throughput),
resets included, and splits the wall time into:

- physics: the executor's control ticks of MuJoCo steps (``Executor._physics``), with the
  pair selection of :class:`pipe_env.world.NearContacts`;
- sweeps: the rotating LiDAR's ray casting (``RotatingLidar.scan``);
- detection: ``detector.detect`` (including the axis fit the plant runs for steering);
- fusion: ``StructureTracker.update``;
- world build: compiling the MuJoCo world of each episode's network (``build_world``);
- other: everything else (control-tick Python, telemetry, ground truth, the environment).

MuJoCo's own timers (``data.timer``, ``mjtTimer``) split the steps into collision (broad and
narrow phase), kinematics, constraint solving and the rest. They need a time callback, which
adds a little to every step: the figures are ratios within the same run.

``--contacts near,all`` runs the same episodes twice: with the robot colliding only with the
wall pieces near it (the default) and with MuJoCo's automatic collisions against all of them
(the reference), and prints both. ``--walls once,every`` does the same for the static wall
geoms: posed once (the default, MuJoCo's sleeping with the robot kept awake) or at every step
(the reference). Two runs print their ratio.

Usage: python benchmarks/bench_physics.py [--episodes 3] [--seed 0] [--contacts near,all]
[--walls once,every]
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

import pipe_env  # noqa: F401
import pipe_env.envs.plant_full as plant_full
import pipe_env.world as world_mod
import primitives.executor as executor_mod
from agents.evaluate import random_valid_episode
from agents.train import DEFAULT_CONFIG, TrainConfig
from detector.atomic import atomic_write_text
from detector.fusion import StructureTracker
from pipe_env.lidar import RotatingLidar
from primitives.executor import Executor

NETWORK = {"n_fittings": 6, "planar": False, "allow_loops": True}
PARTS = ("physics", "sweeps", "detection", "fusion", "world build")
TIMERS = {
    "collision: broad phase": mujoco.mjtTimer.mjTIMER_COL_BROAD,
    "collision: narrow and mid phase": mujoco.mjtTimer.mjTIMER_COL_NARROW,
    "kinematics": mujoco.mjtTimer.mjTIMER_POS_KINEMATICS,
    "inertia": mujoco.mjtTimer.mjTIMER_POS_INERTIA,
    "constraint making": mujoco.mjtTimer.mjTIMER_POS_MAKE,
    "velocity": mujoco.mjtTimer.mjTIMER_VELOCITY,
    "constraint solving": mujoco.mjtTimer.mjTIMER_CONSTRAINT,
    "integration": mujoco.mjtTimer.mjTIMER_ADVANCE,
}


class _Clock:
    """Wall time spent inside wrapped functions, outermost calls only."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._depth = 0
        self._undo: list[tuple[Any, str, Any]] = []

    def wrap(self, owner: Any, name: str, part: str) -> None:
        original = getattr(owner, name)

        def timed(*args: Any, **kwargs: Any) -> Any:
            if self._depth:
                return original(*args, **kwargs)
            self._depth += 1
            t0 = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                self.seconds[part] += time.perf_counter() - t0
                self.calls[part] += 1
                self._depth -= 1

        self._undo.append((owner, name, original))
        setattr(owner, name, timed)

    def restore(self) -> None:
        for owner, name, original in reversed(self._undo):
            setattr(owner, name, original)
        self._undo.clear()


def run(contacts: str, episodes: int, seed: int, walls: str = "once") -> dict[str, Any]:
    """Episodes of random valid actions on fresh seeded networks; the time split."""
    clock = _Clock()
    clock.wrap(Executor, "_physics", "physics")
    clock.wrap(RotatingLidar, "scan", "sweeps")
    clock.wrap(plant_full.detection, "detect", "detection")
    clock.wrap(StructureTracker, "update", "fusion")
    clock.wrap(executor_mod, "build_world", "world build")
    timers: dict[str, float] = defaultdict(float)
    steps = [0]
    made: list[Executor] = []
    original_for_network: Callable[..., Executor] = Executor.for_network.__func__  # type: ignore[attr-defined]

    def for_network(cls: type[Executor], *args: Any, **kwargs: Any) -> Executor:
        ex = original_for_network(cls, *args, **kwargs)
        if contacts == "all":
            ex.use_near_contacts(False)
        if walls == "every":
            ex.model.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        made.append(ex)
        return ex

    def harvest() -> None:
        for ex in made:
            d = ex.data
            for label, k in TIMERS.items():
                timers[label] += d.timer[k].duration
            timers["step"] += d.timer[mujoco.mjtTimer.mjTIMER_STEP].duration
            steps[0] += d.timer[mujoco.mjtTimer.mjTIMER_STEP].number
            ex.data.timer[mujoco.mjtTimer.mjTIMER_STEP].number = 0
        made.clear()

    Executor.for_network = classmethod(for_network)  # type: ignore[method-assign,assignment]
    mujoco.set_mjcb_time(time.perf_counter)
    cfg = TrainConfig.from_yaml(DEFAULT_CONFIG)
    env_kwargs = {k: v for k, v in cfg.env_kwargs.items() if k not in ("network_pool", "pool_seed")}
    env_kwargs.update(fidelity="full", detector="improved", network_config=NETWORK)
    env = gym.make("pipenav/PipeNav-v0", **env_kwargs)
    rng = np.random.default_rng(seed)
    decisions = 0
    sim = 0.0
    near_stats = defaultdict(int)
    t0 = time.perf_counter()
    try:
        for ep in range(episodes):
            n, t = random_valid_episode(env, rng, seed + ep)
            decisions += n
            sim += t
            for ex in made:
                if ex.near is not None:
                    for key in ("selections", "fallbacks", "overruns"):
                        near_stats[key] += getattr(ex.near, key)
            harvest()
    finally:
        wall = time.perf_counter() - t0
        mujoco.set_mjcb_time(None)
        Executor.for_network = classmethod(original_for_network)  # type: ignore[method-assign,assignment]
        clock.restore()
        env.close()
    split = {p: clock.seconds[p] for p in PARTS}
    split["other"] = wall - sum(split.values())
    step_s = timers.pop("step", 0.0)
    mj = {k: v / step_s for k, v in timers.items()} if step_s else {}
    if mj:
        mj["rest of the step"] = 1.0 - sum(mj.values())
    return {
        "contacts": contacts,
        "walls": walls,
        "episodes": episodes,
        "decisions": decisions,
        "wall_s": round(wall, 2),
        "decisions_per_s": round(decisions / wall, 3),
        "sim_s_per_wall_s": round(sim / wall, 2),
        "mj_steps": steps[0],
        "us_per_mj_step": round(1e6 * step_s / steps[0], 1) if steps[0] else None,
        "split_s": {k: round(v, 2) for k, v in split.items()},
        "split_s_per_decision": {k: round(v / max(decisions, 1), 3) for k, v in split.items()},
        "mj_step_split": {k: round(v, 3) for k, v in mj.items()},
        "calls": dict(clock.calls),
        "near_contacts": dict(near_stats),
        "pair_pool": world_mod.CONTACT_PAIR_POOL,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--contacts", default="near", help="comma-separated: near, all")
    parser.add_argument("--walls", default="once", help="comma-separated: once, every")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    choices = {"contacts": ("near", "all"), "walls": ("once", "every")}
    picked = {}
    for name, allowed in choices.items():
        picked[name] = [c.strip() for c in getattr(args, name).split(",") if c.strip()]
        bad = set(picked[name]) - set(allowed)
        if bad or not picked[name]:
            parser.error(f"--{name} has {sorted(bad)}; allowed: {', '.join(allowed)}")
    results = [
        run(contacts, args.episodes, args.seed, walls)
        for contacts in picked["contacts"]
        for walls in picked["walls"]
    ]
    for r in results:
        print(
            f"\n## contacts={r['contacts']}, walls={r['walls']}: {r['episodes']} episodes, "
            f"seed {args.seed}\n"
        )
        print(
            f"{r['decisions']} decisions in {r['wall_s']} s: {r['decisions_per_s']} decisions/s, "
            f"{r['sim_s_per_wall_s']} sim s per wall s; {r['mj_steps']} MuJoCo steps, "
            f"{r['us_per_mj_step']} us each (timers on)"
        )
        wall = r["wall_s"]
        print("\n| part | s per decision | share of wall time |")
        print("|---|---|---|")
        for part, s in r["split_s"].items():
            print(f"| {part} | {r['split_s_per_decision'][part]} | {s / wall:.3f} |")
        print("\n| MuJoCo step part | share of step time |")
        print("|---|---|")
        for part, share in r["mj_step_split"].items():
            print(f"| {part} | {share:.3f} |")
        if r["near_contacts"]:
            print(f"\nnear-contact pair selections etc.: {r['near_contacts']}")
    if len(results) == 2:
        a, b = results
        label = "contacts" if a["contacts"] != b["contacts"] else "walls"
        print(
            f"\n{label} {a[label]} / {b[label]}: decisions/s x"
            f"{a['decisions_per_s'] / b['decisions_per_s']:.2f}, MuJoCo step time x"
            f"{b['us_per_mj_step'] / a['us_per_mj_step']:.2f} faster"
        )
    if args.json:
        atomic_write_text(args.json, json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
