"""The exact answer of a step that overflows float64, in rational arithmetic.

From a finite ``x``, ``u``, ``w`` a step can overflow float64: its floating-point sums then give
``inf - inf = NaN``, or an infinity whose sign depends on the order of the sums (which differs
between the one-state and the batched path of :meth:`~sdjls_gym.dynamics.Dynamics.transition`).
Both environments answer such a step with :func:`exact_transition`: each value is the exact
value of its formula, rounded once to float64 (``+-inf`` beyond its range, never NaN). Slow,
and only called on such a step. :func:`row_sign` decides a row of the region test whose
floating-point value is within round-off of 0.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

__all__ = ["exact_transition", "row_sign", "rounded"]


def _times(a: float, b: Fraction) -> Fraction:
    return Fraction(a) * b


def rounded(q: Fraction) -> float:
    """``q`` rounded to the nearest float64 (Python's int division is correctly rounded), or
    +-inf beyond float64's range."""
    try:
        return float(q)
    except OverflowError:
        return math.inf if q > 0 else -math.inf


def row_sign(g: list[float], x: list[float], h: float) -> int:
    """The sign (-1, 0 or 1) of ``g x - h`` for finite floats, exactly."""
    value = sum(map(_times, g, map(Fraction, x)), Fraction(0)) - Fraction(h)
    return (value > 0) - (value < 0)


def exact_transition(
    ABE: np.ndarray,
    QR: np.ndarray,
    G: np.ndarray,
    H_next: np.ndarray,
    x: np.ndarray,
    u: np.ndarray,
    w: np.ndarray,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Next state, stage cost and constraint values of one step, exact then rounded to float64.

    Parameters
    ----------
    ABE : (n, n + m + p)
        ``[A B E]`` of the current mode.
    QR : (n + m, n + m)
        ``blkdiag(Q, R)`` of the current mode.
    G : (r, n)
    H_next : (r,)
        ``H_{k+1}``.
    x : (n,), u : (m,), w : (p,)
        Finite float64 state, input and noise.

    Returns
    -------
    x_next : (n,)
        ``ABE [x; u; w]``.
    stage_cost : float
        ``[x; u]' QR [x; u]``.
    constraint_values : (r,)
        ``G x_next - H_{k+1}``, from the exact ``x_next``.
    """
    z = [Fraction(v) for v in np.concatenate((x, u, w)).tolist()]
    x_next = [sum(map(_times, row, z), Fraction(0)) for row in ABE.tolist()]
    zxu = z[: QR.shape[0]]
    cost = sum(
        (
            a * sum(map(_times, row, zxu), Fraction(0))
            for a, row in zip(zxu, QR.tolist(), strict=True)
        ),
        Fraction(0),
    )
    values = [
        sum(map(_times, row, x_next), Fraction(0)) - Fraction(h)
        for row, h in zip(G.tolist(), H_next.tolist(), strict=True)
    ]
    return (
        np.array(list(map(rounded, x_next))),
        rounded(cost),
        np.array(list(map(rounded, values))),
    )
