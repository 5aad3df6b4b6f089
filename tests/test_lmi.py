"""Tests of controllers/lmi.py: Proposition 2 synthesis and the Proposition 1 certificate."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import UNSHOWN, raises_naming

from controllers import (
    GainSynthesisResult,
    MeanSquareCertificate,
    check_proposition2,
    second_moment_spectral_radius,
    synthesize_gains,
    verify_mean_square_bound,
)
from sdjls_gym import SDJLSModel
from sdjls_gym.errors import LMIError, LMIInfeasibleError, LMISolverError
from sdjls_gym.systems.macro import PAPER_K, PAPER_X, PAPER_Y, macro

#: Half a unit in the 4th decimal: the rounding of the printed X and Y of section 6.
HALF_ULP = 0.5e-4

#: Two-sided 99.9% normal quantile, z_{0.9995}.
Z_999 = 3.2905


@pytest.fixture(scope="module")
def model() -> SDJLSModel:
    return macro()


@pytest.fixture(scope="module")
def synthesized(model: SDJLSModel) -> GainSynthesisResult:
    return synthesize_gains(model)


@pytest.fixture(scope="module")
def paper_cert(model: SDJLSModel) -> MeanSquareCertificate:
    return verify_mean_square_bound(model, PAPER_K)


def one_mode(A, B) -> SDJLSModel:
    """A system with a single mode (an LTI system), so P_in = P_out = [[1]]."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n, m = B.shape
    return SDJLSModel(
        A=A[None],
        B=B,
        P_in=[[1.0]],
        P_out=[[1.0]],
        G=np.eye(n)[:1],
        H0=[1.0],
        Q=np.eye(n),
        R=np.eye(m),
        x0=np.ones(n),
    )


# ------------------------------------------------------------------------- the paper's numbers
def test_paper_X_Y_satisfy_proposition2(model: SDJLSModel) -> None:
    assert check_proposition2(model, PAPER_X, PAPER_Y) < 0


def test_paper_K_is_Y_times_inverse_X_up_to_rounding() -> None:
    """K_i = Y_i X_i^{-1} (eq. controller:stateFB) reproduces the printed K up to rounding.

    X and Y are printed to 4 decimals, so the printed values are only within 0.5e-4 of the ones
    that gave the printed K. Literal 4-decimal agreement is impossible: e.g. the slump mode has
    X_3(2,2) = 0.1044, and 0.5429 / 0.1044 = 5.2002, while the printed K_3(2) is 5.2; a change of
    0.5e-4 in 0.1044 alone moves the quotient by about 2.5e-3. Since X is diagonal,
    K_i[0, c] = Y_i[0, c] / X_i[c, c] and the worst case over the rounding box is
    (|Y| + h) / (X - h) - |Y| / X = h / X + |Y| h / X^2 + O(h^2).
    """
    assert np.all(PAPER_X == np.einsum("iab,ab->iab", PAPER_X, np.eye(2)))  # diagonal
    K = PAPER_Y @ np.linalg.inv(PAPER_X)
    X_diag = np.diagonal(PAPER_X, axis1=1, axis2=2)[:, None, :]  # (3, 1, 2)
    tol = (np.abs(PAPER_Y) + HALF_ULP) / (X_diag - HALF_ULP) - np.abs(PAPER_Y) / X_diag
    first_order = HALF_ULP / X_diag + np.abs(PAPER_Y) * HALF_ULP / X_diag**2
    assert np.allclose(tol, first_order, rtol=1e-2)
    assert np.all(np.abs(K - PAPER_K) <= tol)
    assert np.max(tol) < 5e-3
    # ... but not to 4 decimals:
    assert np.max(np.abs(K - PAPER_K)) > 0.5e-4
    assert K[2, 0, 1] == pytest.approx(5.2002, abs=1e-4)


