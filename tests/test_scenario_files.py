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
    ScenarioFieldError,
    build_network,
    load_scenario,
    packaged_scenario_dir,
    parse_scenario,
)
from detector.validation import ArgumentError

GOOD = (packaged_scenario_dir() / "tee_run_90mm.yaml").read_text()


@pytest.mark.parametrize(
    ("mutation", "message"),
    [
        ({"fidelity": "medium"}, r"fidelity = 'medium': unknown; allowed: full, fast$"),
        ({"seeds": [-1]}, r"seeds\[0\] = -1: out of range; allowed: an integer 0 to 2\*\*63 - 1$"),
        ({"criteria": {"max_jamz": 0}}, r"criteria.max_jamz = 0: unknown criterion; allowed: "),
        ({"criteria": {"max_jams": -1}}, r"criteria.max_jams = -1: out of range; allowed: an "),
        ({"criteria": {"max_jams": True}}, r"criteria.max_jams = True: not an integer; allowed"),
        ({"criteria": {"success": 1}}, r"criteria.success = 1: not a boolean; allowed: true"),
        (
            {"criteria": {"max_detection_error": {"angle": 5}}},
            r"criteria.max_detection_error.angle = 5: unknown field; allowed: angle_deg, ",
        ),
        ({"sensor": {"preset": "velodyne"}}, r"sensor.preset = 'velodyne': unknown; allowed:"),
        ({"sensor": {"overrides": {"range": 3}}}, r"sensor.overrides.range = 3: unknown key"),
        (
            {"sensor": {"misalignment": {"offset": [0, "a", 0]}}},
            r"sensor.misalignment.offset\[1\] = 'a': not a number; allowed: a finite number",
        ),
        ({"network": {"layout": "spiral"}}, r"network.layout = 'spiral': unknown; allowed: "),
        ({"network": {}}, r"network = \{\}: 0 given; allowed: exactly one of layout, "),
        (
            {"network": {"generator": {}, "seed": -2}},
            r"network.seed = -2: out of range; allowed: an integer 0 to",
        ),
        ({"goal": [1, 2]}, r"goal = \[1, 2\]: not such a list; allowed: a list of 3 numbers"),
        ({"goal": {"way": 1}}, r"goal.distance = None: missing; allowed:"),
        ({"agent": "genius"}, r"agent = 'genius': unknown; allowed: goal_greedy, "),
        ({"extra": 1}, r"extra = 1: unknown key; allowed: agent, auto_single, "),
        ({"timeout_s": 0}, r"timeout_s = 0: out of range; allowed: above 0 to 86400 \(s\)$"),
        ({"detect": {}}, r"detect = \{\}: not allowed here; allowed: only with mode: detect$"),
    ],
)
def test_errors_name_file_key_and_allowed(mutation: dict, message: str) -> None:
    data = yaml.safe_load(GOOD)
    data.update(mutation)
    with pytest.raises(ScenarioFieldError, match=r"^my_file.yaml: " + message) as info:
        parse_scenario(data, "my_file.yaml")
    # one error type and format for every checked field: the file, the field path, the value
    assert isinstance(info.value, ArgumentError) and isinstance(info.value, ScenarioError)
    assert info.value.where == "my_file.yaml"
    assert str(info.value).startswith(f"my_file.yaml: {info.value.field} = ")


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
