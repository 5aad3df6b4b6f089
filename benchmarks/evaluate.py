"""The public scoring protocol, and its command line ``python -m benchmarks.evaluate``.

>>> from benchmarks.evaluate import evaluate
>>> from controllers import LinearFeedbackController
>>> from sdjls_gym.systems.macro import PAPER_K, macro
>>> score = evaluate(LinearFeedbackController(macro(), PAPER_K), episodes=50)
>>> score.violation > 0.9, score.diverged
(True, 0)

The protocol lives in :mod:`benchmarks.core.evaluate` (its module docstring states it); this
module is its public face: :func:`evaluate`, :class:`Score`, :class:`RawEnvPolicy` and the
names users import from here, and the command line.

Command line: ``python -m benchmarks.evaluate --policy PATH.zip --algo ppo`` (an SB3 model;
``--train-env package.module:attribute`` names its training environment, ``--vec-normalize
PATH.pkl`` its VecNormalize statistics), ``--policy package.module:attribute``, or ``--run
runs/NAME.json`` (a kept run of the RL comparison, rebuilt by :func:`benchmarks.rl.runs.load_agent`
and scored on its own task); ``--json PATH`` writes the score. Every input is checked before the
evaluation; a bad one is a parser error (exit status 2) naming the file, module, attribute or
option.
"""

from __future__ import annotations

import json
from typing import Any

from benchmarks.core.cli import SB3_ALGOS, CliError, file_option_error, load_cli_policy
from benchmarks.core.commands import prog
from benchmarks.core.environment import (
    TaskEnv,
    check_fits,
    infer_env,
    resolve_env,
    rollout_statistics,
)
from benchmarks.core.evaluate import (
    MAX_EPISODES,
    Score,
    check_evaluation,
    describe_score,
    evaluate,
    evaluate_rollouts,
)
from benchmarks.core.files import write_atomic
from benchmarks.core.policies import RawEnvPolicy, as_controller
from benchmarks.core.reference import REFERENCE_CONSTRAINT, REFERENCE_XIS

__all__ = [
    "MAX_EPISODES",
    "REFERENCE_CONSTRAINT",
    "REFERENCE_XIS",
    "RawEnvPolicy",
    "Score",
    "TaskEnv",
    "check_evaluation",
    "evaluate",
    "evaluate_rollouts",
    "main",
    "resolve_env",
    "rollout_statistics",
]


def _parser() -> Any:
    import argparse
    from pathlib import Path

    parser = argparse.ArgumentParser(
        prog=prog("evaluate"),
        description="Score a policy with the benchmarks' evaluation protocol.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--policy",
                       help="a stable-baselines3 .zip file (with --algo), or "
                       "package.module:attribute (an object with predict, or a callable)")  # fmt: skip
    which.add_argument("--run", type=Path,
                       help="a kept run of the RL comparison (runs/NAME.json, .pt or NAME): its "
                       "agent rebuilt with its wrappers (benchmarks.rl.runs.load_agent) and scored "
                       "on its own task, within the comparison's action bound")  # fmt: skip
    parser.add_argument("--algo", choices=SB3_ALGOS, help="algorithm of a .zip file")
    parser.add_argument("--train-env", help="package.module:attribute: the .zip agent's training "
                        "environment (or a function making it), whose wrappers RawEnvPolicy "
                        "undoes; default: the agent acts on the raw environment")  # fmt: skip
    parser.add_argument("--vec-normalize", help="the VecNormalize statistics (.pkl) the .zip "
                        "agent was trained under (with --train-env)")  # fmt: skip
    parser.add_argument("--episodes", type=int, default=1000,
                        help="evaluation episodes per noise seed")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="(first) noise seed")
    parser.add_argument("--seeds", type=int, default=1,
                        help="noise seeds --seed, --seed + 1, ..., their episodes pooled")  # fmt: skip
    parser.add_argument("--env-id", default=None,
                        help="registered environment (None: the policy's own task: a "
                        "controller's model's, a --train-env's, a --run's; else SDJLS-Macro-v0)")  # fmt: skip
    parser.add_argument("--json", type=Path, help="write the score (and the versions) here")
    return parser


