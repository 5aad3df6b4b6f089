"""``controllers.ExplorationPolicy``: ``u = K_theta x + input_mean + input_std * eps``."""

from __future__ import annotations

import pickle
import threading

import numpy as np
import pytest

from controllers import ExplorationPolicy
from sdjls_gym.systems import TASKS
from sdjls_gym.systems.macro import PAPER_K, macro


def test_the_input_is_the_feedback_plus_the_offset_plus_the_noise():
    model = macro()
    policy = ExplorationPolicy(model, PAPER_K, 2.0, np.random.default_rng(0), input_mean=5.0)
    rng = np.random.default_rng(1)
    x, mode = rng.normal(size=(4000, 2)), rng.integers(0, 3, size=4000)
    u, info = policy.act_batch(x, mode, 0)
    feedback = np.einsum("bij,bj->bi", PAPER_K[mode], x)
    np.testing.assert_allclose(u - feedback, info["nu"], rtol=0, atol=1e-12)
    # the same draws as the generator gives: 5 + 2 * standard normals
    expected = 5.0 + 2.0 * np.random.default_rng(0).standard_normal((4000, 1))
    np.testing.assert_allclose(info["nu"], expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(info["cost"], model.stage_cost(x, mode, u))
    assert set(info["status"]) == {"explore"} and info["ok"].all() and not info["rho"].any()


def test_one_state_and_per_input_settings():
    task = TASKS["SDJLS-VTOL-v0"]  # m = 2
    policy = ExplorationPolicy(
        task.model, task.K, [0.0, 1.0], np.random.default_rng(2), input_mean=[3.0, 0.0]
    )
    x = np.arange(4.0)
    u, info = policy.act(x, 1, 7)
    assert u.shape == (2,) and isinstance(info["status"], str)
    assert info["nu"][0] == 3.0 and info["nu"][1] != 0.0  # no noise on input 0
    np.testing.assert_allclose(u, task.K[1] @ x + info["nu"])


def test_the_same_generator_state_gives_the_same_inputs():
    def inputs(policy):
        return policy.act_batch(np.ones((5, 2)), np.zeros(5, dtype=int), 0)[0]

    a = ExplorationPolicy(macro(), PAPER_K, 1.0, np.random.default_rng(3))
    b = ExplorationPolicy(macro(), PAPER_K, 1.0, np.random.default_rng(3))
    np.testing.assert_array_equal(inputs(a), inputs(b))
    copy = pickle.loads(pickle.dumps(a))  # carries the generator's state: repeats a's next draws
    np.testing.assert_array_equal(inputs(copy), inputs(a))


def test_threads_share_the_stream_and_use_every_draw_once():
    """4 threads, 50 calls of 10 rows each: the noise drawn is the generator's first 2000
    normals, each once (the draws are taken under the controller's lock)."""
    policy = ExplorationPolicy(macro(), PAPER_K, 1.0, np.random.default_rng(4))
    out: list[np.ndarray] = []
    lock = threading.Lock()

    def work():
        for _ in range(50):
            _, info = policy.act_batch(np.zeros((10, 2)), np.zeros(10, dtype=int), 0)
            with lock:
                out.append(info["nu"].ravel())

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    drawn = np.sort(np.concatenate(out))
    np.testing.assert_array_equal(drawn, np.sort(np.random.default_rng(4).standard_normal(2000)))


def test_predict_decodes_the_observation():
    policy = ExplorationPolicy(macro(), PAPER_K, 0.0, np.random.default_rng(5), input_mean=1.0)
    obs = np.array([2.0, 3.0, 0.0, 1.0, 0.0, 0.5], dtype=np.float32)  # x, one-hot mode 1, k/T
    action, _ = policy.predict(obs)
    np.testing.assert_allclose(action, PAPER_K[1] @ [2.0, 3.0] + 1.0, rtol=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "error", "words"),
    [
        ({"input_std": -1.0}, ValueError, ["input_std", "-1.0"]),
        ({"input_std": [1.0, 2.0]}, ValueError, ["input_std", "(2,)", "(1,)"]),
        ({"input_std": "1"}, TypeError, ["input_std", "'1'"]),
        ({"input_std": np.nan}, ValueError, ["input_std", "nan"]),
        ({"input_mean": [[1.0]]}, ValueError, ["input_mean", "(1, 1)"]),
        ({"rng": 0}, TypeError, ["rng", "0", "Generator"]),
        ({"rng": np.random.RandomState(0)}, TypeError, ["rng", "RandomState"]),
        ({"K": np.zeros((3, 1, 3))}, ValueError, ["K", "(3, 1, 3)"]),
        ({"model": "macro"}, TypeError, ["model", "'macro'"]),
    ],
)
def test_bad_settings_are_refused(kwargs, error, words):
    arguments = {
        "model": macro(), "K": PAPER_K, "input_std": 1.0, "rng": np.random.default_rng(0),
        **kwargs,
    }  # fmt: skip
    with pytest.raises(error) as raised:
        ExplorationPolicy(**arguments)
    for word in words:
        assert word in str(raised.value), (word, str(raised.value))
