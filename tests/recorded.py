"""Comparing a run against its recorded values: exactly where a value is discrete, to a tolerance
where it is a float.

Pinned rollouts used to be sha256 digests of their values, floats rounded to 9 decimals. A
machine with other SIMD extensions (AVX2 against AVX-512: numpy's vectorised transcendental
functions differ in the last bits) gives the same decisions, statuses, counts and kinds, with
floats that the physics has carried from the last bit to the 1e-9 digit. So the values are
recorded, and a run must repeat every string, bool and integer and every float to within
``RTOL``/``ATOL``: a change of behaviour moves them by millimetres at once.
"""

from __future__ import annotations

import math
from typing import Any

#: Relative and absolute tolerance of a float (metres, seconds, radians: 10 micrometres).
RTOL, ATOL = 1e-6, 1e-5


def mismatches(
    got: Any, want: Any, path: str = "", rtol: float = RTOL, atol: float = ATOL
) -> list[str]:
    """Where ``got`` departs from the recorded ``want`` (both JSON's own types:
    :func:`pipe_env.network_io.plain` makes them): one line per
    differing leaf, ``path: got != want``; empty when they agree."""
    if isinstance(want, dict) and isinstance(got, dict):
        if sorted(got) != sorted(want):
            return [f"{path}: keys {sorted(got)} != {sorted(want)}"]
        return [
            m for k in sorted(want) for m in mismatches(got[k], want[k], f"{path}/{k}", rtol, atol)
        ]
    if isinstance(want, list) and isinstance(got, list):
        if len(got) != len(want):
            return [f"{path}: {len(got)} items != {len(want)}"]
        return [
            m
            for i, (a, b) in enumerate(zip(got, want))
            for m in mismatches(a, b, f"{path}[{i}]", rtol, atol)
        ]
    if isinstance(want, float) and isinstance(got, (float, int)) and not isinstance(got, bool):
        same = math.isclose(got, want, rel_tol=rtol, abs_tol=atol) or (
            math.isnan(got) and math.isnan(want)
        )
        return [] if same else [f"{path}: {got!r} != {want!r}"]
    if type(got) is not type(want) or got != want:
        return [f"{path}: {got!r} != {want!r}"]
    return []
