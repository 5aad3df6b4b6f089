"""``Task``: one environment of the suite with its model-based reference controller's data.

A task is what a benchmark needs to build the environment (``gym.make(task.env_id,
**task.env_kwargs)``) and the receding-horizon controller of the paper on it
(``RecedingHorizonController(task.model, task.K, horizon=task.horizon, **task.rhc)``, or
``ScenarioTreeController`` with the same keyword arguments).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any

import numpy as np

from sdjls_gym.dynamics import Sizes
from sdjls_gym.model import SDJLSModel

__all__ = ["Task"]


def _frozen_array(value: Any) -> np.ndarray:
    out = np.array(value, dtype=np.float64)
    out.setflags(write=False)
    return out


def _frozen_mapping(value: Mapping[str, Any], arrays: bool) -> Mapping[str, Any]:
    items = {}
    for key, item in dict(value).items():
        items[key] = (
            _frozen_array(item) if arrays and isinstance(item, (np.ndarray, list)) else item
        )
    return MappingProxyType(items)


def _model_size(name: str) -> property:
    """The model's size ``name`` (:class:`sdjls_gym.dynamics.Sizes`), with its docstring."""
    return property(lambda task: getattr(task.model, name), doc=getattr(Sizes, name).__doc__)


@dataclass(frozen=True, eq=False)
class Task:
    """A task of the suite: an SDJLS environment and its receding-horizon controller's data.

    Attributes
    ----------
    env_id : str
        The registered Gymnasium id, e.g. ``"SDJLS-Solar-v0"``.
    model : SDJLSModel
        The system (also ``gym.make(env_id, **env_kwargs).unwrapped.model``).
    horizon : int
        Episode length T.
    action_bound : float
        Bound on ``|u_i|`` of the environment's action Box.
    K : (N, m, n) ndarray
        Pre-stabilizing gains of ``u = K_theta x + nu`` (Proposition 2), read-only.
    rhc : Mapping[str, Any]
        Keyword arguments of ``RecedingHorizonController`` and ``ScenarioTreeController``
        besides the model, ``K`` and ``horizon``: ``Psi`` (N, n, n), ``xi``, ``constraint``,
        ``alpha``, ``nu_bound``. Read-only (``dict(task.rhc)`` for a copy to change).
    source : str
        Where the system's data come from (the module docstring says what was verified).
    env_kwargs : Mapping[str, Any]
        Keyword arguments that rebuild this task's environment with ``gym.make(env_id,
        **env_kwargs)``: empty for the fixed tasks, the generator's parameters for
        ``SDJLS-Random-v0``. Read-only.

    Notes
    -----
    Frozen and picklable; the arrays are read-only copies and the mappings read-only views,
    so a task cannot be changed by accident (build a new one with ``dataclasses.replace``).
    """

    env_id: str
    model: SDJLSModel
    horizon: int
    action_bound: float
    K: np.ndarray
    rhc: Mapping[str, Any]
    source: str
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.model, SDJLSModel):
            raise TypeError(f"model is a {type(self.model).__name__}; expected an SDJLSModel")
        K = _frozen_array(self.K)
        expected = (self.model.N, self.model.m, self.model.n)
        if K.shape != expected:
            raise ValueError(f"K has shape {K.shape}; expected {expected} = (N, m, n)")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "rhc", _frozen_mapping(self.rhc, arrays=True))
        object.__setattr__(self, "env_kwargs", _frozen_mapping(self.env_kwargs, arrays=False))

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        # mappingproxy does not pickle: rebuild from plain dicts
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values["rhc"], values["env_kwargs"] = dict(self.rhc), dict(self.env_kwargs)
        return (Task, tuple(values[f.name] for f in fields(self)))

    N = _model_size("N")
    n = _model_size("n")
    m = _model_size("m")
    r = _model_size("r")

    def __repr__(self) -> str:
        return (
            f"Task({self.env_id!r}, n={self.n}, m={self.m}, N={self.N}, r={self.r}, "
            f"horizon={self.horizon}, xi={self.rhc.get('xi')})"
        )
