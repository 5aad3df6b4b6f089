"""The macroeconomic example of section 6 of the paper (Samuelson multiplier-accelerator model).

``x_k = [x_k(1), x_k(2)]``: ``x_k(2)`` is the national income, ``x_k(1)`` its value one quarter
earlier; ``u_k`` is government expenditure; modes 0, 1, 2 are the paper's 1 (normal), 2 (boom)
and 3 (slump). One time unit is a quarter; the planning horizon is 20 quarters (5 years).
The target band for the income is ``2 + 0.5 k <= x_k(2) <= 5 + 0.5 k``, written as
``G x <= H_k`` with ``G = [[0, -1], [0, 1]]`` and ``H_k = [-2 - 0.5 k, 5 + 0.5 k]``.
"""

from __future__ import annotations

from typing import TypedDict

import numpy as np
from numpy.typing import NDArray

from sdjls_gym.model import SDJLSModel

__all__ = ["macro", "HORIZON", "ACTION_BOUND", "PAPER_X", "PAPER_Y", "PAPER_K", "PAPER_RHC"]

#: Planning horizon of the example: 20 quarters.
HORIZON = 20

#: Bound on |u_k| of ``SDJLS-Macro-v0``. The paper's controller stays far inside it: the
#: largest |u_k| it uses is in ``results/paper/REPORT.md`` (``python -m benchmarks.paper.reproduce``)
#: and in the action row of the manual's table (docs/environment.md, "Dynamics and time indexing").
ACTION_BOUND = 200.0

#: The paper's solution of Proposition 2 (section 6), printed there to 4 decimals.
PAPER_X = np.array(
    [[[1.3146, 0.0], [0.0, 0.7534]], [[1.9255, 0.0], [0.0, 0.7628]], [[1.1393, 0.0], [0.0, 0.1044]]]
)
PAPER_Y = np.array([[[3.2866, -2.4108]], [[8.2797, -3.4325]], [[-6.0384, 0.5429]]])
#: The paper's gains ``K_i = Y_i X_i^{-1}`` as printed (section 6).
PAPER_K = np.array([[[2.5, -3.2]], [[4.3, -4.5]], [[-5.3, 5.2]]])


class PaperRHC(TypedDict):
    """The types of :data:`PAPER_RHC`'s entries (a plain dict at run time)."""

    xi: float
    alpha: float
    Psi: NDArray[np.float64]
    nu_bound: float


#: The paper's receding-horizon parameters (section 6): chance level, slack penalty, terminal
#: weights Psi_i, and the bound on the offset |nu_k| <= 100.
PAPER_RHC: PaperRHC = {
    "xi": 0.85,
    "alpha": 1000.0,
    "Psi": np.array([np.eye(2), 2.0 * np.eye(2), 3.0 * np.eye(2)]),
    "nu_bound": 100.0,
}


def macro() -> SDJLSModel:
    """The model of section 6, exactly as printed in the paper.

    Returns
    -------
    SDJLSModel
        N = 3 modes (normal, boom, slump), n = 2, m = 1, p = 2 (E = I, W = I), r = 2; the
        states are named ``"income (k-1)"`` (x(1), last quarter's national income) and
        ``"income"`` (x(2)).
    """
    return SDJLSModel(
        A=[
            [[0.0, 1.0], [-2.5, 3.2]],
            [[0.0, 1.0], [-4.3, 4.5]],
            [[0.0, 1.0], [5.3, -5.2]],
        ],
        B=[[0.0], [1.0]],
        P_in=[[0.6, 0.3, 0.1], [0.25, 0.55, 0.2], [0.35, 0.15, 0.5]],
        P_out=[[0.67, 0.17, 0.16], [0.30, 0.47, 0.23], [0.26, 0.10, 0.64]],
        G=[[0.0, -1.0], [0.0, 1.0]],
        H0=[-2.0, 5.0],
        H_rate=[-0.5, 0.5],
        Q=[np.eye(2), 1.1 * np.eye(2), 1.2 * np.eye(2)],
        R=[[[1.0]], [[1.2]], [[1.3]]],
        x0=[2.0, 2.0],
        mode0=0,
        mode_names=("normal", "boom", "slump"),
        state_names=("income (k-1)", "income"),
    )
