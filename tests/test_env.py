"""SDJLSEnv: API conformance, determinism, time indexing, info channel, actions, rendering.

Expected values are computed in the tests from the paper's numbers (``conftest.py``) and the
formulas of section 2; the env is only ever compared with those, or with itself.
"""

from __future__ import annotations

import pickle
import re
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from gymnasium.wrappers import RescaleAction
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from sdjls_gym import SDJLSEnv, SDJLSModel, SDJLSVectorEnv

# The action space is u_k itself (section 2), so both checkers' advice to normalize it is
# expected; it is the only warning allowed.
ALLOWED = re.compile(r"symmetric and normalized (Box action )?space")


def _make(name, other_model):
    if name == "macro":
        return gym.make("SDJLS-Macro-v0")
    return gym.make("SDJLS-v0", model=other_model, horizon=7)


def _messages(record):
    return [f"{w.category.__name__}: {w.message}" for w in record]


# --------------------------------------------------------------------------- API conformance


@pytest.mark.parametrize("name", ["macro", "other"])
def test_env_checkers_pass_with_only_the_action_space_advice(name, other_model):
    env = _make(name, other_model)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        gymnasium_check_env(env.unwrapped)
        sb3_check_env(env)
    messages = _messages(record)
    unexpected = [m for m in messages if not ALLOWED.search(m)]
    assert unexpected == []
    # both checkers give that advice once: the filter above is not vacuous
    assert len(messages) == 2


@pytest.mark.parametrize("name", ["macro", "other"])
def test_env_checkers_after_rescale_action_emit_no_warnings(name, other_model):
    """After ``RescaleAction(env, -1.0, 1.0)`` the action-space advice goes away too.

    Two warnings that are Gymnasium's own, not this package's, are kept out: (1) with Python
    float bounds ``RescaleAction`` warns "Box low's precision lowered by casting to float32"
    whenever it is constructed, for any float32 env (Pendulum-v1 too); Gymnasium's checker
    re-makes the wrapped env from its spec, so it is checked with float32 bounds, which build
    the same wrapper without that warning. (2) Gymnasium's checker always notes that a wrapped
    env "is different from the unwrapped version"; that notice is the only one allowed.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # RescaleAction's own warning, see (1)
        env = RescaleAction(_make(name, other_model), -1.0, 1.0)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        sb3_check_env(env)
    assert _messages(record) == []

    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        env = RescaleAction(_make(name, other_model), np.float32(-1.0), np.float32(1.0))
        assert env.action_space == gym.spaces.Box(-1.0, 1.0, (1 if name == "macro" else 2,))
        sb3_check_env(env)
        gymnasium_check_env(env)
    messages = _messages(record)
    assert len(messages) == 1
    assert "is different from the unwrapped version" in messages[0]


def test_spaces():
    env = gym.make("SDJLS-Macro-v0")
    assert env.action_space.shape == (1,)
    assert env.action_space.dtype == np.float32
    assert env.observation_space.shape == (2 + 3 + 1,)  # [x (n), one-hot (N), k / horizon]
    assert env.observation_space.dtype == np.float32


# --------------------------------------------------------------------------- pickling


def _episode(env, policy, seed=None, steps=None):
    """Run ``policy`` from a reset; return lists of observations, rewards, flags and infos."""
    obs, info = env.reset(seed=seed)
    out = {"obs": [obs], "reward": [], "flags": [], "info": [info]}
    k = 0
    while steps is None or k < steps:
        obs, reward, terminated, truncated, info = env.step(policy(info))
        out["obs"].append(obs)
        out["reward"].append(reward)
        out["flags"].append((terminated, truncated))
        out["info"].append(info)
        k += 1
        if terminated or truncated:
            break
    return out


def _assert_same_info(a, b):
    assert a.keys() == b.keys()
    for key in a:
        assert np.array_equal(a[key], b[key]), key
        assert type(a[key]) is type(b[key]), key


def _assert_same_episode(a, b):
    assert len(a["obs"]) == len(b["obs"])
    for x, y in zip(a["obs"], b["obs"], strict=True):
        assert x.dtype == y.dtype and np.array_equal(x, y)  # bit-identical
    assert a["reward"] == b["reward"]
    assert a["flags"] == b["flags"]
    for x, y in zip(a["info"], b["info"], strict=True):
        _assert_same_info(x, y)


@pytest.fixture
def info_policy(paper_policy):
    """The paper's feedback, as a function of the info of the current state."""

    def policy(info):
        return paper_policy(info["state"], info["mode"], info["k"]).astype(np.float32)

    return policy


def test_pickled_env_continues_identically(info_policy):
    env = gym.make("SDJLS-Macro-v0")
    env.reset(seed=11)
    for _ in range(3):
        *_, info = env.step(np.array([1.0], dtype=np.float32))
    clone = pickle.loads(pickle.dumps(env))
    assert clone.unwrapped.model == env.unwrapped.model
    np.testing.assert_array_equal(clone.unwrapped.state, env.unwrapped.state)

    # the rest of the episode (same RNG state) ...
    a = [env.step(info_policy(info))]
    b = [clone.step(info_policy(info))]
    while not (a[-1][2] or a[-1][3]):
        a.append(env.step(info_policy(a[-1][4])))
        b.append(clone.step(info_policy(b[-1][4])))
    assert len(a) == len(b) == 20 - 3
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x[0], y[0]) and x[1:4] == y[1:4]
        _assert_same_info(x[4], y[4])
    # ... and a new episode with the same seed
    _assert_same_episode(_episode(env, info_policy, seed=5), _episode(clone, info_policy, seed=5))


