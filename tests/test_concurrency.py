"""Controllers shared by threads, sent to other processes, and kept for a long time.

* One controller used by 4 threads at once gives, call for call, the answers of a single thread
  (the threads run in a subprocess: the failure this guards against was a segmentation fault).
* A controller can be pickled and deep-copied after it has solved (its DAQP and OSQP workspaces
  are dropped and rebuilt on use) and the copy answers the same.
* Set-up is lazy and bounded: the first ``act()`` of a family enumerates no active sets when there
  are too many of them, and memory stays bounded on large systems and over thousands of calls.
"""

from __future__ import annotations

import copy
import pickle
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from controllers import RecedingHorizonController
from controllers.active_set import _MAX_RANGES
from controllers.qp import MAX_CANDIDATES
from sdjls_gym import SDJLSModel
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro

ROOT = Path(__file__).resolve().parents[1]


def random_system(N: int, n: int, m: int, r: int, seed: int = 0) -> SDJLSModel:
    rng = np.random.default_rng(seed)
    return SDJLSModel(
        A=rng.normal(size=(N, n, n)) * 0.3,
        B=rng.normal(size=(N, n, m)),
        P_in=rng.dirichlet(np.ones(N), size=N),
        P_out=rng.dirichlet(np.ones(N), size=N),
        G=rng.normal(size=(r, n)),
        H0=rng.uniform(1.0, 3.0, size=r),
        Q=np.eye(n),
        R=np.eye(m),
        x0=np.zeros(n),
    )


THREADS_SCRIPT = textwrap.dedent(
    """
    import sys, threading
    import numpy as np
    from controllers import RecedingHorizonController
    from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro

    rng = np.random.default_rng(0)
    states = [(rng.normal(size=2) * rng.choice([1.0, 10.0, 60.0]), int(rng.integers(3)),
               int(rng.integers(20))) for _ in range(400)]
    batches = [(rng.normal(size=(16, 2)) * 5, rng.integers(0, 3, 16), rng.integers(0, 20, 16))
               for _ in range(40)]

    def answers(ctrl, order):
        out = {}
        for i in order:
            if i < len(states):
                u, info = ctrl.act(*states[i])
                out[i] = np.concatenate([u, info["nu"], [info["rho"], info["cost"]]])
            else:
                u, info = ctrl.act_batch(*batches[i - len(states)])
                out[i] = np.concatenate([u.ravel(), info["rho"], info["cost"]])
        return out

    def make():
        return RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC, solver=sys.argv[1])

    reference = answers(make(), range(len(states) + len(batches)))
    shared = make()
    shared.set_warm_start(False)  # the solver at every call: the threads share its workspaces
    results, errors = {}, []

    def work(t):
        try:
            order = list(range(t, len(states) + len(batches), 4))
            np.random.default_rng(t).shuffle(order)
            for _ in range(3):
                results.update(answers(shared, order))
        except Exception as exc:  # reported below
            errors.append(repr(exc))

    threads = [threading.Thread(target=work, args=(t,)) for t in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    assert results.keys() == reference.keys()
    worst = max(float(np.max(np.abs(results[i] - reference[i]) / (1 + np.abs(reference[i]))))
                for i in reference)
    print("calls", 3 * len(reference), "worst relative difference", worst)
    sys.exit(0 if worst <= 1e-12 else 1)
    """
)


@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_one_controller_shared_by_four_threads_answers_as_one_thread(solver):
    """4 threads x 3 passes over 400 states and 40 batches (1320 calls) on one controller whose
    every act() runs DAQP (or OSQP) in the family's workspace; every answer equals the
    single-threaded one (relative 1e-12). Without the controller's lock this crashed with a
    segmentation fault (exit 139, three runs out of three on the code before the lock)."""
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-c", THREADS_SCRIPT, solver],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, (done.returncode, done.stdout, done.stderr[-2000:])
    assert "worst relative difference" in done.stdout


