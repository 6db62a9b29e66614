"""Run scenario x seed tasks on a local process pool or on Ray, and write JUnit XML and JSON.

Each task is identified by the scenario file and the seed, so workers load the scenario
themselves and the same seeds give the same results on every backend. Results come back in the
order of the task list whatever the backend finished first.

Ray, as Ray users run it (:func:`ray_init_kwargs`): with an address (``ray_address``, else the
``RAY_ADDRESS`` environment variable) the run connects to that existing cluster and leaves it
running, its size set by the cluster (``jobs`` is not used); without one it starts a private
local Ray instance with ``jobs`` CPUs and shuts it down at the end. An already initialised Ray
(``ray.init`` called by the caller) is used as it is.
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

from agents.scenarios import Scenario, ScenarioResult, load_scenario, run_scenario

JSON_SCHEMA_VERSION = 1
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
    return run_scenario(load_scenario(source), seed)


def tasks_of(
    scenarios: Sequence[Scenario], seeds: Sequence[int] | None = None
) -> list[tuple[str, int]]:
    """(scenario file, seed) pairs: every scenario with its own seeds, or with ``seeds``."""
    return [(sc.source, s) for sc in scenarios for s in (seeds if seeds is not None else sc.seeds)]


def run_tasks(
    tasks: Sequence[tuple[str, int]],
    jobs: int = 1,
    backend: str = "local",
    on_result: Callable[[ScenarioResult], None] | None = None,
    ray_address: str | None = None,
) -> list[ScenarioResult]:
    """Run the tasks on ``backend`` with ``jobs`` workers; results in task order
    (``ray_address``: see module docstring)."""
    if backend not in BACKENDS:
        raise ValueError(f"backend={backend!r} is not allowed; use one of {BACKENDS}")
    if jobs < 1:
        raise ValueError(f"jobs={jobs} is not allowed; use an int >= 1")
    results: list[ScenarioResult | None] = [None] * len(tasks)
    if backend == "ray":
        return _run_ray(tasks, jobs, on_result, ray_address)
    if jobs == 1:
        for i, (src, seed) in enumerate(tasks):
            results[i] = _task(src, seed)
            if on_result:
                on_result(results[i])  # type: ignore[arg-type]
        return results  # type: ignore[return-value]
    import multiprocessing as mp

    with ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn")) as pool:
        futures = {pool.submit(_task, src, seed): i for i, (src, seed) in enumerate(tasks)}
        from concurrent.futures import as_completed

        for fut in as_completed(futures):
            i = futures[fut]
            results[i] = fut.result()
            if on_result:
                on_result(results[i])  # type: ignore[arg-type]
    return results  # type: ignore[return-value]


def ray_init_kwargs(jobs: int, address: str | None = None) -> dict[str, Any]:
    """The ``ray.init`` arguments of a run: connect to ``address`` (else ``$RAY_ADDRESS``) when
    one is given, else start a new local instance with ``jobs`` CPUs (``address="local"``, so
    Ray does not attach to some other cluster it finds on this machine)."""
    address = address or os.environ.get("RAY_ADDRESS") or None
    common: dict[str, Any] = {"log_to_driver": False, "ignore_reinit_error": True}
    if address:
        return {"address": address, **common}
    return {"address": "local", "num_cpus": jobs, "include_dashboard": False, **common}


def _run_ray(
    tasks: Sequence[tuple[str, int]],
    jobs: int,
    on_result: Callable[[ScenarioResult], None] | None,
    address: str | None = None,
) -> list[ScenarioResult]:
    try:
        import ray
    except ImportError as exc:
        raise RuntimeError(
            "backend 'ray' needs Ray: install the optional extra with pip install 'pipenav[ray]'"
        ) from exc
    started = False
    if not ray.is_initialized():
        ray.init(**ray_init_kwargs(jobs, address))
        started = True
    try:
        remote = ray.remote(num_cpus=1)(_task)
        refs = [remote.remote(src, seed) for src, seed in tasks]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list[ScenarioResult | None] = [None] * len(tasks)
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                results[index[ref]] = ray.get(ref)
                if on_result:
                    on_result(results[index[ref]])  # type: ignore[arg-type]
        return results  # type: ignore[return-value]
    finally:
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


def write_json(
    results: Sequence[ScenarioResult],
    path: str | Path,
    backend: str,
    jobs: int,
    wall_seconds: float,
) -> dict[str, Any]:
    doc = {
        "schema_version": JSON_SCHEMA_VERSION,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "packages": package_versions(),
        "backend": backend,
        "jobs": jobs,
        "wall_seconds": round(wall_seconds, 3),
        "summary": {
            "total": len(results),
            "passed": sum(r.passed for r in results),
            "failed": sum(not r.passed for r in results),
        },
        "results": [r.to_dict() for r in results],
    }
    Path(path).write_text(json.dumps(doc, indent=2, default=_plain))
    return doc


def _plain(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"cannot serialise {type(value).__name__}")


def write_junit(results: Sequence[ScenarioResult], path: str | Path) -> None:
    """One testcase per scenario and seed; failures name criterion, measured value, threshold."""
    suite = ET.Element(
        "testsuite",
        name="pipenav.scenarios",
        tests=str(len(results)),
        failures=str(sum(not r.passed and r.error is None for r in results)),
        errors=str(sum(r.error is not None for r in results)),
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
        if r.error is not None:
            err = ET.SubElement(case, "error", message=r.error, type="RunError")
            err.text = f"replay: {r.replay_command()}"
        elif not r.passed:
            msgs = "; ".join(c.message for c in r.failures)
            fail = ET.SubElement(case, "failure", message=msgs, type="CriterionFailed")
            fail.text = "\n".join(
                [c.message for c in r.failures] + [f"replay: {r.replay_command()}"]
            )
    tree = ET.ElementTree(ET.Element("testsuites"))
    tree.getroot().append(suite)
    ET.indent(tree)
    tree.write(path, encoding="utf-8", xml_declaration=True)


def run_and_report(
    scenarios: Sequence[Scenario],
    seeds: Sequence[int] | None = None,
    jobs: int = 1,
    backend: str = "local",
    junit: str | Path | None = None,
    json_path: str | Path | None = None,
    on_result: Callable[[ScenarioResult], None] | None = None,
    ray_address: str | None = None,
) -> list[ScenarioResult]:
    """Run scenarios and write the reports that were asked for."""
    t0 = time.perf_counter()
    results = run_tasks(tasks_of(scenarios, seeds), jobs, backend, on_result, ray_address)
    wall = time.perf_counter() - t0
    if junit:
        write_junit(results, junit)
    if json_path:
        write_json(results, json_path, backend, jobs, wall)
    return results
