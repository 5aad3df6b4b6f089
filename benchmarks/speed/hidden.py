"""The speed rows of the hidden mode: per task of the suite, one decision of
``BeliefRecedingHorizonController.act(x, belief, k)`` against ``RecedingHorizonController.act(x,
mode, k)`` in alternating rounds on the same closed-loop states (target: at most
:data:`BELIEF_TARGET` times), and one step of the mode filter (``ModeFilter.step_batch``) on one
row and per row of a batch; and, as a check of what is timed, the belief controller at a certain belief
(the true mode's one-hot) against the mode controller on the same states (P3's answer).

The states are those of the belief controller's own closed loop with the mode hidden
(``HiddenModePolicy``, the inputs applied fed back), each with its belief and its true mode: the
mode controller decides from the true mode, the belief controller from the belief it had.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from benchmarks.speed.timing import calls_block, median_time, paired_times
from controllers import (
    BeliefRecedingHorizonController,
    HiddenModePolicy,
    ModeFilter,
    RecedingHorizonController,
)
from sdjls_gym import SDJLSVectorEnv
from sdjls_gym.systems import TASKS

__all__ = ["BELIEF_TARGET", "QUICK_TASKS", "hidden_states", "measure_hidden", "measure_hidden_task"]

#: The target of the hidden mode's speed: the belief controller's decision within this many
#: times the mode controller's.
BELIEF_TARGET = 3.0
#: The tasks timed with ``--quick``.
QUICK_TASKS = ("SDJLS-Solar-v0", "SDJLS-Degradation-v0")


def hidden_states(env_id: str, policy: HiddenModePolicy, count: int, seed: int) -> dict[str, Any]:
    """``count`` states of ``policy``'s closed loop on ``env_id`` with the mode hidden (20 steps
    of ``count // 20`` episodes): ``x`` (B, n), ``belief`` (B, N), ``mode`` (B,), ``k`` (B,),
    and the filter's steps ``(x, u, x_next, k)`` from them (``moved``: the rows whose next
    state follows from them, not a restart of the vector environment)."""
    task = TASKS[env_id]
    runs = max(1, count // 20)
    env = SDJLSVectorEnv(num_envs=runs, model=task.model, horizon=task.horizon,
                         action_bound=task.action_bound)  # fmt: skip
    _, info = env.reset(seed=seed)
    policy.reset(runs)
    applied = None
    xs, beliefs, modes, ks, us, nexts, moved = [], [], [], [], [], [], []
    for _ in range(20):
        u, decision = policy.act_hidden(info["state"], info["k"], applied)
        xs.append(info["state"])
        beliefs.append(decision["belief"])
        modes.append(info["mode"])
        ks.append(info["k"])
        _, _, _, _, info = env.step(u)
        applied = info["u"]
        us.append(info["u"])
        nexts.append(info["state"])
        moved.append(info["k"] == ks[-1] + 1)  # not a row the vector env restarted
    out = {key: np.concatenate(v) for key, v in
           (("x", xs), ("belief", beliefs), ("mode", modes), ("k", ks), ("u", us),
            ("x_next", nexts), ("moved", moved))}  # fmt: skip
    out["moved"] &= np.all(np.isfinite(out["x_next"]), axis=1)
    return out


def measure_hidden_task(env_id: str, opts: Any) -> dict[str, Any]:
    """One task's row (see the module)."""
    task = TASKS[env_id]
    model = task.model
    rhc = RecedingHorizonController(model, task.K, horizon=task.horizon, **task.rhc)
    belief = BeliefRecedingHorizonController(model, task.K, horizon=task.horizon, **task.rhc)
    s = hidden_states(env_id, HiddenModePolicy(belief), 100 if opts.quick else 400, seed=7)
    B = len(s["x"])
    it = iter(np.resize(np.arange(B), 10**7))

    def mode_act() -> Any:
        i = next(it)
        return rhc.act(s["x"][i], int(s["mode"][i]), int(s["k"][i]))

    jt = iter(np.resize(np.arange(B), 10**7))

    def belief_act() -> Any:
        i = next(jt)
        return belief.act(s["x"][i], s["belief"][i], int(s["k"][i]))

    (t_belief, t_mode), ratio = paired_times(
        [calls_block(belief_act, B), calls_block(mode_act, B)], opts.repeats
    )
    mode_filter = ModeFilter(model)
    steps = {key: s[key][s["moved"]] for key in ("belief", "x", "u", "x_next", "k")}
    one = {key: v[:1] for key, v in steps.items()}
    t_filter = median_time(
        lambda: mode_filter.step_batch(one["belief"], one["x"], one["u"], one["x_next"],
                                       one["k"]), opts.repeats, 200)  # fmt: skip
    t_filter_batch = median_time(
        lambda: mode_filter.step_batch(steps["belief"], steps["x"], steps["u"],
                                       steps["x_next"], steps["k"]),
        opts.repeats, 5) / len(steps["x"])  # fmt: skip
    certain = max(
        float(np.max(np.abs(belief.act(s["x"][i], np.eye(model.N)[s["mode"][i]], int(s["k"][i]))[0]
                            - rhc.act(s["x"][i], int(s["mode"][i]), int(s["k"][i]))[0])))
        for i in range(B)
    )  # fmt: skip
    return {
        "task": env_id,
        "states": B,
        "max_abs_diff_u_certain_belief_vs_mode": certain,
        "belief_act_us": 1e6 * t_belief,
        "mode_act_us": 1e6 * t_mode,
        "belief_vs_mode": ratio,
        "within_target": bool(ratio <= BELIEF_TARGET),
        "filter_step_us": 1e6 * t_filter,
        "filter_step_batch_per_row_us": 1e6 * t_filter_batch,
    }


def measure_hidden(opts: Any) -> dict[str, Any]:
    """Every task's row (quick: :data:`QUICK_TASKS`) and the target."""
    tasks = QUICK_TASKS if opts.quick else tuple(TASKS)
    rows = []
    for env_id in tasks:
        print(f"  {env_id}", flush=True)
        rows.append(measure_hidden_task(env_id, opts))
    return {"target": BELIEF_TARGET, "tasks": rows}
