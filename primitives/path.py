"""The driven path: the drive target's poses by odometer, the executor's memory of where it went.

Every follower module of the robot is welded to the pose the front module had at its place
(follow-the-leader), and reversing retraces the path, so the executor keeps the path as samples
(odometer s in metres, world position in metres, rotation matrix) in growing arrays. The path
is stored in the rear half's frame (the commanded roll of the front half removed). Samples are
appended in increasing odometer order; :meth:`DrivenPath.truncate` forgets everything beyond
an odometer (driving forward again after reversing, or after a stall).
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

#: Smallest capacity the sample arrays grow to, samples.
MIN_CAPACITY = 1024


class DrivenPath:
    """Samples (s, position, rotation) of the driven path, s increasing (see module docstring).

    ``s``, ``positions`` and ``rotations`` are views of the stored samples: (N,) m, (N, 3) m and
    (N, 3, 3).
    """

    def __init__(self) -> None:
        self._cap = 0
        self._hs: NDArray[np.float64] = np.zeros(0)
        self._hp: NDArray[np.float64] = np.zeros((0, 3))
        self._hr: NDArray[np.float64] = np.zeros((0, 3, 3))
        self._n = 0

    def clear(self) -> None:
        """Forget every sample and release the arrays (the next push allocates small ones)."""
        self._cap, self._n = 0, 0
        self._hs, self._hp, self._hr = np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3))

    def __len__(self) -> int:
        return self._n

    @property
    def capacity(self) -> int:
        """Samples the arrays hold before they grow."""
        return self._cap

    @property
    def s(self) -> NDArray[np.float64]:
        return self._hs[: self._n]

    @property
    def positions(self) -> NDArray[np.float64]:
        return self._hp[: self._n]

    @property
    def rotations(self) -> NDArray[np.float64]:
        return self._hr[: self._n]

    def push_many(self, s: NDArray, p: NDArray, r: NDArray) -> None:
        """Append samples: odometers ``s`` (K,) m, positions ``p`` (K, 3) m, rotations ``r``
        (K, 3, 3) or one (3, 3) for all."""
        k = len(s)
        self._ensure(self._n + k)
        self._hs[self._n : self._n + k] = s
        self._hp[self._n : self._n + k] = p
        self._hr[self._n : self._n + k] = r
        self._n += k

    def push(self, s: float, p: NDArray, r: NDArray) -> None:
        """Append one sample: odometer ``s`` m, position ``p`` (3,) m, rotation ``r`` (3, 3)."""
        self._ensure(self._n + 1)
        self._hs[self._n] = s
        self._hp[self._n] = p
        self._hr[self._n] = r
        self._n += 1

    def _ensure(self, size: int) -> None:
        if size <= self._cap:
            return
        cap = max(MIN_CAPACITY, 2 * size)
        hs, hp, hr = np.zeros(cap), np.zeros((cap, 3)), np.zeros((cap, 3, 3))
        hs[: self._n], hp[: self._n], hr[: self._n] = (
            self._hs[: self._n],
            self._hp[: self._n],
            self._hr[: self._n],
        )
        self._hs, self._hp, self._hr, self._cap = hs, hp, hr, cap

    def truncate(self, s: float) -> None:
        """Forget the samples beyond odometer ``s`` m (the first sample is always kept)."""
        k = int(np.searchsorted(self._hs[: self._n], s, side="right"))
        self._n = max(k, 1)

    def pose(self, s: float) -> tuple[NDArray, NDArray]:
        """Pose (position m, rotation) of the driven path at odometer ``s`` m: interpolated
        between samples, extrapolated straight beyond the ends."""
        hs = self._hs[: self._n]
        if s <= hs[0]:
            r = self._hr[0]
            return self._hp[0] + (s - hs[0]) * r[:, 0], r
        if s >= hs[-1]:
            r = self._hr[self._n - 1]
            return self._hp[self._n - 1] + (s - hs[-1]) * r[:, 0], r
        k = int(np.searchsorted(hs, s))
        s0, s1 = hs[k - 1], hs[k]
        w = (s - s0) / (s1 - s0) if s1 > s0 else 0.0
        p = (1 - w) * self._hp[k - 1] + w * self._hp[k]
        return p, self._hr[k if w > 0.5 else k - 1]

    def poses_into(
        self, s: NDArray[np.float64], positions: NDArray[np.float64], rotations: NDArray[np.float64]
    ) -> None:
        """:meth:`pose` at every odometer of ``s`` (K,) m in one call: positions (K, 3) m and
        rotations (K, 3, 3) are written into the given arrays (the same arithmetic as
        :meth:`pose`, bit for bit)."""
        _poses_into(self._hs, self._hp, self._hr, self._n, s, positions, rotations)

    def shift(self, indices: NDArray[np.intp], weights: NDArray, move: NDArray) -> None:
        """Move the samples ``indices`` by ``weights[:, None] * move`` (m)."""
        self._hp[indices] += weights[:, None] * move[None, :]


@numba.njit(cache=True, error_model="numpy")
def _poses_into(
    hs: NDArray[np.float64],
    hp: NDArray[np.float64],
    hr: NDArray[np.float64],
    n: int,
    s: NDArray[np.float64],
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
) -> None:
    """:meth:`DrivenPath.pose` of the first ``n`` samples at every odometer of ``s``."""
    first, last = hs[0], hs[n - 1]
    for i in range(s.shape[0]):
        si = s[i]
        if si <= first or si >= last:
            k = 0 if si <= first else n - 1
            ds = si - hs[k]
            for j in range(3):
                positions[i, j] = hp[k, j] + ds * hr[k, j, 0]
            rotations[i] = hr[k]
            continue
        k = np.searchsorted(hs[:n], si)
        s0, s1 = hs[k - 1], hs[k]
        w = (si - s0) / (s1 - s0) if s1 > s0 else 0.0
        for j in range(3):
            positions[i, j] = (1 - w) * hp[k - 1, j] + w * hp[k, j]
        rotations[i] = hr[k if w > 0.5 else k - 1]
