"""Every input checked before any work (issue 28, section 3): bools among batch indices, Python
ints beyond float64, LMI data that overflows, wrappers ``policy_for`` cannot act through, and
one answer for a step that overflows float64 in both environments.

Each test asserts the exception type, the argument's name and the offending value; the checks
that promise "before any solver runs" replace the solvers by a trap.
"""

from __future__ import annotations

import json
import warnings

import cvxpy as cp
import gymnasium as gym
import numpy as np
import osqp
import pytest
from gymnasium.wrappers import (
    MaxAndSkipObservation,
    RecordEpisodeStatistics,
    RescaleAction,
    TimeLimit,
)

from controllers import (
    LinearFeedbackController,
    LMIInfeasibleError,
    MJLSLQRController,
    RecedingHorizonController,
    ScenarioTreeController,
    UnconstrainedRecedingHorizonController,
    check_proposition2,
    policy_for,
    second_moment_spectral_radius,
    synthesize_gains,
    verify_mean_square_bound,
)
from sdjls_gym import SDJLSEnv, SDJLSModel, SDJLSVectorEnv, load_model
from sdjls_gym.model_files import _to_toml
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, PAPER_X, PAPER_Y, macro
from sdjls_gym.wrappers import ScaleObservationReward, ViolationPenalty

HUGE = 10**400  # a Python int beyond float64 (1.8e308)


@pytest.fixture
def no_solver(monkeypatch):
    """Fail the test if OSQP or cvxpy is asked to solve anything."""

    def trap(*args, **kwargs):
        raise AssertionError("a solver ran before the input was checked")

    monkeypatch.setattr(osqp.OSQP, "solve", trap)
    monkeypatch.setattr(cp.Problem, "solve", trap)


