"""The trainings' backends: the same runs and scores in one process, two processes and Ray.

Each training is seeded, rebuilt from its spec and uses one torch thread, so the backend and the
number of workers must not change a result. The Ray test starts a local instance of 2 CPUs
(never another address) and ships this checkout's packages to its workers.
"""

from __future__ import annotations

import json

import pytest

pytest.importorskip("stable_baselines3")

from benchmarks.rl import backends as backends  # noqa: E402
from benchmarks.rl import compare as compare_rl

ARGS = [
    "--quick", "--tasks", "SDJLS-Macro-v0", "--algos", "ppo", "td3", "--variants", "reward", "residual", "--seeds", "1",
    "--timesteps", "1050", "--eval-episodes", "50", "--no-progress",
]  # fmt: skip


def _runs(out) -> list[dict]:
    """The runs of a summary without what measures the machine (times)."""
    runs = json.loads((out / "summary.json").read_text())["rl_runs"]
    drop = ("train_time_s", "wall_time_s", "cpu_time_s", "eval_time_s")
    for r in runs:
        for key in drop:
            r.pop(key)
        for p in r["learning_curve"]:
            p.pop("wall_s")
        r["score"] = {k: v for k, v in r["score"].items() if not k.startswith("decision_time")}
    return runs


def assert_same_points(got: list[dict], expected: list[dict], rel: float) -> None:
    """Two lists of records (dicts) agree key by key, numbers to ``rel``; ``pytest.approx`` takes
    no nested structures (a TypeError from pytest 9 on; pytest 8 compared them)."""
    assert len(got) == len(expected)
    for g, e in zip(got, expected, strict=True):
        assert g.keys() == e.keys()
        for key, value in e.items():
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                assert g[key] == pytest.approx(value, rel=rel), key
            else:
                assert g[key] == value, key


def test_records_are_compared_key_by_key():
    """The comparison of learning curves works on the installed pytest (9.2 here), and fails
    where a record differs."""
    curve = [{"timesteps": 0, "violation": 0.5, "beta": None}, {"timesteps": 8, "violation": 0.25,
                                                                  "beta": None}]  # fmt: skip
    assert_same_points([dict(p) for p in curve], curve, rel=1e-5)
    close = [dict(curve[0]), {**curve[1], "violation": 0.25 * (1 + 1e-7)}]
    assert_same_points(close, curve, rel=1e-5)
    for bad in ({**curve[1], "violation": 0.3}, {**curve[1], "beta": 1.0}):
        with pytest.raises(AssertionError):
            assert_same_points([curve[0], bad], curve, rel=1e-5)


@pytest.mark.slow
def test_backends_and_worker_counts_give_the_same_runs(tmp_path):
    pytest.importorskip("ray")
    compare_rl.main([*ARGS, "--workers", "1", "--out", str(tmp_path / "one")])
    compare_rl.main([*ARGS, "--workers", "2", "--out", str(tmp_path / "two")])
    compare_rl.main([*ARGS, "--backend", "ray", "--workers", "2", "--out", str(tmp_path / "ray")])
    one, two, ray = (_runs(tmp_path / name) for name in ("one", "two", "ray"))
    assert [r["name"] for r in one] == ["ppo_reward_s0", "ppo_residual_s0", "td3_reward_s0",
                                        "td3_residual_s0"]  # fmt: skip
    for a, b, c in zip(one, two, ray, strict=True):
        assert a["fingerprint"] == b["fingerprint"] == c["fingerprint"]
        assert len(a["learning_curve"]) == 4
        # float32 networks on one thread: identical here; the tolerance allows for a machine
        # whose BLAS sums in another order
        for other in (b, c):
            assert_same_points(other["learning_curve"], a["learning_curve"], rel=1e-5)
            assert other["score"]["cost_mean"] == pytest.approx(a["score"]["cost_mean"], rel=1e-5)
            assert other["score"]["violation"] == pytest.approx(a["score"]["violation"], abs=1e-3)
    # the rest of the summaries (the model-based controllers, the best agent, the gaps) agree too
    full = [json.loads((tmp_path / name / "summary.json").read_text()) for name in ("one", "ray")]
    assert [full[1][key] for key in ("best_config", "best_agent")] == [
        full[0][key] for key in ("best_config", "best_agent")
    ]
    gaps = [
        [(d["name"], d["mean"]) for d in f["against_best_agent"]]
        + [(d["name"], d["mean"]) for rows in f["against_curves"].values() for d in rows]
        for f in full
    ]
    assert [name for name, _ in gaps[1]] == [name for name, _ in gaps[0]]
    assert [m for _, m in gaps[1]] == pytest.approx([m for _, m in gaps[0]], rel=1e-5, abs=1e-6)
    for a, c in zip(full[0]["model_based"], full[1]["model_based"], strict=True):
        assert a["name"] == c["name"]
        assert c["score"]["cost_mean"] == a["score"]["cost_mean"]  # no network: bit-identical
        assert c["score"]["violation"] == a["score"]["violation"]
    # a run interrupted on one backend resumes on the other, both ways: nothing is trained again
    for out, backend in (("ray", ["--workers", "1"]), ("one", ["--backend", "ray"])):
        stamps = {p.name: p.stat().st_mtime_ns for p in (tmp_path / out / "runs").rglob("*")}
        compare_rl.main([*ARGS, *backend, "--out", str(tmp_path / out)])
        after = {p.name: p.stat().st_mtime_ns for p in (tmp_path / out / "runs").rglob("*")}
        assert after == stamps, backend


def test_ray_missing_names_the_extra(monkeypatch, tmp_path):
    import builtins

    real = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray":
            raise ImportError("No module named 'ray'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(ImportError, match=r'pip install -e "\.\[cluster\]"'):
        backends.train_all([], tmp_path, backend="ray")
    with pytest.raises(ValueError, match="backend = 'dask'"):
        backends.train_all([], tmp_path, backend="dask")


def test_a_worker_stops_when_asked(monkeypatch):
    """The process backend's stop signal reaches a training through its callback."""
    from benchmarks.rl import train as rl_train

    spec = rl_train.RunSpec("ppo", "residual", 0, 10_000_000, 1, 5, 1)
    with pytest.raises(rl_train.TrainingStopped, match="ppo_residual_s0 was stopped"):
        rl_train.train_run(spec, should_stop=lambda: True)
