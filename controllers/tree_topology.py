"""The topology of a scenario tree of modes, and the size limits of its QP.

Tree
----
A node is a pair (state, mode) at a stage ``t`` of the horizon. The root is ``(x_k, theta_k)`` at
stage 0. Nodes at stages ``0 .. steps-1`` carry a decision (an offset ``nu`` and a slack
``rho``); the states at stage ``steps`` only carry the terminal cost. A node at a stage
``t < branching`` has one child per mode ``j`` that can follow its mode (at the root: the modes
of positive probability in its row of ``P_in`` or ``P_out``; later: in either row); a node at a
later stage has one child, with its own mode (the "robust horizon" of multi-stage MPC). All
children of a node share its next state: their mean is ``Atilde_theta mean + B_theta nu`` and
their covariance ``Atilde_theta Sigma Atilde_theta' + E_theta W E_theta'`` (``Sigma = 0`` at the
root), where ``theta`` is the parent's mode.

The tree of a controller depends on the root's mode and on whether ``x_k`` is in C1 (which row
of transition probabilities the root uses): one tree per pair. :func:`check_tree_size` refuses,
before anything is built, a tree whose QP is beyond :data:`MAX_TREE_VARIABLES` variables or
whose dense matrices are beyond :data:`MAX_FAMILY_FLOATS` floats (the QP data are
:mod:`controllers.tree_data`'s).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "MAX_FAMILY_FLOATS",
    "MAX_TREE_VARIABLES",
    "Tree",
    "build_tree",
    "check_tree_size",
    "tree_node_count",
]

#: Largest number of QP variables (``m + 1`` per decision node) of a tree.
MAX_TREE_VARIABLES = 1000

#: Largest number of floats in the dense matrices of one family (64 MB).
MAX_FAMILY_FLOATS = 8_000_000


def _stage_counts(
    root_support: np.ndarray, support: np.ndarray, mode: int, steps: int, branching: int
) -> list[np.ndarray]:
    """Number of nodes per mode at each stage ``0 .. steps-1`` (Python ints, no overflow)."""
    N = support.shape[0]
    counts = [np.zeros(N, dtype=object)]
    counts[0][mode] = 1
    S = support.astype(object)
    for t in range(steps - 1):
        prev = counts[-1]
        if t >= branching:
            nxt = prev.copy()
        elif t == 0:
            nxt = np.where(root_support, 1, 0).astype(object)
        else:
            nxt = prev @ S
        counts.append(nxt)
    return counts


def tree_node_count(
    root_support: np.ndarray, support: np.ndarray, mode: int, steps: int, branching: int
) -> tuple[int, int]:
    """``(M, M_last)``: decision nodes of the tree and those at the last stage."""
    counts = _stage_counts(root_support, support, mode, steps, branching)
    return int(sum(int(c.sum()) for c in counts)), int(counts[-1].sum())


def check_tree_size(model: Any, steps: int, branching: int) -> None:
    """ValueError naming ``steps`` and ``branching`` when a family's tree is beyond
    :data:`MAX_TREE_VARIABLES` variables or :data:`MAX_FAMILY_FLOATS` floats."""
    N, n, m = model.N, model.n, model.m
    hint = (
        "lower steps, or branching (the stages from branching on do not branch: one child per node)"
    )
    if steps * (m + 1) > MAX_TREE_VARIABLES:
        raise ValueError(
            f"steps = {steps} needs at least {steps * (m + 1)} QP variables (m + 1 = {m + 1} "
            f"per stage); a scenario tree has at most {MAX_TREE_VARIABLES} "
            f"(controllers.tree_data.MAX_TREE_VARIABLES): {hint}"
        )
    support = (model.P_in + model.P_out) > 0.0
    worst = (0, 0, 0, False)
    for mode in range(N):
        for inside in (True, False):
            row = (model.P_in if inside else model.P_out)[mode] > 0.0
            M, M_last = tree_node_count(row, support, mode, steps, branching)
            worst = max(worst, (M, M_last, mode, inside))
    M, M_last, mode, _ = worst
    d = M * (m + 1)
    if d > MAX_TREE_VARIABLES:
        raise ValueError(
            f"steps = {steps} and branching = {branching} make a scenario tree of {M} decision "
            f"nodes for mode {mode}, a QP of {d} variables (m + 1 = {m + 1} per node); at most "
            f"{MAX_TREE_VARIABLES} are supported (controllers.tree_data.MAX_TREE_VARIABLES): "
            f"{hint}"
        )
    rows = M * (n + m) + M_last * N * n
    c = M * (model.r + 2 * m + 1)
    floats = rows * (n + d) + 2 * c * d + 2 * M * n * (n + d)
    if floats > MAX_FAMILY_FLOATS:
        raise ValueError(
            f"steps = {steps} and branching = {branching} make a scenario tree of {M} decision "
            f"nodes whose QP matrices hold {floats:,} floats per family; at most "
            f"{MAX_FAMILY_FLOATS:,} are supported (controllers.tree_data.MAX_FAMILY_FLOATS): "
            f"{hint}"
        )


@dataclass(frozen=True, eq=False)
class Tree:
    """The topology of one family's tree; nodes in breadth-first order (the root is 0).

    Attributes
    ----------
    mode, parent, stage : (M,) int arrays
        The node's mode, its parent (-1 for the root) and its stage.
    branched : (M,) bool
        Whether the node branches (``stage < branching``; a last-stage node never has children).
    children : (M, N) int array
        ``children[i, j]``: the node that follows ``i`` when the next mode is ``j``; for a node
        that does not branch, its single child whatever ``j``; -1 where there is none.
    by_stage : tuple of (M_t,) int arrays
        The nodes of each stage ``0 .. steps-1``.
    last : (M_last,) int array
        The nodes of the last stage (they carry the terminal cost).
    sq : int array
        The nodes whose branch probabilities depend on the state (stage >= 1 and branched or
        last): their region probability ``q`` is computed at every decision.
    """

    mode: np.ndarray
    parent: np.ndarray
    stage: np.ndarray
    branched: np.ndarray
    children: np.ndarray
    by_stage: tuple
    last: np.ndarray
    sq: np.ndarray

    @property
    def size(self) -> int:
        return int(self.mode.shape[0])


def build_tree(
    root_support: np.ndarray, support: np.ndarray, root_mode: int, steps: int, branching: int
) -> Tree:
    """The tree of a family (see the module docstring); ``support[i, j]``: mode ``j`` can follow
    mode ``i`` below the root, ``root_support[j]``: at the root."""
    N = support.shape[0]
    mode, parent, stage = [root_mode], [-1], [0]
    children: list[list[int]] = [[-1] * N]
    frontier = [0]
    for t in range(steps - 1):
        nxt = []
        for i in frontier:
            if t < branching:
                follow = root_support if t == 0 else support[mode[i]]
                modes = np.flatnonzero(follow).tolist()
            else:
                modes = [mode[i]]
            for j in modes:
                c = len(mode)
                mode.append(j)
                parent.append(i)
                stage.append(t + 1)
                children.append([-1] * N)
                nxt.append(c)
                if t < branching:
                    children[i][j] = c
                else:
                    children[i] = [c] * N
        frontier = nxt
    mode_a = np.array(mode, dtype=np.int64)
    stage_a = np.array(stage, dtype=np.int64)
    branched = (stage_a < branching) & (stage_a < steps - 1)
    last = np.flatnonzero(stage_a == steps - 1)
    sq = np.flatnonzero((stage_a >= 1) & (branched | (stage_a == steps - 1)))
    out = Tree(
        mode=mode_a,
        parent=np.array(parent, dtype=np.int64),
        stage=stage_a,
        branched=branched,
        children=np.array(children, dtype=np.int64),
        by_stage=tuple(np.flatnonzero(stage_a == t) for t in range(steps)),
        last=last,
        sq=sq,
    )
    for name in ("mode", "parent", "stage", "branched", "children", "last", "sq"):
        getattr(out, name).setflags(write=False)
    return out
