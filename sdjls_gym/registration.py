"""The Gymnasium ids of the package: their registration and the entry points of the Random task.

Imported by ``sdjls_gym/__init__.py``, so ``import sdjls_gym`` registers:

* ``SDJLS-v0``: any system, ``gym.make("SDJLS-v0", model=model, horizon=T)``;
* ``SDJLS-Macro-v0``: the macroeconomic example of section 6 of the paper (20 quarters);
* the other tasks of the suite (``sdjls_gym.systems.TASKS``), among them the seeded generator
  ``SDJLS-Random-v0``, built by :func:`make_random_env` / :func:`make_random_vector_env`.

Every id has a ``vector_entry_point`` (:class:`~sdjls_gym.vector_env.SDJLSVectorEnv`) and none
registers a ``TimeLimit``: the environments truncate at their own ``horizon``. Every id accepts
the environments' arguments, among them ``observe="state"`` (the mode hidden from the
observation; ``gym.make(env_id, observe="state")``). The id of a preset task builds that task's
system only: ``gym.make("SDJLS-Solar-v0", model=...)`` with another model is a ``ValueError``
(:func:`sdjls_gym.env.own_spec`); ``SDJLS-v0`` takes any model.
"""

from __future__ import annotations

import inspect
from typing import Any

import gymnasium

from sdjls_gym.env import SDJLSEnv, make_env
from sdjls_gym.systems import TASKS
from sdjls_gym.systems import random_system as _random
from sdjls_gym.systems.macro import ACTION_BOUND as MACRO_ACTION_BOUND
from sdjls_gym.systems.macro import HORIZON as MACRO_HORIZON
from sdjls_gym.vector_env import SDJLSVectorEnv

__all__ = ["check_random_kwargs", "make_random_env", "make_random_vector_env", "register_ids"]

ENTRY_POINT = "sdjls_gym.env:make_env"
VECTOR_ENTRY_POINT = "sdjls_gym.vector_env:SDJLSVectorEnv"


def check_random_kwargs(kwargs: dict[str, Any]) -> None:
    """Refuse what is left of ``SDJLS-Random-v0``'s keyword arguments (``seed`` with a hint).

    Raises
    ------
    TypeError
        ``kwargs`` is not empty.
    """
    if "seed" in kwargs:
        raise TypeError(
            f"seed = {kwargs['seed']!r} is not an argument of SDJLS-Random-v0: system_seed=... "
            "chooses the system, and env.reset(seed=...) seeds the noise and the initial mode"
        )
    if kwargs:
        raise TypeError(
            f"unexpected argument(s) {sorted(kwargs)} of SDJLS-Random-v0; expected n, m, N, r, "
            "system_seed, spectral_radius and the environment's arguments"
        )


#: The environment's own arguments that the Random task's entry points pass on.
_ENV_ARGUMENTS = ("divergence_bound", "render_mode", "observe")


def make_random_env(
    n: int = 3,
    m: int = 1,
    N: int = 2,
    r: int = 2,
    system_seed: int = 0,
    spectral_radius: float = 1.2,
    horizon: int = _random.HORIZON,
    action_bound: float = _random.ACTION_BOUND,
    **env_kwargs: Any,
) -> SDJLSEnv:
    """The entry point of ``SDJLS-Random-v0``: an ``SDJLSEnv`` of
    :func:`~sdjls_gym.systems.random_task`.

    ``env_kwargs`` may hold ``divergence_bound``, ``render_mode`` and ``observe``; ``seed`` is
    refused (``system_seed`` chooses the system, ``reset(seed=...)`` the noise).
    """
    extra = _env_arguments(env_kwargs, _ENV_ARGUMENTS)
    task = _random.random_task(n, m, N, r, system_seed, spectral_radius=spectral_radius)
    return make_env(model=task.model, horizon=horizon, action_bound=action_bound, **extra)


def make_random_vector_env(num_envs: int = 1, **kwargs: Any) -> SDJLSVectorEnv:
    """The vector entry point of ``SDJLS-Random-v0``: an ``SDJLSVectorEnv`` of ``num_envs``
    environments of the system :func:`make_random_env` builds from the same arguments
    (``kwargs``: its parameters, and ``max_episode_steps`` besides the environment's own)."""
    arguments = inspect.signature(make_random_env).bind(**kwargs)
    arguments.apply_defaults()
    a = arguments.arguments
    extra = _env_arguments(a["env_kwargs"], (*_ENV_ARGUMENTS, "max_episode_steps"))
    task = _random.random_task(
        a["n"], a["m"], a["N"], a["r"], a["system_seed"], spectral_radius=a["spectral_radius"]
    )
    return SDJLSVectorEnv(
        num_envs=num_envs,
        model=task.model,
        horizon=a["horizon"],
        action_bound=a["action_bound"],
        **extra,
    )


def _env_arguments(env_kwargs: dict[str, Any], names: tuple[str, ...]) -> dict[str, Any]:
    """The entries of ``env_kwargs`` named in ``names``; anything else refused
    (:func:`check_random_kwargs`)."""
    rest = dict(env_kwargs)
    extra = {key: rest.pop(key) for key in names if key in rest}
    check_random_kwargs(rest)
    return extra


def register_ids() -> None:
    """Register every id of the package with Gymnasium (ids already registered are kept)."""
    if "SDJLS-v0" not in gymnasium.registry:
        gymnasium.register(
            id="SDJLS-v0", entry_point=ENTRY_POINT, vector_entry_point=VECTOR_ENTRY_POINT
        )
    if "SDJLS-Macro-v0" not in gymnasium.registry:
        gymnasium.register(
            id="SDJLS-Macro-v0",
            entry_point=ENTRY_POINT,
            vector_entry_point=VECTOR_ENTRY_POINT,
            # no max_episode_steps: the env truncates at its own horizon (so that horizon=40
            # alone works) and reports it as env.spec.max_episode_steps
            kwargs={"model": "macro", "horizon": MACRO_HORIZON, "action_bound": MACRO_ACTION_BOUND},
        )
    # the suite's other tasks, registered as SDJLS-Macro-v0 is (no TimeLimit: see above); the
    # model goes in as its to_dict(), so that the registered spec is plain JSON
    for env_id, task in TASKS.items():
        if env_id in ("SDJLS-Macro-v0", "SDJLS-Random-v0") or env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point=ENTRY_POINT,
            vector_entry_point=VECTOR_ENTRY_POINT,
            kwargs={
                "model": task.model.to_dict(),
                "horizon": task.horizon,
                "action_bound": task.action_bound,
            },
        )
    if "SDJLS-Random-v0" not in gymnasium.registry:
        gymnasium.register(
            id="SDJLS-Random-v0",
            entry_point="sdjls_gym.registration:make_random_env",
            vector_entry_point="sdjls_gym.registration:make_random_vector_env",
        )
