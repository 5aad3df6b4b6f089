"""Bad input gives a clear error before any work: the catalogue of the environments' checks.

Each case is checked by ``conftest.refused`` (and the ``no_solver`` trap).

``SDJLSEnv`` (construction, ``reset`` options, actions, ``step`` after the end),
``SDJLSVectorEnv`` and the wrappers; then a rejected action leaves the environment untouched,
and finite actions out of bounds are clipped, not refused.
"""

from __future__ import annotations

from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
from conftest import UNSHOWN, raises_naming, refused
from gymnasium.error import ResetNeeded

from sdjls_gym import SDJLSEnv, SDJLSVectorEnv
from sdjls_gym.systems.macro import PAPER_K
from sdjls_gym.wrappers import ResidualAction, ViolationPenalty

nan, inf = float("nan"), float("inf")


# ------------------------------------------------------------------------------------ helpers
def env_step(action):
    env = gym.make("SDJLS-Macro-v0")
    env.reset(seed=0)
    return env.step(action)


def env_step_after_the_end():
    env = gym.make("SDJLS-v0", model="macro", horizon=1)
    env.reset(seed=0)
    env.step(np.zeros(1, np.float32))
    return env.step(np.zeros(1, np.float32))


def vec_step(actions, num_envs=2):
    envs = SDJLSVectorEnv(num_envs, model="macro")
    envs.reset(seed=0)
    return envs.step(actions)


def case(call, error, name, value, id):
    return pytest.param(call, error, name, value, id=id)


