"""The kept runs of the RL comparison, usable: rebuild a run's agent and score it.

A run is kept as ``<name>-<fingerprint>.json`` (its record: configuration, learning curve,
times) beside ``.pt`` (the policy's state dict). :func:`load_agent` rebuilds the policy from the
configuration recorded in the file, with the wrappers of its training environment
(:func:`benchmarks.rl_train.env_from_config`, the recipe :func:`benchmarks.rl_envs.make_train_env`
follows), so that it acts on the raw environment in units of ``u``;
:func:`benchmarks.evaluate.score_run` scores it on its own task (and ``python -m
benchmarks.evaluate --run PATH``).

>>> from benchmarks.runs import load_agent, read_run  # doctest: +SKIP
>>> policy = load_agent("results/rl/runs/ppo_residual_s0-e884595880b28e6a.json")  # doctest: +SKIP
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from benchmarks.policies import RawEnvPolicy
from benchmarks.rl_envs import MACRO
from benchmarks.rl_train import ALGOS, VARIANTS, RunRecord, policy_from_config, policy_path

__all__ = ["load_agent", "read_run", "run_env"]


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
        raise ValueError(f"run_path = {str(run_path)!r}: no run record {path} exists")
    if not policy_path(path).is_file():
        raise ValueError(
            f"run_path = {str(run_path)!r}: the run's policy {policy_path(path)} is missing"
        )
    return path


def read_run(run_path: str | Path) -> RunRecord:
    """The :class:`~benchmarks.rl_train.RunRecord` kept at ``run_path`` (``.json``, ``.pt`` or the
    name without a suffix).

    Raises
    ------
    TypeError
        ``run_path`` is not a path.
    ValueError
        The record or its policy is missing, or the record is not a run of the comparison.
    """
    path = _json_path(run_path)
    try:
        data = json.loads(path.read_text())
        record = RunRecord.from_json(data)
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as exc:
        raise ValueError(
            f"run_path = {str(run_path)!r}: {path} is not a run record ({exc})"
        ) from None
    if record.algo not in ALGOS or record.variant not in VARIANTS or not record.config:
        raise ValueError(
            f"run_path = {str(run_path)!r}: algorithm {record.algo!r}, variant "
            f"{record.variant!r}; expected one of {ALGOS} and {VARIANTS} with a configuration"
        )
    return record


def run_env(run_path: str | Path) -> tuple[str, dict[str, Any]]:
    """``(env_id, env_kwargs)`` of the raw environment the run at ``run_path`` acts on (a run
    kept before the suite: the macro task)."""
    record = read_run(run_path)
    return record.config.get("task", MACRO), dict(record.config.get("env_kwargs", {}))


def load_agent(run_path: str | Path) -> RawEnvPolicy:
    """The agent of the kept run at ``run_path``, acting on its raw environment.

    Rebuilt from the configuration the run recorded (its algorithm's policy network, its
    training environment's wrappers: the recipe of :func:`benchmarks.rl_envs.make_train_env`),
    not from today's tables, so a kept run loads after the defaults change.

    Parameters
    ----------
    run_path : str or Path
        ``runs/<name>-<fingerprint>.json`` or ``.pt`` (or the name without a suffix).

    Returns
    -------
    RawEnvPolicy
        ``act_batch(x, mode, k)`` / ``predict(obs)`` in units of ``u``, for
        :func:`benchmarks.evaluate.evaluate` with :func:`run_env`'s ``env_id`` and ``env_kwargs``.

    Raises
    ------
    TypeError, ValueError
        See :func:`read_run`; also a ValueError when the run's task changed since it was
        trained (its recorded task digest).
    """
    path = _json_path(run_path)
    record = read_run(path)
    return policy_from_config(record.algo, record.variant, record.config, policy_path(path))