def test_paper_K_makes_every_mode_nilpotent(model: SDJLSModel) -> None:
    """Atilde_i = A_i + B K_i = [[0, 1], [0, 0]] for every mode: a deadbeat design."""
    At = model.A + model.B @ PAPER_K
    assert np.allclose(At, np.array([[0.0, 1.0], [0.0, 0.0]]), atol=1e-12)


# ------------------------------------------------------------------------- synthesis
@pytest.mark.parametrize("objective", ["feasibility", "max_margin"])
def test_synthesize_gains_on_macro(model: SDJLSModel, objective: str) -> None:
    res = synthesize_gains(model, objective=objective)
    assert res.K.shape == (3, 1, 2) and res.X.shape == (3, 2, 2) and res.Y.shape == (3, 1, 2)
    assert res.status == "optimal"
    assert res.margin < 0
    # its own verification, redone here from the returned arrays
    assert np.allclose(res.K, res.Y @ np.linalg.inv(res.X))
    assert np.allclose(res.P @ res.X, np.eye(2))
    assert np.all(np.linalg.eigvalsh(res.X)[:, 0] > 0)
    assert check_proposition2(model, res.X, res.Y) < 0
    At = model.A + model.B @ res.K
    for Pi in (model.P_in, model.P_out):
        L = np.einsum("ij,jab->iab", Pi, res.P)
        E = At.transpose(0, 2, 1) @ L @ At - res.P  # eqs. (LMI1), (LMI2)
        assert np.max(np.linalg.eigvalsh((E + E.transpose(0, 2, 1)) / 2)) <= res.margin + 1e-9
    cert = verify_mean_square_bound(model, res.K)
    assert np.all(cert.margins < 0)
    assert second_moment_spectral_radius(model, res.K) < 1


def test_synthesized_gains_result_is_read_only(synthesized: GainSynthesisResult) -> None:
    with pytest.raises(ValueError):
        synthesized.K[0, 0, 0] = 1.0


def test_one_mode_system_is_stabilized() -> None:
    sys = one_mode([[1.2, 1.0], [0.0, 0.9]], [[0.0], [1.0]])
    res = synthesize_gains(sys)
    At = sys.A[0] + sys.B[0] @ res.K[0]
    assert np.max(np.abs(np.linalg.eigvals(At))) < 1
    assert np.max(np.abs(np.linalg.eigvals(sys.A[0]))) > 1  # it needed stabilizing


def test_unstabilizable_system_raises_infeasible() -> None:
    sys = one_mode([[2.0, 0.0], [0.0, 0.5]], [[0.0], [0.0]])  # B = 0, eigenvalue 2
    # README: the message names the solver and its status
    with raises_naming(LMIInfeasibleError, ("solver", "status"), "infeasible") as info:
        synthesize_gains(sys)
    assert isinstance(info.value, ValueError) and isinstance(info.value, LMIError)
    with pytest.raises(LMIInfeasibleError):
        synthesize_gains(sys, objective="max_margin")


def test_inaccurate_solver_answer_is_never_returned() -> None:
    """SCS may call this infeasible problem 'optimal'; the float64 check must then refuse it."""
    sys = one_mode([[2.0, 0.0], [0.0, 0.5]], [[0.0], [0.0]])
    with pytest.raises(LMIError):
        synthesize_gains(sys, solver="SCS")


def test_exception_hierarchy() -> None:
    assert issubclass(LMIInfeasibleError, ValueError)
    assert issubclass(LMIInfeasibleError, RuntimeError)
    assert issubclass(LMISolverError, LMIError) and not issubclass(LMISolverError, ValueError)


