"""``SDJLSVectorEnv``: the same dynamics as :class:`~sdjls_gym.env.SDJLSEnv` on a batch, in numpy."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.envs.registration import EnvSpec
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from sdjls_gym import functional
from sdjls_gym.env import (
    action_space,
    check_divergence_bound,
    check_model_x0,
    check_seed,
    own_spec,
    parse_reset_options,
    resolve_model,
)
from sdjls_gym.functional import EnvParams, Restart, may_overflow
from sdjls_gym.messages import describe
from sdjls_gym.model import SDJLSModel
from sdjls_gym.observation import check_observe, encode_observation, observation_space
from sdjls_gym.validation import check_int, check_numbers, check_optional_int

__all__ = ["SDJLSVectorEnv", "check_max_episode_steps"]


def check_max_episode_steps(max_episode_steps: Any, horizon: int) -> int | None:
    """``max_episode_steps`` as an int (or None), refused when it is larger than ``horizon``.

    The environment ends its episodes at its ``horizon``: ``max_episode_steps`` may only end
    them earlier. A larger value would make ``spec.max_episode_steps`` report more steps than an
    episode has.

    Parameters
    ----------
    max_episode_steps : int or None
        The limit asked for; None for none.
    horizon : int
        The environment's horizon.

    Raises
    ------
    TypeError
        ``max_episode_steps`` is not an int.
    ValueError
        ``max_episode_steps`` is below 1 or above ``horizon``.
    """
    steps = check_optional_int("max_episode_steps", max_episode_steps, low=1)
    if steps is not None and steps > horizon:
        raise ValueError(
            f"max_episode_steps = {steps} is larger than horizon = {horizon}: the "
            f"environment ends its episodes at its horizon; pass horizon={steps} instead "
            "(max_episode_steps may only shorten episodes)"
        )
    return steps


class SDJLSVectorEnv(VectorEnv):
    """``num_envs`` independent copies of :class:`~sdjls_gym.env.SDJLSEnv`, stepped together.

    The whole batch is advanced by one call of the model's batched dynamics; there is no
    Python loop over sub-environments. Semantics per sub-environment are those of
    ``SDJLSEnv`` (time indexing, reward, info keys, clipping of actions, truncation at the
    horizon, termination on divergence), with Gymnasium's vector conventions:

    * autoreset mode ``NEXT_STEP``: the step after a sub-environment ended resets it (from the
      model's ``x0`` and ``mode0``; ``reset(options=...)`` applies to the explicit reset only,
      as with Gymnasium's sync vector env), ignores its action and returns its reset
      observation with reward 0 and ``terminated = truncated = False``;
    * a sub-environment whose state leaves the divergence box or is not finite, or whose stage
      cost overflows float64, terminates as diverged with a finite reward (the largest float
      stands for an overflowed cost) and an observation inside the space;
    * infos are a dict of arrays with a leading batch axis, each key ``key`` with a boolean
      mask ``_key`` (``u`` is masked out for sub-environments that were reset this step);
    * randomness comes from one ``numpy.random.Generator`` (``self.np_random``) for the batch,
      so the same seed gives the same batch. The stream differs from ``num_envs`` separate
      ``SDJLSEnv`` instances; the two agree in distribution. The initial modes of autoresets
      (when ``mode0`` is a probability vector) are drawn from a second stream, a jump ahead of
      ``np_random`` taken at ``reset()``: the noise and mode draws of the other rows do not
      depend on which rows ended when, so two policies run from the same seed see the same
      noise in every row that has not ended (common random numbers).

    Parameters
    ----------
    num_envs : int
        Number of sub-environments.
    model, horizon, action_bound, divergence_bound, observe
        As for :class:`~sdjls_gym.env.SDJLSEnv` (``model`` is required; ``observe="state"``
        hides the mode: observations ``(num_envs, n + 1)``, ``infos["mode"]`` for scoring
        only).
    max_episode_steps : int, optional
        Episodes are truncated after ``max_episode_steps`` steps, as a ``TimeLimit`` would do
        (``gymnasium.make_vec`` passes it when given to it or when an id registers one; the ids
        of this package do not). It may only shorten episodes: an int from 1 to ``horizon``
        (a larger value is a ``ValueError``; pass ``horizon`` instead). ``spec.max_episode_steps``
        reports it, or ``horizon`` when it is None.
    render_mode : None
        Rendering is not supported for the batch; render one ``SDJLSEnv`` instead.

    Examples
    --------
    >>> import gymnasium as gym, sdjls_gym
    >>> envs = gym.make_vec("SDJLS-Macro-v0", num_envs=1024, vectorization_mode="vector_entry_point")
    >>> obs, info = envs.reset(seed=0)
    >>> obs.shape
    (1024, 6)
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    _spec: EnvSpec | None = None

    def __init__(
        self,
        num_envs: int = 1,
        model: SDJLSModel | str | dict | None = None,
        horizon: int = 20,
        action_bound: float | np.ndarray = 200.0,
        divergence_bound: float = 1e6,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        observe: str = "mode",
    ) -> None:
        if render_mode is not None:
            raise ValueError(
                f"render_mode = {render_mode!r}; SDJLSVectorEnv does not render, use SDJLSEnv"
            )
        self.model = resolve_model(model)
        self.num_envs = check_int("num_envs", num_envs, low=1)
        self.horizon = check_int("horizon", horizon, low=1)
        steps = check_max_episode_steps(max_episode_steps, self.horizon)
        self.episode_steps = self.horizon if steps is None else steps
        self.divergence_bound = check_divergence_bound(divergence_bound)
        check_model_x0(self.model, self.divergence_bound)
        self.render_mode = None
        self.observe = check_observe(observe)

        self.single_observation_space = observation_space(
            self.model, self.divergence_bound, self.observe
        )
        self.single_action_space = action_space(self.model, action_bound)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._low = self.single_action_space.low.astype(np.float64)
        self._actions_what = f"a ({self.num_envs}, {self.model.m}) array of finite numbers"
        self._high = self.single_action_space.high.astype(np.float64)
        self._params = EnvParams(
            self.model,
            self.horizon,
            self.divergence_bound,
            may_overflow(self.model, self._high, self.divergence_bound, self.horizon),
        )

        B, model = self.num_envs, self.model
        self._x = np.zeros((B, model.n))
        self._mode = np.zeros(B, dtype=np.int64)
        self._k = np.zeros(B, dtype=np.int64)
        self._prev_done = np.zeros(B, dtype=bool)
        self._started = False

    # ------------------------------------------------------------------ spec
    @property
    def spec(self) -> EnvSpec | None:
        """The ``EnvSpec`` that ``gymnasium.make_vec`` set, with ``max_episode_steps`` the
        episode length and JSON-friendly kwargs (see :func:`sdjls_gym.env.own_spec`)."""
        return self._spec

    @spec.setter
    def spec(self, value: EnvSpec | None) -> None:
        self._spec = own_spec(value, self.episode_steps, self.model)

    # ------------------------------------------------------------------ helpers
    def _infos(self, stage_cost: np.ndarray, diverged: np.ndarray, values: Any = None) -> dict:
        """:func:`~sdjls_gym.functional.step_info` of the current states, each key ``key``
        followed by its mask ``_key`` (all True)."""
        raw = functional.step_info(
            self.model, self._x, self._mode.copy(), self._k.copy(), stage_cost, diverged, values
        )
        self._inside = raw["in_region"]  # region test of the current states, reused by step()
        infos: dict[str, Any] = {}
        everyone = np.ones(self.num_envs, dtype=bool)
        for key, value in raw.items():
            infos[key] = value
            infos[f"_{key}"] = everyone
        return infos

    # ------------------------------------------------------------------ Gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=check_seed(seed))
        x0, mode0 = parse_reset_options(self.model, options, self.divergence_bound)
        B = self.num_envs
        self._x = np.broadcast_to(self.model.x0 if x0 is None else x0, (B, self.model.n)).copy()
        self._mode = (
            self.model.sample_mode0(self.np_random, B)
            if mode0 is None
            else np.full(B, mode0, dtype=np.int64)
        )
        self._k = np.zeros(B, dtype=np.int64)
        self._prev_done = np.zeros(B, dtype=bool)
        # autoreset modes: a stream of their own (a jump of this one, which it leaves as it is;
        # a bit generator that cannot jump, such as SFC64, spawns a child stream instead)
        bits = self.np_random.bit_generator
        self._reset_rng = (
            np.random.Generator(bits.jumped())
            if hasattr(bits, "jumped")
            else self.np_random.spawn(1)[0]
        )
        self._started = True
        obs = encode_observation(
            self.model,
            self._x,
            self._mode,
            self._k,
            self.horizon,
            self.divergence_bound,
            self.observe,
        )
        with np.errstate(over="ignore", invalid="ignore"):
            return obs, self._infos(np.zeros(B), np.zeros(B, dtype=bool))

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        B, model = self.num_envs, self.model
        u = check_numbers("actions", actions, what=self._actions_what)
        if u.shape != (B, model.m):
            if u.size == B * model.m and model.m == 1 and u.shape == (B,):
                u = u.reshape(B, 1)
            else:
                raise ValueError(f"actions have shape {u.shape}; expected ({B}, {model.m})")
        if not np.isfinite(u.sum()) and not np.isfinite(u).all():  # the sum first: cheaper
            row = int(np.flatnonzero(~np.isfinite(u).all(axis=1))[0])
            raise ValueError(
                f"actions[{row}] = {describe(u[row])} is not finite (NaN or inf); expected "
                f"finite numbers, actions = {describe(u)}"
            )
        u = np.clip(u, self._low, self._high)

        reset = self._prev_done
        rng = self.np_random
        w = model.sample_noise(rng, (B,))
        uniform = rng.random(B)
        restart = None
        if reset.any():  # these rows restart from the model's x0 and mode0, as a plain reset()
            modes0 = np.asarray(model.sample_mode0(self._reset_rng, int(reset.sum())))
            restart = Restart(reset, model.x0, modes0)
        x, mode, k, cost, values, diverged = functional.step(
            self._params, self._x, self._mode, self._k, u, w, uniform, self._inside, restart
        )
        self._x, self._mode, self._k = x, mode, k
        with np.errstate(over="ignore", invalid="ignore"):
            infos = self._infos(cost, diverged, values)
        infos["u"] = u
        infos["_u"] = ~reset
        terminated = diverged & ~reset
        truncated = (k >= self.episode_steps) & ~reset
        self._prev_done = terminated | truncated
        obs = encode_observation(
            model, self._x, self._mode, self._k, self.horizon, self.divergence_bound, self.observe
        )
        return obs, -cost, terminated, truncated, infos