# ------------------------------------------------------------------------------------ the table
CASES = [
    # ---- environment: construction and reset
    case(lambda c: SDJLSEnv(3), TypeError, "model", 3, "env-model"),
    # no value to show: the argument is missing (the full message: test_env.py, README quotes it)
    # gym.make("SDJLS-v0") re-raises it with the id appended
    case(lambda c: SDJLSEnv(), TypeError, "model", UNSHOWN, "env-no-model"),
    case(lambda c: SDJLSEnv("macr0"), ValueError, "model", "macr0", "env-preset"),
    case(lambda c: SDJLSEnv("macro", horizon=0), ValueError, "horizon", 0, "env-horizon"),
    case(lambda c: SDJLSEnv("macro", horizon=2.0), TypeError, "horizon", 2.0, "env-horizon-float"),
    case(
        lambda c: SDJLSEnv("macro", horizon=2**70), ValueError, "horizon", 2**70, "env-horizon-huge"
    ),
    case(
        lambda c: SDJLSEnv("macro", divergence_bound=True),
        TypeError,
        "divergence_bound",
        True,
        "env-div-bool",
    ),
    case(
        lambda c: SDJLSEnv("macro", divergence_bound=0.0),
        ValueError,
        "divergence_bound",
        0.0,
        "env-div-0",
    ),
    case(
        lambda c: SDJLSEnv("macro", divergence_bound=inf),
        ValueError,
        "divergence_bound",
        inf,
        "env-div-inf",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=0.0),
        ValueError,
        "action_bound",
        0.0,
        "env-bound-0",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=1e300),
        ValueError,
        "action_bound",
        1e300,
        "env-bound-float32",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=1e-300),
        ValueError,
        "action_bound",
        1e-300,
        "env-bound-subnormal",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=nan),
        ValueError,
        "action_bound",
        nan,
        "env-bound-nan",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=[1.0, 2.0]),
        ValueError,
        "action_bound",
        (2,),
        "env-bound-shape",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound="big"),
        TypeError,
        "action_bound",
        "big",
        "env-bound-string",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"x0": [1.0]}),
        ValueError,
        "options['x0']",
        (1,),
        "reset-x0",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options=[1, 2]),
        TypeError,
        "options",
        [1, 2],
        "reset-options-list",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"mode0": np.uint64(2**64 - 1)}),
        ValueError,
        "options['mode0']",
        np.uint64(2**64 - 1),
        "reset-mode0-uint64",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"mode0": True}),
        TypeError,
        "options['mode0']",
        True,
        "reset-mode0-bool",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"x0": [nan, 1.0]}),
        ValueError,
        "options['x0']",
        nan,
        "reset-x0-nan",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"mode0": 3}),
        ValueError,
        "options['mode0']",
        3,
        "reset-mode0",
    ),
    # ---- environment: actions (finite out-of-bounds actions are clipped: see below)
    case(lambda c: env_step(np.zeros(2, np.float32)), ValueError, "action", (2,), "step-shape"),
    case(lambda c: env_step(np.zeros((1, 1), np.float32)), ValueError, "action", (1, 1), "step-2d"),
    case(lambda c: env_step(np.zeros(0, np.float32)), ValueError, "action", (0,), "step-empty"),
    case(
        lambda c: env_step(np.array([nan], np.float32)),
        ValueError,
        "action",
        np.array([nan]),
        "step-nan",
    ),
    case(lambda c: env_step(np.array([inf])), ValueError, "action", np.array([inf]), "step-inf"),
    case(
        lambda c: env_step(np.array([-inf])),
        ValueError,
        "action",
        np.array([-inf]),
        "step-minus-inf",
    ),
    # NotANumberError: a ValueError and a TypeError
    # NotANumberError: a ValueError and a TypeError
    case(lambda c: env_step("a"), ValueError, "action", "a", "step-string"),
    case(lambda c: env_step(None), TypeError, "action", None, "step-none"),  # None is named
    # no argument: the message names the time (k = 1 = horizon) and what to call
    case(lambda c: env_step_after_the_end(), ResetNeeded, ("k", "reset()"), 1, "step-after-end"),
    # ---- vector environment
    case(lambda c: SDJLSVectorEnv(0, model="macro"), ValueError, "num_envs", 0, "vec-num-envs"),
    case(
        lambda c: SDJLSVectorEnv(2, model="macro", max_episode_steps=0),
        ValueError,
        "max_episode_steps",
        0,
        "vec-max-steps",
    ),
    case(
        lambda c: SDJLSVectorEnv(2, model="macro", horizon=2.0),
        TypeError,
        "horizon",
        2.0,
        "vec-horizon-float",
    ),
    case(lambda c: SDJLSVectorEnv(2), TypeError, "model", UNSHOWN, "vec-no-model"),  # missing
    case(
        lambda c: vec_step(np.zeros((3, 1), np.float32)), ValueError, "actions", (3, 1), "vec-shape"
    ),
    case(lambda c: vec_step(np.array([[0.0], [nan]])), ValueError, "actions[1]", nan, "vec-nan"),
    case(lambda c: vec_step(np.array([[inf], [0.0]])), ValueError, "actions[0]", inf, "vec-inf"),
    case(lambda c: vec_step([["a"], ["b"]]), ValueError, "actions", [["a"], ["b"]], "vec-string"),
    case(
        lambda c: SDJLSVectorEnv(2, model="macro").reset(options={"mode0": 5}),
        ValueError,
        "options['mode0']",
        5,
        "vec-reset",
    ),
    # ---- wrappers
    case(
        lambda c: ViolationPenalty(gym.make("SDJLS-Macro-v0"), -1.0),
        ValueError,
        "beta",
        -1.0,
        "penalty-beta",
    ),
    case(
        lambda c: ViolationPenalty(gym.make("SDJLS-Macro-v0"), "high"),
        TypeError,
        "beta",
        "high",
        "penalty-beta-string",
    ),
    case(
        lambda c: ViolationPenalty(gym.make("SDJLS-Macro-v0"), 10**400),
        ValueError,
        "beta",
        10**400,
        "penalty-beta-huge-int",
    ),
    case(
        lambda c: ViolationPenalty(gym.make("SDJLS-Macro-v0"), True),
        TypeError,
        "beta",
        True,
        "penalty-beta-bool",
    ),
    case(
        lambda c: ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K[0]),
        ValueError,
        "K",
        (1, 2),
        "residual-K",
    ),
    case(
        lambda c: ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K, nu_bound=0.0),
        ValueError,
        "nu_bound",
        0.0,
        "residual-nu-0",
    ),
    case(
        lambda c: ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K, nu_bound="big"),
        TypeError,
        "nu_bound",
        "big",
        "residual-nu-string",
    ),
    case(
        lambda c: ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K, nu_bound=1e39),
        ValueError,
        "nu_bound",
        1e39,
        "residual-nu-float32",
    ),
    case(
        lambda c: ResidualAction(
            gym.wrappers.RescaleAction(gym.make("SDJLS-Macro-v0"), np.float32(-1), np.float32(1)),
            PAPER_K,
        ),
        ValueError,
        "ResidualAction",  # the argument env is not named: the wrapper and the offending layer are
        "RescaleAction",
        "residual-over-rescale",
    ),
]


@pytest.fixture
def ctx(no_solver):
    """Every solver replaced by a trap (nothing may be solved)."""
    return SimpleNamespace()


@pytest.mark.parametrize(("call", "error", "name", "value"), CASES)
def test_bad_input_is_refused_naming_the_argument_and_the_value(ctx, call, error, name, value):
    """The error's type, the argument's name and the offending value; no warning on the way,
    raised by a check of this project, before any solver starts."""
    refused(error, name, value, lambda: call(ctx))


