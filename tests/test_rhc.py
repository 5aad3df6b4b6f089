"""Tests of controllers.rhc: the one-step receding-horizon controller (problem P3)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from scipy import optimize, stats

from controllers import Status
from controllers.chance import row_satisfaction_probability, tightening
from controllers.rhc import RecedingHorizonController, UnconstrainedRecedingHorizonController
from sdjls_gym import SDJLSModel, SDJLSVectorEnv
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro

Z_999 = stats.norm.ppf(0.999)  # one-sided 99.9% normal quantile, 3.09


def random_model(rng: np.random.Generator, N: int, n: int, m: int, p: int, r: int) -> SDJLSModel:
    """A random SDJLS with E != I and W != I."""
    L = rng.normal(size=(p, p))
    M = rng.normal(size=(N, m, m))
    return SDJLSModel(
        A=rng.normal(size=(N, n, n)) * 0.7,
        B=rng.normal(size=(N, n, m)),
        E=rng.normal(size=(N, n, p)),
        W=L @ L.T + 0.2 * np.eye(p),
        P_in=rng.dirichlet(np.ones(N), size=N),
        P_out=rng.dirichlet(np.ones(N), size=N),
        G=rng.normal(size=(r, n)),
        H0=rng.uniform(1.0, 3.0, size=r),
        H_rate=rng.uniform(-0.1, 0.1, size=r),
        Q=np.eye(n) * rng.uniform(0.5, 2.0),
        R=M @ M.transpose(0, 2, 1) + 0.3 * np.eye(m),
        x0=np.zeros(n),
    )


def random_problem(seed: int):
    """A random system (n <= 4, m <= 2, N <= 3, r <= 4), random K (stabilising or not), Psi."""
    rng = np.random.default_rng(seed)
    N, n, m = int(rng.integers(1, 4)), int(rng.integers(1, 5)), int(rng.integers(1, 3))
    p, r = int(rng.integers(1, 5)), int(rng.integers(1, 5))
    model = random_model(rng, N, n, m, p, r)
    K = rng.normal(size=(N, m, n))
    S = rng.normal(size=(N, n, n))
    Psi = S @ S.transpose(0, 2, 1) + 0.5 * np.eye(n)
    return rng, model, K, Psi


def paper_cost(model, K, Psi, alpha, x, mode, k, nu, rho):
    """J_k of P3 written out term by term: stage cost + sum_j pi_j E[x' Psi_j x] + alpha rho."""
    u = K[mode] @ x + nu
    pi = model.transition_rows(x, mode, k)
    mean = model.next_state(x, mode, u, np.zeros(model.p))
    cov = model.E[mode] @ model.W @ model.E[mode].T
    terminal = sum(pi[j] * (mean @ Psi[j] @ mean + np.trace(Psi[j] @ cov)) for j in range(model.N))
    return x @ model.Q[mode] @ x + u @ model.R[mode] @ u + terminal + alpha * rho


def assert_feasible(ctrl, x, mode, k, u, info, tol=1e-7):
    """(nu, rho) satisfies nu in U, rho >= 0 and every tightened row on x_{k+1}."""
    model = ctrl.model
    nu, rho = info["nu"], info["rho"]
    np.testing.assert_allclose(u, ctrl.K[mode] @ x + nu, rtol=0, atol=1e-12)
    assert rho >= 0.0
    if ctrl.nu_set == "box" or model.m == 1:
        assert np.all(np.abs(nu) <= ctrl.nu_bound + tol)
    else:
        assert np.linalg.norm(nu) <= ctrl.nu_bound + tol
    if ctrl.tightening is not None:
        mean = model.next_state(x, mode, u, np.zeros(model.p))
        slack = model.H(k + 1) - ctrl.tightening[mode] + rho - model.G @ mean
        assert np.all(slack >= -tol * max(1.0, np.max(np.abs(model.H(k + 1))))), slack


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


# ---------------------------------------------------------------------- robustness
def _no_enumeration(monkeypatch):
    """Make the enumeration find nothing, so that the fallbacks after it are reached."""
    from controllers.active_set import ActiveSetQP

    monkeypatch.setattr(ActiveSetQP, "solve_one", lambda self, w: None)


def test_forced_osqp_failure_is_solved_exactly_by_the_enumeration():
    """OSQP failing (iteration limit) does not reach cvxpy or nu = 0 while the enumeration of
    the family's active sets settles the state: the answer is the exact optimum."""
    model = macro()
    normal = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    failing = RecedingHorizonController(
        model,
        PAPER_K,
        **PAPER_RHC,
        solver="osqp",
        osqp_settings={"max_iter": 1},
        cvxpy_fallback=False,
    )
    x = np.array([1.0, 4.0])
    _, i1 = normal.act(x, 2, 3)
    _, i2 = failing.act(x, 2, 3)
    assert i2["solver"] == "active_set" and i2["ok"]
    assert i2["status"] == "solved" and i2["status"] is Status.SOLVED
    assert i2["notes"] == "osqp status 'maximum iterations reached'"
    np.testing.assert_array_equal(i2["nu"], i1["nu"])
    assert i2["cost"] == i1["cost"] and i2["rho"] == i1["rho"]


def test_forced_daqp_failure_goes_to_osqp_then_the_enumeration(monkeypatch):
    """The default path: DAQP failing (forced) hands over to OSQP, and OSQP failing to the
    enumeration; the answer is the exact optimum, the notes say what failed."""
    from controllers.qp import QPFamily

    model = macro()
    normal = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    x = np.array([1.0, 4.0])
    _, i1 = normal.act(x, 2, 3)
    monkeypatch.setattr(QPFamily, "run_daqp", lambda *args, **kwargs: (None, None, "exit flag -4"))
    by_osqp = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    _, i2 = by_osqp.act(x, 2, 3)
    assert i2["solver"] == "osqp" and i2["ok"] and i2["notes"] == "daqp exit flag -4"
    failing = RecedingHorizonController(model, PAPER_K, **PAPER_RHC, osqp_settings={"max_iter": 1})
    _, i3 = failing.act(x, 2, 3)
    assert i3["solver"] == "active_set" and i3["ok"]
    assert i3["notes"] == "daqp exit flag -4; osqp status 'maximum iterations reached'"
    for info in (i2, i3):
        np.testing.assert_array_equal(info["nu"], i1["nu"])
        assert info["cost"] == i1["cost"] and info["rho"] == i1["rho"]


def test_forced_osqp_failure_falls_back_to_nu_zero(monkeypatch):
    _no_enumeration(monkeypatch)
    model = macro()
    ctrl = RecedingHorizonController(
        model,
        PAPER_K,
        **PAPER_RHC,
        solver="osqp",
        osqp_settings={"max_iter": 1},
        cvxpy_fallback=False,
    )
    x = np.array([2.0, 2.0])
    u, info = ctrl.act(x, 0, 0)
    assert info["status"] == "fallback_nu0" and "osqp" in info["notes"] and not info["ok"]
    assert info["solver"] == "fallback"
    np.testing.assert_array_equal(info["nu"], [0.0])
    np.testing.assert_allclose(u, PAPER_K[0] @ x)
    # nu = 0 puts the next income's mean at 0: the lower row needs rho = 2.5 + Phi^{-1}(0.85)
    assert info["rho"] == pytest.approx(2.5 + stats.norm.ppf(0.85), abs=1e-12)
    expected = paper_cost(
        model, PAPER_K, PAPER_RHC["Psi"], 1000.0, x, 0, 0, np.zeros(1), info["rho"]
    )
    assert math.isfinite(info["cost"]) and info["cost"] == pytest.approx(expected, rel=1e-12)


def test_forced_osqp_failure_is_rescued_by_cvxpy(monkeypatch):
    _no_enumeration(monkeypatch)
    model = macro()
    normal = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    rescued = RecedingHorizonController(
        model, PAPER_K, **PAPER_RHC, solver="osqp", osqp_settings={"max_iter": 1}
    )
    x = np.array([1.0, 4.0])
    _, i1 = normal.act(x, 2, 3)
    _, i2 = rescued.act(x, 2, 3)
    assert i2["solver"] == "cvxpy" and i2["status"] == "solved" and i2["ok"]
    assert "maximum iterations" in i2["notes"]
    # cvxpy's active set is re-solved exactly: the same answer as the healthy controller
    np.testing.assert_array_equal(i2["nu"], i1["nu"])
    assert i2["cost"] == i1["cost"]


@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_warm_started_families_are_reused(solver):
    model = macro()
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC, solver=solver)
    rng = np.random.default_rng(4)
    for _ in range(30):
        ctrl.act(rng.normal(size=2) * 5, int(rng.integers(3)), int(rng.integers(20)))
    engines = [fam.engine for fam in ctrl._families.values()]
    assert len(engines) == 2 * model.N  # one QP family per (mode, in_region)
    # the solver's workspace is set up on first use, then kept
    workspace = "_daqp_ws" if solver == "daqp" else "_osqp"
    assert any(getattr(e, workspace) is not None for e in engines)


