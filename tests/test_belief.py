"""Tests of controllers.belief: problem P3 on the belief of a hidden mode.

* at a certain belief ``e_theta`` it is RecedingHorizonController's P3, on every suite task and
  constraint kind, and continuous as the belief tends to certainty;
* its chance constraints hold under the belief's mixture of modes (seeded Monte Carlo, one-sided
  binomial bound at 99.9% per case);
* its answers are the optimum of an independent cvxpy formulation written here from the
  paper's equations (eq:exp_noise, constraint:det_univariate, constraint:chi_square,
  constraint:feasibility);
* inputs, settings, solvers, batches, threads, pickling, predict.
"""

from __future__ import annotations

import inspect
import pickle
import threading

import cvxpy as cp
import numpy as np
import pytest
from conftest import UNSHOWN, raises_naming
from scipy import stats

from controllers import (
    BeliefRecedingHorizonController,
    RecedingHorizonController,
    tightened_set_empty,
)
from controllers.belief_qp import BeliefQP
from sdjls_gym.errors import ModeNotObservedError
from sdjls_gym.observation import encode_observation
from sdjls_gym.systems import TASKS

KINDS = ("individual", "joint", "bonferroni")
CONFIDENCE = 0.999  # one-sided, per Monte Carlo case
DRAWS = 20000


def _controllers(task, constraint, **kw):
    rhc = {**task.rhc, "constraint": constraint}
    belief = BeliefRecedingHorizonController(task.model, task.K, **rhc, **kw)
    return belief, RecedingHorizonController(task.model, task.K, **rhc)


def _states(task, rng, count):
    """States around x0 and the band, at several sizes, and times within the horizon."""
    model = task.model
    scale = rng.choice([0.3, 1.0, 3.0, 10.0], size=(count, 1))
    x = model.x0 + scale * rng.normal(size=(count, model.n))
    return x, rng.integers(0, task.horizon, size=count)


