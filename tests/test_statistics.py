"""Seeded statistical tests, a soak test, determinism, and no use of a global random generator.

* ``test_chance_constraints_hold_at_the_stated_frequency``: 102,000 closed-loop samples of a
  3-state system that is not the paper's example; the per-row violation counts are compared with
  binomial bounds for the guarantee 1 - xi at 99.9% confidence (details in its docstring).
* ``test_soak_one_million_steps_of_the_example``: 10^6 closed-loop steps of SDJLS-Macro-v0 under
  the paper's controller: nothing non-finite, rho = 0 throughout, and the empirical E||x_k||^2
  (upper 99.9% confidence bound) under the Proposition 1 bound at every k.
* Determinism: the same seed gives bit-identical closed-loop trajectories, in one process and
  across processes with different hash seeds.
* numpy's and Python's global random generators are never touched.
"""

from __future__ import annotations

import ast
import hashlib
import os
import random
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
from scipy import stats

from benchmarks.core.montecarlo import rollout
from controllers import (
    LinearFeedbackController,
    MJLSLQRController,
    RecedingHorizonController,
    row_satisfaction_probability,
    synthesize_gains,
    tightening,
    verify_mean_square_bound,
)
from sdjls_gym import SDJLSModel, SDJLSVectorEnv
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro
from sdjls_gym.wrappers import ResidualAction, ViolationPenalty

ROOT = Path(__file__).resolve().parents[1]
CONFIDENCE = 0.999


