"""The training wrappers of ``sdjls_gym.wrappers`` (ScaleObservationReward, TerminateOutside,
FiniteHorizon), checked against hand computations."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from conftest import raises_naming

from sdjls_gym import wrappers as W


def test_scale_observation_clips_the_state_only():
    obs = np.array([[1e6, -5.0, 0.0, 1.0, 0.0, 0.5]], dtype=np.float32)
    out = W.scale_observation(obs, 2, 10.0, 10.0)
    np.testing.assert_allclose(out, [[10.0, -0.5, 0.0, 1.0, 0.0, 0.5]])
    assert out.dtype == np.float32 and obs[0, 0] == 1e6  # a copy


def test_scale_observation_reward_defaults_are_the_comparisons_and_log_the_cost():
    env = W.ScaleObservationReward(gym.make("SDJLS-Macro-v0"))
    assert (env.x_scale, env.obs_clip, env.reward_scale) == (W.X_SCALE, W.OBS_CLIP, W.REWARD_SCALE)
    assert env.reward_transform == "log"
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs, [0.2, 0.2, 1.0, 0.0, 0.0, 0.0])  # x0 = (2, 2), mode 0
    assert env.observation_space.contains(obs)
    _, reward, _, _, info = env.step(np.array([5.0], dtype=np.float32))
    assert reward == pytest.approx(-np.log1p(-info["reward_raw"] / W.REWARD_SCALE), rel=1e-12)
    linear = W.ScaleObservationReward(gym.make("SDJLS-Macro-v0"), reward_transform="linear",
                                      reward_clip=10.0)  # fmt: skip
    linear.reset(seed=0)
    _, reward, _, _, info = linear.step(np.array([5.0], dtype=np.float32))
    assert reward == max(info["reward_raw"], -10.0) / W.REWARD_SCALE


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"x_scale": 0.0}, ValueError),
        ({"obs_clip": float("nan")}, ValueError),
        ({"reward_scale": "100"}, TypeError),
        ({"reward_clip": True}, TypeError),
        ({"reward_transform": "exp"}, ValueError),
    ],
)
def test_scale_observation_reward_rejects_bad_arguments(kwargs, error):
    [(name, value)] = kwargs.items()
    with raises_naming(error, name, value):
        W.ScaleObservationReward(gym.make("SDJLS-Macro-v0"), **kwargs)


def test_training_wrappers_need_an_sdjls_env():
    for wrapper in (W.ScaleObservationReward, W.TerminateOutside):
        with raises_naming(TypeError, (wrapper.__name__, "SDJLSEnv"), "PendulumEnv"):
            wrapper(gym.make("Pendulum-v1"))
    with raises_naming(ValueError, "bound", -1.0):
        W.TerminateOutside(gym.make("SDJLS-Macro-v0"), -1.0)


def test_terminate_outside_charges_the_rest_of_the_horizon():
    """The open loop (u = 0) from x0 = (0, 60) in the slump mode leaves |x| <= 100 at once:
    the episode ends at k = 1 with the step's reward times the 20 steps left (k = 1..20)."""
    env = W.TerminateOutside(gym.make("SDJLS-Macro-v0"), 100.0)
    env.reset(seed=0, options={"x0": [0.0, 60.0], "mode0": 2})
    _, reward, terminated, truncated, info = env.step(np.array([0.0], dtype=np.float32))
    assert np.max(np.abs(info["state"])) > 100.0 and terminated and not truncated
    plain = gym.make("SDJLS-Macro-v0")
    plain.reset(seed=0, options={"x0": [0.0, 60.0], "mode0": 2})
    _, raw, _, _, _ = plain.step(np.array([0.0], dtype=np.float32))
    assert reward == pytest.approx(raw * 20, rel=1e-12)


def test_finite_horizon_turns_the_last_truncation_into_a_termination():
    env = W.FiniteHorizon(gym.make("SDJLS-Macro-v0"))
    env.reset(seed=0)
    ends = []
    for _ in range(20):
        _, _, terminated, truncated, _ = env.step(np.array([0.0], dtype=np.float32))
        ends.append((terminated, truncated))
        if terminated:
            break
    assert ends[-1] == (True, False) and all(not t for t, _ in ends[:-1])
