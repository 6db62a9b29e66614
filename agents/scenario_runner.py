"""Run scenario x seed tasks on a local process pool or on Ray, and write JUnit XML and JSON.

Each task is identified by the scenario file and the seed, so workers load the scenario
themselves and the same seeds give the same results on every backend. Results come back in the
order of the task list whatever the backend finished first.

A run loses nothing: each task runs in a worker process (local) or a Ray task with a wall-clock
limit; a worker that dies or a task that times out is an ``error`` testcase for that scenario
and the others go on; a scenario file that does not load is an ``error`` testcase; Ctrl-C
writes the reports with every finished result (the rest marked not run). Scenarios marked
``known_failure`` that fail are expected failures (JUnit ``<skipped>``), ones that pass are
flagged; ``strict`` counts both as failures. Reports are written atomically and the JSON holds
no NaN or Infinity.

Ray, as Ray users run it (:func:`ray_init_kwargs`): with an address (``ray_address``, else the
``RAY_ADDRESS`` environment variable) the run connects to that existing cluster and leaves it
running, its size set by the cluster (``jobs`` is not used); without one it starts a private
local Ray instance with ``jobs`` CPUs and shuts it down at the end. An already initialised Ray
(``ray.init`` called by the caller) is used as it is.
"""

from __future__ import annotations

import contextlib
import json
import math
import multiprocessing as mp
import os
import platform
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from datetime import datetime, timezone
from importlib import metadata
from multiprocessing import connection as mp_connection
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

from agents.scenarios import (
    DEFAULT_TIMEOUT_S,
    ResultStatus,
    Scenario,
    ScenarioError,
    ScenarioResult,
    error_result,
    load_scenario,
    run_scenario,
)
from detector.atomic import atomic_open, atomic_write_text
from pipe_env.network_io import finite_json

JSON_SCHEMA_VERSION = 1
#: The test hook's environment variable (see :func:`_injected_fault`).
FAULT_ENV = "PIPENAV_SCENARIO_FAULT"
FAULT_EXIT_CODE = 86
#: How long a local worker process may take to start (import its packages), s.
WORKER_START_S = 300.0
_READY = "ready"
BACKENDS = ("local", "ray")
REPORTED_PACKAGES = (
    "pipenav",
    "numpy",
    "mujoco",
    "manifold3d",
    "gymnasium",
    "stable-baselines3",
    "sb3-contrib",
    "torch",
)


def _task(source: str, seed: int) -> ScenarioResult:
    _injected_fault(source)
    try:
        scenario = load_scenario(source)
    except ScenarioError as exc:  # the file changed since discovery: still one testcase
        return error_result(source, seed, str(exc))
    return run_scenario(scenario, seed)


def _injected_fault(source: str) -> None:
    """Test hook: ``PIPENAV_SCENARIO_FAULT="STEM=exit,STEM2=hang"`` makes the worker running
    the scenario file with that stem die at once (``exit``) or never finish (``hang``). It
    exercises the runner's handling of dead and hung workers with real worker processes."""
    spec = os.environ.get(FAULT_ENV, "")
    for item in filter(None, (part.strip() for part in spec.split(","))):
        stem, _, fault = item.partition("=")
        if stem != Path(source).stem:
            continue
        if fault == "exit":
            os._exit(FAULT_EXIT_CODE)
        if fault == "hang":
            while True:
                time.sleep(1.0)


def tasks_of(
    scenarios: Sequence[Scenario], seeds: Sequence[int] | None = None
) -> list[tuple[str, int]]:
    """(scenario file, seed) pairs: every scenario with its own seeds, or with ``seeds``."""
    return [(sc.source, s) for sc in scenarios for s in (seeds if seeds is not None else sc.seeds)]


