"""SDJLSModel's dynamics: single and batched calls agree with section 2, mode sampling.

Expected numbers come from the paper (typed into ``conftest.py``) or are computed by hand in
the test from the formulas of section 2; nothing is copied from the code under test.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import raises_naming

import sdjls_gym
from sdjls_gym import SDJLSModel

# --------------------------------------------------------------------------- batched dynamics


def _random_batch(rng, shape):
    """States around the band (some in, some out), modes, times, inputs, noises, uniforms."""
    x = rng.normal([3.0, 4.0], [2.0, 3.0], size=(*shape, 2))
    mode = rng.integers(0, 3, size=shape)
    k = rng.integers(0, 21, size=shape)
    u = rng.normal(0.0, 2.0, size=(*shape, 1))
    w = rng.normal(size=(*shape, 2))
    uniform = rng.random(shape)
    return x, mode, k, u, w, uniform


def test_single_calls_follow_section_2(paper, paper_kwargs):
    """The reference for the batch test, itself checked against the paper's formulas."""
    model = SDJLSModel(**paper_kwargs)
    x, mode, k, u, w, _ = _random_batch(np.random.default_rng(1), (40,))
    for i in range(40):
        m, kk = int(mode[i]), int(k[i])
        values = paper.G @ x[i] - paper.H(kk)
        np.testing.assert_allclose(model.constraint_values(x[i], kk), values, atol=1e-12)
        inside = bool(np.all(values <= 0))
        assert bool(model.in_region(x[i], kk)) is inside
        row = paper.lam[m] if inside else paper.mu[m]
        np.testing.assert_array_equal(model.transition_rows(x[i], m, kk), row)
        expected = paper.A[m] @ x[i] + paper.B @ u[i] + w[i]  # E = I
        np.testing.assert_allclose(model.next_state(x[i], m, u[i], w[i]), expected, atol=1e-12)
        cost = x[i] @ paper.Q[m] @ x[i] + u[i] @ paper.R[m] @ u[i]
        np.testing.assert_allclose(model.stage_cost(x[i], m, u[i]), cost, rtol=1e-12)
    # the test must see both regions
    inside = [bool(model.in_region(x[i], int(k[i]))) for i in range(40)]
    assert any(inside) and not all(inside)


@pytest.mark.parametrize("shape", [(50,), (4, 7)])
def test_batched_dynamics_agree_with_a_loop_of_single_calls(other_model, paper_kwargs, shape):
    rng = np.random.default_rng(7)
    paper_center = lambda k: np.stack([np.zeros(k.shape), 3.5 + 0.5 * k], axis=-1)  # noqa: E731
    other_center = lambda k: np.zeros((*k.shape, 3))  # noqa: E731
    for model, center in ((SDJLSModel(**paper_kwargs), paper_center), (other_model, other_center)):
        N, n, m, p = model.N, model.n, model.m, model.p
        mode = rng.integers(0, N, size=shape)
        k = rng.integers(0, 21, size=shape)
        x = center(k) + rng.normal(0.0, 2.0, size=(*shape, n))
        u = rng.normal(size=(*shape, m))
        w = rng.normal(size=(*shape, p))
        uniform = rng.random(shape)

        x_next, mode_next = model.step(x, mode, u, k, w, uniform)
        batched = {
            "next_state": model.next_state(x, mode, u, w),
            "step_x": x_next,
            "step_mode": mode_next,
            "next_mode": model.next_mode(x, mode, k, uniform),
            "in_region": model.in_region(x, k),
            "transition_rows": model.transition_rows(x, mode, k),
            "constraint_values": model.constraint_values(x, k),
            "stage_cost": model.stage_cost(x, mode, u),
        }
        assert batched["next_state"].shape == (*shape, n)
        assert batched["step_mode"].shape == shape
        assert batched["in_region"].shape == shape
        assert batched["transition_rows"].shape == (*shape, N)
        assert batched["constraint_values"].shape == (*shape, model.r)
        assert np.any(batched["in_region"]) and not np.all(batched["in_region"])

        for idx in np.ndindex(*shape):
            mi, ki = int(mode[idx]), int(k[idx])
            single_x, single_mode = model.step(x[idx], mi, u[idx], ki, w[idx], float(uniform[idx]))
            single = {
                "next_state": model.next_state(x[idx], mi, u[idx], w[idx]),
                "step_x": single_x,
                "step_mode": single_mode,
                "next_mode": model.next_mode(x[idx], mi, ki, float(uniform[idx])),
                "in_region": model.in_region(x[idx], ki),
                "transition_rows": model.transition_rows(x[idx], mi, ki),
                "constraint_values": model.constraint_values(x[idx], ki),
                "stage_cost": model.stage_cost(x[idx], mi, u[idx]),
            }
            for key, value in single.items():
                np.testing.assert_allclose(
                    batched[key][idx], value, rtol=1e-13, atol=1e-13, err_msg=f"{key} at {idx}"
                )


def test_scalar_k_and_mode_broadcast_over_a_batch(paper_kwargs, paper):
    model = SDJLSModel(**paper_kwargs)
    x = np.array([[0.0, 3.0], [0.0, 2.9], [0.0, 6.1]])
    np.testing.assert_array_equal(model.in_region(x, 2), [True, False, False])  # band [3, 6]
    np.testing.assert_array_equal(
        model.transition_rows(x, 1, 2), [paper.lam[1], paper.mu[1], paper.mu[1]]
    )
    np.testing.assert_allclose(
        model.constraint_values(x, 2), x @ paper.G.T - paper.H(2), rtol=0, atol=1e-12
    )


