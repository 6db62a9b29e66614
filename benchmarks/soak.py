"""Soak: many full-fidelity episodes and many fast decisions in one process, RSS printed as it goes.

Part 1 runs ``--episodes`` full-fidelity episodes (MuJoCo robot, rotating LiDAR, the improved
detector; a fresh 6-fitting network each episode, random valid actions) and prints the
process's resident set size (RSS, MB) every ``--every`` episodes. Part 2 runs ``--decisions``
fast-fidelity decisions (a pool of 50 networks, random valid actions, resets included) and
prints RSS every tenth of the way. Each report gives the RSS and the RSS after glibc's
``malloc_trim`` (memory freed but kept by the allocator given back): the second is what is
judged. Memory is flat when it changes little between the warm-up and the end: the script
prints both and exits 1 if the growth over the second half of a part exceeds
``--max-growth-mb``.

Each full-fidelity report also counts the Python objects the garbage collector tracks and the
live MuJoCo worlds: both stay flat when nothing accumulates.

Measured (100 full-fidelity episodes, ``--max-steps 4``, a fresh 6-fitting 3D network each):
RSS after ``malloc_trim`` 256 MB after the first episode (the first episode loads MuJoCo, the
meshes and the compiled kernels: +110 MB), 288 MB at episode 10 and 291 MB at episode 100,
wandering between 270 and 305 MB with the allocator's pages and no trend (growth over the
second half -13.5 MB); 144,2xx Python objects and one MuJoCo world throughout. Python's heap
(tracemalloc) over 14 plants built one after another: 18.69 -> 18.77 MB.

Usage: python benchmarks/soak.py [--episodes 100] [--decisions 1000000] [--every 10]
       [--max-steps 12] [--max-growth-mb 30] [--write-docs]
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time
from pathlib import Path
from typing import Any

# Runnable as a script from anywhere: the repository root holds the benchmarks package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym
import numpy as np

import pipe_env  # noqa: F401
from agents.evaluate import random_valid_episode


def rss_mb() -> float:
    """The current process's resident set size, MB (from /proc; 0 where it is unavailable)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as fh:
            pages = int(fh.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def trimmed_rss_mb() -> float:
    """RSS after glibc's ``malloc_trim(0)`` returns freed heap pages to the OS, MB: what the
    process really holds (without it, RSS also counts memory freed but kept by the allocator).
    The plain RSS where glibc is not available."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    return rss_mb()


def live_objects() -> tuple[int, int]:
    """(Python objects the garbage collector tracks, live MuJoCo worlds): what the process
    holds besides the allocator's pages; both stay flat when nothing accumulates."""
    from pipe_env.world import PipeWorld

    objs = gc.get_objects()
    return len(objs), sum(1 for o in objs if isinstance(o, PipeWorld))


def soak_full(
    episodes: int, every: int, seed: int = 0, max_steps: int = 12
) -> list[tuple[int, float]]:
    """Run ``episodes`` full-fidelity episodes of at most ``max_steps`` decisions; (episodes
    done, RSS MB) every ``every``."""
    env = gym.make(
        "pipenav/PipeNav-v0",
        fidelity="full",
        detector="improved",
        network_config={"n_fittings": 6, "planar": False, "allow_loops": True},
        max_episode_steps=max_steps,
    )
    rng = np.random.default_rng(seed)
    marks = [(0, rss_mb())]
    print(f"full  episode     0/{episodes}: RSS {marks[0][1]:7.1f} MB (start)", flush=True)
    t0 = time.perf_counter()
    for ep in range(1, episodes + 1):
        random_valid_episode(env, rng, seed + ep)
        if ep % every == 0 or ep in (1, episodes):
            gc.collect()
            raw = rss_mb()
            marks.append((ep, trimmed_rss_mb()))
            objects, models = live_objects()
            print(
                f"full  episode {ep:5d}/{episodes}: RSS {raw:7.1f} MB, after malloc_trim "
                f"{marks[-1][1]:7.1f} MB, {objects} objects, {models} MuJoCo world(s) "
                f"({time.perf_counter() - t0:6.0f} s)",
                flush=True,
            )
    env.close()
    return marks


def soak_fast(decisions: int, seed: int = 0) -> list[tuple[int, float]]:
    """Run at least ``decisions`` fast-fidelity decisions; (decisions, RSS MB) ten times."""
    env = gym.make("pipenav/PipeNav-v0", fidelity="fast", network_pool=50, max_episode_steps=64)
    rng = np.random.default_rng(seed)
    step = max(1, decisions // 10)
    marks = [(0, rss_mb())]
    done, ep, next_mark = 0, 0, step
    t0 = time.perf_counter()
    while done < decisions:
        n, _ = random_valid_episode(env, rng, seed + ep)
        done += n
        ep += 1
        if done >= next_mark:
            gc.collect()
            raw = rss_mb()
            marks.append((done, trimmed_rss_mb()))
            print(
                f"fast  decisions {done:9d}/{decisions}: RSS {raw:7.1f} MB, after malloc_trim "
                f"{marks[-1][1]:7.1f} MB "
                f"({time.perf_counter() - t0:6.0f} s)",
                flush=True,
            )
            next_mark += step
    env.close()
    return marks


def growth(marks: list[tuple[int, float]]) -> tuple[float, float, float]:
    """(RSS after warm-up, RSS at the end, growth over the second half), MB."""
    warm = marks[2][1] if len(marks) > 2 else marks[-1][1]
    half = marks[len(marks) // 2][1]
    return warm, marks[-1][1], marks[-1][1] - half


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=100, help="full-fidelity episodes")
    parser.add_argument("--decisions", type=int, default=1_000_000, help="fast decisions")
    parser.add_argument("--every", type=int, default=10, help="print RSS every this many episodes")
    parser.add_argument(
        "--max-steps", type=int, default=12, help="decisions per full-fidelity episode at most"
    )
    parser.add_argument("--max-growth-mb", type=float, default=30.0)
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args(argv)
    if args.episodes < 0 or args.decisions < 0 or args.every < 1 or args.max_steps < 1:
        parser.error("--episodes and --decisions must be >= 0, --every and --max-steps >= 1")
    rows: list[tuple[str, Any, float, float, float]] = []
    if args.episodes:
        marks = soak_full(args.episodes, args.every, max_steps=args.max_steps)
        rows.append(("full episodes", args.episodes, *growth(marks)))
    if args.decisions:
        marks = soak_fast(args.decisions)
        rows.append(("fast decisions", marks[-1][0], *growth(marks)))
    lines = [
        "| part | count | RSS after warm-up MB | RSS at end MB | growth over 2nd half MB |",
        # (RSS after malloc_trim: memory the process holds, not pages the allocator keeps)
        "|---|---|---|---|---|",
    ]
    lines += [f"| {p} | {n} | {w:.1f} | {e:.1f} | {g:+.1f} |" for p, n, w, e, g in rows]
    table = "\n".join(lines)
    print("\n" + table)
    if args.write_docs:
        from benchmarks.report import write_section

        write_section("soak", table)
    worst = max((g for *_, g in rows), default=0.0)
    return 0 if worst <= args.max_growth_mb else 1


if __name__ == "__main__":
    sys.exit(main())
