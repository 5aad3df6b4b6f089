"""The scenario tree's level runs: the store keeps them by their whole key, several workers give
the curve of one, and a stored run is not run again."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.core import tree_levels
from benchmarks.core.frontier import LevelRunner, tree_curve
from benchmarks.core.reference import tree_rhc
from benchmarks.core.tree_levels import LevelStore, level_key, run_tree_levels
from sdjls_gym.systems import TASKS

TASK = TASKS["SDJLS-Macro-v0"]
HORIZON, EPISODES, SEEDS, LEVELS = 6, 5, (3, 4), (0.5, 0.9)
SETTINGS = {"steps": 2, "horizon": HORIZON, "bound": 200.0, "divergence_bound": 1e6}


def _serial_reference() -> list[tuple[np.ndarray, np.ndarray, int]]:
    """The levels as the one-process runner of the one-step curve runs a family."""
    run = LevelRunner(TASK.model, lambda xi: tree_rhc(TASK, xi, 2, horizon=HORIZON), EPISODES,
                      SEEDS, HORIZON, 200.0, 1e6)  # fmt: skip
    return [run(xi) for xi in LEVELS]


def _same(a: list, b: list) -> None:
    assert len(a) == len(b)
    for (ca, va, da), (cb, vb, db) in zip(a, b, strict=True):
        np.testing.assert_array_equal(ca, cb)
        np.testing.assert_array_equal(va, vb)
        assert da == db


def test_store_round_trip_and_foreign_key(tmp_path):
    store = LevelStore(tmp_path)
    key = level_key(TASK, 2, HORIZON, 200.0, 1e6, 0.5, 3, EPISODES)
    assert store.get(key) is None
    run = (np.array([1.0, 2.5]), np.array([0.0, 0.25]), 1)
    store.put(key, run)
    got = store.get(key)
    assert got is not None
    _same([got], [run])
    other = {**key, "episodes": EPISODES + 1}
    assert store.get(other) is None  # another key, another file
    store._path = lambda text: next(tmp_path.glob("*.npz"))  # type: ignore[method-assign]
    assert store.get(other) is None  # a file holding another key is not its run
    next(tmp_path.glob("*.npz")).write_bytes(b"not an npz")
    assert store.get(key) is None  # a damaged file: run again


def test_workers_and_store_give_the_serial_curve(tmp_path, monkeypatch):
    expected = _serial_reference()
    store = LevelStore(tmp_path)
    parallel = run_tree_levels(TASK, LEVELS, SEEDS, EPISODES, store=store, workers=2, **SETTINGS)
    _same(parallel, expected)
    assert len(list(tmp_path.glob("*.npz"))) == len(LEVELS) * len(SEEDS)

    def refuse(*args, **kwargs):
        raise AssertionError("a stored level was run again")

    monkeypatch.setattr(tree_levels, "run_level", refuse)
    _same(run_tree_levels(TASK, LEVELS, SEEDS, EPISODES, store=store, **SETTINGS), expected)
    curve = tree_curve(TASK, EPISODES, SEEDS, LEVELS, steps=2, horizon=HORIZON,
                       action_bound=200.0, store=store)  # fmt: skip
    assert curve.xis == LEVELS and curve.costs.shape == (len(LEVELS), EPISODES * len(SEEDS))
    np.testing.assert_array_equal(curve.costs[1], expected[1][0])


def test_a_partly_filled_store_runs_only_what_is_missing(tmp_path, monkeypatch):
    expected = _serial_reference()
    store = LevelStore(tmp_path)
    run_tree_levels(TASK, LEVELS[:1], SEEDS[:1], EPISODES, store=store, **SETTINGS)
    calls = []
    real = tree_levels.run_level

    def counted(task, steps, horizon, bound, div, xi, seed, episodes, progress=None):
        calls.append((xi, seed))
        return real(task, steps, horizon, bound, div, xi, seed, episodes, progress)

    monkeypatch.setattr(tree_levels, "run_level", counted)
    _same(run_tree_levels(TASK, LEVELS, SEEDS, EPISODES, store=store, **SETTINGS), expected)
    assert sorted(calls) == [(0.5, 4), (0.9, 3), (0.9, 4)]


@pytest.mark.parametrize("argv", [["--workers", "0"]])
def test_suite_refuses_bad_workers(argv, capsys):
    from benchmarks.suite.cli import parse_args

    with pytest.raises(SystemExit) as info:
        parse_args(argv)
    assert info.value.code == 2
    assert "--workers = 0; expected a positive integer" in capsys.readouterr().err