def raises(error, match, call):
    """``call()`` raises ``error`` matching ``match``, with no warning on the way."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(error, match=match) as info:
            call()
    return info.value


# ------------------------------------------------------------------------- a. bools as indices
CONTROLLERS = {
    "linear": lambda: LinearFeedbackController(macro(), PAPER_K),
    "mjls-lq": lambda: MJLSLQRController(macro()),
    "rhc": lambda: RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC),
    "rhc-cvxpy": lambda: RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC, solver="cvxpy"),
    "unconstrained": lambda: UnconstrainedRecedingHorizonController(
        macro(), PAPER_K, Psi=PAPER_RHC["Psi"], nu_bound=PAPER_RHC["nu_bound"]
    ),
    "tree": lambda: ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=2),
}

BOOL_INDICES = {
    "mode-list": ([0, True], 0, r"^mode\[1\] = True is a bool"),
    "mode-tuple-numpy-bool": ((np.True_, 0), [1, 2], r"^mode\[0\] = np\.True_ is a bool"),
    "k-list": ([0, 1], [True, 2], r"^k\[0\] = True is a bool"),
    "k-scalar": ([0, 1], False, r"^k = False is a bool"),
    "mode-float-in-list": ([0, 1.0], 0, r"^mode\[1\] = 1\.0 is a float"),
}


@pytest.mark.parametrize("which", list(CONTROLLERS))
@pytest.mark.parametrize("case", list(BOOL_INDICES))
def test_act_batch_refuses_a_bool_among_modes_or_times(which, case, no_solver):
    """numpy reads ``[0, True]`` as ``[0, 1]``: every controller's act_batch refuses it, by
    entry, before any solver runs (README: a bool is never a number)."""
    ctrl = CONTROLLERS[which]()
    modes, k, match = BOOL_INDICES[case]
    raises(TypeError, match, lambda: ctrl.act_batch(np.ones((2, 2)), modes, k))


def test_model_band_refuses_a_bool_among_times():
    raises(TypeError, r"^k\[0\] = True is a bool", lambda: macro().H([True, 2]))
    np.testing.assert_array_equal(macro().H([1, 2]), macro().H(np.array([1, 2])))


# ------------------------------------------------------------------ b. ints beyond float64
def _model_file(tmp_path, suffix):
    data = {**macro().to_dict(), "x0": [0.0, 0.0]}
    if suffix == ".json":
        text = json.dumps(data).replace('"x0": [0.0', f'"x0": [{HUGE}')
    else:
        text = _to_toml(data).replace("x0 = [0.0", f"x0 = [{HUGE}")
    path = tmp_path / f"huge{suffix}"
    path.write_text(text, encoding="utf-8")
    return path


def _stepped_env():
    env = gym.make("SDJLS-Macro-v0")
    env.reset(seed=0)
    return env


def _stepped_vector_env():
    envs = SDJLSVectorEnv(2, model=macro())
    envs.reset(seed=0)
    return envs


HUGE_INTS = {
    "env-step": (lambda _: _stepped_env().step([HUGE]), r"^action has an entry 1000"),
    "env-step-negative": (lambda _: _stepped_env().step([-HUGE]), r"^action has an entry -1000"),
    "env-step-array": (
        lambda _: _stepped_env().step(np.array([HUGE], dtype=object)),
        r"^action has an entry 1000",
    ),
    "vector-step": (
        lambda _: _stepped_vector_env().step([[0.0], [HUGE]]),
        r"^actions has an entry 1000.* at index \(1, 0\)",
    ),
    "act": (
        lambda _: RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC).act([0.0, HUGE], 0, 0),
        r"^x has an entry 1000.* at index \(1,\)",
    ),
    "act-batch": (
        lambda _: LinearFeedbackController(macro(), PAPER_K).act_batch([[HUGE, 0.0]], [0], 0),
        r"^x has an entry 1000.* at index \(0, 0\)",
    ),
    "predict": (
        lambda _: LinearFeedbackController(macro(), PAPER_K).predict([HUGE, 0, 1, 0, 0, 0]),
        r"^observation has an entry 1000",
    ),
    "model-x0": (
        lambda _: SDJLSModel(**{**macro().to_dict(), "x0": [HUGE, 0]}),
        r"^x0 has an entry 1000",
    ),
    "model-A": (
        lambda _: SDJLSModel(**{**macro().to_dict(), "A": [[1.0, 0.0], [0.0, -HUGE]]}),
        r"^A has an entry -1000.* at index \(1, 1\)",
    ),
    "reset-x0": (
        lambda _: gym.make("SDJLS-Macro-v0").reset(options={"x0": [0, HUGE]}),
        r"^options\['x0'\] has an entry 1000",
    ),
    "action-bound": (
        lambda _: gym.make("SDJLS-Macro-v0", action_bound=[HUGE]),
        r"^action_bound has an entry 1000",
    ),
    "json-file": (
        lambda tmp: load_model(_model_file(tmp, ".json")),
        r"^model file .*huge\.json': x0 has an entry 1000",
    ),
    "toml-file": (
        lambda tmp: load_model(_model_file(tmp, ".toml")),
        r"^model file .*huge\.toml': x0 has an entry 1000",
    ),
}


@pytest.mark.parametrize("case", list(HUGE_INTS))
def test_an_int_beyond_float64_is_a_value_error_naming_the_argument(case, tmp_path, no_solver):
    """``10**400`` is a ValueError naming the argument and showing the value, as ``1e400`` is,
    not numpy's bare OverflowError."""
    call, match = HUGE_INTS[case]
    error = raises(ValueError, match, lambda: call(tmp_path))
    assert "beyond the range of float64" in str(error) and "about 10**400" in str(error)


# ------------------------------------------------------------------------ c. LMI inputs
def test_mean_square_bound_refuses_a_nu_bound_whose_square_overflows(no_solver):
    model = macro()
    raises(
        ValueError,
        r"^nu_bound = 1e\+200 is out of range; expected a finite number in \[0, 1\.34078e\+154\]",
        lambda: verify_mean_square_bound(model, PAPER_K, nu_bound=1e200),
    )
    raises(ValueError, r"^nu_bound = 1000.* is not finite", lambda: verify_mean_square_bound(
        model, PAPER_K, nu_bound=HUGE
    ))  # fmt: skip


@pytest.mark.parametrize("scale", [1e160, 1e200, 1e300])
def test_gains_whose_products_overflow_are_named_before_any_solver(scale, no_solver):
    """K of 1e200 gave cvxpy's "Problem data contains NaN or Inf" (and numpy's LinAlgError in
    the spectral radius): now a ValueError naming K and its size, before any solver runs."""
    model = macro()
    K = np.full_like(PAPER_K, scale)
    for call in (verify_mean_square_bound, second_moment_spectral_radius):
        raises(
            ValueError,
            rf"^K has entries up to {scale:.0e}".replace("+", r"\+"),
            lambda c=call: c(model, K),
        )


