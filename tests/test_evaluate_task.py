"""Which task ``evaluate`` scores a policy on, and policies and tasks a user brings.

A controller is scored on the task of its own model, an agent wrapped in ``RawEnvPolicy`` on its
training environment's id, a policy and its ``env=`` on that environment; a policy that names no
task goes to the paper's task, and where it does not fit, the error names ``env_id``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import RescaleAction

import sdjls_gym  # noqa: F401  (registers the ids)
from benchmarks.evaluate import RawEnvPolicy, evaluate
from benchmarks.suite import check_tasks, evaluate_suite
from controllers import LinearFeedbackController, RecedingHorizonController
from sdjls_gym import SDJLSModel
from sdjls_gym.systems import TASKS, Task
from sdjls_gym.wrappers import ScaleObservationReward

VTOL = TASKS["SDJLS-VTOL-v0"]


class Zero:
    """An agent acting on ``space`` that always answers 0 (in its own units)."""

    def __init__(self, env: gym.Env) -> None:
        self.observation_space, self.action_space = env.observation_space, env.action_space

    def predict(self, obs, deterministic=True):
        return np.zeros((len(obs), self.action_space.shape[0]), dtype=np.float32), None


def _wrapped(env_id: str) -> gym.Env:
    return ScaleObservationReward(RescaleAction(gym.make(env_id), -1.0, 1.0))


def test_a_controller_is_scored_on_its_models_task():
    score = evaluate(LinearFeedbackController(VTOL.model, VTOL.K), episodes=4)
    assert score.env_id == "SDJLS-VTOL-v0" and score.steps == VTOL.horizon


def test_a_raw_env_policy_is_scored_on_its_training_environments_task():
    env = _wrapped("SDJLS-VTOL-v0")
    score = evaluate(RawEnvPolicy(Zero(env), env), episodes=4)
    assert score.env_id == "SDJLS-VTOL-v0"


def test_an_agent_with_its_wrapped_env_is_scored_on_the_raw_environment():
    env = _wrapped("SDJLS-VTOL-v0")
    zero = evaluate(Zero(env), env=env, episodes=4, seed=3)
    assert zero.env_id == "SDJLS-VTOL-v0"
    # a = 0 in [-1, 1] is u = 0: the same episodes as a controller that applies u = 0
    same = evaluate(LinearFeedbackController(VTOL.model, np.zeros_like(VTOL.K)), episodes=4,
                    seed=3)  # fmt: skip
    assert np.allclose(zero.episode_costs, same.episode_costs, rtol=1e-6)


def test_env_and_env_id_together_are_refused():
    env = _wrapped("SDJLS-VTOL-v0")
    with pytest.raises(ValueError, match="env_id"):
        evaluate(Zero(env), env=env, env_id="SDJLS-VTOL-v0", episodes=4)


def test_an_agent_that_names_no_task_and_does_not_fit_the_default_names_env_id():
    env = _wrapped("SDJLS-VTOL-v0")
    with pytest.raises(ValueError, match="env_id") as exc:
        evaluate(Zero(env), episodes=4)
    assert "SDJLS-Macro-v0" in str(exc.value)


def test_a_callable_with_the_wrong_number_of_inputs_names_the_task_it_was_scored_on():
    with pytest.raises(ValueError, match="SDJLS-Macro-v0") as exc:
        evaluate(lambda obs: np.zeros(2), episodes=4)
    assert "env_id" in str(exc.value)


def test_a_controller_on_another_systems_env_id_is_refused_naming_env_id():
    with pytest.raises(ValueError, match="env_id = 'SDJLS-Macro-v0'") as exc:
        evaluate(LinearFeedbackController(VTOL.model, VTOL.K), env_id="SDJLS-Macro-v0",
                 episodes=4)  # fmt: skip
    assert "(4, 2, 3)" in str(exc.value)


def _own_model() -> SDJLSModel:
    data = TASKS["SDJLS-Solar-v0"].model.to_dict()
    data["A"] = [[[0.85]], [[0.97]]]  # another system of the solar task's shape
    return SDJLSModel.from_dict(data)


def test_a_controller_of_a_users_own_model_is_scored_on_sdjls_v0_with_that_model():
    model = _own_model()
    ctrl = RecedingHorizonController.from_model(model, xi=0.9, horizon=30)
    score = evaluate(ctrl, episodes=4)
    assert score.env_id == "SDJLS-v0" and score.steps == 30
    assert score.curve_gap is None and "not a task of the suite" in score.curve_gap_reason


def test_evaluate_suite_takes_a_users_task_with_a_model_in_env_kwargs():
    model = _own_model()
    solar = TASKS["SDJLS-Solar-v0"]
    task = Task(env_id="SDJLS-v0", model=model, horizon=50, action_bound=100.0, K=solar.K,
                rhc=dict(solar.rhc), source="a user's system",
                env_kwargs={"model": model, "horizon": 50, "action_bound": 100.0})  # fmt: skip
    assert check_tasks([task, "SDJLS-Solar-v0"]) == (task, solar)
    with pytest.raises(ValueError, match="twice"):
        check_tasks([task, task])
    suite = evaluate_suite(lambda t: LinearFeedbackController(t.model, t.K), tasks=[task],
                           episodes=6)  # fmt: skip
    assert suite.results[0].env_id == "SDJLS-v0" and suite.results[0].scores[0].episodes == 6


class EmptyInfo:
    """A policy with ``act_batch`` whose info is empty (the hostile round's G5)."""

    model = TASKS["SDJLS-Macro-v0"].model

    def act_batch(self, x, mode, k):
        return np.zeros((len(x), 1)), {}

    def act(self, x, mode, k):
        return np.zeros(1), {}


def test_a_controller_whose_info_has_no_cost_is_scored():
    score = evaluate(EmptyInfo(), episodes=4)
    assert np.isfinite(score.cost_mean) and score.env_id == "SDJLS-Macro-v0"


def test_a_controller_answering_without_info_is_a_clear_error():
    class Bare(EmptyInfo):
        def act_batch(self, x, mode, k):
            return np.zeros((len(x), 1))

    with pytest.raises(TypeError, match="act_batch"):
        evaluate(Bare(), episodes=4)
