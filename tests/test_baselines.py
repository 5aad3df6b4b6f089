"""Tests of controllers.baselines: linear feedback and the MJLS LQ regulator."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg

from controllers.baselines import LinearFeedbackController, MJLSLQRController
from sdjls_gym import SDJLSModel
from sdjls_gym.errors import RiccatiConvergenceError
from sdjls_gym.systems.macro import PAPER_K, macro


def random_mjls(rng: np.random.Generator, N: int, n: int, m: int) -> SDJLSModel:
    S = rng.normal(size=(N, n, n))
    M = rng.normal(size=(N, m, m))
    return SDJLSModel(
        A=rng.normal(size=(N, n, n)) * 0.8,
        B=rng.normal(size=(N, n, m)),
        P_in=rng.dirichlet(np.ones(N), size=N),
        P_out=rng.dirichlet(np.ones(N), size=N),
        G=np.eye(n)[:1],
        H0=[1.0],
        Q=S @ S.transpose(0, 2, 1) + 0.1 * np.eye(n),
        R=M @ M.transpose(0, 2, 1) + 0.5 * np.eye(m),
        x0=np.zeros(n),
    )


def ms_spectral_radius(A_cl: np.ndarray, P: np.ndarray) -> float:
    """Spectral radius of V_j -> sum_i P[i, j] A_i V_i A_i' (mean-square stability iff < 1)."""
    N, n = A_cl.shape[0], A_cl.shape[1]
    T = np.zeros((N * n * n, N * n * n))
    for i in range(N):
        for j in range(N):
            T[j * n * n : (j + 1) * n * n, i * n * n : (i + 1) * n * n] = P[i, j] * np.kron(
                A_cl[i], A_cl[i]
            )
    return float(np.max(np.abs(np.linalg.eigvals(T))))


# ---------------------------------------------------------------------- linear feedback
def test_linear_feedback_is_K_x_with_stage_cost():
    model = macro()
    ctrl = LinearFeedbackController(model, PAPER_K)
    u, info = ctrl.act([2.0, 2.0], 0, 0)
    np.testing.assert_allclose(u, [2.5 * 2.0 - 3.2 * 2.0])  # K_1 = [2.5, -3.2] of section 6
    rng = np.random.default_rng(0)
    for _ in range(10):
        x, mode, k = rng.normal(size=2), int(rng.integers(3)), int(rng.integers(20))
        u, info = ctrl.act(x, mode, k)
        assert u.shape == (1,) and u.dtype == np.float64
        np.testing.assert_allclose(u, PAPER_K[mode] @ x, rtol=1e-14)
        np.testing.assert_array_equal(info["nu"], [0.0])
        assert info["rho"] == 0.0
        q = [1.0, 1.1, 1.2][mode]  # Q_i = q I, R_i = r of section 6
        r = [1.0, 1.2, 1.3][mode]
        assert info["cost"] == pytest.approx(q * x @ x + r * u[0] ** 2, rel=1e-13)


@pytest.mark.parametrize(
    "K, pattern",
    [
        (np.zeros((3, 2, 2)), r"K has shape \(3, 2, 2\); expected \(3, 1, 2\)"),
        (np.full((3, 1, 2), np.inf), r"K has a non-finite entry inf at index \(0, 0, 0\)"),
    ],
)
def test_linear_feedback_rejects_bad_gains(K, pattern):
    with pytest.raises(ValueError, match=pattern):
        LinearFeedbackController(macro(), K)


# ---------------------------------------------------------------------- MJLS LQ regulator
@pytest.mark.parametrize("seed", range(4))
def test_single_mode_equals_discrete_are(seed):
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(1, 5)), int(rng.integers(1, 3))
    model = random_mjls(rng, 1, n, m)
    ctrl = MJLSLQRController(model)
    A, B, Q, R = model.A[0], model.B[0], model.Q[0], model.R[0]
    X = linalg.solve_discrete_are(A, B, Q, R)
    F = -np.linalg.solve(R + B.T @ X @ B, B.T @ X @ A)
    scale = max(1.0, float(np.max(np.abs(X))))
    np.testing.assert_allclose(ctrl.X[0], X, rtol=0, atol=1e-8 * scale)
    np.testing.assert_allclose(ctrl.F[0], F, rtol=0, atol=1e-8 * max(1.0, np.max(np.abs(F))))
    x = rng.normal(size=n)
    np.testing.assert_allclose(ctrl.act(x, 0, 0)[0], F @ x, atol=1e-8 * max(1.0, np.max(np.abs(F))))


@pytest.mark.parametrize("seed", range(4))
def test_two_modes_solve_the_coupled_riccati_equations(seed):
    rng = np.random.default_rng(50 + seed)
    model = random_mjls(rng, 2, int(rng.integers(1, 5)), int(rng.integers(1, 3)))
    P = rng.dirichlet(np.ones(2), size=2)
    ctrl = MJLSLQRController(model, transition=P)
    X = ctrl.X
    scale = max(1.0, float(np.max(np.abs(X))))
    for i in range(2):
        A, B, Q, R = model.A[i], model.B[i], model.Q[i], model.R[i]
        E = P[i, 0] * X[0] + P[i, 1] * X[1]
        gain = np.linalg.inv(R + B.T @ E @ B)
        residual = Q + A.T @ E @ A - A.T @ E @ B @ gain @ B.T @ E @ A - X[i]
        assert np.max(np.abs(residual)) < 1e-8 * scale
        np.testing.assert_allclose(ctrl.F[i], -gain @ B.T @ E @ A, atol=1e-8 * scale)
        assert np.all(np.linalg.eigvalsh(X[i]) > 0)  # Q > 0 here, so X_i > 0
    # the regulator stabilises the jump system in the mean-square sense
    assert ms_spectral_radius(model.A + model.B @ ctrl.F, P) < 1.0


