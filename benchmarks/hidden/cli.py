"""``python -m benchmarks.hidden``: every task with the mode hidden, every design against the
oracle that sees it, into ``results/hidden`` (``REPORT.md``, ``summary.json``, ``summary.csv``,
the figures).

The agents are the kept runs of ``python -m benchmarks.compare_rl --preset hidden`` (``--runs``,
found by the fingerprint of their configuration: ``--seeds``, ``--timesteps`` and ``--quick``
must be those they were trained with); a run not kept yet is named as missing. ``--no-agents``
scores the model-based designs alone (without stable-baselines3).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from benchmarks.core.aggregate import AGGREGATE_RESAMPLES
from benchmarks.core.cli import options_parser, output_folder, parse_options
from benchmarks.core.commands import prog
from benchmarks.core.evaluate import check_evaluation
from benchmarks.core.logs import log
from benchmarks.hidden.figures import across_figure, task_figure
from benchmarks.hidden.report import write_outputs
from benchmarks.hidden.score import EVAL_SEEDS, TaskResult, score_task
from benchmarks.hidden.summary import across_tasks
from sdjls_gym import SUITE

__all__ = ["DEFAULT_OUT", "Options", "main", "parse_args"]

DEFAULT_OUT = Path("results/hidden")
#: Stratified-bootstrap resamples of the aggregates with ``--quick``.
QUICK_RESAMPLES = 200


@dataclass
class Options:
    """The options of ``python -m benchmarks.hidden`` (``--help``)."""

    tasks: list[str] = field(
        default_factory=lambda: list(SUITE),
        metadata={"help": "tasks of the suite", "choices": SUITE},
    )
    configs: list[str] | None = field(
        default=None,
        metadata={"help": "agent configurations <algo>_<observation>_<variant> (default: the "
                  "hidden comparison's six, rl_hyperparams.HIDDEN_CONFIGS)", "metavar": "CONFIG"},
    )  # fmt: skip
    seeds: int | None = field(
        default=None,
        metadata={"help": "training seeds per configuration (default: the hidden comparison's)"},
    )
    timesteps: int | None = field(
        default=None,
        metadata={"help": "the agents' budget, if they were trained with compare_rl --timesteps"},
    )
    runs: Path | None = field(
        default=None,
        metadata={"help": "folder of the kept runs (default: <results/hidden>/runs)"},
    )
    out: Path | None = field(
        default=None,
        metadata={"help": "folder for REPORT.md, summary.json, summary.csv and the figures; "
                  "default results/hidden, or a new temporary folder with --quick"},
    )  # fmt: skip
    episodes: int | None = field(
        default=None,
        metadata={"help": "evaluation episodes per design, task and noise seed (the seeds "
                  f"{EVAL_SEEDS}, their episodes pooled); default 1000, 50 with --quick"},
    )  # fmt: skip
    quick: bool = field(
        default=False,
        metadata={"help": "smoke test: 50 episodes, 200 bootstrap resamples, the agents of "
                  "compare_rl --preset hidden --quick (their smoke-test budgets)"},
    )  # fmt: skip
    no_agents: bool = field(default=False, metadata={"help": "score the model-based designs alone"})
    workers: int = field(
        default=1,
        metadata={"help": "tasks scored at once, each in its own process (the same numbers for "
                  "any count)"},
    )  # fmt: skip


def parse_args(argv: list[str] | None = None) -> Options:
    """The options, each checked before any work (a bad one: exit status 2, naming it)."""
    parser = options_parser(
        Options,
        prog=prog("hidden"),
        description="Every task with the mode hidden: the oracle, certainty equivalence, the "
        "belief RHC and the hidden comparison's agents.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    opts = parse_options(parser, Options, argv)
    opts.tasks = list(dict.fromkeys(opts.tasks))
    if opts.episodes is None:
        opts.episodes = 50 if opts.quick else 1000
    try:
        check_evaluation(opts.episodes, EVAL_SEEDS)
    except ValueError as exc:
        parser.error(str(exc).replace("episodes = ", "--episodes = ", 1))
    for name in ("seeds", "timesteps", "workers"):
        value = getattr(opts, name)
        if value is not None and value < 1:
            parser.error(f"--{name} = {value}; expected a positive integer")
    if opts.configs is not None and not opts.no_agents:
        from benchmarks.rl import parse_config

        for config in opts.configs:
            try:
                parse_config(config)
            except ValueError as exc:
                parser.error(f"--configs: {exc}")
    opts.out = output_folder(parser, "--out", opts.out, quick=opts.quick, default=DEFAULT_OUT,
                             script="hidden")  # fmt: skip
    if opts.runs is None:
        opts.runs = DEFAULT_OUT / "runs"
    return opts


def _runs(opts: Options) -> list[Any]:
    """The kept runs of the agents (``benchmarks.rl``'s ``hidden_runs``), or none."""
    if opts.no_agents:
        return []
    from benchmarks.rl import hidden_runs

    assert opts.runs is not None
    return hidden_runs(opts.runs, tasks=opts.tasks, configs=opts.configs, seeds=opts.seeds,
                       timesteps=opts.timesteps, quick=opts.quick)  # fmt: skip


def _train_cpu_hours(runs: list[Any]) -> float | None:
    kept = [r.path for r in runs if r.path is not None]
    if not kept:
        return None
    from benchmarks.rl import read_run

    return sum(read_run(p).cpu_time_s or 0.0 for p in kept) / 3600.0


def _children_cpu() -> float:
    """CPU seconds of this process's finished children (the workers, once joined)."""
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def _score_one(task: str, runs: list[Any], episodes: int) -> TaskResult:
    """One task's :func:`score_task` (in this process or a worker's)."""
    if runs:
        import torch

        torch.set_num_threads(1)  # as in training, and for the agents' decision times
    log(f"scoring {task}: the oracle, 2 controllers, {sum(r.path is not None for r in runs)}"
        f" of {len(runs)} agent run(s) kept, {episodes} episodes x {len(EVAL_SEEDS)} "
        "noise seeds")  # fmt: skip
    return score_task(task, runs, episodes, log)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Score every design on every task and write the report; returns the summary."""
    argv = sys.argv[1:] if argv is None else list(argv)
    opts = parse_args(argv)
    out = Path(opts.out or DEFAULT_OUT)
    out.mkdir(parents=True, exist_ok=True)
    if opts.quick:
        log(f"--quick: writing to {out}")
    start, cpu0, child0 = time.perf_counter(), time.process_time(), _children_cpu()
    runs = _runs(opts)
    jobs = [(task, [r for r in runs if r.task == task], int(opts.episodes or 0))
            for task in opts.tasks]  # fmt: skip
    if opts.workers > 1 and len(jobs) > 1:
        spawn = get_context("spawn")
        with ProcessPoolExecutor(min(opts.workers, len(jobs)), mp_context=spawn) as pool:
            results = list(pool.map(_score_one, *zip(*jobs, strict=True)))
    else:
        results = [_score_one(*job) for job in jobs]
    configs = list(dict.fromkeys(r.configuration for r in runs))
    across = across_tasks(results, configs, QUICK_RESAMPLES if opts.quick else AGGREGATE_RESAMPLES)
    figures = {r.env_id: task_figure(out, r) for r in results}
    figures["across"] = across_figure(out, across)
    meta = {
        "command": "python -m benchmarks.hidden" + ("" if not argv else " " + " ".join(argv)),
        "options": {k: str(v) if isinstance(v, Path) else v for k, v in asdict(opts).items()},
        "runs": {
            "expected": len(runs),
            "kept": sum(r.path is not None for r in runs),
            "train_cpu_h": _train_cpu_hours(runs),
            "budgets": {r.configuration: r.timesteps for r in runs},
        },  # fmt: skip
        "scoring_wall_min": (time.perf_counter() - start) / 60,
        "scoring_cpu_min": (time.process_time() - cpu0 + _children_cpu() - child0) / 60,
    }
    summary = write_outputs(out, results, across, meta, figures)
    log(f"wrote {out}/REPORT.md")
    return summary
