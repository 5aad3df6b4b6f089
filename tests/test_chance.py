"""Tests of controllers.chance: tightening of the chance constraints and exact row probabilities."""

from __future__ import annotations

import math
from functools import partial

import cvxpy as cp
import numpy as np
import pytest
from conftest import raises_naming, random_sdjls
from scipy import stats

from controllers.chance import row_satisfaction_probability, tightened_set_empty, tightening
from sdjls_gym import SDJLSModel
from sdjls_gym.systems.macro import macro

#: A random SDJLS with E != I and W != I (full rank W), identity weights.
random_model = partial(random_sdjls, a_scale=0.6, weights=False)


# ---------------------------------------------------------------------- the paper's example
def test_example_tightening_matches_hand_computed_quantiles():
    """E = W = I, G rows (0, -1), (0, 1): every row of every mode has unit variance."""
    model = macro()
    ind = tightening(model, 0.85, "individual")
    joint = tightening(model, 0.85, "joint")
    bonf = tightening(model, 0.85, "bonferroni")
    assert ind.shape == joint.shape == bonf.shape == (3, 2)
    # Phi^{-1}(0.85) = 1.0364 (normal tables); chi2 with 2 dof: F^{-1}(xi) = -2 ln(1 - xi)
    np.testing.assert_allclose(ind, 1.0364333894937898, rtol=0, atol=1e-12)
    np.testing.assert_allclose(joint, math.sqrt(-2.0 * math.log(0.15)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(joint, 1.9478808920906, rtol=0, atol=1e-10)
    # union bound over r = 2 rows: Phi^{-1}(1 - 0.15 / 2) = Phi^{-1}(0.925) = 1.4395
    np.testing.assert_allclose(bonf, 1.4395314709384563, rtol=0, atol=1e-12)
    np.testing.assert_allclose(tightening(model, 0.95), 1.6448536269514722, rtol=0, atol=1e-12)
    # the facts the example relies on: the band for the income has width 3
    assert 2 * ind[0, 0] < 3.0 < 2 * joint[0, 0]
    assert 2 * tightening(model, 0.95)[0, 0] > 3.0


def test_joint_equals_paper_lemma1_for_identity_noise():
    """E = W = I: the generalised Lemma 1 is delta * ||G_j||_2 with delta^2 = chi2.ppf(xi, n)."""
    rng = np.random.default_rng(3)
    model = random_model(rng, N=2, n=3, m=1, p=3, r=3)
    model = SDJLSModel(**{**model.to_dict(), "E": None, "W": None})
    for xi in (0.3, 0.85, 0.99):
        delta = math.sqrt(stats.chi2.ppf(xi, df=3))
        expected = delta * np.linalg.norm(model.G, axis=1)
        np.testing.assert_allclose(tightening(model, xi, "joint"), [expected, expected], rtol=1e-12)


# ---------------------------------------------------------------------- random E and W
@pytest.mark.parametrize("seed", range(5))
def test_individual_and_bonferroni_are_exact_gaussian_quantiles(seed):
    rng = np.random.default_rng(seed)
    N, n, p, r = 3, int(rng.integers(1, 5)), int(rng.integers(1, 5)), int(rng.integers(1, 5))
    model = random_model(rng, N=N, n=n, m=1, p=p, r=r)
    xi = float(rng.uniform(0.05, 0.99))
    ind = tightening(model, xi, "individual")
    bonf = tightening(model, xi, "bonferroni")
    for i in range(N):
        for j in range(r):
            g = model.G[j] @ model.E[i]  # G_j E_i, so G_j E_i w ~ N(0, g W g')
            sd = math.sqrt(g @ model.W @ g)
            assert ind[i, j] == pytest.approx(stats.norm(loc=0.0, scale=sd).ppf(xi), rel=1e-10)
            level = 1.0 - (1.0 - xi) / r
            assert bonf[i, j] == pytest.approx(stats.norm(scale=sd).ppf(level), rel=1e-10)
            # the defining property: Pr{G_j E_i w <= t} = xi exactly
            assert stats.norm.cdf(ind[i, j] / sd) == pytest.approx(xi, abs=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_joint_is_support_function_of_the_chi2_ellipsoid(seed):
    """t_ij = max { G_j E_i w : w' W^{-1} w <= chi2.ppf(xi, p) }, found here by a conic solver."""
    rng = np.random.default_rng(10 + seed)
    model = random_model(rng, N=2, n=3, m=1, p=int(rng.integers(2, 5)), r=2)
    xi = 0.9
    delta2 = stats.chi2.ppf(xi, df=model.p)
    joint = tightening(model, xi, "joint")
    W_inv = np.linalg.inv(model.W)
    W_inv = 0.5 * (W_inv + W_inv.T)
    for i in range(model.N):
        for j in range(model.r):
            w = cp.Variable(model.p)
            prob = cp.Problem(
                cp.Maximize(model.G[j] @ model.E[i] @ w), [cp.quad_form(w, W_inv) <= delta2]
            )
            prob.solve(solver=cp.CLARABEL)
            assert joint[i, j] == pytest.approx(prob.value, rel=1e-6)


def test_ordering_individual_below_bonferroni_and_joint():
    rng = np.random.default_rng(7)
    for _ in range(20):
        r = int(rng.integers(2, 5))
        model = random_model(
            rng, N=2, n=int(rng.integers(1, 5)), m=1, p=int(rng.integers(1, 5)), r=r
        )
        for xi in (0.01, 0.3, 0.5, 0.7, 0.85, 0.95, 0.999):
            ind = tightening(model, xi, "individual")
            assert np.all(ind <= tightening(model, xi, "bonferroni") + 1e-12)
            assert np.all(ind <= tightening(model, xi, "joint") + 1e-12)
            # strictly so wherever the row has noise at all
            assert np.all(ind < tightening(model, xi, "bonferroni"))


def test_zero_noise_row_is_not_tightened():
    """A row that the noise does not reach (G_j E_i = 0) needs no tightening."""
    model = SDJLSModel(
        A=np.eye(2)[None],
        B=[[1.0], [0.0]],
        E=[[[1.0], [0.0]]],  # noise only in x(1)
        P_in=[[1.0]],
        P_out=[[1.0]],
        G=[[0.0, 1.0], [1.0, 0.0]],
        H0=[1.0, 1.0],
        Q=np.eye(2),
        R=[[1.0]],
        x0=[0.0, 0.0],
    )
    for kind in ("individual", "joint", "bonferroni"):
        t = tightening(model, 0.9, kind)
        assert t[0, 0] == 0.0 and t[0, 1] > 0.0
    # and its probability is deterministic: 1 inside, 0 outside
    probs = row_satisfaction_probability(model, np.array([[0.0, 0.5], [0.0, 1.5]]), 0, 0)
    assert probs[0, 0] == 1.0 and probs[1, 0] == 0.0


# ---------------------------------------------------------------------- exact row probabilities
def test_row_probability_matches_monte_carlo():
    """Compare with 200000 samples of x_{k+1} drawn with the model's own noise and dynamics.

    Each of the 2 x 3 x r entries is checked against a 4.9-sigma band (two-sided 99.9999%),
    so a false alarm over the whole test has probability below 1e-4.
    """
    rng = np.random.default_rng(11)
    model = random_model(rng, N=3, n=3, m=2, p=2, r=3)
    n_samples = 200_000
    for mode in range(model.N):
        x = rng.normal(size=model.n)
        u = rng.normal(size=model.m)
        k = int(rng.integers(0, 10))
        mean = model.next_state(x, mode, u, np.zeros(model.p))
        exact = row_satisfaction_probability(model, mean, mode, k + 1)
        w = model.sample_noise(rng, (n_samples,))
        x_next = model.next_state(np.broadcast_to(x, (n_samples, model.n)), mode, u, w)
        empirical = np.mean(model.constraint_values(x_next, k + 1) <= 0.0, axis=0)
        se = np.sqrt(exact * (1.0 - exact) / n_samples)
        assert np.all(np.abs(empirical - exact) <= 4.9 * se + 1e-12), (empirical, exact)


def test_row_probability_batched_shapes_and_tightened_mean():
    rng = np.random.default_rng(12)
    model = random_model(rng, N=2, n=3, m=1, p=3, r=4)
    xi = 0.8
    t = tightening(model, xi)
    # a mean lying exactly on the tightened row j has Pr{row j} = xi
    k_next = 5
    for mode in range(model.N):
        for j in range(model.r):
            g = model.G[j]
            mean = g * (model.H(k_next)[j] - t[mode, j]) / (g @ g)
            assert row_satisfaction_probability(model, mean, mode, k_next)[j] == pytest.approx(
                xi, abs=1e-12
            )
    means = rng.normal(size=(5, 4, model.n))
    modes = rng.integers(0, model.N, size=(5, 4))
    out = row_satisfaction_probability(model, means, modes, 3)
    assert out.shape == (5, 4, model.r)
    assert np.all((out >= 0.0) & (out <= 1.0))
    np.testing.assert_allclose(
        out[2, 1], row_satisfaction_probability(model, means[2, 1], modes[2, 1], 3)
    )


# ---------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize("xi", [0, 0.0, 1, 1.0, -0.1, 1.5, float("nan")])
def test_bad_xi_is_rejected(xi):
    with raises_naming(ValueError, "xi", xi):
        tightening(macro(), xi)


@pytest.mark.parametrize("xi", ["high", "0.85", True, None])
def test_xi_that_is_not_a_number_is_a_type_error(xi):
    with raises_naming(TypeError, "xi", xi):
        tightening(macro(), xi)


def test_bad_xi_message_names_value():
    with raises_naming(ValueError, "xi", 1.0):
        tightening(macro(), 1.0)


def test_bad_constraint_is_rejected():
    with raises_naming(ValueError, "constraint", "jiont"):
        tightening(macro(), 0.9, "jiont")


def test_model_must_be_a_model():
    with raises_naming(TypeError, "model", {"A": 1}):
        tightening({"A": 1}, 0.9)


# ------------------------------------------------------------------ empty tightened sets
@pytest.mark.parametrize("k_next", [1, 10, 20])
def test_example_tightened_band_is_empty_exactly_past_its_half_width(k_next):
    """The example's band ``2 + k/2 <= x(2) <= 5 + k/2`` is 3 wide and both rows have unit
    variance: it is empty once a row is tightened by more than 1.5, i.e. for individual
    constraints above xi = Phi(1.5) and for joint ones (p = 2, chi2 quantile delta^2 > 2.25)
    above xi = 1 - exp(-2.25 / 2)."""
    model = macro()
    H = model.H(k_next)
    assert H[0] + H[1] == pytest.approx(3.0)  # -(lower) + upper: the width
    edges = {"individual": stats.norm.cdf(1.5), "joint": 1.0 - math.exp(-2.25 / 2.0)}
    for constraint, edge in edges.items():
        below = tightened_set_empty(model, edge - 1e-3, k_next, constraint)
        above = tightened_set_empty(model, edge + 1e-3, k_next, constraint)
        assert below.shape == above.shape == (model.N,)
        assert not below.any(), (constraint, edge)
        assert above.all(), (constraint, edge)
    # the paper's two configurations at xi = 0.85: the individual band is not empty, the joint is
    assert not tightened_set_empty(model, 0.85, k_next).any()
    assert tightened_set_empty(model, 0.85, k_next, "joint").all()


def test_tightened_set_empty_agrees_with_a_cvxpy_feasibility_problem():
    """Random polyhedra in 3-d with 6 rows (seeds 0-3, 4 levels, 2 modes): the HiGHS answer
    matches cvxpy's (another solver), and both answers occur."""
    answers = []
    for seed in range(4):
        model = random_model(np.random.default_rng(seed), N=2, n=3, m=1, p=2, r=6)
        for xi in (0.6, 0.9, 0.99, 0.9999):
            got = tightened_set_empty(model, xi, 2, "joint")
            t = tightening(model, xi, "joint")
            for i in range(model.N):
                y = cp.Variable(model.n)
                prob = cp.Problem(cp.Minimize(0), [model.G @ y <= model.H(2) - t[i]])
                prob.solve(solver=cp.CLARABEL)
                assert prob.status in (cp.OPTIMAL, cp.INFEASIBLE), prob.status
                assert got[i] == (prob.status == cp.INFEASIBLE), (seed, xi, i)
                answers.append(bool(got[i]))
    assert 0 < sum(answers) < len(answers)


def test_rhc_ignores_xi_once_the_tightened_band_is_empty():
    """Past the half-width the slack absorbs the excess tightening: the QP's nu is the same for
    individual xi = 0.95, 0.99 and joint xi = 0.85 (all empty bands), rho > 0, and differs from
    the non-empty individual xi = 0.85."""
    from benchmarks.core.reference import paper_rhc

    model = macro()
    rng = np.random.default_rng(3)
    ctrls = {
        ("individual", 0.95): paper_rhc(model, 0.95, "individual"),
        ("individual", 0.99): paper_rhc(model, 0.99, "individual"),
        ("joint", 0.85): paper_rhc(model, 0.85, "joint"),
    }
    ref = paper_rhc(model, 0.85, "individual")
    differs = 0
    for _ in range(20):
        x = rng.normal(size=2) * 2.0 + np.array([0.0, 3.0])
        mode, k = int(rng.integers(model.N)), int(rng.integers(0, 20))
        out = {key: c.act(x, mode, k) for key, c in ctrls.items()}
        u0, _ = out[("individual", 0.95)]
        for key, (u, info) in out.items():
            assert info["rho"] > 0.0, key
            np.testing.assert_allclose(u, u0, rtol=1e-6, atol=1e-6, err_msg=str(key))
        differs += not np.allclose(ref.act(x, mode, k)[0], u0, rtol=1e-6, atol=1e-6)
    assert differs > 0


@pytest.mark.parametrize(
    ("k_next", "error"), [(-1, ValueError), (1.5, TypeError), (True, TypeError)]
)
def test_tightened_set_empty_rejects_bad_k_next(k_next, error):
    with raises_naming(error, "k_next", k_next):
        tightened_set_empty(macro(), 0.9, k_next)