# ------------------------------------------------------------------------- certificate
def test_paper_K_certificate_constants(paper_cert: MeanSquareCertificate) -> None:
    """For the deadbeat PAPER_K the certificate problem has a unique, hand-computable solution.

    With Atilde_i = J = [[0, 1], [0, 0]], J' L_i J = diag(0, L_i[0, 0]). Minimizing t subject to
    -E_i^j >= I and I <= P_i <= t I forces P_i = diag(1, 2): P_i[0, 0] >= 1 gives L_i[0, 0] >= 1
    and P_i[1, 1] >= 1 + L_i[0, 0] >= 2. Then -E_i^j = I (mu = 1), L_i = M_i = diag(1, 2)
    (alpha1 = alpha2 = 2), beta = 1 * 2 * ||J|| = 2, kappa = mu / 2, c1 = 1, c2 = 2,
    q = 1 - 0.5 / 2 = 0.75, beta1 = 2, beta2 = n alpha2 / (c1 (1 - q)) = 16.
    """
    c = paper_cert
    assert np.allclose(c.P, np.array([np.diag([1.0, 2.0])] * 3), atol=1e-5)
    expected = dict(mu=1, alpha1=2, alpha2=2, beta=2, kappa=0.5, c1=1, c2=2, q=0.75)
    expected.update(beta1=2, beta2=16, delta=0, noise_term=4, spectral_radius=0)
    for name, value in expected.items():
        assert getattr(c, name) == pytest.approx(value, abs=1e-5), name
    assert c.margins.shape == (3, 2) and np.all(c.margins < 0)


def random_system(seed: int = 1) -> SDJLSModel:
    """Three modes, n = 2, m = 1, p = 3, random stable A, E and W not identity."""
    rng = np.random.default_rng(seed)
    A = 0.6 * rng.standard_normal((3, 2, 2))
    P_in, P_out = rng.random((3, 3)), rng.random((3, 3))
    P_in /= P_in.sum(axis=1, keepdims=True)
    P_out /= P_out.sum(axis=1, keepdims=True)
    C = rng.standard_normal((3, 3))
    return SDJLSModel(
        A=A, B=[[0.0], [1.0]], P_in=P_in, P_out=P_out, G=[[1.0, 0.0]], H0=[1.0], Q=np.eye(2),
        R=[[1.0]], x0=[0.0, 0.0], E=rng.standard_normal((3, 2, 3)), W=C @ C.T + np.eye(3),
    )  # fmt: skip


#: Small gains for :func:`random_system` (mean-square stable with them).
RANDOM_K = np.array([[[0.1, -0.2]], [[0.0, 0.1]], [[-0.1, 0.0]]])


@pytest.mark.parametrize("case", ["macro", "random"])
def test_certificate_constants_follow_appendix_A(
    model: SDJLSModel, synthesized: GainSynthesisResult, case: str
) -> None:
    """Recompute the Appendix-A constants from the certificate's P, with loops."""
    if case == "random":
        model = random_system()
        K = RANDOM_K
    else:
        K = synthesized.K
    c = verify_mean_square_bound(model, K, nu_bound=2.0)
    N = model.N
    At = [model.A[i] + model.B[i] @ K[i] for i in range(N)]
    Ls = [sum(model.P_in[i, j] * c.P[j] for j in range(N)) for i in range(N)]
    Ms = [sum(model.P_out[i, j] * c.P[j] for j in range(N)) for i in range(N)]
    eigs = lambda S: np.linalg.eigvalsh((S + S.T) / 2)  # noqa: E731
    E = [[At[i].T @ S @ At[i] - c.P[i] for S in (Ls[i], Ms[i])] for i in range(N)]
    assert np.allclose(c.margins, [[eigs(e)[-1] for e in row] for row in E], atol=1e-9)
    mu = min(eigs(-e)[0] for row in E for e in row)
    BLB = [model.B[i].T @ S @ model.B[i] for i in range(N) for S in (Ls[i], Ms[i])]
    alpha1 = max(eigs(S)[-1] for S in BLB)
    alpha2 = max(eigs(S)[-1] for i in range(N) for S in (Ls[i], Ms[i]))
    norm_B = max(np.linalg.norm(b, 2) for b in model.B)
    beta = norm_B * alpha2 * max(np.linalg.norm(a, 2) for a in At)
    c1 = min(eigs(p)[0] for p in c.P)
    c2 = max(eigs(p)[-1] for p in c.P)
    kappa = mu / 2
    q = 1 - (mu - kappa) / c2
    delta = 1 * 2.0**2  # m * nu_bound^2
    noise = alpha2 * max(np.trace(e @ model.W @ e.T) for e in model.E)
    beta2 = (noise + delta * (alpha1 + beta**2 / kappa)) / (c1 * (1 - q))
    got = [c.mu, c.alpha1, c.alpha2, c.beta, c.c1, c.c2, c.q, c.delta, c.beta1, c.beta2]
    want = [mu, alpha1, alpha2, beta, c1, c2, q, delta, c2 / c1, beta2]
    assert np.allclose(got, want, rtol=1e-9)
    assert c.noise_term == pytest.approx(noise, rel=1e-9)
    assert 0 < c.q < 1 and c.beta1 >= 1 and c.kappa < c.mu


