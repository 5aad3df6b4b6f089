"""The kept runs of the RL comparison, usable: rebuild a run's agent and score it.

A run is kept as ``<name>-<fingerprint>.json`` (its record: configuration, learning curve,
times) beside ``.pt`` (the policy's state dict). :func:`load_agent` rebuilds the policy from the
configuration recorded in the file, with the wrappers of its training environment
(:func:`benchmarks.rl.train.env_from_config`, the recipe :func:`benchmarks.rl.envs.make_train_env`
follows), so that it acts on the raw environment in units of ``u``;
:func:`score_run` scores it on its own task (and ``python -m
benchmarks.evaluate --run PATH``).

>>> from benchmarks.rl.runs import load_agent, read_run  # doctest: +SKIP
>>> policy = load_agent("results/rl/runs/ppo_residual_s0-e884595880b28e6a.json")  # doctest: +SKIP
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks.core.evaluate import Score, check_evaluation, evaluate
from benchmarks.core.policies import RawEnvPolicy
from benchmarks.rl import hyperparams as HP
from benchmarks.rl.belief_env import BeliefAgentPolicy
from benchmarks.rl.envs import (
    AGENT_ALGOS,
    MACRO,
    VARIANTS,
    config_name,
    observation_of,
    parse_config,
    task_settings,
)
from benchmarks.rl.records import RunRecord
from benchmarks.rl.run_files import kept_run_path, policy_from_config, policy_path, run_path
from benchmarks.rl.spec import RunSpec, config_fingerprint, run_specs
from sdjls_gym import SUITE
from sdjls_gym.errors import InvalidRunError

__all__ = [
    "HIDDEN_CONFIG_NAMES",
    "KeptRun",
    "check_kept_runs",
    "hidden_runs",
    "load_agent",
    "read_run",
    "run_env",
    "score_run",
]

#: The names of the hidden comparison's configurations (:data:`HP.HIDDEN_CONFIGS`).
HIDDEN_CONFIG_NAMES: tuple[str, ...] = tuple(config_name(*c) for c in HP.HIDDEN_CONFIGS)


def _json_path(run_path: str | Path) -> Path:
    """``run_path`` as the record's path: ``NAME.json``, ``NAME.pt`` or ``NAME`` alike."""
    if not isinstance(run_path, (str, Path)) or isinstance(run_path, bool):
        raise TypeError(f"run_path = {run_path!r}; expected a path (str or pathlib.Path)")
    path = Path(run_path)
    if path.suffix in (".json", ".pt"):
        path = path.with_suffix(".json")
    else:
        path = path.with_name(path.name + ".json")
    if not path.is_file():
        raise InvalidRunError(f"run_path = {str(run_path)!r}: no run record {path} exists")
    if not policy_path(path).is_file():
        raise InvalidRunError(
            f"run_path = {str(run_path)!r}: the run's policy {policy_path(path)} is missing"
        )
    return path