def timeouts_of(
    scenarios: Sequence[Scenario],
    seeds: Sequence[int] | None = None,
    timeout: float | None = None,
) -> list[float]:
    """Each task's wall-clock limit (s), in :func:`tasks_of` order: ``timeout`` if given,
    else the scenario's ``timeout_s``, else :data:`DEFAULT_TIMEOUT_S`."""
    out = []
    for sc in scenarios:
        limit = timeout if timeout is not None else (sc.timeout_s or DEFAULT_TIMEOUT_S)
        out += [float(limit)] * len(seeds if seeds is not None else sc.seeds)
    return out


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C during a run: ``results`` holds every finished result, the rest marked not run."""

    def __init__(self, results: list[ScenarioResult]) -> None:
        super().__init__("interrupted")
        self.results = results


def run_tasks(
    tasks: Sequence[tuple[str, int]],
    jobs: int = 1,
    backend: str = "local",
    on_result: Callable[[ScenarioResult], None] | None = None,
    timeouts: Sequence[float] | float | None = None,
    ray_address: str | None = None,
) -> list[ScenarioResult]:
    """Run the tasks on ``backend`` with ``jobs`` workers; results in task order
    (``ray_address``: see module docstring).

    Every task gets a result, whatever happens to its worker: a worker that dies is an error
    result for the task it ran (the others go on, on a fresh worker), a task running longer
    than its timeout (s; one per task or one for all, default :data:`DEFAULT_TIMEOUT_S`) is
    stopped and is an error result. On Ctrl-C the workers are stopped and
    :class:`RunInterrupted` carries every finished result with the rest marked not run.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend={backend!r} is not allowed; use one of {BACKENDS}")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs={jobs!r} is not allowed; use an int >= 1")
    if timeouts is None or isinstance(timeouts, (int, float)):
        limit = DEFAULT_TIMEOUT_S if timeouts is None else float(timeouts)
        limits = [limit] * len(tasks)
    else:
        limits = [float(t) for t in timeouts]
    if len(limits) != len(tasks) or not all(math.isfinite(t) and t > 0 for t in limits):
        raise ValueError(
            f"timeouts={timeouts!r} is not allowed; use one number of seconds > 0 per task "
            f"({len(tasks)}) or one for all"
        )
    results: list[ScenarioResult | None] = [None] * len(tasks)

    def finish(i: int, result: ScenarioResult) -> None:
        results[i] = result
        if on_result:
            on_result(result)

    try:
        if backend == "ray":
            _run_ray(tasks, jobs, limits, finish, ray_address)
        else:
            _LocalPool(tasks, jobs, limits, finish).run()
    except KeyboardInterrupt:
        raise RunInterrupted(_with_not_run(tasks, results)) from None
    return _with_not_run(tasks, results)


def _with_not_run(
    tasks: Sequence[tuple[str, int]], results: list[ScenarioResult | None]
) -> list[ScenarioResult]:
    return [
        r if r is not None else error_result(src, seed, "not run (interrupted)", not_run=True)
        for r, (src, seed) in zip(results, tasks)
    ]


