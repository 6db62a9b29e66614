"""The procedural generator: every seed validates and compiles; same seed, same network."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipe_env.generator import NetworkConfig, NetworkGenerationError, generate_network
from pipe_env.routing import route
from pipe_env.world import build_world

configs = st.builds(
    NetworkConfig,
    n_fittings=st.integers(1, 14),
    planar=st.booleans(),
    allow_loops=st.booleans(),
    branch_same_diameter=st.floats(0.0, 1.0),
)


@settings(max_examples=300)
@given(seed=st.integers(0, 2**32 - 1), config=configs)
def test_generated_networks_validate_and_reach_their_goal(seed: int, config: NetworkConfig) -> None:
    net = generate_network(config, np.random.default_rng(seed))
    net.validate()
    kinds = [f.kind for f in net.fittings]
    assert sum(k != "closure" for k in kinds) >= 1
    assert len(net.goals) == config.n_goals
    assert net.start_pose is not None
    for goal in net.goals:
        assert route(net, net.start_pose, goal) is not None
    d = net.to_dict()
    assert type(net).from_dict(d).to_dict() == d


@settings(max_examples=25)
@given(seed=st.integers(0, 2**32 - 1), config=configs)
def test_generated_networks_compile(seed: int, config: NetworkConfig) -> None:
    net = generate_network(config, np.random.default_rng(seed))
    world = build_world(net)
    assert world.model.ngeom > len(net.fittings)
    assert world.triangle_count > 0


@pytest.mark.slow
@settings(max_examples=300)
@given(seed=st.integers(0, 2**32 - 1), config=configs)
def test_hundreds_of_generated_networks_compile(seed: int, config: NetworkConfig) -> None:
    build_world(generate_network(config, np.random.default_rng(seed)))


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=20)
def test_same_seed_same_network(seed: int) -> None:
    cfg = NetworkConfig(n_fittings=10, planar=False, allow_loops=True)
    a = generate_network(cfg, np.random.default_rng(seed)).to_dict()
    b = generate_network(cfg, np.random.default_rng(seed)).to_dict()
    assert a == b


def test_different_seeds_differ() -> None:
    cfg = NetworkConfig()
    nets = {str(generate_network(cfg, np.random.default_rng(s)).to_dict()) for s in range(5)}
    assert len(nets) == 5


def test_loops_are_generated_when_allowed() -> None:
    cfg = NetworkConfig(
        n_fittings=12, allow_loops=True, loop_probability=1.0, kind_weights={"tee": 1.0}
    )
    net = generate_network(cfg, np.random.default_rng(3))
    # a tree has runs = fittings - 1; every loop adds one run
    assert len(net.runs) > len(net.fittings) - 1


def test_max_extent_bounds_the_network() -> None:
    net = generate_network(NetworkConfig(n_fittings=6, max_extent=2.5), np.random.default_rng(2))
    pts = np.array([f.position for f in net.fittings])
    assert np.all(np.ptp(pts, axis=0) <= 2.5 + 1e-9)


def test_planar_networks_stay_horizontal() -> None:
    net = generate_network(NetworkConfig(n_fittings=12, planar=True), np.random.default_rng(4))
    assert np.allclose([f.position[2] for f in net.fittings], 0.0, atol=1e-9)


def test_three_d_networks_leave_the_plane() -> None:
    zs = []
    for seed in range(5):
        net = generate_network(
            NetworkConfig(n_fittings=10, planar=False), np.random.default_rng(seed)
        )
        zs.append(np.ptp([f.position[2] for f in net.fittings]))
    assert max(zs) > 0.2


def test_mix_and_diameters_follow_the_config() -> None:
    cfg = NetworkConfig(
        n_fittings=10, kind_weights={"mitre_bend": 1.0}, diameter_range=(0.06, 0.07), n_goals=0
    )  # (bends only: the start drives to the one closure without a decision, so no goal)
    net = generate_network(cfg, np.random.default_rng(0))
    assert {f.kind for f in net.fittings} == {"bend", "closure"}
    assert all(f.style == "mitre" for f in net.fittings if f.kind == "bend")
    assert all(0.06 <= r.diameter <= 0.07 for r in net.runs)


def test_bounded_retries_then_clear_error() -> None:
    cfg = NetworkConfig(n_fittings=40, max_extent=2.0, max_retries=3)
    with pytest.raises(NetworkGenerationError, match=r"n_fittings=40 in 3 attempts"):
        generate_network(cfg, np.random.default_rng(0))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"n_fittings": 0},
            r"^NetworkConfig.n_fittings = 0: out of range; allowed: an integer 1 to 200$",
        ),
        (
            {"kind_weights": {"spiral": 1.0}},
            r"^NetworkConfig.kind_weights key = 'spiral': unknown; allowed: mitre_bend",
        ),
        (
            {"diameter_range": (0.1, 0.05)},
            r"^NetworkConfig.diameter_range = \(0.1, 0.05\): lo above hi; allowed: two numbers",
        ),
        (
            {"bend_deflection_range": (0.1, 1.5)},
            r"^NetworkConfig.bend_deflection_range\[0\] = 0.1: out of range; allowed: 0.523599 "
            r"to 1.5708 \(rad\)",
        ),
        (
            {"bend_deflection_step": 15.0},
            r"^NetworkConfig.bend_deflection_step = 15.0: out of range; allowed: 0 to 1.0472",
        ),
        ({"run_length_range": (0.01, 1.0)}, r"^NetworkConfig.run_length_range\[0\] = 0.01"),
        ({"planar": 1}, r"^NetworkConfig.planar = 1: not a boolean"),
        ({"start_offset": 1.5}, r"^NetworkConfig.start_offset = 1.5: the start would lie"),
        ({"max_extent": 1.0}, r"^NetworkConfig.max_extent = 1.0: out of range; allowed: above 1.2"),
    ],
)
def test_config_errors_name_the_field(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        NetworkConfig(**kwargs)


def test_config_round_trip() -> None:
    cfg = NetworkConfig(n_fittings=5, planar=False)
    assert NetworkConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match=r"^NetworkConfig.size = 3: no key; allowed: n_fittings"):
        NetworkConfig.from_dict({"size": 3})


def test_rng_must_be_a_generator() -> None:
    with pytest.raises(ValueError, match=r"^rng = 42: a int; allowed: a numpy.random.Generator"):
        generate_network(NetworkConfig(), 42)  # type: ignore[arg-type]


#: sha256[:16] of ``to_json()`` (metadata dropped: it records the config's field names) of
#: the networks of seeds 0-19, recorded before NetworkConfig moved to radians; again with the
#: floats rounded to 1e-6 when another machine's arithmetic (other SIMD extensions) gave the
#: same networks with coordinates a few ulps apart (a fast episode's clock on a recorded
#: network agreed to 1e-16).
GOLDEN_DIGESTS: dict[str, list[str]] = {
    "default": [
        "deb1a824c9b9ca09",
        "9133d59cdf100a91",
        "f0933a8355c95ab2",
        "1926d4d6afd0410d",
        "044eeff24071ce79",
        "773aa169eb545c63",
        "a826e2b3933809fb",
        "1f24555cc6d0d0dc",
        "2aaac4474a1ba52c",
        "f6ab9661d4799007",
        "1d90f14670f21aff",
        "43f5e9b6e8816d2a",
        "cacaeabdc059f075",
        "dd75089ca4ec85e9",
        "2c0c492916f97a5e",
        "bda66c07a524c50e",
        "7097b9f5b947e64a",
        "667f783bd1e4ab12",
        "96e42a336922a7f7",
        "1603086d61cbe3a0",
    ],
    "3d_loops": [
        "5c53ae0039cde498",
        "f1067386323c0015",
        "b84da08af56a3352",
        "d21cbc1573f87163",
        "951873931ac6025a",
        "161b3de108a174d3",
        "d16a1bb7b8052e4b",
        "8b851e6f13f94db8",
        "6d81ee35e259621b",
        "5a594d1a0fd9ebef",
        "0c615a7c89da5f59",
        "b77a213f54089142",
        "517458e463630c44",
        "b2d291825cb9e10d",
        "a81b32902e9972e2",
        "0186c598286d31b1",
        "3cc98c46bd35b625",
        "c75d5ffd4ea4385c",
        "0fe8ebdb2d92cc5b",
        "327fcf802083b108",
    ],
    "continuous": [
        "b49e276b3561e149",
        "e942f5e4e35b2ac7",
        "082dfdb66a41ec32",
        "7f6a9eede3602a87",
        "f4505811615e8502",
        "6464516026a3897f",
        "5126ad22e48bd712",
        "46bdf850a541f2eb",
        "14588c0323241f05",
        "92a1b7813ec60abc",
        "bf4bbcc6bf50efe6",
        "d4a2de9905a5c75d",
        "6c429700bf8a91a3",
        "a17e8e59c21fb349",
        "39aa09b2d5d8a66c",
        "e3ab3cd203822296",
        "583a9df59a0a003c",
        "8f519a31a866a473",
        "cffe7b257fe690fb",
        "eec2bc20081b793f",
    ],
    "custom": [
        "52fbef7504832574",
        "f50631d3d8ed8351",
        "79b92009a5b1713b",
        "cac9caec80d48735",
        "e5ca8a416c87b0d3",
        "647f02322fa6ca1a",
        "0e48e6671bcd08ae",
        "6d13af9e02da8ee6",
        "ebcee53efa4580f9",
        "209a2a9fe12af32d",
        "fbe5622c41e4f51d",
        "982c4d9edb82fc17",
        "94dbc12392cf2255",
        "d987ceca40578395",
        "b1707ac8015d8b7e",
        "222603ea0e41ab29",
        "d24de191af535815",
        "0e1aab416cda2d17",
        "512dd4220280d10a",
        "6bfbae4bc2c11049",
    ],
}
GOLDEN_CONFIGS: dict[str, dict] = {
    "default": {},
    "3d_loops": {"n_fittings": 10, "planar": False, "allow_loops": True},
    "continuous": {
        "n_fittings": 7,
        "planar": False,
        "bend_deflection_step": 0.0,
        "roll_angle_step": 0.0,
    },
    "custom": {
        "n_fittings": 6,
        "planar": False,
        "bend_deflection_range": (math.radians(40.0), math.radians(80.0)),
        "bend_deflection_step": math.radians(10.0),
        "roll_angle_step": math.pi / 6,
    },
}
#: The same configs as they were written when NetworkConfig took degrees.
GOLDEN_DEGREE_CONFIGS: dict[str, dict] = {
    "default": {},
    "continuous": {"n_fittings": 7, "planar": False, "bend_angle_step": 0.0, "roll_step": 0.0},
    "custom": {
        "n_fittings": 6,
        "planar": False,
        "bend_angle_range": (40.0, 80.0),
        "bend_angle_step": 10.0,
        "roll_step": 30.0,
    },
}


def _digest(net) -> str:
    text = json.dumps(_rounded(json.loads(net.derived(metadata={}).to_json())), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _rounded(value: object) -> object:
    """``value`` with every float rounded to a micrometre (a microradian)."""
    if isinstance(value, float):
        return round(value, 6) + 0.0  # (no -0.0)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


@pytest.mark.parametrize("name", sorted(GOLDEN_CONFIGS))
def test_same_config_and_seed_give_the_recorded_network(name: str) -> None:
    cfg = NetworkConfig(**GOLDEN_CONFIGS[name])
    got = [_digest(generate_network(cfg, np.random.default_rng(seed))) for seed in range(20)]
    assert got == GOLDEN_DIGESTS[name]


@pytest.mark.parametrize("name", sorted(GOLDEN_DEGREE_CONFIGS))
def test_deprecated_degree_fields_give_the_recorded_network(name: str) -> None:
    kwargs = GOLDEN_DEGREE_CONFIGS[name]
    if kwargs:
        with pytest.warns(FutureWarning, match=r"\(degrees\) is deprecated"):
            cfg = NetworkConfig(**kwargs)
    else:
        cfg = NetworkConfig(**kwargs)
    assert cfg == NetworkConfig(**GOLDEN_CONFIGS[name])
    got = [_digest(generate_network(cfg, np.random.default_rng(seed))) for seed in range(20)]
    assert got == GOLDEN_DIGESTS[name]


def test_deprecated_degree_fields_warn_naming_the_new_field() -> None:
    with pytest.warns(
        FutureWarning,
        match=r"NetworkConfig.roll_step \(degrees\) is "
        r"deprecated .* use roll_angle_step \(radians\)",
    ):
        cfg = NetworkConfig.from_dict({"roll_step": 90.0})
    assert cfg.roll_angle_step == math.pi / 2
    assert "roll_step" not in cfg.to_dict() and cfg.to_dict()["roll_angle_step"] == math.pi / 2
    with pytest.warns(FutureWarning, match="use bend_deflection_step"):
        assert NetworkConfig(bend_angle_step=30.0).bend_deflection_step == math.radians(30.0)
    with pytest.raises(ValueError, match=r"^NetworkConfig.bend_angle_range\[0\] = 10.0: out of"):
        with pytest.warns(FutureWarning):
            NetworkConfig(bend_angle_range=(10.0, 90.0))
    with pytest.raises(ValueError, match=r"NetworkConfig.roll_step = 30.0: given with roll_angle"):
        NetworkConfig(roll_step=30.0, roll_angle_step=0.5)


def test_config_angles_are_radians_and_round_trip() -> None:
    cfg = NetworkConfig(bend_deflection_range=(math.pi / 6, math.pi / 3), roll_angle_step=0.0)
    assert cfg.bend_deflection_range == (math.pi / 6, math.pi / 3)
    assert NetworkConfig.from_dict(cfg.to_dict()) == cfg
    net = generate_network(cfg, np.random.default_rng(1))
    assert NetworkConfig.from_dict(net.metadata["generator"]) == cfg
    for f in net.fittings:
        if f.kind == "bend":
            assert math.pi / 6 - 1e-6 <= net.geometry[f.id].deflection <= math.pi / 3 + 1e-6
