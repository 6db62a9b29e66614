"""Full fidelity at speed: physics where contact decides against the all-physics reference.

Runs RoutePlanner on the same held-out networks (``--networks``, default 48; 6-fitting 3D
networks with loops, ``pool_network(config, EVAL_POOL_SEED, i)``) in full fidelity twice in one
run, episode by episode alternating: ``physics="contact"`` (straight drives away from fittings
kinematic, see :meth:`primitives.executor.Executor.free_straight`) and
``physics="everywhere"`` (contact physics for every motion: the reference). Both use the same
seeds, the same detector (``improved``), the same sweep cadence. One untimed episode per mode
on the next held-out network comes first (the process's one-off costs: compiling or loading
the compiled kernels, first MuJoCo builds). Prints:

- decisions/s of each (one core; resets, model builds included, and the steps alone) and their
  ratio; control ticks run with physics and driven kinematically;
- RoutePlanner success and jams per episode of each;
- the detection error at each decision (distance mm, angle deg, direction deg against ground
  truth, as the environment records them) of each;
- the sensor pose at each episode's first decision: the difference between the two modes
  (position mm, heading deg);
- tests of equivalence: success by McNemar's exact test on the paired episodes; jams per
  episode by the Wilcoxon signed-rank test on the paired counts; each detection error by the
  two-sample Kolmogorov-Smirnov test on the per-decision errors. A p-value above 0.05 means no
  difference detectable at this sample size (not proof of equality: the sample size bounds the
  difference that could be detected, reported as the 95 % interval of the success difference).

With ``--ticks N`` it instead profiles one seeded ``physics="contact"`` episode (held-out
network N, seed ``EVAL_POOL_SEED + N``) per control tick (see :func:`tick_profile`): the
executor's time per physics tick split into MuJoCo's ``mj_step`` and the rest (the executor's
Python: targets, contact-pair selection, telemetry, checks), the contact pairs' selection rate
and the episode's decisions/s. ``--repeat K`` runs the episode K times (the figures of the
fastest run are printed, each run's on its own line).

With ``--phases contact`` (or ``everywhere``) it instead runs that mode alone on the networks
``--first`` .. ``--first + --networks - 1`` and prints the physics control ticks (and simulated
seconds of physics) per decision by motion phase and by sequence (see :func:`phase_profile`):
where the simulated time of a decision goes.

Usage: python benchmarks/bench_full_fidelity.py [--networks 48] [--write-docs] [--json out.json]
       python benchmarks/bench_full_fidelity.py --ticks 0 [--repeat 3]
       python benchmarks/bench_full_fidelity.py --phases contact [--networks 12]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

# Runnable as a script from anywhere: the repository root holds the benchmarks package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym
import mujoco
import numpy as np
from scipy import stats

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.evaluate import EVAL_POOL_SEED, held_out_networks
from agents.scripted import make_agent
from detector.atomic import atomic_write_text
from detector.validation import fail
from pipe_env.generator import NetworkConfig
from primitives.executor import CONTROL_DT

MODES = ("contact", "everywhere")
NETWORK_CONFIG = {"n_fittings": 6, "planar": False, "allow_loops": True}


def run_episode(env: gym.Env, network: Any, seed: int) -> dict[str, Any]:
    """One RoutePlanner episode on ``network``: outcome, timing and the decisions' errors."""
    base: Any = env.unwrapped
    agent = make_agent("route_planner", env)
    t0 = time.perf_counter()
    obs, info = env.reset(seed=seed, options={"network": network})
    t_reset = time.perf_counter() - t0
    agent.reset()
    first = base.decision.pose if base.decision is not None else None
    done = bool(base.terminated or base.truncated)
    t1 = time.perf_counter()
    while not done:
        obs, _, term, trunc, info = env.step(agent.act(obs, info))
        done = term or trunc
    t_steps = time.perf_counter() - t1
    ex = base.plant.executor
    return {
        "success": bool(info["is_success"]),
        "jams": int(info["jams"]),
        "decisions": int(info["decisions"]),
        "reset_s": t_reset,
        "steps_s": t_steps,
        "errors": list(base.detection_errors),
        "first_pose": None
        if first is None
        else {"position": first.position.tolist(), "forward": first.rotation[:, 0].tolist()},
        "physics_ticks": int(ex.physics_ticks),
        "kinematic_ticks": int(ex.kinematic_ticks),
    }


