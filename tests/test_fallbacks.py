"""Running through trouble: solver failures, ill-posed SDPs and diverging states.

* The receding-horizon QP: OSQP failures are forced (iteration limit; simulated numerical
  trouble: an exception, a NaN solution, an inaccurate or infeasible status) in ``act`` and in
  ``act_batch``, on the OSQP path and on the default path (where DAQP is made to fail first);
  the controller retries, falls back to cvxpy, then to ``nu = 0``, says so in
  ``info["status"]`` and ``info["notes"]``, and the episode goes on.
* The LMIs: infeasible or ill-conditioned Proposition-2 problems, and forced solver statuses,
  give an ``LMIError`` that names the solver and its status; gains are only ever returned verified.
* Diverging states under poor policies (an RL agent early in training): the env and the vector
  env terminate with ``info["diverged"]``, rewards stay finite and nothing overflows. Overflow,
  invalid and divide warnings are errors in this module (and numpy is told to warn on them).
"""

from __future__ import annotations

import math

import cvxpy as cp
import gymnasium as gym
import numpy as np
import osqp
import pytest
from scipy import stats

from controllers import (
    LMIError,
    LMIInfeasibleError,
    LMISolverError,
    RecedingHorizonController,
    synthesize_gains,
    verify_mean_square_bound,
)
from controllers.active_set import ActiveSetQP
from controllers.qp import QPFamily
from sdjls_gym import SDJLSModel, SDJLSVectorEnv
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro
from sdjls_gym.wrappers import ResidualAction, ViolationPenalty

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

HEALTHY_STATES = [
    ([2.0, 2.0], 0, 0),
    ([1.0, 4.0], 2, 3),
    ([-3.0, 8.0], 1, 11),
    ([30.0, -5.0], 0, 7),
]


@pytest.fixture(autouse=True)
def _numpy_warns_on_overflow():
    with np.errstate(over="warn", invalid="warn", divide="warn"):
        yield


def controller(**overrides) -> RecedingHorizonController:
    kw = {"model": macro(), "K": PAPER_K, **PAPER_RHC}
    kw.update(overrides)
    return RecedingHorizonController(**kw)


def nu_zero_answer(x, mode, k, xi=PAPER_RHC["xi"]):
    """rho and J of P3 at nu = 0 for the macro example, from the paper's formulas.

    E = W = I, |G_j| = 1: the tightening of every row is Phi^{-1}(xi), eq.
    (constraint:det_univariate); rho is the smallest slack that makes nu = 0 feasible, eq.
    (constraint:feasibility); J is the objective of P3 with tr(Pi) for the noise, eq.
    (eq:exp_noise).
    """
    model, Psi, alpha = macro(), PAPER_RHC["Psi"], PAPER_RHC["alpha"]
    x = np.asarray(x, dtype=np.float64)
    u = PAPER_K[mode] @ x
    mean = (model.A[mode] + model.B[mode] @ PAPER_K[mode]) @ x
    hbar = np.array([-2.0 - 0.5 * (k + 1), 5.0 + 0.5 * (k + 1)]) - stats.norm.ppf(xi)
    rho = max(0.0, float(np.max(model.G @ mean - hbar)))
    inside = bool(np.all(model.G @ x <= np.array([-2.0 - 0.5 * k, 5.0 + 0.5 * k])))
    pi = (model.P_in if inside else model.P_out)[mode]
    Pi = np.einsum("j,jab->ab", pi, Psi)
    J = x @ model.Q[mode] @ x + u @ model.R[mode] @ u + mean @ Pi @ mean + np.trace(Pi)
    return rho, float(J + alpha * rho)


# ----------------------------------------------------------------------------- forcing failures
REAL_OSQP_SOLVE = osqp.OSQP.solve
REAL_CVXPY_SOLVE = cp.Problem.solve


def failing_osqp(kind: str, failures: float = math.inf):
    """A replacement for ``osqp.OSQP.solve`` that fails ``failures`` times, then works."""
    calls = {"n": 0}

    def solve(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] > failures:
            return REAL_OSQP_SOLVE(self, *args, **kwargs)
        if kind == "exception":
            raise RuntimeError("simulated numerical trouble")
        res = REAL_OSQP_SOLVE(self, *args, **kwargs)
        if kind == "nan":  # OSQP says solved, but the iterate is not finite
            res.x = np.full_like(res.x, np.nan)
        elif kind == "inaccurate":
            res.info.status, res.info.status_val = (
                "solved inaccurate",
                osqp.SolverStatus.OSQP_SOLVED_INACCURATE,
            )
        elif kind == "infeasible":
            res.info.status, res.info.status_val = (
                "primal infeasible",
                osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE,
            )
        return res

    return solve


