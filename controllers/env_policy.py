"""A controller acting on a wrapped environment: :func:`policy_for`.

The controllers' ``predict`` reads the raw environment's observation and returns the input ``u``
in the raw environment's units (its action space). An environment wrapped for reinforcement
learning, e.g. with ``gymnasium.wrappers.RescaleAction`` (actions in [-1, 1]), expects other
actions: fed ``u`` directly, it multiplies them by the bound and the episode diverges, silently.
:func:`policy_for` reads the wrappers of the environment, converts ``u`` into the outer action
for the ones it can invert (``RescaleAction``, ``ClipAction``), acts through a known list of
wrappers that leave the observation and the action alone, and refuses every other one by name.

It reads what it needs of the environment (``env.unwrapped.model``, ``.horizon`` and the
spaces), not its class: the controllers depend on the model, never on the environments.
"""

from __future__ import annotations

from typing import Any, cast

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium import wrappers as gw

from sdjls_gym.messages import a_type, describe
from sdjls_gym.model import SDJLSModel

from .base import Controller, ObservationPolicy

__all__ = ["ControllerPolicy", "PASS_THROUGH_NAMES", "PASS_THROUGH_WRAPPERS", "policy_for"]

#: Wrappers that leave the observation and the action alone (they change the reward, the
#: episode's end, records or rendering): a controller acts through them unchanged. Matched by
#: exact type: a subclass may change what its parent leaves alone.
PASS_THROUGH_WRAPPERS: tuple[type, ...] = (
    gw.TimeLimit,
    gw.OrderEnforcing,
    gw.PassiveEnvChecker,
    gw.Autoreset,
    gw.RecordEpisodeStatistics,
    gw.RecordVideo,
    gw.RenderCollection,
    gw.HumanRendering,
    gw.TransformReward,
    gw.ClipReward,
    gw.NormalizeReward,
)
#: The same, named by module and class: this project's reward and episode wrappers (named, so
#: that the controllers do not import the environments) and libraries that need not be
#: installed.
PASS_THROUGH_NAMES = (
    "sdjls_gym.wrappers.ViolationPenalty",
    "sdjls_gym.wrappers.TerminateOutside",
    "sdjls_gym.wrappers.FiniteHorizon",
    "stable_baselines3.common.monitor.Monitor",
)


def _layers(env: gym.Env) -> tuple[list[gym.Wrapper], gym.Env]:
    """The wrappers of ``env`` from the outermost inwards, and the unwrapped env."""
    wrappers = []
    while isinstance(env, gym.Wrapper):
        wrappers.append(env)
        env = env.env
    return wrappers, env


class ControllerPolicy(ObservationPolicy):
    """``predict`` of a controller for a wrapped SDJLS environment (see :func:`policy_for`):
    the observation decoded with the environment's own horizon, the controller's input mapped
    to the outer action (see :meth:`action`).

    Attributes
    ----------
    controller : Controller
    horizon : int
        The environment's episode length (it decodes ``k`` from the observation).
    rescales : list of (low, high, min, max) arrays
        The ``RescaleAction`` layers, outermost first.
    """

    def __init__(self, controller: Controller, horizon: int, rescales: list) -> None:
        self.controller = controller
        self.horizon = horizon
        self.rescales = rescales

    def action(self, u: np.ndarray) -> np.ndarray:
        """The outer action that the wrappers turn into the input ``u`` (..., m)."""
        a = np.asarray(u, dtype=np.float64)
        for low, high, lo_a, hi_a in reversed(self.rescales):  # innermost first
            a = lo_a + (a - low) * (hi_a - lo_a) / (high - low)
        return a

    def _observed_inputs(self, observation: Any) -> tuple[np.ndarray, bool]:
        """The outer actions for observations of the wrapped environment: decoded as
        :meth:`Controller.predict` does (the mode part must be one-hot), with time at the
        environment's own horizon (a time entry that is not a multiple of ``1 / horizon`` in
        [0, 1] is refused, whatever the controller), then mapped by :meth:`action`."""
        obs = self.controller._observation(observation)
        x, mode, k = self.controller._decode(
            obs,
            self.horizon,
            f"the environment's horizon {self.horizon}: the observation is not one of this "
            "environment's",
        )
        return self.action(self.controller.act_batch(x, mode, k)[0]), obs.ndim == 1


