"""Agent comparison on held-out networks, environment throughput, and the cost of detection.

1. Per agent on ``--episodes`` held-out networks (fast fidelity, improved detector's measured
   error model): success rate, jams and decisions per episode, path length over the shortest
   drivable route. Agents: RoutePlanner, GoalGreedy, LeftHand, Random, and the learned
   MaskablePPO policy (``--model``, or trained here first for ``--train-minutes``; its training
   wall time is reported).
2. Throughput in decisions/s on one core, random valid actions, resets included: fast fidelity
   on a pool of 50 networks (how RL training runs: a network is generated once, then reused)
   and on a fresh network every episode (generation included); full fidelity (MuJoCo robot,
   rotating LiDAR, detector) on ``--full-episodes`` episodes of 6-fitting networks, with physics
   where contact decides (``physics="contact"``, the default) and the all-physics reference
   (``physics="everywhere"``) on the same networks.
3. RoutePlanner in full fidelity with ``detector="improved"`` against ``"ground_truth"``: the
   success gap is what detection errors cost.

The reference measured in the same run is the fast environment's throughput, so full-fidelity
speed is also printed as a ratio to it.

Usage: python benchmarks/bench_agents.py [--episodes 200] [--model runs/ppo/best/best_model.zip]
       [--train-minutes 28] [--full-episodes 20] [--parts agents,throughput,full] [--json F]
       [--write-docs]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import sys
import time
from pathlib import Path
from typing import TextIO

# Runnable as a script from anywhere: the repository root holds the benchmarks package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym
import numpy as np
import torch

import pipe_env  # noqa: F401
from agents.evaluate import EVAL_POOL_SEED, evaluate, random_valid_episode
from agents.train import DEFAULT_CONFIG, TrainConfig, train
from detector.atomic import atomic_write_text
from pipe_env.envs import pool_network

torch.set_num_threads(1)


def throughput(fidelity: str, episodes: int, env_kwargs: dict, seed: int = 0) -> dict:
    """Decisions per second with random valid actions, resets included. A network pool is
    generated before the clock starts (training reuses it for millions of decisions)."""
    env = gym.make("pipenav/PipeNav-v0", **{**env_kwargs, "fidelity": fidelity})
    pool = env_kwargs.get("network_pool")
    if pool:
        base = env.unwrapped
        for i in range(pool):
            pool_network(base.network_config, base.pool_seed, i)
    rng = np.random.default_rng(seed)
    steps = 0
    sim = 0.0
    t0 = time.perf_counter()
    for ep in range(episodes):
        n, t = random_valid_episode(env, rng, seed + ep)
        steps += n
        sim += t
    wall = time.perf_counter() - t0
    env.close()
    return {
        "decisions": steps,
        "wall_s": round(wall, 2),
        "decisions_per_s": round(steps / wall, 3),
        "sim_s_per_wall_s": round(sim / wall, 1),
    }


def compare_agents(args: argparse.Namespace, env_kwargs: dict, report: dict) -> None:
    """Part 1: every agent on the held-out networks; trains the policy first without --model."""
    model = args.model
    if model is None:
        cfg = TrainConfig.from_yaml(DEFAULT_CONFIG)
        cfg.max_minutes = args.train_minutes
        summary = train(cfg, args.train_out, progress_bar=False)
        report["training"] = summary
        model = (
            summary["best_model"]
            if Path(summary["best_model"]).exists()
            else summary["final_model"]
        )
        print(
            f"trained MaskablePPO: {summary['timesteps']} decisions in "
            f"{summary['wall_seconds'] / 60:.1f} min -> {model}",
            flush=True,
        )
    rows = {}
    for agent in ("route_planner", "goal_greedy", "left_hand", "random", model):
        r = evaluate(agent, args.episodes, env_kwargs=env_kwargs)
        name = "maskable_ppo" if agent == model else agent
        rows[name] = r.to_dict()
        print(f"evaluated {name}: success {r.success_rate:.3f}", flush=True)
    report["agents"] = rows
    print(
        f"\n## Agents on {args.episodes} held-out networks (fast fidelity, "
        f"detector={env_kwargs.get('detector')})\n"
    )
    print("| agent | success | jams/episode | decisions/episode | path / shortest (median) |")
    print("|---|---|---|---|---|")
    for name, r in rows.items():
        print(
            f"| {name} | {r['success_rate']:.3f} | {r['jams_per_episode']:.2f} | "
            f"{r['decisions_per_episode']:.1f} | {r['path_over_shortest']:.2f} |"
        )
    ppo, greedy, planner = rows["maskable_ppo"], rows["goal_greedy"], rows["route_planner"]
    beats = ppo["success_rate"] >= greedy["success_rate"]
    print(
        f"\nlearned vs GoalGreedy success: {ppo['success_rate']:.3f} vs "
        f"{greedy['success_rate']:.3f} -> {'met' if beats else 'NOT met'}"
    )
    ratio = ppo["success_rate"] / planner["success_rate"] if planner["success_rate"] else math.nan
    print(
        f"learned / RoutePlanner success: {ratio:.3f} (target >= 0.90) -> "
        f"{'met' if ratio >= 0.9 else 'NOT met'}"
    )
    if "training" in report:
        print(
            f"training wall time: {report['training']['wall_seconds'] / 60:.1f} min "
            f"(target <= 30), {report['training']['timesteps']} decisions"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--model", default=None, help="a trained MaskablePPO .zip")
    parser.add_argument("--train-minutes", type=float, default=28.0)
    parser.add_argument("--train-out", default="runs/bench_ppo")
    parser.add_argument("--full-episodes", type=int, default=20)
    parser.add_argument(
        "--parts",
        default="agents,throughput,full",
        help="comma-separated subset of: agents (part 1), throughput (part 2, fast), "
        "full (part 2 full fidelity and part 3)",
    )
    parser.add_argument("--json", default=None)
    parser.add_argument(
        "--write-docs", action="store_true", help="write the tables into docs/benchmarks.md"
    )
    args = parser.parse_args()
    unknown = {p.strip() for p in args.parts.split(",") if p.strip()} - {
        "agents",
        "throughput",
        "full",
    }
    if unknown:
        parser.error(f"--parts has {sorted(unknown)}; allowed: agents, throughput, full")
    if args.write_docs:
        tee = _Tee(sys.stdout)
        with contextlib.redirect_stdout(tee):
            run(args)
        from benchmarks.report import write_section

        command = "python benchmarks/bench_agents.py " + " ".join(sys.argv[1:])
        write_section("agents", f"`{command.replace(' --write-docs', '')}`\n\n" + tee.markdown())
    else:
        run(args)


class _Tee(io.StringIO):
    """Writes through to ``out`` and keeps the text (progress lines dropped) for the docs."""

    def __init__(self, out: TextIO) -> None:
        super().__init__()
        self.out = out

    def write(self, text: str) -> int:
        self.out.write(text)
        return super().write(text)

    def flush(self) -> None:
        self.out.flush()

    def markdown(self) -> str:
        lines = self.getvalue().splitlines()
        keep = [ln for ln in lines if not ln.startswith(("evaluated ", "trained MaskablePPO"))]
        return "\n".join(keep).strip() + "\n"


def run(args: argparse.Namespace) -> None:
    """Every part asked for in ``args.parts``."""
    parts = {p.strip() for p in args.parts.split(",") if p.strip()}
    cfg = TrainConfig.from_yaml(DEFAULT_CONFIG)
    env_kwargs = {k: v for k, v in cfg.env_kwargs.items() if k not in ("network_pool", "pool_seed")}
    report: dict = {"episodes": args.episodes, "eval_pool_seed": EVAL_POOL_SEED, "env": env_kwargs}
    if "agents" in parts:
        compare_agents(args, env_kwargs, report)
    fast_rate = None
    print("\n## Throughput (one core, random valid actions, resets included)\n")
    print("| fidelity | networks | decisions | wall s | decisions/s | sim s / wall s | vs fast |")
    print("|---|---|---|---|---|---|---|")
    report["throughput"] = {}
    if "throughput" in parts:
        fast = throughput("fast", 200, {**env_kwargs, "network_pool": 50})
        fresh = throughput("fast", 100, {**env_kwargs, "network_pool": None})
        report["throughput"].update(fast=fast, fast_fresh_networks=fresh)
        fast_rate = fast["decisions_per_s"]
        for label, r in (("pool of 50", fast), ("fresh each episode", fresh)):
            print(
                f"| fast | {label} | {r['decisions']} | {r['wall_s']} | {r['decisions_per_s']} | "
                f"{r['sim_s_per_wall_s']} | {r['decisions_per_s'] / fast_rate:.2f} |"
            )
    if "full" in parts:
        full_kwargs = {
            **env_kwargs,
            "network_config": {"n_fittings": 6, "planar": False, "allow_loops": True},
        }
        # physics where contact decides (the default) and the all-physics reference, same
        # networks and seeds, one run
        for physics in ("contact", "everywhere"):
            full = throughput("full", args.full_episodes, {**full_kwargs, "physics": physics})
            report["throughput"]["full" if physics == "contact" else "full_" + physics] = full
            ratio = f"{full['decisions_per_s'] / fast_rate:.4f}" if fast_rate else "-"
            print(
                f"| full (physics={physics}) | fresh each episode | {full['decisions']} | "
                f"{full['wall_s']} | {full['decisions_per_s']} | {full['sim_s_per_wall_s']} | "
                f"{ratio} |",
                flush=True,
            )
        c = report["throughput"]["full"]["decisions_per_s"]
        e = report["throughput"]["full_everywhere"]["decisions_per_s"]
        print(
            f"\nfull fidelity: physics where contact decides {c} decisions/s, all-physics "
            f"reference {e} decisions/s, ratio {c / e:.2f} (target >= 10 decisions/s: "
            f"{'met' if c >= 10 else 'NOT met'}; equivalence: benchmarks/bench_full_fidelity.py)"
        )
        print(f"\n## RoutePlanner in full fidelity, {args.full_episodes} held-out networks\n")
        print("| detector | success | jams/episode | decisions/episode | wall s | decisions/s |")
        print("|---|---|---|---|---|---|")
        gap = {}
        for det in ("ground_truth", "improved"):
            t0 = time.perf_counter()
            r = evaluate(
                "route_planner",
                args.full_episodes,
                env_kwargs={**full_kwargs, "fidelity": "full", "detector": det},
            )
            wall = time.perf_counter() - t0
            gap[det] = {**r.to_dict(), "wall_s": round(wall, 1)}
            rate = r.decisions_per_episode * r.episodes / wall
            print(
                f"| {det} | {r.success_rate:.3f} | {r.jams_per_episode:.2f} | "
                f"{r.decisions_per_episode:.1f} | {wall:.1f} | {rate:.3f} |",
                flush=True,
            )
        report["detection_cost"] = gap
        print(
            f"\nsuccess lost to detection errors: "
            f"{gap['ground_truth']['success_rate'] - gap['improved']['success_rate']:+.3f}"
        )
    if args.json:
        atomic_write_text(args.json, json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