def failing_cvxpy(*args, **kwargs):
    raise cp.error.SolverError("simulated Clarabel failure")


OSQP_NOTE = {  # what info["status"] reports for each forced OSQP failure
    "max_iter": "osqp status 'maximum iterations reached'",
    "exception": "osqp status 'error RuntimeError: simulated numerical trouble'",
    "nan": "osqp status 'solved'",  # solved, but rejected: the iterate is not finite
    "inaccurate": "osqp status 'solved inaccurate'",
    "infeasible": "osqp status 'primal infeasible'",
}


def no_enumeration(monkeypatch):
    """Make the enumeration of active sets find nothing, so that the fallbacks after OSQP and
    the enumeration (cvxpy, then nu = 0) are reached on the example's small QP."""
    monkeypatch.setattr(ActiveSetQP, "solve_one", lambda self, w: None)


#: The fast paths: DAQP finds the active sets (then OSQP), or OSQP alone.
FAST_PATHS = ["daqp", "osqp"]

#: What the notes say first when DAQP is made to fail (:func:`fail_daqp`).
DAQP_NOTE = "daqp exit flag -4"


def fail_daqp(monkeypatch) -> None:
    """Make every DAQP run fail (exit flag -4, DAQP's 'iteration limit')."""
    monkeypatch.setattr(QPFamily, "run_daqp", lambda *args, **kwargs: (None, None, "exit flag -4"))


def force(monkeypatch, kind: str, solver: str = "osqp", failures: float = math.inf) -> dict:
    """Make OSQP fail the ``kind`` way (and DAQP fail first on the ``"daqp"`` path); returns the
    controller settings that go with it."""
    if solver == "daqp":
        fail_daqp(monkeypatch)
    if kind == "max_iter":  # a real failure: OSQP stops after one iteration (10 on the retry)
        return {"solver": solver, "osqp_settings": {"max_iter": 1}}
    monkeypatch.setattr(osqp.OSQP, "solve", failing_osqp(kind, failures))
    return {"solver": solver}


def first_notes(kind: str, solver: str) -> str:
    """The start of ``info["notes"]`` when OSQP fails the ``kind`` way on path ``solver``."""
    return (DAQP_NOTE + "; " if solver == "daqp" else "") + OSQP_NOTE[kind]


@pytest.mark.parametrize("solver", FAST_PATHS)
@pytest.mark.parametrize("kind", list(OSQP_NOTE))
def test_osqp_failure_in_act_is_solved_exactly_by_the_enumeration(monkeypatch, kind, solver):
    """OSQP (and DAQP) failing in any way does not reach cvxpy or nu = 0 on a family small
    enough to enumerate: the enumeration answers, exactly (the same bits as a healthy
    controller)."""
    healthy = controller()
    expected = [healthy.act(*s)[1] for s in HEALTHY_STATES]
    ctrl = controller(**force(monkeypatch, kind, solver))
    for state, ref in zip(HEALTHY_STATES, expected, strict=True):
        u, info = ctrl.act(*state)
        assert info["status"] == "solved", info["notes"]
        assert info["notes"] == first_notes(kind, solver)
        assert info["solver"] == "active_set" and info["ok"]
        np.testing.assert_array_equal(info["nu"], ref["nu"])
        assert info["rho"] == ref["rho"] and info["cost"] == ref["cost"]


@pytest.mark.parametrize("solver", FAST_PATHS)
@pytest.mark.parametrize("kind", list(OSQP_NOTE))
def test_osqp_failure_in_act_is_rescued_by_cvxpy_and_reported(monkeypatch, kind, solver):
    healthy = controller()
    expected = [healthy.act(*s)[1] for s in HEALTHY_STATES]
    no_enumeration(monkeypatch)
    ctrl = controller(**force(monkeypatch, kind, solver))
    for state, ref in zip(HEALTHY_STATES, expected, strict=True):
        u, info = ctrl.act(*state)
        assert info["status"] == "solved" and info["solver"] == "cvxpy", info["notes"]
        assert info["notes"].startswith(first_notes(kind, solver)), info["notes"]
        assert "osqp retry status" in info["notes"]
        # cvxpy's active set is verified and re-solved exactly
        np.testing.assert_array_equal(info["nu"], ref["nu"])
        assert info["rho"] == ref["rho"] and info["cost"] == ref["cost"] and info["ok"]


