"""The batched paths agree with the single-state ones (issue: performance).

* ``act_batch`` returns the same decisions as ``act`` (OSQP) on the same states;
* ``SDJLSModel.transition`` of one state (the single env's hot path) equals the batched one
  (``tests/test_functional.py`` has more);
* the vector env driven by ``act_batch`` gives the same trajectories as stepping one
  sub-environment alone, with ``act``, on the same noise (replayed through a recording RNG).
"""

from __future__ import annotations

import numpy as np
import pytest

import sdjls_gym
from controllers import (
    LinearFeedbackController,
    MJLSLQRController,
    RecedingHorizonController,
    UnconstrainedRecedingHorizonController,
)
from sdjls_gym import SDJLSModel, SDJLSVectorEnv
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC

KINDS = ("individual", "joint", "bonferroni")


def random_system(seed: int) -> tuple[SDJLSModel, np.ndarray, np.ndarray]:
    """A random system with E != I, W != I, and random gains and terminal weights."""
    rng = np.random.default_rng(seed)
    N, n, m, p, r = 3, 3, 2, 2, 3
    P_in = rng.random((N, N)) + 0.1
    P_out = rng.random((N, N)) + 0.1
    L = rng.standard_normal((p, p))
    model = SDJLSModel(
        A=0.6 * rng.standard_normal((N, n, n)),
        B=rng.standard_normal((N, n, m)),
        E=rng.standard_normal((N, n, p)),
        W=L @ L.T + 0.1 * np.eye(p),
        P_in=P_in / P_in.sum(1, keepdims=True),
        P_out=P_out / P_out.sum(1, keepdims=True),
        G=rng.standard_normal((r, n)),
        H0=rng.uniform(0.5, 3.0, r),
        H_rate=rng.uniform(-0.1, 0.1, r),
        Q=np.eye(n),
        R=np.eye(m),
        x0=rng.standard_normal(n),
    )
    K = 0.3 * rng.standard_normal((N, m, n))
    Psi = np.array([np.eye(n) * (1 + i) for i in range(N)])
    return model, K, Psi


def random_states(model: SDJLSModel, size: int, seed: int, scale: float = 5.0):
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, scale, (size, model.n))
    return x, rng.integers(0, model.N, size), rng.integers(0, 20, size)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("xi", [0.3, 0.85, 0.97])
def test_act_batch_equals_act_on_the_example(kind, xi):
    model = sdjls_gym.macro()
    ctrl = RecedingHorizonController(model, PAPER_K, Psi=PAPER_RHC["Psi"], xi=xi, constraint=kind)
    x, mode, k = random_states(model, 60, seed=int(xi * 100))
    u_b, info_b = ctrl.act_batch(x, mode, k)
    for i in range(len(x)):
        u, info = ctrl.act(x[i], int(mode[i]), int(k[i]))
        assert info["status"] == "solved"
        np.testing.assert_allclose(u_b[i], u, atol=1e-6, rtol=0)
        assert info_b["rho"][i] == pytest.approx(info["rho"], abs=1e-6)
        assert info_b["cost"][i] == pytest.approx(info["cost"], rel=1e-9, abs=1e-6)
    assert info_b["ok"].all()


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("kind", KINDS)
def test_act_batch_equals_act_on_random_systems(seed, kind):
    model, K, Psi = random_system(seed)
    ctrl = RecedingHorizonController(model, K, Psi=Psi, xi=0.9, constraint=kind, nu_bound=2.0)
    x, mode, k = random_states(model, 40, seed=seed + 10)
    u_b, info_b = ctrl.act_batch(x, mode, k)
    for i in range(len(x)):
        u, info = ctrl.act(x[i], int(mode[i]), int(k[i]))
        np.testing.assert_allclose(u_b[i], u, atol=1e-6, rtol=0)
        assert info_b["rho"][i] == pytest.approx(info["rho"], abs=1e-6)
        assert info_b["cost"][i] == pytest.approx(info["cost"], rel=1e-8, abs=1e-6)


