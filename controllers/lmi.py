"""Mean-square pre-stabilization by LMIs: Proposition 2 synthesis, Proposition 1 certificate.

Section 3 of the paper pre-stabilizes the SDJLS with a mode-dependent state feedback
``u_k = K_theta x_k + nu_k`` (eq. eq:stabilization_input), closed loop
``x_{k+1} = Atilde_theta x_k + B_theta nu_k + E_theta w_k`` with ``Atilde_i = A_i + B_i K_i``
(eq. sys:stabilized_input).

* :func:`synthesize_gains` solves Proposition 2 (eqs. lmi:stabiization1, lmi:stabiization2) for
  ``X_i > 0``, ``Y_i`` and returns ``K_i = Y_i X_i^{-1}`` (eq. controller:stateFB), after checking
  the Proposition-1 conditions (eqs. LMI1, LMI2) in float64 with ``P_i = X_i^{-1}``.
* :func:`check_proposition2` evaluates the Proposition-2 matrices for given ``X``, ``Y``.
* :func:`verify_mean_square_bound` certifies given gains: it finds ``P_i`` satisfying (LMI1),
  (LMI2) and computes the constants of Appendix A, so that
  ``E||x_k||^2 <= beta1 ||x0||^2 q^k + beta2`` (eq. eq:msqs).
* :func:`second_moment_spectral_radius` is an independent sufficient mean-square test.

Modes are numbered ``0 .. N-1`` (the paper numbers them ``1 .. N``). The paper uses ``mu`` both
for the transition matrix used outside ``C1`` (here ``model.P_out``) and for the decay margin of
Appendix A (here :attr:`MeanSquareCertificate.mu`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cvxpy as cp
import numpy as np

from sdjls_gym import SDJLSModel
from sdjls_gym._validate import check_array, check_number, describe

from .base import check_model

__all__ = [
    "GainSynthesisResult",
    "LMIError",
    "LMIInfeasibleError",
    "LMISolverError",
    "MeanSquareCertificate",
    "check_proposition2",
    "second_moment_spectral_radius",
    "synthesize_gains",
    "verify_mean_square_bound",
]

_OBJECTIVES = ("feasibility", "max_margin")

#: Multiple of the float64 unit roundoff allowed as the error of a computed eigenvalue, relative
#: to the size of the matrix, before a "negative" eigenvalue is accepted as really negative.
_ROUNDOFF_FACTOR = 1e3


# ---------------------------------------------------------------------------------- exceptions
class LMIError(RuntimeError):
    """Base class of the errors of this module: an LMI problem gave no usable answer."""


class LMIInfeasibleError(LMIError, ValueError):
    """The solver reports the LMIs infeasible (also a :class:`ValueError`: the data are bad)."""


class LMISolverError(LMIError):
    """The solver failed, was inaccurate, or its answer did not pass the float64 check."""


# ---------------------------------------------------------------------------------- results
def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, dtype=np.float64)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class GainSynthesisResult:
    """Gains from Proposition 2, verified against Proposition 1.

    Attributes
    ----------
    K : (N, m, n)
        Feedback gains ``K_i = Y_i X_i^{-1}``, eq. (controller:stateFB).
    X : (N, n, n)
        Solution ``X_i > 0`` of eqs. (lmi:stabiization1), (lmi:stabiization2).
    Y : (N, m, n)
        Solution ``Y_i``.
    P : (N, n, n)
        Lyapunov matrices ``P_i = X_i^{-1}`` of Proposition 1.
    status : str
        The cvxpy status reported by the solver.
    solver : str
        Name of the solver used.
    margin : float
        Largest eigenvalue over all Proposition-1 matrices ``E_i^1``, ``E_i^2`` (eqs. LMI1, LMI2)
        computed in float64 with ``P`` and ``K``; negative means verified.
    """

    K: np.ndarray
    X: np.ndarray
    Y: np.ndarray
    P: np.ndarray
    status: str
    solver: str
    margin: float


@dataclass(frozen=True, eq=False)
class MeanSquareCertificate:
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
        ValueError
            If ``k`` is negative or not an integer, or ``x0`` has the wrong shape.
        """
        n = self.P.shape[1]
        x0 = np.asarray(x0, dtype=np.float64)
        if x0.shape != (n,):
            raise ValueError(f"x0 has shape {x0.shape}; expected ({n},)")
        k_arr = np.asarray(k)
        if not np.issubdtype(k_arr.dtype, np.integer) or np.any(k_arr < 0):
            raise ValueError(f"k = {k!r}; expected a non-negative integer or integer array")
        out = self.beta1 * float(x0 @ x0) * self.q ** k_arr.astype(np.float64) + self.beta2
        return float(out) if k_arr.ndim == 0 else out


