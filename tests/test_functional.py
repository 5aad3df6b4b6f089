"""One implementation of the environments' step, observation and info (issue 32).

Both environments call ``sdjls_gym.functional.step``, ``step_info`` and
``sdjls_gym.observation.encode_observation``; for one state these take a path with few numpy
calls (the single environment's speed target), for a batch the batched one. The two paths are
the same functions: on random systems and random inputs (seeded; 40 systems x 25 inputs), on
states beyond the divergence box, NaN and inf, and on steps that overflow float64, they give the
same modes, ends, flags and observations, and states, costs and constraint values equal to
1e-12 relative to the scale of the terms summed (BLAS may sum a product in another order).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import pytest
from conftest import noiseless_model

from sdjls_gym import SDJLSEnv, SDJLSModel, SDJLSVectorEnv, functional
from sdjls_gym.functional import EnvParams, Restart, may_overflow
from sdjls_gym.observation import encode_observation

RTOL = 1e-12


class Step(NamedTuple):
    """The fields of ``functional.step``'s answer, by name."""

    x: np.ndarray
    mode: Any
    k: Any
    stage_cost: Any
    constraint_values: np.ndarray
    diverged: Any


def random_model(seed: int, scale: float = 1.0) -> SDJLSModel:
    """A random system with E != I, W != I and a drifting region; entries times ``scale``."""
    rng = np.random.default_rng(seed)
    N, n, m, p, r = (int(v) for v in rng.integers(1, 5, 5))
    L = rng.standard_normal((p, p))
    return SDJLSModel(
        A=scale * rng.standard_normal((N, n, n)),
        B=scale * rng.standard_normal((N, n, m)),
        E=rng.standard_normal((N, n, p)),
        W=L @ L.T + 0.1 * np.eye(p),
        P_in=rng.dirichlet(np.ones(N), size=N),
        P_out=rng.dirichlet(np.ones(N), size=N),
        G=rng.standard_normal((r, n)),
        H0=rng.uniform(-1.0, 3.0, r),
        H_rate=rng.uniform(-0.1, 0.1, r),
        Q=scale * np.eye(n),
        R=np.eye(m),
        x0=np.zeros(n),
    )


BLOWUPS = [
    noiseless_model([[1e303, -2e303], [1e303, -2e303]]),  # A x_0 is NaN in float64
    noiseless_model([[1e303, 0.0], [0.0, 1e303]]),  # A x_0 is inf
    noiseless_model(np.zeros((2, 2)), Q=1e300 * np.eye(2)),  # the stage cost overflows
    noiseless_model(np.zeros((2, 2)), Q=1e300 * np.ones((2, 2)), x0=(0.0, 1e10)),  # cost NaN
]


def params(model: SDJLSModel, bound: float = 1e6, horizon: int = 30) -> EnvParams:
    high = np.full(model.m, 100.0)
    return EnvParams(model, horizon, bound, may_overflow(model, high, bound, horizon))


def close(a, b, scale, what: str) -> None:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    same_kind = (np.isnan(a) == np.isnan(b)) & (np.isinf(a) == np.isinf(b))
    assert np.all(same_kind), f"{what}: {a} vs {b}"
    finite = np.isfinite(a) & np.isfinite(b)
    assert np.all(a[~finite & ~np.isnan(a)] == b[~finite & ~np.isnan(a)]), f"{what}: {a} vs {b}"
    err = np.abs(a - b, where=finite, out=np.zeros_like(a))
    assert np.all(err <= RTOL * np.asarray(scale) + 1e-300), f"{what}: {a} vs {b}"


def inputs(model: SDJLSModel, rng: np.random.Generator, x_scale: float):
    x = rng.normal(0.0, x_scale, model.n)
    u = rng.normal(0.0, 10.0, model.m)
    w = model.sample_noise(rng)
    return x, int(rng.integers(model.N)), u, int(rng.integers(0, 25)), w, float(rng.random())


