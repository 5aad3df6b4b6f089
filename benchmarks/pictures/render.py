"""The ``render()`` picture of ``SDJLS-Macro-v0``: two example frames and the frame rate.

``python -m benchmarks.render_picture`` writes to ``results/render/``:

1. ``macro_rhc.png``: the last frame of one episode of the macro example under the paper's
   receding-horizon controller (``RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC,
   horizon=20)``), seed ``--seed``;
2. ``macro_zero_input.png``: the last frame of an episode with ``u = 0``, which diverges;
3. ``render.json`` and ``RENDER.md``: frames per second of ``env.render()`` called after the
   reset and after every step of 20-step episodes under that controller, on one env (its figure
   reused, as ``RecordVideo`` does) against the reference of the same run: a fresh figure for
   every frame (``render_episode``, what ``render()`` did before the figure was reused), on the
   same histories. Also the wall time of recording one episode with
   ``gymnasium.wrappers.RecordVideo`` (encoding included).

``--fps-only`` skips the pictures and times only ``env.render()``, through the public API, so the
same command can time an older checkout of ``sdjls_gym``::

    git worktree add /tmp/old <commit>
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=/tmp/old python benchmarks/render_picture.py \\
        --fps-only --out /tmp/old-render
    python -m benchmarks.render_picture --before /tmp/old-render/render.json

``--before`` copies that run's numbers into ``RENDER.md`` with the commit it names.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import sdjls_gym  # noqa: F401  (registers the ids)
from benchmarks.core.cli import option, options_parser, output_folder, parse_options
from benchmarks.core.commands import prog
from sdjls_gym.env import SDJLSEnv
from sdjls_gym.systems.macro import HORIZON, PAPER_K, PAPER_RHC, macro

TARGET_FPS = 30.0  # a 20-step episode recorded as video at >= 30 frames per second


@dataclass
class Options:
    out: Path = option(
        Path("results/render"), "directory for the pictures, render.json and RENDER.md"
    )
    seed: int = option(
        0, "seed of the pictured episodes; the timed ones use seed + 1, seed + 2, ..."
    )
    episodes: int = option(10, "number of timed 20-step episodes")
    fps_only: bool = option(
        False, "time env.render() only (no pictures, no reference; works on older code)"
    )
    before: Path | None = option(
        None, "render.json of an --fps-only run on the code before the change, for RENDER.md"
    )


def paper_controller():
    from controllers import RecedingHorizonController

    return RecedingHorizonController(macro(), PAPER_K, **PAPER_RHC, horizon=HORIZON)


def rhc_policy(ctrl):
    def policy(info: dict[str, Any]) -> np.ndarray:
        u, _ = ctrl.act(info["state"], info["mode"], info["k"])
        return np.asarray(u, dtype=np.float32)

    return policy


def zero_policy(info: dict[str, Any]) -> np.ndarray:
    return np.zeros(1, dtype=np.float32)


def run_episode(env: gym.Env, policy, seed: int) -> tuple[list[float], np.ndarray, np.ndarray]:
    """One episode with ``env.render()`` after the reset and every step.

    Returns the time of each ``render()`` call, and the states and modes of the episode.
    """
    _, info = env.reset(seed=seed)
    times, xs, modes = [], [info["state"]], [info["mode"]]
    while True:
        t0 = time.perf_counter()
        env.render()
        times.append(time.perf_counter() - t0)
        *_, terminated, truncated, info = env.step(policy(info))
        xs.append(info["state"])
        modes.append(info["mode"])
        if terminated or truncated:
            break
    t0 = time.perf_counter()
    env.render()
    times.append(time.perf_counter() - t0)
    return times, np.array(xs), np.array(modes)


def time_reused(opts: Options, policy) -> tuple[dict[str, Any], list]:
    """Frames per second of ``env.render()`` on one env; the episodes' histories."""
    env = gym.make("SDJLS-Macro-v0", render_mode="rgb_array")
    run_episode(env, policy, opts.seed)  # warm-up: imports, first figure
    per_episode, histories = [], []
    for e in range(opts.episodes):
        times, xs, modes = run_episode(env, policy, opts.seed + 1 + e)
        per_episode.append(len(times) / sum(times))
        histories.append((xs, modes))
    return {
        "frames_per_episode": int(HORIZON + 1),
        "fps_median": statistics.median(per_episode),
        "fps_min": min(per_episode),
        "fps_max": max(per_episode),
    }, histories


