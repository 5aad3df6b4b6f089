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
``solver="daqp"`` (default, fast path)
    The QP in ``z = (nu, rho)`` has a Hessian and a constraint matrix that depend only on the
    mode and on whether ``x_k`` is in C1 (a *family*, :mod:`controllers.p3`), and its data are
    affine in ``x_k``. Each family is a :class:`controllers.qp.QPFamily`: the active set of its
    last solution is re-solved exactly and kept if it passes the KKT test
    (``info["solver"] == "active_set_warm"``); otherwise DAQP, a dense dual active-set solver
    (its workspace set up once per family, then only updated), finds the optimum and the active
    set of its multipliers is re-solved exactly and verified (``"daqp"``); OSQP and the
    enumeration of the candidate active sets follow if that fails. Every answer is the exact
    solution of a verified active set, so it does not depend on the call history (except in
    degenerate problems, where several active sets verify). The exact solution of each active
    set met is kept as linear maps (:mod:`controllers.kkt`): verifying an answer whose active
    set was met before costs one matrix-vector product and the test. With ``nu_set="ball"``
    and ``m > 1`` the QP engine cannot express ``||nu||_2 <= nu_bound``; the controller then
    solves the second-order cone program with cvxpy + Clarabel instead.
``solver="osqp"``
    The same, with OSQP (set up once per family, then only updated and warm-started) finding
    the active sets instead of DAQP (``"osqp"``).
``solver="cvxpy"``
    The plain formulation written with cvxpy and solved by Clarabel, rebuilt at every call; a
    reference for checking the fast path. Its answer is verified like every other: the active
    set it identifies is re-solved exactly and must pass the engine's KKT test ("solved"), else
    it is returned as "unverified" (``ok`` False) with the smallest feasible ``rho`` for its
    offset.
``solver="active_set"``
    Exact solution by enumeration of the candidate active sets at every call (no warm start),
    for families small enough to enumerate (:data:`controllers.qp.MAX_CANDIDATES`).

:meth:`RecedingHorizonController.act_batch` solves a whole batch with matrix products: the
enumeration where the family is small enough, else the exact maps of the active sets met so far;
a state that neither settles goes through :meth:`act`.

An episode never crashes on a solver failure: after the fast path's solvers and the
enumeration, the cvxpy reference is tried (unless ``cvxpy_fallback=False``) and its active set
verified, and as a last resort ``nu = 0`` with the smallest feasible ``rho``. ``info["status"]``
(a :class:`controllers.Status`) says what happened, ``info["notes"]`` what failed on the way.

