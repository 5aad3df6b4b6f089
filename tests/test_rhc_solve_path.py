"""Tests of controllers.rhc's solve path: the fallbacks when a solver fails (the enumeration,
OSQP, cvxpy, ``nu = 0``) and the active-set warm start against the enumeration and cvxpy."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from conftest import assert_feasible, paper_cost, random_problem
from scipy import stats

from controllers import Status
from controllers.rhc import RecedingHorizonController, UnconstrainedRecedingHorizonController
from sdjls_gym import SDJLSVectorEnv
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro


# ---------------------------------------------------------------------- robustness
def _no_enumeration(monkeypatch):
    """Make the enumeration find nothing, so that the fallbacks after it are reached."""
    from controllers.active_set import ActiveSetQP

    monkeypatch.setattr(ActiveSetQP, "solve_one", lambda self, w: None)


def failing_osqp(model):
    """P3 by OSQP alone, stopped after one iteration, without the cvxpy rescue."""
    return RecedingHorizonController(
        model,
        PAPER_K,
        **PAPER_RHC,
        solver="osqp",
        osqp_settings={"max_iter": 1},
        cvxpy_fallback=False,
    )


def test_forced_osqp_failure_is_solved_exactly_by_the_enumeration():
    """OSQP failing (iteration limit) does not reach cvxpy or nu = 0 while the enumeration of
    the family's active sets settles the state: the answer is the exact optimum."""
    model = macro()
    normal = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    failing = failing_osqp(model)
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
    ctrl = failing_osqp(model)
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
