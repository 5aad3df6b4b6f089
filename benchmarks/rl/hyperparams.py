"""Every hyperparameter of ``python -m benchmarks.compare_rl``, in one place.

Starting point: rl-zoo3's entries for Pendulum-v1 (the closest continuous-control task in size),
changed where short trials on this environment showed a need: ``gamma = 0.99`` (a 20-step horizon
scored undiscounted), ``net_arch = [64, 64]`` (6 observations; faster per gradient step on a
CPU), PPO with 8 envs x 256 steps and ``log_std_init = -2`` (a good action is about 0.1 in
[-1, 1]), SAC and TD3 with ``learning_starts = 1000``, a 200k replay buffer and one training
phase per episode. Observations and rewards are scaled by fixed functions
(:data:`ENV`, :class:`sdjls_gym.wrappers.ScaleObservationReward`) rather than ``VecNormalize``,
whose running statistics never forget the first, diverging episodes. What was tried and what it
gave is in ``results/rl/HISTORY.md``.

The suite comparison uses the same hyperparameters on every task, with the scalings
of each task (:data:`TASK_SCALES`), the penalties in units of its reward scale, its own
configurations, seeds and budgets (:data:`SUITE_CONFIGS`, :data:`SUITE_SEEDS`,
:data:`SUITE_TIMESTEPS`); their history is ``results/rl_suite/HISTORY.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from sdjls_gym import wrappers as W

#: Fixed observation and reward scalings of the training environments (the keyword arguments of
#: :class:`~sdjls_gym.wrappers.ScaleObservationReward`, whose defaults they are) and the bound of
#: :class:`~sdjls_gym.wrappers.TerminateOutside`: ``x / x_scale`` clipped to ``+-obs_clip``; the
#: penalized reward ``r`` becomes ``-log(1 + max(-r, 0) / reward_scale)`` (``reward_clip = 1e30``
#: is no clipping); training episodes end once ``max |x| > terminate_bound``.
ENV: dict[str, float | str] = {
    "x_scale": W.X_SCALE,
    "obs_clip": W.OBS_CLIP,
    "reward_scale": W.REWARD_SCALE,
    "reward_clip": W.REWARD_CLIP,
    "reward_transform": W.REWARD_TRANSFORM,
    "terminate_bound": W.TERMINATE_BOUND,
}

#: Per task of the suite: the observation's state scale ``x_scale``, the reward scale
#: ``reward_scale`` (both of :data:`ENV`) and the bound ``u_bound`` on ``|u|`` of the agents acting
#: on ``u`` (:data:`U_BOUND` on the macro task). Written from one rule,
#: :func:`benchmarks.rl.envs.derive_scales`, on 300 episodes (noise seed 0) of the task's own
#: receding-horizon controller at its ``xi``: ``x_scale`` is the 95th percentile of ``|x_i|``,
#: ``reward_scale`` the mean stage cost / 2.5 and ``u_bound`` 1.25 x the largest ``|u_i|`` (not
#: below it, at most the task's action bound), each to one significant digit. The rule gives the
#: macro task the values ``results/rl`` was trained with. Every penalty (:data:`BETAS`,
#: :data:`RESIDUAL_BETA`, the Lagrangian's ``beta0`` and ``lr_dual``) is written for the macro
#: task's reward scale, 100, and multiplied by ``reward_scale / 100`` on the others; training
#: episodes end at ``|x| > TERMINATE_SCALES * x_scale``. Tasks outside this table (the generator
#: with other parameters) get :func:`~benchmarks.rl.envs.derive_scales` at run time.
TASK_SCALES: dict[str, dict[str, float]] = {
    "SDJLS-Macro-v0": {"x_scale": 10.0, "reward_scale": 100.0, "u_bound": 60.0},
    "SDJLS-Solar-v0": {"x_scale": 2.0, "reward_scale": 20.0, "u_bound": 50.0},
    "SDJLS-VTOL-v0": {"x_scale": 2.0, "reward_scale": 3.0, "u_bound": 20.0},
    "SDJLS-ThreeState-v0": {"x_scale": 0.9, "reward_scale": 0.5, "u_bound": 2.0},
    "SDJLS-Degradation-v0": {"x_scale": 1.0, "reward_scale": 0.2, "u_bound": 2.0},
    "SDJLS-Random-v0": {"x_scale": 0.2, "reward_scale": 0.02, "u_bound": 0.8},
}

#: Training episodes end once ``max |x| > TERMINATE_SCALES * x_scale`` (100 on the macro task,
#: :data:`ENV`'s ``terminate_bound``): there the scaled observation is saturated.
TERMINATE_SCALES = 10.0

#: Fixed violation penalties ``beta`` of the penalized variants, added to the stage cost before
#: the training reward's log transform (see :data:`ENV`): the penalized per-step cost is
#: ``c = x'Qx + u'Ru + beta * info["cost"]``. Staying just inside the band costs ``x'Q x`` of
#: about 10 (k = 0) to 300 (k = 20) per step more than sitting at the origin, so 100, 1000 and
#: 10000 span "violate when it is cheap" to "never violate" in ``c``. The log compresses the
#: spread: at a stage cost of 250 a violation lowers the training reward by 0.25, 1.35 and 3.39.
BETAS: tuple[float, ...] = (100.0, 1000.0, 10000.0)

#: Dual ascent of the constrained (Lagrangian) variant:
#: ``beta <- max(0, beta + lr_dual * (violation frequency - (1 - xi)))`` at the end of the first
#: rollout after ``period`` env steps (PPO: every rollout of 8 x 256 steps; SAC, TD3: every 25
#: episodes). The frequency is the deterministic policy's (the one evaluated and compared with
#: the RHC) on ``episodes`` fresh evaluation episodes (new noise each update, from ``seed`` and
#: the run's seed); the exploring policy's own frequency is only logged: with TD3's action noise
#: it never comes near the target, and beta would only grow.
LAGRANGIAN: dict[str, Any] = {
    "xi": 0.85,
    "beta0": 1000.0,
    "lr_dual": 2000.0,
    "period": {"ppo": 2048, "sac": 500, "td3": 500},
    "episodes": 100,
    "seed": 777,
}

#: Bound on ``|u|`` of the agents acting on ``u``: they train on ``SDJLS-Macro-v0`` made with
#: ``action_bound=U_BOUND``, so their action ``a`` in [-1, 1] is ``u = U_BOUND * a``. The
#: registered bound, 200, is about four times the paper's controller's largest input; at 200,
#: exploration noise of 0.1 in ``a`` is an input noise of 20. Evaluation runs the registered
#: environment (bound 200); the agent never asks for more than 60.
U_BOUND = 60.0

#: Offsets of the residual agents: ``u = K_theta x + nu`` with ``|nu| <= nu_bound`` (the paper's
#: set U, the same as the receding-horizon controller's).
RESIDUAL_NU_BOUND = 100.0

#: On the suite's tasks the residual agents' bound on ``|nu|`` is the task's receding-horizon
#: controller's ``nu_bound``, at most this many times the task's ``u_bound`` (:data:`TASK_SCALES`):
#: ``nu`` must be able to cancel ``K x`` (about ``u``) and add as much again. The RHC's bounds are
#: 5-50 times the largest ``|u|`` it applies on the small tasks, where exploration noise of a
#: fixed share of ``[-1, 1]`` would otherwise be an input noise several times the useful input.
#: Macro: min(100, 2 x 60) = :data:`RESIDUAL_NU_BOUND`.
RESIDUAL_NU_U_BOUNDS = 2.0

#: Violation penalty of the residual agents (the middle of :data:`BETAS`): like the
#: receding-horizon controller, they trade cost against violations rather than ignore the band.
RESIDUAL_BETA = 1000.0

_NET = [64, 64]

PPO: dict[str, Any] = {
    "n_envs": 8,
    "n_steps": 256,
    "batch_size": 256,
    "n_epochs": 10,
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "learning_rate": 3e-4,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "policy_kwargs": {"net_arch": _NET, "log_std_init": -2.0},
}

SAC: dict[str, Any] = {
    "n_envs": 1,
    "learning_rate": 1e-3,
    "buffer_size": 200_000,
    "learning_starts": 1000,
    "batch_size": 256,
    "tau": 0.005,
    "gamma": 0.99,
    "train_freq": (1, "episode"),
    "gradient_steps": -1,
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

#: sb3-contrib's ``RecurrentPPO`` (``MlpLstmPolicy``) of the hidden comparison: PPO's entries,
#: with an LSTM of 64 units (actor and critic each; sb3-contrib's default 256 cost 4 times as
#: much per step) and minibatches of 1024 steps (1.8 CPU ms per step at 256, 0.9 at 1024).
RECURRENT_PPO: dict[str, Any] = {
    **PPO,
    "batch_size": 1024,
    "policy_kwargs": {**PPO["policy_kwargs"], "lstm_hidden_size": 64, "n_lstm_layers": 1},
}

HYPERPARAMS: dict[str, dict[str, Any]] = {
    "ppo": PPO,
    "sac": SAC,
    "td3": TD3,
    "recurrent_ppo": RECURRENT_PPO,
}

#: The algorithm whose entry of ``LAGRANGIAN["period"]`` an algorithm's dual ascent uses (the
#: recurrent PPO collects the rollouts of PPO: 8 x 256 steps).
DUAL_PERIOD_OF: dict[str, str] = {"recurrent_ppo": "ppo"}

#: Per-variant changes to :data:`HYPERPARAMS` (the entries here replace the algorithm's). SAC
#: beta10000: the learning rate falls linearly from 1e-3 to 0 (``"lin_1e-3"``, rl-zoo3's notation,
#: see :func:`learning_rate`); at a constant rate its policy kept swinging between evaluations.
HYPERPARAMS_VARIANT: dict[tuple[str, str], dict[str, Any]] = {
    ("sac", "beta10000"): {"learning_rate": "lin_1e-3"},
}


#: Prefix of a linearly decaying learning rate in the tables, rl-zoo3's notation: ``"lin_1e-3"``.
LINEAR_SCHEDULE_PREFIX = "lin_"


def learning_rate(value: float | str) -> float | Callable[[float], float]:
    """The ``learning_rate`` argument of stable-baselines3 for an entry of :data:`HYPERPARAMS`.

    A positive number is a constant rate. ``"lin_<r>"`` (:data:`LINEAR_SCHEDULE_PREFIX`) is a
    rate falling linearly from ``r`` at the start of training to 0 at its end: SB3 calls it with
    ``progress_remaining``, 1 at the start and 0 at the end (below 0 when the last episode ends
    past the budget; the rate stays 0 there). Kept as text in the tables so that a run's
    configuration (and its cache fingerprint) stays JSON.
    """
    linear = isinstance(value, str) and value.startswith(LINEAR_SCHEDULE_PREFIX)
    rate: Any = value
    if linear:
        try:
            rate = float(str(value)[len(LINEAR_SCHEDULE_PREFIX) :])  # value is a str here
        except ValueError:
            rate = None
    if (
        isinstance(rate, bool)
        or not isinstance(rate, (int, float))
        or not (math.isfinite(rate) and rate > 0)
    ):
        raise ValueError(
            f"learning_rate = {value!r}; expected a positive finite number or "
            f"'{LINEAR_SCHEDULE_PREFIX}<positive number>' (a linear decay to 0, e.g. 'lin_1e-3')"
        )
    if not linear:
        return float(rate)

    def schedule(progress_remaining: float) -> float:
        # clamped: an episode that ends past the budget makes the progress negative, and a
        # negative rate would be gradient ascent
        return max(progress_remaining, 0.0) * rate

    return schedule


def hyperparams(algo: str, variant: str) -> dict[str, Any]:
    """The hyperparameters of ``algo`` in ``variant``: :data:`HYPERPARAMS` with the changes of
    :data:`HYPERPARAMS_VARIANT` (a new dict; the module's are not modified)."""
    return {**HYPERPARAMS[algo], **HYPERPARAMS_VARIANT.get((algo, variant), {})}


#: Default training budget (env steps) per run and algorithm; :data:`TIMESTEPS_VARIANT` raises
#: it for some variants.
TIMESTEPS: dict[str, int] = {
    "ppo": 2_500_000,
    "sac": 60_000,
    "td3": 100_000,
    "recurrent_ppo": 300_000,
}

#: Larger budgets for the (algorithm, variant) pairs whose learning curves still moved at the
#: per-algorithm budget, by the report's flatness test (:func:`benchmarks.core.stats.curve_status`);
#: the others keep the budget of :data:`TIMESTEPS`.
TIMESTEPS_VARIANT: dict[tuple[str, str], int] = {
    ("ppo", "reward"): 8_000_000,
    ("ppo", "beta100"): 14_000_000,
    ("sac", "beta10000"): 600_000,
    ("sac", "residual"): 300_000,
    ("sac", "lagrangian"): 800_000,
    ("td3", "beta1000"): 600_000,
    ("td3", "beta10000"): 300_000,
    ("td3", "residual"): 1_200_000,
    ("td3", "lagrangian"): 600_000,
}


#: The suite comparison: per task, PPO on the reward alone, PPO residual over the
#: task's gains, and the Lagrangian PPO, SAC and TD3; :data:`SUITE_SEEDS` seeds each.
SUITE_CONFIGS: tuple[tuple[str, str], ...] = (
    ("ppo", "reward"),
    ("ppo", "residual"),
    ("ppo", "lagrangian"),
    ("sac", "lagrangian"),
    ("td3", "lagrangian"),
)
SUITE_SEEDS = 5

#: Budgets (env steps per run) of the suite comparison, the same on every task but where
#: :data:`SUITE_TIMESTEPS_TASK` changes one: the default command (6 tasks x 5 configurations x
#: 5 seeds) must fit in 12 CPU-hours of training. First set by that cap alone (TD3 at 50k);
#: then doubled where the flatness test found the curves not flat and the cap had room. Per-step
#: costs (median CPU ms over the committed runs, one torch thread, two to six trainings at once):
#: PPO about 0.23, SAC 6.2, TD3 3.2, varying 2x with the machine's load. The measured totals and
#: what the flatness test said: ``results/rl_suite/HISTORY.md``.
SUITE_TIMESTEPS: dict[tuple[str, str], int] = {
    ("ppo", "reward"): 600_000,
    ("ppo", "residual"): 600_000,
    ("ppo", "lagrangian"): 600_000,
    ("sac", "lagrangian"): 40_000,
    ("td3", "lagrangian"): 100_000,
}
#: Per-task changes to :data:`SUITE_TIMESTEPS`: ``{(task, algo, variant): steps}``; each a
#: doubling (PPO residual and Lagrangian on VTOL: two) where that task's curves were not flat.
SUITE_TIMESTEPS_TASK: dict[tuple[str, str, str], int] = {
    ("SDJLS-Macro-v0", "ppo", "residual"): 1_200_000,
    ("SDJLS-Macro-v0", "td3", "lagrangian"): 200_000,
    ("SDJLS-VTOL-v0", "ppo", "reward"): 1_200_000,
    ("SDJLS-VTOL-v0", "ppo", "residual"): 2_400_000,
    ("SDJLS-VTOL-v0", "ppo", "lagrangian"): 2_400_000,
    ("SDJLS-VTOL-v0", "sac", "lagrangian"): 80_000,
    ("SDJLS-VTOL-v0", "td3", "lagrangian"): 200_000,
    ("SDJLS-ThreeState-v0", "sac", "lagrangian"): 80_000,
}


def suite_timesteps(task: str, algo: str, variant: str) -> int:
    """Budget of one run of the suite comparison (:data:`SUITE_TIMESTEPS`, changed per task by
    :data:`SUITE_TIMESTEPS_TASK`); a configuration outside the suite's gets the budget of
    :func:`timesteps`."""
    default = SUITE_TIMESTEPS.get((algo, variant), timesteps(algo, variant))
    return SUITE_TIMESTEPS_TASK.get((task, algo, variant), default)


#: The hidden comparison: per task, with the mode hidden (``observe="state"``), PPO
#: on the state-only observation, sb3-contrib's recurrent PPO on it, and PPO with the mode
#: filter's belief appended (``"belief"``), each on the reward alone and Lagrangian:
#: ``(algo, variant, observation)``; :data:`HIDDEN_SEEDS` seeds each.
HIDDEN_CONFIGS: tuple[tuple[str, str, str], ...] = (
    ("ppo", "reward", "state"),
    ("ppo", "lagrangian", "state"),
    ("recurrent_ppo", "reward", "state"),
    ("recurrent_ppo", "lagrangian", "state"),
    ("ppo", "reward", "belief"),
    ("ppo", "lagrangian", "belief"),
)
HIDDEN_SEEDS = 5

#: Budgets (env steps per run) of the hidden comparison, by ``(algo, observation)``, the same on
#: every task and for both variants: the whole preset (6 tasks x 6 configurations x 5 seeds)
#: must fit in 8 CPU-hours of training. Per-step costs measured first (CPU ms per step of
#: 20k-step Lagrangian trainings, one torch thread, two at once on the 2-core machine shared at
#: load 3-7): PPO on the state-only observation 0.27 (VTOL), PPO with the belief 0.39 (VTOL;
#: the filter steps the 8 environments at once, :mod:`benchmarks.rl.belief_vec`; 0.77 with one
#: filter step per environment), the recurrent PPO 0.73 (macro) to 1.08 (VTOL). Both PPO kinds
#: get 300k steps, the recurrent PPO half of that (about twice the CPU of a PPO run): about
#: 60 x 300k x 0.27 + 60 x 300k x 0.39 + 60 x 150k x 0.95 ms = 5.5 CPU-hours. What was tried
#: and what it gave: ``results/hidden/HISTORY.md``.
HIDDEN_TIMESTEPS: dict[tuple[str, str], int] = {
    ("ppo", "state"): 300_000,
    ("ppo", "belief"): 300_000,
    ("recurrent_ppo", "state"): 150_000,
}


def hidden_timesteps(algo: str, observation: str) -> int:
    """Budget of one run of the hidden comparison (:data:`HIDDEN_TIMESTEPS`)."""
    return HIDDEN_TIMESTEPS[(algo, observation)]


#: Rough training speeds (env steps/s, one torch thread, two trainings in parallel on the
#: 2-core machine). Only the order of the trainings uses them: the longest start first, so that
#: the workers finish close together.
STEPS_PER_SECOND: dict[str, float] = {
    "ppo": 8000.0,
    "sac": 310.0,
    "td3": 600.0,
    "recurrent_ppo": 1100.0,
}


def timesteps(algo: str, variant: str) -> int:
    """Default training budget (env steps) of one run of ``algo`` in ``variant``."""
    return TIMESTEPS_VARIANT.get((algo, variant), TIMESTEPS[algo])


#: Budget of ``--quick``.
QUICK_TIMESTEPS = 2000

#: Learning curves: ``points`` evaluations per run of ``episodes`` episodes on a fixed seed.
LEARNING_CURVE: dict[str, int] = {"points": 10, "episodes": 100, "seed": 12345}
