"""Validation of the fields of :class:`~sdjls_gym.model.SDJLSModel`.

Every check names the field, shows the bad value and says what is expected. Type mistakes
(a string, a bool or ``None`` where numbers belong, a generator of names) raise
:class:`InvalidModelTypeError`, bad values :class:`InvalidModelError`; the first is a subclass
of the second, so ``except InvalidModelError`` catches every model error. The argument rules
are those of :mod:`sdjls_gym.validation`; the exceptions live in :mod:`sdjls_gym.errors`.

Thresholds on matrices are relative to each matrix's scale (its largest entry): a matrix
multiplied by ``1e-12`` or ``1e12`` gets the same verdict as the original.
"""

from __future__ import annotations

import contextlib
import unicodedata
from collections.abc import Iterator
from typing import Any

import numpy as np

from sdjls_gym.errors import InvalidModelError, InvalidModelTypeError
from sdjls_gym.validation import check_array, check_int, check_str_sequence

__all__ = ["PD_RTOL", "ROW_SUM_TOL", "SYM_RTOL", "validate_fields"]

#: Tolerance on the sum of a row of a transition matrix (and of a mode0 vector).
ROW_SUM_TOL = 1e-9
#: A symmetric matrix M is positive definite when its smallest eigenvalue exceeds this times
#: max |M_ij| (smaller eigenvalues are round-off of a singular matrix).
PD_RTOL = 1e-12
#: Asymmetry |M - M'| and negative eigenvalues of a PSD matrix tolerated, relative to max |M_ij|.
SYM_RTOL = 1e-9


@contextlib.contextmanager
def model_errors(field: str) -> Iterator[None]:
    """Turn the TypeError / ValueError of a :mod:`~sdjls_gym.validation` check of ``field`` into
    model errors (and a RecursionError on a deeply nested value into one naming the field)."""
    try:
        yield
    except InvalidModelError:
        raise
    except TypeError as exc:
        raise InvalidModelTypeError(str(exc)) from None
    except ValueError as exc:
        raise InvalidModelError(str(exc)) from None
    except RecursionError:
        raise InvalidModelError(
            f"{field} is nested too deeply to be read; model fields are arrays of at most 3 "
            "dimensions"
        ) from None


def _fmt(value: Any) -> str:
    """Short printable form of a (possibly large) value for error messages."""
    text = np.array2string(np.asarray(value), precision=4, threshold=12, separator=", ")
    text = " ".join(text.split())  # one line, so that messages stay greppable
    return text if len(text) < 160 else text[:157] + "..."


def _has_none(value: Any, depth: int = 0) -> tuple[int, ...] | None:
    """The index of the first ``None`` in nested lists/tuples (a null in a file), or None."""
    if depth > 3 or not isinstance(value, (list, tuple)):
        return None
    for i, item in enumerate(value):
        if item is None:
            return (i,)
        inner = _has_none(item, depth + 1)
        if inner is not None:
            return (i, *inner)
    return None


def as_float_array(name: str, value: Any) -> np.ndarray:
    """A float64 copy of ``value``; every entry a finite real number."""
    if value is None:
        raise InvalidModelTypeError(
            f"{name} is missing (None, or null in a file); expected numbers"
        )
    missing = _has_none(value)
    if missing is not None:
        raise InvalidModelTypeError(
            f"{name} has a missing entry (None, or null in a file) at index {missing}; every "
            "entry must be a finite number"
        )
    with model_errors(name):
        return check_array(name, value)


def per_mode(name: str, arr: np.ndarray, N: int, shape: tuple[int, ...], what: str) -> np.ndarray:
    """Accept ``shape`` (shared by all modes) or ``(N, *shape)``; return ``(N, *shape)``."""
    if arr.shape == shape:
        arr = np.broadcast_to(arr, (N, *shape)).copy()
    if arr.shape != (N, *shape):
        raise InvalidModelError(
            f"{name} has shape {arr.shape}; expected {(N, *shape)} ({what}) "
            f"or {shape} to use the same matrix in every mode"
        )
    return arr


def _scale(M: np.ndarray) -> float:
    return float(np.max(np.abs(M))) if M.size else 0.0


def _check_symmetric(name: str, arr: np.ndarray) -> None:
    for i, M in enumerate(arr):
        asym = float(np.max(np.abs(M - M.T))) if M.size else 0.0
        if asym > SYM_RTOL * _scale(M):
            raise InvalidModelError(
                f"{name}[{i}] is not symmetric (max |M - M'| = {asym:.3g}); it must be a "
                f"symmetric matrix, got {_fmt(M)}"
            )


