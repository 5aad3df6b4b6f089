"""SDJLS-VTOL-v0: the VTOL helicopter at three airspeeds, sampled by zero-order hold.

## Description

The longitudinal dynamics of a VTOL helicopter linearized at three airspeeds, the
continuous-time Markov jump linear system of de Farias, Geromel, do Val and Costa, *Output
feedback control of Markov jump linear systems in continuous-time*, IEEE TAC 45(5), 2000,
used throughout the MJLS literature. States ``x = [horizontal velocity (knots), vertical
velocity (knots), pitch rate (deg/s), pitch angle (deg)]``, inputs ``u = [collective pitch,
longitudinal cyclic pitch]``; modes 0, 1, 2 are the airspeeds 135 (nominal), 60 and 170 knots.

## Source, and what is taken from it

* The nominal 135-knot matrices (Narendra and Tripathi 1973; Keel, Bhattacharyya and Howze
  1988; quoted in Singh and Coelho, J. Dyn. Syst. Meas. Control 106, 1984)::

      A = [[-0.0366, 0.0271, 0.0188, -0.4555], [0.0482, -1.01, 0.0024, -4.0208],
           [0.1002, a32, -0.707, a34], [0, 0, 1, 0]]
      B = [[0.4422, 0.1761], [b21, -7.5922], [-5.52, 4.49], [0, 0]]

  **Verified** against ``demo/solvebmi_examples/example_hinf.m`` of the public repository
  ``lennyQL/linearizebmi`` (commit f1deae0, which cites Singh and Coelho 1984): every entry
  above agrees, with the nominal ``a32 = 0.3681``, ``a34 = 1.42``, ``b21 = 3.5446``.
* The airspeed-dependent entries ``a32 in (0.3681, 0.0664, 0.5047)``,
  ``a34 in (1.4200, 0.1198, 2.5460)``, ``b21 in (3.5446, 0.9775, 5.1120)`` and the
  transition-rate matrix ``Lambda = [[-0.0907, 0.0671, 0.0236], [0.0671, -0.0671, 0],
  [0.0236, 0, -0.0236]]`` (1/s) of de Farias et al. are as quoted in the project's request
  for the suite. **Not verified**: no public copy was found; the 135-knot entries agree with
  the verified nominal matrices above.

## Discretization

Zero-order hold with sampling time ``Ts = 0.5`` s (:data:`SAMPLING_TIME`): ``[[A_d, B_d],
[0, I]] = scipy.linalg.expm([[A, B], [0, 0]] Ts)`` per mode (:func:`zoh`), and the transition
probabilities over one sampling period ``P_in = scipy.linalg.expm(Lambda Ts)``
(:func:`rates_to_probabilities`), the exact law of the continuous-time chain sampled every
``Ts`` (a jump is assumed to act from the next sample on). At 135 knots the open loop has an
unstable oscillatory pair ``0.28 +- 0.26i`` (1/s, period 24 s), sampled 48 times per period,
and its fastest pole ``-2.07`` (time constant 0.48 s) is sampled at about its time constant;
``P_in[0, 0] = 0.956``: 93% of the 60-step episodes (30 s) from 135 knots see at least one
change of airspeed (``exp(-0.0907 * 30) = 0.066``).

## Region ``G x <= H_k``

``|x(2)| <= 0.8`` knots and ``|x(4)| <= 0.5`` deg (``r = 4``, constant): the vertical velocity
and the pitch angle stay within a tolerance band around the trim, as for a hold mode.

## Transition matrices

``P_in = expm(Lambda Ts)`` (published rates). ``P_out = expm(Lambda_out Ts)`` with
``Lambda_out`` equal to ``Lambda`` except that the rates out of the 135-knot mode are five
times larger (project's choice): once outside the band, the helicopter leaves its nominal
airspeed five times as often (``P_out[0, 0] = 0.80`` against ``P_in[0, 0] = 0.956``).

## Noise, cost, start

``E = I``, ``W = diag(0.5, 0.5, 0.5, 0.1)^2`` (gusts over one sampling period); ``Q_i = I``,
``R_i = I`` (the source gives no weights for this use); ``x0 = [0, 0, 0, 3]`` (a pitch
disturbance of 3 deg, outside the band), ``mode0 = 0``.

## Episode

Horizon 60 steps (30 s); action bound ``|u_i| <= 30``.

## Receding-horizon controller (``RHC``)

The suite's recipe (:mod:`sdjls_gym.systems`), with ``|nu_i| <= 20``.

## Version History

* v0: Initial version.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from sdjls_gym.model import SDJLSModel

__all__ = [
    "vtol",
    "zoh",
    "rates_to_probabilities",
    "ENV_ID",
    "HORIZON",
    "ACTION_BOUND",
    "SAMPLING_TIME",
    "RATES",
    "K",
    "RHC",
    "SOURCE",
]

ENV_ID = "SDJLS-VTOL-v0"
HORIZON = 60
ACTION_BOUND = 30.0
#: Sampling time of the zero-order hold, seconds.
SAMPLING_TIME = 0.5
SOURCE = (
    "de Farias, Geromel, do Val and Costa, IEEE TAC 45(5), 2000 (airspeed entries and rates as "
    "quoted in the project's request for the suite, not verified); nominal A, B verified against "
    "github.com/lennyQL/linearizebmi demo/solvebmi_examples/example_hinf.m"
)

#: The nominal 135-knot matrices (continuous time).
A_NOMINAL = np.array(
    [
        [-0.0366, 0.0271, 0.0188, -0.4555],
        [0.0482, -1.01, 0.0024, -4.0208],
        [0.1002, 0.3681, -0.707, 1.42],
        [0.0, 0.0, 1.0, 0.0],
    ]
)
B_NOMINAL = np.array([[0.4422, 0.1761], [3.5446, -7.5922], [-5.52, 4.49], [0.0, 0.0]])
#: Airspeed-dependent entries per mode (135, 60, 170 knots).
A32 = (0.3681, 0.0664, 0.5047)
A34 = (1.4200, 0.1198, 2.5460)
B21 = (3.5446, 0.9775, 5.1120)
#: Transition-rate matrix Lambda (1/s).
RATES = np.array([[-0.0907, 0.0671, 0.0236], [0.0671, -0.0671, 0.0], [0.0236, 0.0, -0.0236]])
#: Factor on the rates out of the nominal mode outside the region (``P_out``).
OUT_RATE_FACTOR = 5.0

#: Pre-stabilizing gains from Proposition 2 (``synthesize_gains(vtol())``), (N, m, n).
K = np.array(
    [
        [[-0.4083, 0.2701, 0.5428, 0.4639], [-0.2568, 0.3195, 0.1692, -0.251]],
        [[-0.2404, 0.1725, 0.333, 0.0265], [-0.0872, 0.2203, -0.04, -0.4645]],
        [[-0.4465, 0.3865, 0.718, 0.7673], [-0.3652, 0.45, 0.3913, 0.0257]],
    ]
)

#: Keyword arguments of the receding-horizon controllers.
RHC = {
    "xi": 0.9,
    "constraint": "individual",
    "alpha": 1000.0,
    "nu_bound": 20.0,
    "Psi": np.array(
        [
            [
                [5.303, 0.2754, -0.0381, -2.159],
                [0.2754, 1.155, 0.1474, -0.1594],
                [-0.0381, 0.1474, 1.373, 0.6818],
                [-2.159, -0.1594, 0.6818, 4.779],
            ],
            [
                [5.081, 0.2014, -0.2005, -2.296],
                [0.2014, 1.077, 0.03233, -0.2071],
                [-0.2005, 0.03233, 1.257, 0.7141],
                [-2.296, -0.2071, 0.7141, 4.951],
            ],
            [
                [6.211, 0.4882, 0.2972, -1.989],
                [0.4882, 1.291, 0.3606, 0.02399],
                [0.2972, 0.3606, 1.663, 0.8428],
                [-1.989, 0.02399, 0.8428, 4.618],
            ],
        ]
    ),
}

for _name in ("A_NOMINAL", "B_NOMINAL", "RATES"):
    globals()[_name].setflags(write=False)


def zoh(A: np.ndarray, B: np.ndarray, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretization of ``dx/dt = A x + B u`` with sampling time ``Ts``.

    ``expm([[A, B], [0, 0]] Ts) = [[A_d, B_d], [0, I]]``.

    Parameters
    ----------
    A : (n, n)
    B : (n, m)
    Ts : float, > 0

    Returns
    -------
    A_d : (n, n)
    B_d : (n, m)
    """
    A, B = np.asarray(A, dtype=np.float64), np.asarray(B, dtype=np.float64)
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * Ts)
    return E[:n, :n], E[:n, n:]