@pytest.mark.parametrize("solver", FAST_PATHS)
@pytest.mark.parametrize("kind", list(OSQP_NOTE))
def test_osqp_failure_without_cvxpy_falls_back_to_nu_zero(monkeypatch, kind, solver):
    no_enumeration(monkeypatch)
    ctrl = controller(cvxpy_fallback=False, **force(monkeypatch, kind, solver))
    for x, mode, k in HEALTHY_STATES:
        u, info = ctrl.act(x, mode, k)
        assert info["status"] == "fallback_nu0" and not info["ok"], info["notes"]
        assert info["notes"].startswith(first_notes(kind, solver)), info["notes"]
        assert info["notes"].endswith("cvxpy retry disabled") and info["solver"] == "fallback"
        rho, cost = nu_zero_answer(x, mode, k)
        np.testing.assert_array_equal(info["nu"], [0.0])
        np.testing.assert_allclose(u, PAPER_K[mode] @ np.array(x), rtol=1e-15)
        assert info["rho"] == pytest.approx(rho, rel=1e-12, abs=1e-12)
        assert info["cost"] == pytest.approx(cost, rel=1e-12)


def test_a_transient_failure_is_retried_then_forgotten(monkeypatch):
    """One failure: the cold retry solves it ("retried"); the next calls are plain "solved" again
    and agree with a controller that never failed."""
    healthy = controller()
    expected = [healthy.act(*s)[1] for s in HEALTHY_STATES]
    no_enumeration(monkeypatch)
    monkeypatch.setattr(osqp.OSQP, "solve", failing_osqp("exception", failures=1))
    ctrl = controller(solver="osqp")
    infos = [ctrl.act(*s)[1] for s in HEALTHY_STATES]
    assert infos[0]["status"] == "solved"
    assert infos[0]["notes"] == (
        f"{OSQP_NOTE['exception']}; no enumerated active set verified; retried"
    )
    assert infos[0]["solver"] == "osqp_retry"
    assert [(i["status"], i["notes"]) for i in infos[1:]] == [("solved", "")] * (len(infos) - 1)
    for info, ref in zip(infos, expected, strict=True):
        np.testing.assert_allclose(info["nu"], ref["nu"], rtol=0, atol=1e-6)
        assert info["cost"] == pytest.approx(ref["cost"], rel=1e-8)


@pytest.mark.parametrize("solver", ["daqp", "osqp", "cvxpy", "ball"])
def test_every_solver_failing_falls_back_to_nu_zero(monkeypatch, solver):
    """DAQP, OSQP and cvxpy all fail (and the SOCP path, nu_set="ball" with m = 2, which only
    has cvxpy): nu = 0 with the smallest feasible slack, and the notes list every attempt."""
    no_enumeration(monkeypatch)
    fail_daqp(monkeypatch)
    monkeypatch.setattr(osqp.OSQP, "solve", failing_osqp("exception"))
    monkeypatch.setattr(cp.Problem, "solve", failing_cvxpy)
    if solver == "ball":
        model = SDJLSModel(**{**macro().to_dict(), "B": [[1.0, 0.0], [0.0, 1.0]], "R": np.eye(2)})
        K = np.concatenate([np.zeros((3, 1, 2)), PAPER_K], axis=1)  # same closed loop as the paper
        ctrl = controller(model=model, K=K, nu_set="ball")
    else:
        ctrl = controller(solver=solver)
    osqp_notes = [OSQP_NOTE["exception"], "osqp retry status", "cvxpy status 'error SolverError"]
    notes = {
        "daqp": [DAQP_NOTE, *osqp_notes],
        "osqp": osqp_notes,
        "cvxpy": ["cvxpy status 'error SolverError: simulated Clarabel failure'"],
        "ball": ["cvxpy status 'error SolverError: simulated Clarabel failure'"],
    }[solver]
    for x, mode, k in HEALTHY_STATES:
        u, info = ctrl.act(x, mode, k)
        assert info["status"] == "fallback_nu0" and info["solver"] == "fallback"
        assert all(note in info["notes"] for note in notes), info["notes"]
        np.testing.assert_array_equal(info["nu"], np.zeros(ctrl.model.m))
        rho, cost = nu_zero_answer(x, mode, k)
        assert info["rho"] == pytest.approx(rho, rel=1e-12, abs=1e-12)
        if solver != "ball":
            assert info["cost"] == pytest.approx(cost, rel=1e-12)
        assert np.all(np.isfinite(u)) and math.isfinite(info["cost"])
        _, batch = ctrl.act_batch(np.array([x]), np.array([mode]), np.array([k]))
        if solver in FAST_PATHS:  # the batched path solves P3 exactly, without a solver
            assert batch["status"][0] == "solved" and batch["ok"][0]
        else:  # the batched path loops over act
            assert batch["status"][0] == "fallback_nu0" and not batch["ok"][0]


