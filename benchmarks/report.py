"""Benchmark figures into ``docs/benchmarks.md``: one stamped section per benchmark.

Each benchmark script prints its tables and, with ``--write-docs``, calls
:func:`write_section` with a section name and its markdown. The section replaces the previous
one of that name between HTML comment markers (current figures only; history goes into
``CHANGELOG.md``) and is stamped with the commit, the date, the machine, the thread count and
the load average (figures are comparable only between runs on an otherwise idle machine).
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import re
import subprocess
from pathlib import Path

from detector.atomic import atomic_write_text

DOCS_PATH = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"
HEADER = (
    "# Benchmark figures\n\n"
    "Written by the scripts in `benchmarks/` (`--write-docs`); each section holds the current\n"
    "figures of one script, stamped with the commit, date, machine, thread count and load\n"
    "average of its run (a load above the run's own threads: other work shared the machine).\n"
    "Rerun a script to refresh its section. Ratios compare methods measured in the same run.\n"
)


def _commit() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).resolve().parent,
        )
        dirty = subprocess.run(
            # the figures file itself is what the benchmarks rewrite: not a change of code
            ["git", "status", "--porcelain", "--untracked-files=no", "--", ".", ":!docs"],
            capture_output=True,
            text=True,
            check=False,
            cwd=Path(__file__).resolve().parent,
        )
        return out.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def threads() -> str:
    """The numerical libraries' thread setting, as the run saw it."""
    omp = os.environ.get("OMP_NUM_THREADS")
    return f"OMP_NUM_THREADS={omp}" if omp else f"default ({os.cpu_count()} cores)"


def load() -> str:
    """The machine's load averages over the last 1 and 5 minutes (runnable processes, the
    benchmark's own included) as ``"1.0 / 1.0"``, or ``"unknown"`` where the system does not
    report them. Other processes running beside a benchmark slow it, in CPU time too (they
    share the caches and memory): a load above the benchmark's own thread count flags figures
    taken on a busy machine."""
    try:
        one, five, _ = os.getloadavg()
        return f"{one:.1f} / {five:.1f}"
    except (AttributeError, OSError):
        return "unknown"


def stamp() -> str:
    """One line: commit, UTC date, machine (CPU, cores), thread setting and load average."""
    machine = platform.processor() or platform.machine()
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (
        f"_commit {_commit()}, {date}, {platform.system()} {machine}, "
        f"{os.cpu_count()} cores, threads: {threads()}, load (1 / 5 min): {load()}, "
        f"Python {platform.python_version()}_"
    )


def write_section(name: str, markdown: str, path: Path = DOCS_PATH) -> Path:
    """Replace (or append) the section ``name`` of ``docs/benchmarks.md`` with ``markdown``.

    ``name`` is a short identifier such as ``"detection"``; the section gets a ``## name``
    title, the stamp line, then ``markdown``. Other sections are left as they are.
    """
    if not re.fullmatch(r"[A-Za-z0-9_. -]+", name):
        raise ValueError(f"name: {name!r} is not allowed; expected letters, digits, _ . - space")
    begin, end = f"<!-- begin {name} -->", f"<!-- end {name} -->"
    body = f"{begin}\n## {name}\n\n{stamp()}\n\n{markdown.strip()}\n{end}\n"
    text = path.read_text(encoding="utf-8") if path.exists() else HEADER
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end) + r"\n?", re.DOTALL)
    if pattern.search(text):
        text = pattern.sub(lambda _m: body, text)
    else:
        text = text.rstrip("\n") + "\n\n" + body
    atomic_write_text(path, text)
    return path
