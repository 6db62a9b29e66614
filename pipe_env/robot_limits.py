"""The robot's limits as the rest of the project needs them: the inner diameters the PIRATE
works in, the largest turn it drives through, and the margins with which it attempts a sensed way.

A module of its own so that motion primitives, the plants and the generator share these
numbers without importing one another.
"""

from __future__ import annotations

import math

from detector.options import StructureOption

#: The PIRATE's working range of inner diameters, metres.
ROBOT_DIAMETER_RANGE = (0.057, 0.125)

#: Largest deflection the robot can drive through at one fitting, radians: 90 deg plus the
#: angular tolerance with which networks are validated (a tee branch may be 90.5 deg).
MAX_TURN = math.radians(90.5) + 1e-6

#: Sensed values are noisy: a true 90 deg way may be sensed at 91 deg. The robot attempts ways
#: sensed up to this much beyond its turn limit (fittings turn at most 90 deg, thesis
#: assumption ii) and diameters this far outside its range; execution checks the truth.
SENSED_ANGLE_MARGIN = math.radians(10.0)
SENSED_DIAMETER_MARGIN = 0.001


def drivable(
    option: StructureOption,
    diameter_range: tuple[float, float] = ROBOT_DIAMETER_RANGE,
    max_turn: float = MAX_TURN,
) -> bool:
    """Whether the robot would attempt this sensed way on: inside its diameter range and turn
    limit, with the sensing margins above."""
    if option.kind in ("closure", "straight"):
        return False
    lo, hi = diameter_range
    return (
        lo - SENSED_DIAMETER_MARGIN <= option.diameter <= hi + SENSED_DIAMETER_MARGIN
        and option.angle <= max_turn + SENSED_ANGLE_MARGIN
    )