@pytest.mark.parametrize("cvxpy_fallback", [True, False])
def test_failed_steps_do_not_stop_an_episode(monkeypatch, cvxpy_fallback):
    """A whole episode of SDJLS-Macro-v0 with OSQP failing at every step runs to truncation;
    with the cvxpy rescue it is the healthy controller's episode (same noise, inputs within
    1e-6), without it every step is nu = 0 and says so."""

    def episode(ctrl):
        env = gym.make("SDJLS-Macro-v0")
        obs, info = env.reset(seed=3)
        rows, statuses = [], []
        for _ in range(20):
            u, cinfo = ctrl.act(info["state"], info["mode"], info["k"])
            obs, reward, terminated, truncated, info = env.step(u)
            rows.append(np.concatenate([u, info["state"], [reward, cinfo["rho"], cinfo["cost"]]]))
            statuses.append((cinfo["status"], cinfo["solver"], cinfo["notes"]))
            if terminated or truncated:
                break
        assert (terminated, truncated) == (False, True)
        return np.array(rows), statuses

    ref, _ = episode(controller())
    no_enumeration(monkeypatch)
    failing = controller(
        solver="osqp", osqp_settings={"max_iter": 1}, cvxpy_fallback=cvxpy_fallback
    )
    rows, statuses = episode(failing)
    assert rows.shape == ref.shape and np.all(np.isfinite(rows))
    first = "osqp status 'maximum it"
    if cvxpy_fallback:
        assert all((s, p) == ("solved", "cvxpy") and n.startswith(first) for s, p, n in statuses)
        np.testing.assert_allclose(rows[:, 0], ref[:, 0], rtol=0, atol=1e-6)
    else:
        assert all((s, p) == ("fallback_nu0", "fallback") for s, p, _ in statuses)
        assert all(n.startswith(first) for _, _, n in statuses)


# ----------------------------------------------------------------------------- act_batch
def leave_some_unsettled(monkeypatch):
    """Make the batched active-set solver give up on the instances whose linear term in
    ``nu_1`` is positive (about half of them), so that those go through the single-state path
    (OSQP and its fallbacks) inside ``act_batch``."""
    real = ActiveSetQP.solve

    def solve(self, q, *args, **kwargs):
        z, found = real(self, q, *args, **kwargs)
        found = np.array(found, dtype=bool) & (np.atleast_2d(q)[:, 0] <= 0.0)
        z = np.array(z, dtype=np.float64)
        z[~found] = np.nan
        return z, found

    monkeypatch.setattr(ActiveSetQP, "solve", solve)


def batch_states(size=64, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(size, 2)) * rng.choice([1.0, 5.0, 40.0], size=(size, 1))
    return x, rng.integers(0, 3, size), rng.integers(0, 20, size)


