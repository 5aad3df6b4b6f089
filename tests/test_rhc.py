"""Tests of controllers.rhc: the one-step receding-horizon controller (problem P3); its solve
path (fallbacks, warm start) is tested in test_rhc_solve_path.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import assert_feasible, paper_cost, random_problem
from scipy import optimize, stats

from controllers.chance import row_satisfaction_probability, tightening
from controllers.rhc import RecedingHorizonController, UnconstrainedRecedingHorizonController
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro

Z_999 = stats.norm.ppf(0.999)  # one-sided 99.9% normal quantile, 3.09


# ---------------------------------------------------------------------- OSQP against cvxpy
@pytest.mark.parametrize("solver", ["daqp", "osqp"])
@pytest.mark.parametrize("constraint", ["individual", "joint", "bonferroni"])
def test_fast_path_matches_cvxpy_on_the_example(constraint, solver):
    model = macro()
    fast = RecedingHorizonController(
        model, PAPER_K, **PAPER_RHC, constraint=constraint, solver=solver
    )
    ref = RecedingHorizonController(
        model, PAPER_K, **PAPER_RHC, constraint=constraint, solver="cvxpy"
    )
    rng = np.random.default_rng(1)
    n_rho = 0
    for _ in range(50):
        x = rng.normal(size=2) * rng.choice([1.0, 10.0, 60.0])  # 60: the box |nu| <= 100 binds
        mode, k = int(rng.integers(3)), int(rng.integers(0, 25))
        u1, i1 = fast.act(x, mode, k)
        u2, i2 = ref.act(x, mode, k)
        assert i1["status"] == "solved" and i1["solver"] in (solver, "active_set_warm")
        np.testing.assert_allclose(i1["nu"], i2["nu"], rtol=0, atol=1e-6)
        assert i1["rho"] == pytest.approx(i2["rho"], abs=1e-6)
        assert i1["cost"] == pytest.approx(i2["cost"], rel=1e-10, abs=1e-6)
        assert_feasible(fast, x, mode, k, u1, i1)
        n_rho += i1["rho"] > 0
    assert n_rho > 0  # the comparison covers states where the slack is used


@pytest.mark.parametrize("seed", range(8))
def test_osqp_matches_cvxpy_on_random_systems(seed):
    rng, model, K, Psi = random_problem(seed)
    for constraint in ("individual", "joint", "bonferroni"):
        kw = dict(
            xi=float(rng.uniform(0.6, 0.97)),
            constraint=constraint,
            alpha=float(rng.uniform(10.0, 1000.0)),
            nu_bound=float(rng.uniform(0.5, 5.0)),
        )
        fast = RecedingHorizonController(model, K, Psi=Psi, **kw)
        ref = RecedingHorizonController(model, K, Psi=Psi, solver="cvxpy", **kw)
        for _ in range(6):
            x = rng.normal(size=model.n) * rng.uniform(0.1, 3.0)
            mode, k = int(rng.integers(model.N)), int(rng.integers(0, 20))
            u1, i1 = fast.act(x, mode, k)
            u2, i2 = ref.act(x, mode, k)
            assert i1["status"] == "solved"
            np.testing.assert_allclose(i1["nu"], i2["nu"], rtol=0, atol=1e-6)
            assert i1["rho"] == pytest.approx(i2["rho"], abs=1e-6)
            assert i1["cost"] == pytest.approx(i2["cost"], rel=1e-10, abs=1e-6)
            np.testing.assert_allclose(u1, u2, rtol=0, atol=1e-6)
            assert_feasible(fast, x, mode, k, u1, i1)


def test_random_systems_cover_both_slack_regimes():
    """Over the random systems of the comparison, both rho = 0 and rho > 0 occur."""
    seen = set()
    for seed in range(8):
        rng, model, K, Psi = random_problem(seed)
        ctrl = RecedingHorizonController(model, K, Psi=Psi, xi=0.9, nu_bound=2.0)
        for _ in range(10):
            x = rng.normal(size=model.n) * rng.uniform(0.1, 3.0)
            seen.add(ctrl.act(x, int(rng.integers(model.N)), 3)[1]["rho"] > 0)
    assert seen == {True, False}


# ---------------------------------------------------------------------- optimality and cost
@pytest.mark.parametrize(
    "constraint, xi", [("individual", 0.85), ("joint", 0.85), ("individual", 0.95)]
)
def test_example_optimum_against_a_one_dimensional_search(constraint, xi):
    """m = 1: eliminate rho (its optimum is the smallest feasible one) and minimise over nu."""
    model = macro()
    rhc = dict(PAPER_RHC, xi=xi)
    ctrl = RecedingHorizonController(model, PAPER_K, **rhc, constraint=constraint)
    # E = W = I and ||G_j|| = 1: hand-computed tightening of both rows
    t = stats.norm.ppf(xi) if constraint == "individual" else math.sqrt(stats.chi2.ppf(xi, 2))
    rng = np.random.default_rng(5)
    for _ in range(10):
        x, mode, k = rng.normal(size=2) * 5.0, int(rng.integers(3)), int(rng.integers(0, 20))

        def rho_of(nu, x=x, mode=mode, k=k):
            u = PAPER_K[mode] @ x + nu
            mean = model.next_state(x, mode, u, np.zeros(2))
            return max(0.0, float(np.max(model.G @ mean - (model.H(k + 1) - t))))

        def f(nu, x=x, mode=mode, k=k):
            nu = np.array([nu])
            return paper_cost(model, PAPER_K, rhc["Psi"], 1000.0, x, mode, k, nu, rho_of(nu))

        grid = np.linspace(-100.0, 100.0, 401)  # f is convex: its minimiser is within 0.5
        best = grid[np.argmin([f(v) for v in grid])]
        res = optimize.minimize_scalar(
            f, bounds=(max(-100.0, best - 0.5), min(100.0, best + 0.5)), method="bounded",
            options={"xatol": 1e-11},
        )  # fmt: skip
        _, info = ctrl.act(x, mode, k)
        assert info["nu"][0] == pytest.approx(res.x, abs=1e-5)
        # the controller's cost is J_k at its own (nu, rho) and no worse than the search's best
        assert info["cost"] == pytest.approx(f(info["nu"][0]), rel=1e-12)
        assert info["rho"] == pytest.approx(rho_of(info["nu"]), abs=1e-9)
        assert info["cost"] <= res.fun + 1e-9 * abs(res.fun)
        assert info["cost"] == pytest.approx(res.fun, rel=1e-6)


@pytest.mark.parametrize("use_example", [True, False])
def test_cost_is_the_expected_one_step_cost(use_example):
    """J*_k = E[x'Qx + u'Ru + x_{k+1}' Psi_{theta_{k+1}} x_{k+1} | F_k] + alpha rho, eq. (obj:func).

    The expectation is estimated from 400000 draws of (w_k, theta_{k+1}) made with the model's
    own next_state / next_mode; the check is a two-sided 4.4-sigma band (99.999%).
    """
    if use_example:
        model, K, Psi = macro(), PAPER_K, PAPER_RHC["Psi"]
        ctrl = RecedingHorizonController(model, K, **PAPER_RHC, constraint="joint")
        x, mode, k = np.array([1.0, 3.0]), 1, 4
    else:
        rng, model, K, Psi = random_problem(21)
        ctrl = RecedingHorizonController(model, K, Psi=Psi, xi=0.9, alpha=50.0, nu_bound=3.0)
        x, mode, k = rng.normal(size=model.n), model.N - 1, 2
    u, info = ctrl.act(x, mode, k)
    rng = np.random.default_rng(99)
    n_samples = 400_000
    xs = np.broadcast_to(x, (n_samples, model.n))
    x_next = model.next_state(xs, mode, u, model.sample_noise(rng, (n_samples,)))
    mode_next = model.next_mode(xs, mode, k, rng.random(n_samples))
    terminal = np.einsum("bi,bij,bj->b", x_next, Psi[mode_next], x_next)
    samples = model.stage_cost(x, mode, u) + terminal + ctrl.alpha * info["rho"]
    se = samples.std(ddof=1) / math.sqrt(n_samples)
    assert abs(samples.mean() - info["cost"]) <= 4.4 * se
    # and exactly, with the expectation written out
    exact = paper_cost(model, K, Psi, ctrl.alpha, x, mode, k, info["nu"], info["rho"])
    assert info["cost"] == pytest.approx(exact, rel=1e-12)


# ---------------------------------------------------------------------- the chance constraints
@pytest.mark.parametrize("seed", [None, 0, 1, 2, 3])
def test_individual_rows_hold_with_probability_xi_when_rho_is_zero(seed):
    if seed is None:
        model, K, Psi, xi = macro(), PAPER_K, PAPER_RHC["Psi"], 0.85
        ctrl = RecedingHorizonController(model, K, **PAPER_RHC)
        rng = np.random.default_rng(8)
    else:
        rng, model, K, Psi = random_problem(100 + seed)
        xi = 0.8
        ctrl = RecedingHorizonController(model, K, Psi=Psi, xi=xi, nu_bound=5.0)
    checked = active = 0
    for _ in range(40):
        x = rng.normal(size=model.n) * rng.uniform(0.1, 3.0)
        mode, k = int(rng.integers(model.N)), int(rng.integers(0, 20))
        u, info = ctrl.act(x, mode, k)
        if info["rho"] > 0:
            continue
        mean = model.next_state(x, mode, u, np.zeros(model.p))
        probs = row_satisfaction_probability(model, mean, mode, k + 1)
        assert np.all(probs >= xi - 1e-9), probs
        checked += 1
        active += bool(np.any(np.abs(probs - xi) < 1e-7))  # a binding row sits exactly on xi
    assert checked >= 5
    if seed is None:
        assert active > 0


def _joint_probability_lcb(model, x, mode, k, u, rng, n_samples=200_000):
    """One-sided 99.9% lower confidence bound on Pr{G x_{k+1} <= H_{k+1}} (normal approx.)."""
    xs = np.broadcast_to(x, (n_samples, model.n))
    x_next = model.next_state(xs, mode, u, model.sample_noise(rng, (n_samples,)))
    p_hat = float(np.mean(model.in_region(x_next, k + 1)))
    return p_hat - Z_999 * math.sqrt(p_hat * (1.0 - p_hat) / n_samples)


@pytest.mark.parametrize("constraint, xi", [("joint", 0.6), ("bonferroni", 0.85)])
def test_all_rows_hold_jointly_on_the_example(constraint, xi):
    """Joint/Bonferroni: Pr{all rows} >= xi (Monte Carlo, 99.9% lower confidence bound)."""
    model = macro()
    ctrl = RecedingHorizonController(
        model, PAPER_K, **dict(PAPER_RHC, xi=xi), constraint=constraint
    )
    rng = np.random.default_rng(31)
    for x, mode, k in [([2.0, 2.0], 0, 0), ([3.0, 4.0], 1, 5), ([-1.0, 8.0], 2, 12)]:
        x = np.array(x)
        u, info = ctrl.act(x, mode, k)
        assert info["rho"] == 0.0  # 2 t < 3 for these levels: feasible
        mean = model.next_state(x, mode, u, np.zeros(model.p))
        probs = row_satisfaction_probability(model, mean, mode, k + 1)
        if constraint == "bonferroni":
            assert 1.0 - np.sum(1.0 - probs) >= xi - 1e-9  # union bound, exact
        assert _joint_probability_lcb(model, x, mode, k, u, rng) >= xi


@pytest.mark.parametrize("constraint", ["joint", "bonferroni"])
def test_all_rows_hold_jointly_on_random_systems(constraint):
    xi = 0.8
    checked = 0
    for seed in range(200, 260):
        rng, model, K, Psi = random_problem(seed)
        if model.r < 2:
            continue
        ctrl = RecedingHorizonController(
            model, K, Psi=Psi, xi=xi, constraint=constraint, nu_bound=5.0
        )
        x = rng.normal(size=model.n) * 0.3
        mode, k = int(rng.integers(model.N)), 1
        u, info = ctrl.act(x, mode, k)
        if info["rho"] > 0:
            continue
        mean = model.next_state(x, mode, u, np.zeros(model.p))
        probs = row_satisfaction_probability(model, mean, mode, k + 1)
        if constraint == "bonferroni":
            assert 1.0 - np.sum(1.0 - probs) >= xi - 1e-9
        assert _joint_probability_lcb(model, x, mode, k, u, rng) >= xi
        checked += 1
        if checked == 4:
            break
    assert checked == 4


# ---------------------------------------------------------------------- the paper's Monte Carlo
def closed_loop_rho(ctrl, model, runs=50, steps=20, seed=2016):
    """rho_k of a seeded closed loop simulated with the model's own dynamics: (runs, steps)."""
    rng = np.random.default_rng(seed)
    rho = np.empty((runs, steps))
    for run in range(runs):
        x, mode = np.array(model.x0), model.sample_mode0(rng)
        for k in range(steps):
            u, info = ctrl.act(x, mode, k)
            assert np.all(np.isfinite(u)) and info["status"] == "solved"
            rho[run, k] = info["rho"]
            w, uniform = model.sample_noise(rng), rng.random()
            x, mode = model.next_state(x, mode, u, w), int(model.next_mode(x, mode, k, uniform))
    return rho


def test_paper_monte_carlo_slack():
    """Section 6: rho_k = 0 for all k with individual constraints at xi = 0.85; rho_k > 0 with the
    joint constraint and with xi = 0.95. In this example Atilde_i = [[0, 1], [0, 0]], so the mean
    of the next income is nu and the band has width 3: the slack is 0 iff 2 t <= 3, and otherwise
    it is t - 1.5 at every step (t = 1.9479 joint, 1.6449 individual at 0.95).
    """
    model = macro()
    np.testing.assert_allclose(model.A + model.B @ PAPER_K, [[[0, 1], [0, 0]]] * 3, atol=1e-12)
    ind = closed_loop_rho(RecedingHorizonController(model, PAPER_K, **PAPER_RHC), model)
    assert np.all(ind == 0.0)
    joint = closed_loop_rho(
        RecedingHorizonController(model, PAPER_K, **PAPER_RHC, constraint="joint"), model
    )
    assert np.any(joint > 0.0)
    np.testing.assert_allclose(joint, math.sqrt(-2.0 * math.log(0.15)) - 1.5, rtol=0, atol=1e-7)
    high = closed_loop_rho(
        RecedingHorizonController(model, PAPER_K, **dict(PAPER_RHC, xi=0.95)), model
    )
    assert np.any(high > 0.0)
    np.testing.assert_allclose(high, stats.norm.ppf(0.95) - 1.5, rtol=0, atol=1e-7)


# ---------------------------------------------------------------------- variants
def test_unconstrained_controller_is_the_clipped_unconstrained_minimiser():
    model = macro()
    ctrl = UnconstrainedRecedingHorizonController(
        model, PAPER_K, Psi=PAPER_RHC["Psi"], nu_bound=5.0
    )
    rng = np.random.default_rng(6)
    for _ in range(20):
        x, mode, k = rng.normal(size=2) * 8, int(rng.integers(3)), int(rng.integers(20))
        pi = model.transition_rows(x, mode, k)
        Pi = np.einsum("j,jab->ab", pi, PAPER_RHC["Psi"])
        B, R, a = model.B[mode], model.R[mode], (model.A[mode] + model.B[mode] @ PAPER_K[mode]) @ x
        # d/dnu [(Kx + nu)'R(Kx + nu) + (a + B nu)' Pi (a + B nu)] = 0, then clip to the box
        nu_star = np.linalg.solve(R + B.T @ Pi @ B, -(R @ PAPER_K[mode] @ x + B.T @ Pi @ a))
        u, info = ctrl.act(x, mode, k)
        np.testing.assert_allclose(info["nu"], np.clip(nu_star, -5.0, 5.0), atol=1e-7)
        assert info["rho"] == 0.0
        expected = paper_cost(model, PAPER_K, PAPER_RHC["Psi"], 0.0, x, mode, k, info["nu"], 0.0)
        assert info["cost"] == pytest.approx(expected, rel=1e-12)
    ref = UnconstrainedRecedingHorizonController(
        model, PAPER_K, Psi=PAPER_RHC["Psi"], nu_bound=5.0, solver="cvxpy"
    )
    np.testing.assert_allclose(ref.act(x, mode, k)[1]["nu"], info["nu"], atol=1e-6)


def test_ball_offset_set_with_two_inputs():
    rng, model, K, Psi = random_problem(3)
    while model.m != 2:
        rng, model, K, Psi = random_problem(int(rng.integers(1000, 10**6)))
    ball = RecedingHorizonController(model, K, Psi=Psi, xi=0.9, nu_set="ball", nu_bound=0.3)
    ref = RecedingHorizonController(
        model, K, Psi=Psi, xi=0.9, nu_set="ball", nu_bound=0.3, solver="cvxpy"
    )
    on_boundary = 0
    for _ in range(10):
        x, mode = rng.normal(size=model.n) * 2, int(rng.integers(model.N))
        u, info = ball.act(x, mode, 2)
        assert info["solver"] == "cvxpy_socp" and info["status"] == "solved"
        assert_feasible(ball, x, mode, 2, u, info)
        np.testing.assert_allclose(info["nu"], ref.act(x, mode, 2)[1]["nu"], atol=1e-6)
        on_boundary += abs(np.linalg.norm(info["nu"]) - 0.3) < 1e-6
    assert on_boundary > 0
    # with a bound nothing reaches, the ball and the box give the same answer
    big_ball = RecedingHorizonController(model, K, Psi=Psi, xi=0.9, nu_set="ball", nu_bound=1e4)
    big_box = RecedingHorizonController(model, K, Psi=Psi, xi=0.9, nu_set="box", nu_bound=1e4)
    x = rng.normal(size=model.n)
    np.testing.assert_allclose(
        big_ball.act(x, 0, 1)[1]["nu"], big_box.act(x, 0, 1)[1]["nu"], atol=1e-6
    )


# ---------------------------------------------------------------------- predict()
def _observation(model, x, mode, k, horizon):
    return np.concatenate([x, np.eye(model.N)[mode], [k / horizon]]).astype(np.float32)


def test_predict_decodes_single_and_batched_observations():
    model = macro()
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC, horizon=20)
    rng = np.random.default_rng(13)
    rows, expected = [], []
    for _ in range(6):
        x, mode, k = rng.normal(size=2) * 4, int(rng.integers(3)), int(rng.integers(0, 21))
        obs = _observation(model, x, mode, k, 20)
        u_ref = ctrl.act(obs[:2].astype(np.float64), mode, k)[0]
        action, state = ctrl.predict(obs)
        assert action.shape == (1,) and action.dtype == np.float32 and state is None
        np.testing.assert_allclose(action, u_ref.astype(np.float32), rtol=1e-6)
        rows.append(obs)
        expected.append(u_ref)
    actions, state = ctrl.predict(np.stack(rows), state=None, episode_start=np.ones(6, bool))
    assert actions.shape == (6, 1) and actions.dtype == np.float32 and state is None
    np.testing.assert_allclose(actions, np.array(expected, dtype=np.float32), rtol=1e-6)


