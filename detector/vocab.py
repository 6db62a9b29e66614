"""The project's shared vocabulary: string enums for the words the layers exchange.

Owns :class:`StrEnum` (a Python 3.10-compatible string enum), :class:`Kind` (the kind of a
structure option) and :class:`Method` (the detector that turns scans into options, or the
``ground_truth`` oracle). Members are ``str`` instances that compare and hash equal to their
values, so configuration files, scenario files and public arguments keep accepting plain
strings; ``json.dumps`` writes the value. YAML's safe dumper does not know enums: dump
``member.value``. This module is the lowest layer (no MuJoCo, no project imports).
"""

from __future__ import annotations

from enum import Enum


class StrEnum(str, Enum):
    """A string enum whose ``str()`` and ``format()`` give the value (like Python 3.11's)."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


class Kind(StrEnum):
    """The kind of a structure ahead (see :mod:`detector.options` for the definitions)."""

    STRAIGHT = "straight"
    REDUCER = "reducer"
    CLOSURE = "closure"
    BEND = "bend"
    JUNCTION = "junction"


class Method(StrEnum):
    """Where the structure options come from: a detector method or the exact oracle."""

    IMPROVED = "improved"
    THESIS = "thesis"
    GROUND_TRUTH = "ground_truth"


#: Every source of structure options, as plain strings, in :class:`Method` order.
DETECTORS: tuple[str, ...] = tuple(m.value for m in Method)
