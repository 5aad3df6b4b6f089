"""sdjls-gym: state-dependent jump linear systems as Gymnasium environments.

Importing the package registers these environment ids:

* ``SDJLS-v0``: any system, ``gym.make("SDJLS-v0", model=model, horizon=T)``;
* ``SDJLS-Macro-v0``: the macroeconomic example of section 6 of the paper (20 quarters);
* the other tasks of the suite, ``SUITE`` (see ``sdjls_gym.systems.TASKS``):
  ``SDJLS-Solar-v0``, ``SDJLS-VTOL-v0``, ``SDJLS-ThreeState-v0``, ``SDJLS-Degradation-v0`` and
  the seeded generator ``SDJLS-Random-v0`` (``gym.make("SDJLS-Random-v0", n=4,
  system_seed=3)``; ``system_seed`` chooses the system, ``reset(seed=...)`` the noise).

All have a ``vector_entry_point`` (``SDJLSVectorEnv``). None registers a
``TimeLimit``: the environments truncate at their own ``horizon``, which ``env.spec`` reports as
``max_episode_steps``. ``max_episode_steps=`` given to ``gym.make`` or ``gym.make_vec`` may only
shorten episodes (a value above the horizon is a ``ValueError``).
``gym.make("sdjls_gym:SDJLS-Macro-v0")`` imports the package first.
"""

import gymnasium

from sdjls_gym.env import SDJLSEnv
from sdjls_gym.model import InvalidModelError, InvalidModelTypeError, SDJLSModel
from sdjls_gym.model_files import load_model, save_model
from sdjls_gym.systems import TASKS, macro
from sdjls_gym.systems.macro import ACTION_BOUND as _MACRO_ACTION_BOUND
from sdjls_gym.systems.macro import HORIZON as _MACRO_HORIZON
from sdjls_gym.vector_env import SDJLSVectorEnv

__all__ = [
    "SDJLSModel",
    "InvalidModelError",
    "InvalidModelTypeError",
    "SDJLSEnv",
    "SDJLSVectorEnv",
    "load_model",
    "save_model",
    "macro",
    "SUITE",
    "TASKS",
]

#: The env ids of the suite, the paper's macro example first (``sdjls_gym.systems.TASKS``).
SUITE: tuple[str, ...] = tuple(TASKS)

__version__ = "0.1.0"

if "SDJLS-v0" not in gymnasium.registry:
    gymnasium.register(
        id="SDJLS-v0",
        entry_point="sdjls_gym.env:make_env",
        vector_entry_point="sdjls_gym.vector_env:SDJLSVectorEnv",
    )
if "SDJLS-Macro-v0" not in gymnasium.registry:
    gymnasium.register(
        id="SDJLS-Macro-v0",
        entry_point="sdjls_gym.env:make_env",
        vector_entry_point="sdjls_gym.vector_env:SDJLSVectorEnv",
        # no max_episode_steps: the env truncates at its own horizon (so that horizon=40 alone
        # works) and reports it as env.spec.max_episode_steps
        kwargs={"model": "macro", "horizon": _MACRO_HORIZON, "action_bound": _MACRO_ACTION_BOUND},
    )

# the suite's other tasks, registered as SDJLS-Macro-v0 is (no TimeLimit: see above); the model
# goes in as its to_dict(), so that the registered spec is plain JSON
for _env_id, _task in TASKS.items():
    if _env_id in ("SDJLS-Macro-v0", "SDJLS-Random-v0") or _env_id in gymnasium.registry:
        continue
    gymnasium.register(
        id=_env_id,
        entry_point="sdjls_gym.env:make_env",
        vector_entry_point="sdjls_gym.vector_env:SDJLSVectorEnv",
        kwargs={
            "model": _task.model.to_dict(),
            "horizon": _task.horizon,
            "action_bound": _task.action_bound,
        },
    )
if "SDJLS-Random-v0" not in gymnasium.registry:
    gymnasium.register(
        id="SDJLS-Random-v0",
        entry_point="sdjls_gym.systems.random_system:make_random_env",
        vector_entry_point="sdjls_gym.systems.random_system:make_random_vector_env",
    )
