"""The observation layouts of an SDJLS, one per setting of ``observe``.

The layout belongs to the model (its sizes ``n`` and ``N``), so it lives next to it: the
environments encode their observations here and the controllers decode them here, without
either depending on the other.

``observe="mode"`` (the default): ``[x (n), one-hot of the mode (N), k / horizon]``

========  =============================================  ==================  =================
index     entry                                          min                 max
========  =============================================  ==================  =================
0..n-1    ``x_k``, clipped to ``+-divergence_bound``     -divergence_bound   divergence_bound
n..n+N-1  one-hot of ``theta_k``                          0                   1
n+N       ``k / horizon``                                0                   1
========  =============================================  ==================  =================

``observe="state"`` (the mode is hidden): ``[x (n), k / horizon]``

========  =============================================  ==================  =================
index     entry                                          min                 max
========  =============================================  ==================  =================
0..n-1    ``x_k``, clipped to ``+-divergence_bound``     -divergence_bound   divergence_bound
n         ``k / horizon``                                0                   1
========  =============================================  ==================  =================

The observation is float32; the exact float64 state is the environments' ``info["state"]``.
The environments' ``info["mode"]`` carries the true mode in either setting, for scoring: a
policy of the hidden setting must not read it (``controllers.ModeFilter`` gives the belief of
the mode from the states and inputs).
"""

from __future__ import annotations

from typing import Any, Literal, overload

import numpy as np
from gymnasium import spaces

from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import check_choice

__all__ = [
    "OBSERVE",
    "check_observe",
    "decode_observation",
    "encode_observation",
    "observation_size",
    "observation_space",
]

#: The settings of ``observe``: ``"mode"`` shows the mode (one-hot), ``"state"`` hides it.
OBSERVE = ("mode", "state")


def check_observe(observe: Any) -> str:
    """``observe`` checked: one of :data:`OBSERVE`.

    Raises
    ------
    TypeError
        ``observe`` is not a string.
    ValueError
        ``observe`` is a string other than ``"mode"`` or ``"state"``.

    Examples
    --------
    >>> check_observe("state")
    'state'
    >>> check_observe("belief")
    Traceback (most recent call last):
    ...
    ValueError: observe = 'belief' is not known; expected one of 'mode', 'state'
    """
    return check_choice("observe", observe, OBSERVE)


def observation_size(model: SDJLSModel, observe: str = "mode") -> int:
    """The length of an observation: ``n + N + 1`` (``"mode"``) or ``n + 1`` (``"state"``)."""
    return model.n + (model.N if check_observe(observe) == "mode" else 0) + 1


def observation_space(
    model: SDJLSModel, divergence_bound: float, observe: str = "mode"
) -> spaces.Box:
    """The Box of the observations of ``observe``'s layout, float32.

    ``x`` is clipped to ``[-divergence_bound, divergence_bound]`` in the observation (an episode
    terminates as soon as it leaves that box); the exact state is ``info["state"]``. The one-hot
    (``"mode"`` only) and the time entry are in ``[0, 1]``.
    """
    rest = observation_size(model, observe) - model.n
    low = np.concatenate([np.full(model.n, -divergence_bound), np.zeros(rest)])
    high = np.concatenate([np.full(model.n, divergence_bound), np.ones(rest)])
    return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)