# ------------------------------------------------------------------------- local pool
def _worker_main(conn: Connection) -> None:
    """A worker process: run (index, source, seed) tasks until told to stop (None)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    # import what every run needs before saying ready: the timeout clocks the run, not this
    import gymnasium  # noqa: F401

    import agents.scripted  # noqa: F401
    import pipe_env.envs  # noqa: F401

    conn.send(_READY)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        i, src, seed = msg
        try:
            result = _task(src, seed)
        except BaseException as exc:  # noqa: BLE001 (a result, whatever went wrong)
            result = error_result(src, seed, f"{type(exc).__name__}: {exc}")
        conn.send((i, result))


class _Worker:
    """One worker process, its pipe, and the task it runs (index and deadline)."""

    def __init__(self, ctx: Any) -> None:
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_worker_main, args=(child,), daemon=True)
        self.process.start()
        child.close()
        self.task: int | None = None
        self.ready = False
        self.deadline = time.monotonic() + WORKER_START_S  # to say ready, then the task's
        self.started = 0.0

    def give(self, i: int, src: str, seed: int, limit: float) -> None:
        self.task, self.started = i, time.monotonic()
        self.deadline = self.started + limit
        self.conn.send((i, src, seed))

    def stop(self, force: bool = False) -> None:
        if not force:
            with contextlib.suppress(OSError, ValueError):
                self.conn.send(None)
            self.process.join(timeout=5.0)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=5.0)
        self.conn.close()


class _CtrlCAtTheWait:
    """Ctrl-C (SIGINT) turned into a flag and a byte on a pipe the pool's wait watches: the
    interrupt is raised (:meth:`check`) where the loop checks for it, never inside whatever
    the main thread happened to be running (a lock taken by the progress display, a pipe to
    a worker), which could leave that half done. Off the main thread (where signal handlers
    cannot be set) Ctrl-C stays Python's default."""

    def __init__(self) -> None:
        self.hit = False
        self._fds: tuple[int, int] | None = None
        self._saved: tuple[Any, int] | None = None

    def __enter__(self) -> _CtrlCAtTheWait:
        if threading.current_thread() is threading.main_thread():
            r, w = os.pipe()
            os.set_blocking(r, False)
            os.set_blocking(w, False)
            self._fds = (r, w)
            old_fd = signal.set_wakeup_fd(w)
            self._saved = (signal.signal(signal.SIGINT, self._on_sigint), old_fd)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._saved is not None:
            handler, old_fd = self._saved
            signal.signal(signal.SIGINT, handler)
            signal.set_wakeup_fd(old_fd)
            self._saved = None
        if self._fds is not None:
            for fd in self._fds:
                os.close(fd)
            self._fds = None

    def _on_sigint(self, signum: int, frame: Any) -> None:
        self.hit = True

    def fds(self) -> list[int]:
        """The pipe's read end, to wait on with the workers (none off the main thread)."""
        return [] if self._fds is None else [self._fds[0]]

    def check(self) -> None:
        """Raise ``KeyboardInterrupt`` if Ctrl-C came."""
        if self.hit:
            raise KeyboardInterrupt


class _LocalPool:
    """The local backend: up to ``jobs`` worker processes, each running one task at a time
    under its deadline. A worker that dies or misses its deadline is replaced, and its task
    (or, if it never took one, the next task) gets an error result."""

    def __init__(
        self,
        tasks: Sequence[tuple[str, int]],
        jobs: int,
        limits: Sequence[float],
        finish: Callable[[int, ScenarioResult], None],
    ) -> None:
        self.ctx = mp.get_context("spawn")
        self.tasks, self.jobs, self.limits, self.finish = tasks, jobs, limits, finish
        self.todo = list(range(len(tasks)))[::-1]  # popped from the end: task order
        self.workers: list[_Worker] = []

    def run(self) -> None:
        """Run every task; on any exception (Ctrl-C) the workers are killed. Ctrl-C is taken
        at the wait for the workers (see :class:`_CtrlCAtTheWait`), not wherever the loop
        happens to be."""
        try:
            with _CtrlCAtTheWait() as ctrl_c:
                self._loop(ctrl_c)
        finally:
            interrupted = sys.exc_info()[0] is not None
            for w in self.workers:
                w.stop(force=interrupted)

    def _loop(self, ctrl_c: _CtrlCAtTheWait) -> None:
        while self.todo or any(w.task is not None for w in self.workers):
            ctrl_c.check()
            self._start_and_assign()
            watched = [w for w in self.workers if w.task is not None or not w.ready]
            wait_s = max(0.0, min(w.deadline for w in watched) - time.monotonic())
            ready = set(
                mp_connection.wait(
                    [w.conn for w in watched]
                    + [w.process.sentinel for w in watched]
                    + ctrl_c.fds(),
                    timeout=wait_s,
                )
            )
            ctrl_c.check()
            for w in watched:
                if w.conn in ready or w.process.sentinel in ready:
                    self._receive(w)
                elif time.monotonic() >= w.deadline:
                    self._overdue(w)

    def _start_and_assign(self) -> None:
        busy = sum(w.task is not None for w in self.workers)
        while len(self.workers) < min(self.jobs, len(self.todo) + busy):
            self.workers.append(_Worker(self.ctx))
        for w in self.workers:
            if w.ready and w.task is None and self.todo:
                i = self.todo.pop()
                w.give(i, *self.tasks[i], self.limits[i])

    def _drop(self, w: _Worker) -> None:
        w.stop(force=True)
        self.workers.remove(w)

    def _fail(self, i: int | None, why: str) -> None:
        """An error result for task ``i``, or for the next task when the worker had none."""
        if i is None:
            if not self.todo:
                return
            i = self.todo.pop()
        self.finish(i, error_result(*self.tasks[i], why))

    def _receive(self, w: _Worker) -> None:
        """A message from ``w`` (ready, or a result), or its death."""
        try:
            if not w.conn.poll():
                raise EOFError
            message = w.conn.recv()
        except (EOFError, OSError):  # the worker died
            w.process.join(timeout=5.0)
            code = w.process.exitcode
            i = w.task
            self._drop(w)
            if i is None:  # before it took a task: the next task reports it
                self._fail(None, f"a worker process failed to start (exit code {code})")
            else:
                self._fail(
                    i,
                    f"the worker process died (exit code {code}) while running this "
                    "scenario; the other scenarios went on",
                )
            return
        if message == _READY:
            w.ready, w.deadline = True, math.inf
            return
        w.task, w.deadline = None, math.inf
        self.finish(message[0], message[1])

    def _overdue(self, w: _Worker) -> None:
        """``w`` missed its deadline: it did not start in time, or its task timed out."""
        i = w.task
        self._drop(w)
        if i is None:
            self._fail(None, f"a worker process did not start within {WORKER_START_S:g} s")
        else:
            self._fail(i, f"timed out after {self.limits[i]:g} s (the run was stopped)")