def _checked_options(parser: Any, argv: list[str]) -> Any:
    """The options; every input checked before the evaluation, each error naming its option."""
    opts = parser.parse_args(argv)
    if opts.seeds < 1:
        parser.error(f"--seeds = {opts.seeds}; expected a positive integer")
    opts.noise = opts.seed if opts.seeds == 1 else tuple(range(opts.seed, opts.seed + opts.seeds))
    try:
        check_evaluation(opts.episodes, opts.seed)  # --seed itself, then every seed's
        check_evaluation(opts.episodes, opts.noise)
    except ValueError as exc:
        parser.error(
            str(exc).replace("episodes = ", "--episodes = ").replace("seed = ", "--seed = ")
        )
    if opts.json is not None and (error := file_option_error("--json", opts.json)):
        parser.error(error)  # a folder, a block device, a folder that is missing or read-only
    return opts


def _run_env(parser: Any, opts: Any) -> dict[str, Any]:
    """With ``--run``: the kept run's environment (``opts.env_id`` set), its keyword arguments."""
    for flag in ("algo", "train_env", "vec_normalize"):
        if getattr(opts, flag) is not None:
            parser.error(f"--{flag.replace('_', '-')} does not apply to --run (a kept run "
                         "records its algorithm and training environment)")  # fmt: skip
    from benchmarks.rl.runs import run_env  # the RL wing, only for --run

    try:
        run_id, env_kwargs = run_env(opts.run)
    except (TypeError, ValueError) as exc:
        parser.error(str(exc).replace("run_path = ", "--run "))
    if opts.env_id is not None and opts.env_id != run_id:
        parser.error(f"--env-id {opts.env_id}: the run at {opts.run} acts on {run_id}; "
                     "leave --env-id out (a kept run is scored on its own task)")  # fmt: skip
    opts.env_id = run_id
    return env_kwargs


def _policy(parser: Any, opts: Any, env_kwargs: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
    """The policy to score and its environment's keyword arguments (``opts.env_id`` set),
    checked against each other."""
    try:
        if opts.run is not None:
            from benchmarks.rl.runs import load_agent  # the RL wing, only for --run

            policy = load_agent(opts.run)
        else:
            policy = load_cli_policy(opts.policy, opts.algo, opts.train_env, opts.vec_normalize)
        opts.env_id, env_kwargs, how = infer_env(policy, opts.env_id, env_kwargs)
        spec = resolve_env(opts.env_id, dict(env_kwargs))
        check_fits(policy, spec, how)
        as_controller(policy, spec)  # the agent's spaces against the environment's
    except (CliError, TypeError, ValueError) as exc:
        message = str(exc).replace("run_path = ", "--run ")
        if isinstance(exc, ValueError) and "RawEnvPolicy(agent, train_env)" in message:
            message = f"--policy {opts.policy}: {message}"
        parser.error(message.replace("env_id = ", "--env-id = "))
    return policy, env_kwargs


def main(argv: list[str] | None = None) -> Score:
    """``python -m benchmarks.evaluate``: score a policy (``--policy``) or a kept run
    (``--run``) and print its row; see the module docstring and ``--help``."""
    import sys

    from benchmarks.core.versions import package_versions

    argv = sys.argv[1:] if argv is None else list(argv)
    parser = _parser()
    opts = _checked_options(parser, argv)
    env_kwargs = _run_env(parser, opts) if opts.run is not None else {}
    name = opts.policy if opts.run is None else str(opts.run)
    policy, env_kwargs = _policy(parser, opts, env_kwargs)
    try:
        score = evaluate(policy, episodes=opts.episodes, seed=opts.noise, env_id=opts.env_id,
                         env_kwargs=env_kwargs)  # fmt: skip
    except (TypeError, ValueError) as exc:
        parser.error(str(exc))
    print("\n".join(describe_score(name, score)))
    if opts.json is not None:
        data = {**score.to_dict(), "policy": name, "versions": package_versions()}
        write_atomic(opts.json, json.dumps(data, indent=1) + "\n")
    return score


if __name__ == "__main__":
    main()


if __name__ == "__main__":
    main()
