"""One public function per training variant: the environment an agent of that variant trains on.

Each is :func:`benchmarks.rl.envs.make_train_env` with its variant fixed, so that a saved agent
is scored with one flag, ``--train-env benchmarks.rl.train_envs:VARIANT`` (on the macro task by
default; the rl-zoo3 files of ``benchmarks/rl/zoo/`` build the same wrappers, which
``tests/test_rl_zoo3.py`` checks)::

    python -m benchmarks.evaluate --policy /tmp/sdjls-zoo/sac/SDJLS-Macro-v0_1/SDJLS-Macro-v0.zip \\
        --algo sac --train-env benchmarks.rl.train_envs:beta10000

>>> from benchmarks.rl.train_envs import residual
>>> residual("SDJLS-VTOL-v0").action_space.shape
(2,)
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from benchmarks.rl.envs import MACRO, make_train_env

__all__ = ["beta100", "beta1000", "beta10000", "lagrangian", "residual", "reward"]


def reward(task: Any = MACRO) -> gym.Env:
    """``task``'s training environment of the agent on the reward alone."""
    return make_train_env(task, "reward")


def beta100(task: Any = MACRO) -> gym.Env:
    """``task``'s training environment with the fixed violation penalty beta = 100."""
    return make_train_env(task, "beta100")


def beta1000(task: Any = MACRO) -> gym.Env:
    """``task``'s training environment with the fixed violation penalty beta = 1000."""
    return make_train_env(task, "beta1000")


def beta10000(task: Any = MACRO) -> gym.Env:
    """``task``'s training environment with the fixed violation penalty beta = 10000 (the SAC
    and TD3 files of ``benchmarks/rl/zoo/``)."""
    return make_train_env(task, "beta10000")


def residual(task: Any = MACRO) -> gym.Env:
    """``task``'s training environment of the residual agent, ``u = K_theta x + nu`` (the PPO
    file of ``benchmarks/rl/zoo/``)."""
    return make_train_env(task, "residual")


def lagrangian(task: Any = MACRO) -> gym.Env:
    """``task``'s training environment of the Lagrangian agents (its penalty is the dual
    variable's starting value; training adapts it)."""
    return make_train_env(task, "lagrangian")
