"""The risk allocation of problem P3 on a belief: which modes keep chance rows, at what level.

The chance constraints under the belief ``pi`` hold when each mode ``i`` has its rows tightened
at its own risk ``eps_i`` with ``sum_i pi_i eps_i <= 1 - xi`` (the law of total probability over
the mixture; :mod:`controllers.belief` states the guarantee). :class:`RiskAllocation` chooses:
the modes of smallest belief are *given up* (``eps_i = 1``: no rows) while their total belief
``m_D`` is at most ``give_up (1 - xi)``, the modes of zero belief always; the others are *kept*
at the same risk ``eps = (1 - xi - m_D) / (1 - m_D)``. It gives the kept modes' tightening of
:func:`controllers.chance.tightening` at level ``1 - eps``: the table at level ``xi`` itself when
``m_D = 0`` (so a certain belief is P3), else that kind's quantile at ``1 - eps`` times its row
scales (:func:`tightening_factor`).
"""

from __future__ import annotations

import numpy as np
from scipy import special

from sdjls_gym.model import SDJLSModel

from .chance import tightening

__all__ = ["RiskAllocation", "tightening_factor"]

#: The level at which the row scales of a kind are read (any level with a positive factor).
_REFERENCE_LEVEL = 0.9


def tightening_factor(kind: str, eps: float, r: int, p: int) -> float:
    """The tightening of ``kind`` at level ``1 - eps`` per unit of its row scale: the
    ``(1 - eps)``-quantile of a standard normal (``"individual"``, eq.
    constraint:det_univariate), the same at ``1 - eps / r`` (``"bonferroni"``), or the square root
    of the chi-square quantile with ``p`` degrees of freedom (``"joint"``, eq.
    constraint:chi_square); computed from ``eps``, accurate for a small risk."""
    if kind == "individual":
        return float(-special.ndtri(eps))
    if kind == "bonferroni":
        return float(-special.ndtri(eps / r))
    return float(np.sqrt(special.chdtri(p, eps)))


class RiskAllocation:
    """The risk allocation of a model's modes for a level ``xi`` and a constraint kind.

    Parameters
    ----------
    model : SDJLSModel
    xi : float
        The chance-constraint level (checked by the caller).
    constraint : str
        The kind of :func:`controllers.chance.tightening`.
    give_up : float
        In ``(0, 1)``: the share of ``1 - xi`` the modes given up may take (checked by the
        caller).

    Attributes
    ----------
    table : (N, r) ndarray
        ``tightening(model, xi, constraint)``, read-only: P3's.
    """

    def __init__(self, model: SDJLSModel, xi: float, constraint: str, give_up: float) -> None:
        self.model, self.xi, self.constraint, self.give_up = model, xi, constraint, give_up
        self.table = tightening(model, xi, constraint)
        self.table.setflags(write=False)
        reference = tightening(model, _REFERENCE_LEVEL, constraint)
        factor = tightening_factor(constraint, 1.0 - _REFERENCE_LEVEL, model.r, model.p)
        self._unit = reference / factor  # the row scales of the kind
        self._all = tuple(range(model.N))
        self._risk_xi = np.full(model.N, 1.0 - xi)
        self._kept: dict[tuple[int, ...], tuple[list[int], np.ndarray, np.ndarray]] = {}

    def allocate(self, belief: np.ndarray) -> tuple[tuple[int, ...], float]:
        """``(kept, m_D)`` of a probability vector (N,): the kept modes (ascending) and the
        total belief of the modes given up (the smallest first, ties by index)."""
        values = belief.tolist()
        budget = self.give_up * (1.0 - self.xi)
        if min(values) > budget:  # no mode given up: every mode at level xi
            return self._all, 0.0
        mass, dropped = 0.0, set()
        for i in sorted(range(len(values)), key=values.__getitem__):  # smallest first (stable)
            if mass + values[i] > budget:
                break
            mass += values[i]
            dropped.add(i)
        return tuple(i for i in range(len(values)) if i not in dropped), mass

    def risks(self, kept: tuple[int, ...], mass: float) -> tuple[np.ndarray, np.ndarray]:
        """``(risk, t)`` of an allocation: the risk ``eps_i`` of every mode (1 for a mode given
        up, ``(1 - xi - m_D) / (1 - m_D)`` for the kept ones) and the kept modes' tightening
        (len(kept), r) at level ``1 - eps`` (P3's own table when ``m_D = 0``)."""
        N = self.model.N
        if mass == 0.0 and len(kept) == N:
            return self._risk_xi.copy(), self.table
        held = self._kept.get(kept)
        if held is None:  # at most 2^N kept sets
            idx = list(kept)
            held = self._kept[kept] = (idx, self.table[idx], self._unit[idx])
        idx, table, unit = held
        risk = np.ones(N)
        if mass == 0.0:
            risk[idx] = 1.0 - self.xi
            return risk, table.copy()
        eps = (1.0 - self.xi - mass) / (1.0 - mass)
        risk[idx] = eps
        factor = tightening_factor(self.constraint, eps, self.model.r, self.model.p)
        return risk, factor * unit
