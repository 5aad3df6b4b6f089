"""The scoring protocol: any policy scored on an SDJLS environment (public face: :mod:`benchmarks.evaluate`).

>>> from benchmarks.core.evaluate import evaluate
>>> from controllers import LinearFeedbackController
>>> from sdjls_gym.systems.macro import PAPER_K, macro
>>> score = evaluate(LinearFeedbackController(macro(), PAPER_K), episodes=50)
>>> score.violation > 0.9, score.diverged
(True, 0)

The protocol, the same for every controller of ``python -m benchmarks.compare_rl`` and for any
user's agent: ``episodes`` episodes of the *raw* environment (``gym.make(env_id, **env_kwargs)``,
actions in units of ``u``), simulated together on :class:`~sdjls_gym.SDJLSVectorEnv` from one
noise seed, so that two policies scored with the same seed see the same noise (common random
numbers). An episode whose state exceeds the divergence bound ends there; its cost is the cost
up to then and its remaining steps count as violated. :class:`Score` holds the mean episode cost
with a 95% Student-t interval and the median; the per-step violation frequency (any row of
``G x <= H_k``) with its 95% Wilson interval and a Student-t interval over the episodes' shares
of violated steps; the diverged episodes; the largest ``|u|``; the decision time per state; and,
on a task of the suite (:data:`sdjls_gym.systems.TASKS`), the paired gap to the task's reference
curve, its one-step receding-horizon controller over a sweep of ``xi`` scored on the same episodes
(:mod:`benchmarks.core.reference`; on the paper's system, the paper's controller with individual
constraints at ``xi`` in :data:`REFERENCE_XIS`).

A policy is one of

* an object with the controllers' ``act_batch(x, mode, k)`` (the project's controllers,
  :class:`RawEnvPolicy`): called with the exact states, once per step for the whole batch;
* an object with stable-baselines3's ``predict(obs, deterministic=True)`` (an SB3 model trained
  on the raw environment, a user's object), or a plain callable ``obs -> action``: called with
  the environment's observations. A policy that accepts a batch of observations (B, n + N + 1)
  and returns (B, m) actions is called once per step; this is checked on the first step against
  row-by-row calls, and a policy that fails the check is called row by row.

An agent trained behind wrappers that rescale its actions or observations
(``gymnasium.wrappers.RescaleAction``, :class:`~sdjls_gym.wrappers.ScaleObservationReward`,
:class:`~sdjls_gym.wrappers.ResidualAction`, SB3's ``VecNormalize``) acts in other units: wrap it
with ``RawEnvPolicy(agent, train_env)``, which reads the wrappers of its training environment.
An agent whose ``observation_space`` / ``action_space`` are not the scored environment's is
refused (:func:`benchmarks.core.policies.check_spaces`). A ``predict`` with SB3's ``state`` and
``episode_start`` parameters (recurrent policies) gets its state back at each step, as SB3's
``evaluate_policy`` does. A policy's actions are read by ``env.step``'s rule
(:func:`sdjls_gym.validation.check_numbers`). A diverged episode's state never reaches the policy.
The command line is :mod:`benchmarks.evaluate`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from benchmarks.core.environment import (
    TaskEnv,
    check_fits,
    check_hidden,
    infer_env,
    is_hidden_policy,
    resolve_env,
    rollout_statistics,
)
from benchmarks.core.frontier import as_seeds, bounded_gap, gap_reason, reference_curve
from benchmarks.core.montecarlo import Rollouts, rollout, rollouts
from benchmarks.core.policies import RawEnvPolicy, as_controller, check_policy, unwrap_vec_env
from benchmarks.core.reference import REFERENCE_CONSTRAINT, REFERENCE_XIS, curve_xis
from benchmarks.core.score_table import TABLE_HEADER, table_row
from benchmarks.core.stats import CurveGap
from sdjls_gym.messages import a_type, describe
from sdjls_gym.systems import TASKS
from sdjls_gym.validation import check_int, check_mapping

__all__ = [
    "REFERENCE_CONSTRAINT",
    "REFERENCE_XIS",
    "RawEnvPolicy",
    "Score",
    "check_evaluation",
    "check_seed",
    "evaluate",
    "evaluate_rollouts",
    "score_policy",
    "score_policy_rollouts",
]

#: Visited states drawn from the rollouts to time the decisions on.
TIMING_STATES = 1000
#: Most episodes one evaluation simulates: they run together, and their rollouts are held in
#: memory (about 1 GB for 10**6 episodes of the paper's system).
MAX_EPISODES = 1_000_000


@dataclass(frozen=True)
class Score:
    """The evaluation of one policy (see the module docstring for the protocol).

    Attributes
    ----------
    env_id : str
    episodes, steps : int
        Episodes (all noise seeds together) of ``steps`` steps.
    seed : int or tuple of int
        The noise seed, or the seeds whose episodes are pooled.
    cost_mean, cost_ci95, cost_median
        Episode cost ``sum_k x_k'Q x_k + u_k'R u_k``: mean, 95% Student-t interval over the
        episodes (cut at 0), median.
    violation, violation_wilson95
        Share of the ``episodes x steps`` steps whose next state violates a row of the band,
        with its 95% Wilson interval (which treats the steps as independent).
    violation_episode_t95
        95% Student-t interval over the episodes' shares of violated steps (cut to [0, 1]),
        which allows for dependence between the steps of an episode.
    diverged : int
        Episodes whose state exceeded the divergence bound.
    max_abs_u : float
        Largest ``|u|`` applied.
    decision_time_batched_s, decision_time_single_s : float
        Seconds per state: a batch of visited states at once, and one state at a time.
    curve_gap : CurveGap or None
        Mean cost minus the task's reference curve's at this violation frequency, paired over
        the episodes, with a 95% bootstrap interval, also in percent of the curve's cost
        (:func:`benchmarks.core.stats.paired_curve_gap`; the curve refined at this frequency,
        :mod:`benchmarks.core.frontier`); None where the frequency is outside the curve's
        range, an episode diverged, or the system is not a task of the suite.
    bounded_gap : float or None
        The score every run has (:func:`benchmarks.core.frontier.bounded_gap`): the gap in
        percent clipped to ``[-100, 100]``, ``+100`` for a run with a diverged episode or riskier
        than the curve, the gap to the curve's strictest level for a run safer than it; None
        only on a system that is no task of the suite (no curve).
    bounded_gap_rule : str or None
        Which of those rules gave :attr:`bounded_gap` (``"gap"``, ``"diverged"``, ``"riskier
        than the curve"``, ``"safer than the curve"``).
    episode_costs, episode_violations : (episodes,) arrays
        Each episode's cost and share of violated steps (for paired comparisons).
    curve_gap_reason : str or None
        Why ``curve_gap`` is None (diverged episodes, a violation frequency above or below the
        curve's range and that range, a system that is not a task of the suite); None when
        there is a gap.
    curve_points : tuple of dict
        The reference curve's points on the same episodes, one dict per level ``xi`` (``xi``,
        ``cost_mean``, ``cost_ci95``, ``cost_median``, ``violation``, ``violation_wilson95``,
        ``diverged``), to plot a policy against; empty when no curve was computed (a diverged
        episode, or not a task of the suite). Neither this nor the reason is in
        :meth:`to_dict`, whose schema the committed summaries share.
    """

    env_id: str
    episodes: int
    steps: int
    seed: int | tuple[int, ...]
    cost_mean: float
    cost_ci95: tuple[float, float]
    cost_median: float
    violation: float
    violation_wilson95: tuple[float, float]
    violation_episode_t95: tuple[float, float]
    diverged: int
    max_abs_u: float
    decision_time_batched_s: float
    decision_time_single_s: float
    curve_gap: CurveGap | None
    bounded_gap: float | None
    bounded_gap_rule: str | None
    episode_costs: np.ndarray = field(repr=False, compare=False)
    episode_violations: np.ndarray = field(repr=False, compare=False)
    curve_gap_reason: str | None = field(default=None, compare=False)
    curve_points: tuple[dict[str, Any], ...] = field(default=(), repr=False, compare=False)

    def to_dict(self, per_episode: bool = False) -> dict[str, Any]:
        """Plain JSON types; the per-episode arrays only with ``per_episode``."""
        out = asdict(self)
        out.pop("curve_gap_reason"), out.pop("curve_points")
        costs, viols = out.pop("episode_costs"), out.pop("episode_violations")
        if per_episode:
            out["episode_costs"] = np.asarray(costs).tolist()
            out["episode_violations"] = np.asarray(viols).tolist()
        return json.loads(json.dumps(out))  # tuples become lists


# ----------------------------------------------------------------------------- the protocol
def decision_states(
    ro: Rollouts, size: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``size`` visited states ``(x (B, n), mode (B,), k (B,))``, k < T, drawn from ``ro``;
    none from after a diverged episode ended."""
    runs, T = ro.ended.shape
    rng = np.random.default_rng(seed)
    lived = np.flatnonzero(~ro.ended.ravel())
    i, k = np.divmod(lived[rng.integers(0, lived.size, size)], T)
    return ro.x[i, k], ro.mode[i, k].astype(np.int64), k.astype(np.int64)


def decision_time(
    controller: Any, x: np.ndarray, mode: np.ndarray, k: np.ndarray, single: int = 50,
    repeats: int = 3,
) -> tuple[float, float]:  # fmt: skip
    """Seconds per state: the best of ``repeats`` calls of ``act_batch`` on all of ``x`` (B, n)
    divided by B, and the mean of ``single`` calls of ``act`` on one state."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        controller.act_batch(x, mode, k)
        best = min(best, time.perf_counter() - t0)
    idx = np.linspace(0, len(x) - 1, min(single, len(x))).astype(int)
    t0 = time.perf_counter()
    for i in idx:
        controller.act(x[i], int(mode[i]), int(k[i]))
    return float(best / len(x)), float((time.perf_counter() - t0) / len(idx))


def hidden_decision_time(
    policy: Any, spec: TaskEnv, episodes: int, seed: int
) -> tuple[float, float]:
    """Seconds per state of a hidden-mode policy (``act_hidden``), in closed loop: a rollout of
    ``episodes`` episodes at once over its states, and one episode alone over its steps."""
    t0 = time.perf_counter()
    rollout(spec.model, policy, episodes, spec.horizon, seed, spec.action_bound, None,
            spec.divergence_bound)  # fmt: skip
    batched = (time.perf_counter() - t0) / (episodes * spec.horizon)
    t0 = time.perf_counter()
    rollout(spec.model, policy, 1, spec.horizon, seed, spec.action_bound, None,
            spec.divergence_bound)  # fmt: skip
    return float(batched), float((time.perf_counter() - t0) / spec.horizon)


def evaluate_rollouts(
    controller: Any,
    spec: TaskEnv,
    episodes: int,
    seed: int | tuple[int, ...],
    env_id: str = "SDJLS-Macro-v0",
) -> tuple[Score, Rollouts]:
    """The protocol on a controller with ``act_batch`` (or ``act_hidden``): its :class:`Score`
    and its rollouts (``episodes`` from each noise seed of ``seed``, pooled), scored against
    ``spec.task``'s reference curve on the same episodes."""
    seeds = as_seeds(seed)
    ro = rollouts(spec.model, controller, episodes, spec.horizon, seeds, spec.action_bound, None,
                  spec.divergence_bound)  # fmt: skip
    stats = rollout_statistics(ro, spec.divergence_bound)
    if is_hidden_policy(controller):  # its decisions need its episodes' memory: timed in a run
        batched, single = hidden_decision_time(controller, spec, min(episodes, 50), seeds[0])
    else:
        states = decision_states(ro, min(TIMING_STATES, ro.runs * spec.horizon))
        batched, single = decision_time(controller, *states)
    gap = bounded = rule = None
    points: tuple[dict[str, Any], ...] = ()
    if spec.task is None:
        reason: str | None = f"{env_id} is not a task of the suite: it has no reference curve"
    else:
        curve = reference_curve(
            spec.task, episodes, seeds, horizon=spec.horizon, action_bound=spec.action_bound,
            divergence_bound=spec.divergence_bound,
        )  # fmt: skip
        costs, viols = stats["episode_costs"], stats["episode_violations"]
        score = bounded_gap(curve, costs, viols, stats["diverged"])
        gap, bounded, rule = score.gap, score.value, score.rule
        if rule != "gap":
            gap = None
        reason = gap_reason(stats["violation"], stats["diverged"], gap, curve.violations,
                            curve.costs)  # fmt: skip
        if not stats["diverged"]:  # a diverged run is not drawn against the curve
            shown = curve.refine(stats["violation"])
            points = tuple(shown.point(i) for i in range(len(shown.xis)))
    score_ = Score(
        curve_gap_reason=reason,
        curve_points=points,
        env_id=env_id,
        seed=seed if isinstance(seed, int) else seeds,
        decision_time_batched_s=batched,
        decision_time_single_s=single,
        curve_gap=gap,
        bounded_gap=bounded,
        bounded_gap_rule=rule,
        **stats,
    )
    return score_, ro


def check_seed(seed: Any) -> int | tuple[int, ...]:
    """``seed`` as :func:`evaluate` takes it: an int ``>= 0``, or a non-empty sequence of
    distinct ones (their episodes pooled), returned as a tuple."""
    if isinstance(seed, (str, bytes)) or not isinstance(seed, Sequence):
        return check_int("seed", seed, low=0)
    seeds = tuple(check_int(f"seed[{i}]", s, low=0) for i, s in enumerate(seed))
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"seed = {describe(seed)}; expected a non-empty sequence of distinct "
                         "noise seeds (or one int)")  # fmt: skip
    return seeds


