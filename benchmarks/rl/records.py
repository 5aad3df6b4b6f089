"""What a kept RL run records: its learning curve, its dual ascent and its :class:`RunRecord`.

Plain records without stable-baselines3, so that the report and the loaders read kept runs with
the base install; :mod:`benchmarks.rl.train` makes them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

from benchmarks.core.files import jsonable
from benchmarks.rl.envs import MACRO

__all__ = ["CurvePoint", "DualPoint", "RunRecord"]


@dataclass(frozen=True)
class CurvePoint:
    """One learning-curve evaluation: the deterministic policy on the fixed curve episodes."""

    timesteps: int
    wall_s: float
    episode_cost_mean: float
    episode_cost_median: float
    violation: float
    diverged: int
    beta: float | None


@dataclass(frozen=True)
class DualPoint:
    """One dual-ascent update: the deterministic policy's frequency, the exploring policy's
    (``train_freq``, logged only) and the new ``beta``."""

    timesteps: int
    freq: float
    train_freq: float
    beta: float


@dataclass
class RunRecord:
    """What ``runs/<name>.json`` holds: one training, without its evaluation."""

    name: str
    algo: str
    variant: str
    seed: int
    fingerprint: str
    config: dict[str, Any]
    timesteps: int
    train_time_s: float  # the whole agent.learn, with the evaluations made during training
    wall_time_s: float
    final_beta: float | None
    learning_curve: list[CurvePoint]
    dual_ascent: list[DualPoint]
    cpu_time_s: float | None = None  # below the wall time when the training shared its core
    eval_time_s: float | None = None  # the learning curve's and the dual ascent's share
    kind: str = "rl-seed"
    task: str = MACRO  # the env id (runs kept before the suite are all on the macro task)

    @property
    def curve_episodes(self) -> int:
        return int(self.config["curve_episodes"])

    def to_json(self) -> dict[str, Any]:
        return jsonable(asdict(self))

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RunRecord:
        known = {f.name for f in fields(cls)}
        data = {k: v for k, v in data.items() if k in known}
        data["learning_curve"] = [CurvePoint(**p) for p in data["learning_curve"]]
        data["dual_ascent"] = [DualPoint(**p) for p in data["dual_ascent"]]
        return cls(**data)
