"""The simulation fidelity of an environment or plant: :class:`Fidelity`, :data:`FIDELITIES`.

``fast``: kinematic motion on the centreline and modelled sensing (RL iterations); ``full``: the
MuJoCo robot, the rotating LiDAR, the detector and the primitive executor. Members are strings
(see :class:`detector.vocab.StrEnum`), so arguments and files keep accepting ``"fast"``/``"full"``.
"""

from __future__ import annotations

from detector.vocab import StrEnum


class Fidelity(StrEnum):
    """How faithfully the robot and its sensing are simulated."""

    FAST = "fast"
    FULL = "full"


#: The fidelities as plain strings, in :class:`Fidelity` order.
FIDELITIES: tuple[str, ...] = tuple(f.value for f in Fidelity)