def check_evaluation(episodes: Any, seed: Any) -> tuple[int, Any]:
    """``(episodes, seed)`` as :func:`evaluate` accepts them: ``2 <= episodes``, at most
    :data:`MAX_EPISODES` over all seeds, ``seed`` an int ``>= 0`` or a sequence of distinct
    ones (:func:`check_seed`); the checks every script runs before its work."""
    seed = check_seed(seed)
    count = 1 if isinstance(seed, int) else len(seed)
    episodes = check_int(
        "episodes", episodes, low=2, high=MAX_EPISODES // count,
        what="the intervals are over episodes; the rollouts of all of them (every seed's) are "
        "held in memory",
    )  # fmt: skip
    return episodes, seed


def evaluate(
    policy: Any,
    *,
    episodes: int = 1000,
    seed: int | Sequence[int] = 0,
    env_id: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    env: Any = None,
) -> Score:
    """Score ``policy`` on ``episodes`` episodes of the raw ``env_id`` from each noise seed of
    ``seed``.

    Parameters
    ----------
    policy : object
        A controller with ``act_batch(x, mode, k)``, an object with ``predict(obs,
        deterministic=True)``, or a callable ``obs -> action`` (see the module docstring). An
        agent trained behind rescaling wrappers goes in as ``RawEnvPolicy(agent, train_env)``,
        or with ``env=train_env``.
    episodes : int
        At least 2 (the intervals are over episodes), at most :data:`MAX_EPISODES`.
    seed : int or sequence of int
        Noise seed, >= 0, or several (their episodes pooled: ``episodes`` from each); the same
        seeds give every policy the same noise.
    env_id : str, optional
        A registered SDJLS environment. Default: the policy's own task
        (:func:`benchmarks.core.environment.infer_env`): a ``RawEnvPolicy``'s training environment, a
        controller's model's task (``SDJLS-v0`` with that model when it is not a registered
        task's), else ``SDJLS-Macro-v0``.
    env_kwargs : dict, optional
        Keyword arguments of ``gym.make(env_id, ...)``.
    env : gymnasium.Env or stable-baselines3 VecEnv, optional
        Instead of ``env_id``: the environment the policy acts on, as stable-baselines3's
        ``evaluate_policy(model, env)`` takes it. The policy is scored on its raw environment
        (the same id and keyword arguments); an agent (with ``predict``) acting on a wrapped
        ``env`` is wrapped as ``RawEnvPolicy(policy, env)``, which undoes the wrappers.

    Returns
    -------
    Score

    Raises
    ------
    TypeError, ValueError
        A bad argument (a class instead of an agent, an agent whose spaces are not the raw
        environment's, an unknown ``env_id``), before any episode is run.
    sdjls_gym.errors.NotANumberError
        The policy returned what ``env.step`` refuses (``"1.0"``, ``True``, None).
    """
    episodes, seeds = check_evaluation(episodes, seed)
    if env_id is not None and not isinstance(env_id, str):
        raise TypeError(f"env_id = {describe(env_id)} is {a_type(env_id)}; expected a str")
    env_kwargs = check_mapping("env_kwargs", env_kwargs)
    check_policy(policy)
    if env is not None:
        env, _ = unwrap_vec_env(env)
        if not callable(getattr(policy, "act_batch", None)) and env is not env.unwrapped:
            policy = RawEnvPolicy(policy, env)  # an agent on its (wrapped) training env
    env_id, env_kwargs, how = infer_env(policy, env_id, env_kwargs, env)
    return score_policy(policy, resolve_env(env_id, env_kwargs), episodes, seeds, how)


