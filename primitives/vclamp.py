"""The clamping V: the robot's middle modules folded towards one side until the apex touches.

:class:`VClamp` holds the V's half-angle (0: straight) and the side it folds towards (0: +y,
1: +z, 2: -y, 3: -z of the driven path's frame; clamping folds towards ``CLAMP_SIDE``, centring
probes all four). :meth:`VClamp.leg_poses` places the legs' modules about the apex: the joint
at the front of the V follows the driven path, the legs fold towards the side, and the modules
behind the V follow the path ``VClamp.shortening`` further back (a folded V shortens the
robot). :meth:`VClamp.leg_targets` does the same into the executor's per-tick target arrays.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
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
        j, k = config.middle_joint, config.leg_modules
        #: the V's front joint is this far behind the front module along the path, m
        self._apex_back = (j - k - 0.5) * config.pitch
        self._leg_length = config.leg_length
        #: the legs' rotations of the last (side, alpha) asked for
        self._folds: tuple[int, float, NDArray[np.float64]] | None = None

    @property
    def folded(self) -> bool:
        """True while the V is folded at all."""
        return self.alpha > 0.0

    @property
    def shortening(self) -> float:
        """How much closer the rear half follows the front along the path, m."""
        return 2.0 * self._leg_length * (1.0 - math.cos(self.alpha))

    def in_legs(self, i: int) -> bool:
        """True if module ``i`` is one of the folded V's legs."""
        c = self.config
        j, k = c.middle_joint, c.leg_modules
        return self.alpha > 0.0 and j - k <= i < j + k

    def behind(self, i: int) -> bool:
        """True if module ``i`` is behind the V (it follows the path ``shortening`` further)."""
        return i >= self.config.middle_joint + self.config.leg_modules

    def _fold_rotations(self) -> NDArray[np.float64]:
        """The front and rear legs' rotations (2, 3, 3) in the path frame at the current side
        and half-angle (kept while they stay the same)."""
        f = self._folds
        if f is None or f[0] != self.side or f[1] != self.alpha:
            _, fold_front, fold_rear = V_SIDES[self.side]
            f = (self.side, self.alpha, np.stack([fold_front(self.alpha), fold_rear(self.alpha)]))
            self._folds = f
        return f[2]

    def apex_odometer(self, odometer: float) -> float:
        """Odometer (m) of the driven path at the joint at the front of the V, the front
        module being at ``odometer`` m."""
        return odometer - self._apex_back

    def leg_targets(
        self,
        p0: NDArray[np.float64],
        r0: NDArray[np.float64],
        positions: NDArray[np.float64],
        rotations: NDArray[np.float64],
    ) -> bool:
        """:meth:`leg_poses` written into rows ``i`` of ``positions`` (n, 3) m and ``rotations``
        (n, 3, 3) for every leg module ``i`` (bit for bit the same poses), the driven path's
        pose at :meth:`apex_odometer` being ``p0`` (m), ``r0``; returns False (and writes
        nothing) while the V is straight."""
        a = self.alpha
        if a <= 0.0:
            return False
        c = self.config
        j, k = c.middle_joint, c.leg_modules
        nv = r0 @ V_SIDES[self.side][0]  # the apex goes towards nv
        ca, sa = math.cos(a), math.sin(a)
        _leg_positions(p0, r0, nv, ca, sa, c.leg_length, c.pitch, j, k, positions)
        legs = r0 @ self._fold_rotations()
        rotations[j - k : j] = legs[0]
        rotations[j : j + k] = legs[1]
        return True

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


@numba.njit(cache=True, error_model="numpy")
def _leg_positions(
    p0: NDArray[np.float64],
    r0: NDArray[np.float64],
    nv: NDArray[np.float64],
    ca: float,
    sa: float,
    leg_length: float,
    pitch: float,
    j: int,
    k: int,
    out: NDArray[np.float64],
) -> None:
    """The legs' module positions of :meth:`VClamp.leg_poses` (the same arithmetic, in the same
    order) into rows ``j - k .. j + k - 1`` of ``out``: apex joint ``p0`` (m), path frame ``r0``
    (its axis: the first column), apex direction ``nv``, ``ca``/``sa`` the cosine and sine of
    the half-angle."""
    for i in range(j - k, j + k):
        if i < j:  # front leg, going towards the apex
            along = (i - (j - k) + 0.5) * pitch
            for c in range(3):
                out[i, c] = p0[c] - along * ca * r0[c, 0] + along * sa * nv[c]
        else:  # rear leg, coming back
            along = (i - j + 0.5) * pitch
            for c in range(3):
                apex = p0[c] - leg_length * (ca * r0[c, 0] - sa * nv[c])
                out[i, c] = apex - along * ca * r0[c, 0] - along * sa * nv[c]
