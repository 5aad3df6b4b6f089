"""Every input checked before any work (issue 28, section 3): bools among batch indices, Python
ints beyond float64, LMI data that overflows, wrappers ``policy_for`` cannot act through, and
one answer for a step that overflows float64 in both environments.

Each test asserts the exception type, the argument's name and the offending value; the checks
that promise "before any solver runs" replace the solvers by a trap.
"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from conftest import UNSHOWN, noiseless_model, refused
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


def raises(error, name, value, call):
    """``call()`` raises ``error`` naming ``name`` and showing ``value``, with no warning on the
    way, from a check of this project (``conftest.refused``); the exception."""
    return refused(error, name, value, call).value


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

BOOL_INDICES = {  # modes, k, the name and the value in the message
    "mode-list": ([0, True], 0, "mode[1]", True),
    "mode-tuple-numpy-bool": ((np.True_, 0), [1, 2], "mode[0]", np.True_),
    "k-list": ([0, 1], [True, 2], "k[0]", True),
    "k-scalar": ([0, 1], False, "k", False),
    "mode-float-in-list": ([0, 1.0], 0, "mode[1]", 1.0),
}


@pytest.mark.parametrize("which", list(CONTROLLERS))
@pytest.mark.parametrize("case", list(BOOL_INDICES))
def test_act_batch_refuses_a_bool_among_modes_or_times(which, case, no_solver):
    """numpy reads ``[0, True]`` as ``[0, 1]``: every controller's act_batch refuses it, by
    entry, before any solver runs (README: a bool is never a number)."""
    ctrl = CONTROLLERS[which]()
    modes, k, name, value = BOOL_INDICES[case]
    raises(TypeError, name, value, lambda: ctrl.act_batch(np.ones((2, 2)), modes, k))


def test_model_band_refuses_a_bool_among_times():
    raises(TypeError, "k[0]", True, lambda: macro().H([True, 2]))
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


HUGE_INTS = {  # the call, the name in the message (its value: HUGE or -HUGE)
    "env-step": (lambda _: _stepped_env().step([HUGE]), "action"),
    "env-step-negative": (lambda _: _stepped_env().step([-HUGE]), "action"),
    "env-step-array": (lambda _: _stepped_env().step(np.array([HUGE], dtype=object)), "action"),
    "vector-step": (lambda _: _stepped_vector_env().step([[0.0], [HUGE]]), "actions"),
    "act": (
        lambda _: RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC).act([0.0, HUGE], 0, 0),
        "x",
    ),
    "act-batch": (
        lambda _: LinearFeedbackController(macro(), PAPER_K).act_batch([[HUGE, 0.0]], [0], 0),
        "x",
    ),
    "predict": (
        lambda _: LinearFeedbackController(macro(), PAPER_K).predict([HUGE, 0, 1, 0, 0, 0]),
        "observation",
    ),
    "model-x0": (lambda _: SDJLSModel(**{**macro().to_dict(), "x0": [HUGE, 0]}), "x0"),
    "model-A": (
        lambda _: SDJLSModel(**{**macro().to_dict(), "A": [[1.0, 0.0], [0.0, -HUGE]]}),
        "A",
    ),
    "reset-x0": (
        lambda _: gym.make("SDJLS-Macro-v0").reset(options={"x0": [0, HUGE]}),
        "options['x0']",
    ),
    "action-bound": (lambda _: gym.make("SDJLS-Macro-v0", action_bound=[HUGE]), "action_bound"),
    "json-file": (lambda tmp: load_model(_model_file(tmp, ".json")), ("huge.json", "x0")),
    "toml-file": (lambda tmp: load_model(_model_file(tmp, ".toml")), ("huge.toml", "x0")),
}


@pytest.mark.parametrize("case", list(HUGE_INTS))
def test_an_int_beyond_float64_is_a_value_error_naming_the_argument(case, tmp_path, no_solver):
    """``10**400`` is a ValueError naming the argument and showing the value, as ``1e400`` is,
    not numpy's bare OverflowError."""
    call, name = HUGE_INTS[case]
    raises(ValueError, name, -HUGE if "negative" in case or case == "model-A" else HUGE, lambda: (
        call(tmp_path)
    ))  # fmt: skip


# ------------------------------------------------------------------------ c. LMI inputs
def test_mean_square_bound_refuses_a_nu_bound_whose_square_overflows(no_solver):
    model = macro()
    raises(ValueError, "nu_bound", 1e200, lambda: (
        verify_mean_square_bound(model, PAPER_K, nu_bound=1e200)
    ))  # fmt: skip
    raises(ValueError, "nu_bound", HUGE, lambda: verify_mean_square_bound(
        model, PAPER_K, nu_bound=HUGE
    ))  # fmt: skip


