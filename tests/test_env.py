"""SDJLSEnv: API conformance, pickling and specs, determinism, time indexing, info, rendering.

Expected values are computed in the tests from the paper's numbers (``conftest.py``) and the
formulas of section 2; the env is only ever compared with those, or with itself. The
limits (episode end, divergence, horizon, bad arguments and actions) are in
``test_env_limits.py``.
"""

from __future__ import annotations

import pickle
import re
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from conftest import assert_same_episode, assert_same_info, raises_naming, run_episode
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from gymnasium.wrappers import RescaleAction
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from sdjls_gym import SDJLSEnv, SDJLSModel

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
        assert_same_info(x[4], y[4])
    # ... and a new episode with the same seed
    assert_same_episode(
        run_episode(env, info_policy, seed=5), run_episode(clone, info_policy, seed=5)
    )


# --------------------------------------------------------------------------- determinism


def test_same_seed_gives_bit_identical_episodes(info_policy, other_model):
    a = run_episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=123)
    b = run_episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=123)
    assert len(a["reward"]) == 20
    assert_same_episode(a, b)

    def zero(info):
        return np.zeros(2, dtype=np.float32)

    a = run_episode(gym.make("SDJLS-v0", model=other_model, horizon=7), zero, seed=4)
    b = run_episode(gym.make("SDJLS-v0", model=other_model, horizon=7), zero, seed=4)
    assert_same_episode(a, b)


def test_different_seeds_give_different_episodes(info_policy):
    a = run_episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=1)
    b = run_episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=2)
    assert len(a["reward"]) == len(b["reward"]) == 20
    assert not np.array_equal(a["info"][-1]["state"], b["info"][-1]["state"])
    assert all(a["reward"][k] != b["reward"][k] for k in range(1, 20))


def test_reset_with_the_same_seed_replays_the_episode(info_policy):
    env = gym.make("SDJLS-Macro-v0")
    a = run_episode(env, info_policy, seed=77)
    run_episode(env, info_policy)  # something else in between
    b = run_episode(env, info_policy, seed=77)
    assert_same_episode(a, b)
    c = run_episode(env, info_policy)  # no seed: the stream goes on
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


def test_random_initial_mode_follows_the_mode0_vector(other_model):
    """mode0 = [0.3, 0.7]: 4000 resets, the frequency of mode 1 within 5 standard errors
    (two-sided 5-sigma bound: a correct sampler fails with probability 5.7e-7)."""
    env = SDJLSEnv(other_model, horizon=7)
    env.reset(seed=0)
    modes = np.array([env.reset()[1]["mode"] for _ in range(4000)])
    se = np.sqrt(0.3 * 0.7 / 4000)
    assert abs(np.mean(modes == 1) - 0.7) <= 5 * se
    assert set(modes.tolist()) == {0, 1}


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
    with raises_naming(ValueError, "render_mode", render_mode):
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


# --------------------------------------------------------------------------- specs


def test_made_env_with_a_longer_horizon_pickles_and_passes_the_checkers(info_policy):
    env = gym.make("SDJLS-Macro-v0", horizon=40)
    clone = pickle.loads(pickle.dumps(env))
    assert clone.spec.max_episode_steps == 40 and clone.unwrapped.horizon == 40
    assert len(run_episode(clone, info_policy)["reward"]) == 40
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        gymnasium_check_env(env.unwrapped)
        sb3_check_env(env)
    assert all(ALLOWED.search(m) for m in _messages(record)), _messages(record)


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
        a = run_episode(env, lambda info: np.ones(2, np.float32), seed=3)
        b = run_episode(again, lambda info: np.ones(2, np.float32), seed=3)
        assert_same_episode(a, b)
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