def test_predict_decodes_time_for_the_band():
    """The same (x, mode) at different k gives different inputs: the band moves with k."""
    model = macro()
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC, horizon=20)
    x = np.array([2.0, 2.0])
    a0 = ctrl.predict(_observation(model, x, 0, 0, 20))[0]
    a10 = ctrl.predict(_observation(model, x, 0, 10, 20))[0]
    np.testing.assert_allclose(a0, ctrl.act(x, 0, 0)[0], rtol=1e-6)
    np.testing.assert_allclose(a10, ctrl.act(x, 0, 10)[0], rtol=1e-6)
    assert abs(a10[0] - a0[0]) > 1.0


def test_predict_without_horizon_assumes_the_environments_default():
    """Built without horizon, predict decodes time with the environments' default horizon (20)
    and refuses a time entry that is not a multiple of 1/20 (an environment with another
    horizon), naming the fix."""
    model = macro()
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    x = np.array([2.0, 2.0])
    np.testing.assert_allclose(
        ctrl.predict(_observation(model, x, 0, 7, 20))[0], ctrl.act(x, 0, 7)[0], rtol=1e-6
    )
    with pytest.raises(ValueError, match=r"k / horizon = 0\.0125 does not decode.*pass horizon="):
        ctrl.predict(_observation(model, x, 0, 1, 80))
    with pytest.raises(ValueError, match=r"k / horizon = 1\.05 does not decode"):
        ctrl.predict(_observation(model, x, 0, 21, 20))


