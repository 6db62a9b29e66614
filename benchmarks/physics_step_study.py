"""The largest physics step and control period at which the primitives still hold (issue 20).

Full fidelity spends its time in control ticks (the executor's per-tick work) and physics steps
(``mj_step``); both fall as the physics step (``timestep``, s) and the control period
(``control_dt``, s, a whole number of physics steps) grow. This study measures, per grid point
(physics step x control period; the period is rounded to a whole number of steps, the period in
use is printed), in one run against the reference point (``REFERENCE``: 2 ms / 20 ms, the
defaults before this study):

1. tolerance cases (sampled from ``benchmarks/bench_primitives.py``'s study): per cell
   (90 deg mitre bend, diameter, roll direction, option field, sign) the largest error
   ``take_turn`` survives is found by bisection at the reference; the grid point passes the
   cell if it survives that error too (its tolerance is no smaller) and the error-free turn;
2. jam cases with their expected outcomes (from the executor, primitives and jam-fix tests):
   wrong options jam or are blocked, a tight turn in a wide bend jams, a 45 mm bore jams at its
   mouth, a jammed turn backs out and re-clamps on the axis, the right options pass (bends,
   junctions, the smallest pipe's tee branch, a long bend seen in part) and leave the robot on
   the axis. Every case also fails on a diverged simulation or a module pushed off its path
   where no jam is expected. Over these cases the near-contact selection
   (:class:`pipe_env.world.NearContacts`) must not overrun: no robot geom may move further
   than its reach between two selections (a contact MuJoCo's automatic collisions have could
   then be missed);
3. seeded full-fidelity RoutePlanner episodes (held-out 6-fitting 3D networks, ``improved``
   detector, ``physics="contact"``) at the reference and at the candidates (the largest grid
   points that pass 1 and 2; every point with ``--episodes-everywhere``): success
   and jams no worse than the reference's, no diverged simulation, no module pushed off its
   path and no near-contact overrun.

Per grid point it prints pass/fail of each check, control ticks (physics / kinematic) and
physics steps per decision, decisions/s and their ratio to the reference measured in the same
run (episodes interleaved point by point, so load drifts hit every point alike), and the same
per second of the process's CPU time (steadier than the wall clock on a shared machine).

The margin: a grid point is adopted only if it passes everything and the next larger physics
step at its period passes checks 1 and 2 too (one grid step of margin in the step, where the
cases fail gradually: the front stalls nearer and nearer a bore's mouth). The period's limit
is the near-contact reach, a sharp one (the V folding at its full rate moves its apex about
0.1 m/s: 6 mm, the reach, in 60 ms); the adopted period is the longest without an overrun.

Time compression (``--speedups 1 1.5 2 3 4``): every grid point is also run at each time
compression k (``Executor(time_compression=k)``, ``PhysicalPlant(time_compression=k)``: the
quasi-static motions run k times faster in physics, the clock keeps the robot's nominal speeds;
the rule is at ``primitives.executor.TIME_COMPRESSION``). The checks are the same; the margin
is then one grid step in k: a k is adopted only if the next larger k passes checks 1 and 2 too.

Usage: python benchmarks/physics_step_study.py [--timesteps 0.002 0.003 ...]
       [--periods 0.02 0.04 ...] [--speedups 1 2 ...] [--episodes 3] [--candidates 2]
       [--episodes-everywhere] [--quick] [--json out.json] [--write-docs]
       (--quick: two grid points, one tolerance cell, three jam cases, no episodes: a smoke
       test of the study itself)
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.bench_primitives import SEARCH_MAX, survives  # noqa: E402
from detector.atomic import atomic_write_text  # noqa: E402
from detector.options import StructureOption  # noqa: E402
from pipe_env import layouts  # noqa: E402
from pipe_env.ground_truth import (  # noqa: E402
    fitting_ahead,
    option_angles,
    structures_ahead,
    ways_at,
)
from pipe_env.network import PipeNetwork  # noqa: E402
from pipe_env.routing import locate  # noqa: E402
from primitives.executor import Executor, SequenceOutcome  # noqa: E402
from primitives.sequences import Sequence, back_out, for_option, take_turn  # noqa: E402
from primitives.steps import Drive, Unclamp  # noqa: E402

#: The grid, s.
TIMESTEPS = (0.002, 0.003, 0.004, 0.005, 0.006, 0.008)
PERIODS = (0.02, 0.04, 0.06, 0.1)
#: The defaults before this study (physics step, control period), s.
REFERENCE = (0.002, 0.02)
#: Time compressions (``--speedups``; the reference runs at 1).
SPEEDUPS = (1.0,)
#: Tolerance cells: (diameter m, roll direction deg, field, sign); bisection steps at the
#: reference.
TOLERANCE_CELLS = (
    (0.06, 0.0, "distance", -1.0),
    (0.06, 135.0, "distance", 1.0),
    (0.12, 0.0, "direction", 1.0),
    (0.09, 135.0, "angle", -1.0),
)
TOLERANCE_ITERATIONS = 3
#: Words of a jam reason that mean the physics failed, not the motion.
UNSTABLE = ("diverged", "pushed")
#: The RoutePlanner episodes' networks (as ``benchmarks/bench_full_fidelity.py``).
NETWORK_CONFIG = {"n_fittings": 6, "planar": False, "allow_loops": True}
OUTPUT: list[str] = []


def emit(line: str = "") -> None:
    """Print ``line`` and keep it for the docs section."""
    print(line, flush=True)
    OUTPUT.append(line)


@dataclass(frozen=True)
class Point:
    """A grid point: physics step and nominal control period, s; time compression k."""

    timestep: float
    period: float
    speedup: float = 1.0

    @property
    def args(self) -> dict[str, float]:
        """The executor's arguments."""
        return {
            "timestep": self.timestep,
            "control_dt": self.period,
            "time_compression": self.speedup,
        }

    @property
    def substeps(self) -> int:
        """Physics steps per control tick (as the executor rounds them)."""
        return max(1, int(round(self.period / self.timestep)))

    @property
    def period_used(self) -> float:
        """The control period the executor runs at, s."""
        return self.substeps * self.timestep

    def label(self) -> str:
        base = f"{self.timestep * 1000:g}/{self.period_used * 1000:g}"
        return base if self.speedup == 1.0 else f"{base} x{self.speedup:g}"