# ------------------------------------------------------------------ P3 at a certain belief
@pytest.mark.parametrize("constraint", KINDS)
@pytest.mark.parametrize("env_id", list(TASKS))
def test_a_certain_belief_gives_p3s_answer(env_id, constraint):
    task = TASKS[env_id]
    model = task.model
    belief_ctrl, rhc = _controllers(task, constraint)
    rng = np.random.default_rng(list(TASKS).index(env_id))
    xs, ks = _states(task, rng, 60)
    used_rho = 0
    for x, k in zip(xs, ks.tolist(), strict=True):
        mode = int(rng.integers(model.N))
        u, info = belief_ctrl.act(x, np.eye(model.N)[mode], k)
        u_ref, ref = rhc.act(x, mode, k)
        assert info["ok"] and ref["ok"]
        scale = np.abs(task.K[mode] @ x).sum() + np.abs(ref["nu"]).sum() + 1e-300
        np.testing.assert_allclose(u, u_ref, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(info["nu"], ref["nu"], rtol=0, atol=1e-9 * scale)
        mean = model.A[mode] @ x + model.B[mode] @ u_ref
        row_terms = np.abs(model.H(k + 1)).max() + np.abs(model.G @ mean).max() + ref["rho"]
        assert abs(info["rho"] - ref["rho"]) <= 1e-9 * row_terms
        assert info["cost"] == pytest.approx(ref["cost"], rel=1e-9)
        risk = np.ones(model.N)
        risk[mode] = 1.0 - task.rhc["xi"]
        np.testing.assert_allclose(info["risk"], risk, rtol=1e-15)
        used_rho += info["rho"] > 0
    if env_id == "SDJLS-Macro-v0" and constraint == "joint":
        assert used_rho  # the tightened band is empty there: the slack is compared too


@pytest.mark.parametrize("env_id", list(TASKS))
def test_the_answer_is_continuous_as_the_belief_becomes_certain(env_id):
    task = TASKS[env_id]
    model = task.model
    belief_ctrl, rhc = _controllers(task, "individual")
    rng = np.random.default_rng(7)
    xs, ks = _states(task, rng, 20)
    for x, k in zip(xs, ks.tolist(), strict=True):
        mode = int(rng.integers(model.N))
        belief = np.full(model.N, 1e-12 / (model.N - 1))
        belief[mode] = 1.0 - 1e-12
        u, info = belief_ctrl.act(x, belief, k)
        u_ref, ref = rhc.act(x, mode, k)
        scale = np.abs(task.K[mode] @ x).sum() + np.abs(ref["nu"]).sum() + 1.0
        np.testing.assert_allclose(u, u_ref, rtol=0, atol=1e-6 * scale)
        assert info["cost"] == pytest.approx(ref["cost"], rel=1e-6)
        assert info["ok"] and info["risk"][mode] < 1.0


# ------------------------------------------------------------------ the guarantee
def _draw_next(model, x, u, belief, rng, count):
    """``x_{k+1}`` of ``count`` draws: theta ~ belief, then the noise of that mode."""
    theta = rng.choice(model.N, size=count, p=belief)
    w = rng.multivariate_normal(np.zeros(model.p), model.W, size=count)
    return model.A[theta] @ x + model.B[theta] @ u + np.einsum("bij,bj->bi", model.E[theta], w)


def _random_belief(rng, N):
    kind = rng.integers(3)
    if kind == 0:
        return rng.dirichlet(np.ones(N))
    if kind == 1:  # concentrated: some modes given up
        b = rng.dirichlet(np.full(N, 0.3))
        return b
    b = np.zeros(N)
    b[rng.integers(N)] = 1.0
    return 0.97 * b + 0.03 * rng.dirichlet(np.ones(N))


MC_TASKS = ["SDJLS-Solar-v0", "SDJLS-VTOL-v0", "SDJLS-ThreeState-v0", "SDJLS-Degradation-v0",
            "SDJLS-Random-v0", "SDJLS-Macro-v0"]  # fmt: skip


@pytest.mark.parametrize("constraint", KINDS)
@pytest.mark.parametrize("env_id", MC_TASKS)
def test_the_chance_constraints_hold_under_the_mixture(env_id, constraint):
    """With ``rho == 0``, ``Pr{G_j x_{k+1} > H_{k+1,j}} <= 1 - xi`` per row (individual) or for
    any row (joint, bonferroni) under theta ~ belief: the observed frequency of DRAWS draws is
    at most the one-sided 99.9% binomial quantile of 1 - xi, in every case."""
    task = TASKS[env_id]
    model = task.model
    if tightened_set_empty(model, task.rhc["xi"], 1, constraint).any():
        pytest.skip("the tightened band is empty: rho > 0 at every state, even for P3")
    ctrl, _ = _controllers(task, constraint)
    xi = task.rhc["xi"]
    rng = np.random.default_rng([11, list(TASKS).index(env_id), KINDS.index(constraint)])
    limit = stats.binom.ppf(CONFIDENCE, DRAWS, 1.0 - xi) / DRAWS
    cases, worst = 0, 0.0
    for _ in range(200):
        if cases == 6:
            break
        # states near the band's centre (the origin or x0, scaled) and farther out
        centre = model.x0 * rng.choice([0.0, 0.5, 1.0])
        x = centre + rng.choice([0.05, 0.3, 1.0]) * rng.normal(size=model.n)
        k = int(rng.integers(task.horizon))
        belief = _random_belief(rng, model.N)
        u, info = ctrl.act(x, belief, k)
        if info["rho"] > 0:
            continue
        assert info["ok"]
        assert belief @ info["risk"] <= 1.0 - xi + 1e-12  # the budget
        x_next = _draw_next(model, x, u, belief, rng, DRAWS)
        violated = x_next @ model.G.T > model.H(k + 1)  # (DRAWS, r)
        freq = violated.mean(axis=0) if constraint == "individual" else violated.any(axis=1).mean()
        assert np.all(freq <= limit), (x, belief, freq, limit)
        worst = max(worst, float(np.max(freq)))
        cases += 1
    assert cases >= 3, "too few decisions with rho == 0 to test"


def test_the_bound_is_reached_where_one_mode_carries_the_risk_on_an_active_row():
    """Not conservative where it should not be: a certain belief and an active row give the
    frequency 1 - xi (two-sided 99.9% binomial interval)."""
    task = TASKS["SDJLS-Degradation-v0"]
    model = task.model
    ctrl, _ = _controllers(task, "individual")
    xi = task.rhc["xi"]
    rng = np.random.default_rng(3)
    lo, hi = stats.binom.interval(CONFIDENCE, DRAWS, 1.0 - xi)
    found = 0
    for _ in range(200):
        x, k = _states(task, rng, 1)
        x, k = x[0], int(k[0])
        belief = np.eye(model.N)[int(rng.integers(model.N))]
        u, info = ctrl.act(x, belief, k)
        mean = model.A @ x + model.B @ u
        slack = model.H(k + 1) - model.G @ mean[int(np.argmax(belief))] - ctrl.tightening[0]
        if info["rho"] > 0 or np.abs(slack).min() > 1e-9:
            continue  # not an active row
        x_next = _draw_next(model, x, u, belief, rng, DRAWS)
        freq = (x_next @ model.G.T > model.H(k + 1)).mean(axis=0).max()
        assert lo / DRAWS <= freq <= hi / DRAWS
        found += 1
        if found == 3:
            break
    assert found


# ------------------------------------------------------------------ optimality (cvxpy)
def _reference(task, constraint, give_up, x, belief, k):
    """P3 on the belief written from the paper's equations with cvxpy (Clarabel): the
    allocation of the docs, the tightening from scipy's quantiles, Pi_i of eq. (eq:exp_noise)."""
    model, s = task.model, {**task.rhc, "constraint": constraint}
    xi, N = s["xi"], model.N
    order = np.argsort(belief, kind="stable")
    mass, dropped = 0.0, []
    for i in order:
        if mass + belief[i] > give_up * (1.0 - xi):
            break
        mass += belief[i]
        dropped.append(int(i))
    kept = [i for i in range(N) if i not in dropped]
    eps = (1.0 - xi - mass) / (1.0 - mass)
    Sigma = model.E @ model.W @ model.E.transpose(0, 2, 1)
    std = np.sqrt(np.einsum("jn,inm,jm->ij", model.G, Sigma, model.G))
    if constraint == "individual":
        t = stats.norm.ppf(1.0 - eps) * std
    elif constraint == "bonferroni":
        t = stats.norm.ppf(1.0 - eps / model.r) * std
    else:
        W_half = np.linalg.cholesky(model.W)
        rows = np.einsum("jn,inp,pq->ijq", model.G, model.E, W_half)
        t = np.sqrt(stats.chi2.ppf(1.0 - eps, model.p)) * np.linalg.norm(rows, axis=-1)
    inside = np.all(model.G @ x <= model.H(k))
    P = model.P_in if inside else model.P_out
    Pi = np.einsum("ij,jab->iab", P, np.asarray(s["Psi"]))
    K = np.einsum("i,iab->ab", belief, task.K)
    nu, rho = cp.Variable(model.m), cp.Variable(nonneg=True)
    u = K @ x + nu
    objective = s["alpha"] * rho
    rows_ = [cp.abs(nu) <= s["nu_bound"]]
    for i in range(N):
        mean = model.A[i] @ x + model.B[i] @ u
        Pi_i = 0.5 * (Pi[i] + Pi[i].T)
        objective = objective + belief[i] * (
            x @ model.Q[i] @ x + cp.quad_form(u, model.R[i]) + cp.quad_form(mean, Pi_i)
            + np.trace(Pi_i @ Sigma[i])
        )  # fmt: skip
        if i in kept:
            rows_.append(model.G @ mean <= model.H(k + 1) - t[i] + rho)
    problem = cp.Problem(cp.Minimize(objective), rows_)
    problem.solve(solver=cp.CLARABEL, tol_gap_abs=1e-11, tol_gap_rel=1e-11, tol_feas=1e-11)
    assert problem.status == cp.OPTIMAL
    risk = np.ones(N)
    risk[kept] = eps
    return np.asarray(u.value), float(rho.value), float(problem.value), risk


@pytest.mark.parametrize("constraint", KINDS)
@pytest.mark.parametrize("env_id", list(TASKS))
def test_answers_are_the_optimum_of_the_papers_problem_on_the_belief(env_id, constraint):
    task = TASKS[env_id]
    ctrl, _ = _controllers(task, constraint)
    rng = np.random.default_rng([5, list(TASKS).index(env_id)])
    xs, ks = _states(task, rng, 8)
    for x, k in zip(xs, ks.tolist(), strict=True):
        belief = _random_belief(rng, task.model.N)
        u, info = ctrl.act(x, belief, k)
        u_ref, rho_ref, cost_ref, risk_ref = _reference(
            task, constraint, ctrl.give_up, x, belief, k
        )
        assert info["ok"]
        np.testing.assert_allclose(info["risk"], risk_ref, rtol=1e-12)
        assert info["cost"] == pytest.approx(cost_ref, rel=1e-6)
        scale = np.abs(u_ref).sum() + np.abs(info["gain"] @ x).sum() + 1.0
        np.testing.assert_allclose(u, u_ref, rtol=0, atol=1e-5 * scale)
        assert info["rho"] == pytest.approx(rho_ref, abs=1e-6 * (1.0 + rho_ref))


# ------------------------------------------------------------------ the allocation and gain
def test_the_smallest_modes_are_given_up_within_their_share_of_the_budget():
    task = TASKS["SDJLS-VTOL-v0"]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc, give_up=0.75)
    x = task.model.x0
    # 1 - xi = 0.1: modes of total belief up to 0.075 are given up, the smallest first
    _, info = ctrl.act(x, [0.93, 0.05, 0.02], 0)
    eps = (0.1 - 0.07) / 0.93
    np.testing.assert_allclose(info["risk"], [eps, 1.0, 1.0])
    _, info = ctrl.act(x, [0.9, 0.07, 0.03], 0)  # 0.03 fits, 0.03 + 0.07 does not
    np.testing.assert_allclose(info["risk"], [(0.1 - 0.03) / 0.97] * 2 + [1.0])
    _, info = ctrl.act(x, [0.5, 0.3, 0.2], 0)  # nothing fits: every mode at level xi
    np.testing.assert_allclose(info["risk"], [0.1, 0.1, 0.1])


