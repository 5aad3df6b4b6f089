"""The files a run of the RL comparison is kept in, and its policy rebuilt from them.

:func:`save_run` writes a run under ``runs/<task>/<name>-<fingerprint>.json`` and ``.pt``, named
by the run's whole configuration hashed into :meth:`~benchmarks.rl.spec.RunSpec.fingerprint`, so
that a run of another configuration never replaces a kept one; :func:`load_run` reads the kept
run of a spec back (also the macro comparison's runs kept before the suite,
:meth:`~benchmarks.rl.spec.RunSpec.legacy_fingerprint`); :func:`policy_from_config` rebuilds the
trained policy from the configuration a run recorded, acting on the raw environment
(:func:`benchmarks.rl.belief_env.agent_policy`).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

from benchmarks.core.files import write_atomic
from benchmarks.core.policies import RawEnvPolicy
from benchmarks.rl.belief_env import BeliefAgentPolicy, agent_policy
from benchmarks.rl.envs import env_from_config
from benchmarks.rl.records import RunRecord
from benchmarks.rl.spec import RunSpec
from sdjls_gym.errors import InvalidRunError

__all__ = [
    "kept_run_path",
    "load_policy",
    "load_run",
    "policy_from_config",
    "policy_path",
    "run_path",
    "save_run",
]


def run_path(run_dir: str | Path, name: str, fingerprint: str) -> Path:
    """``run_dir/<name>-<fingerprint>.json``: a run's record is named by its whole configuration,
    so that a run of another configuration (``--quick``, ``--timesteps``, changed
    hyperparameters) lands beside a kept run and never replaces it."""
    return Path(run_dir) / f"{name}-{fingerprint}.json"


def policy_path(json_path: str | Path) -> Path:
    """Where the trained policy of the run recorded in ``json_path`` is kept."""
    return Path(json_path).with_suffix(".pt")


def save_run(run_dir: Path, record: RunRecord, policy: bytes) -> Path:
    """Write ``<task>/<name>-<fingerprint>.pt`` then ``.json`` under ``run_dir`` (a JSON file
    implies its policy), each atomically (:func:`benchmarks.core.files.write_atomic`); only a run of
    the same configuration (``--retrain``) is replaced."""
    path = run_path(Path(run_dir) / record.task, record.name, record.fingerprint)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(policy_path(path), policy)
    write_atomic(path, json.dumps(record.to_json()) + "\n")
    return path


def kept_run_path(run_dir: Path, spec: RunSpec) -> Path | None:
    """The record file of the kept run of ``spec`` (with its policy beside it), or None.

    Reads ``run_dir/<task>/<name>-<fingerprint>.json``; on the macro task also the layouts of
    the macro comparison before the suite (read, never written): ``run_dir/<name>-<fp>.json``
    and ``run_dir/<name>.json``, where ``fp`` is the run's fingerprint or
    :meth:`RunSpec.legacy_fingerprint` and the file records it."""
    fingerprint = spec.fingerprint()
    candidates = [(run_path(Path(run_dir) / spec.task, spec.name, fingerprint), {fingerprint})]
    legacy = spec.legacy_fingerprint()
    if legacy is not None:
        accepted = {fingerprint, legacy}
        candidates += [(run_path(run_dir, spec.name, fp), accepted) for fp in (fingerprint, legacy)]
        candidates.append((Path(run_dir) / f"{spec.name}.json", accepted))
    for path, accepted in candidates:
        if not (path.exists() and policy_path(path).exists()):
            continue
        try:
            data = json.loads(path.read_text())
        except (ValueError, RecursionError):  # not JSON, or nested too deep to read
            continue
        if isinstance(data, dict) and data.get("fingerprint") in accepted:
            return path
    return None


def load_run(run_dir: Path, spec: RunSpec) -> RunRecord | None:
    """The kept run of ``spec``, or None if it is missing, unreadable or of another configuration."""
    path = kept_run_path(run_dir, spec)
    return None if path is None else RunRecord.from_json(json.loads(path.read_text()))


def policy_from_config(
    algo: str, variant: str, config: dict[str, Any], path: str | Path
) -> RawEnvPolicy | BeliefAgentPolicy:
    """The policy whose state dict is at ``path``, rebuilt from a run's recorded ``config``
    (its hyperparameters' ``policy_kwargs`` and its training environment,
    :func:`env_from_config`), acting on the raw environment: a ``RawEnvPolicy`` (a recurrent
    agent keeps its LSTM state across an episode there), or for an agent fed the mode filter's
    belief a :class:`~benchmarks.rl.belief_env.BeliefAgentPolicy`, which keeps the filter per
    episode (:func:`~benchmarks.rl.belief_env.agent_policy`).

    Raises
    ------
    InvalidRunError
        The file at ``path`` is not a state dict (truncated, not torch's) or does not fit the
        network ``config`` describes.
    """
    import torch
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.base_class import BaseAlgorithm

    env = env_from_config(config, variant)
    classes: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "sac": SAC, "td3": TD3}
    if algo == "recurrent_ppo":
        from sb3_contrib import RecurrentPPO

        classes[algo] = RecurrentPPO
    cls = classes[algo]
    kwargs = copy.deepcopy(config["hyperparams"].get("policy_kwargs", {}))
    policy = cls.policy_aliases["MlpLstmPolicy" if algo == "recurrent_ppo" else "MlpPolicy"](
        env.observation_space, env.action_space, lambda _: 0.0, **kwargs
    )
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - truncated, not torch's, or not weights alone
        raise InvalidRunError(
            f"the policy file {path} cannot be read ({type(exc).__name__}: "
            f"{' '.join(str(exc).split())[:200]}); expected the state dict a training saved"
        ) from None
    try:
        policy.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as exc:  # another network's weights
        raise InvalidRunError(
            f"the policy file {path} does not fit the {algo.upper()} network its run record "
            f"describes ({' '.join(str(exc).split())[:200]}): another run's policy, or an edited "
            "record"
        ) from None
    policy.set_training_mode(False)
    return agent_policy(policy, env)


def load_policy(spec: RunSpec, path: str | Path) -> RawEnvPolicy | BeliefAgentPolicy:
    """The trained policy of ``spec`` from its state dict at ``path``, acting on the raw env."""
    return policy_from_config(spec.algo, spec.variant, spec.config(), path)
