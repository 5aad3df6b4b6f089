"""The environments' step as pure functions of (parameters, state, action, noise draws).

In the shape of gymnax's ``step(params, state, action, noise)``: :func:`step` computes the
next state and mode, the stage cost, the constraint values and whether the episode diverged;
:func:`step_info` builds the info channel; :func:`~sdjls_gym.observation.encode_observation`
the observation. :class:`~sdjls_gym.env.SDJLSEnv` calls them with one state,
:class:`~sdjls_gym.vector_env.SDJLSVectorEnv` with a batch (and the rows that restart); the
environments only check arguments, draw the noise and keep the state between calls.

One state (``mode`` a Python int) takes a path written with few numpy calls: the single
environment must step within 1.5 times Pendulum-v1's time (``benchmarks/speed.py``), which a
batched call of one row does not (it costs some 20 times more). Both paths compute the same
values (``tests/test_functional.py`` compares them, overflowing steps included); they may
differ in the last bits where BLAS sums a product in another order.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from sdjls_gym.dynamics import max_last
from sdjls_gym.model import SDJLSModel

__all__ = [
    "MAX_DIVERGENCE_BOUND",
    "MAX_STAGE_COST",
    "EnvParams",
    "Restart",
    "Step",
    "may_overflow",
    "step",
    "step_info",
]

#: Largest allowed ``divergence_bound``: squares of states stay finite in float64 and the clipped
#: observation stays finite in float32.
MAX_DIVERGENCE_BOUND = 1e30

#: The stage cost reported (and negated as the reward) when it overflows float64 (or is NaN):
#: the largest finite float. Such a step terminates the episode as diverged.
MAX_STAGE_COST = sys.float_info.max

#: Bound on a standard normal draw assumed when deciding whether a step can overflow float64.
#: It only decides whether numpy's overflow warnings are silenced; overflow is handled anyway.
NOISE_DRAW_BOUND = 1e3


def may_overflow(
    model: SDJLSModel, action_high: np.ndarray, divergence_bound: float, horizon: int
) -> bool:
    """Whether a step from a state inside the divergence box could overflow float64.

    A bound on every product and sum of a step (next state, constraint values, stage cost) for
    ``|x| <= divergence_bound``, ``|u| <= action_high`` and standard normal draws below
    :data:`NOISE_DRAW_BOUND`. Only used to skip numpy's error-state switch on the hot path: a
    step that overflows anyway is still detected and terminated.
    """
    dyn = model.dynamics
    noise = np.abs(dyn.W_sqrt).sum(axis=1) * NOISE_DRAW_BOUND
    z = np.concatenate([np.full(model.n, divergence_bound), action_high, noise])
    with np.errstate(over="ignore", invalid="ignore"):
        M = np.abs(np.concatenate([dyn.ABE, model.G @ dyn.ABE], axis=1))
        y = M @ z
        zxu = z[: model.n + model.m]
        cost = np.abs(dyn.QR) @ zxu @ zxu
        H = np.abs(model.H0) + horizon * np.abs(model.H_rate)
        worst = max(float(np.max(y)), float(np.max(cost)), float(np.max(H)))
    return not worst < 1e300


@dataclass(frozen=True)
class EnvParams:
    """What a step reads besides the state: the model, the episode length, the divergence box.

    Attributes
    ----------
    model : SDJLSModel
    horizon : int
        Episode length T (``k / horizon`` is the observation's time entry).
    divergence_bound : float
        An episode terminates when ``max |x| > divergence_bound``.
    may_overflow : bool
        :func:`may_overflow` of these parameters and the action bound.
    """

    model: SDJLSModel
    horizon: int
    divergence_bound: float
    may_overflow: bool


class Restart(NamedTuple):
    """Rows of a batch that start a new episode instead of stepping (the vector environment's
    autoreset): they get ``x0``, the initial ``modes`` (one per restarted row), ``k = 0`` and a
    stage cost of 0."""

    #: (B,) bool
    rows: np.ndarray
    #: (n,) initial state
    x0: np.ndarray
    #: (rows.sum(),) int64 initial modes
    modes: np.ndarray


#: What :func:`step` returns: the new state ``(x_{k+1}, theta_{k+1}, k + 1)`` and the step's
#: outcome, ``(x, mode, k, stage_cost, constraint_values, diverged)``: the stage cost
#: ``x_k' Q x_k + u_k' R u_k`` (:data:`MAX_STAGE_COST` when it overflowed), ``G x_{k+1} -
#: H_{k+1}``, and whether ``max |x_{k+1}| > divergence_bound``, ``x_{k+1}`` is not finite or the
#: cost overflowed. For one state: arrays ``x`` (n,) and ``constraint_values`` (r,) and a Python
#: int, int, float and bool; for a batch, arrays with a leading batch axis. A plain tuple, as
#: :data:`~sdjls_gym.dynamics.Transition`.
Step = tuple[np.ndarray, Any, Any, Any, np.ndarray, Any]


def step(
    params: EnvParams,
    x: np.ndarray,
    mode: Any,
    k: Any,
    u: np.ndarray,
    w: np.ndarray,
    uniform: Any,
    inside: Any,
    restart: Restart | None = None,
) -> Step:
    """One step of the environment from given noise draws.

    :meth:`SDJLSModel.transition <sdjls_gym.SDJLSModel.transition>` from ``(x_k, theta_k, k)``
    under the (clipped) input ``u_k``; a step that overflows float64 gets the exact values
    rounded (:meth:`~sdjls_gym.SDJLSModel.exact_transition`, never NaN); a stage cost beyond
    float64 is saturated at :data:`MAX_STAGE_COST`; the episode diverged when the new state
    leaves the box ``max |x| <= divergence_bound`` or is not finite, or the cost overflowed.

    Parameters
    ----------
    params : EnvParams
    x : (n,) or (B, n) float64
    mode : int or (B,) int64
    k : int or (B,) int64
    u : (m,) or (B, m) float64, inside the action box
    w : (p,) or (B, p) noise, ``w ~ N(0, W)``
    uniform : float or (B,) draws from U[0, 1) for the next mode
    inside : bool or (B,) bool
        The region test of ``x`` at ``k`` (``info["in_region"]`` of the previous step).
    restart : Restart, optional
        Rows of a batch that start over instead (their ``x``, ``u`` and draws are not used).

    Returns
    -------
    Step
        ``(x, mode, k, stage_cost, constraint_values, diverged)`` of the new state.
    """
    model = params.model
    if type(mode) is int:  # one state: in plain Python where numpy's overhead would dominate
        dynamics = model.dynamics  # SDJLSModel.transition, without its one line of delegation
        if params.may_overflow:
            with np.errstate(over="ignore", invalid="ignore"):
                x1, mode1, cost, values = dynamics.transition(x, mode, u, k, w, uniform, inside)
            if not math.isfinite(cost + sum(x1.tolist()) + sum(values.tolist())):
                x1, cost, values = dynamics.exact_transition(x, mode, u, k, w)
        else:
            x1, mode1, cost, values = dynamics.transition(x, mode, u, k, w, uniform, inside)
        # outside the box or not finite: max() may skip a NaN, which the sum does not (a sum of
        # entries of at most 1e30 is finite)
        xs = x1.tolist()
        diverged = not (max(map(abs, xs)) <= params.divergence_bound and math.isfinite(sum(xs)))
        if not cost <= MAX_STAGE_COST:  # inf or NaN: saturated, and the episode ends
            cost, diverged = MAX_STAGE_COST, True
        return x1, mode1, k + 1, cost, values, diverged

    if restart is not None and not restart.rows.any():
        restart = None
    if restart is not None:
        x = x.copy()
        x[restart.rows] = restart.x0  # keep a diverged state out of the arithmetic of these rows
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is detected below
        x1, mode1, cost, values = model.transition(x, mode, u, k, w, uniform, inside)
        k1 = k + 1
        if restart is not None:
            rows = restart.rows
            x1[rows] = restart.x0
            mode1[rows] = restart.modes
            k1[rows] = 0
            cost[rows] = 0.0
            values = model.constraint_values(x1, k1)  # the restarted rows' values, at x0
        if params.may_overflow:
            ok = np.isfinite(cost + x1.sum(axis=1) + values.sum(axis=1))
            if restart is not None:
                ok |= restart.rows
            for b in np.flatnonzero(~ok).tolist():
                # the exact values rounded, as the single environment gives (never NaN)
                x1[b], cost[b], values[b] = model.exact_transition(
                    x[b], int(mode[b]), u[b], int(k[b]), w[b]
                )
        overflow = ~(cost <= MAX_STAGE_COST)
        if overflow.any():  # an overflowed (inf) stage cost is saturated and ends the episode
            cost[overflow] = MAX_STAGE_COST
        # NaN-safe: max propagates a NaN, which fails the comparison
        diverged = ~(max_last(np.abs(x1)) <= params.divergence_bound) | overflow
    return x1, mode1, k1, cost, values, diverged


def step_info(
    model: SDJLSModel,
    x: np.ndarray,
    mode: Any,
    k: Any,
    stage_cost: Any,
    diverged: Any,
    values: np.ndarray | None = None,
) -> dict[str, Any]:
    """The info of a state ``(x, mode, k)`` reached by a step of cost ``stage_cost``.

    Keys: ``state`` (a copy of ``x``), ``mode``, ``k``, ``in_region`` (``G x <= H_k`` in every
    row), ``constraint_values`` (``G x - H_k``, computed unless given as ``values``),
    ``violations`` (rows with a positive value; a NaN value, from a diverged state, counts as
    violated), ``cost`` (1.0 if any row is violated, else 0.0), ``stage_cost`` and ``diverged``.

    One state (``mode`` a Python int) gives Python ``int``, ``bool`` and ``float`` values beside
    the arrays; a batch gives arrays with a leading batch axis.
    """
    if type(mode) is int:
        if values is None:
            values = model.constraint_values_one(x, k)
        if diverged:  # NaN values count as violated
            violations = ~(values <= 0.0)
            inside = not any(violations.tolist())
        else:  # x is finite: so are the values
            violations = values > 0.0
            inside = max(values.tolist()) <= 0.0
        return {
            "state": x.copy(),
            "mode": mode,
            "k": k,
            "in_region": inside,
            "constraint_values": values,
            "violations": violations,
            "cost": 0.0 if inside else 1.0,
            "stage_cost": stage_cost,
            "diverged": diverged,
        }
    if values is None:
        values = model.constraint_values(x, k)
    in_region = max_last(values) <= 0.0  # False when a value is NaN: max propagates it
    return {
        "state": np.array(x, dtype=np.float64),
        "mode": mode,
        "k": k,
        "in_region": in_region,
        "constraint_values": values,
        "violations": ~(values <= 0.0),
        "cost": np.where(in_region, 0.0, 1.0),
        "stage_cost": stage_cost,
        "diverged": diverged,
    }