@pytest.mark.parametrize("scale", [1e160, 1e200, 1e300])
def test_gains_whose_products_overflow_are_named_before_any_solver(scale, no_solver):
    """K of 1e200 gave cvxpy's "Problem data contains NaN or Inf" (and numpy's LinAlgError in
    the spectral radius): now a ValueError naming K and its size, before any solver runs."""
    model = macro()
    K = np.full_like(PAPER_K, scale)
    for call in (verify_mean_square_bound, second_moment_spectral_radius):
        raises(ValueError, "K", scale, lambda c=call: c(model, K))


def test_gains_that_are_clearly_not_mean_square_stable_are_infeasible_without_a_solver(no_solver):
    """K of 1e20 made Clarabel fail ("try another solver"); the second-moment operator of
    P_in alone has radius 1e40 > 1, which settles the LMIs' infeasibility without a solver."""
    error = raises(LMIInfeasibleError, "model.P_in", 1e40, lambda: (  # the radius, 1e+40
        verify_mean_square_bound(macro(), np.full_like(PAPER_K, 1e20))
    ))  # fmt: skip
    assert isinstance(error, ValueError)
    assert "(no solver run)" in str(error)  # the words the README quotes


def test_a_certificate_whose_bound_overflows_names_the_argument():
    """delta = 1e308 (or kappa = 1e-320) makes beta2 overflow: a ValueError naming them, not a
    certificate with beta2 = inf."""
    model = macro()
    raises(ValueError, ("beta2", "delta"), 1e308, lambda: (
        verify_mean_square_bound(model, PAPER_K, delta=1e308)
    ))  # fmt: skip
    raises(ValueError, ("beta2", "kappa"), 1e-320, lambda: (
        verify_mean_square_bound(model, PAPER_K, delta=1, kappa=1e-320)
    ))  # fmt: skip


def test_proposition2_names_X_and_Y_when_their_products_overflow():
    scale = 1e308 / np.max(np.abs(PAPER_X))
    raises(ValueError, ("X", "Y"), 1e308, lambda: (  # X has entries up to 1e+308
        check_proposition2(macro(), PAPER_X * scale, PAPER_Y)
    ))  # fmt: skip


def test_lmi_flags_and_the_bound_follow_the_argument_rules(no_solver):
    model = macro()
    raises(TypeError, "verbose", "yes", lambda: synthesize_gains(model, verbose="yes"))
    raises(TypeError, "objective", ["max_margin"], lambda: synthesize_gains(
        model, objective=["max_margin"]
    ))  # fmt: skip


def test_certificate_bound_checks_k_and_x0():
    cert = verify_mean_square_bound(macro(), PAPER_K)
    raises(TypeError, "k", True, lambda: cert.bound(True, [1.0, 1.0]))
    raises(TypeError, "k[1]", True, lambda: cert.bound([0, True], [1.0, 1.0]))
    raises(ValueError, "x0", HUGE, lambda: cert.bound(1, [HUGE, 0]))
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
    raises(ValueError, "env", name, lambda: policy_for(ctrl, env))


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
    time = "observation's time entry k / horizon"
    raises(ValueError, time, 7.3, lambda: policy.predict(_obs(tau=7.3)))
    raises(ValueError, time, 0.33, lambda: policy.predict(_obs(tau=0.33)))
    for bad in ((1.0, 1.0, 0.0), (0.0, 0.0, 0.0), (0.5, 0.5, 0.0), (2.0, -1.0, 0.0)):
        raises(ValueError, "observation's mode part", np.array(bad), lambda b=bad: (
            policy.predict(_obs(one_hot=b))
        ))  # fmt: skip
    batch = np.stack([_obs(), _obs(one_hot=(0.0, 1.0, 1.0))])
    raises(ValueError, "observation[1]'s mode part", np.array([0.0, 1.0, 1.0]), lambda: (
        policy.predict(batch)
    ))  # fmt: skip
    action, _ = policy.predict(_obs(one_hot=(0.0, 1.0, 0.0), tau=0.05))
    assert action.shape == (1,)


