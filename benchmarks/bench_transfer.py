"""Policies judged in the physical loop: the fast-to-full transfer table.

Runs each agent (default: RoutePlanner, GoalGreedy and the shipped MaskablePPO policy
``agents/maskable_ppo_policy.zip``) on the same held-out networks (``pool_network(config,
EVAL_POOL_SEED, i)``, ``i`` from ``--first`` for ``--networks``), episode ``i`` with seed
``EVAL_POOL_SEED + i`` in both fidelities: ``fast`` (kinematic plant, modelled sensing) and
``full`` (the MuJoCo robot in closed loop, the rotating LiDAR, the ``improved`` detector). The
episodes are those of ``pipenav eval`` (:func:`agents.evaluate.run_held_out_episode`, the unit of
:func:`agents.evaluate.evaluate`; same env arguments: the packaged training config's, with its
decision budget, and the network config below). Prints, per agent:

- per fidelity: success rate with its 95 % Wilson interval, jams and decisions per episode;
- the transfer gap: fast minus full success, in percentage points, with McNemar's exact test
  (two-sided) on the paired per-network outcomes;
- the learned policy's success as a fraction of RoutePlanner's in each fidelity and their gap
  in points (target: fraction >= 0.98, gap <= 3 points), McNemar's exact test on the pairs;
- the wall time per full-fidelity episode.

Network config: ``--network-config JSON``; default the 6-fitting 3D networks with loops of
``benchmarks/bench_full_fidelity.py`` (the shipped policy was trained on 20-fitting ones: this
default is off its training distribution; the output says which config was used).

Cost (one core, unloaded): a full-fidelity episode on the 6-fitting default takes ~8.5 s, on the
20-fitting training distribution ~35 s; fast-fidelity episodes take well under a second. So
``--networks 24`` with three agents is ~10-15 min on one core; the 200 networks of a tight
estimate are ~1.5 h (6-fitting) or ~6 h (20-fitting) per core.

Every finished episode is written to ``--json`` at once (atomically), so an interrupted run
keeps what it did; ``--merge A.json B.json`` adds earlier runs' episodes (same network config)
and ``--first K`` starts at network K, so a run extends an earlier one:
``--first 24 --networks 16 --merge run1.json --json run2.json``. The table counts only networks
on which every agent finished both fidelities.

Usage: python benchmarks/bench_transfer.py [--networks 24] [--first 0] [--jobs 1]
       [--agents route_planner,goal_greedy,agents/maskable_ppo_policy.zip]
       [--network-config JSON] [--merge FILE ...] [--json out.json] [--write-docs]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from scipy import stats

# Runnable as a script from anywhere: the repository root holds the benchmarks package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.workers import run_plan  # noqa: E402
from detector.atomic import atomic_write_text

FIDELITIES = ("fast", "full")
DETECTOR = "improved"
#: The default networks: those of benchmarks/bench_full_fidelity.py.
NETWORK_CONFIG: dict[str, Any] = {"n_fittings": 6, "planar": False, "allow_loops": True}
DEFAULT_NOTE = ", 6-fitting 3D with loops; the policy was trained on 20-fitting networks"
POLICY = "agents/maskable_ppo_policy.zip"
DEFAULT_AGENTS = ("route_planner", "goal_greedy", POLICY)
REFERENCE = "route_planner"
#: The learned policy's targets against RoutePlanner (success fraction, gap in points).
TARGET_FRACTION = 0.98
TARGET_GAP_POINTS = 3.0
Z95 = 1.959963984540054


# ------------------------------------------------------------------------- statistics
def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial rate ``successes / n`` (``z``: the normal quantile,
    1.96 for 95 %); ``(nan, nan)`` for ``n == 0``."""
    if n == 0:
        return (math.nan, math.nan)
    if not 0 <= successes <= n:
        raise ValueError(f"wilson_interval: successes = {successes}; allowed: 0..{n}")
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    low = 0.0 if successes == 0 else max(0.0, centre - half)  # exact at the ends
    high = 1.0 if successes == n else min(1.0, centre + half)
    return (low, high)


def mcnemar_exact(a: Sequence[bool], b: Sequence[bool]) -> tuple[int, int, float]:
    """McNemar's exact test of paired outcomes: (pairs where only ``a`` succeeded, pairs where
    only ``b`` did, the two-sided p-value); p = 1 with no discordant pair."""
    if len(a) != len(b):
        raise ValueError(f"mcnemar_exact: len(a) = {len(a)}, len(b) = {len(b)}; allowed: equal")
    only_a = sum(1 for x, y in zip(a, b) if x and not y)
    only_b = sum(1 for x, y in zip(a, b) if y and not x)
    if only_a + only_b == 0:
        return only_a, only_b, 1.0
    return only_a, only_b, float(stats.binomtest(only_a, only_a + only_b, 0.5).pvalue)


