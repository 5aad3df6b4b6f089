"""Speed of the environment and the controllers, as ratios against references in the same run.

``python -m benchmarks.speed [--out results/speed] [--quick]`` measures, in one process, with
warm-up and medians over repeats:

1. one env step of ``SDJLS-Macro-v0`` against ``Pendulum-v1`` (both from ``gym.make`` with
   their default wrappers; resets are not timed);
2. one decision of ``RecedingHorizonController.act`` (the default OSQP path with its active-set
   warm start, the same with the warm start disabled so that OSQP runs at every call, and the
   exact active-set enumeration) against the same QP rebuilt and solved with cvxpy at every
   step, and against a cvxpy ``Parameter`` formulation solved repeatedly, with the largest
   difference of the solutions and the share of the timed calls that the warm start answered;
3. the batched closed loop: ``SDJLSVectorEnv`` with 10,000 sub-environments driven by
   ``act_batch`` against a Python loop of one env + ``act``, and the largest difference between
   ``act_batch`` and ``act`` on the same states;
4. one decision of the multi-step ``ScenarioTreeController`` (``steps`` in 1, 2, 3, 5, and
   ``steps=10, branching=2``) against its cvxpy reference (the same tree written plainly, solved
   by Clarabel) and against one-step ``act()``, with the QP solves per decision and the largest
   difference of the two answers;
5. scaling of ``synthesize_gains`` and ``act`` with the number of modes N and states n, and
   of the batched Monte Carlo with the number of trajectories;
6. the peak memory (RSS) of the largest Monte Carlo.

It writes ``speed.json`` and ``SPEED.md`` to ``--out``. BLAS runs single-threaded (set in
``benchmarks/__init__.py``): the products here are small and thread start-up would dominate.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import sdjls_gym
from benchmarks.versions import package_versions
from controllers import RecedingHorizonController, ScenarioTreeController, synthesize_gains
from controllers.scenario_tree import PROB_TOL
from sdjls_gym import SDJLSModel, SDJLSVectorEnv
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC

TARGETS = {
    "env_step_ratio_max": 1.5,
    "act_speedup_vs_cvxpy_rebuild_min": 200.0,
    "batched_steps_per_second_min": 1_000_000.0,
    "batched_speedup_vs_loop_min": 50.0,
    "tree_steps3_speedup_vs_cvxpy_min": 50.0,
    "agreement_tol": 1e-6,
}


def median_time(
    fn: Callable[[], Any],
    repeats: int,
    number: int,
    after_warmup: Callable[[], Any] | None = None,
) -> float:
    """Median over ``repeats`` of the mean time of ``number`` calls (after one warm-up round;
    ``after_warmup`` is called between the warm-up and the timed rounds, untimed)."""
    for _ in range(number):
        fn()
    if after_warmup is not None:
        after_warmup()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return statistics.median(times)


def env_step_time(env_id: str, episodes: int, repeats: int) -> float:
    """Median time of one ``step`` (resets excluded) of ``gym.make(env_id)``."""
    env = gym.make(env_id)
    action = np.zeros(env.action_space.shape, dtype=np.float32) + 0.5
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

    block()
    return statistics.median(block() for _ in range(repeats))


class CvxpyParametric:
    """P3 of one (mode, region) family as a cvxpy problem with Parameters, solved repeatedly."""

    def __init__(self, ctrl: RecedingHorizonController, mode: int, inside: bool) -> None:
        import cvxpy as cp

        fam = ctrl._families[(mode, inside)]
        m, r = ctrl.model.m, ctrl.model.r
        self.nu, self.rho = cp.Variable(m), cp.Variable(nonneg=True)
        self.g, self.rhs = cp.Parameter(m), cp.Parameter(r)
        L = np.linalg.cholesky(fam.H_nu)
        objective = cp.sum_squares(L.T @ self.nu) + self.g @ self.nu + ctrl.alpha * self.rho
        constraints = [fam.GB @ self.nu - self.rho <= self.rhs, cp.abs(self.nu) <= ctrl.nu_bound]
        self.problem = cp.Problem(cp.Minimize(objective), constraints)
        self.ctrl, self.fam = ctrl, fam

    def solve(self, x: np.ndarray, k: int) -> np.ndarray:
        import cvxpy as cp

        fam = self.fam
        self.g.value = fam.grad @ x
        self.rhs.value = self.ctrl._hbar(fam, np.array([k]))[0] - fam.GA @ x
        self.problem.solve(solver=cp.CLARABEL, tol_gap_abs=1e-11, tol_gap_rel=1e-11, tol_feas=1e-11)
        return fam.K @ x + self.nu.value


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


def measure_act(opts) -> dict[str, Any]:
    model = sdjls_gym.macro()
    kw = dict(PAPER_RHC)
    osqp_ctrl = RecedingHorizonController(model, PAPER_K, **kw)
    cold_ctrl = RecedingHorizonController(model, PAPER_K, **kw)
    cold_ctrl._warm_start = False  # documented switch: OSQP at every call
    exact_ctrl = RecedingHorizonController(model, PAPER_K, **kw, solver="active_set")
    rebuild_ctrl = RecedingHorizonController(model, PAPER_K, **kw, solver="cvxpy")
    x, mode, k = closed_loop_states(model, osqp_ctrl, 400, seed=1)
    n_cvx = 10 if opts.quick else 60
    idx = np.arange(len(x))

    def cycle(ctrl, n):
        it = iter(np.resize(idx, 10**7))
        return lambda: ctrl.act(x[(i := next(it))], int(mode[i]), int(k[i]))

    t_osqp = median_time(
        cycle(osqp_ctrl, len(x)), opts.repeats, 200, after_warmup=osqp_ctrl._path_counts.clear
    )
    # share of the timed calls answered by the active-set warm start (no OSQP)
    counts = dict(osqp_ctrl._path_counts)
    warm_share = counts.get("active_set_warm", 0) / sum(counts.values())
    t_cold = median_time(cycle(cold_ctrl, len(x)), opts.repeats, 200)
    t_exact = median_time(cycle(exact_ctrl, len(x)), opts.repeats, 200)
    t_rebuild = median_time(cycle(rebuild_ctrl, len(x)), 3, n_cvx)
    params = {}
    t_param_runs = []
    diffs = {"rebuild": 0.0, "parametric": 0.0, "active_set": 0.0, "osqp_every_call": 0.0}
    for i in range(n_cvx):
        inside = bool(model.in_region(x[i], k[i]))
        key = (int(mode[i]), inside)
        if key not in params:
            params[key] = CvxpyParametric(osqp_ctrl, *key)
            params[key].solve(x[i], int(k[i]))  # compile once
        t0 = time.perf_counter()
        u_param = params[key].solve(x[i], int(k[i]))
        t_param_runs.append(time.perf_counter() - t0)
        u_osqp = osqp_ctrl.act(x[i], int(mode[i]), int(k[i]))[0]
        diffs["parametric"] = max(diffs["parametric"], float(np.max(np.abs(u_param - u_osqp))))
        u_rebuild = rebuild_ctrl.act(x[i], int(mode[i]), int(k[i]))[0]
        diffs["rebuild"] = max(diffs["rebuild"], float(np.max(np.abs(u_rebuild - u_osqp))))
        u_exact = exact_ctrl.act(x[i], int(mode[i]), int(k[i]))[0]
        diffs["active_set"] = max(diffs["active_set"], float(np.max(np.abs(u_exact - u_osqp))))
        u_cold = cold_ctrl.act(x[i], int(mode[i]), int(k[i]))[0]
        diffs["osqp_every_call"] = max(
            diffs["osqp_every_call"], float(np.max(np.abs(u_cold - u_osqp)))
        )
    t_param = statistics.median(t_param_runs)
    return {
        "act_osqp_us": 1e6 * t_osqp,
        "act_active_set_us": 1e6 * t_exact,
        "act_osqp_every_call_us": 1e6 * t_cold,
        "warm_start_share": warm_share,
        "timed_calls_by_path": counts,
        "cvxpy_rebuild_us": 1e6 * t_rebuild,
        "cvxpy_parametric_us": 1e6 * t_param,
        "speedup_osqp_vs_rebuild": t_rebuild / t_osqp,
        "speedup_active_set_vs_rebuild": t_rebuild / t_exact,
        "speedup_osqp_every_call_vs_rebuild": t_rebuild / t_cold,
        "speedup_osqp_vs_parametric": t_param / t_osqp,
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


def measure_tree(opts, act_one_step_us: float) -> dict[str, Any]:
    """One decision of ``ScenarioTreeController`` per tree of :data:`TREES` on closed-loop
    states of the paper's controller, against its cvxpy reference and one-step ``act()``."""
    model = sdjls_gym.macro()
    p3 = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    x, mode, k = closed_loop_states(model, p3, 400, seed=6)
    idx = np.arange(len(x))
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
        t_fast = median_time(one, opts.repeats, number, after_warmup=fast._path_counts.clear)
        counts = dict(fast._path_counts)
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
                "cvxpy_us": 1e6 * t_cvx,
                "speedup_vs_cvxpy": t_cvx / t_fast,
                "vs_one_step_act": 1e6 * t_fast / act_one_step_us,
                "max_abs_diff_u_vs_cvxpy": diff,
                "cvxpy_states": n_cvx,
            }
        )
    return {"rows": rows}


