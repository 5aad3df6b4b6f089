"""The scenario tree of modes and its QP data, for :class:`controllers.ScenarioTreeController`.

The tree itself (its nodes, their modes and stages, its size limits) is
:mod:`controllers.tree_topology`'s.

The tree of a controller depends on the root's mode and on whether ``x_k`` is in C1 (which row
of transition probabilities the root uses): one tree and one QP *family* per pair, as for P3.

Condensed QP
------------
The decisions are ``z = [nu_0 .. nu_{M-1}, rho_0 .. rho_{M-1}]`` (``M`` decision nodes); every
node's state mean is affine in ``(x_k, z)``: ``mean_i = Mx_i x_k + Mz_i z``. With ``w_i`` the
node's path probability and ``b_i`` its branch probabilities, the objective is::

    sum_i w_i ( E[x'Q x + u'R u] + alpha rho_i )                 x ~ N(mean_i, Sigma_i), u = K x + nu_i
    + sum_{i at stage steps-1} w_i sum_j b_ij E[x'Psi_j x]       x ~ N(next mean_i, next Sigma_i)

a sum of squares of the rows of ``Lx x + Lz z`` weighted per row, plus the trace terms (Lemma 1,
eq. eq:lemm1). The constraints are the chance constraints on each node's next state (tightened
with the node's next covariance), the box ``|nu| <= nu_bound`` and ``rho >= 0``; the constraint
matrix depends only on the family, the weights (through the path probabilities) change the
Hessian.

Size limit, and families built on first use
--------------------------------------------
A tree has at most :data:`MAX_TREE_VARIABLES` QP variables (``M (m + 1)``) and the dense
matrices of one family hold at most :data:`MAX_FAMILY_FLOATS` floats; :func:`check_tree_size`
raises a ValueError naming ``steps`` and ``branching`` before anything is built. A controller
builds a family when a decision first needs it (:class:`FamilyCache`) and keeps the built ones
within :data:`FAMILY_BUDGET_FLOATS` floats, least recently used first out; the constructor
computes only the magnitudes of every family's matrices (:func:`family_magnitudes`), so that bad
magnitudes fail before any work.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy import special, stats

from .horizon import HorizonSettings
from .lru import BudgetedLRU
from .tree_qp import OSQP_MAX_VARIABLES, TreeQP
from .tree_region import RegionClasses
from .tree_topology import (
    MAX_FAMILY_FLOATS,
    MAX_TREE_VARIABLES,
    Tree,
    build_tree,
    check_tree_size,
    tree_node_count,
)

__all__ = [
    "FAMILY_BUDGET_FLOATS",
    "MAX_FAMILY_FLOATS",
    "MAX_TREE_VARIABLES",
    "FamilyCache",
    "RegionClasses",
    "Tree",
    "TreeFamily",
    "build_tree_family",
    "check_tree_size",
    "family_magnitudes",
    "tree_node_count",
]

#: Largest number of floats the matrices of the built families of one controller hold together
#: (256 MB): beyond, the least recently used family is dropped (and built again when a decision
#: needs it). Each family's engine also caches active-set factors (at most
#: :data:`controllers.tree_qp.FACTOR_CACHE_FLOATS`), reduced Hessians (at most
#: :data:`controllers.tree_qp.REDUCED_CACHE_FLOATS`) and DAQP's scaled rows, and the family the
#: probabilities it met (:data:`WEIGHTS_FLOATS`).
FAMILY_BUDGET_FLOATS = 32_000_000


#: Matrices of a family with at most this many entries are kept dense (see TreeFamily.Lz).
DENSE_FLOATS = 200_000

#: Floats of the probabilities and Hessians a family keeps by region probabilities (1.6 MB).
WEIGHTS_FLOATS = 200_000


def _compact(M: Any) -> Any:
    """``M`` dense (read-only) when it has at most :data:`DENSE_FLOATS` entries, else CSR."""
    if M.shape[0] * M.shape[1] <= DENSE_FLOATS:
        return _frozen(M.toarray() if sp.issparse(M) else M)
    return sp.csr_matrix(M)


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def _sqrt_psd(M: np.ndarray) -> np.ndarray:
    """``F`` with ``F'F = M`` for a symmetric positive semidefinite ``M`` (n, n)."""
    vals, vecs = np.linalg.eigh(0.5 * (M + M.T))
    return (vecs * np.sqrt(np.clip(vals, 0.0, None))).T


