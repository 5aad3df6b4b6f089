"""The second computation of a multiplier the KKT test of :mod:`controllers.kkt` found below
zero: from the dense KKT system of the active set, against the gradient's scale.

An ill-conditioned reduced Hessian can make the magnitudes of the first computation so large
(1e10 for a multiplier of -3.8, on a scenario tree of path probabilities over three decades)
that a point above the optimum passes within round-off of them; the dense system's multiplier
must be nonnegative to :data:`CONFIRM_TOL` of the gradient's scale, per unit of its row.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CONFIRM_TOL", "confirm_multipliers"]

#: Relative tolerance of :func:`confirm_multipliers`, of the gradient's scale per unit of row.
CONFIRM_TOL = 1e-9


def confirm_multipliers(
    P: np.ndarray,
    C: np.ndarray,
    rows: tuple[int, ...],
    w: np.ndarray,
    which: np.ndarray,
    z: np.ndarray,
) -> bool:
    """Whether the multipliers ``which`` (a mask over the sorted ``rows``), computed again from
    the dense KKT system of the active set (``P z + C_S' lam = -q``, ``C_S z = h_S``), have each
    ``-lam_i max_j |C_ij| <= CONFIRM_TOL max(|P| |z| + |q|)`` at the returned ``z`` (False when
    the system is singular or a number not finite). Called only for multipliers found below 0."""
    d, idx = P.shape[0], np.asarray(rows, dtype=np.int64)
    CS = C[idx]
    K = np.zeros((d + idx.size, d + idx.size))
    K[:d, :d], K[:d, d:], K[d:, :d] = P, CS.T, CS
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            lam = np.linalg.solve(K, np.concatenate([-w[:d], w[d + idx]]))[d:][which]
    except np.linalg.LinAlgError:
        return False
    scale = float(np.max(np.abs(P) @ np.abs(z) + np.abs(w[:d]), initial=0.0))
    size = np.abs(CS[which]).max(axis=1, initial=0.0)
    if not (np.all(np.isfinite(lam)) and math.isfinite(scale)):
        return False
    return bool(np.all(-lam * size <= CONFIRM_TOL * scale))
