"""Shared fixtures for the model, env, vector env and wrapper tests.

The numbers of the macroeconomic example are typed in from section 6 of the paper
(``/work/shared/paper/sdjls-rhc-paper.tex``), never imported from ``sdjls_gym``, so that a
wrong number in the preset makes a test fail. Modes are 0-based here (the paper's 1, 2, 3 are
0, 1, 2: normal, boom, slump).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sdjls_gym import SDJLSModel


def _paper_numbers() -> SimpleNamespace:
    """Section 6: A_1..A_3, B, lambda, mu, G, H_k, x_0, Q_i, R_i, K_i, horizon."""
    return SimpleNamespace(
        A=np.array(
            [
                [[0.0, 1.0], [-2.5, 3.2]],
                [[0.0, 1.0], [-4.3, 4.5]],
                [[0.0, 1.0], [5.3, -5.2]],
            ]
        ),
        B=np.array([[0.0], [1.0]]),  # B = [0 1]', the same in every mode
        lam=np.array([[0.6, 0.3, 0.1], [0.25, 0.55, 0.2], [0.35, 0.15, 0.5]]),
        mu=np.array([[0.67, 0.17, 0.16], [0.30, 0.47, 0.23], [0.26, 0.10, 0.64]]),
        G=np.array([[0.0, -1.0], [0.0, 1.0]]),
        H=lambda k: np.array([-2.0 - 0.5 * k, 5.0 + 0.5 * k]),  # H_k
        x0=np.array([2.0, 2.0]),
        Q=np.array([np.eye(2), 1.1 * np.eye(2), 1.2 * np.eye(2)]),
        R=np.array([[[1.0]], [[1.2]], [[1.3]]]),
        K=np.array([[[2.5, -3.2]], [[4.3, -4.5]], [[-5.3, 5.2]]]),
        mode_names=("normal", "boom", "slump"),
        mode0=0,
        horizon=20,
    )


@pytest.fixture
def paper() -> SimpleNamespace:
    """The numbers of section 6 of the paper (a fresh copy per test)."""
    return _paper_numbers()


def _paper_kwargs() -> dict:
    p = _paper_numbers()
    return {
        "A": p.A,
        "B": p.B,
        "P_in": p.lam,
        "P_out": p.mu,
        "G": p.G,
        "H0": p.H(0),
        "H_rate": p.H(1) - p.H(0),
        "Q": p.Q,
        "R": p.R,
        "x0": p.x0,
        "E": np.eye(2),
        "W": np.eye(2),
        "mode0": p.mode0,
        "mode_names": p.mode_names,
    }


@pytest.fixture
def paper_kwargs() -> dict:
    """``SDJLSModel(**paper_kwargs)`` is the paper's example (E = I, W = I given explicitly)."""
    return _paper_kwargs()


@pytest.fixture
def quiet_paper_model() -> SDJLSModel:
    """The paper's example with W = 0: ``x_{k+1} = A x_k + B u_k`` exactly, modes still random."""
    return SDJLSModel(**{**_paper_kwargs(), "W": np.zeros((2, 2))})


@pytest.fixture
def paper_policy():
    """``u_k = K_theta x_k + nu_k`` with the paper's gains and ``nu_k = 3.5 + 0.5 k``.

    ``A_i + B K_i = [[0, 1], [0, 0]]`` in every mode, so the income is ``x_{k+1}(2) = nu_k +
    w_k(2)``, half a unit under the middle of the band. Works on one state or on a batch.
    """
    K = _paper_numbers().K

    def policy(state, mode, k):
        state = np.asarray(state, dtype=np.float64)
        nu = 3.5 + 0.5 * np.asarray(k, dtype=np.float64)
        return np.einsum("...ij,...j->...i", K[np.asarray(mode)], state) + nu[..., None]

    return policy


def _other_model() -> SDJLSModel:
    """A model unlike the paper's: N = 2, n = 3, m = 2, p = 1, r = 3, random initial mode."""
    return SDJLSModel(
        A=[
            [[0.9, 0.1, 0.0], [0.0, 0.8, 0.1], [0.0, 0.0, 0.7]],
            [[1.05, 0.0, 0.2], [0.1, 0.9, 0.0], [0.0, 0.3, 0.6]],
        ],
        B=[[[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]], [[0.5, 0.0], [0.0, 1.0], [0.2, 0.2]]],
        P_in=[[0.9, 0.1], [0.4, 0.6]],
        P_out=[[0.2, 0.8], [0.05, 0.95]],
        G=[[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [1.0, 1.0, 1.0]],
        H0=[1.0, 1.0, 2.0],
        H_rate=[0.1, 0.0, -0.05],
        Q=[[2.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]],
        R=[np.eye(2), [[2.0, 0.3], [0.3, 1.0]]],
        x0=[0.5, -0.2, 0.1],
        E=[[[1.0], [0.0], [0.5]], [[0.0], [1.0], [1.0]]],
        W=[[0.25]],
        mode0=[0.3, 0.7],
        mode_names=("calm", "stormy"),
    )


@pytest.fixture
def other_model() -> SDJLSModel:
    """A second, structurally different model (every optional field set)."""
    return _other_model()


# Hypothesis (6.1xx) also seeds its examples with constants mined from the project's own modules
# (every literal of every loaded local module), so a derandomized test would draw other examples
# whenever any literal in the repository changes or another set of modules is loaded (a single
# test file against the whole suite). Keep the draws a function of the test alone.
try:
    from hypothesis.internal.conjecture import providers as _hypothesis_providers

    _hypothesis_providers._get_local_constants = lambda: _hypothesis_providers._local_constants
except (ImportError, AttributeError):  # another Hypothesis version: nothing to pin
    pass