# ---------------------------------------------------------------------------------- families
def _hessian_stack(Lz: np.ndarray, source: np.ndarray, sources: int) -> sp.csr_matrix:
    """``S`` (d * d, sources) with ``2 Lz' diag(v[source]) Lz = (S @ v).reshape(d, d)``: each
    source's rows contribute ``2 L_s' L_s`` on the few columns they involve (exactly symmetric)."""
    d = Lz.shape[1]
    data, flat, col = [], [], []
    start = 0
    while start < source.size:
        s = int(source[start])
        stop = start
        while stop < source.size and source[stop] == s:
            stop += 1
        block = Lz[start:stop]
        cols = np.flatnonzero(np.any(block != 0.0, axis=0))
        sub = 2.0 * (block[:, cols].T @ block[:, cols])
        sub = 0.5 * (sub + sub.T)
        data.append(sub.ravel())
        flat.append((cols[:, None] * d + cols[None, :]).ravel())
        col.append(np.full(cols.size * cols.size, s))
        start = stop
    return sp.csr_matrix(
        (np.concatenate(data), (np.concatenate(flat), np.concatenate(col))), shape=(d * d, sources)
    )


@dataclass(frozen=True, eq=False)
class TreeFamily:
    """The tree and every matrix of the condensed QP for one ``(mode, x_k in C1)`` pair.

    Arrays are read-only. ``M`` decision nodes, ``d = M (m + 1)`` variables, ``R`` weighted
    rows of the objective; see the module docstring for the QP.
    """

    mode: int
    inside: bool
    tree: Tree
    P_row: np.ndarray  # (N,) the root's branch probabilities (exact)
    Pin_q: np.ndarray  # (S, N) P_in rows of the nodes tree.sq
    dP_q: np.ndarray  # (S, N) P_in - P_out rows of the nodes tree.sq
    Pout_q: np.ndarray  # (S, N)
    proj_x: np.ndarray  # (S * classes, n)  projections of the means of tree.sq on the classes
    proj_z: np.ndarray  # (S * classes, d)
    proj_sd: np.ndarray  # (S, classes) their standard deviations
    q_time: np.ndarray  # (S,) stage of the nodes tree.sq (the band H_{k + stage})
    q_tightening: np.ndarray  # (S, r) the tightening of their parents' chance rows
    mean_x: np.ndarray  # (M * n, n)  node means: mean = mean_x x + mean_z z
    mean_z: np.ndarray  # (M * n, d)
    cov: np.ndarray  # (M, n, n) covariance of each node's state
    cov_next: np.ndarray  # (M, n, n) covariance of each node's next state
    tightening: np.ndarray  # (M, r)
    Lx: np.ndarray  # (R, n)
    # sparse beyond DENSE_FLOATS (a node's rows involve the offsets of its ancestors only),
    # dense below (scipy.sparse's product costs more than a small dense one)
    Lz: Any  # (R, d)
    LzT: Any  # (d, R)
    P_stack: Any  # (d * d, sources): the Hessian is (P_stack @ v).reshape(d, d)
    row_source: np.ndarray  # (R,) index of each row's weight in [w (M); w_last b_last (M_last N)]
    stage_trace: np.ndarray  # (M,) tr((Q + K'RK) Sigma_i)
    term_trace: np.ndarray  # (M_last, N) tr(Psi_j next Sigma_i)
    chance_x: np.ndarray  # (M r, n)  chance rows' bounds: band - tightening + chance_x x
    chance_time: np.ndarray  # (M,) stage + 1 of each node (the band H_{k + stage + 1})
    h_fixed: np.ndarray  # (2 M m + M,) the bounds of the box and rho rows
    idle_bound: np.ndarray  # (M r,) bounds that make a chance row slack for every z
    GA: np.ndarray  # (M, r, n)  G Atilde of each node's mode (the plan's constraint rows)
    GB: np.ndarray  # (M, r, m)
    engine: TreeQP
    depends: bool  # whether the region probabilities (and the Hessian) depend on the plan
    weights: BudgetedLRU  # the controller's probabilities (with their Hessian) by q.tobytes()

    @property
    def size(self) -> int:
        return self.tree.size


