"""Argument checks shared by the model, the environments, the wrappers, the controllers and the
benchmarks: the project's public rules for arguments.

One rule per kind of argument, so that the same mistake gets the same kind of error everywhere:

* a **number** is a real number: a Python ``int`` or ``float``, a numpy integer or floating
  scalar, or a 0-d real numpy array. ``bool`` (Python or numpy) is never a number, nor is a
  string (``"0.85"``), ``None`` or a complex number: those are :class:`TypeError`.
* an **int** is a Python ``int`` or a numpy integer (never a ``bool``: :class:`TypeError`).
  A float where an int is expected (``steps = 2.0`` or ``2.5``) raises
  :class:`~sdjls_gym.errors.NotAnIntError`,
  which is both a :class:`TypeError` (the rule above) and a :class:`ValueError` (a count that is
  not a whole number is also a bad value), so either ``except`` catches it. Its range is checked
  on the exact integer, before any conversion to a fixed-width type, so ``2**70`` or
  ``np.uint64(2**64 - 1)`` are rejected, not wrapped.
* a value of the right type outside its range (``xi = 1.5``, ``alpha = -1``, ``nan``) is a
  :class:`ValueError`.

Every message names the argument, shows the bad value and says what is expected::

    xi = 1.5 is out of range; expected a number in (0, 1)
    horizon = 2.0 is a float; expected an int >= 1

The functions return the value converted to the canonical Python type (``float``, ``int``,
``bool``, ``str``) or a new float64 / int64 array. Values are shown in messages by
:mod:`sdjls_gym.messages`.

Public names (``__all__``):

* scalars: :func:`check_number`, :func:`check_positive`, :func:`check_probability`,
  :func:`check_int`, :func:`check_optional_int`, :func:`check_bool`, :func:`check_choice`;
* containers: :func:`check_mapping`, :func:`check_str_sequence`;
* arrays: :func:`check_array`, :func:`check_numbers` (an action: no finiteness test,
  :class:`~sdjls_gym.errors.NotANumberError` for a non-number), :func:`check_int_array`,
  :func:`check_float32_bound`;
* limits: :data:`MAX_INDEX` (the largest count or time index), :data:`FLOAT32_TINY` and
  :data:`FLOAT32_MAX` (the normal float32 range of a ``Box`` bound).
"""

from __future__ import annotations

import math
import numbers
import sys
from collections.abc import Iterable, Mapping
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

from sdjls_gym.errors import NotAnIntError, NotANumberError
from sdjls_gym.messages import a_type, describe, type_name

__all__ = [
    "FLOAT32_MAX",
    "FLOAT32_TINY",
    "MAX_INDEX",
    "check_array",
    "check_bool",
    "check_choice",
    "check_float32_bound",
    "check_int",
    "check_int_array",
    "check_mapping",
    "check_number",
    "check_numbers",
    "check_optional_int",
    "check_positive",
    "check_probability",
    "check_str_sequence",
]

#: Largest time index ``k`` (and any other count) accepted: integers up to 2**53 are exact in
#: float64 (``H_k = H0 + k * H_rate``) and fit in int64 with room for ``k + 1``.
MAX_INDEX = 2**53

#: The range of positive float32 numbers that are normal (not subnormal, not zero, not inf).
FLOAT32_TINY = float(np.finfo(np.float32).tiny)
FLOAT32_MAX = float(np.finfo(np.float32).max)


#: dtype codes of the ints and floats that float64 holds without overflow (not longdouble 'g'):
#: the fast path of :func:`check_numbers`.
_EXACT_IN_FLOAT64 = frozenset("efdbhilqpnBHILQPN")


def check_numbers(name: str, value: Any, what: str = "") -> np.ndarray:
    """:func:`check_array` without the finiteness test, whose type errors are
    :class:`NotANumberError` (an action ``["1"]`` or ``[True]`` is not silently 1.0). A float or
    integer ndarray, the environments' common case, is only copied to float64."""
    if type(value) is np.ndarray and value.dtype.char in _EXACT_IN_FLOAT64:
        return value.astype(np.float64)
    try:
        return check_array(name, value, finite=False, what=what)
    except TypeError as exc:
        raise NotANumberError(str(exc)) from None


def _is_bool(value: Any) -> bool:
    return isinstance(value, (bool, np.bool_)) or (
        isinstance(value, np.ndarray) and value.dtype == np.bool_
    )


