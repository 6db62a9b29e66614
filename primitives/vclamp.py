"""The clamping V: the robot's middle modules folded towards one side until the apex touches.

:class:`VClamp` holds the V's half-angle (0: straight) and the side it folds towards (0: +y,
1: +z, 2: -y, 3: -z of the driven path's frame; clamping folds towards ``CLAMP_SIDE``, centring
probes all four). :meth:`VClamp.leg_poses` places the legs' modules about the apex: the joint
at the front of the V follows the driven path, the legs fold towards the side, and the modules
behind the V follow the path ``VClamp.shortening`` further back (a folded V shortens the
robot).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from detector.geometry import rotation_about
from pipe_env.robot import RobotConfig
from primitives.path import DrivenPath
from primitives.rotations import ry

#: The clamping V folds towards -z of the path frame (side 3, see ``V_SIDES``).
CLAMP_SIDE = 3

Fold = Callable[[float], NDArray[np.float64]]


def _v_side(n_local: tuple[float, float, float]) -> tuple[NDArray[np.float64], Fold, Fold]:
    """Apex direction in the path frame and the legs' rotations (front, rear) for a V folding
    towards it by half-angle ``a``."""
    nl = np.array(n_local, dtype=float)
    k = np.cross([1.0, 0.0, 0.0], nl)

    def front(a: float) -> NDArray[np.float64]:
        return rotation_about(k, -a)

    def rear(a: float) -> NDArray[np.float64]:
        return rotation_about(k, a)

    return nl, front, rear


def _ry_neg(a: float) -> NDArray[np.float64]:
    return ry(-a)


#: The V's fold sides (0: +y, 1: +z, 2: -y, 3: -z of the path frame), as the robot's wheels:
#: (apex direction, front leg's rotation, rear leg's rotation).
V_SIDES: dict[int, tuple[NDArray[np.float64], Fold, Fold]] = {
    0: _v_side((0.0, 1.0, 0.0)),
    1: _v_side((0.0, 0.0, 1.0)),
    2: _v_side((0.0, -1.0, 0.0)),
    3: (np.array([0.0, 0.0, -1.0]), _ry_neg, ry),
}


class VClamp:
    """The V's state (see module docstring): ``alpha`` its half-angle (rad), ``side`` the side
    it folds towards."""

    def __init__(self, config: RobotConfig) -> None:
        self.config = config
        self.alpha = 0.0
        self.side = CLAMP_SIDE

    @property
    def folded(self) -> bool:
        """True while the V is folded at all."""
        return self.alpha > 0.0

    @property
    def shortening(self) -> float:
        """How much closer the rear half follows the front along the path, m."""
        return 2.0 * self.config.leg_length * (1.0 - math.cos(self.alpha))

    def in_legs(self, i: int) -> bool:
        """True if module ``i`` is one of the folded V's legs."""
        c = self.config
        j, k = c.middle_joint, c.leg_modules
        return self.alpha > 0.0 and j - k <= i < j + k

    def behind(self, i: int) -> bool:
        """True if module ``i`` is behind the V (it follows the path ``shortening`` further)."""
        return i >= self.config.middle_joint + self.config.leg_modules

    def leg_poses(
        self, path: DrivenPath, odometer: float
    ) -> dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """Module index -> (position m, rotation) of the folded V's legs, the front module at
        ``odometer`` m of ``path``; empty while the V is straight."""
        a = self.alpha
        if a <= 0.0:
            return {}
        c = self.config
        j, k = c.middle_joint, c.leg_modules
        n_local, fold_front, fold_rear = V_SIDES[self.side]
        rot_front, rot_rear = fold_front(a), fold_rear(a)
        s_top = odometer - (j - k - 0.5) * c.pitch  # joint at the front of the V
        p0, r0 = path.pose(s_top)
        x, nv = r0[:, 0], r0 @ n_local  # the apex goes towards nv
        out = {}
        for i in range(j - k, j + k):
            if i < j:  # front leg, going towards the apex
                along = (i - (j - k) + 0.5) * c.pitch
                pos = p0 - along * math.cos(a) * x + along * math.sin(a) * nv
                rot = r0 @ rot_front
            else:  # rear leg, coming back
                apex = p0 - c.leg_length * (math.cos(a) * x - math.sin(a) * nv)
                along = (i - j + 0.5) * c.pitch
                pos = apex - along * math.cos(a) * x - along * math.sin(a) * nv
                rot = r0 @ rot_rear
            out[i] = (pos, rot)
        return out
