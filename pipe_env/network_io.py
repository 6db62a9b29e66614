"""Reading and writing pipe network specs: field-by-field checks with paths, files, JSON/YAML.

This module owns the network's serialised form (see :mod:`pipe_env.network` for the schema):
:func:`parse_spec` checks a mapping field by field before anything is built, so every problem
is a :class:`NetworkSpecError` (a ``ValueError``) naming the field's path (``start.forward``,
``goals[0]``, ``fittings[3].position``), the value and what is allowed, whatever the mapping
holds; :func:`load_network` and :func:`save_network` read and write files (atomically), and
name the file in every error. JSON written here never holds NaN or Infinity.
:class:`~pipe_env.network.PipeNetwork`'s ``from_dict``, ``load`` and ``save`` call these.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from detector.atomic import atomic_write_text

if TYPE_CHECKING:
    from detector.geometry import Pose
    from pipe_env.network import PipeNetwork

__all__ = [
    "NetworkSpecError",
    "finite_json",
    "load_network",
    "network_from_text",
    "parse_pose",
    "parse_spec",
    "save_network",
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


class NetworkSpecError(ValueError):
    """A network spec or file is invalid; the message names the file (if any), the field's
    path, the value and what is allowed."""


def _short(value: Any, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _fail(path: str, value: Any, allowed: str) -> NetworkSpecError:
    return NetworkSpecError(f"{path}: got {_short(value)}; allowed: {allowed}")


def _number(value: Any) -> float | None:
    """``value`` as a finite float, or None if it is not a finite real number."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return None
    try:
        out = float(value)
    except (OverflowError, ValueError, TypeError):
        return None
    return out if math.isfinite(out) else None


def _vector(value: Any, path: str, size: int = 3, what: str = "m") -> list[float]:
    allowed = f"{size} finite numbers ({what})"
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != size:
        raise _fail(path, value, allowed)
    out = []
    for i, v in enumerate(value):
        x = _number(v)
        if x is None:
            raise _fail(f"{path}[{i}]", v, f"a finite number ({what})")
        out.append(x)
    return out


def _ident(value: Any, path: str) -> str:
    if isinstance(value, bool) or not isinstance(value, (str, int)) or value == "":
        raise _fail(path, value, "a non-empty string (an id)")
    return str(value)


def _mapping(value: Any, path: str, keys: tuple[str, ...], required: tuple[str, ...]) -> dict:
    if not isinstance(value, dict):
        raise _fail(path, value, f"a mapping with keys {list(keys)}")
    unknown = sorted(str(k) for k in value if k not in keys)
    if unknown:
        raise NetworkSpecError(f"{path}.{unknown[0]}: unknown key; allowed: {list(keys)}")
    missing = [k for k in required if k not in value]
    if missing:
        raise NetworkSpecError(f"{path}.{missing[0]}: missing; required keys: {list(required)}")
    return value


def _plain_metadata(value: Any, path: str, depth: int = 0) -> Any:
    """Metadata as JSON/YAML-safe values: strings, finite numbers, booleans, null, lists and
    string-keyed mappings (numpy values converted)."""
    if depth > MAX_METADATA_DEPTH:
        raise _fail(path, value, f"nesting at most {MAX_METADATA_DEPTH} deep")
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)):
        if _number(value) is None:
            raise _fail(path, value, "finite numbers, strings, booleans, null, lists, mappings")
        return value
    if isinstance(value, (list, tuple)):
        return [_plain_metadata(v, f"{path}[{i}]", depth + 1) for i, v in enumerate(value)]
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, (str, int)) or isinstance(k, bool):
                raise _fail(f"{path} key", k, "string keys")
            out[str(k)] = _plain_metadata(v, f"{path}.{k}", depth + 1)
        return out
    raise _fail(path, value, "finite numbers, strings, booleans, null, lists, mappings")


def parse_pose(value: Any, path: str = "start") -> Pose:
    """A pose from ``{position, forward[, up]}`` or ``{position, rotation}``; errors name
    ``path`` and its fields."""
    return _start(value, path)