# ------------------------------------------------------------------------------------ no work
def _env_snapshot(env):
    base = env.unwrapped
    return (base.state, base.mode, base.k, base.np_random.bit_generator.state)


BAD_ACTIONS = [
    pytest.param(np.array([nan]), id="nan"),
    pytest.param(np.array([inf]), id="inf"),
    pytest.param(np.zeros(2), id="shape"),
    pytest.param("a", id="string"),
    # not numbers, never read as 1.0 (NotANumberError: both a ValueError and a TypeError)
    pytest.param(["1"], id="numeric-string"),
    pytest.param([True], id="bool-list"),
    pytest.param(np.array([True]), id="bool-array"),
    pytest.param(None, id="none"),
]


@pytest.mark.parametrize("action", BAD_ACTIONS)
def test_rejected_action_leaves_the_env_untouched(action):
    """A rejected action neither advances time nor consumes randomness: the episode continues
    exactly as if the bad call had not been made."""
    env, ref = gym.make("SDJLS-Macro-v0"), gym.make("SDJLS-Macro-v0")
    env.reset(seed=11)
    ref.reset(seed=11)
    env.step(np.array([3.0], np.float32))
    ref.step(np.array([3.0], np.float32))
    before = _env_snapshot(env)
    with raises_naming(ValueError, "action", UNSHOWN):
        env.step(action)
    after = _env_snapshot(env)
    np.testing.assert_array_equal(after[0], before[0])
    assert after[1:] == before[1:]
    out, expected = env.step(np.array([4.0], np.float32)), ref.step(np.array([4.0], np.float32))
    np.testing.assert_array_equal(out[0], expected[0])
    assert out[1:4] == expected[1:4]
    np.testing.assert_array_equal(out[4]["state"], expected[4]["state"])


@pytest.mark.parametrize(
    "actions",
    [
        np.array([[0.0], [nan]]),
        np.array([[inf], [0.0]]),
        np.zeros((3, 1)),
        np.zeros((2, 2)),
        [["1"], ["2"]],
        np.array([[True], [False]]),
    ],
    ids=["nan", "inf", "batch-size", "m", "numeric-strings", "bools"],
)
def test_rejected_actions_leave_the_vector_env_untouched(actions):
    envs, ref = SDJLSVectorEnv(2, model="macro"), SDJLSVectorEnv(2, model="macro")
    envs.reset(seed=5)
    ref.reset(seed=5)
    rng_state = envs.np_random.bit_generator.state
    with raises_naming(ValueError, "actions", UNSHOWN):
        envs.step(actions)
    assert envs.np_random.bit_generator.state == rng_state
    good = np.array([[1.0], [-2.0]])
    a, b = envs.step(good), ref.step(good)
    for x, y in zip(a[:4], b[:4], strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a[4]["state"], b[4]["state"])
    np.testing.assert_array_equal(a[4]["k"], [1, 1])


# ------------------------------------------------------------------------------------ clipping
EXTREME = [1e300, -1e300, float(np.finfo(np.float32).max), -float(np.finfo(np.float64).max)]


def test_out_of_bounds_finite_actions_are_clipped_and_documented():
    """Finite actions outside the Box, however large, are clipped to it without any overflow
    (RuntimeWarnings are errors in this suite), in the env and in the vector env; both
    docstrings say so."""
    for cls in (SDJLSEnv, SDJLSVectorEnv):  # "are clipped to it" / "clipping of actions"
        assert "clip" in (cls.__doc__ or ""), f"{cls.__name__} does not document the clipping"
    bound = 200.0
    env = gym.make("SDJLS-Macro-v0")
    for value in EXTREME:
        env.reset(seed=0)
        _, reward, _, _, info = env.step(np.array([value]))
        assert info["u"].tolist() == [np.sign(value) * bound]
        assert np.isfinite(reward) and np.all(np.isfinite(info["state"]))
    envs = SDJLSVectorEnv(len(EXTREME), model="macro")
    envs.reset(seed=0)
    _, rewards, _, _, infos = envs.step(np.array(EXTREME)[:, None])
    np.testing.assert_array_equal(infos["u"][:, 0], np.sign(EXTREME) * bound)
    assert np.all(np.isfinite(rewards)) and np.all(np.isfinite(infos["state"]))


def test_the_message_the_messages_module_quotes():
    """``sdjls_gym.messages`` shows this message as the shape of every one: kept word for word."""
    with pytest.raises(TypeError) as excinfo:
        SDJLSEnv("macro", horizon=2.0)
    assert str(excinfo.value) == "horizon = 2.0 is a float; expected an int >= 1"