# ---------------------------------------------------------------------- active-set warm start
def assert_same_answer(i1, i2, tol):
    np.testing.assert_allclose(i1["nu"], i2["nu"], rtol=0, atol=tol)
    assert i1["rho"] == pytest.approx(i2["rho"], abs=tol)
    assert i1["cost"] == pytest.approx(i2["cost"], rel=1e-10, abs=tol)


def warm_start_cases():
    """(model, K, Psi, kwargs, state scale, controller class) of the warm-start comparisons:
    the example (both slack regimes and the box bind at scale 60) and random systems with E, W
    not identity, m = 1 or 2 and up to 4 rows."""
    cases = [
        (
            macro(),
            PAPER_K,
            PAPER_RHC["Psi"],
            {k: v for k, v in PAPER_RHC.items() if k != "Psi"},
            20.0,
        )
    ]
    for seed in (0, 1, 2, 5):
        rng, model, K, Psi = random_problem(seed)
        kw = dict(xi=float(rng.uniform(0.6, 0.97)), alpha=float(rng.uniform(10.0, 1000.0)),
                  nu_bound=float(rng.uniform(0.5, 5.0)))  # fmt: skip
        cases.append((model, K, Psi, kw, 2.0))
    return cases


@pytest.mark.parametrize("case", range(5))
@pytest.mark.parametrize("cls", [RecedingHorizonController, UnconstrainedRecedingHorizonController])
def test_warm_start_equals_enumeration_and_cvxpy(case, cls):
    """Random states, modes and times: the OSQP path (warm start first) gives the answer of the
    full enumeration and of the cvxpy reference, and the warm start answers some of them."""
    model, K, Psi, kw, scale = warm_start_cases()[case]
    if cls is UnconstrainedRecedingHorizonController:
        kw = {key: kw[key] for key in ("alpha", "nu_bound")}
    fast = cls(model, K, Psi=Psi, **kw)
    enum = cls(model, K, Psi=Psi, **kw, solver="active_set")
    ref = cls(model, K, Psi=Psi, **kw, solver="cvxpy")
    rng = np.random.default_rng(100 + case)
    paths = []
    for i in range(60):
        if i % 6 == 0:  # runs of states near one another (as in a closed loop), then a jump
            base = rng.normal(size=model.n) * scale
        x = base + rng.normal(size=model.n) * 0.05 * scale
        mode, k = int(rng.integers(model.N)), int(rng.integers(0, 20))
        u1, i1 = fast.act(x, mode, k)
        _, i2 = enum.act(x, mode, k)
        _, i3 = ref.act(x, mode, k)
        assert i1["status"] == "solved" and i2["solver"] == "active_set"
        assert_same_answer(i1, i2, 1e-9)
        assert_same_answer(i1, i3, 1e-6)
        np.testing.assert_allclose(u1, K[mode] @ x + i1["nu"], rtol=0, atol=1e-12)
        assert_feasible(fast, x, mode, k, u1, i1)
        paths.append(i1["solver"])
    assert "active_set_warm" in paths and "daqp" in paths
    assert fast.path_counts == {p: paths.count(p) for p in set(paths)}