# --------------------------------------------------------------------------- mode sampling

DRAWS = 200_000


def test_next_mode_frequencies_match_the_transition_rows(paper, paper_kwargs):
    """Seeded frequency check of inverse-CDF sampling, without a chi-square test.

    Each of the 18 empirical frequencies (3 modes x 2 regions x 3 next modes, 200000 draws
    each) must lie within 5 standard errors sqrt(p (1 - p) / n) of the paper's probability.
    This is a two-sided 5-sigma bound: under the normal approximation a correct sampler
    fails one check with probability 5.7e-7, so all 18 pass with probability > 99.99%.
    A mis-indexed row or a swapped lambda/mu moves a frequency by >= 0.01, i.e. > 9 errors.
    """
    model = SDJLSModel(**paper_kwargs)
    rng = np.random.default_rng(20240601)
    for x, table in ((np.array([0.0, 3.5]), paper.lam), (np.array([0.0, 9.0]), paper.mu)):
        xs = np.broadcast_to(x, (DRAWS, 2))
        for mode in range(3):
            draws = model.next_mode(xs, mode, 0, rng.random(DRAWS))
            assert draws.shape == (DRAWS,)
            freq = np.bincount(draws, minlength=3) / DRAWS
            p = table[mode]
            se = np.sqrt(p * (1 - p) / DRAWS)
            assert np.all(np.abs(freq - p) <= 5 * se), (mode, freq, p)


def _chain_model(P_in, P_out) -> SDJLSModel:
    """A model of one state whose transition matrices are what matters: ``x`` in C1 for
    ``x <= 0``, in C2 above."""
    N = len(P_in)
    return SDJLSModel(A=np.ones((N, 1, 1)), B=[[1.0]], P_in=P_in, P_out=P_out, G=[[1.0]],
                      H0=[0.0], Q=[[1.0]], R=[[1.0]], x0=[0.0])  # fmt: skip


def test_zero_probability_mode_is_never_drawn():
    model = _chain_model(
        [[0.0, 0.5, 0.5], [0.5, 0.0, 0.5], [0.5, 0.5, 0.0]],
        [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.6, 0.4, 0.0]],
    )
    rng = np.random.default_rng(3)
    for x in ([-1.0], [1.0]):  # in C1 (P_in) and in C2 (P_out)
        xs = np.broadcast_to(np.array(x), (DRAWS, 1))
        rows = model.P_in if x[0] <= 0 else model.P_out
        for mode in range(3):
            draws = model.next_mode(xs, mode, 0, rng.random(DRAWS))
            counts = np.bincount(draws, minlength=3)
            np.testing.assert_array_equal(counts == 0, rows[mode] == 0, err_msg=f"{x}, {mode}")


_LARGEST_UNIFORM = float(np.nextafter(1.0, 0.0))  # 1 - 2**-53, a possible Generator.random()


@pytest.mark.parametrize(
    ("row", "uniform", "forbidden"),
    [
        pytest.param([0.0, 0.6, 0.4, 0.0], 0.0, 0, id="leading-zero-u=0"),
        pytest.param([0.6, 0.0, 0.4, 0.0], 0.6, 1, id="middle-zero-u=cdf"),
        pytest.param([0.6, 0.3, 0.1, 0.0], _LARGEST_UNIFORM, 3, id="trailing-zero-u=1-2^-53"),
    ],
)
def test_zero_probability_mode_at_the_edges_of_the_uniform(row, uniform, forbidden):
    P = np.array([row] * 4)
    model = _chain_model(P, P)
    assert int(model.next_mode(np.array([0.0]), 0, 0, uniform)) != forbidden


def test_sample_next_mode_draws_the_transition_rows_with_a_generator():
    """Inside and outside the region, the drawn modes follow ``P_in`` / ``P_out``.

    200,000 draws per (region, mode); each frequency is checked against its row entry with a
    two-sided 99.99% binomial (normal) bound, 18 checks in all. Seeded, so it cannot flake.
    """
    model = sdjls_gym.macro()
    rng = np.random.default_rng(123)
    draws = 200_000
    inside_x, outside_x = np.array([0.0, 3.0]), np.array([0.0, 0.0])  # band at k = 0: [2, 5]
    for x, P in ((inside_x, model.P_in), (outside_x, model.P_out)):
        for mode in range(model.N):
            states = np.broadcast_to(x, (draws, model.n))
            nxt = model.sample_next_mode(states, np.full(draws, mode), 0, rng)
            freq = np.bincount(nxt, minlength=model.N) / draws
            sd = np.sqrt(P[mode] * (1 - P[mode]) / draws)
            assert np.all(np.abs(freq - P[mode]) <= 3.89 * sd), (mode, freq, P[mode])


def test_sample_next_mode_is_next_mode_with_the_generator_uniforms():
    model = sdjls_gym.macro()
    x = np.random.default_rng(0).normal(size=(50, 2)) * 3
    modes, k = np.arange(50) % 3, np.arange(50) % 20
    drawn = model.sample_next_mode(x, modes, k, np.random.default_rng(5))
    replayed = model.next_mode(x, modes, k, np.random.default_rng(5).random(50))
    assert np.array_equal(drawn, replayed)
    with raises_naming(TypeError, "rng", 5):
        model.sample_next_mode(x, modes, k, 5)