def test_gain_rules():
    task = TASKS["SDJLS-VTOL-v0"]
    belief = np.array([0.5, 0.2, 0.3])
    for gain, K in (
        ("weighted", np.einsum("i,iab->ab", belief, task.K)),
        ("most_probable", task.K[0]),
    ):
        ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc, gain=gain)
        u, info = ctrl.act(task.model.x0, belief, 0)
        np.testing.assert_allclose(info["gain"], K, rtol=1e-14)
        np.testing.assert_allclose(u, K @ task.model.x0 + info["nu"], rtol=1e-14)
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc, gain="most_probable")
    assert np.array_equal(ctrl.act(task.model.x0, [0.4, 0.4, 0.2], 0)[1]["gain"], task.K[0])


# ------------------------------------------------------------------ settings and inputs
def test_the_constructor_shows_the_settings_of_the_receding_horizon_controller():
    mine = inspect.signature(BeliefRecedingHorizonController).parameters
    theirs = inspect.signature(RecedingHorizonController).parameters
    for name, p in theirs.items():
        assert mine[name].kind == p.kind and mine[name].default == p.default, name
    assert mine["gain"].default == "weighted" and mine["give_up"].default == 0.75


@pytest.mark.parametrize(
    "kw, error, name, value",
    [
        ({"gain": "mean"}, ValueError, "gain", "mean"),
        ({"gain": 1}, TypeError, "gain", 1),
        ({"give_up": 0.0}, ValueError, "give_up", 0.0),
        ({"give_up": 1.0}, ValueError, "give_up", 1.0),
        ({"give_up": "0.5"}, TypeError, "give_up", "0.5"),
        ({"give_up": True}, TypeError, "give_up", True),
        ({"xi": 1.5}, ValueError, "xi", 1.5),
        ({"solver": "qp"}, ValueError, "solver", "qp"),
        ({"nu_bound": -1.0}, ValueError, "nu_bound", -1.0),
    ],
)
def test_bad_settings_are_refused_by_name(kw, error, name, value):
    task = TASKS["SDJLS-Degradation-v0"]
    with raises_naming(error, name, value):
        BeliefRecedingHorizonController(task.model, task.K, **{**task.rhc, **kw})


