"""The RL wing: stable-baselines3 agents trained on the suite's tasks and scored by the core's
protocol against the receding-horizon controllers (``python -m benchmarks.compare_rl``,
:mod:`.compare`), their training environments (:mod:`.envs`, :mod:`.train_envs`,
:mod:`.hyperparams`), runs (:mod:`.train`, :mod:`.records`, :mod:`.runs`, :mod:`.backends`),
reports (:mod:`.report`, :mod:`.figures`, :mod:`.suite_report`, :mod:`.suite_tables`,
:mod:`.suite_figures`) and tuning (:mod:`.tune`, :mod:`.tune_summary`, :mod:`.tuned_report`)."""
