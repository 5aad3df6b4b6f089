"""``SDJLSEnv``: a state-dependent jump linear system as a Gymnasium environment."""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec

from sdjls_gym import functional
from sdjls_gym.errors import ResetNeededError
from sdjls_gym.functional import MAX_DIVERGENCE_BOUND, EnvParams, may_overflow
from sdjls_gym.messages import a_type, describe
from sdjls_gym.model import SDJLSModel
from sdjls_gym.observation import check_observe, encode_observation, observation_space
from sdjls_gym.validation import (
    check_array,
    check_choice,
    check_float32_bound,
    check_int,
    check_mapping,
    check_number,
    check_numbers,
)

if TYPE_CHECKING:  # for the annotation only: render() imports it on first use
    from sdjls_gym.render import EpisodeRenderer

__all__ = [
    "SDJLSEnv",
    "action_space",
    "check_divergence_bound",
    "check_model_x0",
    "check_seed",
    "make_env",
    "own_spec",
    "parse_reset_options",
    "resolve_model",
]


def resolve_model(model: SDJLSModel | str | dict | None) -> SDJLSModel:
    """Accept a model, a preset name (``"macro"``) or a ``to_dict()`` dict.

    Raises
    ------
    TypeError
        ``model`` is missing (None) or of another type.
    ValueError
        ``model`` is a string that names no preset.
    """
    if isinstance(model, SDJLSModel):
        return model
    if isinstance(model, str):
        from sdjls_gym.systems import PRESETS

        return PRESETS[check_choice("model", model, sorted(PRESETS))]()
    if isinstance(model, dict):
        return SDJLSModel.from_dict(model)
    example = 'e.g. gym.make("SDJLS-v0", model=sdjls_gym.macro(), horizon=20)'
    if model is None:
        raise TypeError(
            "model is missing; pass an SDJLSModel, a preset name (model='macro') or a "
            f"to_dict() dict, {example}"
        )
    raise TypeError(
        f"model = {describe(model)} is {a_type(model)}; expected an SDJLSModel, a preset "
        f"name or a to_dict() dict, {example}"
    )


def check_divergence_bound(value: Any) -> float:
    """A threshold on ``max |x|`` in ``(0, MAX_DIVERGENCE_BOUND]``."""
    return check_number(
        "divergence_bound",
        value,
        low=0.0,
        low_open=True,
        high=MAX_DIVERGENCE_BOUND,
        what="termination threshold on max |x|",
    )


def check_model_x0(model: SDJLSModel, divergence_bound: float) -> None:
    """The model's initial state must start inside the divergence box."""
    if float(np.max(np.abs(model.x0))) > divergence_bound:
        raise ValueError(
            f"the model's x0 = {describe(model.x0)} has an entry beyond divergence_bound = "
            f"{divergence_bound:g}; raise divergence_bound or change x0"
        )


def check_seed(seed: Any) -> int | None:
    """``reset(seed=...)``: None, or an int ``>= 0`` of any size (Gymnasium itself would take a
    bool as a seed and refuse a numpy int)."""
    return None if seed is None else check_int("seed", seed, low=0, high=None)


def parse_reset_options(
    model: SDJLSModel, options: dict[str, Any] | None, divergence_bound: float
) -> tuple[np.ndarray | None, int | None]:
    """Validate ``reset(options=...)``: ``(x0 or None, mode0 or None)``, None when not given."""
    options = check_mapping("options", options, allowed=("x0", "mode0"))
    x0 = mode0 = None
    if "x0" in options:
        x0 = check_array(
            "options['x0']",
            options["x0"],
            shape=(model.n,),
            max_abs=divergence_bound,
            what="the initial state, inside the divergence box",
        )
    if "mode0" in options:
        mode0 = check_int("options['mode0']", options["mode0"], low=0, high=model.N - 1)
    return x0, mode0


def _plain(value: Any) -> Any:
    """A JSON-friendly form of a constructor argument (a model becomes its ``to_dict()``, numpy
    arrays lists, also inside a model given as a dict)."""
    if isinstance(value, SDJLSModel):
        return value.to_dict()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    return value


