"""``benchmarks.evaluate``: every input checked before any work, and an agent scored the wrong way
refused (issue 28, sections 3 and 4)."""

from __future__ import annotations

import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest
from conftest import raises_naming

from benchmarks import evaluate as evaluate_module
from benchmarks.evaluate import MAX_EPISODES, RawEnvPolicy, evaluate, main
from benchmarks.rl import compare as compare_rl
from controllers import LinearFeedbackController
from sdjls_gym import SDJLSModel
from sdjls_gym.errors import NotANumberError
from sdjls_gym.systems.macro import PAPER_K, macro

E = 30  # episodes per evaluation in these tests


# ------------------------------------------------------------------ compare_rl's options
@pytest.mark.parametrize(
    ("argv", "shown"),
    [
        (["--seed", "-1"], "--seed = -1"),
        (["--eval-episodes", "1000000000"], "--eval-episodes = 1000000000"),
        (["--eval-episodes", "1"], "--eval-episodes = 1"),
    ],
)
def test_compare_rl_refuses_what_evaluate_refuses_at_parse_time(argv, shown, capsys):
    with pytest.raises(SystemExit) as exc:
        compare_rl.parse_args(argv)
    assert exc.value.code == 2
    assert shown in capsys.readouterr().err


def test_compare_rl_limits_are_evaluates_limits():
    """The parse-time checks are evaluate()'s own: its largest episode count passes both (one
    noise seed; with three, a third of it per seed)."""
    one = ["--eval-episodes", str(MAX_EPISODES), "--eval-seeds", "1"]
    assert compare_rl.parse_args(one).eval_episodes == MAX_EPISODES
    assert compare_rl.parse_args(["--eval-episodes", str(MAX_EPISODES // 3)]).eval_seeds == 3
    with pytest.raises(SystemExit):
        compare_rl.parse_args(["--eval-episodes", str(MAX_EPISODES // 3 + 1)])
    assert compare_rl.parse_args(["--seed", "0"]).seed == 0
    feedback = LinearFeedbackController(macro(), PAPER_K, horizon=20)
    with raises_naming(ValueError, "episodes", MAX_EPISODES + 1):
        evaluate(feedback, episodes=MAX_EPISODES + 1)


# ------------------------------------------------------------------ the policy's actions
@pytest.mark.parametrize("action", ["1.0", True, np.array([True]), ["1.0"]])
def test_an_action_env_step_refuses_is_refused_by_evaluate(action):
    """env.step raises NotANumberError for these; evaluate applied np.asarray(.., float) and
    scored them as 1.0."""
    env = gym.make("SDJLS-Macro-v0")
    env.reset(seed=0)
    with pytest.raises(NotANumberError):
        env.step(action)
    with raises_naming(NotANumberError, "the policy's action", action):
        evaluate(lambda obs: action, episodes=E)

    class Agent:
        def predict(self, obs, deterministic=True):
            return action, None

    with pytest.raises(NotANumberError):
        evaluate(Agent(), episodes=E)


def test_a_policy_returning_none_is_named_so():
    with raises_naming(NotANumberError, "policy", None) as exc:  # README: None is named
        evaluate(lambda obs: None, episodes=E)
    assert "non-finite" not in str(exc.value)

    class Agent:
        def predict(self, obs, deterministic=True):
            return None, None

    with raises_naming(NotANumberError, "policy", None):
        evaluate(Agent(), episodes=E)


def test_an_episode_past_the_state_limit_in_one_step_is_a_diverged_episode():
    """x jumps from 1e5 to 1e101 (beyond the 1e100 a controller accepts) in one step: the
    episode is diverged, and the controller never sees that state (it raised ValueError)."""
    model = SDJLSModel(A=[[[1e96]]], B=[[[1.0]]], E=[[[1.0]]], W=[[1.0]], P_in=[[1.0]],
                       P_out=[[1.0]], G=[[1.0], [-1.0]], H0=[1e3, 1e3], Q=[[1.0]], R=[[1.0]],
                       x0=[1e5])  # fmt: skip
    controller = LinearFeedbackController(model, np.zeros((1, 1, 1)), horizon=5)
    score = evaluate(controller, episodes=4, env_id="SDJLS-v0",
                     env_kwargs={"model": model, "horizon": 5})  # fmt: skip
    assert score.diverged == 4 and score.violation == 1.0


# ------------------------------------------------------------------ scoring the wrong way
def test_a_class_instead_of_an_agent_is_named():
    def dotted(cls):  # how the message shows a class
        return f"{cls.__module__}.{cls.__qualname__}"

    with raises_naming(TypeError, "policy", dotted(LinearFeedbackController)):
        evaluate(LinearFeedbackController, episodes=E)
    sb3 = pytest.importorskip("stable_baselines3")
    with raises_naming(TypeError, "policy", dotted(sb3.PPO)):
        evaluate(sb3.PPO, episodes=E)
    with raises_naming(TypeError, "agent", dotted(sb3.PPO)):
        RawEnvPolicy(sb3.PPO, gym.make("SDJLS-Macro-v0"))


def test_max_episode_steps_alone_suggests_the_horizon():
    feedback = LinearFeedbackController(macro(), PAPER_K)
    with raises_naming(ValueError, ("max_episode_steps", "horizon"), 10) as exc:
        evaluate(feedback, episodes=E, env_kwargs={"max_episode_steps": 10})
    assert "horizon=10" in str(exc.value)


def test_an_unknown_env_id_is_a_value_error_naming_it():
    feedback = LinearFeedbackController(macro(), PAPER_K)
    with raises_naming(ValueError, "env_id", "SDJLS-Macro-v9"):
        evaluate(feedback, episodes=E, env_id="SDJLS-Macro-v9")


def _trained_behind_wrappers():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from benchmarks.rl.train import make_train_env

    env = make_train_env("residual", 1000.0, None, PAPER_K)
    return PPO("MlpPolicy", env, n_steps=64, batch_size=64, seed=0, device="cpu"), env


def test_an_agent_of_other_spaces_is_refused_naming_raw_env_policy():
    """An agent trained behind wrappers (observations scaled, actions in [-1, 1]) scored on the
    raw environment: every episode would diverge without a word."""
    agent, train_env = _trained_behind_wrappers()
    # README: the refusal names RawEnvPolicy and --train-env
    names = ("agent's observation space", "RawEnvPolicy", "--train-env")
    with raises_naming(ValueError, names, agent.observation_space):
        evaluate(agent, episodes=E)
    # RawEnvPolicy with the wrong training env (the raw one, or other wrappers)
    with raises_naming(ValueError, names, agent.observation_space):
        RawEnvPolicy(agent, gym.make("SDJLS-Macro-v0"))
    from sdjls_gym.wrappers import ScaleObservationReward

    # no RescaleAction: u in [-200, 200]
    with raises_naming(ValueError, ("agent's action space", "RawEnvPolicy"), agent.action_space):
        RawEnvPolicy(agent, ScaleObservationReward(gym.make("SDJLS-Macro-v0")))
    # the right one is accepted; and an agent on another action bound than the scored env
    assert evaluate(RawEnvPolicy(agent, train_env), episodes=E).episodes == E


def test_vec_normalize_statistics_are_applied():
    """An agent trained under VecNormalize sees normalized observations: RawEnvPolicy applies
    the saved statistics (frozen), whether given the VecNormalize, or the advice's
    venv.envs[0] of an agent that still holds it."""
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from benchmarks.rl.train import make_train_env

    venv = VecNormalize(DummyVecEnv([lambda: make_train_env("residual", 1000.0, None, PAPER_K)]))
    rng = np.random.default_rng(0)
    venv.obs_rms.mean = rng.normal(size=6)
    venv.obs_rms.var = rng.uniform(0.1, 4.0, size=6)

    class Seen:
        observation_space = venv.observation_space
        action_space = venv.action_space

        def predict(self, obs, deterministic=True):
            self.obs = np.array(obs)
            return np.zeros((len(obs), 1), dtype=np.float32), None

    inner = venv.envs[0]
    obs, info = inner.reset(seed=2)
    for policy_env in (venv, inner):
        agent = Seen()
        norm = venv if policy_env is inner else None
        RawEnvPolicy(agent, policy_env, vec_normalize=norm).act(info["state"], info["mode"], 0)
        np.testing.assert_allclose(agent.obs[0], venv.normalize_obs(obs), rtol=1e-6, atol=1e-6)
    agent = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, seed=0, device="cpu")
    policy = RawEnvPolicy(agent, inner)  # the agent's own VecNormalize
    u, _ = policy.act(info["state"], info["mode"], 0)
    a, _ = agent.predict(venv.normalize_obs(obs), deterministic=True)
    np.testing.assert_allclose(u, PAPER_K[info["mode"]] @ info["state"] + 100.0 * a, rtol=1e-5)
    before = venv.obs_rms.mean.copy()
    venv.obs_rms.mean += 1.0  # the statistics were copied: later training does not move them
    seen = Seen()
    frozen = RawEnvPolicy(seen, venv)
    venv.obs_rms.mean = before
    frozen.act(info["state"], info["mode"], 0)
    assert not np.allclose(seen.obs[0], venv.normalize_obs(obs))


class Recurrent:
    """SB3's recurrent predict signature; records what it is passed; its state is a step
    counter per row; it acts as the paper's stabilizing gains (no episode diverges)."""

    def __init__(self):
        self.calls = []
        self.gains = LinearFeedbackController(macro(), PAPER_K, horizon=20)

    def predict(self, observation, state=None, episode_start=None, deterministic=False):
        obs = np.atleast_2d(observation)
        self.calls.append((state, np.array(episode_start), len(obs)))
        count = np.zeros(len(obs)) if state is None else state[0].copy()
        count[np.asarray(episode_start, dtype=bool)] = 0
        return self.gains.predict(obs)[0], (count + 1,)


def test_a_recurrent_agent_keeps_its_state_through_an_episode():
    """As SB3's evaluate_policy: the state returned at one step is passed at the next,
    episode_start is True at each episode's first step only."""
    agent = Recurrent()
    evaluate(agent, episodes=E)
    rollout = [c for c in agent.calls if c[2] == E][:20]
    assert len(rollout) == 20
    state0, start0, _ = rollout[0]
    assert state0 is None and start0.all()
    for state, start, _ in rollout[1:]:
        assert state is not None and not start.any()
    for k in range(1, 20):  # what it returned at k - 1 comes back at k
        np.testing.assert_array_equal(rollout[k][0][0], np.full(E, float(k)))


def test_sb3_contrib_recurrent_ppo_is_scored_with_its_memory():
    sb3_contrib = pytest.importorskip("sb3_contrib")
    agent = sb3_contrib.RecurrentPPO("MlpLstmPolicy", gym.make("SDJLS-Macro-v0"), n_steps=32,
                                     batch_size=32, seed=0, device="cpu")  # fmt: skip
    calls = []
    real = agent.predict

    def recording(observation, state=None, episode_start=None, deterministic=False):
        calls.append((state, np.array(episode_start)))
        return real(observation, state=state, episode_start=episode_start,
                    deterministic=deterministic)  # fmt: skip

    agent.predict = recording
    score = evaluate(agent, episodes=E)
    assert score.episodes == E
    assert calls[0][0] is None and calls[0][1].all()
    assert calls[1][0] is not None and not calls[1][1].any()  # the LSTM's state carried


# ------------------------------------------------------------------ the command line
def _cli_error(argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    return capsys.readouterr().err


def test_cli_names_a_missing_module_attribute_or_env_id(tmp_path, monkeypatch, capsys):
    (tmp_path / "my_policies.py").write_text("def good(obs):\n    return [0.0]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    err = _cli_error(["--policy", "no_such_module_xyz:policy"], capsys)
    assert "no_such_module_xyz" in err and "Traceback" not in err
    err = _cli_error(["--policy", "my_policies:missing"], capsys)
    assert "'missing'" in err and "my_policies" in err
    err = _cli_error(["--policy", "my_policies:good", "--env-id", "SDJLS-Nope-v0"], capsys)
    assert "SDJLS-Nope-v0" in err


def test_cli_refuses_json_into_a_missing_folder_before_the_evaluation(tmp_path, monkeypatch,
                                                                        capsys):  # fmt: skip
    (tmp_path / "pol.py").write_text("def policy(obs):\n    return [0.0]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    ran = []
    monkeypatch.setattr(evaluate_module, "evaluate", lambda *a, **k: ran.append(1))
    target = tmp_path / "no" / "such" / "score.json"
    err = _cli_error(["--policy", "pol:policy", "--json", str(target)], capsys)
    assert str(target.parent) in err and not ran
    err = _cli_error(["--policy", "pol:policy", "--episodes", "1"], capsys)
    assert "--episodes = 1" in err and not ran
    err = _cli_error(["--policy", "pol:policy", "--seed", "-3"], capsys)
    assert "--seed = -3" in err and not ran


def test_cli_names_a_missing_corrupt_or_foreign_zip(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import SAC

    missing = tmp_path / "x.zip"
    err = _cli_error(["--policy", str(missing), "--algo", "ppo"], capsys)
    assert f"{missing}: no such file" in err and "x.zip.zip" not in err
    corrupt = tmp_path / "corrupt.zip"
    corrupt.write_bytes(b"PK\x03\x04 not a zip at all")
    err = _cli_error(["--policy", str(corrupt), "--algo", "ppo"], capsys)
    assert str(corrupt) in err and "cannot be loaded" in err
    empty = tmp_path / "empty.zip"
    with zipfile.ZipFile(empty, "w") as archive:
        archive.writestr("readme.txt", "no agent here")
    assert str(empty) in _cli_error(["--policy", str(empty), "--algo", "ppo"], capsys)
    sac = tmp_path / "sac.zip"
    SAC("MlpPolicy", gym.make("SDJLS-Macro-v0"), learning_starts=0, buffer_size=100, seed=0,
        device="cpu").save(sac)  # fmt: skip
    err = _cli_error(["--policy", str(sac), "--algo", "ppo"], capsys)
    assert str(sac) in err and "SAC" in err and "--algo sac" in err


def test_cli_refuses_an_agent_trained_behind_wrappers_without_train_env(tmp_path, capsys):
    agent, _ = _trained_behind_wrappers()
    path = tmp_path / "agent.zip"
    agent.save(path)
    err = _cli_error(["--policy", str(path), "--algo", "ppo", "--episodes", "20"], capsys)
    assert "--train-env" in err and "RawEnvPolicy" in err and str(path) in err


def test_cli_applies_saved_vec_normalize_statistics(tmp_path, monkeypatch, capsys):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from benchmarks.rl.train import make_train_env

    venv = VecNormalize(DummyVecEnv([lambda: make_train_env("residual", 1000.0, None, PAPER_K)]))
    venv.obs_rms.mean = np.linspace(-1, 1, 6)
    venv.obs_rms.var = np.linspace(0.5, 3, 6)
    agent = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, seed=0, device="cpu")
    agent.save(tmp_path / "agent.zip")
    venv.save(tmp_path / "vecnormalize.pkl")
    (tmp_path / "zoo_env.py").write_text(
        "from benchmarks.rl.train import make_train_env\n"
        "from sdjls_gym.systems.macro import PAPER_K\n"
        "def make():\n    return make_train_env('residual', 1000.0, None, PAPER_K)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "score.json"
    score = main(["--policy", str(tmp_path / "agent.zip"), "--algo", "ppo", "--train-env",
                  "zoo_env:make", "--vec-normalize", str(tmp_path / "vecnormalize.pkl"),
                  "--episodes", "20", "--json", str(out)])  # fmt: skip
    expected = evaluate(RawEnvPolicy(agent, venv), episodes=20)
    assert score.cost_mean == pytest.approx(expected.cost_mean, rel=1e-6)
    assert json.loads(out.read_text())["episodes"] == 20
