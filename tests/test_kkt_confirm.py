"""The KKT test does not accept a clearly negative multiplier that its magnitudes hide.

``tests/data/kkt_negative_multiplier.json`` holds one QP ``min 1/2 z'Pz + q'z  s.t.  C z <= h``
of the scenario tree (how it was made: its ``about`` field) and an active set whose multipliers
of rows 6 and 51 are about -3.8 and -1.0, while the first computation of the test gave them
magnitudes of 1.8e10 and 2.1e9 (an ill-conditioned reduced Hessian in the scaled variables):
within ``KKT_TOL`` of those, so the point, 4.0 above the optimum in the objective, was called
verified. Every multiplier accepted below zero is now computed a second time
(:func:`controllers.kkt.confirm_multipliers`).
"""

from __future__ import annotations

import json
from pathlib import Path

import cvxpy as cp
import numpy as np
import pytest

from controllers import ScenarioTreeController
from controllers.kkt import KKT_TOL, active_set_factor, check_active_set, confirm_multipliers
from controllers.kkt_maps import active_set_maps
from controllers.rhc import DEFAULT_OSQP_SETTINGS
from controllers.tree_qp import TreeQP
from sdjls_gym import SDJLSModel

DATA = Path(__file__).parent / "data" / "kkt_negative_multiplier.json"


@pytest.fixture(scope="module")
def case():
    raw = json.loads(DATA.read_text())
    P, C, w = (np.array(raw[key], dtype=np.float64) for key in ("P", "C", "w"))
    return P, C, w, tuple(raw["rows"])


def objective(P, w, z):
    d = P.shape[0]
    return 0.5 * z @ P @ z + w[:d] @ z


def dense_kkt(P, C, w, rows):
    """``(z, lam)`` of the active set by the dense KKT system (the test's own computation)."""
    d, idx = P.shape[0], np.array(rows)
    K = np.block([[P, C[idx].T], [C[idx], np.zeros((idx.size, idx.size))]])
    sol = np.linalg.solve(K, np.concatenate([-w[:d], w[d + idx]]))
    return sol[:d], sol[d:]


def test_the_case_has_a_clearly_negative_multiplier(case):
    """The premise, by the test's own dense solve: the point is feasible, rows 6 and 51 have
    multipliers below -0.5, and the QP's optimum (Clarabel) is lower by more than 1."""
    P, C, w, rows = case
    d = P.shape[0]
    z, lam = dense_kkt(P, C, w, rows)
    assert np.max(C @ z - w[d:]) <= 1e-12
    assert lam[0] < -0.5 and lam[1] < -0.5, lam[:2]
    x = cp.Variable(d)
    prob = cp.Problem(
        cp.Minimize(0.5 * cp.quad_form(x, cp.psd_wrap(P)) + w[:d] @ x), [C @ x <= w[d:]]
    )
    prob.solve(solver=cp.CLARABEL)
    assert objective(P, w, z) - prob.value > 1.0


def test_single_instance_test_rejects_it(case):
    """``check_active_set`` (the tree's form) rejects the set and reports the negative rows to
    drop; before the confirmation it returned the point."""
    P, C, w, rows = case
    pivots = ~P.any(axis=1)
    fac = active_set_factor(C, rows, pivots)
    assert fac is not None
    report: dict = {}
    assert check_active_set(fac, P, C, w, np.abs(C), report) is None
    assert {6, 51} <= set(report["drop"])


def test_maps_form_rejects_it(case):
    """The maps form (P3's, a Hessian fixed per family) gives the same verdict."""
    P, C, w, rows = case
    maps = active_set_maps(P, C, rows, pivots=~P.any(axis=1))
    assert maps is not None
    assert maps.check(w) is None


def test_confirmation_rejects_negative_and_accepts_nothing_to_confirm(case):
    """``confirm_multipliers`` on its own: at the case's set the two negative multipliers fail
    (-3.8 and -1.0 against a tolerance of 1e-9 times a gradient of about 6e5); a mask of nothing
    passes trivially."""
    P, C, w, rows = case
    z, lam = dense_kkt(P, C, w, rows)
    assert not confirm_multipliers(P, C, rows, w, lam < 0.0, z)
    assert confirm_multipliers(P, C, rows, w, np.zeros(len(rows), dtype=bool), z)


def test_a_multiplier_negative_within_the_gradients_scale_is_accepted():
    """The other side: on the same random system, at a state where the optimum's active set has
    multipliers of -1.5e-6 and -9.4e-7 (the dense system's, accurate there) against a gradient
    of 2.8e4, the answer is accepted (a tolerance relative to the dense solve's own terms
    rejected it: the decision ended unverified) and costs what the cvxpy reference's does."""
    case = json.loads((DATA.parent / "tree_zero_probability_branch.json").read_text())
    model = SDJLSModel.from_dict(case["model"])
    kwargs = dict(Psi=case["Psi"], **case["kwargs"])
    x, mode, k = np.array([-2.8190086521959823, 8.072578647121663]), 2, 18
    fast = ScenarioTreeController(model, case["K"], **kwargs).act(x, mode, k)[1]
    ref = ScenarioTreeController(model, case["K"], solver="cvxpy", **kwargs).act(x, mode, k)[1]
    assert fast["status"] == "unconverged", (fast["status"], fast["notes"])  # iterations = 1
    assert "did not verify" not in fast["notes"]
    assert abs(fast["cost"] - ref["cost"]) <= 1e-9 * abs(ref["cost"])


def test_the_engine_finds_the_optimum(case):
    """The engine's chain, started from the case's set (its warm start), ends at the optimum:
    feasible, every multiplier nonnegative to KKT_TOL of the gradient's scale (the test's dense
    solve), the objective Clarabel's to 1e-9 relative."""
    P, C, w, rows = case
    d, c = P.shape[0], C.shape[0]
    engine = TreeQP(
        P, C, np.zeros(c, bool), np.ones(c, bool), DEFAULT_OSQP_SETTINGS, enumerate_all=False
    )
    engine.warm = rows
    sol = engine.solve(w)
    assert sol is not None and tuple(sol.rows) != rows
    z = np.asarray(sol.z)
    z_dense, lam = dense_kkt(P, C, w, sol.rows)
    assert np.max(C @ z - w[d:]) <= KKT_TOL * np.max(np.abs(C) @ np.abs(z) + np.abs(w[d:]))
    scale = np.max(np.abs(P) @ np.abs(z) + np.abs(w[:d]))
    assert np.all(lam >= -KKT_TOL * scale), lam.min()
    x = cp.Variable(d)
    prob = cp.Problem(
        cp.Minimize(0.5 * cp.quad_form(x, cp.psd_wrap(P)) + w[:d] @ x), [C @ x <= w[d:]]
    )
    prob.solve(solver=cp.CLARABEL)
    assert abs(objective(P, w, z) - prob.value) <= 1e-9 * abs(prob.value)
    assert np.max(np.abs(z - z_dense)) <= 1e-8 * (1.0 + np.max(np.abs(z)))