def random_system(N: int, n: int, seed: int) -> SDJLSModel:
    """A random controllable system with a box region around the origin."""
    rng = np.random.default_rng(seed)
    P = rng.random((N, N)) + 0.2
    P2 = rng.random((N, N)) + 0.2
    return SDJLSModel(
        A=rng.standard_normal((N, n, n)) / np.sqrt(n),
        B=rng.standard_normal((N, n, 1)),
        P_in=P / P.sum(1, keepdims=True),
        P_out=P2 / P2.sum(1, keepdims=True),
        G=np.vstack([np.eye(n), -np.eye(n)]),
        H0=np.full(2 * n, 5.0),
        Q=np.eye(n),
        R=np.eye(1),
        x0=np.zeros(n),
    )


def measure_scaling(opts) -> dict[str, Any]:
    rows = []
    Ns, ns = ((2, 3), (2, 4)) if opts.quick else ((2, 3, 5, 10), (2, 4, 8))
    for N in Ns:
        for n in ns:
            model = random_system(N, n, seed=10 * N + n)
            t0 = time.perf_counter()
            try:
                res = synthesize_gains(model)
                t_syn, K, status = time.perf_counter() - t0, res.K, "ok"
            except Exception as exc:  # noqa: BLE001 - recorded in the table
                t_syn, K, status = time.perf_counter() - t0, np.zeros((N, 1, n)), type(exc).__name__
            ctrl = RecedingHorizonController(model, K, np.array([np.eye(n)] * N), 0.9)
            xs = np.random.default_rng(0).normal(0, 1, (50, n))
            it = iter(range(10**7))
            t_act = median_time(lambda c=ctrl, s=xs, i=it: c.act(s[next(i) % 50], 0, 1), 3, 30)
            rows.append(
                {"N": N, "n": n, "synthesize_s": t_syn, "status": status, "act_us": 1e6 * t_act}
            )
    mc = []
    model = sdjls_gym.macro()
    ctrl = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    sizes = (10**3, 10**4) if opts.quick else (10**3, 10**4, 10**5)
    for runs in sizes:
        env = SDJLSVectorEnv(num_envs=runs, model=model)
        _, info = env.reset(seed=5)
        t0 = time.perf_counter()
        for _ in range(20):
            u, _ = ctrl.act_batch(info["state"], info["mode"], info["k"])
            _, _, _, _, info = env.step(u)
        mc.append({"trajectories": runs, "seconds": time.perf_counter() - t0})
        del env, info
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"synthesis_and_act": rows, "monte_carlo": mc, "peak_rss_mb": peak_kb / 1024}


