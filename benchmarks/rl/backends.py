"""Where the trainings of the RL comparison run: local processes, or Ray tasks.

:func:`train_all` trains every run whose files are not already kept (under a fingerprint of its
configuration, :func:`benchmarks.rl.train.load_run`), on one of two backends:

* ``"process"``: a :class:`concurrent.futures.ProcessPoolExecutor` of ``workers`` processes
  (spawned, one torch thread each). A worker stops training when the main process ends or when
  a training fails or is interrupted (it checks every two seconds), so nothing trains on;
* ``"ray"``: one Ray task per training (``num_cpus=1``, retried on worker failure), on a local
  Ray instance of ``workers`` CPUs, or on an existing cluster (``address="auto"`` after
  ``ray start --head``). The workers get this checkout's ``sdjls_gym``, ``controllers`` and
  ``benchmarks`` packages through Ray's ``py_modules``, so a cluster needs only the
  dependencies installed. Ray is an optional extra: ``pip install -e ".[cluster]"``.

Every training is seeded and rebuilt from its :class:`~benchmarks.rl.train.RunSpec`, so the
results do not depend on the backend or the number of workers. A finished training is written
by the main process at once (``runs/<name>-<fingerprint>.pt`` and ``.json``), so an interrupted
run resumes.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any

from tqdm import tqdm

from benchmarks.rl import hyperparams as HP
from benchmarks.rl.train import RunRecord, RunSpec, load_run, save_run, train_run

BACKENDS = ("process", "ray")
#: Retries of a Ray task whose worker died (a node lost, an out-of-memory kill).
RAY_MAX_RETRIES = 2

# ---------------------------------------------------------------------------- process backend
_QUEUE: Any = None  # in a worker: where progress goes
_STOP: Any = None  # in a worker: set by the main process to stop every training
_PARENT_PID: int | None = None  # in a worker: the main process's pid


def _init_worker(queue: Any, stop: Any) -> None:
    global _QUEUE, _STOP, _PARENT_PID
    _QUEUE, _STOP, _PARENT_PID = queue, stop, os.getppid()


def _should_stop() -> bool:
    """Asked, the main process ended, or the worker was handed to another parent: a main
    process killed by a signal (``kill PID``) left its workers training on, their parent
    sentinel never reporting it (measured here), so the parent's pid is compared too."""
    if _STOP.is_set() or (_PARENT_PID is not None and os.getppid() != _PARENT_PID):
        return True
    parent = mp.parent_process()
    return parent is not None and not parent.is_alive()


def _report(name: str, steps: int) -> None:
    _QUEUE.put((name, steps))


def _process_task(spec: RunSpec) -> tuple[RunRecord, bytes]:
    return train_run(spec, _report, _should_stop)


def _run_processes(
    todo: list[RunSpec], workers: int, finished: Callable, progress: Callable, log: Callable
) -> None:
    ctx = mp.get_context("spawn")
    queue, stop = ctx.Queue(), ctx.Event()
    started: set[str] = set()

    def drain() -> None:
        while not queue.empty():
            name, steps = queue.get()
            if name not in started:
                started.add(name)
                log(f"[train] {name}")
            progress(name, steps)

    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker,
                               initargs=(queue, stop))  # fmt: skip
    try:
        pending = {pool.submit(_process_task, spec): spec for spec in todo}
        while pending:
            done, _ = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
            drain()
            for fut in done:
                finished(pending.pop(fut), *fut.result())
    except BaseException:
        stop.set()  # Ctrl-C or a failed training: the other trainings stop within seconds
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    drain()


# ---------------------------------------------------------------------------- Ray backend
def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ImportError(
            '--backend ray needs Ray, an optional dependency: pip install -e ".[cluster]"'
        ) from None
    return ray


