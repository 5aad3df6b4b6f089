"""SDJLSEnv's limits: episode end, actions, divergence and non-finite states, the horizon and
the spec's ``max_episode_steps``, and bad arguments (each error asserted by its type, the
argument's name and the offending value).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from conftest import doubling_model, noiseless_model, paper_numbers, raises_naming, run_episode
from gymnasium.error import ResetNeeded

from sdjls_gym import SDJLSEnv, SDJLSVectorEnv

# --------------------------------------------------------------------------- episode end


def test_truncation_after_exactly_horizon_steps(other_model, info_policy):
    env = gym.make("SDJLS-v0", model=other_model, horizon=7)
    env.reset(seed=0)
    flags = [env.step(np.zeros(2, dtype=np.float32))[2:4] for _ in range(7)]
    assert flags == [(False, False)] * 6 + [(False, True)]

    run = run_episode(gym.make("SDJLS-Macro-v0"), info_policy, seed=8)
    assert run["flags"] == [(False, False)] * 19 + [(False, True)]
    assert [info["k"] for info in run["info"]] == list(range(21))


def test_termination_on_divergence_with_finite_reward():
    """x_{k+1} = 2 x_k from x_0 = 1: 2, 4, 8, 16 > 10 ends the episode at step 4."""
    env = gym.make("SDJLS-v0", model=doubling_model(), horizon=20, divergence_bound=10.0)
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


# --------------------------------------------------------------------------- arguments
X0, MODE0 = "options['x0']", "options['mode0']"


@pytest.mark.parametrize(
    ("options", "error", "name", "value"),
    [
        ({"x0": [1.0, 2.0, 3.0]}, ValueError, X0, (3,)),
        ({"x0": [np.nan, 2.0]}, ValueError, X0, np.nan),
        ({"x0": [np.inf, 2.0]}, ValueError, X0, np.inf),
        ({"x0": [2e6, 2.0]}, ValueError, X0, 2e6),
        ({"x0": ["1", 2.0]}, TypeError, X0, "1"),
        ({"mode0": 3}, ValueError, MODE0, 3),
        ({"mode0": -1}, ValueError, MODE0, -1),
        ({"mode0": 2**70}, ValueError, MODE0, 2**70),
        ({"mode0": np.uint64(2**64 - 1)}, ValueError, MODE0, np.uint64(2**64 - 1)),
        ({"mode0": True}, TypeError, MODE0, True),
        ({"mode0": 1.0}, TypeError, MODE0, 1.0),
        ({"x_0": [1.0, 2.0]}, ValueError, "options", ["x_0"]),
        ([1, 2], TypeError, "options", [1, 2]),
        ("x0", TypeError, "options", "x0"),
    ],
)
def test_bad_reset_options_raise(options, error, name, value):
    """Every reset option is checked by the one validation module, with messages that name the
    option; a huge Python int or the largest uint64 is out of range, not wrapped."""
    env = gym.make("SDJLS-Macro-v0")
    with raises_naming(error, name, value):
        env.reset(seed=0, options=options)


@pytest.mark.parametrize(
    ("kwargs", "error", "name", "value"),
    [
        ({"horizon": 2.0}, TypeError, "horizon", 2.0),
        ({"horizon": True}, TypeError, "horizon", True),
        ({"horizon": 0}, ValueError, "horizon", 0),
        ({"horizon": 2**70}, ValueError, "horizon", 2**70),
        ({"horizon": np.uint64(2**64 - 1)}, ValueError, "horizon", np.uint64(2**64 - 1)),
        ({"divergence_bound": True}, TypeError, "divergence_bound", True),
        ({"divergence_bound": "1e6"}, TypeError, "divergence_bound", "1e6"),
        ({"divergence_bound": 1e31}, ValueError, "divergence_bound", 1e31),
        # the model's x0 = [2., 2.] is beyond divergence_bound = 1
        ({"divergence_bound": 1.0}, ValueError, ("x0", "divergence_bound"), np.array([2.0, 2.0])),
        ({"action_bound": 1e300}, ValueError, "action_bound", 1e300),
        ({"action_bound": 1e-300}, ValueError, "action_bound", 1e-300),
        ({"action_bound": 1e-40}, ValueError, "action_bound", 1e-40),
        ({"action_bound": 10**400}, ValueError, "action_bound", 10**400),
        ({"action_bound": [1e39]}, ValueError, "action_bound[0]", 1e39),
        ({"action_bound": [0.0]}, ValueError, "action_bound[0]", 0),
        ({"action_bound": True}, TypeError, "action_bound", True),
        ({"action_bound": "big"}, TypeError, "action_bound", "big"),
    ],
)
def test_bad_constructor_arguments(kwargs, error, name, value):
    """One rule per kind of argument: a float horizon is a TypeError like the controllers', a
    bool is never a number, and bounds that the float32 spaces cannot hold are rejected (a Box
    of +-inf or of zeros)."""
    with raises_naming(error, name, value):
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
    ("action", "value"),
    [
        (np.zeros(2, dtype=np.float32), (2,)),
        (np.zeros((1, 1), dtype=np.float32), (1, 1)),
        (np.zeros(0, dtype=np.float32), (0,)),
        (np.array([np.nan], dtype=np.float32), np.array([np.nan])),
        (np.array([np.inf], dtype=np.float32), np.array([np.inf])),
        (np.array([-np.inf], dtype=np.float32), np.array([-np.inf])),
    ],
    ids=["shape-2", "shape-1x1", "empty", "nan", "inf", "-inf"],
)
def test_bad_action_raises_naming_the_action(action, value):
    """The action's name and its shape (or the action itself, when it holds NaN or inf)."""
    env = gym.make("SDJLS-Macro-v0")
    env.reset(seed=0)
    with raises_naming(ValueError, "action", value):
        env.step(action)


