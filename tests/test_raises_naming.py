"""``conftest.raises_naming`` can fail: a message without the argument's name or its value, a
value that is only part of another number, or a value far from the name, is not accepted."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import UNSHOWN, raises_naming


def _raise(message, error=ValueError):
    raise error(message)


@pytest.mark.parametrize(
    ("message", "name", "value"),
    [
        ("xi = 1.5 is out of range; expected a number in (0, 1)", "xi", 1.5),
        ("K has shape (3, 2); expected (3, 1, 2)", "K", (3, 2)),
        ("options['mode0'] = np.uint64(18446744073709551615) is out of range", "options['mode0']",
         np.uint64(2**64 - 1)),
        ("x = [1.e+101, 0.e+000] has an entry of magnitude above 1e+100", "x",
         np.array([1e101, 0.0])),
        ("model = 'macr0' is not known", "model", "macr0"),
        ("beta = 10000000000000000000000000000000... is not finite", "beta", 10**400),
        ("options['x0'] has an entry 2e+06 at index (0,)", "options['x0']", 2e6),
        ("the bound overflows with delta = 1e+308", ("bound", "delta"), 1e308),
        ("actions contain NaN or inf", "actions", UNSHOWN),
    ],
)  # fmt: skip
def test_a_message_naming_the_argument_and_the_value_passes(message, name, value):
    with raises_naming(ValueError, name, value):
        _raise(message)


@pytest.mark.parametrize(
    ("message", "name", "value"),
    [
        pytest.param("xi is out of range; expected a number in (0, 1)", "xi", 1.5, id="no-value"),
        pytest.param("1.5 is out of range", "xi", 1.5, id="no-name"),
        pytest.param("xi = 10 is out of range", "xi", 1, id="value-inside-a-number"),
        pytest.param("xi = -1 is out of range", "xi", 1, id="value-is-the-negative"),
        pytest.param("xi = 1.5 is out of range", "x", 1.5, id="name-inside-a-name"),
        pytest.param("the value 1.5 is out of range for xi", "xi", 1.5, id="value-before-name"),
        pytest.param(
            "xi is out of range; expected a number in (0, 1): " + "." * 200 + " xi = 1.5 ...",
            ("xi", "alpha"),
            1.5,
            id="a-second-name-missing",
        ),
        pytest.param(
            "K is out of range; " + "." * 200 + " 3.5", "K", 3.5, id="value-far-from-the-name"
        ),
    ],
)
def test_a_message_missing_the_name_or_the_value_fails(message, name, value):
    with pytest.raises(AssertionError, match="does not (name|show)"):
        with raises_naming(ValueError, name, value):
            _raise(message)


def test_the_wrong_type_or_no_error_fails():
    with pytest.raises(TypeError):  # not a ValueError: passes through
        with raises_naming(ValueError, "xi", 1.5):
            _raise("xi = 1.5 is a float", TypeError)
    with pytest.raises(pytest.fail.Exception):
        with raises_naming(ValueError, "xi", 1.5):
            pass
