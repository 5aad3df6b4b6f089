"""The scenario tree's levels run on fixed episodes: kept on disk, and run on several processes.

The tree's decisions cost 10 to 1000 times the one-step controller's, so its curve on the
evaluation's own episodes (1000 per noise seed) takes CPU-hours. Two things make that practical:

* a :class:`LevelStore`: each ``(level, noise seed)`` run is written to its own file the moment it
  is done, keyed by everything its numbers depend on (the task's model, ``K`` and RHC data, the
  tree's stages, the horizon, the action and divergence bounds, the level, the seed, the
  episodes, and the installed version of ``sdjls-gym``), so an interrupted scoring resumes where it
  stopped and a second scoring of the same tree reuses it. A file whose stored key is not the
  one asked for is ignored (and replaced when the run is repeated);
* ``workers``: the runs not in the store go to that many processes at once (each run is one
  controller on the episodes of one seed, as :class:`benchmarks.core.frontier.LevelRunner` does),
  and the results are assembled in the order of the serial loop, so the curve is the same for
  any number of workers.

Delete the store's folder after a change to the controllers' code: the version in the key
changes only with a release.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.files import write_atomic
from benchmarks.core.montecarlo import rollout
from benchmarks.core.reference import task_key, tree_rhc
from sdjls_gym.systems import Task

__all__ = ["TREE_STORE", "LevelStore", "level_key", "run_level", "run_tree_levels"]

#: The store's folder inside a report's output folder (``results/rl_suite/tree_levels``,
#: ``results/suite/tree_levels``; not committed).
TREE_STORE = "tree_levels"

#: One run's statistics: episode costs (E,), shares of violated steps (E,), diverged episodes.
LevelRun = tuple[np.ndarray, np.ndarray, int]


class LevelStore:
    """A folder of the tree's level runs (see the module): ``get(key)`` / ``put(key, run)``,
    ``key`` a JSON-able dict (:func:`level_key`)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)

    def _path(self, text: str) -> Path:
        return self.folder / f"{hashlib.sha256(text.encode()).hexdigest()[:24]}.npz"

    def get(self, key: dict[str, Any]) -> LevelRun | None:
        """The stored run of ``key``, or None (none stored, or a file of another key)."""
        text = json.dumps(key, sort_keys=True)
        path = self._path(text)
        if not path.is_file():
            return None
        try:
            with np.load(path) as data:
                if str(data["key"]) != text:
                    return None
                return data["costs"].copy(), data["violations"].copy(), int(data["diverged"])
        except (OSError, ValueError, KeyError):  # a damaged file: run the level again
            return None

    def put(self, key: dict[str, Any], run: LevelRun) -> None:
        """Keep ``run`` under ``key`` (atomically: a reader sees the whole file or none)."""
        text = json.dumps(key, sort_keys=True)
        buf = io.BytesIO()
        np.savez(buf, key=np.array(text), costs=run[0], violations=run[1],
                 diverged=np.array(run[2]))  # fmt: skip
        self.folder.mkdir(parents=True, exist_ok=True)
        write_atomic(self._path(text), buf.getvalue())


def level_key(task: Task, steps: int, horizon: int, bound: float, divergence_bound: float,
              xi: float, seed: int, episodes: int) -> dict[str, Any]:  # fmt: skip
    """Everything a tree level run's numbers depend on (see the module)."""
    from importlib.metadata import version

    return {"task": task_key(task), "steps": int(steps), "horizon": int(horizon),
            "bound": float(bound), "divergence_bound": float(divergence_bound), "xi": float(xi),
            "seed": int(seed), "episodes": int(episodes), "sdjls_gym": version("sdjls-gym")}  # fmt: skip


def run_level(task: Task, steps: int, horizon: int, bound: float, divergence_bound: float,
              xi: float, seed: int, episodes: int, progress: Any = None) -> LevelRun:  # fmt: skip
    """The tree at level ``xi`` on ``episodes`` episodes of noise seed ``seed``."""
    ctrl = tree_rhc(task, xi, steps, horizon=horizon)
    ro = rollout(task.model, ctrl, episodes, horizon, seed, bound, progress, divergence_bound)
    return ro.outcomes(divergence_bound)


def run_tree_levels(task: Task, levels: Sequence[float], seeds: Sequence[int], episodes: int, *,
                    steps: int, horizon: int, bound: float, divergence_bound: float,
                    store: LevelStore | None = None, workers: int = 1,
                    progress: Any = None) -> list[LevelRun]:  # fmt: skip
    """Each level's run, the episodes of every seed pooled in the order of ``seeds``: from
    ``store`` where it has them, the others on ``workers`` processes (kept in ``store`` as each
    finishes). ``progress`` advances by one per step of a run (a run's ``horizon`` steps at
    once when it comes from the store or from a worker)."""
    args = (steps, horizon, bound, divergence_bound)
    done: dict[tuple[float, int], LevelRun] = {}
    todo = []
    for xi in levels:
        for seed in seeds:
            key = level_key(task, *args, xi, seed, episodes)
            held = None if store is None else store.get(key)
            if held is None:
                todo.append((xi, seed, key))
            else:
                done[xi, seed] = held
                if progress is not None:
                    progress.update(horizon)

    def keep(xi: float, seed: int, key: dict[str, Any], run: LevelRun) -> None:
        done[xi, seed] = run
        if store is not None:
            store.put(key, run)

    if workers <= 1 or len(todo) <= 1:
        for xi, seed, key in todo:
            keep(xi, seed, key, run_level(task, *args, xi, seed, episodes, progress))
    else:
        with ProcessPoolExecutor(min(workers, len(todo)), mp_context=get_context("spawn")) as pool:
            jobs = {pool.submit(run_level, task, *args, xi, seed, episodes): (xi, seed, key)
                    for xi, seed, key in todo}  # fmt: skip
            for job in as_completed(jobs):
                keep(*jobs[job], job.result())
                if progress is not None:
                    progress.update(horizon)
    return [
        (np.concatenate([done[xi, s][0] for s in seeds]),
         np.concatenate([done[xi, s][1] for s in seeds]),
         sum(done[xi, s][2] for s in seeds))
        for xi in levels
    ]  # fmt: skip
