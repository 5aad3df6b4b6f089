"""The reference frontier: a task's one-step RHC over levels ``xi`` on a policy's own episodes.

A task's *reference curve* is its one-step receding-horizon controller
(:func:`benchmarks.core.reference.one_step_rhc`, individual chance constraints) over levels
``xi``, every level scored on the same episodes as the policy it is compared with (common random
numbers; the episodes of several noise seeds pooled). A policy's *gap* is its mean episode cost
minus the curve's at the policy's own violation frequency, paired over the episodes
(:func:`benchmarks.core.stats.paired_curve_gap`), in percent of the curve's cost.

The cost-violation frontier bends, and a polyline between a few levels flatters whoever lies
between its points. So the curve is built in two stages:

* the *base grid* (:func:`reference_curve`): the task's levels (:func:`~benchmarks.core.reference.curve_xis`),
  with a level added halfway (in ``probit(xi)``) between two neighbours whose violation
  frequencies differ by more than :data:`BASE_STEP`, until none do (at most :data:`MAX_LEVELS`);
* the *refinement at the policy's level* (:meth:`ReferenceCurve.refine`, done by
  :meth:`ReferenceCurve.gap`): the controller is run again at levels bisected (in ``probit(xi)``)
  between the two efficient levels that bracket the policy's violation frequency, until they are
  within :data:`REFINE_STEP` of each other. The gap is then measured between two levels of the
  controller that violate almost exactly as often as the policy: the reference controller run
  at a level between the grid's points scores 0 against its own curve (tests/test_frontier.py).

Which levels a gap uses depends only on the base grid and on the policy's own violation
frequency, not on which other policies were scored before (every level's rollouts are cached,
but a gap uses the base grid and its own refinement only).

*Every run counts* (:func:`bounded_gap`): a score defined for every run, in percent and bounded
at :data:`WORST_GAP`: the gap where there is one, clipped to ``[-WORST_GAP, WORST_GAP]``; a run
with a diverged episode, or riskier than the curve's loosest efficient level, takes the worst
value ``+WORST_GAP``; a run safer than its strictest efficient level is measured against that
level (no credit for the extra safety).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.special import ndtr, ndtri

from benchmarks.core.montecarlo import rollout
from benchmarks.core.reference import (
    REFERENCE_CONSTRAINT,
    curve_xis,
    one_step_rhc,
    task_key,
)
from benchmarks.core.stats import CurveGap, efficient_points, mean_ci, paired_curve_gap, wilson
from benchmarks.core.tree_levels import LevelStore, run_tree_levels
from controllers.lru import BudgetedLRU
from sdjls_gym.systems import Task

__all__ = [
    "BASE_STEP",
    "CURVE_CACHE_SIZE",
    "MAX_LEVELS",
    "MAX_REFINE",
    "REFINE_STEP",
    "WORST_GAP",
    "BoundedGap",
    "LevelRunner",
    "ReferenceCurve",
    "as_seeds",
    "bounded_gap",
    "gap_reason",
    "reference_curve",
    "tree_curve",
]

#: Largest difference of violation frequency between neighbouring levels of the base grid.
BASE_STEP = 0.02
#: The refinement stops when the two levels bracketing a policy's violation frequency are this
#: close in violation frequency.
REFINE_STEP = 0.002
#: Most levels of a base grid, and most bisections of one refinement.
MAX_LEVELS = 48
MAX_REFINE = 10
#: The worst value of :func:`bounded_gap` (percent): a run that diverged or is riskier than the
#: whole curve; gaps beyond it are clipped to it.
WORST_GAP = 100.0
#: Level runners kept in memory (each holds its levels' per-episode arrays).
CURVE_CACHE_SIZE = 32


def as_seeds(seed: int | Sequence[int]) -> tuple[int, ...]:
    """``seed`` as a tuple of noise seeds (one int is one seed)."""
    return (int(seed),) if isinstance(seed, (int, np.integer)) else tuple(int(s) for s in seed)


def _probit_mid(a: float, b: float) -> float:
    """The level halfway between ``a`` and ``b`` in ``probit(xi)`` (levels near 0 and 1 are
    spread as the tightening ``Phi^-1(xi)`` spreads them)."""
    return float(ndtr(0.5 * (ndtri(a) + ndtri(b))))


class LevelRunner:
    """Runs a controller family at a level ``xi`` on fixed episodes, once per level: ``make(xi)``
    builds the controller, and its rollouts on ``episodes`` episodes from each of ``seeds`` are
    pooled. Returns ``(costs (E,), shares of violated steps (E,), diverged count)``."""

    def __init__(self, model: Any, make: Callable[[float], Any], episodes: int,
                 seeds: tuple[int, ...], horizon: int, bound: float,
                 divergence_bound: float) -> None:  # fmt: skip
        self.model, self.make, self.episodes, self.seeds = model, make, episodes, seeds
        self.horizon, self.bound, self.divergence_bound = horizon, bound, divergence_bound
        self._levels: dict[float, tuple[np.ndarray, np.ndarray, int]] = {}

    def __call__(self, xi: float, progress: Any = None) -> tuple[np.ndarray, np.ndarray, int]:
        xi = float(xi)
        if xi not in self._levels:
            ctrl = self.make(xi)
            costs, viols, diverged = [], [], 0
            for seed in self.seeds:
                ro = rollout(self.model, ctrl, self.episodes, self.horizon, seed, self.bound,
                             progress, self.divergence_bound)  # fmt: skip
                cost, viol, count = ro.outcomes(self.divergence_bound)
                costs.append(cost)
                viols.append(viol)
                diverged += count
            self._levels[xi] = (np.concatenate(costs), np.concatenate(viols), diverged)
        return self._levels[xi]

    @property
    def levels_run(self) -> int:
        """How many levels have been run (for the reports' cost accounting)."""
        return len(self._levels)


@dataclass(frozen=True)
class ReferenceCurve:
    """A controller family over levels ``xi``, each scored on the same episodes.

    Attributes
    ----------
    env_id : str
    xis : (P,) tuple of float
        The levels, increasing, in the order of the rows below.
    constraint : str
        ``"individual"`` (the reference) or ``"joint"``.
    episodes : int
        Episodes per noise seed; the rows hold ``episodes * len(seeds)`` of them.
    seeds : tuple of int
        The noise seeds whose episodes are pooled.
    steps : int
        Steps per episode.
    costs, violations : (P, E) arrays
        Each level's episode costs and shares of violated steps.
    diverged : (P,) int array
        Each level's episodes that diverged.
    runner : LevelRunner or None
        What runs further levels (:meth:`refine`); None for a fixed grid (the tree's).
    """

    env_id: str
    xis: tuple[float, ...]
    constraint: str
    episodes: int
    seeds: tuple[int, ...]
    steps: int
    costs: np.ndarray = field(repr=False)
    violations: np.ndarray = field(repr=False)
    diverged: np.ndarray
    runner: LevelRunner | None = field(default=None, repr=False, compare=False)

    @property
    def seed(self) -> int:
        """The first noise seed (the only one of a one-seed curve)."""
        return self.seeds[0]

    def efficient(self) -> np.ndarray:
        """The indices of the efficient levels, in order of violation frequency
        (:func:`benchmarks.core.stats.efficient_points`)."""
        return efficient_points(self.violations.mean(axis=1), self.costs.mean(axis=1))

    def with_levels(self, xis: Sequence[float]) -> ReferenceCurve:
        """This curve with the levels ``xis`` added (run by :attr:`runner`), in order of ``xi``."""
        new = sorted({float(x) for x in xis} - set(self.xis))
        if not new:
            return self
        if self.runner is None:
            raise ValueError(f"{self.env_id}: a fixed-grid curve cannot run the levels {new}")
        rows = [self.runner(x) for x in new]
        xis_all = [*self.xis, *new]
        order = np.argsort(xis_all, kind="stable")
        costs = np.concatenate([self.costs, np.stack([r[0] for r in rows])])[order]
        viols = np.concatenate([self.violations, np.stack([r[1] for r in rows])])[order]
        diverged = np.concatenate([self.diverged, np.array([r[2] for r in rows])])[order]
        return replace(self, xis=tuple(float(xis_all[i]) for i in order), costs=costs,
                       violations=viols, diverged=diverged)  # fmt: skip

    def refine(self, violation: float) -> ReferenceCurve:
        """This curve with levels bisected between the two efficient levels that bracket
        ``violation``, until they are within :data:`REFINE_STEP` of each other in violation
        frequency (at most :data:`MAX_REFINE` levels); itself outside the efficient range or
        without a :attr:`runner`."""
        if self.runner is None:
            return self
        curve = self
        for _ in range(MAX_REFINE):
            keep = curve.efficient()
            v = curve.violations.mean(axis=1)[keep]
            if not v[0] <= violation <= v[-1] or keep.size < 2:
                return curve
            if np.any(v == violation):  # a level violates exactly as often: the gap is to it
                return curve
            j = min(int(np.searchsorted(v, violation, side="left")), keep.size - 1)
            j = max(j, 1)
            lo, hi = keep[j - 1], keep[j]  # less and more violating
            if v[j] - v[j - 1] <= REFINE_STEP:
                return curve
            a, b = sorted((curve.xis[lo], curve.xis[hi]))
            mid = _probit_mid(a, b)
            if mid in curve.xis or not a < mid < b:
                return curve
            curve = curve.with_levels([mid])
        return curve

    def gap(self, costs: np.ndarray, violations: np.ndarray) -> CurveGap | None:
        """A policy's paired gap to this curve, refined at its violation frequency
        (:meth:`refine`), from its episode costs and shares of violated steps (E,) on the same
        episodes (:func:`benchmarks.core.stats.paired_curve_gap`); None outside the range of
        the curve's efficient levels."""
        curve = self.refine(float(np.mean(violations)))
        return paired_curve_gap(costs, violations, curve.costs, curve.violations, curve.xis)

    def point(self, i: int) -> dict[str, Any]:
        """Level ``i``'s statistics, as :class:`benchmarks.core.evaluate.Score` states them:
        mean cost with its 95% Student-t interval, median, violation frequency with its 95%
        Wilson interval, diverged episodes."""
        mean, lo, hi = mean_ci(self.costs[i], floor=0.0)
        count = int(round(float(self.violations[i].sum()) * self.steps))
        total = self.violations.shape[1] * self.steps
        wlo, whi = wilson(count, total)
        return {
            "xi": self.xis[i],
            "cost_mean": mean,
            "cost_ci95": (lo, hi),
            "cost_median": float(np.median(self.costs[i])),
            "violation": count / total,
            "violation_wilson95": (wlo, whi),
            "diverged": int(self.diverged[i]),
        }


#: Not functools: the key is what a curve depends on (the task as its JSON, the seeds, ...), not
#: the arguments (a Task does not hash; the progress bar is no part of a curve).
_RUNNERS: BudgetedLRU[tuple[Any, ...], LevelRunner] = BudgetedLRU(CURVE_CACHE_SIZE)


def _runner(task: Task, episodes: int, seeds: tuple[int, ...], horizon: int, bound: float,
            divergence_bound: float, constraint: str) -> LevelRunner:  # fmt: skip
    key = (task_key(task), episodes, seeds, horizon, bound, float(divergence_bound), constraint)

    def make() -> LevelRunner:
        return LevelRunner(task.model, lambda xi: one_step_rhc(task, xi, constraint, horizon),
                           episodes, seeds, horizon, bound, divergence_bound)  # fmt: skip

    return _RUNNERS.get(key, make)


def reference_curve(
    task: Task,
    episodes: int,
    seed: int | Sequence[int],
    *,
    horizon: int | None = None,
    action_bound: float | np.ndarray | None = None,
    divergence_bound: float = 1e6,
    constraint: str = REFERENCE_CONSTRAINT,
    xis: tuple[float, ...] | None = None,
    adaptive: bool = True,
    progress: Any = None,
) -> ReferenceCurve:
    """The one-step receding-horizon controller of ``task`` over its base grid, each level
    scored on ``episodes`` episodes from each noise seed of ``seed`` (an int or a sequence; the
    episodes pooled).

    The grid starts at ``xis`` (default :func:`~benchmarks.core.reference.curve_xis`) and, with
    ``adaptive``, gets levels halfway between neighbours whose violation frequencies differ by
    more than :data:`BASE_STEP` (at most :data:`MAX_LEVELS`). ``horizon``, ``action_bound`` and
    ``divergence_bound`` are the environment's (default: the task's horizon and bound, and the
    environments' default divergence bound). Levels are run once per task, episodes, seeds and
    bounds (the last :data:`CURVE_CACHE_SIZE` such runners are kept); ``progress`` (a tqdm
    bar) advances by one per simulated step of a level run now.
    """
    seeds = as_seeds(seed)
    start = curve_xis(task) if xis is None else tuple(float(x) for x in xis)
    horizon = task.horizon if horizon is None else int(horizon)
    bound = float(np.max(task.action_bound if action_bound is None else action_bound))
    run = _runner(task, episodes, seeds, horizon, bound, divergence_bound, constraint)
    levels = sorted(set(start))
    while adaptive and len(levels) < MAX_LEVELS:
        v = [float(run(x, progress)[1].mean()) for x in levels]
        add = [_probit_mid(a, b) for a, b, va, vb in zip(levels, levels[1:], v, v[1:], strict=False)
               if abs(va - vb) > BASE_STEP]  # fmt: skip
        add = [x for x in add if x not in levels][: MAX_LEVELS - len(levels)]
        if not add:
            break
        levels = sorted({*levels, *add})
    rows = [run(x, progress) for x in levels]
    return ReferenceCurve(task.env_id, tuple(levels), constraint, episodes, seeds, horizon,
                          np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows]),
                          np.array([r[2] for r in rows]), run)  # fmt: skip