def test_warm_start_answers_most_closed_loop_steps():
    """On the example's closed loop the active set rarely changes: most decisions are made by
    the warm start (no OSQP), and they equal those with OSQP at every call."""
    model = macro()
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    cold = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    cold.set_warm_start(False)
    env = SDJLSVectorEnv(16, model=model)
    _, info = env.reset(seed=7)
    for _ in range(20):
        us = []
        for x, mode, k in zip(info["state"], info["mode"], info["k"], strict=True):
            u, i1 = ctrl.act(x, mode, k)
            _, i2 = cold.act(x, mode, k)
            assert_same_answer(i1, i2, 1e-9)
            us.append(u)
        _, _, _, _, info = env.step(np.array(us))
    counts = ctrl.path_counts
    assert sum(counts.values()) == 16 * 20
    assert counts.get("active_set_warm", 0) > 0.5 * 16 * 20, counts
    assert "active_set_warm" not in cold.path_counts


def test_a_wrong_remembered_active_set_is_rejected():
    """Whatever active set is remembered for the family, the answer is the optimum: a wrong
    one fails the KKT test, DAQP decides, and its (right) active set is remembered instead."""
    model = macro()
    ref = RecedingHorizonController(model, PAPER_K, **PAPER_RHC, solver="cvxpy")
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    states = [  # one per active set of the example's optima (rows of ActiveSetQP.C)
        ([0.1, -0.1], 0, 0),  # lower band row, rho = 0
        ([4.7, -3.5], 2, 3),  # upper band row, rho = 0
        ([0.3, 3.4], 1, 3),  # no row: rho = 0 only
        ([1.7, -93.0], 1, 0),  # slack used on the lower row
        ([63.0, -17.3], 2, 3),  # slack used on the upper row
        ([0.5, -3.7], 2, 250),  # nu = 100 (box) and slack
        ([55.0, -72.6], 2, 0),  # the upper row, nu = 100 and slack
    ]
    seen = set()
    for x, mode, k in states:
        x = np.array(x)
        _, expected = ctrl.act(x, mode, k)
        assert_same_answer(expected, ref.act(x, mode, k)[1], 1e-6)
        key = (mode, expected["in_region"])
        engine = ctrl._families[key].engine
        right = engine.warm
        seen.add(right)
        for wrong in engine.enumeration().active_sets:
            engine.warm = wrong
            _, info = ctrl.act(x, mode, k)
            assert info["solver"] == ("active_set_warm" if wrong == right else "daqp"), wrong
            assert engine.warm == right
            np.testing.assert_array_equal(info["nu"], expected["nu"])
            assert info["cost"] == expected["cost"] and info["rho"] == expected["rho"]
    assert len(seen) == len(states)


