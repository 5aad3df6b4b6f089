"""``benchmarks.evaluate``: the public evaluation protocol, its policy adapters and its CLI."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from conftest import raises_naming

from benchmarks.core.montecarlo import rollout
from benchmarks.core.reference import paper_rhc
from benchmarks.evaluate import (
    REFERENCE_XIS,
    RawEnvPolicy,
    Score,
    evaluate,
    main,
    rollout_statistics,
)
from controllers import LinearFeedbackController
from sdjls_gym.systems.macro import PAPER_K, macro

ROOT = Path(__file__).resolve().parents[1]
E = 100  # episodes per evaluation in these tests


@pytest.fixture(scope="module")
def feedback():
    return LinearFeedbackController(macro(), PAPER_K, horizon=20)


def test_a_controller_is_scored_on_its_exact_states(feedback):
    """The score is the statistics of the closed-loop rollouts of the same seed."""
    s = evaluate(feedback, episodes=E, seed=3)
    ro = rollout(macro(), feedback, E, 20, 3)
    ref = rollout_statistics(ro, 1e6)
    assert isinstance(s, Score) and (s.episodes, s.steps, s.seed) == (E, 20, 3)
    assert s.cost_mean == ref["cost_mean"] and s.violation == ref["violation"]
    np.testing.assert_array_equal(s.episode_costs, ro.episode_cost)
    assert s.cost_ci95[0] <= s.cost_mean <= s.cost_ci95[1]
    assert s.violation_wilson95[0] <= s.violation <= s.violation_wilson95[1]
    assert s.decision_time_batched_s > 0 and s.decision_time_single_s > 0
    assert s.curve_gap is None  # 0.99 of the steps violate: beyond the RHC curve's range
    assert s.max_abs_u == float(np.max(np.abs(ro.u)))
    json.dumps(s.to_dict())  # plain JSON
    assert len(s.to_dict(per_episode=True)["episode_costs"]) == E


def test_a_point_of_the_reference_curve_has_a_zero_gap_at_its_own_xi():
    s = evaluate(paper_rhc(macro(), 0.8), episodes=E, seed=1)
    g = s.curve_gap
    assert g.mean == pytest.approx(0.0, abs=1e-9 * s.cost_mean) and g.xi == pytest.approx(0.8)
    assert g.violation == pytest.approx(s.violation, rel=1e-12)
    assert g.ci95[0] <= g.mean <= g.ci95[1] and abs(g.ci95[0]) < 1e-9 * s.cost_mean
    joint = evaluate(paper_rhc(macro(), 0.5, "joint"), episodes=E, seed=1)
    assert REFERENCE_XIS[0] < joint.curve_gap.xi < REFERENCE_XIS[-1]


class _Counting:
    """A policy with SB3's predict that counts its calls; ``batch`` says whether it accepts a
    batch of observations."""

    def __init__(self, batch: bool) -> None:
        self.ctrl = LinearFeedbackController(macro(), PAPER_K, horizon=20)
        self.batch, self.calls = batch, 0

    def predict(self, obs, deterministic=True):
        self.calls += 1
        if np.ndim(obs) != 1 and not self.batch:
            raise ValueError("one observation at a time")
        return self.ctrl.predict(obs)


def test_a_batch_policy_is_called_once_per_step_and_a_single_one_per_row(feedback):
    """Both agree with the controller's exact-state score up to the float32 observation."""
    ref = evaluate(feedback, episodes=E)
    batch, single = _Counting(batch=True), _Counting(batch=False)
    sb, ss = evaluate(batch, episodes=E), evaluate(single, episodes=E)
    # 20 steps, one call each (+8 single calls checking the first), then the timing calls
    assert batch.calls < 20 + 8 + 3 + 50 + 2
    assert single.calls > 20 * E
    for s in (sb, ss):
        assert s.cost_mean == pytest.approx(ref.cost_mean, rel=1e-5)
        assert s.violation == pytest.approx(ref.violation, abs=2 / (E * 20))
    assert sb.cost_mean == ss.cost_mean


def test_a_callable_that_mishandles_a_batch_is_called_row_by_row():
    """A batch comes back in the right shape with its rows reversed. Every episode starts in
    the same state, so the first batch cannot show it; the check waits for distinct rows."""
    calls = []

    def policy(obs):  # u = -2 x2
        obs = np.asarray(obs)
        calls.append(obs.ndim)
        return np.array([-2.0 * obs[1]]) if obs.ndim == 1 else -2.0 * obs[::-1, 1:2]

    s = evaluate(policy, episodes=E)
    good = evaluate(lambda obs: -2.0 * np.asarray(obs)[..., 1:2], episodes=E)
    assert s.cost_mean == pytest.approx(good.cost_mean, rel=1e-12)
    assert s.violation == good.violation
    assert 1 <= calls.count(2) <= 3  # found wrong within the first steps, then row by row


