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
    family is a :class:`controllers.qp.QPFamily`: the active set of its last solution is re-solved
    exactly and kept if it passes the KKT test (``info["solver"] == "active_set_warm"``);
    otherwise OSQP (set up once per family, then only updated and warm-started) finds the
    optimum and the active set it identifies is re-solved exactly and verified
    (``"osqp"``); if that fails, the candidate active sets are enumerated (``"active_set"``).
    Every answer is the exact solution of a verified active set, so it does not depend on the
    call history (except in degenerate problems, where several active sets verify). The KKT
    test and the report ``rho = 0`` use tolerances relative to the scale of each row (see
    :mod:`controllers.qp`). With ``nu_set="ball"`` and ``m > 1`` OSQP cannot express
    ``||nu||_2 <= nu_bound``; the controller then solves the second-order cone program with
    cvxpy + Clarabel instead.
``solver="cvxpy"``
    The plain formulation written with cvxpy and solved by Clarabel, rebuilt at every call; a
    reference for checking the fast path. Its answer is verified like every other: the active
    set it identifies is re-solved exactly and must pass the engine's KKT test ("solved"), else
    it is returned as "unverified" (``ok`` False) with the smallest feasible ``rho`` for its
    offset.
``solver="active_set"``
    Exact solution by enumeration of the candidate active sets at every call (no warm start),
    for families small enough to enumerate (:data:`controllers.qp.MAX_CANDIDATES`).
    :meth:`RecedingHorizonController.act_batch` uses the enumeration whenever the family is
    small enough, and :meth:`act` for each state otherwise.

An episode never crashes on a solver failure: after OSQP (and a cold retry) and the
enumeration, the cvxpy reference is tried (unless ``cvxpy_fallback=False``) and its active set
verified, and as a last resort ``nu = 0`` with the smallest feasible ``rho``. ``info["status"]``
says what happened: ``"solved"`` means the answer was verified optimal.

