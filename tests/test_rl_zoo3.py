"""The rl-zoo3 hyperparameter files of ``benchmarks/rl/zoo/``: they load, name existing wrappers, and
train exactly the RL comparison's agents (hyperparameters, budget, wrapper chain)."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from benchmarks.rl import hyperparams as HP
from benchmarks.rl.train import make_train_env, variant_setup
from sdjls_gym.systems.macro import PAPER_K

yaml = pytest.importorskip("yaml")


@pytest.fixture
def zoo_utils():
    """``rl_zoo3.utils``, imported without leaking its global patch: importing rl_zoo3 replaces
    Gymnasium's ``TimeLimit`` everywhere by a subclass that adds ``info["TimeLimit.truncated"]``,
    which would change the envs of every later test in the session."""
    import gymnasium.envs.registration
    import gymnasium.wrappers
    import gymnasium.wrappers.common

    modules = (gymnasium.wrappers, gymnasium.wrappers.common, gymnasium.envs.registration)
    saved = [getattr(module, "TimeLimit", None) for module in modules]
    yield pytest.importorskip("rl_zoo3.utils")
    for module, value in zip(modules, saved, strict=True):
        if value is None:
            module.__dict__.pop("TimeLimit", None)
        else:
            module.TimeLimit = value


ROOT = Path(__file__).resolve().parents[1]
FILES = {"ppo": "residual", "sac": "beta10000", "td3": "beta10000"}  # algo: the variant it trains


def _entry(algo: str) -> dict:
    data = yaml.safe_load((ROOT / "benchmarks" / "rl" / "zoo" / f"{algo}.yml").read_text())
    assert list(data) == ["SDJLS-Macro-v0"]
    return data["SDJLS-Macro-v0"]


def _chain(env: gym.Env) -> list[tuple[str, dict]]:
    """The wrappers of ``env``, outermost first, with what defines them."""
    out = []
    while isinstance(env, gym.Wrapper):
        params = {}
        for key in ("beta", "x_scale", "obs_clip", "reward_scale", "reward_clip", "bound", "K"):
            if hasattr(env, key) and not callable(getattr(env, key)):
                params[key] = np.asarray(getattr(env, key)).tolist()
        params["action_space"] = str(env.action_space)
        out.append((type(env).__name__, params))
        env = env.env
    return out


@pytest.mark.parametrize("algo", sorted(FILES))
def test_zoo_file_has_the_comparisons_hyperparameters(algo):
    variant = FILES[algo]
    entry = _entry(algo)
    expected = HP.hyperparams(algo, variant)
    assert entry.pop("n_timesteps") == HP.timesteps(algo, variant)
    assert entry.pop("policy") == "MlpPolicy"
    kwargs = entry.pop("policy_kwargs")
    call = ast.parse(kwargs, mode="eval").body  # "dict(net_arch=[64, 64], ...)"
    assert {k.arg: ast.literal_eval(k.value) for k in call.keywords} == expected["policy_kwargs"]
    entry.pop("env_wrapper")
    env_kwargs = entry.pop("env_kwargs", {})
    kind, _, _ = variant_setup(variant)
    assert env_kwargs == ({"action_bound": HP.U_BOUND} if kind == "u" else {})
    if algo == "td3":
        assert entry.pop("noise_type") == "normal"
    train_freq = entry.get("train_freq")
    if isinstance(train_freq, list):
        entry["train_freq"] = tuple(train_freq)
    assert entry == {k: v for k, v in expected.items() if k != "policy_kwargs"}


@pytest.mark.parametrize("algo", sorted(FILES))
def test_zoo_file_builds_the_comparisons_training_env(algo, zoo_utils):
    """rl-zoo3's own wrapper loader imports every wrapper named in the file; the env it builds
    has the wrappers and parameters of the comparison's training env."""
    entry = _entry(algo)
    wrap = zoo_utils.get_wrapper_class(entry)
    zoo_env = wrap(gym.make("SDJLS-Macro-v0", **entry.get("env_kwargs", {})))
    kind, beta, _ = variant_setup(FILES[algo])
    u_bound = HP.U_BOUND if kind == "u" else None
    ours = make_train_env(kind, beta, None, PAPER_K if kind == "residual" else None,
                          HP.RESIDUAL_NU_BOUND, u_bound)  # fmt: skip
    assert _chain(zoo_env) == _chain(ours)
    obs_a, _ = zoo_env.reset(seed=1)
    obs_b, _ = ours.reset(seed=1)
    np.testing.assert_array_equal(obs_a, obs_b)
    a = np.array([0.3], dtype=np.float32)
    step_a, step_b = zoo_env.step(a), ours.step(a)
    np.testing.assert_array_equal(step_a[0], step_b[0])
    assert step_a[1:4] == step_b[1:4]


