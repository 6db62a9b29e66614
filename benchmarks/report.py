"""Benchmark figures into ``docs/benchmarks.md``: one stamped section per benchmark.

Each benchmark script prints its tables and, with ``--write-docs``, calls
:func:`write_section` with a section name and its markdown. The section replaces the previous
one of that name between HTML comment markers (current figures only; history goes into
``CHANGELOG.md``) and is stamped with the commit, the date, the machine and the thread count.
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
    "figures of one script, stamped with the commit, date, machine and thread count of its run.\n"
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


def stamp() -> str:
    """One line: commit, UTC date, machine (CPU, cores) and thread setting."""
    machine = platform.processor() or platform.machine()
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (
        f"_commit {_commit()}, {date}, {platform.system()} {machine}, "
        f"{os.cpu_count()} cores, threads: {threads()}, Python {platform.python_version()}_"
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