def test_gains_that_are_clearly_not_mean_square_stable_are_infeasible_without_a_solver(no_solver):
    """K of 1e20 made Clarabel fail ("try another solver"); the second-moment operator of
    P_in alone has radius 1e40 > 1, which settles the LMIs' infeasibility without a solver."""
    error = raises(
        LMIInfeasibleError,
        r"could not be certified \(no solver run\).*model\.P_in.*radius 1e\+40",
        lambda: verify_mean_square_bound(macro(), np.full_like(PAPER_K, 1e20)),
    )
    assert isinstance(error, ValueError)


def test_a_certificate_whose_bound_overflows_names_the_argument():
    """delta = 1e308 (or kappa = 1e-320) makes beta2 overflow: a ValueError naming them, not a
    certificate with beta2 = inf."""
    model = macro()
    raises(ValueError, r"beta2 .* overflows float64 with delta = 1e\+308", lambda: (
        verify_mean_square_bound(model, PAPER_K, delta=1e308)
    ))  # fmt: skip
    raises(ValueError, r"overflows float64 with delta = 1, kappa = 1e-320", lambda: (
        verify_mean_square_bound(model, PAPER_K, delta=1, kappa=1e-320)
    ))  # fmt: skip


def test_proposition2_names_X_and_Y_when_their_products_overflow():
    scale = 1e308 / np.max(np.abs(PAPER_X))
    raises(ValueError, r"^X and Y are too large: A_0 X_0 \+ B_0 Y_0 overflows", lambda: (
        check_proposition2(macro(), PAPER_X * scale, PAPER_Y)
    ))  # fmt: skip


def test_lmi_flags_and_the_bound_follow_the_argument_rules(no_solver):
    model = macro()
    raises(TypeError, r"^verbose = 'yes' is a str", lambda: synthesize_gains(model, verbose="yes"))
    raises(TypeError, r"^objective = \['max_margin'\] is a list", lambda: synthesize_gains(
        model, objective=["max_margin"]
    ))  # fmt: skip


def test_certificate_bound_checks_k_and_x0():
    cert = verify_mean_square_bound(macro(), PAPER_K)
    raises(TypeError, r"^k = True is a bool", lambda: cert.bound(True, [1.0, 1.0]))
    raises(TypeError, r"^k\[1\] = True is a bool", lambda: cert.bound([0, True], [1.0, 1.0]))
    raises(ValueError, r"^x0 has an entry 1000", lambda: cert.bound(1, [HUGE, 0]))
    assert cert.bound(2, [1.0, 1.0]) == pytest.approx(cert.bound(np.array([2]), [1, 1])[0])


# ------------------------------------------------------------------------------ d. policy_for
REFUSED_WRAPPERS = {
    "MaxAndSkipObservation": lambda: MaxAndSkipObservation(gym.make("SDJLS-Macro-v0")),
    # the clip 1e6 keeps the Box of the raw env, the state is doubled
    "ScaleObservationReward": lambda: ScaleObservationReward(
        gym.make("SDJLS-Macro-v0"), x_scale=0.5, obs_clip=1e6
    ),
    "MyTimeLimit": lambda: type("MyTimeLimit", (TimeLimit,), {})(
        gym.make("SDJLS-Macro-v0").unwrapped, 20
    ),
}


@pytest.mark.parametrize("name", list(REFUSED_WRAPPERS))
def test_policy_for_refuses_a_wrapper_it_does_not_know_by_name(name):
    """A wrapper that keeps the observation space may still change the observation
    (``MaxAndSkipObservation``; a rescaling whose clip leaves the Box as it was): the controller
    would act on a wrong state. Only a known list is acted through, matched by exact type."""
    env = REFUSED_WRAPPERS[name]()
    assert env.observation_space == env.unwrapped.observation_space
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    raises(ValueError, rf"^env has a {name} ", lambda: policy_for(ctrl, env))


