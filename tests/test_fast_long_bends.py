"""The fast fidelity takes a long bend as the full loop does: on its own arc, complying with the
walls to the arc's end, so a lower bound of its angle (seen short of the arc's end) does not
jam where the arc's start is right; a mitre bend read as short does."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from detector.options import StructureOption
from pipe_env import layouts
from pipe_env.envs.plant import KinematicPlant, PlantStatus


def _take(net, read) -> PlantStatus:  # noqa: ANN001
    plant = KinematicPlant(net, "ground_truth", drive_jam_rate=0.0)
    plant.reset(np.random.default_rng(0))
    dec, _ = plant.advance()
    assert dec is not None and len(dec.truth) == 1
    return plant.execute(read(dec.truth[0])).status


def _short(o: StructureOption, by: float, keep_arc: bool) -> StructureOption:
    angle = o.angle - by
    nearer = o.bend_radius * (math.tan(0.5 * o.angle) - math.tan(0.5 * angle)) if keep_arc else 0
    return replace(o, angle=angle, distance=o.distance - nearer)


def test_a_long_bend_read_short_with_its_arc_start_right_does_not_jam() -> None:
    net = layouts.long_bend(0.1, radius_factor=2.0)
    assert _take(net, lambda t: t) == PlantStatus.DONE
    assert _take(net, lambda t: _short(t, math.radians(30.0), keep_arc=True)) == PlantStatus.DONE
    # the arc's start 6 cm early (the reference point kept as read): a jam
    assert _take(net, lambda t: _short(t, math.radians(30.0), keep_arc=False)) == (
        PlantStatus.JAMMED
    )
    # read beyond its angle: a jam, as for any turn
    net60 = layouts.long_bend(0.1, angle=math.radians(60.0), radius_factor=2.0)
    assert _take(net60, lambda t: replace(t, angle=t.angle + math.radians(15.0))) == (
        PlantStatus.JAMMED
    )


def test_a_mitre_bend_read_short_jams() -> None:
    net = layouts.mitre_bend(0.1)
    assert _take(net, lambda t: t) == PlantStatus.DONE
    assert _take(net, lambda t: replace(t, angle=t.angle - math.radians(30.0))) == (
        PlantStatus.JAMMED
    )
