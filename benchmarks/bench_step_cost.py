"""The cost of one physics step (``mj_step``) in full fidelity, and what solver settings do to it.

Runs seeded primitive scenarios in typical states (issue 20) with the executor, one MuJoCo step
at a time, and per state (scenario x primitive step op: ``drive`` clamped in a run, in a bend,
at a T-junction, ``roll``/``bend`` of a turn, ``clamp``) prints:

- microseconds per ``mj_step`` (the thread's CPU time around each step: steadier than the wall
  clock on a shared machine; one core, the same run),
- active contacts (``data.ncon``), constraint rows (``data.nefc``) and solver iterations
  (``data.solver_niter[0]``), mean and max,
- MuJoCo's own split of the step (``data.timer``; a time callback is installed for it, which
  adds a little to every step: the split is a share within the run).

``--variants`` runs the same scenarios with other solver settings (:data:`VARIANTS`: each a
change of ``model.opt`` applied after the world is built) side by side with the model's own
settings (``model``: the reference, measured in the same run, scenarios interleaved variant by
variant so load drifts hit all alike); ``before`` is the settings before this benchmark
(island discovery on: see :func:`pipe_env.world.build_world`). Per variant: µs/step and its
ratio to the reference, mean solver iterations, each scenario's outcome (status) and the
largest distance between its front module's path and the reference's at the same control tick
(mm): a variant that changes no outcome and keeps the paths within a fraction of a millimetre
changes the physics by no more than its tolerance.

What it found (issue 20): a step holds the six welds of the modules to their drive targets
(36 constraint rows) and rarely more than four contacts; Newton solves it in one iteration, so
the solver's iterations and tolerance, warm start, cones, CG/PGS and the Jacobian's layout
(dense, MuJoCo's choice for 17 degrees of freedom; sparse is slower) cannot make it cheaper.
Without the welds a step costs about half, without any constraint about a third: the step is
the fixed cost of a small constrained model. Island discovery (one island: the robot) was
pure cost and is off, bit for bit the same physics; disabling gravity (cancelled by the
modules' full compensation) saves a few per cent more but changes the last bits (the golden
digests), so it stays on.

Usage: python benchmarks/bench_step_cost.py [--variants model,before,tol1e-6,...] [--repeat 2]
       [--json out.json] [--write-docs]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from detector.atomic import atomic_write_text  # noqa: E402
from pipe_env import layouts  # noqa: E402
from pipe_env.ground_truth import fitting_ahead, ways_at  # noqa: E402
from pipe_env.network import PipeNetwork  # noqa: E402
from primitives.executor import Executor  # noqa: E402
from primitives.sequences import Sequence, for_option  # noqa: E402
from primitives.steps import Drive, Step  # noqa: E402

#: MuJoCo's timers of a step's parts.
TIMERS = {
    "collision": mujoco.mjtTimer.mjTIMER_POS_COLLISION,
    "kinematics": mujoco.mjtTimer.mjTIMER_POS_KINEMATICS,
    "inertia": mujoco.mjtTimer.mjTIMER_POS_INERTIA,
    "constraint making": mujoco.mjtTimer.mjTIMER_POS_MAKE,
    "velocity": mujoco.mjtTimer.mjTIMER_VELOCITY,
    "constraint solving": mujoco.mjtTimer.mjTIMER_CONSTRAINT,
    "integration": mujoco.mjtTimer.mjTIMER_ADVANCE,
}


def _dsbl(*bits: mujoco.mjtDisableBit) -> Callable[[mujoco.MjOption], None]:
    def apply(o: mujoco.MjOption) -> None:
        for b in bits:
            o.disableflags |= int(b)

    return apply


def _cleared(*bits: mujoco.mjtDisableBit) -> Callable[[mujoco.MjOption], None]:
    def apply(o: mujoco.MjOption) -> None:
        for b in bits:
            o.disableflags &= ~int(b)

    return apply


def _set(**values: Any) -> Callable[[mujoco.MjOption], None]:
    def apply(o: mujoco.MjOption) -> None:
        for k, v in values.items():
            setattr(o, k, v)

    return apply


D = mujoco.mjtDisableBit
#: Variant name -> change of ``model.opt`` (``model``: none, the reference).
VARIANTS: dict[str, Callable[[mujoco.MjOption], None]] = {
    "model": lambda o: None,
    # the settings before this benchmark: island discovery on
    "before": _cleared(D.mjDSBL_ISLAND),
    "tol1e-6": _set(tolerance=1e-6),
    "tol1e-5": _set(tolerance=1e-5),
    "iter10": _set(iterations=10, ls_iterations=10),
    "sparse": _set(jacobian=int(mujoco.mjtJacobian.mjJAC_SPARSE)),
    "dense": _set(jacobian=int(mujoco.mjtJacobian.mjJAC_DENSE)),
    "elliptic": _set(cone=int(mujoco.mjtCone.mjCONE_ELLIPTIC)),
    "cg": _set(solver=int(mujoco.mjtSolver.mjSOL_CG)),
    "pgs": _set(solver=int(mujoco.mjtSolver.mjSOL_PGS)),
    "nowarmstart": _dsbl(D.mjDSBL_WARMSTART),
    "nomidphase": _dsbl(D.mjDSBL_MIDPHASE),
    "nofilterparent": _dsbl(D.mjDSBL_FILTERPARENT),
    "nonativeccd": _dsbl(D.mjDSBL_NATIVECCD),
    "nomulticcd": _dsbl(D.mjDSBL_MULTICCD),
    "norefsafe": _dsbl(D.mjDSBL_REFSAFE),
    "noeulerdamp": _dsbl(D.mjDSBL_EULERDAMP),
    "implicitfast": _set(integrator=int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST)),
    # the modules are fully gravity-compensated: gravity and compensation cancel to rounding
    "nogravity": _dsbl(D.mjDSBL_GRAVITY),
}


def _way(net: PipeNetwork, ex: Executor, way: int) -> Sequence:
    pose = ex.robot.sensor_pose()
    option, _ = ways_at(net, *fitting_ahead(net, pose), pose)[way]
    return for_option(option, ex.robot.clamped_diameter())


def _drive_in_run(net: PipeNetwork, ex: Executor) -> Sequence:
    return Sequence("drive", (Drive(0.4),))


@dataclass(frozen=True)
class Scenario:
    """A network and the sequence run on it from its start pose."""

    name: str
    network: Callable[[], PipeNetwork]
    sequence: Callable[[PipeNetwork, Executor], Sequence]


SCENARIOS = (
    Scenario("run", lambda: layouts.straight(0.1, 3.0), _drive_in_run),
    Scenario(
        "bend", lambda: layouts.mitre_bend(0.09, math.pi / 2, 0.0), lambda n, e: _way(n, e, 0)
    ),
    Scenario(
        "tee",
        lambda: layouts.t_junction(0.0571, direction=math.pi),
        lambda n, e: _way(n, e, 1),
    ),
    Scenario(
        "long bend",
        lambda: layouts.long_bend(0.09, math.pi / 2, math.radians(225)),
        lambda n, e: _way(n, e, 0),
    ),
)


@dataclass
class Stats:
    """Per-state sums over steps."""

    steps: int = 0
    seconds: float = 0.0
    ncon: list[int] = field(default_factory=list)
    nefc: list[int] = field(default_factory=list)
    niter: list[int] = field(default_factory=list)


@dataclass
class Run:
    """One scenario under one variant."""

    states: dict[str, Stats] = field(default_factory=lambda: defaultdict(Stats))
    front: list[np.ndarray] = field(default_factory=list)
    status: str = ""
    timers: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    step_timer: float = 0.0


class _Instrumented(Executor):
    """The executor with single steps timed and counted per state (the primitive step op)."""

    record: Run = Run()  # replaced per run (the first placing in __init__ goes here)
    label: str = "clamp"

    def _do(self, step: Step, on_scan: Any, rng: np.random.Generator) -> None:
        self.label = step.op
        super()._do(step, on_scan, rng)

    def _physics(self) -> None:
        m, d, st = self.model, self.data, self.record.states[self.label]
        chunks = self.near_steps if self.near is not None else (self.substeps,)
        for n in chunks:
            if self.near is not None:
                self.near.update(d)
            for _ in range(n):
                t0 = time.thread_time()
                mujoco.mj_step(m, d)
                st.seconds += time.thread_time() - t0
                st.steps += 1
                st.ncon.append(d.ncon)
                st.nefc.append(d.nefc)
                st.niter.append(int(d.solver_niter[0]))
        self.physics_ticks += 1
        self.record.front.append(d.xpos[self.robot.body_ids[0]].copy())


def run_scenario(sc: Scenario, variant: str, timers: bool = False) -> Run:
    """Run ``sc`` under ``variant`` (built, then ``model.opt`` changed, then placed again)."""
    net = sc.network()
    rec = Run()
    ex = _Instrumented.for_network(net, lidar=None)
    assert isinstance(ex, _Instrumented)
    ex.record = rec
    ex.label = "clamp"
    VARIANTS[variant](ex.model.opt)
    assert net.start_pose is not None
    ex.place(net.start_pose, float(net.inner_diameter_at(net.start_pose.position)))
    seq = sc.sequence(net, ex)
    if timers:
        mujoco.set_mjcb_time(time.perf_counter)
    try:
        out = ex.run(seq)
    finally:
        if timers:
            mujoco.set_mjcb_time(None)
    rec.status = f"{out.status} {out.reason}".strip()
    for label, k in TIMERS.items():
        rec.timers[label] = float(ex.data.timer[k].duration)
    rec.step_timer = float(ex.data.timer[mujoco.mjtTimer.mjTIMER_STEP].duration)
    return rec


def _summary(rec: Run) -> dict[str, dict[str, float]]:
    out = {}
    for label, st in rec.states.items():
        if not st.steps:
            continue
        out[label] = {
            "steps": st.steps,
            "us_per_step": 1e6 * st.seconds / st.steps,
            "ncon": float(np.mean(st.ncon)),
            "ncon_max": max(st.ncon),
            "nefc": float(np.mean(st.nefc)),
            "nefc_max": max(st.nefc),
            "niter": float(np.mean(st.niter)),
            "niter_max": max(st.niter),
        }
    return out


def _total(rec: Run) -> tuple[int, float, float]:
    steps = sum(s.steps for s in rec.states.values())
    secs = sum(s.seconds for s in rec.states.values())
    iters = sum(sum(s.niter) for s in rec.states.values())
    return steps, secs, iters / max(steps, 1)


def _deviation(a: Run, b: Run) -> float:
    """Largest distance between the front's positions of two runs at the same control tick
    (over the ticks both ran), m."""
    n = min(len(a.front), len(b.front))
    if n == 0:
        return math.inf
    return float(np.max(np.linalg.norm(np.asarray(a.front[:n]) - np.asarray(b.front[:n]), axis=1)))


def emit(lines: list[str], line: str = "") -> None:
    """Print ``line`` and keep it."""
    print(line, flush=True)
    lines.append(line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--variants", default="model,before", help=f"comma-separated of {list(VARIANTS)}"
    )
    parser.add_argument("--repeat", type=int, default=1, help="runs per scenario and variant")
    parser.add_argument("--json", default=None)
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args()
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    bad = [v for v in variants if v not in VARIANTS]
    if bad or not variants:
        parser.error(f"--variants has {bad}; allowed: {', '.join(VARIANTS)}")
    if "model" not in variants:
        variants.insert(0, "model")
    lines: list[str] = []
    # the model's own settings: per-state figures with MuJoCo's timer split
    ref: dict[str, Run] = {sc.name: run_scenario(sc, "model", timers=True) for sc in SCENARIOS}
    emit(lines, "### Step cost per state (the model's settings)\n")
    emit(lines, "| scenario | state | steps | us/step | ncon | nefc | solver iterations |")
    emit(lines, "|---|---|---|---|---|---|---|")
    for name, rec in ref.items():
        for label, s in _summary(rec).items():
            emit(
                lines,
                f"| {name} | {label} | {s['steps']} | {s['us_per_step']:.0f} | "
                f"{s['ncon']:.1f} (max {s['ncon_max']}) | {s['nefc']:.0f} (max {s['nefc_max']}) "
                f"| {s['niter']:.1f} (max {s['niter_max']}) |",
            )
    step_s = sum(r.step_timer for r in ref.values())
    emit(lines, "\n| MuJoCo step part | share of step time |")
    emit(lines, "|---|---|")
    for label in TIMERS:
        share = sum(r.timers[label] for r in ref.values()) / max(step_s, 1e-12)
        emit(lines, f"| {label} | {share:.3f} |")
    # variants side by side, interleaved
    results: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for _ in range(max(1, args.repeat)):
        for sc in SCENARIOS:
            for v in variants:
                rec = run_scenario(sc, v)
                steps, secs, iters = _total(rec)
                results[v].append(
                    {
                        "scenario": sc.name,
                        "steps": steps,
                        "seconds": secs,
                        "niter": iters,
                        "status": rec.status,
                        "same_status": rec.status.split(" ")[0]
                        == ref[sc.name].status.split(" ")[0],
                        "deviation_mm": 1000 * _deviation(rec, ref[sc.name]),
                        "tick_difference": len(rec.front) - len(ref[sc.name].front),
                    }
                )
    emit(lines, "\n### Solver settings side by side (scenarios interleaved)\n")
    emit(
        lines,
        "| variant | us/step | speed vs model (model µs / variant µs) | solver iterations "
        "| outcomes as model | largest front path deviation, mm | largest tick count difference |",
    )
    emit(lines, "|---|---|---|---|---|---|---|")
    base = sum(r["seconds"] for r in results["model"]) / sum(r["steps"] for r in results["model"])
    summary: dict[str, Any] = {}
    for v in variants:
        rs = results[v]
        us = sum(r["seconds"] for r in rs) / sum(r["steps"] for r in rs)
        it = sum(r["niter"] * r["steps"] for r in rs) / sum(r["steps"] for r in rs)
        same = sum(r["same_status"] for r in rs)
        dev = max(r["deviation_mm"] for r in rs)
        ticks = max(abs(r["tick_difference"]) for r in rs)
        summary[v] = {"us_per_step": 1e6 * us, "ratio": base / us, "niter": it, "runs": rs}
        emit(
            lines,
            f"| {v} | {1e6 * us:.0f} | x{base / us:.2f} | {it:.1f} | {same}/{len(rs)} "
            f"| {dev:.2g} | {ticks} |",
        )
    if args.json:
        atomic_write_text(
            args.json,
            json.dumps(
                {"states": {k: _summary(r) for k, r in ref.items()}, "variants": summary},
                indent=2,
                default=float,
            ),
        )
    if args.write_docs:
        from benchmarks.report import write_section

        write_section("Physics step cost", "\n".join(lines))


if __name__ == "__main__":
    main()