def test_noise_term_uses_E_W_E_transpose(model: SDJLSModel) -> None:
    """With E = 2 I the noise covariance is 4 I: the noise term is 4 times the paper's n alpha2."""
    scaled = SDJLSModel.from_dict({**model.to_dict(), "E": (2.0 * np.eye(2)).tolist()})
    c0 = verify_mean_square_bound(model, PAPER_K)
    c1 = verify_mean_square_bound(scaled, PAPER_K)
    assert c1.noise_term == pytest.approx(4 * c0.noise_term)
    assert c1.noise_term == pytest.approx(c1.alpha2 * 4 * 2)


def test_kappa_choice(model: SDJLSModel, paper_cert: MeanSquareCertificate) -> None:
    c = verify_mean_square_bound(model, PAPER_K, kappa=0.1)
    assert c.kappa == 0.1
    assert c.beta2 < paper_cert.beta2  # delta = 0: a smaller kappa gives a smaller beta2
    with raises_naming(ValueError, "kappa", 5.0):  # above mu = 1
        verify_mean_square_bound(model, PAPER_K, kappa=5.0)
    with raises_naming(ValueError, "kappa", -0.1):
        verify_mean_square_bound(model, PAPER_K, kappa=-0.1)


def test_bad_gains_cannot_be_certified(model: SDJLSModel) -> None:
    K0 = np.zeros((3, 1, 2))  # open loop: every mode is unstable
    # the gains are named, not shown (they are an N x m x n array)
    with raises_naming(LMIInfeasibleError, "K", UNSHOWN):
        verify_mean_square_bound(model, K0)
    assert second_moment_spectral_radius(model, K0) > 1


def test_check_proposition2_closed_form() -> None:
    """Two scalar modes, B = 0, X_i = 1, Y_i = 0: the matrix of eq. (lmi:stabiization1) is
    [[-I, v], [v', -1]] with v = a_i (sqrt(lambda_i0), sqrt(lambda_i1)), whose largest eigenvalue
    is -1 + ||v|| = -1 + |a_i| (the rows of lambda sum to 1); likewise for mu."""
    a = np.array([0.5, -0.8])
    sys = SDJLSModel(
        A=a[:, None, None],
        B=[[0.0]],
        P_in=[[0.7, 0.3], [0.4, 0.6]],
        P_out=[[0.1, 0.9], [0.5, 0.5]],
        G=[[1.0]],
        H0=[1.0],
        Q=[[1.0]],
        R=[[1.0]],
        x0=[0.0],
    )
    got = check_proposition2(sys, np.ones((2, 1, 1)), np.zeros((2, 1, 1)))
    assert got == pytest.approx(-1 + 0.8, abs=1e-12)


def test_spectral_radius_matches_power_iteration() -> None:
    """Iterate Z_j <- sum_i Pmax[i, j] Atilde_i Z_i Atilde_i' directly; its growth rate is rho."""
    sys = random_system()
    A, P_in, P_out = sys.A, sys.P_in, sys.P_out
    K = np.zeros((3, 1, 2))
    Pmax = np.maximum(P_in, P_out)
    Z = [np.eye(2)] * 3
    for _ in range(400):
        Z_new = [sum(Pmax[i, j] * A[i] @ Z[i] @ A[i].T for i in range(3)) for j in range(3)]
        growth = sum(np.trace(z) for z in Z_new) / sum(np.trace(z) for z in Z)
        Z = [z / sum(np.trace(z) for z in Z_new) for z in Z_new]
    assert second_moment_spectral_radius(sys, K) == pytest.approx(growth, rel=1e-8)


