"""Score any policy on an SDJLS environment with the benchmarks' evaluation protocol.

>>> from benchmarks.evaluate import evaluate
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
on the paper's system, the paired gap to the curve of the paper's receding-horizon controller
(individual constraints, ``xi`` in :data:`REFERENCE_XIS`) scored on the same episodes.

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
:class:`~sdjls_gym.wrappers.ResidualAction`) acts in other units: wrap it with
``RawEnvPolicy(agent, train_env)``, which reads the wrappers of its training environment.

Command line: ``python -m benchmarks.evaluate --policy PATH.zip --algo ppo`` (an SB3 model;
``--train-env package.module:attribute`` names its training environment) or
``--policy package.module:attribute``; ``--json PATH`` writes the score.
"""

from __future__ import annotations

import functools
import json
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from benchmarks.montecarlo import Rollouts, paper_rhc, rollout
from benchmarks.stats import CurveGap, mean_ci, paired_curve_gap, wilson
from sdjls_gym import SDJLSModel
from sdjls_gym._validate import check_int, check_mapping, describe, type_name
from sdjls_gym.env import SDJLSEnv, decode_observation, encode_observation
from sdjls_gym.wrappers import ResidualAction, ScaleObservationReward, scale_observation

__all__ = [
    "REFERENCE_CONSTRAINT",
    "REFERENCE_XIS",
    "RawEnvPolicy",
    "Score",
    "evaluate",
    "evaluate_rollouts",
]

#: The reference curve: the paper's receding-horizon controller with these constraints at these
#: levels ``xi`` (section 6's gains, Psi, alpha and |nu| <= 100).
REFERENCE_XIS: tuple[float, ...] = (0.3, 0.5, 0.7, 0.8, 0.85, 0.9, 0.95, 0.99)
REFERENCE_CONSTRAINT = "individual"
#: Visited states drawn from the rollouts to time the decisions on.
TIMING_STATES = 1000


@dataclass(frozen=True)
class Score:
    """The evaluation of one policy (see the module docstring for the protocol).

    Attributes
    ----------
    env_id : str
    episodes, steps, seed : int
        Episodes of ``steps`` steps, noise seed.
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
        Mean cost minus the reference curve's at this violation frequency, paired over the
        episodes, with a 95% bootstrap interval (:func:`benchmarks.stats.paired_curve_gap`);
        None where the frequency is outside the curve's range, an episode diverged, or the
        system is not the paper's.
    episode_costs, episode_violations : (episodes,) arrays
        Each episode's cost and share of violated steps (for paired comparisons).
    """

    env_id: str
    episodes: int
    steps: int
    seed: int
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
    episode_costs: np.ndarray = field(repr=False, compare=False)
    episode_violations: np.ndarray = field(repr=False, compare=False)

    def to_dict(self, per_episode: bool = False) -> dict[str, Any]:
        """Plain JSON types; the per-episode arrays only with ``per_episode``."""
        out = asdict(self)
        costs, viols = out.pop("episode_costs"), out.pop("episode_violations")
        if per_episode:
            out["episode_costs"] = np.asarray(costs).tolist()
            out["episode_violations"] = np.asarray(viols).tolist()
        return json.loads(json.dumps(out))  # tuples become lists


# ----------------------------------------------------------------------------- environments
@dataclass(frozen=True)
class EnvSpec:
    """What the rollouts need to know of ``gym.make(env_id, **env_kwargs)``."""

    model: SDJLSModel
    horizon: int
    action_bound: float
    divergence_bound: float
    paper_system: bool  # the macro example: the reference curve applies


def _key(model: SDJLSModel) -> str:
    return json.dumps(model.to_dict(), sort_keys=True)


