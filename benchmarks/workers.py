"""Run a benchmark's episodes in order or in spawned worker processes, results in plan order.

Each worker process builds its own environments, so no MuJoCo world is shared between
processes; ``spawn`` keeps workers free of the parent's threads and GL state.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

Result = dict[str, Any]


def run_plan(
    run: Callable[..., Result],
    plan: Sequence[tuple[Any, ...]],
    jobs: int = 1,
    on_result: Callable[[Result], None] | None = None,
) -> list[Result]:
    """``run(*args)`` for each ``args`` of ``plan`` (in ``jobs`` spawned worker processes when
    ``jobs`` > 1; ``run`` must then be a module-level function); ``on_result`` after each one
    as it finishes; the results in plan order."""
    if jobs <= 1:
        out: list[Result] = []
        for args in plan:
            out.append(run(*args))
            if on_result:
                on_result(out[-1])
        return out
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    results: dict[int, Result] = {}
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
        futures = {pool.submit(run, *args): k for k, args in enumerate(plan)}
        for future in as_completed(futures):
            results[futures[future]] = future.result()
            if on_result:
                on_result(results[futures[future]])
    return [results[k] for k in range(len(plan))]