def test_answer_from_a_failed_osqp_identification_comes_from_the_enumeration(monkeypatch):
    """If no active set read from OSQP's solution verifies, the full enumeration settles the
    state (same answer, reported as "active_set") and its set is remembered."""
    from controllers.qp import QPFamily

    model = macro()
    healthy = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    monkeypatch.setattr(QPFamily, "local", lambda *args, **kwargs: None)
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC, solver="osqp")
    x = np.array([0.0, 1.0])
    _, info = ctrl.act(x, 1, 5)
    _, expected = healthy.act(x, 1, 5)
    assert info["solver"] == "active_set" and info["status"] == "solved"
    np.testing.assert_array_equal(info["nu"], expected["nu"])
    assert ctrl.act(x, 1, 5)[1]["solver"] == "active_set_warm"


def test_bounds_that_osqp_rejects_are_a_failure_not_the_previous_answer(monkeypatch):
    """OSQP's update() silently keeps the previous data when it rejects new bounds (l > u once
    clipped to 1e30: a state of size 1e31 here); that must be reported as an OSQP failure,
    answered exactly by the enumeration, and without it go down the fallback chain, never
    return the previous state's solution as "solved"."""
    kw = {**PAPER_RHC, "nu_bound": 1.0}
    ctrl = RecedingHorizonController(
        macro(), np.zeros((3, 1, 2)), **kw, solver="osqp", cvxpy_fallback=False
    )
    ctrl.set_warm_start(False)  # OSQP at every call
    assert ctrl.act(np.array([10.0, -10.0]), 1, 3)[1]["solver"] == "osqp"
    _, info = ctrl.act(np.array([1e31, -1e31]), 1, 3)
    assert info["solver"] == "active_set", info["notes"]
    assert info["status"] == "solved"
    assert info["notes"] == (
        "osqp status 'error ValueError: bounds rejected by OSQP (l > u after clipping)'"
    )
    # with K = 0 the next income's mean is -8.8e31 + nu: nu = +1 moves it towards the band's
    # lower row as far as U allows (the exact rational optimum, tests/exact_p3.py, agrees)
    assert info["nu"][0] == 1.0 and info["rho"] > 1e31
    _no_enumeration(monkeypatch)
    ctrl.act(np.array([10.0, -10.0]), 1, 3)
    _, info = ctrl.act(np.array([1e31, -1e31]), 1, 3)
    assert info["solver"] == "fallback", info["notes"]
    assert info["status"] == "fallback_nu0"
    assert info["notes"].startswith("osqp status 'error ValueError: bounds rejected")
    # the default path answers the same state exactly (DAQP on its regularized objective)
    default = RecedingHorizonController(macro(), np.zeros((3, 1, 2)), **kw, cvxpy_fallback=False)
    _, info = default.act(np.array([1e31, -1e31]), 1, 3)
    assert info["ok"] and info["nu"][0] == 1.0 and info["rho"] > 1e31, info["notes"]