Limits: ``alpha`` and ``nu_bound`` up to :data:`MAX_ALPHA` and :data:`MAX_NU_BOUND` (answers are
verified optimal to ~1e-8 relative in ``J*`` over the whole range); the matrices of the QP
(from ``Psi``, ``K`` and the model's ``Q``, ``R``, ``G``) up to :data:`MAX_QP_ENTRY` in magnitude.
"""

from __future__ import annotations

from operator import mul
from typing import Any

import numpy as np

from sdjls_gym.dynamics import max_last
from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import (
    MAX_INDEX,
    check_bool,
    check_choice,
    check_number,
)

from .base import MAX_STATE, Controller, check_gain, check_terminal_weights
from .chance import CONSTRAINT_KINDS, check_xi, tightening
from .p3 import Family, build_family, check_magnitudes, solve_p3_cvxpy
from .qp import DEFAULT_OSQP_SETTINGS, KKT_TOL, EnumerationBudget, Solution, check_osqp_settings

__all__ = [
    "DEFAULT_OSQP_SETTINGS",
    "RecedingHorizonController",
    "UnconstrainedRecedingHorizonController",
]

SOLVERS = ("osqp", "cvxpy", "active_set")
NU_SETS = ("box", "ball")

#: Largest slack penalty ``alpha`` and offset bound ``nu_bound`` accepted: up to these, answers
#: are verified optimal (tests/test_scale.py). Beyond, a unit of slack outweighs the band so much
#: that float64 cannot resolve both in one objective.
MAX_ALPHA = 1e12
MAX_NU_BOUND = 1e12


def check_slack_and_offsets(alpha: Any, nu_bound: Any) -> tuple[float, float]:
    """``(alpha, nu_bound)``, each a number in ``(0, 1e12]`` (:data:`MAX_ALPHA`,
    :data:`MAX_NU_BOUND`), for every receding-horizon controller."""
    alpha = check_number(
        "alpha", alpha, low=0.0, low_open=True, high=MAX_ALPHA, what="penalty on the slack rho"
    )
    nu_bound = check_number(
        "nu_bound",
        nu_bound,
        low=0.0,
        low_open=True,
        high=MAX_NU_BOUND,
        what="size of the set U of offsets nu",
    )
    return alpha, nu_bound


#: Largest entry of the QP's matrices (see :func:`controllers.p3.check_magnitudes`).
MAX_QP_ENTRY = 1e100

#: Types accepted without conversion by the fast input check of ``act`` (bool is not among them).
_INT_TYPES = frozenset([int] + [np.dtype(c).type for c in np.typecodes["AllInteger"]])
_FLOAT64 = np.dtype(np.float64)

#: Cached offsets ``w0(k)`` per family before the cache is cleared (k is unbounded).
_MAX_OFFSETS = 4096

_PATHS = {"warm": "active_set_warm", "osqp": "osqp", "osqp_retry": "osqp_retry"}


class RecedingHorizonController(Controller):
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
        Penalty on the slack ``rho``, in ``(0, 1e12]`` (large, e.g. 1000).
    nu_bound : float
        Size of the set ``U`` of offsets ``nu``, in ``(0, 1e12]``.
    solver : {"osqp", "cvxpy", "active_set"}
        Fast path with warm-started OSQP, the cvxpy/Clarabel reference, or enumeration (see the
        module docstring).
    nu_set : {"box", "ball"}
        ``U = {|nu_i| <= nu_bound}`` or ``U = {||nu||_2 <= nu_bound}`` (the same when ``m = 1``).
    horizon : int, optional
        Episode length of the environment; used only by :meth:`predict` (default: the
        environments' default, 20).
    osqp_settings : dict, optional
        Overrides of :data:`DEFAULT_OSQP_SETTINGS` (e.g. ``{"max_iter": 1}`` forces failures).
    cvxpy_fallback : bool
        Whether to try the cvxpy reference when OSQP and the enumeration fail, before falling
        back to ``nu = 0``.

    Attributes
    ----------
    tightening : (N, r) ndarray
        ``t[i, j]`` of eq. (constraint:det_univariate) / (constraint:chi_square).
    A_tilde : (N, n, n) ndarray
        ``A_i + B_i K_i``.

    Raises
    ------
    TypeError
        An argument of the wrong type (a string or a bool for a number, a non-model).
    ValueError
        A value out of range, including weights whose QP would exceed
        :data:`MAX_QP_ENTRY`; the message names the argument, its value and what is expected.
        Raised before any work.

    Notes
    -----
    Thread-safe: concurrent calls on one controller are serialized by its lock. Picklable at
    any time (the solver state is rebuilt on use). The private attribute ``_warm_start``
    (default True) switches the warm start off (OSQP at every call); the private dict
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
        super().__init__(model, horizon)
        self.xi = check_xi(xi)
        self.constraint = check_choice("constraint", constraint, CONSTRAINT_KINDS)
        self._init_common(K, Psi, alpha, nu_bound, solver, nu_set, osqp_settings, cvxpy_fallback)

    def _init_common(
        self,
        K: Any,
        Psi: Any,
        alpha: Any,
        nu_bound: Any,
        solver: Any,
        nu_set: Any,
        osqp_settings: Any,
        cvxpy_fallback: Any,
    ) -> None:
        model = self.model
        self.K = check_gain(model, K)
        self.Psi = check_terminal_weights(model, Psi)
        self.alpha, self.nu_bound = check_slack_and_offsets(alpha, nu_bound)
        self.solver = check_choice("solver", solver, SOLVERS)
        self.nu_set = check_choice("nu_set", nu_set, NU_SETS)
        self.osqp_settings = check_osqp_settings(osqp_settings)
        self.cvxpy_fallback = check_bool("cvxpy_fallback", cvxpy_fallback)
        self.A_tilde = model.A + model.B @ self.K  # eq. (sys:stabilized_input)
        self.A_tilde.setflags(write=False)
        self.tightening: np.ndarray | None = None
        if self._chance_constrained:
            self.tightening = tightening(model, self.xi, self.constraint)
            self.tightening.setflags(write=False)
        # every family's matrices, built now so that bad magnitudes fail before any work
        budget = EnumerationBudget()  # the enumerations of all families share one memory budget
        self._families: dict[tuple[int, bool], Family] = {
            (mode, inside): build_family(self, mode, inside, budget)
            for mode in range(model.N)
            for inside in (True, False)
        }
        check_magnitudes(self, self._families.values(), MAX_QP_ENTRY)
        self._qp_path = self.solver in ("osqp", "active_set") and not self._uses_socp
        if self.solver == "active_set" and self._qp_path:
            fam = self._families[(0, True)]
            if not fam.engine.can_enumerate:
                raise ValueError(
                    f"solver = 'active_set' enumerates {fam.engine.n_candidates} candidate active "
                    f"sets per family for m = {model.m}, r = {model.r}, more than the limit "
                    "controllers.qp.MAX_CANDIDATES; use solver='osqp' (exact re-solve of the "
                    "active set OSQP finds)"
                )
        #: active-set warm start of the OSQP path; False: OSQP at every call
        self._warm_start = True
        #: how many act() calls each path (info["solver"]) answered
        self._path_counts: dict[str, int] = {}

    # ------------------------------------------------------------------ problem data
    @property
    def _uses_socp(self) -> bool:
        """``||nu||_2 <= nu_bound`` with m > 1 is not a QP: solved with cvxpy + Clarabel."""
        return self.nu_set == "ball" and self.model.m > 1

    def _offset(self, fam: Family, k: int) -> np.ndarray:
        """``w0(k)`` of the family at time ``k`` (cached)."""
        cache = fam.offsets
        if len(cache) >= _MAX_OFFSETS:
            cache.clear()
        w0 = fam.w0.copy()
        if self._chance_constrained:
            r, d = self.model.r, fam.engine.d
            # eq. (constraint:feasibility): the constraint is on x_{k+1}, band H_{k+1}
            w0[d : d + r] += self.model.H(k + 1) - self.tightening[fam.mode]
        w0.setflags(write=False)
        cache[k] = w0
        return w0

    def _hbar(self, fam: Family, k: np.ndarray) -> np.ndarray:
        """``H_{k+1} - t[theta]`` (B, r): the right side of the rows at times ``k`` (B,)."""
        return self.model.H(k + 1) - self.tightening[fam.mode]

    def _project_nu(self, nu: np.ndarray) -> np.ndarray:
        """Remove solver round-off outside ``U``; ``nu`` (..., m)."""
        if self._uses_socp:
            norm = np.linalg.norm(nu, axis=-1, keepdims=True)
            return nu * np.minimum(1.0, self.nu_bound / np.maximum(norm, 1e-300))
        return np.clip(nu, -self.nu_bound, self.nu_bound)

    def _min_rho(
        self,
        fam: Family,
        x: np.ndarray,
        k: np.ndarray,
        nu: np.ndarray,
        hbar: np.ndarray | None = None,
    ) -> np.ndarray:
        """Smallest ``rho >= 0`` (B,) that makes ``nu`` (B, m) feasible in eq.
        (constraint:feasibility); an excess within round-off of its row's terms is 0.
        ``hbar = H_{k+1} - t`` when the caller has it already."""
        if not self._chance_constrained:
            return np.zeros(nu.shape[0])
        if hbar is None:
            hbar = self._hbar(fam, k)
        GAx, GBnu = x @ fam.GA.T, nu @ fam.GB.T
        excess = GAx + GBnu - hbar
        # round-off of a row's terms is not a use of the slack: a cheap first test with the
        # sizes of the partial sums, then, for the few excesses above it, the terms themselves
        real = excess > KKT_TOL * (np.abs(GAx) + np.abs(GBnu) + np.abs(hbar))
        if real.any():
            i, j = np.nonzero(real)
            terms = (
                np.abs(x[i]) @ np.abs(fam.GA).T + np.abs(nu[i]) @ np.abs(fam.GB).T + np.abs(hbar[i])
            )[np.arange(i.size), j]
            real[i, j] = excess[i, j] > KKT_TOL * terms
        excess = np.where(real, excess, 0.0)
        return np.maximum(max_last(excess), 0.0)

    def _objective(self, fam: Family, x: np.ndarray, nu: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """``J_k`` (B,) of P3 at ``(nu, rho)``, every constant term included (see
        :meth:`_cost_one` for the two ways of writing it)."""
        if fam.expand_cost:
            return (
                np.sum((x @ fam.C) * x, axis=1)
                + fam.noise_term
                + np.sum((nu @ fam.H_nu) * nu, axis=1)
                + np.sum((x @ fam.grad.T) * nu, axis=1)
                + self.alpha * rho
            )
        u = x @ fam.K.T + nu
        mean = x @ fam.A_tilde.T + nu @ fam.B.T
        return (
            np.sum((x @ fam.Q) * x, axis=1)
            + np.sum((u @ fam.R) * u, axis=1)
            + np.sum((mean @ fam.Pi) * mean, axis=1)
            + fam.noise_term
            + self.alpha * rho
        )

    def _answer(
        self, fam: Family, x: np.ndarray, k: int, nu: np.ndarray, status: str, path: str
    ) -> tuple:
        """``(nu, rho, cost, status, path)`` for an offset found by a solver other than the
        exact path: ``nu`` projected on ``U`` and the smallest feasible ``rho``."""
        nu = self._project_nu(np.asarray(nu, dtype=np.float64))
        kk = np.array([k])
        rho = self._min_rho(fam, x[None], kk, nu[None])
        cost = self._objective(fam, x[None], nu[None], rho)
        return nu, float(rho[0]), float(cost[0]), status, path

    # ------------------------------------------------------------------ exact answers
    def _exact(
        self, fam: Family, x: np.ndarray, y: list[float], w: np.ndarray, sol: Solution
    ) -> tuple[list[float], float, float]:
        """``(nu, rho, cost)`` from the exact solution of a verified active set.

        A function of ``(x, k, active set)`` and the family only (plain float arithmetic on the
        data of the single-state path), so the answer does not depend on which path found it.
        ``rho`` is 0 when the bound ``rho >= 0`` is in the active set (the rows then hold to the
        tolerance of the KKT test, relative to each row), else the largest excess of a row
        (eq. constraint:feasibility). The cost ``J_k`` has every constant term.
        """
        m, nb = self.model.m, self.nu_bound
        nu = [min(max(v, -nb), nb) for v in sol.z[:m]]  # round-off outside U
        rho = 0.0
        if self._chance_constrained and fam.rho_row not in sol.rows:
            wl = w.tolist()
            d = m + 1
            h = wl[d : d + len(fam.GB_list)]  # H_{k+1} - t - G Atilde x
            excess = max(
                sum(map(mul, row, nu)) - hj for row, hj in zip(fam.GB_list, h, strict=True)
            )
            rho = max(excess, 0.0)
        return nu, rho, self._cost_one(fam, x.tolist(), y, nu, rho)

    def _cost_one(self, fam: Family, x: list, y: list, nu: list, rho: float) -> float:
        """``J_k`` of P3 for one state, in plain floats from ``y = [K x; W x; Atilde x; Q x]``:
        ``x'Qx + u'Ru + mean'Pi mean + tr(Pi E W E') + alpha rho`` with ``u = K x + nu`` and
        ``mean = Atilde x + B nu``. Expanded in ``nu`` (``x'Cx + nu'H nu + g'nu + ...``, cheaper)
        where the family's terms do not cancel (``fam.expand_cost``), else written with ``u`` and
        ``mean`` themselves, so that large weights do not cancel (a dominant R makes u small)."""
        m, n = self.model.m, self.model.n
        start = len(y) - 2 * n
        if fam.expand_cost:
            xCx = sum(map(mul, x, y[start - n : start]))
            nuHnu = sum(v * sum(map(mul, row, nu)) for v, row in zip(nu, fam.H_list, strict=True))
            g = y[m : 2 * m]  # the first m entries of W x are the gradient
            return xCx + fam.noise_term + nuHnu + sum(map(mul, g, nu)) + self.alpha * rho
        u = [a + b for a, b in zip(y[:m], nu, strict=True)]
        mean = [
            a + sum(map(mul, row, nu))
            for a, row in zip(y[start : start + n], fam.B_list, strict=True)
        ]
        xQx = sum(map(mul, x, y[start + n :]))
        uRu = sum(v * sum(map(mul, row, u)) for v, row in zip(u, fam.R_list, strict=True))
        mPm = sum(v * sum(map(mul, row, mean)) for v, row in zip(mean, fam.Pi_list, strict=True))
        return xQx + uRu + mPm + fam.noise_term + self.alpha * rho

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
            and 0 <= k < MAX_INDEX  # max_k: P3 reads H_{k+1}
            and all(-MAX_STATE <= v <= MAX_STATE for v in x.tolist())  # False for NaN
        ):
            return x, int(mode), int(k)
        return super()._check_inputs(x, mode, k)

    def _act_qp(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """:meth:`act` for the box ``U`` with ``solver="osqp"`` or ``"active_set"``."""
        m = self.model.m
        inside = max(self.model.constraint_values_one(x, k).tolist()) <= 0.0  # in C1 at time k
        fam = self._families[(mode, inside)]
        y, w = self._instance(fam, x, k)
        engine = fam.engine
        notes: list[str] = []
        sol = None
        if self.solver == "active_set":
            sol = engine.enumerate_one(w)
            if sol is None:
                notes.append("no enumerated active set verified")
        if sol is None:
            sol = engine.solve(w, warm=self._warm_start and self.solver == "osqp", notes=notes)
        if sol is not None:
            nu, rho, cost = self._exact(fam, x, y.tolist(), w, sol)
            path = "active_set" if sol.path == "enumeration" else _PATHS[sol.path]
            status = "solved" if not notes else f"solved ({'; '.join(notes)})"
            answer = (nu, rho, cost, status, path)
        else:
            answer = self._rescue(fam, x, k, w, notes)
        nu, rho, cost, status, path = answer
        u = y[:m] + np.asarray(nu)  # eq. (eq:stabilization_input)
        return u, self._info(nu, rho, cost, status, path, fam)

    def _instance(self, fam: Family, x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(y, w)``: ``y = [K x; W x; Atilde x; Q x]`` and the instance ``w = [q; h]``."""
        m = self.model.m
        y = fam.lin @ x
        w0 = fam.offsets.get(k)
        if w0 is None:
            w0 = self._offset(fam, k)
        return y, y[m : m + w0.shape[0]] + w0

    def _rescue(
        self,
        fam: Family,
        x: np.ndarray,
        k: int,
        w: np.ndarray | None,
        notes: list[str],
        always: bool = False,
    ):
        """The end of the fallback chain, and the whole of ``solver="cvxpy"`` (``always``):
        the cvxpy reference (unless ``cvxpy_fallback=False``; always for the second-order cone
        program), its active set verified by the engine's KKT test when it is a QP (else
        "unverified", with its offset and the smallest feasible slack); then ``nu = 0``.
        Returns ``(nu, rho, cost, status, path)``."""
        if self._uses_socp or self.cvxpy_fallback or always:
            nu, _, _, status = solve_p3_cvxpy(self, fam, x, k)
            path = "cvxpy_socp" if self._uses_socp else "cvxpy"
            if nu is not None:
                if self._uses_socp:
                    text = "solved" if not notes else f"solved by cvxpy ({'; '.join(notes)})"
                    return self._answer(fam, x, k, nu, text, path)
                if w is None:
                    w = self._instance(fam, x, k)[1]
                nu = self._project_nu(nu)
                z = np.concatenate([nu, self._min_rho(fam, x[None], np.array([k]), nu[None])])
                sol = fam.engine.local(z, w)
                if sol is not None:
                    y = fam.lin @ x
                    text = "solved" if not notes else f"solved by cvxpy ({'; '.join(notes)})"
                    return (*self._exact(fam, x, y.tolist(), w, sol), text, path)
                notes.append("the cvxpy answer did not verify")
                return self._answer(fam, x, k, nu, "unverified: " + "; ".join(notes), path)
            notes.append(f"cvxpy status {status!r}")
        else:
            notes.append("cvxpy retry disabled")
        return self._answer(
            fam, x, k, np.zeros(self.model.m), "fallback_nu0: " + "; ".join(notes), "fallback"
        )

    def _info(self, nu, rho, cost, status: str, path: str, fam: Family) -> dict[str, Any]:
        """The ``info`` dict of :meth:`act` (keys documented there)."""
        return {
            "nu": np.array(nu, dtype=np.float64),
            "rho": float(rho),
            "cost": float(cost),
            "status": status,
            "solver": path,
            "in_region": fam.inside,
            "Pi": fam.Pi,  # read-only
            "ok": status == "solved" or status.startswith("solved "),
        }

    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """Solve P3 at ``(x_k, theta_k, k)`` and return ``u_k = K_theta x_k + nu_k``.

        Parameters
        ----------
        x : (n,) array
            Current state ``x_k``.
        mode : int
            Current mode ``theta_k`` in ``[0, N)``.
        k : int
            Current time ``k`` in ``[0, 2**53 - 1]`` (the constraint uses the band ``H_{k+1}``).

        Returns
        -------
        u : (m,) float64 array
        info : dict
            ``"nu"`` (m,), ``"rho"`` (float), ``"cost"`` (``J*_k`` with every constant term),
            ``"status"`` (``"solved"`` when the answer was verified optimal; ``"solved (...)"``
            or ``"solved by cvxpy (...)"`` after solver failures, listing them;
            ``"unverified: ..."`` for a cvxpy answer that could not be verified;
            ``"fallback_nu0: ..."`` for the last resort), ``"ok"`` (the answer is verified),
            ``"solver"`` (which path produced the answer: ``"active_set_warm"``, ``"osqp"``,
            ``"osqp_retry"``, ``"active_set"``, ``"cvxpy"``, ``"cvxpy_socp"`` or
            ``"fallback"``), ``"in_region"`` (``x_k`` in C1), ``"Pi"`` (n, n), read-only.

        Raises
        ------
        TypeError
            ``mode`` or ``k`` not an int, ``x`` not numbers.
        ValueError
            ``x`` not a finite ``(n,)`` vector within ``1e100``, ``mode`` out of range or ``k``
            outside ``[0, 2**53 - 1]``.
        """
        x, mode, k = self._check_inputs(x, mode, k)
        with self._lock:
            if self._qp_path:
                u, info = self._act_qp(x, mode, k)
            else:
                inside = max(self.model.constraint_values_one(x, k).tolist()) <= 0.0
                fam = self._families[(mode, inside)]
                answer = self._rescue(fam, x, k, None, [], always=self.solver == "cvxpy")
                nu, rho, cost, status, path = answer
                u = fam.K @ x + nu  # eq. (eq:stabilization_input)
                info = self._info(nu, rho, cost, status, path, fam)
            counts = self._path_counts
            counts[info["solver"]] = counts.get(info["solver"], 0) + 1
        return np.asarray(u, dtype=np.float64), info

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray | int
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Solve P3 for a batch of states at once, with no Python loop over the batch.

        The states are grouped by family ``(mode, x_k in C1)``; each family's QP has fixed
        matrices and is solved exactly for the whole group by the enumeration of
        :class:`controllers.active_set.ActiveSetQP` (built once per family, when the family is
        small enough to enumerate). A state that no candidate settles, every state of a family
        too large to enumerate, and every state when ``nu_set="ball"`` with ``m > 1`` or
        ``solver="cvxpy"``, goes through :meth:`act`. The answers equal those of :meth:`act` up
        to round-off.

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
            objects, ``"ok"`` (B,) bool (the answer was verified optimal), ``"in_region"`` (B,).
        """
        x, mode, k = self._check_batch_inputs(x, mode, k)
        if self._uses_socp or self.solver == "cvxpy":
            return super().act_batch(x, mode, k)
        with self._lock:
            return self._act_batch(x, mode, k)

    def _act_batch(self, x: np.ndarray, mode: np.ndarray, k: np.ndarray) -> tuple:
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
            fam = self._families[(key // 2, bool(key % 2))]
            xf, kf = xs[start:stop], ks[start:stop]
            hbar_f = None
            enum = fam.engine.enumeration()
            if enum is not None:
                wT = np.empty((fam.w0.shape[0], count))  # [q; h] of the family's QP
                wT[:] = fam.w0[:, None]
                wT[:m] = fam.grad @ xf.T
                if self._chance_constrained:
                    hbar_f = self._hbar(fam, kf)
                    wT[d : d + r] = (hbar_f - xf @ fam.GA.T).T
                z, found = enum.solve(wT.T)
                nu_f = self._project_nu(
                    z[:, :m] if found.all() else np.where(found[:, None], z[:, :m], 0.0)
                )
            else:
                nu_f, found = np.zeros((count, m)), np.zeros(count, dtype=bool)
            for j in np.flatnonzero(~found).tolist():  # not settled: the single-state path
                i = int(order[start + j])
                _, info_j = self.act(x[i], int(mode[i]), int(k[i]))
                nu_f[j], status[i], ok[i] = info_j["nu"], info_j["status"], info_j["ok"]
            if hbar_f is None and self._chance_constrained:
                hbar_f = self._hbar(fam, kf)
            rho_f = self._min_rho(fam, xf, kf, nu_f, hbar_f)  # the optimal rho for this nu
            nu_s[start:stop], rho_s[start:stop] = nu_f, rho_f
            cost_s[start:stop] = self._objective(fam, xf, nu_f, rho_f)
            np.add(xf @ fam.K.T, nu_f, out=u_s[start:stop])  # eq. (eq:stabilization_input)
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
        Controller.__init__(self, model, horizon)
        self.xi = None
        self.constraint = None
        self._init_common(K, Psi, alpha, nu_bound, solver, nu_set, osqp_settings, cvxpy_fallback)