@pytest.mark.parametrize("cvxpy_fallback", [True, False])
def test_osqp_failure_inside_act_batch_is_reported_per_instance(monkeypatch, cvxpy_fallback):
    x, mode, k = batch_states()
    _, ref = controller().act_batch(x, mode, k)
    assert list(ref["status"]) == ["solved"] * len(k) and ref["ok"].all()

    leave_some_unsettled(monkeypatch)
    no_enumeration(monkeypatch)
    ctrl = controller(solver="osqp", osqp_settings={"max_iter": 1}, cvxpy_fallback=cvxpy_fallback)
    u, info = ctrl.act_batch(x, mode, k)
    for key in ("nu", "rho", "cost"):
        assert np.all(np.isfinite(info[key])), key
    assert np.all(np.isfinite(u))
    pairs = zip(info["status"], info["notes"], strict=True)
    settled = np.array([s == "solved" and not n for s, n in pairs])
    assert 10 <= settled.sum() <= len(k) - 10  # a mixed batch
    np.testing.assert_allclose(info["nu"][settled], ref["nu"][settled], rtol=0, atol=1e-6)
    failed = ~settled
    if cvxpy_fallback:
        assert all(s == "solved" for s in info["status"][failed])
        assert all(n.startswith("osqp status") for n in info["notes"][failed])
        np.testing.assert_array_equal(info["ok"], np.ones(len(k), bool))
        np.testing.assert_allclose(info["nu"][failed], ref["nu"][failed], rtol=0, atol=1e-6)
        np.testing.assert_allclose(info["rho"], ref["rho"], rtol=0, atol=1e-6)
    else:
        assert all(s == "fallback_nu0" for s in info["status"][failed])
        assert all(n.startswith("osqp status") for n in info["notes"][failed])
        np.testing.assert_array_equal(info["ok"], settled)
        np.testing.assert_array_equal(info["nu"][failed], 0.0)
        for i in np.flatnonzero(failed):
            rho, cost = nu_zero_answer(x[i], int(mode[i]), int(k[i]))
            assert info["rho"][i] == pytest.approx(rho, rel=1e-12, abs=1e-12)
            assert info["cost"][i] == pytest.approx(cost, rel=1e-12)
            np.testing.assert_allclose(u[i], PAPER_K[mode[i]] @ x[i], rtol=1e-15)


def test_failures_inside_act_batch_do_not_stop_the_vector_env(monkeypatch):
    leave_some_unsettled(monkeypatch)
    no_enumeration(monkeypatch)
    monkeypatch.setattr(osqp.OSQP, "solve", failing_osqp("exception"))
    ctrl = controller(solver="osqp", cvxpy_fallback=False)
    envs = SDJLSVectorEnv(32, model="macro")
    _, infos = envs.reset(seed=1)
    fallbacks = 0
    for _ in range(20):
        u, cinfo = ctrl.act_batch(infos["state"], infos["mode"], infos["k"])
        fallback = np.array([s == "fallback_nu0" for s in cinfo["status"]])
        np.testing.assert_array_equal(cinfo["ok"], ~fallback)
        fallbacks += int(fallback.sum())
        assert np.all(np.isfinite(u)) and np.all(np.isfinite(cinfo["cost"]))
        _, rewards, terminated, truncated, infos = envs.step(u)
        assert np.all(np.isfinite(rewards)) and not terminated.any()
    assert truncated.all() and 0 < fallbacks < 32 * 20


# ----------------------------------------------------------------------------- the LMIs
def lmi_model(A, B, P=None) -> SDJLSModel:
    A = np.asarray(A, dtype=np.float64)
    A = A[None] if A.ndim == 2 else A
    N, n, m = A.shape[0], A.shape[1], np.asarray(B).shape[-1]
    P = np.full((N, N), 1.0 / N) if P is None else P
    return SDJLSModel(
        A=A, B=B, P_in=P, P_out=P, G=np.eye(n)[:1], H0=[1.0], Q=np.eye(n), R=np.eye(m),
        x0=np.zeros(n),
    )  # fmt: skip


HARD_SYSTEMS = {
    "unstabilisable": lmi_model([[2.0, 0.0], [0.0, 0.5]], [[0.0], [0.0]]),
    "marginal": lmi_model([[1.0]], [[0.0]]),  # spectral radius exactly 1, no input
    "huge-A": lmi_model([[1e6, 1.0], [0.0, 0.9]], [[0.0], [1.0]]),
    "spread-scales": lmi_model([[1e4, 0.0], [0.0, 1e-4]], [[1.0], [1.0]]),
    "tiny-B": lmi_model([[1.5, 1.0], [0.0, 0.9]], [[0.0], [1e-9]]),
    "weak-input": lmi_model([[1.2, 0.0], [0.0, 0.5]], [[1e-7], [1.0]]),
    "two-modes-one-unstabilisable": lmi_model(
        [[[0.5, 0.0], [0.0, 0.5]], [[3.0, 0.0], [0.0, 0.2]]], [[0.0], [1.0]], np.eye(2)
    ),
}
NO_GAINS = ("unstabilisable", "marginal", "two-modes-one-unstabilisable")


