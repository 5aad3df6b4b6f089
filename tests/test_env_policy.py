"""controllers.policy_for: a controller driving a wrapped environment (the RescaleAction trap)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from conftest import raises_naming
from gymnasium.wrappers import ClipAction, RescaleAction, TransformObservation

from controllers import (
    LinearFeedbackController,
    RecedingHorizonController,
    policy_for,
)
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro
from sdjls_gym.wrappers import ResidualAction


def episode(env, policy, seed=0):
    obs, info = env.reset(seed=seed)
    us, done = [], False
    while not done:
        action, _ = policy.predict(obs)
        obs, _, terminated, truncated, info = env.step(action)
        us.append(info["u"])
        done = terminated or truncated
    return np.array(us), info


@pytest.mark.parametrize("make", [lambda: RescaleAction(gym.make("SDJLS-Macro-v0"), -1.0, 1.0),
                                  lambda: ClipAction(RescaleAction(gym.make("SDJLS-Macro-v0"), -1.0, 1.0)),
                                  lambda: RescaleAction(RescaleAction(gym.make("SDJLS-Macro-v0"), -1.0, 1.0), 0.0, 5.0)])  # fmt: skip
def test_policy_for_a_rescaled_env_applies_the_controllers_inputs(make):
    """Through policy_for the wrapped env receives the controller's u and the episode is the raw
    env's, to the float32 resolution of an action in [-1, 1] (200 * 6e-8 per step, compounded
    over 20 steps of a feedback loop); predict alone would be scaled by 200."""
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC, horizon=20)
    raw_us, raw_info = episode(gym.make("SDJLS-Macro-v0"), ctrl)
    env = make()
    us, info = episode(env, policy_for(ctrl, env))
    np.testing.assert_allclose(us, raw_us, rtol=0, atol=5e-4)
    assert info["k"] == raw_info["k"] == 20 and not info["diverged"]
    # the trap policy_for avoids: predict's raw u fed to the rescaled env
    env = make()
    trap_us, _ = episode(env, ctrl)
    assert np.max(np.abs(trap_us)) > 10 * np.max(np.abs(raw_us))


def test_policy_for_decodes_time_with_the_envs_horizon():
    """A 40-step env: the controller built without horizon decodes k with the env's horizon."""
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    env = RescaleAction(gym.make("SDJLS-Macro-v0", horizon=40), -1.0, 1.0)
    policy = policy_for(ctrl, env)
    obs, info = env.reset(seed=1)
    for _ in range(25):
        action, _ = policy.predict(obs)
        u_expected = ctrl.act(info["state"], info["mode"], info["k"])[0]
        obs, _, _, _, info = env.step(action)
        np.testing.assert_allclose(info["u"], u_expected, rtol=1e-5, atol=1e-5)
    assert info["k"] == 25


def test_policy_for_refuses_what_it_cannot_undo():
    ctrl = LinearFeedbackController(macro(), PAPER_K)
    base = gym.make("SDJLS-Macro-v0")
    with raises_naming(ValueError, "env", "TransformObservation"):
        policy_for(ctrl, TransformObservation(base, lambda o: 2 * o, base.observation_space))
    with raises_naming(ValueError, "env", "ResidualAction"):
        policy_for(ctrl, ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K))
    other = gym.make("SDJLS-Macro-v0").unwrapped.model
    with raises_naming(ValueError, ("env's model", "controller's model"), other):
        policy_for(
            LinearFeedbackController(
                other.__class__(**{**other.to_dict(), "x0": [1.0, 1.0]}), PAPER_K
            ),
            base,
        )
    with raises_naming(ValueError, "env", "CartPoleEnv"):
        policy_for(ctrl, gym.make("CartPole-v1"))
    with raises_naming(TypeError, "controller", 3):
        policy_for(3, base)
    with raises_naming(TypeError, "env", "SDJLS-Macro-v0"):
        policy_for(ctrl, "SDJLS-Macro-v0")


def test_pass_through_names_name_the_projects_wrappers():
    """The controllers match this project's pass-through wrappers by module and class name (so
    that they never import the environments): each name must be the class's own."""
    import importlib

    from controllers.env_policy import PASS_THROUGH_NAMES

    ours = [path for path in PASS_THROUGH_NAMES if path.startswith("sdjls_gym.")]
    assert len(ours) == 3
    for path in ours:
        module, _, name = path.rpartition(".")
        cls = getattr(importlib.import_module(module), name)
        assert f"{cls.__module__}.{cls.__qualname__}" == path


def test_policy_for_recognizes_an_sdjls_env_by_its_model_and_horizon():
    """An environment underneath without an ``SDJLSModel`` model and an int horizon is refused,
    one with them (an ``SDJLSEnv``) is driven."""
    ctrl = LinearFeedbackController(macro(), PAPER_K)
    env = gym.make("SDJLS-Macro-v0")
    assert policy_for(ctrl, env).horizon == 20
    env.unwrapped.horizon = 20.0  # not an int: not an SDJLS environment any more
    # known gap: "env is a SDJLSEnv underneath; expected an SDJLS environment" names neither
    # horizon nor its value 20.0
    with raises_naming(ValueError, "env", "SDJLSEnv"):
        policy_for(ctrl, env)
