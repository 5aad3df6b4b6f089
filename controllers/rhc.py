"""The one-step receding-horizon controller with probabilistic constraints (problem P3).

At each time ``k`` the controller observes ``(x_k, theta_k)`` and solves (section 5 of the paper)::

    P3:  min_{nu, rho}  x'Q_theta x + u'R_theta u + (Atilde_theta x + B_theta nu)' Pi (...)
                        + tr(Pi E_theta W E_theta') + alpha rho
         s.t.  G_j (Atilde_theta x + B_theta nu) <= H_{k+1, j} - t[theta, j] + rho,  j = 1..r
               nu in U,  rho >= 0,          u = K_theta x + nu

with ``Atilde_i = A_i + B_i K_i``, ``Pi = sum_j pi_{theta j}(x_k) Psi_j`` (eq. eq:exp_noise; the
row ``pi_{theta .}(x_k)`` is ``P_in[theta]`` if ``x_k`` is in C1 at time ``k`` and ``P_out[theta]``
otherwise) and the tightening ``t`` of :func:`controllers.chance.tightening`. The constraint is on
``x_{k+1}``, so it uses the band ``H_{k+1}``. The paper writes ``tr(Pi)``: that is the special case
``E = W = I`` of the noise term above (Lemma 1, eq. eq:lemm1).

Solvers
-------
``solver="osqp"`` (default, fast path)
    The QP in ``z = (nu, rho)`` has a Hessian and a constraint matrix that depend only on the
    mode and on whether ``x_k`` is in C1 (a *family*), and its data are affine in ``x_k``. Each
    call first tries an *active-set warm start*: the active set of the family's last solution
    is re-solved exactly (the equality-constrained KKT system, a precomputed linear map of
    :class:`controllers.active_set.ActiveSetQP`) and accepted if the KKT conditions hold
    (primal feasibility, nonnegative multipliers: sufficient for this convex QP);
    ``info["solver"]`` is then ``"active_set_warm"``. Otherwise one ``osqp.OSQP`` object per
    family (set up on first use; later only ``update(q=, l=, u=)`` and a warm-started
    ``solve()``) finds the optimum, and the answer is recomputed exactly from the active set
    OSQP identified (verified the same way; if it does not verify, by enumeration of every
    candidate, ``info["solver"] == "active_set"``; only if that fails too is OSQP's own iterate
    kept). That active set is remembered for the next call. Since every answer then comes from
    the exact KKT solution of a verified active set, it does not depend on the call history
    (except in degenerate problems, where several active sets verify, and on the fallback
    paths below). Setting the private attribute ``_warm_start = False`` on a controller skips
    the warm start (OSQP at every call, answers still recomputed exactly); the speed benchmark
    uses it for comparison. With ``nu_set="ball"`` and ``m > 1`` OSQP cannot express
    ``||nu||_2 <= nu_bound``; the controller then solves the second-order cone program with
    cvxpy + Clarabel instead.
``solver="cvxpy"``
    The plain formulation written with cvxpy and solved by Clarabel, rebuilt at every call; a
    reference for checking the fast path.
``solver="active_set"``
    Exact solution by enumeration of the candidate active sets of the family's QP (see
    :mod:`controllers.active_set`), set up once per family, at every call (no warm start); OSQP
    takes over in the rare case where no candidate satisfies the KKT conditions.
    :meth:`RecedingHorizonController.act_batch` always uses the enumeration for the box ``U``.

An episode never crashes on a solver failure: OSQP is retried once (cold, 10x the iterations),
then the cvxpy reference is tried (unless ``cvxpy_fallback=False``), and as a last resort
``nu = 0`` with the smallest feasible ``rho``. ``info["status"]`` says what happened.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from operator import mul
from typing import Any

import numpy as np
import osqp
import scipy.sparse as sp

from sdjls_gym.model import SDJLSModel, _check_psd, max_last

from .active_set import ActiveSetQP
from .baselines import MAX_STATE, _check_gain, _check_positive, _FeedbackPolicy
from .chance import _check_constraint, _check_xi, tightening

__all__ = ["RecedingHorizonController", "UnconstrainedRecedingHorizonController"]

SOLVERS = ("osqp", "cvxpy", "active_set")
NU_SETS = ("box", "ball")

#: Settings of the OSQP fast path; tight enough that OSQP and the cvxpy/Clarabel reference agree
#: to ~1e-8. Override any of them with ``osqp_settings=``.
DEFAULT_OSQP_SETTINGS: dict[str, Any] = {
    "eps_abs": 1e-10,
    "eps_rel": 1e-10,
    "eps_prim_inf": 1e-12,
    "eps_dual_inf": 1e-12,
    "max_iter": 20000,
    "polishing": True,
    "polish_refine_iter": 10,
    "warm_starting": True,
    "verbose": False,
}

#: A slack below this (relative to max |H_{k+1} - t|) is round-off on an active row and is
#: reported as ``rho = 0``; the constraint then holds to within this tolerance.
_RHO_ZERO_TOL = 1e-10

#: Types accepted without conversion by the fast input check of ``act`` (bool is not among them).
_INT_TYPES = frozenset([int] + [np.dtype(c).type for c in np.typecodes["AllInteger"]])
_FLOAT64 = np.dtype(np.float64)

#: OSQP's infinity: bounds beyond it are clipped.
_OSQP_INFTY = float(osqp.constant("OSQP_INFTY"))

#: Cached offsets ``w0(k)`` per family before the cache is cleared (k is unbounded).
_MAX_OFFSETS = 4096

#: Clarabel settings of the cvxpy reference.
CLARABEL_SETTINGS: dict[str, Any] = {
    "tol_gap_abs": 1e-11,
    "tol_gap_rel": 1e-11,
    "tol_feas": 1e-11,
    "tol_ktratio": 1e-9,
    "max_iter": 200,
}


def _check_Psi(model: SDJLSModel, Psi: Any) -> np.ndarray:
    """A finite ``(N, n, n)`` array of symmetric positive definite terminal weights."""
    try:
        Psi = np.array(Psi, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"Psi could not be read as an array of numbers ({exc})") from None
    expected = (model.N, model.n, model.n)
    if Psi.shape != expected:
        raise ValueError(
            f"Psi has shape {Psi.shape}; expected {expected} (one n x n terminal weight per mode)"
        )
    if not np.all(np.isfinite(Psi)):
        raise ValueError("Psi has a non-finite entry; every entry must be finite")
    _check_psd("Psi", Psi, strict=True)  # the model's own check: "Psi[i] is not ..."
    Psi = 0.5 * (Psi + Psi.transpose(0, 2, 1))
    Psi.setflags(write=False)
    return Psi


def _check_choice(name: str, value: Any, allowed: tuple[str, ...]) -> str:
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name} = {value!r} is not known; expected one of {allowed}")
    return value


def _check_osqp_settings(settings: Any) -> dict[str, Any]:
    merged = dict(DEFAULT_OSQP_SETTINGS)
    if settings is None:
        return merged
    if not isinstance(settings, dict):
        raise ValueError(
            f"osqp_settings = {settings!r:.80} must be a dict of OSQP settings (e.g. "
            "{'max_iter': 50000}) or None"
        )
    merged.update(settings)
    try:  # let OSQP itself reject unknown names or bad values, on a one-variable problem
        probe = osqp.OSQP()
        one = sp.csc_matrix(np.ones((1, 1)))
        probe.setup(one, np.zeros(1), one, -np.ones(1), np.ones(1), **merged)
    except Exception as exc:  # OSQP raises ValueError/TypeError/OSQPException
        raise ValueError(
            f"osqp_settings = {settings!r:.120} were rejected by OSQP ({exc}); see "
            "https://osqp.org/docs/interfaces/solver_settings.html for the valid names"
        ) from None
    return merged


def _act_info(nu, rho, cost, status: str, path: str, inside: bool, Pi: np.ndarray) -> dict:
    """The ``info`` dict of :meth:`RecedingHorizonController.act` (keys documented there)."""
    return {
        "nu": np.array(nu, dtype=np.float64),
        "rho": float(rho),
        "cost": float(cost),
        "status": status,
        "solver": path,
        "in_region": inside,
        "Pi": Pi,
    }


@dataclass(frozen=True, eq=False)
class _Family:
    """P3 for one ``(mode, x_k in C1)`` pair: ``Pi`` and every matrix of the QP are fixed.

    With ``u = K x + nu`` the objective of P3 expands to (eq. eq:exp_noise, Lemma 1)::

        J = x'C x + tr(Pi E W E') + nu'H_nu nu + g'nu + alpha rho,
        C = Q + K'RK + Atilde'Pi Atilde,   H_nu = R + B'Pi B,   g = 2 (R K + B'Pi Atilde) x

    and the constraint rows are ``G Atilde x + G B nu - rho <= H_{k+1} - t``.

    For the single-state path the data ``w = [q; h]`` of :attr:`solver` (linear term and
    one-sided bounds, see :meth:`ActiveSetQP.one_sided_bounds`) are affine in ``x``:
    ``w = W x + w0(k)``; ``lin = [K; W; C]`` gives ``K x``, ``W x`` and ``C x`` in one product.
    """

    mode: int
    inside: bool
    Pi: np.ndarray  # (n, n)
    maps: np.ndarray  # (2m + n + r, n): rows [K; Atilde; 2(RK + B'Pi Atilde); G Atilde]
    C: np.ndarray  # (n, n)
    H_nu: np.ndarray  # (m, m)
    GB: np.ndarray  # (r, m)
    noise_term: float  # tr(Pi E W E')
    P: np.ndarray  # (m+1, m+1) Hessian of the QP in z = (nu, rho), OSQP's 1/2 z'Pz
    A: np.ndarray  # constraint matrix of the QP
    solver: ActiveSetQP | None  # exact batched solver (box U only)
    lin: np.ndarray | None = None  # (m + len(w) + n, n): rows [K; W; C] (box U only)
    w0: np.ndarray | None = None  # w at x = 0 without the band (H_{k+1} - t added per k)
    lo: np.ndarray | None = None  # OSQP lower bounds (constant)
    hi: np.ndarray | None = None  # OSQP upper bounds, the r constraint rows filled per call
    H_list: list = field(default_factory=list)  # H_nu as nested lists (m x m)
    GB_list: list = field(default_factory=list)  # G B as nested lists (r x m)
    offsets: dict = field(default_factory=dict)  # k -> (w0(k), zero tolerance of rho)


@dataclass(frozen=True)
class _Step:
    """Data of P3 for ``B`` states of one family (``B = 1`` for :meth:`act`)."""

    fam: _Family
    x: np.ndarray  # (B, n)
    k: np.ndarray  # (B,)
    Kx: np.ndarray  # (B, m)
    a: np.ndarray  # (B, n)  Atilde x
    g: np.ndarray  # (B, m)  gradient of J in nu at nu = 0
    GAx: np.ndarray  # (B, r)  G Atilde x
    hbar: np.ndarray  # (B, r)  H_{k+1} - t[theta]

    @property
    def mode(self) -> int:
        return self.fam.mode

    @property
    def Pi(self) -> np.ndarray:
        return self.fam.Pi

    @property
    def noise_term(self) -> float:
        return self.fam.noise_term


class RecedingHorizonController(_FeedbackPolicy):
    """One-step receding-horizon control with chance constraints, problem P3 of the paper.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n) array
        Pre-stabilising gains of ``u = K_theta x + nu`` (eq. eq:stabilization_input), e.g. from
        Proposition 2 or ``PAPER_K`` of the macro example.
    Psi : (N, n, n) array
        Terminal weights ``Psi_i``, symmetric positive definite.
    xi : float
        Chance-constraint level, strictly between 0 and 1.
    constraint : {"individual", "joint", "bonferroni"}
        Kind of chance constraint; see :func:`controllers.chance.tightening`.
    alpha : float
        Penalty on the slack ``rho`` (> 0; large, e.g. 1000).
    nu_bound : float
        Size of the set ``U`` of offsets ``nu`` (> 0).
    solver : {"osqp", "cvxpy", "active_set"}
        Fast path with warm-started OSQP, or the cvxpy/Clarabel reference (see module docstring).
    nu_set : {"box", "ball"}
        ``U = {|nu_i| <= nu_bound}`` or ``U = {||nu||_2 <= nu_bound}`` (the same when ``m = 1``).
    horizon : int, optional
        Episode length of the environment; needed only by :meth:`predict`.
    osqp_settings : dict, optional
        Overrides of :data:`DEFAULT_OSQP_SETTINGS` (e.g. ``{"max_iter": 1}`` forces failures).
    cvxpy_fallback : bool
        Whether to try the cvxpy reference when OSQP fails twice before falling back to
        ``nu = 0``.

    Attributes
    ----------
    tightening : (N, r) ndarray
        ``t[i, j]`` of eq. (constraint:det_univariate) / (constraint:chi_square).
    A_tilde : (N, n, n) ndarray
        ``A_i + B_i K_i``.

    Raises
    ------
    ValueError
        Any invalid argument; the message names it, its value and what is expected. Raised
        before any work.
    TypeError
        If ``model`` is not an :class:`SDJLSModel`.

    Notes
    -----
    With ``solver="osqp"`` most calls are answered by the active-set warm start (see the module
    docstring). The private attribute ``_warm_start`` (default True) switches it off: OSQP then
    runs at every call (its answer still re-solved exactly on its active set). The private dict
    ``_path_counts`` counts the calls of :meth:`act` per ``info["solver"]`` value.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro, PAPER_K, PAPER_RHC
    >>> ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    >>> u, info = ctrl.act([2.0, 2.0], 0, 0)
    >>> info["rho"], info["status"]
    (0.0, 'solved')
    """

    _chance_constrained = True

    def __init__(
        self,
        model: SDJLSModel,
        K: np.ndarray,
        Psi: np.ndarray,
        xi: float,
        constraint: str = "individual",
        alpha: float = 1000.0,
        nu_bound: float = 100.0,
        solver: str = "osqp",
        nu_set: str = "box",
        horizon: int | None = None,
        osqp_settings: dict[str, Any] | None = None,
        cvxpy_fallback: bool = True,
    ) -> None:
        self._init_common(
            model, K, Psi, alpha, nu_bound, solver, nu_set, horizon, osqp_settings, cvxpy_fallback
        )
        self.xi = _check_xi(xi)
        self.constraint = _check_constraint(constraint)
        self.tightening = tightening(self.model, self.xi, self.constraint)
        self.tightening.setflags(write=False)

    def _init_common(
        self,
        model: SDJLSModel,
        K: Any,
        Psi: Any,
        alpha: Any,
        nu_bound: Any,
        solver: Any,
        nu_set: Any,
        horizon: Any,
        osqp_settings: Any,
        cvxpy_fallback: Any,
    ) -> None:
        super().__init__(model, horizon)
        model = self.model
        self.K = _check_gain(model, K)
        self.Psi = _check_Psi(model, Psi)
        self.alpha = _check_positive("alpha", alpha, "penalty on the slack rho")
        self.nu_bound = _check_positive("nu_bound", nu_bound, "size of the set U of offsets nu")
        self.solver = _check_choice("solver", solver, SOLVERS)
        self.nu_set = _check_choice("nu_set", nu_set, NU_SETS)
        self.osqp_settings = _check_osqp_settings(osqp_settings)
        if not isinstance(cvxpy_fallback, (bool, np.bool_)):
            raise ValueError(f"cvxpy_fallback = {cvxpy_fallback!r:.60} must be True or False")
        self.cvxpy_fallback = bool(cvxpy_fallback)
        self.A_tilde = model.A + model.B @ self.K  # eq. (sys:stabilized_input)
        self.A_tilde.setflags(write=False)
        self._osqp: dict[tuple[int, bool], osqp.OSQP] = {}
        self._families: dict[tuple[int, bool], _Family] = {}
        self.tightening: np.ndarray | None = None
        # single-state QP path of act(): the box U (or m = 1), solved by OSQP or enumeration
        self._qp_path = self.solver in ("osqp", "active_set") and not self._uses_socp
        #: active-set warm start of the OSQP path (see the module docstring); False: OSQP at
        #: every call
        self._warm_start = True
        self._warm: dict[tuple[int, bool], int] = {}  # family -> candidate of the last solution
        #: how many act() calls each path (info["solver"]) answered
        self._path_counts: dict[str, int] = {}
        self._x_shape = (model.n,)

    # ------------------------------------------------------------------ problem data
    @property
    def _uses_socp(self) -> bool:
        """``||nu||_2 <= nu_bound`` with m > 1 is not a QP: solved with cvxpy + Clarabel."""
        return self.nu_set == "ball" and self.model.m > 1

    def _family(self, mode: int, inside: bool) -> _Family:
        """The QP family of ``(mode, inside)``, built on first use and cached."""
        key = (mode, inside)
        fam = self._families.get(key)
        if fam is not None:
            return fam
        model, m, r = self.model, self.model.m, self.model.r
        P_row = (model.P_in if inside else model.P_out)[mode]  # eq. (eq:p_tran)
        Pi = np.einsum("j,jab->ab", P_row, self.Psi)  # eq. (eq:exp_noise)
        Pi = 0.5 * (Pi + Pi.T)
        K, At, Bm, R = self.K[mode], self.A_tilde[mode], model.B[mode], model.R[mode]
        H_nu = R + Bm.T @ Pi @ Bm
        C = model.Q[mode] + K.T @ R @ K + At.T @ Pi @ At
        grad = 2.0 * (R @ K + Bm.T @ Pi @ At)
        P = np.zeros((m + 1, m + 1))
        P[:m, :m] = H_nu + H_nu.T  # 0.5 z'P z = nu'(R + B'Pi B) nu
        rows = []
        if self._chance_constrained:
            rows.append(np.hstack([model.G @ Bm, -np.ones((r, 1))]))  # G B nu - rho
        rows.append(np.hstack([np.eye(m), np.zeros((m, 1))]))  # nu in the box U
        rows.append(np.hstack([np.zeros((1, m)), np.ones((1, 1))]))  # rho >= 0
        A = np.vstack(rows)
        lo, hi = self._bounds(np.zeros((1, r)))
        qp = None if self._uses_socp else ActiveSetQP(P, A, np.isfinite(lo[0]), np.isfinite(hi[0]))
        fast: dict[str, Any] = {}
        if qp is not None:
            # w = [q; h] = W x + w0(k): q = (g, alpha) with g = grad x; the first r one-sided
            # rows are the constraint rows, h = H_{k+1} - t - G Atilde x (the rest is constant)
            d, n = m + 1, model.n
            W = np.zeros((d + qp.C.shape[0], n))
            W[:m] = grad
            alpha = self.alpha if self._chance_constrained else 0.0
            w0 = np.concatenate([np.zeros(m), [alpha], qp.one_sided_bounds(lo, hi)[0]])
            if self._chance_constrained:
                W[d : d + r] = -model.G @ At  # eq. (constraint:feasibility)
            fast = {
                "lin": np.vstack([K, W, C]),
                "w0": w0,
                "lo": lo[0],
                "hi": hi[0],
                "H_list": H_nu.tolist(),
                "GB_list": (model.G @ Bm).tolist(),
            }
        fam = _Family(
            mode=mode,
            inside=inside,
            Pi=Pi,
            maps=np.vstack([K, At, grad, model.G @ At]),
            C=C,
            H_nu=H_nu,
            GB=model.G @ Bm,
            noise_term=float(np.trace(Pi @ model.noise_cov[mode])),  # Lemma 1, eq. (eq:lemm1)
            P=P,
            A=A,
            solver=qp,
            **fast,
        )
        self._families[key] = fam
        return fam

    def _offset(self, fam: _Family, k: int) -> tuple[np.ndarray, float]:
        """``w0(k)`` of the family at time ``k`` and the zero tolerance of ``rho`` (cached)."""
        if len(fam.offsets) >= _MAX_OFFSETS:
            fam.offsets.clear()
        w0, zero_tol = fam.w0.copy(), 0.0
        if self._chance_constrained:
            d, r = self.model.m + 1, self.model.r
            # eq. (constraint:feasibility): the constraint is on x_{k+1}, band H_{k+1}
            hbar = self.model.H(k + 1) - self.tightening[fam.mode]
            w0[d : d + r] += hbar
            zero_tol = _RHO_ZERO_TOL * max(1.0, float(np.max(np.abs(hbar))))
        w0.setflags(write=False)
        out = fam.offsets[k] = (w0, zero_tol)
        return out

    def _data(self, fam: _Family, x: np.ndarray, k: np.ndarray) -> _Step:
        """P3's state-dependent data for states ``x`` (B, n) of one family at times ``k`` (B,)."""
        m, n = self.model.m, self.model.n
        y = x @ fam.maps.T
        if self._chance_constrained:
            # eq. (constraint:feasibility): the constraint is on x_{k+1}, band H_{k+1}
            hbar = self.model.H(k + 1) - self.tightening[fam.mode]
        else:
            hbar = np.zeros((x.shape[0], self.model.r))  # unused: no chance constraints
        return _Step(
            fam=fam,
            x=x,
            k=k,
            Kx=y[:, :m],
            a=y[:, m : m + n],
            g=y[:, m + n : 2 * m + n],
            GAx=y[:, 2 * m + n :],
            hbar=hbar,
        )

    def _step(self, x: np.ndarray, mode: int, k: int) -> _Step:
        inside = max(self.model.constraint_values_one(x, k).tolist()) <= 0.0  # in C1 at time k
        return self._data(self._family(mode, inside), x[None], np.array([k]))

    def _bounds(self, upper_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``l, u`` (B, rows) of the QP in OSQP form, given the right sides of the rows."""
        size, m, nb = upper_rows.shape[0], self.model.m, self.nu_bound
        lo = [np.full((size, m), -nb), np.zeros((size, 1))]
        hi = [
            np.full((size, m), nb),
            np.full((size, 1), np.inf if self._chance_constrained else 0.0),
        ]
        if self._chance_constrained:
            lo.insert(0, np.full(upper_rows.shape, -np.inf))
            hi.insert(0, upper_rows)
        return np.hstack(lo), np.hstack(hi)

    def _min_rho(self, d: _Step, nu: np.ndarray) -> np.ndarray:
        """Smallest ``rho >= 0`` (B,) that makes ``nu`` (B, m) feasible in eq. (constraint:feasibility)."""
        if not self._chance_constrained:
            return np.zeros(nu.shape[0])
        excess = max_last(d.GAx + nu @ d.fam.GB.T - d.hbar)
        # round-off on an active row (|excess| ~ 1e-15) is not a use of the slack: report 0
        zero = excess <= _RHO_ZERO_TOL * np.maximum(1.0, max_last(np.abs(d.hbar)))
        return np.where(zero, 0.0, excess)

    def _objective(self, d: _Step, nu: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """``J_k`` (B,) of P3 at ``(nu, rho)``, every constant term included (see :class:`_Family`)."""
        fam = d.fam
        return (
            np.sum((d.x @ fam.C) * d.x, axis=1)
            + fam.noise_term
            + np.sum((nu @ fam.H_nu) * nu, axis=1)
            + np.sum(d.g * nu, axis=1)
            + self.alpha * rho
        )

    def _project_nu(self, nu: np.ndarray) -> np.ndarray:
        """Remove solver round-off outside ``U``; ``nu`` (..., m)."""
        if self.nu_set == "ball" and self.model.m > 1:
            norm = np.linalg.norm(nu, axis=-1, keepdims=True)
            return nu * np.minimum(1.0, self.nu_bound / np.maximum(norm, 1e-300))
        return np.clip(nu, -self.nu_bound, self.nu_bound)

    def _osqp_vectors(
        self, fam: _Family, w: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``q, l, u`` of the QP in OSQP form from the fast path's ``w = [q; h]`` (one state)."""
        d, r = self.model.m + 1, self.model.r
        hi = fam.hi
        if self._chance_constrained:
            hi = hi.copy()
            hi[:r] = w[d : d + r]  # H_{k+1} - t - G Atilde x, eq. (constraint:feasibility)
        return w[:d].copy(), fam.lo, hi

    def _run_osqp(
        self, fam: _Family, q: np.ndarray, lo: np.ndarray, hi: np.ndarray, retry: bool
    ) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        """Solve with OSQP; return ``(z, y, status)`` (``y`` the multipliers), None on failure."""
        key = (fam.mode, fam.inside)
        try:
            if retry or key not in self._osqp:
                settings = dict(self.osqp_settings)
                if retry:
                    settings["max_iter"] = 10 * int(settings["max_iter"])
                solver = osqp.OSQP()
                P, A = sp.csc_matrix(np.triu(fam.P)), sp.csc_matrix(fam.A)
                solver.setup(P, q, A, lo, hi, **settings)
                if not retry:
                    self._osqp[key] = solver
            else:
                # update() ignores data that OSQP's validation rejects (l > u once the bounds are
                # clipped to +-OSQP_INFTY, e.g. for a huge state) and would then solve the
                # previous problem again: fail as setup() does instead
                if not np.all(np.maximum(lo, -_OSQP_INFTY) <= np.minimum(hi, _OSQP_INFTY)):
                    raise ValueError("bounds rejected by OSQP (l > u after clipping)")
                solver = self._osqp[key]
                solver.update(q=q, l=lo, u=hi)
            res = solver.solve(raise_error=False)
        except Exception as exc:  # noqa: BLE001 - an episode must not crash on a solver error
            self._osqp.pop(key, None)
            return None, None, f"error {type(exc).__name__}: {exc}"
        z = np.asarray(res.x, dtype=np.float64)
        status = str(res.info.status)
        if res.info.status_val != osqp.SolverStatus.OSQP_SOLVED or not np.all(np.isfinite(z)):
            self._osqp.pop(key, None)  # do not warm start from a failed iterate
            return None, None, status
        return z, np.asarray(res.y, dtype=np.float64), status

    # ------------------------------------------------------------------ cvxpy reference
    def _run_cvxpy(self, step: _Step) -> tuple[np.ndarray | None, float, float, str]:
        """P3 written plainly with cvxpy, solved by Clarabel; ``(nu, rho, value, status)``."""
        import cvxpy as cp

        model, mode = self.model, step.mode
        nu = cp.Variable(model.m)
        u = step.Kx[0] + nu  # eq. (eq:stabilization_input)
        mean_next = step.a[0] + model.B[mode] @ nu  # E[x_{k+1} | F_k], eq. (sys:stabilized_input)
        x = step.x[0]
        objective = (
            float(x @ model.Q[mode] @ x)
            + cp.quad_form(u, model.R[mode])
            + cp.quad_form(mean_next, step.Pi)
            + step.noise_term
        )
        constraints = []
        if self.nu_set == "ball":
            constraints.append(cp.norm(nu, 2) <= self.nu_bound)
        else:
            constraints.append(cp.abs(nu) <= self.nu_bound)
        rho = None
        if self._chance_constrained:
            rho = cp.Variable(nonneg=True)
            objective = objective + self.alpha * rho
            constraints.append(
                model.G @ mean_next <= step.hbar[0] + rho
            )  # eq. (constraint:feasibility)
        problem = cp.Problem(cp.Minimize(objective), constraints)
        try:
            problem.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
        except Exception as exc:  # noqa: BLE001 - an episode must not crash on a solver error
            return None, np.nan, np.nan, f"error {type(exc).__name__}: {exc}"
        status = str(problem.status)
        nu_val = None if nu.value is None else np.asarray(nu.value, dtype=np.float64).reshape(-1)
        rho_val = 0.0 if rho is None else (np.nan if rho.value is None else float(rho.value))
        value = np.nan if problem.value is None else float(problem.value)
        ok = (
            status == cp.OPTIMAL
            and nu_val is not None
            and np.all(np.isfinite(nu_val))
            and np.isfinite(rho_val)
            and np.isfinite(value)
        )
        return (nu_val if ok else None), rho_val, value, status

    # ------------------------------------------------------------------ decision
    def _solve(self, step: _Step) -> tuple[np.ndarray, float, float, str, str]:
        """``(nu, rho, cost, status, path)`` of P3 with cvxpy (``solver="cvxpy"``, or the
        second-order cone program of ``nu_set="ball"``), never raising, never NaN."""
        if self.solver == "cvxpy":
            nu, rho, value, status = self._run_cvxpy(step)
            if nu is not None:  # the plain reference: values exactly as the solver returned them
                return nu, rho, value, "solved", "cvxpy"
            return self._nu_zero(step, [f"cvxpy status {status!r}"])
        return self._rescue(step, [])

    def _rescue(self, step: _Step, notes: list[str]) -> tuple[np.ndarray, float, float, str, str]:
        """The end of the fallback chain: the cvxpy reference (unless ``cvxpy_fallback=False``;
        always for the second-order cone program), then ``nu = 0``."""
        if self._uses_socp or self.cvxpy_fallback:
            nu, _, _, status = self._run_cvxpy(step)
            path = "cvxpy_socp" if self._uses_socp else "cvxpy"
            if nu is not None:
                text = "solved" if not notes else f"solved by cvxpy ({'; '.join(notes)})"
                return self._finish(step, nu, text, path)
            notes.append(f"cvxpy status {status!r}")
        else:
            notes.append("cvxpy retry disabled")
        return self._nu_zero(step, notes)

    def _nu_zero(self, step: _Step, notes: list[str]) -> tuple[np.ndarray, float, float, str, str]:
        """Last resort: ``nu = 0`` (in U) with the smallest feasible slack."""
        nu = np.zeros(self.model.m)
        rho = float(self._min_rho(step, nu[None])[0])
        return (
            nu,
            rho,
            float(self._objective(step, nu[None], np.array([rho]))[0]),
            "fallback_nu0: " + "; ".join(notes),
            "fallback",
        )

    def _finish(self, step: _Step, nu: np.ndarray, status: str, path: str) -> tuple:
        nu = self._project_nu(np.asarray(nu, dtype=np.float64))
        rho = self._min_rho(step, nu[None])  # the optimal rho for this nu (alpha > 0)
        return nu, float(rho[0]), float(self._objective(step, nu[None], rho)[0]), status, path

    def _check_inputs(self, x: Any, mode: Any, k: Any) -> tuple[np.ndarray, int, int]:
        """The checks of the base class, with a shortcut for the common case: ``x`` a finite
        float64 ``(n,)`` array (used as is, not copied), ``mode`` and ``k`` Python or numpy
        ints in range. Anything else goes through the full checks (same errors)."""
        if (
            type(x) is np.ndarray
            and x.dtype is _FLOAT64
            and x.shape == self._x_shape
            and type(mode) in _INT_TYPES
            and type(k) in _INT_TYPES
            and 0 <= mode < self.model.N
            and k >= 0
            and all(-MAX_STATE <= v <= MAX_STATE for v in x.tolist())  # False for NaN
        ):
            return x, int(mode), int(k)
        return super()._check_inputs(x, mode, k)

    def _exact(
        self,
        fam: _Family,
        x: np.ndarray,
        y: list[float],
        w: np.ndarray,
        zero_tol: float,
        z: list[float],
    ) -> tuple[list[float], float, float]:
        """``(nu, rho, cost)`` from the exact solution ``z`` of a verified active set.

        A function of ``(x, k, z)`` and the family only (plain float arithmetic on the data of
        the single-state path), so the answer does not depend on which path found ``z``.
        ``rho`` is the smallest feasible slack for ``nu`` (eq. constraint:feasibility) and the
        cost ``J_k`` has every constant term (see :class:`_Family`).
        """
        m, nb = self.model.m, self.nu_bound
        nu = [min(max(v, -nb), nb) for v in z[:m]]  # round-off outside U
        wl = w.tolist()
        rho = 0.0
        if self._chance_constrained:
            # eq. (constraint:feasibility): G B nu - rho <= h, h = H_{k+1} - t - G Atilde x
            h = wl[m + 1 : m + 1 + len(fam.GB_list)]
            excess = max(
                sum(map(mul, row, nu)) - hj for row, hj in zip(fam.GB_list, h, strict=True)
            )
            # round-off on an active row is not a use of the slack: report 0
            rho = 0.0 if excess <= zero_tol else excess
        xCx = sum(map(mul, x.tolist(), y[m + len(wl) :]))  # y = [K x; W x; C x]
        nuHnu = sum(v * sum(map(mul, row, nu)) for v, row in zip(nu, fam.H_list, strict=True))
        cost = xCx + fam.noise_term + nuHnu + sum(map(mul, wl[:m], nu)) + self.alpha * rho
        return nu, rho, cost

    def _act_qp(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """:meth:`act` for the box ``U`` with ``solver="osqp"`` or ``"active_set"``.

        Warm start (OSQP path): the remembered active set of the family, verified exactly;
        then OSQP (warm started), its active set re-solved exactly and verified, else the
        enumeration, else OSQP's iterate; then the fallback chain of :meth:`_rescue`.
        """
        m = self.model.m
        inside = max(self.model.constraint_values_one(x, k).tolist()) <= 0.0  # in C1 at time k
        key = (mode, inside)
        fam = self._families.get(key) or self._family(mode, inside)
        y = fam.lin @ x  # [K x; W x; C x]
        w0, zero_tol = fam.offsets.get(k) or self._offset(fam, k)
        w = y[m : m + w0.shape[0]] + w0  # [q; h] of the family's ActiveSetQP
        qp = fam.solver
        notes: list[str] = []
        answer: tuple | None = None
        if self.solver == "osqp":
            candidate = self._warm.get(key) if self._warm_start else None
            if candidate is not None:
                z = qp.verify(candidate, w, strict=True)  # the last active set, re-solved
                if z is not None:
                    answer = (
                        *self._exact(fam, x, y.tolist(), w, zero_tol, z),
                        "solved",
                        "active_set_warm",
                    )
        else:  # "active_set": enumeration at every call
            candidate, z = qp.solve_one(w)
            if z is not None:
                answer = (*self._exact(fam, x, y.tolist(), w, zero_tol, z), "solved", "active_set")
            else:
                notes.append("active-set enumeration found no KKT point")
        if answer is None:
            answer = self._osqp_answer(fam, key, x, k, y, w, zero_tol, notes)
        nu, rho, cost, status, path = answer
        u = y[:m] + nu  # eq. (eq:stabilization_input)
        return u, _act_info(nu, rho, cost, status, path, inside, fam.Pi)

    def _osqp_answer(
        self,
        fam: _Family,
        key: tuple[int, bool],
        x: np.ndarray,
        k: int,
        y: np.ndarray,
        w: np.ndarray,
        zero_tol: float,
        notes: list[str],
    ) -> tuple:
        """OSQP (then its cold retry) with the exact re-solve of the active set it identified;
        the fallback chain if both fail. Returns ``(nu, rho, cost, status, path)``."""
        m, qp = self.model.m, fam.solver
        q, lo, hi = self._osqp_vectors(fam, w)
        for retry in (False, True):
            z, dual, status = self._run_osqp(fam, q, lo, hi, retry)
            if z is None:
                notes.append(f"osqp {'retry ' if retry else ''}status {status!r}")
                continue
            text = f"solved ({'; '.join(notes)}; retried)" if retry else "solved"
            path = "osqp_retry" if retry else "osqp"
            candidate = qp.candidate_from_duals(dual, lo, hi)
            exact = None if candidate is None else qp.verify(candidate, w, strict=True)
            if exact is None:  # OSQP's active set does not verify: enumerate them all
                candidate, exact = qp.solve_one(w)
                path = "active_set"
            if exact is not None:
                self._warm[key] = candidate
                return (*self._exact(fam, x, y.tolist(), w, zero_tol, exact), text, path)
            step = self._data(fam, x[None], np.array([k]))  # no KKT point: OSQP's iterate
            return self._finish(step, z[:m], text, "osqp_retry" if retry else "osqp")
        return self._rescue(self._data(fam, x[None], np.array([k])), notes)

    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """Solve P3 at ``(x_k, theta_k, k)`` and return ``u_k = K_theta x_k + nu_k``.

        Parameters
        ----------
        x : (n,) array
            Current state ``x_k``.
        mode : int
            Current mode ``theta_k`` in ``[0, N)``.
        k : int
            Current time ``k >= 0`` (the constraint uses the band ``H_{k+1}``).

        Returns
        -------
        u : (m,) float64 array
        info : dict
            ``"nu"`` (m,), ``"rho"`` (float), ``"cost"`` (``J*_k`` with every constant term),
            ``"status"`` (``"solved"``, or a description of the retries / fallback),
            ``"solver"`` (which path produced the answer: ``"active_set_warm"``, ``"osqp"``,
            ``"osqp_retry"``, ``"active_set"``, ``"cvxpy"``, ``"cvxpy_socp"`` or
            ``"fallback"``), ``"in_region"`` (``x_k`` in C1), ``"Pi"`` (n, n).

        Raises
        ------
        ValueError
            If ``x`` is not a finite ``(n,)`` vector, ``mode`` is out of range or ``k < 0``.
        """
        x, mode, k = self._check_inputs(x, mode, k)
        if self._qp_path:
            u, info = self._act_qp(x, mode, k)
        else:
            step = self._step(x, mode, k)
            nu, rho, cost, status, path = self._solve(step)
            u = step.Kx[0] + nu  # eq. (eq:stabilization_input)
            info = _act_info(nu, rho, cost, status, path, step.fam.inside, step.Pi)
        counts = self._path_counts
        counts[info["solver"]] = counts.get(info["solver"], 0) + 1
        return np.asarray(u, dtype=np.float64), info

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray | int
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Solve P3 for a batch of states at once, with no Python loop over the batch.

        The states are grouped by family ``(mode, x_k in C1)``; each family's QP has fixed
        matrices, and is solved exactly for the whole group by
        :class:`controllers.active_set.ActiveSetQP` (enumeration of the candidate active sets,
        built once per family and cached). The rare instance that no candidate settles, and
        every instance when ``nu_set="ball"`` with ``m > 1``, goes through :meth:`act` (OSQP
        and its fallbacks). The answers equal those of :meth:`act` up to solver tolerance.

        Parameters
        ----------
        x : (B, n) array
        mode : (B,) int array
        k : (B,) int array or int

        Returns
        -------
        u : (B, m) float64 array
        info : dict of arrays
            ``"nu"`` (B, m), ``"rho"`` (B,), ``"cost"`` (B,) (J*_k), ``"status"`` (B,) str
            objects, ``"ok"`` (B,) bool (False where the last resort ``nu = 0`` was used; an
            OSQP retry or a cvxpy rescue is optimal and counts as ok), ``"in_region"`` (B,).
        """
        x, mode, k = self._check_batch_inputs(x, mode, k)
        if self._uses_socp or self.solver == "cvxpy":
            return super().act_batch(x, mode, k)
        model = self.model
        size, m, r = x.shape[0], model.m, model.r
        d = m + 1
        inside = model.in_region(x, k)
        status = np.full(size, "solved", dtype=object)
        ok = np.ones(size, dtype=bool)
        # the states sorted by family (mode, inside): every family is a contiguous slice
        family = mode * 2 + inside
        # (a stable radix sort on small ints; np.take is much faster than x[order] here)
        order = np.argsort(family.astype(np.int8 if model.N < 64 else np.int64), kind="stable")
        counts = np.bincount(family, minlength=2 * model.N).tolist()
        xs, ks = np.take(x, order, axis=0), np.take(k, order)
        u_s, nu_s = np.empty((size, m)), np.empty((size, m))
        rho_s, cost_s = np.empty(size), np.empty(size)
        start = 0
        for key, count in enumerate(counts):
            if not count:
                continue
            stop = start + count
            fam = self._family(key // 2, bool(key % 2))
            step = self._data(fam, xs[start:stop], ks[start:stop])
            wT = np.empty((fam.w0.shape[0], count))  # [q; h] of the family's ActiveSetQP
            wT[:] = fam.w0[:, None]
            wT[:m] = step.g.T
            if self._chance_constrained:
                wT[d : d + r] = (step.hbar - step.GAx).T
            w = wT.T  # (count, d + c1), a view
            z, found = fam.solver.solve(w)  # w = [q; h]
            nu_f = self._project_nu(
                z[:, :m] if found.all() else np.where(found[:, None], z[:, :m], 0.0)
            )
            for j in np.flatnonzero(~found).tolist():  # not settled: the single-state path
                i = int(order[start + j])
                _, info_j = self.act(x[i], int(mode[i]), int(k[i]))
                nu_f[j], status[i] = info_j["nu"], info_j["status"]
                ok[i] = not info_j["status"].startswith("fallback")
            rho_f = self._min_rho(step, nu_f)  # the optimal rho for this nu (alpha > 0)
            nu_s[start:stop], rho_s[start:stop] = nu_f, rho_f
            cost_s[start:stop] = self._objective(step, nu_f, rho_f)
            np.add(step.Kx, nu_f, out=u_s[start:stop])  # eq. (eq:stabilization_input)
            start = stop
        back = np.empty(size, dtype=np.intp)  # the inverse permutation of order
        back[order] = np.arange(size)
        u, nu = np.take(u_s, back, axis=0), np.take(nu_s, back, axis=0)
        rho, cost = np.take(rho_s, back), np.take(cost_s, back)
        info = {"nu": nu, "rho": rho, "cost": cost, "status": status, "ok": ok, "in_region": inside}
        return u, info


class UnconstrainedRecedingHorizonController(RecedingHorizonController):
    """Problem P3 without the chance constraints: only ``nu in U`` (``rho = 0`` always).

    Same parameters as :class:`RecedingHorizonController` minus ``xi`` and ``constraint``;
    ``alpha`` is accepted for symmetry and has no effect.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro, PAPER_K, PAPER_RHC
    >>> ctrl = UnconstrainedRecedingHorizonController(macro(), PAPER_K, PAPER_RHC["Psi"])
    >>> ctrl.act([2.0, 2.0], 0, 0)[1]["rho"]
    0.0
    """

    _chance_constrained = False

    def __init__(
        self,
        model: SDJLSModel,
        K: np.ndarray,
        Psi: np.ndarray,
        alpha: float = 1000.0,
        nu_bound: float = 100.0,
        solver: str = "osqp",
        nu_set: str = "box",
        horizon: int | None = None,
        osqp_settings: dict[str, Any] | None = None,
        cvxpy_fallback: bool = True,
    ) -> None:
        self._init_common(
            model, K, Psi, alpha, nu_bound, solver, nu_set, horizon, osqp_settings, cvxpy_fallback
        )
        self.xi = None
        self.constraint = None
