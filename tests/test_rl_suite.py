"""The RL comparison on every task of the suite (issue 31): the training recipe per task and
variant, run fingerprints that name the task, ``--quick`` on two tasks, and the kept runs'
agents rebuilt by ``benchmarks.rl.runs``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from benchmarks.core.reference import tree_rhc  # noqa: E402
from benchmarks.evaluate import evaluate  # noqa: E402
from benchmarks.rl import backends as backends  # noqa: E402
from benchmarks.rl import compare as compare_rl  # noqa: E402
from benchmarks.rl import envs as rl_envs  # noqa: E402
from benchmarks.rl import hyperparams as HP  # noqa: E402
from benchmarks.rl import runs  # noqa: E402
from benchmarks.rl import train as rl_train  # noqa: E402
from benchmarks.rl.runs import score_run  # noqa: E402
from sdjls_gym import SUITE  # noqa: E402
from sdjls_gym.systems import TASKS  # noqa: E402
from sdjls_gym.wrappers import (  # noqa: E402
    ResidualAction,
    ScaleObservationReward,
    TerminateOutside,
    ViolationPenalty,
)

ROOT = Path(__file__).resolve().parents[1]


def _layers(env: gym.Env) -> dict[str, gym.Env]:
    """The wrappers of ``env`` by class name."""
    out = {}
    while isinstance(env, gym.Wrapper):
        out[type(env).__name__] = env
        env = env.env
    return out


def _chain(env: gym.Env) -> list[tuple[str, str]]:
    out = []
    while isinstance(env, gym.Wrapper):
        out.append((type(env).__name__, str(env.action_space)))
        env = env.env
    return out


# ------------------------------------------------------------------ the recipe per task
@pytest.mark.parametrize("task_id", SUITE)
@pytest.mark.parametrize("variant", ["reward", "residual", "lagrangian"])
def test_train_env_recipe_on_every_task(task_id, variant):
    """Spaces, wrappers and values of the training env: the residual agent acts on nu over the
    task's own K; agents on u are bounded by the task's u_bound; the scalings are the task's;
    training builds the same env as the public recipe."""
    task, settings = TASKS[task_id], rl_envs.task_settings(task_id)
    env = rl_envs.make_train_env(task_id, variant)
    n, m, N = task.n, task.m, task.N
    assert env.observation_space.shape == (n + N + 1,)
    assert env.action_space.shape == (m,)
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    layers = _layers(env)
    scale = layers["ScaleObservationReward"]
    assert isinstance(scale, ScaleObservationReward) and scale.x_scale == settings.x_scale
    assert scale.reward_scale == settings.reward_scale
    assert isinstance(layers["TerminateOutside"], TerminateOutside)
    assert layers["TerminateOutside"].bound == HP.TERMINATE_SCALES * settings.x_scale
    if variant == "residual":
        residual = layers["ResidualAction"]
        assert isinstance(residual, ResidualAction)
        np.testing.assert_array_equal(residual.K, task.K)
        assert residual.action_space.high[0] == settings.nu_bound
        assert settings.nu_bound == min(task.rhc["nu_bound"], 2 * settings.u_bound)
        assert env.unwrapped.action_space.high[0] == task.action_bound
    else:
        assert "ResidualAction" not in layers
        assert env.unwrapped.action_space.high[0] == settings.u_bound <= task.action_bound
    penalty = layers.get("ViolationPenalty")
    if variant == "reward":
        assert penalty is None
    else:
        assert isinstance(penalty, ViolationPenalty)
        unit = settings.reward_scale / 100.0
        expected = HP.RESIDUAL_BETA if variant == "residual" else HP.LAGRANGIAN["beta0"]
        assert penalty.beta == pytest.approx(expected * unit, rel=1e-12)
    spec = rl_train.RunSpec("ppo", variant, 0, 1000, 1, 5, 1, task=task_id)
    assert _chain(rl_train._train_env(spec)) == _chain(env)
    obs, _ = env.reset(seed=3)
    assert env.observation_space.contains(obs)


@pytest.mark.parametrize("task_id", SUITE)
def test_lagrangian_aims_at_the_tasks_own_level(task_id):
    """The dual ascent's target is 1 - xi of the task's receding-horizon controller; its step
    and initial penalty are in the task's units."""
    lag = rl_train.RunSpec("td3", "lagrangian", 0, 1000, 1, 5, 1, task=task_id).lagrangian()
    assert lag["xi"] == TASKS[task_id].rhc["xi"]
    unit = rl_envs.task_settings(task_id).reward_scale / 100.0
    assert lag["lr_dual"] == pytest.approx(HP.LAGRANGIAN["lr_dual"] * unit, rel=1e-12)
    assert lag["beta0"] == pytest.approx(HP.LAGRANGIAN["beta0"] * unit, rel=1e-12)