def tree_curve(task: Task, episodes: int, seed: int | Sequence[int], xis: Sequence[float], *,
               steps: int, horizon: int | None = None,
               action_bound: float | np.ndarray | None = None, divergence_bound: float = 1e6,
               progress: Any = None, store: LevelStore | None = None,
               workers: int = 1) -> ReferenceCurve:  # fmt: skip
    """The scenario tree's curve (:func:`~benchmarks.core.reference.tree_rhc` with ``steps``
    stages) on the fixed levels ``xis``, each on ``episodes`` episodes from each noise seed of
    ``seed``: the second view, with no refinement (its decisions cost 10 to 1000 times the
    one-step controller's). ``store`` keeps each level's run on disk and ``workers`` runs the
    missing ones on that many processes (:func:`benchmarks.core.tree_levels.run_tree_levels`:
    the same curve either way)."""
    seeds = as_seeds(seed)
    horizon = task.horizon if horizon is None else int(horizon)
    bound = float(np.max(task.action_bound if action_bound is None else action_bound))
    levels = sorted({float(x) for x in xis})
    rows = run_tree_levels(task, levels, seeds, episodes, steps=steps, horizon=horizon,
                           bound=bound, divergence_bound=divergence_bound, store=store,
                           workers=workers, progress=progress)  # fmt: skip
    return ReferenceCurve(task.env_id, tuple(levels), REFERENCE_CONSTRAINT, episodes, seeds,
                          horizon, np.stack([r[0] for r in rows]),
                          np.stack([r[1] for r in rows]), np.array([r[2] for r in rows]))  # fmt: skip