def _check_psd(name: str, arr: np.ndarray, strict: bool) -> None:
    """arr: (N, d, d). Raise unless every slice is symmetric PSD (PD when ``strict``).

    The thresholds are relative to ``max |M_ij|``: PD means the smallest eigenvalue exceeds
    ``PD_RTOL`` times it, PSD that it is at least ``-SYM_RTOL`` times it.
    """
    _check_symmetric(name, arr)
    for i, M in enumerate(arr):
        scale = _scale(M)
        eig_min = float(np.linalg.eigvalsh(M)[0]) if M.size else 1.0
        if strict and eig_min <= PD_RTOL * scale:
            raise InvalidModelError(
                f"{name}[{i}] is not positive definite (smallest eigenvalue {eig_min:.3g}); "
                f"it must be symmetric positive definite, got {_fmt(M)}"
            )
        if not strict and eig_min < -SYM_RTOL * scale:
            raise InvalidModelError(
                f"{name}[{i}] is not positive semidefinite (smallest eigenvalue {eig_min:.3g}); "
                f"it must be symmetric positive semidefinite, got {_fmt(M)}"
            )


def _check_stochastic(name: str, P: np.ndarray, N: int) -> None:
    if P.shape != (N, N):
        raise InvalidModelError(f"{name} has shape {P.shape}; expected ({N}, {N}) for N={N} modes")
    neg = np.argwhere(P < 0)
    if neg.size:
        i, j = (int(v) for v in neg[0])
        raise InvalidModelError(
            f"{name}[{i}, {j}] = {P[i, j]:.6g} is negative; transition probabilities must be >= 0"
        )
    sums = P.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > ROW_SUM_TOL)
    if bad.size:
        i = int(bad[0])
        raise InvalidModelError(
            f"{name} row {i} sums to {sums[i]:.12g}; each row of a transition matrix must sum "
            f"to 1 (tolerance {ROW_SUM_TOL:g})"
        )


def _check_mode0(value: Any, N: int) -> int | np.ndarray:
    """An initial mode in ``[0, N)`` or a probability vector of length N."""
    if isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray) and value.ndim > 0):
        mode0 = as_float_array("mode0", value)
        if mode0.shape != (N,):
            raise InvalidModelError(
                f"mode0 has shape {mode0.shape}; expected an int in [0, {N - 1}] or a probability "
                f"vector of shape ({N},)"
            )
        if np.any(mode0 < 0) or abs(mode0.sum() - 1.0) > ROW_SUM_TOL:
            raise InvalidModelError(
                f"mode0 = {_fmt(mode0)} is not a probability vector; entries must be >= 0 and "
                f"sum to 1 (tolerance {ROW_SUM_TOL:g})"
            )
        return mode0
    with model_errors("mode0"):
        return check_int(
            "mode0",
            value,
            low=0,
            high=N - 1,
            what=f"modes are numbered from 0; or a probability vector of length {N}",
        )


def _check_names(name: str, value: Any, count: int) -> tuple[str, ...]:
    """The names as a tuple of ``count`` str. A name is a label (a legend, a table cell, a key
    of a TOML or JSON file): a control character (Unicode category Cc: U+0000-U+001F, DEL,
    U+0080-U+009F; tab and newline too) or a lone surrogate (which no UTF-8 file can hold) is
    refused, so that every accepted name round-trips through ``save_model`` / ``load_model``."""
    with model_errors(name):
        names = check_str_sequence(name, value, length=count)
    for i, item in enumerate(names):
        bad = next((c for c in item if unicodedata.category(c) in ("Cc", "Cs")), None)
        if bad is not None:
            kind = (
                "a lone surrogate" if unicodedata.category(bad) == "Cs" else "a control character"
            )
            raise InvalidModelError(
                f"{name}[{i}] = {item!r} holds {kind} (U+{ord(bad):04X}); a name is a label: "
                "expected printable text"
            )
    return names


def validate_fields(f: dict[str, Any]) -> dict[str, Any]:
    """The validated, canonical fields of a model (float64 arrays with the mode axis, ints,
    tuples of str) from the raw ones given to the constructor, checked in the order of the
    constructor's parameters (the first error is the one raised)."""
    A, B, P_in = _system_matrices(f)
    N, n, m = A.shape[0], A.shape[1], B.shape[-1]
    E, W = _noise(f, A.shape)
    P_out = as_float_array("P_out", f["P_out"])
    _check_stochastic("P_in", P_in, N)
    _check_stochastic("P_out", P_out, N)
    G, H0, H_rate = _region(f, n)
    Q = per_mode("Q", as_float_array("Q", f["Q"]), N, (n, n), "one n x n weight per mode")
    _check_psd("Q", Q, strict=False)
    R = per_mode("R", as_float_array("R", f["R"]), N, (m, m), "one m x m weight per mode")
    _check_psd("R", R, strict=True)
    x0 = as_float_array("x0", f["x0"])
    if x0.shape != (n,):
        raise InvalidModelError(f"x0 has shape {x0.shape}; expected ({n},)")
    mode0 = _check_mode0(f["mode0"], N)
    if f["mode_names"] is None:
        mode_names = tuple(f"mode {i}" for i in range(N))
    else:
        mode_names = _check_names("mode_names", f["mode_names"], N)
    state_names = None
    if f["state_names"] is not None:
        state_names = _check_names("state_names", f["state_names"], n)
    return {
        "A": A, "B": B, "E": E, "W": W, "P_in": P_in, "P_out": P_out, "G": G, "H0": H0,
        "H_rate": H_rate, "Q": Q, "R": R, "x0": x0, "mode0": mode0, "mode_names": mode_names,
        "state_names": state_names,
    }  # fmt: skip


