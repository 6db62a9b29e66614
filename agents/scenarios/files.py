"""Scenario files: reading and checking one (:func:`load_scenario`), the packaged library of
scenario files (``agents/scenarios/library/``, shipped as package data) and selecting files
by a glob of their stems (:func:`scenario_files`, :func:`discover`).

Loading a file parses its YAML, validates it (:mod:`agents.scenarios.schema`) and builds its
network once (:mod:`agents.scenarios.building`), so a broken file is reported when it is
selected, naming the file and the field, rather than when it runs.
"""

from __future__ import annotations

import fnmatch
from importlib import resources
from pathlib import Path

import yaml

from agents.scenarios.building import build_network
from agents.scenarios.schema import Scenario, ScenarioError, parse_scenario

__all__ = [
    "LIBRARY",
    "discover",
    "discover_with_errors",
    "load_scenario",
    "packaged_scenario_dir",
    "scenario_files",
]

#: The folder of packaged scenario files inside the ``agents.scenarios`` package.
LIBRARY = "library"


def load_scenario(path: str | Path) -> Scenario:
    """Read, validate and build one scenario file; every problem is a :class:`ScenarioError`
    whose message starts with the file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ScenarioError(f"{p}: cannot read the scenario file ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ScenarioError(f"{p}: not UTF-8 text") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ScenarioError(
            f"{p}: not valid YAML{where}: {getattr(exc, 'problem', None) or exc}"
        ) from None
    scenario = parse_scenario(data, str(p))
    build_network(scenario)  # layout/generator parameters and goals are checked here too
    return scenario


def packaged_scenario_dir() -> Path:
    """The folder of the packaged scenario files (a real folder in an installed package)."""
    return Path(str(resources.files("agents.scenarios").joinpath(LIBRARY)))


def scenario_files(pattern: str = "*", directory: str | Path | None = None) -> list[Path]:
    """Packaged (or ``directory``'s) scenario files whose stem matches the glob ``pattern``.

    Only the names are read: a file the pattern does not select is never parsed. (A
    scenario's ``name`` defaults to its file stem; select a renamed one by its file stem.)
    """
    root = Path(directory) if directory is not None else packaged_scenario_dir()
    return [f for f in sorted(root.glob("*.yaml")) if fnmatch.fnmatch(f.stem, pattern)]


def discover_with_errors(
    pattern: str = "*", directory: str | Path | None = None
) -> tuple[list[Scenario], list[tuple[str, ScenarioError]]]:
    """The selected scenarios, and (file, error) for each selected file that does not load."""
    found: list[Scenario] = []
    broken: list[tuple[str, ScenarioError]] = []
    for f in scenario_files(pattern, directory):
        try:
            found.append(load_scenario(f))
        except ScenarioError as exc:
            broken.append((str(f), exc))
    return found, broken


def discover(pattern: str = "*", directory: str | Path | None = None) -> list[Scenario]:
    """Packaged (or ``directory``'s) scenarios whose file stem matches the glob ``pattern``;
    raises the :class:`ScenarioError` of the first selected file that does not load."""
    return [load_scenario(f) for f in scenario_files(pattern, directory)]