@pytest.mark.parametrize(
    "belief, error, value",
    [
        ([0.5, 0.6], ValueError, [0.5, 0.6]),
        ([1.2, -0.2], ValueError, -0.2),
        ([np.nan, 1.0], ValueError, "nan"),
        ([1.0, 0.0, 0.0], ValueError, "(3,)"),
        ("ab", TypeError, "ab"),
    ],
)
def test_a_belief_must_be_a_probability_vector(belief, error, value):
    task = TASKS["SDJLS-Degradation-v0"]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    with raises_naming(error, "belief", value):
        ctrl.act(task.model.x0, belief, 0)
    with raises_naming(error, "belief", UNSHOWN):
        ctrl.act_batch(task.model.x0[None], np.atleast_2d(np.asarray(belief, dtype=object)), 0)


def test_a_belief_within_1e_9_of_summing_to_one_is_normalized():
    task = TASKS["SDJLS-Degradation-v0"]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    a = ctrl.act(task.model.x0, [0.7 * (1 + 5e-10), 0.3 * (1 + 5e-10)], 0)[1]
    b = ctrl.act(task.model.x0, [0.7, 0.3], 0)[1]
    assert a["cost"] == pytest.approx(b["cost"], rel=1e-9)
    with raises_naming(ValueError, "belief", "1.000000003"):
        ctrl.act(task.model.x0, [0.7, 0.300000003], 0)


