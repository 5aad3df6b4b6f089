"""Deprecated alias of :mod:`benchmarks.rl.train_envs`, kept for one release: saved agents and
rl-zoo3 files that name ``--train-env benchmarks.train_envs:VARIANT`` keep working."""

from benchmarks.rl.train_envs import beta100, beta1000, beta10000, lagrangian, residual, reward

__all__ = ["beta100", "beta1000", "beta10000", "lagrangian", "residual", "reward"]
