"""One held-out episode of the transfer table, traced decision by decision.

Replays episode ``--network i`` of :mod:`benchmarks.bench_transfer` (network ``i`` of the
held-out pool, seed ``EVAL_POOL_SEED + i``, the same env arguments) for one agent in one
fidelity and prints, per decision:

- where the robot truly is (run, arc length ``s`` in metres, the fitting it heads for);
- the true ways on at the structure ahead (ground truth) and the detected options, with the
  action mask and the action chosen;
- how the step ended: the chosen way's outcome and the executor's note, the jams so far, and
  every way attempted in the step (the agent's and those the environment took by itself);
- with ``--sweeps``, every sweep read since the last decision (full fidelity): the true fitting
  ahead and the detector's reading (kind; distance m, diameter mm, angle and roll deg).

Option columns: ``kind:d=<distance m>,D=<diameter mm>,a=<deflection deg>,r=<roll deg>`` (roll
0 = left, 90 = up, in the sensor frame).

Usage: python benchmarks/trace_episode.py AGENT --network I [--fidelity full] [--sweeps]
       [--network-config JSON]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

# Runnable as a script from anywhere: the repository root holds the benchmarks package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from detector.options import StructureOption
from pipe_env.envs.actions import BACK_ROW

#: Rows of the action space that are ways on (the last row backs out).
_ROW_NAMES = {BACK_ROW: "back out"}


def option_text(o: StructureOption | dict[str, Any]) -> str:
    """One option as ``kind:d=..,D=..,a=..,r=..`` (m, mm, deg, deg)."""
    if isinstance(o, dict):
        o = StructureOption(**o)
    return (
        f"{o.kind}:d={o.distance:.2f},D={o.diameter * 1000:.0f},"
        f"a={math.degrees(o.angle):.0f},r={math.degrees(o.direction):.0f}"
    )


def options_text(options: Iterable[StructureOption | dict[str, Any]]) -> str:
    """Options as a bracketed list of :func:`option_text`."""
    return "[" + "; ".join(option_text(o) for o in options) + "]"


def _where(env: Any) -> str:
    from pipe_env.routing import locate

    ep, towards = locate(env.network, env.plant.pose())
    return f"run {ep.run_id} s={ep.s:.2f} m -> {towards}"


def _decision_lines(env: Any, action: int) -> list[str]:
    dec = env.decision
    mask = "".join(str(int(m)) for m in env.action_masks())
    return [
        f"decision {env.decisions}: {_where(env)}; structure {dec.node_id} (entered by "
        f"{dec.entry_run})",
        f"  truth    {options_text(dec.truth)}",
        f"  detected {dec.kind} {options_text(dec.options)} mask {mask}",
        f"  action   {action} ({_ROW_NAMES.get(action, 'way in that row')})",
    ]


def _step_lines(env: Any, info: dict[str, Any], attempts: list[Any]) -> list[str]:
    note = info.get("outcome_note") or info.get("auto_jammed_note") or ""
    out = info.get("outcome", "")
    lines = [
        f"  outcome  {getattr(out, 'value', out)}{' (' + note + ')' if note else ''}; "
        f"jams {info['jams']}; now {_where(env) if env.plant is not None else '-'}"
    ]
    for a in attempts:
        by = "env" if a.auto else "agent"
        lines.append(f"  attempt  {by}: {a.way} ({a.side}) at a {a.true_kind}: {a.status}")
    return lines


def _sweep_lines(records: list[dict[str, Any]]) -> list[str]:
    return [
        f"    sweep t={r['time']:.1f} s ahead {r['node']} ({r['true_kind']}, "
        f"d={r['true_distance'] if r['true_distance'] is None else round(r['true_distance'], 2)})"
        f": {r['kind']} {options_text(r['options'])}"
        for r in records
    ]


def trace_episode(
    agent: str,
    fidelity: str,
    index: int,
    network_config: dict[str, Any],
    sweeps: bool = False,
    emit: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run held-out episode ``index`` of ``agent`` in ``fidelity`` and trace it; each line is
    passed to ``emit`` as it is made. Returns the final info (without the action mask) and
    the trace lines under ``"trace"``."""
    from agents.evaluate import EVAL_POOL_SEED, env_setup, pool_network, worker_env
    from benchmarks.bench_transfer import env_kwargs

    kwargs = env_kwargs(fidelity, network_config)
    wrapped, actor = worker_env(agent, "pipenav/PipeNav-v0", kwargs)
    env: Any = wrapped.unwrapped
    cfg, _ = env_setup(kwargs)
    lines: list[str] = []

    def say(items: list[str]) -> None:
        lines.extend(items)
        if emit is not None:
            for line in items:
                emit(line)

    network = pool_network(cfg, EVAL_POOL_SEED, index)
    obs, info = wrapped.reset(seed=EVAL_POOL_SEED + index, options={"network": network})
    actor.reset()
    say([f"network {index} ({agent}, {fidelity}): goal {list(network.goals[:1])}"])
    seen_sweeps = 0
    seen_attempts = 0
    done = env.decision is None
    while not done:
        log = list(getattr(env.plant, "detection_log", []))
        if sweeps:
            say(_sweep_lines(log[seen_sweeps:]))
        seen_sweeps = len(log)
        action = int(actor.act(obs, info))
        say(_decision_lines(env, action))
        obs, _, term, trunc, info = wrapped.step(action)
        attempts = env.outcome_log.attempts[seen_attempts:]
        seen_attempts = len(env.outcome_log.attempts)
        say(_step_lines(env, info, attempts))
        done = term or trunc
    final = {k: v for k, v in info.items() if k != "action_mask"}
    say(
        [
            f"end: success {bool(final.get('is_success'))}, jams {final.get('jams')}, "
            f"decisions {final.get('decisions')}"
        ]
    )
    final["trace"] = lines
    return final


def main(argv: list[str] | None = None) -> int:
    from benchmarks.bench_transfer import NETWORK_CONFIG

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("agent", help="route_planner, goal_greedy, ... or a MaskablePPO .zip")
    p.add_argument("--network", type=int, required=True, help="held-out network index")
    p.add_argument("--fidelity", choices=("fast", "full"), default="full")
    p.add_argument("--sweeps", action="store_true", help="also print every sweep's reading")
    p.add_argument("--network-config", type=json.loads, default=dict(NETWORK_CONFIG))
    a = p.parse_args(argv)
    trace_episode(a.agent, a.fidelity, a.network, a.network_config, a.sweeps, emit=print)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