def test_raw_env_policy_undoes_the_training_wrappers():
    """The adapter sees what the wrapped env shows the agent and applies the same input u."""
    from benchmarks.rl.train import make_train_env

    class Fixed:
        def __init__(self):
            self.seen = None

        def predict(self, obs, deterministic=True):
            self.seen = np.array(obs)
            return np.full((len(obs), 1), 0.3, dtype=np.float32), None

    for kind, u_bound in (("u", None), ("u", 60.0), ("residual", None)):
        env = make_train_env(kind, None, None, PAPER_K, 100.0, u_bound)
        agent = Fixed()
        policy = RawEnvPolicy(agent, env)
        obs, info = env.reset(seed=3)
        for _ in range(5):
            u, _ = policy.act(info["state"], info["mode"], info["k"])
            np.testing.assert_allclose(agent.seen[0], obs, rtol=1e-6)
            obs, _, _, _, info = env.step(np.array([0.3], dtype=np.float32))
            np.testing.assert_allclose(info["u"], np.clip(u, -200, 200), rtol=1e-6, atol=1e-9)
            if kind == "u":
                np.testing.assert_allclose(info["u"], [0.3 * (u_bound or 200.0)], rtol=1e-6)


def test_raw_env_policy_refuses_what_it_cannot_undo():
    agent = _Counting(batch=True)
    env = gym.wrappers.TransformObservation(gym.make("SDJLS-Macro-v0"), lambda o: 2 * o, None)
    with raises_naming(ValueError, "env", "TransformObservation"):
        RawEnvPolicy(agent, env)
    not_an_agent = object()
    with raises_naming(TypeError, "agent", not_an_agent):
        RawEnvPolicy(not_an_agent, gym.make("SDJLS-Macro-v0"))
    with raises_naming(TypeError, "env", "SDJLS-Macro-v0"):
        RawEnvPolicy(agent, "SDJLS-Macro-v0")


@pytest.mark.parametrize(
    ("kwargs", "error", "name", "value"),
    [
        ({"episodes": 1}, ValueError, "episodes", 1),
        ({"episodes": 100.0}, TypeError, "episodes", 100.0),
        ({"episodes": True}, TypeError, "episodes", True),
        ({"seed": -1}, ValueError, "seed", -1),
        ({"seed": "0"}, TypeError, "seed", "0"),
        ({"env_id": 3}, TypeError, "env_id", 3),
        ({"env_kwargs": [("horizon", 5)]}, TypeError, "env_kwargs", [("horizon", 5)]),
        ({"env_id": "CartPole-v1"}, ValueError, "env_id", "CartPole-v1"),
        (
            {"env_kwargs": {"horizon": 40, "max_episode_steps": 20}},
            ValueError,
            ("max_episode_steps", "horizon"),
            20,
        ),
    ],
)
def test_bad_arguments_are_refused_with_their_value(feedback, kwargs, error, name, value):
    with raises_naming(error, name, value):
        evaluate(feedback, **kwargs)


def test_a_bad_policy_is_refused():
    with raises_naming(TypeError, "policy", 3):
        evaluate(3)
    with raises_naming(ValueError, ("policy", "action"), np.array([np.nan])):
        evaluate(lambda obs: np.full((len(np.atleast_2d(obs)), 1), np.nan), episodes=E)
    with raises_naming(ValueError, "policy", np.zeros(3)):  # expected 1 number
        evaluate(lambda obs: np.zeros(3), episodes=E)


def test_other_horizons_and_systems(feedback):
    long = evaluate(feedback, episodes=E, env_kwargs={"horizon": 40, "max_episode_steps": 40})
    assert long.steps == 40
    model = macro().to_dict()
    model["H0"] = [-2.0, 4.0]  # another band: not the paper's system, no reference curve
    from sdjls_gym import SDJLSModel

    other = evaluate(paper_rhc(SDJLSModel.from_dict(model), 0.85), episodes=E, env_id="SDJLS-v0",
                     env_kwargs={"model": SDJLSModel.from_dict(model), "horizon": 20})  # fmt: skip
    assert other.curve_gap is None and other.steps == 20
    assert "not a task of the suite" in other.curve_gap_reason and other.curve_points == ()


