"""Proposition 1: a mean-square certificate of given gains (section 3 and Appendix A).

* :func:`verify_mean_square_bound` finds ``P_i`` satisfying (LMI1), (LMI2) and computes the
  constants of Appendix A, so that ``E||x_k||^2 <= beta1 ||x0||^2 q^k + beta2`` (eq. eq:msqs).
* :func:`second_moment_spectral_radius` is an independent sufficient mean-square test.

Modes are numbered ``0 .. N-1``. The paper uses ``mu`` both for the transition matrix used outside
``C1`` (here ``model.P_out``) and for the decay margin of Appendix A (here
:attr:`MeanSquareCertificate.mu`).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import cvxpy as cp
import numpy as np

from sdjls_gym import SDJLSModel
from sdjls_gym.errors import LMIInfeasibleError, LMISolverError
from sdjls_gym.validation import check_array, check_int_array, check_number

from .base import ReadOnlyArrays, check_model
from .lmi import (
    as_array,
    check_eps,
    check_scalar,
    checked_closed_loop,
    pick_solver,
    prop1_matrices,
    roundoff,
    solve,
    sym,
    weighted_sums,
)

__all__ = ["MeanSquareCertificate", "second_moment_spectral_radius", "verify_mean_square_bound"]


@dataclass(frozen=True, eq=False)
class MeanSquareCertificate(ReadOnlyArrays):
    """The constants of Appendix A for given gains: ``E||x_k||^2 <= beta1 ||x0||^2 q^k + beta2``.

    The bound (eq. eq:msqs) holds for the closed loop ``u_k = K_theta x_k + nu_k`` with any
    ``F_k``-measurable ``nu_k`` with ``E||nu_k||^2 <= delta``, whatever the region ``C1`` is,
    because (LMI1) and (LMI2) hold for both transition matrices.

    Attributes
    ----------
    K : (N, m, n)
        The certified gains.
    P : (N, n, n)
        Lyapunov matrices ``P_i > 0`` satisfying (LMI1) and (LMI2).
    margins : (N, 2)
        ``lambda_max(E_i^1)``, ``lambda_max(E_i^2)`` (all negative).
    mu : float
        ``min_{i, j} lambda_min(-E_i^j)``: the decay margin of Appendix A.
    alpha1 : float
        ``max_i max(lambda_max(B_i' L_i B_i), lambda_max(B_i' M_i B_i))``.
    alpha2 : float
        ``max_i max(lambda_max(L_i), lambda_max(M_i))``.
    beta : float
        ``max_i ||B_i|| * alpha2 * max_i ||Atilde_i||`` (spectral norms).
    kappa : float
        The Young's-inequality parameter, ``0 < kappa < mu``.
    c1, c2 : float
        ``min_i lambda_min(P_i)`` and ``max_i lambda_max(P_i)``.
    q : float
        ``1 - (mu - kappa) / c2``, in ``(0, 1)``.
    beta1 : float
        ``c2 / c1``.
    beta2 : float
        ``(noise_term + delta (alpha1 + beta^2 / kappa)) / (c1 (1 - q))``.
    delta : float
        The bound on ``E||nu_k||^2`` used.
    noise_term : float
        ``alpha2 * max_i trace(E_i W E_i')``; the paper's ``n alpha2`` when ``E_i = I``, ``W = I``.
    spectral_radius : float
        :func:`second_moment_spectral_radius` of the gains (an independent check, < 1 is good).
    status : str
        The cvxpy status of the problem that found ``P``.
    solver : str
        Name of the solver used.
    """

    K: np.ndarray
    P: np.ndarray
    margins: np.ndarray
    mu: float
    alpha1: float
    alpha2: float
    beta: float
    kappa: float
    c1: float
    c2: float
    q: float
    beta1: float
    beta2: float
    delta: float
    noise_term: float
    spectral_radius: float
    status: str
    solver: str

    ARRAYS = ("K", "P", "margins")

    def bound(self, k: int | np.ndarray, x0: np.ndarray) -> float | np.ndarray:
        """The bound ``beta1 ||x0||^2 q^k + beta2`` on ``E||x_k||^2``, eq. (eq:msqs).

        Parameters
        ----------
        k : int or (...) int array
            Time steps, ``k >= 0``.
        x0 : (n,)
            Initial state.

        Returns
        -------
        float, or (...) array when ``k`` is an array.

        Raises
        ------
        TypeError
            If ``k`` is not an int or an int array (a float, a bool), or ``x0`` has entries that
            are not numbers.
        ValueError
            If ``k`` is negative, or ``x0`` has the wrong shape or a non-finite entry.
        """
        n = self.P.shape[1]
        x0 = check_array("x0", x0, shape=(n,), what="the initial state")
        k_arr = check_int_array("k", k, low=0)
        with np.errstate(over="ignore"):  # ||x0||^2 beyond float64 is an infinite bound
            out = self.beta1 * float(x0 @ x0) * self.q ** k_arr.astype(np.float64) + self.beta2
        return float(out) if k_arr.ndim == 0 else out


# ---------------------------------------------------------------------------------- Prop. 1
def second_moment_spectral_radius(model: SDJLSModel, K: np.ndarray) -> float:
    """A sufficient mean-square-stability test for the gains ``K``, independent of the LMIs.

    With ``Pmax = max(P_in, P_out)`` elementwise and ``Atilde_i = A_i + B_i K_i``, returns the
    spectral radius of the linear operator on ``(Z_0, ..., Z_{N-1})``::

        T(Z)_j = sum_i Pmax[i, j] Atilde_i Z_i Atilde_i'

    as a ``(N n^2, N n^2)`` matrix of Kronecker blocks ``Pmax[i, j] kron(Atilde_i, Atilde_i)``.

    Why ``rho(T) < 1`` bounds ``E||x_k||^2``: let ``Q_j(k) = E[x_k x_k' 1{theta_k = j}]``. With
    ``nu = 0`` and ``w_k`` independent of ``(x_k, theta_k)``::

        Q_j(k+1) = sum_i E[1{theta_k = i} pi_ij(x_k) (Atilde_i x_k x_k' Atilde_i' + E_i W E_i')]
                <= T(Q(k))_j + sum_i Pmax[i, j] E_i W E_i'

    in the positive-semidefinite order, because ``pi_ij(x) <= Pmax[i, j]`` for every ``x`` and
    the matrices multiplied are positive semidefinite. ``T`` maps PSD tuples to PSD tuples
    (monotone), so ``Q(k) <= T^k Q(0) + sum_l T^l c`` stays bounded when ``rho(T) < 1``, and
    ``E||x_k||^2 = sum_j trace Q_j(k)``. A bounded ``nu`` is absorbed by
    ``(a + b)(a + b)' <= (1 + s) a a' + (1 + 1/s) b b'`` with ``s`` small enough that
    ``(1 + s) rho(T) < 1``. The test is only sufficient: the rows of ``Pmax`` may sum to more
    than 1. It neither uses nor implies the LMIs of Proposition 1.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n)
        Feedback gains.

    Returns
    -------
    float
        ``rho(T)``; ``< 1`` certifies bounded second moments.

    Raises
    ------
    TypeError
        If ``model`` is not an :class:`SDJLSModel`.
    ValueError
        If ``K`` has the wrong shape or a non-finite entry, or the products of the closed loop
        ``A_i + B_i K_i`` overflow float64.
    """
    model = check_model(model)
    N, n, m = model.N, model.n, model.m
    K = as_array("K", K, (N, m, n), "one m x n gain K_i per mode")
    At = checked_closed_loop(model, K)
    return _radius(At, np.maximum(model.P_in, model.P_out))


def _operator(At: np.ndarray, Pi: np.ndarray) -> np.ndarray:
    """``T(Z)_j = sum_i Pi[i, j] At_i Z_i At_i'`` as a matrix of Kronecker blocks
    ``Pi[i, j] kron(At_i, At_i)``."""
    N, n = At.shape[0], At.shape[1]
    d = n * n
    T = np.zeros((N * d, N * d))
    for i in range(N):
        kron = np.kron(At[i], At[i])  # vec(A Z A') = kron(A, A) vec(Z)
        for j in range(N):
            T[j * d : (j + 1) * d, i * d : (i + 1) * d] = Pi[i, j] * kron
    return T


def _radius(At: np.ndarray, Pi: np.ndarray) -> float:
    """The spectral radius of :func:`_operator`."""
    return float(np.max(np.abs(np.linalg.eigvals(_operator(At, Pi)))))


#: Largest size N n^2 of the operator whose spectral radius is checked before the LMIs are
#: solved (an eigenvalue problem of that size, cheap next to the LMIs).
_PRECHECK_SIZE = 1024
#: Margin above 1 of that spectral radius, relative to the operator's norm (a bound far above
#: the error of a computed eigenvalue, even a defective one), that proves the LMIs infeasible.
_PRECHECK_MARGIN = 1e-6


def _refuse_unstable(model: SDJLSModel, At: np.ndarray) -> None:
    """Raise :class:`LMIInfeasibleError` when (LMI1) or (LMI2) alone is clearly infeasible.

    For one transition matrix ``Pi``, ``P_i > 0`` with ``At_i' (sum_j Pi_ij P_j) At_i < P_i``
    exists if and only if the spectral radius of ``T(Z)_j = sum_i Pi_ij At_i Z_i At_i'`` is
    below 1 (mean-square stability of the Markov jump linear system; Costa, Fragoso and
    Marques 2005, Theorem 3.9). A radius clearly above 1 for ``P_in`` or ``P_out`` settles it
    without a solver (whose answer on such data is often a failure, not "infeasible").
    """
    if model.N * model.n**2 > _PRECHECK_SIZE:
        return
    for name, Pi, lmi in (("P_in", model.P_in, "LMI1"), ("P_out", model.P_out, "LMI2")):
        T = _operator(At, Pi)
        radius = float(np.max(np.abs(np.linalg.eigvals(T))))
        if radius > 1.0 + _PRECHECK_MARGIN * max(1.0, float(np.linalg.norm(T, 1))):
            raise LMIInfeasibleError(
                "Proposition 1 certificate (eqs. LMI1, LMI2): the gains K could not be "
                f"certified (no solver run): with the transition matrix model.{name}, "
                f"the closed loop A_i + B_i K_i has second-moment spectral radius {radius:.6g} "
                f">= 1 (not mean-square stable), so no P_i > 0 satisfies ({lmi})"
            )


def verify_mean_square_bound(
    model: SDJLSModel,
    K: np.ndarray,
    *,
    nu_bound: float | None = None,
    delta: float | None = None,
    kappa: float | None = None,
    solver: str | None = None,
    eps: float = 1e-6,
) -> MeanSquareCertificate:
    """Certify gains with Proposition 1 and compute the constants of Appendix A.

    Finds ``P_i > 0`` with (``Atilde_i = A_i + B_i K_i``)::

        Atilde_i' (sum_j lambda_ij P_j) Atilde_i - P_i = E_i^1 << -I     eq. (LMI1)
        Atilde_i' (sum_j mu_ij P_j) Atilde_i - P_i     = E_i^2 << -I     eq. (LMI2)
        I << P_i << t I,   minimize t.

    (LMI1), (LMI2) are linear and homogeneous in ``P``, so asking for the margin ``-I`` instead
    of any ``-eps I`` loses no generality; it fixes the scale (``mu >= 1``, ``c1 >= 1``), and
    minimizing ``t = c2`` then keeps ``c2 / mu`` small, which is what ``q`` and ``beta2``
    depend on. From the ``P`` found, with ``L_i = sum_j lambda_ij P_j``, ``M_i = sum_j mu_ij P_j``:

    * ``mu = min_{i,j} lambda_min(-E_i^j)``, ``c1 = min_i lambda_min(P_i)``,
      ``c2 = max_i lambda_max(P_i)``;
    * ``alpha1 = max_i max(lambda_max(B_i' L_i B_i), lambda_max(B_i' M_i B_i))``;
    * ``alpha2 = max_i max(lambda_max(L_i), lambda_max(M_i))``;
    * ``beta = max_i ||B_i|| * alpha2 * max_i ||Atilde_i||``; ``0 < kappa < mu``;
    * ``q = 1 - (mu - kappa) / c2``; ``beta1 = c2 / c1``;
    * ``beta2 = (noise_term + delta (alpha1 + beta^2 / kappa)) / (c1 (1 - q))`` with
      ``noise_term = alpha2 * max_i trace(E_i W E_i')``,

    and ``E||x_k||^2 <= beta1 ||x_0||^2 q^k + beta2`` for every ``k`` (eq. eq:msqs).

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n)
        Feedback gains to certify.
    nu_bound : float, optional
        A bound on the offsets: ``|nu_k| <= nu_bound`` (Euclidean norm, or every entry). Gives
        ``delta = m * nu_bound**2``, which bounds ``E||nu_k||^2`` in both readings.
    delta : float, optional
        A bound on ``E||nu_k||^2`` given directly (not together with ``nu_bound``). If neither
        is given, ``delta = 0``: the pre-stabilized system alone, ``nu = 0``.
    kappa : float, optional
        Young's-inequality parameter, ``0 < kappa < mu``; default ``mu / 2``. With
        ``delta = 0`` a smaller ``kappa`` gives a smaller ``beta2`` (the ``beta^2 / kappa`` term
        is multiplied by ``delta``); pass one explicitly for a tighter bound.
    solver : str, optional
        A cvxpy solver name; default Clarabel if installed, else SCS.
    eps : float
        Float64 acceptance threshold, > 0: the ``P`` found is accepted only if ``mu >= eps``
        (the normalization aims at ``mu >= 1``) and every ``P_i`` is positive definite.

    Returns
    -------
    MeanSquareCertificate

    Raises
    ------
    TypeError, ValueError
        As :func:`second_moment_spectral_radius` for ``model`` and ``K``.
    ValueError
        If ``nu_bound``, ``delta``, ``kappa``, ``eps`` or ``solver`` is invalid (``nu_bound``
        at most ``sqrt(1.8e308 / m)``, so that ``delta`` is finite); or if ``beta2`` overflows
        float64 (``delta`` too large or ``kappa`` too small).
    LMIInfeasibleError
        If no ``P`` satisfies (LMI1) and (LMI2) for these gains: they cannot be certified. Gains
        whose closed loop is clearly not mean-square stable under ``P_in`` or ``P_out`` alone
        are refused before the solver runs.
    LMISolverError
        On any other non-optimal status, or if the ``P`` found fails the float64 check.

    Notes
    -----
    Checking the derivation of Appendix A:

    * The appendix writes the closed loop as ``x_{k+1} = Atilde x_k + B nu_k + w_k`` (eq.
      sys:proof1), i.e. ``E_i = I`` and ``W = I``; its noise term ``n alpha2`` is
      ``alpha2 E[w'w]`` under that assumption. For general ``E_i``, ``W`` the correct term is
      ``E[w' E_i' Upsilon E_i w] = trace(Upsilon E_i W E_i') <= lambda_max(Upsilon)
      trace(E_i W E_i') <= alpha2 max_i trace(E_i W E_i')``, which is what is implemented; it
      equals ``n alpha2`` for ``E_i = I``, ``W = I`` (the paper's example).
      (``max_{i, Upsilon} trace(Upsilon E_i W E_i')`` over ``Upsilon in {L_i, M_i}`` would also
      be valid and tighter; it is not used, to stay with the paper's constant chain.)
    * The recursion's sums are written ``sum_{p=1}^{k-1}``; unrolling
      ``E V_{k+1} <= q E V_k + c`` gives ``sum_{p=0}^{k-1}``. The final bound with ``1/(1 - q)``
      is unaffected.
    * The paper uses ``mu`` both for the transition matrix outside ``C1`` and for the decay
      margin ``min lambda_min(-E_i^j)``; here they are ``model.P_out`` and ``mu``.
    * ``q in (0, 1)`` holds automatically: ``-E_i^j <= P_i`` gives ``mu <= c1 <= c2``.
    * The remaining steps (the decrease ``x'(Atilde' Upsilon Atilde - P) x <= -mu ||x||^2``
      because ``Upsilon`` is exactly ``L_i`` or ``M_i``, ``||Upsilon|| <= alpha2``, Young's
      inequality, ``V <= c2 ||x||^2`` and ``c1 ||x||^2 <= V``) check out as printed.
    """
    model = check_model(model)
    N, n, m = model.N, model.n, model.m
    K = as_array("K", K, (N, m, n), "one m x n gain K_i per mode")
    eps = check_eps(eps)
    delta_v = _offset_bound(nu_bound, delta, m)
    if kappa is not None:
        kappa_v = check_scalar("kappa", kappa, positive=True, what="a finite number in (0, mu)")
    solver = pick_solver(solver)

    At = checked_closed_loop(model, K)
    _refuse_unstable(model, At)
    what = "Proposition 1 certificate (eqs. LMI1, LMI2) for the given gains K"
    Pv, status = _solve_lmis(model, At, solver, what)
    c1, c2, margins, mu = _checked_margins(model, K, Pv, eps, f"{what}: solver {solver}", status)
    if kappa is None:
        kappa_v = mu / 2.0
    elif not kappa_v < mu:
        raise ValueError(f"kappa = {kappa!r}; expected 0 < kappa < mu = {mu:.6g}")

    alpha1, alpha2, beta, noise_term = _appendix_constants(model, At, Pv)
    q = 1.0 - (mu - kappa_v) / c2
    beta1 = c2 / c1
    given = {"nu_bound": nu_bound, "delta": delta, "kappa": kappa}
    beta2 = _beta2(noise_term, delta_v, alpha1, beta, kappa_v, c1, q, given)
    return MeanSquareCertificate(
        K=K,
        P=Pv,
        margins=margins,
        mu=mu,
        alpha1=alpha1,
        alpha2=alpha2,
        beta=beta,
        kappa=kappa_v,
        c1=c1,
        c2=c2,
        q=q,
        beta1=beta1,
        beta2=beta2,
        delta=delta_v,
        noise_term=noise_term,
        spectral_radius=second_moment_spectral_radius(model, K),
        status=status,
        solver=solver,
    )


def _beta2(
    noise_term: float,
    delta: float,
    alpha1: float,
    beta: float,
    kappa: float,
    c1: float,
    q: float,
    given: dict[str, float | None],
) -> float:
    """Appendix A's ``beta2 = (noise_term + delta (alpha1 + beta^2 / kappa)) / (c1 (1 - q))``;
    a ValueError naming the arguments ``given`` (by the caller) when it overflows float64."""
    # beta * beta, not beta**2 (a float's ** raises OverflowError); never 0 * inf
    offsets = delta * (alpha1 + beta * beta / kappa) if delta else 0.0
    # q rounds to 1 when mu - kappa is below c2's last digit: an infinite bound, named below
    beta2 = (noise_term + offsets) / (c1 * (1.0 - q)) if q < 1.0 else math.inf
    if not math.isfinite(beta2):
        named = [f"{name} = {value!r}" for name, value in given.items() if value is not None]
        raise ValueError(
            f"the bound beta2 = (noise_term + delta (alpha1 + beta^2 / kappa)) / (c1 (1 - q)) "
            f"overflows float64 with {', '.join(named) or 'the defaults'} (alpha1 = "
            f"{alpha1:.3g}, beta = {beta:.3g}, kappa = {kappa:.3g}); expected a smaller "
            "bound on nu (nu_bound, delta) or a larger kappa"
        )
    return beta2


def _offset_bound(nu_bound: float | None, delta: float | None, m: int) -> float:
    """``delta``, the bound on ``E||nu_k||^2``: ``m * nu_bound**2``, ``delta`` as given, or 0
    (at most one of the two given)."""
    if nu_bound is not None and delta is not None:
        raise ValueError(
            f"nu_bound = {nu_bound!r} and delta = {delta!r} were both given; give at most one "
            "(delta = m * nu_bound**2 is derived from nu_bound)"
        )
    if nu_bound is not None:
        limit = math.sqrt(sys.float_info.max / m)  # delta = m * nu_bound**2 finite
        nu_v = check_number(
            "nu_bound", nu_bound, low=0.0, high=limit, what="delta = m * nu_bound**2 is a float64"
        )
        return m * nu_v**2
    if delta is not None:
        return check_scalar(
            "delta", delta, positive=False, what="a finite number >= 0 bounding E||nu_k||^2"
        )
    return 0.0


def _solve_lmis(
    model: SDJLSModel, At: np.ndarray, solver: str, what: str
) -> tuple[np.ndarray, str]:
    """``P`` (N, n, n) satisfying (LMI1), (LMI2) with ``I << P_i << t I``, ``t`` minimal, and
    the solver's status; :class:`LMIInfeasibleError` when there is none."""
    N, n = model.N, model.n
    I_n = np.eye(n)
    P = [cp.Variable((n, n), symmetric=True, name=f"P_{i}") for i in range(N)]
    t = cp.Variable(name="t")
    constraints = []
    for i in range(N):
        constraints += [P[i] >> I_n, P[i] << t * I_n]
        for Pi in (model.P_in, model.P_out):
            L = sum(Pi[i, j] * P[j] for j in range(N) if Pi[i, j] != 0.0)
            Ei = At[i].T @ L @ At[i] - P[i]
            constraints.append((Ei + Ei.T) / 2 << -I_n)  # eqs. (LMI1), (LMI2), normalized
    problem = cp.Problem(cp.Minimize(t), constraints)
    try:
        status = solve(problem, solver, False, what)
    except LMIInfeasibleError as exc:
        raise LMIInfeasibleError(
            f"{exc}: the gains K could not be certified; no P_i > 0 satisfies (LMI1) and (LMI2) "
            "with Atilde_i = A_i + B_i K_i"
        ) from None
    return sym(np.array([p.value for p in P], dtype=np.float64)), status


def _checked_margins(
    model: SDJLSModel, K: np.ndarray, Pv: np.ndarray, eps: float, source: str, status: str
) -> tuple[float, float, np.ndarray, float]:
    """``(c1, c2, margins, mu)`` of the ``P`` found, after its float64 check
    (:class:`LMISolverError` when it fails; ``source`` names the certificate and the solver)."""
    if not np.all(np.isfinite(Pv)):
        raise LMISolverError(f"{source} returned a non-finite P")
    eigP = np.linalg.eigvalsh(Pv)
    c1 = float(np.min(eigP[:, 0]))
    c2 = float(np.max(eigP[:, -1]))
    with np.errstate(over="ignore", invalid="ignore"):
        E = prop1_matrices(model, K, Pv)  # E_i^1, E_i^2, eqs. (LMI1), (LMI2)
    if not np.all(np.isfinite(E)):
        raise LMISolverError(
            f"{source} returned status {status!r} but E_i^j (eqs. LMI1, LMI2) "
            f"overflows float64 with the P found (entries up to {float(np.max(np.abs(Pv))):.3g})"
        )
    eigE = np.linalg.eigvalsh(E)  # (N, 2, n)
    margins = eigE[..., -1]
    mu = float(np.min(-eigE[..., -1]))  # min_{i,j} lambda_min(-E_i^j)
    allowance = roundoff(E, Pv)
    if not (c1 > allowance and mu >= max(eps, allowance)):
        raise LMISolverError(
            f"{source} returned status {status!r} but the float64 check failed: "
            f"min eigenvalue of P is {c1:.3g}, mu = min lambda_min(-E_i^j) is {mu:.3g}; expected "
            f"both positive and mu >= eps = {eps:g}"
        )
    return c1, c2, margins, mu


def _appendix_constants(
    model: SDJLSModel, At: np.ndarray, Pv: np.ndarray
) -> tuple[float, float, float, float]:
    """``(alpha1, alpha2, beta, noise_term)`` of Appendix A for the ``P`` found."""
    L = weighted_sums(model.P_in, Pv)
    M = weighted_sums(model.P_out, Pv)
    Bt = model.B.transpose(0, 2, 1)
    alpha1 = float(
        max(
            np.max(np.linalg.eigvalsh(sym(Bt @ L @ model.B))[:, -1]),
            np.max(np.linalg.eigvalsh(sym(Bt @ M @ model.B))[:, -1]),
        )
    )
    alpha2 = float(max(np.max(np.linalg.eigvalsh(L)[:, -1]), np.max(np.linalg.eigvalsh(M)[:, -1])))
    norm_B = float(np.max(np.linalg.norm(model.B, ord=2, axis=(1, 2))))
    norm_At = float(np.max(np.linalg.norm(At, ord=2, axis=(1, 2))))
    # E[w' E_i' Upsilon E_i w] = trace(Upsilon E_i W E_i') <= lambda_max(Upsilon) trace(E_i W E_i')
    # <= alpha2 * max_i trace(E_i W E_i'); the paper's n * alpha2 is the case E_i = I, W = I.
    noise_term = alpha2 * float(np.max(np.trace(model.noise_cov, axis1=1, axis2=2)))
    return alpha1, alpha2, norm_B * alpha2 * norm_At, noise_term