# ---------------------------------------------------------------------------------- helpers
def _check_scalar(name: str, value: object, *, positive: bool, what: str) -> float:
    """``value`` as a finite float that is > 0 (``positive``) or >= 0."""
    return check_number(name, value, low=0.0, low_open=positive, what=what)


def _check_eps(eps: float) -> float:
    return _check_scalar("eps", eps, positive=True, what="margin of the strict LMIs")


def _pick_solver(solver: str | None) -> str:
    installed = cp.installed_solvers()
    if solver is None:
        return "CLARABEL" if "CLARABEL" in installed else "SCS"
    if not isinstance(solver, str):
        raise TypeError(
            f"solver = {describe(solver)} is a {type(solver).__name__}; expected the name of an "
            f"installed cvxpy solver, one of {installed}"
        )
    if solver.upper() not in installed:
        raise ValueError(
            f"solver = {solver!r} is not an installed cvxpy solver; expected one of {installed}"
        )
    return solver.upper()


def _as_array(name: str, value: object, shape: tuple[int, ...], what: str) -> np.ndarray:
    return check_array(name, value, shape=shape, what=what)


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + np.swapaxes(M, -1, -2))


def _closed_loop(model: SDJLSModel, K: np.ndarray) -> np.ndarray:
    """``Atilde_i = A_i + B_i K_i``, eq. (sys:stabilized_input); shape (N, n, n)."""
    return model.A + model.B @ K


