"""Every input checked before any work (issue 28, section 3): bools among batch indices, Python
ints beyond float64, LMI data that overflows, wrappers ``policy_for`` cannot act through, and
one answer for a step that overflows float64 in both environments.

Each test asserts the exception type, the argument's name and the offending value; the checks
that promise "before any solver runs" replace the solvers by a trap.
"""

from __future__ import annotations

import json
import warnings

import cvxpy as cp
import gymnasium as gym
import numpy as np
import osqp
import pytest

from controllers import (
    LinearFeedbackController,
    MJLSLQRController,
    RecedingHorizonController,
    ScenarioTreeController,
    UnconstrainedRecedingHorizonController,
)
from sdjls_gym import SDJLSModel, SDJLSVectorEnv, load_model
from sdjls_gym.model_files import _to_toml
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro

HUGE = 10**400  # a Python int beyond float64 (1.8e308)


@pytest.fixture
def no_solver(monkeypatch):
    """Fail the test if OSQP or cvxpy is asked to solve anything."""

    def trap(*args, **kwargs):
        raise AssertionError("a solver ran before the input was checked")

    monkeypatch.setattr(osqp.OSQP, "solve", trap)
    monkeypatch.setattr(cp.Problem, "solve", trap)


def raises(error, match, call):
    """``call()`` raises ``error`` matching ``match``, with no warning on the way."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(error, match=match) as info:
            call()
    return info.value


# ------------------------------------------------------------------------- a. bools as indices
CONTROLLERS = {
    "linear": lambda: LinearFeedbackController(macro(), PAPER_K),
    "mjls-lq": lambda: MJLSLQRController(macro()),
    "rhc": lambda: RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC),
    "rhc-cvxpy": lambda: RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC, solver="cvxpy"),
    "unconstrained": lambda: UnconstrainedRecedingHorizonController(
        macro(), PAPER_K, PAPER_RHC["Psi"], nu_bound=PAPER_RHC["nu_bound"]
    ),
    "tree": lambda: ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=2),
}

BOOL_INDICES = {
    "mode-list": ([0, True], 0, r"^mode\[1\] = True is a bool"),
    "mode-tuple-numpy-bool": ((np.True_, 0), [1, 2], r"^mode\[0\] = np\.True_ is a bool"),
    "k-list": ([0, 1], [True, 2], r"^k\[0\] = True is a bool"),
    "k-scalar": ([0, 1], False, r"^k = False is a bool"),
    "mode-float-in-list": ([0, 1.0], 0, r"^mode\[1\] = 1\.0 is a float"),
}


@pytest.mark.parametrize("which", list(CONTROLLERS))
@pytest.mark.parametrize("case", list(BOOL_INDICES))
def test_act_batch_refuses_a_bool_among_modes_or_times(which, case, no_solver):
    """numpy reads ``[0, True]`` as ``[0, 1]``: every controller's act_batch refuses it, by
    entry, before any solver runs (README: a bool is never a number)."""
    ctrl = CONTROLLERS[which]()
    modes, k, match = BOOL_INDICES[case]
    raises(TypeError, match, lambda: ctrl.act_batch(np.ones((2, 2)), modes, k))


def test_model_band_refuses_a_bool_among_times():
    raises(TypeError, r"^k\[0\] = True is a bool", lambda: macro().H([True, 2]))
    np.testing.assert_array_equal(macro().H([1, 2]), macro().H(np.array([1, 2])))


# ------------------------------------------------------------------ b. ints beyond float64
def _model_file(tmp_path, suffix):
    data = {**macro().to_dict(), "x0": [0.0, 0.0]}
    if suffix == ".json":
        text = json.dumps(data).replace('"x0": [0.0', f'"x0": [{HUGE}')
    else:
        text = _to_toml(data).replace("x0 = [0.0", f"x0 = [{HUGE}")
    path = tmp_path / f"huge{suffix}"
    path.write_text(text, encoding="utf-8")
    return path


def _stepped_env():
    env = gym.make("SDJLS-Macro-v0")
    env.reset(seed=0)
    return env


def _stepped_vector_env():
    envs = SDJLSVectorEnv(2, model=macro())
    envs.reset(seed=0)
    return envs


HUGE_INTS = {
    "env-step": (lambda _: _stepped_env().step([HUGE]), r"^action has an entry 1000"),
    "env-step-negative": (lambda _: _stepped_env().step([-HUGE]), r"^action has an entry -1000"),
    "env-step-array": (
        lambda _: _stepped_env().step(np.array([HUGE], dtype=object)),
        r"^action has an entry 1000",
    ),
    "vector-step": (
        lambda _: _stepped_vector_env().step([[0.0], [HUGE]]),
        r"^actions has an entry 1000.* at index \(1, 0\)",
    ),
    "act": (
        lambda _: RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC).act([0.0, HUGE], 0, 0),
        r"^x has an entry 1000.* at index \(1,\)",
    ),
    "act-batch": (
        lambda _: LinearFeedbackController(macro(), PAPER_K).act_batch([[HUGE, 0.0]], [0], 0),
        r"^x has an entry 1000.* at index \(0, 0\)",
    ),
    "predict": (
        lambda _: LinearFeedbackController(macro(), PAPER_K).predict([HUGE, 0, 1, 0, 0, 0]),
        r"^observation has an entry 1000",
    ),
    "model-x0": (
        lambda _: SDJLSModel(**{**macro().to_dict(), "x0": [HUGE, 0]}),
        r"^x0 has an entry 1000",
    ),
    "model-A": (
        lambda _: SDJLSModel(**{**macro().to_dict(), "A": [[1.0, 0.0], [0.0, -HUGE]]}),
        r"^A has an entry -1000.* at index \(1, 1\)",
    ),
    "reset-x0": (
        lambda _: gym.make("SDJLS-Macro-v0").reset(options={"x0": [0, HUGE]}),
        r"^options\['x0'\] has an entry 1000",
    ),
    "action-bound": (
        lambda _: gym.make("SDJLS-Macro-v0", action_bound=[HUGE]),
        r"^action_bound has an entry 1000",
    ),
    "json-file": (
        lambda tmp: load_model(_model_file(tmp, ".json")),
        r"^model file .*huge\.json': x0 has an entry 1000",
    ),
    "toml-file": (
        lambda tmp: load_model(_model_file(tmp, ".toml")),
        r"^model file .*huge\.toml': x0 has an entry 1000",
    ),
}


@pytest.mark.parametrize("case", list(HUGE_INTS))
def test_an_int_beyond_float64_is_a_value_error_naming_the_argument(case, tmp_path, no_solver):
    """``10**400`` is a ValueError naming the argument and showing the value, as ``1e400`` is,
    not numpy's bare OverflowError."""
    call, match = HUGE_INTS[case]
    error = raises(ValueError, match, lambda: call(tmp_path))
    assert "beyond the range of float64" in str(error) and "about 10**400" in str(error)