@dataclass
class Result:
    """What a grid point did: check name -> passed (with a note), wall time of the cases."""

    point: Point
    checks: dict[str, bool] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)
    case_wall: float = 0.0
    case_ticks: int = 0
    episodes: list[dict[str, Any]] = field(default_factory=list)
    #: every case ran (a point's cases stop at the first failure unless ``--all-cases``)
    complete: bool = True

    @property
    def cases_pass(self) -> bool:
        return self.complete and all(
            v for k, v in self.checks.items() if not k.startswith("episodes")
        )

    @property
    def all_pass(self) -> bool:
        return all(self.checks.values())


# ---------------------------------------------------------------- cases
#: The executors the current grid point's jam cases built (their near-contact counters).
_BUILT: list[Executor] = []


def _executor(net: PipeNetwork, point: Point) -> Executor:
    ex = Executor.for_network(
        net,
        lidar=None,
        timestep=point.timestep,
        control_dt=point.period,
        time_compression=point.speedup,
    )
    _BUILT.append(ex)
    return ex


def near_contact_check(executors: list[Executor]) -> tuple[bool, str]:
    """No overrun of the near-contact selection (a robot geom moving further than the
    selection's reach between two selections: a contact the automatic collisions have could be
    missed) in any of ``executors``; the note gives overruns, fallbacks and selections/tick."""
    near = [ex.near for ex in executors if ex.near is not None]
    overruns = sum(n.overruns for n in near)
    ticks = max(1, sum(ex.physics_ticks for ex in executors))
    note = (
        f"overruns {overruns}, fallbacks {sum(n.fallbacks for n in near)}, selections per "
        f"tick {sum(n.selections for n in near) / ticks:.2f}"
    )
    return overruns == 0, note


def _stable(out: SequenceOutcome) -> bool:
    return not any(w in out.reason for w in UNSTABLE)


