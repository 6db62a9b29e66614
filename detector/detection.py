"""The detector's answer for one scan: :class:`Detection`.

A detection names the kind of the structure ahead (one of :data:`detector.options.KINDS`), its
options (one :class:`~detector.options.StructureOption` per way on; empty for a straight pipe),
an overall confidence in [0, 1] and a diagnostics dictionary (points per class, fit residuals,
timings, the method's intermediate numbers). Nothing in a detection is ever NaN or infinite:
the constructor rejects non-finite numbers in the options and the confidence and replaces them
by ``None`` in the diagnostics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from detector.options import KINDS, StructureOption, option_order
from detector.vocab import Kind


def clean_diagnostics(value: Any) -> Any:
    """A copy of ``value`` with numpy scalars/arrays as Python numbers/lists and every
    non-finite float replaced by ``None``."""
    kind = type(value)
    if kind is float:
        return value if math.isfinite(value) else None
    if kind is int or kind is str or kind is bool or value is None:
        return value
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            t = type(v)  # (plain entries inline: most of a detector's diagnostics)
            if t is float:
                out[str(k)] = v if math.isfinite(v) else None
            elif t is int or t is str or t is bool or v is None:
                out[str(k)] = v
            else:
                out[str(k)] = clean_diagnostics(v)
        return out
    if isinstance(value, (list, tuple)):
        return [clean_diagnostics(v) for v in value]
    if isinstance(value, np.ndarray):
        return clean_diagnostics(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else None
    return value


@dataclass(frozen=True)
class Detection:
    """The structure ahead as one scan shows it.

    Attributes:
        kind: one of ``KINDS``.
        options: the ways on past the structure (empty for ``straight``), sorted by
            :func:`~detector.options.option_order` (straight on first, then by roll direction);
            distances along the current pipe axis from the sensor origin, metres; angles in
            radians.
        confidence: in [0, 1]: how much the method trusts its answer.
        diagnostics: method-specific numbers (plain Python types, never NaN).
    """

    kind: str
    options: list[StructureOption] = field(default_factory=list)
    confidence: float = 0.0
    diagnostics: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"Detection.kind must be one of {KINDS}, got {self.kind!r}")
        opts = list(self.options)
        for k, o in enumerate(opts):
            if not isinstance(o, StructureOption):
                raise ValueError(
                    f"Detection.options must be StructureOption instances, got "
                    f"{type(o).__name__} at index {k}"
                )
        if self.kind == Kind.STRAIGHT and opts:
            raise ValueError("a straight detection has no options")
        if self.kind != Kind.STRAIGHT and not opts:
            raise ValueError(f"a {self.kind} detection needs at least one option")
        c = float(self.confidence)
        if not math.isfinite(c):
            raise ValueError(f"Detection.confidence must be finite, got {self.confidence!r}")
        object.__setattr__(self, "confidence", min(1.0, max(0.0, c)))
        object.__setattr__(self, "options", sorted(opts, key=option_order))
        object.__setattr__(self, "diagnostics", clean_diagnostics(dict(self.diagnostics)))

    @classmethod
    def straight(cls, confidence: float = 1.0, **diagnostics: Any) -> Detection:
        """A straight-pipe detection."""
        return cls("straight", [], confidence, diagnostics)

    @property
    def distance(self) -> float:
        """Distance to the structure's reference point (the nearest option), metres; ``inf``
        for a straight pipe."""
        if not self.options:
            return math.inf
        return min(o.distance for o in self.options)

    def with_diagnostics(self, **extra: Any) -> Detection:
        return replace(self, diagnostics={**self.diagnostics, **extra})

    def describe(self) -> str:
        """One line per option in operator units."""
        if not self.options:
            return f"straight pipe (confidence {self.confidence:.2f})"
        head = f"{self.kind} (confidence {self.confidence:.2f})"
        return head + "".join(f"\n  - {o.describe()}" for o in self.options)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "options": [o.to_dict() for o in self.options],
            "confidence": self.confidence,
            "diagnostics": self.diagnostics,
        }