def resolve_env(env_id: str, env_kwargs: dict[str, Any]) -> EnvSpec:
    """Make the environment once and read its model, horizon and bounds."""
    from sdjls_gym.systems.macro import macro

    env = gym.make(env_id, **env_kwargs)
    try:
        base = env.unwrapped
        if not isinstance(base, SDJLSEnv):
            raise ValueError(
                f"env_id = {env_id!r} makes a {type(base).__name__}; expected an SDJLS "
                "environment (an SDJLSEnv underneath)"
            )
        limit = env.spec.max_episode_steps if env.spec is not None else None
        if limit is not None and limit != base.horizon:
            raise ValueError(
                f"env_kwargs give horizon = {base.horizon} but episodes end after "
                f"max_episode_steps = {limit} steps; pass max_episode_steps={base.horizon} too"
            )
        bound = np.asarray(base.action_space.high, dtype=np.float64)
        return EnvSpec(
            model=base.model,
            horizon=int(base.horizon),
            action_bound=float(bound[0]) if np.all(bound == bound[0]) else bound,
            divergence_bound=float(base.divergence_bound),
            paper_system=_key(base.model) == _key(macro()),
        )
    finally:
        env.close()


# ----------------------------------------------------------------------------- policies
class _ObservationPolicy:
    """A ``predict`` or callable policy behind the controllers' ``act_batch`` / ``act``."""

    def __init__(self, policy: Any, spec: EnvSpec) -> None:
        if callable(getattr(policy, "predict", None)):
            self.call = lambda obs: policy.predict(obs, deterministic=True)[0]
        elif callable(policy):
            self.call = policy
        else:  # checked by as_controller first
            raise TypeError(f"policy is a {type_name(policy)}")
        self.spec, self.m = spec, spec.model.m
        self.batched: bool | None = None  # decided at the first batch

    def _one(self, obs: np.ndarray) -> np.ndarray:
        a = np.asarray(self.call(obs), dtype=np.float64)
        if a.size != self.m:
            raise ValueError(
                f"the policy returned {describe(a)} (shape {a.shape}) for one observation; "
                f"expected {self.m} number(s)"
            )
        return a.reshape(self.m)

    def _rows(self, obs: np.ndarray) -> np.ndarray:
        return np.stack([self._one(o) for o in obs])

    def _batch(self, obs: np.ndarray) -> np.ndarray:
        B = len(obs)
        if self.batched is False:
            return self._rows(obs)
        if self.batched:
            return np.asarray(self.call(obs), dtype=np.float64).reshape(B, self.m)
        # the first batch: one call on all rows, checked against single calls on a few rows
        try:
            a = np.asarray(self.call(obs), dtype=np.float64)
            a = a.reshape(B, self.m) if a.shape in ((B, self.m), (B,) * (self.m == 1)) else None
        except Exception:  # noqa: BLE001 - a policy for one observation may fail on many
            a = None
        try:
            rows, error = self._rows(obs[:8]), None
        except Exception as exc:  # noqa: BLE001 - a policy for batches may fail on one row
            rows, error = None, exc
        if a is not None and rows is not None:
            scale = max(1.0, float(np.max(np.abs(rows))))
            self.batched = bool(np.allclose(a[:8], rows, rtol=1e-5, atol=1e-6 * scale))
        else:
            self.batched = a is not None
        if self.batched:
            return a
        if error is not None:
            raise error
        return np.concatenate([rows, self._rows(obs[8:])]) if B > 8 else rows

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        s = self.spec
        obs = encode_observation(s.model, x, mode, k, s.horizon, s.divergence_bound)
        u = self._batch(obs)
        if not np.all(np.isfinite(u)):
            row = int(np.argwhere(~np.isfinite(u))[0, 0])
            raise ValueError(
                f"the policy returned a non-finite action {describe(u[row])} for the observation "
                f"{describe(obs[row])}; expected finite numbers"
            )
        B = len(x)
        cost = s.model.stage_cost(x, mode, np.clip(u, -s.action_bound, s.action_bound))
        return u, {"rho": np.zeros(B), "cost": cost, "ok": np.ones(B, dtype=bool)}

    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        u, info = self.act_batch(np.asarray(x)[None], np.array([mode]), np.array([k]))
        return u[0], {key: value[0] for key, value in info.items()}


