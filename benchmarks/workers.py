"""Run a benchmark's episodes in order or in spawned worker processes, results in plan order.

Each worker process builds its own environments, so no MuJoCo world is shared between
processes; ``spawn`` keeps workers free of the parent's threads and GL state. A worker ends
with the benchmark's process, however that ends (see :func:`_end_with_parent`).
"""

from __future__ import annotations

import os
import signal
import sys
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
    with ProcessPoolExecutor(
        max_workers=jobs,
        mp_context=context,
        initializer=_end_with_parent,
        initargs=(os.getpid(),),
    ) as pool:
        futures = {pool.submit(run, *args): k for k, args in enumerate(plan)}
        for future in as_completed(futures):
            results[futures[future]] = future.result()
            if on_result:
                on_result(results[futures[future]])
    return [results[k] for k in range(len(plan))]


#: prctl's option: the signal a process gets when its parent ends (Linux).
PR_SET_PDEATHSIG = 1


def _end_with_parent(parent: int) -> None:
    """A worker's start: on Linux, ask for SIGTERM when the process that started it ends
    (killed or stopped with Ctrl-C, a pool's workers would otherwise live on, each holding
    its MuJoCo worlds, waiting for work that never comes); end at once if it already has
    (``parent``: its pid)."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM))
    if os.getppid() != parent:  # (it ended before the request was made)
        os._exit(1)
