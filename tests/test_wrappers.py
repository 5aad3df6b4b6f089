"""ViolationPenalty and ResidualAction, checked against hand computations with W = 0."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from conftest import raises_naming

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
    with raises_naming(ValueError, "beta", beta):
        ViolationPenalty(gym.make("SDJLS-Macro-v0"), beta)
    env = ViolationPenalty(gym.make("SDJLS-Macro-v0"), 1.0)
    with raises_naming(ValueError, "beta", beta):
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
    with raises_naming(ValueError, "K", (2, 1, 2)):
        ResidualAction(env, paper.K[:2])
    with raises_naming(ValueError, "K", np.nan):
        ResidualAction(env, np.full((3, 1, 2), np.nan))
    with raises_naming(ValueError, "nu_bound", -1.0):
        ResidualAction(env, paper.K, nu_bound=-1.0)
    with pytest.raises(TypeError):
        ResidualAction(gym.make("Pendulum-v1"), paper.K)
    wrapped = ResidualAction(env, paper.K)
    wrapped.reset(seed=0)
    nan_action = np.array([np.nan], dtype=np.float32)
    with raises_naming(ValueError, "action (nu)", nan_action):
        wrapped.step(nan_action)


@pytest.mark.parametrize(
    ("beta", "error"),
    [(10**400, ValueError), (True, TypeError), ("10", TypeError), (None, TypeError)],
    ids=["int-beyond-float64", "bool", "str", "none"],
)
def test_violation_penalty_beta_follows_the_number_rule(beta, error):
    with raises_naming(error, "beta", beta):
        ViolationPenalty(gym.make("SDJLS-Macro-v0"), beta)
    env = ViolationPenalty(gym.make("SDJLS-Macro-v0"), 10**3)
    assert env.beta == 1000.0 and type(env.beta) is float


def _rescaled(env):
    import warnings

    from gymnasium.wrappers import RescaleAction

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # RescaleAction's own float32 precision notice
        return RescaleAction(env, -1.0, 1.0)


@pytest.mark.parametrize(
    ("below", "name"),
    [
        (_rescaled, "RescaleAction"),
        (lambda env: gym.wrappers.ClipAction(env), "ClipAction"),
        (lambda env: ResidualAction(env, np.zeros((3, 1, 2))), "ResidualAction"),
        (lambda env: gym.wrappers.TransformAction(env, lambda a: 2 * a, None), "TransformAction"),
    ],
    ids=["rescale", "clip", "residual", "transform"],
)
def test_residual_action_refuses_wrappers_that_change_the_action_below_it(paper, below, name):
    """``ResidualAction(RescaleAction(env), K)`` would apply ``u = K x + nu`` through the rescaling
    (``u = +-200`` at ``nu = 0``): it is refused with a message naming the wrapper and saying
    where to put it, in the words of the README."""
    with raises_naming(ValueError, "ResidualAction", name) as excinfo:
        ResidualAction(below(gym.make("SDJLS-Macro-v0")), paper.K)
    assert "RescaleAction(ResidualAction(env, K), -1.0, 1.0)" in str(excinfo.value)


def test_rescale_on_top_of_residual_action_applies_K_x_at_zero(quiet_paper_model, paper):
    """The supported order: the agent's 0 is nu = 0, so the applied u is K_theta x exactly."""
    env = _rescaled(ResidualAction(_quiet_env(quiet_paper_model), paper.K, nu_bound=100.0))
    _, info = env.reset(seed=0, options={"x0": [1.5, -0.5], "mode0": 1})
    x = info["state"]
    *_, info = env.step(np.zeros(1, np.float32))
    np.testing.assert_allclose(info["u"], paper.K[1] @ x, rtol=1e-12, atol=1e-12)
    *_, info2 = env.step(np.ones(1, np.float32))  # the agent's 1 is nu = nu_bound
    np.testing.assert_allclose(info2["u"], paper.K[info["mode"]] @ info["state"] + 100.0, rtol=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "error", "name", "value"),
    [
        ({"nu_bound": 1e300}, ValueError, "nu_bound", 1e300),
        ({"nu_bound": True}, TypeError, "nu_bound", True),
        ({"K": "abc"}, TypeError, "K", "abc"),
        ({"K": np.full((3, 1, 2), np.inf)}, ValueError, "K", np.inf),
    ],
)
def test_residual_action_arguments(paper, kwargs, error, name, value):
    with raises_naming(error, name, value):
        ResidualAction(gym.make("SDJLS-Macro-v0"), **{"K": paper.K, **kwargs})