def assert_proposition1_holds(model: SDJLSModel, K: np.ndarray, P: np.ndarray) -> None:
    """(LMI1), (LMI2) in float64 with the returned P and K: P_i > 0, E_i^j < 0."""
    assert np.all(np.linalg.eigvalsh(P)[:, 0] > 0)
    At = model.A + model.B @ K
    for Pi in (model.P_in, model.P_out):
        L = np.einsum("ij,jab->iab", Pi, P)
        E = At.transpose(0, 2, 1) @ L @ At - P
        assert np.all(np.linalg.eigvalsh(0.5 * (E + E.transpose(0, 2, 1)))[:, -1] < 0)


@pytest.mark.parametrize("solver", ["CLARABEL", "SCS"])
@pytest.mark.parametrize("name", list(HARD_SYSTEMS))
def test_ill_posed_lmis_raise_naming_the_solver_status(name, solver):
    """Infeasible or badly scaled Proposition-2 problems: either gains that pass Proposition 1
    in float64, or an LMIError naming the solver and its status (or its failure); never another
    exception, never unverified gains."""
    model = HARD_SYSTEMS[name]
    try:
        res = synthesize_gains(model, solver=solver)
    except LMIError as exc:
        text = str(exc)
        assert f"solver {solver}" in text and ("status '" in text or "failed" in text), text
        if isinstance(exc, LMIInfeasibleError):
            assert "status 'infeasible'" in text
        return
    assert name not in NO_GAINS, "gains returned for a system that has none"
    assert res.status == "optimal" and res.margin < 0
    assert_proposition1_holds(model, res.K, res.P)


def force_cvxpy_status(monkeypatch, status):
    def solve(self, *args, **kwargs):
        value = REAL_CVXPY_SOLVE(self, *args, **kwargs)
        self._status = status
        return value

    monkeypatch.setattr(cp.Problem, "solve", solve)


@pytest.mark.parametrize(
    "status", ["optimal_inaccurate", "infeasible_inaccurate", "unbounded", "user_limit"]
)
@pytest.mark.parametrize("what", ["synthesize_gains", "verify_mean_square_bound"])
def test_non_optimal_sdp_status_is_an_error_naming_it(monkeypatch, status, what):
    force_cvxpy_status(monkeypatch, status)
    with pytest.raises(LMISolverError, match=rf"solver CLARABEL returned status '{status}'"):
        if what == "synthesize_gains":
            synthesize_gains(macro())
        else:
            verify_mean_square_bound(macro(), PAPER_K)


@pytest.mark.parametrize("what", ["synthesize_gains", "verify_mean_square_bound"])
def test_sdp_solver_crash_and_forced_infeasibility_are_errors(monkeypatch, what):
    def call():
        if what == "synthesize_gains":
            return synthesize_gains(macro(), objective="max_margin")
        return verify_mean_square_bound(macro(), PAPER_K, nu_bound=1.0)

    monkeypatch.setattr(cp.Problem, "solve", failing_cvxpy)
    with pytest.raises(LMISolverError, match=r"solver CLARABEL failed \(simulated Clarabel"):
        call()
    force_cvxpy_status(monkeypatch, "infeasible")
    with pytest.raises(LMIInfeasibleError, match=r"solver CLARABEL reports status 'infeasible'"):
        call()


# ----------------------------------------------------------------------------- divergence
def unstable_model() -> SDJLSModel:
    """Two modes, growth up to 60x per step: 1e30 is crossed within 20 steps."""
    return SDJLSModel(
        A=[[[60.0, 1.0], [0.0, 0.5]], [[-3.0, 0.0], [2.0, 40.0]]], B=[[1.0], [1.0]],
        P_in=[[0.5, 0.5], [0.5, 0.5]], P_out=[[0.1, 0.9], [0.9, 0.1]], G=[[1.0, 1.0]],
        H0=[10.0], Q=np.eye(2), R=[[1.0]], x0=[1.0, -1.0], E=[[1.0], [0.5]], W=[[2.0]],
    )  # fmt: skip


POOR_ENVS = {
    "macro-bang-bang": dict(id="SDJLS-Macro-v0"),
    "unstable-max-bound": dict(
        id="SDJLS-v0", model=unstable_model(), horizon=60, divergence_bound=1e30, action_bound=1e30
    ),
}


def check_step(space, obs, reward, terminated, info, bound):
    assert math.isfinite(reward) and space.contains(obs), (reward, obs)
    assert info["diverged"] == bool(np.max(np.abs(info["state"])) > bound)
    assert terminated == info["diverged"]
    assert np.all(np.isfinite(info["state"])) and np.all(np.isfinite(info["constraint_values"]))


