"""sdjls-gym: state-dependent jump linear systems as Gymnasium environments.

Importing the package registers these environment ids (``sdjls_gym.registration``):

* ``SDJLS-v0``: any system, ``gym.make("SDJLS-v0", model=model, horizon=T)``;
* ``SDJLS-Macro-v0``: the macroeconomic example of section 6 of the paper (20 quarters);
* the other tasks of the suite, ``SUITE`` (see ``sdjls_gym.systems.TASKS``):
  ``SDJLS-Solar-v0``, ``SDJLS-VTOL-v0``, ``SDJLS-ThreeState-v0``, ``SDJLS-Degradation-v0`` and
  the seeded generator ``SDJLS-Random-v0`` (``gym.make("SDJLS-Random-v0", n=4,
  system_seed=3)``; ``system_seed`` chooses the system, ``reset(seed=...)`` the noise).

All have a ``vector_entry_point`` (``SDJLSVectorEnv``). None registers a
``TimeLimit``: the environments truncate at their own ``horizon``, which ``env.spec`` reports as
``max_episode_steps``. ``max_episode_steps=`` given to ``gym.make`` adds Gymnasium's
``TimeLimit``, which can only shorten episodes (above the horizon it changes nothing but the
spec it reports: pass ``horizon=`` instead); ``SDJLSVectorEnv`` (``gym.make_vec``) refuses a
value above the horizon. ``gym.make("sdjls_gym:SDJLS-Macro-v0")`` imports the package first.

The exceptions are in :mod:`sdjls_gym.errors`, the argument rules in
:mod:`sdjls_gym.validation`.
"""

from sdjls_gym.env import SDJLSEnv
from sdjls_gym.errors import InvalidModelError, InvalidModelTypeError
from sdjls_gym.model import SDJLSModel
from sdjls_gym.model_files import load_model, save_model
from sdjls_gym.registration import register_ids
from sdjls_gym.systems import TASKS, macro
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

register_ids()