# -------------------------------------------------------------------------------- ray
def ray_init_kwargs(jobs: int, address: str | None = None) -> dict[str, Any]:
    """The ``ray.init`` arguments of a run: connect to ``address`` (else ``$RAY_ADDRESS``) when
    one is given, else start a new local instance with ``jobs`` CPUs (``address="local"``, so
    Ray does not attach to some other cluster it finds on this machine)."""
    address = address or os.environ.get("RAY_ADDRESS") or None
    common: dict[str, Any] = {"log_to_driver": False, "ignore_reinit_error": True}
    fault = os.environ.get(FAULT_ENV)
    if fault:  # the test hook reaches the Ray workers too
        common["runtime_env"] = {"env_vars": {FAULT_ENV: fault}}
    if address:
        return {"address": address, **common}
    return {"address": "local", "num_cpus": jobs, "include_dashboard": False, **common}


def _run_ray(
    tasks: Sequence[tuple[str, int]],
    jobs: int,
    limits: Sequence[float],
    finish: Callable[[int, ScenarioResult], None],
    address: str | None = None,
) -> None:
    try:
        import ray
        from ray.exceptions import GetTimeoutError, RayError
    except ImportError as exc:
        raise RuntimeError(
            "backend 'ray' needs Ray: install the optional extra with pip install 'pipenav[ray]'"
        ) from exc
    started = False
    if not ray.is_initialized():
        ray.init(**ray_init_kwargs(jobs, address))
        started = True
    # at most this many tasks in flight, so that a task's clock starts when it can run: the
    # local instance's ``jobs`` CPUs, or the CPUs of the cluster connected to
    in_flight = jobs if started and not (address or os.environ.get("RAY_ADDRESS")) else 0
    if not in_flight:
        in_flight = max(1, int(ray.cluster_resources().get("CPU", jobs)))
    refs: list[Any] = []
    try:
        # no retries: a task that kills its worker is reported, not run again
        remote = ray.remote(num_cpus=1, max_retries=0)(_task)
        todo = list(range(len(tasks)))[::-1]
        running: dict[Any, tuple[int, float]] = {}  # ref -> (task index, deadline)
        while todo or running:
            while todo and len(running) < in_flight:
                i = todo.pop()
                ref = remote.remote(*tasks[i])
                refs.append(ref)
                running[ref] = (i, time.monotonic() + limits[i])
            wait_s = max(0.0, min(d for _, d in running.values()) - time.monotonic())
            done, _ = ray.wait(list(running), num_returns=1, timeout=wait_s)
            for ref in done:
                i, _ = running.pop(ref)
                src, seed = tasks[i]
                try:
                    finish(i, ray.get(ref, timeout=60))
                except (RayError, GetTimeoutError) as exc:
                    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
                    finish(
                        i,
                        error_result(
                            src,
                            seed,
                            f"the Ray worker failed while running this scenario "
                            f"({type(exc).__name__}: {first}); the other scenarios went on",
                        ),
                    )
            now = time.monotonic()
            for ref, (i, deadline) in list(running.items()):
                if now >= deadline:
                    running.pop(ref)
                    with contextlib.suppress(Exception):
                        ray.cancel(ref, force=True)
                    src, seed = tasks[i]
                    finish(
                        i,
                        error_result(
                            src, seed, f"timed out after {limits[i]:g} s (the run was stopped)"
                        ),
                    )
    finally:
        if sys.exc_info()[0] is not None:
            for ref in refs:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
        if started:
            ray.shutdown()


