"""The hidden mode as a setting of every task: ``observe="state"`` in the observation layout, the
single and the vector environment, the registered ids, the wrappers, and the controllers that
refuse an observation without the mode."""

from __future__ import annotations

import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
from conftest import raises_naming
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from gymnasium.wrappers import RescaleAction
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sdjls_gym
from controllers import LinearFeedbackController, ModeNotObservedError, policy_for
from sdjls_gym import SDJLSEnv, SDJLSVectorEnv
from sdjls_gym.observation import (
    decode_observation,
    encode_observation,
    observation_size,
    observation_space,
)
from sdjls_gym.systems import TASKS
from sdjls_gym.systems.macro import PAPER_K
from sdjls_gym.wrappers import ResidualAction, ScaleObservationReward

SUITE = sdjls_gym.SUITE
ALLOWED = re.compile(r"symmetric and normalized (Box action )?space")


def _make(env_id: str, **kwargs):
    return gym.make(env_id, **{**TASKS[env_id].env_kwargs, **kwargs})


def _messages(record):
    return [f"{w.category.__name__}: {w.message}" for w in record]


# ----------------------------------------------------------------------------- the layout
def test_layouts_and_spaces_of_both_settings():
    model = sdjls_gym.macro()  # n = 2, N = 3
    assert observation_size(model) == observation_size(model, "mode") == 6
    assert observation_size(model, "state") == 3
    space = observation_space(model, 50.0, "state")
    assert space.shape == (3,) and space.dtype == np.float32
    np.testing.assert_array_equal(space.low, [-50.0, -50.0, 0.0])
    np.testing.assert_array_equal(space.high, [50.0, 50.0, 1.0])


def test_encode_and_decode_a_state_only_observation_one_state_and_a_batch():
    """``[clip(x), k / horizon]``, the same values on the single path and the batched one
    (clipping at the bound, NaN at +bound, as for the default layout); decode gives mode None."""
    model = sdjls_gym.macro()
    x = np.array([[1.5, -3.0], [np.inf, np.nan], [-np.inf, 2.0]])
    batch = encode_observation(model, x, np.array([0, 1, 2]), np.array([0, 5, 20]), 20, 10.0,
                               observe="state")  # fmt: skip
    np.testing.assert_array_equal(batch, [[1.5, -3.0, 0.0], [10.0, 10.0, 0.25], [-10, 2.0, 1.0]])
    for row, k in zip(range(3), (0, 5, 20), strict=True):
        one = encode_observation(model, x[row], row, k, 20, 10.0, "state")
        np.testing.assert_array_equal(one, batch[row])
        assert one.dtype == np.float32
    xs, mode, ks = decode_observation(model, batch, 20, observe="state")
    assert mode is None and ks.tolist() == [0, 5, 20]
    np.testing.assert_array_equal(xs[0], [1.5, -3.0])
    # the default layout of the same states keeps the one-hot
    full = encode_observation(model, x, np.array([0, 1, 2]), np.array([0, 5, 20]), 20, 10.0)
    np.testing.assert_array_equal(full[:, [0, 1, 5]], batch)
    np.testing.assert_array_equal(full[:, 2:5], np.eye(3))


def test_decode_refuses_the_other_layouts_size():
    model = sdjls_gym.macro()
    with raises_naming(ValueError, "observation", (6,)):
        decode_observation(model, np.zeros(6), 20, observe="state")
    with raises_naming(ValueError, "observation", (3,)):
        decode_observation(model, np.zeros(3), 20)


# ----------------------------------------------------------------------------- every task
@pytest.mark.parametrize("env_id", SUITE)
def test_every_task_runs_with_the_mode_hidden_and_passes_the_checkers(env_id):
    """``gym.make(env_id, observe="state")``: observations ``[x, k / horizon]`` of the info's
    state, in the space; the info keeps the true mode. Gymnasium's checker gives no warning and
    SB3's only its advice to normalize the action space (as for the default)."""
    model = TASKS[env_id].model
    env = _make(env_id, observe="state")
    assert env.unwrapped.observe == "state"
    assert env.observation_space.shape == (model.n + 1,)
    obs, info = env.reset(seed=3)
    horizon = env.unwrapped.horizon
    for _ in range(horizon):
        assert env.observation_space.contains(obs)
        np.testing.assert_array_equal(obs[:-1], info["state"].astype(np.float32))
        assert obs[-1] == np.float32(info["k"] / horizon)
        assert isinstance(info["mode"], int) and 0 <= info["mode"] < model.N
        obs, _, terminated, truncated, info = env.step(env.action_space.sample() * 0)
        if terminated or truncated:
            break
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        gymnasium_check_env(env.unwrapped)
        sb3_check_env(env)
        sb3_check_env(
            RescaleAction(_make(env_id, observe="state"), np.float32(-1.0), np.float32(1.0))
        )
    assert [m for m in _messages(record) if not ALLOWED.search(m)] == []