def test_predict_rejects_wrong_observation_size():
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC, horizon=20)
    with pytest.raises(ValueError, match=r"observation has shape \(5,\); expected \(6,\)"):
        ctrl.predict(np.zeros(5, dtype=np.float32))


# ---------------------------------------------------------------------- bad inputs
def _kwargs(**overrides):
    kw = dict(model=macro(), K=PAPER_K, **PAPER_RHC)
    kw.update(overrides)
    return kw


BAD_PSI = np.array([np.eye(2), -np.eye(2), np.eye(2)])
NAN_K = np.array(PAPER_K)
NAN_K[1, 0, 1] = np.nan


@pytest.mark.parametrize(
    "overrides, pattern",
    [
        ({"xi": 0.0}, r"xi = 0\.0 .*in \(0, 1\)"),
        ({"xi": 1.0}, r"xi = 1\.0 .*in \(0, 1\)"),
        ({"xi": -0.1}, r"xi = -0\.1 .*in \(0, 1\)"),
        ({"xi": 1.5}, r"xi = 1\.5 .*in \(0, 1\)"),
        ({"alpha": 0.0}, r"alpha = 0\.0 .*in \(0, 1e\+12\]"),
        ({"alpha": -5.0}, r"alpha = -5\.0 .*in \(0, 1e\+12\]"),
        ({"alpha": float("inf")}, r"alpha = inf"),
        ({"nu_bound": 0.0}, r"nu_bound = 0\.0 .*in \(0, 1e\+12\]"),
        ({"nu_bound": -1.0}, r"nu_bound = -1\.0"),
        ({"Psi": BAD_PSI}, r"Psi\[1\] is not positive definite"),
        ({"Psi": np.array([[[1.0, 0.5], [0.0, 1.0]]] * 3)}, r"Psi\[0\] = .* is not symmetric"),
        ({"Psi": np.eye(2)}, r"Psi has shape \(2, 2\); expected \(3, 2, 2\)"),
        ({"K": PAPER_K[:, :, :1]}, r"K has shape \(3, 1, 1\); expected \(3, 1, 2\)"),
        ({"K": PAPER_K[0]}, r"K has shape \(1, 2\)"),
        ({"K": NAN_K}, r"K has a non-finite entry nan at index \(1, 0, 1\)"),
        ({"constraint": "chance"}, r"constraint = 'chance'.*'individual', 'joint', 'bonferroni'"),
        ({"solver": "gurobi"}, r"solver = 'gurobi'.*'osqp', 'cvxpy'"),
        ({"nu_set": "sphere"}, r"nu_set = 'sphere'.*'box', 'ball'"),
        ({"osqp_settings": {"max_iterations": 5}}, r"osqp_settings"),
        ({"horizon": 0}, r"horizon = 0"),
    ],
)
def test_constructor_rejects_bad_arguments(overrides, pattern):
    with pytest.raises(ValueError, match=pattern):
        RecedingHorizonController(**_kwargs(**overrides))


