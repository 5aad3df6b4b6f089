"""Receding horizon on the belief of a hidden mode: problem P3 under a mixture of modes.

When ``theta_k`` is not observed, the controller knows the belief
``pi(i) = Pr{theta_k = i | x_0..x_k, u_0..u_{k-1}}`` (:class:`controllers.ModeFilter`). Given
``(x_k, pi, k)`` it solves, over the offset ``nu`` and the slack ``rho`` (section 5 of the paper,
with the mode averaged out under the belief)::

    min  sum_i pi_i [x'Q_i x + u'R_i u + (A_i x + B_i u)' Pi_i (A_i x + B_i u) + tr(Pi_i E_i W E_i')]
         + alpha rho
    s.t. G (A_i + B_i K(pi)) x + G B_i nu <= H_{k+1} - t_i(eps_i) + rho   for each kept mode i
         nu in U,  rho >= 0,   u = K(pi) x + nu

with ``Pi_i = sum_j p_ij(x_k) Psi_j`` (eq. eq:exp_noise; row ``i`` of ``P_in`` when
``G x_k <= H_k``, of ``P_out`` otherwise) and ``t_i(eps)`` the tightening of
:func:`controllers.chance.tightening` at level ``1 - eps`` (eq. constraint:det_univariate,
constraint:chi_square, or the union bound). The objective is ``E[J_k]`` of eq. (obj:func) under
the belief (Lemma 1, eq. eq:lemm1, in each mode).

**The risk allocation.** Mode ``i`` gets a risk ``eps_i`` with ``sum_i pi_i eps_i <= 1 - xi``:
the modes of smallest belief are *given up* (``eps_i = 1``: no rows) while their total belief
``m_D`` is at most ``give_up * (1 - xi)``; every other mode is *kept* at the same risk
``eps = (1 - xi - m_D) / (1 - m_D)``, level ``xi / (1 - m_D)``. A mode of zero belief is always
given up, so a certain belief ``e_theta`` keeps ``theta`` alone at level ``xi``: problem P3.

**The guarantee.** ``u_k`` is a function of the observations, and given ``theta_k = i`` and the
observations ``x_{k+1} ~ N(A_i x_k + B_i u_k, E_i W E_i')``. By the law of total probability over
the mixture, whenever the belief is the law of ``theta_k`` given the observations and the answer
has ``rho = 0``::

    Pr{G_j x_{k+1} > H_{k+1,j} | x_0..x_k, u_0..u_{k-1}}
        = sum_i pi_i Pr{G_j x_{k+1} > H_{k+1,j} | theta_k = i, ...}
        <= sum_{i kept} pi_i eps + sum_{i given up} pi_i  =  1 - xi

for each row ``j`` (``constraint="individual"``), and the same for the event that any row is
violated (``"joint"``, ``"bonferroni"``): each row (all rows together) of ``x_{k+1}`` holds with
probability at least ``xi``. With ``rho > 0`` the same holds for the band loosened by ``rho``.

**The gain.** ``gain="weighted"`` (default): ``K(pi) = sum_i pi_i K_i``, continuous in the
belief, the input of the linear feedback averaged over the modes the belief carries; or
``"most_probable"``: the gain of the most probable mode (ties: the smallest index). The
objective and the rows depend on ``u`` alone, so the gain only places the box ``U`` of ``nu``
around ``K(pi) x``: it matters where the box binds.

The QP in ``z = (nu, rho)`` has a Hessian that changes with the belief; it is solved by
:class:`controllers.belief_qp.BeliefQP`, and every answer is the exact solution of an active set
that passed the KKT test of :mod:`controllers.kkt` (``info["ok"]``).
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from sdjls_gym.errors import ModeNotObservedError
from sdjls_gym.messages import describe
from sdjls_gym.model import SDJLSModel
from sdjls_gym.model_checks import ROW_SUM_TOL
from sdjls_gym.validation import check_array, check_choice, check_int, check_int_array, check_number

if sys.version_info >= (3, 11):
    from typing import Unpack
else:  # pragma: no cover
    from typing_extensions import Unpack

from .base import MAX_STATE
from .belief_qp import BeliefQP
from .belief_risk import RiskAllocation
from .belief_rows import answer_rho, min_rho, solve_belief_cvxpy
from .horizon import MAX_QP_ENTRY, HorizonKwargs, RecedingHorizonBase, Status, shows_settings
from .p3 import build_family, check_magnitudes
from .qp import EnumerationBudget

__all__ = ["GAINS", "BeliefRecedingHorizonController"]

#: The rules of the pre-stabilizing gain ``K(pi)``.
GAINS = ("weighted", "most_probable")

_FLOAT64 = np.dtype(np.float64)

_PATHS = {
    "warm": "active_set_warm",
    "recent": "active_set_recent",
    "repair": "active_set_repair",
    "daqp": "daqp",
    "osqp": "osqp",
    "enumeration": "active_set",
}


@shows_settings
class BeliefRecedingHorizonController(RecedingHorizonBase):
    """Problem P3 on the belief of a hidden mode, with the risk shared across the modes.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n) array
        Pre-stabilising gains ``K_i``; the input is ``u = K(pi) x + nu``.
    gain : {"weighted", "most_probable"}
        The rule of ``K(pi)`` (see the module docstring).
    give_up : float
        In ``(0, 1)``: the share of the risk budget ``1 - xi`` that modes of small belief may
        take by being given up (default 0.75: the kept modes' level is at most
        ``xi / (1 - 0.75 (1 - xi))``, 0.973 for ``xi = 0.9``). Above 0, so that the answer is
        continuous as the belief tends to a certain one; below 1, so that the kept modes' risk
        stays positive.
    **settings
        The settings of :class:`controllers.RecedingHorizonController`, keyword, with the same
        names, types, defaults and checks (:class:`controllers.horizon.RecedingHorizonBase`,
        :class:`~controllers.horizon.HorizonKwargs`): ``Psi`` the terminal weights (required),
        ``xi`` the chance-constraint level (required), ``constraint``, ``alpha``, ``nu_bound``,
        ``solver`` (here ``"daqp"``, ``"osqp"``, ``"cvxpy"`` or ``"active_set"``), ``nu_set``,
        ``horizon``, ``osqp_settings``, ``cvxpy_fallback``.

    Attributes
    ----------
    tightening : (N, r) ndarray
        The tightening at level ``xi`` (P3's).
    risk_allocation : RiskAllocation
        The allocation of the risk among the modes (:mod:`controllers.belief_risk`).
    settings : HorizonSettings
        The checked parameters of the base.

    Raises
    ------
    TypeError, ValueError
        As :class:`controllers.RecedingHorizonController`; ``gain`` or ``give_up`` invalid.

    Notes
    -----
    Thread-safe: concurrent calls on one controller are serialized by its lock. Picklable.
    Decisions are stateless (a function of ``(x, belief, k)``); the filter of the belief
    across an episode is :class:`controllers.HiddenModePolicy`'s. :meth:`predict` takes
    observations that show the mode: the belief is then certain, ``e_theta``, and the answer
    is P3's.

    Examples
    --------
    >>> import numpy as np
    >>> from sdjls_gym.systems.macro import macro, PAPER_K, PAPER_RHC
    >>> ctrl = BeliefRecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    >>> u, info = ctrl.act([2.0, 2.0], [0.5, 0.3, 0.2], 0)
    >>> info["ok"], info["risk"].round(3).tolist()
    (True, [0.15, 0.15, 0.15])
    >>> u, info = ctrl.act([2.0, 2.0], [0.96, 0.03, 0.01], 0)  # 0.04 <= 0.75 * 0.15: given up
    >>> info["risk"].round(4).tolist()
    [0.1146, 1.0, 1.0]
    """

    SOLVERS = ("daqp", "osqp", "cvxpy", "active_set")

    def __init__(
        self,
        model: SDJLSModel,
        K: np.ndarray,
        *,
        gain: str = "weighted",
        give_up: float = 0.75,
        **settings: Unpack[HorizonKwargs],
    ) -> None:
        self.gain = check_choice("gain", gain, GAINS)
        self.give_up = check_number(
            "give_up",
            give_up,
            low=0.0,
            high=1.0,
            low_open=True,
            high_open=True,
            what="the share of the risk budget 1 - xi that modes of small belief may take",
        )
        super().__init__(model, K, **settings)

    def _build(self) -> None:
        """The tightening, every mode's matrices per region, and the QP's solver."""
        s, model = self.settings, self.model
        assert s.xi is not None  # checked: the chance constraints are imposed
        self.risk_allocation = RiskAllocation(model, s.xi, s.constraint, self.give_up)
        self.tightening = self.risk_allocation.table  # P3's, level xi
        # P3's families, for the same magnitude checks and the same Pi, R + B'Pi B and noise
        # terms (eq. eq:exp_noise, Lemma 1)
        budget = EnumerationBudget()
        families = {
            (i, inside): build_family(s, self.tightening, i, inside, budget)
            for i in range(model.N)
            for inside in (False, True)
        }
        check_magnitudes(s, families.values(), MAX_QP_ENTRY)
        # per region: every mode's linear maps of x stacked, [K_i; B_i'Pi_i A_i; G A_i; A_i; Q_i]
        # (one product gives all), R_i + B_i'Pi_i B_i flattened, Pi_i and tr(Pi_i E_i W E_i')
        N, m, n, r = model.N, model.m, model.n, model.r
        self._region = []
        for inside in (False, True):
            fams = [families[(i, inside)] for i in range(N)]
            Pi = np.stack([f.Pi for f in fams])
            F = np.einsum("iam,iab,ibn->imn", model.B, Pi, model.A)  # B_i'Pi_i A_i
            lin = np.concatenate([s.K, F, model.G @ model.A, model.A, model.Q], axis=1)
            # R_i + B_i'Pi_i B_i made exactly symmetric: every mixture of them is then symmetric
            H_nu = np.stack([f.H_nu for f in fams])
            H_sym = 0.5 * (H_nu + H_nu.transpose(0, 2, 1))
            # the cost as a quadratic form in (x, u) per mode, for families whose terms do not
            # cancel (P3's own test, p3.cost_condition): [[Q + A'Pi A, A'Pi B], [., R + B'Pi B]]
            M = np.zeros((N, n + m, n + m))
            M[:, :n, :n] = model.Q + np.einsum("ian,iab,ibk->ink", model.A, Pi, model.A)
            M[:, :n, n:] = F.transpose(0, 2, 1)
            M[:, n:, :n] = F
            M[:, n:, n:] = H_nu
            self._region.append(
                {
                    "lin": np.ascontiguousarray(lin.reshape(-1, n)),
                    "KH": np.concatenate([s.K.reshape(N, -1), H_sym.reshape(N, -1)], axis=1),
                    "Pi": Pi,
                    "noise": np.array([f.noise_term for f in fams]),
                    "M": M.reshape(N, -1) if all(f.expand_cost for f in fams) else None,
                }
            )
        self._rows_per_mode = 2 * m + r + 2 * n
        self._GB = model.G @ model.B  # (N, r, m)
        self._GB_flat = self._GB.reshape(-1, m)
        self._B_flat = model.B.reshape(-1, m)
        self._tail = np.concatenate([np.full(2 * m, s.nu_bound), [0.0]])  # box, rho >= 0
        self._R_flat = model.R.reshape(-1, m)
        self._qp = BeliefQP(self._GB, s.osqp_settings)
        self._uses_socp = s.nu_set == "ball" and model.m > 1  # a cone, not a QP: cvxpy

    # ------------------------------------------------------------------ checks
    def _check_belief(self, belief: Any, name: str = "belief") -> np.ndarray:
        """A probability vector (N,) or rows (B, N): finite, >= 0, summing to 1 within a
        relative 1e-9 (normalized)."""
        N = self.model.N
        b = check_array(name, belief, what=f"a probability vector per row, {N} entries")
        rows = b.reshape(-1, N) if b.ndim >= 1 and b.shape[-1] == N else None
        if rows is None or b.ndim > 2:
            raise ValueError(
                f"{name} has shape {b.shape}; expected ({N},) (one probability per mode)"
                if b.ndim <= 1
                else f"{name} has shape {b.shape}; expected (batch, {N})"
            )
        sums = rows.sum(axis=1)
        bad = ~(np.all(rows >= 0.0, axis=1) & (np.abs(sums - 1.0) <= ROW_SUM_TOL))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            label = name if b.ndim == 1 else f"{name}[{i}]"
            raise ValueError(
                f"{label} = {describe(rows[i])} (sum {float(sums[i]):.12g}) is not a probability "
                f"vector; expected {N} entries >= 0 summing to 1 (relative tolerance "
                f"{ROW_SUM_TOL:g})"
            )
        return (rows / sums[:, None]).reshape(b.shape)

    def _check_belief_inputs(
        self, x: Any, belief: Any, k: Any
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """``x`` a finite ``(n,)`` vector within :data:`controllers.base.MAX_STATE`, ``belief`` a
        probability vector ``(N,)``, ``k`` an int in ``[0, max_k]``; messages name the argument.
        A float64 ``x`` and ``belief`` that pass are used as they are."""
        N = self.model.N
        if not (
            type(x) is np.ndarray
            and x.dtype is _FLOAT64
            and x.shape == self._x_shape
            and all(-MAX_STATE <= v <= MAX_STATE for v in x.tolist())  # False for NaN
        ):
            x = check_array("x", x, shape=self._x_shape, what="one state vector")
            if np.max(np.abs(x)) > MAX_STATE:
                raise ValueError(
                    f"x = {describe(x)} has an entry of magnitude above {MAX_STATE:.0e}, the "
                    "largest state a controller accepts"
                )
        if type(belief) is np.ndarray and belief.dtype is _FLOAT64 and belief.shape == (N,):
            values = belief.tolist()
            total = sum(values)
            if min(values) >= 0.0 and abs(total - 1.0) <= ROW_SUM_TOL:
                belief = belief if total == 1.0 else belief / total
            else:
                belief = self._check_belief(belief)
        else:
            belief = check_array("belief", belief, what=f"a probability vector, {N} entries")
            if belief.shape != (N,):
                raise ValueError(
                    f"belief has shape {belief.shape}; expected ({N},), one probability per mode"
                )
            belief = self._check_belief(belief)
        if not (type(k) is int and 0 <= k <= self.max_k):
            k = check_int("k", k, low=0, high=self.max_k, what=self._k_what)
        return x, belief, k

    # ------------------------------------------------------------------ the pieces of P3
    def gain_of(self, belief: np.ndarray) -> np.ndarray:
        """``K(pi)`` (m, n) of a checked belief: ``sum_i pi_i K_i`` or the most probable mode's."""
        if self.gain == "most_probable":
            return self.K[int(np.argmax(belief))]
        support = np.flatnonzero(belief)
        return np.tensordot(belief[support], self.K[support], 1)

    # ------------------------------------------------------------------ decisions
    def act(self, x: Any, belief: Any, k: Any) -> tuple[np.ndarray, dict[str, Any]]:
        """Solve P3 on the belief at ``(x_k, pi, k)`` and return ``u_k = K(pi) x_k + nu_k``.

        Parameters
        ----------
        x : (n,) array
            The state ``x_k``.
        belief : (N,) array
            ``pi(i) = Pr{theta_k = i | observations}``: entries >= 0 summing to 1 (relative
            tolerance 1e-9), finite.
        k : int
            The time of ``x_k`` (the rows use the band ``H_{k+1}``).

        Returns
        -------
        u : (m,) float64 array
        info : dict
            As :meth:`controllers.RecedingHorizonController.act` (``"nu"``, ``"rho"``,
            ``"cost"``: the optimal value with every constant term, ``"status"``, ``"notes"``,
            ``"ok"``, ``"solver"``: ``"active_set_warm"``, ``"active_set_recent"``, ``"daqp"``,
            ``"osqp"``, ``"active_set"``, ``"cvxpy"``, ``"cvxpy_socp"`` or ``"fallback"``,
            ``"in_region"``), plus ``"risk"`` (N,) the ``eps_i`` used (1: given up) and
            ``"gain"`` (m, n) ``K(pi)``.

        Raises
        ------
        TypeError, ValueError
            ``x``, ``belief`` or ``k`` invalid (the message names it).
        """
        x, belief, k = self._check_belief_inputs(x, belief, k)
        with self._lock:
            u, info = self._decide(x, belief, k)
            self._count(info["solver"])
        return u, info

    def _decide(self, x: np.ndarray, pi: np.ndarray, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        model, s = self.model, self.settings
        N, m, n, r = model.N, model.m, model.n, model.r
        dyn = model.dynamics  # its one-state paths, without the model's hand-over
        inside = max(dyn.constraint_values_one(x, k).tolist()) <= 0.0  # in C1 at time k
        data = self._region[inside]
        y = (data["lin"] @ x).reshape(N, self._rows_per_mode)  # every mode's maps of x
        mixed = pi @ data["KH"]  # sum_i pi_i [K_i, R_i + B_i'Pi_i B_i], flattened
        H = mixed[m * n :].reshape(m, m)
        if self.gain == "weighted":
            Kpi = mixed[: m * n].reshape(m, n)
            v = pi @ y[:, :m]  # K(pi) x
        else:
            top = int(np.argmax(pi))
            Kpi, v = self.K[top], y[top, :m]
        P = np.zeros((m + 1, m + 1))
        P[:m, :m] = 2.0 * H  # 1/2 z'P z = nu'H(pi) nu
        q = 2.0 * (H @ v + pi @ y[:, m : 2 * m])  # the gradient in nu at nu = 0
        band = dyn.H_one(k + 1) - y[:, 2 * m : 2 * m + r] - (self._GB_flat @ v).reshape(N, r)
        kept, mass = self.risk_allocation.allocate(pi)
        risk, tight = self.risk_allocation.risks(kept, mass)
        # eq. (constraint:feasibility), the rows of the kept modes
        hbar = (band if len(kept) == N else band[list(kept)]) - tight
        w = np.concatenate([q, [s.alpha], hbar.ravel(), self._tail])
        notes: list[str] = []
        nu, rho, status, path = self._solve(self._qp.rows(kept), P, w, notes)
        u = v + nu  # eq. (eq:stabilization_input)
        info = {
            "nu": nu,
            "rho": float(rho),
            "cost": self._cost(data, x, y, u, pi, rho),
            "status": status,
            "notes": "; ".join(notes),
            "solver": path,
            "in_region": inside,
            "ok": status is Status.SOLVED,
            "risk": risk,
            "gain": Kpi,
        }
        return u, info

    def _solve(
        self, kr: Any, P: np.ndarray, w: np.ndarray, notes: list[str]
    ) -> tuple[np.ndarray, float, Status, str]:
        """``(nu, rho, status, path)`` of the QP of instance ``w`` on the kept rows ``kr``."""
        s, m = self.settings, self.model.m
        if self._uses_socp or s.solver == "cvxpy":
            return self._rescue(kr, P, w, notes, always=True)
        method = "daqp" if s.solver == "daqp" else s.solver
        sol = self._qp.solve(kr, P, w, method=method, warm=self._warm_start, notes=notes)
        if sol is None:
            return self._rescue(kr, P, w, notes)
        b = s.nu_bound  # round-off outside U clipped (the floats of a verified answer)
        nu = np.array([min(max(v, -b), b) for v in sol.z[:m]])
        return nu, answer_rho(kr, sol, nu, w), Status.SOLVED, _PATHS[sol.path]

    def _cost(
        self,
        data: dict[str, np.ndarray],
        x: np.ndarray,
        y: np.ndarray,
        u: np.ndarray,
        pi: np.ndarray,
        rho: float,
    ) -> float:
        """The objective at ``u``: ``sum_i pi_i [x'Q_i x + u'R_i u + mean_i'Pi_i mean_i +
        tr(Pi_i E_i W E_i')] + alpha rho``; expanded in ``(x, u)`` where P3 expands its cost
        (its terms cancel by at most :data:`controllers.p3.EXPAND_COST_CONDITION`), else
        written with ``u`` and the means themselves; ``y`` the stacked maps of ``x``."""
        model = self.model
        m, n, r = model.m, model.n, model.r
        M = data["M"]
        if M is not None:  # expanded: x'(Q + A'Pi A)x + 2 x'A'Pi B u + u'(R + B'Pi B)u
            xu = np.concatenate([x, u])
            with np.errstate(over="ignore", invalid="ignore"):
                total = float(xu @ (pi @ M).reshape(n + m, n + m) @ xu + pi @ data["noise"])
            if np.isfinite(total):
                return total + self.settings.alpha * rho
        a = 2 * m + r
        mean = y[:, a : a + n] + (self._B_flat @ u).reshape(-1, n)  # A_i x + B_i u
        terms = (
            y[:, a + n :] @ x
            + (self._R_flat @ u).reshape(-1, m) @ u
            + np.einsum("ia,iab,ib->i", mean, data["Pi"], mean)
            + data["noise"]
        )
        with np.errstate(invalid="ignore"):
            total = float(pi @ terms)
        if not np.isfinite(total):  # an overflowed term of a mode of zero belief
            support = np.flatnonzero(pi)
            total = float(pi[support] @ terms[support])
        return total + self.settings.alpha * rho

    def _rescue(
        self,
        kr: Any,
        P: np.ndarray,
        w: np.ndarray,
        notes: list[str],
        always: bool = False,
    ) -> tuple[np.ndarray, float, Status, str]:
        """The cvxpy reference (unless ``cvxpy_fallback=False``; always for the cone and for
        ``solver="cvxpy"``), its active set verified when it is a QP; then ``nu = 0``. Returns
        ``(nu, rho, status, path)``."""
        s, m = self.settings, self.model.m
        if self._uses_socp or s.cvxpy_fallback or always:
            nu, status = solve_belief_cvxpy(P, w, kr, s.nu_bound, s.nu_set == "ball")
            path = "cvxpy_socp" if self._uses_socp else "cvxpy"
            if nu is not None:
                if self._uses_socp:
                    nu = nu * min(1.0, s.nu_bound / max(float(np.linalg.norm(nu)), 1e-300))
                    return nu, min_rho(kr, nu, w), Status.SOLVED, path
                nu = np.clip(nu, -s.nu_bound, s.nu_bound)
                z = np.concatenate([nu, [min_rho(kr, nu, w)]])
                sol = self._qp.local(kr, P, w, z)
                if sol is not None:
                    nu = np.clip(sol.z[:m], -s.nu_bound, s.nu_bound)
                    return nu, answer_rho(kr, sol, nu, w), Status.SOLVED, path
                notes.append("the cvxpy answer did not verify")
                return nu, min_rho(kr, nu, w), Status.UNVERIFIED, path
            notes.append(f"cvxpy status {status!r}")
        else:
            notes.append("cvxpy retry disabled")
        zero = np.zeros(m)
        return zero, min_rho(kr, zero, w), Status.FALLBACK_NU0, "fallback"

    # ------------------------------------------------------------------ batches
    def act_batch(self, x: Any, belief: Any, k: Any) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`act` for a batch: ``x`` (B, n), ``belief`` (B, N), ``k`` (B,) or an int.

        Returns ``u`` (B, m) and the info of :meth:`act` as arrays with a leading axis B
        (``"status"``, ``"notes"``, ``"solver"``: object arrays; ``"risk"`` (B, N); ``"gain"``
        (B, m, n)). Each row is the answer :meth:`act` gives it.
        """
        model = self.model
        x = check_array("x", x, shape=(None, model.n), what="one state per row")
        B = x.shape[0]
        if x.size and np.max(np.abs(x)) > MAX_STATE:
            row = int(np.argmax(np.max(np.abs(x), axis=1)))
            raise ValueError(
                f"x[{row}] = {describe(x[row])} has an entry of magnitude above "
                f"{MAX_STATE:.0e}, the largest state a controller accepts"
            )
        beliefs = check_array("belief", belief, what="one probability vector per row")
        if beliefs.shape != (B, model.N):
            raise ValueError(
                f"belief has shape {beliefs.shape}; expected ({B}, {model.N}) to match x"
            )
        beliefs = self._check_belief(beliefs)
        times = check_int_array("k", k, low=0, high=self.max_k)
        times = np.broadcast_to(times, (B,)) if times.ndim == 0 else times
        if times.shape != (B,):
            raise ValueError(f"k has shape {times.shape}; expected ({B},) to match x")
        results = []
        with self._lock:
            for xb, bb, kb in zip(x, beliefs, times.tolist(), strict=True):
                u, info = self._decide(xb, bb, int(kb))
                self._count(info["solver"])
                results.append((u, info))
        m, n = model.m, model.n
        infos = [r[1] for r in results]
        out: dict[str, np.ndarray] = {
            "nu": np.array([i["nu"] for i in infos], dtype=np.float64).reshape(B, m),
            "rho": np.array([i["rho"] for i in infos], dtype=np.float64),
            "cost": np.array([i["cost"] for i in infos], dtype=np.float64),
            "ok": np.array([i["ok"] for i in infos], dtype=bool),
            "in_region": np.array([i["in_region"] for i in infos], dtype=bool),
            "risk": np.array([i["risk"] for i in infos], dtype=np.float64).reshape(B, model.N),
            "gain": np.array([i["gain"] for i in infos], dtype=np.float64).reshape(B, m, n),
        }
        for key in ("status", "notes", "solver"):
            arr = np.empty(B, dtype=object)
            arr[:] = [i[key] for i in infos]
            out[key] = arr
        u = np.array([r[0] for r in results], dtype=np.float64).reshape(B, m)
        return u, out

    # ------------------------------------------------------------------ observations
    def _observed_inputs(self, observation: Any) -> tuple[np.ndarray, bool]:
        """For observations that show the mode (``observe="mode"``): the belief is then
        certain, ``e_theta``, and the answer is P3's. A state-only observation raises
        :class:`~sdjls_gym.errors.ModeNotObservedError`: the belief across an episode is
        :class:`controllers.HiddenModePolicy`'s (its ``predict`` keeps the filter)."""
        model = self.model
        obs = np.asarray(observation)
        if obs.ndim in (1, 2) and obs.shape[-1] == model.n + 1:
            raise ModeNotObservedError(
                f"observation has shape {obs.shape}: the state-only layout [x ({model.n}), "
                "k / horizon (1)] of observe='state'; the belief of the mode across an episode "
                "is kept by controllers.HiddenModePolicy(ctrl), whose predict(observation, "
                "state, episode_start) takes these observations"
            )
        obs = self._observation(observation)
        xs, modes, ks = self._decode_own(obs)
        return self.act_batch(xs, np.eye(model.N)[modes], ks)[0], obs.ndim == 1