def gap_reason(
    violation: float,
    diverged: int,
    gap: CurveGap | None,
    curve_violations: np.ndarray,
    curve_costs: np.ndarray | None = None,
) -> str | None:
    """Why a controller with this violation frequency and these diverged episodes has no
    normalized gap ``gap`` to a curve whose points' shares of violated steps are
    ``curve_violations`` (P, E) and episode costs ``curve_costs`` (P, E); None if it has one.
    The range named is that of the curve's efficient points
    (:func:`benchmarks.core.stats.efficient_points`, the points the gap is measured against); all
    points' without ``curve_costs``."""
    if diverged:
        return f"{diverged} episode(s) diverged"
    means = np.asarray(curve_violations).mean(axis=1)
    if curve_costs is not None:
        means = means[efficient_points(means, np.asarray(curve_costs).mean(axis=1))]
    lo, hi = float(np.min(means)), float(np.max(means))
    if gap is None and violation > hi:
        return (f"violation frequency {violation:.3f} is above the curve's range "
                f"{lo:.3f}..{hi:.3f} (more than the RHC at its loosest efficient level)")  # fmt: skip
    if gap is None:
        return (f"violation frequency {violation:.3f} is below the curve's range "
                f"{lo:.3f}..{hi:.3f} (less than the RHC at its strictest efficient level)")  # fmt: skip
    if gap.relative is None:
        return "the curve's cost is not positive"
    return None