def test_transition_options_on_the_example():
    model = macro()
    for name, P in [
        ("in", model.P_in),
        ("out", model.P_out),
        ("average", 0.5 * (model.P_in + model.P_out)),
    ]:
        by_name = MJLSLQRController(model, transition=name)
        explicit = MJLSLQRController(model, transition=P)
        np.testing.assert_allclose(by_name.X, explicit.X, rtol=1e-12)
        np.testing.assert_allclose(by_name.transition_matrix, P)
        assert ms_spectral_radius(model.A + model.B @ by_name.F, P) < 1.0
    default = MJLSLQRController(model)
    np.testing.assert_allclose(default.X, MJLSLQRController(model, transition="average").X)
    assert not np.allclose(
        MJLSLQRController(model, transition="in").X, MJLSLQRController(model, transition="out").X
    )


def test_not_stabilisable_raises():
    """x' = 2 x + 0 u cannot be stabilised: the Riccati iteration X <- 1 + 4 X diverges."""
    model = SDJLSModel(
        A=[[[2.0]]], B=[[0.0]], P_in=[[1.0]], P_out=[[1.0]], G=[[1.0]], H0=[1.0], Q=[[1.0]],
        R=[[1.0]], x0=[0.0],
    )  # fmt: skip
    with pytest.raises(RiccatiConvergenceError, match="not mean-square stabilisable"):
        MJLSLQRController(model)
    assert issubclass(RiccatiConvergenceError, RuntimeError)


def test_too_few_iterations_raises():
    with pytest.raises(RuntimeError, match=r"did not converge in max_iter = 3 iterations"):
        MJLSLQRController(macro(), max_iter=3)


@pytest.mark.parametrize(
    "kwargs, pattern",
    [
        ({"transition": "markov"}, r"transition = 'markov' is not known"),
        ({"transition": np.eye(2)}, r"transition has shape \(2, 2\); expected \(3, 3\)"),
        ({"transition": np.full((3, 3), 0.3)}, r"transition row 0 sums to 0\.9"),
        (
            {"transition": -np.eye(3)},
            r"transition = .* has a negative entry; expected entries >= 0",
        ),
        ({"tol": 0.0}, r"tol = 0\.0"),
        ({"max_iter": 0}, r"max_iter = 0 is out of range"),
        ({"horizon": -3}, r"horizon = -3 is out of range"),
    ],
)
def test_lqr_rejects_bad_arguments(kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        MJLSLQRController(macro(), **kwargs)


# ---------------------------------------------------------------------- shared predict()
@pytest.mark.parametrize("which", ["feedback", "lqr"])
def test_predict_matches_act(which):
    model = macro()
    if which == "feedback":
        ctrl = LinearFeedbackController(model, PAPER_K, horizon=20)
    else:
        ctrl = MJLSLQRController(model, horizon=20)
    rng = np.random.default_rng(3)
    obs, expected = [], []
    for _ in range(5):
        x, mode, k = rng.normal(size=2) * 3, int(rng.integers(3)), int(rng.integers(21))
        o = np.concatenate([x, np.eye(3)[mode], [k / 20]]).astype(np.float32)
        u = ctrl.act(o[:2].astype(np.float64), mode, k)[0]
        action, state = ctrl.predict(o)
        assert action.shape == (1,) and action.dtype == np.float32 and state is None
        np.testing.assert_allclose(action, u, rtol=1e-6)
        obs.append(o)
        expected.append(u)
    actions, state = ctrl.predict(np.stack(obs), state=None)
    assert actions.shape == (5, 1) and actions.dtype == np.float32 and state is None
    np.testing.assert_allclose(actions, np.array(expected), rtol=1e-6)


def test_predict_of_a_time_invariant_controller_needs_no_horizon():
    """u = K_theta x does not depend on k: predict decodes no time and needs no horizon, whatever
    the observation's time entry (the README shows these controllers without horizon)."""
    rng = np.random.default_rng(0)
    obs = np.zeros((5, 6), np.float32)
    obs[:, :2] = rng.normal(size=(5, 2))
    modes = np.array([0, 1, 2, 1, 0])
    obs[np.arange(5), 2 + modes] = 1.0
    obs[:, -1] = [0.0, 0.025, 0.5, 0.7, 1.0]  # any time, even off a 1/20 grid
    for ctrl in (LinearFeedbackController(macro(), PAPER_K), MJLSLQRController(macro())):
        actions, _ = ctrl.predict(obs)
        expected = np.einsum("bij,bj->bi", ctrl.K[modes], obs[:, :2].astype(np.float64))
        np.testing.assert_allclose(actions, expected.astype(np.float32), rtol=1e-6)
