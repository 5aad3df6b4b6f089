"""The observation layout of an SDJLS: ``[x (n), one-hot of the mode (N), k / horizon]``.

The layout belongs to the model (its sizes ``n`` and ``N``), so it lives next to it: the
environments encode their observations here and the controllers decode them here, without
either depending on the other.

========  =============================================  ==================  =================
index     entry                                          min                 max
========  =============================================  ==================  =================
0..n-1    ``x_k``, clipped to ``+-divergence_bound``     -divergence_bound   divergence_bound
n..n+N-1  one-hot of ``theta_k``                          0                   1
n+N       ``k / horizon``                                0                   1
========  =============================================  ==================  =================

The observation is float32; the exact float64 state is the environments' ``info["state"]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from sdjls_gym.model import SDJLSModel

__all__ = ["decode_observation", "encode_observation", "observation_space"]


def observation_space(model: SDJLSModel, divergence_bound: float) -> spaces.Box:
    """The Box ``[x (n), one-hot of the mode (N), k / horizon]`` of float32.

    ``x`` is clipped to ``[-divergence_bound, divergence_bound]`` in the observation (an episode
    terminates as soon as it leaves that box); the exact state is ``info["state"]``.
    """
    low = np.concatenate([np.full(model.n, -divergence_bound), np.zeros(model.N + 1)])
    high = np.concatenate([np.full(model.n, divergence_bound), np.ones(model.N + 1)])
    return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)


def encode_observation(
    model: SDJLSModel,
    x: np.ndarray,
    mode: Any,
    k: Any,
    horizon: int,
    divergence_bound: float,
) -> np.ndarray:
    """Observation(s) ``[clip(x), one_hot(mode), k / horizon]`` (float32).

    A state beyond the bound (or not finite) shows at the bound: ``+-inf`` at ``+-bound``, NaN at
    ``+bound``, so observations stay inside :func:`observation_space`.

    Parameters
    ----------
    model : SDJLSModel
    x : (..., n) float64
    mode : int or (...) int array
    k : int or (...) int array
    horizon : int
    divergence_bound : float

    Returns
    -------
    (..., n + N + 1) float32 array. One state given with a Python int ``mode`` (the single
    environment's case) is encoded without the batch machinery, to the same values.
    """
    n, N = model.n, model.N
    if type(mode) is int:  # one state: the single environment's hot path
        obs = np.zeros(n + N + 1, dtype=np.float32)
        b = divergence_bound
        xs = x.tolist()
        for v in xs:
            if not -b <= v <= b:  # beyond the bound or NaN: clipped, NaN at +bound (n is small)
                obs[:n] = [v if -b <= v <= b else -b if v < 0 else b for v in xs]
                break
        else:
            obs[:n] = x
        obs[n + mode] = 1.0
        obs[-1] = k / horizon
        return obs
    x = np.asarray(x, dtype=np.float64)
    batch = x.shape[:-1]
    obs = np.zeros((*batch, n + N + 1), dtype=np.float32)
    clipped = np.clip(x, -divergence_bound, divergence_bound)
    obs[..., :n] = np.nan_to_num(clipped, copy=False, nan=divergence_bound)
    one_hot = obs[..., n : n + N]
    np.put_along_axis(one_hot, np.broadcast_to(np.asarray(mode), batch)[..., None], 1.0, axis=-1)
    obs[..., -1] = np.asarray(k, dtype=np.float64) / horizon
    return obs


def decode_observation(
    model: SDJLSModel, observation: np.ndarray, horizon: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`encode_observation`: ``(x (..., n), mode (...), k (...))``.

    ``x`` comes back as float64 but carries float32 precision; use ``info["state"]`` when the
    exact state matters. The mode is the position of the largest one-hot entry and ``k`` the
    nearest integer to ``observation[..., -1] * horizon``; the controllers check that an
    observation is well formed before they decode it.

    Raises
    ------
    ValueError
        The last axis is not ``n + N + 1`` long.
    """
    obs = np.asarray(observation, dtype=np.float64)
    if obs.shape[-1] != model.n + model.N + 1:
        raise ValueError(
            f"observation has shape {obs.shape}; expected (..., {model.n + model.N + 1}) = "
            "[x (n), one-hot mode (N), k/horizon]"
        )
    x = obs[..., : model.n]
    mode = np.argmax(obs[..., model.n : model.n + model.N], axis=-1)
    k = np.rint(obs[..., -1] * horizon).astype(np.int64)
    return x, mode, k
