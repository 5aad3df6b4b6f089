"""Every hyperparameter of ``python -m benchmarks.compare_rl``, in one place.

Starting point: the rl-zoo3 entries (github.com/DLR-RM/rl-baselines3-zoo, ``hyperparams/*.yml``)
for Pendulum-v1, the closest continuous-control task in size (a 1-d action, a few observations,
a quadratic-like cost to drive down). What changed, and why:

* ``gamma = 0.99`` for all three (Pendulum: PPO 0.9, TD3 0.98, SAC default 0.99): an episode
  here is a finite 20-step horizon that is scored by its undiscounted cost, with the time
  ``k / 20`` in the observation, so the discount is kept close to 1.
* ``net_arch = [64, 64]`` for every network (TD3's Pendulum entry uses [400, 300], SAC's the
  SB3 default [256, 256]): the observation has 6 entries and a good policy is nearly linear
  in ``x``; the small network is 3-5x faster per gradient step on a CPU, which buys the longer
  budgets below on 2 cores.
* PPO: rl-zoo's Pendulum entry (4 envs x 1024 steps, 10 epochs, lr 1e-3, clip 0.2,
  gae_lambda 0.95, gSDE with sde_sample_freq 4) with ``log_std_init = -1``: the action is
  rescaled to [-1, 1] where a good ``u`` is about 0.1, so the default unit noise mostly
  produces diverging episodes at the start.
* SAC: Pendulum's (lr 1e-3, otherwise SB3 defaults: batch 256, tau 0.005, ent_coef auto,
  train_freq 1) with ``learning_starts = 1000`` instead of 100.
* TD3: Pendulum's (lr 1e-3, normal action noise 0.1, ``train_freq = (1, "episode")`` with
  ``gradient_steps = -1``) with ``learning_starts = 1000`` instead of 10000: the 10000 random
  steps of Pendulum's entry would be most of the budget here.

Rewards and observations are scaled by fixed constants (:data:`ENV`) instead of
``VecNormalize``: a random policy makes the unstable system diverge, with per-step rewards near
``-1e11``, and ``VecNormalize``'s running statistics never forget those first episodes, so a
good policy's rewards (``-1e2``..``-1e3``) would be normalized to zero for the rest of training.
Evaluation always scores the true, unscaled cost.
"""

from __future__ import annotations

from typing import Any

#: Fixed observation and reward scaling of the training environments (and of the policy
#: adapter at evaluation): ``x / x_scale`` clipped to ``+-obs_clip``; the penalized reward
#: clipped below at ``-reward_clip`` (only diverging states reach it) then divided by
#: ``reward_scale``.
ENV: dict[str, float] = {
    "x_scale": 10.0,
    "obs_clip": 10.0,
    "reward_scale": 100.0,
    "reward_clip": 1e5,
}

#: Fixed violation penalties ``beta`` of the penalized variants, in units of the stage cost.
#: Staying just inside the band costs ``x'Q x`` of about 10 (k = 0) to 300 (k = 20) per step
#: more than sitting at the origin, so 100, 1000 and 10000 span "violate when it is cheap" to
#: "never violate".
BETAS: tuple[float, ...] = (100.0, 1000.0, 10000.0)

#: Dual ascent of the constrained (Lagrangian) variant:
#: ``beta <- max(0, beta + lr_dual * (violation frequency - (1 - xi)))`` every ``period`` env
#: steps, the frequency being the per-step ``info["cost"]`` mean over those steps.
LAGRANGIAN: dict[str, float] = {
    "xi": 0.85,
    "beta0": 1000.0,
    "lr_dual": 2000.0,
    "period": 2000,
}

#: Offsets of the residual agents: ``u = K_theta x + nu`` with ``|nu| <= nu_bound`` (the paper's
#: set U, the same as the receding-horizon controller's).
RESIDUAL_NU_BOUND = 100.0

_NET = [64, 64]

PPO: dict[str, Any] = {
    "n_envs": 4,
    "n_steps": 1024,
    "batch_size": 64,
    "n_epochs": 10,
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "learning_rate": 1e-3,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "use_sde": True,
    "sde_sample_freq": 4,
    "policy_kwargs": {"net_arch": _NET, "log_std_init": -1.0},
}

SAC: dict[str, Any] = {
    "n_envs": 1,
    "learning_rate": 1e-3,
    "buffer_size": 200_000,
    "learning_starts": 1000,
    "batch_size": 256,
    "tau": 0.005,
    "gamma": 0.99,
    "train_freq": 1,
    "gradient_steps": 1,
    "ent_coef": "auto",
    "policy_kwargs": {"net_arch": _NET},
}

TD3: dict[str, Any] = {
    "n_envs": 1,
    "learning_rate": 1e-3,
    "buffer_size": 200_000,
    "learning_starts": 1000,
    "batch_size": 256,
    "gamma": 0.99,
    "train_freq": (1, "episode"),
    "gradient_steps": -1,
    "noise_std": 0.1,
    "policy_kwargs": {"net_arch": _NET},
}

HYPERPARAMS: dict[str, dict[str, Any]] = {"ppo": PPO, "sac": SAC, "td3": TD3}

#: Default training budget (env steps) per run, chosen from measured speeds on 2 cores so that
#: the default run (3 algorithms x 3 seeds x 6 variants) takes about 75 minutes; see
#: ``benchmarks/compare_rl.py``'s docstring for the measurement.
TIMESTEPS: dict[str, int] = {"ppo": 100_000, "sac": 20_000, "td3": 20_000}

#: Budget of ``--quick``.
QUICK_TIMESTEPS = 2000

#: Learning curves: ``points`` evaluations per run of ``episodes`` episodes on a fixed seed.
LEARNING_CURVE: dict[str, int] = {"points": 10, "episodes": 100, "seed": 12345}