@pytest.mark.parametrize("name", list(POOR_ENVS))
def test_env_terminates_on_divergence_with_finite_rewards(name):
    """A random bang-bang policy (an untrained agent): every episode that blows up ends with
    info["diverged"]; every reward and observation stays finite; no overflow anywhere."""
    kwargs = dict(POOR_ENVS[name])
    env = gym.make(kwargs.pop("id"), **kwargs)
    bound = env.unwrapped.divergence_bound
    env.action_space.seed(0)
    diverged = 0
    for episode in range(40):
        obs, info = env.reset(seed=episode)
        terminated = truncated = False
        while not (terminated or truncated):
            action = np.sign(env.action_space.sample()) * env.action_space.high
            obs, reward, terminated, truncated, info = env.step(action)
            check_step(env.observation_space, obs, reward, terminated, info, bound)
        diverged += terminated
    assert diverged >= 10


def test_rl_wrappers_on_a_diverging_env():
    """ResidualAction + ViolationPenalty, as used for RL training, with random offsets."""
    env = gym.make("SDJLS-v0", model=unstable_model(), horizon=60, divergence_bound=1e30)
    env = ViolationPenalty(ResidualAction(env, np.zeros((2, 1, 2)), nu_bound=100.0), beta=50.0)
    env.action_space.seed(1)
    terminated_any = False
    for episode in range(10):
        obs, info = env.reset(seed=episode)
        done = False
        while not done:
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert math.isfinite(reward) and math.isfinite(info["reward_unpenalized"])
            assert np.all(np.isfinite(obs))
            done = terminated or truncated
            terminated_any |= terminated
    assert terminated_any


@pytest.mark.parametrize("name", list(POOR_ENVS))
def test_vector_env_terminates_on_divergence_and_resets(name):
    kwargs = dict(POOR_ENVS[name])
    envs = gym.make_vec(
        kwargs.pop("id"), num_envs=64, vectorization_mode="vector_entry_point", **kwargs
    )
    bound = envs.unwrapped.divergence_bound
    high = envs.single_action_space.high
    rng = np.random.default_rng(0)
    obs, infos = envs.reset(seed=0)
    terminations = 0
    for _ in range(150):
        actions = rng.choice([-1.0, 1.0], size=(64, 1)) * high
        obs, rewards, terminated, truncated, infos = envs.step(actions)
        assert np.all(np.isfinite(rewards)) and envs.observation_space.contains(obs)
        assert np.all(np.isfinite(infos["state"]))
        np.testing.assert_array_equal(
            infos["diverged"], np.max(np.abs(infos["state"]), axis=1) > bound
        )
        assert not np.any(terminated & ~infos["diverged"])
        terminations += int(terminated.sum())
    assert terminations >= 64


def test_rhc_with_destabilising_gains_runs_into_divergence_without_crashing():
    """K = 0 leaves the macro modes unstable and |nu| <= 1 cannot hold them: the states grow to
    the maximum divergence bound 1e30 and beyond. The controller keeps answering with finite
    inputs (falling back and saying so where the solvers give up), and the vector env ends
    those episodes with info["diverged"]."""
    model = macro()
    ctrl = controller(K=np.zeros((3, 1, 2)), nu_bound=1.0)
    envs = SDJLSVectorEnv(256, model=model, horizon=200, divergence_bound=1e30, action_bound=1e30)
    _, infos = envs.reset(seed=2)
    seen_max, terminations = 0.0, 0
    for _ in range(150):
        u, cinfo = ctrl.act_batch(infos["state"], infos["mode"], infos["k"])
        assert np.all(np.isfinite(u))
        for key in ("nu", "rho", "cost"):
            assert np.all(np.isfinite(cinfo[key])), key
        assert np.all(np.abs(cinfo["nu"]) <= 1.0)
        np.testing.assert_array_equal(
            cinfo["ok"], [not s.startswith("fallback") for s in cinfo["status"]]
        )
        _, rewards, terminated, truncated, infos = envs.step(u)
        assert np.all(np.isfinite(rewards)) and np.all(np.isfinite(infos["state"]))
        assert not np.any(terminated & ~infos["diverged"])
        terminations += int(terminated.sum())
        seen_max = max(seen_max, float(np.max(np.abs(infos["state"]))))
    assert terminations >= 256 and seen_max > 1e30  # every env diverged at least once on average