def test_td3_noise_has_one_entry_per_input():
    """VTOL has two inputs: TD3's exploration noise is drawn per input (it was one number added
    to both)."""
    spec = rl_train.RunSpec("td3", "lagrangian", 0, 1000, 1, 5, 1, task="SDJLS-VTOL-v0")
    agent = rl_train.build_agent(spec, [lambda: rl_train._train_env(spec)])
    noise = agent.action_noise()
    assert noise.shape == (2,) and noise[0] != noise[1]


def test_older_form_of_make_train_env_is_the_macro_recipe():
    """``make_train_env(action_kind, beta, env_hp, K, ...)``, the form before the suite, still
    builds the macro comparison's env; other arguments with a task are refused."""
    old = rl_train.make_train_env("residual", 1000.0, None, TASKS["SDJLS-Macro-v0"].K)
    assert _chain(old) == _chain(rl_envs.make_train_env("SDJLS-Macro-v0", "residual"))
    with pytest.raises(TypeError, match="takes no other argument"):
        rl_envs.make_train_env("SDJLS-Solar-v0", "residual", 3.0)
    with pytest.raises(ValueError, match="'Foo-v0'"):
        rl_envs.make_train_env("Foo-v0", "residual")
    with pytest.raises(ValueError, match="variant = 'betaX'"):
        rl_envs.make_train_env("SDJLS-Solar-v0", "betaX")


def _one_digit_neighbours(raw: float) -> set[float]:
    """The one-digit roundings of ``raw`` and of ``raw`` moved by 0.5%: a value that close to a
    rounding boundary may round either way after a change in the last bits of a controller."""
    return {float(f"{raw * f:.0e}") for f in (0.995, 1.0, 1.005)}


@pytest.mark.parametrize("task_id", SUITE)
def test_task_scales_follow_their_rule(task_id):
    """TASK_SCALES holds what derive_scales computes from the task's receding-horizon controller
    (300 episodes); the macro task's are the values results/rl was trained with."""
    task = TASKS[task_id]
    table = HP.TASK_SCALES[task_id]
    raw = rl_envs.raw_scales(task)
    assert table["x_scale"] in _one_digit_neighbours(raw["x"])
    assert table["reward_scale"] in _one_digit_neighbours(raw["stage_cost"] / 2.5)
    assert raw["u"] <= table["u_bound"] <= min(task.action_bound, 2 * 1.25 * raw["u"])
    if all(
        len(_one_digit_neighbours(v)) == 1 for v in (raw["x"], raw["stage_cost"] / 2.5)
    ):  # no boundary nearby: the rule gives exactly the table
        assert rl_envs.derive_scales(task) == table
    if task_id == "SDJLS-Macro-v0":
        assert table == {"x_scale": HP.ENV["x_scale"], "reward_scale": HP.ENV["reward_scale"],
                         "u_bound": HP.U_BOUND}  # fmt: skip


# ------------------------------------------------------------------ fingerprints
def test_fingerprint_names_the_task():
    """The same algorithm, variant, seed and budget on two tasks are two configurations; a
    change of the task's data (its gains) is another configuration too; the pre-suite
    fingerprint exists only on the macro task."""
    specs = [rl_train.RunSpec("ppo", "residual", 0, 1000, 1, 5, 1, task=t) for t in SUITE]
    assert len({s.fingerprint() for s in specs}) == len(SUITE)
    for s in specs:
        config = s.config()
        assert config["task"] == s.task
        assert config["task_digest"] == rl_envs.task_digest(TASKS[s.task])
        assert (s.legacy_fingerprint() is None) == (s.task != "SDJLS-Macro-v0")
    solar = TASKS["SDJLS-Solar-v0"]
    moved = dataclasses.replace(solar, K=solar.K * 1.01)
    assert rl_envs.task_digest(moved) != rl_envs.task_digest(solar)
    # a run's record is refused on a task whose data changed
    config = specs[1].config() | {"task_digest": rl_envs.task_digest(moved)}
    with pytest.raises(ValueError, match="task_digest"):
        rl_train.env_from_config(config, "residual")


