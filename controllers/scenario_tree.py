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
``q`` from the new plan's means and repeats (fixed-point iterations, at most ``iterations``
solves; :data:`PROB_TOL` ends them early, and so does an answer of the fast path that is not
verified). They start from the plan of ``nu = 0`` with each node's mean moved into the interval
that its parent's chance rows allow (per class of parallel rows of ``G``, the nearest point):
where the optimum keeps a row active, that is where it puts the mean, and the first solve then
confirms the start (most decisions take one solve; results/speed/HISTORY.md). When it does not,
the next ``q`` is Newton's step along the first move, ``q + t (q(plan) - q)``: the answer's
change along that line is that of its active set held (the exact solve applied to the change of
the QP's data, no new factorization), the region probabilities are evaluated exactly along it,
and ``t`` makes the residual ``q(plan) - q`` smallest (one solve fewer than the plain
iteration). Later steps are damped iterations with Aitken's extrapolation.
This is an approximation of the state-dependent jumps in two ways: ``q`` is evaluated at the
plan instead of being part of the optimization, and the Gaussian law of a node's state given
its path ignores that a mode drawn from a random state tilts that state's law (the law of the
next state is exactly Gaussian at the root and at stage 1, whose modes were drawn from the known
``x_k``). It is exact when ``steps = 1`` (P3), when ``P_in == P_out`` (the jumps do not depend
on the state) and when ``q`` is robustly 0 or 1; the root's constraint and the first input are
always P3's (the probability that each row of ``x_{k+1}`` holds is ``>= xi`` whenever
``rho_0 = 0``, exactly). No plan is carried from one decision to the next: the start is a
function of ``(x, mode, k)``, and so is the answer.
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
``solver="daqp"`` (default): the tree's topology and constraint matrix are fixed per (mode,
region) family; one :class:`controllers.tree_qp.TreeQP` per family (a
:class:`controllers.qp.QPFamily`) has its Hessian updated at every solve (the path probabilities
weight the stage costs) and is warm started: the last active set is re-solved exactly for the
new data, then the sets optimal before it, then the last one is repaired by primal-dual
active-set steps (these two while they pay), then DAQP finds the active set (OSQP too, on small
trees), which is re-solved exactly; the answer is verified by the KKT test. On a large tree far
from its warm set (the first solve at a new state), Clarabel's interior-point answer indicates
the active set first (:mod:`controllers.qp_ipm`), verified in turn, and DAQP starts from it when
it fails. Whatever depends only on the probabilities (the
Hessian, the weights of the objective's rows, and per active set the reduced Hessian and, once
met again, the exact solve as two matrices) is kept for the probabilities met again, as they are
wherever the chance rows are active. After failures the condensed QP goes to cvxpy + Clarabel
(its active set verified), and as a last resort every ``nu = 0`` with the smallest feasible
slacks. ``solver="osqp"``: the same with OSQP instead of DAQP (on a tree of more than 64
variables OSQP runs once, then DAQP from its iterate). ``solver="cvxpy"``: the same tree
written plainly in cvxpy (rebuilt at every solve, solved by Clarabel), the reference the tests
compare against.