def own_spec(
    spec: EnvSpec | None, max_episode_steps: int, model: SDJLSModel | None = None
) -> EnvSpec | None:
    """``spec`` with JSON-friendly kwargs and ``max_episode_steps`` set when it is None.

    ``gymnasium.make`` gives an env a spec whose ``max_episode_steps`` is None when no
    ``TimeLimit`` is added; the environment truncates at its own horizon, which is reported
    there instead, so that ``env.spec.max_episode_steps`` says when episodes end and
    ``env.spec.to_json()`` works with a model object among the arguments.

    Raises
    ------
    ValueError
        ``spec.id`` is a preset task (``sdjls_gym.systems.TASKS``, but ``SDJLS-Random-v0``,
        whose system its own arguments choose) and ``model``, the environment's model, is
        not that task's: ``gym.make("SDJLS-Solar-v0", model="macro")`` would build the macro
        system under the Solar id. ``gym.make("SDJLS-v0", model=...)`` takes any model.
    """
    if spec is None:
        return None
    if model is not None:
        from sdjls_gym.systems import TASKS

        task = TASKS.get(spec.id) if spec.id != "SDJLS-Random-v0" else None
        if task is not None and model != task.model:
            given = spec.kwargs.get("model")
            shown = (
                repr(given) if isinstance(given, str) else f"a model with n={model.n}, N={model.N}"
            )
            raise ValueError(
                f"model = {shown} given to {spec.id}, a preset task whose model is fixed; "
                f'leave model out, or use gym.make("SDJLS-v0", model=..., horizon=...) for '
                "another system"
            )
    steps = spec.max_episode_steps if spec.max_episode_steps is not None else max_episode_steps
    kwargs = {key: _plain(value) for key, value in spec.kwargs.items()}
    return dataclasses.replace(spec, kwargs=kwargs, max_episode_steps=steps)


def action_space(model: SDJLSModel, action_bound: float | np.ndarray) -> spaces.Box:
    """The Box ``|u_i| <= action_bound`` of float32.

    Raises
    ------
    TypeError
        ``action_bound`` is not a number or an array of numbers.
    ValueError
        A bound is not positive, or not a normal float32 number (above 3.4e38 the Box would be
        infinite; below 1.2e-38 it would round to a subnormal number or to zero).
    """
    bound = check_float32_bound(
        "action_bound", action_bound, size=model.m, what="bound(s) on |u_i| of the float32 Box"
    ).astype(np.float32)
    return spaces.Box(-bound, bound, dtype=np.float32)


def _check_render_mode(render_mode: Any) -> str | None:
    if render_mode is None:
        return None
    if isinstance(render_mode, str) and render_mode == "human":
        raise ValueError(
            'render_mode = "human" is not supported: the picture is drawn off-screen with '
            'matplotlib. Use render_mode="rgb_array": env.render() returns the frame as an '
            "array, and gymnasium.wrappers.RecordVideo saves episodes as video"
        )
    return check_choice("render_mode", render_mode, SDJLSEnv.metadata["render_modes"])


def make_env(**kwargs: Any) -> SDJLSEnv:
    """The entry point of the registered ids: ``SDJLSEnv(**kwargs)``.

    A function rather than the class so that ``gym.make`` hands ``render_mode`` to the
    constructor unchanged: for a class whose ``metadata`` lists ``"rgb_array"`` but not
    ``"human"``, ``gym.make`` replaces ``render_mode="human"`` by ``"rgb_array"`` and adds
    Gymnasium's pygame ``HumanRendering`` wrapper, which fails only at ``reset`` when pygame is
    missing. Through this function ``"human"`` is rejected at ``make``, with what to use instead.
    """
    return SDJLSEnv(**kwargs)