def time_fresh(histories: list) -> dict[str, Any]:
    """Frames per second of a fresh figure per frame, on the same histories."""
    from sdjls_gym.render import render_episode

    model = macro()
    render_episode(model, histories[0][0][:1], histories[0][1][:1], HORIZON)  # warm-up
    per_episode = []
    for xs, modes in histories:
        t0 = time.perf_counter()
        for k in range(len(xs)):
            render_episode(model, xs[: k + 1], modes[: k + 1], HORIZON)
        per_episode.append(len(xs) / (time.perf_counter() - t0))
    return {
        "fps_median": statistics.median(per_episode),
        "fps_min": min(per_episode),
        "fps_max": max(per_episode),
    }


def time_record_video(opts: Options, policy) -> dict[str, Any]:
    """Wall time of one episode recorded by ``RecordVideo`` (stepping, frames and encoding)."""
    with tempfile.TemporaryDirectory() as tmp:
        env = gym.wrappers.RecordVideo(
            gym.make("SDJLS-Macro-v0", render_mode="rgb_array"),
            str(Path(tmp) / "video"),
            episode_trigger=lambda episode: True,
            disable_logger=True,
        )
        t0 = time.perf_counter()
        _, info = env.reset(seed=opts.seed)
        frames = 1
        while True:
            *_, terminated, truncated, info = env.step(policy(info))
            frames += 1
            if terminated or truncated:
                break
        env.close()  # writes the video
        seconds = time.perf_counter() - t0
        size = sum(p.stat().st_size for p in Path(tmp).rglob("*.mp4"))
    return {"frames": frames, "seconds": seconds, "fps": frames / seconds, "video_bytes": size}


def save_picture(opts: Options, policy, name: str) -> dict[str, Any]:
    from PIL import Image

    env = gym.make("SDJLS-Macro-v0", render_mode="rgb_array")
    run_episode(env, policy, opts.seed)
    frame = env.render()
    if not isinstance(frame, np.ndarray):  # render_mode="rgb_array" gives one image
        raise TypeError(f"env.render() returned {type(frame).__name__}; expected an RGB array")
    path = opts.out / name
    Image.fromarray(frame).save(path, optimize=True)
    unwrapped = env.unwrapped
    if not isinstance(unwrapped, SDJLSEnv):
        raise TypeError(f"SDJLS-Macro-v0 made a {type(unwrapped).__name__}; expected an SDJLSEnv")
    return {"file": name, "k": unwrapped.k, "shape": list(frame.shape), "final_state": [
        float(v) for v in unwrapped.state
    ]}  # fmt: skip