def _on_axis(net: PipeNetwork, ex: Executor, tol: float = 0.002) -> bool:
    ends = (0, ex.config.n_modules - 1)
    return all(
        net.centreline.nearest(ex.robot.module_pose(i).position).distance < tol for i in ends
    )


def _ways(net: PipeNetwork, ex: Executor) -> list[tuple[StructureOption, str]]:
    """Ground-truth options of the fitting ahead, each with the run it leads into."""
    pose = ex.robot.sensor_pose()
    return ways_at(net, *fitting_ahead(net, pose), pose)


def _option_case(
    net: PipeNetwork, point: Point, way: int = 0, errors: dict[str, float] | None = None
) -> tuple[SequenceOutcome, bool, Executor]:
    """Run the sequence for ground-truth way ``way`` with ``errors`` added to its fields;
    returns the outcome, whether the robot ends in that way's run, and the executor."""
    ex = _executor(net, point)
    true, run = _ways(net, ex)[way]
    option = replace(true, **{k: getattr(true, k) + v for k, v in (errors or {}).items()})
    out = ex.run(for_option(option, ex.robot.clamped_diameter()))
    return out, locate(net, ex.robot.sensor_pose())[0].run_id == run, ex


def _passes(net: PipeNetwork, point: Point, way: int = 0) -> tuple[bool, str, int]:
    """The way's ground-truth option passes: done, in the way's run, the robot on its axis."""
    out, arrived, ex = _option_case(net, point, way)
    ok = out.status == "done" and arrived and _on_axis(net, ex, 0.004)
    return ok, f"{out.status} {out.reason}".strip(), ex.physics_ticks


def _jams(net: PipeNetwork, point: Point, **errors: float) -> tuple[bool, str, int]:
    """The option with ``errors`` jams (or is refused) without the simulation diverging."""
    out, _, ex = _option_case(net, point, errors=errors)
    ok = out.status in ("jammed", "blocked") and "diverged" not in out.reason
    return ok, f"{out.status} {out.reason}".strip(), ex.physics_ticks


def case_bore(point: Point) -> tuple[bool, str, int]:
    """Driving into a 45 mm bore jams at its mouth (the front never in the bore)."""
    net = layouts.reducer(0.1, 0.045, taper_length=0.1, distance=0.5)
    ex = _executor(net, point)
    out = ex.run(Sequence("force_in", (Unclamp(), Drive(1.2))))
    front = ex.robot.front_pose().position
    mouth = float(net.geometry["s"].reference_point("r_out0")[0])
    ok = out.status == "jammed" and "stalled" in out.reason
    short = mouth - (front[0] + 0.5 * ex.config.pitch)
    ok = ok and short > 0.0 and out.travelled < 0.7
    note = (
        f"{out.status}, front wheels {short * 1000:.1f} mm short of the mouth (> 0), "
        f"travelled {out.travelled * 1000:.0f} mm (< 700)"
    )
    return ok, note, ex.physics_ticks


def case_back_out(point: Point) -> tuple[bool, str, int]:
    """A turn with the wrong roll jams; backing out re-clamps on the axis, unrolled."""
    net = layouts.mitre_bend(0.1, math.pi / 2, 0.0)
    ex = _executor(net, point)
    o = structures_ahead(net, ex.robot.sensor_pose(), 5.0)[0]
    out = ex.run(for_option(replace(o, direction=o.direction + 1.7), incoming_diameter=0.1))
    back = ex.run(back_out(out.travelled, diameter=0.1))
    ok = out.status == "jammed" and back.status == "done" and abs(ex.robot.roll_angle) < 0.05
    ok = ok and abs(ex.robot.clamped_diameter() - 0.1) < 0.0015 and _on_axis(net, ex)
    return ok, f"{out.status}, back {back.status} {back.reason}".strip(), ex.physics_ticks


