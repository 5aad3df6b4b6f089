"""ModeFilter: Hamilton's recursion with the state-dependent jumps, against a recursion written
here from the paper's equations (scipy.stats densities, probability domain), on trajectories of
every task of the suite simulated by the environment with the mode hidden; the rule for singular
noise covariances; the belief that would become all zero; the batched path; input checks.

The reference shares no code with the filter: it builds each mode's Gaussian with
``scipy.stats.multivariate_normal`` from the model's fields, tests the region ``G x <= H_k``
itself and multiplies probabilities.
"""

from __future__ import annotations

import threading

import gymnasium as gym
import numpy as np
import pytest
from conftest import UNSHOWN, raises_naming
from scipy import stats

import sdjls_gym
from controllers import ImpossibleObservationError, ModeFilter
from sdjls_gym import SDJLSModel
from sdjls_gym.systems import TASKS

#: Episodes per task and the seeds of their noise and dither (the reference of every step).
EPISODES = 3
SEED = 100


# ----------------------------------------------------------------------------- the reference
def reference_step(model: SDJLSModel, alpha, x, u, x_next, k):
    """One step of Hamilton's filter from the paper's section 2, in the probability domain.

    ``l(i) = N(x_next; A_i x + B_i u, E_i W E_i')`` (scipy's density; a singular covariance
    has its density on its support and 0 off it, and among the modes that fit, the ones of the
    smallest rank take all the mass: the limit of ``Sigma_i + eps I``); ``beta = alpha * l /
    sum``; ``alpha_next = beta @ (P_in if G x <= H_k else P_out)``.
    """
    N = model.N
    lik, rank = np.zeros(N), np.zeros(N, dtype=int)
    for i in range(N):
        cov = model.E[i] @ model.W @ model.E[i].T
        mean = model.A[i] @ x + model.B[i] @ u
        rank[i] = np.linalg.matrix_rank(cov)
        if rank[i] == 0:  # deterministic: the point mass at the mean
            lik[i] = float(np.allclose(x_next, mean, rtol=0.0, atol=1e-9))
        else:
            lik[i] = stats.multivariate_normal(mean, cov, allow_singular=True).pdf(x_next)
    fits = (lik > 0) & (alpha > 0)
    lik = np.where(fits & (rank == rank[fits].min()), lik, 0.0)
    joint = alpha * lik
    assert joint.sum() > 1e-280, "the reference's densities would underflow"
    beta = joint / joint.sum()
    inside = np.all(model.G @ x <= model.H0 + k * model.H_rate)
    return beta @ (model.P_in if inside else model.P_out)


def prior_of(model: SDJLSModel) -> np.ndarray:
    mode0 = model.mode0
    return np.eye(model.N)[mode0] if isinstance(mode0, int) else np.array(mode0)


def hidden_episode(env_id: str, seed: int):
    """An episode of ``env_id`` with the mode hidden, under the certainty-equivalence input
    ``u = K_j x`` of the reference's most probable mode ``j``, plus a dither: states, applied
    inputs, times, true modes and the reference's beliefs (``beliefs[t]`` of ``theta_t``)."""
    task = TASKS[env_id]
    model = task.model
    env = gym.make(env_id, observe="state")
    obs, info = env.reset(seed=seed)
    assert obs.shape == (model.n + 1,)
    rng = np.random.default_rng(seed)
    xs, us, ks, modes = [info["state"]], [], [info["k"]], [info["mode"]]
    beliefs = [prior_of(model)]
    done = False
    while not done:
        x = xs[-1]
        u = task.K[int(np.argmax(beliefs[-1]))] @ x + 0.3 * rng.standard_normal(model.m)
        obs, _, terminated, truncated, info = env.step(u.astype(np.float32))
        done = terminated or truncated
        us.append(info["u"])
        beliefs.append(reference_step(model, beliefs[-1], x, info["u"], info["state"], ks[-1]))
        xs.append(info["state"])
        ks.append(info["k"])
        modes.append(info["mode"])
    return np.array(xs), np.array(us), np.array(ks), np.array(modes), np.array(beliefs)