def check_one_against_batch(p: EnvParams, x, mode, u, k, w, uniform, inside) -> None:
    """``step`` of one state equals ``step`` of the same state as a batch of 3 (row 1)."""
    model, dyn = p.model, p.model.dynamics
    one = Step(*functional.step(p, x, mode, k, u, w, uniform, inside))
    X, U, Wb = (np.stack([v * 0.5, v, -v]) for v in (x, u, w))
    batch = Step(*functional.step(
        p, X, np.array([0, mode, model.N - 1]), np.array([k, k, 0]), U, Wb,
        np.array([0.5, uniform, 0.9]), np.array([True, inside, False]),
    ))  # fmt: skip
    assert type(one.mode) is int and type(one.k) is int and type(one.diverged) is bool
    assert type(one.stage_cost) is float
    assert one.mode == batch.mode[1] and one.k == batch.k[1] == k + 1
    assert one.diverged == batch.diverged[1]
    z = np.abs(np.concatenate([x, u, w]))
    with np.errstate(over="ignore", invalid="ignore"):
        x_scale = np.abs(dyn.ABE[mode]) @ z
        zxu = z[: model.n + model.m]
        cost_scale = zxu @ np.abs(dyn.QR[mode]) @ zxu
        values_scale = np.abs(model.G) @ x_scale + np.abs(model.H(k + 1))
    close(one.x, batch.x[1], x_scale, "x")
    close(one.stage_cost, batch.stage_cost[1], cost_scale, "stage cost")
    close(one.constraint_values, batch.constraint_values[1], values_scale, "constraint values")


@pytest.mark.parametrize("seed", range(40))
def test_one_state_step_equals_the_batched_step(seed):
    rng = np.random.default_rng(1000 + seed)
    model = random_model(seed, scale=[1.0, 1e3, 1e-3, 40.0][seed % 4])
    p = params(model, bound=[1e6, 5.0, 1e30, 1e6][seed % 4])
    for i in range(25):
        x, mode, u, k, w, uniform = inputs(model, rng, x_scale=[1.0, 1e3, 10.0][i % 3])
        inside = bool(model.in_region(x, k))
        check_one_against_batch(p, x, mode, u, k, w, uniform, inside)
        # the region test done by the transition itself, when not given
        mode1 = model.transition(x, mode, u, k, w, uniform)[1]
        mode2 = model.transition(x[None], [mode], u[None], np.array([k]), w[None], [uniform])[1]
        margin = np.abs(model.constraint_values(x, k)).min()
        if margin > 1e-9 * (1.0 + np.abs(x).max()):  # not on the region's boundary
            assert mode1 == mode2[0]


@pytest.mark.parametrize("case", range(len(BLOWUPS)))
def test_overflowing_step_is_the_same_exact_answer_in_both_paths(case):
    """A step that overflows float64 gets ``exact_transition`` (never NaN) in both paths, with
    the same bits: the exact value rounded once has one answer."""
    model = BLOWUPS[case]
    p = params(model, bound=1e30, horizon=5)
    assert p.may_overflow
    x, u, w = model.x0.copy(), np.zeros(1), np.zeros(2)
    with np.errstate(all="raise"):
        one = Step(*functional.step(p, x, 0, 0, u, w, 0.5, True))
        batch = Step(*functional.step(
            p, np.stack([x, x]), np.zeros(2, np.int64), np.zeros(2, np.int64),
            np.zeros((2, 1)), np.zeros((2, 2)), np.full(2, 0.5), np.ones(2, bool),
        ))  # fmt: skip
    exact_x, exact_cost, exact_values = model.exact_transition(x, 0, u, 0, w)
    assert one.diverged and batch.diverged.all()
    assert not np.isnan(one.x).any() and not np.isnan(one.constraint_values).any()
    for got_x, got_values in (
        (one.x, one.constraint_values),
        (batch.x[0], batch.constraint_values[0]),
    ):
        assert got_x.tolist() == exact_x.tolist()
        assert got_values.tolist() == exact_values.tolist()
    saturated = min(exact_cost, functional.MAX_STAGE_COST)
    assert one.stage_cost == batch.stage_cost[0] == batch.stage_cost[1] == saturated


