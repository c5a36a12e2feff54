"""The whole training loop on an MJX task: the device loop against the host loop.

Both loops train the same VSG (``cpu``, ``small`` and ``debug``; ``--sizes`` picks) with the
same config on ``mjx_cartpole_swingup``; only ``train.loop`` differs:

* ``device``: one jitted call per episode of every env (policy, MJX steps, replay, updates);
* ``host``: the host loop driving the same MJX envs through ``vsgjax/envs/mjx/vector_env.py`` (one
  jitted vmapped env step per agent step, the policy and the updates jitted apart, the replay
  and the episode files in Python).

Each trainer is warmed up past prefill and the compilation of its training programs (device:
its first training call; host: ``HOST_WARM_UPDATES`` updates), then windows of W agent steps
are timed, W = ``WINDOW_CALLS`` device calls (each ``env.num_envs`` x the episode's agent
steps), median of ``REPEATS``. Rate: W x action repeat env steps per second, the train ratio of
the config (one update per ``train.train_every`` agent steps) included. Evaluation (but the one
at the end of prefill, in the warm-up), videos and checkpoints are off; episode files and logs
are written as in training. The host loop's count includes its one reset step per episode
(gymnasium's NEXT_STEP autoreset).

    python -m experiments.bench.bench_mjx_loop [--sizes cpu small debug] [--smoke]

``--smoke`` times one short window at the debug size with 40-step episodes and writes nothing
(its warm-up, mostly compilation, takes minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import datetime
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax

from experiments.bench.run_all import machine_line
from vsgjax.config import make_config
from vsgjax.train import enable_compilation_cache, make_trainer

TASK, MODEL = "mjx_cartpole_swingup", "vsg"
LOOPS = ("device", "host")
WINDOW_CALLS, REPEATS, HOST_WARM_UPDATES = 1, 3, 3
OFF = ["train.eval_every=1000000000", "train.video_every=1000000000",
       "train.ckpt_every=1000000000", "train.steps=1000000000"]
SMOKE = ["env.time_limit=40", "env.num_envs=2", "train.length=8", "train.batch=3",
         "train.train_every=5", "train.prefill=80", "train.pretrain=1"]
RESULTS = Path(__file__).parent / "results" / "mjx_loop.md"


def warm_trainer(loop: str, size: str, overrides: list[str], logdir: Path):
    """A trainer of ``loop`` past prefill and its training programs' compilation, and the
    seconds that took."""
    config = make_config(TASK, MODEL, size, [f"train.loop={loop}", *OFF, *overrides])
    started = time.perf_counter()
    trainer = make_trainer([config], [logdir], progress=False)
    while not warm(trainer, loop):
        trainer.iteration()
    jax.block_until_ready(trainer.state)
    return trainer, time.perf_counter() - started


def warm(trainer, loop: str) -> bool:
    """Past prefill with the training programs compiled: the device loop's first training call
    is done, the host loop has made its pretraining and ``HOST_WARM_UPDATES`` more updates."""
    c = trainer.counters
    if loop == "device":
        return 0 <= c.train_start < c.agent_steps
    return c.updates >= trainer.config.train.pretrain + HOST_WARM_UPDATES


def time_window(trainer, agent_steps: int) -> float:
    """Seconds for ``agent_steps`` agent steps of the loop (all envs counted)."""
    start = trainer.counters.agent_steps
    started = time.perf_counter()
    while trainer.counters.agent_steps - start < agent_steps:
        trainer.iteration()
    jax.block_until_ready(trainer.state)
    return time.perf_counter() - started


def bench_loop(loop: str, size: str, overrides: list[str], window: int, repeats: int) -> dict:
    """Env steps per second of ``loop`` (median over ``repeats`` windows) and its warm-up."""
    with tempfile.TemporaryDirectory() as logdir:
        trainer, warmup = warm_trainer(loop, size, overrides, Path(logdir))
        try:
            repeat = trainer.config.env.action_repeat
            seconds = statistics.median(time_window(trainer, window) for _ in range(repeats))
            return {"loop": loop, "rate": window * repeat / seconds, "seconds": seconds,
                    "warmup": warmup, "config": trainer.config}
        finally:
            trainer.close()


def window_steps(size: str, overrides: list[str], calls: int) -> int:
    """W: the agent steps of ``calls`` device calls (N envs x E agent steps each)."""
    config = make_config(TASK, MODEL, size, overrides)
    episode = math.ceil(config.env.time_limit / config.env.action_repeat)
    return calls * config.env.num_envs * episode


def markdown(rows: list[dict], size: str, calls: int, window: int, repeats: int) -> str:
    config = rows[0]["config"]
    device, host = (next(r for r in rows if r["loop"] == loop) for loop in LOOPS)
    lines = [f"## MJX whole training loop: device vs host ({size} VSG, {TASK})", "",
             f"_Measured {datetime.date.today().isoformat()} on {machine_line()}._", "",
             f"Same config for both loops but `train.loop`: {config.env.num_envs} envs, "
             f"{config.env.time_limit} env steps per episode (action repeat "
             f"{config.env.action_repeat}), one update of {config.train.batch} x "
             f"{config.train.length} per {config.train.train_every} agent steps. Timed "
             f"window: {window} agent steps ({calls} device calls) after prefill and "
             f"compilation, median of {repeats}; evaluation, videos and checkpoints off.", "",
             "| loop | env steps/s | window s | warm-up s (prefill, compilation) |",
             "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['loop']} | {r['rate']:,.1f} | {r['seconds']:.2f} | "
                     f"{r['warmup']:.0f} |")
    lines += ["", f"Device / host: {device['rate'] / host['rate']:.1f}x."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.bench.bench_mjx_loop",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", nargs="+", default=["cpu", "small", "debug"],
                        choices=("cpu", "small", "debug"))
    parser.add_argument("--smoke", action="store_true",
                        help="one short window (debug size, short episodes); writes nothing")
    args = parser.parse_args(argv or [])
    sizes = ["debug"] if args.smoke else args.sizes
    overrides = SMOKE if args.smoke else []
    repeats, calls = (1, 1) if args.smoke else (REPEATS, WINDOW_CALLS)
    enable_compilation_cache()  # compilation is reported (warm-up), never timed
    sections = []
    for size in sizes:
        window = window_steps(size, overrides, calls)
        rows = [bench_loop(loop, size, overrides, window, repeats) for loop in LOOPS]
        sections.append(markdown(rows, size, calls, window, repeats))
    text = "\n".join(sections)
    if not args.smoke:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main(sys.argv[1:])
