"""Seeded episodes of both environments replay bit for bit.

``tests/data/env_episodes.json`` holds episodes recorded by ``tests/data/make_env_episodes.py``
on the code before the environments' step, observation and info were folded into one set of
functions (``sdjls_gym.functional``): the paper's example, four suite tasks, a diverging
episode and four steps that overflow float64, in ``SDJLSEnv`` and ``SDJLSVectorEnv`` (with
autoresets). The same seeds and actions must give the same observations, rewards, ends and
infos, bit for bit, with the same Python types in the single environment's info.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.data.make_env_episodes import make

DATA = json.loads((Path(__file__).parent / "data" / "env_episodes.json").read_text())
CASES = {f"{c['kind']}-{c['name']}": c for c in DATA["cases"]}


def same(actual, expected, what: str) -> None:
    """Equal bit for bit (NaN equal to NaN; -0.0 and 0.0 told apart), with the same shape."""
    a = np.asarray(actual)
    e = np.asarray(expected, dtype=a.dtype if a.dtype != object else None)
    assert a.shape == e.shape, f"{what}: shape {a.shape} != {e.shape}"
    if a.dtype.kind == "f":
        assert np.array_equal(a, e, equal_nan=True), f"{what}: {a} != {e}"
        assert np.array_equal(np.signbit(a), np.signbit(e)), f"{what}: signs differ"
    else:
        assert np.array_equal(a, e), f"{what}: {a} != {e}"


def same_info(info: dict, expected: dict, what: str) -> None:
    assert sorted(info) == sorted(expected), f"{what}: keys {sorted(info)}"
    for key, value in expected.items():
        same(info[key], value, f"{what} info[{key!r}]")


@pytest.mark.parametrize("name", list(CASES))
def test_seeded_episode_replays_bit_for_bit(name):
    case = CASES[name]
    single = case["kind"] == "single"
    env = make(case["kind"], case["constructor"], dict(case["kwargs"]))
    dtype = env.action_space.dtype
    obs, info = env.reset(seed=case["seed"])
    same(obs, case["reset"]["obs"], "reset obs")
    same_info(info, case["reset"]["info"], "reset")
    if single:
        assert {k: type(v).__name__ for k, v in info.items()} == case["reset_types"]
    for t, step in enumerate(case["steps"]):
        obs, reward, terminated, truncated, info = env.step(np.array(step["action"], dtype=dtype))
        what = f"step {t}"
        assert obs.dtype == np.float32
        same(obs, step["obs"], f"{what} obs")
        same(reward, step["reward"], f"{what} reward")
        same(terminated, step["terminated"], f"{what} terminated")
        same(truncated, step["truncated"], f"{what} truncated")
        same_info(info, step["info"], what)
        assert type(reward).__name__ == step["reward_type"]
        if single:
            assert {k: type(v).__name__ for k, v in info.items()} == step["types"]
