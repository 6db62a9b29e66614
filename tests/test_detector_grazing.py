"""The ring-hole finder on synthetic grids: a far side bump over part of one ring is a hole
(placed and sized by its far side), a bump all around or on several rings is not."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from detector import grazing
from detector.grazing import find_ring_holes

R = 0.0285
ROWS = 180  # rolls, 2 deg apart
STEP = math.radians(0.5)
BETAS = np.radians(np.arange(1.0, 30.0, 0.5))[::-1]  # far rings first


def _grid(position: float | None, rho: float, roll: float, all_around: bool = False):
    """(xyz, valid, sigma) of a noiseless scan of a straight run of radius R with a
    perpendicular branch of radius ``rho`` at ``position`` (None: no branch)."""
    phi = np.linspace(-math.pi, math.pi, ROWS, endpoint=False)[:, None]
    tb = np.tan(BETAS)[None, :]
    u = R / tb * np.ones_like(phi)
    if position is not None:
        dphi = phi - roll
        sd = np.sin(dphi)
        # the beam enters where it crosses the run's wall inside the hole ...
        inside = ((R / tb - position) ** 2 + (R * sd) ** 2 < rho * rho) & (np.cos(dphi) > 0.0)
        if all_around:
            inside = np.abs(R / tb - position) < rho * np.ones_like(phi)
            sd = np.zeros_like(sd)
        # ... and runs on to the branch's far side: (u - position)^2 + (u tb sd)^2 = rho^2
        a = 1.0 + (tb * sd) ** 2
        far = (position + np.sqrt(np.maximum(position**2 - a * (position**2 - rho**2), 0.0))) / a
        u = np.where(inside, far, u)
    r = u * tb
    xyz = np.stack([u, r * np.cos(phi), r * np.sin(phi)])
    valid = np.ones(u.shape, dtype=bool)
    return xyz, valid, np.zeros(u.shape)


@settings(max_examples=25, deadline=None)
@given(
    position=st.floats(0.25, 0.45),
    rho=st.floats(0.6 * R, R),
    roll=st.floats(-math.pi, math.pi),
)
def test_one_ring_hole_is_placed_and_sized(position: float, rho: float, roll: float) -> None:
    xyz, valid, sig = _grid(position, rho, roll)
    holes = find_ring_holes(xyz, valid, sig, True, R, before=2.0, beam_step=STEP)
    entered = np.unique(np.nonzero(np.abs(np.hypot(xyz[1], xyz[2]) - R) > 0.00035)[1])
    if entered.size != 1:
        return  # no single ring entered far enough (or several: the regular detector's case)
    if not holes:
        # a ring that enters only the edge of the hole shows too few returns beyond the wall
        assert np.count_nonzero(np.hypot(xyz[1], xyz[2]) - R > 0.00035) < 12
        return
    (h,) = holes
    assert abs(h.position - position) < 0.003
    assert abs(h.radius - rho) < 0.003
    assert abs((h.roll - roll + math.pi) % (2 * math.pi) - math.pi) < math.radians(3.0)


def test_straight_run_has_no_hole() -> None:
    xyz, valid, sig = _grid(None, R, 0.0)
    assert find_ring_holes(xyz, valid, sig, True, R, before=2.0, beam_step=STEP) == []


def test_bump_all_around_is_no_side_hole() -> None:
    xyz, valid, sig = _grid(0.4, R, 0.0, all_around=True)
    assert find_ring_holes(xyz, valid, sig, True, R, before=2.0, beam_step=STEP) == []


def test_roll_span_guard_rejects_a_bump_all_around(monkeypatch: pytest.MonkeyPatch) -> None:
    # a far-side fit that accepts every bump: only the roll-span guard can reject one
    def fit_anything(
        p: np.ndarray, big_r: float, cfg: object, sigma_range: object = None
    ) -> grazing.RingHole:
        return grazing.RingHole(0.4, big_r, 0.0, int(p.shape[1]), 0.0, 0.4)

    monkeypatch.setattr(grazing, "_fit_far_side", fit_anything)
    xyz, valid, sig = _grid(0.4, R, 0.0, all_around=True)
    assert find_ring_holes(xyz, valid, sig, True, R, before=2.0, beam_step=STEP) == []
    # (a bump over part of the circumference passes the guard)
    xyz, valid, sig = _grid(0.4, R, 1.0)
    assert len(find_ring_holes(xyz, valid, sig, True, R, before=2.0, beam_step=STEP)) == 1


def test_holes_past_the_limit_are_left_out() -> None:
    xyz, valid, sig = _grid(0.4, R, 1.0)
    assert len(find_ring_holes(xyz, valid, sig, True, R, before=2.0, beam_step=STEP)) == 1
    assert find_ring_holes(xyz, valid, sig, True, R, before=0.35, beam_step=STEP) == []
