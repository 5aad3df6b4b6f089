"""How the speed wing times: medians over repeats, rounds that alternate a measurement with its
reference (so both see the same machine load), and the closed-loop states the decisions are
timed on."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from sdjls_gym import SDJLSModel, SDJLSVectorEnv

__all__ = [
    "calls_block",
    "closed_loop_states",
    "cycling",
    "env_step_blocks",
    "median_time",
    "paired_times",
    "round_ratio",
    "timed_rounds",
]


def median_time(
    fn: Callable[[], Any],
    repeats: int,
    number: int,
    after_warmup: Callable[[], Any] | None = None,
) -> float:
    """Median over ``repeats`` of the mean time of ``number`` calls (after one warm-up round;
    ``after_warmup`` is called between the warm-up and the timed rounds, untimed)."""
    block = calls_block(fn, number)
    block()
    if after_warmup is not None:
        after_warmup()
    return statistics.median(block() for _ in range(repeats))


def env_step_blocks(env_id: str, episodes: int) -> Callable[[], float]:
    """A function that times ``episodes`` episodes of ``gym.make(env_id)`` (20 steps at most)
    and returns the mean time of one ``step`` (resets excluded)."""
    env = gym.make(env_id)
    shape = env.action_space.shape
    assert shape is not None  # the environments' action spaces are Boxes
    action = np.zeros(shape, dtype=np.float32) + 0.5
    env.reset(seed=0)
    T = 20

    def block() -> float:
        total, steps = 0.0, 0
        for _ in range(episodes):
            env.reset()
            t0 = time.perf_counter()
            for _ in range(T):
                steps += 1
                if any(env.step(action)[2:4]):  # ended (SDJLS envs raise on a step after that)
                    break
            total += time.perf_counter() - t0
        return total / steps

    return block


def paired_times(
    blocks: Sequence[Callable[[], float]],
    repeats: int,
    after_warmup: Callable[[], Any] | None = None,
) -> tuple[list[float], float]:
    """Time the ``blocks`` (each returns its own time per call) in turn, ``repeats`` rounds
    after a warm-up round: ``(medians, ratio)``, each block's median time and the median over
    the rounds of the first block's time over the second's. Interleaving puts both blocks of a
    ratio under the same load (two separate medians taken minutes apart on a shared machine
    moved a ratio from 1.4x to 3.2x between runs). ``after_warmup`` is called between the
    warm-up and the timed rounds, untimed."""
    rounds = timed_rounds(blocks, repeats, after_warmup)
    medians = [statistics.median(r[i] for r in rounds) for i in range(len(blocks))]
    return medians, round_ratio(rounds, 0, 1)


def timed_rounds(
    blocks: Sequence[Callable[[], float]],
    repeats: int,
    after_warmup: Callable[[], Any] | None = None,
) -> list[list[float]]:
    """The times of the ``blocks`` in ``repeats`` rounds, each round timing every block in
    turn, after a warm-up round (``after_warmup`` called after it, untimed)."""
    for block in blocks:
        block()
    if after_warmup is not None:
        after_warmup()
    return [[block() for block in blocks] for _ in range(repeats)]


def round_ratio(rounds: list[list[float]], i: int, j: int) -> float:
    """The median over the rounds of block ``i``'s time over block ``j``'s."""
    return statistics.median(r[i] / r[j] for r in rounds)


def calls_block(fn: Callable[[], Any], number: int) -> Callable[[], float]:
    """A block for :func:`paired_times`: ``number`` calls of ``fn``, their mean time."""

    def block() -> float:
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        return (time.perf_counter() - t0) / number

    return block


def cycling(
    fn: Callable[..., Any], x: np.ndarray, mode: np.ndarray, k: np.ndarray
) -> Callable[[], Any]:
    """A function that calls ``fn(x[i], int(mode[i]), int(k[i]))`` on the states in turn (from
    the first, wrapping around): the timed calls of a controller on closed-loop states."""
    it = iter(np.resize(np.arange(len(x)), 10**7))
    return lambda: fn(x[(i := next(it))], int(mode[i]), int(k[i]))


def closed_loop_states(model: SDJLSModel, ctrl, count: int, seed: int):
    """States, modes and times visited by the closed loop (realistic inputs for timing)."""
    env = SDJLSVectorEnv(num_envs=max(1, count // 20), model=model)
    _, info = env.reset(seed=seed)
    xs, ms, ks = [], [], []
    for _ in range(20):
        xs.append(info["state"])
        ms.append(info["mode"])
        ks.append(info["k"])
        u, _ = ctrl.act_batch(info["state"], info["mode"], info["k"])
        _, _, _, _, info = env.step(u)
    return np.concatenate(xs), np.concatenate(ms), np.concatenate(ks)