# --------------------------------------------------------------------------- determinism


def test_same_seed_gives_bit_identical_episodes(info_policy, other_model):
    a = _episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=123)
    b = _episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=123)
    assert len(a["reward"]) == 20
    _assert_same_episode(a, b)

    def zero(info):
        return np.zeros(2, dtype=np.float32)

    a = _episode(gym.make("SDJLS-v0", model=other_model, horizon=7), zero, seed=4)
    b = _episode(gym.make("SDJLS-v0", model=other_model, horizon=7), zero, seed=4)
    _assert_same_episode(a, b)


def test_different_seeds_give_different_episodes(info_policy):
    a = _episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=1)
    b = _episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=2)
    assert len(a["reward"]) == len(b["reward"]) == 20
    assert not np.array_equal(a["info"][-1]["state"], b["info"][-1]["state"])
    assert all(a["reward"][k] != b["reward"][k] for k in range(1, 20))


def test_reset_with_the_same_seed_replays_the_episode(info_policy):
    env = gym.make("SDJLS-Macro-v0")
    a = _episode(env, info_policy, seed=77)
    _episode(env, info_policy)  # something else in between
    b = _episode(env, info_policy, seed=77)
    _assert_same_episode(a, b)
    c = _episode(env, info_policy)  # no seed: the stream goes on
    assert c["reward"] != a["reward"]


# --------------------------------------------------------------------------- time indexing


def test_reset_returns_x0_mode0_and_k_0(paper):
    env = gym.make("SDJLS-Macro-v0")
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32
    np.testing.assert_array_equal(obs, [2.0, 2.0, 1.0, 0.0, 0.0, 0.0])  # [x0, one-hot(0), 0]
    assert info["k"] == 0
    assert info["mode"] == 0
    np.testing.assert_array_equal(info["state"], paper.x0)
    assert info["stage_cost"] == 0.0


def test_observation_encodes_state_mode_and_time(info_policy):
    env = gym.make("SDJLS-Macro-v0")
    obs, info = env.reset(seed=3)
    for k in range(1, 21):
        obs, *_, info = env.step(info_policy(info))
        np.testing.assert_array_equal(obs[:2], info["state"].astype(np.float32))
        np.testing.assert_array_equal(obs[2:5], np.eye(3)[info["mode"]])
        assert obs[5] == np.float32(k / 20)
        assert info["k"] == k


def test_reward_is_the_stage_cost_of_the_pre_step_state_and_mode(paper, info_policy):
    env = gym.make("SDJLS-Macro-v0")
    rng = np.random.default_rng(0)
    _, info = env.reset(seed=21)
    mode_changed = differs_from_post_step = 0
    for _ in range(20):
        x, mode = info["state"], info["mode"]
        u = info_policy(info) + rng.normal(0.0, 3.0, size=1).astype(np.float32)
        u64 = u.astype(np.float64)
        expected = -(x @ paper.Q[mode] @ x + u64 @ paper.R[mode] @ u64)
        _, reward, _, _, info = env.step(u)
        assert isinstance(reward, float)
        np.testing.assert_allclose(reward, expected, rtol=1e-12)
        assert info["stage_cost"] == -reward
        post = -(info["state"] @ paper.Q[info["mode"]] @ info["state"] + u64 @ paper.R[mode] @ u64)
        mode_changed += info["mode"] != mode
        differs_from_post_step += not np.isclose(post, expected)
    assert mode_changed > 0 and differs_from_post_step > 0  # the test can tell pre from post


def test_zero_noise_state_update_is_A_x_plus_B_u(quiet_paper_model, paper, info_policy):
    env = gym.make("SDJLS-v0", model=quiet_paper_model, horizon=20)
    rng = np.random.default_rng(5)
    _, info = env.reset(seed=9)
    modes = {info["mode"]}
    for _ in range(20):
        x, mode = info["state"], info["mode"]
        u = info_policy(info) + rng.uniform(-10.0, 10.0, size=1).astype(np.float32)
        _, _, terminated, _, info = env.step(u)
        assert not terminated
        expected = paper.A[mode] @ x + paper.B @ u.astype(np.float64)
        np.testing.assert_allclose(info["state"], expected, rtol=1e-12, atol=1e-12)
        modes.add(info["mode"])
    assert len(modes) > 1  # the A of the pre-step mode was exercised in several modes