def test_runs_of_two_tasks_are_kept_apart(tmp_path, monkeypatch):
    """Same name on two tasks: two files in two folders, each reused by its own spec."""

    def fake_train(spec, report=None, should_stop=None):
        point = rl_train.CurvePoint(spec.timesteps, 0.0, 1.0, 1.0, 0.5, 0, None)
        record = rl_train.RunRecord(spec.name, spec.algo, spec.variant, spec.seed,
                                    spec.fingerprint(), spec.config(), spec.timesteps, 0.0, 0.0,
                                    None, [point], [], task=spec.task)  # fmt: skip
        return record, spec.task.encode()

    monkeypatch.setattr(backends, "train_run", fake_train)
    specs = rl_train.run_specs([("ppo", "residual")], 2, 64, False,
                               tasks=["SDJLS-Solar-v0", "SDJLS-VTOL-v0"])  # fmt: skip
    records = backends.train_all(specs, tmp_path, workers=1, progress=False, log=lambda m: None)
    assert [r.task for r in records] == [s.task for s in specs]
    for s in specs:
        path = rl_train.kept_run_path(tmp_path, s)
        assert path.parent == tmp_path / s.task
        assert rl_train.policy_path(path).read_bytes() == s.task.encode()


def test_trainings_go_seed_by_seed(tmp_path, monkeypatch):
    """Every configuration's first seed is trained before any second seed (a pilot that
    finishes early), longest first within a seed."""
    order = []

    def fake_train(spec, report=None, should_stop=None):
        order.append(spec)
        point = rl_train.CurvePoint(spec.timesteps, 0.0, 1.0, 1.0, 0.5, 0, None)
        record = rl_train.RunRecord(spec.name, spec.algo, spec.variant, spec.seed,
                                    spec.fingerprint(), spec.config(), spec.timesteps, 0.0, 0.0,
                                    None, [point], [], task=spec.task)  # fmt: skip
        return record, b"policy"

    monkeypatch.setattr(backends, "train_run", fake_train)
    specs = rl_train.run_specs(list(HP.SUITE_CONFIGS), 2, None, False, tasks=list(SUITE)[:2])
    backends.train_all(specs, tmp_path, workers=1, progress=False, log=lambda m: None)
    seeds = [s.seed for s in order]
    assert seeds == sorted(seeds) and len(order) == len(specs) == 2 * 2 * 5
    first = [s.timesteps / HP.STEPS_PER_SECOND[s.algo] for s in order if s.seed == 0]
    assert first == sorted(first, reverse=True)


