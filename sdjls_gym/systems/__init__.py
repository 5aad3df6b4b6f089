"""Preset systems and the suite's tasks.

* ``macro()`` is the paper's example (section 6), also the preset ``"macro"`` of ``PRESETS``
  (``gym.make("SDJLS-v0", model="macro")``); ``solar()``, ``vtol()``, ``three_state()`` and
  ``degradation()`` are published Markov jump linear systems with a state-dependent part added
  by this project (each module's docstring says what comes from where).
* ``TASKS``: env id -> :class:`Task` (the model, horizon, action bound, pre-stabilizing gains
  ``K`` and the keyword arguments ``rhc`` of the receding-horizon controllers) for every id of
  ``sdjls_gym.SUITE``; ``TASKS["SDJLS-Random-v0"]`` is :func:`random_task` with its defaults.

The published tasks' receding-horizon controllers follow one recipe (each module gives its
bound on ``nu``): individual chance constraints at ``xi = 0.9``, ``alpha = 1000``; ``Psi_i`` is
the solution ``X_i`` of the coupled Riccati equations of the MJLS LQ problem with ``P_in``
(``MJLSLQRController(model, "in").X``) to 4 significant digits, and ``K`` the solution of
Proposition 2 by ``controllers.synthesize_gains(model)`` (Clarabel) to 4 decimals.
``tests/test_suite_tasks.py`` checks both against a fresh computation and certifies ``K`` with
Proposition 1; ``RecedingHorizonController.from_model`` follows the same recipe.
"""

from sdjls_gym.systems import degradation as _degradation
from sdjls_gym.systems import macro as _macro
from sdjls_gym.systems import solar as _solar
from sdjls_gym.systems import three_state as _three_state
from sdjls_gym.systems import vtol as _vtol
from sdjls_gym.systems.degradation import degradation
from sdjls_gym.systems.macro import macro
from sdjls_gym.systems.random_system import random_task
from sdjls_gym.systems.solar import solar
from sdjls_gym.systems.task import Task
from sdjls_gym.systems.three_state import three_state
from sdjls_gym.systems.vtol import vtol

PRESETS = {"macro": macro}

#: Source of the macro example.
MACRO_SOURCE = (
    "Chitraganti, Aberkane, Aubrun, Valencia-Palomo and Dragan, Systems & Control Letters "
    "2014, section 6 (the paper this project implements)"
)


def _build_tasks() -> dict[str, Task]:
    # the macro task: the paper's gains and parameters, with the (default) constraint kind
    # written out so that every task's rhc has the same keys
    tasks = {
        "SDJLS-Macro-v0": Task(
            env_id="SDJLS-Macro-v0",
            model=macro(),
            horizon=_macro.HORIZON,
            action_bound=_macro.ACTION_BOUND,
            K=_macro.PAPER_K,
            rhc={"constraint": "individual", **_macro.PAPER_RHC},
            source=MACRO_SOURCE,
        )
    }
    for module, make in (
        (_solar, solar),
        (_vtol, vtol),
        (_three_state, three_state),
        (_degradation, degradation),
    ):
        tasks[module.ENV_ID] = Task(
            env_id=module.ENV_ID,
            model=make(),
            horizon=module.HORIZON,
            action_bound=module.ACTION_BOUND,
            K=module.K,
            rhc=module.RHC,
            source=module.SOURCE,
        )
    tasks["SDJLS-Random-v0"] = random_task()
    return tasks


#: Env id -> Task for every id of ``sdjls_gym.SUITE`` (the macro example first).
TASKS: dict[str, Task] = _build_tasks()

__all__ = [
    "PRESETS",
    "MACRO_SOURCE",
    "TASKS",
    "Task",
    "degradation",
    "macro",
    "random_task",
    "solar",
    "three_state",
    "vtol",
]
