"""Mean-square pre-stabilization by LMIs: Proposition 2 synthesis, Proposition 1 certificate.

Section 3 of the paper pre-stabilizes the SDJLS with a mode-dependent state feedback
``u_k = K_theta x_k + nu_k`` (eq. eq:stabilization_input), closed loop
``x_{k+1} = Atilde_theta x_k + B_theta nu_k + E_theta w_k`` with ``Atilde_i = A_i + B_i K_i``
(eq. sys:stabilized_input).

* :func:`synthesize_gains` solves Proposition 2 (eqs. lmi:stabiization1, lmi:stabiization2) for
  ``X_i > 0``, ``Y_i`` and returns ``K_i = Y_i X_i^{-1}`` (eq. controller:stateFB), after checking
  the Proposition-1 conditions (eqs. LMI1, LMI2) in float64 with ``P_i = X_i^{-1}``.
* :func:`check_proposition2` evaluates the Proposition-2 matrices for given ``X``, ``Y``.
* :func:`verify_mean_square_bound` and :func:`second_moment_spectral_radius` (Proposition 1, the
  certificate of given gains) live in :mod:`controllers.mean_square`, which imports the helpers
  below (this module does not import it: no cycle).

The helpers without a leading underscore (``check_eps``, ``pick_solver``, ``solve``, ...) are
shared with :mod:`controllers.mean_square`; they are not part of the public API.

Modes are numbered ``0 .. N-1`` (the paper numbers them ``1 .. N``). The paper uses ``mu`` both
for the transition matrix used outside ``C1`` (here ``model.P_out``) and for the decay margin of
Appendix A (here :attr:`controllers.mean_square.MeanSquareCertificate.mu`).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Literal

import cvxpy as cp
import numpy as np

from sdjls_gym import SDJLSModel
from sdjls_gym.errors import LMIInfeasibleError, LMISolverError
from sdjls_gym.messages import a_type, describe
from sdjls_gym.validation import check_array, check_bool, check_number

from .base import ReadOnlyArrays, check_model

__all__ = [
    "GainSynthesisResult",
    "check_proposition2",
    "synthesize_gains",
]

_OBJECTIVES = ("feasibility", "max_margin")

#: Multiple of the float64 unit roundoff allowed as the error of a computed eigenvalue, relative
#: to the size of the matrix, before a "negative" eigenvalue is accepted as really negative.
_ROUNDOFF_FACTOR = 1e3


# ---------------------------------------------------------------------------------- results
@dataclass(frozen=True, eq=False)
class GainSynthesisResult(ReadOnlyArrays):
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

    ARRAYS = ("K", "X", "Y", "P")


# ---------------------------------------------------------------------------------- helpers
def check_scalar(name: str, value: object, *, positive: bool, what: str) -> float:
    """``value`` as a finite float that is > 0 (``positive``) or >= 0."""
    return check_number(name, value, low=0.0, low_open=positive, what=what)


def check_eps(eps: float) -> float:
    return check_scalar("eps", eps, positive=True, what="margin of the strict LMIs")


def pick_solver(solver: str | None) -> str:
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


def as_array(name: str, value: object, shape: tuple[int, ...], what: str) -> np.ndarray:
    return check_array(name, value, shape=shape, what=what)


def sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + np.swapaxes(M, -1, -2))


def closed_loop(model: SDJLSModel, K: np.ndarray) -> np.ndarray:
    """``Atilde_i = A_i + B_i K_i``, eq. (sys:stabilized_input); shape (N, n, n)."""
    return model.A + model.B @ K


def checked_closed_loop(model: SDJLSModel, K: np.ndarray) -> np.ndarray:
    """:func:`closed_loop` of finite gains ``K``, refused (a ValueError naming ``K``) when its
    products ``Atilde_i' P Atilde_i`` (eqs. LMI1, LMI2) or ``kron(Atilde_i, Atilde_i)`` would
    overflow float64: the solver would see infinite data, numpy's eigenvalues would fail."""
    with np.errstate(over="ignore", invalid="ignore"):
        At = closed_loop(model, K)
        products = np.abs(At).transpose(0, 2, 1) @ np.abs(At)  # bounds every sum of products
    if not np.all(np.isfinite(products)):
        limit = math.sqrt(sys.float_info.max / model.n)
        raise ValueError(
            f"K has entries up to {float(np.max(np.abs(K))):.3g}: the closed loop "
            f"A_i + B_i K_i has entries up to {float(np.max(np.abs(At))):.3g}, whose products "
            f"(Atilde_i' P Atilde_i in eqs. LMI1, LMI2) overflow float64; expected gains whose "
            f"closed loop has entries below about {limit:.3g}"
        )
    return At


