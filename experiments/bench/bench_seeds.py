"""Many seeds in one process against as many single-seed processes; the sharded update.

``main()`` (``make bench``) runs, at the ``small`` size on BringBackShapes::

    python -m experiments.bench.bench_seeds                      # S = 1, 2, 4, 5 (~25 min)
    python -m experiments.bench.bench_seeds --seeds 1 2 --window 8 --repeats 1   # a quick look

1. The whole training loop (collection, replay, updates, logging, checkpoints; evaluation off)
   of S seeds in one process, and of S single-seed processes started together, each in a fresh
   process. Every process first warms up (prefill, compilation, 3 updates), then waits at a
   barrier, so the S processes time their windows at the same time on the same cores. A window
   is ``window`` agent steps per seed at the default train ratio; medians over ``repeats``.
   Rates are summed over seeds (S processes: the sum of their median rates). Memory: the peak
   resident set of the process (S processes: the sum of their peaks, an upper bound).
   The share of the loop spent in collection (policy + env steps of all seeds) shows whether
   collection is on the critical path. A third configuration runs the S seeds in one process
   sharded over S forced host devices (one seed per device).
2. One update, timed alone: the plain ``DreamerAgent.train_step``, the trainer's vmapped update
   of one
   seed, of 2 seeds, and both sharded over 2 forced host devices
   (``XLA_FLAGS=--xla_force_host_platform_device_count=2``; on a CPU both "devices" share the
   same cores, so this measures the partitioning's overhead, not a speed-up).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TASK = "bbs_basic"
# 250-step episodes: the replay holds a sequence sooner; the update's cost does not change
OVERRIDES = ["env.time_limit=1000", "train.eval_every=100000000",
             "train.video_every=100000000"]
SEEDS = (1, 2, 4, 5)
WINDOW, REPEATS = 24, 3  # agent steps per seed per timed window (12 updates at small)
UPDATE_REPEATS = 5
RESULTS = Path(__file__).parent / "results" / "seeds.md"


# --- in a child process --------------------------------------------------------------------------


def loop_child(seeds: list[int], window: int, repeats: int, barrier: str | None = None,
               size: str = "small", overrides: tuple[str, ...] = ()) -> dict:
    """Warm up a trainer of ``seeds``, wait at the barrier, time ``repeats`` loop windows."""
    from vsgjax.config import make_config
    from vsgjax.loop.host_trainer import HostTrainer
    from vsgjax.train import enable_compilation_cache

    enable_compilation_cache()
    configs = [make_config(TASK, "vsg", size, [f"train.seed={s}", *OVERRIDES, *overrides])
               for s in seeds]
    with tempfile.TemporaryDirectory() as root:
        started = time.perf_counter()
        trainer = HostTrainer(configs, [Path(root) / f"s{s}" for s in seeds], progress=False,
                          out=lambda *_: None)
        try:
            while trainer.counters.updates < 3:
                trainer.iteration()
            warmup = time.perf_counter() - started
            if barrier:
                wait_at(Path(barrier), seeds[0])
            windows = [time_window(trainer, window) for _ in range(repeats)]
        finally:
            trainer.close()
    row = {key: statistics.median(w[key] for w in windows) for key in windows[0]}
    return {**row, "warmup_s": warmup, "seeds": len(seeds),
            "repeat": configs[0].env.action_repeat,
            "peak_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}


def wait_at(barrier: Path, seed: int) -> None:
    (barrier / f"ready-{seed}").touch()
    while not (barrier / "go").exists():
        time.sleep(0.05)


def time_window(trainer, window: int) -> dict:
    """One window of the loop; the seconds spent collecting and updating inside it."""
    import jax

    spent = {"collect": 0.0, "train": 0.0}

    def timed(name, method):
        def call():
            started = time.perf_counter()
            method()
            spent[name] += time.perf_counter() - started
        return call

    collect, train_due = trainer.collect, trainer.train_due
    trainer.collect, trainer.train_due = timed("collect", collect), timed("train", train_due)
    start_steps, start_updates = trainer.counters.agent_steps, trainer.counters.updates
    started = time.perf_counter()
    while trainer.counters.agent_steps - start_steps < window:
        trainer.iteration()
    jax.block_until_ready(trainer.state)
    loop = time.perf_counter() - started
    trainer.collect, trainer.train_due = collect, train_due
    return {"loop_s": loop, "collect_s": spent["collect"], "train_s": spent["train"],
            "agent_steps": trainer.counters.agent_steps - start_steps,
            "updates": trainer.counters.updates - start_updates}


def update_child(repeats: int) -> dict:
    """Median seconds of one update: plain, vmapped over 1 and 2 seeds, on 1 and 2 devices."""
    import jax

    from experiments.bench.bench_agent import replay_batch
    from vsgjax.agents import make_agent
    from vsgjax.config import make_config
    from vsgjax.envs import EnvSpec
    from vsgjax.loop.parallel import Parallel, stack

    config = make_config(TASK, "vsg", "small")
    agent = make_agent(config, EnvSpec((64, 64, 3), 2, False))
    states = [agent.init(jax.random.PRNGKey(seed)) for seed in (0, 1)]
    batch = replay_batch(config, 2)
    key = jax.random.PRNGKey(0)

    def median_time(call, make_args) -> float:
        """Median seconds of ``call(*make_args())`` (the arguments are made untimed)."""
        times = []
        for _ in range(repeats + 1):  # the first call compiles
            args = jax.block_until_ready(make_args())
            started = time.perf_counter()
            jax.block_until_ready(call(*args)[1])
            times.append(time.perf_counter() - started)
        return statistics.median(times[1:])

    times = {"plain": median_time(agent.train_step, lambda: (states[0], batch, key))}
    for seeds, devices in ((1, 1), (1, 2), (2, 1), (2, 2)):
        parallel = Parallel(agent, seeds, devices)
        state = parallel.put_state(stack(states[:seeds]))
        inputs = (parallel.put_batch([batch] * seeds), np.stack([key] * seeds))
        # a copy per call: the update donates (consumes) its state
        copy = lambda state=state, inputs=inputs: (
            jax.tree.map(lambda leaf: leaf.copy(), state), *inputs)
        times[f"{seeds}x{devices}"] = median_time(parallel.train_step, copy)
    return times


# --- in the parent -------------------------------------------------------------------------------


def spawn(args: list[str], env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "experiments.bench.bench_seeds", *args],
                            stdout=subprocess.PIPE, text=True, env=env)


def result(process: subprocess.Popen) -> dict:
    out, _ = process.communicate()
    if process.returncode:
        raise RuntimeError(f"bench child failed ({process.returncode}): {out[-2000:]}")
    return json.loads(out.strip().splitlines()[-1])


def run_together(groups: list[list[int]], window: int, repeats: int,
                 devices: int = 0) -> list[dict]:
    """One child per seed group, timed windows after all of them warmed up; with ``devices``,
    each child sees that many forced host devices and shards its seeds over them."""
    env, overrides = None, []
    if devices:
        env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
        overrides = [f"train.devices={devices}"]
    with tempfile.TemporaryDirectory() as barrier:
        children = [spawn(["--child", json.dumps({"seeds": g, "window": window,
                                                  "repeats": repeats, "barrier": barrier,
                                                  "overrides": overrides})], env)
                    for g in groups]
        while len(list(Path(barrier).glob("ready-*"))) < len(groups):
            if any(child.poll() not in (None, 0) for child in children):
                break
            time.sleep(0.2)
        (Path(barrier) / "go").touch()
        return [result(child) for child in children]


def summary(rows: list[dict]) -> dict:
    """Seeds' summed rates of one configuration (one process, or S processes together)."""
    return {"env_steps_per_s": sum(r["seeds"] * r["agent_steps"] * r["repeat"] / r["loop_s"]
                                   for r in rows),
            "updates_per_s": sum(r["seeds"] * r["updates"] / r["loop_s"] for r in rows),
            "collect_share": statistics.mean(r["collect_s"] / r["loop_s"] for r in rows),
            "peak_rss": sum(r["peak_rss"] for r in rows),
            "warmup_s": max(r["warmup_s"] for r in rows)}


