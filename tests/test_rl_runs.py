"""No run of the RL comparison is ever overwritten by a run of another configuration (issue 28).

A smoke test (``--quick``) once replaced 10 of the 54 committed policies (19 CPU-hours): run files
were named by algorithm, variant and seed only. A run is now named by the fingerprint of its
whole configuration, ``--quick`` writes outside the repository by default, and the report's
files are written atomically.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")

from benchmarks.core import files  # noqa: E402
from benchmarks.rl import backends as backends  # noqa: E402
from benchmarks.rl import compare as compare_rl  # noqa: E402
from benchmarks.rl import train as rl_train  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _fake_train(spec, report=None, should_stop=None):
    """A training that returns at once: its policy bytes name its configuration."""
    point = rl_train.CurvePoint(spec.timesteps, 0.0, 1.0, 1.0, 0.5, 0, None)
    record = rl_train.RunRecord(spec.name, spec.algo, spec.variant, spec.seed,
                                spec.fingerprint(), spec.config(), spec.timesteps, 0.0, 0.0,
                                None, [point], [])  # fmt: skip
    return record, f"policy of {spec.fingerprint()}".encode()


def _snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (the runs of a task are in ``<task>/``), by relative path."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}  # fmt: skip


def test_a_run_of_another_configuration_never_replaces_a_kept_run(tmp_path, monkeypatch):
    """Same algorithm, variant and seed, another budget (what --quick and --timesteps do): the
    kept run's files stay byte-identical, the new run is kept beside it, and each is reused by
    its own configuration."""
    monkeypatch.setattr(backends, "train_run", _fake_train)
    kept = rl_train.RunSpec("ppo", "reward", 0, 8_000_000, 20, 100, 1)
    smoke = rl_train.RunSpec("ppo", "reward", 0, 64, 3, 20, 1)
    assert kept.name == smoke.name and kept.fingerprint() != smoke.fingerprint()
    quiet = {"workers": 1, "progress": False, "log": lambda msg: None}
    backends.train_all([kept], tmp_path, **quiet)
    before = _snapshot(tmp_path)
    backends.train_all([smoke], tmp_path, **quiet)
    after = _snapshot(tmp_path)
    assert {name: after[name] for name in before} == before  # byte-identical
    assert len(after) == 4
    assert set(before) == {f"SDJLS-Macro-v0/ppo_reward_s0-{kept.fingerprint()}.json",
                           f"SDJLS-Macro-v0/ppo_reward_s0-{kept.fingerprint()}.pt"}  # fmt: skip
    assert rl_train.load_run(tmp_path, kept).timesteps == 8_000_000
    assert rl_train.load_run(tmp_path, smoke).timesteps == 64
    # --retrain replaces only the run of the same configuration
    backends.train_all([smoke], tmp_path, retrain=True, **quiet)
    assert {name: _snapshot(tmp_path)[name] for name in before} == before


def test_a_run_in_the_older_layout_is_reused_and_never_written(tmp_path, monkeypatch):
    """A folder of runs named ``<name>.json`` (before the fingerprint was in the name) is read
    when the fingerprint recorded inside matches; a run of another configuration goes beside."""
    monkeypatch.setattr(backends, "train_run", _fake_train)
    spec = rl_train.RunSpec("sac", "residual", 1, 5000, 2, 10, 1)
    record, policy = _fake_train(spec)
    (tmp_path / "sac_residual_s1.json").write_text(json.dumps(record.to_json()))
    (tmp_path / "sac_residual_s1.pt").write_bytes(policy)
    before = _snapshot(tmp_path)
    assert rl_train.kept_run_path(tmp_path, spec) == tmp_path / "sac_residual_s1.json"
    other = rl_train.RunSpec("sac", "residual", 1, 100, 2, 10, 1)
    backends.train_all([spec, other], tmp_path, workers=1, progress=False, log=lambda m: None)
    after = _snapshot(tmp_path)
    assert {name: after[name] for name in before} == before and len(after) == 4


def test_quick_writes_outside_the_committed_results_by_default(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the quick folder made here
    opts = compare_rl.parse_args(["--quick"])
    assert opts.out.parent == tmp_path and opts.out.name.startswith("sdjls-gym-compare_rl-")
    assert ROOT not in opts.out.resolve().parents
    assert compare_rl.parse_args([]).out == Path("results/rl_suite")
    assert compare_rl.parse_args(["--preset", "macro"]).out == Path("results/rl")
    # a smoke test into a folder that holds a full comparison's report is refused by name
    with pytest.raises(SystemExit):
        compare_rl.parse_args(["--quick", "--out", str(ROOT / "results" / "rl")])
    err = capsys.readouterr().err
    assert "--quick" in err and "--out" in err and "results/rl" in err


def test_write_atomic_leaves_the_old_file_when_interrupted(tmp_path, monkeypatch):
    path = tmp_path / "summary.json"
    files.write_atomic(path, '{"old": 1}\n')

    def interrupted(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        files.write_atomic(path, '{"new": 2}\n' * 1000)
    assert path.read_text() == '{"old": 1}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]  # no temporary left


@pytest.mark.slow  # one PPO training of 1100 steps and a --quick scoring (about 30 s)
def test_compare_rl_keeps_a_run_of_another_budget_beside_the_kept_one(tmp_path, monkeypatch):
    """The command end to end: ``--timesteps`` changed, the kept run's files are byte-identical;
    the report's files are written through write_atomic (write, then rename)."""
    args = ["--quick", "--tasks", "SDJLS-Macro-v0", "--configs", "ppo_residual", "--seeds", "1",
            "--eval-episodes", "20", "--workers", "1", "--no-progress", "--out", str(tmp_path)]  # fmt: skip
    compare_rl.main([*args, "--timesteps", "1050"])
    runs = tmp_path / "runs" / "SDJLS-Macro-v0"
    before = _snapshot(runs)
    written = []
    real = compare_rl.write_atomic

    def recording(path, data):
        written.append(Path(path).name)
        return real(path, data)

    monkeypatch.setattr(compare_rl, "write_atomic", recording)
    summary = compare_rl.main([*args, "--timesteps", "1100"])
    after = _snapshot(runs)
    assert {name: after[name] for name in before} == before and len(after) == 4
    assert summary.rl_runs[0].run.timesteps >= 1100
    assert {"summary.json", "REPORT.md"} <= set(written)