def ray_init_kwargs(workers: int, address: str | None) -> dict[str, Any]:
    """``ray.init``'s arguments for the trainings (and :mod:`benchmarks.rl.tune`'s trials): this
    checkout's ``sdjls_gym``, ``controllers`` and ``benchmarks`` packages on every worker
    (``py_modules``), one BLAS thread, no worker logs on the driver; a local instance of
    ``workers`` CPUs (``address`` None) or the cluster at ``address``."""
    import benchmarks
    import controllers
    import sdjls_gym

    packages = []
    for m in (sdjls_gym, controllers, benchmarks):
        if m.__file__ is None:
            raise ValueError(f"{m.__name__}.__file__ = None; expected the package's folder for Ray")
        packages.append(str(Path(m.__file__).parent))
    runtime_env = {
        "py_modules": packages,
        "excludes": ["__pycache__"],
        "env_vars": {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"},
    }
    kwargs: dict[str, Any] = {"runtime_env": runtime_env, "log_to_driver": False}
    if address is None:  # a local instance, shut down at the end
        kwargs.update(num_cpus=workers, include_dashboard=False)
    else:
        kwargs["address"] = address
    return kwargs


def _run_ray(
    todo: list[RunSpec], workers: int, address: str | None, finished: Callable, log: Callable
) -> None:
    ray = _import_ray()
    ray.init(**ray_init_kwargs(workers, address))
    pending: dict[Any, RunSpec] = {}
    try:
        task = ray.remote(num_cpus=1, max_retries=RAY_MAX_RETRIES)(train_run)
        for spec in todo:
            pending[task.remote(spec)] = spec
            log(f"[train] {spec.label} (Ray task)")
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                finished(pending.pop(ref), *ray.get(ref))
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    finally:
        ray.shutdown()


# ---------------------------------------------------------------------------- entry point
def _split_kept(
    specs: list[RunSpec], run_dir: Path, retrain: bool
) -> tuple[dict[str, RunRecord], list[RunSpec]]:
    """The records kept in ``run_dir`` (by :attr:`RunSpec.label`) and the runs left to train,
    in the order they are handed out: seed by seed (the first seed of every configuration is a
    pilot that finishes first), and within a seed longest first (by estimated training time), so
    that the workers finish close together."""
    kept_records: dict[str, RunRecord] = {}
    todo = []
    for spec in specs:
        kept = None if retrain else load_run(run_dir, spec)
        if kept is None:
            todo.append(spec)
        else:
            kept_records[spec.label] = kept
    todo.sort(key=lambda s: (s.seed, -s.timesteps / HP.STEPS_PER_SECOND[s.algo]))
    return kept_records, todo


def _dispatch(
    todo: list[RunSpec],
    backend: str,
    workers: int,
    address: str | None,
    finished: Callable,
    on_progress: Callable,
    log: Callable[[str], None],
) -> None:
    """Train ``todo`` on ``backend``, handing every finished training to ``finished``."""
    if not todo:
        return
    if backend == "ray":
        _run_ray(todo, workers, address, finished, log)
    elif workers == 1 or len(todo) == 1:
        for spec in todo:
            log(f"[train] {spec.label} ({spec.timesteps} steps)")
            finished(spec, *train_run(spec, on_progress))
    else:
        _run_processes(todo, workers, finished, on_progress, log)


def train_all(
    specs: list[RunSpec],
    run_dir: Path,
    *,
    backend: str = "process",
    workers: int = 2,
    address: str | None = None,
    retrain: bool = False,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> list[RunRecord]:
    """Train every run of ``specs`` not kept in ``run_dir``; their records, in ``specs``' order.

    ``workers`` trainings run at once (``backend="process"``, or a local Ray instance); with
    ``address`` the Ray cluster's CPUs decide. ``retrain`` trains every run anew.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend = {backend!r}; expected one of {BACKENDS}")
    if backend == "ray":
        _import_ray()  # the message naming the extra, before any work
    run_dir.mkdir(parents=True, exist_ok=True)
    results, todo = _split_kept(specs, run_dir, retrain)  # results by RunSpec.label
    if results:
        log(f"reusing {len(results)} finished run(s) from {run_dir} (--retrain to train again)")
    bar = tqdm(total=sum(s.timesteps for s in todo), desc="training", unit="step",
               disable=not progress or not todo)  # fmt: skip
    seen: dict[str, int] = {}

    def on_progress(name: str, steps: int) -> None:
        bar.update(max(0, steps - seen.get(name, 0)))
        seen[name] = max(steps, seen.get(name, 0))

    def finished(spec: RunSpec, record: RunRecord, policy: bytes) -> None:
        save_run(run_dir, record, policy)
        on_progress(spec.label, spec.timesteps)
        results[spec.label] = record
        last = record.learning_curve[-1]
        cpu = "" if record.cpu_time_s is None else f" ({record.cpu_time_s:.0f} s CPU)"
        log(
            f"[done] {spec.label}: {record.timesteps} steps in {record.train_time_s:.0f} s{cpu}; last "
            f"learning-curve point: median cost {last.episode_cost_median:.4g}, violations "
            f"{last.violation:.3f}, diverged {last.diverged}/{spec.curve_episodes}"
        )

    t0 = time.perf_counter()
    _dispatch(todo, backend, workers, address, finished, on_progress, log)
    bar.close()
    if todo:
        log(f"trained {len(todo)} run(s) in {time.perf_counter() - t0:.0f} s ({backend})")
    return [results[s.label] for s in specs]