@dataclass(frozen=True, eq=False)
class _NodeLaws:
    """Each node's state law and its next state's, affine in ``(x_k, z)``, and the tightening."""

    tree: Tree
    P_row: np.ndarray
    Mx: np.ndarray  # (M, n, n)  mean = Mx x + Mz z
    Mz: np.ndarray  # (M, n, d)
    cov: np.ndarray  # (M, n, n)
    next_x: np.ndarray  # (M, n, n)
    next_z: np.ndarray  # (M, n, d)
    cov_next: np.ndarray  # (M, n, n)
    tight: np.ndarray  # (M, r)
    S: np.ndarray  # (M, m, d) selects nu_i


def _node_laws(
    s: HorizonSettings, steps: int, branching: int, mode: int, inside: bool
) -> _NodeLaws:
    """The tree of the family ``(mode, inside)`` and its nodes' laws (small: ``M n (n + d)``)."""
    model = s.model
    n, m, r, p = model.n, model.m, model.r, model.p
    P_row = (model.P_in if inside else model.P_out)[mode]  # eq. (eq:p_tran)
    support = (model.P_in + model.P_out) > 0.0
    tree = build_tree(P_row > 0.0, support, mode, steps, branching)
    M, modes, parent = tree.size, tree.mode, tree.parent
    d = M * (m + 1)
    At, B = s.A_tilde, model.B
    noise = model.noise_cov
    # node means (affine in x, z) and covariances, parents before children
    Mx = np.zeros((M, n, n))
    Mz = np.zeros((M, n, d))
    cov = np.zeros((M, n, n))
    Mx[0] = np.eye(n)
    S = np.zeros((M, m, d))  # selects nu_i
    for i in range(M):
        S[i, :, i * m : (i + 1) * m] = np.eye(m)
    with np.errstate(over="ignore", invalid="ignore"):  # magnitudes are checked afterwards
        for i in range(1, M):
            a, th = parent[i], modes[parent[i]]
            Mx[i] = At[th] @ Mx[a]
            Mz[i] = At[th] @ Mz[a] + B[th] @ S[a]
            cov[i] = At[th] @ cov[a] @ At[th].T + noise[th]
        At_n, B_n = At[modes], B[modes]
        next_x = At_n @ Mx  # (M, n, n)
        next_z = At_n @ Mz + B_n @ S  # (M, n, d)
        cov_next = At_n @ cov @ At_n.transpose(0, 2, 1) + noise[modes]
        cov_next = 0.5 * (cov_next + cov_next.transpose(0, 2, 1))
        # tightening of each node's chance rows with its next covariance (section 4)
        std = np.sqrt(np.clip(np.einsum("jn,inm,jm->ij", model.G, cov_next, model.G), 0.0, None))
        xi = s.xi
        assert xi is not None  # the tree always imposes its chance constraints (xi checked)
        if s.constraint == "individual":
            tight = special.ndtri(xi) * std  # eq. (constraint:det_univariate)
        elif s.constraint == "bonferroni":
            tight = special.ndtri(1.0 - (1.0 - xi) / r) * std
        else:  # eq. (constraint:chi_square): an ellipsoid of the noise driving the next state
            dof = np.minimum(p * (tree.stage + 1), max(n, p))  # p at the root (section 4)
            tight = np.sqrt(stats.chi2.ppf(xi, df=dof))[:, None] * std
        if s.constraint == "joint":  # at the root exactly controllers.chance.tightening
            root = np.einsum("jn,np,pq->jq", model.G, model.E[mode], model.W_sqrt)
            tight[0] = math.sqrt(stats.chi2.ppf(xi, df=p)) * np.linalg.norm(root, axis=-1)
    return _NodeLaws(tree, P_row, Mx, Mz, cov, next_x, next_z, cov_next, tight, S)