@pytest.mark.parametrize("env_id", SUITE)
def test_the_vector_env_hides_the_mode_too(env_id):
    """``gym.make_vec(env_id, observe="state")`` (native): ``(num_envs, n + 1)`` observations of
    the infos' states and times, the single env's space, the true modes in the infos."""
    model = TASKS[env_id].model
    envs = gym.make_vec(env_id, num_envs=4, vectorization_mode="vector_entry_point",
                        observe="state")  # fmt: skip
    assert isinstance(envs, SDJLSVectorEnv)
    assert envs.single_observation_space == _make(env_id, observe="state").observation_space
    obs, infos = envs.reset(seed=0)
    for _ in range(3):
        assert obs.shape == (4, model.n + 1) and envs.observation_space.contains(obs)
        np.testing.assert_array_equal(obs[:, :-1], infos["state"].astype(np.float32))
        np.testing.assert_array_equal(obs[:, -1], (infos["k"] / envs.horizon).astype(np.float32))
        assert infos["mode"].shape == (4,)
        obs, _, _, _, infos = envs.step(np.zeros((4, model.m)))


@pytest.mark.parametrize("observe", ["mode", "state"])
def test_the_same_seed_gives_the_same_episode_in_both_settings(observe):
    """The setting changes the observation only: states, modes, rewards and infos are those of
    the default with the same seed and actions, and the default's observation is unchanged."""
    default, other = gym.make("SDJLS-VTOL-v0"), gym.make("SDJLS-VTOL-v0", observe=observe)
    obs_a, info_a = default.reset(seed=11)
    obs_b, info_b = other.reset(seed=11)
    rng = np.random.default_rng(0)
    for _ in range(10):
        keep = np.r_[0:4, -1] if observe == "state" else slice(None)
        np.testing.assert_array_equal(obs_a[keep], obs_b)
        np.testing.assert_array_equal(info_a["state"], info_b["state"])
        assert info_a["mode"] == info_b["mode"]
        u = rng.uniform(-1, 1, 2).astype(np.float32)
        obs_a, r_a, *_, info_a = default.step(u)
        obs_b, r_b, *_, info_b = other.step(u)
        assert r_a == r_b


@pytest.mark.parametrize("env_id", ["SDJLS-v0", "SDJLS-Macro-v0", "SDJLS-Random-v0"])
def test_a_bad_observe_is_refused_by_name(env_id):
    kwargs = {"model": "macro"} if env_id == "SDJLS-v0" else {}
    with raises_naming(ValueError, "observe", "belief"):
        gym.make(env_id, observe="belief", **kwargs)
    with raises_naming(TypeError, "observe", 1):
        gym.make(env_id, observe=1, **kwargs)
    with raises_naming(ValueError, "observe", "hidden"):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point",
                     observe="hidden", **kwargs)  # fmt: skip


def test_the_setting_is_in_the_spec_and_remakes_the_same_env():
    env = gym.make("SDJLS-Random-v0", n=4, system_seed=2, observe="state")
    assert env.observation_space.shape == (5,)
    again = gym.make(env.spec)
    assert again.unwrapped.observe == "state" and again.observation_space == env.observation_space
    assert SDJLSEnv(model="macro").observe == "mode"


# ----------------------------------------------------------------------------- wrappers
def test_scale_observation_reward_keeps_the_state_only_layout():
    env = ScaleObservationReward(gym.make("SDJLS-Macro-v0", observe="state"))
    obs, info = env.reset(seed=0)
    assert env.observation_space.shape == (3,) and env.observation_space.contains(obs)
    np.testing.assert_allclose(obs, [*(info["state"] / 10.0), 0.0], rtol=1e-6)
    obs, *_ = env.step(np.zeros(1, dtype=np.float32))
    assert env.observation_space.contains(obs) and obs[-1] == np.float32(1 / 20)


def test_residual_action_with_the_mode_hidden_takes_one_gain_for_every_mode():
    """Gains that differ by mode would read the hidden mode: refused; the same gain repeated
    is applied as ``u = K_0 x + nu`` whatever the mode."""
    with raises_naming(ModeNotObservedError, "observe", "state") as excinfo:
        ResidualAction(gym.make("SDJLS-Macro-v0", observe="state"), PAPER_K)
    assert isinstance(excinfo.value, ValueError) and "ModeFilter" in str(excinfo.value)
    K = np.stack([PAPER_K[1]] * 3)
    env = ResidualAction(gym.make("SDJLS-Macro-v0", observe="state"), K)
    _, info = env.reset(seed=0)
    for _ in range(5):
        x = info["state"]
        _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
        np.testing.assert_allclose(info["u"], np.clip(PAPER_K[1] @ x + 0.5, -200, 200))


# ----------------------------------------------------------------------------- controllers
def test_controllers_refuse_an_observation_without_the_mode():
    """``predict`` (and a policy_for policy) on a state-only observation: ModeNotObservedError
    (a ValueError) naming the observation's shape and ModeFilter, never a misread."""
    env = gym.make("SDJLS-Macro-v0", observe="state")
    controller = LinearFeedbackController(env.unwrapped.model, PAPER_K)
    obs, _ = env.reset(seed=0)
    for call in (controller.predict, policy_for(controller, env).predict):
        for given in (obs, np.stack([obs, obs])):
            with raises_naming(ModeNotObservedError, "observation", given.shape) as excinfo:
                call(given)
            assert "ModeFilter" in str(excinfo.value)
    with raises_naming(ValueError, "observation", (4,)):  # another size: the usual error
        controller.predict(np.zeros(4))