def test_act_batch_of_the_other_controllers_equals_act():
    model, K, Psi = random_system(7)
    x, mode, k = random_states(model, 30, seed=3)
    for ctrl in (
        UnconstrainedRecedingHorizonController(model, K, Psi=Psi, nu_bound=1.5),
        LinearFeedbackController(model, K),
        LinearFeedbackController(model, -K),
    ):
        u_b, info_b = ctrl.act_batch(x, mode, k)
        for i in range(len(x)):
            u, info = ctrl.act(x[i], int(mode[i]), int(k[i]))
            np.testing.assert_allclose(u_b[i], u, atol=1e-6, rtol=0)
            assert info_b["cost"][i] == pytest.approx(info["cost"], rel=1e-9)
    lqr = MJLSLQRController(sdjls_gym.macro())
    xm, mm, km = random_states(sdjls_gym.macro(), 20, seed=4)
    u_b, _ = lqr.act_batch(xm, mm, km)
    for i in range(len(xm)):
        np.testing.assert_allclose(u_b[i], lqr.act(xm[i], int(mm[i]), int(km[i]))[0], atol=1e-9)


def test_one_state_transition_equals_the_batched_step():
    model, _, _ = random_system(11)
    rng = np.random.default_rng(0)
    for _ in range(200):
        x = rng.normal(0, 2, model.n)
        mode = int(rng.integers(model.N))
        u = rng.normal(0, 1, model.m)
        k = int(rng.integers(0, 30))
        w = rng.normal(0, 1, model.p)
        v = float(rng.random())
        x1, m1, cost1, values1 = model.transition(x, mode, u, k, w, v)
        x2, m2 = model.step(x[None], np.array([mode]), u[None], np.array([k]), w[None], [v])
        np.testing.assert_allclose(x1, x2[0], rtol=1e-12, atol=1e-12)
        assert m1 == m2[0]
        assert cost1 == pytest.approx(float(model.stage_cost(x, mode, u)), rel=1e-12)
        np.testing.assert_allclose(values1, model.constraint_values(x2[0], k + 1), atol=1e-12)


