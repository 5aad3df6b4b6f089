"""The RL wing: stable-baselines3 agents trained on the suite's tasks and scored by the core's
protocol against the receding-horizon controllers (``python -m benchmarks.compare_rl``,
:mod:`.compare`), their training environments (:mod:`.envs`, :mod:`.train_envs`,
:mod:`.hyperparams`), runs (:mod:`.train`, :mod:`.records`, :mod:`.runs`, :mod:`.backends`),
reports (:mod:`.report`, :mod:`.macro_report`, :mod:`.figures`, :mod:`.suite_report`,
:mod:`.suite_tables`, :mod:`.suite_figures`) and tuning (:mod:`.tune`, :mod:`.tune_summary`, :mod:`.tuned_report`).

Agents with the mode hidden: :mod:`.belief_env` (the mode filter's belief in the
observation), sb3-contrib's recurrent PPO, :mod:`.spec` (a run's configuration with its
observation), :mod:`.run_files` (its files).

The wing's public face (what another wing may import; never its modules): a kept run rebuilt
and scored (``load_agent``, ``score_run``, ``run_env``, ``read_run``), a task's training
environment (``make_train_env``, ``task_settings``), the suite comparison's budgets
(``SUITE_CONFIGS``, ``SUITE_SEEDS``, ``suite_timesteps``) and the hidden comparison's runs
(``hidden_runs``, ``KeptRun``, ``HIDDEN_CONFIG_NAMES``, ``HIDDEN_SEEDS``,
``HIDDEN_TIMESTEPS``, ``parse_config``). Importing it imports stable-baselines3.
"""

from benchmarks.rl.envs import make_train_env, parse_config, task_settings
from benchmarks.rl.hyperparams import (
    HIDDEN_SEEDS,
    HIDDEN_TIMESTEPS,
    SUITE_CONFIGS,
    SUITE_SEEDS,
    suite_timesteps,
)
from benchmarks.rl.runs import (
    HIDDEN_CONFIG_NAMES,
    KeptRun,
    hidden_runs,
    load_agent,
    read_run,
    run_env,
    score_run,
)

__all__ = [
    "HIDDEN_CONFIG_NAMES",
    "HIDDEN_SEEDS",
    "HIDDEN_TIMESTEPS",
    "SUITE_CONFIGS",
    "SUITE_SEEDS",
    "KeptRun",
    "hidden_runs",
    "load_agent",
    "make_train_env",
    "parse_config",
    "read_run",
    "run_env",
    "score_run",
    "suite_timesteps",
    "task_settings",
]