@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_a_controller_that_has_solved_can_be_pickled_and_copied(how):
    """Pickling used to fail after the first act() ("cannot pickle 'module' object")."""
    ctrl = RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC)
    rng = np.random.default_rng(0)
    states = [
        (rng.normal(size=2) * 5, int(rng.integers(3)), int(rng.integers(20))) for _ in range(20)
    ]
    before = [ctrl.act(*s)[1] for s in states]
    ctrl.act_batch(np.array([s[0] for s in states]), np.array([s[1] for s in states]), 0)
    clone = pickle.loads(pickle.dumps(ctrl)) if how == "pickle" else copy.deepcopy(ctrl)
    for s, info in zip(states, before, strict=True):
        _, again = clone.act(*s)
        np.testing.assert_array_equal(again["nu"], info["nu"])
        assert again["cost"] == info["cost"] and again["rho"] == info["rho"]
    _, a = clone.act_batch(np.zeros((3, 2)), np.array([0, 1, 2]), 0)
    _, b = ctrl.act_batch(np.zeros((3, 2)), np.array([0, 1, 2]), 0)
    np.testing.assert_array_equal(a["nu"], b["nu"])


@pytest.mark.parametrize("N, n, m, r", [(2, 4, 4, 20), (2, 6, 5, 20), (2, 12, 10, 50)])
def test_first_act_of_a_large_family_enumerates_nothing(N, n, m, r):
    """m = 4, r = 20 used to enumerate 146,596 active sets on the first act() (38 s, 5.6 GB);
    m = 5 ran out of memory. Now DAQP and an exact re-solve answer, nothing is enumerated, and
    the first act() allocates little (traced by tracemalloc)."""
    model = random_system(N, n, m, r)
    ctrl = RecedingHorizonController(
        model, np.zeros((N, m, n)), Psi=np.array([np.eye(n)] * N), xi=0.9
    )
    rng = np.random.default_rng(1)
    tracemalloc.start()
    try:
        _, info = ctrl.act(rng.normal(size=n), 0, 0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert info["ok"] and info["status"] == "solved", info["notes"]
    assert peak < 20e6, peak
    engines = [fam.engine for fam in ctrl._families.values()]
    assert all(e.n_candidates > MAX_CANDIDATES and not e.can_enumerate for e in engines)
    assert all(e._enum is None for e in engines)
    for _ in range(10):  # further calls and a batch, all exact, still nothing enumerated
        _, info = ctrl.act(rng.normal(size=n), int(rng.integers(N)), int(rng.integers(5)))
        assert info["ok"], info["status"]
    _, binfo = ctrl.act_batch(rng.normal(size=(8, n)), rng.integers(0, N, 8), 0)
    assert binfo["ok"].all()
    assert all(e._enum is None for e in engines)


@pytest.mark.slow
def test_many_modes_and_rows_keep_memory_bounded():
    """N = 50, n = 30, r = 30 kept about 156 MB per family; now every family of a batch over all
    100 (mode, region) families fits in a few tens of MB in all."""
    N, n, m, r = 50, 30, 1, 30
    model = random_system(N, n, m, r, seed=3)
    ctrl = RecedingHorizonController(
        model, np.zeros((N, m, n)), Psi=np.array([np.eye(n)] * N), xi=0.9
    )
    rng = np.random.default_rng(2)
    x = rng.normal(size=(400, n)) * 0.5
    tracemalloc.start()
    try:
        for _ in range(3):
            ctrl.act_batch(x, rng.integers(0, N, 400), rng.integers(0, 5, 400))
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 200e6 and current < 150e6, (current, peak)


@pytest.mark.slow
def test_act_batch_memory_is_flat_over_thousands_of_calls():
    """The enumeration's cache of candidate ranges grew without bound under act_batch (8 MB to
    509 MB over 3000 calls on a one-mode system): it now holds at most two ranges."""
    model = random_system(1, 2, 1, 3, seed=5)
    ctrl = RecedingHorizonController(model, np.zeros((1, 1, 2)), Psi=np.array([np.eye(2)]), xi=0.9)
    rng = np.random.default_rng(0)
    for _ in range(50):  # warm-up: every family and its enumeration built
        ctrl.act_batch(rng.normal(size=(64, 2)) * rng.uniform(0.1, 10), np.zeros(64, int), 0)
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        for _ in range(3000):
            size = int(rng.integers(1, 200))
            x = rng.normal(size=(size, 2)) * 10.0 ** rng.uniform(-1, 2)
            ctrl.act_batch(x, np.zeros(size, int), int(rng.integers(0, 20)))
        current, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    enums = [f.engine._enum for f in ctrl._families.values() if f.engine._enum is not None]
    assert enums and all(e._range.cache_info().currsize <= _MAX_RANGES for e in enums)
    assert current - base < 5e6, current - base