def test_spectral_radius(model: SDJLSModel, synthesized: GainSynthesisResult) -> None:
    assert second_moment_spectral_radius(model, PAPER_K) < 1e-6  # nilpotent closed loop
    assert second_moment_spectral_radius(model, synthesized.K) < 1
    # one mode, K = 0: the operator is kron(A, A), spectral radius rho(A)^2
    sys = one_mode([[0.5, 1.0], [0.0, -0.8]], [[0.0], [1.0]])
    assert second_moment_spectral_radius(sys, np.zeros((1, 1, 2))) == pytest.approx(0.64)


# ------------------------------------------------------------------------- Monte Carlo
def simulate_second_moment(
    model: SDJLSModel, K: np.ndarray, steps: int, n_traj: int, seed: int, nu=None
) -> tuple[np.ndarray, np.ndarray]:
    """Batched simulation of u = K_theta x + nu(x); mean and std of ||x_k||^2, k = 0..steps."""
    rng = np.random.default_rng(seed)
    x = np.broadcast_to(model.x0, (n_traj, model.n)).copy()
    mode = np.full(n_traj, model.sample_mode0(rng), dtype=np.int64)
    sq = [np.sum(x**2, axis=1)]
    for k in range(steps):
        u = np.einsum("bij,bj->bi", K[mode], x)
        if nu is not None:
            u = u + nu(x)
        w = model.sample_noise(rng, (n_traj,))
        x, mode = model.step(x, mode, u, k, w, rng.random(n_traj))
        sq.append(np.sum(x**2, axis=1))
    sq = np.array(sq)
    return sq.mean(axis=1), sq.std(axis=1, ddof=1)


@pytest.mark.parametrize("which", ["paper", "synthesized", "random"])
def test_certificate_bounds_monte_carlo_second_moment(
    model: SDJLSModel, synthesized: GainSynthesisResult, which: str
) -> None:
    """E||x_k||^2 <= beta1 ||x0||^2 q^k + beta2 (eq. eq:msqs) with nu = 0, checked by Monte Carlo.

    20000 seeded trajectories of 20 steps. At every k, the upper end of a 99.9% (two-sided,
    normal) confidence interval of the mean of ||x_k||^2 must lie below the bound. A bound that
    forgot the noise term (beta2 = 0) would fail from k = 2 on, where E||x_k||^2 = 3 for PAPER_K.
    """
    K = {"paper": PAPER_K, "synthesized": synthesized.K, "random": RANDOM_K}[which]
    if which == "random":  # E and W are not the identity: exercises the general noise term
        model = random_system()
    cert = verify_mean_square_bound(model, K)
    mean, std = simulate_second_moment(model, K, steps=20, n_traj=20_000, seed=12345)
    upper = mean + Z_999 * std / np.sqrt(20_000)
    bound = cert.bound(np.arange(21), model.x0)
    assert np.all(upper < bound), (upper, bound)
    if which == "paper":  # deadbeat: x_k = J w_{k-2} + w_{k-1} for k >= 2, E||x_k||^2 = 3
        assert np.allclose(mean[2:], 3.0, atol=0.15)
        assert np.all(bound[2:] > 16.0)


def test_certificate_with_bounded_offsets_monte_carlo(model: SDJLSModel) -> None:
    """With |nu_k| <= 1 (here nu_k = -sign(x_k(2)), F_k-measurable), delta = 1 and the bound
    still holds for the upper end of a 99.9% confidence interval, 5000 trajectories."""
    cert = verify_mean_square_bound(model, PAPER_K, nu_bound=1.0)
    assert cert.delta == 1.0
    mean, std = simulate_second_moment(
        model, PAPER_K, 20, 5000, seed=7, nu=lambda x: -np.sign(x[:, 1:2])
    )
    upper = mean + Z_999 * std / np.sqrt(5000)
    assert np.all(upper < cert.bound(np.arange(21), model.x0))


