"""Multi-step receding horizon on a scenario tree of modes (beyond the paper).

At each time ``k`` the controller observes ``(x_k, theta_k)`` and plans ``steps`` stages ahead on
a tree of modes (see :mod:`controllers.tree_data`): the root is ``(x_k, theta_k)``; a node at a
stage ``t < branching`` has one child per mode that can follow, a later node one child with its
own mode. Every node up to stage ``steps - 1`` has its own offset ``nu`` in ``U`` and slack
``rho >= 0``; the QP minimizes the expected stage costs weighted by the path probabilities, the
slacks penalized by ``alpha`` times the path probability, and the terminal cost
``Pi = sum_j p_j Psi_j`` at the leaves, subject to each node's chance constraint on its next
state, tightened with that state's covariance (section 4). Only the root's offset is applied.
With ``steps = 1`` this is problem P3 exactly.

Branch probabilities, and what is approximated
----------------------------------------------
The root's are the paper's (eq. eq:p_tran): row ``theta_k`` of ``P_in`` if ``G x_k <= H_k``, else
of ``P_out``. A later node's are ``q P_in[theta] + (1 - q) P_out[theta]`` with
``q = Pr{G x <= H_{k+t}}`` for the node's state ``x ~ N(mean, Sigma)``. ``q`` depends on the
decisions; to keep every solve a QP, the controller fixes the probabilities, solves, recomputes
``q`` from the new plan's means and repeats (damped fixed-point iterations, at most
``iterations`` solves; :data:`PROB_TOL` ends them early), starting from the plan of ``nu = 0``.
This is an approximation of the state-dependent jumps in two ways: ``q`` is evaluated at the
plan instead of being part of the optimization, and the Gaussian law of a node's state given
its path ignores that a mode drawn from a random state tilts that state's law (the law of the
next state is exactly Gaussian at the root and at stage 1, whose modes were drawn from the known
``x_k``). It is exact when ``steps = 1`` (P3), when ``P_in == P_out`` (the jumps do not depend
on the state) and when ``q`` is robustly 0 or 1; the root's constraint and the first input are
always P3's (the probability that each row of ``x_{k+1}`` holds is ``>= xi`` whenever
``rho_0 = 0``, exactly). No plan is carried from one decision to the next: every decision
starts from the plan of ``nu = 0``, so that an answer depends only on ``(x, mode, k)``.
``q`` itself is exact when the rows of ``G`` are parallel or antiparallel (an interval on one
projection, e.g. the band of the macroeconomic example); otherwise see
:class:`controllers.tree_data.RegionClasses`.

Chance constraints at later stages: ``"individual"`` tightens row ``j`` of node ``i`` by
``Phi^{-1}(xi) sqrt(G_j Sigma G_j')`` with ``Sigma`` the covariance of the node's next state;
``"bonferroni"`` the same at level ``1 - (1 - xi) / r``; ``"joint"`` by
``sqrt(F^{-1}_{chi2, d}(xi)) sqrt(G_j Sigma G_j')`` with ``d = p`` at the root (section 4, as
:func:`controllers.chance.tightening`) and ``d = min(p (t + 1), max(n, p))`` at stage ``t``, at
least the rank of ``Sigma`` (the noise of the next state is ``L v`` with ``L L' = Sigma``,
``v ~ N(0, I_d)``, and the ellipsoid ``||v||^2 <= F^{-1}_{chi2, d}(xi)`` lies in the tightened
rows), so each node's rows hold together with probability ``>= xi`` under its Gaussian law.

Solvers
-------
``solver="osqp"`` (default): the tree's topology and constraint matrix are fixed per (mode,
region) family; one :class:`controllers.tree_qp.TreeQP` per family (a
:class:`controllers.qp.QPFamily`) is only updated (``update_P``, ``update(q, l, u)``) and warm
started: the last active set is re-solved exactly for the new data, then OSQP, whose active set
is re-solved exactly; the answer is verified by the KKT test. After failures the condensed QP
goes to cvxpy + Clarabel (its active set verified), and as a last resort every ``nu = 0`` with
the smallest feasible slacks. ``solver="cvxpy"``: the same tree written plainly in cvxpy
(rebuilt at every solve, solved by Clarabel), the reference the tests compare against.

Thread-safe (the base class's lock) and picklable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import check_bool, check_choice, check_int

from .base import Controller, check_gain, check_terminal_weights
from .chance import CONSTRAINT_KINDS, check_xi
from .qp import KKT_TOL, check_osqp_settings
from .rhc import MAX_QP_ENTRY, check_slack_and_offsets
from .tree_data import (
    WEIGHT_FLOOR,
    RegionClasses,
    TreeFamily,
    build_tree_family,
    check_tree_size,
)
from .tree_qp import solve_condensed_cvxpy, solve_tree_cvxpy

__all__ = ["ScenarioTreeController", "TreePlan", "PROB_TOL", "DAMPING", "MAX_WEIGHT_RATIO"]

SOLVERS = ("osqp", "cvxpy")

#: The fixed-point iterations stop when no region probability ``q`` moves by more than this.
PROB_TOL = 1e-6

#: The fixed-point update is ``q <- q + step (q(plan) - q)``; ``step`` starts at 1 and is multiplied
#: by ``DAMPING`` whenever the change of ``q`` grows from one solve to the next (oscillation).
DAMPING = 0.5

#: Largest ratio of the weights' norms (``Q_i``, ``R_i``, ``Psi_i``) the tree accepts. The paper's
#: example has 3; the tree's answers were verified up to ratios of 1e14 and start failing
#: verification (reported, not silent) from about 1e16 at steps = 3. P3 accepts more (its cost
#: condition, :data:`controllers.p3.MAX_COST_CONDITION`).
MAX_WEIGHT_RATIO = 1e12

_PATHS = {"warm": "active_set_warm", "osqp": "osqp", "osqp_retry": "osqp_retry"}


@dataclass(frozen=True, eq=False)
class TreePlan:
    """The plan of one decision: every node of the tree (breadth-first, the root is 0).

    Attributes
    ----------
    k : int
        Time of the root.
    mode, parent, stage : (M,) int arrays
        Each node's mode, parent (-1 at the root) and stage.
    children : (M, N) int array
        See :class:`controllers.tree_data.Tree`.
    probability : (M,) float
        Path probability of each node (product of the branch probabilities on its path).
    branch : (M, N) float
        Conditional probability of each next mode: the branch probabilities where the tree
        branches and at the last stage (its terminal weight ``Pi = sum_j branch_j Psi_j``); the
        node's own mode with probability 1 where it does not branch.
    mean, cov : (M, n), (M, n, n)
        Law of each node's state (``cov`` is 0 at the root).
    next_mean, next_cov : (M, n), (M, n, n)
        Law of each node's next state (shared by its children).
    nu : (M, m), rho : (M,)
        The offsets and slacks.
    tightening : (M, r)
        The tightening of each node's chance rows.
    """

    k: int
    mode: np.ndarray
    parent: np.ndarray
    stage: np.ndarray
    children: np.ndarray
    probability: np.ndarray
    branch: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    next_mean: np.ndarray
    next_cov: np.ndarray
    nu: np.ndarray
    rho: np.ndarray
    tightening: np.ndarray


@dataclass
class _Probabilities:
    """The probabilities one QP is built with."""

    q: np.ndarray  # (S,) region probabilities of the nodes tree.sq
    branch: np.ndarray  # (M, N)
    path: np.ndarray  # (M,)
    weight: np.ndarray  # (M,) path probabilities floored at WEIGHT_FLOOR


class ScenarioTreeController(Controller):
    """Multi-step receding-horizon control on a scenario tree of modes (beyond the paper).

    See the module docstring for the problem, its approximation of the state-dependent jumps
    and where it is exact.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n) array
        Pre-stabilising gains of ``u = K_theta x + nu``.
    Psi : (N, n, n) array
        Terminal weights, symmetric positive definite.
    xi : float
        Chance-constraint level, strictly between 0 and 1.
    steps : int
        Horizon of the tree, ``>= 1`` (``steps = 1`` is problem P3).
    branching : int, optional
        Stages that branch, in ``[0, steps]`` (default: ``steps``, every stage). From stage
        ``branching`` on, a node has one child with its own mode; ``branching = 0`` plans along
        the current mode only (the terminal weights still use the branch probabilities).
    constraint : {"individual", "joint", "bonferroni"}
    alpha : float
        Penalty on each slack (times its node's path probability), in ``(0, 1e12]``.
    nu_bound : float
        ``U = {|nu_i| <= nu_bound}``, in ``(0, 1e12]``.
    horizon : int, optional
        Episode length of the environment (used by :meth:`predict`).
    solver : {"osqp", "cvxpy"}
        The fast path or the plain cvxpy/Clarabel reference (see the module docstring).
    iterations : int
        Largest number of QP solves per decision (fixed-point iterations on the branch
        probabilities), ``>= 1``.
    osqp_settings : dict, optional
        Overrides of :data:`controllers.rhc.DEFAULT_OSQP_SETTINGS`.
    cvxpy_fallback : bool
        Whether a failed fast path tries cvxpy before ``nu = 0``.

    Raises
    ------
    TypeError, ValueError
        Bad arguments (the message names the argument), including a tree of more than
        :data:`controllers.tree_data.MAX_TREE_VARIABLES` QP variables.

    Notes
    -----
    Thread-safe: calls on one controller are serialized by its lock, and answers do not depend
    on earlier calls (no plan is carried between decisions, and every answer of the fast path is
    the exact solution of a verified active set, whichever path found it; only degenerate
    problems, where several active sets verify, can differ by round-off). Picklable.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro, PAPER_K, PAPER_RHC
    >>> ctrl = ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=3)
    >>> u, info = ctrl.act([2.0, 2.0], 0, 0)
    >>> info["rho"], info["status"], info["plan"].mode.shape
    (0.0, 'solved', (13,))
    """

    def __init__(
        self,
        model: SDJLSModel,
        K: np.ndarray,
        Psi: np.ndarray,
        xi: float,
        *,
        steps: int = 3,
        branching: int | None = None,
        constraint: str = "individual",
        alpha: float = 1000.0,
        nu_bound: float = 100.0,
        horizon: int | None = None,
        solver: str = "osqp",
        iterations: int = 10,
        osqp_settings: dict[str, Any] | None = None,
        cvxpy_fallback: bool = True,
    ) -> None:
        super().__init__(model, horizon)
        self.xi = check_xi(xi)
        self.steps = check_int("steps", steps, low=1, what="stages of the tree")
        self._lookahead = self.steps  # the chance constraints read H up to k + steps
        if branching is None:
            self.branching = self.steps
        else:
            self.branching = check_int(
                "branching", branching, low=0, high=self.steps, what="stages that branch"
            )
        self.constraint = check_choice("constraint", constraint, CONSTRAINT_KINDS)
        self.K = check_gain(self.model, K)
        self.Psi = check_terminal_weights(self.model, Psi)
        self.alpha, self.nu_bound = check_slack_and_offsets(alpha, nu_bound)
        self.solver = check_choice("solver", solver, SOLVERS)
        self.iterations = check_int(
            "iterations", iterations, low=1, high=100, what="QP solves per decision"
        )
        self.osqp_settings = check_osqp_settings(osqp_settings)
        self.cvxpy_fallback = check_bool("cvxpy_fallback", cvxpy_fallback)
        check_tree_size(self.model, self.steps, self.branching)
        self._check_weight_ratio()
        model = self.model
        self.A_tilde = model.A + model.B @ self.K  # eq. (sys:stabilized_input)
        self.A_tilde.setflags(write=False)
        self._regions = RegionClasses(model.G)
        self._families: dict[tuple[int, bool], TreeFamily] = {
            (mode, inside): build_tree_family(self, mode, inside, self._regions)
            for mode in range(model.N)
            for inside in (True, False)
        }
        self._check_magnitudes()
        #: active-set warm start of the OSQP path; False: OSQP at every solve
        self._warm_start = True
        #: how many QP solves each path answered
        self._path_counts: dict[str, int] = {}

    # ------------------------------------------------------------------ checks
    def _check_weight_ratio(self) -> None:
        """ValueError unless the weights ``Q_i``, ``R_i`` and ``Psi_i`` are within
        :data:`MAX_WEIGHT_RATIO` of each other (spectral norms, zero matrices aside)."""
        model = self.model
        sizes = {
            name: [float(np.linalg.norm(w, 2)) for w in mats]
            for name, mats in (("model.Q", model.Q), ("model.R", model.R), ("Psi", self.Psi))
        }
        nonzero = [v for values in sizes.values() for v in values if v > 0.0]
        ratio = max(nonzero) / min(nonzero)
        if ratio > MAX_WEIGHT_RATIO:
            text = ", ".join(f"{k} of norm {min(v):.3g} to {max(v):.3g}" for k, v in sizes.items())
            raise ValueError(
                f"the weights differ by a factor {ratio:.3g} ({text}); the scenario tree's QP "
                f"accepts at most {MAX_WEIGHT_RATIO:.0e} (its one matrix holds every weight and "
                "loses the small ones' digits beyond): bring Q, R and Psi closer, or use the "
                "one-step RecedingHorizonController, which accepts more"
            )

    def _check_magnitudes(self) -> None:
        """ValueError unless every matrix of every family is finite and at most
        :data:`controllers.rhc.MAX_QP_ENTRY` in magnitude (long horizons of unstable
        ``A + B K`` overflow)."""
        for fam in self._families.values():
            for name in ("Lx", "Lz", "chance_x", "cov_next", "tightening", "term_trace"):
                arr = getattr(fam, name)
                arr = arr.data if sp.issparse(arr) else arr
                worst = float(np.max(np.abs(arr))) if arr.size else 0.0
                if not worst <= MAX_QP_ENTRY:  # NaN included
                    raise ValueError(
                        f"the scenario tree of mode {fam.mode} with steps = {self.steps} has an "
                        f"entry of magnitude {worst:.3g} in {name} (K up to "
                        f"{float(np.max(np.abs(self.K))):.3g}, Psi up to "
                        f"{float(np.max(np.abs(self.Psi))):.3g}); every entry must be at most "
                        f"{MAX_QP_ENTRY:.0e}: lower steps, or use gains K that stabilize A + B K"
                    )

    # ------------------------------------------------------------------ probabilities
    def _region_q(self, fam: TreeFamily, x: np.ndarray, k: int, z: np.ndarray | None):
        """``q`` (S,) of the nodes ``tree.sq`` for the plan ``z`` (None: every ``nu = 0``)."""
        proj = fam.proj_x @ x
        if z is not None:
            proj = proj + fam.proj_z @ z
        model = self.model
        H = model.H0 + (k + fam.q_time)[:, None] * model.H_rate  # H_{k + t}
        return self._regions.probability(proj.reshape(fam.proj_sd.shape), fam.proj_sd, H)

    def _probabilities(self, fam: TreeFamily, q: np.ndarray) -> _Probabilities:
        tree = fam.tree
        branch = np.zeros((tree.size, self.model.N))
        branch[np.arange(tree.size), tree.mode] = 1.0  # nodes that do not branch
        if tree.branched[0] or self.steps == 1:  # the paper's row (branches or terminal weight)
            branch[0] = fam.P_row
        if tree.sq.size:
            branch[tree.sq] = fam.Pout_q + q[:, None] * fam.dP_q
        path = np.ones(tree.size)
        for idx in tree.by_stage[1:]:
            par = tree.parent[idx]
            path[idx] = path[par] * branch[par, tree.mode[idx]]
        weight = np.maximum(path, WEIGHT_FLOOR)
        return _Probabilities(q, branch, path, weight)

    # ------------------------------------------------------------------ the QP
    @staticmethod
    def _row_weights(fam: TreeFamily, pr: _Probabilities) -> tuple[np.ndarray, np.ndarray]:
        """``(v, wrow)``: the weight of each source (node, then last node and mode) and of
        each row of the objective."""
        last = fam.tree.last
        v = np.concatenate([pr.weight, (pr.weight[last, None] * pr.branch[last]).ravel()])
        return v, v[fam.row_source]

    def _qp(self, fam: TreeFamily, x: np.ndarray, k: int, pr: _Probabilities):
        """``(P, w)``: the Hessian and the instance ``[q; h]`` of the engine."""
        M, m = fam.size, self.model.m
        v, wrow = self._row_weights(fam, pr)
        d = fam.engine.d
        P = (fam.P_stack @ v).reshape(d, d)
        lx = fam.Lx @ x
        qlin = 2.0 * (fam.LzT @ (wrow * lx))
        qlin[M * m :] += self.alpha * pr.weight
        model = self.model
        band = model.H0 + (k + fam.chance_time)[:, None] * model.H_rate  # H_{k + t + 1}
        h_chance = (band - fam.tightening).ravel() + fam.chance_x @ x
        w = np.concatenate([qlin, h_chance, fam.h_fixed])
        return P, w

    def _objective(self, fam: TreeFamily, x, nu, rho, pr: _Probabilities) -> float:
        """``J`` at ``(nu, rho)`` with every constant term (Lemma 1's traces included): a sum of
        nonnegative terms, computed as such (no cancellation)."""
        _, wrow = self._row_weights(fam, pr)
        t = fam.Lx @ x + fam.Lz @ np.concatenate([nu.ravel(), rho])
        last = fam.tree.last
        return float(
            wrow @ (t * t)
            + pr.weight @ fam.stage_trace
            + np.sum(pr.weight[last, None] * pr.branch[last] * fam.term_trace)
            + self.alpha * (pr.weight @ rho)
        )

    def _excess(self, fam: TreeFamily, x: np.ndarray, k: int, nu: np.ndarray) -> np.ndarray:
        """Smallest feasible ``rho`` (M,) for the offsets ``nu`` (M, m); an excess within
        round-off of its row's terms is 0."""
        M, n = fam.size, self.model.n
        z = np.concatenate([nu.ravel(), np.zeros(M)])
        mean = (fam.mean_x @ x + fam.mean_z @ z).reshape(M, n)
        GAm = np.einsum("irn,in->ir", fam.GA, mean)
        GBnu = np.einsum("irm,im->ir", fam.GB, nu)
        model = self.model
        hbar = model.H0 + (k + fam.chance_time)[:, None] * model.H_rate - fam.tightening
        excess = GAm + GBnu - hbar
        terms = (
            np.einsum("irn,in->ir", np.abs(fam.GA), np.abs(mean))
            + np.einsum("irm,im->ir", np.abs(fam.GB), np.abs(nu))
            + np.abs(hbar)
        )
        excess = np.where(excess <= KKT_TOL * terms, 0.0, excess)
        return np.maximum(excess.max(axis=1), 0.0)

    def _solve(self, fam: TreeFamily, x: np.ndarray, k: int, pr: _Probabilities):
        """One QP with fixed probabilities: ``(nu (M, m), rho (M,), cost, status, path)``;
        ``cost`` is None unless a solver reported it (the caller computes the last one only)."""
        M, m = fam.size, self.model.m
        if self.solver == "cvxpy":
            out = solve_tree_cvxpy(self, fam, x, k, pr)
            if out is not None:
                nu, rho, cost = out
                return nu, rho, cost, "solved", "cvxpy"
            return self._answer(fam, x, k, np.zeros((M, m)), "fallback_nu0: cvxpy failed",
                                "fallback")  # fmt: skip
        P, w = self._qp(fam, x, k, pr)
        engine = fam.engine
        engine.update_P(P)
        notes: list[str] = []
        sol = engine.solve(w, warm=self._warm_start, notes=notes)
        path = None if sol is None else _PATHS.get(sol.path, sol.path)
        if sol is None and self.cvxpy_fallback:
            rescue = solve_condensed_cvxpy(P, w, engine)
            if rescue is None:
                notes.append("cvxpy failed")
            else:
                # the smallest feasible slacks for its offsets: a slack of small weight is left
                # loose within the solver's tolerance, which hides the active set
                z, y = rescue
                nu = np.clip(z[: M * m].reshape(M, m), -self.nu_bound, self.nu_bound)
                z = np.concatenate([nu.ravel(), self._excess(fam, x, k, nu)])
                sol = engine.local(z, w, y)
                path = "cvxpy"
                if sol is None:
                    notes.append("the cvxpy answer did not verify")
                    nu = z[: M * m].reshape(M, m)
                    return self._answer(fam, x, k, nu, "unverified: " + "; ".join(notes),
                                        "cvxpy")  # fmt: skip
        elif sol is None:
            notes.append("cvxpy retry disabled")
        if sol is None:
            return self._answer(fam, x, k, np.zeros((M, m)), "fallback_nu0: " + "; ".join(notes),
                                "fallback")  # fmt: skip
        z = np.asarray(sol.z)
        nb = self.nu_bound
        nu = np.clip(z[: M * m].reshape(M, m), -nb, nb)  # round-off outside U
        # rho = 0 where the bound rho >= 0 is active (the node's rows then hold to the KKT
        # test's tolerance), else the exact solution's (the excess of its worst row)
        rho = np.maximum(z[M * m :], 0.0)
        active = np.zeros(engine.c, dtype=bool)
        active[list(sol.rows)] = True
        rho[active[engine.c - M :]] = 0.0
        if not notes:
            status = "solved"
        else:
            status = f"solved {'by cvxpy ' if path == 'cvxpy' else ''}({'; '.join(notes)})"
        return nu, rho, None, status, path

    def _answer(self, fam, x, k, nu, status, path):
        """An answer that is not an exact verified one: ``nu`` projected on ``U`` and the
        smallest feasible slacks."""
        nu = np.clip(np.asarray(nu, dtype=np.float64), -self.nu_bound, self.nu_bound)
        return nu, self._excess(fam, x, k, nu), None, status, path

    # ------------------------------------------------------------------ decisions
    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """Plan on the tree at ``(x_k, theta_k, k)`` and return ``u_k = K_theta x_k + nu_0``.

        Parameters
        ----------
        x : (n,) array
        mode : int in ``[0, N)``
        k : int in ``[0, 2**53 - steps]`` (the tree reads the band ``H`` up to ``k + steps``)

        Returns
        -------
        u : (m,) float64 array
        info : dict
            ``"nu"`` (m,) and ``"rho"`` (float): the root's offset and slack; ``"cost"``: the
            optimal value of the tree's QP (every constant included; P3's ``J*`` when
            ``steps = 1``); ``"status"`` and ``"ok"`` as for
            :class:`controllers.RecedingHorizonController` (``"solved"``: verified optimal);
            ``"solver"``: the path of the last solve; ``"in_region"``; ``"plan"``: a
            :class:`TreePlan`; ``"iterations"``: QP solves; ``"fixed_point_gap"``: the largest
            change of a region probability that the last solve would cause (0 when the
            probabilities do not depend on the plan).
        """
        x, mode, k = self._check_inputs(x, mode, k)
        with self._lock:
            inside = max(self.model.constraint_values_one(x, k).tolist()) <= 0.0
            fam = self._families[(mode, inside)]
            depends = bool(fam.tree.sq.size) and bool(np.any(fam.dP_q))
            q = self._region_q(fam, x, k, None)  # the plan of nu = 0
            gap, last_gap, step = 0.0, math.inf, 1.0
            for it in range(1, self.iterations + 1):
                pr = self._probabilities(fam, q)
                nu, rho, cost, status, path = self._solve(fam, x, k, pr)
                counts = self._path_counts
                counts[path] = counts.get(path, 0) + 1
                if not depends:
                    break
                z = np.concatenate([nu.ravel(), rho])
                q_new = self._region_q(fam, x, k, z)
                gap = float(np.max(np.abs(q_new - q)))
                if gap <= PROB_TOL or it == self.iterations:
                    break
                if gap > last_gap:  # oscillation: damp
                    step *= DAMPING
                last_gap = gap
                q = q + step * (q_new - q)
            if cost is None:
                cost = self._objective(fam, x, nu, rho, pr)
            plan = self._plan(fam, x, k, pr, nu, rho)
        m = self.model.m
        u = self.K[mode] @ x + nu[0]  # eq. (eq:stabilization_input)
        info = {
            "nu": np.array(nu[0], dtype=np.float64).reshape(m),
            "rho": float(rho[0]),
            "cost": float(cost),
            "status": status,
            "ok": status == "solved" or status.startswith("solved "),
            "solver": path,
            "in_region": bool(inside),
            "plan": plan,
            "iterations": it,
            "fixed_point_gap": gap,
        }
        return np.asarray(u, dtype=np.float64), info

    def _plan(self, fam: TreeFamily, x, k, pr: _Probabilities, nu, rho) -> TreePlan:
        M, n = fam.size, self.model.n
        tree = fam.tree
        z = np.concatenate([nu.ravel(), rho])
        mean = (fam.mean_x @ x + fam.mean_z @ z).reshape(M, n)
        At = self.A_tilde[tree.mode]
        next_mean = np.einsum("ian,in->ia", At, mean) + np.einsum(
            "iam,im->ia", self.model.B[tree.mode], nu
        )
        out = TreePlan(
            k=int(k),
            mode=tree.mode,
            parent=tree.parent,
            stage=tree.stage,
            children=tree.children,
            probability=pr.path,
            branch=pr.branch,
            mean=mean,
            cov=fam.cov,
            next_mean=next_mean,
            next_cov=fam.cov_next,
            nu=nu,
            rho=rho,
            tightening=fam.tightening,
        )
        return out