def _record(path: Path) -> RunRecord:
    """The record in ``path``, checked: an :class:`InvalidRunError` says what is wrong (the
    caller names the file)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise InvalidRunError(f"is not a run record (not UTF-8 JSON: {exc})") from None
    except RecursionError:
        raise InvalidRunError("is not a run record (nested too deep to read)") from None
    if not isinstance(data, dict):
        raise InvalidRunError(
            f"is not a run record: it holds a JSON {type(data).__name__}; expected an object"
        )
    try:
        record = RunRecord.from_json(data)
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise InvalidRunError(f"is not a run record ({type(exc).__name__}: {exc})") from None
    config = record.config
    if (record.algo not in AGENT_ALGOS or record.variant not in VARIANTS
            or not isinstance(config, dict)):  # fmt: skip
        raise InvalidRunError(
            f"records algorithm {record.algo!r}, variant {record.variant!r}; expected one of "
            f"{AGENT_ALGOS} and {VARIANTS} with a configuration"
        )
    # what the fingerprint covers: the configuration; the record's own fields must agree with it
    fingerprint = config_fingerprint(config)
    if record.fingerprint != fingerprint:
        raise InvalidRunError(
            f"fingerprint = {record.fingerprint!r} recorded, but its configuration hashes to "
            f"{fingerprint!r}: the record was edited"
        )
    for field in ("algo", "variant", "seed"):
        if config.get(field) != getattr(record, field) or type(config.get(field)) is bool:
            raise InvalidRunError(
                f"{field} = {getattr(record, field)!r} recorded, {config.get(field)!r} in its "
                "configuration: the record was edited"
            )
    named = config_name(record.algo, record.variant, observation_of(config))
    if record.name != f"{named}_s{record.seed}" or path.stem not in (
        record.name,
        f"{record.name}-{record.fingerprint}",
    ):
        raise InvalidRunError(
            f"name = {record.name!r}, fingerprint {record.fingerprint!r}: they do not name the "
            f"file {path.name!r} (<configuration>_s<seed>-<fingerprint>.json): a renamed or "
            "edited record"
        )
    if "task" in config and not re.fullmatch(r"[0-9a-f]{16}", str(config.get("task_digest"))):
        raise InvalidRunError(
            f"task_digest = {config.get('task_digest')!r} in its configuration of task "
            f"{config['task']!r}; expected the digest of the task it was trained on"
        )
    if record.task != config.get("task", MACRO):
        raise InvalidRunError(
            f"task = {record.task!r} recorded, {config.get('task', MACRO)!r} in its "
            "configuration: the record was edited"
        )
    return record


def read_run(run_path: str | Path) -> RunRecord:
    """The :class:`~benchmarks.rl.train.RunRecord` kept at ``run_path`` (``.json``, ``.pt`` or the
    name without a suffix), checked.

    The record must be a JSON object of a run's fields; its fingerprint must be the hash of its
    configuration (:func:`benchmarks.rl.train.config_fingerprint`), which must agree with its
    algorithm, variant, seed and task; its file name must be its name and fingerprint; a run of
    the suite (a task in its configuration) must record its task's digest.

    Raises
    ------
    TypeError
        ``run_path`` is not a path.
    InvalidRunError
        (a :class:`ValueError`) The record or its policy is missing, or the record is not a run
        record or was edited; the message names the file and what is wrong.
    """
    path = _json_path(run_path)
    try:
        return _record(path)
    except InvalidRunError as exc:
        record = "" if Path(run_path) == path else f" (its record {path})"
        raise InvalidRunError(f"run_path = {str(run_path)!r}{record}: {exc}") from None


def run_env(run_path: str | Path) -> tuple[str, dict[str, Any]]:
    """``(env_id, env_kwargs)`` of the raw environment the run at ``run_path`` is scored on: its
    task (a run kept before the suite: the macro task) with the comparison's action bound, the
    one every controller and agent of the comparison acts within
    (:func:`benchmarks.rl.envs.comparison_env_kwargs`); a run trained with the mode hidden: with
    ``observe="state"``."""
    record = read_run(run_path)
    env_id = record.config.get("task", MACRO)
    kwargs = dict(record.config.get("env_kwargs", {}))
    kwargs["action_bound"] = task_settings(env_id, kwargs).u_bound
    if observation_of(record.config) != "mode":
        kwargs["observe"] = "state"
    return env_id, kwargs


def load_agent(run_path: str | Path) -> RawEnvPolicy | BeliefAgentPolicy:
    """The agent of the kept run at ``run_path``, acting on its raw environment.

    Rebuilt from the configuration the run recorded (its algorithm's policy network, its
    training environment's wrappers: the recipe of :func:`benchmarks.rl.envs.make_train_env`),
    not from today's tables, so a kept run loads after the defaults change.

    Parameters
    ----------
    run_path : str or Path
        ``runs/<name>-<fingerprint>.json`` or ``.pt`` (or the name without a suffix).

    Returns
    -------
    RawEnvPolicy or BeliefAgentPolicy
        ``act_batch(x, mode, k)`` / ``predict(obs)`` in units of ``u``, for
        :func:`benchmarks.evaluate.evaluate` with :func:`run_env`'s ``env_id`` and ``env_kwargs``
        (an agent trained with the mode hidden never reads it; a recurrent one keeps its LSTM
        state across an episode). An agent fed the mode filter's belief is a
        :class:`~benchmarks.rl.belief_env.BeliefAgentPolicy`: ``act_hidden(x, k, u_applied)``,
        with the filter kept per episode.

    Raises
    ------
    TypeError
        ``run_path`` is not a path.
    InvalidRunError
        (a :class:`ValueError`) See :func:`read_run`; also when the run's task changed since it
        was trained (its recorded task digest), when its configuration does not build an
        environment and a network, or when its policy file is truncated or does not fit that
        network (another run's policy). The message names the file.
    """
    path = _json_path(run_path)
    record = read_run(path)
    try:
        return policy_from_config(record.algo, record.variant, record.config, policy_path(path))
    except InvalidRunError as exc:
        raise InvalidRunError(f"run_path = {str(run_path)!r}: {exc}") from None
    except (AttributeError, IndexError, KeyError, TypeError, ValueError) as exc:
        raise InvalidRunError(
            f"run_path = {str(run_path)!r}: the configuration in {path} does not rebuild its "
            f"agent ({type(exc).__name__}: {exc})"
        ) from None


def check_kept_runs(specs: list[RunSpec], run_dir: Path) -> list[Path | None]:
    """The record file of each of ``specs``' kept runs under ``run_dir`` (None where it is
    missing), each loaded as :func:`load_agent` loads it, so that a command stops before any
    scoring when one is tampered with or corrupted.

    A run whose files are in the place of its configuration (``<task>/<name>-<fingerprint>``)
    but do not read as that run is refused, not counted as missing.

    Raises
    ------
    InvalidRunError
        Naming the file and what is wrong (:func:`load_agent`).
    """
    paths = []
    for spec in specs:
        path = kept_run_path(run_dir, spec)
        there = run_path(Path(run_dir) / spec.task, spec.name, spec.fingerprint())
        if path is None and there.exists():
            path = there  # in the run's place, but not readable as it: load_agent says why
        if path is not None:
            load_agent(path)
        paths.append(path)
    return paths


def score_run(run_path: Any, *, episodes: int = 1000, seed: int | tuple[int, ...] = 0) -> Score:
    """The :class:`Score` of the kept run at ``run_path`` (``runs/NAME.json``, ``.pt`` or the
    name without a suffix) on its own task, within the comparison's action bound
    (:func:`run_env`): its agent rebuilt by
    :func:`load_agent`, scored by :func:`benchmarks.core.evaluate.evaluate` on ``episodes`` episodes from
    noise seed ``seed`` (``python -m benchmarks.evaluate --run PATH``)."""
    episodes, seed = check_evaluation(episodes, seed)
    env_id, env_kwargs = run_env(run_path)
    return evaluate(load_agent(run_path), episodes=episodes, seed=seed, env_id=env_id,
                    env_kwargs=env_kwargs)  # fmt: skip


@dataclass(frozen=True)
class KeptRun:
    """One run a comparison asks for: its task, configuration name (``ppo_belief_reward``),
    seed and budget, and its kept record (None: not trained yet)."""

    task: str
    configuration: str
    seed: int
    timesteps: int
    path: Path | None


def hidden_runs(
    run_dir: str | Path,
    *,
    tasks: Sequence[str] | None = None,
    configs: Sequence[str] | None = None,
    seeds: int | None = None,
    timesteps: int | None = None,
    quick: bool = False,
) -> list[KeptRun]:
    """The runs of the hidden comparison (``python -m benchmarks.compare_rl --preset hidden``)
    and where each is kept under ``run_dir`` (None: missing), task by task.

    Defaults: every task of the suite, :data:`HIDDEN_CONFIG_NAMES`, :data:`HP.HIDDEN_SEEDS`
    seeds and the hidden budgets; ``timesteps`` replaces every budget and ``quick`` makes them
    the smoke test's, as the comparison's options do (the runs are found by the fingerprint of
    their whole configuration). Each kept run is loaded once (:func:`check_kept_runs`).

    Raises
    ------
    InvalidRunError
        A kept run that does not load (tampered with, truncated), naming its file.
    ValueError
        A configuration name that is not ``<algo>[_<observation>]_<variant>``.
    """
    keys = [parse_config(c) for c in (configs or HIDDEN_CONFIG_NAMES)]
    specs = run_specs(keys, HP.HIDDEN_SEEDS if seeds is None else seeds, timesteps, quick,
                      list(tasks or SUITE), budgets="hidden")  # fmt: skip
    paths = check_kept_runs(specs, Path(run_dir))
    return [KeptRun(s.task, s.configuration, s.seed, s.timesteps, p)
            for s, p in zip(specs, paths, strict=True)]  # fmt: skip
