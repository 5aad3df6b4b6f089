"""``HiddenModePolicy``: a controller on a hidden mode, with the mode's filter kept per episode.

A controller decides from ``(x_k, belief or mode, k)`` and keeps nothing between decisions; with
the mode hidden (``observe="state"``) something must keep the belief of ``theta_k`` across the
steps of an episode. :class:`HiddenModePolicy` holds one belief per episode of a batch, steps it
with :meth:`controllers.ModeFilter.step_batch` from each row's previous state and input to its
new state, and hands the controller either the belief (``rule="belief"``, for a
:class:`controllers.BeliefRecedingHorizonController`) or its most probable mode
(``rule="most_probable"``: certainty equivalence, for any controller that takes a mode, e.g. a
:class:`controllers.RecedingHorizonController`; ties go to the smallest index).

Rules of the memory:

* a row at ``k == 0`` starts an episode: its belief is the prior (the model's ``mode0``, or
  ``prior``), whatever the row held;
* a row at ``k > 0`` must follow the row's previous call at ``k - 1``: the filter steps from
  that call's state with the input applied then (``u_applied``, e.g. the environment's
  ``info["u"]``, clipped to its action box; the inputs this policy returned when None);
* a row whose new state no mode of positive belief can produce
  (:class:`~sdjls_gym.errors.ImpossibleObservationError`, e.g. a diverged episode whose state
  the caller replaced) starts again from the prior; ``info["filter_resets"]`` counts those rows
  and ``info["filter_reset"]`` marks them. The belief is never NaN.

:meth:`HiddenModePolicy.predict` is stable-baselines3's recurrent signature on the state-only
observations ``[x, k / horizon]``: the filter's memory travels in ``state``, so a plain
Gymnasium loop or SB3's ``evaluate_policy`` can run it.

Not thread-safe: the memory of the episodes changes at every call (one policy per rollout);
``predict`` with an explicit ``state`` reads and writes only that state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sdjls_gym.errors import ImpossibleObservationError
from sdjls_gym.messages import a_type, describe
from sdjls_gym.observation import decode_observation
from sdjls_gym.validation import (
    check_array,
    check_choice,
    check_int,
    check_int_array,
    check_optional_int,
)

from .base import ENV_DEFAULT_HORIZON, Controller
from .belief import BeliefRecedingHorizonController
from .mode_filter import ModeFilter

__all__ = ["RULES", "FilterMemory", "HiddenModePolicy"]

#: The decision rules: the belief itself, or its most probable mode (certainty equivalence).
RULES = ("belief", "most_probable")

#: How far ``k / horizon * horizon`` may be from an integer (float32 rounding).
_TIME_TOL = 1e-3


@dataclass(frozen=True, eq=False)
class FilterMemory:
    """The memory of a batch of episodes (the ``state`` of :meth:`HiddenModePolicy.predict`).

    Attributes
    ----------
    log_belief : (B, N)
        The logarithm of each row's belief of ``theta_k`` at its last call (-inf: zero).
    x : (B, n)
        Each row's state at its last call.
    u : (B, m)
        The input applied after it (the policy's own answer unless the caller said otherwise).
    k : (B,) int
        The time of the last call; -1 for a row that has none yet.
    """

    log_belief: np.ndarray
    x: np.ndarray
    u: np.ndarray
    k: np.ndarray


class HiddenModePolicy:
    """A controller run on a hidden mode: the filter's belief per episode, then a decision.

    Parameters
    ----------
    controller : Controller
        A :class:`controllers.BeliefRecedingHorizonController` (``rule="belief"`` by default)
        or any controller that takes a mode (``act_batch(x, mode, k)``, e.g. a
        :class:`controllers.RecedingHorizonController`; ``rule="most_probable"``).
    rule : {"belief", "most_probable"}, optional
        The controller's input: the belief, or the index of its largest entry (ties: the
        smallest). Default: ``"belief"`` for a belief controller, else ``"most_probable"``.
    prior : (N,) array, optional
        The belief of ``theta_0`` (default: the model's ``mode0``).
    horizon : int, optional
        The environment's episode length, to decode ``k / horizon`` in :meth:`predict`
        (default: the controller's ``horizon``, else the environments' default, 20).
    action_bound : float or (m,) array, optional
        The environment's action bound: :meth:`predict` clips its actions to it, so that the
        input the filter uses is the one applied. None: no clipping.

    Attributes
    ----------
    controller, rule, mode_filter (:class:`controllers.ModeFilter`), prior (N,), horizon
    filter_resets : int
        Rows started again from the prior after an impossible observation, since construction.

    Examples
    --------
    >>> import numpy as np
    >>> from controllers import BeliefRecedingHorizonController, HiddenModePolicy
    >>> from sdjls_gym.systems.macro import macro, PAPER_K, PAPER_RHC
    >>> policy = HiddenModePolicy(BeliefRecedingHorizonController(macro(), PAPER_K, **PAPER_RHC))
    >>> beliefs = policy.reset(2)  # two episodes at their prior, mode0 = 0
    >>> u, info = policy.act_hidden(np.array([[2.0, 2.0], [2.0, 3.0]]), np.array([0, 0]))
    >>> info["belief"].tolist(), info["ok"].tolist()
    ([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [True, True])
    """

    def __init__(
        self,
        controller: Controller,
        *,
        rule: str | None = None,
        prior: Any = None,
        horizon: int | None = None,
        action_bound: Any = None,
    ) -> None:
        if not isinstance(controller, Controller):
            raise TypeError(
                f"controller = {describe(controller, 60)} is {a_type(controller)}; expected a "
                "controllers.Controller (e.g. BeliefRecedingHorizonController or "
                "RecedingHorizonController)"
            )
        takes_belief = isinstance(controller, BeliefRecedingHorizonController)
        if rule is None:
            rule = "belief" if takes_belief else "most_probable"
        self.rule = check_choice("rule", rule, RULES)
        if self.rule == "belief" and not takes_belief:
            raise ValueError(
                f"rule = 'belief' needs a controller that decides from a belief "
                f"(BeliefRecedingHorizonController); {type(controller).__name__} takes a mode: "
                "use rule='most_probable'"
            )
        self.controller = controller
        self.model = controller.model
        self.mode_filter = ModeFilter(self.model)
        self.prior = self.mode_filter.initial_belief(prior)
        with np.errstate(divide="ignore"):
            self._log_prior = np.log(self.prior)
        self.horizon = check_optional_int("horizon", horizon, low=1, what="episode length")
        if self.horizon is None:
            self.horizon = controller.horizon
        self.action_bound = None
        if action_bound is not None:
            bound = check_array("action_bound", action_bound, what="the environment's action bound")
            bound = np.broadcast_to(bound, (self.model.m,)).astype(np.float32)
            if not np.all(bound > 0):
                raise ValueError(f"action_bound = {describe(bound)} must be positive")
            self.action_bound = bound.astype(np.float64)
        self.filter_resets = 0
        self._memory: FilterMemory | None = None

    # ------------------------------------------------------------------ episodes
    def reset(self, batch: int) -> np.ndarray:
        """Start ``batch`` episodes at their prior; returns the beliefs (batch, N)."""
        batch = check_int("batch", batch, low=1, what="the number of episodes")
        self._memory = self._fresh(batch)
        return np.tile(self.prior, (batch, 1))

    def _fresh(self, batch: int) -> FilterMemory:
        model = self.model
        return FilterMemory(
            np.tile(self._log_prior, (batch, 1)),
            np.zeros((batch, model.n)),
            np.zeros((batch, model.m)),
            np.full(batch, -1, dtype=np.int64),
        )

    def act_hidden(
        self, x: Any, k: Any, u_applied: Any = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Decisions for a batch of episodes whose modes are hidden.

        Parameters
        ----------
        x : (B, n) array
            The states ``x_k``.
        k : (B,) int array or int
            Their times; ``k == 0`` starts the row's episode at the prior.
        u_applied : (B, m) array, optional
            The inputs applied at the rows' previous step (the environment's ``info["u"]``);
            None: the inputs this policy returned then. Unused for rows at ``k == 0``.

        Returns
        -------
        u : (B, m) float64 array
        info : dict
            The controller's info, ``"belief"`` (B, N) (the belief the decision used),
            ``"filter_reset"`` (B,) bool and ``"filter_resets"`` (int; see the module).

        Raises
        ------
        ValueError, TypeError
            Arguments of the wrong shape or value (named); a row at ``k > 0`` that does not
            follow a call at ``k - 1``.

        Notes
        -----
        A policy that holds no episodes, or another number of them, starts ``B`` episodes
        (as :meth:`reset`) when every row is at ``k == 0``.
        """
        model = self.model
        x = check_array("x", x, shape=(None, model.n), what="the states x_k, one per row")
        B = x.shape[0]
        times = check_int_array("k", k, low=0)
        times = np.broadcast_to(times, (B,)).astype(np.int64) if times.ndim == 0 else times
        if times.shape != (B,):
            raise ValueError(f"k has shape {times.shape}; expected ({B},) to match x")
        memory = self._memory
        if memory is None or memory.k.shape[0] != B:
            if np.any(times != 0):
                held = "no episodes" if memory is None else f"{memory.k.shape[0]} episodes"
                raise ValueError(
                    f"x has {B} rows but the policy holds {held}; call reset({B}) at the "
                    "episodes' start (rows at k == 0)"
                )
            memory = self._fresh(B)
        if u_applied is not None:
            u_applied = check_array(
                "u_applied", u_applied, shape=(B, model.m), what="the inputs applied, one per row"
            )
        u, info, self._memory = self._step(memory, x, times, u_applied)
        return u, info

    def act(self, x: Any, k: Any, u_applied: Any = None) -> tuple[np.ndarray, dict[str, Any]]:
        """:meth:`act_hidden` for one episode: ``x`` (n,), ``k`` an int, ``u_applied`` (m,)
        or None; returns ``u`` (m,) and the info of the row (``"belief"`` (N,))."""
        x = check_array("x", x, shape=(self.model.n,), what="the state x_k")
        u_row = None
        if u_applied is not None:
            u_row = check_array("u_applied", u_applied, shape=(self.model.m,))[None]
        u, info = self.act_hidden(x[None], np.asarray([k]).reshape(1), u_row)
        row = {
            key: (value[0] if isinstance(value, np.ndarray) and value.ndim else value)
            for key, value in info.items()
        }
        return u[0], row

    # ------------------------------------------------------------------ the step
    def _step(
        self, memory: FilterMemory, x: np.ndarray, k: np.ndarray, u_applied: np.ndarray | None
    ) -> tuple[np.ndarray, dict[str, Any], FilterMemory]:
        """Beliefs of the rows (the prior at ``k == 0``, else a filter step), the decisions,
        and the new memory; ``memory`` is not changed."""
        log_belief = memory.log_belief.copy()
        start = k == 0
        log_belief[start] = self._log_prior
        moving = np.flatnonzero(~start)
        if moving.size:
            bad = memory.k[moving] != k[moving] - 1
            if bad.any():
                row = int(moving[np.flatnonzero(bad)[0]])
                last = int(memory.k[row])
                raise ValueError(
                    f"k[{row}] = {int(k[row])} does not follow the row's last call "
                    + ("(none)" if last < 0 else f"at k = {last}")
                    + "; a row at k > 0 must be called at every step of its episode, from k = 0"
                )
        reset = np.zeros(k.shape[0], dtype=bool)
        if moving.size:
            u_prev = memory.u if u_applied is None else u_applied
            log_belief[moving], failed = self._filter(
                log_belief[moving], memory.x[moving], u_prev[moving], x[moving], memory.k[moving]
            )
            reset[moving[failed]] = True
        count = int(reset.sum())
        self.filter_resets += count
        belief = np.exp(log_belief)
        belief /= belief.sum(axis=1, keepdims=True)
        if self.rule == "belief":
            u, info = self.controller.act_batch(x, belief, k)
        else:
            top = np.argmax(belief, axis=1)  # the first largest: ties to the smallest index
            if isinstance(self.controller, BeliefRecedingHorizonController):
                u, info = self.controller.act_batch(x, np.eye(self.model.N)[top], k)
            else:
                u, info = self.controller.act_batch(x, top, k)
        out: dict[str, Any] = {**info, "belief": belief, "filter_reset": reset}
        out["filter_resets"] = count
        u = np.asarray(u, dtype=np.float64)
        return u, out, FilterMemory(log_belief, x.copy(), u.copy(), k.copy())

    def _filter(
        self,
        log_belief: np.ndarray,
        x: np.ndarray,
        u: np.ndarray,
        x_next: np.ndarray,
        k: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One filter step of the rows (logarithms); the rows whose observation is impossible
        go back to the prior. Returns the new log-beliefs and the mask of those rows."""
        step = self.mode_filter.step_batch
        try:
            return step(log_belief, x, u, x_next, k, log=True), np.zeros(k.shape[0], dtype=bool)
        except ImpossibleObservationError:
            pass
        out = np.empty_like(log_belief)
        failed = np.zeros(k.shape[0], dtype=bool)
        for i in range(k.shape[0]):  # rare: find the rows, one at a time
            try:
                out[i] = step(log_belief[i : i + 1], x[i : i + 1], u[i : i + 1],
                              x_next[i : i + 1], k[i : i + 1], log=True)[0]  # fmt: skip
            except ImpossibleObservationError:
                out[i], failed[i] = self._log_prior, True
        return out, failed

    # ------------------------------------------------------------------ observations
    def predict(
        self,
        observation: Any,
        state: FilterMemory | None = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, FilterMemory]:
        """Actions for state-only observations, in stable-baselines3's recurrent shape.

        Parameters
        ----------
        observation : (n + 1,) or (B, n + 1) array
            ``[x, k / horizon]`` of an environment made with ``observe="state"``.
        state : FilterMemory, optional
            The memory returned by the previous call (None: every row starts; its time must be
            0).
        episode_start : (B,) bool array, optional
            Rows that start an episode (their belief goes back to the prior; so does every row
            at ``k == 0``).
        deterministic : bool
            Accepted and ignored (the decisions are deterministic).

        Returns
        -------
        actions : (m,) or (B, m) float32 array
            Clipped to ``action_bound`` when it was given; the filter's next step uses them as
            the inputs applied.
        state : FilterMemory
            The memory to pass to the next call.
        """
        model = self.model
        obs = check_array("observation", observation, what="[x, k / horizon]")
        if obs.ndim not in (1, 2) or obs.shape[-1] != model.n + 1:
            raise ValueError(
                f"observation has shape {obs.shape}; expected ({model.n + 1},) or (batch, "
                f"{model.n + 1}): the state-only layout [x ({model.n}), k / horizon (1)] of an "
                "environment made with observe='state'"
            )
        rows = obs.reshape(-1, model.n + 1)
        B = rows.shape[0]
        horizon = self.horizon if self.horizon is not None else ENV_DEFAULT_HORIZON
        tau = rows[:, -1]
        scaled = tau * horizon
        bad = ~((tau >= 0.0) & (tau <= 1.0) & (np.abs(scaled - np.rint(scaled)) <= _TIME_TOL))
        if np.any(bad):
            raise ValueError(
                f"observation's time entry k / horizon = {float(tau[bad][0]):.6g} does not "
                f"decode to a time k in [0, {horizon}]; pass horizon= (the environment's episode "
                "length) to HiddenModePolicy"
            )
        x, _, k = decode_observation(model, rows, horizon, observe="state")
        if state is None and np.any(k > 0):
            row = int(np.flatnonzero(k > 0)[0])
            raise ValueError(
                f"state is None but observation row {row} is at k = {int(k[row])}: pass the "
                "state the previous predict returned (None only at the episodes' start)"
            )
        memory = state if state is not None else self._fresh(B)
        if not isinstance(memory, FilterMemory) or memory.k.shape[0] != B:
            raise ValueError(
                f"state = {describe(state, 60)} is not the FilterMemory of {B} rows that the "
                "previous predict returned; pass None at the start"
            )
        if episode_start is not None:
            starts = np.broadcast_to(np.asarray(episode_start, dtype=bool), (B,))
            if starts.any():
                k_mem = memory.k.copy()
                k_mem[starts] = -1
                memory = FilterMemory(memory.log_belief, memory.x, memory.u, k_mem)
        u, _, memory = self._step(memory, np.asarray(x, dtype=np.float64), np.asarray(k), None)
        if self.action_bound is not None:
            u = np.clip(u, -self.action_bound, self.action_bound)
        actions = u.astype(np.float32)
        memory = FilterMemory(memory.log_belief, memory.x, actions.astype(np.float64), memory.k)
        return (actions[0] if obs.ndim == 1 else actions), memory