@pytest.mark.parametrize(
    "x, k, error, name, value",
    [
        ([1.0, np.inf], 0, ValueError, "x", "inf"),
        ([1.0], 0, ValueError, "x", "(1,)"),
        ([1.0, 2.0], -1, ValueError, "k", -1),
        ([1.0, 2.0], 1.5, TypeError, "k", 1.5),
    ],
)
def test_bad_states_and_times_are_refused_by_name(x, k, error, name, value):
    task = TASKS["SDJLS-Degradation-v0"]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    with raises_naming(error, name, value):
        ctrl.act(x, [0.5, 0.5], k)


# ------------------------------------------------------------------ paths, batches, threads
@pytest.mark.parametrize("env_id", ["SDJLS-Macro-v0", "SDJLS-VTOL-v0"])
def test_every_solver_gives_the_same_verified_answer(env_id):
    task = TASKS[env_id]
    ctrls = {
        solver: BeliefRecedingHorizonController(task.model, task.K, **task.rhc, solver=solver)
        for solver in ("daqp", "osqp", "active_set", "cvxpy")
    }
    rng = np.random.default_rng(2)
    xs, ks = _states(task, rng, 10)
    for x, k in zip(xs, ks.tolist(), strict=True):
        belief = _random_belief(rng, task.model.N)
        answers = {s: c.act(x, belief, k) for s, c in ctrls.items()}
        u0, i0 = answers["daqp"]
        for solver, (u, info) in answers.items():
            assert info["ok"], (solver, info["notes"])
            scale = np.abs(u0).sum() + np.abs(i0["gain"] @ x).sum() + 1.0
            np.testing.assert_allclose(u, u0, rtol=0, atol=1e-9 * scale)
            assert info["cost"] == pytest.approx(i0["cost"], rel=1e-9)
    assert ctrls["cvxpy"].path_counts == {"cvxpy": 10}


def test_a_failed_fast_path_is_rescued_by_cvxpy_then_by_nu_zero(monkeypatch):
    task = TASKS["SDJLS-Random-v0"]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    ref = ctrl.act(task.model.x0, [0.6, 0.4], 3)[1]
    monkeypatch.setattr(BeliefQP, "solve", lambda self, *a, **kw: None)
    u, info = ctrl.act(task.model.x0, [0.6, 0.4], 3)
    assert info["solver"] == "cvxpy" and info["ok"]
    assert info["cost"] == pytest.approx(ref["cost"], rel=1e-9)
    off = BeliefRecedingHorizonController(task.model, task.K, **task.rhc, cvxpy_fallback=False)
    u, info = off.act(task.model.x0, [0.6, 0.4], 3)
    assert info["status"] == "fallback_nu0" and not info["ok"] and np.all(info["nu"] == 0.0)
    assert "cvxpy retry disabled" in info["notes"]


def test_the_ball_is_solved_as_a_cone():
    task = TASKS["SDJLS-VTOL-v0"]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc, nu_set="ball")
    x = task.model.x0 * 10
    u, info = ctrl.act(x, [0.6, 0.3, 0.1], 0)
    assert info["solver"] == "cvxpy_socp" and info["ok"]
    assert np.linalg.norm(info["nu"]) <= task.rhc["nu_bound"] * (1 + 1e-12)