def test_mode_transition_uses_P_in_inside_and_P_out_outside_at_time_k(paper):
    """Mode k+1 is 0 if G x_k <= H_k (P_in = [[1, 0], [1, 0]]), else 1 (P_out = [[0, 1], [0, 1]]).

    A = I, B = [0 1]', W = 0 and the paper's moving band, so the income follows the inputs
    exactly. The income path is chosen so that testing the band at k + 1 (or at k - 1)
    instead of k would give a different mode sequence.
    """
    model = SDJLSModel(
        A=[np.eye(2), np.eye(2)],
        B=[[0.0], [1.0]],
        P_in=[[1.0, 0.0], [1.0, 0.0]],
        P_out=[[0.0, 1.0], [0.0, 1.0]],
        G=paper.G,
        H0=paper.H(0),
        H_rate=paper.H(1) - paper.H(0),
        Q=np.eye(2),
        R=[[1.0]],
        x0=[0.0, 0.0],
        W=np.zeros((2, 2)),
    )
    # band at k: [2 + 0.5 k, 5 + 0.5 k]
    incomes = [5.2, 5.4, 2.8, 3.6, 6.9, 7.2, 4.6, 6.0, 6.0]
    expected_modes = [1, 0, 1, 0, 0, 0, 1, 0]  # out, in, out, in, in, in, out, in
    env = gym.make("SDJLS-v0", model=model, horizon=8)
    _, info = env.reset(seed=0, options={"x0": [0.0, incomes[0]], "mode0": 1})
    modes, inside_at_k, inside_at_k_plus_1 = [], [], []
    for k in range(8):
        x = info["state"]
        inside_at_k.append(bool(np.all(paper.G @ x <= paper.H(k))))
        inside_at_k_plus_1.append(bool(np.all(paper.G @ x <= paper.H(k + 1))))
        *_, info = env.step(np.array([incomes[k + 1] - x[1]], dtype=np.float32))
        modes.append(info["mode"])
    assert [1 - m for m in expected_modes] == inside_at_k
    assert inside_at_k != inside_at_k_plus_1
    assert inside_at_k[1:] != inside_at_k[:-1]
    assert modes == expected_modes


# --------------------------------------------------------------------------- episode end


def test_truncation_after_exactly_horizon_steps(other_model, info_policy):
    env = gym.make("SDJLS-v0", model=other_model, horizon=7)
    env.reset(seed=0)
    flags = [env.step(np.zeros(2, dtype=np.float32))[2:4] for _ in range(7)]
    assert flags == [(False, False)] * 6 + [(False, True)]

    run = _episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=8)
    assert run["flags"] == [(False, False)] * 19 + [(False, True)]
    assert [info["k"] for info in run["info"]] == list(range(21))


def test_termination_on_divergence_with_finite_reward():
    """x_{k+1} = 2 x_k from x_0 = 1: 2, 4, 8, 16 > 10 ends the episode at step 4."""
    model = SDJLSModel(
        A=[[[2.0]]], B=[[1.0]], P_in=[[1.0]], P_out=[[1.0]], G=[[1.0]], H0=[100.0],
        Q=[[1.0]], R=[[1.0]], x0=[1.0], W=[[0.0]],
    )  # fmt: skip
    env = gym.make("SDJLS-v0", model=model, horizon=20, divergence_bound=10.0)
    _, info = env.reset(seed=0)
    assert info["diverged"] is False
    for expected_x in (2.0, 4.0, 8.0):
        obs, reward, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        assert (terminated, truncated, info["diverged"]) == (False, False, False)
        assert info["state"][0] == expected_x
    obs, reward, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
    assert (terminated, truncated, info["diverged"]) == (True, False, True)
    assert info["state"][0] == 16.0
    assert reward == -64.0  # the stage cost of x_3 = 8, finite
    assert env.observation_space.contains(obs)
    assert obs[0] == 10.0  # clipped to the divergence bound in the observation


# --------------------------------------------------------------------------- info channel


def _check_info_types(info, n, r, at_reset):
    state = info["state"]
    assert isinstance(state, np.ndarray) and state.dtype == np.float64 and state.shape == (n,)
    assert isinstance(info["mode"], int) and not isinstance(info["mode"], bool)
    assert isinstance(info["k"], int) and not isinstance(info["k"], bool)
    assert isinstance(info["in_region"], bool)
    values = info["constraint_values"]
    assert isinstance(values, np.ndarray) and values.dtype == np.float64 and values.shape == (r,)
    violations = info["violations"]
    assert isinstance(violations, np.ndarray) and violations.dtype == bool
    assert violations.shape == (r,)
    assert type(info["cost"]) is float and info["cost"] in (0.0, 1.0)
    assert type(info["stage_cost"]) is float
    assert isinstance(info["diverged"], bool)
    if not at_reset:
        u = info["u"]
        assert isinstance(u, np.ndarray) and u.dtype == np.float64


@pytest.mark.parametrize("name", ["macro", "other"])
def test_info_keys_and_types_at_reset_and_every_step(name, other_model):
    env = _make(name, other_model)
    model = env.unwrapped.model
    keys = {"state", "mode", "k", "in_region", "constraint_values", "violations", "cost"}
    keys |= {"stage_cost", "diverged"}
    env.action_space.seed(0)
    _, info = env.reset(seed=0)
    assert keys <= info.keys()
    _check_info_types(info, model.n, model.r, at_reset=True)
    for _ in range(env.unwrapped.horizon):
        *_, terminated, truncated, info = env.step(env.action_space.sample() * 0.01)
        assert keys | {"u"} <= info.keys()
        _check_info_types(info, model.n, model.r, at_reset=False)
        if terminated or truncated:
            break


