"""``controllers.identify``: the model estimated from exploratory episodes of every suite task.

The data come from :class:`sdjls_gym.SDJLSVectorEnv` (all episodes of a task at once) under
:class:`controllers.ExplorationPolicy`. The estimator is given a *designer's template*: the
task's model with its dynamics, noise and transition matrices replaced by placeholders, so that
nothing it returns can come from the truth.

Errors: ``A`` and ``B`` separately, ``||A_hat_i - A_i||_F / ||A_i||_F`` per mode (relative to
the largest ``||A_j||_F`` if ``A_i`` is zero; no suite task has one), the covariance alike,
and ``max |P_hat - P|`` over every entry of ``P_in`` and ``P_out``.
"""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from benchmarks.identify.learner import EXPLORATION  # (std, mean) per task: the wing's own
from controllers import ExplorationPolicy, IdentificationInfo, InsufficientDataError, identify
from sdjls_gym import SDJLSModel, SDJLSVectorEnv
from sdjls_gym.systems import TASKS

EPISODES = 400


def designer_template(model: SDJLSModel) -> SDJLSModel:
    """``model`` with placeholder dynamics, noise and transitions: what a designer knows."""
    N, n, m = model.N, model.n, model.m
    uniform = np.full((N, N), 1.0 / N)
    return dataclasses.replace(
        model, A=np.zeros((N, n, n)), B=np.zeros((N, n, m)), E=None, W=None, P_in=uniform,
        P_out=uniform,
    )  # fmt: skip


def rollout(model, policy, episodes, horizon, action_bound, seed):
    """``episodes`` trajectories of ``policy`` on ``model`` (one vector environment step per
    time step), each cut where its episode ended; ``u`` is the applied (clipped) input."""
    env = SDJLSVectorEnv(num_envs=episodes, model=model, horizon=horizon, action_bound=action_bound)
    _, info = env.reset(seed=seed)
    xs, us, modes = [info["state"]], [], [info["mode"]]
    length = np.full(episodes, horizon)
    alive = np.ones(episodes, dtype=bool)
    for t in range(horizon):
        u, _ = policy.act_batch(info["state"], info["mode"], info["k"])
        _, _, terminated, _, info = env.step(u)
        us.append(info["u"])
        xs.append(info["state"])
        modes.append(info["mode"])
        length[alive & terminated] = t + 1
        alive &= ~terminated
    X, U, M = np.stack(xs, axis=1), np.stack(us, axis=1), np.stack(modes, axis=1)
    return [
        {"x": X[b, : L + 1], "u": U[b, :L], "mode": M[b, : L + 1]}
        for b, L in enumerate(length.tolist())
    ]


def policy_rng(seed: int) -> np.random.Generator:
    """The policy's stream, independent of the environment's ``reset(seed=seed)`` stream (the
    same seed in both would make the input noise equal the state noise and bias the fit)."""
    return np.random.default_rng([seed, 12345])


@cache
def explore(env_id: str, seed: int, episodes: int = EPISODES) -> tuple[dict, ...]:
    """The stated exploration of a task from ``seed`` (cached: several tests read it)."""
    task = TASKS[env_id]
    std, mean = EXPLORATION[env_id]
    policy = ExplorationPolicy(
        designer_template(task.model), task.K, std, policy_rng(seed), input_mean=mean
    )
    data = rollout(task.model, policy, episodes, task.horizon, task.action_bound, seed)
    return tuple(data)