@dataclass(frozen=True)
class BoundedGap:
    """A run's score that every run has (see the module docstring).

    Attributes
    ----------
    value : float
        Percent, in ``[-WORST_GAP, WORST_GAP]``; lower is better, 0 on the curve.
    rule : str
        ``"gap"``, ``"diverged"``, ``"riskier than the curve"``, ``"safer than the curve"`` or
        ``"the curve's cost is not positive"``.
    gap : CurveGap or None
        The paired gap at equal risk, where the run's violation frequency lies in the curve's
        range (its ``relative`` None where the curve's cost there is not positive).
    """

    value: float
    rule: str
    gap: CurveGap | None

    @property
    def equal_risk_gap(self) -> CurveGap | None:
        """:attr:`gap` where the score is that gap (``rule == "gap"``), else None."""
        return self.gap if self.rule == "gap" else None

    @property
    def reason(self) -> str | None:
        """Why the score is not the gap at equal risk: :attr:`rule`, None where it is."""
        return None if self.rule == "gap" else self.rule


def bounded_gap(curve: ReferenceCurve, costs: np.ndarray, violations: np.ndarray,
                diverged: int) -> BoundedGap:  # fmt: skip
    """The score of a run with these episode costs, shares of violated steps (E,) and diverged
    episodes against ``curve`` (on the same episodes): see the module docstring."""
    if diverged:
        return BoundedGap(WORST_GAP, "diverged", None)
    gap = curve.gap(costs, violations)
    if gap is not None and gap.relative is not None:
        return BoundedGap(float(np.clip(gap.relative, -WORST_GAP, WORST_GAP)), "gap", gap)
    keep = curve.efficient()
    v = curve.violations.mean(axis=1)[keep]
    if float(np.mean(violations)) > v[-1]:
        return BoundedGap(WORST_GAP, "riskier than the curve", None)
    strictest = float(curve.costs[keep[0]].mean())
    if strictest <= 0:
        return BoundedGap(WORST_GAP, "the curve's cost is not positive", gap)
    value = 100.0 * (float(np.mean(costs)) - strictest) / strictest
    return BoundedGap(float(np.clip(value, -WORST_GAP, WORST_GAP)), "safer than the curve", gap)