def paired_difference_interval(
    a: Sequence[bool], b: Sequence[bool], z: float = Z95
) -> tuple[float, float]:
    """Interval of the difference of paired success rates ``mean(a) - mean(b)``: Newcombe's
    hybrid score interval for paired proportions (Newcombe 1998, method 10: the marginal
    rates' Wilson intervals combined with the pairs' correlation), which keeps its width with no
    discordant pair (the Wald interval then collapses to a point); ``(nan, nan)`` if empty."""
    if len(a) != len(b):
        raise ValueError(
            f"paired_difference_interval: len(a) = {len(a)}, len(b) = {len(b)}; allowed: equal"
        )
    n = len(a)
    if n == 0:
        return (math.nan, math.nan)
    both = sum(1 for x, y in zip(a, b) if x and y)
    only_a = sum(1 for x, y in zip(a, b) if x and not y)
    only_b = sum(1 for x, y in zip(a, b) if y and not x)
    neither = n - both - only_a - only_b
    p1, p2 = (both + only_a) / n, (both + only_b) / n
    l1, u1 = wilson_interval(both + only_a, n, z)
    l2, u2 = wilson_interval(both + only_b, n, z)
    denom = math.sqrt((both + only_a) * (only_b + neither) * (both + only_b) * (only_a + neither))
    cross = both * neither - only_a * only_b
    # the pairs' correlation, shrunk towards 0 by n/2 when positive (as in Altman et al.,
    # Statistics with Confidence, 2000, section 6)
    shrunk = max(cross - n / 2, 0.0) if cross > 0 else cross
    phi = 0.0 if denom == 0 else shrunk / denom
    delta = math.sqrt(max((p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2, 0))
    eps = math.sqrt(max((u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2, 0))
    return (p1 - p2 - delta, p1 - p2 + eps)


def _mean(values: Iterable[float]) -> float:
    vals = list(values)
    return sum(vals) / len(vals) if vals else math.nan


def _median(values: list[float]) -> float:
    vals = sorted(values)
    n = len(vals)
    if n == 0:
        return math.nan
    return vals[n // 2] if n % 2 else 0.5 * (vals[n // 2 - 1] + vals[n // 2])


# ------------------------------------------------------------------------- episodes
def env_kwargs(fidelity: str, network_config: dict[str, Any]) -> dict[str, Any]:
    """The env arguments of ``pipenav eval --fidelity FIDELITY --network-config CONFIG``: the
    packaged training config's, with this fidelity, detector and network config."""
    from agents.train import DEFAULT_CONFIG, TrainConfig

    kwargs: dict[str, Any] = dict(TrainConfig.from_yaml(DEFAULT_CONFIG).env_kwargs)
    kwargs.update(fidelity=fidelity, detector=DETECTOR, network_config=dict(network_config))
    return kwargs


def run_episode(
    agent: str, fidelity: str, index: int, network_config: dict[str, Any]
) -> dict[str, Any]:
    """Held-out episode ``index`` of ``agent`` in ``fidelity``; its outcome as plain data."""
    from agents.evaluate import EVAL_POOL_SEED, run_held_out_episode

    t0 = time.perf_counter()
    info = run_held_out_episode(
        agent, index, env_kwargs=env_kwargs(fidelity, network_config), pool_seed=EVAL_POOL_SEED
    )
    return {
        "agent": agent,
        "fidelity": fidelity,
        "network": index,
        "seed": EVAL_POOL_SEED + index,
        "success": bool(info["is_success"]),
        "jams": int(info["jams"]),
        "decisions": int(info["decisions"]),
        "sim_s": float(info["sim_time"]),
        "wall_s": time.perf_counter() - t0,
    }


def episode_plan(agents: Sequence[str], first: int, networks: int) -> list[tuple[str, str, int]]:
    """(agent, fidelity, network) of every episode: the fast ones first (cheap), then the full
    ones network by network (an interrupted run leaves networks complete for every agent)."""
    idx = range(first, first + networks)
    return [(a, f, i) for f in FIDELITIES for i in idx for a in agents]


def run_all(
    plan: list[tuple[str, str, int]],
    network_config: dict[str, Any],
    jobs: int = 1,
    on_episode: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run ``plan`` (in ``jobs`` spawned worker processes when > 1); ``on_episode`` after each
    episode as it finishes; the episodes in plan order."""
    return run_plan(run_episode, [(a, f, i, network_config) for a, f, i in plan], jobs, on_episode)


def merge_episodes(*groups: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """The episodes of ``groups``, one per (agent, fidelity, network) (a later group's episode
    replaces an earlier one's), sorted."""
    keyed: dict[tuple[str, str, int], dict[str, Any]] = {}
    for group in groups:
        for e in group:
            keyed[(e["agent"], e["fidelity"], int(e["network"]))] = e
    return [keyed[k] for k in sorted(keyed)]


def load_run(path: str | Path, network_config: dict[str, Any]) -> list[dict[str, Any]]:
    """The episodes of an earlier run's json; its network config must be ``network_config``."""
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    if data.get("network_config") != network_config:
        raise ValueError(
            f"--merge {path}: network_config = {data.get('network_config')}; "
            f"allowed: this run's {network_config}"
        )
    return list(data["episodes"])


# ------------------------------------------------------------------------- summary
def complete_networks(episodes: list[dict[str, Any]], agents: Sequence[str]) -> list[int]:
    """The networks on which every agent has an episode in both fidelities."""
    have = {(e["agent"], e["fidelity"], int(e["network"])) for e in episodes}
    nets = sorted({int(e["network"]) for e in episodes})
    return [n for n in nets if all((a, f, n) in have for a in agents for f in FIDELITIES)]


def _rate(outcomes: list[bool]) -> dict[str, Any]:
    k, n = sum(outcomes), len(outcomes)
    low, high = wilson_interval(k, n)
    return {"successes": k, "n": n, "rate": k / n if n else math.nan, "ci95": [low, high]}


def summarise(episodes: list[dict[str, Any]], agents: Sequence[str]) -> dict[str, Any]:
    """The figures of the transfer table over the complete networks (see the module doc)."""
    nets = complete_networks(episodes, agents)
    by = {(e["agent"], e["fidelity"], int(e["network"])): e for e in episodes}
    out: dict[str, Any] = {"networks": nets, "n": len(nets), "agents": {}}
    for agent in agents:
        row: dict[str, Any] = {}
        for fid in FIDELITIES:
            eps = [by[(agent, fid, n)] for n in nets]
            row[fid] = {
                **_rate([e["success"] for e in eps]),
                "jams_per_episode": _mean(e["jams"] for e in eps),
                "decisions_per_episode": _mean(e["decisions"] for e in eps),
                "wall_s_per_episode": _mean(e["wall_s"] for e in eps),
                "wall_s_median": _median([e["wall_s"] for e in eps]),
            }
        fast = [by[(agent, "fast", n)]["success"] for n in nets]
        full = [by[(agent, "full", n)]["success"] for n in nets]
        only_fast, only_full, p = mcnemar_exact(fast, full)
        row["transfer"] = {
            "gap_points": 100.0 * (row["fast"]["rate"] - row["full"]["rate"]),
            "only_fast": only_fast,
            "only_full": only_full,
            "mcnemar_p": p,
        }
        out["agents"][agent] = row
    out["identical"] = {fid: _identical(by, nets, agents, fid) for fid in FIDELITIES}
    if REFERENCE in agents:
        out["against_reference"] = _against_reference(by, nets, agents)
    return out


def _identical(
    by: dict[tuple[str, str, int], dict[str, Any]], nets: list[int], agents: Sequence[str], fid: str
) -> int:
    """On how many networks every agent's episode in ``fid`` was the same: the same outcome,
    decisions, jams and simulated time (to the millisecond), so the same choices in effect."""

    def key(e: dict[str, Any]) -> tuple[Any, ...]:
        return (e["success"], e["decisions"], e["jams"], round(float(e["sim_s"]), 3))

    return sum(1 for n in nets if len({key(by[(a, fid, n)]) for a in agents}) == 1)


def _against_reference(
    by: dict[tuple[str, str, int], dict[str, Any]], nets: list[int], agents: Sequence[str]
) -> dict[str, Any]:
    """Each other agent's success as a fraction of RoutePlanner's, per fidelity."""
    out: dict[str, Any] = {}
    for agent in agents:
        if agent == REFERENCE:
            continue
        out[agent] = {}
        for fid in FIDELITIES:
            ref = [by[(REFERENCE, fid, n)]["success"] for n in nets]
            own = [by[(agent, fid, n)]["success"] for n in nets]
            only_own, only_ref, p = mcnemar_exact(own, ref)
            r_ref, r_own = _mean(ref), _mean(own)
            fraction = r_own / r_ref if r_ref > 0 else math.nan
            gap = 100.0 * (r_ref - r_own)
            out[agent][fid] = {
                "fraction": fraction,
                "gap_points": gap,
                "only_agent": only_own,
                "only_reference": only_ref,
                "mcnemar_p": p,
                "target_met": bool(fraction >= TARGET_FRACTION and gap <= TARGET_GAP_POINTS),
            }
    return out


def _name(agent: str) -> str:
    return {"route_planner": "RoutePlanner", "goal_greedy": "GoalGreedy"}.get(
        agent, f"MaskablePPO ({Path(agent).name})" if agent.endswith(".zip") else agent
    )


def _pct(rate: dict[str, Any]) -> str:
    low, high = rate["ci95"]
    return f"{100 * rate['rate']:.1f} % [{100 * low:.1f}, {100 * high:.1f}]"


def markdown(figures: dict[str, Any], header: str) -> str:
    """The transfer table and the comparison with RoutePlanner as markdown."""
    lines = [header, ""]
    lines.append(
        "| agent | success fast [95 % Wilson] | success full [95 % Wilson] | gap fast - full "
        "(points) | fast-only / full-only | McNemar p | jams/ep fast | jams/ep full | "
        "decisions/ep fast | decisions/ep full | s per full episode (median, mean) |"
    )
    lines.append("|---|---|---|---|---|---|---|---|---|---|---|")
    for agent, row in figures["agents"].items():
        fa, fu, tr = row["fast"], row["full"], row["transfer"]
        lines.append(
            f"| {_name(agent)} | {_pct(fa)} | {_pct(fu)} | {tr['gap_points']:+.1f} | "
            f"{tr['only_fast']} / {tr['only_full']} | {tr['mcnemar_p']:.3f} | "
            f"{fa['jams_per_episode']:.2f} | {fu['jams_per_episode']:.2f} | "
            f"{fa['decisions_per_episode']:.1f} | {fu['decisions_per_episode']:.1f} | "
            f"{fu['wall_s_median']:.1f}, {fu['wall_s_per_episode']:.1f} |"
        )
    same = figures.get("identical", {})
    if same and len(figures["agents"]) > 1:
        lines += [
            "",
            "Networks on which all agents' episodes were the same (outcome, decisions, jams, "
            "simulated time): "
            + ", ".join(f"{fid} {k} of {figures['n']}" for fid, k in same.items())
            + ".",
        ]
    against = figures.get("against_reference", {})
    if against:
        lines += [
            "",
            f"Success against RoutePlanner on the same networks (target: fraction >= "
            f"{TARGET_FRACTION}, gap <= {TARGET_GAP_POINTS:.0f} points):",
            "",
            "| agent | fidelity | fraction of RoutePlanner's success | gap (points) | "
            "agent-only / RoutePlanner-only | McNemar p | target |",
            "|---|---|---|---|---|---|---|",
        ]
        for agent, per in against.items():
            for fid, c in per.items():
                lines.append(
                    f"| {_name(agent)} | {fid} | {c['fraction']:.3f} | {c['gap_points']:+.1f} | "
                    f"{c['only_agent']} / {c['only_reference']} | {c['mcnemar_p']:.3f} | "
                    f"{'met' if c['target_met'] else 'not met'} |"
                )
    lines += [
        "",
        "Gap: fast minus full success; McNemar's exact test (two-sided) on the paired "
        "per-network outcomes. p > 0.05 means no difference detectable at this sample size, not "
        "equality: the Wilson intervals show how wide the uncertainty still is.",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------------------- main
def _agents(text: str) -> list[str]:
    agents = [a.strip() for a in text.split(",") if a.strip()]
    from agents.scripted import SCRIPTED_AGENTS

    for a in agents:
        if a not in SCRIPTED_AGENTS and not (a.endswith(".zip") and Path(a).is_file()):
            raise argparse.ArgumentTypeError(
                f"--agents: {a!r}; allowed: {sorted(SCRIPTED_AGENTS)} or an existing model .zip"
            )
    if not agents:
        raise argparse.ArgumentTypeError("--agents: empty; allowed: a comma-separated list")
    return agents


def _network_config(text: str) -> dict[str, Any]:
    try:
        config = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"--network-config = {text!r}: not JSON ({exc})") from None
    if not isinstance(config, dict):
        raise argparse.ArgumentTypeError(f"--network-config = {text!r}; allowed: a JSON object")
    from pipe_env.generator import NetworkConfig

    try:
        NetworkConfig.from_dict(config)
    except (TypeError, ValueError) as exc:
        raise argparse.ArgumentTypeError(f"--network-config: {exc}") from None
    return config


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--networks", type=int, default=24, help="networks to run (>= 0)")
    parser.add_argument("--first", type=int, default=0, help="first network index (>= 0)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (>= 1)")
    parser.add_argument(
        "--agents", type=_agents, default=list(DEFAULT_AGENTS), help="comma-separated agents"
    )
    parser.add_argument(
        "--network-config",
        type=_network_config,
        default=dict(NETWORK_CONFIG),
        help="NetworkConfig as JSON (default: 6-fitting 3D with loops)",
    )
    parser.add_argument("--merge", nargs="*", default=[], help="earlier runs' json to include")
    parser.add_argument("--json", default=None, help="write figures and episodes here")
    parser.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = parser.parse_args(argv)
    for name, low in (("networks", 0), ("first", 0), ("jobs", 1)):
        if getattr(args, name) < low:
            parser.error(f"--{name} = {getattr(args, name)}; allowed: >= {low}")
    if args.networks == 0 and not args.merge:
        parser.error("--networks = 0 needs --merge FILE (nothing to run or summarise)")
    return args


def _save(path: str | None, payload: dict[str, Any]) -> None:
    if path:
        from pipe_env.network_io import finite_json

        atomic_write_text(path, json.dumps(finite_json(payload), indent=1, allow_nan=False))


def _code_commit() -> str:
    """The commit the episodes run on (``+changes`` when the code differs from it)."""
    try:
        from benchmarks.report import _commit
    except ImportError:  # run without the repository root on the path
        return "unknown"
    return _commit()


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run (and merge) the episodes; prints the table and returns the figures."""
    args = parse_args(argv)
    earlier: list[dict[str, Any]] = []
    for path in args.merge:
        earlier = merge_episodes(earlier, load_run(path, args.network_config))
    done: list[dict[str, Any]] = []
    payload: dict[str, Any] = {
        "network_config": args.network_config,
        "detector": DETECTOR,
        "env_kwargs": {f: env_kwargs(f, args.network_config) for f in FIDELITIES},
        "agents": args.agents,
        "episodes": earlier,
    }

    commit = _code_commit()

    def progress(e: dict[str, Any]) -> None:
        e["commit"] = commit
        done.append(e)
        payload["episodes"] = merge_episodes(earlier, done)
        _save(args.json, payload)
        print(
            f"{e['fidelity']} {_name(e['agent'])} network {e['network']}: success "
            f"{e['success']}, {e['decisions']} decisions, {e['jams']} jams, {e['wall_s']:.1f} s",
            flush=True,
        )

    t0 = time.perf_counter()
    run_all(
        episode_plan(args.agents, args.first, args.networks),
        args.network_config,
        args.jobs,
        progress,
    )
    wall = time.perf_counter() - t0
    episodes = merge_episodes(earlier, done)
    figures = summarise(episodes, args.agents)
    default = args.network_config == NETWORK_CONFIG
    nets = figures["networks"]
    span = f"networks {nets[0]}..{nets[-1]}" if nets else "no network"
    config_arg = "" if default else f" --network-config '{json.dumps(args.network_config)}'"
    header = (
        f"{figures['n']} held-out networks ({span}; "
        f"{'the default: ' if default else ''}{json.dumps(args.network_config, sort_keys=True)}"
        f"{DEFAULT_NOTE if default else ''}"
        f"), each agent in both fidelities with the same seeds, {DETECTOR} detector, the "
        f"packaged training config's env arguments (decision budget "
        f"{payload['env_kwargs']['full'].get('max_episode_steps')}). "
        f"{len(episodes)} episodes, {sum(e['wall_s'] for e in episodes) / 60:.0f} min of "
        f"episode wall time (this invocation: {len(done)} episodes, {wall:.0f} s, "
        f"{args.jobs} job(s); a shared machine); episodes run on commit(s) "
        f"{', '.join(sorted({str(e.get('commit', 'unknown')) for e in episodes}))}. Command: "
        f"`python benchmarks/bench_transfer.py --networks N{config_arg}`; extend a run with "
        "`--first K --networks M --merge earlier.json`."
    )
    report = markdown(figures, header)
    print("\n" + report)
    payload["figures"] = figures
    payload["episodes"] = episodes
    _save(args.json, payload)
    if args.write_docs:
        from benchmarks.report import write_section

        write_section("transfer", report)
    return figures


if __name__ == "__main__":
    main()
