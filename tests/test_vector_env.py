"""SDJLSVectorEnv: registration, shapes and masks, autoreset, determinism, and agreement in
distribution with the single SDJLSEnv."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from conftest import UNSHOWN, doubling_model, raises_naming
from gymnasium.vector import AutoresetMode
from scipy import stats

from sdjls_gym import SDJLSModel, SDJLSVectorEnv

INFO_KEYS = [
    "state",
    "mode",
    "k",
    "in_region",
    "constraint_values",
    "violations",
    "cost",
    "stage_cost",
    "diverged",
]


def _make_vec(num_envs, **kwargs):
    return gym.make_vec(
        "SDJLS-Macro-v0", num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs
    )


def _act(policy, infos):
    return policy(infos["state"], infos["mode"], infos["k"]).astype(np.float32)


def test_make_vec_gives_the_native_vector_env():
    envs = _make_vec(3)
    assert isinstance(envs, SDJLSVectorEnv)
    assert envs.num_envs == 3
    assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    single = gym.make("SDJLS-Macro-v0")
    assert envs.single_observation_space == single.observation_space
    assert envs.single_action_space == single.action_space
    assert envs.model == single.unwrapped.model


def test_shapes_dtypes_and_info_masks(paper_policy):
    B = 5
    envs = _make_vec(B)
    obs, infos = envs.reset(seed=0)
    assert obs.shape == (B, 6) and obs.dtype == np.float32
    assert envs.observation_space.contains(obs)
    for key in INFO_KEYS:
        assert infos[key].shape[0] == B, key
        mask = infos[f"_{key}"]
        assert mask.dtype == bool and mask.shape == (B,) and mask.all(), key
    assert infos["state"].shape == (B, 2) and infos["state"].dtype == np.float64
    assert infos["constraint_values"].shape == (B, 2)
    assert infos["violations"].shape == (B, 2) and infos["violations"].dtype == bool
    assert infos["in_region"].dtype == bool
    assert infos["cost"].dtype == np.float64
    np.testing.assert_array_equal(infos["k"], np.zeros(B))

    obs, rewards, terminated, truncated, infos = envs.step(_act(paper_policy, infos))
    assert obs.shape == (B, 6) and obs.dtype == np.float32
    assert rewards.shape == (B,) and np.issubdtype(rewards.dtype, np.floating)
    assert terminated.shape == truncated.shape == (B,)
    assert terminated.dtype == truncated.dtype == bool
    for key in [*INFO_KEYS, "u"]:
        assert infos[key].shape[0] == B, key
        assert infos[f"_{key}"].shape == (B,) and infos[f"_{key}"].all(), key
    assert infos["u"].shape == (B, 1)
    # the info channel follows the sign convention per sub-environment
    np.testing.assert_array_equal(infos["violations"], infos["constraint_values"] > 0)
    np.testing.assert_array_equal(infos["cost"], infos["violations"].any(axis=1).astype(float))
    np.testing.assert_array_equal(infos["in_region"], ~infos["violations"].any(axis=1))


def test_autoreset_next_step_after_truncation(paper_policy, paper):
    B = 4
    envs = _make_vec(B)
    _, infos = envs.reset(seed=1)
    for k in range(1, 21):
        obs, rewards, terminated, truncated, infos = envs.step(_act(paper_policy, infos))
        assert not terminated.any()
        assert truncated.all() == (k == 20) and truncated.any() == (k == 20)
        np.testing.assert_array_equal(infos["k"], np.full(B, k))
    before = infos["state"].copy()

    # the step after the end: reset observation, reward 0, no flags, k = 0, action ignored
    obs, rewards, terminated, truncated, infos = envs.step(np.full((B, 1), 150.0, np.float32))
    reset_obs = np.float32([*paper.x0, 1.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(obs, np.broadcast_to(reset_obs, (B, 6)))
    np.testing.assert_array_equal(rewards, np.zeros(B))
    assert not terminated.any() and not truncated.any()
    np.testing.assert_array_equal(infos["k"], np.zeros(B))
    np.testing.assert_array_equal(infos["state"], np.broadcast_to(paper.x0, (B, 2)))
    assert not infos["_u"].any()
    assert not np.array_equal(infos["state"], before)

    # and the episode goes on from x0
    obs, rewards, terminated, truncated, infos = envs.step(_act(paper_policy, infos))
    np.testing.assert_array_equal(infos["k"], np.ones(B))
    assert infos["_u"].all()
    assert not terminated.any() and not truncated.any()


def test_autoreset_after_divergence_of_one_sub_env():
    """x_{k+1} = 2 x_k + u_k from x_0 = 1, W = 0: env 0 (u = 0) reaches 16 > 10 at step 4 and
    terminates; env 1 (u = -2 x) stays at 0 and goes on."""
    envs = gym.make_vec(
        "SDJLS-v0",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        model=doubling_model(),
        horizon=20,
        divergence_bound=10.0,
    )
    _, infos = envs.reset(seed=0)
    for k in range(1, 5):
        actions = np.array([[0.0], [-2.0 * infos["state"][1, 0]]], dtype=np.float32)
        obs, rewards, terminated, truncated, infos = envs.step(actions)
        assert terminated.tolist() == [k == 4, False]
        assert not truncated.any()
    assert infos["diverged"].tolist() == [True, False]
    assert rewards[0] == -64.0  # stage cost of x_3 = 8, finite
    assert envs.observation_space.contains(obs)

    obs, rewards, terminated, truncated, infos = envs.step(np.zeros((2, 1), np.float32))
    assert infos["k"].tolist() == [0, 5]
    assert infos["state"][:, 0].tolist() == [1.0, 0.0]
    assert rewards[0] == 0.0
    assert infos["_u"].tolist() == [False, True]
    assert not terminated.any() and not truncated.any()


def _vector_episode(envs, policy, seed):
    obs, infos = envs.reset(seed=seed)
    out = [(obs, infos)]
    for _ in range(20):
        obs, rewards, terminated, truncated, infos = envs.step(_act(policy, infos))
        out.append((obs, rewards, terminated, truncated, infos))
    return out


def test_same_seed_same_results_different_seed_different(paper_policy):
    a = _vector_episode(_make_vec(8), paper_policy, seed=3)
    b = _vector_episode(_make_vec(8), paper_policy, seed=3)
    c = _vector_episode(_make_vec(8), paper_policy, seed=4)
    for step_a, step_b in zip(a, b, strict=True):
        for x, y in zip(step_a[:-1], step_b[:-1], strict=True):
            np.testing.assert_array_equal(x, y)
        assert step_a[-1].keys() == step_b[-1].keys()
        for key in step_a[-1]:
            np.testing.assert_array_equal(step_a[-1][key], step_b[-1][key], err_msg=key)
    assert not np.array_equal(a[-1][-1]["state"], c[-1][-1]["state"])


def test_zero_noise_batch_follows_the_paper_with_clipping(quiet_paper_model, paper):
    """Each sub-env: x_{k+1} = A x_k + B clip(u_k), reward -(x' Q x + u' R u), pre-step mode."""
    B = 6
    envs = gym.make_vec(
        "SDJLS-v0",
        num_envs=B,
        vectorization_mode="vector_entry_point",
        model=quiet_paper_model,
        action_bound=1.0,
    )
    rng = np.random.default_rng(0)
    _, infos = envs.reset(seed=2, options={"x0": [0.3, -0.2]})
    for _ in range(5):
        x, mode = infos["state"].copy(), infos["mode"].copy()
        actions = rng.uniform(-3.0, 3.0, size=(B, 1)).astype(np.float32)
        _, rewards, _, _, infos = envs.step(actions)
        u = np.clip(actions.astype(np.float64), -1.0, 1.0)
        assert np.any(u != actions) and np.any(u == actions)
        np.testing.assert_array_equal(infos["u"], u)
        for i in range(B):
            expected = paper.A[mode[i]] @ x[i] + paper.B @ u[i]
            np.testing.assert_allclose(infos["state"][i], expected, rtol=1e-12, atol=1e-12)
            cost = x[i] @ paper.Q[mode[i]] @ x[i] + u[i] @ paper.R[mode[i]] @ u[i]
            np.testing.assert_allclose(rewards[i], -cost, rtol=1e-12)


def test_vector_env_errors():
    envs = _make_vec(2)
    with pytest.raises(RuntimeError, match="reset"):
        envs.step(np.zeros((2, 1), np.float32))
    envs.reset(seed=0)
    with raises_naming(ValueError, "actions", (3, 1)):
        envs.step(np.zeros((3, 1), np.float32))
    with raises_naming(ValueError, "actions", UNSHOWN):  # known gap: NaN/inf actions not shown
        envs.step(np.array([[0.0], [np.nan]], np.float32))
    with raises_naming(ValueError, "options['mode0']", 5):
        envs.reset(options={"mode0": 5})


def test_max_episode_steps_may_only_shorten_episodes(paper_policy):
    """``max_episode_steps`` truncates earlier than the horizon, as a ``TimeLimit`` would; a
    larger value is refused (the episodes would end at the horizon, not at it)."""
    with raises_naming(ValueError, ("max_episode_steps", "horizon"), 21):
        SDJLSVectorEnv(2, model="macro", max_episode_steps=21)
    for steps, horizon in ((20, 20), (21, 40)):
        envs = _make_vec(2, horizon=horizon, max_episode_steps=steps)
        assert envs.spec.max_episode_steps == steps
        _, infos = envs.reset(seed=0)
        for k in range(1, steps + 1):
            _, _, terminated, truncated, infos = envs.step(_act(paper_policy, infos))
            assert truncated.all() == (k == steps) and not terminated.any(), k


# --------------------------------------------------------------------------- distribution

VECTOR_EPISODES = 4000
# 1500 rather than 4000 single-env episodes: one env step takes ~0.15 ms here, so 4000 x 20
# steps would take ~12 s; 1500 x 20 take ~5 s.
SINGLE_EPISODES = 1500
ALPHA = 1e-3
Z_CRIT = stats.norm.ppf(1 - ALPHA / 2)  # 3.29, two-sided


def _two_mean_z(a, b):
    return (a.mean() - b.mean()) / np.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)


def _two_proportion_z(hits_a, n_a, hits_b, n_b):
    pooled = (hits_a + hits_b) / (n_a + n_b)
    se = np.sqrt(pooled * (1 - pooled) * (1 / n_a + 1 / n_b))
    return np.where(se > 0, (hits_a / n_a - hits_b / n_b) / np.where(se > 0, se, 1.0), 0.0)


def test_vector_env_and_single_env_agree_in_distribution(paper_policy):
    """Both driven by u = K_theta x + nu_k (paper's K, nu_k = 3.5 + 0.5 k) for 20 steps.

    Compared, each with a two-sided test at alpha = 1e-3 (|z| < 3.29): the mean of x_T(2) and
    the mean return (two-sample z-tests), the violation frequency at each k = 1..20 and the
    frequency of each mode at T (two-proportion z-tests). That is 25 tests, so by Bonferroni
    the chance that a correct pair of envs fails any of them is at most 2.5% for a random
    seed; the seeds are fixed, so the outcome is deterministic. Power: with 1500 vs 4000
    episodes a shift of ~0.04 in a frequency near 0.18, or of 0.15 in the mean of x_T(2)
    (sd 1), is detected about half the time.

    The vector env is also checked against values computed by hand: A_i + B K_i = [[0, 1],
    [0, 0]] in every mode, so x_k(2) = 3 + 0.5 k + w (k >= 1), x_T(2) has mean 13, and the
    band [2 + 0.5 k, 5 + 0.5 k] is violated iff w < -1 or w > 2, with probability
    Phi(-1) + 1 - Phi(2) = 0.1814 at every k >= 1 (one-sample tests at the same alpha).
    """
    # vector env
    envs = _make_vec(VECTOR_EPISODES)
    _, infos = envs.reset(seed=2024)
    vec_viol = [infos["cost"].copy()]
    vec_return = np.zeros(VECTOR_EPISODES)
    for _ in range(20):
        _, rewards, terminated, truncated, infos = envs.step(_act(paper_policy, infos))
        vec_return += rewards
        vec_viol.append(infos["cost"].copy())
    assert truncated.all() and not terminated.any()
    vec_xT = infos["state"][:, 1].copy()
    vec_modeT = infos["mode"].copy()
    vec_viol = np.array(vec_viol)  # (21, episodes)

    # single env, seeded once
    env = gym.make("SDJLS-Macro-v0")
    one_xT = np.empty(SINGLE_EPISODES)
    one_modeT = np.empty(SINGLE_EPISODES, dtype=np.int64)
    one_return = np.zeros(SINGLE_EPISODES)
    one_viol = np.empty((21, SINGLE_EPISODES))
    for e in range(SINGLE_EPISODES):
        _, info = env.reset(seed=99 if e == 0 else None)
        one_viol[0, e] = info["cost"]
        for k in range(20):
            u = paper_policy(info["state"], info["mode"], k).astype(np.float32)
            _, reward, terminated, truncated, info = env.step(u)
            one_return[e] += reward
            one_viol[k + 1, e] = info["cost"]
        assert truncated and not terminated
        one_xT[e] = info["state"][1]
        one_modeT[e] = info["mode"]

    # x_0 = [2, 2] is on the lower edge of the band at k = 0: never a violation
    assert vec_viol[0].sum() == 0 and one_viol[0].sum() == 0

    z = {
        "mean x_T(2)": _two_mean_z(vec_xT, one_xT),
        "mean return": _two_mean_z(vec_return, one_return),
    }
    viol_z = _two_proportion_z(
        vec_viol[1:].sum(axis=1), VECTOR_EPISODES, one_viol[1:].sum(axis=1), SINGLE_EPISODES
    )
    z.update({f"violations at k={k}": viol_z[k - 1] for k in range(1, 21)})
    for mode in range(3):
        z[f"mode {mode} at T"] = _two_proportion_z(
            np.sum(vec_modeT == mode), VECTOR_EPISODES, np.sum(one_modeT == mode), SINGLE_EPISODES
        )
    rejected = {name: float(value) for name, value in z.items() if abs(value) >= Z_CRIT}
    assert rejected == {}

    # hand-computed expectations for the vector env
    assert abs(vec_xT.mean() - 13.0) / (1.0 / np.sqrt(VECTOR_EPISODES)) < Z_CRIT
    p = stats.norm.cdf(-1.0) + stats.norm.sf(2.0)
    freq = vec_viol[1:].mean(axis=1)
    assert np.all(np.abs(freq - p) / np.sqrt(p * (1 - p) / VECTOR_EPISODES) < Z_CRIT), freq
    # every mode is visited at T, so the mode comparison is not vacuous
    assert np.all(np.bincount(vec_modeT, minlength=3) > 500)


def test_autoreset_after_a_huge_divergence_does_not_overflow():
    """A state far past the divergence bound is restarted without any arithmetic on it.

    With ``A = 1e200 I`` the first step diverges to ~1e200; squaring it in the stage cost or
    multiplying it by ``A`` again in the autoreset step would overflow (a RuntimeWarning, an error
    in this suite), and the reset rows must come back exactly at ``x0``.
    """
    huge = SDJLSModel(
        A=[np.eye(2) * 1e200],
        B=[[0.0], [1.0]],
        P_in=[[1.0]],
        P_out=[[1.0]],
        G=[[0.0, 1.0]],
        H0=[1.0],
        Q=np.eye(2),
        R=[[1.0]],
        x0=[1.0, 1.0],
    )
    envs = SDJLSVectorEnv(2, model=huge, horizon=5)
    envs.reset(seed=0)
    _, _, terminated, _, infos = envs.step(np.zeros((2, 1)))
    assert terminated.all() and infos["diverged"].all()
    _, reward, terminated, truncated, infos = envs.step(np.zeros((2, 1)))
    assert np.array_equal(infos["state"], np.ones((2, 2))) and np.all(infos["k"] == 0)
    assert np.all(reward == 0.0) and not terminated.any() and not truncated.any()