def policy_for(controller: Controller, env: gym.Env) -> ControllerPolicy:
    """An object with stable-baselines3's ``predict`` that drives ``env`` with ``controller``.

    Parameters
    ----------
    controller : Controller
        Any controller of this package (its ``model`` must be the environment's).
    env : gymnasium.Env
        An SDJLS environment (its ``unwrapped`` has an ``SDJLSModel`` ``model`` and an int
        ``horizon``: ``SDJLSEnv``), possibly wrapped. The wrappers of
        :data:`PASS_THROUGH_WRAPPERS` and :data:`PASS_THROUGH_NAMES` (this project's
        ``ViolationPenalty``, ``TerminateOutside``, ``FiniteHorizon``, stable-baselines3's
        ``Monitor``), which leave the observation and the action alone, are acted through; ``RescaleAction`` (the input ``u`` is mapped to the outer action) and
        ``ClipAction`` (a no-op on the bounded input) are undone. Every other wrapper is refused
        by name, even one that keeps the observation space (``MaxAndSkipObservation``, a
        rescaling whose clip leaves the Box as it was): the controller needs the raw state and
        the raw input.

    Returns
    -------
    ControllerPolicy
        Decodes time with the environment's own horizon.

    Raises
    ------
    TypeError
        ``controller`` is not a controller or ``env`` not a Gymnasium environment.
    ValueError
        ``env`` is not an SDJLS environment of the controller's model, or has a wrapper the
        controller cannot act through (named in the message).

    Examples
    --------
    >>> import gymnasium as gym
    >>> from gymnasium.wrappers import RescaleAction
    >>> from controllers import LinearFeedbackController, policy_for
    >>> from sdjls_gym.systems.macro import PAPER_K
    >>> env = RescaleAction(gym.make("SDJLS-Macro-v0"), -1.0, 1.0)
    >>> policy = policy_for(LinearFeedbackController(env.unwrapped.model, PAPER_K), env)
    >>> obs, info = env.reset(seed=0)
    >>> action, _ = policy.predict(obs)  # u = K x = -1.4, as an action in [-1, 1]
    >>> round(float(action[0]) * 200.0, 4)
    -1.4
    """
    if not isinstance(controller, Controller):
        raise TypeError(
            f"controller = {describe(controller)} is {a_type(controller)}; expected a controller "
            "of this package (RecedingHorizonController, LinearFeedbackController, ...)"
        )
    if not isinstance(env, gym.Env):
        raise TypeError(f"env = {describe(env)} is {a_type(env)}; expected a gymnasium.Env")
    wrappers, base = _layers(env)
    horizon = _check_base(base, controller)
    return ControllerPolicy(controller, horizon, _rescales(wrappers, base))


def _check_base(base: gym.Env, controller: Controller) -> int:
    """The horizon of the environment ``base`` under the wrappers, after checking that it is an
    SDJLS environment of the controller's model."""
    model, horizon = getattr(base, "model", None), getattr(base, "horizon", None)
    if isinstance(model, SDJLSModel) and not (
        isinstance(horizon, int) and not isinstance(horizon, bool)
    ):
        raise TypeError(
            f"env's horizon = {describe(horizon)} is {a_type(horizon)} ({type(base).__name__} "
            "underneath); expected an int, the number of steps of an episode"
        )
    if not isinstance(model, SDJLSModel) or not isinstance(horizon, int):
        raise ValueError(
            f"env is a {type(base).__name__} underneath; expected an SDJLS environment "
            '(gym.make("SDJLS-v0", ...) or "SDJLS-Macro-v0")'
        )
    if model != controller.model:
        raise ValueError(
            f"env's model {model!r} is not the controller's model {controller.model!r}"
        )
    return horizon


def _rescales(wrappers: list[gym.Wrapper], base: gym.Env) -> list:
    """The ``RescaleAction`` layers among ``wrappers`` (outermost first) as ``(low, high, min,
    max)``; the layers that pass through are skipped, any other is refused by name."""
    rescales = []
    for layer in wrappers:
        kind = type(layer)
        if kind in PASS_THROUGH_WRAPPERS or f"{kind.__module__}.{kind.__qualname__}" in (
            PASS_THROUGH_NAMES
        ):
            continue
        if kind is gw.RescaleAction:
            # RescaleAction accepts Box action spaces only
            inner = cast(spaces.Box, layer.env.action_space)
            outer = cast(spaces.Box, layer.action_space)
            rescales.append(
                (
                    inner.low.astype(np.float64),
                    inner.high.astype(np.float64),
                    outer.low.astype(np.float64),
                    outer.high.astype(np.float64),
                )
            )
        elif kind is not gw.ClipAction:  # ClipAction: the env clips the inputs to the box anyway
            raise ValueError(_refusal(layer, base))
    return rescales


def _refusal(layer: gym.Wrapper, base: gym.Env) -> str:
    """What :func:`policy_for` says of a wrapper it cannot act through."""
    if layer.observation_space != base.observation_space or isinstance(
        layer, gym.ObservationWrapper
    ):
        what = "that changes the observation"
    elif isinstance(layer, gym.ActionWrapper) or layer.action_space != layer.env.action_space:
        what = "that changes the action in a way policy_for cannot undo"
    else:
        what = "that policy_for does not know (it may change the observation or the action)"
    known = ", ".join(
        [k.__name__ for k in PASS_THROUGH_WRAPPERS]
        + [path.rsplit(".", 1)[1] for path in PASS_THROUGH_NAMES]
    )
    return (
        f"env has a {type(layer).__name__} {what}; a controller needs the raw observation [x, "
        "one-hot(mode), k / horizon] and its input u must reach the raw env. policy_for "
        f"acts through {known}, undoes RescaleAction and ClipAction, and "
        "refuses every other wrapper (act on env.unwrapped instead)"
    )
