"""SDJLS-Degradation-v0: a double integrator whose actuator degrades (Dolgov and Hanebeck 2015).

## Description

A mass on a line, position ``x(1)`` and velocity ``x(2)``, pushed by a force ``u`` (one
sampling period per step). In mode 0 (nominal) it is the double integrator; in mode 1
(degraded) the actuator has lost most of its effect and couples into the position, and the
position drifts away (``A_1(1, 1) = 1.2``). The example of Dolgov and Hanebeck, *Dynamic
compensation of Markov jump linear systems without mode observation* (2015); here the mode is
observed.

## Source, and what is taken from it

``A_0 = [[1, 1], [0, 1]]``, ``A_1 = [[1.2, 1.2], [0, 1]]``, ``B_0 = [0, 1]'``,
``B_1 = [0.01, 0.8]'``, ``P_in = [[0.7, 0.3], [0.2, 0.8]]``, ``E = I``, ``W = 0.1^2 I``,
``Q = I``, ``R = 1``, ``x0 = [2, 0]``. **Verified** against ``simmain.m`` of the public
repository ``Mxttak/MJLS`` (commit 6f5362a; M. Dolgov's reference implementation of that
paper): every number agrees (the script also has a measurement equation, not used here, and
draws ``x0`` around ``[2, 0]`` with covariance ``0.2^2 I`` and starts from the uniform mode
distribution; here ``x0 = [2, 0]`` and ``mode0 = 0``).

Added by this project: the region, ``P_out``, horizon, action bound and the controller's data.

## Region ``G x <= H_k``

``x(1) + 2 x(2) >= -0.1`` (``G = [[-1, -2]]``, ``H = [0.1]``, constant, ``r = 1``): the
position two sampling periods ahead at the current velocity must stay in front of a wall at
``-0.1``, just behind the target ``0``: the mass is to be parked at the origin without hitting
the wall. The row is actuated in one step in both modes (``G B_i != 0``), unlike the position
alone. The LQ regulator approaches the target symmetrically and crosses the line often.

## Transition matrices

``P_in`` is the published chain. ``P_out = [[0.4, 0.6], [0.1, 0.9]]`` (project's choice):
hitting the wall makes the degradation likelier and stickier.

## Noise, cost, start

As published: ``E = I``, ``W = 0.01 I``, ``Q = I``, ``R = 1``, ``x0 = [2, 0]``; ``mode0 = 0``.

## Episode

Horizon 30 steps; action bound ``|u| <= 5``.

## Receding-horizon controller (``RHC``)

The suite's recipe (:mod:`sdjls_gym.systems`), with ``|nu| <= 5``.

## Version History

* v0: Initial version.
"""

from __future__ import annotations

import numpy as np

from sdjls_gym.model import SDJLSModel

__all__ = ["degradation", "ENV_ID", "HORIZON", "ACTION_BOUND", "K", "RHC", "SOURCE"]

ENV_ID = "SDJLS-Degradation-v0"
HORIZON = 30
ACTION_BOUND = 5.0
SOURCE = (
    "Dolgov and Hanebeck, Dynamic compensation of Markov jump linear systems without mode "
    "observation, 2015; verified against github.com/Mxttak/MJLS simmain.m"
)

#: Pre-stabilizing gains from Proposition 2 (``synthesize_gains(degradation())``), (N, m, n).
K = np.array([[[-0.4772, -1.457]], [[-0.7534, -1.9587]]])

#: Keyword arguments of the receding-horizon controllers.
RHC = {
    "xi": 0.9,
    "constraint": "individual",
    "alpha": 1000.0,
    "nu_bound": 5.0,
    "Psi": np.array([[[3.051, 2.509], [2.509, 4.813]], [[4.275, 4.1], [4.1, 7.178]]]),
}


def degradation() -> SDJLSModel:
    """The double integrator with actuator degradation: N = 2, n = 2, m = 1, p = 2, r = 1.

    Returns
    -------
    SDJLSModel
    """
    return SDJLSModel(
        A=[[[1.0, 1.0], [0.0, 1.0]], [[1.2, 1.2], [0.0, 1.0]]],
        B=[[[0.0], [1.0]], [[0.01], [0.8]]],
        P_in=[[0.7, 0.3], [0.2, 0.8]],
        P_out=[[0.4, 0.6], [0.1, 0.9]],
        G=[[-1.0, -2.0]],
        H0=[0.1],
        Q=np.eye(2),
        R=[[1.0]],
        x0=[2.0, 0.0],
        E=np.eye(2),
        W=0.1**2 * np.eye(2),
        mode0=0,
        mode_names=("nominal", "degraded"),
        state_names=("position", "velocity"),
    )