def _as_real(name: str, value: Any, expected: str) -> float:
    """The float value of a number (see the module docstring), or a TypeError naming ``name``."""
    if isinstance(value, np.ndarray) and value.ndim == 0 and not _is_bool(value):
        value = value[()]
    if _is_bool(value) or not isinstance(value, (numbers.Real, np.integer, np.floating)):
        kind = "a bool" if _is_bool(value) else a_type(value)
        raise TypeError(f"{name} = {describe(value)} is {kind}; expected {expected}")
    try:
        return float(value)
    except OverflowError:  # an int beyond float64
        return -math.inf if value < 0 else math.inf


def check_number(
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    what: str = "",
) -> float:
    """A finite real number in ``[low, high]`` (open ends with ``low_open`` / ``high_open``).

    Parameters
    ----------
    name : str
        The argument's name, as the user wrote it (``"alpha"``, ``"options['x0']"``).
    value : Any
    low, high : float, optional
        Range; None for no bound.
    low_open, high_open : bool
        Exclude the bound itself.
    what : str
        A few words on what the argument is (``"penalty on the slack rho"``), added to messages.

    Returns
    -------
    float

    Raises
    ------
    TypeError
        ``value`` is not a number (a bool, a string, None, ...).
    ValueError
        ``value`` is NaN, infinite or out of range.

    Examples
    --------
    >>> check_number("xi", 0.85, low=0, high=1, low_open=True, high_open=True)
    0.85
    >>> check_number("xi", "0.85")
    Traceback (most recent call last):
    ...
    TypeError: xi = '0.85' is a str; expected a finite number
    """
    lo_txt = "" if low is None else f"{'>' if low_open else '>='} {low:g}"
    hi_txt = "" if high is None else f"{'<' if high_open else '<='} {high:g}"
    if low is not None and high is not None:
        rng = f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    else:
        rng = lo_txt or hi_txt
    expected = "a finite number" + (f" {rng}" if rng else "")
    if what:
        expected += f" ({what})"
    out = _as_real(name, value, expected)
    if not math.isfinite(out):
        raise ValueError(f"{name} = {describe(value)} is not finite; expected {expected}")
    bad = (
        (low is not None and (out < low or (low_open and out == low)))
        or (high is not None and (out > high or (high_open and out == high)))
    )  # fmt: skip
    if bad:
        raise ValueError(f"{name} = {describe(value)} is out of range; expected {expected}")
    return out


def check_positive(name: str, value: Any, what: str = "") -> float:
    """A finite number ``> 0`` (see :func:`check_number`)."""
    return check_number(name, value, low=0.0, low_open=True, what=what)


def check_probability(name: str, value: Any, what: str = "") -> float:
    """A probability level strictly between 0 and 1 (see :func:`check_number`)."""
    return check_number(name, value, low=0.0, high=1.0, low_open=True, high_open=True, what=what)


def check_int(
    name: str, value: Any, *, low: int | None = None, high: int | None = MAX_INDEX, what: str = ""
) -> int:
    """An integer in ``[low, high]`` (``high`` defaults to :data:`MAX_INDEX`).

    Raises
    ------
    NotAnIntError
        ``value`` is a float or another real number that is not an int (both a TypeError and a
        ValueError).
    TypeError
        ``value`` is not a number (a bool, a string, None, ...).
    ValueError
        ``value`` is out of range.

    Examples
    --------
    >>> check_int("horizon", 20, low=1)
    20
    >>> check_int("horizon", 2.0, low=1)
    Traceback (most recent call last):
    ...
    sdjls_gym.errors.NotAnIntError: horizon = 2.0 is a float; expected an int >= 1
    """
    # the default upper bound is a technical limit, named only when it is exceeded
    shown_high = None if high == MAX_INDEX else high
    if low is not None and shown_high is not None:
        expected = f"an int in [{low}, {shown_high}]"
    elif low is not None:
        expected = f"an int >= {low}"
    elif shown_high is not None:
        expected = f"an int <= {shown_high}"
    else:
        expected = "an int"
    if what:
        expected += f" ({what})"
    if isinstance(value, np.ndarray) and value.ndim == 0 and not _is_bool(value):
        value = value[()]
    if _is_bool(value) or not isinstance(value, (numbers.Integral, np.integer)):
        kind = "a bool" if _is_bool(value) else a_type(value)
        error = (
            NotAnIntError
            if not _is_bool(value) and isinstance(value, (numbers.Real, np.floating))
            else TypeError
        )
        raise error(f"{name} = {describe(value)} is {kind}; expected {expected}")
    out = int(value)  # exact, for numpy's unsigned types too
    if low is not None and out < low:
        raise ValueError(f"{name} = {describe(value)} is out of range; expected {expected}")
    if high is not None and out > high:
        if high == MAX_INDEX:
            raise ValueError(
                f"{name} = {describe(value)} is too large; expected {expected}, at most 2**53, "
                "the largest index that float64 holds exactly"
            )
        raise ValueError(f"{name} = {describe(value)} is out of range; expected {expected}")
    return out