def _check_policy(policy: Any) -> None:
    if not (
        callable(getattr(policy, "act_batch", None))
        or callable(getattr(policy, "predict", None))
        or callable(policy)
    ):
        raise TypeError(
            f"policy = {describe(policy)} is a {type_name(policy)}; expected an object with "
            "predict(obs, deterministic=True) (stable-baselines3's), a callable obs -> action, "
            "or a controller with act_batch(x, mode, k) and act(x, mode, k)"
        )


def as_controller(policy: Any, spec: EnvSpec) -> Any:
    """``policy`` behind ``act_batch(x, mode, k)`` / ``act(x, mode, k)`` (see the module doc)."""
    _check_policy(policy)
    if callable(getattr(policy, "act_batch", None)) and callable(getattr(policy, "act", None)):
        return policy
    return _ObservationPolicy(policy, spec)


class RawEnvPolicy:
    """An agent trained behind wrappers, acting on the raw environment (actions in units of u).

    Reads the wrappers of ``env``, the agent's training environment, and undoes them:
    :class:`~sdjls_gym.wrappers.ScaleObservationReward` (the agent sees the scaled state),
    ``gymnasium.wrappers.RescaleAction`` (the agent's action, clipped to its action space, is
    mapped back to the wrapped box) and :class:`~sdjls_gym.wrappers.ResidualAction`
    (``u = K_theta x + nu``). Wrappers that change only the reward or the episode's end
    (``ViolationPenalty``, ``TerminateOutside``, ``FiniteHorizon``, ``TimeLimit``, SB3's
    ``Monitor``) are skipped; any other wrapper that changes the observation or action space is
    an error.

    Parameters
    ----------
    agent : object
        With ``predict(obs, deterministic=True)``: an SB3 model or policy.
    env : gymnasium.Env
        The training environment (wrapped), or one built the same way.

    Examples
    --------
    >>> import gymnasium as gym
    >>> from gymnasium.wrappers import RescaleAction
    >>> from sdjls_gym.wrappers import ScaleObservationReward
    >>> env = ScaleObservationReward(RescaleAction(gym.make("SDJLS-Macro-v0"), -1.0, 1.0))
    >>> class Half:  # always a = 0.5 in [-1, 1]
    ...     def predict(self, obs, deterministic=True):
    ...         return np.full((len(obs), 1), 0.5, dtype=np.float32), None
    >>> u, _ = RawEnvPolicy(Half(), env).act(np.array([2.0, 2.0]), 0, 0)
    >>> float(u[0])  # 0.5 of the raw bound 200
    100.0
    """

    def __init__(self, agent: Any, env: gym.Env) -> None:
        if not callable(getattr(agent, "predict", None)):
            raise TypeError(
                f"agent = {describe(agent)} is a {type_name(agent)}; expected an object with "
                "predict(obs, deterministic=True), such as a stable-baselines3 model"
            )
        if not isinstance(env, gym.Env):
            raise TypeError(
                f"env = {describe(env)} is a {type_name(env)}; expected the agent's training "
                "environment, a gymnasium.Env (for an SB3 VecEnv pass venv.envs[0])"
            )
        base = env.unwrapped
        if not isinstance(base, SDJLSEnv):
            raise TypeError(f"env has a {type(base).__name__} underneath; expected an SDJLSEnv")
        self.agent, self.model = agent, base.model
        self.horizon, self.divergence_bound = int(base.horizon), float(base.divergence_bound)
        self.action_bound = float(np.max(base.action_space.high))
        box = env.action_space
        self.low, self.high = box.low.astype(np.float64), box.high.astype(np.float64)
        self.scaling: tuple[float, float] | None = None
        self.actions: list[tuple[str, Any]] = []  # outermost first: how an action reaches u
        e = env
        while isinstance(e, gym.Wrapper):
            inner = e.env
            if isinstance(e, ScaleObservationReward):
                self.scaling = (e.x_scale, e.obs_clip)
            elif isinstance(e, gym.wrappers.RescaleAction):
                lo, hi = e.action_space.low, e.action_space.high
                in_lo, in_hi = inner.action_space.low, inner.action_space.high
                bounds = tuple(np.asarray(v, dtype=np.float64) for v in (lo, hi, in_lo, in_hi))
                self.actions.append(("rescale", bounds))
            elif isinstance(e, ResidualAction):
                self.actions.append(("residual", e.K))
            elif isinstance(e, gym.wrappers.ClipAction):
                pass  # the action is clipped to the agent's space anyway
            elif (
                isinstance(e, (gym.ObservationWrapper, gym.ActionWrapper))
                or e.observation_space != inner.observation_space
                or e.action_space != inner.action_space
            ):
                raise ValueError(
                    f"env has a {type(e).__name__} wrapper, which changes the observation or the "
                    "action in a way RawEnvPolicy cannot undo; it knows ScaleObservationReward, "
                    "RescaleAction, ResidualAction and wrappers of the reward"
                )
            e = inner

    def observe(self, x: np.ndarray, mode: np.ndarray, k: np.ndarray) -> np.ndarray:
        """The observations (B, n + N + 1) the agent was trained on, for states (B, n)."""
        obs = encode_observation(self.model, x, mode, k, self.horizon, self.divergence_bound)
        return obs if self.scaling is None else scale_observation(obs, self.model.n, *self.scaling)

    def act_batch(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """``u`` (B, m) for states ``x`` (B, n), modes (B,), times (B,); info as a controller's."""
        x = np.asarray(x, dtype=np.float64)
        mode = np.asarray(mode, dtype=np.int64)
        a, _ = self.agent.predict(self.observe(x, mode, k), deterministic=True)
        v = np.clip(np.asarray(a, dtype=np.float64).reshape(len(x), -1), self.low, self.high)
        nu = np.zeros_like(v)
        for kind, data in self.actions:
            if kind == "rescale":
                lo, hi, in_lo, in_hi = data
                if np.all(lo == -hi) and np.all(in_lo == -in_hi):  # symmetric: a * bound
                    v = v * (in_hi / hi)
                else:
                    v = in_lo + (in_hi - in_lo) * (v - lo) / (hi - lo)
            else:  # residual: u = K_theta x + nu
                nu = v
                v = np.einsum("bij,bj->bi", data[mode], x) + nu
        B = len(x)
        cost = self.model.stage_cost(x, mode, np.clip(v, -self.action_bound, self.action_bound))
        info = {"nu": nu, "rho": np.zeros(B), "cost": cost, "ok": np.ones(B, dtype=bool)}
        return v, info

    def act(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, dict[str, Any]]:
        """One decision: ``act_batch`` on a batch of one."""
        u, info = self.act_batch(np.asarray(x)[None], np.array([mode]), np.array([k]))
        return u[0], {key: value[0] for key, value in info.items()}

    def predict(
        self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:  # fmt: skip
        """stable-baselines3's ``predict`` on raw observations (the state at float32 precision)."""
        single = np.ndim(observation) == 1
        x, mode, k = decode_observation(self.model, np.atleast_2d(observation), self.horizon)
        u = self.act_batch(x, mode, k)[0].astype(np.float32)
        return (u[0] if single else u), state


# ----------------------------------------------------------------------------- the protocol
def statistics(ro: Rollouts, divergence_bound: float) -> dict[str, Any]:
    """Cost, violation and divergence statistics of rollouts (the fields of :class:`Score`)."""
    costs = ro.episode_cost
    violations = ro.any_violation
    total, count = violations.size, int(violations.sum())
    lo, hi = wilson(count, total)
    shares = violations.mean(axis=1)
    _, elo, ehi = mean_ci(shares)  # the episodes are independent; their steps need not be
    mean, clo, chi = mean_ci(costs, floor=0.0)  # a cost is >= 0
    return {
        "episodes": int(ro.runs),
        "steps": int(violations.shape[1]),
        "cost_mean": float(mean),
        "cost_ci95": (float(clo), float(chi)),
        "cost_median": float(np.median(costs)),
        "violation": count / total,
        "violation_wilson95": (float(lo), float(hi)),
        "violation_episode_t95": (max(float(elo), 0.0), min(float(ehi), 1.0)),
        "diverged": int(np.any(np.abs(ro.x) > divergence_bound, axis=(1, 2)).sum()),
        "max_abs_u": float(np.max(np.abs(ro.u))),
        "episode_costs": costs,
        "episode_violations": shares,
    }


def decision_states(ro: Rollouts, size: int, seed: int = 0) -> tuple[np.ndarray, ...]:
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


@functools.lru_cache(maxsize=8)
def reference_curve(
    episodes: int, seed: int, horizon: int, action_bound: float, divergence_bound: float
) -> tuple[tuple[float, ...], np.ndarray, np.ndarray]:
    """``(xis, costs (P, E), violations (P, E))`` of the reference curve on the paper's system."""
    from sdjls_gym.systems.macro import macro

    model = macro()
    costs, viols = [], []
    for xi in REFERENCE_XIS:
        ctrl = paper_rhc(model, xi, REFERENCE_CONSTRAINT, horizon=horizon)
        ro = rollout(model, ctrl, episodes, horizon, seed, action_bound, None, divergence_bound)
        costs.append(ro.episode_cost)
        viols.append(ro.any_violation.mean(axis=1))
    return REFERENCE_XIS, np.stack(costs), np.stack(viols)


def evaluate_rollouts(
    controller: Any, spec: EnvSpec, episodes: int, seed: int, env_id: str = "SDJLS-Macro-v0"
) -> tuple[Score, Rollouts]:
    """The protocol on a controller with ``act_batch``: its :class:`Score` and its rollouts."""
    ro = rollout(
        spec.model, controller, episodes, spec.horizon, seed, spec.action_bound, None,
        spec.divergence_bound,
    )  # fmt: skip
    stats = statistics(ro, spec.divergence_bound)
    states = decision_states(ro, min(TIMING_STATES, ro.runs * spec.horizon))
    batched, single = decision_time(controller, *states)
    gap = None
    if spec.paper_system and stats["diverged"] == 0:
        xis, c_costs, c_viols = reference_curve(
            episodes, seed, spec.horizon, float(np.max(spec.action_bound)), spec.divergence_bound
        )
        gap = paired_curve_gap(
            stats["episode_costs"], stats["episode_violations"], c_costs, c_viols, xis
        )
    score = Score(
        env_id=env_id,
        seed=seed,
        decision_time_batched_s=batched,
        decision_time_single_s=single,
        curve_gap=gap,
        **stats,
    )
    return score, ro


def evaluate(
    policy: Any,
    *,
    episodes: int = 1000,
    seed: int = 0,
    env_id: str = "SDJLS-Macro-v0",
    env_kwargs: dict[str, Any] | None = None,
) -> Score:
    """Score ``policy`` on ``episodes`` episodes of the raw ``env_id`` from noise seed ``seed``.

    Parameters
    ----------
    policy : object
        A controller with ``act_batch(x, mode, k)``, an object with ``predict(obs,
        deterministic=True)``, or a callable ``obs -> action`` (see the module docstring). An
        agent trained behind rescaling wrappers goes in as ``RawEnvPolicy(agent, train_env)``.
    episodes : int
        At least 2 (the intervals are over episodes).
    seed : int
        Noise seed, >= 0; the same seed gives every policy the same noise.
    env_id : str
        A registered SDJLS environment.
    env_kwargs : dict, optional
        Keyword arguments of ``gym.make(env_id, ...)``.

    Returns
    -------
    Score

    Raises
    ------
    TypeError, ValueError
        A bad argument, before any episode is run.
    """
    episodes = check_int("episodes", episodes, low=2, what="the intervals are over episodes")
    seed = check_int("seed", seed, low=0)
    if not isinstance(env_id, str):
        raise TypeError(f"env_id = {describe(env_id)} is a {type_name(env_id)}; expected a str")
    env_kwargs = check_mapping("env_kwargs", env_kwargs)
    _check_policy(policy)
    spec = resolve_env(env_id, env_kwargs)
    return evaluate_rollouts(as_controller(policy, spec), spec, episodes, seed, env_id)[0]
