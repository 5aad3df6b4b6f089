"""Property-based tests of the receding-horizon QP (problem P3) over random small systems.

For each kind of chance constraint (individual, joint, Bonferroni), hypothesis draws the sizes
(N <= 4 modes, n <= 4 states, m <= 2 inputs, p <= 4 noise inputs, so p != n often, r <= 4
constraint rows), ``xi``, ``alpha``, ``nu_bound`` and a seed; the seed fills a
``numpy.random.Generator`` that draws the matrices: ``E`` and ``W`` are never the identity,
``P_in`` and ``P_out`` are random row-stochastic (with some exact zeros), and ``K`` is random,
often destabilising. The properties:

* the answer of the OSQP fast path is feasible and satisfies the KKT conditions of P3, which the
  test builds itself from the paper (section 5): the multipliers of the active constraints are
  recovered by nonnegative least squares and must make the gradient of the Lagrangian vanish to
  1e-6 relative;
* OSQP agrees with the cvxpy/Clarabel reference (1e-6 on nu and rho, 1e-8 relative on J*), and
  ``act_batch`` agrees with ``act`` (1e-6);
* whenever rho = 0, every row of ``G x_{k+1} <= H_{k+1}`` holds with probability >= xi,
  computed exactly from the Gaussian law of ``x_{k+1}`` (and, for the Bonferroni kind, all rows
  together by the union bound).

25 examples per kind and property, 4 states each; runs are derandomized (a fixed sequence of
examples), so CI does not flake.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import optimize, stats

from controllers import RecedingHorizonController, row_satisfaction_probability
from sdjls_gym import SDJLSModel

KINDS = ("individual", "joint", "bonferroni")
SETTINGS = settings(
    max_examples=25,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)


@dataclass
class Problem:
    model: SDJLSModel
    K: np.ndarray
    Psi: np.ndarray
    kw: dict  # xi, constraint, alpha, nu_bound
    states: list  # [(x, mode, k)]

    def controller(self, **extra) -> RecedingHorizonController:
        return RecedingHorizonController(self.model, self.K, Psi=self.Psi, **self.kw, **extra)


def stochastic(rng: np.random.Generator, N: int) -> np.ndarray:
    P = rng.dirichlet(np.ones(N), size=N)
    P[rng.random((N, N)) < 0.2] = 0.0  # some impossible transitions
    P[np.arange(N), rng.integers(0, N, N)] += 0.05  # every row keeps a positive entry
    return P / P.sum(axis=1, keepdims=True)


@st.composite
def problems(draw, kind: str) -> Problem:
    N, n, m = draw(st.integers(1, 4)), draw(st.integers(1, 4)), draw(st.integers(1, 2))
    p, r = draw(st.integers(1, 4)), draw(st.integers(1, 4))
    kw = {
        "constraint": kind,
        "xi": draw(st.floats(0.05, 0.995)),
        "alpha": draw(st.floats(10.0, 1000.0)),
        "nu_bound": draw(st.floats(0.3, 5.0)),
    }
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    L = rng.normal(size=(p, p))
    S = rng.normal(size=(N, m, m))
    model = SDJLSModel(
        A=rng.normal(size=(N, n, n)) * rng.uniform(0.3, 1.2),
        B=rng.normal(size=(N, n, m)),
        E=rng.normal(size=(N, n, p)),
        W=L @ L.T + 0.2 * np.eye(p),
        P_in=stochastic(rng, N),
        P_out=stochastic(rng, N),
        G=rng.normal(size=(r, n)),
        H0=rng.uniform(0.5, 3.0, size=r),
        H_rate=rng.uniform(-0.1, 0.1, size=r),
        Q=np.eye(n) * rng.uniform(0.2, 2.0),
        R=S @ S.transpose(0, 2, 1) + 0.3 * np.eye(m),
        x0=np.zeros(n),
    )
    T = rng.normal(size=(N, n, n))
    Psi = T @ T.transpose(0, 2, 1) + 0.5 * np.eye(n)
    K = rng.normal(size=(N, m, n)) * rng.uniform(0.1, 2.0)  # often destabilising
    states = [
        (rng.normal(size=n) * rng.choice([0.1, 1.0, 3.0]), int(rng.integers(N)), int(k))
        for k in rng.integers(0, 20, size=4)
    ]
    return Problem(model, K, Psi, kw, states)


# ----------------------------------------------------------------------------- P3, from the paper
@dataclass
class QP:
    """P3 at one (x_k, theta_k, k) in z = (nu, rho): f(z) and the rows ``C z <= d``."""

    f: object  # z -> J
    grad: object  # z -> (dJ/dz, size of the terms summed in each entry of dJ/dz)
    C: np.ndarray
    d: np.ndarray
    mean: object  # nu -> E[x_{k+1} | F_k]
    cov: np.ndarray  # Cov[x_{k+1} | F_k] = E W E'
    H_next: np.ndarray  # H_{k+1}


def tightening_of(model: SDJLSModel, xi: float, kind: str, mode: int) -> np.ndarray:
    """t_j = c * sd(G_j E w): Phi^{-1}(xi) (eq. constraint:det_univariate), Phi^{-1}(1-(1-xi)/r)
    (union bound) or sqrt(chi2_p^{-1}(xi)) (Lemma 1, eq. constraint:chi_square, with
    ||W^{1/2} E' G_j'|| = sd(G_j E w))."""
    cov = model.E[mode] @ model.W @ model.E[mode].T
    sd = np.sqrt(np.einsum("jn,nm,jm->j", model.G, cov, model.G))
    c = {
        "individual": stats.norm.ppf(xi),
        "bonferroni": stats.norm.ppf(1.0 - (1.0 - xi) / model.r),
        "joint": math.sqrt(stats.chi2.ppf(xi, model.p)),
    }[kind]
    return c * sd


def paper_qp(prob: Problem, x: np.ndarray, mode: int, k: int) -> QP:
    model, K, kw = prob.model, prob.K, prob.kw
    m, r = model.m, model.r
    A, B, E = model.A[mode], model.B[mode], model.E[mode]
    Q, R = model.Q[mode], model.R[mode]
    H_k = model.H0 + k * model.H_rate
    H_next = model.H0 + (k + 1) * model.H_rate
    inside = bool(np.all(model.G @ x <= H_k))  # eq. (eq:polyhedral)
    pi = (model.P_in if inside else model.P_out)[mode]  # eq. (eq:p_tran)
    Pi = np.einsum("j,jab->ab", pi, prob.Psi)  # Pi = sum_j pi_j Psi_j
    cov = E @ model.W @ E.T
    At = A + B @ K[mode]  # eq. (sys:stabilized_input)
    a = At @ x
    hbar = H_next - tightening_of(model, kw["xi"], kw["constraint"], mode)
    alpha, nb = kw["alpha"], kw["nu_bound"]

    def f(z):
        nu, rho = z[:m], z[m]
        u, mean = K[mode] @ x + nu, a + B @ nu
        return x @ Q @ x + u @ R @ u + mean @ Pi @ mean + np.trace(Pi @ cov) + alpha * rho

    def grad(z):
        nu = z[:m]
        g_u, g_mean = 2.0 * R @ (K[mode] @ x + nu), 2.0 * B.T @ Pi @ (a + B @ nu)
        return np.append(g_u + g_mean, alpha), np.append(np.abs(g_u) + np.abs(g_mean), alpha)

    eye = np.eye(m)
    C = np.vstack(
        [
            np.hstack([model.G @ B, -np.ones((r, 1))]),  # eq. (constraint:feasibility)
            np.hstack([eye, np.zeros((m, 1))]),  # nu <= nu_bound
            np.hstack([-eye, np.zeros((m, 1))]),  # -nu <= nu_bound
            np.concatenate([np.zeros(m), [-1.0]])[None],  # rho >= 0
        ]
    )
    d = np.concatenate([hbar - model.G @ a, np.full(2 * m, nb), [0.0]])
    return QP(f, grad, C, d, lambda nu: a + B @ nu, cov, H_next)


def assert_kkt(qp: QP, nu: np.ndarray, rho: float, tol: float = 1e-6) -> None:
    """Primal feasibility, and stationarity with nonnegative multipliers on the active rows:
    ``grad J + C_act' lam = 0`` with ``lam >= 0`` found by NNLS, each entry to ``tol`` relative
    to the size of the terms it sums."""
    z = np.append(nu, rho)
    slack = qp.C @ z - qp.d  # <= 0 when feasible
    scale = np.maximum(1.0, np.abs(qp.d) + np.abs(qp.C) @ np.abs(z))
    assert np.all(slack <= 1e-8 * scale), f"infeasible: {slack}"
    active = np.flatnonzero(slack >= -1e-7 * scale)  # complementary slackness: lam = 0 elsewhere
    g, size = qp.grad(z)
    lam = optimize.nnls(qp.C[active].T, -g)[0] if active.size else np.zeros(0)
    residual = g + qp.C[active].T @ lam
    bound = tol * (1.0 + size + np.abs(qp.C[active].T) @ lam)
    assert np.all(np.abs(residual) <= bound), (residual, bound, active)


# ----------------------------------------------------------------------------- the properties
@pytest.mark.parametrize("kind", KINDS)
@SETTINGS
@given(data=st.data())
def test_osqp_answer_is_feasible_and_satisfies_kkt(kind, data):
    prob = data.draw(problems(kind))
    ctrl = prob.controller()
    for x, mode, k in prob.states:
        u, info = ctrl.act(x, mode, k)
        assert info["status"] == "solved"
        nu, rho = info["nu"], info["rho"]
        np.testing.assert_allclose(u, prob.K[mode] @ x + nu, rtol=1e-12, atol=1e-12)
        qp = paper_qp(prob, x, mode, k)
        assert_kkt(qp, nu, rho)
        assert info["cost"] == pytest.approx(qp.f(np.concatenate([nu, [rho]])), rel=1e-9)


@pytest.mark.parametrize("kind", KINDS)
@SETTINGS
@given(data=st.data())
def test_osqp_agrees_with_cvxpy_and_act_batch_with_act(kind, data):
    prob = data.draw(problems(kind))
    fast, ref = prob.controller(), prob.controller(solver="cvxpy")
    xs, modes, ks = (np.array(v) for v in zip(*prob.states, strict=True))
    u_batch, batch = fast.act_batch(xs, modes, ks)
    assert list(batch["status"]) == ["solved"] * len(ks) and batch["ok"].all()
    for i, (x, mode, k) in enumerate(prob.states):
        u1, i1 = fast.act(x, mode, k)
        u2, i2 = ref.act(x, mode, k)
        assert i2["status"] == "solved"
        np.testing.assert_allclose(i1["nu"], i2["nu"], rtol=0, atol=1e-6)
        assert i1["rho"] == pytest.approx(i2["rho"], abs=1e-6)
        assert i1["cost"] == pytest.approx(i2["cost"], rel=1e-8)
        np.testing.assert_allclose(batch["nu"][i], i1["nu"], rtol=0, atol=1e-6)
        assert batch["rho"][i] == pytest.approx(i1["rho"], abs=1e-6)
        np.testing.assert_allclose(u_batch[i], u1, rtol=0, atol=1e-6)
        # and the batched answer is itself optimal for P3
        assert_kkt(paper_qp(prob, x, mode, k), batch["nu"][i], float(batch["rho"][i]))


@pytest.mark.parametrize("kind", KINDS)
@SETTINGS
@given(data=st.data())
def test_rows_hold_with_probability_at_least_xi_when_rho_is_zero(kind, data):
    prob = data.draw(problems(kind))
    xi, model = prob.kw["xi"], prob.model
    ctrl = prob.controller()
    for x, mode, k in prob.states:
        _, info = ctrl.act(x, mode, k)
        if info["rho"] > 0.0:
            continue
        qp = paper_qp(prob, x, mode, k)
        mean = qp.mean(info["nu"])
        sd = np.sqrt(np.einsum("jn,nm,jm->j", model.G, qp.cov, model.G))
        probs = stats.norm.cdf((qp.H_next - model.G @ mean) / sd)  # exact: x_{k+1} is Gaussian
        assert np.all(probs >= xi - 1e-7), (probs, xi)
        if prob.kw["constraint"] == "bonferroni":
            assert 1.0 - np.sum(1.0 - probs) >= xi - 1e-7  # all rows together, union bound
        np.testing.assert_allclose(
            row_satisfaction_probability(model, mean, mode, k + 1), probs, rtol=0, atol=1e-12
        )