def check_optional_int(
    name: str, value: Any, *, low: int | None = None, what: str = ""
) -> int | None:
    """None, or an int as :func:`check_int`."""
    return None if value is None else check_int(name, value, low=low, what=what)


def check_bool(name: str, value: Any) -> bool:
    """``True`` or ``False`` (Python or numpy bool); anything else is a :class:`TypeError`."""
    if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype == np.bool_:
        value = value[()]
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} = {describe(value)} is {a_type(value)}; expected True or False")
    return bool(value)


def check_choice(name: str, value: Any, allowed: Iterable[str]) -> str:
    """One of the strings ``allowed``.

    Raises
    ------
    TypeError
        ``value`` is not a string.
    ValueError
        ``value`` is a string not among ``allowed``.
    """
    allowed = tuple(allowed)
    expected = "one of " + ", ".join(repr(a) for a in allowed)
    if not isinstance(value, str):
        raise TypeError(f"{name} = {describe(value)} is {a_type(value)}; expected {expected}")
    if value not in allowed:
        raise ValueError(f"{name} = {value!r} is not known; expected {expected}")
    return value


def check_mapping(name: str, value: Any, allowed: Iterable[str] | None = None) -> dict[str, Any]:
    """A mapping (``dict``-like) with string keys, all among ``allowed`` when given; a copy.

    ``None`` gives ``{}``.

    Raises
    ------
    TypeError
        ``value`` is not a mapping, or a key is not a string.
    ValueError
        A key is not among ``allowed``.
    """
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        expected = "a dict" + (f" with keys among {sorted(allowed)}" if allowed is not None else "")
        raise TypeError(f"{name} = {describe(value)} is {a_type(value)}; expected {expected}")
    out = dict(value)
    for key in out:
        if not isinstance(key, str):
            raise TypeError(
                f"{name} has a key {describe(key)} of type {type_name(key)}; keys are str"
            )
    if allowed is not None:
        allowed = sorted(allowed)
        unknown = sorted(set(out) - set(allowed))
        if unknown:
            raise ValueError(f"{name} has unknown keys {unknown}; expected keys among {allowed}")
    return out


def check_str_sequence(name: str, value: Any, length: int | None = None) -> tuple[str, ...]:
    """A list or tuple of strings (of ``length`` items when given), as a tuple.

    A generator, a set or a single string is a :class:`TypeError` (its order or its items would
    be guessed).
    """
    expected = f"a list or tuple of {length if length is not None else ''} str".replace("  ", " ")
    if not isinstance(value, (list, tuple)):
        raise TypeError(f"{name} = {describe(value)} is {a_type(value)}; expected {expected}")
    for i, item in enumerate(value):
        if not isinstance(item, str):
            raise TypeError(
                f"{name}[{i}] = {describe(item)} is {a_type(item)}; expected {expected}"
            )
    if length is not None and len(value) != length:
        raise ValueError(f"{name} = {describe(value)} has {len(value)} items; expected {length}")
    return tuple(value)


def check_array(
    name: str,
    value: Any,
    *,
    shape: tuple[int | None, ...] | None = None,
    finite: bool = True,
    max_abs: float | None = None,
    what: str = "",
) -> np.ndarray:
    """A real float64 array (a new copy), of ``shape`` when given (``None`` entries: any size).

    Raises
    ------
    TypeError
        ``value`` has entries that are not real numbers (bools, strings, None, complex).
    ValueError
        Ragged input, wrong shape, a non-finite entry (when ``finite``), or an entry above
        ``max_abs`` in magnitude.
    """
    suffix = f" ({what})" if what else ""
    value = _real_entries(name, value, suffix)
    try:
        with np.errstate(over="ignore"):  # a longdouble beyond float64: inf, reported below
            arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name} = {describe(value)} could not be read as an array of numbers ({exc}){suffix}"
        ) from None
    _check_values(name, arr, shape, finite, max_abs, suffix)
    return arr


