"""Speed of the environment and the controllers, as ratios against references in the same run.

``python -m benchmarks.speed [--out results/speed] [--quick]`` (``--quick``: into a new temporary
folder) measures, in one process, with warm-up and medians over repeats (the env against
Pendulum, each ``act()`` against its DAQP floor, and the cvxpy rebuild with each ``act()`` path
in alternating rounds, a ratio the median of the rounds' ratios; :func:`paired_times`,
:func:`timed_rounds`):

1. one env step of ``SDJLS-Macro-v0`` against ``Pendulum-v1`` (both from ``gym.make`` with
   their default wrappers; resets are not timed);
2. one decision of ``RecedingHorizonController.act`` on the macro example (the default path:
   the active-set warm start, then DAQP; the same with the warm start disabled; ``solver="osqp"``;
   the exact active-set enumeration) against the DAQP floor of the same P3 (:class:`DaqpFloor`:
   P3 written here from the model, solved by DAQP alone), against the same QP rebuilt and solved
   with cvxpy at every step, and against a cvxpy ``Parameter`` formulation solved repeatedly,
   with the largest difference of the solutions and the share of the timed calls that the warm
   start answered;
3. the batched closed loop: ``SDJLSVectorEnv`` with 10,000 sub-environments driven by
   ``act_batch`` against a Python loop of one env + ``act``, and the largest difference between
   ``act_batch`` and ``act`` on the same states;
4. one decision of the multi-step ``ScenarioTreeController`` (``steps`` in 1, 2, 3, 5, and
   ``steps=10, branching=2``) against its cvxpy reference (the same tree written plainly, solved
   by Clarabel) and against one-step ``act()``, with the QP solves per decision and the largest
   difference of the two answers; and the 111-node tree (:func:`large_tree_model`) on its own
   closed loop;
5. scaling of one-step ``act`` and ``act_batch`` with m, r, n and N (:data:`SCALING_SIZES`) on
   closed-loop states of random tasks, each row against the DAQP floor of the same P3, and of
   the batched Monte Carlo with the number of trajectories;
6. the peak memory (RSS) of the largest Monte Carlo;
7. the mode hidden (:mod:`benchmarks.speed.hidden`): the belief controller's ``act`` against
   the mode controller's on every task, and the mode filter's step.

It reads no private attribute of the controllers (``path_counts``, ``reset_path_counts`` and
``set_warm_start`` are their public hooks). It writes ``speed.json`` and ``SPEED.md`` to
``--out``. BLAS runs single-threaded (set in ``benchmarks/__init__.py``): the products here are
small and thread start-up would dominate.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import sdjls_gym
from benchmarks.core.cli import output_folder
from benchmarks.core.commands import prog
from benchmarks.core.files import write_atomic
from benchmarks.core.versions import package_versions
from benchmarks.speed.hidden import measure_hidden
from benchmarks.speed.references import CvxpyParametric, DaqpFloor, P3Data
from benchmarks.speed.report import TARGETS, write_markdown
from benchmarks.speed.timing import (
    calls_block,
    closed_loop_states,
    cycling,
    env_step_blocks,
    median_time,
    paired_times,
    round_ratio,
    timed_rounds,
)
from controllers import RecedingHorizonController, ScenarioTreeController
from controllers.scenario_tree import PROB_TOL
from sdjls_gym import SDJLSModel, SDJLSVectorEnv
from sdjls_gym.systems import TASKS
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC
from sdjls_gym.systems.random_system import random_task
from sdjls_gym.systems.task import Task


def measure_act(opts) -> dict[str, Any]:
    model = sdjls_gym.macro()
    kw: dict[str, Any] = dict(PAPER_RHC)
    ctrl = RecedingHorizonController(model, PAPER_K, **kw)  # the default: solver="daqp"
    cold_ctrl = RecedingHorizonController(model, PAPER_K, **kw)
    cold_ctrl.set_warm_start(False)  # DAQP at every call
    osqp_ctrl = RecedingHorizonController(model, PAPER_K, **kw, solver="osqp")
    exact_ctrl = RecedingHorizonController(model, PAPER_K, **kw, solver="active_set")
    rebuild_ctrl = RecedingHorizonController(model, PAPER_K, **kw, solver="cvxpy")
    p3 = P3Data(model, PAPER_K, kw)
    floor = DaqpFloor(p3)
    x, mode, k = closed_loop_states(model, ctrl, 400, seed=1)
    n_cvx = 10 if opts.quick else 60

    def cycle(fn):
        return cycling(fn, x, mode, k)

    median_time(cycle(ctrl.act), opts.repeats, 200, after_warmup=ctrl.reset_path_counts)
    counts = ctrl.path_counts  # the timed calls (and the warm-up's last round) by path
    warm_share = counts.get("active_set_warm", 0) / sum(counts.values())
    # the cvxpy rebuild and each act() path in alternating rounds: every speedup is the median
    # of the rounds' ratios (the rebuild's time moved 6.7-11.2 ms between two runs minutes apart)
    paths = [rebuild_ctrl, ctrl, cold_ctrl, osqp_ctrl, exact_ctrl]
    rounds = timed_rounds(
        [calls_block(cycle(c.act), n_cvx if c is rebuild_ctrl else 200) for c in paths],
        3 if opts.quick else max(3, opts.repeats),
    )
    t_rebuild, t_act, t_cold, t_osqp, t_exact = (
        statistics.median(r[i] for r in rounds) for i in range(len(paths))
    )
    speedup = {name: round_ratio(rounds, 0, i) for i, name in enumerate(paths) if i}
    # act() again, in rounds alternating with the floor's (the ratio under one load)
    (t_act_paired, t_floor), act_vs_floor = paired_times(
        [calls_block(cycle(ctrl.act), 200), calls_block(cycle(floor.solve), 200)], opts.repeats
    )
    params = {}
    t_param_runs = []
    others = {"active_set": exact_ctrl, "every_call": cold_ctrl, "osqp": osqp_ctrl}
    diffs = {key: 0.0 for key in ("rebuild", "parametric", "daqp_floor", *others)}
    for i in range(n_cvx):
        xi, mi, ki = x[i], int(mode[i]), int(k[i])
        key = (mi, bool(model.in_region(xi, ki)))
        if key not in params:
            params[key] = CvxpyParametric(p3, *key)
            params[key].solve(xi, ki)  # compile once
        t0 = time.perf_counter()
        u_param = params[key].solve(xi, ki)
        t_param_runs.append(time.perf_counter() - t0)
        u = ctrl.act(xi, mi, ki)[0]
        answers = {
            "parametric": u_param,
            "rebuild": rebuild_ctrl.act(xi, mi, ki)[0],
            "daqp_floor": floor.solve(xi, mi, ki)[0],
        }
        answers.update({name: c.act(xi, mi, ki)[0] for name, c in others.items()})
        for name, v in answers.items():
            diffs[name] = max(diffs[name], float(np.max(np.abs(v - u))))
    t_param = statistics.median(t_param_runs)
    return {
        "act_us": 1e6 * t_act,
        "act_every_call_us": 1e6 * t_cold,
        "act_osqp_us": 1e6 * t_osqp,
        "act_active_set_us": 1e6 * t_exact,
        "daqp_floor_us": 1e6 * t_floor,
        "act_paired_us": 1e6 * t_act_paired,  # act() in the rounds alternating with the floor
        "warm_start_share": warm_share,
        "timed_calls_by_path": counts,
        "cvxpy_rebuild_us": 1e6 * t_rebuild,
        "cvxpy_parametric_us": 1e6 * t_param,
        "speedup_vs_rebuild": speedup[ctrl],
        "speedup_every_call_vs_rebuild": speedup[cold_ctrl],
        "speedup_osqp_vs_rebuild": speedup[osqp_ctrl],
        "speedup_active_set_vs_rebuild": speedup[exact_ctrl],
        "speedup_vs_parametric": t_param / t_act,
        "act_vs_daqp_floor": act_vs_floor,
        "max_abs_diff_u": diffs,
        "states": int(n_cvx),
    }


def measure_batched(opts) -> dict[str, Any]:
    model = sdjls_gym.macro()
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    B = 1000 if opts.quick else 10_000
    env = SDJLSVectorEnv(num_envs=B, model=model)

    def run_batched() -> float:
        _, info = env.reset(seed=2)
        t0 = time.perf_counter()
        for _ in range(20):
            u, _ = ctrl.act_batch(info["state"], info["mode"], info["k"])
            _, _, _, _, info = env.step(u)
        return (time.perf_counter() - t0) / (20 * B)

    run_batched()
    t_batched = statistics.median(run_batched() for _ in range(opts.repeats))

    single = gym.make("SDJLS-Macro-v0")
    episodes = 5 if opts.quick else 25

    def run_loop() -> float:
        _, info = single.reset(seed=3)
        t0 = time.perf_counter()
        for _ in range(episodes):
            _, info = single.reset()
            for _ in range(20):
                u, _ = ctrl.act(info["state"], info["mode"], info["k"])
                _, _, _, _, info = single.step(u)
        return (time.perf_counter() - t0) / (20 * episodes)

    run_loop()
    t_loop = statistics.median(run_loop() for _ in range(3))
    x, mode, k = closed_loop_states(model, ctrl, 2000, seed=4)
    u_b, _ = ctrl.act_batch(x, mode, k)
    sample = np.random.default_rng(0).choice(len(x), 200, replace=False)
    diff = max(
        float(np.max(np.abs(u_b[i] - ctrl.act(x[i], int(mode[i]), int(k[i]))[0]))) for i in sample
    )
    return {
        "num_envs": B,
        "batched_steps_per_second": 1.0 / t_batched,
        "loop_steps_per_second": 1.0 / t_loop,
        "speedup_vs_loop": t_loop / t_batched,
        "max_abs_diff_act_batch_vs_act": diff,
    }


#: The trees of the multi-step section: (steps, branching); None branches at every stage.
TREES = ((1, None), (2, None), (3, None), (5, None), (10, 2))


def measure_tree(opts) -> dict[str, Any]:
    """One decision of ``ScenarioTreeController`` per tree of :data:`TREES` on closed-loop
    states of the paper's controller, against its cvxpy reference and one-step ``act()``."""
    model = sdjls_gym.macro()
    p3 = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    # one state per timed call: a replayed state meets the caches its first visit filled
    calls = (opts.repeats + 1) * (40 if opts.quick else 200)
    x, mode, k = closed_loop_states(model, p3, max(400, -(-calls // 20) * 20), seed=6)
    idx = np.arange(len(x))
    one_step = cycling(p3.act, x, mode, k)
    rows = []
    for steps, branching in TREES:
        fast = ScenarioTreeController(model, PAPER_K, **PAPER_RHC, steps=steps, branching=branching)
        ref = ScenarioTreeController(
            model, PAPER_K, **PAPER_RHC, steps=steps, branching=branching, solver="cvxpy"
        )
        large = steps >= 5
        it = iter(np.resize(idx, 10**7))
        solves: list[int] = []
        gaps: list[float] = []

        def one(ctrl=fast, it=it, solves=solves, gaps=gaps) -> None:
            i = next(it)
            info = ctrl.act(x[i], int(mode[i]), int(k[i]))[1]
            solves.append(info["iterations"])
            gaps.append(info["fixed_point_gap"])

        number = (10 if large else 40) if opts.quick else (60 if large else 200)
        # in rounds alternating with one-step act() on the same states (the ratio under one load)
        (t_fast, t_one), vs_one = paired_times(
            [calls_block(one, number), calls_block(one_step, 200)],
            opts.repeats,
            after_warmup=fast.reset_path_counts,
        )
        counts = fast.path_counts
        n_cvx = (1 if large else 3) if opts.quick else (8 if large else 20)
        t_ref, diff = [], 0.0
        for i in range(n_cvx):
            j = 20 * i + 7  # spread over the episodes' times
            t0 = time.perf_counter()
            u_ref = ref.act(x[j], int(mode[j]), int(k[j]))[0]
            t_ref.append(time.perf_counter() - t0)
            u_fast = fast.act(x[j], int(mode[j]), int(k[j]))[0]
            diff = max(diff, float(np.max(np.abs(u_fast - u_ref))))
        plan = fast.act(x[0], int(mode[0]), int(k[0]))[1]["plan"]
        t_cvx = statistics.median(t_ref)
        rows.append(
            {
                "steps": steps,
                "branching": steps if branching is None else branching,
                "nodes": int(plan.mode.size),
                "variables": int(plan.mode.size * (model.m + 1)),
                "act_us": 1e6 * t_fast,
                "qp_solves_per_decision": float(np.mean(solves)),
                "fixed_point_converged_share": float(np.mean(np.array(gaps) <= PROB_TOL)),
                "warm_start_share": counts.get("active_set_warm", 0) / max(1, sum(counts.values())),
                "recent_set_share": counts.get("active_set_recent", 0)
                / max(1, sum(counts.values())),
                "cvxpy_us": 1e6 * t_cvx,
                "speedup_vs_cvxpy": t_cvx / t_fast,
                "one_step_act_us": 1e6 * t_one,
                "vs_one_step_act": vs_one,
                "max_abs_diff_u_vs_cvxpy": diff,
                "cvxpy_states": n_cvx,
            }
        )
    return {"rows": rows}


#: The rows of the scaling table, ``(n, m, r, N)``: five base sizes, then one knob at a
#: time (m, r, n, N) around them.
SCALING_SIZES = (
    (2, 1, 2, 3),
    (4, 2, 6, 3),
    (4, 2, 8, 2),
    (6, 3, 12, 3),
    (8, 4, 16, 2),
    (8, 1, 8, 4),
    (8, 2, 8, 4),
    (8, 3, 8, 4),
    (8, 4, 8, 4),
    (4, 2, 2, 4),
    (4, 2, 4, 4),
    (4, 2, 8, 4),
    (4, 2, 16, 4),
    (2, 1, 4, 3),
    (4, 1, 4, 3),
    (8, 1, 4, 3),
    (4, 1, 4, 2),
    (4, 1, 4, 5),
    (4, 1, 4, 10),
)
QUICK_SCALING_SIZES = ((2, 1, 2, 3), (4, 2, 8, 2))


#: The suite's tasks in the scaling study (their own models, gains and settings); quick: two.
SUITE_SCALING = tuple(sdjls_gym.SUITE)
QUICK_SUITE_SCALING = ("SDJLS-Solar-v0", "SDJLS-Degradation-v0")


def measure_p3_size(n: int, m: int, r: int, N: int, opts) -> dict[str, Any]:
    """One row of the scaling table: ``random_task(n, m, N, r, seed=0)`` with its receding-
    horizon data (see :func:`measure_p3_task`)."""
    return {"n": n, "m": m, "r": r, "N": N,
            **measure_p3_task(random_task(n=n, m=m, N=N, r=r, seed=0), opts)}  # fmt: skip


def measure_suite_task(env_id: str, opts) -> dict[str, Any]:
    """One row of the suite's scaling table: the task's own model, gains and receding-horizon
    settings (``sdjls_gym.systems.TASKS``; see :func:`measure_p3_task`)."""
    task = TASKS[env_id]
    model = task.model
    dims = {"n": model.n, "m": model.m, "r": model.r, "N": model.N}
    return {"task": env_id, **dims, **measure_p3_task(task, opts)}


def measure_p3_task(task: Task, opts) -> dict[str, Any]:
    """``act()`` of the task's receding-horizon controller on the states of its own closed loop,
    against the DAQP floor of the same P3 (:class:`DaqpFloor`) in the same run; ``act_batch``
    on the same states, per state."""
    model = task.model
    ctrl = RecedingHorizonController(model, task.K, **task.rhc)
    floor = DaqpFloor(P3Data(model, task.K, dict(task.rhc)))
    x, mode, k = closed_loop_states(model, ctrl, 100 if opts.quick else 400, seed=7)
    B = len(x)

    def cycle(fn):
        return cycling(fn, x, mode, k)

    (t_act, t_floor), act_vs_floor = paired_times(
        [calls_block(cycle(ctrl.act), B), calls_block(cycle(floor.solve), B)], opts.repeats
    )
    t_batch = median_time(lambda: ctrl.act_batch(x, mode, k), opts.repeats, 1) / B
    u_batch = ctrl.act_batch(x, mode, k)[0]
    diff_floor = diff_batch = 0.0
    active = 0
    for i in range(B):
        u = ctrl.act(x[i], int(mode[i]), int(k[i]))[0]
        u_floor, on = floor.solve(x[i], int(mode[i]), int(k[i]))
        active += on
        scale = 1.0 + float(np.max(np.abs(u)))
        diff_floor = max(diff_floor, float(np.max(np.abs(u_floor - u))) / scale)
        diff_batch = max(diff_batch, float(np.max(np.abs(u_batch[i] - u))))
    return {
        "states": B,
        "active_share": active / B,
        "act_us": 1e6 * t_act,
        "act_batch_per_state_us": 1e6 * t_batch,
        "daqp_floor_us": 1e6 * t_floor,
        "act_vs_floor": act_vs_floor,
        "batch_vs_act": t_batch / t_act,
        "max_rel_diff_u_vs_floor": diff_floor,
        "max_abs_diff_u_batch_vs_act": diff_batch,
    }


def large_tree_model(seed: int = 11, N: int = 10, r: int = 20) -> SDJLSModel:
    """The system of the 111-node tree: N = 10 modes, n = 4, m = 1, r = 20 random rows
    (the large trees of ``tests/test_tree_reliability.py`` too, with zero gains)."""
    rng = np.random.default_rng(seed)
    n, m = 4, 1
    return SDJLSModel(
        A=rng.normal(size=(N, n, n)) * 0.4,
        B=rng.normal(size=(N, n, m)),
        E=np.tile(np.eye(n) * 0.3, (N, 1, 1)),
        W=np.eye(n),
        P_in=rng.dirichlet(np.ones(N), size=N),
        P_out=rng.dirichlet(np.ones(N), size=N),
        G=rng.normal(size=(r, n)),
        H0=rng.uniform(1.0, 3.0, size=r),
        Q=np.tile(np.eye(n), (N, 1, 1)),
        R=np.tile(np.eye(m), (N, 1, 1)),
        x0=np.zeros(n),
    )


def measure_large_tree(opts, act_one_step_us: float) -> dict[str, Any]:
    """Decisions of the 111-node tree (steps = 3 on :func:`large_tree_model`, ``Psi = I``,
    ``xi = 0.9``) along its own closed loop: 120 decisions build the families (not timed), the
    next 40 (quick: 30 and 10) are timed, each on a new state (replayed states let the caches
    answer from an earlier pass: 12 ms against ~60 ms); those that built a family are counted."""
    model = large_tree_model()
    n, N = model.n, model.N
    ctrl = ScenarioTreeController(
        model, np.zeros((N, 1, n)), Psi=np.tile(np.eye(n), (N, 1, 1)), xi=0.9, steps=3
    )
    env = SDJLSVectorEnv(num_envs=1, model=model)
    _, info = env.reset(seed=3)
    warm, timed = (30, 10) if opts.quick else (120, 40)
    runs, builds = [], 0  # (seconds, QP solves, ok) of the timed decisions
    for step in range(warm + timed):
        if step == warm:
            ctrl.reset_path_counts()
        built, t0 = ctrl.families_built, time.perf_counter()
        u, dec = ctrl.act(info["state"][0].copy(), int(info["mode"][0]), int(info["k"][0]))
        elapsed = time.perf_counter() - t0
        if step >= warm and ctrl.families_built > built:
            builds += 1
        elif step >= warm:
            runs.append((elapsed, dec["iterations"], bool(dec["ok"])))
        _, _, term, trunc, info = env.step(u[None])
        if term[0] or trunc[0]:
            _, info = env.reset()
    times = [run[0] for run in runs]
    nodes = int(dec["plan"].mode.size)
    return {
        "nodes": nodes,
        "variables": nodes * (model.m + 1),
        "decisions": len(times),
        "decisions_with_a_build": builds,
        "median_ms": 1e3 * statistics.median(times),
        "mean_ms": 1e3 * float(np.mean(times)),
        "max_ms": 1e3 * max(times),
        "qp_solves_per_decision": float(np.mean([run[1] for run in runs])),
        "ok_share": float(np.mean([run[2] for run in runs])),
        "solves_by_path": ctrl.path_counts,
        "vs_one_step_act": 1e3 * statistics.median(times) / act_one_step_us,
    }


def measure_scaling(opts) -> dict[str, Any]:
    sizes = QUICK_SCALING_SIZES if opts.quick else SCALING_SIZES
    rows = []
    for n, m, r, N in sizes:
        print(f"  n={n} m={m} r={r} N={N}", flush=True)
        rows.append(measure_p3_size(n, m, r, N, opts))
    suite = []
    for env_id in QUICK_SUITE_SCALING if opts.quick else SUITE_SCALING:
        print(f"  {env_id}", flush=True)
        suite.append(measure_suite_task(env_id, opts))
    mc = []
    model = sdjls_gym.macro()
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    for runs in (10**3, 10**4) if opts.quick else (10**3, 10**4, 10**5):
        env = SDJLSVectorEnv(num_envs=runs, model=model)
        _, info = env.reset(seed=5)
        t0 = time.perf_counter()
        for _ in range(20):
            u, _ = ctrl.act_batch(info["state"], info["mode"], info["k"])
            _, _, _, _, info = env.step(u)
        mc.append({"trajectories": runs, "seconds": time.perf_counter() - t0})
        del env, info
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"p3": rows, "suite": suite, "monte_carlo": mc, "peak_rss_mb": peak_kb / 1024}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """``python -m benchmarks.speed``: every measurement, ``speed.json`` and ``SPEED.md`` into
    ``--out``; see the module docstring and ``--help``."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(prog=prog("speed"), description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, help="folder for speed.json and SPEED.md (default "
                        "results/speed; with --quick a new temporary folder)")  # fmt: skip
    parser.add_argument("--quick", action="store_true", help="small sizes, few repeats: a smoke "
                        "test")  # fmt: skip
    parser.add_argument("--repeats", type=int, help="repeats per measurement (default 7, quick 2)")
    opts = parser.parse_args(argv)
    opts.repeats = (2 if opts.quick else 7) if opts.repeats is None else opts.repeats
    if opts.repeats < 1:
        parser.error(f"--repeats = {opts.repeats}; expected a positive integer")
    opts.out = output_folder(parser, "--out", opts.out, quick=opts.quick,
                             default=Path("results/speed"), script="speed")  # fmt: skip
    print(f"writing to {opts.out}", flush=True)
    opts.out.mkdir(parents=True, exist_ok=True)
    episodes = 50 if opts.quick else 500
    print("env step ...", flush=True)
    blocks = [env_step_blocks(env_id, episodes) for env_id in ("SDJLS-Macro-v0", "Pendulum-v1")]
    (sdj, pend), env_ratio = paired_times(blocks, opts.repeats)
    res: dict[str, Any] = {
        "command": "python -m benchmarks.speed" + ("" if not argv else " " + " ".join(argv)),
        "machine": f"{platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}",
        "versions": package_versions(),
        "targets": TARGETS,
        "env_step": {"pendulum_us": 1e6 * pend, "sdjls_us": 1e6 * sdj, "ratio": env_ratio},
    }
    print("act ...", flush=True)
    res["act"] = measure_act(opts)
    print("batched closed loop ...", flush=True)
    res["batched"] = measure_batched(opts)
    print("multi-step (scenario tree) ...", flush=True)
    res["tree"] = measure_tree(opts)
    print("the 111-node tree ...", flush=True)
    res["tree"]["large"] = measure_large_tree(opts, res["act"]["act_us"])
    print("scaling ...", flush=True)
    res["scaling"] = measure_scaling(opts)
    print("the mode hidden ...", flush=True)
    res["hidden"] = measure_hidden(opts)
    write_atomic(opts.out / "speed.json", json.dumps(res, indent=1) + "\n")
    md = write_markdown(res, res["command"])
    write_atomic(opts.out / "SPEED.md", md)
    print(md)
    return res


if __name__ == "__main__":
    main()