def test_constructor_rejects_a_non_model():
    with pytest.raises(
        TypeError, match="model = 'macro' is a str; expected an sdjls_gym.SDJLSModel"
    ):
        RecedingHorizonController(**_kwargs(model="macro"))


def test_unconstrained_constructor_validates_too():
    with pytest.raises(ValueError, match=r"Psi\[1\] is not positive definite"):
        UnconstrainedRecedingHorizonController(macro(), PAPER_K, Psi=BAD_PSI)
    with pytest.raises(ValueError, match=r"nu_bound = 0\.0"):
        UnconstrainedRecedingHorizonController(macro(), PAPER_K, Psi=PAPER_RHC["Psi"], nu_bound=0.0)


@pytest.mark.parametrize(
    "args, error, pattern",
    [
        (([1.0, 2.0, 3.0], 0, 0), ValueError, r"x has shape \(3,\); expected \(2,\)"),
        (([1.0, np.nan], 0, 0), ValueError, r"x has a non-finite entry"),
        (([1.0, 2.0], 3, 0), ValueError, r"mode = 3 is out of range"),
        (([1.0, 2.0], -1, 0), ValueError, r"mode = -1 is out of range"),
        (([1.0, 2.0], 1.0, 0), TypeError, r"mode = 1\.0 is a float; expected an int"),
        (([1.0, 2.0], 0, -1), ValueError, r"k = -1 is out of range"),
        (([1.0, 2.0], 0, 2**53 + 1), ValueError, r"k = 9007199254740993 is out of range"),
        # the same through the fast check of float64 arrays and numpy ints
        ((np.array([1.0, np.nan]), 0, 0), ValueError, r"x has a non-finite entry"),
        ((np.array([np.inf, -np.inf]), 0, 0), ValueError, r"x has a non-finite entry"),
        ((np.array([1.0, 2.0, 3.0]), 0, 0), ValueError, r"x has shape \(3,\); expected \(2,\)"),
        ((np.array([1.0, 2.0]), np.int64(3), 0), ValueError, r"mode = np\.int64\(3\) is out of"),
        ((np.array([1.0, 2.0]), True, 0), TypeError, r"mode = True is a bool"),
        ((np.array([1.0, 2.0]), 0, np.int32(-1)), ValueError, r"k = np\.int32\(-1\) is out of"),
        ((np.array([1.0, 2.0]), 0, np.uint64(2**64 - 1)), ValueError, r"k = np\.uint64\(1844"),
    ],
)
def test_act_rejects_bad_inputs(args, error, pattern):
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    with pytest.raises(error, match=pattern):
        ctrl.act(*args)


def test_tightening_attribute_matches_chance_module():
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC, constraint="bonferroni")
    np.testing.assert_array_equal(ctrl.tightening, tightening(macro(), 0.85, "bonferroni"))