def git_commit() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(sdjls_gym.__file__).parent,
        )
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def write_report(opts: Options, result: dict[str, Any], before: dict[str, Any] | None) -> None:
    reused, fresh, video = result["render"], result["fresh"], result["record_video"]
    cmd = "python -m benchmarks.render_picture" + (
        f" --before {opts.before}" if opts.before else ""
    )
    lines = [
        "# The render() picture: frame rate",
        "",
        f"Made by `{cmd}` (code at commit `{result['commit']}`; {result['machine']}; load "
        f"average {result['load_average']:.2f} at the start). Frames per second of "
        f"`env.render()` called after the reset and after every step of {opts.episodes} "
        f"20-step episodes of `SDJLS-Macro-v0` under the paper's receding-horizon controller "
        f"({reused['frames_per_episode']} frames each; controller and steps not timed); median "
        "(min - max) over the episodes.",
        "",
        "| | frames/s |",
        "|---|---|",
        f"| `render()`, one figure per env, reused (this code) | {reused['fps_median']:.0f} "
        f"({reused['fps_min']:.0f} - {reused['fps_max']:.0f}) |",
        f"| reference in the same run: a fresh figure per frame (`render_episode`) | "
        f"{fresh['fps_median']:.1f} ({fresh['fps_min']:.1f} - {fresh['fps_max']:.1f}) |",
        f"| ratio reused / fresh | {reused['fps_median'] / fresh['fps_median']:.1f} |",
    ]
    if before is not None:
        b = before["render"]
        lines.append(
            f"| before the change: `render()` at commit `{before['commit']}` (load average "
            f"{before['load_average']:.2f}) | {b['fps_median']:.1f} "
            f"({b['fps_min']:.1f} - {b['fps_max']:.1f}) |"
        )
    if before is not None:
        lines += [
            "",
            f"The row *before the change* is the same timing loop run on commit "
            f"`{before['commit']}`, just before: `git worktree add /tmp/old {before['commit']} && "
            f"OPENBLAS_NUM_THREADS=1 PYTHONPATH=/tmp/old python benchmarks/render_picture.py "
            f"--fps-only --out {before['options']['out']}`.",
        ]
    lines += [
        "",
        f"Target: a 20-step episode recorded as video at >= {TARGET_FPS:.0f} frames/s: "
        f"**{'met' if reused['fps_min'] >= TARGET_FPS else 'NOT met'}** (slowest episode "
        f"{reused['fps_min']:.0f} frames/s).",
        "",
        f"`gymnasium.wrappers.RecordVideo`, one episode, seed {opts.seed}: {video['frames']} "
        f"frames in {video['seconds']:.2f} s wall time including the controller, the steps and "
        f"moviepy's encoding ({video['fps']:.0f} frames/s end to end; "
        f"{video['video_bytes'] / 1000:.0f} kB of mp4).",
        "",
        "Pictures (last frame of the episode, seed " + f"{opts.seed}):",
        "",
    ]
    for pic in result["pictures"]:
        lines.append(f"- `{pic['file']}`: {pic['what']}, k = {pic['k']}")
    lines.append("")
    (opts.out / "RENDER.md").write_text("\n".join(lines), encoding="utf-8")


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """``python -m benchmarks.render_picture``: the two example frames and the frame rate into
    ``--out``; see the module docstring and ``--help``."""
    parser = options_parser(
        Options, prog=prog("render_picture"), description=__doc__.split("\n\n")[0]
    )
    opts = parse_options(parser, Options, argv)
    if opts.episodes < 1:
        parser.error(f"--episodes = {opts.episodes}; expected an int >= 1")
    opts.out = output_folder(parser, "--out", opts.out, quick=False, default=None,
                             script="render_picture")  # fmt: skip
    opts.out.mkdir(parents=True, exist_ok=True)

    result: dict[str, Any] = {
        "commit": git_commit(),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}",
        "load_average": os.getloadavg()[0],
        "options": {k: str(v) for k, v in asdict(opts).items()},
    }
    policy = rhc_policy(paper_controller())
    result["render"], histories = time_reused(opts, policy)
    print(f"render(): {result['render']['fps_median']:.1f} frames/s", flush=True)
    if not opts.fps_only:
        result["fresh"] = time_fresh(histories)
        print(f"fresh figure per frame: {result['fresh']['fps_median']:.1f} frames/s", flush=True)
        result["record_video"] = time_record_video(opts, policy)
        result["pictures"] = [
            {**save_picture(opts, policy, "macro_rhc.png"), "what": "the paper's controller"},
            {**save_picture(opts, zero_policy, "macro_zero_input.png"), "what": "u = 0, diverges"},
        ]
    (opts.out / "render.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    if not opts.fps_only:
        before = json.loads(opts.before.read_text(encoding="utf-8")) if opts.before else None
        write_report(opts, result, before)
        print(f"wrote {opts.out / 'RENDER.md'}")
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
