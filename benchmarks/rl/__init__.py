"""The RL wing: stable-baselines3 agents trained on the suite's tasks and scored by the core's
protocol against the receding-horizon controllers (``python -m benchmarks.compare_rl``,
:mod:`.compare`), their training environments (:mod:`.envs`, :mod:`.train_envs`,
:mod:`.hyperparams`), runs (:mod:`.train`, :mod:`.records`, :mod:`.runs`, :mod:`.backends`),
reports (:mod:`.report`, :mod:`.figures`, :mod:`.suite_report`, :mod:`.suite_tables`,
:mod:`.suite_figures`) and tuning (:mod:`.tune`, :mod:`.tune_summary`, :mod:`.tuned_report`).

The wing's public face (what another wing may import; never its modules): a kept run rebuilt
and scored (``load_agent``, ``score_run``, ``run_env``, ``read_run``), a task's training
environment (``make_train_env``, ``task_settings``) and the suite comparison's budgets
(``SUITE_CONFIGS``, ``SUITE_SEEDS``, ``suite_timesteps``). Importing it imports
stable-baselines3.
"""

from benchmarks.rl.envs import make_train_env, task_settings
from benchmarks.rl.hyperparams import SUITE_CONFIGS, SUITE_SEEDS, suite_timesteps
from benchmarks.rl.runs import load_agent, read_run, run_env, score_run

__all__ = [
    "SUITE_CONFIGS",
    "SUITE_SEEDS",
    "load_agent",
    "make_train_env",
    "read_run",
    "run_env",
    "score_run",
    "suite_timesteps",
    "task_settings",
]
