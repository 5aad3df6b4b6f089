"""SDJLS-Random-v0: seeded random systems with guaranteed pre-stabilization, for scaling studies.

## Description

:func:`random_task` draws an SDJLS with ``n`` states, ``m`` inputs, ``N`` modes and ``r``
region rows from ``numpy.random.default_rng(seed)``: the same arguments give the same system
on every machine (only numpy's documented generator and linear algebra are used). The
difficulty knob is ``spectral_radius``, the open-loop spectral radius of the last ("bad")
mode; mode ``i`` has ``spectral_radius * (0.8 + 0.2 i / (N - 1))``.

## Construction and guarantees

For each mode ``i``: a closed loop ``Acl_i = U diag(s) V'`` with random orthogonal ``U``,
``V`` and singular values ``s`` in ``[0.1 gamma, gamma]``, ``gamma = min(0.8, 0.9 *
smallest target radius)``; random ``B_i`` and a random gain direction ``K0_i``; then
``A_i = Acl_i - c_i B_i K0_i`` with ``c_i > 0`` found by Brent's method so that the spectral radius
of ``A_i`` is its target, and ``K_i = c_i K0_i``, so ``A_i + B_i K_i = Acl_i``.

* **Proposition 2 is feasible by construction**: ``X_i = I``, ``Y_i = K_i`` satisfy its LMIs
  for any ``P_in``, ``P_out``, since ``||Acl_i||_2 <= gamma < 1`` (the LMIs reduce to
  ``Acl_i' Acl_i < I``); ``Task.K`` is this ``K``. ``controllers.synthesize_gains`` then
  succeeds too (tests/test_suite_tasks.py checks both over many seeds).
* **The tightened set is non-empty** for individual chance constraints at any
  ``xi < Phi(2) = 0.977``: each row is ``g_j x <= 2 sigma_j`` with ``g_j`` a random unit
  vector and ``sigma_j`` the largest standard deviation of ``g_j E_i w`` over the modes, so the
  origin keeps a margin of ``(2 - Phi^{-1}(xi)) sigma_j`` in every row.

Other data: ``E_i = I``, ``W = 0.01 I``, ``Q_i = I``, ``R_i = I``; ``P_in`` has rows
``0.7 e_i + 0.3 d_i`` with ``d_i`` a Dirichlet(1, ..., 1) draw; ``P_out = (P_in + 1 e_{N-1}')
/ 2`` (leaving the region makes the bad mode ``N - 1`` likelier, visibly: half of every row
moves to it); ``x0 = 4 sigma_0 g_0``, outside the first row's half-space; ``mode0 = 0``.
Horizon 50, action bound 100. The receding-horizon data: individual constraints at
``xi = 0.9``, ``alpha = 1000``, ``|nu_i| <= 10``, ``Psi_i = I``.

## Arguments of ``gym.make``

``gym.make("SDJLS-Random-v0", n=3, m=1, N=2, r=2, system_seed=0, spectral_radius=1.2)``
(these are the defaults) plus the usual ``horizon``, ``action_bound``, ``divergence_bound``,
``render_mode``. **``system_seed`` chooses the system; the noise and the initial mode are
seeded by ``env.reset(seed=...)``, as for every Gymnasium environment.** The two are
independent: one system, many noise seeds. ``seed=`` given to ``gym.make`` is refused with a
``TypeError`` that says so. ``gym.make_vec`` takes the same keyword arguments, in every
vectorization mode.

## Version History

* v0: Initial version.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from scipy.optimize import brentq

from sdjls_gym.model import SDJLSModel
from sdjls_gym.systems.task import Task
from sdjls_gym.validation import check_int, check_number

__all__ = [
    "random_task",
    "ENV_ID",
    "HORIZON",
    "ACTION_BOUND",
    "REGION_SIGMAS",
    "MAX_SIZE",
    "MAX_SPECTRAL_RADIUS",
]

ENV_ID = "SDJLS-Random-v0"
HORIZON = 50
ACTION_BOUND = 100.0
#: Each region row is ``g_j x <= REGION_SIGMAS * sigma_j`` (see the module docstring).
REGION_SIGMAS = 2.0
#: Largest ``n``, ``m``, ``N``, ``r`` accepted.
MAX_SIZE = 64
#: Largest ``spectral_radius`` accepted.
MAX_SPECTRAL_RADIUS = 10.0
NOISE_VARIANCE = 0.01
SOURCE = "random: sdjls_gym.systems.random_system.random_task (this project)"
DEFAULTS: dict[str, Any] = {"n": 3, "m": 1, "N": 2, "r": 2, "seed": 0, "spectral_radius": 1.2}


def _orthogonal(rng: np.random.Generator, n: int) -> np.ndarray:
    Z = rng.standard_normal((n, n))
    Q, R = np.linalg.qr(Z)
    return Q * np.where(np.diag(R) < 0, -1.0, 1.0)  # Haar-distributed


def _radius(M: np.ndarray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def _scale_to_radius(Acl: np.ndarray, BK0: np.ndarray, target: float) -> float | None:
    """``c > 0`` with ``radius(Acl - c BK0) = target``, or None if none is found.

    The bracket ``[lo, hi]`` is found by doubling ``hi``, then Brent's method finds the root in
    it to 4 ulps: about 12 eigenvalue computations (the whole cost of a large task), where a
    bisection to the last bit needs about 100. The two agree to the last bits of ``c``, which a
    run's task digest (12 digits) does not see.
    """
    lo, hi = 0.0, 1.0
    for _ in range(80):  # radius(Acl) < target at c = 0; find c where it is above
        if _radius(Acl - hi * BK0) > target:
            break
        lo, hi = hi, 2.0 * hi
    else:
        return None
    root = brentq(lambda c: _radius(Acl - c * BK0) - target, lo, hi, xtol=1e-300,
                  rtol=4 * np.finfo(float).eps)  # fmt: skip
    return float(root)


def _check_args(
    n: Any, m: Any, N: Any, r: Any, seed: Any, spectral_radius: Any
) -> tuple[int, int, int, int, int, float]:
    n = check_int("n", n, low=1, high=MAX_SIZE, what="number of states")
    m = check_int("m", m, low=1, high=n, what="number of inputs, at most n")
    N = check_int("N", N, low=2, high=MAX_SIZE, what="number of modes")
    r = check_int("r", r, low=1, high=MAX_SIZE, what="number of region rows")
    seed = check_int("seed", seed, low=0, what="seed of the system's generator")
    rho = check_number(
        "spectral_radius",
        spectral_radius,
        low=0.0,
        low_open=True,
        high=MAX_SPECTRAL_RADIUS,
        what="open-loop spectral radius of the bad mode",
    )
    return n, m, N, r, seed, rho


def random_task(
    n: int = 3,
    m: int = 1,
    N: int = 2,
    r: int = 2,
    seed: int = 0,
    *,
    spectral_radius: float = 1.2,
) -> Task:
    """A random SDJLS task (see the module docstring for the construction and its guarantees).

    Parameters
    ----------
    n, m, N, r : int
        States (1..64), inputs (1..n), modes (2..64), region rows (1..64).
    seed : int
        Seed of the system's generator, ``>= 0`` (not the noise seed of the environment).
    spectral_radius : float
        Open-loop spectral radius of the bad mode ``N - 1``, in ``(0, 10]``; above 1 the open
        loop is unstable.

    Returns
    -------
    Task
        ``env_id = "SDJLS-Random-v0"``; ``env_kwargs`` rebuild the environment with
        ``gym.make``; ``K`` pre-stabilizes (Proposition 2 holds with ``X_i = I``, ``Y_i = K_i``).

    Raises
    ------
    TypeError
        An argument that is not an int (or a number, for ``spectral_radius``).
    ValueError
        An argument out of range.

    Examples
    --------
    >>> task = random_task(n=4, m=2, N=3, r=3, seed=7)
    >>> task.model.n, task.model.m, task.model.N, task.model.r, task.K.shape
    (4, 2, 3, 3, (3, 2, 4))
    """
    return _random_task(*_check_args(n, m, N, r, seed, spectral_radius))


@functools.lru_cache(maxsize=64)
def _random_task(n: int, m: int, N: int, r: int, seed: int, rho: float) -> Task:
    rng = np.random.default_rng(seed)
    targets = rho * (0.8 + 0.2 * np.arange(N) / (N - 1))
    gamma = min(0.8, 0.9 * float(targets[0]))
    A, B, K = [], [], []
    for target in targets:
        while True:  # a redraw is needed only if K0 B is nilpotent (probability 0)
            s = rng.uniform(0.1 * gamma, gamma, n)
            Acl = (_orthogonal(rng, n) * s) @ _orthogonal(rng, n).T
            Bi = rng.standard_normal((n, m)) / math.sqrt(n)
            K0 = rng.standard_normal((m, n)) / math.sqrt(n)
            c = _scale_to_radius(Acl, Bi @ K0, float(target))
            if c is not None:
                break
        A.append(Acl - c * Bi @ K0)
        B.append(Bi)
        K.append(c * K0)
    P_in = 0.7 * np.eye(N) + 0.3 * rng.dirichlet(np.ones(N), size=N)
    P_out = 0.5 * P_in
    P_out[:, -1] += 0.5
    G = rng.standard_normal((r, n))
    G /= np.linalg.norm(G, axis=1, keepdims=True)
    sigma = math.sqrt(NOISE_VARIANCE)  # E_i = I, W = 0.01 I: every unit row has this std
    H0 = np.full(r, REGION_SIGMAS * sigma)
    x0 = 4.0 * sigma * G[0]
    model = SDJLSModel(
        A=np.array(A),
        B=np.array(B),
        P_in=P_in,
        P_out=P_out,
        G=G,
        H0=H0,
        Q=np.eye(n),
        R=np.eye(m),
        x0=x0,
        E=np.eye(n),
        W=NOISE_VARIANCE * np.eye(n),
        mode0=0,
    )
    env_kwargs = {"n": n, "m": m, "N": N, "r": r, "system_seed": seed, "spectral_radius": rho}
    return Task(
        env_id=ENV_ID,
        model=model,
        horizon=HORIZON,
        action_bound=ACTION_BOUND,
        K=np.array(K),
        rhc={
            "xi": 0.9,
            "constraint": "individual",
            "alpha": 1000.0,
            "nu_bound": 10.0,
            "Psi": np.array([np.eye(n)] * N),
        },
        source=SOURCE,
        env_kwargs=env_kwargs,
    )
