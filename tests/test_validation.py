"""The project's one argument-check module: message format, conversions and refusals."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from detector.validation import (
    ArgumentError,
    check_bool,
    check_choice,
    check_int,
    check_number,
    check_vector,
    fail,
)


def test_message_names_place_field_value_problem_and_allowed() -> None:
    err = fail("fittings[3].position", [0, "x"], "three finite numbers (m)", "not finite", "a.json")
    assert str(err) == (
        "a.json: fittings[3].position = [0, 'x']: not finite; allowed: three finite numbers (m)"
    )
    assert isinstance(err, ValueError)
    assert err.within("run.yaml").where == "run.yaml: a.json"
    copy = pickle.loads(pickle.dumps(err))
    assert str(copy) == str(err) and copy.field == "fittings[3].position"


@pytest.mark.parametrize("bad", [True, "1", None, [1.0], math.nan, math.inf, 10**400])
def test_check_number_refuses_what_is_not_a_finite_number(bad: object) -> None:
    with pytest.raises(ArgumentError, match=r"^length = .*allowed: at least 0 \(m\)$"):
        check_number("length", bad, low=0.0, unit="m")


def test_check_number_range_and_conversion() -> None:
    assert check_number("x", np.float32(0.5), 0.0, 1.0) == 0.5
    assert isinstance(check_number("x", 1, 0.0, 1.0), float)
    with pytest.raises(ArgumentError, match="out of range; allowed: above 0 to 1"):
        check_number("x", 0.0, 0.0, 1.0, open_low=True)
    with pytest.raises(ArgumentError, match="allowed: at most 2"):
        check_number("x", 3, high=2)


@given(st.integers(min_value=-(10**30), max_value=10**30))
def test_check_int_accepts_exactly_the_integers_in_range(value: int) -> None:
    if 0 <= value <= 100:
        assert check_int("n", value, 0, 100) == value
    else:
        with pytest.raises(ArgumentError, match="^n = "):
            check_int("n", value, 0, 100)


@pytest.mark.parametrize("bad", [0.5, 1.0, True, "3", b"3", None])
def test_check_int_refuses_non_integers(bad: object) -> None:
    with pytest.raises(ArgumentError, match="not an integer"):
        check_int("n", bad)


def test_check_bool_and_choice() -> None:
    assert check_bool("flag", np.True_) is True
    with pytest.raises(ArgumentError, match="allowed: true or false"):
        check_bool("flag", 1)
    assert check_choice("kind", "tee", ["bend", "tee"]) == "tee"
    with pytest.raises(ArgumentError, match="kind = 'x': unknown; allowed: bend, tee"):
        check_choice("kind", "x", ["bend", "tee"])
    with pytest.raises(ArgumentError, match="unknown"):
        check_choice("kind", [1], ["bend"])


def test_check_vector() -> None:
    v = check_vector("start.forward", [0, 0, 2], 3, unit_length=True)
    assert np.allclose(v, [0, 0, 1])
    for bad, problem in [
        ([0, 0, 0], "zero length"),
        ([1, 2], "shape"),
        ("abc", "not a list"),
        ([1, math.nan, 0], "not finite"),
        ([1, 10**400, 0], "not a list"),
    ]:
        with pytest.raises(ArgumentError, match=f"^start.forward = .*{problem}"):
            check_vector("start.forward", bad, 3, unit_length=True)
    with pytest.raises(ArgumentError, match="out of range"):
        check_vector("p", [0, 0, 2000.0], 3, bound=1000.0)