def test_score_says_why_it_has_no_gap_and_carries_the_curve(feedback):
    """Issue 33: a Score without curve_gap says why, and holds the reference curve's points
    (one per level xi of its base grid, scored on the same episodes: the task's levels and the
    ones added where the curve bends) so that a user can plot against them."""
    out = evaluate(feedback, episodes=E, seed=3)  # ignores the band: 0.99 of the steps violate
    assert out.curve_gap is None and "above the curve's range" in out.curve_gap_reason
    assert out.bounded_gap == 100.0 and out.bounded_gap_rule == "riskier than the curve"
    levels = [p["xi"] for p in out.curve_points]
    assert levels == sorted(levels) and set(REFERENCE_XIS) <= set(levels)
    top = max(p["violation"] for p in out.curve_points)
    assert f"{out.violation:.3f}" in out.curve_gap_reason and f"{top:.3f}" in out.curve_gap_reason
    on = evaluate(paper_rhc(macro(), 0.8), episodes=E, seed=3)
    assert on.curve_gap is not None and on.curve_gap_reason is None
    (point,) = [p for p in on.curve_points if p["xi"] == 0.8]
    assert point["cost_mean"] == pytest.approx(on.cost_mean, rel=1e-12)
    assert point["violation"] == on.violation
    zero = evaluate(lambda obs: np.zeros(1), episodes=E, seed=3)  # open loop: diverges
    assert zero.diverged > 0 and zero.curve_gap is None and zero.curve_points == ()
    assert zero.curve_gap_reason == f"{zero.diverged} episode(s) diverged"
    assert set(out.to_dict()) == set(on.to_dict())  # the JSON schema is unchanged
    assert "curve_points" not in out.to_dict()


# ------------------------------------------------------------------ command line
def test_cli_scores_a_module_attribute_and_writes_json(tmp_path, monkeypatch, capsys):
    (tmp_path / "my_policy.py").write_text(
        "import numpy as np\n"
        "from controllers import LinearFeedbackController\n"
        "from sdjls_gym.systems.macro import PAPER_K, macro\n"
        "policy = LinearFeedbackController(macro(), PAPER_K, horizon=20)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "score.json"
    score = main(["--policy", "my_policy:policy", "--episodes", "50", "--json", str(out)])
    text = capsys.readouterr().out
    assert "| my_policy:policy | 50 |" in text
    data = json.loads(out.read_text())
    assert data["cost_mean"] == score.cost_mean and data["episodes"] == 50
    assert data["versions"]["numpy"] == np.__version__


def test_cli_scores_an_sb3_zip_with_its_training_env(tmp_path, monkeypatch, capsys):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from benchmarks.rl.train import make_train_env

    env = make_train_env("residual", 1000.0, None, PAPER_K)
    PPO("MlpPolicy", env, n_steps=64, batch_size=64, seed=0, device="cpu").save(tmp_path / "a.zip")
    (tmp_path / "train_env.py").write_text(
        "from benchmarks.rl.train import make_train_env\n"
        "from sdjls_gym.systems.macro import PAPER_K\n"
        "def make():\n    return make_train_env('residual', 1000.0, None, PAPER_K)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    zip_path = str(tmp_path / "a.zip")
    s = main(["--policy", zip_path, "--algo", "ppo", "--train-env", "train_env:make",
              "--episodes", "30"])  # fmt: skip
    assert s.diverged == 0  # u = K x + nu: the residual agent is pre-stabilized
    assert f"| {zip_path} | 30 |" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        main(["--policy", zip_path])
    assert exc.value.code == 2 and "give --algo" in capsys.readouterr().err


# ------------------------------------------------------------------ the README example
def _readme_example() -> str:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = re.search(r"^## Score your own agent\n(.*?)(?=^## |\Z)", readme, re.M | re.S)
    assert section, "README has no section '## Score your own agent'"
    (block,) = re.findall(r"```python\n(.*?)```", section.group(1), flags=re.S)
    return block


def test_readme_example_trains_and_scores_an_agent_in_under_15_lines(tmp_path, monkeypatch, capsys):
    pytest.importorskip("stable_baselines3")
    block = _readme_example()
    assert len(block.strip().splitlines()) < 15
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(block, "README.md: Score your own agent", "exec"), namespace)
    score = namespace["score"]
    assert isinstance(score, Score) and score.episodes >= 100
    # what the README says of it: 4096 steps are too few, the agent diverges, no paired gap
    assert score.diverged > 0 and score.curve_gap is None
    assert isinstance(namespace["policy"], RawEnvPolicy)
    assert capsys.readouterr().out.strip()
    assert sys.modules.get("benchmarks.evaluate") is not None
