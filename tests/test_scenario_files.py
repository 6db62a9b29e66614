"""Scenario files: validation errors name the file and the key; mangled YAML never escapes as
an exception from inside the library."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.scenarios import (
    ScenarioError,
    build_network,
    load_scenario,
    packaged_scenario_dir,
    parse_scenario,
)

GOOD = (packaged_scenario_dir() / "tee_run_90mm.yaml").read_text()


@pytest.mark.parametrize(
    ("mutation", "message"),
    [
        ({"fidelity": "medium"}, r"key 'fidelity': got 'medium'; allowed: \('full', 'fast'\)"),
        (
            {"seeds": [-1]},
            r"key 'seeds': got \[-1\]; allowed: a non-empty list of ints in \[0, 2\*\*63\)",
        ),
        ({"criteria": {"max_jamz": 0}}, r"key 'criteria.max_jamz': unknown criterion"),
        ({"criteria": {"max_jams": -1}}, r"key 'criteria.max_jams': got -1; allowed: int >= 0"),
        ({"sensor": {"preset": "velodyne"}}, r"key 'sensor.preset': got 'velodyne'; allowed:"),
        ({"sensor": {"overrides": {"range": 3}}}, r"key 'sensor.overrides.range': unknown field"),
        ({"network": {"layout": "spiral"}}, r"key 'network.layout': got 'spiral'"),
        ({"network": {}}, r"key 'network': give exactly one of"),
        ({"goal": [1, 2]}, r"key 'goal': got \[1, 2\]; allowed: three finite numbers"),
        ({"agent": "genius"}, r"key 'agent': got 'genius'; allowed:"),
        ({"extra": 1}, r"key 'extra': unknown key; allowed:"),
    ],
)
def test_errors_name_file_key_and_allowed(mutation: dict, message: str) -> None:
    data = yaml.safe_load(GOOD)
    data.update(mutation)
    with pytest.raises(ScenarioError, match=r"^my_file.yaml: " + message):
        parse_scenario(data, "my_file.yaml")


def test_yaml_syntax_error_names_line(tmp_path: Path) -> None:
    f = tmp_path / "bad.yaml"
    f.write_text("network: {layout: tee\nagent: [")
    with pytest.raises(ScenarioError, match=r"bad.yaml: not valid YAML at line"):
        load_scenario(f)


@settings(max_examples=300)
@given(st.data())
def test_mangled_yaml_never_raises_anything_but_scenario_errors(data: st.DataObject) -> None:
    text = GOOD
    ops = data.draw(
        st.lists(
            st.tuples(
                st.sampled_from(["delete", "insert", "replace"]),
                st.integers(0, len(GOOD) - 1),
                st.text(min_size=0, max_size=6),
            ),
            min_size=1,
            max_size=4,
        )
    )
    for op, pos, s in ops:
        pos = min(pos, len(text))
        if op == "delete":
            text = text[:pos] + text[pos + len(s) + 1 :]
        elif op == "insert":
            text = text[:pos] + s + text[pos:]
        else:
            text = text[:pos] + s + text[pos + len(s) :]
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError:
        return  # load_scenario reports these as ScenarioError, tested above
    try:
        sc = parse_scenario(raw, "fuzz.yaml")
        build_network(sc)  # what loading a scenario also does: layouts, goals, generators
    except ScenarioError as exc:
        assert str(exc).startswith("fuzz.yaml")
        return
    assert sc.name


@settings(max_examples=200)
@given(
    st.dictionaries(
        st.sampled_from(
            sorted(
                {
                    "network",
                    "mode",
                    "env",
                    "seeds",
                    "criteria",
                    "sensor",
                    "goal",
                    "detect",
                    "agent",
                    "max_decisions",
                    "repetitions",
                    "start",
                }
            )
        ),
        st.recursive(
            st.none()
            | st.booleans()
            | st.integers(-5, 5)
            | st.floats(allow_nan=True)
            | st.text(max_size=5),
            lambda inner: (
                st.lists(inner, max_size=3)
                | st.dictionaries(st.text(max_size=5), inner, max_size=3)
            ),
            max_leaves=8,
        ),
    )
)
def test_random_structures_raise_only_scenario_errors(raw: dict) -> None:
    try:
        parse_scenario(raw, "random.yaml")
    except ScenarioError as exc:
        assert str(exc).startswith("random.yaml")


def test_auto_single_is_a_checked_scenario_key(tmp_path: Path) -> None:
    """A single-way layout sets ``auto_single: false`` so its episode starts at the decision;
    anything but a boolean is an error naming the key."""
    packaged = packaged_scenario_dir() / "reducer_to_60mm.yaml"
    assert load_scenario(packaged).auto_single is False
    text = packaged.read_text().replace("auto_single: false", "auto_single: 'no'")
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    with pytest.raises(ScenarioError, match="auto_single"):
        load_scenario(bad)