def case_long_bend_seen_in_part(point: Point) -> tuple[bool, str, int]:
    """A 90 deg bend of 2.7 D radius taken as the 55 deg of it a sweep sees is passed."""
    diameter, radius = 0.1057, 0.2903
    net = layouts.long_bend(
        diameter, math.pi / 2, math.radians(45), radius_factor=radius / diameter
    )
    ex = _executor(net, point)
    pose = ex.robot.sensor_pose()
    node, entry = fitting_ahead(net, pose)
    g = net.geometry[node]
    travel = -g.port(entry).axis
    out_port = next(p for p in g.ports if p.run_id != entry)
    angle, direction = option_angles(travel, out_port.axis, pose)
    vertex = float((g.reference_point(entry) - pose.position) @ travel)
    seen = math.radians(55.0)
    distance = vertex - radius * math.tan(0.5 * angle) + radius * math.tan(0.5 * seen)
    option = StructureOption("bend", distance, diameter, direction, seen, bend_radius=radius)
    out = ex.run(take_turn(option, ex.robot.clamped_diameter()))
    ok = out.status == "done" and locate(net, ex.robot.sensor_pose())[0].run_id == out_port.run_id
    return ok, f"{out.status} {out.reason}".strip(), ex.physics_ticks


Case = Callable[[Point], tuple[bool, str, int]]


def _passing(make: Callable[[], PipeNetwork], way: int = 0) -> Case:
    return lambda p: _passes(make(), p, way)


def _jamming(make: Callable[[], PipeNetwork], **errors: float) -> Case:
    return lambda p: _jams(make(), p, **errors)


def jam_cases() -> dict[str, Case]:
    """Case name (with its expected outcome) -> case."""
    bend, long_bend = layouts.mitre_bend, layouts.long_bend
    right = math.pi / 2
    return {
        "45 mm bore jams at mouth": case_bore,
        "direction +90 jams": _jamming(lambda: bend(0.09, right, 0.0), direction=right),
        "tee branch 57 mm passes": _passing(
            lambda: layouts.t_junction(0.0571, direction=math.pi), 1
        ),
        "bend 90 passes": _passing(lambda: bend(0.09, right, 0.0)),
        "distance +D jams": _jamming(lambda: bend(0.12, right, math.radians(270)), distance=0.12),
        "long bend seen in part passes": case_long_bend_seen_in_part,
        "jammed turn backs out on axis": case_back_out,
        "distance -D jams": _jamming(lambda: bend(0.06, right / 2, right), distance=-0.06),
        "bend 90 in 60 mm passes": _passing(lambda: bend(0.06, right, right)),
        "tight turn in wide bend jams": _jamming(
            lambda: long_bend(0.1, right, math.radians(45), radius_factor=3.0),
            bend_radius=-0.3,
        ),
        "long bend 90 passes": _passing(lambda: long_bend(0.09, right, math.radians(225))),
        "cross way passes": _passing(
            lambda: layouts.cross_junction(0.12, direction=math.radians(75)), 2
        ),
    }


# ---------------------------------------------------------------- tolerance
def _cell_net(cell: tuple[float, float, str, float]) -> PipeNetwork:
    return layouts.mitre_bend(cell[0], math.pi / 2, math.radians(cell[1]))


def reference_bounds(
    cells: tuple[tuple[float, float, str, float], ...], iterations: int
) -> dict[tuple[float, float, str, float], float]:
    """Per cell, the largest error (signed) take_turn survives at the reference (bisection:
    the largest survived error with the next tested one failing)."""
    ref = Point(*REFERENCE)
    bounds = {}
    for cell in cells:
        d, _, fld, sign = cell
        lo, hi = 0.0, SEARCH_MAX[fld](d)
        net = _cell_net(cell)
        if survives(net, fld, sign * hi, **ref.args):
            lo = hi
        else:
            for _ in range(iterations):
                mid = 0.5 * (lo + hi)
                if survives(_cell_net(cell), fld, sign * mid, **ref.args):
                    lo = mid
                else:
                    hi = mid
        bounds[cell] = sign * lo
    return bounds


def _cell_name(cell: tuple[float, float, str, float], error: float) -> str:
    d, r, fld, _ = cell
    size = f"{error * 1000:+.0f}mm" if fld == "distance" else f"{math.degrees(error):+.0f}d"
    return f"tol {d * 1000:.0f}mm r{r:.0f} {fld} {size}"


