"""One QP of the scenario tree with fixed probabilities: its data, its solve, its answer.

:class:`TreeSolver` is the part of :class:`controllers.ScenarioTreeController` that turns the
tree's probabilities into the engine's QP (:meth:`TreeSolver._qp`), solves it by the chain of
:mod:`controllers.tree_qp` (then continuation in the state, the approximate answer without the
nodes of negligible probability, the cvxpy rescue, ``nu = 0``) and reads the verified answer
(:meth:`TreeSolver._exact`). Every answer called solved passed the KKT test of
:mod:`controllers.kkt`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .horizon import HorizonSettings, Status
from .kkt import KKT_TOL
from .tree_data import TreeFamily
from .tree_qp import solve_condensed_cvxpy, solve_tree_cvxpy

if TYPE_CHECKING:
    from sdjls_gym.model import SDJLSModel

    from .tree_region import RegionClasses

__all__ = [
    "CONTINUATION_FROM",
    "CONTINUATION_STEP",
    "NEWTON_STEPS",
    "TINY_PROBABILITY",
    "TreeSolver",
]

#: Nodes of positive path probability below this are weighted exactly; only when the exact
#: answer cannot be verified (the KKT test cannot resolve multipliers this many times smaller
#: than the root's) are they left out, and the answer is reported as "approximate" (ok False).
TINY_PROBABILITY = 1e-12

#: When the chain fails at a state larger than this, the QP is solved by continuation from the
#: state scaled to this size, by factors of ``CONTINUATION_STEP`` (see ``_continuation``).
CONTINUATION_FROM = 1e3
CONTINUATION_STEP = 1e3

#: Newton's steps on the line of :meth:`TreeSolver._newton` at most (enough for the decisions
#: of the example's closed loop to converge at their second solve; results/speed/HISTORY.md).
NEWTON_STEPS = 3

_PATHS = {
    "warm": "active_set_warm",
    "recent": "active_set_recent",
    "repair": "active_set_repair",
    "enumeration": "active_set",
}

_TOKENS = itertools.count()  # one per Hessian built (see TreeQP.update_P)


@dataclass
class _Probabilities:
    """The probabilities one QP is built with, and what depends on them alone (set by
    :meth:`TreeSolver._weigh` where they are made; a family keeps the probabilities of recent
    ``q``, :attr:`controllers.tree_data.TreeFamily.weights`, so that a decision meeting the same
    ``q`` again, as the closed loop does where the region probabilities saturate, builds
    nothing)."""

    q: np.ndarray  # (S,) region probabilities of the nodes tree.sq
    branch: np.ndarray  # (M, N)
    path: np.ndarray  # (M,)
    weight: np.ndarray  # (M,) the path probabilities that weight the objective (= path)
    idle: np.ndarray  # (M,) bool: nodes of path probability 0 (left out of the QP)
    P: np.ndarray | None = None  # (d, d) read-only: the Hessian
    wrow: np.ndarray | None = None  # (R,) the weight of each row of the objective
    const: float = 0.0  # the objective's constant terms (Lemma 1's traces)
    token: int = -1  # identifies P for the engine's caches
    idle_z: np.ndarray | None = None  # the variables of idle nodes (None: no idle node)
    idle_rows: np.ndarray | None = None  # (M r,) bool: their chance rows


@dataclass
class _Context:
    """What one decision computes once: the parts of the QP and of the region probabilities
    that depend on the state and the time alone (not on the probabilities)."""

    lx: np.ndarray  # (R,) Lx x
    h_chance: np.ndarray  # (M r,) the chance rows' bounds: band - tightening + chance_x x
    proj0: np.ndarray  # (S, classes) the projections of the nodes tree.sq's means at nu = 0
    limits: tuple  # RegionClasses.limits of the bands H_{k + t} of those nodes
    bands: np.ndarray  # (S, r) those bands


class TreeSolver:
    """The QP methods of :class:`controllers.ScenarioTreeController` (a mixin: it reads the
    controller's ``model``, ``settings``, ``steps``, ``alpha``, ``nu_bound``, ``solver``,
    ``cvxpy_fallback`` and ``_warm_start``)."""

    # set by the controller (annotations only: no class attributes)
    model: SDJLSModel
    settings: HorizonSettings
    steps: int
    alpha: float
    nu_bound: float
    solver: str
    cvxpy_fallback: bool
    _warm_start: bool
    _regions: RegionClasses
    _rows: tuple[int, ...] | None

    def _weigh(self, fam: TreeFamily, pr: _Probabilities) -> None:
        """Set the parts of ``pr`` that depend on the probabilities alone: the Hessian, the
        weight of each row of the objective (from the weight of each source: node, then last
        node and mode), the objective's constant terms and the idle nodes' variables and rows.

        A node of path probability 0 (and its subtree) weighs nothing: its offset and slack
        appear in no other node's cost or rows, so they are decoupled exactly, with unit
        curvature, no linear cost and chance rows made slack for every ``z`` (their optimum is
        then ``nu = rho = 0``; the plan reports their smallest feasible slacks)."""
        M, m, r = fam.size, self.model.m, self.model.r
        last = fam.tree.last
        end = pr.weight[last, None] * pr.branch[last]
        v = np.concatenate([pr.weight, end.ravel()])
        d = fam.engine.d
        P = (fam.P_stack @ v).reshape(d, d)
        if pr.idle.any():
            nodes = np.flatnonzero(pr.idle)
            idle = np.concatenate([(nodes[:, None] * m + np.arange(m)).ravel(), M * m + nodes])
            P[idle, :] = 0.0
            P[:, idle] = 0.0
            P[idle, idle] = 1.0
            pr.idle_z, pr.idle_rows = idle, np.repeat(pr.idle, r)
        P.flags.writeable = False
        pr.P, pr.wrow = P, v[fam.row_source]
        pr.const = float(pr.weight @ fam.stage_trace + np.sum(end * fam.term_trace))
        pr.token = next(_TOKENS)

    def _context(self, fam: TreeFamily, x: np.ndarray, k: int) -> _Context:
        """The :class:`_Context` of a decision at ``(x, k)``."""
        model = self.model
        band = model.H0 + (k + fam.chance_time)[:, None] * model.H_rate  # H_{k + t + 1}
        h_chance = (band - fam.tightening).ravel() + fam.chance_x @ x
        H = model.H0 + (k + fam.q_time)[:, None] * model.H_rate  # H_{k + t}
        proj0 = (fam.proj_x @ x).reshape(fam.proj_sd.shape)
        return _Context(fam.Lx @ x, h_chance, proj0, self._regions.limits(H), H)

    def _qp(
        self,
        fam: TreeFamily,
        x: np.ndarray,
        k: int,
        pr: _Probabilities,
        ctx: _Context | None = None,
    ):
        """``(P, w)``: the Hessian (read-only) and the instance ``[q; h]`` of the engine
        (``ctx``: the decision's :class:`_Context` at ``(x, k)``, when the caller has it); idle
        nodes as in :meth:`_weigh`."""
        M, m = fam.size, self.model.m
        ctx = self._context(fam, x, k) if ctx is None else ctx
        qlin = 2.0 * (fam.LzT @ (pr.wrow * ctx.lx))
        qlin[M * m :] += self.alpha * pr.weight
        h_chance = ctx.h_chance
        if pr.idle_z is not None:
            qlin[pr.idle_z] = 0.0
            rows = pr.idle_rows
            h_chance = h_chance.copy()
            h_chance[rows] = np.maximum(h_chance[rows], fam.idle_bound[rows])
        w = np.concatenate([qlin, h_chance, fam.h_fixed])
        return pr.P, w

    def _objective(self, fam: TreeFamily, x, nu, rho, pr: _Probabilities, ctx=None) -> float:
        """``J`` at ``(nu, rho)`` with every constant term (Lemma 1's traces included): a sum of
        nonnegative terms, computed as such (no cancellation)."""
        lx = fam.Lx @ x if ctx is None else ctx.lx
        t = lx + fam.Lz @ np.concatenate([nu.ravel(), rho])
        return float(pr.wrow @ (t * t) + pr.const + self.alpha * (pr.weight @ rho))

    def _newton(self, fam: TreeFamily, ctx: _Context, pr: _Probabilities, z, q, q_new, tol):
        """The region probabilities ``q + t delta`` where the fixed-point residual ``F - q`` is
        smallest along the step ``delta = F(q) - q`` (``F``: the region probabilities of the
        plan; ``z`` the answer at ``q``, of active set ``self._rows``), or None. Along that line
        the answer is taken linear in ``t``, its derivative that of the exact solve with the
        active set held (:meth:`controllers.tree_qp.TreeQP.direction`: the same factors applied
        to the change of the QP's data; no new factorization), and the region probabilities are
        evaluated exactly; Newton's steps on ``t`` (the slope by a forward difference) stop at a
        residual of ``tol`` or after :data:`NEWTON_STEPS`."""
        if self._rows is None:
            return None
        if pr.idle_z is not None:
            return None
        delta = q_new - q
        M, m = fam.size, self.model.m
        tree = fam.tree
        # the derivatives along delta of the branch and path probabilities, then of the weights
        # v of the sources (node, then last node and mode): forward through the stages
        dbranch = np.zeros_like(pr.branch)
        dbranch[tree.sq] = delta[:, None] * fam.dP_q
        dpath = np.zeros(M)
        for idx in tree.by_stage[1:]:
            par, mode = tree.parent[idx], tree.mode[idx]
            dpath[idx] = dpath[par] * pr.branch[par, mode] + pr.path[par] * dbranch[par, mode]
        last = tree.last
        dend = dpath[last, None] * pr.branch[last] + pr.path[last, None] * dbranch[last]
        dv = np.concatenate([dpath, dend.ravel()])
        d = fam.engine.d
        dq = (fam.P_stack @ dv).reshape(d, d) @ z + 2.0 * (fam.LzT @ (dv[fam.row_source] * ctx.lx))
        dq[M * m :] += self.alpha * dpath
        dz = fam.engine.direction(self._rows, np.concatenate([dq, np.zeros(fam.engine.c)]))
        if dz is None:
            return None
        shape = ctx.proj0.shape
        proj = ctx.proj0 + (fam.proj_z @ z).reshape(shape)
        dproj = (fam.proj_z @ dz).reshape(shape)
        size = float(np.max(np.abs(dproj) / np.maximum(fam.proj_sd, 1e-300)))
        if not (math.isfinite(size) and size > 0.0):
            return None
        h = 1e-4 / size  # a step of 1e-4 standard deviations
        regions = self._regions

        def residual(t: float) -> np.ndarray:  # F - q along the line, the answer linear in t
            return regions.probability_within(proj + t * dproj, fam.proj_sd, ctx.limits) - (
                q + t * delta
            )

        slope = (residual(h) - delta) / h  # residual(0) = delta
        norm = float(slope @ slope)
        if not norm > 0.0:
            return None
        t, r = 0.0, delta
        for _ in range(NEWTON_STEPS):  # Newton on the line (Gauss-Newton: r has S components)
            t -= float(r @ slope) / norm
            if not 0.0 < t <= 10.0:
                return None
            r = residual(t)
            if float(np.max(np.abs(r))) <= tol:
                break
        return np.minimum(np.maximum(q + t * delta, 0.0), 1.0)

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

    def _solve(
        self,
        fam: TreeFamily,
        x: np.ndarray,
        k: int,
        pr: _Probabilities,
        notes: list,
        ctx: _Context | None = None,
    ):
        """One QP with fixed probabilities: ``(nu (M, m), rho (M,), cost, status, path)``;
        ``cost`` is None unless a solver reported it (the caller computes the last one only);
        ``notes`` receives what failed on the way. Whatever path found the answer (the warm
        active set, DAQP, OSQP, cvxpy), it is called solved only after the engine's KKT test
        (:mod:`controllers.kkt`)."""
        M, m = fam.size, self.model.m
        P, w = self._qp(fam, x, k, pr, ctx)
        engine = fam.engine
        engine.update_P(P, pr.token)
        if self.solver == "cvxpy":  # the plain reference, its active set verified
            engine.open_budget()  # (the fast path's solve opens it, and its rescue shares it)
            out = solve_tree_cvxpy(self.settings, self.steps, fam, x, k, pr)
            if out is None:
                notes.append("cvxpy failed")
                return self._answer(fam, x, k, np.zeros((M, m)), Status.FALLBACK_NU0, "fallback")
            return self._verified(fam, x, k, pr, w, out[0], None, notes, "cvxpy")
        sol = engine.solve(w, warm=self._warm_start, notes=notes)
        if sol is None:
            sol = self._continuation(fam, x, k, pr, notes)
        if sol is not None:
            nu, rho = self._exact(fam, x, k, pr, sol)
            return nu, rho, None, Status.SOLVED, _PATHS.get(sol.path, sol.path)
        tiny = (pr.path > 0.0) & (pr.path < TINY_PROBABILITY)
        if tiny.any():  # the test cannot resolve their weights: an answer without them
            rough = _Probabilities(pr.q, pr.branch, pr.path, pr.weight, pr.idle | tiny)
            self._weigh(fam, rough)
            P2, w2 = self._qp(fam, x, k, rough, ctx)
            engine.update_P(P2, rough.token)
            sol = engine.solve(w2, warm=False, notes=[])
            if sol is not None:
                nu, rho = self._exact(fam, x, k, rough, sol)
                notes.append(
                    f"{int(tiny.sum())} nodes of path probability below {TINY_PROBABILITY:g} "
                    "left out"
                )
                return nu, rho, None, Status.APPROXIMATE, _PATHS.get(sol.path, sol.path)
            engine.update_P(P, pr.token)
        if not self.cvxpy_fallback:
            notes.append("cvxpy retry disabled")
        else:
            rescue = solve_condensed_cvxpy(P, w, engine)
            if rescue is not None:
                z, y = rescue
                nu0 = z[: M * m].reshape(M, m)
                return self._verified(fam, x, k, pr, w, nu0, y, notes, "cvxpy")
            notes.append("cvxpy failed")
        return self._answer(fam, x, k, np.zeros((M, m)), Status.FALLBACK_NU0, "fallback")

    def _continuation(self, fam: TreeFamily, x: np.ndarray, k: int, pr: _Probabilities, notes):
        """The QP at a huge state by continuation in the state: its data are affine in ``x``
        and its Hessian does not depend on ``x``, so the instances at ``t x`` for ``t`` growing
        by :data:`CONTINUATION_STEP` from ``|t x| = CONTINUATION_FROM`` to ``t = 1`` are solved
        in turn, each started from the last one's active set. A function of ``(x, k)`` and the
        probabilities only: a state of size 1e30 makes the linear term 1e30 times the Hessian,
        where the solvers fail from a cold start. None if a step fails (or ``x`` is small)."""
        size = float(np.max(np.abs(x), initial=0.0))
        if not size > CONTINUATION_FROM:
            return None
        engine = fam.engine
        t, warm, sol = CONTINUATION_FROM / size, False, None
        while True:
            sol = engine.solve(self._qp(fam, t * x, k, pr)[1], warm=warm)
            if sol is None:
                return None
            if t == 1.0:
                notes.append(f"by continuation from {CONTINUATION_FROM:g} / |x| times the state")
                return sol
            t, warm = min(1.0, t * CONTINUATION_STEP), True

    def _verified(self, fam, x, k, pr: _Probabilities, w, nu, y, notes: list[str], path: str):
        """The answer of a solver outside the engine (offsets ``nu`` (M, m), multipliers ``y``
        or None): its active set re-solved exactly and verified by the engine's KKT test
        (then solved), else unverified with its offsets and their smallest feasible slacks."""
        M, m = fam.size, self.model.m
        nu = np.clip(np.asarray(nu, dtype=np.float64).reshape(M, m), -self.nu_bound, self.nu_bound)
        nu[pr.idle] = 0.0
        # the smallest feasible slacks for its offsets: a slack of small weight is left loose
        # within the solver's tolerance, which hides the active set
        rho = self._excess(fam, x, k, nu)
        rho[pr.idle] = 0.0
        engine = fam.engine
        z = np.concatenate([nu.ravel(), rho])
        sol = engine.local(z, w, y)
        if sol is None:
            # an offset of tiny path probability is determined by the objective only to about
            # sqrt(tolerance / probability): complete the active set with DAQP, started from
            # the rows the answer leaves nearly active, and verify again
            near = tuple(engine.near_active(z, w, loose=True).tolist())
            z2, y2, _ = engine.run_daqp(w, near)
            sol = None if z2 is None else engine.local(z2, w, y2)
            if sol is not None:
                notes.append(f"the {path} answer's active set completed by daqp")
        if sol is None:
            notes.append(f"the {path} answer did not verify")
            return self._answer(fam, x, k, nu, Status.UNVERIFIED, path)
        nu, rho = self._exact(fam, x, k, pr, sol)
        return nu, rho, None, Status.SOLVED, path

    def _exact(self, fam: TreeFamily, x, k, pr: _Probabilities, sol) -> tuple:
        """``(nu, rho)`` of a verified solution: ``rho = 0`` where the bound ``rho >= 0`` is
        active (the node's rows then hold at the returned offsets to the KKT test's tolerance
        of their own terms), else the exact solution's; the smallest feasible slacks at the
        nodes of path probability 0 (left out of the QP)."""
        M, m = fam.size, self.model.m
        engine = fam.engine
        z = np.asarray(sol.z)
        self._rows = sol.rows
        nb = self.nu_bound
        nu = np.minimum(np.maximum(z[: M * m].reshape(M, m), -nb), nb)  # round-off outside U
        rho = np.maximum(z[M * m :], 0.0)
        first = engine.c - M  # the rows rho >= 0 are the last M
        bound = [i - first for i in sol.rows if i >= first]
        if bound:
            rho[bound] = 0.0
        if pr.idle.any():  # decoupled: their exact optimum is nu = 0
            nu[pr.idle] = 0.0
            rho[pr.idle] = self._excess(fam, x, k, nu)[pr.idle]
        return nu, rho

    def _answer(self, fam, x, k, nu, status, path):
        """An answer that is not an exact verified one: ``nu`` projected on ``U`` and the
        smallest feasible slacks."""
        nu = np.clip(np.asarray(nu, dtype=np.float64), -self.nu_bound, self.nu_bound)
        return nu, self._excess(fam, x, k, nu), None, status, path