def _weight_roots(s: HorizonSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(FQ, FR, FPsi)``: square roots ``F'F`` of the weights ``Q_i``, ``R_i``, ``Psi_i``."""
    model = s.model
    FQ = np.array([_sqrt_psd(Qi) for Qi in model.Q])
    FR = np.array([_sqrt_psd(Ri) for Ri in model.R])
    FPsi = np.array([_sqrt_psd(Pi) for Pi in s.Psi])
    return FQ, FR, FPsi


def family_magnitudes(
    s: HorizonSettings, steps: int, branching: int, mode: int, inside: bool
) -> dict[str, float]:
    """The largest magnitude of every matrix of the family ``(mode, inside)`` that
    :class:`TreeFamily` holds as ``Lx``, ``Lz``, ``chance_x``, ``cov_next``, ``tightening`` and
    ``term_trace`` (NaN or inf when they overflow), computed from the nodes' laws without
    building the family's large matrices."""
    model = s.model
    law = _node_laws(s, steps, branching, mode, inside)
    modes, last = law.tree.mode, law.tree.last
    FQ, FR, FPsi = _weight_roots(s)
    K = s.K
    top = lambda a: float(np.max(np.abs(a))) if a.size else 0.0  # noqa: E731 (NaN propagates)
    with np.errstate(over="ignore", invalid="ignore"):
        FRK = FR[modes] @ K[modes]
        lx = max(
            top(FQ[modes] @ law.Mx),
            top(FRK @ law.Mx),
            top(np.einsum("jab,ibc->ijac", FPsi, law.next_x[last])),
        )
        lz = max(
            top(FQ[modes] @ law.Mz),
            top(FRK @ law.Mz + FR[modes] @ law.S),
            top(np.einsum("jab,ibc->ijac", FPsi, law.next_z[last])),
        )
        chance_x = top(np.einsum("jn,ink->ijk", model.G, law.next_x))
        term = top(np.einsum("jab,iba->ij", s.Psi, law.cov_next[last]))
    out = {"Lx": lx, "Lz": lz, "chance_x": chance_x, "cov_next": top(law.cov_next)}
    out.update(tightening=top(law.tight), term_trace=term)
    return {k: (v if math.isfinite(v) else math.inf) for k, v in out.items()}


def build_tree_family(
    s: HorizonSettings,
    steps: int,
    branching: int,
    mode: int,
    inside: bool,
    regions: RegionClasses,
) -> TreeFamily:
    """The family ``(mode, inside)`` of a :class:`controllers.ScenarioTreeController` with the
    checked parameters ``s``, ``steps`` and ``branching``."""
    model = s.model
    n, m = model.n, model.m
    law = _node_laws(s, steps, branching, mode, inside)
    tree, P_row = law.tree, law.P_row
    M, modes = tree.size, tree.mode
    d = M * (m + 1)
    Mx, Mz, cov, tight = law.Mx, law.Mz, law.cov, law.tight
    with np.errstate(over="ignore", invalid="ignore"):  # magnitudes were checked by the caller
        Lx, Lz, source = _objective_rows(s, law)
        P_stack = _hessian_stack(Lz, source, M + tree.last.size * model.N)
        K = s.K
        QKRK = model.Q[modes] + K[modes].transpose(0, 2, 1) @ model.R[modes] @ K[modes]
        stage_trace = np.einsum("iab,iba->i", QKRK, cov)
        term_trace = np.einsum("jab,iba->ij", s.Psi, law.cov_next[tree.last])
        GA = model.G @ s.A_tilde[modes]  # (M, r, n)
        GB = model.G @ model.B[modes]  # (M, r, m)
        chance, chance_x = _chance_rows(s, law, d)
    engine = _tree_engine(s, chance, M, d)
    nb = s.nu_bound
    h_fixed = np.concatenate([np.full(2 * M * m, nb), np.zeros(M)])
    # a chance row of a node of path probability 0 is made slack for every z: its bound is at
    # least its largest value over the box, |C_nu| nu_bound (its slack is then 0)
    idle_bound = np.abs(chance[:, : M * m]).sum(axis=1) * nb + 1.0
    # the region probabilities of the nodes tree.sq
    sq = tree.sq
    dirs = regions.directions  # (classes, n)
    proj_x = np.einsum("cn,ink->ick", dirs, Mx[sq]).reshape(-1, n)
    proj_z = np.einsum("cn,ind->icd", dirs, Mz[sq]).reshape(-1, d)
    proj_sd = np.sqrt(np.clip(np.einsum("cn,inm,cm->ic", dirs, cov[sq], dirs), 0.0, None))
    Pin, Pout = model.P_in[modes[sq]], model.P_out[modes[sq]]
    return TreeFamily(
        mode=mode,
        inside=inside,
        tree=tree,
        P_row=_frozen(P_row),
        Pin_q=_frozen(Pin),
        dP_q=_frozen(Pin - Pout),
        Pout_q=_frozen(Pout),
        proj_x=_frozen(proj_x),
        proj_z=_frozen(proj_z),
        proj_sd=_frozen(proj_sd),
        q_time=_frozen(tree.stage[sq].astype(np.float64)),
        q_tightening=_frozen(tight[tree.parent[sq]]),
        mean_x=_frozen(Mx.reshape(M * n, n)),
        mean_z=_frozen(Mz.reshape(M * n, d)),
        cov=_frozen(cov),
        cov_next=_frozen(law.cov_next),
        tightening=_frozen(tight),
        Lx=_frozen(Lx),
        Lz=_compact(Lz),
        LzT=_compact(Lz.T),
        P_stack=_compact(P_stack),
        row_source=source,
        stage_trace=_frozen(stage_trace),
        term_trace=_frozen(term_trace),
        chance_x=_frozen(chance_x),
        chance_time=_frozen(tree.stage.astype(np.float64) + 1.0),
        h_fixed=_frozen(h_fixed),
        idle_bound=_frozen(idle_bound),
        GA=_frozen(GA),
        GB=_frozen(GB),
        engine=engine,
        depends=bool(sq.size) and bool(np.any(Pin != Pout)),
        weights=BudgetedLRU(WEIGHTS_FLOATS, _weights_floats),
    )


def _objective_rows(
    s: HorizonSettings, law: _NodeLaws
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Lx, Lz, source)``: the weighted rows of the objective, ``Lx x + Lz z`` (the stage
    costs of every node, then the terminal costs of the last stage's nodes, one block per next
    mode), and the weight each row takes (its node, or its node and next mode)."""
    model, tree, K = s.model, law.tree, s.K
    n, m, N, M = model.n, model.m, model.N, law.tree.size
    FQ, FR, FPsi = _weight_roots(s)
    rows_x, rows_z, source = [], [], []
    for i in range(M):
        th = tree.mode[i]
        rows_x += [FQ[th] @ law.Mx[i], FR[th] @ K[th] @ law.Mx[i]]
        rows_z += [FQ[th] @ law.Mz[i], FR[th] @ (K[th] @ law.Mz[i] + law.S[i])]
        source += [i] * (n + m)
    for a, i in enumerate(tree.last.tolist()):
        for j in range(N):
            rows_x.append(FPsi[j] @ law.next_x[i])
            rows_z.append(FPsi[j] @ law.next_z[i])
            source += [M + a * N + j] * n
    return np.vstack(rows_x), np.vstack(rows_z), np.array(source, dtype=np.int64)


def _chance_rows(s: HorizonSettings, law: _NodeLaws, d: int) -> tuple[np.ndarray, np.ndarray]:
    """``(chance, chance_x)``: the chance rows of every node on ``z`` (less its slack) and on
    ``x_k`` (negated), before their right side."""
    G, M, r = s.model.G, law.tree.size, s.model.r
    chance = np.einsum("jn,ind->ijd", G, law.next_z).reshape(M * r, d)
    chance[np.arange(M * r), M * s.model.m + np.repeat(np.arange(M), r)] = -1.0  # - rho_i
    chance_x = -np.einsum("jn,ink->ijk", G, law.next_x).reshape(M * r, s.model.n)
    return chance, chance_x


def _tree_engine(s: HorizonSettings, chance: np.ndarray, M: int, d: int) -> TreeQP:
    """The family's QP engine: the constraints ``[chance rows (M r); box (M m); rho (M)]`` and
    the solvers of ``s.solver`` (OSQP only on small trees; see
    :data:`controllers.tree_qp.OSQP_MAX_VARIABLES`)."""
    m, r = s.model.m, s.model.r
    A = np.zeros((M * r + M * m + M, d))
    A[: M * r] = chance
    A[M * r + np.arange(M * m), np.arange(M * m)] = 1.0
    A[M * r + M * m + np.arange(M), M * m + np.arange(M)] = 1.0
    upper = np.concatenate([np.ones(M * r + M * m, bool), np.zeros(M, bool)])
    lower = np.concatenate([np.zeros(M * r, bool), np.ones(M * m + M, bool)])
    daqp = s.solver != "osqp"  # the cvxpy reference's families solve its rescue's active sets
    return TreeQP(
        np.eye(d),
        A,
        lower,
        upper,
        s.osqp_settings,
        use_daqp=daqp,
        osqp_runs=2 if d <= OSQP_MAX_VARIABLES else int(not daqp),
        daqp_after_osqp=not daqp and d > OSQP_MAX_VARIABLES,
    )


def _weights_floats(pr: Any) -> int:
    held = pr.branch.size + 3 * pr.path.size
    return held + sum(a.size for a in (pr.P, pr.wrow) if a is not None)


def _floats(fam: TreeFamily) -> int:
    """Floats held by a family's arrays (sparse: their stored entries)."""
    total = 0
    for value in fam.__dict__.values():
        if isinstance(value, np.ndarray):
            total += value.size
        elif sp.issparse(value):
            total += value.data.size + value.indices.size
    return total + fam.engine.A.size + fam.engine.C.size


class FamilyCache(BudgetedLRU[tuple[int, bool], TreeFamily]):
    """The families of one controller, built on first use (``cache[(mode, inside)]``) and kept
    within :data:`FAMILY_BUDGET_FLOATS` floats, least recently used first out (the one in use
    is always kept). Not thread-safe (the controller's lock covers it); pickles empty.

    Not ``functools``: the budget is in floats, and a controller pickles without its families.

    Attributes
    ----------
    built : int
        How many families were built so far (a family dropped and needed again counts twice).
    """

    def __init__(self, build: Any, limit: int = FAMILY_BUDGET_FLOATS) -> None:
        super().__init__(limit, _floats)
        self._build = build

    def __getitem__(self, key: tuple[int, bool]) -> TreeFamily:
        return self.get(key, self._build, *key)

    @property
    def floats(self) -> int:
        """Floats held by the built families."""
        return self.total