def test_one_training_env_function_per_variant():
    """benchmarks.rl.train_envs has exactly one public function per variant, each the recipe
    make_train_env(task, variant) on the macro task by default and on any task given."""
    from benchmarks.rl import train_envs as train_envs
    from benchmarks.rl.envs import VARIANTS

    assert sorted(train_envs.__all__) == sorted(VARIANTS)
    for variant in VARIANTS:
        make = getattr(train_envs, variant)
        assert _chain(make()) == _chain(make_train_env("SDJLS-Macro-v0", variant))
        assert _chain(make("SDJLS-Solar-v0")) == _chain(make_train_env("SDJLS-Solar-v0", variant))


@pytest.mark.parametrize("algo", sorted(FILES))
def test_an_agent_of_a_zoo_file_is_scored_with_one_flag(algo, zoo_utils, tmp_path, capsys):
    """An agent built as rl-zoo3 builds it from the file (its wrappers, untrained: the scoring
    is what is tested) and saved is scored by ``benchmarks.evaluate`` with ``--train-env
    benchmarks.rl.train_envs:VARIANT``; without the flag it is refused (its spaces are the wrapped
    env's), a parser error naming --train-env."""
    sb3 = pytest.importorskip("stable_baselines3")
    from benchmarks import evaluate

    entry = _entry(algo)
    zoo_env = zoo_utils.get_wrapper_class(entry)(
        gym.make("SDJLS-Macro-v0", **entry.get("env_kwargs", {}))
    )
    from benchmarks.rl import train_envs as train_envs

    # the flag's env is the file's: same wrappers, same scalings and bounds
    assert _chain(zoo_env) == _chain(getattr(train_envs, FILES[algo])())
    agent = getattr(sb3, algo.upper())("MlpPolicy", zoo_env, seed=0, device="cpu")
    path = tmp_path / f"{algo}.zip"
    agent.save(path)
    flag = f"benchmarks.rl.train_envs:{FILES[algo]}"
    score = evaluate.main(["--policy", str(path), "--algo", algo, "--train-env", flag,
                           "--episodes", "20"])  # fmt: skip
    assert score.episodes == 20 and np.isfinite(score.violation)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--policy", str(path), "--algo", algo, "--episodes", "20"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "RawEnvPolicy(agent, train_env)" in err and "--train-env" in err


@pytest.mark.slow
def test_rl_zoo3_trains_a_few_hundred_steps_with_the_file(tmp_path):
    """The README's command, shortened to 512 steps of PPO (one rollout of 8 x 64)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [
        sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", "SDJLS-Macro-v0",
        "--gym-packages", "sdjls_gym", "-conf", "benchmarks/rl/zoo/ppo.yml", "-n", "512",
        "--log-folder", str(tmp_path), "--eval-freq", "-1", "--seed", "0",
        "--hyperparams", "n_steps:64", "batch_size:64",
    ]  # fmt: skip
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert list(tmp_path.rglob("SDJLS-Macro-v0.zip"))


def test_readme_zoo_command_writes_outside_the_checkout():
    """The manual's rl_zoo3 command (docs/benchmarks.md, "rl-zoo3") sets its log folder outside
    the repository (rl_zoo3's default, logs/, landed in the checkout), and each file's comment
    shows the same command."""
    readme = (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8")
    commands = [line for line in readme.splitlines() if line.startswith("python -m rl_zoo3.train")]
    assert commands
    for command in commands:
        folder = command.split(" -f ")[1].split()[0]
        assert Path(folder).is_absolute() and ROOT not in Path(folder).parents, command
    for algo in FILES:
        text = (ROOT / "benchmarks" / "rl" / "zoo" / f"{algo}.yml").read_text()
        assert f"-conf benchmarks/rl/zoo/{algo}.yml -f /tmp/sdjls-zoo" in text