def _tolerance_case(cell: tuple[float, float, str, float], error: float) -> Case:
    def case(point: Point) -> tuple[bool, str, int]:
        ok = survives(_cell_net(cell), cell[2], error, **point.args)
        return ok, "survived" if ok else "failed", 0

    return case


def check_point(
    point: Point,
    bounds: dict[tuple[float, float, str, float], float],
    cases: dict[str, Case],
    fail_fast: bool = True,
) -> Result:
    """Run the jam cases and the tolerance cells (at the reference's bounds) at ``point``;
    with ``fail_fast`` the rest are skipped after the first failure (the point fails)."""
    res = Result(point)
    todo = dict(cases)
    todo.update({_cell_name(c, e): _tolerance_case(c, e) for c, e in bounds.items()})
    _BUILT.clear()
    t0 = time.perf_counter()
    for name, case in todo.items():
        ok, note, ticks = case(point)
        res.checks[name], res.notes[name] = bool(ok), note
        res.case_ticks += ticks
        if fail_fast and not ok and point != Point(*REFERENCE):
            res.complete = False
            break
    else:
        name = "near contacts: no overrun"
        res.checks[name], res.notes[name] = near_contact_check(_BUILT)
    _BUILT.clear()
    res.case_wall = time.perf_counter() - t0
    return res


# ---------------------------------------------------------------- episodes
def _episode_env(point: Point) -> gym.Env:
    """A PipeNav full-fidelity environment whose plants run at ``point``."""
    from pipe_env.envs.env import PipeNavEnv
    from pipe_env.envs.plant_full import PhysicalPlant
    from pipe_env.generator import NetworkConfig

    class TimedEnv(PipeNavEnv):
        def _make_plant(self, network: PipeNetwork) -> Any:
            c = self.config
            return PhysicalPlant(
                network,
                c.detector,
                c.trigger_distance,
                lidar=c.lidar_spec,
                misalignment=c.misalignment,
                scan_image=c.scan_image,
                physics=c.physics,
                timestep=point.timestep,
                control_dt=point.period,
                time_compression=point.speedup,
            )

    env = TimedEnv(
        fidelity="full",
        detector="improved",
        network_config=NetworkConfig.from_dict(NETWORK_CONFIG),
        physics="contact",
    )
    return gym.wrappers.TimeLimit(env, max_episode_steps=64)


def run_episode(env: gym.Env, network: PipeNetwork, seed: int) -> dict[str, Any]:
    """One RoutePlanner episode: outcome, decisions, ticks, physics steps, wall time, notes."""
    from agents.scripted import make_agent

    base: Any = env.unwrapped
    agent = make_agent("route_planner", env)
    notes: list[str] = []
    t0, c0 = time.perf_counter(), time.process_time()
    obs, info = env.reset(seed=seed, options={"network": network})
    agent.reset()
    done = bool(base.terminated or base.truncated)
    while not done:
        obs, _, term, trunc, info = env.step(agent.act(obs, info))
        notes += [str(v) for k, v in info.items() if k.endswith("_note")]
        done = term or trunc
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    ex = base.plant.executor
    return {
        "success": bool(info["is_success"]),
        "jams": int(info["jams"]),
        "decisions": int(info["decisions"]),
        "wall_s": wall,
        "cpu_s": cpu,
        "physics_ticks": int(ex.physics_ticks),
        "kinematic_ticks": int(ex.kinematic_ticks),
        "mj_steps": int(ex.physics_ticks * ex.substeps),
        "overruns": int(ex.near.overruns) if ex.near is not None else 0,
        "unstable": [n for n in notes if any(w in n for w in UNSTABLE)],
    }


def warm_up() -> None:
    """Sense and decide once, untimed: the detector's compiled kernels are built on first use
    (tens of seconds), which would otherwise count against the first point timed."""
    from pipe_env.envs.plant_full import PhysicalPlant
    from pipe_env.routing import EdgePosition, edge_length

    net = layouts.t_junction(0.09, direction=0.0, distance=0.5)
    plant = PhysicalPlant(net, detector="improved")
    plant.advance(EdgePosition("r_out1", 0.45, edge_length(net, "r_out1")))