# ----------------------------------------------------------------------------- every task
@pytest.mark.parametrize("env_id", list(TASKS))
def test_filter_matches_the_reference_recursion_on_every_task(env_id):
    """Every step of 3 seeded episodes (seeds 100..102) to 1e-9 (the largest difference seen is
    9e-16); the belief is a probability vector throughout. The episodes run to the horizon,
    except the macro example's, which diverge (past 1e6) after 11 to 17 steps under this input:
    large states are covered too."""
    model = TASKS[env_id].model
    mode_filter = ModeFilter(model)
    steps = 0
    for e in range(EPISODES):
        xs, us, ks, _, reference = hidden_episode(env_id, SEED + e)
        np.testing.assert_allclose(mode_filter.reset(), reference[0], rtol=0, atol=1e-15)
        for t in range(len(us)):
            belief = mode_filter.step(xs[t], us[t], xs[t + 1], ks[t])
            np.testing.assert_allclose(belief, reference[t + 1], rtol=0, atol=1e-9)
            assert np.all(belief >= 0.0) and abs(belief.sum() - 1.0) <= 1e-12
            steps += 1
    assert steps >= EPISODES * 10


@pytest.mark.parametrize("env_id", ["SDJLS-VTOL-v0", "SDJLS-ThreeState-v0", "SDJLS-Random-v0"])
def test_step_batch_equals_step_row_by_row(env_id):
    """The batched path on 3 episodes at once (their common steps) equals the single one to
    1e-12, with probabilities or logarithms; the filter's own belief is untouched."""
    model = TASKS[env_id].model
    episodes = [hidden_episode(env_id, SEED + e) for e in range(EPISODES)]
    T = min(len(ep[1]) for ep in episodes)
    single = ModeFilter(model)
    batch = ModeFilter(model)
    rows = np.tile(batch.reset(), (EPISODES, 1))
    log_rows = np.log(rows, where=rows > 0, out=np.full_like(rows, -np.inf))
    expected = []
    for xs, us, ks, _, _ in episodes:
        single.reset()
        expected.append([single.step(xs[t], us[t], xs[t + 1], ks[t]) for t in range(T)])
    for t in range(T):
        x = np.array([ep[0][t] for ep in episodes])
        u = np.array([ep[1][t] for ep in episodes])
        x_next = np.array([ep[0][t + 1] for ep in episodes])
        k = np.array([ep[2][t] for ep in episodes])
        rows = batch.step_batch(rows, x, u, x_next, k)
        log_rows = batch.step_batch(log_rows, x, u, x_next, k, log=True)
        want = np.array([expected[b][t] for b in range(EPISODES)])
        np.testing.assert_allclose(rows, want, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.exp(log_rows), want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(batch.belief, batch.initial_belief())


def test_most_probable_mode_is_right_more_often_than_the_commonest_mode():
    """A sanity check, not a proof: one seeded VTOL trajectory of 1000 steps (seed 1, mode
    hidden, the filter's own certainty-equivalence input ``u = K_j x`` of its most probable mode
    j plus a dither of 0.1). The filter's most probable ``theta_{k+1}`` is the true one in 89%
    of the steps here; asserted: above 80%, and above the share of the commonest mode (48%
    here), the best constant guess. The belief of ``theta_{k+1}`` is a prediction through one
    jump, so it cannot be right every time."""
    task = TASKS["SDJLS-VTOL-v0"]
    T = 1000
    env = gym.make("SDJLS-VTOL-v0", observe="state", horizon=T)
    _, info = env.reset(seed=1)
    mode_filter = ModeFilter(task.model)
    belief = mode_filter.reset()
    rng = np.random.default_rng(0)
    hits, modes = 0, []
    for _ in range(T):
        x, k = info["state"], info["k"]
        u = task.K[int(np.argmax(belief))] @ x + 0.1 * rng.standard_normal(task.model.m)
        _, _, terminated, truncated, info = env.step(u.astype(np.float32))
        belief = mode_filter.step(x, info["u"], info["state"], k)
        hits += int(np.argmax(belief) == info["mode"])
        modes.append(info["mode"])
        assert not terminated
    assert truncated
    share = hits / T
    assert share > 0.80
    assert share > np.bincount(modes).max() / T


def test_step_batch_is_thread_safe():
    """4 threads, 20 calls each, of step_batch on the same filter give the single thread's
    answer."""
    xs, us, ks, _, _ = hidden_episode("SDJLS-VTOL-v0", SEED)
    mode_filter = ModeFilter(TASKS["SDJLS-VTOL-v0"].model)
    prior = mode_filter.initial_belief()
    want = mode_filter.step_batch(prior, xs[:-1], us, xs[1:], ks[:-1])
    errors = []

    def work():
        for _ in range(20):
            got = mode_filter.step_batch(prior, xs[:-1], us, xs[1:], ks[:-1])
            if not np.array_equal(got, want):
                errors.append(got)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert errors == []


# ----------------------------------------------------------------------------- singular noise
def three_noise_model(range_mode2=None) -> SDJLSModel:
    """n = 2, N = 3, x' = 0.5 x + u + E_i w with W = I: mode 0 has noise along e1 only (rank
    1), mode 1 in the plane (rank 2), mode 2 none (E_2 = 0, rank 0). The region ``x1 <= 1``."""
    E2 = np.zeros((2, 2)) if range_mode2 is None else range_mode2
    return SDJLSModel(
        A=np.eye(2) * 0.5,
        B=np.eye(2),
        E=[[[1.0, 0.0], [0.0, 0.0]], np.eye(2) * 2.0, E2],
        P_in=[[0.8, 0.1, 0.1], [0.2, 0.7, 0.1], [0.3, 0.3, 0.4]],
        P_out=[[0.5, 0.25, 0.25], [0.1, 0.8, 0.1], [0.2, 0.2, 0.6]],
        G=[[1.0, 0.0]],
        H0=[1.0],
        Q=np.eye(2),
        R=np.eye(2),
        x0=[0.0, 0.0],
        mode0=[0.2, 0.3, 0.5],
    )


def test_noise_ranks_are_read_from_the_covariances():
    assert ModeFilter(three_noise_model()).ranks.tolist() == [1, 2, 0]


@pytest.mark.parametrize(
    ("residual", "theta_k"),
    [
        ([0.7, 0.0], 0),  # on e1: modes 0 (rank 1) and 1 (rank 2) fit; the smaller rank wins
        ([0.7, 1e-9], 0),  # off e1 by 1e-9 of the step's size: within range_rtol = 1e-6
        ([0.7, 1e-3], 1),  # off e1 beyond the tolerance: only the full-rank mode fits
        ([0.0, 0.0], 2),  # at the deterministic mode's prediction: it takes all the mass
    ],
)
def test_singular_rule_the_smallest_rank_that_fits_takes_the_mass(residual, theta_k):
    """``x = [0.4, 0.6]`` (inside ``x1 <= 1`` at k = 0), ``u = [0.1, -0.2]``; the residual is
    what is added to the common mean. The belief of theta_{k+1} is then row theta_k of P_in."""
    model = three_noise_model()
    mode_filter = ModeFilter(model)
    mode_filter.reset()
    x, u = np.array([0.4, 0.6]), np.array([0.1, -0.2])
    x_next = 0.5 * x + u + np.array(residual)
    belief = mode_filter.step(x, u, x_next, 0)
    np.testing.assert_allclose(belief, model.P_in[theta_k], rtol=0, atol=1e-15)


def test_singular_rule_is_the_limit_of_a_small_regularization():
    """Two rank-1 modes along the same line with variances 1 and 4 (and the full-rank mode 1):
    the belief is the one of the recursion with ``Sigma_i + eps I``, eps = 1e-14, its Gaussian
    densities written out here (to 1e-6: the full-rank mode's share is about sqrt(eps))."""
    model = three_noise_model(range_mode2=[[2.0, 0.0], [0.0, 0.0]])
    mode_filter = ModeFilter(model)
    prior = mode_filter.reset()
    x, u = np.array([2.0, 0.6]), np.array([0.1, -0.2])  # outside x1 <= 1: P_out
    x_next = 0.5 * x + u + np.array([1.3, 0.0])
    belief = mode_filter.step(x, u, x_next, 0)
    eps = 1e-14
    log_lik = np.zeros(3)
    for i in range(3):
        cov = model.E[i] @ model.W @ model.E[i].T + eps * np.eye(2)
        r = x_next - model.A[i] @ x - model.B[i] @ u
        log_lik[i] = -0.5 * (2 * np.log(2 * np.pi) + np.linalg.slogdet(cov)[1])
        log_lik[i] -= 0.5 * r @ np.linalg.solve(cov, r)
    joint = prior * np.exp(log_lik - log_lik.max())
    beta = joint / joint.sum()
    assert beta[1] < 1e-6 and beta[0] > 0.1 and beta[2] > 0.1  # both rank-1 modes keep mass
    np.testing.assert_allclose(belief, beta @ model.P_out, rtol=0, atol=1e-6)


def test_other_models_rank_one_noise_reveals_the_mode_also_from_float32_states(other_model):
    """``other_model``: n = 3 with one noise input whose direction differs by mode, so
    ``x_{k+1}`` tells ``theta_k``: the belief of ``theta_{k+1}`` is row ``theta_k`` of the
    jump's matrix, from the exact states and from the observation's float32 states alike (the
    default tolerance, 1e-6, covers float32 rounding). 40 steps, seed 5."""
    env = gym.make("SDJLS-v0", model=other_model, horizon=40, observe="state")
    obs, info = env.reset(seed=5)
    exact, rounded = ModeFilter(other_model), ModeFilter(other_model)
    exact.reset()
    rounded.reset()
    rng = np.random.default_rng(5)
    for _ in range(40):
        x, k, mode, x32 = info["state"], info["k"], info["mode"], obs[:3].astype(np.float64)
        obs, _, _, truncated, info = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        row = (other_model.P_in if other_model.in_region(x, k) else other_model.P_out)[mode]
        np.testing.assert_allclose(
            exact.step(x, info["u"], info["state"], k), row, rtol=0, atol=1e-15
        )
        np.testing.assert_allclose(
            rounded.step(x32, info["u"], obs[:3].astype(np.float64), k), row, rtol=0, atol=1e-15
        )
    assert truncated


# ----------------------------------------------------------------------------- all zero
def test_an_impossible_state_raises_and_leaves_the_belief_as_it_was():
    """A prior on the deterministic mode 2 only and an ``x_next`` it cannot produce: no mode of
    positive belief fits, the belief would be all zero: ImpossibleObservationError (a
    ValueError), the belief unchanged, never NaN; with prior mass on mode 1 it is fine."""
    model = three_noise_model()
    mode_filter = ModeFilter(model)
    before = mode_filter.reset(prior=[0.0, 0.0, 1.0])
    x, u = np.array([0.4, 0.6]), np.array([0.1, -0.2])
    x_next = 0.5 * x + u + np.array([0.0, 0.3])
    with pytest.raises(ImpossibleObservationError, match="all zero") as excinfo:
        mode_filter.step(x, u, x_next, 0)
    assert isinstance(excinfo.value, ValueError)
    np.testing.assert_array_equal(mode_filter.belief, before)
    mode_filter.reset(prior=[0.0, 1e-300, 1.0 - 1e-300])  # a tiny belief is enough
    np.testing.assert_allclose(mode_filter.step(x, u, x_next, 0), model.P_in[1], atol=1e-15)


def test_a_likelihood_beyond_float64_raises_not_nan():
    """Full-rank noise, ``x_next`` 1e200 away from every mode's mean: every log-likelihood is
    below float64's range (-1e400); the batched call names the row."""
    model = TASKS["SDJLS-VTOL-v0"].model
    mode_filter = ModeFilter(model)
    prior = mode_filter.reset()
    x, u = np.zeros((2, 4)), np.zeros((2, 2))
    x_next = np.zeros((2, 4))
    x_next[1, 0] = 1e200
    with pytest.raises(ImpossibleObservationError, match="row 1"):
        mode_filter.step_batch(prior, x, u, x_next, 0)
    with pytest.raises(ImpossibleObservationError):
        mode_filter.step(x[1], u[1], x_next[1], 0)
    assert np.all(np.isfinite(mode_filter.belief))


# ----------------------------------------------------------------------------- beliefs, checks
def test_reset_gives_the_models_initial_law_or_the_prior():
    model = TASKS["SDJLS-ThreeState-v0"].model  # mode0 = [0.5, 0.5]
    mode_filter = ModeFilter(model)
    assert mode_filter.reset().tolist() == [0.5, 0.5]
    assert mode_filter.reset(prior=[0.25, 0.75]).tolist() == [0.25, 0.75]
    assert mode_filter.belief.tolist() == [0.25, 0.75]
    np.testing.assert_allclose(mode_filter.log_belief, np.log([0.25, 0.75]))
    assert ModeFilter(sdjls_gym.macro()).reset().tolist() == [1.0, 0.0, 0.0]


def _checks_filter() -> ModeFilter:
    mode_filter = ModeFilter(TASKS["SDJLS-VTOL-v0"].model)  # N = 3, n = 4, m = 2
    mode_filter.reset()
    return mode_filter


@pytest.mark.parametrize(
    ("call", "error", "name", "value"),
    [
        (lambda f: ModeFilter("vtol"), TypeError, "model", "vtol"),
        (lambda f: ModeFilter(f.model, range_rtol=-1.0), ValueError, "range_rtol", -1.0),
        (lambda f: f.reset(prior=[0.5, 0.6, 0.0]), ValueError, "prior", UNSHOWN),
        (lambda f: f.reset(prior=[1.0, 0.0]), ValueError, "prior", (2,)),
        (lambda f: f.step(np.zeros(3), np.zeros(2), np.zeros(4), 0), ValueError, "x", (3,)),
        (lambda f: f.step(np.zeros(4), [np.nan, 0], np.zeros(4), 0), ValueError, "u", UNSHOWN),
        (lambda f: f.step(np.zeros(4), np.zeros(2), np.zeros(5), 0), ValueError, "x_next", (5,)),
        (lambda f: f.step(np.zeros(4), np.zeros(2), np.zeros(4), -1), ValueError, "k", -1),
        (lambda f: f.step(np.zeros(4), np.zeros(2), np.zeros(4), 1.0), TypeError, "k", 1.0),
        (
            lambda f: f.step_batch([[0.5, 0.5, 0.5]], np.zeros((1, 4)), np.zeros((1, 2)),
                                   np.zeros((1, 4)), 0),
            ValueError, "belief", UNSHOWN,
        ),
        (
            lambda f: f.step_batch(f.belief, np.zeros((2, 4)), np.zeros((3, 2)),
                                   np.zeros((2, 4)), 0),
            ValueError, "u", (3, 2),
        ),
        (
            lambda f: f.step_batch(f.belief, np.zeros((2, 4)), np.zeros((2, 2)),
                                   np.zeros((2, 4)), [0, 1, 2]),
            ValueError, "k", (3,),
        ),
        (
            lambda f: f.step_batch([0.0, 0.0, 0.0], np.zeros((1, 4)), np.zeros((1, 2)),
                                   np.zeros((1, 4)), 0, log=True),
            ValueError, "belief", UNSHOWN,
        ),
    ],
)  # fmt: skip
def test_bad_arguments_are_refused_by_name(call, error, name, value):
    mode_filter = _checks_filter()
    with raises_naming(error, name, value):
        call(mode_filter)


def test_step_before_reset_is_refused():
    with pytest.raises(RuntimeError, match="reset"):
        ModeFilter(sdjls_gym.macro()).step(np.zeros(2), np.zeros(1), np.zeros(2), 0)
