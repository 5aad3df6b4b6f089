"""``python -m benchmarks.suite``: score a policy on every task (``--policy``), or compute the
model-based references into ``results/suite/`` (:mod:`benchmarks.suite.report`)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from benchmarks.core.cli import option
from benchmarks.core.evaluate import check_evaluation
from benchmarks.core.suite import describe_suite, evaluate_suite
from sdjls_gym import SUITE
from sdjls_gym.messages import a_type

__all__ = ["Options", "main", "parse_args"]


@dataclass
class Options:
    policy: str | None = option(
        None,
        "package.module:factory, a function task -> policy (or a list of "
        "policies, one per run); without it, compute the model-based references",
    )
    tasks: list[str] = option(list(SUITE), "tasks of the suite", choices=SUITE)
    episodes: int | None = option(
        None, "episodes per task and controller, per noise seed; default 1000, 50 with --quick"
    )
    seed: int = option(0, "(first) noise seed")
    seeds: int | None = option(
        None,
        "noise seeds --seed, --seed + 1, ... whose episodes are pooled; "
        "default 3 for the references, 1 with --quick or --policy",
    )
    json: str | None = option(None, "with --policy: write the suite's score here")
    out: str | None = option(
        None,
        "references: output folder; default results/suite, or a new temporary "
        "folder with --quick (a smoke test never writes into the committed results)",
    )
    tree_episodes: int | None = option(
        None,
        "references: episodes per seed of the 3-step tree curve on every task "
        "(default: --episodes, the one-step curves' own episodes)",
    )
    workers: int = option(
        1,
        "references: processes running the 3-step tree's levels at once (each level run is "
        "kept in <out>/tree_levels, so an interrupted run resumes)",
    )
    quick: bool = option(
        False,
        "references, smoke test: 50 episodes, a coarse grid of xi, a 2-point "
        "tree curve on 10 episodes",
    )
    no_progress: bool = option(False, "do not show the progress bar")


def parse_args(argv: list[str] | None = None) -> tuple[Options, Any]:
    """The options, each checked before any work (a bad one: exit status 2, naming it); with
    ``--policy``, also the factory it names."""
    from benchmarks.core.cli import parse_options, script_parser

    parser = script_parser(Options, "suite", "Score a policy on every task of the suite, or "
                           "compute the model-based references (without --policy).")  # fmt: skip
    opts = parse_options(parser, Options, argv)
    opts.tasks = list(dict.fromkeys(opts.tasks))
    if opts.episodes is None:
        opts.episodes = 50 if opts.quick else 1000
    if opts.seeds is None:
        opts.seeds = 1 if opts.quick or opts.policy is not None else 3
    for name in ("seeds", "workers"):
        if getattr(opts, name) < 1:
            parser.error(f"--{name} = {getattr(opts, name)}; expected a positive integer")
    try:
        check_evaluation(opts.episodes, opts.seed)  # --seed itself, then every seed's
        check_evaluation(opts.episodes, tuple(range(opts.seed, opts.seed + opts.seeds)))
    except ValueError as exc:
        parser.error(
            str(exc).replace("episodes = ", "--episodes = ").replace("seed = ", "--seed = ")
        )
    if opts.tree_episodes is not None:
        try:
            check_evaluation(opts.tree_episodes, 0)
        except ValueError as exc:
            parser.error(str(exc).replace("episodes = ", "--tree-episodes = "))
    if opts.policy is not None:
        return opts, _factory(parser, opts)
    if opts.json is not None:
        parser.error("--json applies with --policy only (the references write into --out)")
    from benchmarks.core.cli import output_folder
    from benchmarks.suite.report import DEFAULT_OUT

    opts.out = str(output_folder(parser, "--out", opts.out, quick=opts.quick, default=DEFAULT_OUT,
                                 script="suite"))  # fmt: skip
    return opts, None


def _factory(parser: Any, opts: Options) -> Any:
    """With ``--policy``: the factory it names, the options checked against it."""
    from benchmarks.core.cli import CliError, file_option_error, import_attribute

    given = [f"--{n.replace('_', '-')}" for n in ("out", "tree_episodes", "quick")
             if getattr(opts, n) not in (None, False)]  # fmt: skip
    if given:
        parser.error(f"{', '.join(given)}: apply to the references (without --policy) only")
    if opts.json is not None and (error := file_option_error("--json", opts.json)):
        parser.error(error)
    try:
        factory = import_attribute(str(opts.policy), "--policy")
    except CliError as exc:
        parser.error(str(exc))
    if not callable(factory):
        parser.error(f"--policy {opts.policy} is {a_type(factory)}; expected a function "
                     "task -> policy")  # fmt: skip
    return factory


def main(argv: list[str] | None = None) -> Any:
    """``python -m benchmarks.suite``: see the module docstring and ``--help``."""
    import sys

    argv = sys.argv[1:] if argv is None else list(argv)
    opts, factory = parse_args(argv)
    if factory is None:
        from benchmarks.suite.report import run_references

        if opts.quick:
            print(f"--quick: writing to {opts.out}", file=sys.stderr)
        return run_references(opts, argv)
    from benchmarks.core.files import write_atomic
    from benchmarks.core.versions import package_versions

    if opts.episodes is None:
        raise ValueError("opts.episodes = None; expected the value parse_args fills in")
    count = opts.seeds or 1
    seeds = opts.seed if count == 1 else tuple(range(opts.seed, opts.seed + count))
    suite = evaluate_suite(factory, tuple(opts.tasks), opts.episodes, seeds,
                           progress=not opts.no_progress)  # fmt: skip
    print("\n".join(describe_suite(suite)))
    if opts.json is not None:
        data = {**suite.to_dict(), "policy": opts.policy, "versions": package_versions()}
        write_atomic(opts.json, json.dumps(data, indent=1) + "\n")
    return suite


if __name__ == "__main__":
    main()
