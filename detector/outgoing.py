"""The outgoing pipe of a bend or junction as the improved detector fits it: shared by the
straight-axes model (:mod:`detector.branches`) and the long-radius bend model
(:mod:`detector.long_bend`), which both import it from here (neither imports the other's
fit types).

Angles in radians, lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class BranchFit:
    """One outgoing pipe: its axis deflected by ``theta`` (rad) from the incoming axis towards
    roll ``phi`` (rad), its radius ``rho`` (m), and for a long-radius bend the arc radius ``rb``
    (m; 0 for the straight-axes model)."""

    theta: float
    phi: float
    rho: float
    rb: float = 0.0
