"""ViolationPenalty and ResidualAction, checked against hand computations with W = 0."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from sdjls_gym.wrappers import ResidualAction, ViolationPenalty


def _quiet_env(model, **kwargs):
    return gym.make("SDJLS-v0", model=model, horizon=20, **kwargs)


# --------------------------------------------------------------------------- ViolationPenalty


def test_violation_penalty_subtracts_beta_times_cost(quiet_paper_model, paper):
    """Two steps from chosen states, with the band [2.5, 5.5] of k = 1: from [0, 4] in mode 2
    (slump), u = 30 gives x_1 = [4, 9.2], above it (cost 1); from [0, 1] in mode 0 (normal),
    u = 0 gives x_1 = [1, 3.2], inside (cost 0)."""
    beta = 2.5
    env = ViolationPenalty(_quiet_env(quiet_paper_model), beta)
    seen_costs = set()
    for x0, mode0, u in (([0.0, 4.0], 2, 30.0), ([0.0, 1.0], 0, 0.0)):
        _, info = env.reset(seed=0, options={"x0": x0, "mode0": mode0})
        _, reward, _, _, info = env.step(np.array([u], dtype=np.float32))
        x0 = np.array(x0)
        unpenalized = -(x0 @ paper.Q[mode0] @ x0 + paper.R[mode0, 0, 0] * u**2)
        x1 = paper.A[mode0] @ x0 + paper.B @ [u]
        cost = float(np.any(paper.G @ x1 - paper.H(1) > 0))
        assert info["cost"] == cost
        np.testing.assert_allclose(info["reward_unpenalized"], unpenalized, rtol=1e-12)
        np.testing.assert_allclose(reward, unpenalized - beta * cost, rtol=1e-12)
        assert isinstance(reward, float)
        seen_costs.add(cost)
    assert seen_costs == {0.0, 1.0}


def test_violation_penalty_beta_can_change(quiet_paper_model):
    env = ViolationPenalty(_quiet_env(quiet_paper_model), 0.0)
    env.reset(seed=0, options={"x0": [0.0, 4.0], "mode0": 2})
    _, reward, _, _, info = env.step(np.array([30.0], dtype=np.float32))
    assert info["cost"] == 1.0 and reward == info["reward_unpenalized"]
    env.beta = 10.0
    env.reset(seed=0, options={"x0": [0.0, 4.0], "mode0": 2})
    _, reward, _, _, info = env.step(np.array([30.0], dtype=np.float32))
    assert reward == info["reward_unpenalized"] - 10.0


@pytest.mark.parametrize("beta", [-1.0, -1e-12, float("nan"), float("inf")])
def test_violation_penalty_rejects_bad_beta(beta):
    with pytest.raises(ValueError, match="beta"):
        ViolationPenalty(gym.make("SDJLS-Macro-v0"), beta)
    env = ViolationPenalty(gym.make("SDJLS-Macro-v0"), 1.0)
    with pytest.raises(ValueError, match="beta"):
        env.beta = beta
    assert env.beta == 1.0


# --------------------------------------------------------------------------- ResidualAction


def test_residual_action_applies_K_theta_x_plus_nu(quiet_paper_model, paper):
    """With the paper's K, A_i + B K_i = [[0, 1], [0, 0]]: x_{k+1} = [x_k(2), nu_k] in every
    mode. Checked together with u_k = K_theta x_k + nu_k, step by step."""
    env = ResidualAction(_quiet_env(quiet_paper_model), paper.K, nu_bound=100.0)
    assert env.action_space.shape == (1,)
    assert env.action_space.low[0] == -100.0 and env.action_space.high[0] == 100.0
    _, info = env.reset(seed=4, options={"x0": [1.5, -0.5]})
    rng = np.random.default_rng(1)
    modes = set()
    for _ in range(20):
        x, mode = info["state"], info["mode"]
        nu = rng.uniform(-5.0, 5.0, size=1).astype(np.float32)
        _, _, _, truncated, info = env.step(nu)
        u = paper.K[mode] @ x + nu.astype(np.float64)
        np.testing.assert_allclose(info["u"], u, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(
            info["state"], paper.A[mode] @ x + paper.B @ u, rtol=1e-12, atol=1e-12
        )
        np.testing.assert_allclose(info["state"], [x[1], nu[0]], atol=1e-9)
        modes.add(mode)
    assert truncated
    assert len(modes) == 3


def test_residual_action_errors(paper):
    env = gym.make("SDJLS-Macro-v0")
    with pytest.raises(ValueError, match="K"):
        ResidualAction(env, paper.K[:2])
    with pytest.raises(ValueError, match="K"):
        ResidualAction(env, np.full((3, 1, 2), np.nan))
    with pytest.raises(ValueError, match="nu_bound"):
        ResidualAction(env, paper.K, nu_bound=-1.0)
    with pytest.raises(TypeError):
        ResidualAction(gym.make("Pendulum-v1"), paper.K)
    wrapped = ResidualAction(env, paper.K)
    wrapped.reset(seed=0)
    with pytest.raises(ValueError, match="nu"):
        wrapped.step(np.array([np.nan], dtype=np.float32))