def _weighted_sums(Pi: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``sum_j Pi[i, j] P_j`` for every ``i``: ``L_i`` (Pi = lambda) or ``M_i`` (Pi = mu)."""
    return np.einsum("ij,jab->iab", Pi, P)


def _prop1_matrices(model: SDJLSModel, K: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``E_i^1``, ``E_i^2`` of eqs. (LMI1), (LMI2) in float64; shape (N, 2, n, n)."""
    At = _closed_loop(model, K)
    out = []
    for Pi in (model.P_in, model.P_out):
        L = _weighted_sums(Pi, P)
        out.append(_sym(At.transpose(0, 2, 1) @ L @ At - P))  # eqs. (LMI1), (LMI2)
    return np.stack(out, axis=1)


def _roundoff(*mats: np.ndarray) -> float:
    """An allowance for the float64 error of the eigenvalues of matrices built from ``mats``."""
    scale = max(float(np.max(np.abs(M))) for M in mats)
    return _ROUNDOFF_FACTOR * np.finfo(np.float64).eps * max(scale, 1.0)


def _solve(problem: cp.Problem, solver: str, verbose: bool, what: str) -> str:
    """Solve and map the status to this module's errors; return the status."""
    try:
        problem.solve(solver=solver, verbose=verbose)
    except cp.error.SolverError as exc:
        raise LMISolverError(f"{what}: solver {solver} failed ({exc})") from exc
    status = problem.status
    if status == cp.INFEASIBLE:
        raise LMIInfeasibleError(f"{what}: solver {solver} reports status {status!r}")
    if status != cp.OPTIMAL:
        raise LMISolverError(
            f"{what}: solver {solver} returned status {status!r}, not 'optimal'; the answer "
            "cannot be trusted (try another solver, or objective='max_margin')"
        )
    return status


# ---------------------------------------------------------------------------------- Prop. 2
def _prop2_blocks(model: SDJLSModel, X: list, Y: list) -> list:
    """The 2N block matrices of eqs. (lmi:stabiization1), (lmi:stabiization2).

    ``X``, ``Y`` are lists of per-mode cvxpy expressions or numpy arrays. Returned matrices are
    ``((N + 1) n, (N + 1) n)`` and explicitly symmetrized.
    """
    N, n = model.N, model.n
    zero = np.zeros((n, n))
    X_D = [[X[a] if a == b else zero for b in range(N)] for a in range(N)]
    blocks = []
    for i in range(N):
        AXBY = model.A[i] @ X[i] + model.B[i] @ Y[i]
        for Pi in (model.P_in, model.P_out):
            # Lambda_i (resp. Gamma_i) = [sqrt(lambda_i1) I, ..., sqrt(lambda_iN) I]'
            Lam = np.kron(np.sqrt(Pi[i])[:, None], np.eye(n))
            off = Lam @ AXBY
            if isinstance(X[i], np.ndarray):
                M = np.block([[-np.block(X_D), off], [off.T, -X[i]]])
                blocks.append(_sym(M))
            else:
                M = cp.bmat([[-cp.bmat(X_D), off], [off.T, -X[i]]])
                blocks.append((M + M.T) / 2)  # eqs. (lmi:stabiization1), (lmi:stabiization2)
    return blocks


def check_proposition2(model: SDJLSModel, X: np.ndarray, Y: np.ndarray) -> float:
    """Evaluate the Proposition-2 conditions numerically.

    Builds the left-hand sides of eqs. (lmi:stabiization1) and (lmi:stabiization2) for every mode
    (``2N`` matrices of size ``(N + 1) n``) and the matrices ``-X_i``.

    Parameters
    ----------
    model : SDJLSModel
    X : (N, n, n)
        Symmetric matrices ``X_i``.
    Y : (N, m, n)
        Matrices ``Y_i``.

    Returns
    -------
    float
        The largest eigenvalue over all ``2N`` block matrices and all ``-X_i``; negative means
        the conditions hold strictly (then ``K_i = Y_i X_i^{-1}`` pre-stabilizes the system).

    Raises
    ------
    TypeError
        If ``model`` is not an :class:`SDJLSModel`.
    ValueError
        If ``X`` or ``Y`` has the wrong shape, a non-finite entry, or ``X`` is not symmetric.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro, PAPER_X, PAPER_Y
    >>> check_proposition2(macro(), PAPER_X, PAPER_Y) < 0
    True
    """
    model = check_model(model)
    N, n, m = model.N, model.n, model.m
    X = _as_array("X", X, (N, n, n), "one symmetric n x n matrix X_i per mode")
    Y = _as_array("Y", Y, (N, m, n), "one m x n matrix Y_i per mode")
    asym = np.max(np.abs(X - X.transpose(0, 2, 1)), axis=(1, 2))
    scale = np.maximum(1.0, np.max(np.abs(X), axis=(1, 2)))
    if np.any(asym > 1e-9 * scale):
        i = int(np.argmax(asym / scale))
        raise ValueError(
            f"X[{i}] is not symmetric (max |X - X'| = {asym[i]:.3g}); X_i must be symmetric"
        )
    blocks = _prop2_blocks(model, list(X), list(Y))
    eigs = [np.linalg.eigvalsh(M)[-1] for M in blocks]
    eigs += [np.linalg.eigvalsh(-X[i])[-1] for i in range(N)]
    return float(max(eigs))


def synthesize_gains(
    model: SDJLSModel,
    *,
    solver: str | None = None,
    eps: float = 1e-6,
    objective: Literal["feasibility", "max_margin"] = "feasibility",
    verbose: bool = False,
) -> GainSynthesisResult:
    """Pre-stabilizing gains from Proposition 2, verified with Proposition 1.

    Solves, for symmetric ``X_i`` (n, n) and ``Y_i`` (m, n), ``i = 0 .. N-1``::

        [[-X_D, Lambda_i (A_i X_i + B_i Y_i)], [*, -X_i]] < 0     eq. (lmi:stabiization1)
        [[-X_D, Gamma_i  (A_i X_i + B_i Y_i)], [*, -X_i]] < 0     eq. (lmi:stabiization2)

    with ``X_D = diag(X_0, ..., X_{N-1})``, ``Lambda_i = [sqrt(lambda_i0) I, ...]'`` from
    ``model.P_in`` and ``Gamma_i`` likewise from ``model.P_out``, and returns
    ``K_i = Y_i X_i^{-1}`` (eq. controller:stateFB).

    Parameters
    ----------
    model : SDJLSModel
    solver : str, optional
        A cvxpy solver name; default Clarabel if installed, else SCS.
    eps : float
        Strictness margin, > 0. ``"feasibility"``: the LMIs are imposed as ``<< -eps I`` and
        ``X_i >> eps I``. ``"max_margin"``: the margin ``t`` must be at least ``eps``.
    objective : {"feasibility", "max_margin"}
        ``"feasibility"``: no objective (any strictly feasible point). ``"max_margin"``: maximize
        ``t`` subject to both LMIs ``<< -t I``, ``eps <= t <= 1`` and the normalization
        ``X_i << I``. The LMIs are homogeneous in ``(X, Y)``, so the normalization loses no
        generality; it makes the largest-margin problem bounded and the gains well-conditioned.
    verbose : bool
        Passed to the solver.

    Returns
    -------
    GainSynthesisResult
        Only returned after checking in float64 that every ``X_i > 0`` and that (LMI1), (LMI2)
        hold strictly with ``P_i = X_i^{-1}`` and the computed ``K``.

    Raises
    ------
    TypeError
        If ``model`` is not an :class:`SDJLSModel`.
    ValueError
        If ``eps``, ``objective`` or ``solver`` is invalid.
    LMIInfeasibleError
        If the solver reports the LMIs infeasible (no gains of this form are certified).
    LMISolverError
        On any other non-optimal status, or if the float64 check fails.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro
    >>> res = synthesize_gains(macro())
    >>> res.K.shape, res.margin < 0
    ((3, 1, 2), True)
    """
    model = check_model(model)
    eps = _check_eps(eps)
    if objective not in _OBJECTIVES:
        raise ValueError(f"objective = {objective!r}; expected one of {_OBJECTIVES}")
    solver = _pick_solver(solver)
    N, n, m = model.N, model.n, model.m

    X = [cp.Variable((n, n), symmetric=True, name=f"X_{i}") for i in range(N)]
    Y = [cp.Variable((m, n), name=f"Y_{i}") for i in range(N)]
    size = (N + 1) * n
    constraints = []
    if objective == "feasibility":
        margin_var = None
        bound = eps
        constraints += [X[i] >> eps * np.eye(n) for i in range(N)]  # X_i > 0
    else:
        margin_var = cp.Variable(name="t")
        bound = margin_var
        constraints += [margin_var >= eps, margin_var <= 1.0]
        constraints += [X[i] >> margin_var * np.eye(n) for i in range(N)]
        constraints += [X[i] << np.eye(n) for i in range(N)]  # normalization
    for M in _prop2_blocks(model, X, Y):
        constraints.append(M << -bound * np.eye(size))  # eqs. (lmi:stabiization1), (...2)
    goal = cp.Minimize(0) if margin_var is None else cp.Maximize(margin_var)
    problem = cp.Problem(goal, constraints)
    what = f"Proposition 2 gain synthesis (objective={objective!r}, eps={eps:g})"
    status = _solve(problem, solver, verbose, what)

    Xv = _sym(np.array([x.value for x in X], dtype=np.float64))
    Yv = np.array([y.value for y in Y], dtype=np.float64)
    if not (np.all(np.isfinite(Xv)) and np.all(np.isfinite(Yv))):
        raise LMISolverError(f"{what}: solver {solver} returned non-finite X or Y")
    x_min = np.linalg.eigvalsh(Xv)[:, 0]
    if np.any(x_min <= _roundoff(Xv)):
        i = int(np.argmin(x_min))
        raise LMISolverError(
            f"{what}: solver {solver} returned status {status!r} but X[{i}] is not positive "
            f"definite in float64 (smallest eigenvalue {x_min[i]:.3g})"
        )
    P = _sym(np.linalg.inv(Xv))
    K = np.linalg.solve(Xv, Yv.transpose(0, 2, 1)).transpose(0, 2, 1)  # eq. (controller:stateFB)
    E = _prop1_matrices(model, K, P)
    margin = float(np.max(np.linalg.eigvalsh(E)[..., -1]))
    allowance = _roundoff(E, P)
    if not margin < -allowance:
        raise LMISolverError(
            f"{what}: solver {solver} returned status {status!r} but the Proposition-1 check "
            f"failed in float64: largest eigenvalue of E_i^j (eqs. LMI1, LMI2) is {margin:.3g}, "
            f"not below -{allowance:.1g}; the gains are not returned because they are unverified"
        )
    return GainSynthesisResult(
        K=_frozen(K),
        X=_frozen(Xv),
        Y=_frozen(Yv),
        P=_frozen(P),
        status=status,
        solver=solver,
        margin=margin,
    )


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
        If ``K`` has the wrong shape or a non-finite entry.
    """
    model = check_model(model)
    N, n, m = model.N, model.n, model.m
    K = _as_array("K", K, (N, m, n), "one m x n gain K_i per mode")
    At = _closed_loop(model, K)
    Pmax = np.maximum(model.P_in, model.P_out)
    d = n * n
    T = np.zeros((N * d, N * d))
    for i in range(N):
        kron = np.kron(At[i], At[i])  # vec(A Z A') = kron(A, A) vec(Z)
        for j in range(N):
            T[j * d : (j + 1) * d, i * d : (i + 1) * d] = Pmax[i, j] * kron
    return float(np.max(np.abs(np.linalg.eigvals(T))))


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
    TypeError
        If ``model`` is not an :class:`SDJLSModel`.
    ValueError
        If ``K`` has the wrong shape or a non-finite entry, or ``nu_bound``, ``delta``,
        ``kappa``, ``eps`` or ``solver`` is invalid.
    LMIInfeasibleError
        If no ``P`` satisfies (LMI1) and (LMI2) for these gains: they cannot be certified.
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
    K = _as_array("K", K, (N, m, n), "one m x n gain K_i per mode")
    eps = _check_eps(eps)
    if nu_bound is not None and delta is not None:
        raise ValueError(
            f"nu_bound = {nu_bound!r} and delta = {delta!r} were both given; give at most one "
            "(delta = m * nu_bound**2 is derived from nu_bound)"
        )
    if nu_bound is not None:
        nu_v = _check_scalar("nu_bound", nu_bound, positive=False, what="a finite number >= 0")
        delta_v = m * nu_v**2
    elif delta is not None:
        delta_v = _check_scalar(
            "delta", delta, positive=False, what="a finite number >= 0 bounding E||nu_k||^2"
        )
    else:
        delta_v = 0.0
    if kappa is not None:
        kappa_v = _check_scalar("kappa", kappa, positive=True, what="a finite number in (0, mu)")
    solver = _pick_solver(solver)

    At = _closed_loop(model, K)
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
    what = "Proposition 1 certificate (eqs. LMI1, LMI2) for the given gains K"
    try:
        status = _solve(problem, solver, False, what)
    except LMIInfeasibleError as exc:
        raise LMIInfeasibleError(
            f"{exc}: the gains K could not be certified; no P_i > 0 satisfies (LMI1) and (LMI2) "
            "with Atilde_i = A_i + B_i K_i"
        ) from None

    Pv = _sym(np.array([p.value for p in P], dtype=np.float64))
    if not np.all(np.isfinite(Pv)):
        raise LMISolverError(f"{what}: solver {solver} returned a non-finite P")
    eigP = np.linalg.eigvalsh(Pv)
    c1 = float(np.min(eigP[:, 0]))
    c2 = float(np.max(eigP[:, -1]))
    E = _prop1_matrices(model, K, Pv)  # E_i^1, E_i^2, eqs. (LMI1), (LMI2)
    eigE = np.linalg.eigvalsh(E)  # (N, 2, n)
    margins = eigE[..., -1]
    mu = float(np.min(-eigE[..., -1]))  # min_{i,j} lambda_min(-E_i^j)
    allowance = _roundoff(E, Pv)
    if not (c1 > allowance and mu >= max(eps, allowance)):
        raise LMISolverError(
            f"{what}: solver {solver} returned status {status!r} but the float64 check failed: "
            f"min eigenvalue of P is {c1:.3g}, mu = min lambda_min(-E_i^j) is {mu:.3g}; expected "
            f"both positive and mu >= eps = {eps:g}"
        )
    if kappa is None:
        kappa_v = mu / 2.0
    elif not kappa_v < mu:
        raise ValueError(f"kappa = {kappa!r}; expected 0 < kappa < mu = {mu:.6g}")

    L = _weighted_sums(model.P_in, Pv)
    M = _weighted_sums(model.P_out, Pv)
    Bt = model.B.transpose(0, 2, 1)
    alpha1 = float(
        max(
            np.max(np.linalg.eigvalsh(_sym(Bt @ L @ model.B))[:, -1]),
            np.max(np.linalg.eigvalsh(_sym(Bt @ M @ model.B))[:, -1]),
        )
    )
    alpha2 = float(max(np.max(np.linalg.eigvalsh(L)[:, -1]), np.max(np.linalg.eigvalsh(M)[:, -1])))
    norm_B = float(np.max(np.linalg.norm(model.B, ord=2, axis=(1, 2))))
    norm_At = float(np.max(np.linalg.norm(At, ord=2, axis=(1, 2))))
    beta = norm_B * alpha2 * norm_At
    q = 1.0 - (mu - kappa_v) / c2
    # E[w' E_i' Upsilon E_i w] = trace(Upsilon E_i W E_i') <= lambda_max(Upsilon) trace(E_i W E_i')
    # <= alpha2 * max_i trace(E_i W E_i'); the paper's n * alpha2 is the case E_i = I, W = I.
    noise_term = alpha2 * float(np.max(np.trace(model.noise_cov, axis1=1, axis2=2)))
    beta1 = c2 / c1
    beta2 = (noise_term + delta_v * (alpha1 + beta**2 / kappa_v)) / (c1 * (1.0 - q))
    return MeanSquareCertificate(
        K=_frozen(K),
        P=_frozen(Pv),
        margins=_frozen(margins),
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
