"""The model-based reference of every task: its receding-horizon controllers and their levels.

A task's reference controller is the one-step receding-horizon controller of the paper (P3) on
that task, ``RecedingHorizonController(task.model, task.K, horizon=T, **task.rhc)`` with
individual chance constraints (:func:`one_step_rhc`), over the levels ``xi`` of
:func:`curve_xis`; its curve on a policy's own episodes, and the gap to it, are
:mod:`benchmarks.core.frontier`'s. The macro task keeps the levels the paper's controller has
always been drawn at (:data:`REFERENCE_XIS`, section 6's gains, ``Psi``, ``alpha`` and
``|nu| <= 100``); the other tasks start from the wider :data:`SUITE_XIS`, from nearly
unconstrained (``xi = 0.01``) to nearly never violating (``xi = 0.999``). The multi-step
scenario tree (:func:`tree_rhc`) is the second view, on the levels of :data:`TREE_XIS`.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from benchmarks.core.files import jsonable
from sdjls_gym.model import SDJLSModel
from sdjls_gym.systems import TASKS, Task, random_task

if TYPE_CHECKING:
    from controllers import RecedingHorizonController, ScenarioTreeController

__all__ = [
    "QUICK_TREE",
    "REFERENCE_CONSTRAINT",
    "REFERENCE_XIS",
    "SUITE_XIS",
    "TREE_BY_TASK",
    "TREE_STEPS",
    "TREE_XIS",
    "curve_xis",
    "multistep_rhc",
    "one_step_rhc",
    "paper_rhc",
    "task_key",
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
MACRO_ID = "SDJLS-Macro-v0"
#: The scenario tree's reference curve (the second view): its stages and its levels ``xi``. It
#: runs on the evaluation's own episodes (every noise seed's, as many as the one-step curve's),
#: so that a gap to the tree rests on as many episodes as a gap to the one-step RHC. Its
#: decisions cost 10 to 1000 times the one-step controller's; each level's run is kept
#: (:mod:`benchmarks.core.tree_levels`), so a rerun of the scoring does not repeat them.
TREE_STEPS = 3
TREE_XIS: tuple[float, ...] = (0.5, 0.7, 0.85, 0.9, 0.95)
#: Tasks whose tree is much slower get fewer levels: ``env_id -> levels``; VTOL's 13 nodes of
#: 2 inputs take about 5 ms a decision on one core (one level on 3000 episodes: about 10 CPU-min).
TREE_BY_TASK: dict[str, tuple[float, ...]] = {"SDJLS-VTOL-v0": (0.5, 0.9, 0.97)}
#: A smoke test's tree curve: episodes and levels.
QUICK_TREE: tuple[int, tuple[float, ...]] = (10, (0.5,))


def _model_key(model: SDJLSModel) -> str:
    return json.dumps(model.to_dict(), sort_keys=True)


def task_key(task: Task) -> str:
    """Everything of ``task`` that its controllers depend on, as one string."""
    return json.dumps(
        jsonable({"model": task.model.to_dict(), "K": task.K, "rhc": dict(task.rhc)}),
        sort_keys=True,
    )


def curve_xis(task: Task) -> tuple[float, ...]:
    """The levels ``xi`` of ``task``'s reference curve: :data:`REFERENCE_XIS` on the macro
    task (the paper's system), :data:`SUITE_XIS` on every other."""
    return REFERENCE_XIS if task_key(task) == task_key(TASKS[MACRO_ID]) else SUITE_XIS


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