class _Clock:
    """Wall time spent in the executor's entry points (scans excluded) and in ``mj_step``."""

    def __init__(self) -> None:
        self.executor_s = 0.0
        self.scan_s = 0.0
        self.step_s = 0.0
        self.steps = 0
        self.updates = 0
        self.depth = 0

    def mj_step(self, *args: Any, **kwargs: Any) -> None:
        t = time.perf_counter()
        mujoco.mj_step(*args, **kwargs)
        self.step_s += time.perf_counter() - t
        self.steps += 1


class _TimedMujoco:
    """The ``mujoco`` module as the executor sees it, ``mj_step`` timed by ``clock``."""

    def __init__(self, clock: _Clock) -> None:
        self._clock = clock

    def __getattr__(self, name: str) -> Any:
        if name == "mj_step":
            return self._clock.mj_step
        return getattr(mujoco, name)


def _timed_entry(clock: _Clock, method: Callable[..., Any], attr: str) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        clock.depth += 1
        t = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            clock.depth -= 1
            if clock.depth == 0:
                setattr(clock, attr, getattr(clock, attr) + time.perf_counter() - t)

    return wrapper


@contextmanager
def _instrumented(clock: _Clock) -> Iterator[None]:
    """Time the executor's entry points (``place``, ``run``, ``drive_until``), its sweeps and
    ``mj_step`` while inside; count NearContacts updates."""
    import primitives.executor as executor_module
    from pipe_env.world import NearContacts
    from primitives.executor import Executor

    saved = {name: getattr(Executor, name) for name in ("place", "run", "drive_until", "_scan")}
    saved_update = NearContacts.update
    for name in ("place", "run", "drive_until"):
        setattr(Executor, name, _timed_entry(clock, saved[name], "executor_s"))

    def scan(self: Any, *args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return saved["_scan"](self, *args, **kwargs)
        finally:
            clock.scan_s += time.perf_counter() - t

    def update(self: Any, *args: Any, **kwargs: Any) -> None:
        clock.updates += 1
        saved_update(self, *args, **kwargs)

    Executor._scan = scan  # type: ignore[method-assign]
    NearContacts.update = update  # type: ignore[method-assign]
    executor_module.mujoco = _TimedMujoco(clock)
    try:
        yield
    finally:
        executor_module.mujoco = mujoco
        for name, method in saved.items():
            setattr(Executor, name, method)
        NearContacts.update = saved_update  # type: ignore[method-assign]


def tick_profile(index: int) -> dict[str, Any]:
    """One RoutePlanner episode (``physics="contact"``, held-out network ``index``, seed
    ``EVAL_POOL_SEED + index``) timed per control tick: µs of ``mj_step`` and of the rest of
    the executor's work per physics tick (sweeps excluded), contact-pair selections per
    physics tick, decisions/s of the episode, and the outcome (to compare runs)."""
    cfg = NetworkConfig.from_dict(NETWORK_CONFIG)
    net = held_out_networks(cfg, index + 1)[index]
    env = gym.make(
        "pipenav/PipeNav-v0",
        fidelity="full",
        detector="improved",
        network_config=cfg,
        physics="contact",
    )
    clock = _Clock()
    with _instrumented(clock):
        row = run_episode(env, net, EVAL_POOL_SEED + index)
    base: Any = env.unwrapped
    ex = base.plant.executor
    near = ex.near
    position = base.plant.pose().position.tolist()
    env.close()
    ticks = max(row["physics_ticks"], 1)
    rest = clock.executor_s - clock.scan_s - clock.step_s
    return {
        "network": index,
        "physics_ticks": row["physics_ticks"],
        "kinematic_ticks": row["kinematic_ticks"],
        "mj_step_us": 1e6 * clock.step_s / ticks,
        "rest_us": 1e6 * rest / ticks,
        "updates": clock.updates,
        "selections": int(near.selections) if near is not None else 0,
        "selection_rate": (near.selections / ticks) if near is not None else 0.0,
        "overruns": int(near.overruns) if near is not None else 0,
        "fallbacks": int(near.fallbacks) if near is not None else 0,
        "decisions": row["decisions"],
        "decisions_per_s": row["decisions"] / (row["reset_s"] + row["steps_s"]),
        "success": row["success"],
        "jams": row["jams"],
        "position": position,
        "time": float(ex.time),
    }


def _print_tick_profile(index: int, repeat: int) -> None:
    runs = []
    for k in range(repeat):
        r = tick_profile(index)
        runs.append(r)
        print(
            f"run {k}: network {r['network']}: {r['physics_ticks']} physics ticks, "
            f"{r['kinematic_ticks']} kinematic; per physics tick mj_step {r['mj_step_us']:.0f} "
            f"us, rest {r['rest_us']:.0f} us (rest/mj_step {r['rest_us'] / r['mj_step_us']:.2f})"
            f"; selections {r['selections']} of {r['updates']} updates "
            f"({100 * r['selection_rate']:.1f} % of physics ticks), overruns {r['overruns']}, "
            f"fallbacks {r['fallbacks']}; {r['decisions']} decisions, "
            f"{r['decisions_per_s']:.3f} decisions/s; success {r['success']}, jams {r['jams']}, "
            f"final position {np.round(r['position'], 9).tolist()}, time {r['time']:.4f} s",
            flush=True,
        )
    best = min(runs, key=lambda r: r["rest_us"] + r["mj_step_us"])
    print(
        f"fastest: mj_step {best['mj_step_us']:.0f} us/tick, rest {best['rest_us']:.0f} us/tick, "
        f"{best['decisions_per_s']:.3f} decisions/s"
    )


#: The executor's motion methods a physics tick is attributed to (innermost first wins), with
#: the phase each stands for; a ``_settle`` inside one is that phase's settle.
_PHASE_METHODS = {
    "_stop_here": "stop after a jam",
    "_clamp": "clamp",
    "_unclamp": "unclamp",
    "_probe": "centre: probes",
    "_shift": "centre: shift",
    "_roll": "roll",
    "_bend": "bend",
    "_reverse": "reverse",
    "_glide": "kinematic glide",
    "_drive": "drive",
}


def _drive_phase(ex: Any, context: str) -> str:
    """The phase of a physical ``_drive`` starting now: the sensing drives of ``advance``
    (near fittings: the kinematic rule refused them), a turn's arc, the drive holding its
    heading after the arc, or a straight drive of a sequence (clamped or not)."""
    if context == "drive_until":
        return "drive: sensing (approach)"
    if ex.command.curvature != 0.0:
        return "drive: turn arc"
    if ex.command.hold_heading:
        return "drive: after arc (held heading)"
    return "drive: straight " + ("clamped" if ex.vclamp.alpha > 0.0 else "unclamped")


class PhaseCounter:
    """Physics control ticks by motion phase (see :func:`phase_profile`): a tick counts
    towards the innermost executor motion running it (``_PHASE_METHODS``; a ``Stop`` step is
    ``"stop"``), its settle separately (``"<phase>: settle"``), and towards the sequence (or
    ``drive_until``, ``place``) it belongs to."""

    def __init__(self) -> None:
        self.by_phase: dict[str, int] = {}
        self.by_sequence: dict[str, int] = {}
        self.stack: list[str] = []
        self.context: list[str] = []

    def count(self) -> None:
        seq = self.context[-1] if self.context else "other"
        phase = "place (reset)" if seq == "place" else self.stack[-1] if self.stack else "other"
        self.by_phase[phase] = self.by_phase.get(phase, 0) + 1
        self.by_sequence[seq] = self.by_sequence.get(seq, 0) + 1


@contextmanager
def _phased(counter: PhaseCounter) -> Iterator[None]:
    """Attribute every physics tick the executor runs while inside to its phase (see
    :class:`PhaseCounter`); the executor's methods are restored on exit."""
    from primitives.executor import Executor
    from primitives.steps import Stop

    names = [*_PHASE_METHODS, "_settle", "_physics", "_do", "run", "drive_until", "place"]
    saved = {name: getattr(Executor, name) for name in names}

    def phase(name: str, label: str) -> Callable[..., Any]:
        method = saved[name]

        def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
            top = counter.stack[-1] if counter.stack else ""
            if name == "_drive":
                tag = _drive_phase(self, counter.context[-1] if counter.context else "")
            elif top.startswith("centre") or (top == "clamp" and name == "_unclamp"):
                tag = f"{top} ({label})"  # a probe's unfolding, a clamp's unclamping first
            else:
                tag = label
            counter.stack.append(tag)
            try:
                return method(self, *args, **kwargs)
            finally:
                counter.stack.pop()

        return wrapper

    def context(name: str) -> Callable[..., Any]:
        method = saved[name]

        def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
            seq = args[0] if args else None
            counter.context.append(getattr(seq, "name", name) if name == "run" else name)
            try:
                return method(self, *args, **kwargs)
            finally:
                counter.context.pop()

        return wrapper

    def settle(self: Any, *args: Any, **kwargs: Any) -> Any:
        parent = counter.stack[-1] if counter.stack else "stop"
        counter.stack.append(parent if parent.endswith("settle") else f"{parent}: settle")
        try:
            return saved["_settle"](self, *args, **kwargs)
        finally:
            counter.stack.pop()

    def do(self: Any, step: Any, *args: Any, **kwargs: Any) -> Any:
        if isinstance(step, Stop):
            counter.stack.append("stop")
        try:
            return saved["_do"](self, step, *args, **kwargs)
        finally:
            if isinstance(step, Stop):
                counter.stack.pop()

    def physics(self: Any, *args: Any, **kwargs: Any) -> Any:
        counter.count()
        return saved["_physics"](self, *args, **kwargs)

    for name, label in _PHASE_METHODS.items():
        setattr(Executor, name, phase(name, label))
    for name in ("run", "drive_until", "place"):
        setattr(Executor, name, context(name))
    Executor._settle = settle  # type: ignore[method-assign]
    Executor._do = do  # type: ignore[method-assign]
    Executor._physics = physics  # type: ignore[method-assign]
    try:
        yield
    finally:
        for name, method in saved.items():
            setattr(Executor, name, method)


def phase_profile(first: int, n: int, physics: str = "contact") -> dict[str, Any]:
    """Physics control ticks per decision by motion phase and by sequence, over RoutePlanner
    episodes on held-out networks ``first .. first + n - 1`` (seeds ``EVAL_POOL_SEED + i``)
    with ``physics``; resets (building, placing and clamping the robot) counted apart."""
    cfg = NetworkConfig.from_dict(NETWORK_CONFIG)
    networks = held_out_networks(cfg, first + n)[first:]
    env = gym.make(
        "pipenav/PipeNav-v0",
        fidelity="full",
        detector="improved",
        network_config=cfg,
        physics=physics,
    )
    counter = PhaseCounter()
    rows = []
    with _phased(counter):
        for i, net in enumerate(networks):
            rows.append(run_episode(env, net, EVAL_POOL_SEED + first + i))
    env.close()
    return {
        "physics": physics,
        "episodes": len(rows),
        "decisions": sum(r["decisions"] for r in rows),
        "success": sum(r["success"] for r in rows),
        "jams": sum(r["jams"] for r in rows),
        "steps_s": sum(r["steps_s"] for r in rows),
        "reset_s": sum(r["reset_s"] for r in rows),
        "kinematic_ticks": sum(r["kinematic_ticks"] for r in rows),
        "by_phase": counter.by_phase,
        "by_sequence": counter.by_sequence,
        "outcomes": [[r["success"], r["jams"], r["decisions"]] for r in rows],
    }


def phase_table(profile: dict[str, Any], control_dt: float = CONTROL_DT) -> str:
    """The markdown tables of a :func:`phase_profile`: physics ticks per decision (and the
    simulated seconds of physics, ``control_dt`` s a tick) by phase and by sequence. A
    profile of no networks (no time stepped) is refused."""
    if not profile["steps_s"] > 0.0:
        raise fail(
            "profile['steps_s']",
            profile["steps_s"],
            "above 0 s (a profile of at least one network)",
            "no episode was stepped",
            where="phase_table",
        )
    dec = max(profile["decisions"], 1)
    out = [
        f"physics={profile['physics']}: {profile['episodes']} episodes, "
        f"{profile['decisions']} decisions, success {profile['success']}, jams "
        f"{profile['jams']}; decisions/s steps {profile['decisions'] / profile['steps_s']:.3f}, "
        f"with resets {profile['decisions'] / (profile['steps_s'] + profile['reset_s']):.3f}; "
        f"kinematic ticks/decision {profile['kinematic_ticks'] / dec:.0f}\n"
    ]
    for key, title in (("by_phase", "phase"), ("by_sequence", "sequence")):
        counts = profile[key]
        resets = ("place", "place (reset)")
        total = max(sum(v for k, v in counts.items() if k not in resets), 1)
        out.append(f"| {title} | physics ticks/decision | physics s/decision | share |")
        out.append("|---|---|---|---|")
        for name, v in sorted(counts.items(), key=lambda kv: -kv[1]):
            share = f"{100 * v / total:.1f} %" if name not in resets else "(resets)"
            out.append(f"| {name} | {v / dec:.1f} | {v * control_dt / dec:.2f} | {share} |")
        steps = total / dec
        out.append(f"| total (steps) | {steps:.1f} | {steps * control_dt:.2f} | 100 % |\n")
    return "\n".join(out)


def _errors(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    vals = [e[key] for r in rows for e in r["errors"] if key in e and math.isfinite(e[key])]
    return np.asarray(vals, dtype=float)


def mcnemar_exact(a: list[bool], b: list[bool]) -> float:
    """Two-sided exact McNemar p-value of paired successes ``a`` against ``b``."""
    from benchmarks.bench_transfer import mcnemar_exact as paired_test

    return paired_test(a, b)[2]


def summarise(results: dict[str, list[dict[str, Any]]]) -> tuple[dict[str, Any], str]:
    """Figures and the markdown report of both modes' episodes."""
    out: dict[str, Any] = {}
    lines = []
    n = len(results[MODES[0]])
    lines.append(
        f"RoutePlanner, improved detector, {n} held-out networks "
        f"({NETWORK_CONFIG['n_fittings']}-fitting 3D with loops), both modes in one run.\n"
    )
    lines.append(
        "| physics | decisions | decisions/s (all) | decisions/s (steps) | success | "
        "jams/episode | physics ticks | kinematic ticks |"
    )
    lines.append("|---|---|---|---|---|---|---|---|")
    for mode in MODES:
        rows = results[mode]
        dec = sum(r["decisions"] for r in rows)
        wall = sum(r["reset_s"] + r["steps_s"] for r in rows)
        steps = sum(r["steps_s"] for r in rows)
        step_dec = sum(r["decisions"] for r in rows)
        m = {
            "decisions": dec,
            "decisions_per_s": dec / wall if wall > 0 else math.nan,
            "step_decisions_per_s": step_dec / steps if steps > 0 else math.nan,
            "success_rate": float(np.mean([r["success"] for r in rows])),
            "jams_per_episode": float(np.mean([r["jams"] for r in rows])),
            "physics_ticks": sum(r["physics_ticks"] for r in rows),
            "kinematic_ticks": sum(r["kinematic_ticks"] for r in rows),
        }
        out[mode] = m
        lines.append(
            f"| {mode} | {dec} | {m['decisions_per_s']:.3f} | {m['step_decisions_per_s']:.3f} | "
            f"{m['success_rate']:.3f} | {m['jams_per_episode']:.2f} | {m['physics_ticks']} | "
            f"{m['kinematic_ticks']} |"
        )
    c, e = out["contact"], out["everywhere"]
    ratio = c["decisions_per_s"] / e["decisions_per_s"]
    out["speed_ratio"] = ratio
    lines.append(f"\ncontact / everywhere decisions/s (all): {ratio:.2f}")
    lines.append(
        f"full-fidelity decisions/s (contact, all): {c['decisions_per_s']:.3f} "
        f"(target >= 10: {'met' if c['decisions_per_s'] >= 10 else 'NOT met'})\n"
    )
    # detection errors at each decision
    lines.append("| detection error at the decisions | physics | n | median | p90 | KS p |")
    lines.append("|---|---|---|---|---|---|")
    out["errors"] = {}
    for key, unit, scale in (
        ("distance", "mm", 1000.0),
        ("angle", "deg", 180 / math.pi),
        ("direction", "deg", 180 / math.pi),
    ):
        a = np.abs(_errors(results["contact"], key)) * scale
        b = np.abs(_errors(results["everywhere"], key)) * scale
        p = float(stats.ks_2samp(a, b).pvalue) if len(a) and len(b) else math.nan
        out["errors"][key] = {"ks_p": p}
        for mode, v in (("contact", a), ("everywhere", b)):
            med = float(np.median(v)) if len(v) else math.nan
            p90 = float(np.percentile(v, 90)) if len(v) else math.nan
            out["errors"][key][mode] = {"n": len(v), "median": med, "p90": p90}
            lines.append(
                f"| {key} ({unit}) | {mode} | {len(v)} | {med:.2f} | {p90:.2f} | {p:.3f} |"
            )
    # the sensor pose at the first decision
    dpos, dang = [], []
    for rc, re_ in zip(results["contact"], results["everywhere"]):
        if rc["first_pose"] is None or re_["first_pose"] is None:
            continue
        pc, pe = np.array(rc["first_pose"]["position"]), np.array(re_["first_pose"]["position"])
        fc, fe = np.array(rc["first_pose"]["forward"]), np.array(re_["first_pose"]["forward"])
        dpos.append(1000 * float(np.linalg.norm(pc - pe)))
        dang.append(math.degrees(math.acos(max(-1.0, min(1.0, float(fc @ fe))))))
    if dpos:
        out["first_pose"] = {
            "median_mm": float(np.median(dpos)),
            "max_mm": float(np.max(dpos)),
            "median_deg": float(np.median(dang)),
            "max_deg": float(np.max(dang)),
        }
        fp = out["first_pose"]
        lines.append(
            f"\nsensor pose at the first decision, contact vs everywhere ({len(dpos)} episodes): "
            f"position median {fp['median_mm']:.2f} mm, max {fp['max_mm']:.2f} mm; heading "
            f"median {fp['median_deg']:.3f} deg, max {fp['max_deg']:.3f} deg"
        )
    # equivalence tests
    sc = [r["success"] for r in results["contact"]]
    se = [r["success"] for r in results["everywhere"]]
    p_success = mcnemar_exact(sc, se)
    from benchmarks.bench_transfer import paired_difference_interval

    diff = np.array(sc, dtype=float) - np.array(se, dtype=float)
    low, high = paired_difference_interval(sc, se)
    jc = np.array([r["jams"] for r in results["contact"]])
    je = np.array([r["jams"] for r in results["everywhere"]])
    p_jams = float(stats.wilcoxon(jc, je).pvalue) if np.any(jc != je) else 1.0
    out["tests"] = {
        "success_mcnemar_p": p_success,
        "success_diff": float(diff.mean()),
        "success_diff_ci95": [low, high],
        "jams_wilcoxon_p": p_jams,
    }
    lines.append(
        f"\nsuccess: McNemar exact p = {p_success:.3f} (difference {diff.mean():+.3f}, 95 % "
        f"interval [{low:+.3f}, {high:+.3f}], Newcombe); jams/episode: "
        f"Wilcoxon signed-rank p = {p_jams:.3f}; detection errors: two-sample KS p above. "
        "p > 0.05: no difference detectable at this sample size."
    )
    return out, "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--networks", type=int, default=48)
    parser.add_argument("--first", type=int, default=0, help="first held-out network index")
    parser.add_argument("--json", default=None)
    parser.add_argument("--write-docs", action="store_true")
    parser.add_argument("--ticks", type=int, default=None, help="profile this network per tick")
    parser.add_argument("--repeat", type=int, default=1, help="runs of the --ticks episode")
    parser.add_argument(
        "--phases",
        choices=MODES,
        default=None,
        help="print physics ticks per decision by motion phase with this physics mode "
        "(networks --first .. --first + --networks - 1)",
    )
    args = parser.parse_args()
    if args.phases is not None:
        profile = phase_profile(args.first, args.networks, args.phases)
        print(phase_table(profile))
        if args.json:
            atomic_write_text(args.json, json.dumps(profile))
        return
    if args.ticks is not None:
        if args.ticks < 0 or args.repeat < 1:
            parser.error(f"--ticks = {args.ticks}, --repeat = {args.repeat}; allowed: >= 0, >= 1")
        _print_tick_profile(args.ticks, args.repeat)
        return
    if args.networks < 1:
        parser.error(f"--networks = {args.networks}; allowed: >= 1")
    cfg = NetworkConfig.from_dict(NETWORK_CONFIG)
    pool = held_out_networks(cfg, args.first + args.networks + 1)
    networks, spare = pool[args.first : -1], pool[-1]
    envs = {
        mode: gym.make(
            "pipenav/PipeNav-v0",
            fidelity="full",
            detector="improved",
            network_config=cfg,
            physics=mode,
        )
        for mode in MODES
    }
    # untimed: one episode per mode on a network outside the run (the next held-out one),
    # so the process's one-off costs (compiling or loading the compiled kernels of a fresh
    # checkout, first MuJoCo builds) are not counted in whichever mode happens to go first
    t_warm = time.perf_counter()
    for mode in MODES:
        run_episode(envs[mode], spare, EVAL_POOL_SEED + args.first + args.networks)
    print(f"warm-up: {time.perf_counter() - t_warm:.1f} s (not counted)", flush=True)
    results: dict[str, list[dict[str, Any]]] = {m: [] for m in MODES}
    for i, net in enumerate(networks):
        seed = EVAL_POOL_SEED + args.first + i
        order = MODES if i % 2 == 0 else MODES[::-1]  # alternate: load drifts hit both
        for mode in order:
            results[mode].append(run_episode(envs[mode], net, seed))
        rc, re_ = results["contact"][-1], results["everywhere"][-1]
        print(
            f"network {args.first + i}: contact {rc['success']} {rc['decisions']} dec "
            f"{rc['reset_s'] + rc['steps_s']:.1f} s | everywhere {re_['success']} "
            f"{re_['decisions']} dec {re_['reset_s'] + re_['steps_s']:.1f} s",
            flush=True,
        )
    for env in envs.values():
        env.close()
    figures, markdown = summarise(results)
    print("\n" + markdown)
    if args.json:
        atomic_write_text(args.json, json.dumps({"figures": figures, "episodes": results}))
    if args.write_docs:
        from benchmarks.report import write_section

        write_section("full fidelity", markdown)


if __name__ == "__main__":
    main()