class SDJLSEnv(gym.Env[np.ndarray, np.ndarray]):
    r"""
    ## Description

    A discrete-time state-dependent jump linear system (SDJLS), the model of section 2 of
    Chitraganti et al., *On control of discrete-time state-dependent jump linear systems with
    probabilistic constraints: a receding horizon approach*:

    ```
    x_{k+1} = A_{θ_k} x_k + B_{θ_k} u_k + E_{θ_k} w_k,          w_k ~ N(0, W)
    θ_{k+1} ~ row θ_k of P_in   if G x_k <= H_k   (x_k in the region C1)
    θ_{k+1} ~ row θ_k of P_out  otherwise                       H_k = H0 + k · H_rate
    ```

    The mode θ_k (0-based) is observed by default; with `observe="state"` it is hidden (see
    Observation Space). The region `G x <= H_k` is also the constraint the controller should
    keep the state in; violations are reported on the info channel.

    ## Time indexing

    `reset()` returns the observation of `(x_0, θ_0, k = 0)`. The `k`-th call of `step(u_k)`
    (k = 0, 1, ...) draws `w_k`, sets `x_{k+1}`, draws `θ_{k+1}` using the region test on
    `x_k` at time `k`, and returns the observation and the info of `(x_{k+1}, θ_{k+1}, k+1)`
    together with the reward of the pair `(x_k, u_k)`. An episode has `horizon` steps: it is
    truncated when `k + 1 = horizon`, so the last state is `x_T`.

    ## Action Space

    `Box(-action_bound, action_bound, (m,), float32)`: the input `u_k`.

    | Num | Action | Min | Max |
    |-----|--------|-----|-----|
    | i   | u_k(i) | -action_bound[i] | action_bound[i] |

    Finite actions outside the box are clipped to it (the clipped action is used for the
    dynamics and the reward and returned as `info["u"]`). An action of the wrong shape or
    with NaN or inf raises `ValueError`.

    ## Observation Space

    With `observe="mode"` (the default), `Box((n + N + 1,), float32)`:

    | Index | Observation | Min | Max |
    |-------|-------------|-----|-----|
    | 0 .. n-1 | x_k, clipped to ±divergence_bound | -divergence_bound | divergence_bound |
    | n .. n+N-1 | one-hot of θ_k | 0 | 1 |
    | n+N | k / horizon (the band moves with k) | 0 | 1 |

    With `observe="state"` (the mode is hidden), `Box((n + 1,), float32)`:

    | Index | Observation | Min | Max |
    |-------|-------------|-----|-----|
    | 0 .. n-1 | x_k, clipped to ±divergence_bound | -divergence_bound | divergence_bound |
    | n | k / horizon | 0 | 1 |

    The exact float64 state is `info["state"]`. A diverged state shows at the bound (an
    infinite entry at ±divergence_bound), so observations stay inside the space. The layouts
    are `sdjls_gym.observation`'s. In the hidden setting the state is observed exactly, so
    the belief of the mode given the states and inputs is finite-dimensional:
    `controllers.ModeFilter` computes it.

    ## Rewards

    `reward = -(x_k' Q_{θ_k} x_k + u_k' R_{θ_k} u_k)`, a Python float: the negative stage cost
    of the state the action was applied in. Always finite: a stage cost that overflows float64
    is reported as the largest float (`sys.float_info.max`) and ends the episode as diverged.

    ## Info

    At reset and at every step, describing the new state `(x_{k+1}, θ_{k+1}, k+1)`:

    | Key | Meaning |
    |-----|---------|
    | `state` | x (float64, exact) |
    | `mode` | θ (int): the true mode, also with `observe="state"`, for scoring only (a policy of the hidden setting must not read it, nor `env.unwrapped.mode`) |
    | `k` | time index of the new state |
    | `in_region` | whether `G x <= H_k` holds in every row (x in C1) |
    | `constraint_values` | `G x - H_k` (r,); positive means violated |
    | `violations` | `constraint_values > 0` (r,) bool (a NaN value counts as violated) |
    | `cost` | 1.0 if any row is violated, else 0.0 (Safety-Gymnasium convention) |
    | `stage_cost` | `x_k' Q x_k + u_k' R u_k` of the step (0.0 at reset) |
    | `u` | the applied (clipped) action, float64 (steps only) |
    | `diverged` | whether `max |x| > divergence_bound`, `x` is not finite, or the stage cost overflowed |

    ## Starting State

    `x_0 = model.x0` and `θ_0 = model.mode0` (or a draw from it, if it is a probability
    vector). `reset(options={"x0": ..., "mode0": ...})` overrides either.

    ## Episode End

    * Truncation: after `horizon` steps. The environment truncates by itself (the ids register
      no `TimeLimit`), and `env.spec.max_episode_steps` reports the horizon. `gym.make(...,
      max_episode_steps=M)` adds Gymnasium's `TimeLimit(M)` outside the environment, which
      only shortens episodes: with `M > horizon` they still end at the horizon while the
      wrapper's spec reports `M` (Gymnasium adds the wrapper out of the environment's sight,
      so this cannot be refused): pass `horizon=M` instead.
    * Termination: only on divergence, when `max |x_{k+1}| > divergence_bound`, when `x_{k+1}`
      is not finite, or when the stage cost overflows float64 (`info["diverged"] = True`).
      Rewards and observations stay finite. A step that overflows float64 reports the exact
      `x_{k+1}`, stage cost and constraint values rounded to float64 (±inf beyond its range,
      never NaN: `SDJLSModel.exact_transition`), the same as the vector environment.
    * After the end, `step()` raises `sdjls_gym.errors.ResetNeededError` (a
      `gymnasium.error.ResetNeeded` and a
      `RuntimeError`): call `reset()`. The vector environment resets by itself instead.

    ## Arguments

    * `model` (required): an `SDJLSModel`, a preset name (`"macro"`) or a `to_dict()` dict. In
      `env.spec` a model object is stored as its `to_dict()`, so `env.spec.to_json()` and
      `gym.make(env.spec)` work.
    * `horizon`: episode length T (default 20), an int >= 1. `gym.make("SDJLS-Macro-v0",
      horizon=40)` gives 40-step episodes.
    * `action_bound`: bound on |u_i|, float or (m,) (default 200.0); it must be a normal
      float32 number (1.2e-38 to 3.4e38), since the action Box is float32.
    * `divergence_bound`: termination threshold on max |x| (default 1e6, at most 1e30).
    * `render_mode`: `None` or `"rgb_array"`: `render()` returns a matplotlib picture of the
      episode so far, `(400, 640, 3) uint8` (see `sdjls_gym.render`); record videos with
      `gymnasium.wrappers.RecordVideo`. `"human"` is rejected (`ValueError`). The picture
      shows the true mode in either setting of `observe`.
    * `observe`: `"mode"` (default: the observation shows θ_k) or `"state"` (it shows `x_k`
      and `k / horizon` only; see Observation Space). Every registered id accepts it:
      `gym.make("SDJLS-Solar-v0", observe="state")`. Another value is a `ValueError` naming
      `observe`.

    ```python
    import gymnasium as gym
    import sdjls_gym  # registers the ids
    env = gym.make("SDJLS-Macro-v0")
    env = gym.make("SDJLS-v0", model=my_model, horizon=40)
    env = gym.make("SDJLS-Macro-v0", observe="state")  # the mode hidden
    ```

    ## Version History

    * v0: Initial version.
    * v0: `observe="state"` added (the mode hidden); the default, `observe="mode"`, keeps the
      observation of the initial version, so the version is unchanged.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    _spec: EnvSpec | None = None

    def __init__(
        self,
        model: SDJLSModel | str | dict | None = None,
        horizon: int = 20,
        action_bound: float | np.ndarray = 200.0,
        divergence_bound: float = 1e6,
        render_mode: str | None = None,
        observe: str = "mode",
    ) -> None:
        self.model = resolve_model(model)
        self.horizon = check_int("horizon", horizon, low=1)
        self.divergence_bound = check_divergence_bound(divergence_bound)
        check_model_x0(self.model, self.divergence_bound)
        self.render_mode = _check_render_mode(render_mode)
        self.observe = check_observe(observe)
        self.action_space = action_space(self.model, action_bound)
        self.observation_space = observation_space(self.model, self.divergence_bound, self.observe)
        self._low = self.action_space.low.astype(np.float64)
        self._action_what = f"the input u_k, {self.model.m} finite number(s)"  # for step's errors
        self._high = self.action_space.high.astype(np.float64)
        self._low_list, self._high_list = self._low.tolist(), self._high.tolist()
        self._params = EnvParams(
            self.model,
            self.horizon,
            self.divergence_bound,
            may_overflow(self.model, self._high, self.divergence_bound, self.horizon),
        )
        self._x: np.ndarray | None = None
        self._mode = 0
        self._k = 0
        self._inside = True  # the region test of the current state, reused by step()
        self._ended: str | None = None  # why the episode ended, until the next reset()
        self._history: list[tuple[np.ndarray, int]] = []
        self._renderer: EpisodeRenderer | None = None  # render()'s figure, built on first use

    # ------------------------------------------------------------------ spec
    @property
    def spec(self) -> EnvSpec | None:
        """The ``EnvSpec`` that ``gymnasium.make`` set, with ``max_episode_steps = horizon``
        (the environment truncates by itself) and JSON-friendly kwargs (see :func:`own_spec`).

        ``gymnasium.make(..., max_episode_steps=M)`` wraps the environment in its ``TimeLimit``
        after setting this spec (with ``max_episode_steps=None``): the limit never reaches the
        environment, so an ``M`` above the horizon cannot be refused here. Episodes still end
        at the horizon; the ``TimeLimit``'s spec reports ``M``: pass ``horizon=M`` instead.
        """
        return self._spec

    @spec.setter
    def spec(self, value: EnvSpec | None) -> None:
        self._spec = own_spec(value, self.horizon, self.model)

    # ------------------------------------------------------------------ current state
    @property
    def state(self) -> np.ndarray:
        """The current state ``x_k`` (float64 copy)."""
        if self._x is None:
            raise RuntimeError("call reset() before reading the state")
        return self._x.copy()

    @property
    def mode(self) -> int:
        """The current mode ``theta_k`` (the true one, also with ``observe="state"``: for
        scoring, not for a policy of the hidden setting)."""
        return self._mode

    @property
    def k(self) -> int:
        """The current time index ``k``."""
        return self._k

    # ------------------------------------------------------------------ Gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=check_seed(seed))
        model = self.model
        x0, mode0 = parse_reset_options(model, options, self.divergence_bound)
        self._x = x = model.x0.copy() if x0 is None else x0
        self._mode = mode = model.sample_mode0(self.np_random) if mode0 is None else mode0
        self._k = 0
        self._ended = None
        self._history = [(x.copy(), mode)]
        with np.errstate(over="ignore", invalid="ignore"):
            info = functional.step_info(model, x, mode, 0, 0.0, False)
        self._inside = info["in_region"]
        obs = encode_observation(
            model, x, mode, 0, self.horizon, self.divergence_bound, self.observe
        )
        return obs, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._ended is not None or self._x is None:
            raise ResetNeededError(
                f"step() called after the episode ended ({self._ended}); call reset() to start "
                "a new one"
                if self._ended is not None
                else "call reset() before step()"
            )
        model = self.model
        m = model.m
        u = check_numbers("action", action, what=self._action_what)
        if u.shape != (m,):
            if u.size != m or u.ndim > 1:
                raise ValueError(f"action has shape {u.shape}; expected ({m},), the input u_k")
            u = u.reshape(m)
        # finiteness and bounds in plain Python: for a few numbers it beats numpy's reductions
        inside_box = True
        for v, lo, hi in zip(u.tolist(), self._low_list, self._high_list, strict=True):
            if not math.isfinite(v):
                raise ValueError(f"action = {u} contains NaN or inf; expected finite numbers")
            inside_box = inside_box and lo <= v <= hi
        if not inside_box:
            u = np.clip(u, self._low, self._high)  # finite actions outside the Box are clipped

        rng = self.np_random
        w = model.sample_noise(rng)
        x, mode, k, cost, values, diverged = functional.step(
            self._params, self._x, self._mode, self._k, u, w, rng.random(), self._inside
        )
        self._x, self._mode, self._k = x, mode, k
        if self.render_mode is not None:
            self._history.append((x, mode))
        info = functional.step_info(model, x, mode, k, cost, diverged, values)
        info["u"] = u
        self._inside = info["in_region"]
        truncated = k >= self.horizon
        if diverged or truncated:
            self._ended = (
                f"terminated: diverged at k = {k}"
                if diverged
                else f"truncated at k = {k} = horizon"
            )
        obs = encode_observation(
            model, x, mode, k, self.horizon, self.divergence_bound, self.observe
        )
        return obs, -cost, diverged, truncated, info

    def _get_renderer(self) -> EpisodeRenderer:
        if self._renderer is None:
            from sdjls_gym.render import EpisodeRenderer

            self._renderer = EpisodeRenderer(self.model, self.horizon, self.divergence_bound)
        return self._renderer

    def render(self) -> np.ndarray | None:
        """The picture of the episode so far (see :mod:`sdjls_gym.render`).

        Returns
        -------
        (400, 640, 3) uint8 RGB image with ``render_mode="rgb_array"``; None without a
        render mode. One figure per env is reused from frame to frame.
        """
        if self.render_mode is None:
            gym.logger.warn('render() needs render_mode="rgb_array" at construction')
            return None
        if self._x is None:
            raise RuntimeError("call reset() before render()")
        xs = np.array([x for x, _ in self._history])
        modes = np.array([mode for _, mode in self._history], dtype=np.int64)
        return self._get_renderer().frame(xs, modes)

    def close(self) -> None:
        """Free the picture's figure."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()