def statistical_model() -> SDJLSModel:
    """N = 2, n = 3, m = 2, p = 2, r = 3; E and W are not the identity.

    The rows ask for ``x(1) >= 0.5 + 0.01 k``, ``x(2) >= 0.2`` and ``x(1) - x(2) <= 1.2 - 0.05 k``
    while the cost pulls the state towards 0, so the controller keeps the mean of ``x_{k+1}`` on
    the tightened boundary of the first two rows most of the time, and on the third one late in
    the episode: every row is often active (tight), which is what gives the test its power.
    """
    return SDJLSModel(
        A=[
            [[0.9, 0.2, 0.0], [0.0, 0.8, 0.1], [0.1, 0.0, 0.7]],
            [[1.1, 0.0, 0.3], [0.2, 0.95, 0.0], [0.0, 0.4, 0.6]],
        ],
        B=[[[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]], [[0.6, 0.0], [0.0, 1.0], [0.3, 0.3]]],
        E=[[[0.4, 0.0], [0.1, 0.3], [0.0, 0.2]], [[0.3, 0.1], [0.0, 0.5], [0.2, 0.2]]],
        W=[[1.0, 0.3], [0.3, 0.5]],
        P_in=[[0.85, 0.15], [0.3, 0.7]],
        P_out=[[0.4, 0.6], [0.1, 0.9]],
        G=[[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [1.0, -1.0, 0.0]],
        H0=[-0.5, -0.2, 1.2],
        H_rate=[-0.01, 0.0, -0.05],
        Q=np.diag([1.0, 2.0, 0.5]),
        R=[np.eye(2), [[2.0, 0.3], [0.3, 1.0]]],
        x0=[1.0, 0.5, 0.0],
        mode0=[0.5, 0.5],
    )


def test_chance_constraints_hold_at_the_stated_frequency():
    """Individual chance constraints at xi = 0.9 on ``statistical_model()`` with gains from
    ``synthesize_gains``: 5100 episodes x 20 steps = 102,000 closed-loop samples (x_k, theta_k,
    k) -> x_{k+1} on SDJLSVectorEnv (seed 20240), decisions by ``act_batch``.

    Given F_k, row j of x_{k+1} is violated with probability 1 - Pr_j <= 1 - xi when rho_k = 0,
    with equality on the rows that are active (tight) at the optimum. The selection of samples
    (rho_k = 0, row j active) depends only on F_k and the violation only on the fresh noise w_k,
    so the selected violation indicators are i.i.d. Bernoulli: the counts are exactly binomial.
    For each row j, at confidence 99.9% each (9 assertions, all seeded):

    1. over all samples with rho = 0 (at least 10^5 of them): violations <= the upper 99.9%
       quantile of Binomial(n, 1 - xi);
    2. over the samples where row j is active: violations within the central 99.9% interval of
       Binomial(n_active, 1 - xi), i.e. the frequency is 1 - xi, not just at most 1 - xi
       (n_active >= 30,000 for every row);
    3. over all samples with rho = 0: violations within 3.29 standard deviations of the sum of
       the exact per-sample violation probabilities (a two-sided 99.9% normal bound).
    """
    model, xi = statistical_model(), 0.9
    K = synthesize_gains(model).K
    ctrl = RecedingHorizonController(
        model, K, Psi=np.array([np.eye(3), 2.0 * np.eye(3)]), xi=xi, alpha=1000.0, nu_bound=50.0
    )
    envs = SDJLSVectorEnv(5100, model=model, horizon=20, action_bound=1e4)
    _, infos = envs.reset(seed=20240)
    sd = np.sqrt(
        np.einsum("jn,inm,jm->ij", model.G, model.E @ model.W @ model.E.transpose(0, 2, 1), model.G)
    )
    t = stats.norm.ppf(xi) * sd  # (N, r): eq. (constraint:det_univariate), computed here
    rho_zero, violated, active, prob_ok = [], [], [], []
    for _ in range(20):
        x, mode, k = infos["state"], infos["mode"], infos["k"]
        u, cinfo = ctrl.act_batch(x, mode, k)
        assert cinfo["ok"].all()
        mean = np.einsum("bij,bj->bi", model.A[mode], x) + np.einsum("bij,bj->bi", model.B[mode], u)
        H_next = model.H0 + (k[:, None] + 1) * model.H_rate
        margin = H_next - mean @ model.G.T  # > 0: the mean is inside row j
        _, _, terminated, truncated, infos = envs.step(u)
        np.testing.assert_array_equal(infos["u"], u)  # nothing clipped: x_{k+1} is Gaussian
        assert not terminated.any()
        rho_zero.append(cinfo["rho"] == 0.0)
        violated.append(infos["violations"])
        active.append(np.abs(margin - t[mode]) <= 1e-9 * np.maximum(1.0, np.abs(H_next)))
        prob_ok.append(stats.norm.cdf(margin / sd[mode]))  # exact Pr{row j holds | F_k}
    assert truncated.all()
    rho_zero, violated = np.concatenate(rho_zero), np.concatenate(violated)
    active, prob_ok = np.concatenate(active), np.concatenate(prob_ok)
    assert violated.shape == (102_000, 3) and rho_zero.sum() >= 100_000

    q = 1.0 - prob_ok[rho_zero]  # exact violation probabilities, all <= 1 - xi
    assert np.all(q <= 1.0 - xi + 1e-9)
    alpha = 1.0 - CONFIDENCE
    for j in range(model.r):
        count, n = int(violated[rho_zero, j].sum()), int(rho_zero.sum())
        assert count <= stats.binom.ppf(CONFIDENCE, n, 1.0 - xi), (j, count, n)

        sel = rho_zero & active[:, j]
        count, n = int(violated[sel, j].sum()), int(sel.sum())
        low, high = stats.binom.ppf([alpha / 2, 1.0 - alpha / 2], n, 1.0 - xi)
        assert n >= 30_000 and low <= count <= high, (j, count, n, low, high)

        expected, var = q[:, j].sum(), (q[:, j] * (1.0 - q[:, j])).sum()
        z = (violated[rho_zero, j].sum() - expected) / np.sqrt(var)
        assert abs(z) <= stats.norm.ppf(1.0 - alpha / 2), (j, z)


def test_soak_one_million_steps_of_the_example():
    """SDJLS-Macro-v0 under the paper's controller (PAPER_K, PAPER_RHC), 50,000 episodes x 20
    steps = 10^6 closed-loop steps, seed 7: every state, input, reward, slack and cost is finite,
    every QP is solved (rho = 0 throughout, as section 6 reports), and the upper 99.9% confidence
    bound of E||x_k||^2 (mean + 3.09 standard errors) is below the Proposition 1 bound
    ``beta1 ||x0||^2 q^k + beta2`` of ``verify_mean_square_bound(..., nu_bound=100)`` at every
    k = 0..20. (That bound is valid for any |nu_k| <= 100 and is far from tight here.)"""
    model, runs, horizon = macro(), 50_000, 20
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    cert = verify_mean_square_bound(model, PAPER_K, nu_bound=PAPER_RHC["nu_bound"])
    envs = gym.make_vec("SDJLS-Macro-v0", num_envs=runs, vectorization_mode="vector_entry_point")
    obs, infos = envs.reset(seed=7)
    sq_norm = np.empty((horizon + 1, runs))
    sq_norm[0] = np.sum(infos["state"] ** 2, axis=1)
    with np.errstate(all="raise"):
        for k in range(horizon):
            u, cinfo = ctrl.act_batch(infos["state"], infos["mode"], infos["k"])
            assert cinfo["ok"].all() and np.all(cinfo["rho"] == 0.0)
            for value in (u, cinfo["nu"], cinfo["cost"]):
                assert np.all(np.isfinite(value))
            obs, rewards, terminated, truncated, infos = envs.step(u)
            assert np.all(np.isfinite(rewards)) and np.all(np.isfinite(obs))
            assert np.all(np.isfinite(infos["state"])) and not terminated.any()
            sq_norm[k + 1] = np.sum(infos["state"] ** 2, axis=1)
    assert truncated.all()
    z = stats.norm.ppf(CONFIDENCE)
    upper = sq_norm.mean(axis=1) + z * sq_norm.std(axis=1, ddof=1) / np.sqrt(runs)
    bound = cert.bound(np.arange(horizon + 1), model.x0)
    assert np.all(upper <= bound), np.c_[upper, bound]


# ----------------------------------------------------------------------------- determinism
def closed_loop(seed: int, ctrl=None, episodes: int = 3) -> np.ndarray:
    """Episodes of SDJLS-Macro-v0 with the paper's controller (``act``): every state, mode,
    input, reward, slack and cost, as one float64 array."""
    ctrl = ctrl or RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    env = gym.make("SDJLS-Macro-v0")
    rows = []
    for episode in range(episodes):
        _, info = env.reset(seed=seed + episode)
        done = False
        while not done:
            u, cinfo = ctrl.act(info["state"], info["mode"], info["k"])
            _, reward, terminated, truncated, info = env.step(u)
            rows.append([*info["state"], info["mode"], *u, reward, cinfo["rho"], cinfo["cost"]])
            done = terminated or truncated
    return np.array(rows)


def closed_loop_batch(seed: int, ctrl=None) -> np.ndarray:
    """64 episodes on the vector env with ``act_batch`` on statistical_model(), with gains from
    synthesize_gains: states, modes, inputs, rewards, slacks, costs."""
    model = statistical_model()
    if ctrl is None:
        K = synthesize_gains(model).K
        ctrl = RecedingHorizonController(
            model, K, Psi=np.array([np.eye(3)] * 2), xi=0.9, nu_bound=50.0
        )
    envs = SDJLSVectorEnv(64, model=model, horizon=20, action_bound=1e4)
    _, infos = envs.reset(seed=seed)
    out = []
    for _ in range(25):  # past the horizon: autoreset included
        u, cinfo = ctrl.act_batch(infos["state"], infos["mode"], infos["k"])
        _, rewards, _, _, infos = envs.step(u)
        out.append(np.c_[infos["state"], infos["mode"], u, rewards, cinfo["rho"], cinfo["cost"]])
    return np.stack(out)


def digest() -> str:
    """sha256 of both closed loops with seed 123 (run in a fresh process by the test below)."""
    h = hashlib.sha256()
    for arr in (closed_loop(123), closed_loop_batch(123)):
        h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    return h.hexdigest()


def test_same_seed_gives_bit_identical_closed_loops():
    a, b, c = closed_loop(123), closed_loop(123), closed_loop(124)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    a, b, c = closed_loop_batch(123), closed_loop_batch(123), closed_loop_batch(124)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_reused_batch_controller_gives_bit_identical_closed_loops():
    model = statistical_model()
    ctrl = RecedingHorizonController(
        model, synthesize_gains(model).K, Psi=np.array([np.eye(3)] * 2), xi=0.9, nu_bound=50.0
    )
    assert np.array_equal(closed_loop_batch(5, ctrl), closed_loop_batch(5, ctrl))


def test_act_does_not_depend_on_the_call_history():
    """The same (x, mode, k) gives bit-identical answers from a fresh controller and from one
    that has already been used, so re-running with the same seed reproduces a run exactly."""
    rng = np.random.default_rng(0)
    used = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    for _ in range(300):
        x, mode, k = rng.normal(size=2) * 5, int(rng.integers(3)), int(rng.integers(20))
        fresh = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
        a, b = fresh.act(x, mode, k)[1], used.act(x, mode, k)[1]
        assert np.array_equal(a["nu"], b["nu"]) and a["cost"] == b["cost"]


def test_same_seed_gives_bit_identical_closed_loops_across_processes():
    """Two fresh interpreters with different hash seeds reproduce this process's trajectories."""
    code = "import test_statistics as t; print(t.digest())"
    path = os.pathsep.join([str(ROOT), str(ROOT / "tests")])
    digests = set()
    for hash_seed in ("0", "12345"):
        env = {**os.environ, "PYTHONPATH": path, "PYTHONHASHSEED": hash_seed}
        out = subprocess.run(
            [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
            timeout=300, check=True,
        )  # fmt: skip
        digests.add(out.stdout.strip().splitlines()[-1])
    assert digests == {digest()}


# ----------------------------------------------------------------------------- global RNG
def test_global_random_generators_are_never_touched():
    # reading the legacy global state is the point of this test
    np_state, py_state = np.random.get_state(), random.getstate()  # noqa: NPY002
    model = macro()
    env = ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K)
    env = ViolationPenalty(env, beta=10.0)
    env.action_space.seed(0)
    env.reset(seed=0)
    for _ in range(5):
        env.step(env.action_space.sample())
    envs = gym.make_vec("SDJLS-Macro-v0", num_envs=4, vectorization_mode="vector_entry_point")
    envs.reset(seed=0)
    envs.step(np.zeros((4, 1)))
    # unseeded resets: each env seeds its own generator from OS entropy, not from np.random
    gym.make("SDJLS-v0", model=statistical_model()).reset()
    SDJLSVectorEnv(3, model=statistical_model()).reset()
    for solver in ("osqp", "cvxpy"):
        ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC, solver=solver, horizon=20)
        ctrl.act([2.0, 2.0], 0, 0)
        ctrl.act_batch(np.ones((3, 2)), np.arange(3), 1)
        ctrl.predict(np.array([2, 2, 1, 0, 0, 0], dtype=np.float32))  # mode part one-hot
    synthesize_gains(model)
    verify_mean_square_bound(model, PAPER_K, nu_bound=1.0)
    tightening(model, 0.9, "joint")
    row_satisfaction_probability(model, np.zeros(2), 0, 1)
    MJLSLQRController(model).act([1.0, 1.0], 0, 0)
    LinearFeedbackController(model, PAPER_K).act_batch(np.ones((2, 2)), np.zeros(2, int), 0)
    rollout(model, RecedingHorizonController(model, PAPER_K, **PAPER_RHC), 8, 20, seed=0)
    model.sample_noise(np.random.default_rng(0), (3,))
    after = np.random.get_state()  # noqa: NPY002
    assert after[0] == np_state[0] and np.array_equal(after[1], np_state[1])
    assert after[2:] == np_state[2:]
    assert random.getstate() == py_state