def run_episodes(results: list[Result], n: int) -> None:
    """``n`` seeded episodes at every point of ``results``, interleaved point by point."""
    from agents.evaluate import EVAL_POOL_SEED, held_out_networks
    from pipe_env.generator import NetworkConfig

    networks = held_out_networks(NetworkConfig.from_dict(NETWORK_CONFIG), n)
    warm_up()
    envs = [_episode_env(r.point) for r in results]
    for i, net in enumerate(networks):
        order = list(range(len(results)))
        if i % 2:
            order.reverse()
        for k in order:
            results[k].episodes.append(run_episode(envs[k], net, EVAL_POOL_SEED + i))
            e = results[k].episodes[-1]
            print(
                f"  network {i} at {results[k].point.label()}: success {e['success']} "
                f"jams {e['jams']} decisions {e['decisions']} {e['wall_s']:.0f} s",
                flush=True,
            )
    for env in envs:
        env.close()


def episode_figures(res: Result) -> dict[str, float]:
    """Totals over a point's episodes: success, jams, per-decision ticks and steps, speed."""
    eps = res.episodes
    dec = max(1, sum(e["decisions"] for e in eps))
    wall = sum(e["wall_s"] for e in eps)
    cpu = sum(e.get("cpu_s", math.nan) for e in eps)
    return {
        "success": sum(e["success"] for e in eps),
        "jams": sum(e["jams"] for e in eps),
        "decisions": dec,
        "physics_ticks_per_decision": sum(e["physics_ticks"] for e in eps) / dec,
        "kinematic_ticks_per_decision": sum(e["kinematic_ticks"] for e in eps) / dec,
        "mj_steps_per_decision": sum(e["mj_steps"] for e in eps) / dec,
        "decisions_per_s": dec / wall if wall > 0 else math.nan,
        "decisions_per_cpu_s": dec / cpu if cpu > 0 else math.nan,
        "unstable": sum(len(e["unstable"]) for e in eps),
        "overruns": sum(e.get("overruns", 0) for e in eps),
    }


def judge_episodes(res: Result, ref: Result) -> None:
    """Episodes pass: success and jams no worse than the reference's, no unstable physics, no
    near-contact overrun."""
    f, r = episode_figures(res), episode_figures(ref)
    ok = f["success"] >= r["success"] and f["jams"] <= r["jams"]
    ok = ok and f["unstable"] == 0 and f["overruns"] == 0
    res.checks["episodes"] = ok
    res.notes["episodes"] = (
        f"success {f['success']} (ref {r['success']}), jams {f['jams']} (ref {r['jams']}), "
        f"unstable {f['unstable']}, near-contact overruns {f['overruns']}"
    )


# ---------------------------------------------------------------- the study
def grid(
    timesteps: list[float],
    periods: list[float],
    speedups: tuple[float, ...] | list[float] = SPEEDUPS,
) -> list[Point]:
    """Grid points, the reference first; periods shorter than the step are skipped."""
    pts = [Point(*REFERENCE)]
    seen = {(pts[0].timestep, pts[0].substeps, 1.0)}
    for ts in timesteps:
        for cp in periods:
            for k in speedups:
                p = Point(ts, cp, k)
                if cp >= ts and (ts, p.substeps, k) not in seen:
                    seen.add((ts, p.substeps, k))
                    pts.append(p)
    return pts


def larger_step(p: Point, timesteps: list[float]) -> Point | None:
    """The next larger physics step of the grid at ``p``'s control period (None: none)."""
    bigger = [t for t in timesteps if t > p.timestep]
    return Point(min(bigger), p.period, p.speedup) if bigger else None


def larger_speedup(p: Point, speedups: list[float]) -> Point | None:
    """The next larger time compression of the grid at ``p``'s step and period (None:
    none)."""
    bigger = [k for k in speedups if k > p.speedup]
    return Point(p.timestep, p.period, min(bigger)) if bigger else None


