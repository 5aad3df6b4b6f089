"""Tests of controllers.hidden_policy: the filter kept across an episode, the decision rules,
predict in a Gymnasium loop, and closed-loop episodes with the mode hidden."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from conftest import raises_naming

import sdjls_gym
from controllers import (
    BeliefRecedingHorizonController,
    HiddenModePolicy,
    ModeFilter,
    RecedingHorizonController,
)
from sdjls_gym.systems import TASKS


def _belief_policy(env_id, **kw):
    task = TASKS[env_id]
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc, horizon=task.horizon)
    return task, HiddenModePolicy(ctrl, **kw)


def _vector_env(task, episodes, observe="state"):
    return sdjls_gym.SDJLSVectorEnv(
        num_envs=episodes,
        model=task.model,
        horizon=task.horizon,
        action_bound=task.action_bound,
        observe=observe,
    )


# ------------------------------------------------------------------ the filter's memory
def test_beliefs_are_the_filters_steps_and_restart_at_k_zero():
    """On the vector environment (autoreset: rows restart at k == 0), the belief each decision
    uses is ModeFilter.step_batch applied by hand to the previous state and applied input."""
    task, policy = _belief_policy("SDJLS-Macro-v0")
    env = _vector_env(task, 16)
    env.horizon = env.episode_steps = 6  # short episodes: several restarts in 15 steps
    mode_filter = ModeFilter(task.model)
    _, info = env.reset(seed=0)
    policy.reset(16)
    expected = np.tile(mode_filter.initial_belief(), (16, 1))
    x_prev = u_prev = k_prev = None
    for step in range(15):
        x, k = info["state"], info["k"]
        if step:
            moved = k > 0
            expected[moved] = mode_filter.step_batch(
                expected[moved], x_prev[moved], u_prev[moved], x[moved], k_prev[moved]
            )
            expected[~moved] = mode_filter.initial_belief()
        u, out = policy.act_hidden(x, k, None if step == 0 else u_prev)
        np.testing.assert_allclose(out["belief"], expected, rtol=1e-12, atol=1e-300)
        assert not np.isnan(out["belief"]).any() and out["filter_resets"] == 0
        x_prev, k_prev = x, k
        _, _, _, _, info = env.step(u)
        u_prev = info["u"]
    assert np.any(k_prev == 0)  # some rows restarted


def test_a_batch_equals_its_episodes_one_at_a_time():
    task, policy = _belief_policy("SDJLS-Degradation-v0")
    env = _vector_env(task, 4)
    _, info = env.reset(seed=3)
    singles = [_belief_policy("SDJLS-Degradation-v0")[1] for _ in range(4)]
    policy.reset(4)
    u_applied = None
    for _ in range(8):
        x, k = info["state"], info["k"]
        u, out = policy.act_hidden(x, k, u_applied)
        for i, single in enumerate(singles):
            u_i, out_i = single.act(x[i], int(k[i]), None if u_applied is None else u_applied[i])
            np.testing.assert_allclose(u[i], u_i, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(out["belief"][i], out_i["belief"], rtol=1e-12)
            assert out_i["belief"].shape == (task.model.N,) and isinstance(out_i["rho"], float)
        _, _, _, _, info = env.step(u)
        u_applied = info["u"]


def test_the_inputs_applied_are_the_ones_the_filter_uses():
    """An environment that clips the actions: the filter must use info["u"]; with the inputs
    the policy returned it sees other steps (and other beliefs)."""
    task = TASKS["SDJLS-VTOL-v0"]
    env = sdjls_gym.SDJLSVectorEnv(num_envs=8, model=task.model, horizon=task.horizon,
                                   action_bound=1.0, observe="state")  # fmt: skip
    ctrl = BeliefRecedingHorizonController(task.model, task.K, **task.rhc)
    applied, returned = HiddenModePolicy(ctrl), HiddenModePolicy(ctrl)
    _, info = env.reset(seed=1)
    applied.reset(8)
    returned.reset(8)
    mode_filter = ModeFilter(task.model)
    belief = np.tile(mode_filter.initial_belief(), (8, 1))
    u_env = None
    for step in range(6):
        x, k = info["state"], info["k"]
        u, out = applied.act_hidden(x, k, u_env)
        _, out_r = returned.act_hidden(x, k)
        if step:
            np.testing.assert_allclose(out["belief"], belief, rtol=1e-12, atol=1e-300)
        _, _, _, _, info = env.step(u)
        assert np.any(info["u"] != u)  # clipped
        belief = mode_filter.step_batch(belief, x, info["u"], info["state"], k)
        u_env = info["u"]
    assert not np.allclose(out["belief"], out_r["belief"])


def test_certainty_equivalence_uses_the_most_probable_mode():
    task = TASKS["SDJLS-Macro-v0"]
    rhc = RecedingHorizonController(task.model, task.K, **task.rhc)
    policy = HiddenModePolicy(rhc)
    assert policy.rule == "most_probable"
    x = np.array([[2.0, 3.0], [1.0, 2.5], [3.0, 3.0]])
    policy.reset(3)
    u, info = policy.act_hidden(x, np.zeros(3, dtype=int))
    np.testing.assert_allclose(u, rhc.act_batch(x, np.zeros(3, dtype=int), 0)[0])
    # ties go to the smallest index: a prior of [0.4, 0.4, 0.2] decides with mode 0
    tie = HiddenModePolicy(rhc, prior=[0.2, 0.4, 0.4])
    u, info = tie.act_hidden(x, np.zeros(3, dtype=int))
    np.testing.assert_allclose(u, rhc.act_batch(x, np.ones(3, dtype=int), 0)[0])
    # a belief controller under the same rule answers as P3 with that mode
    ce = HiddenModePolicy(BeliefRecedingHorizonController(task.model, task.K, **task.rhc),
                          rule="most_probable", prior=[0.2, 0.4, 0.4])  # fmt: skip
    np.testing.assert_allclose(ce.act_hidden(x, np.zeros(3, dtype=int))[0], u, rtol=1e-9)


def test_an_impossible_observation_restarts_the_row_at_the_prior(other_model):
    """Rank-one noise: a state off the noise's range cannot follow; that row's belief goes back
    to the prior and is counted, the other row is filtered as usual."""
    K = np.zeros((2, 2, 3))
    ctrl = BeliefRecedingHorizonController(other_model, K, Psi=np.stack([np.eye(3)] * 2), xi=0.9)
    policy = HiddenModePolicy(ctrl, prior=[0.5, 0.5])
    x0 = np.tile(other_model.x0, (2, 1))
    u, _ = policy.act_hidden(x0, [0, 0])
    possible = other_model.A[1] @ x0[0] + other_model.B[1] @ u[0]  # mode 1, noise 0
    x1 = np.array([possible, possible + [5.0, -5.0, 5.0]])
    _, info = policy.act_hidden(x1, [1, 1])
    assert info["filter_resets"] == 1 and info["filter_reset"].tolist() == [False, True]
    np.testing.assert_allclose(info["belief"][1], [0.5, 0.5])
    expected = ModeFilter(other_model).step_batch([0.5, 0.5], x0[:1], u[:1], x1[:1], 0)
    np.testing.assert_allclose(info["belief"][0], expected[0], rtol=1e-12)
    assert policy.filter_resets == 1 and not np.isnan(info["belief"]).any()


def test_misuse_is_refused_by_name():
    task, policy = _belief_policy("SDJLS-Degradation-v0")
    rhc = RecedingHorizonController(task.model, task.K, **task.rhc)
    with raises_naming(ValueError, "rule", "belief"):
        HiddenModePolicy(rhc, rule="belief")
    with raises_naming(ValueError, "rule", "mode"):
        HiddenModePolicy(rhc, rule="mode")
    with raises_naming(TypeError, "controller", "None"):
        HiddenModePolicy(None)
    with raises_naming(ValueError, "prior", "0.9"):
        HiddenModePolicy(rhc, prior=[0.9, 0.9])
    x = np.tile(task.model.x0, (2, 1))
    with raises_naming(ValueError, "x", 2):
        policy.act_hidden(x, [3, 3])  # mid-episode without reset
    policy.act_hidden(x, [0, 0])
    with raises_naming(ValueError, "k[1]", 2):
        policy.act_hidden(x, [1, 2])  # skips a step
    with raises_naming(ValueError, "u_applied", "(3, 1)"):
        policy.act_hidden(x, [1, 1], np.zeros((3, 1)))


# ------------------------------------------------------------------ predict
def test_predict_runs_a_gymnasium_episode_with_the_mode_hidden():
    task, policy = _belief_policy("SDJLS-VTOL-v0", action_bound=TASKS["SDJLS-VTOL-v0"].action_bound)
    env = gym.make("SDJLS-VTOL-v0", observe="state")
    obs, info = env.reset(seed=0)
    state, steps, done = None, 0, False
    mode_filter = ModeFilter(task.model)
    belief = mode_filter.reset()
    while not done:
        action, state = policy.predict(obs, state=state, episode_start=np.array([steps == 0]))
        assert action.shape == (task.model.m,) and action.dtype == np.float32
        np.testing.assert_allclose(np.exp(state.log_belief[0]), belief, rtol=1e-6, atol=1e-12)
        x = obs[:-1].astype(np.float64)
        obs, reward, terminated, truncated, info = env.step(action)
        assert np.array_equal(info["u"], action.astype(np.float64))  # within the bound: applied
        belief = mode_filter.step(x, info["u"], obs[:-1].astype(np.float64), info["k"] - 1)
        done = terminated or truncated
        steps += 1
    assert steps == task.horizon and not info["diverged"]


def test_predict_works_with_stable_baselines3_evaluate_policy():
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.monitor import Monitor

    task, policy = _belief_policy("SDJLS-Degradation-v0", action_bound=5.0)
    env = Monitor(gym.make("SDJLS-Degradation-v0", observe="state"))
    rewards, lengths = evaluate_policy(policy, env, n_eval_episodes=3, return_episode_rewards=True)
    assert lengths == [task.horizon] * 3 and all(np.isfinite(rewards))


def test_predict_refuses_an_observation_that_is_not_state_only():
    task, policy = _belief_policy("SDJLS-Degradation-v0")
    with raises_naming(ValueError, "observation", "(5,)"):
        policy.predict(np.zeros(5))
    with raises_naming(ValueError, "observation", "0.51"):
        policy.predict(np.array([1.0, 0.0, 0.51]))  # not a multiple of 1 / 30
    with raises_naming(ValueError, "state", 15):
        policy.predict(np.array([1.0, 0.0, 0.5]))  # k = 15 of 30, but no memory


# ------------------------------------------------------------------ closed loop
@pytest.mark.parametrize("env_id", ["SDJLS-Degradation-v0", "SDJLS-VTOL-v0", "SDJLS-Solar-v0"])
def test_every_episode_stays_bounded_with_the_mode_hidden(env_id):
    """200 seeded episodes of the belief controller with the task's gains and settings, the
    mode hidden: none reaches the environment's divergence bound, and every decision is
    verified."""
    task, policy = _belief_policy(env_id)
    env = _vector_env(task, 200)
    _, info = env.reset(seed=0)
    policy.reset(200)
    u_applied, diverged, largest = None, np.zeros(200, bool), 0.0
    for _ in range(task.horizon):
        u, out = policy.act_hidden(info["state"], info["k"], u_applied)
        assert out["ok"].all() and out["filter_resets"] == 0
        _, _, _, _, info = env.step(u)
        u_applied = info["u"]
        diverged |= info["diverged"]
        largest = max(largest, float(np.abs(info["state"]).max()))
    assert not diverged.any() and largest < env.divergence_bound