def test_controller_predict_refuses_a_mode_part_that_is_not_one_hot():
    ctrl = LinearFeedbackController(macro(), PAPER_K)
    raises(ValueError, "mode part", np.array([0.5, 0.5, 0.0]), lambda: (
        ctrl.predict(_obs(one_hot=(0.5, 0.5, 0.0)))
    ))  # fmt: skip


# ------------------------------------------------------------------- e. an overflowing step
def _overflow_model(A, B=((0.0,), (1.0,)), G=((0.0, 1.0),), x0=(1e10, 1e10)):
    """conftest's noiseless model (both envs step x_1 = A x_0 + B u_0 exactly alike), with the
    band at 1 and the state at 1e10."""
    return noiseless_model(A, B=B, G=G, H0=[1.0] * len(G), x0=x0)


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
    "datetime64": (np.array(["2020-01-01"], dtype="datetime64[D]"), TypeError),
    "timedelta64": (np.array([3], dtype="timedelta64[s]"), TypeError),
    # the data under a mask is not the user's value (the message shows no value: there is none)
    "masked": (np.ma.masked_array([0.5], mask=[True]), ValueError),
    # a longdouble beyond float64: numpy's cast warned "overflow" before the error
    "longdouble-1e400": (np.array([np.longdouble("1e400")]), ValueError),
}


@pytest.mark.parametrize("case", list(ODD_ACTIONS))
def test_odd_arrays_are_refused_by_name_without_a_warning(case):
    value, error = ODD_ACTIONS[case]
    masked = case == "masked"
    actions = (
        np.ma.masked_array([[0.5], [0.5]], mask=[[False], [True]])
        if masked
        else value.reshape(1, 1).repeat(2, axis=0)
    )
    x = (
        np.ma.masked_array([0.5, 0.5], mask=[False, True])
        if masked
        else np.concatenate([value] * 2)
    )
    # known gap: a longdouble beyond float64 is shown as its float64 cast (inf), not as 1e+400
    shown = (lambda v: UNSHOWN) if masked or case == "longdouble-1e400" else (lambda v: v)
    raises(error, "action", shown(value), lambda: _stepped_env().step(value))
    raises(error, "actions", shown(actions), lambda: _stepped_vector_env().step(actions))
    raises(error, "x", shown(x), lambda: LinearFeedbackController(macro(), PAPER_K).act(x, 0, 0))
    if not masked:
        raises(error, "x0", shown(x), lambda: SDJLSModel(**{**macro().to_dict(), "x0": x}))


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
    raises(ValueError, "observation", [0.5, [0.5], 1, 0, 0, 0], lambda: policy.predict(
        [0.5, [0.5], 1, 0, 0, 0]
    ))  # fmt: skip
    raises(ValueError, "observation's state part", np.array([0.5, 1e200]), lambda: (
        policy.predict([0.5, 1e200, 1, 0, 0, 0])
    ))  # fmt: skip
    if isinstance(policy, LinearFeedbackController):
        return  # its decision does not read k
    raises(ValueError, "observation's time entry k / horizon", 1e308, lambda: policy.predict(
        [0.5, 0.5, 1, 0, 0, 1e308]
    ))  # fmt: skip


@pytest.mark.parametrize("vector", [False, True], ids=["env", "vector-env"])
def test_reset_seed_follows_the_int_rule(vector):
    """Gymnasium took seed=True as the seed 1 and refused np.int8(3) with its own Error."""
    make = (lambda: SDJLSVectorEnv(2, model=macro())) if vector else (
        lambda: gym.make("SDJLS-Macro-v0")
    )  # fmt: skip
    raises(TypeError, "seed", True, lambda: make().reset(seed=True))
    raises(TypeError, "seed", 1.0, lambda: make().reset(seed=1.0))
    raises(ValueError, "seed", -1, lambda: make().reset(seed=-1))
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
    raises(ValueError, "model file", "twice.json", lambda: load_model(path))  # the key 'x0' twice


@pytest.mark.parametrize("action", [[None], np.array([None], dtype=object)])
def test_a_none_entry_in_an_action_is_not_a_number(action):
    """A None entry is named as such, as the README says, not read as NaN ('non-finite')."""
    from sdjls_gym.errors import NotANumberError

    env = gym.make("SDJLS-Macro-v0")
    env.reset(seed=0)
    with pytest.raises(NotANumberError, match="None"):
        env.step(action)
    venv = gym.make_vec("SDJLS-Macro-v0", num_envs=1, vectorization_mode="vector_entry_point")
    venv.reset(seed=0)
    with pytest.raises(NotANumberError, match="None"):
        venv.step(np.array([action], dtype=object))
