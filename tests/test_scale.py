"""Exact answers of the receding-horizon controller at every scale (issue: silent wrong answers).

Every answer is compared with :mod:`exact_p3`, an exact rational-arithmetic solution of the same
P3 (every active set tried, no solver): ``J*`` must match to 1e-8 relative, ``rho`` must match
relative to the scale of its row, and ``rho = 0`` must mean that every row holds (to 1e-9 of the
magnitude of its terms), over penalties ``alpha``, offset bounds ``nu_bound`` and region scales
from 1e-6 to 1e12, with loose rows, on the paper's example and on random systems.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_sdjls
from exact_p3 import exact_p3
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import stats

from controllers import RecedingHorizonController
from controllers.chance import row_satisfaction_probability
from sdjls_gym import SDJLSModel
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro

J_REL = 1e-8  # relative accuracy of J* promised over the whole range
ROW_REL = 1e-9  # the KKT tolerance of controllers.qp, relative to a row's terms


def scaled(model: SDJLSModel, scale: float, loose: tuple[int, float] | None = None) -> SDJLSModel:
    """The same region ``G x <= H_k`` written with rows scaled by ``scale``; ``loose = (j, b)``
    moves row j's bound out by ``b`` (a row that never binds)."""
    d = model.to_dict()
    G, H0, rate = np.array(d["G"]), np.array(d["H0"]), np.array(d["H_rate"])
    if loose is not None:
        H0[loose[0]] += loose[1]
    return SDJLSModel(**{**d, "G": G * scale, "H0": H0 * scale, "H_rate": rate * scale})


def row_terms(ctrl, x, mode, k, nu):
    """Magnitude of the terms of each constraint row ``G(Atilde x + B nu) - (H_{k+1} - t)``."""
    model = ctrl.model
    At, B = ctrl.A_tilde[mode], model.B[mode]
    hbar = model.H(k + 1) - ctrl.tightening[mode]
    return np.abs(model.G @ At) @ np.abs(x) + np.abs(model.G @ B) @ np.abs(nu) + np.abs(hbar)


def check_answer(ctrl, x, mode, k, info):
    """The answer against the exact optimum, and the rho = 0 promise."""
    ref = exact_p3(ctrl, x, mode, k)
    # verified optimal; "solved (...)" lists solver trouble on the way (OSQP may fail where the
    # slack has little weight: the enumeration then answers)
    assert info["status"].startswith("solved") and info["ok"], info["status"]
    assert info["cost"] == pytest.approx(ref.J, rel=J_REL), (info, ref)
    model = ctrl.model
    mean = ctrl.A_tilde[mode] @ x + model.B[mode] @ info["nu"]
    excess = model.G @ mean - (model.H(k + 1) - ctrl.tightening[mode])
    terms = row_terms(ctrl, x, mode, k, info["nu"])
    assert abs(info["rho"] - ref.rho) <= 1e-8 * max(terms.max(), abs(ref.rho)), (info, ref)
    if info["rho"] == 0.0:
        assert np.all(excess <= ROW_REL * terms), (excess, terms)
    else:
        assert np.max(excess - info["rho"]) <= ROW_REL * terms.max()
    return ref


def random_system(rng: np.random.Generator, m: int) -> tuple[SDJLSModel, np.ndarray, np.ndarray]:
    """A random system of two modes and two states (``conftest.random_sdjls``), gains, ``Psi``."""
    N, n = 2, 2
    model = random_sdjls(rng, N, n, m, 3, int(rng.integers(1, 4)))
    S = rng.normal(size=(N, n, n))
    return model, rng.normal(size=(N, m, n)), S @ S.transpose(0, 2, 1) + 0.5 * np.eye(n)