def _start(value: Any, path: str = "start") -> Pose:
    from detector.geometry import Pose, frame_from_forward

    st = _mapping(value, path, START_KEYS, ("position",))
    position = np.array(_vector(st["position"], f"{path}.position"))
    if "rotation" in st:
        if "forward" in st or "up" in st:
            raise NetworkSpecError(
                f"{path}: give either 'rotation' or 'forward' (and optionally 'up'), not both"
            )
        rows = st["rotation"]
        if not isinstance(rows, (list, tuple, np.ndarray)) or len(rows) != 3:
            raise _fail(f"{path}.rotation", rows, "a 3x3 rotation matrix (3 rows of 3 numbers)")
        rot = np.array([_vector(r, f"{path}.rotation[{i}]", 3, "-") for i, r in enumerate(rows)])
        try:
            return Pose(position, rot)
        except ValueError:
            raise _fail(
                f"{path}.rotation", rows, "a proper rotation matrix (orthonormal, det +1)"
            ) from None
    if "forward" not in st:
        raise NetworkSpecError(f"{path}.forward: missing; give 'forward' (or 'rotation')")
    forward = np.array(_vector(st["forward"], f"{path}.forward", 3, "a direction"))
    up = None if st.get("up") is None else np.array(_vector(st["up"], f"{path}.up", 3, "-"))
    if not np.linalg.norm(forward) > 1e-9:
        raise _fail(f"{path}.forward", st["forward"], "a non-zero direction")
    if up is not None and not np.linalg.norm(np.cross(forward, up)) > 1e-9 * max(
        1.0, float(np.linalg.norm(forward) * np.linalg.norm(up))
    ):
        raise _fail(f"{path}.up", st["up"], "a non-zero direction not parallel to 'forward'")
    try:
        return Pose.trusted(position, frame_from_forward(forward, up))
    except (ValueError, ArithmeticError):
        raise _fail(f"{path}.forward", st["forward"], "a non-zero direction") from None


def parse_spec(d: Any, validate: bool = True) -> PipeNetwork:
    """A :class:`~pipe_env.network.PipeNetwork` from its mapping (``to_dict`` form).

    Raises :class:`NetworkSpecError` naming the field's path for any problem; with
    ``validate`` the built network is checked too (:meth:`PipeNetwork.validate`).
    """
    from pipe_env.network import SCHEMA_VERSION, Fitting, PipeNetwork, Run

    if not isinstance(d, dict):
        raise NetworkSpecError(
            f"network: got {type(d).__name__} {_short(d)}; allowed: a mapping with keys "
            f"{list(TOP_KEYS)}"
        )
    version = d.get("version")
    if isinstance(version, bool) or version != SCHEMA_VERSION:
        raise _fail("version", version, f"{SCHEMA_VERSION} (this pipenav reads version 1)")
    unknown = sorted(str(k) for k in d if k not in TOP_KEYS)
    if unknown:
        raise NetworkSpecError(f"{unknown[0]}: unknown key; allowed: {list(TOP_KEYS)}")
    for key in ("fittings", "runs", "goals"):
        items = d.get(key, [])
        if not isinstance(items, list):
            raise _fail(key, items, "a list")
        if len(items) > MAX_ELEMENTS:
            raise _fail(key, f"{len(items)} items", f"at most {MAX_ELEMENTS}")
    fittings = []
    for i, f in enumerate(d.get("fittings", [])):
        path = f"fittings[{i}]"
        _mapping(f, path, FITTING_KEYS, ("id", "kind", "position"))
        kind = f["kind"]
        if not isinstance(kind, str):
            raise _fail(f"{path}.kind", kind, "a fitting kind (a string)")
        style = f.get("style")
        if style is not None and not isinstance(style, str):
            raise _fail(f"{path}.style", style, "a string ('mitre' or 'long') or null")
        extra: dict[str, Any] = {}
        for key in ("bend_radius", "taper_length"):
            if f.get(key) is not None:
                value = _number(f[key])
                if value is None:
                    raise _fail(f"{path}.{key}", f[key], "a finite number or null")
                extra[key] = value
        fittings.append(
            Fitting(
                _ident(f["id"], f"{path}.id"),
                kind,
                tuple(_vector(f["position"], f"{path}.position")),
                style,
                **extra,
            )
        )
    runs = []
    for i, r in enumerate(d.get("runs", [])):
        path = f"runs[{i}]"
        _mapping(r, path, RUN_KEYS, RUN_KEYS)
        diameter = _number(r["diameter"])
        if diameter is None:
            raise _fail(f"{path}.diameter", r["diameter"], "a finite number of metres")
        runs.append(
            Run(
                _ident(r["id"], f"{path}.id"),
                _ident(r["a"], f"{path}.a"),
                _ident(r["b"], f"{path}.b"),
                diameter,
            )
        )
    goals = [tuple(_vector(g, f"goals[{i}]")) for i, g in enumerate(d.get("goals", []))]
    start = None if d.get("start") is None else _start(d["start"])
    name = d.get("name", "network")
    if isinstance(name, bool) or not isinstance(name, (str, int)):
        raise _fail("name", name, "a string")
    metadata = d.get("metadata", {})
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, dict):
        raise _fail("metadata", metadata, "a mapping")
    metadata = _plain_metadata(metadata, "metadata")
    net = PipeNetwork(tuple(fittings), tuple(runs), start, tuple(goals), str(name), metadata)
    if validate:
        try:
            net.validate()
        except NetworkSpecError:
            raise
        except ValueError as exc:
            raise NetworkSpecError(str(exc)) from None
        except (ArithmeticError, TypeError, IndexError, KeyError) as exc:  # a safety net
            raise NetworkSpecError(
                f"network: invalid geometry ({type(exc).__name__}); check the fittings' "
                "positions and the runs' diameters"
            ) from None
    return net


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