def _real_entries(name: str, value: Any, suffix: str) -> Any:
    """``value`` if its entries may be real numbers (an object array of them: as float64),
    else :func:`check_array`'s error (ragged input is left to the conversion)."""
    if isinstance(value, (str, bytes)) or value is None:
        raise TypeError(
            f"{name} = {describe(value)} is {a_type(value)}; expected an array of numbers{suffix}"
        )
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError):
        raw = None  # ragged: reported below
    if raw is not None and raw.dtype.kind in "iuf" and raw.size and type(value) is not np.ndarray:
        entries = np.asarray(value, dtype=object)  # numpy reads a bool among numbers as 1 or 0
        if any(_is_bool(v) for v in entries.ravel()):
            raw = entries  # reported below
    if raw is not None and raw.dtype.kind in "mMV":  # not numbers, though numpy casts them
        kind = {"m": "timedelta64", "M": "datetime64"}.get(raw.dtype.kind, "structured")
        raise TypeError(
            f"{name} = {describe(value)} has {kind} entries; expected an array of real "
            f"numbers{suffix}"
        )
    if isinstance(value, np.ma.MaskedArray) and np.ma.is_masked(value):  # missing entries
        bad = tuple(int(i) for i in np.argwhere(np.ma.getmaskarray(value))[0])
        raise ValueError(
            f"{name} has a masked (missing) entry at index {bad}; every entry must be a "
            f"number{suffix}"
        )
    if raw is not None and (raw.dtype.kind in "bcSUO" or raw.dtype == np.bool_):
        if raw.dtype.kind == "O":
            bad_entries = [
                v
                for v in raw.ravel()
                if _is_bool(v) or not isinstance(v, (numbers.Real, np.integer, np.floating))
            ]  # a list, not next(..., None): a None entry is itself what must be reported
            if not bad_entries and raw.size:
                value = raw = _objects_as_float(name, raw, suffix)
            else:
                bad_entry = bad_entries[0] if bad_entries else None
                raise TypeError(
                    f"{name} has an entry {describe(bad_entry)} of type {type_name(bad_entry)}; "
                    f"expected an array of real numbers{suffix}"
                )
        else:
            entry_kind = {"b": "bool", "c": "complex", "S": "bytes", "U": "str"}[raw.dtype.kind]
            raise TypeError(
                f"{name} = {describe(value)} has {entry_kind} entries; expected an array of real "
                f"numbers{suffix}"
            )
    return value


def _check_values(
    name: str,
    arr: np.ndarray,
    shape: tuple[int | None, ...] | None,
    finite: bool,
    max_abs: float | None,
    suffix: str,
) -> None:
    """The shape, finiteness and size rules of :func:`check_array` on the float64 ``arr``."""
    if shape is not None and (
        arr.ndim != len(shape)
        or any(s is not None and a != s for a, s in zip(arr.shape, shape, strict=True))
    ):
        want = (
            "("
            + ", ".join("B" if s is None else str(s) for s in shape)
            + ("," if len(shape) == 1 else "")
            + ")"
        )
        raise ValueError(f"{name} has shape {arr.shape}; expected {want}{suffix}")
    if finite and not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(
            f"{name} has a non-finite entry {arr[bad]} at index {bad}; every entry must be "
            f"finite{suffix}"
        )
    if max_abs is not None and arr.size and float(np.max(np.abs(arr))) > max_abs:
        bad = tuple(int(i) for i in np.unravel_index(int(np.argmax(np.abs(arr))), arr.shape))
        raise ValueError(
            f"{name} has an entry {arr[bad]:.6g} at index {bad}; entries must be at most "
            f"{max_abs:g} in magnitude{suffix}"
        )


def _objects_as_float(name: str, raw: np.ndarray, suffix: str) -> np.ndarray:
    """The float64 values of an object array of real numbers; a Python int beyond float64
    (``10**400``) is a ValueError naming the entry, as ``1e400`` is, not numpy's OverflowError."""
    try:
        return raw.astype(np.float64)
    except OverflowError:
        for index, v in np.ndenumerate(raw):
            try:
                float(v)
            except OverflowError:
                size = (
                    f" (about 10**{int(abs(v).bit_length() * 0.30103)})" if type(v) is int else ""
                )
                raise ValueError(
                    f"{name} has an entry {describe(v, 40)}{size} at index {index} beyond the "
                    f"range of float64 (magnitude above {sys.float_info.max:.4g}); every entry "
                    f"must be a finite number{suffix}"
                ) from None
        raise