Thread-safe (the base class's lock) and picklable.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import check_int

if sys.version_info >= (3, 11):
    from typing import Unpack
else:  # pragma: no cover
    from typing_extensions import Unpack

from .horizon import MAX_QP_ENTRY, HorizonKwargs, RecedingHorizonBase, Status, shows_settings
from .tree_data import (
    FamilyCache,
    RegionClasses,
    TreeFamily,
    build_tree_family,
    check_tree_size,
    family_magnitudes,
)
from .tree_solve import TINY_PROBABILITY, TreeSolver, _Context, _Probabilities

__all__ = [
    "DAMPING",
    "MAX_WEIGHT_RATIO",
    "PROB_TOL",
    "TINY_PROBABILITY",
    "ScenarioTreeController",
    "TreePlan",
]

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


def _aitken(q0: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Aitken's extrapolation of three fixed-point iterates ``q1 = F(q0)``, ``q2 = F(q1)``:
    per component, ``q2 + r (q2 - q1) / (1 - r)`` with ``r = (q2 - q1) / (q1 - q0)`` (the
    limit of a linearly converging sequence); ``q2`` itself unless every ratio is within
    ``[-0.5, 0.5]`` (a contraction), clipped to ``[0, 1]``."""
    d1, d2 = q1 - q0, q2 - q1
    moved = d1 != 0.0
    r = np.divide(d2, d1, out=np.zeros_like(d2), where=moved)
    if not (np.all(np.abs(r) <= 0.5) and np.all(d2[~moved] == 0.0)):
        return q2
    return np.clip(q2 + r / (1.0 - r) * d2, 0.0, 1.0)


@shows_settings
class ScenarioTreeController(TreeSolver, RecedingHorizonBase):
    """Multi-step receding-horizon control on a scenario tree of modes (beyond the paper).

    See the module docstring for the problem, its approximation of the state-dependent jumps
    and where it is exact.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n) array
        Pre-stabilising gains of ``u = K_theta x + nu``.
    steps : int
        Horizon of the tree, ``>= 1`` (``steps = 1`` is problem P3).
    branching : int, optional
        Stages that branch, in ``[0, steps]`` (default: ``steps``, every stage). From stage
        ``branching`` on, a node has one child with its own mode; ``branching = 0`` plans along
        the current mode only (the terminal weights still use the branch probabilities).
    iterations : int
        Largest number of QP solves per decision (fixed-point iterations on the branch
        probabilities), ``>= 1``.
    **settings
        The settings of every receding-horizon controller, keyword, with the names, types,
        defaults and checks of :class:`controllers.horizon.RecedingHorizonBase`
        (:class:`~controllers.horizon.HorizonKwargs`): ``Psi`` the terminal weights (required),
        ``xi`` the chance-constraint level (required), ``constraint``, ``alpha``, ``nu_bound``,
        ``solver``, ``nu_set``, ``horizon``, ``osqp_settings``, ``cvxpy_fallback``. Here each
        slack is penalized by ``alpha`` times its node's path probability, ``solver`` is
        ``"daqp"``, ``"osqp"`` or ``"cvxpy"`` and ``nu_set`` ``"box"`` only.

    Raises
    ------
    TypeError, ValueError
        Bad arguments (the message names the argument), including a tree of more than
        :data:`controllers.tree_data.MAX_TREE_VARIABLES` QP variables.

    Notes
    -----
    A model without gains or terminal weights of its own: :meth:`from_model` synthesizes ``K``
    (Proposition 2) and takes the MJLS LQ value matrices as ``Psi``.

    Thread-safe: calls on one controller are serialized by its lock, and answers do not depend
    on earlier calls (no plan is carried between decisions, and every answer of the fast path is
    the exact solution of a verified active set, whichever path found it; only degenerate
    problems, where several active sets verify, can differ by round-off). Picklable.
    :attr:`path_counts` counts the QP solves per path.

    Examples
    --------
    >>> from sdjls_gym.systems.macro import macro, PAPER_K, PAPER_RHC
    >>> ctrl = ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=3)
    >>> u, info = ctrl.act([2.0, 2.0], 0, 0)
    >>> info["rho"], info["status"] == "solved", info["plan"].mode.shape
    (0.0, True, (13,))
    """

    NU_SETS = ("box",)

    def __init__(
        self,
        model: SDJLSModel,
        K: np.ndarray,
        *,
        steps: int = 3,
        branching: int | None = None,
        iterations: int = 10,
        **settings: Unpack[HorizonKwargs],
    ) -> None:
        super().__init__(model, K, **settings)
        self.steps = check_int("steps", steps, low=1, what="stages of the tree")
        self._lookahead = self.steps  # the chance constraints read H up to k + steps
        if branching is None:
            self.branching = self.steps
        else:
            self.branching = check_int(
                "branching", branching, low=0, high=self.steps, what="stages that branch"
            )
        self.iterations = check_int(
            "iterations", iterations, low=1, high=100, what="QP solves per decision"
        )
        check_tree_size(self.model, self.steps, self.branching)
        self._check_weight_ratio()
        self._regions = RegionClasses(self.model.G)
        self._check_magnitudes()
        #: the families, built when a decision first needs one (within a memory budget)
        self._families = FamilyCache(self._build_family)
        self._records: dict[str, list[int]] = {}  # the families' warm tries (share_records)
        self._rows: tuple[int, ...] | None = None  # the active set of the last verified answer

    @property
    def families_built(self) -> int:
        """How many (mode, region) families this controller has built so far (on first use; a
        family dropped from the memory budget and needed again counts twice): a decision that
        raised it paid a family's set-up."""
        return self._families.built

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
        ``A + B K`` overflow); from the nodes' laws, without building the families."""
        for mode in range(self.model.N):
            for inside in (True, False):
                magnitudes = family_magnitudes(
                    self.settings, self.steps, self.branching, mode, inside
                )
                for name, worst in magnitudes.items():
                    if not worst <= MAX_QP_ENTRY:
                        raise ValueError(
                            f"the scenario tree of mode {mode} with steps = {self.steps} has an "
                            f"entry of magnitude {worst:.3g} in {name} (K up to "
                            f"{float(np.max(np.abs(self.K))):.3g}, Psi up to "
                            f"{float(np.max(np.abs(self.Psi))):.3g}); every entry must be at "
                            f"most {MAX_QP_ENTRY:.0e}: lower steps, or use gains K that "
                            "stabilize A + B K"
                        )

    def _build_family(self, mode: int, inside: bool) -> TreeFamily:
        fam = build_tree_family(
            self.settings, self.steps, self.branching, mode, inside, self._regions
        )
        fam.engine.share_records(self._records)
        return fam

    # ------------------------------------------------------------------ probabilities
    def _region_q(self, fam: TreeFamily, ctx: _Context, z: np.ndarray) -> np.ndarray:
        """``q`` (S,) of the nodes ``tree.sq`` for the plan ``z`` of the decision ``ctx``."""
        proj = ctx.proj0 + (fam.proj_z @ z).reshape(ctx.proj0.shape)
        return self._regions.probability_within(proj, fam.proj_sd, ctx.limits)

    def _start_q(self, fam: TreeFamily, ctx: _Context) -> np.ndarray:
        """The ``q`` (S,) the fixed-point iterations start from: that of the plan of ``nu = 0``
        with each node's mean moved into the interval its parent's chance rows allow (where
        the optimum puts it when those rows are active); where that interval is empty (the
        rows cannot hold), the mean stays where it is."""
        regions = self._regions
        lo, hi, nonempty, _ = regions.limits(ctx.bands - fam.q_tightening)
        proj = np.where(nonempty, np.minimum(np.maximum(ctx.proj0, lo), hi), ctx.proj0)
        return regions.probability_within(proj, fam.proj_sd, ctx.limits)

    def _probabilities(self, fam: TreeFamily, q: np.ndarray) -> _Probabilities:
        """The :class:`_Probabilities` of the region probabilities ``q`` (cached per family)."""
        return fam.weights.get(q.tobytes(), self._new_probabilities, fam, q)

    def _branch_path(self, fam: TreeFamily, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The branch (M, N) and path (M,) probabilities of the region probabilities ``q``."""
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
        return branch, path

    def _new_probabilities(self, fam: TreeFamily, q: np.ndarray) -> _Probabilities:
        q = q.copy()
        q.flags.writeable = False
        branch, path = self._branch_path(fam, q)
        pr = _Probabilities(q, branch, path, path, path == 0.0)
        self._weigh(fam, pr)
        return pr

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
            ``steps = 1``); ``"status"``, ``"notes"`` and ``"ok"`` as for
            :class:`controllers.RecedingHorizonController` (``"solved"``: verified optimal),
            plus the statuses ``"unconverged"`` and ``"approximate"`` (see
            :class:`controllers.Status`); ``"solver"``: the path of the last solve;
            ``"in_region"``; ``"plan"``: a :class:`TreePlan`; ``"iterations"``: QP solves;
            ``"fixed_point_gap"``: the largest change of a region probability that the last
            solve would cause (0 when the probabilities do not depend on the plan);
            ``"converged"``: whether that gap is at most :data:`PROB_TOL`. ``"ok"`` is True only
            for a verified QP answer at a converged fixed point; a verified answer whose fixed
            point did not converge within ``iterations`` solves has the status
            ``"unconverged"`` (the notes say by how much).
        """
        x, mode, k = self._check_inputs(x, mode, k)
        with self._lock:
            inside = self.model.in_region_one(x, k)
            fam = self._families[(mode, inside)]
            depends = fam.depends
            ctx = self._context(fam, x, k)
            q = self._start_q(fam, ctx) if depends else np.zeros(fam.tree.sq.size)
            gap, last_gap, step = 0.0, math.inf, 1.0
            prev: tuple[np.ndarray, np.ndarray] | None = None  # the last undamped step
            for it in range(1, self.iterations + 1):
                pr = self._probabilities(fam, q)
                notes: list[str] = []
                nu, rho, cost, status, path = self._solve(fam, x, k, pr, notes, ctx)
                self._count(path)
                if not depends:
                    break
                z = np.concatenate([nu.ravel(), rho])
                q_new = self._region_q(fam, ctx, z)
                gap = float(np.max(np.abs(q_new - q)))
                if gap <= PROB_TOL or it == self.iterations or self._fails(status):
                    break
                if it == 1 and status is Status.SOLVED:
                    q_next = self._newton(fam, ctx, pr, z, q, q_new, 1e-3 * PROB_TOL)
                    if q_next is not None:
                        last_gap, q = gap, q_next
                        continue
                if gap > last_gap:  # oscillation: damp
                    step *= DAMPING
                last_gap = gap
                if step == 1.0 and prev is not None and np.array_equal(prev[1], q):
                    q_next = _aitken(prev[0], q, q_new)
                    prev = None
                else:
                    prev = (q, q_new)
                    q_next = q + step * (q_new - q)
                q = q_next
            if cost is None:
                cost = self._objective(fam, x, nu, rho, pr, ctx)
            plan = self._plan(fam, x, k, pr, nu, rho)
        converged = gap <= PROB_TOL
        if status is Status.SOLVED and not converged:  # the QP is solved, not the fixed point
            status = Status.UNCONVERGED
            notes.append(
                f"the last QP was solved, but a region probability still moves by {gap:.2g} > "
                f"PROB_TOL = {PROB_TOL:g} after {it} solves (iterations = {self.iterations})"
            )
        m = self.model.m
        u = self.K[mode] @ x + nu[0]  # eq. (eq:stabilization_input)
        info = {
            "nu": np.array(nu[0], dtype=np.float64).reshape(m),
            "rho": float(rho[0]),
            "cost": float(cost),
            "status": status,
            "notes": "; ".join(notes),
            "ok": status is Status.SOLVED,
            "solver": path,
            "in_region": bool(inside),
            "plan": plan,
            "iterations": it,
            "fixed_point_gap": gap,
            "converged": converged,
        }
        return np.asarray(u, dtype=np.float64), info

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray | int
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`act` for each state of a batch (a loop). Returns ``u`` (B, m) and the arrays
        ``"nu"`` (B, m), ``"rho"``, ``"cost"``, ``"status"``, ``"notes"``, ``"ok"`` (B,); an
        empty batch gives empty arrays."""
        x, mode, k = self._check_batch_inputs(x, mode, k)
        return self._act_each(x, mode, k)

    def _fails(self, status: Status) -> bool:
        """Whether a QP's answer ends the fixed-point iterations: on the fast path, an answer
        that is not verified (the decision is not, whatever follows, and the next QPs, nearby,
        fail alike: a 33-node tree failed nine in a row, 2,300 factorizations each). The
        cvxpy reference iterates on its own answers, verified or not."""
        return self.solver != "cvxpy" and status in (Status.UNVERIFIED, Status.FALLBACK_NU0)

    def _plan(self, fam: TreeFamily, x, k, pr: _Probabilities, nu, rho) -> TreePlan:
        M, n = fam.size, self.model.n
        tree = fam.tree
        z = np.concatenate([nu.ravel(), rho])
        mean = (fam.mean_x @ x + fam.mean_z @ z).reshape(M, n)
        At, Bt = self.A_tilde[tree.mode], self.model.B[tree.mode]
        next_mean = (At @ mean[:, :, None] + Bt @ nu[:, :, None])[:, :, 0]
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
