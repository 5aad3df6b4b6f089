"""A controller for a user's own model in one call, and constructors that show their settings.

``RecedingHorizonController.from_model(model, xi=...)`` (and the scenario tree's) synthesizes
``K`` by Proposition 2 and takes the MJLS LQ value matrices as ``Psi``: the recipe the suite's
tasks state for their committed data (``sdjls_gym.systems``), which is what these
tests hold it against.
"""

from __future__ import annotations

import inspect
import logging
import typing
from pathlib import Path

import numpy as np
import pytest

from controllers import (
    BeliefRecedingHorizonController,
    RecedingHorizonController,
    ScenarioTreeController,
    UnconstrainedRecedingHorizonController,
)
from controllers.design import design_from_model
from controllers.horizon import HorizonKwargs, RecedingHorizonBase
from sdjls_gym import SDJLSModel
from sdjls_gym.errors import LMIInfeasibleError
from sdjls_gym.systems import TASKS

#: The tasks whose modules say: K from synthesize_gains to 4 decimals, Psi the coupled-Riccati
#: solution with P_in to 4 significant digits.
RECIPE_TASKS = ("SDJLS-Solar-v0", "SDJLS-VTOL-v0", "SDJLS-ThreeState-v0", "SDJLS-Degradation-v0")
SETTINGS = ("Psi", "xi", "constraint", "alpha", "nu_bound", "solver", "nu_set", "horizon",
            "osqp_settings", "cvxpy_fallback")  # fmt: skip


@pytest.mark.parametrize("env_id", RECIPE_TASKS)
def test_from_model_follows_the_suites_recipe(env_id):
    task = TASKS[env_id]
    ctrl = RecedingHorizonController.from_model(task.model, xi=0.9, horizon=task.horizon)
    # K rounded to 4 decimals (plus the LMI solver's tolerance), Psi to 4 significant digits
    assert np.max(np.abs(ctrl.K - task.K)) <= 1e-4
    Psi = np.asarray(task.rhc["Psi"])
    assert np.max(np.abs(ctrl.Psi - Psi)) <= 1e-3 * np.max(np.abs(Psi))
    assert ctrl.design.K_source.startswith("Proposition 2")
    assert ctrl.design.Psi_source.startswith("MJLS LQ value matrices")
    assert ctrl.design.gains is not None and ctrl.design.gains.margin < 0
    u, info = ctrl.act(np.asarray(task.model.x0, dtype=float), 0, 0)
    assert info["ok"] and u.shape == (task.model.m,)


def test_from_model_says_what_it_chose_in_a_log_line(caplog):
    with caplog.at_level(logging.INFO, logger="controllers"):
        ctrl = RecedingHorizonController.from_model(TASKS["SDJLS-Solar-v0"].model, xi=0.8)
    assert ctrl.design.summary() in caplog.text
    assert "Proposition 2" in caplog.text and "Psi" in caplog.text


def test_the_tree_and_the_unconstrained_controller_have_from_model_too():
    model = TASKS["SDJLS-Macro-v0"].model
    tree = ScenarioTreeController.from_model(model, xi=0.85, steps=2)
    assert isinstance(tree, ScenarioTreeController) and tree.steps == 2
    assert tree.act(np.array([2.0, 2.0]), 0, 0)[1]["ok"]
    free = UnconstrainedRecedingHorizonController.from_model(model, xi=0.85)
    assert free.act(np.array([2.0, 2.0]), 0, 0)[1]["rho"] == 0.0


def test_given_gains_and_weights_are_used_as_they_are():
    task = TASKS["SDJLS-Degradation-v0"]
    Psi = np.array([np.eye(2)] * 2)
    ctrl = RecedingHorizonController.from_model(task.model, xi=0.9, K=task.K, Psi=Psi)
    assert np.array_equal(ctrl.K, task.K) and np.array_equal(ctrl.Psi, Psi)
    assert ctrl.design.K_source == "given" and ctrl.design.Psi_source == "given"


def _with(env_id: str, **fields) -> SDJLSModel:
    data = TASKS[env_id].model.to_dict()
    data.update(fields)
    return SDJLSModel.from_dict(data)