def rates_to_probabilities(rates: np.ndarray, Ts: float) -> np.ndarray:
    """Transition matrix ``expm(Lambda Ts)`` of a continuous-time chain sampled every ``Ts``.

    Rows are renormalized to sum to 1 exactly (they do up to round-off).
    """
    P = expm(np.asarray(rates, dtype=np.float64) * Ts)
    P = np.clip(P, 0.0, None)
    return P / P.sum(axis=1, keepdims=True)


def vtol() -> SDJLSModel:
    """The VTOL helicopter sampled at ``Ts = 0.5`` s: N = 3, n = 4, m = 2, p = 4, r = 4.

    Returns
    -------
    SDJLSModel
    """
    As, Bs = [], []
    for a32, a34, b21 in zip(A32, A34, B21, strict=True):
        A, B = A_NOMINAL.copy(), B_NOMINAL.copy()
        A[2, 1], A[2, 3], B[1, 0] = a32, a34, b21
        Ad, Bd = zoh(A, B, SAMPLING_TIME)
        As.append(Ad)
        Bs.append(Bd)
    rates_out = RATES.copy()
    rates_out[0] *= OUT_RATE_FACTOR
    return SDJLSModel(
        A=As,
        B=Bs,
        P_in=rates_to_probabilities(RATES, SAMPLING_TIME),
        P_out=rates_to_probabilities(rates_out, SAMPLING_TIME),
        G=[
            [0.0, 1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
            [0.0, 0.0, 0.0, -1.0],
        ],
        H0=[0.8, 0.8, 0.5, 0.5],
        Q=np.eye(4),
        R=np.eye(2),
        x0=[0.0, 0.0, 0.0, 3.0],
        E=np.eye(4),
        W=np.diag([0.25, 0.25, 0.25, 0.01]),
        mode0=0,
        mode_names=("135 knots", "60 knots", "170 knots"),
        state_names=("horizontal velocity", "vertical velocity", "pitch rate", "pitch angle"),
    )