def check_int_array(
    name: str, value: Any, *, low: int | None = None, high: int = MAX_INDEX
) -> np.ndarray:
    """An int64 array of integers in ``[low, high]`` (an int gives a 0-d array).

    The rule of :func:`check_int` for every entry: a bool is never an int, not even one entry of
    a list (numpy would read ``[0, True]`` as ``[0, 1]``), nor is a float or a string. The range
    is checked on the exact values, before the conversion to int64, so ``2**70`` is refused, not
    wrapped. An int64 array, the common case, is returned as is.

    Raises
    ------
    TypeError
        A bool, float, string or other non-int entry, or an array of another dtype.
    ValueError
        Ragged input, or an entry out of range.
    """
    if not isinstance(value, (np.ndarray, list, tuple, range)):  # one int: check_int's rule
        return np.array(check_int(name, value, low=low, high=high), dtype=np.int64)
    expected = f"ints in [{low}, {high}]" if low is not None else f"ints <= {high}"
    if isinstance(value, np.ndarray) and value.dtype.kind != "O":
        if value.dtype.kind not in "iu":
            raise TypeError(
                f"{name} has dtype {value.dtype}; expected {expected.replace('ints', 'integers')}"
            )
        arr = value
    else:
        try:
            arr = np.asarray(value)
            entries = arr if arr.dtype.kind == "O" else np.asarray(value, dtype=object)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"{name} = {describe(value)} could not be read as an array of ints ({exc})"
            ) from None
        for index, v in np.ndenumerate(entries):  # numpy reads a bool among ints as 1 or 0
            if _is_bool(v) or not isinstance(v, (numbers.Integral, np.integer)):
                label = f"{name}[{', '.join(map(str, index))}]" if entries.ndim else name
                kind = "a bool" if _is_bool(v) else a_type(v)
                raise TypeError(f"{label} = {describe(v)} is {kind}; expected {expected}")
        if arr.dtype.kind not in "iu":  # Python ints beyond int64 (or an empty list)
            arr = entries if entries.size else np.zeros(entries.shape, dtype=np.int64)
    if arr.size:
        for bad in (arr.min(), arr.max()):  # exact, before any conversion that could wrap
            if (low is not None and bad < low) or bad > high:
                limit = (
                    ", at most 2**53, the largest index that float64 holds exactly"
                    if high == MAX_INDEX and bad > high
                    else ""
                )
                if not isinstance(value, np.ndarray):
                    bad = int(bad)  # shown as the user wrote it: 3, not np.int64(3)
                raise ValueError(
                    f"{name} = {describe(bad)} is out of range; expected {expected}{limit}"
                )
    return arr if arr.dtype == np.int64 else arr.astype(np.int64)


@overload
def check_float32_bound(name: str, value: Any, size: None = None, what: str = "") -> float: ...
@overload
def check_float32_bound(
    name: str, value: Any, size: int, what: str = ""
) -> NDArray[np.float64]: ...
def check_float32_bound(
    name: str, value: Any, size: int | None = None, what: str = ""
) -> float | NDArray[np.float64]:
    """A positive bound that a float32 ``Box`` holds exactly enough: a normal float32 number.

    Parameters
    ----------
    name : str
    value : number, or (size,) array when ``size`` is given
        One bound (used for every entry when ``size`` is given) or one per entry.
    size : int, optional
        Accept an array of this many bounds as well as a single number.
    what : str
        A few words on what is bounded, added to messages.

    Returns
    -------
    float, or (size,) float64 array when ``size`` is given

    Raises
    ------
    TypeError
        Not a number (or an array of numbers).
    ValueError
        Not finite, not positive, above the largest float32 (3.4e38, where the Box would become
        infinite), or below the smallest normal float32 (1.2e-38, where it would round to a
        subnormal number or to zero).

    Examples
    --------
    >>> check_float32_bound("action_bound", 200.0)
    200.0
    >>> check_float32_bound("action_bound", 1e300)
    Traceback (most recent call last):
    ...
    ValueError: action_bound = 1e+300 does not fit in float32; expected a number in [1.17549e-38, 3.40282e+38]
    """
    scalar = size is None or (
        not isinstance(value, (list, tuple)) and not (isinstance(value, np.ndarray) and value.ndim)
    )
    if scalar:
        bounds = np.array([check_positive(name, value, what=what)])
    else:
        bounds = check_array(name, value, shape=(size,), what=what)
        bad = np.flatnonzero(~(bounds > 0))
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"{name}[{i}] = {bounds[i]:g} is not positive; expected bounds > 0"
                + (f" ({what})" if what else "")
            )
    outside = np.flatnonzero((bounds > FLOAT32_MAX) | (bounds < FLOAT32_TINY))
    if outside.size:
        i = int(outside[0])
        label = name if scalar else f"{name}[{i}]"
        shown = describe(value) if scalar else f"{bounds[i]:g}"
        raise ValueError(
            f"{label} = {shown} does not fit in float32; expected a number in "
            f"[{FLOAT32_TINY:g}, {FLOAT32_MAX:g}]" + (f" ({what})" if what else "")
        )
    if size is None:
        return float(bounds[0])
    return np.broadcast_to(bounds, (size,)).copy()