def encode_observation(
    model: SDJLSModel,
    x: np.ndarray,
    mode: int | np.ndarray,
    k: int | np.ndarray,
    horizon: int,
    divergence_bound: float,
    observe: str = "mode",
) -> np.ndarray:
    """Observation(s) ``[clip(x), one_hot(mode), k / horizon]``, or ``[clip(x), k / horizon]``
    with ``observe="state"`` (float32).

    A state beyond the bound (or not finite) shows at the bound: ``+-inf`` at ``+-bound``, NaN at
    ``+bound``, so observations stay inside :func:`observation_space`.

    Parameters
    ----------
    model : SDJLSModel
    x : (..., n) float64
    mode : int or (...) int array
        Not read with ``observe="state"``.
    k : int or (...) int array
    horizon : int
    divergence_bound : float
    observe : {"mode", "state"}
        The layout (the environments check it once, at construction).

    Returns
    -------
    (..., n + N + 1) float32 array, or (..., n + 1) with ``observe="state"``. One state given
    with a Python int ``mode`` (the single environment's case) is encoded without the batch
    machinery, to the same values.
    """
    n, N = model.n, model.N
    show_mode = observe == "mode"
    size = n + N + 1 if show_mode else n + 1
    if type(mode) is int:  # one state: the single environment's hot path
        obs = np.zeros(size, dtype=np.float32)
        b = divergence_bound
        xs = x.tolist()
        for v in xs:
            if not -b <= v <= b:  # beyond the bound or NaN: clipped, NaN at +bound (n is small)
                obs[:n] = [v if -b <= v <= b else -b if v < 0 else b for v in xs]
                break
        else:
            obs[:n] = x
        if show_mode:
            obs[n + mode] = 1.0
        obs[-1] = k / horizon
        return obs
    x = np.asarray(x, dtype=np.float64)
    batch = x.shape[:-1]
    obs = np.zeros((*batch, size), dtype=np.float32)
    clipped = np.clip(x, -divergence_bound, divergence_bound)
    obs[..., :n] = np.nan_to_num(clipped, copy=False, nan=divergence_bound)
    if show_mode:
        one_hot = obs[..., n : n + N]
        where = np.broadcast_to(np.asarray(mode), batch)[..., None]
        np.put_along_axis(one_hot, where, 1.0, axis=-1)
    obs[..., -1] = np.asarray(k, dtype=np.float64) / horizon
    return obs


@overload
def decode_observation(
    model: SDJLSModel,
    observation: np.ndarray,
    horizon: int,
    observe: Literal["mode"] = "mode",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...
@overload
def decode_observation(
    model: SDJLSModel, observation: np.ndarray, horizon: int, observe: Literal["state"]
) -> tuple[np.ndarray, None, np.ndarray]: ...
@overload
def decode_observation(
    model: SDJLSModel, observation: np.ndarray, horizon: int, observe: str
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]: ...
def decode_observation(
    model: SDJLSModel, observation: np.ndarray, horizon: int, observe: str = "mode"
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Inverse of :func:`encode_observation`: ``(x (..., n), mode (...), k (...))``.

    A state-only observation (``observe="state"``) carries no mode: ``mode`` is then None (the
    belief of the mode is :class:`controllers.ModeFilter`'s). ``x`` comes back as float64 but
    carries float32 precision; use ``info["state"]`` when the exact state matters. The mode is
    the position of the largest one-hot entry and ``k`` the nearest integer to
    ``observation[..., -1] * horizon``; the controllers check that an observation is well
    formed before they decode it.

    Raises
    ------
    ValueError
        The last axis is not ``n + N + 1`` long (``"mode"``) or ``n + 1`` long (``"state"``),
        or ``observe`` is not one of them.

    Examples
    --------
    >>> import sdjls_gym
    >>> model = sdjls_gym.macro()  # n = 2, N = 3
    >>> obs = encode_observation(model, model.x0, 1, 5, 20, 1e6, observe="state")
    >>> obs.tolist()
    [2.0, 2.0, 0.25]
    >>> x, mode, k = decode_observation(model, obs, 20, observe="state")
    >>> x.tolist(), mode, int(k)
    ([2.0, 2.0], None, 5)
    """
    size = observation_size(model, observe)
    obs = np.asarray(observation, dtype=np.float64)
    if obs.shape[-1:] != (size,):
        layout = (
            "[x (n), one-hot mode (N), k/horizon] of observe='mode'"
            if observe == "mode"
            else "[x (n), k/horizon] of observe='state'"
        )
        raise ValueError(f"observation has shape {obs.shape}; expected (..., {size}) = {layout}")
    x = obs[..., : model.n]
    k = np.rint(obs[..., -1] * horizon).astype(np.int64)
    if observe == "state":
        return x, None, k
    mode = np.argmax(obs[..., model.n : model.n + model.N], axis=-1)
    return x, mode, k
