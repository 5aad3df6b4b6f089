"""Bad input gives a clear error before any work: the catalogue of the controllers' checks.

Each case is checked by ``conftest.refused`` (and the ``no_solver`` trap).

The receding-horizon controllers (construction, ``act``, ``act_batch``), the scenario tree, the
chance constraints, the baselines and the LMI functions.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from conftest import refused

from controllers import (
    LinearFeedbackController,
    MJLSLQRController,
    RecedingHorizonController,
    ScenarioTreeController,
    UnconstrainedRecedingHorizonController,
    check_proposition2,
    row_satisfaction_probability,
    second_moment_spectral_radius,
    synthesize_gains,
    tightened_set_empty,
    tightening,
    verify_mean_square_bound,
)
from sdjls_gym import SDJLSModel
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, PAPER_X, PAPER_Y, macro

nan, inf = float("nan"), float("inf")
PSI = PAPER_RHC["Psi"]
A_DICT = "{'A': array("  # a dict of arrays is shown shortened: its start


# ------------------------------------------------------------------------------------ helpers
def rhc(**override):
    kw = {"model": macro(), "K": PAPER_K, **PAPER_RHC}
    kw.update(override)
    return RecedingHorizonController(**kw)


def poke(value, bad):
    """A copy of ``value`` with its last entry replaced by ``bad``."""
    out = np.array(value, dtype=np.float64)
    out.flat[-1] = bad
    return out


def case(call, error, name, value, id):
    return pytest.param(call, error, name, value, id=id)


# ------------------------------------------------------------------------------------ the table
CASES = [
    # ---- receding-horizon controller: construction
    case(lambda c: rhc(model="macro"), TypeError, "model", "macro", "rhc-model"),
    case(lambda c: rhc(xi=0.0), ValueError, "xi", 0.0, "xi-0"),
    case(lambda c: rhc(xi=1.0), ValueError, "xi", 1.0, "xi-1"),
    case(lambda c: rhc(xi=-0.1), ValueError, "xi", -0.1, "xi-negative"),
    case(lambda c: rhc(xi=1.5), ValueError, "xi", 1.5, "xi-above-1"),
    case(lambda c: rhc(xi=nan), ValueError, "xi", nan, "xi-nan"),
    case(lambda c: rhc(xi=True), TypeError, "xi", True, "xi-bool"),
    case(lambda c: rhc().act([True, 1.0], 0, 0), TypeError, "x", True, "act-x-bool-among-numbers"),
    case(lambda c: rhc(xi="0.85"), TypeError, "xi", "0.85", "xi-str"),
    case(lambda c: rhc(alpha="1000"), TypeError, "alpha", "1000", "alpha-str"),
    case(lambda c: rhc(alpha=True), TypeError, "alpha", True, "alpha-bool"),
    case(lambda c: rhc(alpha=1e13), ValueError, "alpha", 1e13, "alpha-above-limit"),
    case(lambda c: rhc(nu_bound=1e13), ValueError, "nu_bound", 1e13, "nu-bound-above-limit"),
    case(lambda c: rhc(Psi=1e200 * PSI), ValueError, "Psi", 3e200, "Psi-huge"),
    case(
        lambda c: RecedingHorizonController(
            SDJLSModel(**{**c.kw, "R": 1e120 * np.ones((1, 1))}), PAPER_K, **PAPER_RHC
        ),
        ValueError,
        "model.R",
        1e120,
        "R-huge",
    ),
    case(lambda c: rhc(horizon=2.0), TypeError, "horizon", 2.0, "rhc-horizon-float"),
    case(
        lambda c: LinearFeedbackController(macro(), PAPER_K, horizon=2.0),
        TypeError,
        "horizon",
        2.0,
        "linear-horizon-float",
    ),
    case(lambda c: rhc(alpha=0.0), ValueError, "alpha", 0.0, "alpha-0"),
    case(lambda c: rhc(alpha=-5.0), ValueError, "alpha", -5.0, "alpha-negative"),
    case(lambda c: rhc(alpha=inf), ValueError, "alpha", inf, "alpha-inf"),
    case(lambda c: rhc(nu_bound=0.0), ValueError, "nu_bound", 0.0, "nu-bound-0"),
    case(lambda c: rhc(nu_bound=-1.0), ValueError, "nu_bound", -1.0, "nu-bound-neg"),
    # shown by its eigenvalues (-1 .. -1), not its entries
    case(
        lambda c: rhc(Psi=np.array([np.eye(2), -np.eye(2), np.eye(2)])),
        ValueError,
        "Psi[1]",
        -1,
        "Psi-neg",
    ),
    case(lambda c: rhc(Psi=np.zeros((3, 2, 2))), ValueError, "Psi[0]", np.zeros((2, 2)), "Psi-0"),
    case(
        lambda c: rhc(Psi=np.array([[[1.0, 0.5], [0.0, 1.0]]] * 3)),
        ValueError,
        "Psi[0]",
        np.array([[1.0, 0.5], [0.0, 1.0]]),
        "Psi-asym",
    ),
    case(lambda c: rhc(Psi=poke(PSI, nan)), ValueError, "Psi", nan, "Psi-nan"),
    case(lambda c: rhc(Psi=np.eye(2)), ValueError, "Psi", (2, 2), "Psi-shape"),
    case(lambda c: rhc(K=PAPER_K[:, :, :1]), ValueError, "K", (3, 1, 1), "K-shape"),
    case(lambda c: rhc(K=PAPER_K[0]), ValueError, "K", (1, 2), "K-no-modes"),
    case(lambda c: rhc(K=poke(PAPER_K, inf)), ValueError, "K", inf, "K-inf"),
    case(lambda c: rhc(constraint="chance"), ValueError, "constraint", "chance", "constraint"),
    case(lambda c: rhc(solver="gurobi"), ValueError, "solver", "gurobi", "solver"),
    case(lambda c: rhc(nu_set="sphere"), ValueError, "nu_set", "sphere", "nu-set"),
    case(
        lambda c: rhc(osqp_settings={"max_iterations": 5}),
        ValueError,
        "osqp_settings",
        {"max_iterations": 5},
        "osqp-name",
    ),
    case(lambda c: rhc(osqp_settings=3), TypeError, "osqp_settings", 3, "osqp-type"),
    case(lambda c: rhc(cvxpy_fallback="yes"), TypeError, "cvxpy_fallback", "yes", "fallback"),
    case(
        lambda c: UnconstrainedRecedingHorizonController(macro(), PAPER_K, Psi=PSI, alpha=0.0),
        ValueError,
        "alpha",
        0.0,
        "unconstrained-alpha",
    ),
    # ---- receding-horizon controller: act and act_batch
    case(lambda c: rhc().act([1.0, 2.0, 3.0], 0, 0), ValueError, "x", (3,), "act-x-shape"),
    case(lambda c: rhc().act([1.0, nan], 0, 0), ValueError, "x", nan, "act-x-nan"),
    case(lambda c: rhc().act([1.0, 2.0], 3, 0), ValueError, "mode", 3, "act-mode"),
    case(lambda c: rhc().act([1.0, 2.0], 1.0, 0), TypeError, "mode", 1.0, "act-mode-float"),
    case(lambda c: rhc().act([1.0, 2.0], 0, -1), ValueError, "k", -1, "act-k"),
    case(lambda c: rhc().act([1.0, 2.0], 0, 2**70), ValueError, "k", 2**70, "act-k-huge"),
    case(
        lambda c: rhc().act([1.0, 2.0], 0, np.uint64(2**64 - 1)),
        ValueError,
        "k",
        np.uint64(2**64 - 1),
        "act-k-uint64-max",
    ),
    case(
        lambda c: rhc().act_batch(
            np.zeros((2, 2)), np.zeros(2, int), np.full(2, 2**64 - 1, np.uint64)
        ),
        ValueError,
        "k",
        np.uint64(2**64 - 1),
        "batch-k-uint64-max",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((2, 2)), np.zeros(2, int), 10**30),
        ValueError,
        "k",
        10**30,
        "batch-k-python-huge",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((2, 2)), np.zeros(2, int), [10**30, 1]),
        ValueError,
        "k",
        10**30,
        "batch-k-python-huge-list",
    ),
    case(
        lambda c: rhc().act([1.0, 2.0], 0, 2**53),
        ValueError,
        "k",
        2**53,
        "act-k-2-53-needs-k-plus-1",
    ),
    case(
        lambda c: ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=3).act(
            [1.0, 2.0], 0, 2**53 - 2
        ),
        ValueError,
        "k",
        2**53 - 2,
        "tree-k-beyond-2-53-minus-steps",
    ),
    # NotAnIntError: a ValueError and a TypeError
    case(
        lambda c: ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=2.5),
        ValueError,
        "steps",
        2.5,
        "tree-steps-non-integer",
    ),
    case(
        lambda c: rhc().act(np.array([1e101, 0.0]), 0, 0),
        ValueError,
        "x",
        np.array([1e101, 0.0]),
        "act-huge-state",
    ),
    case(
        lambda c: rhc().act_batch(np.array([[0.0, 1.0], [0.0, -2e300]]), np.zeros(2, int), 0),
        ValueError,
        "x[1]",
        np.array([0.0, -2e300]),
        "act-batch-huge-state",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 3)), np.zeros(4, int), 0),
        ValueError,
        "x",
        (4, 3),
        "batch-x-shape",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 2)), np.zeros(3, int), 0),
        ValueError,
        "mode",
        (3,),
        "batch-mode-shape",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 2)), np.full(4, 3), 0),
        ValueError,
        "mode",
        np.int64(3),
        "batch-mode",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 2)), np.zeros(4), 0),
        TypeError,
        "mode",
        np.dtype("float64"),
        "batch-mode-float",
    ),
    case(
        lambda c: rhc().act_batch(np.full((4, 2), inf), np.zeros(4, int), 0),
        ValueError,
        "x",
        inf,
        "batch-x-inf",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 2)), np.zeros(4, int), -1),
        ValueError,
        "k",
        -1,
        "batch-k",
    ),
    # ---- chance constraints
    case(lambda c: tightening(macro(), 0.0), ValueError, "xi", 0.0, "tightening-xi-0"),
    case(lambda c: tightening(macro(), 1), ValueError, "xi", 1, "tightening-xi-1"),
    case(
        lambda c: tightening(macro(), 0.9, "both"),
        ValueError,
        "constraint",
        "both",
        "tightening-kind",
    ),
    case(lambda c: tightening(c.kw, 0.9), TypeError, "model", A_DICT, "tightening-model"),
    case(lambda c: tightened_set_empty(macro(), 1.5, 1), ValueError, "xi", 1.5, "empty-set-xi"),
    case(
        lambda c: tightened_set_empty(macro(), 0.9, -2),
        ValueError,
        "k_next",
        -2,
        "empty-set-k-negative",
    ),
    case(
        lambda c: tightened_set_empty(macro(), 0.9, 2.0),
        TypeError,
        "k_next",
        2.0,
        "empty-set-k-float",
    ),
    case(
        lambda c: tightened_set_empty(macro(), 0.9, 1, "all"),
        ValueError,
        "constraint",
        "all",
        "empty-set-kind",
    ),
    case(
        lambda c: tightened_set_empty(c.kw, 0.9, 1), TypeError, "model", A_DICT, "empty-set-model"
    ),
    case(
        lambda c: row_satisfaction_probability(macro(), np.zeros(3), 0, 1),
        ValueError,
        "mean_next",
        (3,),
        "probability-mean",
    ),
    case(
        lambda c: row_satisfaction_probability(macro(), np.zeros(2), 3, 1),
        ValueError,
        "mode",
        np.array(3),
        "probability-mode",
    ),
    # ---- baselines
    case(
        lambda c: LinearFeedbackController(macro(), np.zeros((3, 2))),
        ValueError,
        "K",
        (3, 2),
        "linear-K",
    ),
    case(
        lambda c: MJLSLQRController(macro(), transition=0.5 * np.eye(3)),
        ValueError,
        "transition",
        0.5,
        "lqr-P",
    ),
    # ---- LMI synthesis and certificate
    case(lambda c: synthesize_gains(c.kw), TypeError, "model", A_DICT, "synth-model"),
    case(lambda c: synthesize_gains(macro(), eps=0.0), ValueError, "eps", 0.0, "synth-eps-0"),
    case(lambda c: synthesize_gains(macro(), eps=-1e-6), ValueError, "eps", -1e-6, "synth-eps-neg"),
    case(
        lambda c: synthesize_gains(macro(), objective="fastest"),
        ValueError,
        "objective",
        "fastest",
        "synth-objective",
    ),
    case(
        lambda c: synthesize_gains(macro(), solver="NOPE"),
        ValueError,
        "solver",
        "NOPE",
        "synth-solver",
    ),
    case(
        lambda c: verify_mean_square_bound(macro(), PAPER_K[0]), ValueError, "K", (1, 2), "verify-K"
    ),
    case(
        lambda c: verify_mean_square_bound(macro(), PAPER_K, nu_bound=-1.0),
        ValueError,
        "nu_bound",
        -1.0,
        "verify-nu-bound",
    ),
    case(
        lambda c: verify_mean_square_bound(macro(), PAPER_K, kappa=0.0),
        ValueError,
        "kappa",
        0.0,
        "verify-kappa",
    ),
    case(
        lambda c: second_moment_spectral_radius(macro(), PAPER_K[:, :, :1]),
        ValueError,
        "K",
        (3, 1, 1),
        "radius-K",
    ),
    case(
        lambda c: check_proposition2(macro(), PAPER_X[:2], PAPER_Y),
        ValueError,
        "X",
        (2, 2, 2),
        "prop2-X",
    ),
]


@pytest.fixture
def ctx(paper_kwargs, no_solver):
    """Inputs of the cases (every solver replaced by a trap: nothing may be solved)."""
    return SimpleNamespace(kw=paper_kwargs)


@pytest.mark.parametrize(("call", "error", "name", "value"), CASES)
def test_bad_input_is_refused_naming_the_argument_and_the_value(ctx, call, error, name, value):
    """The error's type, the argument's name and the offending value; no warning on the way,
    raised by a check of this project, before any solver starts."""
    refused(error, name, value, lambda: call(ctx))
