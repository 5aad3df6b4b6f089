"""The search around a solver's answer is bounded by a count of factorizations, not a time.

``tests/data/tree_repair_budget.json`` holds two random systems in the shape of the hostile
review's scenario tree (N = 4, n = m = 3, r = 4, steps = branching = 4, xi = 0.99, bonferroni;
how they were made: its ``note``). A factorization is a QR factor of an active set's rows or a
reduced Hessian, counted here by wrapping the two functions that compute them.

* The 33-node decision spent 20,809 factorizations (13-18 s) and ended ok False: at its second
  QP, nodes of path probability ~1e-12 made the optimum's reduced Hessian look singular (its
  smallest eigenvalue 2.5e-13 of the largest), no answer verified, the search around each of
  DAQP's six attempts and cvxpy's answer tried up to 256 subsets and 20 repair steps, and the
  fixed-point iterations repeated that for nine QPs in a row.
* The 111-node tree with ``solver="osqp"`` ran OSQP to its iteration limit twice per QP
  (20,000, then 200,000 iterations) before the cvxpy rescue: 5.7 s a decision against cvxpy's
  1.3 s.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import controllers.tree_qp as tree_qp
from benchmarks.speed.measure import large_tree_model
from controllers import ScenarioTreeController
from controllers.qp import QPFamily
from sdjls_gym import SDJLSModel

DATA = Path(__file__).parent / "data" / "tree_repair_budget.json"


@pytest.fixture
def factorizations(monkeypatch):
    """A dict whose ``"n"`` counts the factorizations of the scenario tree's exact solves."""
    count = {"n": 0}
    for name in ("active_set_factor", "reduce_hessian"):
        compute = getattr(tree_qp, name)

        def counted(*args, _compute=compute, **kwargs):
            count["n"] += 1
            return _compute(*args, **kwargs)

        monkeypatch.setattr(tree_qp, name, counted)
    return count


def tree_case(name: str):
    case = json.loads(DATA.read_text())
    K, Psi = np.zeros((4, 3, 3)), np.tile(np.eye(3), (4, 1, 1))
    model = SDJLSModel.from_dict(case[name]["model"])
    ctrl = ScenarioTreeController(model, K, Psi=Psi, **case["kwargs"])
    x, mode, k = case[name]["state"]
    return ctrl, np.array(x), mode, k


def engine_factorizations(ctrl: ScenarioTreeController) -> int:
    return sum(fam.engine.factorizations for fam in ctrl._families.values())


def test_the_33_node_decision_is_verified_with_few_factorizations(factorizations):
    """Now verified (ok True) in 3 QPs and a handful of factorizations: a reduced Hessian that
    fails the definiteness test is judged again with its diagonal scaled to 1."""
    ctrl, x, mode, k = tree_case("issue")
    _, info = ctrl.act(x, mode, k)
    assert info["plan"].mode.size == 33
    assert info["ok"], (info["status"], info["notes"])
    assert factorizations["n"] <= 50, factorizations
    assert engine_factorizations(ctrl) == factorizations["n"]


def test_a_hard_tree_fails_fast(factorizations):
    """A 21-node decision that no answer verifies: the search of each QP stops at its budget and
    hands over, and the first QP whose answer is not verified ends the fixed-point iterations
    (the cvxpy reference iterates on). It spent 18,712 factorizations in 10 QPs (236 now)."""
    ctrl, x, mode, k = tree_case("hard")
    _, info = ctrl.act(x, mode, k)
    assert info["plan"].mode.size == 21
    assert info["ok"] or factorizations["n"] <= 1000, (info["status"], factorizations)
    if not info["ok"]:  # ended at the QP that failed (here the third), not after ten
        assert info["iterations"] < ctrl.iterations and "did not verify" in info["notes"]
    assert engine_factorizations(ctrl) == factorizations["n"]


def test_osqp_on_the_111_node_tree_runs_once_per_qp_then_daqp(monkeypatch):
    """``solver="osqp"`` on the 111-node tree (N = 10, n = 4, m = 1, r = 20, steps = 3): OSQP
    runs once per QP that the warm sets do not answer, within its 20,000 iterations (no retry at
    ten times that), and DAQP, started from the rows its last iterate leaves nearly active,
    finds the active set; no cvxpy rescue, every decision verified."""
    runs: list[bool] = []
    run_osqp = QPFamily.run_osqp

    def counted(self, w, retry=False):
        runs.append(retry)
        return run_osqp(self, w, retry)

    monkeypatch.setattr(QPFamily, "run_osqp", counted)
    model = large_tree_model(seed=11, N=10, r=20)
    ctrl = ScenarioTreeController(
        model, np.zeros((10, 1, 4)), Psi=np.tile(np.eye(4), (10, 1, 1)), xi=0.9, steps=3,
        solver="osqp",
    )  # fmt: skip
    rng = np.random.default_rng(0)
    _, info = ctrl.act(rng.normal(size=4), int(rng.integers(10)), 0)
    assert info["plan"].mode.size == 111 and info["ok"], (info["status"], info["notes"])
    assert not any(runs) and 1 <= len(runs) <= info["iterations"], runs
    assert "cvxpy" not in ctrl.path_counts, ctrl.path_counts
    iterations = sum(fam.engine.osqp_iterations for fam in ctrl._families.values())
    assert iterations <= 20_000 * len(runs), iterations