def margin_ok(
    res: Result,
    by_point: dict[Point, Result],
    timesteps: list[float],
    speedups: list[float] | None = None,
) -> bool:
    """``res`` passes its cases and so does the next larger physics step at its period (one
    grid step of margin in the step, where the cases fail gradually: the robot's front stalls
    nearer and nearer a bore's mouth); studying time compressions (``speedups``, more than
    one), the next larger k at its step and period instead. The period's limit is the
    near-contact selection's reach, a sharp one: a period passes it (no overrun) or not."""
    if speedups is not None and len(speedups) > 1:
        near = larger_speedup(res.point, speedups)
    else:
        near = larger_step(res.point, timesteps)
    return res.cases_pass and near in by_point and by_point[near].cases_pass


def _size(r: Result) -> tuple[float, float, float]:
    return (r.point.period_used * r.point.speedup, r.point.period_used, r.point.timestep)


def adopt(
    results: list[Result], timesteps: list[float], speedups: list[float] | None = None
) -> Result | None:
    """The largest point (nominal time per tick, control period, then physics step) that
    passes everything, the episodes included, with one grid step of margin in the step (or in
    k, see :func:`margin_ok`)."""
    by_point = {r.point: r for r in results}
    ok = [
        r
        for r in results
        if r.all_pass and r.episodes and margin_ok(r, by_point, timesteps, speedups)
    ]
    return max(ok, key=_size) if ok else None


def print_checks(results: list[Result]) -> None:
    """One line per grid point: P/F per check (columns named below the table)."""
    names = [n for n in results[0].checks if n != "episodes"]
    emit("Checks per grid point (P pass, F fail; columns below)")
    emit("```")
    emit(
        f"{'step/period ms':>20s} {'steps/tick':>10s}  "
        + " ".join(f"{i + 1:>2d}" for i in range(len(names)))
    )
    for r in results:
        marks = {True: "P", False: "F", None: "-"}
        cells = " ".join(f"{marks[r.checks.get(n)]:>2s}" for n in names)
        cells += f"   episodes {marks[r.checks.get('episodes')]}"
        emit(f"{r.point.label():>20s} {r.point.substeps:10d}  {cells}")
    for i, n in enumerate(names):
        emit(f"  {i + 1:2d}: {n}")
    emit("  (-: not run: a point's cases stop at its first failure)")
    for r in results:
        for n in [*names, "episodes"]:
            if r.checks.get(n) is False:
                emit(f"  {r.point.label()} failed {n}: {r.notes.get(n, '')}")
    emit("```")