def test_step_before_reset_raises():
    with pytest.raises(RuntimeError, match="reset"):
        SDJLSEnv("macro").step(np.zeros(1, dtype=np.float32))
    with pytest.raises(ResetNeeded):
        gym.make("SDJLS-Macro-v0").step(np.zeros(1, dtype=np.float32))


# --------------------------------------------------------------------------- non-finite states


# x_0 = [1e6, 1e6]: A x_0 is -1e309 (NaN in float64 arithmetic: 1e309 - 2e309), 1e309, or the
# stage cost x_0' Q x_0 = 2e312 overflows while the next state 0 is fine
BLOWUPS = {
    "nan-state": (noiseless_model([[1e303, -2e303], [1e303, -2e303]]), -2e12),
    "inf-state": (noiseless_model([[1e303, 0.0], [0.0, 1e303]]), -2e12),
    "cost-overflow": (
        noiseless_model(np.zeros((2, 2)), Q=1e300 * np.eye(2)),
        -1.7976931348623157e308,
    ),
    # Q x_0 = [inf, inf] with x_0 = [0, 1e10]: x_0' Q x_0 is inf * 0 + inf = NaN
    "cost-nan": (
        noiseless_model(np.zeros((2, 2)), Q=1e300 * np.ones((2, 2)), x0=(0.0, 1e10)),
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
            with raises_naming(ResetNeeded, ("k", "horizon", "reset()"), 3):
                env.step(np.zeros(2, np.float32))
            with pytest.raises(RuntimeError, match="reset"):
                env.step(np.zeros(2, np.float32))
    assert issubclass(ResetNeededError, ResetNeeded) and issubclass(ResetNeededError, RuntimeError)


def test_step_after_termination_raises_until_reset():
    model, _ = BLOWUPS["inf-state"]
    env = SDJLSEnv(model, horizon=5, divergence_bound=1e30)
    env.reset(seed=0)
    assert env.step(np.zeros(1, np.float32))[2] is True
    with raises_naming(RuntimeError, ("k", "reset()"), 1):  # terminated: diverged at k = 1
        env.step(np.zeros(1, np.float32))
    env.reset()
    assert env.step(np.zeros(1, np.float32))[2] is True


# --------------------------------------------------------------------------- horizon and spec


# the paper's gains (typed in conftest), to keep the macro example from diverging
_K = paper_numbers().K


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


def test_max_episode_steps_only_shortens_episodes():
    """``max_episode_steps`` may only shorten episodes. ``SDJLSVectorEnv`` (``gym.make_vec`` in
    its default mode) refuses a value above the horizon; ``gym.make`` adds Gymnasium's
    ``TimeLimit`` out of the environment's sight (the environment is given a spec without the
    limit), so there the rule is documented, not enforced: episodes still end at the horizon."""
    with raises_naming(ValueError, ("max_episode_steps", "horizon"), 40):
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


def test_sdjls_v0_without_a_model_says_what_to_pass():
    """The README says this error tells what to pass (a model, a preset name or a dict): the
    one message of the environments kept word for word."""
    for make in (
        lambda: gym.make("SDJLS-v0"),
        lambda: gym.make_vec("SDJLS-v0", num_envs=2, vectorization_mode="vector_entry_point"),
        lambda: SDJLSEnv(),
        lambda: SDJLSVectorEnv(2),
    ):
        with pytest.raises(
            TypeError, match=r"^model is missing; pass an SDJLSModel, a preset name"
        ):
            make()
