"""Reading and writing pipe network specs: field-by-field checks with paths, files, JSON/YAML.

This module owns the network's serialised form (see :mod:`pipe_env.network` for the schema):
:func:`parse_spec` checks a mapping field by field before anything is built and returns the
network's parts, so every problem is a :class:`NetworkSpecError` (a ``ValueError`` in the
project's one format, see :mod:`detector.validation`) naming the field's path
(``start.forward``, ``goals[0]``, ``fittings[3] (id 'f3').position``), the value and what is
allowed, whatever the mapping holds. :func:`read_spec_file`, :func:`spec_from_text` and
:func:`write_spec_file` read and write files (atomically) and name the file in every error.
JSON written here never holds NaN or Infinity.

It sits below the model: :class:`~pipe_env.network.PipeNetwork`'s ``from_dict``, ``load``,
``save`` and ``to_json`` call it, and it imports only the elements
(:mod:`pipe_env.network_elements`), so there is no import cycle.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from detector.atomic import atomic_write_text
from detector.geometry import Pose, frame_from_forward
from detector.validation import ArgumentError, check_number, check_vector
from pipe_env.network_elements import SCHEMA_VERSION, Fitting, Run

__all__ = [
    "NetworkParts",
    "NetworkSpecError",
    "finite_json",
    "parse_pose",
    "parse_spec",
    "plain",
    "read_spec_file",
    "spec_errors",
    "spec_from_text",
    "spec_to_json",
    "spec_to_yaml",
    "write_spec_file",
]

TOP_KEYS = ("version", "name", "fittings", "runs", "start", "goals", "metadata")
FITTING_KEYS = ("id", "kind", "position", "style", "bend_radius", "taper_length")
RUN_KEYS = ("id", "a", "b", "diameter")
START_KEYS = ("position", "forward", "up", "rotation")
SUFFIXES = (".json", ".yaml", ".yml")
#: Largest number of fittings or runs a spec may hold.
MAX_ELEMENTS = 10_000
#: Deepest nesting of ``metadata``.
MAX_METADATA_DEPTH = 16
_METADATA_ALLOWED = "finite numbers, strings, booleans, null, lists, mappings"


class NetworkSpecError(ArgumentError):
    """A network spec or file is invalid; the message names the file (if any), the field's
    path, the value and what is allowed (an :class:`~detector.validation.ArgumentError`)."""

    @classmethod
    def of(cls, exc: ArgumentError, where: str | None = None) -> NetworkSpecError:
        """``exc`` as a :class:`NetworkSpecError`, placed in ``where`` (a file) if given."""
        err = cls(exc.field, exc.value, exc.allowed, exc.problem, exc.where)
        return err.within(where) if where else err

    def within(self, where: str) -> NetworkSpecError:
        place = f"{where}: {self.where}" if self.where else where
        return NetworkSpecError(self.field, self.value, self.allowed, self.problem, place)

    def __reduce__(self) -> tuple[Any, ...]:
        return (NetworkSpecError, (self.field, self.value, self.allowed, self.problem, self.where))


def _fail(path: str, value: Any, allowed: str, problem: str = "not allowed") -> NetworkSpecError:
    return NetworkSpecError(path, value, allowed, problem)


class NetworkParts(NamedTuple):
    """A parsed spec: the arguments of :class:`~pipe_env.network.PipeNetwork`, in order."""

    fittings: tuple[Fitting, ...]
    runs: tuple[Run, ...]
    start_pose: Pose | None
    goals: tuple[tuple[float, float, float], ...]
    name: str
    metadata: dict[str, Any]


@contextmanager
def spec_errors(where: str | None = None) -> Iterator[None]:
    """Turn any checking error inside into a :class:`NetworkSpecError` placed in ``where``
    (a file name), and arithmetic surprises from degenerate geometry into one too."""
    try:
        yield
    except NetworkSpecError as exc:
        raise (exc.within(where) if where else exc) from None
    except ArgumentError as exc:
        raise NetworkSpecError.of(exc, where) from None
    except (ValueError, ArithmeticError, TypeError, IndexError, KeyError) as exc:
        err = _fail(
            "network",
            "(the spec)",
            "valid geometry (check the fittings' positions and the runs' diameters)",
            f"invalid geometry ({type(exc).__name__}: {exc})",
        )
        raise (err.within(where) if where else err) from None


# --------------------------------------------------------------------------- parsing
def _vector(value: Any, path: str, unit: str = "m") -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple, np.ndarray)):
        raise _fail(path, value, f"3 finite numbers ({unit})", "not a list of numbers")
    v = check_vector(path, value, 3, unit=unit)
    return (float(v[0]), float(v[1]), float(v[2]))


def _ident(value: Any, path: str) -> str:
    if isinstance(value, bool) or not isinstance(value, (str, int)) or value == "":
        raise _fail(path, value, "a non-empty string (an id)", "not an id")
    return str(value)


def _mapping(value: Any, path: str, keys: tuple[str, ...], required: tuple[str, ...]) -> dict:
    if not isinstance(value, dict):
        raise _fail(path, value, f"a mapping with keys {', '.join(keys)}", "not a mapping")
    unknown = sorted(str(k) for k in value if k not in keys)
    if unknown:
        raise _fail(f"{path}.{unknown[0]}", value[unknown[0]], ", ".join(keys), "unknown key")
    missing = [k for k in required if k not in value]
    if missing:
        raise _fail(f"{path}.{missing[0]}", None, f"required keys {', '.join(required)}", "missing")
    return value


def _plain_metadata(value: Any, path: str, depth: int = 0) -> Any:
    """Metadata as JSON/YAML-safe values: strings, finite numbers, booleans, null, lists and
    string-keyed mappings (numpy values converted)."""
    if depth > MAX_METADATA_DEPTH:
        raise _fail(path, value, f"nesting at most {MAX_METADATA_DEPTH} deep", "nested too deeply")
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)):
        check_number(path, value)  # finite, and an int that fits a float
        return value
    if isinstance(value, (list, tuple)):
        return [_plain_metadata(v, f"{path}[{i}]", depth + 1) for i, v in enumerate(value)]
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, (str, int)) or isinstance(k, bool):
                raise _fail(f"{path} key", k, "string keys", "not a string")
            out[str(k)] = _plain_metadata(v, f"{path}.{k}", depth + 1)
        return out
    raise _fail(path, value, _METADATA_ALLOWED, "not a plain value")


def parse_pose(value: Any, path: str = "start") -> Pose:
    """A pose from ``{position, forward[, up]}`` or ``{position, rotation}``; errors name
    ``path`` and its fields."""
    with spec_errors():
        st = _mapping(value, path, START_KEYS, ("position",))
        position = np.array(_vector(st["position"], f"{path}.position"))
        if "rotation" in st:
            return _rotation_pose(st, path, position)
        return _forward_pose(st, path, position)
    raise AssertionError("unreachable")  # pragma: no cover (mypy: spec_errors re-raises)


def _rotation_pose(st: dict, path: str, position: np.ndarray) -> Pose:
    if "forward" in st or "up" in st:
        raise _fail(
            f"{path}.rotation", st["rotation"], "either rotation or forward (and up)", "both given"
        )
    rows = st["rotation"]
    allowed = "a 3x3 rotation matrix (3 rows of 3 numbers)"
    if not isinstance(rows, (list, tuple, np.ndarray)) or len(rows) != 3:
        raise _fail(f"{path}.rotation", rows, allowed, "not 3 rows")
    rot = np.array([_vector(r, f"{path}.rotation[{i}]", "-") for i, r in enumerate(rows)])
    try:
        return Pose(position, rot)
    except ValueError:
        raise _fail(
            f"{path}.rotation", rows, "a proper rotation (orthonormal, det +1)", "not a rotation"
        ) from None


def _forward_pose(st: dict, path: str, position: np.ndarray) -> Pose:
    if "forward" not in st:
        raise _fail(f"{path}.forward", None, "forward (or rotation)", "missing")
    forward = np.array(_vector(st["forward"], f"{path}.forward", "a direction"))
    up = None if st.get("up") is None else np.array(_vector(st["up"], f"{path}.up", "-"))
    if not np.linalg.norm(forward) > 1e-9:
        raise _fail(f"{path}.forward", st["forward"], "a non-zero direction", "zero length")
    if up is not None and not np.linalg.norm(np.cross(forward, up)) > 1e-9 * max(
        1.0, float(np.linalg.norm(forward) * np.linalg.norm(up))
    ):
        raise _fail(
            f"{path}.up", st["up"], "a non-zero direction not parallel to forward", "parallel"
        )
    try:
        return Pose.trusted(position, frame_from_forward(forward, up))
    except (ValueError, ArithmeticError):
        raise _fail(
            f"{path}.forward", st["forward"], "a non-zero direction", "degenerate"
        ) from None


def _check_top(d: Any) -> None:
    if not isinstance(d, dict):
        raise _fail("network", d, f"a mapping with keys {', '.join(TOP_KEYS)}", "not a mapping")
    version = d.get("version")
    if isinstance(version, bool) or version != SCHEMA_VERSION:
        raise _fail(
            "version", version, f"{SCHEMA_VERSION} (this pipenav reads version 1)", "unsupported"
        )
    unknown = sorted(str(k) for k in d if k not in TOP_KEYS)
    if unknown:
        raise _fail(unknown[0], d[unknown[0]], ", ".join(TOP_KEYS), "unknown key")
    for key in ("fittings", "runs", "goals"):
        items = d.get(key, [])
        if not isinstance(items, list):
            raise _fail(key, items, "a list", "not a list")
        if len(items) > MAX_ELEMENTS:
            raise _fail(key, f"{len(items)} items", f"at most {MAX_ELEMENTS}", "too many")


def _parse_fitting(f: Any, index: int) -> Fitting:
    _mapping(f, f"fittings[{index}]", FITTING_KEYS, ("id", "kind", "position"))
    ident = _ident(f["id"], f"fittings[{index}].id")
    path = f"fittings[{index}] (id {ident!r})"
    kind = f["kind"]
    if not isinstance(kind, str):
        raise _fail(f"{path}.kind", kind, "a fitting kind (a string)", "not a string")
    style = f.get("style")
    if style is not None and not isinstance(style, str):
        raise _fail(f"{path}.style", style, "'mitre', 'long' or null", "not a string")
    extra: dict[str, Any] = {}
    for key in ("bend_radius", "taper_length"):
        if f.get(key) is not None:
            extra[key] = check_number(f"{path}.{key}", f[key], unit="m")
    return Fitting(ident, kind, _vector(f["position"], f"{path}.position"), style, **extra)


def _parse_run(r: Any, index: int) -> Run:
    _mapping(r, f"runs[{index}]", RUN_KEYS, RUN_KEYS)
    ident = _ident(r["id"], f"runs[{index}].id")
    path = f"runs[{index}] (id {ident!r})"
    diameter = check_number(f"{path}.diameter", r["diameter"], unit="m")
    return Run(ident, _ident(r["a"], f"{path}.a"), _ident(r["b"], f"{path}.b"), diameter)


def _parse_name_and_metadata(d: dict) -> tuple[str, dict[str, Any]]:
    name = d.get("name", "network")
    if isinstance(name, bool) or not isinstance(name, (str, int)):
        raise _fail("name", name, "a string", "not a string")
    metadata = d.get("metadata", {})
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, dict):
        raise _fail("metadata", metadata, "a mapping", "not a mapping")
    return str(name), _plain_metadata(metadata, "metadata")


def parse_spec(d: Any) -> NetworkParts:
    """The parts of a :class:`~pipe_env.network.PipeNetwork` from its mapping (``to_dict``
    form), checked field by field; raises :class:`NetworkSpecError` naming the field's path.
    (:meth:`~pipe_env.network.PipeNetwork.from_dict` builds and validates the network.)"""
    with spec_errors():
        _check_top(d)
        fittings = tuple(_parse_fitting(f, i) for i, f in enumerate(d.get("fittings", [])))
        runs = tuple(_parse_run(r, i) for i, r in enumerate(d.get("runs", [])))
        goals = tuple(_vector(g, f"goals[{i}]") for i, g in enumerate(d.get("goals", [])))
        start = None if d.get("start") is None else parse_pose(d["start"])
        name, metadata = _parse_name_and_metadata(d)
        return NetworkParts(fittings, runs, start, goals, name, metadata)
    raise AssertionError("unreachable")  # pragma: no cover (mypy: spec_errors re-raises)


# ------------------------------------------------------------------------ JSON, YAML
def plain(value: Any) -> Any:
    """Numpy scalars and arrays inside ``value`` as plain Python values (JSON/YAML-safe)."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def finite_json(value: Any) -> Any:
    """``value`` with numpy values made plain and non-finite floats replaced by None, so that
    ``json.dumps(..., allow_nan=False)`` accepts it."""
    if isinstance(value, dict):
        return {str(k): finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite_json(value.tolist())
    if isinstance(value, np.generic):
        return finite_json(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def spec_to_json(d: dict[str, Any], **kwargs: Any) -> str:
    """JSON text of a spec; never NaN or Infinity (non-finite numbers become null)."""
    kwargs["allow_nan"] = False
    return json.dumps(finite_json(d), **kwargs)


def spec_to_yaml(d: dict[str, Any]) -> str:
    """YAML text of a spec, keys in schema order."""
    import yaml

    return str(yaml.safe_dump(d, sort_keys=False))


def _text_error(source: str, fmt: str, problem: str) -> NetworkSpecError:
    return NetworkSpecError(
        "contents", source, f"a {fmt} network spec", problem, source if source else None
    )


def spec_from_text(text: str, fmt: str, source: str = "network") -> Any:
    """The mapping in JSON (``fmt="json"``) or YAML text; errors name ``source``."""
    if fmt == "json":
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            where = f"line {exc.lineno}, column {exc.colno}"
            raise _text_error(source, "JSON", f"not valid JSON at {where}: {exc.msg}") from None
        except RecursionError:
            raise _text_error(source, "JSON", "not valid JSON (nested too deeply)") from None
    if fmt == "yaml":
        import yaml

        try:
            return yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            problem = getattr(exc, "problem", None) or "cannot parse"
            raise _text_error(source, "YAML", f"not valid YAML{where}: {problem}") from None
        except RecursionError:
            raise _text_error(source, "YAML", "not valid YAML (nested too deeply)") from None
    raise NetworkSpecError("fmt", fmt, "json, yaml", "unknown")


# ----------------------------------------------------------------------------- files
def _format_of(p: Path) -> str:
    if p.suffix not in SUFFIXES:
        raise NetworkSpecError(
            "suffix", p.suffix, ", ".join(SUFFIXES), "not a network file suffix", str(p)
        )
    return "json" if p.suffix == ".json" else "yaml"


def _file_error(p: Path, problem: str) -> NetworkSpecError:
    return NetworkSpecError("file", p.name, "a readable network file", problem, str(p))


def read_spec_file(path: str | Path) -> Any:
    """The mapping in a network file (.json, .yaml, .yml); every error names the file."""
    p = Path(path)
    fmt = _format_of(p)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise _file_error(p, "network file not found") from None
    except IsADirectoryError:
        raise _file_error(p, "a folder, not a network file") from None
    except OSError as exc:
        raise _file_error(p, f"cannot be read ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _file_error(p, f"not UTF-8 text (byte {exc.start}); JSON or YAML is") from None
    return spec_from_text(text, fmt, str(p))


def write_spec_file(path: str | Path, d: dict[str, Any]) -> None:
    """Write a spec as JSON or YAML, chosen by the file suffix, atomically."""
    p = Path(path)
    text = spec_to_yaml(d) if _format_of(p) == "yaml" else spec_to_json(d, indent=1)
    atomic_write_text(p, text)