def markdown(table: list[tuple[int, dict, dict | None, dict | None]], updates: dict, window: int,
             repeats: int) -> str:
    gib = 2**30
    lines = [
        "## Many seeds in one process (small VSG, BringBackShapes)",
        "",
        f"The whole training loop at the default train ratio (one update of 8 x 32 per 2 agent "
        f"steps per seed; evaluation off), {window} agent steps per seed per window, median of "
        f"{repeats} windows after prefill, compilation and 3 updates. *One process*: S seeds "
        "in lockstep, one vmapped update. *S processes*: S single-seed runs started together "
        "(windows timed at the same time on the same 2 cores). Rates are totals over seeds; "
        "memory is the peak resident set (S processes: the sum of their peaks). "
        "Collection % is the loop's time in the policy and env steps of all seeds.",
        "",
        "| S | one process: env steps/s | seed-updates/s | collection % | peak GiB "
        "| S processes: env steps/s | seed-updates/s | peak GiB | speed ratio | memory ratio "
        "| one process on S forced devices: seed-updates/s | its speed ratio |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for seeds, one, many, sharded in table:
        cells = [f"{one['env_steps_per_s']:.1f}", f"{one['updates_per_s']:.2f}",
                 f"{100 * one['collect_share']:.1f}", f"{one['peak_rss'] / gib:.1f}"]
        if many is None:
            cells += ["(= one process)", "", "", "", "", "", ""]
        else:
            cells += [f"{many['env_steps_per_s']:.1f}", f"{many['updates_per_s']:.2f}",
                      f"{many['peak_rss'] / gib:.1f}",
                      f"{one['updates_per_s'] / many['updates_per_s']:.2f}",
                      f"{one['peak_rss'] / many['peak_rss']:.2f}",
                      f"{sharded['updates_per_s']:.2f}",
                      f"{sharded['updates_per_s'] / many['updates_per_s']:.2f}"]
        lines.append(f"| {seeds} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Speed ratio: seed-updates per second of one process over S processes (> 1: one "
        "process is faster); memory ratio: its peak over theirs (< 1: it needs less). The last "
        "columns: the same S seeds in one process with "
        "`XLA_FLAGS=--xla_force_host_platform_device_count=S train.devices=S` (each seed on its "
        "own host device, so XLA runs the seeds' programs side by side), against S processes.",
        "",
        "### One update, timed alone (small, batch 8 x 32, 2 forced host devices)",
        "",
        f"Median of {UPDATE_REPEATS} after compilation. `S x D`: the trainer's vmapped update of "
        "S seeds over D devices (`vsgjax.loop.parallel`); on one CPU the two forced devices share "
        "the "
        "same 2 cores, so D = 2 shows the sharding's overhead.",
        "",
        "| update | s | per seed s | vs plain |",
        "|---|---|---|---|",
    ]
    plain = updates["plain"]
    for name, seconds in updates.items():
        seeds = 1 if name == "plain" else int(name.split("x")[0])
        label = "plain `DreamerAgent.train_step`" if name == "plain" else name
        lines.append(f"| {label} | {seconds:.3f} | {seconds / seeds:.3f} | "
                     f"{seconds / seeds / plain:.2f} |")
    return "\n".join(lines) + "\n"


def main(seeds: tuple[int, ...] = SEEDS, window: int = WINDOW, repeats: int = REPEATS) -> None:
    table = []
    for count in seeds:
        one = summary(run_together([list(range(count))], window, repeats))
        many = sharded = None
        if count > 1:
            many = summary(run_together([[s] for s in range(count)], window, repeats))
            sharded = summary(run_together([list(range(count))], window, repeats, count))
        table.append((count, one, many, sharded))
        print(f"S={count}: one process {one}, S processes {many}, sharded {sharded}",
              flush=True)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    updates = result(spawn(["--updates", str(UPDATE_REPEATS)], env))
    text = markdown(table, updates, window, repeats)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, nargs="*", default=list(SEEDS))
    parser.add_argument("--window", type=int, default=WINDOW)
    parser.add_argument("--repeats", type=int, default=REPEATS)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--updates", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(loop_child(**json.loads(args.child))))
    elif args.updates:
        print(json.dumps(update_child(args.updates)))
    else:
        main(tuple(args.seeds), args.window, args.repeats)
