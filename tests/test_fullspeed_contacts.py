"""Near contacts: the robot colliding only with the wall pieces near it has the contacts that
MuJoCo's automatic collisions against every piece have, at every physics step."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from pipe_env import layouts
from pipe_env.ground_truth import structures_ahead
from pipe_env.world import CONTACT_BIT, NearContacts, build_world
from primitives.executor import Executor
from primitives.sequences import for_option, go_straight


def _contacts(m: mujoco.MjModel, d: mujoco.MjData) -> dict[tuple[int, int], list]:
    out: dict[tuple[int, int], list] = {}
    for c in d.contact[: d.ncon]:
        key = (min(c.geom1, c.geom2), max(c.geom1, c.geom2))
        out.setdefault(key, []).append(
            np.concatenate(
                [[c.dist], c.pos, c.solref, c.solimp, c.friction, [c.dim], [c.includemargin]]
            )
        )
    return {k: sorted(v, key=lambda row: tuple(row)) for k, v in out.items()}


def _automatic(ex: Executor, d: mujoco.MjData) -> dict[tuple[int, int], list]:
    """Contacts of the state ``d`` with automatic collisions against every piece."""
    m = ex.model
    bodies = ex.robot.body_ids
    saved = (m.pair_geom1.copy(), m.pair_geom2.copy(), m.body_contype.copy())
    saved_affinity = m.body_conaffinity.copy()
    park = (m.geom("park:a").id, m.geom("park:b").id)
    m.pair_geom1[:], m.pair_geom2[:], m.body_contype[0] = park[0], park[1], CONTACT_BIT
    m.body_conaffinity[bodies] = CONTACT_BIT
    try:
        dc = mujoco.MjData(m)
        mujoco.mj_copyData(dc, m, d)
        mujoco.mj_forward(m, dc)
        return _contacts(m, dc)
    finally:
        m.pair_geom1[:], m.pair_geom2[:], m.body_contype[:] = saved
        m.body_conaffinity[:] = saved_affinity


def _near(ex: Executor, d: mujoco.MjData) -> dict[tuple[int, int], list]:
    dc = mujoco.MjData(ex.model)
    mujoco.mj_copyData(dc, ex.model, d)
    mujoco.mj_forward(ex.model, dc)
    return _contacts(ex.model, dc)


def _same(a: dict, b: dict) -> bool:
    if a.keys() != b.keys():
        return False
    return all(
        len(a[k]) == len(b[k]) and all(np.allclose(x, y, atol=1e-9) for x, y in zip(a[k], b[k]))
        for k in a
    )


def _checked(ex: Executor, log: list[tuple[int, int, bool]], every_step: bool = False) -> None:
    """Step the executor's ticks one physics step at a time, comparing near and automatic
    contacts before the last step of every tick (where the pair selection is oldest), or before
    every step; ``log`` gets (near contacts, automatic, same)."""

    def physics() -> None:
        assert ex.near is not None
        ex.near.update(ex.data)
        for k in range(ex.substeps):
            if every_step or k == ex.substeps - 1:
                a, b = _near(ex, ex.data), _automatic(ex, ex.data)
                log.append((sum(map(len, a.values())), sum(map(len, b.values())), _same(a, b)))
            mujoco.mj_step(ex.model, ex.data)

    ex._physics = physics  # type: ignore[method-assign]


def _turn(ex: Executor, net) -> str:
    o = structures_ahead(net, ex.robot.sensor_pose(), 5.0)[0]
    out = ex.run(for_option(o, incoming_diameter=ex.robot.clamped_diameter()))
    return out.status


def test_near_contacts_equal_the_automatic_ones_through_a_mitre_turn() -> None:
    net = layouts.mitre_bend(0.06, math.pi / 2, math.pi / 2)
    ex = Executor.for_network(net, lidar=None)
    assert ex.near is not None
    log: list[tuple[int, int, bool]] = []
    _checked(ex, log)
    ex.run(go_straight(0.05))
    assert _turn(ex, net) == "done"
    assert len(log) > 300
    assert sum(1 for n, _, _ in log if n > 0) >= 20  # the turn presses wheels on the walls
    assert all(same for _, _, same in log), [i for i, (_, _, s) in enumerate(log) if not s][:5]
    assert ex.near.fallbacks == 0 and ex.near.overruns == 0
    assert ex.model.body_contype[0] == 0 and ex.near.n_pairs > 0


@pytest.mark.slow
def test_near_contacts_equal_the_automatic_ones_at_every_step_of_a_tee_branch() -> None:
    net = layouts.t_junction(0.09, direction=math.pi / 2)
    ex = Executor.for_network(net, lidar=None)
    log: list[tuple[int, int, bool]] = []
    _checked(ex, log, every_step=True)
    ex.run(go_straight(0.1))
    assert _turn(ex, net) == "done"
    assert sum(1 for n, _, _ in log if n > 0) >= 100
    assert all(same for _, _, same in log), [i for i, (_, _, s) in enumerate(log) if not s][:5]
    assert ex.near is not None and ex.near.fallbacks == 0 and ex.near.overruns == 0


def test_the_comparison_catches_a_missing_pair() -> None:
    """The check above can fail: a selection that drops the pairs of one touching geom
    (here: too small a reach with no margin for motion) is caught."""
    net = layouts.mitre_bend(0.06, math.pi / 2, math.pi / 2)
    ex = Executor.for_network(net, lidar=None)
    assert ex.near is not None
    d = ex.data
    touching = {
        c.geom1 if c.geom1 in set(ex.robot.geom_ids) else c.geom2 for c in d.contact[: d.ncon]
    }
    assert touching
    keep = np.array([g for g in ex.robot.geom_ids if g != min(touching)])
    broken = NearContacts(ex.world, keep)
    broken.update(d, force=True)
    assert not _same(_near(ex, d), _automatic(ex, d))
    ex.near.update(d, force=True)
    assert _same(_near(ex, d), _automatic(ex, d))


def test_the_robot_drives_the_same_with_near_or_all_contacts() -> None:
    net = layouts.t_junction(0.09, direction=math.pi / 2)
    results = []
    for use in (True, False):
        ex = Executor.for_network(net, lidar=None)
        ex.use_near_contacts(use)
        ex.run(go_straight(0.1))
        status = _turn(ex, net)
        results.append((status, ex.robot.sensor_pose().position, ex.robot.joint_angles()))
    (s0, p0, j0), (s1, p1, j1) = results
    assert s0 == s1 == "done"
    assert np.allclose(p0, p1, atol=1e-6)
    assert np.allclose(j0, j1, atol=1e-5)


def test_near_contacts_reject_bad_input() -> None:
    world = build_world(layouts.straight(0.1))
    with pytest.raises(ValueError, match="reach"):
        NearContacts(world, np.array([0]), reach=0.5)
    bare = build_world(layouts.straight(0.1), contact_walls=False)
    with pytest.raises(ValueError, match="predefined pairs"):
        NearContacts(bare, np.array([0]))


def test_too_many_pairs_for_the_pool_fall_back_to_automatic_collisions() -> None:
    net = layouts.mitre_bend(0.06, math.pi / 2, math.pi / 2)
    ex = Executor.for_network(net, lidar=None)
    near = ex.near
    assert near is not None and near.n_pairs > 0
    near.reach = 0.05  # every piece within 5 cm: more pairs than the pool holds
    near.update(ex.data, force=True)
    assert near.fallbacks == 1 and near.n_pairs == 0
    assert ex.model.body_contype[0] == CONTACT_BIT
    assert np.all(ex.model.body_conaffinity[ex.robot.body_ids] == CONTACT_BIT)
    assert _same(_near(ex, ex.data), _automatic(ex, ex.data))
    ex.run(go_straight(0.05))
    assert near.overruns == 0


def test_static_walls_posed_once_change_nothing_in_the_robot_drive() -> None:
    """The world poses its static wall geoms once (MuJoCo's sleeping, with the robot kept
    awake): the drive is bit-for-bit the drive with every geom posed at every step."""
    net = layouts.t_junction(0.09, direction=math.pi / 2)
    sleep = int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    results = []
    for posed_once in (True, False):
        ex = Executor.for_network(net, lidar=None)
        assert bool(ex.model.opt.enableflags & sleep)
        assert np.all(ex.model.tree_sleep_policy == mujoco.mjtSleepPolicy.mjSLEEP_NEVER)
        if not posed_once:
            ex.model.opt.enableflags &= ~sleep
        ex.run(go_straight(0.1))
        status = _turn(ex, net)
        assert ex.data.ntree_awake == ex.model.ntree  # (the robot never slept)
        results.append((status, ex.data.qpos.copy(), ex.data.geom_xpos.copy(), ex.data.time))
    (s0, q0, g0, t0), (s1, q1, g1, t1) = results
    assert s0 == s1 == "done" and t0 == t1
    assert np.array_equal(q0, q1)
    assert np.array_equal(g0, g1)  # the walls too (and the robot's geoms)


def _unpaired_clearances(near: NearContacts, data: mujoco.MjData) -> np.ndarray:
    """Each geom's distance from its bounding sphere to the nearest contact piece (of all of
    them) it is not paired with, by brute force, m."""
    m = near.model
    paired = {(int(a), int(b)) for a, b in zip(m.pair_geom1, m.pair_geom2)}
    xp = data.geom_xpos[near.geoms]
    local = np.einsum("gki,kij->gkj", xp[:, None, :] - near._centre[None, :, :], near._rot)
    out = np.maximum(np.abs(local) - near._half[None, :, :], 0.0)
    dist = np.sqrt(np.einsum("gki,gki->gk", out, out)) - near._radius[:, None]
    for gi, g in enumerate(near.geoms):
        for k, w in enumerate(near.walls):
            if (int(g), int(w)) in paired:
                dist[gi, k] = np.inf
    return dist.min(axis=1)


def test_pairs_are_selected_again_only_when_a_geom_can_reach_an_unpaired_piece() -> None:
    """The clearances (how far each geom may move before it can touch a piece it is not paired
    with) never exceed the true distances to every unpaired piece, whether from a selection
    (then they exceed the reach) or measured again with the pairs kept; through a straight
    drive and a mitre turn the pairs are selected again on a small fraction of the ticks (the
    fixed-reach rule: about a third), with no overrun, and the robot drives exactly as with
    the pairs selected on every tick."""
    net = layouts.mitre_bend(0.06, math.pi / 2, math.pi / 2)
    ex = Executor.for_network(net, lidar=None)
    near = ex.near
    assert near is not None
    select, remeasure = near._select, near._remeasure
    checked: list[bool] = []

    def check(selected: bool) -> None:
        true = _unpaired_clearances(near, ex.data)
        checked.append(bool(np.all(near._clearance <= true + 1e-12)))
        if selected:
            checked.append(bool(np.all(near._clearance > near.reach - near._margin)))

    def checking_select(xp: np.ndarray) -> None:
        select(xp)
        if near.n_pairs:
            check(True)

    def checking_remeasure(xp: np.ndarray) -> bool:
        kept = remeasure(xp)
        if kept:
            check(False)
        return kept

    near._select = checking_select  # type: ignore[method-assign]
    near._remeasure = checking_remeasure  # type: ignore[method-assign]
    ticks0 = ex.physics_ticks
    ex.run(go_straight(0.1))
    assert _turn(ex, net) == "done"
    ticks = ex.physics_ticks - ticks0
    assert len(checked) >= 20 and all(checked)
    assert near.remeasures >= 10
    assert near.overruns == 0 and near.fallbacks == 0
    assert near.selections < 0.15 * ticks, (near.selections, ticks)
    # the same drive selecting on every tick (the contacts of automatic collisions, see above)
    ref = Executor.for_network(net, lidar=None)
    assert ref.near is not None
    ref.near.slack = 1.0  # every update selects
    ref.run(go_straight(0.1))
    assert _turn(ref, net) == "done"
    assert ref.near.selections >= ticks
    assert np.array_equal(ref.data.qpos, ex.data.qpos)


def test_an_approach_within_the_clearance_measures_again() -> None:
    """Moving one geom (by hand) until it can reach an unpaired piece makes the next update
    measure (or select) again; a geom moved beyond its clearance in one interval is counted an
    overrun."""
    net = layouts.mitre_bend(0.06, math.pi / 2, math.pi / 2)
    ex = Executor.for_network(net, lidar=None)
    near = ex.near
    assert near is not None
    d = ex.data
    near.update(d, force=True)
    before = near.selections

    def measured() -> int:
        return near.selections + near.remeasures

    near.update(d)  # nothing moved: no selection
    assert near.selections == before and measured() == before + near.remeasures
    g = int(np.argmin(near._clearance))
    gid = int(near.geoms[g])
    saved = d.geom_xpos[gid].copy()
    try:
        # moved m, with the guard's 2 m + slack ahead still short of the clearance: nothing
        count = measured()
        step = (near._clearance[g] - near.slack) / 3.0 - 1e-6
        d.geom_xpos[gid] = saved + [step, 0.0, 0.0]
        near.update(d)
        assert measured() == count
        # the last interval's motion makes the next one's reach: measured again
        d.geom_xpos[gid] = saved + [near._clearance[g] - 0.5 * near.slack, 0.0, 0.0]
        near.update(d)
        assert measured() == count + 1 and near.overruns == 0
        # beyond the clearance (of the new selection) within one interval: an overrun
        d.geom_xpos[gid] = saved + [3.0 * near._clearance[g] + 0.05, 0.0, 0.0]
        near.update(d)
        assert near.overruns == 1
    finally:
        d.geom_xpos[gid] = saved
        near.update(d, force=True)