class RecordingRNG:
    """Delegates to a Generator and records what ``standard_normal`` and ``random`` return."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.normals: list[np.ndarray] = []
        self.uniforms: list[np.ndarray] = []

    def standard_normal(self, size):
        out = self.rng.standard_normal(size)
        self.normals.append(out)
        return out

    def random(self, size=None):
        out = self.rng.random(size)
        self.uniforms.append(np.asarray(out))
        return out


class ReplayRNG:
    """Returns, in order, given noise vectors and uniforms (one sub-environment's share)."""

    def __init__(self, normals: list[np.ndarray], uniforms: list[float]) -> None:
        self.normals, self.uniforms = list(normals), list(uniforms)

    def standard_normal(self, size):
        out = self.normals.pop(0)
        assert out.shape == (size,) if np.ndim(size) == 0 else tuple(size)
        return out.copy()

    def random(self, size=None):
        assert size is None
        return float(self.uniforms.pop(0))


@pytest.mark.parametrize("observe", ["mode", "state"])
@pytest.mark.parametrize("which", ["macro", "random"])
def test_vector_env_with_act_batch_equals_single_env_with_act_on_the_same_noise(which, observe):
    """Step by step on the same draws: the inputs, the states and the observations (of either
    layout: ``observe="state"`` hides the mode, the controller reads it from the infos)."""
    if which == "macro":
        model, K, Psi = sdjls_gym.macro(), PAPER_K, PAPER_RHC["Psi"]
    else:
        model, K, Psi = random_system(5)
        model = SDJLSModel(**{**model.to_dict(), "W": np.eye(model.p)})  # W = I: same draws
    ctrl = RecedingHorizonController(model, K, Psi=Psi, xi=0.85, nu_bound=100.0)
    B, T = 6, 20
    venv = SDJLSVectorEnv(num_envs=B, model=model, horizon=T, observe=observe)
    obs, info = venv.reset(seed=0)  # x0 and an int mode0: the reset draws nothing
    rec = RecordingRNG(123)
    venv.np_random = rec
    xs, us, observations = [info["state"].copy()], [], [obs]
    for _ in range(T):
        u, _ = ctrl.act_batch(info["state"], info["mode"], info["k"])
        obs, _, _, _, info = venv.step(u)
        xs.append(info["state"].copy())
        us.append(info["u"].copy())
        observations.append(obs)
    xs = np.array(xs)
    assert observations[0].shape == (B, model.n + (model.N if observe == "mode" else 0) + 1)
    for i in range(B):
        env = sdjls_gym.SDJLSEnv(model, horizon=T, observe=observe)
        sobs, sinfo = env.reset(seed=1)
        np.testing.assert_array_equal(sobs, observations[0][i])
        env.np_random = ReplayRNG(
            [nrm[i] for nrm in rec.normals], [float(uni[i]) for uni in rec.uniforms]
        )
        for t in range(T):
            u, _ = ctrl.act(sinfo["state"], sinfo["mode"], sinfo["k"])
            np.testing.assert_allclose(u, us[t][i], atol=1e-6)
            sobs, _, _, _, sinfo = env.step(u)
            np.testing.assert_allclose(sinfo["state"], xs[t + 1, i], atol=1e-6)
            np.testing.assert_allclose(sobs, observations[t + 1][i], rtol=1e-6, atol=1e-6)


def test_active_set_solve_of_a_batch_equals_the_single_instance_path():
    """``ActiveSetQP.solve(w)`` on a batch (C- or Fortran-ordered ``w = [q; h]``) gives the same
    active sets as the single-instance enumeration and the same optimum as cvxpy, on a small QP
    with a singular Hessian (the slack-like second variable)."""
    import cvxpy as cp

    from controllers.qp import QPFamily
    from controllers.rhc import DEFAULT_OSQP_SETTINGS

    P = np.array([[2.0, 0.0], [0.0, 0.0]])
    A = np.array([[1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])
    lo, hi = np.array([-np.inf, -1.0, 0.0]), np.array([0.5, 1.0, np.inf])
    fam = QPFamily(P, A, np.isfinite(lo), np.isfinite(hi), DEFAULT_OSQP_SETTINGS)
    qp = fam.enumeration()
    rng = np.random.default_rng(0)
    q = np.column_stack([rng.normal(size=50) * 3, np.full(50, 10.0)])
    lower, upper = np.tile(lo, (50, 1)), np.tile(hi, (50, 1))
    upper[:, 0] = rng.normal(size=50)
    w = np.concatenate([q, fam.one_sided_bounds(lower, upper)], axis=1)
    z1, ok1 = qp.solve(w)
    z2, ok2 = qp.solve(np.ascontiguousarray(w.T).T)
    assert ok1.all() and np.array_equal(ok1, ok2) and np.array_equal(z1, z2)
    for i in range(50):
        rows, z_one = qp.solve_one(w[i])
        np.testing.assert_allclose(fam.verify(rows, w[i]), z1[i], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(z_one, fam.verify(rows, w[i]))
        z = cp.Variable(2)
        prob = cp.Problem(
            cp.Minimize(cp.square(z[0]) + q[i] @ z),
            [A[0] @ z <= upper[i, 0], cp.abs(z[0]) <= 1.0, z[1] >= 0.0],
        )
        prob.solve(solver=cp.CLARABEL)
        assert 0.5 * z1[i] @ P @ z1[i] + q[i] @ z1[i] == pytest.approx(prob.value, abs=1e-7)


def test_act_and_act_batch_choose_the_same_family_at_an_exact_tie():
    """States on the region's boundary to the last bit: ``H0 = G x`` as float64 computes it for
    one state, so ``G x - H_0`` was 0.0 for ``act`` and 2.2e-16 for ``act_batch`` where BLAS
    sums a batch in another order (11 of these 40 here): different families (``P_in`` or
    ``P_out``), possibly different answers. Both now take the model's region test, which
    decides a row within round-off of 0 exactly: the same family and answer, that of
    ``G x <= H_0`` in rational arithmetic."""
    from fractions import Fraction

    rng = np.random.default_rng(0)
    Psi = np.tile(np.eye(3), (2, 1, 1))
    checked = []
    for _ in range(40):
        G, x = rng.normal(size=(2, 3)), rng.normal(size=3)
        model = SDJLSModel(
            A=0.5 * rng.normal(size=(2, 3, 3)), B=rng.normal(size=(2, 3, 1)),
            P_in=[[0.9, 0.1], [0.2, 0.8]], P_out=[[0.1, 0.9], [0.7, 0.3]], G=G, H0=G @ x,
            Q=np.eye(3), R=np.eye(1), x0=np.zeros(3),
        )  # fmt: skip
        exact = all(
            sum(Fraction(g) * Fraction(v) for g, v in zip(row, x, strict=True)) <= Fraction(h)
            for row, h in zip(G.tolist(), model.H0.tolist(), strict=True)
        )
        ctrl = RecedingHorizonController(model, np.zeros((2, 1, 3)), Psi=Psi, xi=0.9)
        _, one = ctrl.act(x, 0, 0)
        _, batch = ctrl.act_batch(np.tile(x, (8, 1)), np.zeros(8, dtype=int), 0)
        assert np.all(batch["in_region"] == one["in_region"]), (one["in_region"], exact)
        np.testing.assert_allclose(batch["nu"], np.tile(one["nu"], (8, 1)), rtol=1e-9, atol=1e-12)
        assert np.allclose(batch["cost"], one["cost"], rtol=1e-12)
        checked.append((model, x, one["in_region"], exact))
    for model, x, inside, exact in checked:
        assert inside is exact and np.all(model.in_region(x, 0) == exact)
        assert model.in_region_one(x, 0) is exact


def test_a_batch_of_tied_and_untied_states_decides_each_as_alone():
    """The exact tie rule decides each distinct tied (row, state) once for a whole batch (a
    vector env started from one state ties in every env): a shuffled batch of copies of tied
    states, states off the boundary and non-finite ones gives, state by state, what
    ``in_region_one`` gives alone, in every batch shape."""
    rng = np.random.default_rng(1)
    G = rng.normal(size=(3, 2))
    ties = rng.normal(size=(4, 2))
    model = SDJLSModel(
        A=0.5 * rng.normal(size=(2, 2, 2)), B=rng.normal(size=(2, 2, 1)),
        P_in=[[0.9, 0.1], [0.2, 0.8]], P_out=[[0.1, 0.9], [0.7, 0.3]], G=G, H0=G @ ties[0],
        Q=np.eye(2), R=np.eye(1), x0=np.zeros(2),
    )  # fmt: skip
    # ties[0] lies on every row's boundary to the last bit (H0 = G x), 50 copies of it
    states = np.concatenate([np.repeat(ties, 50, axis=0), rng.normal(size=(100, 2)),
                             [[np.inf, 0.0], [np.nan, 1.0]]])  # fmt: skip
    states = states[rng.permutation(len(states))]
    alone = np.array([model.in_region_one(s, 0) if np.all(np.isfinite(s))
                      else bool(np.all(model.in_region(s, 0))) for s in states])  # fmt: skip
    assert alone.any() and not alone.all()
    np.testing.assert_array_equal(model.in_region(states, 0), alone)
    np.testing.assert_array_equal(model.in_region(states.reshape(2, -1, 2), 0),
                                  alone.reshape(2, -1))  # fmt: skip
