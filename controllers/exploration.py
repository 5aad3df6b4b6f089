"""``ExplorationPolicy``: linear feedback plus Gaussian input noise, to collect data for
:func:`controllers.identify`.

The feedback keeps the exploratory episodes bounded (a task's pre-stabilizing gains ``K``); the
noise excites the inputs independently of the state, without which least squares cannot tell
``A_i`` from ``B_i`` (the regressors ``[x_k, K_i x_k]`` have rank ``n``). An optional constant
offset moves the closed loop's resting point, e.g. into the region ``G x <= H_k`` when the
gains alone drive the state out of it, so that the jumps from inside are seen too.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sdjls_gym.messages import a_type, describe
from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import check_array

from .base import check_gain, frozen
from .baselines import _LinearPolicy

__all__ = ["ExplorationPolicy"]


class ExplorationPolicy(_LinearPolicy):
    """The exploration policy ``u_k = K_theta x_k + input_mean + input_std * eps_k``.

    ``eps_k ~ N(0, I_m)`` is drawn from ``rng``, independently at every call and for every row
    of a batch (``input_std`` multiplies it entrywise). The region ``G x <= H_k`` and the time
    ``k`` are not read.

    Parameters
    ----------
    model : SDJLSModel
        Gives the sizes ``N``, ``m``, ``n`` (and the weights of the reported stage cost); its
        dynamics are not read, so a template with placeholder matrices serves.
    K : (N, m, n) array
        Feedback gains, e.g. a task's pre-stabilizing ``task.K``.
    input_std : float or (m,) array
        Standard deviation of the input noise, >= 0 (0 gives the feedback alone, from which
        ``identify`` cannot separate ``A_i`` from ``B_i``).
    rng : numpy.random.Generator
        The source of the noise.
    input_mean : float or (m,) array, optional
        Constant offset added to the input (0 by default).
    horizon : int, optional
        Accepted for symmetry with the other controllers; unused (the decision does not depend
        on ``k``).

    Notes
    -----
    ``info["nu"]`` is the offset and the noise, ``u - K_theta x``. The draws are taken under the
    controller's lock: threads may share a policy and every draw is used once, in the order the
    calls take the lock. :meth:`predict` draws the noise whatever ``deterministic`` says (the
    policy exists to explore). A pickled or deep-copied policy carries a copy of ``rng``'s
    state, so the copy repeats the original's draws.

    Examples
    --------
    >>> import numpy as np
    >>> from sdjls_gym.systems.macro import macro, PAPER_K
    >>> policy = ExplorationPolicy(macro(), PAPER_K, 4.0, np.random.default_rng(0))
    >>> u, info = policy.act_batch(np.zeros((1000, 2)), np.zeros(1000, dtype=int), 0)
    >>> u.shape, bool(abs(u.std() - 4.0) < 0.5)
    ((1000, 1), True)
    """

    _status = "explore"

    def __init__(
        self,
        model: SDJLSModel,
        K: Any,
        input_std: Any,
        rng: np.random.Generator,
        *,
        input_mean: Any = 0.0,
        horizon: int | None = None,
    ) -> None:
        super().__init__(model, horizon)
        self.K = check_gain(self.model, K)
        self.input_std = _per_input(self.model, "input_std", input_std)
        if np.any(self.input_std < 0.0):
            raise ValueError(
                f"input_std = {describe(input_std)} has a negative entry; expected standard "
                "deviations >= 0"
            )
        self.input_mean = _per_input(self.model, "input_mean", input_mean)
        if not isinstance(rng, np.random.Generator):
            raise TypeError(
                f"rng = {describe(rng)} is {a_type(rng)}; expected a numpy.random.Generator "
                "(numpy.random.default_rng(seed))"
            )
        self.rng = rng

    def _offsets(self, size: int) -> np.ndarray:
        """``input_mean + input_std * eps`` (size, m), one noise draw per row."""
        with self._lock:
            eps = self.rng.standard_normal((size, self.model.m))
        return self.input_mean + self.input_std * eps


def _per_input(model: SDJLSModel, name: str, value: Any) -> np.ndarray:
    """A finite (m,) array from a number or an (m,) array (read-only)."""
    arr = check_array(name, value, what=f"a number or one per input, m = {model.m}")
    if arr.ndim == 0:
        arr = np.full(model.m, float(arr))
    if arr.shape != (model.m,):
        raise ValueError(
            f"{name} has shape {arr.shape}; expected a number or ({model.m},), one per input"
        )
    return frozen(arr)