def test_fast_input_check_leaves_the_state_alone():
    """float64 (n,) states are used without a copy and never written; numpy ints are accepted."""
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    x = np.array([1.0, 3.0])
    x.setflags(write=False)
    u1, i1 = ctrl.act(x, np.int64(1), np.int32(4))
    u2, i2 = ctrl.act([1.0, 3.0], 1, 4)
    np.testing.assert_array_equal(u1, u2)
    assert isinstance(i1["cost"], float) and np.array_equal(x, [1.0, 3.0])
    assert ctrl._check_inputs(np.array([1e100, -1e100]), 0, 0)[1:] == (0, 0)  # the bound itself
    with pytest.raises(ValueError, match=r"magnitude above 1e\+100"):  # costs would overflow
        ctrl._check_inputs(np.array([1e308, 1e308]), 0, 0)


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


def test_warm_start_rejects_a_stale_active_set_that_is_barely_infeasible():
    """A remembered active set that leaves the band row out, and breaks it by ~5e-7 at the next
    state, is not accepted (the KKT tolerance of the enumeration scales with alpha = 1000 and
    would pass it, reporting a spurious rho > 0): the answer is the enumeration's, rho = 0."""
    warm = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    enum = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC, solver="active_set")
    warm.act(np.array([-3.32597337, 1.75755035]), 0, 3)  # remembers {rho >= 0}
    x = np.array([-1.8313282, 2.48824919])
    _, got = warm.act(x, 0, 3)
    _, want = enum.act(x, 0, 3)
    assert got["rho"] == want["rho"] == 0.0
    assert np.array_equal(got["nu"], want["nu"]) and got["cost"] == want["cost"]


def test_warm_start_answers_equal_the_enumeration_bit_for_bit_along_closed_loops():
    """Along 40 closed-loop episodes (800 decisions) per constraint kind, act() with the warm
    start returns exactly the enumeration's answer, and the warm start answers most calls."""
    for kind in ("individual", "joint", "bonferroni"):
        kw = {**PAPER_RHC, "constraint": kind}
        warm = RecedingHorizonController(macro(), PAPER_K, **kw)
        enum = RecedingHorizonController(macro(), PAPER_K, **kw, solver="active_set")
        env = gym.make("SDJLS-Macro-v0")
        for episode in range(40):
            _, info = env.reset(seed=episode)
            done = False
            while not done:
                u, a = warm.act(info["state"], info["mode"], info["k"])
                _, b = enum.act(info["state"], info["mode"], info["k"])
                assert np.array_equal(a["nu"], b["nu"]) and a["rho"] == b["rho"], (kind, info)
                _, _, terminated, truncated, info = env.step(u.astype(np.float32))
                done = terminated or truncated
        counts = warm.path_counts
        assert counts.get("active_set_warm", 0) > 0.5 * sum(counts.values())