@settings(
    max_examples=60,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(
    seed=st.integers(0, 2**31 - 1),
    log_alpha=st.floats(-6.0, 12.0),
    log_nu_bound=st.floats(-6.0, 12.0),
    log_scale=st.floats(-6.0, 12.0),
    log_loose=st.one_of(st.none(), st.floats(0.0, 12.0)),
    system=st.sampled_from(["paper", "m=1", "m=2"]),
    constraint=st.sampled_from(["individual", "joint", "bonferroni"]),
)
def test_answers_are_exact_optima_at_every_scale(
    seed, log_alpha, log_nu_bound, log_scale, log_loose, system, constraint
):
    """60 derandomized examples x 4 states x 3 solvers (OSQP path, enumeration, act_batch):
    J* to 1e-8 relative of the exact optimum, rho to its row's scale, and rho = 0 only when every
    row holds; the same answers again in reverse order (no dependence on the call history)."""
    rng = np.random.default_rng(seed)
    if system == "paper":
        model, K, Psi = macro(), PAPER_K, PAPER_RHC["Psi"]
    else:
        model, K, Psi = random_system(rng, 1 if system == "m=1" else 2)
    loose = None if log_loose is None else (int(rng.integers(model.r)), 10.0**log_loose)
    model = scaled(model, 10.0**log_scale, loose)
    kw = dict(xi=0.85, constraint=constraint, alpha=10.0**log_alpha, nu_bound=10.0**log_nu_bound)
    fast = RecedingHorizonController(model, K, Psi=Psi, **kw)
    enum = RecedingHorizonController(model, K, Psi=Psi, **kw, solver="active_set")
    states = [
        (rng.normal(size=model.n) * 10.0 ** rng.uniform(-2, 2), int(rng.integers(model.N)),
         int(rng.integers(0, 30)))
        for _ in range(4)
    ]  # fmt: skip
    answers = []
    for x, mode, k in states:
        _, info = fast.act(x, mode, k)
        check_answer(fast, x, mode, k, info)
        _, info_e = enum.act(x, mode, k)
        check_answer(enum, x, mode, k, info_e)
        answers.append(info)
    _, batch = fast.act_batch(
        np.array([s[0] for s in states]), np.array([s[1] for s in states]),
        np.array([s[2] for s in states]),
    )  # fmt: skip
    for i, (x, mode, k) in enumerate(states):
        info = {key: batch[key][i] for key in ("nu", "rho", "cost", "status", "ok")}
        check_answer(fast, x, mode, k, info)
    for (x, mode, k), first in zip(reversed(states), reversed(answers), strict=True):
        _, again = fast.act(x, mode, k)
        np.testing.assert_allclose(again["nu"], first["nu"], rtol=1e-12, atol=0)
        assert again["rho"] == pytest.approx(first["rho"], rel=1e-12, abs=0)
        assert again["cost"] == pytest.approx(first["cost"], rel=1e-12)


# ------------------------------------------------------------------ the cases
def loose_row_controller(scale: float = 1.0, solver: str = "osqp") -> RecedingHorizonController:
    """The paper's example with the upper band row moved out to 1e9 and U = [-3.5, 3.5]: at k = 0
    the lower row needs nu >= 2.5 + Phi^{-1}(0.85) = 3.536 (the paper's gains make the next
    income's mean equal to nu), so the optimum uses the slack, rho = 0.036."""
    model = scaled(macro(), scale, loose=(1, 1e9))
    kw = {**PAPER_RHC, "nu_bound": 3.5}
    return RecedingHorizonController(model, PAPER_K, **kw, solver=solver)


@pytest.mark.parametrize("solver", ["osqp", "active_set"])
def test_a_loose_row_does_not_hide_the_slack_of_another(solver):
    """The zero test of rho was relative to the largest right-hand side (1e9 here), so a slack of
    0.036 on the other row was reported as rho = 0 with a J* 36 below the optimum, while that row
    held with probability 0.841 < xi = 0.85."""
    ctrl = loose_row_controller(solver=solver)
    x = np.array([2.0, 2.0])
    _, info = ctrl.act(x, 0, 0)
    expected_rho = 2.5 + stats.norm.ppf(0.85) - 3.5
    assert info["nu"][0] == 3.5
    assert info["rho"] == pytest.approx(expected_rho, rel=1e-12)
    ref = check_answer(ctrl, x, 0, 0, info)
    assert ref.rho == pytest.approx(expected_rho, rel=1e-12)
    mean = ctrl.A_tilde[0] @ x + ctrl.model.B[0] @ info["nu"]
    prob = row_satisfaction_probability(ctrl.model, mean, 0, 1)
    assert prob[0] == pytest.approx(stats.norm.cdf(1.0), abs=1e-12) and prob[0] < 0.85


def loose_row_controller_with(scale: float, alpha: float) -> RecedingHorizonController:
    model = scaled(macro(), scale, loose=(1, 1e9))
    kw = {**PAPER_RHC, "nu_bound": 6.0, "alpha": alpha}
    return RecedingHorizonController(model, PAPER_K, **kw)


@pytest.mark.parametrize(
    "scale, alpha", [(1e-11, 1.0), (1e-6, 1000.0), (1e6, 1000.0), (1e11, 1.0), (1e11, 1000.0)]
)
def test_a_scaled_region_gives_the_same_decision(scale, alpha):
    """The same problem written with its rows scaled by ``scale`` (and alpha by 1 / scale, so
    that alpha * rho is unchanged): the same nu and J*, rho in the rows' units. A slack of 0.036
    scaled by 1e-11 is still a slack, and a row that holds still holds: the zero test of rho and
    the KKT tests are relative to each row, not absolute."""
    base = loose_row_controller_with(1.0, alpha)
    other = loose_row_controller_with(scale, alpha / scale)
    rng = np.random.default_rng(3)
    slack_used = 0
    for _ in range(30):
        x, mode, k = rng.normal(size=2) * 3, int(rng.integers(3)), int(rng.integers(10))
        _, a = base.act(x, mode, k)
        _, b = other.act(x, mode, k)
        np.testing.assert_allclose(b["nu"], a["nu"], rtol=1e-9, atol=1e-12)
        assert (a["rho"] == 0.0) == (b["rho"] == 0.0)
        assert b["rho"] == pytest.approx(a["rho"] * scale, rel=1e-6)
        assert b["cost"] == pytest.approx(a["cost"], rel=1e-9)
        check_answer(other, x, mode, k, b)
        slack_used += a["rho"] > 0.0
    assert slack_used > 0
    if alpha >= 1000.0:  # a dear slack: both regimes are seen
        assert slack_used < 30


@pytest.mark.parametrize("alpha, nu_bound", [(1e9, 100.0), (1e12, 100.0), (1e3, 1e9), (1e12, 1e12)])
def test_huge_penalty_or_bound_keeps_the_exact_optimum(alpha, nu_bound):
    """alpha or nu_bound of 1e9 and more widened the KKT tolerance of every row (it scaled with
    the largest number of the QP): suboptimal nu, J up to 13% above the optimum, "solved"."""
    kw = {**PAPER_RHC, "alpha": alpha, "nu_bound": nu_bound}
    for solver in ("osqp", "active_set"):
        ctrl = RecedingHorizonController(macro(), PAPER_K, **kw, solver=solver)
        rng = np.random.default_rng(0)
        for _ in range(40):
            x = rng.normal(3.0, 2.0, 2)
            mode, k = int(rng.integers(3)), int(rng.integers(20))
            check_answer(ctrl, x, mode, k, ctrl.act(x, mode, k)[1])


@pytest.mark.parametrize("psi_scale", [1e10, 1e30])
def test_osqp_failure_on_extreme_weights_is_solved_by_the_enumeration(psi_scale):
    """alpha = 1e12 with large terminal weights: on the first call of a family OSQP reaches its
    iteration limit (in about 1 of 10 states at Psi = 1e10 Psi_paper); the chain used to go to
    cvxpy, then nu = 0, without trying the exact enumeration it has."""
    kw = {**PAPER_RHC, "alpha": 1e12, "Psi": psi_scale * np.array(PAPER_RHC["Psi"])}
    rng = np.random.default_rng(1)
    paths = set()
    for _ in range(40):
        ctrl = RecedingHorizonController(macro(), PAPER_K, **kw)  # a fresh family each time
        x = rng.normal(0.0, 10.0 ** rng.uniform(-2, 2), 2)
        mode, k = int(rng.integers(3)), int(rng.integers(20))
        _, info = ctrl.act(x, mode, k)
        check_answer(ctrl, x, mode, k, info)
        paths.add(info["solver"])
    assert not paths & {"fallback", "cvxpy"}, paths


@pytest.mark.parametrize(
    "field, factor",
    [("Psi", 1e90), ("R", 1e16), ("R", 1e-90), ("Q", 1e90), ("G", 1e90), ("G", 1e-90)],
)
def test_huge_and_tiny_but_valid_weights_are_solved_exactly(field, factor):
    """Weights far from 1 (below the documented limit of 1e100 on the QP's entries) are solved
    exactly; they used to crash act() with an unnamed LinAlgError from the active-set set-up."""
    model, Psi = macro(), np.array(PAPER_RHC["Psi"])
    if field == "Psi":
        Psi = Psi * factor
    elif field == "G":
        model = scaled(model, factor)
    else:
        d = model.to_dict()
        model = SDJLSModel(**{**d, field: np.array(d[field]) * factor})
    ctrl = RecedingHorizonController(model, PAPER_K, **{**PAPER_RHC, "Psi": Psi})
    rng = np.random.default_rng(2)
    for _ in range(10):
        x, mode, k = rng.normal(3.0, 2.0, 2), int(rng.integers(3)), int(rng.integers(20))
        check_answer(ctrl, x, mode, k, ctrl.act(x, mode, k)[1])


@pytest.mark.parametrize("factor", [1e30, 1e90])
def test_a_dominant_input_weight_is_refused_by_name(factor):
    """With R 1e30 times the other weights the optimal u cancels K x to 15 digits and no float64
    answer has an accurate cost (R = 1e90 gave J = 3.8e60 for J* = 17358): refused up front."""
    d = macro().to_dict()
    model = SDJLSModel(**{**d, "R": np.array(d["R"]) * factor})
    with pytest.raises(ValueError, match=r"model\.R up to .* the ratio must be at most 1e\+22"):
        RecedingHorizonController(model, PAPER_K, **PAPER_RHC)


def test_pi_in_info_is_read_only():
    """info["Pi"] was the controller's own array: writing to it changed later answers."""
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC, solver="cvxpy")
    x = np.array([2.0, 2.0])
    _, first = ctrl.act(x, 0, 0)
    with pytest.raises(ValueError, match="read-only"):
        first["Pi"][0, 0] = 1e6
    _, again = ctrl.act(x, 0, 0)
    assert again["cost"] == first["cost"]