#: numpy.random names that do not use the global generator.
ALLOWED = {"default_rng", "Generator", "SeedSequence", "BitGenerator", "PCG64", "PCG64DXSM",
           "Philox", "SFC64"}  # fmt: skip


def global_rng_uses(path: Path) -> list[str]:
    """Every use of numpy's legacy global generator or of Python's ``random`` module in a file:
    ``np.random.seed(...)``, ``np.random.normal(...)``, ``RandomState``, ``import random``, ..."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    random_names, found = _random_imports(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            owner = ast.unparse(node.value)
            if owner in random_names and node.attr not in ALLOWED:
                found.append(f"line {node.lineno}: {owner}.{node.attr}")
    return found


def _random_imports(tree: ast.AST) -> tuple[set[str], list[str]]:
    """The names ``numpy.random`` goes by in a module, and its imports of the global generators."""
    numpy_names, random_names, found = {"numpy"}, {"numpy.random"}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "numpy":
                    numpy_names.add(alias.asname or "numpy")
                elif alias.name == "numpy.random":
                    random_names.add(alias.asname or "numpy.random")
                elif alias.name == "random":
                    found.append(f"line {node.lineno}: import random")
        elif isinstance(node, ast.ImportFrom):
            names = {a.name for a in node.names}
            if node.module == "random":
                found.append(f"line {node.lineno}: from random import ...")
            elif node.module == "numpy" and "random" in names:
                random_names.update(a.asname or a.name for a in node.names if a.name == "random")
            elif node.module == "numpy.random" and names - ALLOWED:
                found.append(f"line {node.lineno}: from numpy.random import {sorted(names)}")
    return random_names | {f"{name}.random" for name in numpy_names}, found


def test_no_global_random_generator_in_the_sources():
    files = sorted(
        p for d in ("sdjls_gym", "controllers", "benchmarks") for p in (ROOT / d).rglob("*.py")
    )
    assert len(files) >= 10
    uses = {str(p.relative_to(ROOT)): global_rng_uses(p) for p in files}
    # the one exception: rliable draws from the legacy generator, so aggregate.py seeds it for
    # the call and restores the caller's state (test_suite_benchmark.py checks both)
    scoped = [f"np.random.{name}" for name in ("get_state", "seed", "set_state")]
    uses["benchmarks/core/aggregate.py"] = [
        u for u in uses["benchmarks/core/aggregate.py"] if not any(u.endswith(s) for s in scoped)
    ]
    assert {p: u for p, u in uses.items() if u} == {}


def test_the_source_scan_finds_legacy_calls(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "import random\nimport numpy as np\nimport numpy.random as npr\n"
        "from numpy.random import rand, default_rng\n"
        "np.random.seed(0)\nx = np.random.normal(size=3)\ny = npr.uniform()\n"
        "r = np.random.RandomState(1)\ng = np.random.default_rng(0)\n"
    )
    found = global_rng_uses(bad)
    for text in ("import random", "['default_rng', 'rand']", "np.random.seed", "np.random.normal",
                 "npr.uniform", "np.random.RandomState"):  # fmt: skip
        assert any(text in f for f in found), (text, found)
    assert not any("default_rng" in f and "import" not in f for f in found)
