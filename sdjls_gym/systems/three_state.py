"""SDJLS-ThreeState-v0: the 3-state, 2-mode system of the MJLS policy-gradient literature.

## Description

The small example of Jansch-Porto, Hu and Dullerud, *Convergence guarantees of policy
optimization methods for Markovian jump linear systems* (ACC 2020) and *Policy learning of
MDPs with mixed continuous/discrete variables: a case study on model-free control of
Markovian jump systems* (L4DC 2020): a numerical example without physical units, chosen there
to test learning. Each mode has a marginally stable direction its input cannot move (``x(3)``
in mode 0, ``x(2)`` in mode 1), so neither mode is stabilizable alone by a constant input
direction and the switching matters. Mode 1 is the expensive one (``Q_1 = 2 I``, ``R_1 = 2``).

## Source, and what is taken from it

``A_0 = [[.4, .6, -.1], [-.4, -.6, .3], [0, 0, 1]]``, ``A_1 = [[.9, .5, -.1], [0, 1, 0],
[-.1, .5, -.4]]``, ``B_0 = [1, 1, 0]'``, ``B_1 = [1, 0, 1]'``, ``P_in = [[.7, .3], [.4, .6]]``,
``Q_0 = I``, ``Q_1 = 2 I``, ``R_0 = 1``, ``R_1 = 2``, and the uniform initial mode.
**Verified** against ``main_small.cpp`` of the authors' public repository
``jpjporto/MJLS_Learning`` (commit 2a8e963), whose README names both papers: every number
agrees (Eigen's comma initializer fills row by row; the code uses ``u = -K x``, with the same
system matrices). The source system has no noise and draws ``x0`` uniformly from
``[-0.5, 0.5]^3``.

Added by this project: the noise, the region, ``P_out``, the fixed ``x0``, horizon, action
bound and the controller's data below.

## Region ``G x <= H_k``

``0.5 <= x(1) <= 1.5`` (``G = [[1, 0, 0], [-1, 0, 0]]``, ``H = [1.5, -0.5]``, constant): a set
point band for the first state, which both modes actuate directly (``B_i(1) = 1``). The origin,
where the LQ regulator drives the state, is outside the band.

## Transition matrices

``P_in`` is the published chain. ``P_out = [[0.4, 0.6], [0.1, 0.9]]`` (project's choice):
outside the band the expensive mode 1 becomes likelier and stickier.

## Noise, cost, start

``E = I``, ``W = 0.1^2 I``; the published weights; ``x0 = 0`` (the centre of the source's
initial distribution, outside the band); ``mode0 = [0.5, 0.5]`` (as the source).

## Episode

Horizon 50 steps; action bound ``|u| <= 10``.

## Receding-horizon controller (``RHC``)

The suite's recipe (:mod:`sdjls_gym.systems`), with ``|nu| <= 10``.

## Version History

* v0: Initial version.
"""

from __future__ import annotations

import numpy as np

from sdjls_gym.model import SDJLSModel

__all__ = ["three_state", "ENV_ID", "HORIZON", "ACTION_BOUND", "K", "RHC", "SOURCE"]

ENV_ID = "SDJLS-ThreeState-v0"
HORIZON = 50
ACTION_BOUND = 10.0
SOURCE = (
    "Jansch-Porto, Hu and Dullerud, ACC 2020 and L4DC 2020; verified against "
    "github.com/jpjporto/MJLS_Learning main_small.cpp"
)

#: Pre-stabilizing gains from Proposition 2 (``synthesize_gains(three_state())``), (N, m, n).
K = np.array([[[0.0233, 0.0332, -0.117]], [[-0.4174, -0.6542, 0.2418]]])

#: Keyword arguments of the receding-horizon controllers.
RHC = {
    "xi": 0.9,
    "constraint": "individual",
    "alpha": 1000.0,
    "nu_bound": 10.0,
    "Psi": np.array(
        [
            [[1.68, 1.02, -0.2967], [1.02, 2.531, -0.4451], [-0.2967, -0.4451, 5.946]],
            [[3.785, 0.9729, 0.3394], [0.9729, 8.767, -0.05957], [0.3394, -0.05957, 2.255]],
        ]
    ),
}


def three_state() -> SDJLSModel:
    """The 3-state, 2-mode example: N = 2, n = 3, m = 1, p = 3, r = 2.

    Returns
    -------
    SDJLSModel
    """
    return SDJLSModel(
        A=[
            [[0.4, 0.6, -0.1], [-0.4, -0.6, 0.3], [0.0, 0.0, 1.0]],
            [[0.9, 0.5, -0.1], [0.0, 1.0, 0.0], [-0.1, 0.5, -0.4]],
        ],
        B=[[[1.0], [1.0], [0.0]], [[1.0], [0.0], [1.0]]],
        P_in=[[0.7, 0.3], [0.4, 0.6]],
        P_out=[[0.4, 0.6], [0.1, 0.9]],
        G=[[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]],
        H0=[1.5, -0.5],
        Q=[np.eye(3), 2.0 * np.eye(3)],
        R=[[[1.0]], [[2.0]]],
        x0=[0.0, 0.0, 0.0],
        E=np.eye(3),
        W=0.01 * np.eye(3),
        mode0=[0.5, 0.5],
    )