def test_policy_for_acts_through_the_known_wrappers():
    """Reward, statistics and time-limit wrappers around a rescaled env: the episode is the raw
    env's (to the float32 resolution of an action in [-1, 1])."""
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    raw = gym.make("SDJLS-Macro-v0")
    obs, info = raw.reset(seed=3)
    raw_us = []
    for _ in range(20):
        obs, *_, info = raw.step(ctrl.predict(obs)[0])
        raw_us.append(info["u"])
    env = ViolationPenalty(
        RecordEpisodeStatistics(RescaleAction(gym.make("SDJLS-Macro-v0"), -1.0, 1.0)), 2.0
    )
    policy = policy_for(ctrl, env)
    obs, info = env.reset(seed=3)
    us = []
    for _ in range(20):
        obs, *_, info = env.step(policy.predict(obs)[0])
        us.append(info["u"])
    np.testing.assert_allclose(us, raw_us, rtol=0, atol=5e-4)


def _obs(x=(1.0, 1.0), one_hot=(1.0, 0.0, 0.0), tau=0.0):
    return np.array([*x, *one_hot, tau], dtype=np.float32)


@pytest.mark.parametrize(
    "make",
    [
        lambda: LinearFeedbackController(macro(), PAPER_K),
        lambda: RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC),
    ],
    ids=["linear", "rhc"],
)
def test_policy_for_predict_checks_time_and_the_one_hot_mode(make):
    """``policy_for(...).predict`` decoded k = round(7.3 * 20) = 146 (and any mode part by
    argmax); now time must be a multiple of 1 / horizon in [0, 1], for every controller, and the
    mode part one-hot."""
    policy = policy_for(make(), gym.make("SDJLS-Macro-v0"))
    raises(ValueError, r"time entry k / horizon = 7\.3 does not decode", lambda: (
        policy.predict(_obs(tau=7.3))
    ))  # fmt: skip
    raises(ValueError, r"time entry k / horizon = 0\.33 ", lambda: policy.predict(_obs(tau=0.33)))
    for bad in ((1.0, 1.0, 0.0), (0.0, 0.0, 0.0), (0.5, 0.5, 0.0), (2.0, -1.0, 0.0)):
        shown = r"\[\s*" + r",\s*".join(rf"{v:g}\.?" for v in bad)
        raises(ValueError, rf"^observation's mode part {shown}.*is not one-hot", lambda b=bad: (
            policy.predict(_obs(one_hot=b))
        ))  # fmt: skip
    batch = np.stack([_obs(), _obs(one_hot=(0.0, 1.0, 1.0))])
    raises(ValueError, r"^observation\[1\]'s mode part", lambda: policy.predict(batch))
    action, _ = policy.predict(_obs(one_hot=(0.0, 1.0, 0.0), tau=0.05))
    assert action.shape == (1,)


def test_controller_predict_refuses_a_mode_part_that_is_not_one_hot():
    ctrl = LinearFeedbackController(macro(), PAPER_K)
    raises(ValueError, r"mode part \[0\.5, 0\.5, 0\. \] is not one-hot", lambda: (
        ctrl.predict(_obs(one_hot=(0.5, 0.5, 0.0)))
    ))  # fmt: skip


# ------------------------------------------------------------------- e. an overflowing step
def _overflow_model(A, B=((0.0,), (1.0,)), G=((0.0, 1.0),), x0=(1e10, 1e10)):
    """One mode, n = 2, W = 0 (no noise): both envs step x_1 = A x_0 + B u_0 exactly alike."""
    return SDJLSModel(
        A=[A], B=[list(b) for b in B], P_in=[[1.0]], P_out=[[1.0]], G=[list(g) for g in G],
        H0=[1.0] * len(G), Q=np.eye(2), R=[[1.0]], x0=list(x0), W=np.zeros((2, 2)),
    )  # fmt: skip


def _both_steps(model, action, divergence_bound=1e30):
    env = SDJLSEnv(model, horizon=5, divergence_bound=divergence_bound, action_bound=3e38)
    env.reset(seed=0)
    single = env.step(np.array(action))
    envs = SDJLSVectorEnv(3, model=model, horizon=5, divergence_bound=divergence_bound,
                          action_bound=3e38)  # fmt: skip
    envs.reset(seed=0)
    vector = envs.step(np.tile(np.array(action, dtype=np.float64), (3, 1)))
    return single, vector


def _assert_same_answer(single, vector):
    obs, reward, terminated, truncated, info = single
    obs_v, reward_v, term_v, trunc_v, infos = vector
    for b in range(3):
        np.testing.assert_array_equal(infos["state"][b], info["state"])
        np.testing.assert_array_equal(infos["constraint_values"][b], info["constraint_values"])
        np.testing.assert_array_equal(obs_v[b], obs)
        assert reward_v[b] == reward and term_v[b] == terminated and trunc_v[b] == truncated
        assert infos["diverged"][b] == info["diverged"]
        assert infos["in_region"][b] == info["in_region"]
        assert infos["violations"][b].tolist() == info["violations"].tolist()


