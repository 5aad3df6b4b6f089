"""``python -m benchmarks.identify``: the learning curve of identify + RHC on every task of the
suite, beside the agents' (``results/identify/``).

Every option is checked before any work (a bad one: exit status 2, naming it). ``--quick`` is a
smoke test in seconds (two tasks, two budgets, one seed, 20 episodes) into a new temporary
folder; a run that is started again continues where it stopped (the points are cached in
``<out>/points/``).
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from benchmarks.core.cli import COMMITTED_RESULTS, option
from benchmarks.core.commands import prog
from benchmarks.core.logs import log
from sdjls_gym import SUITE

__all__ = ["DEFAULT_OUT", "QUICK", "SEEDS", "Options", "Settings", "main", "parse_args"]

#: The committed study.
DEFAULT_OUT = COMMITTED_RESULTS / "identify"
#: Seeds per task: the suite comparison's (``benchmarks.rl.SUITE_SEEDS``).
SEEDS = 5
#: The smoke test: tasks, budgets (episodes of the horizon), seeds, evaluation episodes.
QUICK: dict[str, Any] = {"tasks": ("SDJLS-Solar-v0", "SDJLS-Degradation-v0"),
                         "episodes_grid": (2, 10), "seeds": 1, "episodes": 20}  # fmt: skip


@dataclass
class Options:
    tasks: list[str] | None = option(
        None,
        f"tasks of the suite (default: all; with --quick: {', '.join(QUICK['tasks'])})",
        choices=SUITE,
        metavar="TASK",
    )
    seeds: int | None = option(
        None, f"exploration seeds 0..SEEDS-1 per task (default {SEEDS}; 1 with --quick)"
    )
    episodes: int | None = option(
        None,
        "evaluation episodes per point and evaluation seed (default 1000; "
        f"{QUICK['episodes']} with --quick)",
    )
    agents: str | None = option(
        None,
        "the suite comparison's summary.json to read the agents' learning "
        "curves from (default: results/rl_suite/summary.json)",
    )
    out: str | None = option(
        None,
        "output folder; default results/identify, or a new temporary folder "
        "with --quick (a smoke test never writes into the committed results)",
    )
    quick: bool = option(
        False,
        "smoke test: two tasks, budgets of 2 and 10 episodes, one seed, "
        f"{QUICK['episodes']} episodes",
    )


@dataclass(frozen=True)
class Settings:
    """The options with their defaults filled in and checked (:func:`parse_args`)."""

    tasks: tuple[str, ...]
    seeds: int
    episodes: int
    agents: str
    out: str
    quick: bool


def parse_args(argv: list[str] | None = None) -> Settings:
    """The options, each checked before any work, with their defaults filled in."""
    from benchmarks.core.cli import output_folder, parse_options, script_parser
    from benchmarks.core.evaluate import check_evaluation
    from benchmarks.identify.agents import DEFAULT_AGENTS
    from sdjls_gym.validation import check_int

    parser = script_parser(Options, "identify",
                           "Learn the model, then control: explore, identify, design the RHC on "
                           "the estimate, score it at the agents' budgets.")  # fmt: skip
    opts = parse_options(parser, Options, argv)
    quick = opts.quick
    seeds = opts.seeds if opts.seeds is not None else QUICK["seeds"] if quick else SEEDS
    episodes = opts.episodes if opts.episodes is not None else QUICK["episodes"] if quick else 1000
    try:
        check_int("--seeds", seeds, low=1, high=1000, what="exploration seeds per task")
        check_evaluation(episodes, 0)
    except ValueError as exc:
        parser.error(str(exc).replace("episodes = ", "--episodes = "))
    agents = str(DEFAULT_AGENTS) if opts.agents is None else opts.agents
    if opts.agents is not None and not Path(agents).is_file():
        parser.error(f"--agents {agents}: no such file; expected a suite comparison's "
                     "summary.json (python -m benchmarks.compare_rl)")  # fmt: skip
    out = output_folder(parser, "--out", opts.out, quick=quick, default=DEFAULT_OUT,
                        script="identify")  # fmt: skip
    tasks = tuple(dict.fromkeys(opts.tasks or (QUICK["tasks"] if quick else SUITE)))
    return Settings(tasks, seeds, episodes, agents, str(out), quick)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """``python -m benchmarks.identify``: see the module docstring and ``--help``."""
    from benchmarks.core.versions import CORE_PACKAGES, package_versions
    from benchmarks.identify.agents import read_agents
    from benchmarks.identify.figures import write_figures
    from benchmarks.identify.report import write_csv, write_report, write_summary
    from benchmarks.identify.run import EVAL_SEEDS, Plan, run_task
    from benchmarks.identify.steps import agent_budgets, step_grid
    from benchmarks.identify.summary import task_summary
    from sdjls_gym.systems import TASKS

    args = sys.argv[1:] if argv is None else list(argv)
    opts = parse_args(args)
    start, cpu0 = time.perf_counter(), time.process_time()
    out = Path(opts.out)
    out.mkdir(parents=True, exist_ok=True)
    agents = read_agents(opts.agents)
    log(f"writing into {out}; agents from {opts.agents} ({len(agents)} task(s))")
    results, tasks, explore_cpu = {}, [], 0.0
    for env_id in opts.tasks:
        task = TASKS[env_id]
        budgets = {} if opts.quick else agent_budgets(env_id)
        grid = (tuple(e * task.horizon for e in QUICK["episodes_grid"]) if opts.quick
                else step_grid(task, budgets.values()))  # fmt: skip
        plan = Plan(task, tuple(range(opts.seeds)), grid, opts.episodes)
        log(f"{env_id}: {len(grid)} budgets, {grid[0]} to {grid[-1]} steps, {opts.seeds} seed(s)")
        results[env_id] = run_task(plan, out, log)
        explore_cpu += results[env_id]["exploration_cpu_s"]
        tasks.append(task_summary(env_id, task.horizon, grid, plan.seeds, results[env_id],
                                  agents.get(env_id, []), budgets))  # fmt: skip
    command = " ".join([prog("identify"), *args])
    summary = {
        "command": command,
        "options": {**asdict(opts), "seeds": list(range(opts.seeds)),
                    "eval_seeds": list(EVAL_SEEDS), "out": _shown(opts.out),
                    "agents": _shown(opts.agents)},
        "versions": package_versions((*CORE_PACKAGES, "daqp")),
        "agents_source": _shown(opts.agents),
        "points": sum(len(r["points"]) + 1 for r in results.values()),
        "cpu_s": sum(t["cpu_s"] for t in tasks) + explore_cpu,
        "this_run": {"cpu_s": time.process_time() - cpu0,
                     "wall_s": time.perf_counter() - start, "exploration_cpu_s": explore_cpu},
        "tasks": tasks,
    }  # fmt: skip
    write_summary(out, summary)
    write_csv(out, tasks)
    summary["figures"] = write_figures(out, tasks)
    write_summary(out, summary)
    write_report(out, summary)
    log(f"done: {out / 'REPORT.md'} ({summary['this_run']['cpu_s']:.0f} s CPU in this run)")
    return summary


def _shown(path: str) -> str:
    """``path`` relative to the repository when it is inside it (a committed file names no
    machine's folders)."""
    resolved = Path(path).resolve()
    root = COMMITTED_RESULTS.parent
    return str(resolved.relative_to(root)) if root in resolved.parents else str(path)
