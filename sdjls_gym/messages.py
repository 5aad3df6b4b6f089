"""How values are shown in error messages: short, one line, with their type as a user reads it.

Every check of :mod:`sdjls_gym.validation` (and the model's, the environments' and the
controllers' own) names the argument, shows the bad value with :func:`describe` and its type
with :func:`a_type`::

    horizon = 2.0 is a float; expected an int >= 1
    model = {'A': ...} is a dict; expected an SDJLSModel
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["a_type", "describe", "type_name"]


def type_name(value: Any) -> str:
    """The type of ``value`` as a user reads it (``'numpy.float32'``, ``'str'``)."""
    t = type(value)
    module = t.__module__
    return t.__qualname__ if module == "builtins" else f"{module.split('.')[0]}.{t.__qualname__}"


def a_type(value: Any) -> str:
    """``'a str'``, ``'an int'``, ``'a numpy.float32'``: the type of ``value`` with its article."""
    name = type_name(value)
    return ("an " if name[0].lower() in "aeiou" else "a ") + name


def describe(value: Any, width: int = 80) -> str:
    """A short ``repr`` of ``value`` for an error message (one line, at most ``width`` chars)."""
    try:
        if isinstance(value, np.ndarray):
            text = np.array2string(value, precision=6, threshold=12, separator=", ")
        else:
            text = repr(value)
    except Exception:  # noqa: BLE001 - a broken __repr__ must not hide the real error
        text = f"<{type_name(value)} object>"
    text = " ".join(text.split())
    return text if len(text) <= width else text[: width - 3] + "..."