def _system_matrices(f: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, P_in)``: ``A`` (N, n, n) and ``B`` (N, n, m) with their mode axis (N from
    ``P_in`` when one ``A`` is given for every mode), ``P_in`` as given."""
    A = as_float_array("A", f["A"])
    P_in = as_float_array("P_in", f["P_in"])
    if A.ndim == 2 and A.shape[0] == A.shape[1] and A.shape[0] >= 1:
        # one A for every mode: the number of modes comes from P_in
        if P_in.ndim != 2 or P_in.shape[0] != P_in.shape[1] or P_in.shape[0] < 1:
            raise InvalidModelError(
                f"P_in has shape {P_in.shape}; expected (N, N) for N >= 1 modes (A of shape "
                f"{A.shape} is shared by every mode, so N is read from P_in)"
            )
        A = np.broadcast_to(A, (P_in.shape[0], *A.shape)).copy()
    if A.ndim != 3 or A.shape[1] != A.shape[2] or A.shape[0] < 1 or A.shape[1] < 1:
        raise InvalidModelError(
            f"A has shape {A.shape}; expected (N, n, n): one square n x n matrix per mode, or "
            "(n, n) for the same matrix in every mode"
        )
    B = _per_mode_columns("B", f["B"], A.shape, "m", "one n x m input matrix per mode")
    return A, B, P_in


def _per_mode_columns(
    name: str, value: Any, A_shape: tuple[int, ...], k: str, what: str
) -> np.ndarray:
    """``B`` or ``E``: (N, n, k) with its mode axis, from (N, n, k) or (n, k), any ``k >= 1``."""
    N, n = A_shape[0], A_shape[1]
    M = as_float_array(name, value)
    if M.ndim not in (2, 3) or M.shape[-2] != n or M.shape[-1] < 1:
        raise InvalidModelError(
            f"{name} has shape {M.shape}; expected ({N}, {n}, {k}) or ({n}, {k}) to match A of "
            f"shape {A_shape}"
        )
    return per_mode(name, M, N, (n, M.shape[-1]), what)


def _noise(f: dict[str, Any], A_shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """``(E, W)``: ``E`` (N, n, p) with its mode axis (identities by default) and the
    covariance ``W`` (p, p) (the identity by default), positive semidefinite."""
    N, n = A_shape[0], A_shape[1]
    if f["E"] is None:
        E = np.broadcast_to(np.eye(n), (N, n, n)).copy()
    else:
        E = _per_mode_columns("E", f["E"], A_shape, "p", "one n x p noise matrix per mode")
    p = E.shape[-1]
    if f["W"] is None:
        W = np.eye(p)
    else:
        W = as_float_array("W", f["W"])
        if W.shape != (p, p):
            raise InvalidModelError(
                f"W has shape {W.shape}; expected ({p}, {p}), the covariance of the {p} noise "
                "inputs (columns of E)"
            )
    _check_psd("W", W[None], strict=False)
    return E, W


def _region(f: dict[str, Any], n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(G, H0, H_rate)`` of the region ``G x <= H0 + k H_rate`` (``H_rate`` 0 by default)."""
    G = as_float_array("G", f["G"])
    if G.ndim != 2 or G.shape[1] != n or G.shape[0] < 1:
        raise InvalidModelError(
            f"G has shape {G.shape}; expected (r, {n}) with r >= 1 rows of the region G x <= H"
        )
    r = G.shape[0]
    if np.any(np.all(G == 0.0, axis=1)):
        i = int(np.flatnonzero(np.all(G == 0.0, axis=1))[0])
        raise InvalidModelError(
            f"G row {i} is all zeros; every row of G must have a nonzero entry (a zero row "
            "is not a constraint on the state)"
        )
    H0 = as_float_array("H0", f["H0"])
    if H0.shape != (r,):
        raise InvalidModelError(f"H0 has shape {H0.shape}; expected ({r},), one entry per row of G")
    if f["H_rate"] is None:
        return G, H0, np.zeros(r)
    H_rate = as_float_array("H_rate", f["H_rate"])
    if H_rate.shape != (r,):
        raise InvalidModelError(
            f"H_rate has shape {H_rate.shape}; expected ({r},), one entry per row of G"
        )
    return G, H0, H_rate
