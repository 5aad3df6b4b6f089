"""Write ``env_episodes.json``: seeded episodes of both environments, replayed bit for bit by
``tests/test_env_episodes.py``.

The committed file was written by this script at commit b99c1a1 (before the environments'
step, observation and info were folded into ``sdjls_gym.functional``), so the test checks the
refactored code against the numbers of the code before it. Run from the repository root with
``python tests/data/make_env_episodes.py``; regenerate only when a change of the numbers is
intended, and say so in the commit message.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import sdjls_gym  # noqa: E402
from sdjls_gym import SDJLSEnv, SDJLSModel, SDJLSVectorEnv  # noqa: E402
from sdjls_gym.systems.macro import PAPER_K  # noqa: E402

OUT = Path(__file__).with_name("env_episodes.json")


def blowup_model(A: Any, Q: Any = None, x0: Any = (1e6, 1e6)) -> dict[str, Any]:
    """One mode, W = 0: x_1 = A x_0 exactly, entries near 1e303 (tests/conftest.py's noiseless_model)."""
    return SDJLSModel(
        A=[A], B=[[0.0], [1.0]], P_in=[[1.0]], P_out=[[1.0]], G=[[0.0, 1.0]], H0=[1e9],
        Q=np.eye(2) if Q is None else Q, R=[[1.0]], x0=list(x0), W=np.zeros((2, 2)),
    ).to_dict()  # fmt: skip


#: (name, kind, constructor, kwargs, seed, action seed, action scale (times the bound), steps);
#: the macro cases act with the paper's gains plus noise (u = K_theta x + noise), the others
#: with noise alone (the "diverges" cases too: their income leaves a box of 100)
CASES: list[tuple[str, str, str, dict[str, Any], int, int, float, int]] = [
    ("macro", "single", "SDJLS-Macro-v0", {}, 0, 100, 0.05, 20),
    ("macro-seed-1", "single", "SDJLS-Macro-v0", {}, 1, 101, 0.3, 20),
    ("macro-diverges", "single", "SDJLS-Macro-v0", {"divergence_bound": 100.0}, 2, 102, 0.0, 20),
    ("vtol", "single", "SDJLS-VTOL-v0", {}, 3, 103, 0.5, 60),
    ("three-state", "single", "SDJLS-ThreeState-v0", {}, 4, 104, 0.5, 30),
    ("solar", "single", "SDJLS-Solar-v0", {}, 5, 105, 0.5, 30),
    ("random", "single", "SDJLS-Random-v0", {"n": 4, "system_seed": 3}, 6, 106, 0.5, 30),
    ("macro", "vector", "SDJLS-Macro-v0", {"num_envs": 5}, 7, 107, 0.05, 45),
    ("macro-diverges", "vector", "SDJLS-Macro-v0", {"num_envs": 4, "divergence_bound": 100.0},
     8, 108, 0.05, 30),
    ("vtol", "vector", "SDJLS-VTOL-v0", {"num_envs": 2}, 9, 109, 0.5, 62),
    ("three-state", "vector", "SDJLS-ThreeState-v0", {"num_envs": 4, "horizon": 7},
     10, 110, 0.5, 30),
]  # fmt: skip
# steps that overflow float64 (exact answers), in both environments
for _name, _model in {
    "nan-state": blowup_model([[1e303, -2e303], [1e303, -2e303]]),
    "inf-state": blowup_model([[1e303, 0.0], [0.0, 1e303]]),
    "cost-overflow": blowup_model(np.zeros((2, 2)), Q=1e300 * np.eye(2)),
    "cost-nan": blowup_model(np.zeros((2, 2)), Q=1e300 * np.ones((2, 2)), x0=(0.0, 1e10)),
}.items():
    _kwargs = {"model": _model, "horizon": 5, "divergence_bound": 1e30}
    CASES.append((_name, "single", "SDJLSEnv", _kwargs, 11, 111, 0.5, 5))
    CASES.append((_name, "vector", "SDJLSVectorEnv", {**_kwargs, "num_envs": 3}, 12, 112, 0.5, 4))


def make(kind: str, constructor: str, kwargs: dict[str, Any]) -> Any:
    """The environment of a case (unwrapped: the ids' default wrappers change nothing here)."""
    if constructor == "SDJLSEnv":
        return SDJLSEnv(**kwargs)
    if constructor == "SDJLSVectorEnv":
        return SDJLSVectorEnv(**kwargs)
    if kind == "single":
        return gym.make(constructor, **kwargs).unwrapped
    num_envs = kwargs.pop("num_envs")
    return gym.make_vec(
        constructor, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs
    )


def plain(value: Any) -> Any:
    """JSON form: arrays as nested lists (floats exact through repr), numpy scalars as Python."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def types(info: dict[str, Any]) -> dict[str, str]:
    return {key: type(value).__name__ for key, value in info.items()}


def run(case: tuple) -> dict[str, Any]:
    name, kind, constructor, kwargs, seed, action_seed, scale, steps = case
    env = make(kind, constructor, dict(kwargs))
    space = env.action_space
    arng = np.random.default_rng(action_seed)
    obs, info = env.reset(seed=seed)
    record: dict[str, Any] = {
        "name": name,
        "kind": kind,
        "constructor": constructor,
        "kwargs": kwargs,
        "seed": seed,
        "reset": {"obs": plain(obs), "info": {k: plain(v) for k, v in info.items()}},
        "reset_types": types(info),
        "steps": [],
    }
    for _ in range(steps):
        action = arng.normal(0.0, 1.0, space.shape) * scale * space.high
        if constructor == "SDJLS-Macro-v0" and "diverges" not in name:
            x, mode = np.asarray(info["state"]), np.asarray(info["mode"])
            action = action + np.einsum("...ij,...j->...i", PAPER_K[mode], x)
        action = action.astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        record["steps"].append(
            {
                "action": plain(action),
                "obs": plain(obs),
                "reward": plain(reward),
                "terminated": plain(terminated),
                "truncated": plain(truncated),
                "info": {k: plain(v) for k, v in info.items()},
                "types": types(info) if kind == "single" else None,
                "reward_type": type(reward).__name__,
            }
        )
        if kind == "single" and (terminated or truncated):
            break
    return record


def main() -> None:
    with np.errstate(all="raise"):  # as the test suite: no numpy warning on any path
        records = [run(case) for case in CASES]
    OUT.write_text(json.dumps({"sdjls_gym": sdjls_gym.__version__, "cases": records}) + "\n")
    print(f"wrote {OUT} ({len(records)} cases)")


if __name__ == "__main__":
    main()