Limits: ``alpha`` and ``nu_bound`` up to :data:`MAX_ALPHA` and :data:`MAX_NU_BOUND` (answers are
verified optimal to ~1e-8 relative in ``J*`` over the whole range); the matrices of the QP
(from ``Psi``, ``K`` and the model's ``Q``, ``R``, ``G``) up to :data:`MAX_QP_ENTRY` in magnitude.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .chance import tightening
from .horizon import MAX_ALPHA, MAX_NU_BOUND, MAX_QP_ENTRY, RecedingHorizonBase, Status
from .p3 import (
    Family,
    build_family,
    check_magnitudes,
    exact_answer,
    hbar,
    instance,
    min_rho,
    objective,
    project_nu,
    solve_p3_cvxpy,
)
from .qp import DEFAULT_OSQP_SETTINGS, EnumerationBudget

__all__ = [
    "DEFAULT_OSQP_SETTINGS",
    "MAX_ALPHA",
    "MAX_NU_BOUND",
    "MAX_QP_ENTRY",
    "RecedingHorizonController",
    "UnconstrainedRecedingHorizonController",
]

#: ``(nu, rho, cost, status, path)`` of one decision (see RecedingHorizonController._info)
_Answer = tuple[np.ndarray | list[float], float, float, Status, str]

_PATHS = {
    "warm": "active_set_warm",
    "daqp": "daqp",
    "osqp": "osqp",
    "osqp_retry": "osqp_retry",
    "enumeration": "active_set",
}


class RecedingHorizonController(RecedingHorizonBase):
    """One-step receding-horizon control with chance constraints, problem P3 of the paper.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n) array
        Pre-stabilising gains.
    Psi : (N, n, n) array
        Terminal weights, symmetric positive definite (keyword, required).
    xi : float
        Chance-constraint level in (0, 1) (keyword, required).
    constraint, alpha, nu_bound, solver, nu_set, horizon, osqp_settings, cvxpy_fallback
        Keyword-only, with the defaults of the signature, documented in
        :class:`controllers.horizon.RecedingHorizonBase`; ``solver`` is ``"daqp"``, ``"osqp"``,
        ``"cvxpy"`` or ``"active_set"``.

    Attributes
    ----------
    tightening : (N, r) ndarray
        ``t[i, j]`` of eq. (constraint:det_univariate) / (constraint:chi_square).
    A_tilde : (N, n, n) ndarray
        ``A_i + B_i K_i``.
    settings : HorizonSettings
        The checked parameters.

    Raises
    ------
    TypeError, ValueError
        See :class:`controllers.horizon.RecedingHorizonBase`; also weights whose QP would exceed
        :data:`MAX_QP_ENTRY`, and ``solver="active_set"`` for a family too large to enumerate.

    Notes
    -----
    A model without gains or terminal weights of its own: :meth:`from_model` synthesizes ``K``
    (Proposition 2) and takes the MJLS LQ value matrices as ``Psi``.

    Thread-safe: concurrent calls on one controller are serialized by its lock. Picklable at
    any time (the solver state is rebuilt on use). :attr:`path_counts` counts the answers per
    ``info["solver"]`` value; :meth:`set_warm_start` switches the warm start off.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro, PAPER_K, PAPER_RHC
    >>> ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    >>> u, info = ctrl.act([2.0, 2.0], 0, 0)
    >>> info["rho"], info["status"] == "solved", info["notes"]
    (0.0, True, '')
    """

    SOLVERS = ("daqp", "osqp", "cvxpy", "active_set")

    def _build(self) -> None:
        """The tightening and every family's matrices, from the checked :attr:`settings`."""
        s = self.settings
        model = self.model
        self.tightening: np.ndarray | None = None
        if s.chance:
            assert s.xi is not None  # checked whenever the chance constraints are imposed
            self.tightening = tightening(model, s.xi, s.constraint)
            self.tightening.setflags(write=False)
        # every family's matrices, built now so that bad magnitudes fail before any work
        budget = EnumerationBudget()  # the enumerations of all families share one memory budget
        self._families: dict[tuple[int, bool], Family] = {
            (mode, inside): build_family(s, self.tightening, mode, inside, budget)
            for mode in range(model.N)
            for inside in (True, False)
        }
        check_magnitudes(s, self._families.values(), MAX_QP_ENTRY)
        self._uses_socp = s.nu_set == "ball" and model.m > 1  # a cone, not a QP: cvxpy
        self._qp_path = s.solver != "cvxpy" and not self._uses_socp
        if s.solver == "active_set" and self._qp_path:
            fam = self._families[(0, True)]
            if not fam.engine.can_enumerate:
                raise ValueError(
                    f"solver = 'active_set' enumerates {fam.engine.n_candidates} candidate active "
                    f"sets per family for m = {model.m}, r = {model.r}, more than the limit "
                    "controllers.qp.MAX_CANDIDATES; use solver='daqp' (exact re-solve of the "
                    "active set DAQP finds)"
                )

    # ------------------------------------------------------------------ single decisions
    def _family(self, x: np.ndarray, mode: int, k: int) -> Family:
        inside = self.model.in_region_one(x, k)  # in C1 at time k: act_batch's test
        return self._families[(mode, inside)]

    def _act_qp(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """:meth:`act` on the QP engine (every solver but cvxpy, the box ``U``)."""
        fam = self._family(x, mode, k)
        y, w = instance(fam, self.model, x, k)
        engine = fam.engine
        notes: list[str] = []
        sol = None
        if self.solver == "active_set":
            sol = engine.enumerate_one(w)
            if sol is None:
                notes.append("no enumerated active set verified")
        if sol is None:
            sol = engine.solve(
                w, warm=self._warm_start and self.solver != "active_set", notes=notes
            )
        if sol is not None:
            nu, rho, cost = exact_answer(fam, self.nu_bound, x, y.tolist(), w, sol)
            answer: _Answer = (nu, rho, cost, Status.SOLVED, _PATHS[sol.path])
        else:
            answer = self._rescue(fam, x, k, w, notes)
        u = y[: self.model.m] + np.asarray(answer[0])  # eq. (eq:stabilization_input)
        return u, self._info(fam, *answer, notes)

    def _answer(
        self, fam: Family, x: np.ndarray, k: int, nu: np.ndarray
    ) -> tuple[np.ndarray, float, float]:
        """``(nu, rho, cost)`` for an offset found by a solver other than the exact path:
        ``nu`` projected on ``U`` and the smallest feasible ``rho``."""
        nu = project_nu(self.settings, np.asarray(nu, dtype=np.float64))
        rho = min_rho(fam, x[None], nu[None], hbar(fam, self.model, np.array([k])))
        cost = objective(fam, x[None], nu[None], rho)
        return nu, float(rho[0]), float(cost[0])

    def _rescue(
        self,
        fam: Family,
        x: np.ndarray,
        k: int,
        w: np.ndarray | None,
        notes: list[str],
        always: bool = False,
    ) -> _Answer:
        """The end of the fallback chain, and the whole of ``solver="cvxpy"`` (``always``):
        the cvxpy reference (unless ``cvxpy_fallback=False``; always for the second-order cone
        program), its active set verified by the engine's KKT test when it is a QP (else
        "unverified", with its offset and the smallest feasible slack); then ``nu = 0``.
        Returns ``(nu, rho, cost, status, path)``; ``notes`` receives what failed."""
        if self._uses_socp or self.cvxpy_fallback or always:
            nu, _, _, status = solve_p3_cvxpy(self.settings, fam, x, k)
            path = "cvxpy_socp" if self._uses_socp else "cvxpy"
            if nu is not None:
                if self._uses_socp:
                    return (*self._answer(fam, x, k, nu), Status.SOLVED, path)
                if w is None:
                    w = instance(fam, self.model, x, k)[1]
                nu = project_nu(self.settings, nu)
                hb = hbar(fam, self.model, np.array([k]))
                z = np.concatenate([nu, min_rho(fam, x[None], nu[None], hb)])
                if always:  # no solve ran (the fast path's rescue shares its solve's budget)
                    fam.engine.open_budget()
                sol = fam.engine.local(z, w)
                if sol is not None:
                    y = (fam.lin @ x).tolist()
                    return (*exact_answer(fam, self.nu_bound, x, y, w, sol), Status.SOLVED, path)
                notes.append("the cvxpy answer did not verify")
                return (*self._answer(fam, x, k, nu), Status.UNVERIFIED, path)
            notes.append(f"cvxpy status {status!r}")
        else:
            notes.append("cvxpy retry disabled")
        zero = np.zeros(self.model.m)
        return (*self._answer(fam, x, k, zero), Status.FALLBACK_NU0, "fallback")

    @staticmethod
    def _info(
        fam: Family, nu: Any, rho: float, cost: float, status: Status, path: str, notes: list[str]
    ) -> dict[str, Any]:
        """The ``info`` dict of :meth:`act` (keys documented there)."""
        return {
            "nu": np.array(nu, dtype=np.float64),
            "rho": float(rho),
            "cost": float(cost),
            "status": status,
            "notes": "; ".join(notes),
            "solver": path,
            "in_region": fam.inside,
            "Pi": fam.Pi,  # read-only
            "ok": status is Status.SOLVED,
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
            ``"status"`` (a :class:`controllers.Status`: ``"solved"`` when the answer was
            verified optimal, ``"unverified"`` for a cvxpy answer that could not be verified,
            ``"fallback_nu0"`` for the last resort), ``"notes"`` (str: the solver trouble met
            on the way, e.g. ``"daqp exit flag -4; osqp status 'maximum iterations reached'"``;
            empty when there was none), ``"ok"`` (the answer is verified), ``"solver"`` (which
            path produced the answer: ``"active_set_warm"``, ``"daqp"``, ``"osqp"``,
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
                fam = self._family(x, mode, k)
                notes: list[str] = []
                answer = self._rescue(fam, x, k, None, notes, always=self.solver == "cvxpy")
                u = fam.K @ x + answer[0]  # eq. (eq:stabilization_input)
                info = self._info(fam, *answer, notes)
            self._count(info["solver"])
        return np.asarray(u, dtype=np.float64), info

    # ------------------------------------------------------------------ batches
    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray | int
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Solve P3 for a batch of states at once, with matrix products over the batch.

        The states are grouped by family ``(mode, x_k in C1)``; each family's QP has fixed
        matrices, and its instances are affine in the state. A family small enough to enumerate
        is solved exactly for the whole group by the enumeration of
        :class:`controllers.active_set.ActiveSetQP` (built once per family); a larger one by the
        exact maps of the active sets it has met (:meth:`controllers.qp.QPFamily.seen`), the
        same test applied to the whole group at once. A state that neither settles goes through
        :meth:`act` (whose active set then joins the family's), and so does every state when
        ``nu_set="ball"`` with ``m > 1`` or ``solver="cvxpy"``. The answers equal those of
        :meth:`act` up to round-off.

        Parameters
        ----------
        x, mode, k
            As :meth:`controllers.base.Controller.act_batch`: ``(B, n)``, ``(B,)`` ints and
            ``(B,)`` ints or an int.

        Returns
        -------
        u : (B, m) float64 array
        info : dict of arrays
            ``"nu"`` (B, m), ``"rho"`` (B,), ``"cost"`` (B,) (J*_k), ``"status"`` (B,)
            :class:`controllers.Status` objects, ``"notes"`` (B,) str objects, ``"ok"`` (B,)
            bool (the answer was verified optimal), ``"in_region"`` (B,).
        """
        x, mode, k = self._check_batch_inputs(x, mode, k)
        if not self._qp_path:
            u, info = self._act_each(x, mode, k)
            info["in_region"] = self.model.in_region(x, k)
            return u, info
        with self._lock:
            return self._act_batch(x, mode, k)

    def _batch_solve(self, fam: Family, xf: np.ndarray, hb: np.ndarray | None) -> tuple:
        """``(nu (B, m), settled (B,))`` of a family's states by matrix products: the
        enumeration, or else the exact maps of the active sets the family has met."""
        model = self.model
        m, r, d, count = model.m, model.r, model.m + 1, xf.shape[0]
        solver = fam.engine.enumeration() or fam.engine.seen()
        if solver is None:
            return np.zeros((count, m)), np.zeros(count, dtype=bool)
        wT = np.empty((fam.w0.shape[0], count))  # [q; h] of the family's QP
        wT[:] = fam.w0[:, None]
        wT[:m] = fam.grad @ xf.T
        if hb is not None:
            wT[d : d + r] = (hb - xf @ fam.GA.T).T
        z, found = solver.solve(wT.T)
        nu = project_nu(
            self.settings, z[:, :m] if found.all() else np.where(found[:, None], z[:, :m], 0.0)
        )
        return nu, found

    def _act_batch(self, x: np.ndarray, mode: np.ndarray, k: np.ndarray) -> tuple:
        model = self.model
        size, m = x.shape[0], model.m
        inside = model.in_region(x, k)
        status = np.empty(size, dtype=object)  # (np.full would store a plain str)
        status[:] = Status.SOLVED
        notes = np.full(size, "", dtype=object)
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
            hb = hbar(fam, model, kf) if fam.chance else None
            nu_f, found = self._batch_solve(fam, xf, hb)
            for j in np.flatnonzero(~found).tolist():  # not settled: the single-state path
                i = int(order[start + j])
                _, info_j = self.act(x[i], int(mode[i]), int(k[i]))
                nu_f[j], status[i], ok[i] = info_j["nu"], info_j["status"], info_j["ok"]
                notes[i] = info_j["notes"]
            rho_f = min_rho(fam, xf, nu_f, hb) if hb is not None else np.zeros(count)
            nu_s[start:stop], rho_s[start:stop] = nu_f, rho_f
            cost_s[start:stop] = objective(fam, xf, nu_f, rho_f)
            np.add(xf @ fam.K.T, nu_f, out=u_s[start:stop])  # eq. (eq:stabilization_input)
            start = stop
        back = np.empty(size, dtype=np.intp)  # the inverse permutation of order
        back[order] = np.arange(size)
        u, nu = np.take(u_s, back, axis=0), np.take(nu_s, back, axis=0)
        rho, cost = np.take(rho_s, back), np.take(cost_s, back)
        info = {
            "nu": nu,
            "rho": rho,
            "cost": cost,
            "status": status,
            "notes": notes,
            "ok": ok,
            "in_region": inside,
        }
        return u, info


class UnconstrainedRecedingHorizonController(RecedingHorizonController):
    """Problem P3 without the chance constraints: only ``nu in U`` (``rho = 0`` always).

    The same parameters as :class:`RecedingHorizonController` (keyword-only after ``K``);
    ``xi`` is optional and, like ``constraint`` and ``alpha``, checked and unused, so the same
    keyword arguments build both (``**PAPER_RHC``, ``**task.rhc``).

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro, PAPER_K, PAPER_RHC
    >>> ctrl = UnconstrainedRecedingHorizonController(macro(), PAPER_K, Psi=PAPER_RHC["Psi"])
    >>> ctrl.act([2.0, 2.0], 0, 0)[1]["rho"]
    0.0
    """

    _chance_constrained = False