@pytest.mark.parametrize(
    ("A", "state"),
    [
        # 1e310 - 2e310: NaN in float64 (SDJLSEnv gave [0, nan]), exactly -1e310
        ([[0.0, 0.0], [1e300, -2e300]], [0.0, -np.inf]),
        # the same with the larger term second
        ([[0.0, 0.0], [-2e300, 1e300]], [0.0, -np.inf]),
        # 1e310 - 1e310: NaN in float64, exactly 0: the step does not diverge
        ([[0.0, 0.0], [1e300, -1e300]], [0.0, 0.0]),
        # 1e310 + 1e310: +inf in any order
        ([[1.0, 0.0], [1e300, 1e300]], [1e10, np.inf]),
    ],
    ids=["nan-is-minus-inf", "nan-is-minus-inf-swapped", "nan-is-zero", "inf"],
)
def test_an_overflowing_step_gives_one_answer_in_both_envs(A, state):
    """The same overflowing step gave state [0, nan] in SDJLSEnv and [0, -inf] in
    SDJLSVectorEnv. Both now give the exact next state rounded to float64 (+-inf beyond its
    range, never NaN), with its constraint values, diverged flag and observation."""
    model = _overflow_model(A)
    single, vector = _both_steps(model, [0.0])
    info = single[4]
    assert info["state"].tolist() == state
    diverged = not np.all(np.isfinite(state))
    assert info["diverged"] is diverged and single[2] is diverged
    assert not np.isnan(info["constraint_values"]).any()
    _assert_same_answer(single, vector)


def test_an_overflowing_step_from_a_huge_action_gives_one_answer():
    """A huge action on a huge input matrix: B u = 1e300 * 3e38 overflows with a sign set by u."""
    model = _overflow_model([[0.5, 0.0], [0.0, 0.5]], B=((0.0,), (-1e300,)), x0=(1.0, 1.0))
    single, vector = _both_steps(model, [3e38])
    assert single[4]["state"].tolist() == [0.5, -np.inf] and single[4]["diverged"]
    assert single[4]["constraint_values"].tolist() == [-np.inf]
    _assert_same_answer(single, vector)


def test_random_overflowing_steps_agree_between_the_envs():
    """Seeded sweep: 300 models with entries in {0, +-0.5, +-1, 1e10, +-1e300, +-1e308} and
    states and actions up to 1e30 (most steps overflow). The two envs agree on which entries
    are infinite and their signs, on the diverged flag and on the reward, and never give NaN.
    (Finite entries may differ by the round-off of a cancellation, as on any step.)"""
    rng = np.random.default_rng(28)
    values = [0.0, 0.5, -0.5, 1.0, -1.0, 1e10, 1e300, -1e300, 1e308, -1e308]
    overflowed = 0
    for _ in range(300):
        A = rng.choice(values, size=(2, 2))
        B = rng.choice(values, size=(2, 1))
        G = rng.choice([1.0, -1.0, 0.5], size=(1, 2))
        model = _overflow_model(A, B=B, G=G, x0=rng.choice([0.0, 1.0, -1e30, 1e30], size=2))
        single, vector = _both_steps(model, rng.choice([0.0, 1e30, -1e30, 1.0], size=1))
        info, infos = single[4], vector[4]
        overflowed += not np.all(np.isfinite(info["state"]))
        for a, b in ((info["state"], infos["state"][0]), (single[1], vector[1][0])):
            a, b = np.asarray(a), np.asarray(b)
            assert not np.isnan(a).any() and not np.isnan(b).any()
            np.testing.assert_array_equal(np.isinf(a) * np.sign(a), np.isinf(b) * np.sign(b))
        assert info["diverged"] == infos["diverged"][0] and single[2] == vector[2][0]
        assert not np.isnan(info["constraint_values"]).any()
        assert not np.isnan(infos["constraint_values"]).any()
    assert overflowed > 100  # the sweep does exercise overflow