@pytest.mark.parametrize(
    ("x0", "inside"),
    [
        ([0.0, 10.0], False),  # above the band
        ([0.0, 1.0], False),  # below the band
        ([7.0, 3.0], True),
        ([0.0, 5.0], True),  # on the edge: G x <= H_k holds
        ([0.0, 2.0], True),
    ],
)
def test_constraint_sign_convention(paper, x0, inside):
    env = gym.make("SDJLS-Macro-v0")
    _, info = env.reset(seed=0, options={"x0": x0})
    values = paper.G @ np.array(x0) - paper.H(0)  # positive = violated
    np.testing.assert_allclose(info["constraint_values"], values, atol=1e-12)
    np.testing.assert_array_equal(info["violations"], values > 0)
    assert info["cost"] == float(np.any(values > 0))
    assert info["in_region"] is inside
    assert info["in_region"] is (not np.any(info["violations"]))
    np.testing.assert_array_equal(info["state"], x0)


def test_constraint_values_after_a_step_use_H_k_plus_1(quiet_paper_model, paper):
    env = gym.make("SDJLS-v0", model=quiet_paper_model)
    _, info = env.reset(seed=0, options={"x0": [0.0, 4.0], "mode0": 2})
    u = np.array([30.0], dtype=np.float32)
    *_, info = env.step(u)
    x1 = paper.A[2] @ np.array([0.0, 4.0]) + paper.B @ [30.0]  # = [4, 9.2]
    values = paper.G @ x1 - paper.H(1)  # band [2.5, 5.5]
    np.testing.assert_allclose(info["constraint_values"], values, atol=1e-12)
    assert info["violations"].tolist() == [False, True]
    assert info["cost"] == 1.0 and info["in_region"] is False


def test_reset_options_override_x0_and_mode0(paper):
    env = gym.make("SDJLS-Macro-v0")
    obs, info = env.reset(seed=0, options={"x0": [1.5, -0.5], "mode0": 2})
    np.testing.assert_array_equal(obs, np.float32([1.5, -0.5, 0.0, 0.0, 1.0, 0.0]))
    assert info["mode"] == 2
    np.testing.assert_array_equal(info["state"], [1.5, -0.5])
    obs, info = env.reset(options={"mode0": np.int64(1)})
    np.testing.assert_array_equal(obs, np.float32([2.0, 2.0, 0.0, 1.0, 0.0, 0.0]))
    obs, info = env.reset()  # options do not stick
    np.testing.assert_array_equal(obs, np.float32([*paper.x0, 1.0, 0.0, 0.0, 0.0]))


@pytest.mark.parametrize(
    ("options", "error", "message"),
    [
        ({"x0": [1.0, 2.0, 3.0]}, ValueError, r"^options\['x0'\] has shape \(3,\)"),
        ({"x0": [np.nan, 2.0]}, ValueError, r"^options\['x0'\] has a non-finite entry nan"),
        ({"x0": [np.inf, 2.0]}, ValueError, r"^options\['x0'\] has a non-finite entry inf"),
        ({"x0": [2e6, 2.0]}, ValueError, r"^options\['x0'\] has an entry 2e\+06"),
        ({"x0": ["1", 2.0]}, TypeError, r"^options\['x0'\] = .* has str entries"),
        ({"mode0": 3}, ValueError, r"^options\['mode0'\] = 3 is out of range"),
        ({"mode0": -1}, ValueError, r"^options\['mode0'\] = -1 is out of range"),
        ({"mode0": 2**70}, ValueError, r"^options\['mode0'\] = 1180591620717411303424 is out"),
        ({"mode0": np.uint64(2**64 - 1)}, ValueError, r"^options\['mode0'\] = .* is out of range"),
        ({"mode0": True}, TypeError, r"^options\['mode0'\] = True is a bool"),
        ({"mode0": 1.0}, TypeError, r"^options\['mode0'\] = 1\.0 is a float"),
        ({"x_0": [1.0, 2.0]}, ValueError, r"^options has unknown keys \['x_0'\]"),
        ([1, 2], TypeError, r"^options = \[1, 2\] is a list; expected a dict"),
        ("x0", TypeError, r"^options = 'x0' is a str; expected a dict"),
    ],
)
def test_bad_reset_options_raise(options, error, message):
    """Every reset option is checked by the one validation module, with messages that name the
    option; a huge Python int or the largest uint64 is out of range, not wrapped."""
    env = gym.make("SDJLS-Macro-v0")
    with pytest.raises(error, match=message):
        env.reset(seed=0, options=options)


def test_random_initial_mode_follows_the_mode0_vector(other_model):
    """mode0 = [0.3, 0.7]: 4000 resets, the frequency of mode 1 within 5 standard errors
    (two-sided 5-sigma bound: a correct sampler fails with probability 5.7e-7)."""
    env = SDJLSEnv(other_model, horizon=7)
    env.reset(seed=0)
    modes = np.array([env.reset()[1]["mode"] for _ in range(4000)])
    se = np.sqrt(0.3 * 0.7 / 4000)
    assert abs(np.mean(modes == 1) - 0.7) <= 5 * se
    assert set(modes.tolist()) == {0, 1}