def test_a_slack_penalty_of_1e9_does_not_spoil_the_offsets():
    """Regression (a hypothesis example): alpha = 1e9, the region in units of 1e7, m = 2. The
    optimal active set is one band row and rho >= 0 (multipliers 1.1e-7 and 1e9). The exact
    solve used to mix the penalty into the offsets through a round-off in its null-space basis:
    nu off by 1.6e-4 and J* by 1.1e-8 relative (every path: they share the solve). The slack's
    bound is now eliminated exactly: J* to 1e-15."""
    rng = np.random.default_rng(649329948)
    model, K, Psi = random_system(rng, 2)
    model = scaled(model, 1e7)
    kw = dict(xi=0.85, constraint="individual", alpha=1e9, nu_bound=1.0)
    x, mode, k = rng.normal(size=model.n) * 10.0 ** rng.uniform(-2, 2), 1, 25
    for solver in ("daqp", "osqp", "active_set"):
        ctrl = RecedingHorizonController(model, K, Psi=Psi, **kw, solver=solver)
        _, info = ctrl.act(x, mode, k)
        ref = check_answer(ctrl, x, mode, k, info)
        assert info["cost"] == pytest.approx(ref.J, rel=1e-14), solver
        np.testing.assert_allclose(info["nu"], ref.nu, rtol=1e-12, atol=0)
