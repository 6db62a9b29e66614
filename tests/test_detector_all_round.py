"""The split of a region of returns that goes all round the axis (a tee entered from a
narrower stem): the depth profile over the azimuth and the sharing out of the region's returns
among its deep parts (``detector.branches``)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from detector.branches import _nearest_in_roll, _profile_depth


def _ring(rolls: np.ndarray, radius: float, x: float = 0.3) -> np.ndarray:
    """(n, 3) pipe-frame points at ``rolls`` (rad), ``radius`` m from the axis."""
    return np.column_stack([np.full(rolls.size, x), radius * np.cos(rolls), radius * np.sin(rolls)])


def test_the_profile_middle_lies_between_the_bulge_and_the_ways_along_the_run() -> None:
    # a run along roll 0 / pi reaching 29 mm beyond the wall, its wall bulging 16 mm square to it
    rolls = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    depth = 0.0225 + 0.0065 * np.cos(2.0 * rolls)
    middle = _profile_depth(_ring(rolls, 0.05), depth, 24, 0.0024)
    assert middle is not None
    # the deepest return per 15 deg sector: from 16.8 mm (square) to 29 mm (along the run)
    assert 0.0220 < middle < 0.0230
    deep = depth > middle
    # beyond it, two parts: one about each way along the run
    assert deep[np.abs(rolls) < math.radians(30)].all()
    assert deep[np.abs(np.abs(rolls) - math.pi) < math.radians(30)].all()
    assert not deep[np.abs(np.abs(rolls) - math.pi / 2) < math.radians(30)].any()


def test_a_sparse_profile_gives_no_middle() -> None:
    # returns in fewer than half the sectors: no profile to split by
    rolls = np.linspace(-0.5, 0.5, 200)
    assert _profile_depth(_ring(rolls, 0.05), np.full(rolls.size, 0.01), 24, 0.0) is None


def test_an_even_region_gives_no_middle() -> None:
    # all round, its depth varying by 2 mm: no way stands out beyond a 2.4 mm contrast
    rolls = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    depth = 0.010 + 0.001 * np.cos(2.0 * rolls)
    assert _profile_depth(_ring(rolls, 0.05), depth, 24, 0.0024) is None
    assert _profile_depth(_ring(rolls, 0.05), depth, 24, 0.001) is not None


@settings(max_examples=50, deadline=None)
@given(
    centres=st.lists(
        st.floats(-math.pi, math.pi, allow_nan=False), min_size=2, max_size=4, unique=True
    ),
    seed=st.integers(0, 2**16),
)
def test_every_return_goes_to_the_part_nearest_in_roll(centres: list[float], seed: int) -> None:
    rng = np.random.default_rng(seed)
    grid = (36, 20)
    mask = rng.random(grid) < 0.6
    n = int(mask.sum())
    rolls = rng.uniform(-math.pi, math.pi, n)
    # each deep part: a few returns at its centre's roll
    cells = np.flatnonzero(mask)
    parts = []
    for j, c in enumerate(centres):
        rolls[j] = c
        part = np.zeros(grid, dtype=bool)
        part.flat[cells[j]] = True
        parts.append((part, 1, None))
    p = _ring(rolls, 0.05)
    shared = _nearest_in_roll(mask, p, parts)
    assert len(shared) == len(parts)
    owned = np.zeros(grid, dtype=int)
    for j, (m, count, pts) in enumerate(shared):
        assert count == int(m.sum()) and pts is not None and pts.shape == (count, 3)
        assert not (m & ~mask).any()
        owned += m
        # each of its returns is no nearer in roll to another part's centre
        own = m[mask]
        gap = np.abs(np.angle(np.exp(1j * (rolls[own, None] - np.array(centres)[None, :]))))
        assert (gap[:, j] <= gap.min(axis=1) + 1e-12).all()
    assert (owned == mask).all()