def weighted_sums(Pi: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``sum_j Pi[i, j] P_j`` for every ``i``: ``L_i`` (Pi = lambda) or ``M_i`` (Pi = mu)."""
    return np.einsum("ij,jab->iab", Pi, P)


def prop1_matrices(model: SDJLSModel, K: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``E_i^1``, ``E_i^2`` of eqs. (LMI1), (LMI2) in float64; shape (N, 2, n, n)."""
    At = closed_loop(model, K)
    out = []
    for Pi in (model.P_in, model.P_out):
        L = weighted_sums(Pi, P)
        out.append(sym(At.transpose(0, 2, 1) @ L @ At - P))  # eqs. (LMI1), (LMI2)
    return np.stack(out, axis=1)


def roundoff(*mats: np.ndarray) -> float:
    """An allowance for the float64 error of the eigenvalues of matrices built from ``mats``."""
    scale = max(float(np.max(np.abs(M))) for M in mats)
    return _ROUNDOFF_FACTOR * np.finfo(np.float64).eps * max(scale, 1.0)


def solve(problem: cp.Problem, solver: str, verbose: bool, what: str) -> str:
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
                blocks.append(sym(M))
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
        If ``X`` or ``Y`` has the wrong shape, a non-finite entry, or ``X`` is not symmetric, or
        if ``A_i X_i + B_i Y_i`` overflows float64.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro, PAPER_X, PAPER_Y
    >>> check_proposition2(macro(), PAPER_X, PAPER_Y) < 0
    True
    """
    model = check_model(model)
    N, n, m = model.N, model.n, model.m
    X = as_array("X", X, (N, n, n), "one symmetric n x n matrix X_i per mode")
    Y = as_array("Y", Y, (N, m, n), "one m x n matrix Y_i per mode")
    asym = np.max(np.abs(X - X.transpose(0, 2, 1)), axis=(1, 2))
    scale = np.maximum(1.0, np.max(np.abs(X), axis=(1, 2)))
    if np.any(asym > 1e-9 * scale):
        i = int(np.argmax(asym / scale))
        raise ValueError(
            f"X[{i}] is not symmetric (max |X - X'| = {asym[i]:.3g}); X_i must be symmetric"
        )
    with np.errstate(over="ignore", invalid="ignore"):
        blocks = _prop2_blocks(model, list(X), list(Y))
    bad = next((i for i, M in enumerate(blocks) if not np.all(np.isfinite(M))), None)
    if bad is not None:
        i = bad // 2
        raise ValueError(
            f"X and Y are too large: A_{i} X_{i} + B_{i} Y_{i} overflows float64 (X has entries "
            f"up to {float(np.max(np.abs(X))):.3g}, Y up to {float(np.max(np.abs(Y))):.3g}); "
            "expected matrices whose products stay finite (the conditions are homogeneous: "
            "scaling X and Y down changes no verdict)"
        )
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
        If ``model`` is not an :class:`SDJLSModel`, ``objective`` or ``solver`` not a string,
        ``eps`` not a number or ``verbose`` not a bool.
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
    eps = check_eps(eps)
    if not isinstance(objective, str):
        raise TypeError(
            f"objective = {describe(objective)} is {a_type(objective)}; expected one of "
            f"{_OBJECTIVES}"
        )
    if objective not in _OBJECTIVES:
        raise ValueError(f"objective = {objective!r}; expected one of {_OBJECTIVES}")
    verbose = check_bool("verbose", verbose)
    solver = pick_solver(solver)
    X, Y, problem = _prop2_problem(model, objective, eps)
    what = f"Proposition 2 gain synthesis (objective={objective!r}, eps={eps:g})"
    status = solve(problem, solver, verbose, what)
    Xv = sym(np.array([x.value for x in X], dtype=np.float64))
    Yv = np.array([y.value for y in Y], dtype=np.float64)
    K, P, margin = _verified_gains(model, Xv, Yv, f"{what}: solver {solver}", status)
    return GainSynthesisResult(K=K, X=Xv, Y=Yv, P=P, status=status, solver=solver, margin=margin)


def _prop2_problem(model: SDJLSModel, objective: str, eps: float) -> tuple[list, list, cp.Problem]:
    """``(X, Y, problem)``: the variables ``X_i``, ``Y_i`` and the problem of Proposition 2 with
    ``objective`` (see :func:`synthesize_gains`)."""
    N, n, m = model.N, model.n, model.m
    X = [cp.Variable((n, n), symmetric=True, name=f"X_{i}") for i in range(N)]
    Y = [cp.Variable((m, n), name=f"Y_{i}") for i in range(N)]
    size = (N + 1) * n
    constraints = []
    bound: float | cp.Variable  # -bound I bounds the blocks: eps, or the margin t
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
    return X, Y, cp.Problem(goal, constraints)


def _verified_gains(
    model: SDJLSModel, Xv: np.ndarray, Yv: np.ndarray, source: str, status: str
) -> tuple[np.ndarray, np.ndarray, float]:
    """``(K, P, margin)`` of the solver's ``X``, ``Y``, after the float64 checks of
    :func:`synthesize_gains` (:class:`LMISolverError` when one fails; ``source`` names the
    synthesis and the solver)."""
    if not (np.all(np.isfinite(Xv)) and np.all(np.isfinite(Yv))):
        raise LMISolverError(f"{source} returned non-finite X or Y")
    x_min = np.linalg.eigvalsh(Xv)[:, 0]
    if np.any(x_min <= roundoff(Xv)):
        i = int(np.argmin(x_min))
        raise LMISolverError(
            f"{source} returned status {status!r} but X[{i}] is not positive "
            f"definite in float64 (smallest eigenvalue {x_min[i]:.3g})"
        )
    P = sym(np.linalg.inv(Xv))
    K = np.linalg.solve(Xv, Yv.transpose(0, 2, 1)).transpose(0, 2, 1)  # eq. (controller:stateFB)
    E = prop1_matrices(model, K, P)
    margin = float(np.max(np.linalg.eigvalsh(E)[..., -1]))
    allowance = roundoff(E, P)
    if not margin < -allowance:
        raise LMISolverError(
            f"{source} returned status {status!r} but the Proposition-1 check "
            f"failed in float64: largest eigenvalue of E_i^j (eqs. LMI1, LMI2) is {margin:.3g}, "
            f"not below -{allowance:.1g}; the gains are not returned because they are unverified"
        )
    return K, P, margin
