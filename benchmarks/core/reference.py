"""The model-based reference of every task: its receding-horizon controllers and cost-violation curves.

A task's *reference curve* is the one-step receding-horizon controller of the paper (P3) on that
task, ``RecedingHorizonController(task.model, task.K, horizon=T, **task.rhc)`` with individual
chance constraints, its level ``xi`` swept over :func:`curve_xis` and every point scored on the
same episodes (common random numbers) as the policy it is compared with. A policy's *gap* is its
mean episode cost minus the curve's at the policy's own violation frequency, paired over the
episodes (:func:`benchmarks.core.stats.paired_curve_gap`); :attr:`~benchmarks.core.stats.CurveGap.relative`
is the gap in percent of the curve's cost.

>>> from sdjls_gym.systems import TASKS
>>> curve = reference_curve(TASKS["SDJLS-Solar-v0"], episodes=20, seed=0)
>>> curve.xis == SUITE_XIS, curve.costs.shape
(True, (11, 20))

The macro task keeps the curve :func:`benchmarks.evaluate.evaluate` has always drawn on it
(:data:`REFERENCE_XIS`, section 6's gains, ``Psi``, ``alpha`` and ``|nu| <= 100``); the other
tasks sweep the wider :data:`SUITE_XIS`, from nearly unconstrained (``xi = 0.01``) to nearly
never violating (``xi = 0.999``), so that the curve covers as many policies as it can.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from benchmarks.core.files import jsonable
from benchmarks.core.montecarlo import rollout
from benchmarks.core.stats import CurveGap, efficient_points, mean_ci, paired_curve_gap, wilson
from controllers.lru import BudgetedLRU
from sdjls_gym.model import SDJLSModel
from sdjls_gym.systems import TASKS, Task, random_task

if TYPE_CHECKING:
    from controllers import RecedingHorizonController, ScenarioTreeController

__all__ = [
    "CURVE_CACHE_SIZE",
    "QUICK_TREE",
    "REFERENCE_CONSTRAINT",
    "REFERENCE_XIS",
    "SUITE_XIS",
    "TREE_BY_TASK",
    "TREE_EPISODES",
    "TREE_STEPS",
    "TREE_XIS",
    "ReferenceCurve",
    "curve_xis",
    "gap_reason",
    "multistep_rhc",
    "one_step_rhc",
    "paper_rhc",
    "reference_curve",
    "task_of",
    "tree_rhc",
]

#: The macro task's reference curve: the levels ``xi`` of the paper's controller (unchanged
#: since the curve was introduced, so that every committed gap on the macro task stays valid).
REFERENCE_XIS: tuple[float, ...] = (0.3, 0.5, 0.7, 0.8, 0.85, 0.9, 0.95, 0.99)
#: The other tasks' reference curves: a wider sweep of ``xi``.
SUITE_XIS: tuple[float, ...] = (0.01, 0.1, 0.3, 0.5, 0.7, 0.8, 0.85, 0.9, 0.95, 0.99, 0.999)
#: The reference curves use individual chance constraints, eq. (constraint:det_univariate).
REFERENCE_CONSTRAINT = "individual"
#: Reference curves kept in memory (each is 2 float arrays of (levels, episodes)).
CURVE_CACHE_SIZE = 32
MACRO_ID = "SDJLS-Macro-v0"
#: The scenario tree's reference curve (the second view): its stages, its levels ``xi`` and its
#: episodes per level.
TREE_STEPS = 3
TREE_XIS: tuple[float, ...] = (0.5, 0.7, 0.85, 0.9, 0.95)
TREE_EPISODES = 100
#: Tasks whose tree is much slower get fewer episodes and levels: ``env_id -> (episodes,
#: levels)`` (VTOL: 13 nodes of 2 inputs).
TREE_BY_TASK: dict[str, tuple[int, tuple[float, ...]]] = {"SDJLS-VTOL-v0": (20, (0.5, 0.9))}
#: A smoke test's tree curve: episodes and levels.
QUICK_TREE: tuple[int, tuple[float, ...]] = (10, (0.5,))


def _model_key(model: SDJLSModel) -> str:
    return json.dumps(model.to_dict(), sort_keys=True)


def _task_key(task: Task) -> str:
    """Everything of ``task`` that its controllers depend on, as one string."""
    return json.dumps(
        jsonable({"model": task.model.to_dict(), "K": task.K, "rhc": dict(task.rhc)}),
        sort_keys=True,
    )


def curve_xis(task: Task) -> tuple[float, ...]:
    """The levels ``xi`` of ``task``'s reference curve: :data:`REFERENCE_XIS` on the macro
    task (the paper's system), :data:`SUITE_XIS` on every other."""
    return REFERENCE_XIS if _task_key(task) == _task_key(TASKS[MACRO_ID]) else SUITE_XIS


def task_of(env_id: str, env_kwargs: dict[str, Any], model: SDJLSModel) -> Task | None:
    """The suite's task whose system is ``model`` (the environment ``gym.make(env_id,
    **env_kwargs)`` made), or None: a task of :data:`sdjls_gym.systems.TASKS` with this model,
    or for ``SDJLS-Random-v0`` the :func:`~sdjls_gym.systems.random_task` of its arguments."""
    key = _model_key(model)
    for task in TASKS.values():
        if _model_key(task.model) == key:
            return task
    if env_id == "SDJLS-Random-v0":
        names = {"n": "n", "m": "m", "N": "N", "r": "r", "system_seed": "seed"}
        args = {names[k]: v for k, v in env_kwargs.items() if k in names}
        task = random_task(**args, spectral_radius=env_kwargs.get("spectral_radius", 1.2))
        if _model_key(task.model) == key:
            return task
    return None


def paper_rhc(
    model: SDJLSModel, xi: float, constraint: str = "individual", horizon: int | None = None
) -> RecedingHorizonController:
    """The paper's receding-horizon controller (section 6: PAPER_K, Psi, alpha, |nu| <= 100),
    for episodes of ``horizon`` steps (default: the paper's 20)."""
    from controllers import RecedingHorizonController
    from sdjls_gym.systems.macro import HORIZON, PAPER_K, PAPER_RHC

    return RecedingHorizonController(
        model, PAPER_K, Psi=PAPER_RHC["Psi"], xi=xi, alpha=PAPER_RHC["alpha"],
        nu_bound=PAPER_RHC["nu_bound"], constraint=constraint, horizon=horizon or HORIZON,
    )  # fmt: skip


def multistep_rhc(
    model: SDJLSModel,
    xi: float,
    steps: int = 3,
    constraint: str = "individual",
    horizon: int | None = None,
) -> ScenarioTreeController:
    """The multi-step receding-horizon controller on a fully branched scenario tree of
    ``steps`` stages (:class:`controllers.ScenarioTreeController`) with the paper's gains,
    ``Psi``, ``alpha`` and ``|nu| <= 100`` (section 6), for episodes of ``horizon`` steps."""
    from controllers import ScenarioTreeController
    from sdjls_gym.systems.macro import HORIZON, PAPER_K, PAPER_RHC

    return ScenarioTreeController(
        model, PAPER_K, Psi=PAPER_RHC["Psi"], xi=xi, alpha=PAPER_RHC["alpha"],
        nu_bound=PAPER_RHC["nu_bound"], steps=steps, constraint=constraint,
        horizon=horizon or HORIZON,
    )  # fmt: skip


def one_step_rhc(
    task: Task, xi: float, constraint: str = REFERENCE_CONSTRAINT, horizon: int | None = None
) -> Any:
    """The task's one-step receding-horizon controller (P3) at level ``xi``:
    ``RecedingHorizonController(task.model, task.K, horizon=horizon or task.horizon,
    **task.rhc)`` with ``xi`` and ``constraint`` replaced."""
    from controllers import RecedingHorizonController

    kw = {**task.rhc, "xi": xi, "constraint": constraint}
    return RecedingHorizonController(task.model, task.K, horizon=horizon or task.horizon, **kw)


def tree_rhc(
    task: Task,
    xi: float,
    steps: int = 3,
    constraint: str = REFERENCE_CONSTRAINT,
    horizon: int | None = None,
) -> Any:
    """The task's multi-step controller on a fully branched scenario tree of ``steps`` stages
    (:class:`controllers.ScenarioTreeController`) with the task's ``K`` and ``rhc`` data."""
    from controllers import ScenarioTreeController

    kw = {**task.rhc, "xi": xi, "constraint": constraint}
    return ScenarioTreeController(
        task.model, task.K, steps=steps, horizon=horizon or task.horizon, **kw
    )


@dataclass(frozen=True)
class ReferenceCurve:
    """A controller family over levels ``xi``, each scored on the same episodes.

    Attributes
    ----------
    env_id : str
    xis : (P,) tuple of float
        The levels, in the order of the rows below.
    constraint : str
        ``"individual"`` (the reference) or ``"joint"``.
    episodes, seed, steps : int
        ``episodes`` episodes of ``steps`` steps from noise seed ``seed``.
    costs, violations : (P, episodes) arrays
        Each point's episode costs and shares of violated steps.
    diverged : (P,) int array
        Each point's episodes that diverged.
    """

    env_id: str
    xis: tuple[float, ...]
    constraint: str
    episodes: int
    seed: int
    steps: int
    costs: np.ndarray
    violations: np.ndarray
    diverged: np.ndarray

    def gap(self, costs: np.ndarray, violations: np.ndarray) -> CurveGap | None:
        """A policy's paired gap to this curve from its episode costs and shares of violated
        steps (E,) on the same episodes (:func:`benchmarks.core.stats.paired_curve_gap`); None
        outside the curve's range of violation frequencies."""
        return paired_curve_gap(costs, violations, self.costs, self.violations, self.xis)

    def point(self, i: int) -> dict[str, Any]:
        """Point ``i``'s statistics, as :class:`benchmarks.evaluate.Score` states them: mean
        cost with its 95% Student-t interval, median, violation frequency with its 95% Wilson
        interval, diverged episodes."""
        mean, lo, hi = mean_ci(self.costs[i], floor=0.0)
        count = int(round(float(self.violations[i].sum()) * self.steps))
        total = self.episodes * self.steps
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


#: Not functools: the key is what a curve depends on (the task as its JSON, the levels, ...), not
#: the arguments (a Task does not hash; the progress bar is no part of a curve).
_CACHE: BudgetedLRU[tuple[Any, ...], ReferenceCurve] = BudgetedLRU(CURVE_CACHE_SIZE)


def reference_curve(
    task: Task,
    episodes: int,
    seed: int,
    *,
    horizon: int | None = None,
    action_bound: float | np.ndarray | None = None,
    divergence_bound: float = 1e6,
    constraint: str = REFERENCE_CONSTRAINT,
    xis: tuple[float, ...] | None = None,
    progress: Any = None,
) -> ReferenceCurve:
    """The one-step receding-horizon controller of ``task`` over ``xis`` (default
    :func:`curve_xis`), each level scored on ``episodes`` episodes from noise seed ``seed``.

    ``horizon``, ``action_bound`` and ``divergence_bound`` are the environment's (default: the
    task's horizon and bound, and the environments' default divergence bound). The last
    :data:`CURVE_CACHE_SIZE` curves are kept, keyed by everything they depend on; ``progress``
    (a tqdm bar) advances by one per simulated step, on a computed curve only.
    """
    xis = curve_xis(task) if xis is None else tuple(float(x) for x in xis)
    horizon = task.horizon if horizon is None else int(horizon)
    bound = float(np.max(task.action_bound if action_bound is None else action_bound))
    key = (_task_key(task), episodes, seed, horizon, bound, float(divergence_bound), constraint,
           xis)  # fmt: skip
    return _CACHE.get(key, _curve, task, episodes, seed, horizon, bound, divergence_bound,
                      constraint, xis, progress)  # fmt: skip


def _curve(task: Task, episodes: int, seed: int, horizon: int, bound: float,
           divergence_bound: float, constraint: str, xis: tuple[float, ...],
           progress: Any) -> ReferenceCurve:  # fmt: skip
    costs, viols, diverged = [], [], []
    for xi in xis:
        ctrl = one_step_rhc(task, xi, constraint, horizon)
        ro = rollout(task.model, ctrl, episodes, horizon, seed, bound, progress, divergence_bound)
        costs.append(ro.episode_cost)
        viols.append(ro.any_violation.mean(axis=1))
        diverged.append(int(np.any(np.abs(ro.x) > divergence_bound, axis=(1, 2)).sum()))
    return ReferenceCurve(task.env_id, xis, constraint, episodes, seed, horizon,
                          np.stack(costs), np.stack(viols), np.array(diverged))  # fmt: skip


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
