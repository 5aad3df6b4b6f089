"""Agents with the mode hidden (issue 48): a run's configuration records its observation only
when it is not the default (every kept run keeps its fingerprint), the belief wrapper is the
mode filter's recursion, and each new kind of agent trains and is scored with the mode hidden."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("sb3_contrib")

from stable_baselines3.common.vec_env import DummyVecEnv  # noqa: E402

from benchmarks.core.evaluate import evaluate  # noqa: E402
from benchmarks.core.policies import RawEnvPolicy  # noqa: E402
from benchmarks.rl import compare as compare_rl  # noqa: E402
from benchmarks.rl import hidden_runs, load_agent, read_run, run_env  # noqa: E402
from benchmarks.rl import hyperparams as HP  # noqa: E402
from benchmarks.rl.belief_env import BeliefAgentPolicy  # noqa: E402
from benchmarks.rl.belief_vec import VecBeliefObservation  # noqa: E402
from benchmarks.rl.envs import (  # noqa: E402
    config_name,
    make_train_env,
    parse_config,
    task_settings,
)
from benchmarks.rl.spec import RunSpec  # noqa: E402
from benchmarks.rl.train import save_run, train_run  # noqa: E402
from controllers import ModeFilter  # noqa: E402
from sdjls_gym.errors import InvalidRunError  # noqa: E402
from sdjls_gym.systems import TASKS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TASK = "SDJLS-Degradation-v0"
HIDDEN = {"observe": "state"}
#: Tiny budgets: one rollout of 8 x 32 steps.
TINY = (("n_steps", 32), ("batch_size", 128))


# ----------------------------------------------------------------------------- configurations
def test_a_mode_observed_run_keeps_its_committed_fingerprint():
    """The configuration of a run with the mode observed has no observation entry, and the
    committed suite runs are found under their fingerprints."""
    spec = RunSpec("ppo", "lagrangian", 0, HP.suite_timesteps("SDJLS-Solar-v0", "ppo", "lagrangian"),
                   HP.LEARNING_CURVE["points"], HP.LEARNING_CURVE["episodes"],
                   HP.LEARNING_CURVE["seed"], task="SDJLS-Solar-v0")  # fmt: skip
    assert "observe" not in spec.config() and "features" not in spec.config()
    assert spec.name == "ppo_lagrangian_s0"
    kept = ROOT / "results/rl_suite/runs/SDJLS-Solar-v0" / f"{spec.name}-{spec.fingerprint()}.json"
    assert kept.is_file(), kept
    assert json.loads(kept.read_text())["fingerprint"] == spec.fingerprint()


@pytest.mark.parametrize(
    ("algo", "observation", "name", "extra"),
    [
        ("ppo", "state", "ppo_state_reward", {"observe": "state"}),
        ("recurrent_ppo", "state", "recurrent_ppo_state_reward", {"observe": "state"}),
        ("ppo", "belief", "ppo_belief_reward", {"observe": "state", "features": ["belief"]}),
    ],
)
def test_a_hidden_run_records_its_observation_and_is_named_apart(algo, observation, name, extra):
    spec = RunSpec(algo, "reward", 0, 1000, 2, 4, 1, task=TASK, observation=observation)
    observed = RunSpec("ppo", "reward", 0, 1000, 2, 4, 1, task=TASK)
    assert {k: spec.config()[k] for k in extra} == extra
    assert spec.configuration == name and spec.name == f"{name}_s0"
    assert spec.fingerprint() != observed.fingerprint()
    assert parse_config(name) == (algo, "reward", observation)
    assert config_name(algo, "reward", observation) == name
    assert spec.env_kwargs() == HIDDEN and observed.env_kwargs() == {}


def test_configuration_names_are_checked():
    with pytest.raises(ValueError, match="'ppo_hidden_reward'"):
        parse_config("ppo_hidden_reward")
    with pytest.raises(ValueError, match="observation"):
        RunSpec("ppo", "reward", 0, 10, 2, 4, 1, observation="belief_state")
    assert parse_config("sac_lagrangian") == ("sac", "lagrangian", "mode")


def test_the_hidden_preset_asks_for_every_task_configuration_and_seed():
    opts = compare_rl.parse_args(["--preset", "hidden", "--train-only"])
    specs = compare_rl.specs_of(opts)
    assert opts.out == Path("results/hidden") and len(specs) == 6 * 6 * 5
    assert {s.configuration for s in specs} == {config_name(*c) for c in HP.HIDDEN_CONFIGS}
    assert {s.observation for s in specs} == {"state", "belief"}
    assert all(s.timesteps == HP.hidden_timesteps(s.algo, s.observation) for s in specs)


# ----------------------------------------------------------------------------- the belief
def test_the_belief_in_the_observation_is_the_mode_filters():
    """Stepped by hand with ModeFilter.step on the exact states and the inputs applied, reset at
    each episode; the rest of the observation is the state-only training observation."""
    env = make_train_env(TASK, "reward", observation="belief")
    plain = make_train_env(TASK, "reward", observation="state")
    model = TASKS[TASK].model
    mode_filter = ModeFilter(model)
    rng = np.random.default_rng(3)
    obs, info = env.reset(seed=4)
    ref, _ = plain.reset(seed=4)
    belief = mode_filter.reset()
    episodes = 0
    for _ in range(100):
        assert np.allclose(obs[-model.N :], belief, atol=1e-6)
        assert np.array_equal(obs[: -model.N], ref)
        action = rng.uniform(-1, 1, size=env.action_space.shape).astype(np.float32)
        x, k = info["state"], info["k"]
        obs, _, terminated, truncated, info = env.step(action)
        ref, *_ = plain.step(action)
        belief = mode_filter.step(x, info["u"], info["state"], k)
        if terminated or truncated:
            episodes += 1
            assert np.allclose(obs[-model.N :], belief, atol=1e-6)
            obs, info = env.reset()
            ref, _ = plain.reset()
            belief = mode_filter.reset()
    assert episodes >= 2  # horizon 30: the resets were checked


def test_the_vector_wrapper_gives_the_single_wrappers_observations():
    singles = [make_train_env(TASK, "reward", observation="belief") for _ in range(3)]
    venv = VecBeliefObservation(DummyVecEnv(
        [lambda: make_train_env(TASK, "reward", observation="belief").env] * 3))  # fmt: skip
    venv.seed(5)
    got = venv.reset()
    assert np.array_equal(got, np.stack([e.reset(seed=5 + i)[0] for i, e in enumerate(singles)]))
    rng = np.random.default_rng(0)
    for _ in range(70):
        a = rng.uniform(-1, 1, (3, 1)).astype(np.float32)
        got, _, dones, infos = venv.step(a)
        rows = []
        for i, e in enumerate(singles):
            o, _, terminated, truncated, _ = e.step(a[i])
            if terminated or truncated:
                assert dones[i] and np.array_equal(infos[i]["terminal_observation"], o)
                o, _ = e.reset()
            rows.append(o)
        assert np.array_equal(got, np.stack(rows))


def test_a_belief_fed_agent_sees_on_the_raw_environment_what_it_saw_in_training():
    env = make_train_env(TASK, "reward", observation="belief")
    task, settings = TASKS[TASK], task_settings(TASK)
    n, N = task.model.n, task.model.N
    seen: list[np.ndarray] = []

    def act(obs: np.ndarray) -> np.ndarray:  # the likeliest mode's gain, in [-1, 1]
        x = obs[..., :n] * settings.x_scale
        K = task.K[np.argmax(obs[..., -N:], axis=-1)]
        u = np.einsum("...ij,...j->...i", K, x) / settings.u_bound
        return np.clip(u, -1, 1).astype(np.float32)

    class Spy:
        observation_space, action_space = env.observation_space, env.action_space

        def predict(self, obs, deterministic=True):
            seen.append(np.array(obs))
            return act(obs), None

    policy = BeliefAgentPolicy(Spy(), env)
    policy.reset(1)
    obs, info = env.reset(seed=2)
    applied, steps = None, 0
    for steps in range(1, 26):  # noqa: B007 - counted
        u, decision = policy.act_hidden(info["state"][None], np.array([info["k"]]), applied)
        assert np.array_equal(seen[-1][0], obs)
        assert np.allclose(decision["belief"][0], env.belief)
        obs, _, terminated, _, info = env.step(act(obs))
        assert np.allclose(info["u"], u[0], rtol=1e-6)
        applied = info["u"][None]
        if terminated:  # the training environment's end outside its bound
            break
    assert steps >= 20


# ----------------------------------------------------------------------------- end to end
@pytest.mark.parametrize(
    ("algo", "variant", "observation", "kind"),
    [
        ("ppo", "reward", "state", RawEnvPolicy),
        ("recurrent_ppo", "lagrangian", "state", RawEnvPolicy),
        ("ppo", "lagrangian", "belief", BeliefAgentPolicy),
    ],
)
def test_each_new_kind_trains_and_is_scored_with_the_mode_hidden(tmp_path, algo, variant,
                                                                  observation, kind):  # fmt: skip
    spec = RunSpec(algo, variant, 0, 256, 2, 4, 1, task=TASK, overrides=TINY,
                   observation=observation)  # fmt: skip
    record, policy = train_run(spec)
    assert record.config["observe"] == "state" and len(record.learning_curve) >= 2
    path = save_run(tmp_path, record, policy)
    assert read_run(path).name == spec.name
    # scored with the mode hidden, within the comparison's action bound (the agents' u_bound)
    assert run_env(path) == (TASK, {"action_bound": task_settings(TASK).u_bound, **HIDDEN})
    agent = load_agent(path)
    assert isinstance(agent, kind)
    score = evaluate(agent, episodes=6, seed=1, env_id=TASK, env_kwargs=HIDDEN)
    again = evaluate(load_agent(path), episodes=6, seed=1, env_id=TASK, env_kwargs=HIDDEN)
    assert np.array_equal(score.episode_costs, again.episode_costs)  # the memory reset per rollout
    assert score.episodes == 6 and np.isfinite(score.cost_mean)
    renamed = path.with_name(path.name.replace(spec.configuration, f"{algo}_{variant}"))
    path.rename(renamed)
    path.with_suffix(".pt").rename(renamed.with_suffix(".pt"))
    with pytest.raises(InvalidRunError, match="renamed or edited"):
        read_run(renamed)


def test_hidden_runs_finds_the_kept_runs_by_their_configuration(tmp_path):
    spec = RunSpec("ppo", "reward", 0, HP.QUICK_TIMESTEPS, 3, 20, HP.LEARNING_CURVE["seed"],
                   task=TASK, observation="state")  # fmt: skip
    record, policy = train_run(spec)
    save_run(tmp_path, record, policy)
    runs = hidden_runs(tmp_path, tasks=[TASK], configs=["ppo_state_reward", "ppo_belief_reward"],
                       seeds=2, quick=True)  # fmt: skip
    kept = {(r.configuration, r.seed): r.path is not None for r in runs}
    assert kept == {("ppo_state_reward", 0): True, ("ppo_state_reward", 1): False,
                    ("ppo_belief_reward", 0): False, ("ppo_belief_reward", 1): False}  # fmt: skip
