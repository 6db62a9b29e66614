"""What the agent does: the action type of the environments, its space, mask and checking.

In the manner of highway-env's ``ActionType``: :class:`OptionAction` owns the action space
(``Discrete(K)``, :meth:`~OptionAction.space`), checks an action strictly
(:meth:`~OptionAction.check`: integers of the space only, so ``0.9``, ``"1"`` or ``True`` are
refused rather than rounded), marks the rows the robot would attempt (:meth:`~OptionAction.mask`)
and turns a row into what the plant executes (:meth:`~OptionAction.choice`).

| row | action |
|---|---|
| ``0..K-2`` | the detected way in that row (straight on first, then by roll direction) |
| ``K-1`` | back out to the last junction passed (or the start) and decide again |

A row is allowed (mask True) when it holds a detected way inside the robot's 57-125 mm range
turning at most 90 deg (:func:`pipe_env.robot_limits.drivable`); backing out always is.
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from detector.options import StructureOption
from detector.validation import ArgumentError
from pipe_env.envs.plant import BACK_OUT
from pipe_env.robot_limits import drivable

#: Rows of the options table: K-1 detected ways on and "back out".
K_OPTIONS = 6
#: The back-out row.
BACK_ROW = K_OPTIONS - 1


class OptionAction:
    """The discrete action type of both environments (see the module docstring)."""

    n = K_OPTIONS

    def space(self) -> spaces.Discrete:
        """``Discrete(K)``."""
        return spaces.Discrete(self.n)

    def check(self, action: Any) -> int:
        """``action`` as an int row, refusing anything but an integer of the space.

        Raises:
            ValueError (:class:`~detector.validation.ArgumentError`): not a Python or numpy
                integer (a bool, float, string, array...) or outside ``0..K-1``.
        """
        if isinstance(action, np.ndarray) and action.shape == () and action.dtype.kind in "iu":
            action = action.item()
        if (
            isinstance(action, bool | np.bool_)
            or not isinstance(action, numbers.Integral | np.integer)
            or not 0 <= int(action) < self.n
        ):
            raise ArgumentError(
                "action",
                action,
                f"an integer (Python or numpy) in Discrete({self.n}), 0..{self.n - 1}",
                problem=f"not allowed ({type(action).__name__})",
            )
        return int(action)

    def mask(self, options: list[StructureOption] | None) -> NDArray[np.bool_]:
        """The rows the robot would attempt for the pending ``options`` (None: no decision
        pending, only backing out is allowed)."""
        mask = np.zeros(self.n, dtype=bool)
        for i, o in enumerate((options or [])[:BACK_ROW]):
            mask[i] = drivable(o)
        mask[BACK_ROW] = True
        return mask

    @staticmethod
    def choice(options: list[StructureOption], row: int) -> StructureOption | str:
        """What the plant executes for ``row``: a detected way, or :data:`BACK_OUT`."""
        return BACK_OUT if row == BACK_ROW else options[row]