def test_act_batch_is_act_row_by_row():
    task = TASKS["SDJLS-Macro-v0"]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    rng = np.random.default_rng(4)
    xs, ks = _states(task, rng, 12)
    beliefs = np.array([_random_belief(rng, 3) for _ in range(12)])
    u, info = ctrl.act_batch(xs, beliefs, ks)
    for i in range(12):
        u_i, info_i = ctrl.act(xs[i], beliefs[i], int(ks[i]))
        np.testing.assert_allclose(u[i], u_i, rtol=1e-12, atol=1e-12)
        for key in ("rho", "cost"):
            assert info[key][i] == pytest.approx(info_i[key], rel=1e-12, abs=1e-12)
        np.testing.assert_array_equal(info["risk"][i], info_i["risk"])
        assert info["status"][i] == info_i["status"] and info["ok"][i]
    assert info["risk"].shape == (12, 3) and info["gain"].shape == (12, 1, 2)


def test_threads_get_the_answers_of_one_thread():
    task = TASKS["SDJLS-VTOL-v0"]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    rng = np.random.default_rng(9)
    xs, ks = _states(task, rng, 40)
    beliefs = [_random_belief(rng, 3) for _ in range(40)]
    alone = [ctrl.act(x, b, int(k))[0] for x, b, k in zip(xs, beliefs, ks, strict=True)]
    shared = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    out: list = [None] * 40

    def work(start):
        for i in range(start, 40, 4):
            out[i] = shared.act(xs[i], beliefs[i], int(ks[i]))[0]

    threads = [threading.Thread(target=work, args=(s,)) for s in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for a, b in zip(alone, out, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_pickled_controllers_answer_the_same():
    task = TASKS["SDJLS-Random-v0"]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    u, _ = ctrl.act(task.model.x0, [0.3, 0.7], 2)
    copy = pickle.loads(pickle.dumps(ctrl))
    np.testing.assert_allclose(copy.act(task.model.x0, [0.3, 0.7], 2)[0], u, rtol=1e-12)


def test_from_model_builds_a_belief_controller():
    task = TASKS["SDJLS-Degradation-v0"]
    ctrl = BeliefRecedingHorizonController.from_model(task.model, xi=0.9, give_up=0.5)
    assert isinstance(ctrl, BeliefRecedingHorizonController) and ctrl.give_up == 0.5
    assert ctrl.act(task.model.x0, [0.5, 0.5], 0)[1]["ok"]


def test_predict_reads_the_mode_when_it_is_shown_and_refuses_a_hidden_one():
    task = TASKS["SDJLS-Macro-v0"]
    model = task.model
    ctrl = BeliefRecedingHorizonController(model, task.K, **task.rhc, horizon=task.horizon)
    rhc = RecedingHorizonController(model, task.K, **task.rhc, horizon=task.horizon)
    x = np.array([[2.0, 3.0], [1.0, 4.5]])
    obs = encode_observation(model, x, np.array([1, 2]), np.array([0, 5]), task.horizon, 1e6)
    np.testing.assert_allclose(ctrl.predict(obs)[0], rhc.predict(obs)[0], rtol=1e-6)
    hidden = encode_observation(
        model, x, np.array([1, 2]), np.array([0, 5]), task.horizon, 1e6, "state"
    )
    with pytest.raises(ModeNotObservedError, match="HiddenModePolicy"):
        ctrl.predict(hidden)


@pytest.mark.parametrize("env_id", ["SDJLS-Macro-v0", "SDJLS-VTOL-v0"])
def test_without_daqp_the_warm_sets_and_the_enumeration_give_the_same_answers(env_id, monkeypatch):
    """The paths after DAQP (the warm sets with their screen and repair steps for m = 2, the
    enumeration of every candidate active set) answer as the default path does."""
    task = TASKS[env_id]
    rng = np.random.default_rng(8)
    xs, ks = _states(task, rng, 12)
    beliefs = [_random_belief(rng, task.model.N) for _ in range(12)]
    default = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    expected = [default.act(x, b, int(k)) for x, b, k in zip(xs, beliefs, ks, strict=True)]
    monkeypatch.setattr(BeliefQP, "_daqp_solve", lambda self, *a: None)
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    for x, b, k, (u0, i0) in zip(xs, beliefs, ks, expected, strict=True):
        u, info = ctrl.act(x, b, int(k))
        assert info["ok"] and info["solver"] != "daqp"
        scale = np.abs(u0).sum() + np.abs(i0["gain"] @ x).sum() + 1.0
        np.testing.assert_allclose(u, u0, rtol=0, atol=1e-9 * scale)
        assert info["cost"] == pytest.approx(i0["cost"], rel=1e-9)
    assert "active_set" in ctrl.path_counts  # the enumeration answered some