def test_bound_method(paper_cert: MeanSquareCertificate) -> None:
    x0 = np.array([2.0, 2.0])
    assert paper_cert.bound(0, x0) == pytest.approx(2 * 8 + 16, rel=1e-6)
    assert isinstance(paper_cert.bound(3, x0), float)
    ks = np.arange(5)
    assert np.allclose(paper_cert.bound(ks, x0), 16 * 0.75**ks + 16, rtol=1e-6)
    with raises_naming(ValueError, "k", -1):
        paper_cert.bound(-1, x0)
    with raises_naming(ValueError, "x0", (3,)):
        paper_cert.bound(1, np.ones(3))


# ------------------------------------------------------------------------- bad inputs
def test_K_wrong_shape(model: SDJLSModel) -> None:
    with raises_naming(ValueError, "K", (3, 2)):
        verify_mean_square_bound(model, np.zeros((3, 2)))
    with raises_naming(ValueError, "K", (2, 1, 2)):
        second_moment_spectral_radius(model, np.zeros((2, 1, 2)))


def test_K_not_finite(model: SDJLSModel) -> None:
    K = PAPER_K.copy()
    K[1, 0, 1] = np.nan
    with raises_naming(ValueError, "K", np.nan):
        verify_mean_square_bound(model, K)


@pytest.mark.parametrize(
    ("eps", "error"),
    [(0.0, ValueError), (-1e-6, ValueError), (float("nan"), ValueError),
     (float("inf"), ValueError), ("small", TypeError)],
)  # fmt: skip
def test_bad_eps(model: SDJLSModel, eps, error) -> None:
    with raises_naming(error, "eps", eps):
        synthesize_gains(model, eps=eps)
    with raises_naming(error, "eps", eps):
        verify_mean_square_bound(model, PAPER_K, eps=eps)


def test_bad_objective(model: SDJLSModel) -> None:
    with raises_naming(ValueError, "objective", "fastest"):
        synthesize_gains(model, objective="fastest")


def test_bad_solver(model: SDJLSModel) -> None:
    with raises_naming(ValueError, "solver", "NOPE"):
        synthesize_gains(model, solver="NOPE")


def test_not_a_model() -> None:
    with raises_naming(TypeError, "model", {}):
        synthesize_gains({})
    with raises_naming(TypeError, "model", None):
        verify_mean_square_bound(None, PAPER_K)


def test_X_Y_wrong_shape(model: SDJLSModel) -> None:
    with raises_naming(ValueError, "X", (2, 2, 2)):
        check_proposition2(model, PAPER_X[:2], PAPER_Y)
    with raises_naming(ValueError, "Y", (3, 2)):
        check_proposition2(model, PAPER_X, PAPER_Y[:, 0, :])
    X = PAPER_X.copy()
    X[0, 0, 1] = 0.3
    with raises_naming(ValueError, "X[0]", 0.3):  # shown by its asymmetry max |X - X'|
        check_proposition2(model, X, PAPER_Y)


def test_nu_bound_and_delta(model: SDJLSModel) -> None:
    with raises_naming(ValueError, ("nu_bound", "delta"), 1.0):  # both given
        verify_mean_square_bound(model, PAPER_K, nu_bound=1.0, delta=1.0)
    with raises_naming(ValueError, "nu_bound", -1.0):
        verify_mean_square_bound(model, PAPER_K, nu_bound=-1.0)
    with raises_naming(ValueError, "delta", float("inf")):
        verify_mean_square_bound(model, PAPER_K, delta=float("inf"))
    c = verify_mean_square_bound(model, PAPER_K, delta=3.0)
    assert c.delta == 3.0 and c.beta2 > 16.0
