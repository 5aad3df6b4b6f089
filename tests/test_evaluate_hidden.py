"""Scoring with the mode hidden (``env_kwargs={"observe": "state"}``): the protocol never hands
the true mode to a policy; a controller that asks for it is refused by name, a hidden-mode policy
keeps its filter across an episode, an agent gets the state-only observations."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import RescaleAction

import sdjls_gym  # noqa: F401  (registers the ids)
from benchmarks.evaluate import RawEnvPolicy, evaluate
from controllers import HiddenModePolicy, LinearFeedbackController, RecedingHorizonController
from sdjls_gym.systems import TASKS
from sdjls_gym.wrappers import ScaleObservationReward

TASK = TASKS["SDJLS-Degradation-v0"]
HIDDEN = {"observe": "state"}


def _rhc() -> RecedingHorizonController:
    return RecedingHorizonController(TASK.model, TASK.K, horizon=TASK.horizon, **TASK.rhc)


def test_a_hidden_mode_policy_is_scored_with_the_mode_hidden_on_its_models_task():
    score = evaluate(HiddenModePolicy(_rhc()), episodes=20, seed=1)
    assert score.env_id == TASK.env_id and score.diverged == 0
    assert score.curve_gap is not None  # against the oracle's curve: the RHC with the true mode
    assert score.decision_time_batched_s > 0 and score.decision_time_single_s > 0


def test_a_controller_that_reads_the_mode_is_refused_when_it_is_hidden():
    with pytest.raises(ValueError, match="HiddenModePolicy") as exc:
        evaluate(_rhc(), env_kwargs=HIDDEN, episodes=4)
    assert "observe = 'state'" in str(exc.value)


def test_the_hidden_and_the_observed_setting_share_their_noise():
    """A policy that never reads the mode scores the same episodes in both settings: the
    hidden setting changes what a policy sees, not the system."""
    zero = LinearFeedbackController(TASK.model, np.zeros_like(TASK.K))
    observed = evaluate(zero, episodes=10, seed=3)
    hidden = evaluate(HiddenModePolicy(zero), episodes=10, seed=3)
    assert np.array_equal(observed.episode_costs, hidden.episode_costs)


def test_an_agent_sees_the_state_only_observation():
    seen: list[tuple[int, ...]] = []

    class Agent:
        observation_space = gym.make(TASK.env_id, observe="state").observation_space
        action_space = gym.make(TASK.env_id).action_space

        def predict(self, obs, deterministic=True):
            seen.append(np.shape(obs))
            return np.zeros((len(obs), 1), dtype=np.float32), None

    evaluate(Agent(), env_id=TASK.env_id, env_kwargs=HIDDEN, episodes=4)
    assert seen and all(shape[-1] == TASK.model.n + 1 for shape in seen)


def test_an_agent_trained_with_the_mode_hidden_keeps_its_setting():
    class Zero:
        def __init__(self, env):
            self.observation_space, self.action_space = env.observation_space, env.action_space

        def predict(self, obs, deterministic=True):
            assert obs.shape[-1] == TASK.model.n + 1  # never the mode
            return np.zeros((len(obs), 1), dtype=np.float32), None

    hidden_env = ScaleObservationReward(
        RescaleAction(gym.make(TASK.env_id, observe="state"), -1, 1)
    )
    score = evaluate(RawEnvPolicy(Zero(hidden_env), hidden_env), episodes=4)
    assert score.env_id == TASK.env_id
    observed_env = ScaleObservationReward(RescaleAction(gym.make(TASK.env_id), -1, 1))
    with pytest.raises(ValueError, match="observe"):
        evaluate(RawEnvPolicy(Zero(observed_env), observed_env), env_kwargs=HIDDEN, episodes=4)