def print_speed(results: list[Result], ref: Result) -> None:
    """Cases' ticks and wall time, and the episodes' figures, with ratios to the reference."""
    emit()
    emit(
        "| step/period ms | cases | case ticks | case wall / ref | episodes | success | jams "
        "| physics ticks/dec | kinematic ticks/dec | mj_steps/dec | decisions/s | / ref "
        "| decisions/CPU-s | / ref |"
    )
    emit("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rf = episode_figures(ref) if ref.episodes else None
    for r in results:
        row = (
            f"| {r.point.label()} | {'pass' if r.cases_pass else 'FAIL'} | {r.case_ticks} | "
            f"{r.case_wall / ref.case_wall:.2f} |"
        )
        if r.episodes and rf is not None:
            f = episode_figures(r)
            row += (
                f" {'pass' if r.checks.get('episodes') else 'FAIL'} | {f['success']}/"
                f"{len(r.episodes)} | {f['jams']} | {f['physics_ticks_per_decision']:.0f} | "
                f"{f['kinematic_ticks_per_decision']:.0f} | {f['mj_steps_per_decision']:.0f} | "
                f"{f['decisions_per_s']:.3f} | {f['decisions_per_s'] / rf['decisions_per_s']:.2f} |"
                f" {f['decisions_per_cpu_s']:.3f} |"
                f" {f['decisions_per_cpu_s'] / rf['decisions_per_cpu_s']:.2f} |"
            )
        else:
            row += " - | - | - | - | - | - | - | - | - | - |"
        emit(row)


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--timesteps", type=float, nargs="+", default=list(TIMESTEPS))
    parser.add_argument("--periods", type=float, nargs="+", default=list(PERIODS))
    parser.add_argument(
        "--speedups", type=float, nargs="+", default=list(SPEEDUPS), help="time compressions k"
    )
    parser.add_argument("--episodes", type=int, default=3, help="networks per point")
    parser.add_argument("--candidates", type=int, default=2, help="points given episodes")
    parser.add_argument("--episodes-everywhere", action="store_true")
    parser.add_argument("--quick", action="store_true", help="a smoke test of the study")
    parser.add_argument(
        "--all-cases", action="store_true", help="run every case (not only to a first failure)"
    )
    parser.add_argument("--json", default=None)
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args(argv)
    if any(not 1.0 <= k <= 8.0 for k in args.speedups):
        parser.error(f"--speedups = {args.speedups}; allowed: each in [1, 8]")
    if args.episodes < 0 or args.candidates < 0:
        parser.error(
            f"--episodes = {args.episodes}, --candidates = {args.candidates}; allowed: >= 0"
        )
    if args.quick:
        args.timesteps, args.periods, args.episodes = [0.002, 0.004], [0.02, 0.04], 0
    return args


def study(args: argparse.Namespace) -> tuple[list[Result], Result | None]:
    """Run the study; returns every point's result (the reference first) and the adopted."""
    cases = jam_cases()
    cells: tuple[tuple[float, float, str, float], ...] = TOLERANCE_CELLS
    if args.quick:
        cases = {k: cases[k] for k in list(cases)[:3]}
        cells = cells[:1]
    t0 = time.perf_counter()
    bounds = reference_bounds(cells, 1 if args.quick else TOLERANCE_ITERATIONS)
    print(
        f"reference tolerance bounds ({time.perf_counter() - t0:.0f} s): "
        + "; ".join(_cell_name(c, e) for c, e in bounds.items()),
        flush=True,
    )
    results = []
    for p in grid(args.timesteps, args.periods, args.speedups):
        results.append(check_point(p, bounds, cases, not args.all_cases))
        r = results[-1]
        print(
            f"{p.label()}: cases {'pass' if r.cases_pass else 'FAIL'} "
            f"({sum(r.checks.values())}/{len(r.checks)}) {r.case_wall:.0f} s",
            flush=True,
        )
    ref = results[0]
    if args.episodes:
        chosen = [r for r in results[1:] if args.episodes_everywhere or r.cases_pass]
        chosen = sorted(chosen, key=_size, reverse=True)
        if not args.episodes_everywhere:
            chosen = chosen[: args.candidates]
        run_episodes([ref, *chosen], args.episodes)
        for r in [ref, *chosen]:
            judge_episodes(r, ref)
    return results, adopt(results, args.timesteps, args.speedups)


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    t0 = time.perf_counter()
    results, chosen = study(args)
    print_checks(results)
    print_speed(results, results[0])
    emit()
    if chosen is None:
        emit("adopted: none (no point passes everything with one grid step of margin)")
    else:
        emit(
            f"adopted: physics step {chosen.point.timestep * 1000:g} ms, control period "
            f"{chosen.point.period_used * 1000:g} ms ({chosen.point.substeps} steps per tick), "
            f"time compression {chosen.point.speedup:g}"
        )
    print(f"total wall time {time.perf_counter() - t0:.0f} s")
    if args.json:
        atomic_write_text(
            args.json,
            json.dumps(
                [
                    {
                        "timestep": r.point.timestep,
                        "period": r.point.period_used,
                        "speedup": r.point.speedup,
                        "checks": r.checks,
                        "notes": r.notes,
                        "case_wall": r.case_wall,
                        "case_ticks": r.case_ticks,
                        "episodes": r.episodes,
                    }
                    for r in results
                ],
                default=float,
            ),
        )
    if args.write_docs:
        from benchmarks.report import write_section

        given = list(argv if argv is not None else sys.argv[1:])
        if "--json" in given:  # (where the figures were saved is no part of the command)
            k = given.index("--json")
            del given[k : k + 2]
        argv_ = [a for a in given if a != "--write-docs"]
        command = " ".join(["python benchmarks/physics_step_study.py", *argv_])
        name = "time compression" if len(args.speedups) > 1 else "physics step"
        write_section(name, "\n".join([f"`{command}`", "", *OUTPUT]))
    return 0 if results and all(r.cases_pass for r in results[:1]) else 1


if __name__ == "__main__":
    raise SystemExit(main())
