"""SDJLS-Solar-v0: the solar thermal receiver of Sworder and Rogers (1983).

## Description

The two-mode scalar Markov jump linear system of a solar thermal central receiver, the
example of Sworder and Rogers, *An LQ-solution to a control problem associated with a solar
thermal central receiver*, IEEE TAC 28(10), 1983, as used in the examples of Costa, Fragoso
and Marques, *Discrete-Time Markov Jump Linear Systems*, Springer 2005. The state ``x`` is the
deviation of the receiver's outlet temperature from its set point, the input ``u`` the
feedwater flow correction, and the mode the insolation: 0 sunny, 1 cloudy.

## Source, and what is taken from it

From the source, as quoted in the project's request for the suite: ``A = (0.8353, 0.9646)``,
``B = (0.0915, 0.0982)``, ``P_in = [[0.9767, 0.0233], [0.0435, 0.9565]]``, ``Q = 0.0355``,
``R = 1``. **Not verified**: no public copy of the paper or of the book's example could be found
(searched for the numbers 0.8353, 0.9646, 0.9767 and for the example's name); the numbers are
as quoted.

Added by this project: the noise, the region, ``P_out``, ``x0``, horizon, action bound and the
controller's data below.

## Region ``G x <= H_k``

``|x| <= 2`` (``G = [[1], [-1]]``, ``H = [2, 2]``, constant): the outlet temperature stays
within 2 units of its set point (2 standard deviations of the one-step disturbance).
Outside, the receiver runs off-design.

## Transition matrices

``P_in`` is the published chain. ``P_out = [[0.85, 0.15], [0.01, 0.99]]`` is the project's
choice and not a physical claim (the weather does not depend on the receiver): off-design, the
cloudy mode, whose dynamics are slower (``A = 0.9646``), becomes likelier and stickier, a
stress test of the state-dependent switching.

## Noise, cost, start

``E = 1``, ``W = 1`` (the unit of ``x`` is the standard deviation of the one-step
disturbance). Stage cost ``0.0355 x^2 + u^2`` (the published weights): the regulator barely
acts, so the LQ regulator leaves the band often. ``x0 = 4`` (a hot start, outside the band),
``mode0 = 0`` (sunny).

## Episode

Horizon 50 steps; action bound ``|u| <= 100``.

## Receding-horizon controller (``RHC``)

The suite's recipe (:mod:`sdjls_gym.systems`), with ``|nu| <= 50``.

## Version History

* v0: Initial version.
"""

from __future__ import annotations

import numpy as np

from sdjls_gym.model import SDJLSModel

__all__ = ["solar", "ENV_ID", "HORIZON", "ACTION_BOUND", "K", "RHC", "SOURCE"]

ENV_ID = "SDJLS-Solar-v0"
HORIZON = 50
ACTION_BOUND = 100.0
SOURCE = (
    "Sworder and Rogers, IEEE TAC 28(10), 1983; example of Costa, Fragoso and Marques, "
    "Discrete-Time Markov Jump Linear Systems, Springer 2005 (numbers as quoted in the "
    "project's request for the suite, not verified against a public copy)"
)

#: Pre-stabilizing gains from Proposition 2 (``synthesize_gains(solar())``), (N, m, n).
K = np.array([[[-9.129]], [[-9.8228]]])

#: Keyword arguments of the receding-horizon controllers.
RHC = {
    "xi": 0.9,
    "constraint": "individual",
    "alpha": 1000.0,
    "nu_bound": 50.0,
    "Psi": np.array([[[0.1295]], [[0.3603]]]),
}


def solar() -> SDJLSModel:
    """The solar thermal receiver: N = 2 (sunny, cloudy), n = 1, m = 1, p = 1, r = 2.

    Returns
    -------
    SDJLSModel
    """
    return SDJLSModel(
        A=[[[0.8353]], [[0.9646]]],
        B=[[[0.0915]], [[0.0982]]],
        P_in=[[0.9767, 0.0233], [0.0435, 0.9565]],
        P_out=[[0.85, 0.15], [0.01, 0.99]],
        G=[[1.0], [-1.0]],
        H0=[2.0, 2.0],
        Q=[[0.0355]],
        R=[[1.0]],
        x0=[4.0],
        E=[[1.0]],
        W=[[1.0]],
        mode0=0,
        mode_names=("sunny", "cloudy"),
        state_names=("outlet temperature deviation",),
    )