def relative(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) ``||estimate_i - truth_i||_F / ||truth_i||_F``, the largest norm for a zero truth."""
    den = np.linalg.norm(truth, axis=(1, 2))
    den = np.where(den > 0.0, den, den.max())
    return np.linalg.norm(estimate - truth, axis=(1, 2)) / den


def errors(model: SDJLSModel, truth: SDJLSModel) -> dict[str, float]:
    return {
        "A": float(relative(model.A, truth.A).max()),
        "B": float(relative(model.B, truth.B).max()),
        "AB": float(
            relative(
                np.concatenate([model.A, model.B], axis=2),
                np.concatenate([truth.A, truth.B], axis=2),
            ).max()
        ),
        "cov": float(relative(model.noise_cov, truth.noise_cov).max()),
        "P": float(
            max(np.abs(model.P_in - truth.P_in).max(), np.abs(model.P_out - truth.P_out).max())
        ),
    }


# ----------------------------------------------------------------------------- the suite
@pytest.mark.parametrize("env_id", list(TASKS))
def test_recovers_every_suite_task_from_400_episodes(env_id):
    """Dynamics within 10% and transition matrices within 0.1 from 400 episodes (seed 0).

    Over seeds 0-19 of this exploration the worst errors were 0.031 (A; VTOL), 0.018 (B;
    VTOL), 0.058 (P; Macro's P_in) and 0.068 (covariance; Macro): a margin of more than 1.7.
    """
    task = TASKS[env_id]
    data = explore(env_id, 0)
    assert all(len(t["u"]) == task.horizon for t in data), "an exploratory episode diverged"
    model, info = identify(list(data), designer_template(task.model), return_info=True)
    assert info.prior_rows == (), f"rows never reached by the exploration: {info.prior_rows}"
    err = errors(model, task.model)
    assert err["A"] <= 0.1 and err["B"] <= 0.1, err
    assert err["P"] <= 0.1, err
    assert err["cov"] <= 0.15, err
    # the designer's fields are the template's; the noise is E = Sigma^(1/2), W = I
    for name in ("G", "H0", "H_rate", "Q", "R", "x0"):
        np.testing.assert_array_equal(getattr(model, name), getattr(task.model, name))
    assert model.mode_names == task.model.mode_names and model.E.shape == (task.N,) + (task.n,) * 2
    np.testing.assert_array_equal(model.W, np.eye(task.n))
    np.testing.assert_allclose(model.noise_cov, info.noise_cov, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("env_id", list(TASKS))
def test_the_error_shrinks_with_the_data(env_id):
    """Mean errors over seeds 0-7 of the first 25, 100 and 400 episodes of each seed's
    exploration decrease: [A B] jointly, the covariances, the transition matrices.

    Each mean halves from one size to the next (the error goes as one over the root of the
    data); in each of 4 disjoint groups of 8 seeds (0-31) the order held for every task and
    every measure (with groups of 4, Solar's covariance failed in 2 of 8).
    """
    task = TASKS[env_id]
    template = designer_template(task.model)
    means = []
    for size in (25, 100, 400):
        per_seed = [
            errors(identify(explore(env_id, s)[:size], template), task.model) for s in range(8)
        ]
        means.append({key: np.mean([e[key] for e in per_seed]) for key in ("AB", "cov", "P")})
    for key in ("AB", "cov", "P"):
        curve = [m[key] for m in means]
        assert curve[0] > curve[1] > curve[2], (key, curve)


@pytest.mark.parametrize("env_id", list(TASKS))
def test_noise_free_data_give_the_exact_model(env_id):
    task = TASKS[env_id]
    truth = dataclasses.replace(task.model, W=np.zeros_like(task.model.W))
    std, mean = EXPLORATION[env_id]
    policy = ExplorationPolicy(truth, task.K, std, policy_rng(1), input_mean=mean)
    data = rollout(truth, policy, 30, task.horizon, task.action_bound, seed=1)
    model, info = identify(data, designer_template(truth), return_info=True)
    assert relative(model.A, truth.A).max() <= 1e-8
    assert relative(model.B, truth.B).max() <= 1e-8
    x_scale = max(float(np.abs(t["x"]).max()) for t in data)
    assert np.abs(info.noise_cov).max() <= 1e-20 * x_scale**2  # rounding: ~1e-31


def test_the_applied_input_is_the_one_to_regress_on():
    """With an action bound that clips often, the environment's ``info["u"]`` recovers B; the
    requested input does not (it overstates what the system received)."""
    task = TASKS["SDJLS-Solar-v0"]
    template = designer_template(task.model)
    policy = ExplorationPolicy(template, task.K, 20.0, policy_rng(2))
    env = SDJLSVectorEnv(num_envs=200, model=task.model, horizon=task.horizon, action_bound=10.0)
    _, info = env.reset(seed=2)
    xs, applied, requested, modes = [info["state"]], [], [], [info["mode"]]
    for _ in range(task.horizon):
        u, _ = policy.act_batch(info["state"], info["mode"], info["k"])
        _, _, terminated, _, info = env.step(u)
        assert not terminated.any()
        requested.append(u)
        applied.append(info["u"])
        xs.append(info["state"])
        modes.append(info["mode"])
    X, M = np.stack(xs, axis=1), np.stack(modes, axis=1)
    clipped = np.mean(np.abs(np.stack(requested)) > 10.0)
    assert clipped > 0.2
    results = {}
    for name, U in (
        ("applied", np.stack(applied, axis=1)),
        ("requested", np.stack(requested, axis=1)),
    ):
        data = [{"x": X[b], "u": U[b], "mode": M[b]} for b in range(200)]
        results[name] = relative(identify(data, template).B, task.model.B).max()
    assert results["applied"] <= 0.1 < results["requested"], results


# ----------------------------------------------------------------------------- the counts
def _reference_counts(data, G, H0, H_rate, N):
    """The jumps theta_k -> theta_{k+1} split by G x_k <= H0 + k H_rate, written out here."""
    counts = {True: np.zeros((N, N), dtype=int), False: np.zeros((N, N), dtype=int)}
    for t in data:
        for step in range(len(t["u"])):
            k = t.get("k0", 0) + step
            inside = bool(np.all(G @ t["x"][step] <= H0 + k * H_rate))
            counts[inside][t["mode"][step], t["mode"][step + 1]] += 1
    return counts[True], counts[False]


def _random_data(template, trajectories, T, rng, k0=False):
    """Trajectories of random states, inputs and modes (identify does not check that they
    follow any dynamics: only its counts and shapes are read here)."""
    n, m, N = template.n, template.m, template.N
    out = []
    for _ in range(trajectories):
        t = {
            "x": rng.normal(size=(T + 1, n)),
            "u": rng.normal(size=(T, m)),
            "mode": rng.integers(0, N, size=T + 1),
        }
        if k0:
            t["k0"] = int(rng.integers(0, 5))
        out.append(t)
    return out


@pytest.fixture
def moving_band():
    """Two modes, n = 2, m = 1, a region that moves with k: |x(1)| <= 0.3 + 0.1 k."""
    return SDJLSModel(
        A=np.zeros((2, 2, 2)), B=[[0.0], [0.0]], P_in=[[0.5, 0.5], [0.5, 0.5]],
        P_out=[[0.2, 0.8], [0.6, 0.4]], G=[[1.0, 0.0], [-1.0, 0.0]], H0=[0.3, 0.3],
        H_rate=[0.1, 0.1], Q=np.eye(2), R=[[1.0]], x0=[0.0, 0.0],
    )  # fmt: skip


def test_jumps_are_counted_by_the_region_of_x_k_at_its_time(moving_band):
    rng = np.random.default_rng(3)
    data = _random_data(moving_band, 40, 12, rng, k0=True)
    _, info = identify(data, moving_band, return_info=True)
    ref_in, ref_out = _reference_counts(
        data, moving_band.G, moving_band.H0, moving_band.H_rate, moving_band.N
    )
    np.testing.assert_array_equal(info.counts_in, ref_in)
    np.testing.assert_array_equal(info.counts_out, ref_out)
    assert info.counts_in.sum() > 50 and info.counts_out.sum() > 50
    # without k0 the times differ, and so do the counts
    shifted = [{key: value for key, value in t.items() if key != "k0"} for t in data]
    _, info0 = identify(shifted, moving_band, return_info=True)
    assert not np.array_equal(info0.counts_in, info.counts_in)


def test_transition_rows_are_the_dirichlet_posterior_mean(moving_band):
    rng = np.random.default_rng(4)
    data = _random_data(moving_band, 20, 10, rng)
    model, info = identify(data, moving_band, prior_count=0.5, return_info=True)
    C = info.counts_in
    np.testing.assert_allclose(model.P_in, (C + 0.5) / (C.sum(axis=1, keepdims=True) + 1.0))
    model, info = identify(data, moving_band, prior="template", prior_count=2.0, return_info=True)
    C, T = info.counts_out, moving_band.P_out
    np.testing.assert_allclose(model.P_out, (C + 4.0 * T) / (C.sum(axis=1, keepdims=True) + 4.0))
    assert info.prior == "template" and info.prior_count == 2.0


def test_a_row_never_observed_is_the_prior_mean(moving_band):
    """States that never leave the region: every P_out row is the prior's, listed as such."""
    rng = np.random.default_rng(5)
    data = _random_data(moving_band, 20, 10, rng)
    for t in data:
        t["x"] = 0.01 * t["x"]  # inside |x(1)| <= 0.3 at every k
    model, info = identify(data, moving_band, return_info=True)
    assert info.prior_rows == ((0, "out"), (1, "out"))
    np.testing.assert_array_equal(model.P_out, np.full((2, 2), 0.5))
    model = identify(data, moving_band, prior="template")
    np.testing.assert_allclose(model.P_out, moving_band.P_out, rtol=1e-15)


def test_the_estimate_does_not_depend_on_the_units(moving_band):
    """States and inputs scaled by 1e80 or 1e-80: the same A and B, the covariance scaled by
    the square; never NaN."""
    rng = np.random.default_rng(6)
    data = _random_data(moving_band, 10, 20, rng)
    base, info = identify(data, moving_band, return_info=True)
    assert isinstance(info, IdentificationInfo)
    for c in (1e80, 1e-80):
        scaled = [{**t, "x": c * t["x"], "u": c * t["u"]} for t in data]
        model = identify(scaled, moving_band)
        np.testing.assert_allclose(model.A, base.A, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(model.B, base.B, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(model.noise_cov, c**2 * base.noise_cov, rtol=1e-9)


# ----------------------------------------------------------------------------- too little data
@pytest.fixture
def two_modes():
    """Two modes, n = m = 1 (n + m + 1 = 3 steps per mode at least)."""
    return SDJLSModel(
        A=[[[0.0]], [[0.0]]], B=[[0.0]], P_in=[[0.5, 0.5], [0.5, 0.5]],
        P_out=[[0.5, 0.5], [0.5, 0.5]], G=[[1.0]], H0=[1.0], Q=[[1.0]], R=[[1.0]], x0=[0.0],
        mode_names=("calm", "storm"),
    )  # fmt: skip


def _one_mode_data(rng, steps, mode=0):
    return {
        "x": rng.normal(size=(steps + 1, 1)),
        "u": rng.normal(size=(steps, 1)),
        "mode": np.full(steps + 1, mode),
    }


def test_a_mode_never_visited_is_an_insufficient_data_error(two_modes):
    data = [_one_mode_data(np.random.default_rng(7), 30)]
    with pytest.raises(InsufficientDataError, match=r"mode 1 \('storm'\) is the mode of no step"):
        identify(data, two_modes)
    assert issubclass(InsufficientDataError, ValueError)


def test_too_few_steps_in_a_mode_is_an_insufficient_data_error(two_modes):
    rng = np.random.default_rng(8)
    data = [_one_mode_data(rng, 30), _one_mode_data(rng, 2, mode=1)]
    with pytest.raises(InsufficientDataError, match=r"mode 1 .* 2 step\(s\).* n \+ m \+ 1 = 3"):
        identify(data, two_modes)
    data[1] = _one_mode_data(rng, 3, mode=1)  # three steps: enough
    assert np.all(np.isfinite(identify(data, two_modes).A))


@pytest.mark.parametrize("env_id", ["SDJLS-Macro-v0", "SDJLS-VTOL-v0"])
def test_feedback_without_input_noise_is_an_insufficient_data_error(env_id):
    """u = K x alone: the regressors [x, K x] have rank n, so A and B cannot be told apart."""
    task = TASKS[env_id]
    template = designer_template(task.model)
    policy = ExplorationPolicy(template, task.K, 0.0, policy_rng(9))
    data = rollout(task.model, policy, 20, task.horizon, task.action_bound, seed=9)
    with pytest.raises(InsufficientDataError, match=r"mode \d .* rank \d < n \+ m = .*input_std"):
        identify(data, template)


def test_an_input_never_used_is_an_insufficient_data_error(two_modes):
    rng = np.random.default_rng(10)
    data = [_one_mode_data(rng, 30, mode=0), _one_mode_data(rng, 30, mode=1)]
    data[1]["u"] = np.zeros((30, 1))
    with pytest.raises(InsufficientDataError, match=r"mode 1 .* rank 1 < n \+ m = 2"):
        identify(data, two_modes)


# ----------------------------------------------------------------------------- bad arguments
def _good(rng, T=5):
    return {"x": rng.normal(size=(T + 1, 1)), "u": rng.normal(size=(T, 1)), "mode": [0, 1] * 3}


@pytest.mark.parametrize(
    ("change", "error", "words"),
    [
        (
            lambda t: t.update(x=np.zeros((6, 2))),
            ValueError,
            ["trajectories[1]['x']", "(6, 2)", "(T + 1, 1)"],
        ),
        (lambda t: t.update(x=np.zeros(6)), ValueError, ["trajectories[1]['x']", "(6,)"]),
        (
            lambda t: t.update(u=np.zeros((4, 1))),
            ValueError,
            ["trajectories[1]['u']", "(4, 1)", "(5, 1)"],
        ),
        (
            lambda t: t.update(mode=[0, 1, 0]),
            ValueError,
            ["trajectories[1]['mode']", "(3,)", "(6,)"],
        ),
        (lambda t: t.update(mode=[0, 1, 2, 0, 1, 0]), ValueError, ["trajectories[1]['mode']", "2"]),
        (lambda t: t.update(mode=[0.0, 1, 0, 1, 0, 1]), TypeError, ["trajectories[1]['mode']"]),
        (lambda t: t["x"].__setitem__((2, 0), np.nan), ValueError, ["trajectories[1]['x']", "nan"]),
        (
            lambda t: t["u"].__setitem__((0, 0), 1e150),
            ValueError,
            ["trajectories[1]['u']", "1e+150"],
        ),
        (lambda t: t.update(u=[["a"]] * 5), TypeError, ["trajectories[1]['u']", "'a'"]),
        (lambda t: t.pop("u"), ValueError, ["trajectories[1]", "'u'"]),
        (lambda t: t.update(modes=t["mode"]), ValueError, ["trajectories[1]", "modes"]),
        (lambda t: t.update(k0=-1), ValueError, ["trajectories[1]['k0']", "-1"]),
        (lambda t: t.update(k0=1.0), TypeError, ["trajectories[1]['k0']", "1.0"]),
    ],
)
def test_a_bad_trajectory_is_named_with_its_key(two_modes, change, error, words):
    rng = np.random.default_rng(11)
    data = [_good(rng), _good(rng)]
    change(data[1])
    with pytest.raises(error) as raised:
        identify(data, two_modes)
    for word in words:
        assert word in str(raised.value), (word, str(raised.value))


@pytest.mark.parametrize(
    ("trajectories", "error", "word"),
    [
        ([], ValueError, "[]"),
        ({"x": [[0.0]], "u": np.zeros((0, 1)), "mode": [0]}, TypeError, "wrap it in a list"),
        ((t for t in []), TypeError, "generator"),
        ("x", TypeError, "'x'"),
        ([[1.0, 2.0]], TypeError, "trajectories[0]"),
    ],
)
def test_trajectories_must_be_a_list_of_dicts(two_modes, trajectories, error, word):
    with pytest.raises(error, match="trajectories") as raised:
        identify(trajectories, two_modes)
    assert word in str(raised.value)


@pytest.mark.parametrize(
    ("kwargs", "error", "words"),
    [
        ({"template": "macro"}, TypeError, ["model", "'macro'"]),
        ({"prior": "jeffreys"}, ValueError, ["prior", "jeffreys"]),
        ({"prior_count": 0.0}, ValueError, ["prior_count", "0.0"]),
        ({"prior_count": float("inf")}, ValueError, ["prior_count", "inf"]),
        ({"return_info": 1}, TypeError, ["return_info", "1"]),
    ],
)
def test_bad_options_are_refused(two_modes, kwargs, error, words):
    rng = np.random.default_rng(12)
    data = [_good(rng, T=20), _good(rng, T=20)]
    for t in data:
        t["mode"] = rng.integers(0, 2, size=21)
    arguments = {"template": two_modes, **kwargs}
    with pytest.raises(error) as raised:
        identify(data, **arguments)
    for word in words:
        assert word in str(raised.value), (word, str(raised.value))