# ------------------------------------------------------------------ the command
def test_unknown_task_is_refused_at_parse_time(capsys):
    with pytest.raises(SystemExit) as exc:
        compare_rl.parse_args(["--tasks", "SDJLS-Macro-v0", "SDJLS-Moon-v0"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--tasks" in err and "SDJLS-Moon-v0" in err
    with pytest.raises(SystemExit) as exc:
        compare_rl.parse_args(["--configs", "ppo_residual", "--algos", "td3"])
    assert exc.value.code == 2 and "--configs" in capsys.readouterr().err


def test_a_partial_comparison_never_replaces_the_presets_report(capsys, tmp_path):
    """Tasks, configurations, seeds or budgets other than the preset's, scored into the preset's
    folder, would replace its report of all runs (the macro task alone even in the macro
    comparison's format): a parser error naming the options, unless --out, --train-only or
    --quick says where the report goes or that there is none."""
    for argv, named, folder in [
        (["--tasks", "SDJLS-Macro-v0"], "--tasks", "results/rl_suite"),
        (
            ["--configs", "ppo_residual", "--seeds", "2"],
            "--configs (or --algos/--variants), --seeds",
            "results/rl_suite",
        ),
        (["--timesteps", "1000"], "--timesteps", "results/rl_suite"),
        (["--preset", "macro", "--seeds", "2"], "--seeds", "results/rl"),
    ]:
        with pytest.raises(SystemExit) as exc:
            compare_rl.parse_args(argv)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and f"error: {named} other than the preset's" in err
        assert f"the full report in {folder}; give --out" in err
        assert compare_rl.parse_args([*argv, "--train-only"]).out == Path(folder)
        assert compare_rl.parse_args([*argv, "--out", str(tmp_path)]).out == tmp_path
    # the preset itself, in any order of its tasks, scores into its folder
    assert compare_rl.parse_args(["--tasks", *reversed(SUITE)]).out == Path("results/rl_suite")
    assert compare_rl.parse_args(["--score-only"]).out == Path("results/rl_suite")


def _measured_ms_per_step() -> dict[tuple[str, str], float]:
    """Median CPU ms per env step of each configuration over the committed suite runs
    (``cpu_time_s`` of results/rl_suite/runs/*/*.json, one torch thread, two trainings at once;
    SAC and TD3 without their 1000 first steps, which take no gradient step)."""
    per: dict[tuple[str, str], list[float]] = {}
    for path in (ROOT / "results" / "rl_suite" / "runs").glob("*/*.json"):
        run = json.loads(path.read_text())
        steps = run["timesteps"] - (run["algo"] != "ppo") * 1000
        per.setdefault((run["algo"], run["variant"]), []).append(1e3 * run["cpu_time_s"] / steps)
    return {key: float(np.median(v)) for key, v in per.items()}


def test_presets_and_their_budgets():
    """The default command is the suite: every task, the five configurations, 5 seeds, the
    suite's budgets (the same on every task but where ``SUITE_TIMESTEPS_TASK`` changes one),
    which fit 12 CPU-hours at the per-step costs of the committed runs."""
    opts = compare_rl.parse_args([])
    assert opts.tasks == list(SUITE) and opts.seeds == HP.SUITE_SEEDS == 5
    assert opts.config_pairs() == list(HP.SUITE_CONFIGS)
    specs = compare_rl.specs_of(opts)
    assert len(specs) == 6 * 5 * 5
    ms = _measured_ms_per_step()
    assert set(ms) >= set(HP.SUITE_CONFIGS) and all(0 < v < 20 for v in ms.values()), ms
    cpu_s = sum(ms[s.algo, s.variant] * (s.timesteps - (s.algo != "ppo") * 1000) for s in specs)
    assert cpu_s / 1e3 / 3600 <= 12.0
    for s in specs:
        default = HP.SUITE_TIMESTEPS[(s.algo, s.variant)]
        assert s.timesteps == HP.SUITE_TIMESTEPS_TASK.get((s.task, s.algo, s.variant), default)
    assert {k[0] for k in HP.SUITE_TIMESTEPS_TASK} <= set(SUITE)
    assert {k[1:] for k in HP.SUITE_TIMESTEPS_TASK} <= set(HP.SUITE_CONFIGS)
    macro = compare_rl.specs_of(compare_rl.parse_args(["--preset", "macro"]))
    assert {s.timesteps for s in macro if (s.algo, s.variant) == ("ppo", "reward")} == {8_000_000}


def test_tuned_configuration_is_retrained_at_the_study_budget(tmp_path, capsys):
    """``--tuned`` retrains the study's configuration at the budget the study tuned at (unless
    ``--timesteps``), with its best overrides; the other configurations keep theirs."""
    study = {"settings": {"task": "SDJLS-Solar-v0", "algo": "td3", "variant": "lagrangian",
                          "timesteps": 12_345, "seeds": 1},
             "trials": [], "best": {"number": 0, "overrides": {"learning_rate": 1e-3}}}  # fmt: skip
    path = tmp_path / "s.json"
    path.write_text(json.dumps(study))
    base = ["--tasks", "SDJLS-Solar-v0", "SDJLS-VTOL-v0", "--configs", "td3_lagrangian",
            "ppo_residual", "--seeds", "2", "--tuned", str(path), "--train-only"]  # fmt: skip
    for extra, tuned_steps in (([], 12_345), (["--timesteps", "777"], 777)):
        specs = compare_rl.specs_of(compare_rl.parse_args([*base, *extra]))
        for s in specs:
            key = (s.task, s.algo, s.variant)
            if key == ("SDJLS-Solar-v0", "td3", "lagrangian"):
                assert (s.timesteps, s.overrides) == (tuned_steps, (("learning_rate", 1e-3),))
            else:
                expected = 777 if extra else HP.suite_timesteps(*key)
                assert (s.timesteps, s.overrides) == (expected, ())
    for bad in ("many", True, 0):  # a bool is not a budget (json's true would pass as 1)
        study["settings"]["timesteps"] = bad
        path.write_text(json.dumps(study))
        with pytest.raises(SystemExit):
            compare_rl.parse_args(base)
        err = capsys.readouterr().err
        assert f"settings.timesteps = {bad!r}; expected the study's budget" in err


def test_quick_on_two_tasks(tmp_path):
    """``--quick`` on two tasks trains every configuration asked for, keeps the runs by task,
    scores each agent on its own task against both model-based curves (the report of
    benchmarks.rl.suite_report: its sections, figures and JSON keys), writes nothing into
    results/, and resumes; ``--score-only`` after a run is lost names it as missing."""
    results = ROOT / "results"
    before = {p: p.stat().st_mtime_ns for p in results.rglob("*")}
    two = ["SDJLS-Solar-v0", "SDJLS-Degradation-v0"]  # the cheapest trees of the suite
    args = ["--quick", "--tasks", *two, "--configs", "ppo_residual", "ppo_lagrangian", "--seeds",
            "1", "--timesteps", "2048", "--eval-episodes", "20", "--workers", "1",
            "--no-progress", "--out", str(tmp_path / "quick")]  # fmt: skip
    summary = compare_rl.main(args)
    assert {p: p.stat().st_mtime_ns for p in results.rglob("*")} == before
    out = tmp_path / "quick"
    assert set(summary["tasks"]) == set(two)
    for task_id, section in summary["tasks"].items():
        task = TASKS[task_id]
        assert len(list((out / "runs" / task_id).glob("*.json"))) == 2
        for r in section["rl_runs"]:
            assert r["task"] == task_id and r["score"]["env_id"] == task_id
            assert r["score"]["steps"] == task.horizon and r["score"]["episodes"] == 20
            assert r["cpu_time_s"] > 0 and [p["timesteps"] for p in r["learning_curve"]][0] == 0
            # both gaps: a value or the reason it has none, never both or neither
            if r["curve_gap_reason"] is None:
                assert r["score"]["curve_gap"]["relative"] is not None
            assert (r["tree_gap"] is None) != (r["tree_gap_reason"] is None)
            assert len(r["learning_curve_gaps"]) == len(r["learning_curve"])
            if r["variant"] == "lagrangian":  # one update, towards the task's 1 - xi
                lag = rl_train.RunSpec("ppo", "lagrangian", 0, 2048, 3, 20, 1, task_id).lagrangian()
                (point,) = r["dual_ascent"]
                step = lag["lr_dual"] * (point["freq"] - (1 - task.rhc["xi"]))
                assert point["beta"] == pytest.approx(max(0.0, lag["beta0"] + step), rel=1e-12)
        assert {a["name"] for a in section["rl_aggregates"]} == {"PPO residual", "PPO lagrangian"}
        # the tree's reference row, recomputed by evaluate() on the same 10 episodes
        assert section["tree"]["episodes"] == 10 and task.rhc["xi"] in section["tree"]["xis"]
        tree = evaluate(tree_rhc(task, task.rhc["xi"], 3), episodes=10, seed=0, env_id=task_id,
                        env_kwargs=dict(task.env_kwargs))  # fmt: skip
        (row,) = [v for k, v in section["references"].items() if "3-step" in k]
        assert row["cost_mean"] == pytest.approx(tree.cost_mean, rel=1e-9)
        assert row["violation"] == pytest.approx(tree.violation, abs=1e-12)
        assert section["missing"] == {}
    saved = json.loads((out / "summary.json").read_text())
    assert set(saved["tasks"]) == set(summary["tasks"])
    assert saved["runs"] == {"expected": 4, "kept": 4, "missing": {t: {} for t in two}}
    for config in ("ppo_residual", "ppo_lagrangian"):
        across = saved["across_tasks"][config]
        for key in ("vs_rhc", "vs_tree"):  # an aggregate or what was left out, and why
            assert across[key] is not None or across[key.replace("vs", "") + "_left_out"]
        assert set(saved["sample_efficiency"][config]) == {"steps", "iqm", "ci95"}
        assert None not in saved["sample_efficiency"][config]["iqm"]  # every run counts
    report = (out / "REPORT.md").read_text()
    for heading in ("## Runs", "## Across tasks (rliable)", *(f"## {t}" for t in two)):
        assert heading in report
    assert "4 of the 4 runs asked for are kept and scored, none missing." in report
    figures = ["fig_aggregate.png", "fig_profiles.png", "fig_sample_efficiency.png"] + [
        f"fig_{t}_{kind}.png" for t in two for kind in ("cost_violation", "learning_curves")
    ]
    assert sorted(saved["figures"]) == sorted(figures)
    for name in figures:
        assert (out / name).stat().st_size > 10_000 and f"]({name})" in report
    rows = (out / "summary.csv").read_text().splitlines()
    assert rows[0].startswith("task,name,kind") and len(rows) == 1 + 2 * (2 + 2)
    # rerun with --train-only: every run is reused, nothing is scored or written again
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    assert compare_rl.main([*args, "--train-only"]) is None
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == stamps
    # a kept run of the suite's layout is rebuilt by benchmarks.rl.runs and acts as the report's
    (path,) = (out / "runs" / two[1]).glob("ppo_residual_s0-*.json")
    score = score_run(path, episodes=20, seed=0)
    kept = next(r for r in summary["tasks"][two[1]]["rl_runs"] if r["name"] == "ppo_residual_s0")
    assert score.cost_mean == pytest.approx(kept["score"]["cost_mean"], rel=1e-9)
    # a lost run: --score-only trains nothing and names it (task, configuration, seed)
    path.unlink()
    partial = compare_rl.main([*args, "--score-only"])
    assert not path.exists()
    assert partial["runs"]["kept"] == 3
    assert partial["runs"]["missing"] == {two[0]: {}, two[1]: {"ppo_residual": [0]}}
    assert [r["name"] for r in partial["tasks"][two[1]]["rl_runs"]] == ["ppo_lagrangian_s0"]
    assert f"no kept run on {two[1]}" in partial["across_tasks"]["ppo_residual"]["rhc_left_out"]
    report = (out / "REPORT.md").read_text()
    assert "3 of the 4 runs asked for are kept and scored, 1 missing:" in report
    assert f"| {two[1]} | ppo_residual | 0 of 1 (-) | 0 |" in report
    assert "Missing runs: ppo_residual seed(s) 0." in report


# ------------------------------------------------------------------ kept agents
COMMITTED = ROOT / "results" / "rl" / "runs" / "ppo_residual_s0-e884595880b28e6a.json"


def test_a_committed_run_is_rebuilt_and_scores_as_its_report():
    """load_agent rebuilds a kept policy of results/rl from its recorded configuration; scored on
    the same episodes (the committed report's noise seeds, within the comparison's action bound)
    it gives the committed report's numbers."""
    import torch

    torch.set_num_threads(1)
    assert runs.run_env(COMMITTED) == ("SDJLS-Macro-v0", {"action_bound": 60.0})
    policy = runs.load_agent(COMMITTED.with_suffix(".pt"))
    assert type(policy.agent).__name__ == "ActorCriticPolicy"
    committed = json.loads((ROOT / "results" / "rl" / "summary.json").read_text())
    o = committed["options"]
    seeds = tuple(range(o["seed"], o["seed"] + o["eval_seeds"]))
    score = score_run(COMMITTED, episodes=o["eval_episodes"], seed=seeds)
    (row,) = [r for r in committed["rl_runs"] if r["name"] == "ppo_residual_s0"]
    # float32 networks: the last bits of a sum may differ between machines (results/rl/HISTORY.md)
    assert score.cost_mean == pytest.approx(row["score"]["cost_mean"], rel=1e-6)
    assert score.violation == pytest.approx(row["score"]["violation"], abs=2e-4)
    assert score.diverged == row["score"]["diverged"] == 0
    assert score.bounded_gap == pytest.approx(row["score"]["bounded_gap"], rel=1e-4, abs=1e-6)


def test_load_agent_refuses_what_is_not_a_kept_run(tmp_path):
    with pytest.raises(TypeError, match="run_path = 3"):
        runs.load_agent(3)
    with pytest.raises(ValueError, match="no run record"):
        runs.load_agent(tmp_path / "ppo_residual_s0-0000.json")
    (tmp_path / "x.json").write_text("{}")
    with pytest.raises(ValueError, match="policy .* is missing"):
        runs.load_agent(tmp_path / "x.json")
    (tmp_path / "x.pt").write_bytes(b"")
    with pytest.raises(ValueError, match="is not a run record"):
        runs.load_agent(tmp_path / "x")


def test_evaluate_cli_scores_a_kept_run(tmp_path, capsys):
    """``python -m benchmarks.evaluate --run PATH`` scores a kept run on its own task as
    score_run does (50 episodes, the JSON it writes); the options a run records itself, another
    task and a missing run are parser errors naming the option."""
    import torch

    from benchmarks import evaluate

    torch.set_num_threads(1)
    out = tmp_path / "score.json"
    cli = evaluate.main(["--run", str(COMMITTED.with_suffix("")), "--episodes", "50",
                         "--json", str(out)])  # fmt: skip
    direct = score_run(COMMITTED, episodes=50, seed=0)
    assert cli.cost_mean == direct.cost_mean and cli.violation == direct.violation
    data = json.loads(out.read_text())
    assert data["policy"] == str(COMMITTED.with_suffix("")) and data["episodes"] == 50
    assert data["cost_mean"] == pytest.approx(direct.cost_mean, rel=1e-12)
    capsys.readouterr()
    for argv, needle in [
        (["--run", str(COMMITTED), "--algo", "ppo"], "--algo does not apply to --run"),
        (["--run", str(COMMITTED), "--env-id", "SDJLS-Solar-v0"], "acts on SDJLS-Macro-v0"),
        (["--run", str(tmp_path / "none.json")], "no run record"),
        (["--run", str(COMMITTED), "--policy", "x:y"], "not allowed with argument"),
        ([], "one of the arguments --policy --run is required"),
    ]:
        with pytest.raises(SystemExit) as exc:
            evaluate.main(argv)
        assert exc.value.code == 2
        assert needle in capsys.readouterr().err


def test_tuned_hyperparameters_reach_only_their_configuration(tmp_path, capsys):
    """``--tuned STUDY.json`` gives the best trial's overrides to that task's configuration, on
    the comparison's seeds (0..), as runs of their own fingerprint; a file that is not a study
    summary is a parser error naming it."""
    summary = {
        "settings": {"task": "SDJLS-Macro-v0", "algo": "ppo", "variant": "residual",
                     "timesteps": 600_000},
        "best": {"number": 3, "value": -0.01, "params": {},
                 "overrides": {"learning_rate": 1e-4, "net_arch": [128, 128]}},
    }  # fmt: skip
    path = tmp_path / "study.json"
    path.write_text(json.dumps(summary))
    args = ["--tasks", "SDJLS-Macro-v0", "SDJLS-Solar-v0", "--configs", "ppo_residual",
            "ppo_reward", "--seeds", "2"]  # fmt: skip
    default = {
        s.label: s for s in compare_rl.specs_of(compare_rl.parse_args([*args, "--train-only"]))
    }
    tuned = compare_rl.specs_of(
        compare_rl.parse_args([*args, "--tuned", str(path), "--train-only"])
    )
    for s in tuned:
        if (s.task, s.algo, s.variant) == ("SDJLS-Macro-v0", "ppo", "residual"):
            assert dict(s.overrides) == summary["best"]["overrides"] and s.seed in (0, 1)
            assert s.hyperparams()["policy_kwargs"]["net_arch"] == [128, 128]
            assert s.fingerprint() != default[s.label].fingerprint()
        else:
            assert s == default[s.label]
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(SystemExit) as exc:
        compare_rl.parse_args([*args, "--tuned", str(tmp_path / "bad.json"), "--train-only"])
    assert exc.value.code == 2 and "bad.json" in capsys.readouterr().err
    # scoring tuned runs into the preset's folder would replace the default runs' report
    with pytest.raises(SystemExit) as exc:
        compare_rl.parse_args([*args, "--tuned", str(path)])
    assert exc.value.code == 2 and "--train-only" in capsys.readouterr().err
    assert compare_rl.parse_args([*args, "--tuned", str(path), "--out", str(tmp_path)]).tuned


def test_a_worker_whose_main_process_died_stops(monkeypatch):
    """A worker of the process backend stops when its main process is gone: after ``kill PID``
    of the main process, the orphaned workers went on training (their parent's sentinel did not
    report it), so the worker also compares its parent's pid."""
    import multiprocessing as mp
    import threading

    stop = threading.Event()
    backends._init_worker(None, stop)
    monkeypatch.setattr(mp, "parent_process", lambda: None)
    assert backends._should_stop() is False
    monkeypatch.setattr(backends.os, "getppid", lambda: backends._PARENT_PID + 1)  # reparented
    assert backends._should_stop() is True
    monkeypatch.undo()
    stop.set()
    assert backends._should_stop() is True