# ------------------------------------------------------------------------------ reports
def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in REPORTED_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def summary_of(results: Sequence[ScenarioResult], strict: bool = False) -> dict[str, int]:
    """Counts by status, and ``failed``: the results that fail the suite (see
    :meth:`ScenarioResult.counts_as_failure`)."""
    statuses = [r.status for r in results]
    return {
        "total": len(results),
        "passed": sum(s in (ResultStatus.PASSED, ResultStatus.UNEXPECTED_PASS) for s in statuses),
        "failed": sum(r.counts_as_failure(strict) for r in results),
        "errors": statuses.count(ResultStatus.ERROR),
        "expected_failures": statuses.count(ResultStatus.EXPECTED_FAILURE),
        "unexpected_passes": statuses.count(ResultStatus.UNEXPECTED_PASS),
        "not_run": statuses.count(ResultStatus.NOT_RUN),
    }


def write_json(
    results: Sequence[ScenarioResult],
    path: str | Path,
    backend: str,
    jobs: int,
    wall_seconds: float,
    strict: bool = False,
    interrupted: bool = False,
) -> dict[str, Any]:
    """Write the JSON report atomically (no NaN or Infinity: non-finite numbers become null)."""
    doc = {
        "schema_version": JSON_SCHEMA_VERSION,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "packages": package_versions(),
        "backend": backend,
        "jobs": jobs,
        "strict": strict,
        "interrupted": interrupted,
        "wall_seconds": round(wall_seconds, 3),
        "summary": summary_of(results, strict),
        "results": [r.to_dict() for r in results],
    }
    atomic_write_text(path, json.dumps(finite_json(doc), indent=2, allow_nan=False))
    return doc