# ------------------------------------------------------------- found by the hostile round
ODD_ACTIONS = {
    # numpy casts dates to numbers of days: not a number
    "datetime64": (np.array(["2020-01-01"], dtype="datetime64[D]"), TypeError, r"datetime64"),
    "timedelta64": (np.array([3], dtype="timedelta64[s]"), TypeError, r"timedelta64"),
    # the data under a mask is not the user's value
    "masked": (np.ma.masked_array([0.5], mask=[True]), ValueError, r"masked \(missing\) entry"),
    # a longdouble beyond float64: numpy's cast warned "overflow" before the error
    "longdouble-1e400": (np.array([np.longdouble("1e400")]), ValueError, r"inf"),
}


@pytest.mark.parametrize("case", list(ODD_ACTIONS))
def test_odd_arrays_are_refused_by_name_without_a_warning(case):
    value, error, match = ODD_ACTIONS[case]
    raises(error, rf"^action.*{match}", lambda: _stepped_env().step(value))
    raises(error, rf"^actions.*{match}", lambda: _stepped_vector_env().step(
        value.reshape(1, 1).repeat(2, axis=0) if case != "masked" else
        np.ma.masked_array([[0.5], [0.5]], mask=[[False], [True]])
    ))  # fmt: skip
    raises(error, rf"^x.*{match}", lambda: LinearFeedbackController(macro(), PAPER_K).act(
        np.concatenate([value, value]) if case != "masked" else
        np.ma.masked_array([0.5, 0.5], mask=[False, True]), 0, 0
    ))  # fmt: skip
    if case != "masked":
        raises(error, rf"^x0.*{match}", lambda: SDJLSModel(
            **{**macro().to_dict(), "x0": np.concatenate([value, value])}
        ))  # fmt: skip


@pytest.mark.parametrize(
    "make",
    [
        lambda: LinearFeedbackController(macro(), PAPER_K),
        lambda: policy_for(LinearFeedbackController(macro(), PAPER_K), gym.make("SDJLS-Macro-v0")),
    ],
    ids=["controller", "policy_for"],
)
def test_predict_checks_the_observation_before_reading_its_shape(make):
    """A ragged observation reached numpy's np.ndim first (its ValueError, not naming the
    observation); a state part above MAX_STATE was named 'x[0]'; a time entry of 1e308 made
    numpy warn of an overflow before the error."""
    policy = make()
    raises(ValueError, r"^observation = .* could not be read", lambda: policy.predict(
        [0.5, [0.5], 1, 0, 0, 0]
    ))  # fmt: skip
    raises(ValueError, r"^observation's state part \[5\.e-0+1, 1\.e\+200\] has an entry of "
           r"magnitude above 1e\+100", lambda: policy.predict([0.5, 1e200, 1, 0, 0, 0]))  # fmt: skip
    if isinstance(policy, LinearFeedbackController):
        return  # its decision does not read k
    raises(ValueError, r"time entry k / horizon = 1e\+308", lambda: policy.predict(
        [0.5, 0.5, 1, 0, 0, 1e308]
    ))  # fmt: skip


@pytest.mark.parametrize("vector", [False, True], ids=["env", "vector-env"])
def test_reset_seed_follows_the_int_rule(vector):
    """Gymnasium took seed=True as the seed 1 and refused np.int8(3) with its own Error."""
    make = (lambda: SDJLSVectorEnv(2, model=macro())) if vector else (
        lambda: gym.make("SDJLS-Macro-v0")
    )  # fmt: skip
    raises(TypeError, r"^seed = True is a bool", lambda: make().reset(seed=True))
    raises(TypeError, r"^seed = 1\.0 is a float", lambda: make().reset(seed=1.0))
    raises(ValueError, r"^seed = -1 is out of range", lambda: make().reset(seed=-1))
    a, b = make(), make()
    a.reset(seed=np.int8(3))
    b.reset(seed=3)
    np.testing.assert_array_equal(a.step(a.action_space.sample() * 0)[0], b.step(
        b.action_space.sample() * 0
    )[0])  # fmt: skip


def test_a_json_model_file_with_a_key_twice_is_refused(tmp_path):
    """JSON parsers keep the last of two equal keys silently (TOML refuses them)."""
    text = json.dumps(macro().to_dict())[:-1] + ', "x0": [1.0, 1.0]}'
    path = tmp_path / "twice.json"
    path.write_text(text, encoding="utf-8")
    raises(ValueError, r"^model file .*twice\.json' has the key 'x0' twice", lambda: load_model(
        path
    ))  # fmt: skip