def network_from_text(text: str, fmt: str, source: str = "network", validate: bool = True):
    """Parse JSON (``fmt="json"``) or YAML text; errors name ``source``."""
    if fmt == "json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise NetworkSpecError(
                f"{source}: not valid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
            ) from None
        except RecursionError:
            raise NetworkSpecError(f"{source}: not valid JSON (nested too deeply)") from None
    elif fmt == "yaml":
        import yaml

        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            problem = getattr(exc, "problem", None) or "cannot parse"
            raise NetworkSpecError(f"{source}: not valid YAML{where}: {problem}") from None
        except RecursionError:
            raise NetworkSpecError(f"{source}: not valid YAML (nested too deeply)") from None
    else:
        raise ValueError(f"fmt={fmt!r} is not allowed; use 'json' or 'yaml'")
    try:
        return parse_spec(data, validate=validate)
    except NetworkSpecError as exc:
        raise NetworkSpecError(f"{source}: {exc}") from None


def _suffix(p: Path) -> str:
    if p.suffix not in SUFFIXES:
        raise NetworkSpecError(
            f"{p}: network file suffix {p.suffix!r} is not allowed; use one of {list(SUFFIXES)}"
        )
    return "json" if p.suffix == ".json" else "yaml"


def load_network(path: str | Path, validate: bool = True) -> PipeNetwork:
    """Read a network file (.json, .yaml, .yml); every error names the file."""
    p = Path(path)
    fmt = _suffix(p)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise NetworkSpecError(f"{p}: network file not found") from None
    except IsADirectoryError:
        raise NetworkSpecError(f"{p}: is a folder, not a network file") from None
    except OSError as exc:
        raise NetworkSpecError(f"{p}: cannot read the network file ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise NetworkSpecError(
            f"{p}: not UTF-8 text (byte {exc.start}); a network file is JSON or YAML"
        ) from None
    return network_from_text(text, fmt, str(p), validate=validate)


def save_network(network: PipeNetwork, path: str | Path) -> None:
    """Write JSON or YAML, chosen by the file suffix, atomically."""
    p = Path(path)
    if _suffix(p) == "yaml":
        atomic_write_text(p, network.to_yaml())
    else:
        atomic_write_text(p, network.to_json(indent=1))