def write_junit(results: Sequence[ScenarioResult], path: str | Path, strict: bool = False) -> None:
    """One testcase per scenario and seed; failures name criterion, measured value, threshold.

    An error (a crash, a dead worker, a timeout, a file that does not load) is ``<error>``; a
    run that never started is ``<skipped>``; an expected failure is ``<skipped>`` with the
    ``known_failure`` reason (``<failure>`` when ``strict``); an unexpected pass is flagged in
    ``<system-out>`` (a ``<failure>`` when ``strict``).
    """
    summary = summary_of(results, strict)
    suite = ET.Element(
        "testsuite",
        name="pipenav.scenarios",
        tests=str(len(results)),
        failures=str(summary["failed"] - summary["errors"]),
        errors=str(summary["errors"]),
        skipped=str(summary["not_run"] + (0 if strict else summary["expected_failures"])),
        time=f"{sum(sum(r.timings.values()) for r in results):.3f}",
        timestamp=datetime.now(timezone.utc).isoformat(timespec="seconds"),
    )
    for r in results:
        case = ET.SubElement(
            suite,
            "testcase",
            classname=f"pipenav.scenarios.{r.scenario}",
            name=f"{r.scenario}[seed={r.seed}]",
            time=f"{sum(r.timings.values()):.3f}",
            file=r.source,
        )
        props = ET.SubElement(case, "properties")
        for key in ("is_success", "jams", "decisions", "sim_time_s", "classification"):
            if key in r.metrics:
                ET.SubElement(props, "property", name=key, value=str(r.metrics[key]))
        if r.known_failure:
            ET.SubElement(props, "property", name="known_failure", value=r.known_failure)
        status = r.status
        msgs = "; ".join(c.message for c in r.failures)
        detail = "\n".join([c.message for c in r.failures] + [f"replay: {r.replay_command()}"])
        if status == ResultStatus.NOT_RUN:
            ET.SubElement(case, "skipped", message="not run: the suite was interrupted")
        elif status == ResultStatus.ERROR:
            err = ET.SubElement(case, "error", message=r.error or "", type="RunError")
            err.text = f"replay: {r.replay_command()}"
        elif status == ResultStatus.FAILED or (status == ResultStatus.EXPECTED_FAILURE and strict):
            kind = "KnownFailure" if status == ResultStatus.EXPECTED_FAILURE else "CriterionFailed"
            fail = ET.SubElement(case, "failure", message=msgs, type=kind)
            fail.text = detail
        elif status == ResultStatus.EXPECTED_FAILURE:
            skip = ET.SubElement(
                case, "skipped", message=f"expected failure (known_failure: {r.known_failure})"
            )
            skip.text = detail
        elif status == ResultStatus.UNEXPECTED_PASS:
            note = (
                f"unexpected pass: the scenario is marked known_failure "
                f"({r.known_failure}) but passed; remove the note"
            )
            if strict:
                ET.SubElement(case, "failure", message=note, type="UnexpectedPass")
            else:
                ET.SubElement(case, "system-out").text = note
    root = ET.Element("testsuites")
    root.append(suite)
    tree = ET.ElementTree(root)
    ET.indent(tree)
    with atomic_open(path, "wb") as handle:
        tree.write(handle, encoding="utf-8", xml_declaration=True)


def run_and_report(
    scenarios: Sequence[Scenario],
    seeds: Sequence[int] | None = None,
    jobs: int = 1,
    backend: str = "local",
    junit: str | Path | None = None,
    json_path: str | Path | None = None,
    on_result: Callable[[ScenarioResult], None] | None = None,
    broken: Sequence[tuple[str, Exception]] = (),
    timeout: float | None = None,
    strict: bool = False,
    ray_address: str | None = None,
) -> list[ScenarioResult]:
    """Run scenarios and write the reports that were asked for.

    ``broken`` are (file, error) pairs of selected scenario files that did not load: each is
    an error testcase. ``timeout`` (s) overrides every scenario's limit. On Ctrl-C the reports
    are written with what finished, then :class:`RunInterrupted` is raised.
    """
    t0 = time.perf_counter()
    failed_to_load = [error_result(src, 0, str(exc)) for src, exc in broken]
    for r in failed_to_load:
        if on_result:
            on_result(r)
    interrupted: RunInterrupted | None = None
    try:
        results = run_tasks(
            tasks_of(scenarios, seeds),
            jobs,
            backend,
            on_result,
            timeouts_of(scenarios, seeds, timeout),
            ray_address,
        )
    except RunInterrupted as exc:
        interrupted, results = exc, exc.results
    results = failed_to_load + results
    wall = time.perf_counter() - t0
    if junit:
        write_junit(results, junit, strict)
    if json_path:
        write_json(results, json_path, backend, jobs, wall, strict, interrupted is not None)
    if interrupted is not None:
        raise RunInterrupted(results)
    return results