def write_markdown(res: dict[str, Any], cmd: str) -> str:
    e, a, b, s = res["env_step"], res["act"], res["batched"], res["scaling"]
    t = TARGETS

    def ok(flag: bool) -> str:
        return "yes" if flag else "**no**"

    lines = [
        "# Speed",
        "",
        f"Generated by `{cmd}` on {res['machine']}. Medians over repeats after warm-up; the",
        "machine is shared, so the ratios (measured in the same run) are what to read.",
        "",
        "How the act() fast path works: it first re-solves exactly the KKT system of the active set "
        "that was optimal at the last call in the same (mode, region) family and keeps that answer "
        "if it passes the KKT test (primal feasibility, nonnegative multipliers), and only "
        "otherwise runs warm-started OSQP, whose active set is then re-solved exactly and "
        "remembered.",
        "",
        "| measurement | value | reference | ratio | target | met |",
        "|---|---|---|---|---|---|",
        f"| env step, SDJLS-Macro-v0 vs Pendulum-v1 | {e['sdjls_us']:.1f} us | {e['pendulum_us']:.1f} us | "
        f"{e['ratio']:.2f}x | <= {t['env_step_ratio_max']}x | {ok(e['ratio'] <= t['env_step_ratio_max'])} |",
        f'| act(), solver="osqp" (default: warm active set, then OSQP) vs cvxpy rebuild | {a["act_osqp_us"]:.0f} us | {a["cvxpy_rebuild_us"]:.0f} us | '
        f"{a['speedup_osqp_vs_rebuild']:.0f}x faster | >= {t['act_speedup_vs_cvxpy_rebuild_min']:.0f}x | "
        f"{ok(a['speedup_osqp_vs_rebuild'] >= t['act_speedup_vs_cvxpy_rebuild_min'])} |",
        f"| act() calls answered by the active-set warm start (no OSQP), timed loop | "
        f"{100 * a['warm_start_share']:.1f}% | | | - | - |",
        f"| act() with the warm start disabled (OSQP at every call) vs cvxpy rebuild | "
        f"{a['act_osqp_every_call_us']:.0f} us | {a['cvxpy_rebuild_us']:.0f} us | "
        f"{a['speedup_osqp_every_call_vs_rebuild']:.0f}x faster | - | - |",
        f'| act(), solver="active_set" (full enumeration) vs cvxpy rebuild | {a["act_active_set_us"]:.0f} us | {a["cvxpy_rebuild_us"]:.0f} us | '
        f"{a['speedup_active_set_vs_rebuild']:.0f}x faster | (same) | "
        f"{ok(a['speedup_active_set_vs_rebuild'] >= t['act_speedup_vs_cvxpy_rebuild_min'])} |",
        f'| act(), solver="osqp" vs cvxpy Parameter problem | {a["act_osqp_us"]:.0f} us | {a["cvxpy_parametric_us"]:.0f} us | '
        f"{a['speedup_osqp_vs_parametric']:.0f}x faster | - | - |",
        f"| solutions: max abs difference of u (rebuild / Parameter / active set / OSQP at every call vs act()) | "
        f"{a['max_abs_diff_u']['rebuild']:.1e} / {a['max_abs_diff_u']['parametric']:.1e} / {a['max_abs_diff_u']['active_set']:.1e} "
        f"/ {a['max_abs_diff_u']['osqp_every_call']:.1e} "
        f"| | | <= {t['agreement_tol']:g} | {ok(max(a['max_abs_diff_u'].values()) <= t['agreement_tol'])} |",
        f"| batched closed loop ({b['num_envs']} envs, act_batch) | {b['batched_steps_per_second']:,.0f} steps/s | "
        f"{b['loop_steps_per_second']:,.0f} steps/s (loop) | {b['speedup_vs_loop']:.0f}x | >= {t['batched_speedup_vs_loop_min']:.0f}x and "
        f">= {t['batched_steps_per_second_min']:,.0f} steps/s | "
        f"{ok(b['speedup_vs_loop'] >= t['batched_speedup_vs_loop_min'] and b['batched_steps_per_second'] >= t['batched_steps_per_second_min'])} |",
        f"| act_batch vs act on the same states: max abs difference of u | {b['max_abs_diff_act_batch_vs_act']:.1e} | | | "
        f"<= {t['agreement_tol']:g} | {ok(b['max_abs_diff_act_batch_vs_act'] <= t['agreement_tol'])} |",
    ]
    tree = res["tree"]["rows"]
    three = next(row for row in tree if row["steps"] == 3 and row["branching"] == 3)
    lines += [
        f"| act(), ScenarioTreeController steps=3 vs its cvxpy reference (same tree) | "
        f"{three['act_us']:.0f} us | {three['cvxpy_us']:.0f} us | "
        f"{three['speedup_vs_cvxpy']:.0f}x faster | >= {t['tree_steps3_speedup_vs_cvxpy_min']:.0f}x | "
        f"{ok(three['speedup_vs_cvxpy'] >= t['tree_steps3_speedup_vs_cvxpy_min'])} |",
        "",
        "## Multi-step receding horizon (scenario tree)",
        "",
        "One decision of `ScenarioTreeController` on the macro example (closed-loop states of the "
        "paper's controller), against the same tree written plainly in cvxpy (Clarabel) and "
        "against one-step act() above. A decision solves the tree's QP once per fixed-point "
        "iteration on the branch probabilities (at most 10, the default; 'converged': no region probability "
        f"moved by more than {PROB_TOL:g} at the last one); the fast path re-solves the last "
        "active set exactly first (warm start) and runs OSQP only when it does not verify.",
        "",
        "| steps | branching | nodes | QP variables | act() | QP solves per decision | "
        "fixed point converged | solves by warm start | cvxpy reference | speedup | "
        "vs one-step act() | max abs diff of u (states) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in tree:
        lines.append(
            f"| {row['steps']} | {row['branching']} | {row['nodes']} | {row['variables']} | "
            f"{row['act_us']:,.0f} us | {row['qp_solves_per_decision']:.2f} | "
            f"{100 * row['fixed_point_converged_share']:.0f}% | "
            f"{100 * row['warm_start_share']:.0f}% | {row['cvxpy_us']:,.0f} us | "
            f"{row['speedup_vs_cvxpy']:.0f}x | {row['vs_one_step_act']:.0f}x | "
            f"{row['max_abs_diff_u_vs_cvxpy']:.1e} ({row['cvxpy_states']}) |"
        )
    lines += [
        "",
        "## Scaling",
        "",
        "| N modes | n states | synthesize_gains (s) | status | act() (us) |",
        "|---|---|---|---|---|",
    ]
    for row in s["synthesis_and_act"]:
        lines.append(
            f"| {row['N']} | {row['n']} | {row['synthesize_s']:.3f} | {row['status']} | {row['act_us']:.0f} |"
        )
    lines += ["", "| trajectories (20 steps) | seconds | per trajectory (us) |", "|---|---|---|"]
    for row in s["monte_carlo"]:
        lines.append(
            f"| {row['trajectories']:,} | {row['seconds']:.3f} | {1e6 * row['seconds'] / row['trajectories']:.1f} |"
        )
    lines += [
        "",
        f"Peak memory (RSS) of the process, largest Monte Carlo included: {s['peak_rss_mb']:.0f} MB.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.speed", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "--out", type=Path, default=Path("results/speed"), help="folder for speed.json and SPEED.md"
    )
    parser.add_argument(
        "--quick", action="store_true", help="small sizes and few repeats (a smoke test)"
    )
    parser.add_argument(
        "--repeats", type=int, default=None, help="repeats per measurement (default 7, quick 2)"
    )
    opts = parser.parse_args(argv)
    if opts.repeats is None:
        opts.repeats = 2 if opts.quick else 7
    if opts.repeats < 1:
        parser.error(f"--repeats = {opts.repeats}; expected a positive integer")
    opts.out.mkdir(parents=True, exist_ok=True)
    episodes = 50 if opts.quick else 500
    print("env step ...", flush=True)
    pend = env_step_time("Pendulum-v1", episodes, opts.repeats)
    sdj = env_step_time("SDJLS-Macro-v0", episodes, opts.repeats)
    res: dict[str, Any] = {
        "command": "python -m benchmarks.speed" + ("" if not argv else " " + " ".join(argv)),
        "machine": f"{platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}",
        "versions": package_versions(),
        "targets": TARGETS,
        "env_step": {"pendulum_us": 1e6 * pend, "sdjls_us": 1e6 * sdj, "ratio": sdj / pend},
    }
    print("act ...", flush=True)
    res["act"] = measure_act(opts)
    print("batched closed loop ...", flush=True)
    res["batched"] = measure_batched(opts)
    print("multi-step (scenario tree) ...", flush=True)
    res["tree"] = measure_tree(opts, res["act"]["act_osqp_us"])
    print("scaling ...", flush=True)
    res["scaling"] = measure_scaling(opts)
    (opts.out / "speed.json").write_text(json.dumps(res, indent=1) + "\n")
    md = write_markdown(res, res["command"])
    (opts.out / "SPEED.md").write_text(md)
    print(md)
    return res


if __name__ == "__main__":
    main()
