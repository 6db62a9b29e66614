"""Cheaper world building, the same worlds: ray meshes on demand and the batched contact pieces.

A world built with ``ray_meshes=False`` must hold, bit for bit, every other array of the world
built with them (geom ids shifted by the number of ray meshes), give the same physics, and hand
its consumers (renders, MJCF export, the MuJoCo ray caster) the world with them through
``PipeWorld.complete``. The contact pieces, now computed sector by sector in one pass of array
arithmetic, must be bit for bit those of the per-piece formulas they replaced (kept here as the
reference).
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from detector.geometry import frame_from_forward
from pipe_env import layouts
from pipe_env.contact_walls import (
    SEAM_OVERLAP,
    SECTORS,
    THICKNESS,
    _chord_radius,
    _have_volume,
    _torus_pieces,
    run_panels,
)
from pipe_env.export import mjcf_text
from pipe_env.generator import NetworkConfig, generate_network
from pipe_env.network import PipeNetwork
from pipe_env.raycast_mujoco import MujocoCaster
from pipe_env.robot import Robot
from pipe_env.world import PipeWorld, build_world
from primitives.executor import Executor
from primitives.sequences import go_straight


def _network() -> PipeNetwork:
    return generate_network(
        NetworkConfig(n_fittings=4, planar=False, allow_loops=False), np.random.default_rng(5)
    )


def _pair(net: PipeNetwork) -> tuple[PipeWorld, PipeWorld]:
    eager = build_world(net, customize=Robot().customize)
    lean = build_world(net, customize=Robot().customize, ray_meshes=False)
    return eager, lean


def _arrays(m: mujoco.MjModel, prefix: str) -> dict[str, np.ndarray]:
    out = {}
    for name in dir(m):
        if name.startswith(prefix) and isinstance(getattr(m, name), np.ndarray):
            out[name] = getattr(m, name)
    return out


@pytest.mark.parametrize("which", ["tee", "generated"])
def test_a_world_without_ray_meshes_holds_the_same_physics_arrays(which: str) -> None:
    net = layouts.t_junction(0.09, direction=0.0, distance=0.5) if which == "tee" else _network()
    eager, lean = _pair(net)
    e, m = eager.model, lean.model
    nw = len(eager.wall_geoms)
    assert not lean.has_ray_meshes and lean.wall_geoms == {} and lean.triangle_count == 0
    assert e.ngeom - m.ngeom == nw == e.nmesh - m.nmesh > 0
    assert sorted(eager.wall_geoms) == list(range(nw))  # the ray meshes come first
    assert lean.contact_geom_count == eager.contact_geom_count
    for name, a in _arrays(e, "geom_").items():
        a = a[nw:]
        if name == "geom_dataid":
            a = np.where(a >= 0, a - nw, a)
        assert a.tobytes() == getattr(m, name).tobytes(), name
    for prefix in ("body_", "jnt_", "dof_", "pair_", "eq_", "actuator_"):
        for name, a in _arrays(e, prefix).items():
            if name.startswith("body_bvh"):
                continue  # the world body's geom tree holds the ray meshes
            a = a.copy()
            if name in ("pair_geom1", "pair_geom2"):
                a -= nw
            elif name == "body_geomadr":
                a[a > 0] -= nw
            elif name == "body_geomnum":
                a[0] -= nw
            assert a.tobytes() == getattr(m, name).tobytes(), name
    # the contact pieces' meshes: every vertex, bit for bit
    for k in range(m.nmesh):
        j = k + nw
        ev = e.mesh_vert[e.mesh_vertadr[j] : e.mesh_vertadr[j] + e.mesh_vertnum[j]]
        lv = m.mesh_vert[m.mesh_vertadr[k] : m.mesh_vertadr[k] + m.mesh_vertnum[k]]
        assert ev.tobytes() == lv.tobytes()
    for a, b in ((e.opt, m.opt), (e.stat, m.stat)):
        for name in dir(a):
            x = getattr(a, name)
            if not name.startswith("_") and isinstance(x, (np.ndarray, float, int)):
                assert np.asarray(x).tobytes() == np.asarray(getattr(b, name)).tobytes(), name


def test_physics_without_ray_meshes_is_bit_identical() -> None:
    net = layouts.t_junction(0.09, direction=0.0, distance=0.5)
    runs = []
    for ray_meshes in (True, False):
        ex = Executor.for_network(net, lidar=None, physics="everywhere", ray_meshes=ray_meshes)
        assert ex.world.has_ray_meshes is ray_meshes
        out = ex.run(go_straight(0.15), rng=np.random.default_rng(0))
        states = [ex.data.qpos.tobytes(), ex.data.qvel.tobytes(), ex.data.ncon]
        # automatic collisions against every piece (no contact pairs): the same too
        assert ex.near is not None
        ex.near.disable()
        for _ in range(20):
            mujoco.mj_step(ex.model, ex.data)
        states += [ex.data.qpos.tobytes(), ex.data.ncon]
        runs.append((out.status, out.travelled, ex.physics_ticks, states))
    assert runs[0] == runs[1]


def test_a_world_without_ray_meshes_or_a_rebuild_fails_in_the_shared_format() -> None:
    net = layouts.t_junction(0.09, direction=0.0, distance=0.5)
    lean = dataclasses.replace(build_world(net, ray_meshes=False), _rebuild=None)
    with pytest.raises(ValueError, match=r"^PipeWorld.complete: ray_meshes = False: no ray meshes"):
        lean.complete()


@pytest.mark.parametrize("field", ["ray_meshes", "contact_walls"])
@pytest.mark.parametrize("value", [0, 1, "yes", None])
def test_build_world_flags_must_be_booleans(field: str, value: object) -> None:
    net = layouts.t_junction(0.09, direction=0.0, distance=0.5)
    with pytest.raises(ValueError, match=rf"^build_world: {field} = .*: not a boolean; allowed"):
        build_world(net, **{field: value})


def test_complete_gives_the_world_with_ray_meshes_in_the_same_state() -> None:
    net = layouts.t_junction(0.09, direction=0.0, distance=0.5)
    eager, lean = _pair(net)
    assert eager.complete() is eager
    lean.data.qpos[:3] += [0.01, 0.002, -0.001]
    lean.data.mocap_pos[:] += 0.003
    mujoco.mj_forward(lean.model, lean.data)
    full = lean.complete()
    assert full.has_ray_meshes and lean.complete() is full  # built once
    assert full.wall_geoms == eager.wall_geoms and full.triangle_count == eager.triangle_count
    for name in ("geom_size", "geom_pos", "geom_quat", "mesh_vert", "mesh_face", "body_pos"):
        assert getattr(full.model, name).tobytes() == getattr(eager.model, name).tobytes()
    assert full.data.qpos.tobytes() == lean.data.qpos.tobytes()
    assert full.data.mocap_pos.tobytes() == lean.data.mocap_pos.tobytes()
    # the MJCF export of the lean world is the eager world's
    assert mjcf_text(lean) == mjcf_text(eager)


def test_the_mujoco_caster_on_a_lean_world_casts_as_on_the_eager_one() -> None:
    net = layouts.t_junction(0.09, direction=0.0, distance=0.5)
    eager = build_world(net, contact_walls=False)
    lean = build_world(net, contact_walls=False, ray_meshes=False)
    rng = np.random.default_rng(1)
    origins = np.zeros((4, 3))
    dirs = rng.normal(size=(4, 16, 3))
    dirs /= np.linalg.norm(dirs, axis=2, keepdims=True)
    for kwargs in ({}, {"sensing_only": False, "inner_only": False}):
        a, _ = MujocoCaster(eager, **kwargs).cast(origins, dirs, 5.0)
        b, _ = MujocoCaster(lean, **kwargs).cast(origins, dirs, 5.0)
        assert np.isfinite(a).all() and a.tobytes() == b.tobytes()


def test_a_render_of_a_lean_world_is_the_eager_worlds() -> None:
    from pipe_env.rendering import RenderingUnavailable, WorldRenderer

    net = layouts.mitre_bend(0.1)
    eager = build_world(net)
    lean = build_world(net, ray_meshes=False)
    try:
        a = WorldRenderer(eager, 64, 48).render("iso")
        b = WorldRenderer(lean, 64, 48).render("iso")
    except RenderingUnavailable:
        pytest.skip("no OpenGL backend")
    assert a.std() > 0 and np.array_equal(a, b)


# ---------------------------------------------------------------- contact pieces, batched


def _run_panels_one_by_one(p0: np.ndarray, p1: np.ndarray, diameter: float) -> list:
    """The per-panel formulas ``run_panels`` replaced."""
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    axis = axis / length
    frame = frame_from_forward(axis)
    u, v = frame[:, 1], frame[:, 2]
    r = 0.5 * diameter
    delta = 2 * math.pi / SECTORS
    face = r * (1.0 + math.cos(0.5 * delta)) / 2.0
    half_width = face * math.tan(0.5 * delta) * 1.15 + 0.0005
    half_len = 0.5 * length + SEAM_OVERLAP
    mid = 0.5 * (p0 + p1)
    panels = []
    for j in range(SECTORS):
        phi = (j + 0.5) * delta
        normal = math.cos(phi) * u + math.sin(phi) * v
        tangent = np.cross(normal, axis)
        rot = np.column_stack([axis, tangent, normal])
        centre = mid + normal * (face + 0.5 * THICKNESS)
        panels.append((centre, rot, np.array([half_len, half_width, 0.5 * THICKNESS])))
    return panels


_coord = st.floats(-5.0, 5.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    st.tuples(_coord, _coord, _coord),
    st.tuples(_coord, _coord, _coord),
    st.floats(0.04, 0.4),
)
def test_run_panels_are_the_per_panel_formulas_bit_for_bit(
    a: tuple[float, float, float], b: tuple[float, float, float], diameter: float
) -> None:
    p0, p1 = np.array(a), np.array(b)
    if np.linalg.norm(p1 - p0) < 0.05:
        p1 = p0 + np.array([0.3, 0.0, 0.0])
    got = run_panels(p0, p1, diameter)
    want = _run_panels_one_by_one(p0, p1, diameter)
    assert len(got) == len(want) == SECTORS
    for panel, (centre, rot, half) in zip(got, want):
        assert panel.centre.tobytes() == centre.tobytes()
        assert panel.rotation.tobytes() == np.ascontiguousarray(rot).tobytes()
        assert panel.half_size.tobytes() == half.tobytes()


def _torus_one_by_one(g) -> list[np.ndarray]:
    """The per-slice, per-sector formulas ``_torus_pieces`` replaced."""
    from pipe_env.contact_walls import bend_slices

    sl = bend_slices(g)  # the slicing is shared; the pieces are built one by one
    centre, normal, bend_r, r, psis = sl.centre, sl.normal, sl.bend_r, sl.r, sl.psis
    u0, w0 = sl.u0, sl.w0
    delta = 2 * math.pi / SECTORS
    k_in = _chord_radius(1.0, delta)
    k_arc = _chord_radius(1.0, psis[1] - psis[0])
    pieces = []
    for lo, hi in zip(psis[:-1], psis[1:]):
        ps = np.array([lo, hi])
        radial = np.cos(ps)[:, None] * u0 + np.sin(ps)[:, None] * w0
        for j in range(SECTORS):
            phis = np.array([j * delta, (j + 1) * delta])
            dirs = (
                np.cos(phis)[None, :, None] * radial[:, None, :]
                + np.sin(phis)[None, :, None] * normal[None, None, :]
            )
            inner = bend_r * radial[:, None, :] + dirs * (r * k_in)
            outer = bend_r * radial[:, None, :] + dirs * (r + THICKNESS)
            pts = centre + k_arc * np.concatenate([inner.reshape(-1, 3), outer.reshape(-1, 3)])
            pieces.append(pts)
    return pieces


def test_long_bend_pieces_are_the_per_piece_formulas_bit_for_bit() -> None:
    seen = 0
    for seed in range(12):
        net = generate_network(
            NetworkConfig(n_fittings=6, planar=False, allow_loops=False),
            np.random.default_rng(seed),
        )
        for f in net.fittings:
            g = net.geometry[f.id]
            if g.kind != "bend" or g.style != "long":
                continue
            got = [p.points for p in _torus_pieces(g)]
            want = _torus_one_by_one(g)
            assert len(got) == len(want)
            assert all(x.tobytes() == y.tobytes() for x, y in zip(got, want))
            seen += 1
    assert seen >= 3


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 10), min_size=1, max_size=30), st.integers(0, 2**31))
def test_have_volume_is_the_one_at_a_time_test(sizes: list[int], seed: int) -> None:
    rng = np.random.default_rng(seed)
    sets = []
    for n in sizes:
        pts = rng.normal(size=(n, 3))
        if n and rng.random() < 0.4:
            pts[:, 2] = 0.25 * rng.random() * 1e-5  # (nearly) flat: no volume
        sets.append(pts)

    def one(points: np.ndarray) -> bool:
        if len(points) == 0:
            return False
        sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
        return bool(len(sv) == 3 and sv[2] > 1e-5)

    assert _have_volume(sets) == [one(p) for p in sets]


def test_the_full_fidelity_plant_builds_ray_meshes_only_for_the_mujoco_lidar() -> None:
    from pipe_env.envs.plant_full import PhysicalPlant

    net = layouts.t_junction(0.09, direction=0.0, distance=0.5)
    analytic = PhysicalPlant(net)  # the default backend: analytic ray casting
    assert analytic.world is not None and not analytic.world.has_ray_meshes
    meshes = PhysicalPlant(net, lidar_backend="mujoco")
    assert meshes.world is not None and meshes.world.has_ray_meshes
    # the same physics world but for the ray meshes
    a, m = analytic.world.model, meshes.world.model
    nw = len(meshes.world.wall_geoms)
    assert m.ngeom - a.ngeom == nw > 0
    assert m.geom_pos[nw:].tobytes() == a.geom_pos.tobytes()
    assert m.geom_size[nw:].tobytes() == a.geom_size.tobytes()
    # a render or an export of the analytic plant's world gets the ray meshes on demand
    assert analytic.world.complete().has_ray_meshes
    assert mjcf_text(analytic.world) == mjcf_text(meshes.world)