def score_policy(policy: Any, spec: TaskEnv, episodes: int, seed: int | tuple[int, ...],
                 how: str = "env_id") -> Score:  # fmt: skip
    """The protocol on ``policy`` in the environment ``spec`` (checked arguments): the policy
    checked against the environment (its sizes, the hidden mode, its spaces), then scored by
    :func:`evaluate_rollouts`. ``how`` says how the environment was chosen, for the errors.
    :func:`evaluate` and :func:`benchmarks.core.suite.evaluate_suite` both score through it."""
    return score_policy_rollouts(policy, spec, episodes, seed, how)[0]


def score_policy_rollouts(policy: Any, spec: TaskEnv, episodes: int,
                          seed: int | tuple[int, ...], how: str = "env_id",
                          ) -> tuple[Score, Rollouts]:  # fmt: skip
    """:func:`score_policy` and the rollouts it scored (for a caller that measures more on the
    same episodes, such as the hidden wing's filter accuracy)."""
    check_fits(policy, spec, how)
    check_hidden(policy, spec)
    try:
        controller = as_controller(policy, spec)
    except ValueError as exc:
        if how == "env_id":
            raise
        raise ValueError(f"{exc} (scored on env_id = {spec.env_id!r}: {how}; pass env_id or env= "
                         "of the policy's task)") from None  # fmt: skip
    return evaluate_rollouts(controller, spec, episodes, seed, spec.env_id)


# ----------------------------------------------------------------------------- report lines
def describe_score(name: str, score: Score) -> list[str]:
    """The table row of ``score`` (the RL comparison's columns) and where it sits on the curve."""
    from types import SimpleNamespace

    lines = [*TABLE_HEADER, table_row(SimpleNamespace(name=name, score=score))]
    g = score.curve_gap
    if g is None:
        lines.append("Against the RHC curve: no paired gap (an episode diverged, the violation "
                     "frequency is outside the curve's range, or the system is not a task of "
                     "the suite).")  # fmt: skip
    else:
        xis = curve_xis(TASKS[score.env_id]) if score.env_id in TASKS else REFERENCE_XIS
        lines.append(
            f"Against the RHC curve ({REFERENCE_CONSTRAINT} constraints, xi in {xis[0]:g}.."
            f"{xis[-1]:g}): at violation frequency {g.violation:.3f} the curve, at xi = "
            f"{g.xi:.3f}, costs {g.curve_cost:.4g}; cost minus curve {g.mean:+.1f} (95% bootstrap "
            f"interval {g.ci95[0]:+.1f} to {g.ci95[1]:+.1f})."
        )
    return lines
