"""Seeded episodes of both environments replay the recorded ones.

``tests/data/env_episodes.json`` holds episodes recorded by ``tests/data/make_env_episodes.py``
on the code before the environments' step, observation and info were folded into one set of
functions (``sdjls_gym.functional``): the paper's example, four suite tasks, a diverging
episode and four steps that overflow float64, in ``SDJLSEnv`` and ``SDJLSVectorEnv`` (with
autoresets). The same seeds and actions must give the same observations, rewards, ends and
infos, with the same Python types in the single environment's info.

Bit for bit only on one machine: numpy and OpenBLAS choose their SIMD kernels by CPU, which
changes the last bits of the products (recorded on one x86_64 machine, replayed on an AVX-512
one: up to 1e-12 of the array's largest entry after 20-62 steps, 2e-10 of its own size on a
constraint value near 0). So against the recording, every discrete outcome
(modes, ends, violation flags, which entries are NaN or infinite, the sign of a zero) is exact
and every finite float within :data:`RTOL` of its array's largest entry; replayed twice on the
same machine, episodes agree bit for bit.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.data.make_env_episodes import make

DATA = json.loads((Path(__file__).parent / "data" / "env_episodes.json").read_text())
CASES = {f"{c['kind']}-{c['name']}": c for c in DATA["cases"]}


#: Largest difference of a finite float from the recording, relative to its array's largest
#: entry: another machine's round-off (below 1e-12 on the AVX-512 machine), with a wide margin,
#: far below any change of the arithmetic.
RTOL = 1e-9


def same(actual, expected, what: str, exact: bool = False) -> None:
    """Equal with the same shape: non-finite entries and the signs of zeros exactly, finite
    floats within :data:`RTOL` of the array's largest entry (bit for bit with ``exact``)."""
    a = np.asarray(actual)
    e = np.asarray(expected, dtype=a.dtype if a.dtype != object else None)
    assert a.shape == e.shape, f"{what}: shape {a.shape} != {e.shape}"
    if a.dtype.kind != "f":
        assert np.array_equal(a, e), f"{what}: {a} != {e}"
        return
    if exact:
        assert np.array_equal(a, e, equal_nan=True), f"{what}: {a} != {e}"
        assert np.array_equal(np.signbit(a), np.signbit(e)), f"{what}: signs differ"
        return
    fa, fe = np.isfinite(a), np.isfinite(e)
    assert np.array_equal(fa, fe), f"{what}: non-finite entries differ: {a} != {e}"
    assert np.array_equal(a[~fa], e[~fe], equal_nan=True), f"{what}: {a} != {e}"
    zeros = (a == 0.0) & (e == 0.0)
    assert np.array_equal(np.signbit(a[zeros]), np.signbit(e[zeros])), f"{what}: signs differ"
    if fa.any():
        scale = float(np.max(np.abs(e[fe])))
        err = float(np.max(np.abs(a[fa] - e[fe])))
        assert err <= RTOL * scale, f"{what}: {a} != {e} (difference {err:.3g}, size {scale:.3g})"


def same_info(info: dict, expected: dict, what: str, exact: bool = False) -> None:
    assert sorted(info) == sorted(expected), f"{what}: keys {sorted(info)}"
    for key, value in expected.items():
        same(info[key], value, f"{what} info[{key!r}]", exact)


def _replay(case) -> list:
    """The reset and every step of a recorded case's seed and actions, in a new environment."""
    env = make(case["kind"], case["constructor"], dict(case["kwargs"]))
    dtype = env.action_space.dtype
    out = [env.reset(seed=case["seed"])]
    out += [env.step(np.array(step["action"], dtype=dtype)) for step in case["steps"]]
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_seeded_episode_replays_the_recording(name):
    case = CASES[name]
    single = case["kind"] == "single"
    (obs, info), *steps = _replay(case)
    same(obs, case["reset"]["obs"], "reset obs")
    same_info(info, case["reset"]["info"], "reset")
    if single:
        assert {k: type(v).__name__ for k, v in info.items()} == case["reset_types"]
    for t, (step, out) in enumerate(zip(case["steps"], steps, strict=True)):
        obs, reward, terminated, truncated, info = out
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


@pytest.mark.parametrize("name", list(CASES))
def test_seeded_episode_replays_bit_for_bit_on_one_machine(name):
    first, second = _replay(CASES[name]), _replay(CASES[name])
    assert len(first) == len(second) == len(CASES[name]["steps"]) + 1
    for t, (a, b) in enumerate(zip(first, second, strict=True)):
        *values, info = a
        *values2, info2 = b
        for i, (v, v2) in enumerate(zip(values, values2, strict=True)):
            same(v, v2, f"step {t - 1} item {i}", exact=True)
        same_info(info, info2, f"step {t - 1}", exact=True)