def test_a_semidefinite_lq_solution_falls_back_to_the_lyapunov_matrices():
    model = _with("SDJLS-Degradation-v0", Q=[np.zeros((2, 2))] * 2)  # X_i = 0: no weight
    ctrl = RecedingHorizonController.from_model(model, xi=0.9)
    assert ctrl.design.Psi_source.startswith("Proposition 2's Lyapunov matrices")
    assert "not positive definite" in ctrl.design.Psi_source
    assert np.allclose(ctrl.Psi, ctrl.design.gains.P)
    assert np.all(np.linalg.eigvalsh(ctrl.Psi) > 0)


def test_the_lyapunov_rule_on_request():
    ctrl = RecedingHorizonController.from_model(TASKS["SDJLS-Solar-v0"].model, xi=0.9,
                                                psi="lyapunov")  # fmt: skip
    assert ctrl.design.Psi_source == "Proposition 2's Lyapunov matrices P_i = X_i^{-1}"


def test_an_unstabilizable_model_is_a_clear_error_that_says_to_pass_K():
    model = _with("SDJLS-Solar-v0", A=[[[1.5]], [[1.2]]], B=[[[0.0]], [[0.0]]])  # u does nothing
    with pytest.raises(LMIInfeasibleError, match="K="):
        RecedingHorizonController.from_model(model, xi=0.9)


def test_a_bad_rule_names_psi():
    with pytest.raises(ValueError, match="psi"):
        design_from_model(TASKS["SDJLS-Solar-v0"].model, psi="riccati")


@pytest.mark.parametrize(
    "cls",
    [
        RecedingHorizonController,
        UnconstrainedRecedingHorizonController,
        ScenarioTreeController,
        BeliefRecedingHorizonController,
    ],
)
def test_the_constructors_name_every_setting_with_its_default(cls):
    params = inspect.signature(cls).parameters
    assert not any(p.kind is p.VAR_KEYWORD for p in params.values())
    for name in SETTINGS:
        assert name in params and params[name].kind is params[name].KEYWORD_ONLY, name
        assert params[name].annotation is not inspect.Parameter.empty, name
    assert params["Psi"].default is inspect.Parameter.empty  # required
    assert params["alpha"].default == 1000.0 and params["solver"].default == "daqp"


def test_the_typed_settings_are_the_base_constructors():
    """``HorizonKwargs`` (the subclasses' ``**settings``) has the names and types of
    ``RecedingHorizonBase.__init__``'s keyword settings."""
    hints = typing.get_type_hints(RecedingHorizonBase.__init__)
    params = inspect.signature(RecedingHorizonBase.__init__).parameters.values()
    settings = [p.name for p in params if p.kind is p.KEYWORD_ONLY]
    assert settings == list(SETTINGS)
    assert typing.get_type_hints(HorizonKwargs) == {name: hints[name] for name in settings}


WRONG_CALLS = """
import numpy as np
from controllers import BeliefRecedingHorizonController, ScenarioTreeController
from sdjls_gym.systems.macro import PAPER_K, macro

ScenarioTreeController(macro(), PAPER_K, Psi=np.eye(2), xi=0.9, alpha="1000")
BeliefRecedingHorizonController(macro(), PAPER_K, Psi=np.eye(2), xi=0.9, alpah=1.0)
ScenarioTreeController(macro(), PAPER_K, steps=2, xi=0.9)
ScenarioTreeController(macro(), PAPER_K, Psi=np.eye(2), xi=0.9, steps=2)
"""


@pytest.mark.slow
def test_a_type_checker_checks_every_setting_of_a_subclass(tmp_path):
    """mypy sees a wrong type, a misspelt name and a missing ``Psi`` in the calls of the
    constructors that take ``**settings: Unpack[HorizonKwargs]`` (the project's configuration and
    cache: a few seconds after ``mypy sdjls_gym controllers benchmarks``)."""
    api = pytest.importorskip("mypy.api")
    root = Path(__file__).resolve().parents[1]
    snippet = tmp_path / "calls.py"
    snippet.write_text(WRONG_CALLS, encoding="utf-8")
    out, _, _ = api.run([
        "--config-file", str(root / "pyproject.toml"),
        "--cache-dir", str(root / ".mypy_cache"),
        "--no-error-summary", "--hide-error-context", str(snippet),
    ])  # fmt: skip
    errors = [line.split(": error: ")[1] for line in out.splitlines() if ": error: " in line]
    lines = [int(line.split(":")[1]) for line in out.splitlines() if ": error: " in line]
    assert lines == [6, 7, 8], out
    assert '"alpha"' in errors[0] and '"str"' in errors[0] and '"float"' in errors[0]
    assert '"alpah"' in errors[1] and '"Psi"' in errors[2]
