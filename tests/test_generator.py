"""The procedural generator: every seed validates and compiles; same seed, same network."""

from __future__ import annotations

import hashlib
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
#: the networks of seeds 0-19, recorded before NetworkConfig moved to radians.
GOLDEN_DIGESTS: dict[str, list[str]] = {
    "default": [
        "f7494eb7f480683d",
        "32a577b664331257",
        "05f995b427ee38b5",
        "c6b46618690fb5a9",
        "b415a719f2b4c677",
        "cbfd958efce1312c",
        "addd13b3b13e118a",
        "af5f172f13a3c376",
        "755aff0503e37842",
        "906237f3d8a47a3f",
        "e4db58d66046c1ef",
        "4a93784564781a82",
        "312e2ae5ef4dcfe5",
        "42d42d5b6a998454",
        "dfcd357706c08598",
        "ee23f564693874d0",
        "4e8bafe44cc46ccc",
        "567ce32b3c6a938e",
        "ec190a891b1b9251",
        "2eef6b0df2846664",
    ],
    "3d_loops": [
        "c24b3c30033a5025",
        "5f01a4a5aa038ed6",
        "9d56caadf2b96465",
        "ded6be7cf9ecb118",
        "1cac33b66b37608c",
        "3412da7df077ec47",
        "303dab30185628a9",
        "4f04c7b625781348",
        "972eb27f7690e3b9",
        "454e0a77d3c91a98",
        "9b9f44c905bc2be7",
        "b00ff0fbcf77ae4d",
        "94be9a36e18a7936",
        "ffd2bdbd97122a75",
        "00fec241a332c2f9",
        "04b40ab62f4ab07b",
        "c042046d475bd786",
        "46941845896b3e66",
        "de3fca36abb2004e",
        "dfc5c26004617c65",
    ],
    "continuous": [
        "7fdb7fc271600710",
        "193aeb9627e82fe9",
        "8231ea3f09ffb66a",
        "e3b19ba984edbfe0",
        "eb91e761f69a1786",
        "5269b323937e04cf",
        "bd5b5fe37744649d",
        "c95a9451d7315280",
        "e4032b7db300287d",
        "c37d46deb32fc3f0",
        "11b1dba9facac996",
        "9dc60929b4147cf2",
        "2b1d194939e2b032",
        "a23cca78c95318ff",
        "88888d10c34dbb13",
        "d6247323514e0a3a",
        "f42505c6138d548b",
        "ab07f735535f5599",
        "bbc8cb4fb04b24ac",
        "914179c072742203",
    ],
    "custom": [
        "23a6d8128e152ea3",
        "4fe01942f381c98f",
        "c593374a8a101245",
        "88d9009fcf539ad6",
        "f69b9317216ce3f8",
        "69605a45d2c5689d",
        "d5449ff0b2a6b759",
        "7372b8e7b1b99f23",
        "79a96c2e9aeb4675",
        "c3fd5d0f61b48309",
        "1e1f047873b6a2d3",
        "7a3bf1928e36e0cf",
        "9ab3929384e536ca",
        "a723864764e2ac1a",
        "a9ec415bac534cc7",
        "fda2987b2a8b1314",
        "f694445260935536",
        "3e74ac85128f9879",
        "a7b8df424de69d77",
        "bc3c5b86fb77da10",
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
    return hashlib.sha256(net.derived(metadata={}).to_json().encode()).hexdigest()[:16]


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