# --------------------------------------------------------------------------- actions


def test_out_of_bounds_action_is_clipped(quiet_paper_model, paper):
    env = gym.make("SDJLS-v0", model=quiet_paper_model, action_bound=1.0)
    x = np.array([0.5, 1.0])
    for action, applied in ((5.0, 1.0), (-7.0, -1.0), (0.25, 0.25)):
        _, info = env.reset(seed=0, options={"x0": x, "mode0": 1})
        _, reward, _, _, info = env.step(np.array([action], dtype=np.float32))
        np.testing.assert_array_equal(info["u"], [applied])
        np.testing.assert_allclose(info["state"], paper.A[1] @ x + paper.B @ [applied], atol=1e-12)
        np.testing.assert_allclose(
            reward, -(x @ paper.Q[1] @ x + paper.R[1, 0, 0] * applied**2), rtol=1e-12
        )


@pytest.mark.parametrize(
    "action",
    [
        np.zeros(2, dtype=np.float32),
        np.zeros((1, 1), dtype=np.float32),
        np.zeros(0, dtype=np.float32),
        np.array([np.nan], dtype=np.float32),
        np.array([np.inf], dtype=np.float32),
        np.array([-np.inf], dtype=np.float32),
    ],
    ids=["shape-2", "shape-1x1", "empty", "nan", "inf", "-inf"],
)
def test_bad_action_raises_naming_the_action(action):
    env = gym.make("SDJLS-Macro-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(action)


def test_step_before_reset_raises():
    with pytest.raises(RuntimeError, match="reset"):
        SDJLSEnv("macro").step(np.zeros(1, dtype=np.float32))
    with pytest.raises(ResetNeeded):
        gym.make("SDJLS-Macro-v0").step(np.zeros(1, dtype=np.float32))


# --------------------------------------------------------------------------- rendering


def test_render_rgb_array(info_policy):
    env = gym.make("SDJLS-Macro-v0", render_mode="rgb_array")
    _, info = env.reset(seed=0)
    for _ in range(4):
        *_, info = env.step(info_policy(info))
    frame = env.render()
    assert isinstance(frame, np.ndarray)
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.shape[0] > 50 and frame.shape[1] > 50
    assert frame.dtype == np.uint8
    assert frame.std() > 0  # something is drawn


@pytest.mark.parametrize("render_mode", ["human", "ansi", "rgb"])
def test_invalid_render_mode_raises(render_mode):
    with pytest.raises(ValueError, match="render_mode"):
        SDJLSEnv("macro", render_mode=render_mode)


def test_render_leaves_the_matplotlib_backend_alone():
    import matplotlib
    import matplotlib.pyplot as plt

    original = matplotlib.get_backend()
    try:
        plt.switch_backend("svg")
        env = gym.make("SDJLS-Macro-v0", render_mode="rgb_array")
        env.reset(seed=0)
        env.render()
        assert matplotlib.get_backend() == "svg"
    finally:
        plt.switch_backend(original)


# --------------------------------------------------------------------------- non-finite states


def _blowup_model(A, Q=None, x0=(1e6, 1e6)):
    """One mode, n = 2, W = 0: x_1 = A x_0 exactly (no noise), with entries near 1e303."""
    return SDJLSModel(
        A=[A], B=[[0.0], [1.0]], P_in=[[1.0]], P_out=[[1.0]], G=[[0.0, 1.0]], H0=[1e9],
        Q=np.eye(2) if Q is None else Q, R=[[1.0]], x0=list(x0), W=np.zeros((2, 2)),
    )  # fmt: skip


# x_0 = [1e6, 1e6]: A x_0 is -1e309 (NaN in float64 arithmetic: 1e309 - 2e309), 1e309, or the
# stage cost x_0' Q x_0 = 2e312 overflows while the next state 0 is fine
BLOWUPS = {
    "nan-state": (_blowup_model([[1e303, -2e303], [1e303, -2e303]]), -2e12),
    "inf-state": (_blowup_model([[1e303, 0.0], [0.0, 1e303]]), -2e12),
    "cost-overflow": (
        _blowup_model(np.zeros((2, 2)), Q=1e300 * np.eye(2)),
        -1.7976931348623157e308,
    ),
    # Q x_0 = [inf, inf] with x_0 = [0, 1e10]: x_0' Q x_0 is inf * 0 + inf = NaN
    "cost-nan": (
        _blowup_model(np.zeros((2, 2)), Q=1e300 * np.ones((2, 2)), x0=(0.0, 1e10)),
        -1.7976931348623157e308,
    ),
}


@pytest.mark.parametrize("case", list(BLOWUPS))
def test_non_finite_state_or_cost_terminates_as_diverged_in_both_envs(case):
    """A step to a NaN or inf state, or with a stage cost beyond float64, ends the episode as
    diverged in the single and in the vector env alike: ``terminated``, ``info["diverged"]``,
    the same finite reward (minus the pre-step stage cost, or minus the largest float when that
    overflowed) and an observation inside the observation space. No numpy warning either
    (RuntimeWarnings are errors in this suite)."""
    model, reward = BLOWUPS[case]
    env = SDJLSEnv(model, horizon=5, divergence_bound=1e30)
    env.reset(seed=0)
    obs, r, terminated, truncated, info = env.step(np.zeros(1, np.float32))
    assert (terminated, truncated, info["diverged"]) == (True, False, True)
    assert isinstance(r, float) and np.isfinite(r) and r == reward
    assert info["stage_cost"] == -r
    assert env.observation_space.contains(obs) and np.all(np.isfinite(obs))
    assert info["cost"] == float(not info["in_region"])

    envs = SDJLSVectorEnv(3, model=model, horizon=5, divergence_bound=1e30)
    envs.reset(seed=0)
    obs_v, r_v, term_v, trunc_v, infos = envs.step(np.zeros((3, 1)))
    assert term_v.all() and not trunc_v.any() and infos["diverged"].all()
    np.testing.assert_array_equal(r_v, np.full(3, reward))
    assert envs.observation_space.contains(obs_v) and np.all(np.isfinite(obs_v))
    np.testing.assert_array_equal(obs_v[0], obs)  # the same picture of the diverged state
    # the next vector step restarts those rows from x0
    _, r_v, term_v, _, infos = envs.step(np.zeros((3, 1)))
    assert not term_v.any() and np.all(r_v == 0.0) and np.all(infos["k"] == 0)


def test_a_step_that_is_nan_in_float64_gives_the_exact_state():
    """A x_0 = 1e309 - 2e309 is NaN in float64 arithmetic; the step reports its exact value
    rounded, -inf, and the row G x = x(2) <= 1e9 holds (tests/test_input_checks.py has more)."""
    model, _ = BLOWUPS["nan-state"]
    env = SDJLSEnv(model, horizon=5, divergence_bound=1e30)
    env.reset(seed=0)
    *_, info = env.step(np.zeros(1, np.float32))
    assert info["state"].tolist() == [-np.inf, -np.inf]
    assert info["constraint_values"].tolist() == [-np.inf]
    assert info["violations"].tolist() == [False]
    assert info["in_region"] is True and info["cost"] == 0.0 and info["diverged"] is True


# --------------------------------------------------------------------------- after the end


def test_step_after_truncation_raises_until_reset(other_model):
    """Gymnasium's convention: after ``truncated`` (or ``terminated``) the next ``step()`` raises
    ``ResetNeeded`` (also a RuntimeError), telling to call ``reset()``; until then every
    observation is inside the observation space, ``k / horizon`` at most 1."""
    from gymnasium.error import ResetNeeded

    from sdjls_gym.errors import ResetNeededError

    for env in (gym.make("SDJLS-v0", model=other_model, horizon=3), SDJLSEnv(other_model, 3)):
        for _ in range(2):  # and again after a reset
            obs, _ = env.reset(seed=1)
            truncated = False
            while not truncated:
                obs, _, terminated, truncated, _ = env.step(np.zeros(2, np.float32))
                assert env.observation_space.contains(obs)
            assert obs[-1] == 1.0
            with pytest.raises(ResetNeeded, match=r"truncated at k = 3 = horizon.*call reset\(\)"):
                env.step(np.zeros(2, np.float32))
            with pytest.raises(RuntimeError, match="reset"):
                env.step(np.zeros(2, np.float32))
    assert issubclass(ResetNeededError, ResetNeeded) and issubclass(ResetNeededError, RuntimeError)


def test_step_after_termination_raises_until_reset():
    model, _ = BLOWUPS["inf-state"]
    env = SDJLSEnv(model, horizon=5, divergence_bound=1e30)
    env.reset(seed=0)
    assert env.step(np.zeros(1, np.float32))[2] is True
    with pytest.raises(RuntimeError, match=r"terminated: diverged at k = 1.*call reset\(\)"):
        env.step(np.zeros(1, np.float32))
    env.reset()
    assert env.step(np.zeros(1, np.float32))[2] is True


# --------------------------------------------------------------------------- horizon and spec


# the paper's gains (typed in conftest), to keep the macro example from diverging
_K = np.array([[[2.5, -3.2]], [[4.3, -4.5]], [[-5.3, 5.2]]])


def _episode_length(env):
    """Steps until the end under u = K_theta x, and the last observation."""
    _, info = env.reset(seed=0)
    steps, done = 0, False
    while not done:
        u = (_K[info["mode"]] @ info["state"]).astype(np.float32)
        obs, _, terminated, truncated, info = env.step(u)
        steps += 1
        done = terminated or truncated
    return steps, obs


def test_horizon_alone_sets_the_episode_length():
    """``gym.make("SDJLS-Macro-v0", horizon=40)`` gives 40-step episodes (no second limit from
    the registration), ``k / horizon`` reaches 1 and ``env.spec.max_episode_steps`` says 40."""
    env = gym.make("SDJLS-Macro-v0", horizon=40)
    steps, last_obs = _episode_length(env)
    assert steps == 40 and last_obs[-1] == 1.0
    assert env.spec.max_episode_steps == 40
    assert gym.make("SDJLS-Macro-v0").spec.max_episode_steps == 20
    # an explicit max_episode_steps still adds its TimeLimit, and the spec says so
    short = gym.make("SDJLS-Macro-v0", max_episode_steps=10)
    assert _episode_length(short)[0] == 10 and short.spec.max_episode_steps == 10
    # the same through make_vec, in every vectorization mode
    for mode in ("vector_entry_point", "sync"):
        envs = gym.make_vec("SDJLS-Macro-v0", num_envs=2, vectorization_mode=mode, horizon=40)
        _, infos = envs.reset(seed=0)
        for k in range(1, 41):
            u = np.einsum("bij,bj->bi", _K[infos["mode"]], infos["state"]).astype(np.float32)
            _, _, terminated, truncated, infos = envs.step(u)
            assert truncated.all() == (k == 40) and not terminated.any(), (mode, k)
        envs.close()
    envs = gym.make_vec("SDJLS-Macro-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert envs.spec.max_episode_steps == 20


def _too_long(steps, horizon):
    return (
        rf"^max_episode_steps = {steps}.* is larger than horizon = {horizon}: the environment "
        rf"ends its episodes at its horizon; pass horizon={steps} instead"
    )


def test_max_episode_steps_only_shortens_episodes():
    """``max_episode_steps`` may only shorten episodes. ``SDJLSVectorEnv`` (``gym.make_vec`` in
    its default mode) refuses a value above the horizon; ``gym.make`` adds Gymnasium's
    ``TimeLimit`` out of the environment's sight (the environment is given a spec without the
    limit), so there the rule is documented, not enforced: episodes still end at the horizon."""
    with pytest.raises(ValueError, match=_too_long(40, 20)):
        gym.make_vec("SDJLS-Macro-v0", num_envs=2, max_episode_steps=40)
    # gym.make: a longer TimeLimit never fires, the environment truncates at its horizon
    for mode_kwargs in ({}, {"horizon": 10}):
        env = gym.make("SDJLS-Macro-v0", max_episode_steps=40, **mode_kwargs)
        assert isinstance(env, gym.wrappers.TimeLimit)
        assert _episode_length(env)[0] == mode_kwargs.get("horizon", 20)
        assert env.unwrapped.spec.max_episode_steps == mode_kwargs.get("horizon", 20)
    # a spec that carries the limit of the env it came from, remade with a shorter horizon
    spec = gym.make("SDJLS-Macro-v0").spec
    assert spec.max_episode_steps == 20
    assert _episode_length(gym.make(spec, horizon=10))[0] == 10
    unlimited = gym.make(spec, horizon=10, max_episode_steps=-1)  # -1: no TimeLimit
    assert _episode_length(unlimited)[0] == 10 and unlimited.spec.max_episode_steps == 10
    # up to the horizon: Gymnasium's TimeLimit, and the spec says its value
    for steps, horizon in ((20, 20), (7, 20), (21, 40)):
        env = gym.make("SDJLS-Macro-v0", horizon=horizon, max_episode_steps=steps)
        assert _episode_length(env)[0] == steps and env.spec.max_episode_steps == steps
    # a spec set by hand is kept, its limit included
    env = SDJLSEnv(model="macro")
    env.spec = spec
    assert env.spec.max_episode_steps == 20


def test_make_vec_spec_reports_the_horizon_in_vector_entry_point_mode():
    """What the README says of ``envs.spec`` through ``gym.make_vec``: the native vector env
    (the default ``vector_entry_point`` mode) reports the episode length; in ``"sync"`` and
    ``"async"`` mode ``envs.spec`` is Gymnasium's, built from the registration (no
    ``max_episode_steps``), and each sub-environment's spec reports the horizon."""
    for kwargs, steps in (({}, 20), ({"horizon": 40}, 40), ({"max_episode_steps": 10}, 10)):
        envs = gym.make_vec("SDJLS-Macro-v0", num_envs=2, **kwargs)
        assert isinstance(envs, SDJLSVectorEnv) and envs.spec.max_episode_steps == steps
    for mode in ("sync", "async"):
        envs = gym.make_vec("SDJLS-Macro-v0", num_envs=2, vectorization_mode=mode, horizon=40)
        assert envs.spec.max_episode_steps is None
        assert [spec.max_episode_steps for spec in envs.get_attr("spec")] == [40, 40]
        envs.close()


def test_made_env_with_a_longer_horizon_pickles_and_passes_the_checkers():
    env = gym.make("SDJLS-Macro-v0", horizon=40)
    clone = pickle.loads(pickle.dumps(env))
    assert clone.spec.max_episode_steps == 40 and clone.unwrapped.horizon == 40
    assert _episode_length(clone)[0] == 40
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        gymnasium_check_env(env.unwrapped)
        sb3_check_env(env)
    assert all(ALLOWED.search(m) for m in _messages(record)), _messages(record)


def test_sdjls_v0_without_a_model_says_what_to_pass():
    for make in (
        lambda: gym.make("SDJLS-v0"),
        lambda: gym.make_vec("SDJLS-v0", num_envs=2, vectorization_mode="vector_entry_point"),
        lambda: SDJLSEnv(),
        lambda: SDJLSVectorEnv(2),
    ):
        with pytest.raises(TypeError, match=r"model is missing; pass an SDJLSModel, a preset name"):
            make()


def test_spec_with_a_model_object_is_json_and_remakes_the_same_env(other_model):
    """``SDJLS-v0`` made with an ``SDJLSModel`` keeps the model in its spec as ``to_dict()``:
    ``env.spec.to_json()`` works and ``gym.make(env.spec)`` (or the spec read back from JSON)
    builds the same environment."""
    from gymnasium.envs.registration import EnvSpec

    env = gym.make("SDJLS-v0", model=other_model, horizon=7, action_bound=np.array([3.0, 4.0]))
    text = env.spec.to_json()
    for spec in (env.spec, EnvSpec.from_json(text)):
        again = gym.make(spec)
        assert again.unwrapped.model == other_model
        assert again.unwrapped.horizon == 7 and again.spec.max_episode_steps == 7
        assert again.action_space == env.action_space
        a = _episode(env, lambda info: np.ones(2, np.float32), seed=3)
        b = _episode(again, lambda info: np.ones(2, np.float32), seed=3)
        _assert_same_episode(a, b)
    envs = gym.make_vec(
        "SDJLS-v0", num_envs=2, vectorization_mode="vector_entry_point", model=other_model
    )
    assert EnvSpec.from_json(envs.spec.to_json()).kwargs["model"] == other_model.to_dict()
    # a model given as a dict of numpy arrays is stored as plain lists too
    arrays = {
        key: np.asarray(value) if key not in ("mode_names", "state_names") else value
        for key, value in other_model.to_dict().items()
    }
    env = gym.make("SDJLS-v0", model=arrays, horizon=7)
    assert gym.make(EnvSpec.from_json(env.spec.to_json())).unwrapped.model == other_model


def test_the_ids_can_be_made_without_importing_the_package():
    """``gym.make("sdjls_gym:SDJLS-Macro-v0")`` imports the package itself (a fresh process)."""
    import subprocess
    import sys

    code = (
        "import sys, gymnasium as gym\n"
        "assert 'sdjls_gym' not in sys.modules\n"
        "env = gym.make('sdjls_gym:SDJLS-Macro-v0')\n"
        "print(env.unwrapped.horizon, env.reset(seed=0)[0].shape)\n"
    )
    root = str(Path(__file__).resolve().parents[1])
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=root
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["20", "(6,)"]


# --------------------------------------------------------------------------- arguments


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"horizon": 2.0}, TypeError, r"^horizon = 2\.0 is a float; expected an int >= 1"),
        ({"horizon": True}, TypeError, r"^horizon = True is a bool"),
        ({"horizon": 0}, ValueError, r"^horizon = 0 is out of range"),
        ({"horizon": 2**70}, ValueError, r"^horizon = 1180591620717411303424 is too large"),
        ({"horizon": np.uint64(2**64 - 1)}, ValueError, r"^horizon = .* is too large"),
        ({"divergence_bound": True}, TypeError, r"^divergence_bound = True is a bool"),
        ({"divergence_bound": "1e6"}, TypeError, r"^divergence_bound = '1e6' is a str"),
        ({"divergence_bound": 1e31}, ValueError, r"^divergence_bound = 1e\+31 is out of range"),
        ({"divergence_bound": 1.0}, ValueError, r"^the model's x0 = .* beyond divergence_bound"),
        (
            {"action_bound": 1e300},
            ValueError,
            r"^action_bound = 1e\+300 does not fit in float32; expected a number in "
            r"\[1\.17549e-38, 3\.40282e\+38\]",
        ),
        ({"action_bound": 1e-300}, ValueError, r"^action_bound = 1e-300 does not fit in float32"),
        ({"action_bound": 1e-40}, ValueError, r"^action_bound = 1e-40 does not fit in float32"),
        ({"action_bound": 10**400}, ValueError, r"^action_bound = 1000.* is not finite"),
        ({"action_bound": [1e39]}, ValueError, r"^action_bound\[0\] = 1e\+39 does not fit"),
        ({"action_bound": [0.0]}, ValueError, r"^action_bound\[0\] = 0 is not positive"),
        ({"action_bound": True}, TypeError, r"^action_bound = True is a bool"),
        ({"action_bound": "big"}, TypeError, r"^action_bound = 'big' is a str"),
    ],
)
def test_bad_constructor_arguments(kwargs, error, message):
    """One rule per kind of argument: a float horizon is a TypeError like the controllers', a
    bool is never a number, and bounds that the float32 spaces cannot hold are rejected (a Box
    of +-inf or of zeros) with the float32 limits in the message."""
    with pytest.raises(error, match=message):
        SDJLSEnv("macro", **kwargs)


@pytest.mark.parametrize("bound", [float(np.finfo(np.float32).max), 1.2e-38, 1e30])
def test_action_bounds_at_the_float32_limits_give_finite_nonzero_boxes(bound):
    env = SDJLSEnv("macro", action_bound=bound)
    high = env.action_space.high
    assert np.all(np.isfinite(high)) and np.all(high > 0) and high[0] == np.float32(bound)
    env.reset(seed=0)
    action = np.array([1e30], np.float32)
    *_, info = env.step(action)
    assert info["u"][0] == min(float(action[0]), float(np.float32(bound)))
