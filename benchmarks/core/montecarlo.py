"""Closed-loop Monte Carlo on the vector environment (the statistics are in ``benchmarks.core.stats``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sdjls_gym import SDJLSModel, SDJLSVectorEnv

__all__ = ["Rollouts", "decide_batch", "decide_hidden", "rollout", "rollouts"]


@dataclass
class Rollouts:
    """Closed-loop trajectories of ``runs`` episodes of ``T`` steps.

    Attributes
    ----------
    x : (runs, T+1, n) states x_0 .. x_T
    mode : (runs, T+1) modes
    u : (runs, T, m) applied inputs
    rho : (runs, T) slack of the controller's QP (0 for controllers without one)
    J : (runs, T) the controller's reported cost (J*_k for the receding-horizon controller; 0
        where it reports none)
    stage_cost : (runs, T) x_k'Q x_k + u_k'R u_k
    violations : (runs, T, r) whether row j of G x_{k+1} <= H_{k+1} is violated
    status_ok : (runs, T) whether the controller's solver succeeded without fallback
    ended : (runs, T) whether the episode had already ended (diverged, ``terminated``) before
        step k. Such a step is not simulated: the row keeps the diverged state and mode, with
        ``u = 0``, ``rho = J = stage_cost = 0``, ``status_ok = True``, and every row of the
        constraint counts as violated (the episode failed; a frequency over ``runs x T`` steps
        counts those steps as violated, whatever direction the state diverged in).
    """

    x: np.ndarray
    mode: np.ndarray
    u: np.ndarray
    rho: np.ndarray
    J: np.ndarray
    stage_cost: np.ndarray
    violations: np.ndarray
    status_ok: np.ndarray
    ended: np.ndarray

    @property
    def runs(self) -> int:
        return self.x.shape[0]

    @property
    def any_violation(self) -> NDArray[np.bool_]:
        """(runs, T) whether any row is violated at k+1."""
        return np.asarray(self.violations.any(axis=-1))  # an array: violations is (runs, T, r)

    @property
    def episode_cost(self) -> np.ndarray:
        """(runs,) sum over the episode of the stage costs."""
        return self.stage_cost.sum(axis=1)

    def diverged(self, divergence_bound: float) -> int:
        """How many episodes have a state entry beyond ``divergence_bound`` in magnitude."""
        return int(np.any(np.abs(self.x) > divergence_bound, axis=(1, 2)).sum())

    def outcomes(self, divergence_bound: float) -> tuple[np.ndarray, np.ndarray, int]:
        """What a curve's level keeps of its episodes: costs (runs,), shares of violated steps
        (runs,) and the diverged count (:meth:`diverged`)."""
        return self.episode_cost, self.any_violation.mean(axis=1), self.diverged(divergence_bound)

    @classmethod
    def pooled(cls, parts: list[Rollouts]) -> Rollouts:
        """The episodes of ``parts`` (rollouts of the same horizon) as one set, in order."""
        if len(parts) == 1:
            return parts[0]
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)))


def decide_batch(controller: Any, x: np.ndarray, mode: np.ndarray, k: np.ndarray) -> tuple:
    """``controller.act_batch`` when the controller has one, else a loop over ``act``.

    Returns ``(u (B, m), rho (B,), J (B,), ok (B,))``; ``rho`` and ``J`` are 0 and ``ok`` True
    where the controller's info has no ``"rho"``, ``"cost"`` or ``"ok"``.
    """
    if hasattr(controller, "act_batch"):
        u, info = _answer(controller.act_batch(x, mode, k), "act_batch")
        B = x.shape[0]
        rho = np.asarray(info.get("rho", np.zeros(B)), dtype=np.float64)
        ok = np.asarray(info.get("ok", np.ones(B, dtype=bool)), dtype=bool)
        return u, rho, np.asarray(info.get("cost", np.zeros(B)), dtype=np.float64), ok
    us, rhos, Js, oks = [], [], [], []
    for x_row, mode_row, k_row in zip(x, mode, k, strict=True):
        u, info = _answer(controller.act(x_row, int(mode_row), int(k_row)), "act")
        us.append(u)
        rhos.append(float(info.get("rho", 0.0)))
        Js.append(float(info.get("cost", 0.0)))
        oks.append(str(info.get("status", "")).startswith(("solved", "optimal")))
    return np.array(us), np.array(rhos), np.array(Js), np.array(oks)


def decide_hidden(policy: Any, x: np.ndarray, k: np.ndarray, u_applied: np.ndarray | None) -> tuple:
    """``policy.act_hidden(x, k, u_applied)`` of a policy that keeps the belief of a hidden mode
    (:class:`controllers.HiddenModePolicy`); returns what :func:`decide_batch` does."""
    u, info = _answer(policy.act_hidden(x, k, u_applied), "act_hidden")
    B = x.shape[0]
    rho = np.asarray(info.get("rho", np.zeros(B)), dtype=np.float64)
    ok = np.asarray(info.get("ok", np.ones(B, dtype=bool)), dtype=bool)
    return u, rho, np.asarray(info.get("cost", np.zeros(B)), dtype=np.float64), ok


def _answer(out: Any, method: str) -> tuple[Any, Mapping[str, Any]]:
    """A controller's ``(u, info)``, checked: ``info`` a mapping (its keys ``"rho"``,
    ``"cost"``, ``"ok"`` optional)."""
    if not (isinstance(out, tuple) and len(out) == 2 and isinstance(out[1], Mapping)):
        raise TypeError(
            f"the policy's {method} returned {type(out).__name__} {str(out)[:80]!r}; expected a "
            "tuple (u, info) with info a dict (its keys 'rho', 'cost', 'ok' optional)"
        )
    return out[0], out[1]


def rollouts(
    model: SDJLSModel,
    controller: Any,
    runs: int,
    horizon: int,
    seeds: tuple[int, ...],
    action_bound: float | np.ndarray = 200.0,
    progress: Any = None,
    divergence_bound: float = 1e6,
) -> Rollouts:
    """:func:`rollout` from each noise seed of ``seeds``, ``runs`` episodes each, pooled
    (:meth:`Rollouts.pooled`): ``runs * len(seeds)`` episodes."""
    return Rollouts.pooled([
        rollout(model, controller, runs, horizon, seed, action_bound, progress, divergence_bound)
        for seed in seeds
    ])  # fmt: skip


def rollout(
    model: SDJLSModel,
    controller: Any,
    runs: int,
    horizon: int,
    seed: int,
    action_bound: float | np.ndarray = 200.0,
    progress: Any = None,
    divergence_bound: float = 1e6,
) -> Rollouts:
    """Simulate ``runs`` closed-loop episodes on :class:`~sdjls_gym.SDJLSVectorEnv`.

    The controller sees the exact state (``info["state"]``), the mode and ``k``; a policy with
    ``act_hidden`` (:class:`controllers.HiddenModePolicy`, the mode hidden) sees the state, ``k``
    and the inputs the environment applied at the previous step, never the mode, and is
    ``reset(runs)`` first. The
    environment's noise comes from ``seed``, so two controllers run with the same seed see the
    same noise sequence as long as they draw nothing themselves (common random numbers).

    An episode that diverges (``terminated``: ``max |x|`` beyond the environment's divergence
    bound, 1e6 by default) ends there: the vector environment restarts that row, but the rest of
    the row is not a new episode here; it holds the diverged state (see :attr:`Rollouts.ended`),
    and the controller is never shown the diverged state: it decides on ``x = 0`` for that row,
    and the decision is discarded (the input is set to 0). So a state beyond what a controller
    accepts (``max |x| > 1e100`` after one step) cannot stop the batch: a diverged episode is a
    diverged episode, whatever the policy. Every row has ``horizon`` steps.
    """
    env = SDJLSVectorEnv(
        num_envs=runs,
        model=model,
        horizon=horizon,
        action_bound=action_bound,
        divergence_bound=divergence_bound,
    )
    _, info = env.reset(seed=seed)
    n, m, r = model.n, model.m, model.r
    x = np.empty((runs, horizon + 1, n))
    modes = np.empty((runs, horizon + 1), dtype=np.int64)
    u_all = np.empty((runs, horizon, m))
    rho = np.empty((runs, horizon))
    J = np.empty((runs, horizon))
    stage = np.empty((runs, horizon))
    viol = np.empty((runs, horizon, r), dtype=bool)
    ok = np.empty((runs, horizon), dtype=bool)
    ended = np.zeros((runs, horizon), dtype=bool)
    done = np.zeros(runs, dtype=bool)  # rows whose episode has diverged
    x[:, 0], modes[:, 0] = info["state"], info["mode"]
    hidden = callable(getattr(controller, "act_hidden", None))
    if hidden:
        controller.reset(runs)
    for k in range(horizon):
        state = info["state"]
        if done.any():  # a diverged row's state (up to inf) never reaches the policy
            state = np.array(state, dtype=np.float64)
            state[done] = 0.0
        if hidden:  # the mode hidden: the policy sees (x, k) and the inputs applied before
            applied = u_all[:, k - 1] if k else None
            u, rho[:, k], J[:, k], ok[:, k] = decide_hidden(controller, state, info["k"], applied)
        else:
            u, rho[:, k], J[:, k], ok[:, k] = decide_batch(
                controller, state, info["mode"], info["k"]
            )
        if done.any():
            u = np.array(u, dtype=np.float64)
            u[done] = 0.0
        _, _, terminated, _, info = env.step(u)
        x[:, k + 1], modes[:, k + 1] = info["state"], info["mode"]
        u_all[:, k], stage[:, k], viol[:, k] = info["u"], info["stage_cost"], info["violations"]
        if done.any():  # the env restarted these rows: hold the diverged state instead
            ended[:, k] = done
            x[done, k + 1], modes[done, k + 1] = x[done, k], modes[done, k]
            u_all[done, k], rho[done, k], J[done, k], stage[done, k] = 0.0, 0.0, 0.0, 0.0
            viol[done, k], ok[done, k] = True, True
        done |= terminated
        if progress is not None:
            progress.update(1)
    return Rollouts(x, modes, u_all, rho, J, stage, viol, ok, ended)
