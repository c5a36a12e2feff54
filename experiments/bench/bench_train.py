"""Training-loop throughput of VSG and the loop's own overhead.

``main()`` (``make bench``) measures the ``small`` size; ``python -m
experiments.bench.bench_train debug`` measures the ``debug`` size (a worst case for the
overhead share, since its updates are cheapest).

For each task, a :class:`vsgjax.loop.host_trainer.HostTrainer` is warmed up (prefill, compilation,
first
updates), then a window of agent steps (``WINDOWS``) of the steady-state loop is timed at the
default train ratio (one update per ``train_every`` agent steps; evaluation disabled; logging,
episode writing and checkpointing as configured). The same amounts of work are then timed bare:

* env: the same number of agent steps of a plain gymnasium env with random actions;
* train: the same number of the trainer's update calls on replay batches (compiled already);
* policy: the same number of jitted ``policy_step`` calls on one observation.

overhead = loop - (env + train + policy): the collection boundary (io_callback, episode
recording), replay (adds and sampling), MCAP writing and logging. Medians over ``REPEATS``.
Replay memory: bytes per stored step (uint8 images) times one million frames.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from vsgjax.config import make_config
from vsgjax.envs import make_env
from vsgjax.loop.host_trainer import HostTrainer
from vsgjax.loop.parallel import take
from vsgjax.train import enable_compilation_cache

TASKS = ("dmc_walker_walk", "bbs_basic")
WINDOWS = {"small": 60, "debug": 200}  # agent steps per timed window, by size
REPEATS = 3
RESULTS = Path(__file__).parent / "results" / "train.md"


def warm_trainer(task: str, size: str, logdir: Path) -> tuple[HostTrainer, float]:
    """A VSG trainer past prefill with a few updates done; returns it and the warm-up time.

    The train ratio is the size's default (one update of ``train.batch`` x ``train.length``
    per ``train.train_every`` agent steps).
    """
    config = make_config(task, "vsg", size, ["train.eval_every=100000000",
                                             "train.video_every=100000000"])
    started = time.perf_counter()
    trainer = HostTrainer(config, logdir, progress=False)
    while trainer.counters.updates < 3:
        trainer.iteration()
    return trainer, time.perf_counter() - started


def time_loop(trainer: HostTrainer, window: int) -> tuple[float, int]:
    """Seconds for ``window`` agent steps of the loop, and the updates it made."""
    start_steps, start_updates = trainer.counters.agent_steps, trainer.counters.updates
    started = time.perf_counter()
    while trainer.counters.agent_steps - start_steps < window:
        trainer.iteration()
    jax.block_until_ready(trainer.state)
    return time.perf_counter() - started, trainer.counters.updates - start_updates


def time_env(task_config, steps: int) -> float:
    env = make_env(task_config.env, seed=123)  # also seeds the action space
    env.reset()
    started = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - started
    env.close()
    return elapsed


def time_train(trainer: HostTrainer, updates: int) -> float:
    """Seconds of ``updates`` of the trainer's (one-seed) update on replay batches."""
    total, replay = 0.0, trainer.runs[0].replay
    keys = np.asarray(trainer.keys)
    for _ in range(updates):
        batch = trainer.parallel.put_batch([replay.sample(trainer.config.train.batch)])
        state = jax.tree.map(lambda leaf: leaf.copy(), trainer.state)  # the update donates it
        jax.block_until_ready((batch, state))  # copying and sampling are not timed
        started = time.perf_counter()
        _, metrics = trainer.parallel.train_step(state, batch, keys)
        jax.block_until_ready(metrics)
        total += time.perf_counter() - started
    return total


def time_policy(trainer: HostTrainer, steps: int) -> float:
    agent, spec = trainer.agent, trainer.collector.envs.spec
    params = take(trainer.state.params, 0)
    carry = agent.initial_carry(1)
    obs = {"image": np.zeros((1, *spec.obs_shape), np.uint8), "is_first": np.zeros(1, bool)}
    key = jax.random.PRNGKey(0)
    jax.block_until_ready(agent.policy_step(params, carry, obs, key))
    started = time.perf_counter()
    for _ in range(steps):
        carry, action = agent.policy_step(params, carry, obs, key)
        np.asarray(action)
    return time.perf_counter() - started


def bench_task(task: str, size: str) -> dict:
    with tempfile.TemporaryDirectory() as logdir:
        trainer, warmup = warm_trainer(task, size, Path(logdir))
        try:
            window = WINDOWS[size]
            loops = [time_loop(trainer, window) for _ in range(REPEATS)]
            updates = int(statistics.median(u for _, u in loops))
            row = {
                "task": task, "warmup_s": warmup, "updates": updates, "window": window,
                "train_every": trainer.config.train.train_every,
                "repeat": trainer.config.env.action_repeat,
                "loop": statistics.median(t for t, _ in loops),
                "env": statistics.median(time_env(trainer.config, window) for _ in range(REPEATS)),
                "train": statistics.median(time_train(trainer, updates) for _ in range(REPEATS)),
                "policy": statistics.median(time_policy(trainer, window) for _ in range(REPEATS)),
                "bytes_per_step": trainer.runs[0].replay.bytes_per_step,
            }
        finally:
            trainer.close()
    row["overhead"] = row["loop"] - row["env"] - row["train"] - row["policy"]
    return row


def markdown(rows: list[dict], size: str) -> str:
    lines = [
        f"## Training loop ({size} VSG, default train ratio)",
        "",
        f"Timed window: {WINDOWS[size]} agent steps of the steady-state loop (after prefill and "
        f"compilation), median of {REPEATS}. Bare times are the same amount of work alone: env "
        "steps with random actions, `train_step` calls, jitted `policy_step` calls. Overhead = "
        "loop − (env + train + policy): collection boundary, replay, episode files, logging.",
        "",
        "| task | env steps/s (loop) | loop s | env s | train s (updates) | policy s "
        "| overhead s | overhead % | warm-up s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        rate = r["window"] * r["repeat"] / r["loop"]
        lines.append(
            f"| {r['task']} | {rate:.1f} | {r['loop']:.2f} | {r['env']:.2f} | "
            f"{r['train']:.2f} ({r['updates']}) | {r['policy']:.2f} | {r['overhead']:.2f} | "
            f"{100 * r['overhead'] / r['loop']:.1f} | {r['warmup_s']:.0f} |")
    lines += ["", "Replay memory (uint8 images, one stored step per agent step):", ""]
    for r in rows:
        lines.append(f"- {r['task']}: {r['bytes_per_step']} bytes/step = "
                     f"{r['bytes_per_step'] * 1e6 / 2**30:.2f} GiB per million frames")
    return "\n".join(lines) + "\n"


def main(size: str = "small") -> None:
    enable_compilation_cache()  # compilation is reported (warm-up), not timed in the window
    rows = [bench_task(task, size) for task in TASKS]
    text = markdown(rows, size)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main(*sys.argv[1:2])