def test_restarted_rows_start_over():
    """Rows that restart get x0, their initial modes, k = 0, a zero cost and the constraint
    values of x0 at 0, whatever their state and draws; the other rows step as without them."""
    model = random_model(3)
    p = params(model)
    rng = np.random.default_rng(0)
    B = 5
    x = rng.normal(0.0, 1.0, (B, model.n))
    x[2] = np.inf  # a diverged row that restarts: kept out of the arithmetic
    mode, k = rng.integers(0, model.N, B), rng.integers(0, 10, B)
    u, w = rng.normal(0.0, 1.0, (B, model.m)), model.sample_noise(rng, (B,))
    uniform, inside = rng.random(B), np.ones(B, bool)
    rows = np.array([False, False, True, False, True])
    modes0 = np.array([model.N - 1, 0])
    with np.errstate(all="raise"):
        new = Step(
            *functional.step(p, x, mode, k, u, w, uniform, inside, Restart(rows, model.x0, modes0))
        )
    plain = Step(
        *functional.step(p, np.where(rows[:, None], 0.0, x), mode, k, u, w, uniform, inside)
    )
    assert np.array_equal(new.x[rows], np.stack([model.x0] * 2))
    assert new.mode[rows].tolist() == modes0.tolist() and new.k[rows].tolist() == [0, 0]
    assert new.stage_cost[rows].tolist() == [0.0, 0.0] and not new.diverged[rows].any()
    assert np.array_equal(new.constraint_values[rows], model.constraint_values(new.x[rows], 0))
    for key in ("x", "mode", "k", "stage_cost", "constraint_values", "diverged"):
        assert np.array_equal(getattr(new, key)[~rows], getattr(plain, key)[~rows]), key
    assert np.isinf(x[2]).all()  # the caller's state is not changed


@pytest.mark.parametrize("seed", range(10))
def test_observation_and_info_of_one_state_equal_the_batched_ones(seed):
    """``encode_observation`` and ``step_info`` of one state: the batched values, bit for bit,
    with Python scalars in the info; states beyond the box, inf and NaN included."""
    rng = np.random.default_rng(seed)
    model = random_model(seed)
    bound = 10.0
    for i in range(30):
        x = rng.normal(0.0, 8.0, model.n)
        if i % 5 == 1:
            x[rng.integers(model.n)] = [np.inf, -np.inf, np.nan][i % 3]
        mode, k = int(rng.integers(model.N)), int(rng.integers(0, 30))
        one = encode_observation(model, x, mode, k, 30, bound)
        batch = encode_observation(model, x[None], np.array([mode]), np.array([k]), 30, bound)
        assert one.dtype == batch.dtype == np.float32 and np.array_equal(one, batch[0])
        assert np.all(np.isfinite(one)) and np.abs(one[: model.n]).max() <= bound
        diverged = not (np.abs(x).max() <= bound)
        with np.errstate(invalid="ignore", over="ignore"):
            info = functional.step_info(model, x, mode, k, 2.5, diverged)
            infos = functional.step_info(
                model, x[None], np.array([mode]), np.array([k]), np.array([2.5]),
                np.array([diverged]),
            )  # fmt: skip
        assert sorted(info) == sorted(infos)
        types = {key: type(value) for key, value in info.items()}
        assert types["mode"] is types["k"] is int and types["in_region"] is bool
        assert types["cost"] is types["stage_cost"] is float and types["diverged"] is bool
        for key, value in info.items():
            assert np.array_equal(value, infos[key][0], equal_nan=True), key


def test_both_environments_step_through_the_one_function(monkeypatch):
    """``SDJLSEnv`` and ``SDJLSVectorEnv`` both take their steps with ``functional.step`` and
    build their infos with ``functional.step_info``."""
    calls = {"step": [], "step_info": []}
    for name in calls:
        original = getattr(functional, name)

        def spy(*args, _original=original, _name=name, **kwargs):
            calls[_name].append(np.ndim(args[1]))  # 1: one state, 2: a batch
            return _original(*args, **kwargs)

        monkeypatch.setattr(functional, name, spy)
    env = SDJLSEnv("macro")
    env.reset(seed=0)
    env.step(np.zeros(1, np.float32))
    envs = SDJLSVectorEnv(3, model="macro")
    envs.reset(seed=0)
    envs.step(np.zeros((3, 1)))
    assert calls["step"] == [1, 2]
    assert calls["step_info"] == [1, 1, 2, 2]  # reset and step of each
